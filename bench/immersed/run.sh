#!/usr/bin/env bash
# Objects immersed in absorbing bodies (a lamp in tinted glass, a stone in coloured water, a
# clear marble and a block in a coloured liquid, and a plain absorbing ball as a control):
# raytile's integrators against Mitsuba 3's `volpath`, which renders each body as a
# dielectric around an absorbing medium. Not part of CI.
#
#   bash bench/immersed/run.sh [SCENE ...]
#
# Environment: RAYTILE (binary; default target/release/raytile), SPP (1024), SEEDS ("1 2 3 4"),
# INTEGRATORS ("path volpath bdpt sppm"; `whitted` is compared on lamp_in_glass_nofloor, the
# scene without diffuse interreflection), REF_SPP (8192) and REF_SEEDS (4) for the references,
# which are rendered once and kept in bench/out/immersed. Mitsuba comes from bench/.venv (see
# bench/README.md). Exit status 1 when a mean differs by more than 2 % or a 16 × 16-pixel block
# by more than 5 standard errors (sppm is consistent, not unbiased: near caustics its blocks
# may stray further at a finite number of iterations).
set -u
cd "$(dirname "$0")/../.."
RAYTILE=${RAYTILE:-target/release/raytile}
PY=${PY:-bench/.venv/bin/python}
SPP=${SPP:-1024}
SEEDS=${SEEDS:-"1 2 3 4"}
INTEGRATORS=${INTEGRATORS:-"path volpath bdpt sppm"}
OUT=bench/out/immersed
SCENES=${*:-"lamp_in_glass stone_in_water marble_in_liquid camera_outside_plain lamp_in_glass_nofloor"}
"$PY" bench/immersed/scenes.py || exit 1
for name in $SCENES; do
    if [ ! -f "$OUT/${name}_seeds.npy" ]; then
        "$PY" bench/immersed/scenes.py --refs --only "$name" --spp "${REF_SPP:-8192}" \
            --seeds "${REF_SEEDS:-4}" || exit 1
    fi
done
status=0
for name in $SCENES; do
    integrators=$INTEGRATORS
    [ "$name" = lamp_in_glass_nofloor ] && integrators="$INTEGRATORS whitted"
    for integ in $integrators; do
        exrs=()
        for seed in $SEEDS; do
            exr=$OUT/$name-$integ-s$seed.exr
            "$RAYTILE" render "$OUT/$name.json" -o "$exr" --width 64 --height 64 --spp "$SPP" \
                --max-depth 64 --seed "$seed" --integrator "$integ" --filter box --passes 1 \
                2> "$OUT/$name-$integ-s$seed.log" || { tail -5 "$OUT/$name-$integ-s$seed.log"; status=1; continue; }
            exrs+=("$exr")
        done
        echo "=== $name / $integ ($SPP spp, seeds $SEEDS)"
        "$PY" bench/immersed/compare.py "${exrs[@]}" "$name" || status=1
    done
done
exit $status
