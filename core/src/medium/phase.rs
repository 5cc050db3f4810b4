//! The Henyey–Greenstein phase function.
//!
//! Convention (pbrt-v4's, `PhaseFunction::p(wo, wi)`): both directions point *away* from the
//! scattering point. `wo` points back to where the light is going (the camera side: it is
//! `-ray.d` of the ray that reached the point) and `wi` to where it comes from. Light that keeps
//! going straight on has `wi == -wo`, so forward scattering (`g > 0`) makes `p` largest when
//! `dot(wo, wi) = -1`. The value depends only on that cosine:
//!
//! p(wo, wi) = (1 − g²) / (4π (1 + g² + 2g·dot(wo, wi))^{3/2})
//!
//! and `g` is the mean cosine of the deflection, E[dot(-wo, wi)] = g.

use crate::sampling::warp::{sincos_2pi, Frame};
use glam::{Vec2, Vec3A};
use std::f32::consts::PI;

/// 1 / 4π: the isotropic phase function.
pub const INV_4PI: f32 = 1.0 / (4.0 * PI);

/// Below this |g| the function is taken as isotropic (`g` is stored as 0): the relative
/// difference from 1/4π is below 3|g| = 3e-5, and sampling the exact inverse CDF would lose
/// all its precision to cancellation.
const ISOTROPIC_BELOW: f32 = 1e-5;

/// A Henyey–Greenstein phase function with asymmetry `g` in (-1, 1): 0 scatters isotropically,
/// positive `g` forward, negative backward. Small and `Copy`, made per medium sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HenyeyGreenstein {
    g: f32,
}

/// A direction sampled from a phase function.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseSample {
    /// The sampled incident direction (unit, pointing away from the scattering point).
    pub wi: Vec3A,
    /// p(wo, wi).
    pub value: f32,
    /// The density the direction was sampled with (solid angle). Sampling is exact, so it
    /// equals `value`, and the path throughput is multiplied by `value / pdf = 1`.
    pub pdf: f32,
}

impl HenyeyGreenstein {
    /// Isotropic scattering.
    pub const ISOTROPIC: Self = Self { g: 0.0 };

    /// The phase function with asymmetry `g`, or `None` unless -1 < g < 1.
    pub fn new(g: f32) -> Option<Self> {
        if !(g > -1.0 && g < 1.0) {
            return None;
        }
        let g = if g.abs() < ISOTROPIC_BELOW { 0.0 } else { g };
        Some(Self { g })
    }

    /// The asymmetry parameter (0 when it was below 1e-5 in magnitude).
    #[inline]
    pub fn g(&self) -> f32 {
        self.g
    }

    /// p as a function of `cos_theta = dot(wo, wi)`.
    #[inline]
    pub fn eval_cos(&self, cos_theta: f32) -> f32 {
        let g = self.g;
        if g == 0.0 {
            return INV_4PI;
        }
        // 1 + g² + 2g·c written as a sum of two non-negative terms, so that strongly peaked
        // functions (g near ±1) neither cancel to zero nor go negative through rounding.
        let c = cos_theta.clamp(-1.0, 1.0);
        let denom = if g > 0.0 {
            (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 + c)
        } else {
            (1.0 + g) * (1.0 + g) - 2.0 * g * (1.0 - c)
        };
        INV_4PI * (1.0 - g * g) / (denom * denom.sqrt())
    }

    /// p(wo, wi) for unit directions (see the module documentation for the convention).
    #[inline]
    pub fn eval(&self, wo: Vec3A, wi: Vec3A) -> f32 {
        self.eval_cos(wo.dot(wi))
    }

    /// The density [`HenyeyGreenstein::sample`] draws `wi` with: equal to `eval`.
    #[inline]
    pub fn pdf(&self, wo: Vec3A, wi: Vec3A) -> f32 {
        self.eval(wo, wi)
    }

    /// Samples `wi` for unit `wo` from two uniform numbers in [0, 1), exactly proportional to
    /// p (the inverse of its CDF in the cosine, a uniform azimuth).
    #[inline]
    pub fn sample(&self, wo: Vec3A, u: Vec2) -> PhaseSample {
        let g = self.g;
        let cos_theta = if g == 0.0 {
            1.0 - 2.0 * u.x
        } else {
            // pbrt-v4's inversion, in f64: for small |g| the numerator is a difference of
            // nearly equal numbers. `u = 0` gives cos = -1 (straight on) for g > 0.
            let g = g as f64;
            let s = (1.0 - g * g) / (1.0 + g - 2.0 * g * u.x as f64);
            ((-(1.0 + g * g - s * s) / (2.0 * g)) as f32).clamp(-1.0, 1.0)
        };
        let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
        let (sin_phi, cos_phi) = sincos_2pi(u.y);
        let local = Vec3A::new(sin_theta * cos_phi, sin_theta * sin_phi, cos_theta);
        let wi = Frame::from_z(wo).to_world(local);
        let value = self.eval_cos(cos_theta);
        PhaseSample {
            wi,
            value,
            pdf: value,
        }
    }
}

impl Default for HenyeyGreenstein {
    fn default() -> Self {
        Self::ISOTROPIC
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::warp::uniform_sphere;

    const GS: [f32; 7] = [0.0, 0.3, -0.3, 0.7, -0.8, 0.95, 2e-4];

    /// A low-discrepancy point in [0,1)² (Hammersley-like with a golden-ratio second axis).
    fn qmc(i: u32, n: u32) -> Vec2 {
        Vec2::new(
            (i as f32 + 0.5) / n as f32,
            (i as f64 * 0.618_033_988_749_894_9).fract() as f32,
        )
    }

    fn wo() -> Vec3A {
        Vec3A::new(0.3, -0.4, 0.866).normalize()
    }

    #[test]
    fn g_outside_the_open_interval_is_refused() {
        for g in [-1.0, 1.0, 1.5, f32::NAN, f32::INFINITY] {
            assert!(HenyeyGreenstein::new(g).is_none(), "{g}");
        }
        assert_eq!(HenyeyGreenstein::new(3e-6).unwrap().g(), 0.0);
        assert_eq!(HenyeyGreenstein::new(0.5).unwrap().g(), 0.5);
    }

    #[test]
    fn isotropic_is_exactly_one_over_four_pi() {
        let p = HenyeyGreenstein::new(0.0).unwrap();
        for i in 0..100 {
            let s = p.sample(wo(), qmc(i, 100));
            assert_eq!(s.value, INV_4PI);
            assert_eq!(s.pdf, INV_4PI);
            assert_eq!(p.eval(wo(), s.wi), INV_4PI);
        }
    }

    #[test]
    fn integrates_to_one_over_the_sphere() {
        let n = 200_000;
        for g in GS {
            let p = HenyeyGreenstein::new(g).unwrap();
            let mut sum = 0.0f64;
            for i in 0..n {
                let wi = uniform_sphere(qmc(i, n));
                sum += p.eval(wo(), wi) as f64 * 4.0 * std::f64::consts::PI;
            }
            let mean = sum / n as f64;
            // Peaked functions need more points: the tolerance follows the peak's height.
            let tol = if g.abs() > 0.9 { 0.02 } else { 2e-3 };
            assert!((mean - 1.0).abs() < tol, "g = {g}: ∫p = {mean}");
        }
    }

    #[test]
    fn samples_are_unit_and_value_equals_pdf() {
        for g in GS {
            let p = HenyeyGreenstein::new(g).unwrap();
            for i in 0..1000 {
                let s = p.sample(wo(), qmc(i, 1000));
                assert!((s.wi.length() - 1.0).abs() < 1e-5);
                assert_eq!(s.value, s.pdf);
                let back = p.pdf(wo(), s.wi);
                assert!(
                    (back - s.pdf).abs() <= 2e-3 * s.pdf,
                    "g = {g}: {back} vs {}",
                    s.pdf
                );
            }
        }
    }

    #[test]
    fn mean_cosine_equals_g() {
        let n = 100_000;
        for g in GS {
            let p = HenyeyGreenstein::new(g).unwrap();
            let mut sum = 0.0f64;
            for i in 0..n {
                let s = p.sample(wo(), qmc(i, n));
                sum += (-wo()).dot(s.wi) as f64;
            }
            let mean = sum / n as f64;
            assert!(
                (mean - p.g() as f64).abs() < 2e-3,
                "g = {g}: mean cosine {mean}"
            );
        }
    }

    #[test]
    fn forward_scattering_peaks_where_light_goes_straight_on() {
        // A camera ray travelling along +Z reaches the point, so wo = -Z (back to the camera).
        // Light that passes the point undeflected on its way to the camera travels along -Z,
        // so it came from +Z: wi = +Z = -wo.
        let p = HenyeyGreenstein::new(0.8).unwrap();
        let wo = -Vec3A::Z;
        let straight = p.eval(wo, Vec3A::Z);
        let back = p.eval(wo, -Vec3A::Z);
        assert!(straight > 100.0 * back, "{straight} vs {back}");
        assert!((straight - 0.36 / (4.0 * PI * 0.2f32.powi(3))).abs() < 1e-3 * straight);
        // Samples follow: most continue along +Z.
        let mut ahead = 0;
        for i in 0..1000 {
            if p.sample(wo, qmc(i, 1000)).wi.z > 0.0 {
                ahead += 1;
            }
        }
        assert!(ahead > 900, "{ahead} of 1000 ahead");
        // Back scattering mirrors it.
        let b = HenyeyGreenstein::new(-0.8).unwrap();
        assert!((b.eval(wo, -Vec3A::Z) - straight).abs() < 1e-3 * straight);
    }

    #[test]
    fn sample_histogram_matches_the_pdf() {
        // Chi-square over bins of cos θ (azimuth is uniform by construction): 20 bins,
        // 10⁵ pseudo-random samples; the expected count per bin is the pdf integrated over it
        // (2π ∫ p dc, computed by the midpoint rule on 200 sub-steps).
        let n = 100_000u32;
        let bins = 20;
        for g in GS {
            let p = HenyeyGreenstein::new(g).unwrap();
            let mut counts = vec![0u32; bins];
            let mut state = 0x1234_5678u32;
            let mut rnd = || {
                state = crate::sampling::hash_u32(state.wrapping_add(0x9e37_79b9));
                (state >> 8) as f32 / (1u32 << 24) as f32
            };
            let w = wo();
            for _ in 0..n {
                let s = p.sample(w, Vec2::new(rnd(), rnd()));
                let c = w.dot(s.wi).clamp(-1.0, 0.999_999);
                counts[((c + 1.0) * 0.5 * bins as f32) as usize] += 1;
            }
            let mut chi2 = 0.0f64;
            let mut dof = 0;
            for (b, &count) in counts.iter().enumerate() {
                let (c0, c1) = (
                    -1.0 + 2.0 * b as f64 / bins as f64,
                    -1.0 + 2.0 * (b + 1) as f64 / bins as f64,
                );
                let steps = 200;
                let mut mass = 0.0f64;
                for k in 0..steps {
                    let c = c0 + (c1 - c0) * (k as f64 + 0.5) / steps as f64;
                    mass += p.eval_cos(c as f32) as f64 * 2.0 * std::f64::consts::PI * (c1 - c0)
                        / steps as f64;
                }
                let expected = mass * n as f64;
                if expected < 5.0 {
                    continue;
                }
                dof += 1;
                chi2 += (count as f64 - expected).powi(2) / expected;
            }
            // The 99.9% quantile of χ² with ≤ 19 degrees of freedom is below 43.9.
            assert!(
                chi2 < 43.9,
                "g = {g}: χ² = {chi2} over {dof} bins, counts {counts:?}"
            );
        }
    }
}
