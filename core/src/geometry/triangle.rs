//! Triangle meshes: storage in object space and the ray–triangle test.

use glam::{Vec2, Vec3A};

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
    /// Triangles.
    pub indices: Vec<[u32; 3]>,
}

impl Mesh {
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
    #[inline(always)]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
        let p = d.cross(self.e2);
        let det = self.e1.dot(p);
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let inv = 1.0 / det;
        let s = o - self.v0;
        let b1 = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&b1) {
            return None;
        }
        let q = s.cross(self.e1);
        let b2 = d.dot(q) * inv;
        if b2 < 0.0 || b1 + b2 > 1.0 {
            return None;
        }
        let t = self.e2.dot(q) * inv;
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
}
