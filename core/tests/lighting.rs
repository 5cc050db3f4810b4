//! Lighting of glTF-style scenes: index-matched bodies leave the image unchanged, and the
//! default light rule (which models get the default environment).

use glam::{Mat4, Vec3};
use raytile_core::scene::desc::*;
use raytile_core::scene::load_scene;
use raytile_core::{render, RenderJob, RenderSettings, Scene};
use std::path::Path;

fn repo(p: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(p)
}

/// Renders `desc` (its own max depth) at `size`² and `spp`; linear RGB pixels, row-major.
fn render_desc(desc: &SceneDesc, size: u32, spp: u32, seed: u32) -> Vec<Vec3> {
    let settings = RenderSettings {
        width: size,
        height: size,
        spp,
        seed,
        max_depth: 64,
        ..Default::default()
    };
    let scene = Scene::build(desc).unwrap_or_else(|e| panic!("{e}"));
    let job = RenderJob::new(&scene, &settings).unwrap_or_else(|e| panic!("{e}"));
    let film = render(&scene, &job, &());
    assert_eq!(film.bad_samples, 0);
    film.resolve().into_iter().map(Vec3::from).collect()
}

fn mean(px: &[Vec3]) -> f64 {
    px.iter().map(|p| p.element_sum() as f64 / 3.0).sum::<f64>() / px.len() as f64
}

/// The Cornell box with a glTF-style ball of transmission 1 and ior 1.0 in it: a body
/// (`KHR_materials_volume`) or a thin-walled shell, smooth or rough.
fn cornell_with_matched_ball(roughness: f32, thin_walled: bool) -> SceneDesc {
    let mut desc = load_scene(&repo("scenes/cornell-box.json")).unwrap();
    desc.materials.push(MaterialDesc::new(
        "index-matched",
        BsdfDesc::Pbr(Box::new(PbrDesc {
            metallic: 0.0,
            roughness,
            ior: 1.0,
            transmission: 1.0,
            thin_walled,
            ..PbrDesc::default()
        })),
    ));
    desc.objects.push(ObjectDesc {
        name: "ball".into(),
        shape: ShapeDesc::Sphere {
            center: Vec3::new(0.1, -0.45, 0.2),
            radius: 0.5,
        },
        material: desc.materials.len() - 1,
        transform: Mat4::IDENTITY,
        media: None,
    });
    desc
}

/// An index-matched object is invisible: light crosses an interface between equal indices
/// unchanged (pbrt-v4's dielectric at η = 1), whatever the roughness, with or without a
/// volume. The image mean equals the empty box's within 4 standard errors of the per-pixel
/// difference (the black ball of the bug made the image 13–18 % darker).
#[test]
fn an_index_matched_ball_leaves_the_cornell_box_unchanged() {
    let (size, spp) = (32, 64);
    let base = render_desc(
        &load_scene(&repo("scenes/cornell-box.json")).unwrap(),
        size,
        spp,
        0,
    );
    let base_mean = mean(&base);
    for thin in [false, true] {
        for roughness in [0.0, 0.5] {
            // An independent seed: the difference is pure noise if the ball is invisible.
            let px = render_desc(&cornell_with_matched_ball(roughness, thin), size, spp, 1);
            let d: Vec<f64> = px
                .iter()
                .zip(&base)
                .map(|(a, b)| (*a - *b).element_sum() as f64 / 3.0)
                .collect();
            let n = d.len() as f64;
            let dm = d.iter().sum::<f64>() / n;
            let var = d.iter().map(|x| (x - dm) * (x - dm)).sum::<f64>() / (n - 1.0);
            let se = (var / n).sqrt();
            println!(
                "thin {thin} roughness {roughness}: mean {:.5} vs {base_mean:.5}, \
                 difference {dm:.5} (standard error {se:.5})",
                mean(&px)
            );
            assert!(
                dm.abs() < 4.0 * se + 1e-6,
                "thin {thin} roughness {roughness}: the ball changes the image mean by {dm} \
                 (standard error {se}, image mean {base_mean})"
            );
            assert!(
                dm.abs() < 0.02 * base_mean,
                "thin {thin} roughness {roughness}: {dm} of {base_mean}"
            );
        }
    }
}
