//! Majorants: upper bounds of σt along a ray, piece by piece (pbrt-v4's `MajorantGrid`,
//! `DDAMajorantIterator` and `HomogeneousMajorantIterator`).
//!
//! Delta and ratio tracking sample tentative collisions with a majorant σ_maj ≥ σt and reject
//! the null ones; the tighter the majorant, the fewer null collisions. A heterogeneous medium
//! keeps a coarse grid of the largest density per cell and walks the cells a ray crosses with a
//! 3D DDA, so that empty cells cost one step and thin ones few collisions.

use super::grid::DensityGrid;
use glam::Vec3A;

/// A stretch `t_min..t_max` of a ray over which σt ≤ `sigma_maj` (per channel, per unit of the
/// ray parameter, which is distance: the tracking code walks unit-length directions).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MajorantSegment {
    /// Start of the stretch.
    pub t_min: f32,
    /// End of the stretch (≥ `t_min`; may be infinite for a homogeneous medium).
    pub t_max: f32,
    /// The majorant per colour channel (0 over empty space).
    pub sigma_maj: Vec3A,
}

/// Default number of majorant cells per axis (pbrt-v4's choice).
pub const DEFAULT_MAJORANT_RES: usize = 16;

/// The largest density of a [`DensityGrid`] over each cell of a coarse grid spanning the same
/// box, counting every voxel whose trilinear support reaches into the cell: the density is at
/// most the cell's value everywhere in it. Stored x fastest, like the density.
#[derive(Clone, Debug, PartialEq)]
pub struct MajorantGrid {
    res: [usize; 3],
    /// Shared, like the density's voxels.
    max: std::sync::Arc<[f32]>,
}

impl MajorantGrid {
    /// The majorant grid of `density` with `res` cells per axis (each at least 1).
    pub fn new(density: &DensityGrid, res: [usize; 3]) -> Self {
        let res = res.map(|r| r.max(1));
        let n = Vec3A::new(res[0] as f32, res[1] as f32, res[2] as f32);
        // Collected from an iterator of known length: the cells are written in place in the
        // shared allocation, not gathered in a Vec and copied (64 MiB twice at 256³).
        let max = (0..res[0] * res[1] * res[2])
            .map(|i| {
                let (x, y, z) = (i % res[0], (i / res[0]) % res[1], i / (res[0] * res[1]));
                let c = Vec3A::new(x as f32, y as f32, z as f32);
                let m = density.max_in_unit_box(c / n, (c + Vec3A::ONE) / n);
                // Trilinear weights that sum to 1 only up to rounding can lift a lookup a few
                // ulps above its largest voxel: keep the bound strict.
                m * (1.0 + 4.0 * f32::EPSILON)
            })
            .collect();
        Self { res, max }
    }

    /// Identifies the cells: grids that share them (clones) give the same number, which a
    /// memory count uses to count them once.
    #[inline]
    pub fn cells_id(&self) -> usize {
        std::sync::Arc::as_ptr(&self.max) as *const f32 as usize
    }

    /// Cells per axis.
    #[inline]
    pub fn resolution(&self) -> [usize; 3] {
        self.res
    }

    /// The bound of cell (`x`, `y`, `z`).
    #[inline]
    pub fn cell(&self, x: usize, y: usize, z: usize) -> f32 {
        self.max[(z * self.res[1] + y) * self.res[0] + x]
    }
}

/// The parameter range in which the ray `o + t·d` is inside the unit cube [0, 1]³, clipped to
/// `t_min..t_max`, or `None`. A zero direction component (either sign) means "inside this slab
/// or not", never `0 · ∞`.
pub fn clip_unit_cube(o: Vec3A, d: Vec3A, t_min: f32, t_max: f32) -> Option<(f32, f32)> {
    if o.is_nan() || d.is_nan() {
        return None;
    }
    let (mut near, mut far) = (t_min, t_max);
    for k in 0..3 {
        if d[k] == 0.0 {
            if !(o[k] >= 0.0 && o[k] <= 1.0) {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[k];
        let (a, b) = ((0.0 - o[k]) * inv, (1.0 - o[k]) * inv);
        let (a, b) = if inv > 0.0 { (a, b) } else { (b, a) };
        near = near.max(a);
        far = far.min(b);
    }
    (near < far).then_some((near, far))
}

/// A 3D DDA through a [`MajorantGrid`] in unit coordinates (the grid spans [0, 1]³): one
/// [`MajorantSegment`] per cell the ray crosses, in order, with `sigma_t · cell bound`.
#[derive(Clone, Debug)]
pub struct DdaIter<'a> {
    grid: &'a MajorantGrid,
    sigma_t: Vec3A,
    t_min: f32,
    t_max: f32,
    cell: [i32; 3],
    step: [i32; 3],
    limit: [i32; 3],
    next_crossing: [f32; 3],
    delta: [f32; 3],
}

impl<'a> DdaIter<'a> {
    /// Walks the ray `o + t·d` (unit coordinates) over `t_min..t_max`, which must lie inside
    /// the unit cube (see [`clip_unit_cube`]).
    pub fn new(
        grid: &'a MajorantGrid,
        sigma_t: Vec3A,
        o: Vec3A,
        d: Vec3A,
        t_min: f32,
        t_max: f32,
    ) -> Self {
        let p = o + d * t_min;
        let mut it = Self {
            grid,
            sigma_t,
            t_min,
            t_max,
            cell: [0; 3],
            step: [1; 3],
            limit: [0; 3],
            next_crossing: [f32::INFINITY; 3],
            delta: [f32::INFINITY; 3],
        };
        for k in 0..3 {
            let n = grid.res[k] as i32;
            let nf = n as f32;
            it.cell[k] = ((p[k] * nf).floor() as i32).clamp(0, n - 1);
            if d[k] == 0.0 {
                // Never crosses a face on this axis: `next_crossing` stays infinite.
                it.limit[k] = n;
                continue;
            }
            it.delta[k] = 1.0 / (d[k].abs() * nf);
            if d[k] > 0.0 {
                let face = (it.cell[k] + 1) as f32 / nf;
                it.next_crossing[k] = t_min + (face - p[k]) / d[k];
                it.limit[k] = n;
            } else {
                let face = it.cell[k] as f32 / nf;
                it.next_crossing[k] = t_min + (face - p[k]) / d[k];
                it.step[k] = -1;
                it.limit[k] = -1;
            }
        }
        it
    }

    /// The next segment and the cell it lies in.
    pub fn next_cell(&mut self) -> Option<(MajorantSegment, [usize; 3])> {
        if !(self.t_min < self.t_max) {
            return None;
        }
        let nc = self.next_crossing;
        let axis = if nc[0] < nc[1] {
            if nc[0] < nc[2] {
                0
            } else {
                2
            }
        } else if nc[1] < nc[2] {
            1
        } else {
            2
        };
        // The last cell reaches exactly to `t_max`: a crossing computed a rounding error short
        // of the grid's face must not leave a sliver uncovered.
        let last = nc[axis] >= self.t_max || self.cell[axis] + self.step[axis] == self.limit[axis];
        let exit = if last {
            self.t_max
        } else {
            nc[axis].max(self.t_min)
        };
        let cell = self.cell.map(|c| c as usize);
        let seg = MajorantSegment {
            t_min: self.t_min,
            t_max: exit,
            sigma_maj: self.sigma_t * self.grid.cell(cell[0], cell[1], cell[2]),
        };
        self.t_min = exit;
        self.cell[axis] += self.step[axis];
        self.next_crossing[axis] += self.delta[axis];
        Some((seg, cell))
    }
}

impl Iterator for DdaIter<'_> {
    type Item = MajorantSegment;

    #[inline]
    fn next(&mut self) -> Option<MajorantSegment> {
        self.next_cell().map(|(s, _)| s)
    }
}

/// The majorant segments of a ray through any medium: one for a homogeneous medium, one per
/// crossed cell for a grid. An enum, not a trait object: no allocation or dynamic dispatch per
/// ray.
#[derive(Clone, Debug)]
pub enum MajorantIter<'a> {
    /// At most one segment left.
    Single(Option<MajorantSegment>),
    /// Cells of a majorant grid.
    Dda(DdaIter<'a>),
}

impl Iterator for MajorantIter<'_> {
    type Item = MajorantSegment;

    #[inline]
    fn next(&mut self) -> Option<MajorantSegment> {
        match self {
            MajorantIter::Single(s) => s.take(),
            MajorantIter::Dda(d) => d.next(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Aabb;
    use crate::medium::testutil::Rng;

    fn noise_grid(res: [usize; 3]) -> DensityGrid {
        let n = super::super::NoiseDensity::default();
        DensityGrid::from_fn(res, Aabb::new(Vec3A::ZERO, Vec3A::ONE), |p| n.density(p)).unwrap()
    }

    /// The cell of unit point `p` in a grid of `res` cells.
    fn cell_of(p: Vec3A, res: [usize; 3]) -> [usize; 3] {
        [0, 1, 2]
            .map(|k| ((p[k] * res[k] as f32).floor() as i64).clamp(0, res[k] as i64 - 1) as usize)
    }

    fn random_ray(rng: &mut Rng) -> (Vec3A, Vec3A) {
        // From around the cube, some origins inside, towards a point of it; some directions
        // lie in a coordinate plane or along an axis (zero components of either sign).
        let mut o = Vec3A::new(rng.f32(), rng.f32(), rng.f32()) * 3.0 - Vec3A::ONE;
        let target = Vec3A::new(rng.f32(), rng.f32(), rng.f32());
        match (rng.f32() * 6.0) as u32 {
            0 => o.y = target.y,
            1 => {
                o.x = target.x;
                o.z = target.z;
            }
            _ => {}
        }
        let mut d = (target - o).normalize_or(Vec3A::X);
        if d.x == 0.0 {
            d.x = -0.0;
        }
        (o, d)
    }

    #[test]
    fn dda_visits_exactly_the_cells_the_ray_crosses() {
        let density = noise_grid([20, 20, 20]);
        let mut rng = Rng::new(11);
        let mut rays = 0;
        for res in [[16, 16, 16], [5, 7, 3], [1, 1, 1]] {
            let grid = MajorantGrid::new(&density, res);
            for _ in 0..400 {
                let (o, d) = random_ray(&mut rng);
                let Some((t0, t1)) = clip_unit_cube(o, d, 0.0, 10.0) else {
                    continue;
                };
                rays += 1;
                let mut it = DdaIter::new(&grid, Vec3A::ONE, o, d, t0, t1);
                let mut segs = Vec::new();
                while let Some(s) = it.next_cell() {
                    segs.push(s);
                    assert!(segs.len() < 100, "runaway DDA");
                }
                // Contiguous cover of t0..t1 by neighbouring cells.
                assert_eq!(segs[0].0.t_min, t0);
                assert_eq!(segs.last().unwrap().0.t_max, t1);
                for w in segs.windows(2) {
                    assert_eq!(w[0].0.t_max, w[1].0.t_min);
                    let moved: usize = (0..3).map(|k| w[0].1[k].abs_diff(w[1].1[k])).sum();
                    assert!(moved <= 1, "{:?} -> {:?}", w[0].1, w[1].1);
                }
                // Brute force: dense points along the ray lie in the segment's cell, away from
                // the faces (where rounding may put a point either side).
                let n = 2000;
                for i in 0..n {
                    let t = t0 + (t1 - t0) * (i as f32 + 0.5) / n as f32;
                    let (seg, cell) = segs
                        .iter()
                        .find(|(s, _)| t >= s.t_min && t < s.t_max)
                        .expect("every t in a segment");
                    if t - seg.t_min < 1e-4 || seg.t_max - t < 1e-4 {
                        continue;
                    }
                    assert_eq!(*cell, cell_of(o + d * t, res), "t = {t}");
                    assert_eq!(
                        seg.sigma_maj,
                        Vec3A::splat(grid.cell(cell[0], cell[1], cell[2]))
                    );
                }
                // And no cell is listed that the ray does not cross for a visible length.
                for (s, cell) in &segs {
                    if s.t_max - s.t_min > 1e-3 {
                        let mid = o + d * (0.5 * (s.t_min + s.t_max));
                        assert_eq!(*cell, cell_of(mid, res));
                    }
                }
            }
        }
        assert!(rays > 1000, "{rays} rays hit the cube");
    }

    #[test]
    fn majorant_bounds_the_density_everywhere() {
        let density = noise_grid([24, 17, 9]);
        let mut rng = Rng::new(12);
        for res in [[16, 16, 16], [4, 4, 4], [30, 30, 30]] {
            let grid = MajorantGrid::new(&density, res);
            for _ in 0..20_000 {
                let u = Vec3A::new(rng.f32(), rng.f32(), rng.f32());
                let c = cell_of(u, res);
                let d = density.density_unit(u);
                assert!(d <= grid.cell(c[0], c[1], c[2]), "{u}: {d} > cell {c:?}");
            }
        }
    }

    #[test]
    fn empty_cells_have_a_zero_majorant() {
        // Density only in the upper half of x: cells entirely in the lower half, more than a
        // voxel's support away, are exactly 0.
        let density = DensityGrid::from_fn([32, 8, 8], Aabb::new(Vec3A::ZERO, Vec3A::ONE), |p| {
            if p.x > 0.5 {
                1.0
            } else {
                0.0
            }
        })
        .unwrap();
        let grid = MajorantGrid::new(&density, [8, 2, 2]);
        for x in 0..8 {
            let m = grid.cell(x, 1, 1);
            if x < 3 {
                assert_eq!(m, 0.0, "cell {x}");
            } else if x >= 4 {
                assert!(m >= 1.0);
            }
        }
        // A ray through the empty half gets zero majorants, then the full ones.
        let o = Vec3A::new(-0.5, 0.5, 0.5);
        let (t0, t1) = clip_unit_cube(o, Vec3A::X, 0.0, f32::INFINITY).unwrap();
        let segs: Vec<_> =
            DdaIter::new(&grid, Vec3A::new(1.0, 2.0, 3.0), o, Vec3A::X, t0, t1).collect();
        assert_eq!(segs.len(), 8);
        assert_eq!(segs[0].sigma_maj, Vec3A::ZERO);
        assert!(segs[7].sigma_maj.cmpge(Vec3A::new(1.0, 2.0, 3.0)).all());
    }

    #[test]
    fn rays_that_miss_the_cube_are_clipped_away() {
        assert_eq!(
            clip_unit_cube(Vec3A::new(2.0, 0.5, 0.5), Vec3A::X, 0.0, 9.0),
            None
        );
        assert_eq!(
            clip_unit_cube(Vec3A::new(0.5, 2.0, 0.5), Vec3A::X, 0.0, 9.0),
            None
        );
        assert_eq!(
            clip_unit_cube(Vec3A::new(-1.0, 0.5, 0.5), Vec3A::X, 0.0, 0.5),
            None
        );
        assert_eq!(
            clip_unit_cube(Vec3A::new(-1.0, 0.5, 0.5), Vec3A::X, 0.0, 9.0),
            Some((1.0, 2.0))
        );
        assert_eq!(
            clip_unit_cube(Vec3A::splat(0.5), -Vec3A::Z, 0.0, 0.25),
            Some((0.0, 0.25))
        );
        assert_eq!(clip_unit_cube(Vec3A::NAN, Vec3A::X, 0.0, 1.0), None);
    }
}
