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
//! [`render_tile`] evaluates samples `[s0, s1)` of every pixel of a tile. Each pixel's sum is
//! accumulated sample by sample in index order from zero, with random numbers that depend only
//! on (pixel, sample index, seed): the result cannot depend on the tile layout or the thread.

pub mod debug;
pub mod path;
pub mod whitted;

use crate::film::FilterSampler;
use crate::geometry::{offset_ray_origin, Ray};
use crate::sampling::Sampler;
use crate::scene::build::Interaction;
use crate::{Film, IntegratorKind, RenderSettings, Scene, Tile, TileAccum};
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

/// A ray leaving surface point `it` in direction `d`, offset so it cannot re-hit the surface.
#[inline]
pub(crate) fn spawn_ray(it: &Interaction, d: Vec3A) -> Ray {
    Ray::new(offset_ray_origin(it.p, it.ng, d), d)
}

/// A shadow ray from `it` to the point `target`: (ray, tmax), stopping just short of the target.
#[inline]
pub(crate) fn spawn_ray_to(it: &Interaction, target: Vec3A, target_n: Vec3A) -> (Ray, f32) {
    let d0 = target - it.p;
    let o = offset_ray_origin(it.p, it.ng, d0);
    let t = if target_n == Vec3A::ZERO {
        target
    } else {
        offset_ray_origin(target, target_n, o - target)
    };
    let d = t - o;
    let len = d.length();
    (Ray::new(o, d / len), len * (1.0 - 1e-4))
}

/// The power heuristic (β = 2) weight of a strategy with density `f` against one with `g`.
#[inline]
pub(crate) fn power_heuristic(f: f32, g: f32) -> f32 {
    let (f2, g2) = (f * f, g * g);
    if f2.is_infinite() {
        return 1.0;
    }
    if f2 + g2 <= 0.0 {
        0.0
    } else {
        f2 / (f2 + g2)
    }
}

/// Radiance estimate for one camera ray with the selected integrator.
#[inline]
fn li(scene: &Scene, settings: &RenderSettings, ray: Ray, sampler: &mut Sampler) -> Vec3A {
    match settings.integrator {
        IntegratorKind::Path => path::li(scene, ray, sampler, settings.max_depth),
        IntegratorKind::Whitted => whitted::li(scene, ray, sampler, settings.max_depth),
        k => debug::li(scene, ray, sampler, k),
    }
}

/// Renders samples `samples` of every pixel of `tile`, in parallel over rows.
pub fn render_tile(
    scene: &Scene,
    settings: &RenderSettings,
    tile: Tile,
    samples: Range<u32>,
) -> TileAccum {
    let filter = FilterSampler::new(settings.filter);
    render_tile_with(scene, settings, &filter, tile, samples)
}

fn render_tile_with(
    scene: &Scene,
    settings: &RenderSettings,
    filter: &FilterSampler,
    tile: Tile,
    samples: Range<u32>,
) -> TileAccum {
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
                    let mut sampler = Sampler::new(x, y, s, settings.seed);
                    let offset = filter.sample(sampler.next_2d());
                    let lens = sampler.next_2d();
                    let film = Vec2::new(x as f32 + 0.5 + offset.x, y as f32 + 0.5 + offset.y);
                    let ray = scene.camera.generate_ray(film, lens);
                    let l = li(scene, settings, ray, &mut sampler);
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

/// Renders the whole frame on the current rayon pool, pass by pass: every tile of pass 0, then
/// every tile of pass 1, and so on; each pass's tile sums are added into the film in pass order.
pub fn render(scene: &Scene, settings: &RenderSettings, progress: &dyn RenderProgress) -> Film {
    let filter = FilterSampler::new(settings.filter);
    let mut film = Film::new(settings.width, settings.height);
    let tiles = settings.tiles();
    for pass in settings.pass_ranges() {
        let n = (pass.end - pass.start) as u64;
        let accums: Vec<TileAccum> = tiles
            .par_iter()
            .map(|&t| {
                let a = render_tile_with(scene, settings, &filter, t, pass.clone());
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
