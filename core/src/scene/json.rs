//! raytile's JSON scene format: analytic shapes, meshes, glTF includes, materials, lights,
//! cameras and render settings in one readable file. The reference is `docs/scene-format.md`.
//!
//! Errors name the JSON path and line: syntax and type errors come from serde (with
//! `serde_path_to_error` for the path), semantic ones (an unknown material name, a degenerate
//! shape) from the conversion below, with the line of the offending value where it can be found.

use super::desc::*;
use super::files::{folder_of, show, FileError, Resolved, SceneFiles};
use super::SceneError;
use crate::geometry::quadric::Quadric;
use crate::light::check_radiance;
use crate::light::environment::check_map;
use crate::texture::Texels;
use glam::{EulerRot, Mat3, Mat4, Quat, Vec2, Vec3, Vec3A};
use serde::Deserialize;
use std::cell::RefCell;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

type Rgb = [f32; 3];

/// A value written `{"type": "kind", ...its fields}`: a shape, a texture, a medium, a light,
/// an environment. serde's own tagged enums read such a value through a buffer that hides the
/// path inside it (an error in a sphere's radius was "at objects[0].shape", on the line where the
/// shape ends). Here the object is read, its `type` taken out, and the rest read as that
/// variant of the externally tagged enum `T` with the path tracked, so an error names
/// `objects[0].shape.radius` and its line ([`SUBPATH`]).
struct Tagged<T>(T);

/// What the values of a [`Tagged`] enum are, for messages ("naming a shape").
trait Kind: serde::de::DeserializeOwned {
    const WHAT: &'static str;
}

/// Marks the path inside a [`Tagged`] value at the start of an error's message:
/// `SUBPATH + "radius" + SUBPATH + message`. `parse_json_files` adds it to the error's path.
const SUBPATH: char = '\u{1f}';

/// Reads an object's members into a map, refusing a member given twice; `T` says what the
/// object should be, for the message when it is not an object.
struct Fields<T>(std::marker::PhantomData<T>);

impl<'de, T: Kind> serde::de::Visitor<'de> for Fields<T> {
    type Value = serde_json::Map<String, serde_json::Value>;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "an object with a `type` naming {}", T::WHAT)
    }
    fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<Self::Value, A::Error> {
        raytile_proto::json::read_members(map)
    }
}

/// An error at `sub` inside the value being read ([`SUBPATH`]).
fn error_at<E: serde::de::Error>(sub: &str, message: impl std::fmt::Display) -> E {
    E::custom(format!("{SUBPATH}{sub}{SUBPATH}{message}"))
}

/// Reads `T` from `value`, found at `sub` inside the value being read; an error names its
/// path below `sub`.
fn read_at<T: serde::de::DeserializeOwned, E: serde::de::Error>(
    sub: &str,
    value: serde_json::Value,
) -> Result<T, E> {
    serde_path_to_error::deserialize(raytile_proto::json::Objects(value)).map_err(
        |e: serde_path_to_error::Error<serde_json::Error>| {
            let below = e.path().to_string();
            let full = match below.as_str() {
                "." => sub.to_string(),
                b if b.starts_with('[') => format!("{sub}{b}"),
                b => format!("{sub}.{b}"),
            };
            error_at(&full, e.inner())
        },
    )
}

/// The variant of `T` that an object's `type` names, read from its other `fields`.
fn tagged_from<T: Kind, E: serde::de::Error>(
    mut fields: serde_json::Map<String, serde_json::Value>,
) -> Result<T, E> {
    use serde_json::{Map, Value};
    let kind = match fields.remove("type") {
        Some(Value::String(kind)) => kind,
        Some(other) => {
            return Err(error_at(
                "type",
                format!("expected a string naming {}, got {other}", T::WHAT),
            ))
        }
        None => return Err(E::missing_field("type")),
    };
    let value = Value::Object(Map::from_iter([(kind, Value::Object(fields))]));
    let objects = raytile_proto::json::Objects(value);
    serde_path_to_error::deserialize(objects).map_err(
        |e: serde_path_to_error::Error<serde_json::Error>| {
            // The path below the variant's name (which the file does not write); an unknown
            // variant is an error at the root: the `type`'s.
            let path = e.path().to_string();
            let sub = if path == "." {
                "type"
            } else {
                path.split_once('.').map_or("", |(_, rest)| rest)
            };
            error_at(sub, e.inner())
        },
    )
}

impl<'de, T: Kind> Deserialize<'de> for Tagged<T> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let fields = d.deserialize_map(Fields::<T>(std::marker::PhantomData))?;
        tagged_from(fields).map(Tagged)
    }
}

/// A material: the fields every material takes, and the rest by its `type` ([`Tagged`]).
impl<'de> Deserialize<'de> for JMaterial {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let mut fields = d.deserialize_map(Fields::<JBsdf>(std::marker::PhantomData))?;
        let emission = match fields.remove("emission") {
            Some(v) => read_at("emission", v)?,
            None => Rgb::default(),
        };
        let two_sided = match fields.remove("two_sided") {
            Some(v) => read_at("two_sided", v)?,
            None => false,
        };
        Ok(JMaterial {
            bsdf: tagged_from(fields)?,
            emission,
            two_sided,
        })
    }
}

/// The [`Kind`] of each tagged enum: what its values are.
macro_rules! kinds {
    ($($ty:ty: $what:literal,)*) => {
        $(impl Kind for $ty {
            const WHAT: &'static str = $what;
        })*
    };
}

kinds! {
    JBsdf: "a material",
    JTexture: "a texture (image or checker)",
    JMedium: "a medium",
    JShape: "a shape",
    JLight: "a light",
    JEnvironment: "an environment",
}

/// A map of named entries (textures, materials, media) that refuses a name given twice: JSON
/// parsers differ on which one wins, and the scene's author meant one of them.
fn unique_keys<'de, D, V>(d: D) -> Result<BTreeMap<String, V>, D::Error>
where
    D: serde::Deserializer<'de>,
    V: Deserialize<'de>,
{
    struct Unique<V>(std::marker::PhantomData<V>);
    impl<'de, V: Deserialize<'de>> serde::de::Visitor<'de> for Unique<V> {
        type Value = BTreeMap<String, V>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("an object of named entries")
        }
        fn visit_map<A: serde::de::MapAccess<'de>>(
            self,
            mut map: A,
        ) -> Result<Self::Value, A::Error> {
            let mut out = BTreeMap::new();
            while let Some(key) = map.next_key::<String>()? {
                if out.contains_key(&key) {
                    return Err(serde::de::Error::custom(format!(
                        "the name '{key}' is given twice"
                    )));
                }
                let value = map.next_value()?;
                out.insert(key, value);
            }
            Ok(out)
        }
    }
    d.deserialize_map(Unique(std::marker::PhantomData))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    render: RenderDefaults,
    #[serde(default)]
    camera: Option<JCamera>,
    #[serde(default)]
    cameras: Vec<JCamera>,
    #[serde(default, deserialize_with = "unique_keys")]
    textures: BTreeMap<String, Tagged<JTexture>>,
    #[serde(default, deserialize_with = "unique_keys")]
    materials: BTreeMap<String, JMaterial>,
    #[serde(default)]
    objects: Vec<JObject>,
    #[serde(default)]
    lights: Vec<Tagged<JLight>>,
    #[serde(default)]
    environment: Option<Tagged<JEnvironment>>,
    #[serde(default, deserialize_with = "unique_keys")]
    media: BTreeMap<String, Tagged<JMedium>>,
    /// The medium outside every object (global fog), where the camera stands.
    #[serde(default)]
    medium: Option<String>,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}
fn default_fov() -> f32 {
    40.0
}
fn one() -> f32 {
    1.0
}
fn white() -> Rgb {
    [1.0; 3]
}
fn grey() -> Rgb {
    [0.8; 3]
}
fn ior_glass() -> f32 {
    1.5
}
fn yes() -> bool {
    true
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JCamera {
    #[serde(default)]
    name: Option<String>,
    #[serde(default, rename = "type")]
    kind: JCameraKind,
    position: [f32; 3],
    look_at: [f32; 3],
    #[serde(default = "default_up")]
    up: [f32; 3],
    /// Vertical field of view, degrees.
    #[serde(default = "default_fov")]
    fov: f32,
    /// Lens radius (thin lens); 0 is a pinhole.
    #[serde(default)]
    aperture: f32,
    /// Distance to the focus plane; defaults to the distance to `look_at`.
    #[serde(default)]
    focus_distance: Option<f32>,
    /// Orthographic: half the view height.
    #[serde(default = "one")]
    half_height: f32,
}

#[derive(Deserialize, Default, Clone, Copy)]
#[serde(rename_all = "snake_case")]
enum JCameraKind {
    #[default]
    Perspective,
    Orthographic,
}

#[derive(Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum JTexture {
    Image {
        path: PathBuf,
        #[serde(default = "yes")]
        srgb: bool,
        #[serde(default)]
        wrap: WrapMode,
        #[serde(default = "yes")]
        bilinear: bool,
        #[serde(default)]
        uv: JUv,
    },
    Checker {
        #[serde(default = "white")]
        even: Rgb,
        #[serde(default)]
        odd: Rgb,
        /// Checks per unit of texture coordinate.
        #[serde(default = "one")]
        scale: f32,
        #[serde(default)]
        uv: JUv,
    },
}

/// A texture's own transform of the texture coordinates (`KHR_texture_transform`'s).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JUv {
    #[serde(default)]
    offset: [f32; 2],
    /// Degrees.
    #[serde(default)]
    rotation: f32,
    #[serde(default = "ones2")]
    scale: [f32; 2],
}

impl Default for JUv {
    fn default() -> Self {
        JUv {
            offset: [0.0; 2],
            rotation: 0.0,
            scale: ones2(),
        }
    }
}

fn ones2() -> [f32; 2] {
    [1.0, 1.0]
}

impl JUv {
    /// The transform, or which of its fields is not finite.
    fn matrix(&self) -> Result<Mat3, &'static str> {
        for (field, ok) in [
            ("offset", self.offset.iter().all(|x| x.is_finite())),
            ("rotation", self.rotation.is_finite()),
            ("scale", self.scale.iter().all(|x| x.is_finite())),
        ] {
            if !ok {
                return Err(field);
            }
        }
        Ok(TextureRef::uv_transform(
            self.offset,
            self.rotation.to_radians(),
            self.scale,
        ))
    }
}

struct JMaterial {
    bsdf: JBsdf,
    emission: Rgb,
    two_sided: bool,
}

/// What a material is; its fields beside `emission` and `two_sided` (which [`JMaterial`] takes
/// before the rest comes here), so that an unknown one is an error, not a typo ignored.
#[derive(Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum JBsdf {
    Diffuse {
        #[serde(default = "grey")]
        albedo: Rgb,
        #[serde(default)]
        texture: Option<String>,
    },
    Mirror {
        #[serde(default = "white")]
        reflectance: Rgb,
    },
    #[serde(alias = "glass")]
    Dielectric {
        #[serde(default = "ior_glass")]
        ior: f32,
        #[serde(default = "white")]
        transmittance: Rgb,
        #[serde(default)]
        absorption: Rgb,
        #[serde(default)]
        thin: bool,
    },
    #[serde(alias = "metal")]
    Conductor {
        #[serde(default)]
        preset: Option<String>,
        #[serde(default)]
        eta: Option<Rgb>,
        #[serde(default)]
        k: Option<Rgb>,
        #[serde(default)]
        roughness: f32,
    },
    #[serde(alias = "frosted_glass")]
    RoughDielectric {
        #[serde(default = "ior_glass")]
        ior: f32,
        #[serde(default = "default_roughness")]
        roughness: f32,
        #[serde(default = "white")]
        transmittance: Rgb,
    },
    Pbr {
        #[serde(default = "white")]
        base_color: Rgb,
        #[serde(default)]
        texture: Option<String>,
        #[serde(default)]
        metallic: f32,
        #[serde(default = "default_roughness")]
        roughness: f32,
        #[serde(default = "one")]
        specular: f32,
        #[serde(default = "ior_glass")]
        ior: f32,
        #[serde(default)]
        transmission: f32,
    },
    /// Emits only (black surface): a light.
    Emitter {},
    /// No scattering: light crosses the surface unchanged (a medium's boundary).
    Interface {},
}

fn default_roughness() -> f32 {
    0.5
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JTransform {
    #[serde(default)]
    translate: Option<[f32; 3]>,
    /// Euler angles in degrees, applied about X, then Y, then Z.
    #[serde(default)]
    rotate: Option<[f32; 3]>,
    #[serde(default)]
    scale: Option<JScale>,
    /// A full 4×4 matrix, rows as arrays (row-major, as written on paper).
    #[serde(default)]
    matrix: Option<[[f32; 4]; 4]>,
}

#[derive(Deserialize)]
#[serde(untagged)]
#[serde(expecting = "expected a number or an array of 3 numbers")]
enum JScale {
    Uniform(f32),
    Axes([f32; 3]),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JObject {
    #[serde(default)]
    name: Option<String>,
    shape: Tagged<JShape>,
    #[serde(default)]
    material: Option<String>,
    #[serde(default)]
    transform: Option<JTransform>,
    /// The medium inside the object's closed surface.
    #[serde(default)]
    interior: Option<String>,
    /// The medium outside it (the scene's `medium` if not given).
    #[serde(default)]
    exterior: Option<String>,
}

/// A participating medium; coefficients per metre, multiplied by `scale` (and by the density
/// of a grid).
#[derive(Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum JMedium {
    Homogeneous {
        sigma_a: Rgb,
        sigma_s: Rgb,
        #[serde(default)]
        g: f32,
        #[serde(default = "one")]
        scale: f32,
    },
    /// A density grid from a file (`.vol` or `.vdb`), filling the box the file states.
    Grid {
        path: PathBuf,
        /// The `.vdb` grid to read (default: `density`, else the only float grid).
        #[serde(default)]
        grid: Option<String>,
        #[serde(default)]
        majorant_resolution: Option<[u32; 3]>,
        sigma_a: Rgb,
        sigma_s: Rgb,
        #[serde(default)]
        g: f32,
        #[serde(default = "one")]
        scale: f32,
    },
    /// A procedural smoke density (fractal value noise) baked into a grid over [min, max].
    Noise {
        #[serde(default = "noise_resolution")]
        resolution: [u32; 3],
        #[serde(default = "minus_one3")]
        min: [f32; 3],
        #[serde(default = "one3")]
        max: [f32; 3],
        #[serde(default)]
        seed: u32,
        #[serde(default = "noise_frequency")]
        frequency: f32,
        #[serde(default = "noise_octaves")]
        octaves: u32,
        #[serde(default = "noise_threshold")]
        threshold: f32,
        #[serde(default = "noise_gain")]
        gain: f32,
        #[serde(default)]
        majorant_resolution: Option<[u32; 3]>,
        sigma_a: Rgb,
        sigma_s: Rgb,
        #[serde(default)]
        g: f32,
        #[serde(default = "one")]
        scale: f32,
    },
}

fn noise_resolution() -> [u32; 3] {
    [32; 3]
}
fn minus_one3() -> [f32; 3] {
    [-1.0; 3]
}
fn one3() -> [f32; 3] {
    [1.0; 3]
}
fn noise_frequency() -> f32 {
    crate::medium::NoiseDensity::default().frequency
}
fn noise_octaves() -> u32 {
    crate::medium::NoiseDensity::default().octaves
}
fn noise_threshold() -> f32 {
    crate::medium::NoiseDensity::default().threshold
}
fn noise_gain() -> f32 {
    crate::medium::NoiseDensity::default().gain
}

/// Most voxels a `noise` medium may bake (128³): baking costs time when the scene loads.
const MAX_NOISE_VOXELS: u64 = 128 * 128 * 128;

#[derive(Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum JShape {
    Sphere {
        #[serde(default)]
        center: [f32; 3],
        #[serde(default = "one")]
        radius: f32,
    },
    Box {
        min: [f32; 3],
        max: [f32; 3],
    },
    Plane {
        #[serde(default)]
        point: [f32; 3],
        #[serde(default = "default_up")]
        normal: [f32; 3],
    },
    Disk {
        #[serde(default)]
        center: [f32; 3],
        #[serde(default = "default_up")]
        normal: [f32; 3],
        #[serde(default = "one")]
        radius: f32,
    },
    Rectangle {
        corner: [f32; 3],
        edge_u: [f32; 3],
        edge_v: [f32; 3],
    },
    Polygon {
        vertices: Vec<[f32; 3]>,
    },
    Quadric {
        /// The symmetric matrix Q (rows), for pᵀQp = 0.
        matrix: [[f32; 4]; 4],
        clip_min: [f32; 3],
        clip_max: [f32; 3],
    },
    /// x²/a² + y²/b² + z²/c² = 1.
    Ellipsoid {
        radii: [f32; 3],
    },
    /// x² + z² = r² about the Y axis, for y in [y_min, y_max].
    Cylinder {
        radius: f32,
        y_min: f32,
        y_max: f32,
    },
    /// x² + z² = (tan(angle)·y)², apex at the origin, for y in [y_min, y_max].
    Cone {
        /// Half-angle in degrees.
        angle: f32,
        y_min: f32,
        y_max: f32,
    },
    /// y = a·(x² + z²), for y ≤ y_max.
    Paraboloid {
        a: f32,
        y_max: f32,
    },
    /// x²/a² + z²/a² − y²/c² = 1 (one sheet), for y in [y_min, y_max].
    Hyperboloid {
        a: f32,
        c: f32,
        y_min: f32,
        y_max: f32,
    },
    Mesh {
        positions: Vec<[f32; 3]>,
        indices: Vec<[u32; 3]>,
        #[serde(default)]
        normals: Vec<[f32; 3]>,
        #[serde(default)]
        uvs: Vec<[f32; 2]>,
    },
    /// Every object, light and camera of a glTF file (path relative to this file).
    Gltf {
        path: PathBuf,
    },
}

#[derive(Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum JLight {
    Point {
        position: [f32; 3],
        intensity: Rgb,
        #[serde(default)]
        range: Option<f32>,
    },
    Spot {
        position: [f32; 3],
        #[serde(default)]
        direction: Option<[f32; 3]>,
        #[serde(default)]
        look_at: Option<[f32; 3]>,
        intensity: Rgb,
        /// Degrees.
        #[serde(default)]
        inner_angle: f32,
        /// Degrees.
        #[serde(default = "default_spot")]
        outer_angle: f32,
        #[serde(default)]
        range: Option<f32>,
    },
    Directional {
        direction: [f32; 3],
        irradiance: Rgb,
    },
}

fn default_spot() -> f32 {
    30.0
}

#[derive(Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum JEnvironment {
    Constant {
        radiance: Rgb,
    },
    Map {
        path: PathBuf,
        #[serde(default = "one")]
        scale: f32,
        /// Degrees about +Y.
        #[serde(default)]
        rotation: f32,
    },
}

/// Loads a JSON scene file; its paths may name any file of the user's (the trusted policy).
pub fn load_json(path: &Path) -> Result<SceneDesc, SceneError> {
    load_json_files(path, &SceneFiles::trusted())
}

/// Loads a JSON scene file, reading it and every file it names (recursively: the files of the
/// glTF files it includes) through `files`.
pub fn load_json_files(path: &Path, files: &SceneFiles) -> Result<SceneDesc, SceneError> {
    let err = |message: String| SceneError::Json {
        path: path.to_path_buf(),
        message,
    };
    let (r, bytes) = files
        .read_scene(path, u64::MAX)
        .map_err(|e| err(e.refusal.to_string()))?;
    let text = String::from_utf8(bytes).map_err(|_| err("the file is not UTF-8 text".into()))?;
    files
        .enter(&r, "")
        .map_err(|e| err(e.refusal.to_string()))?;
    let desc = parse_json_files(&text, folder_of(path), path, files);
    files.leave();
    desc
}

/// Parses JSON scene text; relative paths resolve against `base` (the trusted policy); `name`
/// is used in messages.
pub fn parse_json(text: &str, base: &Path, name: &Path) -> Result<SceneDesc, SceneError> {
    parse_json_files(text, base, name, &SceneFiles::trusted())
}

/// Parses JSON scene text, reading the files it names through `files`.
fn parse_json_files(
    text: &str,
    base: &Path,
    name: &Path,
    files: &SceneFiles,
) -> Result<SceneDesc, SceneError> {
    // Some editors start a UTF-8 file with a byte order mark, which JSON parsers refuse.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let tree = parse_tree_bytes(text.len());
    files
        .charge_memory(tree, "the scene's JSON text")
        .map_err(json_error(name))?;
    let parsed = parse_text(text, base, name, files);
    files.release_memory(tree);
    parsed
}

/// How many bytes of parsed JSON values a byte of scene text may become, at most.
const JSON_TREE_BYTES_PER_BYTE: u64 = 32;

/// Scene text not charged for its parse: a scene of materials, lights and analytic shapes.
const UNCHARGED_TEXT: usize = 64 << 10;

/// The memory charged for parsing `len` bytes of scene text: a shape is read into a tree of
/// JSON values before it is converted, up to [`JSON_TREE_BYTES_PER_BYTE`] bytes of tree per
/// byte of text (a mesh's list of numbers), held while the scene is parsed. The first
/// [`UNCHARGED_TEXT`] bytes are free (at most 2 MiB of tree).
fn parse_tree_bytes(len: usize) -> u64 {
    (len.saturating_sub(UNCHARGED_TEXT) as u64).saturating_mul(JSON_TREE_BYTES_PER_BYTE)
}

/// An error in the JSON scene `name`, from its message.
fn json_error(name: &Path) -> impl Fn(String) -> SceneError + '_ {
    move |message| SceneError::Json {
        path: name.to_path_buf(),
        message,
    }
}

/// [`parse_json_files`] once the parse's memory is charged.
fn parse_text(
    text: &str,
    base: &Path,
    name: &Path,
    files: &SceneFiles,
) -> Result<SceneDesc, SceneError> {
    let err = json_error(name);
    let mut de = serde_json::Deserializer::from_str(text);
    // Every struct from a JSON object only (serde would also take an array of its fields).
    let objects = raytile_proto::json::Objects(&mut de);
    let file: File = serde_path_to_error::deserialize(objects).map_err(|e| {
        let inner = e.inner();
        let mut path = e.path().to_string();
        let msg = inner.to_string();
        // serde_json appends " at line L column C" itself; keep one copy.
        let msg = msg.split(" at line ").next().unwrap_or(&msg);
        let mut place = format!("line {}, column {}", inner.line(), inner.column());
        // serde_json says "trailing characters" (a syntax error) for an array longer than
        // its value, which is the value's error, said at its path.
        if matches!(
            inner.classify(),
            serde_json::error::Category::Syntax | serde_json::error::Category::Eof
        ) && msg != "trailing characters"
        {
            // Text that is not JSON: its place, and the value it was in where that is known
            // (serde_path_to_error writes `?` for a part it does not know, `.` for the root).
            // (A path of more than 200 bytes, as nesting deeper than serde_json reads makes,
            // is left out.)
            let known = path.split('?').next().unwrap_or("").trim_end_matches('.');
            let within = if known.is_empty() || known.len() > 200 {
                String::new()
            } else {
                format!(", in {known}")
            };
            return err(format!("not valid JSON ({place}{within}): {msg}"));
        }
        // An error inside a `type`d value: its path there, and the line of the value it names
        // (serde's position is where the whole value ends).
        let msg = match msg
            .strip_prefix(SUBPATH)
            .and_then(|m| m.split_once(SUBPATH))
        {
            Some((sub, m)) => {
                if !sub.is_empty() {
                    path = if sub.starts_with('[') {
                        format!("{path}{sub}")
                    } else {
                        format!("{path}.{sub}")
                    };
                }
                if let Some(pos) = value_at(text, &path) {
                    place = format!("line {}", text[..pos].matches('\n').count() + 1);
                }
                m
            }
            None => msg,
        };
        let mut msg = raytile_proto::json::plain_message(msg);
        if path.starts_with("materials.") && msg.starts_with("unknown field") {
            // serde lists only the fields of the material's type.
            msg.push_str(" (and every material takes `emission` and `two_sided`)");
        }
        err(format!("at {path} ({place}): {msg}"))
    })?;
    de.end().map_err(|e| {
        err(format!(
            "trailing characters (line {}, column {})",
            e.line(),
            e.column()
        ))
    })?;
    let line_of = |at: &str, needle: &str| -> String {
        value_at(text, at)
            .or_else(|| text.find(needle))
            .map_or(String::new(), |pos| {
                format!(" (line {})", text[..pos].matches('\n').count() + 1)
            })
    };
    Converter {
        base,
        name,
        files,
        line_of: &line_of,
        images: RefCell::default(),
        grids: RefCell::default(),
        desc: SceneDesc::default(),
    }
    .convert(file)
}

/// How many edges of a triangle mesh belong to one triangle, or to more than two (a closed
/// surface has none). Vertices at the same position count as one, so a mesh whose seams
/// repeat vertices (for normals or texture coordinates) is closed if its surface is.
fn open_edges(positions: &[[f32; 3]], indices: &[[u32; 3]]) -> usize {
    let mut first: HashMap<[u32; 3], u32> = HashMap::with_capacity(positions.len());
    let weld: Vec<u32> = (0..positions.len() as u32)
        .map(|i| {
            *first
                .entry(positions[i as usize].map(f32::to_bits))
                .or_insert(i)
        })
        .collect();
    let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(indices.len() * 3 / 2);
    for t in indices {
        // Indices were checked against the positions; an unwelded one cannot occur.
        let v = t.map(|i| weld.get(i as usize).copied().unwrap_or(i));
        for (a, b) in [(v[0], v[1]), (v[1], v[2]), (v[2], v[0])] {
            if a != b {
                *edges.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
    }
    edges.values().filter(|&&n| n != 2).count()
}

/// Whether a closed mesh faces inward: its signed volume (corners counter-clockwise seen from
/// outside count positive) is negative by more than rounding. A mirroring transform does not
/// change this: the renderer flips the front face of a mirrored object.
fn wound_inward(positions: &[[f32; 3]], indices: &[[u32; 3]]) -> bool {
    // About one of the mesh's own corners, so that a mesh far from the origin is judged as
    // well as one at it.
    let origin = indices
        .first()
        .and_then(|t| positions.get(t[0] as usize))
        .map_or([0.0; 3], |p| p.map(f64::from));
    let corner = |i: u32| {
        positions
            .get(i as usize)
            .map(|p| [0, 1, 2].map(|k| f64::from(p[k]) - origin[k]))
    };
    let mut volume = 0.0;
    let mut scale = 0.0f64;
    for t in indices {
        let (Some(a), Some(b), Some(c)) = (corner(t[0]), corner(t[1]), corner(t[2])) else {
            continue;
        };
        let cross = [
            b[1] * c[2] - b[2] * c[1],
            b[2] * c[0] - b[0] * c[2],
            b[0] * c[1] - b[1] * c[0],
        ];
        let term = a[0] * cross[0] + a[1] * cross[1] + a[2] * cross[2];
        volume += term;
        scale += term.abs();
    }
    volume < -1e-6 * scale
}

/// Density grids read so far, by canonical path and the `grid` asked for: (grid, file bytes).
type GridCache = HashMap<(PathBuf, Option<String>), (crate::medium::LoadedGrid, u64)>;

struct Converter<'a> {
    base: &'a Path,
    name: &'a Path,
    /// Reads every file the scene names.
    files: &'a SceneFiles,
    /// The line of the value at a JSON path, else of the first `needle`, as " (line N)".
    line_of: &'a dyn Fn(&str, &str) -> String,
    /// Images decoded so far, by canonical path: (width, height, texels, file bytes).
    images: RefCell<HashMap<PathBuf, (u32, u32, Texels, u64)>>,
    /// Density grids read so far.
    grids: RefCell<GridCache>,
    desc: SceneDesc,
}

/// Where in the JSON `text` the value at `path` starts (`objects[1].transform`,
/// `materials.wood.ior`: members joined by dots, elements as `[i]`, as the loader and
/// `serde_path_to_error` write paths), or the deepest value on the way to it that exists
/// (an object that lacks the member); `None` when not even the first step exists. Only used
/// to point at an error, so it walks the text again rather than keep positions of every value.
fn value_at(text: &str, path: &str) -> Option<usize> {
    /// Walks the value at `*i`, whose path `here` leads to `path`; returns the position of
    /// the deepest value on the way that exists, and the length of its path.
    fn walk(b: &[u8], i: &mut usize, here: &str, path: &str, depth: u32) -> (usize, usize) {
        skip_ws(b, i);
        let start = (*i, here.len());
        if here == path || depth > 200 {
            // The value is stepped over, so that the walk stays in step with the text.
            skip_value(b, i);
            return start;
        }
        let mut deepest = start;
        let mut child = |i: &mut usize, sub: String| {
            let leads = path.starts_with(&sub)
                && matches!(path.as_bytes().get(sub.len()), None | Some(b'.' | b'['));
            if leads {
                let d = walk(b, i, &sub, path, depth + 1);
                if d.1 > deepest.1 {
                    deepest = d;
                }
            } else {
                skip_value(b, i);
            }
        };
        match b.get(*i) {
            Some(b'{') => {
                *i += 1;
                loop {
                    skip_ws(b, i);
                    let before = *i;
                    match b.get(*i) {
                        Some(b'}') | None => break,
                        Some(b',') => *i += 1,
                        _ => {
                            let key_start = *i + 1;
                            skip_string(b, i);
                            let key_end = i.saturating_sub(1).max(key_start);
                            let key = String::from_utf8_lossy(&b[key_start..key_end]);
                            skip_ws(b, i);
                            if b.get(*i) == Some(&b':') {
                                *i += 1;
                            }
                            let sub = match here.is_empty() {
                                true => key.into_owned(),
                                false => format!("{here}.{key}"),
                            };
                            child(i, sub);
                        }
                    }
                    // Text the walk cannot read (it was parsed already, so never): stop.
                    if *i <= before {
                        break;
                    }
                }
                *i += 1;
            }
            Some(b'[') => {
                *i += 1;
                let mut n = 0;
                loop {
                    skip_ws(b, i);
                    let before = *i;
                    match b.get(*i) {
                        Some(b']') | None => break,
                        Some(b',') => *i += 1,
                        _ => {
                            child(i, format!("{here}[{n}]"));
                            n += 1;
                        }
                    }
                    if *i <= before {
                        break;
                    }
                }
                *i += 1;
            }
            _ => skip_value(b, i),
        }
        deepest
    }
    /// Skips the value at `*i` (after white space), however deep, without recursion.
    fn skip_value(b: &[u8], i: &mut usize) {
        skip_ws(b, i);
        let mut depth = 0usize;
        loop {
            match b.get(*i) {
                None => return,
                Some(b'"') => skip_string(b, i),
                Some(b'{' | b'[') => {
                    depth += 1;
                    *i += 1;
                }
                Some(b'}' | b']') => {
                    if depth == 0 {
                        return;
                    }
                    depth -= 1;
                    *i += 1;
                }
                Some(b',') if depth == 0 => return,
                Some(_) => *i += 1,
            }
            if depth == 0 && matches!(b.get(*i), None | Some(b',' | b'}' | b']')) {
                return;
            }
        }
    }
    fn skip_ws(b: &[u8], i: &mut usize) {
        while b.get(*i).is_some_and(u8::is_ascii_whitespace) {
            *i += 1;
        }
    }
    /// Skips the string at `*i` (its opening quote) and its closing quote.
    fn skip_string(b: &[u8], i: &mut usize) {
        *i += 1;
        while let Some(&c) = b.get(*i) {
            *i += 1;
            match c {
                b'\\' => *i += 1,
                b'"' => return,
                _ => {}
            }
        }
    }
    let (pos, len) = walk(text.as_bytes(), &mut 0, "", path, 0);
    (len > 0).then_some(pos)
}

fn v3(a: [f32; 3]) -> Vec3 {
    Vec3::from(a)
}

impl Converter<'_> {
    fn err(&self, at: &str, msg: impl std::fmt::Display, needle: &str) -> SceneError {
        SceneError::Json {
            path: self.name.to_path_buf(),
            message: format!("at {at}{}: {msg}", (self.line_of)(at, needle)),
        }
    }

    /// Reads the file the scene names at `at` (a JSON path: `textures.wood.path`), at most
    /// `cap` bytes.
    fn read_file(
        &self,
        at: &str,
        path: &Path,
        cap: u64,
    ) -> Result<(Resolved, Vec<u8>), SceneError> {
        let needle = path.to_string_lossy();
        let refused = |e: FileError| self.err(at, e.describe(), &needle);
        let r = self
            .files
            .resolve_path(self.base, path, at)
            .map_err(refused)?;
        let bytes = self.files.read(&r, at, cap).map_err(refused)?;
        Ok((r, bytes))
    }

    /// Decodes the image file the scene names at `at` (PNG, JPEG, Radiance HDR, OpenEXR; see
    /// [`super::image`] for the limits) into a texture: sRGB colour, repeated, bilinear. Its
    /// texels are charged to the scene's memory budget before they are decoded.
    fn image(&self, at: &str, path: &Path) -> Result<TextureDesc, SceneError> {
        let needle = path.to_string_lossy();
        let texture = |width, height, texels| TextureDesc {
            name: path.display().to_string(),
            width,
            height,
            texels,
            srgb: true,
            wrap_u: WrapMode::Repeat,
            wrap_v: WrapMode::Repeat,
            bilinear: true,
        };
        // An image several textures name is read and decoded once; they share its texels.
        let r = self
            .files
            .resolve_path(self.base, path, at)
            .map_err(|e| self.err(at, e.describe(), &needle))?;
        if let Some((w, h, texels, bytes)) = self.images.borrow().get(&r.canonical) {
            // Recorded by this name too: a package for a farm must carry it.
            self.files.note_used(&r, *bytes);
            return Ok(texture(*w, *h, texels.clone()));
        }
        let (r, bytes) = self.read_file(at, path, super::image::MAX_IMAGE_FILE)?;
        let shown = show(&needle);
        let bad = |e: String| self.err(at, format!("{shown}: {e}"), &needle);
        self.files
            .charge_memory(super::image::image_bytes(&bytes).map_err(bad)?, &shown)
            .map_err(|e| self.err(at, e, &needle))?;
        let img = super::image::decode_image(&bytes).map_err(bad)?;
        let entry = (
            img.width,
            img.height,
            img.texels.clone(),
            bytes.len() as u64,
        );
        self.images.borrow_mut().insert(r.canonical, entry);
        Ok(texture(img.width, img.height, img.texels))
    }

    /// Reads the density grid `grid` (a `.vdb` grid name) of the file the scene names at `at`
    /// (`media.NAME.path`), its voxels charged to the scene's memory budget. Media that name
    /// the same file and grid share one decoded grid, read and charged once.
    fn grid_file(
        &self,
        at: &str,
        path: &Path,
        grid: &Option<String>,
    ) -> Result<crate::medium::LoadedGrid, SceneError> {
        let needle = path.to_string_lossy();
        let r = self
            .files
            .resolve_path(self.base, path, at)
            .map_err(|e| self.err(at, e.describe(), &needle))?;
        let key = (r.canonical.clone(), grid.clone());
        if let Some((loaded, bytes)) = self.grids.borrow().get(&key) {
            // Recorded by this name too: a package for a farm must carry it.
            self.files.note_used(&r, *bytes);
            return Ok(loaded.clone());
        }
        let limits = crate::medium::GridLimits::default();
        let (r, bytes) = self.read_file(at, path, limits.max_file_bytes)?;
        let loaded = crate::medium::load_grid_bytes(&bytes, &r.named, grid.as_deref(), &limits)
            .map_err(|e| self.err(at, e, &needle))?;
        // The same grid by another name (`"grid": "density"` and no `grid`, which picks it):
        // held and charged once.
        let same = self
            .grids
            .borrow()
            .iter()
            .find(|((p, _), (g, _))| *p == r.canonical && *g == loaded)
            .map(|(_, (g, _))| g.clone());
        if let Some(shared) = same {
            self.grids
                .borrow_mut()
                .insert(key, (shared.clone(), bytes.len() as u64));
            return Ok(shared);
        }
        self.files
            .charge_memory(
                std::mem::size_of_val(loaded.density.values()) as u64,
                &show(&needle),
            )
            .map_err(|e| self.err(at, e, &needle))?;
        self.grids
            .borrow_mut()
            .insert(key, (loaded.clone(), bytes.len() as u64));
        Ok(loaded)
    }

    /// Loads the glTF file the scene includes at `at`; a file that is already being loaded
    /// (the scene itself) is refused rather than loaded again.
    fn include(&self, at: &str, path: &Path) -> Result<SceneDesc, SceneError> {
        let needle = path.to_string_lossy();
        let refused = |e: FileError| self.err(at, e.describe(), &needle);
        let r = self
            .files
            .resolve_path(self.base, path, at)
            .map_err(refused)?;
        self.files.enter(&r, at).map_err(refused)?;
        let desc = self
            .files
            .read(&r, at, super::gltf::MAX_FILE_BYTES)
            .map_err(refused)
            .and_then(|bytes| {
                // The including scene states its own light: an unlit model gets no default
                // environment of its own (which the merge would drop, warning and all). Nor
                // a camera of its own: the scene's cameras are its own and those the file
                // has (without any, the renderer frames the whole scene).
                let opts = super::gltf::GltfOptions {
                    default_light: false,
                    default_camera: false,
                    ..Default::default()
                };
                super::gltf::load_gltf_bytes(&bytes, &r.named, &opts, self.files)
                    .map_err(|e| self.err(at, e, &needle))
            });
        self.files.leave();
        desc
    }

    fn convert(mut self, f: File) -> Result<SceneDesc, SceneError> {
        // Names were checked by serde (typed fields); ranges are checked here, so that a scene
        // asking for `"spp": 0` is refused when it is loaded, not when it is rendered.
        if let Err(e) = f.render.to_overrides().check() {
            let needle = format!("\"{}\"", e.field);
            return Err(self.err(&format!("render.{}", e.field), e.message, &needle));
        }
        self.desc.render = f.render;
        // Textures.
        let mut tex_index = BTreeMap::new();
        let mut spaces = HashSet::new();
        for (name, t) in &f.textures {
            let at = format!("textures.{name}");
            let (JTexture::Image { uv, .. } | JTexture::Checker { uv, .. }) = &t.0;
            let uv = uv.matrix().map_err(|field| {
                self.err(
                    &format!("{at}.uv.{field}"),
                    format!("uv {field} must be finite"),
                    &format!("\"{field}\""),
                )
            })?;
            let desc = match &t.0 {
                JTexture::Image {
                    path,
                    srgb,
                    wrap,
                    bilinear,
                    ..
                } => {
                    let mut d = self.image(&format!("{at}.path"), path)?;
                    // An f32 image is converted for each of colour and data it is read as
                    // (`Scene::build`): its second reading is charged once more.
                    if let Texels::F32(values) = &d.texels {
                        let image = Arc::as_ptr(values) as usize;
                        if spaces.insert((image, *srgb)) && spaces.contains(&(image, !*srgb)) {
                            let bytes = 16 * u64::from(d.width) * u64::from(d.height);
                            let what = format!(
                                "{} as {}",
                                show(&path.to_string_lossy()),
                                if *srgb { "colour" } else { "data" }
                            );
                            self.files
                                .charge_memory(bytes, &what)
                                .map_err(|e| self.err(&format!("{at}.srgb"), e, name))?;
                        }
                    }
                    d.name = name.clone();
                    d.srgb = *srgb;
                    d.wrap_u = *wrap;
                    d.wrap_v = *wrap;
                    d.bilinear = *bilinear;
                    (d, uv)
                }
                JTexture::Checker {
                    even, odd, scale, ..
                } => {
                    if !(*scale > 0.0 && scale.is_finite()) {
                        return Err(self.err(&at, "checker scale must be positive", name));
                    }
                    // A texture gives a material's albedo or base colour: a reflectance.
                    for (field, c) in [("even", even), ("odd", odd)] {
                        check_reflectance(field, v3(*c))
                            .map_err(|e| self.err(&format!("{at}.{field}"), e, name))?;
                    }
                    let (e, o) = (
                        [even[0], even[1], even[2], 1.0],
                        [odd[0], odd[1], odd[2], 1.0],
                    );
                    let d = TextureDesc {
                        name: name.clone(),
                        width: 2,
                        height: 2,
                        texels: vec![e, o, o, e].into(),
                        srgb: false,
                        wrap_u: WrapMode::Repeat,
                        wrap_v: WrapMode::Repeat,
                        bilinear: false,
                    };
                    // Two texels per check pair: scale uv so `scale` checks fit one unit
                    // (after the texture's own transform).
                    (d, Mat3::from_scale(Vec2::splat(*scale * 0.5)) * uv)
                }
            };
            tex_index.insert(name.clone(), (self.desc.textures.len(), desc.1));
            self.desc.textures.push(desc.0);
        }
        let tex_ref = |this: &Self,
                       at: &str,
                       name: &Option<String>|
         -> Result<Option<TextureRef>, SceneError> {
            match name {
                None => Ok(None),
                Some(n) => match tex_index.get(n) {
                    Some(&(texture, transform)) => Ok(Some(TextureRef {
                        texture,
                        texcoord: 0,
                        transform,
                    })),
                    None => {
                        Err(this.err(at, format!("unknown texture '{n}'"), &format!("\"{n}\"")))
                    }
                },
            }
        };
        // Materials.
        let mut mat_index = BTreeMap::new();
        for (name, m) in &f.materials {
            let at = format!("materials.{name}");
            let bsdf = match &m.bsdf {
                JBsdf::Diffuse { albedo, texture } => BsdfDesc::Diffuse {
                    albedo: v3(*albedo),
                    texture: tex_ref(&self, &format!("{at}.texture"), texture)?,
                },
                JBsdf::Mirror { reflectance } => BsdfDesc::Mirror {
                    reflectance: v3(*reflectance),
                },
                JBsdf::Dielectric {
                    ior,
                    transmittance,
                    absorption,
                    thin,
                } => {
                    check_ior(*ior).map_err(|e| self.err(&format!("{at}.ior"), e, name))?;
                    check_coefficient("absorption", v3(*absorption))
                        .map_err(|e| self.err(&format!("{at}.absorption"), e, name))?;
                    BsdfDesc::Dielectric {
                        ior: *ior,
                        transmittance: v3(*transmittance),
                        absorption: v3(*absorption),
                        thin: *thin,
                    }
                }
                JBsdf::Conductor {
                    preset,
                    eta,
                    k,
                    roughness,
                } => {
                    check_unit("roughness", *roughness)
                        .map_err(|e| self.err(&format!("{at}.roughness"), e, name))?;
                    let (pe, pk) = match preset.as_deref() {
                        None => ([0.2, 0.92, 1.1], [3.9, 2.45, 2.14]),
                        Some(p) => metal_preset(p).ok_or_else(|| {
                            self.err(&format!("{at}.preset"), format!("unknown metal '{p}' (gold, silver, copper, aluminium, iron, chrome)"), p)
                        })?,
                    };
                    BsdfDesc::Conductor {
                        eta: v3(eta.unwrap_or(pe)),
                        k: v3(k.unwrap_or(pk)),
                        alpha: roughness.powi(2),
                    }
                }
                JBsdf::RoughDielectric {
                    ior,
                    roughness,
                    transmittance,
                } => {
                    check_ior(*ior).map_err(|e| self.err(&format!("{at}.ior"), e, name))?;
                    check_unit("roughness", *roughness)
                        .map_err(|e| self.err(&format!("{at}.roughness"), e, name))?;
                    BsdfDesc::RoughDielectric {
                        ior: *ior,
                        alpha: roughness.powi(2),
                        transmittance: v3(*transmittance),
                    }
                }
                JBsdf::Pbr {
                    base_color,
                    texture,
                    metallic,
                    roughness,
                    specular,
                    ior,
                    transmission,
                } => {
                    for (field, x) in [
                        ("metallic", metallic),
                        ("roughness", roughness),
                        ("specular", specular),
                        ("transmission", transmission),
                    ] {
                        check_unit(field, *x)
                            .map_err(|e| self.err(&format!("{at}.{field}"), e, name))?;
                    }
                    check_ior(*ior).map_err(|e| self.err(&format!("{at}.ior"), e, name))?;
                    BsdfDesc::Pbr(Box::new(PbrDesc {
                        base_color: [base_color[0], base_color[1], base_color[2], 1.0],
                        base_color_texture: tex_ref(&self, &format!("{at}.texture"), texture)?,
                        metallic: *metallic,
                        roughness: *roughness,
                        specular: *specular,
                        ior: *ior,
                        transmission: *transmission,
                        ..PbrDesc::default()
                    }))
                }
                JBsdf::Emitter {} => BsdfDesc::Diffuse {
                    albedo: Vec3::ZERO,
                    texture: None,
                },
                JBsdf::Interface {} => BsdfDesc::Interface,
            };
            if let Some((field, v)) = bsdf.tint() {
                check_reflectance(field, v)
                    .map_err(|e| self.err(&format!("{at}.{field}"), e, name))?;
            }
            if let BsdfDesc::Conductor { eta, k, .. } = &bsdf {
                check_metal(*eta, *k)
                    .map_err(|(field, e)| self.err(&format!("{at}.{field}"), e, name))?;
            }
            let mut md = MaterialDesc::new(name.clone(), bsdf);
            md.emission = v3(m.emission);
            md.two_sided = m.two_sided;
            check_radiance("emission", md.emission.into())
                .map_err(|e| self.err(&format!("{at}.emission"), e, name))?;
            if matches!(md.bsdf, BsdfDesc::Interface) && md.emission != Vec3::ZERO {
                return Err(self.err(
                    &format!("{at}.emission"),
                    "an interface (a medium boundary) neither scatters nor emits: remove \
                     `emission`, or give a glowing surface a material of its own",
                    "\"emission\"",
                ));
            }
            mat_index.insert(name.clone(), self.desc.materials.len());
            self.desc.materials.push(md);
        }
        // Media.
        let mut medium_index = BTreeMap::new();
        for (name, m) in &f.media {
            let desc = self.medium(name, &m.0)?;
            medium_index.insert(name.clone(), self.desc.media.len());
            self.desc.media.push(desc);
        }
        let find_medium = |this: &Self, at: &str, n: &str| -> Result<usize, SceneError> {
            medium_index.get(n).copied().ok_or_else(|| {
                let known: Vec<_> = medium_index.keys().map(String::as_str).collect();
                this.err(
                    at,
                    format!(
                        "unknown medium '{n}' (known: {})",
                        if known.is_empty() {
                            "none: define it under `media`".to_string()
                        } else {
                            known.join(", ")
                        }
                    ),
                    &format!("\"{n}\""),
                )
            })
        };
        if let Some(n) = &f.medium {
            self.desc.medium = Some(find_medium(&self, "medium", n)?);
        }
        // Objects.
        for (i, o) in f.objects.iter().enumerate() {
            let at = format!("objects[{i}]");
            let transform = match &o.transform {
                Some(t) => transform(t)
                    .map_err(|e| self.err(&format!("{at}.transform"), e, "\"transform\""))?,
                None => Mat4::IDENTITY,
            };
            let name = o.name.clone().unwrap_or_else(|| format!("object {i}"));
            if let JShape::Gltf { path } = &o.shape.0 {
                if o.interior.is_some() || o.exterior.is_some() {
                    return Err(self.err(
                        &at,
                        "`interior` and `exterior` apply to one closed shape, not to a glTF include",
                        "\"interior\"",
                    ));
                }
                if let Some(m) = &o.material {
                    return Err(self.err(
                        &format!("{at}.material"),
                        "a glTF include takes its materials from the file: remove `material`",
                        &format!("\"{m}\""),
                    ));
                }
                let inc = self.include(&format!("{at}.shape.path"), path)?;
                self.merge(inc, transform);
                continue;
            }
            let material = match &o.material {
                Some(m) => *mat_index.get(m).ok_or_else(|| {
                    let known: Vec<_> = mat_index.keys().map(String::as_str).collect();
                    self.err(
                        &format!("{at}.material"),
                        format!("unknown material '{m}' (known: {})", known.join(", ")),
                        &format!("\"{m}\""),
                    )
                })?,
                None => {
                    return Err(self.err(&at, "missing field `material`", &format!("\"{name}\"")))
                }
            };
            let shape = self.shape(&o.shape.0, &name, &at)?;
            let m = &self.desc.materials[material];
            if let Some(why) = m
                .emits()
                .then(|| super::build::emit_refusal(&shape))
                .flatten()
            {
                return Err(self.err(
                    &at,
                    format!("its material '{}' emits light, but {why}", m.name),
                    &format!("\"{name}\""),
                ));
            }
            // A flat shape encloses no volume: a ray that crossed it into its `interior` would
            // stay in that medium for ever (behind a disk, everything drawn black).
            let flat = match &o.shape.0 {
                JShape::Disk { .. } => Some("disk"),
                JShape::Rectangle { .. } => Some("rectangle"),
                JShape::Polygon { .. } => Some("polygon"),
                _ => None,
            };
            if let (Some(kind), true) = (flat, o.interior.is_some() || o.exterior.is_some()) {
                let field = if o.interior.is_some() {
                    "interior"
                } else {
                    "exterior"
                };
                return Err(self.err(
                    &format!("{at}.{field}"),
                    format!(
                        "a {kind} encloses no volume: media take a closed surface (a sphere, a \
                         box, a closed mesh) or a plane (a half-space)"
                    ),
                    &format!("\"{field}\""),
                ));
            }
            // An open surface bounds no volume either, but a surface with a few holes (or a
            // mesh whose seams are not welded) renders well enough where rays rarely pass the
            // openings: warned of, not refused.
            if o.interior.is_some() || o.exterior.is_some() {
                let open = match &o.shape.0 {
                    JShape::Cylinder { .. } => Some("a cylinder has no caps".to_string()),
                    JShape::Cone { .. } => Some("a cone has no caps".to_string()),
                    JShape::Paraboloid { .. } => Some("a paraboloid has no cap".to_string()),
                    JShape::Hyperboloid { .. } => Some("a hyperboloid has no caps".to_string()),
                    JShape::Mesh {
                        positions, indices, ..
                    } => match open_edges(positions, indices) {
                        0 => None,
                        n => Some(format!("the mesh has {n} edges on one triangle only")),
                    },
                    _ => None,
                };
                if let Some(why) = open {
                    self.desc.warnings.push(format!(
                        "{at} ('{name}'): {why}, so it encloses no volume: a ray that leaves \
                         its medium through an opening stays in that medium (close the \
                         surface, e.g. with disks or a closed mesh)"
                    ));
                } else if let JShape::Mesh {
                    positions, indices, ..
                } = &o.shape.0
                {
                    if wound_inward(positions, indices) {
                        self.desc.warnings.push(format!(
                            "{at} ('{name}'): the mesh's triangles face inward (their corners \
                             run clockwise seen from outside), so its `interior` medium is \
                             taken to be outside it and its `exterior` inside (list each \
                             triangle's corners the other way round)"
                        ));
                    }
                }
            }
            let media = if o.interior.is_some() || o.exterior.is_some() {
                let side = |field: &str, n: &Option<String>| {
                    n.as_deref()
                        .map(|n| find_medium(&self, &format!("{at}.{field}"), n))
                        .transpose()
                };
                Some(ObjectMedia {
                    interior: side("interior", &o.interior)?,
                    exterior: match &o.exterior {
                        Some(_) => side("exterior", &o.exterior)?,
                        None => self.desc.medium,
                    },
                })
            } else {
                None
            };
            // The grid this object holds is placed by its transform: the two together must be
            // invertible, as the object's transform is.
            if let Some(mi) = media.and_then(|m| m.interior) {
                let medium = &self.desc.media[mi];
                if let Some(grid) = &medium.density {
                    if let Some(d) = Degenerate::of(&(transform * Mat4::from(grid.transform))) {
                        let (field, needle) = match o.transform {
                            Some(_) => (format!("{at}.transform"), "\"transform\"".to_string()),
                            None => (format!("{at}.interior"), format!("\"{}\"", medium.name)),
                        };
                        return Err(self.err(
                            &field,
                            format!(
                                "placing the grid of medium '{}', which it holds: {d}",
                                medium.name
                            ),
                            &needle,
                        ));
                    }
                }
            }
            self.desc.objects.push(ObjectDesc {
                name,
                shape,
                material,
                transform,
                media,
            });
        }
        self.check_grid_exteriors(&f.objects)?;
        // Lights.
        for (i, l) in f.lights.iter().enumerate() {
            let at = format!("lights[{i}]");
            let range = |r: &Option<f32>| r.unwrap_or(f32::INFINITY);
            let (field, value) = match &l.0 {
                JLight::Point { intensity, .. } | JLight::Spot { intensity, .. } => {
                    ("intensity", intensity)
                }
                JLight::Directional { irradiance, .. } => ("irradiance", irradiance),
            };
            check_radiance(field, v3(*value).into())
                .map_err(|e| self.err(&format!("{at}.{field}"), e, &format!("\"{field}\"")))?;
            let light = match &l.0 {
                JLight::Point {
                    position,
                    intensity,
                    range: r,
                } => LightDesc::Point {
                    position: v3(*position),
                    intensity: v3(*intensity),
                    range: range(r),
                },
                JLight::Spot {
                    position,
                    direction,
                    look_at,
                    intensity,
                    inner_angle,
                    outer_angle,
                    range: r,
                } => {
                    let dir = match (direction, look_at) {
                        (Some(d), _) => v3(*d),
                        (None, Some(t)) => v3(*t) - v3(*position),
                        (None, None) => {
                            return Err(self.err(
                                &at,
                                "a spot light needs `direction` or `look_at`",
                                "\"spot\"",
                            ))
                        }
                    };
                    check_spot_angles(*inner_angle, *outer_angle).map_err(|(field, e)| {
                        self.err(&format!("{at}.{field}"), e, &format!("\"{field}\""))
                    })?;
                    LightDesc::Spot {
                        position: v3(*position),
                        direction: dir,
                        intensity: v3(*intensity),
                        inner_angle: inner_angle.to_radians(),
                        outer_angle: outer_angle.to_radians(),
                        range: range(r),
                    }
                }
                JLight::Directional {
                    direction,
                    irradiance,
                } => LightDesc::Directional {
                    direction: v3(*direction),
                    irradiance: v3(*irradiance),
                },
            };
            super::build::check_light(&light).map_err(|e| self.err(&at, e, "\"lights\""))?;
            self.desc.lights.push(light);
        }
        // Environment.
        if let Some(env) = &f.environment {
            self.desc.environment = Some(match &env.0 {
                JEnvironment::Constant { radiance } => {
                    check_radiance("radiance", v3(*radiance).into())
                        .map_err(|e| self.err("environment.radiance", e, "\"radiance\""))?;
                    EnvironmentDesc::Constant {
                        radiance: v3(*radiance),
                    }
                }
                JEnvironment::Map {
                    path,
                    scale,
                    rotation,
                } => {
                    if !(scale.is_finite() && *scale >= 0.0) {
                        return Err(self.err(
                            "environment.scale",
                            "scale must be finite and non-negative",
                            "\"scale\"",
                        ));
                    }
                    if !rotation.is_finite() {
                        return Err(self.err(
                            "environment.rotation",
                            format!("must be a finite number of degrees, got {rotation}"),
                            "\"rotation\"",
                        ));
                    }
                    let mut texture = self.image("environment.path", path)?;
                    check_map(&texture.texels, texture.width, *scale, "scale").map_err(|e| {
                        self.err(
                            "environment",
                            format!("{}: {e}", show(&path.to_string_lossy())),
                            "\"environment\"",
                        )
                    })?;
                    // Its sampling tables (a CDF and the values per texel, 8 bytes, built from
                    // 4 bytes of weights per texel freed after) are held beside the image.
                    let texels = u64::from(texture.width) * u64::from(texture.height);
                    let what = format!(
                        "{} as the environment's sampling tables",
                        show(&path.to_string_lossy())
                    );
                    self.files
                        .charge_memory(12 * texels, &what)
                        .map_err(|e| self.err("environment.path", e, "\"path\""))?;
                    texture.srgb = false;
                    texture.wrap_v = WrapMode::Clamp;
                    EnvironmentDesc::Map {
                        texture,
                        scale: *scale,
                        rotation_y: rotation.to_radians(),
                    }
                }
            });
        }
        // Cameras: `camera` first, then `cameras`.
        let single = usize::from(f.camera.is_some());
        for (i, c) in f.camera.iter().chain(f.cameras.iter()).enumerate() {
            // Errors name the value in the file: `camera`, or its place in `cameras`.
            let at = match i.checked_sub(single) {
                None => "camera".to_string(),
                Some(k) => format!("cameras[{k}]"),
            };
            let cam = self.camera(c, i, &at)?;
            self.desc
                .cameras
                .insert(self.desc.cameras.len().min(i), cam);
        }
        // `render.camera` names one of the cameras now known (its own and its includes').
        if let Some(sel) = self.desc.render.camera.as_deref() {
            let names: Vec<&str> = self.desc.cameras.iter().map(|c| c.name.as_str()).collect();
            if let Err(e) = super::job::pick_camera(&names, Some(sel)) {
                return Err(self.err("render.camera", e.message, &format!("\"{sel}\"")));
            }
        }
        if !self.desc.is_lit() {
            self.desc.warnings.push(UNLIT_WARNING.into());
        }
        Ok(self.desc)
    }

    /// The medium `media.NAME`: coefficients checked, its grid read (through the scene's
    /// resolver, charged to its memory budget) or baked.
    fn medium(&self, name: &str, m: &JMedium) -> Result<MediumDesc, SceneError> {
        let at = format!("media.{name}");
        let (sigma_a, sigma_s, g, scale) = match m {
            JMedium::Homogeneous {
                sigma_a,
                sigma_s,
                g,
                scale,
            }
            | JMedium::Grid {
                sigma_a,
                sigma_s,
                g,
                scale,
                ..
            }
            | JMedium::Noise {
                sigma_a,
                sigma_s,
                g,
                scale,
                ..
            } => (v3(*sigma_a), v3(*sigma_s), *g, *scale),
        };
        let needle = format!("\"{name}\"");
        for (field, v) in [("sigma_a", sigma_a), ("sigma_s", sigma_s)] {
            if !(v.is_finite() && v.min_element() >= 0.0) {
                return Err(self.err(
                    &format!("{at}.{field}"),
                    "must be finite and non-negative in every channel",
                    &needle,
                ));
            }
        }
        if !(g > -1.0 && g < 1.0) {
            return Err(self.err(&format!("{at}.g"), "g must be in (-1, 1)", &needle));
        }
        if !(scale.is_finite() && scale >= 0.0) {
            return Err(self.err(
                &format!("{at}.scale"),
                "scale must be finite and non-negative",
                &needle,
            ));
        }
        let density = match m {
            JMedium::Homogeneous { .. } => None,
            JMedium::Grid {
                path,
                grid,
                majorant_resolution,
                ..
            } => {
                let majorant_resolution = self.majorant(name, &at, majorant_resolution)?;
                let field = format!("{at}.path");
                let loaded = self.grid_file(&field, path, grid)?;
                if let Some(d) = Degenerate::of_affine(&loaded.transform) {
                    let needle = path.to_string_lossy();
                    return Err(self.err(
                        &field,
                        format!("{}: the grid's index-to-world map: {d}", show(&needle)),
                        &needle,
                    ));
                }
                Some(GridDesc {
                    density: loaded.density,
                    transform: loaded.transform,
                    majorant_resolution,
                })
            }
            JMedium::Noise {
                resolution,
                min,
                max,
                seed,
                frequency,
                octaves,
                threshold,
                gain,
                majorant_resolution,
                ..
            } => {
                let voxels = resolution.iter().map(|&r| u64::from(r)).product::<u64>();
                if resolution.contains(&0) || voxels > MAX_NOISE_VOXELS {
                    return Err(self.err(
                        &format!("{at}.resolution"),
                        format!(
                            "between 1 and {MAX_NOISE_VOXELS} voxels in all, each axis at least 1"
                        ),
                        &needle,
                    ));
                }
                if !(frequency.is_finite()
                    && *frequency > 0.0
                    && threshold.is_finite()
                    && gain.is_finite())
                {
                    return Err(self.err(
                        &at,
                        "frequency must be positive, threshold and gain finite",
                        &needle,
                    ));
                }
                if !(1..=16).contains(octaves) {
                    return Err(self.err(
                        &format!("{at}.octaves"),
                        format!("{octaves} octaves: from 1 to 16"),
                        &needle,
                    ));
                }
                let majorant_resolution = self.majorant(name, &at, majorant_resolution)?;
                self.files
                    .charge_memory(voxels * 4, &format!("noise medium '{name}'"))
                    .map_err(|e| self.err(&at, e, &needle))?;
                let bounds =
                    crate::geometry::Aabb::new(Vec3A::from(v3(*min)), Vec3A::from(v3(*max)));
                let noise = crate::medium::NoiseDensity {
                    seed: *seed,
                    frequency: *frequency,
                    octaves: *octaves,
                    threshold: *threshold,
                    gain: *gain,
                };
                let density = crate::medium::DensityGrid::from_fn(
                    resolution.map(|r| r as usize),
                    bounds,
                    |p| noise.density(p),
                )
                .map_err(|e| self.err(&at, e, &needle))?;
                Some(GridDesc {
                    density,
                    transform: glam::Affine3A::IDENTITY,
                    majorant_resolution,
                })
            }
        };
        // Checked here, where the coordinator parses the scene, as well as where it is built.
        let max_density = density.as_ref().map_or(1.0, |d| d.density.max_value());
        // The coefficients as the scene's build scales them (in f32).
        crate::medium::check_extinction(
            Vec3A::from(sigma_a) * scale,
            Vec3A::from(sigma_s) * scale,
            1.0,
            max_density,
            density.is_some(),
        )
        .map_err(|e| self.err(&at, e.to_string(), &needle))?;
        Ok(MediumDesc {
            name: name.to_string(),
            sigma_a,
            sigma_s,
            g,
            scale,
            density,
        })
    }

    /// The `majorant_resolution` of the grid medium `media.NAME` (at `at`), checked, with its
    /// majorant grid (one f32 bound per cell, built once per medium) charged to the scene's
    /// memory budget: 256³ cells take 64 MiB.
    fn majorant(
        &self,
        name: &str,
        at: &str,
        res: &Option<[u32; 3]>,
    ) -> Result<Option<[usize; 3]>, SceneError> {
        let checked = self.majorant_resolution(at, res)?;
        let cells = checked
            .unwrap_or([crate::medium::majorant::DEFAULT_MAJORANT_RES; 3])
            .iter()
            .map(|&c| c as u64)
            .product::<u64>();
        let field = match res {
            Some(_) => format!("{at}.majorant_resolution"),
            None => at.to_string(),
        };
        self.files
            .charge_memory(
                cells * std::mem::size_of::<f32>() as u64,
                &format!("the majorant grid of medium '{name}'"),
            )
            .map_err(|e| self.err(&field, e, &format!("\"{name}\"")))?;
        Ok(checked)
    }

    /// A grid medium's `majorant_resolution`, checked: 1 to 256 cells per axis.
    fn majorant_resolution(
        &self,
        at: &str,
        res: &Option<[u32; 3]>,
    ) -> Result<Option<[usize; 3]>, SceneError> {
        match res {
            None => Ok(None),
            Some(r) if r.iter().all(|&c| (1..=256).contains(&c)) => Ok(Some(r.map(|c| c as usize))),
            Some(_) => Err(self.err(
                &format!("{at}.majorant_resolution"),
                "1 to 256 cells per axis",
                "\"majorant_resolution\"",
            )),
        }
    }

    /// A grid medium is placed by the object that holds it as its interior, so an `exterior`
    /// may name a grid only when one object holds it (or it is the scene's medium, placed by
    /// the world): refused here, naming the JSON path, rather than when the scene is built.
    fn check_grid_exteriors(&self, objects: &[JObject]) -> Result<(), SceneError> {
        // Counted once: a scene of many objects is checked in linear time.
        let mut held = std::collections::HashMap::<&str, usize>::new();
        for name in objects.iter().filter_map(|o| o.interior.as_deref()) {
            *held.entry(name).or_default() += 1;
        }
        let holders = |name: &str| held.get(name).copied().unwrap_or(0);
        for (i, o) in objects.iter().enumerate() {
            let Some(ext) = o.exterior.as_deref() else {
                continue;
            };
            let grid = self
                .desc
                .media
                .iter()
                .position(|m| m.name == ext)
                .filter(|&mi| {
                    self.desc.media[mi].density.is_some() && self.desc.medium != Some(mi)
                });
            if grid.is_some() && holders(ext) > 1 {
                return Err(self.err(
                    &format!("objects[{i}].exterior"),
                    format!(
                        "medium '{ext}' is a grid held by several objects (as their \
                         `interior`), which place it each their own way: an exterior may name \
                         a grid only when it is the scene's medium or one object's interior"
                    ),
                    "\"exterior\"",
                ));
            }
        }
        Ok(())
    }

    fn camera(&self, c: &JCamera, i: usize, at: &str) -> Result<CameraDesc, SceneError> {
        let (pos, target, up) = (v3(c.position), v3(c.look_at), v3(c.up));
        let fwd = target - pos;
        if !(pos.is_finite() && target.is_finite() && up.is_finite() && fwd.is_finite()) {
            return Err(self.err(
                at,
                "camera position, look_at and up must be finite (at most about 3.4e38 in size)",
                "\"look_at\"",
            ));
        }
        // Collinear whatever the scene's scale: the directions are compared, not the vectors.
        let (f, u) = (fwd.normalize_or_zero(), up.normalize_or_zero());
        if f == Vec3::ZERO || u == Vec3::ZERO || f.cross(u).length_squared() <= 1e-12 {
            return Err(self.err(
                at,
                "camera position, look_at and up must be distinct and not collinear",
                "\"look_at\"",
            ));
        }
        // Camera-to-world: the inverse of a right-handed view matrix (camera looks down −Z).
        let f = fwd.normalize();
        // With the unit `up` where the given one's cross product under- or overflows (an `up`
        // of 1e-26 or 1e38); as given otherwise, which keeps the bits scenes have always had.
        let r = match f.cross(up) {
            r if (f32::MIN_POSITIVE..f32::INFINITY).contains(&r.length_squared()) => r.normalize(),
            _ => f.cross(u).normalize(),
        };
        let u = r.cross(f);
        let transform = Mat4::from_cols(
            r.extend(0.0),
            u.extend(0.0),
            (-f).extend(0.0),
            pos.extend(1.0),
        );
        let projection = match c.kind {
            JCameraKind::Perspective => {
                if !(c.fov > 0.0 && c.fov < 180.0) {
                    return Err(self.err(
                        &format!("{at}.fov"),
                        "fov must be between 0 and 180 degrees",
                        "\"fov\"",
                    ));
                }
                Projection::Perspective {
                    yfov: c.fov.to_radians(),
                    aperture_radius: c.aperture,
                    focus_distance: c.focus_distance.unwrap_or(fwd.length()),
                }
            }
            JCameraKind::Orthographic => Projection::Orthographic {
                half_height: c.half_height,
            },
        };
        projection
            .check()
            .map_err(|(field, e)| self.err(&format!("{at}.{field}"), e, &format!("\"{field}\"")))?;
        Ok(CameraDesc {
            name: c.name.clone().unwrap_or_else(|| format!("camera {i}")),
            transform,
            projection,
            aspect: None,
        })
    }

    fn shape(&mut self, s: &JShape, name: &str, at: &str) -> Result<ShapeDesc, SceneError> {
        let q = |rows: [[f32; 4]; 4]| Mat4::from_cols_array_2d(&rows).transpose();
        // A named quadric, built (and checked) by the geometry's own constructor.
        let quadric = |r: Result<Quadric, String>, this: &Self, kind: &str| {
            r.map(|q| ShapeDesc::Quadric {
                q: q.q(),
                clip_min: q.clip_min().into(),
                clip_max: q.clip_max().into(),
                v_by_height: q.v_by_height(),
            })
            .map_err(|e| this.err(&format!("{at}.shape"), e, &format!("\"{kind}\"")))
        };
        // The named quadrics' parameters, checked in the scene's own terms (the geometry's
        // constructors speak of slopes and clip boxes).
        let check = |field: &str, ok: bool, msg: String| match ok {
            true => Ok(()),
            false => Err(self.err(&format!("{at}.shape.{field}"), msg, &format!("\"{field}\""))),
        };
        let heights = |y_min: f32, y_max: f32| {
            check(
                "y_max",
                y_min.is_finite() && y_max.is_finite() && y_min < y_max,
                format!("y_max must be above y_min, got y_min {y_min}, y_max {y_max}"),
            )
        };
        match s {
            JShape::Cylinder { y_min, y_max, .. } | JShape::Hyperboloid { y_min, y_max, .. } => {
                heights(*y_min, *y_max)?
            }
            JShape::Cone {
                angle,
                y_min,
                y_max,
            } => {
                check(
                    "angle",
                    *angle > 0.0 && *angle < 90.0,
                    format!("cone angle must be between 0 and 90 degrees, got {angle}"),
                )?;
                heights(*y_min, *y_max)?
            }
            JShape::Paraboloid { a, y_max } => {
                check(
                    "a",
                    *a > 0.0 && a.is_finite(),
                    format!("paraboloid a must be positive and finite, got {a}"),
                )?;
                check(
                    "y_max",
                    *y_max > 0.0 && y_max.is_finite(),
                    format!("paraboloid y_max must be positive and finite, got {y_max}"),
                )?
            }
            _ => {}
        }
        let shape = match s {
            JShape::Sphere { center, radius } => ShapeDesc::Sphere {
                center: v3(*center),
                radius: *radius,
            },
            JShape::Box { min, max } => ShapeDesc::Box {
                min: v3(*min),
                max: v3(*max),
            },
            JShape::Plane { point, normal } => ShapeDesc::Plane {
                point: v3(*point),
                normal: v3(*normal),
            },
            JShape::Disk {
                center,
                normal,
                radius,
            } => ShapeDesc::Disk {
                center: v3(*center),
                normal: v3(*normal),
                radius: *radius,
            },
            JShape::Rectangle {
                corner,
                edge_u,
                edge_v,
            } => ShapeDesc::Rectangle {
                corner: v3(*corner),
                edge_u: v3(*edge_u),
                edge_v: v3(*edge_v),
            },
            JShape::Polygon { vertices } => ShapeDesc::Polygon {
                vertices: vertices.iter().map(|&v| v3(v)).collect(),
            },
            JShape::Quadric {
                matrix,
                clip_min,
                clip_max,
            } => ShapeDesc::Quadric {
                q: q(*matrix),
                clip_min: v3(*clip_min),
                clip_max: v3(*clip_max),
                v_by_height: false,
            },
            JShape::Ellipsoid { radii } => quadric(
                Quadric::ellipsoid(Vec3A::from(v3(*radii))),
                self,
                "ellipsoid",
            )?,
            JShape::Cylinder {
                radius,
                y_min,
                y_max,
            } => quadric(Quadric::cylinder(*radius, *y_min, *y_max), self, "cylinder")?,
            JShape::Cone {
                angle,
                y_min,
                y_max,
            } => quadric(
                Quadric::cone(angle.to_radians().tan(), *y_min, *y_max),
                self,
                "cone",
            )?,
            JShape::Paraboloid { a, y_max } => {
                quadric(Quadric::paraboloid(*a, *y_max), self, "paraboloid")?
            }
            JShape::Hyperboloid { a, c, y_min, y_max } => quadric(
                Quadric::hyperboloid(*a, *c, *y_min, *y_max),
                self,
                "hyperboloid",
            )?,
            JShape::Mesh {
                positions,
                indices,
                normals,
                uvs,
            } => {
                // The copy below, beside the parsed lists it is made from.
                let bytes = 2
                    * (12 * (positions.len() + normals.len() + indices.len()) as u64
                        + 8 * uvs.len() as u64);
                self.files
                    .charge_memory(bytes, &format!("mesh '{name}'"))
                    .map_err(|e| self.err(&format!("{at}.shape"), e, "\"positions\""))?;
                let mesh = MeshDesc {
                    name: name.to_string(),
                    positions: positions.iter().map(|&p| v3(p)).collect(),
                    normals: normals.iter().map(|&p| v3(p)).collect(),
                    tangents: Vec::new(),
                    uvs: [uvs.iter().map(|&p| Vec2::from(p)).collect(), Vec::new()],
                    colors: Vec::new(),
                    indices: indices.clone(),
                };
                let n = mesh.positions.len();
                for (key, list) in [("positions", positions), ("normals", normals)] {
                    if let Some(k) = list.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
                        return Err(self.err(
                            &format!("{at}.shape.{key}[{k}]"),
                            format!(
                                "{:?} is not finite (JSON numbers beyond about 3.4e38 are too \
                                 large for 32-bit floats)",
                                list[k]
                            ),
                            &format!("\"{key}\""),
                        ));
                    }
                }
                if let Some(bad) = mesh.indices.iter().flatten().find(|&&i| i as usize >= n) {
                    return Err(self.err(
                        &format!("{at}.shape.indices"),
                        format!("index {bad} out of range ({n} positions)"),
                        "\"indices\"",
                    ));
                }
                if !normals.is_empty() && normals.len() != n || !uvs.is_empty() && uvs.len() != n {
                    return Err(self.err(
                        &format!("{at}.shape"),
                        "normals and uvs need one entry per position",
                        "\"normals\"",
                    ));
                }
                self.desc.meshes.push(mesh);
                ShapeDesc::Mesh {
                    mesh: self.desc.meshes.len() - 1,
                }
            }
            JShape::Gltf { .. } => unreachable!("handled by the caller"),
        };
        // Analytic shapes' parameters, checked now so that the error names the JSON path
        // (the build checks them again for scenes made in code).
        if !matches!(shape, ShapeDesc::Mesh { .. }) {
            super::build::check_shape(&shape)
                .map_err(|e| self.err(&format!("{at}.shape"), e, &format!("\"{name}\"")))?;
        }
        Ok(shape)
    }

    /// Appends an included glTF scene under `transform`.
    fn merge(&mut self, inc: SceneDesc, transform: Mat4) {
        let (mo, to, mato) = (
            self.desc.meshes.len(),
            self.desc.textures.len(),
            self.desc.materials.len(),
        );
        self.desc.meshes.extend(inc.meshes);
        self.desc.textures.extend(inc.textures);
        for mut m in inc.materials {
            for (_, r) in m.texture_refs_mut() {
                r.texture += to;
            }
            self.desc.materials.push(m);
        }
        for mut o in inc.objects {
            if let ShapeDesc::Mesh { mesh } = &mut o.shape {
                *mesh += mo;
            }
            o.material += mato;
            o.transform = transform * o.transform;
            self.desc.objects.push(o);
        }
        for l in inc.lights {
            self.desc.lights.push(match l {
                LightDesc::Point {
                    position,
                    intensity,
                    range,
                } => LightDesc::Point {
                    position: transform.transform_point3(position),
                    intensity,
                    range,
                },
                LightDesc::Spot {
                    position,
                    direction,
                    intensity,
                    inner_angle,
                    outer_angle,
                    range,
                } => LightDesc::Spot {
                    position: transform.transform_point3(position),
                    direction: transform.transform_vector3(direction),
                    intensity,
                    inner_angle,
                    outer_angle,
                    range,
                },
                LightDesc::Directional {
                    direction,
                    irradiance,
                } => LightDesc::Directional {
                    direction: transform.transform_vector3(direction),
                    irradiance,
                },
            });
        }
        for mut c in inc.cameras {
            c.transform = transform * c.transform;
            self.desc.cameras.push(c);
        }
        self.desc.warnings.extend(inc.warnings);
    }
}

/// The warning a JSON scene gets when nothing in it gives light.
pub const UNLIT_WARNING: &str = "the scene has no light (no light, no environment, no emissive \
    surface): it renders black unless the render brings an environment (--environment)";

/// Complex indices of refraction (η, k) at roughly 650/550/450 nm for common metals.
fn metal_preset(name: &str) -> Option<(Rgb, Rgb)> {
    Some(match name {
        "gold" => ([0.143, 0.374, 1.442], [3.983, 2.385, 1.603]),
        "silver" => ([0.155, 0.117, 0.138], [4.828, 3.122, 2.147]),
        "copper" => ([0.200, 0.924, 1.102], [3.912, 2.452, 2.142]),
        "aluminium" | "aluminum" => ([1.657, 0.880, 0.521], [9.224, 6.270, 4.837]),
        "iron" => ([2.911, 2.950, 2.585], [3.089, 2.932, 2.767]),
        "chrome" | "chromium" => ([3.175, 2.764, 2.131], [3.330, 3.320, 3.223]),
        _ => return None,
    })
}

fn transform(t: &JTransform) -> Result<Mat4, String> {
    if let Some(m) = t.matrix {
        if t.translate.is_some() || t.rotate.is_some() || t.scale.is_some() {
            return Err("use either `matrix` or translate/rotate/scale, not both".into());
        }
        let m = Mat4::from_cols_array_2d(&m).transpose();
        check_transform(&m)?;
        return Ok(m);
    }
    let s = match t.scale {
        None => Vec3::ONE,
        Some(JScale::Uniform(s)) => Vec3::splat(s),
        Some(JScale::Axes(a)) => v3(a),
    };
    let r = t.rotate.map_or(Quat::IDENTITY, |[x, y, z]| {
        Quat::from_euler(
            EulerRot::ZYX,
            z.to_radians(),
            y.to_radians(),
            x.to_radians(),
        )
    });
    let m = Mat4::from_scale_rotation_translation(s, r, v3(t.translate.unwrap_or([0.0; 3])));
    check_transform(&m)?;
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<SceneDesc, String> {
        parse_json(text, Path::new("."), Path::new("test.json")).map_err(|e| e.to_string())
    }

    /// Text that is not JSON is said to be so, with its line and column and the value it was
    /// in where that is known: not as an error "at ?" or "at ." (a path of nothing).
    #[test]
    fn syntax_errors_say_where_they_are() {
        let e = parse(
            "{\"camera\": {\"position\": [0, 0, 4], \"look_at\": [0, 0, 0]},\n \"objects\": [{\"shape\": {\"type\": \"sphere\"},, }]}",
        )
        .unwrap_err();
        assert!(e.contains("not valid JSON (line 2, column"), "{e}");
        assert!(!e.contains('?') && !e.contains(" at ."), "{e}");
        let e =
            parse("{\"camera\": {\"position\": [0, 0, 4], \"look_at\": [0, 0, 0]}, \"render\": {\"width\": 8").unwrap_err();
        assert!(e.contains("not valid JSON (line 1, column"), "{e}");
        assert!(e.contains(", in render): EOF while parsing"), "{e}");
        let e = parse("{\"camera\" {}}").unwrap_err();
        assert!(
            e.contains("not valid JSON (line 1, column 11): expected `:`"),
            "{e}"
        );
    }

    /// A texture's `uv` transforms the texture coordinates its materials read it through:
    /// flipped (an image upright on a rectangle whose `edge_v` points up), turned, tiled;
    /// a checker's own scale applies after it.
    #[test]
    fn a_textures_uv_transform_reaches_its_materials() {
        let d = parse(
            r#"{
              "textures": {
                "flipped": {"type": "checker", "uv": {"scale": [1, -1], "offset": [0, 1]}},
                "turned": {"type": "checker", "scale": 2, "uv": {"rotation": 90}},
                "plain": {"type": "checker"}
              },
              "materials": {
                "a": {"type": "diffuse", "texture": "flipped"},
                "b": {"type": "diffuse", "texture": "turned"},
                "c": {"type": "diffuse", "texture": "plain"}
              },
              "objects": [
                {"shape": {"type": "sphere"}, "material": "a"},
                {"shape": {"type": "sphere"}, "material": "b"},
                {"shape": {"type": "sphere"}, "material": "c"}
              ]
            }"#,
        )
        .unwrap();
        let transform = |name: &str| {
            let m = d.materials.iter().find(|m| m.name == name).unwrap();
            match &m.bsdf {
                BsdfDesc::Diffuse {
                    texture: Some(t), ..
                } => t.transform,
                other => panic!("{other:?}"),
            }
        };
        let at = |name: &str, u: f32, v: f32| (transform(name) * Vec3::new(u, v, 1.0)).truncate();
        // The checker's two texels per check pair halve the coordinates.
        // Materials a, b and c read the textures flipped, turned and plain.
        assert!((at("a", 0.2, 0.3) - Vec2::new(0.1, 0.35)).length() < 1e-6);
        assert!((at("c", 0.2, 0.3) - Vec2::new(0.1, 0.15)).length() < 1e-6);
        // A quarter turn takes (1, 0) to (0, −1), then scale 2 × 0.5.
        assert!((at("b", 1.0, 0.0) - Vec2::new(0.0, -1.0)).length() < 1e-6);
        let e =
            parse(r#"{"textures": {"t": {"type": "checker", "uv": {"shear": 1}}}}"#).unwrap_err();
        assert!(e.contains("shear"), "{e}");
    }

    #[test]
    fn a_small_scene_parses() {
        let d = parse(
            r#"{
              "render": {"width": 64, "height": 48, "spp": 4},
              "camera": {"position": [0, 1, 5], "look_at": [0, 1, 0], "fov": 40},
              "textures": {"check": {"type": "checker", "scale": 8, "odd": [0.1, 0.1, 0.1]}},
              "materials": {
                "floor": {"type": "diffuse", "texture": "check"},
                "glass": {"type": "glass", "ior": 1.5},
                "lamp": {"type": "emitter", "emission": [10, 10, 10]}
              },
              "objects": [
                {"shape": {"type": "plane"}, "material": "floor"},
                {"name": "ball", "shape": {"type": "sphere", "radius": 0.5}, "material": "glass",
                 "transform": {"translate": [0, 0.5, 0]}},
                {"shape": {"type": "rectangle", "corner": [-1, 3, -1], "edge_u": [2, 0, 0], "edge_v": [0, 0, 2]},
                 "material": "lamp"}
              ],
              "lights": [{"type": "point", "position": [0, 4, 0], "intensity": [5, 5, 5]}],
              "environment": {"type": "constant", "radiance": [0.1, 0.1, 0.1]}
            }"#,
        )
        .unwrap();
        assert_eq!(d.objects.len(), 3);
        assert_eq!(d.objects[1].name, "ball");
        assert_eq!(d.render.width, Some(64));
        assert_eq!(d.cameras.len(), 1);
        assert_eq!(d.materials.len(), 3);
        assert_eq!(d.textures[0].width, 2);
    }

    #[test]
    fn errors_name_the_path_and_line() {
        let e = parse("{\n \"objects\": [\n  {\"shape\": {\"type\": \"sphere\", \"radius\": \"big\"}, \"material\": \"m\"}\n ]\n}").unwrap_err();
        assert!(
            e.contains("objects[0].shape") && e.contains("line 3"),
            "{e}"
        );
        let e = parse("{\"materials\": {\"m\": {\"type\": \"diffuse\"}},\n\"objects\": [{\"shape\": {\"type\": \"sphere\"},\n \"material\": \"nope\"}]}").unwrap_err();
        assert!(
            e.contains("objects[0].material") && e.contains("nope") && e.contains("line 3"),
            "{e}"
        );
        let e = parse("{\"render\": {\"integrator\": \"magic\"}}").unwrap_err();
        assert!(
            e.contains("render.integrator") && e.contains("magic"),
            "{e}"
        );
        let e = parse("{\"render\": {\"filter\": \"tent\"}}").unwrap_err();
        assert!(e.contains("render.filter") && e.contains("tent"), "{e}");
        let e = parse("{\n\"render\": {\n\"spp\": 0}}").unwrap_err();
        assert!(
            e.contains("render.spp") && e.contains("line 3") && e.contains("between 1 and"),
            "{e}"
        );
        let d = parse("{\"render\": {\"integrator\": \"ao\", \"filter\": \"blackman-harris\"}}")
            .unwrap();
        assert_eq!(d.render.integrator, Some(crate::IntegratorKind::Ao));
        assert_eq!(
            d.render.filter,
            Some(crate::settings::FilterKind::BlackmanHarris)
        );
        let e = parse("{\"objekts\": []}").unwrap_err();
        assert!(e.contains("unknown field"), "{e}");
        assert!(parse("{").is_err());
        assert!(parse("{\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 1e999}, \"material\": \"m\"}]}").is_err());
    }

    #[test]
    fn errors_point_at_the_line_of_their_path_not_at_the_first_match() {
        let at = |text: &str| parse(text).unwrap_err();
        // The first `"transform"` and the texture named like the material come earlier.
        let e = at(r#"{
  "camera": {"position": [0, 1, 5], "look_at": [0, 0, 0]},
  "materials": {"white": {"type": "diffuse"}},
  "objects": [
    {"name": "a", "shape": {"type": "sphere"}, "material": "white",
     "transform": {"translate": [1, 0, 0]}},
    {"name": "b", "shape": {"type": "sphere"}, "material": "white",
     "transform": {"scale": 0}}
  ]
}"#);
        assert!(e.contains("at objects[1].transform (line 8)"), "{e}");
        let e = at(r#"{
  "textures": {"wood": {"type": "checker"}},
  "materials": {
    "wood": {"type": "pbr", "texture": "wood",
             "ior": -2}
  }
}"#);
        assert!(e.contains("at materials.wood.ior (line 5)"), "{e}");
        // A member that is missing: the line of the object that lacks it.
        let e = at("{\n\"objects\": [\n {\"shape\": {\"type\": \"sphere\"}},\n {\"shape\": {\"type\": \"sphere\"}}]}");
        assert!(e.contains("at objects[0] (line 3)"), "{e}");
        // Dotted names: the longest path that exists wins.
        assert_eq!(
            value_at(r#"{"a": {"b": 1}, "a.b": {"c": 2}}"#, "a.b.c"),
            Some(29)
        );
        assert_eq!(value_at(r#"{"a": [1, {"b": "x,]}"}]}"#, "a[1].b"), Some(16));
        assert_eq!(value_at(r#"{"a": 1}"#, "b"), None);
        // A value at the path is stepped over: the braces inside a later string are text.
        let e = at(r#"{"materials": {"w": {"type": "diffuse"}},
 "objects": [{"shape": {"type": "sphere"}, "material": "w",
              "transform": {"scale": 0}, "name": "x}}"}]}"#);
        assert!(e.contains("at objects[0].transform (line 3)"), "{e}");
        let text = r#"{"a": [{"b": {"c": 1}, "d": "} }"}, {"b": [1, 2]}], "e": 3}"#;
        assert_eq!(value_at(text, "a[1].b"), Some(text.find("[1, 2]").unwrap()));
        assert_eq!(value_at(text, "e"), Some(text.len() - 2));
    }

    #[test]
    fn shapes_lights_and_cameras_are_checked_at_their_path() {
        let scene = |objects: &str, lights: &str| {
            parse(&format!(
                "{{\"materials\": {{\"w\": {{\"type\": \"diffuse\"}}}},\n\"objects\": [{objects}],\n\"lights\": [{lights}]}}"
            ))
            .unwrap_err()
        };
        let e = scene(
            r#"{"shape": {"type": "box", "min": [1, 1, 1], "max": [0, 0, 0]}, "material": "w"}"#,
            "",
        );
        assert!(
            e.contains("at objects[0].shape (line 2): box min must be below max"),
            "{e}"
        );
        let e = scene(
            "",
            r#"{"type": "point", "position": [0, 3, 3], "intensity": [1, 1, 1], "range": -1}"#,
        );
        assert!(
            e.contains("at lights[0] (line 3): light range must be positive, got -1"),
            "{e}"
        );
        let e = scene(
            "",
            r#"{"type": "point", "position": [0, 1e39, 3], "intensity": [1, 1, 1]}"#,
        );
        assert!(e.contains("at lights[0]") && e.contains("3.4e38"), "{e}");
        // Named quadrics in the scene's own terms.
        for (shape, want) in [
            (
                r#"{"type": "cone", "angle": 90, "y_min": 0, "y_max": 1}"#,
                "at objects[0].shape.angle (line 2): cone angle must be between 0 and 90 degrees, got 90",
            ),
            (
                r#"{"type": "cylinder", "radius": 1, "y_min": 1, "y_max": -1}"#,
                "at objects[0].shape.y_max (line 2): y_max must be above y_min, got y_min 1, y_max -1",
            ),
            (
                r#"{"type": "paraboloid", "a": -1, "y_max": 1}"#,
                "at objects[0].shape.a (line 2): paraboloid a must be positive and finite, got -1",
            ),
        ] {
            let e = scene(&format!(r#"{{"shape": {shape}, "material": "w"}}"#), "");
            assert!(e.contains(want), "{e}");
        }
        let e = parse(r#"{"cameras": [{"position": [0, 1e39, 5], "look_at": [0, 0, 0]}]}"#)
            .unwrap_err();
        assert!(e.contains("at cameras[0]") && e.contains("finite"), "{e}");
        // The single `camera` by its own name, and `cameras` by their places in the list.
        let e = parse(
            r#"{"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
                "cameras": [{"position": [0, 0, 5], "look_at": [0, 0, 0]},
                            {"position": [0, 0, 5], "look_at": [0, 0, 0], "fov": 500}]}"#,
        )
        .unwrap_err();
        assert!(e.contains("at cameras[1].fov (line 3)"), "{e}");
        let e = parse(r#"{"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "fov": -1}}"#)
            .unwrap_err();
        assert!(e.contains("at camera.fov (line 1)"), "{e}");
        // A tiny scene: a camera a micrometre from what it looks at is fine.
        let d =
            parse(r#"{"cameras": [{"position": [0, 0, 1e-6], "look_at": [0, 0, 0]}]}"#).unwrap();
        assert_eq!(d.cameras.len(), 1);
    }

    #[test]
    fn a_name_given_twice_is_an_error() {
        let e = parse(
            "{\"materials\": {\n\"m\": {\"type\": \"diffuse\"},\n\"m\": {\"type\": \"mirror\"}}}",
        )
        .unwrap_err();
        assert!(
            e.contains("at materials") && e.contains("the name 'm' is given twice"),
            "{e}"
        );
    }

    #[test]
    fn a_byte_order_mark_is_tolerated() {
        let d = parse("\u{feff}{\"render\": {\"spp\": 3}}").unwrap();
        assert_eq!(d.render.spp, Some(3));
    }

    #[test]
    fn a_misspelt_material_field_is_an_error() {
        // A typo must not silently give a default (a lamp without its `emission`).
        for (material, typo) in [
            (r#"{"type": "diffuse", "albdo": [0.5, 0.5, 0.5]}"#, "albdo"),
            (r#"{"type": "emitter", "emision": [5, 5, 5]}"#, "emision"),
            (r#"{"type": "mirror", "roughness": 0.2}"#, "roughness"),
            (r#"{"type": "glass", "two_side": true}"#, "two_side"),
        ] {
            let e = parse(&format!(
                "{{\"materials\": {{\n\"m\": {material}}},\n\"objects\": [{{\"shape\": {{\"type\": \"sphere\"}}, \"material\": \"m\"}}]}}"
            ))
            .unwrap_err();
            assert!(
                e.contains("materials.m")
                    && e.contains("line 2")
                    && e.contains("unknown field")
                    && e.contains(typo)
                    && e.contains("`emission` and `two_sided`"),
                "{material}: {e}"
            );
        }
        // The fields every material takes are still known.
        parse(r#"{"materials": {"m": {"type": "diffuse", "emission": [1, 1, 1], "two_sided": true}}}"#)
            .unwrap();
    }

    #[test]
    fn a_gltf_include_with_a_material_is_an_error() {
        // The file's own materials are used: a `material` here would be ignored.
        let e = parse(
            r#"{"materials": {"red": {"type": "diffuse"}},
                "objects": [{"shape": {"type": "gltf", "path": "model.gltf"}, "material": "red"}]}"#,
        )
        .unwrap_err();
        assert!(
            e.contains("objects[0].material") && e.contains("remove `material`"),
            "{e}"
        );
    }

    #[test]
    fn named_quadrics_are_checked_by_the_geometry() {
        let shape = |s: &str| {
            parse(&format!(
                r#"{{"materials": {{"m": {{"type": "diffuse"}}}},
                "objects": [{{"shape": {s}, "material": "m"}}]}}"#
            ))
        };
        for bad in [
            r#"{"type": "cylinder", "radius": 0, "y_min": 0, "y_max": 1}"#,
            r#"{"type": "cone", "angle": 0, "y_min": 0, "y_max": 1}"#,
            r#"{"type": "hyperboloid", "a": 1, "c": -1, "y_min": 0, "y_max": 1}"#,
            r#"{"type": "paraboloid", "a": 1, "y_max": 0}"#,
            r#"{"type": "ellipsoid", "radii": [1, 0, 1]}"#,
            r#"{"type": "cylinder", "radius": 1, "y_min": 1, "y_max": 0}"#,
        ] {
            let e = shape(bad).unwrap_err();
            assert!(e.contains("objects[0].shape"), "{bad}: {e}");
        }
        // What the loader stores is the geometry's own quadric.
        let d = shape(r#"{"type": "cylinder", "radius": 0.5, "y_min": -1, "y_max": 2}"#).unwrap();
        let expected = Quadric::cylinder(0.5, -1.0, 2.0).unwrap();
        let ShapeDesc::Quadric {
            q,
            clip_min,
            clip_max,
            v_by_height,
        } = d.objects[0].shape
        else {
            panic!("a cylinder is a quadric");
        };
        assert!(v_by_height, "a cylinder's v is its height");
        let built = Quadric::new(q, clip_min.into(), clip_max.into())
            .unwrap()
            .with_v_by_height(v_by_height);
        assert_eq!(built, expected);
    }

    /// A folder with a scene folder in it, removed when dropped.
    struct Dir(PathBuf);

    impl Dir {
        /// Writes `scene/tri.gltf` and its buffer: one triangle, the nodes `nodes` (a JSON
        /// array), the scene made of node 0.
        fn triangle_gltf(&self, nodes: &str) {
            let positions: Vec<u8> = [-1.0f32, -1.0, 0.0, 1.0, -1.0, 0.0, 0.0, 1.0, 0.0]
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect();
            std::fs::write(self.0.join("scene/tri.bin"), positions).unwrap();
            let gltf = format!(
                r#"{{"asset": {{"version": "2.0"}},
                    "buffers": [{{"byteLength": 36, "uri": "tri.bin"}}],
                    "bufferViews": [{{"buffer": 0, "byteLength": 36}}],
                    "accessors": [{{"bufferView": 0, "componentType": 5126, "type": "VEC3",
                        "count": 3, "min": [-1, -1, 0], "max": [1, 1, 0]}}],
                    "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}}}]}}],
                    "nodes": {nodes}, "scenes": [{{"nodes": [0]}}]}}"#
            );
            std::fs::write(self.0.join("scene/tri.gltf"), gltf).unwrap();
        }

        fn new(tag: &str) -> Dir {
            let d = std::env::temp_dir().join(format!("raytile-json-{tag}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&d);
            std::fs::create_dir_all(d.join("scene")).unwrap();
            let img = image::RgbaImage::from_pixel(2, 2, image::Rgba([255, 0, 0, 255]));
            img.save(d.join("outside.png")).unwrap();
            img.save(d.join("scene/wood.png")).unwrap();
            Dir(d)
        }
    }

    impl Drop for Dir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    #[test]
    fn confined_scenes_name_only_files_in_their_folder() {
        let d = Dir::new("confined");
        let scene = d.0.join("scene/scene.json");
        let load = |text: &str| {
            std::fs::write(&scene, text).unwrap();
            let files = SceneFiles::confined_to_scene(&scene, 1 << 20, 1 << 20).unwrap();
            let r = load_json_files(&scene, &files).map_err(|e| e.to_string());
            (r, files)
        };
        let texture = |path: &str| {
            format!("{{\"textures\": {{\"t\": {{\"type\": \"image\", \"path\": {path:?}}}}}}}")
        };
        // Inside: read, and recorded with the scene.
        let (r, files) = load(&texture("wood.png"));
        assert_eq!(r.unwrap().textures[0].width, 2);
        let names: Vec<_> = files.used().into_iter().filter_map(|u| u.name).collect();
        assert_eq!(
            names,
            [PathBuf::from("scene.json"), PathBuf::from("wood.png")]
        );
        // Outside, however it is named: refused, naming the JSON path and the path.
        let outside = d.0.join("outside.png");
        for (path, why) in [
            (outside.to_str().unwrap(), "absolute paths are refused"),
            ("../outside.png", "'..' leads out"),
            ("/dev/zero", "absolute paths are refused"),
        ] {
            let (r, files) = load(&texture(path));
            let e = r.unwrap_err();
            assert!(
                e.contains("at textures.t.path (line 1)")
                    && e.contains(&format!("{path:?} refused"))
                    && e.contains(why),
                "{path}: {e}"
            );
            assert_eq!(files.refusal().unwrap().field, "textures.t.path");
        }
        let (r, _) = load(&format!(
            "{{\"environment\": {{\"type\": \"map\", \"path\": {:?}}}}}",
            outside.to_str().unwrap()
        ));
        assert!(r.unwrap_err().contains("at environment.path"));
        // The user's own scene may name the user's files.
        std::fs::write(&scene, texture(outside.to_str().unwrap())).unwrap();
        assert_eq!(load_json(&scene).unwrap().textures[0].width, 2);
    }

    #[test]
    fn a_scene_that_includes_itself_is_refused() {
        let d = Dir::new("cycle");
        let scene = d.0.join("scene/scene.json");
        std::fs::write(
            &scene,
            r#"{"objects": [{"shape": {"type": "gltf", "path": "./scene.json"}}]}"#,
        )
        .unwrap();
        for e in [
            load_json(&scene).unwrap_err().to_string(),
            load_json_files(
                &scene,
                &SceneFiles::confined_to_scene(&scene, 1 << 20, 1 << 20).unwrap(),
            )
            .unwrap_err()
            .to_string(),
        ] {
            assert!(
                e.contains("at objects[0].shape.path")
                    && e.contains("includes itself (scene.json → scene.json)"),
                "{e}"
            );
        }
    }

    #[test]
    fn an_included_unlit_model_takes_the_scene_s_light() {
        let d = Dir::new("unlit");
        d.triangle_gltf(r#"[{"mesh": 0}]"#);
        let scene = d.0.join("scene/scene.json");
        let load = |lights: &str| {
            std::fs::write(
                &scene,
                format!(
                    r#"{{"objects": [{{"shape": {{"type": "gltf", "path": "tri.gltf"}}}}],
                        "lights": [{lights}]}}"#
                ),
            )
            .unwrap();
            load_json(&scene).unwrap()
        };
        // Lit by the including scene: no default environment, no warning about one.
        let lit = load(r#"{"type": "point", "position": [0, 0, 2], "intensity": [1, 1, 1]}"#);
        assert!(lit.environment.is_none() && !lit.default_environment);
        assert!(lit.warnings.is_empty(), "{:?}", lit.warnings);
        // Nothing lights it: one warning that says so, and what to do.
        let dark = load("");
        assert!(dark.environment.is_none());
        assert_eq!(dark.warnings, [UNLIT_WARNING]);
        // Nor does a model without a camera bring one: the scene's cameras are its own.
        assert!(lit.cameras.is_empty(), "{:?}", lit.cameras);
    }

    /// A projective node matrix in an included glTF file is refused naming the include's JSON
    /// path, the file and the node.
    #[test]
    fn a_projective_node_in_an_included_model_names_the_include_the_file_and_the_node() {
        let d = Dir::new("projective");
        d.triangle_gltf(
            r#"[{"children": [1]},
                {"name": "tilted", "mesh": 0,
                 "matrix": [1, 0, 0, 0.5, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}]"#,
        );
        let scene = d.0.join("scene/scene.json");
        std::fs::write(
            &scene,
            "{\"objects\": [\n {\"shape\": {\"type\": \"gltf\", \"path\": \"tri.gltf\"}}\n]}",
        )
        .unwrap();
        assert_eq!(
            load_json(&scene).unwrap_err().to_string(),
            format!(
                "{}: at objects[0].shape.path (line 2): {}: node 1 ('tilted'): the transform's \
                 last row must be [0, 0, 0, 1] (no projection), got [0.5, 0, 0, 1]",
                scene.display(),
                d.0.join("scene/tri.gltf").display()
            )
        );
    }

    /// An object whose material emits light is an area light: a plane or a quadric, which
    /// cannot be one, is refused when the scene is loaded, naming the object's JSON path.
    #[test]
    fn an_emissive_plane_or_quadric_is_refused_naming_the_object() {
        let scene = |shape: &str, material: &str| {
            parse(&format!(
                r#"{{"materials": {{"white": {{"type": "diffuse"}},
                               "lamp": {{"type": "diffuse", "emission": [1, 1, 1]}},
                               "dark": {{"type": "diffuse", "emission": [0, 0, 0]}}}},
                "objects": [
                  {{"shape": {{"type": "sphere"}}, "material": "lamp"}},
                  {{"shape": {{"type": "sphere"}}, "material": "white"}},
                  {{"name": "floor lamp", "shape": {shape}, "material": "{material}"}}
                ]}}"#
            ))
        };
        for shape in [
            r#"{"type": "plane"}"#,
            r#"{"type": "ellipsoid", "radii": [1, 2, 1]}"#,
        ] {
            assert_eq!(
                scene(shape, "lamp").unwrap_err(),
                "test.json: at objects[2] (line 7): its material 'lamp' emits light, but this \
                 shape cannot be an area light (planes and quadrics cannot be sampled); use a \
                 mesh, sphere, box, disk, rectangle or polygon",
                "{shape}"
            );
            // Without emission, the same shape is only a surface.
            for material in ["white", "dark"] {
                scene(shape, material).unwrap();
            }
        }
    }

    /// `render.camera` is checked when the scene is loaded, against its cameras.
    #[test]
    fn render_camera_names_one_of_the_scenes_cameras() {
        let scene = |cameras: &str, camera: &str| {
            parse(&format!(
                "{{\"render\": {{\"camera\": {camera}}},\n\"cameras\": [{cameras}]}}"
            ))
        };
        let two = r#"{"name": "front", "position": [0, 0, 5], "look_at": [0, 0, 0]},
                     {"name": "side", "position": [5, 0, 0], "look_at": [0, 0, 0]}"#;
        for ok in [r#""side""#, r#""1""#, "1", r#""front""#] {
            assert_eq!(scene(two, ok).unwrap().cameras.len(), 2, "{ok}");
        }
        assert_eq!(
            scene(two, r#""nope""#).unwrap_err(),
            "test.json: at render.camera (line 1): the scene has no camera named or numbered \
             'nope' (its cameras: 0: 'front', 1: 'side')"
        );
        assert!(scene(two, r#""2""#).unwrap_err().contains("numbered '2'"));
        assert!(scene(two, "2").unwrap_err().contains("numbered '2'"));
        let e = scene(two, "-1").unwrap_err();
        assert!(
            e.contains("render.camera") && e.contains("index (integer ≥ 0)"),
            "{e}"
        );
        let e = scene("", r#""0""#).unwrap_err();
        assert!(
            e.starts_with("test.json: at render.camera (line 1): the scene has no camera"),
            "{e}"
        );
    }

    /// An image read once for two textures is recorded by every name the scene gives it (a
    /// link inside the folder is a second name): a package for a farm carries both.
    #[cfg(unix)]
    #[test]
    fn an_image_named_twice_is_recorded_by_both_names() {
        let d = Dir::new("aliases");
        let scene = d.0.join("scene/scene.json");
        std::os::unix::fs::symlink("wood.png", d.0.join("scene/alias.png")).unwrap();
        std::fs::write(
            &scene,
            r#"{"textures": {"a": {"type": "image", "path": "wood.png"},
                             "b": {"type": "image", "path": "alias.png"}}}"#,
        )
        .unwrap();
        let files = SceneFiles::confined_to_scene(&scene, 1 << 20, 1 << 20).unwrap();
        let desc = load_json_files(&scene, &files).unwrap();
        assert!(desc.textures[0].texels.shares(&desc.textures[1].texels));
        let mut names: Vec<_> = files.used().into_iter().filter_map(|u| u.name).collect();
        names.sort();
        assert_eq!(
            names,
            ["alias.png", "scene.json", "wood.png"].map(PathBuf::from)
        );
    }

    #[test]
    fn textures_are_charged_to_the_memory_budget() {
        let d = Dir::new("memory");
        let scene = d.0.join("scene/scene.json");
        std::fs::write(
            &scene,
            r#"{"textures": {"a": {"type": "image", "path": "wood.png"},
                             "b": {"type": "image", "path": "wood.png"}}}"#,
        )
        .unwrap();
        // Two textures of one 2×2 8-bit image, which keeps its bytes: decoded once, shared,
        // 16 bytes.
        let files = SceneFiles::trusted().with_memory_limit(16);
        let desc = load_json_files(&scene, &files).unwrap();
        assert!(desc.textures[0].texels.shares(&desc.textures[1].texels));
        let files = SceneFiles::trusted().with_memory_limit(15);
        let e = load_json_files(&scene, &files).unwrap_err().to_string();
        assert!(
            e.contains("at textures.a.path") && e.contains("more memory"),
            "{e}"
        );
        // A 16-bit image, kept as f32 values (64 bytes), read as colour and as data: the build
        // converts it once for each, so it is charged twice.
        let deep = image::ImageBuffer::<image::Rgb<u16>, _>::from_pixel(2, 2, image::Rgb([9; 3]));
        deep.save(d.0.join("scene/deep.png")).unwrap();
        std::fs::write(
            &scene,
            r#"{"textures": {"a": {"type": "image", "path": "deep.png"},
                             "b": {"type": "image", "path": "deep.png", "srgb": false},
                             "c": {"type": "image", "path": "deep.png", "srgb": false}}}"#,
        )
        .unwrap();
        let files = SceneFiles::trusted().with_memory_limit(128);
        assert!(load_json_files(&scene, &files).is_ok());
        let files = SceneFiles::trusted().with_memory_limit(127);
        let e = load_json_files(&scene, &files).unwrap_err().to_string();
        assert!(
            e.contains("at textures.b.srgb") && e.contains("\"deep.png\" as data"),
            "{e}"
        );
    }

    #[test]
    fn an_environment_maps_sampling_tables_are_charged() {
        let d = Dir::new("env-memory");
        let deep = image::ImageBuffer::<image::Rgb<u16>, _>::from_pixel(2, 2, image::Rgb([9; 3]));
        deep.save(d.0.join("scene/sky.png")).unwrap();
        let scene = d.0.join("scene/scene.json");
        std::fs::write(
            &scene,
            r#"{"environment": {"type": "map", "path": "sky.png"}}"#,
        )
        .unwrap();
        // The image as f32 values (64 bytes) and its tables (12 bytes a texel).
        let files = SceneFiles::trusted().with_memory_limit(64 + 48);
        assert!(load_json_files(&scene, &files).is_ok());
        let files = SceneFiles::trusted().with_memory_limit(64 + 47);
        let e = load_json_files(&scene, &files).unwrap_err().to_string();
        assert!(
            e.contains("at environment.path")
                && e.contains("\"sky.png\" as the environment's sampling tables")
                && e.contains("more memory"),
            "{e}"
        );
    }

    #[test]
    fn majorant_grids_are_charged_to_the_memory_budget() {
        // Two noise media of 2³ voxels (32 bytes each) with majorant grids of 64³ cells
        // (1 MiB each) and the default 16³ (16 KiB).
        let json = r#"{"media": {
            "a": {"type": "noise", "resolution": [2, 2, 2], "majorant_resolution": [64, 64, 64],
                  "sigma_a": [1, 1, 1], "sigma_s": [1, 1, 1]},
            "b": {"type": "noise", "resolution": [2, 2, 2],
                  "sigma_a": [1, 1, 1], "sigma_s": [1, 1, 1]}}}"#;
        let need = 2 * 32 + (64 * 64 * 64 + 16 * 16 * 16) * 4;
        let load = |limit: u64| {
            let files = SceneFiles::trusted().with_memory_limit(limit);
            parse_json_files(json, Path::new("."), Path::new("smoke.json"), &files)
        };
        assert!(load(need).is_ok());
        // Charged in order: a's majorant and voxels, then b's.
        let e = load(need - 33).unwrap_err().to_string();
        assert!(
            e.contains("at media.b (line 4)")
                && e.contains("the majorant grid of medium 'b'")
                && e.contains("more memory"),
            "{e}"
        );
        let e = load((1 << 20) - 1).unwrap_err().to_string();
        assert!(
            e.contains("at media.a.majorant_resolution (line 2)")
                && e.contains("the majorant grid of medium 'a'"),
            "{e}"
        );
    }

    #[test]
    fn noise_octaves_outside_1_to_16_are_refused() {
        let json = |octaves: u32| {
            format!(
                r#"{{"media": {{"n": {{"type": "noise", "resolution": [2, 2, 2], "octaves": {octaves},
                   "sigma_a": [1, 1, 1], "sigma_s": [1, 1, 1]}}}}}}"#
            )
        };
        for bad in [0, 17, 1_000_000_000] {
            let e = parse(&json(bad)).unwrap_err();
            assert!(
                e.contains("at media.n.octaves") && e.contains("from 1 to 16"),
                "{e}"
            );
        }
        for good in [1, 16] {
            parse(&json(good)).unwrap();
        }
    }

    #[test]
    fn media_naming_one_grid_file_share_its_voxels() {
        // A Mitsuba 3 .vol file of 4×4×4 voxels (256 bytes decoded), named by three media.
        let d = Dir::new("grids");
        let mut vol = b"VOL\x03".to_vec();
        for v in [1i32, 4, 4, 4, 1] {
            vol.extend(v.to_le_bytes());
        }
        for v in [0f32, 0., 0., 1., 1., 1.].into_iter().chain([0.5; 64]) {
            vol.extend(v.to_le_bytes());
        }
        std::fs::write(d.0.join("scene/smoke.vol"), vol).unwrap();
        let scene = d.0.join("scene/scene.json");
        let medium = r#"{"type": "grid", "path": "smoke.vol", "majorant_resolution": [1, 1, 1],
                         "sigma_a": [1, 1, 1], "sigma_s": [1, 1, 1]}"#;
        std::fs::write(
            &scene,
            format!(r#"{{"media": {{"a": {medium}, "b": {medium}, "c": {medium}}}}}"#),
        )
        .unwrap();
        // The voxels once, three majorant grids of one cell.
        let files = SceneFiles::trusted().with_memory_limit(256 + 3 * 4);
        let desc = load_json_files(&scene, &files).unwrap();
        let ids: Vec<_> = desc
            .media
            .iter()
            .map(|m| m.density.as_ref().unwrap().density.values_id())
            .collect();
        assert_eq!(ids, [ids[0]; 3]);
        let used = files.used();
        let grid_files = used
            .iter()
            .filter(|u| u.path.ends_with("smoke.vol"))
            .count();
        assert_eq!(grid_files, 1, "{used:?}");
        let files = SceneFiles::trusted().with_memory_limit(256 + 3 * 4 - 1);
        let e = load_json_files(&scene, &files).unwrap_err().to_string();
        assert!(e.contains("more memory"), "{e}");
    }

    /// A `.vdb` grid named `density` is the one a medium naming no grid picks: two media that
    /// name it both ways share it, held and charged once.
    #[test]
    fn a_grid_named_and_picked_by_default_is_held_once() {
        use crate::medium::vdb::tests::{write_vdb, Write};
        let d = Dir::new("grid-names");
        let voxels = (0..4).map(|i| ([i, 1, 2], 0.5)).collect();
        std::fs::write(
            d.0.join("scene/smoke.vdb"),
            write_vdb(&voxels, &Write::default()),
        )
        .unwrap();
        let scene = d.0.join("scene/scene.json");
        let medium = |grid: &str| {
            format!(
                r#"{{"type": "grid", "path": "smoke.vdb", "majorant_resolution": [1, 1, 1]{grid},
                    "sigma_a": [1, 1, 1], "sigma_s": [1, 1, 1]}}"#
            )
        };
        let load = |media: &str, memory: u64| {
            std::fs::write(&scene, format!(r#"{{"media": {{{media}}}}}"#)).unwrap();
            load_json_files(&scene, &SceneFiles::trusted().with_memory_limit(memory))
        };
        // The least memory one medium on the grid loads with.
        let one = format!(r#""a": {}"#, medium(""));
        let (mut need, mut hi) = (0u64, 1 << 20);
        while need < hi {
            let mid = (need + hi) / 2;
            if load(&one, mid).is_ok() {
                hi = mid;
            } else {
                need = mid + 1;
            }
        }
        assert!(need > 0 && load(&one, need).is_ok());
        let both = format!(
            r#""a": {}, "b": {}"#,
            medium(""),
            medium(r#", "grid": "density""#)
        );
        // One more majorant cell (4 bytes), no second grid.
        let desc = load(&both, need + 4).unwrap();
        let ids: Vec<_> = desc
            .media
            .iter()
            .map(|m| m.density.as_ref().unwrap().density.values_id())
            .collect();
        assert_eq!(ids, [ids[0]; 2]);
    }

    #[test]
    fn grid_placements_are_checked_as_transforms_naming_the_json_path() {
        use crate::medium::vdb::tests::{write_vdb, Write};
        let d = Dir::new("placements");
        // A .vdb grid of a few voxels whose index-to-world map turns them by 30° about z and
        // scales them by `voxel`.
        let write = |name: &str, voxel: f64| {
            let (s, c) = (voxel * 0.5, voxel * 0.75f64.sqrt());
            let w = Write {
                affine: Some([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, voxel]]),
                translation: [0.0; 3],
                ..Default::default()
            };
            let voxels = (0..4).map(|i| ([i, 1, 2], 0.5)).collect();
            std::fs::write(d.0.join("scene").join(name), write_vdb(&voxels, &w)).unwrap();
        };
        write("small.vdb", 1e-4);
        write("tiny.vdb", 1e-13);
        let scene = |file: &str, transform: &str| {
            let json = format!(
                r#"{{"media": {{"m": {{"type": "grid", "path": "{file}",
                                      "sigma_a": [1, 1, 1], "sigma_s": [1, 1, 1]}}}},
                    "materials": {{"b": {{"type": "interface"}}}},
                    "objects": [{{"shape": {{"type": "box", "min": [-1, -1, -1], "max": [1, 1, 1]}},
                                 "material": "b", "interior": "m"{transform}}}]}}"#
            );
            let path = d.0.join("scene/scene.json");
            std::fs::write(&path, json).unwrap();
            load_json(&path)
        };
        // Voxels of 10⁻⁴ in an object at a scale of 10⁻⁴ (a determinant of 10⁻²⁴): f32
        // inverts them, as it does the object's own transform.
        let desc = scene("small.vdb", r#", "transform": {"scale": 1e-4}"#).unwrap();
        crate::Scene::build(&desc).unwrap();
        // Past what f32 inverts: the object's transform is named, or the grid file.
        let e = scene("small.vdb", r#", "transform": {"scale": 1e-9}"#)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("at objects[0].transform (line 5)")
                && e.contains("grid of medium 'm'")
                && e.contains("too small to invert"),
            "{e}"
        );
        let e = scene("tiny.vdb", "").unwrap_err().to_string();
        assert!(
            e.contains("at media.m.path (line 1)")
                && e.contains("\"tiny.vdb\": the grid's index-to-world map")
                && e.contains("too small to invert"),
            "{e}"
        );
    }

    #[test]
    fn an_interface_with_emission_is_refused() {
        let e = parse(
            r#"{"materials": {
                "glow": {"type": "emitter", "emission": [1, 1, 1]},
                "boundary": {"type": "interface",
                             "emission": [5, 5, 5]}}}"#,
        )
        .unwrap_err();
        assert!(
            e.contains("at materials.boundary.emission (line 4)")
                && e.contains("neither scatters nor emits"),
            "{e}"
        );
        // Zero emission is no emission.
        parse(r#"{"materials": {"boundary": {"type": "interface", "emission": [0, 0, 0]}}}"#)
            .unwrap();
    }

    #[test]
    fn values_that_would_overflow_when_rendered_are_refused_when_parsed() {
        let refused = |text: &str, at: &str, says: &str| {
            let e = parse(text).unwrap_err();
            assert!(e.contains(at) && e.contains(says), "{text}: {e}");
        };
        // Extinction past 1e30, alone or through `scale` or a grid's density.
        let medium = |m: &str| format!(r#"{{"media": {{"fog": {m}}}}}"#);
        refused(
            &medium(r#"{"type": "homogeneous", "sigma_a": [2e38, 0, 0], "sigma_s": [2e38, 0, 0]}"#),
            "at media.fog",
            "extinction",
        );
        refused(
            &medium(
                r#"{"type": "homogeneous", "sigma_a": [0, 0, 0], "sigma_s": [1e20, 1, 1], "scale": 1e20}"#,
            ),
            "at media.fog",
            "at most 1e30",
        );
        refused(
            &medium(
                r#"{"type": "noise", "resolution": [2, 2, 2], "gain": 1e20, "threshold": 0,
                    "sigma_a": [0, 0, 0], "sigma_s": [1e20, 1e20, 1e20]}"#,
            ),
            "at media.fog",
            "largest density",
        );
        parse(&medium(
            r#"{"type": "homogeneous", "sigma_a": [1e29, 0, 0], "sigma_s": [1e29, 0, 0]}"#,
        ))
        .unwrap();
        // A noise box too thin (or too wide) to divide by.
        refused(
            &medium(
                r#"{"type": "noise", "resolution": [2, 2, 2], "min": [0, 0, 0],
                    "max": [1e-40, 1, 1], "sigma_a": [0, 0, 0], "sigma_s": [1, 1, 1]}"#,
            ),
            "at media.fog",
            "not a finite, non-empty box",
        );
        refused(
            &medium(
                r#"{"type": "noise", "resolution": [2, 2, 2], "min": [-3e38, 0, 0],
                    "max": [3e38, 1, 1], "sigma_a": [0, 0, 0], "sigma_s": [1, 1, 1]}"#,
            ),
            "at media.fog",
            "not a finite, non-empty box",
        );
        // Checker colours are reflectances, as a material's albedo.
        refused(
            r#"{"textures": {"c": {"type": "checker", "even": [5, 5, 5]}}}"#,
            "at textures.c.even",
            "between 0 and 1",
        );
        refused(
            r#"{"textures": {"c": {"type": "checker", "odd": [-1, 0, 0]}}}"#,
            "at textures.c.odd",
            "between 0 and 1",
        );
        refused(
            r#"{"textures": {"c": {"type": "checker", "uv": {"scale": [1e39, 1]}}}}"#,
            "at textures.c.uv.scale",
            "must be finite",
        );
        // A field of view or a lens so small that bdpt's importance would overflow.
        refused(
            r#"{"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "fov": 1e-17}}"#,
            "fov",
            "at least 0.001 degrees",
        );
        refused(
            r#"{"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "aperture": 1e-20}}"#,
            "aperture",
            "at least 1e-9",
        );
    }

    #[test]
    fn an_up_vector_too_small_to_cross_still_makes_a_camera() {
        // Looking down −Z with an `up` so small that its cross product with the view
        // underflows to zero (its own length does not).
        let d = parse(
            r#"{"camera": {"position": [0, 0, 0], "look_at": [0, 0, -1], "up": [0, 1e-25, 1e-20]}}"#,
        )
        .unwrap();
        let m = d.cameras[0].transform;
        assert!(m.is_finite(), "{m}");
        // Orthonormal: the basis of a camera.
        let (r, u) = (m.x_axis.truncate(), m.y_axis.truncate());
        assert!(
            (r.length() - 1.0).abs() < 1e-6 && r.dot(u).abs() < 1e-6,
            "{m}"
        );
        // A unit `up` gives the basis it always gave.
        let d = parse(r#"{"camera": {"position": [0, 1, 5], "look_at": [0, 0, 0]}}"#).unwrap();
        assert_eq!(d.cameras[0].transform.x_axis.truncate(), Vec3::X);
    }

    #[test]
    fn a_scene_of_many_objects_with_media_parses_in_linear_time() {
        // Every object names a grid medium as its exterior: checking that each grid has one
        // holder used to scan every object for each, 10^10 steps here.
        let objects =
            vec![r#"{"shape": {"type": "sphere"}, "material": "m", "exterior": "g"}"#; 100_000]
                .join(",");
        let text = format!(
            r#"{{"media": {{"g": {{"type": "noise", "resolution": [1, 1, 1],
                 "majorant_resolution": [1, 1, 1], "sigma_a": [0, 0, 0], "sigma_s": [1, 1, 1]}}}},
                "materials": {{"m": {{"type": "diffuse"}}}}, "objects": [{objects}]}}"#
        );
        let start = std::time::Instant::now();
        parse(&text).unwrap();
        assert!(start.elapsed().as_secs() < 60, "{:?}", start.elapsed());
    }

    #[test]
    fn a_json_scene_is_charged_for_its_parse_and_its_meshes() {
        // A 10,000-triangle mesh, some 0.5 MB of text, in a scene allowed 4 MB.
        let n = 10_000;
        let positions = vec!["[0, 0, 0], [1, 0, 0], [0, 1, 0]"; n].join(",");
        let indices = (0..n)
            .map(|i| format!("[{}, {}, {}]", 3 * i, 3 * i + 1, 3 * i + 2))
            .collect::<Vec<_>>()
            .join(",");
        let text = format!(
            r#"{{"materials": {{"m": {{"type": "diffuse"}}}}, "objects": [{{"material": "m",
                 "shape": {{"type": "mesh", "positions": [{positions}], "indices": [{indices}]}}}}]}}"#
        );
        let files = |limit: u64| SceneFiles::trusted().with_memory_limit(limit);
        let e = parse_json_files(&text, Path::new("."), Path::new("t.json"), &files(4 << 20))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("the scene's JSON text") && e.contains("more memory"),
            "{e}"
        );
        // Room for the parse but not for the mesh's copies (the parse's share is given back).
        let tree = parse_tree_bytes(text.len());
        assert!(tree > 4 << 20);
        let e = parse_json_files(
            &text,
            Path::new("."),
            Path::new("t.json"),
            &files(tree + 1000),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("mesh") && e.contains("more memory"), "{e}");
        parse_json_files(
            &text,
            Path::new("."),
            Path::new("t.json"),
            &files(tree + (4 << 20)),
        )
        .unwrap();
    }

    #[test]
    fn media_on_a_flat_shape_are_refused() {
        let scene = |shape: &str, side: &str| {
            format!(
                r#"{{"materials": {{"b": {{"type": "interface"}}}},
  "media": {{"m": {{"type": "homogeneous", "sigma_a": [1, 1, 1], "sigma_s": [0, 0, 0]}}}},
  "objects": [{{"shape": {shape}, "material": "b", "{side}": "m"}}]}}"#
            )
        };
        let disk = r#"{"type": "disk", "radius": 1}"#;
        let rect = r#"{"type": "rectangle", "corner": [0, 0, 0], "edge_u": [1, 0, 0], "edge_v": [0, 1, 0]}"#;
        for (shape, kind) in [(disk, "disk"), (rect, "rectangle")] {
            for side in ["interior", "exterior"] {
                let e = parse(&scene(shape, side)).unwrap_err();
                assert!(
                    e.contains(&format!("at objects[0].{side}"))
                        && e.contains(&format!("a {kind} encloses no volume")),
                    "{e}"
                );
            }
        }
        // A closed shape, and a plane (a half-space), may hold a medium.
        parse(&scene(r#"{"type": "sphere"}"#, "interior")).unwrap();
        parse(&scene(r#"{"type": "plane"}"#, "interior")).unwrap();
    }

    /// Media on an open surface (a quadric without caps, a mesh with holes) are rendered, with
    /// a warning naming the object and why; a closed mesh, welded or not at its seams, is not
    /// warned of.
    #[test]
    fn media_on_an_open_surface_are_warned_of() {
        let scene = |shape: &str| {
            format!(
                r#"{{"materials": {{"b": {{"type": "interface"}}}},
  "media": {{"m": {{"type": "homogeneous", "sigma_a": [1, 1, 1], "sigma_s": [0, 0, 0]}}}},
  "objects": [{{"name": "o", "shape": {shape}, "material": "b", "interior": "m"}}]}}"#
            )
        };
        let warned = |shape: &str| {
            let d = parse(&scene(shape)).unwrap();
            d.warnings
                .iter()
                .find(|w| w.contains("objects[0] ('o')") && w.contains("encloses no volume"))
                .cloned()
        };
        let cyl = r#"{"type": "cylinder", "radius": 1, "y_min": 0, "y_max": 1}"#;
        assert!(warned(cyl).unwrap().contains("a cylinder has no caps"));
        // A tetrahedron: indexed, and with every face's vertices repeated.
        let p = ["[0,0,0]", "[1,0,0]", "[0,1,0]", "[0,0,1]"];
        let faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        let closed = format!(
            r#"{{"type": "mesh", "positions": [{}], "indices": {faces:?}}}"#,
            p.join(",")
        );
        assert_eq!(warned(&closed), None);
        let split: Vec<&str> = faces.iter().flatten().map(|&i| p[i]).collect();
        let unwelded = format!(
            r#"{{"type": "mesh", "positions": [{}], "indices": [[0,1,2],[3,4,5],[6,7,8],[9,10,11]]}}"#,
            split.join(",")
        );
        assert_eq!(warned(&unwelded), None);
        let open = format!(
            r#"{{"type": "mesh", "positions": [{}], "indices": {:?}}}"#,
            p.join(","),
            &faces[..3]
        );
        assert!(warned(&open)
            .unwrap()
            .contains("the mesh has 3 edges on one triangle only"));
        assert_eq!(warned(r#"{"type": "sphere"}"#), None);
        // Closed but inside out: said, with what it does to the media.
        let inward = |shape: &str| {
            let d = parse(&scene(shape)).unwrap();
            d.warnings.iter().any(|w| w.contains("face inward"))
        };
        let reversed: Vec<[usize; 3]> = faces.iter().map(|f| [f[0], f[2], f[1]]).collect();
        let inside_out = format!(
            r#"{{"type": "mesh", "positions": [{}], "indices": {reversed:?}}}"#,
            p.join(",")
        );
        assert!(inward(&inside_out));
        assert!(!inward(&closed) && !inward(&unwelded));
        // As well 100 km from the origin.
        let far = ["[1e5,0,0]", "[100001,0,0]", "[1e5,1,0]", "[1e5,0,1]"];
        let far_inside_out = format!(
            r#"{{"type": "mesh", "positions": [{}], "indices": {reversed:?}}}"#,
            far.join(",")
        );
        assert!(inward(&far_inside_out));
    }

    #[test]
    fn transforms_compose_scale_then_rotate_then_translate() {
        let t = JTransform {
            translate: Some([1.0, 2.0, 3.0]),
            rotate: Some([0.0, 90.0, 0.0]),
            scale: Some(JScale::Uniform(2.0)),
            matrix: None,
        };
        let m = transform(&t).unwrap();
        let p = m.transform_point3(Vec3::X);
        assert!((p - Vec3::new(1.0, 2.0, 1.0)).length() < 1e-5, "{p}");
    }
}
