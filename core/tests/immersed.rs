//! Objects immersed in an absorbing body (a lamp and a floor in tinted glass, a stone and a
//! clear marble in coloured water): every integrator attenuates every stretch of a path inside
//! the body, to an immersed object as well as to the body's own surface. Checked against an
//! exact value where there is one, and against the same scene built with an absorbing medium
//! that `volpath` renders by its own, independent, tracking of media.

mod estimates;

use estimates::{image, load, stats};
use raytile_core::{IntegratorKind, RenderSettings};

const ALL: [IntegratorKind; 5] = [
    IntegratorKind::Path,
    IntegratorKind::Volpath,
    IntegratorKind::Whitted,
    IntegratorKind::Bdpt,
    IntegratorKind::Sppm,
];

/// A point light and a diffuse floor inside an index-matched absorbing box (no refraction, no
/// reflection at its surface), seen from straight above by an orthographic camera: each pixel
/// is ρ/π · I cosθ / r² · e^(−σ r) · e^(−σ h), with r from the floor point to the light and h
/// its depth below the box's top. Without the tracking of bodies, both attenuations were
/// missing (neither stretch ends on the box's surface from within).
#[test]
fn light_in_an_absorbing_body_reaches_an_immersed_floor_attenuated_in_every_integrator() {
    // The camera above the box, then inside it (the probe finds it there): the floor is 0.9
    // and 0.7 below the camera's entry into the ink.
    for (camera_y, depth) in [(3.0, 0.9), (0.8, 0.7)] {
        floor_under_a_lamp_in_ink(camera_y, depth);
    }
}

fn floor_under_a_lamp_in_ink(camera_y: f64, depth: f64) {
    let scene = load(&format!(
        r#"{{
  "materials": {{
    "ink": {{"type": "dielectric", "ior": 1.0, "absorption": [0.2, 0.5, 1.0]}},
    "floor": {{"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}}
  }},
  "objects": [
    {{"shape": {{"type": "box", "min": [-1, 0, -1], "max": [1, 1, 1]}}, "material": "ink"}},
    {{"shape": {{"type": "rectangle", "corner": [-0.8, 0.1, -0.8], "edge_u": [0, 0, 1.6],
               "edge_v": [1.6, 0, 0]}}, "material": "floor"}}
  ],
  "lights": [{{"type": "point", "position": [0, 0.6, 0], "intensity": [5, 5, 5]}}],
  "camera": {{"type": "orthographic", "position": [0, {camera_y}, 0], "look_at": [0, 0, 0],
             "up": [0, 0, -1], "half_height": 0.1}}
}}"#
    ));
    let (w, h) = (8u32, 8u32);
    let sigma = [0.2f64, 0.5, 1.0];
    // The floor point under pixel (x, y): the view is 0.2 m square (pixels small enough that
    // the value at a pixel's centre is its mean within 0.1 %), x along +X, y along +Z.
    let want = |x: u32, y: u32| {
        let px = (f64::from(x) + 0.5) / f64::from(w) * 0.2 - 0.1;
        let pz = (f64::from(y) + 0.5) / f64::from(h) * 0.2 - 0.1;
        let dy = 0.5f64;
        let r = (px * px + dy * dy + pz * pz).sqrt();
        let e = 5.0 * (dy / r) / (r * r);
        sigma.map(|s| 0.5 / std::f64::consts::PI * e * (-s * (r + depth)).exp())
    };
    for integrator in ALL {
        let s = RenderSettings {
            width: w,
            height: h,
            spp: 16,
            max_depth: 4,
            integrator,
            ..Default::default()
        };
        let px = image(&scene, &s);
        for y in 0..h {
            for x in 0..w {
                let (got, want) = (px[(y * w + x) as usize], want(x, y));
                for k in 0..3 {
                    let err = (f64::from(got[k]) - want[k]).abs() / want[k];
                    assert!(
                        err < 0.01,
                        "{integrator:?}, camera at {camera_y}, pixel ({x}, {y}), channel {k}: \
                         {} against {}",
                        got[k],
                        want[k]
                    );
                }
            }
        }
    }
}

/// A stone, a clear glass marble and a lamp in a box of coloured water (ior 1.33), a floor
/// and a sky outside. `interior` is the water's absorption either as the dielectric's own
/// (`"absorption"`) or as a medium (`"interior"`, rendered by `volpath` only).
fn water_scene(absorbing_material: bool) -> raytile_core::Scene {
    let (water, box_media, marble_media) = if absorbing_material {
        (r#""absorption": [0.3, 0.9, 1.8]"#, "", "")
    } else {
        (
            r#""absorption": [0, 0, 0]"#,
            r#", "interior": "ink""#,
            r#", "exterior": "ink""#,
        )
    };
    load(&format!(
        r#"{{
  "media": {{"ink": {{"type": "homogeneous", "sigma_a": [0.3, 0.9, 1.8], "sigma_s": [0, 0, 0]}}}},
  "materials": {{
    "water": {{"type": "dielectric", "ior": 1.33, {water}}},
    "marble": {{"type": "dielectric", "ior": 1.5}},
    "stone": {{"type": "diffuse", "albedo": [0.8, 0.7, 0.5]}},
    "lamp": {{"type": "emitter", "emission": [12, 12, 12]}},
    "floor": {{"type": "diffuse", "albedo": [0.6, 0.6, 0.6]}}
  }},
  "objects": [
    {{"shape": {{"type": "rectangle", "corner": [-3, 0, -3], "edge_u": [0, 0, 6],
                "edge_v": [6, 0, 0]}}, "material": "floor"}},
    {{"shape": {{"type": "box", "min": [-0.8, 0.02, -0.8], "max": [0.8, 1.2, 0.8]}},
      "material": "water"{box_media}}},
    {{"shape": {{"type": "sphere", "center": [0.25, 0.35, 0.1], "radius": 0.3}},
      "material": "stone"}},
    {{"shape": {{"type": "sphere", "center": [-0.35, 0.4, 0.2], "radius": 0.22}},
      "material": "marble"{marble_media}}},
    {{"shape": {{"type": "sphere", "center": [-0.2, 0.9, -0.3], "radius": 0.1}},
      "material": "lamp"}}
  ],
  "environment": {{"type": "constant", "radiance": [0.2, 0.2, 0.2]}},
  "camera": {{"position": [0.4, 1.6, 3.2], "look_at": [0, 0.5, 0], "fov": 35}}
}}"#
    ))
}

/// The image mean and its standard error over renders with seeds `0..seeds`.
fn seed_stats(scene: &raytile_core::Scene, s: &RenderSettings, seeds: u32) -> ([f64; 3], [f64; 3]) {
    let means: Vec<[f32; 3]> = (0..seeds)
        .map(|seed| {
            let (m, _) = stats(&image(scene, &RenderSettings { seed, ..s.clone() }));
            [m[0] as f32, m[1] as f32, m[2] as f32]
        })
        .collect();
    stats(&means)
}

/// Every integrator agrees with `volpath` rendering the water as a medium: the lamp's light
/// on the stone and the floor, the sky seen through the water and the marble, all attenuated
/// by the stretches they run in the water. (Whitted's tracer has no indirect diffuse light,
/// so it renders another image: the first test checks it.)
#[test]
fn integrators_agree_with_a_medium_on_objects_immersed_in_coloured_water() {
    let with_medium = water_scene(false);
    let with_absorption = water_scene(true);
    let settings = |integrator, spp| RenderSettings {
        width: 24,
        height: 24,
        spp,
        max_depth: 12,
        integrator,
        ..Default::default()
    };
    let (want, want_se) = seed_stats(&with_medium, &settings(IntegratorKind::Volpath, 64), 6);
    for integrator in [
        IntegratorKind::Path,
        IntegratorKind::Volpath,
        IntegratorKind::Bdpt,
        IntegratorKind::Sppm,
    ] {
        let spp = if integrator == IntegratorKind::Bdpt {
            16
        } else {
            64
        };
        let got = seed_stats(&with_absorption, &settings(integrator, spp), 6);
        let what = format!("{integrator:?} with absorption");
        assert_agree(&what, got, (want, want_se), 0.01);
    }
}

/// `got` and `want`, (means, standard errors), agree within four standard errors of their
/// difference and `rel` of `want`, in every channel.
fn assert_agree(what: &str, got: ([f64; 3], [f64; 3]), want: ([f64; 3], [f64; 3]), rel: f64) {
    let ((g, g_se), (w, w_se)) = (got, want);
    eprintln!("{what}: {g:.4?} ± {g_se:.4?} against {w:.4?} ± {w_se:.4?}");
    for k in 0..3 {
        let tol = 4.0 * (g_se[k].powi(2) + w_se[k].powi(2)).sqrt() + rel * w[k];
        assert!(
            (g[k] - w[k]).abs() <= tol,
            "{what}, channel {k}: {} against {} (tolerance {tol})",
            g[k],
            w[k]
        );
    }
}

/// A camera above a sea of coloured water (an index-matched absorbing half-space, a `plane`)
/// looks straight down through it into the sky below: light that reaches the camera from
/// inside the water has come an infinite way through it, so only the channel the water does
/// not absorb is left. Escaping paths kept the sky's light before.
#[test]
fn the_sky_seen_through_an_endless_absorbing_sea_keeps_what_it_does_not_absorb() {
    let scene = load(
        r#"{
  "materials": {"sea": {"type": "dielectric", "ior": 1.0, "absorption": [1, 0, 1]}},
  "objects": [{"shape": {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0]},
               "material": "sea"}],
  "environment": {"type": "constant", "radiance": [0.5, 0.5, 0.5]},
  "camera": {"type": "orthographic", "position": [0, 2, 0], "look_at": [0, 0, 0],
             "up": [0, 0, -1], "half_height": 0.5}
}"#,
    );
    for integrator in [
        IntegratorKind::Path,
        IntegratorKind::Volpath,
        IntegratorKind::Whitted,
        IntegratorKind::Bdpt,
    ] {
        let s = RenderSettings {
            width: 4,
            height: 4,
            spp: 4,
            integrator,
            ..Default::default()
        };
        for p in image(&scene, &s) {
            assert_eq!(p, [0.0, 0.5, 0.0], "{integrator:?}");
        }
    }
}

/// One absorbing glass for three balls in `volpath`: one holds a medium as absorbing as the
/// glass (`interior`: the medium stands for its inside), one names only an `exterior` medium
/// of empty air, and one bounds no medium. All three absorb as the glass says, as `path`
/// renders them (which ignores media and takes the glass's own absorption everywhere).
#[test]
fn volpath_takes_a_bodys_absorption_from_its_own_interior_medium_or_from_its_glass() {
    let scene = load(
        r#"{
  "media": {
    "ink": {"type": "homogeneous", "sigma_a": [0.5, 2, 4], "sigma_s": [0, 0, 0]},
    "air": {"type": "homogeneous", "sigma_a": [0, 0, 0], "sigma_s": [0, 0, 0]}
  },
  "materials": {"glass": {"type": "dielectric", "ior": 1.3, "absorption": [0.5, 2, 4]}},
  "objects": [
    {"shape": {"type": "sphere", "center": [-1.1, 0, 0], "radius": 0.5}, "material": "glass",
     "interior": "ink"},
    {"shape": {"type": "sphere", "center": [0, 0, 0], "radius": 0.5}, "material": "glass",
     "exterior": "air"},
    {"shape": {"type": "sphere", "center": [1.1, 0, 0], "radius": 0.5}, "material": "glass"}
  ],
  "environment": {"type": "constant", "radiance": [1, 1, 1]},
  "camera": {"position": [0, 0, 6], "look_at": [0, 0, 0], "fov": 30}
}"#,
    );
    let s = |integrator| RenderSettings {
        width: 36,
        height: 12,
        spp: 32,
        max_depth: 16,
        integrator,
        ..Default::default()
    };
    let want = seed_stats(&scene, &s(IntegratorKind::Path), 4);
    let got = seed_stats(&scene, &s(IntegratorKind::Volpath), 4);
    assert_agree("volpath against path", got, want, 0.005);
}
