"""Objects immersed in absorbing bodies: scenes written from one description both as raytile JSON and as a Mitsuba 3
scene dict (volpath; an absorbing dielectric = `dielectric` BSDF around a homogeneous medium
of albedo 0 and sigma_t = absorption; anything immersed names that medium as `exterior`).

    python scenes.py                 # writes NAME.json for every scene (in bench/out/immersed)
    python scenes.py --refs [--spp 1024] [--seeds 4] [--only NAME]   # + Mitsuba references

References: NAME_ref.npy (float32 HxWx3, mean of the seeds), NAME_seeds.npy (S x HxWx3, one
image per seed, for compare.py's noise estimate), NAME_ref.json (means, timing).
Everything is in world coordinates (no raytile transforms); units: metres, +Y up.
"""

import argparse
import json
import os
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
# Scenes, references and renders go here (bench/out is not kept in git).
OUT = os.path.join(os.path.dirname(HERE), "out", "immersed")
SIZE = 64
MAX_DEPTH = 64          # raytile bounces; Mitsuba max_depth = MAX_DEPTH + 1 (counts vertices)
FOV = 35.0

FLOOR = {"kind": "floor", "y": 0.0, "half": 2.0, "albedo": [0.6, 0.6, 0.6]}
QUAD = {"kind": "quad", "corner": [-0.5, 2.0, -0.5], "size": 1.0, "emission": [10.0, 10.0, 10.0]}


def scene_list():
    """name -> dict(camera, items). Item kinds: floor, quad (emitter facing down), sphere, box.
    sphere/box take mat: ('diffuse', albedo) | ('glass', ior_rel, absorption) |
    ('emitter', radiance); `body` names the absorbing body an item is immersed in; `ior_in`
    and `ior_out` give the absolute indices Mitsuba needs (raytile takes the relative one)."""
    cam = lambda pos, at: {"position": pos, "look_at": at, "fov": FOV}
    return {
        "lamp_in_glass": {
            "camera": cam([0.3, 1.2, 2.6], [0.0, 0.45, 0.0]),
            "items": [
                FLOOR,
                {"kind": "sphere", "name": "glass", "center": [0.0, 0.52, 0.0], "radius": 0.5,
                 "mat": ("glass", 1.5, [0.6, 1.5, 3.0]), "ior_in": 1.5, "ior_out": 1.0},
                {"kind": "sphere", "name": "lamp", "center": [0.15, 0.45, 0.05], "radius": 0.18,
                 "mat": ("emitter", [8.0, 8.0, 8.0]), "body": "glass"},
            ],
        },
        # No floor: every path is specular until it meets the lamp, so `whitted` (no diffuse
        # interreflection, no caustics) must match here too.
        "lamp_in_glass_nofloor": {
            "camera": cam([0.3, 1.2, 2.6], [0.0, 0.45, 0.0]),
            "items": [
                {"kind": "sphere", "name": "glass", "center": [0.0, 0.52, 0.0], "radius": 0.5,
                 "mat": ("glass", 1.5, [0.6, 1.5, 3.0]), "ior_in": 1.5, "ior_out": 1.0},
                {"kind": "sphere", "name": "lamp", "center": [0.15, 0.45, 0.05], "radius": 0.18,
                 "mat": ("emitter", [8.0, 8.0, 8.0]), "body": "glass"},
            ],
        },
        "stone_in_water": {
            "camera": cam([0.5, 1.3, 2.8], [0.0, 0.4, 0.0]),
            "items": [
                FLOOR, QUAD,
                {"kind": "box", "name": "water", "min": [-0.6, 0.02, -0.5], "max": [0.6, 0.82, 0.5],
                 "mat": ("glass", 1.33, [1.2, 0.5, 0.3]), "ior_in": 1.33, "ior_out": 1.0},
                {"kind": "sphere", "name": "stone", "center": [-0.15, 0.32, 0.05], "radius": 0.25,
                 "mat": ("diffuse", [0.8, 0.6, 0.3]), "body": "water"},
            ],
        },
        "marble_in_liquid": {
            "camera": cam([0.4, 1.3, 2.9], [0.0, 0.4, 0.0]),
            "items": [
                FLOOR, QUAD,
                {"kind": "box", "name": "liquid", "min": [-0.7, 0.02, -0.5], "max": [0.7, 0.82, 0.5],
                 "mat": ("glass", 1.33, [0.3, 0.9, 1.5]), "ior_in": 1.33, "ior_out": 1.0},
                {"kind": "sphere", "name": "marble", "center": [0.25, 0.3, 0.1], "radius": 0.22,
                 "mat": ("glass", 1.5 / 1.33, [0.0, 0.0, 0.0]), "ior_in": 1.5, "ior_out": 1.33,
                 "body": "liquid"},
                {"kind": "box", "name": "block", "min": [-0.5, 0.06, -0.3], "max": [-0.15, 0.4, 0.05],
                 "mat": ("diffuse", [0.2, 0.5, 0.8]), "body": "liquid"},
            ],
        },
        "camera_outside_plain": {
            "camera": cam([0.3, 1.2, 2.8], [0.0, 0.45, 0.0]),
            "items": [
                FLOOR, QUAD,
                {"kind": "sphere", "name": "glass", "center": [0.0, 0.52, 0.0], "radius": 0.5,
                 "mat": ("glass", 1.5, [0.4, 1.0, 1.6]), "ior_in": 1.5, "ior_out": 1.0},
                {"kind": "sphere", "name": "ball", "center": [0.85, 0.25, -0.3], "radius": 0.25,
                 "mat": ("diffuse", [0.7, 0.3, 0.3])},
            ],
        },
    }


# ------------------------------------------------------------------------------ raytile
def raytile_scene(s, media=False):
    """media=False: the absorbing bodies as dielectric `absorption` (the feature under test).
    media=True: NAME_media.json, the same scene for volpath as a medium: a clear dielectric
    around a homogeneous medium (sigma_a = absorption, sigma_s = 0) and `exterior` on
    immersed objects (an independent check of the references and of the mapping)."""
    mats, objs, mdict = {}, [], {}
    for it in s["items"]:
        k = it["kind"]
        if k == "floor":
            h, y = it["half"], it["y"]
            mats["floor"] = {"type": "diffuse", "albedo": it["albedo"]}
            # front = edge_u x edge_v = Z x X = +Y
            objs.append({"name": "floor", "shape": {"type": "rectangle", "corner": [-h, y, -h],
                         "edge_u": [0, 0, 2 * h], "edge_v": [2 * h, 0, 0]}, "material": "floor"})
            continue
        if k == "quad":
            c, e = it["corner"], it["size"]
            mats["lamp"] = {"type": "emitter", "emission": it["emission"]}
            # front = X x Z = -Y: faces down
            objs.append({"name": "quad_light", "shape": {"type": "rectangle", "corner": c,
                         "edge_u": [e, 0, 0], "edge_v": [0, 0, e]}, "material": "lamp"})
            continue
        name, m = it["name"], it["mat"]
        if m[0] == "diffuse":
            mats[name] = {"type": "diffuse", "albedo": m[1]}
        elif m[0] == "glass":
            mats[name] = {"type": "dielectric", "ior": round(m[1], 6), "absorption": m[2]}
            if media and max(m[2]) > 0:
                mats[name]["absorption"] = [0.0, 0.0, 0.0]
                mdict[name] = {"type": "homogeneous", "sigma_a": m[2], "sigma_s": [0.0, 0.0, 0.0]}
        elif m[0] == "emitter":
            mats[name] = {"type": "emitter", "emission": m[1]}
        if k == "sphere":
            shape = {"type": "sphere", "center": it["center"], "radius": it["radius"]}
        else:
            shape = {"type": "box", "min": it["min"], "max": it["max"]}
        obj = {"name": name, "shape": shape, "material": name}
        if media and name in mdict:
            obj["interior"] = name
        if media and it.get("body"):
            obj["exterior"] = it["body"]
        objs.append(obj)
    extra = {"media": mdict} if media else {}
    return extra | {
        "render": {"width": SIZE, "height": SIZE, "spp": 64, "max_depth": MAX_DEPTH,
                   "integrator": "volpath" if media else "path", "filter": "box"},
        "camera": s["camera"],
        "materials": mats,
        "objects": objs,
    }


# ------------------------------------------------------------------------------ Mitsuba
def mitsuba_dict(mi, s, spp=64, seed=0):
    T = mi.ScalarTransform4f
    rgb = lambda v: {"type": "rgb", "value": list(v)}
    black = {"type": "diffuse", "reflectance": rgb([0, 0, 0])}
    media = {}
    for it in s["items"]:
        if it.get("mat", ("",))[0] == "glass" and max(it["mat"][2]) > 0:
            a = it["mat"][2]
            top = max(a)  # rgb above 1 is refused: normalise, then `scale`
            media[it["name"]] = mi.load_dict({
                "type": "homogeneous", "albedo": rgb([0, 0, 0]),
                "sigma_t": rgb([v / top for v in a]), "scale": top})
    cam = s["camera"]
    d = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": MAX_DEPTH + 1, "rr_depth": 1000},
        "sensor": {
            "type": "perspective", "fov": cam["fov"], "fov_axis": "y", "near_clip": 1e-3,
            "to_world": T().look_at(origin=cam["position"], target=cam["look_at"], up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            "film": {"type": "hdrfilm", "width": SIZE, "height": SIZE,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        },
    }
    for i, it in enumerate(s["items"]):
        k = it["kind"]
        if k == "floor":
            h, y = it["half"], it["y"]
            # Mitsuba rectangle: [-1,1]^2 in z=0, normal +z; -90 deg about X -> normal +Y
            d["floor"] = {"type": "rectangle",
                          "to_world": T().translate([0, y, 0]) @ T().rotate([1, 0, 0], -90)
                          @ T().scale([h, h, 1]),
                          "bsdf": {"type": "diffuse", "reflectance": rgb(it["albedo"])}}
            continue
        if k == "quad":
            c, e = it["corner"], it["size"]
            centre = [c[0] + e / 2, c[1], c[2] + e / 2]
            d["quad_light"] = {"type": "rectangle",
                               "to_world": T().translate(centre) @ T().rotate([1, 0, 0], 90)
                               @ T().scale([e / 2, e / 2, 1]),
                               "bsdf": black,
                               "emitter": {"type": "area", "radiance": rgb(it["emission"])}}
            continue
        m = it["mat"]
        if k == "sphere":
            sh = {"type": "sphere", "center": it["center"], "radius": it["radius"]}
        else:
            lo, hi = np.array(it["min"]), np.array(it["max"])
            sh = {"type": "cube", "to_world": T().translate(list((lo + hi) / 2))
                  @ T().scale(list((hi - lo) / 2))}
        if m[0] == "diffuse":
            sh["bsdf"] = {"type": "diffuse", "reflectance": rgb(m[1])}
        elif m[0] == "emitter":
            sh["bsdf"] = black
            sh["emitter"] = {"type": "area", "radiance": rgb(m[1])}
        elif m[0] == "glass":
            sh["bsdf"] = {"type": "dielectric", "int_ior": it["ior_in"], "ext_ior": it["ior_out"]}
            if it["name"] in media:
                sh["interior"] = media[it["name"]]
        if it.get("body"):
            sh["exterior"] = media[it["body"]]
        d[it["name"]] = sh
    return d


def render_refs(name, s, spp, seeds, threads):
    import drjit as dr
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    dr.set_thread_count(threads)
    imgs, t0 = [], time.time()
    for k in range(seeds):
        seed = 1000 + k
        scene = mi.load_dict(mitsuba_dict(mi, s, spp, seed))
        imgs.append(np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float32)[:, :, :3])
        print(f"  {name} seed {seed}: mean {imgs[-1].reshape(-1, 3).mean(0)}  "
              f"({time.time() - t0:.0f} s)", flush=True)
    imgs = np.stack(imgs)
    mean = imgs.mean(0).astype(np.float32)
    np.save(os.path.join(OUT, f"{name}_ref.npy"), mean)
    np.save(os.path.join(OUT, f"{name}_seeds.npy"), imgs)
    m = mean.reshape(-1, 3).mean(0)
    se = imgs.reshape(seeds, -1, 3).mean(1).std(0, ddof=1) / np.sqrt(seeds)
    info = {"scene": name, "variant": "scalar_rgb", "integrator": "volpath",
            "max_depth": MAX_DEPTH + 1, "spp_per_seed": spp, "seeds": seeds,
            "size": SIZE, "mean": m.tolist(), "mean_se_from_seeds": se.tolist(),
            "seconds": time.time() - t0, "mitsuba": mi.__version__}
    with open(os.path.join(OUT, f"{name}_ref.json"), "w") as f:
        json.dump(info, f, indent=1)
    print(f"{name}: mean {np.round(m, 5)}  se {np.round(se, 6)}  rel se "
          f"{np.round(se / np.maximum(m, 1e-12) * 100, 3)} %", flush=True)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--refs", action="store_true")
    p.add_argument("--spp", type=int, default=1024)
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--only", nargs="*")
    a = p.parse_args()
    os.makedirs(OUT, exist_ok=True)
    for name, s in scene_list().items():
        if a.only and name not in a.only:
            continue
        with open(os.path.join(OUT, f"{name}.json"), "w") as f:
            json.dump(raytile_scene(s), f, indent=1)
        with open(os.path.join(OUT, f"{name}_media.json"), "w") as f:
            json.dump(raytile_scene(s, media=True), f, indent=1)
        if a.refs:
            render_refs(name, s, a.spp, a.seeds, a.threads)


if __name__ == "__main__":
    main()
