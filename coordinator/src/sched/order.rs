//! Which task comes next. Jobs by priority (higher first), then submission order; within a
//! job, pass by pass (every tile of pass 0 before any of pass 1, so a partial frame sharpens
//! evenly), tiles centre-out within a pass. The task layout is the one place that knows how a
//! task index maps to a tile and a pass.

use super::jobs::Job;
use raytile_core::{RenderSettings, Tile};
use std::collections::HashMap;
use std::ops::Range;

/// How a job's frame is cut into tasks: tiles × passes, pass-major, tiles centre-out within a
/// pass. Task `i` is pass `i / tiles` and the `i % tiles`-th tile from the centre.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TaskLayout {
    width: u32,
    height: u32,
    /// Tiles in `RenderSettings::tiles` order.
    tiles: Vec<Tile>,
    /// Sample ranges of the passes.
    passes: Vec<Range<u32>>,
    /// Tile indices, centre-out.
    order: Vec<u32>,
    /// Whether the job's results carry coverage (an alpha channel).
    alpha: bool,
}

/// What one task renders.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TaskWork {
    /// Index into the job's tiles (`RenderSettings::tiles` order).
    pub tile_index: u32,
    /// The pixels.
    pub tile: Tile,
    /// Pass index.
    pub pass: u32,
    /// Sample indices of the pass.
    pub samples: Range<u32>,
}

impl TaskWork {
    /// Samples of the task: pixels × samples per pixel.
    pub fn sample_count(&self) -> u64 {
        self.tile.pixel_count() as u64 * u64::from(self.samples.end - self.samples.start)
    }
}

impl TaskLayout {
    /// The layout of a job with `settings`.
    pub fn new(settings: &RenderSettings) -> TaskLayout {
        let tiles = settings.tiles();
        let order = centre_out(settings, &tiles);
        TaskLayout {
            width: settings.width,
            height: settings.height,
            tiles,
            passes: settings.pass_ranges(),
            order,
            alpha: settings.alpha,
        }
    }

    /// Whether the frame has an alpha channel: every result carries coverage.
    pub fn alpha(&self) -> bool {
        self.alpha
    }

    /// Frame width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Frame height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Tiles of the frame.
    pub fn tile_count(&self) -> usize {
        self.tiles.len()
    }

    /// Passes of every tile.
    pub fn pass_count(&self) -> usize {
        self.passes.len()
    }

    /// Tasks: tiles × passes.
    pub fn task_count(&self) -> usize {
        self.tiles.len() * self.passes.len()
    }

    /// The task indices of pass `pass`.
    pub fn pass_tasks(&self, pass: usize) -> Range<usize> {
        let n = self.tiles.len();
        pass * n..(pass + 1) * n
    }

    /// What task `idx` renders, or `None` past the last task.
    pub fn task(&self, idx: usize) -> Option<TaskWork> {
        if idx >= self.task_count() {
            return None;
        }
        let n = self.tiles.len();
        let tile_index = self.order[idx % n];
        let pass = idx / n;
        Some(TaskWork {
            tile_index,
            tile: self.tiles[tile_index as usize],
            pass: pass as u32,
            samples: self.passes[pass].clone(),
        })
    }
}

/// Tiles ordered centre-out: by distance of the tile centre from the image centre, ties by
/// row order, so the interesting middle of the frame appears first.
pub fn centre_out(settings: &RenderSettings, tiles: &[Tile]) -> Vec<u32> {
    let (cx, cy) = (settings.width as f64 / 2.0, settings.height as f64 / 2.0);
    let mut order: Vec<u32> = (0..tiles.len() as u32).collect();
    let d = |t: &Tile| {
        let x = (t.x0 + t.x1) as f64 / 2.0 - cx;
        let y = (t.y0 + t.y1) as f64 / 2.0 - cy;
        x * x + y * y
    };
    order.sort_by(|&a, &b| {
        d(&tiles[a as usize])
            .total_cmp(&d(&tiles[b as usize]))
            .then(a.cmp(&b))
    });
    order
}

/// The ids of the jobs `eligible` keeps, in the order they get workers: highest priority
/// first, then oldest.
pub(super) fn job_queue(
    jobs: &HashMap<String, Job>,
    eligible: impl Fn(&Job) -> bool,
) -> Vec<String> {
    // `Reverse`, not negation: `-i32::MIN` overflows (a priority is any i32).
    let mut order: Vec<(std::cmp::Reverse<i32>, u64, &str)> = jobs
        .values()
        .filter(|j| eligible(j))
        .map(|j| (std::cmp::Reverse(j.priority), j.seq, j.id.as_str()))
        .collect();
    order.sort_unstable();
    order.into_iter().map(|(_, _, id)| id.to_string()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(width: u32, height: u32, tile_size: u32, spp: u32, passes: u32) -> RenderSettings {
        RenderSettings {
            width,
            height,
            tile_size,
            spp,
            passes,
            ..Default::default()
        }
    }

    #[test]
    fn centre_tiles_go_first() {
        let s = settings(48, 48, 16, 1, 1);
        let tiles = s.tiles();
        let order = centre_out(&s, &tiles);
        assert_eq!(
            tiles[order[0] as usize],
            Tile {
                x0: 16,
                y0: 16,
                x1: 32,
                y1: 32
            }
        );
        // Ties (the four edge-centre tiles) in row order, corners last.
        assert_eq!(order, vec![4, 1, 3, 5, 7, 0, 2, 6, 8]);
    }

    #[test]
    fn every_tile_and_pass_is_one_task_pass_major() {
        let s = settings(40, 24, 16, 7, 3);
        let l = TaskLayout::new(&s);
        assert_eq!((l.tile_count(), l.pass_count()), (6, 3));
        let mut seen = std::collections::HashSet::new();
        let mut samples = vec![0u32; l.tile_count()];
        for i in 0..l.task_count() {
            let w = l.task(i).unwrap();
            assert!(l.pass_tasks(w.pass as usize).contains(&i));
            assert_eq!(w.tile, s.tiles()[w.tile_index as usize]);
            assert!(seen.insert((w.tile_index, w.pass)), "task {i} twice");
            // Passes of a tile follow each other without a gap.
            assert_eq!(w.samples.start, samples[w.tile_index as usize]);
            samples[w.tile_index as usize] = w.samples.end;
        }
        assert!(samples.iter().all(|&n| n == 7), "{samples:?}");
        assert_eq!(l.task(l.task_count()), None);
    }
}
