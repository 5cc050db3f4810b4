#!/usr/bin/env bash
# Farm efficiency: a two-worker cluster against one process with the same total threads.
#
#   bash bench/farm.sh [--size 512] [--spp 64] [--threads 2] [--runs 3]
#
# Times `raytile render SCENE --threads T` and `raytile cluster --workers 2 --threads T
# --render SCENE` (a coordinator and two workers of T/2 threads each, talking HTTP on
# loopback: leases, heartbeats, binary tile uploads, SQLite), each as a whole process, the
# median of --runs runs, checks that both images are byte-identical, and prints
# efficiency = local time / cluster time (1.0: the farm costs nothing).
# RAYTILE_BIN overrides the binary (default: cargo build --release -p raytile).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
SIZE=512 SPP=64 THREADS=2 RUNS=3
SCENE=scenes/cornell-box.json
while [ $# -gt 0 ]; do
    case "$1" in
        --size) SIZE=$2; shift 2 ;;
        --spp) SPP=$2; shift 2 ;;
        --threads) THREADS=$2; shift 2 ;;
        --runs) RUNS=$2; shift 2 ;;
        --scene) SCENE=$2; shift 2 ;;
        -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
        *) echo "farm.sh: unknown argument '$1'" >&2; exit 2 ;;
    esac
done
if [ -z "${RAYTILE_BIN:-}" ]; then
    cargo build --release -q -p raytile
    RAYTILE_BIN=$ROOT/target/release/raytile
fi
OUT=$ROOT/bench/out
mkdir -p "$OUT"
FLAGS=(--width "$SIZE" --height "$SIZE" --spp "$SPP")

median() { sort -g | awk '{ a[NR] = $1 } END { print a[int((NR + 1) / 2)] }'; }
timed() { # command... -> seconds on stdout
    local s e
    s=$(date +%s%N)
    "$@" > /dev/null 2>&1
    e=$(date +%s%N)
    awk -v ns=$((e - s)) 'BEGIN { printf "%.3f\n", ns / 1e9 }'
}

local_times=() cluster_times=()
for _ in $(seq "$RUNS"); do
    local_times+=("$(timed "$RAYTILE_BIN" render "$SCENE" -o "$OUT/farm-local.exr" \
        --threads "$THREADS" "${FLAGS[@]}")")
    cluster_times+=("$(timed "$RAYTILE_BIN" cluster --workers 2 --threads "$THREADS" \
        --render "$SCENE" -o "$OUT/farm-cluster.exr" "${FLAGS[@]}")")
done
tl=$(printf '%s\n' "${local_times[@]}" | median)
tc=$(printf '%s\n' "${cluster_times[@]}" | median)
same=no
cmp -s "$OUT/farm-local.exr" "$OUT/farm-cluster.exr" && same=yes
printf 'scene %s, %sx%s, %s spp, %s threads in total, median of %s runs\n' \
    "$SCENE" "$SIZE" "$SIZE" "$SPP" "$THREADS" "$RUNS"
printf 'local  raytile render:               %s s  (runs: %s)\n' "$tl" "${local_times[*]}"
printf 'farm   raytile cluster --workers 2:  %s s  (runs: %s)\n' "$tc" "${cluster_times[*]}"
awk -v a="$tl" -v b="$tc" 'BEGIN { printf "efficiency (local / farm): %.3f\n", a / b }'
echo "images byte-identical: $same"
[ "$same" = yes ]
