//! raytile's JSON scene format.

use super::{SceneDesc, SceneError};
use std::path::Path;

/// Loads a JSON scene file.
pub fn load_json(path: &Path) -> Result<SceneDesc, SceneError> {
    let _ = path;
    todo!()
}
