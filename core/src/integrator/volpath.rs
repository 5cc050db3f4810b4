//! Volumetric path tracing: the path tracer of [`super::path`] with participating media, after
//! pbrt-v4's `VolPathIntegrator`.
//!
//! A ray carries the medium it travels in: the camera's (the scene's `medium`), then whatever
//! the interior or exterior of the surfaces it crosses says (an object that bounds no medium
//! leaves it unchanged). Along each segment in a medium, [`sample_t_maj`] proposes collisions
//! with the majorant of one colour channel (the *hero* channel, chosen uniformly per camera
//! path); each is an absorption (the path ends), a real scattering (next-event estimation with
//! the phase function, then a new direction sampled from it) or a null collision (the walk goes
//! on), with probabilities σa/σ_maj, σs/σ_maj and σn/σ_maj of the hero channel.
//!
//! Chromatic media (σt differing by channel) use null-scattering MIS over the three channels
//! as pbrt-v4 and Mitsuba 3 do: besides the throughput `beta`, the path keeps `r_u` and `r_l`,
//! the densities of the same path under unidirectional sampling and under light sampling, per
//! channel, divided by the hero channel's unidirectional density. Contributions are divided by
//! the mean of `r_u` (or of `r_u + r_l`, which is also the balance heuristic between light and
//! BSDF or phase sampling), which makes the estimate unbiased in every channel whichever
//! channel drove the walk.
//!
//! Shadow rays cross interface surfaces and media, their transmittance estimated by ratio
//! tracking with the same hero channel (and Russian roulette on small estimates). Surfaces are
//! shaded as in `path`; a dielectric without an `interior` medium keeps its Beer–Lambert
//! absorption, along every stretch inside it (`scene::bodies`), as in `path`.
//!
//! Random numbers: the hero channel is the sampler's first dimension after the camera's; each
//! scattering vertex (surface or medium) takes one 4D set of the sampler (light choice and
//! point, direction) and a hash of it (the light number's refinement, lobe, roulette), as
//! `path` does; the media's decisions (distances, event types, ratio tracking) come from a
//! [`HashRng`] seeded from a hash of the dimension after the hero channel's. All depend on
//! (pixel, sample index, seed) only.

use super::Estimate;
use crate::geometry::{Interaction, Ray};
use crate::material::Bsdf;
use crate::medium::{sample_t_maj, HashRng, HenyeyGreenstein, RandomSource};
use crate::sampling::detmath::exp3;
use crate::sampling::warp::Frame;
use crate::sampling::Sampler;
use crate::scene::bodies::{beer, Bodies};
use crate::{RenderJob, Scene};
use glam::{Vec2, Vec3A};

/// The mean over the colour channels.
#[inline]
fn avg(v: Vec3A) -> f32 {
    v.element_sum() * (1.0 / 3.0)
}

/// Where light is gathered for next-event estimation.
enum Vertex<'a> {
    /// A surface point with its BSDF; `wo` in the shading frame.
    Surface {
        it: &'a Interaction,
        bsdf: &'a Bsdf,
        frame: &'a Frame,
        wo: Vec3A,
    },
    /// A real scattering event in a medium; `wo` in world space (towards the previous vertex).
    Medium {
        p: Vec3A,
        phase: HenyeyGreenstein,
        wo: Vec3A,
    },
}

/// Radiance along `ray`, and whether it left the scene before any vertex (a surface or a
/// medium's real scattering or absorption).
pub fn li(
    scene: &Scene,
    job: &RenderJob,
    mut ray: Ray,
    sampler: &mut Sampler,
    max_depth: u32,
) -> Estimate {
    // The hero channel (a Sobol dimension: stratified over the pixel's samples) and the
    // media's random stream (a hash of the next dimension: no vertex's numbers reuse it).
    let channel = ((sampler.next_1d() * 3.0) as usize).min(2);
    let [u_seed_hi, u_seed_lo, _] = sampler.hashed_3();
    let mut rng = HashRng::new(
        (((u_seed_hi * 16_777_216.0) as u32) << 8) ^ (u_seed_lo * 16_777_216.0) as u32,
    );
    let mut medium = scene.camera_medium;
    let mut bodies = job.starts.camera();

    let mut l = Vec3A::ZERO;
    let mut beta = Vec3A::ONE;
    let mut r_u = Vec3A::ONE;
    let mut r_l = Vec3A::ONE;
    let mut specular = true;
    // The previous scattering vertex, for the light-sampling density of emitters found by
    // BSDF or phase sampling; `None` before the first.
    let mut prev_p: Option<Vec3A> = None;
    let mut eta_scale = 1.0f32;
    let mut depth = 0u32;
    loop {
        let hit = scene.intersect(&ray, f32::INFINITY);

        if let Some(mi) = medium {
            let m = &scene.media[mi as usize];
            let t_max = hit.map_or(f32::INFINITY, |h| h.t);
            let mut scattered: Option<Vec3A> = None;
            let mut terminated = false;
            let t_maj = sample_t_maj(m, &ray, t_max, channel, &mut rng, |c, rng| {
                let (sa, ss, smaj) = (c.props.sigma_a, c.props.sigma_s, c.sigma_maj);
                let p_absorb = sa[channel] / smaj[channel];
                let p_scatter = ss[channel] / smaj[channel];
                let u = rng.next_1d();
                if u < p_absorb {
                    terminated = true;
                    false
                } else if u < p_absorb + p_scatter {
                    if depth >= max_depth {
                        terminated = true;
                        return false;
                    }
                    let pdf = c.t_maj[channel] * ss[channel];
                    if !(pdf > 0.0) {
                        terminated = true;
                        return false;
                    }
                    beta *= c.t_maj * ss / pdf;
                    r_u *= c.t_maj * ss / pdf;
                    scattered = Some(c.p);
                    false
                } else {
                    let sn = (smaj - sa - ss).max(Vec3A::ZERO);
                    let pdf = c.t_maj[channel] * sn[channel];
                    if !(pdf > 0.0) {
                        beta = Vec3A::ZERO;
                        return false;
                    }
                    beta *= c.t_maj * sn / pdf;
                    r_u *= c.t_maj * sn / pdf;
                    r_l *= c.t_maj * smaj / pdf;
                    beta != Vec3A::ZERO && r_u != Vec3A::ZERO
                }
            });
            if terminated || beta == Vec3A::ZERO || r_u == Vec3A::ZERO || !beta.is_finite() {
                break;
            }
            if let Some(p) = scattered {
                // A medium can go on inside a body without an interior medium of its own.
                if scene.absorbs {
                    let sigma = bodies.sigma(scene, true);
                    if sigma != Vec3A::ZERO {
                        beta *= exp3(-sigma * (p - ray.o).dot(ray.d));
                    }
                }
                depth += 1;
                let phase = m.phase();
                let wo = -ray.d;
                sampler.align4();
                let [u_fine, _, _] = sampler.hashed_3();
                let u_light = sampler.next_2d();
                let u_dir = sampler.next_2d();
                let v = Vertex::Medium { p, phase, wo };
                let u_ld = (u_light, u_fine);
                l += beta
                    * sample_ld(
                        scene, job, &v, medium, &bodies, channel, &mut rng, r_u, u_ld,
                    );
                let ps = phase.sample(wo, u_dir);
                if !(ps.pdf > 0.0) {
                    break;
                }
                beta *= ps.value / ps.pdf;
                r_l = r_u / ps.pdf;
                specular = false;
                prev_p = Some(p);
                ray = Ray::new(p, ps.wi);
                continue;
            }
            // The ray got through: T_maj over the pdf of getting through (hero channel).
            let pass = t_maj[channel];
            if !(pass > 0.0) {
                break;
            }
            beta *= t_maj / pass;
            r_u *= t_maj / pass;
            r_l *= t_maj / pass;
        }

        let Some(hit) = hit else {
            if let Some(env) = job.environment() {
                let le = env.radiance(ray.d) * bodies.escape(scene, true);
                match prev_p {
                    Some(_) if !specular => {
                        let env_index = job.lights().environment().unwrap_or(0);
                        let light_pdf = job.lights().pmf(env_index) * env.pdf(ray.d);
                        l += beta * le / avg(r_u + r_l * light_pdf);
                    }
                    _ => l += beta * le / avg(r_u),
                }
            }
            // Escaped before any vertex: the environment seen straight on.
            let escaped = prev_p.is_none();
            return Estimate { l, escaped };
        };
        let it = scene.interaction(&ray, &hit);
        // Beer–Lambert inside a transmissive body without an interior medium (as `path` does).
        if scene.absorbs {
            let sigma = bodies.arrive(scene, &it, ray.d, true);
            if sigma != Vec3A::ZERO {
                beta *= exp3(-sigma * hit.t);
            }
        }
        // An interface: cross into the medium on its other side.
        if scene.is_interface(it.object) {
            medium = scene.medium_after(it.object, it.ng, ray.d, medium);
            ray = it.spawn_ray(ray.d);
            continue;
        }
        let wo_world = -ray.d;
        let le = scene.emitted(&it, wo_world);
        if le != Vec3A::ZERO {
            match prev_p {
                Some(prev) if !specular => {
                    let light_pdf = job.area_light_pdf(scene, &it, prev);
                    l += beta * le / avg(r_u + r_l * light_pdf);
                }
                _ => l += beta * le / avg(r_u),
            }
        }
        if depth >= max_depth {
            break;
        }
        let bsdf = scene.bsdf(&it);
        let frame = it.shading_frame();
        let wo = frame.to_local(wo_world);

        // The layout of `path`: one 4D set per vertex, choices from its hash.
        sampler.align4();
        let [u_fine, u_lobe, u_rr] = sampler.hashed_3();
        let u_light = sampler.next_2d();
        let u_dir = sampler.next_2d();

        if !bsdf.is_delta() {
            let v = Vertex::Surface {
                it: &it,
                bsdf: &bsdf,
                frame: &frame,
                wo,
            };
            let u_ld = (u_light, u_fine);
            l += beta
                * sample_ld(
                    scene, job, &v, medium, &bodies, channel, &mut rng, r_u, u_ld,
                );
        }
        let Some(bs) = bsdf.sample(wo, u_lobe, u_dir) else {
            break;
        };
        if !(bs.pdf > 0.0) {
            break;
        }
        let weight = bs.f * bs.wi.z.abs() / bs.pdf;
        if !weight.is_finite() || weight.max_element() <= 0.0 {
            break;
        }
        beta *= weight;
        r_l = r_u / bs.pdf;
        specular = bs.lobe.is_delta();
        if bs.lobe.is_transmission() {
            eta_scale *= bs.eta * bs.eta;
        }
        let wi = frame.to_world(bs.wi).normalize();
        medium = scene.medium_after(it.object, it.ng, wi, medium);
        if scene.absorbs {
            bodies.leave(scene, &it, wi);
        }
        ray = it.spawn_ray(wi);
        prev_p = Some(it.p);
        depth += 1;
        // Russian roulette on the throughput as the estimate weighs it (pbrt-v4).
        let rr_beta = beta * eta_scale / avg(r_u);
        if depth > 2 && rr_beta.max_element() < 1.0 {
            let q = (1.0 - rr_beta.max_element()).max(0.0);
            if u_rr < q {
                break;
            }
            beta /= 1.0 - q;
        }
    }
    Estimate { l, escaped: false }
}

/// Next-event estimation at `v` (in `medium` if it is a medium vertex; for a surface, the
/// medium on the light's side follows from the surface): one light chosen and a point on it
/// sampled with `(u, jitter)` (see `LightSet::choose_in`), the shadow ray's transmittance
/// through interfaces and media by ratio tracking, weighted against BSDF or phase sampling
/// (balance heuristic, per channel through `r_p`, the path's `r_u`). To be multiplied by the
/// path throughput.
#[allow(clippy::too_many_arguments)]
fn sample_ld<R: RandomSource>(
    scene: &Scene,
    job: &RenderJob,
    v: &Vertex<'_>,
    medium: Option<u32>,
    bodies: &Bodies,
    channel: usize,
    rng: &mut R,
    r_p: Vec3A,
    (u, jitter): (Vec2, f32),
) -> Vec3A {
    let Some((index, pmf, u)) = job.lights().choose_in(u, jitter) else {
        return Vec3A::ZERO;
    };
    let p = match v {
        Vertex::Surface { it, .. } => it.p,
        Vertex::Medium { p, .. } => *p,
    };
    let Some(s) = job.sample_light(scene, index, p, u) else {
        return Vec3A::ZERO;
    };
    if s.li == Vec3A::ZERO || !(s.pdf > 0.0) {
        return Vec3A::ZERO;
    }
    let light_pdf = pmf * s.pdf;
    let (f_hat, scatter_pdf, mut ray, mut t_max, mut medium) = match v {
        Vertex::Surface {
            it,
            bsdf,
            frame,
            wo,
        } => {
            let wi_local = frame.to_local(s.wi);
            let (f, pdf) = bsdf.eval_pdf(*wo, wi_local);
            let (ray, t_max) = if s.dist.is_finite() {
                it.spawn_ray_to(s.p_light, s.n_light)
            } else {
                (it.spawn_ray(s.wi), f32::INFINITY)
            };
            let medium = scene.medium_after(it.object, it.ng, s.wi, medium);
            (f * wi_local.z.abs(), pdf, ray, t_max, medium)
        }
        Vertex::Medium { p, phase, wo } => {
            let f = phase.eval(*wo, s.wi);
            let t_max = if s.dist.is_finite() {
                s.dist * (1.0 - 1e-4)
            } else {
                f32::INFINITY
            };
            (
                Vec3A::splat(f),
                phase.pdf(*wo, s.wi),
                Ray::new(*p, s.wi),
                t_max,
                medium,
            )
        }
    };
    if f_hat.max_element() <= 0.0 {
        return Vec3A::ZERO;
    }
    // Absorption inside the body the shadow ray runs through (bodies block shadow rays, so it
    // is one body all the way).
    let mut f_hat = f_hat;
    if scene.absorbs {
        let sigma = match v {
            Vertex::Surface { it, .. } => bodies.sigma_leaving(scene, it, s.wi, true),
            Vertex::Medium { .. } => bodies.sigma(scene, true),
        };
        if sigma != Vec3A::ZERO {
            f_hat *= beer(sigma, s.dist);
        }
    }
    let weigh = |t_ray: Vec3A, r_l: Vec3A, r_u: Vec3A| {
        let r_l = r_l * r_p * light_pdf;
        let r_u = r_u * r_p * scatter_pdf;
        if s.delta {
            f_hat * t_ray * s.li / avg(r_l)
        } else {
            f_hat * t_ray * s.li / avg(r_l + r_u)
        }
    };
    // Nothing to cross (no medium, no interface in the scene): one any-hit query.
    if medium.is_none() && !scene.has_interfaces {
        return if scene.occluded(&ray, t_max) {
            Vec3A::ZERO
        } else {
            weigh(Vec3A::ONE, Vec3A::ONE, Vec3A::ONE)
        };
    }
    // The shadow ray, surface by surface: interfaces let it through (into the medium on their
    // other side), anything else blocks it; each segment in a medium by ratio tracking.
    let mut t_ray = Vec3A::ONE;
    let mut r_l = Vec3A::ONE;
    let mut r_u = Vec3A::ONE;
    // Each step crosses one surface; the bound keeps a degenerate case from looping.
    for _ in 0..256 {
        let hit = scene.intersect(&ray, t_max);
        if let Some(h) = &hit {
            if !scene.is_interface(h.object) {
                return Vec3A::ZERO;
            }
        }
        if let Some(mi) = medium {
            let seg = hit.map_or(t_max, |h| h.t);
            let t_maj = sample_t_maj(
                &scene.media[mi as usize],
                &ray,
                seg,
                channel,
                rng,
                |c, rng| {
                    let sn = (c.sigma_maj - c.props.sigma_t()).max(Vec3A::ZERO);
                    let pdf = c.t_maj[channel] * c.sigma_maj[channel];
                    if !(pdf > 0.0) {
                        t_ray = Vec3A::ZERO;
                        return false;
                    }
                    t_ray *= c.t_maj * sn / pdf;
                    r_l *= c.t_maj * c.sigma_maj / pdf;
                    r_u *= c.t_maj * sn / pdf;
                    // Russian roulette on small transmittance estimates.
                    let tr = t_ray / avg(r_l + r_u);
                    if tr.max_element() < 0.05 {
                        if rng.next_1d() < 0.75 {
                            t_ray = Vec3A::ZERO;
                        } else {
                            t_ray /= 0.25;
                        }
                    }
                    t_ray != Vec3A::ZERO && t_ray.is_finite()
                },
            );
            let pass = t_maj[channel];
            if !(pass > 0.0) {
                return Vec3A::ZERO;
            }
            t_ray *= t_maj / pass;
            r_l *= t_maj / pass;
            r_u *= t_maj / pass;
        }
        if t_ray == Vec3A::ZERO || !t_ray.is_finite() {
            return Vec3A::ZERO;
        }
        let Some(h) = hit else {
            return weigh(t_ray, r_l, r_u);
        };
        let it = scene.interaction(&ray, &h);
        medium = scene.medium_after(it.object, it.ng, ray.d, medium);
        let next = it.spawn_ray(ray.d);
        t_max -= (next.o - ray.o).dot(ray.d);
        ray = next;
        if !(t_max > 0.0) {
            // The light is at the interface itself.
            return weigh(t_ray, r_l, r_u);
        }
    }
    Vec3A::ZERO
}
