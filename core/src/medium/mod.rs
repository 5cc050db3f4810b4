//! Participating media: fog, smoke, murky liquids (pbrt-v4's `media.h` is the model).
//!
//! - [`phase`]: the Henyey–Greenstein phase function and its conventions.
//! - [`homogeneous`], [`heterogeneous`]: the two media, behind the [`Medium`] enum.
//! - [`grid`]: dense density grids (trilinear); [`noise`]: a procedural density to bake into
//!   one.
//! - [`majorant`]: majorant grids and the DDA that yields σ_maj segment by segment.
//! - [`tracking`]: `sample_t_maj` (delta tracking with a callback, as pbrt-v4's volumetric
//!   path tracer uses it) and ratio-tracking transmittance for shadow rays.
//! - [`vol`], [`vdb`]: grid files (Mitsuba 3's `.vol`, OpenVDB's `.vdb`), read with a voxel
//!   budget; [`load_grid_file`] picks the reader by extension.
//!
//! Coefficients are per metre (per unit of scene length) per colour channel. Everything a ray
//! touches is plain data and enums: no allocation, locking or dynamic dispatch per ray.
//!
//! How an integrator uses them (pbrt-v4's `VolPathIntegrator` in outline): along a ray segment
//! inside a medium, [`sample_t_maj`] proposes collisions; the callback picks absorption,
//! real scattering or a null collision with probabilities σa/σ_maj, σs/σ_maj and σn/σ_maj,
//! and at a real scattering event samples the phase function. Shadow rays multiply
//! [`transmittance`] over the media they cross.
//!
//! ```
//! use glam::{Vec2, Vec3A};
//! use raytile_core::geometry::Ray;
//! use raytile_core::medium::{sample_t_maj, HashRng, HomogeneousMedium, Medium, RandomSource};
//!
//! // Fog: σa = 0.1, σs = 0.4 per metre, forward scattering.
//! let fog = Medium::Homogeneous(HomogeneousMedium::new(Vec3A::splat(0.1), Vec3A::splat(0.4), 0.6)?);
//! let ray = Ray::new(Vec3A::ZERO, Vec3A::Z);
//! let mut rng = HashRng::new(42); // seeded from (pixel, sample index, seed)
//! let mut scattered = None;
//! sample_t_maj(&fog, &ray, 10.0, 0, &mut rng, |c, rng| {
//!     let u = rng.next_1d() * c.sigma_maj.x;
//!     if u < c.props.sigma_a.x {
//!         false // absorbed: the path ends
//!     } else if u < c.props.sigma_t().x {
//!         let wo = -ray.d;
//!         let s = c.props.phase.sample(wo, Vec2::new(rng.next_1d(), rng.next_1d()));
//!         scattered = Some((c.p, s.wi));
//!         false // scattered: continue the path from c.p along s.wi
//!     } else {
//!         true // a null collision: keep going
//!     }
//! });
//! # Ok::<(), raytile_core::medium::MediumError>(())
//! ```

pub mod file;
pub mod grid;
pub mod heterogeneous;
pub mod homogeneous;
pub mod majorant;
pub mod noise;
pub mod phase;
pub mod tracking;
pub mod vdb;
pub mod vol;

pub use file::{
    load_grid_bytes, load_grid_file, GridFileError, GridFormatError, GridLimits, LoadedGrid,
};
pub use grid::DensityGrid;
pub use heterogeneous::GridMedium;
pub use homogeneous::HomogeneousMedium;
pub use majorant::{MajorantGrid, MajorantIter, MajorantSegment};
pub use noise::NoiseDensity;
pub use phase::{HenyeyGreenstein, PhaseSample};
pub use tracking::{delta_tracking, sample_t_maj, transmittance, Collision, HashRng, RandomSource};

use crate::geometry::Ray;
use glam::Vec3A;

/// A medium's coefficients at one point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MediumProperties {
    /// Absorption coefficient per channel.
    pub sigma_a: Vec3A,
    /// Scattering coefficient per channel.
    pub sigma_s: Vec3A,
    /// The phase function.
    pub phase: HenyeyGreenstein,
}

impl MediumProperties {
    /// Extinction σt = σa + σs.
    #[inline]
    pub fn sigma_t(&self) -> Vec3A {
        self.sigma_a + self.sigma_s
    }
}

/// A participating medium. An enum, so a ray's medium code is static dispatch; the grid is
/// boxed to keep the enum small.
#[derive(Clone, Debug, PartialEq)]
pub enum Medium {
    /// The same coefficients everywhere.
    Homogeneous(HomogeneousMedium),
    /// Coefficients scaled by a density grid.
    Grid(Box<GridMedium>),
}

impl Medium {
    /// The phase function (one per medium).
    #[inline]
    pub fn phase(&self) -> HenyeyGreenstein {
        match self {
            Medium::Homogeneous(h) => h.phase(),
            Medium::Grid(g) => g.phase(),
        }
    }

    /// The coefficients at world point `p`.
    #[inline]
    pub fn properties(&self, p: Vec3A) -> MediumProperties {
        match self {
            Medium::Homogeneous(h) => h.properties(),
            Medium::Grid(g) => g.properties(p),
        }
    }

    /// The majorant segments of `ray` over `0 < t < t_max`, with `t` in the units of `ray.d`
    /// and σ_maj per unit of that parameter: a unit `ray.d` (as world rays have) gives σ_maj
    /// per metre. [`sample_t_maj`] normalises the direction itself.
    #[inline]
    pub fn majorants(&self, ray: &Ray, t_max: f32) -> MajorantIter<'_> {
        match self {
            Medium::Homogeneous(h) => {
                let len = ray.d.length();
                let mut it = h.majorants(t_max);
                if let MajorantIter::Single(Some(s)) = &mut it {
                    s.sigma_maj *= len;
                }
                it
            }
            Medium::Grid(g) => g.majorants(ray.o, ray.d, t_max),
        }
    }
}

/// Why a medium could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MediumError {
    /// A coefficient was negative, infinite or NaN in some channel.
    #[error("{name} must be finite and non-negative in every channel, got [{}, {}, {}]", value[0], value[1], value[2])]
    Coefficient {
        /// `sigma_a` or `sigma_s`.
        name: &'static str,
        /// The value given.
        value: [f32; 3],
    },
    /// The phase function's asymmetry was outside (-1, 1).
    #[error("g must be in (-1, 1), got {0}")]
    G(f32),
    /// The density grid was malformed (shape, values or box).
    #[error("density grid: {0}")]
    Grid(String),
    /// The extinction σt = σa + σs (times the largest density of a grid) exceeded
    /// [`MAX_EXTINCTION`], past which transmittances and majorants overflow.
    #[error(
        "the extinction, {what}, reaches {value:e} per unit of length: at most {MAX_EXTINCTION:e}"
    )]
    Extinction {
        /// The extinction reached.
        value: f64,
        /// What was multiplied.
        what: &'static str,
    },
    /// The grid's placement was not an invertible affine map.
    #[error("medium transform: {0}")]
    Transform(String),
}

/// The largest extinction (per unit of length) a medium may reach: far above any physical
/// medium, and far enough below f32's range that a majorant times a distance stays finite.
pub const MAX_EXTINCTION: f64 = 1e30;

/// Checks that the extinction of `sigma_a` and `sigma_s` times `scale`, at a density of
/// `max_density` (1 for a homogeneous medium; `grid` says which), stays within
/// [`MAX_EXTINCTION`] in every channel. Computed in f64, so the check itself never overflows.
pub fn check_extinction(
    sigma_a: Vec3A,
    sigma_s: Vec3A,
    scale: f32,
    max_density: f32,
    grid: bool,
) -> Result<(), MediumError> {
    let t = (0..3)
        .map(|c| (f64::from(sigma_a[c]) + f64::from(sigma_s[c])) * f64::from(scale))
        .fold(0.0f64, f64::max)
        * f64::from(max_density);
    if t <= MAX_EXTINCTION {
        Ok(())
    } else {
        Err(MediumError::Extinction {
            value: t,
            what: if grid {
                "(sigma_a + sigma_s) × scale × the grid's largest density"
            } else {
                "(sigma_a + sigma_s) × scale"
            },
        })
    }
}

/// Checks that every channel of `value` is finite and non-negative.
fn check_coefficient(name: &'static str, value: Vec3A) -> Result<(), MediumError> {
    if value.is_finite() && value.cmpge(Vec3A::ZERO).all() {
        Ok(())
    } else {
        Err(MediumError::Coefficient {
            name,
            value: value.to_array(),
        })
    }
}

/// Deterministic random numbers for the media tests.
#[cfg(test)]
pub(crate) mod testutil {
    use super::{HashRng, RandomSource};

    /// A hashed counter: every run draws the same values.
    pub struct Rng(HashRng);

    impl Rng {
        /// The stream `seed`.
        pub fn new(seed: u32) -> Self {
            Self(HashRng::new(seed ^ 0x51ed_270b))
        }

        /// A float in [0, 1).
        pub fn f32(&mut self) -> f32 {
            self.0.next_1d()
        }

        /// A float in [lo, hi).
        pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
            lo + (hi - lo) * self.f32()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Aabb;

    #[test]
    fn the_enum_answers_for_both_media() {
        let h = Medium::Homogeneous(
            HomogeneousMedium::new(Vec3A::ONE, Vec3A::splat(2.0), 0.25).unwrap(),
        );
        let g = DensityGrid::new([1, 1, 1], Aabb::new(Vec3A::ZERO, Vec3A::ONE), vec![0.5]).unwrap();
        let g = Medium::Grid(Box::new(
            GridMedium::new(g, Vec3A::ONE, Vec3A::splat(2.0), -0.5).unwrap(),
        ));
        assert_eq!(h.phase().g(), 0.25);
        assert_eq!(g.phase().g(), -0.5);
        assert_eq!(
            h.properties(Vec3A::splat(100.0)).sigma_t(),
            Vec3A::splat(3.0)
        );
        assert_eq!(g.properties(Vec3A::splat(0.5)).sigma_t(), Vec3A::splat(1.5));
        assert_eq!(g.properties(Vec3A::splat(2.0)).sigma_t(), Vec3A::ZERO);
        // Majorants per unit of the ray parameter: a direction of length 2 doubles them.
        let ray = Ray::new(Vec3A::new(-1.0, 0.5, 0.5), Vec3A::X * 2.0);
        let hs: Vec<_> = h.majorants(&ray, 1.0).collect();
        assert_eq!(hs.len(), 1);
        assert_eq!(hs[0].sigma_maj, Vec3A::splat(6.0));
        let gs: Vec<_> = g.majorants(&ray, 10.0).collect();
        assert_eq!((gs[0].t_min, gs.last().unwrap().t_max), (0.5, 1.0));
        assert!(
            gs.iter()
                .all(|s| s.sigma_maj.x >= 3.0 && s.sigma_maj.x < 3.0001),
            "{gs:?}"
        );
        let err =
            HomogeneousMedium::new(Vec3A::new(1.0, f32::NAN, 0.0), Vec3A::ZERO, 0.0).unwrap_err();
        assert_eq!(
            err.to_string(),
            "sigma_a must be finite and non-negative in every channel, got [1, NaN, 0]"
        );
    }
}
