//! Mitsuba 3's `.vol` grid files (the format of `mitsuba::VolumeGrid`, from Mitsuba 0.6 on).
//!
//! Little endian: the bytes `VOL`, a version byte (3), an i32 encoding (1 = float32), i32
//! resolutions x, y, z, an i32 channel count, six f32 for the box (xmin ymin zmin xmax ymax
//! zmax), then the float32 values with x fastest:
//! `data[((z · yres + y) · xres + x) · channels + c]`.
//!
//! A density is one number per voxel. With 1 channel it is the value; with 3 channels it is the
//! luminance 0.212671 R + 0.715160 G + 0.072169 B and with 6 the mean, as Mitsuba's grid volume
//! gives when a scalar is asked of it (`GridVolume::eval_1`). Other channel counts are refused.

use super::file::{Cursor, GridFormatError, GridLimits};
use super::grid::DensityGrid;
use crate::geometry::Aabb;
use glam::Vec3A;

/// Size of the header in bytes.
const HEADER_BYTES: usize = 48;

/// Reads a `.vol` file's bytes into a density grid, within `limits`.
pub fn read_vol(bytes: &[u8], limits: &GridLimits) -> Result<DensityGrid, GridFormatError> {
    let invalid = |m: String| GridFormatError::Invalid(m);
    let mut c = Cursor::new(bytes);
    if c.take(3, "the VOL signature")? != b"VOL" {
        return Err(invalid("not a .vol file (no VOL signature)".into()));
    }
    let version = c.u8("the version")?;
    if version != 3 {
        return Err(GridFormatError::Unsupported(format!(
            ".vol version {version} (only version 3 is defined)"
        )));
    }
    let encoding = c.i32("the encoding")?;
    if encoding != 1 {
        return Err(GridFormatError::Unsupported(format!(
            ".vol encoding {encoding} (only 1, float32, is supported)"
        )));
    }
    let mut res = [0usize; 3];
    for (k, r) in res.iter_mut().enumerate() {
        let v = c.i32("the resolution")?;
        if v < 1 {
            return Err(invalid(format!("resolution {v} along axis {k}")));
        }
        *r = v as usize;
    }
    let channels = c.i32("the channel count")?;
    if !matches!(channels, 1 | 3 | 6) {
        return Err(GridFormatError::Unsupported(format!(
            "{channels} channels (a density grid has 1, 3 or 6)"
        )));
    }
    let channels = channels as usize;
    let mut b = [0f32; 6];
    for v in &mut b {
        *v = c.f32("the bounding box")?;
    }
    // Each resolution is below 2³¹, so the product fits in 128 bits.
    let voxels = res.iter().map(|&r| r as u128).product::<u128>();
    if voxels > limits.max_voxels as u128 {
        return Err(GridFormatError::TooLarge {
            what: format!("the {}x{}x{} grid", res[0], res[1], res[2]),
            count: voxels.min(u64::MAX as u128) as u64,
            limit: limits.max_voxels,
        });
    }
    let data_bytes = voxels * channels as u128 * 4;
    if data_bytes != (bytes.len() - HEADER_BYTES) as u128 {
        return Err(invalid(format!(
            "the header announces {data_bytes} bytes of voxel data ({}x{}x{}, {channels} \
             channels), the file has {}",
            res[0],
            res[1],
            res[2],
            bytes.len() - HEADER_BYTES
        )));
    }
    let data = c.take(data_bytes as usize, "the voxel data")?;
    let mut values = Vec::with_capacity(voxels as usize);
    for voxel in data.chunks_exact(4 * channels) {
        let ch = |i: usize| {
            f32::from_le_bytes([
                voxel[4 * i],
                voxel[4 * i + 1],
                voxel[4 * i + 2],
                voxel[4 * i + 3],
            ])
        };
        values.push(match channels {
            1 => ch(0),
            3 => 0.212_671 * ch(0) + 0.715_160 * ch(1) + 0.072_169 * ch(2),
            // In f64: six finite values near f32's largest would sum to infinity in f32.
            _ => ((0..6).map(|i| f64::from(ch(i))).sum::<f64>() / 6.0) as f32,
        });
    }
    let bounds = Aabb::new(Vec3A::new(b[0], b[1], b[2]), Vec3A::new(b[3], b[4], b[5]));
    DensityGrid::new(res, bounds, values).map_err(|e| invalid(e.to_string()))
}

/// Writes `grid` as a one-channel `.vol` file (for tools, tests and example scenes).
pub fn write_vol(grid: &DensityGrid) -> Vec<u8> {
    let res = grid.resolution();
    let b = grid.bounds();
    let mut out = Vec::with_capacity(HEADER_BYTES + 4 * grid.values().len());
    out.extend_from_slice(b"VOL");
    out.push(3);
    out.extend_from_slice(&1i32.to_le_bytes());
    for r in res {
        out.extend_from_slice(&(r as i32).to_le_bytes());
    }
    out.extend_from_slice(&1i32.to_le_bytes());
    for v in [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in grid.values() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `.vol` file built field by field, as Mitsuba's `VolumeGrid::write` lays it out.
    fn vol_bytes(res: [i32; 3], channels: i32, bbox: [f32; 6], data: &[f32]) -> Vec<u8> {
        let mut out = b"VOL\x03".to_vec();
        for v in [1, res[0], res[1], res[2], channels] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in bbox.iter().chain(data) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    fn limits() -> GridLimits {
        GridLimits::default()
    }

    #[test]
    fn reads_values_x_fastest_and_the_box() {
        let data: Vec<f32> = (0..24).map(|i| i as f32).collect();
        let bytes = vol_bytes([2, 3, 4], 1, [-1.0, 0.0, 2.0, 1.0, 3.0, 6.0], &data);
        let g = read_vol(&bytes, &limits()).unwrap();
        assert_eq!(g.resolution(), [2, 3, 4]);
        assert_eq!(g.bounds().min, Vec3A::new(-1.0, 0.0, 2.0));
        assert_eq!(g.bounds().max, Vec3A::new(1.0, 3.0, 6.0));
        // ((z·yres + y)·xres + x)
        assert_eq!(g.voxel(1, 0, 0), 1.0);
        assert_eq!(g.voxel(0, 1, 0), 2.0);
        assert_eq!(g.voxel(0, 0, 1), 6.0);
        assert_eq!(g.voxel(1, 2, 3), 23.0);
        // Voxel (1, 2, 3)'s centre is at min + (1.5, 2.5, 3.5) · size / res.
        assert_eq!(g.density(Vec3A::new(0.5, 2.5, 5.5)), 23.0);
    }

    #[test]
    fn colour_grids_give_mitsubas_scalar() {
        let bytes = vol_bytes(
            [1, 1, 1],
            3,
            [0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
            &[1.0, 2.0, 4.0],
        );
        let g = read_vol(&bytes, &limits()).unwrap();
        let want = 0.212_671 + 0.715_160 * 2.0 + 0.072_169 * 4.0;
        assert!((g.voxel(0, 0, 0) - want).abs() < 1e-6);
        let bytes = vol_bytes(
            [1, 1, 1],
            6,
            [0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
            &[1.0, 2.0, 3.0, 4.0, 5.0, 9.0],
        );
        assert_eq!(read_vol(&bytes, &limits()).unwrap().voxel(0, 0, 0), 4.0);
        // Six values near f32's largest: their mean, not an overflow to infinity.
        let big = f32::MAX / 2.0;
        let bytes = vol_bytes([1, 1, 1], 6, [0.0, 0.0, 0.0, 1.0, 1.0, 1.0], &[big; 6]);
        assert_eq!(read_vol(&bytes, &limits()).unwrap().voxel(0, 0, 0), big);
    }

    #[test]
    fn write_then_read_is_the_identity() {
        let n = super::super::NoiseDensity::default();
        let g = DensityGrid::from_fn(
            [7, 5, 3],
            Aabb::new(Vec3A::new(-1.0, -2.0, -3.0), Vec3A::new(1.0, 2.0, 3.0)),
            |p| n.density(p),
        )
        .unwrap();
        assert_eq!(read_vol(&write_vol(&g), &limits()).unwrap(), g);
    }

    #[test]
    fn bad_headers_are_errors() {
        let good = vol_bytes([2, 2, 2], 1, [0.0, 0.0, 0.0, 1.0, 1.0, 1.0], &[0.5; 8]);
        assert!(read_vol(&good, &limits()).is_ok());
        let check = |bytes: &[u8], want: &str| {
            let err = read_vol(bytes, &limits()).unwrap_err().to_string();
            assert!(err.contains(want), "{err:?} should mention {want:?}");
        };
        check(b"", "truncated");
        check(b"VOX\x03", "signature");
        let mut v = good.clone();
        v[3] = 2;
        check(&v, "version 2");
        let mut v = good.clone();
        v[4] = 2;
        check(&v, "encoding 2");
        check(
            &vol_bytes([2, 0, 2], 1, [0.0, 0.0, 0.0, 1.0, 1.0, 1.0], &[]),
            "resolution 0",
        );
        check(
            &vol_bytes([2, -5, 2], 1, [0.0, 0.0, 0.0, 1.0, 1.0, 1.0], &[]),
            "resolution -5",
        );
        check(
            &vol_bytes([1, 1, 1], 2, [0.0, 0.0, 0.0, 1.0, 1.0, 1.0], &[0.0; 2]),
            "2 channels",
        );
        check(&good[..good.len() - 1], "announces 32 bytes");
        let mut long = good.clone();
        long.push(0);
        check(&long, "announces 32 bytes");
        check(
            &vol_bytes([2, 2, 2], 1, [0.0, 0.0, 0.0, 1.0, -1.0, 1.0], &[0.5; 8]),
            "box",
        );
        check(
            &vol_bytes([2, 2, 2], 1, [0.0, 0.0, 0.0, 1.0, f32::NAN, 1.0], &[0.5; 8]),
            "box",
        );
        check(
            &vol_bytes([1, 1, 2], 1, [0.0, 0.0, 0.0, 1.0, 1.0, 1.0], &[0.5, -1.0]),
            "(0, 0, 1)",
        );
        // A header claiming 2³¹ voxels per axis is refused before anything is allocated.
        check(
            &vol_bytes(
                [i32::MAX, i32::MAX, i32::MAX],
                1,
                [0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
                &[],
            ),
            "more than the limit",
        );
        let small = GridLimits {
            max_voxels: 7,
            ..GridLimits::default()
        };
        assert!(matches!(
            read_vol(&good, &small),
            Err(GridFormatError::TooLarge { count: 8, .. })
        ));
    }

    #[test]
    fn truncated_and_corrupted_files_never_panic() {
        let n = super::super::NoiseDensity::default();
        let g = DensityGrid::from_fn([4, 3, 2], Aabb::new(Vec3A::ZERO, Vec3A::ONE), |p| {
            n.density(p)
        })
        .unwrap();
        let good = write_vol(&g);
        for cut in 0..good.len() {
            assert!(read_vol(&good[..cut], &limits()).is_err(), "cut at {cut}");
        }
        // Every header byte set to a few hostile values: an error or a grid, never a panic.
        for i in 0..HEADER_BYTES {
            for v in [0u8, 1, 0x7f, 0x80, 0xff] {
                let mut b = good.clone();
                b[i] = v;
                let _ = read_vol(&b, &limits());
            }
        }
    }
}
