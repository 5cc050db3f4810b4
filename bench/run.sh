#!/usr/bin/env bash
# Benchmark: raytile vs Mitsuba 3 (scalar_rgb, llvm_ad_rgb) vs Blender Cycles on two scenes in
# one run: the Cornell box, and the Cornell box with a 1.05 M-triangle bumpy sphere (written by
# scripts/make-mesh-glb.py --cornell into target/bench-scenes).
#
#   bash bench/run.sh [--spp N] [--threads T] [--seed S] [--ref-spp N] [--scene cornell|sphere]
#                     [--repeat N] [--pgo] [--smoke] [--no-bvh] [--no-crosscheck]
#
# --pgo builds raytile with profile-guided optimisation (scripts/build-pgo.sh: two release
# builds and a training run; the same image bits, 11-15 % faster where measured).
# --repeat N renders each scene N times with every renderer, in turn (raytile, Mitsuba, Cycles,
# then again), and times each by the median of its N rounds: on a shared machine whose speed
# drifts from one minute to the next, a single round can be 25 % off; see bench/README.md.
# The same settings can come from the environment: SPP, THREADS, SEED, REF_SPP, REF_SPP_SPHERE
# (the sphere's reference; default REF_SPP), REPEAT, SCENES (cornell, sphere or "cornell sphere"),
# BVH=0, CROSSCHECK=0, MESH_TRIANGLES, SCENE (one other glTF scene instead of both), PGO=1,
# RAYTILE_CPU=avx2 (raytile built for AVX2 CPUs, scripts/cpu-flags.sh; with or without --pgo),
# RAYTILE_BIN (use this binary instead of building). See bench/README.md for what it installs,
# the columns and timings.
# Exit status: 0 on success (a missing optional renderer is a skip with a message),
# non-zero on a real failure (a renderer crashing, means more than 5 sigma apart, ...).
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

SPP=${SPP:-64}
THREADS=${THREADS:-$(nproc)}
SEED=${SEED:-0}
REPEAT=${REPEAT:-1}
PGO=${PGO:-0}
REF_SPP=${REF_SPP:-4096}
REF_SPP_SPHERE=${REF_SPP_SPHERE:-} # the sphere's reference, if not REF_SPP (it is 2x slower)
REF_SEED=1000000 # far from SEED's passes: the reference's noise is independent
BVH=${BVH:-1}
CROSSCHECK=${CROSSCHECK:-1}
SCENES=${SCENES:-cornell sphere}
MESH_TRIANGLES=${MESH_TRIANGLES:-1048576} # the grid rounds up: 1 051 250 triangles
CORNELL=$ROOT/../shared/scenes/cornell-box.gltf
WIDTH=256
HEIGHT=256
RAYTILE_MAX_DEPTH=1000
COMMAND="bash bench/run.sh${*:+ $*}"

while [ $# -gt 0 ]; do
    case "$1" in
        --spp) SPP=$2; shift 2 ;;
        --threads) THREADS=$2; shift 2 ;;
        --seed) SEED=$2; shift 2 ;;
        --ref-spp) REF_SPP=$2; shift 2 ;;
        --repeat) REPEAT=$2; shift 2 ;;
        --pgo) PGO=1; shift ;;
        --scene) SCENES=$2; shift 2 ;;
        --smoke) SPP=4; REF_SPP=64; REF_SPP_SPHERE=64; CROSSCHECK=0; BVH=0; shift ;;
        --no-bvh) BVH=0; shift ;;
        --no-crosscheck) CROSSCHECK=0; shift ;;
        -h|--help) sed -n '2,20p' "$0"; exit 0 ;;
        *) echo "run.sh: unknown argument '$1' (try --help)" >&2; exit 2 ;;
    esac
done
case "$REPEAT" in
    ''|*[!0-9]*|0|0*) echo "run.sh: --repeat needs a positive whole number, not '$REPEAT'" >&2; exit 2 ;;
esac
for key in $SCENES; do
    case "$key" in
        cornell|sphere) ;;
        *) echo "run.sh: unknown scene '$key' (cornell or sphere)" >&2; exit 2 ;;
    esac
done

OUT=$ROOT/bench/out
REF_DIR=${REF_DIR:-$ROOT/target/bench-reference}
SCENE_DIR=${SCENE_DIR:-$ROOT/target/bench-scenes}
VENV=$ROOT/bench/.venv
PY=$VENV/bin/python
NOTES=()  # notes of the run (skips, machine), under every table
SCENE_NOTES=() # notes of the scene being run

say() { printf '\n== %s\n' "$*" >&2; }
skip() { printf 'SKIP: %s\n' "$*" >&2; SCENE_NOTES+=("skipped: $*"); }
absolute() { echo "$(cd "$(dirname "$1")" && pwd)/$(basename "$1")"; }

if [ -n "${SCENE:-}" ]; then
    [ -f "$SCENE" ] || { echo "run.sh: scene not found: $SCENE" >&2; exit 1; }
    SCENE=$(absolute "$SCENE")
    SCENES=custom
fi
[ -f "$CORNELL" ] || { echo "run.sh: the Cornell box is not at $CORNELL" >&2; exit 1; }
CORNELL=$(absolute "$CORNELL")

mkdir -p "$OUT" "$REF_DIR" "$SCENE_DIR"

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
    install_apt $(command -v blender > /dev/null || echo blender) python3-numpy libllvm19 time
fi
install_venv

LLVM_LIB=""
if command -v dpkg > /dev/null; then
    LLVM_LIB=$(dpkg -L libllvm19 2> /dev/null | grep -m1 -E '/libLLVM-19\.so$|/libLLVM\.so\.19' || true)
fi
export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-$LLVM_LIB}

NOTES+=(${SCENE_NOTES[@]+"${SCENE_NOTES[@]}"}) # install skips concern every scene
SCENE_NOTES=()

# ---------------------------------------------------------------- helpers
row_from() { # keep the BENCH_JSON lines of a render's output as result rows
    grep '^BENCH_JSON ' "$1" | sed 's/^BENCH_JSON //' >> "$ROWS"
}

mitsuba() { # scene variant spp seed out name [extra args...]
    local scene=$1 variant=$2 spp=$3 seed=$4 exr=$5 name=$6 log
    shift 6
    log=$SOUT/$name.log
    if ! "$PY" bench/mitsuba_render.py "$scene" --variant "$variant" --spp "$spp" \
        --threads "$THREADS" --seed "$seed" --width $WIDTH --height $HEIGHT \
        --out "$exr" --work "$SOUT/ply" --name "$name" "$@" > "$log" 2>&1; then
        cat "$log" >&2
        echo "run.sh: Mitsuba $variant failed (log above)" >&2
        exit 1
    fi
}

llvm_works() {
    [ -n "$DRJIT_LIBLLVM_PATH" ] && "$PY" -c \
        "import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); mi.Float(1) + 1" > /dev/null 2>&1
}
LLVM=0
if llvm_works; then LLVM=1; fi

# ---------------------------------------------------------------- machine
CPU_MODEL=$(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo 2> /dev/null | head -1)
CPU_FLAGS=" $(sed -n 's/^flags[[:space:]]*: //p' /proc/cpuinfo 2> /dev/null | head -1) "
VECTOR=""
for f in sse4_1 sse4_2 avx avx2 fma avx512f avx512bw avx512vl avx512_vnni; do
    case "$CPU_FLAGS" in *" $f "*) VECTOR+="${VECTOR:+ }$f" ;; esac
done
MACHINE="${CPU_MODEL:-unknown CPU}, $(nproc) cores, $(free -g 2> /dev/null | awk '/^Mem:/ { print $2 " GiB" }'); vector extensions: ${VECTOR:-none of sse4_1..avx512}"

# ---------------------------------------------------------------- raytile binary
if [ -n "${RAYTILE_BIN:-}" ]; then
    RAYTILE=$RAYTILE_BIN # a prebuilt binary (or a stand-in when testing this script)
elif [ "$PGO" = 1 ]; then
    say "raytile: scripts/build-pgo.sh (profile-guided optimisation)"
    bash scripts/build-pgo.sh target/pgo/bin
    RAYTILE=$ROOT/target/pgo/bin/raytile
    NOTES+=("raytile built with profile-guided optimisation (scripts/build-pgo.sh)")
elif [ "${RAYTILE_CPU:-baseline}" = baseline ]; then
    say "raytile: cargo build --release -p raytile"
    cargo build --release -p raytile
    RAYTILE=$ROOT/target/release/raytile
else
    # A build for newer CPUs (scripts/cpu-flags.sh): its own target directory, as the flags
    # differ; --target keeps them off build scripts and proc macros.
    host=$(rustc -vV | sed -n 's/^host: //p')
    say "raytile: cargo build --release -p raytile, RAYTILE_CPU=$RAYTILE_CPU"
    RUSTFLAGS="$(bash scripts/cpu-flags.sh "$RAYTILE_CPU")" cargo build --release -p raytile \
        --target "$host" --target-dir "target/cpu-$RAYTILE_CPU"
    RAYTILE=$ROOT/target/cpu-$RAYTILE_CPU/$host/release/raytile
fi
if [ -z "${RAYTILE_BIN:-}" ] && [ "${RAYTILE_CPU:-baseline}" != baseline ]; then
    NOTES+=("raytile built for RAYTILE_CPU=$RAYTILE_CPU ($(bash scripts/cpu-flags.sh "$RAYTILE_CPU"))")
fi
RAYTILE_OK=1
if ! "$RAYTILE" render --help > /dev/null 2>&1; then
    RAYTILE_OK=0
    NOTES+=("skipped: raytile has no working 'render' subcommand yet ('$RAYTILE render --help' fails)")
fi

# ---------------------------------------------------------------- one scene
# run_scene KEY FILE TITLE REF_SPP [TRIANGLES]: reference, every renderer, the table in
# $OUT/KEY/results.md.
status=0
run_scene() {
    local key=$1 scene=$2 title=$3 ref_spp=$4 triangles=${5:-}
    SOUT=$OUT/$key
    ROWS=$SOUT/rows.jsonl
    SCENE_NOTES=()
    mkdir -p "$SOUT"
    rm -f "$SOUT"/*.exr "$SOUT"/*.log
    : > "$ROWS"
    say "scene $key: $title"

    # Reference (cached): keyed by the scene file, the Mitsuba scene builder and the settings.
    local variant=scalar_rgb hash ref ref_label
    [ "$LLVM" = 1 ] && variant=llvm_ad_rgb
    hash=$(cat "$scene" bench/mitsuba_render.py bench/gltf_scene.py | sha256sum | cut -c1-12)
    ref=$REF_DIR/$key-${WIDTH}x${HEIGHT}-${ref_spp}spp-$hash.exr
    if [ ! -f "$ref" ]; then
        say "rendering the reference once: Mitsuba $variant, $ref_spp spp -> $ref"
        mitsuba "$scene" "$variant" "$ref_spp" "$REF_SEED" "$ref.tmp.exr" reference
        mv "$ref.tmp.exr" "$ref"
        grep '^BENCH_JSON ' "$SOUT/reference.log" | sed 's/^BENCH_JSON //' > "$ref.json"
    fi
    ref_label="Mitsuba $(sed -n 's/.*"variant": "\([a-z_]*\)".*/\1/p' "$ref.json" 2>/dev/null || echo "$variant"), $ref_spp spp, path max_depth -1 ($(basename "$ref"))"

    # The renderers, REPEAT rounds (each round runs them in turn).
    local round
    for ((round = 1; round <= REPEAT; round++)); do
        [ "$REPEAT" -gt 1 ] && say "round $round of $REPEAT"
        # raytile: the render time from its summary, and the whole process.
        if [ "$RAYTILE_OK" = 1 ]; then
            say "raytile: $SPP spp, $THREADS threads, max depth $RAYTILE_MAX_DEPTH"
            local start wall timer=()
            # Peak resident memory of the whole process, where GNU time is installed.
            [ -x /usr/bin/time ] && timer=(/usr/bin/time -f '%M' -o "$SOUT/raytile.maxrss")
            start=$(date +%s%N)
            if ! ${timer[@]+"${timer[@]}"} "$RAYTILE" render "$scene" -o "$SOUT/raytile.exr" \
                --width $WIDTH --height $HEIGHT --spp "$SPP" --max-depth $RAYTILE_MAX_DEPTH \
                --threads "$THREADS" --seed "$SEED" 2> "$SOUT/raytile.log"; then
                cat "$SOUT/raytile.log" >&2
                echo "run.sh: raytile render failed (stderr above)" >&2
                exit 1
            fi
            wall=$(awk -v ns=$(($(date +%s%N) - start)) 'BEGIN { printf "%.3f", ns / 1e9 }')
            tail -3 "$SOUT/raytile.log" >&2
            "$PY" bench/raytile_rows.py --stderr "$SOUT/raytile.log" --wall "$wall" \
                --exr "$SOUT/raytile.exr" --spp "$SPP" --threads "$THREADS" >> "$ROWS"
            if [ "$round" -eq "$REPEAT" ] && [ -s "$SOUT/raytile.maxrss" ]; then
                local kb
                kb=$(tail -1 "$SOUT/raytile.maxrss")
                SCENE_NOTES+=("raytile peak resident memory (whole process, /usr/bin/time -f %M): $((kb / 1024)) MiB${triangles:+, $((kb * 1024 / triangles)) bytes per triangle of the sphere}.")
            fi
        fi

        # Mitsuba
        say "Mitsuba scalar_rgb: $SPP spp"
        mitsuba "$scene" scalar_rgb "$SPP" "$SEED" "$SOUT/mitsuba-scalar.exr" "mitsuba scalar_rgb"
        row_from "$SOUT/mitsuba scalar_rgb.log"
        if [ "$LLVM" = 1 ]; then
            say "Mitsuba llvm_ad_rgb: $SPP spp (JIT warm-up excluded)"
            mitsuba "$scene" llvm_ad_rgb "$SPP" "$SEED" "$SOUT/mitsuba-llvm.exr" "mitsuba llvm_ad_rgb"
            row_from "$SOUT/mitsuba llvm_ad_rgb.log"
        elif [ "$round" = 1 ]; then
            skip "Mitsuba llvm_ad_rgb: needs LLVM >= 16 (install libllvm19; DRJIT_LIBLLVM_PATH='$DRJIT_LIBLLVM_PATH')"
        fi
        # Cycles
        if command -v blender > /dev/null; then
            say "Blender Cycles: $SPP spp"
            if ! PYTHONPATH=/usr/lib/python3/dist-packages${PYTHONPATH:+:$PYTHONPATH} \
                blender -b --factory-startup --python-exit-code 1 --python bench/cycles_render.py -- \
                "$scene" --spp "$SPP" --threads "$THREADS" --seed "$SEED" --width $WIDTH \
                --height $HEIGHT --out "$SOUT/cycles.exr" > "$SOUT/cycles.log" 2>&1; then
                tail -30 "$SOUT/cycles.log" >&2
                echo "run.sh: Cycles render failed (log tail above)" >&2
                exit 1
            fi
            row_from "$SOUT/cycles.log"
        elif [ "$round" = 1 ]; then
            skip "Blender Cycles: no 'blender' on PATH (apt-get install blender)"
        fi
    done

    if [ "$CROSSCHECK" = 1 ] && [ "$key" = cornell ]; then
        say "cross-check: Mitsuba's own mitsuba.cornell_box(), $SPP spp"
        mitsuba "$scene" "$variant" "$SPP" "$SEED" "$SOUT/mitsuba-builtin.exr" \
            "mitsuba.cornell_box() $variant" --builtin-cornell
        row_from "$SOUT/mitsuba.cornell_box() $variant.log"
        SCENE_NOTES+=("mitsuba.cornell_box() is Mitsuba's own scene (not read from the glTF), light BSDF black, same settings: it checks the glTF conversion.")
    fi

    # Table
    say "results: $title ($(uptime | sed 's/.*load/load/'))"
    local note_args=() n
    for n in ${NOTES[@]+"${NOTES[@]}"} ${SCENE_NOTES[@]+"${SCENE_NOTES[@]}"}; do
        note_args+=(--note "$n")
    done
    note_args+=(--note "load after this scene: $(uptime | sed 's/.*load average: //')")
    "$PY" bench/compare.py --rows "$ROWS" --reference "$ref" --reference-label "$ref_label" \
        --title "$title" --markdown "$SOUT/results.md" ${note_args[@]+"${note_args[@]}"} \
        || status=$?
}

# ---------------------------------------------------------------- the scenes
STARTED=$(date -u '+%F %H:%M UTC')
NOTES+=("machine: $MACHINE; $THREADS render threads")
NOTES+=("run started $STARTED at commit $(git rev-parse --short HEAD 2>/dev/null || echo '?'), load average then: $(uptime | sed 's/.*load average: //')")
printf '%s\n%s\n' "machine: $MACHINE" "date: $STARTED" >&2
for key in $SCENES; do
    case "$key" in
        cornell)
            run_scene cornell "$CORNELL" "Cornell box (../shared/scenes/cornell-box.gltf, 36 triangles)" \
                "$REF_SPP" ;;
        sphere)
            mesh_hash=$(printf '%s\n' "$MESH_TRIANGLES" | cat - scripts/make-mesh-glb.py "$CORNELL" \
                | sha256sum | cut -c1-12)
            mesh=$SCENE_DIR/cornell-sphere-$mesh_hash.glb
            if [ ! -f "$mesh" ]; then
                say "writing the bumpy-sphere scene: $mesh"
                python3 scripts/make-mesh-glb.py "$mesh.tmp" "$MESH_TRIANGLES" --cornell "$CORNELL"
                mv "$mesh.tmp" "$mesh"
            fi
            triangles=$(python3 -c "import math, sys; g = math.ceil(math.sqrt($MESH_TRIANGLES / 2)); print(2 * g * g)")
            run_scene cornell-sphere "$mesh" "Cornell box with a bumpy sphere of $triangles triangles (scripts/make-mesh-glb.py --cornell, $(basename "$mesh"))" \
                "${REF_SPP_SPHERE:-$REF_SPP}" "$triangles" ;;
        custom)
            run_scene "$(basename "${SCENE%.*}")" "$SCENE" "$(basename "$SCENE")" "$REF_SPP" ;;
    esac
done

# ---------------------------------------------------------------- results.md
{
    printf '# raytile vs Mitsuba 3 vs Cycles\n\n'
    printf -- '- machine: %s\n- date: %s; %s spp, %s threads, %sx%s, seed %s\n- command: `%s`\n' \
        "$MACHINE" "$STARTED" "$SPP" "$THREADS" "$WIDTH" "$HEIGHT" "$SEED" "$COMMAND"
    for key in $SCENES; do
        [ "$key" = sphere ] && key=cornell-sphere
        [ "$key" = custom ] && key=$(basename "${SCENE%.*}")
        [ -f "$OUT/$key/results.md" ] && { printf '\n'; cat "$OUT/$key/results.md"; }
    done
} > "$OUT/results.md"

# ---------------------------------------------------------------- BVH and ray throughput
if [ "$BVH" = 1 ] && [ "$RAYTILE_OK" = 1 ]; then
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

printf '\nmachine: %s\ndate: %s, finished %s (%s)\n' "$MACHINE" "$STARTED" \
    "$(date -u '+%H:%M UTC')" "$(uptime | sed 's/.*load/load/')" >&2
echo "Markdown: $OUT/results.md" >&2
exit $status
