//! Plain scene descriptions: what a scene *is*, before anything is built for rendering.
//!
//! Front ends (the JSON format in [`super::json`], glTF in [`super::gltf`]) parse files into a
//! [`SceneDesc`]; [`super::build`] turns it into the render-ready [`crate::Scene`]. These types hold
//! no BVH, no sampling tables and no file handles, so they are cheap to inspect in tests.
//!
//! Conventions: right-handed, +Y up, metres; colours are linear Rec.709 RGB; emission is radiance
//! in W·sr⁻¹·m⁻² per channel (glTF "nits"); angles in the JSON format are degrees, here radians.

use crate::settings::{FilterKind, IntegratorKind, RenderOverrides, RenderSettings, SettingsError};
use glam::{Mat4, Vec2, Vec3};
use serde::{Deserialize, Serialize};

// Plain parameters the runtime takes as they are: defined beside the code that uses them (the
// runtime never imports this module), named here too so that front ends find every part of a
// description in one place.
pub use crate::camera::Projection;
pub use crate::geometry::transform::Degenerate;
pub use crate::material::AlphaMode;
pub use crate::texture::WrapMode;

/// Largest difference from [0, 0, 0, 1] the last row of a transform may show (rounding).
const AFFINE_TOLERANCE: f32 = 1e-6;

/// Checks an object's transform: finite, affine (its last row is [0, 0, 0, 1]: a projective
/// transform has no meaning for an object), and invertible ([`Degenerate::of`]).
pub fn check_transform(m: &Mat4) -> Result<(), String> {
    if !m.is_finite() {
        return Err("transform is not finite".into());
    }
    if let Some(d) = Degenerate::of(m) {
        return Err(d.to_string());
    }
    check_affine(m)
}

/// Checks a camera's transform: finite, affine, and with a direction (no zero axis, axes
/// that span space). A camera uses only its rotation and position, so a scale too small to
/// invert will do, as long as its axes' lengths can be divided out in f32.
pub fn check_camera_transform(m: &Mat4) -> Result<(), String> {
    if !m.is_finite() {
        return Err("transform is not finite".into());
    }
    match Degenerate::of(m) {
        Some(Degenerate::TooSmall)
            if [m.x_axis, m.y_axis, m.z_axis]
                .iter()
                .all(|c| c.truncate().length_squared().is_normal()) => {}
        Some(d) => return Err(d.to_string()),
        None => {}
    }
    check_affine(m)
}

/// Checks that a transform is affine: its last row is [0, 0, 0, 1] (no projection).
pub fn check_affine(m: &Mat4) -> Result<(), String> {
    let row = m.row(3);
    if (row - glam::Vec4::W).abs().max_element() > AFFINE_TOLERANCE {
        return Err(format!(
            "the transform's last row must be [0, 0, 0, 1] (no projection), got [{}, {}, {}, {}]",
            row.x, row.y, row.z, row.w
        ));
    }
    Ok(())
}

/// Checks a material parameter that lives in [0, 1] (metallic, roughness...).
pub fn check_unit(what: &str, x: f32) -> Result<(), String> {
    if (0.0..=1.0).contains(&x) {
        Ok(())
    } else {
        Err(format!("{what} must be between 0 and 1, got {x}"))
    }
}

/// Checks a reflectance or transmittance (an albedo, a tint): every channel in [0, 1]. More
/// than 1 would make light, less than 0 negative light.
pub fn check_reflectance(what: &str, v: Vec3) -> Result<(), String> {
    check_channels(what, v, "between 0 and 1", |v| {
        v.cmpge(Vec3::ZERO).all() && v.cmple(Vec3::ONE).all()
    })
}

/// Checks a metal's complex index of refraction: η finite and positive, k finite and
/// non-negative, in every channel. The error is the field (`eta` or `k`) and its message.
pub fn check_metal(eta: Vec3, k: Vec3) -> Result<(), (&'static str, String)> {
    check_channels("eta", eta, "finite and positive", |v| {
        v.is_finite() && v.min_element() > 0.0
    })
    .map_err(|e| ("eta", e))?;
    check_coefficient("k", k).map_err(|e| ("k", e))
}

/// `Ok` if `ok(v)`, else "`what` must be `rule` in every channel, got [x, y, z]".
fn check_channels(
    what: &str,
    v: Vec3,
    rule: &str,
    ok: impl Fn(Vec3) -> bool,
) -> Result<(), String> {
    if ok(v) {
        Ok(())
    } else {
        Err(format!(
            "{what} must be {rule} in every channel, got [{}, {}, {}]",
            v.x, v.y, v.z
        ))
    }
}

/// Checks an index of refraction (inside relative to outside): finite and positive.
pub fn check_ior(ior: f32) -> Result<(), String> {
    if ior.is_finite() && ior > 0.0 {
        Ok(())
    } else {
        Err(format!("ior must be positive, got {ior}"))
    }
}

/// Checks a per-channel coefficient (absorption per metre): finite and non-negative.
pub fn check_coefficient(what: &str, v: Vec3) -> Result<(), String> {
    check_channels(what, v, "finite and non-negative", |v| {
        v.is_finite() && v.min_element() >= 0.0
    })
}

/// Checks a spot light's cone (half-angles in degrees): 0 ≤ inner ≤ outer, 0 < outer ≤ 90.
/// The error is the field (`inner_angle` or `outer_angle`) and its message.
pub fn check_spot_angles(inner: f32, outer: f32) -> Result<(), (&'static str, String)> {
    if !(outer > 0.0 && outer <= 90.0 + 1e-4) {
        return Err((
            "outer_angle",
            format!("outer_angle must be above 0 and at most 90 degrees, got {outer}"),
        ));
    }
    if !(inner >= 0.0 && inner <= outer) {
        return Err((
            "inner_angle",
            format!("inner_angle must be between 0 and outer_angle ({outer} degrees), got {inner}"),
        ));
    }
    Ok(())
}

/// A complete scene description: geometry, materials, lights, cameras and render defaults.
#[derive(Clone, Debug, Default)]
pub struct SceneDesc {
    /// Triangle meshes, referenced by [`ShapeDesc::Mesh`]. One mesh may be used by many objects
    /// (instancing): its vertex data is stored once.
    pub meshes: Vec<MeshDesc>,
    /// Decoded images, referenced by [`TextureRef::texture`].
    pub textures: Vec<TextureDesc>,
    /// Materials, referenced by [`ObjectDesc::material`].
    pub materials: Vec<MaterialDesc>,
    /// Shapes placed in the world, each with a material and a transform.
    pub objects: Vec<ObjectDesc>,
    /// Lights that are not surfaces (emissive surfaces are objects whose material emits).
    pub lights: Vec<LightDesc>,
    /// Light arriving from infinitely far away, if any.
    pub environment: Option<EnvironmentDesc>,
    /// `environment` is the default one a loader added because the scene has no light;
    /// [`crate::RenderSettings::default_light`] `false` leaves it out.
    pub default_environment: bool,
    /// Cameras; the render picks one by name or index (`--camera`), the first by default.
    pub cameras: Vec<CameraDesc>,
    /// Render settings the scene file asks for; command-line flags and job settings override them.
    pub render: RenderDefaults,
    /// Participating media, referenced by [`ObjectDesc::media`] and [`SceneDesc::medium`].
    pub media: Vec<MediumDesc>,
    /// Index into [`SceneDesc::media`] of the medium that fills space outside every object
    /// (global fog), in which the camera stands; `None` is vacuum.
    pub medium: Option<usize>,
    /// Non-fatal problems found while loading (unsupported optional extensions, skipped
    /// primitives...), to be shown to the user.
    pub warnings: Vec<String>,
}

/// An indexed triangle mesh in its own object space.
#[derive(Clone, Debug, Default)]
pub struct MeshDesc {
    /// Name for messages (glTF mesh name and primitive index, or the JSON object name).
    pub name: String,
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals; empty means flat shading from the geometric normal.
    pub normals: Vec<Vec3>,
    /// Per-vertex tangents (xyz) with handedness in w, for normal mapping; may be empty.
    pub tangents: Vec<[f32; 4]>,
    /// Texture coordinate sets 0 and 1; each is empty or has one entry per vertex.
    pub uvs: [Vec<Vec2>; 2],
    /// Per-vertex colours (glTF `COLOR_0`, linear RGB) multiplying the material's base
    /// colour; empty or one per vertex.
    pub colors: Vec<Vec3>,
    /// Triangles as vertex indices, counter-clockwise seen from the front.
    pub indices: Vec<[u32; 3]>,
}

/// A decoded texture image.
#[derive(Clone, Debug)]
pub struct TextureDesc {
    /// Name for messages (file name or glTF image index).
    pub name: String,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Texels row by row from the top, RGBA (the bytes of an 8-bit image, or values; a
    /// `Vec<[f32; 4]>` converts with `.into()`). Colour data stays encoded as stored (see
    /// `srgb`); alpha is always linear.
    pub texels: crate::texture::Texels,
    /// Whether RGB is sRGB-encoded (base colour and emissive textures) and must be decoded to
    /// linear on lookup, or linear data (normal, metallic-roughness maps).
    pub srgb: bool,
    /// Addressing outside [0, 1] along u.
    pub wrap_u: WrapMode,
    /// Addressing outside [0, 1] along v.
    pub wrap_v: WrapMode,
    /// Bilinear (true) or nearest (false) magnification.
    pub bilinear: bool,
}

/// A reference from a material slot to a texture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into [`SceneDesc::textures`].
    pub texture: usize,
    /// Which texture coordinate set (0 or 1).
    pub texcoord: u8,
    /// `KHR_texture_transform` as a 3×3 affine matrix applied to (u, v, 1); identity if absent.
    pub transform: glam::Mat3,
}

impl TextureRef {
    /// A reference to `texture` through TEXCOORD_0 with no transform.
    pub fn new(texture: usize) -> Self {
        Self {
            texture,
            texcoord: 0,
            transform: glam::Mat3::IDENTITY,
        }
    }

    /// A texture coordinate transform: translation · rotation · scale, applied to
    /// `(u, v, 1)` (glTF's `KHR_texture_transform`, and the JSON format's `uv` of a texture).
    ///
    /// The rotation turns the UVs by `rotation` radians counter-clockwise as seen in texture
    /// space, where v runs down the image: `(u, v)` → `(u·cos + v·sin, −u·sin + v·cos)`, which
    /// turns the image clockwise on the surface. That is the transpose of the rotation in
    /// `KHR_texture_transform`'s GLSL listing, a counter-clockwise turn only where v runs up
    /// (KhronosGroup/glTF issue 1563); the sample asset TextureTransformTest, Blender's
    /// importer and Babylon.js use this one.
    pub fn uv_transform(offset: [f32; 2], rotation: f32, scale: [f32; 2]) -> glam::Mat3 {
        use glam::{Mat3, Vec3};
        let (s, c) = rotation.sin_cos();
        let t = Mat3::from_cols(Vec3::X, Vec3::Y, Vec3::new(offset[0], offset[1], 1.0));
        let r = Mat3::from_cols(Vec3::new(c, -s, 0.0), Vec3::new(s, c, 0.0), Vec3::Z);
        let sc = Mat3::from_diagonal(Vec3::new(scale[0], scale[1], 1.0));
        t * r * sc
    }
}

/// A surface material: a BSDF plus emission, alpha and normal mapping.
#[derive(Clone, Debug)]
pub struct MaterialDesc {
    /// Name for messages and tests.
    pub name: String,
    /// How the surface scatters light.
    pub bsdf: BsdfDesc,
    /// Emitted radiance (already multiplied by any strength factor); zero for non-emitters.
    pub emission: Vec3,
    /// Multiplies `emission` per texel (sRGB texture).
    pub emission_texture: Option<TextureRef>,
    /// Whether the surface emits from both sides. One-sided emitters emit only on the side
    /// their geometric normal faces (the counter-clockwise side of a triangle). Every surface
    /// is seen, lit and casts shadows from both sides whatever this says (no back-face
    /// culling).
    pub two_sided: bool,
    /// Alpha handling; alpha is base colour alpha times the base colour texture's alpha.
    pub alpha_mode: AlphaMode,
    /// Tangent-space normal map with its scale (glTF `normalTexture.scale`).
    pub normal_texture: Option<(TextureRef, f32)>,
}

impl MaterialDesc {
    /// A named material with the given BSDF, no emission, one-sided, opaque.
    pub fn new(name: impl Into<String>, bsdf: BsdfDesc) -> Self {
        Self {
            name: name.into(),
            bsdf,
            emission: Vec3::ZERO,
            emission_texture: None,
            two_sided: false,
            alpha_mode: AlphaMode::Opaque,
            normal_texture: None,
        }
    }

    /// Whether a surface of this material gives light: its emission is above zero, and it is
    /// not an interface (no surface: it neither scatters nor emits).
    pub fn emits(&self) -> bool {
        self.emission.max_element() > 0.0 && !matches!(self.bsdf, BsdfDesc::Interface)
    }

    /// Every texture the material looks up, with the name of its slot (the one list of a
    /// material's slots that loaders walk: to check, to renumber).
    pub fn texture_refs_mut(&mut self) -> Vec<(&'static str, &mut TextureRef)> {
        let mut refs = vec![
            ("emissive", self.emission_texture.as_mut()),
            ("normal", self.normal_texture.as_mut().map(|(t, _)| t)),
        ];
        match &mut self.bsdf {
            BsdfDesc::Diffuse { texture, .. } => refs.push(("albedo", texture.as_mut())),
            BsdfDesc::Pbr(p) => refs.extend([
                ("base colour", p.base_color_texture.as_mut()),
                ("metallic-roughness", p.metallic_roughness_texture.as_mut()),
                ("specular", p.specular_texture.as_mut()),
                ("specular colour", p.specular_color_texture.as_mut()),
                ("transmission", p.transmission_texture.as_mut()),
                ("clearcoat", p.clearcoat_texture.as_mut()),
                (
                    "clearcoat roughness",
                    p.clearcoat_roughness_texture.as_mut(),
                ),
            ]),
            _ => {}
        }
        refs.into_iter()
            .filter_map(|(slot, t)| Some((slot, t?)))
            .collect()
    }
}

/// The scattering model of a material.
#[derive(Clone, Debug)]
pub enum BsdfDesc {
    /// Ideal diffuse reflection.
    Diffuse {
        /// Reflectance (albedo).
        albedo: Vec3,
        /// Multiplies `albedo` (sRGB texture).
        texture: Option<TextureRef>,
    },
    /// Perfect specular reflection.
    Mirror {
        /// Reflectance.
        reflectance: Vec3,
    },
    /// Smooth glass: Snell refraction, exact Fresnel, total internal reflection.
    Dielectric {
        /// Index of refraction inside relative to outside.
        ior: f32,
        /// Multiplies transmitted light (a cheap tint; use `absorption` for physical colour).
        transmittance: Vec3,
        /// Beer–Lambert absorption coefficient per metre inside the body (zero: clear).
        absorption: Vec3,
        /// Thin-walled sheet: transmission without bending, no interior.
        thin: bool,
    },
    /// A metal with GGX microfacets.
    Conductor {
        /// Complex index of refraction, real part (per channel).
        eta: Vec3,
        /// Complex index of refraction, imaginary part (per channel).
        k: Vec3,
        /// GGX alpha (perceptual roughness squared); 0 is a perfect mirror with Fresnel.
        alpha: f32,
    },
    /// A surface that does not scatter: light crosses it unchanged. It bounds a medium
    /// ([`ObjectDesc::media`]).
    Interface,
    /// Frosted glass: GGX microfacet reflection and refraction.
    RoughDielectric {
        /// Index of refraction inside relative to outside.
        ior: f32,
        /// GGX alpha (perceptual roughness squared).
        alpha: f32,
        /// Multiplies transmitted light.
        transmittance: Vec3,
    },
    /// The glTF 2.0 metallic–roughness model with the extensions raytile understands.
    Pbr(Box<PbrDesc>),
}

impl SceneDesc {
    /// What decides whether `sppm` can render the scene (checked by
    /// [`super::job::SppmFacts::check`] against a job's settings).
    pub fn sppm_facts(&self) -> super::job::SppmFacts {
        super::job::SppmFacts {
            // The one shape without bounds, which the scene's builder keeps out of the BVH.
            unbounded: self
                .objects
                .iter()
                .any(|o| matches!(o.shape, ShapeDesc::Plane { .. })),
            directional_light: self
                .lights
                .iter()
                .any(|l| matches!(l, LightDesc::Directional { .. })),
            environment: self.environment.is_some(),
            default_environment: self.default_environment,
        }
    }

    /// Whether anything in the scene gives light: a light, an environment, or an object whose
    /// material emits.
    pub fn is_lit(&self) -> bool {
        !self.lights.is_empty()
            || self.environment.is_some()
            || self.objects.iter().any(|o| {
                self.materials
                    .get(o.material)
                    .is_some_and(|m| m.emission.max_element() > 0.0 || m.emission_texture.is_some())
            })
    }
}

impl BsdfDesc {
    /// The material's reflectance or transmittance colour, with its name in raytile's JSON
    /// format, for [`check_reflectance`]: diffuse albedo, mirror reflectance, glass
    /// transmittance or the base colour.
    pub fn tint(&self) -> Option<(&'static str, Vec3)> {
        match self {
            BsdfDesc::Diffuse { albedo, .. } => Some(("albedo", *albedo)),
            BsdfDesc::Mirror { reflectance } => Some(("reflectance", *reflectance)),
            BsdfDesc::Dielectric { transmittance, .. }
            | BsdfDesc::RoughDielectric { transmittance, .. } => {
                Some(("transmittance", *transmittance))
            }
            BsdfDesc::Pbr(p) => Some(("base_color", Vec3::from_slice(&p.base_color[..3]))),
            BsdfDesc::Conductor { .. } | BsdfDesc::Interface => None,
        }
    }
}

/// Parameters of the glTF metallic–roughness material (core spec plus extensions).
#[derive(Clone, Debug)]
pub struct PbrDesc {
    /// `baseColorFactor` (linear RGBA).
    pub base_color: [f32; 4],
    /// `baseColorTexture` (sRGB).
    pub base_color_texture: Option<TextureRef>,
    /// `metallicFactor`.
    pub metallic: f32,
    /// `roughnessFactor` (perceptual roughness; GGX alpha is its square).
    pub roughness: f32,
    /// `metallicRoughnessTexture`: roughness in G, metallic in B (linear).
    pub metallic_roughness_texture: Option<TextureRef>,
    /// `KHR_materials_specular.specularFactor` (1 if absent; 0 removes the specular layer).
    pub specular: f32,
    /// `KHR_materials_specular.specularColorFactor`.
    pub specular_color: Vec3,
    /// `KHR_materials_specular.specularTexture`: multiplies `specular` by its A channel
    /// (linear).
    pub specular_texture: Option<TextureRef>,
    /// `KHR_materials_specular.specularColorTexture`: multiplies `specular_color` (sRGB).
    pub specular_color_texture: Option<TextureRef>,
    /// `KHR_materials_ior.ior` (1.5 if absent).
    pub ior: f32,
    /// `KHR_materials_transmission.transmissionFactor`.
    pub transmission: f32,
    /// `KHR_materials_transmission.transmissionTexture` (R channel).
    pub transmission_texture: Option<TextureRef>,
    /// `KHR_materials_volume`: `thicknessFactor == 0` (or no volume extension) means thin-walled.
    pub thin_walled: bool,
    /// `KHR_materials_volume.attenuationColor`.
    pub attenuation_color: Vec3,
    /// `KHR_materials_volume.attenuationDistance` (infinite: no absorption).
    pub attenuation_distance: f32,
    /// `KHR_materials_clearcoat.clearcoatFactor`.
    pub clearcoat: f32,
    /// `KHR_materials_clearcoat.clearcoatRoughnessFactor`.
    pub clearcoat_roughness: f32,
    /// `KHR_materials_clearcoat.clearcoatTexture`: multiplies `clearcoat` by its R channel.
    pub clearcoat_texture: Option<TextureRef>,
    /// `KHR_materials_clearcoat.clearcoatRoughnessTexture`: multiplies `clearcoat_roughness`
    /// by its G channel.
    pub clearcoat_roughness_texture: Option<TextureRef>,
}

impl Default for PbrDesc {
    fn default() -> Self {
        Self {
            base_color: [1.0; 4],
            base_color_texture: None,
            metallic: 1.0,
            roughness: 1.0,
            metallic_roughness_texture: None,
            specular: 1.0,
            specular_color: Vec3::ONE,
            specular_texture: None,
            specular_color_texture: None,
            ior: 1.5,
            transmission: 0.0,
            transmission_texture: None,
            thin_walled: true,
            attenuation_color: Vec3::ONE,
            attenuation_distance: f32::INFINITY,
            clearcoat: 0.0,
            clearcoat_roughness: 0.0,
            clearcoat_texture: None,
            clearcoat_roughness_texture: None,
        }
    }
}

/// A shape in object space. Objects place it in the world with a transform.
#[derive(Clone, Debug, PartialEq)]
pub enum ShapeDesc {
    /// A sphere.
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius (> 0).
        radius: f32,
    },
    /// An axis-aligned box (in object space; a transform may rotate it).
    Box {
        /// Minimum corner.
        min: Vec3,
        /// Maximum corner.
        max: Vec3,
    },
    /// An infinite plane through `point` with normal `normal` (its front side).
    Plane {
        /// A point on the plane.
        point: Vec3,
        /// Front-facing normal.
        normal: Vec3,
    },
    /// A disk.
    Disk {
        /// Centre.
        center: Vec3,
        /// Front-facing normal.
        normal: Vec3,
        /// Radius.
        radius: f32,
    },
    /// A parallelogram `corner + s·edge_u + t·edge_v`, s, t ∈ [0, 1]; front is edge_u × edge_v.
    Rectangle {
        /// One corner.
        corner: Vec3,
        /// First edge.
        edge_u: Vec3,
        /// Second edge.
        edge_v: Vec3,
    },
    /// A planar polygon, convex or concave, vertices in order (front: counter-clockwise).
    Polygon {
        /// At least three coplanar vertices.
        vertices: Vec<Vec3>,
    },
    /// The quadric surface pᵀ Q p = 0 (p homogeneous), clipped to the box [clip_min, clip_max].
    Quadric {
        /// The symmetric 4×4 matrix Q (column-major as glam stores it).
        q: Mat4,
        /// Minimum corner of the clipping box.
        clip_min: Vec3,
        /// Maximum corner of the clipping box.
        clip_max: Vec3,
        /// Texture coordinate v from the height along Y, 0 at the box's top (the JSON format's
        /// cylinders, cones, paraboloids and hyperboloids), rather than from the angle from +Y
        /// (see [`crate::geometry::quadric::Quadric`]).
        v_by_height: bool,
    },
    /// A triangle mesh: index into [`SceneDesc::meshes`].
    Mesh {
        /// Index into [`SceneDesc::meshes`].
        mesh: usize,
    },
}

/// A shape placed in the world.
#[derive(Clone, Debug)]
pub struct ObjectDesc {
    /// Name for messages and tests (glTF node name, JSON object name).
    pub name: String,
    /// The shape in object space.
    pub shape: ShapeDesc,
    /// Index into [`SceneDesc::materials`].
    pub material: usize,
    /// Object-to-world transform (affine; may scale non-uniformly or mirror).
    pub transform: Mat4,
    /// The media on the two sides of the surface; `None`: the surface is no medium boundary
    /// (a ray crossing it stays in the medium it was in).
    pub media: Option<ObjectMedia>,
}

/// The media inside and outside an object's closed surface: indices into
/// [`SceneDesc::media`], `None` for vacuum.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ObjectMedia {
    /// The medium inside (behind the surface's front side).
    pub interior: Option<usize>,
    /// The medium outside (the side the front normal points to).
    pub exterior: Option<usize>,
}

/// A participating medium: absorption and scattering per colour channel (per metre), a
/// Henyey–Greenstein phase function, and for heterogeneous media a density grid.
#[derive(Clone, Debug)]
pub struct MediumDesc {
    /// Name for messages.
    pub name: String,
    /// Absorption coefficient σa per metre, per channel (before `scale`).
    pub sigma_a: Vec3,
    /// Scattering coefficient σs per metre, per channel (before `scale`).
    pub sigma_s: Vec3,
    /// Henyey–Greenstein asymmetry in (-1, 1); 0 is isotropic.
    pub g: f32,
    /// Multiplies `sigma_a` and `sigma_s`.
    pub scale: f32,
    /// `None`: homogeneous. Else σa and σs are multiplied by this density, which fills its
    /// box in the space of the object that holds the medium as its interior (world space for
    /// the scene's global medium); an exterior reference sees it where its holder put it.
    pub density: Option<GridDesc>,
}

/// A density grid and where it sits in its object's space.
#[derive(Clone, Debug)]
pub struct GridDesc {
    /// The voxels and the box they fill.
    pub density: crate::medium::DensityGrid,
    /// From the density's space to the object's space (the identity but for `.vdb` grids
    /// whose index-to-world map rotates).
    pub transform: glam::Affine3A,
    /// Cells of the majorant grid per axis (`None`: the default); `[1, 1, 1]` is one global
    /// majorant, the slowest but simplest bound.
    pub majorant_resolution: Option<[usize; 3]>,
}

/// A light that is not a surface.
#[derive(Clone, Debug, PartialEq)]
pub enum LightDesc {
    /// An isotropic point light.
    Point {
        /// Position in the world.
        position: Vec3,
        /// Radiant intensity in W/sr per channel (glTF candela).
        intensity: Vec3,
        /// glTF `range`: the light is cut off beyond it (infinite if absent).
        range: f32,
    },
    /// A spot light with a smooth falloff between the inner and outer cone.
    Spot {
        /// Position in the world.
        position: Vec3,
        /// Direction the spot points in.
        direction: Vec3,
        /// Radiant intensity on the axis, W/sr per channel.
        intensity: Vec3,
        /// Half-angle of full intensity, radians.
        inner_angle: f32,
        /// Half-angle beyond which there is no light, radians.
        outer_angle: f32,
        /// Cut-off distance (infinite if absent).
        range: f32,
    },
    /// A light from infinitely far away in one direction (the sun).
    Directional {
        /// Direction the light travels in.
        direction: Vec3,
        /// Irradiance on a surface facing the light, W/m² per channel (glTF lux).
        irradiance: Vec3,
    },
}

/// Light from infinitely far away.
#[derive(Clone, Debug)]
pub enum EnvironmentDesc {
    /// The same radiance from every direction.
    Constant {
        /// Radiance.
        radiance: Vec3,
    },
    /// An equirectangular (latitude–longitude) HDR map, importance-sampled.
    Map {
        /// The image (linear RGB).
        texture: TextureDesc,
        /// Multiplies the map.
        scale: f32,
        /// World-to-map rotation about +Y, radians.
        rotation_y: f32,
    },
}

/// A camera: a camera-to-world transform (looking down −Z, +Y up, as glTF) and a projection.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraDesc {
    /// Name used by `--camera NAME`.
    pub name: String,
    /// Camera-to-world transform (rigid; scale is ignored).
    pub transform: Mat4,
    /// Projection and lens.
    pub projection: Projection,
    /// Aspect ratio the file asks for (the render's width/height wins).
    pub aspect: Option<f32>,
}

/// Render settings stored in the scene file (the JSON format's `render` object). `None` means
/// "use raytile's default". Typed, so that a wrong name is refused when the scene is loaded, with
/// the JSON path named.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderDefaults {
    /// Image width in pixels.
    pub width: Option<u32>,
    /// Image height in pixels.
    pub height: Option<u32>,
    /// Samples per pixel.
    pub spp: Option<u32>,
    /// Maximum path length in bounces.
    pub max_depth: Option<u32>,
    /// Integrator.
    pub integrator: Option<IntegratorKind>,
    /// Random seed.
    pub seed: Option<u32>,
    /// Camera name or index: a string, or an integer index (`"camera": 1` is `"camera": "1"`),
    /// as a job's `camera` and `--camera` take either.
    #[serde(
        default,
        deserialize_with = "raytile_proto::settings::camera_name_or_index"
    )]
    pub camera: Option<String>,
    /// Reconstruction filter.
    pub filter: Option<FilterKind>,
    /// An alpha channel (the environment seen straight from the camera transparent).
    pub alpha: Option<bool>,
}

impl RenderDefaults {
    /// The scene's settings as overrides of raytile's defaults.
    pub fn to_overrides(&self) -> RenderOverrides {
        // Destructured, so that a new field cannot be forgotten here.
        let Self {
            width,
            height,
            spp,
            max_depth,
            integrator,
            seed,
            camera,
            filter,
            alpha,
        } = self;
        RenderOverrides {
            width: *width,
            height: *height,
            spp: *spp,
            max_depth: *max_depth,
            integrator: *integrator,
            seed: *seed,
            camera: camera.clone(),
            filter: *filter,
            alpha: *alpha,
            ..RenderOverrides::default()
        }
    }

    /// The settings of a render: raytile's defaults, overridden by these (the scene's own),
    /// overridden by `overrides` (command-line flags, job fields), validated. `raytile render`,
    /// `raytile submit` (through the coordinator) and the coordinator all come here, so a job
    /// renders with the same settings wherever it runs.
    ///
    /// The error names the field as the API does (`max_depth`); the command line prints it as a
    /// flag (`--max-depth`).
    pub fn resolve(&self, overrides: &RenderOverrides) -> Result<RenderSettings, SettingsError> {
        // The user's values on their own first, so that the error is about what they typed.
        overrides.check()?;
        let mut s = RenderSettings::default();
        self.to_overrides().apply_to(&mut s);
        overrides.apply_to(&mut s);
        s.validate()?;
        Ok(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_transform_is_t_r_s() {
        use glam::{Mat3, Vec3};
        let m = TextureRef::uv_transform([0.5, 0.25], std::f32::consts::FRAC_PI_2, [2.0, 3.0]);
        // (1, 0) scaled to (2, 0), turned a quarter counter-clockwise in a v-down space (up
        // the image, toward −v) to (0, −2), then offset.
        let p = m * Vec3::new(1.0, 0.0, 1.0);
        assert!((p - Vec3::new(0.5, -1.75, 1.0)).length() < 1e-5, "{p}");
        // (0, 1), down the image, is turned toward +u.
        let p = m * Vec3::new(0.0, 1.0 / 3.0, 1.0);
        assert!((p - Vec3::new(1.5, 0.25, 1.0)).length() < 1e-5, "{p}");
        assert_eq!(
            TextureRef::uv_transform([0.0; 2], 0.0, [1.0; 2]),
            Mat3::IDENTITY
        );
    }

    #[test]
    fn flags_override_the_scene_which_overrides_the_defaults() {
        let scene = RenderDefaults {
            width: Some(64),
            spp: Some(4),
            integrator: Some(IntegratorKind::Whitted),
            camera: Some("side".into()),
            ..Default::default()
        };
        let s = scene
            .resolve(&RenderOverrides {
                spp: Some(16),
                passes: Some(2),
                default_light: Some(false),
                ..Default::default()
            })
            .unwrap();
        assert_eq!(
            s,
            RenderSettings {
                width: 64,
                spp: 16,
                passes: 2,
                integrator: IntegratorKind::Whitted,
                camera: Some("side".into()),
                default_light: false,
                ..RenderSettings::default()
            }
        );
        assert_eq!(
            RenderDefaults::default().resolve(&RenderOverrides::default()),
            Ok(RenderSettings::default())
        );
    }

    #[test]
    fn resolve_errors_name_the_field() {
        let scene = RenderDefaults {
            spp: Some(4),
            ..Default::default()
        };
        let err = |o: RenderOverrides| scene.resolve(&o).unwrap_err().field;
        // More passes than the scene's samples: only the merged settings can tell.
        let passes = RenderOverrides {
            passes: Some(8),
            ..Default::default()
        };
        assert_eq!(err(passes), "passes");
        let depth = RenderOverrides {
            max_depth: Some(MAX_DEPTH_PLUS_ONE),
            ..Default::default()
        };
        assert_eq!(err(depth), "max_depth");
    }

    const MAX_DEPTH_PLUS_ONE: u32 = crate::settings::MAX_DEPTH + 1;
}
