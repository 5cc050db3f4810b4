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

#[cfg(test)]
mod tests {
    use super::super::testutil::*;
    use super::super::Analytic;
    use super::*;

    fn sphere() -> Sphere {
        Sphere {
            center: Vec3A::new(1.0, 2.0, 3.0),
            radius: 2.0,
        }
    }

    fn distance(s: Sphere) -> impl Fn(Vec3A) -> f32 {
        move |p| ((p - s.center).length() - s.radius).abs()
    }

    #[test]
    fn head_on_hit() {
        let s = sphere();
        let (o, d) = (Vec3A::new(1.0, 2.0, 10.0), -Vec3A::Z * 0.5);
        let t = s.intersect(o, d, 0.0, f32::INFINITY).unwrap();
        assert!((t - 10.0).abs() < 1e-5, "{t}");
        let h = s.hit(o, d, t);
        assert_close(h.p, Vec3A::new(1.0, 2.0, 5.0), 1e-6, "point");
        assert_eq!(h.n, Vec3A::Z);
        // +Z is φ = 3π/2 (φ runs from +X towards −Z), on the equator.
        assert!((h.uv - Vec2::new(0.75, 0.5)).length() < 1e-6, "uv {}", h.uv);
        assert_close(h.dpdu, Vec3A::X * (4.0 * PI), 1e-5, "dpdu");
        // The north pole.
        let t = s
            .intersect(Vec3A::new(1.0, 7.0, 3.0), -Vec3A::Y, 0.0, 100.0)
            .unwrap();
        let h = s.hit(Vec3A::new(1.0, 7.0, 3.0), -Vec3A::Y, t);
        assert!((t - 3.0).abs() < 1e-6 && h.n == Vec3A::Y && h.uv.y == 0.0);
    }

    #[test]
    fn misses() {
        let s = sphere();
        assert_eq!(
            s.intersect(Vec3A::new(3.01, 2.0, 10.0), -Vec3A::Z, 0.0, 100.0),
            None
        );
        assert_eq!(
            s.intersect(Vec3A::new(1.0, 2.0, 10.0), Vec3A::Z, 0.0, 100.0),
            None
        );
        assert_eq!(
            s.intersect(Vec3A::new(1.0, 2.0, 10.0), -Vec3A::Z, 0.0, 4.9),
            None
        );
    }

    #[test]
    fn rays_from_inside_find_the_exit() {
        let s = sphere();
        let mut rng = Rng::new(90);
        for _ in 0..500 {
            let o = s.center + rng.unit() * rng.range(0.0, 1.99);
            let d = rng.unit() * rng.range(0.1, 10.0);
            let t = s.intersect(o, d, 0.0, f32::INFINITY).expect("exit");
            let h = s.hit(o, d, t);
            assert!(distance(s.clone())(o + d * t) < 1e-5 && h.n.dot(d) > 0.0);
        }
    }

    #[test]
    fn no_self_intersection() {
        for s in [
            sphere(),
            Sphere {
                center: Vec3A::new(1000.0, -500.0, 200.0),
                radius: 3.0,
            },
            Sphere {
                center: Vec3A::ZERO,
                radius: 0.01,
            },
        ] {
            let r = Vec3A::splat(s.radius);
            let (lo, hi) = (s.center - r, s.center + r);
            let a = Analytic::Sphere(s);
            check_no_self_hit(&a, lo, hi, Leave::Never, Some(Leave::OnlyElsewhere), 91);
        }
    }

    #[test]
    fn properties() {
        let s = sphere();
        let b = s.bounds().unwrap();
        let (lo, hi) = (b.min, b.max);
        let a = Analytic::Sphere(s.clone());
        check_grazing(&a, lo, hi, &distance(s.clone()), 1e-5, 92);
        check_direction_scale(&a, lo, hi, 93);
        check_sampling(&a, &distance(s.clone()), 4.0, s.center, Vec3A::ZERO);
        check_bad_inputs(&a, Vec3A::new(1.0, 2.0, 10.0), -Vec3A::Z);
    }
}
