//! Image files for the scene front ends: one decoder with one set of limits, for the textures
//! and environment maps of JSON scenes and the images of glTF files (PNG, JPEG, Radiance HDR,
//! OpenEXR, the format found from the bytes).
//!
//! Limits: at most [`MAX_IMAGE_SIDE`] pixels on a side and [`MAX_IMAGE_PIXELS`] in all (an
//! 8-bit image keeps its RGBA bytes, 256 MiB at the limit; others are kept as f32 RGBA, 16
//! bytes a texel, 1 GiB at the limit), the decoder's allocations capped likewise, files read up to [`MAX_IMAGE_FILE`] (by the scene's resolver,
//! `scene::files`). A larger image is an error, never an allocation failure.

use crate::texture::Texels;
use image::ImageDecoder;

/// Largest accepted image side, in pixels.
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// Largest accepted image area, in pixels (8192², or 16384 × 4096): 1 GiB of f32 RGBA texels,
/// 256 MiB of 8-bit ones.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 26;
/// Largest image file read, in bytes.
pub const MAX_IMAGE_FILE: u64 = 1 << 30;
/// Largest allocation the decoder may make, in bytes.
const MAX_DECODE_ALLOC: u64 = 1 << 30;

/// A decoded image: RGBA texels row by row from the top, values as stored (sRGB-encoded colour
/// stays encoded), scaled to [0, 1] for integer formats.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodedImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The texels: the bytes of an 8-bit image, values otherwise.
    pub texels: Texels,
}

/// A reader of `bytes`, its decoder's allocations limited.
fn reader(bytes: &[u8]) -> Result<image::ImageReader<std::io::Cursor<&[u8]>>, String> {
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("cannot read: {e}"))?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    limits.max_alloc = Some(MAX_DECODE_ALLOC);
    reader.limits(limits);
    Ok(reader)
}

/// The size of the image in `bytes` without decoding it, within the limits.
pub fn image_size(bytes: &[u8]) -> Result<(u32, u32), String> {
    check_exr_windows(bytes)?;
    // Reading the header allocates little: no limits, so that the error below names the size.
    let (w, h) = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("cannot read: {e}"))?
        .into_dimensions()
        .map_err(|e| format!("cannot decode: {e}"))?;
    if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        return Err(format!(
            "{w}×{h} pixels: more than the {MAX_IMAGE_SIDE} allowed on a side"
        ));
    }
    if (w as u64) * (h as u64) > MAX_IMAGE_PIXELS || w == 0 || h == 0 {
        return Err(format!(
            "{w}×{h} pixels is empty or more than the {MAX_IMAGE_PIXELS} allowed"
        ));
    }
    Ok((w, h))
}

/// Bytes the texels of the image in `bytes` take once decoded ([`decode_image`]): 4 per texel
/// for 8-bit images, 16 for others. Read from the header, within the limits, so that a
/// memory budget is charged before anything is decoded.
pub fn image_bytes(bytes: &[u8]) -> Result<u64, String> {
    let (w, h) = image_size(bytes)?;
    let colour = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("cannot read: {e}"))?
        .into_decoder()
        .map_err(|e| format!("cannot decode: {e}"))?
        .color_type();
    let texel = if eight_bit(colour) { 4 } else { 16 };
    Ok(u64::from(w) * u64::from(h) * texel)
}

/// Whether images of this colour type have 8 bits per channel (their bytes are kept).
fn eight_bit(colour: image::ColorType) -> bool {
    colour.bytes_per_pixel() == colour.channel_count()
}

/// The first bytes of an OpenEXR file.
const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

/// Refuses an OpenEXR file whose header gives an inverted data or display window (a maximum
/// below its minimum): the decoder reads such a file as some other size instead of failing.
/// Other files, and headers this walk cannot follow, pass (the decoder judges them).
fn check_exr_windows(bytes: &[u8]) -> Result<(), String> {
    if !bytes.starts_with(&EXR_MAGIC) {
        return Ok(());
    }
    // After the magic and the version field: attributes (name NUL, type NUL, i32 size, value)
    // up to an empty name.
    let mut at = 8;
    let cstr = |from: usize| -> Option<(&[u8], usize)> {
        let len = bytes.get(from..)?.iter().position(|&b| b == 0)?;
        Some((&bytes[from..from + len], from + len + 1))
    };
    while let Some((name, next)) = cstr(at) {
        if name.is_empty() {
            break;
        }
        let Some((kind, next)) = cstr(next) else {
            break;
        };
        let Some(size) = bytes.get(next..next + 4) else {
            break;
        };
        let size = i32::from_le_bytes(size.try_into().expect("four bytes")) as usize;
        let value = next + 4;
        let Some(v) = bytes.get(value..value.saturating_add(size)) else {
            break;
        };
        if kind == b"box2i" && size == 16 && (name == b"dataWindow" || name == b"displayWindow") {
            let i = |k: usize| i32::from_le_bytes(v[4 * k..4 * k + 4].try_into().expect("4"));
            let (x0, y0, x1, y1) = (i(0), i(1), i(2), i(3));
            if x1 < x0 || y1 < y0 {
                return Err(format!(
                    "corrupt OpenEXR header: {} from ({x0}, {y0}) to ({x1}, {y1}) is inverted",
                    String::from_utf8_lossy(name)
                ));
            }
        }
        at = value + size;
    }
    Ok(())
}

/// Decodes the image in `bytes`, within the limits.
pub fn decode_image(bytes: &[u8]) -> Result<DecodedImage, String> {
    image_size(bytes)?;
    let img = reader(bytes)?
        .decode()
        .map_err(|e| format!("cannot decode: {e}"))?;
    let (width, height) = (img.width(), img.height());
    let texels = if eight_bit(img.color()) {
        // 8 bits per channel: the bytes are kept (a quarter of the memory of f32 values).
        Texels::Unorm8(rgba(img.into_rgba8().into_raw()))
    } else {
        Texels::F32(rgba(img.into_rgba32f().into_raw()))
    };
    Ok(DecodedImage {
        width,
        height,
        texels,
    })
}

/// The decoder's RGBA buffer as texels: the same allocation (no second copy of the image at
/// its peak), unless its capacity is no whole number of texels.
fn rgba<T: bytemuck::Pod>(raw: Vec<T>) -> Vec<[T; 4]> {
    bytemuck::allocation::try_cast_vec::<T, [T; 4]>(raw).unwrap_or_else(|(_, raw)| {
        raw.chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png(w: u32, h: u32) -> Vec<u8> {
        let img =
            image::RgbaImage::from_fn(w, h, |x, _| image::Rgba([x.min(1) as u8 * 255, 0, 51, 255]));
        let mut out = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
            .unwrap();
        out
    }

    /// A PNG file claiming `w × h` pixels without their data: enough to read its size.
    fn png_header(w: u32, h: u32) -> Vec<u8> {
        fn crc32(bytes: &[u8]) -> u32 {
            let mut c = !0u32;
            for &b in bytes {
                c ^= b as u32;
                for _ in 0..8 {
                    c = if c & 1 != 0 {
                        0xEDB8_8320 ^ (c >> 1)
                    } else {
                        c >> 1
                    };
                }
            }
            !c
        }
        let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut chunk = |kind: &[u8], data: &[u8]| {
            let body = [kind, data].concat();
            out.extend((data.len() as u32).to_be_bytes());
            out.extend(&body);
            out.extend(crc32(&body).to_be_bytes());
        };
        let ihdr = [&w.to_be_bytes()[..], &h.to_be_bytes(), &[8, 6, 0, 0, 0]].concat();
        chunk(b"IHDR", &ihdr);
        // An empty image data chunk: decoders read the header up to the first one.
        chunk(b"IDAT", &[]);
        chunk(b"IEND", &[]);
        out
    }

    #[test]
    fn an_exr_with_an_inverted_window_is_refused() {
        let img = image::Rgba32FImage::from_pixel(6, 4, image::Rgba([0.5, 0.25, 1.0, 1.0]));
        let mut exr = Vec::new();
        img.write_to(
            &mut std::io::Cursor::new(&mut exr),
            image::ImageFormat::OpenExr,
        )
        .unwrap();
        assert_eq!(decode_image(&exr).unwrap().width, 6);
        for window in ["dataWindow", "displayWindow"] {
            // The window's box2i follows its name, its type and its size.
            let name = format!("{window}\0box2i\0");
            let at = exr
                .windows(name.len())
                .position(|w| w == name.as_bytes())
                .unwrap()
                + name.len()
                + 4;
            let mut bad = exr.clone();
            for (k, v) in [5i32, 3, 0, 0].into_iter().enumerate() {
                bad[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
            }
            let e = decode_image(&bad).unwrap_err();
            assert!(
                e.contains("corrupt OpenEXR header")
                    && e.contains(window)
                    && e.contains("inverted"),
                "{e}"
            );
        }
    }

    #[test]
    fn decodes_as_stored_and_refuses_what_is_too_big_or_not_an_image() {
        let d = decode_image(&png(2, 1)).unwrap();
        assert_eq!((d.width, d.height), (2, 1));
        // An 8-bit image keeps its bytes; they stand for what the decoder's f32 gives.
        assert_eq!(
            d.texels,
            Texels::Unorm8(vec![[0, 0, 51, 255], [255, 0, 51, 255]])
        );
        assert_eq!(d.texels.get(1), [1.0, 0.0, 0.2, 1.0]);
        // Grey and grey-alpha images too: byte b is b / 255, in every channel.
        let grey = image::GrayAlphaImage::from_fn(2, 1, |x, _| image::LumaA([3 + x as u8, 128]));
        let mut bytes = Vec::new();
        grey.write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .unwrap();
        let d = decode_image(&bytes).unwrap();
        assert_eq!(
            d.texels,
            Texels::Unorm8(vec![[3, 3, 3, 128], [4, 4, 4, 128]])
        );
        assert_eq!(
            d.texels.get(0),
            [3.0 / 255.0, 3.0 / 255.0, 3.0 / 255.0, 128.0 / 255.0]
        );
        // Deeper images keep their values.
        let deep = image::ImageBuffer::<image::Rgba<u16>, _>::from_pixel(
            1,
            1,
            image::Rgba([0, 65535, 32768, 65535]),
        );
        let mut bytes = Vec::new();
        image::DynamicImage::ImageRgba16(deep)
            .write_to(
                &mut std::io::Cursor::new(&mut bytes),
                image::ImageFormat::Png,
            )
            .unwrap();
        assert!(matches!(
            decode_image(&bytes).unwrap().texels,
            Texels::F32(_)
        ));
        assert_eq!(image_size(&png(3, 5)).unwrap(), (3, 5));
        // Sizes are refused from the header, before any texel is decoded.
        assert_eq!(image_size(&png_header(300, 200)).unwrap(), (300, 200));
        let e = decode_image(&png_header(MAX_IMAGE_SIDE + 1, 1)).unwrap_err();
        assert!(e.contains("on a side"), "{e}");
        let e = decode_image(&png_header(MAX_IMAGE_SIDE, 4097)).unwrap_err();
        assert!(e.contains("allowed"), "{e}");
        assert!(decode_image(b"not an image").is_err());
    }
}
