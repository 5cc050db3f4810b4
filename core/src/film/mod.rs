//! The film: per-pixel accumulation, and image output.

use crate::Tile;

/// Per-pixel sums of one tile over one range of samples: RGB sum and weight sum, plus the
/// count of NaN/Inf samples that were dropped.
#[derive(Clone, Debug, PartialEq)]
pub struct TileAccum {
    /// The pixels covered.
    pub tile: Tile,
    /// Row-major [r, g, b, weight] sums.
    pub pixels: Vec<[f32; 4]>,
    /// Samples dropped because they were NaN or infinite.
    pub bad_samples: u64,
}

/// The whole frame's accumulated sums.
#[derive(Clone, Debug, PartialEq)]
pub struct Film {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major [r, g, b, weight] sums.
    pub pixels: Vec<[f32; 4]>,
    /// Samples dropped because they were NaN or infinite.
    pub bad_samples: u64,
}
