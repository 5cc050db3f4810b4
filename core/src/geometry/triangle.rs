//! Triangle meshes: storage in object space and the ray–triangle test.

use glam::{Vec2, Vec3A, Vec4};

/// A mesh ready for rendering, in object space. Shared by every object that instances it.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Name for messages.
    pub name: String,
    /// Vertex positions.
    pub positions: Vec<Vec3A>,
    /// Per-vertex shading normals (empty: flat shading).
    pub normals: Vec<Vec3A>,
    /// Per-vertex tangents with handedness in w (empty: derived from uvs or arbitrary).
    pub tangents: Vec<[f32; 4]>,
    /// Texture coordinate sets 0 and 1 (each empty or one per vertex).
    pub uvs: [Vec<Vec2>; 2],
    /// Vertex colours multiplying the base colour (empty or one per vertex).
    pub colors: Vec<Vec3A>,
    /// Triangles.
    pub indices: Vec<[u32; 3]>,
}

impl Mesh {
    /// Texture coordinates (sets 0 and 1) at barycentrics (b1, b2) of triangle `tri`; a set
    /// the mesh lacks gives (b1, b2) themselves.
    #[inline]
    pub fn uvs_at(&self, tri: u32, b1: f32, b2: f32) -> [Vec2; 2] {
        let [a, b, c] = self.indices[tri as usize];
        let b0 = 1.0 - b1 - b2;
        let get = |set: &Vec<Vec2>| {
            if set.is_empty() {
                Vec2::new(b1, b2)
            } else {
                set[a as usize] * b0 + set[b as usize] * b1 + set[c as usize] * b2
            }
        };
        [get(&self.uvs[0]), get(&self.uvs[1])]
    }

    /// The vertex colour at barycentrics (b1, b2) of triangle `tri`; white for a mesh without
    /// vertex colours.
    #[inline]
    pub fn color_at(&self, tri: u32, b1: f32, b2: f32) -> Vec3A {
        if self.colors.is_empty() {
            return Vec3A::ONE;
        }
        let [a, b, c] = self.indices[tri as usize];
        self.colors[a as usize] * (1.0 - b1 - b2)
            + self.colors[b as usize] * b1
            + self.colors[c as usize] * b2
    }

    /// The three corners of triangle `i`.
    #[inline]
    pub fn corners(&self, i: usize) -> [Vec3A; 3] {
        let [a, b, c] = self.indices[i];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }
}

/// A triangle stored for intersection: one vertex and two edges (Möller–Trumbore's form).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleGeom {
    /// First vertex.
    pub v0: Vec3A,
    /// v1 − v0.
    pub e1: Vec3A,
    /// v2 − v0.
    pub e2: Vec3A,
}

impl TriangleGeom {
    /// From three corners.
    #[inline]
    pub fn new([v0, v1, v2]: [Vec3A; 3]) -> Self {
        Self {
            v0,
            e1: v1 - v0,
            e2: v2 - v0,
        }
    }

    /// Möller–Trumbore: the hit parameter and barycentrics (b1, b2) of v1 and v2, if the ray
    /// hits within (tmin, tmax). Edges are inclusive so rays through a shared edge hit one of
    /// its two triangles. `d` need not be unit length.
    ///
    /// Written out per component in a fixed order, the same operations as one lane of
    /// [`Tri4::intersect`], so the scalar and the 4-wide test agree to the bit.
    #[inline(always)]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
        let (e1, e2) = (self.e1, self.e2);
        let p = Vec3A::new(
            d.y * e2.z - d.z * e2.y,
            d.z * e2.x - d.x * e2.z,
            d.x * e2.y - d.y * e2.x,
        );
        let det = e1.x * p.x + e1.y * p.y + e1.z * p.z;
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let inv = 1.0 / det;
        let s = Vec3A::new(o.x - self.v0.x, o.y - self.v0.y, o.z - self.v0.z);
        let b1 = (s.x * p.x + s.y * p.y + s.z * p.z) * inv;
        if !(0.0..=1.0).contains(&b1) {
            return None;
        }
        let q = Vec3A::new(
            s.y * e1.z - s.z * e1.y,
            s.z * e1.x - s.x * e1.z,
            s.x * e1.y - s.y * e1.x,
        );
        let b2 = (d.x * q.x + d.y * q.y + d.z * q.z) * inv;
        if !(b2 >= 0.0) || !(b1 + b2 <= 1.0) {
            return None;
        }
        let t = (e2.x * q.x + e2.y * q.y + e2.z * q.z) * inv;
        (t > tmin && t < tmax).then_some((t, b1, b2))
    }

    /// The point at barycentrics (b1, b2), computed from the vertices (not from o + t·d) so it
    /// lies on the triangle as closely as f32 allows.
    #[inline]
    pub fn point(&self, b1: f32, b2: f32) -> Vec3A {
        self.v0 + self.e1 * b1 + self.e2 * b2
    }

    /// Unnormalised geometric normal (e1 × e2: the counter-clockwise side).
    #[inline]
    pub fn normal(&self) -> Vec3A {
        self.e1.cross(self.e2)
    }
}

/// Four triangles stored lane by lane (structure of arrays) and tested against one ray with
/// one SIMD Möller–Trumbore (Embree's "triangle4" layout). Unused lanes hold degenerate
/// triangles, which nothing hits.
#[derive(Clone, Copy, Debug)]
pub struct Tri4 {
    v0: [Vec4; 3],
    e1: [Vec4; 3],
    e2: [Vec4; 3],
}

impl Tri4 {
    /// Packs up to four triangles (lane i = `tris[i]`).
    pub fn new(tris: &[TriangleGeom]) -> Self {
        assert!(tris.len() <= 4, "a Tri4 holds at most four triangles");
        let mut t = Self {
            v0: [Vec4::ZERO; 3],
            e1: [Vec4::ZERO; 3],
            e2: [Vec4::ZERO; 3],
        };
        for (lane, g) in tris.iter().enumerate() {
            for axis in 0..3 {
                t.v0[axis][lane] = g.v0[axis];
                t.e1[axis][lane] = g.e1[axis];
                t.e2[axis][lane] = g.e2[axis];
            }
        }
        t
    }

    /// The nearest hit among the four within (tmin, tmax): (lane, t, b1, b2). Each lane
    /// computes exactly what [`TriangleGeom::intersect`] computes; among equal distances the
    /// lowest lane wins, as if the triangles were tested one after the other.
    #[inline(always)]
    pub fn intersect(
        &self,
        o: Vec3A,
        d: Vec3A,
        tmin: f32,
        tmax: f32,
    ) -> Option<(usize, f32, f32, f32)> {
        let (hits, t, b1, b2) = self.test(o, d, tmin, tmax);
        if hits == 0 {
            return None;
        }
        let (t, b1, b2) = (t.to_array(), b1.to_array(), b2.to_array());
        let mut best = hits.trailing_zeros() as usize;
        let mut rest = hits & (hits - 1);
        while rest != 0 {
            let lane = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            if t[lane] < t[best] {
                best = lane;
            }
        }
        Some((best, t[best], b1[best], b2[best]))
    }

    /// Whether any of the four is hit within (tmin, tmax).
    #[inline(always)]
    pub fn any(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> bool {
        self.test(o, d, tmin, tmax).0 != 0
    }

    /// The lanes hit, and every lane's t, b1, b2.
    #[inline(always)]
    fn test(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> (u32, Vec4, Vec4, Vec4) {
        let [e1x, e1y, e1z] = self.e1;
        let [e2x, e2y, e2z] = self.e2;
        let (dx, dy, dz) = (Vec4::splat(d.x), Vec4::splat(d.y), Vec4::splat(d.z));
        let px = dy * e2z - dz * e2y;
        let py = dz * e2x - dx * e2z;
        let pz = dx * e2y - dy * e2x;
        let det = e1x * px + e1y * py + e1z * pz;
        let inv = Vec4::ONE / det;
        let sx = Vec4::splat(o.x) - self.v0[0];
        let sy = Vec4::splat(o.y) - self.v0[1];
        let sz = Vec4::splat(o.z) - self.v0[2];
        let b1 = (sx * px + sy * py + sz * pz) * inv;
        let qx = sy * e1z - sz * e1y;
        let qy = sz * e1x - sx * e1z;
        let qz = sx * e1y - sy * e1x;
        let b2 = (dx * qx + dy * qy + dz * qz) * inv;
        let t = (e2x * qx + e2y * qy + e2z * qz) * inv;
        let ok = det.cmpne(Vec4::ZERO)
            & det.abs().cmplt(Vec4::INFINITY)
            & b1.cmpge(Vec4::ZERO)
            & b1.cmple(Vec4::ONE)
            & b2.cmpge(Vec4::ZERO)
            & (b1 + b2).cmple(Vec4::ONE)
            & t.cmpgt(Vec4::splat(tmin))
            & t.cmplt(Vec4::splat(tmax));
        (ok.bitmask(), t, b1, b2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri() -> TriangleGeom {
        TriangleGeom::new([Vec3A::ZERO, Vec3A::X, Vec3A::Y])
    }

    #[test]
    fn head_on_hit_reports_t_and_barycentrics() {
        let (t, b1, b2) = tri()
            .intersect(Vec3A::new(0.25, 0.5, 2.0), -Vec3A::Z, 0.0, f32::INFINITY)
            .unwrap();
        assert!((t - 2.0).abs() < 1e-6 && (b1 - 0.25).abs() < 1e-6 && (b2 - 0.5).abs() < 1e-6);
        assert!(tri().normal().z > 0.0, "counter-clockwise side is +Z");
    }

    #[test]
    fn misses_outside_and_behind_and_parallel() {
        let t = tri();
        assert!(t
            .intersect(Vec3A::new(0.8, 0.8, 1.0), -Vec3A::Z, 0.0, 10.0)
            .is_none());
        assert!(t
            .intersect(Vec3A::new(0.2, 0.2, 1.0), Vec3A::Z, 0.0, 10.0)
            .is_none());
        assert!(t
            .intersect(Vec3A::new(0.2, 0.2, 0.0), Vec3A::X, 0.0, 10.0)
            .is_none());
        assert!(t
            .intersect(Vec3A::new(0.2, 0.2, 1.0), -Vec3A::Z, 0.0, 0.5)
            .is_none());
        assert!(t.intersect(Vec3A::NAN, -Vec3A::Z, 0.0, 10.0).is_none());
    }

    #[test]
    fn shared_edge_is_watertight_for_a_grid_of_rays() {
        // Two triangles forming a quad: every ray through the quad hits exactly one or both
        // (on the diagonal), never neither.
        let a = TriangleGeom::new([Vec3A::ZERO, Vec3A::X, Vec3A::new(1.0, 1.0, 0.0)]);
        let b = TriangleGeom::new([Vec3A::ZERO, Vec3A::new(1.0, 1.0, 0.0), Vec3A::Y]);
        for i in 0..200 {
            let x = 0.0025 + i as f32 * 0.005;
            let o = Vec3A::new(x, x, 1.0);
            let d = Vec3A::new(0.0, 0.0, -1.0);
            let hit =
                a.intersect(o, d, 0.0, 9.0).is_some() || b.intersect(o, d, 0.0, 9.0).is_some();
            assert!(hit, "crack at {x}");
        }
    }

    /// Every lane of the 4-wide test returns what the scalar test returns, to the bit, and
    /// the nearest lane wins (the lowest among equals).
    #[test]
    fn tri4_matches_scalar_bit_for_bit() {
        use crate::sampling::hash_u32;
        let r = |i: u32| (hash_u32(i) >> 8) as f32 / (1 << 24) as f32 * 2.0 - 1.0;
        let v = |i: u32| Vec3A::new(r(3 * i), r(3 * i + 1), r(3 * i + 2));
        let mut hits = 0;
        for k in 0..2000u32 {
            let n = 1 + (k % 4) as usize;
            let mut tris: Vec<TriangleGeom> = (0..n as u32)
                .map(|j| {
                    TriangleGeom::new([
                        v(k * 97 + j * 7),
                        v(k * 97 + j * 7 + 1),
                        v(k * 97 + j * 7 + 2),
                    ])
                })
                .collect();
            if k % 5 == 0 {
                tris.push(tris[0]); // a duplicate: equal distances, the lower lane must win
                tris.truncate(4);
            }
            let packet = Tri4::new(&tris);
            // Aimed near the first triangle, so that many rays hit and some graze edges.
            let o = v(900_000 + k) * 2.0;
            let d = tris[0].point(0.3, 0.3) + v(800_000 + k) * 0.3 - o;
            let tmax = if k % 3 == 0 { 1.5 } else { f32::INFINITY };
            let mut want = None;
            let mut best = tmax;
            for (lane, t) in tris.iter().enumerate() {
                if let Some((th, b1, b2)) = t.intersect(o, d, 0.0, best) {
                    best = th;
                    want = Some((lane, th, b1, b2));
                }
            }
            let got = packet.intersect(o, d, 0.0, tmax);
            assert_eq!(
                got.map(|g| (g.0, g.1.to_bits(), g.2.to_bits(), g.3.to_bits())),
                want.map(|g| (g.0, g.1.to_bits(), g.2.to_bits(), g.3.to_bits())),
                "case {k}"
            );
            assert_eq!(packet.any(o, d, 0.0, tmax), want.is_some());
            hits += usize::from(want.is_some());
        }
        assert!(hits > 500, "too few hits to mean anything: {hits}");
    }
}
