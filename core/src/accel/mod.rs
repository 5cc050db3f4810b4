//! The bounding-volume hierarchy: a 4-, 8- or 16-wide BVH with uncompressed single-precision
//! child bounds, traversed with one SIMD slab test per node (all children at once: SSE through
//! glam's `Vec4` for four; eight with AVX2 when the CPU has it, detected at run time, two 4-lane
//! tests otherwise; sixteen as two 8-lane AVX2 tests, the width chosen on CPUs with AVX2, see
//! [`Width::native`]):
//! the leaves a ray enters are intersected at once, and traversal descends into the
//! nearest inner child, pushing the others farthest first (an insertion sort of the entered
//! children only when there are several; the common single child costs none). Leaf lanes hold
//! the leaf's first slot and count, and the entered children's nodes are prefetched.
//!
//! Two builders. Small scenes: obvhs's PLOC binary BVH with reinsertion optimisation and SAH
//! leaf collapsing ([`obvhs::bvh2::builder::build_bvh2`]), collapsed into wide nodes by always
//! opening the child with the largest surface area (Embree's and pbrt's way of making wide
//! BVHs from binary ones). Large scenes: our own binned-SAH builder ([`binned`]), which makes
//! the wide nodes directly, in parallel, with one 32-byte reference per primitive made in place
//! from the caller's bounds (obvhs's PLOC needed about 150 bytes per primitive at its peak).
//! This is the only module that talks to obvhs.
//!
//! Why our own traversal: the closure that intersects a leaf is inlined into the loop, the slab
//! test needs no decompression, the ray's reciprocal direction and octant are computed once,
//! and the stack lives uninitialised on the call stack. Measured against obvhs's compressed
//! 8-wide BVH (CWBVH) with its own traversal, which this replaced (2026-11-30, 2-core Xeon,
//! 2 threads, `raytile bench`, old and new binaries run alternately): on the glTF Cornell box
//! 21.1 -> 32.2 Mrays/s coherent and 14.8 -> 19.9 incoherent (closest hit, with the scene's
//! 4-wide triangle packets); on a 1 M-triangle mesh (fast_build) 5.1 -> 11.9 coherent and
//! 1.57 -> 1.75 incoherent, build 0.55 -> 0.35 s.
//!
//! Robustness: the slab test is conservative (pbrt's `1 + 2γ₃` scaling of the far distance; a
//! slab whose distance is NaN, a ray lying in a bounding plane, does not cull), so every
//! primitive a ray can hit is offered to the closure, whatever the rounding. Which primitive is
//! the nearest is decided by the primitive tests alone, and among hits at the same distance by
//! the lowest slot (not by the order leaves are visited in, which depends on the width): so
//! every CPU renders the same bits whichever width it traverses. The 8-wide node tests its
//! lanes with exactly the arithmetic of the 4-wide one (same roundings, same NaN rules, no FMA).
//!
//! Primitives are identified by their *slot*: the position in BVH order. [`Bvh::build`] returns
//! the permutation so callers can store their primitives in slot order (no indirection per hit).

use crate::geometry::{Aabb, Ray};
use glam::Vec4;
use obvhs::bvh2::{builder::build_bvh2, Bvh2};
/// The build parameters (obvhs's), for [`Bvh::build_with`].
pub use obvhs::ploc::{PlocSearchDistance, SortPrecision};
pub use obvhs::BvhBuildParams;
use rayon::prelude::*;
use std::mem::MaybeUninit;
use std::time::Duration;

mod binned;

/// obvhs build presets, fastest to best quality.
pub const PRESETS: [(&str, BvhBuildParams); 6] = [
    ("fastest_build", BvhBuildParams::fastest_build()),
    ("very_fast_build", BvhBuildParams::very_fast_build()),
    ("fast_build", BvhBuildParams::fast_build()),
    ("medium_build", BvhBuildParams::medium_build()),
    ("slow_build", BvhBuildParams::slow_build()),
    ("very_slow_build", BvhBuildParams::very_slow_build()),
];

/// Largest primitive count [`Bvh::build_in_scene`] builds with obvhs's thorough preset (above,
/// the binned-SAH builder).
pub const SMALL_BUILD: usize = 1 << 16;

/// Most primitives in one leaf.
const MAX_LEAF: u32 = 4;

/// Whether `bounds` hold many copies of one primitive in one place (an exporter's duplicates,
/// instances stacked on one spot): the squares of the numbers of primitives sharing one box,
/// summed, pass 2^22 (some 2,000 copies of one). obvhs's thorough build takes time growing
/// with the square of such a count (minutes for 40,000 copies of one quad, from a 120-KB
/// file), so such scenes are built by the binned-SAH builder, which splits them in linear
/// time. Boxes shared by a few primitives (the two triangles of an axis-aligned quad, the two
/// faces of a double-sided one) add little: other scenes keep the thorough build, and their
/// images their bits.
fn many_coincident(bounds: &[Aabb]) -> bool {
    const LIMIT: u64 = 1 << 22;
    if (bounds.len() as u64).pow(2) <= LIMIT {
        return false;
    }
    let key = |b: &Aabb| {
        let (lo, hi) = (b.min.to_array(), b.max.to_array());
        [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]].map(f32::to_bits)
    };
    let mut keys: Vec<[u32; 6]> = bounds.iter().map(key).collect();
    keys.sort_unstable();
    keys.chunk_by(|a, b| a == b)
        .map(|run| (run.len() as u64).pow(2))
        .sum::<u64>()
        > LIMIT
}

/// `child` of an empty lane.
const EMPTY: u32 = u32::MAX;

/// `1 + 2γ₃` (pbrt-v4, `Bounds3::IntersectP`): scaling the far distance by it makes the slab
/// test conservative under rounding.
const FAR_SCALE: f32 = 1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// Traversal culls boxes entered beyond `tmax · CULL`, not `tmax`: a triangle's computed hit
/// distance can lie a few ulps before the computed entry of its own box (a ray through a vertex,
/// a grazing ray), and such a hit must still be found, whatever the best hit so far (so that
/// the result does not depend on the order leaves are visited in). Costs a few leaves more.
const CULL: f32 = 1.0 + 1.0 / 4096.0;

/// `N` children (4, 8 or 16): their bounds as SIMD lanes, and what each lane is.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Node<const N: usize> {
    /// `bounds[2 * axis]` holds the children's minima on `axis`, `bounds[2 * axis + 1]` their
    /// maxima. Empty lanes hold an empty box (min +∞, max −∞), which no ray enters.
    bounds: [[f32; N]; 6],
    /// Internal child: its node index. Leaf: its first slot (while [`collapse`] builds: its
    /// index in [`Bvh::leaves`], until [`inline_leaves`]). Empty lane: [`EMPTY`].
    child: [u32; N],
    /// Leaf child: its primitive count (at most [`MAX_LEAF`]). With the first slot in `child`,
    /// a leaf is reached without a look-up in another array (one cache miss fewer per leaf).
    count: [u8; N],
    /// Bit `lane` set: that child is a leaf.
    leaf_mask: u32,
    /// Bit `lane` set: that child is an internal node. (Empty lanes are in neither mask, so
    /// whatever the slab test says about them, traversal never follows one.)
    inner_mask: u32,
    /// Bit `lane` set: that leaf is marked (see [`Bvh::mark_leaves`]).
    mark_mask: u32,
}

// Two, four and eight cache lines: the per-leaf fields fit in what alignment pads anyway.
const _: () = assert!(std::mem::size_of::<Node<4>>() == 128);
const _: () = assert!(std::mem::size_of::<Node<8>>() == 256);
const _: () = assert!(std::mem::size_of::<Node<16>>() == 512);

impl<const N: usize> Node<N> {
    const EMPTY: Self = Self {
        bounds: [
            [f32::INFINITY; N],
            [f32::NEG_INFINITY; N],
            [f32::INFINITY; N],
            [f32::NEG_INFINITY; N],
            [f32::INFINITY; N],
            [f32::NEG_INFINITY; N],
        ],
        child: [EMPTY; N],
        count: [0; N],
        leaf_mask: 0,
        inner_mask: 0,
        mark_mask: 0,
    };
}

/// Replaces each leaf child's index in `leaves` by its first slot and count, once the tree is
/// built.
fn inline_leaves<const N: usize>(nodes: &mut [Node<N>], leaves: &[(u32, u32)]) {
    for n in nodes {
        for lane in 0..N {
            if (n.leaf_mask >> lane) & 1 == 1 {
                let (start, count) = leaves[n.child[lane] as usize];
                debug_assert!(count <= MAX_LEAF, "a leaf of {count} primitives");
                n.child[lane] = start;
                n.count[lane] = u8::try_from(count).expect("leaves hold at most MAX_LEAF");
            }
        }
    }
}

/// Node width of a [`Bvh`]: how many children each node tests at once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Width {
    /// Four children per node, one SSE slab test (every CPU: SSE2 is baseline on x86-64,
    /// and glam's portable lanes elsewhere).
    Four,
    /// Eight children per node, one AVX2 slab test when the CPU has AVX2 (two 4-lane tests
    /// otherwise).
    Eight,
    /// Sixteen children per node, two 8-lane AVX2 slab tests when the CPU has AVX2 (four
    /// 4-lane tests otherwise). Half the levels of a 4-wide tree: fewer dependent node
    /// fetches per ray, and the two halves' tests run side by side.
    Sixteen,
}

impl Width {
    /// The width traversal is fastest with on this CPU: sixteen with AVX2, four otherwise. All
    /// widths find the same hits to the bit (see [`Bvh::closest_leaves`]), so the choice is
    /// speed only; the figures below are `raytile render` at 256×256, 2 threads, the binaries
    /// run alternately.
    ///
    /// Eight against four, on a 2-core AMD EPYC Zen 3 (2026-12-02, 64 spp): the Cornell box
    /// with a 1 M-triangle sphere 0.577 → 0.616 M samples/s (+7 %), the 36-triangle Cornell
    /// box 1.557 → 1.602 (+3 %); `raytile bench`'s 1 M-triangle mesh, incoherent rays 1.28 →
    /// 1.57 M/s.
    ///
    /// Sixteen against eight (the test is two AVX2 halves):
    /// - a 2-core Intel Xeon with AVX-512 (2026-12-05, profile-guided builds for AVX2 CPUs):
    ///   the sphere scene at 32 spp 1.384 → 1.492 M samples/s (+7.8 %), the Cornell box
    ///   2.450 → 2.475 (+1.0 %, noise). One 16-lane AVX-512 test instead of the two halves
    ///   measured slower there (1.354 → 1.330);
    /// - a 2-core AMD EPYC Zen 1 with AVX2 and no AVX-512, whose 256-bit operations are two
    ///   128-bit halves (2026-12-05, builds for AVX2 CPUs): the sphere scene at 32 spp
    ///   0.833 → 0.863 and 0.887 → 0.930 M samples/s in two series (+4–5 %, sixteen faster in
    ///   11 of 13 pairs), the Cornell box 1.400 → 1.392 (noise); incoherent rays on `raytile
    ///   bench`'s 1 M-triangle mesh 2.05 M/s four wide, 2.54 eight and 2.54 sixteen. The
    ///   16-wide tree is also the smallest there (17.4 MB against 23.1 eight wide).
    pub fn native() -> Self {
        if avx2() {
            Width::Sixteen
        } else {
            Width::Four
        }
    }
}

/// Whether this CPU has AVX2 (detected once; the standard library caches it).
#[inline]
pub fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The next float above a positive finite `t` (`f32::next_up`, which needs Rust 1.86); other
/// values are returned as they are.
#[inline(always)]
fn next_above(t: f32) -> f32 {
    if t > 0.0 && t < f32::INFINITY {
        f32::from_bits(t.to_bits() + 1)
    } else {
        t
    }
}

/// A ray prepared for slab tests: origin and reciprocal direction splatted across lanes, and
/// for each axis whether the direction is negative (the near bound is then the maximum).
struct SlabRay {
    o: [Vec4; 3],
    inv: [Vec4; 3],
    neg: [bool; 3],
}

impl SlabRay {
    #[inline(always)]
    fn new(ray: &Ray) -> Self {
        let inv = ray.d.recip();

        Self {
            o: [
                Vec4::splat(ray.o.x),
                Vec4::splat(ray.o.y),
                Vec4::splat(ray.o.z),
            ],
            inv: [Vec4::splat(inv.x), Vec4::splat(inv.y), Vec4::splat(inv.z)],
            neg: [inv.x < 0.0, inv.y < 0.0, inv.z < 0.0],
        }
    }

    /// Entry distances of the four children in lanes `at..at + 4` of `b` and the mask of those
    /// the ray enters within (0, `tmax`).
    #[inline(always)]
    fn test<const N: usize>(&self, b: &[[f32; N]; 6], at: usize, tmax: f32) -> (Vec4, u32) {
        // Indices built from bools so that the compiler sees them in bounds (no checks).
        let [nx, ny, nz] = self.neg.map(usize::from);
        let [fx, fy, fz] = self.neg.map(|n| usize::from(!n));
        let l = |row: &[f32; N]| Vec4::from_slice(&row[at..at + 4]);
        let tn_x = (l(&b[nx]) - self.o[0]) * self.inv[0];
        let tf_x = (l(&b[fx]) - self.o[0]) * self.inv[0];
        let tn_y = (l(&b[2 + ny]) - self.o[1]) * self.inv[1];
        let tf_y = (l(&b[2 + fy]) - self.o[1]) * self.inv[1];
        let tn_z = (l(&b[4 + nz]) - self.o[2]) * self.inv[2];
        let tf_z = (l(&b[4 + fz]) - self.o[2]) * self.inv[2];
        // max/min return their second operand when the first is NaN (0·∞: the ray lies in a
        // bounding plane), so a NaN slab never culls: candidates come first, accumulators second.
        let tnear = tn_x.max(tn_y.max(tn_z.max(Vec4::ZERO)));
        let tfar = tf_x.min(tf_y.min(tf_z.min(Vec4::splat(tmax)))) * FAR_SCALE;
        (tnear, tnear.cmple(tfar).bitmask())
    }

    /// [`SlabRay::test`] of a 4-wide node.
    #[inline(always)]
    fn test4(&self, n: &Node<4>, tmax: f32) -> ([f32; 4], u32) {
        let (t, m) = self.test(&n.bounds, 0, tmax);
        (t.to_array(), m)
    }

    /// An 8-wide node as two 4-wide tests (the lanes compute exactly what the AVX2 test
    /// computes).
    #[inline(always)]
    fn test8(&self, n: &Node<8>, tmax: f32) -> ([f32; 8], u32) {
        let (lo, ml) = self.test(&n.bounds, 0, tmax);
        let (hi, mh) = self.test(&n.bounds, 4, tmax);
        let (lo, hi) = (lo.to_array(), hi.to_array());
        (
            [lo[0], lo[1], lo[2], lo[3], hi[0], hi[1], hi[2], hi[3]],
            ml | (mh << 4),
        )
    }

    /// A 16-wide node as four 4-wide tests (the lanes compute exactly what the AVX2 halves
    /// compute).
    #[inline(always)]
    fn test16(&self, n: &Node<16>, tmax: f32) -> ([f32; 16], u32) {
        let mut tn = [0.0f32; 16];
        let mut mask = 0;
        for q in 0..4 {
            let (t, m) = self.test(&n.bounds, 4 * q, tmax);
            tn[4 * q..4 * q + 4].copy_from_slice(&t.to_array());
            mask |= m << (4 * q);
        }
        (tn, mask)
    }
}

/// The 8-wide slab test with AVX2.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{Node, FAR_SCALE};
    use crate::geometry::Ray;
    use std::arch::x86_64::*;

    /// (bounds − origin) · reciprocal direction, for eight bounds.
    ///
    /// # Safety
    /// The CPU must have AVX2 (see [`SlabRay8::test`] for why this is not a
    /// `target_feature` function).
    #[inline(always)]
    unsafe fn slab(row: &[f32; 8], o: __m256, inv: __m256) -> __m256 {
        // SAFETY: `row` is eight floats.
        _mm256_mul_ps(
            _mm256_sub_ps(unsafe { _mm256_loadu_ps(row.as_ptr()) }, o),
            inv,
        )
    }

    /// [`super::SlabRay`] with eight lanes.
    pub(super) struct SlabRay8 {
        o: [__m256; 3],
        inv: [__m256; 3],
        neg: [bool; 3],
    }

    impl SlabRay8 {
        /// # Safety
        /// The CPU must have AVX2.
        #[inline]
        #[target_feature(enable = "avx2")]
        pub(super) unsafe fn new(ray: &Ray) -> Self {
            let inv = ray.d.recip();
            Self {
                o: [
                    _mm256_set1_ps(ray.o.x),
                    _mm256_set1_ps(ray.o.y),
                    _mm256_set1_ps(ray.o.z),
                ],
                inv: [
                    _mm256_set1_ps(inv.x),
                    _mm256_set1_ps(inv.y),
                    _mm256_set1_ps(inv.z),
                ],
                neg: [inv.x < 0.0, inv.y < 0.0, inv.z < 0.0],
            }
        }

        /// Lane for lane the arithmetic of [`super::SlabRay::test`] (the same roundings, the
        /// same operand order for min/max, so the same NaN behaviour).
        ///
        /// Not a `target_feature` function, so that it can be `inline(always)`: it is called
        /// only from a closure that is inlined into the AVX2 traversal functions, where the
        /// intrinsics inline too. As a `target_feature` function the compiler kept it a call
        /// per node, with the ray reloaded from memory each time.
        ///
        /// # Safety
        /// The CPU must have AVX2.
        #[inline(always)]
        pub(super) unsafe fn test(&self, n: &Node<8>, tmax: f32) -> ([f32; 8], u32) {
            let mut tn = [0.0f32; 8];
            // SAFETY: the caller's CPU has AVX2; `tn` holds the eight lanes from 0.
            let mask = unsafe { self.test_at(&n.bounds, 0, tmax, &mut tn) };
            (tn, mask)
        }

        /// [`SlabRay8::test`] of a 16-wide node: two 8-lane tests.
        ///
        /// # Safety
        /// The CPU must have AVX2.
        #[inline(always)]
        pub(super) unsafe fn test16(&self, n: &Node<16>, tmax: f32) -> ([f32; 16], u32) {
            let mut tn = [0.0f32; 16];
            // SAFETY: as for `test`; `tn` holds lanes 0..16.
            let lo = unsafe { self.test_at(&n.bounds, 0, tmax, &mut tn) };
            let hi = unsafe { self.test_at(&n.bounds, 8, tmax, &mut tn) };
            (tn, lo | (hi << 8))
        }

        /// The test of lanes `at..at + 8` of `b`: their entry distances into the same lanes of
        /// `tn`, and the mask of those the ray enters (bit 0: lane `at`).
        ///
        /// # Safety
        /// The CPU must have AVX2.
        #[inline(always)]
        unsafe fn test_at<const N: usize>(
            &self,
            b: &[[f32; N]; 6],
            at: usize,
            tmax: f32,
            tn: &mut [f32; N],
        ) -> u32 {
            let [nx, ny, nz] = self.neg.map(usize::from);
            let [fx, fy, fz] = self.neg.map(|n| usize::from(!n));
            let row = |k: usize| -> &[f32; 8] {
                b[k][at..at + 8].try_into().expect("eight lanes from `at`")
            };
            let tn_x = slab(row(nx), self.o[0], self.inv[0]);
            let tf_x = slab(row(fx), self.o[0], self.inv[0]);
            let tn_y = slab(row(2 + ny), self.o[1], self.inv[1]);
            let tf_y = slab(row(2 + fy), self.o[1], self.inv[1]);
            let tn_z = slab(row(4 + nz), self.o[2], self.inv[2]);
            let tf_z = slab(row(4 + fz), self.o[2], self.inv[2]);
            let tnear = _mm256_max_ps(
                tn_x,
                _mm256_max_ps(tn_y, _mm256_max_ps(tn_z, _mm256_setzero_ps())),
            );
            let tfar = _mm256_mul_ps(
                _mm256_min_ps(
                    tf_x,
                    _mm256_min_ps(tf_y, _mm256_min_ps(tf_z, _mm256_set1_ps(tmax))),
                ),
                _mm256_set1_ps(FAR_SCALE),
            );
            let mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(tnear, tfar)) as u32;
            let out: &mut [f32; 8] = (&mut tn[at..at + 8])
                .try_into()
                .expect("eight lanes from `at`");
            // SAFETY: `out` holds eight floats.
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), tnear) };
            mask
        }
    }
}

/// A traversal stack that lives on the call stack (no allocation per ray) for BVHs up to
/// `N` entries deep, the common case, and on the heap beyond.
struct Stack<const N: usize> {
    inline: [MaybeUninit<(u32, f32)>; N],
    heap: Vec<(u32, f32)>,
    len: usize,
}

impl<const N: usize> Stack<N> {
    #[inline(always)]
    fn new() -> Self {
        Self {
            // Uninitialised: zeroing it cost as much as a third of a shadow ray.
            inline: [const { MaybeUninit::uninit() }; N],
            heap: Vec::new(),
            len: 0,
        }
    }

    #[inline(always)]
    fn push(&mut self, e: (u32, f32)) {
        if self.len < N {
            self.inline[self.len].write(e);
        } else {
            self.heap.push(e);
        }
        self.len += 1;
    }

    #[inline(always)]
    fn pop(&mut self) -> Option<(u32, f32)> {
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        if self.len < N {
            // SAFETY: entries below the length before this pop were written by `push`.
            Some(unsafe { self.inline[self.len].assume_init() })
        } else {
            self.heap.pop()
        }
    }
}

/// Entries on the stack that live on the call stack: a 16-wide node pushes up to fifteen.
const STACK: usize = 128;

/// Asks the CPU to bring the cache lines of `*p` in (no effect on results; a prefetch never
/// faults, whatever the address).
#[inline(always)]
fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let p = p.cast::<i8>();
        for line in (0..std::mem::size_of::<T>()).step_by(64) {
            // SAFETY: a prefetch does not access memory architecturally.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(line)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// Prefetches the inner children of `n` in `mask`: their nodes arrive while the leaves of `n`
/// are intersected (a node fetched only when it is visited stalls traversal on every miss).
#[inline(always)]
fn prefetch_inner<const N: usize>(nodes: &[Node<N>], n: &Node<N>, mask: u32) {
    let mut inner = mask & n.inner_mask;
    while inner != 0 {
        let lane = inner.trailing_zeros() as usize;
        inner &= inner - 1;
        prefetch(nodes.as_ptr().wrapping_add(n.child[lane] as usize));
    }
}

/// The bound a leaf's hits must stay below to beat the best hit so far (at `tmax`, in slot
/// `best`): among hits at the same distance the lowest slot wins, whatever order the leaves
/// come in (which depends on the node width), so a leaf of lower slots than the best hit's may
/// also return a hit at exactly `tmax`.
#[inline(always)]
pub fn limit(start: u32, best: Option<usize>, tmax: f32) -> f32 {
    match best {
        Some(b) if (start as usize) < b => next_above(tmax),
        _ => tmax,
    }
}

/// For two leaves from slots `a` and `b` tested at once ([`ClosestLeaves::pair`]): the bound
/// for both (the larger of their [`limit`]s) and whether a hit (slot, t) beats the best so far
/// (at `tmax`, in slot `best`), by the bound of its own leaf.
#[inline(always)]
pub fn pair_limits(
    a: u32,
    b: u32,
    best: Option<usize>,
    tmax: f32,
) -> (f32, impl Fn(usize, f32) -> bool) {
    let beats = move |slot: usize, t: f32| t < limit(slot as u32, best, tmax);
    (limit(a.min(b), best, tmax), beats)
}

/// What closest-hit traversal asks of the leaves it enters. A closure
/// `FnMut(marked, first_slot, count, ray_tmax) -> Option<(slot, t)>` is one (see
/// [`Bvh::closest_leaves`]); a type that can also test two marked leaves at once says so with
/// [`ClosestLeaves::pairs`].
pub trait ClosestLeaves {
    /// The nearest hit in the leaf of `count` slots from `start` (`marked`: see
    /// [`Bvh::mark_leaves`]) before `ray_tmax`, as (slot, t), the lowest slot among hits at
    /// the same distance.
    fn leaf(&mut self, marked: bool, start: u32, count: u32, ray_tmax: f32)
        -> Option<(usize, f32)>;

    /// Whether traversal may test two marked leaves of at most [`PAIR_LEAF`] slots that one
    /// node enters with [`ClosestLeaves::pair`].
    #[inline(always)]
    fn pairs(&self) -> bool {
        false
    }

    /// The nearest hit in the marked leaves `a` and `b` ((first slot, count), at most
    /// [`PAIR_LEAF`] slots each) that beats the best so far (`tmax`, in slot `best`; see
    /// [`limit`]), as (slot, t): the lowest slot among hits at the same distance. What
    /// [`ClosestLeaves::leaf`] on `a` and then on `b` gives.
    #[inline(always)]
    fn pair(
        &mut self,
        a: (u32, u32),
        b: (u32, u32),
        tmax: f32,
        best: Option<usize>,
    ) -> Option<(usize, f32)> {
        let first = self.leaf(true, a.0, a.1, limit(a.0, best, tmax));
        let (tmax, best) = first.map_or((tmax, best), |(slot, t)| (t, Some(slot)));
        self.leaf(true, b.0, b.1, limit(b.0, best, tmax)).or(first)
    }
}

impl<F: FnMut(bool, u32, u32, f32) -> Option<(usize, f32)>> ClosestLeaves for F {
    #[inline(always)]
    fn leaf(&mut self, marked: bool, start: u32, count: u32, tmax: f32) -> Option<(usize, f32)> {
        self(marked, start, count, tmax)
    }
}

/// Closest-hit traversal of `N`-wide nodes; `test` is the node's slab test. See
/// [`Bvh::closest_leaves`].
#[inline(always)]
fn closest_in<const N: usize>(
    nodes: &[Node<N>],
    tmax: f32,
    leaf: &mut impl ClosestLeaves,
    test: impl Fn(&Node<N>, f32) -> ([f32; N], u32),
) -> Option<(usize, f32)> {
    if nodes.is_empty() {
        return None;
    }
    let mut tmax = tmax;
    let mut cull = tmax * CULL;
    let mut best: Option<usize> = None;
    let mut stack = Stack::<STACK>::new();
    let mut node = 0u32;
    loop {
        let n = &nodes[node as usize];
        let (tn, mask) = test(n, cull);
        prefetch_inner(nodes, n, mask);
        // Leaves the ray enters are intersected at once (in lane order: each hit shrinks
        // tmax, and a leaf entered beyond it, give or take `CULL`, is skipped).
        let mut lanes = mask & n.leaf_mask;
        while lanes != 0 {
            let lane = lanes.trailing_zeros() as usize;
            lanes &= lanes - 1;
            if tn[lane] <= cull {
                let (start, count) = (n.child[lane], u32::from(n.count[lane]));
                let marked = (n.mark_mask >> lane) & 1 == 1;
                // Two small marked leaves entered before the nearest hit so far are tested
                // at once (which hit wins does not depend on the order or grouping).
                let partner = match leaf.pairs() && marked && count <= PAIR_LEAF {
                    true => pairable(n, lanes, |l| tn[l] <= cull),
                    false => None,
                };
                let found = match partner {
                    Some(other) => {
                        lanes &= !(1 << other);
                        let b = (n.child[other], u32::from(n.count[other]));
                        leaf.pair((start, count), b, tmax, best)
                    }
                    None => leaf.leaf(marked, start, count, limit(start, best, tmax)),
                };
                if let Some((slot, th)) = found {
                    tmax = th;
                    cull = th * CULL;
                    best = Some(slot);
                }
            }
        }
        // Inner children entered: descend into the nearest, push the others farthest first
        // (so that the nearer pop first and shrink tmax early). No sorting and no push or
        // pop for the common single child.
        let mut inner = mask & n.inner_mask;
        let mut hit = [(0u32, 0.0f32); N];
        let mut len = 0;
        while inner != 0 {
            let lane = inner.trailing_zeros() as usize;
            inner &= inner - 1;
            let t = tn[lane];
            if t <= cull {
                hit[len] = (n.child[lane], t);
                len += 1;
            }
        }
        if len > 0 {
            if len > 1 {
                // Insertion sort, nearest last (the order of equal distances does not matter:
                // the result never depends on the order nodes are visited in).
                for i in 1..len {
                    let e = hit[i];
                    let mut j = i;
                    while j > 0 && hit[j - 1].1 < e.1 {
                        hit[j] = hit[j - 1];
                        j -= 1;
                    }
                    hit[j] = e;
                }
                for &e in &hit[..len - 1] {
                    stack.push(e);
                }
            }
            node = hit[len - 1].0;
            continue;
        }
        loop {
            match stack.pop() {
                None => return best.map(|s| (s, tmax)),
                Some((c, t)) if t <= cull => {
                    node = c;
                    break;
                }
                Some(_) => {}
            }
        }
    }
}

/// Leaves of at most this many slots may be tested in pairs ([`AnyLeaves::pair`]).
pub const PAIR_LEAF: u32 = 4;

/// What any-hit traversal asks of the leaves it enters. A closure
/// `FnMut(marked, first_slot, count) -> bool` is one (see [`Bvh::any_leaves`]); a type that
/// can also test two marked leaves at once says so with [`AnyLeaves::pairs`].
pub trait AnyLeaves {
    /// Whether anything in the leaf of `count` slots from `start` blocks the ray (`marked`:
    /// see [`Bvh::mark_leaves`]).
    fn leaf(&mut self, marked: bool, start: u32, count: u32) -> bool;

    /// Whether traversal may test two marked leaves of at most [`PAIR_LEAF`] slots that one
    /// node enters with [`AnyLeaves::pair`].
    #[inline(always)]
    fn pairs(&self) -> bool {
        false
    }

    /// Whether anything in the marked leaves `a` or `b` ((first slot, count), at most
    /// [`PAIR_LEAF`] slots each) blocks the ray.
    fn pair(&mut self, a: (u32, u32), b: (u32, u32)) -> bool;
}

impl<F: FnMut(bool, u32, u32) -> bool> AnyLeaves for F {
    #[inline(always)]
    fn leaf(&mut self, marked: bool, start: u32, count: u32) -> bool {
        self(marked, start, count)
    }

    fn pair(&mut self, a: (u32, u32), b: (u32, u32)) -> bool {
        self(true, a.0, a.1) || self(true, b.0, b.1)
    }
}

/// The lowest lane in `lanes` that holds a marked leaf of at most [`PAIR_LEAF`] slots and is
/// `entered`.
#[inline(always)]
fn pairable<const N: usize>(
    n: &Node<N>,
    lanes: u32,
    entered: impl Fn(usize) -> bool,
) -> Option<usize> {
    let mut rest = lanes & n.mark_mask;
    while rest != 0 {
        let lane = rest.trailing_zeros() as usize;
        rest &= rest - 1;
        if u32::from(n.count[lane]) <= PAIR_LEAF && entered(lane) {
            return Some(lane);
        }
    }
    None
}

/// Any-hit traversal of `N`-wide nodes. See [`Bvh::any_leaves`].
#[inline(always)]
fn any_in<const N: usize>(
    nodes: &[Node<N>],
    tmax: f32,
    leaf: &mut impl AnyLeaves,
    test: impl Fn(&Node<N>, f32) -> ([f32; N], u32),
) -> bool {
    if nodes.is_empty() {
        return false;
    }
    let cull = tmax * CULL;
    let mut stack = Stack::<STACK>::new();
    let mut node = 0u32;
    loop {
        let n = &nodes[node as usize];
        let (_, mask) = test(n, cull);
        prefetch_inner(nodes, n, mask);
        let mut lanes = mask & n.leaf_mask;
        while lanes != 0 {
            let lane = lanes.trailing_zeros() as usize;
            lanes &= lanes - 1;
            let (start, count) = (n.child[lane], u32::from(n.count[lane]));
            let marked = (n.mark_mask >> lane) & 1 == 1;
            // Two small marked leaves entered together are tested at once (the answer is
            // whether any leaf blocks the ray, whatever the order or grouping).
            if leaf.pairs() && marked && count <= PAIR_LEAF {
                if let Some(other) = pairable(n, lanes, |_| true) {
                    lanes &= !(1 << other);
                    if leaf.pair((start, count), (n.child[other], u32::from(n.count[other]))) {
                        return true;
                    }
                    continue;
                }
            }
            if leaf.leaf(marked, start, count) {
                return true;
            }
        }
        // Descend into the first inner child entered, push the others.
        let mut inner = mask & n.inner_mask;
        if inner != 0 {
            let first = n.child[inner.trailing_zeros() as usize];
            inner &= inner - 1;
            while inner != 0 {
                stack.push((n.child[inner.trailing_zeros() as usize], 0.0));
                inner &= inner - 1;
            }
            node = first;
            continue;
        }
        match stack.pop() {
            None => return false,
            Some((c, _)) => node = c,
        }
    }
}

/// 8-wide traversals compiled for AVX2.
/// The traversals with AVX2: [`closest_in`] and [`any_in`] with the AVX2 slab test of 8-wide
/// nodes (one 8-lane test) or 16-wide nodes (two).
#[cfg(target_arch = "x86_64")]
mod traverse_avx2 {
    use super::avx2::SlabRay8;
    use super::{any_in, closest_in, Node};
    use crate::geometry::Ray;

    /// The AVX2 slab test of an `N`-wide node.
    pub(super) trait NodeTest<const N: usize> {
        /// # Safety
        /// The CPU must have AVX2.
        unsafe fn node(&self, n: &Node<N>, tmax: f32) -> ([f32; N], u32);
    }

    impl NodeTest<8> for SlabRay8 {
        #[inline(always)]
        unsafe fn node(&self, n: &Node<8>, tmax: f32) -> ([f32; 8], u32) {
            // SAFETY: the caller's CPU has AVX2.
            unsafe { self.test(n, tmax) }
        }
    }

    impl NodeTest<16> for SlabRay8 {
        #[inline(always)]
        unsafe fn node(&self, n: &Node<16>, tmax: f32) -> ([f32; 16], u32) {
            // SAFETY: the caller's CPU has AVX2.
            unsafe { self.test16(n, tmax) }
        }
    }

    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn closest<const N: usize>(
        nodes: &[Node<N>],
        ray: &Ray,
        tmax: f32,
        leaf: &mut impl super::ClosestLeaves,
    ) -> Option<(usize, f32)>
    where
        SlabRay8: NodeTest<N>,
    {
        // SAFETY: the caller checked AVX2.
        let sr = unsafe { SlabRay8::new(ray) };
        // SAFETY: the caller checked AVX2; the closure runs only inside this function.
        closest_in(nodes, tmax, leaf, |n, t| unsafe { sr.node(n, t) })
    }

    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn any<const N: usize>(
        nodes: &[Node<N>],
        ray: &Ray,
        tmax: f32,
        leaf: &mut impl super::AnyLeaves,
    ) -> bool
    where
        SlabRay8: NodeTest<N>,
    {
        // SAFETY: the caller checked AVX2.
        let sr = unsafe { SlabRay8::new(ray) };
        // SAFETY: the caller checked AVX2; the closure runs only inside this function.
        any_in(nodes, tmax, leaf, |n, t| unsafe { sr.node(n, t) })
    }
}

/// A BVH over primitive bounds.
#[derive(Clone, Default)]
pub struct Bvh {
    /// The nodes when 4 wide (else empty).
    nodes4: Vec<Node<4>>,
    /// The nodes when 8 wide (else empty).
    nodes8: Vec<Node<8>>,
    /// The nodes when 16 wide (else empty).
    nodes16: Vec<Node<16>>,
    /// Each leaf's first slot and primitive count, in slot order.
    leaves: Vec<(u32, u32)>,
    /// Whether 8- and 16-wide nodes are tested with AVX2 (the CPU has it).
    avx2: bool,
}

impl Bvh {
    /// Builds over `bounds` with a builder chosen by size; returns the BVH and the slot order
    /// (`order[slot]` = index into `bounds`). [`Bvh::build_in_scene`] with the tree alone.
    pub fn build(bounds: Vec<Aabb>) -> (Self, Vec<u32>) {
        let n = bounds.len();
        Self::build_in_scene(bounds, n)
    }

    /// Builds one of the BVHs of a scene of `scene_prims` primitives (all its trees together).
    ///
    /// Up to [`SMALL_BUILD`] scene primitives, obvhs's most thorough preset (`very_slow_build`:
    /// a wide PLOC search and full reinsertion): it costs milliseconds there, and a small scene
    /// of big primitives (a room, a Cornell box) is where tree quality shows most; measured on
    /// the glTF Cornell box, 6 % fewer instructions per path sample than `fast_build`. Above,
    /// the binned-SAH builder ([`Bvh::build_sah`]): on a million-triangle mesh a better tree
    /// than obvhs's `fast_build` in a fraction of its time and memory. The scene's size
    /// decides, not the tree's, so that many instanced meshes do not each pay for the thorough
    /// build.
    pub fn build_in_scene(bounds: Vec<Aabb>, scene_prims: usize) -> (Self, Vec<u32>) {
        if scene_prims <= SMALL_BUILD && !many_coincident(&bounds) {
            Self::build_with(&bounds, BvhBuildParams::very_slow_build())
        } else {
            Self::build_sah(bounds, Width::native())
        }
    }

    /// Builds with the binned-SAH builder (see [`binned`]), nodes of the given width; consumes
    /// the bounds (their memory becomes the builder's references).
    pub fn build_sah(bounds: Vec<Aabb>, width: Width) -> (Self, Vec<u32>) {
        if bounds.is_empty() {
            return (Self::default(), Vec::new());
        }
        let mut bvh = Self {
            avx2: avx2(),
            ..Self::default()
        };
        let order = match width {
            Width::Four => {
                let (nodes, leaves, order) = binned::build::<4>(bounds);
                (bvh.nodes4, bvh.leaves) = (nodes, leaves);
                order
            }
            Width::Eight => {
                let (nodes, leaves, order) = binned::build::<8>(bounds);
                (bvh.nodes8, bvh.leaves) = (nodes, leaves);
                order
            }
            Width::Sixteen => {
                let (nodes, leaves, order) = binned::build::<16>(bounds);
                (bvh.nodes16, bvh.leaves) = (nodes, leaves);
                order
            }
        };
        (bvh, order)
    }

    /// Builds with explicit obvhs parameters (leaves hold at most 4 primitives: the triangle
    /// packets are four wide), nodes of the CPU's [`Width::native`]: both widths find the same
    /// hits, and 16-wide nodes with AVX2 measured faster (see [`Width::native`]).
    pub fn build_with(bounds: &[Aabb], params: BvhBuildParams) -> (Self, Vec<u32>) {
        Self::build_wide(bounds, params, Width::native())
    }

    /// [`Bvh::build_with`] with nodes of the given width. The slot order and the leaves do not
    /// depend on the width.
    pub fn build_wide(
        bounds: &[Aabb],
        mut params: BvhBuildParams,
        width: Width,
    ) -> (Self, Vec<u32>) {
        if bounds.is_empty() {
            return (Self::default(), Vec::new());
        }
        params.max_prims_per_leaf = params.max_prims_per_leaf.clamp(1, MAX_LEAF);
        let mut build_time = Duration::ZERO;
        let mut bvh2 = build_bvh2(bounds, params, &mut build_time);
        let (leaves, leaf_of) = leaf_table(&bvh2);
        let mut bvh = Self {
            leaves,
            avx2: avx2(),
            ..Self::default()
        };
        match width {
            Width::Four => {
                bvh.nodes4 = collapse(&bvh2, &leaf_of);
                inline_leaves(&mut bvh.nodes4, &bvh.leaves);
            }
            Width::Eight => {
                bvh.nodes8 = collapse(&bvh2, &leaf_of);
                inline_leaves(&mut bvh.nodes8, &bvh.leaves);
            }
            Width::Sixteen => {
                bvh.nodes16 = collapse(&bvh2, &leaf_of);
                inline_leaves(&mut bvh.nodes16, &bvh.leaves);
            }
        }
        (bvh, std::mem::take(&mut bvh2.primitive_indices))
    }

    /// The node width.
    pub fn width(&self) -> Width {
        if !self.nodes16.is_empty() {
            Width::Sixteen
        } else if !self.nodes8.is_empty() {
            Width::Eight
        } else {
            Width::Four
        }
    }

    /// Closest hit: `hit(slot, ray_tmax)` returns the hit parameter of that primitive or
    /// `f32::INFINITY`. Returns the slot and parameter of the nearest hit before `tmax`.
    /// Among hits at the same distance, the lowest slot wins.
    #[inline]
    pub fn closest(
        &self,
        ray: &Ray,
        tmax: f32,
        mut hit: impl FnMut(usize, f32) -> f32,
    ) -> Option<(usize, f32)> {
        self.closest_leaves(ray, tmax, |_, start, count, mut tmax| {
            let mut best = None;
            for slot in start as usize..(start + count) as usize {
                let t = hit(slot, tmax);
                if t < tmax {
                    tmax = t;
                    best = Some((slot, t));
                }
            }
            best
        })
    }

    /// Closest hit, a leaf at a time: `leaf(marked, first_slot, count, ray_tmax)` returns the
    /// nearest hit in that leaf (`marked`: see [`Bvh::mark_leaves`]) before `ray_tmax`, as
    /// (slot, t), the lowest slot among hits at the same distance. Returns the nearest hit
    /// before `tmax`, the lowest slot among equals: a leaf whose slots are below the best
    /// hit's is offered a `ray_tmax` one float above the best distance, so that a tie there
    /// wins. Which hit wins therefore does not depend on the order leaves are visited in, nor
    /// on the node width, and every hit `leaf` returns is the new best (so a closure may keep
    /// the latest hit it returned).
    #[inline]
    pub fn closest_leaves(
        &self,
        ray: &Ray,
        tmax: f32,
        mut leaf: impl FnMut(bool, u32, u32, f32) -> Option<(usize, f32)>,
    ) -> Option<(usize, f32)> {
        self.closest_leaves_on(ray, tmax, &mut leaf, self.avx2)
    }

    /// [`Bvh::closest_leaves`] with leaves that may be tested in pairs
    /// ([`ClosestLeaves::pairs`]).
    #[inline]
    pub fn closest_with(
        &self,
        ray: &Ray,
        tmax: f32,
        leaves: &mut impl ClosestLeaves,
    ) -> Option<(usize, f32)> {
        self.closest_leaves_on(ray, tmax, leaves, self.avx2)
    }

    /// [`Bvh::closest_leaves`], with AVX2 for 8- and 16-wide nodes only if `simd` (and the CPU
    /// has it).
    #[inline(always)]
    fn closest_leaves_on(
        &self,
        ray: &Ray,
        tmax: f32,
        leaf: &mut impl ClosestLeaves,
        simd: bool,
    ) -> Option<(usize, f32)> {
        if !self.nodes16.is_empty() {
            #[cfg(target_arch = "x86_64")]
            if simd && self.avx2 {
                // SAFETY: `self.avx2` says the CPU has AVX2.
                return unsafe { traverse_avx2::closest(&self.nodes16, ray, tmax, leaf) };
            }
            let sr = SlabRay::new(ray);
            return closest_in(&self.nodes16, tmax, leaf, |n, t| sr.test16(n, t));
        }
        if self.nodes8.is_empty() {
            let sr = SlabRay::new(ray);
            return closest_in(&self.nodes4, tmax, leaf, |n, t| sr.test4(n, t));
        }
        #[cfg(target_arch = "x86_64")]
        if simd && self.avx2 {
            // SAFETY: `self.avx2` says the CPU has AVX2.
            return unsafe { traverse_avx2::closest(&self.nodes8, ray, tmax, leaf) };
        }
        let _ = simd;
        let sr = SlabRay::new(ray);
        closest_in(&self.nodes8, tmax, leaf, |n, t| sr.test8(n, t))
    }

    /// Any hit before `tmax`: `hit(slot)` says whether that primitive blocks the ray.
    #[inline]
    pub fn any(&self, ray: &Ray, tmax: f32, mut hit: impl FnMut(usize) -> bool) -> bool {
        self.any_leaves(ray, tmax, |_, start, count| {
            (start..start + count).any(|slot| hit(slot as usize))
        })
    }

    /// Any hit, a leaf at a time: `leaf(marked, first_slot, count)` says whether anything in
    /// that leaf (`marked`: see [`Bvh::mark_leaves`]) blocks the ray.
    #[inline]
    pub fn any_leaves(
        &self,
        ray: &Ray,
        tmax: f32,
        mut leaf: impl FnMut(bool, u32, u32) -> bool,
    ) -> bool {
        self.any_leaves_on(ray, tmax, &mut leaf, self.avx2)
    }

    /// [`Bvh::any_leaves`] with leaves that may be tested in pairs ([`AnyLeaves::pairs`]).
    #[inline]
    pub fn any_with(&self, ray: &Ray, tmax: f32, leaves: &mut impl AnyLeaves) -> bool {
        self.any_leaves_on(ray, tmax, leaves, self.avx2)
    }

    /// [`Bvh::any_leaves`], with AVX2 for 8- and 16-wide nodes only if `simd` (and the CPU has
    /// it).
    #[inline(always)]
    fn any_leaves_on(&self, ray: &Ray, tmax: f32, leaf: &mut impl AnyLeaves, simd: bool) -> bool {
        if !self.nodes16.is_empty() {
            #[cfg(target_arch = "x86_64")]
            if simd && self.avx2 {
                // SAFETY: `self.avx2` says the CPU has AVX2.
                return unsafe { traverse_avx2::any(&self.nodes16, ray, tmax, leaf) };
            }
            let sr = SlabRay::new(ray);
            return any_in(&self.nodes16, tmax, leaf, |n, t| sr.test16(n, t));
        }
        if self.nodes8.is_empty() {
            let sr = SlabRay::new(ray);
            return any_in(&self.nodes4, tmax, leaf, |n, t| sr.test4(n, t));
        }
        #[cfg(target_arch = "x86_64")]
        if simd && self.avx2 {
            // SAFETY: `self.avx2` says the CPU has AVX2.
            return unsafe { traverse_avx2::any(&self.nodes8, ray, tmax, leaf) };
        }
        let _ = simd;
        let sr = SlabRay::new(ray);
        any_in(&self.nodes8, tmax, leaf, |n, t| sr.test8(n, t))
    }

    /// Marks the leaves for which `marked(first_slot, count)` holds (and unmarks the others):
    /// traversal passes each leaf's mark to the leaf callbacks of [`Bvh::closest_leaves`] and
    /// [`Bvh::any_leaves`], from the node that holds the leaf (no look-up per leaf).
    /// The nodes are marked in parallel.
    pub fn mark_leaves(&mut self, marked: impl Fn(u32, u32) -> bool + Sync) {
        fn mark<const N: usize>(nodes: &mut [Node<N>], marked: impl Fn(u32, u32) -> bool + Sync) {
            nodes.par_iter_mut().with_min_len(1 << 10).for_each(|n| {
                n.mark_mask = 0;
                for lane in 0..N {
                    if (n.leaf_mask >> lane) & 1 == 1
                        && marked(n.child[lane], u32::from(n.count[lane]))
                    {
                        n.mark_mask |= 1 << lane;
                    }
                }
            });
        }
        mark(&mut self.nodes4, &marked);
        mark(&mut self.nodes8, &marked);
        mark(&mut self.nodes16, &marked);
    }

    /// The leaves: (first slot, primitive count), in slot order. Every slot is in exactly
    /// one.
    pub fn leaves(&self) -> &[(u32, u32)] {
        &self.leaves
    }

    /// Inner nodes.
    pub fn node_count(&self) -> usize {
        self.nodes4.len() + self.nodes8.len() + self.nodes16.len()
    }

    /// The surface-area heuristic's expected cost of a ray through the tree (one that enters
    /// the root's bounds, uniformly distributed): (inner nodes tested, leaves tested).
    pub fn sah_cost(&self) -> (f64, f64) {
        match self.width() {
            Width::Four => sah_of(&self.nodes4),
            Width::Eight => sah_of(&self.nodes8),
            Width::Sixteen => sah_of(&self.nodes16),
        }
    }

    /// Bytes held by the nodes and the leaf table, for cache budgets.
    pub fn memory_bytes(&self) -> usize {
        self.nodes4.capacity() * std::mem::size_of::<Node<4>>()
            + self.nodes8.capacity() * std::mem::size_of::<Node<8>>()
            + self.nodes16.capacity() * std::mem::size_of::<Node<16>>()
            + self.leaves.capacity() * std::mem::size_of::<(u32, u32)>()
    }
}

/// [`Bvh::sah_cost`] of `N`-wide nodes.
fn sah_of<const N: usize>(nodes: &[Node<N>]) -> (f64, f64) {
    let half_area = |n: &Node<N>, lane: usize| {
        let e = [0, 1, 2].map(|a| f64::from(n.bounds[2 * a + 1][lane] - n.bounds[2 * a][lane]));
        e[0] * e[1] + e[1] * e[2] + e[2] * e[0]
    };
    let Some(root) = nodes.first() else {
        return (0.0, 0.0);
    };
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for lane in (0..N).filter(|&l| ((root.leaf_mask | root.inner_mask) >> l) & 1 == 1) {
        for a in 0..3 {
            lo[a] = lo[a].min(root.bounds[2 * a][lane]);
            hi[a] = hi[a].max(root.bounds[2 * a + 1][lane]);
        }
    }
    let e = [0, 1, 2].map(|a| f64::from(hi[a] - lo[a]));
    let root_area = e[0] * e[1] + e[1] * e[2] + e[2] * e[0];
    let (mut inner, mut leaves) = (1.0, 0.0);
    for n in nodes {
        for lane in 0..N {
            if (n.inner_mask >> lane) & 1 == 1 {
                inner += half_area(n, lane) / root_area;
            } else if (n.leaf_mask >> lane) & 1 == 1 {
                leaves += half_area(n, lane) / root_area;
            }
        }
    }
    (inner, leaves)
}

/// The leaves of obvhs's binary BVH in slot order, as (first slot, count), and for every binary
/// node its leaf id (meaningful for leaves only).
fn leaf_table(bvh2: &Bvh2) -> (Vec<(u32, u32)>, Vec<u32>) {
    let b2 = &bvh2.nodes;
    let mut found = Vec::new();
    let mut work = vec![0usize];
    while let Some(n) = work.pop() {
        if b2[n].is_leaf() {
            found.push((b2[n].first_index, b2[n].prim_count, n));
        } else {
            let f = b2[n].first_index as usize;
            work.extend([f, f + 1]);
        }
    }
    found.sort_unstable_by_key(|l| l.0);
    let mut leaf_of = vec![EMPTY; b2.len()];
    for (id, l) in found.iter().enumerate() {
        leaf_of[l.2] = id as u32;
    }
    (found.iter().map(|l| (l.0, l.1)).collect(), leaf_of)
}

/// Collapses obvhs's binary BVH into `N`-wide nodes: each node takes the two children of a
/// binary node and keeps opening its inner child with the largest surface area until it has
/// `N`. Children keep their binary left-to-right order.
fn collapse<const N: usize>(bvh2: &Bvh2, leaf_of: &[u32]) -> Vec<Node<N>> {
    let b2 = &bvh2.nodes;
    let mut nodes = vec![Node::<N>::EMPTY];
    // (binary node, index of the wide node it becomes)
    let mut work = vec![(0usize, 0usize)];
    while let Some((n2, nw)) = work.pop() {
        let mut kids = [0usize; N];
        let mut len = if b2[n2].is_leaf() {
            kids[0] = n2;
            1
        } else {
            let f = b2[n2].first_index as usize;
            kids[..2].copy_from_slice(&[f, f + 1]);
            2
        };
        while len < N {
            let open = kids[..len]
                .iter()
                .enumerate()
                .filter(|(_, &k)| !b2[k].is_leaf())
                .max_by(|a, b| {
                    b2[*a.1]
                        .aabb()
                        .half_area()
                        .total_cmp(&b2[*b.1].aabb().half_area())
                })
                .map(|(i, _)| i);
            let Some(i) = open else { break };
            let f = b2[kids[i]].first_index as usize;
            kids.copy_within(i + 1..len, i + 2);
            kids[i] = f;
            kids[i + 1] = f + 1;
            len += 1;
        }
        let mut node = Node::<N>::EMPTY;
        for (lane, &k) in kids[..len].iter().enumerate() {
            let bb = b2[k].aabb();
            let (lo, hi) = (bb.min.to_array(), bb.max.to_array());
            for axis in 0..3 {
                node.bounds[2 * axis][lane] = lo[axis];
                node.bounds[2 * axis + 1][lane] = hi[axis];
            }
            if b2[k].is_leaf() {
                node.child[lane] = leaf_of[k];
                node.leaf_mask |= 1 << lane;
            } else {
                let idx = nodes.len();
                nodes.push(Node::<N>::EMPTY);
                work.push((k, idx));
                node.child[lane] = idx as u32;
                node.inner_mask |= 1 << lane;
            }
        }
        nodes[nw] = node;
    }
    nodes
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::triangle::{LeafTris, Tri4, TriangleGeom};
    use crate::sampling::hash_u32;
    use glam::Vec3A;

    fn rnd(i: u32) -> f32 {
        (hash_u32(i) >> 8) as f32 / (1 << 24) as f32
    }

    fn v(i: u32) -> Vec3A {
        Vec3A::new(rnd(3 * i), rnd(3 * i + 1), rnd(3 * i + 2))
    }

    /// The BVH must return exactly what testing every primitive returns.
    #[test]
    fn bvh_matches_brute_force_on_random_soups() {
        for (name, params) in PRESETS {
            for n in [1u32, 7, 500] {
                let tris: Vec<TriangleGeom> = (0..n)
                    .map(|i| {
                        let c = v(i) * 4.0;
                        TriangleGeom::new([c, c + v(i + 7000) - 0.5, c + v(i + 9000) - 0.5])
                    })
                    .collect();
                let bounds: Vec<Aabb> = tris
                    .iter()
                    .map(|t| Aabb::from_points(&[t.v0, t.v0 + t.e1, t.v0 + t.e2]))
                    .collect();
                let builds = [
                    Bvh::build_with(&bounds, params),
                    Bvh::build_sah(bounds.clone(), Width::Four),
                    Bvh::build_sah(bounds.clone(), Width::Eight),
                    Bvh::build_sah(bounds.clone(), Width::Sixteen),
                ];
                for (b, (bvh, order)) in builds.iter().enumerate() {
                    for k in 0..300u32 {
                        let o = v(20_000 + k) * 6.0 - 1.0;
                        let d = (v(40_000 + k) - 0.5).normalize();
                        let ray = Ray::new(o, d);
                        let brute = tris
                            .iter()
                            .enumerate()
                            .filter_map(|(i, t)| {
                                t.intersect(o, d, 0.0, f32::INFINITY).map(|h| (i, h.0))
                            })
                            .min_by(|a, b| a.1.total_cmp(&b.1));
                        let got = bvh
                            .closest(&ray, f32::INFINITY, |slot, tmax| {
                                tris[order[slot] as usize]
                                    .intersect(o, d, 0.0, tmax)
                                    .map_or(f32::INFINITY, |h| h.0)
                            })
                            .map(|(slot, t)| (order[slot] as usize, t));
                        assert_eq!(got, brute, "{name}, build {b}, n={n}, ray {k}");
                        let any = bvh.any(&ray, f32::INFINITY, |slot| {
                            tris[order[slot] as usize]
                                .intersect(o, d, 0.0, f32::INFINITY)
                                .is_some()
                        });
                        assert_eq!(any, brute.is_some());
                    }
                }
            }
        }
    }

    /// Every path (4-wide; 8- and 16-wide with AVX2 when the CPU has it, and without) returns the
    /// nearest hit of the lowest slot, to the bit, and the same any-hit answer, on soups with
    /// shared edges, duplicated and degenerate triangles, for random, axis-parallel,
    /// plane-grazing and non-finite rays.
    #[test]
    fn wide_and_narrow_paths_hit_identically() {
        let mut tris: Vec<TriangleGeom> = Vec::new();
        // A bumpy grid: neighbours share edges, so rays through an edge hit two triangles.
        let g = 24;
        let p = |i: u32, j: u32| {
            Vec3A::new(
                i as f32 / g as f32,
                0.1 * rnd(i * 131 + j),
                j as f32 / g as f32,
            )
        };
        for i in 0..g {
            for j in 0..g {
                tris.push(TriangleGeom::new([p(i, j), p(i + 1, j), p(i + 1, j + 1)]));
                tris.push(TriangleGeom::new([p(i, j), p(i + 1, j + 1), p(i, j + 1)]));
            }
        }
        // Random triangles, some of them twice (exact ties) and some degenerate.
        for i in 0..600u32 {
            let c = v(i) * 1.5 - 0.25;
            let t = match i % 10 {
                0 => TriangleGeom::new([c, c + v(i + 7000) * 0.2, c + v(i + 7000) * 0.4]),
                _ => TriangleGeom::new([c, c + v(i + 7000) * 0.3 - 0.15, c + v(i + 9000) * 0.3]),
            };
            tris.push(t);
            if i % 4 == 0 {
                tris.push(t);
            }
        }
        let bounds: Vec<Aabb> = tris
            .iter()
            .map(|t| Aabb::from_points(&[t.v0, t.v0 + t.e1, t.v0 + t.e2]))
            .collect();
        let params = BvhBuildParams::fast_build();
        for sah in [false, true] {
            let build = |width| {
                if sah {
                    Bvh::build_sah(bounds.clone(), width)
                } else {
                    Bvh::build_wide(&bounds, params, width)
                }
            };
            let (narrow, order) = build(Width::Four);
            for width in [Width::Eight, Width::Sixteen] {
                let (wide, order_wide) = build(width);
                assert_eq!(wide.width(), width);
                assert_eq!(
                    order, order_wide,
                    "the slot order must not depend on the width"
                );
                assert_eq!(narrow.leaves(), wide.leaves());
                paths_hit_identically(&tris, &narrow, &wide, &order, g, p);
            }
        }
    }

    /// The rays of [`wide_and_narrow_paths_hit_identically`] through `narrow` and `wide`, two
    /// BVHs of the same slot `order` over `tris`.
    fn paths_hit_identically(
        tris: &[TriangleGeom],
        narrow: &Bvh,
        wide: &Bvh,
        order: &[u32],
        g: u32,
        p: impl Fn(u32, u32) -> Vec3A,
    ) {
        let slots: Vec<TriangleGeom> = order.iter().map(|&i| tris[i as usize]).collect();
        let packets: Vec<Tri4> = narrow
            .leaves()
            .iter()
            .map(|&(s, c)| Tri4::new(&slots[s as usize..(s + c) as usize]))
            .collect();
        // Both widths have the same leaves; traversal names a leaf by its first slot.
        assert_eq!(narrow.leaves(), wide.leaves());
        let packet_at = |start: u32| {
            let leaf = narrow.leaves().partition_point(|l| l.0 < start);
            assert_eq!(narrow.leaves()[leaf].0, start, "a leaf starts at {start}");
            &packets[leaf]
        };
        // Shadow rays through marked leaves, two at a time where a node enters two.
        let packed = LeafTris::new(slots.len(), narrow.leaves(), |s| Some(slots[s]));
        let marked = |bvh: &Bvh| {
            let mut bvh = bvh.clone();
            bvh.mark_leaves(|_, _| true);
            bvh
        };
        let (narrow_marked, wide_marked) = (marked(narrow), marked(wide));
        struct Pairs<'a> {
            tris: &'a LeafTris,
            o: Vec3A,
            d: Vec3A,
            tmax: f32,
            avx2: bool,
            pairs: usize,
        }
        impl AnyLeaves for Pairs<'_> {
            fn leaf(&mut self, marked: bool, start: u32, count: u32) -> bool {
                assert!(marked, "every leaf is marked");
                self.tris.any(start, count, self.o, self.d, 0.0, self.tmax)
            }
            fn pairs(&self) -> bool {
                true
            }
            fn pair(&mut self, a: (u32, u32), b: (u32, u32)) -> bool {
                self.pairs += 1;
                let (o, d) = (self.o, self.d);
                let hits = self.tris.hits_pair(a, b, o, d, (0.0, self.tmax), self.avx2);
                assert_eq!(
                    hits & 0xf != 0,
                    self.tris.any(a.0, a.1, o, d, 0.0, self.tmax)
                );
                assert_eq!(
                    hits >> 4 != 0,
                    self.tris.any(b.0, b.1, o, d, 0.0, self.tmax)
                );
                hits != 0
            }
        }
        impl ClosestLeaves for Pairs<'_> {
            fn leaf(
                &mut self,
                marked: bool,
                start: u32,
                count: u32,
                tmax: f32,
            ) -> Option<(usize, f32)> {
                assert!(marked, "every leaf is marked");
                let hit = self.tris.intersect(start, count, self.o, self.d, 0.0, tmax);
                hit.map(|(lane, t, _, _)| (start as usize + lane, t))
            }
            fn pairs(&self) -> bool {
                true
            }
            fn pair(
                &mut self,
                a: (u32, u32),
                b: (u32, u32),
                tmax: f32,
                best: Option<usize>,
            ) -> Option<(usize, f32)> {
                self.pairs += 1;
                let (o, d) = (self.o, self.d);
                let (bound, beats) = pair_limits(a.0, b.0, best, tmax);
                let hit = self
                    .tris
                    .nearest_pair(a, b, o, d, (0.0, bound), beats, self.avx2);
                hit.map(|(slot, t, _, _)| (slot, t))
            }
        }
        let mut pairs = 0;
        let mut closest_pairs = 0;
        let mut hits = 0;
        let mut ties = 0;
        for k in 0..6000u32 {
            let o = v(20_000 + k) * 1.6 - 0.3;
            let mut d = (v(40_000 + k) - 0.5).normalize();
            match k % 8 {
                // Axis-parallel, both signs.
                0 => {
                    d = [Vec3A::X, Vec3A::Y, Vec3A::Z][(k / 8 % 3) as usize]
                        * [1.0, -1.0][(k / 24 % 2) as usize]
                }
                // Aimed at a grid vertex or edge midpoint (shared by several triangles).
                1 | 2 => {
                    let (i, j) = (hash_u32(k) % g, hash_u32(k + 1) % g);
                    let target = if k % 8 == 1 {
                        p(i, j)
                    } else {
                        (p(i, j) + p(i + 1, j + 1)) * 0.5
                    };
                    d = target - o;
                }
                // Non-finite directions.
                3 if k % 24 == 3 => d = Vec3A::new(f32::NAN, 0.0, 1.0),
                3 if k % 24 == 11 => d = Vec3A::ZERO,
                3 => d = Vec3A::new(0.0, -1.0, 0.0),
                _ => {}
            }
            let ray = Ray::new(o, d);
            let tmax = if k % 5 == 0 { 0.7 } else { f32::INFINITY };
            // Reference: every slot in order, strictly nearer wins (the lowest slot among ties).
            let mut want = None;
            let mut best = tmax;
            let mut at_best = 0;
            for (slot, t) in slots.iter().enumerate() {
                if let Some((th, _, _)) = t.intersect(o, d, 0.0, f32::INFINITY) {
                    if th < best {
                        (best, at_best) = (th, 1);
                        want = Some((slot, th.to_bits()));
                    } else if th == best {
                        at_best += 1;
                    }
                }
            }
            hits += usize::from(want.is_some());
            ties += usize::from(at_best > 1);
            for (bvh, simd) in [(narrow, false), (wide, false), (wide, true)] {
                let packet = bvh
                    .closest_leaves_on(
                        &ray,
                        tmax,
                        &mut |_: bool, start: u32, _: u32, tmax: f32| {
                            packet_at(start)
                                .intersect(o, d, 0.0, tmax)
                                .map(|(lane, t, _, _)| (start as usize + lane, t))
                        },
                        simd,
                    )
                    .map(|(s, t)| (s, t.to_bits()));
                let width = bvh.width();
                assert_eq!(packet, want, "{width:?}, simd {simd}, ray {k}");
                let any = bvh.any_leaves_on(
                    &ray,
                    tmax,
                    &mut |_: bool, start: u32, _: u32| packet_at(start).any(o, d, 0.0, tmax),
                    simd,
                );
                assert_eq!(any, want.is_some(), "{width:?}, simd {simd}, ray {k}");
            }
            for (bvh, simd) in [
                (&narrow_marked, false),
                (&wide_marked, false),
                (&wide_marked, true),
            ] {
                for avx2 in [false, avx2()] {
                    let mut leaves = Pairs {
                        tris: &packed,
                        o,
                        d,
                        tmax,
                        avx2,
                        pairs: 0,
                    };
                    let any = bvh.any_leaves_on(&ray, tmax, &mut leaves, simd);
                    assert_eq!(
                        any,
                        want.is_some(),
                        "pairs, simd {simd}, avx2 {avx2}, ray {k}"
                    );
                    pairs += leaves.pairs;
                    leaves.pairs = 0;
                    let nearest = bvh
                        .closest_leaves_on(&ray, tmax, &mut leaves, simd)
                        .map(|(s, t)| (s, t.to_bits()));
                    assert_eq!(
                        nearest, want,
                        "closest pairs, simd {simd}, avx2 {avx2}, ray {k}"
                    );
                    closest_pairs += leaves.pairs;
                }
            }
            let scalar = wide
                .closest(&ray, tmax, |slot, tmax| {
                    slots[slot]
                        .intersect(o, d, 0.0, tmax)
                        .map_or(f32::INFINITY, |h| h.0)
                })
                .map(|(s, t)| (s, t.to_bits()));
            assert_eq!(scalar, want, "scalar closure, ray {k}");
        }
        assert!(
            hits > 2000 && ties > 20 && pairs > 2000 && closest_pairs > 2000,
            "too few hits, ties or leaf pairs to mean anything: {hits}, {ties}, {pairs}, \
             {closest_pairs}"
        );
    }

    /// Many copies of one primitive in one place go to the binned-SAH builder (obvhs's
    /// thorough build takes minutes on them); scenes without such copies do not.
    #[test]
    fn coincident_primitives_are_built_by_the_binned_builder() {
        let boxes = |n: u32, distinct: u32| -> Vec<Aabb> {
            (0..n)
                .map(|i| {
                    let c = Vec3A::splat((i % distinct) as f32);
                    Aabb::new(c, c + Vec3A::ONE)
                })
                .collect()
        };
        assert!(many_coincident(&boxes(20_000, 1)));
        assert!(many_coincident(&boxes(30_000, 10)));
        assert!(!many_coincident(&boxes(2000, 1)));
        // Pairs and fours sharing a box (quads, double-sided faces): the thorough build.
        assert!(!many_coincident(&boxes(65_536, 32_768)));
        assert!(!many_coincident(&boxes(65_536, 16_384)));
        assert!(!many_coincident(&boxes(60_000, 60_000)));
        // Built, every primitive in one leaf.
        let (bvh, order) = Bvh::build_in_scene(boxes(20_000, 1), 20_000);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert!(sorted.iter().copied().eq(0..20_000));
        let leaf_prims: u32 = bvh.leaves().iter().map(|&(_, c)| c).sum();
        assert_eq!(leaf_prims, 20_000);
    }

    /// The binned-SAH builder: every slot in exactly one leaf of at most [`MAX_LEAF`], leaves
    /// in slot order, and the same tree on one thread as on several (its parallel paths run
    /// above `PAR_PRIMS` primitives), including primitives with NaN and infinite bounds.
    #[test]
    fn binned_build_is_complete_and_thread_independent() {
        let n = 150_000u32;
        let mut bounds: Vec<Aabb> = (0..n)
            .map(|i| {
                // Clusters of many sizes, and runs of identical boxes (no split separates them).
                let c = if i % 7 == 0 {
                    Vec3A::splat((i / 1000) as f32)
                } else {
                    v(i) * (1 + i % 13) as f32
                };
                Aabb::new(c, c + v(i + n) * 0.01)
            })
            .collect();
        bounds[17].min.x = f32::NAN;
        bounds[18].max = Vec3A::splat(f32::INFINITY);
        bounds[19].min = Vec3A::splat(f32::NEG_INFINITY);
        let build = |threads: usize, width: Width| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| Bvh::build_sah(bounds.clone(), width))
        };
        for width in [Width::Four, Width::Eight, Width::Sixteen] {
            let (one, order1) = build(1, width);
            let (many, order4) = build(4, width);
            assert_eq!(order1, order4, "{width:?}: slot order");
            assert_eq!(one.leaves(), many.leaves(), "{width:?}: leaves");
            let bits = |b: &Bvh| -> Vec<u32> {
                let words = |n: &[f32]| n.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                b.nodes4
                    .iter()
                    .flat_map(|n| {
                        n.bounds
                            .iter()
                            .flat_map(|r| words(r))
                            .chain(n.child)
                            .chain(n.count.map(u32::from))
                            .chain([n.leaf_mask, n.inner_mask, n.mark_mask])
                    })
                    .chain(b.nodes8.iter().flat_map(|n| {
                        n.bounds
                            .iter()
                            .flat_map(|r| words(r))
                            .chain(n.child)
                            .chain(n.count.map(u32::from))
                            .chain([n.leaf_mask, n.inner_mask, n.mark_mask])
                    }))
                    .chain(b.nodes16.iter().flat_map(|n| {
                        n.bounds
                            .iter()
                            .flat_map(|r| words(r))
                            .chain(n.child)
                            .chain(n.count.map(u32::from))
                            .chain([n.leaf_mask, n.inner_mask, n.mark_mask])
                    }))
                    .collect()
            };
            assert_eq!(bits(&one), bits(&many), "{width:?}: nodes");
            let mut sorted = order1.clone();
            sorted.sort_unstable();
            assert!(sorted.iter().copied().eq(0..n), "every primitive once");
            let mut next = 0;
            for &(start, count) in one.leaves() {
                assert_eq!(start, next, "leaves in slot order, none missing");
                assert!((1..=MAX_LEAF).contains(&count));
                next += count;
            }
            assert_eq!(next, n);
            let slot_bounds: Vec<Aabb> = order1.iter().map(|&i| bounds[i as usize]).collect();
            let depth = match width {
                Width::Four => check_tree(&one.nodes4, one.leaves(), &slot_bounds),
                Width::Eight => check_tree(&one.nodes8, one.leaves(), &slot_bounds),
                Width::Sixteen => check_tree(&one.nodes16, one.leaves(), &slot_bounds),
            };
            assert!(depth <= 40, "{width:?}: depth {depth}");
            match width {
                Width::Four => assert_tight(&one.nodes4, &slot_bounds),
                Width::Eight => assert_tight(&one.nodes8, &slot_bounds),
                Width::Sixteen => assert_tight(&one.nodes16, &slot_bounds),
            }
        }
        // Points on a line (no split has any area): balanced, not peeled a bin at a time.
        let line: Vec<Aabb> = (0..20_000)
            .map(|i| {
                Aabb::new(
                    Vec3A::new(i as f32, 0.0, 0.0),
                    Vec3A::new(i as f32, 0.0, 0.0),
                )
            })
            .collect();
        let (bvh, order) = Bvh::build_sah(line.clone(), Width::Four);
        let slot_bounds: Vec<Aabb> = order.iter().map(|&i| line[i as usize]).collect();
        let depth = check_tree(&bvh.nodes4, bvh.leaves(), &slot_bounds);
        assert!(depth <= 12, "points on a line: depth {depth}");
    }

    /// Checks a tree's structure: every node but the root referenced once, masks disjoint,
    /// empty lanes empty, every lane's box containing its child's boxes or its primitives'
    /// (`bounds` by slot; NaN boxes skipped). Returns the depth.
    /// Every lane's box is exactly its subtree's: the union of its primitives' boxes (a box
    /// with a NaN counts as a point at the origin, as the binned builder takes it).
    fn assert_tight<const N: usize>(nodes: &[Node<N>], slot_bounds: &[Aabb]) {
        fn subtree<const N: usize>(nodes: &[Node<N>], i: usize, slots: &[Aabb]) -> Aabb {
            let n = &nodes[i];
            let mut all = Aabb::empty();
            for lane in 0..N {
                let c = n.child[lane] as usize;
                let b = if (n.inner_mask >> lane) & 1 == 1 {
                    subtree(nodes, c, slots)
                } else if (n.leaf_mask >> lane) & 1 == 1 {
                    slots[c..c + usize::from(n.count[lane])]
                        .iter()
                        .fold(Aabb::empty(), |a, b| {
                            let nan = b.min.is_nan() || b.max.is_nan();
                            a.union(&if nan {
                                Aabb::new(Vec3A::ZERO, Vec3A::ZERO)
                            } else {
                                *b
                            })
                        })
                } else {
                    continue;
                };
                let (lo, hi) = (b.min.to_array(), b.max.to_array());
                for a in 0..3 {
                    assert_eq!(
                        n.bounds[2 * a][lane],
                        lo[a],
                        "node {i} lane {lane} axis {a}"
                    );
                    assert_eq!(
                        n.bounds[2 * a + 1][lane],
                        hi[a],
                        "node {i} lane {lane} axis {a}"
                    );
                }
                all = all.union(&b);
            }
            all
        }
        subtree(nodes, 0, slot_bounds);
    }

    fn check_tree<const N: usize>(
        nodes: &[Node<N>],
        leaves: &[(u32, u32)],
        bounds: &[Aabb],
    ) -> usize {
        let contains = |n: &Node<N>, lane: usize, b: &Aabb| {
            let (lo, hi) = (b.min.to_array(), b.max.to_array());
            (0..3).all(|a| n.bounds[2 * a][lane] <= lo[a] && hi[a] <= n.bounds[2 * a + 1][lane])
        };
        let lane_box = |n: &Node<N>, lane: usize| {
            let c = |row: usize| n.bounds[row][lane];
            Aabb::new(Vec3A::new(c(0), c(2), c(4)), Vec3A::new(c(1), c(3), c(5)))
        };
        let mut seen = vec![false; nodes.len()];
        let mut leaf_seen = vec![false; leaves.len()];
        let mut work = vec![(0usize, 1usize)];
        let mut depth = 0;
        while let Some((i, d)) = work.pop() {
            assert!(!seen[i], "node {i} referenced twice");
            seen[i] = true;
            depth = depth.max(d);
            let n = &nodes[i];
            assert_eq!(n.leaf_mask & n.inner_mask, 0);
            for lane in 0..N {
                let c = n.child[lane] as usize;
                if (n.inner_mask >> lane) & 1 == 1 {
                    for l in 0..N {
                        if (nodes[c].leaf_mask | nodes[c].inner_mask) >> l & 1 == 1 {
                            assert!(contains(n, lane, &lane_box(&nodes[c], l)));
                        }
                    }
                    work.push((c, d + 1));
                } else if (n.leaf_mask >> lane) & 1 == 1 {
                    // A leaf lane holds the leaf's first slot and count.
                    let c = leaves
                        .binary_search_by_key(&n.child[lane], |l| l.0)
                        .expect("a leaf lane holds a leaf's first slot");
                    assert_eq!(u32::from(n.count[lane]), leaves[c].1, "leaf {c}: count");
                    assert!(!leaf_seen[c], "leaf {c} referenced twice");
                    leaf_seen[c] = true;
                    let (start, count) = leaves[c];
                    for b in &bounds[start as usize..(start + count) as usize] {
                        if !(b.min.is_nan() || b.max.is_nan()) {
                            assert!(contains(n, lane, b), "leaf {c} sticks out of its box");
                        }
                    }
                } else {
                    assert_eq!(n.child[lane], EMPTY);
                    assert!(
                        n.bounds[0][lane] > n.bounds[1][lane],
                        "empty lane not empty"
                    );
                }
            }
        }
        assert!(seen.iter().all(|&s| s), "unreachable nodes");
        assert!(leaf_seen.iter().all(|&s| s), "unreachable leaves");
        depth
    }

    /// Marks reach the callbacks, and on a tree big enough for subtrees built apart (several
    /// times `binned::PAR_PRIMS`) closest hits match a scan of every slot.
    #[test]
    fn leaf_marks_reach_the_leaf_callbacks() {
        let tris: Vec<TriangleGeom> = (0..60_000u32)
            .map(|i| {
                let a = v(3 * i) * 4.0;
                TriangleGeom::new([a, a + v(3 * i + 1) * 0.3, a + v(3 * i + 2) * 0.3])
            })
            .collect();
        let bounds: Vec<Aabb> = tris
            .iter()
            .map(|t| Aabb::from_points(&[t.v0, t.v0 + t.e1, t.v0 + t.e2]))
            .collect();
        for (mut bvh, order) in [
            Bvh::build_wide(&bounds, BvhBuildParams::fast_build(), Width::Four),
            Bvh::build_sah(bounds.clone(), Width::Eight),
            Bvh::build_wide(&bounds, BvhBuildParams::fast_build(), Width::Sixteen),
            Bvh::build_sah(bounds.clone(), Width::Sixteen),
        ] {
            let slots: Vec<TriangleGeom> = order.iter().map(|&i| tris[i as usize]).collect();
            let marked = |start: u32, count: u32| (start + count).is_multiple_of(3);
            bvh.mark_leaves(marked);
            let (mut seen_marked, mut seen_plain, mut hits) = (0, 0, 0);
            for k in 0..500u32 {
                let ray = Ray::new(v(1_000_000 + k) * 4.0, v(2_000_000 + k) - 0.5);
                let mut check = |m: bool, start: u32, count: u32| {
                    assert_eq!(m, marked(start, count), "leaf at {start}");
                    assert_eq!(
                        bvh.leaves().iter().find(|l| l.0 == start).map(|l| l.1),
                        Some(count)
                    );
                    if m {
                        seen_marked += 1;
                    } else {
                        seen_plain += 1;
                    }
                };
                bvh.closest_leaves(&ray, f32::INFINITY, |m, start, count, _| {
                    check(m, start, count);
                    None
                });
                bvh.any_leaves(&ray, f32::INFINITY, |m, start, count| {
                    check(m, start, count);
                    false
                });
                // Nearest, lowest slot among equals.
                let mut want = None;
                let mut best = f32::INFINITY;
                for (slot, t) in slots.iter().enumerate() {
                    if let Some((th, _, _)) = t.intersect(ray.o, ray.d, 0.0, best) {
                        (best, want) = (th, Some((slot, th.to_bits())));
                    }
                }
                let got = bvh
                    .closest(&ray, f32::INFINITY, |slot, tmax| {
                        slots[slot]
                            .intersect(ray.o, ray.d, 0.0, tmax)
                            .map_or(f32::INFINITY, |h| h.0)
                    })
                    .map(|(s, t)| (s, t.to_bits()));
                assert_eq!(got, want, "ray {k}");
                hits += usize::from(want.is_some());
            }
            assert!(
                seen_marked > 100 && seen_plain > 100,
                "{seen_marked}, {seen_plain}"
            );
            assert!(hits > 100, "{hits} hits");
        }
    }

    #[test]
    fn empty_bvh_misses() {
        let (bvh, order) = Bvh::build(Vec::new());
        assert!(order.is_empty());
        assert!(bvh
            .closest(&Ray::new(Vec3A::ZERO, Vec3A::X), 1.0, |_, _| 0.0)
            .is_none());
    }
}
