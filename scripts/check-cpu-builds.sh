#!/usr/bin/env bash
# Checks that the build for AVX2 CPUs (RAYTILE_CPU=avx2, scripts/cpu-flags.sh) renders the
# same bits as the default build.
#
#   bash scripts/check-cpu-builds.sh [PROFILE]   # builds `raytile` both ways with one cargo
#                                                # profile (default release) and compares
#                                                # scripts/image-hashes.sh of the two: every
#                                                # example scene, every integrator
#   bash scripts/check-cpu-builds.sh --golden    # lighter (CI): the core's golden-image test
#                                                # (pinned hashes, every integrator), compiled
#                                                # for AVX2
#
# The AVX2 builds go to target/cpu-avx2 (their flags differ, so they need a directory of
# their own). On a CPU without AVX2 there is nothing to run them on: the check is skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
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
  avx2_cargo test -q -p raytile-core --test golden
  echo "check-cpu-builds: the AVX2 build renders the pinned golden bits" >&2
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
