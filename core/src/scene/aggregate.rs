//! Scene traversal: the closest hit along a ray ([`Scene::intersect`]) and whether anything
//! blocks it ([`Scene::occluded`]), as pbrt-v4's aggregates answer `Intersect` and
//! `IntersectP`, plus the brute-force reference they are tested against.
//!
//! Meshes used by one object are flattened into world-space triangles in the top-level BVH
//! (fastest to trace). Meshes used by several objects are instanced: their triangles stay in
//! object space, once, under a per-mesh BVH, and the top level holds one primitive per instance
//! that transforms the ray (a two-level BVH). Analytic shapes are primitives through their
//! world bounds and are intersected in object space; unbounded ones (planes) are tested
//! outside the BVH. Triangles of materials that are not opaque pass the alpha test.

use super::{ObjectKind, Scene};
use crate::accel::{pair_limits, AnyLeaves, Bvh, ClosestLeaves};
use crate::alloc::huge_vec;
use crate::geometry::interaction::NO_SLOT;
use crate::geometry::triangle::{leaf_runs, LeafTris, Mesh, TriangleGeom};
use crate::geometry::{Aabb, Hit, Ray};
use crate::material::AlphaMode;
use crate::sampling::hash_u32;
use glam::Vec4;
use rayon::prelude::*;

/// [`Hit::object`] of a hit in a packed leaf before its primitive is looked up.
const UNRESOLVED: u32 = u32::MAX;

/// A top-level BVH primitive, stored in BVH slot order. Twelve bytes: a triangle's corners
/// live in the aggregate's [`LeafTris`], at its leaf (the slot minus `lane`).
#[derive(Clone, Copy, Debug)]
pub(crate) enum Prim {
    Tri {
        object: u32,
        tri: u32,
        /// The material is not opaque: hits need the alpha test.
        alpha: bool,
        /// Its lane in its BVH leaf, and the leaf's slot count.
        lane: u8,
        count: u8,
    },
    Analytic {
        object: u32,
    },
    Instance {
        object: u32,
    },
}

/// Whether a leaf of these primitives is tested as one packet: opaque triangles only.
fn packable(prims: &[Prim]) -> bool {
    prims
        .iter()
        .all(|p| matches!(p, Prim::Tri { alpha: false, .. }))
}

/// The top level's primitives before the build, in input order, as runs: from `.0` on (up to
/// the next run) the triangles of one flattened object, or one other primitive. A
/// million-triangle mesh is one run, not a million primitives.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Run {
    /// Triangle `i − first` of `object` at input index `i`.
    Tris { object: u32, alpha: bool },
    /// One primitive.
    One(Prim),
}

/// The per-mesh BVH of an instanced mesh (object space).
#[derive(Clone)]
pub(crate) struct MeshBlas {
    bvh: Bvh,
    /// By slot: the corners, leaf by leaf.
    tris: LeafTris,
    /// By slot: the mesh's triangle.
    index: Vec<u32>,
}

impl MeshBlas {
    /// The BVH of mesh `m`, one of the trees of a scene of `scene_prims` primitives.
    pub(crate) fn new(m: &Mesh, scene_prims: usize) -> Self {
        let bounds: Vec<Aabb> = (0..m.indices.len())
            .into_par_iter()
            .map(|i| Aabb::from_points(&m.corners(i)))
            .collect();
        let (bvh, mut order) = Bvh::build_in_scene(bounds, scene_prims);
        order.shrink_to_fit();
        let tris = LeafTris::new(order.len(), bvh.leaves(), |slot| {
            Some(TriangleGeom::new(m.corners(order[slot] as usize)))
        });
        MeshBlas {
            bvh,
            tris,
            index: order,
        }
    }

    fn memory_bytes(&self) -> usize {
        self.bvh.memory_bytes()
            + self.tris.memory_bytes()
            + self.index.capacity() * std::mem::size_of::<u32>()
    }
}

/// The acceleration structures of a scene.
pub(crate) struct Aggregate {
    bvh: Bvh,
    /// The top level's primitives in BVH slot order.
    pub(crate) prims: Vec<Prim>,
    /// By slot, leaf by leaf: the corners of flattened triangles (world space).
    pub(crate) tris: LeafTris,
    /// By BVH slot, for flattened triangles: the unit world-space front normal (xyz), and in w
    /// 1 when the shading normal is that normal (no vertex normals, or all three equal to it),
    /// else 0. What a hit record needs without going back to the mesh and its transform.
    pub(crate) tri_shading: Vec<Vec4>,
    /// Objects outside the BVH (unbounded shapes).
    unbounded: Vec<u32>,
    /// By mesh: the BVH of an instanced mesh.
    blas: Vec<Option<MeshBlas>>,
    /// Whether shadow rays test two packed leaves a node enters at once ([`TopAny`]): with
    /// AVX2, where eight lanes cost about what four do.
    pairs: bool,
}

/// What [`Aggregate::new`] builds the top level from.
pub(crate) struct TopLevel {
    /// Every primitive's world bounds, in input order.
    pub(crate) bounds: Vec<Aabb>,
    /// The primitives in input order (see [`Run`]), by first input index.
    pub(crate) runs: Vec<(u32, Run)>,
}

impl Aggregate {
    /// The top-level BVH over `top` for a scene of `scene_prims` primitives. `geom(object,
    /// tri)` gives a flattened triangle's world-space corners, `tri_shading(object, tri)` its
    /// entry of [`Aggregate::tri_shading`]. Returns the aggregate and the bounds of its
    /// primitives. The bounds are freed once the BVH is built, before the primitives and their
    /// corners are laid out in slot order.
    pub(crate) fn new(
        top: TopLevel,
        unbounded: Vec<u32>,
        blas: Vec<Option<MeshBlas>>,
        scene_prims: usize,
        geom: impl Fn(u32, u32) -> TriangleGeom + Sync,
        tri_shading: impl Fn(u32, u32) -> Vec4 + Sync,
    ) -> (Self, Aabb) {
        let TopLevel {
            bounds: bounds_list,
            runs,
        } = top;
        let bounds = bounds_list
            .par_iter()
            .fold(Aabb::empty, |a, b| a.union(b))
            .reduce(Aabb::empty, |a, b| a.union(&b));
        let (mut bvh, order) = Bvh::build_in_scene(bounds_list, scene_prims);
        let prim = |i: u32| {
            let (first, run) = runs[runs.partition_point(|r| r.0 <= i) - 1];
            match run {
                Run::Tris { object, alpha } => Prim::Tri {
                    object,
                    tri: i - first,
                    alpha,
                    lane: 0,
                    count: 0,
                },
                Run::One(p) => p,
            }
        };
        // Arrays every ray reads at random go on huge pages (crate::alloc).
        let mut prims: Vec<Prim> = huge_vec(order.len());
        prims.par_extend(order.par_iter().map(|&i| prim(i)));
        drop(order);
        // Each triangle's lane in its leaf and the leaf's size, runs of leaves in parallel.
        leaf_runs(&mut prims, bvh.leaves(), 1)
            .into_par_iter()
            .for_each(|(run, part)| {
                let base = run.first().map_or(0, |l| l.0);
                for &(start, count) in run {
                    for lane in 0..count {
                        if let Prim::Tri {
                            lane: l, count: c, ..
                        } = &mut part[(start - base + lane) as usize]
                        {
                            *l = u8::try_from(lane).expect("leaves hold at most 255 primitives");
                            *c = u8::try_from(count).expect("leaves hold at most 255 primitives");
                        }
                    }
                }
            });
        // Marked: the leaf holds only opaque triangles, tested at once by
        // [`LeafTris::intersect`] (else its primitives are tested one by one).
        bvh.mark_leaves(|start, count| packable(&prims[start as usize..(start + count) as usize]));
        let tris = LeafTris::new(prims.len(), bvh.leaves(), |slot| match prims[slot] {
            Prim::Tri { object, tri, .. } => Some(geom(object, tri)),
            _ => None,
        });
        let mut shading = huge_vec(prims.len());
        shading.par_extend(prims.par_iter().map(|p| match *p {
            Prim::Tri { object, tri, .. } => tri_shading(object, tri),
            _ => Vec4::ZERO,
        }));
        let aggregate = Aggregate {
            bvh,
            prims,
            tris,
            tri_shading: shading,
            unbounded,
            blas,
            pairs: crate::accel::avx2(),
        };
        (aggregate, bounds)
    }

    /// The world-space corners of the flattened triangle in `slot`, at `lane` of a leaf of
    /// `count` slots.
    #[inline]
    pub(crate) fn tri_geom(&self, slot: u32, lane: u8, count: u8) -> TriangleGeom {
        self.tris
            .geom(slot - u32::from(lane), u32::from(count), u32::from(lane))
    }

    /// Whether the scene has unbounded shapes (planes), which reach beyond its bounds.
    pub(crate) fn has_unbounded(&self) -> bool {
        !self.unbounded.is_empty()
    }

    /// Bytes held by the BVHs and primitives.
    pub(crate) fn memory_bytes(&self) -> usize {
        use std::mem::size_of;
        self.bvh.memory_bytes()
            + self.prims.capacity() * size_of::<Prim>()
            + self.tris.memory_bytes()
            + self.tri_shading.capacity() * size_of::<Vec4>()
            + self.unbounded.capacity() * size_of::<u32>()
            + self.blas.capacity() * size_of::<Option<MeshBlas>>()
            + self
                .blas
                .iter()
                .flatten()
                .map(MeshBlas::memory_bytes)
                .sum::<usize>()
    }
}

/// The top level's leaves for any-hit traversal: packed triangles four at a time, or eight
/// (two leaves) with AVX2, else primitive by primitive.
struct TopAny<'a> {
    scene: &'a Scene,
    ray: &'a Ray,
    tmax: f32,
}

impl AnyLeaves for TopAny<'_> {
    #[inline(always)]
    fn leaf(&mut self, packed: bool, start: u32, count: u32) -> bool {
        let (scene, ray, tmax) = (self.scene, self.ray, self.tmax);
        let agg = &scene.aggregate;
        if packed {
            return agg.tris.any(start, count, ray.o, ray.d, 0.0, tmax);
        }
        (start as usize..(start + count) as usize).any(|slot| match agg.prims[slot] {
            Prim::Tri {
                object,
                tri,
                alpha,
                lane,
                count,
            } => match agg
                .tri_geom(slot as u32, lane, count)
                .intersect(ray.o, ray.d, 0.0, tmax)
            {
                Some((t, b1, b2)) => !alpha || scene.alpha_passes(object, tri, b1, b2, t),
                None => false,
            },
            Prim::Analytic { object } => scene.intersect_analytic(object, ray, tmax).is_some(),
            Prim::Instance { object } => scene.intersect_instance(object, ray, tmax).is_some(),
        })
    }

    #[inline(always)]
    fn pairs(&self) -> bool {
        self.scene.aggregate.pairs
    }

    #[inline(always)]
    fn pair(&mut self, a: (u32, u32), b: (u32, u32)) -> bool {
        let (ray, tris) = (self.ray, &self.scene.aggregate.tris);
        tris.hits_pair(a, b, ray.o, ray.d, (0.0, self.tmax), true) != 0
    }
}

/// The top level's leaves for closest-hit traversal: packed triangles four at a time, or
/// eight (two leaves) with AVX2, else primitive by primitive. `cand` is the latest accepted
/// hit, which is the nearest (each accepted hit shrinks tmax); from a packed leaf its object
/// is [`UNRESOLVED`] (looked up once at the end).
struct TopClosest<'a> {
    scene: &'a Scene,
    ray: &'a Ray,
    cand: Option<Hit>,
}

impl TopClosest<'_> {
    #[inline(always)]
    fn packed_hit(&mut self, slot: usize, t: f32, b1: f32, b2: f32) -> Option<(usize, f32)> {
        self.cand = Some(Hit {
            t,
            object: UNRESOLVED,
            prim: 0,
            b1,
            b2,
            slot: slot as u32,
        });
        Some((slot, t))
    }
}

impl ClosestLeaves for TopClosest<'_> {
    #[inline(always)]
    fn leaf(&mut self, packed: bool, start: u32, count: u32, tmax: f32) -> Option<(usize, f32)> {
        let (scene, ray) = (self.scene, self.ray);
        if packed {
            let (lane, t, b1, b2) = scene
                .aggregate
                .tris
                .intersect(start, count, ray.o, ray.d, 0.0, tmax)?;
            return self.packed_hit(start as usize + lane, t, b1, b2);
        }
        let mut tmax = tmax;
        let mut best = None;
        for slot in start as usize..(start + count) as usize {
            if let Some(h) = scene.intersect_prim(slot, ray, tmax) {
                tmax = h.t;
                self.cand = Some(h);
                best = Some((slot, h.t));
            }
        }
        best
    }

    #[inline(always)]
    fn pairs(&self) -> bool {
        self.scene.aggregate.pairs
    }

    #[inline(always)]
    fn pair(
        &mut self,
        a: (u32, u32),
        b: (u32, u32),
        tmax: f32,
        best: Option<usize>,
    ) -> Option<(usize, f32)> {
        let (ray, tris) = (self.ray, &self.scene.aggregate.tris);
        let (bound, beats) = pair_limits(a.0, b.0, best, tmax);
        let (slot, t, b1, b2) = tris.nearest_pair(a, b, ray.o, ray.d, (0.0, bound), beats, true)?;
        self.packed_hit(slot, t, b1, b2)
    }
}

impl Scene {
    /// Nearest hit along `ray` with parameter in (0, tmax).
    #[inline]
    pub fn intersect(&self, ray: &Ray, tmax: f32) -> Option<Hit> {
        let agg = &self.aggregate;
        let mut best: Option<Hit> = None;
        let mut tmax = tmax;
        for &oi in &agg.unbounded {
            if let Some(t) = self.intersect_analytic(oi, ray, tmax) {
                tmax = t;
                best = Some(Hit {
                    t,
                    object: oi,
                    prim: 0,
                    b1: 0.0,
                    b2: 0.0,
                    slot: NO_SLOT,
                });
            }
        }
        let mut top = TopClosest {
            scene: self,
            ray,
            cand: None,
        };
        let found = agg.bvh.closest_with(ray, tmax, &mut top);
        let cand = top.cand;
        // `cand` holds the latest accepted hit, which is the nearest: each accepted hit
        // shrinks tmax, so later candidates are always closer.
        if found.is_some() {
            best = cand.map(|mut h| {
                if h.object == UNRESOLVED {
                    let Prim::Tri { object, tri, .. } = agg.prims[h.slot as usize] else {
                        unreachable!("packed leaves hold triangles only");
                    };
                    (h.object, h.prim) = (object, tri);
                }
                h
            });
        }
        best
    }

    /// The hit of primitive `slot` within (0, tmax), if any.
    #[inline]
    fn intersect_prim(&self, slot: usize, ray: &Ray, tmax: f32) -> Option<Hit> {
        match self.aggregate.prims[slot] {
            Prim::Tri {
                object,
                tri,
                alpha,
                lane,
                count,
            } => {
                let geom = self.aggregate.tri_geom(slot as u32, lane, count);
                let (t, b1, b2) = geom.intersect(ray.o, ray.d, 0.0, tmax)?;
                (!alpha || self.alpha_passes(object, tri, b1, b2, t)).then_some(Hit {
                    t,
                    object,
                    prim: tri,
                    b1,
                    b2,
                    slot: slot as u32,
                })
            }
            Prim::Analytic { object } => {
                let t = self.intersect_analytic(object, ray, tmax)?;
                Some(Hit {
                    t,
                    object,
                    prim: 0,
                    b1: 0.0,
                    b2: 0.0,
                    slot: NO_SLOT,
                })
            }
            Prim::Instance { object } => self.intersect_instance(object, ray, tmax),
        }
    }

    /// Whether anything blocks `ray` before `tmax`.
    #[inline]
    pub fn occluded(&self, ray: &Ray, tmax: f32) -> bool {
        let agg = &self.aggregate;
        for &oi in &agg.unbounded {
            if self.intersect_analytic(oi, ray, tmax).is_some() {
                return true;
            }
        }
        agg.bvh.any_with(
            ray,
            tmax,
            &mut TopAny {
                scene: self,
                ray,
                tmax,
            },
        )
    }

    /// Brute-force nearest hit, testing every primitive: the reference the BVH is checked
    /// against.
    pub fn intersect_brute_force(&self, ray: &Ray, tmax: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut tmax = tmax;
        for (oi, o) in self.objects.iter().enumerate() {
            let oi = oi as u32;
            match &o.kind {
                ObjectKind::Analytic(_) => {
                    if let Some(t) = self.intersect_analytic(oi, ray, tmax) {
                        tmax = t;
                        best = Some(Hit {
                            t,
                            object: oi,
                            prim: 0,
                            b1: 0.0,
                            b2: 0.0,
                            slot: NO_SLOT,
                        });
                    }
                }
                ObjectKind::Mesh { mesh, .. } => {
                    let m = &self.meshes[*mesh as usize];
                    for ti in 0..m.indices.len() {
                        let geom = TriangleGeom::new(
                            m.corners(ti).map(|v| o.to_world.transform_point3a(v)),
                        );
                        if let Some((t, b1, b2)) = geom.intersect(ray.o, ray.d, 0.0, tmax) {
                            if self.alpha_passes(oi, ti as u32, b1, b2, t) {
                                tmax = t;
                                best = Some(Hit {
                                    t,
                                    object: oi,
                                    prim: ti as u32,
                                    b1,
                                    b2,
                                    slot: NO_SLOT,
                                });
                            }
                        }
                    }
                }
            }
        }
        best
    }

    #[inline]
    fn intersect_analytic(&self, object: u32, ray: &Ray, tmax: f32) -> Option<f32> {
        let o = &self.objects[object as usize];
        let ObjectKind::Analytic(a) = &o.kind else {
            return None;
        };
        let oo = o.to_object.transform_point3a(ray.o);
        let od = o.to_object.transform_vector3a(ray.d);
        a.intersect(oo, od, 0.0, tmax)
    }

    // Out of line: inlined, it made the common (non-instanced) path about 10 % slower
    // (measured with commit b8761c3, 2026-12-01, on a 2-core machine whose CPU was not
    // recorded).
    #[inline(never)]
    fn intersect_instance(&self, object: u32, ray: &Ray, tmax: f32) -> Option<Hit> {
        let o = &self.objects[object as usize];
        let ObjectKind::Mesh { mesh, .. } = o.kind else {
            return None;
        };
        let blas = self.aggregate.blas[mesh as usize].as_ref()?;
        let local = Ray::new(
            o.to_object.transform_point3a(ray.o),
            o.to_object.transform_vector3a(ray.d),
        );
        let mut cand = None;
        if self.material_of(object).alpha_mode == AlphaMode::Opaque {
            let (slot, t) = blas
                .bvh
                .closest_leaves(&local, tmax, |_, start, count, tmax| {
                    let (lane, t, b1, b2) = blas
                        .tris
                        .intersect(start, count, local.o, local.d, 0.0, tmax)?;
                    let slot = start as usize + lane;
                    cand = Some((b1, b2));
                    Some((slot, t))
                })?;
            let (b1, b2) = cand?;
            return Some(Hit {
                t,
                object,
                prim: blas.index[slot],
                b1,
                b2,
                slot: NO_SLOT,
            });
        }
        // Triangles one by one, as `Bvh::closest` offers them, with the alpha test.
        let mut cand = None;
        blas.bvh
            .closest_leaves(&local, tmax, |_, start, count, mut tmax| {
                let mut best = None;
                for lane in 0..count {
                    let slot = (start + lane) as usize;
                    let tri = blas.index[slot];
                    let geom = blas.tris.geom(start, count, lane);
                    match geom.intersect(local.o, local.d, 0.0, tmax) {
                        Some((t, b1, b2)) if self.alpha_passes(object, tri, b1, b2, t) => {
                            cand = Some(Hit {
                                t,
                                object,
                                prim: tri,
                                b1,
                                b2,
                                slot: NO_SLOT,
                            });
                            tmax = t;
                            best = Some((slot, t));
                        }
                        _ => {}
                    }
                }
                best
            })?;
        cand
    }

    /// Alpha test for MASK (cutoff) and BLEND (hashed stochastic transparency: a deterministic
    /// random threshold from the primitive, the hit's barycentrics and its distance).
    ///
    /// The barycentrics tell apart the hits of rays that cross a surface at one distance
    /// (parallel rays from a plane toward a directional light, an orthographic camera's
    /// rays), which would otherwise share one threshold per triangle and all pass or all stop.
    #[inline]
    fn alpha_passes(&self, object: u32, tri: u32, b1: f32, b2: f32, t: f32) -> bool {
        let o = &self.objects[object as usize];
        let mat = &self.materials[o.material as usize];
        let threshold = match mat.alpha_mode {
            AlphaMode::Opaque => return true,
            AlphaMode::Mask(cutoff) => cutoff,
            AlphaMode::Blend => {
                let h = hash_u32(hash_u32(object ^ tri.rotate_left(16)) ^ t.to_bits());
                let h = hash_u32(hash_u32(h ^ b1.to_bits()) ^ b2.to_bits());
                (h >> 8) as f32 / (1u32 << 24) as f32
            }
        };
        let ObjectKind::Mesh { mesh, .. } = o.kind else {
            return true;
        };
        let uvs = self.meshes[mesh as usize].uvs_at(tri, b1, b2);
        let alpha = mat.base_color(&self.textures, &uvs).w;
        match mat.alpha_mode {
            AlphaMode::Mask(_) => alpha >= threshold,
            _ => alpha > threshold,
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::geometry::interaction::NO_SLOT;
    use crate::geometry::Ray;
    use crate::sampling::hash_u32;
    use crate::scene::desc::*;
    use crate::Scene;
    use glam::{Mat4, Vec2, Vec3, Vec3A};

    fn rnd(i: u32) -> f32 {
        (hash_u32(i) >> 8) as f32 / (1u32 << 24) as f32
    }

    /// A unit quad in the XY plane with uvs over [0, 1]².
    fn quad(name: &str) -> MeshDesc {
        MeshDesc {
            name: name.into(),
            positions: vec![
                Vec3::new(-0.5, -0.5, 0.0),
                Vec3::new(0.5, -0.5, 0.0),
                Vec3::new(0.5, 0.5, 0.0),
                Vec3::new(-0.5, 0.5, 0.0),
            ],
            uvs: [vec![Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y], vec![]],
            colors: Vec::new(),
            indices: vec![[0, 1, 2], [0, 2, 3]],
            ..Default::default()
        }
    }

    /// 64 random triangles in the slab 1 < x < 1.5, away from the other objects.
    fn soup() -> MeshDesc {
        soup_from("soup", 100_000)
    }

    /// 64 random triangles in the slab 1 < x < 1.5 from the random numbers at `seed`.
    fn soup_from(name: &str, seed: u32) -> MeshDesc {
        let p = |i: u32| {
            Vec3::new(
                1.0 + 0.5 * rnd(i),
                3.0 * rnd(i + 1) - 1.5,
                3.0 * rnd(i + 2) - 1.5,
            )
        };
        MeshDesc {
            name: name.into(),
            positions: (0..192).map(|v| p(seed + 3 * v)).collect(),
            indices: (0..64).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect(),
            ..Default::default()
        }
    }

    /// Every kind of primitive: flattened and instanced triangles, opaque and alpha-masked
    /// (a checkerboard of alpha 0 and 1), a sphere, a box and an unbounded plane.
    fn scene() -> Scene {
        let mut cutout = MaterialDesc::new(
            "cutout",
            BsdfDesc::Diffuse {
                albedo: Vec3::ONE,
                texture: Some(TextureRef::new(0)),
            },
        );
        cutout.alpha_mode = AlphaMode::Mask(0.5);
        let object = |name: &str, shape, material, transform| ObjectDesc {
            name: name.into(),
            shape,
            material,
            transform,
            media: None,
        };
        let at = |x: f32, y: f32, z: f32| Mat4::from_translation(Vec3::new(x, y, z));
        let desc = SceneDesc {
            textures: vec![TextureDesc {
                name: "alpha".into(),
                width: 2,
                height: 2,
                texels: vec![
                    [1.0; 4],
                    [1.0, 1.0, 1.0, 0.0],
                    [1.0, 1.0, 1.0, 0.0],
                    [1.0; 4],
                ]
                .into(),
                srgb: false,
                wrap_u: WrapMode::Repeat,
                wrap_v: WrapMode::Repeat,
                bilinear: false,
            }],
            materials: vec![
                MaterialDesc::new(
                    "opaque",
                    BsdfDesc::Diffuse {
                        albedo: Vec3::ONE,
                        texture: None,
                    },
                ),
                cutout,
            ],
            meshes: vec![
                quad("once"),
                quad("shared"),
                quad("once-cutout"),
                soup(),
                soup_from("herd", 200_000),
            ],
            objects: vec![
                object("flat", ShapeDesc::Mesh { mesh: 0 }, 0, at(0.0, 0.0, -1.0)),
                object("inst-a", ShapeDesc::Mesh { mesh: 1 }, 0, at(0.7, 0.2, 0.0)),
                object(
                    "inst-b",
                    ShapeDesc::Mesh { mesh: 1 },
                    1,
                    at(-0.6, 0.1, 0.4) * Mat4::from_rotation_y(0.8),
                ),
                object("cut", ShapeDesc::Mesh { mesh: 2 }, 1, at(0.1, -0.2, 0.8)),
                object(
                    "ball",
                    ShapeDesc::Sphere {
                        center: Vec3::ZERO,
                        radius: 0.3,
                    },
                    0,
                    at(0.0, 0.5, 0.0),
                ),
                object(
                    "box",
                    ShapeDesc::Box {
                        min: Vec3::splat(-0.2),
                        max: Vec3::splat(0.2),
                    },
                    0,
                    at(-0.5, -0.5, -0.3) * Mat4::from_rotation_z(0.4),
                ),
                // Opaque triangles enough to fill leaves of their own (tested as packets).
                object("soup", ShapeDesc::Mesh { mesh: 3 }, 0, Mat4::IDENTITY),
                // As many instanced twice, opaque and with the alpha test, on the far side.
                object("herd-a", ShapeDesc::Mesh { mesh: 4 }, 0, at(-2.6, 0.0, 0.0)),
                object(
                    "herd-b",
                    ShapeDesc::Mesh { mesh: 4 },
                    1,
                    at(-2.4, 0.2, 0.1) * Mat4::from_rotation_x(0.3),
                ),
                object(
                    "floor",
                    ShapeDesc::Plane {
                        point: Vec3::new(0.0, -1.0, 0.0),
                        normal: Vec3::Y,
                    },
                    0,
                    Mat4::IDENTITY,
                ),
            ],
            ..Default::default()
        };
        Scene::build(&desc).unwrap()
    }

    #[test]
    fn closest_and_any_hit_agree_with_each_other_and_with_brute_force() {
        let scene = scene();
        assert!(scene.stats.flattened_triangles == 68 && scene.stats.instanced_triangles == 66);
        let (mut hits, mut packed_hits, mut herd_hits) = (0, 0, 0);
        // Whether the slot's leaf holds opaque triangles only (is tested as one packet).
        let agg = &scene.aggregate;
        let in_packed_leaf = |slot: u32| {
            let &(start, count) = agg
                .bvh
                .leaves()
                .iter()
                .find(|l| l.0 <= slot && slot < l.0 + l.1)
                .expect("every slot is in a leaf");
            super::packable(&agg.prims[start as usize..(start + count) as usize])
        };
        for i in 0..20_000u32 {
            let o = Vec3A::new(rnd(7 * i), rnd(7 * i + 1), rnd(7 * i + 2)) * 3.0 - 1.5;
            let d = (Vec3A::new(rnd(7 * i + 3), rnd(7 * i + 4), rnd(7 * i + 5)) - 0.5)
                .normalize_or(Vec3A::Z);
            let tmax = if i % 3 == 0 {
                f32::INFINITY
            } else {
                rnd(7 * i + 6) * 3.0
            };
            let ray = Ray::new(o, d);
            let closest = scene.intersect(&ray, tmax);
            assert_eq!(closest.is_some(), scene.occluded(&ray, tmax), "ray {i}");
            let brute = scene.intersect_brute_force(&ray, tmax);
            assert_eq!(closest.is_some(), brute.is_some(), "ray {i}");
            if let (Some(a), Some(b)) = (closest, brute) {
                assert!(
                    a.t < tmax && (a.t - b.t).abs() <= 1e-5 * a.t.max(1.0),
                    "ray {i}"
                );
                // The same primitive: a hit found in a packed leaf is resolved to its object
                // and triangle after traversal.
                assert_eq!((a.object, a.prim), (b.object, b.prim), "ray {i}");
                hits += 1;
                packed_hits += usize::from(a.slot != NO_SLOT && in_packed_leaf(a.slot));
                herd_hits += usize::from(scene.objects[a.object as usize].name.starts_with("herd"));
            }
        }
        assert!(hits > 5000, "{hits}");
        assert!(packed_hits > 200, "hits in packed leaves: {packed_hits}");
        assert!(herd_hits > 200, "hits on the instanced soup: {herd_hits}");
    }

    /// A flattened triangle costs its top-level primitive (12 bytes), its corners (36), its
    /// shading entry (16) and a share of a node: no copy of its corners elsewhere.
    #[test]
    fn primitives_stay_small() {
        assert!(std::mem::size_of::<super::Prim>() <= 12);
        let scene = scene();
        let agg = &scene.aggregate;
        // Every flattened triangle's corners come back from the leaf data as placed.
        for (slot, p) in agg.prims.iter().enumerate() {
            if let super::Prim::Tri {
                object,
                tri,
                lane,
                count,
                ..
            } = *p
            {
                let o = &scene.objects[object as usize];
                let crate::scene::ObjectKind::Mesh { mesh } = o.kind else {
                    panic!("a triangle of a shape");
                };
                let m = &scene.meshes[mesh as usize];
                let want = crate::geometry::triangle::TriangleGeom::new(
                    m.corners(tri as usize)
                        .map(|v| o.to_world.transform_point3a(v)),
                );
                assert_eq!(agg.tri_geom(slot as u32, lane, count), want);
            }
        }
    }

    /// BLEND stops a share alpha of rays, whatever their distances: parallel rays that cross
    /// a quad at one distance (toward a directional light, from an orthographic camera) are
    /// stopped in that share too, flattened or instanced, and the closest-hit and any-hit
    /// queries agree ray by ray.
    #[test]
    fn blended_surfaces_stop_their_share_of_parallel_rays() {
        let mut veil = MaterialDesc::new(
            "veil",
            BsdfDesc::Diffuse {
                albedo: Vec3::ONE,
                texture: Some(TextureRef::new(0)),
            },
        );
        veil.alpha_mode = AlphaMode::Blend;
        let object = |mesh, x: f32| ObjectDesc {
            name: format!("veil at {x}"),
            shape: ShapeDesc::Mesh { mesh },
            material: 0,
            transform: Mat4::from_translation(Vec3::new(x, 0.0, 0.0)),
            media: None,
        };
        for alpha in [0.3f32, 0.9] {
            let desc = SceneDesc {
                textures: vec![TextureDesc {
                    name: "alpha".into(),
                    width: 1,
                    height: 1,
                    texels: vec![[1.0, 1.0, 1.0, alpha]].into(),
                    srgb: false,
                    wrap_u: WrapMode::Repeat,
                    wrap_v: WrapMode::Repeat,
                    bilinear: false,
                }],
                materials: vec![veil.clone()],
                // One quad flattened, one instanced twice (its own BVH).
                meshes: vec![quad("once"), quad("shared")],
                objects: vec![object(0, 0.0), object(1, 3.0), object(1, 6.0)],
                ..Default::default()
            };
            let scene = Scene::build(&desc).unwrap();
            for x0 in [0.0, 3.0, 6.0] {
                for d in [-Vec3A::Z, Vec3A::new(0.1, 0.05, -1.0)] {
                    let n = 64;
                    let mut stopped = 0;
                    for i in 0..n * n {
                        // Origins on z = 1 whose rays all meet the quad (z = 0) inside it.
                        let (x, y) = ((i % n) as f32 / n as f32, (i / n) as f32 / n as f32);
                        let o = Vec3A::new(x0 - 0.4 + 0.7 * x, -0.4 + 0.7 * y, 1.0);
                        let ray = Ray::new(o, d);
                        let hit = scene.intersect(&ray, 10.0).is_some();
                        assert_eq!(hit, scene.occluded(&ray, 10.0), "ray {i}");
                        stopped += usize::from(hit);
                    }
                    let share = stopped as f32 / (n * n) as f32;
                    // 4096 rays: a standard deviation of at most 0.008.
                    assert!(
                        (share - alpha).abs() < 0.04,
                        "alpha {alpha}, quad at {x0}, {d}: {share} stopped"
                    );
                }
            }
        }
    }

    #[test]
    fn masked_texels_let_rays_through() {
        let scene = scene();
        // Straight down the z axis through the cut-out quad at (0.1, -0.2, 0.8): its texel
        // (0, 0) is opaque, texel (1, 0) is cut out (uv (0.75, 0.25) is at x = +0.25, y = −0.25).
        let down = |x: f32, y: f32| Ray::new(Vec3A::new(x, y, 2.0), -Vec3A::Z);
        let solid = scene.intersect(&down(0.1 - 0.25, -0.2 - 0.25), f32::INFINITY);
        assert_eq!(
            solid.map(|h| scene.objects[h.object as usize].name.as_str()),
            Some("cut")
        );
        let hole = scene.intersect(&down(0.1 + 0.25, -0.2 - 0.25), f32::INFINITY);
        assert_ne!(
            hole.map(|h| scene.objects[h.object as usize].name.as_str()),
            Some("cut")
        );
        assert!(!scene.occluded(&down(0.1 + 0.25, -0.2 - 0.25), 1.5));
        assert!(scene.occluded(&down(0.1 - 0.25, -0.2 - 0.25), 1.5));
    }
}
