//! GGX conductors (metals), rough or perfectly smooth.
//!
//! Follows pbrt-v4's `ConductorBxDF`: Torrance–Sparrow reflection D·F·G / (4 cos θo cos θi) with
//! the complex-index Fresnel term, sampled through the visible normals. Below
//! [`SMOOTH_ALPHA`](super::microfacet::SMOOTH_ALPHA) the surface is a perfect mirror tinted by
//! the Fresnel term (a delta lobe). Two-sided: seen from below it behaves as seen from above.

#![allow(clippy::neg_cmp_op_on_partial_ord)] // `!(x > 0.0)` is deliberate: NaN must fail the guards.

use super::dielectric::finite_sample;
use super::microfacet::Ggx;
use super::{reflect, BsdfSample, Lobe};
use glam::{Vec2, Vec3A};

/// GGX conductor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Conductor {
    /// Complex IOR real part (per channel, relative to the outside medium).
    pub eta: Vec3A,
    /// Complex IOR imaginary part (absorption, per channel).
    pub k: Vec3A,
    /// GGX alpha; below [`SMOOTH_ALPHA`](super::microfacet::SMOOTH_ALPHA) a perfect mirror.
    pub alpha: f32,
}

impl Conductor {
    /// A conductor whose normal-incidence reflectance is `f0` (per channel, in [0, 1)): a real
    /// index η = (1 + √f0)/(1 − √f0) with k = 0, whose Fresnel curve rises to 1 at grazing
    /// angles. Convenient for artist-specified metals (glTF base colour).
    pub fn from_f0(f0: Vec3A, alpha: f32) -> Self {
        let s = f0.clamp(Vec3A::ZERO, Vec3A::splat(0.9999)).max(Vec3A::ZERO);
        let s = Vec3A::new(s.x.sqrt(), s.y.sqrt(), s.z.sqrt());
        Self {
            eta: (Vec3A::ONE + s) / (Vec3A::ONE - s),
            k: Vec3A::ZERO,
            alpha,
        }
    }

    /// f(wo, wi) without cosine; zero for the smooth (delta) case.
    pub fn eval(&self, wo: Vec3A, wi: Vec3A) -> Vec3A {
        let ggx = Ggx::new(self.alpha);
        if ggx.effectively_smooth() {
            return Vec3A::ZERO;
        }
        let Some((wo, wi)) = upper(wo, wi) else {
            return Vec3A::ZERO;
        };
        let Some(wm) = half_vector(wo, wi) else {
            return Vec3A::ZERO;
        };
        let f = fresnel_conductor(wo.dot(wm).abs(), self.eta, self.k)
            * (ggx.d(wm) * ggx.g(wo, wi) / (4.0 * wo.z * wi.z));
        if f.is_finite() {
            f
        } else {
            Vec3A::ZERO
        }
    }
    /// Density of `sample`: visible-normal density times the reflection Jacobian 1/(4 |wo·wm|).
    pub fn pdf(&self, wo: Vec3A, wi: Vec3A) -> f32 {
        let ggx = Ggx::new(self.alpha);
        if ggx.effectively_smooth() {
            return 0.0;
        }
        let Some((wo, wi)) = upper(wo, wi) else {
            return 0.0;
        };
        let Some(wm) = half_vector(wo, wi) else {
            return 0.0;
        };
        reflection_pdf(&ggx, wo, wm)
    }
    /// Samples a visible microfacet normal and reflects about it (or mirrors when smooth).
    pub fn sample(&self, wo: Vec3A, _uc: f32, u: Vec2) -> Option<BsdfSample> {
        if !wo.is_finite() || wo.z == 0.0 {
            return None;
        }
        let flip = wo.z < 0.0;
        let wo_u = Vec3A::new(wo.x, wo.y, wo.z.abs());
        let ggx = Ggx::new(self.alpha);
        if ggx.effectively_smooth() {
            let wi = Vec3A::new(-wo.x, -wo.y, wo.z);
            let f = fresnel_conductor(wo_u.z, self.eta, self.k) / wo_u.z;
            return finite_sample(BsdfSample {
                wi,
                f,
                pdf: 1.0,
                lobe: Lobe::SpecularReflection,
                eta: 1.0,
            });
        }
        let wm = ggx.sample_wm(wo_u, u);
        let mut wi = reflect(wo_u, wm);
        if !(wi.z > 0.0) {
            return None;
        }
        let f = fresnel_conductor(wo_u.dot(wm).abs(), self.eta, self.k)
            * (ggx.d(wm) * ggx.g(wo_u, wi) / (4.0 * wo_u.z * wi.z));
        let pdf = reflection_pdf(&ggx, wo_u, wm);
        if flip {
            wi.z = -wi.z;
        }
        finite_sample(BsdfSample {
            wi,
            f,
            pdf,
            lobe: Lobe::GlossyReflection,
            eta: 1.0,
        })
    }
    /// Delta when effectively smooth.
    pub fn is_delta(&self) -> bool {
        Ggx::new(self.alpha).effectively_smooth()
    }
    /// The reflectance at normal incidence.
    pub fn albedo(&self) -> Vec3A {
        fresnel_conductor(1.0, self.eta, self.k)
    }
}

/// Both directions mirrored into the upper hemisphere (two-sided reflection), or `None` when
/// they are on opposite sides, grazing or not finite.
#[inline]
pub(crate) fn upper(wo: Vec3A, wi: Vec3A) -> Option<(Vec3A, Vec3A)> {
    if !(wo.z * wi.z > 0.0) || !wo.is_finite() || !wi.is_finite() {
        return None;
    }
    if wo.z < 0.0 {
        Some((Vec3A::new(wo.x, wo.y, -wo.z), Vec3A::new(wi.x, wi.y, -wi.z)))
    } else {
        Some((wo, wi))
    }
}

/// The normalised reflection half vector of two upper-hemisphere directions.
#[inline]
pub(crate) fn half_vector(wo: Vec3A, wi: Vec3A) -> Option<Vec3A> {
    let wm = (wo + wi).normalize_or_zero();
    if wm == Vec3A::ZERO {
        None
    } else {
        Some(wm)
    }
}

/// Solid-angle density of a reflection through visible normal `wm` seen from upper `wo`.
#[inline]
pub(crate) fn reflection_pdf(ggx: &Ggx, wo: Vec3A, wm: Vec3A) -> f32 {
    let c = wo.dot(wm).abs();
    if !(c > 0.0) {
        return 0.0;
    }
    let p = ggx.pdf_visible(wo, wm) / (4.0 * c);
    if p.is_finite() {
        p
    } else {
        0.0
    }
}

/// Fresnel reflectance of a conductor with complex index η + ik (per channel) for unpolarised
/// light at incidence cosine `cos_i` (clamped to [0, 1]). The closed form of pbrt-v3
/// `FrConductor`, equal to pbrt-v4's complex-arithmetic `FrComplex`.
pub fn fresnel_conductor(cos_i: f32, eta: Vec3A, k: Vec3A) -> Vec3A {
    let cos_i = if cos_i.is_nan() {
        0.0
    } else {
        cos_i.clamp(0.0, 1.0)
    };
    let cos2 = cos_i * cos_i;
    let sin2 = 1.0 - cos2;
    let eta2 = eta * eta;
    let k2 = k * k;
    let t0 = eta2 - k2 - Vec3A::splat(sin2);
    let a2b2 = (t0 * t0 + 4.0 * eta2 * k2).max(Vec3A::ZERO);
    let a2b2 = Vec3A::new(a2b2.x.sqrt(), a2b2.y.sqrt(), a2b2.z.sqrt());
    let t1 = a2b2 + Vec3A::splat(cos2);
    let a = (0.5 * (a2b2 + t0)).max(Vec3A::ZERO);
    let a = Vec3A::new(a.x.sqrt(), a.y.sqrt(), a.z.sqrt());
    let t2 = 2.0 * cos_i * a;
    let rs = (t1 - t2) / (t1 + t2).max(Vec3A::splat(1e-12));
    let t3 = cos2 * a2b2 + Vec3A::splat(sin2 * sin2);
    let t4 = t2 * sin2;
    let rp = rs * (t3 - t4) / (t3 + t4).max(Vec3A::splat(1e-12));
    let r = 0.5 * (rp + rs);
    if r.is_finite() {
        r.clamp(Vec3A::ZERO, Vec3A::ONE)
    } else {
        Vec3A::ONE
    }
}
