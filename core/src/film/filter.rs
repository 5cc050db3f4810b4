//! Pixel reconstruction filters, sampled by importance (pbrt-v4's FilterSampler idea).
//! All filters here are separable and non-negative, so each axis is sampled independently
//! from a tabulated 1D distribution and every sample has weight 1.

use crate::sampling::distrib::Distribution1D;
use crate::settings::FilterKind;
use glam::Vec2;

/// Draws pixel offsets distributed like a filter.
#[derive(Clone, Debug)]
pub struct FilterSampler {
    radius: f32,
    table: Option<Distribution1D>,
}

const TABLE: usize = 256;

impl FilterSampler {
    /// The sampler for `kind`.
    pub fn new(kind: FilterKind) -> Self {
        let (radius, f): (f32, fn(f32, f32) -> f32) = match kind {
            FilterKind::Box => {
                return Self {
                    radius: 0.5,
                    table: None,
                }
            }
            FilterKind::Gaussian => (1.5, |x, r| {
                let g = |x: f32| (-x * x / (2.0 * 0.5 * 0.5)).exp();
                (g(x) - g(r)).max(0.0)
            }),
            FilterKind::BlackmanHarris => (2.0, |x, r| {
                let t = 2.0 * std::f32::consts::PI * (x / (2.0 * r) + 0.5);
                (0.35875 - 0.48829 * t.cos() + 0.14128 * (2.0 * t).cos()
                    - 0.01168 * (3.0 * t).cos())
                .max(0.0)
            }),
        };
        let weights: Vec<f32> = (0..TABLE)
            .map(|i| {
                f(
                    ((i as f32 + 0.5) / TABLE as f32 * 2.0 - 1.0) * radius,
                    radius,
                )
            })
            .collect();
        Self {
            radius,
            table: Some(Distribution1D::new(&weights)),
        }
    }

    /// Filter radius in pixels.
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// An offset from the pixel centre, in pixels.
    #[inline]
    pub fn sample(&self, u: Vec2) -> Vec2 {
        match &self.table {
            None => u - Vec2::splat(0.5),
            Some(t) => {
                let x = t.sample_continuous(u.x).0;
                let y = t.sample_continuous(u.y).0;
                (Vec2::new(x, y) * 2.0 - Vec2::ONE) * self.radius
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_stay_within_the_radius_and_centre_on_zero() {
        for kind in FilterKind::ALL {
            let f = FilterSampler::new(kind);
            let mut mean = Vec2::ZERO;
            let n = 64;
            for i in 0..n {
                for j in 0..n {
                    let o = f.sample(Vec2::new(
                        (i as f32 + 0.5) / n as f32,
                        (j as f32 + 0.5) / n as f32,
                    ));
                    assert!(o.abs().max_element() <= f.radius() + 1e-5, "{kind:?} {o}");
                    mean += o;
                }
            }
            assert!((mean / (n * n) as f32).length() < 1e-3, "{kind:?}");
        }
    }
}
