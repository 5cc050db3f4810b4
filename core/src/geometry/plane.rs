//! Infinite planes, disks and rectangles.

use super::{Aabb, LocalHit, ShapeSample};
use glam::{Vec2, Vec3A};

/// An infinite plane.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane {
    /// A point on it.
    pub point: Vec3A,
    /// Unit front normal.
    pub normal: Vec3A,
}

/// A disk.
#[derive(Clone, Debug, PartialEq)]
pub struct Disk {
    /// Centre.
    pub center: Vec3A,
    /// Unit front normal.
    pub normal: Vec3A,
    /// Radius.
    pub radius: f32,
}

/// A parallelogram corner + s·edge_u + t·edge_v.
#[derive(Clone, Debug, PartialEq)]
pub struct Rectangle {
    /// Corner.
    pub corner: Vec3A,
    /// First edge.
    pub edge_u: Vec3A,
    /// Second edge.
    pub edge_v: Vec3A,
}

macro_rules! stub {
    ($t:ty) => {
        impl $t {
            /// Object-space bounds (None if unbounded).
            pub fn bounds(&self) -> Option<Aabb> {
                todo!()
            }
            /// Nearest hit in (tmin, tmax).
            pub fn intersect(&self, _o: Vec3A, _d: Vec3A, _tmin: f32, _tmax: f32) -> Option<f32> {
                todo!()
            }
            /// Surface details.
            pub fn hit(&self, _o: Vec3A, _d: Vec3A, _t: f32) -> LocalHit {
                todo!()
            }
            /// Area.
            pub fn area(&self) -> f32 {
                todo!()
            }
            /// Uniform point by area.
            pub fn sample(&self, _u: Vec2) -> Option<ShapeSample> {
                todo!()
            }
        }
    };
}
stub!(Plane);
stub!(Disk);
stub!(Rectangle);
