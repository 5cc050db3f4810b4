//! Materials at render time: a scattering model with its texture slots, and what the surface
//! emits. Evaluated at a surface point, a material gives the point's [`Bsdf`] (pbrt-v4's
//! `Material::GetBSDF`), its base colour (also the alpha test's alpha), its normal-mapped
//! shading normal (pbrt-v4's `NormalMap`) and its emitted radiance.
//!
//! The scene builder makes these from descriptions; everything constant is resolved there, so
//! that shading only looks textures up and combines numbers.

use super::conductor::Conductor;
use super::dielectric::Dielectric;
use super::diffuse::Diffuse;
use super::mirror::Mirror;
use super::pbr::Pbr;
use super::rough_dielectric::RoughDielectric;
use super::Bsdf;
use crate::sampling::warp::Frame;
use crate::texture::{TexSlot, Texture};
use glam::{Vec2, Vec3A, Vec4};

/// How a material treats alpha (glTF `alphaMode`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum AlphaMode {
    /// Alpha is ignored.
    #[default]
    Opaque,
    /// Surface is absent where alpha < cutoff.
    Mask(f32),
    /// Surface is present with probability alpha (stochastic transparency).
    Blend,
}

/// The scattering model of a material.
#[derive(Clone, Copy, Debug)]
pub enum Model {
    /// Lambertian reflection of the base colour (factor times texture).
    Diffuse,
    /// A BSDF that is the same at every point (mirror, glass, metals).
    Uniform(Bsdf),
    /// The glTF metallic–roughness model; its base colour is the material's.
    Pbr(PbrParams),
}

/// The untextured parameters of the glTF metallic–roughness model (see [`Pbr`]).
#[derive(Clone, Copy, Debug)]
pub struct PbrParams {
    /// `metallicFactor` (times the texture's B channel at a point).
    pub metallic: f32,
    /// `roughnessFactor`, perceptual (times the texture's G channel at a point).
    pub roughness: f32,
    /// Specular factor, clamped to [0, 1].
    pub specular: f32,
    /// Specular colour, non-negative.
    pub specular_color: Vec3A,
    /// Index of refraction.
    pub ior: f32,
    /// Transmission factor (times the transmission texture's R channel at a point).
    pub transmission: f32,
    /// Thin-walled transmission.
    pub thin: bool,
    /// Clearcoat factor, clamped to [0, 1].
    pub clearcoat: f32,
    /// Clearcoat GGX alpha (clearcoat roughness squared).
    pub clearcoat_alpha: f32,
}

/// Texture slots of a material (texture references resolved at build time).
#[derive(Clone, Copy, Debug, Default)]
pub struct MaterialSlots {
    /// Multiplies the base colour.
    pub base: Option<TexSlot>,
    /// Roughness in G and metalness in B (glTF).
    pub metallic_roughness: Option<TexSlot>,
    /// Transmission in R.
    pub transmission: Option<TexSlot>,
    /// `KHR_materials_specular` strength in A.
    pub specular: Option<TexSlot>,
    /// `KHR_materials_specular` colour in RGB.
    pub specular_color: Option<TexSlot>,
    /// Clearcoat in R.
    pub clearcoat: Option<TexSlot>,
    /// Clearcoat roughness in G.
    pub clearcoat_roughness: Option<TexSlot>,
    /// Tangent-space normal map and its scale.
    pub normal: Option<(TexSlot, f32)>,
}

/// Light a surface emits (glTF's `emissiveFactor` and `emissiveTexture`): what its area light
/// gives off, whether a ray hits the surface or a light sample lands on it.
#[derive(Clone, Copy, Debug)]
pub struct Emission {
    /// Emitted radiance, positive in some channel.
    pub radiance: Vec3A,
    /// Whether both sides emit; else only the side the geometric normal faces.
    pub two_sided: bool,
    /// Multiplies `radiance` (colour texture).
    pub texture: Option<TexSlot>,
    /// Where the surface is there at all (a MASK or BLEND material); `None`: everywhere.
    pub coverage: Option<Coverage>,
}

/// The alpha of an emitting MASK or BLEND surface, for its light samples: a ray finds such a
/// surface only where, or as often as, its alpha lets it (the intersection's alpha test), so a
/// point sampled on it counts by the same share.
#[derive(Clone, Copy, Debug)]
pub struct Coverage {
    /// MASK (with its cutoff) or BLEND.
    pub mode: AlphaMode,
    /// The base colour's alpha factor.
    pub alpha: f32,
    /// The base colour texture, whose alpha multiplies `alpha`.
    pub texture: Option<TexSlot>,
}

impl Coverage {
    /// The share of the surface that is there at texture coordinates `uv`: 1 or 0 for MASK
    /// (alpha at least the cutoff), alpha in [0, 1] for BLEND, as the intersection's alpha
    /// test passes a ray there (`Scene::alpha_passes`).
    #[inline]
    pub fn at(&self, textures: &[Texture], uv: &[Vec2; 2]) -> f32 {
        let alpha = match self.texture {
            Some(s) => self.alpha * s.lookup(textures, uv).w,
            None => self.alpha,
        };
        match self.mode {
            AlphaMode::Opaque => 1.0,
            AlphaMode::Mask(cutoff) => {
                if alpha >= cutoff {
                    1.0
                } else {
                    0.0
                }
            }
            AlphaMode::Blend => {
                if alpha > 0.0 {
                    alpha.min(1.0)
                } else {
                    0.0
                }
            }
        }
    }
}

impl Emission {
    /// Whether [`Emission::radiance`] or [`Emission::coverage`] reads texture coordinates.
    #[inline]
    pub fn reads_uv(&self) -> bool {
        self.texture.is_some() || self.coverage.is_some_and(|c| c.texture.is_some())
    }

    /// The share of the surface that is there at `uv` (see [`Coverage`]): 1 without alpha.
    #[inline]
    pub fn coverage(&self, textures: &[Texture], uv: &[Vec2; 2]) -> f32 {
        self.coverage.map_or(1.0, |c| c.at(textures, uv))
    }

    /// Radiance leaving a point with geometric normal `ng` and texture coordinates `uv`
    /// towards `wo` (unit, pointing away from the surface).
    #[inline]
    pub fn radiance(&self, textures: &[Texture], ng: Vec3A, uv: &[Vec2; 2], wo: Vec3A) -> Vec3A {
        if !self.two_sided && ng.dot(wo) <= 0.0 {
            return Vec3A::ZERO;
        }
        match self.texture {
            Some(s) => {
                let c = s.lookup(textures, uv);
                self.radiance * Vec3A::new(c.x, c.y, c.z)
            }
            None => self.radiance,
        }
    }
}

/// A surface material ready to shade.
#[derive(Clone, Debug)]
pub struct Material {
    /// How the surface scatters light.
    pub model: Model,
    /// Base colour factor (linear RGBA): the diffuse albedo or the glTF `baseColorFactor`, 1
    /// for models without one; the base colour texture multiplies it.
    pub base_color: Vec4,
    /// Texture slots.
    pub slots: MaterialSlots,
    /// What the surface emits, if anything.
    pub emission: Option<Emission>,
    /// Alpha handling.
    pub alpha_mode: AlphaMode,
    /// Beer–Lambert absorption coefficient inside a solid transmissive body (per metre).
    pub absorption: Vec3A,
    /// The surface bounds a solid transmissive body (glass, water: not thin-walled), which a
    /// path that refracts through it is inside (see `scene::bodies`).
    pub body: bool,
    /// A medium boundary that does not scatter: rays cross it unchanged.
    pub interface: bool,
}

impl Material {
    /// Whether shading looks any texture up (else it never reads texture coordinates).
    #[inline]
    pub fn reads_uv(&self) -> bool {
        let s = &self.slots;
        s.base.is_some()
            || s.metallic_roughness.is_some()
            || s.transmission.is_some()
            || s.specular.is_some()
            || s.specular_color.is_some()
            || s.clearcoat.is_some()
            || s.clearcoat_roughness.is_some()
            || s.normal.is_some()
            || self.emission.is_some_and(|e| e.texture.is_some())
    }

    /// Base colour (linear RGBA) at texture coordinates `uvs`.
    #[inline]
    pub fn base_color(&self, textures: &[Texture], uvs: &[Vec2; 2]) -> Vec4 {
        match self.slots.base {
            Some(s) => self.base_color * s.lookup(textures, uvs),
            None => self.base_color,
        }
    }

    /// The BSDF at texture coordinates `uv`, with every texture looked up.
    #[inline]
    pub fn bsdf(&self, textures: &[Texture], uv: &[Vec2; 2]) -> Bsdf {
        self.bsdf_tinted(textures, uv, Vec3A::ONE)
    }

    /// [`Material::bsdf`] with the base colour multiplied by the vertex colour `color` (white:
    /// none).
    #[inline]
    pub fn bsdf_tinted(&self, textures: &[Texture], uv: &[Vec2; 2], color: Vec3A) -> Bsdf {
        let base_color = |textures: &[Texture], uv: &[Vec2; 2]| {
            let c = self.base_color(textures, uv);
            if color == Vec3A::ONE {
                c
            } else {
                c * color.extend(1.0)
            }
        };
        match &self.model {
            Model::Uniform(b) => *b,
            Model::Diffuse => {
                let c = base_color(textures, uv);
                Bsdf::Diffuse(Diffuse {
                    albedo: Vec3A::new(c.x, c.y, c.z).clamp(Vec3A::ZERO, Vec3A::ONE),
                })
            }
            Model::Pbr(p) => {
                let c = base_color(textures, uv);
                let (mut metallic, mut roughness) = (p.metallic, p.roughness);
                if let Some(s) = self.slots.metallic_roughness {
                    let t = s.lookup(textures, uv);
                    roughness *= t.y;
                    metallic *= t.z;
                }
                let mut transmission = p.transmission;
                if let Some(s) = self.slots.transmission {
                    transmission *= s.lookup(textures, uv).x;
                }
                let (mut specular, mut specular_color) = (p.specular, p.specular_color);
                if let Some(s) = self.slots.specular {
                    specular *= s.lookup(textures, uv).w;
                }
                if let Some(s) = self.slots.specular_color {
                    let t = s.lookup(textures, uv);
                    specular_color *= Vec3A::new(t.x, t.y, t.z);
                }
                let (mut clearcoat, mut clearcoat_alpha) = (p.clearcoat, p.clearcoat_alpha);
                if let Some(s) = self.slots.clearcoat {
                    clearcoat *= s.lookup(textures, uv).x;
                }
                if let Some(s) = self.slots.clearcoat_roughness {
                    // Alpha is roughness squared: the texture scales the roughness.
                    let g = s.lookup(textures, uv).y;
                    clearcoat_alpha *= g * g;
                }
                let base_color = Vec3A::new(c.x, c.y, c.z).clamp(Vec3A::ZERO, Vec3A::ONE);
                if !(metallic > 0.0)
                    && !(specular > 0.0)
                    && !(transmission > 0.0)
                    && !(clearcoat > 0.0)
                {
                    // No metal, no specular lobe (KHR_materials_specular factor 0), no
                    // transmission, no coat: the model is exactly Lambertian, bit for bit
                    // (material test `pbr_without_specular_is_exactly_lambertian`), and the
                    // Lambertian BSDF computes it for a fraction of the cost.
                    return Bsdf::Diffuse(Diffuse { albedo: base_color });
                }
                let roughness = roughness.clamp(0.0, 1.0);
                Bsdf::Pbr(Pbr {
                    base_color,
                    metallic: metallic.clamp(0.0, 1.0),
                    alpha: roughness * roughness,
                    specular,
                    specular_color,
                    ior: p.ior,
                    transmission: transmission.clamp(0.0, 1.0),
                    thin: p.thin,
                    clearcoat,
                    clearcoat_alpha,
                })
            }
        }
    }

    /// The shading normal after normal mapping: `ns` (unit) perturbed by the tangent-space
    /// normal map at `uv`, whose tangent is `dpdu` and whose bitangent has sign
    /// `tangent_sign`; `ns` itself without a normal map.
    #[inline]
    pub fn shading_normal(
        &self,
        textures: &[Texture],
        uv: &[Vec2; 2],
        ns: Vec3A,
        dpdu: Vec3A,
        tangent_sign: f32,
    ) -> Vec3A {
        let Some((slot, scale)) = self.slots.normal else {
            return ns;
        };
        let tex = slot.lookup(textures, uv);
        let tn = Vec3A::new(
            (tex.x * 2.0 - 1.0) * scale,
            (tex.y * 2.0 - 1.0) * scale,
            tex.z * 2.0 - 1.0,
        );
        let frame = Frame::from_zx(ns, dpdu);
        let bitangent = frame.y * tangent_sign;
        let mapped = (frame.x * tn.x + bitangent * tn.y + ns * tn.z).normalize_or(ns);
        if mapped.is_finite() {
            mapped
        } else {
            ns
        }
    }
}

/// Uniform models from their parameters, as the scene builder makes them.
impl Model {
    /// A perfect mirror.
    pub fn mirror(reflectance: Vec3A) -> Self {
        Model::Uniform(Bsdf::Mirror(Mirror { reflectance }))
    }

    /// Smooth glass (or a thin sheet).
    pub fn dielectric(eta: f32, transmittance: Vec3A, thin: bool) -> Self {
        Model::Uniform(Bsdf::Dielectric(Dielectric {
            eta,
            transmittance,
            thin,
        }))
    }

    /// A GGX metal.
    pub fn conductor(eta: Vec3A, k: Vec3A, alpha: f32) -> Self {
        Model::Uniform(Bsdf::Conductor(Conductor { eta, k, alpha }))
    }

    /// Frosted glass.
    pub fn rough_dielectric(eta: f32, alpha: f32, transmittance: Vec3A) -> Self {
        Model::Uniform(Bsdf::RoughDielectric(RoughDielectric {
            eta,
            alpha,
            transmittance,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::texture::TextureLookup;

    fn material(model: Model, base: Option<TexSlot>) -> Material {
        Material {
            model,
            base_color: Vec4::new(0.5, 0.25, 1.0, 1.0),
            slots: MaterialSlots {
                base,
                ..Default::default()
            },
            emission: None,
            alpha_mode: AlphaMode::Opaque,
            absorption: Vec3A::ZERO,
            body: false,
            interface: false,
        }
    }

    #[test]
    fn the_base_colour_texture_multiplies_the_factor() {
        let textures = [Texture::new(
            2,
            1,
            &[[1.0, 0.5, 0.5, 1.0], [0.0, 0.0, 0.0, 0.25]],
            false,
            TextureLookup::default(),
        )];
        let m = material(
            Model::Diffuse,
            Some(TexSlot::new(0, 0, glam::Mat3::IDENTITY)),
        );
        let left = [Vec2::new(0.25, 0.5); 2];
        assert_eq!(
            m.base_color(&textures, &left),
            Vec4::new(0.5, 0.125, 0.5, 1.0)
        );
        let Bsdf::Diffuse(d) = m.bsdf(&textures, &left) else {
            panic!("a diffuse material gives a diffuse BSDF");
        };
        assert_eq!(d.albedo, Vec3A::new(0.5, 0.125, 0.5));
        let right = [Vec2::new(0.75, 0.5); 2];
        assert_eq!(m.base_color(&textures, &right).w, 0.25);
    }

    #[test]
    fn a_pbr_material_without_metal_specular_transmission_or_coat_is_lambertian() {
        let params = PbrParams {
            metallic: 0.0,
            roughness: 0.5,
            specular: 0.0,
            specular_color: Vec3A::ONE,
            ior: 1.5,
            transmission: 0.0,
            thin: true,
            clearcoat: 0.0,
            clearcoat_alpha: 0.0,
        };
        let m = material(Model::Pbr(params), None);
        assert!(matches!(m.bsdf(&[], &[Vec2::ZERO; 2]), Bsdf::Diffuse(_)));
        let m = material(
            Model::Pbr(PbrParams {
                metallic: 1.0,
                ..params
            }),
            None,
        );
        let Bsdf::Pbr(p) = m.bsdf(&[], &[Vec2::ZERO; 2]) else {
            panic!("a metal is not Lambertian");
        };
        assert_eq!((p.metallic, p.alpha), (1.0, 0.25));
    }

    #[test]
    fn a_flat_normal_map_keeps_the_normal_and_a_tilted_one_tilts_it() {
        let lookup = TextureLookup::default();
        // (0.5, 0.5, 1) encodes the unperturbed normal; (1, 0.5, 1) tilts it 45° along +u.
        let flat = [Texture::new(1, 1, &[[0.5, 0.5, 1.0, 1.0]], false, lookup)];
        let tilted = [Texture::new(1, 1, &[[1.0, 0.5, 1.0, 1.0]], false, lookup)];
        let mut m = material(Model::Diffuse, None);
        let uv = [Vec2::splat(0.5); 2];
        m.slots.normal = Some((TexSlot::new(0, 0, glam::Mat3::IDENTITY), 1.0));
        let n = m.shading_normal(&flat, &uv, Vec3A::Z, Vec3A::X, 1.0);
        assert!((n - Vec3A::Z).length() < 1e-6, "{n}");
        let n = m.shading_normal(&tilted, &uv, Vec3A::Z, Vec3A::X, 1.0);
        let expected = Vec3A::new(1.0, 0.0, 1.0).normalize();
        assert!((n - expected).length() < 1e-5, "{n}");
        m.slots.normal = None;
        assert_eq!(
            m.shading_normal(&tilted, &uv, Vec3A::Z, Vec3A::X, 1.0),
            Vec3A::Z
        );
    }
}
