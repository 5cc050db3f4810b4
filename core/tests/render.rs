//! Rendering correctness, the way pbrt-v4's `integrators_test.cpp` does it: analytic scenes
//! with known radiance run through every integrator that applies, compared with a tolerance
//! derived from the sample count; plus determinism and BVH-versus-brute-force checks on whole
//! scenes.

use glam::{Mat4, Vec3};
use raytile_core::film::{encode, ImageFormat, OutputOptions};
use raytile_core::geometry::Ray;
use raytile_core::scene::desc::*;
use raytile_core::settings::FilterKind;
use raytile_core::{render, IntegratorKind, RenderJob, RenderSettings, Scene};
use std::path::Path;

fn repo(p: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(p)
}

fn camera_at(z: f32) -> CameraDesc {
    CameraDesc {
        name: "cam".into(),
        transform: Mat4::from_translation(Vec3::new(0.0, 0.0, z)),
        projection: Projection::Perspective {
            yfov: 0.8,
            aperture_radius: 0.0,
            focus_distance: z,
        },
        aspect: None,
    }
}

/// A sphere of material `bsdf` inside a uniform environment of radiance 1.
fn furnace(bsdf: BsdfDesc) -> SceneDesc {
    SceneDesc {
        materials: vec![MaterialDesc::new("m", bsdf)],
        objects: vec![ObjectDesc {
            name: "sphere".into(),
            shape: ShapeDesc::Sphere {
                center: Vec3::ZERO,
                radius: 1.0,
            },
            material: 0,
            transform: Mat4::IDENTITY,
            media: None,
        }],
        environment: Some(EnvironmentDesc::Constant {
            radiance: Vec3::ONE,
        }),
        // Close enough that the sphere fills the frame: every pixel sees it.
        cameras: vec![camera_at(1.5)],
        ..Default::default()
    }
}

/// Renders and returns (mean, max |pixel − expected|) over the image's channels.
fn check_furnace(desc: &SceneDesc, integrator: IntegratorKind, spp: u32, expected: f32, tol: f32) {
    let settings = RenderSettings {
        width: 24,
        height: 24,
        spp,
        max_depth: 100,
        integrator,
        ..Default::default()
    };
    let scene = Scene::build(desc).unwrap();
    let job = RenderJob::new(&scene, &settings).unwrap();
    let film = render(&scene, &job, &());
    assert_eq!(film.bad_samples, 0);
    let px = film.resolve();
    let mean: f64 = px.iter().flatten().map(|&v| v as f64).sum::<f64>() / (px.len() * 3) as f64;
    let worst = px
        .iter()
        .flatten()
        .map(|&v| (v - expected).abs())
        .fold(0.0f32, f32::max);
    // The image mean is tight (many pixels); single pixels only catch structural errors.
    assert!(
        (mean as f32 - expected).abs() < tol * 0.25,
        "{integrator:?}: mean {mean}, expected {expected}"
    );
    assert!(
        worst < tol,
        "{integrator:?}: a pixel is off by {worst} (expected {expected})"
    );
}

#[test]
fn white_furnace_lambertian() {
    let white = furnace(BsdfDesc::Diffuse {
        albedo: Vec3::ONE,
        texture: None,
    });
    check_furnace(&white, IntegratorKind::Path, 64, 1.0, 0.08);
    // Whitted samples each light once per camera sample: also unbiased for diffuse surfaces.
    check_furnace(&white, IntegratorKind::Whitted, 256, 1.0, 0.15);
    let grey = furnace(BsdfDesc::Diffuse {
        albedo: Vec3::splat(0.5),
        texture: None,
    });
    check_furnace(&grey, IntegratorKind::Path, 64, 0.5, 0.05);
    check_furnace(&grey, IntegratorKind::Whitted, 256, 0.5, 0.1);
}

#[test]
fn furnace_mirror_and_glass_are_invisible() {
    // A perfect mirror and a clear dielectric (R + T = 1) in a uniform environment.
    let mirror = furnace(BsdfDesc::Mirror {
        reflectance: Vec3::ONE,
    });
    check_furnace(&mirror, IntegratorKind::Path, 4, 1.0, 1e-3);
    check_furnace(&mirror, IntegratorKind::Whitted, 4, 1.0, 1e-3);
    let glass = furnace(BsdfDesc::Dielectric {
        ior: 1.5,
        transmittance: Vec3::ONE,
        absorption: Vec3::ZERO,
        thin: false,
    });
    check_furnace(&glass, IntegratorKind::Path, 256, 1.0, 0.06);
    check_furnace(&glass, IntegratorKind::Whitted, 4, 1.0, 0.01);
}

#[test]
fn furnace_rough_ggx() {
    let conductor = furnace(BsdfDesc::Conductor {
        eta: Vec3::splat(1e-4),
        k: Vec3::splat(1e4),
        alpha: 0.3,
    });
    check_furnace(&conductor, IntegratorKind::Path, 128, 1.0, 0.05);
    let pbr = furnace(BsdfDesc::Pbr(Box::new(PbrDesc {
        base_color: [1.0; 4],
        metallic: 0.0,
        roughness: 0.5,
        ..Default::default()
    })));
    check_furnace(&pbr, IntegratorKind::Path, 128, 1.0, 0.06);
}

/// `scene` rendered by `integrator` at `size` × `size` pixels and `spp` samples.
fn debug_image(scene: &Scene, size: u32, spp: u32, integrator: IntegratorKind) -> Vec<[f32; 3]> {
    let settings = RenderSettings {
        width: size,
        height: size,
        spp,
        integrator,
        ..Default::default()
    };
    let job = RenderJob::new(scene, &settings).unwrap();
    render(scene, &job, &()).resolve()
}

#[test]
fn debug_integrators_give_known_values() {
    let desc = furnace(BsdfDesc::Diffuse {
        albedo: Vec3::new(0.2, 0.4, 0.6),
        texture: None,
    });
    let scene = Scene::build(&desc).unwrap();
    let image = |integrator| debug_image(&scene, 16, 4, integrator);
    let centre = 8 * 16 + 8;
    // The centre pixel sees the sphere: its albedo.
    let c = image(IntegratorKind::Albedo)[centre];
    assert!(
        (c[0] - 0.2).abs() < 1e-5 && (c[2] - 0.6).abs() < 1e-5,
        "{c:?}"
    );
    // The camera is 1.5 from the centre of a unit sphere: the nearest point is 0.5 away.
    let d = image(IntegratorKind::Depth)[centre];
    assert!((d[0] - 0.5).abs() < 0.02, "depth {d:?}");
    // Normals, in [-1, 1] as denoisers take them: the sphere faces the camera (+Z) at the
    // centre, and turns left and right (x below and above 0) towards the edges; up is +Y at
    // the top rows.
    let n = image(IntegratorKind::Normals);
    assert!(
        n[centre][0].abs() < 0.1 && n[centre][1].abs() < 0.1,
        "centre normal {:?}",
        n[centre]
    );
    assert!(n[centre][2] > 0.9, "centre normal {:?}", n[centre]);
    // (The sphere fills the view: at the image's edge the normal is about 0.36 off the axis.)
    let (left, right, top) = (n[8 * 16 + 1], n[8 * 16 + 14], n[16 + 8]);
    assert!(left[0] < -0.1 && right[0] > 0.1, "{left:?} {right:?}");
    assert!((left[0] + right[0]).abs() < 0.04, "{left:?} {right:?}");
    assert!(top[1] > 0.1, "{top:?}");
    // Ambient occlusion: nothing but the sphere, which is convex, so no occlusion ray from its
    // surface can hit anything: exactly 1 everywhere (a self-hit would show as 0).
    let ao = image(IntegratorKind::Ao);
    assert!(
        ao.iter().flatten().all(|&v| v == 1.0),
        "occlusion on a lone convex sphere: {:?}",
        ao.iter().flatten().fold(f32::INFINITY, |a, &b| a.min(b))
    );
}

/// The denoiser buffers keep Open Image Denoise's ranges: an emitter's albedo is its colour in
/// [0, 1] (not its radiance), and where no surface is seen the normal is zero and the albedo
/// black (no sky here).
#[test]
fn denoiser_buffers_keep_their_ranges() {
    let desc = raytile_core::scene::json::parse_json(
        r#"{"render": {"width": 9, "height": 9, "spp": 1},
            "camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "fov": 30},
            "materials": {"lamp": {"type": "emitter", "emission": [40, 20, 0]}},
            "objects": [{"shape": {"type": "sphere", "radius": 0.5}, "material": "lamp"}]}"#,
        Path::new("."),
        Path::new("lamp.json"),
    )
    .unwrap();
    let scene = Scene::build(&desc).unwrap();
    let image = |integrator| debug_image(&scene, 9, 1, integrator);
    let (centre, corner) = (4 * 9 + 4, 0);
    let albedo = image(IntegratorKind::Albedo);
    assert_eq!(albedo[centre], [1.0, 0.5, 0.0]);
    assert_eq!(albedo[corner], [0.0; 3]);
    let normals = image(IntegratorKind::Normals);
    assert_eq!(normals[corner], [0.0; 3]);
    assert!(normals[centre][2] > 0.95, "{:?}", normals[centre]);
}

#[test]
fn ambient_occlusion_darkens_a_corner() {
    // A sphere resting on a floor: the floor next to the contact point is occluded by the
    // sphere, the floor far away is not.
    let mut desc = furnace(BsdfDesc::Diffuse {
        albedo: Vec3::ONE,
        texture: None,
    });
    desc.objects.push(ObjectDesc {
        name: "floor".into(),
        shape: ShapeDesc::Plane {
            point: Vec3::new(0.0, -1.0, 0.0),
            normal: Vec3::Y,
        },
        material: 0,
        transform: Mat4::IDENTITY,
        media: None,
    });
    // Looking straight down at the floor from above, the sphere in the middle.
    desc.cameras = vec![CameraDesc {
        name: "top".into(),
        transform: Mat4::from_translation(Vec3::new(0.0, 4.0, 0.0))
            * Mat4::from_rotation_x(-std::f32::consts::FRAC_PI_2),
        projection: Projection::Orthographic { half_height: 2.0 },
        aspect: None,
    }];
    let settings = RenderSettings {
        width: 32,
        height: 32,
        spp: 64,
        integrator: IntegratorKind::Ao,
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    let job = RenderJob::new(&scene, &settings).unwrap();
    let px = render(&scene, &job, &()).resolve();
    // Pixel columns 0..32 span x ∈ [−2, 2]: column 24 is x ≈ 1.06, just outside the sphere's
    // outline, where the floor sees the sphere over much of its sky; column 31 is x ≈ 1.94.
    let near = px[16 * 32 + 24][0];
    let far = px[16 * 32 + 31][0];
    assert!(near < 0.9 && near < far, "near {near}, far {far}");
}

fn cornell() -> Option<SceneDesc> {
    let p = repo("scenes/cornell-box.json");
    Some(raytile_core::load_scene(&p).expect("scenes/cornell-box.json loads"))
}

fn exr(desc: &SceneDesc, settings: &RenderSettings, threads: usize) -> Vec<u8> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let scene = Scene::build(desc).unwrap();
        let job = RenderJob::new(&scene, settings).unwrap();
        encode(
            &render(&scene, &job, &()),
            ImageFormat::Exr,
            &OutputOptions::default(),
        )
        .unwrap()
    })
}

#[test]
fn tiles_and_threads_never_change_a_bit() {
    let desc = cornell().unwrap();
    for (filter, integrator) in [
        (FilterKind::Box, IntegratorKind::Path),
        (FilterKind::Gaussian, IntegratorKind::Whitted),
    ] {
        let base = RenderSettings {
            width: 40,
            height: 36,
            spp: 6,
            passes: 2,
            max_depth: 8,
            filter,
            integrator,
            seed: 7,
            ..Default::default()
        };
        let a = exr(
            &desc,
            &RenderSettings {
                tile_size: 16,
                ..base.clone()
            },
            1,
        );
        let b = exr(
            &desc,
            &RenderSettings {
                tile_size: 64,
                ..base.clone()
            },
            2,
        );
        let c = exr(
            &desc,
            &RenderSettings {
                tile_size: 7,
                ..base.clone()
            },
            2,
        );
        assert!(
            a == b && b == c,
            "tile size or thread count changed the image ({filter:?})"
        );
        let d = exr(
            &desc,
            &RenderSettings {
                seed: 8,
                ..base.clone()
            },
            2,
        );
        assert_ne!(a, d, "the seed must change the image");
    }
}

#[test]
fn bvh_agrees_with_brute_force_on_whole_scenes() {
    let mut desc = cornell().unwrap();
    // Add an instanced mesh (two objects share mesh 0), analytic shapes and a mirrored object.
    let m0 = match desc.objects[0].shape {
        ShapeDesc::Mesh { mesh } => mesh,
        _ => unreachable!(),
    };
    for (i, t) in [
        Mat4::from_translation(Vec3::new(0.2, 0.1, 0.3)),
        Mat4::from_scale(Vec3::new(-0.3, 0.5, 0.4)),
    ]
    .into_iter()
    .enumerate()
    {
        desc.objects.push(ObjectDesc {
            name: format!("inst{i}"),
            shape: ShapeDesc::Mesh { mesh: m0 },
            material: 0,
            transform: t,
            media: None,
        });
    }
    desc.objects.push(ObjectDesc {
        name: "ball".into(),
        shape: ShapeDesc::Sphere {
            center: Vec3::new(0.3, -0.5, 0.2),
            radius: 0.25,
        },
        material: 0,
        transform: Mat4::from_scale(Vec3::new(1.0, 1.5, 1.0)),
        media: None,
    });
    desc.objects.push(ObjectDesc {
        name: "slab".into(),
        shape: ShapeDesc::Box {
            min: Vec3::splat(-0.1),
            max: Vec3::splat(0.1),
        },
        material: 0,
        transform: Mat4::from_rotation_y(0.7),
        media: None,
    });
    let scene = Scene::build(&desc).unwrap();
    assert!(scene.stats.instanced_triangles > 0);
    let rnd = |i: u32| (raytile_core::sampling::hash_u32(i) >> 8) as f32 / (1 << 24) as f32;
    let mut hits = 0;
    for k in 0..4000u32 {
        let o = glam::Vec3A::new(
            rnd(6 * k) * 2.0 - 1.0,
            rnd(6 * k + 1) * 2.0 - 1.0,
            rnd(6 * k + 2) * 2.0 - 1.0,
        );
        let d = glam::Vec3A::new(
            rnd(6 * k + 3) - 0.5,
            rnd(6 * k + 4) - 0.5,
            rnd(6 * k + 5) - 0.5,
        )
        .normalize();
        let ray = Ray::new(o, d);
        let a = scene.intersect(&ray, f32::INFINITY);
        let b = scene.intersect_brute_force(&ray, f32::INFINITY);
        assert_eq!(a.is_some(), b.is_some(), "ray {k}: {a:?} {b:?} {ray:?}");
        if let (Some(a), Some(b)) = (a, b) {
            // Same distance; the same primitive unless two surfaces coincide there (the boxes
            // stand on the floor, so a ray can meet both at once).
            assert!(
                (a.t - b.t).abs() <= 1e-5 * a.t.max(1.0),
                "ray {k}: {a:?} {b:?}"
            );
            let tie = scene
                .intersect_brute_force(&ray, a.t * (1.0 - 1e-5))
                .is_none()
                && (a.object, a.prim) != (b.object, b.prim);
            assert!(
                (a.object, a.prim) == (b.object, b.prim) || tie,
                "ray {k}: {a:?} {b:?}"
            );
            hits += 1;
        }
        assert_eq!(scene.occluded(&ray, f32::INFINITY), b.is_some());
    }
    assert!(
        hits > 3000,
        "the rays start inside the closed box: almost all hit ({hits})"
    );
}

#[test]
fn cornell_box_is_lit_and_finite() {
    let desc = cornell().unwrap();
    let settings = RenderSettings {
        width: 32,
        height: 32,
        spp: 16,
        max_depth: 64,
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    let job = RenderJob::new(&scene, &settings).unwrap();
    let film = render(&scene, &job, &());
    assert_eq!(film.bad_samples, 0);
    let m = film.mean();
    // Red wall on the left, green on the right: colour bleeding shows in the channel means.
    assert!(m[0] > 0.1 && m[1] > 0.1 && m[2] > 0.05, "{m:?}");
}

#[test]
fn every_example_scene_loads_and_renders() {
    let dir = repo("scenes");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("json") {
            continue;
        }
        let desc = raytile_core::load_scene(&path).unwrap_or_else(|e| panic!("{e}"));
        for integrator in IntegratorKind::ALL {
            let settings = RenderSettings {
                width: 12,
                height: 8,
                spp: 2,
                integrator,
                ..Default::default()
            };
            let scene = Scene::build(&desc).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            let job = match RenderJob::new(&scene, &settings) {
                Ok(job) => job,
                // sppm refuses an unbounded plane under the sun or the sky (classic, fog).
                Err(e)
                    if integrator == IntegratorKind::Sppm
                        && e.to_string()
                            .contains("sppm cannot render an unbounded plane") =>
                {
                    continue
                }
                Err(e) => panic!("{} {integrator:?}: {e}", path.display()),
            };
            let film = render(&scene, &job, &());
            assert_eq!(film.bad_samples, 0, "{} {integrator:?}", path.display());
        }
        n += 1;
    }
    assert!(n >= 3, "expected the example scenes in {}", dir.display());
}

#[test]
fn bad_scenes_are_errors_not_panics() {
    let mut desc = furnace(BsdfDesc::Diffuse {
        albedo: Vec3::ONE,
        texture: None,
    });
    desc.objects[0].material = 5;
    assert!(Scene::build(&desc)
        .unwrap_err()
        .to_string()
        .contains("material index 5"));
    let mut desc = furnace(BsdfDesc::Diffuse {
        albedo: Vec3::ONE,
        texture: None,
    });
    desc.objects[0].shape = ShapeDesc::Sphere {
        center: Vec3::NAN,
        radius: 1.0,
    };
    assert!(Scene::build(&desc).is_err());
    let mut desc = furnace(BsdfDesc::Diffuse {
        albedo: Vec3::ONE,
        texture: None,
    });
    desc.objects[0].transform = Mat4::ZERO;
    assert!(Scene::build(&desc)
        .unwrap_err()
        .to_string()
        .contains("singular"));
    let mut desc = furnace(BsdfDesc::Diffuse {
        albedo: Vec3::ONE,
        texture: None,
    });
    desc.meshes.push(MeshDesc {
        name: "m".into(),
        positions: vec![Vec3::ZERO; 3],
        colors: Vec::new(),
        indices: vec![[0, 1, 7]],
        ..Default::default()
    });
    desc.objects[0].shape = ShapeDesc::Mesh { mesh: 0 };
    assert!(Scene::build(&desc)
        .unwrap_err()
        .to_string()
        .contains("out of range"));
    // What is wrong with the job, not the scene, is the job's error.
    let desc = furnace(BsdfDesc::Diffuse {
        albedo: Vec3::ONE,
        texture: None,
    });
    let scene = Scene::build(&desc).unwrap();
    let s = RenderSettings {
        camera: Some("nope".into()),
        ..Default::default()
    };
    let e = RenderJob::new(&scene, &s).unwrap_err().to_string();
    assert!(
        e.starts_with("render setting camera: the scene has no camera named or numbered 'nope'"),
        "{e}"
    );
    let s = RenderSettings {
        spp: 0,
        ..Default::default()
    };
    assert!(RenderJob::new(&scene, &s)
        .unwrap_err()
        .to_string()
        .contains("spp"));
}

/// A tile render watches its cancel flag: set from another thread, the render stops within a
/// fraction of a second (a worker is free for the next task), and a render nobody cancels gives
/// the same bits as the whole-frame render's tile.
#[test]
fn a_cancelled_tile_render_stops_soon_and_an_uncancelled_one_is_unchanged() {
    use raytile_core::{render_tile, Cancel, Cancelled, Tile};
    let desc = furnace(BsdfDesc::Diffuse {
        albedo: Vec3::splat(0.5),
        texture: None,
    });
    let scene = Scene::build(&desc).unwrap();
    let settings = RenderSettings {
        width: 16,
        height: 16,
        spp: 4,
        max_depth: 100,
        tile_size: 16,
        ..Default::default()
    };
    let job = RenderJob::new(&scene, &settings).unwrap();
    let tile = Tile {
        x0: 0,
        y0: 0,
        x1: 16,
        y1: 16,
    };
    let film = render(&scene, &job, &());
    let acc = render_tile(&scene, &job, tile, 0..4, &Cancel::new()).unwrap();
    let mut one = raytile_core::Film::new(16, 16);
    one.add_tile(&acc).unwrap();
    let bits = |f: &raytile_core::Film| -> Vec<u32> {
        f.pixels.iter().flatten().map(|v| v.to_bits()).collect()
    };
    assert_eq!(bits(&one), bits(&film));
    // Samples enough for minutes: cancelled after 200 ms, it returns at once.
    let cancel = Cancel::new();
    let t = std::time::Instant::now();
    let r = std::thread::scope(|s| {
        let h = s.spawn(|| render_tile(&scene, &job, tile, 0..1 << 24, &cancel));
        std::thread::sleep(std::time::Duration::from_millis(200));
        cancel.cancel();
        h.join().unwrap()
    });
    let took = t.elapsed();
    assert_eq!(r.map(|_| ()), Err(Cancelled));
    assert!(
        took < std::time::Duration::from_secs(2),
        "stopped after {took:?}"
    );
}
