//! Perfect specular reflection.

use super::{BsdfSample, Lobe};
use glam::{Vec2, Vec3A};

/// A perfect mirror.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mirror {
    /// Reflectance.
    pub reflectance: Vec3A,
}

impl Mirror {
    /// Zero: a delta lobe is never hit by a chosen direction.
    pub fn eval(&self, _wo: Vec3A, _wi: Vec3A) -> Vec3A {
        Vec3A::ZERO
    }
    /// Zero.
    pub fn pdf(&self, _wo: Vec3A, _wi: Vec3A) -> f32 {
        0.0
    }
    /// The reflected direction.
    pub fn sample(&self, wo: Vec3A, _uc: f32, _u: Vec2) -> Option<BsdfSample> {
        if wo.z == 0.0 {
            return None;
        }
        let wi = Vec3A::new(-wo.x, -wo.y, wo.z);
        Some(BsdfSample {
            wi,
            f: self.reflectance / wi.z.abs(),
            pdf: 1.0,
            lobe: Lobe::SpecularReflection,
            eta: 1.0,
        })
    }
    /// Always delta.
    pub fn is_delta(&self) -> bool {
        true
    }
    /// The reflectance.
    pub fn albedo(&self) -> Vec3A {
        self.reflectance
    }
}
