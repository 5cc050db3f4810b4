//! Turns a [`SceneDesc`] into the render-ready [`Scene`].

use super::{SceneDesc, SceneError};
use crate::RenderSettings;

/// A scene ready to render: world-space primitives in a BVH, materials, lights, camera.
pub struct Scene {}

impl Scene {
    /// Builds the scene for a render with `settings` (the camera and aspect come from them).
    pub fn build(desc: &SceneDesc, settings: &RenderSettings) -> Result<Scene, SceneError> {
        let _ = (desc, settings);
        todo!()
    }
}
