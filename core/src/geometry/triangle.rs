//! Triangle meshes: storage in object space and the ray–triangle test.

use glam::{Vec2, Vec3A, Vec4};
use rayon::prelude::*;

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
        nearest_lane(test4(&self.v0, &self.e1, &self.e2, o, d, tmin, tmax))
    }

    /// Whether any of the four is hit within (tmin, tmax).
    #[inline(always)]
    pub fn any(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> bool {
        test4(&self.v0, &self.e1, &self.e2, o, d, tmin, tmax).0 != 0
    }
}

/// Of the lanes hit (a mask, and every lane's t, b1, b2), the nearest: the lowest lane among
/// equal distances.
#[inline(always)]
fn nearest_lane((hits, t, b1, b2): (u32, Vec4, Vec4, Vec4)) -> Option<(usize, f32, f32, f32)> {
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

/// One SIMD Möller–Trumbore of four triangles given lane by lane (v0, e1, e2 by axis): the
/// lanes hit within (tmin, tmax), and every lane's t, b1, b2. Each lane computes exactly what
/// [`TriangleGeom::intersect`] computes.
#[inline(always)]
fn test4(
    v0: &[Vec4; 3],
    e1: &[Vec4; 3],
    e2: &[Vec4; 3],
    o: Vec3A,
    d: Vec3A,
    tmin: f32,
    tmax: f32,
) -> (u32, Vec4, Vec4, Vec4) {
    let [e1x, e1y, e1z] = *e1;
    let [e2x, e2y, e2z] = *e2;
    let (dx, dy, dz) = (Vec4::splat(d.x), Vec4::splat(d.y), Vec4::splat(d.z));
    let px = dy * e2z - dz * e2y;
    let py = dz * e2x - dx * e2z;
    let pz = dx * e2y - dy * e2x;
    let det = e1x * px + e1y * py + e1z * pz;
    let inv = Vec4::ONE / det;
    let sx = Vec4::splat(o.x) - v0[0];
    let sy = Vec4::splat(o.y) - v0[1];
    let sz = Vec4::splat(o.z) - v0[2];
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

/// [`test4`] on eight lanes with AVX, for [`LeafTris::hits_pair`]: the same operations in
/// the same order, each exactly rounded, so every lane decides what [`test4`] decides.
#[cfg(target_arch = "x86_64")]
mod pair_avx2 {
    use glam::Vec3A;
    use std::arch::x86_64::*;

    /// The lanes hit: bits 0..4 from `a`'s first four slots, 4..8 from `b`'s (lanes past a
    /// leaf's count hold other values and must be masked off).
    ///
    /// # Safety
    /// The CPU must have AVX2; `a` and `b` hold at least `9 na + 3` and `9 nb + 3` floats.
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn hits8(
        a: &[f32],
        na: usize,
        b: &[f32],
        nb: usize,
        o: Vec3A,
        d: Vec3A,
        tmin: f32,
        tmax: f32,
    ) -> u32 {
        // SAFETY: the caller's promises are `test8`'s.
        let (ok, _, _, _) = unsafe { test8(a, na, b, nb, o, d, tmin, tmax) };
        _mm256_movemask_ps(ok) as u32
    }

    /// [`hits8`] with every lane's t, b1 and b2.
    ///
    /// # Safety
    /// As [`hits8`].
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn hits8_at(
        a: &[f32],
        na: usize,
        b: &[f32],
        nb: usize,
        o: Vec3A,
        d: Vec3A,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [[f32; 8]; 3]) {
        // SAFETY: the caller's promises are `test8`'s.
        let (ok, t, b1, b2) = unsafe { test8(a, na, b, nb, o, d, tmin, tmax) };
        let mut out = [[0.0f32; 8]; 3];
        for (row, v) in out.iter_mut().zip([t, b1, b2]) {
            // SAFETY: a row holds eight floats.
            unsafe { _mm256_storeu_ps(row.as_mut_ptr(), v) };
        }
        (_mm256_movemask_ps(ok) as u32, out)
    }

    /// The eight-lane Möller–Trumbore: the lanes' hit mask, t, b1 and b2.
    ///
    /// # Safety
    /// As [`hits8`].
    #[inline]
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn test8(
        a: &[f32],
        na: usize,
        b: &[f32],
        nb: usize,
        o: Vec3A,
        d: Vec3A,
        tmin: f32,
        tmax: f32,
    ) -> (__m256, __m256, __m256, __m256) {
        debug_assert!(a.len() >= 9 * na + 3 && b.len() >= 9 * nb + 3);
        // SAFETY: component c of a leaf of n slots starts at c n, and c n + 4 <= 9 n + 3.
        let load = |c: usize| unsafe {
            _mm256_set_m128(
                _mm_loadu_ps(b.as_ptr().add(c * nb)),
                _mm_loadu_ps(a.as_ptr().add(c * na)),
            )
        };
        let (v0x, v0y, v0z) = (load(0), load(1), load(2));
        let (e1x, e1y, e1z) = (load(3), load(4), load(5));
        let (e2x, e2y, e2z) = (load(6), load(7), load(8));
        let (mul, add, sub, and) = (_mm256_mul_ps, _mm256_add_ps, _mm256_sub_ps, _mm256_and_ps);
        let splat = _mm256_set1_ps;
        let (dx, dy, dz) = (splat(d.x), splat(d.y), splat(d.z));
        let px = sub(mul(dy, e2z), mul(dz, e2y));
        let py = sub(mul(dz, e2x), mul(dx, e2z));
        let pz = sub(mul(dx, e2y), mul(dy, e2x));
        let det = add(add(mul(e1x, px), mul(e1y, py)), mul(e1z, pz));
        let inv = _mm256_div_ps(splat(1.0), det);
        let sx = sub(splat(o.x), v0x);
        let sy = sub(splat(o.y), v0y);
        let sz = sub(splat(o.z), v0z);
        let b1 = mul(add(add(mul(sx, px), mul(sy, py)), mul(sz, pz)), inv);
        let qx = sub(mul(sy, e1z), mul(sz, e1y));
        let qy = sub(mul(sz, e1x), mul(sx, e1z));
        let qz = sub(mul(sx, e1y), mul(sy, e1x));
        let b2 = mul(add(add(mul(dx, qx), mul(dy, qy)), mul(dz, qz)), inv);
        let t = mul(add(add(mul(e2x, qx), mul(e2y, qy)), mul(e2z, qz)), inv);
        let (zero, one) = (_mm256_setzero_ps(), splat(1.0));
        let abs = and(det, _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff)));
        // glam's SSE comparisons: != is unordered (true for NaN), the others ordered.
        let geometric = and(
            and(
                _mm256_cmp_ps::<_CMP_NEQ_UQ>(det, zero),
                _mm256_cmp_ps::<_CMP_LT_OQ>(abs, splat(f32::INFINITY)),
            ),
            and(
                and(
                    _mm256_cmp_ps::<_CMP_GE_OQ>(b1, zero),
                    _mm256_cmp_ps::<_CMP_LE_OQ>(b1, one),
                ),
                and(
                    _mm256_cmp_ps::<_CMP_GE_OQ>(b2, zero),
                    _mm256_cmp_ps::<_CMP_LE_OQ>(add(b1, b2), one),
                ),
            ),
        );
        let within = and(
            _mm256_cmp_ps::<_CMP_GT_OQ>(t, splat(tmin)),
            _mm256_cmp_ps::<_CMP_LT_OQ>(t, splat(tmax)),
        );
        (and(geometric, within), t, b1, b2)
    }
}

/// Floats per triangle in a [`LeafTris`]: v0, e1 and e2, three components each.
const FLOATS: usize = 9;

/// Leaves with at least this many slots are packed by one parallel task each.
const PACK_TASK_SLOTS: usize = 1 << 14;

/// Leaves ((first slot, count)) and the part of a per-slot array that holds their slots.
pub(crate) type LeafRun<'a, T> = (&'a [(u32, u32)], &'a mut [T]);

/// Splits `data`, `per` elements per slot from slot 0, into runs of whole leaves of about
/// [`PACK_TASK_SLOTS`] slots, each with its leaves: for filling per-slot arrays in parallel.
/// `leaves` ((first slot, count)) must be in slot order and cover the slots from 0 once each,
/// as [`crate::accel::Bvh::leaves`] does; elements past the last leaf's are left out.
pub(crate) fn leaf_runs<'a, T>(
    data: &'a mut [T],
    leaves: &'a [(u32, u32)],
    per: usize,
) -> Vec<LeafRun<'a, T>> {
    let mut runs = Vec::new();
    let (mut rest, mut first, mut run_start) = (data, 0usize, 0usize);
    for (i, &(start, count)) in leaves.iter().enumerate() {
        let end = (start + count) as usize;
        if end - run_start >= PACK_TASK_SLOTS || i + 1 == leaves.len() {
            let (part, tail) = std::mem::take(&mut rest).split_at_mut(per * (end - run_start));
            runs.push((&leaves[first..=i], part));
            rest = tail;
            first = i + 1;
            run_start = end;
        }
    }
    runs
}

/// The triangles of a BVH's leaves, stored for the SIMD test with nothing else and no padding
/// lanes: 36 bytes per slot (a [`Tri4`] per leaf takes 144 bytes, however few triangles the
/// leaf holds). Slots are BVH positions; a leaf of `count` slots from `start` keeps, for each
/// of the nine components (v0, e1, e2 by axis), its `count` lanes one after the other from
/// float `9 · start`. Four lanes are read with one unaligned load: in a leaf of fewer than four
/// slots the extra lanes hold the next component's values (or the three floats of padding at
/// the end) and are masked off, so the arithmetic per lane is exactly [`Tri4`]'s and the
/// results are the scalar test's to the bit. Slots that are not triangles hold zeros and must
/// not be tested as triangles.
#[derive(Clone, Debug, Default)]
pub struct LeafTris {
    data: Vec<f32>,
}

impl LeafTris {
    /// Packs `slots` slots for the leaves `leaves` ((first slot, count), in any order; they
    /// must cover `0..slots` exactly, as [`crate::accel::Bvh::leaves`] does), with `geom(slot)`
    /// the triangle in each slot (`None`: not a triangle). In parallel on rayon's pool.
    pub fn new(
        slots: usize,
        leaves: &[(u32, u32)],
        geom: impl Fn(usize) -> Option<TriangleGeom> + Sync,
    ) -> Self {
        let mut sorted = leaves.to_vec();
        sorted.sort_unstable();
        let mut next = 0usize;
        for &(start, count) in &sorted {
            assert!(
                start as usize == next && count > 0,
                "leaves must cover the slots once each"
            );
            next += count as usize;
        }
        assert_eq!(next, slots, "leaves must cover the slots once each");
        let mut data = vec![0.0f32; FLOATS * slots + 3];
        crate::alloc::advise_huge(&data); // not touched yet: rays read it at random

        // Runs of whole leaves, each with its part of `data`, packed in parallel.
        let tasks = leaf_runs(&mut data, &sorted, FLOATS);
        tasks.into_par_iter().for_each(|(run, part)| {
            let base = run.first().map_or(0, |l| l.0 as usize);
            for &(start, count) in run {
                let at = FLOATS * (start as usize - base);
                let n = count as usize;
                let leaf = &mut part[at..at + FLOATS * n];
                for lane in 0..n {
                    let Some(g) = geom(start as usize + lane) else {
                        continue;
                    };
                    for (c, v) in [g.v0, g.e1, g.e2]
                        .iter()
                        .flat_map(|v| v.to_array())
                        .enumerate()
                    {
                        leaf[c * n + lane] = v;
                    }
                }
            }
        });
        Self { data }
    }

    /// The triangle in lane `lane` of the leaf of `count` slots from `start`.
    #[inline]
    pub fn geom(&self, start: u32, count: u32, lane: u32) -> TriangleGeom {
        let (n, at) = (count as usize, FLOATS * start as usize + lane as usize);
        let c = |k: usize| self.data[at + k * n];
        TriangleGeom {
            v0: Vec3A::new(c(0), c(1), c(2)),
            e1: Vec3A::new(c(3), c(4), c(5)),
            e2: Vec3A::new(c(6), c(7), c(8)),
        }
    }

    /// The nearest hit among the triangles of the leaf of `count` slots from `start` within
    /// (tmin, tmax): (lane, t, b1, b2), the lowest lane among equal distances, what testing
    /// them one by one with [`TriangleGeom::intersect`] gives.
    #[inline(always)]
    pub fn intersect(
        &self,
        start: u32,
        count: u32,
        o: Vec3A,
        d: Vec3A,
        tmin: f32,
        tmax: f32,
    ) -> Option<(usize, f32, f32, f32)> {
        let leaf = self.leaf(start, count);
        let n = count as usize;
        if n <= 4 {
            let (hits, t, b1, b2) = Self::test(leaf, n, 0, o, d, tmin, tmax);
            return nearest_lane((hits & ((1 << n) - 1), t, b1, b2));
        }
        // Wider leaves four lanes at a time; each group only sees hits nearer than the
        // previous groups' best, so the lowest lane still wins among equal distances.
        let mut best = None;
        let mut tmax = tmax;
        for first in (0..n).step_by(4) {
            let (hits, t, b1, b2) = Self::test(leaf, n, first, o, d, tmin, tmax);
            let lanes = (n - first).min(4);
            if let Some((lane, th, b1, b2)) = nearest_lane((hits & ((1 << lanes) - 1), t, b1, b2)) {
                tmax = th;
                best = Some((first + lane, th, b1, b2));
            }
        }
        best
    }

    /// Whether any triangle of the leaf of `count` slots from `start` is hit within
    /// (tmin, tmax).
    #[inline(always)]
    pub fn any(&self, start: u32, count: u32, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> bool {
        let leaf = self.leaf(start, count);
        let n = count as usize;
        (0..n).step_by(4).any(|first| {
            let lanes = (n - first).min(4);
            Self::test(leaf, n, first, o, d, tmin, tmax).0 & ((1 << lanes) - 1) != 0
        })
    }

    /// The lanes of two leaves of at most four slots each, `a` and `b` ((first slot,
    /// count)), hit within (tmin, tmax): bits 0..4 `a`'s, 4..8 `b`'s, what
    /// [`LeafTris::any`] tests in each, lane by lane to the bit. With AVX2 (`avx2`, which the
    /// caller has checked) one 8-lane test, else two 4-lane ones.
    #[inline(always)]
    pub fn hits_pair(
        &self,
        a: (u32, u32),
        b: (u32, u32),
        o: Vec3A,
        d: Vec3A,
        (tmin, tmax): (f32, f32),
        avx2: bool,
    ) -> u32 {
        assert!(a.1 <= 4 && b.1 <= 4, "leaves of at most four slots");
        let (la, lb) = (self.leaf(a.0, a.1), self.leaf(b.0, b.1));
        let (na, nb) = (a.1 as usize, b.1 as usize);
        let lanes = ((1u32 << na) - 1) | (((1u32 << nb) - 1) << 4);
        #[cfg(target_arch = "x86_64")]
        if avx2 && na > 0 && nb > 0 {
            // SAFETY: the caller says the CPU has AVX2; each leaf holds 9n + 3 floats.
            return unsafe { pair_avx2::hits8(la, na, lb, nb, o, d, tmin, tmax) } & lanes;
        }
        let _ = avx2;
        let hits = |leaf: &[f32], n: usize| match n {
            0 => 0,
            _ => Self::test(leaf, n, 0, o, d, tmin, tmax).0,
        };
        (hits(la, na) | hits(lb, nb) << 4) & lanes
    }

    /// The nearest hit in two leaves of at most four slots each, `a` and `b` ((first slot,
    /// count)), among those within (tmin, bound) that `beats(slot, t)` accepts, as (slot, t,
    /// b1, b2), the lowest slot among equal distances. With `beats` checking the bound each
    /// leaf would be tested with (the traversal's tie rule) and `bound` the larger of the two,
    /// as `crate::accel::pair_limits` gives them, this is what [`LeafTris::intersect`] on
    /// each, one after the other, gives, lane by lane to the bit. With AVX2 (`avx2`, which
    /// the caller has checked) one 8-lane test, else two 4-lane ones.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub fn nearest_pair(
        &self,
        a: (u32, u32),
        b: (u32, u32),
        o: Vec3A,
        d: Vec3A,
        (tmin, bound): (f32, f32),
        beats: impl Fn(usize, f32) -> bool,
        avx2: bool,
    ) -> Option<(usize, f32, f32, f32)> {
        assert!(a.1 <= 4 && b.1 <= 4, "leaves of at most four slots");
        let (la, lb) = (self.leaf(a.0, a.1), self.leaf(b.0, b.1));
        let (na, nb) = (a.1 as usize, b.1 as usize);
        let (hits, [t, b1, b2]) = 'test: {
            #[cfg(target_arch = "x86_64")]
            if avx2 && na > 0 && nb > 0 {
                // SAFETY: the caller says the CPU has AVX2; each leaf holds 9n + 3 floats.
                break 'test unsafe { pair_avx2::hits8_at(la, na, lb, nb, o, d, tmin, bound) };
            }
            let _ = avx2;
            let mut out = [[0.0f32; 8]; 3];
            let mut hits = 0;
            for (k, (leaf, n)) in [(la, na), (lb, nb)].into_iter().enumerate() {
                if n > 0 {
                    let (h, t, b1, b2) = Self::test(leaf, n, 0, o, d, tmin, bound);
                    hits |= h << (4 * k);
                    for (row, v) in out.iter_mut().zip([t, b1, b2]) {
                        row[4 * k..4 * k + 4].copy_from_slice(&v.to_array());
                    }
                }
            }
            (hits, out)
        };
        let lanes = ((1u32 << na) - 1) | (((1u32 << nb) - 1) << 4);
        let mut rest = hits & lanes;
        let mut won: Option<(usize, usize)> = None;
        while rest != 0 {
            let lane = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            let slot = if lane < 4 {
                a.0 as usize + lane
            } else {
                b.0 as usize + lane - 4
            };
            let th = t[lane];
            let nearer = match won {
                None => true,
                Some((s, l)) => th < t[l] || (th == t[l] && slot < s),
            };
            if nearer && beats(slot, th) {
                won = Some((slot, lane));
            }
        }
        won.map(|(slot, lane)| (slot, t[lane], b1[lane], b2[lane]))
    }

    /// The floats of the leaf of `count` slots from `start`, with the three that may be read
    /// past its last component.
    #[inline(always)]
    fn leaf(&self, start: u32, count: u32) -> &[f32] {
        let at = FLOATS * start as usize;
        &self.data[at..at + FLOATS * count as usize + 3]
    }

    /// [`test4`] on lanes `first..first + 4` of a leaf of `n` slots (`leaf` from
    /// [`LeafTris::leaf`]); lanes at `n` and beyond hold other values and must be masked off.
    #[inline(always)]
    fn test(
        leaf: &[f32],
        n: usize,
        first: usize,
        o: Vec3A,
        d: Vec3A,
        tmin: f32,
        tmax: f32,
    ) -> (u32, Vec4, Vec4, Vec4) {
        debug_assert!(first < n && leaf.len() >= FLOATS * n + 3);
        let load = |c: usize| {
            let at = c * n + first;
            // SAFETY: `first < n`, so `at + 3 <= 8n + n - 1 + 3 < 9n + 3 <= leaf.len()`.
            Vec4::from_array(unsafe { leaf.as_ptr().add(at).cast::<[f32; 4]>().read_unaligned() })
        };
        let v0 = [load(0), load(1), load(2)];
        let e1 = [load(3), load(4), load(5)];
        let e2 = [load(6), load(7), load(8)];
        test4(&v0, &e1, &e2, o, d, tmin, tmax)
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> usize {
        self.data.capacity() * std::mem::size_of::<f32>()
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

    /// Leaves of one to eight triangles packed without padding lanes (and a slot that is not a
    /// triangle) give what testing their triangles one by one gives, to the bit: the lane, t,
    /// b1, b2 of the nearest (the lowest lane among equals), any-hit, and the corners back.
    #[test]
    fn leaf_pairs_hit_what_each_leaf_hits() {
        use crate::sampling::hash_u32;
        let r = |i: u32| (hash_u32(i) >> 8) as f32 / (1 << 24) as f32 * 2.0 - 1.0;
        let v = |i: u32| Vec3A::new(r(3 * i), r(3 * i + 1), r(3 * i + 2));
        // Leaves of 1..=4 slots; every 7th triangle degenerate (a line), every 5th repeats the
        // one before (a ray through one hits both).
        let mut leaves = Vec::new();
        let mut slots = 0u32;
        for k in 0..400u32 {
            let count = 1 + hash_u32(k + 5) % 4;
            leaves.push((slots, count));
            slots += count;
        }
        let tri = |slot: u32| {
            let s = if slot.is_multiple_of(5) && slot > 0 {
                slot - 1
            } else {
                slot
            };
            let (a, b) = (v(3 * s), v(3 * s + 1));
            let c = if s % 7 == 3 {
                a * 0.5 + b * 0.5
            } else {
                v(3 * s + 2)
            };
            TriangleGeom::new([a, b, c])
        };
        let pack = LeafTris::new(slots as usize, &leaves, |s| Some(tri(s as u32)));
        let avx2 = crate::accel::avx2();
        let (mut hit_lanes, mut nearest_hits) = (0, 0);
        for (n, pair) in leaves.windows(2).enumerate() {
            let (a, b) = (pair[0], pair[1]);
            for k in 0..12u32 {
                let o = v(700_000 + 12 * n as u32 + k) * 2.0;
                let aim = tri(if k % 2 == 0 { a.0 } else { b.0 + b.1 - 1 });
                let mut d = aim.point(0.25, 0.25) + v(600_000 + 12 * n as u32 + k) * 0.3 - o;
                if k == 11 {
                    d = aim.v0 - o; // through a vertex
                }
                let tmax = [f32::INFINITY, 1.0, 0.5][(k % 3) as usize];
                let four = |(start, count): (u32, u32)| {
                    LeafTris::test(pack.leaf(start, count), count as usize, 0, o, d, 0.0, tmax).0
                        & ((1 << count) - 1)
                };
                let want = four(a) | four(b) << 4;
                for simd in [false, avx2] {
                    let got = pack.hits_pair(a, b, o, d, (0.0, tmax), simd);
                    assert_eq!(got, want, "leaves {a:?} {b:?}, ray {k}, avx2 {simd}");
                }
                // The same leaf twice: both halves agree.
                let twice = pack.hits_pair(a, a, o, d, (0.0, tmax), avx2);
                assert_eq!(twice, four(a) | four(a) << 4);
                hit_lanes += want.count_ones();
                // The nearest hit of the pair is what each leaf gives, one after the other, to
                // the bit: with no hit so far, and with one at exactly the pair's nearest
                // distance in a slot above every leaf's (a tie the pair wins) or below (one
                // it loses).
                let one = |(start, count): (u32, u32), tmax: f32, best: Option<usize>| {
                    let bound = crate::accel::limit(start, best, tmax);
                    pack.intersect(start, count, o, d, 0.0, bound)
                        .map(|(lane, t, b1, b2)| (start as usize + lane, t, b1, b2))
                };
                let one_by_one = |x, y, tmax, best| {
                    let first = one(x, tmax, best);
                    let (tmax, best) = first.map_or((tmax, best), |h| (h.1, Some(h.0)));
                    one(y, tmax, best).or(first)
                };
                let bits = |h: Option<(usize, f32, f32, f32)>| {
                    h.map(|(s, t, b1, b2)| (s, t.to_bits(), b1.to_bits(), b2.to_bits()))
                };
                let nearest = one_by_one(a, b, tmax, None);
                let mut states = vec![(tmax, None)];
                if let Some((_, t, _, _)) = nearest {
                    states.extend([(t, Some(usize::MAX)), (t, Some(0))]);
                }
                for (tmax, best) in states {
                    for (x, y) in [(a, b), (b, a)] {
                        let want = bits(one_by_one(x, y, tmax, best));
                        let bound = crate::accel::limit(x.0.min(y.0), best, tmax);
                        let beats =
                            |slot: usize, t: f32| t < crate::accel::limit(slot as u32, best, tmax);
                        for simd in [false, avx2] {
                            let got = pack.nearest_pair(x, y, o, d, (0.0, bound), beats, simd);
                            assert_eq!(bits(got), want, "nearest, {x:?} {y:?}, ray {k}, {simd}");
                        }
                    }
                }
                nearest_hits += usize::from(nearest.is_some());
            }
        }
        assert!(
            hit_lanes > 1000 && nearest_hits > 1000,
            "too few hits to mean anything: {hit_lanes}, {nearest_hits}"
        );
    }

    #[test]
    fn leaf_tris_match_scalar_bit_for_bit() {
        use crate::sampling::hash_u32;
        let r = |i: u32| (hash_u32(i) >> 8) as f32 / (1 << 24) as f32 * 2.0 - 1.0;
        let v = |i: u32| Vec3A::new(r(3 * i), r(3 * i + 1), r(3 * i + 2));
        // Leaves of 1..=8 slots, listed out of slot order as a BVH's may be.
        let mut leaves = Vec::new();
        let mut slots = 0u32;
        for k in 0..600u32 {
            let count = 1 + hash_u32(k + 77) % 8;
            leaves.push((slots, count));
            slots += count;
        }
        leaves.reverse();
        let base = |slot: u32| TriangleGeom::new([v(3 * slot), v(3 * slot + 1), v(3 * slot + 2)]);
        // Every 11th slot repeats the one before: equal distances, the lower lane must win.
        let tri = |slot: u32| {
            base(if slot.is_multiple_of(11) && slot > 0 {
                slot - 1
            } else {
                slot
            })
        };
        let hole = |slot: u32| slot % 97 == 5; // not a triangle: zeros, never tested as one
        let pack = LeafTris::new(slots as usize, &leaves, |s| {
            (!hole(s as u32)).then(|| tri(s as u32))
        });
        let mut hits = 0;
        for (n, &(start, count)) in leaves.iter().enumerate() {
            let n = n as u32;
            let tris: Vec<Option<TriangleGeom>> = (start..start + count)
                .map(|s| (!hole(s)).then(|| tri(s)))
                .collect();
            for (lane, t) in tris.iter().enumerate() {
                let got = pack.geom(start, count, lane as u32);
                assert_eq!(got, t.unwrap_or(TriangleGeom::new([Vec3A::ZERO; 3])));
            }
            let Some(aim) = tris.iter().flatten().next() else {
                continue;
            };
            for k in 0..8u32 {
                let o = v(900_000 + 8 * n + k) * 2.0;
                let d = aim.point(0.3, 0.3) + v(800_000 + 8 * n + k) * 0.4 - o;
                let tmax = if k % 3 == 0 { 1.5 } else { f32::INFINITY };
                let mut want = None;
                let mut best = tmax;
                for (lane, t) in tris.iter().enumerate() {
                    if let Some((th, b1, b2)) = t.and_then(|t| t.intersect(o, d, 0.0, best)) {
                        best = th;
                        want = Some((lane, th, b1, b2));
                    }
                }
                if tris.iter().all(Option::is_some) {
                    let got = pack.intersect(start, count, o, d, 0.0, tmax);
                    let bits = |h: Option<(usize, f32, f32, f32)>| {
                        h.map(|g| (g.0, g.1.to_bits(), g.2.to_bits(), g.3.to_bits()))
                    };
                    assert_eq!(bits(got), bits(want), "leaf {n} ray {k}");
                    assert_eq!(pack.any(start, count, o, d, 0.0, tmax), want.is_some());
                    if count <= 4 {
                        let packet = Tri4::new(&tris.iter().flatten().copied().collect::<Vec<_>>());
                        assert_eq!(bits(packet.intersect(o, d, 0.0, tmax)), bits(want));
                    }
                }
                hits += usize::from(want.is_some());
            }
        }
        assert!(hits > 1000, "too few hits to mean anything: {hits}");
    }
}
