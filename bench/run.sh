#!/usr/bin/env bash
# Cornell box benchmark: raytile vs Mitsuba 3 (scalar_rgb, llvm_ad_rgb) vs Blender Cycles.
#
#   bash bench/run.sh [--spp N] [--threads T] [--seed S] [--ref-spp N] [--no-bvh] [--no-crosscheck]
#
# The same settings can come from the environment: SPP, THREADS, SEED, REF_SPP, BVH=0,
# CROSSCHECK=0, SCENE, RAYTILE_BIN (use this binary instead of building). See bench/README.md for what it installs, the columns and timings.
# Exit status: 0 on success (a missing optional renderer is a skip with a message),
# non-zero on a real failure (a renderer crashing, means more than 5 sigma apart, ...).
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

SPP=${SPP:-64}
THREADS=${THREADS:-$(nproc)}
SEED=${SEED:-0}
REF_SPP=${REF_SPP:-4096}
REF_SEED=1000000 # far from SEED's passes: the reference's noise is independent
BVH=${BVH:-1}
CROSSCHECK=${CROSSCHECK:-1}
SCENE=${SCENE:-$ROOT/../shared/scenes/cornell-box.gltf}
WIDTH=256
HEIGHT=256
RAYTILE_MAX_DEPTH=1000

while [ $# -gt 0 ]; do
    case "$1" in
        --spp) SPP=$2; shift 2 ;;
        --threads) THREADS=$2; shift 2 ;;
        --seed) SEED=$2; shift 2 ;;
        --ref-spp) REF_SPP=$2; shift 2 ;;
        --no-bvh) BVH=0; shift ;;
        --no-crosscheck) CROSSCHECK=0; shift ;;
        -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
        *) echo "run.sh: unknown argument '$1' (try --help)" >&2; exit 2 ;;
    esac
done

OUT=$ROOT/bench/out
REF_DIR=$ROOT/target/bench-reference
VENV=$ROOT/bench/.venv
PY=$VENV/bin/python
ROWS=$OUT/rows.jsonl
NOTES=()

say() { printf '\n== %s\n' "$*" >&2; }
skip() { printf 'SKIP: %s\n' "$*" >&2; NOTES+=("skipped: $*"); }

[ -f "$SCENE" ] || { echo "run.sh: scene not found: $SCENE" >&2; exit 1; }
SCENE=$(cd "$(dirname "$SCENE")" && pwd)/$(basename "$SCENE")
mkdir -p "$OUT" "$REF_DIR"
: > "$ROWS"

# ---------------------------------------------------------------- installs (idempotent)
apt_missing() {
    local pkg missing=()
    for pkg in "$@"; do
        dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" \
            || missing+=("$pkg")
    done
    echo "${missing[@]:-}"
}

install_apt() {
    local missing sudo=""
    missing=$(apt_missing "$@")
    [ -z "$missing" ] && return 0
    if [ "$(id -u)" != 0 ]; then
        if command -v sudo > /dev/null && sudo -n true 2> /dev/null; then
            sudo="sudo -n"
        else
            skip "cannot install $missing (not root, no password-less sudo)"
            return 0
        fi
    fi
    say "apt-get install $missing"
    $sudo apt-get update -qq > /dev/null
    # shellcheck disable=SC2086
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq $missing > /dev/null \
        || skip "apt-get install $missing failed"
}

install_venv() {
    if [ -x "$PY" ] && "$PY" -c "import mitsuba, numpy" 2> /dev/null; then return 0; fi
    say "creating $VENV with mitsuba and numpy"
    python3 -m venv "$VENV"
    "$PY" -m pip install -q --disable-pip-version-check "mitsuba==3.9.1" numpy
}

if command -v dpkg-query > /dev/null; then
    # shellcheck disable=SC2046
    install_apt $(command -v blender > /dev/null || echo blender) python3-numpy libllvm19
fi
install_venv

LLVM_LIB=""
if command -v dpkg > /dev/null; then
    LLVM_LIB=$(dpkg -L libllvm19 2> /dev/null | grep -m1 -E '/libLLVM-19\.so$|/libLLVM\.so\.19' || true)
fi
export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-$LLVM_LIB}

# ---------------------------------------------------------------- helpers
row_from() { # keep the BENCH_JSON line of a render's output as a result row
    grep '^BENCH_JSON ' "$1" | tail -1 | sed 's/^BENCH_JSON //' >> "$ROWS"
}

mitsuba() { # variant spp seed out name [extra args...]
    local variant=$1 spp=$2 seed=$3 exr=$4 name=$5 log
    shift 5
    log=$OUT/$name.log
    if ! "$PY" bench/mitsuba_render.py "$SCENE" --variant "$variant" --spp "$spp" \
        --threads "$THREADS" --seed "$seed" --width $WIDTH --height $HEIGHT \
        --out "$exr" --work "$OUT/ply" --name "$name" "$@" > "$log" 2>&1; then
        cat "$log" >&2
        echo "run.sh: Mitsuba $variant failed (log above)" >&2
        exit 1
    fi
}

llvm_works() {
    [ -n "$DRJIT_LIBLLVM_PATH" ] && "$PY" -c \
        "import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); mi.Float(1) + 1" > /dev/null 2>&1
}

# ---------------------------------------------------------------- reference (cached)
REF_VARIANT=scalar_rgb
if llvm_works; then REF_VARIANT=llvm_ad_rgb; fi
SCENE_HASH=$(cat "$SCENE" bench/mitsuba_render.py bench/gltf_scene.py | sha256sum | cut -c1-12)
REF=$REF_DIR/cornell-${WIDTH}x${HEIGHT}-${REF_SPP}spp-$SCENE_HASH.exr
if [ ! -f "$REF" ]; then
    say "rendering the reference once: Mitsuba $REF_VARIANT, $REF_SPP spp -> $REF"
    mitsuba "$REF_VARIANT" "$REF_SPP" "$REF_SEED" "$REF.tmp.exr" reference
    mv "$REF.tmp.exr" "$REF"
    grep '^BENCH_JSON ' "$OUT/reference.log" | sed 's/^BENCH_JSON //' > "$REF.json"
fi
REF_LABEL="Mitsuba $(sed -n 's/.*"variant": "\([a-z_]*\)".*/\1/p' "$REF.json" 2>/dev/null || echo "$REF_VARIANT"), $REF_SPP spp, path max_depth -1 ($(basename "$REF"))"

# ---------------------------------------------------------------- raytile
if [ -n "${RAYTILE_BIN:-}" ]; then
    RAYTILE=$RAYTILE_BIN # a prebuilt binary (or a stand-in when testing this script)
else
    say "raytile: cargo build --release -p raytile"
    cargo build --release -p raytile
    RAYTILE=$ROOT/target/release/raytile
fi
if ! "$RAYTILE" render --help > /dev/null 2>&1; then
    skip "raytile has no working 'render' subcommand yet ('$RAYTILE render --help' fails)"
else
    say "raytile: $SPP spp, $THREADS threads, max depth $RAYTILE_MAX_DEPTH"
    start=$(date +%s%N)
    if ! "$RAYTILE" render "$SCENE" -o "$OUT/raytile.exr" --width $WIDTH --height $HEIGHT \
        --spp "$SPP" --max-depth $RAYTILE_MAX_DEPTH --threads "$THREADS" --seed "$SEED" \
        2> "$OUT/raytile.log"; then
        cat "$OUT/raytile.log" >&2
        echo "run.sh: raytile render failed (stderr above)" >&2
        exit 1
    fi
    wall=$(awk -v ns=$(($(date +%s%N) - start)) 'BEGIN { printf "%.3f", ns / 1e9 }')
    tail -3 "$OUT/raytile.log" >&2
    "$PY" bench/raytile_rows.py --stderr "$OUT/raytile.log" --wall "$wall" \
        --exr "$OUT/raytile.exr" --spp "$SPP" --threads "$THREADS" >> "$ROWS"
fi

# ---------------------------------------------------------------- Mitsuba
say "Mitsuba scalar_rgb: $SPP spp"
mitsuba scalar_rgb "$SPP" "$SEED" "$OUT/mitsuba-scalar.exr" "mitsuba scalar_rgb"
row_from "$OUT/mitsuba scalar_rgb.log"
if llvm_works; then
    say "Mitsuba llvm_ad_rgb: $SPP spp (JIT warm-up excluded)"
    mitsuba llvm_ad_rgb "$SPP" "$SEED" "$OUT/mitsuba-llvm.exr" "mitsuba llvm_ad_rgb"
    row_from "$OUT/mitsuba llvm_ad_rgb.log"
else
    skip "Mitsuba llvm_ad_rgb: needs LLVM >= 16 (install libllvm19; DRJIT_LIBLLVM_PATH='$DRJIT_LIBLLVM_PATH')"
fi
if [ "$CROSSCHECK" = 1 ]; then
    say "cross-check: Mitsuba's own mitsuba.cornell_box(), $SPP spp"
    variant=scalar_rgb
    llvm_works && variant=llvm_ad_rgb
    mitsuba $variant "$SPP" "$SEED" "$OUT/mitsuba-builtin.exr" "mitsuba.cornell_box() $variant" \
        --builtin-cornell
    row_from "$OUT/mitsuba.cornell_box() $variant.log"
    NOTES+=("mitsuba.cornell_box() is Mitsuba's own scene (not read from the glTF), light BSDF black, same settings: it checks the glTF conversion.")
fi

# ---------------------------------------------------------------- Cycles
if command -v blender > /dev/null; then
    say "Blender Cycles: $SPP spp"
    if ! PYTHONPATH=/usr/lib/python3/dist-packages${PYTHONPATH:+:$PYTHONPATH} \
        blender -b --factory-startup --python-exit-code 1 --python bench/cycles_render.py -- \
        "$SCENE" --spp "$SPP" --threads "$THREADS" --seed "$SEED" --width $WIDTH \
        --height $HEIGHT --out "$OUT/cycles.exr" > "$OUT/cycles.log" 2>&1; then
        tail -30 "$OUT/cycles.log" >&2
        echo "run.sh: Cycles render failed (log tail above)" >&2
        exit 1
    fi
    row_from "$OUT/cycles.log"
else
    skip "Blender Cycles: no 'blender' on PATH (apt-get install blender)"
fi

# ---------------------------------------------------------------- table
say "results ($(uptime | sed 's/.*load/load/'))"
NOTES+=("machine: $(nproc) cores, $(uptime | sed 's/.*load/load/'), $(date -u +%FT%TZ), commit $(git rev-parse --short HEAD 2>/dev/null || echo '?')")
NOTE_ARGS=()
for n in "${NOTES[@]}"; do NOTE_ARGS+=(--note "$n"); done
status=0
"$PY" bench/compare.py --rows "$ROWS" --reference "$REF" --reference-label "$REF_LABEL" \
    --markdown "$OUT/results.md" "${NOTE_ARGS[@]}" || status=$?

# ---------------------------------------------------------------- BVH and ray throughput
if [ "$BVH" = 1 ]; then
    say "RAYON_NUM_THREADS=$THREADS $RAYTILE bench (samples/s, Mrays/s, BVH presets on 1M triangles)"
    if RAYON_NUM_THREADS=$THREADS "$RAYTILE" bench > "$OUT/bvh.txt" 2>&1; then
        cat "$OUT/bvh.txt" >&2
        { printf '\n## Rays and BVH (`RAYON_NUM_THREADS=%s raytile bench`)\n\n```\n' "$THREADS"
          cat "$OUT/bvh.txt"; printf '```\n'; } >> "$OUT/results.md"
    else
        cat "$OUT/bvh.txt" >&2
        echo "run.sh: raytile bench failed (output above)" >&2
        status=1
    fi
fi

echo "Markdown: $OUT/results.md" >&2
exit $status
