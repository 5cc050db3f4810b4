//! Stochastic progressive photon mapping against known answers: a closed diffuse furnace, `path`
//! on the Cornell box, the caustic of a glass ball under a point light (which `path` cannot
//! render), and bit-identical images whatever the tiling, the threads and the job's cache.
//!
//! An sppm image's pixels are not independent (neighbours share photons), so the standard
//! error of its mean is measured across renders with independent seeds, not across pixels.
//! sppm is consistent, not unbiased: the settings below (iterations, the initial radius of
//! `sppm::INITIAL_RADIUS_PIXELS`) keep the bias of the compared means under the tolerance, and
//! each test says by how much.

mod estimates;

use estimates::{caustic_under_point_light, image, load, load_file, stats};
use raytile_core::integrator::sppm;
use raytile_core::{render_tile, Cancel, IntegratorKind, RenderJob, RenderSettings};

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

/// Mean and standard error of the image mean over renders with seeds `0..seeds`.
fn seed_stats(scene: &raytile_core::Scene, s: &RenderSettings, seeds: u32) -> ([f64; 3], [f64; 3]) {
    let means: Vec<[f32; 3]> = (0..seeds)
        .map(|seed| {
            let s = RenderSettings { seed, ..s.clone() };
            let (m, _) = stats(&image(scene, &s));
            [m[0] as f32, m[1] as f32, m[2] as f32]
        })
        .collect();
    stats(&means)
}

#[test]
fn furnace_a_closed_emitting_diffuse_sphere() {
    // Inside a sphere that emits Le = 1 and reflects diffusely with albedo ρ = 0.5, radiance
    // is Le / (1 − ρ) = 2 everywhere: 1 seen directly, 0.5 by direct light at the visible
    // point, 0.5 by photons. A sphere's surface within distance r of a point on it has area
    // exactly π r², so the density estimate has no bias here.
    let scene = load(
        r#"{
  "materials": {"wall": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5],
                         "emission": [1, 1, 1], "two_sided": true}},
  "objects": [{"shape": {"type": "sphere", "radius": 1}, "material": "wall"}],
  "camera": {"position": [0, 0, 0.3], "look_at": [0, 0, -1], "fov": 60}
}"#,
    );
    let mut s = settings(24, 24, 16, IntegratorKind::Sppm);
    s.max_depth = 40;
    let (mean, se) = seed_stats(&scene, &s, 6);
    eprintln!("sppm furnace: mean {mean:.4?}, standard error {se:.4?}, want 2");
    for k in 0..3 {
        assert!(se[k] < 0.02, "too noisy: {se:?}");
        assert!(
            (mean[k] - 2.0).abs() <= 4.0 * se[k] + 1e-3,
            "{mean:?} ± {se:?}"
        );
    }
}

#[test]
fn sppm_matches_path_on_the_cornell_box() {
    let scene = load_file("cornell-box.json");
    // Both means with their standard errors across seeds (a mean over pixels varies with the
    // picture, not only with the noise).
    let (pm, pse) = seed_stats(&scene, &settings(32, 32, 16, IntegratorKind::Path), 6);
    let (sm, sse) = seed_stats(&scene, &settings(32, 32, 32, IntegratorKind::Sppm), 6);
    eprintln!("cornell: path {pm:.4?} ± {pse:.4?}, sppm {sm:.4?} ± {sse:.4?} (standard errors)");
    for k in 0..3 {
        let se = (pse[k].powi(2) + sse[k].powi(2)).sqrt();
        assert!(pm[k] > 0.05 && se < 0.005, "{pm:?} ± {se}");
        assert!(
            (sm[k] - pm[k]).abs() <= 4.0 * se + 1e-3,
            "channel {k}: sppm {} vs path {} (standard error {se})",
            sm[k],
            pm[k]
        );
    }
}

/// `max_depth` bounds the whole path: seen through a glass ball, a visible point is some delta
/// bounces from the camera, and its photons may take only the bounces left. (sppm had bounded
/// the camera and the photon paths each on its own: inside the ball at a depth of 3 it was
/// some 17 % brighter than `path`, `bdpt` and Mitsuba.)
#[test]
fn sppm_bounds_the_whole_path_by_max_depth_behind_glass() {
    ball_agrees_with_path(r#"{"type": "dielectric", "ior": 1.5}"#, 3, "");
}

/// Smooth glTF-model glass and smooth metal are not delta (their GGX alpha is clamped above
/// zero): `sppm` carries its camera paths on through them, as through delta surfaces, instead
/// of gathering photons on them, which had left a smooth glass ball at a quarter of its light
/// after 1024 iterations.
#[test]
fn sppm_sees_through_smooth_pbr_glass_and_in_smooth_metal() {
    for ball in [
        r#"{"type": "pbr", "transmission": 1, "roughness": 0}"#,
        r#"{"type": "pbr", "metallic": 1, "roughness": 0.1, "base_color": [0.9, 0.8, 0.6]}"#,
    ] {
        ball_agrees_with_path(ball, 6, "");
    }
    // A point light's glint on smooth metal: no ray can find the light, so the camera path
    // takes it from a light sample on the surface it goes on through.
    ball_agrees_with_path(
        r#"{"type": "pbr", "metallic": 1, "roughness": 0.2}"#,
        4,
        r#""lights": [{"type": "point", "position": [0.8, 1.8, 2], "intensity": [20, 20, 20]}],"#,
    );
}

/// `sppm` and `path` agree, within 4 standard errors over six seeds, on the 8 × 8 pixels at
/// the centre of a ball of material `ball` (JSON) on a floor before a wall, under a lamp, a
/// grey sky and the scene's `lights` (a JSON member and its comma, or nothing), with paths of
/// at most `max_depth` bounces.
fn ball_agrees_with_path(ball: &str, max_depth: u32, lights: &str) {
    let scene = load(&format!(
        r#"{{
  "camera": {{"position": [0, 1, 4], "look_at": [0, 0.7, 0], "fov": 40}},
  {lights}
  "materials": {{
    "floor": {{"type": "diffuse", "albedo": [0.7, 0.6, 0.5]}},
    "wall": {{"type": "diffuse", "albedo": [0.3, 0.5, 0.7]}},
    "lamp": {{"type": "emitter", "emission": [8, 8, 8]}},
    "ball": {ball}
  }},
  "objects": [
    {{"shape": {{"type": "rectangle", "corner": [-2, 0, -2], "edge_u": [0, 0, 4], "edge_v": [4, 0, 0]}}, "material": "floor"}},
    {{"shape": {{"type": "rectangle", "corner": [-2, 0, -2], "edge_u": [4, 0, 0], "edge_v": [0, 3, 0]}}, "material": "wall"}},
    {{"shape": {{"type": "rectangle", "corner": [-0.5, 2, -0.5], "edge_u": [1, 0, 0], "edge_v": [0, 0, 1]}}, "material": "lamp"}},
    {{"shape": {{"type": "sphere", "center": [0, 0.6, 0], "radius": 0.6}}, "material": "ball"}}
  ],
  "environment": {{"type": "constant", "radiance": [0.3, 0.3, 0.3]}}
}}"#
    ));
    // The mean of the 8 × 8 pixels at the image's centre, inside the ball, per seed.
    let ball_px = |s: &RenderSettings| {
        let means: Vec<[f32; 3]> = (0..6)
            .map(|seed| {
                let px = image(&scene, &RenderSettings { seed, ..s.clone() });
                let crop: Vec<[f32; 3]> = (12..20)
                    .flat_map(|y| (12..20).map(move |x| (x, y)))
                    .map(|(x, y)| px[y * 32 + x])
                    .collect();
                let (m, _) = stats(&crop);
                [m[0] as f32, m[1] as f32, m[2] as f32]
            })
            .collect();
        stats(&means)
    };
    let mut p = settings(32, 32, 64, IntegratorKind::Path);
    p.max_depth = max_depth;
    let mut q = settings(32, 32, 64, IntegratorKind::Sppm);
    q.max_depth = max_depth;
    let ((pm, pse), (sm, sse)) = (ball_px(&p), ball_px(&q));
    eprintln!("{ball}, depth {max_depth}: path {pm:.4?} ± {pse:.4?}, sppm {sm:.4?} ± {sse:.4?}");
    for k in 0..3 {
        let se = (pse[k].powi(2) + sse[k].powi(2)).sqrt();
        assert!(pm[k] > 0.05 && se < 0.04 * pm[k], "{pm:?} ± {se}");
        assert!(
            (sm[k] - pm[k]).abs() <= 4.0 * se + 0.01 * pm[k],
            "{ball}, channel {k}: sppm {} vs path {} (standard error {se})",
            sm[k],
            pm[k]
        );
    }
}

#[test]
fn the_caustic_under_a_point_light_is_there_with_sppm_and_not_with_path() {
    estimates::check_caustic_under_point_light(IntegratorKind::Sppm);
}

#[test]
fn sppm_is_deterministic_whatever_the_tiling_the_threads_and_the_cache() {
    let scene = caustic_under_point_light();
    let bits = |px: &[[f32; 3]]| px.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
    let mut s = settings(40, 30, 4, IntegratorKind::Sppm);
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
    // Every tile with a job of its own (no photon map kept from another tile): the same bits.
    s.tile_size = 16;
    let mut film = raytile_core::Film::new(s.width, s.height);
    for t in s.tiles() {
        let job = RenderJob::new(&scene, &s).unwrap();
        film.add_tile(&render_tile(&scene, &job, t, 0..s.spp, &Cancel::new()).unwrap())
            .unwrap();
    }
    assert_eq!(bits(&a), bits(&film.resolve()));
}

#[test]
fn a_job_traces_each_photon_map_once_and_keeps_it_for_its_other_tiles() {
    let scene = load_file("cornell-box.json");
    let mut s = settings(32, 32, 4, IntegratorKind::Sppm);
    s.tile_size = 16;
    let job = RenderJob::new(&scene, &s).unwrap();
    let first = sppm::photon_map(&scene, &job, 0, 0, sppm::MAP_DEPOSITS);
    let again = sppm::photon_map(&scene, &job, 0, 0, sppm::MAP_DEPOSITS);
    assert!(std::sync::Arc::ptr_eq(&first, &again));
    assert_eq!(first.traced, 32 * 32);
    assert!(job.cache_bytes() > 0);
}

#[test]
fn sppm_renders_in_one_pass() {
    let scene = load_file("cornell-box.json");
    let mut s = settings(8, 8, 4, IntegratorKind::Sppm);
    s.passes = 2;
    let e = RenderJob::new(&scene, &s).unwrap_err().to_string();
    assert!(e.contains("passes") && e.contains("sppm"), "{e}");
}

#[test]
fn sppm_refuses_an_unbounded_plane_under_the_sun_or_the_sky() {
    // Its photons would start on a disk around the finite objects and never reach the plane
    // beyond it: the plane's indirect light would be missing. A finite floor, or a plane under
    // a point light, renders.
    let scene = |floor: &str, lights: &str| {
        load(&format!(
            r#"{{"materials": {{"d": {{"type": "diffuse"}}}},
  "objects": [{{"shape": {{"type": "sphere", "radius": 0.5}}, "material": "d"}},
              {{"shape": {floor}, "material": "d"}}],
  {lights}}}"#
        ))
    };
    let plane = r#"{"type": "plane", "point": [0, -1, 0], "normal": [0, 1, 0]}"#;
    let rect = r#"{"type": "rectangle", "corner": [-5, -1, 5], "edge_u": [10, 0, 0], "edge_v": [0, 0, -10]}"#;
    let sun = r#""lights": [{"type": "directional", "direction": [0, -1, 0.2], "irradiance": [1, 1, 1]}]"#;
    let sky = r#""environment": {"type": "constant", "radiance": [1, 1, 1]}"#;
    let lamp = r#""lights": [{"type": "point", "position": [0, 3, 0], "intensity": [1, 1, 1]}]"#;
    let s = settings(8, 8, 1, IntegratorKind::Sppm);
    for lights in [sun, sky] {
        let e = RenderJob::new(&scene(plane, lights), &s)
            .unwrap_err()
            .to_string();
        assert!(e.contains("sppm cannot render an unbounded plane"), "{e}");
        assert!(RenderJob::new(&scene(rect, lights), &s).is_ok());
        let path = settings(8, 8, 1, IntegratorKind::Path);
        assert!(RenderJob::new(&scene(plane, lights), &path).is_ok());
    }
    // An environment a program adds to a job later is refused the same way.
    let job = RenderJob::new(&scene(plane, lamp), &s).unwrap();
    let sky = std::sync::Arc::new(raytile_core::light::Environment::constant(glam::Vec3A::ONE));
    let e = job
        .with_environment(&scene(plane, lamp), Some(sky))
        .unwrap_err()
        .to_string();
    assert!(e.contains("sppm cannot render an unbounded plane"), "{e}");
}

/// What a farm's coordinator checks from a scene's description (`SppmFacts`) refuses exactly
/// the jobs a worker's `RenderJob::new` refuses: scenes with and without a plane, under the
/// sun, the sky, a lamp or the default light an unlit glTF model gets, and jobs that bring
/// their own environment, none, or turn the default light off.
#[test]
fn the_facts_a_coordinator_keeps_refuse_what_a_worker_refuses() {
    use raytile_core::scene::{json::parse_json, Scene};
    use raytile_core::EnvironmentChoice as Env;
    let plane = r#"{"type": "plane", "point": [0, -1, 0], "normal": [0, 1, 0]}"#;
    let rect = r#"{"type": "rectangle", "corner": [-5, -1, 5], "edge_u": [10, 0, 0], "edge_v": [0, 0, -10]}"#;
    let sun = r#""lights": [{"type": "directional", "direction": [0, -1, 0.2], "irradiance": [1, 1, 1]}]"#;
    let sky = r#""environment": {"type": "constant", "radiance": [1, 1, 1]}"#;
    let lamp = r#""lights": [{"type": "point", "position": [0, 3, 0], "intensity": [1, 1, 1]}]"#;
    let mut descs = Vec::new();
    for floor in [plane, rect] {
        for lights in [sun, sky, lamp] {
            let text = format!(
                r#"{{"materials": {{"d": {{"type": "diffuse"}}}},
  "objects": [{{"shape": {{"type": "sphere", "radius": 0.5}}, "material": "d"}},
              {{"shape": {floor}, "material": "d"}}],
  {lights}}}"#
            );
            descs.push(parse_json(&text, ".".as_ref(), "t.json".as_ref()).unwrap());
        }
        // Unlit, with the default light a glTF loader adds.
        let mut unlit = descs.last().unwrap().clone();
        unlit.lights.clear();
        unlit.environment = descs[1].environment.clone();
        unlit.default_environment = true;
        descs.push(unlit);
    }
    let mut refused = 0;
    for desc in &descs {
        let facts = desc.sppm_facts();
        let scene = Scene::build(desc).unwrap();
        for env in [None, Some(Env::None), Some(Env::Constant([0.5; 3]))] {
            for (integrator, default_light) in [
                (IntegratorKind::Sppm, true),
                (IntegratorKind::Sppm, false),
                (IntegratorKind::Path, true),
            ] {
                let s = RenderSettings {
                    environment: env.clone(),
                    default_light,
                    ..settings(8, 8, 1, integrator)
                };
                let worker = RenderJob::new(&scene, &s)
                    .map(drop)
                    .map_err(|e| e.to_string());
                let coordinator = facts.check(&s);
                assert_eq!(
                    coordinator.is_err(),
                    worker.is_err(),
                    "{env:?} {s:?}: {worker:?}"
                );
                if let (Err(c), Err(w)) = (&coordinator, &worker) {
                    assert!(w.contains(c.as_str()), "{w} / {c}");
                    refused += 1;
                }
            }
        }
    }
    assert!(refused >= 8, "{refused}");
}

#[test]
fn the_initial_radius_follows_what_the_camera_sees_not_the_scenes_extent() {
    // scenes/caustic.json's glass ball over a floor, with the floor 4 m or 2 km wide, or with
    // a 1 cm speck 100 km away: the camera sees much the same (more floor towards the horizon
    // under the wide floor), so the search radius is much the same. It used to grow with the
    // scene's bounding sphere (to some 140 m under the wide floor) until the caustic blurred
    // away.
    let scene = |floor: f32, speck: bool| {
        let speck = if speck {
            r#", {"shape": {"type": "sphere", "center": [1e5, 0, 0], "radius": 0.01}, "material": "floor"}"#
        } else {
            ""
        };
        load(&format!(
            r#"{{"camera": {{"position": [0, 1.6, 3.2], "look_at": [0, 0.3, 0], "fov": 40}},
  "materials": {{"floor": {{"type": "diffuse"}}, "glass": {{"type": "dielectric", "ior": 1.5}},
                 "lamp": {{"type": "emitter", "emission": [1000, 1000, 1000]}}}},
  "objects": [
    {{"shape": {{"type": "rectangle", "corner": [{h}, 0, {h}], "edge_u": [0, 0, {floor}],
                "edge_v": [{floor}, 0, 0]}}, "material": "floor"}},
    {{"shape": {{"type": "sphere", "center": [0, 1, 0], "radius": 0.5}}, "material": "glass"}},
    {{"shape": {{"type": "disk", "center": [0, 3, 0], "normal": [0, -1, 0], "radius": 0.05}},
     "material": "lamp"}}{speck}]}}"#,
            h = -floor / 2.0
        ))
    };
    let s = settings(80, 60, 1, IntegratorKind::Sppm);
    let radius = |scene: &raytile_core::Scene| {
        sppm::initial_radius(scene, &RenderJob::new(scene, &s).unwrap())
    };
    let small = radius(&scene(4.0, false));
    // Two pixel widths on the floor about 3.5 m from the camera: 2 · 3.5 · 2 tan 20° / 60.
    assert!((0.03..0.1).contains(&small), "{small}");
    let speck = radius(&scene(4.0, true));
    assert_eq!(speck, small);
    let wide = radius(&scene(2000.0, false));
    assert!((wide / small - 1.0).abs() < 0.25, "{wide} against {small}");
    // A camera that sees nothing: the scene's extent.
    let away = load(
        r#"{"camera": {"position": [0, 0, 0], "look_at": [0, 0, 1]},
        "materials": {"d": {"type": "diffuse"}},
        "objects": [{"shape": {"type": "sphere", "center": [0, 0, -5], "radius": 1}, "material": "d"}]}"#,
    );
    let r = radius(&away);
    assert!(r.is_finite() && r > 0.0, "{r}");
}
