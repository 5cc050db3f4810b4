//! Bidirectional path tracing against known answers: a closed diffuse furnace, `path` on the
//! Cornell box, the caustic of a glass ball under a point light (which `path` cannot render),
//! and bit-identical images whatever the tiling and the threads. Tolerances are four standard
//! errors of the compared means, measured from the images themselves (pixels are independent
//! estimates).

mod estimates;

use estimates::{
    assert_mean, caustic_under_point_light, differences, image, load, load_file, stats,
};
use raytile_core::{IntegratorKind, RenderJob, RenderSettings};

fn settings(w: u32, h: u32, spp: u32, integrator: IntegratorKind) -> RenderSettings {
    RenderSettings {
        width: w,
        height: h,
        spp,
        max_depth: 8,
        integrator,
        ..Default::default()
    }
}

/// Renders `scene` at (width, height, spp) with `path` and `bdpt` and checks that their
/// pixel-by-pixel differences average to zero within four standard errors; `path`'s image
/// must be brighter than `least` (a black image would match anything).
fn matches_path(what: &str, scene: &raytile_core::Scene, (w, h, spp): (u32, u32, u32), least: f64) {
    let a = image(scene, &settings(w, h, spp, IntegratorKind::Path));
    let b = image(scene, &settings(w, h, spp, IntegratorKind::Bdpt));
    let (mean, _) = stats(&a);
    assert!(mean.iter().all(|&m| m > least), "{what}: {mean:?}");
    assert_mean(
        &format!("{what}: bdpt − path"),
        &differences(&b, &a),
        [0.0; 3],
        0.03,
    );
}

#[test]
fn furnace_a_closed_emitting_diffuse_sphere() {
    // Inside a sphere that emits Le = 1 and reflects diffusely with albedo ρ = 0.5, radiance
    // is Le / (1 − ρ) = 2 everywhere. Light subpaths start on the sphere and reach the camera
    // (t = 1), so the camera's importance is checked as well as every other strategy.
    let scene = load(
        r#"{
  "materials": {"wall": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5],
                         "emission": [1, 1, 1], "two_sided": true}},
  "objects": [{"shape": {"type": "sphere", "radius": 1}, "material": "wall"}],
  "camera": {"position": [0, 0, 0.3], "look_at": [0, 0, -1], "fov": 60}
}"#,
    );
    let mut s = settings(24, 24, 16, IntegratorKind::Bdpt);
    s.max_depth = 40;
    let px = image(&scene, &s);
    assert_mean("bdpt furnace", &px, [2.0; 3], 0.02);
}

#[test]
fn bdpt_matches_path_on_the_cornell_box() {
    let scene = load_file("cornell-box.json");
    let s = settings(24, 24, 16, IntegratorKind::Path);
    let a = image(&scene, &s);
    let b = image(&scene, &settings(24, 24, 16, IntegratorKind::Bdpt));
    let (mean, _) = stats(&a);
    assert!(mean.iter().all(|&m| m > 0.05), "{mean:?}");
    assert_mean("bdpt − path", &differences(&b, &a), [0.0; 3], 0.03);
}

#[test]
fn the_caustic_under_a_point_light_is_there_with_bdpt_and_not_with_path() {
    estimates::check_caustic_under_point_light(IntegratorKind::Bdpt);
}

#[test]
fn bdpt_is_deterministic_whatever_the_tiling_and_the_threads() {
    let scene = caustic_under_point_light();
    let bits = |px: &[[f32; 3]]| px.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
    let mut s = settings(40, 30, 4, IntegratorKind::Bdpt);
    s.tile_size = 8;
    let a = image(&scene, &s);
    s.tile_size = 64;
    let b = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| image(&scene, &s));
    assert!(a.iter().flatten().any(|&v| v > 0.0));
    assert_eq!(bits(&a), bits(&b));
}

#[test]
fn bdpt_refuses_filters_other_than_the_box() {
    let scene = load_file("cornell-box.json");
    let mut s = settings(8, 8, 1, IntegratorKind::Bdpt);
    s.filter = raytile_core::settings::FilterKind::Gaussian;
    let e = RenderJob::new(&scene, &s).unwrap_err().to_string();
    assert!(e.contains("filter") && e.contains("bdpt"), "{e}");
}

#[test]
fn bdpt_matches_path_under_spot_directional_and_environment_light() {
    // Every light type but the area light (the Cornell box has that): a diffuse ball on a
    // diffuse floor under a spot light, the sun and a uniform sky, each alone and together.
    let base = r#"{
  "materials": {"white": {"type": "diffuse", "albedo": [0.8, 0.6, 0.4]}},
  "objects": [
    {"shape": {"type": "rectangle", "corner": [-2, 0, -2], "edge_u": [0, 0, 4], "edge_v": [4, 0, 0]}, "material": "white"},
    {"shape": {"type": "sphere", "center": [0, 0.5, 0], "radius": 0.5}, "material": "white"}
  ],
  "camera": {"position": [0, 1.5, 3], "look_at": [0, 0.3, 0], "fov": 45}
  LIGHTS
}"#;
    let spot = r#""lights": [{"type": "spot", "position": [0.5, 2.5, 0.5], "look_at": [0, 0, 0], "intensity": [8, 8, 8], "inner_angle": 10, "outer_angle": 30}]"#;
    let sun = r#""lights": [{"type": "directional", "direction": [-0.3, -1, -0.2], "irradiance": [2, 2, 2]}]"#;
    let sky = r#""environment": {"type": "constant", "radiance": [0.5, 0.7, 1]}"#;
    for (what, lights) in [
        ("spot", spot.to_string()),
        ("sun", sun.to_string()),
        ("sky", sky.to_string()),
        (
            "all",
            format!(
                "{}, {}, {sky}",
                spot.trim_end_matches(']'),
                sun.trim_start_matches(r#""lights": ["#)
            ),
        ),
    ] {
        let scene = load(&base.replace("LIGHTS", &format!(", {lights}")));
        matches_path(what, &scene, (24, 24, 16), 0.02);
    }
}

#[test]
fn bdpt_matches_path_on_an_infinite_plane_under_the_sun_and_the_sky() {
    // Rays of the sun and the sky start on a disk of the bounding sphere of the finite objects;
    // an infinite floor reaches beyond it. Out there its light is found by the camera's
    // strategies alone, and the MIS weights must say so; and rays that start on the disk in the
    // floor's shadow (light from below the horizon) carry nothing. Without either, this image
    // came out several times too dark (sun) or 2 % too bright (sky).
    let base = r#"{
  "materials": {"d": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
  "objects": [
    WALL
    {"shape": {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0]}, "material": "d"}
  ],
  "camera": {"position": [0, 1, 3], "look_at": [0, LOOK, 0], "fov": 30},
  LIGHTS
}"#;
    let wall = r#"{"shape": {"type": "rectangle", "corner": [-2, 0, -1], "edge_u": [4, 0, 0], "edge_v": [0, 3, 0]}, "material": "d"},"#;
    let sun = r#""lights": [{"type": "directional", "direction": [0, -0.8, 1], "irradiance": [10, 10, 10]}]"#;
    let sky = r#""environment": {"type": "constant", "radiance": [1, 1, 1]}"#;
    let scene = |wall: &str, look: &str, lights: &str| {
        load(
            &base
                .replace("WALL", wall)
                .replace("LOOK", look)
                .replace("LIGHTS", lights),
        )
    };
    for (what, lights) in [("sun", sun), ("sky", sky)] {
        matches_path(what, &scene(wall, "1", lights), (16, 16, 256), 0.05);
    }
    // The floor alone under a uniform sky of radiance 1 reflects albedo × 1.
    let floor = image(
        &scene("", "0", sky),
        &settings(16, 16, 256, IntegratorKind::Bdpt),
    );
    assert_mean("bdpt: floor under the sky", &floor, [0.5; 3], 0.01);
}

#[test]
fn bdpt_matches_path_on_glossy_and_coated_materials() {
    // The glTF model weighs its lobes by the outgoing direction (it is not reciprocal): light
    // subpaths must scatter with the adjoint BSDF, as connections evaluate it. A glossy
    // dielectric ball and a rough metal one on a glossy floor, under a sun and a sky.
    let scene = load(
        r#"{
  "materials": {
    "floor": {"type": "pbr", "base_color": [0.7, 0.6, 0.5], "roughness": 0.25},
    "plastic": {"type": "pbr", "base_color": [0.2, 0.5, 0.9], "roughness": 0.15},
    "metal": {"type": "pbr", "base_color": [0.9, 0.7, 0.4], "metallic": 1, "roughness": 0.4}
  },
  "objects": [
    {"shape": {"type": "rectangle", "corner": [-2, 0, -2], "edge_u": [0, 0, 4], "edge_v": [4, 0, 0]}, "material": "floor"},
    {"shape": {"type": "sphere", "center": [-0.55, 0.5, 0], "radius": 0.5}, "material": "plastic"},
    {"shape": {"type": "sphere", "center": [0.55, 0.5, 0], "radius": 0.5}, "material": "metal"}
  ],
  "lights": [{"type": "directional", "direction": [-0.5, -0.6, -0.3], "irradiance": [2, 2, 2]}],
  "environment": {"type": "constant", "radiance": [0.4, 0.5, 0.6]},
  "camera": {"position": [0, 0.6, 3], "look_at": [0, 0.4, 0], "fov": 45}
}"#,
    );
    let a = image(&scene, &settings(32, 32, 32, IntegratorKind::Path));
    let b = image(&scene, &settings(32, 32, 32, IntegratorKind::Bdpt));
    let (mean, _) = stats(&a);
    assert!(mean.iter().all(|&m| m > 0.05), "{mean:?}");
    assert_mean("glossy: bdpt − path", &differences(&b, &a), [0.0; 3], 0.03);
}

/// `bdpt` is linear in its lights, however dim or bright: a floor under an emitter of radiance
/// 10⁻⁸ or 10¹² renders as `path` renders it, scaled. (Splats summed in i64 at 2^28 rounded
/// the dim light away and saturated on the bright: `bdpt` kept 38 % and 42 % of `path`.)
#[test]
fn bdpt_keeps_the_light_of_very_dim_and_very_bright_emitters() {
    for e in [1e-8f32, 1e12] {
        let scene = load(&format!(
            r#"{{
  "materials": {{"white": {{"type": "diffuse", "albedo": [0.8, 0.8, 0.8]}},
                 "lamp": {{"type": "emitter", "emission": [{e:e}, {e:e}, {e:e}]}}}},
  "objects": [
    {{"shape": {{"type": "rectangle", "corner": [-2, 0, 2], "edge_u": [4, 0, 0],
                 "edge_v": [0, 0, -4]}}, "material": "white"}},
    {{"shape": {{"type": "sphere", "center": [0, 1, 0], "radius": 0.3}}, "material": "lamp"}}
  ],
  "camera": {{"position": [0, 1, 4], "look_at": [0, 0.5, 0], "fov": 50}}
}}"#
        ));
        let scaled = |integrator| -> Vec<[f32; 3]> {
            let mut s = settings(32, 32, 8, integrator);
            s.max_depth = 4;
            image(&scene, &s)
                .into_iter()
                .map(|p| p.map(|v| v / e))
                .collect()
        };
        let (a, b) = (scaled(IntegratorKind::Path), scaled(IntegratorKind::Bdpt));
        let (mean, _) = stats(&a);
        assert!(mean.iter().all(|&m| m > 0.02), "{e}: {mean:?}");
        assert_mean(
            &format!("emission {e}: (bdpt − path) / emission"),
            &differences(&b, &a),
            [0.0; 3],
            0.03,
        );
    }
}
