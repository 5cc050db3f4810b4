#!/usr/bin/env bash
# Equal-time caustic comparison of the path, bdpt and sppm integrators.
#
#   bash bench/caustic-compare.sh [--seconds T] [--ref-spp N] [--threads N] [--scene FILE]
#
# Renders a reference (bdpt, REF_SPP samples per pixel, seed REF_SEED; cached under
# target/bench-reference, keyed by the scene's hash, the binary's hash and the settings),
# measures each integrator's samples/s with a short run, renders path, bdpt and sppm with the
# sample count that fills T render seconds (rescaled and rendered again, up to 3 times, until
# the time is within 10 % of T) (sppm with --passes 1) and prints, for each, the
# samples per pixel, the render seconds, the RMSE over the caustic region and over the image
# against the reference, and the ratios of path's RMSE to bdpt's and sppm's.
#
# Caustic region: the 13x13 pixels whose mean in the reference is the highest among all
# 13x13 windows lying wholly on floor pixels (those with the floor's colour in the `albedo`
# integrator's image, taken at the image's bottom centre).
#
# Settings from the environment: SECONDS_TARGET (1), REF_SPP (1024), REF_SEED (1000000),
# SEED (0), THREADS (2), WIDTH (160), HEIGHT (120), SCENE (scenes/caustic.json),
# RAYTILE_BIN (default target/release/raytile if present, else target/debug/raytile).
# Python: bench/.venv/bin/python if it has numpy, else a python3 with numpy (apt python3-numpy
# is installed if none has it).
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

SECONDS_TARGET=${SECONDS_TARGET:-1}
REF_SPP=${REF_SPP:-1024}
REF_SEED=${REF_SEED:-1000000}
SEED=${SEED:-0}
THREADS=${THREADS:-2}
WIDTH=${WIDTH:-160}
HEIGHT=${HEIGHT:-120}
SCENE=${SCENE:-scenes/caustic.json}
WINDOW=13
COMMAND="bash bench/caustic-compare.sh${*:+ $*}"

while [ $# -gt 0 ]; do
    case "$1" in
        --seconds) SECONDS_TARGET=$2; shift 2 ;;
        --ref-spp) REF_SPP=$2; shift 2 ;;
        --threads) THREADS=$2; shift 2 ;;
        --scene) SCENE=$2; shift 2 ;;
        -h|--help) sed -n '2,22p' "$0"; exit 0 ;;
        *) echo "caustic-compare.sh: unknown argument '$1' (try --help)" >&2; exit 2 ;;
    esac
done

if [ -z "${RAYTILE_BIN:-}" ]; then
    if [ -x target/release/raytile ]; then RAYTILE_BIN=target/release/raytile
    else RAYTILE_BIN=target/debug/raytile; fi
fi
[ -x "$RAYTILE_BIN" ] || { echo "caustic-compare.sh: no binary at $RAYTILE_BIN (set RAYTILE_BIN)" >&2; exit 2; }
[ -f "$SCENE" ] || { echo "caustic-compare.sh: no scene at $SCENE" >&2; exit 2; }

PY=
for candidate in "$ROOT/bench/.venv/bin/python" python3 /usr/bin/python3; do
    if command -v "$candidate" > /dev/null && "$candidate" -c "import numpy" 2> /dev/null; then
        PY=$candidate; break
    fi
done
if [ -z "$PY" ]; then
    sudo=; [ "$(id -u)" -eq 0 ] || sudo=sudo
    echo "caustic-compare.sh: apt-get install python3-numpy" >&2
    $sudo apt-get update -qq > /dev/null
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq python3-numpy > /dev/null
    PY=/usr/bin/python3
fi

OUT=$ROOT/bench/out/caustic
REF_DIR=${REF_DIR:-$ROOT/target/bench-reference}
mkdir -p "$OUT" "$REF_DIR"

# render INTEGRATOR SPP SEED OUTPUT [extra flags]: prints the render seconds raytile reports.
render() {
    local integrator=$1 spp=$2 seed=$3 output=$4 log
    shift 4
    log=$("$RAYTILE_BIN" render "$SCENE" -o "$output" --width "$WIDTH" --height "$HEIGHT" \
        --spp "$spp" --integrator "$integrator" --seed "$seed" --threads "$THREADS" "$@" 2>&1) \
        || { echo "$log" >&2; echo "caustic-compare.sh: $integrator render failed" >&2; exit 1; }
    echo "$log" | sed -n 's/.* \([0-9.]*\) s render.*/\1/p' | tail -n 1
}

# The reference's key: the scene, the settings and the bits of a 1-spp bdpt image (another
# binary that renders bdpt identically reuses the reference; one that does not, renders anew).
render bdpt 1 "$REF_SEED" "$OUT/key-probe.hdr" > /dev/null
key=$( (sha256sum < "$SCENE"; sha256sum < "$OUT/key-probe.hdr";
        echo "bdpt $WIDTH $HEIGHT $REF_SPP $REF_SEED") | sha256sum | cut -c1-16)
REF=$REF_DIR/caustic-$key.hdr
if [ -f "$REF" ]; then
    echo "reference: $REF (cached)"
else
    echo "reference: bdpt, $REF_SPP spp, seed $REF_SEED -> $REF (rendering)"
    secs=$(render bdpt "$REF_SPP" "$REF_SEED" "$REF.tmp.hdr")
    mv "$REF.tmp.hdr" "$REF"
    echo "reference: ${secs} s"
fi
ALBEDO=$REF_DIR/caustic-$key-albedo.hdr
[ -f "$ALBEDO" ] || render albedo 1 0 "$ALBEDO" > /dev/null

if ! "$RAYTILE_BIN" render "$SCENE" -o "$OUT/sppm-check.hdr" --width 8 --height 6 --spp 1 \
    --integrator sppm --passes 1 > /dev/null 2>&1; then
    echo "caustic-compare.sh: $RAYTILE_BIN has no sppm integrator (rebuild it)" >&2; exit 2
fi

# Samples/s of each integrator from a short run, then the spp that fills SECONDS_TARGET.
ROWS=$OUT/rows.txt
: > "$ROWS"
for spec in "path 16" "bdpt 4" "sppm 4"; do
    set -- $spec
    integrator=$1 probe_spp=$2
    extra=(); [ "$integrator" = sppm ] && extra=(--passes 1)
    probe_secs=$(render "$integrator" "$probe_spp" "$SEED" "$OUT/probe-$integrator.hdr" "${extra[@]}")
    echo "$integrator: probe $probe_spp spp in $probe_secs s"
    # Scale the spp by the last run's time and render; again (3 renders at most) while the
    # time is more than 10 % off the target: a render's fixed cost skews the short probe.
    spp=$probe_spp secs=$probe_secs
    for _ in 1 2 3; do
        spp=$("$PY" -c "import sys; t, n, s = float(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]); print(max(1, round(t * n / max(s, 1e-3))))" \
            "$SECONDS_TARGET" "$spp" "$secs")
        secs=$(render "$integrator" "$spp" "$SEED" "$OUT/$integrator.hdr" "${extra[@]}")
        echo "$integrator: $spp spp in $secs s"
        "$PY" -c "import sys; sys.exit(abs(float(sys.argv[2]) / float(sys.argv[1]) - 1) > 0.1)" \
            "$SECONDS_TARGET" "$secs" && break
    done
    echo "$integrator $spp $secs $OUT/$integrator.hdr" >> "$ROWS"
done

"$PY" - "$REF" "$ALBEDO" "$ROWS" "$WINDOW" <<'PYEOF'
import sys
import numpy as np


def read_hdr(path):
    """Radiance RGBE (flat or new-style run-length scanlines) as float64 H x W x 3."""
    data = open(path, "rb").read()
    pos = 0
    while True:  # header up to the blank line
        end = data.index(b"\n", pos)
        line = data[pos:end]
        pos = end + 1
        if line == b"":
            break
    end = data.index(b"\n", pos)
    dims = data[pos:end].split()
    pos = end + 1
    if dims[0] != b"-Y" or dims[2] != b"+X":
        raise ValueError(f"{path}: unsupported orientation {dims}")
    h, w = int(dims[1]), int(dims[3])
    out = np.zeros((h, w, 4), dtype=np.uint8)
    for y in range(h):
        if w >= 8 and w < 32768 and data[pos] == 2 and data[pos + 1] == 2 and data[pos + 2] < 128:
            pos += 4
            for c in range(4):
                x = 0
                while x < w:
                    n = data[pos]
                    pos += 1
                    if n > 128:
                        n -= 128
                        out[y, x:x + n, c] = data[pos]
                        pos += 1
                    else:
                        out[y, x:x + n, c] = np.frombuffer(data[pos:pos + n], dtype=np.uint8)
                        pos += n
                    x += n
        else:
            out[y] = np.frombuffer(data[pos:pos + 4 * w], dtype=np.uint8).reshape(w, 4)
            pos += 4 * w
    e = out[:, :, 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)
    return out[:, :, :3].astype(np.float64) * scale[:, :, None]


ref_path, albedo_path, rows_path, window = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
ref = read_hdr(ref_path)
albedo = read_hdr(albedo_path)
# Floor pixels: the colour of the bottom centre pixel (the floor) in the albedo image.
floor = np.all(np.abs(albedo - albedo[-1, albedo.shape[1] // 2]) < 0.02, axis=2)
lum = ref.mean(axis=2)
h, w = lum.shape
best, region = -1.0, None
for y in range(h - window + 1):
    for x in range(w - window + 1):
        if floor[y:y + window, x:x + window].all():
            m = lum[y:y + window, x:x + window].mean()
            if m > best:
                best, region = m, (y, x)
y0, x0 = region
floor_median = float(np.median(lum[floor]))
print(f"caustic region: {window}x{window} pixels at x {x0}..{x0 + window - 1}, "
      f"y {y0}..{y0 + window - 1}; reference mean there {best:.3g}, "
      f"{best / floor_median:.1f}x the floor's median {floor_median:.3g}")

rows = []
for line in open(rows_path):
    name, spp, secs, path = line.split()
    img = read_hdr(path)
    diff = img - ref
    rows.append({"name": name, "spp": int(spp), "secs": float(secs),
                 "caustic": float(np.sqrt(np.mean(diff[y0:y0 + window, x0:x0 + window] ** 2))),
                 "image": float(np.sqrt(np.mean(diff ** 2))),
                 "bias": float(diff[y0:y0 + window, x0:x0 + window].mean())})
base = next(r for r in rows if r["name"] == "path")
print()
print("| integrator | spp | render s | RMSE caustic | RMSE image | mean error caustic "
      "| path/this RMSE caustic | path/this RMSE image | path/this MSE x s, caustic |")
print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
for r in rows:
    eff = (base["caustic"] ** 2 * base["secs"]) / (r["caustic"] ** 2 * r["secs"])
    print(f"| `{r['name']}` | {r['spp']} | {r['secs']:.2f} | {r['caustic']:.3g} | {r['image']:.3g} "
          f"| {r['bias']:+.3g} | {base['caustic'] / r['caustic']:.1f}x "
          f"| {base['image'] / r['image']:.1f}x | {eff:.1f}x |")
PYEOF
echo
echo "binary: $RAYTILE_BIN; scene: $SCENE, ${WIDTH}x${HEIGHT}, --threads $THREADS, seed $SEED;" \
    "reference bdpt $REF_SPP spp seed $REF_SEED; target ${SECONDS_TARGET} s per integrator"
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//'), $(nproc) cores;" \
    "$(date -u +%Y-%m-%d); load average $(cut -d' ' -f1-3 /proc/loadavg)"
echo "command: $COMMAND"
