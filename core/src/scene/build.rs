//! Turns a [`SceneDesc`] into the render-ready [`Scene`]: world-space primitives in a BVH,
//! materials with resolved textures, lights with their selection distribution, one camera.
//!
//! Meshes used by one object are flattened into world-space triangles in the top-level BVH
//! (fastest to trace). Meshes used by several objects are instanced: their triangles stay in
//! object space, once, under a per-mesh BVH, and the top level holds one primitive per instance
//! that transforms the ray (a two-level BVH). Analytic shapes are primitives through their
//! world bounds and are intersected in object space.

use super::desc::{
    AlphaMode, BsdfDesc, CameraDesc, MaterialDesc, Projection, SceneDesc, ShapeDesc,
};
use super::SceneError;
use crate::accel::Bvh;
use crate::camera::Camera;
use crate::geometry::triangle::{Mesh, Tri4, TriangleGeom};
use crate::geometry::{aabox, plane, polygon, quadric, sphere, Aabb, Analytic, Ray};
use crate::light::{luminance, Environment, Light, LightSet};
use crate::material::{self, Bsdf};
use crate::sampling::hash_u32;
use crate::sampling::warp::Frame;
use crate::texture::{TexSlot, Texture};
use crate::RenderSettings;
use glam::{Affine3A, Mat3A, Mat4, Vec2, Vec3, Vec3A, Vec4};
use std::f32::consts::PI;

/// What an object is made of. (Objects are few: the size of the analytic variant does not matter.)
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub(crate) enum ObjectKind {
    /// Mesh `mesh` (flattened into the top level, or instanced through its own BVH).
    Mesh { mesh: u32 },
    /// An analytic shape in object space.
    Analytic(Analytic),
}

/// A placed object.
#[derive(Clone, Debug)]
pub(crate) struct Object {
    pub name: String,
    pub kind: ObjectKind,
    pub material: u32,
    pub to_world: Affine3A,
    pub to_object: Affine3A,
    /// Inverse transpose of the linear part: transforms normals.
    pub normal_matrix: Mat3A,
    /// Index of this object's first light (one per triangle for meshes), or `u32::MAX`.
    pub light_base: u32,
    /// |det| of the linear part, for area-density changes of analytic emitters.
    pub det: f32,
}

/// A top-level BVH primitive, stored in BVH slot order.
#[derive(Clone, Copy, Debug)]
enum Prim {
    Tri {
        geom: TriangleGeom,
        object: u32,
        tri: u32,
        /// The material is not opaque: hits need the alpha test.
        alpha: bool,
    },
    Analytic {
        object: u32,
    },
    Instance {
        object: u32,
    },
}

/// The per-mesh BVH of an instanced mesh (object space).
#[derive(Clone)]
struct MeshBlas {
    bvh: Bvh,
    tris: Vec<(TriangleGeom, u32)>,
    /// By leaf: its triangles packed for the 4-wide test (used for opaque instances).
    packets: Vec<Tri4>,
}

/// A material with texture references resolved to slots.
#[derive(Clone, Debug)]
pub(crate) struct Material {
    pub bsdf: BsdfDesc,
    pub slots: MaterialSlots,
    pub emission: Vec3A,
    pub two_sided: bool,
    pub alpha_mode: AlphaMode,
    /// Beer–Lambert absorption coefficient inside a solid transmissive body (per metre).
    pub absorption: Vec3A,
}

/// Texture slots of a material, resolved once.
#[derive(Clone, Debug, Default)]
pub(crate) struct MaterialSlots {
    pub base: Option<TexSlot>,
    pub metallic_roughness: Option<TexSlot>,
    pub transmission: Option<TexSlot>,
    pub emission: Option<TexSlot>,
    pub normal: Option<(TexSlot, f32)>,
}

impl MaterialSlots {
    /// Whether any texture is looked up (else shading never reads texture coordinates).
    #[inline]
    pub fn any(&self) -> bool {
        self.base.is_some()
            || self.metallic_roughness.is_some()
            || self.transmission.is_some()
            || self.emission.is_some()
            || self.normal.is_some()
    }
}

/// The nearest intersection found by [`Scene::intersect`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter.
    pub t: f32,
    /// Object index.
    pub object: u32,
    /// Triangle index within the object's mesh (0 for analytic shapes).
    pub prim: u32,
    /// Barycentric coordinate of the triangle's second vertex.
    pub b1: f32,
    /// Barycentric coordinate of the triangle's third vertex.
    pub b2: f32,
    /// BVH slot of a flattened (world-space) triangle, [`NO_SLOT`] for other primitives.
    pub(crate) slot: u32,
}

/// [`Hit::slot`] of a hit that is not a flattened triangle.
pub(crate) const NO_SLOT: u32 = u32::MAX;

/// Everything about a surface point that shading needs, in world space.
#[derive(Clone, Copy, Debug)]
pub struct Interaction {
    /// Hit point.
    pub p: Vec3A,
    /// Unit geometric normal on the object's front side.
    pub ng: Vec3A,
    /// Unit shading normal (interpolated, normal-mapped), on the same side as `ng`.
    pub ns: Vec3A,
    /// Tangent for the shading frame (may be zero).
    pub dpdu: Vec3A,
    /// Texture coordinate sets 0 and 1 (zero on meshes whose material has no texture).
    pub uv: [Vec2; 2],
    /// Ray parameter of the hit.
    pub t: f32,
    /// Object index.
    pub object: u32,
    /// Triangle index within the mesh (0 for analytic shapes).
    pub prim: u32,
}

impl Interaction {
    /// The frame BSDFs are evaluated in: Z along the shading normal. Every BSDF here is
    /// isotropic, so the frame's rotation about the normal does not matter and the cheap
    /// branchless one serves (an anisotropic BSDF would need `Frame::from_zx(ns, dpdu)`).
    #[inline]
    pub fn shading_frame(&self) -> Frame {
        Frame::from_z(self.ns)
    }
}

/// Counts describing a built scene.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SceneStats {
    /// Objects placed.
    pub objects: usize,
    /// Triangles in the top-level BVH (flattened meshes).
    pub flattened_triangles: usize,
    /// Triangles stored once for instanced meshes.
    pub instanced_triangles: usize,
    /// Lights (every emissive triangle counts).
    pub lights: usize,
}

/// A mesh triangle that emits, in world space, precomputed at build time.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LightTri {
    /// Its corners.
    pub geom: TriangleGeom,
    /// Unit geometric normal (front side).
    pub ng: Vec3A,
    /// Area.
    pub area: f32,
}

/// A scene ready to render.
pub struct Scene {
    /// World-space geometry of each mesh-triangle area light, by light index (`None` for
    /// other lights): sampling a light does no transform per sample.
    pub(crate) light_tris: Vec<Option<LightTri>>,
    pub(crate) camera: Camera,
    pub(crate) objects: Vec<Object>,
    pub(crate) meshes: Vec<Mesh>,
    blas: Vec<Option<MeshBlas>>,
    prims: Vec<Prim>,
    bvh: Bvh,
    /// By BVH leaf: its triangles packed for the 4-wide test, when the leaf holds only opaque
    /// triangles (else its primitives are tested one by one).
    packets: Vec<Option<Tri4>>,
    /// By BVH slot, for flattened triangles: the unit world-space front normal (xyz), and in w
    /// 1 when the shading normal is that normal (no vertex normals, or all three equal to it),
    /// else 0. What a hit record needs without going back to the mesh and its transform.
    tri_shading: Vec<Vec4>,
    unbounded: Vec<u32>,
    pub(crate) materials: Vec<Material>,
    pub(crate) textures: Vec<Texture>,
    pub(crate) lights: LightSet,
    pub(crate) environment: Option<Environment>,
    pub(crate) bounds: Aabb,
    /// Counts for reports and tests.
    pub stats: SceneStats,
}

fn invalid(msg: impl Into<String>) -> SceneError {
    SceneError::Invalid(msg.into())
}

fn finite3(v: Vec3) -> bool {
    v.is_finite()
}

/// Picks the camera named or numbered `sel` (the first if `None`).
pub fn select_camera<'a>(
    cameras: &'a [CameraDesc],
    sel: Option<&str>,
) -> Result<&'a CameraDesc, SceneError> {
    let names = || {
        cameras
            .iter()
            .enumerate()
            .map(|(i, c)| format!("{i}:{}", c.name))
            .collect::<Vec<_>>()
            .join(", ")
    };
    match sel {
        None => cameras
            .first()
            .ok_or_else(|| invalid("the scene has no camera")),
        Some(s) => {
            if let Some(c) = cameras.iter().find(|c| c.name == s) {
                return Ok(c);
            }
            if let Ok(i) = s.parse::<usize>() {
                if let Some(c) = cameras.get(i) {
                    return Ok(c);
                }
            }
            Err(invalid(format!(
                "no camera named or numbered '{s}' (cameras: {})",
                names()
            )))
        }
    }
}

/// A default camera framing `bounds` from +Z, for scenes without one.
pub fn default_camera(bounds: &Aabb) -> CameraDesc {
    let (center, radius) =
        if bounds.min.is_finite() && bounds.max.is_finite() && bounds.min.cmple(bounds.max).all() {
            (
                bounds.center(),
                (bounds.diagonal().length() * 0.5).max(1e-3),
            )
        } else {
            (Vec3A::ZERO, 1.0)
        };
    let yfov = 45f32.to_radians();
    let dist = radius / (yfov * 0.5).sin();
    CameraDesc {
        name: "default".into(),
        transform: Mat4::from_translation(Vec3::from(center + Vec3A::Z * dist)),
        projection: Projection::Perspective {
            yfov,
            aperture_radius: 0.0,
            focus_distance: dist,
        },
        aspect: None,
    }
}

impl Scene {
    /// Builds the scene for a render with `settings` (camera choice and image size).
    pub fn build(desc: &SceneDesc, settings: &RenderSettings) -> Result<Scene, SceneError> {
        settings
            .validate()
            .map_err(|e| invalid(format!("render setting {e}")))?;
        let textures: Vec<Texture> = desc.textures.iter().map(Texture::new).collect();
        let materials = desc
            .materials
            .iter()
            .map(|m| build_material(m, desc.textures.len()))
            .collect::<Result<Vec<_>, _>>()?;

        // Meshes: validate and convert.
        let mut meshes = Vec::with_capacity(desc.meshes.len());
        for (mi, m) in desc.meshes.iter().enumerate() {
            meshes.push(build_mesh(mi, m)?);
        }
        let mut uses = vec![0u32; meshes.len()];
        for o in &desc.objects {
            if let ShapeDesc::Mesh { mesh } = o.shape {
                if let Some(u) = uses.get_mut(mesh) {
                    *u += 1;
                }
            }
        }

        // Primitives of all the scene's BVHs together (each used mesh's triangles once, in the
        // top level or in its own tree, and at most one top-level primitive per object): picks
        // the build preset.
        let scene_prims = desc.objects.len()
            + meshes
                .iter()
                .zip(&uses)
                .filter(|(_, &u)| u > 0)
                .map(|(m, _)| m.indices.len())
                .sum::<usize>();
        let mut objects = Vec::with_capacity(desc.objects.len());
        let mut prims_unordered: Vec<(Aabb, Prim)> = Vec::new();
        let mut unbounded = Vec::new();
        let mut blas: Vec<Option<MeshBlas>> = vec![None; meshes.len()];
        let mut stats = SceneStats {
            objects: desc.objects.len(),
            ..Default::default()
        };
        for (oi, o) in desc.objects.iter().enumerate() {
            let ctx = || format!("object {oi} ('{}')", o.name);
            if o.material >= materials.len() {
                return Err(invalid(format!(
                    "{}: material index {} out of range",
                    ctx(),
                    o.material
                )));
            }
            if !o.transform.is_finite() {
                return Err(invalid(format!("{}: transform is not finite", ctx())));
            }
            let to_world = Affine3A::from_mat4(o.transform);
            let det = to_world.matrix3.determinant();
            if !(det.abs() > 1e-12) || !det.is_finite() {
                return Err(invalid(format!("{}: transform is singular", ctx())));
            }
            let to_object = to_world.inverse();
            let normal_matrix = to_object.matrix3.transpose();
            let kind = match &o.shape {
                ShapeDesc::Mesh { mesh } => {
                    let mesh_i = *mesh;
                    let m = meshes.get(mesh_i).ok_or_else(|| {
                        invalid(format!("{}: mesh index {mesh_i} out of range", ctx()))
                    })?;
                    let flattened = uses[mesh_i] <= 1;
                    if flattened {
                        let needs_alpha = materials[o.material].alpha_mode != AlphaMode::Opaque;
                        for (ti, _) in m.indices.iter().enumerate() {
                            let c = m.corners(ti).map(|v| to_world.transform_point3a(v));
                            let geom = TriangleGeom::new(c);
                            prims_unordered.push((
                                Aabb::from_points(&c),
                                Prim::Tri {
                                    geom,
                                    object: oi as u32,
                                    tri: ti as u32,
                                    alpha: needs_alpha,
                                },
                            ));
                        }
                        stats.flattened_triangles += m.indices.len();
                    } else {
                        if blas[mesh_i].is_none() {
                            blas[mesh_i] = Some(build_blas(m, scene_prims));
                            stats.instanced_triangles += m.indices.len();
                        }
                        let mut b = Aabb::empty();
                        for v in &m.positions {
                            b.extend(to_world.transform_point3a(*v));
                        }
                        if !m.indices.is_empty() {
                            prims_unordered.push((b, Prim::Instance { object: oi as u32 }));
                        }
                    }
                    ObjectKind::Mesh {
                        mesh: mesh_i as u32,
                    }
                }
                shape => {
                    let a =
                        build_analytic(shape).map_err(|e| invalid(format!("{}: {e}", ctx())))?;
                    match a.bounds() {
                        Some(b) => prims_unordered.push((
                            transform_aabb(&to_world, &b),
                            Prim::Analytic { object: oi as u32 },
                        )),
                        None => unbounded.push(oi as u32),
                    }
                    ObjectKind::Analytic(a)
                }
            };
            objects.push(Object {
                name: o.name.clone(),
                kind,
                material: o.material as u32,
                to_world,
                to_object,
                normal_matrix,
                light_base: u32::MAX,
                det: det.abs(),
            });
        }

        let bounds_list: Vec<Aabb> = prims_unordered.iter().map(|(b, _)| *b).collect();
        let mut bounds = Aabb::empty();
        for b in &bounds_list {
            bounds = bounds.union(b);
        }
        let (bvh, order) = Bvh::build_in_scene(&bounds_list, scene_prims);
        let prims: Vec<Prim> = order
            .iter()
            .map(|&i| prims_unordered[i as usize].1)
            .collect();
        let packets = leaf_packets(&bvh, &prims);
        let tri_shading = prims
            .iter()
            .map(|p| match *p {
                Prim::Tri { object, tri, .. } => {
                    let o = &objects[object as usize];
                    let ObjectKind::Mesh { mesh } = o.kind else {
                        unreachable!("triangles belong to meshes");
                    };
                    tri_shading(o, &meshes[mesh as usize], tri)
                }
                _ => Vec4::ZERO,
            })
            .collect();

        // Camera.
        let camera_desc = if desc.cameras.is_empty() && settings.camera.is_none() {
            default_camera(&bounds)
        } else {
            select_camera(&desc.cameras, settings.camera.as_deref())?.clone()
        };
        let camera = Camera::new(&camera_desc, settings.width, settings.height);

        let scene_radius = if bounds.min.cmple(bounds.max).all() {
            (bounds.diagonal().length() * 0.5).max(1e-3)
        } else {
            1.0
        };

        // Lights.
        let mut lights = Vec::new();
        let mut light_tris: Vec<Option<LightTri>> = Vec::new();
        for (li, l) in desc.lights.iter().enumerate() {
            lights.push(build_light(l).map_err(|e| invalid(format!("light {li}: {e}")))?);
        }
        for (oi, o) in objects.iter_mut().enumerate() {
            let mat = &materials[o.material as usize];
            if mat.emission.max_element() <= 0.0 {
                continue;
            }
            let scale = if mat.two_sided { 2.0 * PI } else { PI };
            let lum = luminance(mat.emission);
            match &o.kind {
                ObjectKind::Mesh { mesh, .. } => {
                    o.light_base = lights.len() as u32;
                    let m = &meshes[*mesh as usize];
                    for ti in 0..m.indices.len() {
                        let local = TriangleGeom::new(m.corners(ti));
                        let geom = TriangleGeom::new(
                            m.corners(ti).map(|v| o.to_world.transform_point3a(v)),
                        );
                        let area = 0.5 * geom.normal().length();
                        light_tris.resize(lights.len(), None);
                        light_tris.push(Some(LightTri {
                            geom,
                            ng: (o.normal_matrix * local.normal()).normalize_or(Vec3A::Y),
                            area,
                        }));
                        lights.push(Light::Area {
                            object: oi as u32,
                            prim: ti as u32,
                            power: lum * area * scale,
                        });
                    }
                }
                ObjectKind::Analytic(a) => {
                    if a.sample(Vec2::splat(0.5)).is_none() {
                        return Err(invalid(format!(
                            "object {oi} ('{}'): this shape cannot be an area light (planes and quadrics cannot be sampled); use a mesh, sphere, box, disk, rectangle or polygon",
                            o.name
                        )));
                    }
                    o.light_base = lights.len() as u32;
                    // World area estimate: object area scaled by |det|^(2/3) (exact for uniform scale).
                    let area = a.area() * o.det.powf(2.0 / 3.0);
                    lights.push(Light::Area {
                        object: oi as u32,
                        prim: 0,
                        power: lum * area * scale,
                    });
                }
            }
        }
        let environment = if desc.default_environment && !settings.default_light {
            None
        } else {
            desc.environment.as_ref().map(Environment::new)
        };
        let env_power = environment.as_ref().map_or(0.0, |e| e.power(scene_radius));
        if environment.is_some() {
            lights.push(Light::Environment);
        }
        stats.lights = lights.len();
        light_tris.resize(lights.len(), None);
        let lights = LightSet::new(lights, scene_radius, env_power);

        Ok(Scene {
            light_tris,
            camera,
            objects,
            meshes,
            blas,
            prims,
            bvh,
            packets,
            tri_shading,
            unbounded,
            materials,
            textures,
            lights,
            environment,
            bounds,
            stats,
        })
    }

    /// World bounds of all bounded geometry.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The camera.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Nearest hit along `ray` with parameter in (0, tmax).
    #[inline]
    pub fn intersect(&self, ray: &Ray, tmax: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut tmax = tmax;
        for &oi in &self.unbounded {
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
        let mut cand = None;
        let found = self
            .bvh
            .closest_leaves(ray, tmax, |leaf, start, count, tmax| {
                if let Some(p) = &self.packets[leaf as usize] {
                    let (lane, t, b1, b2) = p.intersect(ray.o, ray.d, 0.0, tmax)?;
                    let slot = start as usize + lane;
                    let Prim::Tri { object, tri, .. } = self.prims[slot] else {
                        unreachable!("packets hold triangles only");
                    };
                    cand = Some(Hit {
                        t,
                        object,
                        prim: tri,
                        b1,
                        b2,
                        slot: slot as u32,
                    });
                    return Some((slot, t));
                }
                let mut tmax = tmax;
                let mut best = None;
                for slot in start as usize..(start + count) as usize {
                    if let Some(h) = self.intersect_prim(slot, ray, tmax) {
                        tmax = h.t;
                        cand = Some(h);
                        best = Some((slot, h.t));
                    }
                }
                best
            });
        // `cand` holds the latest accepted hit, which is the nearest: each accepted hit
        // shrinks tmax, so later candidates are always closer.
        if found.is_some() {
            best = cand;
        }
        best
    }

    /// The hit of primitive `slot` within (0, tmax), if any.
    #[inline]
    fn intersect_prim(&self, slot: usize, ray: &Ray, tmax: f32) -> Option<Hit> {
        match self.prims[slot] {
            Prim::Tri {
                geom,
                object,
                tri,
                alpha,
            } => {
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
        for &oi in &self.unbounded {
            if self.intersect_analytic(oi, ray, tmax).is_some() {
                return true;
            }
        }
        self.bvh.any_leaves(ray, tmax, |leaf, start, count| {
            match &self.packets[leaf as usize] {
                Some(p) => p.any(ray.o, ray.d, 0.0, tmax),
                None => {
                    (start as usize..(start + count) as usize).any(|slot| match self.prims[slot] {
                        Prim::Tri {
                            geom,
                            object,
                            tri,
                            alpha,
                        } => match geom.intersect(ray.o, ray.d, 0.0, tmax) {
                            Some((t, b1, b2)) => {
                                !alpha || self.alpha_passes(object, tri, b1, b2, t)
                            }
                            None => false,
                        },
                        Prim::Analytic { object } => {
                            self.intersect_analytic(object, ray, tmax).is_some()
                        }
                        Prim::Instance { object } => {
                            self.intersect_instance(object, ray, tmax).is_some()
                        }
                    })
                }
            }
        })
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

    // Out of line: inlined, it made the common (non-instanced) path about 10 % slower.
    #[inline(never)]
    fn intersect_instance(&self, object: u32, ray: &Ray, tmax: f32) -> Option<Hit> {
        let o = &self.objects[object as usize];
        let ObjectKind::Mesh { mesh, .. } = o.kind else {
            return None;
        };
        let blas = self.blas[mesh as usize].as_ref()?;
        let local = Ray::new(
            o.to_object.transform_point3a(ray.o),
            o.to_object.transform_vector3a(ray.d),
        );
        let mut cand = None;
        if self.material_of(object).alpha_mode == AlphaMode::Opaque {
            let (slot, t) = blas
                .bvh
                .closest_leaves(&local, tmax, |leaf, start, _, tmax| {
                    let (lane, t, b1, b2) =
                        blas.packets[leaf as usize].intersect(local.o, local.d, 0.0, tmax)?;
                    let slot = start as usize + lane;
                    cand = Some((b1, b2));
                    Some((slot, t))
                })?;
            let (b1, b2) = cand?;
            return Some(Hit {
                t,
                object,
                prim: blas.tris[slot].1,
                b1,
                b2,
                slot: NO_SLOT,
            });
        }
        let mut cand = None;
        blas.bvh.closest(&local, tmax, |slot, tmax| {
            let (geom, tri) = blas.tris[slot];
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
                    t
                }
                _ => f32::INFINITY,
            }
        })?;
        cand
    }

    /// Alpha test for MASK (cutoff) and BLEND (hashed stochastic transparency: a deterministic
    /// random threshold from the primitive and the hit distance).
    #[inline]
    fn alpha_passes(&self, object: u32, tri: u32, b1: f32, b2: f32, t: f32) -> bool {
        let o = &self.objects[object as usize];
        let mat = &self.materials[o.material as usize];
        let threshold = match mat.alpha_mode {
            AlphaMode::Opaque => return true,
            AlphaMode::Mask(cutoff) => cutoff,
            AlphaMode::Blend => {
                let h = hash_u32(hash_u32(object ^ tri.rotate_left(16)) ^ t.to_bits());
                (h >> 8) as f32 / (1u32 << 24) as f32
            }
        };
        let ObjectKind::Mesh { mesh, .. } = o.kind else {
            return true;
        };
        let uvs = self.mesh_uvs(&self.meshes[mesh as usize], tri, b1, b2);
        let alpha = self.base_color(mat, &uvs).w;
        match mat.alpha_mode {
            AlphaMode::Mask(_) => alpha >= threshold,
            _ => alpha > threshold,
        }
    }

    fn mesh_uvs(&self, m: &Mesh, tri: u32, b1: f32, b2: f32) -> [Vec2; 2] {
        let [a, b, c] = m.indices[tri as usize];
        let b0 = 1.0 - b1 - b2;
        let get = |set: &Vec<Vec2>| {
            if set.is_empty() {
                Vec2::new(b1, b2)
            } else {
                set[a as usize] * b0 + set[b as usize] * b1 + set[c as usize] * b2
            }
        };
        [get(&m.uvs[0]), get(&m.uvs[1])]
    }

    /// Base colour (linear RGBA) of a material at a point.
    #[inline]
    pub(crate) fn base_color(&self, mat: &Material, uvs: &[Vec2; 2]) -> Vec4 {
        let factor = match &mat.bsdf {
            BsdfDesc::Pbr(p) => Vec4::from(p.base_color),
            BsdfDesc::Diffuse { albedo, .. } => albedo.extend(1.0),
            _ => Vec4::ONE,
        };
        match mat.slots.base {
            Some(s) => factor * s.lookup(&self.textures, uvs),
            None => factor,
        }
    }

    /// Full surface details for a hit of `ray`.
    pub fn interaction(&self, ray: &Ray, hit: &Hit) -> Interaction {
        let o = &self.objects[hit.object as usize];
        match &o.kind {
            ObjectKind::Analytic(a) => {
                let lo = o.to_object.transform_point3a(ray.o);
                let ld = o.to_object.transform_vector3a(ray.d);
                let lh = a.hit(lo, ld, hit.t);
                let n = (o.normal_matrix * lh.n).normalize_or(Vec3A::Y);
                let dpdu = o.to_world.transform_vector3a(lh.dpdu);
                Interaction {
                    p: o.to_world.transform_point3a(lh.p),
                    ng: n,
                    ns: n,
                    dpdu,
                    uv: [lh.uv, lh.uv],
                    t: hit.t,
                    object: hit.object,
                    prim: 0,
                }
            }
            ObjectKind::Mesh { mesh, .. } => {
                self.mesh_interaction(o, &self.meshes[*mesh as usize], hit)
            }
        }
    }

    fn mesh_interaction(&self, o: &Object, m: &Mesh, hit: &Hit) -> Interaction {
        let mat = &self.materials[o.material as usize];
        let (b1, b2) = (hit.b1, hit.b2);
        // Texture coordinates only for materials that look textures up (nothing else reads them).
        let uv = if mat.slots.any() {
            self.mesh_uvs(m, hit.prim, b1, b2)
        } else {
            [Vec2::ZERO; 2]
        };
        // A flattened triangle: its world-space corners and normal are at hand (the BVH slot).
        if let Some(Prim::Tri { geom, .. }) = self.prims.get(hit.slot as usize) {
            let shading = self.tri_shading[hit.slot as usize];
            if shading.w != 0.0 && mat.slots.normal.is_none() {
                let ng = Vec3A::from_vec4(shading);
                return Interaction {
                    p: geom.point(b1, b2),
                    ng,
                    ns: ng,
                    // Shading frames need no tangent (every BSDF is isotropic); only normal
                    // mapping does, and it takes the path below.
                    dpdu: geom.e1,
                    uv,
                    t: hit.t,
                    object: hit.object,
                    prim: hit.prim,
                };
            }
        }
        let [ia, ib, ic] = m.indices[hit.prim as usize];
        let b0 = 1.0 - b1 - b2;
        let [p0, p1, p2] = m.corners(hit.prim as usize);
        let geom = TriangleGeom::new([p0, p1, p2]);
        // Point from barycentrics in object space, then to world: accurate to a few ulps.
        let p = o.to_world.transform_point3a(geom.point(b1, b2));
        // The inverse transpose maps the object-space front normal to the world front side even
        // when the transform mirrors (a mirrored winding flips e1×e2 in world space, not this).
        let ng = (o.normal_matrix * geom.normal()).normalize_or(Vec3A::Y);
        let mut ns = if m.normals.is_empty() {
            ng
        } else {
            let n = m.normals[ia as usize] * b0
                + m.normals[ib as usize] * b1
                + m.normals[ic as usize] * b2;
            let n = (o.normal_matrix * n).normalize_or(ng);
            if n.is_finite() {
                n
            } else {
                ng
            }
        };
        // Tangent: from vertex tangents, else from the uv parameterisation.
        let mut tangent_sign = 1.0;
        let dpdu_obj = if !m.tangents.is_empty() {
            let t = |i: u32| {
                let [x, y, z, w] = m.tangents[i as usize];
                (Vec3A::new(x, y, z), w)
            };
            let (ta, wa) = t(ia);
            tangent_sign = if wa < 0.0 { -1.0 } else { 1.0 };
            ta * b0 + t(ib).0 * b1 + t(ic).0 * b2
        } else if !m.uvs[0].is_empty() {
            let (uv0, uv1, uv2) = (
                m.uvs[0][ia as usize],
                m.uvs[0][ib as usize],
                m.uvs[0][ic as usize],
            );
            let (d1, d2) = (uv1 - uv0, uv2 - uv0);
            let det = d1.x * d2.y - d1.y * d2.x;
            if det.abs() > 1e-12 {
                (geom.e1 * d2.y - geom.e2 * d1.y) / det
            } else {
                geom.e1
            }
        } else {
            geom.e1
        };
        let dpdu = o.to_world.transform_vector3a(dpdu_obj);
        if let Some((slot, scale)) = mat.slots.normal {
            let tex = slot.lookup(&self.textures, &uv);
            let tn = Vec3A::new(
                (tex.x * 2.0 - 1.0) * scale,
                (tex.y * 2.0 - 1.0) * scale,
                tex.z * 2.0 - 1.0,
            );
            let frame = Frame::from_zx(ns, dpdu);
            let bitangent = frame.y * tangent_sign;
            let mapped = (frame.x * tn.x + bitangent * tn.y + ns * tn.z).normalize_or(ns);
            if mapped.is_finite() {
                ns = mapped;
            }
        }
        if ns.dot(ng) < 0.0 {
            // Interpolated normals disagreeing with the winding: the winding defines the front
            // side (glTF), so bring the shading normal over to it.
            ns = -ns;
        }
        Interaction {
            p,
            ng,
            ns,
            dpdu,
            uv,
            t: hit.t,
            object: hit.object,
            prim: hit.prim,
        }
    }

    /// The material of object `object`.
    #[inline]
    pub(crate) fn material_of(&self, object: u32) -> &Material {
        &self.materials[self.objects[object as usize].material as usize]
    }

    /// Radiance emitted from `it` towards `wo` (unit, pointing away from the surface).
    #[inline]
    pub fn emitted(&self, it: &Interaction, wo: Vec3A) -> Vec3A {
        let mat = self.material_of(it.object);
        if mat.emission.max_element() <= 0.0 {
            return Vec3A::ZERO;
        }
        if !mat.two_sided && it.ng.dot(wo) <= 0.0 {
            return Vec3A::ZERO;
        }
        match mat.slots.emission {
            Some(s) => {
                let c = s.lookup(&self.textures, &it.uv);
                mat.emission * Vec3A::new(c.x, c.y, c.z)
            }
            None => mat.emission,
        }
    }

    /// The BSDF at `it`, with every texture looked up.
    #[inline]
    pub fn bsdf(&self, it: &Interaction) -> Bsdf {
        let mat = self.material_of(it.object);
        match &mat.bsdf {
            BsdfDesc::Diffuse { .. } => {
                let c = self.base_color(mat, &it.uv);
                Bsdf::Diffuse(material::diffuse::Diffuse {
                    albedo: Vec3A::new(c.x, c.y, c.z).clamp(Vec3A::ZERO, Vec3A::ONE),
                })
            }
            BsdfDesc::Mirror { reflectance } => Bsdf::Mirror(material::mirror::Mirror {
                reflectance: Vec3A::from(*reflectance),
            }),
            BsdfDesc::Dielectric {
                ior,
                transmittance,
                thin,
                ..
            } => Bsdf::Dielectric(material::dielectric::Dielectric {
                eta: *ior,
                transmittance: Vec3A::from(*transmittance),
                thin: *thin,
            }),
            BsdfDesc::Conductor { eta, k, alpha } => {
                Bsdf::Conductor(material::conductor::Conductor {
                    eta: Vec3A::from(*eta),
                    k: Vec3A::from(*k),
                    alpha: *alpha,
                })
            }
            BsdfDesc::RoughDielectric {
                ior,
                alpha,
                transmittance,
            } => Bsdf::RoughDielectric(material::rough_dielectric::RoughDielectric {
                eta: *ior,
                alpha: *alpha,
                transmittance: Vec3A::from(*transmittance),
            }),
            BsdfDesc::Pbr(p) => {
                let c = self.base_color(mat, &it.uv);
                let (mut metallic, mut roughness) = (p.metallic, p.roughness);
                if let Some(s) = mat.slots.metallic_roughness {
                    let t = s.lookup(&self.textures, &it.uv);
                    roughness *= t.y;
                    metallic *= t.z;
                }
                let mut transmission = p.transmission;
                if let Some(s) = mat.slots.transmission {
                    transmission *= s.lookup(&self.textures, &it.uv).x;
                }
                let base_color = Vec3A::new(c.x, c.y, c.z).clamp(Vec3A::ZERO, Vec3A::ONE);
                if !(metallic > 0.0)
                    && !(p.specular > 0.0)
                    && !(transmission > 0.0)
                    && !(p.clearcoat > 0.0)
                {
                    // No metal, no specular lobe (KHR_materials_specular factor 0), no
                    // transmission, no coat: the model is exactly Lambertian, bit for bit
                    // (material test `pbr_without_specular_is_exactly_lambertian`), and the
                    // Lambertian BSDF computes it for a fraction of the cost.
                    return Bsdf::Diffuse(material::diffuse::Diffuse { albedo: base_color });
                }
                let roughness = roughness.clamp(0.0, 1.0);
                Bsdf::Pbr(material::pbr::Pbr {
                    base_color,
                    metallic: metallic.clamp(0.0, 1.0),
                    alpha: roughness * roughness,
                    specular: p.specular.clamp(0.0, 1.0),
                    specular_color: Vec3A::from(p.specular_color).max(Vec3A::ZERO),
                    ior: p.ior,
                    transmission: transmission.clamp(0.0, 1.0),
                    thin: p.thin_walled,
                    clearcoat: p.clearcoat.clamp(0.0, 1.0),
                    clearcoat_alpha: p.clearcoat_roughness * p.clearcoat_roughness,
                })
            }
        }
    }

    /// Samples a point on area light `light` (object + triangle) as seen from `p`:
    /// (point, front normal, emitted radiance towards p, solid-angle pdf).
    #[inline]
    pub(crate) fn sample_area(
        &self,
        object: u32,
        prim: u32,
        p: Vec3A,
        u: Vec2,
    ) -> Option<(Vec3A, Vec3A, Vec3A, f32)> {
        let o = &self.objects[object as usize];
        let (it, pdf_area) = match &o.kind {
            ObjectKind::Mesh { mesh, .. } => {
                let m = &self.meshes[*mesh as usize];
                let (b1, b2) = crate::sampling::warp::uniform_triangle(u);
                // Only what emission needs: point, front normal, and uv if it is textured.
                let lt = self.light_tris[(o.light_base + prim) as usize].as_ref()?;
                let (geom, ng, area) = (&lt.geom, lt.ng, lt.area);
                let textured = self.materials[o.material as usize].slots.emission.is_some();
                let uv = if textured {
                    self.mesh_uvs(m, prim, b1, b2)
                } else {
                    [Vec2::ZERO; 2]
                };
                let it = Interaction {
                    p: geom.point(b1, b2),
                    ng,
                    ns: ng,
                    dpdu: Vec3A::ZERO,
                    uv,
                    t: 0.0,
                    object,
                    prim,
                };
                (it, 1.0 / area)
            }
            ObjectKind::Analytic(a) => {
                let s = a.sample(u)?;
                let n_world = o.normal_matrix * s.n;
                // Area scale of the affine map for a surface element with normal n: |det|·|M⁻ᵀn|.
                let jac = o.det * n_world.length();
                let n = n_world.normalize_or(Vec3A::Y);
                let it = Interaction {
                    p: o.to_world.transform_point3a(s.p),
                    ng: n,
                    ns: n,
                    dpdu: Vec3A::ZERO,
                    uv: [Vec2::ZERO; 2],
                    t: 0.0,
                    object,
                    prim: 0,
                };
                (it, s.pdf_area / jac)
            }
        };
        let to = it.p - p;
        let d2 = to.length_squared();
        if !(d2 > 0.0) || !(pdf_area > 0.0) || !pdf_area.is_finite() {
            return None;
        }
        let wi = to / d2.sqrt();
        let le = self.emitted(&it, -wi);
        let cos_l = it.ng.dot(-wi).abs();
        let pdf = crate::light::area_to_solid_angle(pdf_area, d2, cos_l);
        if pdf <= 0.0 || !pdf.is_finite() {
            return None;
        }
        Some((it.p, it.ng, le, pdf))
    }

    /// Solid-angle density with which light sampling (selection included) would have produced
    /// the point `it` on an emitter seen from `from`.
    #[inline]
    pub(crate) fn area_light_pdf(&self, it: &Interaction, from: Vec3A) -> f32 {
        let o = &self.objects[it.object as usize];
        if o.light_base == u32::MAX {
            return 0.0;
        }
        let li = o.light_base
            + if matches!(o.kind, ObjectKind::Mesh { .. }) {
                it.prim
            } else {
                0
            };
        let pmf = self.lights.pmf(li as usize);
        let pdf_area = match &o.kind {
            ObjectKind::Mesh { .. } => match &self.light_tris[li as usize] {
                Some(lt) => 1.0 / lt.area,
                None => return 0.0,
            },
            ObjectKind::Analytic(a) => {
                let n_obj = o.to_world.matrix3.transpose() * it.ng;
                // |M⁻ᵀ n_obj| with n_obj unit: recover from the world normal.
                let n_obj = n_obj.normalize_or(Vec3A::Y);
                let jac = o.det * (o.normal_matrix * n_obj).length();
                1.0 / (a.area() * jac)
            }
        };
        let to = it.p - from;
        pmf * crate::light::area_to_solid_angle(
            pdf_area,
            to.length_squared(),
            it.ng.dot(to.normalize_or_zero()),
        )
    }

    /// Absorption coefficient of the body behind the surface of `object` (zero if none).
    #[inline]
    pub(crate) fn absorption(&self, object: u32) -> Vec3A {
        self.material_of(object).absorption
    }
}

/// [`Scene::tri_shading`] of triangle `tri` of `m` placed by `o`: the unit world front normal,
/// and whether the shading normal is that normal (w = 1).
fn tri_shading(o: &Object, m: &Mesh, tri: u32) -> Vec4 {
    let geom = TriangleGeom::new(m.corners(tri as usize));
    // As in `mesh_interaction`: the inverse transpose keeps the object's front side.
    let ng = (o.normal_matrix * geom.normal()).normalize_or(Vec3A::Y);
    let flat = m.normals.is_empty() || {
        // Vertex normals all along the face normal (all on one side: a mirrored winding flips
        // them all, and shading brings them back): interpolating them gives the face normal.
        let dots = m.indices[tri as usize].map(|i| {
            (o.normal_matrix * m.normals[i as usize])
                .normalize_or_zero()
                .dot(ng)
        });
        dots.iter().all(|&d| d >= 1.0 - 1e-6) || dots.iter().all(|&d| d <= -(1.0 - 1e-6))
    };
    ng.extend(if flat { 1.0 } else { 0.0 })
}

/// For each BVH leaf, its triangles packed four-wide when the leaf holds only opaque triangles.
fn leaf_packets(bvh: &Bvh, prims: &[Prim]) -> Vec<Option<Tri4>> {
    bvh.leaves()
        .iter()
        .map(|&(start, count)| {
            let range = &prims[start as usize..(start + count) as usize];
            let geoms: Option<Vec<TriangleGeom>> = range
                .iter()
                .map(|p| match *p {
                    Prim::Tri {
                        geom, alpha: false, ..
                    } => Some(geom),
                    _ => None,
                })
                .collect();
            geoms.filter(|g| g.len() <= 4).map(|g| Tri4::new(&g))
        })
        .collect()
}

fn build_blas(m: &Mesh, scene_prims: usize) -> MeshBlas {
    let geoms: Vec<(TriangleGeom, u32)> = (0..m.indices.len())
        .map(|i| (TriangleGeom::new(m.corners(i)), i as u32))
        .collect();
    let bounds: Vec<Aabb> = (0..m.indices.len())
        .map(|i| Aabb::from_points(&m.corners(i)))
        .collect();
    let (bvh, order) = Bvh::build_in_scene(&bounds, scene_prims);
    let tris: Vec<(TriangleGeom, u32)> = order.iter().map(|&i| geoms[i as usize]).collect();
    let packets = bvh
        .leaves()
        .iter()
        .map(|&(start, count)| {
            let leaf: Vec<TriangleGeom> = tris[start as usize..(start + count) as usize]
                .iter()
                .map(|t| t.0)
                .collect();
            Tri4::new(&leaf)
        })
        .collect();
    MeshBlas { bvh, tris, packets }
}

fn transform_aabb(m: &Affine3A, b: &Aabb) -> Aabb {
    let mut out = Aabb::empty();
    for i in 0..8 {
        let c = Vec3A::new(
            if i & 1 == 0 { b.min.x } else { b.max.x },
            if i & 2 == 0 { b.min.y } else { b.max.y },
            if i & 4 == 0 { b.min.z } else { b.max.z },
        );
        out.extend(m.transform_point3a(c));
    }
    out
}

fn build_mesh(mi: usize, m: &super::desc::MeshDesc) -> Result<Mesh, SceneError> {
    let ctx = || format!("mesh {mi} ('{}')", m.name);
    let n = m.positions.len();
    if m.positions.iter().any(|p| !finite3(*p)) {
        return Err(invalid(format!(
            "{}: a vertex position is NaN or infinite",
            ctx()
        )));
    }
    if !m.normals.is_empty() && m.normals.len() != n {
        return Err(invalid(format!(
            "{}: {} normals for {n} vertices",
            ctx(),
            m.normals.len()
        )));
    }
    for (k, set) in m.uvs.iter().enumerate() {
        if !set.is_empty() && set.len() != n {
            return Err(invalid(format!(
                "{}: {} uvs in set {k} for {n} vertices",
                ctx(),
                set.len()
            )));
        }
    }
    if !m.tangents.is_empty() && m.tangents.len() != n {
        return Err(invalid(format!(
            "{}: {} tangents for {n} vertices",
            ctx(),
            m.tangents.len()
        )));
    }
    if let Some(bad) = m.indices.iter().flatten().find(|&&i| i as usize >= n) {
        return Err(invalid(format!(
            "{}: index {bad} out of range ({n} vertices)",
            ctx()
        )));
    }
    // Degenerate triangles cannot be hit and would give NaN normals: drop them.
    let positions: Vec<Vec3A> = m.positions.iter().map(|&p| p.into()).collect();
    let indices = m
        .indices
        .iter()
        .copied()
        .filter(|&[a, b, c]| {
            let (a, b, c) = (
                positions[a as usize],
                positions[b as usize],
                positions[c as usize],
            );
            (b - a).cross(c - a).length_squared() > 0.0
        })
        .collect();
    let clean_normal = |v: &Vec3| {
        let v = Vec3A::from(*v);
        if v.is_finite() && v.length_squared() > 0.0 {
            v.normalize()
        } else {
            Vec3A::ZERO
        }
    };
    Ok(Mesh {
        name: m.name.clone(),
        positions,
        normals: m.normals.iter().map(clean_normal).collect(),
        tangents: m.tangents.clone(),
        uvs: [m.uvs[0].clone(), m.uvs[1].clone()],
        indices,
    })
}

fn build_analytic(shape: &ShapeDesc) -> Result<Analytic, String> {
    let v = |x: Vec3| Vec3A::from(x);
    let finite = |ok: bool| {
        if ok {
            Ok(())
        } else {
            Err("shape parameters must be finite".to_string())
        }
    };
    Ok(match shape {
        ShapeDesc::Sphere { center, radius } => {
            finite(center.is_finite() && radius.is_finite())?;
            if *radius <= 0.0 {
                return Err(format!("sphere radius must be positive, got {radius}"));
            }
            Analytic::Sphere(sphere::Sphere {
                center: v(*center),
                radius: *radius,
            })
        }
        ShapeDesc::Box { min, max } => {
            finite(min.is_finite() && max.is_finite())?;
            if !min.cmplt(*max).all() {
                return Err("box min must be below max on every axis".into());
            }
            Analytic::AaBox(aabox::AaBox {
                min: v(*min),
                max: v(*max),
            })
        }
        ShapeDesc::Plane { point, normal } => {
            finite(point.is_finite() && normal.is_finite())?;
            let n = normal.normalize_or_zero();
            if n == Vec3::ZERO {
                return Err("plane normal must be non-zero".into());
            }
            Analytic::Plane(plane::Plane {
                point: v(*point),
                normal: v(n),
            })
        }
        ShapeDesc::Disk {
            center,
            normal,
            radius,
        } => {
            finite(center.is_finite() && normal.is_finite() && radius.is_finite())?;
            let n = normal.normalize_or_zero();
            if n == Vec3::ZERO || *radius <= 0.0 {
                return Err("disk needs a non-zero normal and a positive radius".into());
            }
            Analytic::Disk(plane::Disk {
                center: v(*center),
                normal: v(n),
                radius: *radius,
            })
        }
        ShapeDesc::Rectangle {
            corner,
            edge_u,
            edge_v,
        } => {
            finite(corner.is_finite() && edge_u.is_finite() && edge_v.is_finite())?;
            if edge_u.cross(*edge_v).length_squared() <= 0.0 {
                return Err("rectangle edges must not be parallel or zero".into());
            }
            Analytic::Rectangle(plane::Rectangle {
                corner: v(*corner),
                edge_u: v(*edge_u),
                edge_v: v(*edge_v),
            })
        }
        ShapeDesc::Polygon { vertices } => Analytic::Polygon(polygon::Polygon::new(
            vertices.iter().map(|&p| v(p)).collect(),
        )?),
        ShapeDesc::Quadric {
            q,
            clip_min,
            clip_max,
        } => Analytic::Quadric(quadric::Quadric::new(*q, v(*clip_min), v(*clip_max))?),
        ShapeDesc::Mesh { .. } => unreachable!("meshes are handled by the caller"),
    })
}

fn build_light(l: &super::desc::LightDesc) -> Result<Light, String> {
    use super::desc::LightDesc;
    let ok = |v: Vec3| {
        if v.is_finite() {
            Ok(Vec3A::from(v))
        } else {
            Err("light parameters must be finite".to_string())
        }
    };
    let dir = |v: Vec3| {
        let d = v.normalize_or_zero();
        if d == Vec3::ZERO || !d.is_finite() {
            Err("light direction must be non-zero and finite".to_string())
        } else {
            Ok(Vec3A::from(d))
        }
    };
    let range = |r: f32| {
        if r > 0.0 {
            Ok(r)
        } else {
            Err(format!("light range must be positive, got {r}"))
        }
    };
    Ok(match *l {
        LightDesc::Point {
            position,
            intensity,
            range: r,
        } => Light::Point {
            position: ok(position)?,
            intensity: ok(intensity)?.max(Vec3A::ZERO),
            range: range(r)?,
        },
        LightDesc::Spot {
            position,
            direction,
            intensity,
            inner_angle,
            outer_angle,
            range: r,
        } => {
            let outer = outer_angle.clamp(0.0, PI * 0.5);
            let inner = inner_angle.clamp(0.0, outer);
            Light::Spot {
                position: ok(position)?,
                axis: dir(direction)?,
                intensity: ok(intensity)?.max(Vec3A::ZERO),
                cos_inner: inner.cos(),
                cos_outer: outer.cos(),
                range: range(r)?,
            }
        }
        LightDesc::Directional {
            direction,
            irradiance,
        } => Light::Directional {
            to_light: -dir(direction)?,
            irradiance: ok(irradiance)?.max(Vec3A::ZERO),
        },
    })
}

fn build_material(m: &MaterialDesc, n_textures: usize) -> Result<Material, SceneError> {
    let check = |r: &Option<super::desc::TextureRef>| -> Result<Option<TexSlot>, SceneError> {
        match r {
            Some(r) if r.texture >= n_textures => Err(invalid(format!(
                "material '{}': texture index {} out of range",
                m.name, r.texture
            ))),
            Some(r) => Ok(Some(TexSlot::from(r))),
            None => Ok(None),
        }
    };
    let mut slots = MaterialSlots {
        emission: check(&m.emission_texture)?,
        normal: match &m.normal_texture {
            Some((r, s)) => check(&Some(*r))?.map(|t| (t, *s)),
            None => None,
        },
        ..Default::default()
    };
    let mut absorption = Vec3A::ZERO;
    match &m.bsdf {
        BsdfDesc::Diffuse { texture, .. } => slots.base = check(texture)?,
        BsdfDesc::Dielectric {
            absorption: a,
            thin,
            ..
        } if !thin => absorption = Vec3A::from(*a).max(Vec3A::ZERO),
        BsdfDesc::Pbr(p) => {
            slots.base = check(&p.base_color_texture)?;
            slots.metallic_roughness = check(&p.metallic_roughness_texture)?;
            slots.transmission = check(&p.transmission_texture)?;
            if !p.thin_walled
                && p.transmission > 0.0
                && p.attenuation_distance.is_finite()
                && p.attenuation_distance > 0.0
            {
                let c = Vec3A::from(p.attenuation_color).clamp(Vec3A::splat(1e-6), Vec3A::ONE);
                absorption = Vec3A::new(-c.x.ln(), -c.y.ln(), -c.z.ln()) / p.attenuation_distance;
            }
        }
        _ => {}
    }
    if !m.emission.is_finite() {
        return Err(invalid(format!(
            "material '{}': emission is not finite",
            m.name
        )));
    }
    Ok(Material {
        bsdf: m.bsdf.clone(),
        slots,
        emission: Vec3A::from(m.emission).max(Vec3A::ZERO),
        two_sided: m.two_sided,
        alpha_mode: m.alpha_mode,
        absorption,
    })
}

impl std::fmt::Debug for Scene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene")
            .field("stats", &self.stats)
            .field("bounds", &self.bounds)
            .finish_non_exhaustive()
    }
}
