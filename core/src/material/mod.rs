//! Materials and BSDFs: how surfaces scatter light. [`surface`] holds the material a scene
//! object has (a model and its textures); evaluated at a point it gives one of the BSDFs here.
//!
//! Every BSDF works in the local shading frame: the shading normal is +Z. `wo` points towards
//! the viewer (the direction light leaves along), `wi` towards the light (the direction light
//! arrives from); both are unit vectors and either may be below the surface (z < 0).
//!
//! Conventions (those of pbrt-v4):
//! - `eval` returns f(wo, wi) **without** the cosine factor; the integrator multiplies by |cos θi|.
//! - `sample` returns `f`, `pdf` (solid angle) and `wi`; for delta lobes `pdf` is the discrete
//!   probability of choosing that lobe and `f` is the lobe's value divided by |cos θi|, so the
//!   estimator is always `f · |cos θi| / pdf`.
//! - Reflection-only BSDFs (diffuse, mirror, conductors) are two-sided: they behave the same
//!   seen from below (they mirror wo into the upper hemisphere internally).
//! - Transmissive BSDFs: `eta` is the index inside relative to outside; the outside is +Z.
//! - Energy is conserved: the directional albedo is ≤ 1 for every wo.
//!
//! A [`Bsdf`] is a small `Copy` value made per hit by [`Material::bsdf`] (textures already looked
//! up), so there is no allocation and no dynamic dispatch per ray.

pub mod conductor;
pub mod dielectric;
pub mod diffuse;
pub mod microfacet;
pub mod mirror;
pub mod pbr;
pub mod rough_dielectric;
pub mod surface;
#[cfg(test)]
mod tests;

pub use surface::{AlphaMode, Coverage, Emission, Material, MaterialSlots, Model, PbrParams};

use glam::{Vec2, Vec3A};

/// Which way light went at a scattering event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lobe {
    /// Diffuse reflection.
    Diffuse,
    /// Glossy (rough, non-delta) reflection.
    GlossyReflection,
    /// Glossy transmission.
    GlossyTransmission,
    /// Delta (perfectly specular) reflection.
    SpecularReflection,
    /// Delta transmission.
    SpecularTransmission,
}

impl Lobe {
    /// Whether the lobe is a Dirac delta (cannot be hit by light sampling).
    pub fn is_delta(self) -> bool {
        matches!(self, Lobe::SpecularReflection | Lobe::SpecularTransmission)
    }
    /// Whether wi is on the other side of the surface from wo.
    pub fn is_transmission(self) -> bool {
        matches!(self, Lobe::SpecularTransmission | Lobe::GlossyTransmission)
    }
}

/// The result of sampling a BSDF.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BsdfSample {
    /// Sampled incident direction (local frame, unit).
    pub wi: Vec3A,
    /// BSDF value for (wo, wi), without the cosine.
    pub f: Vec3A,
    /// Probability density of `wi` (solid angle), or the discrete probability for delta lobes.
    pub pdf: f32,
    /// The lobe that was sampled.
    pub lobe: Lobe,
    /// Relative index of refraction across the boundary for transmission (η_t/η_i as seen from
    /// wo's side), 1 for reflection. Used for radiance scaling and Russian roulette.
    pub eta: f32,
}

/// GGX alpha (roughness squared) up to which [`Bsdf::is_near_specular`] counts a lobe as
/// nearly specular: roughness 0.25.
pub const NEAR_SPECULAR_ALPHA: f32 = 0.0625;

/// A BSDF with its parameters resolved at one surface point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bsdf {
    /// Lambertian reflection.
    Diffuse(diffuse::Diffuse),
    /// Perfect mirror.
    Mirror(mirror::Mirror),
    /// Smooth dielectric (glass, water), optionally thin-walled.
    Dielectric(dielectric::Dielectric),
    /// GGX rough (or smooth) conductor.
    Conductor(conductor::Conductor),
    /// GGX rough dielectric (frosted glass).
    RoughDielectric(rough_dielectric::RoughDielectric),
    /// glTF metallic–roughness (with specular, transmission and clearcoat extensions).
    Pbr(pbr::Pbr),
}

macro_rules! dispatch {
    ($self:ident, $b:ident => $e:expr) => {
        match $self {
            Bsdf::Diffuse($b) => $e,
            Bsdf::Mirror($b) => $e,
            Bsdf::Dielectric($b) => $e,
            Bsdf::Conductor($b) => $e,
            Bsdf::RoughDielectric($b) => $e,
            Bsdf::Pbr($b) => $e,
        }
    };
}

impl Bsdf {
    /// f(wo, wi) without the cosine; zero for delta lobes.
    #[inline]
    pub fn eval(&self, wo: Vec3A, wi: Vec3A) -> Vec3A {
        dispatch!(self, b => b.eval(wo, wi))
    }

    /// Solid-angle density with which [`Bsdf::sample`] picks `wi` (delta lobes excluded).
    #[inline]
    pub fn pdf(&self, wo: Vec3A, wi: Vec3A) -> f32 {
        dispatch!(self, b => b.pdf(wo, wi))
    }

    /// `(eval, pdf)` in one call: the same values, computed once where the two share work
    /// (the glTF pbr model's albedo tables and lobe probabilities).
    #[inline]
    pub fn eval_pdf(&self, wo: Vec3A, wi: Vec3A) -> (Vec3A, f32) {
        match self {
            Bsdf::Pbr(b) => b.eval_pdf(wo, wi),
            _ => (self.eval(wo, wi), self.pdf(wo, wi)),
        }
    }

    /// Samples `wi` given `wo`, a uniform number `uc` (lobe choice) and uniform `u` (direction).
    #[inline]
    pub fn sample(&self, wo: Vec3A, uc: f32, u: Vec2) -> Option<BsdfSample> {
        dispatch!(self, b => b.sample(wo, uc, u))
    }

    /// Whether every lobe is a delta (light sampling is pointless: skip next-event estimation).
    #[inline]
    pub fn is_delta(&self) -> bool {
        dispatch!(self, b => b.is_delta())
    }

    /// Whether every lobe is a delta or a GGX lobe of alpha at most [`NEAR_SPECULAR_ALPHA`],
    /// with no diffuse part: a surface so close to a mirror or clear glass that a photon
    /// arriving at it almost never lines up with a given view. `sppm` carries its camera paths
    /// on through such surfaces, as through delta ones (pbrt-v4's SPPM through every glossy
    /// surface), instead of gathering photons on them.
    #[inline]
    pub fn is_near_specular(&self) -> bool {
        let near = |alpha: f32| alpha <= NEAR_SPECULAR_ALPHA;
        match self {
            Bsdf::Diffuse(_) => false,
            Bsdf::Mirror(_) | Bsdf::Dielectric(_) => true,
            Bsdf::Conductor(c) => near(c.alpha),
            Bsdf::RoughDielectric(d) => near(d.alpha),
            Bsdf::Pbr(p) => p.is_delta() || p.is_near_specular(near),
        }
    }

    /// A colour summarising the surface, for the `albedo` debug output and denoisers.
    pub fn albedo(&self) -> Vec3A {
        dispatch!(self, b => b.albedo())
    }
}

/// Fresnel reflectance of a dielectric interface for unpolarised light. `cos_i` is the cosine
/// on the incident side (negative: coming from inside), `eta` the inside/outside index ratio.
/// Returns 1 under total internal reflection.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let mut cos_i = cos_i.clamp(-1.0, 1.0);
    let mut eta = eta;
    if cos_i < 0.0 {
        eta = 1.0 / eta;
        cos_i = -cos_i;
    }
    let sin2_i = 1.0 - cos_i * cos_i;
    let sin2_t = sin2_i / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).max(0.0).sqrt();
    let r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (r_parl * r_parl + r_perp * r_perp)
}

/// Mirror reflection of `wo` about the (unit) normal `n`: `-wo + 2 (wo·n) n`.
#[inline]
pub fn reflect(wo: Vec3A, n: Vec3A) -> Vec3A {
    -wo + 2.0 * wo.dot(n) * n
}

/// Refraction of `wi` through an interface with normal `n` (on the outside) and relative index
/// `eta` (inside/outside). `wi` may be on either side; returns the transmitted direction and the
/// relative index η_t/η_i actually crossed, or `None` under total internal reflection.
#[inline]
pub fn refract(wi: Vec3A, n: Vec3A, eta: f32) -> Option<(Vec3A, f32)> {
    let mut cos_i = n.dot(wi);
    let mut eta = eta;
    let mut n = n;
    if cos_i < 0.0 {
        eta = 1.0 / eta;
        cos_i = -cos_i;
        n = -n;
    }
    let sin2_i = (1.0 - cos_i * cos_i).max(0.0);
    let sin2_t = sin2_i / (eta * eta);
    if sin2_t >= 1.0 || sin2_t.is_nan() {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let wt = -wi / eta + (cos_i / eta - cos_t) * n;
    if wt.is_finite() {
        Some((wt, eta))
    } else {
        None
    }
}

/// A usable relative index of refraction: NaN, infinite or non-positive values become 1
/// (no interface), so that no BSDF divides by zero.
#[inline]
pub(crate) fn sanitize_eta(eta: f32) -> f32 {
    if eta.is_finite() && eta > 0.0 {
        eta
    } else {
        1.0
    }
}
