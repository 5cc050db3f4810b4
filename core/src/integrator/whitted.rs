//! Whitted's recursive ray tracer, as in the lecture: at each hit, shadow rays to every light
//! for the local (diffuse and glossy) part, then recursive rays for perfect reflection and
//! refraction, weighted by Fresnel. Recursion stops at the maximum depth, when the ray leaves
//! the scene, or when the ray's contribution falls below [`DAMPING`] (ray damping).
//!
//! Area and environment lights are sampled once per light per camera sample (so soft shadows
//! converge with more samples); point, spot and directional lights give hard shadows.

use super::direct::{light_contribution, Counted};
use super::Estimate;
use crate::geometry::Ray;
use crate::material::{fresnel_dielectric, refract, Bsdf};
use crate::sampling::detmath::exp3;
use crate::sampling::Sampler;
use crate::scene::bodies::Bodies;
use crate::{RenderJob, Scene};
use glam::Vec3A;

/// Contributions below this (per channel, relative to the camera ray) are not traced further.
pub const DAMPING: f32 = 1e-3;

/// Radiance along `ray`, and whether it left the scene without meeting a surface.
pub fn li(
    scene: &Scene,
    job: &RenderJob,
    ray: Ray,
    sampler: &mut Sampler,
    max_depth: u32,
) -> Estimate {
    let bodies = job.starts.camera();
    let mut escaped = false;
    let l = trace(
        scene,
        job,
        ray,
        sampler,
        max_depth,
        0,
        Vec3A::ONE,
        bodies,
        &mut escaped,
    );
    Estimate { l, escaped }
}

/// Radiance along `ray`, which starts inside `bodies`; `escaped` is set where a ray of the
/// camera's (depth 0, through interfaces) leaves the scene.
#[allow(clippy::too_many_arguments)]
fn trace(
    scene: &Scene,
    job: &RenderJob,
    ray: Ray,
    sampler: &mut Sampler,
    max_depth: u32,
    depth: u32,
    weight: Vec3A,
    mut bodies: Bodies,
    escaped: &mut bool,
) -> Vec3A {
    let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
        *escaped = depth == 0;
        let le = job.environment().map_or(Vec3A::ZERO, |e| e.radiance(ray.d));
        return le * bodies.escape(scene, false);
    };
    let it = scene.interaction(&ray, &hit);
    // Absorption inside the body the ray ran through.
    let mut transmittance = Vec3A::ONE;
    if scene.absorbs {
        let sigma = bodies.arrive(scene, &it, ray.d, false);
        if sigma != Vec3A::ZERO {
            transmittance = exp3(-sigma * hit.t);
        }
    }
    // An interface (a medium boundary) does not scatter: cross it.
    if scene.is_interface(it.object) {
        let next = it.spawn_ray(ray.d);
        let w = weight * transmittance;
        let li = trace(
            scene, job, next, sampler, max_depth, depth, w, bodies, escaped,
        );
        return li * transmittance;
    }
    let wo_world = -ray.d;
    let mut l = scene.emitted(&it, wo_world);
    let bsdf = scene.bsdf(&it);
    let frame = it.shading_frame();
    let wo = frame.to_local(wo_world);

    // Local illumination: a shadow ray to every light.
    if !bsdf.is_delta() {
        for i in 0..job.lights().len() {
            let u = sampler.next_2d();
            let c = Counted::Full;
            l += light_contribution(scene, job, &it, &bsdf, &frame, wo, &bodies, i, u, c);
        }
    }
    if depth >= max_depth {
        return l * transmittance;
    }
    let recurse = |dir_local: Vec3A, factor: Vec3A, sampler: &mut Sampler| -> Vec3A {
        let w = weight * factor * transmittance;
        if w.max_element() < DAMPING {
            return Vec3A::ZERO;
        }
        let d = frame.to_world(dir_local).normalize();
        let mut inside = bodies;
        if scene.absorbs {
            inside.leave(scene, &it, d);
        }
        let next = it.spawn_ray(d);
        let deeper = &mut false;
        factor
            * trace(
                scene,
                job,
                next,
                sampler,
                max_depth,
                depth + 1,
                w,
                inside,
                deeper,
            )
    };
    match bsdf {
        Bsdf::Mirror(m) => {
            let r = Vec3A::new(-wo.x, -wo.y, wo.z);
            l += recurse(r, m.reflectance, sampler);
        }
        Bsdf::Dielectric(d) if !d.thin => {
            // Both branches, weighted by exact Fresnel: the classic ray tree.
            let f = fresnel_dielectric(wo.z, d.eta);
            let r = Vec3A::new(-wo.x, -wo.y, wo.z);
            l += recurse(r, Vec3A::splat(f), sampler);
            if f < 1.0 {
                if let Some((t, eta_rel)) = refract(wo, Vec3A::Z, d.eta) {
                    // Radiance scales by 1/η² crossing into the denser side.
                    let t = t.normalize();
                    l += recurse(
                        t,
                        d.transmittance * ((1.0 - f) / (eta_rel * eta_rel)),
                        sampler,
                    );
                }
            }
        }
        b if b.is_delta() => {
            // Other perfectly specular surfaces (smooth metals, thin glass): follow one sampled
            // branch, weighted so the estimate stays unbiased.
            let u_lobe = sampler.next_1d();
            let u = sampler.next_2d();
            if let Some(bs) = b.sample(wo, u_lobe, u) {
                if bs.pdf > 0.0 {
                    l += recurse(bs.wi, bs.f * bs.wi.z.abs() / bs.pdf, sampler);
                }
            }
        }
        _ => {}
    }
    l * transmittance
}
