//! Lambertian (ideal diffuse) reflection.

use super::{BsdfSample, Lobe};
use crate::sampling::warp::{cosine_hemisphere, cosine_hemisphere_pdf};
use glam::{Vec2, Vec3A};
use std::f32::consts::FRAC_1_PI;

/// Lambertian reflection: f = albedo/π, sampled by cosine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Diffuse {
    /// Reflectance in [0, 1] per channel.
    pub albedo: Vec3A,
}

impl Diffuse {
    /// f(wo, wi).
    #[inline]
    pub fn eval(&self, wo: Vec3A, wi: Vec3A) -> Vec3A {
        if wo.z * wi.z <= 0.0 {
            return Vec3A::ZERO;
        }
        self.albedo * FRAC_1_PI
    }
    /// Density of `sample`.
    #[inline]
    pub fn pdf(&self, wo: Vec3A, wi: Vec3A) -> f32 {
        if wo.z * wi.z <= 0.0 {
            return 0.0;
        }
        cosine_hemisphere_pdf(wi.z.abs())
    }
    /// Cosine-weighted sampling on wo's side.
    #[inline]
    pub fn sample(&self, wo: Vec3A, _uc: f32, u: Vec2) -> Option<BsdfSample> {
        let mut wi = cosine_hemisphere(u);
        let pdf = cosine_hemisphere_pdf(wi.z);
        if pdf <= 0.0 {
            return None;
        }
        if wo.z < 0.0 {
            wi.z = -wi.z;
        }
        Some(BsdfSample {
            wi,
            f: self.albedo * FRAC_1_PI,
            pdf,
            lobe: Lobe::Diffuse,
            eta: 1.0,
        })
    }
    /// Never delta.
    pub fn is_delta(&self) -> bool {
        false
    }
    /// The albedo.
    pub fn albedo(&self) -> Vec3A {
        self.albedo
    }
}
