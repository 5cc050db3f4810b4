#!/usr/bin/env bash
# Prints the rustc flags of a CPU level, for RUSTFLAGS:
#
#   bash scripts/cpu-flags.sh baseline   # nothing: x86-64 as every x86-64 CPU runs it
#   bash scripts/cpu-flags.sh avx2       # AVX2, BMI1/2, LZCNT, POPCNT; FMA off
#
# scripts/build-pgo.sh, scripts/build-images.sh and bench/run.sh read RAYTILE_CPU (default
# baseline) and add these flags. Both levels render the same bits (scripts/check-cpu-builds.sh checks it):
# the compiler uses the wider instructions for the same operations and, with FMA off, never
# fuses a multiply and an add, which would round once where the baseline rounds twice. An
# avx2 binary refuses to start on a CPU without those instructions (raytile_core::cpu).
set -euo pipefail
case "${1:-baseline}" in
  baseline) echo "" ;;
  avx2) echo "-C target-feature=+avx2,+bmi1,+bmi2,+lzcnt,+popcnt,-fma" ;;
  *)
    echo "cpu-flags: unknown CPU level '$1' (baseline or avx2)" >&2
    exit 2
    ;;
esac
