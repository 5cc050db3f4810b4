//! Reader tests on files a small writer here makes (uncompressed and zlib, with and without
//! active-mask compression), and hostile variants of them. Files written by OpenVDB itself
//! are checked in `core/tests/vdb_openvdb.rs`.

use super::*;
use glam::Vec3A;
use std::collections::BTreeMap;

/// Options of the test writer.
#[derive(Clone, Copy)]
pub(crate) struct Write {
    pub(crate) compression: u32,
    pub(crate) background: f32,
    pub(crate) scale: f64,
    pub(crate) translation: [f64; 3],
    /// An `AffineMap` instead of the `ScaleTranslateMap` of `scale`: the world images of the
    /// index axes (with `translation`).
    pub(crate) affine: Option<[[f64; 3]; 3]>,
}

impl Default for Write {
    fn default() -> Self {
        Self {
            compression: COMPRESS_ZIP | COMPRESS_ACTIVE_MASK,
            background: 0.0,
            scale: 0.5,
            translation: [1.0, -2.0, 3.0],
            affine: None,
        }
    }
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    out.extend_from_slice(&(s.len() as u32).to_le_bytes());
    out.extend_from_slice(s.as_bytes());
}

fn put_mask(out: &mut Vec<u8>, bits: &[bool]) {
    for w in bits.chunks(64) {
        let word = w
            .iter()
            .enumerate()
            .fold(0u64, |a, (i, &b)| a | ((b as u64) << i));
        out.extend_from_slice(&word.to_le_bytes());
    }
}

/// A node's values as OpenVDB's `writeCompressedValues` lays them out for the simple cases:
/// with active-mask compression only the active values (layout 0: inactive ones are the
/// background), else all (layout 6).
fn put_values(out: &mut Vec<u8>, w: &Write, values: &[f32], active: &[bool]) {
    let masked = w.compression & COMPRESS_ACTIVE_MASK != 0;
    out.push(if masked {
        NO_MASK_OR_INACTIVE_VALS
    } else {
        NO_MASK_AND_ALL_VALS
    });
    let raw: Vec<u8> = values
        .iter()
        .zip(active)
        .filter(|(_, &a)| a || !masked)
        .flat_map(|(v, _)| v.to_le_bytes())
        .collect();
    if w.compression & COMPRESS_ZIP != 0 {
        let z = miniz_oxide::deflate::compress_to_vec_zlib(&raw, 6);
        out.extend_from_slice(&(z.len() as i64).to_le_bytes());
        out.extend_from_slice(&z);
    } else {
        out.extend_from_slice(&raw);
    }
}

/// Leaves (voxels by leaf slot) by internal-node slot: one root child's content.
type Node5 = BTreeMap<usize, BTreeMap<usize, Vec<([i32; 3], f32)>>>;

/// A `.vdb` file with one float grid named "density" holding `voxels` (all active), in
/// leaves under one internal node per 128³ and 4096³ block.
pub(crate) fn write_vdb(voxels: &BTreeMap<[i32; 3], f32>, w: &Write) -> Vec<u8> {
    // Group the voxels by root child, internal node and leaf.
    let key = |p: [i32; 3], total: u32| p.map(|v| v & !((1 << total) - 1));
    let mut tree: BTreeMap<[i32; 3], Node5> = BTreeMap::new();
    for (&p, &v) in voxels {
        tree.entry(key(p, N5_TOTAL))
            .or_default()
            .entry(slot(p, N5_LOG2, N4_TOTAL))
            .or_default()
            .entry(slot(p, N4_LOG2, LEAF_TOTAL))
            .or_default()
            .push((p, v));
    }
    let mut out = Vec::new();
    out.extend_from_slice(&MAGIC.to_le_bytes());
    out.extend_from_slice(&224u32.to_le_bytes());
    out.extend_from_slice(&10u32.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.push(1);
    out.extend_from_slice(b"01234567-89ab-cdef-0123-456789abcdef");
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&1u32.to_le_bytes());
    put_str(&mut out, "density");
    put_str(&mut out, "Tree_float_5_4_3");
    put_str(&mut out, "");
    let offsets_at = out.len();
    out.extend_from_slice(&[0u8; 24]);
    let grid_pos = out.len();
    out.extend_from_slice(&w.compression.to_le_bytes());
    out.extend_from_slice(&1u32.to_le_bytes());
    put_str(&mut out, "class");
    put_str(&mut out, "string");
    put_str(&mut out, "fog volume");
    if let Some(axes) = w.affine {
        // Row-vector 4×4: the axes' images, then the translation.
        put_str(&mut out, "AffineMap");
        let [x, y, z] = axes;
        let t = w.translation;
        for v in [x, y, z, t]
            .iter()
            .zip([0.0, 0.0, 0.0, 1.0])
            .flat_map(|(r, w)| {
                let mut row = r.to_vec();
                row.push(w);
                row
            })
        {
            out.extend_from_slice(&v.to_le_bytes());
        }
    } else {
        put_str(&mut out, "ScaleTranslateMap");
        for v in w.translation.iter().chain(&[w.scale; 3]).chain(&[0.0; 12]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out.extend_from_slice(&1u32.to_le_bytes());
    out.extend_from_slice(&w.background.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(tree.len() as u32).to_le_bytes());
    let bg = w.background;
    for (origin, n5) in &tree {
        out.extend_from_slice(&origin.map(|v| v.to_le_bytes()).concat());
        let children: Vec<bool> = (0..32768).map(|s| n5.contains_key(&s)).collect();
        put_mask(&mut out, &children);
        put_mask(&mut out, &[false; 32768]);
        put_values(&mut out, w, &[bg; 32768], &[false; 32768]);
        for n4 in n5.values() {
            let children: Vec<bool> = (0..4096).map(|s| n4.contains_key(&s)).collect();
            put_mask(&mut out, &children);
            put_mask(&mut out, &[false; 4096]);
            put_values(&mut out, w, &[bg; 4096], &[false; 4096]);
            for leaf in n4.values() {
                let mut active = [false; 512];
                for (p, _) in leaf {
                    active[slot(*p, LEAF_LOG2, 0)] = true;
                }
                put_mask(&mut out, &active);
            }
        }
    }
    let block_pos = out.len();
    for n5 in tree.values() {
        for n4 in n5.values() {
            for leaf in n4.values() {
                let mut active = [false; 512];
                let mut values = [bg; 512];
                for (p, v) in leaf {
                    active[slot(*p, LEAF_LOG2, 0)] = true;
                    values[slot(*p, LEAF_LOG2, 0)] = *v;
                }
                put_mask(&mut out, &active);
                put_values(&mut out, w, &values, &active);
            }
        }
    }
    let end_pos = out.len();
    for (i, v) in [grid_pos, block_pos, end_pos].into_iter().enumerate() {
        out[offsets_at + 8 * i..offsets_at + 8 * i + 8].copy_from_slice(&(v as u64).to_le_bytes());
    }
    out
}

/// A blob of smoke spread over two internal nodes and two root children.
pub(crate) fn smoke() -> BTreeMap<[i32; 3], f32> {
    let mut v = BTreeMap::new();
    for i in -6..10 {
        for j in 120..136 {
            for k in -3..4 {
                let d = 1.0 - ((i * i + (j - 128) * (j - 128) + k * k) as f32) / 200.0;
                if d > 0.0 {
                    v.insert([i, j, k], d);
                }
            }
        }
    }
    v.insert([5000, 1, 1], 0.25);
    v
}

fn limits() -> GridLimits {
    GridLimits::default()
}

#[test]
fn written_grids_read_back_exactly() {
    let voxels = smoke();
    for compression in [
        0,
        COMPRESS_ZIP,
        COMPRESS_ACTIVE_MASK,
        COMPRESS_ZIP | COMPRESS_ACTIVE_MASK,
    ] {
        let w = Write {
            compression,
            background: 0.0,
            ..Default::default()
        };
        let g = read_vdb(&write_vdb(&voxels, &w), None, &limits()).unwrap();
        assert_eq!(
            (g.name(), g.class(), g.background()),
            ("density", "fog volume", 0.0)
        );
        for (p, v) in &voxels {
            assert_eq!(g.probe(*p), (*v, true), "{p:?}, compression {compression}");
        }
        assert_eq!(g.probe([0, 0, 100]), (0.0, false));
        assert_eq!(g.probe([-100_000, 0, 0]), (0.0, false));
        assert_eq!(g.active_voxel_count(), voxels.len() as u64);
        assert_eq!(g.active_bbox(), Some(([-6, 1, -3], [5000, 135, 3])));
        let m = g.index_to_world();
        assert_eq!(
            m.transform_point3(DVec3::new(2.0, 0.0, 0.0)),
            DVec3::new(2.0, -2.0, 3.0)
        );
    }
}

#[test]
fn the_dense_grid_covers_the_active_box_in_world_space() {
    let mut voxels = smoke();
    voxels.remove(&[5000, 1, 1]);
    let g = read_vdb(&write_vdb(&voxels, &Write::default()), None, &limits()).unwrap();
    let LoadedGrid { density, transform } = g.to_density(&limits()).unwrap();
    assert_eq!(transform, Affine3A::IDENTITY);
    // Active box -6..9, 120..135, -3..3, one voxel more on each side.
    assert_eq!(density.resolution(), [18, 18, 9]);
    // Index i's centre is at 0.5 i + (1, -2, 3); the box spans the padded voxels' cells,
    // indices -7.5..10.5, 118.5..136.5, -4.5..4.5.
    let b = density.bounds();
    assert_eq!(
        b.min,
        Vec3A::new(0.5 * -7.5 + 1.0, 0.5 * 118.5 - 2.0, 0.5 * -4.5 + 3.0)
    );
    assert_eq!(
        b.max,
        Vec3A::new(0.5 * 10.5 + 1.0, 0.5 * 136.5 - 2.0, 0.5 * 4.5 + 3.0)
    );
    for (p, v) in &voxels {
        let w = Vec3A::new(
            0.5 * p[0] as f32 + 1.0,
            0.5 * p[1] as f32 - 2.0,
            0.5 * p[2] as f32 + 3.0,
        );
        assert!((density.density(w) - v).abs() < 1e-6, "{p:?}");
    }
    // The padding voxels are the background: the density falls to 0 at the faces.
    assert_eq!(density.voxel(0, 0, 0), 0.0);
    // Too many voxels for the limit: an error before allocating.
    let tight = GridLimits {
        max_voxels: 18 * 18 * 9 - 1,
        ..limits()
    };
    assert!(matches!(
        g.to_density(&tight),
        Err(GridFormatError::TooLarge { .. })
    ));
    // With the far voxel the box is 5000 voxels wide: still fine, but not with a small limit.
    let far = read_vdb(&write_vdb(&smoke(), &Write::default()), None, &limits()).unwrap();
    assert!(matches!(
        far.to_density(&GridLimits {
            max_voxels: 1 << 20,
            ..limits()
        }),
        Err(GridFormatError::TooLarge { .. })
    ));
}

#[test]
fn grids_are_picked_by_name() {
    let bytes = write_vdb(&smoke(), &Write::default());
    assert!(read_vdb(&bytes, Some("density"), &limits()).is_ok());
    let err = read_vdb(&bytes, Some("flame"), &limits())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("no grid named 'flame'") && err.contains("'density' (Tree_float_5_4_3)"),
        "{err}"
    );
}

#[test]
fn negative_values_and_empty_grids_are_not_densities() {
    let mut voxels = smoke();
    voxels.insert([0, 128, 0], -1.0);
    voxels.remove(&[5000, 1, 1]);
    let g = read_vdb(&write_vdb(&voxels, &Write::default()), None, &limits()).unwrap();
    let err = g.to_density(&limits()).unwrap_err().to_string();
    assert!(err.contains("density -1"), "{err}");
    let empty = read_vdb(
        &write_vdb(&BTreeMap::new(), &Write::default()),
        None,
        &limits(),
    )
    .unwrap();
    assert!(empty
        .to_density(&limits())
        .unwrap_err()
        .to_string()
        .contains("no active voxels"));
}

#[test]
fn half_floats_convert_exactly() {
    assert_eq!(f16_to_f32(0x3c00), 1.0);
    assert_eq!(f16_to_f32(0xc000), -2.0);
    assert_eq!(f16_to_f32(0x3555), 0.333_251_95);
    assert_eq!(f16_to_f32(0x7bff), 65504.0);
    assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
    assert_eq!(f16_to_f32(0x8001), -(2f32.powi(-24)));
    assert_eq!(f16_to_f32(0x03ff), 1023.0 * 2f32.powi(-24));
    assert_eq!(f16_to_f32(0x7c00), f32::INFINITY);
    assert!(f16_to_f32(0x7e00).is_nan());
    assert_eq!(f16_to_f32(0x8000).to_bits(), (-0.0f32).to_bits());
}

#[test]
fn truncated_files_are_errors() {
    let mut voxels = BTreeMap::new();
    voxels.insert([1, 2, 3], 0.5);
    voxels.insert([9, 2, 3], 0.75);
    let bytes = write_vdb(&voxels, &Write::default());
    assert!(read_vdb(&bytes, None, &limits()).is_ok());
    for cut in 0..bytes.len() {
        assert!(
            read_vdb(&bytes[..cut], None, &limits()).is_err(),
            "cut at {cut} of {}",
            bytes.len()
        );
    }
}

#[test]
fn corrupted_files_never_panic() {
    let mut voxels = BTreeMap::new();
    voxels.insert([1, 2, 3], 0.5);
    voxels.insert([-9, 2, 300], 0.75);
    for w in [
        Write::default(),
        Write {
            compression: COMPRESS_ACTIVE_MASK,
            ..Default::default()
        },
    ] {
        let bytes = write_vdb(&voxels, &w);
        // Every byte of the header, descriptor and grid preamble, and a spread of the rest,
        // set to hostile values: an error or a grid, never a panic or a huge allocation.
        let positions = (0..400.min(bytes.len())).chain((400..bytes.len()).step_by(97));
        for i in positions {
            for v in [0u8, 0x80, 0xff] {
                let mut b = bytes.clone();
                b[i] = v;
                if let Ok(g) = read_vdb(&b, None, &limits()) {
                    let _ = g.to_density(&GridLimits {
                        max_voxels: 1 << 16,
                        ..limits()
                    });
                }
            }
        }
    }
}

#[test]
fn hostile_counts_are_refused_before_allocating() {
    let bytes = write_vdb(&smoke(), &Write::default());
    let check = |patch: &dyn Fn(&mut Vec<u8>), want: &str| {
        let mut b = bytes.clone();
        patch(&mut b);
        let err = read_vdb(&b, None, &limits()).unwrap_err().to_string();
        assert!(err.contains(want), "{err:?} should mention {want:?}");
    };
    // File version, magic.
    check(
        &|b| b[8..12].copy_from_slice(&221u32.to_le_bytes()),
        "version 221",
    );
    check(&|b| b[0] = b'X', "not an OpenVDB file");
    // File metadata count (after magic, version, library, flag, UUID: byte 57).
    check(
        &|b| b[57..61].copy_from_slice(&u32::MAX.to_le_bytes()),
        "metadata entries",
    );
    // Grid count.
    check(
        &|b| b[61..65].copy_from_slice(&u32::MAX.to_le_bytes()),
        "grids in",
    );
    // The grid's type.
    check(
        &|b| {
            let at = 65 + 4 + 7 + 4;
            b[at..at + 16].copy_from_slice(b"Tree_vec3s_5_4_3");
        },
        "the grid named 'density' is not a float grid (it is Tree_vec3s_5_4_3); the file has \
         no float grid",
    );
    // The same grid under another name and type: no 'density' at all.
    check(
        &|b| {
            let at = 65 + 4;
            b[at..at + 7].copy_from_slice(b"tension");
            b[at + 7 + 4..at + 7 + 4 + 16].copy_from_slice(b"Tree_vec3s_5_4_3");
        },
        "no grid named 'density', and the file has no float grid (the file has 'tension' \
         (Tree_vec3s_5_4_3))",
    );
    // A tiny voxel limit: the sparse tree alone exceeds it.
    assert!(matches!(
        read_vdb(
            &bytes,
            None,
            &GridLimits {
                max_voxels: 1000,
                ..limits()
            }
        ),
        Err(GridFormatError::TooLarge { .. })
    ));
}
