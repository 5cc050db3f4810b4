//! Lights: point, spot, directional, area (emissive triangles and shapes, in [`area`]) and
//! environment (in [`environment`]).
//!
//! A light is chosen for next-event estimation in proportion to its (estimated) power by a
//! [`LightSet`] (pbrt-v4's light sampler), then a point or direction is sampled on it. The
//! scene owns its lights; a render job owns the environment and the light set, since both
//! depend on the job (an environment of its own, the default light or none). Everything a
//! light needs (its geometry, the scene's bounding sphere) is given to it when it is made, so
//! sampling is a pure function of the light and the random numbers.

pub mod area;
pub mod environment;

pub use area::AreaLight;
pub use environment::Environment;

use crate::sampling::distrib::Distribution1D;
use glam::{Vec2, Vec3A};
use std::f32::consts::PI;

/// The largest radiance (W·sr⁻¹·m⁻²: emission, environment), radiant intensity (W/sr: point
/// and spot lights) or irradiance (W/m²: directional lights) a scene or a job may give, per
/// channel: 10^30, strengths and scales included. Every physical source is far below it (the
/// sun's luminance is about 1.6·10^9 cd/m², its intensity seen from the Earth as a point light
/// about 3·10^27 cd), and it leaves eight orders of magnitude below f32's largest value
/// (3.4·10^38) for what a path multiplies light by and for the sums of a pixel's samples.
pub const MAX_RADIANCE: f32 = 1e30;

/// A number as messages show it: plain when ordinary, in scientific notation when huge or tiny.
pub fn show_number(x: f32) -> String {
    if x != 0.0 && x.is_finite() && !(1e-4..1e7).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// Checks the value of a light (`what`, named in the message): finite, non-negative and at
/// most [`MAX_RADIANCE`] in every channel.
pub fn check_radiance(what: &str, v: Vec3A) -> Result<(), String> {
    let got = || {
        format!(
            "[{}, {}, {}]",
            show_number(v.x),
            show_number(v.y),
            show_number(v.z)
        )
    };
    if !(v.is_finite() && v.min_element() >= 0.0) {
        return Err(format!(
            "{what} must be finite and non-negative, got {}",
            got()
        ));
    }
    if v.max_element() > MAX_RADIANCE {
        return Err(format!(
            "{what} must be at most 1e30 in every channel (the largest radiance raytile \
             takes), got {}",
            got()
        ));
    }
    Ok(())
}

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
    /// Triangle `prim` of an emitting mesh, or a whole emitting shape (`prim` 0).
    Area {
        /// Index of the [`AreaLight`] in the scene.
        light: u32,
        /// Triangle index within its mesh (0 for analytic shapes).
        prim: u32,
        /// Emitted power estimate, for selection.
        power: f32,
    },
}

/// A sampled light: incident direction at the shading point, radiance arriving along it, its
/// density, and where the shadow ray must stop.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the shading point towards the light.
    pub wi: Vec3A,
    /// Radiance (or, for delta lights, intensity/distance² or irradiance) arriving along `wi`.
    pub li: Vec3A,
    /// Solid-angle density of `wi`; 1 for delta lights, whose estimate is `li` itself.
    pub pdf: f32,
    /// Distance to the sampled point (infinite for directional and environment lights: the
    /// shadow ray then goes along `wi` without end).
    pub dist: f32,
    /// Whether the light is a delta distribution (point, spot, directional: no MIS with BSDF
    /// sampling, which can never find it).
    pub delta: bool,
    /// The point on the light, to spawn the shadow ray towards (when `dist` is finite).
    pub p_light: Vec3A,
    /// Front normal at the point on the light, zero for a point in space (point and spot).
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
    /// Whether the light is a delta distribution (point, spot, directional): no ray finds it.
    #[inline]
    pub fn is_delta(&self) -> bool {
        !matches!(self, Light::Area { .. })
    }

    /// Samples the delta lights (point, spot, directional) from `p`; area lights sample
    /// themselves ([`AreaLight::sample`]).
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

    /// Power estimate used to choose lights (`scene_radius` sizes directional lights).
    pub fn power(&self, scene_radius: f32) -> f32 {
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
        }
    }
}

/// The distributions that pick a light, over a scene's lights (by index) and then, if there is
/// one, the job's environment (the last index):
///
/// - for next-event estimation ([`LightSet::choose_in`], [`LightSet::pmf`]): by power, but
///   where a scene has both finite lights (points, spots, emitting surfaces) and lights at
///   infinity (the environment, directional lights), each light at infinity gets one share and
///   the finite lights together one share (pbrt-v4's `BVHLightSampler` does the same), split
///   by power within each group. The power of a light at infinity is what crosses the scene's
///   bounding disc, so it grows with the scene's extent: on a wide floor lit by a lamp and the
///   sky, by power alone the sky took 97 % of the light samples and the lamp's light came from
///   a few of them (the image's MSE at 64 spp was 230 times as large; docs/speed.md);
/// - for starting paths at the lights (`bdpt`'s light subpaths, `sppm`'s photons:
///   [`LightSet::choose`], [`LightSet::emission_pmf`]): by power, so that every path carries
///   about the same light.
#[derive(Clone, Debug, Default)]
pub struct LightSet {
    /// Selection for next-event estimation.
    select: Distribution1D,
    /// Selection by power, for emission.
    emit: Distribution1D,
    /// Number of lights, the environment included.
    len: usize,
    /// Index of the environment, if any: `lights.len()`.
    environment: Option<usize>,
    /// Selection among the delta lights alone (point, spot, directional) with the shares
    /// `select` gives them, and their indices; empty without one.
    delta: Distribution1D,
    delta_index: Vec<u32>,
}

impl LightSet {
    /// The selection distribution for `lights` and, with `environment_power`, an environment
    /// of that power after them; `scene_radius` sizes directional lights.
    pub fn new(lights: &[Light], scene_radius: f32, environment_power: Option<f32>) -> Self {
        let powers: Vec<f32> = lights
            .iter()
            .map(|l| l.power(scene_radius))
            .chain(environment_power)
            .collect();
        // A light with zero estimated power can still matter (a tiny but bright emitter):
        // keep every light selectable with a small floor.
        let max = powers.iter().cloned().fold(0.0f32, f32::max);
        let floor = if max > 0.0 { max * 1e-4 } else { 1.0 };
        let weights: Vec<f32> = powers
            .iter()
            .map(|&p| if p.is_finite() { p.max(floor) } else { floor })
            .collect();
        let at_infinity: Vec<bool> = lights
            .iter()
            .map(|l| matches!(l, Light::Directional { .. }))
            .chain(environment_power.map(|_| true))
            .collect();
        let direct = group_shares(&weights, &at_infinity);
        let delta_index: Vec<u32> = (0..lights.len() as u32)
            .filter(|&i| lights[i as usize].is_delta())
            .collect();
        let delta_weights: Vec<f32> = delta_index.iter().map(|&i| direct[i as usize]).collect();
        Self {
            delta: if delta_index.is_empty() {
                Distribution1D::default()
            } else {
                Distribution1D::new(&delta_weights)
            },
            delta_index,
            select: Distribution1D::new(&direct),
            emit: Distribution1D::new(&weights),
            len: powers.len(),
            environment: environment_power.map(|_| lights.len()),
        }
    }

    /// Number of lights, the environment included.
    #[inline]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there is no light at all.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The environment's index, if there is one.
    #[inline]
    pub fn environment(&self) -> Option<usize> {
        self.environment
    }

    /// Picks a light to start a path at, by power: (index, probability).
    #[inline]
    pub fn choose(&self, u: f32) -> Option<(usize, f32)> {
        if self.len == 0 {
            return None;
        }
        let (i, p, _) = self.emit.sample_discrete(u);
        Some((i, p))
    }

    /// Probability that [`LightSet::choose`] picks light `i`.
    #[inline]
    pub fn emission_pmf(&self, i: usize) -> f32 {
        if self.len == 0 {
            0.0
        } else {
            self.emit.discrete_pdf(i)
        }
    }

    /// Picks a light with `u.x` and stretches `u.x` back over [0, 1) within the chosen light's
    /// share: (index, probability, the point for sampling that light). The point keeps the
    /// stratification of `u` (Mitsuba 3's `sample_emitter` does the same): measured on the
    /// Cornell box and on the Cornell box with a million-triangle sphere (two lights, the
    /// emitting quad's triangles), 0.7–1 % less RMSE at equal samples than a separate hashed
    /// number for the choice, at no cost. `jitter` ∈ [0, 1) refines `u.x` below the samplers'
    /// grid ([`Distribution1D::sample_discrete_fine`]), so that a light with a tiny share (one
    /// of a million emitting triangles) still gets a continuum of points.
    #[inline]
    pub fn choose_in(&self, u: Vec2, jitter: f32) -> Option<(usize, f32, Vec2)> {
        if self.len == 0 {
            return None;
        }
        let (i, p, x) = self.select.sample_discrete_fine(u.x, jitter);
        Some((i, p, Vec2::new(x, u.y)))
    }

    /// Picks one of the delta lights (point, spot, directional: those no ray can hit) with
    /// `u` refined by `jitter`, in proportion to their shares in [`LightSet::choose_in`]:
    /// (index, probability). `None` without one.
    #[inline]
    pub fn choose_delta(&self, u: f32, jitter: f32) -> Option<(usize, f32)> {
        if self.delta_index.is_empty() {
            return None;
        }
        let (i, p, _) = self.delta.sample_discrete_fine(u, jitter);
        Some((self.delta_index[i] as usize, p))
    }

    /// Probability that [`LightSet::choose_in`] picks light `i`.
    #[inline]
    pub fn pmf(&self, i: usize) -> f32 {
        if self.len == 0 {
            0.0
        } else {
            self.select.discrete_pdf(i)
        }
    }
}

/// Selection weights for next-event estimation from the power `weights` of lights, some of them
/// `at_infinity` (see [`LightSet`]): unchanged unless there are lights of both kinds; then each
/// light at infinity weighs, on average, as much as all the finite lights together, the two
/// groups split by power within.
fn group_shares(weights: &[f32], at_infinity: &[bool]) -> Vec<f32> {
    let sum = |infinite: bool| -> f64 {
        weights
            .iter()
            .zip(at_infinity)
            .filter(|(_, &i)| i == infinite)
            .map(|(&w, _)| w as f64)
            .sum()
    };
    let (finite, infinite) = (sum(false), sum(true));
    let n_infinite = at_infinity.iter().filter(|&&i| i).count() as f64;
    if !(finite > 0.0 && infinite > 0.0 && (finite + infinite).is_finite()) {
        return weights.to_vec();
    }
    // Shares of the whole, in f64 (no weight overflows f32 on the way): the finite lights
    // 1 / (n + 1) together, the n lights at infinity n / (n + 1).
    let (to_finite, to_infinite) = (
        1.0 / ((n_infinite + 1.0) * finite),
        n_infinite / ((n_infinite + 1.0) * infinite),
    );
    weights
        .iter()
        .zip(at_infinity)
        .map(|(&w, &i)| (w as f64 * if i { to_infinite } else { to_finite }) as f32)
        .collect()
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
        assert_eq!((s.pdf, s.dist, s.n_light), (1.0, 2.0, Vec3A::ZERO));
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
            &[
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
            None,
        );
        assert!((set.pmf(0) - 0.25).abs() < 1e-5 && (set.pmf(1) - 0.75).abs() < 1e-5);
        assert_eq!((set.len(), set.environment()), (2, None));
        // An environment comes last: chosen by its power to start paths, and as often as the
        // finite lights together for next-event estimation.
        let point = Light::Point {
            position: Vec3A::ZERO,
            intensity: Vec3A::ONE,
            range: f32::INFINITY,
        };
        let p = point.power(1.0);
        let set = LightSet::new(&[point], 1.0, Some(3.0 * p));
        assert_eq!((set.len(), set.environment()), (2, Some(1)));
        assert!((set.emission_pmf(1) - 0.75).abs() < 1e-5);
        assert!((set.pmf(1) - 0.5).abs() < 1e-5);
        assert_eq!(set.choose(0.9).map(|c| c.0), Some(1));
        assert!(LightSet::new(&[], 1.0, None).choose(0.5).is_none());
        assert!(LightSet::new(&[], 1.0, None)
            .choose_in(Vec2::splat(0.5), 0.5)
            .is_none());
    }

    /// `choose_delta` picks among the point, spot and directional lights alone, in the
    /// proportions `choose_in` gives them, never an area light or the environment.
    #[test]
    fn the_delta_choice_keeps_the_delta_lights_shares() {
        let point = |i: f32| Light::Point {
            position: Vec3A::ZERO,
            intensity: Vec3A::splat(i),
            range: f32::INFINITY,
        };
        let area = || Light::Area {
            light: 0,
            prim: 0,
            power: 50.0,
        };
        let lights = [area(), point(1.0), area(), point(3.0)];
        let set = LightSet::new(&lights, 1.0, Some(10.0));
        let mut got = [0.0f32; 5];
        let n = 4000;
        for k in 0..n {
            let (i, pmf) = set.choose_delta((k as f32 + 0.5) / n as f32, 0.5).unwrap();
            assert!(lights[i].is_delta(), "picked light {i}");
            let want = set.pmf(i) / (set.pmf(1) + set.pmf(3));
            assert!((pmf - want).abs() < 1e-5, "light {i}: {pmf} against {want}");
            got[i] += 1.0 / n as f32;
        }
        assert!(
            (got[1] - 0.25).abs() < 1e-3 && (got[3] - 0.75).abs() < 1e-3,
            "{got:?}"
        );
        assert!(LightSet::new(&[area()], 1.0, Some(1.0))
            .choose_delta(0.5, 0.5)
            .is_none());
    }

    /// Lights at infinity (a directional light, the environment) and finite ones: for
    /// next-event estimation each light at infinity has, on average, the share of all the
    /// finite lights together, whatever the scene's size; within each group, and to start
    /// paths, by power.
    #[test]
    fn lights_at_infinity_share_with_the_finite_ones_by_count_then_by_power() {
        let point = |i: f32| Light::Point {
            position: Vec3A::ZERO,
            intensity: Vec3A::splat(i),
            range: f32::INFINITY,
        };
        let sun = Light::Directional {
            to_light: Vec3A::Y,
            irradiance: Vec3A::splat(1.0),
        };
        for radius in [1.0, 100.0] {
            let sun_power = sun.power(radius);
            let lights = [point(1.0), sun.clone(), point(3.0)];
            let set = LightSet::new(&lights, radius, Some(3.0 * sun_power));
            // Two lights at infinity: each group weight a third on average; the finite third
            // split 1 : 3, the infinite two thirds 1 : 3 (sun : environment).
            let want = [1.0 / 12.0, 2.0 / 3.0 / 4.0, 3.0 / 12.0, 2.0 / 3.0 * 0.75];
            for (i, w) in want.iter().enumerate() {
                assert!(
                    (set.pmf(i) - w).abs() < 1e-5,
                    "{radius}: {i}: {}",
                    set.pmf(i)
                );
            }
            let powers = [
                point(1.0).power(radius),
                sun_power,
                point(3.0).power(radius),
            ];
            let total = powers.iter().sum::<f32>() + 3.0 * sun_power;
            assert!((set.emission_pmf(0) - powers[0] / total).abs() < 1e-5);
            assert!((set.emission_pmf(3) - 3.0 * sun_power / total).abs() < 1e-5);
        }
        // Powers near f32's largest: no share overflows and none is lost.
        let huge = |i: f32| Light::Point {
            position: Vec3A::ZERO,
            intensity: Vec3A::splat(i),
            range: f32::INFINITY,
        };
        let set = LightSet::new(&[huge(1e37), huge(1e37), sun.clone()], 1.0, None);
        assert!((set.pmf(2) - 0.5).abs() < 1e-5 && (set.pmf(0) - 0.25).abs() < 1e-5);
        // One kind only: by power, both ways.
        let set = LightSet::new(std::slice::from_ref(&sun), 1.0, Some(sun.power(1.0)));
        assert!((set.pmf(1) - 0.5).abs() < 1e-5 && (set.emission_pmf(1) - 0.5).abs() < 1e-5);
    }

    #[test]
    fn choosing_in_a_point_keeps_its_stratification() {
        // Lights of power 1, 3 and 4: 1000 evenly spaced numbers pick each light in
        // proportion, and the numbers that picked a light, stretched back, are again evenly
        // spaced over [0, 1) (so a stratified 2D point stays stratified on the light).
        let point = |i: f32| Light::Point {
            position: Vec3A::ZERO,
            intensity: Vec3A::splat(i),
            range: f32::INFINITY,
        };
        let set = LightSet::new(&[point(1.0), point(3.0), point(4.0)], 1.0, None);
        let n = 1000;
        let mut xs: [Vec<f32>; 3] = Default::default();
        for k in 0..n {
            let u = Vec2::new((k as f32 + 0.5) / n as f32, 0.25);
            let (i, pmf, v) = set.choose_in(u, 0.5).unwrap();
            assert_eq!(pmf, set.pmf(i));
            assert_eq!(v.y, 0.25);
            assert!((0.0..1.0).contains(&v.x));
            xs[i].push(v.x);
        }
        for (i, x) in xs.iter().enumerate() {
            assert_eq!(
                x.len(),
                (n as f32 * set.pmf(i)).round() as usize,
                "light {i}"
            );
            // Sorted already (the stretch is monotonic), one per 1/len-wide stratum.
            for (j, v) in x.iter().enumerate() {
                let stratum = (v * x.len() as f32) as usize;
                assert!(
                    stratum.abs_diff(j) <= 1,
                    "light {i}: {v} at {j} of {}",
                    x.len()
                );
            }
        }
    }
}
