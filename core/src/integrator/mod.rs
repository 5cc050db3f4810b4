//! Integrators: how radiance along camera rays is estimated, and `render_tile`.

use crate::{Film, RenderSettings, Scene, Tile, TileAccum};
use std::ops::Range;

/// Progress reports during [`render`].
pub trait RenderProgress: Sync {
    /// Called after each finished tile with the number of samples it took.
    fn tile_done(&self, samples: u64);
}

impl RenderProgress for () {
    fn tile_done(&self, _samples: u64) {}
}

/// Renders samples `samples` of every pixel of `tile`.
pub fn render_tile(
    scene: &Scene,
    settings: &RenderSettings,
    tile: Tile,
    samples: Range<u32>,
) -> TileAccum {
    let _ = (scene, settings, tile, samples);
    todo!()
}

/// Renders the whole frame on the current rayon pool, pass by pass.
pub fn render(scene: &Scene, settings: &RenderSettings, progress: &dyn RenderProgress) -> Film {
    let _ = (scene, settings, progress);
    todo!()
}
