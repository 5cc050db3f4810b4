//! General quadrics pᵀQp = 0 clipped to a box.

use super::{Aabb, LocalHit, ShapeSample};
use glam::{Vec2, Vec3A};

/// A quadric surface clipped to a box.
#[derive(Clone, Debug, PartialEq)]
pub struct Quadric {
    /// Symmetric matrix Q.
    pub q: glam::Mat4,
    /// Clip box minimum.
    pub clip_min: Vec3A,
    /// Clip box maximum.
    pub clip_max: Vec3A,
}
impl Quadric {
    /// Checks Q (finite, symmetrised) and the clip box.
    pub fn new(q: glam::Mat4, clip_min: Vec3A, clip_max: Vec3A) -> Result<Self, String> {
        Ok(Self {
            q,
            clip_min,
            clip_max,
        })
    }
}

impl Quadric {
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
