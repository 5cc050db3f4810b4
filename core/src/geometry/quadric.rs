//! General quadrics pᵀQp = 0 clipped to a box.

use super::{Aabb, LocalHit, ShapeSample};
use crate::sampling::warp::Frame;
use glam::{Mat4, Vec2, Vec3A, Vec4};
use std::f32::consts::PI;

/// A quadric surface f(p) = pᵀQp = 0, p = (x, y, z, 1), clipped to the box
/// [clip_min, clip_max].
///
/// Front side: where f > 0, i.e. the normal is the normalised gradient ∇f = 2·(Qp).xyz. For
/// the constructors below (and any ellipsoid written as x²/a² + y²/b² + z²/c² − 1 = 0) that is
/// outward. Multiply Q by −1 to flip it.
///
/// uv: u = φ/2π, φ the longitude of the hit point about the clip box centre c, about +Y from
/// +X towards −Z (the sphere's convention). v: for the shapes about the Y axis
/// ([`Quadric::cylinder`], [`Quadric::cone`], [`Quadric::paraboloid`],
/// [`Quadric::hyperboloid`]) the height, 0 at the clip box's top and 1 at its bottom, so that
/// an image wraps round them upright, as a label round a can; for the others (ellipsoids,
/// general quadrics) θ/π, θ the angle from +Y seen from c. ∂p/∂u is a unit tangent (the
/// surface tangent closest to the direction of growing φ).
///
/// Quadrics are not supported as area lights: [`Quadric::area`] is NaN and
/// [`Quadric::sample`] returns `None` (the scene builder rejects emissive quadrics).
#[derive(Clone, Debug, PartialEq)]
pub struct Quadric {
    /// Symmetric matrix Q.
    q: Mat4,
    /// Clip box minimum.
    clip_min: Vec3A,
    /// Clip box maximum.
    clip_max: Vec3A,
    /// Slack of the clip test (a tiny fraction of the box size), so that a surface that just
    /// touches the box (an ellipsoid in its own bounds) keeps its poles.
    clip_eps: f32,
    /// v by height along Y (shapes about the Y axis) rather than by the angle from +Y.
    v_by_height: bool,
}

impl Quadric {
    /// Checks Q (all entries finite, not all zero) and the clip box (finite, min < max on
    /// every axis), and symmetrises Q as (Q + Qᵀ)/2, which describes the same surface.
    pub fn new(q: Mat4, clip_min: Vec3A, clip_max: Vec3A) -> Result<Self, String> {
        if !q.is_finite() {
            return Err(format!("quadric matrix has a non-finite entry: {q}"));
        }
        if q == Mat4::ZERO {
            return Err("quadric matrix is zero (every point would be on the surface)".into());
        }
        if !(clip_min.is_finite() && clip_max.is_finite()) {
            return Err(format!(
                "quadric clip box must be finite, got {clip_min} .. {clip_max}"
            ));
        }
        if !clip_min.cmplt(clip_max).all() {
            return Err(format!(
                "quadric clip box needs clip_min < clip_max on every axis, got {clip_min} .. \
                 {clip_max}"
            ));
        }
        let q = (q + q.transpose()) * 0.5;
        let size = (clip_max - clip_min)
            .max_element()
            .max(clip_min.abs().max_element());
        let size = size.max(clip_max.abs().max_element());
        Ok(Self {
            q,
            clip_min,
            clip_max,
            clip_eps: 1e-5 * size,
            v_by_height: false,
        })
    }

    /// The same surface with v by height along Y (`true`) or by the angle from +Y (see the
    /// type's documentation).
    pub fn with_v_by_height(self, on: bool) -> Self {
        Self {
            v_by_height: on,
            ..self
        }
    }

    /// Whether v is the height along Y (see the type's documentation).
    pub fn v_by_height(&self) -> bool {
        self.v_by_height
    }

    // The named quadrics below are what the JSON format's shapes of the same names mean. Their
    // clip boxes reach 0.1 % beyond the surface (the clip test's slack alone would do; the
    // margin is kept because images rendered with it must keep their bits).

    /// The ellipsoid x²/a² + y²/b² + z²/c² − 1 = 0 with radii (a, b, c), clipped to its bounds.
    pub fn ellipsoid(radii: Vec3A) -> Result<Self, String> {
        if !(radii.cmpgt(Vec3A::ZERO).all() && radii.is_finite()) {
            return Err(format!(
                "ellipsoid radii must be positive and finite, got {radii}"
            ));
        }
        let inv = Vec3A::ONE / (radii * radii);
        let q = Mat4::from_diagonal(Vec4::new(inv.x, inv.y, inv.z, -1.0));
        Self::new(q, -radii * 1.001, radii * 1.001)
    }

    /// The cylinder x²/r² + z²/r² − 1 = 0 about the Y axis, for y ∈ [y_min, y_max] (open: no
    /// caps).
    pub fn cylinder(radius: f32, y_min: f32, y_max: f32) -> Result<Self, String> {
        if !(radius > 0.0 && radius.is_finite()) {
            return Err(format!(
                "cylinder radius must be positive and finite, got {radius}"
            ));
        }
        let r2 = radius * radius;
        let m = radius * 1.001;
        let q = Mat4::from_diagonal(Vec4::new(1.0 / r2, 0.0, 1.0 / r2, -1.0));
        Ok(
            Self::new(q, Vec3A::new(-m, y_min, -m), Vec3A::new(m, y_max, m))?
                .with_v_by_height(true),
        )
    }

    /// The double cone x² + z² − (s·y)² = 0 with apex at the origin, axis Y and slope
    /// s = tan(half-angle) (radius s·|y| at height y), for y ∈ [y_min, y_max]; y_min < 0 < y_max
    /// keeps both nappes.
    pub fn cone(slope: f32, y_min: f32, y_max: f32) -> Result<Self, String> {
        if !(slope > 0.0 && slope.is_finite()) {
            return Err(format!(
                "cone slope must be positive and finite, got {slope}"
            ));
        }
        let q = Mat4::from_diagonal(Vec4::new(1.0, -slope * slope, 1.0, 0.0));
        let m = slope * y_min.abs().max(y_max.abs()) * 1.001;
        Ok(
            Self::new(q, Vec3A::new(-m, y_min, -m), Vec3A::new(m, y_max, m))?
                .with_v_by_height(true),
        )
    }

    /// The paraboloid y = k·(x² + z²), i.e. k·x² + k·z² − y = 0, opening towards +Y for k > 0,
    /// for y ∈ [0, height].
    pub fn paraboloid(k: f32, height: f32) -> Result<Self, String> {
        if !(k > 0.0 && k.is_finite() && height > 0.0 && height.is_finite()) {
            return Err(format!(
                "paraboloid needs k > 0 and height > 0, got k = {k}, height = {height}"
            ));
        }
        let mut q = Mat4::from_diagonal(Vec4::new(k, 0.0, k, 0.0));
        // −y = 2·Q[y][w]·y.
        q.y_axis.w = -0.5;
        q.w_axis.y = -0.5;
        let m = (height / k).sqrt() * 1.001;
        Ok(
            Self::new(q, Vec3A::new(-m, -1e-3, -m), Vec3A::new(m, height, m))?
                .with_v_by_height(true),
        )
    }

    /// The hyperboloid of one sheet x²/a² + z²/a² − y²/c² − 1 = 0 about the Y axis (waist radius
    /// a), for y ∈ [y_min, y_max].
    pub fn hyperboloid(a: f32, c: f32, y_min: f32, y_max: f32) -> Result<Self, String> {
        if !(a > 0.0 && a.is_finite() && c > 0.0 && c.is_finite()) {
            return Err(format!(
                "hyperboloid needs a > 0 and c > 0, got a = {a}, c = {c}"
            ));
        }
        let q = Mat4::from_diagonal(Vec4::new(
            1.0 / (a * a),
            -1.0 / (c * c),
            1.0 / (a * a),
            -1.0,
        ));
        let y = y_min.abs().max(y_max.abs());
        let m = a * (1.0 + y * y / (c * c)).sqrt() * 1.001;
        Ok(
            Self::new(q, Vec3A::new(-m, y_min, -m), Vec3A::new(m, y_max, m))?
                .with_v_by_height(true),
        )
    }

    /// The clip box's minimum corner.
    pub fn clip_min(&self) -> Vec3A {
        self.clip_min
    }

    /// The clip box's maximum corner.
    pub fn clip_max(&self) -> Vec3A {
        self.clip_max
    }

    /// The symmetric matrix Q.
    pub fn q(&self) -> Mat4 {
        self.q
    }

    /// f(p) = pᵀQp.
    #[inline]
    pub fn value(&self, p: Vec3A) -> f32 {
        let ph = p.extend(1.0);
        ph.dot(self.q * ph)
    }

    /// ∇f(p) = 2·(Qp).xyz, the direction of the front side.
    #[inline]
    pub fn gradient(&self, p: Vec3A) -> Vec3A {
        2.0 * Vec3A::from_vec4(self.q * p.extend(1.0))
    }

    /// Is `p` inside the clip box (with the slack `clip_eps`)?
    #[inline]
    fn in_clip(&self, p: Vec3A) -> bool {
        p.cmpge(self.clip_min - self.clip_eps).all() && p.cmple(self.clip_max + self.clip_eps).all()
    }

    /// The clip box.
    pub fn bounds(&self) -> Option<Aabb> {
        Some(Aabb::new(self.clip_min, self.clip_max))
    }

    /// Nearest hit in (tmin, tmax) inside the clip box; `d` need not be unit.
    ///
    /// The ray is first clipped to the box, and the quadratic a s² + 2h s + c = 0 is written
    /// about the point where it enters the box (t = t₀ + s), so that the coefficients are
    /// computed near the surface rather than far along the ray. Roots come from the stable
    /// form q = −(h + sign(h)·√(h² − ac)), s = q/a and c/q, which also covers a ≈ 0 (rays
    /// along a cone or paraboloid: one root goes to infinity, the other is the linear root
    /// −c/2h). Both roots are tried in order: the near one may be clipped away.
    #[inline]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<f32> {
        if o.is_nan() || d.is_nan() {
            return None;
        }
        // Clip box slab test (per axis, so zero direction components are handled).
        let (bmin, bmax) = (self.clip_min - self.clip_eps, self.clip_max + self.clip_eps);
        let (mut lo, mut hi) = (tmin, tmax);
        for k in 0..3 {
            if d[k] == 0.0 {
                if !(o[k] >= bmin[k] && o[k] <= bmax[k]) {
                    return None;
                }
                continue;
            }
            let (a, b) = if d[k] > 0.0 {
                ((bmin[k] - o[k]) / d[k], (bmax[k] - o[k]) / d[k])
            } else {
                ((bmax[k] - o[k]) / d[k], (bmin[k] - o[k]) / d[k])
            };
            lo = lo.max(a);
            hi = hi.min(b);
        }
        let overlap = lo <= hi;
        if !overlap {
            return None;
        }
        let t0 = if lo.is_finite() { lo } else { 0.0 };
        let base = o + d * t0;
        let dh = d.extend(0.0);
        let qb = self.q * base.extend(1.0);
        let a = dh.dot(self.q * dh);
        let h = dh.dot(qb);
        let c = base.extend(1.0).dot(qb);
        let disc = h * h - a * c;
        if disc.is_nan() || disc < 0.0 {
            return None;
        }
        let q = -(h + disc.sqrt().copysign(h));
        let (mut s0, mut s1) = (q / a, c / q);
        if a == 0.0 {
            // Linear: 2h s + c = 0 (q = −2h); no second root.
            s0 = c / q;
            s1 = f32::NAN;
        } else if s0 > s1 {
            std::mem::swap(&mut s0, &mut s1);
        }
        [s0, s1].into_iter().find_map(|s| {
            let t = t0 + s;
            (t > tmin && t < tmax && self.in_clip(o + d * t)).then_some(t)
        })
    }

    /// Surface details at parameter `t`. The point is moved onto the surface by one Newton
    /// step along the gradient, p ← p − f(p)·∇f/|∇f|².
    #[inline]
    pub fn hit(&self, o: Vec3A, d: Vec3A, t: f32) -> LocalHit {
        let mut p = o + d * t;
        let g = self.gradient(p);
        let g2 = g.length_squared();
        if g2 > 0.0 {
            let step = g * (self.value(p) / g2);
            if step.is_finite() {
                p -= step;
            }
        }
        // At a singular point (a cone's apex) there is no gradient: face the ray.
        let n = self
            .gradient(p)
            .normalize_or(g.normalize_or(-d.normalize_or(Vec3A::Y)));
        let c = (self.clip_min + self.clip_max) * 0.5;
        let dir = (p - c).normalize_or(Vec3A::Y);
        let phi = (-dir.z).atan2(dir.x);
        let phi = if phi < 0.0 { phi + 2.0 * PI } else { phi };
        let v = if self.v_by_height {
            let (bottom, top) = (self.clip_min.y, self.clip_max.y);
            ((top - p.y) / (top - bottom)).clamp(0.0, 1.0)
        } else {
            dir.y.clamp(-1.0, 1.0).acos() / PI
        };
        let dpdu = Frame::from_zx(n, Vec3A::new(dir.z, 0.0, -dir.x)).x;
        LocalHit {
            p,
            n,
            uv: Vec2::new(phi / (2.0 * PI), v),
            dpdu,
        }
    }

    /// Not supported (quadrics are never area lights): NaN.
    pub fn area(&self) -> f32 {
        f32::NAN
    }

    /// Not supported (quadrics are never area lights): `None`.
    pub fn sample(&self, _u: Vec2) -> Option<ShapeSample> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::super::sphere::Sphere;
    use super::super::testutil::*;
    use super::super::Analytic;
    use super::*;

    /// |f(p)| / |∇f(p)|: the first-order distance from the surface.
    fn distance(q: &Quadric) -> impl Fn(Vec3A) -> f32 + '_ {
        move |p| {
            let g = q.gradient(p).length();
            if g > 0.0 {
                q.value(p).abs() / g
            } else {
                q.value(p).abs()
            }
        }
    }

    fn all_shapes() -> Vec<(&'static str, Quadric, Leave)> {
        vec![
            (
                "ellipsoid",
                Quadric::ellipsoid(Vec3A::new(1.0, 2.0, 0.5)).unwrap(),
                Leave::Never,
            ),
            (
                "cylinder",
                Quadric::cylinder(0.7, -1.0, 2.0).unwrap(),
                Leave::Never,
            ),
            (
                "cone",
                Quadric::cone(0.6, -1.5, 2.0).unwrap(),
                Leave::OnlyElsewhere,
            ),
            (
                "paraboloid",
                Quadric::paraboloid(0.8, 2.0).unwrap(),
                Leave::Never,
            ),
            (
                "hyperboloid",
                Quadric::hyperboloid(0.5, 0.8, -1.5, 1.5).unwrap(),
                Leave::OnlyElsewhere,
            ),
        ]
    }

    #[test]
    fn head_on_hits() {
        // (shape, origin, direction, t, point, normal)
        let e = Quadric::ellipsoid(Vec3A::new(1.0, 2.0, 0.5)).unwrap();
        let cyl = Quadric::cylinder(0.5, -1.0, 1.0).unwrap();
        let cone = Quadric::cone(0.5, -2.0, 2.0).unwrap();
        let par = Quadric::paraboloid(1.0, 4.0).unwrap();
        let hyp = Quadric::hyperboloid(0.5, 1.0, -1.0, 1.0).unwrap();
        let cases = [
            (
                &e,
                Vec3A::new(0.0, 5.0, 0.0),
                -Vec3A::Y,
                3.0,
                Vec3A::Y * 2.0,
                Vec3A::Y,
            ),
            (
                &e,
                Vec3A::new(4.0, 0.0, 0.0),
                -Vec3A::X * 2.0,
                1.5,
                Vec3A::X,
                Vec3A::X,
            ),
            (
                &cyl,
                Vec3A::new(0.0, 0.5, 3.0),
                -Vec3A::Z,
                2.5,
                Vec3A::new(0.0, 0.5, 0.5),
                Vec3A::Z,
            ),
            // Cone at y = 1: radius 0.5, normal ∝ (1, −s, 0)·... = (2x, −2s²y, 2z).
            (
                &cone,
                Vec3A::new(3.0, 1.0, 0.0),
                -Vec3A::X,
                2.5,
                Vec3A::new(0.5, 1.0, 0.0),
                Vec3A::new(1.0, -0.5, 0.0).normalize(),
            ),
            // Paraboloid y = x² + z²: from below along the axis hits the vertex, normal −Y.
            (
                &par,
                Vec3A::new(0.0, -1.0, 0.0),
                Vec3A::Y * 4.0,
                0.25,
                Vec3A::ZERO,
                -Vec3A::Y,
            ),
            // ... and from inside the bowl, at y = 1 the rim x = 1: normal ∝ (2, −1, 0).
            (
                &par,
                Vec3A::new(0.0, 1.0, 0.0),
                Vec3A::X,
                1.0,
                Vec3A::new(1.0, 1.0, 0.0),
                Vec3A::new(2.0, -1.0, 0.0).normalize(),
            ),
            // Hyperboloid waist.
            (
                &hyp,
                Vec3A::new(-2.0, 0.0, 0.0),
                Vec3A::X,
                1.5,
                -Vec3A::X * 0.5,
                -Vec3A::X,
            ),
            // From −X the ray finds the ellipsoid's −X point.
            (
                &e,
                Vec3A::new(-3.0, 0.0, 0.0),
                Vec3A::new(1.0, 0.0, 0.0),
                2.0,
                -Vec3A::X,
                -Vec3A::X,
            ),
        ];
        for (q, o, d, t, p, n) in cases {
            let got = q.intersect(o, d, 0.0, f32::INFINITY).expect("hit");
            assert!((got - t).abs() < 1e-5, "t {got} != {t} ({o} {d})");
            let h = q.hit(o, d, got);
            assert_close(h.p, p, 1e-5, "point");
            assert_close(h.n, n, 1e-5, "normal");
            assert!(h.dpdu.dot(h.n).abs() < 1e-5 && (h.dpdu.length() - 1.0).abs() < 1e-5);
        }
        // uv of the ellipsoid's +X point: φ = 0, θ = π/2.
        let h = e.hit(Vec3A::new(4.0, 0.0, 0.0), -Vec3A::X, 3.0);
        assert!((h.uv - Vec2::new(0.0, 0.5)).length() < 1e-5, "uv {}", h.uv);
        // ... and of its −Z point: φ = π/2.
        let h = e.hit(Vec3A::new(0.0, 0.0, -4.0), Vec3A::Z, 3.5);
        assert!((h.uv - Vec2::new(0.25, 0.5)).length() < 1e-5, "uv {}", h.uv);
    }

    /// The shapes about the Y axis take v from the height, 0 at the top and 1 at the bottom,
    /// linearly (a label wraps a can upright and undistorted); u is the longitude as on a
    /// sphere.
    #[test]
    fn shapes_about_the_y_axis_take_v_from_the_height() {
        let tall = Quadric::cylinder(0.2, 0.0, 2.0).unwrap();
        for (y, v) in [(1.95f32, 0.025f32), (1.5, 0.25), (1.0, 0.5), (0.1, 0.95)] {
            // From +X, and from −Z a quarter turn on.
            let o = Vec3A::new(3.0, y, 0.0);
            let t = tall.intersect(o, -Vec3A::X, 0.0, f32::INFINITY).unwrap();
            let h = tall.hit(o, -Vec3A::X, t);
            assert!(
                (h.uv - Vec2::new(0.0, v)).length() < 1e-5,
                "y {y}: uv {}",
                h.uv
            );
            let o = Vec3A::new(0.0, y, -3.0);
            let t = tall.intersect(o, Vec3A::Z, 0.0, f32::INFINITY).unwrap();
            let h = tall.hit(o, Vec3A::Z, t);
            assert!(
                (h.uv - Vec2::new(0.25, v)).length() < 1e-5,
                "y {y}: uv {}",
                h.uv
            );
        }
        let cone = Quadric::cone(0.5, 1.0, 3.0).unwrap();
        let hyperboloid = Quadric::hyperboloid(1.0, 1.0, -1.0, 1.0).unwrap();
        for (q, y, v) in [(&cone, 2.5f32, 0.25f32), (&hyperboloid, 0.0, 0.5)] {
            let o = Vec3A::new(5.0, y, 0.0);
            let t = q.intersect(o, -Vec3A::X, 0.0, f32::INFINITY).unwrap();
            let h = q.hit(o, -Vec3A::X, t);
            assert!((h.uv.y - v).abs() < 1e-5, "y {y}: uv {}", h.uv);
        }
        // Ellipsoids keep the angle from +Y.
        let e = Quadric::ellipsoid(Vec3A::new(1.0, 2.0, 1.0)).unwrap();
        let h = e.hit(Vec3A::new(0.0, 5.0, 0.0), -Vec3A::Y, 3.0);
        assert!(h.uv.y.abs() < 1e-3, "uv {}", h.uv);
    }

    #[test]
    fn misses() {
        let e = Quadric::ellipsoid(Vec3A::new(1.0, 2.0, 0.5)).unwrap();
        assert_eq!(
            e.intersect(Vec3A::new(1.1, 0.0, 5.0), -Vec3A::Z, 0.0, 100.0),
            None
        );
        assert_eq!(
            e.intersect(Vec3A::new(0.0, 0.0, 5.0), Vec3A::Z, 0.0, 100.0),
            None
        );
        assert_eq!(
            e.intersect(Vec3A::new(0.0, 0.0, 5.0), -Vec3A::Z, 0.0, 4.0),
            None
        );
        // Inside a cylinder, parallel to its axis: a = 0 and h = 0.
        let cyl = Quadric::cylinder(0.5, -1.0, 1.0).unwrap();
        assert_eq!(
            cyl.intersect(Vec3A::new(0.1, -5.0, 0.0), Vec3A::Y, 0.0, 100.0),
            None
        );
        assert!(cyl.area().is_nan());
        assert_eq!(cyl.sample(Vec2::splat(0.5)), None);
        let m = 0.5 * 1.001;
        assert_eq!(cyl.bounds().unwrap().min, Vec3A::new(-m, -1.0, -m));
    }

    #[test]
    fn ellipsoid_with_equal_radii_agrees_with_the_sphere() {
        let q = Quadric::ellipsoid(Vec3A::splat(1.5)).unwrap();
        let s = Sphere {
            center: Vec3A::ZERO,
            radius: 1.5,
        };
        let mut rng = Rng::new(50);
        let mut hits = 0;
        for i in 0..2000 {
            // Outside and inside origins, non-unit directions.
            let o = if i % 4 == 0 {
                rng.unit() * rng.range(0.0, 1.4)
            } else {
                rng.unit() * rng.range(2.0, 20.0)
            };
            let d = (rng.in_box(Vec3A::splat(-1.6), Vec3A::splat(1.6)) - o) * rng.range(0.1, 3.0);
            let ts = s.intersect(o, d, 0.0, f32::INFINITY);
            let tq = q.intersect(o, d, 0.0, f32::INFINITY);
            match (ts, tq) {
                (Some(a), Some(b)) => {
                    hits += 1;
                    assert!((a - b).abs() <= 1e-4 * a.abs().max(1e-3), "{a} vs {b}");
                    let (hs, hq) = (s.hit(o, d, a), q.hit(o, d, b));
                    assert_close(hs.p, hq.p, 1e-4, "point");
                    assert_close(hs.n, hq.n, 1e-4, "normal");
                    assert!((hs.uv - hq.uv).length() < 1e-3 || (hs.uv.x - hq.uv.x).abs() > 0.99);
                }
                (None, None) => {}
                // Only a hair's breadth from tangent may the two disagree.
                (a, b) => {
                    let t = a.or(b).unwrap();
                    let p = o + d * t;
                    let dn = d.normalize();
                    let cos = dn.dot(p.normalize()).abs();
                    assert!(
                        cos < 1e-2,
                        "disagree: sphere {a:?} quadric {b:?} for {o} {d}"
                    );
                }
            }
        }
        assert!(hits > 1000, "{hits}");
    }

    #[test]
    fn hits_lie_on_the_surface_inside_the_clip_box() {
        let mut rng = Rng::new(51);
        for (name, q, _) in all_shapes() {
            let (lo, hi) = (q.clip_min, q.clip_max);
            let scale = (hi - lo).length();
            let mut hits = 0;
            for _ in 0..2000 {
                let o = (lo + hi) * 0.5 + rng.unit() * rng.range(0.0, 3.0 * scale);
                let d = rng.in_box(lo, hi) - o;
                let Some(t) = q.intersect(o, d, 0.0, f32::INFINITY) else {
                    continue;
                };
                hits += 1;
                let h = q.hit(o, d, t);
                let rel = q.value(h.p).abs() / (q.gradient(h.p).length() * scale).max(1e-6);
                assert!(rel < 1e-5, "{name}: |f| relative {rel} at {}", h.p);
                let raw = o + d * t;
                assert!(
                    raw.cmpge(lo - 1e-4 * scale).all() && raw.cmple(hi + 1e-4 * scale).all(),
                    "{name}: hit {raw} outside the clip box"
                );
                assert!((h.n.length() - 1.0).abs() < 1e-4 && h.uv.is_finite());
            }
            assert!(hits > 200, "{name}: {hits}");
        }
    }

    #[test]
    fn clipping_skips_to_the_second_root_or_misses() {
        // A sphere of radius 2 clipped to y ≤ 1: a ray down the axis from above passes the
        // clipped-away north pole and hits the south pole from inside.
        let q = Quadric::new(
            Quadric::ellipsoid(Vec3A::splat(2.0)).unwrap().q(),
            Vec3A::splat(-2.0),
            Vec3A::new(2.0, 1.0, 2.0),
        )
        .unwrap();
        let t = q
            .intersect(Vec3A::new(0.0, 5.0, 0.0), -Vec3A::Y, 0.0, 100.0)
            .unwrap();
        assert!((t - 7.0).abs() < 1e-5, "{t}");
        // The normal is still the outward one (the ray sees the inside).
        let h = q.hit(Vec3A::new(0.0, 5.0, 0.0), -Vec3A::Y, t);
        assert_close(h.n, -Vec3A::Y, 1e-5, "normal");
        // A ray that meets the surface only above the clip plane misses.
        let o = Vec3A::new(-5.0, 1.8, 0.0);
        assert_eq!(q.intersect(o, Vec3A::X, 0.0, 100.0), None);
        // A cylinder clipped to y ∈ [−1, 1]: a ray crossing it at y = 1.5 misses.
        let cyl = Quadric::cylinder(0.5, -1.0, 1.0).unwrap();
        assert_eq!(
            cyl.intersect(Vec3A::new(-3.0, 1.5, 0.0), Vec3A::X, 0.0, 100.0),
            None
        );
        // Entering over the rim and going down hits the inside wall, not the (clipped) outside.
        let o = Vec3A::new(-1.0, 2.0, 0.0);
        let d = Vec3A::new(1.0, -1.2, 0.0);
        let t = cyl.intersect(o, d, 0.0, 100.0).unwrap();
        let p = o + d * t;
        assert!((p.x - 0.5).abs() < 1e-5 && p.y < 1.0, "{p}");
    }

    #[test]
    fn rays_from_inside_an_ellipsoid_find_the_exit() {
        let q = Quadric::ellipsoid(Vec3A::new(1.0, 2.0, 0.5)).unwrap();
        let mut rng = Rng::new(52);
        for _ in 0..500 {
            let o = rng.unit() * rng.range(0.0, 0.45);
            let d = rng.unit() * rng.range(0.1, 10.0);
            let t = q.intersect(o, d, 0.0, f32::INFINITY).expect("exit");
            let h = q.hit(o, d, t);
            assert!(distance(&q)(h.p) < 1e-5 && h.n.dot(d) > 0.0);
        }
    }

    #[test]
    fn along_the_surface_direction() {
        // a = 0: a ray parallel to a generator of the cone hits it once (linear case).
        // x = t − 1, y = t: (t − 1)² = t² at t = 1/2.
        let cone = Quadric::cone(1.0, -2.0, 2.0).unwrap();
        let o = Vec3A::new(-1.0, 0.0, 0.0);
        let d = Vec3A::new(1.0, 1.0, 0.0);
        let t = cone.intersect(o, d, 0.0, 100.0).unwrap();
        assert!((t - 0.5).abs() < 1e-6, "{t}");
        // The same ray the other way never meets the cone again (t = 1/2 is behind it).
        assert_eq!(cone.intersect(o, -d, 0.0, 100.0), None);
        // A ray parallel to the paraboloid's axis (a = 0) hits once.
        let par = Quadric::paraboloid(1.0, 4.0).unwrap();
        let o = Vec3A::new(0.5, -3.0, 1.0);
        let t = par.intersect(o, Vec3A::Y * 2.0, 0.0, 100.0).unwrap();
        assert!((t - (3.0 + 1.25) / 2.0).abs() < 1e-5, "{t}");
    }

    #[test]
    fn no_self_intersection() {
        for (i, (name, q, leave)) in all_shapes().into_iter().enumerate() {
            let (lo, hi) = (q.clip_min, q.clip_max);
            let _ = name;
            let s = Analytic::Quadric(q);
            check_no_self_hit(&s, lo, hi, leave, Some(Leave::OnlyElsewhere), 60 + i as u32);
        }
    }

    #[test]
    fn grazing_rays() {
        for (i, (_, q, _)) in all_shapes().into_iter().enumerate() {
            let (lo, hi) = (q.clip_min, q.clip_max);
            let s = Analytic::Quadric(q.clone());
            check_grazing(&s, lo, hi, &distance(&q), 1e-5, 70 + i as u32);
        }
    }

    #[test]
    fn direction_scale() {
        for (i, (_, q, _)) in all_shapes().into_iter().enumerate() {
            let (lo, hi) = (q.clip_min, q.clip_max);
            check_direction_scale(&Analytic::Quadric(q), lo, hi, 80 + i as u32);
        }
    }

    #[test]
    fn validation_and_bad_inputs() {
        let id = Mat4::IDENTITY;
        assert!(Quadric::new(Mat4::ZERO, -Vec3A::ONE, Vec3A::ONE).is_err());
        let mut nan = id;
        nan.x_axis.y = f32::NAN;
        assert!(Quadric::new(nan, -Vec3A::ONE, Vec3A::ONE).is_err());
        assert!(Quadric::new(id, Vec3A::ONE, -Vec3A::ONE).is_err());
        assert!(Quadric::new(id, Vec3A::ZERO, Vec3A::new(1.0, 0.0, 1.0)).is_err());
        assert!(Quadric::new(id, Vec3A::ZERO, Vec3A::INFINITY).is_err());
        assert!(Quadric::ellipsoid(Vec3A::new(1.0, -1.0, 1.0)).is_err());
        assert!(Quadric::cylinder(0.0, -1.0, 1.0).is_err());
        assert!(Quadric::cylinder(1.0, 1.0, -1.0).is_err());
        assert!(Quadric::cone(f32::NAN, -1.0, 1.0).is_err());
        assert!(Quadric::paraboloid(1.0, -1.0).is_err());
        assert!(Quadric::hyperboloid(1.0, 0.0, -1.0, 1.0).is_err());
        // Symmetrised: an asymmetric Q describes the same surface as its symmetric part.
        let mut asym = Mat4::from_diagonal(Vec4::new(1.0, 1.0, 1.0, -1.0));
        asym.x_axis.y = 0.6; // Q[x][y] = 0.6, Q[y][x] = 0
        let q = Quadric::new(asym, -Vec3A::splat(3.0), Vec3A::splat(3.0)).unwrap();
        assert_eq!(q.q(), q.q().transpose());
        assert!((q.q().x_axis.y - 0.3).abs() < 1e-7);
        // Every constructor's shape, hit from outside its clip box towards the centre of the box.
        for (name, q, _) in all_shapes() {
            let c = (q.clip_min + q.clip_max) * 0.5;
            let s = Analytic::Quadric(q.clone());
            let o = Vec3A::new(c.x + 0.1 * q.clip_max.x, c.y + 0.05, q.clip_max.z + 5.0);
            assert!(s.intersect(o, -Vec3A::Z, 0.0, 100.0).is_some(), "{name}");
            check_bad_inputs(&s, o, -Vec3A::Z);
        }
    }
}
