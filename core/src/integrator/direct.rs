//! Direct lighting: the light a surface point receives straight from the lights, estimated by
//! sampling a point or direction on a light and tracing a shadow ray. Shared by the path tracer
//! (one light chosen by `LightSet::choose_in`, weighted by multiple importance sampling against BSDF sampling),
//! Whitted's tracer (every light, full weight) and `sppm`'s camera paths (full weight at the
//! visible point, delta lights alone on the near-specular surfaces before it).

use crate::geometry::Interaction;
use crate::material::Bsdf;
use crate::sampling::power_heuristic;
use crate::sampling::warp::Frame;
use crate::scene::bodies::{beer, Bodies};
use crate::{RenderJob, Scene};
use glam::{Vec2, Vec3A};

/// Direct light from one light, chosen and sampled with `u` refined by `jitter`
/// ([`LightSet::choose_in`]), MIS-weighted. Returns the contribution (to be multiplied by the
/// path throughput).
///
/// [`LightSet::choose_in`]: crate::light::LightSet::choose_in
#[inline]
#[allow(clippy::too_many_arguments)]
pub(crate) fn sample_one_light(
    scene: &Scene,
    job: &RenderJob,
    it: &Interaction,
    bsdf: &Bsdf,
    frame: &Frame,
    wo: Vec3A,
    bodies: &Bodies,
    u: Vec2,
    jitter: f32,
) -> Vec3A {
    let Some((index, pmf, u)) = job.lights().choose_in(u, jitter) else {
        return Vec3A::ZERO;
    };
    let c = light_contribution(
        scene,
        job,
        it,
        bsdf,
        frame,
        wo,
        bodies,
        index,
        u,
        Counted::Mis,
    );
    c / pmf
}

/// How a light sample counts beside the emitters a path finds by going on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Counted {
    /// Weighted by the power heuristic against BSDF sampling: the path goes on and finds
    /// emitters too (`path`).
    Mis,
    /// In full: nothing else finds the light from here (Whitted's shading, `sppm`'s visible
    /// point).
    Full,
    /// Only a light no ray can hit (point, spot, directional), in full: the path goes on and
    /// finds the others, unweighted (`sppm` through a near-specular surface).
    DeltaOnly,
}

/// Contribution of light `index` sampled once with `u` (without the selection probability),
/// counted as `counted` says, for a path inside `bodies` (whose absorption the shadow ray
/// takes).
#[inline]
#[allow(clippy::too_many_arguments)]
pub(crate) fn light_contribution(
    scene: &Scene,
    job: &RenderJob,
    it: &Interaction,
    bsdf: &Bsdf,
    frame: &Frame,
    wo: Vec3A,
    bodies: &Bodies,
    index: usize,
    u: Vec2,
    counted: Counted,
) -> Vec3A {
    let Some(s) = job.sample_light(scene, index, it.p, u) else {
        return Vec3A::ZERO;
    };
    if s.li == Vec3A::ZERO || !(s.pdf > 0.0) || (counted == Counted::DeltaOnly && !s.delta) {
        return Vec3A::ZERO;
    }
    let wi_local = frame.to_local(s.wi);
    let (f, bsdf_pdf) = bsdf.eval_pdf(wo, wi_local);
    let mut f = f * wi_local.z.abs();
    if f.max_element() <= 0.0 {
        return Vec3A::ZERO;
    }
    if scene.absorbs {
        let sigma = bodies.sigma_leaving(scene, it, s.wi, false);
        if sigma != Vec3A::ZERO {
            f *= beer(sigma, s.dist);
        }
    }
    let (shadow, tmax) = if s.dist.is_finite() {
        it.spawn_ray_to(s.p_light, s.n_light)
    } else {
        (it.spawn_ray(s.wi), f32::INFINITY)
    };
    if scene.occluded_past_interfaces(&shadow, tmax) {
        return Vec3A::ZERO;
    }
    if s.delta || counted != Counted::Mis {
        f * s.li / s.pdf
    } else {
        let w = power_heuristic(s.pdf * job.lights().pmf(index), bsdf_pdf);
        f * s.li * (w / s.pdf)
    }
}
