//! Planar polygons, convex or concave.

use super::plane::{plane_t, project_to_plane};
use super::{Aabb, LocalHit, ShapeSample};
use crate::sampling::warp::uniform_triangle;
use glam::{Vec2, Vec3A};

/// How far (relative to the polygon's size: the largest distance of a vertex from the
/// centroid) a vertex may lie off the polygon's plane.
pub const COPLANAR_TOLERANCE: f32 = 1e-4;

/// The most vertices a polygon may have ([`Polygon::new`]).
pub const MAX_VERTICES: usize = 1024;

/// A simple planar polygon (convex or concave, edges must not cross), vertices in order.
///
/// The front normal comes from Newell's method, so the front is the side from which the
/// vertices run counter-clockwise. Inside/outside is decided by the even-odd rule after
/// projecting onto the coordinate plane the normal is most aligned with.
///
/// uv: planar coordinates in object units, in the frame with origin at the first vertex,
/// u axis along the first edge of non-zero length and v axis = normal × u axis; ∂p/∂u is the
/// unit u axis.
#[derive(Clone, Debug, PartialEq)]
pub struct Polygon {
    /// The vertices as given.
    vertices: Vec<Vec3A>,
    /// The vertices moved onto the fitted plane along the projection axis (the shape whose
    /// surface rays hit; equal to `vertices` for exactly planar input).
    lifted: Vec<Vec3A>,
    /// Unit front normal (Newell).
    normal: Vec3A,
    /// Mean of the vertices, a point on the plane.
    centroid: Vec3A,
    /// Axis dropped by the 2D projection (the normal's largest component).
    axis: usize,
    /// Vertices projected to 2D: coordinates (axis + 1) % 3 and (axis + 2) % 3.
    flat: Vec<Vec2>,
    /// 2D bounds of `flat`, for a quick reject.
    flat_min: Vec2,
    /// See `flat_min`.
    flat_max: Vec2,
    /// Area, from Newell's method.
    area: f32,
    /// Triangulation (ear clipping) as indices into `lifted`, for sampling.
    triangles: Vec<[u32; 3]>,
    /// Cumulative triangle areas, divided by their sum (the last entry is 1).
    cdf: Vec<f32>,
    /// uv frame origin.
    uv_origin: Vec3A,
    /// uv frame u axis (unit).
    uv_u: Vec3A,
    /// uv frame v axis (unit).
    uv_v: Vec3A,
}

impl Polygon {
    /// Bytes held by the vertex, projection and triangulation tables.
    pub fn memory_bytes(&self) -> usize {
        use std::mem::size_of;
        (self.vertices.capacity() + self.lifted.capacity()) * size_of::<Vec3A>()
            + self.flat.capacity() * size_of::<Vec2>()
            + self.triangles.capacity() * size_of::<[u32; 3]>()
            + self.cdf.capacity() * size_of::<f32>()
    }

    /// Checks the vertices and precomputes the plane, the projection and a triangulation.
    ///
    /// Errors: fewer than three vertices, a non-finite vertex, (nearly) zero area, a vertex
    /// further than [`COPLANAR_TOLERANCE`] × size from the plane, or edges that cross.
    pub fn new(vertices: Vec<Vec3A>) -> Result<Self, String> {
        let count = vertices.len();
        if count < 3 {
            return Err(format!("a polygon needs at least 3 vertices, got {count}"));
        }
        // Ear clipping takes time quadratic (cubic for some concave shapes) in the vertex
        // count, and a ray's inside test is linear in it: many vertices belong in a `mesh`.
        if count > MAX_VERTICES {
            return Err(format!(
                "a polygon may have at most {MAX_VERTICES} vertices, got {count} (make a \
                 larger outline a `mesh` of triangles)"
            ));
        }
        if let Some(i) = vertices.iter().position(|v| !v.is_finite()) {
            return Err(format!("polygon vertex {i} is not finite: {}", vertices[i]));
        }
        let centroid = vertices.iter().copied().sum::<Vec3A>() / count as f32;
        // Newell's method: the sum of edge cross products is twice the area times the normal,
        // for concave polygons too. Relative to the centroid to keep the precision.
        let mut newell = Vec3A::ZERO;
        for i in 0..count {
            let (a, b) = (vertices[i] - centroid, vertices[(i + 1) % count] - centroid);
            newell += a.cross(b);
        }
        let size = vertices
            .iter()
            .map(|v| (*v - centroid).length())
            .fold(0.0f32, f32::max);
        let twice_area = newell.length();
        if !(size.is_finite() && twice_area.is_finite()) {
            return Err(format!(
                "polygon is too large: its size or area overflows 32-bit floats (vertices up \
                 to {size} from their centre)"
            ));
        }
        let has_area = twice_area.is_finite() && twice_area > 1e-6 * size * size;
        if !has_area {
            return Err(format!(
                "polygon is degenerate: its area {} is (nearly) zero for its size {size} \
                 (collinear or repeated vertices, or a figure-eight)",
                0.5 * twice_area
            ));
        }
        let normal = newell / twice_area;
        let tolerance = COPLANAR_TOLERANCE * size;
        for (i, v) in vertices.iter().enumerate() {
            let off = normal.dot(*v - centroid);
            if off.abs() > tolerance {
                return Err(format!(
                    "polygon vertex {i} {v} is {} off the plane of the others (tolerance \
                     {tolerance}): polygon vertices must be coplanar",
                    off.abs()
                ));
            }
        }
        let axis = normal.abs().max_position();
        let (ax, bx) = ((axis + 1) % 3, (axis + 2) % 3);
        let flat: Vec<Vec2> = vertices.iter().map(|v| Vec2::new(v[ax], v[bx])).collect();
        let lifted: Vec<Vec3A> = vertices
            .iter()
            .map(|v| {
                let mut w = *v;
                let rest = normal[ax] * v[ax] + normal[bx] * v[bx];
                w[axis] = (normal.dot(centroid) - rest) / normal[axis];
                w
            })
            .collect();
        let (flat_min, flat_max) = flat
            .iter()
            .fold((Vec2::INFINITY, Vec2::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        // Seen from the front, the projection runs counter-clockwise iff the normal's
        // dominant component is positive (e_a × e_b = e_axis).
        let orientation = normal[axis].signum();
        let triangles = triangulate(&flat, orientation)?;
        let mut cdf = Vec::with_capacity(triangles.len());
        let mut total = 0.0f32;
        for t in &triangles {
            let [a, b, c] = t.map(|i| lifted[i as usize]);
            total += 0.5 * (b - a).cross(c - a).length();
            cdf.push(total);
        }
        let area = 0.5 * twice_area;
        let consistent = (total - area).abs() <= 1e-3 * area;
        if !consistent {
            return Err(format!(
                "polygon is not simple: its edges cross (triangulated area {total} differs \
                 from its area {area})"
            ));
        }
        for c in &mut cdf {
            *c /= total;
        }
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        let uv_origin = lifted[0];
        let uv_u = lifted
            .iter()
            .skip(1)
            .find_map(|v| (*v - uv_origin).try_normalize())
            .map(|u| (u - normal * normal.dot(u)).normalize_or(u))
            .unwrap_or(crate::sampling::warp::Frame::from_z(normal).x);
        let uv_v = normal.cross(uv_u);
        Ok(Self {
            vertices,
            lifted,
            normal,
            centroid,
            axis,
            flat,
            flat_min,
            flat_max,
            area,
            triangles,
            cdf,
            uv_origin,
            uv_u,
            uv_v,
        })
    }

    /// The vertices as given.
    pub fn vertices(&self) -> &[Vec3A] {
        &self.vertices
    }

    /// The unit front normal.
    pub fn normal(&self) -> Vec3A {
        self.normal
    }

    /// Even-odd (crossing number) test of a projected point.
    #[inline]
    fn contains(&self, q: Vec2) -> bool {
        if !(q.cmpge(self.flat_min).all() && q.cmple(self.flat_max).all()) {
            return false;
        }
        let mut inside = false;
        let mut j = self.flat.len() - 1;
        for (i, &a) in self.flat.iter().enumerate() {
            let b = self.flat[j];
            // Half-open in y, so a vertex on the test line is counted once.
            if (a.y > q.y) != (b.y > q.y) {
                let x = a.x + (q.y - a.y) * (b.x - a.x) / (b.y - a.y);
                if q.x < x {
                    inside = !inside;
                }
            }
            j = i;
        }
        inside
    }

    /// Object-space bounds (of the vertices on the fitted plane).
    pub fn bounds(&self) -> Option<Aabb> {
        let (lo, hi) = self
            .lifted
            .iter()
            .fold((Vec3A::INFINITY, Vec3A::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        Some(Aabb::new(lo, hi))
    }

    /// Nearest hit in (tmin, tmax); `d` need not be unit.
    #[inline]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<f32> {
        let t = plane_t(self.normal, self.centroid, o, d, tmin, tmax)?;
        let p = o + d * t;
        let q = Vec2::new(p[(self.axis + 1) % 3], p[(self.axis + 2) % 3]);
        self.contains(q).then_some(t)
    }

    /// Surface details at parameter `t`.
    #[inline]
    pub fn hit(&self, o: Vec3A, d: Vec3A, t: f32) -> LocalHit {
        let p = project_to_plane(o + d * t, self.normal, self.centroid);
        let rel = p - self.uv_origin;
        LocalHit {
            p,
            n: self.normal,
            uv: Vec2::new(rel.dot(self.uv_u), rel.dot(self.uv_v)),
            dpdu: self.uv_u,
        }
    }

    /// Surface area (Newell's method).
    pub fn area(&self) -> f32 {
        self.area
    }

    /// Uniform point by area: `u.x` picks a triangle of the triangulation through the area
    /// CDF and is rescaled to pick, with `u.y`, a uniform point in it.
    pub fn sample(&self, u: Vec2) -> Option<ShapeSample> {
        let last = self.cdf.len().checked_sub(1)?;
        let x = u.x.clamp(0.0, 1.0);
        let i = self.cdf.partition_point(|&c| c <= x).min(last);
        let lo = if i == 0 { 0.0 } else { self.cdf[i - 1] };
        let hi = self.cdf[i];
        let x = if hi > lo {
            ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
        } else {
            0.5
        };
        let (b0, b1) = uniform_triangle(Vec2::new(x, u.y.clamp(0.0, 1.0)));
        let [a, b, c] = self.triangles[i].map(|k| self.lifted[k as usize]);
        let p = a * b0 + b * b1 + c * (1.0 - b0 - b1);
        Some(ShapeSample {
            p: project_to_plane(p, self.normal, self.centroid),
            n: self.normal,
            pdf_area: 1.0 / self.area,
        })
    }
}

/// Ear clipping of a simple 2D polygon; `orientation` is +1 for counter-clockwise input and −1
/// for clockwise. Corners of (nearly) zero area, such as collinear vertices, are dropped
/// without a triangle. Fails if no ear can be found, which means the edges cross.
fn triangulate(flat: &[Vec2], orientation: f32) -> Result<Vec<[u32; 3]>, String> {
    let size2 = {
        let (lo, hi) = flat
            .iter()
            .fold((Vec2::INFINITY, Vec2::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        (hi - lo).length_squared()
    };
    let flat_eps = 1e-7 * size2;
    let cross = |a: Vec2, b: Vec2, c: Vec2| (b - a).perp_dot(c - a) * orientation;
    let inside = |p: Vec2, a: Vec2, b: Vec2, c: Vec2| {
        cross(a, b, p) >= 0.0 && cross(b, c, p) >= 0.0 && cross(c, a, p) >= 0.0
    };
    let mut idx: Vec<u32> = (0..flat.len() as u32).collect();
    let mut tris = Vec::with_capacity(flat.len() - 2);
    while idx.len() >= 3 {
        let m = idx.len();
        let corner = |i: usize| (idx[(i + m - 1) % m], idx[i], idx[(i + 1) % m]);
        let ear = (0..m).find(|&i| {
            let (ia, ib, ic) = corner(i);
            let (a, b, c) = (flat[ia as usize], flat[ib as usize], flat[ic as usize]);
            if m == 3 {
                return true;
            }
            cross(a, b, c) > flat_eps
                && !idx.iter().any(|&j| {
                    let p = flat[j as usize];
                    j != ia
                        && j != ib
                        && j != ic
                        && p != a
                        && p != b
                        && p != c
                        && inside(p, a, b, c)
                })
        });
        let i = match ear {
            Some(i) => i,
            None => {
                // Only degenerate corners (collinear, or spikes) may go without an ear.
                let (i, area) = (0..m)
                    .map(|i| {
                        let (ia, ib, ic) = corner(i);
                        let c = cross(flat[ia as usize], flat[ib as usize], flat[ic as usize]);
                        (i, c.abs())
                    })
                    .fold(
                        (0, f32::INFINITY),
                        |best, x| if x.1 < best.1 { x } else { best },
                    );
                if area > flat_eps {
                    return Err("polygon is not simple: its edges cross".to_string());
                }
                idx.remove(i);
                continue;
            }
        };
        let (ia, ib, ic) = corner(i);
        if cross(flat[ia as usize], flat[ib as usize], flat[ic as usize]) > 0.0 {
            tris.push([ia, ib, ic]);
        }
        idx.remove(i);
    }
    if tris.is_empty() {
        return Err("polygon is degenerate: no triangle of non-zero area".to_string());
    }
    Ok(tris)
}

#[cfg(test)]
mod tests {
    use super::super::testutil::*;
    use super::super::Analytic;
    use super::*;
    use glam::Mat3A;

    fn l_shape() -> Vec<Vec2> {
        [
            (0.0, 0.0),
            (3.0, 0.0),
            (3.0, 1.0),
            (1.0, 1.0),
            (1.0, 2.5),
            (0.0, 2.5),
        ]
        .map(|(x, y)| Vec2::new(x, y))
        .to_vec()
    }

    fn star() -> Vec<Vec2> {
        (0..10)
            .map(|i| {
                let a = i as f32 * std::f32::consts::PI / 5.0 + 0.1;
                let r = if i % 2 == 0 { 2.0 } else { 0.8 };
                Vec2::new(a.cos(), a.sin()) * r
            })
            .collect()
    }

    /// A comb: three teeth, many reflex corners and a collinear vertex on the base.
    fn comb() -> Vec<Vec2> {
        [
            (0.0, 0.0),
            (2.5, 0.0),
            (5.0, 0.0),
            (5.0, 3.0),
            (4.0, 3.0),
            (4.0, 1.0),
            (3.0, 1.0),
            (3.0, 3.0),
            (2.0, 3.0),
            (2.0, 1.0),
            (1.0, 1.0),
            (1.0, 3.0),
            (0.0, 3.0),
        ]
        .map(|(x, y)| Vec2::new(x, y))
        .to_vec()
    }

    /// A rotation and offset that put the xy plane somewhere awkward.
    fn placement() -> (Mat3A, Vec3A) {
        let r = Mat3A::from_axis_angle(Vec3A::new(0.4, -1.0, 0.3).normalize().into(), 1.1);
        (r, Vec3A::new(5.0, -3.0, 2.0))
    }

    fn place(poly: &[Vec2]) -> Vec<Vec3A> {
        let (r, off) = placement();
        poly.iter()
            .map(|p| r * Vec3A::new(p.x, p.y, 0.0) + off)
            .collect()
    }

    /// Reference classification: the winding number from summed angles (a different algorithm
    /// from the crossing count; equal to the even-odd rule for simple polygons).
    fn winding(poly: &[Vec2], q: Vec2) -> i32 {
        let mut total = 0.0f64;
        for i in 0..poly.len() {
            let a = (poly[i] - q).as_dvec2();
            let b = (poly[(i + 1) % poly.len()] - q).as_dvec2();
            total += a.perp_dot(b).atan2(a.dot(b));
        }
        (total / std::f64::consts::TAU).round() as i32
    }

    fn segment_distance(p: Vec2, a: Vec2, b: Vec2) -> f32 {
        let ab = b - a;
        let s = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
        (p - a - ab * s).length()
    }

    /// Distance of a point from the polygon surface (plane, then outline if outside).
    fn distance(poly: &Polygon) -> impl Fn(Vec3A) -> f32 + '_ {
        move |p| {
            let h = poly.normal.dot(p - poly.centroid);
            let q = p - poly.normal * h;
            let (ax, bx) = ((poly.axis + 1) % 3, (poly.axis + 2) % 3);
            if poly.contains(Vec2::new(q[ax], q[bx])) {
                return h.abs();
            }
            let n = poly.lifted.len();
            let edge = (0..n)
                .map(|i| {
                    let (a, b) = (poly.lifted[i], poly.lifted[(i + 1) % n]);
                    let s = ((q - a).dot(b - a) / (b - a).length_squared()).clamp(0.0, 1.0);
                    (q - a - (b - a) * s).length()
                })
                .fold(f32::INFINITY, f32::min);
            (h * h + edge * edge).sqrt()
        }
    }

    /// Area-weighted centroid of a simple 2D polygon.
    fn area_centroid(poly: &[Vec2]) -> Vec2 {
        let (mut a, mut c) = (0.0, Vec2::ZERO);
        for i in 0..poly.len() {
            let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
            let w = p.perp_dot(q);
            a += w;
            c += (p + q) * w;
        }
        c / (3.0 * a)
    }

    #[test]
    fn head_on_square() {
        let sq =
            [(0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (0.0, 1.0)].map(|(x, y)| Vec3A::new(x, y, 2.0));
        let poly = Polygon::new(sq.to_vec()).unwrap();
        assert_eq!(poly.normal(), Vec3A::Z);
        assert_eq!(poly.area(), 2.0);
        let (o, d) = (Vec3A::new(1.0, 0.5, 5.0), -Vec3A::Z * 0.5);
        let t = poly.intersect(o, d, 0.0, f32::INFINITY).unwrap();
        assert_eq!(t, 6.0);
        let h = poly.hit(o, d, t);
        assert_close(h.p, Vec3A::new(1.0, 0.5, 2.0), 1e-6, "point");
        assert_eq!(h.n, Vec3A::Z);
        // uv frame: origin at vertex 0, u along the first edge (+X), v = n × u = +Y.
        assert!((h.uv - Vec2::new(1.0, 0.5)).length() < 1e-6, "uv {}", h.uv);
        assert_eq!(h.dpdu, Vec3A::X);
        // From behind: same front normal.
        let t = poly
            .intersect(Vec3A::new(1.0, 0.5, 0.0), Vec3A::Z, 0.0, 10.0)
            .unwrap();
        assert_eq!(poly.hit(Vec3A::new(1.0, 0.5, 0.0), Vec3A::Z, t).n, Vec3A::Z);
        // Misses: beside, parallel, away.
        assert_eq!(
            poly.intersect(Vec3A::new(2.5, 0.5, 5.0), -Vec3A::Z, 0.0, 10.0),
            None
        );
        assert_eq!(
            poly.intersect(Vec3A::new(-1.0, 0.5, 2.0), Vec3A::X, 0.0, 10.0),
            None
        );
        assert_eq!(
            poly.intersect(Vec3A::new(1.0, 0.5, 5.0), Vec3A::Z, 0.0, 10.0),
            None
        );
        // A repeated closing vertex (and a collinear one) changes nothing.
        let mut closed = sq.to_vec();
        closed.insert(1, Vec3A::new(1.0, 0.0, 2.0));
        closed.push(sq[0]);
        let same = Polygon::new(closed).unwrap();
        assert_eq!(same.area(), 2.0);
        assert_eq!(same.normal(), Vec3A::Z);
        assert_eq!(same.intersect(o, d, 0.0, f32::INFINITY), Some(6.0));
        assert_eq!(
            same.intersect(Vec3A::new(2.5, 0.5, 5.0), -Vec3A::Z, 0.0, 10.0),
            None
        );
        assert!(same.sample(Vec2::splat(0.3)).is_some());
        // Clockwise order flips the front.
        let mut cw = sq.to_vec();
        cw.reverse();
        assert_eq!(Polygon::new(cw).unwrap().normal(), -Vec3A::Z);
    }

    #[test]
    fn inside_outside_matches_reference() {
        let mut rng = Rng::new(40);
        for (name, shape) in [("L", l_shape()), ("star", star()), ("comb", comb())] {
            for placed in [false, true] {
                let verts: Vec<Vec3A> = if placed {
                    place(&shape)
                } else {
                    shape.iter().map(|p| Vec3A::new(p.x, p.y, 0.0)).collect()
                };
                let poly = Polygon::new(verts).unwrap();
                let (r, off) = if placed {
                    placement()
                } else {
                    (Mat3A::IDENTITY, Vec3A::ZERO)
                };
                let n = r * Vec3A::Z;
                assert_close(poly.normal(), n, 1e-5, "normal");
                let (lo, hi) = shape
                    .iter()
                    .fold((Vec2::INFINITY, Vec2::NEG_INFINITY), |(lo, hi), p| {
                        (lo.min(*p), hi.max(*p))
                    });
                let (mut inside, mut total) = (0, 0);
                let g = 60;
                for i in 0..=g {
                    for j in 0..=g {
                        let q = Vec2::new(
                            lo.x - 0.3 + (hi.x - lo.x + 0.6) * (i as f32 + 0.37) / g as f32,
                            lo.y - 0.3 + (hi.y - lo.y + 0.6) * (j as f32 + 0.61) / g as f32,
                        );
                        let near_edge = (0..shape.len()).any(|k| {
                            segment_distance(q, shape[k], shape[(k + 1) % shape.len()]) < 1e-3
                        });
                        if near_edge {
                            continue;
                        }
                        let expected = winding(&shape, q) % 2 != 0;
                        let p = r * Vec3A::new(q.x, q.y, 0.0) + off;
                        // From either side, with an arbitrary non-unit slanted direction.
                        let d = -(n + r * (rng.unit() * 0.3)) * rng.range(0.5, 2.0);
                        let sign = if rng.f32() < 0.5 { 1.0 } else { -1.0 };
                        let o = p - d * sign * 1.5;
                        let d = d * sign;
                        let got = poly.intersect(o, d, 0.0, f32::INFINITY);
                        assert_eq!(got.is_some(), expected, "{name} placed={placed} at {q}");
                        if let Some(t) = got {
                            assert_close(poly.hit(o, d, t).p, p, 1e-4, "hit point");
                            inside += 1;
                        }
                        total += 1;
                    }
                }
                assert!(
                    inside > total / 5 && inside < total,
                    "{name}: {inside}/{total}"
                );
            }
        }
    }

    #[test]
    fn degenerate_polygons_are_rejected() {
        let v = |x: f32, y: f32, z: f32| Vec3A::new(x, y, z);
        let cases: Vec<(Vec<Vec3A>, &str)> = vec![
            (vec![], "at least 3"),
            (vec![v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0)], "at least 3"),
            (
                vec![v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(2.0, 0.0, 0.0)],
                "degenerate",
            ),
            (vec![v(1.0, 1.0, 1.0); 4], "degenerate"),
            (
                vec![v(0.0, 0.0, 0.0), v(1.0, f32::NAN, 0.0), v(0.0, 1.0, 0.0)],
                "not finite",
            ),
            (
                vec![
                    v(0.0, 0.0, 0.0),
                    v(1.0, f32::INFINITY, 0.0),
                    v(0.0, 1.0, 0.0),
                ],
                "not finite",
            ),
            (
                vec![
                    v(0.0, 0.0, 0.0),
                    v(1.0, 0.0, 0.0),
                    v(1.0, 1.0, 0.1),
                    v(0.0, 1.0, 0.0),
                ],
                "coplanar",
            ),
            // A bow tie: the two lobes cancel in Newell's sum.
            (
                vec![
                    v(0.0, 0.0, 0.0),
                    v(1.0, 1.0, 0.0),
                    v(1.0, 0.0, 0.0),
                    v(0.0, 1.0, 0.0),
                ],
                "degenerate",
            ),
        ];
        for (verts, msg) in cases {
            let err = Polygon::new(verts.clone()).unwrap_err();
            assert!(err.contains(msg), "{verts:?}: {err}");
        }
        // A pentagram drawn as five crossing edges is not simple.
        let pentagram: Vec<Vec3A> = (0..5)
            .map(|i| {
                let a = (i * 2) as f32 * std::f32::consts::TAU / 5.0;
                v(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let err = Polygon::new(pentagram).unwrap_err();
        assert!(err.contains("not simple"), "{err}");
        // Within the tolerance is fine.
        let ok = vec![
            v(0.0, 0.0, 0.0),
            v(1.0, 0.0, 0.0),
            v(1.0, 1.0, 1e-5),
            v(0.0, 1.0, 0.0),
        ];
        assert!(Polygon::new(ok).is_ok());
        // A circle of the most vertices a polygon takes, and one vertex more.
        let circle = |n: usize| -> Vec<Vec3A> {
            (0..n)
                .map(|i| {
                    let a = i as f32 * std::f32::consts::TAU / n as f32;
                    v(a.cos(), a.sin(), 0.0)
                })
                .collect()
        };
        let p = Polygon::new(circle(MAX_VERTICES)).unwrap();
        assert!(
            p.triangles.len() > MAX_VERTICES / 2,
            "{}",
            p.triangles.len()
        );
        let err = Polygon::new(circle(MAX_VERTICES + 1)).unwrap_err();
        assert!(err.contains("at most 1024 vertices"), "{err}");
    }

    #[test]
    fn properties_of_a_placed_star() {
        let poly = Polygon::new(place(&star())).unwrap();
        let b = poly.bounds().unwrap();
        let (lo, hi) = (b.min, b.max);
        let dist = distance(&poly);
        let s = Analytic::Polygon(poly.clone());
        check_no_self_hit(&s, lo, hi, Leave::Never, Some(Leave::Never), 41);
        check_grazing(&s, lo, hi, &dist, 1e-5, 42);
        check_direction_scale(&s, lo, hi, 43);
        check_bad_inputs(&s, poly.centroid + poly.normal, -poly.normal);
    }

    #[test]
    fn sampling_is_uniform_by_area() {
        let (r, off) = placement();
        for shape in [l_shape(), star(), comb()] {
            let poly = Polygon::new(place(&shape)).unwrap();
            // Shoelace area of the 2D outline (placement is a rotation).
            let c = area_centroid(&shape);
            let area2d = 0.5
                * (0..shape.len())
                    .map(|i| shape[i].perp_dot(shape[(i + 1) % shape.len()]))
                    .sum::<f32>();
            assert!((poly.area() - area2d).abs() < 1e-4 * area2d);
            let b = poly.bounds().unwrap();
            let scale = (b.max - b.min).length();
            let mean = r * Vec3A::new(c.x, c.y, 0.0) + off;
            let s = Analytic::Polygon(poly.clone());
            check_sampling(&s, &distance(&poly), scale, mean, poly.normal);
        }
    }
}
