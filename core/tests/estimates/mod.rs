//! Estimates read off rendered images, for tests that compare an integrator with a known
//! value or with another integrator: pixels are independent estimates, so the image's mean
//! has a standard error measured from the image itself.

use raytile_core::{render, RenderJob, RenderSettings, Scene};

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
