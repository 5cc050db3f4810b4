//! Estimates read off rendered images, for tests that compare an integrator with a known
//! value or with another integrator: pixels are independent estimates, so the image's mean
//! has a standard error measured from the image itself. Also the scenes several of those
//! tests render (each test uses a part of this module).
#![allow(dead_code)]

use raytile_core::scene::json::parse_json;
use raytile_core::{render, RenderJob, RenderSettings, Scene};
use std::path::Path;

/// A scene from JSON text.
pub fn load(json: &str) -> Scene {
    let desc = parse_json(json, Path::new("."), Path::new("test.json")).unwrap();
    Scene::build(&desc).unwrap()
}

/// A scene of the repository's `scenes/` folder.
pub fn load_file(name: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes")
        .join(name);
    Scene::build(&raytile_core::load_scene(&path).unwrap()).unwrap()
}

/// The image's pixels.
pub fn image(scene: &Scene, s: &RenderSettings) -> Vec<[f32; 3]> {
    let job = RenderJob::new(scene, s).unwrap();
    let film = render(scene, &job, &());
    assert_eq!(film.bad_samples, 0, "NaN or infinite samples");
    film.resolve()
}

/// Mean and standard error of the mean, per channel, of per-pixel values.
pub fn stats(px: &[[f32; 3]]) -> ([f64; 3], [f64; 3]) {
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
pub fn assert_mean(what: &str, px: &[[f32; 3]], want: [f64; 3], max_se: f64) {
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

/// Pixel by pixel differences `a − b`: independent across pixels, mean 0 when both images
/// have the same expectation, whatever the picture.
pub fn differences(a: &[[f32; 3]], b: &[[f32; 3]]) -> Vec<[f32; 3]> {
    a.iter()
        .zip(b)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
        .collect()
}

/// `scenes/caustic.json` with its small area light swapped for a point light of
/// `intensity` W/sr at the same place.
pub fn caustic_under_point_light() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/caustic.json");
    let json = std::fs::read_to_string(path).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let objects = v["objects"].as_array_mut().unwrap();
    objects.retain(|o| o["name"] != "lamp");
    v["lights"] =
        serde_json::json!([{"type": "point", "position": [0, 3, 0], "intensity": [10, 10, 10]}]);
    load(&v.to_string())
}

/// Mean of the `r`-pixel square around film position `c`.
pub fn region_mean(px: &[[f32; 3]], w: u32, c: glam::Vec2, r: i32) -> f64 {
    let (cx, cy) = (c.x as i32, c.y as i32);
    let mut sum = 0.0;
    let mut n = 0;
    for y in cy - r..=cy + r {
        for x in cx - r..=cx + r {
            let p = px[(y as u32 * w + x as u32) as usize];
            sum += (p[0] + p[1] + p[2]) as f64 / 3.0;
            n += 1;
        }
    }
    sum / n as f64
}

/// Light from a point light focused by the glass ball of [`caustic_under_point_light`] onto
/// the floor below it: no path from the camera can find the point light after the
/// refractions, so `path` leaves the floor under the ball black (its shadow); `integrator`
/// (which carries light from the lights) renders the caustic brighter than the directly lit
/// floor beside the shadow, which it renders as `path` does (within 10 %). 48×36, 16 spp,
/// depth 8.
pub fn check_caustic_under_point_light(integrator: raytile_core::IntegratorKind) {
    use raytile_core::IntegratorKind;
    let scene = caustic_under_point_light();
    let (w, h) = (48, 36);
    let settings = |integrator| RenderSettings {
        width: w,
        height: h,
        spp: 16,
        max_depth: 8,
        integrator,
        ..Default::default()
    };
    let job = RenderJob::new(&scene, &settings(integrator)).unwrap();
    // Where the floor point under the ball lands on the film.
    let centre = job
        .camera
        .sample_wi(glam::Vec3A::ZERO, glam::Vec2::ZERO)
        .unwrap()
        .raster;
    // Beside the ball's shadow, the floor lit straight by the lamp.
    let lit = job
        .camera
        .sample_wi(glam::Vec3A::new(1.2, 0.0, 0.6), glam::Vec2::ZERO)
        .unwrap()
        .raster;
    let name = integrator.name();
    let it = image(&scene, &settings(integrator));
    let path = image(&scene, &settings(IntegratorKind::Path));
    let caustic_it = region_mean(&it, w, centre, 1);
    let caustic_path = region_mean(&path, w, centre, 1);
    let lit_it = region_mean(&it, w, lit, 1);
    let lit_path = region_mean(&path, w, lit, 1);
    eprintln!(
        "caustic at {centre}: {name} {caustic_it:.4}, path {caustic_path:.4}; \
         lit floor at {lit}: {name} {lit_it:.4}, path {lit_path:.4}"
    );
    assert!(lit_path > 0.05, "the lamp lights the floor: {lit_path}");
    assert!(
        (lit_it - lit_path).abs() < 0.1 * lit_path,
        "directly lit floor: {name} {lit_it} vs path {lit_path}"
    );
    assert!(
        caustic_path < 1e-3,
        "path renders no caustic: {caustic_path}"
    );
    assert!(
        caustic_it > 3.0 * lit_path,
        "{name} renders the caustic brighter than the directly lit floor: {caustic_it} vs {lit_path}"
    );
}
