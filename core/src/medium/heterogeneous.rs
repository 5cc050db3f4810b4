//! A heterogeneous medium: σa and σs scaled by a density grid (pbrt-v4's `GridMedium`).

use super::grid::DensityGrid;
use super::majorant::{clip_unit_cube, DdaIter, MajorantGrid, MajorantIter, DEFAULT_MAJORANT_RES};
use super::phase::HenyeyGreenstein;
use super::{check_coefficient, check_extinction, MediumError, MediumProperties};
use crate::geometry::transform::Degenerate;
use crate::geometry::Aabb;
use glam::{Affine3A, Vec3A};

/// Smoke, clouds, a cup of coffee with milk swirling in it: at a point p,
/// σa(p) = `sigma_a` · density(p) and σs(p) = `sigma_s` · density(p), per colour channel, with
/// the density from a [`DensityGrid`] (trilinear, 0 outside its box) and one Henyey–Greenstein
/// phase function everywhere.
///
/// The grid lives in the medium's own space; `world_from_medium` (identity unless set with
/// [`GridMedium::with_transform`]) places it, like an object's transform. A coarse
/// [`MajorantGrid`] (16³ unless set with [`GridMedium::with_majorant_resolution`]) bounds the
/// density cell by cell for tracking.
#[derive(Clone, Debug, PartialEq)]
pub struct GridMedium {
    density: DensityGrid,
    majorant: MajorantGrid,
    sigma_a: Vec3A,
    sigma_s: Vec3A,
    phase: HenyeyGreenstein,
    world_from_medium: Affine3A,
    /// World to the grid's unit cube: the inverse transform, then the box mapped to [0, 1]³.
    unit_from_world: Affine3A,
}

impl GridMedium {
    /// A medium with coefficients `sigma_a`, `sigma_s` (finite, non-negative per channel, per
    /// metre at density 1) scaled by `density`, and asymmetry `g` in (-1, 1).
    pub fn new(
        density: DensityGrid,
        sigma_a: Vec3A,
        sigma_s: Vec3A,
        g: f32,
    ) -> Result<Self, MediumError> {
        check_coefficient("sigma_a", sigma_a)?;
        check_coefficient("sigma_s", sigma_s)?;
        check_extinction(sigma_a, sigma_s, 1.0, density.max_value(), true)?;
        let phase = HenyeyGreenstein::new(g).ok_or(MediumError::G(g))?;
        let majorant = MajorantGrid::new(&density, [DEFAULT_MAJORANT_RES; 3]);
        let unit_from_medium = unit_from_box(density.bounds());
        Ok(Self {
            density,
            majorant,
            sigma_a,
            sigma_s,
            phase,
            world_from_medium: Affine3A::IDENTITY,
            unit_from_world: unit_from_medium,
        })
    }

    /// The same medium with a majorant grid of `res` cells per axis (each at least 1): finer
    /// cells bound the density more tightly (fewer null collisions) at the price of more DDA
    /// steps per ray.
    pub fn with_majorant_resolution(mut self, res: [usize; 3]) -> Self {
        self.majorant = MajorantGrid::new(&self.density, res);
        self
    }

    /// The same medium placed in the world by `world_from_medium`, which must be finite and
    /// invertible in f32 by the test scene objects' transforms pass ([`Degenerate::of`]: scales
    /// from about 10⁻¹² to 10¹², whatever the determinant).
    pub fn with_transform(mut self, world_from_medium: Affine3A) -> Result<Self, MediumError> {
        if !world_from_medium.is_finite() {
            return Err(MediumError::Transform("transform is not finite".into()));
        }
        if let Some(d) = Degenerate::of_affine(&world_from_medium) {
            return Err(MediumError::Transform(d.to_string()));
        }
        self.world_from_medium = world_from_medium;
        self.unit_from_world = unit_from_box(self.density.bounds()) * world_from_medium.inverse();
        Ok(self)
    }

    /// The density grid.
    #[inline]
    pub fn density(&self) -> &DensityGrid {
        &self.density
    }

    /// The majorant grid.
    #[inline]
    pub fn majorant_grid(&self) -> &MajorantGrid {
        &self.majorant
    }

    /// Absorption per channel at density 1.
    #[inline]
    pub fn sigma_a(&self) -> Vec3A {
        self.sigma_a
    }

    /// Scattering per channel at density 1.
    #[inline]
    pub fn sigma_s(&self) -> Vec3A {
        self.sigma_s
    }

    /// The phase function.
    #[inline]
    pub fn phase(&self) -> HenyeyGreenstein {
        self.phase
    }

    /// The transform from the grid's space to the world.
    #[inline]
    pub fn world_from_medium(&self) -> Affine3A {
        self.world_from_medium
    }

    /// World-space bounds of the grid's box.
    pub fn world_bounds(&self) -> Aabb {
        let b = self.density.bounds();
        let mut out = Aabb::new(Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
        for i in 0..8 {
            let c = Vec3A::new(
                if i & 1 == 0 { b.min.x } else { b.max.x },
                if i & 2 == 0 { b.min.y } else { b.max.y },
                if i & 4 == 0 { b.min.z } else { b.max.z },
            );
            let w = self.world_from_medium.transform_point3a(c);
            out.min = out.min.min(w);
            out.max = out.max.max(w);
        }
        out
    }

    /// The coefficients at world point `p`.
    #[inline]
    pub fn properties(&self, p: Vec3A) -> MediumProperties {
        self.properties_unit(self.unit_from_world.transform_point3a(p))
    }

    /// The coefficients at unit coordinates `u` of the grid's box.
    #[inline]
    pub(crate) fn properties_unit(&self, u: Vec3A) -> MediumProperties {
        let d = self.density.density_unit(u);
        MediumProperties {
            sigma_a: self.sigma_a * d,
            sigma_s: self.sigma_s * d,
            phase: self.phase,
        }
    }

    /// The world ray `o + t·d` in the grid's unit coordinates, with the same `t`.
    #[inline]
    pub(crate) fn ray_to_unit(&self, o: Vec3A, d: Vec3A) -> (Vec3A, Vec3A) {
        (
            self.unit_from_world.transform_point3a(o),
            self.unit_from_world.transform_vector3a(d),
        )
    }

    /// The majorant segments of the world ray `o + t·d`, `0 < t < t_max`: one per majorant
    /// cell crossed inside the grid's box, none outside it (the density is 0 there). `t` is in
    /// the ray's own units and σ_maj per unit of `t` (per metre for a unit `d`).
    pub fn majorants(&self, o: Vec3A, d: Vec3A, t_max: f32) -> MajorantIter<'_> {
        let (ou, du) = self.ray_to_unit(o, d);
        self.majorants_unit(ou, du, t_max, d.length())
    }

    /// [`GridMedium::majorants`] for a ray already in unit coordinates, whose parameter
    /// advances `per_t` metres in the world per unit.
    #[inline]
    pub(crate) fn majorants_unit(
        &self,
        ou: Vec3A,
        du: Vec3A,
        t_max: f32,
        per_t: f32,
    ) -> MajorantIter<'_> {
        let sigma_t = (self.sigma_a + self.sigma_s) * per_t;
        match clip_unit_cube(ou, du, 0.0, t_max) {
            Some((t0, t1)) => {
                MajorantIter::Dda(DdaIter::new(&self.majorant, sigma_t, ou, du, t0, t1))
            }
            None => MajorantIter::Single(None),
        }
    }
}

/// The affine map taking `b` to the unit cube [0, 1]³.
fn unit_from_box(b: Aabb) -> Affine3A {
    let inv = Vec3A::ONE / (b.max - b.min);
    Affine3A::from_scale(inv.into()) * Affine3A::from_translation((-b.min).into())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> DensityGrid {
        DensityGrid::new(
            [2, 1, 1],
            Aabb::new(Vec3A::new(-1.0, 0.0, 0.0), Vec3A::new(1.0, 1.0, 1.0)),
            vec![1.0, 3.0],
        )
        .unwrap()
    }

    #[test]
    fn coefficients_scale_with_density() {
        let m = GridMedium::new(grid(), Vec3A::new(1.0, 2.0, 3.0), Vec3A::splat(0.5), 0.2).unwrap();
        let p = m.properties(Vec3A::new(0.0, 0.5, 0.5));
        assert_eq!(p.sigma_a, Vec3A::new(2.0, 4.0, 6.0));
        assert_eq!(p.sigma_s, Vec3A::splat(1.0));
        assert_eq!(p.phase.g(), 0.2);
        assert_eq!(m.properties(Vec3A::new(0.0, 2.0, 0.5)).sigma_a, Vec3A::ZERO);
        assert!(GridMedium::new(grid(), -Vec3A::ONE, Vec3A::ONE, 0.0).is_err());
        assert!(GridMedium::new(grid(), Vec3A::ONE, Vec3A::ONE, -1.0).is_err());
    }

    #[test]
    fn the_transform_places_the_grid() {
        let m = GridMedium::new(grid(), Vec3A::ONE, Vec3A::ZERO, 0.0)
            .unwrap()
            .with_transform(Affine3A::from_translation(glam::Vec3::new(10.0, 0.0, 0.0)))
            .unwrap();
        assert_eq!(m.properties(Vec3A::new(9.5, 0.5, 0.5)).sigma_a, Vec3A::ONE);
        assert_eq!(
            m.properties(Vec3A::new(10.5, 0.5, 0.5)).sigma_a,
            Vec3A::splat(3.0)
        );
        assert_eq!(m.properties(Vec3A::new(0.5, 0.5, 0.5)).sigma_a, Vec3A::ZERO);
        let wb = m.world_bounds();
        assert_eq!(
            (wb.min, wb.max),
            (Vec3A::new(9.0, 0.0, 0.0), Vec3A::new(11.0, 1.0, 1.0))
        );
        // A ray along +x from the world origin enters the box at t = 9 and leaves at t = 11.
        let segs: Vec<_> = m
            .majorants(Vec3A::new(0.0, 0.5, 0.5), Vec3A::X, 100.0)
            .collect();
        assert_eq!(segs.first().unwrap().t_min, 9.0);
        assert_eq!(segs.last().unwrap().t_max, 11.0);
        let flat = Affine3A::from_scale(glam::Vec3::new(1.0, 0.0, 1.0));
        assert!(GridMedium::new(grid(), Vec3A::ONE, Vec3A::ZERO, 0.0)
            .unwrap()
            .with_transform(flat)
            .is_err());
    }

    #[test]
    fn small_placements_are_taken_as_scene_transforms_are() {
        // An object at a scale of 10⁻⁴ holding a grid (a determinant of 10⁻¹²), and a grid of
        // rotated 10⁻⁴ voxels in it: f32 inverts both, as it does the object's own transform.
        let m = || GridMedium::new(grid(), Vec3A::ONE, Vec3A::ZERO, 0.0).unwrap();
        let small = Affine3A::from_scale(glam::Vec3::splat(1e-4));
        let turned = small * Affine3A::from_rotation_z(0.5);
        for placement in [small, turned, small * turned] {
            let g = m().with_transform(placement).unwrap();
            let centre = placement.transform_point3a(Vec3A::new(0.5, 0.5, 0.5));
            assert_eq!(
                g.properties(centre).sigma_a,
                Vec3A::splat(3.0),
                "{placement}"
            );
        }
        // Past what f32 inverts (scales below about 10⁻¹²): the scene transforms' message.
        let e = m()
            .with_transform(Affine3A::from_scale(glam::Vec3::splat(1e-13)))
            .unwrap_err()
            .to_string();
        assert!(e.contains("too small to invert in f32"), "{e}");
        let e = m()
            .with_transform(Affine3A::from_scale(glam::Vec3::splat(f32::NAN)))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not finite"), "{e}");
    }
}
