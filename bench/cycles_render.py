"""Render a glTF scene with Blender Cycles, set up to match an unbiased Lambert path tracer.

    PYTHONPATH=/usr/lib/python3/dist-packages blender -b --factory-startup \
        --python bench/cycles_render.py -- SCENE.gltf --spp 64 --threads 2 --seed 0 --out OUT.exr

Imports the glTF with Blender's own importer, then:
- replaces every material by a Diffuse BSDF (roughness 0 = Lambert) of its base colour,
  plus, where the material emits, an Emission of its colour x strength on the FRONT face
  only (Geometry "Backfacing" mixes it with the bare diffuse): Cycles' emission is
  two-sided otherwise. Blender 3.4's importer copies emissiveFactor into the Emission
  colour and KHR_materials_emissive_strength into Emission Strength unchanged (its
  lighting-mode option applies to punctual lights only; we pass 'RAW' anyway), and a mesh
  Emission of strength 1 is radiance 1, so the radiance equals the glTF's;
- black world, box pixel filter 1 px wide, no clamping, no adaptive sampling, no
  denoising, 64 bounces of every kind, light threshold 0, fixed seed and thread count;
- renders once at 1 spp (device and kernel start-up), then times the real render only.
Writes OUT.exr (32-bit float, linear) and prints two `BENCH_JSON {...}` lines on stdout: the
sampling time alone (row "cycles"), and the whole render call with the scene sync and BVH build.
"""

import argparse
import ctypes
import json
import os
import re
import sys
import tempfile
import time

import numpy

if not hasattr(numpy, "bool"):
    numpy.bool = bool  # Blender 3.4's glTF importer uses the alias numpy 1.24 removed

import bpy  # noqa: E402

BOUNCES = 64


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="cycles_render.py")
    p.add_argument("scene")
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=256)
    p.add_argument("--height", type=int, default=256)
    p.add_argument("--out", required=True)
    p.add_argument("--name", default="cycles", help="row name in the results table")
    return p.parse_args(argv)


def import_gltf(path):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    options = {"filepath": path}
    if "convert_lighting_mode" in bpy.ops.import_scene.gltf.get_rna_type().properties:
        options["convert_lighting_mode"] = "RAW"
    bpy.ops.import_scene.gltf(**options)


def principled_inputs(material):
    """(base colour, emission colour x strength) of the importer's Principled BSDF."""
    nodes = material.node_tree.nodes
    bsdf = next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None:
        raise RuntimeError(f"material {material.name}: no Principled BSDF from the importer")
    for name in ("Base Color", "Emission", "Emission Strength"):
        if bsdf.inputs[name].is_linked:
            raise RuntimeError(f"material {material.name}: '{name}' is textured; unsupported")
    base = tuple(bsdf.inputs["Base Color"].default_value[:3])
    strength = bsdf.inputs["Emission Strength"].default_value
    emission = tuple(c * strength for c in bsdf.inputs["Emission"].default_value[:3])
    return base, emission


def make_lambert(material):
    """Rebuild the node tree: Diffuse BSDF, plus one-sided emission where it emits."""
    base, emission = principled_inputs(material)
    tree = material.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = base + (1.0,)
    diffuse.inputs["Roughness"].default_value = 0.0
    shader = diffuse.outputs["BSDF"]
    if max(emission) > 0:
        emit = tree.nodes.new("ShaderNodeEmission")
        emit.inputs["Color"].default_value = emission + (1.0,)
        emit.inputs["Strength"].default_value = 1.0
        front = tree.nodes.new("ShaderNodeAddShader")
        tree.links.new(diffuse.outputs["BSDF"], front.inputs[0])
        tree.links.new(emit.outputs["Emission"], front.inputs[1])
        geometry = tree.nodes.new("ShaderNodeNewGeometry")
        mix = tree.nodes.new("ShaderNodeMixShader")  # Fac 0 -> input 1, Fac 1 -> input 2
        tree.links.new(geometry.outputs["Backfacing"], mix.inputs["Fac"])
        tree.links.new(front.outputs["Shader"], mix.inputs[1])
        tree.links.new(diffuse.outputs["BSDF"], mix.inputs[2])
        shader = mix.outputs["Shader"]
    tree.links.new(shader, out.inputs["Surface"])
    return base, emission


def black_world(scene):
    world = scene.world or bpy.data.worlds.new("black")
    scene.world = world
    world.use_nodes = True
    background = world.node_tree.nodes.get("Background")
    background.inputs["Color"].default_value = (0, 0, 0, 1)
    background.inputs["Strength"].default_value = 0.0


def configure_cycles(scene, args):
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = args.spp
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = args.seed
    c.use_animated_seed = False
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0  # one pixel: a sample only counts in its own pixel
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    c.blur_glossy = 0.0
    c.caustics_reflective = c.caustics_refractive = True
    c.max_bounces = c.diffuse_bounces = c.glossy_bounces = BOUNCES
    c.transmission_bounces = c.volume_bounces = c.transparent_max_bounces = BOUNCES
    if hasattr(c, "use_light_tree"):
        c.use_light_tree = False
    r = scene.render
    r.threads_mode = "FIXED"
    r.threads = args.threads
    r.resolution_x, r.resolution_y, r.resolution_percentage = args.width, args.height, 100
    r.film_transparent = False
    r.use_compositing = r.use_sequencer = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    settings = r.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_mode = "RGB"
    settings.color_depth = "32"
    settings.exr_codec = "ZIP"


def use_gltf_camera(scene):
    cameras = [o for o in scene.objects if o.type == "CAMERA"]
    if not cameras:
        raise RuntimeError("the glTF has no camera")
    scene.camera = cameras[0]
    return cameras[0]


STATS_TIME = re.compile(r"\| Time:(?:(\d+):)?(\d+):(\d+(?:\.\d+)?) \|")


def stats_seconds(line):
    """Cycles' own clock on a render statistics line (`Time:MM:SS.ss`, hours if any)."""
    m = STATS_TIME.search(line)
    if not m:
        return None
    hours, minutes, seconds = m.groups()
    return int(hours or 0) * 3600 + int(minutes) * 60 + float(seconds)


def sampling_seconds(stats):
    """Seconds from the first statistics line naming a sample ("Sample 0/N", when the scene
    sync and BVH build are done) to the last one, by Cycles' clock; None if not found."""
    lines = [ln for ln in stats.splitlines() if stats_seconds(ln) is not None]
    first = next((ln for ln in lines if "| Sample " in ln), None)
    if first is None:
        return None
    return stats_seconds(lines[-1]) - stats_seconds(first)


def timed_render(scene, spp):
    """(seconds of the whole render call, seconds of it spent sampling, or None).

    The call includes Cycles' scene sync and BVH build (seconds on a million triangles). Its
    statistics lines, which Blender prints on stdout, are captured to find the sampling time,
    then printed as usual."""
    scene.cycles.samples = spp
    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    libc.fflush(None)
    saved = os.dup(1)
    with tempfile.TemporaryFile() as log:
        os.dup2(log.fileno(), 1)
        try:
            start = time.perf_counter()
            bpy.ops.render.render(write_still=False)
            total = time.perf_counter() - start
        finally:
            sys.stdout.flush()
            libc.fflush(None)
            os.dup2(saved, 1)
            os.close(saved)
        log.seek(0)
        stats = log.read().decode(errors="replace")
    sys.stdout.write(stats)
    return total, sampling_seconds(stats)


def main():
    args = parse_args()
    import_gltf(args.scene)
    scene = bpy.context.scene
    materials = {m.name: make_lambert(m) for m in bpy.data.materials if m.use_nodes}
    black_world(scene)
    configure_cycles(scene, args)
    camera = use_gltf_camera(scene)
    warmup, _ = timed_render(scene, 1)
    total, sampling = timed_render(scene, args.spp)
    seconds = total if sampling is None else sampling
    bpy.data.images["Render Result"].save_render(args.out)
    row = {
        "name": args.name, "exr": args.out, "renderer": "cycles", "version": bpy.app.version_string, "spp": args.spp,
        "threads": scene.render.threads, "sampling_pattern": scene.cycles.sampling_pattern,
        "seconds": seconds, "render_call_seconds": total, "sampling_found": sampling is not None,
        "warmup_seconds": warmup,
        "camera_fov_y_deg": camera.data.angle_y * 180 / 3.141592653589793,
        "camera_sensor_fit": camera.data.sensor_fit, "materials": materials}
    print("BENCH_JSON " + json.dumps(row), flush=True)
    # The same image timed with the scene sync and BVH build in (the whole render call).
    print("BENCH_JSON " + json.dumps({
        **row, "name": f"{args.name} (sync + BVH + render)", "seconds": total,
        "note": f"{args.name} (sync + BVH + render): the whole render call, Cycles' scene sync "
                "and BVH build included; the cycles row times the sampling alone (from the "
                "first 'Sample 0/N' to the last statistics line, by Cycles' clock)."}),
        flush=True)


if __name__ == "__main__":
    main()
