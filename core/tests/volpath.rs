//! The volumetric path tracer against known answers: furnaces (a medium that scatters without
//! absorbing, in an interface sphere under a uniform sky, must look exactly like the sky),
//! Beer–Lambert through an absorbing slab, a half-absorbing medium against an independent
//! random walk, chromatic media with and without the majorant grid, and `volpath` against
//! `path` on a scene without media. Tolerances are four standard errors of the compared means,
//! measured from the images themselves (pixels are independent estimates).

use glam::Vec2;
use raytile_core::scene::json::parse_json;
mod estimates;

use estimates::{assert_mean, differences, image, stats};
use raytile_core::{IntegratorKind, RenderJob, RenderSettings, Scene};
use std::path::Path;

fn load(json: &str) -> Scene {
    let desc = parse_json(json, Path::new("."), Path::new("test.json")).unwrap();
    Scene::build(&desc).unwrap()
}

fn settings(size: u32, spp: u32, integrator: IntegratorKind) -> RenderSettings {
    RenderSettings {
        width: size,
        height: size,
        spp,
        max_depth: 200,
        integrator,
        ..Default::default()
    }
}

/// An interface sphere of radius 1 holding `medium` (a JSON medium), in a sky of radiance 1,
/// seen from 1.5 away so that it fills the frame.
fn sphere_in_sky(medium: &str) -> String {
    format!(
        r#"{{
  "media": {{"m": {medium}}},
  "materials": {{"boundary": {{"type": "interface"}}}},
  "objects": [{{"shape": {{"type": "sphere", "radius": 1}}, "material": "boundary", "interior": "m"}}],
  "environment": {{"type": "constant", "radiance": [1, 1, 1]}},
  "camera": {{"position": [0, 0, 1.5], "look_at": [0, 0, 0], "fov": 60}}
}}"#
    )
}

#[test]
fn furnace_a_medium_that_only_scatters_looks_like_the_sky() {
    // Isotropic, forward scattering, and chromatic (σt 1, 3 and 6 per channel, albedo 1 in
    // each): every path ends in the sky, so every channel has expectation 1.
    for (what, medium) in [
        (
            "g = 0",
            r#"{"type": "homogeneous", "sigma_a": [0, 0, 0], "sigma_s": [3, 3, 3], "g": 0}"#,
        ),
        (
            "g = 0.7",
            r#"{"type": "homogeneous", "sigma_a": [0, 0, 0], "sigma_s": [3, 3, 3], "g": 0.7}"#,
        ),
        (
            "chromatic",
            r#"{"type": "homogeneous", "sigma_a": [0, 0, 0], "sigma_s": [1, 3, 6], "g": 0.3}"#,
        ),
        (
            "noise grid",
            r#"{"type": "noise", "resolution": [16, 16, 16], "sigma_a": [0, 0, 0], "sigma_s": [2, 4, 8], "gain": 8}"#,
        ),
    ] {
        let scene = load(&sphere_in_sky(medium));
        let px = image(&scene, &settings(32, 32, IntegratorKind::Volpath));
        assert_mean(what, &px, [1.0; 3], 0.01);
    }
}

#[test]
fn furnace_a_scattering_liquid_in_glass_looks_like_the_sky() {
    // Glass around a medium that only scatters: refraction carries rays into the medium and
    // out of it (the medium tracked through the dielectric's interior), total internal
    // reflection keeps some inside for long walks, and nothing is lost.
    let json = sphere_in_sky(
        r#"{"type": "homogeneous", "sigma_a": [0, 0, 0], "sigma_s": [1, 2, 4], "g": 0.5}"#,
    )
    .replace(
        r#""boundary": {"type": "interface"}"#,
        r#""boundary": {"type": "dielectric", "ior": 1.33}"#,
    );
    let scene = load(&json);
    let px = image(&scene, &settings(32, 32, IntegratorKind::Volpath));
    assert_mean("glass of milk", &px, [1.0; 3], 0.01);
}

#[test]
fn beer_lambert_through_an_absorbing_slab() {
    // A slab 1 thick of σa = (0.2, 1, 3), seen face on with an orthographic camera in front of
    // a sky of radiance 1: every pixel's expectation is exp(−σa).
    let json = r#"{
  "media": {"ink": {"type": "homogeneous", "sigma_a": [0.2, 1, 3], "sigma_s": [0, 0, 0]}},
  "materials": {"boundary": {"type": "interface"}},
  "objects": [{"shape": {"type": "box", "min": [-5, -5, -0.5], "max": [5, 5, 0.5]},
               "material": "boundary", "interior": "ink"}],
  "environment": {"type": "constant", "radiance": [1, 1, 1]},
  "camera": {"type": "orthographic", "position": [0, 0, 3], "look_at": [0, 0, 0], "half_height": 1}
}"#;
    let scene = load(json);
    let px = image(&scene, &settings(32, 32, IntegratorKind::Volpath));
    let want = [0.2f64, 1.0, 3.0].map(|s| (-s).exp());
    assert_mean("slab", &px, want, 0.01);
    // `path` ignores the medium: the sky, exactly.
    let px = image(&scene, &settings(8, 1, IntegratorKind::Path));
    assert!(px.iter().flatten().all(|&v| v == 1.0), "{:?}", &px[..2]);
}

/// A small deterministic generator for the reference walk (independent of the renderer's).
struct SplitMix(u64);

impl SplitMix {
    fn f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Distance from `o` along unit `d` to where it leaves the unit sphere (None if it misses).
fn exit_unit_sphere(o: [f64; 3], d: [f64; 3]) -> Option<(f64, f64)> {
    let b = o[0] * d[0] + o[1] * d[1] + o[2] * d[2];
    let c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - 1.0;
    let disc = b * b - c;
    (disc > 0.0).then(|| (-b - disc.sqrt(), -b + disc.sqrt()))
}

/// The radiance along a ray into a unit sphere of isotropic medium (σt, albedo) under a sky of
/// radiance 1, by the textbook analog random walk: exponential free flights, isotropic
/// scattering, the albedo as a weight per scattering event.
fn walk(o: [f64; 3], d: [f64; 3], sigma_t: f64, albedo: f64, rng: &mut SplitMix) -> f64 {
    let Some((t0, _)) = exit_unit_sphere(o, d) else {
        return 1.0;
    };
    let mut p = [o[0] + d[0] * t0, o[1] + d[1] * t0, o[2] + d[2] * t0];
    let mut d = d;
    let mut weight = 1.0;
    loop {
        let (_, t1) = exit_unit_sphere(p, d).unwrap_or((0.0, 0.0));
        let s = -(1.0 - rng.f64()).ln() / sigma_t;
        if s >= t1 {
            return weight;
        }
        p = [p[0] + d[0] * s, p[1] + d[1] * s, p[2] + d[2] * s];
        weight *= albedo;
        if weight < 1e-6 {
            return 0.0;
        }
        let z = 1.0 - 2.0 * rng.f64();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = 2.0 * std::f64::consts::PI * rng.f64();
        d = [r * phi.cos(), r * phi.sin(), z];
    }
}

#[test]
fn half_absorbing_medium_matches_an_independent_random_walk() {
    // σa = σs = 1.5: albedo 0.5. The reference follows, per pixel, 64 walks through uniform
    // film points of that pixel (the box filter's footprint) with the renderer's own camera.
    let scene = load(&sphere_in_sky(
        r#"{"type": "homogeneous", "sigma_a": [1.5, 1.5, 1.5], "sigma_s": [1.5, 1.5, 1.5]}"#,
    ));
    let s = settings(16, 32, IntegratorKind::Volpath);
    let px = image(&scene, &s);
    let job = RenderJob::new(&scene, &s).unwrap();
    let mut rng = SplitMix(7);
    let mut reference = Vec::with_capacity(px.len());
    for y in 0..16 {
        for x in 0..16 {
            let mut sum = 0.0;
            for _ in 0..64 {
                let film = Vec2::new(x as f32 + rng.f64() as f32, y as f32 + rng.f64() as f32);
                let ray = job.camera.generate_ray(film, Vec2::splat(0.5));
                let d = ray.d.normalize();
                let o = [ray.o.x as f64, ray.o.y as f64, ray.o.z as f64];
                sum += walk(o, [d.x as f64, d.y as f64, d.z as f64], 3.0, 0.5, &mut rng);
            }
            let v = (sum / 64.0) as f32;
            reference.push([v; 3]);
        }
    }
    let (mean, _) = stats(&px);
    assert!(
        mean[0] > 0.1 && mean[0] < 0.6,
        "the medium must darken the sphere visibly: {mean:?}"
    );
    assert_mean(
        "albedo 0.5 − walk",
        &differences(&px, &reference),
        [0.0; 3],
        0.01,
    );
}

#[test]
fn chromatic_grid_converges_to_the_same_mean_without_the_majorant_grid() {
    // A smoke of σt differing by channel, lit by the sky: the default 16³ majorant grid and a
    // single global majorant give different noise but the same expectation.
    let medium = |res: &str| {
        format!(
            r#"{{"type": "noise", "resolution": [24, 24, 24], "sigma_a": [0.5, 1, 2], "sigma_s": [4, 2, 1], "g": 0.4, "gain": 6, "majorant_resolution": {res}}}"#
        )
    };
    let fine = load(&sphere_in_sky(&medium("[16, 16, 16]")));
    let coarse = load(&sphere_in_sky(&medium("[1, 1, 1]")));
    let s = settings(32, 32, IntegratorKind::Volpath);
    let a = image(&fine, &s);
    let b = image(&coarse, &s);
    let (mean, _) = stats(&a);
    assert!(
        mean.iter().all(|&m| m < 0.9) && (mean[0] - mean[2]).abs() > 0.02,
        "the smoke must darken and tint the sphere: {mean:?}"
    );
    assert_mean("16³ − 1³ majorants", &differences(&a, &b), [0.0; 3], 0.01);
}

#[test]
fn volpath_without_media_matches_path_on_the_cornell_box() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box.json");
    let desc = raytile_core::load_scene(&path).unwrap();
    let scene = Scene::build(&desc).unwrap();
    let mut s = settings(24, 16, IntegratorKind::Path);
    s.max_depth = 8;
    let a = image(&scene, &s);
    s.integrator = IntegratorKind::Volpath;
    let b = image(&scene, &s);
    let (mean, _) = stats(&a);
    assert!(mean.iter().all(|&m| m > 0.05), "{mean:?}");
    assert_mean("volpath − path", &differences(&b, &a), [0.0; 3], 0.02);
}

#[test]
fn volpath_is_deterministic_whatever_the_tiling() {
    let scene = load(&sphere_in_sky(
        r#"{"type": "noise", "resolution": [12, 12, 12], "sigma_a": [0.5, 1, 2], "sigma_s": [4, 2, 1], "g": 0.4}"#,
    ));
    let mut s = settings(20, 4, IntegratorKind::Volpath);
    s.tile_size = 8;
    let a = image(&scene, &s);
    s.tile_size = 64;
    let b = image(&scene, &s);
    let bits = |px: &[[f32; 3]]| px.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a), bits(&b));
}

#[test]
fn media_errors_name_the_json_path() {
    let err = |json: &str| {
        parse_json(json, Path::new("."), Path::new("test.json"))
            .unwrap_err()
            .to_string()
    };
    let e = err(r#"{"materials": {"b": {"type": "interface"}},
            "objects": [{"shape": {"type": "sphere"}, "material": "b", "interior": "fog"}]}"#);
    assert!(
        e.contains("objects[0].interior") && e.contains("unknown medium 'fog'"),
        "{e}"
    );
    let e = err(
        r#"{"media": {"a": {"type": "homogeneous", "sigma_a": [0,0,0], "sigma_s": [1,1,1]}}, "medium": "b"}"#,
    );
    assert!(e.contains("at medium") && e.contains("known: a"), "{e}");
    let e = err(
        r#"{"media": {"a": {"type": "homogeneous", "sigma_a": [0,-1,0], "sigma_s": [1,1,1]}}}"#,
    );
    assert!(e.contains("media.a.sigma_a"), "{e}");
    let e = err(
        r#"{"media": {"a": {"type": "homogeneous", "sigma_a": [0,0,0], "sigma_s": [1,1,1], "g": 1}}}"#,
    );
    assert!(e.contains("media.a.g"), "{e}");
    let e = err(
        r#"{"media": {"a": {"type": "noise", "resolution": [1000, 1000, 1000], "sigma_a": [0,0,0], "sigma_s": [1,1,1]}}}"#,
    );
    assert!(e.contains("media.a.resolution"), "{e}");
    let e = err(
        r#"{"media": {"a": {"type": "grid", "path": "missing.vol", "sigma_a": [0,0,0], "sigma_s": [1,1,1]}}}"#,
    );
    assert!(e.contains("media.a.path"), "{e}");
    let e = err(r#"{"media": {"a": {"type": "smoke"}}}"#);
    assert!(e.contains("media.a"), "{e}");
}

#[test]
fn a_vol_grid_file_fills_its_box_in_the_space_of_its_object() {
    // A Mitsuba 3 .vol file: 2×2×2 voxels of density 2 over the unit box. The object (an
    // interface box over the same unit box) is scaled into a slab 0.5 thick across the view,
    // so the grid's optical depth is σa · 2 · 0.5 = σa.
    let dir = std::env::temp_dir().join(format!("raytile-volpath-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut vol = b"VOL\x03".to_vec();
    for v in [1i32, 2, 2, 2, 1] {
        vol.extend(v.to_le_bytes());
    }
    for v in [0f32, 0., 0., 1., 1., 1.].into_iter().chain([2.0; 8]) {
        vol.extend(v.to_le_bytes());
    }
    std::fs::write(dir.join("slab.vol"), vol).unwrap();
    let json = r#"{
  "media": {"ink": {"type": "grid", "path": "slab.vol", "sigma_a": [0.4, 1, 2], "sigma_s": [0, 0, 0]}},
  "materials": {"boundary": {"type": "interface"}},
  "objects": [{"shape": {"type": "box", "min": [0, 0, 0], "max": [1, 1, 1]},
               "material": "boundary", "interior": "ink",
               "transform": {"scale": [10, 10, 0.5], "translate": [-5, -5, -0.25]}}],
  "environment": {"type": "constant", "radiance": [1, 1, 1]},
  "camera": {"type": "orthographic", "position": [0, 0, 3], "look_at": [0, 0, 0], "half_height": 1}
}"#;
    // The same grid placed by two objects, each a slab half as thick, one behind the other:
    // the same optical depth in all (each object places its own copy of the shared grid).
    let two = json.replace(
        r#""transform": {"scale": [10, 10, 0.5], "translate": [-5, -5, -0.25]}}],"#,
        r#""transform": {"scale": [10, 10, 0.25], "translate": [-5, -5, -0.6]}},
              {"shape": {"type": "box", "min": [0, 0, 0], "max": [1, 1, 1]},
               "material": "boundary", "interior": "ink",
               "transform": {"scale": [10, 10, 0.25], "translate": [-5, -5, 0.3]}}],"#,
    );
    assert_ne!(two, json);
    let desc = parse_json(json, &dir, Path::new("slab.json"));
    let desc_two = parse_json(&two, &dir, Path::new("slabs.json"));
    std::fs::remove_dir_all(&dir).unwrap();
    let want = [0.4f64, 1.0, 2.0].map(|s| (-s).exp());
    for (what, desc) in [("grid slab", desc), ("two half slabs", desc_two)] {
        let scene = Scene::build(&desc.unwrap()).unwrap();
        let px = image(&scene, &settings(32, 32, IntegratorKind::Volpath));
        assert_mean(what, &px, want, 0.01);
    }
}

/// A global absorbing smoke, and a clear interface sphere at (0.3, 0, 0) of radius 0.4 whose
/// exterior is that smoke (by default), seen through the smoke in front of a white sky.
fn smoke_around_a_clear_ball(ball: &str) -> String {
    format!(
        r#"{{
  "media": {{
    "smoke": {{"type": "noise", "resolution": [16, 16, 16], "seed": 5, "threshold": 0.3,
               "sigma_a": [3, 3, 3], "sigma_s": [0, 0, 0]}},
    "clear": {{"type": "homogeneous", "sigma_a": [0, 0, 0], "sigma_s": [0, 0, 0]}}
  }},
  "medium": "smoke",
  "materials": {{"boundary": {{"type": "interface"}}}},
  "objects": [{{{ball}, "material": "boundary", "interior": "clear"}}],
  "environment": {{"type": "constant", "radiance": [1, 1, 1]}},
  "camera": {{"type": "orthographic", "position": [0, 0, 3], "look_at": [0, 0, 0], "half_height": 1}}
}}"#
    )
}

#[test]
fn an_exterior_grid_stays_where_the_scene_puts_it_whatever_the_objects_transform() {
    // The same ball twice: by its own centre and radius, and as a unit sphere moved and scaled
    // by its transform. A ray that leaves the ball goes on in the scene's smoke, in world
    // space, not in a copy of the smoke moved by the ball's transform.
    let own = load(&smoke_around_a_clear_ball(
        r#""shape": {"type": "sphere", "center": [0.3, 0, 0], "radius": 0.4}"#,
    ));
    let moved = load(&smoke_around_a_clear_ball(
        r#""shape": {"type": "sphere", "radius": 1},
           "transform": {"scale": 0.4, "translate": [0.3, 0, 0]}"#,
    ));
    let s = settings(32, 16, IntegratorKind::Volpath);
    let (a, b) = (image(&own, &s), image(&moved, &s));
    let (mean, _) = stats(&a);
    assert!(mean[0] < 0.9, "the smoke absorbs: mean {mean:?}");
    assert_mean(
        "ball by transform − ball by centre",
        &differences(&b, &a),
        [0.0; 3],
        0.01,
    );
}

#[test]
fn an_exterior_grid_held_by_several_objects_is_refused() {
    let json = r#"{
  "media": {"smoke": {"type": "noise", "sigma_a": [1, 1, 1], "sigma_s": [0, 0, 0]}},
  "materials": {"boundary": {"type": "interface"}},
  "objects": [
    {"shape": {"type": "sphere", "center": [-2, 0, 0]}, "material": "boundary", "interior": "smoke"},
    {"shape": {"type": "sphere", "center": [2, 0, 0]}, "material": "boundary", "interior": "smoke"},
    {"shape": {"type": "sphere", "radius": 0.1}, "material": "boundary", "exterior": "smoke"}
  ],
  "camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]}
}"#;
    // The JSON loader names the field and its line.
    let msg = parse_json(json, Path::new("."), Path::new("test.json"))
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("at objects[2].exterior (line 7)") && msg.contains("held by several objects"),
        "{msg}"
    );
    // A description made otherwise is refused when it is built.
    let held_twice = json.replace(r#", "exterior": "smoke""#, "");
    let mut desc = parse_json(&held_twice, Path::new("."), Path::new("test.json")).unwrap();
    desc.objects[2].media = Some(raytile_core::scene::desc::ObjectMedia {
        interior: None,
        exterior: Some(0),
    });
    let Err(err) = Scene::build(&desc) else {
        panic!("an ambiguous exterior grid is an error");
    };
    let msg = err.to_string();
    assert!(msg.contains("held by several objects"), "{msg}");
}

#[test]
fn debug_outputs_see_through_interfaces_as_path_does() {
    // A grey wall lit by a lamp, with a foggy interface sphere in front of it: the boundary is
    // invisible to every integrator but volpath, so the debug outputs must show the wall as if
    // the sphere were not there (the wall itself, its depth from the camera, and no occlusion
    // by the sphere for the ambient-occlusion rays that leave the wall).
    let with = r#"{
  "media": {"fog": {"type": "homogeneous", "sigma_a": [0.1, 0.1, 0.1], "sigma_s": [0.5, 0.5, 0.5]}},
  "materials": {"boundary": {"type": "interface"}, "wall": {"type": "diffuse", "albedo": [0.6, 0.5, 0.4]}},
  "objects": [
    {"shape": {"type": "rectangle", "corner": [-2, -2, -1], "edge_u": [4, 0, 0], "edge_v": [0, 4, 0]}, "material": "wall"},
    {"shape": {"type": "sphere", "center": [0, 0, -0.5], "radius": 0.6}, "material": "boundary", "interior": "fog"}
  ],
  "environment": {"type": "constant", "radiance": [0.2, 0.3, 0.4]},
  "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 40}
}"#;
    let without = with.replace(
        r#",
    {"shape": {"type": "sphere", "center": [0, 0, -0.5], "radius": 0.6}, "material": "boundary", "interior": "fog"}"#,
        "",
    );
    assert_ne!(with, without);
    let (with, without) = (load(with), load(&without));
    for kind in [
        IntegratorKind::Normals,
        IntegratorKind::Albedo,
        IntegratorKind::Depth,
        IntegratorKind::Ao,
    ] {
        let s = settings(24, 4, kind);
        let (a, b) = (image(&with, &s), image(&without, &s));
        for (i, (p, q)) in a.iter().zip(&b).enumerate() {
            for c in 0..3 {
                assert!(
                    (p[c] - q[c]).abs() <= 1e-4 * q[c].abs().max(1.0),
                    "{kind:?}: pixel {i} is {p:?} with the interface sphere, {q:?} without"
                );
            }
        }
    }
}
