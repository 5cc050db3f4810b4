//! glTF primitives to [`MeshDesc`]: triangle lists, strips and fans; attributes; generated
//! tangents for normal-mapped materials.

use super::Loader;
use crate::scene::desc::MeshDesc;
use glam::{Vec2, Vec3};
use gltf::accessor::Dimensions;
use gltf::mesh::Mode;
use gltf::Semantic;
use rayon::prelude::*;

/// Converts a strip or fan (or a list) of indices to triangles, following glTF 2.0 §3.7.2.1.
/// Degenerate triangles of strips and fans (often used to stitch strips) are dropped.
pub(super) fn triangulate(mode: Mode, idx: Vec<u32>) -> Vec<[u32; 3]> {
    match mode {
        Mode::TriangleStrip => (0..idx.len().saturating_sub(2))
            .map(|i| {
                if i % 2 == 0 {
                    [idx[i], idx[i + 1], idx[i + 2]]
                } else {
                    [idx[i], idx[i + 2], idx[i + 1]]
                }
            })
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect(),
        Mode::TriangleFan => (1..idx.len().saturating_sub(1))
            .map(|i| [idx[i], idx[i + 1], idx[0]])
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect(),
        _ => triples(idx),
    }
}

/// A list of indices as triangles (the last `len % 3` dropped), in the same memory: a
/// million-triangle mesh's indices are not copied.
fn triples(mut idx: Vec<u32>) -> Vec<[u32; 3]> {
    idx.truncate(idx.len() / 3 * 3);
    if !idx.capacity().is_multiple_of(3) {
        idx.shrink_to_fit();
    }
    if !idx.capacity().is_multiple_of(3) {
        return idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    }
    let mut idx = std::mem::ManuallyDrop::new(idx);
    let (ptr, len, cap) = (idx.as_mut_ptr(), idx.len(), idx.capacity());
    // SAFETY: `[u32; 3]` has `u32`'s alignment and three times its size, so the allocation of
    // `cap` u32s (a multiple of 3) is exactly one of `cap / 3` triples, and its first `len`
    // u32s (a multiple of 3, initialised) are `len / 3` initialised triples; the vector the
    // pointer came from is not dropped.
    unsafe { Vec::from_raw_parts(ptr.cast::<[u32; 3]>(), len / 3, cap / 3) }
}

/// Elements read as arrays to the type the description holds (in place: the same bytes).
fn to_vecs<const N: usize, T>(v: Vec<[f32; N]>, f: impl Fn([f32; N]) -> T) -> Vec<T> {
    v.into_iter().map(f).collect()
}

impl Loader<'_> {
    /// Warns when `prim` stores positions, normals, tangents or texture coordinates as
    /// integers (`KHR_mesh_quantization`, as gltfpack writes) in a file that does not declare
    /// the extension: such a file is not valid glTF. Its attributes read the same either way
    /// (the accessor's normalisation rules), as glTF viewers read them.
    fn check_quantization(&mut self, prim: &gltf::Primitive, label: &str) {
        use gltf::accessor::DataType;
        let quantized: Vec<String> = prim
            .attributes()
            .filter(|(semantic, acc)| {
                let dt = acc.data_type();
                match semantic {
                    Semantic::Positions | Semantic::Normals | Semantic::Tangents => {
                        dt != DataType::F32
                    }
                    // The core specification allows normalised unsigned bytes and shorts.
                    Semantic::TexCoords(_) => {
                        dt != DataType::F32
                            && !(acc.normalized() && matches!(dt, DataType::U8 | DataType::U16))
                    }
                    _ => false,
                }
            })
            .map(|(semantic, _)| semantic.to_string())
            .collect();
        let declared = self
            .doc
            .extensions_used()
            .any(|e| e == "KHR_mesh_quantization");
        if !quantized.is_empty() && !declared {
            self.warn(format!(
                "{label}: {} stored as integers, which needs KHR_mesh_quantization, but the file \
                 does not declare it; read as that extension says",
                quantized.join(", ")
            ));
        }
    }

    /// Loads one primitive. `None` (with a warning) when it is not made of triangles or has no
    /// positions. `tangent_uv` asks for tangents from that UV set when TANGENT is absent.
    pub(super) fn load_primitive(
        &mut self,
        mesh: &gltf::Mesh,
        prim: &gltf::Primitive,
        tangent_uv: Option<u8>,
    ) -> Result<Option<MeshDesc>, String> {
        let label = format!("mesh {} primitive {}", mesh.index(), prim.index());
        let mode = prim.mode();
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            self.warn(format!(
                "{label}: {mode:?} primitives are not rendered (only triangles are); skipped"
            ));
            return Ok(None);
        }
        let Some(pos_acc) = prim.get(&Semantic::Positions) else {
            self.warn(format!("{label}: no POSITION attribute; skipped"));
            return Ok(None);
        };
        let plabel = format!("{label} (POSITION)");
        let positions: Vec<Vec3> = to_vecs(
            self.read_floats(&pos_acc, &plabel, Dimensions::Vec3)?,
            Vec3::from_array,
        );
        let n = positions.len();
        let same_count = |acc: &gltf::Accessor, what: &str| -> Result<(), String> {
            if acc.count() != n {
                return Err(format!(
                    "{label}: accessor {} ({what}) has {} elements but POSITION has {n}",
                    acc.index(),
                    acc.count()
                ));
            }
            Ok(())
        };
        let mut normals = Vec::new();
        if let Some(acc) = prim.get(&Semantic::Normals) {
            same_count(&acc, "NORMAL")?;
            normals = to_vecs(
                self.read_floats(&acc, &format!("{label} (NORMAL)"), Dimensions::Vec3)?,
                Vec3::from_array,
            );
        }
        let mut tangents = Vec::new();
        if let Some(acc) = prim.get(&Semantic::Tangents) {
            same_count(&acc, "TANGENT")?;
            tangents = self.read_floats(&acc, &format!("{label} (TANGENT)"), Dimensions::Vec4)?;
        }
        let mut uvs: [Vec<Vec2>; 2] = [Vec::new(), Vec::new()];
        for (set, slot) in uvs.iter_mut().enumerate() {
            if let Some(acc) = prim.get(&Semantic::TexCoords(set as u32)) {
                let what = format!("TEXCOORD_{set}");
                same_count(&acc, &what)?;
                *slot = to_vecs(
                    self.read_floats(&acc, &format!("{label} ({what})"), Dimensions::Vec2)?,
                    Vec2::from_array,
                );
            }
        }
        let mut colors = Vec::new();
        if let Some(acc) = prim.get(&Semantic::Colors(0)) {
            same_count(&acc, "COLOR_0")?;
            let what = format!("{label} (COLOR_0)");
            colors = if acc.dimensions() == Dimensions::Vec4 {
                // Alpha is not used: the surface's alpha comes from the material.
                to_vecs(self.read_floats::<4>(&acc, &what, Dimensions::Vec4)?, |c| {
                    Vec3::new(c[0], c[1], c[2])
                })
            } else {
                to_vecs(
                    self.read_floats(&acc, &what, Dimensions::Vec3)?,
                    Vec3::from_array,
                )
            };
        }
        if prim.morph_targets().next().is_some() {
            self.warn(format!("{label}: morph targets are ignored (rest pose)"));
        }
        self.check_quantization(prim, &label);

        let raw_indices = match prim.indices() {
            Some(acc) => {
                let idx = self.read_indices(&acc, &format!("{label} (indices)"))?;
                if let Some(i) = idx.par_iter().position_first(|&v| v as usize >= n) {
                    let v = idx[i];
                    return Err(format!(
                        "{label}: index {v} at position {i} of accessor {} is out of range ({n} vertices)",
                        acc.index()
                    ));
                }
                idx
            }
            None => {
                self.charge(n * 4, &label)?;
                (0..n as u32).collect()
            }
        };
        if mode == Mode::Triangles && raw_indices.len() % 3 != 0 {
            self.warn(format!(
                "{label}: {} indices is not a multiple of 3; the last {} are ignored",
                raw_indices.len(),
                raw_indices.len() % 3
            ));
        }
        self.charge(raw_indices.len() * 4, &label)?;
        let indices = triangulate(mode, raw_indices);
        if indices.is_empty() {
            self.warn(format!("{label}: no triangles; skipped"));
            return Ok(None);
        }

        let name = match mesh.name() {
            Some(m) => format!("{m} primitive {}", prim.index()),
            None => label.clone(),
        };
        let mut desc = MeshDesc {
            name,
            positions,
            normals,
            tangents,
            uvs,
            colors,
            indices,
        };
        if let Some(set) = tangent_uv {
            if desc.tangents.is_empty() {
                if desc.uvs[set as usize % 2].is_empty() {
                    self.warn(format!(
                        "{label}: the material has a normal map but TEXCOORD_{set} is missing; normal map ignored on this primitive"
                    ));
                } else {
                    self.charge(n * 16, &label)?;
                    desc.tangents = generate_tangents(&desc, set as usize % 2);
                }
            }
        }
        Ok(Some(desc))
    }
}

/// MikkTSpace tangents. Tangents are stored per vertex: where MikkTSpace would split a vertex
/// (a UV seam shared by an index), the last face written wins, as most glTF viewers do.
///
/// glTF's texture coordinates run down the image (v = 0 at the top), MikkTSpace's up, so the
/// sign of each bitangent is flipped (as three.js's `computeMikkTSpaceTangents` and
/// glTF-Transform do for glTF): a normal map then bends normals the way the TANGENT attribute
/// an exporter writes would.
///
/// Only triangles whose corners lie at three different positions go to MikkTSpace: the
/// `mikktspace` crate reads out of bounds (and can crash the process) when every triangle it
/// is given is degenerate. The others keep the default tangent; they have no area to shade.
fn generate_tangents(mesh: &MeshDesc, set: usize) -> Vec<[f32; 4]> {
    struct Geo<'a> {
        mesh: &'a MeshDesc,
        faces: Vec<[u32; 3]>,
        set: usize,
        out: Vec<[f32; 4]>,
    }
    impl Geo<'_> {
        fn vertex(&self, face: usize, vert: usize) -> usize {
            self.faces
                .get(face)
                .and_then(|t| t.get(vert))
                .copied()
                .unwrap_or(0) as usize
        }
        fn pos(&self, i: usize) -> Vec3 {
            self.mesh.positions.get(i).copied().unwrap_or(Vec3::ZERO)
        }
    }
    impl mikktspace::Geometry for Geo<'_> {
        fn num_faces(&self) -> usize {
            self.faces.len()
        }
        fn num_vertices_of_face(&self, _face: usize) -> usize {
            3
        }
        fn position(&self, face: usize, vert: usize) -> [f32; 3] {
            self.pos(self.vertex(face, vert)).to_array()
        }
        fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
            if let Some(n) = self.mesh.normals.get(self.vertex(face, vert)) {
                return n.to_array();
            }
            // Flat shading: the geometric normal of the face.
            let [a, b, c] = [0, 1, 2].map(|v| self.pos(self.vertex(face, v)));
            (b - a).cross(c - a).normalize_or_zero().to_array()
        }
        fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
            self.mesh.uvs[self.set]
                .get(self.vertex(face, vert))
                .copied()
                .unwrap_or(Vec2::ZERO)
                .to_array()
        }
        fn set_tangent_encoded(&mut self, tangent: [f32; 4], face: usize, vert: usize) {
            let v = self.vertex(face, vert);
            if let Some(slot) = self.out.get_mut(v) {
                let [x, y, z, w] = tangent;
                *slot = [x, y, z, -w];
            }
        }
    }
    let at = |i: u32| mesh.positions.get(i as usize).copied();
    let faces: Vec<[u32; 3]> = mesh
        .indices
        .iter()
        .copied()
        .filter(|&[a, b, c]| {
            let (pa, pb, pc) = (at(a), at(b), at(c));
            pa.is_some() && pb.is_some() && pc.is_some() && pa != pb && pb != pc && pa != pc
        })
        .collect();
    let mut geo = Geo {
        mesh,
        faces,
        set,
        out: vec![[1.0, 0.0, 0.0, 1.0]; mesh.positions.len()],
    };
    if !geo.faces.is_empty() {
        mikktspace::generate_tangents(&mut geo);
    }
    geo.out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_and_fans_follow_the_spec() {
        assert_eq!(
            triangulate(Mode::TriangleStrip, vec![0, 1, 2, 3, 4]),
            vec![[0, 1, 2], [1, 3, 2], [2, 3, 4]]
        );
        assert_eq!(
            triangulate(Mode::TriangleFan, vec![0, 1, 2, 3]),
            vec![[1, 2, 0], [2, 3, 0]]
        );
        assert_eq!(
            triangulate(Mode::Triangles, vec![0, 1, 2, 3, 4]),
            vec![[0, 1, 2]]
        );
        assert!(triangulate(Mode::TriangleStrip, vec![0, 1]).is_empty());
        assert!(triangulate(Mode::TriangleFan, vec![]).is_empty());
    }

    /// Lists become triangles in the same memory, whatever the vector's spare room.
    #[test]
    fn lists_keep_their_memory() {
        let idx: Vec<u32> = (0..3 * 100_000).collect();
        let at = idx.as_ptr() as usize;
        let tris = triangulate(Mode::Triangles, idx);
        assert_eq!(
            tris.as_ptr() as usize,
            at,
            "a list of whole triangles is not copied"
        );
        assert_eq!(tris.len(), 100_000);
        assert!(tris.iter().enumerate().all(|(i, t)| {
            let i = 3 * i as u32;
            *t == [i, i + 1, i + 2]
        }));
        for room in [7, 8, 9, 10] {
            let mut idx = Vec::with_capacity(room);
            idx.extend([5, 6, 7, 8, 9, 10, 11]);
            assert_eq!(
                triangulate(Mode::Triangles, idx),
                vec![[5, 6, 7], [8, 9, 10]],
                "capacity {room}"
            );
        }
    }
}
