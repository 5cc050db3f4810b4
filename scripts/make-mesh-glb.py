#!/usr/bin/env python3
"""Writes a binary glTF (.glb) of a bumpy sphere tessellated as a latitude-longitude grid, the
procedural mesh of `raytile bench`, with at least the given number of triangles.

    python3 scripts/make-mesh-glb.py OUT.glb [TRIANGLES]
    python3 scripts/make-mesh-glb.py OUT.glb [TRIANGLES] --cornell CORNELL.gltf

With --cornell the sphere stands in a Cornell box: the walls, light, camera and materials of the
given glTF (a self-contained .gltf, such as ../shared/scenes/cornell-box.gltf), its two boxes
replaced by the sphere (radius 0.5, resting on the floor, the box's Lambertian "white"
material). The output depends only on the arguments (and the platform's libm): the same
command writes the same bytes. The standard library only, so it runs on any Python 3.
"""
import argparse
import base64
import json
import math
import struct
import sys
from array import array

# Where the sphere goes in the Cornell box: the unit sphere (radius 0.95-1.05, 1 at the poles)
# scaled by 0.5, its lowest point (y = -1.032 before scaling, a bump near the south pole)
# 0.004 above the floor (y = -1).
CORNELL_SPHERE = {"translation": [0.0, -0.48, 0.0], "scale": [0.5, 0.5, 0.5]}
CORNELL_REMOVED = ("small-box", "large-box")


def bumpy_sphere(triangles):
    """(positions, indices) as little-endian float32 / uint32 arrays; counter-clockwise seen
    from outside (the glTF front face points out)."""
    grid = math.ceil(math.sqrt(triangles / 2))
    pos = array("f")
    for i in range(grid + 1):
        th = math.pi * i / grid
        st, ct = math.sin(th), math.cos(th)
        for j in range(grid + 1):
            ph = 2 * math.pi * j / grid
            r = 1 + 0.05 * math.sin(7 * th) * math.cos(9 * ph)
            pos.extend((r * st * math.cos(ph), r * ct, r * st * math.sin(ph)))
    idx = array("I")
    w = grid + 1
    for i in range(grid):
        row, below = i * w, (i + 1) * w
        for j in range(grid):
            a, b, c, d = row + j, below + j, below + j + 1, row + j + 1
            idx.extend((a, c, b, a, d, c))
    if sys.byteorder != "little":
        pos.byteswap()
        idx.byteswap()
    return pos, idx


def pad4(data, fill=b"\0"):
    return data + fill * (-len(data) % 4)


def sphere_only(pos, idx):
    """The glTF document and binary chunk of the bare sphere."""
    binary = pos.tobytes() + idx.tobytes()
    doc = {
        "asset": {"version": "2.0", "generator": "raytile scripts/make-mesh-glb.py"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(binary)}],
        "bufferViews": [],
        "accessors": [],
    }
    add_sphere_accessors(doc, pos, idx, 0)
    return doc, binary


def add_sphere_accessors(doc, pos, idx, offset):
    """Appends the sphere's buffer views and accessors (at `offset` in buffer 0); returns the
    (POSITION, indices) accessor numbers."""
    views, accessors = doc["bufferViews"], doc["accessors"]
    n_pos = len(pos.tobytes())
    views.append({"buffer": 0, "byteOffset": offset, "byteLength": n_pos, "target": 34962})
    views.append({"buffer": 0, "byteOffset": offset + n_pos, "byteLength": len(idx) * 4,
                  "target": 34963})
    accessors.append({"bufferView": len(views) - 2, "componentType": 5126,
                      "count": len(pos) // 3, "type": "VEC3",
                      "min": [min(pos[k::3]) for k in range(3)],
                      "max": [max(pos[k::3]) for k in range(3)]})
    accessors.append({"bufferView": len(views) - 1, "componentType": 5125, "count": len(idx),
                      "type": "SCALAR"})
    return len(accessors) - 2, len(accessors) - 1


def in_cornell_box(pos, idx, cornell_path):
    """The Cornell box glTF with its boxes replaced by the sphere, as one binary chunk."""
    with open(cornell_path) as f:
        doc = json.load(f)
    if len(doc.get("buffers", [])) != 1 or not doc["buffers"][0].get("uri", "").startswith("data:"):
        sys.exit(f"{cornell_path}: expected one buffer embedded as a data: URI")
    base = pad4(base64.b64decode(doc["buffers"][0]["uri"].split(",", 1)[1]))
    white = next((k for k, m in enumerate(doc.get("materials", [])) if m.get("name") == "white"),
                 None)
    if white is None:
        sys.exit(f"{cornell_path}: no material named 'white' for the sphere")
    position, indices = add_sphere_accessors(doc, pos, idx, len(base))
    doc["meshes"].append({"name": "bumpy-sphere", "primitives": [
        {"attributes": {"POSITION": position}, "indices": indices, "material": white}]})
    # Drop the boxes' nodes (their meshes stay, unreferenced) and renumber the scene's nodes.
    keep = [k for k, n in enumerate(doc["nodes"]) if n.get("name") not in CORNELL_REMOVED]
    if len(keep) != len(doc["nodes"]) - len(CORNELL_REMOVED):
        sys.exit(f"{cornell_path}: expected nodes named {', '.join(CORNELL_REMOVED)}")
    renumber = {old: new for new, old in enumerate(keep)}
    doc["nodes"] = [doc["nodes"][k] for k in keep]
    for node in doc["nodes"]:
        if "children" in node:
            node["children"] = [renumber[c] for c in node["children"] if c in renumber]
    for scene in doc["scenes"]:
        scene["nodes"] = [renumber[n] for n in scene["nodes"] if n in renumber]
    doc["nodes"].append({"name": "bumpy-sphere", "mesh": len(doc["meshes"]) - 1,
                         **CORNELL_SPHERE})
    doc["scenes"][doc.get("scene", 0)]["nodes"].append(len(doc["nodes"]) - 1)
    binary = base + pos.tobytes() + idx.tobytes()
    doc["buffers"] = [{"byteLength": len(binary)}]
    doc["asset"]["generator"] = "raytile scripts/make-mesh-glb.py --cornell"
    return doc, binary


def write_glb(path, doc, binary):
    js = pad4(json.dumps(doc, separators=(",", ":")).encode(), b" ")
    binary = pad4(binary)
    total = 12 + 8 + len(js) + 8 + len(binary)
    with open(path, "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, total))
        f.write(struct.pack("<II", len(js), 0x4E4F534A) + js)
        f.write(struct.pack("<II", len(binary), 0x004E4942) + binary)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("out")
    p.add_argument("triangles", nargs="?", type=int, default=1 << 20)
    p.add_argument("--cornell", metavar="GLTF", help="put the sphere in this Cornell box")
    args = p.parse_args()
    pos, idx = bumpy_sphere(args.triangles)
    doc, binary = in_cornell_box(pos, idx, args.cornell) if args.cornell else sphere_only(pos, idx)
    write_glb(args.out, doc, binary)
    print(f"{args.out}: sphere of {len(idx) // 3} triangles, {len(pos) // 3} vertices"
          + (f", in {args.cornell}" if args.cornell else ""), file=sys.stderr)


if __name__ == "__main__":
    main()
