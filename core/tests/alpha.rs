//! The alpha channel (`RenderSettings::alpha`): a pixel's alpha is the share of its camera rays
//! that meet the scene, the environment seen straight on is transparent, and everything the
//! camera sees of the scene keeps its bits.

use raytile_core::scene::json::parse_json;
use raytile_core::{render, Film, IntegratorKind, RenderJob, RenderSettings, Scene};
use std::path::Path;

/// Image edge in pixels; the camera's vertical field of view in degrees, and its distance from
/// the origin, where the scenes below put a sphere of radius [`RADIUS`].
const SIZE: u32 = 40;
const FOV: f32 = 40.0;
const DISTANCE: f32 = 4.0;
const RADIUS: f32 = 0.6;

/// The radius in pixels of the disk a sphere of [`RADIUS`] at the origin covers in the image:
/// its silhouette's angular radius asin(r / d), projected at the focal length in pixels.
fn disk_radius() -> f32 {
    let focal = (SIZE as f32 / 2.0) / (FOV.to_radians() / 2.0).tan();
    focal * (RADIUS / DISTANCE).asin().tan()
}

/// A sphere of `material` (a JSON material) at the origin, under a constant sky, with a point
/// light (so that `whitted` and `sppm` have a light that is not the sky).
fn scene(material: &str) -> Scene {
    let text = format!(
        r#"{{
          "camera": {{"position": [0, 0, {DISTANCE}], "look_at": [0, 0, 0], "fov": {FOV}}},
          "environment": {{"type": "constant", "radiance": [0.5, 0.6, 0.7]}},
          "materials": {{"ball": {material}}},
          "objects": [{{"name": "ball", "shape": {{"type": "sphere", "center": [0, 0, 0],
                         "radius": {RADIUS}}}, "material": "ball"}}],
          "lights": [{{"type": "point", "position": [2, 3, 3], "intensity": [20, 20, 20]}}]
        }}"#
    );
    let desc = parse_json(&text, Path::new("."), Path::new("alpha-test.json")).unwrap();
    Scene::build(&desc).unwrap()
}

fn film(scene: &Scene, integrator: IntegratorKind, spp: u32, alpha: bool) -> Film {
    let settings = RenderSettings {
        width: SIZE,
        height: SIZE,
        spp,
        max_depth: 8,
        integrator,
        alpha,
        tile_size: 16,
        ..Default::default()
    };
    let job = RenderJob::new(scene, &settings).unwrap();
    render(scene, &job, &())
}

/// Distance of pixel `i`'s centre from the image centre, in pixels.
fn from_centre(i: usize) -> f32 {
    let (x, y) = (
        (i as u32 % SIZE) as f32 + 0.5,
        (i as u32 / SIZE) as f32 + 0.5,
    );
    let c = SIZE as f32 / 2.0;
    ((x - c).powi(2) + (y - c).powi(2)).sqrt()
}

/// For every integrator: the alpha channel sums to the sphere's disk; pixels well inside it
/// are opaque and keep the bits of the render without alpha; pixels well outside are
/// transparent and black (the sky is not seen), where the render without alpha shows the sky.
#[test]
fn alpha_covers_the_scene_and_clears_the_sky() {
    let ball = scene(r#"{"type": "diffuse", "albedo": [0.7, 0.5, 0.3]}"#);
    let r = disk_radius();
    let area = std::f32::consts::PI * r * r;
    for integrator in IntegratorKind::ALL {
        let spp = 64;
        let plain = film(&ball, integrator, spp, false);
        let clear = film(&ball, integrator, spp, true);
        assert!(plain.alpha().is_none(), "{integrator:?}");
        let alpha = clear.alpha().expect("a film with an alpha channel");
        let (px, rgb) = (plain.resolve(), clear.resolve());
        for (i, &a) in alpha.iter().enumerate() {
            assert!(
                (0.0..=1.0).contains(&a),
                "{integrator:?} pixel {i}: alpha {a}"
            );
            let d = from_centre(i);
            if d < r - 1.5 {
                assert_eq!(a, 1.0, "{integrator:?} pixel {i} inside the disk");
                assert_eq!(
                    rgb[i].map(f32::to_bits),
                    px[i].map(f32::to_bits),
                    "{integrator:?} pixel {i}: what the camera sees of the scene keeps its bits"
                );
            } else if d > r + 1.5 {
                assert_eq!(a, 0.0, "{integrator:?} pixel {i} outside the disk");
                assert_eq!(
                    rgb[i], [0.0; 3],
                    "{integrator:?} pixel {i}: the sky is clear"
                );
            }
        }
        // The sky is seen where there is no alpha channel (the debug outputs other than the
        // albedo show nothing there anyway).
        let corner = px[0];
        if !matches!(
            integrator,
            IntegratorKind::Normals | IntegratorKind::Depth | IntegratorKind::Ao
        ) {
            assert!(corner[2] > 0.0, "{integrator:?}: {corner:?}");
        }
        // Coverage is the fraction of each pixel's camera rays that hit the sphere: summed, the
        // area of its disk, up to the sampling of the pixels on its edge.
        let covered: f32 = alpha.iter().sum();
        assert!(
            (covered - area).abs() < 0.01 * area,
            "{integrator:?}: alpha sums to {covered} pixels, the disk covers {area}"
        );
    }
}

/// Glass is opaque in alpha (the sky seen through it is part of the image); a medium covers
/// what it absorbs or scatters: in `volpath`, a grey medium of extinction σ in a sphere has
/// alpha 1 − exp(−σ·chord) at its centre, and `path` (which ignores media) sees through it.
#[test]
fn glass_is_opaque_and_a_medium_covers_what_it_stops() {
    let glass = scene(r#"{"type": "glass", "ior": 1.5}"#);
    let f = film(&glass, IntegratorKind::Path, 16, true);
    let alpha = f.alpha().unwrap();
    let rgb = f.resolve();
    let centre = (SIZE / 2 * SIZE + SIZE / 2) as usize;
    assert_eq!(alpha[centre], 1.0);
    assert!(
        rgb[centre][2] > 0.1,
        "the sky through the glass: {:?}",
        rgb[centre]
    );

    let sigma = 1.0f32;
    let fog = {
        let text = format!(
            r#"{{
              "camera": {{"position": [0, 0, {DISTANCE}], "look_at": [0, 0, 0], "fov": {FOV}}},
              "environment": {{"type": "constant", "radiance": [0.5, 0.6, 0.7]}},
              "media": {{"fog": {{"type": "homogeneous", "sigma_a": [{a}, {a}, {a}],
                                  "sigma_s": [{s}, {s}, {s}], "g": 0}}}},
              "materials": {{"boundary": {{"type": "interface"}}}},
              "objects": [{{"name": "fog", "shape": {{"type": "sphere", "center": [0, 0, 0],
                             "radius": {RADIUS}}}, "material": "boundary", "interior": "fog"}}]
            }}"#,
            a = sigma * 0.25,
            s = sigma * 0.75,
        );
        let desc = parse_json(&text, Path::new("."), Path::new("fog.json")).unwrap();
        Scene::build(&desc).unwrap()
    };
    let f = film(&fog, IntegratorKind::Volpath, 256, true);
    let alpha = f.alpha().unwrap();
    let alpha = &alpha;
    // The 3 × 3 pixels about the centre: chords within 1 % of the diameter.
    let c = SIZE as usize / 2;
    let mean: f32 = (c - 1..=c + 1)
        .flat_map(|y| (c - 1..=c + 1).map(move |x| alpha[y * SIZE as usize + x]))
        .sum::<f32>()
        / 9.0;
    let expected = 1.0 - (-sigma * 2.0 * RADIUS).exp();
    assert!(
        (mean - expected).abs() < 0.04,
        "alpha {mean} at the centre of the fog, expected {expected}"
    );
    // Outside the sphere, nothing; `path` does not see media, so nothing anywhere.
    assert_eq!(alpha[0], 0.0);
    let through = film(&fog, IntegratorKind::Path, 4, true);
    assert!(through.alpha().unwrap().iter().all(|&a| a == 0.0));
}
