//! A binned-SAH builder that makes wide nodes directly (Wald's binning, 2007; the top-down
//! wide build of Embree's `BVHBuilderBinnedSAH`): a node takes its primitive range, splits it
//! at the surface-area heuristic's best of 32 bins per axis, and keeps splitting the child with
//! the largest surface area until it has `N` children (the same rule [`super::collapse`]
//! applies to a binary tree). A leaf holds at most [`MAX_LEAF`] primitives, and the heuristic
//! counts a leaf's cost by 4-wide packets (`⌈n / 4⌉`, Embree's block size), so full leaves cost
//! what a single triangle does.
//!
//! Memory: one 32-byte reference per primitive, made in place from the caller's bounds (the
//! same allocation), and the nodes; no binary tree. Time: subtrees of more than [`PAR_PRIMS`]
//! primitives are built in parallel (rayon) and binned in parallel chunks; each returns its own
//! nodes, which the parent relocates once.
//!
//! Deterministic: every decision depends on the primitives' bounds and input order alone
//! (bins merge by min, max and integer counts, which do not depend on how chunks are split
//! between threads; ties go to the lowest axis and bin), so the tree is the same bits on one
//! thread or many, on every CPU.

use super::{Node, MAX_LEAF};
use crate::geometry::Aabb;
use glam::Vec4;
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

/// A primitive's bounds; the w lane of `lo` holds its input index (its bits), that of `hi` is
/// unused. The same size and alignment as [`Aabb`], so the references are made in place.
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

    /// Twice the centroid (the factor is the same everywhere, so it is left out).
    #[inline(always)]
    fn centroid(&self) -> Vec4 {
        self.lo + self.hi
    }
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

    /// Half the surface area (0 for an empty box).
    #[inline(always)]
    fn half_area(&self) -> f32 {
        let e = (self.hi - self.lo).max(Vec4::ZERO);
        e.x * e.y + e.y * e.z + e.z * e.x
    }
}

/// A primitive range being built: its bounds, the bounds of its (doubled) centroids, and
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
        self.bounds.grow(p.lo, p.hi);
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
        let extent = cent.hi - cent.lo;
        // Just under B so that the largest centroid lands in the last bin; a flat axis
        // (or a non-finite extent) puts everything in bin 0, which never splits.
        let scale = Vec4::select(
            extent.cmpgt(Vec4::ZERO) & extent.cmplt(Vec4::splat(f32::INFINITY)),
            Vec4::splat(B as f32 * 0.999_99) / extent,
            Vec4::ZERO,
        );
        Self {
            origin: cent.lo,
            scale,
        }
    }

    /// The bin on each axis (lanes x, y, z). NaN lands in bin 0.
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
                self.boxes[axis][k].grow(p.lo, p.hi);
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
    /// primitives on both sides. Ties go to the lowest axis, then the lowest bin.
    fn best(&self) -> Option<(usize, usize)> {
        let blocks = |n: u32| n.div_ceil(MAX_LEAF) as f32;
        let mut best = None;
        let mut best_cost = f32::INFINITY;
        for axis in 0..3 {
            let (boxes, counts) = (&self.boxes[axis], &self.counts[axis]);
            // Right side of each split k (bins k..), accumulated from the right.
            let mut right_cost = [0.0f32; B];
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
                let cost = b.half_area() * blocks(n) + right_cost[k];
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
        let mid = refs.len() / 2;
        let (a, b) = refs.split_at(mid);
        return (Range::of(a, r.start), Range::of(b, r.start + mid));
    };
    // Bin < k, computed on the split axis alone: the same sum, difference and product as
    // `Binner::bins`, and for x ≥ 0 truncation below k means x below k (NaN goes to bin 0).
    let (o, sc, kf) = (binner.origin[axis], binner.scale[axis], k as f32);
    let goes_left = |p: &Ref| !(((p.lo[axis] + p.hi[axis]) - o) * sc >= kf);
    let mut left = Range {
        bounds: Box3::EMPTY,
        cent: Box3::EMPTY,
        start: r.start,
        end: r.start,
    };
    let mut right = Range { end: r.end, ..left };
    let (mut i, mut j) = (0, refs.len());
    loop {
        while i < j && goes_left(&refs[i]) {
            left.add(&refs[i]);
            i += 1;
        }
        while i < j && !goes_left(&refs[j - 1]) {
            right.add(&refs[j - 1]);
            j -= 1;
        }
        if i >= j {
            break;
        }
        refs.swap(i, j - 1);
    }
    left.end = r.start + i;
    right.start = left.end;
    debug_assert_eq!(
        i as u32,
        bins.counts[axis][..k].iter().sum::<u32>(),
        "the partition disagrees with the bins"
    );
    (left, right)
}

/// Nodes and leaves of a subtree: node 0 is its root; inner children index `nodes`, leaf
/// children index `leaves` (both local to the subtree until relocated), leaves in slot order.
struct Sub<const N: usize> {
    nodes: Vec<Node<N>>,
    leaves: Vec<(u32, u32)>,
}

impl<const N: usize> Sub<N> {
    /// Appends `o`, relocating its children; returns the index of its root.
    fn append(&mut self, o: Sub<N>) -> u32 {
        let (base, leaf_base) = (self.nodes.len() as u32, self.leaves.len() as u32);
        self.nodes.extend(o.nodes.into_iter().map(|mut n| {
            for lane in 0..N {
                if (n.inner_mask >> lane) & 1 == 1 {
                    n.child[lane] += base;
                } else if (n.leaf_mask >> lane) & 1 == 1 {
                    n.child[lane] += leaf_base;
                }
            }
            n
        }));
        self.leaves.extend(o.leaves);
        base
    }
}

/// Builds the node of range `r` (whose references are `refs`) into `out`; returns its index.
fn build_node<const N: usize>(refs: &mut [Ref], r: Range, out: &mut Sub<N>) -> u32 {
    let offset = r.start;
    // The children: split the one of largest surface area that is too big for a leaf until
    // there are N (ties: the first).
    let mut kids = [r; N];
    let mut len = 1;
    while len < N {
        let open = (0..len)
            .filter(|&i| kids[i].len() > MAX_LEAF as usize)
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
    let mut inner: Vec<(usize, &mut [Ref], Range)> = Vec::new();
    for (lane, k) in kids[..len].iter().enumerate() {
        let (skip, tail) = std::mem::take(&mut rest).split_at_mut(k.start - at);
        debug_assert!(skip.is_empty());
        let (mine, tail) = tail.split_at_mut(k.len());
        rest = tail;
        at = k.end;
        if k.len() > MAX_LEAF as usize {
            inner.push((lane, mine, *k));
        }
    }
    let parallel = inner.iter().filter(|c| c.2.len() > PAR_PRIMS).count() > 1;
    let mut subs: Vec<Option<Sub<N>>> = if parallel {
        inner
            .par_iter_mut()
            .map(|(_, refs, k)| {
                let mut s = Sub {
                    nodes: Vec::new(),
                    leaves: Vec::new(),
                };
                build_node(refs, *k, &mut s);
                Some(s)
            })
            .collect()
    } else {
        Vec::new()
    };
    let mut next = 0;
    for (lane, k) in kids[..len].iter().enumerate() {
        if k.len() <= MAX_LEAF as usize {
            node.child[lane] = out.leaves.len() as u32;
            node.leaf_mask |= 1 << lane;
            out.leaves.push((k.start as u32, k.len() as u32));
            continue;
        }
        let (l, refs, k) = &mut inner[next];
        debug_assert_eq!(*l, lane);
        node.child[lane] = if parallel {
            out.append(subs[next].take().expect("each subtree is appended once"))
        } else {
            build_node(refs, *k, out)
        };
        node.inner_mask |= 1 << lane;
        next += 1;
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
            let (lo, hi) = if (b.min + b.max).is_nan() {
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
    let mut out = Sub {
        nodes: Vec::new(),
        leaves: Vec::new(),
    };
    build_node(&mut refs, root, &mut out);
    let order = refs.iter().map(Ref::id).collect();
    drop(refs);
    out.nodes.shrink_to_fit();
    out.leaves.shrink_to_fit();
    (out.nodes, out.leaves, order)
}
