//! Image files for the scene front ends: one decoder with one set of limits, for the textures
//! and environment maps of JSON scenes and the images of glTF files (PNG, JPEG, Radiance HDR,
//! OpenEXR, the format found from the bytes; Radiance files that start `#?RGBE` as well as
//! `#?RADIANCE`).
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

/// The signature Radiance HDR files from some writers (Mitsuba among them) start with instead
/// of `#?RADIANCE`; the format is the same, but the decoder knows only the other.
const RGBE_SIGNATURE: &[u8] = b"#?RGBE\n";

/// A decoder of the image in `bytes`, its allocations within the limits when `limited` (not
/// for reading the header alone, which allocates little, so that [`image_size`]'s errors name
/// the size).
fn decoder(bytes: &[u8], limited: bool) -> Result<Box<dyn ImageDecoder + '_>, String> {
    let cannot = |e: image::ImageError| format!("cannot decode: {e}");
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    limits.max_alloc = Some(MAX_DECODE_ALLOC);
    if let Some(rest) = bytes.strip_prefix(RGBE_SIGNATURE) {
        let header = &b"#?RADIANCE\n"[..];
        let mut hdr = image::codecs::hdr::HdrDecoder::new(std::io::Read::chain(header, rest))
            .map_err(cannot)?;
        if limited {
            hdr.set_limits(limits).map_err(cannot)?;
        }
        return Ok(Box::new(hdr));
    }
    if let Some(grey) = ExrGrey::new(bytes)? {
        return Ok(Box::new(grey));
    }
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("cannot read: {e}"))?;
    if limited {
        reader.limits(limits);
    }
    Ok(Box::new(reader.into_decoder().map_err(cannot)?))
}

/// The size of the image in `bytes` without decoding it, within the limits.
pub fn image_size(bytes: &[u8]) -> Result<(u32, u32), String> {
    check_exr_windows(bytes)?;
    let (w, h) = decoder(bytes, false)?.dimensions();
    if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        return Err(format!(
            "{w}×{h} pixels: more than the {MAX_IMAGE_SIDE} allowed on a side"
        ));
    }
    if w == 0 || h == 0 {
        return Err(format!("{w}×{h} pixels: the image is empty"));
    }
    if (w as u64) * (h as u64) > MAX_IMAGE_PIXELS {
        return Err(format!(
            "{w}×{h} pixels: {} pixels, more than the {MAX_IMAGE_PIXELS} allowed",
            w as u64 * h as u64
        ));
    }
    Ok((w, h))
}

/// Bytes the texels of the image in `bytes` take once decoded ([`decode_image`]): 4 per texel
/// for 8-bit images, 16 for others. Read from the header, within the limits, so that a
/// memory budget is charged before anything is decoded.
pub fn image_bytes(bytes: &[u8]) -> Result<u64, String> {
    let (w, h) = image_size(bytes)?;
    let texel = if eight_bit(decoder(bytes, false)?.color_type()) {
        4
    } else {
        16
    };
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

/// An OpenEXR file without R, G and B channels whose first flat part has one other channel (a
/// luminance `Y`, or a data map's `R` or `Z` alone), with or without `A`: decoded as grey, the
/// channel in R, G and B. The image crate's decoder reads only files with R, G and B.
struct ExrGrey<'a> {
    bytes: &'a [u8],
    channel: exr::meta::attribute::Text,
    alpha: bool,
    /// The display window: the image's extent; pixels outside the data window are 0.
    display: exr::meta::attribute::IntegerBounds,
    /// Where the data window starts in the display window.
    offset: (i64, i64),
}

impl<'a> ExrGrey<'a> {
    /// The grey reader of `bytes`, or `None` where the file is no OpenEXR file or one with R, G
    /// and B (the image crate reads those). A file with several other channels is refused,
    /// naming them.
    fn new(bytes: &'a [u8]) -> Result<Option<Self>, String> {
        use exr::meta::attribute::Text;
        if !bytes.starts_with(&EXR_MAGIC) {
            return Ok(None);
        }
        let Ok(reader) = exr::block::read(std::io::Cursor::new(bytes), false) else {
            return Ok(None); // the image crate's decoder gives the error
        };
        let flat = || reader.headers().iter().filter(|h| !h.deep);
        let has = |h: &exr::meta::header::Header, name: &str| {
            h.channels
                .find_index_of_channel(&Text::from(name))
                .is_some()
        };
        if flat().any(|h| ["R", "G", "B"].iter().all(|&c| has(h, c))) {
            return Ok(None);
        }
        let Some(header) = flat().next() else {
            return Ok(None);
        };
        let names: Vec<&Text> = header.channels.list.iter().map(|c| &c.name).collect();
        let others: Vec<&&Text> = names.iter().filter(|n| n.as_slice() != b"A").collect();
        let [channel] = others[..] else {
            let list = names.iter().map(|n| n.to_string()).collect::<Vec<_>>();
            return Err(format!(
                "an OpenEXR image with the channels {}: raytile reads R, G and B (and A), or a \
                 single channel such as Y",
                list.join(", ")
            ));
        };
        let display = header.shared_attributes.display_window;
        let offset = header.own_attributes.layer_position - display.position;
        Ok(Some(Self {
            bytes,
            channel: (*channel).clone(),
            alpha: has(header, "A"),
            display,
            offset: (i64::from(offset.x()), i64::from(offset.y())),
        }))
    }

    /// Texels a pixel has in the buffer [`ImageDecoder::read_image`] fills: RGB or RGBA.
    fn channels(&self) -> usize {
        if self.alpha {
            4
        } else {
            3
        }
    }
}

impl ImageDecoder for ExrGrey<'_> {
    fn dimensions(&self) -> (u32, u32) {
        (
            self.display.size.width() as u32,
            self.display.size.height() as u32,
        )
    }

    fn color_type(&self) -> image::ColorType {
        if self.alpha {
            image::ColorType::Rgba32F
        } else {
            image::ColorType::Rgb32F
        }
    }

    fn read_image(self, buf: &mut [u8]) -> image::ImageResult<()> {
        use exr::prelude::{ReadChannels, ReadLayers, ReadSpecificChannel};
        let (display, channels, alpha) = (self.display, self.channels(), self.alpha);
        let failed = |e: exr::error::Error| {
            image::ImageError::Decoding(image::error::DecodingError::new(
                image::ImageFormat::OpenExr.into(),
                e,
            ))
        };
        // The file's values (and alphas) over the display window, 0 outside the data window;
        // then spread to the RGB(A) texels.
        let (w, h) = (display.size.width(), display.size.height());
        let (offset, stride) = (self.offset, if alpha { 2 } else { 1 });
        let image = exr::prelude::read()
            .no_deep_data()
            .largest_resolution_level()
            .specific_channels()
            .required(self.channel)
            .optional("A", 1.0f32)
            .collect_pixels(
                move |_, _: &_| vec![0.0f32; w * h * stride],
                move |out: &mut Vec<f32>, at: exr::math::Vec2<usize>, (v, a): (f32, f32)| {
                    let x = usize::try_from(at.x() as i64 + offset.0)
                        .ok()
                        .filter(|&x| x < w);
                    let y = usize::try_from(at.y() as i64 + offset.1)
                        .ok()
                        .filter(|&y| y < h);
                    if let (Some(x), Some(y)) = (x, y) {
                        let first = (y * w + x) * stride;
                        out[first] = v;
                        if alpha {
                            out[first + 1] = a;
                        }
                    }
                },
            )
            .first_valid_layer()
            .all_attributes()
            .from_buffered(std::io::Cursor::new(self.bytes))
            .map_err(failed)?;
        let values = &image.layer_data.channel_data.pixels;
        for (texel, value) in buf
            .chunks_exact_mut(4 * channels)
            .zip(values.chunks_exact(stride))
        {
            for (c, bytes) in texel.chunks_exact_mut(4).enumerate() {
                let v = if c == 3 { value[1] } else { value[0] };
                bytes.copy_from_slice(&v.to_ne_bytes());
            }
        }
        Ok(())
    }

    fn read_image_boxed(self: Box<Self>, buf: &mut [u8]) -> image::ImageResult<()> {
        (*self).read_image(buf)
    }
}

/// Decodes the image in `bytes`, within the limits.
///
/// Images other than 16-bit grey ones are decoded straight into the RGBA buffer they are kept
/// in, their channels spread (and 16-bit values converted) in place: an RGB image never holds
/// its RGB and RGBA buffers at once.
pub fn decode_image(bytes: &[u8]) -> Result<DecodedImage, String> {
    let (width, height) = image_size(bytes)?;
    let decoder = decoder(bytes, true)?;
    if decoder.total_bytes() > MAX_DECODE_ALLOC {
        return Err(format!(
            "cannot decode: {} bytes of pixels, more than the {MAX_DECODE_ALLOC} allowed",
            decoder.total_bytes()
        ));
    }
    let texels = (width as usize) * (height as usize);
    let colour = decoder.color_type();
    let channels = usize::from(colour.channel_count());
    let texels = match colour {
        image::ColorType::L8
        | image::ColorType::La8
        | image::ColorType::Rgb8
        | image::ColorType::Rgba8 => {
            // 8 bits per channel: the bytes are kept (a quarter of the memory of f32 values).
            Texels::from(decode_rgba(decoder, texels, channels, |v: u8| v, u8::MAX)?)
        }
        image::ColorType::Rgb16 | image::ColorType::Rgba16 => {
            // The image crate's conversion of 16-bit values, to the bit.
            let unit = |v: u16| (f32::from(v) / f32::from(u16::MAX)).clamp(0.0, 1.0);
            Texels::from(decode_rgba(decoder, texels, channels, unit, 1.0)?)
        }
        image::ColorType::Rgb32F | image::ColorType::Rgba32F => {
            Texels::from(decode_rgba(decoder, texels, channels, |v: f32| v, 1.0)?)
        }
        // 16-bit grey: the image crate's conversion, whose values for grey differ from its
        // conversion of colour channels by a unit in the last place (images keep their bits).
        _ => {
            let img = image::DynamicImage::from_decoder(decoder)
                .map_err(|e| format!("cannot decode: {e}"))?;
            Texels::from(rgba(img.into_rgba32f().into_raw()))
        }
    };
    Ok(DecodedImage {
        width,
        height,
        texels,
    })
}

/// Decodes `texels` pixels of `channels` channels of type `S` (grey, grey and alpha, RGB or
/// RGBA) into RGBA texels of type `T`: the decoder writes the front of the RGBA buffer, and
/// each pixel is then converted and spread to its own texel from the last to the first (a
/// texel, at least as large as a pixel, never overwrites a pixel not yet moved). Grey fills the
/// three colour channels; a missing alpha is `opaque`. When `S` and `T` are the same size,
/// `convert` must be the identity (an RGBA image is then kept as the decoder wrote it).
fn decode_rgba<S: bytemuck::Pod, T: bytemuck::Pod + Default>(
    decoder: impl ImageDecoder,
    texels: usize,
    channels: usize,
    convert: impl Fn(S) -> T,
    opaque: T,
) -> Result<Vec<[T; 4]>, String> {
    let mut out = vec![[T::default(); 4]; texels];
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut out);
    let (from, to) = (std::mem::size_of::<S>(), std::mem::size_of::<[T; 4]>());
    let stored = texels * channels * from;
    if decoder.total_bytes() != stored as u64 {
        return Err(format!(
            "cannot decode: {} bytes of pixels where {stored} were expected",
            decoder.total_bytes()
        ));
    }
    decoder
        .read_image(&mut bytes[..stored])
        .map_err(|e| format!("cannot decode: {e}"))?;
    if channels == 4 && 4 * from == to {
        return Ok(out);
    }
    for i in (0..texels).rev() {
        let at = i * channels * from;
        let value = |k: usize| {
            let v = &bytes[at + k * from..at + (k + 1) * from];
            convert(bytemuck::pod_read_unaligned(v))
        };
        let texel = match channels {
            1 => [value(0), value(0), value(0), opaque],
            2 => [value(0), value(0), value(0), value(1)],
            3 => [value(0), value(1), value(2), opaque],
            _ => [value(0), value(1), value(2), value(3)],
        };
        bytes[i * to..(i + 1) * to].copy_from_slice(bytemuck::bytes_of(&texel));
    }
    Ok(out)
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

    /// Every 16-bit value of a colour image converts as the image crate converts it.
    #[test]
    fn sixteen_bit_images_decode_in_place_to_the_decoders_values() {
        let value = |x: u32, y: u32, c: u32| ((y * 256 + x) as u16).wrapping_add(c as u16 * 7919);
        let rgba16 = image::ImageBuffer::<image::Rgba<u16>, _>::from_fn(256, 256, |x, y| {
            image::Rgba([
                value(x, y, 0),
                value(x, y, 1),
                value(x, y, 2),
                value(x, y, 3),
            ])
        });
        let rgba16 = image::DynamicImage::ImageRgba16(rgba16);
        let images: [(&str, image::DynamicImage); 2] =
            [("RGB", rgba16.to_rgb16().into()), ("RGBA", rgba16.clone())];
        for (what, img) in images {
            let mut bytes = Vec::new();
            img.write_to(
                &mut std::io::Cursor::new(&mut bytes),
                image::ImageFormat::Png,
            )
            .unwrap();
            let want = image::load_from_memory(&bytes).unwrap().into_rgba32f();
            let Texels::F32(got) = decode_image(&bytes).unwrap().texels else {
                panic!("{what}: a 16-bit image is kept as f32");
            };
            let bits = |t: &[[f32; 4]]| -> Vec<[u32; 4]> {
                t.iter().map(|p| p.map(f32::to_bits)).collect()
            };
            let (got, want) = (bits(&got), bits(&rgba(want.into_raw())));
            let first = got.iter().zip(&want).position(|(g, w)| g != w);
            assert_eq!(
                first,
                None,
                "{what}: texel {first:?}, {:?} against {:?}",
                first.map(|i| got[i].map(f32::from_bits)),
                first.map(|i| want[i].map(f32::from_bits))
            );
        }
    }

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
        let ihdr = [&w.to_be_bytes()[..], &h.to_be_bytes(), &[8, 6, 0, 0, 0]].concat();
        // An empty image data chunk: decoders read the header up to the first one.
        png_chunks(&[(b"IHDR", &ihdr), (b"IDAT", &[])])
    }

    /// A PNG file of these chunks (and IEND).
    fn png_chunks(chunks: &[(&[u8; 4], &[u8])]) -> Vec<u8> {
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
        for (kind, data) in chunks.iter().copied().chain([(b"IEND", &[][..])]) {
            let body = [&kind[..], data].concat();
            out.extend((data.len() as u32).to_be_bytes());
            out.extend(&body);
            out.extend(crc32(&body).to_be_bytes());
        }
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
    fn every_colour_type_decodes_in_place_to_what_the_decoders_conversion_gives() {
        let (w, h) = (7u32, 5u32);
        let value = |x: u32, y: u32, c: u32| ((x * 37 + y * 11 + c * 71) % 256) as u8;
        let rgba8 = image::RgbaImage::from_fn(w, h, |x, y| {
            image::Rgba([
                value(x, y, 0),
                value(x, y, 1),
                value(x, y, 2),
                value(x, y, 3),
            ])
        });
        let rgba32 = image::Rgba32FImage::from_fn(w, h, |x, y| {
            image::Rgba([0, 1, 2, 3].map(|c| f32::from(value(x, y, c)) / 7.0 + 0.125))
        });
        let encode = |img: image::DynamicImage, format| {
            let mut bytes = Vec::new();
            img.write_to(&mut std::io::Cursor::new(&mut bytes), format)
                .unwrap();
            bytes
        };
        let rgba8 = image::DynamicImage::ImageRgba8(rgba8);
        let rgba32 = image::DynamicImage::ImageRgba32F(rgba32);
        use image::ImageFormat::{Hdr, OpenExr, Png};
        let files = [
            ("grey", encode(rgba8.to_luma8().into(), Png)),
            ("grey and alpha", encode(rgba8.to_luma_alpha8().into(), Png)),
            ("RGB", encode(rgba8.to_rgb8().into(), Png)),
            ("RGBA", encode(rgba8.clone(), Png)),
            ("RGB f32", encode(rgba32.to_rgb32f().into(), Hdr)),
            ("RGBA f32", encode(rgba32.clone(), OpenExr)),
        ];
        for (what, bytes) in files {
            let decoded = image::load_from_memory(&bytes).unwrap();
            let ours = decode_image(&bytes).unwrap();
            assert_eq!((ours.width, ours.height), (w, h), "{what}");
            let want = if eight_bit(decoded.color()) {
                Texels::from(rgba(decoded.into_rgba8().into_raw()))
            } else {
                Texels::from(rgba(decoded.into_rgba32f().into_raw()))
            };
            assert_eq!(ours.texels, want, "{what}");
        }
    }

    /// Texels as the image crate's own conversion gives them (what was kept before decoding in
    /// place).
    fn converted(bytes: &[u8]) -> Texels {
        let img = image::load_from_memory(bytes).unwrap();
        if eight_bit(img.color()) {
            Texels::from(rgba(img.into_rgba8().into_raw()))
        } else {
            Texels::from(rgba(img.into_rgba32f().into_raw()))
        }
    }

    #[test]
    fn pngs_whose_decoded_colour_type_is_not_the_stored_one_decode_in_place_alike() {
        // 7×5 pixels of `depth` bits, `channels` samples each, packed row by row (Adam7 when
        // `interlaced`), filter type 0.
        let (w, h) = (7u32, 5u32);
        let sample = |x: u32, y: u32, c: u32, depth: u8| ((x * 5 + y * 3 + c) % (1 << depth)) as u8;
        let rows = |depth: u8, channels: u32, interlaced: bool| {
            let passes: &[(u32, u32, usize, usize)] = if interlaced {
                &[
                    (0, 0, 8, 8),
                    (4, 0, 8, 8),
                    (0, 4, 4, 8),
                    (2, 0, 4, 4),
                    (0, 2, 2, 4),
                    (1, 0, 2, 2),
                    (0, 1, 1, 2),
                ]
            } else {
                &[(0, 0, 1, 1)]
            };
            let mut raw = Vec::new();
            for &(x0, y0, dx, dy) in passes {
                let xs: Vec<u32> = (x0..w).step_by(dx).collect();
                for y in (y0..h).step_by(dy).filter(|_| !xs.is_empty()) {
                    raw.push(0);
                    let (mut bits, mut n) = (0u32, 0);
                    for (&x, c) in xs.iter().flat_map(|x| (0..channels).map(move |c| (x, c))) {
                        bits = bits << depth | u32::from(sample(x, y, c, depth));
                        n += u32::from(depth);
                        if n == 8 {
                            raw.push(bits as u8);
                            (bits, n) = (0, 0);
                        }
                    }
                    if n > 0 {
                        raw.push((bits << (8 - n)) as u8);
                    }
                }
            }
            miniz_oxide::deflate::compress_to_vec_zlib(&raw, 6)
        };
        let palette: Vec<u8> = (0..16 * 3).map(|i| (i * 53 % 256) as u8).collect();
        let ihdr = |depth: u8, colour: u8, interlaced: bool| {
            [
                &w.to_be_bytes()[..],
                &h.to_be_bytes(),
                &[depth, colour, 0, 0, interlaced as u8],
            ]
            .concat()
        };
        // What, bit depth, PNG colour type, samples a pixel, palette, tRNS, interlaced.
        type File<'a> = (&'a str, u8, u8, u32, &'a [u8], &'a [u8], bool);
        let files: [File; 7] = [
            ("2-bit palette", 2, 3, 1, &palette[..12], &[], false),
            (
                "4-bit palette, tRNS",
                4,
                3,
                1,
                &palette,
                &[0, 90, 180],
                false,
            ),
            (
                "8-bit palette, tRNS, Adam7",
                8,
                3,
                1,
                &palette,
                &[10, 20],
                true,
            ),
            ("1-bit grey", 1, 0, 1, &[], &[], false),
            ("2-bit grey, tRNS, Adam7", 2, 0, 1, &[], &[0, 1], true),
            ("8-bit RGB, tRNS", 8, 2, 3, &[], &[0, 0, 0, 1, 0, 2], false),
            ("16-bit grey, Adam7", 16, 0, 1, &[], &[], true),
        ];
        for (what, depth, colour, channels, plte, trns, interlaced) in files {
            // A 16-bit sample is two 8-bit ones.
            let (packed, channels) = if depth == 16 {
                (8, 2)
            } else {
                (depth, channels)
            };
            let ihdr = ihdr(depth, colour, interlaced);
            let idat = rows(packed, channels, interlaced);
            let mut chunks = vec![(b"IHDR", &ihdr[..])];
            if !plte.is_empty() {
                chunks.push((b"PLTE", plte));
            }
            if !trns.is_empty() {
                chunks.push((b"tRNS", trns));
            }
            chunks.push((b"IDAT", &idat));
            let bytes = png_chunks(&chunks);
            let ours = decode_image(&bytes).unwrap();
            assert_eq!((ours.width, ours.height), (w, h), "{what}");
            assert_eq!(ours.texels, converted(&bytes), "{what}");
        }
    }

    #[test]
    fn openexr_half_channels_decode_and_a_lone_channel_is_grey() {
        // Uncompressed scanlines of 3×2 pixels: each channel's row in turn, names sorted.
        let (w, h) = (3i32, 2i32);
        let file = |channels: &[&str]| {
            let mut b = EXR_MAGIC.to_vec();
            b.extend([2, 0, 0, 0]);
            let mut attribute = |name: &str, kind: &str, value: &[u8]| {
                b.extend([name.as_bytes(), &[0], kind.as_bytes(), &[0]].concat());
                b.extend((value.len() as i32).to_le_bytes());
                b.extend(value);
            };
            // Half (1), linear 0, reserved, sampled 1 × 1.
            let list = channels.iter().flat_map(|n| {
                [
                    n.as_bytes(),
                    &[0, 1, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0],
                ]
                .concat()
            });
            attribute("channels", "chlist", &list.chain([0]).collect::<Vec<_>>());
            attribute("compression", "compression", &[0]);
            let window: Vec<u8> = [0, 0, w - 1, h - 1]
                .iter()
                .flat_map(|v: &i32| v.to_le_bytes())
                .collect();
            attribute("dataWindow", "box2i", &window);
            attribute("displayWindow", "box2i", &window);
            attribute("lineOrder", "lineOrder", &[0]);
            attribute("pixelAspectRatio", "float", &1f32.to_le_bytes());
            attribute("screenWindowCenter", "v2f", &[0; 8]);
            attribute("screenWindowWidth", "float", &1f32.to_le_bytes());
            b.push(0);
            let line = 2 * w as usize * channels.len();
            let first = b.len() + 8 * h as usize;
            for y in 0..h as usize {
                b.extend(((first + y * (8 + line)) as u64).to_le_bytes());
            }
            for y in 0..h {
                b.extend(y.to_le_bytes());
                b.extend((line as i32).to_le_bytes());
                for name in channels {
                    for x in 0..w as u16 {
                        // Halves 1 + k / 8 (sign 0, exponent 15, mantissa k << 7).
                        let k = (x + 3 * y as u16 + u16::from(name.as_bytes()[0])) % 8;
                        b.extend((0x3c00u16 | k << 7).to_le_bytes());
                    }
                }
            }
            b
        };
        for channels in [&["B", "G", "R"][..], &["A", "B", "G", "R"]] {
            let bytes = file(channels);
            let ours = decode_image(&bytes).unwrap();
            assert_eq!((ours.width, ours.height), (3, 2), "{channels:?}");
            assert_eq!(ours.texels, converted(&bytes), "{channels:?}");
            // The last pixel's red: k = (2 + 3 + 'R') % 8 = 7.
            assert_eq!(ours.texels.get(5)[0], 1.0 + 7.0 / 8.0, "{channels:?}");
        }
        // One channel, with or without alpha: grey (the image crate's decoder refuses these).
        for channels in [&["Y"][..], &["A", "Y"], &["R"], &["Z"]] {
            let bytes = file(channels);
            assert_eq!(image_size(&bytes), Ok((3, 2)), "{channels:?}");
            let alpha = channels.contains(&"A");
            assert_eq!(image_bytes(&bytes), Ok(6 * 16), "{channels:?}");
            let Texels::F32(got) = decode_image(&bytes).unwrap().texels else {
                panic!("{channels:?}: an OpenEXR image is kept as f32");
            };
            let grey = channels.iter().find(|&&c| c != "A").unwrap().as_bytes()[0];
            for (i, texel) in got.iter().enumerate() {
                let (x, y) = (i as u16 % 3, i as u16 / 3);
                let half = |name: u8| 1.0 + f32::from((x + 3 * y + u16::from(name)) % 8) / 8.0;
                let a = if alpha { half(b'A') } else { 1.0 };
                assert_eq!(
                    *texel,
                    [half(grey), half(grey), half(grey), a],
                    "{channels:?} {i}"
                );
            }
        }
        // Several channels but not R, G and B: refused, naming them.
        let e = decode_image(&file(&["U", "V"])).unwrap_err();
        assert!(
            e.contains("channels U, V") && e.contains("single channel"),
            "{e}"
        );
        assert!(image_size(&file(&["G", "R"])).is_err());
    }

    #[test]
    fn a_radiance_file_with_the_rgbe_signature_decodes_as_one_with_the_radiance_one() {
        let img = image::Rgb32FImage::from_fn(5, 3, |x, y| {
            image::Rgb([x as f32 * 0.75, y as f32 + 0.5, 2.0])
        });
        let mut radiance = Vec::new();
        img.write_to(
            &mut std::io::Cursor::new(&mut radiance),
            image::ImageFormat::Hdr,
        )
        .unwrap();
        let rest = radiance.strip_prefix(b"#?RADIANCE\n").unwrap();
        let rgbe = [RGBE_SIGNATURE, rest].concat();
        assert_eq!(image_size(&rgbe).unwrap(), (5, 3));
        assert_eq!(image_bytes(&rgbe).unwrap(), 5 * 3 * 16);
        assert_eq!(
            decode_image(&rgbe).unwrap(),
            decode_image(&radiance).unwrap()
        );
        // A truncated one is an error, as with the other signature.
        assert!(decode_image(&rgbe[..rgbe.len() - 9]).is_err());
        assert!(decode_image(RGBE_SIGNATURE).is_err());
    }

    #[test]
    fn decodes_as_stored_and_refuses_what_is_too_big_or_not_an_image() {
        let d = decode_image(&png(2, 1)).unwrap();
        assert_eq!((d.width, d.height), (2, 1));
        // An 8-bit image keeps its bytes; they stand for what the decoder's f32 gives.
        assert_eq!(
            d.texels,
            Texels::from(vec![[0, 0, 51, 255], [255, 0, 51, 255]])
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
        assert_eq!(d.texels, Texels::from(vec![[3, 3, 3, 128], [4, 4, 4, 128]]));
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
        assert!(
            e.contains("67125248 pixels, more than the 67108864 allowed") && !e.contains("empty"),
            "{e}"
        );
        assert!(decode_image(b"not an image").is_err());
    }
}
