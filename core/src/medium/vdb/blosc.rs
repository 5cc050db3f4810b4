//! The decompression OpenVDB's files need: Blosc 1 chunks (the container OpenVDB writes with
//! the LZ4 codec and byte shuffling), raw LZ4 blocks, and zlib streams.
//!
//! Written here, in safe Rust with every length checked, rather than linked from C-Blosc: a
//! grid file is untrusted input, and a hostile chunk must be an error, never a read or write
//! out of bounds. Blosc's `blosclz`, Snappy and Zstandard codecs and its bit shuffle are not
//! supported (OpenVDB asks Blosc for LZ4 with byte shuffling); they are refused by name.

use super::super::file::GridFormatError;

/// Blosc header flags.
const DOSHUFFLE: u8 = 0x01;
const MEMCPYED: u8 = 0x02;
const DOBITSHUFFLE: u8 = 0x04;
const DONT_SPLIT: u8 = 0x10;
/// Blosc splits a block into one stream per byte of the type only for types up to this size
/// and blocks of at least `MIN_BUFFERSIZE` elements (c-blosc's `blosc_d`).
const MAX_SPLITS: usize = 16;
const MIN_BUFFERSIZE: usize = 128;

fn invalid(what: String) -> GridFormatError {
    GridFormatError::Invalid(format!("Blosc chunk: {what}"))
}

/// Decompresses one Blosc 1 chunk that must hold exactly `expected` bytes.
pub(crate) fn blosc_decompress(src: &[u8], expected: usize) -> Result<Vec<u8>, GridFormatError> {
    if src.len() < 16 {
        return Err(invalid(format!(
            "{} bytes, shorter than its header",
            src.len()
        )));
    }
    let u32_at = |i: usize| u32::from_le_bytes([src[i], src[i + 1], src[i + 2], src[i + 3]]);
    let (version, flags, typesize) = (src[0], src[2], src[3] as usize);
    let nbytes = u32_at(4) as usize;
    let blocksize = u32_at(8) as usize;
    let cbytes = u32_at(12) as usize;
    if !(1..=2).contains(&version) {
        return Err(GridFormatError::Unsupported(format!(
            "Blosc format version {version}"
        )));
    }
    if nbytes != expected {
        return Err(invalid(format!(
            "holds {nbytes} bytes, {expected} expected"
        )));
    }
    if cbytes > src.len() {
        return Err(invalid(format!(
            "says {cbytes} bytes, {} present",
            src.len()
        )));
    }
    if flags & MEMCPYED != 0 {
        let data = src
            .get(16..16 + nbytes)
            .ok_or_else(|| invalid("uncompressed data truncated".into()))?;
        return Ok(data.to_vec());
    }
    if flags & DOBITSHUFFLE != 0 && typesize > 1 {
        return Err(GridFormatError::Unsupported("Blosc bit shuffle".into()));
    }
    let codec = flags >> 5;
    if codec != 1 && codec != 3 {
        let name = match codec {
            0 => "blosclz",
            2 => "snappy",
            4 => "zstd",
            _ => "an unknown codec",
        };
        return Err(GridFormatError::Unsupported(format!(
            "Blosc codec {name} (LZ4 and zlib are read)"
        )));
    }
    if nbytes == 0 {
        return Ok(Vec::new());
    }
    if blocksize == 0 || typesize == 0 {
        return Err(invalid(format!(
            "block size {blocksize}, type size {typesize}"
        )));
    }
    let nblocks = nbytes.div_ceil(blocksize);
    let leftover = nbytes % blocksize;
    let starts = src
        .get(16..16 + 4 * nblocks)
        .ok_or_else(|| invalid("block offsets truncated".into()))?;
    let mut out = Vec::with_capacity(nbytes);
    let mut block = Vec::with_capacity(blocksize);
    for j in 0..nblocks {
        let last_leftover = j == nblocks - 1 && leftover > 0;
        let bsize = if last_leftover { leftover } else { blocksize };
        let split = flags & DONT_SPLIT == 0
            && typesize <= MAX_SPLITS
            && bsize / typesize >= MIN_BUFFERSIZE
            && !last_leftover;
        let nsplits = if split { typesize } else { 1 };
        let neblock = bsize / nsplits;
        if neblock * nsplits != bsize {
            return Err(invalid(format!(
                "block of {bsize} bytes in {nsplits} streams"
            )));
        }
        let s = &starts[4 * j..4 * j + 4];
        let mut pos = u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize;
        block.clear();
        for _ in 0..nsplits {
            let len = src
                .get(pos..pos + 4)
                .ok_or_else(|| invalid(format!("stream header at {pos} out of bounds")))?;
            let csize = i32::from_le_bytes([len[0], len[1], len[2], len[3]]);
            pos += 4;
            let csize =
                usize::try_from(csize).map_err(|_| invalid(format!("stream of {csize} bytes")))?;
            let data = src.get(pos..pos.saturating_add(csize)).ok_or_else(|| {
                invalid(format!("stream of {csize} bytes at {pos} out of bounds"))
            })?;
            pos += csize;
            if csize == neblock {
                block.extend_from_slice(data);
            } else if codec == 1 {
                lz4_decompress(data, &mut block, neblock)?;
            } else {
                block.extend_from_slice(&zlib_decompress(data, neblock)?);
            }
        }
        if flags & DOSHUFFLE != 0 && typesize > 1 {
            unshuffle(&block, typesize, &mut out);
        } else {
            out.extend_from_slice(&block);
        }
    }
    Ok(out)
}

/// Undoes Blosc's byte shuffle of one block: byte `b` of element `i` was stored at
/// `b · n + i` (n elements); trailing bytes that make no whole element stay in place.
fn unshuffle(src: &[u8], typesize: usize, out: &mut Vec<u8>) {
    let n = src.len() / typesize;
    for i in 0..n {
        for b in 0..typesize {
            out.push(src[b * n + i]);
        }
    }
    out.extend_from_slice(&src[n * typesize..]);
}

/// Decompresses one raw LZ4 block that must produce exactly `expected` bytes, appending them
/// to `out`.
pub(crate) fn lz4_decompress(
    src: &[u8],
    out: &mut Vec<u8>,
    expected: usize,
) -> Result<(), GridFormatError> {
    let bad = |m: &str| invalid(format!("LZ4 block: {m}"));
    let start = out.len();
    let mut i = 0usize;
    // A length: the token's nibble, then bytes of 255 that continue it.
    let read_len = |i: &mut usize, mut len: usize| -> Result<usize, GridFormatError> {
        if len == 15 {
            loop {
                let b = *src.get(*i).ok_or_else(|| bad("length runs past the end"))?;
                *i += 1;
                len += b as usize;
                if b != 255 {
                    break;
                }
            }
        }
        Ok(len)
    };
    loop {
        let token = *src.get(i).ok_or_else(|| bad("missing token"))?;
        i += 1;
        let lit = read_len(&mut i, (token >> 4) as usize)?;
        let literals = src
            .get(i..i.saturating_add(lit))
            .ok_or_else(|| bad("literals run past the end"))?;
        if out.len() - start + lit > expected {
            return Err(bad("output larger than announced"));
        }
        out.extend_from_slice(literals);
        i += lit;
        if i == src.len() {
            break;
        }
        let off = src
            .get(i..i + 2)
            .ok_or_else(|| bad("offset runs past the end"))?;
        let offset = u16::from_le_bytes([off[0], off[1]]) as usize;
        i += 2;
        let len = read_len(&mut i, (token & 15) as usize)? + 4;
        let produced = out.len() - start;
        if offset == 0 || offset > produced {
            return Err(bad("match offset outside the output"));
        }
        if produced + len > expected {
            return Err(bad("output larger than announced"));
        }
        let from = out.len() - offset;
        if offset >= len {
            out.extend_from_within(from..from + len);
        } else {
            // Overlapping match: a run that repeats the last `offset` bytes.
            for k in 0..len {
                out.push(out[from + k]);
            }
        }
    }
    if out.len() - start != expected {
        return Err(bad("output shorter than announced"));
    }
    Ok(())
}

/// Inflates a zlib stream that must produce exactly `expected` bytes.
pub(crate) fn zlib_decompress(src: &[u8], expected: usize) -> Result<Vec<u8>, GridFormatError> {
    let out = miniz_oxide::inflate::decompress_to_vec_zlib_with_limit(src, expected)
        .map_err(|e| GridFormatError::Invalid(format!("zlib data: {e}")))?;
    if out.len() != expected {
        return Err(GridFormatError::Invalid(format!(
            "zlib data holds {} bytes, {expected} expected",
            out.len()
        )));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An LZ4 block by hand: literals "abcd", then a match of 9 bytes at offset 4 (overlapping:
    /// "abcdabcda"), then the literals "XY".
    fn lz4_sample() -> (Vec<u8>, Vec<u8>) {
        let mut src = vec![(4 << 4) | (9 - 4)];
        src.extend_from_slice(b"abcd");
        src.extend_from_slice(&4u16.to_le_bytes());
        src.push(2 << 4);
        src.extend_from_slice(b"XY");
        (src, b"abcdabcdabcdaXY".to_vec())
    }

    #[test]
    fn lz4_blocks_decode_with_overlapping_matches() {
        let (src, want) = lz4_sample();
        let mut out = Vec::new();
        lz4_decompress(&src, &mut out, want.len()).unwrap();
        assert_eq!(out, want);
        // Long literal runs use continuation bytes: 15 + 255 + 10 = 280 literals.
        let mut long = vec![0xf0, 255, 10];
        long.extend((0..280).map(|i| i as u8));
        let mut out = Vec::new();
        lz4_decompress(&long, &mut out, 280).unwrap();
        assert_eq!(out.len(), 280);
        assert_eq!(out[279], (279 % 256) as u8);
    }

    #[test]
    fn hostile_lz4_blocks_are_errors() {
        let (src, want) = lz4_sample();
        let mut out = Vec::new();
        assert!(lz4_decompress(&src, &mut out, want.len() - 1).is_err());
        for cut in 0..src.len() {
            let mut out = Vec::new();
            assert!(
                lz4_decompress(&src[..cut], &mut out, want.len()).is_err(),
                "cut {cut}"
            );
        }
        // Offset 0 and offsets before the start of the output.
        let mut bad = src.clone();
        bad[5] = 0;
        assert!(lz4_decompress(&bad, &mut Vec::new(), want.len()).is_err());
        bad[5] = 200;
        assert!(lz4_decompress(&bad, &mut Vec::new(), want.len()).is_err());
        // A huge announced literal run: refused, nothing allocated for it.
        let huge = [0xf0, 255, 255, 255, 255, 255, 0];
        assert!(lz4_decompress(&huge, &mut Vec::new(), 100).is_err());
    }

    /// A Blosc chunk around one LZ4 stream, with byte shuffling of 4-byte elements.
    fn blosc_chunk(values: &[f32]) -> Vec<u8> {
        let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let n = values.len();
        let mut shuffled = vec![0u8; raw.len()];
        for i in 0..n {
            for b in 0..4 {
                shuffled[b * n + i] = raw[4 * i + b];
            }
        }
        // The stream stores everything as literals (a valid, if poor, LZ4 block).
        let mut lz = Vec::new();
        let lit = shuffled.len();
        if lit >= 15 {
            lz.push(0xf0);
            let mut rest = lit - 15;
            while rest >= 255 {
                lz.push(255);
                rest -= 255;
            }
            lz.push(rest as u8);
        } else {
            lz.push((lit as u8) << 4);
        }
        lz.extend_from_slice(&shuffled);
        let mut out = vec![2, 1, DOSHUFFLE | DONT_SPLIT | (1 << 5), 4];
        out.extend_from_slice(&(raw.len() as u32).to_le_bytes());
        out.extend_from_slice(&(raw.len() as u32).to_le_bytes());
        let total = 16 + 4 + 4 + lz.len();
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&20u32.to_le_bytes());
        out.extend_from_slice(&(lz.len() as i32).to_le_bytes());
        out.extend_from_slice(&lz);
        out
    }

    #[test]
    fn blosc_chunks_unshuffle() {
        let values: Vec<f32> = (0..100).map(|i| i as f32 * 0.25 - 3.0).collect();
        let chunk = blosc_chunk(&values);
        let out = blosc_decompress(&chunk, 400).unwrap();
        let back: Vec<f32> = out
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        assert_eq!(back, values);
        assert!(blosc_decompress(&chunk, 404).is_err());
    }

    #[test]
    fn hostile_blosc_chunks_are_errors_not_panics() {
        let values: Vec<f32> = (0..50).map(|i| i as f32).collect();
        let chunk = blosc_chunk(&values);
        for cut in 0..chunk.len() {
            assert!(blosc_decompress(&chunk[..cut], 200).is_err(), "cut {cut}");
        }
        for i in 0..24 {
            for v in [0u8, 1, 0x7f, 0x80, 0xff] {
                let mut b = chunk.clone();
                b[i] = v;
                let _ = blosc_decompress(&b, 200);
            }
        }
        let mut zstd = chunk.clone();
        zstd[2] = DOSHUFFLE | (4 << 5);
        let err = blosc_decompress(&zstd, 200).unwrap_err().to_string();
        assert!(err.contains("zstd"), "{err}");
    }

    #[test]
    fn zlib_streams_inflate_to_the_announced_size() {
        let data: Vec<u8> = (0..1000u32).map(|i| (i % 7) as u8).collect();
        let z = miniz_oxide::deflate::compress_to_vec_zlib(&data, 6);
        assert_eq!(zlib_decompress(&z, 1000).unwrap(), data);
        assert!(zlib_decompress(&z, 999).is_err());
        assert!(zlib_decompress(&z, 1001).is_err());
        assert!(zlib_decompress(&z[..z.len() / 2], 1000).is_err());
    }
}
