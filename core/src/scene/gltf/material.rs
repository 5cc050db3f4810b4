//! glTF materials to [`MaterialDesc`] with [`BsdfDesc::Pbr`], textures, samplers and images.

use super::{container, Loader};
use crate::scene::desc::{
    AlphaMode, BsdfDesc, MaterialDesc, PbrDesc, TextureDesc, TextureRef, WrapMode,
};
use glam::{Mat3, Vec3};
use serde_json::Value;
use sha2::Digest as _;
use std::rc::Rc;

use crate::scene::image::{self as img, DecodedImage};
use crate::texture::Texels;

/// A number from raw extension JSON, or `default` when absent.
fn num(obj: Option<&Value>, key: &str, default: f32, what: &str) -> Result<f32, String> {
    match obj.and_then(|o| o.get(key)) {
        None => Ok(default),
        Some(v) => match v.as_f64() {
            Some(x) if x.is_finite() => Ok(x as f32),
            _ => Err(format!("{what}: '{key}' must be a finite number")),
        },
    }
}

/// What `KHR_materials_ior.ior` 0 (an infinite index) becomes: its reflectance at normal
/// incidence ((n − 1)/(n + 1))² is 0.999996, rising to 1 at grazing angles, and the index
/// stays finite for the refraction code.
pub(super) const IOR_INFINITE: f32 = 1e6;

fn check_finite(values: &[f32], what: &str) -> Result<(), String> {
    if values.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(format!("{what} is not finite"))
    }
}

/// The `KHR_texture_transform` of a raw textureInfo object as the spec's T·R·S matrix, and its
/// texCoord override.
pub(super) fn texture_transform(
    info: Option<&Value>,
    what: &str,
) -> Result<(Mat3, Option<u32>), String> {
    let Some(ext) = info
        .and_then(|i| i.get("extensions"))
        .and_then(|e| e.get("KHR_texture_transform"))
    else {
        return Ok((Mat3::IDENTITY, None));
    };
    let what = format!("{what} KHR_texture_transform");
    let pair = |key: &str, default: [f32; 2]| -> Result<[f32; 2], String> {
        match ext.get(key) {
            None => Ok(default),
            Some(Value::Array(a)) if a.len() == 2 => {
                let x = a[0].as_f64().unwrap_or(f64::NAN) as f32;
                let y = a[1].as_f64().unwrap_or(f64::NAN) as f32;
                if x.is_finite() && y.is_finite() {
                    Ok([x, y])
                } else {
                    Err(format!("{what}: '{key}' must hold two finite numbers"))
                }
            }
            Some(_) => Err(format!("{what}: '{key}' must be an array of two numbers")),
        }
    };
    let offset = pair("offset", [0.0, 0.0])?;
    let scale = pair("scale", [1.0, 1.0])?;
    let rotation = num(Some(ext), "rotation", 0.0, &what)?;
    let tex_coord = match ext.get("texCoord") {
        None => None,
        Some(v) => Some(
            v.as_u64()
                .filter(|&t| t <= u32::MAX as u64)
                .ok_or_else(|| format!("{what}: 'texCoord' must be a non-negative integer"))?
                as u32,
        ),
    };
    Ok((TextureRef::uv_transform(offset, rotation, scale), tex_coord))
}

impl Loader<'_> {
    /// The raw JSON object of material `index`.
    fn raw_material(&self, index: Option<usize>) -> Option<&Value> {
        self.raw.get("materials")?.get(index?)
    }

    /// The [`crate::scene::desc::SceneDesc::materials`] index for a glTF material (`None`: the
    /// glTF default material), converting it on first use.
    pub(super) fn material(&mut self, mat: &gltf::Material) -> Result<usize, String> {
        if let Some(&i) = self.material_cache.get(&mat.index()) {
            return Ok(i);
        }
        let desc = self.convert_material(mat)?;
        let i = self.desc.materials.len();
        self.desc.materials.push(desc);
        self.material_cache.insert(mat.index(), i);
        Ok(i)
    }

    /// Whether the material has a normal map, and through which UV set.
    pub(super) fn normal_map_uv(&self, mat: &gltf::Material) -> Option<u8> {
        let nt = mat.normal_texture()?;
        let raw = self
            .raw_material(mat.index())
            .and_then(|m| m.get("normalTexture"));
        let over = texture_transform(raw, "").ok().and_then(|(_, t)| t);
        Some(over.unwrap_or(nt.tex_coord()).min(1) as u8)
    }

    fn convert_material(&mut self, mat: &gltf::Material) -> Result<MaterialDesc, String> {
        let what = match mat.index() {
            Some(i) => format!("material {i}"),
            None => "default material".to_string(),
        };
        let name = match (mat.name(), mat.index()) {
            (Some(n), _) => n.to_string(),
            (None, Some(i)) => format!("material {i}"),
            (None, None) => "default".to_string(),
        };
        let raw = self.raw_material(mat.index()).cloned();
        let raw = raw.as_ref();
        let raw_pbr = raw.and_then(|m| m.get("pbrMetallicRoughness"));
        let raw_ext = |name: &str| {
            raw.and_then(|m| m.get("extensions"))
                .and_then(|e| e.get(name))
        };

        let pbr = mat.pbr_metallic_roughness();
        let base_color = pbr.base_color_factor();
        check_finite(&base_color, &format!("{what}: baseColorFactor"))?;
        let base_color = self.unit_factors(base_color, &format!("{what}: baseColorFactor"));
        let mut p = PbrDesc {
            base_color,
            metallic: pbr.metallic_factor(),
            roughness: pbr.roughness_factor(),
            ..PbrDesc::default()
        };
        check_finite(
            &[p.metallic, p.roughness],
            &format!("{what}: metallic/roughness"),
        )?;
        p.metallic = self.unit_factor(p.metallic, &format!("{what}: metallicFactor"));
        p.roughness = self.unit_factor(p.roughness, &format!("{what}: roughnessFactor"));
        if let Some(info) = pbr.base_color_texture() {
            p.base_color_texture = self.texture_ref(
                &info.texture(),
                info.tex_coord(),
                raw_pbr.and_then(|r| r.get("baseColorTexture")),
                true,
                &format!("{what} baseColorTexture"),
            )?;
        }
        if let Some(info) = pbr.metallic_roughness_texture() {
            p.metallic_roughness_texture = self.texture_ref(
                &info.texture(),
                info.tex_coord(),
                raw_pbr.and_then(|r| r.get("metallicRoughnessTexture")),
                false,
                &format!("{what} metallicRoughnessTexture"),
            )?;
        }
        if let Some(spec) = mat.specular() {
            p.specular = spec.specular_factor();
            p.specular_color = Vec3::from(spec.specular_color_factor());
            check_finite(
                &[
                    p.specular,
                    p.specular_color.x,
                    p.specular_color.y,
                    p.specular_color.z,
                ],
                &format!("{what}: KHR_materials_specular"),
            )?;
            p.specular = self.unit_factor(p.specular, &format!("{what}: specularFactor"));
            let raw_spec = raw_ext("KHR_materials_specular");
            if let Some(info) = spec.specular_texture() {
                p.specular_texture = self.texture_ref(
                    &info.texture(),
                    info.tex_coord(),
                    raw_spec.and_then(|t| t.get("specularTexture")),
                    false,
                    &format!("{what} specularTexture"),
                )?;
            }
            if let Some(info) = spec.specular_color_texture() {
                p.specular_color_texture = self.texture_ref(
                    &info.texture(),
                    info.tex_coord(),
                    raw_spec.and_then(|t| t.get("specularColorTexture")),
                    true,
                    &format!("{what} specularColorTexture"),
                )?;
            }
        }
        if let Some(ior) = mat.ior() {
            check_finite(&[ior], &format!("{what}: KHR_materials_ior.ior"))?;
            p.ior = match ior {
                // The specification's specular-glossiness compatibility mode: an infinite
                // index, whose Fresnel term is 1 at every angle.
                0.0 => IOR_INFINITE,
                ior if ior >= 1.0 => ior,
                _ => {
                    return Err(format!(
                        "{what}: KHR_materials_ior.ior must be at least 1, or 0 (an infinite \
                         index), got {ior}"
                    ))
                }
            };
        }
        if let Some(tr) = mat.transmission() {
            p.transmission = tr.transmission_factor();
            check_finite(&[p.transmission], &format!("{what}: transmissionFactor"))?;
            p.transmission =
                self.unit_factor(p.transmission, &format!("{what}: transmissionFactor"));
            if let Some(info) = tr.transmission_texture() {
                p.transmission_texture = self.texture_ref(
                    &info.texture(),
                    info.tex_coord(),
                    raw_ext("KHR_materials_transmission")
                        .and_then(|t| t.get("transmissionTexture")),
                    false,
                    &format!("{what} transmissionTexture"),
                )?;
            }
        }
        if let Some(vol) = mat.volume() {
            let thickness = vol.thickness_factor();
            // 0 (or less) means thin-walled; a NaN thickness is refused just below.
            p.thin_walled = thickness <= 0.0;
            p.attenuation_color = Vec3::from(vol.attenuation_color());
            p.attenuation_distance = vol.attenuation_distance();
            check_finite(
                &[
                    thickness,
                    p.attenuation_color.x,
                    p.attenuation_color.y,
                    p.attenuation_color.z,
                ],
                &format!("{what}: KHR_materials_volume"),
            )?;
            if p.attenuation_distance.is_nan() || p.attenuation_distance <= 0.0 {
                return Err(format!(
                    "{what}: KHR_materials_volume.attenuationDistance must be positive"
                ));
            }
        }
        if let Some(cc) = raw_ext("KHR_materials_clearcoat") {
            let w = format!("{what}: KHR_materials_clearcoat");
            let coat = num(Some(cc), "clearcoatFactor", 0.0, &w)?;
            p.clearcoat = self.unit_factor(coat, &format!("{w}: clearcoatFactor"));
            let rough = num(Some(cc), "clearcoatRoughnessFactor", 0.0, &w)?;
            p.clearcoat_roughness =
                self.unit_factor(rough, &format!("{w}: clearcoatRoughnessFactor"));
            p.clearcoat_texture =
                self.raw_texture_ref(cc.get("clearcoatTexture"), &format!("{w}.clearcoatTexture"))?;
            p.clearcoat_roughness_texture = self.raw_texture_ref(
                cc.get("clearcoatRoughnessTexture"),
                &format!("{w}.clearcoatRoughnessTexture"),
            )?;
            if cc.get("clearcoatNormalTexture").is_some() {
                self.warn(format!(
                    "{w}: clearcoatNormalTexture is not supported; the coat uses the shading normal"
                ));
            }
        }

        let mut m = MaterialDesc::new(name, BsdfDesc::Pbr(Box::new(p)));
        let strength = mat.emissive_strength().unwrap_or(1.0);
        let ef = mat.emissive_factor();
        check_finite(&ef, &format!("{what}: emissiveFactor"))?;
        check_finite(&[strength], &format!("{what}: emissiveStrength"))?;
        if ef.iter().any(|&c| c < 0.0) {
            return Err(format!(
                "{what}: emissiveFactor must be non-negative, got {ef:?}"
            ));
        }
        if strength < 0.0 {
            return Err(format!(
                "{what}: KHR_materials_emissive_strength.emissiveStrength must be non-negative, \
                 got {strength}"
            ));
        }
        m.emission = Vec3::from(ef) * strength;
        crate::light::check_radiance("emissiveFactor × emissiveStrength", m.emission.into())
            .map_err(|e| format!("{what}: {e}"))?;
        if let Some(info) = mat.emissive_texture() {
            m.emission_texture = self.texture_ref(
                &info.texture(),
                info.tex_coord(),
                raw.and_then(|r| r.get("emissiveTexture")),
                true,
                &format!("{what} emissiveTexture"),
            )?;
        }
        if let Some(nt) = mat.normal_texture() {
            let scale = nt.scale();
            check_finite(&[scale], &format!("{what}: normalTexture.scale"))?;
            if let Some(r) = self.texture_ref(
                &nt.texture(),
                nt.tex_coord(),
                raw.and_then(|r| r.get("normalTexture")),
                false,
                &format!("{what} normalTexture"),
            )? {
                m.normal_texture = Some((r, scale));
            }
        }
        m.two_sided = mat.double_sided();
        m.alpha_mode = match mat.alpha_mode() {
            gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
            gltf::material::AlphaMode::Mask => {
                let cutoff = mat.alpha_cutoff().unwrap_or(0.5);
                check_finite(&[cutoff], &format!("{what}: alphaCutoff"))?;
                AlphaMode::Mask(cutoff)
            }
            gltf::material::AlphaMode::Blend => AlphaMode::Blend,
        };
        Ok(m)
    }

    /// A reference to texture `tex` decoded as sRGB or linear, with its texture transform.
    /// A linear texture reference given as raw JSON (`{"index": I, "texCoord": N}`), for
    /// extensions the `gltf` crate does not parse; `None` when absent.
    fn raw_texture_ref(
        &mut self,
        raw_info: Option<&Value>,
        what: &str,
    ) -> Result<Option<TextureRef>, String> {
        let Some(info) = raw_info else {
            return Ok(None);
        };
        let index = info
            .get("index")
            .and_then(Value::as_u64)
            .ok_or_else(|| format!("{what}: index must be a texture index"))?;
        let tex = usize::try_from(index)
            .ok()
            .and_then(|i| self.doc.textures().nth(i))
            .ok_or_else(|| format!("{what}: no texture {index}"))?;
        let tex_coord = match info.get("texCoord") {
            None => 0,
            Some(v) => v
                .as_u64()
                .and_then(|t| u32::try_from(t).ok())
                .ok_or_else(|| format!("{what}: texCoord must be a small integer"))?,
        };
        self.texture_ref(&tex, tex_coord, Some(info), false, what)
    }

    fn texture_ref(
        &mut self,
        tex: &gltf::Texture,
        tex_coord: u32,
        raw_info: Option<&Value>,
        srgb: bool,
        what: &str,
    ) -> Result<Option<TextureRef>, String> {
        let (transform, over) = texture_transform(raw_info, what)?;
        let set = over.unwrap_or(tex_coord);
        let texcoord = if set > 1 {
            self.warn(format!(
                "{what}: TEXCOORD_{set} is not supported (only 0 and 1); TEXCOORD_0 used"
            ));
            0
        } else {
            set as u8
        };
        let Some(texture) = self.texture(tex, srgb)? else {
            return Ok(None);
        };
        Ok(Some(TextureRef {
            texture,
            texcoord,
            transform,
        }))
    }

    /// The [`crate::scene::desc::SceneDesc::textures`] index of glTF texture `tex` as sRGB or
    /// linear data; `None` (with a warning) for a texture without an image.
    fn texture(&mut self, tex: &gltf::Texture, srgb: bool) -> Result<Option<usize>, String> {
        let Some(image) = tex.source() else {
            self.warn(format!("texture {}: no image source; ignored", tex.index()));
            return Ok(None);
        };
        let sampler = tex.sampler();
        let wrap = |w: gltf::texture::WrappingMode| match w {
            gltf::texture::WrappingMode::ClampToEdge => WrapMode::Clamp,
            gltf::texture::WrappingMode::MirroredRepeat => WrapMode::MirroredRepeat,
            gltf::texture::WrappingMode::Repeat => WrapMode::Repeat,
        };
        let (wrap_u, wrap_v) = (wrap(sampler.wrap_s()), wrap(sampler.wrap_t()));
        let bilinear = !matches!(
            sampler.mag_filter(),
            Some(gltf::texture::MagFilter::Nearest)
        );
        let key = (image.index(), srgb, wrap_u, wrap_v, bilinear);
        if let Some(&i) = self.texture_cache.get(&key) {
            return Ok(Some(i));
        }
        let decoded = self.image(&image)?;
        // The texture shares the image's texels (charged when decoded). f32 texels are
        // converted once for colour and once for data when the scene is built: a copy each.
        // Once per decoded image (images of the same bytes share one) and colour space.
        let converts = matches!(decoded.texels, Texels::F32(_))
            && self.converted.insert((Rc::as_ptr(&decoded) as usize, srgb));
        if converts {
            self.charge(decoded.texels.bytes(), &format!("texture {}", tex.index()))?;
        }
        let desc = TextureDesc {
            name: image
                .name()
                .map(str::to_string)
                .unwrap_or_else(|| format!("image {}", image.index())),
            width: decoded.width,
            height: decoded.height,
            texels: decoded.texels.clone(),
            srgb,
            wrap_u,
            wrap_v,
            bilinear,
        };
        let i = self.desc.textures.len();
        self.desc.textures.push(desc);
        self.texture_cache.insert(key, i);
        Ok(Some(i))
    }

    /// Decodes an image once, with size limits.
    fn image(&mut self, image: &gltf::Image) -> Result<Rc<DecodedImage>, String> {
        if let Some(d) = self.image_cache.get(&image.index()) {
            return Ok(d.clone());
        }
        let what = format!("image {}", image.index());
        let bytes: Vec<u8> = match image.source() {
            gltf::image::Source::View { view, .. } => self.view_bytes(&view, &what)?.to_vec(),
            gltf::image::Source::Uri { uri, .. } => {
                let field = format!("images[{}].uri", image.index());
                container::load_uri(uri, self.base_dir, self.files, &field, img::MAX_IMAGE_FILE)?
            }
        };
        let content: [u8; 32] = sha2::Sha256::digest(&bytes).into();
        if let Some(d) = self.image_content.get(&content).cloned() {
            self.image_cache.insert(image.index(), d.clone());
            return Ok(d);
        }
        // The size first: the memory budget is charged before anything is decoded.
        let size = img::image_bytes(&bytes).map_err(|e| format!("{what}: {e}"))?;
        self.charge(usize::try_from(size).unwrap_or(usize::MAX), &what)?;
        // Values stay as stored (sRGB-encoded for colour); only scaled to [0, 1].
        let decoded = Rc::new(img::decode_image(&bytes).map_err(|e| format!("{what}: {e}"))?);
        self.image_cache.insert(image.index(), decoded.clone());
        self.image_content.insert(content, decoded.clone());
        Ok(decoded)
    }
}
