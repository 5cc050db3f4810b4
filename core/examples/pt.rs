//! Path-tracer timing without the CLI (quick to build): renders a scene several times and prints
//! samples/s for each run and a hash of the image bits, to compare builds and code changes.
//!
//!     cargo run --release -p raytile-core --example pt -- SCENE [SPP] [RUNS]

use raytile_core::{load_scene, render, RenderJob, RenderSettings, Scene};
use std::hash::{DefaultHasher, Hasher};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args
        .get(1)
        .map_or("../shared/scenes/cornell-box.gltf", |s| s.as_str());
    let spp: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(64);
    let runs: u32 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(3);
    let desc = load_scene(path.as_ref()).expect("scene loads");
    let settings = RenderSettings {
        width: 256,
        height: 256,
        spp,
        max_depth: 1000,
        ..Default::default()
    };
    let scene = Scene::build(&desc).expect("scene builds");
    let job = RenderJob::new(&scene, &settings).expect("settings are valid");
    for _ in 0..runs {
        let t = Instant::now();
        let film = render(&scene, &job, &());
        let secs = t.elapsed().as_secs_f64();
        let mut h = DefaultHasher::new();
        for p in film.resolve() {
            for c in p {
                h.write_u32(c.to_bits());
            }
        }
        let n = settings.width as f64 * settings.height as f64 * spp as f64;
        println!(
            "{:.3} Msamples/s ({secs:.3} s), image hash {:016x}",
            n / secs / 1e6,
            h.finish()
        );
    }
}
