//! Distance sampling and transmittance through media with majorants: pbrt-v4's `SampleT_maj`
//! (delta tracking driven by a callback), and ratio tracking for shadow rays.
//!
//! Every random number comes from a caller-provided [`RandomSource`], so a path's media
//! decisions depend only on what seeded it (pixel, sample index, seed), never on tiles or
//! threads. Exponentials and logarithms use [`crate::sampling::detmath`], not the C library.

use super::majorant::MajorantSegment;
use super::{Medium, MediumProperties};
use crate::geometry::Ray;
use crate::sampling::detmath::{exp3, ln};
use crate::sampling::{hash_u32, Sampler};
use glam::Vec3A;

/// A source of uniform random numbers in [0, 1) for the tracking code: a small trait, called
/// with static dispatch.
pub trait RandomSource {
    /// The next number in [0, 1).
    fn next_1d(&mut self) -> f32;
}

/// The renderer's sampler can drive tracking directly; but the number of draws varies from
/// path to path, so an integrator that wants the later bounces of a path to keep their own
/// Sobol dimensions should seed a [`HashRng`] from one sampler dimension instead (as pbrt-v4
/// seeds an `RNG` for its media).
impl RandomSource for Sampler {
    #[inline]
    fn next_1d(&mut self) -> f32 {
        Sampler::next_1d(self)
    }
}

/// A counter-based generator: the `i`-th number is a hash of (seed, i), so a stream is fixed by
/// its seed alone.
#[derive(Clone, Debug)]
pub struct HashRng {
    key: u32,
    counter: u32,
}

impl HashRng {
    /// The stream for `seed` (derive it from the pixel, sample index and render seed, e.g.
    /// `(sampler.next_1d() * 2³²) as u32`).
    #[inline]
    pub fn new(seed: u32) -> Self {
        Self {
            key: hash_u32(seed ^ 0x6c07_8965),
            counter: 0,
        }
    }
}

impl RandomSource for HashRng {
    #[inline]
    fn next_1d(&mut self) -> f32 {
        let bits = hash_u32(hash_u32(self.counter) ^ self.key);
        self.counter = self.counter.wrapping_add(1);
        (bits >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }
}

/// A tentative collision handed to the [`sample_t_maj`] callback.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Collision {
    /// The ray parameter of the point, in the units of the caller's `ray.d` (the distance for a
    /// unit direction).
    pub t: f32,
    /// The point, in world space.
    pub p: Vec3A,
    /// σa, σs and the phase function there.
    pub props: MediumProperties,
    /// The majorant at the point (≥ σt per channel).
    pub sigma_maj: Vec3A,
    /// exp(−∫σ_maj) from the previous collision (or the ray's origin) to this point, per
    /// channel.
    pub t_maj: Vec3A,
}

/// Samples tentative collisions along `ray` in `medium` up to parameter `t_max` (pbrt-v4's
/// `SampleT_maj`).
///
/// Distances are exponential steps with the majorant σ_maj of colour `channel` (0, 1 or 2),
/// segment by segment. At each collision `callback` gets the [`Collision`] and the random
/// source, and returns `true` to keep walking (a null collision) or `false` to stop (absorption
/// or scattering, as the caller decides). Returns exp(−∫σ_maj) per channel from the last
/// collision to `t_max` when the walk reached the end, (1, 1, 1) when the callback stopped
/// it, or (0, 0, 0) when it was cut off after [`MAX_COLLISIONS`] collisions (the path is
/// absorbed). Empty stretches (σ_maj = 0 in `channel`) cost no random numbers and no callback.
///
/// `ray.d` need not be unit (coefficients are per unit of distance); `t_max` may be infinite
/// (a ray leaving the scene in a global medium).
pub fn sample_t_maj<R, F>(
    medium: &Medium,
    ray: &Ray,
    t_max: f32,
    channel: usize,
    rng: &mut R,
    mut callback: F,
) -> Vec3A
where
    R: RandomSource,
    F: FnMut(&Collision, &mut R) -> bool,
{
    let channel = channel.min(2);
    let len = ray.d.length();
    if !(len > 0.0 && len.is_finite() && t_max > 0.0) {
        return Vec3A::ONE;
    }
    // Walk a unit direction, so that t is distance; report t in the caller's units.
    let d = ray.d / len;
    let t_end = t_max * len;
    let inv_len = 1.0 / len;
    match medium {
        Medium::Homogeneous(h) => {
            let props = h.properties();
            walk(
                h.majorants(t_end),
                |_| props,
                ray.o,
                d,
                inv_len,
                channel,
                rng,
                &mut callback,
            )
        }
        Medium::Grid(g) => {
            let (ou, du) = g.ray_to_unit(ray.o, d);
            walk(
                g.majorants_unit(ou, du, t_end, 1.0),
                |t| g.properties_unit(ou + du * t),
                ray.o,
                d,
                inv_len,
                channel,
                rng,
                &mut callback,
            )
        }
    }
}

/// exp(−σ·dt) per channel, with an infinite `dt` meaning "as far as f32 goes", so that a zero
/// majorant gives 1 rather than exp(−0·∞) = NaN.
#[inline]
fn segment_transmittance(sigma: Vec3A, dt: f32) -> Vec3A {
    let dt = if dt.is_infinite() { f32::MAX } else { dt };
    exp3(-sigma * dt)
}

/// A distance with density a·e^(−a·t), from uniform `u` in [0, 1).
#[inline]
fn sample_exponential(u: f32, a: f32) -> f32 {
    -ln(1.0 - u) / a
}

/// The most collisions one walk of [`sample_t_maj`] proposes. A medium whose majorant is far
/// above its density along a long stretch (one voxel of 10^30 in an empty grid under a coarse
/// majorant, say) would otherwise propose about majorant × distance null collisions: a sample
/// that never ends, and a worker that cannot hand back its tile. A walk that reaches the cap
/// ends as absorbed ([`sample_t_maj`] returns zero), which only such media ever see: a
/// sensible one proposes a few collisions per unit of optical depth and stops at the first
/// real one. The cap depends on the path's own random numbers alone, so images keep their
/// bits on every machine.
pub const MAX_COLLISIONS: u32 = 1 << 16;

/// The loop of [`sample_t_maj`] for one medium's segments and point lookup.
#[allow(clippy::too_many_arguments)]
#[inline]
fn walk<I, P, R, F>(
    segments: I,
    props_at: P,
    o: Vec3A,
    d: Vec3A,
    inv_len: f32,
    channel: usize,
    rng: &mut R,
    callback: &mut F,
) -> Vec3A
where
    I: Iterator<Item = MajorantSegment>,
    P: Fn(f32) -> MediumProperties,
    R: RandomSource,
    F: FnMut(&Collision, &mut R) -> bool,
{
    let mut t_maj = Vec3A::ONE;
    let mut collisions = 0u32;
    for seg in segments {
        let sm = seg.sigma_maj[channel];
        if !(sm > 0.0) {
            t_maj *= segment_transmittance(seg.sigma_maj, seg.t_max - seg.t_min);
            continue;
        }
        let mut t_min = seg.t_min;
        loop {
            let t = t_min + sample_exponential(rng.next_1d(), sm);
            if t < seg.t_max {
                collisions += 1;
                if collisions > MAX_COLLISIONS {
                    return Vec3A::ZERO;
                }
                t_maj *= exp3(-(t - t_min) * seg.sigma_maj);
                let c = Collision {
                    t: t * inv_len,
                    p: o + d * t,
                    props: props_at(t),
                    sigma_maj: seg.sigma_maj,
                    t_maj,
                };
                if !callback(&c, rng) {
                    return Vec3A::ONE;
                }
                t_maj = Vec3A::ONE;
                t_min = t;
            } else {
                t_maj *= segment_transmittance(seg.sigma_maj, seg.t_max - t_min);
                break;
            }
        }
    }
    t_maj
}

/// An unbiased estimate of the transmittance exp(−∫σt) per channel along `ray` up to `t_max`,
/// by ratio tracking (for shadow rays).
///
/// The colour channel whose majorant drives the distances is chosen at random, and the
/// estimate is weighted by the balance heuristic over the three channels (one-sample spectral
/// MIS, as pbrt-v4 and Mitsuba 3 do for chromatic media), so a medium whose σt differs per
/// channel converges in every channel without huge weights. Walks whose estimate drops below
/// 0.05 go through Russian roulette. The estimate is per channel in [0, ∞) with mean the
/// transmittance.
pub fn transmittance<R: RandomSource>(
    medium: &Medium,
    ray: &Ray,
    t_max: f32,
    rng: &mut R,
) -> Vec3A {
    let channel = ((rng.next_1d() * 3.0) as usize).min(2);
    // `f`: the estimator's numerator, ∏ T_maj·σ_n; `p`: the density of the same events had
    // each channel driven the walk, ∏ T_maj·σ_maj. Both are rescaled by the driving channel's
    // density after each step (only f / mean(p) matters), so long walks stay in range.
    let mut f = Vec3A::ONE;
    let mut p = Vec3A::ONE;
    let end = sample_t_maj(medium, ray, t_max, channel, rng, |c, rng| {
        let sigma_n = (c.sigma_maj - c.props.sigma_t()).max(Vec3A::ZERO);
        f *= c.t_maj * sigma_n;
        p *= c.t_maj * c.sigma_maj;
        let s = p[channel];
        if !(s > 0.0) || f == Vec3A::ZERO {
            f = Vec3A::ZERO;
            return false;
        }
        f /= s;
        p /= s;
        let estimate = f / (p.element_sum() / 3.0);
        if estimate.max_element() < 0.05 {
            const Q: f32 = 0.75;
            if rng.next_1d() < Q {
                f = Vec3A::ZERO;
                return false;
            }
            f /= 1.0 - Q;
        }
        true
    });
    if f == Vec3A::ZERO {
        return Vec3A::ZERO;
    }
    let f = f * end;
    let mean_p = (p * end).element_sum() / 3.0;
    if mean_p > 0.0 {
        f / mean_p
    } else {
        Vec3A::ZERO
    }
}

/// Delta tracking in one colour channel: the first real collision along `ray` before `t_max`
/// (a tentative collision is real with probability σt/σ_maj of `channel`), or `None` when the
/// ray gets through, which happens with probability exp(−∫σt) of that channel. For media whose
/// σt is the same in every channel, or for one channel of a chromatic one; a spectral
/// integrator uses [`sample_t_maj`] with its own weights instead.
pub fn delta_tracking<R: RandomSource>(
    medium: &Medium,
    ray: &Ray,
    t_max: f32,
    channel: usize,
    rng: &mut R,
) -> Option<Collision> {
    let channel = channel.min(2);
    let mut hit = None;
    sample_t_maj(medium, ray, t_max, channel, rng, |c, rng| {
        let real = c.props.sigma_t()[channel] / c.sigma_maj[channel];
        if rng.next_1d() < real {
            hit = Some(*c);
            false
        } else {
            true
        }
    });
    hit
}

#[cfg(test)]
mod tests {
    use super::super::{DensityGrid, GridMedium, HomogeneousMedium, NoiseDensity};
    use super::*;
    use crate::geometry::Aabb;

    const N: u32 = 20_000;

    /// Mean and standard error of `n` samples of `f(rng)` (each sample gets its own stream).
    fn estimate(n: u32, mut f: impl FnMut(&mut HashRng) -> Vec3A) -> (Vec3A, Vec3A) {
        let (mut sum, mut sum2) = (glam::DVec3::ZERO, glam::DVec3::ZERO);
        for i in 0..n {
            let v = f(&mut HashRng::new(i)).as_dvec3();
            sum += v;
            sum2 += v * v;
        }
        let mean = sum / n as f64;
        let var = (sum2 / n as f64 - mean * mean).max(glam::DVec3::ZERO);
        (
            mean.as_vec3().into(),
            (var / n as f64).map(f64::sqrt).as_vec3().into(),
        )
    }

    /// Asserts `got` is within 4 standard errors (plus a float margin) of `want`, per channel.
    fn check(what: &str, (mean, err): (Vec3A, Vec3A), want: Vec3A) {
        for k in 0..3 {
            let tol = 4.0 * err[k] + 1e-4;
            assert!(
                (mean[k] - want[k]).abs() <= tol,
                "{what}: channel {k}: {} vs exact {} (tolerance {tol})",
                mean[k],
                want[k]
            );
        }
    }

    fn exact(optical_depth: Vec3A) -> Vec3A {
        optical_depth
            .to_array()
            .map(|x| (-x as f64).exp() as f32)
            .into()
    }

    fn homogeneous(sigma_t: Vec3A) -> Medium {
        // Half absorption, half scattering: transmittance depends on σt only.
        Medium::Homogeneous(HomogeneousMedium::new(sigma_t * 0.5, sigma_t * 0.5, 0.3).unwrap())
    }

    fn constant_grid(density: f32, sigma_t: Vec3A) -> Medium {
        let g = DensityGrid::new(
            [4, 3, 5],
            Aabb::new(Vec3A::ZERO, Vec3A::ONE),
            vec![density; 60],
        )
        .unwrap();
        Medium::Grid(Box::new(
            GridMedium::new(g, sigma_t * 0.25, sigma_t * 0.75, 0.0).unwrap(),
        ))
    }

    /// Delta tracking's escape probability, as a colour (the same in each channel).
    fn escaped(m: &Medium, ray: &Ray, t_max: f32, channel: usize, rng: &mut HashRng) -> Vec3A {
        Vec3A::splat(delta_tracking(m, ray, t_max, channel, rng).is_none() as u32 as f32)
    }

    #[test]
    fn beer_lambert_through_a_homogeneous_slab() {
        let ray = Ray::new(Vec3A::ZERO, Vec3A::new(0.0, 0.6, 0.8));
        for (sigma, d) in [(1.0, 1.0), (0.3, 2.5), (4.0, 0.7), (0.0, 3.0)] {
            let m = homogeneous(Vec3A::splat(sigma));
            let want = exact(Vec3A::splat(sigma * d));
            check(
                "ratio",
                estimate(N, |r| transmittance(&m, &ray, d, r)),
                want,
            );
            check("delta", estimate(N, |r| escaped(&m, &ray, d, 0, r)), want);
        }
    }

    #[test]
    fn beer_lambert_through_a_grid_of_constant_density() {
        // The unit box, crossed diagonally in x and y at z = 0.5 from outside: the path length
        // inside is √2.
        let ray = Ray::new(
            Vec3A::new(-1.0, -1.0, 0.5),
            Vec3A::new(1.0, 1.0, 0.0).normalize(),
        );
        for density in [0.5, 2.0] {
            let m = constant_grid(density, Vec3A::splat(1.5));
            let want = exact(Vec3A::splat(1.5 * density * 2f32.sqrt()));
            check(
                "ratio",
                estimate(N, |r| transmittance(&m, &ray, 10.0, r)),
                want,
            );
            check(
                "delta",
                estimate(N, |r| escaped(&m, &ray, 10.0, 1, r)),
                want,
            );
        }
        // Stopping halfway through the box.
        let m = constant_grid(1.0, Vec3A::ONE);
        let x = Ray::new(Vec3A::new(-1.0, 0.5, 0.5), Vec3A::X);
        check(
            "ratio, half",
            estimate(N, |r| transmittance(&m, &x, 1.5, r)),
            exact(Vec3A::splat(0.5)),
        );
    }

    /// One voxel of 10^29 in an empty grid under a single majorant cell: a walk through the
    /// empty part would propose some 10^29 null collisions. It is cut off after
    /// [`MAX_COLLISIONS`] and ends as absorbed, in both tracking estimators.
    #[test]
    fn walks_under_a_huge_majorant_are_cut_off() {
        let g = DensityGrid::from_fn([8, 8, 8], Aabb::new(Vec3A::ZERO, Vec3A::ONE), |p| {
            if p.cmplt(Vec3A::splat(0.125)).all() {
                1e29
            } else {
                0.0
            }
        })
        .unwrap();
        let m = Medium::Grid(Box::new(
            GridMedium::new(g, Vec3A::ONE, Vec3A::ONE, 0.0)
                .unwrap()
                .with_majorant_resolution([1, 1, 1]),
        ));
        // Through the empty far side of the box, x from 0 to 1 at y = z = 0.9.
        let ray = Ray::new(Vec3A::new(-1.0, 0.9, 0.9), Vec3A::X);
        let mut rng = HashRng::new(7);
        let mut calls = 0u32;
        let t = sample_t_maj(&m, &ray, 10.0, 0, &mut rng, |_, _| {
            calls += 1;
            true
        });
        assert_eq!((calls, t), (MAX_COLLISIONS, Vec3A::ZERO));
        assert_eq!(transmittance(&m, &ray, 10.0, &mut rng), Vec3A::ZERO);
    }

    #[test]
    fn beer_lambert_through_a_grid_with_empty_regions() {
        // Density 1 where x > 0.5: the trilinear ramp between the two middle voxel centres is
        // symmetric, so a ray along x through the whole box has optical depth σt · 0.5.
        let g = DensityGrid::from_fn([32, 4, 4], Aabb::new(Vec3A::ZERO, Vec3A::ONE), |p| {
            (p.x > 0.5) as u32 as f32
        })
        .unwrap();
        let m = Medium::Grid(Box::new(
            GridMedium::new(g, Vec3A::ONE, Vec3A::splat(1.0), 0.0).unwrap(),
        ));
        let ray = Ray::new(Vec3A::new(-2.0, 0.3, 0.6), Vec3A::X);
        let want = exact(Vec3A::splat(2.0 * 0.5));
        check(
            "ratio",
            estimate(N, |r| transmittance(&m, &ray, 10.0, r)),
            want,
        );
        check(
            "delta",
            estimate(N, |r| escaped(&m, &ray, 10.0, 2, r)),
            want,
        );
        // Through the empty half only: not a single collision, not a single random number.
        let mut calls = 0;
        let mut rng = HashRng::new(1);
        let t = sample_t_maj(&m, &ray, 2.4, 0, &mut rng, |_, _| {
            calls += 1;
            true
        });
        assert_eq!((calls, t), (0, Vec3A::ONE));
        assert_eq!(rng.counter, 0);
    }

    #[test]
    fn noise_grid_transmittance_matches_quadrature() {
        let noise = NoiseDensity::default();
        let g = DensityGrid::from_fn(
            [24, 24, 24],
            Aabb::new(Vec3A::splat(-1.0), Vec3A::ONE),
            |p| noise.density(p),
        )
        .unwrap();
        let gm = GridMedium::new(g, Vec3A::new(0.2, 0.5, 0.9), Vec3A::new(0.8, 0.5, 0.1), 0.0)
            .unwrap()
            .with_transform(glam::Affine3A::from_rotation_z(0.4))
            .unwrap();
        let m = Medium::Grid(Box::new(gm.clone()));
        let ray = Ray::new(
            Vec3A::new(-2.0, -0.5, -0.3),
            Vec3A::new(1.0, 0.3, 0.2).normalize(),
        );
        // Midpoint rule on the density along the ray.
        let steps = 40_000;
        let mut tau = Vec3A::ZERO;
        for i in 0..steps {
            let t = 5.0 * (i as f32 + 0.5) / steps as f32;
            tau += gm.properties(ray.at(t)).sigma_t() * (5.0 / steps as f32);
        }
        assert!(
            tau.min_element() > 0.3,
            "the ray must cross some smoke: {tau}"
        );
        let want = exact(tau);
        check(
            "ratio",
            estimate(N, |r| transmittance(&m, &ray, 5.0, r)),
            want,
        );
    }

    #[test]
    fn chromatic_media_converge_per_channel() {
        let sigma_t = Vec3A::new(0.4, 1.5, 3.0);
        let ray = Ray::new(Vec3A::new(-1.0, 0.5, 0.5), Vec3A::X);
        let want = exact(sigma_t * 1.0);
        let hom = homogeneous(sigma_t);
        let grid = constant_grid(1.0, sigma_t);
        check(
            "homogeneous",
            estimate(N, |r| {
                transmittance(&hom, &Ray::new(Vec3A::ZERO, Vec3A::X), 1.0, r)
            }),
            want,
        );
        check(
            "grid",
            estimate(N, |r| transmittance(&grid, &ray, 5.0, r)),
            want,
        );
        // The same grid with one majorant cell (a loose bound): the same mean.
        let Medium::Grid(g) = &grid else {
            unreachable!()
        };
        let coarse = Medium::Grid(Box::new((**g).clone().with_majorant_resolution([1, 1, 1])));
        check(
            "one cell",
            estimate(N, |r| transmittance(&coarse, &ray, 5.0, r)),
            want,
        );
        // A channel without extinction: walks it drives see no collisions at all, and the
        // other channels' walks weigh them in through the balance heuristic.
        let clear_red = Vec3A::new(0.0, 1.5, 3.0);
        let m = constant_grid(1.0, clear_red);
        check(
            "clear red",
            estimate(N, |r| transmittance(&m, &ray, 5.0, r)),
            exact(clear_red),
        );
        // Delta tracking, one channel at a time.
        for k in 0..3 {
            let (mean, err) = estimate(N, |r| escaped(&grid, &ray, 5.0, k, r));
            check(
                "delta",
                (Vec3A::splat(mean.x), Vec3A::splat(err.x)),
                Vec3A::splat(want[k]),
            );
        }
    }

    #[test]
    fn collisions_follow_the_majorant() {
        // Homogeneous: the first tentative collision is exponential with rate σ_maj of the
        // chosen channel (mean 1/σ), and the callback sees T_maj up to it.
        let m = homogeneous(Vec3A::new(2.0, 0.5, 1.0));
        let ray = Ray::new(Vec3A::ZERO, Vec3A::Z * 2.0);
        let (mut sum, mut n) = (0.0f64, 0);
        for i in 0..N {
            sample_t_maj(&m, &ray, f32::INFINITY, 0, &mut HashRng::new(i), |c, _| {
                assert!((c.p - ray.at(c.t)).length() < 1e-4);
                let dist = 2.0 * c.t;
                assert!((c.t_maj.x - (-2.0 * dist).exp()).abs() < 1e-5);
                assert!((c.t_maj.y - (-0.5 * dist).exp()).abs() < 1e-5);
                sum += dist as f64;
                n += 1;
                false
            });
        }
        assert_eq!(n, N);
        let mean = sum / N as f64;
        assert!((mean - 0.5).abs() < 4.0 * 0.5 / (N as f64).sqrt(), "{mean}");
    }

    #[test]
    fn tracking_is_deterministic_per_seed() {
        let noise = NoiseDensity::default();
        let g = DensityGrid::from_fn([16, 16, 16], Aabb::new(Vec3A::ZERO, Vec3A::ONE), |p| {
            noise.density(p)
        })
        .unwrap();
        let m = Medium::Grid(Box::new(
            GridMedium::new(g, Vec3A::ONE, Vec3A::ONE, 0.5).unwrap(),
        ));
        let ray = Ray::new(
            Vec3A::new(-0.5, 0.4, 0.3),
            Vec3A::new(1.0, 0.1, 0.2).normalize(),
        );
        for i in 0..100 {
            let a = transmittance(&m, &ray, 3.0, &mut HashRng::new(i));
            let b = transmittance(&m, &ray, 3.0, &mut HashRng::new(i));
            assert_eq!(
                a.to_array().map(f32::to_bits),
                b.to_array().map(f32::to_bits)
            );
        }
        // A sampler drives it too.
        let mut s = Sampler::new(3, 4, 5, 6);
        let a = transmittance(&m, &ray, 3.0, &mut s);
        let b = transmittance(&m, &ray, 3.0, &mut Sampler::new(3, 4, 5, 6));
        assert_eq!(a, b);
    }

    #[test]
    fn degenerate_rays_see_no_medium() {
        let m = homogeneous(Vec3A::ONE);
        let mut rng = HashRng::new(0);
        assert_eq!(
            transmittance(&m, &Ray::new(Vec3A::ZERO, Vec3A::ZERO), 1.0, &mut rng),
            Vec3A::ONE
        );
        assert_eq!(
            transmittance(&m, &Ray::new(Vec3A::ZERO, Vec3A::X), 0.0, &mut rng),
            Vec3A::ONE
        );
        assert_eq!(
            transmittance(&m, &Ray::new(Vec3A::ZERO, Vec3A::NAN), 1.0, &mut rng),
            Vec3A::ONE
        );
        // An infinite ray through fog is fully attenuated, never NaN.
        let t = transmittance(
            &m,
            &Ray::new(Vec3A::ZERO, Vec3A::X),
            f32::INFINITY,
            &mut rng,
        );
        assert_eq!(t, Vec3A::ZERO);
        let clear = homogeneous(Vec3A::ZERO);
        let t = transmittance(
            &clear,
            &Ray::new(Vec3A::ZERO, Vec3A::X),
            f32::INFINITY,
            &mut rng,
        );
        assert_eq!(t, Vec3A::ONE);
    }
}
