//! Render settings: everything about a render that is not the scene.

use serde::{Deserialize, Serialize};
use std::ops::Range;

/// Which light-transport algorithm renders the image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IntegratorKind {
    /// Unidirectional path tracing with next-event estimation and MIS.
    #[default]
    Path,
    /// Whitted's recursive ray tracer: shadow rays, mirror reflection and refraction.
    Whitted,
    /// Shading normals mapped to colours.
    Normals,
    /// Surface albedo (the denoiser's auxiliary buffer).
    Albedo,
    /// Distance from the camera along the primary ray.
    Depth,
    /// Ambient occlusion.
    Ao,
}

impl IntegratorKind {
    /// Every integrator, for tests and help texts.
    pub const ALL: [IntegratorKind; 6] = [
        Self::Path,
        Self::Whitted,
        Self::Normals,
        Self::Albedo,
        Self::Depth,
        Self::Ao,
    ];

    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Path => "path",
            Self::Whitted => "whitted",
            Self::Normals => "normals",
            Self::Albedo => "albedo",
            Self::Depth => "depth",
            Self::Ao => "ao",
        }
    }
}

impl std::str::FromStr for IntegratorKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                let names: Vec<_> = Self::ALL.iter().map(|k| k.name()).collect();
                format!(
                    "unknown integrator '{s}' (expected one of: {})",
                    names.join(", ")
                )
            })
    }
}

/// Pixel reconstruction filter. Samples are drawn from the filter's own distribution (filter
/// importance sampling, as pbrt-v4 does), so each pixel depends only on its own samples and
/// tiles never share pixels: the result cannot depend on tiling.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FilterKind {
    /// Uniform over the pixel.
    #[default]
    Box,
    /// Truncated Gaussian, radius 1.5 px, σ = 0.5 px.
    Gaussian,
    /// Blackman–Harris window, radius 2 px.
    BlackmanHarris,
}

impl FilterKind {
    /// Every filter.
    pub const ALL: [FilterKind; 3] = [Self::Box, Self::Gaussian, Self::BlackmanHarris];

    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Box => "box",
            Self::Gaussian => "gaussian",
            Self::BlackmanHarris => "blackman-harris",
        }
    }
}

impl std::str::FromStr for FilterKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                format!("unknown filter '{s}' (expected one of: box, gaussian, blackman-harris)")
            })
    }
}

/// A rectangle of pixels `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Tile {
    /// Left column (inclusive).
    pub x0: u32,
    /// Top row (inclusive).
    pub y0: u32,
    /// Right column (exclusive).
    pub x1: u32,
    /// Bottom row (exclusive).
    pub y1: u32,
}

impl Tile {
    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.x1 - self.x0
    }
    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.y1 - self.y0
    }
    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width() as usize * self.height() as usize
    }
}

/// Settings of one render. `Default` gives raytile's defaults; a scene's own settings and then
/// command-line flags or job fields override them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RenderSettings {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Maximum number of bounces (path vertices after the camera).
    pub max_depth: u32,
    /// Light-transport algorithm.
    pub integrator: IntegratorKind,
    /// Seed of the random sequences: change it for an independent image.
    pub seed: u32,
    /// Camera name or index; `None` picks the scene's first camera.
    pub camera: Option<String>,
    /// Reconstruction filter.
    pub filter: FilterKind,
    /// Tile edge in pixels (affects scheduling only, never the result).
    pub tile_size: u32,
    /// Number of progressive passes the samples are split into. Part of the job's identity: the
    /// per-pixel sums are added pass by pass in order, so the same `passes` gives the same bits.
    pub passes: u32,
    /// Whether a glTF scene without any light gets the default white environment its loader
    /// adds (as glTF viewers do). `false` renders such a scene black.
    pub default_light: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            width: 512,
            height: 512,
            spp: 64,
            max_depth: 16,
            integrator: IntegratorKind::Path,
            seed: 0,
            camera: None,
            filter: FilterKind::Box,
            tile_size: 32,
            passes: 1,
            default_light: true,
        }
    }
}

/// Largest image edge accepted, in pixels.
pub const MAX_EDGE: u32 = 1 << 15;
/// Largest image accepted, in pixels.
pub const MAX_PIXELS: u64 = 1 << 27;
/// Largest sample count accepted. The sampler draws Owen-scrambled Sobol points for the first
/// [`crate::sampling::SOBOL_SAMPLES`] (2^16, the sequence's length) samples of a pixel and hashed
/// numbers for the samples after them: just as deterministic and unbiased, but not stratified,
/// so the extra samples converge at the plain Monte Carlo rate.
pub const MAX_SPP: u32 = 1 << 20;
/// Longest path accepted.
pub const MAX_DEPTH: u32 = 1024;

impl RenderSettings {
    /// Checks every field; the error names the field and says what is allowed.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let bad = |f: &'static str, m: String| Err((f, m));
        if self.width == 0 || self.width > MAX_EDGE {
            return bad(
                "width",
                format!("must be between 1 and {MAX_EDGE}, got {}", self.width),
            );
        }
        if self.height == 0 || self.height > MAX_EDGE {
            return bad(
                "height",
                format!("must be between 1 and {MAX_EDGE}, got {}", self.height),
            );
        }
        if self.width as u64 * self.height as u64 > MAX_PIXELS {
            return bad(
                "width",
                format!("width × height must be at most {MAX_PIXELS} pixels"),
            );
        }
        if self.spp == 0 || self.spp > MAX_SPP {
            return bad(
                "spp",
                format!("must be between 1 and {MAX_SPP}, got {}", self.spp),
            );
        }
        if self.max_depth > MAX_DEPTH {
            return bad(
                "max_depth",
                format!("must be at most {MAX_DEPTH}, got {}", self.max_depth),
            );
        }
        if self.tile_size == 0 || self.tile_size > 4096 {
            return bad(
                "tile_size",
                format!("must be between 1 and 4096, got {}", self.tile_size),
            );
        }
        if self.passes == 0 || self.passes > self.spp {
            return bad(
                "passes",
                format!(
                    "must be between 1 and spp ({}), got {}",
                    self.spp, self.passes
                ),
            );
        }
        Ok(())
    }

    /// The sample-index ranges of the progressive passes, in order: `spp` split as evenly as
    /// possible, earlier passes taking the remainder.
    pub fn pass_ranges(&self) -> Vec<Range<u32>> {
        let passes = self.passes.clamp(1, self.spp.max(1));
        let (base, extra) = (self.spp / passes, self.spp % passes);
        let mut start = 0;
        (0..passes)
            .map(|i| {
                let n = base + u32::from(i < extra);
                let r = start..start + n;
                start += n;
                r
            })
            .collect()
    }

    /// The frame cut into tiles of `tile_size`, row by row.
    pub fn tiles(&self) -> Vec<Tile> {
        let ts = self.tile_size.max(1);
        let mut out = Vec::new();
        for y0 in (0..self.height).step_by(ts as usize) {
            for x0 in (0..self.width).step_by(ts as usize) {
                out.push(Tile {
                    x0,
                    y0,
                    x1: (x0 + ts).min(self.width),
                    y1: (y0 + ts).min(self.height),
                });
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passes_cover_every_sample_once() {
        for (spp, passes) in [(1, 1), (7, 3), (64, 4), (10, 10)] {
            let s = RenderSettings {
                spp,
                passes,
                ..Default::default()
            };
            let r = s.pass_ranges();
            assert_eq!(r.len() as u32, passes);
            assert_eq!(r[0].start, 0);
            assert_eq!(r.last().unwrap().end, spp);
            assert!(r
                .windows(2)
                .all(|w| w[0].end == w[1].start && !w[1].is_empty()));
        }
    }

    #[test]
    fn tiles_cover_the_frame() {
        let s = RenderSettings {
            width: 100,
            height: 37,
            tile_size: 16,
            ..Default::default()
        };
        let n: usize = s.tiles().iter().map(|t| t.pixel_count()).sum();
        assert_eq!(n, 3700);
    }

    #[test]
    fn validation_names_the_field() {
        let s = RenderSettings {
            spp: 0,
            ..Default::default()
        };
        assert_eq!(s.validate().unwrap_err().0, "spp");
        let s = RenderSettings {
            width: 100_000,
            ..Default::default()
        };
        assert_eq!(s.validate().unwrap_err().0, "width");
    }
}
