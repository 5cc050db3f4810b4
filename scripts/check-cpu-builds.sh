#!/usr/bin/env bash
# Checks that the build for AVX2 CPUs (RAYTILE_CPU=avx2, scripts/cpu-flags.sh) renders the
# same bits as the default build, that the default build renders them on CPUs without SSE4.1
# or AVX2 too, and that a build for AVX2 refuses to start on a CPU without it.
#
#   bash scripts/check-cpu-builds.sh [PROFILE]   # builds `raytile` both ways with one cargo
#                                                # profile (default release) and compares
#                                                # scripts/image-hashes.sh of the two: every
#                                                # example scene, every integrator
#   bash scripts/check-cpu-builds.sh --emulated [PROFILE]
#                                                # the default build's image hashes here and
#                                                # on emulated CPUs (qemu-x86_64 -cpu qemu64:
#                                                # no SSSE3, SSE4.1 nor AVX; -cpu Nehalem:
#                                                # SSE4.2, no AVX), about 80 s per CPU
#   bash scripts/check-cpu-builds.sh --golden    # lighter (CI): the core's golden-image test
#                                                # (pinned hashes, every integrator), compiled
#                                                # for AVX2, and with qemu: the default build's
#                                                # golden test on the emulated CPUs, and the
#                                                # AVX2 build's start-up gate on one without
#                                                # AVX2 (its message, exit status 1)
#
# The AVX2 builds go to target/cpu-avx2 (their flags differ, so they need a directory of
# their own). On a CPU without AVX2 there is nothing to run them on: the check is skipped.
# The emulated CPUs need qemu-user (`apt-get install qemu-user`); without it those checks are
# skipped, except under CI=true, where that fails.
set -euo pipefail
cd "$(dirname "$0")/.."
# The emulated CPUs: the default build takes its narrow paths there (no SSE4.1 sampler, the
# 4-wide BVH traversal).
emulated_cpus=(qemu64 Nehalem)
have_qemu() {
  if command -v qemu-x86_64 > /dev/null; then
    return 0
  fi
  if [ "${CI:-}" = true ] || [ "${CI:-}" = 1 ]; then
    echo "check-cpu-builds: qemu-x86_64 is missing (apt-get install qemu-user)" >&2
    exit 1
  fi
  echo "check-cpu-builds: no qemu-x86_64 (apt-get install qemu-user): emulated CPUs skipped" >&2
  return 1
}
# The path of a test binary cargo builds (it prints "Executable <src> (<path>)").
test_binary() {
  local path
  path=$("$@" --no-run 2>&1 | sed -n 's/^ *Executable .*(\(.*\))$/\1/p' | tail -1)
  if [ -z "$path" ]; then
    echo "check-cpu-builds: no test binary from: $*" >&2
    exit 1
  fi
  echo "$path"
}

if [ "${1:-}" = --emulated ]; then
  have_qemu || exit 0
  profile=${2:-release}
  case "$profile" in
    dev | test) dir=debug ;;
    *) dir=$profile ;;
  esac
  cargo build -q --locked --profile "$profile" -p raytile
  out=$(mktemp -d)
  trap 'rm -rf "$out"' EXIT
  bash scripts/image-hashes.sh "target/$dir/raytile" > "$out/native.txt"
  for cpu in "${emulated_cpus[@]}"; do
    printf '#!/bin/sh\nexec qemu-x86_64 -cpu %s "%s" "$@"\n' "$cpu" "$PWD/target/$dir/raytile" \
      > "$out/raytile-$cpu"
    chmod +x "$out/raytile-$cpu"
    bash scripts/image-hashes.sh "$out/raytile-$cpu" > "$out/$cpu.txt"
    if grep -q '^error' "$out/$cpu.txt" || ! diff "$out/native.txt" "$out/$cpu.txt" >&2; then
      echo "check-cpu-builds: -cpu $cpu renders different bits (diff above: here < > $cpu)" >&2
      exit 1
    fi
    echo "check-cpu-builds: $(wc -l < "$out/native.txt") renders, the same bits here and on -cpu $cpu" >&2
  done
  exit 0
fi

if ! grep -qw avx2 /proc/cpuinfo || ! grep -qw bmi2 /proc/cpuinfo; then
  echo "check-cpu-builds: this CPU has no AVX2/BMI2: skipped" >&2
  exit 0
fi
host=$(rustc -vV | sed -n 's/^host: //p')
flags=$(bash scripts/cpu-flags.sh avx2)
# An explicit --target keeps the flags off build scripts and proc macros.
avx2_cargo() {
  RUSTFLAGS="${RUSTFLAGS:-} $flags" cargo "$@" --locked --target "$host" \
    --target-dir target/cpu-avx2
}

if [ "${1:-}" = --golden ]; then
  echo "check-cpu-builds: the golden-image test built for AVX2 CPUs ($flags)" >&2
  avx2_cargo test -q -p raytile-core --test golden --test cpu_gate
  echo "check-cpu-builds: the AVX2 build renders the pinned golden bits" >&2
  have_qemu || exit 0
  # --workspace: the features the README's test command built with (nothing to rebuild).
  golden=$(test_binary cargo test --locked --workspace --test golden)
  for cpu in "${emulated_cpus[@]}"; do
    qemu-x86_64 -cpu "$cpu" "$golden" -q > /dev/null
    echo "check-cpu-builds: the default build renders the pinned golden bits on -cpu $cpu" >&2
  done
  gate=$(test_binary avx2_cargo test -p raytile-core --test cpu_gate)
  tmp_err=$(mktemp)
  trap 'rm -f "$tmp_err"' EXIT
  status=0
  qemu-x86_64 -cpu Nehalem "$gate" > /dev/null 2> "$tmp_err" || status=$?
  expected="this binary was built for CPUs with sse3, ssse3, sse4.1, sse4.2, popcnt, avx, avx2, bmi1, bmi2, lzcnt, and this CPU lacks avx, avx2, bmi1, bmi2, lzcnt: use the default build (it renders the same images)"
  if [ "$status" != 1 ] || ! grep -qF "$gate: $expected" "$tmp_err"; then
    echo "check-cpu-builds: the AVX2 build on -cpu Nehalem: exit status $status, stderr:" >&2
    cat "$tmp_err" >&2
    exit 1
  fi
  echo "check-cpu-builds: the AVX2 build refuses -cpu Nehalem with its message" >&2
  exit 0
fi

profile=${1:-release}
case "$profile" in
  dev | test) dir=debug ;;
  *) dir=$profile ;;
esac
echo "check-cpu-builds: default build ($profile)" >&2
cargo build -q --locked --profile "$profile" -p raytile
echo "check-cpu-builds: build for AVX2 CPUs ($profile, $flags)" >&2
avx2_cargo build -q --profile "$profile" -p raytile
base=target/$dir/raytile
avx2=target/cpu-avx2/$host/$dir/raytile
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
bash scripts/image-hashes.sh "$base" > "$out/base.txt"
bash scripts/image-hashes.sh "$avx2" > "$out/avx2.txt"
if grep -q '^error' "$out/base.txt" "$out/avx2.txt"; then
  grep '^error' "$out/base.txt" "$out/avx2.txt" >&2
  echo "check-cpu-builds: a render failed" >&2
  exit 1
fi
if ! diff "$out/base.txt" "$out/avx2.txt" >&2; then
  echo "check-cpu-builds: the AVX2 build renders different bits (diff above: default < > avx2)" >&2
  exit 1
fi
echo "check-cpu-builds: $(wc -l < "$out/base.txt") renders, the same bits from both builds" >&2
