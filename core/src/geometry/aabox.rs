//! Axis-aligned boxes (slab method).

use super::{Aabb, LocalHit, ShapeSample};
use glam::{Vec2, Vec3A};

/// An axis-aligned box, a closed surface with outward normals.
///
/// uv: on the face with outward normal ±e_k, with a = (k+1) mod 3 and b = (k+2) mod 3,
/// v = (p_b − min_b)/extent_b and u = (p_a − min_a)/extent_a on the + face, mirrored,
/// (max_a − p_a)/extent_a, on the − face, so that ∂p/∂u × ∂p/∂v points outward on every face.
/// A box that is flat along some axis is a double-sided rectangle whose normal is +e_k.
#[derive(Clone, Debug, PartialEq)]
pub struct AaBox {
    /// Minimum corner.
    pub min: Vec3A,
    /// Maximum corner (≥ `min` component-wise; an inverted box is never hit).
    pub max: Vec3A,
}

impl AaBox {
    /// Object-space bounds: the box itself.
    pub fn bounds(&self) -> Option<Aabb> {
        Some(Aabb::new(self.min, self.max))
    }

    /// Nearest hit in (tmin, tmax); `d` need not be unit. A ray starting inside gets the exit.
    ///
    /// Slab method, written per axis so that a zero (or −0.0) direction component means "inside
    /// this slab or not" instead of the `0 · ∞ = NaN` of the reciprocal form.
    #[inline]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<f32> {
        if o.is_nan() || d.is_nan() {
            return None;
        }
        let (mut near, mut far) = (f32::NEG_INFINITY, f32::INFINITY);
        for k in 0..3 {
            let (lo, hi, ok, dk) = (self.min[k], self.max[k], o[k], d[k]);
            if dk == 0.0 {
                if !(ok >= lo && ok <= hi) {
                    return None;
                }
                continue;
            }
            // Entry and exit of this slab; an inverted slab (lo > hi) stays empty.
            let (a, b) = if dk > 0.0 {
                ((lo - ok) / dk, (hi - ok) / dk)
            } else {
                ((hi - ok) / dk, (lo - ok) / dk)
            };
            // `max`/`min` ignore a NaN operand (∞/∞ for infinite inputs), keeping the old value.
            near = near.max(a);
            far = far.min(b);
        }
        // `near` and `far` are never NaN (`max`/`min` drop NaN operands).
        if near > far {
            return None;
        }
        if near > tmin && near < tmax {
            Some(near)
        } else if far > tmin && far < tmax {
            Some(far)
        } else {
            None
        }
    }

    /// The face a point (on or very near the surface) lies on: (axis, is the max face).
    #[inline]
    fn face(&self, p: Vec3A) -> (usize, bool) {
        let mut best = (0, false);
        let mut best_dist = f32::INFINITY;
        for k in 0..3 {
            let (dlo, dhi) = ((p[k] - self.min[k]).abs(), (self.max[k] - p[k]).abs());
            if dhi < best_dist {
                best = (k, true);
                best_dist = dhi;
            }
            if dlo < best_dist {
                best = (k, false);
                best_dist = dlo;
            }
        }
        best
    }

    /// Surface details at parameter `t`. The point is snapped onto the face it is nearest to.
    #[inline]
    pub fn hit(&self, o: Vec3A, d: Vec3A, t: f32) -> LocalHit {
        let mut p = (o + d * t).clamp(self.min, self.max.max(self.min));
        let (k, is_max) = self.face(p);
        p[k] = if is_max { self.max[k] } else { self.min[k] };
        let mut n = Vec3A::ZERO;
        n[k] = if is_max { 1.0 } else { -1.0 };
        let (a, b) = ((k + 1) % 3, (k + 2) % 3);
        let ext = self.max - self.min;
        let frac = |axis: usize, x: f32| {
            if ext[axis] > 0.0 {
                (x / ext[axis]).clamp(0.0, 1.0)
            } else {
                0.0
            }
        };
        let u = if is_max {
            frac(a, p[a] - self.min[a])
        } else {
            frac(a, self.max[a] - p[a])
        };
        let v = frac(b, p[b] - self.min[b]);
        let mut dpdu = Vec3A::ZERO;
        dpdu[a] = if is_max { ext[a] } else { -ext[a] };
        LocalHit {
            p,
            n,
            uv: Vec2::new(u, v),
            dpdu,
        }
    }

    /// Surface area (of all six faces).
    pub fn area(&self) -> f32 {
        let e = (self.max - self.min).max(Vec3A::ZERO);
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    /// Uniform point by area: `u.x` picks a face with probability proportional to its area and
    /// is then reused (rescaled) with `u.y` for the point on that face. `None` for a box with
    /// no area.
    pub fn sample(&self, u: Vec2) -> Option<ShapeSample> {
        let area = self.area();
        if !(area > 0.0 && area.is_finite()) {
            return None;
        }
        let e = (self.max - self.min).max(Vec3A::ZERO);
        // Face k (both of them) has area e_a·e_b.
        let face_area = [e.y * e.z, e.z * e.x, e.x * e.y];
        let mut x = u.x.clamp(0.0, 1.0) * (0.5 * area);
        let mut k = 2;
        for (i, &fa) in face_area.iter().enumerate() {
            if x < fa || i == 2 {
                k = i;
                break;
            }
            x -= fa;
        }
        let fa = face_area[k];
        // Split face k's share into its − and + halves, and rescale to [0, 1).
        let s = if fa > 0.0 {
            (x / fa).clamp(0.0, 1.0)
        } else {
            0.5
        };
        let (is_max, s) = if s < 0.5 {
            (false, 2.0 * s)
        } else {
            (true, (2.0 * s - 1.0).min(1.0))
        };
        let (a, b) = ((k + 1) % 3, (k + 2) % 3);
        let mut p = self.min;
        p[k] = if is_max { self.max[k] } else { self.min[k] };
        p[a] = self.min[a] + s * e[a];
        p[b] = self.min[b] + u.y.clamp(0.0, 1.0) * e[b];
        let mut n = Vec3A::ZERO;
        n[k] = if is_max { 1.0 } else { -1.0 };
        Some(ShapeSample {
            p,
            n,
            pdf_area: 1.0 / area,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testutil::*;
    use super::super::Analytic;
    use super::*;

    fn unit_box() -> AaBox {
        AaBox {
            min: Vec3A::new(-1.0, -2.0, -0.5),
            max: Vec3A::new(3.0, 1.0, 0.5),
        }
    }

    fn shape() -> Analytic {
        Analytic::AaBox(unit_box())
    }

    /// Distance from the box surface, for points inside or outside.
    fn distance(p: Vec3A) -> f32 {
        let b = unit_box();
        let outside = (b.min - p).max(p - b.max).max(Vec3A::ZERO);
        if outside != Vec3A::ZERO {
            outside.length()
        } else {
            (p - b.min).min(b.max - p).min_element()
        }
    }

    #[test]
    fn head_on_hits_each_face() {
        let b = unit_box();
        // (origin, direction, t, point, normal, uv)
        let cases = [
            (
                Vec3A::new(5.0, 0.0, 0.0),
                -Vec3A::X,
                2.0,
                Vec3A::new(3.0, 0.0, 0.0),
                Vec3A::X,
                // +X face: u along y, v along z.
                Vec2::new(2.0 / 3.0, 0.5),
            ),
            (
                Vec3A::new(0.0, -10.0, 0.25),
                Vec3A::Y * 2.0,
                4.0,
                Vec3A::new(0.0, -2.0, 0.25),
                -Vec3A::Y,
                // −Y face: u mirrored along z, v along x.
                Vec2::new(0.25, 0.25),
            ),
            (
                Vec3A::new(1.0, 0.5, 4.5),
                -Vec3A::Z * 0.5,
                8.0,
                Vec3A::new(1.0, 0.5, 0.5),
                Vec3A::Z,
                Vec2::new(0.5, 2.5 / 3.0),
            ),
        ];
        for (o, d, t, p, n, uv) in cases {
            let got = b.intersect(o, d, 0.0, f32::INFINITY).expect("hit");
            assert!((got - t).abs() < 1e-5, "t {got} != {t}");
            let h = b.hit(o, d, got);
            assert_close(h.p, p, 1e-5, "point");
            assert_eq!(h.n, n);
            assert!((h.uv - uv).length() < 1e-5, "uv {} != {uv}", h.uv);
            assert!(h.dpdu.cross(n).length() > 0.0 && h.dpdu.dot(n) == 0.0);
        }
    }

    #[test]
    fn dpdu_cross_dpdv_is_outward() {
        let b = unit_box();
        let mut rng = Rng::new(1);
        for _ in 0..200 {
            let s = b.sample(rng.vec2()).unwrap();
            let o = s.p + s.n;
            let h = b.hit(o, -s.n, b.intersect(o, -s.n, 0.0, 10.0).unwrap());
            // Moving a little along dpdu changes u by the expected amount.
            let eps = 1e-3;
            let p2 = h.p + h.dpdu * eps;
            let h2 = b.hit(p2 + s.n, -s.n, 1.0);
            if h.uv.x + eps < 1.0 {
                assert!((h2.uv.x - h.uv.x - eps).abs() < 1e-4, "{} {}", h.uv, h2.uv);
            }
            // ∂p/∂v = extent_b · e_b with b = (k + 2) mod 3; with ∂p/∂u it spans the outside.
            let k = h.n.abs().max_position();
            let mut dpdv = Vec3A::ZERO;
            dpdv[(k + 2) % 3] = (b.max - b.min)[(k + 2) % 3];
            let p3 = h.p + dpdv * eps;
            let h3 = b.hit(p3 + s.n, -s.n, 1.0);
            if h.uv.y + eps < 1.0 {
                assert!((h3.uv.y - h.uv.y - eps).abs() < 1e-4, "{} {}", h.uv, h3.uv);
            }
            assert!(
                h.dpdu.cross(dpdv).dot(h.n) > 0.0,
                "{} {} {}",
                h.dpdu,
                dpdv,
                h.n
            );
        }
    }

    #[test]
    fn misses_and_zero_direction_components() {
        let b = unit_box();
        // Beside the box, parallel to a face.
        assert_eq!(
            b.intersect(Vec3A::new(5.0, 2.0, 0.0), -Vec3A::X, 0.0, 100.0),
            None
        );
        // Pointing away.
        assert_eq!(
            b.intersect(Vec3A::new(5.0, 0.0, 0.0), Vec3A::X, 0.0, 100.0),
            None
        );
        // Too short.
        assert_eq!(
            b.intersect(Vec3A::new(5.0, 0.0, 0.0), -Vec3A::X, 0.0, 1.9),
            None
        );
        // Zero and negative-zero components, origin inside the slab: hits.
        for z in [0.0, -0.0] {
            let d = Vec3A::new(-1.0, z, z);
            assert_eq!(
                b.intersect(Vec3A::new(5.0, 0.0, 0.0), d, 0.0, 100.0),
                Some(2.0)
            );
        }
        // Zero component with the origin exactly on the slab boundary: no NaN, a hit.
        let t = b.intersect(
            Vec3A::new(5.0, 1.0, 0.5),
            Vec3A::new(-1.0, 0.0, -0.0),
            0.0,
            100.0,
        );
        assert_eq!(t, Some(2.0));
        // Zero component outside the slab: miss.
        let d = Vec3A::new(-1.0, -0.0, 0.0);
        assert_eq!(b.intersect(Vec3A::new(5.0, 1.5, 0.0), d, 0.0, 100.0), None);
    }

    #[test]
    fn rays_from_inside_find_the_exit() {
        let b = unit_box();
        let mut rng = Rng::new(2);
        for _ in 0..500 {
            let o = rng.in_box(b.min, b.max);
            let d = rng.unit() * rng.range(0.1, 10.0);
            let t = b.intersect(o, d, 0.0, f32::INFINITY).expect("exit");
            let h = b.hit(o, d, t);
            assert!(distance(h.p) < 1e-5 && distance(o + d * t) < 1e-5);
            assert!(h.n.dot(d) > 0.0, "exit normal faces along the ray");
        }
    }

    #[test]
    fn no_self_intersection() {
        let b = unit_box();
        let (lo, hi) = (b.min, b.max);
        check_no_self_hit(
            &shape(),
            lo,
            hi,
            Leave::Never,
            Some(Leave::OnlyElsewhere),
            3,
        );
        // Far from the origin, where offsets are in ulps.
        let far = AaBox {
            min: Vec3A::new(1000.0, -2000.0, 500.0),
            max: Vec3A::new(1003.0, -1990.0, 504.0),
        };
        let (lo, hi) = (far.min, far.max);
        let s = Analytic::AaBox(far);
        check_no_self_hit(&s, lo, hi, Leave::Never, Some(Leave::OnlyElsewhere), 4);
    }

    #[test]
    fn grazing_rays() {
        let b = unit_box();
        check_grazing(&shape(), b.min, b.max, &distance, 1e-5, 5);
    }

    #[test]
    fn direction_scale() {
        let b = unit_box();
        check_direction_scale(&shape(), b.min, b.max, 6);
    }

    #[test]
    fn sampling() {
        let b = unit_box();
        assert!((b.area() - 2.0 * (4.0 * 3.0 + 3.0 + 4.0)).abs() < 1e-4);
        let scale = (b.max - b.min).length();
        let center = (b.min + b.max) * 0.5;
        check_sampling(&shape(), &distance, scale, center, Vec3A::ZERO);
    }

    #[test]
    fn bad_inputs() {
        check_bad_inputs(&shape(), Vec3A::new(5.0, 0.0, 0.0), -Vec3A::X);
        let flat = AaBox {
            min: Vec3A::ZERO,
            max: Vec3A::new(1.0, 0.0, 1.0),
        };
        assert_eq!(flat.area(), 2.0);
        assert!(flat.sample(Vec2::splat(0.3)).is_some());
        let empty = AaBox {
            min: Vec3A::ONE,
            max: Vec3A::ZERO,
        };
        assert_eq!(
            empty.intersect(Vec3A::splat(-1.0), Vec3A::ONE, 0.0, 10.0),
            None
        );
        assert_eq!(empty.sample(Vec2::splat(0.3)), None);
    }
}
