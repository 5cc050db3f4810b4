//! Smooth dielectrics: glass and water interfaces, and thin-walled sheets (windows, bubbles).
//!
//! Follows pbrt-v4's `DielectricBxDF` (smooth branch) and `ThinDielectricBxDF`. Transmitted
//! values are for **radiance** transport (pbrt's `TransportMode::Radiance`): radiance is
//! compressed into a smaller solid angle when entering a denser medium, so the transmitted f is
//! divided by η², η being the relative index crossed ([`BsdfSample::eta`]). A light-tracing
//! (importance) integrator would have to multiply it back.

#![allow(clippy::neg_cmp_op_on_partial_ord)] // `!(x > 0.0)` is deliberate: NaN must fail the guards.

use super::{fresnel_dielectric, refract, sanitize_eta, BsdfSample, Lobe};
use glam::{Vec2, Vec3A};

/// Smooth dielectric: exact Fresnel reflection and Snell refraction (or straight-through
/// transmission when `thin`). Every lobe is a delta.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dielectric {
    /// Inside/outside index ratio (the outside is +Z). 1 is a pure pass-through.
    pub eta: f32,
    /// Multiplies transmission (a tint; it does not change the sampling probabilities).
    pub transmittance: Vec3A,
    /// Thin-walled sheet: no interior, transmission passes straight through (wi = -wo) and the
    /// Fresnel terms account for the light bouncing inside the sheet.
    pub thin: bool,
}

impl Dielectric {
    /// Zero: every lobe is a delta.
    pub fn eval(&self, _wo: Vec3A, _wi: Vec3A) -> Vec3A {
        Vec3A::ZERO
    }
    /// Zero: every lobe is a delta.
    pub fn pdf(&self, _wo: Vec3A, _wi: Vec3A) -> f32 {
        0.0
    }
    /// Reflection with probability R, transmission with probability T = 1 - R.
    pub fn sample(&self, wo: Vec3A, uc: f32, _u: Vec2) -> Option<BsdfSample> {
        if !wo.is_finite() || wo.z == 0.0 {
            return None;
        }
        let eta = sanitize_eta(self.eta);
        let (r, t) = if self.thin {
            thin_reflectance(wo.z.abs(), eta)
        } else {
            let r = fresnel_dielectric(wo.z, eta);
            (r, 1.0 - r)
        };
        if !(r + t > 0.0) {
            return None;
        }
        let pr = r / (r + t);
        let cos_o = wo.z.abs();
        if uc < pr {
            // Specular reflection about +Z (same formula on both sides).
            let wi = Vec3A::new(-wo.x, -wo.y, wo.z);
            return finite_sample(BsdfSample {
                wi,
                f: Vec3A::splat(r / cos_o),
                pdf: pr,
                lobe: Lobe::SpecularReflection,
                eta: 1.0,
            });
        }
        let (wi, etap) = if self.thin || eta == 1.0 {
            (-wo, 1.0)
        } else {
            refract(wo, Vec3A::Z, eta)?
        };
        let cos_i = wi.z.abs();
        if !(cos_i > 0.0) {
            return None;
        }
        // Radiance transport: divide by η² (see the module docs).
        let f = self.transmittance * (t / (cos_i * etap * etap));
        finite_sample(BsdfSample {
            wi,
            f,
            pdf: 1.0 - pr,
            lobe: Lobe::SpecularTransmission,
            eta: etap,
        })
    }
    /// Always delta.
    pub fn is_delta(&self) -> bool {
        true
    }
    /// The transmittance: clear glass is white.
    pub fn albedo(&self) -> Vec3A {
        self.transmittance
    }
}

/// Reflectance and transmittance (R, T) of a thin sheet at incidence cosine `cos` (≥ 0): the
/// interface's R and T summed over all internal bounces, R' = R + T²R/(1 − R²), T' = 1 − R'
/// (pbrt-v4 `ThinDielectricBxDF`).
#[inline]
fn thin_reflectance(cos: f32, eta: f32) -> (f32, f32) {
    let mut r = fresnel_dielectric(cos, eta);
    let t = 1.0 - r;
    if r < 1.0 {
        r += t * t * r / (1.0 - r * r);
    }
    let r = r.clamp(0.0, 1.0);
    (r, 1.0 - r)
}

/// `Some(s)` if the sample's numbers are finite and its pdf positive, otherwise `None`, so that
/// no NaN ever reaches the integrator.
#[inline]
pub(crate) fn finite_sample(s: BsdfSample) -> Option<BsdfSample> {
    if s.wi.is_finite() && s.f.is_finite() && s.pdf.is_finite() && s.pdf > 0.0 {
        Some(s)
    } else {
        None
    }
}
