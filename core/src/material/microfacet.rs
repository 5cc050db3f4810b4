//! GGX (Trowbridge–Reitz) microfacet distribution with visible-normal sampling.
//!
//! Isotropic only. The formulas follow pbrt-v4 (`TrowbridgeReitzDistribution`): the
//! height-correlated Smith masking–shadowing term and the distribution of visible normals
//! (Heitz 2018), sampled with the spherical-cap method of Dupuy & Benyoub 2023. All directions
//! are in the local shading frame (normal +Z); microfacet normals `wm` are in the upper
//! hemisphere.

#![allow(clippy::neg_cmp_op_on_partial_ord)] // `!(x > 0.0)` is deliberate: NaN must fail the guards.

use glam::{Vec2, Vec3A};
use std::f32::consts::PI;

/// Smallest alpha used: below it D overflows in `f32` and sampling degenerates.
pub const MIN_ALPHA: f32 = 1e-4;

/// Below this alpha a surface is treated as perfectly smooth: callers switch to their delta
/// (perfectly specular) path, as pbrt-v4's `EffectivelySmooth`.
pub const SMOOTH_ALPHA: f32 = 1e-3;

/// Largest alpha used; beyond it the distribution is nearly uniform anyway and the clamp keeps
/// the arithmetic finite for absurd inputs.
const MAX_ALPHA: f32 = 1e3;

/// An isotropic GGX distribution of microfacet normals.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ggx {
    /// Roughness alpha (perceptual roughness squared), clamped to [`MIN_ALPHA`, 1000].
    alpha: f32,
}

impl Ggx {
    /// The distribution with roughness `alpha`; NaN or tiny values become [`MIN_ALPHA`].
    #[inline]
    pub fn new(alpha: f32) -> Self {
        let alpha = if alpha.is_nan() {
            MIN_ALPHA
        } else {
            alpha.clamp(MIN_ALPHA, MAX_ALPHA)
        };
        Self { alpha }
    }

    /// The (clamped) alpha.
    #[inline]
    pub fn alpha(&self) -> f32 {
        self.alpha
    }

    /// Whether the surface is so smooth that callers should use a delta lobe instead.
    #[inline]
    pub fn effectively_smooth(&self) -> bool {
        self.alpha < SMOOTH_ALPHA
    }

    /// The normal distribution D(wm) (area-normalised: ∫ D(wm) cos θm dωm = 1). Zero for normals
    /// below the surface.
    #[inline]
    pub fn d(&self, wm: Vec3A) -> f32 {
        if !(wm.z > 0.0) {
            return 0.0;
        }
        // 1 / (π α² (x²/α² + y²/α² + z²)²) avoids tan θ, which overflows near grazing normals.
        let a2 = self.alpha * self.alpha;
        let t = (wm.x * wm.x + wm.y * wm.y) / a2 + wm.z * wm.z;
        let denom = PI * a2 * t * t;
        if !(denom > 0.0) {
            return 0.0;
        }
        let d = 1.0 / denom;
        if d.is_finite() {
            d
        } else {
            0.0
        }
    }

    /// Smith's auxiliary function Λ(w); infinite at (or beyond) grazing directions, so that
    /// G1 and G go to zero there.
    #[inline]
    pub fn lambda(&self, w: Vec3A) -> f32 {
        let z2 = w.z * w.z;
        if !(z2 > 0.0) {
            return f32::INFINITY;
        }
        let a2_tan2 = self.alpha * self.alpha * (w.x * w.x + w.y * w.y) / z2;
        if !a2_tan2.is_finite() {
            return f32::INFINITY;
        }
        // (√(1 + α² tan² θ) − 1) / 2 rewritten without the cancellation for small α tan θ.
        a2_tan2 / (2.0 * (1.0 + (1.0 + a2_tan2).sqrt()))
    }

    /// Smith masking G1(w) = 1 / (1 + Λ(w)).
    #[inline]
    pub fn g1(&self, w: Vec3A) -> f32 {
        1.0 / (1.0 + self.lambda(w))
    }

    /// Height-correlated Smith masking–shadowing G(wo, wi) = 1 / (1 + Λ(wo) + Λ(wi)).
    #[inline]
    pub fn g(&self, wo: Vec3A, wi: Vec3A) -> f32 {
        1.0 / (1.0 + self.lambda(wo) + self.lambda(wi))
    }

    /// Density of visible normals seen from `w`: G1(w)/|cos θw| · D(wm) · max(0, w·wm), with `w`
    /// replaced by `-w` below the surface. Integrates to one over the hemisphere of `wm`.
    #[inline]
    pub fn pdf_visible(&self, w: Vec3A, wm: Vec3A) -> f32 {
        let cos = w.z.abs();
        if !(cos > 0.0) {
            return 0.0;
        }
        // Only normals facing the viewer are visible; for `w` below the surface that viewer
        // is `-w` (see `sample_wm`).
        let facing = (w.dot(wm) * w.z.signum()).max(0.0);
        let p = self.g1(w) / cos * self.d(wm) * facing;
        if p.is_finite() {
            p
        } else {
            0.0
        }
    }

    /// Samples a microfacet normal visible from `w` with density [`Ggx::pdf_visible`]
    /// (spherical caps, Dupuy & Benyoub 2023). `w` below the surface is handled as `-w`, which
    /// has the same visible-normal distribution. Returns +Z for degenerate input.
    #[inline]
    pub fn sample_wm(&self, w: Vec3A, u: Vec2) -> Vec3A {
        // Stretch to the configuration where the distribution is the unit hemisphere.
        let mut wh = Vec3A::new(self.alpha * w.x, self.alpha * w.y, w.z).normalize_or_zero();
        if wh.z < 0.0 {
            wh = -wh;
        }
        if wh == Vec3A::ZERO {
            return Vec3A::Z;
        }
        // Visible normals of a hemisphere: uniform directions on the cap z ≥ -wh.z, plus wh.
        let phi = 2.0 * PI * u.x;
        let z = (1.0 - u.y) * (1.0 + wh.z) - wh.z;
        let sin_t = (1.0 - z * z).clamp(0.0, 1.0).sqrt();
        let c = Vec3A::new(sin_t * phi.cos(), sin_t * phi.sin(), z);
        let h = c + wh;
        // Unstretch; keep the normal strictly in the upper hemisphere.
        let wm = Vec3A::new(self.alpha * h.x, self.alpha * h.y, h.z.max(1e-6)).normalize_or_zero();
        if wm == Vec3A::ZERO {
            Vec3A::Z
        } else {
            wm
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn d_is_normalised_and_vndf_integrates_to_one() {
        for alpha in [0.05f32, 0.3, 0.8] {
            let ggx = Ggx::new(alpha);
            let w = Vec3A::new(0.6, 0.0, 0.8);
            // ∫ D(wm) cos θm dωm and ∫ D_w(wm) dωm over the hemisphere, in (cos θ, φ).
            let (n_t, n_p) = (2000, 64);
            let (mut s_d, mut s_v) = (0.0f64, 0.0f64);
            for i in 0..n_t {
                // Concentrate samples near the pole with cos θ = 1 - s², s uniform.
                let s = (i as f32 + 0.5) / n_t as f32;
                let cos_t = 1.0 - s * s;
                let jac = 2.0 * s / n_t as f32;
                let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
                for j in 0..n_p {
                    let phi = 2.0 * PI * (j as f32 + 0.5) / n_p as f32;
                    let wm = Vec3A::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t);
                    let dw = (jac * 2.0 * PI / n_p as f32) as f64;
                    s_d += (ggx.d(wm) * cos_t) as f64 * dw;
                    s_v += ggx.pdf_visible(w, wm) as f64 * dw;
                }
            }
            assert!((s_d - 1.0).abs() < 5e-3, "alpha {alpha}: ∫D cos = {s_d}");
            assert!((s_v - 1.0).abs() < 5e-3, "alpha {alpha}: ∫D_w = {s_v}");
        }
    }

    #[test]
    fn degenerate_inputs_are_safe() {
        let ggx = Ggx::new(f32::NAN);
        assert_eq!(ggx.alpha(), MIN_ALPHA);
        let nan = Vec3A::splat(f32::NAN);
        assert_eq!(ggx.d(nan), 0.0);
        assert_eq!(ggx.pdf_visible(nan, Vec3A::Z), 0.0);
        assert_eq!(ggx.g1(Vec3A::X), 0.0);
        let wm = ggx.sample_wm(nan, Vec2::splat(0.5));
        assert!(wm.is_finite());
        let wm = Ggx::new(0.3).sample_wm(Vec3A::ZERO, Vec2::splat(0.5));
        assert_eq!(wm, Vec3A::Z);
    }
}
