//! Writes raytile's studio environment: a procedural photo studio as an equirectangular
//! Radiance `.hdr` map (linear RGB), the map `scenes/studio.hdr` was made with:
//!
//!     cargo run -p raytile-core --example studio -- scenes/studio.hdr [WIDTH]
//!
//! A warm grey room (brighter towards the horizon, a darker floor) with three softboxes: a
//! large key light in front of the model, up and to its left (seen from the default camera),
//! a weaker fill light on the other side and a narrow strip light behind it for the rim, plus
//! a round light overhead. Same bits on every machine (plain arithmetic, no randomness).
//! The map uses raytile's convention (see `raytile_core::light::environment`): the centre of the
//! image lies towards −Z (in front of a default camera, behind the model), the top row is +Y.

/// A softbox: a rounded rectangle on the sphere, in degrees of azimuth (0 towards −Z, 90
/// towards +X) and elevation, with soft edges.
struct Softbox {
    azimuth: f32,
    elevation: f32,
    width: f32,
    height: f32,
    radiance: [f32; 3],
}

const SOFTBOXES: [Softbox; 4] = [
    // Key: in front of the model (the camera's side is +Z, azimuth 180), up, to the left.
    Softbox {
        azimuth: -145.0,
        elevation: 30.0,
        width: 40.0,
        height: 28.0,
        radiance: [14.0, 13.3, 12.0],
    },
    // Fill: the other side, lower, cooler and weaker.
    Softbox {
        azimuth: 125.0,
        elevation: 15.0,
        width: 34.0,
        height: 30.0,
        radiance: [3.6, 3.8, 4.2],
    },
    // Rim: a narrow strip behind the model.
    Softbox {
        azimuth: 20.0,
        elevation: 25.0,
        width: 10.0,
        height: 40.0,
        radiance: [10.0, 10.0, 10.0],
    },
    // Overhead.
    Softbox {
        azimuth: 0.0,
        elevation: 90.0,
        width: 360.0,
        height: 24.0,
        radiance: [2.5, 2.5, 2.5],
    },
];

/// 1 inside, 0 outside, a smooth ramp of `soft` across the edge at `half`.
fn inside(d: f32, half: f32, soft: f32) -> f32 {
    let t = ((half + soft * 0.5 - d.abs()) / soft).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Radiance arriving from azimuth `az` and elevation `el` (degrees).
fn studio(az: f32, el: f32) -> [f32; 3] {
    // The room: warm grey, brightest at the horizon, a darker floor.
    let wall = 0.22 + 0.18 * (1.0 - (el / 90.0).abs()).powi(2);
    let mut c = if el >= 0.0 {
        [wall, wall * 0.97, wall * 0.92]
    } else {
        let f = 0.12 + 0.1 * (1.0 + el / 90.0);
        [f, f * 0.96, f * 0.9]
    };
    for b in &SOFTBOXES {
        let mut daz = (az - b.azimuth).rem_euclid(360.0);
        if daz > 180.0 {
            daz -= 360.0;
        }
        // Azimuth distance measured along the sphere at the box's elevation.
        let daz = daz * b.elevation.to_radians().cos().max(0.0);
        let del = el - b.elevation;
        let w = if b.width >= 360.0 {
            1.0
        } else {
            inside(daz, b.width * 0.5, 4.0)
        } * inside(del, b.height * 0.5, 4.0);
        for (ci, bi) in c.iter_mut().zip(b.radiance) {
            *ci += w * bi;
        }
    }
    c
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(out) = args.get(1) else {
        eprintln!("usage: studio OUT.hdr [WIDTH]");
        std::process::exit(2);
    };
    let w: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(256);
    let h = (w / 2).max(1);
    // Each texel is the average of 4 × 4 points inside it, so the softbox edges are smooth.
    const SUB: u32 = 4;
    let mut pixels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0.0f32; 3];
            for sy in 0..SUB {
                for sx in 0..SUB {
                    let u = (x as f32 + (sx as f32 + 0.5) / SUB as f32) / w as f32;
                    let v = (y as f32 + (sy as f32 + 0.5) / SUB as f32) / h as f32;
                    // u = 0.5 + φ/2π with φ = atan2(d.x, −d.z); v = θ/π from +Y.
                    let az = (u - 0.5) * 360.0;
                    let el = 90.0 - v * 180.0;
                    for (a, c) in acc.iter_mut().zip(studio(az, el)) {
                        *a += c;
                    }
                }
            }
            let n = (SUB * SUB) as f32;
            pixels.push(image::Rgb([acc[0] / n, acc[1] / n, acc[2] / n]));
        }
    }
    let file = std::fs::File::create(out).unwrap_or_else(|e| {
        eprintln!("{out}: {e}");
        std::process::exit(1);
    });
    image::codecs::hdr::HdrEncoder::new(std::io::BufWriter::new(file))
        .encode(&pixels, w as usize, h as usize)
        .unwrap_or_else(|e| {
            eprintln!("{out}: {e}");
            std::process::exit(1);
        });
    eprintln!("wrote {out} ({w}x{h})");
}
