//! Integrators: how the radiance arriving along a camera ray is estimated, and the tile loop.
//!
//! - [`path`]: unidirectional path tracing with next-event estimation and multiple importance
//!   sampling (power heuristic), Russian roulette and a maximum depth: an unbiased estimator of
//!   Kajiya's rendering equation.
//! - [`whitted`]: the recursive ray tracer: shadow rays to every light, recursive mirror
//!   reflection and refraction, stopped at max depth, at no hit, or when the ray's contribution
//!   falls below a threshold.
//! - [`debug`]: normals, albedo, depth and ambient occlusion.
//!
//! Both path and Whitted take their direct lighting from `direct.rs`.
//!
//! Every integrator reads the [`Scene`] (geometry, materials, lights) and the [`RenderJob`]
//! (camera, environment, light selection, settings). [`render_tile`] evaluates samples
//! `[s0, s1)` of every pixel of a tile. Each pixel's sum is accumulated sample by sample in
//! index order from zero, with random numbers that depend only on (pixel, sample index, seed):
//! the result cannot depend on the tile layout or the thread.

pub mod debug;
mod direct;
pub mod path;
pub mod whitted;

use crate::geometry::Ray;
use crate::sampling::Sampler;
use crate::{Film, IntegratorKind, RenderJob, Scene, Tile, TileAccum};
use glam::{Vec2, Vec3A};
use rayon::prelude::*;
use std::ops::Range;

/// Progress reports during [`render`].
pub trait RenderProgress: Sync {
    /// Called after each finished tile with the number of samples it took.
    fn tile_done(&self, samples: u64);
}

impl RenderProgress for () {
    fn tile_done(&self, _samples: u64) {}
}

/// Radiance estimate for one camera ray with the selected integrator.
#[inline]
fn li(scene: &Scene, job: &RenderJob, ray: Ray, sampler: &mut Sampler) -> Vec3A {
    let max_depth = job.settings.max_depth;
    match job.settings.integrator {
        IntegratorKind::Path => path::li(scene, job, ray, sampler, max_depth),
        IntegratorKind::Whitted => whitted::li(scene, job, ray, sampler, max_depth),
        k => debug::li(scene, job, ray, sampler, k),
    }
}

/// Renders samples `samples` of every pixel of `tile` of `job`, in parallel over rows.
pub fn render_tile(scene: &Scene, job: &RenderJob, tile: Tile, samples: Range<u32>) -> TileAccum {
    let seed = job.settings.seed;
    let w = tile.width() as usize;
    let mut pixels = vec![[0.0f32; 4]; tile.pixel_count()];
    let bad: u64 = pixels
        .par_chunks_mut(w.max(1))
        .enumerate()
        .map(|(row, out)| {
            let y = tile.y0 + row as u32;
            let mut bad = 0u64;
            for (col, px) in out.iter_mut().enumerate() {
                let x = tile.x0 + col as u32;
                let mut sum = [0.0f32; 4];
                for s in samples.clone() {
                    let mut sampler = Sampler::new(x, y, s, seed);
                    let offset = job.filter.sample(sampler.next_2d());
                    let lens = sampler.next_2d();
                    let film = Vec2::new(x as f32 + 0.5 + offset.x, y as f32 + 0.5 + offset.y);
                    let ray = job.camera.generate_ray(film, lens);
                    let l = li(scene, job, ray, &mut sampler);
                    if l.is_finite() {
                        sum[0] += l.x;
                        sum[1] += l.y;
                        sum[2] += l.z;
                        sum[3] += 1.0;
                    } else {
                        bad += 1;
                    }
                }
                *px = sum;
            }
            bad
        })
        .sum();
    TileAccum {
        tile,
        pixels,
        bad_samples: bad,
    }
}

/// Renders the whole frame of `job` on the current rayon pool, pass by pass: every tile of
/// pass 0, then every tile of pass 1, and so on; each pass's tile sums are added into the film
/// in pass order.
pub fn render(scene: &Scene, job: &RenderJob, progress: &dyn RenderProgress) -> Film {
    let settings = &job.settings;
    let mut film = Film::new(settings.width, settings.height);
    let tiles = settings.tiles();
    for pass in settings.pass_ranges() {
        let n = (pass.end - pass.start) as u64;
        let accums: Vec<TileAccum> = tiles
            .par_iter()
            .map(|&t| {
                let a = render_tile(scene, job, t, pass.clone());
                progress.tile_done(n * t.pixel_count() as u64);
                a
            })
            .collect();
        for a in &accums {
            film.add_tile(a);
        }
    }
    film
}
