//! Dense voxel grids of density over a box, looked up with trilinear interpolation.

use super::MediumError;
use crate::geometry::Aabb;
use glam::Vec3A;
use std::sync::Arc;

/// A dense grid of non-negative density values over an axis-aligned box in the medium's
/// (object) space.
///
/// Values sit at voxel centres: voxel (x, y, z) covers the box's cells
/// `min + (x, y, z) · size / res` to `min + (x + 1, y + 1, z + 1) · size / res` and its value is
/// the density at the cell's centre (the convention of Mitsuba 3's grid volumes and of
/// pbrt-v4's `SampledGrid`). Between centres the density is trilinear; in the outer half voxel
/// the nearest centres' values extend to the box's faces (Mitsuba's clamp mode; a grid whose
/// border voxels are 0, as OpenVDB fog volumes converted here are, fades to 0 at its faces).
/// Outside the box the density is 0.
///
/// Storage is x fastest: `values[(z · res_y + y) · res_x + x]`, shared: a clone (one per
/// object a grid medium is placed in, one per medium that names the same file) costs no copy of
/// the voxels. The values stay in the `Vec` they were made in: turning it into an `Arc<[f32]>`
/// would copy them, and a 512³ grid would briefly take twice its 512 MiB.
#[derive(Clone, Debug, PartialEq)]
pub struct DensityGrid {
    res: [usize; 3],
    bounds: Aabb,
    values: Arc<Vec<f32>>,
    max_value: f32,
}

impl DensityGrid {
    /// A grid of `res` voxels over `bounds` holding `values` (x fastest). Every resolution must
    /// be at least 1, the box finite and non-empty on every axis, and every value finite and
    /// non-negative: a density is not a level set.
    pub fn new(res: [usize; 3], bounds: Aabb, values: Vec<f32>) -> Result<Self, MediumError> {
        if res.contains(&0) {
            return Err(MediumError::Grid(format!(
                "resolution {}x{}x{} has an empty axis",
                res[0], res[1], res[2]
            )));
        }
        let count = res[0]
            .checked_mul(res[1])
            .and_then(|n| n.checked_mul(res[2]))
            .ok_or_else(|| MediumError::Grid("resolution overflows".into()))?;
        if values.len() != count {
            return Err(MediumError::Grid(format!(
                "{} values for a {}x{}x{} grid ({count} voxels)",
                values.len(),
                res[0],
                res[1],
                res[2]
            )));
        }
        // Lookups divide by the extent: it must be finite, and so must its reciprocal (an
        // extent of a denormal would make every unit coordinate infinite).
        let extent = bounds.max - bounds.min;
        if !(bounds.min.is_finite()
            && bounds.max.is_finite()
            && extent.is_finite()
            && extent.recip().is_finite()
            && bounds.min.cmplt(bounds.max).all())
        {
            return Err(MediumError::Grid(format!(
                "bounding box {} .. {} is not a finite, non-empty box",
                bounds.min, bounds.max
            )));
        }
        let mut max_value = 0.0f32;
        for (i, &v) in values.iter().enumerate() {
            if !(v >= 0.0 && v.is_finite()) {
                let (x, y, z) = (i % res[0], (i / res[0]) % res[1], i / (res[0] * res[1]));
                return Err(MediumError::Grid(format!(
                    "voxel ({x}, {y}, {z}) has density {v}: densities must be finite and \
                     non-negative"
                )));
            }
            max_value = max_value.max(v);
        }
        Ok(Self {
            res,
            bounds,
            values: Arc::new(values),
            max_value,
        })
    }

    /// A grid of `res` voxels over `bounds` whose values are `density` at the voxel centres
    /// (a procedural density baked into a grid, see [`super::NoiseDensity`]).
    pub fn from_fn(
        res: [usize; 3],
        bounds: Aabb,
        density: impl Fn(Vec3A) -> f32,
    ) -> Result<Self, MediumError> {
        let count = res
            .iter()
            .try_fold(1usize, |n, &r| n.checked_mul(r))
            .ok_or_else(|| MediumError::Grid("resolution overflows".into()))?;
        let size = bounds.max - bounds.min;
        let mut values = Vec::with_capacity(count);
        for z in 0..res[2] {
            for y in 0..res[1] {
                for x in 0..res[0] {
                    let u = Vec3A::new(
                        (x as f32 + 0.5) / res[0] as f32,
                        (y as f32 + 0.5) / res[1] as f32,
                        (z as f32 + 0.5) / res[2] as f32,
                    );
                    values.push(density(bounds.min + u * size));
                }
            }
        }
        Self::new(res, bounds, values)
    }

    /// Voxels per axis.
    #[inline]
    pub fn resolution(&self) -> [usize; 3] {
        self.res
    }

    /// The box the grid fills, in the medium's space.
    #[inline]
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// All values, x fastest.
    #[inline]
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// Identifies the values: grids that share them (clones) give the same number, which a
    /// memory count uses to count them once.
    #[inline]
    pub fn values_id(&self) -> usize {
        Arc::as_ptr(&self.values) as usize
    }

    /// The largest value.
    #[inline]
    pub fn max_value(&self) -> f32 {
        self.max_value
    }

    /// The value of voxel (`x`, `y`, `z`), which must be inside the grid.
    #[inline]
    pub fn voxel(&self, x: usize, y: usize, z: usize) -> f32 {
        self.values[(z * self.res[1] + y) * self.res[0] + x]
    }

    /// The density at `p` in the medium's space: trilinear inside the box, 0 outside.
    #[inline]
    pub fn density(&self, p: Vec3A) -> f32 {
        let u = (p - self.bounds.min) / (self.bounds.max - self.bounds.min);
        self.density_unit(u)
    }

    /// The density at unit coordinates `u` ([0, 1]³ spans the box): trilinear inside, 0
    /// outside (and for NaN).
    #[inline]
    pub fn density_unit(&self, u: Vec3A) -> f32 {
        if !(u.cmpge(Vec3A::ZERO).all() && u.cmple(Vec3A::ONE).all()) {
            return 0.0;
        }
        // Continuous voxel coordinates: centres at integers.
        let q = u * Vec3A::new(self.res[0] as f32, self.res[1] as f32, self.res[2] as f32)
            - Vec3A::splat(0.5);
        let fl = q.floor();
        let f = q - fl;
        let mut i0 = [0usize; 3];
        let mut i1 = [0usize; 3];
        for k in 0..3 {
            let last = self.res[k] as i64 - 1;
            let a = fl[k] as i64;
            i0[k] = a.clamp(0, last) as usize;
            i1[k] = (a + 1).clamp(0, last) as usize;
        }
        let v = |x: usize, y: usize, z: usize| self.voxel(x, y, z);
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let x00 = lerp(v(i0[0], i0[1], i0[2]), v(i1[0], i0[1], i0[2]), f.x);
        let x10 = lerp(v(i0[0], i1[1], i0[2]), v(i1[0], i1[1], i0[2]), f.x);
        let x01 = lerp(v(i0[0], i0[1], i1[2]), v(i1[0], i0[1], i1[2]), f.x);
        let x11 = lerp(v(i0[0], i1[1], i1[2]), v(i1[0], i1[1], i1[2]), f.x);
        lerp(lerp(x00, x10, f.y), lerp(x01, x11, f.y), f.z)
    }

    /// The largest voxel value whose trilinear support reaches into the unit-space box
    /// `lo..hi`: an upper bound of [`DensityGrid::density_unit`] there (and a little beyond,
    /// so that points rounded across a face are covered too).
    pub fn max_in_unit_box(&self, lo: Vec3A, hi: Vec3A) -> f32 {
        let mut range = [(0usize, 0usize); 3];
        for (k, r) in range.iter_mut().enumerate() {
            let n = self.res[k] as f64;
            // A thousandth of a voxel of slack on each side absorbs rounding of ray points.
            let a = (lo[k] as f64 * n - 0.5 - 1e-3).floor() as i64;
            let b = (hi[k] as f64 * n - 0.5 + 1e-3).floor() as i64 + 1;
            let last = self.res[k] as i64 - 1;
            *r = (a.clamp(0, last) as usize, b.clamp(0, last) as usize);
        }
        let mut m = 0.0f32;
        for z in range[2].0..=range[2].1 {
            for y in range[1].0..=range[1].1 {
                let row = (z * self.res[1] + y) * self.res[0];
                for &v in &self.values[row + range[0].0..=row + range[0].1] {
                    m = m.max(v);
                }
            }
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::medium::testutil::Rng;

    fn unit_box() -> Aabb {
        Aabb::new(Vec3A::ZERO, Vec3A::ONE)
    }

    #[test]
    fn bad_grids_are_errors() {
        let b = unit_box();
        assert!(DensityGrid::new([0, 1, 1], b, vec![]).is_err());
        assert!(DensityGrid::new([2, 1, 1], b, vec![1.0]).is_err());
        assert!(DensityGrid::new([1, 1, 1], b, vec![-1.0]).is_err());
        assert!(DensityGrid::new([1, 1, 1], b, vec![f32::NAN]).is_err());
        assert!(DensityGrid::new([1, 1, 1], b, vec![f32::INFINITY]).is_err());
        let flat = Aabb::new(Vec3A::ZERO, Vec3A::new(1.0, 0.0, 1.0));
        assert!(DensityGrid::new([1, 1, 1], flat, vec![1.0]).is_err());
        let err = DensityGrid::new([2, 2, 1], b, vec![0.0, 0.0, -3.0, 0.0]).unwrap_err();
        assert!(err.to_string().contains("(0, 1, 0)"), "{err}");
    }

    #[test]
    fn values_are_kept_where_they_were_made_and_shared_by_clones() {
        // No copy: a 512³ grid read from a file must not take twice its size while it is made.
        let values = vec![0.5f32; 4 * 3 * 2];
        let at = values.as_ptr();
        let g = DensityGrid::new([4, 3, 2], unit_box(), values).unwrap();
        assert_eq!(g.values().as_ptr(), at);
        let c = g.clone();
        assert_eq!((c.values().as_ptr(), c.values_id()), (at, g.values_id()));
    }

    #[test]
    fn values_sit_at_voxel_centres_and_interpolate_linearly() {
        // 2x1x1 over [0,2]x[0,1]x[0,1]: centres at x = 0.5 and 1.5.
        let g = DensityGrid::new(
            [2, 1, 1],
            Aabb::new(Vec3A::ZERO, Vec3A::new(2.0, 1.0, 1.0)),
            vec![1.0, 3.0],
        )
        .unwrap();
        let at = |x: f32| g.density(Vec3A::new(x, 0.5, 0.5));
        assert_eq!(at(0.5), 1.0);
        assert_eq!(at(1.5), 3.0);
        assert_eq!(at(1.0), 2.0);
        assert_eq!(at(1.25), 2.5);
        // Clamped in the outer half voxels, zero outside.
        assert_eq!(at(0.1), 1.0);
        assert_eq!(at(1.9), 3.0);
        assert_eq!(at(2.0), 3.0);
        assert_eq!(at(-0.01), 0.0);
        assert_eq!(at(2.01), 0.0);
        assert_eq!(g.density(Vec3A::NAN), 0.0);
        assert_eq!(g.max_value(), 3.0);
    }

    #[test]
    fn trilinear_reproduces_linear_functions() {
        let f = |p: Vec3A| 1.0 + p.x + 2.0 * p.y + 3.0 * p.z;
        let g = DensityGrid::from_fn([5, 6, 7], unit_box(), f).unwrap();
        let mut rng = Rng::new(1);
        for _ in 0..1000 {
            // Inside the hull of the centres, where no clamping happens.
            let p = Vec3A::new(
                rng.range(0.1, 0.9),
                rng.range(1.0 / 12.0, 11.0 / 12.0),
                rng.range(1.0 / 14.0, 13.0 / 14.0),
            );
            assert!((g.density(p) - f(p)).abs() < 1e-5, "{p}");
        }
    }

    #[test]
    fn box_maximum_bounds_every_point_inside() {
        let mut rng = Rng::new(2);
        let values: Vec<f32> = (0..7 * 5 * 3).map(|_| rng.f32() * 4.0).collect();
        let g = DensityGrid::new([7, 5, 3], unit_box(), values).unwrap();
        for _ in 0..200 {
            let a = Vec3A::new(rng.f32(), rng.f32(), rng.f32());
            let b = Vec3A::new(rng.f32(), rng.f32(), rng.f32());
            let (lo, hi) = (a.min(b), a.max(b));
            let m = g.max_in_unit_box(lo, hi);
            for _ in 0..50 {
                let t = Vec3A::new(rng.f32(), rng.f32(), rng.f32());
                let u = lo + (hi - lo) * t;
                assert!(g.density_unit(u) <= m, "{u} in {lo}..{hi}");
            }
        }
    }
}
