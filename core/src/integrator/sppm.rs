//! Stochastic progressive photon mapping (Hachisuka and Jensen 2009, as pbrt-v4's
//! `SPPMIntegrator`): each iteration finds one visible point per pixel (the first surface
//! whose BSDF is neither a delta nor near-specular, `Bsdf::is_near_specular`, following
//! mirrors, glass and smooth metal on the way), traces a
//! photon pass from the lights, and updates each pixel's photon count N, search radius r and
//! flux τ from the photons within r of its visible point (α = 2/3):
//! N' = N + αM, r' = r √(N'/(N + M)), τ' = (τ + β Φ) r'²/r². After n iterations of P photons
//! the pixel is L = τ / (n P π r²) + (direct light and emission seen on the way) / n.
//! Consistent (the radius shrinks to zero), not unbiased. `max_depth` bounds the whole path
//! as for every other integrator: a visible point reached through k mirror or glass bounces
//! gathers only photons of fewer than `max_depth` − k bounces (pbrt-v4 bounds the camera and
//! the photon paths each on its own, so its low-depth images are brighter behind glass).
//!
//! Deterministic and cut into tiles freely: a tile task runs every iteration for its pixels,
//! keeping their (N, r, τ) in memory, so a pixel depends only on itself and on the photon maps.
//! The photon map of iteration i holds photon k's deposits, traced with random numbers from
//! (k, i, seed) alone, in photon order; lookups visit them in a fixed order. A job's maps are
//! kept in its [`RenderJob`]'s cache for its other tiles (bounded; a map not kept is traced
//! again, to the same bits). ARCHITECTURE.md, "Photon maps on the farm", says what this costs.
//!
//! Participating media are not rendered (as `path`); light transport on photon paths uses the
//! adjoint BSDF, as `bdpt`'s light subpaths.

use super::bdpt::{adjoint_f, sample_emission, scene_sphere};
use super::direct::{light_contribution, Counted};
use super::Cancelled;
use crate::light::range_window;
use crate::material::Bsdf;
use crate::sampling::detmath::exp3;
use crate::sampling::warp::Frame;
use crate::sampling::{hash_u32, Sampler};
use crate::{RenderJob, Scene, Tile, TileAccum};
use glam::{Vec2, Vec3, Vec3A};
use rayon::prelude::*;
use std::ops::Range;
use std::sync::Arc;

/// The fraction of new photons kept in a pixel's count per iteration.
pub const ALPHA: f32 = 2.0 / 3.0;

/// Initial search radius in pixel widths, where the camera's rays first meet the scene (see
/// [`initial_radius`]).
pub const INITIAL_RADIUS_PIXELS: f32 = 2.0;

/// Mixed into the seed of photon samplers, so that photon k of iteration i draws numbers of its
/// own, not those of pixel (k, 0)'s sample i.
const PHOTON_SEED: u32 = 0x9e37_79b9;

/// Photons traced per parallel work item at a `max_depth` of 16 or less (collected in photon
/// order whatever the threads); deeper paths take proportionally fewer, down to 64
/// ([`chunk_photons`]), so a work item holds at most about 2¹⁶ deposits.
const PHOTON_CHUNK: u32 = 4096;

/// Deposits one photon map holds (40 bytes each): an iteration whose photons leave more
/// is gathered from several maps, one after the other, each of whole chunks of photons in
/// photon order (a chunk that alone leaves more is a map of its own). So an iteration's memory
/// is bounded whatever the image size and path depth (a closed room of white walls at a depth
/// of 1024 leaves about a thousand deposits per photon).
pub const MAP_DEPOSITS: usize = 1 << 22;

/// The initial search radius of every pixel of `job`: tile-independent, and the largest radius
/// any lookup uses (radii only shrink), hence the photon grid's cell size.
///
/// [`INITIAL_RADIUS_PIXELS`] times the median width of a pixel where the camera's rays through
/// a grid of 16 × 16 pixels first meet a surface (passing media boundaries): what the camera
/// sees sets it, not the extent of the scene, which a floor kilometres wide or a far-off object
/// would stretch until every caustic blurred away. A camera that sees nothing falls back to
/// the scene's extent (its bounding-sphere diameter over the image's longer edge).
pub fn initial_radius(scene: &Scene, job: &RenderJob) -> f32 {
    const GRID: u32 = 16;
    let (w, h) = (job.settings.width.max(1), job.settings.height.max(1));
    let (nx, ny) = (GRID.min(w), GRID.min(h));
    let lens = Vec2::splat(0.5);
    let mut widths = Vec::with_capacity((nx * ny) as usize);
    for j in 0..ny {
        for i in 0..nx {
            let x = ((i as f32 + 0.5) * w as f32 / nx as f32).floor() + 0.5;
            let y = ((j as f32 + 0.5) * h as f32 / ny as f32).floor() + 0.5;
            let first = job.camera.generate_ray(Vec2::new(x, y), lens);
            let beside = job.camera.generate_ray(Vec2::new(x + 1.0, y), lens);
            let mut ray = first;
            for _ in 0..16 {
                let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
                    break;
                };
                if !scene.is_interface(hit.object) {
                    let t = (ray.at(hit.t) - first.o).length();
                    let width = (beside.at(t) - first.at(t)).length();
                    if width.is_finite() && width > 0.0 {
                        widths.push(width);
                    }
                    break;
                }
                ray = scene.interaction(&ray, &hit).spawn_ray(ray.d);
            }
        }
    }
    if widths.is_empty() {
        let edge = w.max(h) as f32;
        return INITIAL_RADIUS_PIXELS * 2.0 * scene_sphere(scene).1 / edge;
    }
    let middle = widths.len() / 2;
    let (_, median, _) = widths.select_nth_unstable_by(middle, f32::total_cmp);
    INITIAL_RADIUS_PIXELS * *median
}

/// Photons per iteration: one per pixel, as pbrt's default.
pub fn photons_per_iteration(job: &RenderJob) -> u32 {
    job.settings
        .width
        .saturating_mul(job.settings.height)
        .max(1)
}

/// One photon's deposit: where it landed, the direction it came from, its power, and the
/// bounces its path took before it (at least 1: direct light is the camera pass's).
#[derive(Clone, Copy, Debug)]
struct Photon {
    p: Vec3,
    wi: Vec3,
    beta: Vec3,
    depth: u32,
}

/// The photons of one iteration in a hashed uniform grid whose cells are as large as the
/// largest search radius: a lookup visits the buckets of the 27 cells around the point, each
/// bucket once, in increasing bucket order, and each bucket's photons in photon order.
#[derive(Debug)]
pub struct PhotonMap {
    photons: Vec<Photon>,
    /// `photons[start[b]..start[b + 1]]` are the photons of bucket b.
    start: Vec<u32>,
    inv_cell: f32,
    /// Photon paths traced (for the measurement of repeated work).
    pub traced: u32,
    /// The chunks of the iteration's photons whose deposits this map holds
    /// ([`chunk_photons`] photons each): the next map of the iteration starts at `chunks.end`.
    pub chunks: Range<u32>,
}

impl PhotonMap {
    fn cell(&self, p: Vec3A) -> [i32; 3] {
        let c = (p * self.inv_cell).floor();
        [c.x as i32, c.y as i32, c.z as i32]
    }

    fn bucket(&self, c: [i32; 3]) -> usize {
        let h = hash_u32(
            (c[0] as u32).wrapping_mul(73_856_093)
                ^ (c[1] as u32).wrapping_mul(19_349_663)
                ^ (c[2] as u32).wrapping_mul(83_492_791),
        );
        (h as usize) & (self.start.len() - 2)
    }

    /// Builds the grid over `photons` (in photon order), for lookups of radius ≤ `cell`.
    fn build(photons: Vec<Photon>, cell: f32, traced: u32, chunks: Range<u32>) -> PhotonMap {
        let buckets = photons.len().next_power_of_two().max(1);
        let mut map = PhotonMap {
            photons: Vec::new(),
            start: vec![0; buckets + 1],
            inv_cell: 1.0 / cell,
            traced,
            chunks,
        };
        let keys: Vec<u32> = photons
            .iter()
            .map(|ph| map.bucket(map.cell(Vec3A::from(ph.p))) as u32)
            .collect();
        for &k in &keys {
            map.start[k as usize + 1] += 1;
        }
        for b in 0..buckets {
            map.start[b + 1] += map.start[b];
        }
        // A stable counting sort: photon order within each bucket.
        let mut next: Vec<u32> = map.start[..buckets].to_vec();
        let mut sorted = photons.clone();
        for (ph, &k) in photons.iter().zip(&keys) {
            sorted[next[k as usize] as usize] = *ph;
            next[k as usize] += 1;
        }
        map.photons = sorted;
        map
    }

    /// Calls `f` with every photon within `r` of `p` (r ≤ the cell size), in a fixed order.
    fn for_each_near(&self, p: Vec3A, r: f32, mut f: impl FnMut(&Photon)) {
        if self.photons.is_empty() {
            return;
        }
        let c = self.cell(p);
        let mut buckets = [0usize; 27];
        let mut n = 0;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    buckets[n] = self.bucket([
                        c[0].wrapping_add(dx),
                        c[1].wrapping_add(dy),
                        c[2].wrapping_add(dz),
                    ]);
                    n += 1;
                }
            }
        }
        buckets.sort_unstable();
        let r2 = r * r;
        let mut last = usize::MAX;
        for &b in &buckets {
            if b == last {
                continue;
            }
            last = b;
            let range = self.start[b] as usize..self.start[b + 1] as usize;
            for ph in &self.photons[range] {
                if (Vec3A::from(ph.p) - p).length_squared() <= r2 {
                    f(ph);
                }
            }
        }
    }

    fn memory_bytes(&self) -> usize {
        self.photons.len() * std::mem::size_of::<Photon>() + self.start.len() * 4 + 64
    }
}

/// Photons per parallel work item of `job`'s photon passes: [`PHOTON_CHUNK`] up to a
/// `max_depth` of 16, fewer for deeper paths, at least 64.
pub fn chunk_photons(job: &RenderJob) -> u32 {
    (PHOTON_CHUNK * 16 / job.settings.max_depth.max(16)).max(64)
}

/// The photon maps of iteration `it` of `job`, one after another, each handed to `f`: together
/// they hold the deposits of the iteration's photons, in photon order, each at most `cap` of
/// them (renders use [`MAP_DEPOSITS`]); usually one map. Stops at the first error `f` returns.
pub fn for_each_photon_map<E>(
    scene: &Scene,
    job: &RenderJob,
    it: u32,
    cap: usize,
    mut f: impl FnMut(&PhotonMap) -> Result<(), E>,
) -> Result<(), E> {
    let chunks = photons_per_iteration(job).div_ceil(chunk_photons(job));
    let mut start = 0;
    while start < chunks {
        let map = photon_map(scene, job, it, start, cap);
        f(&map)?;
        start = map.chunks.end;
    }
    Ok(())
}

/// The photon map of iteration `it` of `job` that starts at chunk `start` and holds at most
/// `cap` deposits (but for a chunk that alone leaves more): from the job's cache, or traced
/// (and kept if the cache has room).
pub fn photon_map(
    scene: &Scene,
    job: &RenderJob,
    it: u32,
    start: u32,
    cap: usize,
) -> Arc<PhotonMap> {
    // The key names the integrator and the settings the map depends on besides the job.
    let s = &job.settings;
    let key = (0x5350_504d_u64 << 32 | it as u64)
        ^ ((hash_u32(s.seed ^ hash_u32(s.max_depth ^ hash_u32(s.width ^ s.height << 16))) as u64)
            << 20)
        ^ ((hash_u32(start ^ hash_u32(cap as u32 ^ 0x6368_756e)) as u64) << 32);
    if let Some(m) = job.cache.get::<PhotonMap>(key) {
        return m;
    }
    let m = Arc::new(trace_photons(scene, job, it, start, cap));
    job.cache.insert(key, m.clone(), m.memory_bytes());
    m
}

/// Traces the photons of iteration `it` from chunk `start` on, in parallel batches, and gathers
/// their deposits in photon order, up to the last whole chunk that keeps them within `cap`
/// (at least one chunk). A batch's chunks past that are dropped: the next map traces them
/// again. Which chunks a map takes depends on their deposits alone, never on the batch.
fn trace_photons(scene: &Scene, job: &RenderJob, it: u32, start: u32, cap: usize) -> PhotonMap {
    let n = photons_per_iteration(job);
    let per = chunk_photons(job);
    let chunks = n.div_ceil(per);
    // Two chunks per thread in flight: each leaves at most about 2¹⁶ deposits (2.6 MB), so a
    // batch adds some 5 MB per thread to the map, and a map's end wastes less than a batch.
    let batch = (rayon::current_num_threads() as u32)
        .saturating_mul(2)
        .max(2);
    let sphere = scene_sphere(scene);
    let mut photons: Vec<Photon> = Vec::new();
    let mut end = start;
    'batches: while end < chunks {
        let traced: Vec<Vec<Photon>> = (end..end.saturating_add(batch).min(chunks))
            .into_par_iter()
            .map(|c| {
                let mut out = Vec::new();
                for k in c * per..((c + 1) * per).min(n) {
                    trace_photon(scene, job, sphere, k, it, &mut out);
                }
                out
            })
            .collect();
        for chunk in traced {
            if end > start && photons.len() + chunk.len() > cap {
                break 'batches;
            }
            photons.extend(chunk);
            end += 1;
        }
    }
    let traced = (end * per).min(n) - start * per;
    PhotonMap::build(photons, initial_radius(scene, job), traced, start..end)
}

/// Photon `k` of iteration `it`: from a light chosen by power, scattered with the adjoint BSDF,
/// deposited at every surface with a non-delta BSDF after the first (direct light is the
/// camera pass's), until `max_depth` bounces or Russian roulette.
fn trace_photon(
    scene: &Scene,
    job: &RenderJob,
    sphere: (Vec3A, f32),
    k: u32,
    it: u32,
    out: &mut Vec<Photon>,
) {
    let mut sampler = Sampler::new(k, 0, it, job.settings.seed ^ PHOTON_SEED);
    let Some(e) = sample_emission(scene, job, sphere, &mut sampler) else {
        return;
    };
    let mut beta = e.beta();
    let mut ray = e.ray();
    let max_depth = job.settings.max_depth;
    let mut depth = 0u32;
    let mut travelled = 0.0f32;
    let mut bodies = job.starts.light(scene, e.index);
    while depth < max_depth {
        let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
            return;
        };
        let si = scene.interaction(&ray, &hit);
        if scene.absorbs {
            let sigma = bodies.arrive(scene, &si, ray.d, false);
            if sigma != Vec3A::ZERO {
                beta *= exp3(-sigma * hit.t);
            }
        }
        if scene.is_interface(si.object) {
            travelled += hit.t;
            ray = si.spawn_ray(ray.d);
            continue;
        }
        if depth == 0 && e.range.is_finite() {
            beta *= range_window(travelled + hit.t, e.range);
        }
        let bsdf = scene.bsdf(&si);
        let wo_w = -ray.d;
        // Photons are gathered only where camera paths stop: not on delta or near-specular
        // surfaces.
        if depth > 0 && !bsdf.is_near_specular() && beta.is_finite() && beta != Vec3A::ZERO {
            out.push(Photon {
                p: si.p.into(),
                wi: wo_w.into(),
                beta: beta.into(),
                depth,
            });
        }
        depth += 1;
        let frame = si.shading_frame();
        let wo = frame.to_local(wo_w);
        sampler.align4();
        let [u_lobe, u_rr, _] = sampler.hashed_3();
        let u_dir = sampler.next_2d();
        let Some(bs) = bsdf.sample(wo, u_lobe, u_dir) else {
            return;
        };
        if !(bs.pdf > 0.0) {
            return;
        }
        let wi_w = frame.to_world(bs.wi).normalize();
        let f = adjoint_f(&bsdf, &si, wo, wo_w, wi_w, &bs);
        let next = beta * f * (bs.wi.z.abs() / bs.pdf);
        if !next.is_finite() || next.max_element() <= 0.0 {
            return;
        }
        // Russian roulette on the change of throughput (pbrt's rule for photons).
        let q = (1.0 - next.max_element() / beta.max_element()).max(0.0);
        if u_rr < q {
            return;
        }
        beta = next / (1.0 - q);
        if scene.absorbs {
            bodies.leave(scene, &si, wi_w);
        }
        ray = si.spawn_ray(wi_w);
    }
}

/// Where a camera ray of one iteration came to rest.
struct VisiblePoint {
    p: Vec3A,
    wo: Vec3A,
    frame: Frame,
    bsdf: Bsdf,
    beta: Vec3A,
    /// The bounces (mirrors, glass, near-specular surfaces) the camera ray took to reach it.
    depth: u32,
}

/// The camera path of one pixel's iteration: emission seen directly or through delta and
/// near-specular BSDFs ([`Bsdf::is_near_specular`]), the light of point, spot and
/// directional lights on the near-specular surfaces passed (a light sample there that counts
/// only those, which no ray can find),
/// direct light at the visible point (one light as `path` chooses it, no MIS: emitters found past the
/// visible point are the photons' part), the visible point itself, and whether the camera ray
/// left the scene without meeting a surface ([`super::Estimate::escaped`]).
fn camera_pass(
    scene: &Scene,
    job: &RenderJob,
    x: u32,
    y: u32,
    it: u32,
) -> (Vec3A, Option<VisiblePoint>, bool) {
    let mut sampler = Sampler::new(x, y, it, job.settings.seed);
    let offset = job.filter.sample(sampler.next_2d());
    let lens = sampler.next_2d();
    let film = Vec2::new(x as f32 + 0.5 + offset.x, y as f32 + 0.5 + offset.y);
    let mut ray = job.camera.generate_ray(film, lens);
    let mut l = Vec3A::ZERO;
    let mut beta = Vec3A::ONE;
    let max_depth = job.settings.max_depth;
    let mut depth = 0u32;
    let mut bodies = job.starts.camera();
    loop {
        let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
            if let Some(env) = job.environment() {
                l += beta * env.radiance(ray.d) * bodies.escape(scene, false);
            }
            return (l, None, depth == 0);
        };
        let si = scene.interaction(&ray, &hit);
        let wo_w = -ray.d;
        if scene.absorbs {
            let sigma = bodies.arrive(scene, &si, ray.d, false);
            if sigma != Vec3A::ZERO {
                beta *= exp3(-sigma * hit.t);
            }
        }
        if scene.is_interface(si.object) {
            ray = si.spawn_ray(ray.d);
            continue;
        }
        l += beta * scene.emitted(&si, wo_w);
        if depth >= max_depth {
            return (l, None, false);
        }
        let bsdf = scene.bsdf(&si);
        let frame = si.shading_frame();
        let wo = frame.to_local(wo_w);
        sampler.align4();
        let [u_fine, u_lobe, _] = sampler.hashed_3();
        let u_ld = sampler.next_2d();
        let u_dir = sampler.next_2d();
        // Through delta and near-specular surfaces (mirrors, glass, smooth metal) the camera
        // path goes on, sampling the BSDF: gathering there would need photons that line up
        // with the view, which almost never come. A near-specular surface still takes the
        // lights no ray can find (a point light's glint on smooth metal) from a light sample;
        // the path finds the others.
        let stop = !bsdf.is_near_specular();
        let chosen = if stop {
            job.lights()
                .choose_in(u_ld, u_fine)
                .map(|(index, pmf, u)| (index, pmf, u, Counted::Full))
        } else if !bsdf.is_delta() {
            // Among the delta lights alone (their samples need no numbers).
            job.lights()
                .choose_delta(u_ld.x, u_fine)
                .map(|(index, pmf)| (index, pmf, u_ld, Counted::DeltaOnly))
        } else {
            None
        };
        if let Some((index, pmf, u, counted)) = chosen {
            let ld = light_contribution(
                scene, job, &si, &bsdf, &frame, wo, &bodies, index, u, counted,
            );
            l += beta * ld / pmf;
        }
        if stop {
            let vp = VisiblePoint {
                p: si.p,
                wo,
                frame,
                bsdf,
                beta,
                depth,
            };
            return (l, Some(vp), false);
        }
        let Some(bs) = bsdf.sample(wo, u_lobe, u_dir) else {
            return (l, None, false);
        };
        if !(bs.pdf > 0.0) {
            return (l, None, false);
        }
        beta *= bs.f * (bs.wi.z.abs() / bs.pdf);
        if !beta.is_finite() || beta == Vec3A::ZERO {
            return (l, None, false);
        }
        let wi_w = frame.to_world(bs.wi).normalize();
        if scene.absorbs {
            bodies.leave(scene, &si, wi_w);
        }
        ray = si.spawn_ray(wi_w);
        depth += 1;
    }
}

/// A pixel's state across iterations.
#[derive(Clone, Copy)]
struct PixelState {
    /// Direct light and emission, summed over iterations.
    ld: Vec3A,
    /// Photon count N (fractional).
    n: f32,
    /// Search radius.
    r: f32,
    /// Flux τ.
    tau: Vec3A,
    /// Iterations dropped for a value that was not finite.
    bad: u32,
    /// Good iterations whose camera ray met a surface (the pixel's coverage).
    covered: f32,
}

/// Runs iterations `iterations` (the job's samples; every one of them: sppm is one pass) for
/// every pixel of `tile`; the tile's pixels are (L × n, n) for n good iterations, so the film's
/// division by the weight gives L. Looks at `cancel` before each iteration.
pub fn render_tile(
    scene: &Scene,
    job: &RenderJob,
    tile: Tile,
    iterations: Range<u32>,
    cancel: &super::Cancel,
) -> Result<TileAccum, Cancelled> {
    render_tile_with(scene, job, tile, iterations, cancel, MAP_DEPOSITS)
}

/// [`render_tile`] with photon maps of at most `cap` deposits.
fn render_tile_with(
    scene: &Scene,
    job: &RenderJob,
    tile: Tile,
    iterations: Range<u32>,
    cancel: &super::Cancel,
    cap: usize,
) -> Result<TileAccum, Cancelled> {
    let w = tile.width() as usize;
    let r0 = initial_radius(scene, job);
    let mut state = vec![
        PixelState {
            ld: Vec3A::ZERO,
            n: 0.0,
            r: r0,
            tau: Vec3A::ZERO,
            bad: 0,
            covered: 0.0,
        };
        tile.pixel_count()
    ];
    let mut gathered = vec![Gathered::default(); tile.pixel_count()];
    let mut photons_total = 0.0f64;
    for it in iterations.clone() {
        if cancel.is_cancelled() {
            return Err(Cancelled);
        }
        let mut first = true;
        for_each_photon_map(scene, job, it, cap, |map| {
            if !first && cancel.is_cancelled() {
                return Err(Cancelled);
            }
            photons_total += map.traced as f64;
            state
                .par_chunks_mut(w.max(1))
                .zip(gathered.par_chunks_mut(w.max(1)))
                .enumerate()
                .for_each(|(row, (px, g))| {
                    let y = tile.y0 + row as u32;
                    for (col, (st, g)) in px.iter_mut().zip(g).enumerate() {
                        let x = tile.x0 + col as u32;
                        gather(scene, job, map, x, y, it, first, st, g);
                    }
                });
            first = false;
            Ok(())
        })?;
        state.par_iter_mut().zip(&mut gathered).for_each(|(st, g)| {
            update_pixel(st, g);
            *g = Gathered::default();
        });
    }
    let mut bad = 0u64;
    let alpha = job.settings.alpha;
    let mut coverage = Vec::with_capacity(if alpha { state.len() } else { 0 });
    let pixels = state
        .iter()
        .map(|st| {
            // A pixel dropped whole below covers nothing.
            if alpha {
                coverage.push(0.0);
            }
            bad += st.bad as u64;
            let good = (iterations.len() as u32 - st.bad) as f32;
            if good == 0.0 {
                return [0.0; 4];
            }
            // Weight `good` to the film, which divides by it.
            let area = (photons_total * std::f64::consts::PI * (st.r as f64).powi(2)) as f32;
            let indirect = if area > 0.0 {
                st.tau * (good / area)
            } else {
                Vec3A::ZERO
            };
            let l = st.ld + indirect;
            // `l` is the sum of `good` iterations' estimates.
            if !crate::film::sample_ok(l / good) {
                bad += good as u64;
                return [0.0; 4];
            }
            if let Some(c) = coverage.last_mut() {
                *c = st.covered;
            }
            [l.x, l.y, l.z, good]
        })
        .collect();
    Ok(TileAccum {
        tile,
        pixels,
        bad_samples: bad,
        splats: Vec::new(),
        coverage,
    })
}

/// What one iteration of one pixel gathered from the photon maps so far.
#[derive(Clone, Copy, Default)]
struct Gathered {
    /// Photons found (M).
    m: u32,
    /// Their flux at the visible point (Φ, before the path throughput).
    phi: Vec3A,
    /// The path throughput to the visible point.
    beta: Vec3A,
    /// Whether the camera pass found a visible point and a finite direct-light estimate.
    gathers: bool,
}

/// One iteration of one pixel, with one of its photon maps: its camera pass (its direct light
/// counted with the `first` map), then the photons of `map` near its visible point. A camera
/// pass depends only on (pixel, iteration, seed), so an iteration of several maps runs it again
/// for each, to the same point, rather than keeping every pixel's visible point.
#[allow(clippy::too_many_arguments)]
fn gather(
    scene: &Scene,
    job: &RenderJob,
    map: &PhotonMap,
    x: u32,
    y: u32,
    it: u32,
    first: bool,
    st: &mut PixelState,
    g: &mut Gathered,
) {
    if !first && !g.gathers {
        return;
    }
    let (ld, vp, escaped) = camera_pass(scene, job, x, y, it);
    if first {
        if !crate::film::sample_ok(ld) {
            st.bad += 1;
            return;
        }
        // With an alpha channel the environment seen straight on is transparent.
        if !(escaped && job.settings.alpha) {
            st.ld += ld;
        }
        if !escaped {
            st.covered += 1.0;
        }
    }
    let Some(vp) = vp else {
        return;
    };
    g.gathers = true;
    // A photon of d bounces gathered after the camera's k delta bounces makes a path of
    // d + 1 + k bounces, which `max_depth` bounds as it bounds every integrator's paths.
    let max_photon_depth = job.settings.max_depth - vp.depth;
    map.for_each_near(vp.p, st.r, |ph| {
        if ph.depth >= max_photon_depth {
            return;
        }
        let wi = vp.frame.to_local(Vec3A::from(ph.wi));
        let f = vp.bsdf.eval(vp.wo, wi);
        g.phi += Vec3A::from(ph.beta) * f;
        g.m += 1;
    });
    // The path throughput to the visible point, applied once all maps are gathered.
    g.beta = vp.beta;
}

/// The end of one iteration of one pixel: the radius and flux update from what it gathered.
fn update_pixel(st: &mut PixelState, g: &Gathered) {
    let (phi, m) = (g.phi, g.m);
    if !g.gathers || m == 0 || !phi.is_finite() {
        return;
    }
    let n_new = st.n + ALPHA * m as f32;
    let r_new = st.r * (n_new / (st.n + m as f32)).sqrt();
    st.tau = (st.tau + g.beta * phi) * ((r_new * r_new) / (st.r * st.r));
    st.n = n_new;
    st.r = r_new;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookups_find_exactly_the_photons_within_the_radius_once_each() {
        let mut photons = Vec::new();
        let mut h = 1u32;
        for _ in 0..2000 {
            let mut c = [0.0f32; 3];
            for v in &mut c {
                h = hash_u32(h);
                *v = (h >> 8) as f32 / 16_777_216.0 * 4.0 - 2.0;
            }
            photons.push(Photon {
                p: Vec3::from(c),
                wi: Vec3::Z,
                beta: Vec3::ONE,
                depth: 1,
            });
        }
        let map = PhotonMap::build(photons.clone(), 0.3, 2000, 0..1);
        for q in [Vec3A::ZERO, Vec3A::new(1.0, -0.5, 0.7), Vec3A::splat(1.9)] {
            for r in [0.05, 0.2, 0.3] {
                let mut got = 0;
                map.for_each_near(q, r, |_| got += 1);
                let want = photons
                    .iter()
                    .filter(|p| (Vec3A::from(p.p) - q).length_squared() <= r * r)
                    .count();
                assert_eq!(got, want, "{q} {r}");
            }
        }
    }

    /// The Cornell box at `size`², with 64-photon chunks (a depth of 1024; Russian roulette
    /// ends its photons after a few bounces).
    fn cornell(size: u32, spp: u32) -> (Scene, RenderJob) {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box.json");
        let scene = Scene::build(&crate::load_scene(&path).unwrap()).unwrap();
        let settings = crate::RenderSettings {
            width: size,
            height: size,
            spp,
            max_depth: 1024,
            integrator: crate::IntegratorKind::Sppm,
            ..Default::default()
        };
        let job = RenderJob::new(&scene, &settings).unwrap();
        (scene, job)
    }

    /// Every photon of the maps (position, direction, power bits, depth), sorted.
    fn photon_bits(maps: &[Arc<PhotonMap>]) -> Vec<[u32; 10]> {
        let mut all: Vec<[u32; 10]> = maps
            .iter()
            .flat_map(|m| m.photons.iter())
            .map(|ph| {
                let v = [ph.p, ph.wi, ph.beta];
                std::array::from_fn(|i| match i {
                    0..9 => v[i / 3][i % 3].to_bits(),
                    _ => ph.depth,
                })
            })
            .collect();
        all.sort_unstable();
        all
    }

    #[test]
    fn an_iteration_past_the_cap_is_cut_into_maps_of_whole_chunks_holding_the_same_photons() {
        let (scene, job) = cornell(32, 1);
        assert_eq!(chunk_photons(&job), 64);
        let maps_of = |cap: usize| {
            let mut maps = Vec::new();
            for_each_photon_map::<()>(&scene, &job, 3, cap, |m| {
                maps.push(photon_map(&scene, &job, 3, m.chunks.start, cap));
                Ok(())
            })
            .unwrap();
            maps
        };
        let one = maps_of(MAP_DEPOSITS);
        assert_eq!(one.len(), 1);
        assert_eq!(one[0].chunks, 0..16);
        assert_eq!(one[0].traced, 32 * 32);
        let deposits = one[0].photons.len();
        assert!(deposits > 1000, "{deposits} deposits");
        let cap = deposits / 8;
        let many = maps_of(cap);
        assert!(many.len() >= 8, "{} maps", many.len());
        let mut next = 0;
        for m in &many {
            assert_eq!(m.chunks.start, next);
            assert!(m.chunks.end > m.chunks.start);
            assert!(
                m.photons.len() <= cap || m.chunks.len() == 1,
                "{:?}",
                m.chunks
            );
            next = m.chunks.end;
        }
        assert_eq!(next, 16);
        assert_eq!(many.iter().map(|m| m.traced).sum::<u32>(), 32 * 32);
        assert_eq!(photon_bits(&one), photon_bits(&many));
    }

    #[test]
    fn a_tile_gathered_from_many_maps_matches_one_map_but_for_rounding() {
        let (scene, job) = cornell(16, 3);
        let tile = Tile {
            x0: 0,
            y0: 0,
            x1: 16,
            y1: 16,
        };
        let render = |cap| {
            let job = RenderJob::new(&scene, &job.settings).unwrap();
            render_tile_with(&scene, &job, tile, 0..3, &super::super::Cancel::new(), cap).unwrap()
        };
        let one = render(MAP_DEPOSITS);
        let many = render(64);
        assert_eq!(one.pixels.len(), many.pixels.len());
        let mut lit = 0;
        for (a, b) in one.pixels.iter().zip(&many.pixels) {
            assert_eq!(a[3], b[3], "the same good iterations");
            for k in 0..3 {
                let tol = 1e-5 * a[k].abs().max(1e-3);
                assert!((a[k] - b[k]).abs() <= tol, "{a:?} {b:?}");
            }
            lit += (a[0] > 0.0) as u32;
        }
        assert!(lit > 200, "{lit} lit pixels");
    }
}
