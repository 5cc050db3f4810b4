//! Unidirectional path tracing with next-event estimation and multiple importance sampling.
//!
//! At each vertex: add emission found by BSDF sampling (MIS-weighted against light sampling),
//! sample one light (chosen by [`LightSet::choose_in`](crate::light::LightSet::choose_in)) and add its contribution if unoccluded (MIS-weighted
//! against BSDF sampling; delta lights and delta BSDFs take full weight), then continue the
//! path by sampling the BSDF. Russian roulette from the third bounce keeps long paths cheap
//! and unbiased. Each bounce draws a fixed number of sample dimensions, so the Sobol
//! dimensions line up across samples.

use super::direct::sample_one_light;
use super::Estimate;
use crate::geometry::{Interaction, Ray};
use crate::sampling::detmath::exp3;
use crate::sampling::{power_heuristic, Sampler};
use crate::{RenderJob, Scene};
use glam::Vec3A;

/// Radiance along `ray`, and whether it left the scene before any vertex.
pub fn li(
    scene: &Scene,
    job: &RenderJob,
    mut ray: Ray,
    sampler: &mut Sampler,
    max_depth: u32,
) -> Estimate {
    let mut l = Vec3A::ZERO;
    let mut beta = Vec3A::ONE;
    let mut specular = true;
    let mut prev_pdf = 0.0f32;
    let mut prev_it: Option<Interaction> = None;
    let mut eta_scale = 1.0f32;
    let mut depth = 0u32;
    let mut bodies = job.starts.camera();
    loop {
        let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
            if let Some(env) = job.environment() {
                let le = env.radiance(ray.d) * bodies.escape(scene, false);
                if specular || prev_it.is_none() {
                    l += beta * le;
                } else {
                    let env_index = job.lights().environment().unwrap_or(0);
                    let light_pdf = job.lights().pmf(env_index) * env.pdf(ray.d);
                    l += beta * le * power_heuristic(prev_pdf, light_pdf);
                }
            }
            // Escaped before any vertex: the environment seen straight on.
            let escaped = prev_it.is_none();
            return Estimate { l, escaped };
        };
        let it = scene.interaction(&ray, &hit);
        let wo_world = -ray.d;
        // Absorption inside the body the stretch ran through.
        if scene.absorbs {
            let sigma = bodies.arrive(scene, &it, ray.d, false);
            if sigma != Vec3A::ZERO {
                beta *= exp3(-sigma * hit.t);
            }
        }
        // An interface (a medium boundary) does not scatter: cross it, as if it were not there.
        if scene.is_interface(it.object) {
            ray = it.spawn_ray(ray.d);
            continue;
        }
        let le = scene.emitted(&it, wo_world);
        if le != Vec3A::ZERO {
            if specular {
                l += beta * le;
            } else if let Some(prev) = prev_it {
                let light_pdf = job.area_light_pdf(scene, &it, prev.p);
                l += beta * le * power_heuristic(prev_pdf, light_pdf);
            }
        }
        if depth >= max_depth {
            break;
        }
        let bsdf = scene.bsdf(&it);
        let frame = it.shading_frame();
        let wo = frame.to_local(wo_world);

        // Fixed dimension layout per bounce, one 4D Sobol set: [light choice and point (2), BSDF
        // direction (2)], the two 2D decisions that stratification helps most (the light is
        // chosen by the first light number, stretched back for the point). Lobe, roulette and
        // the light number's refinement below the Sobol grid come from a hash of the same
        // (pixel, sample, dimension): cheaper than a second Sobol set for choices that gain
        // little from stratification.
        sampler.align4();
        let [u_fine, u_lobe, u_rr] = sampler.hashed_3();
        let u_light = sampler.next_2d();
        let u_dir = sampler.next_2d();

        if !bsdf.is_delta() {
            l += beta
                * sample_one_light(scene, job, &it, &bsdf, &frame, wo, &bodies, u_light, u_fine);
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
        specular = bs.lobe.is_delta();
        prev_pdf = bs.pdf;
        if bs.lobe.is_transmission() {
            eta_scale *= bs.eta * bs.eta;
        }
        let wi = frame.to_world(bs.wi).normalize();
        if scene.absorbs {
            bodies.leave(scene, &it, wi);
        }
        ray = it.spawn_ray(wi);
        prev_it = Some(it);
        depth += 1;
        // Russian roulette on the throughput without radiance scaling at refraction (pbrt-v4).
        let rr_beta = beta * eta_scale;
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
