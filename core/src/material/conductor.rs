//! GGX conductors.

use super::BsdfSample;
use glam::{Vec2, Vec3A};

/// GGX conductor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Conductor {
    /// Complex IOR real part.
    pub eta: Vec3A,
    /// Complex IOR imaginary part.
    pub k: Vec3A,
    /// GGX alpha.
    pub alpha: f32,
}

impl Conductor {
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
