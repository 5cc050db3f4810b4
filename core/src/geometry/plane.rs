//! Infinite planes, disks and rectangles.
//!
//! All three are one-sided only in their normal: rays hit them from either side, and the
//! reported normal is always the declared front normal. A ray parallel to the plane misses.

use super::{Aabb, LocalHit, ShapeSample};
use crate::sampling::warp::{concentric_disk, Frame};
use glam::{Vec2, Vec3A};
use std::f32::consts::PI;

/// The parameter where the ray meets the plane {p : n·p = n·point}, if it lies in
/// (tmin, tmax). `n` need not be unit (the parameter does not depend on its length). `None` for
/// rays parallel to the plane and for NaN input.
#[inline]
pub(super) fn plane_t(
    n: Vec3A,
    point: Vec3A,
    o: Vec3A,
    d: Vec3A,
    tmin: f32,
    tmax: f32,
) -> Option<f32> {
    let denom = n.dot(d);
    if denom == 0.0 || denom.is_nan() {
        return None;
    }
    // n·point − n·o rather than n·(point − o): the offset of a ray origin leaving the plane
    // then decides the sign, whatever the magnitude of `point`.
    let t = (n.dot(point) - n.dot(o)) / denom;
    (t > tmin && t < tmax).then_some(t)
}

/// Moves `p` onto the plane through `point` with unit normal `n` (rays leaving it are offset
/// from it, so it must be on the surface as closely as f32 allows).
#[inline]
pub(super) fn project_to_plane(p: Vec3A, n: Vec3A, point: Vec3A) -> Vec3A {
    p - n * (n.dot(p) - n.dot(point))
}

/// An infinite plane. uv: coordinates of `p − point` in [`Frame::from_z`]`(normal)` (x, y axes),
/// in object units; ∂p/∂u is that frame's x axis.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane {
    /// A point on it.
    pub point: Vec3A,
    /// Front normal (unit length expected; it is normalised where a unit vector matters).
    pub normal: Vec3A,
}

impl Plane {
    /// Unbounded: `None` (the plane is kept outside the BVH).
    pub fn bounds(&self) -> Option<Aabb> {
        None
    }

    /// Nearest hit in (tmin, tmax); `d` need not be unit.
    #[inline]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<f32> {
        plane_t(self.normal, self.point, o, d, tmin, tmax)
    }

    /// Surface details at parameter `t`.
    #[inline]
    pub fn hit(&self, o: Vec3A, d: Vec3A, t: f32) -> LocalHit {
        let n = self.normal.normalize_or(Vec3A::Z);
        let p = project_to_plane(o + d * t, n, self.point);
        let f = Frame::from_z(n);
        let rel = p - self.point;
        LocalHit {
            p,
            n,
            uv: Vec2::new(rel.dot(f.x), rel.dot(f.y)),
            dpdu: f.x,
        }
    }

    /// Infinite.
    pub fn area(&self) -> f32 {
        f32::INFINITY
    }

    /// A plane cannot be sampled by area (it is never an area light): `None`.
    pub fn sample(&self, _u: Vec2) -> Option<ShapeSample> {
        None
    }
}

/// A disk. uv: u = r/radius, v = φ/2π with φ ∈ [0, 2π) the angle about the normal measured
/// from the x axis of [`Frame::from_z`]`(normal)` towards its y axis; ∂p/∂u = radius × the
/// radial direction (the frame's x axis at the centre).
#[derive(Clone, Debug, PartialEq)]
pub struct Disk {
    /// Centre.
    pub center: Vec3A,
    /// Front normal (unit length expected; it is normalised where a unit vector matters).
    pub normal: Vec3A,
    /// Radius.
    pub radius: f32,
}

impl Disk {
    /// Tight bounds: along axis k the disk reaches radius·√(1 − n_k²) from its centre.
    pub fn bounds(&self) -> Option<Aabb> {
        let n = self.normal.normalize_or(Vec3A::Z);
        let ext = (Vec3A::ONE - n * n).max(Vec3A::ZERO).sqrt() * self.radius.abs();
        Some(Aabb::new(self.center - ext, self.center + ext))
    }

    /// Nearest hit in (tmin, tmax); `d` need not be unit.
    #[inline]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<f32> {
        let t = plane_t(self.normal, self.center, o, d, tmin, tmax)?;
        let rel = o + d * t - self.center;
        (rel.length_squared() <= self.radius * self.radius).then_some(t)
    }

    /// Surface details at parameter `t`.
    #[inline]
    pub fn hit(&self, o: Vec3A, d: Vec3A, t: f32) -> LocalHit {
        let n = self.normal.normalize_or(Vec3A::Z);
        let p = project_to_plane(o + d * t, n, self.center);
        let f = Frame::from_z(n);
        let rel = p - self.center;
        let (x, y) = (rel.dot(f.x), rel.dot(f.y));
        let r = (x * x + y * y).sqrt();
        let phi = y.atan2(x);
        let phi = if phi < 0.0 { phi + 2.0 * PI } else { phi };
        let radial = if r > 0.0 {
            (f.x * x + f.y * y) / r
        } else {
            f.x
        };
        let u = if self.radius > 0.0 {
            r / self.radius
        } else {
            0.0
        };
        LocalHit {
            p,
            n,
            uv: Vec2::new(u, phi / (2.0 * PI)),
            dpdu: radial * self.radius,
        }
    }

    /// Area πr².
    pub fn area(&self) -> f32 {
        PI * self.radius * self.radius
    }

    /// Uniform point by area (concentric map). `None` for a disk without area.
    pub fn sample(&self, u: Vec2) -> Option<ShapeSample> {
        let area = self.area();
        if !(area > 0.0 && area.is_finite()) {
            return None;
        }
        let n = self.normal.normalize_or(Vec3A::Z);
        let f = Frame::from_z(n);
        let q = concentric_disk(u) * self.radius;
        Some(ShapeSample {
            p: self.center + f.x * q.x + f.y * q.y,
            n,
            pdf_area: 1.0 / area,
        })
    }
}

/// A parallelogram `corner + s·edge_u + t·edge_v`, s, t ∈ [0, 1]. uv = (s, t); the front
/// normal is normalize(edge_u × edge_v); ∂p/∂u = edge_u.
#[derive(Clone, Debug, PartialEq)]
pub struct Rectangle {
    /// Corner.
    pub corner: Vec3A,
    /// First edge.
    pub edge_u: Vec3A,
    /// Second edge.
    pub edge_v: Vec3A,
}

impl Rectangle {
    /// (s, t) of a point in the plane, from the dual basis of the two edges.
    #[inline]
    fn coords(&self, p: Vec3A, nn: Vec3A) -> (f32, f32) {
        let rel = p - self.corner;
        let inv = 1.0 / nn.length_squared();
        (
            rel.cross(self.edge_v).dot(nn) * inv,
            self.edge_u.cross(rel).dot(nn) * inv,
        )
    }

    /// Bounds of the four corners.
    pub fn bounds(&self) -> Option<Aabb> {
        let (c, u, v) = (self.corner, self.edge_u, self.edge_v);
        let (a, b) = (c + u, c + v);
        let e = c + u + v;
        Some(Aabb::new(c.min(a).min(b).min(e), c.max(a).max(b).max(e)))
    }

    /// Nearest hit in (tmin, tmax); `d` need not be unit.
    #[inline]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<f32> {
        let nn = self.edge_u.cross(self.edge_v);
        let t = plane_t(nn, self.corner, o, d, tmin, tmax)?;
        let (s, v) = self.coords(o + d * t, nn);
        ((0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&v)).then_some(t)
    }

    /// Surface details at parameter `t`.
    #[inline]
    pub fn hit(&self, o: Vec3A, d: Vec3A, t: f32) -> LocalHit {
        let nn = self.edge_u.cross(self.edge_v);
        let n = nn.normalize_or(Vec3A::Z);
        let p = project_to_plane(o + d * t, n, self.corner);
        let (s, v) = self.coords(p, nn);
        LocalHit {
            p,
            n,
            uv: Vec2::new(s, v),
            dpdu: self.edge_u,
        }
    }

    /// Area |edge_u × edge_v|.
    pub fn area(&self) -> f32 {
        self.edge_u.cross(self.edge_v).length()
    }

    /// Uniform point by area. `None` for a degenerate parallelogram.
    pub fn sample(&self, u: Vec2) -> Option<ShapeSample> {
        let nn = self.edge_u.cross(self.edge_v);
        let area = nn.length();
        if !(area > 0.0 && area.is_finite()) {
            return None;
        }
        Some(ShapeSample {
            p: self.corner + self.edge_u * u.x + self.edge_v * u.y,
            n: nn / area,
            pdf_area: 1.0 / area,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testutil::*;
    use super::super::Analytic;
    use super::*;

    fn tilted_plane() -> Plane {
        Plane {
            point: Vec3A::new(3.0, -2.0, 1.0),
            normal: Vec3A::new(1.0, 2.0, -0.5).normalize(),
        }
    }

    fn tilted_disk() -> Disk {
        Disk {
            center: Vec3A::new(-1.0, 0.5, 2.0),
            normal: Vec3A::new(0.3, -1.0, 0.6).normalize(),
            radius: 1.5,
        }
    }

    fn skewed_rect() -> Rectangle {
        Rectangle {
            corner: Vec3A::new(1.0, -1.0, 0.5),
            edge_u: Vec3A::new(2.0, 0.5, 0.0),
            edge_v: Vec3A::new(0.5, 0.3, 1.5),
        }
    }

    fn plane_distance(n: Vec3A, point: Vec3A) -> impl Fn(Vec3A) -> f32 {
        move |p| n.dot(p - point).abs()
    }

    /// Distance from a disk: off its plane, and beyond its rim.
    fn disk_distance(dk: Disk) -> impl Fn(Vec3A) -> f32 {
        move |p| {
            let rel = p - dk.center;
            let h = rel.dot(dk.normal);
            let r = (rel - dk.normal * h).length();
            (h * h + (r - dk.radius).max(0.0).powi(2)).sqrt()
        }
    }

    fn rect_distance(r: Rectangle) -> impl Fn(Vec3A) -> f32 {
        move |p| {
            let nn = r.edge_u.cross(r.edge_v);
            let (s, t) = r.coords(p, nn);
            let q = r.corner + r.edge_u * s.clamp(0.0, 1.0) + r.edge_v * t.clamp(0.0, 1.0);
            (p - q).length()
        }
    }

    #[test]
    fn plane_head_on_and_misses() {
        let pl = Plane {
            point: Vec3A::new(0.0, 1.0, 0.0),
            normal: Vec3A::Y,
        };
        let (o, d) = (Vec3A::new(2.0, 5.0, 3.0), -Vec3A::Y * 2.0);
        let t = pl.intersect(o, d, 0.0, f32::INFINITY).unwrap();
        assert_eq!(t, 2.0);
        let h = pl.hit(o, d, t);
        assert_close(h.p, Vec3A::new(2.0, 1.0, 3.0), 1e-6, "point");
        assert_eq!(h.n, Vec3A::Y);
        let f = Frame::from_z(Vec3A::Y);
        let rel = Vec3A::new(2.0, 0.0, 3.0);
        assert!((h.uv - Vec2::new(rel.dot(f.x), rel.dot(f.y))).length() < 1e-6);
        assert_eq!(h.dpdu, f.x);
        // From the back the normal is still the front one.
        let (o, d) = (Vec3A::new(2.0, -1.0, 3.0), Vec3A::Y);
        let t = pl.intersect(o, d, 0.0, f32::INFINITY).unwrap();
        assert_eq!(t, 2.0);
        assert_eq!(pl.hit(o, d, t).n, Vec3A::Y);
        // Parallel (in and off the plane), away, too short.
        assert_eq!(
            pl.intersect(Vec3A::new(0.0, 1.0, 0.0), Vec3A::X, 0.0, 10.0),
            None
        );
        assert_eq!(
            pl.intersect(Vec3A::new(0.0, 3.0, 0.0), Vec3A::X, 0.0, 10.0),
            None
        );
        assert_eq!(
            pl.intersect(Vec3A::new(0.0, 3.0, 0.0), Vec3A::Y, 0.0, 10.0),
            None
        );
        assert_eq!(
            pl.intersect(Vec3A::new(0.0, 3.0, 0.0), -Vec3A::Y, 0.0, 2.0),
            None
        );
        assert_eq!(pl.bounds(), None);
        assert_eq!(pl.area(), f32::INFINITY);
        assert_eq!(pl.sample(Vec2::splat(0.5)), None);
    }

    #[test]
    fn plane_properties() {
        let pl = tilted_plane();
        let (lo, hi) = (pl.point - Vec3A::ONE, pl.point + Vec3A::ONE);
        let dist = plane_distance(pl.normal, pl.point);
        let s = Analytic::Plane(pl.clone());
        check_no_self_hit(&s, lo, hi, Leave::Never, Some(Leave::Never), 10);
        check_grazing(&s, lo, hi, &dist, 1e-5, 11);
        check_direction_scale(&s, lo, hi, 12);
        check_bad_inputs(&s, pl.point + pl.normal, -pl.normal);
    }

    #[test]
    fn disk_head_on_and_misses() {
        let dk = Disk {
            center: Vec3A::new(1.0, 2.0, 3.0),
            normal: Vec3A::Z,
            radius: 2.0,
        };
        // Frame::from_z(+Z) is the identity, so φ is measured from +X towards +Y.
        for (o, uv) in [
            (Vec3A::new(2.0, 2.0, 10.0), Vec2::new(0.5, 0.0)),
            (Vec3A::new(1.0, 3.0, 10.0), Vec2::new(0.5, 0.25)),
            (Vec3A::new(1.0, 0.5, 10.0), Vec2::new(0.75, 0.75)),
        ] {
            let d = -Vec3A::Z * 0.5;
            let t = dk.intersect(o, d, 0.0, f32::INFINITY).unwrap();
            assert!((t - 14.0).abs() < 1e-5, "t {t}");
            let h = dk.hit(o, d, t);
            assert_close(h.p, Vec3A::new(o.x, o.y, 3.0), 1e-6, "point");
            assert_eq!(h.n, Vec3A::Z);
            assert!((h.uv - uv).length() < 1e-5, "uv {} != {uv}", h.uv);
            assert!((h.dpdu.length() - 2.0).abs() < 1e-5 && h.dpdu.z == 0.0);
        }
        // Outside the rim, parallel, from behind (front normal still +Z).
        assert_eq!(
            dk.intersect(Vec3A::new(3.1, 2.0, 10.0), -Vec3A::Z, 0.0, 100.0),
            None
        );
        assert_eq!(
            dk.intersect(Vec3A::new(0.0, 2.0, 3.0), Vec3A::X, 0.0, 100.0),
            None
        );
        let t = dk.intersect(Vec3A::new(1.0, 2.0, 0.0), Vec3A::Z, 0.0, 100.0);
        assert_eq!(t, Some(3.0));
        assert_eq!(dk.hit(Vec3A::new(1.0, 2.0, 0.0), Vec3A::Z, 3.0).n, Vec3A::Z);
    }

    #[test]
    fn disk_bounds_are_tight() {
        let dk = tilted_disk();
        let b = dk.bounds().unwrap();
        let f = Frame::from_z(dk.normal);
        let (mut lo, mut hi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
        for i in 0..3600 {
            let a = i as f32 / 3600.0 * 2.0 * PI;
            let p = dk.center + (f.x * a.cos() + f.y * a.sin()) * dk.radius;
            assert!(p.cmpge(b.min - 1e-5).all() && p.cmple(b.max + 1e-5).all());
            lo = lo.min(p);
            hi = hi.max(p);
        }
        assert_close(lo, b.min, 1e-4, "min");
        assert_close(hi, b.max, 1e-4, "max");
    }

    #[test]
    fn disk_properties() {
        let dk = tilted_disk();
        let b = dk.bounds().unwrap();
        let (lo, hi) = (b.min, b.max);
        let dist = disk_distance(dk.clone());
        let s = Analytic::Disk(dk.clone());
        check_no_self_hit(&s, lo, hi, Leave::Never, Some(Leave::Never), 20);
        check_grazing(&s, lo, hi, &dist, 1e-5, 21);
        check_direction_scale(&s, lo, hi, 22);
        assert!((dk.area() - PI * 2.25).abs() < 1e-5);
        check_sampling(&s, &dist, 3.0, dk.center, dk.normal);
        check_bad_inputs(&s, dk.center + dk.normal, -dk.normal);
    }

    #[test]
    fn rectangle_head_on_and_misses() {
        let r = Rectangle {
            corner: Vec3A::new(-1.0, -1.0, 0.0),
            edge_u: Vec3A::new(2.0, 0.0, 0.0),
            edge_v: Vec3A::new(0.0, 3.0, 0.0),
        };
        let (o, d) = (Vec3A::new(0.0, 0.5, 5.0), -Vec3A::Z * 2.0);
        let t = r.intersect(o, d, 0.0, f32::INFINITY).unwrap();
        assert_eq!(t, 2.5);
        let h = r.hit(o, d, t);
        assert_close(h.p, Vec3A::new(0.0, 0.5, 0.0), 1e-6, "point");
        assert_eq!(h.n, Vec3A::Z);
        assert!((h.uv - Vec2::new(0.5, 0.5)).length() < 1e-6);
        assert_eq!(h.dpdu, r.edge_u);
        assert_eq!(r.area(), 6.0);
        // Outside each edge, parallel.
        for o in [(1.01, 0.0), (-1.01, 0.0), (0.0, 2.01), (0.0, -1.01)] {
            let o = Vec3A::new(o.0, o.1, 5.0);
            assert_eq!(r.intersect(o, -Vec3A::Z, 0.0, 100.0), None, "{o}");
        }
        assert_eq!(
            r.intersect(Vec3A::new(-2.0, 0.0, 0.0), Vec3A::X, 0.0, 100.0),
            None
        );
        // A skewed parallelogram: uv are the (s, t) along the edges.
        let r = skewed_rect();
        let p = r.corner + r.edge_u * 0.25 + r.edge_v * 0.75;
        let n = r.edge_u.cross(r.edge_v).normalize();
        let o = p - n * 3.0;
        let t = r.intersect(o, n, 0.0, 100.0).unwrap();
        assert!((t - 3.0).abs() < 1e-5);
        let h = r.hit(o, n, t);
        assert_close(h.p, p, 1e-5, "point");
        assert_close(h.n, n, 1e-6, "normal");
        assert!((h.uv - Vec2::new(0.25, 0.75)).length() < 1e-5);
    }

    #[test]
    fn rectangle_properties() {
        let r = skewed_rect();
        let b = r.bounds().unwrap();
        let (lo, hi) = (b.min, b.max);
        let dist = rect_distance(r.clone());
        let s = Analytic::Rectangle(r.clone());
        check_no_self_hit(&s, lo, hi, Leave::Never, Some(Leave::Never), 30);
        check_grazing(&s, lo, hi, &dist, 1e-5, 31);
        check_direction_scale(&s, lo, hi, 32);
        let mean = r.corner + (r.edge_u + r.edge_v) * 0.5;
        let n = r.edge_u.cross(r.edge_v).normalize();
        check_sampling(&s, &dist, (hi - lo).length(), mean, n);
        check_bad_inputs(&s, mean + n, -n);
        let flat = Rectangle {
            corner: Vec3A::ZERO,
            edge_u: Vec3A::X,
            edge_v: Vec3A::X * 2.0,
        };
        assert_eq!(flat.intersect(Vec3A::Z, -Vec3A::Z, 0.0, 10.0), None);
        assert_eq!(flat.sample(Vec2::splat(0.5)), None);
    }
}
