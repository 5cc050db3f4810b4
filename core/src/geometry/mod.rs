//! Rays, bounds, hit records and shapes.
//!
//! Analytic shapes live in their own object space; a [`crate::scene::Scene`] object carries the
//! transform, and the ray is transformed into object space before the shape sees it. So a shape's
//! `intersect` must accept a ray direction that is **not** normalised, and return `t` in units of
//! that direction (the same `t` as in world space).

pub mod aabox;
pub mod interaction;
pub mod plane;
pub mod polygon;
pub mod quadric;
pub mod ray;
pub mod sphere;
#[cfg(test)]
mod testutil;
pub mod transform;
pub mod triangle;

pub use interaction::{Hit, Interaction};
pub use ray::{offset_ray_origin, Ray};

use glam::{Vec2, Vec3A};

/// Axis-aligned bounds (obvhs's type, so the BVH builder takes them directly).
pub use obvhs::aabb::Aabb;

/// What a shape reports about the point a ray hit, in the shape's own (object) space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalHit {
    /// Hit point, computed so that it lies on the surface as closely as f32 allows (for
    /// example re-projected onto a sphere), since rays leaving it are offset from it.
    pub p: Vec3A,
    /// Geometric normal, unit length, on the shape's *front* side (outward for closed shapes,
    /// the declared normal for planes, disks, rectangles and polygons) regardless of the side
    /// the ray came from.
    pub n: Vec3A,
    /// Surface parameterisation (each shape documents its own).
    pub uv: Vec2,
    /// ∂p/∂u: a tangent, not necessarily unit; zero if the shape has no natural tangent.
    pub dpdu: Vec3A,
}

/// A point sampled on a shape's surface, in object space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShapeSample {
    /// The point.
    pub p: Vec3A,
    /// Front-side unit normal there.
    pub n: Vec3A,
    /// Density with respect to object-space area (1/area for uniform sampling).
    pub pdf_area: f32,
}

/// An analytic (non-mesh) shape in object space. An enum, not a trait object, so the
/// per-ray dispatch is a jump table the compiler can see through.
#[derive(Clone, Debug)]
pub enum Analytic {
    /// See [`sphere::Sphere`].
    Sphere(sphere::Sphere),
    /// See [`aabox::AaBox`].
    AaBox(aabox::AaBox),
    /// See [`plane::Plane`]; unbounded, so it is kept outside the BVH.
    Plane(plane::Plane),
    /// See [`plane::Disk`].
    Disk(plane::Disk),
    /// See [`plane::Rectangle`].
    Rectangle(plane::Rectangle),
    /// See [`polygon::Polygon`].
    Polygon(polygon::Polygon),
    /// See [`quadric::Quadric`].
    Quadric(quadric::Quadric),
}

macro_rules! dispatch {
    ($self:ident, $s:ident => $e:expr) => {
        match $self {
            Analytic::Sphere($s) => $e,
            Analytic::AaBox($s) => $e,
            Analytic::Plane($s) => $e,
            Analytic::Disk($s) => $e,
            Analytic::Rectangle($s) => $e,
            Analytic::Polygon($s) => $e,
            Analytic::Quadric($s) => $e,
        }
    };
}

impl Analytic {
    /// Object-space bounds; `None` for unbounded shapes (infinite planes).
    pub fn bounds(&self) -> Option<Aabb> {
        dispatch!(self, s => s.bounds())
    }

    /// Nearest intersection with parameter in the open interval (tmin, tmax), if any.
    /// `d` need not be unit length.
    #[inline]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<f32> {
        dispatch!(self, s => s.intersect(o, d, tmin, tmax))
    }

    /// Surface details at the hit found by [`Analytic::intersect`] at parameter `t`.
    #[inline]
    pub fn hit(&self, o: Vec3A, d: Vec3A, t: f32) -> LocalHit {
        dispatch!(self, s => s.hit(o, d, t))
    }

    /// Object-space surface area (infinite for planes).
    pub fn area(&self) -> f32 {
        dispatch!(self, s => s.area())
    }

    /// A point uniformly distributed by area, from `u` ∈ [0,1)². Planes cannot be sampled
    /// (they are never area lights) and return `None`.
    pub fn sample(&self, u: Vec2) -> Option<ShapeSample> {
        dispatch!(self, s => s.sample(u))
    }
}
