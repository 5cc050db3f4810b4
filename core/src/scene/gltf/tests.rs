//! Unit tests with small glTF documents built in memory (data URIs only).

use super::*;
use crate::scene::desc::{AlphaMode, BsdfDesc, PbrDesc};
use crate::scene::files::SceneFiles;
use base64::Engine as _;
use serde_json::json;

/// Builds a glTF document: binary data appended to one data-URI buffer, with views and
/// accessors.
#[derive(Default)]
struct Doc {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Doc {
    /// Appends `bytes` as a new buffer view; returns its index.
    fn view(&mut self, bytes: &[u8]) -> usize {
        while self.bin.len() & 3 != 0 {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.views
            .push(json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()}));
        self.views.len() - 1
    }
    /// Adds an accessor over a new view; returns its index.
    fn accessor(&mut self, bytes: &[u8], component_type: u32, ty: &str, count: usize) -> usize {
        let v = self.view(bytes);
        self.accessors.push(
            json!({"bufferView": v, "componentType": component_type, "type": ty, "count": count}),
        );
        self.accessors.len() - 1
    }
    fn floats(&mut self, v: &[f32], ty: &str, per: usize) -> usize {
        let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.accessor(&bytes, 5126, ty, v.len() / per)
    }
    fn positions(&mut self, v: &[[f32; 3]]) -> usize {
        self.floats(&v.concat(), "VEC3", 3)
    }
    fn indices_u16(&mut self, v: &[u16]) -> usize {
        let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.accessor(&bytes, 5123, "SCALAR", v.len())
    }
    /// The final JSON, with `root`'s members added.
    fn finish(self, root: Value) -> Vec<u8> {
        let mut out = json!({
            "asset": {"version": "2.0"},
            "buffers": [{
                "byteLength": self.bin.len(),
                "uri": format!("data:application/octet-stream;base64,{}",
                    base64::engine::general_purpose::STANDARD.encode(&self.bin)),
            }],
            "bufferViews": self.views,
            "accessors": self.accessors,
        });
        if let (Some(o), Value::Object(r)) = (out.as_object_mut(), root) {
            o.extend(r);
        }
        serde_json::to_vec(&out).unwrap()
    }
}

const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
const QUAD: [[f32; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [1.0, 1.0, 0.0],
];

fn load(bytes: &[u8]) -> Result<SceneDesc, String> {
    load_gltf_slice(bytes, None, "test.gltf", &GltfOptions::default()).map_err(|e| e.to_string())
}

/// A one-triangle scene whose primitive is `prim` (POSITION is accessor 0) plus `extra`.
fn one_prim(doc: Doc, prim: Value, extra: Value) -> Vec<u8> {
    let mut root = json!({
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [prim]}],
    });
    if let (Some(o), Value::Object(e)) = (root.as_object_mut(), extra) {
        o.extend(e);
    }
    doc.finish(root)
}

fn tri_scene(extra_prim: Value, extra: Value) -> Vec<u8> {
    let mut d = Doc::default();
    d.positions(&TRI);
    let mut prim = json!({"attributes": {"POSITION": 0}});
    if let (Some(o), Value::Object(e)) = (prim.as_object_mut(), extra_prim) {
        o.extend(e);
    }
    one_prim(d, prim, extra)
}

fn pbr(m: &crate::scene::desc::MaterialDesc) -> &PbrDesc {
    match &m.bsdf {
        BsdfDesc::Pbr(p) => p,
        other => panic!("not PBR: {other:?}"),
    }
}

fn expect_err(bytes: &[u8], needles: &[&str]) {
    let e = load(bytes).expect_err("loaded a bad file");
    for n in needles {
        assert!(e.contains(n), "error {e:?} does not mention {n:?}");
    }
}

#[test]
fn minimal_triangle_gets_defaults() {
    let s = load(&tri_scene(json!({}), json!({}))).unwrap();
    assert_eq!(s.meshes.len(), 1);
    assert_eq!(s.meshes[0].indices, vec![[0, 1, 2]]);
    assert!(
        s.meshes[0].normals.is_empty(),
        "flat shading when NORMAL is absent"
    );
    // Default material: base colour 1, metallic 1, roughness 1.
    let p = pbr(&s.materials[0]);
    assert_eq!(
        (p.base_color, p.metallic, p.roughness),
        ([1.0; 4], 1.0, 1.0)
    );
    // No light: constant environment with a warning; no camera: a default one.
    assert!(
        matches!(s.environment, Some(EnvironmentDesc::Constant { radiance }) if radiance == Vec3::ONE)
    );
    assert!(s.warnings.iter().any(|w| w.contains("no light")));
    assert_eq!(s.cameras.len(), 1);
    assert_eq!(s.cameras[0].name, "default");
    let eye = s.cameras[0].transform.transform_point3(Vec3::ZERO);
    assert!((eye.x - 0.5).abs() < 1e-5 && (eye.y - 0.5).abs() < 1e-5 && eye.z > 1.0);

    let off = GltfOptions {
        default_light: false,
        ..GltfOptions::default()
    };
    let s = load_gltf_slice(&tri_scene(json!({}), json!({})), None, "t", &off).unwrap();
    assert!(s.environment.is_none());
}

#[test]
fn transforms_compose_through_the_hierarchy() {
    let mut d = Doc::default();
    d.positions(&TRI);
    let q = std::f32::consts::FRAC_1_SQRT_2;
    let bytes = d.finish(json!({
        "scenes": [{"nodes": [0]}],
        "nodes": [
            {"translation": [1, 0, 0], "scale": [2, 1, 1], "children": [1]},
            {"rotation": [0, 0, q, q], "scale": [1, 1, -1], "children": [2], "mesh": 0},
            {"matrix": [1,0,0,0, 0,3,0,0, 0,0,1,0, 0,0,5,1], "mesh": 0},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
    }));
    let s = load(&bytes).unwrap();
    assert_eq!(s.meshes.len(), 1);
    assert_eq!(s.objects.len(), 2);
    let child = s.objects[0].transform;
    // (1,0,0): rotated a quarter turn about Z to (0,1,0), parent scale keeps it, then +x 1.
    let p = child.transform_point3(Vec3::X);
    assert!((p - Vec3::new(1.0, 1.0, 0.0)).length() < 1e-5, "{p}");
    // (0,1,0) → (-1,0,0) → scaled by 2 in x → (-2,0,0) → (-1,0,0).
    let p = child.transform_point3(Vec3::Y);
    assert!((p - Vec3::new(-1.0, 0.0, 0.0)).length() < 1e-5, "{p}");
    assert!(child.determinant() < 0.0, "mirror kept in the transform");
    let grandchild = s.objects[1].transform;
    // (0,1,0) → matrix: (0,3,5) → child transform.
    let expect = child.transform_point3(Vec3::new(0.0, 3.0, 5.0));
    assert!((grandchild.transform_point3(Vec3::Y) - expect).length() < 1e-5);
    // Indices stay as stored even for the mirrored object.
    assert_eq!(s.meshes[0].indices, vec![[0, 1, 2]]);
}

/// A node with both a matrix and TRS properties (invalid glTF) uses the matrix, with a warning.
#[test]
fn a_node_with_a_matrix_and_trs_uses_the_matrix_and_warns() {
    let mut d = Doc::default();
    d.positions(&TRI);
    let bytes = d.finish(json!({
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,5,1], "translation": [7, 0, 0], "mesh": 0},
            {"matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,5,1], "mesh": 0},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
    }));
    let s = load(&bytes).unwrap();
    let p = s.objects[0].transform.transform_point3(Vec3::ZERO);
    assert_eq!(p, Vec3::new(0.0, 0.0, 5.0));
    let warned: Vec<_> = s
        .warnings
        .iter()
        .filter(|w| w.contains("both a matrix"))
        .collect();
    assert!(
        warned.len() == 1 && warned[0].contains("node 0 "),
        "{:?}",
        s.warnings
    );
}

/// A node matrix that is projective (its last row not [0, 0, 0, 1]) is refused when the file is
/// loaded, naming the node by index and name, and the file.
#[test]
fn a_projective_node_matrix_is_refused_naming_the_node() {
    for (name, node) in [
        (json!("tilted"), "node 1 ('tilted')"),
        (Value::Null, "node 1"),
    ] {
        let mut d = Doc::default();
        d.positions(&TRI);
        let mut tilted = json!({"mesh": 0, "matrix": [1,0,0,0.5, 0,1,0,0, 0,0,1,0, 0,0,0,1]});
        if !name.is_null() {
            tilted["name"] = name;
        }
        let bytes = d.finish(json!({
            "scenes": [{"nodes": [0]}],
            "nodes": [{"name": "root", "children": [1]}, tilted],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        }));
        assert_eq!(
            load(&bytes).unwrap_err(),
            format!(
                "test.gltf: {node}: the transform's last row must be [0, 0, 0, 1] (no \
                 projection), got [0.5, 0, 0, 1]"
            )
        );
    }
}

/// A scene of one triangle under `parent_scale` twice (a model in centimetres under a
/// centimetre-to-metre node, nested) and a camera under a node of `camera_scale`.
fn scaled_scene(parent_scale: f32, camera_scale: f32) -> Vec<u8> {
    let mut d = Doc::default();
    d.positions(&TRI);
    d.finish(json!({
        "scenes": [{"nodes": [0, 3]}],
        "nodes": [
            {"name": "outer", "scale": [parent_scale, parent_scale, parent_scale], "children": [1]},
            {"scale": [parent_scale, parent_scale, parent_scale], "children": [2]},
            {"name": "model", "mesh": 0},
            {"scale": [camera_scale, camera_scale, camera_scale], "children": [4]},
            {"translation": [0, 0, 5], "camera": 0},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.1}}],
    }))
}

#[test]
fn small_and_large_scales_load_and_build_whatever_their_determinant() {
    // Scales of 10⁻² twice (a determinant of 10⁻¹²) and 10⁻⁵ under the camera used to be
    // refused as "a zero scale". A camera's scale is divided out: 10⁻¹⁵ will do.
    for (parent, camera) in [(1e-2, 1e-5), (1e-4, 1e-15), (1e3, 1e9)] {
        let desc = load(&scaled_scene(parent, camera)).unwrap();
        assert_eq!(desc.objects.len(), 1, "scale {parent}");
        assert!(
            desc.warnings.iter().all(|w| w == NO_LIGHT_WARNING),
            "{:?}",
            desc.warnings
        );
        let scene = crate::Scene::build(&desc).unwrap_or_else(|e| panic!("scale {parent}: {e}"));
        assert_eq!(scene.cameras().len(), 1);
    }
    // A mesh too small to invert in f32 cannot show: left out with a warning, as at a zero
    // scale; one too large is refused, naming the node.
    let desc = load(&scaled_scene(1e-8, 1.0)).unwrap();
    assert!(desc.objects.is_empty());
    assert!(
        desc.warnings
            .iter()
            .any(|w| w.contains("node 2") && w.contains("too small")),
        "{:?}",
        desc.warnings
    );
    assert_eq!(
        load(&scaled_scene(1e8, 1.0)).unwrap_err(),
        "test.gltf: node 2 ('model'): transform's scale is too large (raytile takes scales \
         from about 1e-12 to 1e12)"
    );
}

#[test]
fn instanced_mesh_is_loaded_once() {
    let mut d = Doc::default();
    d.positions(&TRI);
    let bytes = d.finish(json!({
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0, "name": "a"}, {"mesh": 0, "translation": [3, 0, 0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
    }));
    let s = load(&bytes).unwrap();
    assert_eq!(s.meshes.len(), 1);
    assert_eq!(s.objects.len(), 2);
    assert_eq!(s.objects[0].name, "a");
    assert_eq!(s.objects[1].name, "node 1");
    assert!(matches!(s.objects[1].shape, ShapeDesc::Mesh { mesh: 0 }));
}

/// A one-triangle scene with texture coordinates and material 0, plus `extra`.
fn textured_tri(extra: Value) -> Vec<u8> {
    let mut d = Doc::default();
    d.positions(&TRI);
    d.floats(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0], "VEC2", 2);
    one_prim(
        d,
        json!({"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "material": 0}),
        extra,
    )
}

fn png_data_uri() -> String {
    let img = image::RgbaImage::from_fn(2, 2, |x, y| {
        image::Rgba([x as u8 * 255, y as u8 * 255, 128, 255])
    });
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(png)
    )
}

#[test]
fn a_texture_without_its_coordinates_is_read_at_the_origin() {
    let s = load(&tri_scene(
        json!({"material": 0}),
        json!({
            "images": [{"uri": png_data_uri()}],
            "textures": [{"source": 0}],
            "materials": [{"name": "painted",
                "pbrMetallicRoughness": {"baseColorTexture": {"index": 0, "texCoord": 1}}}],
        }),
    ))
    .unwrap();
    assert_eq!(s.meshes[0].uvs[1], vec![glam::Vec2::ZERO; 3]);
    assert!(s.meshes[0].uvs[0].is_empty());
    assert!(
        s.warnings.iter().any(|w| w.contains("mesh 0 primitive 0")
            && w.contains("'painted'")
            && w.contains("TEXCOORD_1")
            && w.contains("base colour")),
        "{:?}",
        s.warnings
    );
}

/// A 2×2 16-bit RGBA PNG as a data URI: an image kept as f32 texels.
fn png16_data_uri() -> String {
    let img = image::ImageBuffer::<image::Rgba<u16>, _>::from_fn(2, 2, |x, y| {
        image::Rgba([x as u16 * 65535, y as u16 * 30000, 1000, 65535])
    });
    let mut png = Vec::new();
    image::DynamicImage::from(img)
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(png)
    )
}

#[test]
fn textures_of_one_image_share_its_texels() {
    for (uri, eight_bit) in [(png_data_uri(), true), (png16_data_uri(), false)] {
        // One image, two samplers, colour and data: three textures.
        let bytes = textured_tri(json!({
            "images": [{"uri": uri}],
            "samplers": [{"wrapS": 33071}, {"wrapS": 33648}],
            "textures": [{"source": 0, "sampler": 0}, {"source": 0, "sampler": 1}],
            "materials": [{
                "pbrMetallicRoughness": {
                    "baseColorTexture": {"index": 0},
                    "metallicRoughnessTexture": {"index": 1},
                },
                "emissiveTexture": {"index": 1},
                "emissiveFactor": [1, 1, 1],
            }],
        }));
        let desc = load(&bytes).unwrap();
        assert_eq!(desc.textures.len(), 3);
        let first = &desc.textures[0].texels;
        assert!(desc.textures.iter().all(|t| t.texels.shares(first)));
        let p = pbr(&desc.materials[0]);
        let index = [
            p.base_color_texture.unwrap().texture,
            desc.materials[0].emission_texture.unwrap().texture,
            p.metallic_roughness_texture.unwrap().texture,
        ];
        let scene = crate::Scene::build(&desc).unwrap();
        let [base, emissive, data] = index.map(|i| scene.textures[i].texels_id());
        // 8-bit texels are shared as they are; f32 ones converted once per colour space.
        assert_eq!(base, emissive);
        assert_eq!(base == data, eight_bit, "8-bit: {eight_bit}");
        // The lookups are those of separate copies.
        let alone = |i: usize| {
            let mut one = desc.clone();
            one.textures = vec![desc.textures[i].clone()];
            one.textures[0].texels = match &desc.textures[i].texels {
                crate::texture::Texels::F32(t) => t.to_vec().into(),
                crate::texture::Texels::Unorm8(t) => t.to_vec().into(),
            };
            one.materials.clear();
            one.objects.clear();
            crate::Scene::build(&one).unwrap().textures[0].clone()
        };
        for &i in &index {
            for uv in [glam::Vec2::new(0.3, 0.6), glam::Vec2::new(-0.4, 1.7)] {
                assert_eq!(
                    scene.textures[i].lookup(uv).to_array(),
                    alone(i).lookup(uv).to_array(),
                    "texture {i} at {uv}"
                );
            }
        }
    }
}

#[test]
fn images_of_the_same_bytes_are_decoded_once() {
    // Two `images` of one PNG (an exporter's habit, or a hostile file repeating a large one).
    let bytes = textured_tri(json!({
        "images": [{"uri": png_data_uri()}, {"uri": png_data_uri()}],
        "textures": [{"source": 0}, {"source": 1}],
        "materials": [{
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}},
            "emissiveTexture": {"index": 1},
        }],
    }));
    let s = load(&bytes).unwrap();
    assert_eq!(s.textures.len(), 2);
    assert!(s.textures[0].texels.shares(&s.textures[1].texels));
}

#[test]
fn colour_textures_are_srgb_and_data_textures_linear() {
    let bytes = textured_tri(json!({
        "images": [{"uri": png_data_uri()}],
        "samplers": [{"magFilter": 9728, "wrapS": 33071, "wrapT": 33648}],
        // Textures 1 and 2 name the same image and sampling as texture 0 (an exporter's
        // habit): they share its decoded copy.
        "textures": [{"source": 0, "sampler": 0}, {"source": 0, "sampler": 0}, {"source": 0, "sampler": 0}],
        "materials": [{
            "pbrMetallicRoughness": {
                "baseColorTexture": {"index": 0},
                "metallicRoughnessTexture": {"index": 1},
            },
            "normalTexture": {"index": 0, "scale": 0.5},
            "emissiveTexture": {"index": 2},
        }],
    }));
    let s = load(&bytes).unwrap();
    let m = &s.materials[0];
    let p = pbr(m);
    let base = &s.textures[p.base_color_texture.unwrap().texture];
    let mr = &s.textures[p.metallic_roughness_texture.unwrap().texture];
    assert!(base.srgb);
    assert!(!mr.srgb);
    assert!(s.textures[m.emission_texture.unwrap().texture].srgb);
    let (n, scale) = m.normal_texture.unwrap();
    assert!(!s.textures[n.texture].srgb);
    assert_eq!(scale, 0.5);
    assert_eq!(
        s.textures.len(),
        2,
        "one decoded copy per colour space, whichever texture names the image"
    );
    assert_eq!((base.width, base.height), (2, 2));
    assert_eq!(base.texels.get(1), [1.0, 0.0, 128.0 / 255.0, 1.0]);
    assert_eq!(
        (base.wrap_u, base.wrap_v),
        (WrapMode::Clamp, WrapMode::MirroredRepeat)
    );
    assert!(!base.bilinear);
    // Normal map without TANGENT: tangents generated.
    assert_eq!(s.meshes[0].tangents.len(), 3);
    let t = s.meshes[0].tangents[0];
    assert!(
        (Vec3::new(t[0], t[1], t[2]) - Vec3::X).length() < 1e-4,
        "{t:?}"
    );
    // v grows along +Y here, so up the image (where a normal map's green points) is −Y:
    // the bitangent cross(N, T) · w = +Z × +X · w = +Y · w must be −Y.
    assert_eq!(t[3], -1.0, "{t:?}");
}

#[test]
fn tangents_of_a_mesh_of_degenerate_triangles_are_not_generated_and_do_not_crash() {
    // MikkTSpace (the `mikktspace` crate) reads out of bounds when every triangle it is
    // given has two corners at one position: a panic for one such triangle, a crash for two.
    for (positions, indices) in [
        (&TRI[..], &[0u16, 0, 0][..]),
        (
            &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]][..],
            &[0u16, 1, 2, 2, 1, 0][..],
        ),
    ] {
        let mut d = Doc::default();
        d.positions(positions);
        d.floats(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0], "VEC2", 2);
        d.indices_u16(indices);
        let bytes = one_prim(
            d,
            json!({"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}),
            json!({
                "images": [{"uri": png_data_uri()}],
                "textures": [{"source": 0}],
                "materials": [{"normalTexture": {"index": 0}}],
            }),
        );
        // Loaded (its triangles dropped as degenerate), not crashed.
        let _ = load(&bytes);
    }
}

use crate::scene::desc::WrapMode;

#[test]
fn alpha_modes_and_double_sided() {
    let mut d = Doc::default();
    d.positions(&TRI);
    let bytes = d.finish(json!({
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [
            {"attributes": {"POSITION": 0}, "material": 0},
            {"attributes": {"POSITION": 0}, "material": 1},
            {"attributes": {"POSITION": 0}, "material": 2},
            {"attributes": {"POSITION": 0}, "material": 3},
        ]}],
        "materials": [
            {"name": "o"},
            {"alphaMode": "MASK", "alphaCutoff": 0.3, "doubleSided": true},
            {"alphaMode": "BLEND"},
            {"alphaMode": "MASK"},
        ],
    }));
    let s = load(&bytes).unwrap();
    let modes: Vec<AlphaMode> = s
        .objects
        .iter()
        .map(|o| s.materials[o.material].alpha_mode)
        .collect();
    assert_eq!(
        modes,
        vec![
            AlphaMode::Opaque,
            AlphaMode::Mask(0.3),
            AlphaMode::Blend,
            AlphaMode::Mask(0.5)
        ]
    );
    assert!(!s.materials[s.objects[0].material].two_sided);
    assert!(s.materials[s.objects[1].material].two_sided);
    assert_eq!(s.meshes.len(), 4);
    assert_eq!(s.objects[1].name, "node 0 primitive 1");
}

#[test]
fn thin_walled_and_solid_transmission() {
    let bytes = |materials: Value| {
        tri_scene(
            json!({"material": 0}),
            json!({
                "extensionsUsed": ["KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_ior",
                    "KHR_materials_specular", "KHR_materials_clearcoat", "KHR_materials_emissive_strength"],
                "materials": [materials],
            }),
        )
    };
    let s = load(&bytes(json!({"extensions": {
        "KHR_materials_transmission": {"transmissionFactor": 1.0},
        "KHR_materials_volume": {"thicknessFactor": 0.5, "attenuationColor": [1.0, 0.5, 0.25], "attenuationDistance": 2.0},
        "KHR_materials_ior": {"ior": 1.33},
        "KHR_materials_specular": {"specularFactor": 0.5, "specularColorFactor": [1.0, 0.0, 0.0]},
        "KHR_materials_clearcoat": {"clearcoatFactor": 0.75, "clearcoatRoughnessFactor": 0.25},
    }})))
    .unwrap();
    let p = pbr(&s.materials[0]);
    assert_eq!(p.transmission, 1.0);
    assert!(!p.thin_walled);
    assert_eq!(p.attenuation_color, Vec3::new(1.0, 0.5, 0.25));
    assert_eq!(p.attenuation_distance, 2.0);
    assert_eq!(p.ior, 1.33);
    assert_eq!((p.specular, p.specular_color), (0.5, Vec3::X));
    assert_eq!((p.clearcoat, p.clearcoat_roughness), (0.75, 0.25));

    let s = load(&bytes(json!({"extensions": {
        "KHR_materials_transmission": {"transmissionFactor": 0.9},
        "KHR_materials_volume": {"thicknessFactor": 0.0},
    }})))
    .unwrap();
    assert!(pbr(&s.materials[0]).thin_walled);
    let s = load(&bytes(
        json!({"extensions": {"KHR_materials_transmission": {"transmissionFactor": 0.9}}}),
    ))
    .unwrap();
    let p = pbr(&s.materials[0]);
    assert!(p.thin_walled);
    assert_eq!(p.attenuation_distance, f32::INFINITY);

    // Emission = factor × strength; an emitter means no default light.
    let s = load(&bytes(json!({"emissiveFactor": [1.0, 0.5, 0.0],
        "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}}})))
    .unwrap();
    assert_eq!(s.materials[0].emission, Vec3::new(4.0, 2.0, 0.0));
    assert!(s.environment.is_none());
}

/// Factors the specification bounds to [0, 1] are clamped into it with a warning (exporters
/// stray by a rounding error now and then), and the scene builds.
#[test]
fn unit_factors_out_of_range_are_clamped_with_a_warning() {
    let s = load(&tri_scene(
        json!({"material": 0}),
        json!({"extensionsUsed": ["KHR_materials_transmission", "KHR_materials_clearcoat",
                "KHR_materials_specular"],
            "materials": [{
                "pbrMetallicRoughness": {"metallicFactor": 1.0000001, "roughnessFactor": -0.2,
                    "baseColorFactor": [1.5, 0.5, -0.25, 1]},
                "extensions": {"KHR_materials_transmission": {"transmissionFactor": 3.0},
                    "KHR_materials_clearcoat": {"clearcoatFactor": 5,
                        "clearcoatRoughnessFactor": -1},
                    "KHR_materials_specular": {"specularFactor": 7}}}]}),
    ))
    .unwrap();
    let p = pbr(&s.materials[0]);
    assert_eq!((p.metallic, p.roughness, p.transmission), (1.0, 0.0, 1.0));
    assert_eq!(p.base_color, [1.0, 0.5, 0.0, 1.0]);
    assert_eq!(
        (p.clearcoat, p.clearcoat_roughness, p.specular),
        (1.0, 0.0, 1.0)
    );
    for f in [
        "metallicFactor",
        "roughnessFactor",
        "transmissionFactor",
        "baseColorFactor",
        "clearcoatFactor",
        "clearcoatRoughnessFactor",
        "specularFactor",
    ] {
        assert!(
            s.warnings
                .iter()
                .any(|w| w.contains(f) && w.contains("outside [0, 1]")),
            "{f}: {:?}",
            s.warnings
        );
    }
    crate::Scene::build(&s).unwrap();
}

/// `KHR_materials_ior`: at least 1, or 0, which the specification defines as an infinite
/// index (Fresnel reflectance 1); anything else is refused.
#[test]
fn ior_follows_the_specification() {
    let ior = |v: f32| {
        tri_scene(
            json!({"material": 0}),
            json!({"extensionsUsed": ["KHR_materials_ior"],
                "materials": [{"extensions": {"KHR_materials_ior": {"ior": v}}}]}),
        )
    };
    assert_eq!(pbr(&load(&ior(1.0)).unwrap().materials[0]).ior, 1.0);
    assert_eq!(pbr(&load(&ior(2.4)).unwrap().materials[0]).ior, 2.4);
    let s = load(&ior(0.0)).unwrap();
    let n = pbr(&s.materials[0]).ior;
    assert!(((n - 1.0) / (n + 1.0)).powi(2) > 0.9999, "ior 0 became {n}");
    crate::Scene::build(&s).unwrap();
    expect_err(
        &ior(-1.5),
        &["material 0", "KHR_materials_ior.ior", "at least 1"],
    );
    expect_err(
        &ior(0.5),
        &["material 0", "KHR_materials_ior.ior", "at least 1"],
    );
}

/// Negative emission is no light: refused (not taken for an unlit model), and so is emission
/// above the largest radiance, and a light whose colour × intensity is.
#[test]
fn emission_and_lights_must_be_non_negative_and_not_too_bright() {
    let material = |m: Value| {
        tri_scene(
            json!({"material": 0}),
            json!({"extensionsUsed": ["KHR_materials_emissive_strength"], "materials": [m]}),
        )
    };
    let strength = |s: f32| json!({"KHR_materials_emissive_strength": {"emissiveStrength": s}});
    expect_err(
        &material(json!({"emissiveFactor": [1.0, 1.0, 1.0], "extensions": strength(-2.0)})),
        &["material 0", "emissiveStrength", "non-negative"],
    );
    expect_err(
        &material(json!({"emissiveFactor": [-1.0, 0.0, 0.0]})),
        &["material 0", "emissiveFactor", "non-negative"],
    );
    expect_err(
        &material(json!({"emissiveFactor": [1.0, 1.0, 1.0], "extensions": strength(1e31)})),
        &["material 0", "emissiveStrength", "at most 1e30"],
    );
    let s = load(&material(
        json!({"emissiveFactor": [1.0, 1.0, 1.0], "extensions": strength(1e30)}),
    ))
    .unwrap();
    assert_eq!(s.materials[0].emission, Vec3::splat(1e30));
    let light = |intensity: f32| {
        tri_scene(
            json!({}),
            json!({
                "extensions": {"KHR_lights_punctual": {"lights": [
                    {"type": "point", "intensity": intensity}]}},
                "nodes": [{"mesh": 0, "extensions": {"KHR_lights_punctual": {"light": 0}}}],
            }),
        )
    };
    expect_err(&light(-1.0), &["light 0", "non-negative"]);
    expect_err(&light(1e31), &["light 0", "at most 1e30"]);
}

#[test]
fn strips_fans_and_index_widths() {
    let strip_fan = |mode: u32| {
        let mut d = Doc::default();
        d.positions(&QUAD);
        d.indices_u16(&[0, 1, 2, 3]);
        one_prim(
            d,
            json!({"attributes": {"POSITION": 0}, "indices": 1, "mode": mode}),
            json!({}),
        )
    };
    let s = load(&strip_fan(5)).unwrap();
    assert_eq!(s.meshes[0].indices, vec![[0, 1, 2], [1, 3, 2]]);
    let s = load(&strip_fan(6)).unwrap();
    assert_eq!(s.meshes[0].indices, vec![[1, 2, 0], [2, 3, 0]]);
    // Non-indexed strip.
    let mut d = Doc::default();
    d.positions(&QUAD);
    let s = load(&one_prim(
        d,
        json!({"attributes": {"POSITION": 0}, "mode": 5}),
        json!({}),
    ))
    .unwrap();
    assert_eq!(s.meshes[0].indices, vec![[0, 1, 2], [1, 3, 2]]);

    for (ctype, width) in [(5121u32, 1usize), (5123, 2), (5125, 4)] {
        let mut d = Doc::default();
        d.positions(&QUAD);
        let bytes: Vec<u8> = [0u32, 1, 2, 2, 1, 3]
            .iter()
            .flat_map(|&i| i.to_le_bytes()[..width].to_vec())
            .collect();
        d.accessor(&bytes, ctype, "SCALAR", 6);
        let s = load(&one_prim(
            d,
            json!({"attributes": {"POSITION": 0}, "indices": 1}),
            json!({}),
        ))
        .unwrap();
        assert_eq!(
            s.meshes[0].indices,
            vec![[0, 1, 2], [2, 1, 3]],
            "component type {ctype}"
        );
    }
}

#[test]
fn sparse_normalized_and_interleaved_accessors() {
    let mut d = Doc::default();
    d.positions(&TRI);
    let idx = d.view(&[2u8, 0, 0, 0]);
    let vals = d.view(
        &[5.0f32, 6.0, 7.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect::<Vec<_>>(),
    );
    d.accessors[0]["sparse"] = json!({
        "count": 1,
        "indices": {"bufferView": idx, "componentType": 5121},
        "values": {"bufferView": vals},
    });
    // Interleaved: TEXCOORD_0 as normalized u16 pairs with a stride of 8 bytes.
    let uv_bytes: Vec<u8> = [[65535u16, 0, 9, 9], [0, 65535, 9, 9], [32768, 32768, 9, 9]]
        .iter()
        .flat_map(|e| e.iter().flat_map(|x| x.to_le_bytes()))
        .collect();
    let v = d.view(&uv_bytes);
    d.views[v]["byteStride"] = json!(8);
    d.accessors.push(json!({"bufferView": v, "componentType": 5123, "normalized": true, "type": "VEC2", "count": 3}));
    let bytes = one_prim(
        d,
        json!({"attributes": {"POSITION": 0, "TEXCOORD_0": 1}}),
        json!({}),
    );
    let s = load(&bytes).unwrap();
    let m = &s.meshes[0];
    assert_eq!(m.positions[2], Vec3::new(5.0, 6.0, 7.0));
    assert_eq!(m.positions[1], Vec3::X);
    assert_eq!(m.uvs[0][0], glam::Vec2::new(1.0, 0.0));
    assert!((m.uvs[0][2].x - 0.5).abs() < 1e-4);

    // Sparse index out of range.
    let mut d = Doc::default();
    d.positions(&TRI);
    let idx = d.view(&[7u8, 0, 0, 0]);
    let vals = d.view(&[0u8; 12]);
    d.accessors[0]["sparse"] = json!({
        "count": 1,
        "indices": {"bufferView": idx, "componentType": 5121},
        "values": {"bufferView": vals},
    });
    expect_err(
        &one_prim(d, json!({"attributes": {"POSITION": 0}}), json!({})),
        &["sparse index 7"],
    );

    // Sparse indices that repeat or go back.
    for order in [[1u8, 1], [2, 1]] {
        let mut d = Doc::default();
        d.positions(&TRI);
        let idx = d.view(&[order[0], order[1], 0, 0]);
        let vals = d.view(&[0u8; 24]);
        d.accessors[0]["sparse"] = json!({
            "count": 2,
            "indices": {"bufferView": idx, "componentType": 5121},
            "values": {"bufferView": vals},
        });
        expect_err(
            &one_prim(d, json!({"attributes": {"POSITION": 0}}), json!({})),
            &[
                "sparse indices must strictly increase",
                &format!("got {} after {}", order[1], order[0]),
            ],
        );
    }
}

/// `KHR_mesh_quantization` as gltfpack writes it: integer positions placed by the node's
/// scale, normalised byte normals, integer texture coordinates.
#[test]
fn quantized_attributes_read_by_the_accessor_rules() {
    let quantized = |declared: bool| {
        let mut d = Doc::default();
        // i16 positions (each element padded to 8 bytes, as the specification aligns them).
        let pos: Vec<u8> = [[0i16, 0, 0, 0], [1000, 0, 0, 0], [0, -1000, 0, 0]]
            .iter()
            .flat_map(|e| e.iter().flat_map(|x| x.to_le_bytes()))
            .collect();
        let p = d.accessor(&pos, 5122, "VEC3", 3);
        d.views[p]["byteStride"] = json!(8);
        // Normalised i8 normals: 127 is 1, -128 is clamped to -1.
        let n = d.accessor(
            &[0, 0, 127, 0, 0, 0, 127, 0, 0, 0, 0x80, 0],
            5120,
            "VEC3",
            3,
        );
        d.views[n]["byteStride"] = json!(4);
        d.accessors[n]["normalized"] = json!(true);
        // u16 texture coordinates, not normalised (a texture transform scales them).
        let uv: Vec<u8> = [0u16, 0, 4, 0, 0, 2]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let t = d.accessor(&uv, 5123, "VEC2", 3);
        let ext = match declared {
            true => json!({"extensionsUsed": ["KHR_mesh_quantization"],
                           "extensionsRequired": ["KHR_mesh_quantization"]}),
            false => json!({}),
        };
        let mut root = json!({
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0, "scale": [0.001, 0.001, 0.001]}],
            "meshes": [{"primitives": [{"attributes":
                {"POSITION": p, "NORMAL": n, "TEXCOORD_0": t}}]}],
        });
        root.as_object_mut()
            .unwrap()
            .extend(ext.as_object().unwrap().clone());
        load(&d.finish(root)).unwrap()
    };
    let s = quantized(true);
    assert!(
        s.warnings.iter().all(|w| w == NO_LIGHT_WARNING),
        "{:?}",
        s.warnings
    );
    let m = &s.meshes[0];
    assert_eq!(m.positions[1], Vec3::new(1000.0, 0.0, 0.0));
    assert_eq!(m.positions[2], Vec3::new(0.0, -1000.0, 0.0));
    assert_eq!(m.normals[0], Vec3::Z);
    assert_eq!(m.normals[2], Vec3::NEG_Z);
    assert_eq!(m.uvs[0][1], glam::Vec2::new(4.0, 0.0));
    assert_eq!(s.objects[0].transform, Mat4::from_scale(Vec3::splat(0.001)));
    // Without the declaration the file is not valid glTF: read the same, with a warning.
    let s = quantized(false);
    assert_eq!(s.meshes[0].positions[1], Vec3::new(1000.0, 0.0, 0.0));
    assert!(
        s.warnings.iter().any(|w| w.contains("mesh 0 primitive 0")
            && w.contains("KHR_mesh_quantization")
            && w.contains("POSITION, NORMAL, TEXCOORD_0")),
        "{:?}",
        s.warnings
    );
}

#[test]
fn points_and_lines_are_skipped_with_a_warning() {
    let s = load(&tri_scene(json!({"mode": 0}), json!({}))).unwrap();
    assert!(s.objects.is_empty() && s.meshes.is_empty());
    assert!(s
        .warnings
        .iter()
        .any(|w| w.contains("mesh 0 primitive 0") && w.contains("Points")));
}

#[test]
fn versions_a_2_0_loader_may_not_read_are_refused() {
    let with = |asset: Value| load(&tri_scene(json!({}), json!({ "asset": asset })));
    for (asset, says) in [
        (json!({"version": "3.0"}), "glTF version 3.0"),
        (json!({"version": "1.0"}), "glTF version 1.0"),
        (
            json!({"version": "2.1", "minVersion": "2.1"}),
            "asset.minVersion",
        ),
        (json!({"version": "two"}), "asset.version"),
    ] {
        let e = with(asset.clone()).unwrap_err();
        assert!(e.contains(says), "{asset}: {e}");
    }
    // A later minor version is read, as the specification asks of a 2.0 loader.
    for asset in [
        json!({"version": "2.0"}),
        json!({"version": "2.1"}),
        json!({"version": "2.0", "minVersion": "2.0"}),
    ] {
        with(asset.clone()).unwrap_or_else(|e| panic!("{asset}: {e}"));
    }
}

#[test]
fn required_extensions_are_checked() {
    for ext in ["KHR_draco_mesh_compression", "EXT_made_up"] {
        expect_err(
            &tri_scene(
                json!({}),
                json!({"extensionsUsed": [ext], "extensionsRequired": [ext]}),
            ),
            &[ext],
        );
    }
    for ext in [
        "KHR_materials_volume",
        "KHR_materials_specular",
        "KHR_texture_transform",
        "KHR_materials_clearcoat",
        "KHR_mesh_quantization",
    ] {
        load(&tri_scene(
            json!({}),
            json!({"extensionsUsed": [ext], "extensionsRequired": [ext]}),
        ))
        .unwrap_or_else(|e| panic!("{ext}: {e}"));
    }
    let s = load(&tri_scene(
        json!({}),
        json!({"extensionsUsed": ["EXT_optional_thing"]}),
    ))
    .unwrap();
    assert!(s.warnings.iter().any(|w| w.contains("EXT_optional_thing")));
}

#[test]
fn malformed_data_is_refused() {
    // Accessor past the end of its view.
    let mut d = Doc::default();
    d.positions(&TRI);
    d.accessors[0]["count"] = json!(4);
    expect_err(
        &one_prim(d, json!({"attributes": {"POSITION": 0}}), json!({})),
        &[
            "mesh 0 primitive 0",
            "accessor 0",
            "POSITION",
            "past the end",
        ],
    );
    // Absurd count: must not allocate.
    let mut d = Doc::default();
    d.positions(&TRI);
    d.accessors[0]["count"] = json!(u32::MAX);
    expect_err(
        &one_prim(d, json!({"attributes": {"POSITION": 0}}), json!({})),
        &["accessor 0"],
    );
    // Absurd count on an accessor with only sparse values.
    let mut d = Doc::default();
    d.positions(&TRI);
    let idx = d.view(&[0u8; 4]);
    let vals = d.view(&[0u8; 12]);
    d.accessors[0] = json!({"componentType": 5126, "type": "VEC3", "count": u32::MAX, "sparse": {
        "count": 1, "indices": {"bufferView": idx, "componentType": 5121}, "values": {"bufferView": vals}}});
    expect_err(
        &one_prim(d, json!({"attributes": {"POSITION": 0}}), json!({})),
        &["accessor 0"],
    );
    // View past the end of the buffer.
    let mut d = Doc::default();
    d.positions(&TRI);
    d.views[0]["byteLength"] = json!(1000);
    expect_err(
        &one_prim(d, json!({"attributes": {"POSITION": 0}}), json!({})),
        &["buffer view 0", "buffer 0"],
    );
    // Index out of range.
    let mut d = Doc::default();
    d.positions(&TRI);
    d.indices_u16(&[0, 1, 3]);
    expect_err(
        &one_prim(
            d,
            json!({"attributes": {"POSITION": 0}, "indices": 1}),
            json!({}),
        ),
        &["index 3", "out of range"],
    );
    // NaN position.
    let mut d = Doc::default();
    d.positions(&[[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    expect_err(
        &one_prim(d, json!({"attributes": {"POSITION": 0}}), json!({})),
        &["POSITION", "element 1", "not finite"],
    );
    // Bad references, cycles, not JSON.
    expect_err(
        &tri_scene(json!({"material": 9}), json!({})),
        &["invalid glTF"],
    );
    let mut d = Doc::default();
    d.positions(&TRI);
    let cyc = d.finish(
        json!({"scenes": [{"nodes": [0]}], "nodes": [{"children": [1]}, {"children": [0]}]}),
    );
    expect_err(&cyc, &["cycle"]);
    // A cycle no scene reaches, a node that is its own child, a node with two parents.
    for (nodes, needles) in [
        (
            json!([{}, {"children": [2]}, {"children": [1]}]),
            &["node 1", "cycle"][..],
        ),
        (json!([{}, {"children": [1]}]), &["node 1", "cycle"]),
        (
            json!([{"children": [2]}, {"children": [2]}, {}]),
            &["node 2 has two parents"],
        ),
    ] {
        let mut d = Doc::default();
        d.positions(&TRI);
        expect_err(
            &d.finish(json!({"scenes": [{"nodes": [0]}], "nodes": nodes})),
            needles,
        );
    }
    // A node that lists one child twice is not that child's two parents.
    let mut d = Doc::default();
    d.positions(&TRI);
    expect_err(
        &d.finish(json!({"scenes": [{"nodes": [0]}], "nodes": [{"children": [1, 1]}, {}]})),
        &["node 0 lists node 1 among its children twice"],
    );
    // A scene that names a node twice.
    let mut d = Doc::default();
    d.positions(&TRI);
    let twice = d.finish(json!({"scenes": [{"nodes": [0, 0]}], "nodes": [{}]}));
    expect_err(&twice, &["node 0", "twice"]);
    expect_err(b"{\"asset\": ", &["invalid JSON"]);
    expect_err(b"[]", &["not an object"]);
    // Buffer shorter than byteLength.
    let mut v: Value = serde_json::from_slice(&tri_scene(json!({}), json!({}))).unwrap();
    v["buffers"][0]["byteLength"] = json!(1 << 20);
    expect_err(
        &serde_json::to_vec(&v).unwrap(),
        &["buffer 0", "byteLength"],
    );
}

/// The GLB form of `json` with `bin` as its binary chunk.
fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let mut j = json.to_vec();
    while j.len() & 3 != 0 {
        j.push(b' ');
    }
    let mut out = b"glTF".to_vec();
    out.extend_from_slice(&2u32.to_le_bytes());
    let total = 12 + 8 + j.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(j.len() as u32).to_le_bytes());
    out.extend_from_slice(&0x4E4F_534Au32.to_le_bytes());
    out.extend_from_slice(&j);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(&0x004E_4942u32.to_le_bytes());
        out.extend_from_slice(bin);
    }
    out
}

#[test]
fn glb_containers() {
    let bin: Vec<u8> = TRI.concat().iter().flat_map(|x| x.to_le_bytes()).collect();
    let json = serde_json::to_vec(&json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3}],
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
    }))
    .unwrap();
    let good = glb(&json, &bin);
    let s = load(&good).unwrap();
    assert_eq!(s.meshes[0].positions[1], Vec3::X);
    // Truncated anywhere: an error, never a panic.
    for cut in [0, 4, 11, 12, 19, 20, good.len() / 2, good.len() - 1] {
        assert!(load(&good[..cut]).is_err(), "cut at {cut}");
    }
    expect_err(&good[..good.len() - 1], &["truncated"]);
    // No binary chunk although buffer 0 needs it.
    expect_err(&glb(&json, &[]), &["buffer 0", "binary chunk"]);
    // A second buffer without a uri: only the first may be the binary chunk.
    let mut two: Value = serde_json::from_slice(&json).unwrap();
    two["buffers"] = json!([{"byteLength": 36}, {"byteLength": 36}]);
    two["bufferViews"][0]["buffer"] = json!(1);
    let two = serde_json::to_vec(&two).unwrap();
    expect_err(&glb(&two, &bin), &["buffer 1 has no uri", "first buffer"]);
    // Wrong magic for a .glb path.
    let dir = temp_dir("magic");
    let p = dir.join("bad.glb");
    let mut bad = good.clone();
    bad[0] = b'X';
    std::fs::write(&p, &bad).unwrap();
    let e = load_gltf(&p).unwrap_err().to_string();
    assert!(e.contains("bad.glb") && e.contains("magic"), "{e}");
    std::fs::remove_dir_all(dir).ok();
}

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("raytile-gltf-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn hostile_uris_are_refused() {
    let root = temp_dir("uris");
    let scene_dir = root.join("scene");
    std::fs::create_dir_all(&scene_dir).unwrap();
    // A file outside the scene folder that a careless loader would read.
    std::fs::write(root.join("secret.bin"), [0u8; 64]).unwrap();
    std::fs::write(scene_dir.join("ok.bin"), [0u8; 36]).unwrap();
    let scene = |uri: &str| {
        json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 36, "uri": uri}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3}],
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        })
    };
    let path = scene_dir.join("scene.gltf");
    for uri in [
        "../secret.bin",
        "/etc/passwd",
        "file:///etc/passwd",
        "http://x/y.bin",
        "%2e%2e/secret.bin",
        "%2E%2E%2Fsecret.bin",
        "ok%ff.bin",
        "sub/../../secret.bin",
    ] {
        std::fs::write(&path, serde_json::to_vec(&scene(uri)).unwrap()).unwrap();
        let e = load_gltf(&path).expect_err(uri).to_string();
        assert!(
            e.contains("buffers[0].uri") && e.contains("refused"),
            "{uri}: {e}"
        );
        assert!(
            e.contains(&format!("{uri:?}")),
            "{uri}: {e} does not name the URI"
        );
    }
    // A symbolic link inside the folder pointing outside it.
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(root.join("secret.bin"), scene_dir.join("link.bin")).unwrap();
        std::fs::write(&path, serde_json::to_vec(&scene("link.bin")).unwrap()).unwrap();
        let e = load_gltf(&path).unwrap_err().to_string();
        assert!(e.contains("outside"), "{e}");
    }
    // The same file inside the folder is fine, and the resolver records it; from memory,
    // external URIs are refused.
    std::fs::write(&path, serde_json::to_vec(&scene("ok.bin")).unwrap()).unwrap();
    load_gltf(&path).unwrap();
    let files = SceneFiles::confined_to_scene(&path, 1 << 20, 1 << 20).unwrap();
    load_gltf_files(&path, &GltfOptions::default(), &files).unwrap();
    let names: Vec<_> = files.used().into_iter().filter_map(|u| u.name).collect();
    assert_eq!(
        names,
        [PathBuf::from("scene.gltf"), PathBuf::from("ok.bin")]
    );
    // Confined to a folder the glTF file is not in, the file itself is refused.
    std::fs::create_dir_all(root.join("elsewhere")).unwrap();
    let other = root.join("elsewhere/other.gltf");
    let files = SceneFiles::confined_to_scene(&other, 1 << 20, 1 << 20).unwrap();
    let e = load_gltf_files(&path, &GltfOptions::default(), &files).unwrap_err();
    assert!(e.to_string().contains("outside the scene's folder"), "{e}");
    let e = load(&serde_json::to_vec(&scene("ok.bin")).unwrap()).unwrap_err();
    assert!(e.contains("refused"), "{e}");
    // A missing file names the URI.
    std::fs::write(&path, serde_json::to_vec(&scene("missing.bin")).unwrap()).unwrap();
    let e = load_gltf(&path).unwrap_err().to_string();
    assert!(e.contains("\"missing.bin\""), "{e}");
    std::fs::remove_dir_all(root).ok();
}

#[test]
fn lights_cameras_and_units() {
    let q = std::f32::consts::FRAC_1_SQRT_2;
    let bytes = tri_scene(
        json!({}),
        json!({
            "extensionsUsed": ["KHR_lights_punctual"],
            "extensions": {"KHR_lights_punctual": {"lights": [
                {"type": "point", "color": [1.0, 0.5, 0.0], "intensity": 10.0},
                {"type": "spot", "intensity": 2.0, "range": 5.0, "spot": {"innerConeAngle": 0.1, "outerConeAngle": 0.5}},
                {"type": "directional", "intensity": 3.0},
            ]}},
            "scenes": [{"nodes": [0, 1, 2, 3, 4, 5]}],
            "nodes": [
                {"mesh": 0},
                {"translation": [1, 2, 3], "extensions": {"KHR_lights_punctual": {"light": 0}}},
                {"rotation": [-q, 0, 0, q], "extensions": {"KHR_lights_punctual": {"light": 1}}},
                {"rotation": [-q, 0, 0, q], "extensions": {"KHR_lights_punctual": {"light": 2}}},
                {"name": "cam node", "translation": [0, 0, 5], "camera": 0},
                {"camera": 1},
            ],
            "cameras": [
                {"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.1, "aspectRatio": 1.5}},
                {"type": "orthographic", "name": "ortho", "orthographic": {"xmag": 2, "ymag": 1, "znear": 0.1, "zfar": 10}},
            ],
        }),
    );
    let s = load(&bytes).unwrap();
    assert_eq!(
        s.lights[0],
        LightDesc::Point {
            position: Vec3::new(1.0, 2.0, 3.0),
            intensity: Vec3::new(10.0, 5.0, 0.0),
            range: f32::INFINITY
        }
    );
    let LightDesc::Spot {
        direction,
        inner_angle,
        outer_angle,
        range,
        ..
    } = &s.lights[1]
    else {
        panic!("{:?}", s.lights[1]);
    };
    // −Z rotated −90° about X points down.
    assert!((*direction - Vec3::NEG_Y).length() < 1e-5, "{direction}");
    assert_eq!((*inner_angle, *outer_angle, *range), (0.1, 0.5, 5.0));
    assert!(
        matches!(s.lights[2], LightDesc::Directional { irradiance, .. } if irradiance == Vec3::splat(3.0))
    );
    assert!(s.environment.is_none(), "punctual lights: no default light");
    assert_eq!(s.cameras.len(), 2);
    assert_eq!(s.cameras[0].name, "cam node");
    assert_eq!(s.cameras[0].aspect, Some(1.5));
    assert!(matches!(s.cameras[0].projection, Projection::Perspective { yfov, .. } if yfov == 0.7));
    assert_eq!(s.cameras[1].name, "ortho");
    assert_eq!(
        s.cameras[1].projection,
        Projection::Orthographic { half_height: 1.0 }
    );

    // Bad cone angles are refused.
    let bad = tri_scene(
        json!({}),
        json!({
            "extensions": {"KHR_lights_punctual": {"lights": [
                {"type": "spot", "spot": {"innerConeAngle": 0.5, "outerConeAngle": 0.5}}]}},
            "nodes": [{"mesh": 0, "extensions": {"KHR_lights_punctual": {"light": 0}}}],
        }),
    );
    expect_err(&bad, &["light 0", "cone"]);

    // A light index out of range is named by the file's own extension name.
    let bad = tri_scene(
        json!({}),
        json!({
            "extensionsUsed": ["KHR_lights_punctual"],
            "extensions": {"KHR_lights_punctual": {"lights": [{"type": "point"}]}},
            "nodes": [{"mesh": 0, "extensions": {"KHR_lights_punctual": {"light": 3}}}],
        }),
    );
    expect_err(&bad, &["nodes[0].extensions.KHR_lights_punctual.light"]);
    // A value of the wrong shape is named by its path, too.
    let bad = tri_scene(
        json!({"material": 0}),
        json!({
            "extensionsUsed": ["KHR_texture_transform"],
            "images": [{"uri": "data:image/png;base64,"}],
            "textures": [{"source": 0}],
            "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0,
                "extensions": {"KHR_texture_transform": {"offset": [1]}}}}}],
        }),
    );
    expect_err(
        &bad,
        &["invalid glTF at materials[0].pbrMetallicRoughness.baseColorTexture.extensions.KHR_texture_transform.offset"],
    );
    assert_eq!(
        extension_names(
            "materials[2].extensions.khrMaterialsEmissiveStrength.x.khrTextureTransform"
        ),
        "materials[2].extensions.KHR_materials_emissive_strength.x.KHR_texture_transform"
    );

    // A camera on a node of zero scale has no direction: refused, not rendered black.
    let flat = tri_scene(
        json!({}),
        json!({
            "scenes": [{"nodes": [0, 1]}],
            "nodes": [{"mesh": 0}, {"scale": [0, 0, 0], "translation": [0, 0, 5], "camera": 0}],
            "cameras": [{"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.1}}],
        }),
    );
    expect_err(&flat, &["camera 0", "node 1", "singular"]);
}

#[test]
fn memory_limit_is_enforced() {
    let opts = GltfOptions {
        memory_limit: 16,
        ..GltfOptions::default()
    };
    let e = load_gltf_slice(&tri_scene(json!({}), json!({})), None, "t", &opts).unwrap_err();
    assert!(e.to_string().contains("memory"), "{e}");
}

#[test]
fn a_scene_may_leave_out_its_nodes() {
    // `scene.nodes` is optional: an empty scene. The default scene is the second one here.
    let mut d = Doc::default();
    d.positions(&TRI);
    let root = json!({
        "scene": 1,
        "scenes": [{"name": "empty"}, {"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
    });
    assert_eq!(load(&d.finish(root)).unwrap().objects.len(), 1);
    let mut d = Doc::default();
    d.positions(&TRI);
    let root = json!({
        "scenes": [{}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
    });
    assert!(load(&d.finish(root)).unwrap().objects.is_empty());
}

#[test]
fn byte_order_mark_is_tolerated() {
    let mut bytes = b"\xEF\xBB\xBF".to_vec();
    bytes.extend(tri_scene(json!({}), json!({})));
    assert_eq!(load(&bytes).unwrap().meshes.len(), 1);
}

#[test]
fn camera_type_must_match_its_projection() {
    // Regression: the gltf crate's `Camera::projection` panics on this.
    let bytes = tri_scene(
        json!({}),
        json!({
            "scenes": [{"nodes": [0, 1]}],
            "nodes": [{"mesh": 0}, {"camera": 0}],
            "cameras": [{"type": "orthographic", "perspective": {"yfov": 0.5, "znear": 0.1}}],
        }),
    );
    expect_err(&bytes, &["cameras[0]", "type"]);
}

#[test]
fn position_accessor_out_of_range_is_refused() {
    // Regression (fuzz): the gltf crate's validation indexes accessors with it and panics.
    expect_err(
        &tri_scene(json!({"attributes": {"POSITION": 2}}), json!({})),
        &["mesh 0 primitive 0", "POSITION accessor 2"],
    );
    // No POSITION at all: skipped with a warning.
    let s = load(&tri_scene(json!({"attributes": {}}), json!({}))).unwrap();
    assert!(s.objects.is_empty());
    assert!(s.warnings.iter().any(|w| w.contains("no POSITION")));
}

#[test]
fn images_need_a_source() {
    // Regressions (fuzz): the gltf crate's `Image::source` panics on these.
    for image in [json!({}), json!({"bufferView": 0})] {
        let bytes = tri_scene(
            json!({"material": 0}),
            json!({
                "images": [image],
                "textures": [{"source": 0}],
                "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
            }),
        );
        expect_err(&bytes, &["image 0"]);
    }
}

// ---------------------------------------------------------------------------------------------
// Renders of small documents.

/// A 2 × 2 quad in the plane z = 0 facing +Z (towards the default camera), with normals and
/// UVs (u left to right, v top to bottom), material 0, plus `extra_attrs` and `extra` members.
fn quad_scene(mut d: Doc, extra_attrs: Value, extra: Value) -> Vec<u8> {
    let p = d.positions(&[
        [-1.0, -1.0, 0.0],
        [1.0, -1.0, 0.0],
        [1.0, 1.0, 0.0],
        [-1.0, 1.0, 0.0],
    ]);
    let n = d.floats(&[0.0, 0.0, 1.0].repeat(4), "VEC3", 3);
    let uv = d.floats(&[0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0], "VEC2", 2);
    let i = d.indices_u16(&[0, 1, 2, 0, 2, 3]);
    let mut attrs = json!({"POSITION": p, "NORMAL": n, "TEXCOORD_0": uv});
    if let (Some(o), Value::Object(e)) = (attrs.as_object_mut(), extra_attrs) {
        o.extend(e);
    }
    let prim = json!({"attributes": attrs, "indices": i, "material": 0});
    one_prim(d, prim, extra)
}

/// A `w` × `h` PNG as a data URI, texel (x, y) = `f(x, y)` (RGBA, 8 bits).
fn png_uri(w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 4]) -> String {
    let img = image::RgbaImage::from_fn(w, h, |x, y| image::Rgba(f(x, y)));
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(png)
    )
}

/// Renders a loaded document at `n`² with `spp` (path tracer); linear RGB, row-major from the
/// top.
fn render_doc(s: &SceneDesc, n: u32, spp: u32, default_light: bool) -> Vec<Vec3> {
    render_with(
        s,
        crate::RenderSettings {
            width: n,
            height: n,
            spp,
            max_depth: 8,
            default_light,
            ..Default::default()
        },
    )
}

/// Renders a loaded document with `settings`; linear RGB, row-major from the top.
fn render_with(s: &SceneDesc, settings: crate::RenderSettings) -> Vec<Vec3> {
    let scene = crate::Scene::build(s).unwrap();
    let job = crate::RenderJob::new(&scene, &settings).unwrap();
    let film = crate::render(&scene, &job, &());
    film.resolve().into_iter().map(Vec3::from).collect()
}

fn mean(px: &[Vec3]) -> f32 {
    px.iter().map(|p| p.element_sum() / 3.0).sum::<f32>() / px.len() as f32
}

/// Shaped like DamagedHelmet: no light of its own, an emissive texture on part of it (the left
/// half of a grey quad glows red). Emissive textures do not light a model, so it gets the
/// default environment and renders well above black; without the default light (or with the
/// job's `--environment none`) only the glowing half shows.
#[test]
fn a_model_lit_only_by_an_emissive_texture_gets_the_default_light() {
    let bytes = quad_scene(
        Doc::default(),
        json!({}),
        json!({
            "images": [{"uri": png_uri(2, 1, |x, _| if x == 0 { [255, 0, 0, 255] } else { [0, 0, 0, 255] })}],
            "samplers": [{"magFilter": 9728, "minFilter": 9728}],
            "textures": [{"source": 0, "sampler": 0}],
            "materials": [{
                "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1.0], "metallicFactor": 0.0},
                "emissiveFactor": [1.0, 1.0, 1.0],
                "emissiveTexture": {"index": 0},
            }],
        }),
    );
    let s = load(&bytes).unwrap();
    assert!(s.default_environment, "an emissive texture is not a light");
    assert!(s.warnings.iter().any(|w| w.contains("has no light")));
    let n = 24;
    let lit = render_doc(&s, n, 8, true);
    let lit_mean = mean(&lit);
    assert!(lit_mean > 0.5, "lit by default: mean {lit_mean}");

    let dark = render_doc(&s, n, 8, false);
    // The job's `--environment none` gives the same image.
    let none = render_with(
        &s,
        crate::RenderSettings {
            width: n,
            height: n,
            spp: 8,
            max_depth: 8,
            environment: Some(crate::settings::EnvironmentChoice::None),
            ..Default::default()
        },
    );
    assert!(
        none == dark,
        "--environment none is the scene without the default light"
    );
    let at = |x: u32, y: u32| dark[(y * n + x) as usize];
    // The right half (non-emissive quad and background) is black; the left half of the quad
    // glows red (and only red: nothing else lights the scene).
    for y in 0..n {
        for x in n / 2 + 1..n {
            assert_eq!(at(x, y), Vec3::ZERO, "({x}, {y}) should be black");
        }
    }
    assert!(dark.iter().all(|p| p.y == 0.0 && p.z == 0.0));
    let c = at(n / 2 - 3, n / 2);
    assert!(c.x > 0.5, "the emissive half glows: {c}");
    assert!(mean(&dark) < lit_mean / 4.0);
}

/// An untextured emissive surface with power (a lamp) lights the model: no default light.
#[test]
fn an_untextured_emitter_lights_the_model() {
    let bytes = quad_scene(
        Doc::default(),
        json!({}),
        json!({"materials": [{"emissiveFactor": [1.0, 1.0, 1.0]}]}),
    );
    let s = load(&bytes).unwrap();
    assert!(!s.default_environment);
    assert!(s.environment.is_none());
}

/// A 2 × 1 texture (NEAREST) as the members `images`, `samplers` and `textures` of a document:
/// texel 0 (the quad's left half) `left`, texel 1 (right half) `right`.
fn two_texels(left: [u8; 4], right: [u8; 4]) -> Value {
    json!({
        "images": [{"uri": png_uri(2, 1, |x, _| if x == 0 { left } else { right })}],
        "samplers": [{"magFilter": 9728, "minFilter": 9728}],
        "textures": [{"source": 0, "sampler": 0}],
    })
}

/// `two_texels` plus `material` and the extensions it uses.
fn textured_quad(left: [u8; 4], right: [u8; 4], material: Value) -> SceneDesc {
    let mut extra = two_texels(left, right);
    extra["materials"] = json!([material]);
    extra["extensionsUsed"] = json!([
        "KHR_materials_specular",
        "KHR_materials_clearcoat",
        "KHR_materials_emissive_strength"
    ]);
    load(&quad_scene(Doc::default(), json!({}), extra)).unwrap()
}

/// Mean colour of the quad's left and right halves (inner pixels only), rendered at `n`².
fn halves(px: &[Vec3], n: u32) -> (Vec3, Vec3) {
    let (mut l, mut r, mut count) = (Vec3::ZERO, Vec3::ZERO, 0.0);
    for y in n * 2 / 5..n * 3 / 5 {
        for dx in 2..n / 6 {
            l += px[(y * n + n / 2 - dx) as usize];
            r += px[(y * n + n / 2 + dx) as usize];
            count += 1.0;
        }
    }
    (l / count, r / count)
}

/// `KHR_materials_specular` textures: the strength (A channel) switches the specular layer of
/// a black dielectric on the left half and off on the right; the colour texture tints it red.
#[test]
fn specular_textures_render() {
    let n = 40;
    let settings = |spp| crate::RenderSettings {
        width: n,
        height: n,
        spp,
        max_depth: 4,
        ..Default::default()
    };
    let black = json!({"baseColorFactor": [0.0, 0.0, 0.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.4});
    let strength = json!({
        "pbrMetallicRoughness": black.clone(),
        "extensions": {"KHR_materials_specular": {"specularTexture": {"index": 0}}},
    });
    let s = textured_quad([0, 0, 0, 255], [0, 0, 0, 0], strength);
    let p = pbr(&s.materials[0]);
    assert!(p.specular_texture.is_some());
    assert!(!s.textures[p.specular_texture.unwrap().texture].srgb);
    let (l, r) = halves(&render_with(&s, settings(16)), n);
    assert!(l.min_element() > 0.02, "specular on the left: {l}");
    assert_eq!(r, Vec3::ZERO, "no specular and a black base on the right");

    let colour = json!({
        "pbrMetallicRoughness": black,
        "extensions": {"KHR_materials_specular": {"specularColorTexture": {"index": 0}}},
    });
    let s = textured_quad([255, 0, 0, 255], [255, 255, 255, 255], colour);
    let p = pbr(&s.materials[0]);
    assert!(s.textures[p.specular_color_texture.unwrap().texture].srgb);
    let (l, r) = halves(&render_with(&s, settings(16)), n);
    assert!(
        l.x > 1.5 * l.y && l.x > 1.5 * l.z,
        "red specular on the left: {l}"
    );
    assert!(
        (r.x - r.y).abs() < 0.1 * r.x,
        "white specular on the right: {r}"
    );
}

/// `KHR_materials_clearcoat` textures: the coat (R channel) on the left half of a black,
/// specular-free surface reflects the environment, the right half stays black; the roughness
/// texture (G channel) is read as linear data.
#[test]
fn clearcoat_textures_render() {
    let n = 40;
    let m = json!({
        "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0], "metallicFactor": 0.0},
        "extensions": {
            "KHR_materials_specular": {"specularFactor": 0.0},
            "KHR_materials_clearcoat": {"clearcoatFactor": 1.0, "clearcoatTexture": {"index": 0},
                "clearcoatRoughnessFactor": 0.5, "clearcoatRoughnessTexture": {"index": 0, "texCoord": 0}},
        },
    });
    let s = textured_quad([255, 128, 0, 255], [0, 128, 0, 255], m);
    let p = pbr(&s.materials[0]);
    let (cc, ccr) = (
        p.clearcoat_texture.unwrap(),
        p.clearcoat_roughness_texture.unwrap(),
    );
    assert!(!s.textures[cc.texture].srgb && !s.textures[ccr.texture].srgb);
    let px = render_with(
        &s,
        crate::RenderSettings {
            width: n,
            height: n,
            spp: 16,
            max_depth: 4,
            ..Default::default()
        },
    );
    let (l, r) = halves(&px, n);
    assert!(l.min_element() > 0.02, "coated on the left: {l}");
    assert_eq!(r, Vec3::ZERO, "no coat on the right");
    // A clearcoat texture that names no texture is an error naming it.
    let bad = json!({"extensions": {"KHR_materials_clearcoat": {"clearcoatFactor": 1.0, "clearcoatTexture": {"index": 7}}}});
    let mut extra = two_texels([0; 4], [0; 4]);
    extra["materials"] = json!([bad]);
    expect_err(
        &quad_scene(Doc::default(), json!({}), extra),
        &["clearcoatTexture", "no texture 7"],
    );
}

/// `KHR_materials_emissive_strength` scales an emissive texture: a white texel with strength 5
/// emits radiance 5 exactly.
#[test]
fn emissive_strength_scales_emissive_textures() {
    let n = 40;
    let m = json!({
        "emissiveFactor": [1.0, 1.0, 1.0],
        "emissiveTexture": {"index": 0},
        "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 5.0}},
    });
    let s = textured_quad([255, 255, 255, 255], [0, 0, 0, 255], m);
    let px = render_doc(&s, n, 4, false);
    let (l, r) = halves(&px, n);
    assert!((l - Vec3::splat(5.0)).abs().max_element() < 1e-4, "{l}");
    assert_eq!(r, Vec3::ZERO);
}

/// `COLOR_0` multiplies the base colour: two quads side by side, the left one's vertices red
/// (normalized unsigned bytes, RGBA), the right one's white, under a grey material, render
/// red and grey.
#[test]
fn vertex_colours_multiply_the_base_colour() {
    let mut d = Doc::default();
    let mut pos = Vec::new();
    for x0 in [-1.0f32, 0.0] {
        pos.extend([
            [x0, -1.0, 0.0],
            [x0 + 1.0, -1.0, 0.0],
            [x0 + 1.0, 1.0, 0.0],
            [x0, 1.0, 0.0],
        ]);
    }
    let p = d.positions(&pos);
    let colours: Vec<u8> = [[255u8, 0, 0, 255]; 4]
        .into_iter()
        .chain([[255u8, 255, 255, 255]; 4])
        .flatten()
        .collect();
    let c = d.accessor(&colours, 5121, "VEC4", 8);
    d.accessors[c]["normalized"] = json!(true);
    let i = d.indices_u16(&[0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7]);
    let prim = json!({"attributes": {"POSITION": p, "COLOR_0": c}, "indices": i, "material": 0});
    let bytes = one_prim(
        d,
        prim,
        json!({"materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1.0], "metallicFactor": 0.0}}]}),
    );
    let s = load(&bytes).unwrap();
    assert_eq!(s.meshes[0].colors.len(), 8);
    assert!(!s.warnings.iter().any(|w| w.contains("COLOR_0")));
    let n = 40;
    let px = render_with(
        &s,
        crate::RenderSettings {
            width: n,
            height: n,
            spp: 4,
            integrator: crate::IntegratorKind::Albedo,
            ..Default::default()
        },
    );
    let (l, r) = halves(&px, n);
    assert!(
        (l - Vec3::new(0.5, 0.0, 0.0)).abs().max_element() < 1e-3,
        "red half: {l}"
    );
    assert!(
        (r - Vec3::splat(0.5)).abs().max_element() < 1e-3,
        "grey half: {r}"
    );
    // Lit by the default light, the red half is red (its white specular layer aside).
    let lit = render_doc(&s, n, 4, true);
    let (l, r) = halves(&lit, n);
    assert!(l.x > 0.2 && l.y < 0.1 * l.x && l.z < 0.1 * l.x, "{l}");
    assert!(r.min_element() > 0.2, "{r}");
}

#[test]
fn an_accessor_without_a_buffer_view_or_sparse_values_is_zeros() {
    let mut d = Doc::default();
    d.positions(&TRI);
    d.accessors
        .push(json!({"componentType": 5126, "type": "VEC2", "count": 3}));
    let bytes = one_prim(
        d,
        json!({"attributes": {"POSITION": 0, "TEXCOORD_0": 1}}),
        json!({}),
    );
    let s = load(&bytes).unwrap();
    assert_eq!(s.meshes[0].uvs[0], vec![glam::Vec2::ZERO; 3]);
}

#[test]
fn extension_lists_hold_names() {
    for (list, needles) in [
        (
            json!([["KHR_lights_punctual"]]),
            &["extensionsRequired[0]", "extension name"][..],
        ),
        (json!([5123]), &["extensionsRequired[0]", "got 5123"]),
        (
            json!("KHR_lights_punctual"),
            &["extensionsRequired:", "an array"],
        ),
    ] {
        expect_err(
            &tri_scene(json!({}), json!({"extensionsRequired": list})),
            needles,
        );
    }
    expect_err(
        &tri_scene(json!({}), json!({"extensionsUsed": [null]})),
        &["extensionsUsed[0]"],
    );
}

#[test]
fn objects_written_as_arrays_are_refused_where_they_are() {
    // serde's derived structs would read an array of the fields in order.
    expect_err(
        &tri_scene(json!({}), json!({"cameras": [["perspective"]]})),
        &["cameras[0]", "invalid type: array, expected an object"],
    );
    expect_err(
        &tri_scene(json!({}), json!({"asset": ["2.0"]})),
        &["at asset", "expected an object"],
    );
    let e = load(&tri_scene(json!({}), json!({"asset": ["2.0"]}))).unwrap_err();
    assert!(!e.contains("struct"), "{e}");
}
