//! Scenes: plain descriptions ([`desc`]), the front ends that produce them ([`json`], [`gltf`],
//! with [`image`] decoding their pictures and [`files`] reading every file they name), the builder that turns a description into the
//! render-ready [`Scene`] ([`build`]), and the scene at render time: closest- and any-hit
//! queries ([`aggregate`]), shading of the surfaces they find ([`shading`]), and what one
//! render job adds to a scene ([`job`]: camera, environment, light selection).
//!
//! A [`Scene`] depends only on the description (the scene's bytes): a farm worker builds it
//! once and renders every job on that scene with it. A [`RenderJob`] is the cheap rest.

pub mod aggregate;
pub(crate) mod bodies;
pub mod build;
pub mod desc;
pub mod files;
pub mod gltf;
pub mod image;
pub mod job;
pub mod json;
pub mod shading;

pub use desc::SceneDesc;
pub use job::RenderJob;

use crate::camera::Projection;
use crate::geometry::triangle::Mesh;
use crate::geometry::{Aabb, Analytic};
use crate::light::{AreaLight, Environment, Light};
use crate::material::Material;
use crate::texture::Texture;
use aggregate::Aggregate;
use glam::{Affine3A, Mat3A, Mat4, Vec2};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A scene ready to render: geometry under its BVH, materials with their textures, the lights
/// and the environment the scene file gives, and its cameras. Built once from a description by
/// [`Scene::build`]; each render adds a [`RenderJob`].
pub struct Scene {
    pub(crate) objects: Vec<Object>,
    /// Participating media, referenced by [`Object::media`] and `camera_medium`.
    pub(crate) media: Vec<crate::medium::Medium>,
    /// The medium outside every object (global fog), where camera rays start.
    pub(crate) camera_medium: Option<u32>,
    /// Some material is an interface (a medium boundary that does not scatter).
    pub(crate) has_interfaces: bool,
    /// Some body absorbs ([`Material::absorption`]): paths track the bodies they are in.
    pub(crate) absorbs: bool,
    pub(crate) meshes: Vec<Mesh>,
    pub(crate) materials: Vec<Material>,
    pub(crate) textures: Vec<Texture>,
    pub(crate) aggregate: Aggregate,
    /// Point, spot, directional and area lights (one per emitting triangle or shape).
    pub(crate) lights: Vec<Light>,
    /// The emitting surfaces [`Light::Area`] refers to.
    pub(crate) area_lights: Vec<AreaLight>,
    /// The scene's own environment, if any.
    pub(crate) environment: Option<Arc<Environment>>,
    /// `environment` is the default one a loader added to an unlit scene.
    pub(crate) default_environment: bool,
    pub(crate) cameras: Vec<SceneCamera>,
    pub(crate) bounds: Aabb,
    /// Radius of the bounding sphere of `bounds` (1 for an empty scene): sizes directional
    /// lights and the environment for light selection.
    pub(crate) radius: f32,
    /// Counts for reports and tests.
    pub stats: SceneStats,
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
    /// The scene's lights (every emissive triangle counts; the environment does not: it is
    /// the render job's).
    pub lights: usize,
}

/// What an object is made of. (Objects are few: the size of the analytic variant does not
/// matter.)
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
    /// The media inside and outside (indices into `Scene::media`, `None` for vacuum), if the
    /// surface bounds media; `None`: a ray crossing it keeps its medium.
    pub media: Option<[Option<u32>; 2]>,
    pub material: u32,
    pub to_world: Affine3A,
    pub to_object: Affine3A,
    /// Inverse transpose of the linear part: transforms normals.
    pub normal_matrix: Mat3A,
    /// Index in [`Scene::lights`] of this object's first light (one per triangle for meshes),
    /// or `u32::MAX`.
    pub light_base: u32,
}

/// A camera of the scene, before an image size is chosen.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneCamera {
    /// Name used by `--camera NAME`.
    pub name: String,
    /// Camera-to-world transform (rigid; scale is ignored).
    pub transform: Mat4,
    /// Projection and lens.
    pub projection: Projection,
}

impl Scene {
    /// World bounds of all bounded geometry.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The scene's cameras, in file order.
    pub fn cameras(&self) -> &[SceneCamera] {
        &self.cameras
    }

    /// An estimate of the memory the scene holds, in bytes (geometry, BVHs, textures, lights):
    /// what keeping it in a cache costs.
    pub fn memory_bytes(&self) -> usize {
        use std::mem::size_of;
        fn vec<T>(v: &Vec<T>) -> usize {
            v.capacity() * size_of::<T>()
        }
        let objects = vec(&self.objects)
            + self
                .objects
                .iter()
                .map(|o| {
                    o.name.capacity()
                        + match &o.kind {
                            ObjectKind::Analytic(Analytic::Polygon(p)) => p.memory_bytes(),
                            _ => 0,
                        }
                })
                .sum::<usize>();
        let meshes = vec(&self.meshes)
            + self
                .meshes
                .iter()
                .map(|m| {
                    vec(&m.positions)
                        + vec(&m.normals)
                        + vec(&m.tangents)
                        + m.uvs.iter().map(vec::<Vec2>).sum::<usize>()
                        + vec(&m.colors)
                        + vec(&m.indices)
                })
                .sum::<usize>();
        // Textures that share their texels (one image sampled two ways) count them once.
        let mut seen = std::collections::HashSet::new();
        let textures = self
            .textures
            .iter()
            .filter(|t| seen.insert(t.texels_id()))
            .map(Texture::memory_bytes)
            .sum::<usize>();
        let lights = vec(&self.lights)
            + self
                .area_lights
                .iter()
                .map(AreaLight::memory_bytes)
                .sum::<usize>();
        let environment = self.environment.as_ref().map_or(0, |e| e.memory_bytes());
        // Grids placed by several objects, or read from one file by several media, share their
        // voxels and majorants: each is counted once.
        let mut seen_grids = std::collections::HashSet::new();
        let media = vec(&self.media)
            + self
                .media
                .iter()
                .map(|m| match m {
                    crate::medium::Medium::Grid(g) => {
                        let [x, y, z] = g.majorant_grid().resolution();
                        let density = if seen_grids.insert(g.density().values_id()) {
                            size_of_val(g.density().values())
                        } else {
                            0
                        };
                        let majorant = if seen_grids.insert(g.majorant_grid().cells_id()) {
                            x * y * z * size_of::<f32>()
                        } else {
                            0
                        };
                        size_of_val(g.as_ref()) + density + majorant
                    }
                    crate::medium::Medium::Homogeneous(_) => 0,
                })
                .sum::<usize>();
        size_of::<Self>()
            + objects
            + meshes
            + vec(&self.materials)
            + textures
            + self.aggregate.memory_bytes()
            + lights
            + environment
            + media
    }
}

/// Why a scene could not be loaded or built. Messages name the file and the offending object
/// (JSON path, glTF node/mesh/accessor index).
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The JSON scene is malformed or has a wrong value.
    #[error("{path}: {message}")]
    Json {
        /// The file.
        path: PathBuf,
        /// What and where (JSON path, line, column).
        message: String,
    },
    /// The glTF file is malformed, hostile or uses something unsupported.
    #[error("{path}: {message}")]
    Gltf {
        /// The file.
        path: PathBuf,
        /// What and where (glTF object).
        message: String,
    },
    /// The description is inconsistent (bad index, degenerate shape, NaN...).
    #[error("{0}")]
    Invalid(String),
    /// The file's extension is not one raytile reads.
    #[error("{0}: unknown scene format (expected .json, .gltf or .glb)")]
    UnknownFormat(PathBuf),
}

/// Loads a scene file by its extension: `.json` (raytile's format), `.gltf` or `.glb`. The
/// scene may name any file of the user's ([`files::FilePolicy::Trusted`]): for `raytile
/// render` on the user's own machine.
pub fn load_scene(path: &Path) -> Result<SceneDesc, SceneError> {
    load_scene_with(path, &files::SceneFiles::trusted())
}

/// Loads a scene file by its extension, reading it and every file it names through `files`:
/// [`files::SceneFiles::confined_to_scene`] for a scene that came over the network.
pub fn load_scene_with(path: &Path, files: &files::SceneFiles) -> Result<SceneDesc, SceneError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let desc = match ext.as_deref() {
        Some("json") => json::load_json_files(path, files),
        Some("gltf") | Some("glb") => {
            gltf::load_gltf_files(path, &gltf::GltfOptions::default(), files)
        }
        // A path that is not there is said so, whatever its name.
        _ => Err(match std::fs::metadata(path) {
            Err(source) if source.kind() == std::io::ErrorKind::NotFound => SceneError::Io {
                path: path.to_path_buf(),
                source,
            },
            _ => SceneError::UnknownFormat(path.to_path_buf()),
        }),
    }?;
    // Here as well as in the build, so that a coordinator refuses such a scene when it is
    // submitted.
    build::check_extent(&desc)?;
    Ok(desc)
}

impl std::fmt::Debug for Scene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene")
            .field("stats", &self.stats)
            .field("bounds", &self.bounds)
            .finish_non_exhaustive()
    }
}

#[cfg(test)]
mod tests {
    use super::desc::*;
    use super::Scene;
    use glam::{Mat4, Vec3};

    /// A path that is not there is said so, not taken for a file of an unknown format.
    #[test]
    fn a_missing_scene_is_said_missing() {
        let dir = std::env::temp_dir().join(format!("raytile-missing-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let missing = dir.join("no-such-folder");
        let e = super::load_scene(&missing).unwrap_err();
        assert!(matches!(e, super::SceneError::Io { .. }), "{e}");
        let other = dir.join("notes.txt");
        std::fs::write(&other, "hello").unwrap();
        let e = super::load_scene(&other).unwrap_err();
        assert!(e.to_string().contains("unknown scene format"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A grid of `n × n` quads (2 n² triangles), once or instanced twice.
    fn grid(n: u32, instances: usize) -> SceneDesc {
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        for y in 0..=n {
            for x in 0..=n {
                positions.push(Vec3::new(x as f32, y as f32, 0.0));
            }
        }
        for y in 0..n {
            for x in 0..n {
                let i = y * (n + 1) + x;
                indices.push([i, i + 1, i + n + 2]);
                indices.push([i, i + n + 2, i + n + 1]);
            }
        }
        SceneDesc {
            meshes: vec![MeshDesc {
                name: "grid".into(),
                positions,
                indices,
                ..Default::default()
            }],
            materials: vec![MaterialDesc::new(
                "m",
                BsdfDesc::Diffuse {
                    albedo: Vec3::ONE,
                    texture: None,
                },
            )],
            objects: (0..instances)
                .map(|i| ObjectDesc {
                    name: format!("g{i}"),
                    shape: ShapeDesc::Mesh { mesh: 0 },
                    material: 0,
                    transform: Mat4::from_translation(Vec3::Z * i as f32),
                    media: None,
                })
                .collect(),
            ..Default::default()
        }
    }

    #[test]
    fn the_memory_estimate_follows_the_geometry() {
        let small = Scene::build(&grid(4, 1)).unwrap();
        let big = Scene::build(&grid(64, 1)).unwrap();
        let added = (2 * 64 * 64 - 2 * 4 * 4) as usize;
        // Per flattened triangle at least its BVH primitive (corners), its shading entry and
        // its indices.
        let per_triangle = (big.memory_bytes() - small.memory_bytes()) / added;
        assert!(
            per_triangle >= 48 + 16 + 12,
            "{per_triangle} bytes per triangle"
        );
        assert!(per_triangle < 1024, "{per_triangle} bytes per triangle");
        // Instanced twice, the triangles are stored once.
        let twice = Scene::build(&grid(64, 2)).unwrap();
        assert_eq!(twice.stats.instanced_triangles, 2 * 64 * 64);
        assert!(twice.memory_bytes() < 2 * big.memory_bytes());
    }
}
