#!/usr/bin/env bash
# Peak memory and time to the first pixel of `raytile render` on the bumpy sphere of
# scripts/make-mesh-glb.py at several sizes (128x128, 16 spp, the path tracer): peak resident
# set size from /usr/bin/time -v, bytes per triangle at that peak, and the load, build and
# first-pixel times `raytile render` prints. The .glb files are written to target/mesh-memory
# (once per size) so that nothing large lands in the repository.
#
#   bash scripts/mesh-memory.sh [RAYTILE_BINARY] [TRIANGLES ...]
#   bash scripts/mesh-memory.sh target/ci/raytile 1000000 4000000 10000000
#
# Build the binary first with `cargo build --profile ci -p raytile` (the default binary).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${1:-target/ci/raytile}
shift || true
sizes=("$@")
[ ${#sizes[@]} -gt 0 ] || sizes=(1000000 4000000 10000000)
dir=${MESH_DIR:-target/mesh-memory}
threads=${THREADS:-2}
mkdir -p "$dir"
echo "$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), $(nproc) cores; $bin, $threads threads; load average: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "| triangles | file MB | peak RSS MB | B/triangle | load s | build s | first pixel s | scene MB |"
echo "|---:|---:|---:|---:|---:|---:|---:|---:|"
for n in "${sizes[@]}"; do
  glb="$dir/bumpy-$n.glb"
  [ -f "$glb" ] || python3 scripts/make-mesh-glb.py "$glb" "$n" 2>/dev/null
  log="$dir/bumpy-$n.log"
  /usr/bin/time -v "$bin" render "$glb" -o "$dir/out.exr" --width 128 --height 128 --spp 16 \
    --threads "$threads" >/dev/null 2>"$log"
  line=$(grep 'scene loaded in' "$log")
  # "raytile: scene loaded in L s, built in B s (T triangles, M MB); rendering from F s"
  read -r load build tris mb first < <(echo "$line" |
    sed -E 's/.*loaded in ([0-9.]+) s, built in ([0-9.]+) s \(([0-9]+) triangles, ([0-9.]+) MB\); rendering from ([0-9.]+) s.*/\1 \2 \3 \4 \5/')
  rss_kb=$(grep 'Maximum resident set size' "$log" | awk '{print $NF}')
  file_mb=$(awk -v b="$(stat -c %s "$glb")" 'BEGIN { printf "%.1f", b / 1e6 }')
  awk -v t="$tris" -v kb="$rss_kb" -v f="$file_mb" -v l="$load" -v b="$build" -v fp="$first" -v mb="$mb" \
    'BEGIN { printf "| %d | %s | %.1f | %.0f | %s | %s | %s | %s |\n", t, f, kb * 1024 / 1e6, kb * 1024 / t, l, b, fp, mb }'
done
