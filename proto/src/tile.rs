//! The binary tile-result format.
//!
//! A result is a 40-byte header followed by the pixels, everything little-endian:
//!
//! | bytes | field |
//! | --- | --- |
//! | 0..4 | magic `RTTR` |
//! | 4..8 | format version (2) |
//! | 8..24 | tile `x0`, `y0`, `x1`, `y1` (u32 each) |
//! | 24..28 | pass index (u32) |
//! | 28..32 | number of splats `n` (u32; zero but for `bdpt`) |
//! | 32..40 | samples dropped as NaN/Inf (u64) |
//! | 40.. | `[r, g, b, w]` f32 sums per pixel, row-major, `width × height` pixels |
//! | then | `n` splats: frame pixel index (u32) and `[r, g, b]` fixed-point sums (i128 each, value × 2^[`SPLAT_FRACTION_BITS`]) |
//!
//! Floats travel as their exact bits, so the coordinator stores what the worker computed.
//! Version 1 (stored by coordinators before render version 18) had splats of three i64 at
//! 2^28; [`decode`] reads it still, shifting its splats exactly to the current scale.

use crate::settings::Tile;
pub use crate::settings::MAX_TILE_EDGE;

/// Per-pixel sums of one tile over one range of samples: RGB sum and weight sum, plus the
/// count of NaN/Inf samples that were dropped. What a worker renders, uploads and the
/// coordinator adds into the frame (the tracer's film re-exports it).
#[derive(Clone, Debug, PartialEq)]
pub struct TileAccum {
    /// The pixels covered.
    pub tile: Tile,
    /// Row-major [r, g, b, weight] sums.
    pub pixels: Vec<[f32; 4]>,
    /// Samples dropped because they were NaN or infinite.
    pub bad_samples: u64,
    /// Light that the tile's samples carried to other pixels (`bdpt`'s light subpaths joined
    /// to the camera): (row-major pixel index in the whole frame, RGB in fixed point, scaled
    /// by 2^[`SPLAT_FRACTION_BITS`]), sorted by pixel, one entry per pixel. Integer sums, so
    /// adding them in any order gives the same bits. Empty for every other integrator.
    pub splats: Vec<(u32, [i128; 3])>,
    /// Row-major count of each pixel's samples whose camera ray met the scene (did not leave it
    /// straight for the environment), for a job with an alpha channel
    /// (`RenderSettings::alpha`): a pixel's alpha is its coverage over its weight. Whole
    /// numbers, so sums are exact. Empty for a job without alpha.
    pub coverage: Vec<f32>,
}

/// Bits after the binary point of a splat's fixed-point value: a channel value `v` travels as
/// `round(v · 2^56)` in an i128, so sums keep 2^-56 (about 1.4·10⁻¹⁷) and reach 2^71 (about
/// 2.4·10²¹) before they saturate: 37 decades, where the i64 at 2^28 of format version 1
/// kept 19 and lost the light of very dim or very bright scenes.
pub const SPLAT_FRACTION_BITS: u32 = 56;

/// Bytes of one splat on the wire.
pub const SPLAT_LEN: usize = 4 + 3 * 16;

/// Bytes of one splat in format version 1, and the bits after its binary point.
const V1_SPLAT_LEN: usize = 4 + 3 * 8;
const V1_FRACTION_BITS: u32 = 28;

/// First four bytes of every tile result.
pub const MAGIC: [u8; 4] = *b"RTTR";
/// Version of the format written by [`encode`] for a result without coverage; one with
/// coverage (a job with an alpha channel) is written as [`VERSION_COVERAGE`].
pub const VERSION: u32 = 2;
/// Version of a result that carries coverage: version 2's layout with one f32 per pixel after
/// the pixels, before the splats. Results without coverage are still written as version 2, so
/// that a coordinator of an earlier release reads every result it can use.
pub const VERSION_COVERAGE: u32 = 3;
/// Size of the header in bytes.
pub const HEADER_LEN: usize = 40;

/// Why bytes are not a valid tile result.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum TileFormatError {
    /// Fewer bytes than a header.
    #[error("tile result is {0} bytes, shorter than the {HEADER_LEN}-byte header")]
    Short(usize),
    /// The magic bytes are wrong.
    #[error("tile result does not start with the magic bytes RTTR")]
    Magic,
    /// An unknown format version.
    #[error("unsupported tile result version {0} (expected 1, {VERSION} or {VERSION_COVERAGE})")]
    Version(u32),
    /// The rectangle is empty, inverted or too large.
    #[error("bad tile rectangle [{0}, {2}) × [{1}, {3})")]
    Rect(u32, u32, u32, u32),
    /// The pixel data does not match the rectangle's size.
    #[error("tile result has {got} bytes of pixels, expected {expected}")]
    Length {
        /// Bytes needed for the rectangle.
        expected: usize,
        /// Bytes present.
        got: usize,
    },
}

/// The total encoded size of a result for `tile` without splats, with or without coverage.
pub fn encoded_len(tile: &Tile, coverage: bool) -> usize {
    HEADER_LEN + tile.pixel_count() * if coverage { 20 } else { 16 }
}

/// Encodes a tile result for `pass`. Coverage, when present, has one value per pixel
/// (otherwise [`decode`] refuses the bytes).
pub fn encode(accum: &TileAccum, pass: u32) -> Vec<u8> {
    let t = accum.tile;
    let with_coverage = !accum.coverage.is_empty();
    let mut out = Vec::with_capacity(
        encoded_len(&t, false) + accum.coverage.len() * 4 + accum.splats.len() * SPLAT_LEN,
    );
    out.extend_from_slice(&MAGIC);
    let n = accum.splats.len() as u32;
    let version = if with_coverage {
        VERSION_COVERAGE
    } else {
        VERSION
    };
    for v in [version, t.x0, t.y0, t.x1, t.y1, pass, n] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&accum.bad_samples.to_le_bytes());
    for p in &accum.pixels {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    for c in &accum.coverage {
        out.extend_from_slice(&c.to_le_bytes());
    }
    for (i, rgb) in &accum.splats {
        out.extend_from_slice(&i.to_le_bytes());
        for c in rgb {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    out
}

/// Decodes a tile result, checking every length; returns the sums and the pass index.
pub fn decode(bytes: &[u8]) -> Result<(TileAccum, u32), TileFormatError> {
    if bytes.len() < HEADER_LEN {
        return Err(TileFormatError::Short(bytes.len()));
    }
    if bytes[0..4] != MAGIC {
        return Err(TileFormatError::Magic);
    }
    let u = |i: usize| u32::from_le_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
    let version = u(4);
    let splat_len = match version {
        VERSION | VERSION_COVERAGE => SPLAT_LEN,
        1 => V1_SPLAT_LEN,
        _ => return Err(TileFormatError::Version(version)),
    };
    let (x0, y0, x1, y1) = (u(8), u(12), u(16), u(20));
    if x1 <= x0 || y1 <= y0 || x1 - x0 > MAX_TILE_EDGE || y1 - y0 > MAX_TILE_EDGE {
        return Err(TileFormatError::Rect(x0, y0, x1, y1));
    }
    let pass = u(24);
    let mut bad = [0u8; 8];
    bad.copy_from_slice(&bytes[32..40]);
    let tile = Tile { x0, y0, x1, y1 };
    let n_splats = u(28) as usize;
    let pixel_bytes = tile.pixel_count() * 16;
    let coverage_bytes = if version == VERSION_COVERAGE {
        tile.pixel_count() * 4
    } else {
        0
    };
    let expected = n_splats
        .checked_mul(splat_len)
        .and_then(|b| b.checked_add(pixel_bytes + coverage_bytes))
        .unwrap_or(usize::MAX);
    let body = &bytes[HEADER_LEN..];
    if body.len() != expected {
        return Err(TileFormatError::Length {
            expected,
            got: body.len(),
        });
    }
    let (body, rest) = body.split_at(pixel_bytes);
    let (coverage_bytes, splat_bytes) = rest.split_at(coverage_bytes);
    let coverage = coverage_bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let splats = splat_bytes
        .chunks_exact(splat_len)
        .map(|b| {
            let i = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            let c = |k: usize| {
                if version == 1 {
                    let mut v = [0u8; 8];
                    v.copy_from_slice(&b[4 + 8 * k..12 + 8 * k]);
                    // Exact: an i64 shifted by 28 bits fits an i128.
                    i128::from(i64::from_le_bytes(v)) << (SPLAT_FRACTION_BITS - V1_FRACTION_BITS)
                } else {
                    let mut v = [0u8; 16];
                    v.copy_from_slice(&b[4 + 16 * k..20 + 16 * k]);
                    i128::from_le_bytes(v)
                }
            };
            (i, [c(0), c(1), c(2)])
        })
        .collect();
    let pixels = body
        .chunks_exact(16)
        .map(|px| {
            let f = |i: usize| f32::from_le_bytes([px[i], px[i + 1], px[i + 2], px[i + 3]]);
            [f(0), f(4), f(8), f(12)]
        })
        .collect();
    Ok((
        TileAccum {
            tile,
            pixels,
            bad_samples: u64::from_le_bytes(bad),
            splats,
            coverage,
        },
        pass,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> TileAccum {
        let tile = Tile {
            x0: 3,
            y0: 5,
            x1: 6,
            y1: 7,
        };
        TileAccum {
            tile,
            pixels: (0..6)
                .map(|i| [i as f32, -0.0, f32::MIN_POSITIVE, 1e30])
                .collect(),
            bad_samples: 7,
            splats: Vec::new(),
            coverage: Vec::new(),
        }
    }

    /// A result with coverage is version 3: the coverage after the pixels, the splats after it;
    /// without coverage it stays version 2, byte for byte what an earlier release wrote.
    #[test]
    fn coverage_travels_between_pixels_and_splats() {
        let plain = encode(&sample(), 4);
        assert_eq!(u32::from_le_bytes(plain[4..8].try_into().unwrap()), VERSION);
        let mut a = sample();
        a.coverage = vec![0.0, 1.0, 2.0, 3.0, 16_777_216.0, 5.0];
        a.splats = vec![(7, [1, 2, 3])];
        let bytes = encode(&a, 4);
        assert_eq!(
            u32::from_le_bytes(bytes[4..8].try_into().unwrap()),
            VERSION_COVERAGE
        );
        assert_eq!(bytes.len(), encoded_len(&a.tile, true) + SPLAT_LEN);
        // The header (apart from the version and the splat count) and the pixels as before.
        assert_eq!(bytes[8..28], plain[8..28]);
        assert_eq!(bytes[32..plain.len()], plain[32..]);
        let (b, pass) = decode(&bytes).unwrap();
        assert_eq!((pass, &b), (4, &a));
        // The coverage is part of the length: one value short is refused, as is a version 2
        // header on the longer body.
        assert!(matches!(
            decode(&bytes[..bytes.len() - 1]),
            Err(TileFormatError::Length { .. })
        ));
        let mut v2 = bytes.clone();
        v2[4..8].copy_from_slice(&VERSION.to_le_bytes());
        assert!(matches!(decode(&v2), Err(TileFormatError::Length { .. })));
        // Coverage of the wrong length is written as given and refused when read.
        a.coverage.pop();
        assert!(matches!(
            decode(&encode(&a, 4)),
            Err(TileFormatError::Length { .. })
        ));
    }

    #[test]
    fn splats_travel_after_the_pixels() {
        let mut a = sample();
        a.splats = vec![(0, [1, -2, i128::MAX]), (99, [i128::MIN, 0, 5])];
        let bytes = encode(&a, 1);
        assert_eq!(bytes.len(), encoded_len(&a.tile, false) + 2 * SPLAT_LEN);
        let (b, pass) = decode(&bytes).unwrap();
        assert_eq!((pass, &b.splats), (1, &a.splats));
        // A splat count that the body does not hold is refused.
        let mut short = bytes.clone();
        short[28..32].copy_from_slice(&3u32.to_le_bytes());
        assert!(matches!(
            decode(&short),
            Err(TileFormatError::Length { .. })
        ));
        let mut huge = bytes;
        huge[28..32].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(decode(&huge), Err(TileFormatError::Length { .. })));
    }

    /// A result stored in format version 1 (splats of i64 at 2^28) reads as the same values
    /// at the current scale.
    #[test]
    fn version_1_results_still_read() {
        let a = sample();
        let mut bytes = encode(&a, 3);
        bytes[4..8].copy_from_slice(&1u32.to_le_bytes());
        bytes[28..32].copy_from_slice(&2u32.to_le_bytes());
        for (i, rgb) in [(4u32, [1i64, -3, i64::MAX]), (9, [0, i64::MIN, 1 << 40])] {
            bytes.extend_from_slice(&i.to_le_bytes());
            for c in rgb {
                bytes.extend_from_slice(&c.to_le_bytes());
            }
        }
        let (b, pass) = decode(&bytes).unwrap();
        assert_eq!(pass, 3);
        let k = 1i128 << 28;
        assert_eq!(
            b.splats,
            [
                (4, [k, -3 * k, i128::from(i64::MAX) * k]),
                (9, [0, i128::from(i64::MIN) * k, (1 << 40) * k])
            ]
        );
        bytes[4..8].copy_from_slice(&4u32.to_le_bytes());
        assert_eq!(decode(&bytes).unwrap_err(), TileFormatError::Version(4));
    }

    #[test]
    fn round_trip_keeps_bits() {
        let a = sample();
        let bytes = encode(&a, 2);
        assert_eq!(bytes.len(), encoded_len(&a.tile, false));
        let (b, pass) = decode(&bytes).unwrap();
        assert_eq!(pass, 2);
        assert_eq!(b.tile, a.tile);
        assert_eq!(b.bad_samples, 7);
        let bits = |t: &TileAccum| -> Vec<u32> {
            t.pixels.iter().flatten().map(|f| f.to_bits()).collect()
        };
        assert_eq!(bits(&a), bits(&b));
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let good = encode(&sample(), 0);
        assert_eq!(decode(&good[..10]).unwrap_err(), TileFormatError::Short(10));
        assert!(matches!(
            decode(&good[..good.len() - 1]),
            Err(TileFormatError::Length { .. })
        ));
        let mut bad = good.clone();
        bad[0] = b'X';
        assert_eq!(decode(&bad).unwrap_err(), TileFormatError::Magic);
        let mut inverted = good.clone();
        inverted[16..20].copy_from_slice(&0u32.to_le_bytes());
        assert!(matches!(decode(&inverted), Err(TileFormatError::Rect(..))));
        let mut huge = good;
        huge[16..20].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(decode(&huge), Err(TileFormatError::Rect(..))));
    }
}
