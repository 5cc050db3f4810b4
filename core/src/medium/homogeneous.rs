//! A homogeneous medium: the same coefficients everywhere.

use super::majorant::{MajorantIter, MajorantSegment};
use super::phase::HenyeyGreenstein;
use super::{check_coefficient, check_extinction, MediumError, MediumProperties};
use glam::Vec3A;

/// Fog, murky water, a glass of milk: σa and σs per colour channel (per metre, any `scale`
/// already applied) and a Henyey–Greenstein phase function, the same at every point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomogeneousMedium {
    sigma_a: Vec3A,
    sigma_s: Vec3A,
    phase: HenyeyGreenstein,
}

impl HomogeneousMedium {
    /// A medium with absorption `sigma_a`, scattering `sigma_s` (finite, non-negative per
    /// channel) and asymmetry `g` in (-1, 1).
    pub fn new(sigma_a: Vec3A, sigma_s: Vec3A, g: f32) -> Result<Self, MediumError> {
        check_coefficient("sigma_a", sigma_a)?;
        check_coefficient("sigma_s", sigma_s)?;
        check_extinction(sigma_a, sigma_s, 1.0, 1.0, false)?;
        let phase = HenyeyGreenstein::new(g).ok_or(MediumError::G(g))?;
        Ok(Self {
            sigma_a,
            sigma_s,
            phase,
        })
    }

    /// Absorption coefficient per channel.
    #[inline]
    pub fn sigma_a(&self) -> Vec3A {
        self.sigma_a
    }

    /// Scattering coefficient per channel.
    #[inline]
    pub fn sigma_s(&self) -> Vec3A {
        self.sigma_s
    }

    /// Extinction σt = σa + σs per channel.
    #[inline]
    pub fn sigma_t(&self) -> Vec3A {
        self.sigma_a + self.sigma_s
    }

    /// The phase function.
    #[inline]
    pub fn phase(&self) -> HenyeyGreenstein {
        self.phase
    }

    /// The coefficients (at any point).
    #[inline]
    pub fn properties(&self) -> MediumProperties {
        MediumProperties {
            sigma_a: self.sigma_a,
            sigma_s: self.sigma_s,
            phase: self.phase,
        }
    }

    /// One segment `0..t_max` whose majorant is σt itself.
    #[inline]
    pub fn majorants(&self, t_max: f32) -> MajorantIter<'static> {
        MajorantIter::Single((t_max > 0.0).then_some(MajorantSegment {
            t_min: 0.0,
            t_max,
            sigma_maj: self.sigma_t(),
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coefficients_are_checked() {
        let ok = HomogeneousMedium::new(Vec3A::new(0.1, 0.2, 0.3), Vec3A::ONE, 0.5).unwrap();
        assert_eq!(ok.sigma_t(), Vec3A::new(1.1, 1.2, 1.3));
        assert_eq!(ok.phase().g(), 0.5);
        let neg = HomogeneousMedium::new(Vec3A::new(0.1, -0.2, 0.3), Vec3A::ONE, 0.0);
        assert!(neg.unwrap_err().to_string().contains("sigma_a"));
        assert!(HomogeneousMedium::new(Vec3A::ZERO, Vec3A::splat(f32::NAN), 0.0).is_err());
        assert!(HomogeneousMedium::new(Vec3A::ZERO, Vec3A::splat(f32::INFINITY), 0.0).is_err());
        assert_eq!(
            HomogeneousMedium::new(Vec3A::ZERO, Vec3A::ONE, 1.0),
            Err(MediumError::G(1.0))
        );
    }

    #[test]
    fn one_majorant_segment() {
        let m = HomogeneousMedium::new(Vec3A::ONE, Vec3A::splat(2.0), 0.0).unwrap();
        let segs: Vec<_> = m.majorants(5.0).collect();
        assert_eq!(
            segs,
            vec![MajorantSegment {
                t_min: 0.0,
                t_max: 5.0,
                sigma_maj: Vec3A::splat(3.0)
            }]
        );
        assert_eq!(m.majorants(0.0).count(), 0);
        assert_eq!(m.majorants(f32::INFINITY).count(), 1);
    }
}
