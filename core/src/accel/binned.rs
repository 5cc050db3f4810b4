//! A binned-SAH builder that makes wide nodes directly (Wald's binning, 2007; the top-down
//! wide build of Embree's `BVHBuilderBinnedSAH`): a node takes its primitive range, splits it
//! at the surface-area heuristic's best bin boundary (32, 16 or 8 bins per axis by the range's
//! size), and keeps splitting the child with the largest surface area until it has `N`
//! children (the same rule [`super::collapse`] applies to a binary tree; 16-wide nodes keep
//! small children whole, see [`keep_whole`]). A leaf holds at most
//! [`MAX_LEAF`] primitives, and the heuristic counts a leaf's cost by 4-wide packets
//! (`⌈n / 4⌉`, Embree's block size), so full leaves cost what a single triangle does. Ranges
//! no bin boundary separates are split at their median.
//!
//! Memory: one 32-byte reference per primitive, made in place from the caller's bounds (the
//! same allocation), and the nodes; no binary tree. Time: a node's subtrees are built in
//! parallel (rayon) when they hold more than [`PAR_PRIMS`] primitives together, and large
//! ranges are binned in parallel chunks; a subtree built apart keeps its own nodes until the
//! end, when every node is copied once into the final array (the subtrees in parallel). A
//! range is partitioned a block at a time, with no branch on each primitive's side
//! ([`partition`]), into Hoare's permutation.
//!
//! Deterministic: every decision depends on the primitives' bounds and input order alone
//! (bins merge by min, max and integer counts, which do not depend on how chunks are split
//! between threads; NaN boxes become a point; among equal costs the most balanced split wins,
//! then the lowest axis and bin), so the tree is the same bits on one thread or many, on every
//! CPU. Huge and infinite boxes are handled in f64 areas and clamped centroids, so one of them
//! is split off near the root rather than spoiling the splits above it.

use super::{Node, MAX_LEAF};
use crate::geometry::Aabb;
use glam::{BVec4A, Vec4};
use rayon::prelude::*;

/// Bins per axis: more for large ranges (where the split matters most and the bins' own cost
/// is spread over many primitives), fewer for small ones.
const fn bins_for(n: usize) -> usize {
    if n > 1024 {
        32
    } else if n > 64 {
        16
    } else {
        8
    }
}

/// Subtrees and bin passes above this many primitives run in parallel.
const PAR_PRIMS: usize = 16 * 1024;

/// Primitives binned per parallel chunk.
const CHUNK: usize = 8 * 1024;

/// A primitive's bounds; the w lane of `lo` holds its input index (its bits: mostly a
/// subnormal float, so it is masked out before any arithmetic, which subnormals slow down on
/// some CPUs), that of `hi` is 0. The same size and alignment as [`Aabb`], so the references
/// are made in place.
#[derive(Clone, Copy)]
#[repr(C)]
struct Ref {
    lo: Vec4,
    hi: Vec4,
}

impl Ref {
    #[inline(always)]
    fn id(&self) -> u32 {
        self.lo.w.to_bits()
    }

    /// The lower corner with w = 0 (a bitwise select, no arithmetic on the id).
    #[inline(always)]
    fn lo(&self) -> Vec4 {
        Vec4::select(BVec4A::new(true, true, true, false), self.lo, Vec4::ZERO)
    }

    /// The centroid, clamped to the finite floats: halves added (no overflow), NaN (a box
    /// infinite both ways) to −f32::MAX, ±∞ to ±f32::MAX. [`centroid_on`] computes one lane
    /// of it with exactly these operations.
    #[inline(always)]
    fn centroid(&self) -> Vec4 {
        (self.lo() * 0.5 + self.hi * 0.5)
            .max(Vec4::splat(-f32::MAX))
            .min(Vec4::splat(f32::MAX))
    }
}

/// Lane `axis` of [`Ref::centroid`], by the same operations on scalars (max returns the
/// non-NaN operand, as SSE's maxps returns its second).
#[inline(always)]
#[allow(clippy::manual_clamp)] // clamp keeps NaN; max maps it to −f32::MAX, as maxps does
fn centroid_on(p: &Ref, axis: usize) -> f32 {
    (p.lo[axis] * 0.5 + p.hi[axis] * 0.5)
        .max(-f32::MAX)
        .min(f32::MAX)
}

/// A box in the xyz lanes (w is ignored).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Box3 {
    lo: Vec4,
    hi: Vec4,
}

impl Box3 {
    const EMPTY: Self = Self {
        lo: Vec4::splat(f32::INFINITY),
        hi: Vec4::splat(f32::NEG_INFINITY),
    };

    /// Grows to include the box `lo`..`hi` (w lanes must be ordinary floats, e.g. 0).
    #[inline(always)]
    fn grow(&mut self, lo: Vec4, hi: Vec4) {
        self.lo = self.lo.min(lo);
        self.hi = self.hi.max(hi);
    }

    #[inline(always)]
    fn union(&self, o: &Self) -> Self {
        Self {
            lo: self.lo.min(o.lo),
            hi: self.hi.max(o.hi),
        }
    }

    /// Half the surface area (0 for an empty box), in f64 from extents clamped to the finite
    /// floats: a huge or infinite box stays comparable (no ∞, no ∞ · 0).
    #[inline(always)]
    fn half_area(&self) -> f64 {
        let e = (self.hi - self.lo)
            .max(Vec4::ZERO)
            .min(Vec4::splat(f32::MAX))
            .as_dvec4();
        e.x * e.y + e.y * e.z + e.z * e.x
    }
}

/// A primitive range being built: its bounds, the bounds of its centroids, and
/// its position in the reference array.
#[derive(Clone, Copy, Debug)]
struct Range {
    bounds: Box3,
    cent: Box3,
    start: usize,
    end: usize,
}

impl Range {
    fn of(refs: &[Ref], start: usize) -> Self {
        let mut r = Self {
            bounds: Box3::EMPTY,
            cent: Box3::EMPTY,
            start,
            end: start + refs.len(),
        };
        for p in refs {
            r.add(p);
        }
        r
    }

    #[inline(always)]
    fn add(&mut self, p: &Ref) {
        self.bounds.grow(p.lo(), p.hi);
        let c = p.centroid();
        self.cent.grow(c, c);
    }

    fn len(&self) -> usize {
        self.end - self.start
    }
}

/// The map from a centroid to its bin on each axis, for `B` bins.
#[derive(Clone, Copy)]
struct Binner<const B: usize> {
    origin: Vec4,
    scale: Vec4,
}

impl<const B: usize> Binner<B> {
    fn new(cent: &Box3) -> Self {
        // Halves: the centroids are finite, their extent may not be.
        let half_extent = cent.hi * 0.5 - cent.lo * 0.5;
        // Just under B so that the largest centroid lands in the last bin; a flat axis puts
        // everything in bin 0, which never splits.
        let scale = Vec4::select(
            half_extent.cmpgt(Vec4::ZERO),
            Vec4::splat(B as f32 * 0.5 * 0.999_99) / half_extent,
            Vec4::ZERO,
        );
        Self {
            origin: cent.lo,
            scale,
        }
    }

    /// The bin on each axis (lanes x, y, z). NaN (∞ · 0 on a flat axis) lands in bin 0.
    #[inline(always)]
    fn bins(&self, p: &Ref) -> [usize; 3] {
        // max returns its second operand for NaN (SSE's rule, and f32::max's): NaN -> 0.
        let x = ((p.centroid() - self.origin) * self.scale)
            .max(Vec4::ZERO)
            .min(Vec4::splat((B - 1) as f32));
        // In [0, B - 1]: truncation is exact, and with SSE2 one instruction (`as` would check
        // every lane for NaN and overflow).
        #[cfg(target_arch = "x86_64")]
        let k = {
            use std::arch::x86_64::{__m128i, _mm_cvttps_epi32};
            // SAFETY: SSE2 is part of x86-64.
            let k: __m128i = unsafe { _mm_cvttps_epi32(x.into()) };
            // SAFETY: __m128i and [i32; 4] have the same size; every bit pattern is valid.
            unsafe { std::mem::transmute::<__m128i, [i32; 4]>(k) }
        };
        #[cfg(not(target_arch = "x86_64"))]
        let k = x.to_array().map(|v| v as i32);
        [k[0] as usize, k[1] as usize, k[2] as usize]
    }
}

/// Bounds and primitive counts by axis and bin.
#[derive(Clone)]
struct Bins<const B: usize> {
    boxes: [[Box3; B]; 3],
    counts: [[u32; B]; 3],
}

impl<const B: usize> Bins<B> {
    fn new() -> Self {
        Self {
            boxes: [[Box3::EMPTY; B]; 3],
            counts: [[0; B]; 3],
        }
    }

    fn add(mut self, refs: &[Ref], binner: &Binner<B>) -> Self {
        if refs.len() < 256 {
            self.add_each(refs, binner);
            return self;
        }
        // Neighbouring primitives often share a bin: alternating two sets of bins halves the
        // chains of dependent loads and stores through one bin.
        let pairs = refs.chunks_exact(2);
        let rest = pairs.remainder();
        let mut odd = Self::new();
        for pair in pairs {
            self.add_each(&pair[..1], binner);
            odd.add_each(&pair[1..], binner);
        }
        self.add_each(rest, binner);
        self.merge(odd)
    }

    #[inline(always)]
    fn add_each(&mut self, refs: &[Ref], binner: &Binner<B>) {
        for p in refs {
            for (axis, &k) in binner.bins(p).iter().enumerate() {
                let k = k.min(B - 1);
                self.boxes[axis][k].grow(p.lo(), p.hi);
                self.counts[axis][k] += 1;
            }
        }
    }

    fn merge(mut self, o: Self) -> Self {
        for axis in 0..3 {
            for k in 0..B {
                self.boxes[axis][k] = self.boxes[axis][k].union(&o.boxes[axis][k]);
                self.counts[axis][k] += o.counts[axis][k];
            }
        }
        self
    }

    /// The split of least SAH cost as (axis, first bin of the right side), if any split has
    /// primitives on both sides. Among equal costs (primitives on a line have no area) the
    /// most balanced wins, then the lowest axis, then the lowest bin.
    fn best(&self) -> Option<(usize, usize)> {
        let blocks = |n: u32| f64::from(n.div_ceil(MAX_LEAF));
        let mut best = None;
        let mut best_cost = (f64::INFINITY, u32::MAX);
        for axis in 0..3 {
            let (boxes, counts) = (&self.boxes[axis], &self.counts[axis]);
            // Right side of each split k (bins k..), accumulated from the right.
            let mut right_cost = [0.0f64; B];
            let mut right_n = [0u32; B];
            let (mut b, mut n) = (Box3::EMPTY, 0);
            for k in (1..B).rev() {
                b = b.union(&boxes[k]);
                n += counts[k];
                right_cost[k] = b.half_area() * blocks(n);
                right_n[k] = n;
            }
            let (mut b, mut n) = (Box3::EMPTY, 0);
            for k in 1..B {
                b = b.union(&boxes[k - 1]);
                n += counts[k - 1];
                if n == 0 || right_n[k] == 0 {
                    continue;
                }
                let cost = (
                    b.half_area() * blocks(n) + right_cost[k],
                    n.abs_diff(right_n[k]),
                );
                if cost < best_cost {
                    best_cost = cost;
                    best = Some((axis, k));
                }
            }
        }
        best
    }
}

/// Splits `refs` (the range `r`) in two by the best binned split, or in the middle of the
/// range when no split separates the centroids. Both sides are non-empty.
fn split(refs: &mut [Ref], r: &Range) -> (Range, Range) {
    debug_assert!(refs.len() >= 2);
    match bins_for(refs.len()) {
        32 => split_in::<32>(refs, r),
        16 => split_in::<16>(refs, r),
        _ => split_in::<8>(refs, r),
    }
}

/// [`split`] with `B` bins per axis.
fn split_in<const B: usize>(refs: &mut [Ref], r: &Range) -> (Range, Range) {
    let binner = Binner::<B>::new(&r.cent);
    let bins = if refs.len() > PAR_PRIMS {
        refs.par_chunks(CHUNK)
            .fold(Bins::new, |b, c| b.add(c, &binner))
            .reduce(Bins::new, Bins::merge)
    } else {
        Bins::new().add(refs, &binner)
    };
    let Some((axis, k)) = bins.best() else {
        return median(refs, r);
    };
    // Bin < k, computed on the split axis alone: the same operations as `Binner::bins`, and
    // for x ≥ 0 truncation below k means x below k (NaN goes to bin 0).
    let (origin, scale, kf, bit) = (
        binner.origin,
        binner.scale,
        Vec4::splat(k as f32),
        1 << axis,
    );
    let goes_left = |c: Vec4| ((c - origin) * scale).cmpge(kf).bitmask() & bit == 0;
    let left_n = bins.counts[axis][..k].iter().sum::<u32>() as usize;
    if left_n == 0 || left_n == refs.len() {
        // Cannot happen: `best` splits where both sides have primitives.
        return median(refs, r);
    }
    let Some((left_cent, right_cent)) = partition(refs, left_n, goes_left) else {
        // Cannot happen while the partition agrees with the bins.
        debug_assert!(false, "the partition disagrees with the bins");
        return median(refs, r);
    };
    // Each side's bounds are its bins' (the partition puts a primitive on the side its bin
    // is on: the same bins, so the same boxes to the bit).
    let boxes = &bins.boxes[axis];
    let union = |bins: &[Box3]| bins.iter().fold(Box3::EMPTY, |a, b| a.union(b));
    let left = Range {
        bounds: union(&boxes[..k]),
        cent: left_cent,
        start: r.start,
        end: r.start + left_n,
    };
    let right = Range {
        bounds: union(&boxes[k..]),
        cent: right_cent,
        start: left.end,
        end: r.end,
    };
    (left, right)
}

/// Primitives per block of [`partition`].
const BLOCK: usize = 64;

/// Moves the primitives whose centroid `goes_left` to the front, given how many do
/// (`left`), and returns the bounds of the centroids that go left and of those that do not;
/// `None` if the count was wrong (`refs` is then some permutation of itself).
///
/// The permutation is Hoare's: the k-th primitive from the front that goes right trades
/// places with the k-th from the back that goes left. It is found a block at a time without
/// a branch per primitive (Edelkamp and Weiß's BlockQuicksort, 2016): a block of the front
/// part (`..left`) records where its primitives that go right are, a block of the back part
/// where its primitives that go left are, and the two lists are swapped pairwise in order.
fn partition(
    refs: &mut [Ref],
    left: usize,
    goes_left: impl Fn(Vec4) -> bool,
) -> Option<(Box3, Box3)> {
    let n = refs.len();
    let (mut lc, mut rc) = (Box3::EMPTY, Box3::EMPTY);
    // Grows one side's centroid bounds without a branch (the other side's sees ±∞).
    let mut grow = |c: Vec4, l: bool| {
        let m = BVec4A::splat(l);
        lc.lo = lc.lo.min(Vec4::select(m, c, Vec4::INFINITY));
        lc.hi = lc.hi.max(Vec4::select(m, c, Vec4::NEG_INFINITY));
        rc.lo = rc.lo.min(Vec4::select(m, Vec4::INFINITY, c));
        rc.hi = rc.hi.max(Vec4::select(m, Vec4::NEG_INFINITY, c));
    };
    // Not yet scanned: [i, left) and [left, j). The front block starts at `fb`, its
    // misplaced primitives not yet swapped are at offsets `fo[fs..fe]`; the back block ends at
    // `bb`, with offsets (counted down from its end) `bo[bs..be]`.
    let (mut i, mut j, mut goers) = (0, n, 0);
    let (mut fo, mut fb, mut fs, mut fe) = ([0u8; BLOCK], 0, 0, 0);
    let (mut bo, mut bb, mut bs, mut be) = ([0u8; BLOCK], n, 0, 0);
    loop {
        if fs == fe && i < left {
            let len = BLOCK.min(left - i);
            (fb, fs, fe) = (i, 0, 0);
            for (t, p) in refs[i..i + len].iter().enumerate() {
                let c = p.centroid();
                let g = goes_left(c);
                grow(c, g);
                fo[fe] = t as u8;
                fe += usize::from(!g);
            }
            goers += len - fe;
            i += len;
        }
        if bs == be && j > left {
            let len = BLOCK.min(j - left);
            (bb, bs, be) = (j, 0, 0);
            for (t, p) in refs[j - len..j].iter().rev().enumerate() {
                let c = p.centroid();
                let g = goes_left(c);
                grow(c, g);
                bo[be] = t as u8;
                be += usize::from(g);
            }
            goers += be;
            j -= len;
        }
        let k = (fe - fs).min(be - bs);
        for q in 0..k {
            refs.swap(
                fb + usize::from(fo[fs + q]),
                bb - 1 - usize::from(bo[bs + q]),
            );
        }
        (fs, bs) = (fs + k, bs + k);
        let (front, back) = (fe - fs, be - bs);
        if front == 0 && back == 0 && i >= left && j <= left {
            break;
        }
        if (front > 0 && back == 0 && j <= left) || (back > 0 && front == 0 && i >= left) {
            return None; // misplaced primitives left on one side only: `left` was wrong
        }
    }
    (goers == left).then_some((lc, rc))
}

/// Splits `refs` (the range `r`) at its median centroid on the axis of largest centroid
/// extent (ties by input index, so the halves do not depend on the current order): for
/// ranges no binned split separates.
fn median(refs: &mut [Ref], r: &Range) -> (Range, Range) {
    let e = (r.cent.hi * 0.5 - r.cent.lo * 0.5).to_array();
    let axis = if e[0] >= e[1] && e[0] >= e[2] {
        0
    } else if e[1] >= e[2] {
        1
    } else {
        2
    };
    let mid = refs.len() / 2;
    refs.select_nth_unstable_by(mid, |a, b| {
        centroid_on(a, axis)
            .total_cmp(&centroid_on(b, axis))
            .then(a.id().cmp(&b.id()))
    });
    let (a, b) = refs.split_at(mid);
    (Range::of(a, r.start), Range::of(b, r.start + mid))
}

/// Nodes and leaves of a subtree: node 0 is its root; inner children index `nodes` (local to
/// the subtree until [`Sub::flatten`]), leaf children hold their first slot and count.
/// Subtrees built apart (in parallel) are kept aside, not copied into their parent's nodes, and
/// every node is copied once, by [`Sub::flatten`], into an array of the final size: appending
/// them level by level copied the nodes once per level and made the arrays grow (on a
/// 4-million-triangle mesh, the builder's page faults were about a third of the build).
#[derive(Default)]
struct Sub<const N: usize> {
    nodes: Vec<Node<N>>,
    leaves: Vec<(u32, u32)>,
    /// Subtrees built apart: the node (index in `nodes`) and lane they hang from.
    apart: Vec<(usize, usize, Sub<N>)>,
}

impl<const N: usize> Sub<N> {
    /// Nodes and leaves in this subtree and those built apart.
    fn sizes(&self) -> (usize, usize) {
        self.apart.iter().fold(
            (self.nodes.len(), self.leaves.len()),
            |(n, l), (_, _, s)| {
                let (sn, sl) = s.sizes();
                (n + sn, l + sl)
            },
        )
    }

    /// All the nodes in one array (each subtree contiguous, its nodes relocated), and the
    /// leaves (in no particular order). The subtrees built apart are placed in parallel, each
    /// into its own part of the array (their sizes are known), so the array's pages fault in
    /// and its nodes are copied on every thread.
    fn flatten(self) -> (Vec<Node<N>>, Vec<(u32, u32)>) {
        let (n, l) = self.sizes();
        let mut leaves = Vec::with_capacity(l);
        self.gather_leaves(&mut leaves);
        let mut nodes = crate::alloc::huge_vec(n);
        nodes.par_extend((0..n).into_par_iter().map(|_| Node::EMPTY));
        self.place(&mut nodes, 0);
        debug_assert_eq!(leaves.len(), l);
        (nodes, leaves)
    }

    /// Appends the leaves of this subtree and of those built apart.
    fn gather_leaves(&self, leaves: &mut Vec<(u32, u32)>) {
        leaves.extend_from_slice(&self.leaves);
        for (_, _, sub) in &self.apart {
            sub.gather_leaves(leaves);
        }
    }

    /// Writes this subtree's nodes (relocated to start at `base`) to the front of `out`,
    /// then the subtrees built apart after them, in order; `out` holds exactly this
    /// subtree's nodes and those built apart below it.
    fn place(self, out: &mut [Node<N>], base: u32) {
        let (mine, mut rest) = out.split_at_mut(self.nodes.len());
        for (slot, mut n) in mine.iter_mut().zip(self.nodes) {
            let mut inner = n.inner_mask;
            while inner != 0 {
                let lane = inner.trailing_zeros() as usize;
                inner &= inner - 1;
                n.child[lane] += base;
            }
            *slot = n;
        }
        let mut at = base + mine.len() as u32;
        let mut parts = Vec::with_capacity(self.apart.len());
        for (node, lane, sub) in self.apart {
            mine[node].child[lane] = at;
            let (part, tail) = std::mem::take(&mut rest).split_at_mut(sub.sizes().0);
            rest = tail;
            let size = part.len() as u32;
            parts.push((sub, part, at));
            at += size;
        }
        debug_assert!(rest.is_empty());
        parts
            .into_par_iter()
            .for_each(|(sub, part, base)| sub.place(part, base));
    }
}

/// Children of at most this many primitives that a node of `n` primitives does not open (0:
/// it opens any child too big for a leaf). 16-wide nodes keep a child of at most
/// `N · MAX_LEAF` primitives whole, to become one node of its own leaves, unless the node
/// itself is that small: opening the largest child until there are sixteen made most nodes
/// near the bottom hold a few leaves in sixteen lanes (on a 1 M-triangle mesh 72 021 nodes of
/// 512 bytes, 39.1 MB, against 29 556 and 17.4 MB so, with the same expected node tests per
/// ray by the SAH and rays as fast). The leaves do not change: every range is split by the
/// same rule whichever node splits it, so neither do the slot order and the images. 4- and
/// 8-wide nodes open as before (measured with that rule).
fn keep_whole<const N: usize>(n: usize) -> usize {
    let whole = N * MAX_LEAF as usize;
    if N >= 16 && n > whole {
        whole
    } else {
        0
    }
}

/// Builds the node of range `r` (whose references are `refs`) into `out`; returns its index.
fn build_node<const N: usize>(refs: &mut [Ref], r: Range, out: &mut Sub<N>) -> u32 {
    let offset = r.start;
    // The children: split the one of largest surface area that is too big for a leaf (and
    // not kept whole, see `keep_whole`; the node's own range is always split) until there are
    // N (ties: the first).
    let mut kids = [r; N];
    let mut len = 1;
    let keep = keep_whole::<N>(r.len());
    while len < N {
        let open = (0..len)
            .filter(|&i| kids[i].len() > MAX_LEAF as usize && (len == 1 || kids[i].len() > keep))
            .fold(None, |best: Option<usize>, i| match best {
                Some(b) if kids[b].bounds.half_area() >= kids[i].bounds.half_area() => Some(b),
                _ => Some(i),
            });
        let Some(i) = open else { break };
        let k = kids[i];
        let (a, b) = split(&mut refs[k.start - offset..k.end - offset], &k);
        kids.copy_within(i + 1..len, i + 2);
        kids[i] = a;
        kids[i + 1] = b;
        len += 1;
    }
    let index = out.nodes.len();
    out.nodes.push(Node::EMPTY);
    let mut node = Node::<N>::EMPTY;
    for (lane, k) in kids[..len].iter().enumerate() {
        let (lo, hi) = (k.bounds.lo.to_array(), k.bounds.hi.to_array());
        for axis in 0..3 {
            node.bounds[2 * axis][lane] = lo[axis];
            node.bounds[2 * axis + 1][lane] = hi[axis];
        }
    }
    // The inner children's references, each its own slice (disjoint, in lane order).
    let mut rest = refs;
    let mut at = offset;
    let mut slices: [Option<&mut [Ref]>; N] = std::array::from_fn(|_| None);
    let (mut inner, mut inner_prims) = (0, 0);
    for (lane, k) in kids[..len].iter().enumerate() {
        let (skip, tail) = std::mem::take(&mut rest).split_at_mut(k.start - at);
        debug_assert!(skip.is_empty());
        let (mine, tail) = tail.split_at_mut(k.len());
        rest = tail;
        at = k.end;
        if k.len() > MAX_LEAF as usize {
            slices[lane] = Some(mine);
            inner += 1;
            inner_prims += k.len();
        }
    }
    // Subtrees built in parallel each into their own nodes, kept aside (`Sub::apart`) and
    // placed after this subtree's nodes by `Sub::flatten`; whether a subtree is built apart
    // depends on sizes alone, so the arrays do not depend on the number of threads.
    let mut subs: [Option<Sub<N>>; N] = std::array::from_fn(|_| None);
    if inner > 1 && inner_prims > PAR_PRIMS {
        let jobs: Vec<(usize, &mut [Ref])> = slices
            .iter_mut()
            .enumerate()
            .filter_map(|(lane, s)| s.take().map(|s| (lane, s)))
            .collect();
        let built: Vec<(usize, Sub<N>)> = jobs
            .into_par_iter()
            .map(|(lane, refs)| {
                let mut s = Sub::default();
                build_node(refs, kids[lane], &mut s);
                (lane, s)
            })
            .collect();
        for (lane, s) in built {
            subs[lane] = Some(s);
        }
    }
    for (lane, k) in kids[..len].iter().enumerate() {
        if k.len() <= MAX_LEAF as usize {
            node.child[lane] = k.start as u32;
            node.count[lane] = k.len() as u8;
            node.leaf_mask |= 1 << lane;
            out.leaves.push((k.start as u32, k.len() as u32));
            continue;
        }
        node.child[lane] = match (subs[lane].take(), slices[lane].take()) {
            (Some(sub), _) => {
                out.apart.push((index, lane, sub));
                0 // set when the subtree is placed
            }
            (None, Some(refs)) => build_node(refs, *k, out),
            (None, None) => unreachable!("every inner child is built once"),
        };
        node.inner_mask |= 1 << lane;
    }
    out.nodes[index] = node;
    index as u32
}

/// Builds `N`-wide nodes over `bounds`: (nodes, leaves as (first slot, count) in slot order,
/// slot order as input indices). `bounds` must not be empty.
pub(super) fn build<const N: usize>(
    bounds: Vec<Aabb>,
) -> (Vec<Node<N>>, Vec<(u32, u32)>, Vec<u32>) {
    assert!(
        bounds.len() < u32::MAX as usize,
        "a BVH holds fewer than 2^32 primitives"
    );
    // In place: Aabb and Ref have the same size and alignment.
    let mut refs: Vec<Ref> = bounds
        .into_iter()
        .enumerate()
        .map(|(i, b)| {
            // A box with a NaN (a primitive with a NaN corner, which nothing hits) becomes a
            // point at the origin: NaN would make min and max depend on operand order, and
            // so the tree on how bins were merged.
            let (lo, hi) = if b.min.is_nan() || b.max.is_nan() {
                (Vec4::ZERO, Vec4::ZERO)
            } else {
                (b.min.extend(0.0), b.max.extend(0.0))
            };
            Ref {
                lo: lo.with_w(f32::from_bits(i as u32)),
                hi,
            }
        })
        .collect();
    let root = if refs.len() > PAR_PRIMS {
        refs.par_chunks(CHUNK).map(|c| Range::of(c, 0)).reduce(
            || Range::of(&[], 0),
            |a, b| Range {
                bounds: a.bounds.union(&b.bounds),
                cent: a.cent.union(&b.cent),
                start: 0,
                end: 0,
            },
        )
    } else {
        Range::of(&refs, 0)
    };
    let root = Range {
        start: 0,
        end: refs.len(),
        ..root
    };
    let mut out = Sub::default();
    build_node(&mut refs, root, &mut out);
    let order = refs.iter().map(Ref::id).collect();
    drop(refs);
    let (nodes, mut leaves) = out.flatten();
    leaves.par_sort_unstable();
    (nodes, leaves, order)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hoare's partition, one primitive at a time, with a branch on each primitive's side:
    /// (how many go left, their centroids' bounds, the others').
    fn hoare(refs: &mut [Ref], goes_left: impl Fn(Vec4) -> bool) -> (usize, Box3, Box3) {
        let (mut l, mut r) = (Box3::EMPTY, Box3::EMPTY);
        let (mut i, mut j) = (0, refs.len());
        loop {
            while i < j && goes_left(refs[i].centroid()) {
                let c = refs[i].centroid();
                l.grow(c, c);
                i += 1;
            }
            while i < j && !goes_left(refs[j - 1].centroid()) {
                let c = refs[j - 1].centroid();
                r.grow(c, c);
                j -= 1;
            }
            if i >= j {
                break;
            }
            refs.swap(i, j - 1);
        }
        (i, l, r)
    }

    /// The block partition makes Hoare's permutation and centroid bounds, on both sides of
    /// every block size, and reports a wrong count instead of looping on it.
    #[test]
    fn block_partition_is_hoares() {
        let mut seed = 1u32;
        let mut rnd = move || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) as f32 / (1 << 24) as f32
        };
        let sizes = [
            0,
            1,
            2,
            5,
            BLOCK - 1,
            BLOCK,
            BLOCK + 1,
            2 * BLOCK + 1,
            1000,
            4097,
        ];
        for n in sizes {
            let refs: Vec<Ref> = (0..n as u32)
                .map(|i| {
                    let lo = Vec4::new(rnd(), rnd(), rnd(), 0.0);
                    Ref {
                        lo: lo.with_w(f32::from_bits(i)),
                        hi: lo + Vec4::new(0.01, 0.02, 0.03, 0.0),
                    }
                })
                .collect();
            for cut in [0.0, 0.1, 0.5, 0.9, 2.0] {
                let goes_left = |c: Vec4| c.y < cut;
                let (mut a, mut b) = (refs.clone(), refs.clone());
                let (left, lc, rc) = hoare(&mut a, goes_left);
                let got = partition(&mut b, left, goes_left);
                let ids = |v: &[Ref]| v.iter().map(Ref::id).collect::<Vec<_>>();
                assert_eq!(ids(&a), ids(&b), "{n} primitives, cut {cut}");
                assert_eq!(got, Some((lc, rc)), "{n} primitives, cut {cut}");
                for wrong in [left.wrapping_sub(1), left + 1] {
                    if wrong <= n {
                        let got = partition(&mut refs.clone(), wrong, goes_left);
                        assert_eq!(got, None, "{n} primitives, cut {cut}, told {wrong}");
                    }
                }
            }
        }
    }
}
