//! Integrators: how the radiance arriving along a camera ray is estimated, and the tile loop.
//!
//! - [`path`]: unidirectional path tracing with next-event estimation and multiple importance
//!   sampling (power heuristic), Russian roulette and a maximum depth: an unbiased estimator of
//!   Kajiya's rendering equation.
//! - [`volpath`]: path tracing with participating media (fog, smoke): delta tracking with
//!   majorant grids, ratio-tracked shadow rays, null-scattering MIS for chromatic media.
//! - [`bdpt`]: bidirectional path tracing (pbrt-v4's): light and camera subpaths joined by
//!   every strategy, MIS-weighted; light subpaths joined to the camera land in other pixels
//!   as fixed-point splats ([`TileAccum::splats`]), added in any order to the same bits.
//! - [`sppm`]: stochastic progressive photon mapping: per iteration a visible point per pixel
//!   and a whole-frame photon pass (kept in the job's cache for its other tiles); consistent,
//!   renders caustics of point lights. A tile runs every iteration of its pixels.
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

pub mod bdpt;
pub mod debug;
mod direct;
pub mod path;
pub mod sppm;
pub mod volpath;
pub mod whitted;

use crate::geometry::Ray;
use crate::sampling::Sampler;
use crate::{Film, IntegratorKind, RenderJob, Scene, Tile, TileAccum};
use glam::{Vec2, Vec3A};
use rayon::prelude::*;
use std::ops::Range;
use std::sync::atomic::{AtomicBool, Ordering};

/// Progress reports during [`render`].
pub trait RenderProgress: Sync {
    /// Called after each finished tile with the number of samples it took.
    fn tile_done(&self, samples: u64);
}

impl RenderProgress for () {
    fn tile_done(&self, _samples: u64) {}
}

/// What one camera sample brings back.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    /// The radiance (or debug value) along the camera ray.
    pub l: Vec3A,
    /// Whether the camera ray left the scene before any vertex: it met no surface (medium
    /// boundaries, `interface`s, are crossed as if absent) and, in `volpath`, did not scatter
    /// or get absorbed in a medium. Its whole value is then the environment seen straight on.
    /// In a job with an alpha channel ([`crate::RenderSettings::alpha`]) such a sample is
    /// transparent: its value is dropped and it does not count towards the pixel's coverage.
    pub escaped: bool,
}

/// Radiance estimate for one camera ray with the selected integrator.
#[inline]
fn li(scene: &Scene, job: &RenderJob, ray: Ray, sampler: &mut Sampler) -> Estimate {
    let max_depth = job.settings.max_depth;
    match job.settings.integrator {
        IntegratorKind::Path => path::li(scene, job, ray, sampler, max_depth),
        IntegratorKind::Volpath => volpath::li(scene, job, ray, sampler, max_depth),
        IntegratorKind::Whitted => whitted::li(scene, job, ray, sampler, max_depth),
        IntegratorKind::Bdpt => unreachable!("bdpt samples go through bdpt::li"),
        IntegratorKind::Sppm => unreachable!("sppm tiles go through sppm::render_tile"),
        k => debug::li(scene, job, ray, sampler, k),
    }
}

/// A flag that stops a tile render early: another thread (a worker told that the job was
/// cancelled) sets it, and [`render_tile`] looks at it before every block of
/// [`Cancel::CHECK_EVERY`] samples of a pixel, so it returns within a fraction of a second.
/// One relaxed atomic load per check: nothing per ray.
#[derive(Debug, Default)]
pub struct Cancel(AtomicBool);

/// [`render_tile`] stopped because its [`Cancel`] was set; the partial sums are dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("render cancelled")]
pub struct Cancelled;

impl Cancel {
    /// Samples of one pixel between two looks at the flag.
    pub const CHECK_EVERY: u32 = 1024;

    /// A flag not set.
    pub fn new() -> Cancel {
        Cancel::default()
    }

    /// Asks the renders that watch this flag to stop.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }

    /// Whether [`Cancel::cancel`] was called.
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

/// Renders samples `samples` of every pixel of `tile` of `job`, in parallel over rows, or stops
/// with [`Cancelled`] soon after `cancel` is set. A render that was not cancelled gives the same
/// bits whether or not anyone watched the flag.
pub fn render_tile(
    scene: &Scene,
    job: &RenderJob,
    tile: Tile,
    samples: Range<u32>,
    cancel: &Cancel,
) -> Result<TileAccum, Cancelled> {
    if job.settings.integrator == IntegratorKind::Sppm {
        return sppm::render_tile(scene, job, tile, samples, cancel);
    }
    let seed = job.settings.seed;
    let w = tile.width() as usize;
    let mut pixels = vec![[0.0f32; 4]; tile.pixel_count()];
    let alpha = job.settings.alpha;
    let bidirectional = job.settings.integrator == IntegratorKind::Bdpt;
    let rows: Option<Vec<Row>> = pixels
        .par_chunks_mut(w.max(1))
        .enumerate()
        .map(|(row, out)| {
            let y = tile.y0 + row as u32;
            let mut bad = 0u64;
            let mut splats = Vec::new();
            let mut coverage = Vec::with_capacity(if alpha { out.len() } else { 0 });
            for (col, px) in out.iter_mut().enumerate() {
                let x = tile.x0 + col as u32;
                let mut sum = [0.0f32; 4];
                let mut covered = 0.0f32;
                // Blocks of samples, in index order, with a look at the flag before each.
                let mut start = samples.start;
                while start < samples.end {
                    if cancel.is_cancelled() {
                        return None;
                    }
                    let end = start.saturating_add(Cancel::CHECK_EVERY).min(samples.end);
                    for s in start..end {
                        let mut sampler = Sampler::new(x, y, s, seed);
                        let offset = job.filter.sample(sampler.next_2d());
                        let lens = sampler.next_2d();
                        let film = Vec2::new(x as f32 + 0.5 + offset.x, y as f32 + 0.5 + offset.y);
                        let ray = job.camera.generate_ray(film, lens);
                        let e = if bidirectional {
                            let mut light = Sampler::new(x, y, s, seed ^ LIGHT_SUBPATH_SEED);
                            let first = splats.len();
                            let e =
                                bdpt::li(scene, job, ray, &mut sampler, &mut light, &mut splats);
                            if !crate::film::sample_ok(e.l) {
                                // The whole sample is dropped, its splats too.
                                splats.truncate(first);
                            }
                            e
                        } else {
                            li(scene, job, ray, &mut sampler)
                        };
                        // With an alpha channel the environment seen straight on is
                        // transparent: nothing in colour, nothing in coverage.
                        let l = if alpha && e.escaped { Vec3A::ZERO } else { e.l };
                        if crate::film::sample_ok(e.l) {
                            sum[0] += l.x;
                            sum[1] += l.y;
                            sum[2] += l.z;
                            sum[3] += 1.0;
                            if !e.escaped {
                                covered += 1.0;
                            }
                        } else {
                            bad += 1;
                        }
                    }
                    start = end;
                }
                *px = sum;
                if alpha {
                    coverage.push(covered);
                }
            }
            Some(Row {
                bad,
                splats,
                coverage,
            })
        })
        .collect();
    let rows = rows.ok_or(Cancelled)?;
    let bad = rows.iter().map(|r| r.bad).sum();
    let coverage = rows
        .iter()
        .flat_map(|r| r.coverage.iter().copied())
        .collect();
    let splats = if bidirectional {
        bdpt::coalesce(rows.into_iter().flat_map(|r| r.splats).collect())
    } else {
        Vec::new()
    };
    Ok(TileAccum {
        tile,
        pixels,
        bad_samples: bad,
        splats,
        coverage,
    })
}

/// What one row of a tile gives besides its pixels' sums.
struct Row {
    /// Samples dropped (NaN, infinite or too large).
    bad: u64,
    /// `bdpt`'s splats.
    splats: Vec<bdpt::RawSplat>,
    /// The row's coverage, for a job with an alpha channel; empty otherwise.
    coverage: Vec<f32>,
}

/// Mixed into the seed of the sampler of a sample's light subpath (`bdpt`), so that it draws
/// numbers of its own from the same (pixel, sample index, seed).
const LIGHT_SUBPATH_SEED: u32 = 0x5bd1_e995;

/// Renders the whole frame of `job` on the current rayon pool, pass by pass: every tile of
/// pass 0, then every tile of pass 1, and so on, passes added into the film in pass order.
///
/// Within a pass each tile is added as soon as it is done, in whatever order the tiles end:
/// the pass's tiles cover each pixel once (each pixel's sum is the previous passes' plus its
/// tile's, whatever the order), and splats, dropped samples and sample counts are integers
/// (counts below 2^53 in the f64 of [`Film::samples`]), so the bits are the same. Only the
/// tiles being rendered are held, not the whole pass's results (with `bdpt`'s splats, up to a
/// frame's worth each).
pub fn render(scene: &Scene, job: &RenderJob, progress: &dyn RenderProgress) -> Film {
    let settings = &job.settings;
    let film = std::sync::Mutex::new(Film::with_alpha(
        settings.width,
        settings.height,
        settings.alpha,
    ));
    let tiles = settings.tiles();
    let never = Cancel::new();
    for pass in settings.pass_ranges() {
        let n = (pass.end - pass.start) as u64;
        let one = |&t: &Tile| {
            let a = render_tile(scene, job, t, pass.clone(), &never)
                .expect("nobody cancels this render");
            progress.tile_done(n * t.pixel_count() as u64);
            film.lock()
                .unwrap_or_else(|e| e.into_inner())
                .add_tile(&a)
                .expect("render_tile gives every tile of the frame its own pixels");
        };
        // sppm's tiles share the job's photon maps: one tile at a time (each parallel inside)
        // traces each map once rather than once per tile that asks for it at the same time.
        if settings.integrator == IntegratorKind::Sppm {
            tiles.iter().for_each(one);
        } else {
            tiles.par_iter().for_each(one);
        }
    }
    film.into_inner().unwrap_or_else(|e| e.into_inner())
}
