//! Bidirectional path tracing (pbrt-v4's `BDPTIntegrator`, after Veach): a camera subpath and
//! a light subpath per sample, joined by every strategy (s, t) — s vertices of the light
//! subpath, t of the camera subpath — each weighted by multiple importance sampling (the
//! balance heuristic, computed with pbrt's walk over remapped densities). Strategies with
//! t = 1 join a light subpath vertex straight to the camera: they land in whatever pixel the
//! vertex projects to and are returned as *splats*, rounded to fixed point ([`coalesce`]) so
//! that their sum does not depend on the order in which tiles are added.
//!
//! Random numbers: the camera subpath draws from the pixel's [`Sampler`] for (pixel, sample
//! index, seed), the light subpath from a second sampler of the same (pixel, sample index)
//! under a derived seed, so a sample's whole contribution depends on nothing else.
//!
//! Light transport on light subpaths uses the adjoint BSDF (the radiance BSDF with its
//! arguments swapped; for sampled delta transmission, the radiance value times η²) and
//! pbrt's shading-normal correction. Participating media are not rendered (as `path`).

use super::Estimate;
use crate::geometry::{Interaction, Ray};
use crate::light::{range_window, spot_falloff, Light};
use crate::material::Bsdf;
use crate::sampling::detmath::exp3;
use crate::sampling::warp::{concentric_disk, cosine_hemisphere, uniform_cone, uniform_sphere};
use crate::sampling::warp::{Frame, UNIFORM_SPHERE_PDF};
use crate::sampling::{hash_u32, Sampler};
use crate::scene::bodies::{beer, Bodies};
use crate::scene::ObjectKind;
use crate::{RenderJob, Scene};
use glam::{Vec2, Vec3A};
use std::f32::consts::PI;

pub use crate::film::SPLAT_SCALE;

/// One splat: a pixel (row-major index in the frame) and its fixed-point RGB.
pub type Splat = (u32, [i128; 3]);

/// One splat as a sample makes it: a pixel and its RGB, before [`coalesce`] rounds it to fixed
/// point (a quarter of a [`Splat`]'s size: a tile keeps every one of its samples' splats until
/// it is done).
pub type RawSplat = (u32, [f32; 3]);

/// A number in [0, 1) from 24 bits of a hash.
#[inline]
fn unit(h: u32) -> f32 {
    (h >> 8) as f32 / 16_777_216.0
}

/// `v` in fixed point, saturating, rounded to nearest.
#[inline]
pub fn to_fixed(v: f32) -> i128 {
    // f64 holds v · 2^56 exactly (a power-of-two scaling of an f32); the cast saturates.
    (v as f64 * SPLAT_SCALE).round() as i128
}

/// Adds `b` into `a`, channel by channel, saturating.
#[inline]
pub fn add_fixed(a: &mut [i128; 3], b: [i128; 3]) {
    for k in 0..3 {
        a[k] = a[k].saturating_add(b[k]);
    }
}

/// Sorts splats by pixel, rounds each to fixed point and sums those of one pixel: the result
/// depends only on the set of splats, not on their order.
pub fn coalesce(mut splats: Vec<RawSplat>) -> Vec<Splat> {
    splats.sort_unstable_by_key(|s| s.0);
    // Grown as needed: a tile's samples often splat onto far fewer pixels than they make.
    let mut out: Vec<Splat> = Vec::new();
    for (i, c) in splats {
        let v = c.map(to_fixed);
        match out.last_mut() {
            Some(last) if last.0 == i => add_fixed(&mut last.1, v),
            _ => out.push((i, v)),
        }
    }
    out.retain(|s| s.1 != [0; 3]);
    out
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Camera,
    /// A light subpath's first vertex, or a light sampled for s = 1, or the environment
    /// reached by a camera subpath.
    Light,
    Surface,
}

/// Which light a light vertex (or an emitting surface vertex) belongs to.
#[derive(Clone, Copy, Debug)]
enum Src {
    None,
    /// Index in the job's light set (scene lights, then the environment).
    Light(usize),
}

#[derive(Clone, Copy, Debug)]
struct Vertex {
    kind: Kind,
    p: Vec3A,
    /// Geometric normal; zero for points in space (camera, point and spot lights) and
    /// infinitely far lights.
    ng: Vec3A,
    /// Shading normal (zero where `ng` is).
    ns: Vec3A,
    it: Option<Interaction>,
    bsdf: Option<Bsdf>,
    beta: Vec3A,
    delta: bool,
    pdf_fwd: f32,
    pdf_rev: f32,
    src: Src,
    /// An environment or directional light (no position).
    infinite: bool,
    /// The bodies the vertex is inside (for a surface, on the side the walk reached it from).
    bodies: Bodies,
}

impl Vertex {
    fn new(kind: Kind, p: Vec3A, beta: Vec3A) -> Self {
        Vertex {
            kind,
            p,
            ng: Vec3A::ZERO,
            ns: Vec3A::ZERO,
            it: None,
            bsdf: None,
            beta,
            delta: false,
            pdf_fwd: 0.0,
            pdf_rev: 0.0,
            src: Src::None,
            infinite: false,
            bodies: Bodies::default(),
        }
    }

    fn on_surface(&self) -> bool {
        self.ng != Vec3A::ZERO
    }

    fn is_light(&self) -> bool {
        self.kind == Kind::Light || matches!(self.src, Src::Light(_))
    }
}

/// Scene and job values the subpaths need, looked up once per sample.
struct Ctx<'a> {
    scene: &'a Scene,
    job: &'a RenderJob,
    center: Vec3A,
    radius: f32,
}

impl Ctx<'_> {
    fn light(&self, i: usize) -> Option<&Light> {
        self.scene.lights.get(i)
    }

    /// Whether light `i` is a delta in position or direction (point, spot, directional).
    fn delta_light(&self, i: usize) -> bool {
        matches!(
            self.light(i),
            Some(Light::Point { .. } | Light::Spot { .. } | Light::Directional { .. })
        )
    }

    /// The light-set index of the emitter a surface point lies on, if it emits.
    fn emitter_index(&self, it: &Interaction) -> Option<usize> {
        let o = &self.scene.objects[it.object as usize];
        if o.light_base == u32::MAX {
            return None;
        }
        let i = o.light_base
            + if matches!(o.kind, ObjectKind::Mesh { .. }) {
                it.prim
            } else {
                0
            };
        Some(i as usize)
    }

    /// Area density of a light vertex's position, light choice included (pbrt's
    /// `PdfLightOrigin`); `w` is the unit direction from `v` towards the vertex it lights.
    fn pdf_light_origin(&self, v: &Vertex, w: Vec3A) -> f32 {
        let lights = self.job.lights();
        if v.infinite {
            // Only the environment can be hit by a ray; a directional light is a delta.
            return match (self.job.environment(), lights.environment()) {
                (Some(env), Some(e)) => lights.emission_pmf(e) * env.pdf(-w),
                _ => 0.0,
            };
        }
        let Src::Light(i) = v.src else {
            return 0.0;
        };
        let pmf = lights.emission_pmf(i);
        match self.light(i) {
            Some(Light::Point { .. } | Light::Spot { .. }) => pmf,
            Some(&Light::Area { light, prim, .. }) => {
                pmf * self.scene.area_lights[light as usize].pdf_area(prim, v.ng)
            }
            _ => 0.0,
        }
    }

    /// Density with which light vertex `v` emits towards `next`, per unit area at `next`
    /// (pbrt's `PdfLight`).
    fn pdf_light(&self, v: &Vertex, next: &Vertex) -> f32 {
        let to = next.p - v.p;
        let d2 = to.length_squared();
        if !(d2 > 0.0) {
            return 0.0;
        }
        let w = to / d2.sqrt();
        let mut pdf = if v.infinite {
            // Rays of infinitely far lights start on a disk of the scene's bounding sphere
            // facing `w` (`sample_emission`): they reach only the cylinder the disk sweeps.
            // An infinite plane reaches beyond it, and its points there are found by the
            // camera's strategies alone (a margin of 10⁻⁵, far above f32 rounding, keeps the
            // disk's own edge in).
            let rel = next.p - self.center;
            let along = rel.dot(w);
            let reach = self.radius * (1.0 + 1e-5);
            if along < -reach || (rel - w * along).length_squared() > reach * reach {
                return 0.0;
            }
            1.0 / (PI * self.radius * self.radius)
        } else {
            let Src::Light(i) = v.src else {
                return 0.0;
            };
            let pdf_dir = match self.light(i) {
                Some(Light::Point { .. }) => UNIFORM_SPHERE_PDF,
                Some(&Light::Spot {
                    axis, cos_outer, ..
                }) if w.dot(axis) > cos_outer => 1.0 / (2.0 * PI * (1.0 - cos_outer)),
                Some(&Light::Area { light, .. }) => emit_dir_pdf(
                    self.scene.area_lights[light as usize].emission.two_sided,
                    v.ng,
                    w,
                ),
                _ => 0.0,
            };
            pdf_dir / d2
        };
        if next.on_surface() {
            pdf *= next.ng.dot(w).abs();
        }
        pdf
    }

    /// Density with which vertex `v`, reached from `prev`, samples `next`, per unit area at
    /// `next` (pbrt's `Vertex::Pdf`).
    fn pdf(&self, v: &Vertex, prev: Option<&Vertex>, next: &Vertex) -> f32 {
        if v.kind == Kind::Light {
            return self.pdf_light(v, next);
        }
        let to = next.p - v.p;
        if !(to.length_squared() > 0.0) {
            return 0.0;
        }
        let wn = to.normalize();
        let pdf = match v.kind {
            Kind::Camera => self.job.camera.pdf_we(v.p, wn).1,
            _ => {
                let (Some(bsdf), Some(prev)) = (v.bsdf, prev) else {
                    return 0.0;
                };
                let wp = (prev.p - v.p).normalize_or_zero();
                let frame = Frame::from_z(v.ns);
                bsdf.pdf(frame.to_local(wp), frame.to_local(wn))
            }
        };
        convert_density(pdf, v, next)
    }

    /// Radiance emitted by a light vertex or emitting surface `v` towards `to`.
    fn le(&self, v: &Vertex, to: &Vertex) -> Vec3A {
        let w = (to.p - v.p).normalize_or_zero();
        if v.infinite {
            return self
                .job
                .environment()
                .map_or(Vec3A::ZERO, |e| e.radiance(-w));
        }
        match &v.it {
            Some(it) => self.scene.emitted(it, w),
            None => Vec3A::ZERO,
        }
    }
}

/// Cosine-weighted emission density of an area light (half of it on each side of a
/// two-sided one).
#[inline]
fn emit_dir_pdf(two_sided: bool, n: Vec3A, w: Vec3A) -> f32 {
    let c = n.dot(w);
    if two_sided {
        0.5 * c.abs() / PI
    } else if c > 0.0 {
        c / PI
    } else {
        0.0
    }
}

/// Solid-angle density at `from` to area density at `next` (infinitely far lights keep it).
#[inline]
fn convert_density(pdf: f32, from: &Vertex, next: &Vertex) -> f32 {
    if next.infinite {
        return pdf;
    }
    let w = next.p - from.p;
    let d2 = w.length_squared();
    if !(d2 > 0.0) {
        return 0.0;
    }
    let mut pdf = pdf / d2;
    if next.on_surface() {
        pdf *= next.ng.dot(w / d2.sqrt()).abs();
    }
    pdf
}

/// pbrt's correction for the non-symmetry that shading normals bring to importance transport.
#[inline]
fn shading_correction(ns: Vec3A, ng: Vec3A, wo: Vec3A, wi: Vec3A) -> f32 {
    let den = wo.dot(ng).abs() * wi.dot(ns).abs();
    if den == 0.0 {
        0.0
    } else {
        wo.dot(ns).abs() * wi.dot(ng).abs() / den
    }
}

/// BSDF value at surface vertex `v` for light arriving from `from` and leaving to `to`
/// (radiance mode: camera subpath) or importance mode (light subpath), without the cosine.
fn vertex_f(v: &Vertex, prev: &Vertex, next: &Vertex, importance: bool) -> Vec3A {
    let Some(bsdf) = v.bsdf else {
        return Vec3A::ZERO;
    };
    let wp = (prev.p - v.p).normalize_or_zero();
    let wn = (next.p - v.p).normalize_or_zero();
    let frame = Frame::from_z(v.ns);
    let (lp, ln) = (frame.to_local(wp), frame.to_local(wn));
    if importance {
        // Adjoint BSDF: light arrives from `prev`, importance from `next`.
        bsdf.eval(ln, lp) * shading_correction(v.ns, v.ng, wp, wn)
    } else {
        bsdf.eval(lp, ln)
    }
}

/// The value of the adjoint BSDF for a sample `bs` drawn at `it` (light or importance arriving
/// along `wo`, local `wo` and world `wo_w`, leaving along world `wi_w`), shading-normal
/// correction included: how light subpaths and photons scatter.
pub(super) fn adjoint_f(
    bsdf: &Bsdf,
    it: &Interaction,
    wo: Vec3A,
    wo_w: Vec3A,
    wi_w: Vec3A,
    bs: &crate::material::BsdfSample,
) -> Vec3A {
    let mut f = bs.f;
    if !bs.lobe.is_delta() {
        // The adjoint BSDF, f(wi → wo), as connections evaluate it (`vertex_f`): the
        // sampled value is f(wo → wi), which differs for BSDFs that are not reciprocal
        // (the glTF model weighs its lobes by the outgoing direction).
        f = bsdf.eval(bs.wi, wo);
    } else if bs.lobe.is_transmission() {
        f *= bs.eta * bs.eta;
    }
    f * shading_correction(it.ns, it.ng, wo_w, wi_w)
}

/// Whether a vertex can be joined to another by a deterministic segment.
fn connectible(ctx: &Ctx, v: &Vertex) -> bool {
    match v.kind {
        Kind::Camera => true,
        Kind::Light => match v.src {
            Src::Light(i) => !matches!(ctx.light(i), Some(Light::Directional { .. })),
            Src::None => !v.infinite,
        },
        Kind::Surface => v.bsdf.is_some_and(|b| !b.is_delta()),
    }
}

/// Geometry term with visibility between two vertices, times the transmittance of the
/// absorbing body the segment runs through (the one `b`'s side toward `a` is in, as a walk
/// from `b` would find it).
fn g(ctx: &Ctx, a: &Vertex, b: &Vertex) -> Vec3A {
    let d = a.p - b.p;
    let d2 = d.length_squared();
    if !(d2 > 0.0) {
        return Vec3A::ZERO;
    }
    let dist = d2.sqrt();
    let w = d / dist;
    let mut g = 1.0 / d2;
    if a.on_surface() {
        g *= a.ns.dot(w).abs();
    }
    if b.on_surface() {
        g *= b.ns.dot(w).abs();
    }
    if g == 0.0 || occluded(ctx, a, b) {
        return Vec3A::ZERO;
    }
    // `w` points from b to a.
    Vec3A::splat(g) * transmittance(ctx, b, w, dist)
}

/// The transmittance of the absorbing body (if any) along the stretch of length `dist` that
/// leaves vertex `v` along `w`.
fn transmittance(ctx: &Ctx, v: &Vertex, w: Vec3A, dist: f32) -> Vec3A {
    if !ctx.scene.absorbs {
        return Vec3A::ONE;
    }
    let sigma = match &v.it {
        Some(it) => v.bodies.sigma_leaving(ctx.scene, it, w, false),
        None => v.bodies.sigma(ctx.scene, false),
    };
    if sigma == Vec3A::ZERO {
        Vec3A::ONE
    } else {
        beer(sigma, dist)
    }
}

/// Whether the segment between two finite vertices is blocked.
fn occluded(ctx: &Ctx, a: &Vertex, b: &Vertex) -> bool {
    let (ray, tmax) = match (&a.it, &b.it) {
        (Some(ia), _) => ia.spawn_ray_to(b.p, b.ng),
        (None, Some(ib)) => ib.spawn_ray_to(a.p, a.ng),
        (None, None) => {
            let d = b.p - a.p;
            let len = d.length();
            (Ray::new(a.p, d / len), len * (1.0 - 1e-4))
        }
    };
    ctx.scene.occluded_past_interfaces(&ray, tmax)
}

/// The random walk of a subpath from `ray` (pbrt's `RandomWalk`): appends surface vertices
/// (and, for camera subpaths, an environment vertex where the ray escapes) to `path`, whose
/// last vertex is the walk's origin.
#[allow(clippy::too_many_arguments)]
fn random_walk(
    ctx: &Ctx,
    mut ray: Ray,
    sampler: &mut Sampler,
    mut beta: Vec3A,
    pdf: f32,
    max_vertices: usize,
    importance: bool,
    first_range: f32,
    mut bodies: Bodies,
    path: &mut Vec<Vertex>,
) {
    if max_vertices == 0 {
        return;
    }
    let mut pdf_fwd = pdf;
    let mut bounces = 0usize;
    let mut eta_scale = 1.0f32;
    // Distance travelled from the walk's origin through interfaces, for a light's range.
    let mut travelled = 0.0f32;
    loop {
        let Some(hit) = ctx.scene.intersect(&ray, f32::INFINITY) else {
            if !importance && ctx.job.environment().is_some() {
                let beta = beta * bodies.escape(ctx.scene, false);
                let mut v = Vertex::new(Kind::Light, ray.o + ray.d * (2.0 * ctx.radius), beta);
                v.infinite = true;
                v.pdf_fwd = pdf_fwd;
                path.push(v);
            }
            break;
        };
        let it = ctx.scene.interaction(&ray, &hit);
        if ctx.scene.absorbs {
            let sigma = bodies.arrive(ctx.scene, &it, ray.d, false);
            if sigma != Vec3A::ZERO {
                beta *= exp3(-sigma * hit.t);
            }
        }
        if ctx.scene.is_interface(it.object) {
            travelled += hit.t;
            ray = it.spawn_ray(ray.d);
            continue;
        }
        if bounces == 0 && first_range.is_finite() {
            beta *= range_window(travelled + hit.t, first_range);
        }
        let bsdf = ctx.scene.bsdf(&it);
        let mut v = Vertex::new(Kind::Surface, it.p, beta);
        v.ng = it.ng;
        v.ns = it.ns;
        v.it = Some(it);
        v.bsdf = Some(bsdf);
        v.bodies = bodies;
        if let Some(i) = ctx.emitter_index(&it) {
            v.src = Src::Light(i);
        }
        let prev = *path.last().expect("a walk starts from a vertex");
        v.pdf_fwd = convert_density(pdf_fwd, &prev, &v);
        path.push(v);
        bounces += 1;
        if bounces >= max_vertices {
            break;
        }
        let frame = it.shading_frame();
        let wo_w = -ray.d;
        let wo = frame.to_local(wo_w);
        sampler.align4();
        let [u_lobe, u_rr, _] = sampler.hashed_3();
        let u_dir = sampler.next_2d();
        let _ = sampler.next_2d();
        let Some(bs) = bsdf.sample(wo, u_lobe, u_dir) else {
            break;
        };
        if !(bs.pdf > 0.0) {
            break;
        }
        let wi_w = frame.to_world(bs.wi).normalize();
        let mut f = bs.f;
        if importance {
            f = adjoint_f(&bsdf, &it, wo, wo_w, wi_w, &bs);
        } else if bs.lobe.is_transmission() {
            eta_scale *= bs.eta * bs.eta;
        }
        let weight = f * bs.wi.z.abs() / bs.pdf;
        if !weight.is_finite() || weight.max_element() <= 0.0 {
            break;
        }
        beta *= weight;
        let n = path.len();
        let delta = bs.lobe.is_delta();
        let pdf_rev = if delta { 0.0 } else { bsdf.pdf(bs.wi, wo) };
        pdf_fwd = if delta { 0.0 } else { bs.pdf };
        path[n - 1].delta = delta;
        let cur = path[n - 1];
        path[n - 2].pdf_rev = convert_density(pdf_rev, &cur, &path[n - 2]);
        if ctx.scene.absorbs {
            bodies.leave(ctx.scene, &it, wi_w);
        }
        ray = it.spawn_ray(wi_w);
        // Russian roulette from the third bounce, on the throughput (pbrt-v4's rule).
        let rr_beta = beta * eta_scale;
        if bounces > 2 && rr_beta.max_element() < 1.0 {
            let q = (1.0 - rr_beta.max_element()).max(0.0);
            if u_rr < q {
                break;
            }
            beta /= 1.0 - q;
        }
    }
}

/// A ray leaving a light, sampled as light subpaths and photons start (pbrt's `SampleLe`).
pub(super) struct Emission {
    /// Index in the job's light set.
    pub index: usize,
    /// Probability of choosing the light.
    pub pmf: f32,
    /// The point on the light (on the scene's bounding disk for infinitely far lights).
    pub p: Vec3A,
    /// Direction (unit).
    pub d: Vec3A,
    /// Emitted radiance (intensity for point and spot lights, irradiance for the sun).
    pub le: Vec3A,
    /// Density of the origin (area, or 1 for a point).
    pub pdf_pos: f32,
    /// Density of the direction (solid angle, or 1 for the sun).
    pub pdf_dir: f32,
    /// The emitter's normal; zero for points and infinitely far lights.
    pub n: Vec3A,
    /// The light's range (infinite but for point and spot lights with one).
    pub range: f32,
    /// An environment or directional light.
    pub infinite: bool,
}

impl Emission {
    /// The ray, leaving an emitting surface without hitting it again.
    pub fn ray(&self) -> Ray {
        if self.n == Vec3A::ZERO {
            Ray::new(self.p, self.d)
        } else {
            Ray::new(
                crate::geometry::offset_ray_origin(self.p, self.n, self.d),
                self.d,
            )
        }
    }

    /// The ray's throughput: Le cos / (pmf pdf_pos pdf_dir).
    pub fn beta(&self) -> Vec3A {
        let cos = if self.n == Vec3A::ZERO {
            1.0
        } else {
            self.n.dot(self.d).abs()
        };
        self.le * (cos / (self.pmf * self.pdf_pos * self.pdf_dir))
    }
}

/// The centre and radius of the scene's bounding sphere, where infinitely far lights start
/// their rays.
pub(super) fn scene_sphere(scene: &Scene) -> (Vec3A, f32) {
    let b = scene.bounds;
    if b.min.cmple(b.max).all() {
        ((b.min + b.max) * 0.5, scene.radius)
    } else {
        (Vec3A::ZERO, scene.radius)
    }
}

/// Whether the light of an infinitely far light from direction `to_light` is blocked before
/// it reaches `o`, a point of the disk its rays start on. Nothing of a bounded scene lies
/// beyond that disk (it touches the scene's bounding sphere), but an unbounded plane does: a
/// ray that starts on the disk in the plane's shadow (the sun below the horizon of an infinite
/// floor, whose part outside the sphere blocks it) carries no light.
fn shadowed(scene: &Scene, o: Vec3A, to_light: Vec3A) -> bool {
    scene.aggregate.has_unbounded()
        && scene.occluded_past_interfaces(&Ray::new(o, to_light), f32::INFINITY)
}

/// A light chosen by power and a ray sampled from it, with three hashed numbers and two
/// pairs from `sampler`; `None` when the light gives nothing in the sampled direction.
pub(super) fn sample_emission(
    scene: &Scene,
    job: &RenderJob,
    (center, radius): (Vec3A, f32),
    sampler: &mut Sampler,
) -> Option<Emission> {
    let lights = job.lights();
    let [u_sel, u_side, _] = sampler.hashed_3();
    let u1 = sampler.next_2d();
    let u2 = sampler.next_2d();
    let (index, pmf) = lights.choose(u_sel)?;
    // (origin, direction, Le, pdf_pos, pdf_dir, normal, range, infinite)
    let (o, d, le, pdf_pos, pdf_dir, n, range, infinite) = match scene.lights.get(index) {
        Some(&Light::Point {
            position,
            intensity,
            range,
        }) => (
            position,
            uniform_sphere(u1),
            intensity,
            1.0,
            UNIFORM_SPHERE_PDF,
            Vec3A::ZERO,
            range,
            false,
        ),
        Some(&Light::Spot {
            position,
            axis,
            intensity,
            cos_inner,
            cos_outer,
            range,
        }) => {
            let d = Frame::from_z(axis).to_world(uniform_cone(u1, cos_outer));
            let f = spot_falloff(d.dot(axis), cos_inner, cos_outer);
            let pdf_dir = 1.0 / (2.0 * PI * (1.0 - cos_outer));
            (
                position,
                d,
                intensity * f,
                1.0,
                pdf_dir,
                Vec3A::ZERO,
                range,
                false,
            )
        }
        Some(&Light::Directional {
            to_light,
            irradiance,
        }) => {
            let frame = Frame::from_z(to_light);
            let disk = concentric_disk(u1) * radius;
            let o = center + radius * to_light + frame.to_world(Vec3A::new(disk.x, disk.y, 0.0));
            if shadowed(scene, o, to_light) {
                return None;
            }
            let pdf_pos = 1.0 / (PI * radius * radius);
            (
                o,
                -to_light,
                irradiance,
                pdf_pos,
                1.0,
                Vec3A::ZERO,
                f32::INFINITY,
                true,
            )
        }
        Some(&Light::Area { light, prim, .. }) => {
            let al = &scene.area_lights[light as usize];
            let (p, ng, uv, pdf_area) = al.sample_point(prim, u1)?;
            let mut local = cosine_hemisphere(u2);
            let mut nn = ng;
            if al.emission.two_sided && u_side < 0.5 {
                nn = -ng;
            }
            if local.z <= 0.0 {
                local.z = 1e-7;
            }
            let d = Frame::from_z(nn).to_world(local).normalize();
            let pdf_dir = emit_dir_pdf(al.emission.two_sided, ng, d);
            let le = al.emission.radiance(&scene.textures, ng, &uv, d)
                * al.coverage(&scene.textures, &uv);
            (p, d, le, pdf_area, pdf_dir, ng, f32::INFINITY, false)
        }
        None => {
            let env = job.environment()?;
            let (wi, le, pdf_dir) = env.sample(u1)?;
            let frame = Frame::from_z(wi);
            let disk = concentric_disk(u2) * radius;
            let o = center + radius * wi + frame.to_world(Vec3A::new(disk.x, disk.y, 0.0));
            if shadowed(scene, o, wi) {
                return None;
            }
            let pdf_pos = 1.0 / (PI * radius * radius);
            (
                o,
                -wi,
                le,
                pdf_pos,
                pdf_dir,
                Vec3A::ZERO,
                f32::INFINITY,
                true,
            )
        }
    };
    if !(pdf_pos > 0.0) || !(pdf_dir > 0.0) || le == Vec3A::ZERO {
        return None;
    }
    Some(Emission {
        index,
        pmf,
        p: o,
        d,
        le,
        pdf_pos,
        pdf_dir,
        n,
        range,
        infinite,
    })
}

/// The light subpath: a light chosen by power, a ray sampled from it, then the walk.
fn light_subpath(ctx: &Ctx, sampler: &mut Sampler, max_vertices: usize, path: &mut Vec<Vertex>) {
    let Some(e) = sample_emission(ctx.scene, ctx.job, (ctx.center, ctx.radius), sampler) else {
        return;
    };
    let (beta, ray) = (e.beta(), e.ray());
    let Emission {
        index,
        pmf,
        p: o,
        d,
        le,
        pdf_pos,
        pdf_dir,
        n,
        range,
        infinite,
    } = e;
    let mut v = Vertex::new(Kind::Light, o, le);
    v.src = Src::Light(index);
    v.ng = n;
    v.ns = n;
    v.infinite = infinite;
    v.pdf_fwd = pdf_pos * pmf;
    v.bodies = ctx.job.starts.light(ctx.scene, index);
    path.push(v);
    random_walk(
        ctx,
        ray,
        sampler,
        beta,
        pdf_dir,
        max_vertices - 1,
        true,
        range,
        v.bodies,
        path,
    );
    if infinite {
        if path.len() > 1 {
            path[1].pdf_fwd = pdf_pos;
            if path[1].on_surface() {
                path[1].pdf_fwd *= d.dot(path[1].ng).abs();
            }
        }
        // Only an environment has a density of direction that a camera ray could meet.
        path[0].pdf_fwd = match ctx.light(index) {
            None => pmf * ctx.job.environment().map_or(0.0, |e| e.pdf(-d)),
            Some(_) => 0.0,
        };
    }
}

/// MIS weight of strategy (s, t) (balance heuristic), with `sampled` the vertex sampled for
/// s = 1 or t = 1. Works on copies of the subpaths.
fn mis_weight(
    ctx: &Ctx,
    light: &[Vertex],
    camera: &[Vertex],
    sampled: Option<Vertex>,
    s: usize,
    t: usize,
) -> f32 {
    if s + t == 2 {
        return 1.0;
    }
    // (With s = 1 the light subpath may be empty: the sampled vertex stands in for it.)
    let mut lv: Vec<Vertex> = light[..s.min(light.len())].to_vec();
    let mut cv: Vec<Vertex> = camera[..t].to_vec();
    if let Some(v) = sampled {
        if s == 1 {
            lv.truncate(0);
            lv.push(v);
        } else if t == 1 {
            cv[0] = v;
        }
    }
    if t > 0 {
        cv[t - 1].delta = false;
    }
    if s > 0 {
        lv[s - 1].delta = false;
    }
    // Camera vertices from `cut` down cannot be reached by the light's strategies: the light
    // is infinitely far and its rays (from a disk of the scene's bounding sphere) miss the
    // vertex next to it, which an infinite plane puts beyond that disk's reach. Their zero
    // density must not be remapped to 1 as the zeros of delta vertices are.
    let mut cut: Option<usize> = None;
    // pt's reverse density.
    if t > 0 {
        let r = if s > 0 {
            let qs_minus = if s > 1 { Some(lv[s - 2]) } else { None };
            let r = ctx.pdf(&lv[s - 1], qs_minus.as_ref(), &cv[t - 1]);
            if s == 1 && lv[0].infinite && r == 0.0 {
                cut = Some(t - 1);
            }
            r
        } else if t > 1 {
            let w = (cv[t - 2].p - cv[t - 1].p).normalize_or_zero();
            ctx.pdf_light_origin(&cv[t - 1], w)
        } else {
            0.0
        };
        cv[t - 1].pdf_rev = r;
    }
    // pt_minus's reverse density.
    if t > 1 {
        let r = if s > 0 {
            ctx.pdf(&cv[t - 1], Some(&lv[s - 1]), &cv[t - 2])
        } else {
            let r = ctx.pdf_light(&cv[t - 1], &cv[t - 2]);
            if cv[t - 1].infinite && r == 0.0 {
                cut = Some(t - 2);
            }
            r
        };
        cv[t - 2].pdf_rev = r;
    }
    // qs and qs_minus reverse densities.
    if s > 0 && t > 0 {
        let pt_minus = if t > 1 { Some(cv[t - 2]) } else { None };
        lv[s - 1].pdf_rev = ctx.pdf(&cv[t - 1], pt_minus.as_ref(), &lv[s - 1]);
        if s > 1 {
            lv[s - 2].pdf_rev = ctx.pdf(&lv[s - 1], Some(&cv[t - 1]), &lv[s - 2]);
        }
    }
    let remap = |f: f32| if f != 0.0 { f } else { 1.0 };
    let mut sum = 0.0f32;
    let mut ri = 1.0f32;
    for i in (1..t).rev() {
        if cut.is_some_and(|c| i <= c) {
            break;
        }
        ri *= remap(cv[i].pdf_rev) / remap(cv[i].pdf_fwd);
        if !cv[i].delta && !cv[i - 1].delta {
            sum += ri;
        }
    }
    ri = 1.0;
    for i in (0..s).rev() {
        ri *= remap(lv[i].pdf_rev) / remap(lv[i].pdf_fwd);
        let delta_light = if i > 0 {
            lv[i - 1].delta
        } else {
            match lv[0].src {
                Src::Light(j) => ctx.delta_light(j),
                Src::None => false,
            }
        };
        if !lv[i].delta && !delta_light {
            sum += ri;
        }
    }
    let w = 1.0 / (1.0 + sum);
    if w.is_finite() {
        w
    } else {
        0.0
    }
}

/// Radiance of one camera sample along `ray` by every strategy with t ≥ 2, and whether the
/// camera ray left the scene without a vertex; the strategies with t = 1 are pushed to
/// `splats` (pixel index and RGB, not yet divided by the sample count). `light_sampler` is
/// this sample's own light-subpath sampler.
pub fn li(
    scene: &Scene,
    job: &RenderJob,
    ray: Ray,
    sampler: &mut Sampler,
    light_sampler: &mut Sampler,
    splats: &mut Vec<RawSplat>,
) -> Estimate {
    let (center, radius) = scene_sphere(scene);
    let ctx = Ctx {
        scene,
        job,
        center,
        radius,
    };
    let max_depth = job.settings.max_depth as usize;
    // Camera subpath.
    let mut camera: Vec<Vertex> = Vec::with_capacity(max_depth + 2);
    let mut cam0 = Vertex::new(Kind::Camera, ray.o, Vec3A::ONE);
    cam0.bodies = job.starts.camera();
    // An orthographic camera's importance is a delta in direction: no light subpath can
    // reach it, and the strategies that would are out of the weights.
    cam0.delta = !job.camera.is_perspective();
    camera.push(cam0);
    let (_, pdf_dir) = job.camera.pdf_we(ray.o, ray.d);
    random_walk(
        &ctx,
        ray,
        sampler,
        Vec3A::ONE,
        pdf_dir,
        max_depth + 1,
        false,
        f32::INFINITY,
        cam0.bodies,
        &mut camera,
    );
    // The camera ray met nothing: no vertex, or only the environment's at infinity.
    let escaped = camera.get(1).is_none_or(|v| v.infinite);
    // Light subpath.
    let mut light: Vec<Vertex> = Vec::with_capacity(max_depth + 1);
    light_subpath(&ctx, light_sampler, max_depth + 1, &mut light);

    let key = (light_sampler.hashed_3()[0] * 16_777_216.0) as u32;
    let mut l = Vec3A::ZERO;
    // s = 1 samples its own point on a light (next-event estimation): it runs even when the
    // light subpath is empty (its emission sampled nothing, or was shadowed).
    for t in 1..=camera.len() {
        for s in 0..=light.len().max(1) {
            let depth = s as i64 + t as i64 - 2;
            if (s == 1 && t == 1) || depth < 0 || depth > max_depth as i64 {
                continue;
            }
            // Each strategy's own numbers: a hash of the sample's key and (s, t).
            let h = hash_u32(key ^ hash_u32((s as u32) << 16 | t as u32));
            let (h1, h2) = (hash_u32(h ^ 0x6a09_e667), hash_u32(h ^ 0xbb67_ae85));
            let u_conn = (unit(h), Vec2::new(unit(h1), unit(h2)));
            if let Some((c, raster)) = connect(&ctx, &light, &camera, s, t, u_conn) {
                if t == 1 {
                    if let Some(r) = raster {
                        let (w, h) = (job.settings.width, job.settings.height);
                        let x = (r.x as u32).min(w - 1);
                        let y = (r.y as u32).min(h - 1);
                        if c.is_finite() && c != Vec3A::ZERO {
                            splats.push((y * w + x, [c.x, c.y, c.z]));
                        }
                    }
                } else {
                    l += c;
                }
            }
        }
    }
    Estimate { l, escaped }
}

/// Strategy (s, t): its MIS-weighted contribution, and for t = 1 the film position.
fn connect(
    ctx: &Ctx,
    light: &[Vertex],
    camera: &[Vertex],
    s: usize,
    t: usize,
    (u_sel, u): (f32, Vec2),
) -> Option<(Vec3A, Option<Vec2>)> {
    if t > 1 && s != 0 && camera[t - 1].kind == Kind::Light {
        return None;
    }
    let mut sampled: Option<Vertex> = None;
    let mut raster = None;
    let l = if s == 0 {
        let pt = &camera[t - 1];
        if !pt.is_light() {
            return None;
        }
        pt.beta * ctx.le(pt, &camera[t - 2])
    } else if t == 1 {
        let qs = &light[s - 1];
        if !connectible(ctx, qs) || !ctx.job.camera.is_perspective() {
            return None;
        }
        let cs = ctx.job.camera.sample_wi(qs.p, u)?;
        let mut v = Vertex::new(Kind::Camera, cs.p, Vec3A::splat(cs.we / cs.pdf));
        v.pdf_fwd = 0.0;
        // s ≥ 2 here (s = t = 1 is skipped): qs is a surface vertex of the light subpath.
        let mut c = qs.beta * v.beta * vertex_f(qs, &light[s - 2], &v, true);
        let to_camera = cs.p - qs.p;
        c *= qs.ns.dot(to_camera.normalize_or_zero()).abs();
        let dist = to_camera.length();
        c *= transmittance(ctx, qs, to_camera / dist, dist);
        if c == Vec3A::ZERO || occluded(ctx, qs, &v) {
            return None;
        }
        raster = Some(cs.raster);
        sampled = Some(v);
        c
    } else if s == 1 {
        let pt = &camera[t - 1];
        if !connectible(ctx, pt) {
            return None;
        }
        let (index, pmf) = ctx.job.lights().choose(u_sel)?;
        let ls = ctx.job.sample_light(ctx.scene, index, pt.p, u)?;
        if ls.li == Vec3A::ZERO || !(ls.pdf > 0.0) {
            return None;
        }
        let infinite = !ls.dist.is_finite();
        let mut v = Vertex::new(Kind::Light, ls.p_light, ls.li / (ls.pdf * pmf));
        v.src = Src::Light(index);
        v.ng = ls.n_light;
        v.ns = ls.n_light;
        v.infinite = infinite;
        v.pdf_fwd = ctx.pdf_light_origin(&v, -ls.wi);
        let f = vertex_f(pt, &camera[t - 2], &v, false);
        let c =
            pt.beta * f * v.beta * pt.ns.dot(ls.wi).abs() * transmittance(ctx, pt, ls.wi, ls.dist);
        if c == Vec3A::ZERO {
            return None;
        }
        let it = pt.it?;
        let (shadow, tmax) = if infinite {
            (it.spawn_ray(ls.wi), f32::INFINITY)
        } else {
            it.spawn_ray_to(ls.p_light, ls.n_light)
        };
        if ctx.scene.occluded_past_interfaces(&shadow, tmax) {
            return None;
        }
        sampled = Some(v);
        c
    } else {
        let (qs, pt) = (&light[s - 1], &camera[t - 1]);
        if !connectible(ctx, qs) || !connectible(ctx, pt) {
            return None;
        }
        // s ≥ 2: qs is a surface vertex of the light subpath.
        let fq = vertex_f(qs, &light[s - 2], pt, true);
        let fp = vertex_f(pt, &camera[t - 2], qs, false);
        let c = qs.beta * fq * fp * pt.beta;
        if c == Vec3A::ZERO {
            return None;
        }
        let gg = g(ctx, qs, pt);
        if gg == Vec3A::ZERO {
            return None;
        }
        c * gg
    };
    if l == Vec3A::ZERO || !l.is_finite() {
        return None;
    }
    let w = mis_weight(ctx, light, camera, sampled, s, t);
    Some((l * w, raster))
}
