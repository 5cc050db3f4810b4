//! Bad values in scenes and jobs: refused when loaded, with one message naming the field, and
//! never a non-finite pixel, whatever light a render is given.

use glam::{Mat4, Vec3, Vec3A};
use raytile_core::light::Environment;
use raytile_core::scene::desc::*;
use raytile_core::scene::files::SceneFiles;
use raytile_core::scene::json::parse_json;
use raytile_core::settings::EnvironmentChoice;
use raytile_core::{render, IntegratorKind, RenderJob, RenderSettings, Scene};
use std::path::Path;
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
                .with_environment(&scene, Some(Arc::new(env)))
                .unwrap();
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

/// The error of loading the JSON scene `text` (a sphere, a camera and what `extra` adds).
fn json_error(extra: &str) -> String {
    let text = format!(
        r#"{{
  "camera": {{"position": [0, 0, 3], "look_at": [0, 0, 0]}},
  "materials": {{"white": {{"type": "diffuse"}}}},
  "objects": [{{"shape": {{"type": "sphere"}}, "material": "white"}}]{extra}
}}"#
    );
    match parse_json(&text, Path::new("."), Path::new("scene.json")) {
        Ok(desc) => match Scene::build(&desc) {
            Ok(_) => panic!("accepted: {extra}"),
            Err(e) => panic!("refused only when built ({e}): {extra}"),
        },
        Err(e) => e.to_string(),
    }
}

/// Checks that `extra` is refused with a message holding every needle.
fn refused(extra: &str, needles: &[&str]) {
    let e = json_error(extra);
    for n in needles {
        assert!(e.contains(n), "{extra}: error {e:?} does not mention {n:?}");
    }
}

#[test]
fn light_values_must_be_finite_non_negative_and_at_most_the_largest_radiance() {
    let huge = ["at most 1e30", "3e38"];
    let env = |v: &str| format!(r#", "environment": {{"type": "constant", "radiance": {v}}}"#);
    refused(
        &env("[3e38, 0, 0]"),
        &[&["environment.radiance"], &huge[..]].concat(),
    );
    // 1e39 is infinite as an f32.
    refused(&env("[1e39, 0, 0]"), &["environment.radiance", "finite"]);
    refused(
        &env("[-1, -1, -1]"),
        &["environment.radiance", "non-negative"],
    );
    let emitter = |v: &str| {
        let text = format!(
            r#"{{"camera": {{"position": [0, 0, 3], "look_at": [0, 0, 0]}},
  "materials": {{"lamp": {{"type": "emitter", "emission": {v}}}}},
  "objects": [{{"shape": {{"type": "sphere"}}, "material": "lamp"}}]}}"#
        );
        parse_json(&text, Path::new("."), Path::new("scene.json"))
            .unwrap_err()
            .to_string()
    };
    let e = emitter("[1e31, 1, 1]");
    assert!(
        e.contains("materials.lamp.emission") && e.contains("at most 1e30"),
        "{e}"
    );
    let e = emitter("[-1, 1, 1]");
    assert!(
        e.contains("materials.lamp.emission") && e.contains("non-negative"),
        "{e}"
    );
    let light = |l: &str| format!(r#", "lights": [{l}]"#);
    refused(
        &light(r#"{"type": "point", "position": [0, 2, 0], "intensity": [-10, -10, -10]}"#),
        &["lights[0].intensity", "non-negative"],
    );
    refused(
        &light(
            r#"{"type": "spot", "position": [0, 2, 0], "direction": [0, -1, 0], "intensity": [1e31, 1, 1]}"#,
        ),
        &["lights[0].intensity", "at most 1e30"],
    );
    refused(
        &light(r#"{"type": "directional", "direction": [0, -1, 0], "irradiance": [1, 1e39, 1]}"#),
        &["lights[0].irradiance", "finite"],
    );
    refused(
        &light(r#"{"type": "directional", "direction": [0, -1, 0], "irradiance": [1, -1, 1]}"#),
        &["lights[0].irradiance", "non-negative"],
    );
}

/// Descriptions made by a program are held to the same rules when the scene is built.
#[test]
fn descriptions_with_bad_light_values_do_not_build() {
    let build_err = |desc: &SceneDesc| match Scene::build(desc) {
        Ok(_) => panic!("built"),
        Err(e) => e.to_string(),
    };
    let mut d = ball();
    d.environment = Some(EnvironmentDesc::Constant {
        radiance: Vec3::splat(1e38),
    });
    let e = build_err(&d);
    assert!(
        e.contains("environment") && e.contains("at most 1e30"),
        "{e}"
    );
    d.environment = Some(EnvironmentDesc::Constant {
        radiance: Vec3::splat(-1.0),
    });
    assert!(build_err(&d).contains("non-negative"));
    let mut d = ball();
    d.materials[0].emission = Vec3::new(-1.0, 1.0, 1.0);
    let e = build_err(&d);
    assert!(e.contains("material 'm'") && e.contains("emission"), "{e}");
    let mut d = ball();
    d.lights.push(LightDesc::Point {
        position: Vec3::Y * 3.0,
        intensity: Vec3::splat(-5.0),
        range: f32::INFINITY,
    });
    let e = build_err(&d);
    assert!(e.contains("light 0") && e.contains("intensity"), "{e}");
    // A map's texels: not too bright once scaled; NaN, infinite and negative ones are read as
    // zero (real skies hold a few), not refused.
    let map = |texel: [f32; 4], scale: f32| {
        let mut d = ball();
        d.environment = Some(EnvironmentDesc::Map {
            texture: TextureDesc {
                name: "sky.exr".into(),
                width: 2,
                height: 1,
                texels: vec![[0.5; 4], texel].into(),
                srgb: false,
                wrap_u: WrapMode::Repeat,
                wrap_v: WrapMode::Clamp,
                bilinear: true,
            },
            scale,
            rotation_y: 0.0,
        });
        Scene::build(&d).map(|_| ()).map_err(|e| e.to_string())
    };
    map([2.0, 2.0, 2.0, 1.0], 1e29).unwrap();
    let e = map([2.0, 2.0, 2.0, 1.0], 1e30).unwrap_err();
    assert!(
        e.contains("sky.exr") && e.contains("texel (1, 0)") && e.contains("at most 1e30"),
        "{e}"
    );
    map([f32::INFINITY, f32::NAN, 0.0, 1.0], 1.0).unwrap();
    map([-0.5, 0.0, 0.0, 1.0], 1.0).unwrap();
}

/// A Radiance `.hdr` file of `w × 1` texels given as RGBE bytes.
fn hdr_file(dir: &Path, name: &str, texels: &[[u8; 4]]) -> std::path::PathBuf {
    let mut bytes = format!(
        "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X {}\n",
        texels.len()
    )
    .into_bytes();
    bytes.extend(texels.iter().flatten());
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn temp_dir(tag: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("raytile-validation-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A job's own environment is held to the same bound, colour or map, strength included.
#[test]
fn a_jobs_environment_times_its_strength_must_not_be_too_bright() {
    let scene = Scene::build(&ball()).unwrap();
    let job = |environment: EnvironmentChoice, strength: f32| {
        let settings = RenderSettings {
            environment: Some(environment),
            environment_strength: strength,
            ..small(IntegratorKind::Path)
        };
        RenderJob::with_files(&scene, &settings, &SceneFiles::trusted(), Path::new("."))
            .map(|_| ())
            .map_err(|e| e.to_string())
    };
    job(EnvironmentChoice::Constant([1e15; 3]), 1e15).unwrap();
    let e = job(EnvironmentChoice::Constant([1e20, 1.0, 1.0]), 1e20).unwrap_err();
    assert!(
        e.contains("environment_strength") && e.contains("at most 1e30"),
        "{e}"
    );
    let e = job(EnvironmentChoice::Constant([1.0; 3]), 1e38).unwrap_err();
    assert!(e.contains("at most 1e30"), "{e}");
    let dir = temp_dir("maps");
    // RGBE (128, 128, 128, 129) is 1.0; (255, 255, 255, 255) is about 1.7e38.
    let ordinary = hdr_file(&dir, "ordinary.hdr", &[[128, 128, 128, 129]; 2]);
    let brightest = hdr_file(
        &dir,
        "brightest.hdr",
        &[[128, 128, 128, 129], [255, 0, 0, 255]],
    );
    let map = |p: &Path| EnvironmentChoice::Map(p.display().to_string());
    job(map(&ordinary), 1e30).unwrap();
    let e = job(map(&ordinary), 1e31).unwrap_err();
    assert!(
        e.contains("ordinary.hdr")
            && e.contains("environment_strength")
            && e.contains("at most 1e30"),
        "{e}"
    );
    let e = job(map(&brightest), 1.0).unwrap_err();
    assert!(
        e.contains("brightest.hdr") && e.contains("texel (1, 0)"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn cameras_must_have_a_view_and_a_lens() {
    let cam = |fields: &str| {
        json_error(&format!(
            r#", "cameras": [{{"position": [0, 0, 3], "look_at": [0, 0, 0]{fields}}}]"#
        ))
    };
    let refused = |fields: &str, needles: &[&str]| {
        let e = cam(fields);
        for n in needles {
            assert!(
                e.contains(n),
                "{fields}: error {e:?} does not mention {n:?}"
            );
        }
    };
    refused(
        r#", "type": "orthographic", "half_height": 0"#,
        &["cameras[0].half_height", "positive"],
    );
    refused(
        r#", "type": "orthographic", "half_height": -2"#,
        &["cameras[0].half_height"],
    );
    refused(
        r#", "aperture": -0.1"#,
        &["cameras[0].aperture", "non-negative"],
    );
    refused(r#", "focus_distance": -3"#, &["cameras[0].focus_distance"]);
    refused(
        r#", "aperture": 0.1, "focus_distance": 0"#,
        &["cameras[0].focus_distance", "positive"],
    );
    // A pinhole, and a focus distance of 0 with it, are fine.
    let ok = r#"{"cameras": [{"position": [0, 0, 3], "look_at": [0, 0, 0], "aperture": 0, "focus_distance": 0},
        {"type": "orthographic", "position": [0, 0, 3], "look_at": [0, 0, 0], "half_height": 2}]}"#;
    let desc = parse_json(ok, Path::new("."), Path::new("scene.json")).unwrap();
    Scene::build(&desc).unwrap();
    // The same rules for descriptions made by a program, and a camera's transform must
    // have a direction.
    let build_err = |c: CameraDesc| {
        let mut d = ball();
        d.cameras = vec![c];
        Scene::build(&d).map(|_| ()).unwrap_err().to_string()
    };
    let e = build_err(CameraDesc {
        projection: Projection::Orthographic { half_height: 0.0 },
        ..camera()
    });
    assert!(
        e.contains("camera 0 ('cam')") && e.contains("half_height"),
        "{e}"
    );
    let e = build_err(CameraDesc {
        transform: Mat4::from_scale(Vec3::ZERO),
        ..camera()
    });
    assert!(e.contains("camera 0") && e.contains("singular"), "{e}");
    let mut projective = camera().transform;
    projective.x_axis.w = 0.5;
    let e = build_err(CameraDesc {
        transform: projective,
        ..camera()
    });
    assert!(e.contains("last row"), "{e}");
}

#[test]
fn spot_cones_must_be_ordered_and_at_most_a_right_angle() {
    let spot = |inner: f32, outer: f32| {
        format!(
            r#", "lights": [{{"type": "spot", "position": [0, 2, 0], "direction": [0, -1, 0], "intensity": [10, 10, 10], "inner_angle": {inner}, "outer_angle": {outer}}}]"#
        )
    };
    refused(
        &spot(60.0, 10.0),
        &["lights[0].inner_angle", "outer_angle (10 degrees), got 60"],
    );
    refused(&spot(-5.0, 10.0), &["lights[0].inner_angle"]);
    refused(&spot(0.0, 120.0), &["lights[0].outer_angle", "at most 90"]);
    refused(&spot(0.0, 0.0), &["lights[0].outer_angle"]);
    let mut d = ball();
    d.lights.push(LightDesc::Spot {
        position: Vec3::Y * 3.0,
        direction: Vec3::NEG_Y,
        intensity: Vec3::ONE,
        inner_angle: 1.0,
        outer_angle: 0.2,
        range: f32::INFINITY,
    });
    let e = Scene::build(&d).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("light 0") && e.contains("inner_angle"), "{e}");
    // A hard-edged cone (inner = outer) is fine.
    let text = format!(
        r#"{{"camera": {{"position": [0, 0, 3], "look_at": [0, 0, 0]}}{}}}"#,
        spot(30.0, 30.0)
    );
    parse_json(&text, Path::new("."), Path::new("scene.json")).unwrap();
}

#[test]
fn transforms_must_be_affine() {
    let matrix = |last: &str| {
        format!(
            r#", "objects": [{{"shape": {{"type": "sphere"}}, "material": "white", "transform": {{"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], {last}]}}}}]"#
        )
    };
    // `objects` is given twice in `json_error`'s text: use a scene of its own.
    let load = |last: &str| {
        let text = format!(
            r#"{{"camera": {{"position": [0, 0, 3], "look_at": [0, 0, 0]}},
  "materials": {{"white": {{"type": "diffuse"}}}}{}}}"#,
            matrix(last)
        );
        parse_json(&text, Path::new("."), Path::new("scene.json")).map_err(|e| e.to_string())
    };
    let e = load("[0, 0.5, 0, 1]").unwrap_err();
    assert!(
        e.contains("objects[0].transform") && e.contains("last row"),
        "{e}"
    );
    let e = load("[0, 0, 0, 2]").unwrap_err();
    assert!(e.contains("last row"), "{e}");
    // Rounding in the last row is tolerated.
    load("[0, 0, 1e-8, 1.0000001]").unwrap();
    let mut d = ball();
    d.objects[0].transform.z_axis.w = -1.0;
    let e = Scene::build(&d).map(|_| ()).unwrap_err().to_string();
    assert!(
        e.contains("object 0 ('ball')") && e.contains("last row"),
        "{e}"
    );
}

#[test]
fn material_parameters_must_be_in_their_ranges() {
    let material = |m: &str| {
        let text = format!(
            r#"{{"camera": {{"position": [0, 0, 3], "look_at": [0, 0, 0]}},
  "materials": {{"m": {m}}},
  "objects": [{{"shape": {{"type": "sphere"}}, "material": "m"}}]}}"#
        );
        parse_json(&text, Path::new("."), Path::new("scene.json")).map_err(|e| e.to_string())
    };
    let refused = |m: &str, needles: &[&str]| {
        let e = material(m).unwrap_err();
        for n in needles {
            assert!(e.contains(n), "{m}: error {e:?} does not mention {n:?}");
        }
    };
    // Each material, then after `=>` the field its error must name and what else it must
    // mention (separated by `|`).
    for row in [
        r#"{"type": "metal", "roughness": -0.3} => roughness|between 0 and 1"#,
        r#"{"type": "metal", "roughness": 1.5} => roughness"#,
        r#"{"type": "frosted_glass", "roughness": -1} => roughness"#,
        r#"{"type": "pbr", "metallic": 5} => metallic|got 5"#,
        r#"{"type": "pbr", "roughness": -2} => roughness|got -2"#,
        r#"{"type": "pbr", "transmission": 2} => transmission"#,
        r#"{"type": "pbr", "ior": 0} => ior|positive"#,
        r#"{"type": "glass", "ior": 0} => ior|positive"#,
        r#"{"type": "glass", "absorption": [0.1, -0.5, 0]} => absorption|non-negative"#,
        // Colours that reflect or transmit more than all, or less than none, of the light.
        r#"{"type": "diffuse", "albedo": [1.2, 0.5, 0.5]} => albedo|1.2"#,
        r#"{"type": "diffuse", "albedo": [0.5, -0.1, 0.5]} => albedo|-0.1"#,
        r#"{"type": "mirror", "reflectance": [0, 0, 2]} => reflectance|2"#,
        r#"{"type": "glass", "transmittance": [1, 1, 1.5]} => transmittance|1.5"#,
        r#"{"type": "frosted_glass", "transmittance": [-1, 1, 1]} => transmittance|-1"#,
        r#"{"type": "pbr", "base_color": [0.8, 3, 0.8]} => base_color|3"#,
        r#"{"type": "metal", "eta": [0, 1, 1]} => eta|positive"#,
        r#"{"type": "metal", "k": [1, -2, 1]} => k|non-negative"#,
    ] {
        let (m, needles) = row
            .split_once(" => ")
            .expect("a material => what its error says");
        let mut needles: Vec<String> = needles.split('|').map(str::to_string).collect();
        needles[0] = format!("materials.m.{}", needles[0]);
        refused(m, &needles.iter().map(String::as_str).collect::<Vec<_>>());
    }
    for ok in [
        r#"{"type": "diffuse", "albedo": [1, 0, 1]}"#,
        r#"{"type": "mirror", "reflectance": [0, 0, 0]}"#,
        r#"{"type": "metal", "eta": [0.2, 0.9, 1.1], "k": [0, 0, 0]}"#,
        r#"{"type": "metal", "roughness": 0}"#,
        r#"{"type": "metal", "preset": "gold", "roughness": 1}"#,
        r#"{"type": "pbr", "metallic": 1, "roughness": 0, "ior": 1.33, "transmission": 1}"#,
        r#"{"type": "glass", "ior": 0.75, "absorption": [0.1, 0.5, 0]}"#,
    ] {
        Scene::build(&material(ok).unwrap()).unwrap();
    }
    // Descriptions made by a program: the same rules when built.
    let build_err = |bsdf: BsdfDesc| {
        let mut d = ball();
        d.materials[0].bsdf = bsdf;
        Scene::build(&d).map(|_| ()).unwrap_err().to_string()
    };
    let e = build_err(BsdfDesc::Pbr(Box::new(PbrDesc {
        metallic: 5.0,
        ..PbrDesc::default()
    })));
    assert!(e.contains("material 'm'") && e.contains("metallic"), "{e}");
    let e = build_err(BsdfDesc::Pbr(Box::new(PbrDesc {
        ior: -1.0,
        ..PbrDesc::default()
    })));
    assert!(e.contains("ior"), "{e}");
    let e = build_err(BsdfDesc::Dielectric {
        ior: 1.5,
        transmittance: Vec3::ONE,
        absorption: Vec3::new(-1.0, 0.0, 0.0),
        thin: false,
    });
    assert!(e.contains("absorption"), "{e}");
    let e = build_err(BsdfDesc::Conductor {
        eta: Vec3::ONE,
        k: Vec3::ONE,
        alpha: -0.1,
    });
    assert!(e.contains("alpha"), "{e}");
    for (bsdf, field) in [
        (
            BsdfDesc::Diffuse {
                albedo: Vec3::new(0.5, 1.5, 0.5),
                texture: None,
            },
            "albedo",
        ),
        (
            BsdfDesc::Mirror {
                reflectance: Vec3::splat(f32::NAN),
            },
            "reflectance",
        ),
        (
            BsdfDesc::Pbr(Box::new(PbrDesc {
                base_color: [0.5, 0.5, 0.5, 1.5],
                ..PbrDesc::default()
            })),
            "alpha",
        ),
        (
            BsdfDesc::Conductor {
                eta: Vec3::ONE,
                k: Vec3::splat(f32::INFINITY),
                alpha: 0.1,
            },
            "k must be",
        ),
    ] {
        let e = build_err(bsdf);
        assert!(e.contains("material 'm'") && e.contains(field), "{e}");
    }
}

/// The error of loading the JSON scene `text`.
fn whole_json_error(text: &str) -> String {
    match parse_json(text, Path::new("."), Path::new("scene.json")) {
        Ok(_) => panic!("accepted: {text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn json_values_of_the_wrong_shape_are_refused_in_jsons_words() {
    let cases: [(&str, &[&str]); 5] = [
        // A named choice given as a number.
        (
            r#", "render": {"integrator": 3}"#,
            &[
                "at render.integrator",
                "integer `3`, expected one of `path`, ",
            ],
        ),
        // An object written as an array of its fields (serde would read it in field order).
        (
            r#", "cameras": [[[0, 0, 3], [0, 0, 0]]]"#,
            &[
                "at cameras[0] (line",
                "invalid type: array, expected an object",
            ],
        ),
        (
            r#", "render": [8, 8]"#,
            &["at render (line", "invalid type: array, expected an object"],
        ),
        // An array longer than its value.
        (
            r#", "cameras": [{"position": [0, 0, 3, 1]}]"#,
            &["at cameras[0].position", "too many elements"],
        ),
        // A tagged value that is not an object.
        (
            r#", "environment": true"#,
            &[
                "at environment",
                "expected an object with a `type` naming an environment",
            ],
        ),
    ];
    for (extra, needles) in cases {
        let e = json_error(extra);
        for n in needles {
            assert!(e.contains(n), "{extra}: error {e:?} does not mention {n:?}");
        }
        for rust in ["struct", "enum", "sequence"] {
            assert!(
                !e.contains(rust),
                "{extra}: error {e:?} names a Rust {rust}"
            );
        }
    }
    let e = whole_json_error(
        r#"{"materials": {"w": {"type": "diffuse"}},
            "objects": [{"shape": {"type": "sphere"}, "material": "w",
                         "transform": {"scale": [1, 1]}}]}"#,
    );
    assert!(
        e.contains("at objects[0].transform.scale") && e.contains("a number or an array of 3"),
        "{e}"
    );
}

#[test]
fn values_beyond_f32_are_refused_where_they_are_written() {
    // An environment's rotation (the command line's flag refuses it too).
    refused(
        r#", "environment": {"type": "map", "path": "sky.hdr", "rotation": 1e39}"#,
        &["environment.rotation", "finite number of degrees"],
    );
    let scene = |shape: &str, material: &str| {
        format!(
            r#"{{"materials": {{"w": {material}}},
                "objects": [{{"shape": {shape}, "material": "w"}}]}}"#
        )
    };
    let diffuse = r#"{"type": "diffuse"}"#;
    let emitter = r#"{"type": "emitter", "emission": [1, 1, 1]}"#;
    // A mesh vertex that overflowed, named by its place.
    let e = whole_json_error(&scene(
        r#"{"type": "mesh", "positions": [[0, 0, 0], [1e39, 0, 0], [0, 1, 0]],
            "indices": [[0, 1, 2]]}"#,
        diffuse,
    ));
    assert!(
        e.contains("scene.json") && e.contains("objects[0].shape.positions[1]"),
        "{e}"
    );
    // A polygon whose area overflows is too large, not degenerate.
    let e = whole_json_error(&scene(
        r#"{"type": "polygon", "vertices": [[0, 0, 0], [3e38, 0, 0], [0, 3e38, 0]]}"#,
        diffuse,
    ));
    assert!(e.contains("too large") && !e.contains("degenerate"), "{e}");
    // An emitting disk, rectangle or sphere whose area overflows cannot be sampled: too large,
    // not the wrong kind of shape.
    for shape in [
        r#"{"type": "disk", "radius": 2e19}"#,
        r#"{"type": "sphere", "radius": 1e19}"#,
        r#"{"type": "rectangle", "corner": [0, 0, 0], "edge_u": [3e19, 0, 0], "edge_v": [0, 3e19, 0]}"#,
    ] {
        let e = whole_json_error(&scene(shape, emitter));
        assert!(
            e.contains("too large to be an area light") && !e.contains("use a mesh"),
            "{shape}: {e}"
        );
    }
    // One whose area rounds to zero is too small; a subnormal area loads (and gives no light),
    // as it always did.
    let e = whole_json_error(&scene(r#"{"type": "sphere", "radius": 1e-25}"#, emitter));
    assert!(e.contains("too small to be an area light"), "{e}");
    let tiny = scene(r#"{"type": "sphere", "radius": 1e-21}"#, emitter);
    parse_json(&tiny, Path::new("."), Path::new("scene.json")).unwrap();
    // A plane still cannot be one.
    let e = whole_json_error(&scene(r#"{"type": "plane"}"#, emitter));
    assert!(e.contains("cannot be an area light"), "{e}");
}

#[test]
fn errors_inside_a_typed_value_name_its_field_and_line() {
    let scene = |object: &str, extra: &str| {
        format!(
            "{{\"materials\": {{\"w\": {{\"type\": \"diffuse\"}}}},\n\"objects\": [\n{object}\n]{extra}\n}}"
        )
    };
    let ball = r#"{"shape": {"type": "sphere"}, "material": "w"}"#;
    let cases: [(String, &[&str]); 7] = [
        (
            scene(
                "{\"material\": \"w\", \"shape\": {\"type\": \"sphere\",\n\"radius\": \"1\"}}",
                "",
            ),
            &["at objects[0].shape.radius (line 4)", "invalid type: string \"1\""],
        ),
        (
            scene(r#"{"material": "w", "shape": {"type": "sphre"}}"#, ""),
            &["at objects[0].shape.type", "unknown variant `sphre`, expected one of `sphere`"],
        ),
        (
            scene(r#"{"material": "w", "shape": {"type": "sphere", "radius": 1, "radius": 2}}"#, ""),
            &["at objects[0].shape", "duplicate field `radius`"],
        ),
        (
            scene(r#"{"material": "w", "shape": {"radius": 1}}"#, ""),
            &["at objects[0].shape", "missing field `type`"],
        ),
        (
            scene(r#"{"material": "w", "shape": {"type": 3}}"#, ""),
            &["at objects[0].shape.type", "expected a string naming a shape, got 3"],
        ),
        (
            scene(ball, ",\n\"environment\": {\"type\": \"constant\",\n\"radiance\": [1, \"x\", 1]}"),
            &["at environment.radiance[1] (line 6)", "invalid type: string \"x\""],
        ),
        (
            scene(ball, ",\n\"lights\": [{\"type\": \"point\", \"position\": [0, 0, 0], \"intensty\": [1, 1, 1]}]"),
            &["at lights[0].intensty", "unknown field `intensty`"],
        ),
    ];
    for (text, needles) in &cases {
        let e = whole_json_error(text);
        for n in *needles {
            assert!(e.contains(n), "{text}: error {e:?} does not mention {n:?}");
        }
        assert!(!e.contains('\u{1f}'), "{e:?}");
    }
    // Materials: their type's fields, and the two every material takes.
    let material = |m: &str| format!("{{\"materials\": {{\"w\":\n{m}}}}}");
    for (m, needles) in [
        (
            r#"{"type": "diffuse", "albedo": [1, "x", 1]}"#,
            &[
                "at materials.w.albedo[1] (line 2)",
                "invalid type: string \"x\"",
            ][..],
        ),
        (
            r#"{"type": "diffuse", "albdo": [1, 1, 1]}"#,
            &[
                "at materials.w.albdo",
                "unknown field `albdo`",
                "every material takes `emission` and `two_sided`",
            ],
        ),
        (
            r#"{"type": "diffuse", "emission": "x"}"#,
            &["at materials.w.emission", "invalid type: string"],
        ),
        (
            r#"{"type": "diffuse", "two_sided": 1}"#,
            &["at materials.w.two_sided", "expected a boolean"],
        ),
        (
            r#"{"albedo": [1, 1, 1]}"#,
            &["at materials.w (line", "missing field `type`"],
        ),
        (
            r#"{"type": "difuse"}"#,
            &["at materials.w.type", "unknown variant `difuse`"],
        ),
        (
            r#"["diffuse"]"#,
            &[
                "at materials.w",
                "expected an object with a `type` naming a material",
            ],
        ),
    ] {
        let e = whole_json_error(&material(m));
        for n in needles {
            assert!(e.contains(n), "{m}: error {e:?} does not mention {n:?}");
        }
    }
}

#[test]
fn objects_past_2_to_the_40_units_are_refused_by_name() {
    let scene = |objects: &str, camera: &str| {
        format!(
            r#"{{"materials": {{"w": {{"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}}}},
                "objects": [{objects}],
                "camera": {{"position": {camera}, "look_at": [0, 0, 0], "fov": 40}}}}"#
        )
    };
    let build = |text: &str| {
        let desc = parse_json(text, Path::new("."), Path::new("scene.json")).unwrap();
        Scene::build(&desc).map(|_| ())
    };
    let near = "[0, 0, 4e11]";
    for (objects, name) in [
        // A triangle of 10^13 units: its hit distance overflowed and it was never seen.
        (
            r#"{"name": "big", "shape": {"type": "mesh",
                "positions": [[-1e13, -1e13, 0], [1e13, -1e13, 0], [0, 1e13, 0]],
                "indices": [[0, 1, 2]]}, "material": "w"}"#,
            "'big'",
        ),
        // A small ball placed past the limit.
        (
            r#"{"name": "far", "shape": {"type": "sphere", "radius": 1e11}, "material": "w",
                "transform": {"translate": [0, 1.05e12, 0]}}"#,
            "'far'",
        ),
        // A polygon placed past it.
        (
            r#"{"name": "sign", "shape": {"type": "polygon",
                "vertices": [[0, 2e12, 0], [1, 2e12, 0], [0, 2e12, 1]]}, "material": "w"}"#,
            "'sign'",
        ),
        // A unit mesh scaled past it.
        (
            r#"{"name": "a", "shape": {"type": "mesh", "positions": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                "indices": [[0, 1, 2]]}, "material": "w", "transform": {"scale": 2e12}}"#,
            "'a'",
        ),
    ] {
        let e = build(&scene(objects, near)).unwrap_err().to_string();
        assert!(e.contains(name) && e.contains("2^40"), "{e}");
    }
    // Refused when the file is loaded too, before any build (as a coordinator loads it).
    let path = std::env::temp_dir().join(format!("raytile-far-{}.json", std::process::id()));
    std::fs::write(
        &path,
        scene(
            r#"{"name": "far", "shape": {"type": "sphere", "radius": 1e11}, "material": "w",
                "transform": {"translate": [0, 1.05e12, 0]}}"#,
            near,
        ),
    )
    .unwrap();
    let e = raytile_core::load_scene(&path).unwrap_err().to_string();
    let _ = std::fs::remove_file(&path);
    assert!(e.contains("'far'") && e.contains("2^40"), "{e}");
    // Within it: accepted, and a triangle of 10^11 units at the limit's edge is seen. A plane
    // (unbounded) and a position no triangle uses do not count.
    let ok = scene(
        r#"{"shape": {"type": "mesh",
            "positions": [[-1e11, -1e11, 0], [1e11, -1e11, 0], [0, 1e11, 0], [1e30, 0, 0]],
            "indices": [[0, 1, 2]]}, "material": "w"},
           {"shape": {"type": "plane", "point": [0, 0, -1e12], "normal": [0, 0, 1]}, "material": "w"},
           {"shape": {"type": "sphere", "radius": 1e11}, "material": "w",
            "transform": {"translate": [0, 9e11, 0]}}"#,
        near,
    );
    let desc = parse_json(&ok, Path::new("."), Path::new("scene.json")).unwrap();
    let scene = Scene::build(&desc).unwrap();
    let s = RenderSettings {
        width: 8,
        height: 8,
        spp: 1,
        integrator: IntegratorKind::Albedo,
        ..Default::default()
    };
    let film = render(&scene, &RenderJob::new(&scene, &s).unwrap(), &());
    let px = film.resolve();
    // The centre pixels see the triangle (albedo 0.5 where it is hit).
    assert!(
        px[4 * 8 + 4].iter().all(|&v| (v - 0.5).abs() < 1e-3),
        "{:?}",
        px[4 * 8 + 4]
    );
}
