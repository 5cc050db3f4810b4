//! The scene builder: turns a [`SceneDesc`] into the render-ready [`Scene`] (pbrt-v4's
//! `BasicScene`: descriptions in, lights, materials and the aggregate out, once). Everything is
//! checked here; nothing at render time reads a description.
//!
//! What it makes: meshes validated (degenerate triangles dropped), objects placed, the
//! aggregate ([`super::aggregate`]: single-use meshes flattened into world-space triangles,
//! shared ones instanced under their own BVH, analytic shapes by their world bounds),
//! materials with textures resolved, lights (punctual ones and one area light per emitting
//! object), the scene's environment and its cameras. What a render job chooses (camera, image
//! size, which environment) is left to [`super::RenderJob`].

use super::aggregate::{Aggregate, MeshBlas, Prim, Run, TopLevel};
use super::desc::{
    check_camera_transform, check_coefficient, check_ior, check_metal, check_reflectance,
    check_spot_angles, check_transform, check_unit, BsdfDesc, EnvironmentDesc, MaterialDesc,
    MediumDesc, MeshDesc, SceneDesc, ShapeDesc, TextureRef, WrapMode,
};
use super::files::SceneFiles;
use super::{Object, ObjectKind, RenderJob, Scene, SceneCamera, SceneError, SceneStats};
use crate::alloc::huge_vec;
use crate::geometry::triangle::{Mesh, TriangleGeom};
use crate::geometry::{aabox, plane, polygon, quadric, sphere, Aabb, Analytic};
use crate::light::area::{Emitter, PlacedShape, TriangleLight};
use crate::light::environment::check_map;
use crate::light::{check_radiance, AreaLight, Environment, Light};
use crate::material::{AlphaMode, Coverage, Emission, Material, MaterialSlots, Model, PbrParams};
use crate::medium::{GridMedium, HomogeneousMedium, Medium};
use crate::settings::{EnvironmentChoice, RenderSettings};
use crate::texture::{TexSlot, Texels, Texture, TextureLookup};
use glam::{Affine3A, Vec2, Vec3, Vec3A, Vec4};
use rayon::prelude::*;
use std::collections::HashMap;
use std::f32::consts::PI;
use std::path::Path;
use std::sync::Arc;

fn invalid(msg: impl Into<String>) -> SceneError {
    SceneError::Invalid(msg.into())
}

fn finite3(v: Vec3) -> bool {
    v.is_finite()
}

impl Scene {
    /// Builds the scene described by `desc`: every check, the BVHs and the lights. The result
    /// depends on nothing else, so it can be kept and rendered by any number of jobs.
    /// [`Scene::build_owned`] when the description is not needed afterwards (it holds less
    /// memory at once).
    pub fn build(desc: &SceneDesc) -> Result<Scene, SceneError> {
        Self::build_owned(desc.clone())
    }

    /// Builds the scene described by `desc`, as [`Scene::build`], consuming the description:
    /// each mesh's arrays are freed as soon as its runtime mesh is made, before the BVHs are
    /// built (on rayon's pool, in parallel where it pays: bounds, corners, validation).
    pub fn build_owned(mut desc: SceneDesc) -> Result<Scene, SceneError> {
        check_extent(&desc)?;
        // Each texture's description is freed once its texture is made, so a scene's texels
        // are held about once, not twice, while it builds. Textures of one image share its
        // texels: 8-bit ones its bytes, f32 ones its values converted once for each of colour
        // and data. Only the first texture of an f32 image in each colour space keeps the
        // image (the others are made from its texture), so that the last to convert it does
        // so in place.
        let n_textures = desc.textures.len();
        let mut descs = std::mem::take(&mut desc.textures);
        let mut first: HashMap<(usize, bool), usize> = HashMap::new();
        let mut follows = vec![None; descs.len()];
        for (i, t) in descs.iter_mut().enumerate() {
            if let Texels::F32(values) = &t.texels {
                let key = (Arc::as_ptr(values) as usize, t.srgb);
                match first.get(&key) {
                    Some(&maker) => {
                        follows[i] = Some(maker);
                        t.texels = Texels::from(Vec::<[f32; 4]>::new());
                    }
                    None => {
                        first.insert(key, i);
                    }
                }
            }
        }
        drop(first);
        let mut textures: Vec<Texture> = Vec::with_capacity(descs.len());
        for (t, follows) in descs.into_iter().zip(follows) {
            let lookup = TextureLookup {
                wrap_u: t.wrap_u,
                wrap_v: t.wrap_v,
                bilinear: t.bilinear,
            };
            textures.push(match follows {
                Some(maker) => textures[maker].with_lookup(lookup),
                None => Texture::from_texels(t.width, t.height, t.texels, t.srgb, lookup),
            });
        }
        let materials = desc
            .materials
            .iter()
            .map(|m| build_material(m, n_textures))
            .collect::<Result<Vec<_>, _>>()?;

        // Meshes: validate and convert, each description freed once converted.
        let mesh_descs = std::mem::take(&mut desc.meshes);
        let mut meshes = Vec::with_capacity(mesh_descs.len());
        for (mi, m) in mesh_descs.into_iter().enumerate() {
            meshes.push(build_mesh(mi, m)?);
        }
        let environment_desc = desc.environment.take();
        let desc = &desc;
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
        // The top level: every primitive's world bounds (allocated once, at their number) and
        // what they are, as runs (a flattened mesh is one run).
        let top_prims = desc
            .objects
            .iter()
            .map(|o| match o.shape {
                ShapeDesc::Mesh { mesh } if uses.get(mesh).is_some_and(|&u| u <= 1) => {
                    meshes[mesh].indices.len()
                }
                _ => 1,
            })
            .sum::<usize>();
        let mut bounds: Vec<Aabb> = Vec::with_capacity(top_prims);
        let mut runs: Vec<(u32, Run)> = Vec::new();
        let mut unbounded = Vec::new();
        let mut blas: Vec<Option<MeshBlas>> = vec![None; meshes.len()];
        // |det| of each object's linear part: scales the area of its emitting shape.
        let mut dets = Vec::with_capacity(desc.objects.len());
        let mut stats = SceneStats {
            objects: desc.objects.len(),
            ..Default::default()
        };
        // Media: a homogeneous medium (and a grid in world space) is made once; a grid is placed
        // by the object that holds it (whose interior it is), once per holder, and an exterior
        // reference uses the placement of the medium's holder (world space for the scene's medium).
        let mut media: Vec<Medium> = Vec::new();
        let mut placed: std::collections::HashMap<(usize, Option<usize>), u32> =
            std::collections::HashMap::new();
        // Each medium built once; a grid placed by an object is a clone (voxels and majorants
        // shared) with that object's transform.
        let mut built: Vec<Option<Medium>> = vec![None; desc.media.len()];
        let mut place_medium = |mi: usize,
                                holder: Option<usize>,
                                at: &dyn Fn() -> String|
         -> Result<u32, SceneError> {
            let m = desc
                .media
                .get(mi)
                .ok_or_else(|| invalid(format!("{}: medium index {mi} out of range", at())))?;
            let holder = if m.density.is_none() { None } else { holder };
            if let Some(&i) = placed.get(&(mi, holder)) {
                return Ok(i);
            }
            let err = |e| invalid(format!("{}: medium '{}': {e}", at(), m.name));
            if built[mi].is_none() {
                built[mi] = Some(build_medium(m).map_err(err)?);
            }
            let mut placed_medium = built[mi].clone().expect("built just above");
            if let (Medium::Grid(g), Some(grid)) = (&mut placed_medium, &m.density) {
                let to_world = holder
                    .and_then(|h| desc.objects.get(h))
                    .map_or(Affine3A::IDENTITY, |o| Affine3A::from_mat4(o.transform));
                **g = g
                    .as_ref()
                    .clone()
                    .with_transform(to_world * grid.transform)
                    .map_err(err)?;
            }
            media.push(placed_medium);
            let i = (media.len() - 1) as u32;
            placed.insert((mi, holder), i);
            Ok(i)
        };
        // The objects whose interior each medium is: an exterior reference to a grid uses the
        // placement of its one holder.
        let mut holders: Vec<Vec<usize>> = vec![Vec::new(); desc.media.len()];
        for (oi, o) in desc.objects.iter().enumerate() {
            if let Some(mi) = o.media.and_then(|m| m.interior) {
                if let Some(h) = holders.get_mut(mi) {
                    h.push(oi);
                }
            }
        }
        let camera_medium = match desc.medium {
            Some(mi) => Some(place_medium(mi, None, &|| {
                "the scene's medium".to_string()
            })?),
            None => None,
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
            check_transform(&o.transform).map_err(|e| invalid(format!("{}: {e}", ctx())))?;
            let to_world = Affine3A::from_mat4(o.transform);
            let det = to_world.matrix3.determinant();
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
                        runs.push((
                            bounds.len() as u32,
                            Run::Tris {
                                object: oi as u32,
                                alpha: needs_alpha,
                            },
                        ));
                        // The corners as `Aggregate::new`'s `geom` places them.
                        bounds.par_extend((0..m.indices.len()).into_par_iter().map(|ti| {
                            Aabb::from_points(&m.corners(ti).map(|v| to_world.transform_point3a(v)))
                        }));
                        stats.flattened_triangles += m.indices.len();
                    } else {
                        if blas[mesh_i].is_none() {
                            blas[mesh_i] = Some(MeshBlas::new(m, scene_prims));
                            stats.instanced_triangles += m.indices.len();
                        }
                        let mut b = Aabb::empty();
                        for v in &m.positions {
                            b.extend(to_world.transform_point3a(*v));
                        }
                        if !m.indices.is_empty() {
                            runs.push((
                                bounds.len() as u32,
                                Run::One(Prim::Instance { object: oi as u32 }),
                            ));
                            bounds.push(b);
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
                        Some(b) => {
                            runs.push((
                                bounds.len() as u32,
                                Run::One(Prim::Analytic { object: oi as u32 }),
                            ));
                            bounds.push(transform_aabb(&to_world, &b));
                        }
                        None => unbounded.push(oi as u32),
                    }
                    ObjectKind::Analytic(a)
                }
            };
            let object_media = match o.media {
                Some(om) => {
                    let interior = om
                        .interior
                        .map(|mi| place_medium(mi, Some(oi), &ctx))
                        .transpose()?;
                    let exterior = match om.exterior {
                        None => None,
                        Some(mi) => {
                            let grid = desc.media.get(mi).is_some_and(|m| m.density.is_some());
                            let holder = match holders.get(mi).map(Vec::as_slice) {
                                _ if !grid || desc.medium == Some(mi) => None,
                                Some([h]) => Some(*h),
                                Some([_, _, ..]) => {
                                    return Err(invalid(format!(
                                        "{}: exterior medium '{}' is a grid held by several \
                                         objects; an exterior may name a grid only when it is \
                                         the scene's medium or the interior of one object",
                                        ctx(),
                                        desc.media[mi].name
                                    )))
                                }
                                _ => None,
                            };
                            Some(place_medium(mi, holder, &ctx)?)
                        }
                    };
                    Some([interior, exterior])
                }
                None => None,
            };
            objects.push(Object {
                name: o.name.clone(),
                kind,
                media: object_media,
                material: o.material as u32,
                to_world,
                to_object,
                normal_matrix,
                light_base: u32::MAX,
            });
            dets.push(det.abs());
        }

        let mesh_of = |object: u32| {
            let o = &objects[object as usize];
            let ObjectKind::Mesh { mesh } = o.kind else {
                unreachable!("triangles belong to meshes");
            };
            (o, &meshes[mesh as usize])
        };
        let (aggregate, bounds) = Aggregate::new(
            TopLevel { bounds, runs },
            unbounded,
            blas,
            scene_prims,
            |object, tri| {
                let (o, m) = mesh_of(object);
                TriangleGeom::new(
                    m.corners(tri as usize)
                        .map(|v| o.to_world.transform_point3a(v)),
                )
            },
            |object, tri| {
                let (o, m) = mesh_of(object);
                tri_shading(o, m, tri)
            },
        );
        let radius = if bounds.min.cmple(bounds.max).all() {
            (bounds.diagonal().length() * 0.5).max(1e-3)
        } else {
            1.0
        };

        // Lights: the punctual ones, then one area light per emitting object (each of a
        // mesh's triangles a light of its own for selection).
        let mut lights = Vec::new();
        let mut area_lights = Vec::new();
        for (li, l) in desc.lights.iter().enumerate() {
            lights.push(build_light(l).map_err(|e| invalid(format!("light {li}: {e}")))?);
        }
        for (oi, o) in objects.iter_mut().enumerate() {
            let Some(emission) = materials[o.material as usize].emission else {
                continue;
            };
            let shape = match &o.kind {
                ObjectKind::Mesh { mesh } => {
                    let m = &meshes[*mesh as usize];
                    let tris = (0..m.indices.len())
                        .map(|ti| {
                            let local = TriangleGeom::new(m.corners(ti));
                            let geom = TriangleGeom::new(
                                m.corners(ti).map(|v| o.to_world.transform_point3a(v)),
                            );
                            TriangleLight {
                                geom,
                                ng: (o.normal_matrix * local.normal()).normalize_or(Vec3A::Y),
                                area: 0.5 * geom.normal().length(),
                            }
                        })
                        .collect();
                    let uvs = if emission.reads_uv() {
                        m.indices.iter().map(|&c| corner_uvs(m, c)).collect()
                    } else {
                        Vec::new()
                    };
                    Emitter::Triangles { tris, uvs }
                }
                ObjectKind::Analytic(a) => {
                    if let Some(why) = analytic_emit_refusal(a) {
                        return Err(invalid(format!("object {oi} ('{}'): {why}", o.name)));
                    }
                    Emitter::Shape(Box::new(PlacedShape {
                        shape: a.clone(),
                        to_world: o.to_world,
                        normal_matrix: o.normal_matrix,
                        det: dets[oi],
                    }))
                }
            };
            let light = AreaLight { emission, shape };
            let prims = match &light.shape {
                Emitter::Triangles { tris, .. } => tris.len() as u32,
                Emitter::Shape(_) => 1,
            };
            o.light_base = lights.len() as u32;
            for prim in 0..prims {
                lights.push(Light::Area {
                    light: area_lights.len() as u32,
                    prim,
                    power: light.power(prim),
                });
            }
            area_lights.push(light);
        }
        stats.lights = lights.len();
        // The map's description likewise, once the map is made.
        let environment = match environment_desc {
            None => None,
            Some(EnvironmentDesc::Constant { radiance }) => {
                let radiance = Vec3A::from(radiance);
                check_radiance("radiance", radiance)
                    .map_err(|e| invalid(format!("environment: {e}")))?;
                Some(Arc::new(Environment::constant(radiance)))
            }
            Some(EnvironmentDesc::Map {
                texture: t,
                scale,
                rotation_y,
            }) => {
                check_map(&t.texels, t.width, scale, "scale")
                    .map_err(|e| invalid(format!("environment map {}: {e}", t.name)))?;
                let lookup = TextureLookup {
                    wrap_u: t.wrap_u,
                    wrap_v: t.wrap_v,
                    bilinear: t.bilinear,
                };
                let texture = Texture::from_texels(t.width, t.height, t.texels, t.srgb, lookup);
                Some(Arc::new(Environment::map(texture, scale, rotation_y)))
            }
        };
        let cameras = desc
            .cameras
            .iter()
            .enumerate()
            .map(|(ci, c)| {
                let bad = |e: String| invalid(format!("camera {ci} ('{}'): {e}", c.name));
                check_camera_transform(&c.transform).map_err(bad)?;
                c.projection.check().map_err(|(_, e)| bad(e))?;
                Ok(SceneCamera {
                    name: c.name.clone(),
                    transform: c.transform,
                    projection: c.projection,
                })
            })
            .collect::<Result<_, SceneError>>()?;

        let has_interfaces = materials.iter().any(|m| m.interface);
        let absorbs = materials
            .iter()
            .any(|m| m.body && m.absorption != Vec3A::ZERO);
        Ok(Scene {
            absorbs,
            media,
            camera_medium,
            has_interfaces,
            objects,
            meshes,
            materials,
            textures,
            aggregate,
            lights,
            area_lights,
            environment,
            default_environment: desc.default_environment,
            cameras,
            bounds,
            radius,
            stats,
        })
    }
}

/// The texture coordinates of triangle `corners`' corners in sets 0 and 1; a set the mesh
/// lacks gives the corners (0, 0), (1, 0), (0, 1), whose interpolation is (b1, b2) as in
/// [`Mesh::uvs_at`].
fn corner_uvs(m: &Mesh, corners: [u32; 3]) -> [[Vec2; 3]; 2] {
    let set = |k: usize| {
        if m.uvs[k].is_empty() {
            [Vec2::ZERO, Vec2::X, Vec2::Y]
        } else {
            corners.map(|i| m.uvs[k][i as usize])
        }
    };
    [set(0), set(1)]
}

/// The `tri_shading` entry of the aggregate for triangle `tri` of `m` placed by `o`: the unit world front normal,
/// and whether the shading normal is that normal (w = 1).
fn tri_shading(o: &Object, m: &Mesh, tri: u32) -> Vec4 {
    let geom = TriangleGeom::new(m.corners(tri as usize));
    // As in shading (`Scene::interaction`): the inverse transpose keeps the object's front side.
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

/// How far from the origin along any axis a finite object may reach, in scene units: 2⁴⁰,
/// about 1.1·10¹². A ray–triangle test multiplies an edge by an edge by the distance from the
/// ray's origin, which overflows 32-bit floats past about 7·10¹² units, and the triangle is
/// never hit; spheres, rectangles and the quadrics fail the same way further out. Planes are
/// unbounded and exempt.
pub const MAX_COORDINATE: f32 = (1u64 << 40) as f32;

/// Refuses a scene with a finite object that reaches past [`MAX_COORDINATE`], naming it:
/// such an object would not be seen (or only in part) rather than fail. A mesh's reach is that of
/// the finite positions its triangles use; a shape or transform that is not valid passes,
/// for the build to refuse with its own message.
pub fn check_extent(desc: &SceneDesc) -> Result<(), SceneError> {
    let mut mesh_bounds: Vec<Option<Aabb>> = vec![None; desc.meshes.len()];
    for (oi, o) in desc.objects.iter().enumerate() {
        let b = match &o.shape {
            ShapeDesc::Mesh { mesh } => {
                let (Some(m), Some(cached)) = (desc.meshes.get(*mesh), mesh_bounds.get_mut(*mesh))
                else {
                    continue;
                };
                *cached.get_or_insert_with(|| {
                    m.indices
                        .par_iter()
                        .flatten()
                        .filter_map(|&i| m.positions.get(i as usize).filter(|p| p.is_finite()))
                        .fold(Aabb::empty, |mut b, &p| {
                            b.extend(p.into());
                            b
                        })
                        .reduce(Aabb::empty, |a, b| a.union(&b))
                })
            }
            // A polygon's bounds are its vertices' (its build would ear-clip it once more).
            ShapeDesc::Polygon { vertices } => {
                vertices
                    .iter()
                    .filter(|p| p.is_finite())
                    .fold(Aabb::empty(), |mut b, &p| {
                        b.extend(p.into());
                        b
                    })
            }
            shape => match build_analytic(shape).ok().and_then(|a| a.bounds()) {
                Some(b) => b,
                None => continue,
            },
        };
        if !b.valid() || !o.transform.is_finite() {
            continue; // a mesh without triangles; a transform the build refuses
        }
        let w = transform_aabb(&Affine3A::from_mat4(o.transform), &b);
        let reach = w.min.abs().max(w.max.abs()).max_element();
        if reach > MAX_COORDINATE {
            return Err(invalid(format!(
                "object {oi} ('{}') reaches {reach:.3e} units from the origin: raytile renders \
                 objects within {MAX_COORDINATE:.3e} (2^40) units of it, beyond which its \
                 32-bit ray tests overflow and the object would not be seen; scale the scene \
                 down or move it nearer the origin",
                o.name
            )));
        }
    }
    Ok(())
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

/// Validates and converts mesh `mi`, reusing its arrays where the runtime keeps them as they are
/// (indices, uvs, tangents). Checked and converted in parallel.
fn build_mesh(mi: usize, m: MeshDesc) -> Result<Mesh, SceneError> {
    let ctx = || format!("mesh {mi} ('{}')", m.name);
    let n = m.positions.len();
    if m.positions.par_iter().any(|p| !finite3(*p)) {
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
    if !m.colors.is_empty() && m.colors.len() != n {
        return Err(invalid(format!(
            "{}: {} vertex colours for {n} vertices",
            ctx(),
            m.colors.len()
        )));
    }
    if m.colors.iter().any(|c| !c.is_finite()) {
        return Err(invalid(format!("{}: a vertex colour is not finite", ctx())));
    }
    if !m.tangents.is_empty() && m.tangents.len() != n {
        return Err(invalid(format!(
            "{}: {} tangents for {n} vertices",
            ctx(),
            m.tangents.len()
        )));
    }
    let out_of_range = m
        .indices
        .par_iter()
        .find_first(|t| t.iter().any(|&i| i as usize >= n))
        .and_then(|t| t.iter().find(|&&i| i as usize >= n));
    if let Some(bad) = out_of_range {
        return Err(invalid(format!(
            "{}: index {bad} out of range ({n} vertices)",
            ctx()
        )));
    }
    // Degenerate triangles cannot be hit and would give NaN normals: drop them.
    // Vertex arrays are read at random by hits: on huge pages (crate::alloc).
    let mut positions: Vec<Vec3A> = huge_vec(m.positions.len());
    positions.par_extend(m.positions.par_iter().map(|&p| Vec3A::from(p)));
    let keep = |&[a, b, c]: &[u32; 3]| {
        let (a, b, c) = (
            positions[a as usize],
            positions[b as usize],
            positions[c as usize],
        );
        (b - a).cross(c - a).length_squared() > 0.0
    };
    let mut indices = m.indices;
    if !indices.par_iter().all(keep) {
        indices.retain(keep);
        indices.shrink_to_fit();
    }
    let clean_normal = |v: &Vec3| {
        let v = Vec3A::from(*v);
        if v.is_finite() && v.length_squared() > 0.0 {
            v.normalize()
        } else {
            Vec3A::ZERO
        }
    };
    Ok(Mesh {
        name: m.name,
        positions,
        normals: {
            let mut normals = huge_vec(m.normals.len());
            normals.par_extend(m.normals.par_iter().map(clean_normal));
            normals
        },
        tangents: m.tangents,
        uvs: m.uvs,
        colors: m
            .colors
            .par_iter()
            .map(|c| Vec3A::from(*c).max(Vec3A::ZERO))
            .collect(),
        indices,
    })
}

/// Why an emissive plane or quadric is refused.
pub(crate) const NOT_AN_AREA_LIGHT: &str = "this shape cannot be an area light (planes and \
    quadrics cannot be sampled); use a mesh, sphere, box, disk, rectangle or polygon";

/// Why an emissive shape whose area overflows f32 is refused.
pub(crate) const LIGHT_TOO_LARGE: &str = "this shape is too large to be an area light (its \
    surface area overflows 32-bit floats)";

/// Why an emissive shape whose area rounds to zero in f32 is refused.
pub(crate) const LIGHT_TOO_SMALL: &str = "this shape is too small to be an area light (its \
    surface area rounds to zero in 32-bit floats)";

/// Why an object of this shape cannot be an area light, if it cannot: a plane or a quadric
/// cannot be sampled ([`NOT_AN_AREA_LIGHT`]), and a shape whose area overflows or rounds to
/// zero has no density ([`LIGHT_TOO_LARGE`], [`LIGHT_TOO_SMALL`]). A shape whose parameters are wrong passes: the builder refuses it for
/// them.
pub(crate) fn emit_refusal(shape: &ShapeDesc) -> Option<&'static str> {
    match shape {
        ShapeDesc::Mesh { .. } => None,
        s => build_analytic(s)
            .ok()
            .and_then(|a| analytic_emit_refusal(&a)),
    }
}

fn analytic_emit_refusal(a: &Analytic) -> Option<&'static str> {
    if matches!(a, Analytic::Plane(_) | Analytic::Quadric(_)) {
        return Some(NOT_AN_AREA_LIGHT);
    }
    let area = a.area();
    if !area.is_finite() {
        return Some(LIGHT_TOO_LARGE);
    }
    if !(area > 0.0) {
        return Some(LIGHT_TOO_SMALL);
    }
    // A subnormal area samples with an infinite density, which the light skips: such a light
    // loads, as it always did, and gives no light.
    match a.sample(Vec2::splat(0.5)) {
        Some(_) => None,
        None => Some(LIGHT_TOO_LARGE),
    }
}

/// Checks an analytic shape's parameters as the build does: the build's own message.
pub(crate) fn check_shape(shape: &ShapeDesc) -> Result<(), String> {
    build_analytic(shape).map(|_| ())
}

/// Checks a light's parameters as the build does: the build's own message.
pub(crate) fn check_light(light: &super::desc::LightDesc) -> Result<(), String> {
    build_light(light).map(|_| ())
}

fn build_analytic(shape: &ShapeDesc) -> Result<Analytic, String> {
    let v = |x: Vec3| Vec3A::from(x);
    let finite = |ok: bool| {
        if ok {
            Ok(())
        } else {
            Err("shape parameters must be finite (at most about 3.4e38 in size)".to_string())
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
            v_by_height,
        } => Analytic::Quadric(
            quadric::Quadric::new(*q, v(*clip_min), v(*clip_max))?.with_v_by_height(*v_by_height),
        ),
        ShapeDesc::Mesh { .. } => unreachable!("meshes are handled by the caller"),
    })
}

fn build_light(l: &super::desc::LightDesc) -> Result<Light, String> {
    use super::desc::LightDesc;
    let ok = |v: Vec3| {
        if v.is_finite() {
            Ok(Vec3A::from(v))
        } else {
            Err("light parameters must be finite (at most about 3.4e38 in size)".to_string())
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
    let radiance = |what: &str, v: Vec3| {
        let v = Vec3A::from(v);
        check_radiance(what, v).map(|()| v)
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
            intensity: radiance("intensity", intensity)?,
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
            check_spot_angles(inner_angle.to_degrees(), outer_angle.to_degrees())
                .map_err(|(_, e)| e)?;
            // Within rounding of the checked range.
            let outer = outer_angle.min(PI * 0.5);
            let inner = inner_angle.min(outer);
            Light::Spot {
                position: ok(position)?,
                axis: dir(direction)?,
                intensity: radiance("intensity", intensity)?,
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
            irradiance: radiance("irradiance", irradiance)?,
        },
    })
}

/// The medium `m`, its grid (if any) in its own space (placed by the caller).
fn build_medium(m: &MediumDesc) -> Result<Medium, crate::medium::MediumError> {
    let sigma_a = Vec3A::from(m.sigma_a) * m.scale;
    let sigma_s = Vec3A::from(m.sigma_s) * m.scale;
    Ok(match &m.density {
        None => Medium::Homogeneous(HomogeneousMedium::new(sigma_a, sigma_s, m.g)?),
        Some(grid) => {
            let mut gm = GridMedium::new(grid.density.clone(), sigma_a, sigma_s, m.g)?;
            if let Some(res) = grid.majorant_resolution {
                if res.iter().any(|&r| r == 0 || r > 256) {
                    return Err(crate::medium::MediumError::Grid(format!(
                        "majorant_resolution must be 1 to 256 cells per axis, got {res:?}"
                    )));
                }
                gm = gm.with_majorant_resolution(res);
            }
            Medium::Grid(Box::new(gm))
        }
    })
}

fn build_material(m: &MaterialDesc, n_textures: usize) -> Result<Material, SceneError> {
    let check = |r: &Option<TextureRef>| -> Result<Option<TexSlot>, SceneError> {
        match r {
            Some(r) if r.texture >= n_textures => Err(invalid(format!(
                "material '{}': texture index {} out of range",
                m.name, r.texture
            ))),
            Some(r) => Ok(Some(TexSlot::new(
                r.texture as u32,
                r.texcoord,
                r.transform,
            ))),
            None => Ok(None),
        }
    };
    let mut slots = MaterialSlots {
        normal: match &m.normal_texture {
            Some((r, s)) => check(&Some(*r))?.map(|t| (t, *s)),
            None => None,
        },
        ..Default::default()
    };
    let bad = |e: String| invalid(format!("material '{}': {e}", m.name));
    let mut absorption = Vec3A::ZERO;
    let mut base_color = Vec4::ONE;
    let mut interface = false;
    let mut body = false;
    if let Some((field, v)) = m.bsdf.tint() {
        check_reflectance(field, v).map_err(bad)?;
    }
    let model = match &m.bsdf {
        BsdfDesc::Interface => {
            interface = true;
            base_color = Vec4::ZERO;
            Model::Diffuse
        }
        BsdfDesc::Diffuse { albedo, texture } => {
            slots.base = check(texture)?;
            base_color = albedo.extend(1.0);
            Model::Diffuse
        }
        BsdfDesc::Mirror { reflectance } => Model::mirror(Vec3A::from(*reflectance)),
        BsdfDesc::Dielectric {
            ior,
            transmittance,
            absorption: a,
            thin,
        } => {
            check_ior(*ior).map_err(bad)?;
            check_coefficient("absorption", *a).map_err(bad)?;
            if !thin {
                absorption = Vec3A::from(*a);
                body = true;
            }
            Model::dielectric(*ior, Vec3A::from(*transmittance), *thin)
        }
        BsdfDesc::Conductor { eta, k, alpha } => {
            check_unit("alpha (roughness²)", *alpha).map_err(bad)?;
            check_metal(*eta, *k).map_err(|(_, e)| bad(e))?;
            Model::conductor(Vec3A::from(*eta), Vec3A::from(*k), *alpha)
        }
        BsdfDesc::RoughDielectric {
            ior,
            alpha,
            transmittance,
        } => {
            check_ior(*ior).map_err(bad)?;
            check_unit("alpha (roughness²)", *alpha).map_err(bad)?;
            body = true;
            Model::rough_dielectric(*ior, *alpha, Vec3A::from(*transmittance))
        }
        BsdfDesc::Pbr(p) => {
            check_unit("metallic", p.metallic).map_err(bad)?;
            check_unit("roughness", p.roughness).map_err(bad)?;
            check_unit("transmission", p.transmission).map_err(bad)?;
            check_ior(p.ior).map_err(bad)?;
            check_unit("base_color alpha", p.base_color[3]).map_err(bad)?;
            slots.base = check(&p.base_color_texture)?;
            slots.metallic_roughness = check(&p.metallic_roughness_texture)?;
            slots.transmission = check(&p.transmission_texture)?;
            slots.specular = check(&p.specular_texture)?;
            slots.specular_color = check(&p.specular_color_texture)?;
            slots.clearcoat = check(&p.clearcoat_texture)?;
            slots.clearcoat_roughness = check(&p.clearcoat_roughness_texture)?;
            base_color = Vec4::from(p.base_color);
            body = !p.thin_walled && p.transmission > 0.0;
            if !p.thin_walled
                && p.transmission > 0.0
                && p.attenuation_distance.is_finite()
                && p.attenuation_distance > 0.0
            {
                let c = Vec3A::from(p.attenuation_color).clamp(Vec3A::splat(1e-6), Vec3A::ONE);
                absorption = Vec3A::new(-c.x.ln(), -c.y.ln(), -c.z.ln()) / p.attenuation_distance;
            }
            Model::Pbr(PbrParams {
                metallic: p.metallic,
                roughness: p.roughness,
                specular: p.specular.clamp(0.0, 1.0),
                specular_color: Vec3A::from(p.specular_color).max(Vec3A::ZERO),
                ior: p.ior,
                transmission: p.transmission,
                thin: p.thin_walled,
                clearcoat: p.clearcoat.clamp(0.0, 1.0),
                clearcoat_alpha: p.clearcoat_roughness * p.clearcoat_roughness,
            })
        }
    };
    check_radiance("emission", Vec3A::from(m.emission))
        .map_err(|e| invalid(format!("material '{}': {e}", m.name)))?;
    let radiance = Vec3A::from(m.emission);
    let emission = Emission {
        radiance,
        two_sided: m.two_sided,
        texture: check(&m.emission_texture)?,
        coverage: (m.alpha_mode != AlphaMode::Opaque).then_some(Coverage {
            mode: m.alpha_mode,
            alpha: base_color.w,
            texture: slots.base,
        }),
    };
    Ok(Material {
        model,
        base_color,
        slots,
        emission: m.emits().then_some(emission),
        alpha_mode: m.alpha_mode,
        absorption,
        body,
        interface,
    })
}

/// Reads the equirectangular map at `path` (relative to `base`, through `files`: Radiance
/// `.hdr` or OpenEXR, linear RGB) as an importance-sampled environment, times `strength`,
/// turned by `rotation_deg` degrees about +Y. The map's texels are charged to the memory
/// budget of `files`.
pub fn load_environment_map(
    path: &Path,
    base: &Path,
    files: &SceneFiles,
    strength: f32,
    rotation_deg: f32,
) -> Result<Environment, SceneError> {
    const FIELD: &str = "environment";
    let shown = path.display().to_string();
    let r = files
        .resolve_path(base, path, FIELD)
        .map_err(|e| invalid(format!("environment: {}", e.describe())))?;
    let bytes = files
        .read(&r, FIELD, super::image::MAX_IMAGE_FILE)
        .map_err(|e| invalid(format!("environment: {}", e.describe())))?;
    let bad = |e: String| invalid(format!("environment {shown}: {e}"));
    files
        .charge_memory(super::image::image_bytes(&bytes).map_err(bad)?, &shown)
        .map_err(bad)?;
    let img = super::image::decode_image(&bytes).map_err(bad)?;
    check_map(&img.texels, img.width, strength, "environment_strength").map_err(bad)?;
    let lookup = TextureLookup {
        wrap_u: WrapMode::Repeat,
        wrap_v: WrapMode::Clamp,
        bilinear: true,
    };
    let texture = Texture::from_texels(img.width, img.height, img.texels, false, lookup);
    Ok(Environment::map(
        texture,
        strength,
        rotation_deg.to_radians(),
    ))
}

impl RenderJob {
    /// The job rendering `scene` with `settings`, as [`RenderJob::new`], reading the
    /// environment map the settings name (if they name one) through `files`, relative to the
    /// folder `base`: the current folder for `raytile render`, the scene's folder on a farm
    /// (where `files` confines it to that folder like any file of the scene).
    pub fn with_files(
        scene: &Scene,
        settings: &RenderSettings,
        files: &SceneFiles,
        base: &Path,
    ) -> Result<RenderJob, SceneError> {
        let Some(EnvironmentChoice::Map(path)) = &settings.environment else {
            return RenderJob::new(scene, settings);
        };
        let map = load_environment_map(
            Path::new(path),
            base,
            files,
            settings.environment_strength,
            settings.environment_rotation,
        )?;
        let no_map = RenderSettings {
            environment: Some(EnvironmentChoice::None),
            ..settings.clone()
        };
        let mut job = RenderJob::new(scene, &no_map)?;
        job.settings = settings.clone();
        job.with_environment(scene, Some(Arc::new(map)))
    }
}
