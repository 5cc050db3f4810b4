//! A procedural density: deterministic 3D value noise summed over octaves (fBm), for tests and
//! example scenes without a grid file.

use crate::sampling::hash_u32;
use glam::Vec3A;

/// Cloud-like density from fractal value noise.
///
/// `density(p) = max(0, (fbm(p · frequency) − threshold) · gain)` with `fbm` in [0, 1): a
/// weighted sum of `octaves` layers of value noise, each twice the frequency and half the
/// weight of the one before. Lattice values come from a hash of the integer lattice point and
/// `seed`, interpolated with a quintic fade, so the function is C² and uses only `+`, `*` and
/// `floor`: the same bits on every machine. Bake it into a grid with
/// [`super::DensityGrid::from_fn`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseDensity {
    /// Selects an independent noise pattern.
    pub seed: u32,
    /// Lattice cells per unit length of the first octave.
    pub frequency: f32,
    /// Number of octaves (1 to 16).
    pub octaves: u32,
    /// fBm values below this give density 0: higher thresholds give sparser clouds.
    pub threshold: f32,
    /// Density per unit of fBm above the threshold.
    pub gain: f32,
}

impl Default for NoiseDensity {
    fn default() -> Self {
        Self {
            seed: 0,
            frequency: 4.0,
            octaves: 4,
            threshold: 0.45,
            gain: 4.0,
        }
    }
}

/// A lattice value in [0, 1) for integer point (`x`, `y`, `z`).
#[inline]
fn lattice(x: i32, y: i32, z: i32, seed: u32) -> f32 {
    let h = hash_u32(
        (x as u32)
            ^ hash_u32(
                (y as u32) ^ hash_u32((z as u32) ^ hash_u32(seed.wrapping_add(0x2545_f491))),
            ),
    );
    (h >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// 6t⁵ − 15t⁴ + 10t³: zero first and second derivatives at 0 and 1.
#[inline]
fn fade(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// One octave of value noise in [0, 1).
fn value_noise(p: Vec3A, seed: u32) -> f32 {
    // Far from the origin f32 has no fractional part left; clamp to keep the casts defined.
    let p = p.clamp(Vec3A::splat(-1e7), Vec3A::splat(1e7));
    let fl = p.floor();
    let f = p - fl;
    let (x, y, z) = (fl.x as i32, fl.y as i32, fl.z as i32);
    let (u, v, w) = (fade(f.x), fade(f.y), fade(f.z));
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let c = |dx: i32, dy: i32, dz: i32| lattice(x + dx, y + dy, z + dz, seed);
    let x00 = lerp(c(0, 0, 0), c(1, 0, 0), u);
    let x10 = lerp(c(0, 1, 0), c(1, 1, 0), u);
    let x01 = lerp(c(0, 0, 1), c(1, 0, 1), u);
    let x11 = lerp(c(0, 1, 1), c(1, 1, 1), u);
    lerp(lerp(x00, x10, v), lerp(x01, x11, v), w)
}

impl NoiseDensity {
    /// fBm in [0, 1) at `p`.
    pub fn fbm(&self, p: Vec3A) -> f32 {
        let octaves = self.octaves.clamp(1, 16);
        let (mut sum, mut weight, mut total, mut freq) = (0.0f32, 1.0f32, 0.0f32, self.frequency);
        for o in 0..octaves {
            sum += weight * value_noise(p * freq, self.seed.wrapping_add(o.wrapping_mul(0x9e37)));
            total += weight;
            weight *= 0.5;
            freq *= 2.0;
        }
        sum / total
    }

    /// The density at `p` (non-negative, finite for finite parameters).
    pub fn density(&self, p: Vec3A) -> f32 {
        ((self.fbm(p) - self.threshold) * self.gain).max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::medium::testutil::Rng;

    #[test]
    fn noise_is_deterministic_bounded_and_varied() {
        let n = NoiseDensity::default();
        let mut rng = Rng::new(5);
        let (mut lo, mut hi, mut zero) = (f32::MAX, f32::MIN, 0);
        for _ in 0..5000 {
            let p = Vec3A::new(rng.f32(), rng.f32(), rng.f32()) * 3.0 - 1.0;
            let f = n.fbm(p);
            assert!((0.0..1.0).contains(&f), "{f}");
            assert_eq!(f.to_bits(), n.fbm(p).to_bits());
            lo = lo.min(f);
            hi = hi.max(f);
            let d = n.density(p);
            assert!(d >= 0.0 && d.is_finite());
            zero += (d == 0.0) as u32;
        }
        assert!(hi - lo > 0.4, "range {lo}..{hi}");
        // Both empty and filled regions: what a majorant grid is for.
        assert!(zero > 500 && zero < 4500, "{zero} of 5000 empty");
        // Another seed, another pattern.
        let other = NoiseDensity { seed: 7, ..n };
        assert_ne!(other.fbm(Vec3A::splat(0.3)), n.fbm(Vec3A::splat(0.3)));
    }

    #[test]
    fn noise_is_continuous_across_lattice_faces() {
        let n = NoiseDensity {
            octaves: 1,
            frequency: 1.0,
            ..Default::default()
        };
        for i in -3..3 {
            let x = i as f32;
            let a = n.fbm(Vec3A::new(x - 1e-4, 0.3, 0.7));
            let b = n.fbm(Vec3A::new(x + 1e-4, 0.3, 0.7));
            assert!((a - b).abs() < 1e-3, "{x}: {a} vs {b}");
        }
        // Far away and for NaN-free but huge inputs it stays defined.
        assert!(n.fbm(Vec3A::splat(1e30)).is_finite());
    }
}
