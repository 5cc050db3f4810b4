//! Bad values in scenes and jobs: refused when loaded, with one message naming the field, and
//! never a non-finite pixel, whatever light a render is given.

use glam::{Mat4, Vec3, Vec3A};
use raytile_core::light::Environment;
use raytile_core::scene::desc::*;
use raytile_core::{render, IntegratorKind, RenderJob, RenderSettings, Scene};
use std::sync::Arc;

fn camera() -> CameraDesc {
    CameraDesc {
        name: "cam".into(),
        transform: Mat4::from_translation(Vec3::new(0.0, 0.0, 3.0)),
        projection: Projection::Perspective {
            yfov: 0.8,
            aperture_radius: 0.0,
            focus_distance: 3.0,
        },
        aspect: None,
    }
}

/// A diffuse ball under a grey sky.
fn ball() -> SceneDesc {
    SceneDesc {
        materials: vec![MaterialDesc::new(
            "m",
            BsdfDesc::Diffuse {
                albedo: Vec3::splat(0.5),
                texture: None,
            },
        )],
        objects: vec![ObjectDesc {
            name: "ball".into(),
            shape: ShapeDesc::Sphere {
                center: Vec3::ZERO,
                radius: 1.0,
            },
            material: 0,
            transform: Mat4::IDENTITY,
            media: None,
        }],
        environment: Some(EnvironmentDesc::Constant {
            radiance: Vec3::splat(0.5),
        }),
        cameras: vec![camera()],
        ..Default::default()
    }
}

fn small(integrator: IntegratorKind) -> RenderSettings {
    RenderSettings {
        width: 8,
        height: 8,
        spp: 8,
        max_depth: 4,
        integrator,
        ..Default::default()
    }
}

/// Light far brighter than any scene may give (a program can still hand it to a job) makes
/// samples too large to add up: they are dropped and counted, and every pixel stays finite.
#[test]
fn huge_finite_light_never_makes_a_non_finite_pixel() {
    let scene = Scene::build(&ball()).unwrap();
    for integrator in [
        IntegratorKind::Path,
        IntegratorKind::Bdpt,
        IntegratorKind::Sppm,
        IntegratorKind::Whitted,
    ] {
        for radiance in [3e38f32, 1e34] {
            let mut settings = small(integrator);
            if integrator == IntegratorKind::Sppm {
                settings.passes = 1;
            }
            let env = Environment::constant(Vec3A::splat(radiance));
            let job = RenderJob::new(&scene, &settings)
                .unwrap()
                .with_environment(&scene, Some(Arc::new(env)));
            let film = render(&scene, &job, &());
            for (i, p) in film.resolve().iter().enumerate() {
                assert!(
                    p.iter().all(|c| c.is_finite()),
                    "{integrator:?}, radiance {radiance}: pixel {i} is {p:?}"
                );
            }
            assert!(
                film.bad_samples > 0,
                "{integrator:?}, radiance {radiance}: no sample was dropped"
            );
        }
    }
}
