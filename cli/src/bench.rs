//! `raytile bench`: the speed figures the project tracks, as a table.
//!
//! - samples/s of the path tracer on the Cornell box (256×256 by default);
//! - ray throughput (Mrays/s) through the scene for coherent rays (camera rays in scanline
//!   order) and incoherent rays (random origins inside the box, random directions);
//! - samples/s of `path`, `bdpt` and `sppm` on the caustic scene (an sppm sample is one
//!   iteration of one pixel, its share of the photon pass included);
//! - BVH build time and ray throughput on a procedural mesh of ≥ 1 M triangles for every obvhs
//!   build preset.

use anyhow::{Context, Result};
use clap::Args;
use glam::{Vec2, Vec3A};
use rayon::prelude::*;
use raytile_core::accel::{
    pair_limits, AnyLeaves, Bvh, BvhBuildParams, ClosestLeaves, PlocSearchDistance, SortPrecision,
    Width, PRESETS,
};
use raytile_core::geometry::triangle::{LeafTris, TriangleGeom};
use raytile_core::geometry::{Aabb, Ray};
use raytile_core::sampling::hash_u32;
use raytile_core::{load_scene, render, RenderJob, RenderSettings, Scene};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `raytile bench`.
#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Scene for the samples/s and scene ray figures.
    #[arg(long, default_value = "scenes/cornell-box.json")]
    pub scene: PathBuf,
    /// Image edge for the samples/s figure (1 to 8192).
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=8192))]
    pub size: u32,
    /// Samples per pixel for the samples/s figure (1 to 2^20).
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u32).range(1..=1 << 20))]
    pub spp: u32,
    /// Maximum depth for the samples/s figure (at most 1024).
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u32).range(0..=1024))]
    pub max_depth: u32,
    /// Triangles in the BVH mesh (rounded to a grid; 8 to 2^28).
    #[arg(long, default_value_t = 1 << 20,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(8..=1 << 28))]
    pub triangles: usize,
    /// Rays per throughput measurement (at least 1).
    #[arg(long, default_value_t = 2_000_000,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    pub rays: usize,
    /// Scene for the per-integrator samples/s figures.
    #[arg(long, default_value = "scenes/caustic.json")]
    pub caustic_scene: PathBuf,
    /// Samples per pixel (sppm: iterations) of the per-integrator figures, at 160×120 (1 to
    /// 2^20).
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=1 << 20))]
    pub caustic_spp: u32,
    /// Skip the BVH build benchmark and the ray figures on its mesh.
    #[arg(long)]
    pub no_bvh: bool,
    /// BVH builds to measure (repeatable; default `binned_sah` and every obvhs preset):
    /// `binned_sah` (the builder of scenes above 65,536 primitives), an obvhs preset name, or
    /// `fast_build` changed by `key=value` pairs, e.g. `search=14,threshold=3,reinsert=0.05,post=2`
    /// (keys: search 1/2/6/14/24/32, threshold, reinsert, post, sort 64/128, leaf, cost).
    #[arg(long = "build")]
    pub builds: Vec<String>,
    /// Node widths to measure the BVH builds with (repeatable: 4, 8, 16; default all three).
    #[arg(long = "width")]
    pub widths: Vec<u32>,
}

/// The `--build` name of the binned-SAH builder.
const BINNED_SAH: &str = "binned_sah";

/// The obvhs parameters a `--build` names.
fn build_params(spec: &str) -> Result<BvhBuildParams> {
    if let Some((_, p)) = PRESETS.iter().find(|(n, _)| *n == spec) {
        return Ok(*p);
    }
    if !spec.contains('=') {
        let names: Vec<&str> = std::iter::once(BINNED_SAH)
            .chain(PRESETS.iter().map(|(n, _)| *n))
            .collect();
        anyhow::bail!(
            "--build {spec}: no such build (the builds are {}, or `fast_build` changed by \
             key=value pairs such as search=14,reinsert=0.05)",
            names.join(", ")
        );
    }
    let mut p = BvhBuildParams::fast_build();
    for kv in spec.split(',') {
        let (k, v) = kv
            .split_once('=')
            .with_context(|| format!("--build {spec}: `{kv}` is not key=value"))?;
        let bad = || format!("--build {spec}: bad value in `{kv}`");
        match k {
            "search" => {
                p.ploc_search_distance = match v {
                    "1" => PlocSearchDistance::Minimum,
                    "2" => PlocSearchDistance::VeryLow,
                    "6" => PlocSearchDistance::Low,
                    "14" => PlocSearchDistance::Medium,
                    "24" => PlocSearchDistance::High,
                    "32" => PlocSearchDistance::VeryHigh,
                    _ => anyhow::bail!(bad()),
                }
            }
            "threshold" => p.search_depth_threshold = v.parse().with_context(bad)?,
            "reinsert" => p.reinsertion_batch_ratio = v.parse().with_context(bad)?,
            "post" => {
                p.post_collapse_reinsertion_batch_ratio_multiplier = v.parse().with_context(bad)?
            }
            "sort" => {
                p.sort_precision = match v {
                    "64" => SortPrecision::U64,
                    "128" => SortPrecision::U128,
                    _ => anyhow::bail!(bad()),
                }
            }
            "leaf" => p.max_prims_per_leaf = v.parse().with_context(bad)?,
            "cost" => p.collapse_traversal_cost = v.parse().with_context(bad)?,
            _ => anyhow::bail!("--build {spec}: unknown key `{k}`"),
        }
    }
    Ok(p)
}

fn rnd(i: u32) -> f32 {
    (hash_u32(i) >> 8) as f32 / (1u32 << 24) as f32
}

/// samples/s of each integrator that renders caustics, beside `path`, on `--caustic-scene`.
fn integrator_rows(args: &BenchArgs) -> Result<()> {
    use raytile_core::IntegratorKind;
    let path = &args.caustic_scene;
    let desc = load_scene(path).with_context(|| format!("loading {}", path.display()))?;
    let scene = Scene::build(&desc)?;
    for integrator in [
        IntegratorKind::Path,
        IntegratorKind::Bdpt,
        IntegratorKind::Sppm,
    ] {
        let settings = RenderSettings {
            width: 160,
            height: 120,
            spp: args.caustic_spp,
            max_depth: 16,
            integrator,
            ..Default::default()
        };
        let job = RenderJob::new(&scene, &settings)?;
        let t = Instant::now();
        render(&scene, &job, &());
        let secs = t.elapsed().as_secs_f64();
        let samples = settings.width as f64 * settings.height as f64 * settings.spp as f64;
        println!(
            "| {}, {} {}x{} {} spp, depth {} | {:.3} s, {:.3} Msamples/s |",
            integrator.name(),
            path.display(),
            settings.width,
            settings.height,
            settings.spp,
            settings.max_depth,
            secs,
            samples / secs / 1e6
        );
    }
    Ok(())
}

fn mrays(n: usize, secs: f64) -> f64 {
    n as f64 / secs / 1e6
}

/// Runs `raytile bench`.
pub fn run(args: BenchArgs) -> Result<()> {
    // The BVH flags are checked before the render figures, which take minutes.
    let widths = if args.widths.is_empty() {
        vec![(4, Width::Four), (8, Width::Eight), (16, Width::Sixteen)]
    } else {
        let width = |&w: &u32| match w {
            4 => Ok((w, Width::Four)),
            8 => Ok((w, Width::Eight)),
            16 => Ok((w, Width::Sixteen)),
            _ => Err(anyhow::anyhow!(
                "--width {w}: the BVH's nodes are 4, 8 or 16 wide"
            )),
        };
        args.widths.iter().map(width).collect::<Result<Vec<_>>>()?
    };
    for b in args.builds.iter().filter(|b| *b != BINNED_SAH) {
        build_params(b)?;
    }
    println!("raytile bench ({} threads)", rayon::current_num_threads());
    let desc =
        load_scene(&args.scene).with_context(|| format!("loading {}", args.scene.display()))?;
    let settings = RenderSettings {
        width: args.size,
        height: args.size,
        spp: args.spp,
        max_depth: args.max_depth,
        ..Default::default()
    };
    let scene = Scene::build(&desc)?;
    let job = RenderJob::new(&scene, &settings)?;
    // Warm-up pass (page faults, thread start), then the measured render.
    let warm_up = RenderSettings {
        spp: 1,
        ..settings.clone()
    };
    render(&scene, &RenderJob::new(&scene, &warm_up)?, &());
    let t = Instant::now();
    let film = render(&scene, &job, &());
    let secs = t.elapsed().as_secs_f64();
    let samples = settings.width as f64 * settings.height as f64 * settings.spp as f64;
    let m = film.mean();
    println!("| benchmark | figure |");
    println!("|---|---|");
    println!(
        "| path tracer, {} {}x{} {} spp, depth {} | {:.3} s, {:.3} Msamples/s (mean {:.4} {:.4} {:.4}) |",
        args.scene.display(), settings.width, settings.height, settings.spp, settings.max_depth, secs, samples / secs / 1e6, m[0], m[1], m[2]
    );

    integrator_rows(&args)?;

    // Scene ray throughput.
    let n = args.rays;
    let cam = &job.camera;
    let side = (n as f64).sqrt() as u32;
    let coherent: Vec<Ray> = (0..side * side)
        .map(|i| {
            let (x, y) = (i % side, i / side);
            let film = Vec2::new(
                (x as f32 + 0.5) / side as f32 * settings.width as f32,
                (y as f32 + 0.5) / side as f32 * settings.height as f32,
            );
            cam.generate_ray(film, Vec2::splat(0.5))
        })
        .collect();
    let b = scene.bounds();
    let incoherent: Vec<Ray> = (0..n as u32)
        .map(|i| {
            let u = Vec3A::new(rnd(6 * i), rnd(6 * i + 1), rnd(6 * i + 2));
            let o = b.min + (b.max - b.min) * (u * 0.98 + 0.01);
            let d = Vec3A::new(
                rnd(6 * i + 3) - 0.5,
                rnd(6 * i + 4) - 0.5,
                rnd(6 * i + 5) - 0.5,
            )
            .normalize_or(Vec3A::X);
            Ray::new(o, d)
        })
        .collect();
    for (name, rays) in [("coherent", &coherent), ("incoherent", &incoherent)] {
        let t = Instant::now();
        let hits: usize = rays
            .par_chunks(4096)
            .map(|c| {
                c.iter()
                    .filter(|r| scene.intersect(r, f32::INFINITY).is_some())
                    .count()
            })
            .sum();
        let secs = t.elapsed().as_secs_f64();
        println!(
            "| scene closest-hit, {name} rays | {:.2} Mrays/s ({} of {} hit) |",
            mrays(rays.len(), secs),
            hits,
            rays.len()
        );
    }
    if args.no_bvh {
        return Ok(());
    }

    // BVH on a procedural mesh: a bumpy sphere tessellated as a lat-long grid.
    let grid = ((args.triangles / 2) as f64).sqrt().ceil() as usize;
    let vert = |i: usize, j: usize| {
        let (th, ph) = (
            std::f32::consts::PI * i as f32 / grid as f32,
            2.0 * std::f32::consts::PI * j as f32 / grid as f32,
        );
        let r = 1.0 + 0.05 * (7.0 * th).sin() * (9.0 * ph).cos();
        Vec3A::new(
            r * th.sin() * ph.cos(),
            r * th.cos(),
            r * th.sin() * ph.sin(),
        )
    };
    let mut tris = Vec::with_capacity(grid * grid * 2);
    for i in 0..grid {
        for j in 0..grid {
            let (a, b2, c, d) = (
                vert(i, j),
                vert(i + 1, j),
                vert(i + 1, j + 1),
                vert(i, j + 1),
            );
            tris.push(TriangleGeom::new([a, b2, c]));
            tris.push(TriangleGeom::new([a, c, d]));
        }
    }
    let bounds: Vec<Aabb> = tris
        .iter()
        .map(|t| Aabb::from_points(&[t.v0, t.v0 + t.e1, t.v0 + t.e2]))
        .collect();
    let coherent: Vec<Ray> = (0..side * side)
        .map(|i| {
            let (x, y) = (
                (i % side) as f32 / side as f32 * 2.4 - 1.2,
                (i / side) as f32 / side as f32 * 2.4 - 1.2,
            );
            Ray::new(Vec3A::new(x, y, 3.0), Vec3A::new(0.0, 0.0, -1.0))
        })
        .collect();
    let incoherent: Vec<Ray> = (0..n as u32)
        .map(|i| {
            let o = Vec3A::new(rnd(6 * i) - 0.5, rnd(6 * i + 1) - 0.5, rnd(6 * i + 2) - 0.5) * 1.6;
            let d = Vec3A::new(
                rnd(6 * i + 3) - 0.5,
                rnd(6 * i + 4) - 0.5,
                rnd(6 * i + 5) - 0.5,
            )
            .normalize_or(Vec3A::X);
            Ray::new(o, d)
        })
        .collect();
    // Shadow rays: from points just outside the surface toward a small square light above
    // it, as next-event estimation casts them (the lower half are blocked by the sphere).
    let shadow: Vec<Ray> = (0..n as u32)
        .map(|i| {
            let t = &tris[hash_u32(i ^ 0x5bd1_e995) as usize % tris.len()];
            let p = t.point(0.25, 0.25);
            let nrm = t.e1.cross(t.e2).normalize_or(Vec3A::Y);
            let o = p + nrm * 1e-3 * nrm.dot(p).signum();
            let light = Vec3A::new(rnd(2 * i + 900_000) - 0.5, 3.0, rnd(2 * i + 900_001) - 0.5);
            Ray::new(o, light - o)
        })
        .collect();
    let builds: Vec<String> = if args.builds.is_empty() {
        std::iter::once(BINNED_SAH)
            .chain(PRESETS.iter().map(|(n, _)| *n))
            .map(String::from)
            .collect()
    } else {
        args.builds.clone()
    };
    for name in &builds {
        let params = if name == BINNED_SAH {
            None
        } else {
            Some(build_params(name)?)
        };
        for &(w, width) in &widths {
            // The binned builder consumes its bounds: a copy, made before the clock starts.
            let owned = params.is_none().then(|| bounds.clone());
            let t = Instant::now();
            let (mut bvh, order) = match (params, owned) {
                (Some(params), _) => Bvh::build_wide(&bounds, params, width),
                (None, owned) => Bvh::build_sah(owned.unwrap_or_default(), width),
            };
            let build = t.elapsed().as_secs_f64();
            // As the renderer does: each leaf's triangles packed for the 4-wide test.
            let packed = LeafTris::new(order.len(), bvh.leaves(), |slot| {
                Some(tris[order[slot] as usize])
            });
            // Closest hits, one leaf at a time and, as the renderer traces them with AVX2,
            // two small leaves a node enters at once; both must hit the same triangles.
            bvh.mark_leaves(|_, _| true);
            let mut figures = Vec::new();
            for rays in [&coherent, &incoherent] {
                let mut ways = Vec::new();
                for pairs in [false, raytile_core::accel::avx2()] {
                    let t = Instant::now();
                    let hits: Vec<Option<(usize, f32)>> = rays
                        .par_chunks(4096)
                        .flat_map_iter(|c| {
                            c.iter().map(|r| {
                                let mut leaves = ClosestTris {
                                    tris: &packed,
                                    ray: r,
                                    pairs,
                                };
                                bvh.closest_with(r, f32::INFINITY, &mut leaves)
                            })
                        })
                        .collect();
                    ways.push((mrays(rays.len(), t.elapsed().as_secs_f64()), hits));
                }
                anyhow::ensure!(
                    ways[0].1 == ways[1].1,
                    "closest hits one leaf at a time and with leaf pairs differ"
                );
                figures.push((ways[0].0, ways[1].0));
            }
            // Shadow rays (to the light, t < 1) one leaf at a time, then, as the renderer
            // casts them with AVX2, two leaves a node enters at once.
            let mut shadows = Vec::new();
            for pairs in [false, raytile_core::accel::avx2()] {
                let t = Instant::now();
                let blocked: usize = shadow
                    .par_chunks(4096)
                    .map(|c| {
                        c.iter()
                            .filter(|r| {
                                let mut leaves = ShadowLeaves {
                                    tris: &packed,
                                    ray: r,
                                    pairs,
                                };
                                bvh.any_with(r, 1.0, &mut leaves)
                            })
                            .count()
                    })
                    .sum();
                shadows.push((mrays(shadow.len(), t.elapsed().as_secs_f64()), blocked));
            }
            anyhow::ensure!(
                shadows[0].1 == shadows[1].1,
                "shadow rays blocked one leaf at a time ({}) and with leaf pairs ({}) differ",
                shadows[0].1,
                shadows[1].1
            );
            let (sah_nodes, sah_leaves) = bvh.sah_cost();
            println!(
                "| BVH {name}, {w}-wide, {} triangles | build {:.3} s; {:.2} Mrays/s coherent ({:.2} with leaf pairs), {:.2} Mrays/s incoherent ({:.2} with leaf pairs), {:.2} Mrays/s shadow ({:.2} with leaf pairs); {} nodes, {} leaves, {:.1} MB; SAH {:.2} nodes + {:.2} leaves |",
                tris.len(), build, figures[0].0, figures[0].1, figures[1].0, figures[1].1,
                shadows[0].0, shadows[1].0,
                bvh.node_count(), bvh.leaves().len(), bvh.memory_bytes() as f64 / 1e6, sah_nodes,
                sah_leaves
            );
        }
    }
    Ok(())
}

/// The leaves of `raytile bench`'s mesh for closest hits: four triangles at a time, or two
/// leaves at once if `pairs` (which needs AVX2), as the renderer tests them.
struct ClosestTris<'a> {
    tris: &'a LeafTris,
    ray: &'a Ray,
    pairs: bool,
}

impl ClosestLeaves for ClosestTris<'_> {
    fn leaf(&mut self, _: bool, start: u32, count: u32, tmax: f32) -> Option<(usize, f32)> {
        let (o, d) = (self.ray.o, self.ray.d);
        let (lane, t, _, _) = self.tris.intersect(start, count, o, d, 0.0, tmax)?;
        Some((start as usize + lane, t))
    }

    fn pairs(&self) -> bool {
        self.pairs
    }

    fn pair(
        &mut self,
        a: (u32, u32),
        b: (u32, u32),
        tmax: f32,
        best: Option<usize>,
    ) -> Option<(usize, f32)> {
        let (o, d) = (self.ray.o, self.ray.d);
        let (bound, beats) = pair_limits(a.0, b.0, best, tmax);
        let (slot, t, _, _) = self
            .tris
            .nearest_pair(a, b, o, d, (0.0, bound), beats, true)?;
        Some((slot, t))
    }
}

/// The leaves of `raytile bench`'s mesh for shadow rays (t < 1): four triangles at a time,
/// or two leaves at once if `pairs` (which needs AVX2), as the renderer tests them.
struct ShadowLeaves<'a> {
    tris: &'a LeafTris,
    ray: &'a Ray,
    pairs: bool,
}

impl AnyLeaves for ShadowLeaves<'_> {
    fn leaf(&mut self, _: bool, start: u32, count: u32) -> bool {
        self.tris
            .any(start, count, self.ray.o, self.ray.d, 0.0, 1.0)
    }

    fn pairs(&self) -> bool {
        self.pairs
    }

    fn pair(&mut self, a: (u32, u32), b: (u32, u32)) -> bool {
        let (o, d) = (self.ray.o, self.ray.d);
        self.tris.hits_pair(a, b, o, d, (0.0, 1.0), true) != 0
    }
}
