#!/usr/bin/env bash
# Prints the sha256 of the linear EXR that `raytile render` writes for every example scene and
# every integrator (small images, few samples). Run it before and after a change that must not
# change image bits (a refactor, a speed-up) and diff the two outputs.
#
#   bash scripts/image-hashes.sh [RAYTILE_BINARY] > hashes.txt
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${1:-}
if [ -z "$bin" ]; then
  cargo build -q -p raytile
  bin=target/debug/raytile
fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
scenes=(scenes/*.json)
for f in ../shared/scenes/cornell-box.gltf ../shared/gltf-samples/*/*.gltf ../shared/gltf-samples/*/*.glb; do
  [ -f "$f" ] && scenes+=("$f")
done
for scene in "${scenes[@]}"; do
  for integrator in path whitted normals albedo depth ao volpath bdpt sppm; do
    passes=2
    [ "$integrator" = sppm ] && passes=1 # sppm renders in one pass
    if "$bin" render "$scene" -o "$out/i.exr" --width 48 --height 40 --spp 4 --passes $passes \
      --tile-size 16 --max-depth 8 --integrator "$integrator" --threads 2 >/dev/null 2>"$out/err"; then
      echo "$(sha256sum < "$out/i.exr" | cut -c1-16) $integrator $scene"
    else
      echo "error $integrator $scene: $(tail -1 "$out/err")"
    fi
  done
done
