//! Lights: point, spot, directional, area (emissive triangles and shapes) and environment.
//!
//! A light is chosen for next-event estimation in proportion to its (estimated) power, then a
//! point or direction is sampled on it. Everything a light needs from the scene (emitting
//! objects, the scene's bounding sphere) is passed in at build time, so sampling is a pure
//! function of the light and the random numbers.

pub mod environment;

pub use environment::Environment;

use crate::sampling::distrib::Distribution1D;
use glam::Vec3A;
use std::f32::consts::PI;

/// Luminance of linear Rec.709 RGB.
#[inline]
pub fn luminance(c: Vec3A) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// A light source.
#[derive(Clone, Debug)]
pub enum Light {
    /// Isotropic point light.
    Point {
        /// Position.
        position: Vec3A,
        /// Radiant intensity (W/sr).
        intensity: Vec3A,
        /// Cut-off distance.
        range: f32,
    },
    /// Spot light with smooth falloff between the cones.
    Spot {
        /// Position.
        position: Vec3A,
        /// Unit axis the spot points along.
        axis: Vec3A,
        /// Intensity on the axis (W/sr).
        intensity: Vec3A,
        /// Cosine of the inner half-angle.
        cos_inner: f32,
        /// Cosine of the outer half-angle.
        cos_outer: f32,
        /// Cut-off distance.
        range: f32,
    },
    /// Light from one direction (the sun).
    Directional {
        /// Unit direction towards the light (opposite to the direction light travels).
        to_light: Vec3A,
        /// Irradiance on a surface facing the light (W/m²).
        irradiance: Vec3A,
    },
    /// An emissive surface: triangle `prim` of a mesh object, or a whole analytic object.
    Area {
        /// The emitting object.
        object: u32,
        /// Triangle index within its mesh (0 for analytic shapes).
        prim: u32,
        /// Emitted power estimate, for selection.
        power: f32,
    },
    /// The environment (infinitely far away).
    Environment,
}

/// A sampled light: incident direction at the shading point, radiance arriving along it,
/// density (solid angle, or 1 for delta lights), and the distance to the light for shadow rays.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the shading point towards the light.
    pub wi: Vec3A,
    /// Radiance (or, for delta lights, intensity/distance² or irradiance) arriving along `wi`.
    pub li: Vec3A,
    /// Solid-angle density; for delta lights the value 1 and `delta` set.
    pub pdf: f32,
    /// Distance to the sampled point (infinite for directional and environment lights).
    pub dist: f32,
    /// Whether the light is a delta distribution (no MIS with BSDF sampling).
    pub delta: bool,
    /// The point on the light (for area lights), to spawn the shadow ray towards.
    pub p_light: Vec3A,
    /// Front normal at the point on the light (area lights).
    pub n_light: Vec3A,
}

/// Smooth spot falloff (glTF's smoothstep-free variant: linear in cos, squared, like three.js and
/// Filament).
#[inline]
pub fn spot_falloff(cos_theta: f32, cos_inner: f32, cos_outer: f32) -> f32 {
    if cos_theta <= cos_outer {
        return 0.0;
    }
    if cos_theta >= cos_inner {
        return 1.0;
    }
    let t = (cos_theta - cos_outer) / (cos_inner - cos_outer).max(1e-6);
    t * t
}

/// glTF `range` attenuation: a smooth window reaching zero at `range`.
#[inline]
pub fn range_window(dist: f32, range: f32) -> f32 {
    if !range.is_finite() {
        return 1.0;
    }
    let r = dist / range;
    (1.0 - r * r * r * r).clamp(0.0, 1.0)
}

impl Light {
    /// Samples the delta lights (point, spot, directional) from `p`; other lights are sampled
    /// by the scene, which knows their geometry.
    #[inline]
    pub fn sample_delta(&self, p: Vec3A) -> Option<LightSample> {
        match *self {
            Light::Point {
                position,
                intensity,
                range,
            } => {
                let to = position - p;
                let d2 = to.length_squared();
                let dist = d2.sqrt();
                if !(dist > 0.0) {
                    return None;
                }
                let li = intensity * (range_window(dist, range) / d2);
                Some(LightSample {
                    wi: to / dist,
                    li,
                    pdf: 1.0,
                    dist,
                    delta: true,
                    p_light: position,
                    n_light: Vec3A::ZERO,
                })
            }
            Light::Spot {
                position,
                axis,
                intensity,
                cos_inner,
                cos_outer,
                range,
            } => {
                let to = position - p;
                let d2 = to.length_squared();
                let dist = d2.sqrt();
                if !(dist > 0.0) {
                    return None;
                }
                let wi = to / dist;
                let f =
                    spot_falloff((-wi).dot(axis), cos_inner, cos_outer) * range_window(dist, range);
                if f <= 0.0 {
                    return None;
                }
                Some(LightSample {
                    wi,
                    li: intensity * (f / d2),
                    pdf: 1.0,
                    dist,
                    delta: true,
                    p_light: position,
                    n_light: Vec3A::ZERO,
                })
            }
            Light::Directional {
                to_light,
                irradiance,
            } => Some(LightSample {
                wi: to_light,
                li: irradiance,
                pdf: 1.0,
                dist: f32::INFINITY,
                delta: true,
                p_light: p + to_light,
                n_light: Vec3A::ZERO,
            }),
            _ => None,
        }
    }

    /// Power estimate used to choose lights (`scene_radius` sizes infinite lights).
    pub fn power(&self, scene_radius: f32, env_power: f32) -> f32 {
        match *self {
            Light::Point { intensity, .. } => 4.0 * PI * luminance(intensity),
            Light::Spot {
                intensity,
                cos_inner,
                cos_outer,
                ..
            } => 2.0 * PI * luminance(intensity) * (1.0 - 0.5 * (cos_inner + cos_outer)),
            Light::Directional { irradiance, .. } => {
                PI * scene_radius * scene_radius * luminance(irradiance)
            }
            Light::Area { power, .. } => power,
            Light::Environment => env_power,
        }
    }
}

/// The lights of a scene with the distribution used to pick one.
#[derive(Clone, Debug, Default)]
pub struct LightSet {
    /// Every light.
    pub lights: Vec<Light>,
    /// Selection probabilities (∝ power).
    pub select: Distribution1D,
    /// Index of the environment light in `lights`, if any.
    pub environment: Option<u32>,
}

impl LightSet {
    /// Builds the selection distribution.
    pub fn new(lights: Vec<Light>, scene_radius: f32, env_power: f32) -> Self {
        let powers: Vec<f32> = lights
            .iter()
            .map(|l| l.power(scene_radius, env_power))
            .collect();
        // A light with zero estimated power can still matter (a tiny but bright emitter):
        // keep every light selectable with a small floor.
        let max = powers.iter().cloned().fold(0.0f32, f32::max);
        let floor = if max > 0.0 { max * 1e-4 } else { 1.0 };
        let weights: Vec<f32> = powers
            .iter()
            .map(|&p| if p.is_finite() { p.max(floor) } else { floor })
            .collect();
        let environment = lights
            .iter()
            .position(|l| matches!(l, Light::Environment))
            .map(|i| i as u32);
        Self {
            select: Distribution1D::new(&weights),
            lights,
            environment,
        }
    }

    /// Picks a light: (index, probability).
    #[inline]
    pub fn choose(&self, u: f32) -> Option<(usize, f32, f32)> {
        if self.lights.is_empty() {
            return None;
        }
        Some(self.select.sample_discrete(u))
    }

    /// Probability that [`LightSet::choose`] picks light `i`.
    #[inline]
    pub fn pmf(&self, i: usize) -> f32 {
        if self.lights.is_empty() {
            0.0
        } else {
            self.select.discrete_pdf(i)
        }
    }
}

/// Converts an area density at a point on a light to a solid-angle density at the receiver.
#[inline]
pub fn area_to_solid_angle(pdf_area: f32, dist2: f32, cos_light: f32) -> f32 {
    if cos_light.abs() <= 1e-7 {
        0.0
    } else {
        pdf_area * dist2 / cos_light.abs()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_light_falls_off_with_distance_squared() {
        let l = Light::Point {
            position: Vec3A::new(0.0, 2.0, 0.0),
            intensity: Vec3A::splat(8.0),
            range: f32::INFINITY,
        };
        let s = l.sample_delta(Vec3A::ZERO).unwrap();
        assert!((s.li.x - 2.0).abs() < 1e-6 && s.delta && (s.wi - Vec3A::Y).length() < 1e-6);
    }

    #[test]
    fn spot_cones() {
        assert_eq!(spot_falloff(1.0, 0.9, 0.8), 1.0);
        assert_eq!(spot_falloff(0.7, 0.9, 0.8), 0.0);
        assert!((spot_falloff(0.85, 0.9, 0.8) - 0.25).abs() < 1e-5);
        assert_eq!(range_window(5.0, 4.0), 0.0);
        assert_eq!(range_window(1.0, f32::INFINITY), 1.0);
    }

    #[test]
    fn selection_follows_power() {
        let set = LightSet::new(
            vec![
                Light::Point {
                    position: Vec3A::ZERO,
                    intensity: Vec3A::ONE,
                    range: f32::INFINITY,
                },
                Light::Point {
                    position: Vec3A::ZERO,
                    intensity: Vec3A::splat(3.0),
                    range: f32::INFINITY,
                },
            ],
            1.0,
            0.0,
        );
        assert!((set.pmf(0) - 0.25).abs() < 1e-5 && (set.pmf(1) - 0.75).abs() < 1e-5);
    }
}
