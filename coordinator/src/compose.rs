//! Composing a job's frame from its stored tile results, and encoding it.
//!
//! Determinism: a local render adds, for every pixel, pass 0's sums, then pass 1's, ... into a
//! zeroed film. Here too: each tile's passes are added in pass order, never in arrival order,
//! and a partial frame takes for each tile only the passes before its first missing one.

use crate::sched::Job;
use raytile_core::{Film, TileAccum};

/// Image formats the API serves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// 8-bit sRGB PNG.
    Png,
    /// 32-bit float OpenEXR.
    Exr,
    /// Radiance HDR.
    Hdr,
}

impl Format {
    /// Parses `png`, `exr` or `hdr`.
    pub fn from_name(s: &str) -> Option<Format> {
        match s.to_ascii_lowercase().as_str() {
            "png" => Some(Format::Png),
            "exr" => Some(Format::Exr),
            "hdr" => Some(Format::Hdr),
            _ => None,
        }
    }

    /// MIME type.
    pub fn content_type(self) -> &'static str {
        match self {
            Format::Png => "image/png",
            Format::Exr => "image/x-exr",
            Format::Hdr => "image/vnd.radiance",
        }
    }
}

/// The job's layout needed to compose: tile index and pass of every task index.
#[derive(Clone, Debug)]
pub struct Layout {
    width: u32,
    height: u32,
    ntiles: usize,
    npasses: usize,
    /// Task index → tile index.
    task_tile: Vec<u32>,
}

impl Layout {
    /// Captures a job's layout (cheap; taken under the scheduler lock, used after it).
    pub fn of(job: &Job) -> Layout {
        Layout {
            width: job.settings.width,
            height: job.settings.height,
            ntiles: job.tiles.len(),
            npasses: job.passes.len(),
            task_tile: job.tasks.iter().map(|t| t.tile).collect(),
        }
    }
}

/// Builds the frame from `(task index, decoded result)` pairs given in any order.
pub fn compose(layout: &Layout, results: Vec<(u32, TileAccum)>) -> Film {
    // slot[pass][tile]
    let mut slots: Vec<Vec<Option<TileAccum>>> = (0..layout.npasses)
        .map(|_| (0..layout.ntiles).map(|_| None).collect())
        .collect();
    for (idx, acc) in results {
        let idx = idx as usize;
        if idx >= layout.task_tile.len() {
            continue;
        }
        let pass = idx / layout.ntiles.max(1);
        let tile = layout.task_tile[idx] as usize;
        slots[pass][tile] = Some(acc);
    }
    let mut film = film_new(layout.width, layout.height);
    let mut open = vec![true; layout.ntiles];
    for pass in slots {
        for (tile, acc) in pass.into_iter().enumerate() {
            match acc {
                Some(acc) if open[tile] => film_add_tile(&mut film, &acc),
                _ => open[tile] = false,
            }
        }
    }
    film
}

// --- Film operations -------------------------------------------------------------------------
// The core's `Film::new`, `Film::add_tile` and `film::encode` are being written by the lead; until
// they land these mirror their documented behaviour. After merging `main`, replace the bodies
// with the core calls (one place) so the coordinator and a local render share every bit.

/// A zeroed film.
pub fn film_new(width: u32, height: u32) -> Film {
    Film {
        width,
        height,
        pixels: vec![[0.0; 4]; width as usize * height as usize],
        bad_samples: 0,
    }
}

/// Adds a tile's per-pixel sums into the film.
pub fn film_add_tile(film: &mut Film, acc: &TileAccum) {
    let t = acc.tile;
    if t.x1 > film.width || t.y1 > film.height || acc.pixels.len() != t.pixel_count() {
        return;
    }
    let w = t.width() as usize;
    for (row, y) in (t.y0..t.y1).enumerate() {
        let base = y as usize * film.width as usize + t.x0 as usize;
        for (dst, src) in film.pixels[base..base + w]
            .iter_mut()
            .zip(&acc.pixels[row * w..(row + 1) * w])
        {
            for c in 0..4 {
                dst[c] += src[c];
            }
        }
    }
    film.bad_samples += acc.bad_samples;
}

/// Encodes the film's resolved pixels.
pub fn encode(film: &Film, format: Format) -> Result<Vec<u8>, String> {
    let rgb: Vec<f32> = film
        .pixels
        .iter()
        .flat_map(|p| {
            let w = p[3];
            if w > 0.0 {
                [p[0] / w, p[1] / w, p[2] / w]
            } else {
                [0.0; 3]
            }
        })
        .collect();
    let mut out = std::io::Cursor::new(Vec::new());
    let img = image::Rgb32FImage::from_raw(film.width, film.height, rgb)
        .ok_or_else(|| "film size mismatch".to_string())?;
    match format {
        Format::Exr => image::DynamicImage::ImageRgb32F(img)
            .write_to(&mut out, image::ImageFormat::OpenExr)
            .map_err(|e| e.to_string())?,
        Format::Hdr => image::DynamicImage::ImageRgb32F(img)
            .write_to(&mut out, image::ImageFormat::Hdr)
            .map_err(|e| e.to_string())?,
        Format::Png => {
            let srgb = |v: f32| {
                let v = v.clamp(0.0, 1.0);
                let s = if v <= 0.003_130_8 {
                    12.92 * v
                } else {
                    1.055 * v.powf(1.0 / 2.4) - 0.055
                };
                (s * 255.0 + 0.5) as u8
            };
            let bytes: Vec<u8> = img.as_raw().iter().map(|&v| srgb(v)).collect();
            let img8 = image::RgbImage::from_raw(film.width, film.height, bytes)
                .ok_or_else(|| "film size mismatch".to_string())?;
            image::DynamicImage::ImageRgb8(img8)
                .write_to(&mut out, image::ImageFormat::Png)
                .map_err(|e| e.to_string())?
        }
    }
    Ok(out.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sched::centre_out;
    use raytile_core::{RenderSettings, Tile};

    /// Made-up sums for (tile, pass): values that round differently in different orders.
    fn fake(tile: Tile, pass: u32) -> TileAccum {
        TileAccum {
            tile,
            pixels: (0..tile.pixel_count())
                .map(|i| {
                    let v = 0.1 + (i as f32) * 1e-3 + pass as f32 * 1e7;
                    [v, v * 3.3, 1e-8 * (pass as f32 + 1.0), 1.0]
                })
                .collect(),
            bad_samples: 0,
        }
    }

    #[test]
    fn composition_is_independent_of_arrival_order() {
        let s = RenderSettings {
            width: 40,
            height: 24,
            tile_size: 16,
            spp: 3,
            passes: 3,
            ..Default::default()
        };
        let tiles = s.tiles();
        let order = centre_out(&s, &tiles);
        let layout = Layout {
            width: 40,
            height: 24,
            ntiles: tiles.len(),
            npasses: 3,
            task_tile: (0..3).flat_map(|_| order.clone()).collect(),
        };
        // Reference: pass by pass, every tile, into a zeroed film (what a local render does).
        let mut want = film_new(40, 24);
        for p in 0..3 {
            for t in &tiles {
                film_add_tile(&mut want, &fake(*t, p));
            }
        }
        let mut results: Vec<(u32, TileAccum)> = (0..layout.task_tile.len() as u32)
            .map(|i| {
                let pass = i / tiles.len() as u32;
                let tile = tiles[layout.task_tile[i as usize] as usize];
                (i, fake(tile, pass))
            })
            .collect();
        results.reverse();
        let got = compose(&layout, results.clone());
        assert_eq!(bits(&got), bits(&want));
        results.rotate_left(5);
        assert_eq!(bits(&compose(&layout, results)), bits(&want));
    }

    #[test]
    fn partial_frames_use_only_leading_passes() {
        let s = RenderSettings {
            width: 16,
            height: 16,
            tile_size: 16,
            spp: 2,
            passes: 2,
            ..Default::default()
        };
        let t = s.tiles()[0];
        let layout = Layout {
            width: 16,
            height: 16,
            ntiles: 1,
            npasses: 2,
            task_tile: vec![0, 0],
        };
        // Only pass 1 arrived: the tile must stay empty rather than show pass 1 alone.
        let f = compose(&layout, vec![(1, fake(t, 1))]);
        assert!(f.pixels.iter().all(|p| p[3] == 0.0));
        let f = compose(&layout, vec![(0, fake(t, 0))]);
        assert!(f.pixels.iter().all(|p| p[3] == 1.0));
    }

    fn bits(f: &Film) -> Vec<u32> {
        f.pixels.iter().flatten().map(|v| v.to_bits()).collect()
    }

    #[test]
    fn encodes_every_format() {
        let f = film_new(4, 3);
        for fmt in [Format::Png, Format::Exr, Format::Hdr] {
            assert!(!encode(&f, fmt).unwrap().is_empty());
        }
    }
}
