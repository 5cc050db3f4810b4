"""Compare raytile's `volpath` with Mitsuba 3's `volpath` on participating media.

    python bench/media-compare.py [--raytile target/release/raytile] [--spp 256] [--size 64]

Four scenes, written by this script in both formats (bench/out/media/): a homogeneous
chromatic, forward-scattering sphere and a heterogeneous grid (a .vol file both renderers
read) in a box, each inside a `null`/`interface` boundary under a uniform sky of radiance 1
and a small area light; a chromatic sphere lit by the area light alone; and a ball of
coloured glass (a dielectric boundary around a medium that only absorbs) under the sky and
the light. Each renderer renders each scene twice (seeds 1 and 2). Reported per
scene and channel: the image means and their relative difference (must be within 2 %), and
for every 32×32-pixel block the difference of the block means in standard errors (the noise
of a block mean is measured from the per-pixel differences of the two seeds, so the picture's
own variation does not count). Exit status 1 when a mean differs by more than 2 % or a block
by more than 5 standard errors. Mitsuba runs in `scalar_rgb` (pip `mitsuba`, nothing else
needed). Not part of CI.
"""

import argparse
import json
import os
import struct
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
OUT = os.path.join(HERE, "out", "media")

CAMERA = {"position": [0.0, 0.3, 3.2], "look_at": [0.0, 0.0, 0.0], "fov": 40.0}
LIGHT = {"corner": [-0.5, 2.0, -0.5], "size": 1.0, "emission": [6.0, 6.0, 6.0]}

# name -> (raytile medium, Mitsuba medium, boundary shape)
def scenes():
    return {
        "sphere": {
            "medium": {"sigma_t": [2.0, 4.0, 6.0], "albedo": [0.9, 0.7, 0.5], "g": 0.6},
            "grid": None,
            "sky": True,
        },
        # Lit by the lamp alone: every pixel's light comes through next-event estimation and
        # the phase-sampled paths that find the lamp.
        "sphere-lamp": {
            "medium": {"sigma_t": [1.0, 2.5, 5.0], "albedo": [0.95, 0.8, 0.6], "g": 0.3},
            "grid": None,
            "sky": False,
        },
        "grid": {
            "medium": {"sigma_t": [8.0, 8.0, 8.0], "albedo": [0.8, 0.8, 0.8], "g": 0.2},
            "grid": 24,
            "sky": True,
        },
        # Coloured glass: a dielectric boundary (index 1.5) around a medium that only absorbs,
        # so the light inside is refracted, reflected within and attenuated by Beer's law.
        "glass": {
            "medium": {"sigma_t": [0.4, 1.2, 3.0], "albedo": [0.0, 0.0, 0.0], "g": 0.0},
            "grid": None,
            "sky": True,
            "glass": True,
        },
    }


def write_vol(path, n):
    """An n³ smoke-like density over the unit box, zero on the border voxels."""
    idx = (np.arange(n) + 0.5) / n
    z, y, x = np.meshgrid(idx, idx, idx, indexing="ij")
    r = np.sqrt((x - 0.5) ** 2 + (y - 0.5) ** 2 + (z - 0.5) ** 2)
    d = np.clip(1.0 - r / 0.45, 0.0, 1.0) * (0.6 + 0.4 * np.sin(9 * x) * np.cos(7 * y + 3 * z))
    d = np.clip(d, 0.0, None).astype(np.float32)
    d[0, :, :] = d[-1, :, :] = d[:, 0, :] = d[:, -1, :] = d[:, :, 0] = d[:, :, -1] = 0.0
    with open(path, "wb") as f:
        f.write(b"VOL" + bytes([3]))
        f.write(struct.pack("<5i", 1, n, n, n, 1))
        f.write(struct.pack("<6f", 0, 0, 0, 1, 1, 1))
        f.write(d.tobytes())  # x fastest: d[z, y, x]


def raytile_scene(name, s, vol):
    m = s["medium"]
    st, al = np.array(m["sigma_t"]), np.array(m["albedo"])
    medium = {"sigma_a": list(st * (1 - al)), "sigma_s": list(st * al), "g": m["g"]}
    if vol:
        medium.update({"type": "grid", "path": os.path.basename(vol)})
        shape = {"type": "box", "min": [0, 0, 0], "max": [1, 1, 1]}
        transform = {"scale": 1.6, "translate": [-0.8, -0.8, -0.8]}
    else:
        medium["type"] = "homogeneous"
        shape = {"type": "sphere", "radius": 1.0}
        transform = {"scale": 0.8}
    c, e = LIGHT["corner"], LIGHT["size"]
    sky = {"environment": {"type": "constant", "radiance": [1, 1, 1]}} if s["sky"] else {}
    return sky | {
        "camera": CAMERA,
        "media": {"m": medium},
        "materials": {"b": {"type": "glass", "ior": 1.5} if s.get("glass") else {"type": "interface"},
                      "lamp": {"type": "emitter", "emission": LIGHT["emission"]}},
        "objects": [
            {"shape": shape, "material": "b", "interior": "m", "transform": transform},
            {"shape": {"type": "rectangle", "corner": c, "edge_u": [e, 0, 0], "edge_v": [0, 0, e]},
             "material": "lamp"},
        ],
    }


def mitsuba_scene(mi, s, vol, size, spp, seed, depth):
    T = mi.ScalarTransform4f
    m = s["medium"]
    phase = {"type": "hg", "g": m["g"]}
    if vol:
        to_world = T().translate([-0.8, -0.8, -0.8]) @ T().scale(1.6)
        medium = {
            "type": "heterogeneous",
            "albedo": {"type": "rgb", "value": m["albedo"]},
            "sigma_t": {"type": "gridvolume", "filename": vol, "to_world": to_world,
                        "filter_type": "trilinear"},
            "scale": m["sigma_t"][0],
            "phase": phase,
        }
        shape = {"type": "cube",
                 "to_world": to_world @ T().translate([0.5, 0.5, 0.5]) @ T().scale(0.5)}
    else:
        # RGB values above 1 are refused as reflectances: normalise, and scale back.
        top = max(m["sigma_t"])
        medium = {
            "type": "homogeneous",
            "albedo": {"type": "rgb", "value": m["albedo"]},
            "sigma_t": {"type": "rgb", "value": [v / top for v in m["sigma_t"]]},
            "scale": top,
            "phase": phase,
        }
        shape = {"type": "sphere", "radius": 0.8}
    # Both indices given: Mitsuba's defaults are BK7 (1.5046) inside and air (1.000277) outside.
    bsdf = ({"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0} if s.get("glass")
            else {"type": "null"})
    shape.update({"bsdf": bsdf, "interior": medium})
    c, e = LIGHT["corner"], LIGHT["size"]
    centre = [c[0] + e / 2, c[1], c[2] + e / 2]
    # Mitsuba's rectangle is [-1, 1]² in z = 0 facing +z: turn it to face down.
    lamp_tf = T().translate(centre) @ T().rotate([1, 0, 0], 90) @ T().scale([e / 2, e / 2, 1])
    sky = {"sky": {"type": "constant", "radiance": {"type": "rgb", "value": [1, 1, 1]}}}
    return mi.load_dict((sky if s["sky"] else {}) | {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": depth + 1, "rr_depth": 1000},
        "sensor": {
            "type": "perspective", "fov": CAMERA["fov"], "fov_axis": "y",
            "to_world": T().look_at(origin=CAMERA["position"], target=CAMERA["look_at"], up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
        },
        "medium_shape": shape,
        "lamp": {"type": "rectangle", "to_world": lamp_tf,
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": LIGHT["emission"]}}},
    })


def read_exr(mi, path):
    return np.array(mi.Bitmap(path), dtype=np.float64)[:, :, :3]


def block_z(a1, a2, b1, b2, block):
    """Per block and channel: (mean a − mean b) / standard error, noise from seed pairs."""
    h, w, _ = a1.shape
    zs = []
    for y in range(0, h, block):
        for x in range(0, w, block):
            sl = (slice(y, y + block), slice(x, x + block))
            n = a1[sl].shape[0] * a1[sl].shape[1]
            ma = (a1[sl] + a2[sl]).reshape(-1, 3).mean(0) / 2
            mb = (b1[sl] + b2[sl]).reshape(-1, 3).mean(0) / 2
            # var of one render's pixel = var(p1 − p2)/2; of the two-seed block mean: /(2n).
            va = (a1[sl] - a2[sl]).reshape(-1, 3).var(0) / 2 / (2 * n)
            vb = (b1[sl] - b2[sl]).reshape(-1, 3).var(0) / 2 / (2 * n)
            zs.append((ma - mb) / np.sqrt(va + vb + 1e-20))
    return np.array(zs)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--raytile", default=os.path.join(ROOT, "target", "release", "raytile"))
    p.add_argument("--spp", type=int, default=256)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--depth", type=int, default=64)
    p.add_argument("--only", help="render only this scene")
    a = p.parse_args()
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    os.makedirs(OUT, exist_ok=True)
    failed = False
    for name, s in scenes().items():
        if a.only and name != a.only:
            continue
        vol = None
        if s["grid"]:
            vol = os.path.join(OUT, f"{name}.vol")
            write_vol(vol, s["grid"])
        scene_path = os.path.join(OUT, f"{name}.json")
        with open(scene_path, "w") as f:
            json.dump(raytile_scene(name, s, vol), f, indent=1)
        rt, mt = [], []
        for seed in (1, 2):
            exr = os.path.join(OUT, f"{name}-raytile-{seed}.exr")
            subprocess.run([a.raytile, "render", scene_path, "-o", exr, "--width", str(a.size),
                            "--height", str(a.size), "--spp", str(a.spp), "--seed", str(seed),
                            "--max-depth", str(a.depth), "--integrator", "volpath"],
                           check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            rt.append(read_exr(mi, exr))
            img = mi.render(mitsuba_scene(mi, s, vol, a.size, a.spp, seed, a.depth), spp=a.spp, seed=seed)
            mexr = os.path.join(OUT, f"{name}-mitsuba-{seed}.exr")
            mi.Bitmap(img).write(mexr)
            mt.append(read_exr(mi, mexr))
        mr = (rt[0] + rt[1]).reshape(-1, 3).mean(0) / 2
        mm = (mt[0] + mt[1]).reshape(-1, 3).mean(0) / 2
        rel = (mr - mm) / mm
        z = block_z(rt[0], rt[1], mt[0], mt[1], 32)
        bad = np.abs(rel).max() > 0.02 or np.abs(z).max() > 5
        failed |= bad
        print(f"{name}: raytile mean {np.round(mr, 5)}, mitsuba mean {np.round(mm, 5)}, "
              f"relative difference {np.round(rel * 100, 3)} %; "
              f"32-px blocks: max |z| {np.abs(z).max():.2f} over {z.size} block-channels"
              + ("  FAIL" if bad else ""))
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
