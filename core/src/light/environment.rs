//! Environment lighting: constant, or an equirectangular HDR map sampled by importance.
//!
//! Map convention: u = 0.5 + atan2(d.x, −d.z)/2π, v = acos(d.y)/π, so the centre of the image
//! lies towards −Z (straight ahead of a default camera) and the top row is straight up (+Y).

use crate::sampling::distrib::Distribution2D;
use crate::sampling::warp::{uniform_sphere, UNIFORM_SPHERE_PDF};
use crate::texture::{Texels, Texture};
use glam::{Vec2, Vec3A};
use std::f32::consts::PI;

/// Light from infinitely far away.
#[derive(Clone, Debug)]
pub enum Environment {
    /// Uniform radiance.
    Constant(Vec3A),
    /// An importance-sampled lat-long map.
    Map {
        /// The image (linear).
        texture: Texture,
        /// Multiplier.
        scale: f32,
        /// Rotation about +Y (radians) applied to the map.
        rotation: f32,
        /// Sampling distribution ∝ luminance × sin θ.
        distrib: Distribution2D,
        /// Average luminance (for light selection).
        average: f32,
    },
}

/// Checks an equirectangular map (RGBA texels row by row, `width` wide) and the `scale` that
/// multiplies it (named `scale_name` in messages): the scale finite and non-negative, and
/// every texel at most [`super::MAX_RADIANCE`] once scaled (the message names the brightest).
/// NaN, infinite and negative texels are not refused: [`Texture::new`] reads them as zero, as
/// real EXR skies may hold a few (from colour conversions or stitching).
pub fn check_map(texels: &Texels, width: u32, scale: f32, scale_name: &str) -> Result<(), String> {
    use super::{show_number, MAX_RADIANCE};
    if !(scale.is_finite() && scale >= 0.0) {
        return Err(format!(
            "{scale_name} must be finite and non-negative, got {}",
            show_number(scale)
        ));
    }
    let at = |i: usize| {
        let w = width.max(1) as usize;
        format!("texel ({}, {})", i % w, i / w)
    };
    let mut brightest = (0.0f32, 0);
    for i in 0..texels.len() {
        let t = texels.get(i);
        let c = Vec3A::new(t[0], t[1], t[2]);
        if !c.is_finite() {
            continue;
        }
        if c.max_element() > brightest.0 {
            brightest = (c.max_element(), i);
        }
    }
    let (value, i) = brightest;
    if f64::from(value) * f64::from(scale) > f64::from(MAX_RADIANCE) {
        return Err(format!(
            "{} times {scale_name} {} is {:.3e}: must be at most 1e30 (the largest radiance \
             raytile takes)",
            at(i),
            show_number(scale),
            f64::from(value) * f64::from(scale)
        ));
    }
    Ok(())
}

impl Environment {
    /// The same radiance from every direction.
    pub fn constant(radiance: Vec3A) -> Self {
        Environment::Constant(radiance)
    }

    /// An equirectangular map (linear RGB) times `scale`, turned by `rotation_y` radians about
    /// +Y, with its sampling distribution ∝ luminance × sin θ.
    pub fn map(texture: Texture, scale: f32, rotation_y: f32) -> Self {
        let (w, h) = (texture.width() as usize, texture.height() as usize);
        let mut weights = Vec::with_capacity(w * h);
        let mut total = 0.0f64;
        for y in 0..h {
            let sin_t = (PI * (y as f32 + 0.5) / h as f32).sin();
            for x in 0..w {
                let c = texture.texel(x as i64, y as i64);
                let l = super::luminance(Vec3A::new(c.x, c.y, c.z)).max(0.0);
                total += (l * sin_t) as f64;
                weights.push(l * sin_t);
            }
        }
        let average = (total / (w * h) as f64) as f32 * scale.max(0.0);
        Environment::Map {
            distrib: Distribution2D::new(&weights, w, h),
            texture,
            scale: scale.max(0.0),
            rotation: rotation_y,
            average,
        }
    }

    /// Bytes held (the map and its sampling tables), for cache budgets.
    pub fn memory_bytes(&self) -> usize {
        match self {
            Environment::Constant(_) => 0,
            Environment::Map {
                texture, distrib, ..
            } => texture.memory_bytes() + distrib.memory_bytes(),
        }
    }

    /// Radiance arriving from direction `d` (unit, pointing away from the scene).
    #[inline]
    pub fn radiance(&self, d: Vec3A) -> Vec3A {
        match self {
            Environment::Constant(c) => *c,
            Environment::Map {
                texture,
                scale,
                rotation,
                ..
            } => {
                let uv = dir_to_uv(d, *rotation);
                let c = texture.lookup(uv);
                Vec3A::new(c.x, c.y, c.z) * *scale
            }
        }
    }

    /// Samples a direction: (direction, radiance, solid-angle pdf).
    #[inline]
    pub fn sample(&self, u: Vec2) -> Option<(Vec3A, Vec3A, f32)> {
        match self {
            Environment::Constant(c) => Some((uniform_sphere(u), *c, UNIFORM_SPHERE_PDF)),
            Environment::Map {
                distrib, rotation, ..
            } => {
                let (uv, pdf_uv) = distrib.sample(u);
                if pdf_uv <= 0.0 {
                    return None;
                }
                let (d, sin_t) = uv_to_dir(uv, *rotation);
                if sin_t <= 0.0 {
                    return None;
                }
                let pdf = pdf_uv / (2.0 * PI * PI * sin_t);
                Some((d, self.radiance(d), pdf))
            }
        }
    }

    /// Solid-angle density of [`Environment::sample`] for direction `d`.
    #[inline]
    pub fn pdf(&self, d: Vec3A) -> f32 {
        match self {
            Environment::Constant(_) => UNIFORM_SPHERE_PDF,
            Environment::Map {
                distrib, rotation, ..
            } => {
                let uv = dir_to_uv(d, *rotation);
                let sin_t = (1.0 - d.y * d.y).max(0.0).sqrt();
                if sin_t <= 0.0 {
                    return 0.0;
                }
                distrib.pdf(uv) / (2.0 * PI * PI * sin_t)
            }
        }
    }

    /// Power estimate for light selection given the scene's bounding radius.
    pub fn power(&self, radius: f32) -> f32 {
        let avg = match self {
            Environment::Constant(c) => super::luminance(*c),
            Environment::Map { average, .. } => *average,
        };
        4.0 * PI * PI * radius * radius * avg
    }
}

/// The map's (u, v) seen along `d`: u = 0.5 (the image's centre column) along −Z and 0.75
/// along +X when `rotation` is 0, v = 0 (the top row) along +Y. A `rotation` turns the map by
/// the right-hand rule about +Y, as an object's rotation turns the object: at a quarter turn
/// the centre column faces −X.
#[inline]
fn dir_to_uv(d: Vec3A, rotation: f32) -> Vec2 {
    let phi = d.x.atan2(-d.z) + rotation;
    let u = (0.5 + phi / (2.0 * PI)).rem_euclid(1.0);
    let v = d.y.clamp(-1.0, 1.0).acos() / PI;
    Vec2::new(u, v)
}

/// The direction that sees (u, v) of the map, and sin θ there: the inverse of [`dir_to_uv`].
#[inline]
fn uv_to_dir(uv: Vec2, rotation: f32) -> (Vec3A, f32) {
    let phi = (uv.x - 0.5) * 2.0 * PI - rotation;
    let theta = uv.y * PI;
    let (sin_t, cos_t) = theta.sin_cos();
    (
        Vec3A::new(sin_t * phi.sin(), cos_t, -sin_t * phi.cos()),
        sin_t,
    )
}

#[cfg(test)]
mod tests {
    use super::super::luminance;
    use super::*;
    use crate::texture::{TextureLookup, WrapMode};

    #[test]
    fn uv_and_direction_round_trip() {
        for (u, v) in [(0.1, 0.2), (0.5, 0.5), (0.9, 0.7)] {
            let (d, _) = uv_to_dir(Vec2::new(u, v), 0.3);
            let uv = dir_to_uv(d, 0.3);
            assert!((uv - Vec2::new(u, v)).length() < 1e-4, "{uv}");
        }
        assert!((uv_to_dir(Vec2::new(0.5, 0.5), 0.0).0 - (-Vec3A::Z)).length() < 1e-6);
        assert!((dir_to_uv(Vec3A::X, 0.0) - Vec2::new(0.75, 0.5)).length() < 1e-6);
        assert!((dir_to_uv(Vec3A::Y, 0.0).y).abs() < 1e-6);
        // A quarter turn by the right-hand rule about +Y (as an object's rotation turns it)
        // takes the centre column from −Z to −X, and the column that faced +X to −Z.
        let quarter = std::f32::consts::FRAC_PI_2;
        let centre = uv_to_dir(Vec2::new(0.5, 0.5), quarter).0;
        assert!((centre - (-Vec3A::X)).length() < 1e-6, "{centre}");
        let turned = glam::Quat::from_rotation_y(quarter) * glam::Vec3::X;
        let uv = dir_to_uv(Vec3A::from(turned), quarter);
        assert!((uv - Vec2::new(0.75, 0.5)).length() < 1e-6, "{uv}");
    }

    #[test]
    fn map_pdf_matches_sampling_and_integrates_to_one() {
        let (w, h) = (16u32, 8u32);
        let texels = (0..w * h).map(|i| {
            let v = if i % 7 == 0 { 20.0 } else { 0.5 };
            [v, v * 0.5, v, 1.0]
        });
        let texels: Vec<[f32; 4]> = texels.collect();
        let lookup = TextureLookup {
            wrap_u: WrapMode::Repeat,
            wrap_v: WrapMode::Clamp,
            bilinear: false,
        };
        let env = Environment::map(Texture::new(w, h, &texels, false, lookup), 1.0, 0.0);
        // ∫ pdf dω over the sphere = 1 (midpoint rule in (φ, cos θ)).
        let n = 200;
        let mut sum = 0.0;
        for j in 0..n {
            for i in 0..n {
                let z = 1.0 - 2.0 * (j as f32 + 0.5) / n as f32;
                let phi = 2.0 * PI * (i as f32 + 0.5) / n as f32;
                let r = (1.0 - z * z).sqrt();
                sum += env.pdf(Vec3A::new(r * phi.cos(), z, r * phi.sin()));
            }
        }
        assert!(
            (sum * 4.0 * PI / (n * n) as f32 - 1.0).abs() < 0.02,
            "{sum}"
        );
        let (d, _, pdf) = env.sample(Vec2::new(0.37, 0.61)).unwrap();
        assert!((env.pdf(d) - pdf).abs() < 1e-3 * pdf);
    }

    /// Importance sampling a map agrees with uniform sampling of the same map (the irradiance
    /// on an upward-facing surface, within noise) and has a lower variance on a map with a
    /// small bright sun, as a studio or a sky has (measured: about a third of uniform's; the
    /// bilinear lookup blurs the sun beyond the texels the piecewise-constant density favours).
    #[test]
    fn importance_sampling_agrees_with_uniform_sampling_with_lower_variance() {
        let (w, h) = (64u32, 32u32);
        let texels: Vec<[f32; 4]> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let sun = (20..23).contains(&x) && (6..9).contains(&y);
                let sky = 0.2 + 0.3 * (1.0 - y as f32 / h as f32);
                let v = if sun { 400.0 } else { sky };
                [v, v * 0.9, v * 0.8, 1.0]
            })
            .collect();
        let lookup = TextureLookup {
            wrap_u: WrapMode::Repeat,
            wrap_v: WrapMode::Clamp,
            bilinear: true,
        };
        let env = Environment::map(Texture::new(w, h, &texels, false, lookup), 1.5, 0.7);
        // Irradiance at an upward-facing point: ∫ L(ω) max(0, ω·y) dω.
        let f = |d: Vec3A| luminance(env.radiance(d)) * d.y.max(0.0);
        let n = 200_000;
        let stats = |xs: &mut dyn Iterator<Item = f64>| {
            let v: Vec<f64> = xs.collect();
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64;
            (m, var)
        };
        // A 2D sequence that is the same for both estimators' independent uses: hashed.
        let u = |i: u32, k: u32| {
            let mut x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (k as u64) << 32;
            x ^= x >> 33;
            x = x.wrapping_mul(0xff51_afd7_ed55_8ccd);
            x ^= x >> 33;
            x = x.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
            x ^= x >> 33;
            (x >> 40) as f32 / (1u64 << 24) as f32
        };
        let (m_uni, var_uni) = stats(&mut (0..n).map(|i| {
            let d = uniform_sphere(Vec2::new(u(i, 0), u(i, 1)));
            (f(d) / UNIFORM_SPHERE_PDF) as f64
        }));
        let (m_imp, var_imp) =
            stats(
                &mut (0..n).map(|i| match env.sample(Vec2::new(u(i, 2), u(i, 3))) {
                    Some((d, li, pdf)) => {
                        assert!(
                            (luminance(li) - luminance(env.radiance(d))).abs()
                                <= 1e-4 * luminance(li).max(1.0)
                        );
                        (f(d) / pdf) as f64
                    }
                    None => 0.0,
                }),
            );
        let se = ((var_uni + var_imp) / n as f64).sqrt();
        assert!(
            (m_uni - m_imp).abs() < 4.0 * se,
            "uniform {m_uni} vs importance {m_imp} (standard error {se})"
        );
        println!("uniform {m_uni} (variance {var_uni}), importance {m_imp} (variance {var_imp})");
        assert!(
            var_imp < 0.5 * var_uni,
            "importance sampling variance {var_imp} is not well below uniform's {var_uni}"
        );
    }
}
