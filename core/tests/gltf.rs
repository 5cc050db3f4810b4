//! File-based glTF tests: the shared sample assets and the Cornell box load into the expected
//! scene descriptions. Each test prints "skipped" and passes when the shared folder is absent,
//! but fails in CI (`CI=true`), which must run them all.

mod common;

use glam::Vec3;
use raytile_core::scene::desc::{
    BsdfDesc, LightDesc, PbrDesc, Projection, SceneDesc, ShapeDesc, WrapMode,
};
use raytile_core::scene::load_scene;
use std::path::PathBuf;

const SAMPLES: &str = "gltf-samples";
const SCENES: &str = "scenes";

/// The path of a shared file (see [`common::shared`]).
fn shared(base: &str, rel: &str) -> Option<PathBuf> {
    common::shared(&format!("{base}/{rel}"))
}

fn load(base: &str, rel: &str) -> Option<SceneDesc> {
    let p = shared(base, rel)?;
    Some(load_scene(&p).unwrap_or_else(|e| panic!("{e}")))
}

fn pbr(s: &SceneDesc, object: usize) -> &PbrDesc {
    match &s.materials[s.objects[object].material].bsdf {
        BsdfDesc::Pbr(p) => p,
        other => panic!("not PBR: {other:?}"),
    }
}

fn triangles(s: &SceneDesc, object: usize) -> usize {
    match s.objects[object].shape {
        ShapeDesc::Mesh { mesh } => s.meshes[mesh].indices.len(),
        ref other => panic!("not a mesh: {other:?}"),
    }
}

/// Every sample asset loads, with sane meshes (indices in range, finite data).
#[test]
fn every_sample_loads() {
    let Some(dir) = shared(SAMPLES, "") else {
        return;
    };
    let mut n = 0;
    for entry in std::fs::read_dir(dir).unwrap() {
        let folder = entry.unwrap().path();
        if !folder.is_dir() {
            continue;
        }
        for f in std::fs::read_dir(&folder).unwrap() {
            let p = f.unwrap().path();
            let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("");
            if ext != "gltf" && ext != "glb" {
                continue;
            }
            let s = load_scene(&p).unwrap_or_else(|e| panic!("{e}"));
            n += 1;
            assert!(!s.objects.is_empty(), "{}", p.display());
            assert!(!s.cameras.is_empty(), "{}", p.display());
            for m in &s.meshes {
                let nv = m.positions.len() as u32;
                assert!(m.indices.iter().flatten().all(|&i| i < nv), "{}", m.name);
                assert!(m.positions.iter().all(|p| p.is_finite()));
                assert!(m.normals.is_empty() || m.normals.len() == m.positions.len());
            }
            for o in &s.objects {
                assert!(o.material < s.materials.len());
                assert!(o.transform.is_finite());
            }
        }
    }
    assert!(n >= 7, "only {n} sample files found");
}

#[test]
fn box_gltf_and_glb() {
    let (Some(gltf), Some(glb)) = (load(SAMPLES, "Box/Box.gltf"), load(SAMPLES, "Box/Box.glb"))
    else {
        return;
    };
    for s in [&gltf, &glb] {
        assert_eq!(s.objects.len(), 1);
        assert_eq!(triangles(s, 0), 12);
        assert_eq!(s.meshes[0].normals.len(), s.meshes[0].positions.len());
        assert_eq!(s.cameras[0].name, "default");
        // The Box's node matrix turns Z-up into Y-up: a rotation of −90° about X.
        let t = s.objects[0].transform;
        assert!((t.transform_vector3(Vec3::Z) - Vec3::Y).length() < 1e-5);
    }
    // metallicFactor absent (default 1) in the .gltf, 0 in the .glb.
    assert_eq!(pbr(&gltf, 0).metallic, 1.0);
    assert_eq!(pbr(&glb, 0).metallic, 0.0);
    assert_eq!(glb.materials[glb.objects[0].material].name, "Red");
    let c = pbr(&glb, 0).base_color;
    assert!(c[0] > 0.7 && c[1] < 0.1 && c[2] < 0.1, "{c:?}");
}

#[test]
fn box_textured() {
    let Some(s) = load(SAMPLES, "BoxTextured/BoxTextured.gltf") else {
        return;
    };
    let r = pbr(&s, 0).base_color_texture.expect("base colour texture");
    let t = &s.textures[r.texture];
    assert!(t.srgb);
    assert_eq!((t.wrap_u, t.wrap_v), (WrapMode::Repeat, WrapMode::Repeat));
    assert!(t.bilinear);
    assert_eq!((t.width, t.height), (256, 256));
    assert_eq!(t.texels.len(), 256 * 256);
    let mesh = match s.objects[0].shape {
        ShapeDesc::Mesh { mesh } => &s.meshes[mesh],
        _ => unreachable!(),
    };
    assert_eq!(mesh.uvs[0].len(), mesh.positions.len());
    assert!(
        mesh.uvs[0].iter().any(|uv| uv.x > 1.0 || uv.y > 1.0),
        "UVs beyond 1 need REPEAT"
    );
}

#[test]
fn cameras() {
    let Some(s) = load(SAMPLES, "Cameras/Cameras.gltf") else {
        return;
    };
    assert_eq!(s.cameras.len(), 2);
    let persp = s
        .cameras
        .iter()
        .find(|c| matches!(c.projection, Projection::Perspective { .. }))
        .unwrap();
    let ortho = s
        .cameras
        .iter()
        .find(|c| matches!(c.projection, Projection::Orthographic { .. }))
        .unwrap();
    assert!(
        matches!(persp.projection, Projection::Perspective { yfov, .. } if (yfov - 0.7).abs() < 1e-6)
    );
    assert_eq!(persp.aspect, Some(1.0));
    assert_eq!(
        ortho.projection,
        Projection::Orthographic { half_height: 1.0 }
    );
    assert_ne!(persp.name, ortho.name, "selectable by name");
    assert_ne!(s.cameras[0], s.cameras[1], "selectable by index");
    // The mesh has no normals and no material: flat shading, default material.
    assert!(s.meshes.iter().all(|m| m.normals.is_empty()));
    assert_eq!(pbr(&s, 0).metallic, 1.0);
    assert_eq!(pbr(&s, 0).roughness, 1.0);
}

#[test]
fn lights_punctual() {
    let Some(s) = load(SAMPLES, "Lights/Lights.glb") else {
        return;
    };
    let points: Vec<_> = s
        .lights
        .iter()
        .filter(|l| matches!(l, LightDesc::Point { .. }))
        .collect();
    let spots: Vec<_> = s
        .lights
        .iter()
        .filter(|l| matches!(l, LightDesc::Spot { .. }))
        .collect();
    let dirs: Vec<_> = s
        .lights
        .iter()
        .filter(|l| matches!(l, LightDesc::Directional { .. }))
        .collect();
    assert_eq!(
        (points.len(), spots.len(), dirs.len()),
        (1, 2, 1),
        "{:?}",
        s.lights
    );
    if let LightDesc::Point {
        intensity, range, ..
    } = points[0]
    {
        // Red, intensity 5 (candela → W/sr 1:1).
        assert!(
            intensity.x > 0.0 && intensity.y == 0.0 && intensity.z == 0.0,
            "{intensity}"
        );
        assert!(intensity.x <= 5.0 + 1e-4);
        assert!(*range > 0.0);
    }
    for l in spots {
        let LightDesc::Spot {
            inner_angle,
            outer_angle,
            direction,
            ..
        } = l
        else {
            unreachable!()
        };
        assert!(inner_angle < outer_angle, "{l:?}");
        assert!((direction.length() - 1.0).abs() < 1e-4);
    }
    assert!(s.environment.is_none(), "punctual lights: no default light");
    assert_eq!(s.cameras.len(), 1);
    assert_eq!(s.cameras[0].aspect, None);
}

#[test]
fn primitive_modes_and_missing_normals() {
    let Some(s) = load(
        SAMPLES,
        "PrimitiveModeNormalsTest/PrimitiveModeNormalsTest.glb",
    ) else {
        return;
    };
    assert!(
        s.warnings
            .iter()
            .any(|w| w.contains("Points") && w.contains("skipped")),
        "{:?}",
        s.warnings
    );
    assert!(s
        .warnings
        .iter()
        .any(|w| w.contains("LineStrip") && w.contains("skipped")));
    assert!(!s.meshes.is_empty());
    assert!(
        s.meshes.iter().any(|m| m.normals.is_empty()),
        "triangles without normals kept"
    );
    assert!(s.meshes.iter().any(|m| !m.normals.is_empty()));
    let tris: usize = s.meshes.iter().map(|m| m.indices.len()).sum();
    assert!(tris > 1000, "{tris}");
}

#[test]
fn texture_transform() {
    let Some(s) = load(SAMPLES, "TextureTransformTest/TextureTransformTest.gltf") else {
        return;
    };
    let transforms: Vec<glam::Mat3> = s
        .materials
        .iter()
        .filter_map(|m| match &m.bsdf {
            BsdfDesc::Pbr(p) => p.base_color_texture.map(|t| t.transform),
            _ => None,
        })
        .collect();
    assert!(
        transforms
            .iter()
            .filter(|t| **t != glam::Mat3::IDENTITY)
            .count()
            >= 4,
        "{transforms:?}"
    );
    // External PNGs decoded; the CLAMP sampler.
    assert!(s.textures.iter().any(|t| t.wrap_u == WrapMode::Clamp));
    assert!(s
        .textures
        .iter()
        .all(|t| t.width > 0 && t.texels.len() == (t.width * t.height) as usize));
}

/// The sample's arrow, turned by each quad's transform, points at that quad's "Correct"
/// marker (and, for the rotation, not at its "Error" marker). The arrow's tip is where the
/// "Not Supported" marker sits, seen with no transform; each quad shows at a point p the texel
/// at its transform times p's texture coordinates, so the tip shows where that product is the
/// tip's texture coordinates.
#[test]
fn texture_transform_points_the_arrow_at_correct() {
    let Some(s) = load(SAMPLES, "TextureTransformTest/TextureTransformTest.gltf") else {
        return;
    };
    let object = |name: &str| {
        s.objects
            .iter()
            .position(|o| o.name == name)
            .unwrap_or_else(|| panic!("no node '{name}'"))
    };
    let centre = |name: &str| s.objects[object(name)].transform.w_axis.truncate();
    // The affine map from world position (in the quad's plane, z constant) to texture
    // coordinates, from the quad's first triangle.
    let uv_map = |name: &str| {
        let o = &s.objects[object(name)];
        let ShapeDesc::Mesh { mesh } = o.shape else {
            panic!("'{name}' is not a mesh")
        };
        let m = &s.meshes[mesh];
        let [a, b, c] = m.indices[0].map(|i| i as usize);
        let p = |i: usize| o.transform.transform_point3(m.positions[i]).truncate();
        let uv = |i: usize| m.uvs[0][i];
        let world = glam::Mat3::from_cols(p(a).extend(1.0), p(b).extend(1.0), p(c).extend(1.0));
        let tex = glam::Mat3::from_cols(uv(a).extend(1.0), uv(b).extend(1.0), uv(c).extend(1.0));
        tex * world.inverse()
    };
    let tip = uv_map("Rotation") * centre("Rotation - Not Supported").truncate().extend(1.0);
    for (quad, correct, error) in [
        ("Rotation", "Rotation - Correct", Some("Rotation - Error")),
        ("Scale", "Scale - Correct", None),
        ("All", "All - Correct", None),
    ] {
        let i = object(quad);
        let t = pbr(&s, i).base_color_texture.unwrap().transform;
        let shown = (t * uv_map(quad)).inverse() * tip;
        let shown = shown.truncate() / shown.z;
        let miss = (shown - centre(correct).truncate()).length();
        assert!(
            miss < 0.05,
            "{quad}: the arrow points at {shown}, {miss} from '{correct}'"
        );
        if let Some(error) = error {
            let off = (shown - centre(error).truncate()).length();
            assert!(off > 0.3, "{quad}: the arrow points at '{error}'");
        }
    }
}

#[test]
fn cornell_box() {
    let Some(s) = load(SCENES, "cornell-box.gltf") else {
        return;
    };
    let names: Vec<&str> = s.objects.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "floor",
            "ceiling",
            "back",
            "green-wall",
            "red-wall",
            "light",
            "small-box",
            "large-box"
        ]
    );
    for (i, o) in s.objects.iter().enumerate() {
        let m = &s.materials[o.material];
        let p = pbr(&s, i);
        assert_eq!((p.specular, p.metallic), (0.0, 0.0), "{}", o.name);
        assert!(!m.two_sided, "{}", o.name);
        if o.name == "light" {
            let e = m.emission;
            assert!(
                (e - Vec3::new(18.387, 13.9873, 6.75357))
                    .abs()
                    .max_element()
                    < 1e-3,
                "{e}"
            );
        } else {
            assert_eq!(m.emission, Vec3::ZERO, "{}", o.name);
        }
    }
    let colour = |name: &str| {
        let i = names.iter().position(|n| *n == name).unwrap();
        Vec3::from_slice(&pbr(&s, i).base_color[..3])
    };
    let (white, green, red) = (colour("floor"), colour("green-wall"), colour("red-wall"));
    assert!(white.min_element() > 0.5);
    assert!(green.y > green.x && green.y > green.z);
    assert!(red.x > red.y && red.x > red.z);
    assert!(
        s.environment.is_none(),
        "the light is emissive: no default light"
    );
    assert_eq!(s.cameras.len(), 1);
    let cam = &s.cameras[0];
    let eye = cam.transform.transform_point3(Vec3::ZERO);
    assert!((eye - Vec3::new(0.0, 0.0, 3.9)).length() < 1e-5);
    assert!((cam.transform.transform_vector3(Vec3::NEG_Z) - Vec3::NEG_Z).length() < 1e-5);
    assert!(
        matches!(cam.projection, Projection::Perspective { yfov, .. } if (yfov - 0.6860488).abs() < 1e-5)
    );
    // The light faces down.
    let li = names.iter().position(|n| *n == "light").unwrap();
    let ShapeDesc::Mesh { mesh } = s.objects[li].shape else {
        unreachable!()
    };
    let m = &s.meshes[mesh];
    let [a, b, c] = m.indices[0].map(|i| m.positions[i as usize]);
    let t = s.objects[li].transform;
    let n = (t.transform_point3(b) - t.transform_point3(a))
        .cross(t.transform_point3(c) - t.transform_point3(a));
    assert!(n.y < 0.0, "light normal {n}");
}
