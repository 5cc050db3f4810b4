#!/usr/bin/env bash
# Builds `raytile` and `raytile-worker` with profile-guided optimisation (PGO): an
# instrumented `raytile` renders a training set (the example scenes with the path, volpath,
# bdpt and sppm integrators, a glTF scene, and `raytile bench`'s traversal and BVH builds on a
# quarter-million-triangle mesh), then the release build is compiled again with the recorded
# profile (branch layout, inlining, hot and cold code). The images are the same bits as a plain `cargo build --release`: PGO
# changes no floating-point operation (Rust never contracts or reorders them), only how the
# code is laid out; check with `scripts/image-hashes.sh` on both binaries.
#
#   bash scripts/build-pgo.sh [OUTDIR]       # OUTDIR/raytile, OUTDIR/raytile-worker
#                                            # (default target/pgo/bin)
#
# The worker binary is built with the profile `raytile` recorded: the renderer is the same
# code (raytile-core) in both. RUSTFLAGS are passed on (scripts/build-images.sh adds static
# linking), RAYTILE_CPU=avx2 adds scripts/cpu-flags.sh's flags for AVX2 CPUs (the same
# bits); PGO_DIR (default target/pgo) holds the builds and profiles. Needs `llvm-profdata`
# of the compiler's LLVM: rustup's `llvm-tools` component, installed by this script when
# missing. Two release builds (about twice `cargo build --release`'s time) and a minute of
# training.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/pgo/bin}
dir=${PGO_DIR:-target/pgo}
host=$(rustc -vV | sed -n 's/^host: //p')
profdata="$(rustc --print sysroot)/lib/rustlib/$host/bin/llvm-profdata"
if [ ! -x "$profdata" ]; then
  echo "build-pgo: installing rustup's llvm-tools (for llvm-profdata)" >&2
  rustup component add llvm-tools
fi
# RAYTILE_CPU=avx2: a build for AVX2 CPUs (scripts/cpu-flags.sh), the same bits.
RUSTFLAGS="${RUSTFLAGS:-} $(bash scripts/cpu-flags.sh "${RAYTILE_CPU:-baseline}")"
export RUSTFLAGS
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)
profiles="$dir/profiles"
rm -rf "$profiles"
mkdir -p "$profiles"
# An explicit --target keeps RUSTFLAGS off build scripts and proc macros (which would
# otherwise be instrumented and write profiles while compiling).
echo "build-pgo: 1/3 instrumented build" >&2
RUSTFLAGS="${RUSTFLAGS:-} -Cprofile-generate=$profiles" \
  cargo build --locked --release -p raytile --target "$host" --target-dir "$dir/gen"
gen="$dir/gen/$host/release/raytile"

echo "build-pgo: 2/3 training" >&2
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
scenes=(scenes/*.json)
[ -f ../shared/scenes/cornell-box.gltf ] && scenes+=(../shared/scenes/cornell-box.gltf)
for scene in "${scenes[@]}"; do
  for integrator in path volpath bdpt sppm; do
    "$gen" render "$scene" -o "$tmp/i.exr" --width 96 --height 72 --spp 16 --max-depth 64 \
      --integrator "$integrator" --threads 2 2>/dev/null ||
      echo "build-pgo: training render failed: $integrator $scene" >&2
  done
done
"$gen" bench --size 96 --spp 16 --triangles 262144 --rays 300000 --caustic-spp 4 \
  --build binned_sah --build fast_build --width 8 >/dev/null
"$profdata" merge -o "$profiles/merged.profdata" "$profiles"

echo "build-pgo: 3/3 optimised build" >&2
RUSTFLAGS="${RUSTFLAGS:-} -Cprofile-use=$profiles/merged.profdata" \
  cargo build --locked --release -p raytile -p raytile-worker --target "$host" \
  --target-dir "$dir/use"
mkdir -p "$out"
cp "$dir/use/$host/release/raytile" "$dir/use/$host/release/raytile-worker" "$out/"
echo "build-pgo: $out/raytile, $out/raytile-worker" >&2
