#!/usr/bin/env python3
"""Writes a binary glTF (.glb) of a bumpy sphere tessellated as a latitude-longitude grid, the
procedural mesh of `raytile bench`, with at least the given number of triangles.

    python3 scripts/make-mesh-glb.py OUT.glb [TRIANGLES]
"""
import json
import math
import struct
import sys
from array import array

out = sys.argv[1]
triangles = int(sys.argv[2]) if len(sys.argv) > 2 else 1 << 20
grid = math.ceil(math.sqrt(triangles / 2))

pos = array("f")
for i in range(grid + 1):
    th = math.pi * i / grid
    for j in range(grid + 1):
        ph = 2 * math.pi * j / grid
        r = 1 + 0.05 * math.sin(7 * th) * math.cos(9 * ph)
        pos.extend((r * math.sin(th) * math.cos(ph), r * math.cos(th), r * math.sin(th) * math.sin(ph)))
idx = array("I")
w = grid + 1
for i in range(grid):
    for j in range(grid):
        a, b, c, d = i * w + j, (i + 1) * w + j, (i + 1) * w + j + 1, i * w + j + 1
        idx.extend((a, c, b, a, d, c))
if sys.byteorder != "little":
    pos.byteswap()
    idx.byteswap()
pos_bytes, idx_bytes = pos.tobytes(), idx.tobytes()
n_verts = len(pos) // 3
doc = {
    "asset": {"version": "2.0", "generator": "raytile scripts/make-mesh-glb.py"},
    "scene": 0,
    "scenes": [{"nodes": [0]}],
    "nodes": [{"mesh": 0}],
    "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
    "buffers": [{"byteLength": len(pos_bytes) + len(idx_bytes)}],
    "bufferViews": [
        {"buffer": 0, "byteOffset": 0, "byteLength": len(pos_bytes), "target": 34962},
        {"buffer": 0, "byteOffset": len(pos_bytes), "byteLength": len(idx_bytes), "target": 34963},
    ],
    "accessors": [
        {"bufferView": 0, "componentType": 5126, "count": n_verts, "type": "VEC3",
         "min": [-1.05, -1.05, -1.05], "max": [1.05, 1.05, 1.05]},
        {"bufferView": 1, "componentType": 5125, "count": len(idx), "type": "SCALAR"},
    ],
}
js = json.dumps(doc).encode()
js += b" " * (-len(js) % 4)
binary = pos_bytes + idx_bytes
binary += b"\0" * (-len(binary) % 4)
total = 12 + 8 + len(js) + 8 + len(binary)
with open(out, "wb") as f:
    f.write(struct.pack("<III", 0x46546C67, 2, total))
    f.write(struct.pack("<II", len(js), 0x4E4F534A) + js)
    f.write(struct.pack("<II", len(binary), 0x004E4942) + binary)
print(f"{out}: {len(idx) // 3} triangles, {n_verts} vertices", file=sys.stderr)
