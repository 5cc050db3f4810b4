#!/usr/bin/env bash
# Time to the first tile of a second job on the same large scene: the cost of getting a scene
# ready on a worker that has already rendered it once.
#
# Writes a ~1 M-triangle glTF (a bumpy sphere, the mesh of `raytile bench`) with
# scripts/make-mesh-glb.py, starts `raytile cluster` with one worker, renders a first job on
# the scene, then submits a second job (another seed) and times from its submission until its
# first task is done. Prints one line per run.
#
#   bash scripts/first-tile.sh [RAYTILE_BINARY] [RUNS]
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${1:-target/ci/raytile}
runs=${2:-3}
work=$(mktemp -d)
port=$((20000 + RANDOM % 20000))
base=http://127.0.0.1:$port
cleanup() {
  [ -n "${pid:-}" ] && kill "$pid" 2>/dev/null && wait "$pid" 2>/dev/null
  rm -rf "$work"
}
trap cleanup EXIT
python3 scripts/make-mesh-glb.py "$work/mesh.glb" 1048576
"$bin" cluster --workers 1 --threads 2 --listen "127.0.0.1:$port" --data-dir "$work/data" \
  >"$work/cluster.log" 2>&1 &
pid=$!
for _ in $(seq 100); do curl -sf "$base/healthz" >/dev/null && break; sleep 0.1; done
scene=$(curl -sf -X POST "$base/v1/scenes?format=glb" --data-binary @"$work/mesh.glb" | jq -r .id)
now_ms() { date +%s%3N; }
job() { # seed -> job id
  curl -sf -X POST "$base/v1/jobs" -H 'Content-Type: application/json' \
    -d "{\"scene\":\"$scene\",\"width\":64,\"height\":64,\"spp\":1,\"tile_size\":64,\"seed\":$1}" |
    jq -r .id
}
first_task_ms() { # job id -> ms from now until its first task is done
  local t0 done
  t0=$(now_ms)
  while :; do
    done=$(curl -sf "$base/v1/jobs/$1" | jq -r .tasks_done)
    [ "$done" -ge 1 ] && break
    sleep 0.01
  done
  echo $(($(now_ms) - t0))
}
t=$(first_task_ms "$(job 0)")
echo "first job on the scene: first tile after $t ms"
for i in $(seq "$runs"); do
  t=$(first_task_ms "$(job "$i")")
  echo "job $((i + 1)) on the same scene: first tile after $t ms"
done
