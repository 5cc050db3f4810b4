"""Render a glTF scene with Mitsuba 3, from a scene built from the glTF data itself.

    python bench/mitsuba_render.py SCENE.gltf --variant llvm_ad_rgb --spp 64 \
        --threads 2 --seed 0 --out OUT.exr --work DIR

Writes OUT.exr (linear RGB float) and prints `BENCH_JSON {...}` on stdout:
{name, exr, "renderer", "variant", "spp", "threads", "seconds", "warmup_seconds", "mean"}.
`seconds` is the render only: the scene is loaded first, and for JIT variants a
1-spp render compiles the kernels before the timed one (`warmup_seconds`).
Large sample counts are split into passes of at most --max-spp-per-pass, each with
its own seed, averaged with equal weights (for the high-spp reference).
"""

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import gltf_scene  # noqa: E402

# glTF cameras look down local -Z with +X right; Mitsuba's look down +Z with +X left.
GLTF_TO_MITSUBA_CAMERA = np.diag([-1.0, 1.0, -1.0, 1.0])


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scene")
    p.add_argument("--variant", default="llvm_ad_rgb")
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--threads", type=int, default=os.cpu_count())
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=256)
    p.add_argument("--height", type=int, default=256)
    p.add_argument("--max-spp-per-pass", type=int, default=256)
    p.add_argument("--out", required=True)
    p.add_argument("--name", default="mitsuba", help="row name in the results table")
    p.add_argument("--work", required=True, help="folder for the generated PLY meshes")
    p.add_argument("--builtin-cornell", action="store_true",
                   help="cross-check: render mitsuba.cornell_box() (not the glTF) with the same "
                        "settings; its light's BSDF made black like the glTF's")
    return p.parse_args()


def write_meshes(scene, work_dir):
    """One PLY per glTF primitive, in world space; returns [(path, mesh)]."""
    os.makedirs(work_dir, exist_ok=True)
    out = []
    for mesh in scene.meshes:
        gltf_scene.check_winding(mesh)
        path = os.path.join(work_dir, f"{mesh.name}.ply")
        gltf_scene.write_ply(mesh, path)
        out.append((path, mesh))
    return out


def bsdf_dict(material):
    """glTF materials here are pure Lambert (specularFactor 0): a `diffuse` BSDF."""
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(material.base_color)}}


def shape_dict(path, mesh):
    shape = {"type": "ply", "filename": path, "bsdf": bsdf_dict(mesh.material)}
    if mesh.normals is None:
        # glTF without NORMAL means flat shading; Mitsuba would compute smooth vertex normals.
        shape["face_normals"] = True
    if any(c > 0 for c in mesh.material.emission):
        # Mitsuba's area emitter is one-sided: it emits on the side the normal faces,
        # which is the counter-clockwise (glTF front) side, as check_winding verified.
        shape["emitter"] = {"type": "area",
                            "radiance": {"type": "rgb", "value": list(mesh.material.emission)}}
    return shape


def sensor_dict(camera, args):
    import mitsuba as mi
    to_world = camera.to_world @ GLTF_TO_MITSUBA_CAMERA
    return {
        "type": "perspective",
        "fov": gltf_scene.yfov_degrees(camera),
        "fov_axis": "y",
        "near_clip": 0.001,
        "to_world": mi.ScalarTransform4f(to_world.tolist()),
        "sampler": {"type": "independent", "sample_count": args.spp, "seed": args.seed},
        "film": {"type": "hdrfilm", "width": args.width, "height": args.height,
                 "pixel_format": "rgb", "rfilter": {"type": "box"}},
    }


def scene_dict(gltf, meshes, args):
    d = {"type": "scene",
         "integrator": {"type": "path", "max_depth": -1},
         "sensor": sensor_dict(gltf.camera, args)}
    for path, mesh in meshes:
        d[mesh.name] = shape_dict(path, mesh)
    return d


def builtin_cornell_dict(gltf, args):
    """Mitsuba's own Cornell box, which the glTF scene replicates, with our settings."""
    import mitsuba as mi
    d = mi.cornell_box()
    d["integrator"] = {"type": "path", "max_depth": -1}
    d["sensor"] = sensor_dict(gltf.camera, args)
    d["light"]["bsdf"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0, 0, 0]}}
    return d


def render_passes(mi, scene, spp, seed, max_per_pass):
    """Average of ceil(spp / max_per_pass) renders with distinct seeds, as numpy."""
    total, done, k = None, 0, 0
    while done < spp:
        n = min(max_per_pass, spp - done)
        img = np.array(mi.render(scene, spp=n, seed=seed + k), dtype=np.float64)
        total = img * n if total is None else total + img * n
        done, k = done + n, k + 1
    return (total / spp).astype(np.float32)


def main():
    args = parse_args()
    import drjit as dr
    import mitsuba as mi
    mi.set_variant(args.variant)
    dr.set_thread_count(args.threads)
    gltf = gltf_scene.load(args.scene)
    if args.builtin_cornell:
        scene = mi.load_dict(builtin_cornell_dict(gltf, args))
    else:
        scene = mi.load_dict(scene_dict(gltf, write_meshes(gltf, args.work), args))
    warmup = 0.0
    if args.variant.startswith(("llvm", "cuda")):
        start = time.perf_counter()
        render_passes(mi, scene, 1, args.seed + 10_000, 1)  # compile the kernels
        warmup = time.perf_counter() - start
    start = time.perf_counter()
    img = render_passes(mi, scene, args.spp, args.seed, args.max_spp_per_pass)
    seconds = time.perf_counter() - start
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    mi.Bitmap(img).write(args.out)
    print("BENCH_JSON " + json.dumps({"name": args.name, "exr": args.out,
                      "renderer": "mitsuba", "builtin_cornell": args.builtin_cornell,
                      "variant": args.variant, "version": mi.__version__, "spp": args.spp,
                      "threads": dr.thread_count(), "seconds": seconds,
                      "warmup_seconds": warmup,
                      "mean": [float(x) for x in img.reshape(-1, 3).mean(axis=0)]}), flush=True)


if __name__ == "__main__":
    main()
