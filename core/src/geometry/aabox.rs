//! Axis-aligned boxes (slab method).

use super::{Aabb, LocalHit, ShapeSample};
use glam::{Vec2, Vec3A};

/// An axis-aligned box.
#[derive(Clone, Debug, PartialEq)]
pub struct AaBox {
    /// Minimum corner.
    pub min: Vec3A,
    /// Maximum corner.
    pub max: Vec3A,
}

impl AaBox {
    /// Object-space bounds (None if unbounded).
    pub fn bounds(&self) -> Option<Aabb> {
        todo!()
    }
    /// Nearest hit in (tmin, tmax); `d` need not be unit.
    pub fn intersect(&self, _o: Vec3A, _d: Vec3A, _tmin: f32, _tmax: f32) -> Option<f32> {
        todo!()
    }
    /// Surface details at parameter `t`.
    pub fn hit(&self, _o: Vec3A, _d: Vec3A, _t: f32) -> LocalHit {
        todo!()
    }
    /// Surface area.
    pub fn area(&self) -> f32 {
        todo!()
    }
    /// Uniform point by area.
    pub fn sample(&self, _u: Vec2) -> Option<ShapeSample> {
        todo!()
    }
}
