//! The golden image hashes: a tiny scene made here, rendered by every integrator, hashed bit for
//! bit and compared with pinned values. A farm mixes tiles from many workers only because every
//! worker computes the same bits; [`raytile_core::RENDER_VERSION`] is what keeps workers with
//! different arithmetic apart. This test fails when the bits change, so that the version is
//! raised whenever they do.

use glam::{Mat3, Mat4, Vec2, Vec3};
use raytile_core::scene::desc::*;
use raytile_core::{render, IntegratorKind, RenderJob, RenderSettings, Scene};
use sha2::{Digest, Sha256};

/// A checkerboard texture written texel by texel (sRGB, nearest or bilinear).
fn checker(name: &str, n: u32, bilinear: bool) -> TextureDesc {
    TextureDesc {
        name: name.into(),
        width: n,
        height: n,
        texels: (0..n * n)
            .map(|i| {
                let v = if (i % n + i / n) & 1 == 0 { 0.9 } else { 0.2 };
                [v, v * 0.8, v * 0.5, 1.0]
            })
            .collect(),
        srgb: true,
        wrap_u: WrapMode::Repeat,
        wrap_v: WrapMode::MirroredRepeat,
        bilinear,
    }
}

/// A quad of two triangles with uvs, in the XZ plane, facing +Y.
fn quad(name: &str, half: f32, uv_scale: f32) -> MeshDesc {
    MeshDesc {
        name: name.into(),
        positions: vec![
            Vec3::new(-half, 0.0, -half),
            Vec3::new(half, 0.0, -half),
            Vec3::new(half, 0.0, half),
            Vec3::new(-half, 0.0, half),
        ],
        normals: vec![],
        tangents: vec![],
        uvs: [
            vec![
                Vec2::new(0.0, 0.0),
                Vec2::new(uv_scale, 0.0),
                Vec2::new(uv_scale, uv_scale),
                Vec2::new(0.0, uv_scale),
            ],
            vec![],
        ],
        colors: Vec::new(),
        indices: vec![[0, 2, 1], [0, 3, 2]],
    }
}

/// Every kind of thing the tracer shades: textured diffuse and pbr meshes (one instanced
/// twice), a mirror, glass with absorption, a rough metal, analytic shapes under non-uniform
/// transforms, an emissive rectangle and an emissive triangle mesh, a point and a spot light,
/// and a constant environment.
fn scene() -> SceneDesc {
    let mut d = SceneDesc {
        textures: vec![checker("floor", 8, false), checker("pbr", 4, true)],
        ..Default::default()
    };
    let mut textured = TextureRef::new(0);
    textured.transform = Mat3::from_scale_angle_translation(Vec2::splat(1.5), 0.3, Vec2::ZERO);
    let mut lamp = MaterialDesc::new(
        "lamp",
        BsdfDesc::Diffuse {
            albedo: Vec3::splat(0.5),
            texture: None,
        },
    );
    lamp.emission = Vec3::new(6.0, 5.0, 4.0);
    let mut tri_lamp = MaterialDesc::new(
        "tri-lamp",
        BsdfDesc::Diffuse {
            albedo: Vec3::ZERO,
            texture: None,
        },
    );
    tri_lamp.emission = Vec3::new(2.0, 3.0, 6.0);
    tri_lamp.two_sided = true;
    d.materials = vec![
        MaterialDesc::new(
            "floor",
            BsdfDesc::Diffuse {
                albedo: Vec3::ONE,
                texture: Some(textured),
            },
        ),
        MaterialDesc::new(
            "mirror",
            BsdfDesc::Mirror {
                reflectance: Vec3::new(0.9, 0.85, 0.8),
            },
        ),
        MaterialDesc::new(
            "glass",
            BsdfDesc::Dielectric {
                ior: 1.5,
                transmittance: Vec3::ONE,
                absorption: Vec3::new(0.5, 0.1, 0.05),
                thin: false,
            },
        ),
        MaterialDesc::new(
            "metal",
            BsdfDesc::Conductor {
                eta: Vec3::new(0.2, 0.9, 1.1),
                k: Vec3::new(3.9, 2.4, 2.2),
                alpha: 0.2,
            },
        ),
        MaterialDesc::new(
            "pbr",
            BsdfDesc::Pbr(Box::new(PbrDesc {
                base_color: [0.8, 0.6, 0.4, 1.0],
                base_color_texture: Some(TextureRef::new(1)),
                metallic: 0.3,
                roughness: 0.4,
                ..Default::default()
            })),
        ),
        lamp,
        tri_lamp,
    ];
    d.meshes = vec![
        quad("floor", 3.0, 4.0),
        quad("tile", 0.3, 1.0),
        MeshDesc {
            name: "tri-lamp".into(),
            positions: vec![
                Vec3::new(-0.4, 1.6, -1.0),
                Vec3::new(0.4, 1.6, -1.0),
                Vec3::new(0.0, 2.0, -1.2),
            ],
            colors: Vec::new(),
            indices: vec![[0, 1, 2]],
            ..Default::default()
        },
    ];
    let object = |name: &str, shape, material, transform| ObjectDesc {
        name: name.into(),
        shape,
        material,
        transform,
        media: None,
    };
    d.objects = vec![
        object("floor", ShapeDesc::Mesh { mesh: 0 }, 0, Mat4::IDENTITY),
        object(
            "tile-a",
            ShapeDesc::Mesh { mesh: 1 },
            4,
            Mat4::from_translation(Vec3::new(-0.9, 0.01, 0.6)),
        ),
        object(
            "tile-b",
            ShapeDesc::Mesh { mesh: 1 },
            4,
            Mat4::from_translation(Vec3::new(0.9, 0.01, 0.6)) * Mat4::from_rotation_y(0.5),
        ),
        object(
            "mirror-ball",
            ShapeDesc::Sphere {
                center: Vec3::new(-0.6, 0.45, -0.3),
                radius: 0.45,
            },
            1,
            Mat4::IDENTITY,
        ),
        object(
            "glass-ball",
            ShapeDesc::Sphere {
                center: Vec3::ZERO,
                radius: 0.35,
            },
            2,
            Mat4::from_translation(Vec3::new(0.5, 0.4, 0.2))
                * Mat4::from_scale(Vec3::new(1.0, 1.2, 1.0)),
        ),
        object(
            "metal-box",
            ShapeDesc::Box {
                min: Vec3::splat(-0.2),
                max: Vec3::splat(0.2),
            },
            3,
            Mat4::from_translation(Vec3::new(0.2, 0.2, -0.9)) * Mat4::from_rotation_y(0.6),
        ),
        object(
            "lamp",
            ShapeDesc::Rectangle {
                corner: Vec3::new(-0.5, 0.0, -0.5),
                edge_u: Vec3::new(0.0, 0.0, 1.0),
                edge_v: Vec3::new(1.0, 0.0, 0.0),
            },
            5,
            Mat4::from_translation(Vec3::new(0.0, 2.2, 0.0))
                * Mat4::from_scale(Vec3::new(1.0, 1.0, 0.6)),
        ),
        object("tri-lamp", ShapeDesc::Mesh { mesh: 2 }, 6, Mat4::IDENTITY),
    ];
    d.lights = vec![
        LightDesc::Point {
            position: Vec3::new(1.5, 1.5, 1.5),
            intensity: Vec3::splat(2.0),
            range: f32::INFINITY,
        },
        LightDesc::Spot {
            position: Vec3::new(-1.5, 2.0, 1.0),
            direction: Vec3::new(1.0, -1.5, -0.5),
            intensity: Vec3::new(4.0, 3.0, 2.0),
            inner_angle: 0.3,
            outer_angle: 0.5,
            range: 10.0,
        },
    ];
    d.environment = Some(EnvironmentDesc::Constant {
        radiance: Vec3::new(0.05, 0.06, 0.1),
    });
    d.cameras = vec![CameraDesc {
        name: "main".into(),
        transform: Mat4::from_translation(Vec3::new(0.3, 1.4, 3.2)) * Mat4::from_rotation_x(-0.3),
        projection: Projection::Perspective {
            yfov: 0.75,
            aperture_radius: 0.02,
            focus_distance: 3.0,
        },
        aspect: None,
    }];
    d
}

/// The first 16 hex digits of the sha256 of the image's per-pixel sums (f32, little-endian).
fn image_hash(integrator: IntegratorKind) -> String {
    let desc = scene();
    let settings = RenderSettings {
        width: 40,
        height: 30,
        spp: 6,
        // sppm renders in one pass.
        passes: if integrator == IntegratorKind::Sppm {
            1
        } else {
            2
        },
        max_depth: 12,
        integrator,
        seed: 3,
        tile_size: 16,
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    let job = RenderJob::new(&scene, &settings).unwrap();
    let film = render(&scene, &job, &());
    let mut h = Sha256::new();
    for p in &film.pixels {
        for c in p {
            h.update(c.to_le_bytes());
        }
    }
    h.update(film.bad_samples.to_le_bytes());
    // Light carried to other pixels (bdpt's splats; none for other integrators).
    for p in &film.splats {
        for c in p {
            h.update(c.to_le_bytes());
        }
    }
    let digest = h.finalize();
    digest[..8].iter().map(|b| format!("{b:02x}")).collect()
}

/// The hashes of the current arithmetic, pinned with [`raytile_core::RENDER_VERSION`].
const GOLDEN: [(IntegratorKind, &str); 9] = [
    (IntegratorKind::Path, "3597a8cf8e8636a7"),
    (IntegratorKind::Volpath, "12660f1ea1462eae"),
    (IntegratorKind::Bdpt, "d38f1e26fad7077f"),
    (IntegratorKind::Sppm, "8cd6978ad287d687"),
    (IntegratorKind::Whitted, "1fb03513b2104f1a"),
    (IntegratorKind::Normals, "03bf382e05250bd4"),
    (IntegratorKind::Albedo, "4b0825cc18c681e5"),
    (IntegratorKind::Depth, "148ad63ba7c210d5"),
    (IntegratorKind::Ao, "358846d10765ac74"),
];

#[test]
fn image_bits_match_the_pinned_hashes() {
    let mut changed = Vec::new();
    for (integrator, pinned) in GOLDEN {
        let got = image_hash(integrator);
        if got != pinned {
            changed.push(format!("{}: {got} (pinned {pinned})", integrator.name()));
        }
    }
    assert!(
        changed.is_empty(),
        "image bits changed: if on purpose, raise RENDER_VERSION and update the pinned hash\n{}",
        changed.join("\n")
    );
}
