//! Debug and auxiliary outputs: shading normals, albedo, depth and ambient occlusion.
//! Fast previews, and the buffers a denoiser needs.

use super::Estimate;
use crate::geometry::Ray;
use crate::sampling::warp::{cosine_hemisphere, Frame};
use crate::sampling::Sampler;
use crate::{IntegratorKind, RenderJob, Scene};
use glam::Vec3A;

/// Value of debug integrator `kind` along `ray`, and whether the ray met no surface.
pub fn li(
    scene: &Scene,
    job: &RenderJob,
    mut ray: Ray,
    sampler: &mut Sampler,
    kind: IntegratorKind,
) -> Estimate {
    // The first surface that is not an interface (a medium boundary, invisible to every
    // integrator but volpath, as to `path`), and the ray parameter travelled to cross the
    // interfaces in front of it.
    let mut crossed = 0.0f32;
    let (hit, it) = loop {
        let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
            // No surface: a zero normal (a denoiser's "nothing here"), the sky's colour.
            let l = match kind {
                IntegratorKind::Albedo => {
                    unit_colour(job.environment().map_or(Vec3A::ZERO, |e| e.radiance(ray.d)))
                }
                _ => Vec3A::ZERO,
            };
            return Estimate { l, escaped: true };
        };
        let it = scene.interaction(&ray, &hit);
        if scene.is_interface(it.object) {
            let next = it.spawn_ray(ray.d);
            crossed += (next.o - ray.o).dot(ray.d);
            ray = next;
            continue;
        }
        break (hit, it);
    };
    let l = match kind {
        // The world-space shading normal, each component in [-1, 1], as denoisers (Open Image
        // Denoise) and compositors take it.
        IntegratorKind::Normals => it.ns,
        // In [0, 1], as a denoiser takes it: an emitter's is its emission's colour.
        IntegratorKind::Albedo => {
            let e = scene.emitted(&it, -ray.d);
            if e != Vec3A::ZERO {
                unit_colour(e)
            } else {
                scene.bsdf(&it).albedo().clamp(Vec3A::ZERO, Vec3A::ONE)
            }
        }
        // Distance along the primary ray, in scene units.
        IntegratorKind::Depth => Vec3A::splat(crossed + hit.t),
        IntegratorKind::Ao => {
            // One cosine-distributed occlusion ray, reaching a fifth of the scene's size:
            // the estimate of the cosine-weighted visible fraction of the hemisphere.
            let radius = (scene.bounds().diagonal().length() * 0.2).max(1e-3);
            let n = if it.ng.dot(ray.d) > 0.0 {
                -it.ns
            } else {
                it.ns
            };
            let d = Frame::from_z(n).to_world(cosine_hemisphere(sampler.next_2d()));
            if scene.occluded_past_interfaces(&it.spawn_ray(d), radius) {
                Vec3A::ZERO
            } else {
                Vec3A::ONE
            }
        }
        IntegratorKind::Path
        | IntegratorKind::Volpath
        | IntegratorKind::Bdpt
        | IntegratorKind::Sppm
        | IntegratorKind::Whitted => Vec3A::ZERO,
    };
    Estimate { l, escaped: false }
}

/// A radiance's colour as an albedo: scaled so that its largest channel is at most one.
fn unit_colour(c: Vec3A) -> Vec3A {
    let c = c.max(Vec3A::ZERO);
    c / c.max_element().max(1.0)
}
