//! Composing a job's frame from its stored tile results, and encoding it.
//!
//! Determinism: a local render adds, for every pixel, pass 0's sums, then pass 1's, ... into a
//! zeroed film. Here too: each tile's passes are added in pass order, never in arrival order,
//! and a partial frame takes for each tile only the passes before its first missing one.

use crate::sched::TaskLayout;
use raytile_core::film::{ImageFormat, OutputOptions};
use raytile_core::{Film, TileAccum};
use std::ops::Range;

/// The MIME type of an image format the API serves.
pub fn content_type(format: ImageFormat) -> &'static str {
    match format {
        ImageFormat::Png => "image/png",
        ImageFormat::Exr => "image/x-exr",
        ImageFormat::Hdr => "image/vnd.radiance",
    }
}

/// Builds the frame from `(task index, decoded result)` pairs given in any order.
pub fn compose(layout: &TaskLayout, results: Vec<(u32, TileAccum)>) -> Film {
    let mut by_task: Vec<Option<TileAccum>> = (0..layout.task_count()).map(|_| None).collect();
    for (idx, acc) in results {
        if let Some(slot) = by_task.get_mut(idx as usize) {
            *slot = Some(acc);
        }
    }
    let read = |tasks: Range<usize>, add: &mut dyn FnMut(u32, TileAccum)| {
        for i in tasks {
            if let Some(acc) = by_task[i].take() {
                add(i as u32, acc);
            }
        }
        Ok::<(), std::convert::Infallible>(())
    };
    match compose_by_pass(layout, read) {
        Ok((film, _)) => film,
        Err(never) => match never {},
    }
}

/// Builds the frame pass by pass: `read_pass(tasks, add)` hands every stored result among the
/// task indices `tasks` (one pass's) to `add`, one at a time, so that the frame and one tile
/// are all that is held. A tile takes the passes before its first missing one, added in pass
/// order, as a local render adds them. A result that is not its task's tile and pass, or that
/// the film refuses, is left out, and its task is returned with the frame: a stored result
/// that is damaged, like one that does not decode.
pub fn compose_by_pass<E>(
    layout: &TaskLayout,
    mut read_pass: impl FnMut(Range<usize>, &mut dyn FnMut(u32, TileAccum)) -> Result<(), E>,
) -> Result<(Film, Vec<u32>), E> {
    let mut refused = Vec::new();
    let mut film = Film::with_alpha(layout.width(), layout.height(), layout.alpha());
    // Tiles whose passes so far are all present.
    let mut open = vec![true; layout.tile_count()];
    let mut seen = vec![false; layout.tile_count()];
    for pass in 0..layout.pass_count() {
        seen.fill(false);
        read_pass(layout.pass_tasks(pass), &mut |idx, acc| {
            let Some(work) = layout.task(idx as usize) else {
                return;
            };
            let t = work.tile_index as usize;
            if work.pass as usize != pass || acc.tile != work.tile {
                tracing::error!(
                    task = idx,
                    "stored result left out: not its task's tile and pass"
                );
                refused.push(idx);
                return;
            }
            if !open[t] || seen[t] {
                return;
            }
            // The core's own film operations, so the coordinator and a local render share
            // every bit. A tile the film refuses counts as missing.
            match film.add_tile(&acc) {
                Ok(()) => seen[t] = true,
                Err(e) => {
                    tracing::error!(task = idx, "stored result left out: {e}");
                    refused.push(idx);
                }
            }
        })?;
        for (o, s) in open.iter_mut().zip(&seen) {
            *o &= *s;
        }
    }
    Ok((film, refused))
}

/// Encodes the film of a job of `settings` with the core's encoder, output options `opts` and
/// the metadata `raytile render` writes (the same bytes as its file, once every tile is in).
pub fn encode(
    film: &Film,
    format: ImageFormat,
    opts: &OutputOptions,
    settings: &raytile_core::RenderSettings,
) -> Result<Vec<u8>, String> {
    let meta = raytile_core::film::Metadata::of_render(settings, film);
    raytile_core::film::encode_with(film, format, opts, &meta).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
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
            splats: Vec::new(),
            coverage: Vec::new(),
        }
    }

    /// Made-up sums for every task of `layout`, by task index.
    fn results(layout: &TaskLayout) -> Vec<(u32, TileAccum)> {
        (0..layout.task_count())
            .map(|i| {
                let w = layout.task(i).unwrap();
                (i as u32, fake(w.tile, w.pass))
            })
            .collect()
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
        let layout = TaskLayout::new(&s);
        // Reference: pass by pass, every tile, into a zeroed film (what a local render does).
        let mut want = Film::new(40, 24);
        for p in 0..3 {
            for t in &s.tiles() {
                want.add_tile(&fake(*t, p)).unwrap();
            }
        }
        let mut results = results(&layout);
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
        let layout = TaskLayout::new(&s);
        let t = s.tiles()[0];
        // Only pass 1 arrived: the tile must stay empty rather than show pass 1 alone.
        let f = compose(&layout, vec![(1, fake(t, 1))]);
        assert!(f.pixels.iter().all(|p| p[3] == 0.0));
        let f = compose(&layout, vec![(0, fake(t, 0))]);
        assert!(f.pixels.iter().all(|p| p[3] == 1.0));
        // A result for a task the job does not have is ignored.
        let f = compose(&layout, vec![(0, fake(t, 0)), (2, fake(t, 1))]);
        assert!(f.pixels.iter().all(|p| p[3] == 1.0));
        // A stored result of other pixels than its task's is left out and named, as a
        // damaged one; the pass after it is only left out.
        let other = Tile {
            x0: 0,
            y0: 0,
            x1: 8,
            y1: 8,
        };
        let stored = [(0, fake(other, 0)), (1, fake(t, 1))];
        let read = |tasks: Range<usize>, add: &mut dyn FnMut(u32, TileAccum)| {
            for (i, acc) in stored
                .iter()
                .filter(|(i, _)| tasks.contains(&(*i as usize)))
            {
                add(*i, acc.clone());
            }
            Ok::<(), std::convert::Infallible>(())
        };
        let (f, refused) = compose_by_pass(&layout, read).unwrap();
        assert_eq!(refused, [0]);
        assert!(f.pixels.iter().all(|p| p[3] == 0.0));
    }

    fn bits(f: &Film) -> Vec<u32> {
        f.pixels.iter().flatten().map(|v| v.to_bits()).collect()
    }

    #[test]
    fn encodes_every_format() {
        let f = Film::new(4, 3);
        for (fmt, magic) in [
            (ImageFormat::Png, &b"\x89PNG"[..]),
            (ImageFormat::Exr, &[0x76, 0x2f, 0x31, 0x01][..]),
            (ImageFormat::Hdr, &b"#?RADIANCE"[..]),
        ] {
            let bytes = encode(
                &f,
                fmt,
                &OutputOptions::default(),
                &RenderSettings::default(),
            )
            .unwrap();
            assert!(bytes.starts_with(magic), "{fmt:?}: {:?}", &bytes[..8]);
            assert!(content_type(fmt).starts_with("image/"));
        }
    }
}
