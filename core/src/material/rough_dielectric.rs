//! GGX rough dielectrics (frosted glass).
//!
//! Walter et al. 2007, "Microfacet Models for Refraction through Rough Surfaces", in the form of
//! pbrt-v4's `DielectricBxDF` rough branch: the generalised half vector wm ∝ η wi + wo, exact
//! dielectric Fresnel on the microfacet, height-correlated Smith G, visible-normal sampling and
//! the refraction Jacobian |wi·wm| / (wi·wm + wo·wm/η)². Transmission is for radiance transport
//! (divided by η², see [`super::dielectric`]). Below
//! [`SMOOTH_ALPHA`](super::microfacet::SMOOTH_ALPHA), or with η = 1, it is exactly the smooth
//! [`Dielectric`].

#![allow(clippy::neg_cmp_op_on_partial_ord)] // `!(x > 0.0)` is deliberate: NaN must fail the guards.

use super::conductor::reflection_pdf;
use super::dielectric::{finite_sample, Dielectric};
use super::microfacet::Ggx;
use super::{fresnel_dielectric, reflect, refract, sanitize_eta, BsdfSample, Lobe};
use glam::{Vec2, Vec3A};

/// GGX rough dielectric.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoughDielectric {
    /// Inside/outside index ratio (the outside is +Z).
    pub eta: f32,
    /// GGX alpha; below [`SMOOTH_ALPHA`](super::microfacet::SMOOTH_ALPHA) smooth glass.
    pub alpha: f32,
    /// Multiplies transmission (a tint; it does not change the sampling probabilities).
    pub transmittance: Vec3A,
}

/// The microfacet configuration of a pair of directions.
struct Config {
    /// Microfacet normal (upper hemisphere).
    wm: Vec3A,
    /// Relative index crossed (1 for reflection).
    etap: f32,
    /// Whether wi is on the other side from wo.
    transmission: bool,
}

impl RoughDielectric {
    /// The smooth dielectric this one degenerates to, if it does.
    #[inline]
    fn smooth(&self) -> Option<Dielectric> {
        let eta = sanitize_eta(self.eta);
        if eta == 1.0 || Ggx::new(self.alpha).effectively_smooth() {
            Some(Dielectric {
                eta,
                transmittance: self.transmittance,
                thin: false,
            })
        } else {
            None
        }
    }

    /// The generalised half vector of (wo, wi), or `None` for degenerate or back-facing
    /// configurations (which have zero value and density).
    #[inline]
    fn config(&self, wo: Vec3A, wi: Vec3A) -> Option<Config> {
        let eta = sanitize_eta(self.eta);
        let (cos_o, cos_i) = (wo.z, wi.z);
        if cos_o == 0.0 || cos_i == 0.0 || !wo.is_finite() || !wi.is_finite() {
            return None;
        }
        let transmission = cos_o * cos_i < 0.0;
        let etap = if !transmission {
            1.0
        } else if cos_o > 0.0 {
            eta
        } else {
            1.0 / eta
        };
        let mut wm = (wi * etap + wo).normalize_or_zero();
        if wm == Vec3A::ZERO {
            return None;
        }
        if wm.z < 0.0 {
            wm = -wm;
        }
        // Microfacets seen from behind by either direction contribute nothing.
        if wm.dot(wi) * cos_i < 0.0 || wm.dot(wo) * cos_o < 0.0 {
            return None;
        }
        Some(Config {
            wm,
            etap,
            transmission,
        })
    }

    /// f(wo, wi) without cosine; zero in the smooth (delta) case.
    pub fn eval(&self, wo: Vec3A, wi: Vec3A) -> Vec3A {
        if self.smooth().is_some() {
            return Vec3A::ZERO;
        }
        let Some(c) = self.config(wo, wi) else {
            return Vec3A::ZERO;
        };
        let f = self.value(wo, wi, &c);
        if f.is_finite() {
            f
        } else {
            Vec3A::ZERO
        }
    }

    /// The BSDF value for a valid configuration.
    #[inline]
    fn value(&self, wo: Vec3A, wi: Vec3A, c: &Config) -> Vec3A {
        let ggx = Ggx::new(self.alpha);
        let eta = sanitize_eta(self.eta);
        let (wo_m, wi_m) = (wo.dot(c.wm), wi.dot(c.wm));
        let fr = fresnel_dielectric(wo_m, eta);
        let dg = ggx.d(c.wm) * ggx.g(wo, wi);
        if !c.transmission {
            return Vec3A::splat(dg * fr / (4.0 * wo.z * wi.z).abs());
        }
        let denom = sq(wi_m + wo_m / c.etap) * wi.z * wo.z;
        if denom == 0.0 {
            return Vec3A::ZERO;
        }
        // Radiance transport: divide by η².
        let ft = dg * (1.0 - fr) * (wi_m * wo_m / denom).abs() / sq(c.etap);
        self.transmittance * ft
    }

    /// Density of `sample`.
    pub fn pdf(&self, wo: Vec3A, wi: Vec3A) -> f32 {
        if self.smooth().is_some() {
            return 0.0;
        }
        let Some(c) = self.config(wo, wi) else {
            return 0.0;
        };
        let p = self.density(wo, wi, &c);
        if p.is_finite() {
            p
        } else {
            0.0
        }
    }

    /// The sampling density for a valid configuration: lobe probability (R or T on the
    /// microfacet) times the visible-normal density times the Jacobian of wm → wi.
    #[inline]
    fn density(&self, wo: Vec3A, wi: Vec3A, c: &Config) -> f32 {
        let ggx = Ggx::new(self.alpha);
        let r = fresnel_dielectric(wo.dot(c.wm), sanitize_eta(self.eta));
        if !c.transmission {
            return reflection_pdf(&ggx, wo, c.wm) * r;
        }
        let wi_m = wi.dot(c.wm);
        let denom = sq(wi_m + wo.dot(c.wm) / c.etap);
        if !(denom > 0.0) {
            return 0.0;
        }
        ggx.pdf_visible(wo, c.wm) * wi_m.abs() / denom * (1.0 - r)
    }

    /// Samples a visible microfacet normal, then reflects (probability R) or refracts.
    pub fn sample(&self, wo: Vec3A, uc: f32, u: Vec2) -> Option<BsdfSample> {
        if let Some(smooth) = self.smooth() {
            return smooth.sample(wo, uc, u);
        }
        if !wo.is_finite() || wo.z == 0.0 {
            return None;
        }
        let ggx = Ggx::new(self.alpha);
        let eta = sanitize_eta(self.eta);
        let wm = ggx.sample_wm(wo, u);
        let r = fresnel_dielectric(wo.dot(wm), eta);
        let (wi, lobe) = if uc < r {
            let wi = reflect(wo, wm);
            if !(wi.z * wo.z > 0.0) {
                return None;
            }
            (wi, Lobe::GlossyReflection)
        } else {
            let (wi, _) = refract(wo, wm, eta)?;
            if !(wi.z * wo.z < 0.0) {
                return None;
            }
            (wi, Lobe::GlossyTransmission)
        };
        // Recompute through the shared configuration so that f and pdf match eval and pdf.
        let c = self.config(wo, wi)?;
        let f = self.value(wo, wi, &c);
        let pdf = self.density(wo, wi, &c);
        finite_sample(BsdfSample {
            wi,
            f,
            pdf,
            lobe,
            eta: c.etap,
        })
    }
    /// Delta when effectively smooth (or η = 1).
    pub fn is_delta(&self) -> bool {
        self.smooth().is_some()
    }
    /// The transmittance: clear glass is white.
    pub fn albedo(&self) -> Vec3A {
        self.transmittance
    }
}

#[inline]
fn sq(x: f32) -> f32 {
    x * x
}
