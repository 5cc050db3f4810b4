//! Scenes: plain descriptions ([`desc`]), the front ends that produce them ([`json`], [`gltf`])
//! and the builder that turns a description into the render-ready [`Scene`] ([`build`]).

pub mod build;
pub mod desc;
pub mod gltf;
pub mod json;

pub use build::Scene;
pub use desc::SceneDesc;

use std::path::{Path, PathBuf};

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

/// Loads a scene file by its extension: `.json` (raytile's format), `.gltf` or `.glb`.
pub fn load_scene(path: &Path) -> Result<SceneDesc, SceneError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("json") => json::load_json(path),
        Some("gltf") | Some("glb") => gltf::load_gltf(path),
        _ => Err(SceneError::UnknownFormat(path.to_path_buf())),
    }
}
