"""Minimal glTF 2.0 reader for the benchmark scenes (numpy only).

Reads a self-contained .gltf (buffers as base64 data URIs, or .bin files beside it) or a
binary .glb (buffer 0 in its BIN chunk), walks the node hierarchy and returns triangle meshes in world space, their materials
and the first camera. Only what the benchmark scenes use is supported: triangle
primitives, float positions/normals, integer indices, constant material factors.
"""

import base64
import json
import math
import os
import struct
from dataclasses import dataclass

import numpy as np

COMPONENT_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16,
                    5123: np.uint16, 5125: np.uint32, 5126: np.float32}
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
TRIANGLES = 4


@dataclass
class Material:
    name: str
    base_color: tuple  # linear RGB, the glTF baseColorFactor without alpha
    emission: tuple    # radiance: emissiveFactor x KHR_materials_emissive_strength


@dataclass
class Mesh:
    name: str
    positions: np.ndarray  # (n, 3) float32, world space
    normals: np.ndarray    # (n, 3) float32, world space, unit length, or None
    indices: np.ndarray    # (m, 3) uint32, counter-clockwise = front face
    material: Material


@dataclass
class Camera:
    to_world: np.ndarray  # 4x4; glTF convention: looks down local -Z, +Y up
    yfov: float           # radians
    aspect: float


@dataclass
class Scene:
    meshes: list
    camera: Camera


def load(path):
    """Parse a glTF file (.gltf or .glb) into a Scene with everything in world space."""
    with open(path, "rb") as f:
        data = f.read()
    gltf, bin_chunk = _split_glb(path, data) if data[:4] == b"glTF" else (json.loads(data), None)
    buffers = [_load_buffer(b, os.path.dirname(path), bin_chunk if k == 0 else None)
               for k, b in enumerate(gltf["buffers"])]
    materials = [_material(m) for m in gltf.get("materials", [])]
    meshes, cameras = [], []
    scene = gltf["scenes"][gltf.get("scene", 0)]
    for node_index in scene["nodes"]:
        _walk(gltf, buffers, materials, node_index, np.eye(4), meshes, cameras)
    if not cameras:
        raise ValueError(f"{path}: the scene has no camera node")
    return Scene(meshes, cameras[0])


def _split_glb(path, data):
    """(JSON document, BIN chunk or None) of a binary glTF."""
    magic, version, length = struct.unpack_from("<III", data, 0)
    if version != 2 or length > len(data):
        raise ValueError(f"{path}: not a glTF 2.0 binary (version {version}, length {length})")
    doc, binary, offset = None, None, 12
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<II", data, offset)
        chunk = memoryview(data)[offset + 8:offset + 8 + size]
        if kind == 0x4E4F534A:
            doc = json.loads(bytes(chunk))
        elif kind == 0x004E4942 and binary is None:
            binary = chunk
        offset += 8 + size
    if doc is None:
        raise ValueError(f"{path}: no JSON chunk")
    return doc, binary


def _load_buffer(buffer, base_dir, bin_chunk):
    uri = buffer.get("uri")
    if uri is None:
        if bin_chunk is None:
            raise ValueError("a buffer without a uri needs the BIN chunk of a .glb")
        return bin_chunk
    if uri.startswith("data:"):
        return base64.b64decode(uri.split(",", 1)[1])
    with open(os.path.join(base_dir, uri), "rb") as f:
        return f.read()


def _material(m):
    pbr = m.get("pbrMetallicRoughness", {})
    ext = m.get("extensions", {})
    strength = ext.get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1.0)
    emissive = m.get("emissiveFactor", [0.0, 0.0, 0.0])
    return Material(name=m.get("name", "unnamed"),
                    base_color=tuple(pbr.get("baseColorFactor", [1, 1, 1, 1])[:3]),
                    emission=tuple(c * strength for c in emissive))


def _node_matrix(node):
    """Local transform of a node: its column-major matrix, or T * R * S."""
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    t = np.eye(4)
    t[:3, 3] = node.get("translation", [0, 0, 0])
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    r = np.eye(4)
    r[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    s = np.diag(list(node.get("scale", [1, 1, 1])) + [1])
    return t @ r @ s


def _walk(gltf, buffers, materials, index, parent, meshes, cameras):
    node = gltf["nodes"][index]
    world = parent @ _node_matrix(node)
    if "mesh" in node:
        mesh = gltf["meshes"][node["mesh"]]
        for k, prim in enumerate(mesh["primitives"]):
            name = node.get("name") or mesh.get("name") or f"mesh{node['mesh']}"
            meshes.append(_primitive(gltf, buffers, materials, prim, world, f"{name}-{k}"))
    if "camera" in node:
        cam = gltf["cameras"][node["camera"]]
        if cam["type"] != "perspective":
            raise ValueError(f"camera of node {index}: only perspective cameras are supported")
        p = cam["perspective"]
        cameras.append(Camera(world, p["yfov"], p.get("aspectRatio", 1.0)))
    for child in node.get("children", []):
        _walk(gltf, buffers, materials, child, world, meshes, cameras)


def _accessor(gltf, buffers, index):
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    dtype = np.dtype(COMPONENT_DTYPES[acc["componentType"]]).newbyteorder("<")
    width = TYPE_SIZES[acc["type"]]
    offset = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride", width * dtype.itemsize)
    data, count = buffers[view["buffer"]], acc["count"]
    if count == 0:
        return np.zeros((0, width), dtype)
    # Rows `stride` bytes apart, `width` components each: one strided view, then one copy.
    needed = (count - 1) * stride + width * dtype.itemsize
    raw = np.frombuffer(data, np.uint8, needed, offset)
    rows = np.lib.stride_tricks.as_strided(raw, (count, width * dtype.itemsize), (stride, 1))
    return np.ascontiguousarray(rows).view(dtype).reshape(count, width)


def _primitive(gltf, buffers, materials, prim, world, name):
    if prim.get("mode", TRIANGLES) != TRIANGLES:
        raise ValueError(f"{name}: only triangle primitives are supported")
    attrs = prim["attributes"]
    pos = _accessor(gltf, buffers, attrs["POSITION"]).astype(np.float64)
    pos = pos @ world[:3, :3].T + world[:3, 3]
    normals = None
    if "NORMAL" in attrs:
        normal_matrix = np.linalg.inv(world[:3, :3]).T  # inverse transpose
        normals = _accessor(gltf, buffers, attrs["NORMAL"]).astype(np.float64) @ normal_matrix.T
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    if "indices" in prim:
        idx = _accessor(gltf, buffers, prim["indices"]).astype(np.uint32).reshape(-1, 3)
    else:
        idx = np.arange(len(pos), dtype=np.uint32).reshape(-1, 3)
    if np.linalg.det(world[:3, :3]) < 0:
        idx = idx[:, ::-1].copy()  # a mirroring transform flips the winding: undo it
    material = materials[prim["material"]] if "material" in prim else \
        Material("default", (1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
    return Mesh(name, pos.astype(np.float32),
                None if normals is None else normals.astype(np.float32), idx, material)


def face_normals(mesh):
    """Geometric normals from the winding (counter-clockwise = front)."""
    p = mesh.positions.astype(np.float64)
    a, b, c = p[mesh.indices[:, 0]], p[mesh.indices[:, 1]], p[mesh.indices[:, 2]]
    n = np.cross(b - a, c - a)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def check_winding(mesh):
    """Raise if the vertex normals point against the counter-clockwise face normals."""
    if mesh.normals is None:
        return
    vertex_mean = mesh.normals[mesh.indices].astype(np.float64).mean(axis=1)
    if np.any(np.einsum("ij,ij->i", vertex_mean, face_normals(mesh)) <= 0):
        raise ValueError(f"{mesh.name}: vertex normals disagree with the face winding")


def write_ply(mesh, path):
    """Binary little-endian PLY: float positions and normals, uint32 triangle faces."""
    n, m = len(mesh.positions), len(mesh.indices)
    has_normals = mesh.normals is not None
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}",
              "property float x", "property float y", "property float z"]
    if has_normals:
        header += ["property float nx", "property float ny", "property float nz"]
    header += [f"element face {m}", "property list uchar uint vertex_indices", "end_header"]
    columns = [mesh.positions] + ([mesh.normals] if has_normals else [])
    vertices = np.ascontiguousarray(np.hstack(columns), dtype="<f4")
    faces = np.zeros(m, dtype=[("n", "u1"), ("v", "<u4", 3)])
    faces["n"] = 3
    faces["v"] = mesh.indices
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(vertices.tobytes())
        f.write(faces.tobytes())


def yfov_degrees(camera):
    return math.degrees(camera.yfov)


if __name__ == "__main__":
    import sys
    s = load(sys.argv[1])
    for mesh in s.meshes:
        check_winding(mesh)
        print(mesh.name, len(mesh.positions), "vertices", len(mesh.indices), "triangles",
              mesh.material.name, "mean face normal", face_normals(mesh).mean(axis=0).round(3))
    print("camera", s.camera.to_world[:3, 3], "yfov", yfov_degrees(s.camera), "deg")
