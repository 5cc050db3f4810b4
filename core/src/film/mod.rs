//! The film: per-pixel accumulation, reconstruction filters, tone mapping and image output.
//!
//! Pixels hold sums (RGB and weight). Filters are applied by *filter importance sampling*
//! (pbrt-v4): each sample's position within its pixel is drawn from the filter's distribution
//! and its weight is 1, so a pixel depends only on its own samples and tiles never overlap.

pub mod filter;
pub mod output;

pub use filter::FilterSampler;
pub use output::{
    check_writable, encode, encode_with, save, FilmError, ImageFormat, Metadata, OutputOptions,
    ToneMap,
};

/// Per-pixel sums of one tile over one range of samples (what a worker uploads, so the type is
/// the wire crate's).
pub use raytile_proto::tile::TileAccum;

/// Fixed-point scale of splats (light a sample adds to other pixels, as `bdpt`'s light paths
/// joined to the camera do): a splat's channel value `v` is stored as `round(v · 2^56)` in an
/// `i128` ([`raytile_proto::tile::SPLAT_FRACTION_BITS`]), so any number of splats add exactly
/// and in any order.
pub const SPLAT_SCALE: f64 = (1u64 << raytile_proto::tile::SPLAT_FRACTION_BITS) as f64;

/// The largest value a sample may add to a pixel, per channel: half of f32's largest value
/// over the most samples a pixel can receive ([`crate::settings::MAX_SPP`], 2^20), about
/// 1.6·10^32. A pixel's sums therefore never overflow to infinity, whatever the sample count
/// and however the passes are cut. A sample above it (or NaN, or infinite) is dropped and
/// counted in [`Film::bad_samples`], as NaN and infinite ones are.
pub const MAX_SAMPLE: f32 = f32::MAX / (2.0 * crate::settings::MAX_SPP as f32);

/// Whether a sample's value `l` may be added to a pixel: finite and at most [`MAX_SAMPLE`] in
/// magnitude in every channel.
#[inline]
pub fn sample_ok(l: glam::Vec3A) -> bool {
    l.is_finite() && l.abs().max_element() <= MAX_SAMPLE
}

/// Why [`Film::add_tile`] refused a tile.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TileMismatch {
    /// The tile reaches outside the film (or is inverted).
    #[error("tile [{}, {}) × [{}, {}) lies outside the {width}×{height} film", tile.x0, tile.x1, tile.y0, tile.y1)]
    Outside {
        /// The tile.
        tile: crate::Tile,
        /// Film width.
        width: u32,
        /// Film height.
        height: u32,
    },
    /// The tile's pixels are not its size.
    #[error("tile [{}, {}) × [{}, {}) has {got} pixels, expected {expected}", tile.x0, tile.x1, tile.y0, tile.y1)]
    PixelCount {
        /// The tile.
        tile: crate::Tile,
        /// Its pixel count.
        expected: usize,
        /// The pixels given.
        got: usize,
    },
    /// The tile carries coverage and the film has no alpha channel, or the other way round,
    /// or its coverage is not one value per pixel.
    #[error("tile [{}, {}) × [{}, {}) has coverage for {got} pixels, expected {expected}", tile.x0, tile.x1, tile.y0, tile.y1)]
    Coverage {
        /// The tile.
        tile: crate::Tile,
        /// Coverage values the film needs: the tile's pixel count, or none.
        expected: usize,
        /// The coverage values given.
        got: usize,
    },
    /// A splat names a pixel outside the film.
    #[error("splat for pixel {index} lies outside the {width}×{height} film")]
    Splat {
        /// The pixel index.
        index: u32,
        /// Film width.
        width: u32,
        /// Film height.
        height: u32,
    },
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
    /// Samples dropped because they were NaN, infinite or above [`MAX_SAMPLE`].
    pub bad_samples: u64,
    /// Row-major fixed-point RGB sums of the light that samples carried to other pixels
    /// (`bdpt`'s splats, see [`TileAccum::splats`]); empty while none arrived.
    pub splats: Vec<[i128; 3]>,
    /// Camera samples added so far over the whole frame (weights and dropped samples): the
    /// splat sums are divided by this over the pixel count (the samples per pixel).
    pub samples: f64,
    /// Row-major sums of coverage ([`TileAccum::coverage`]) for a film with an alpha channel;
    /// empty for one without.
    pub coverage: Vec<f32>,
}

impl Film {
    /// An empty film without an alpha channel.
    pub fn new(width: u32, height: u32) -> Self {
        Self::with_alpha(width, height, false)
    }

    /// An empty film, with an alpha channel if `alpha` (the job's
    /// [`RenderSettings::alpha`](crate::settings::RenderSettings::alpha)): its tiles must then
    /// carry coverage, and without it they must not.
    pub fn with_alpha(width: u32, height: u32, alpha: bool) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            pixels: vec![[0.0; 4]; n],
            bad_samples: 0,
            splats: Vec::new(),
            samples: 0.0,
            coverage: if alpha { vec![0.0; n] } else { Vec::new() },
        }
    }

    /// Whether the film has an alpha channel.
    pub fn has_alpha(&self) -> bool {
        !self.coverage.is_empty()
    }

    /// Adds a tile's sums. The caller adds the tiles of each pass in pass order, which is what
    /// makes the result independent of who rendered which tile when. A tile that does not fit
    /// the film, whose pixels are not its size, or whose coverage does not match the film's
    /// alpha channel, is refused and the film is unchanged.
    pub fn add_tile(&mut self, t: &TileAccum) -> Result<(), TileMismatch> {
        let tile = t.tile;
        if tile.x0 > tile.x1 || tile.y0 > tile.y1 || tile.x1 > self.width || tile.y1 > self.height {
            return Err(TileMismatch::Outside {
                tile,
                width: self.width,
                height: self.height,
            });
        }
        if t.pixels.len() != tile.pixel_count() {
            return Err(TileMismatch::PixelCount {
                tile,
                expected: tile.pixel_count(),
                got: t.pixels.len(),
            });
        }
        let expected = if self.has_alpha() {
            tile.pixel_count()
        } else {
            0
        };
        if t.coverage.len() != expected {
            return Err(TileMismatch::Coverage {
                tile,
                expected,
                got: t.coverage.len(),
            });
        }
        let len = self.pixels.len();
        if let Some(&(index, _)) = t.splats.iter().find(|s| s.0 as usize >= len) {
            return Err(TileMismatch::Splat {
                index,
                width: self.width,
                height: self.height,
            });
        }
        if !t.splats.is_empty() && self.splats.is_empty() {
            self.splats = vec![[0; 3]; len];
        }
        for &(i, rgb) in &t.splats {
            let dst = &mut self.splats[i as usize];
            for k in 0..3 {
                dst[k] = dst[k].saturating_add(rgb[k]);
            }
        }
        self.samples += t.pixels.iter().map(|p| p[3] as f64).sum::<f64>() + t.bad_samples as f64;
        let w = tile.width() as usize;
        for (row, src) in t.pixels.chunks(w.max(1)).enumerate() {
            let y = tile.y0 as usize + row;
            let start = y * self.width as usize + tile.x0 as usize;
            for (dst, s) in self.pixels[start..start + w].iter_mut().zip(src) {
                for k in 0..4 {
                    dst[k] += s[k];
                }
            }
            if let Some(cov) = t.coverage.get(row * w..(row + 1) * w) {
                for (dst, c) in self.coverage[start..start + w].iter_mut().zip(cov) {
                    *dst += c;
                }
            }
        }
        // Saturating: a count no renderer makes (a stored result from before the coordinator
        // checked it) must not wrap around, nor stop a debug build.
        self.bad_samples = self.bad_samples.saturating_add(t.bad_samples);
        Ok(())
    }

    /// Linear RGB per pixel (sum / weight; black where no sample landed), plus the pixel's
    /// splats divided by the samples per pixel.
    pub fn resolve(&self) -> Vec<[f32; 3]> {
        let mut out: Vec<[f32; 3]> = self
            .pixels
            .iter()
            .map(|p| {
                if p[3] > 0.0 {
                    [p[0] / p[3], p[1] / p[3], p[2] / p[3]]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        if !self.splats.is_empty() && self.samples > 0.0 {
            let spp = self.samples / self.pixels.len() as f64;
            let scale = 1.0 / (spp * SPLAT_SCALE);
            for (o, s) in out.iter_mut().zip(&self.splats) {
                for k in 0..3 {
                    o[k] = (o[k] as f64 + s[k] as f64 * scale) as f32;
                }
            }
        }
        out
    }

    /// Alpha per pixel (coverage / weight; 0 where no sample landed), for a film with an alpha
    /// channel. The colours of [`Film::resolve`] are then premultiplied by it.
    pub fn alpha(&self) -> Option<Vec<f32>> {
        self.has_alpha().then(|| {
            self.pixels
                .iter()
                .zip(&self.coverage)
                .map(|(p, c)| if p[3] > 0.0 { c / p[3] } else { 0.0 })
                .collect()
        })
    }

    /// Mean of each channel over the image.
    pub fn mean(&self) -> [f64; 3] {
        let px = self.resolve();
        let mut m = [0.0f64; 3];
        for p in &px {
            for k in 0..3 {
                m[k] += p[k] as f64;
            }
        }
        m.map(|v| v / px.len().max(1) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Tile;

    #[test]
    fn tiles_land_where_they_belong() {
        let mut f = Film::new(4, 3);
        let tile = Tile {
            x0: 1,
            y0: 1,
            x1: 3,
            y1: 3,
        };
        f.add_tile(&TileAccum {
            tile,
            pixels: vec![[2.0, 4.0, 6.0, 2.0]; 4],
            bad_samples: 1,
            splats: Vec::new(),
            coverage: Vec::new(),
        })
        .unwrap();
        let px = f.resolve();
        assert_eq!(px[4 + 1], [1.0, 2.0, 3.0]);
        assert_eq!(px[0], [0.0; 3]);
        assert_eq!(f.bad_samples, 1);
        let before = f.clone();
        // A tile that does not fit, or is not its size, is refused: an error, not a panic,
        // and the film is unchanged.
        let outside = f.add_tile(&TileAccum {
            tile: Tile {
                x0: 3,
                y0: 0,
                x1: 9,
                y1: 1,
            },
            pixels: vec![[1.0; 4]; 6],
            bad_samples: 5,
            splats: Vec::new(),
            coverage: Vec::new(),
        });
        assert!(
            matches!(outside, Err(TileMismatch::Outside { .. })),
            "{outside:?}"
        );
        let short = f.add_tile(&TileAccum {
            tile,
            pixels: vec![[1.0; 4]; 3],
            bad_samples: 5,
            splats: Vec::new(),
            coverage: Vec::new(),
        });
        assert_eq!(
            short,
            Err(TileMismatch::PixelCount {
                tile,
                expected: 4,
                got: 3
            })
        );
        assert!(short
            .unwrap_err()
            .to_string()
            .contains("3 pixels, expected 4"));
        // Coverage only where the film has an alpha channel, one value per pixel.
        let covered = TileAccum {
            tile,
            pixels: vec![[1.0; 4]; 4],
            bad_samples: 0,
            splats: Vec::new(),
            coverage: vec![1.0; 4],
        };
        assert!(matches!(
            f.add_tile(&covered),
            Err(TileMismatch::Coverage {
                expected: 0,
                got: 4,
                ..
            })
        ));
        assert_eq!(f, before);
        let mut a = Film::with_alpha(4, 3, true);
        let empty = a.clone();
        let bare = TileAccum {
            coverage: Vec::new(),
            ..covered.clone()
        };
        let e = a.add_tile(&bare).unwrap_err();
        assert!(
            e.to_string().contains("coverage for 0 pixels, expected 4"),
            "{e}"
        );
        assert_eq!(a, empty);
        a.add_tile(&covered).unwrap();
        a.add_tile(&covered).unwrap();
        let alpha = a.alpha().unwrap();
        assert_eq!((alpha[5], alpha[0]), (1.0, 0.0));
        assert_eq!(a.coverage[5], 2.0);
    }

    #[test]
    fn dropped_sample_counts_saturate_rather_than_wrap() {
        let mut f = Film::new(1, 1);
        let t = TileAccum {
            tile: Tile {
                x0: 0,
                y0: 0,
                x1: 1,
                y1: 1,
            },
            pixels: vec![[0.0; 4]],
            bad_samples: u64::MAX,
            splats: Vec::new(),
            coverage: Vec::new(),
        };
        f.add_tile(&t).unwrap();
        f.add_tile(&t).unwrap();
        assert_eq!(f.bad_samples, u64::MAX);
    }
}
