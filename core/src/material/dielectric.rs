//! Smooth dielectrics.

use super::BsdfSample;
use glam::{Vec2, Vec3A};

/// Smooth dielectric.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dielectric {
    /// Inside/outside index ratio.
    pub eta: f32,
    /// Multiplies transmission.
    pub transmittance: Vec3A,
    /// Thin-walled sheet.
    pub thin: bool,
}

impl Dielectric {
    /// f(wo, wi) without cosine.
    pub fn eval(&self, _wo: Vec3A, _wi: Vec3A) -> Vec3A {
        todo!()
    }
    /// Density of `sample`.
    pub fn pdf(&self, _wo: Vec3A, _wi: Vec3A) -> f32 {
        todo!()
    }
    /// Samples wi.
    pub fn sample(&self, _wo: Vec3A, _uc: f32, _u: Vec2) -> Option<BsdfSample> {
        todo!()
    }
    /// Whether all lobes are delta.
    pub fn is_delta(&self) -> bool {
        todo!()
    }
    /// Summary colour.
    pub fn albedo(&self) -> Vec3A {
        todo!()
    }
}
