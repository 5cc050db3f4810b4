//! The glTF 2.0 front end: `.gltf` (external or data-URI buffers) and `.glb` files to a
//! [`SceneDesc`].
//!
//! The `gltf` crate parses and validates the JSON; everything else is done here so that hostile
//! files are refused with a message instead of a panic or an out-of-memory: GLB chunks, buffer
//! and image URIs (read through the scene's resolver, `scene::files`, inside the glTF file's
//! folder), accessor byte ranges, index ranges, counts
//! against actual buffer sizes and a memory budget, image sizes. See `docs/gltf.md` for the
//! conventions (units, light intensities, what is supported).
//!
//! Winding: indices are stored as the file has them. A node with a negative-determinant
//! transform mirrors its mesh; the renderer flips the front face for such objects, so the
//! loader leaves the indices alone.

mod accessor;
mod container;
mod material;
mod mesh;
#[cfg(test)]
mod tests;

use super::desc::{
    check_affine, check_camera_transform, CameraDesc, Degenerate, EnvironmentDesc, LightDesc,
    ObjectDesc, Projection, SceneDesc, ShapeDesc, TextureRef,
};
use super::files::{folder_of, SceneFiles};
use super::SceneError;
use glam::{Mat4, Quat, Vec3};
use raytile_proto::json::Objects;
use serde_json::Value;
use std::borrow::Cow;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// Extensions raytile understands (`extensionsRequired` may name only these).
pub const SUPPORTED_EXTENSIONS: &[&str] = &[
    "KHR_lights_punctual",
    "KHR_materials_clearcoat",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
    "KHR_materials_specular",
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_mesh_quantization",
    "KHR_texture_transform",
];

/// Largest glTF/GLB file or external buffer read.
pub(super) const MAX_FILE_BYTES: u64 = 1 << 32;

/// The warning the loader gives a model that nothing lights, when it adds the default light.
pub const NO_LIGHT_WARNING: &str = "the scene has no light (no punctual light, no emissive \
    surface other than emissive textures): a constant white environment was added";

/// [`NO_LIGHT_WARNING`] as it applies to a render with `settings`: the environment a job
/// brings (or none) replaces the default light, and `default_light` false leaves it out, so
/// the warning says what lights the render instead.
pub fn no_light_warning(settings: &crate::RenderSettings) -> String {
    use crate::settings::EnvironmentChoice;
    let unlit = "the scene has no light (no punctual light, no emissive surface other than \
                 emissive textures)";
    match &settings.environment {
        Some(EnvironmentChoice::None) => format!(
            "{unlit} and the render's environment is none: no light was added, only emissive \
             surfaces show"
        ),
        Some(EnvironmentChoice::Constant(_) | EnvironmentChoice::Map(_)) => {
            format!(
            "{unlit}: the render's environment ({}) lights it in place of the default white one",
            settings.environment.as_ref().map_or(String::new(), |e| e.to_string())
        )
        }
        None if !settings.default_light => format!(
            "{unlit} and the default light is off: no light was added, only emissive surfaces \
             show"
        ),
        None => NO_LIGHT_WARNING.to_string(),
    }
}

/// Options for [`load_gltf_with`] and [`load_gltf_slice`].
#[derive(Clone, Debug)]
pub struct GltfOptions {
    /// Add a constant white environment (with a warning) when nothing lights the scene: no
    /// punctual light and no shown surface that emits without an emissive texture (emissive
    /// textures are decals and screens, not lamps). Default: true.
    pub default_light: bool,
    /// Add a camera framing the model (named `default`) when the file has none. Default: true.
    pub default_camera: bool,
    /// Upper bound on the memory the loader allocates for decoded vertex, index and texel
    /// data and objects, in bytes; larger scenes are refused. Default: 8 GiB.
    pub memory_limit: usize,
}

impl Default for GltfOptions {
    fn default() -> Self {
        Self {
            default_light: true,
            default_camera: true,
            memory_limit: 8 << 30,
        }
    }
}

/// Loads a `.gltf` or `.glb` file with the default [`GltfOptions`]. External buffers and
/// images are resolved only inside the file's own folder.
pub fn load_gltf(path: &Path) -> Result<SceneDesc, SceneError> {
    load_gltf_with(path, &GltfOptions::default())
}

/// Loads a `.gltf` or `.glb` file with the given options.
pub fn load_gltf_with(path: &Path, opts: &GltfOptions) -> Result<SceneDesc, SceneError> {
    load_gltf_files(path, opts, &SceneFiles::trusted())
}

/// Loads a `.gltf` or `.glb` file, reading it and every file it names through `files`
/// (which applies its policy and budgets and records what was read).
pub fn load_gltf_files(
    path: &Path,
    opts: &GltfOptions,
    files: &SceneFiles,
) -> Result<SceneDesc, SceneError> {
    let (_, bytes) = files
        .read_scene(path, MAX_FILE_BYTES)
        .map_err(|e| SceneError::Gltf {
            path: path.to_path_buf(),
            message: e.refusal.to_string(),
        })?;
    load_gltf_bytes(&bytes, path, opts, files)
}

/// Loads glTF `bytes` read from `path` (already through `files`): external URIs resolve in
/// the folder of `path`, through `files`.
pub(super) fn load_gltf_bytes(
    bytes: &[u8],
    path: &Path,
    opts: &GltfOptions,
    files: &SceneFiles,
) -> Result<SceneDesc, SceneError> {
    let err = |message: String| SceneError::Gltf {
        path: path.to_path_buf(),
        message,
    };
    let is_glb_name = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("glb"));
    if is_glb_name && !container::is_glb(bytes) {
        return Err(err("not a GLB file: wrong magic (expected \"glTF\")".into()));
    }
    load_inner(bytes, Some(folder_of(path)), opts, files).map_err(err)
}

/// Loads a glTF or GLB held in memory. `base_dir` is the folder relative URIs resolve in; with
/// `None`, every external URI is refused (only data URIs and the GLB binary chunk are used).
/// `name` names the file in error messages.
pub fn load_gltf_slice(
    bytes: &[u8],
    base_dir: Option<&Path>,
    name: &str,
    opts: &GltfOptions,
) -> Result<SceneDesc, SceneError> {
    load_inner(bytes, base_dir, opts, &SceneFiles::trusted()).map_err(|message| SceneError::Gltf {
        path: PathBuf::from(name),
        message,
    })
}

/// State while converting one document.
pub(super) struct Loader<'a> {
    doc: &'a gltf::Document,
    raw: &'a Value,
    base_dir: Option<&'a Path>,
    /// Reads the files URIs name and holds the scene's memory budget.
    files: &'a SceneFiles,
    /// The buffers' bytes: the GLB binary chunk in place (not copied), external and data-URI
    /// buffers as read.
    buffers: Vec<Cow<'a, [u8]>>,
    /// Bytes the loader may still allocate (see [`GltfOptions::memory_limit`]).
    budget: std::cell::Cell<usize>,
    desc: SceneDesc,
    /// SceneDesc mesh per (mesh, primitive); `None` for skipped primitives.
    mesh_cache: HashMap<(usize, usize), Option<usize>>,
    material_cache: HashMap<Option<usize>, usize>,
    /// By (image, sRGB, wrap s, wrap t, bilinear): textures of one image with the same
    /// sampling share one description (and its texels), whichever glTF texture names them.
    texture_cache: HashMap<
        (
            usize,
            bool,
            super::desc::WrapMode,
            super::desc::WrapMode,
            bool,
        ),
        usize,
    >,
    image_cache: HashMap<usize, Rc<crate::scene::image::DecodedImage>>,
    /// By the SHA-256 of the encoded bytes: images of one file (several `images` naming it,
    /// or the same bytes twice) are decoded and held once.
    image_content: HashMap<[u8; 32], Rc<crate::scene::image::DecodedImage>>,
    /// (decoded image, sRGB) pairs whose f32 texels the scene's build converts (a copy each),
    /// charged once.
    converted: std::collections::HashSet<(usize, bool)>,
}

impl Loader<'_> {
    /// Takes `bytes` from the memory budget (the loader's own and the whole scene's), or
    /// refuses the scene.
    pub(super) fn charge(&self, bytes: usize, what: &str) -> Result<(), String> {
        let left = self.budget.get();
        if bytes > left {
            return Err(format!(
                "{what}: the scene needs more memory than the loader's limit allows"
            ));
        }
        self.files.charge_memory(bytes as u64, what)?;
        self.budget.set(left - bytes);
        Ok(())
    }

    /// Records a non-fatal problem.
    pub(super) fn warn(&mut self, message: String) {
        log::warn!("{message}");
        self.desc.warnings.push(message);
    }

    /// A factor the specification bounds to [0, 1] (metallic, roughness, transmission),
    /// clamped into it with a warning when a file strays out (exporters write 1.0000001 now
    /// and then; the renderer refuses such values only from its own scene format).
    pub(super) fn unit_factor(&mut self, value: f32, what: &str) -> f32 {
        self.unit_factors([value], what)[0]
    }

    /// [`Loader::unit_factor`] for a factor of several channels (`baseColorFactor`): every
    /// channel clamped to [0, 1], with one warning if any was outside.
    pub(super) fn unit_factors<const N: usize>(&mut self, value: [f32; N], what: &str) -> [f32; N] {
        let clamped = value.map(|x| x.clamp(0.0, 1.0));
        if clamped != value {
            let show = |v: &[f32; N]| match v.as_slice() {
                [x] => x.to_string(),
                v => format!("{v:?}"),
            };
            self.warn(format!(
                "{what} {} is outside [0, 1]; {} is used",
                show(&value),
                show(&clamped)
            ));
        }
        clamped
    }
}

/// Refuses an asset that a glTF 2.0 loader may not read (glTF 2.0, 3.1): a `version` of
/// another major version, or a `minVersion` above 2.0. A later 2.x is read, as the
/// specification asks.
fn check_version(raw: &Value) -> Result<(), String> {
    let parse = |key: &str| -> Result<Option<(u64, u64)>, String> {
        let Some(v) = raw.get("asset").and_then(|a| a.get(key)) else {
            return Ok(None);
        };
        v.as_str()
            .and_then(|t| t.split_once('.'))
            .and_then(|(major, minor)| Some((major.parse().ok()?, minor.parse().ok()?)))
            .map(Some)
            .ok_or_else(|| {
                format!("invalid glTF at asset.{key}: expected \"major.minor\", got {v}")
            })
    };
    if let Some((major, minor)) = parse("version")? {
        if major != 2 {
            return Err(format!(
                "glTF version {major}.{minor}: raytile reads glTF 2.x"
            ));
        }
    }
    if let Some(min) = parse("minVersion")? {
        if min > (2, 0) {
            return Err(format!(
                "the asset needs glTF {}.{} or newer (asset.minVersion): raytile reads glTF 2.0",
                min.0, min.1
            ));
        }
    }
    Ok(())
}

/// Refuses unsupported required extensions; warns about unsupported optional ones.
fn check_extensions(raw: &Value, warnings: &mut Vec<String>) -> Result<(), String> {
    // Each list is an array of names; anything else is refused here, before it could be taken
    // for an unsupported extension.
    let names = |key: &str| -> Result<Vec<String>, String> {
        let Some(list) = raw.get(key) else {
            return Ok(Vec::new());
        };
        let Some(list) = list.as_array() else {
            return Err(format!(
                "invalid glTF at {key}: expected an array of extension names, got {list}"
            ));
        };
        list.iter()
            .enumerate()
            .map(|(k, v)| match v.as_str() {
                Some(name) => Ok(name.to_string()),
                None => Err(format!(
                    "invalid glTF at {key}[{k}]: expected an extension name (a string), got {v}"
                )),
            })
            .collect()
    };
    let required = names("extensionsRequired")?;
    let missing: Vec<&str> = required
        .iter()
        .map(String::as_str)
        .filter(|e| !SUPPORTED_EXTENSIONS.contains(e))
        .collect();
    if !missing.is_empty() {
        return Err(format!(
            "required extension(s) not supported by raytile: {}",
            missing.join(", ")
        ));
    }
    let optional: Vec<String> = names("extensionsUsed")?
        .into_iter()
        .filter(|e| !SUPPORTED_EXTENSIONS.contains(&e.as_str()))
        .collect();
    if !optional.is_empty() {
        warnings.push(format!(
            "extension(s) not supported and ignored: {}",
            optional.join(", ")
        ));
    }
    Ok(())
}

/// Gives every scene without `nodes` an empty list: the field is optional in glTF 2.0 (an
/// empty scene), but the gltf crate requires it. Whether anything was added (the document is
/// then parsed from `raw`, and its errors have no line numbers).
fn add_scene_nodes(raw: &mut Value) -> bool {
    let mut added = false;
    if let Some(scenes) = raw.get_mut("scenes").and_then(Value::as_array_mut) {
        for scene in scenes.iter_mut().filter_map(Value::as_object_mut) {
            if !scene.contains_key("nodes") {
                scene.insert("nodes".into(), Value::Array(Vec::new()));
                added = true;
            }
        }
    }
    added
}

/// A gltf crate path with the extensions named as the file names them: the crate writes
/// its own field names (`nodes[1].extensions.khrLightsPunctual.light`), the file has
/// `KHR_lights_punctual`.
fn extension_names(path: &str) -> String {
    let mut out = String::with_capacity(path.len() + 8);
    let mut rest = path;
    while let Some(at) = rest.find(".khr") {
        out.push_str(&rest[..at]);
        let name = &rest[at + 4..];
        let end = name
            .find(|c: char| !c.is_ascii_alphanumeric())
            .unwrap_or(name.len());
        out.push_str(".KHR");
        for c in name[..end].chars() {
            if c.is_ascii_uppercase() {
                out.push('_');
            }
            out.push(c.to_ascii_lowercase());
        }
        rest = &name[end..];
    }
    out.push_str(rest);
    out
}

/// The gltf crate's validation (every index in range, every enum known), except for the
/// POSITION `min`/`max` it requires: many exporters omit them and raytile computes bounds itself.
fn validate(root: &gltf::json::Root) -> Result<(), String> {
    use gltf::json::validation::{Error, Validate};
    // The gltf crate's primitive check indexes `accessors` with the POSITION index before
    // checking it, and panics when it is out of range: check it first.
    for (mi, mesh) in root.meshes.iter().enumerate() {
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            let pos = gltf::json::validation::Checked::Valid(gltf::Semantic::Positions);
            if let Some(a) = prim.attributes.get(&pos) {
                if a.value() >= root.accessors.len() {
                    return Err(format!(
                        "mesh {mi} primitive {pi}: POSITION accessor {} does not exist ({} accessors)",
                        a.value(),
                        root.accessors.len()
                    ));
                }
            }
        }
    }
    // The gltf crate's `Image::source` panics on an image with neither a buffer view nor a
    // URI, or with a buffer view but no MIME type.
    for (i, image) in root.images.iter().enumerate() {
        match (&image.buffer_view, &image.uri, &image.mime_type) {
            (Some(_), _, Some(_)) | (None, Some(_), _) => {}
            (Some(_), _, None) => {
                return Err(format!(
                    "image {i}: an image in a buffer view needs a mimeType"
                ))
            }
            (None, None, _) => return Err(format!("image {i}: neither a uri nor a bufferView")),
        }
    }
    let mut errs: Vec<(String, Error)> = Vec::new();
    root.validate(root, gltf::json::Path::new, &mut |path, err| {
        let path = extension_names(&path().to_string());
        let bounds = path.ends_with("[\"POSITION\"].min") || path.ends_with("[\"POSITION\"].max");
        // A primitive without POSITION is skipped with a warning rather than refused.
        let no_position =
            path.ends_with("attributes[\"POSITION\"]") && matches!(err, Error::Missing);
        // An accessor without a buffer view or sparse values is all zeros (glTF 2.0, 3.6.2.1);
        // the gltf crate asks for one of the two.
        let zeros = path.starts_with("accessors[")
            && path.ends_with("].bufferView")
            && matches!(err, Error::Missing);
        if !(bounds && matches!(err, Error::Missing | Error::Invalid) || no_position || zeros) {
            errs.push((path, err));
        }
    });
    // The gltf crate checks that a camera has a projection, not that it matches `type`, and
    // would panic on the mismatch.
    for (i, cam) in root.cameras.iter().enumerate() {
        use gltf::json::camera::Type;
        use gltf::json::validation::Checked;
        let ok = match cam.type_ {
            Checked::Valid(Type::Perspective) => cam.perspective.is_some(),
            Checked::Valid(Type::Orthographic) => cam.orthographic.is_some(),
            Checked::Invalid => true,
        };
        if !ok {
            errs.push((
                format!("cameras[{i}]: the projection does not match \"type\""),
                Error::Missing,
            ));
        }
    }
    if errs.is_empty() {
        return Ok(());
    }
    let shown: Vec<String> = errs
        .iter()
        .take(5)
        .map(|(path, err)| format!("{path}: {err}"))
        .collect();
    let more = match errs.len().saturating_sub(5) {
        0 => String::new(),
        n => format!(" (and {n} more)"),
    };
    Err(format!("invalid glTF: {}{more}", shown.join("; ")))
}

fn load_inner(
    bytes: &[u8],
    base_dir: Option<&Path>,
    opts: &GltfOptions,
    files: &SceneFiles,
) -> Result<SceneDesc, String> {
    let container = if container::is_glb(bytes) {
        container::split_glb(bytes)?
    } else {
        container::Container {
            json: bytes,
            bin: None,
        }
    };
    // Some exporters write a UTF-8 byte order mark, which JSON parsers refuse.
    let json = container
        .json
        .strip_prefix(b"\xEF\xBB\xBF".as_slice())
        .unwrap_or(container.json);
    let mut raw: Value = serde_json::from_slice(json).map_err(|e| format!("invalid JSON: {e}"))?;
    if !raw.is_object() {
        return Err("invalid glTF: the JSON is not an object".into());
    }
    let mut warnings = Vec::new();
    check_version(&raw)?;
    check_extensions(&raw, &mut warnings)?;
    // Errors name the JSON path of the value they are about, as well as serde's message.
    // Every struct from a JSON object only (serde would also take an array of its fields).
    let invalid = |e: serde_path_to_error::Error<serde_json::Error>| {
        let message = raytile_proto::json::plain_message(&e.inner().to_string());
        match e.path().to_string() {
            path if path == "." => format!("invalid glTF: {message}"),
            path => format!("invalid glTF at {path}: {message}"),
        }
    };
    let mut root: gltf::json::Root = if add_scene_nodes(&mut raw) {
        serde_path_to_error::deserialize(Objects(&raw)).map_err(invalid)?
    } else {
        let mut json = serde_json::Deserializer::from_slice(json);
        serde_path_to_error::deserialize(Objects(&mut json)).map_err(invalid)?
    };
    // Already checked against raytile's own list; the gltf crate's list lacks some we support.
    root.extensions_required.clear();
    validate(&root)?;
    let doc = gltf::Document::from_json_without_validation(root);

    let mut loader = Loader {
        doc: &doc,
        raw: &raw,
        base_dir,
        files,
        buffers: Vec::new(),
        budget: std::cell::Cell::new(opts.memory_limit),
        desc: SceneDesc {
            warnings,
            ..SceneDesc::default()
        },
        mesh_cache: HashMap::new(),
        material_cache: HashMap::new(),
        texture_cache: HashMap::new(),
        image_cache: HashMap::new(),
        image_content: HashMap::new(),
        converted: Default::default(),
    };
    loader.load_buffers(container.bin)?;
    loader.load_scene()?;
    loader.finish(opts)?;
    Ok(loader.desc)
}

/// The local transform of a node, checked to be finite and affine (the specification wants a
/// matrix that decomposes into translation, rotation and scale; every node under it inherits
/// it).
fn node_matrix(node: &gltf::Node) -> Result<Mat4, String> {
    let what = match node.name() {
        Some(name) => format!("node {} ('{name}')", node.index()),
        None => format!("node {}", node.index()),
    };
    let m = match node.transform() {
        gltf::scene::Transform::Matrix { matrix } => Mat4::from_cols_array_2d(&matrix),
        gltf::scene::Transform::Decomposed {
            translation,
            rotation,
            scale,
        } => {
            let q = Quat::from_array(rotation);
            let len = q.length();
            if !len.is_finite() || len < 1e-6 {
                return Err(format!("{what}: rotation quaternion is zero or not finite"));
            }
            Mat4::from_scale_rotation_translation(
                Vec3::from(scale),
                q / len,
                Vec3::from(translation),
            )
        }
    };
    if !m.is_finite() {
        return Err(format!("{what}: transform is not finite"));
    }
    check_affine(&m).map_err(|e| format!("{what}: {e}"))?;
    Ok(m)
}

impl<'a> Loader<'a> {
    fn load_buffers(&mut self, bin: Option<&'a [u8]>) -> Result<(), String> {
        let doc = self.doc;
        for buffer in doc.buffers() {
            let what = format!("buffer {}", buffer.index());
            let len = buffer.length();
            let data: Cow<'a, [u8]> = match buffer.source() {
                gltf::buffer::Source::Bin if buffer.index() > 0 => {
                    return Err(format!(
                        "{what} has no uri: only the first buffer may be the GLB binary chunk"
                    ))
                }
                gltf::buffer::Source::Bin => Cow::Borrowed(bin.ok_or_else(|| {
                    format!("{what} refers to the GLB binary chunk, which is missing")
                })?),
                gltf::buffer::Source::Uri(uri) => {
                    let field = format!("buffers[{}].uri", buffer.index());
                    Cow::Owned(container::load_uri(
                        uri,
                        self.base_dir,
                        self.files,
                        &field,
                        MAX_FILE_BYTES,
                    )?)
                }
            };
            if data.len() < len {
                return Err(format!(
                    "{what}: byteLength is {len} but only {} bytes are available",
                    data.len()
                ));
            }
            self.buffers.push(match data {
                Cow::Borrowed(b) => Cow::Borrowed(&b[..len]),
                Cow::Owned(mut v) => {
                    v.truncate(len);
                    Cow::Owned(v)
                }
            });
        }
        Ok(())
    }

    fn load_scene(&mut self) -> Result<(), String> {
        let doc = self.doc;
        check_forest(doc)?;
        let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
            Some(scene) => scene.nodes().collect(),
            None => {
                // No scene: show every root node rather than nothing.
                let mut is_child = vec![false; doc.nodes().len()];
                for n in doc.nodes() {
                    for c in n.children() {
                        if let Some(f) = is_child.get_mut(c.index()) {
                            *f = true;
                        }
                    }
                }
                if doc.nodes().len() > 0 {
                    self.warn("the file has no scene; all root nodes are shown".into());
                }
                doc.nodes()
                    .filter(|n| !is_child.get(n.index()).copied().unwrap_or(false))
                    .collect()
            }
        };
        let mut visited = vec![false; doc.nodes().len()];
        let mut stack: Vec<(gltf::Node, Mat4)> = roots
            .into_iter()
            .rev()
            .map(|n| (n, Mat4::IDENTITY))
            .collect();
        while let Some((node, parent)) = stack.pop() {
            let ni = node.index();
            match visited.get_mut(ni) {
                Some(v) if !*v => *v = true,
                _ => {
                    return Err(format!(
                        "node {ni} is reached twice: the node hierarchy has a cycle or a node with two parents"
                    ))
                }
            }
            let json = &doc.as_json().nodes[ni];
            if json.matrix.is_some()
                && (json.translation.is_some() || json.rotation.is_some() || json.scale.is_some())
            {
                self.warn(format!(
                    "node {ni} has both a matrix and translation, rotation or scale, which glTF \
                     forbids: the matrix is used"
                ));
            }
            let world = parent * node_matrix(&node)?;
            if !world.is_finite() {
                return Err(format!("node {ni}: world transform is not finite"));
            }
            let node_name = node
                .name()
                .map(str::to_string)
                .unwrap_or_else(|| format!("node {ni}"));
            if let Some(mesh) = node.mesh() {
                self.place_mesh(&node, &mesh, &node_name, world)?;
            }
            if let Some(cam) = node.camera() {
                self.add_camera(&cam, &node, world)?;
            }
            if let Some(light) = node.light() {
                self.add_light(&light, world)?;
            }
            if node.skin().is_some() {
                self.warn(format!("node {ni}: skinning is ignored (bind pose)"));
            }
            let children: Vec<gltf::Node> = node.children().collect();
            for child in children.into_iter().rev() {
                stack.push((child, world));
            }
        }
        Ok(())
    }

    fn place_mesh(
        &mut self,
        node: &gltf::Node,
        mesh: &gltf::Mesh,
        node_name: &str,
        world: Mat4,
    ) -> Result<(), String> {
        match Degenerate::of(&world) {
            None => {}
            // A mesh scaled to nothing, flattened or too small to invert (glTF hides nodes
            // with a zero scale) cannot show: leave it out.
            Some(d @ (Degenerate::ZeroAxis | Degenerate::Flat | Degenerate::TooSmall)) => {
                self.warn(format!("node {}: {d}; its mesh is not shown", node.index()));
                return Ok(());
            }
            Some(d @ Degenerate::TooLarge) => {
                return Err(format!("node {} ('{node_name}'): {d}", node.index()));
            }
        }
        let nprims = mesh.primitives().len();
        for prim in mesh.primitives() {
            let key = (mesh.index(), prim.index());
            let mat = prim.material();
            let mesh_index = match self.mesh_cache.get(&key) {
                Some(&m) => m,
                None => {
                    let tangent_uv = self.normal_map_uv(&mat);
                    let m = match self.load_primitive(mesh, &prim, tangent_uv)? {
                        Some(md) => {
                            self.desc.meshes.push(md);
                            Some(self.desc.meshes.len() - 1)
                        }
                        None => None,
                    };
                    self.mesh_cache.insert(key, m);
                    m
                }
            };
            let Some(mesh_index) = mesh_index else {
                continue;
            };
            let material = self.material(&mat)?;
            self.fill_missing_uvs(mesh_index, material)?;
            self.charge(
                std::mem::size_of::<ObjectDesc>() + node_name.len() + 16,
                &format!("node {}", node.index()),
            )?;
            let name = if nprims > 1 {
                format!("{node_name} primitive {}", prim.index())
            } else {
                node_name.to_string()
            };
            self.desc.objects.push(ObjectDesc {
                name,
                shape: ShapeDesc::Mesh { mesh: mesh_index },
                material,
                transform: world,
                media: None,
            });
        }
        Ok(())
    }

    /// A texture of material `material` that reads a texture coordinate set mesh
    /// `mesh_index` lacks is looked up at (0, 0) over the whole primitive, as glTF viewers
    /// do, with a warning (the specification leaves it undefined).
    fn fill_missing_uvs(&mut self, mesh_index: usize, material: usize) -> Result<(), String> {
        let refs: Vec<(&str, TextureRef)> = self.desc.materials[material]
            .texture_refs_mut()
            .into_iter()
            .map(|(slot, t)| (slot, *t))
            .collect();
        for (slot, t) in refs {
            let set = usize::from(t.texcoord.min(1));
            let mesh = &self.desc.meshes[mesh_index];
            if !mesh.uvs[set].is_empty() {
                continue;
            }
            let (n, name) = (mesh.positions.len(), mesh.name.clone());
            let warning = format!(
                "{name}: the material '{}' reads TEXCOORD_{set} for its {slot} texture, which \
                 the primitive does not have; that texture is read at (0, 0) on it",
                self.desc.materials[material].name
            );
            self.warn(warning);
            self.charge(n * std::mem::size_of::<glam::Vec2>(), &name)?;
            self.desc.meshes[mesh_index].uvs[set] = vec![glam::Vec2::ZERO; n];
        }
        Ok(())
    }

    fn add_camera(
        &mut self,
        cam: &gltf::Camera,
        node: &gltf::Node,
        world: Mat4,
    ) -> Result<(), String> {
        let what = format!("camera {}", cam.index());
        // Only the rotation and the position are used (any scale will do), but a zero or
        // flattening scale leaves no direction.
        if let Err(e) = check_camera_transform(&world) {
            return Err(format!(
                "{what} (node {}): the node's {e}, so the camera has no direction",
                node.index()
            ));
        }
        let name = cam
            .name()
            .or(node.name())
            .map(str::to_string)
            .unwrap_or_else(|| what.clone());
        let (projection, aspect) = match cam.projection() {
            gltf::camera::Projection::Perspective(p) => {
                let yfov = p.yfov();
                if !(yfov > 0.0 && yfov < std::f32::consts::PI) {
                    return Err(format!("{what}: yfov {yfov} must be in (0, π)"));
                }
                let aspect = p.aspect_ratio();
                if let Some(a) = aspect {
                    if !(a.is_finite() && a > 0.0) {
                        return Err(format!("{what}: aspectRatio {a} must be positive"));
                    }
                }
                (
                    Projection::Perspective {
                        yfov,
                        aperture_radius: 0.0,
                        focus_distance: 1.0,
                    },
                    aspect,
                )
            }
            gltf::camera::Projection::Orthographic(o) => {
                let (xmag, ymag) = (o.xmag(), o.ymag());
                if !(ymag.is_finite() && ymag != 0.0 && xmag.is_finite() && xmag != 0.0) {
                    return Err(format!("{what}: xmag and ymag must be finite and non-zero"));
                }
                (
                    Projection::Orthographic {
                        half_height: ymag.abs(),
                    },
                    Some(xmag.abs() / ymag.abs()),
                )
            }
        };
        // The renderer's own limits (a field of view of at least 0.001°), here where the
        // coordinator reads the file, not first where a worker builds the scene.
        projection
            .check()
            .map_err(|(_, e)| format!("{what}: {e}"))?;
        self.desc.cameras.push(CameraDesc {
            name,
            // A parent's non-uniform scale may shear the frame: look along its −Z.
            transform: crate::camera::unsheared(world),
            projection,
            aspect,
        });
        Ok(())
    }

    fn add_light(
        &mut self,
        light: &gltf::khr_lights_punctual::Light,
        world: Mat4,
    ) -> Result<(), String> {
        let what = format!("light {}", light.index());
        let color = Vec3::from(light.color());
        let intensity = light.intensity();
        let power = color * intensity;
        crate::light::check_radiance("colour × intensity", power.into())
            .map_err(|e| format!("{what}: {e}"))?;
        let range = light.range().unwrap_or(f32::INFINITY);
        if range.is_nan() || range <= 0.0 {
            return Err(format!("{what}: range must be positive"));
        }
        let position = world.transform_point3(Vec3::ZERO);
        let direction = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
        let needs_dir = !matches!(light.kind(), gltf::khr_lights_punctual::Kind::Point);
        if needs_dir && direction == Vec3::ZERO {
            return Err(format!("{what}: the node's transform gives no direction"));
        }
        let desc = match light.kind() {
            gltf::khr_lights_punctual::Kind::Point => LightDesc::Point {
                position,
                intensity: power,
                range,
            },
            gltf::khr_lights_punctual::Kind::Directional => LightDesc::Directional {
                direction,
                irradiance: power,
            },
            gltf::khr_lights_punctual::Kind::Spot {
                inner_cone_angle,
                outer_cone_angle,
            } => {
                let ok = inner_cone_angle >= 0.0
                    && inner_cone_angle < outer_cone_angle
                    && outer_cone_angle <= std::f32::consts::FRAC_PI_2 + 1e-6;
                if !ok {
                    return Err(format!(
                        "{what}: spot cone angles must satisfy 0 ≤ inner ({inner_cone_angle}) < outer ({outer_cone_angle}) ≤ π/2"
                    ));
                }
                LightDesc::Spot {
                    position,
                    direction,
                    intensity: power,
                    inner_angle: inner_cone_angle,
                    outer_angle: outer_cone_angle,
                    range,
                }
            }
        };
        self.desc.lights.push(desc);
        Ok(())
    }

    /// Default camera and default light.
    fn finish(&mut self, opts: &GltfOptions) -> Result<(), String> {
        if self.desc.cameras.is_empty() && opts.default_camera {
            let camera = default_camera(&self.desc);
            self.desc.cameras.push(camera);
        }
        // An emitter lights the model only if it glows as a whole: an untextured emissive
        // surface (a lamp). Emissive textures are decals, screens and LEDs.
        let lit_by_emitter = self.desc.objects.iter().any(|o| {
            self.desc
                .materials
                .get(o.material)
                .is_some_and(|m| m.emission.max_element() > 0.0 && m.emission_texture.is_none())
        });
        if opts.default_light && self.desc.lights.is_empty() && !lit_by_emitter {
            self.desc.environment = Some(EnvironmentDesc::Constant {
                radiance: Vec3::ONE,
            });
            self.desc.default_environment = true;
            self.warn(NO_LIGHT_WARNING.into());
        }
        Ok(())
    }
}

/// The world bounds of every object's mesh, or `None` for an empty scene.
fn world_bounds(desc: &SceneDesc) -> Option<(Vec3, Vec3)> {
    let local: Vec<Option<(Vec3, Vec3)>> = desc
        .meshes
        .iter()
        .map(|m| {
            let first = *m.positions.first()?;
            Some(
                m.positions
                    .iter()
                    .fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p))),
            )
        })
        .collect();
    let mut out: Option<(Vec3, Vec3)> = None;
    for o in &desc.objects {
        let ShapeDesc::Mesh { mesh } = o.shape else {
            continue;
        };
        let Some(Some((lo, hi))) = local.get(mesh) else {
            continue;
        };
        for i in 0..8 {
            let c = Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let p = o.transform.transform_point3(c);
            out = Some(match out {
                None => (p, p),
                Some((a, b)) => (a.min(p), b.max(p)),
            });
        }
    }
    out
}

/// A perspective camera looking down −Z from +Z, yfov 45°, far enough that the bounding
/// sphere of the scene fits the view.
fn default_camera(desc: &SceneDesc) -> CameraDesc {
    let yfov = 45f32.to_radians();
    let (center, radius) = match world_bounds(desc) {
        Some((lo, hi)) if (hi - lo).is_finite() => ((lo + hi) * 0.5, ((hi - lo) * 0.5).length()),
        _ => (Vec3::ZERO, 1.0),
    };
    let radius = if radius > 0.0 { radius } else { 1.0 };
    let distance = radius / (yfov * 0.5).sin();
    let eye = center + Vec3::Z * distance;
    CameraDesc {
        name: "default".into(),
        transform: Mat4::from_translation(eye),
        projection: Projection::Perspective {
            yfov,
            aperture_radius: 0.0,
            focus_distance: distance,
        },
        aspect: None,
    }
}

/// glTF requires the nodes to form a forest: no node with two parents, no cycle, checked over
/// every node as validators do (also those no scene shows, which the walk from a scene's roots
/// would never meet).
fn check_forest(doc: &gltf::Document) -> Result<(), String> {
    let n = doc.nodes().len();
    let mut parent: Vec<Option<usize>> = vec![None; n];
    for node in doc.nodes() {
        for c in node.children() {
            match parent.get_mut(c.index()) {
                Some(p @ None) => *p = Some(node.index()),
                Some(Some(other)) if *other == node.index() => {
                    return Err(format!(
                        "node {} lists node {} among its children twice: glTF nodes form trees",
                        node.index(),
                        c.index()
                    ))
                }
                Some(Some(other)) => {
                    return Err(format!(
                        "node {} has two parents (nodes {other} and {}): glTF nodes form trees",
                        c.index(),
                        node.index()
                    ))
                }
                None => {}
            }
        }
    }
    // With one parent at most, a node whose chain of parents never ends is in a cycle or
    // below one. Each node's chain is followed once: 0 not seen, 1 on the chain being
    // followed, 2 known to end.
    let mut state = vec![0u8; n];
    let mut chain = Vec::new();
    for start in 0..n {
        let mut i = start;
        while state[i] == 0 {
            state[i] = 1;
            chain.push(i);
            match parent[i] {
                Some(p) => i = p,
                None => break,
            }
        }
        if state[i] == 1 && parent[i].is_some() {
            return Err(format!(
                "node {i} is its own ancestor: the node hierarchy has a cycle"
            ));
        }
        for j in chain.drain(..) {
            state[j] = 2;
        }
    }
    Ok(())
}
