//! Planar polygons, convex or concave.

use super::{Aabb, LocalHit, ShapeSample};
use glam::{Vec2, Vec3A};

/// A planar polygon (vertices in order; front side counter-clockwise).
#[derive(Clone, Debug, PartialEq)]
pub struct Polygon {
    /// Vertices.
    pub vertices: Vec<Vec3A>,
}
impl Polygon {
    /// Checks the vertices (at least three, coplanar, non-degenerate) and precomputes.
    pub fn new(vertices: Vec<Vec3A>) -> Result<Self, String> {
        Ok(Self { vertices })
    }
}

impl Polygon {
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
