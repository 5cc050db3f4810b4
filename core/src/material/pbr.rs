//! glTF metallic-roughness.
//!
//! The BRDF of the glTF 2.0 specification, Appendix B, with `KHR_materials_specular`,
//! `KHR_materials_ior` and `KHR_materials_transmission`:
//!
//! ```text
//! specular_brdf(α)   = D(h) G(v, l) / (4 |n·v| |n·l|)                (GGX, height-correlated Smith)
//! metal_brdf         = F_metal · specular_brdf,  F_metal = c + (1 − c)(1 − |v·h|)⁵
//! F_dielectric       = F0 + (F90 − F0)(1 − |v·h|)⁵,
//!                      F0 = min(((ior − 1)/(ior + 1))² · specular_color, 1) · specular,
//!                      F90 = specular
//! dielectric_brdf    = (1 − max(F_dielectric)) · base + F_dielectric · specular_brdf   (see below)
//! base               = (1 − transmission) · c/π + transmission · c · specular_btdf(α)
//! material           = (1 − metallic) · dielectric_brdf + metallic · metal_brdf
//! ```
//!
//! with c the base colour. The base is weighted by `1 − max(F)` (the channel maximum) as
//! `fresnel_mix` in `KHR_materials_specular`; for a white specular colour this is the plain
//! `mix(base, specular, F)`. With specular = 0 and metallic = 0 the model is exactly Lambertian.
//!
//! **Energy compensation (a deliberate deviation).** Single-scattering GGX loses the energy of
//! light that would bounce more than once between microfacets (up to ~40 % at roughness 1),
//! and the specification's base weight 1 − max F(|v·h|) does not match what the specular lobe
//! actually reflects (a white dielectric reflects up to 1.6 at grazing views). Following
//! Kulla & Conty 2017, both specular lobes (dielectric and metal) get the multiple-scattering
//! lobe F_ms · (1 − E(μo))(1 − E(μi)) / (π (1 − E_avg)) of [`super::conductor`], with
//! F_ms from the closed-form Schlick average F_avg = F0 + (F90 − F0)/21, and the base
//! (diffuse and transmission) is weighted by the energy the compensated dielectric specular
//! lobe does not reflect:
//!
//! ```text
//! base weight = 1 − max(E_spec(μo)),  E_spec = F0 · E(μo) + (F90 − F0) · E₅(μo) + F_ms (1 − E(μo))
//! ```
//!
//! (E, E₅ tabulated in [`super::microfacet::GgxAlbedo`]; Schlick's F is linear in F0 and F90,
//! so two tables give the exact single-scattering albedo for any F0.) A white base with
//! metallic 0 and specular 1 then reflects 1 up to the tables' accuracy (≲ 0.3 %), at every
//! roughness and view angle; with specular 0 the weight is exactly 1 (pure Lambertian). The
//! base weight depends on wo only, so the base lobes are not reciprocal
//! (f(v, l) ≠ f(l, v)), which a unidirectional path tracer does not need; the specular and
//! metal lobes, compensation included, are.
//!
//! `specular_btdf` is the GGX transmission lobe: thin-walled, the reflection lobe mirrored
//! through the surface (light goes straight through, only blurred by the roughness); otherwise
//! Walter et al.'s refraction with `ior` (as [`super::rough_dielectric`], radiance transport,
//! divided by η²). For transmission, h is the (generalised) half vector of the transmitted pair.
//! Seen from inside a body, the interface uses the same Schlick Fresnel at the inside angle
//! (`KHR_materials_volume` evaluates it at the angle outside, which moves light between
//! reflection and refraction without changing their sum), and light the refraction lobe would
//! carry through a microfacet beyond the critical angle is reflected totally, untinted, as the
//! extension's F = 1 there; opaque (or thin) surfaces are two-sided.
//!
//! Clearcoat (`KHR_materials_clearcoat`, `fresnel_coat` of the extension, with the coat normal
//! equal to the shading normal):
//!
//! ```text
//! coated = (1 − clearcoat · Fc) · material + clearcoat · Fc · specular_brdf(α_coat),
//! Fc     = 0.04 + 0.96 (1 − |n·v|)⁵                                      (ior 1.5)
//! ```
//!
//! which stays energy conserving because Fc depends on v only.
//!
//! **Index-matched surfaces.** A body (not thin-walled) or a transmissive surface with `ior` 1
//! has no optical interface: as pbrt-v4's dielectric with η = 1, whatever the roughness, its
//! dielectric specular reflection is zero (F0 = F90 = 0) and its transmission is a delta
//! pass-through (wi = −wo, weight `transmission · base colour`). The generalised half vector of
//! the rough refraction lobe degenerates at η = 1 (wo + wi is never a valid microfacet normal),
//! so without this a body would be black; a rough thin-walled one would lose the energy its
//! single-scattering lobe loses. Opaque thin-walled surfaces with `ior` 1 keep the glTF
//! formula (F0 = 0, F90 = specular).
//! The clearcoat lobe and the transmission lobes are single scattering (not compensated).
//!
//! Very smooth surfaces are not delta: alpha is clamped to [`PBR_MIN_ALPHA`], which keeps D
//! finite while visible-normal sampling keeps f·cos/pdf bounded.
//!
//! Sampling picks one of five lobes (clearcoat, specular reflection = dielectric specular plus
//! metal, their multiple-scattering compensation (cosine-weighted), diffuse, transmission) with
//! probabilities proportional to their albedos at wo (from the albedo tables; the base weight
//! times the mean base colour for diffuse and transmission; the layers below the coat scaled by
//! 1 − clearcoat · Fc), then returns the full mixture value and the mixture density, so that
//! multiple importance sampling sees one consistent pdf.

#![allow(clippy::neg_cmp_op_on_partial_ord)] // `!(x > 0.0)` is deliberate: NaN must fail the guards.

use super::conductor::reflection_pdf;
use super::dielectric::finite_sample;
use super::microfacet::{schlick_albedo, schlick_f_avg, Ggx, GgxAlbedo};
use super::{reflect, refract, sanitize_eta, BsdfSample, Lobe};
use crate::sampling::warp::{cosine_hemisphere, cosine_hemisphere_pdf};
use glam::{Vec2, Vec3A};
use std::f32::consts::FRAC_1_PI;

/// Smallest GGX alpha the glTF model uses (roughness ≈ 0.03): glTF roughness 0 is common and
/// must not produce infinite densities.
pub const PBR_MIN_ALPHA: f32 = 1e-3;

/// glTF metallic-roughness with its parameters resolved at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pbr {
    /// Base colour (linear).
    pub base_color: Vec3A,
    /// Metalness.
    pub metallic: f32,
    /// GGX alpha (roughness squared); clamped to at least [`PBR_MIN_ALPHA`].
    pub alpha: f32,
    /// KHR_materials_specular factor.
    pub specular: f32,
    /// KHR_materials_specular colour.
    pub specular_color: Vec3A,
    /// Index of refraction.
    pub ior: f32,
    /// Transmission factor.
    pub transmission: f32,
    /// Thin-walled transmission.
    pub thin: bool,
    /// Clearcoat factor (0: no coat).
    pub clearcoat: f32,
    /// Clearcoat GGX alpha (clearcoat roughness squared); clamped like `alpha`.
    pub clearcoat_alpha: f32,
}

/// Parameters sanitised once per call: clamped to their glTF ranges, NaN replaced.
struct Params {
    base: Vec3A,
    metallic: f32,
    specular: f32,
    /// Dielectric F0 including the specular factor.
    f0: Vec3A,
    transmission: f32,
    ggx: Ggx,
    ior: f32,
    /// `ior` 1 on a body or a transmissive surface: no dielectric interface, transmission
    /// passes straight through.
    pass_through: bool,
    /// Clearcoat factor.
    coat: f32,
    /// Clearcoat distribution.
    coat_ggx: Ggx,
    /// Albedo tables of the specular/metal distribution.
    alb: GgxAlbedo,
    /// Kulla–Conty F_ms of the dielectric specular lobe (Schlick F0 = `f0`, F90 = `specular`).
    fms_dielectric: Vec3A,
    /// Kulla–Conty F_ms of the metal lobe (Schlick F0 = base colour, F90 = 1).
    fms_metal: Vec3A,
}

/// Quantities that depend on wo only.
struct AtWo {
    /// E(μo) of the specular distribution at F = 1.
    e_o: f32,
    /// Combined multiple-scattering Fresnel (1 − metallic) F_ms,dielectric + metallic F_ms,metal.
    fms: Vec3A,
    /// Weight of the base layer: 1 − max E_spec(μo), the energy the (compensated) dielectric
    /// specular lobe does not reflect.
    base_w: f32,
    probs: Probs,
}

/// Lobe selection probabilities.
struct Probs {
    coat: f32,
    spec: f32,
    /// Multiple-scattering compensation of the specular and metal lobes (cosine sampled).
    ms: f32,
    diffuse: f32,
    trans: f32,
}

#[inline]
fn unit(x: f32) -> f32 {
    if x.is_nan() {
        0.0
    } else {
        x.clamp(0.0, 1.0)
    }
}

#[inline]
fn unit3(v: Vec3A) -> Vec3A {
    Vec3A::new(unit(v.x), unit(v.y), unit(v.z))
}

#[inline]
fn pow5(x: f32) -> f32 {
    let x2 = x * x;
    x2 * x2 * x
}

impl Params {
    /// Dielectric Fresnel F_dielectric(|v·h|) (includes the specular factor).
    #[inline]
    fn f_dielectric(&self, vh: f32) -> Vec3A {
        let w = pow5(1.0 - unit(vh));
        self.f0 + (Vec3A::splat(self.specular) - self.f0) * w
    }
    /// The clearcoat weight clearcoat · Fc(|n·v|).
    #[inline]
    fn coat_weight(&self, cos_o: f32) -> f32 {
        self.coat * (0.04 + 0.96 * pow5(1.0 - unit(cos_o)))
    }
    /// Metal Fresnel: Schlick with F0 = base colour.
    #[inline]
    fn f_metal(&self, vh: f32) -> Vec3A {
        let w = pow5(1.0 - unit(vh));
        self.base + (Vec3A::ONE - self.base) * w
    }
}

/// Whether light along `wo` cannot cross a microfacet with cos θ = `vh` into a medium of
/// relative index `etap` (η_t/η_i): the test [`refract`] makes, so that sampling and evaluation
/// agree on which microfacets reflect totally.
#[inline]
fn total_internal(vh: f32, etap: f32) -> bool {
    let sin2_i = (1.0 - vh * vh).max(0.0);
    sin2_i / (etap * etap) >= 1.0
}

impl Pbr {
    #[inline]
    fn params(&self) -> Params {
        let ior = sanitize_eta(self.ior);
        let pass_through = ior == 1.0 && (!self.thin || self.transmission > 0.0);
        // No interface, no Fresnel reflection (F0 = F90 = 0).
        let specular = if pass_through {
            0.0
        } else {
            unit(self.specular)
        };
        let r0 = ((ior - 1.0) / (ior + 1.0)).powi(2);
        let f0 = (r0 * unit3(self.specular_color)).min(Vec3A::ONE) * specular;
        let base = unit3(self.base_color);
        let clamp_alpha = |a: f32| {
            if a.is_nan() {
                PBR_MIN_ALPHA
            } else {
                a.max(PBR_MIN_ALPHA)
            }
        };
        let alpha = clamp_alpha(self.alpha);
        let alb = GgxAlbedo::new(alpha);
        Params {
            base,
            metallic: unit(self.metallic),
            specular,
            f0,
            transmission: unit(self.transmission),
            ggx: Ggx::new(alpha),
            ior,
            pass_through,
            coat: unit(self.clearcoat),
            coat_ggx: Ggx::new(clamp_alpha(self.clearcoat_alpha)),
            alb,
            fms_dielectric: alb.f_ms(schlick_f_avg(f0, Vec3A::splat(specular))),
            fms_metal: alb.f_ms(schlick_f_avg(base, Vec3A::ONE)),
        }
    }

    /// Energy compensation terms and lobe probabilities at upper-hemisphere `wo`, the
    /// probabilities from the lobes' albedos.
    #[inline]
    fn at_wo(p: &Params, cos_o: f32) -> AtWo {
        let mean = |v: Vec3A| (v.x + v.y + v.z) * (1.0 / 3.0);
        let dielectric = 1.0 - p.metallic;
        // Two table lookups serve every albedo at wo.
        let e_o = p.alb.e(cos_o);
        let e5_o = p.alb.e5(cos_o);
        let ss_d = schlick_albedo(e_o, e5_o, p.f0, Vec3A::splat(p.specular));
        let ss_m = schlick_albedo(e_o, e5_o, p.base, Vec3A::ONE);
        let e_spec = ss_d + p.fms_dielectric * (1.0 - e_o);
        let base_w = (1.0 - e_spec.max_element()).clamp(0.0, 1.0);
        let fms = dielectric * p.fms_dielectric + p.metallic * p.fms_metal;
        let spec = dielectric * mean(ss_d) + p.metallic * mean(ss_m);
        let ms = mean(fms) * (1.0 - e_o);
        let base = dielectric * base_w * mean(p.base);
        let diffuse = base * (1.0 - p.transmission);
        let trans = base * p.transmission;
        let coat = p.coat_weight(cos_o);
        let (spec, ms, diffuse, trans) = (
            spec * (1.0 - coat),
            ms * (1.0 - coat),
            diffuse * (1.0 - coat),
            trans * (1.0 - coat),
        );
        let sum = coat + spec + ms + diffuse + trans;
        let probs = if !(sum > 0.0) || !sum.is_finite() {
            // Black everywhere: any valid density will do; the diffuse one is cheapest.
            Probs {
                coat: 0.0,
                spec: 0.0,
                ms: 0.0,
                diffuse: 1.0,
                trans: 0.0,
            }
        } else {
            Probs {
                coat: coat / sum,
                spec: spec / sum,
                ms: ms / sum,
                diffuse: diffuse / sum,
                trans: trans / sum,
            }
        };
        AtWo {
            e_o,
            fms,
            base_w,
            probs,
        }
    }

    /// Relative index crossed by refraction from `wo`'s side (the outside is +Z).
    #[inline]
    fn etap(&self, p: &Params, wo_below: bool) -> f32 {
        if wo_below {
            1.0 / p.ior
        } else {
            p.ior
        }
    }

    /// Value and density for `wo` flipped into the upper hemisphere (`wi` flipped with it).
    /// `etap` is the index ratio for refraction. Returns (f, pdf).
    /// `at` is [`Pbr::at_wo`] of `wo`.
    fn eval_pdf_upper(
        &self,
        p: &Params,
        at: &AtWo,
        wo: Vec3A,
        wi: Vec3A,
        etap: f32,
    ) -> (Vec3A, f32) {
        let zero = (Vec3A::ZERO, 0.0);
        if !(wo.z > 0.0) || wi.z == 0.0 || !wi.is_finite() {
            return zero;
        }
        let probs = &at.probs;
        let dielectric = 1.0 - p.metallic;
        let ggx = &p.ggx;
        let coat = p.coat_weight(wo.z);
        if wi.z > 0.0 {
            let Some(h) = (wo + wi).try_normalize() else {
                return zero;
            };
            let vh = wo.dot(h).abs();
            let fd = p.f_dielectric(vh);
            let spec_brdf = ggx.d(h) * ggx.g(wo, wi) / (4.0 * wo.z * wi.z);
            let ms_f = at.fms * p.alb.ms_shape(at.e_o, p.alb.e(wi.z));
            let spec_f = (dielectric * fd + p.metallic * p.f_metal(vh)) * spec_brdf + ms_f;
            let diffuse_w = dielectric * (1.0 - p.transmission) * at.base_w;
            let mut f = (spec_f + p.base * FRAC_1_PI * diffuse_w) * (1.0 - coat);
            let mut pdf = probs.spec * reflection_pdf(ggx, wo, h)
                + (probs.diffuse + probs.ms) * cosine_hemisphere_pdf(wi.z);
            // Total internal reflection: light the refraction lobe would carry through a
            // microfacet it cannot cross (inside a body, beyond the critical angle) is
            // reflected instead, untinted (KHR_materials_volume: F = 1 there).
            let trans_w = dielectric * p.transmission * (1.0 - coat);
            if trans_w > 0.0 && !self.thin && !p.pass_through && total_internal(vh, etap) {
                f += Vec3A::splat(trans_w * at.base_w * spec_brdf);
                pdf += probs.trans * reflection_pdf(ggx, wo, h);
            }
            if coat > 0.0 {
                let cg = &p.coat_ggx;
                f += Vec3A::splat(coat * cg.d(h) * cg.g(wo, wi) / (4.0 * wo.z * wi.z));
                pdf += probs.coat * reflection_pdf(cg, wo, h);
            }
            return (f, pdf);
        }
        let weight = dielectric * p.transmission * (1.0 - coat);
        if !(weight > 0.0) || p.pass_through {
            // The pass-through is a delta: it has no value or density for any given pair.
            return zero;
        }
        if self.thin {
            // Straight through: the reflection lobe mirrored to the other side.
            let wr = Vec3A::new(wi.x, wi.y, -wi.z);
            let Some(h) = (wo + wr).try_normalize() else {
                return zero;
            };
            let spec_brdf = ggx.d(h) * ggx.g(wo, wr) / (4.0 * wo.z * wr.z);
            let f = p.base * (weight * at.base_w * spec_brdf);
            return (f, probs.trans * reflection_pdf(ggx, wo, h));
        }
        // Refraction (Walter et al. 2007) with the generalised half vector.
        let Some(mut h) = (wo + wi * etap).try_normalize() else {
            return zero;
        };
        if h.z < 0.0 {
            h = -h;
        }
        let (wo_h, wi_h) = (wo.dot(h), wi.dot(h));
        if !(wo_h > 0.0) || !(wi_h < 0.0) {
            return zero;
        }
        let denom = (wi_h + wo_h / etap) * (wi_h + wo_h / etap);
        if !(denom > 0.0) {
            return zero;
        }
        let btdf =
            ggx.d(h) * ggx.g(wo, wi) * (wi_h * wo_h / (denom * wi.z * wo.z)).abs() / (etap * etap);
        let f = p.base * (weight * at.base_w * btdf);
        let pdf = probs.trans * ggx.pdf_visible(wo, h) * wi_h.abs() / denom;
        (f, pdf)
    }

    /// Flips (wo, wi) so that wo is in the upper hemisphere; `None` for unusable input.
    #[inline]
    fn flip(wo: Vec3A, wi: Vec3A) -> Option<(Vec3A, Vec3A, bool)> {
        if !wo.is_finite() || !wi.is_finite() || wo.z == 0.0 {
            return None;
        }
        let below = wo.z < 0.0;
        let s = if below { -1.0 } else { 1.0 };
        Some((
            Vec3A::new(wo.x, wo.y, wo.z * s),
            Vec3A::new(wi.x, wi.y, wi.z * s),
            below,
        ))
    }

    /// f(wo, wi) without cosine.
    pub fn eval(&self, wo: Vec3A, wi: Vec3A) -> Vec3A {
        self.eval_pdf(wo, wi).0
    }
    /// Density of `sample`: the lobe-probability-weighted mixture of the lobe densities.
    pub fn pdf(&self, wo: Vec3A, wi: Vec3A) -> f32 {
        self.eval_pdf(wo, wi).1
    }
    /// `eval` and `pdf` together, for the price of one (they share every term at wo).
    pub fn eval_pdf(&self, wo: Vec3A, wi: Vec3A) -> (Vec3A, f32) {
        let Some((wo, wi, below)) = Self::flip(wo, wi) else {
            return (Vec3A::ZERO, 0.0);
        };
        let p = self.params();
        let at = Self::at_wo(&p, wo.z);
        let (f, pdf) = self.eval_pdf_upper(&p, &at, wo, wi, self.etap(&p, below));
        (
            if f.is_finite() { f } else { Vec3A::ZERO },
            if pdf.is_finite() { pdf } else { 0.0 },
        )
    }
    /// Picks a lobe with `uc`, samples it with `u`, and returns the full mixture f and pdf.
    pub fn sample(&self, wo: Vec3A, uc: f32, u: Vec2) -> Option<BsdfSample> {
        let (wo_u, _, below) = Self::flip(wo, Vec3A::Z)?;
        let p = self.params();
        let at = Self::at_wo(&p, wo_u.z);
        let probs = &at.probs;
        let etap = self.etap(&p, below);
        let (wi, lobe, eta) = if uc < probs.coat {
            let wm = p.coat_ggx.sample_wm(wo_u, u);
            (reflect(wo_u, wm), Lobe::GlossyReflection, 1.0)
        } else if uc < probs.coat + probs.spec {
            let wm = p.ggx.sample_wm(wo_u, u);
            (reflect(wo_u, wm), Lobe::GlossyReflection, 1.0)
        } else if uc < probs.coat + probs.spec + probs.ms {
            (cosine_hemisphere(u), Lobe::GlossyReflection, 1.0)
        } else if uc < probs.coat + probs.spec + probs.ms + probs.diffuse || !(probs.trans > 0.0) {
            (cosine_hemisphere(u), Lobe::Diffuse, 1.0)
        } else if p.pass_through {
            // Straight through, weight transmission · base colour (base weight 1, as F = 0).
            let weight = (1.0 - p.metallic) * p.transmission * (1.0 - p.coat_weight(wo_u.z));
            let f = p.base * (weight * at.base_w / wo_u.z);
            return finite_sample(BsdfSample {
                wi: -wo,
                f,
                pdf: probs.trans,
                lobe: Lobe::SpecularTransmission,
                eta: 1.0,
            });
        } else if self.thin {
            let wm = p.ggx.sample_wm(wo_u, u);
            let wr = reflect(wo_u, wm);
            if !(wr.z > 0.0) {
                return None;
            }
            (Vec3A::new(wr.x, wr.y, -wr.z), Lobe::GlossyTransmission, 1.0)
        } else {
            let wm = p.ggx.sample_wm(wo_u, u);
            match refract(wo_u, wm, etap) {
                Some((wi, e)) => (wi, Lobe::GlossyTransmission, e),
                // Total internal reflection at this microfacet (see `eval_pdf_upper`).
                None => (reflect(wo_u, wm), Lobe::GlossyReflection, 1.0),
            }
        };
        // The lobe must land on its own side; otherwise the sample is lost.
        if lobe.is_transmission() != (wi.z < 0.0) || wi.z == 0.0 {
            return None;
        }
        let (f, pdf) = self.eval_pdf_upper(&p, &at, wo_u, wi, etap);
        let wi = if below {
            Vec3A::new(wi.x, wi.y, -wi.z)
        } else {
            wi
        };
        finite_sample(BsdfSample {
            wi,
            f,
            pdf,
            lobe,
            eta,
        })
    }
    /// Delta only for a fully transmissive, index-matched surface (the pass-through alone);
    /// very smooth surfaces are otherwise clamped to [`PBR_MIN_ALPHA`], never delta.
    pub fn is_delta(&self) -> bool {
        sanitize_eta(self.ior) == 1.0
            && unit(self.transmission) == 1.0
            && unit(self.metallic) == 0.0
            && unit(self.clearcoat) == 0.0
    }
    /// Whether every lobe is a GGX lobe whose alpha `near` accepts (the clearcoat's too), with
    /// no diffuse part: metallic, or fully transmissive ([`super::Bsdf::is_near_specular`]).
    pub fn is_near_specular(&self, near: impl Fn(f32) -> bool) -> bool {
        let alpha = |a: f32| {
            if a.is_nan() {
                PBR_MIN_ALPHA
            } else {
                a.max(PBR_MIN_ALPHA)
            }
        };
        let diffuse = (1.0 - unit(self.metallic)) * (1.0 - unit(self.transmission));
        diffuse == 0.0
            && near(alpha(self.alpha))
            && (unit(self.clearcoat) == 0.0 || near(alpha(self.clearcoat_alpha)))
    }
    /// The base colour.
    pub fn albedo(&self) -> Vec3A {
        self.base_color
    }
}
