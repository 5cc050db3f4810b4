//! Composing a job's frame from its stored tile results, and encoding it.
//!
//! Determinism: a local render adds, for every pixel, pass 0's sums, then pass 1's, ... into a
//! zeroed film. Here too: each tile's passes are added in pass order, never in arrival order,
//! and a partial frame takes for each tile only the passes before its first missing one.

use crate::sched::Job;
use raytile_core::film::{ImageFormat, OutputOptions};
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

// --- Film operations: the core's own, so the coordinator and a local render share every bit.

/// A zeroed film.
pub fn film_new(width: u32, height: u32) -> Film {
    Film::new(width, height)
}

/// Adds a tile's per-pixel sums into the film.
pub fn film_add_tile(film: &mut Film, acc: &TileAccum) {
    film.add_tile(acc);
}

/// Encodes the film with the core's encoder and default output options.
pub fn encode(film: &Film, format: Format) -> Result<Vec<u8>, String> {
    let f = match format {
        Format::Png => ImageFormat::Png,
        Format::Exr => ImageFormat::Exr,
        Format::Hdr => ImageFormat::Hdr,
    };
    raytile_core::film::encode(film, f, &OutputOptions::default()).map_err(|e| e.to_string())
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
