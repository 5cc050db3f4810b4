//! Shared helpers for the shape tests: a tiny deterministic random-number generator and the
//! properties every analytic shape must have (no self-intersection, sane grazing hits, `t` in
//! units of a non-normalised direction, consistent area sampling, no panics on bad input).

use super::{offset_ray_origin, Analytic};
use crate::sampling::hash_u32;
use crate::sampling::warp::uniform_sphere;
use glam::{Vec2, Vec3A};

/// Deterministic random numbers for tests: a hashed counter, so every run draws the same values.
pub struct Rng {
    state: u32,
}

impl Rng {
    /// A generator for stream `seed`.
    pub fn new(seed: u32) -> Self {
        Self {
            state: hash_u32(seed ^ 0x5bd1_e995),
        }
    }

    /// A float in [0, 1).
    pub fn f32(&mut self) -> f32 {
        self.state = self.state.wrapping_add(0x9e37_79b9);
        (hash_u32(self.state) >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// Two floats in [0, 1).
    pub fn vec2(&mut self) -> Vec2 {
        Vec2::new(self.f32(), self.f32())
    }

    /// A float in [lo, hi).
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }

    /// A uniform unit vector.
    pub fn unit(&mut self) -> Vec3A {
        uniform_sphere(self.vec2())
    }

    /// A uniform point in the box [lo, hi].
    pub fn in_box(&mut self, lo: Vec3A, hi: Vec3A) -> Vec3A {
        Vec3A::new(
            self.range(lo.x, hi.x),
            self.range(lo.y, hi.y),
            self.range(lo.z, hi.z),
        )
    }
}

/// Asserts `|a - b| <= tol` for vectors, with a readable message.
#[track_caller]
pub fn assert_close(a: Vec3A, b: Vec3A, tol: f32, what: &str) {
    assert!(
        (a - b).length() <= tol,
        "{what}: {a} vs {b} (tolerance {tol})"
    );
}

/// Surface points with their front normals, as the renderer gets them: the `hit` of rays shot
/// from a sphere around the region [lo, hi] at random targets inside it.
pub fn surface_points(
    shape: &Analytic,
    lo: Vec3A,
    hi: Vec3A,
    count: usize,
    rng: &mut Rng,
) -> Vec<(Vec3A, Vec3A)> {
    let center = (lo + hi) * 0.5;
    let reach = 3.0 * (hi - lo).length().max(1e-3);
    let mut out = Vec::with_capacity(count);
    let mut attempts = 0;
    while out.len() < count {
        attempts += 1;
        assert!(attempts < 200 * count, "too few rays hit the shape");
        let o = center + rng.unit() * reach;
        let d = rng.in_box(lo, hi) - o;
        if let Some(t) = shape.intersect(o, d, 0.0, f32::INFINITY) {
            let h = shape.hit(o, d, t);
            out.push((h.p, h.n));
        }
    }
    out
}

/// How a shape may legitimately be hit again by a ray that leaves its surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Leave {
    /// Never (flat shapes on either side; convex closed shapes to the outside).
    Never,
    /// Only far away or on a differently oriented part (curved or non-convex surfaces).
    OnlyElsewhere,
}

/// Shoots a ray from each surface point, offset with [`offset_ray_origin`] to the side the ray
/// goes to, and checks it does not hit the surface it left ("surface acne"). `front` governs
/// rays leaving on the front side (along the normal), `back` rays leaving on the back side
/// (`None`: not tested). Back-side directions keep |cos| ≥ 0.05 to the normal, so that a
/// legitimate second hit on a curved surface is not mistaken for acne.
pub fn check_no_self_hit(
    shape: &Analytic,
    lo: Vec3A,
    hi: Vec3A,
    front: Leave,
    back: Option<Leave>,
    seed: u32,
) {
    let mut rng = Rng::new(seed);
    let scale = (hi - lo).length();
    let points = surface_points(shape, lo, hi, 1000, &mut rng);
    for (i, &(p, n)) in points.iter().enumerate() {
        let mut sides = vec![(1.0, front)];
        if let Some(b) = back {
            sides.push((-1.0, b));
        }
        for (sign, rule) in sides {
            let mut w = rng.unit();
            if w.dot(n) * sign < 0.0 {
                w = -w;
            }
            if sign < 0.0 && w.dot(n).abs() < 0.05 {
                w = (w - n * 0.1).normalize();
            }
            let o = offset_ray_origin(p, n, w);
            let Some(t) = shape.intersect(o, w, 0.0, f32::INFINITY) else {
                continue;
            };
            let h = shape.hit(o, w, t);
            let far = (h.p - p).length() > 1e-3 * scale;
            let turned = h.n.dot(n) < 0.99;
            assert!(
                rule == Leave::OnlyElsewhere && (far || turned),
                "point {i} {p} side {sign}: ray along {w} from {o} hit its own surface again at \
                 t = {t}, {} (normal {})",
                h.p,
                h.n
            );
        }
    }
}

/// Rays nearly tangent to the surface either miss or hit a point on the surface: `distance`
/// returns how far a point is from the surface, and must stay below `tol · (scale + |p|)`. Also checks
/// that every reported quantity is finite and the normal unit.
pub fn check_grazing(
    shape: &Analytic,
    lo: Vec3A,
    hi: Vec3A,
    distance: &dyn Fn(Vec3A) -> f32,
    tol: f32,
    seed: u32,
) {
    let mut rng = Rng::new(seed);
    let scale = (hi - lo).length();
    let points = surface_points(shape, lo, hi, 300, &mut rng);
    let mut hits = 0;
    for &(p, n) in &points {
        let tangent = crate::sampling::warp::Frame::from_z(n).to_world(
            crate::sampling::warp::uniform_sphere(rng.vec2()) * Vec3A::new(1.0, 1.0, 0.0),
        );
        let Some(tangent) = tangent.try_normalize() else {
            continue;
        };
        for eps in [0.0, 1e-7, -1e-7, 1e-5, -1e-5, 1e-3, -1e-3] {
            let w = (tangent + n * eps).normalize();
            let o = p - w * (0.5 * scale);
            let Some(t) = shape.intersect(o, w, 0.0, f32::INFINITY) else {
                continue;
            };
            hits += 1;
            assert!(t.is_finite() && t > 0.0, "t = {t}");
            let h = shape.hit(o, w, t);
            assert!(h.p.is_finite() && h.n.is_finite() && h.uv.is_finite() && h.dpdu.is_finite());
            assert!((h.n.length() - 1.0).abs() < 1e-4, "normal {}", h.n);
            // Far-away hits of nearly parallel rays carry the rounding of their magnitude.
            let dist = distance(h.p);
            assert!(
                dist <= tol * (scale + h.p.length()),
                "grazing hit {} off the surface by {dist} (ray {o} + t {w}, t = {t})",
                h.p
            );
            assert!(
                (o + w * t - h.p).length() <= 1e-2 * scale + 1e-5 * h.p.length(),
                "hit point {} far from the ray point {}",
                h.p,
                o + w * t
            );
        }
    }
    assert!(hits > 0, "no grazing ray hit at all");
}

/// Scaling the direction scales `t` inversely and leaves the hit point where it was (for hits
/// that are not grazing).
pub fn check_direction_scale(shape: &Analytic, lo: Vec3A, hi: Vec3A, seed: u32) {
    let mut rng = Rng::new(seed);
    let scale = (hi - lo).length();
    let center = (lo + hi) * 0.5;
    let mut hits = 0;
    for _ in 0..300 {
        let o = center + rng.unit() * (2.0 * scale);
        let d = (rng.in_box(lo, hi) - o).normalize();
        let Some(t) = shape.intersect(o, d, 0.0, f32::INFINITY) else {
            continue;
        };
        let h = shape.hit(o, d, t);
        // Grazing hits are ill-conditioned (rounding the scaled direction moves them); they
        // have their own check.
        if h.n.dot(d).abs() < 0.05 {
            continue;
        }
        hits += 1;
        let p = h.p;
        for k in [1e-3, 0.37, 2.5, 1e3] {
            let tk = shape
                .intersect(o, d * k, 0.0, f32::INFINITY)
                .unwrap_or_else(|| panic!("scaled direction ({k}) missed: {o} {d} t = {t}"));
            assert!(
                (tk * k - t).abs() <= 1e-4 * t.max(scale),
                "t {tk} · {k} != {t} for {o} {d}"
            );
            // Relative to |p| too: a nearly parallel ray meets an infinite plane far away.
            let tol = 1e-4 * (scale + p.length());
            assert_close(shape.hit(o, d * k, tk).p, p, tol, "scaled hit point");
        }
    }
    assert!(hits > 20, "too few hits ({hits})");
}

/// Samples are on the surface (`distance` below `tol · scale`), with pdf 1/area, a unit normal
/// that agrees with the normal a ray finds there, and a mean point and mean normal as expected.
pub fn check_sampling(
    shape: &Analytic,
    distance: &dyn Fn(Vec3A) -> f32,
    scale: f32,
    mean_p: Vec3A,
    mean_n: Vec3A,
) {
    let n = 64;
    let area = shape.area();
    let (mut sum_p, mut sum_n) = (Vec3A::ZERO, Vec3A::ZERO);
    for i in 0..n {
        for j in 0..n {
            let u = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
            let s = shape.sample(u).expect("sample");
            assert!(
                distance(s.p) <= 1e-5 * scale,
                "sample {} off the surface",
                s.p
            );
            assert!((s.pdf_area * area - 1.0).abs() < 1e-4, "pdf {}", s.pdf_area);
            assert!((s.n.length() - 1.0).abs() < 1e-4);
            // A ray shot at the sample from its front side finds it, with the same normal.
            let o = s.p + s.n * (0.01 * scale);
            let t = shape
                .intersect(o, -s.n, 0.0, f32::INFINITY)
                .unwrap_or_else(|| panic!("ray towards sample {} missed", s.p));
            let h = shape.hit(o, -s.n, t);
            assert_close(h.p, s.p, 1e-4 * scale, "ray at sample");
            assert_close(h.n, s.n, 1e-3, "normal at sample");
            sum_p += s.p;
            sum_n += s.n;
        }
    }
    let count = (n * n) as f32;
    assert_close(sum_p / count, mean_p, 1e-2 * scale, "mean sample point");
    assert_close(sum_n / count, mean_n, 1e-2, "mean sample normal");
}

/// Non-finite inputs never panic, and NaN never produces a hit.
pub fn check_bad_inputs(shape: &Analytic, o: Vec3A, d: Vec3A) {
    assert!(
        shape.intersect(o, d, 0.0, f32::INFINITY).is_some(),
        "base ray must hit"
    );
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        for k in 0..6 {
            let (mut o2, mut d2) = (o, d);
            if k < 3 {
                o2[k] = bad;
            } else {
                d2[k - 3] = bad;
            }
            let r = shape.intersect(o2, d2, 0.0, f32::INFINITY);
            if bad.is_nan() {
                assert_eq!(r, None, "NaN in component {k} gave a hit");
            }
            if let Some(t) = r {
                let _ = shape.hit(o2, d2, t);
            }
        }
        assert_eq!(shape.intersect(o, d, f32::NAN, f32::INFINITY), None);
        assert_eq!(shape.intersect(o, d, 0.0, f32::NAN), None);
        let _ = shape.intersect(o, d, bad, bad);
        let _ = shape.hit(o, d, bad);
        let _ = shape.sample(Vec2::splat(bad));
        let _ = shape.sample(Vec2::new(bad, 0.5));
    }
    assert_eq!(shape.intersect(o, Vec3A::ZERO, 0.0, f32::INFINITY), None);
    let _ = shape.sample(Vec2::ONE);
    let _ = shape.sample(Vec2::ZERO);
}

#[cfg(test)]
mod tests {
    use super::super::{aabox, plane, polygon, quadric, sphere};
    use super::*;

    fn every_shape() -> Vec<Analytic> {
        vec![
            Analytic::Sphere(sphere::Sphere {
                center: Vec3A::new(0.5, -1.0, 2.0),
                radius: 1.5,
            }),
            Analytic::AaBox(aabox::AaBox {
                min: Vec3A::new(-1.0, 0.0, -2.0),
                max: Vec3A::new(1.0, 0.5, 3.0),
            }),
            Analytic::Plane(plane::Plane {
                point: Vec3A::new(0.0, 1.0, 0.0),
                normal: Vec3A::new(0.0, 0.6, 0.8),
            }),
            Analytic::Disk(plane::Disk {
                center: Vec3A::ZERO,
                normal: Vec3A::X,
                radius: 2.0,
            }),
            Analytic::Rectangle(plane::Rectangle {
                corner: Vec3A::ZERO,
                edge_u: Vec3A::X,
                edge_v: Vec3A::new(0.0, 1.0, 1.0),
            }),
            Analytic::Polygon(
                polygon::Polygon::new(vec![
                    Vec3A::ZERO,
                    Vec3A::new(2.0, 0.0, 0.0),
                    Vec3A::new(1.0, 1.0, 0.0),
                    Vec3A::new(0.0, 2.0, 0.0),
                ])
                .unwrap(),
            ),
            Analytic::Quadric(quadric::Quadric::cone(0.5, -2.0, 2.0).unwrap()),
            Analytic::Quadric(quadric::Quadric::paraboloid(1.0, 2.0).unwrap()),
        ]
    }

    /// Extreme finite inputs (zeros of both signs, subnormals, huge values) never panic, and
    /// any reported hit lies in the requested interval.
    #[test]
    fn extreme_finite_inputs_never_panic() {
        let values = [
            0.0,
            -0.0,
            1e-45,
            -1e-40,
            1e-20,
            1.0,
            -1.0,
            3.0,
            1e20,
            -1e30,
            f32::MAX,
            f32::MIN,
        ];
        let mut rng = Rng::new(99);
        for shape in every_shape() {
            for _ in 0..20_000 {
                let mut pick = || values[(rng.f32() * values.len() as f32) as usize];
                let o = Vec3A::new(pick(), pick(), pick());
                let d = Vec3A::new(pick(), pick(), pick());
                let (tmin, tmax) = if rng.f32() < 0.5 {
                    (0.0, f32::INFINITY)
                } else {
                    (1e-3, 10.0)
                };
                if let Some(t) = shape.intersect(o, d, tmin, tmax) {
                    assert!(t > tmin && t < tmax, "{shape:?} {o} {d}: t = {t}");
                    let _ = shape.hit(o, d, t);
                }
            }
            let _ = shape.bounds();
            let _ = shape.area();
        }
    }
}
