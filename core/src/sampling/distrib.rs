//! Piecewise-constant distributions for importance sampling (light selection, environment maps,
//! pixel filters).

use glam::Vec2;

/// A discrete/piecewise-constant 1D distribution over [0, 1) with `n` equal bins.
#[derive(Clone, Debug, Default)]
pub struct Distribution1D {
    func: Vec<f32>,
    cdf: Vec<f32>,
    integral: f32,
    /// Whether some bin has probability zero (then a search must step over it).
    zero_bins: bool,
}

impl Distribution1D {
    /// From non-negative bin weights. All-zero or non-finite weights become uniform.
    pub fn new(weights: &[f32]) -> Self {
        let n = weights.len().max(1);
        let mut func: Vec<f32> = weights
            .iter()
            .map(|&w| if w.is_finite() && w > 0.0 { w } else { 0.0 })
            .collect();
        if func.is_empty() {
            func.push(1.0);
        }
        let mut cdf = Vec::with_capacity(n + 1);
        cdf.push(0.0f32);
        let mut acc = 0.0f64;
        for &f in &func {
            acc += f as f64 / n as f64;
            cdf.push(acc as f32);
        }
        let mut integral = acc as f32;
        if integral <= 0.0 {
            func.iter_mut().for_each(|f| *f = 1.0);
            for (i, c) in cdf.iter_mut().enumerate() {
                *c = i as f32 / n as f32;
            }
            integral = 1.0;
        } else {
            cdf.iter_mut().for_each(|c| *c /= integral);
        }
        *cdf.last_mut().unwrap() = 1.0;
        let zero_bins = cdf.windows(2).any(|w| w[1] <= w[0]);
        Self {
            func,
            cdf,
            integral,
            zero_bins,
        }
    }

    /// Number of bins.
    pub fn len(&self) -> usize {
        self.func.len()
    }

    /// Whether there are no bins (never true: an empty input becomes one bin).
    pub fn is_empty(&self) -> bool {
        self.func.is_empty()
    }

    /// The integral of the (un-normalised) function over [0, 1).
    pub fn integral(&self) -> f32 {
        self.integral
    }

    /// Bytes held by the tables, for cache budgets.
    pub fn memory_bytes(&self) -> usize {
        (self.func.capacity() + self.cdf.capacity()) * std::mem::size_of::<f32>()
    }

    /// Picks bin `i` with probability weight_i / Σ weight; returns (i, probability, u remapped
    /// to [0, 1) within the bin for reuse).
    #[inline]
    pub fn sample_discrete(&self, u: f32) -> (usize, f32, f32) {
        let i = self.find(u);
        let (lo, hi) = (self.cdf[i], self.cdf[i + 1]);
        let p = hi - lo;
        let rem = if p > 0.0 {
            ((u - lo) / p).clamp(0.0, 1.0 - f32::EPSILON)
        } else {
            0.0
        };
        (i, p, rem)
    }

    /// [`Self::sample_discrete`] for a `u` from the samplers, refined below their grid by
    /// `jitter` ∈ [0, 1): the bin is picked by u' = u + jitter · 2^-23 (in f64; Sobol numbers
    /// lie on a 2^-23 grid, hashed ones on 2^-24, and a u' past 1 wraps to the start, which
    /// keeps u' uniform on either grid) and the remapped number keeps that precision. A bin of
    /// probability p otherwise sees only about p · 2^23 distinct remapped numbers (a few for a
    /// light among a million), which would confine its samples to a few lines. A Sobol u' stays
    /// in u's grid cell, so a stratified u stays stratified. Same bits on every CPU (f64
    /// arithmetic is exactly rounded).
    #[inline]
    pub fn sample_discrete_fine(&self, u: f32, jitter: f32) -> (usize, f32, f32) {
        let mut u = u as f64 + jitter as f64 * (1.0 / (1u64 << 23) as f64);
        if u >= 1.0 {
            u -= 1.0;
        }
        if !(0.0..1.0).contains(&u) {
            u = 0.0;
        }
        // The bin is the count of inner bounds <= u: then cdf[i] <= u < cdf[i + 1], so it is
        // never a zero-probability bin. Counted without branches for short tables, as `find`.
        let n = self.func.len();
        let inner = &self.cdf[1..n];
        let i = if inner.len() <= 16 {
            inner.iter().map(|&c| usize::from(c as f64 <= u)).sum()
        } else {
            inner.partition_point(|&c| c as f64 <= u)
        };
        let (lo, hi) = (self.cdf[i], self.cdf[i + 1]);
        let rem = (u - lo as f64) / (hi as f64 - lo as f64);
        (i, hi - lo, (rem as f32).clamp(0.0, 1.0 - f32::EPSILON))
    }

    /// Probability of bin `i` under [`Self::sample_discrete`].
    #[inline]
    pub fn discrete_pdf(&self, i: usize) -> f32 {
        self.cdf.get(i + 1).copied().unwrap_or(0.0) - self.cdf.get(i).copied().unwrap_or(0.0)
    }

    /// A continuous sample x ∈ [0, 1) with density pdf(x) = func(x)/integral; returns (x, pdf, bin).
    #[inline]
    pub fn sample_continuous(&self, u: f32) -> (f32, f32, usize) {
        let (i, p, rem) = self.sample_discrete(u);
        let n = self.func.len() as f32;
        let x = ((i as f32 + rem) / n).min(1.0 - f32::EPSILON);
        (x, p * n, i)
    }

    /// Density of [`Self::sample_continuous`] at x.
    #[inline]
    pub fn pdf(&self, x: f32) -> f32 {
        let n = self.func.len();
        let i = ((x * n as f32) as usize).min(n - 1);
        self.discrete_pdf(i) * n as f32
    }

    fn find(&self, u: f32) -> usize {
        // Largest i with cdf[i] <= u, within [0, n-1]; skips zero-probability bins.
        let n = self.func.len();
        // The cdf is sorted, so the count of entries <= u is the partition point. Counting
        // is branch-free, which pays for the few lights of most scenes (a binary search
        // mispredicts about half its branches on random u); long tables are searched.
        let idx = if self.cdf.len() <= 16 {
            self.cdf.iter().map(|&c| usize::from(c <= u)).sum()
        } else {
            self.cdf.partition_point(|&c| c <= u)
        };
        let mut i = idx.saturating_sub(1).min(n - 1);
        if !self.zero_bins {
            return i;
        }
        while i + 1 < n && self.cdf[i + 1] <= self.cdf[i] {
            i += 1;
        }
        while i > 0 && self.cdf[i + 1] <= self.cdf[i] {
            i -= 1;
        }
        i
    }
}

/// A piecewise-constant 2D distribution over [0, 1)² (rows: v, columns: u).
#[derive(Clone, Debug, Default)]
pub struct Distribution2D {
    conditional: Vec<Distribution1D>,
    marginal: Distribution1D,
}

impl Distribution2D {
    /// Bytes held by the tables, for cache budgets.
    pub fn memory_bytes(&self) -> usize {
        self.marginal.memory_bytes()
            + self
                .conditional
                .iter()
                .map(|d| d.memory_bytes() + std::mem::size_of::<Distribution1D>())
                .sum::<usize>()
    }

    /// From a row-major `width × height` table of non-negative weights.
    pub fn new(weights: &[f32], width: usize, height: usize) -> Self {
        let conditional: Vec<_> = weights
            .chunks(width.max(1))
            .take(height)
            .map(Distribution1D::new)
            .collect();
        let row_weights: Vec<f32> = conditional.iter().map(|d| d.integral()).collect();
        Self {
            marginal: Distribution1D::new(&row_weights),
            conditional,
        }
    }

    /// A point with density `pdf` (with respect to area in [0,1)²).
    #[inline]
    pub fn sample(&self, u: Vec2) -> (Vec2, f32) {
        let (v, pv, row) = self.marginal.sample_continuous(u.y);
        let (x, pu, _) = self.conditional[row].sample_continuous(u.x);
        (Vec2::new(x, v), pu * pv)
    }

    /// Density at `p`.
    #[inline]
    pub fn pdf(&self, p: Vec2) -> f32 {
        let h = self.conditional.len();
        let row = ((p.y * h as f32) as usize).min(h - 1);
        self.marginal.pdf(p.y) * self.conditional[row].pdf(p.x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refined_choice_is_exact_and_gives_a_tiny_bin_a_continuum() {
        // Bin 2 holds 1.6e-7 of the mass, between empty bins (one below 0.5, where the f32 cdf
        // is finer than the samplers' grids): on the Sobol grid (2^-23) alone it is picked by
        // one or two numbers (three on the hashed numbers' 2^-24), and its remapped numbers would
        // take as many values.
        let d = Distribution1D::new(&[1.0, 0.0, 4.8e-7, 0.0, 1.0, 1.0]);
        let (lo, hi) = (d.cdf[2], d.cdf[3]);
        assert!(lo > 0.0 && hi > lo && hi < 0.5);
        let jitters = 256;
        // Sobol numbers (2^-23) and hashed ones (2^-24).
        for bits in [23, 24] {
            let grid = 1.0 / (1u32 << bits) as f64;
            let (mut picks, mut rems, mut coarse) = (0usize, Vec::new(), Vec::new());
            let first = (lo as f64 / grid).floor() as u32 - 2;
            for k in first..first + 8 {
                let u = (k as f64 * grid) as f32;
                if let (2, _, rem) = d.sample_discrete(u) {
                    coarse.push(rem);
                }
                for j in 0..jitters {
                    let jitter = (j as f32 + 0.5) / jitters as f32;
                    let (i, p, rem) = d.sample_discrete_fine(u, jitter);
                    assert_eq!(p, d.discrete_pdf(i));
                    assert!(p > 0.0, "u {u} jitter {jitter}: empty bin {i}");
                    assert!((0.0..1.0).contains(&rem));
                    if i == 2 {
                        picks += 1;
                        rems.push(rem);
                    }
                }
            }
            // The refined numbers sweep the grid steps around the bin evenly (each 2^-23 wide,
            // so on the finer grid every point is swept twice), so the bin is picked in
            // proportion to its probability, to within the numbers its ends cut.
            let sweeps = (1.0 / (1u32 << 23) as f64) / grid;
            let step = (1.0 / (1u32 << 23) as f64) / jitters as f64;
            let expected = (hi - lo) as f64 / step * sweeps;
            assert!(
                (picks as f64 - expected).abs() <= 2.0 * sweeps,
                "2^-{bits} grid: {picks} picks, {expected} expected"
            );
            assert!(coarse.len() <= 3, "{coarse:?}");
            // The picks spread evenly over [0, 1) (on the finer grid, two sweeps land alike).
            rems.sort_by(f32::total_cmp);
            let gap = rems.windows(2).map(|w| w[1] - w[0]).fold(rems[0], f32::max);
            let gap = gap.max(1.0 - rems[rems.len() - 1]);
            assert!(
                gap < 2.0 * sweeps as f32 / picks as f32,
                "2^-{bits} grid: gap {gap}, {picks} picks"
            );
        }
        // Where a bin is wide, the refinement moves the remapped number by a grid step of it at
        // most, and never across bins.
        for k in 0..1000 {
            let u = (k as f32 * 8_388.0).floor() / (1u32 << 23) as f32;
            let (i0, p0, r0) = d.sample_discrete(u);
            let (i1, p1, r1) = d.sample_discrete_fine(u, 0.0);
            assert_eq!((i0, p0), (i1, p1), "u {u}");
            assert!((r0 - r1).abs() <= 4.0 * f32::EPSILON, "{r0} {r1}");
        }
        // A hashed number's refinement past 1 wraps to the first bin; numbers stay below 1.
        let last = 1.0 - 1.0 / (1u32 << 24) as f32;
        assert_eq!(d.sample_discrete_fine(last, 0.75).0, 0);
        let (i, _, rem) = d.sample_discrete_fine(last, 0.25);
        assert_eq!(i, 5);
        assert!(rem < 1.0);
        // Out of range or NaN input picks a bin with probability, never an empty one.
        for u in [f32::NAN, -1.0, 2.0] {
            assert!(d.sample_discrete_fine(u, 0.5).1 > 0.0);
        }
    }

    #[test]
    fn discrete_probabilities_match_weights() {
        let d = Distribution1D::new(&[1.0, 0.0, 3.0]);
        assert!((d.discrete_pdf(0) - 0.25).abs() < 1e-6);
        assert_eq!(d.discrete_pdf(1), 0.0);
        assert!((d.discrete_pdf(2) - 0.75).abs() < 1e-6);
        for i in 0..100 {
            let (bin, p, rem) = d.sample_discrete(i as f32 / 100.0);
            assert_ne!(bin, 1, "zero-weight bin must never be chosen");
            assert!(p > 0.0 && (0.0..1.0).contains(&rem));
        }
    }

    #[test]
    fn counting_search_equals_binary_search() {
        // Short tables count, long ones search: both must pick the same bins, zero bins and
        // all, including u exactly on a cdf step.
        let weights = [
            0.0, 2.0, 0.0, 0.0, 1.0, 3.0, 0.0, 0.5, 1.0, 0.0, 4.0, 2.0, 0.0, 1.0,
        ];
        for n in 1..=weights.len() {
            let d = Distribution1D::new(&weights[..n]);
            let mut steps: Vec<f32> = d.cdf.clone();
            steps.extend((0..1000).map(|i| i as f32 / 1000.0));
            for u in steps.into_iter().filter(|u| (0.0..1.0).contains(u)) {
                let i = d.find(u);
                let idx = d.cdf.partition_point(|&c| c <= u);
                let mut j = idx.saturating_sub(1).min(d.len() - 1);
                while j + 1 < d.len() && d.cdf[j + 1] <= d.cdf[j] {
                    j += 1;
                }
                while j > 0 && d.cdf[j + 1] <= d.cdf[j] {
                    j -= 1;
                }
                assert_eq!(i, j, "n {n}, u {u}");
            }
        }
    }

    #[test]
    fn continuous_pdf_integrates_to_one() {
        let d = Distribution2D::new(&[1.0, 2.0, 0.0, 5.0, 1.0, 1.0], 3, 2);
        let n = 300;
        let mut sum = 0.0;
        for j in 0..n {
            for i in 0..n {
                sum += d.pdf(Vec2::new(
                    (i as f32 + 0.5) / n as f32,
                    (j as f32 + 0.5) / n as f32,
                ));
            }
        }
        assert!((sum / (n * n) as f32 - 1.0).abs() < 1e-3);
        let (p, pdf) = d.sample(Vec2::new(0.3, 0.7));
        assert!((pdf - d.pdf(p)).abs() < 1e-4 * pdf);
    }
}
