//! Render-level glTF checks: loaded scenes render as their authors meant, and every shared
//! sample renders without a NaN. Tests on the shared assets skip when they are absent, but fail
//! in CI (`CI=true`).

mod common;

use glam::Vec3;
use raytile_core::scene::desc::{BsdfDesc, SceneDesc};
use raytile_core::scene::load_scene;
use raytile_core::{render, IntegratorKind, RenderJob, RenderSettings, Scene};
use std::path::Path;

const SAMPLES: &str = "gltf-samples";
const SCENES: &str = "scenes";

/// A shared asset, loaded (see [`common::shared`]).
fn load(base: &str, rel: &str) -> Option<SceneDesc> {
    let p = common::shared(&format!("{base}/{rel}"))?;
    Some(load_scene(&p).unwrap_or_else(|e| panic!("{e}")))
}

/// Renders `desc` and returns linear RGB pixels, row-major from the top.
fn render_desc(desc: &SceneDesc, size: u32, spp: u32, integrator: IntegratorKind) -> Vec<Vec3> {
    let settings = RenderSettings {
        width: size,
        height: size,
        spp,
        max_depth: 8,
        integrator,
        ..Default::default()
    };
    let scene = Scene::build(desc).unwrap_or_else(|e| panic!("{e}"));
    let job = RenderJob::new(&scene, &settings).unwrap_or_else(|e| panic!("{e}"));
    let film = render(&scene, &job, &());
    let px: Vec<Vec3> = film.resolve().into_iter().map(Vec3::from).collect();
    assert_eq!(px.len(), (size * size) as usize);
    assert!(px.iter().all(|p| p.is_finite()), "non-finite pixel");
    px
}

fn is_red(p: Vec3) -> bool {
    p.x > 0.3 && p.y < 0.1 && p.z < 0.1
}

/// The red Box seen by the default camera (bounding sphere fits the view, yfov 45°): its front
/// face covers a centred square of about 68% of the image width.
#[test]
fn box_covers_the_expected_pixels() {
    let Some(desc) = load(SAMPLES, "Box/Box.glb") else {
        return;
    };
    let n = 64;
    let px = render_desc(&desc, n, 4, IntegratorKind::Albedo);
    let at = |x: u32, y: u32| px[(y * n + x) as usize];
    assert!(is_red(at(n / 2, n / 2)), "centre {}", at(n / 2, n / 2));
    for (x, y) in [(2, 2), (n - 3, 2), (2, n - 3), (n - 3, n - 3), (n / 2, 1)] {
        assert!(
            !is_red(at(x, y)),
            "({x}, {y}) should be background: {}",
            at(x, y)
        );
    }
    let red = px.iter().filter(|p| is_red(**p)).count() as f32 / px.len() as f32;
    assert!((0.35..0.6).contains(&red), "red coverage {red}");
}

/// BoxTextured shows the texture's colours (decoded from sRGB) on the box.
#[test]
fn textured_box_shows_texture_colours() {
    let Some(desc) = load(SAMPLES, "BoxTextured/BoxTextured.gltf") else {
        return;
    };
    let BsdfDesc::Pbr(p) = &desc.materials[desc.objects[0].material].bsdf else {
        panic!("not PBR");
    };
    let tex = &desc.textures[p.base_color_texture.unwrap().texture];
    let to_linear = |c: f32| {
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let tint = Vec3::from_slice(&p.base_color[..3]);
    let texels: Vec<Vec3> = (0..tex.texels.len())
        .step_by(7)
        .map(|i| tex.texels.get(i))
        .map(|t| Vec3::new(to_linear(t[0]), to_linear(t[1]), to_linear(t[2])) * tint)
        .collect();
    let n = 48;
    let px = render_desc(&desc, n, 16, IntegratorKind::Albedo);
    // The central third of the image is on the box.
    let centre: Vec<Vec3> = (n / 3..2 * n / 3)
        .flat_map(|y| (n / 3..2 * n / 3).map(move |x| (x, y)))
        .map(|(x, y)| px[(y * n + x) as usize])
        .collect();
    let near_texel = centre
        .iter()
        .filter(|c| texels.iter().any(|t| (*t - **c).abs().max_element() < 0.1))
        .count();
    assert!(
        near_texel * 2 >= centre.len(),
        "{near_texel} of {} pixels match texel colours",
        centre.len()
    );
    let (lo, hi) = centre
        .iter()
        .fold((Vec3::splat(f32::MAX), Vec3::ZERO), |(lo, hi), c| {
            (lo.min(*c), hi.max(*c))
        });
    assert!(
        (hi - lo).max_element() > 0.3,
        "the texture should show contrast: {lo} .. {hi}"
    );
}

/// The Cornell box: lit by its emissive quad only, red wall on the left, green on the right.
#[test]
fn cornell_box_walls_have_their_colours() {
    let Some(desc) = load(SCENES, "cornell-box.gltf") else {
        return;
    };
    assert!(desc.environment.is_none());
    let n = 48;
    let px = render_desc(&desc, n, 32, IntegratorKind::Path);
    let mean = |x0: u32, x1: u32| {
        let mut s = Vec3::ZERO;
        let mut k = 0.0;
        for y in n / 3..2 * n / 3 {
            for x in x0..x1 {
                s += px[(y * n + x) as usize];
                k += 1.0;
            }
        }
        s / k
    };
    let left = mean(1, n / 8);
    let right = mean(n - n / 8, n - 1);
    assert!(left.x > 2.0 * left.y, "left wall should be red: {left}");
    assert!(
        right.y > 1.5 * right.x,
        "right wall should be green: {right}"
    );
    let all = px.iter().copied().sum::<Vec3>() / px.len() as f32;
    assert!(all.min_element() > 0.01, "the box is lit: {all}");
}

/// Every `.gltf`/`.glb` under the shared samples renders at low resolution with no NaN or
/// infinite sample, with every integrator.
#[test]
fn every_sample_renders_without_nan() {
    let Some(root) = common::shared(SAMPLES) else {
        return;
    };
    let mut files = Vec::new();
    for dir in std::fs::read_dir(&root).unwrap() {
        let dir = dir.unwrap().path();
        if dir.is_dir() {
            for f in std::fs::read_dir(&dir).unwrap() {
                let f = f.unwrap().path();
                if matches!(f.extension().and_then(|e| e.to_str()), Some("gltf" | "glb")) {
                    files.push(f);
                }
            }
        }
    }
    files.sort();
    assert!(!files.is_empty());
    for f in &files {
        let desc = load_scene(f).unwrap_or_else(|e| panic!("{e}"));
        for integrator in [
            IntegratorKind::Path,
            IntegratorKind::Whitted,
            IntegratorKind::Albedo,
        ] {
            let settings = RenderSettings {
                width: 16,
                height: 16,
                spp: 2,
                max_depth: 6,
                integrator,
                ..Default::default()
            };
            let scene = Scene::build(&desc).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            let job = RenderJob::new(&scene, &settings).unwrap();
            let film = render(&scene, &job, &());
            assert_eq!(film.bad_samples, 0, "{} {integrator:?}", f.display());
        }
    }
}

/// Each camera of the Cameras sample is selectable by index and by name, and they differ.
#[test]
fn each_camera_renders_its_own_view() {
    let Some(desc) = load(SAMPLES, "Cameras/Cameras.gltf") else {
        return;
    };
    assert!(desc.cameras.len() >= 2);
    let mut images = Vec::new();
    for (i, c) in desc.cameras.iter().enumerate() {
        let px = |sel: String| {
            let settings = RenderSettings {
                width: 16,
                height: 16,
                spp: 1,
                integrator: IntegratorKind::Depth,
                camera: Some(sel),
                ..Default::default()
            };
            let scene = Scene::build(&desc).unwrap_or_else(|e| panic!("{e}"));
            let job = RenderJob::new(&scene, &settings).unwrap_or_else(|e| panic!("{e}"));
            render(&scene, &job, &()).resolve()
        };
        let by_index = px(i.to_string());
        assert_eq!(
            by_index,
            px(c.name.clone()),
            "camera {i} by name and by index"
        );
        images.push(by_index);
    }
    assert_ne!(
        images[0], images[1],
        "the cameras must see different images"
    );
}

/// A glTF file with one triangle facing +Z and nothing else (no light, no camera), written
/// here: its buffer travels as a percent-encoded data URI.
fn unlit_triangle_gltf() -> Vec<u8> {
    let positions: [f32; 9] = [-1.0, -1.0, 0.0, 1.0, -1.0, 0.0, 0.0, 1.0, 0.0];
    let bytes: Vec<u8> = positions.iter().flat_map(|v| v.to_le_bytes()).collect();
    let uri: String = bytes.iter().map(|b| format!("%{b:02X}")).collect();
    format!(
        r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}],
        "nodes": [{{"mesh": 0}}],
        "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}}}]}}],
        "buffers": [{{"byteLength": 36, "uri": "data:application/octet-stream,{uri}"}}],
        "bufferViews": [{{"buffer": 0, "byteLength": 36}}],
        "accessors": [{{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
            "min": [-1, -1, 0], "max": [1, 1, 0]}}]}}"#
    )
    .into_bytes()
}

/// A glTF file without light gets the default white environment from its loader, so the path
/// tracer sees the triangle and the background; with `default_light` off
/// (`--no-default-light`) the same scene renders black. A scene with its own light keeps it
/// either way.
#[test]
fn default_light_can_be_turned_off() {
    use raytile_core::scene::gltf::{load_gltf_slice, GltfOptions};
    let desc = load_gltf_slice(
        &unlit_triangle_gltf(),
        None,
        "triangle.gltf",
        &GltfOptions::default(),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(desc.default_environment);
    let sum = |default_light: bool, desc: &SceneDesc| {
        let settings = RenderSettings {
            width: 16,
            height: 16,
            spp: 4,
            default_light,
            ..Default::default()
        };
        let scene = Scene::build(desc).unwrap();
        let job = RenderJob::new(&scene, &settings).unwrap();
        let film = render(&scene, &job, &());
        film.resolve()
            .into_iter()
            .map(|p| Vec3::from(p).element_sum())
            .sum::<f32>()
    };
    assert!(sum(true, &desc) > 0.0);
    assert_eq!(sum(false, &desc), 0.0);
    // The same built scene serves both jobs: the default light is the job's choice.
    let scene = Scene::build(&desc).unwrap();
    for (default_light, lit) in [(true, true), (false, false), (true, true)] {
        let settings = RenderSettings {
            width: 8,
            height: 8,
            spp: 1,
            default_light,
            ..Default::default()
        };
        let job = RenderJob::new(&scene, &settings).unwrap();
        assert_eq!(job.environment().is_some(), lit);
        let mean = render(&scene, &job, &()).mean();
        assert_eq!(mean[0] > 0.0, lit, "default_light {default_light}");
    }
    let cornell = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box.json");
    let cornell = load_scene(&cornell).unwrap_or_else(|e| panic!("{e}"));
    assert!(!cornell.default_environment);
    assert!(sum(false, &cornell) > 0.0);
}
