//! Spheres.

use super::{Aabb, LocalHit, ShapeSample};
use glam::{Vec2, Vec3A};
use std::f32::consts::PI;

/// A sphere. uv: u = φ/2π, the longitude about +Y measured from +X towards −Z, v = θ/π from +Y (latitude).
#[derive(Clone, Debug, PartialEq)]
pub struct Sphere {
    /// Centre.
    pub center: Vec3A,
    /// Radius.
    pub radius: f32,
}

impl Sphere {
    /// Object-space bounds.
    pub fn bounds(&self) -> Option<Aabb> {
        let r = Vec3A::splat(self.radius);
        Some(Aabb::new(self.center - r, self.center + r))
    }

    /// Nearest root in (tmin, tmax). Uses the numerically stable quadratic form (the
    /// discriminant from the vector rejection, as Ray Tracing Gems ch. 7 shows), so grazing and
    /// distant rays keep their precision.
    #[inline]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<f32> {
        let f = o - self.center;
        let a = d.length_squared();
        let b = -f.dot(d);
        let r2 = self.radius * self.radius;
        // |f - (f·d̂)d̂|² computed directly avoids catastrophic cancellation in b² - ac.
        let l = f + d * (b / a);
        let disc = a * (r2 - l.length_squared());
        if disc < 0.0 {
            return None;
        }
        let s = disc.sqrt();
        let q = if b >= 0.0 { b + s } else { b - s };
        let c = f.length_squared() - r2;
        let (mut t0, mut t1) = (c / q, q / a);
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        if t0 > tmin && t0 < tmax {
            Some(t0)
        } else if t1 > tmin && t1 < tmax {
            Some(t1)
        } else {
            None
        }
    }

    /// Surface details at parameter `t`.
    #[inline]
    pub fn hit(&self, o: Vec3A, d: Vec3A, t: f32) -> LocalHit {
        let rel = o + d * t - self.center;
        let n = rel.normalize_or(Vec3A::Y);
        // Re-project onto the surface: the offset logic needs an accurate point.
        let p = self.center + n * self.radius;
        let phi = (-n.z).atan2(n.x);
        let phi = if phi < 0.0 { phi + 2.0 * PI } else { phi };
        let theta = n.y.clamp(-1.0, 1.0).acos();
        let dpdu = Vec3A::new(n.z, 0.0, -n.x) * (2.0 * PI * self.radius);
        LocalHit {
            p,
            n,
            uv: Vec2::new(phi / (2.0 * PI), theta / PI),
            dpdu,
        }
    }

    /// Surface area.
    pub fn area(&self) -> f32 {
        4.0 * PI * self.radius * self.radius
    }

    /// A uniform point by area.
    pub fn sample(&self, u: Vec2) -> Option<ShapeSample> {
        let n = crate::sampling::warp::uniform_sphere(u);
        Some(ShapeSample {
            p: self.center + n * self.radius,
            n,
            pdf_area: 1.0 / self.area(),
        })
    }
}
