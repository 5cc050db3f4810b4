//! Image output: linear OpenEXR and Radiance HDR, and tone-mapped 8-bit sRGB PNG, each with
//! what made it ([`Metadata`]) in its header.

use super::Film;
use crate::texture::linear_to_srgb;
use std::io::Cursor;
use std::path::Path;

/// Why an image could not be written.
#[derive(Debug, thiserror::Error)]
pub enum FilmError {
    /// The extension is not one raytile writes.
    #[error("{0}: unknown image format (expected .png, .exr or .hdr)")]
    UnknownFormat(String),
    /// Encoding failed.
    #[error("encoding {format}: {message}")]
    Encode {
        /// The format.
        format: &'static str,
        /// The encoder's message.
        message: String,
    },
    /// Writing the file failed (the OS error is the source: said once by error chains).
    #[error("writing {path}")]
    Io {
        /// The file.
        path: String,
        /// The OS error.
        source: std::io::Error,
    },
}

/// Output file formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    /// 8-bit sRGB PNG, tone-mapped.
    Png,
    /// 32-bit float linear OpenEXR.
    Exr,
    /// Radiance RGBE, linear.
    Hdr,
}

impl ImageFormat {
    /// Every format.
    pub const ALL: [ImageFormat; 3] = [Self::Png, Self::Exr, Self::Hdr];

    /// The name: the file extension, and the `?format=` of the farm's image endpoint.
    pub fn name(self) -> &'static str {
        match self {
            Self::Png => "png",
            Self::Exr => "exr",
            Self::Hdr => "hdr",
        }
    }

    /// From a file extension (case-insensitive).
    pub fn from_extension(ext: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|f| f.name().eq_ignore_ascii_case(ext))
    }

    /// From a path's extension.
    pub fn from_path(path: &Path) -> Result<Self, FilmError> {
        path.extension()
            .and_then(|e| e.to_str())
            .and_then(Self::from_extension)
            .ok_or_else(|| FilmError::UnknownFormat(path.display().to_string()))
    }
}

/// Tone-mapping operators for 8-bit output.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ToneMap {
    /// Clip to [0, 1] (what "Standard" view transforms do).
    #[default]
    Clamp,
    /// The ACES filmic curve (Narkowicz's fit): soft highlights, richer contrast.
    Aces,
}

impl std::str::FromStr for ToneMap {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "clamp" | "none" => Ok(Self::Clamp),
            "aces" | "filmic" => Ok(Self::Aces),
            _ => Err(format!("unknown tone map '{s}' (expected clamp or aces)")),
        }
    }
}

/// How linear radiance becomes display pixels (PNG only; EXR and HDR are written linear).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OutputOptions {
    /// Exposure in stops: pixels are multiplied by 2^exposure before tone mapping.
    pub exposure: f32,
    /// Tone-mapping curve.
    pub tonemap: ToneMap,
}

/// How an image was made, written into its file beside the pixels: the software, and a JSON
/// object under the key `raytile` (OpenEXR header attributes `software` and `raytile`; PNG
/// `iTXt` chunks `Software` and `raytile`; Radiance header lines `SOFTWARE=` and `raytile=`).
/// Made from the job alone (no date, no host), so one job's file has the same bytes whichever
/// machines rendered it. One key, not several: the OpenEXR writer keeps other attributes in a
/// hash map, whose order (and so the file's bytes) would change from one process to the next.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Metadata {
    /// The software that made the image.
    pub software: String,
    /// The `raytile` JSON object (one line).
    pub raytile: String,
}

impl Metadata {
    /// What raytile writes with a render of `settings` summed in `film`: the program and
    /// renderer version (`software`), and as JSON the renderer version (`render_version`), the
    /// settings that decide the pixels (`settings`: the job's, after the scene's and the user's
    /// were merged), the samples per pixel the film holds (`samples_per_pixel`: fewer than the
    /// settings' in a preview of a job under way) and the samples dropped as NaN, infinite or
    /// too large (`dropped_samples`).
    ///
    /// Left out, so that a job's file has the same bytes from `raytile render` and from any
    /// farm: the tile size (scheduling only) and the folders of an environment map (its file
    /// name stays: a farm names the map inside the scene's package, `raytile render` where it
    /// lies).
    pub fn of_render(settings: &crate::RenderSettings, film: &Film) -> Self {
        use crate::settings::EnvironmentChoice;
        let mut s = settings.clone();
        if let Some(EnvironmentChoice::Map(path)) = &s.environment {
            let name = path.rsplit(['/', '\\']).next().unwrap_or(path);
            s.environment = Some(EnvironmentChoice::Map(name.to_string()));
        }
        let mut settings = serde_json::to_value(&s).unwrap_or_default();
        if let Some(map) = settings.as_object_mut() {
            map.remove("tile_size");
        }
        let pixels = (film.width as f64 * film.height as f64).max(1.0);
        let raytile = serde_json::json!({
            "render_version": crate::RENDER_VERSION,
            "settings": settings,
            "samples_per_pixel": film.samples / pixels,
            "dropped_samples": film.bad_samples,
        });
        Metadata {
            software: format!(
                "raytile {} (render version {})",
                env!("CARGO_PKG_VERSION"),
                crate::RENDER_VERSION
            ),
            raytile: raytile.to_string(),
        }
    }

    /// Whether there is nothing to write.
    pub fn is_empty(&self) -> bool {
        self.software.is_empty() && self.raytile.is_empty()
    }

    /// The Radiance header lines of the metadata (newlines in values as spaces).
    fn hdr_lines(&self) -> String {
        let line = |v: &str| v.replace(['\n', '\r'], " ");
        let mut out = String::new();
        if !self.software.is_empty() {
            out += &format!("SOFTWARE={}\n", line(&self.software));
        }
        if !self.raytile.is_empty() {
            out += &format!("raytile={}\n", line(&self.raytile));
        }
        out
    }
}

/// Narkowicz's fit of the ACES film curve. Values above 10⁹ (where the curve has long been
/// flat at one) are taken as 10⁹, so that x² cannot overflow to ∞/∞ = NaN and a very bright
/// pixel comes out white, not black.
#[inline]
fn aces(x: f32) -> f32 {
    let x = x.min(1e9);
    let (a, b, c, d, e) = (2.51, 0.03, 2.43, 0.59, 0.14);
    ((x * (a * x + b)) / (x * (c * x + d) + e)).clamp(0.0, 1.0)
}

/// The widest scanline Radiance's run-length encoding can state (its marker holds the width
/// in 15 bits). The image crate's encoder uses it up to 32,768 pixels, and its files of that
/// width are unreadable; wider images are written flat here.
const HDR_RLE_WIDTH: u32 = 32_767;

/// A Radiance `.hdr` file of flat (not run-length encoded) RGBE pixels, top row first.
fn write_flat_hdr(
    out: &mut impl std::io::Write,
    px: &[image::Rgb<f32>],
    w: u32,
    h: u32,
) -> std::io::Result<()> {
    write!(out, "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n")?;
    let mut bytes = Vec::with_capacity(px.len() * 4);
    for p in px {
        let m = p.0[0].max(p.0[1]).max(p.0[2]);
        if m < f32::MIN_POSITIVE {
            bytes.extend_from_slice(&[0; 4]);
            continue;
        }
        // m = f · 2^e with f in [0.5, 1), read from the bits; each channel is stored as
        // trunc(256 · v / 2^e), and the exponent as e + 128.
        // (At most 127: pixels are finite and far below 2^127.)
        let e = (((m.to_bits() >> 23) & 0xff) as i32 - 126).min(127);
        let scale = 2f64.powi(8 - e);
        let c = p.0.map(|v| ((v as f64 * scale) as u32).min(255) as u8);
        bytes.extend_from_slice(&[c[0], c[1], c[2], (e + 128) as u8]);
    }
    out.write_all(&bytes)
}

/// Encodes the film in `format`, without metadata.
pub fn encode(
    film: &Film,
    format: ImageFormat,
    opts: &OutputOptions,
) -> Result<Vec<u8>, FilmError> {
    encode_with(film, format, opts, &Metadata::default())
}

/// Encodes the film in `format`, with `meta` in the file's header (none where it is empty).
pub fn encode_with(
    film: &Film,
    format: ImageFormat,
    opts: &OutputOptions,
    meta: &Metadata,
) -> Result<Vec<u8>, FilmError> {
    let px = film.resolve();
    let alpha = film.alpha();
    let (w, h) = (film.width, film.height);
    let mut out = Cursor::new(Vec::new());
    let err = |format: &'static str| {
        move |e: image::ImageError| FilmError::Encode {
            format,
            message: e.to_string(),
        }
    };
    match format {
        ImageFormat::Exr => {
            // The image crate's encoder (RLE in 64² tiles) writes its tiles in whatever order
            // its threads finish them (line order "random"): the same frame gave other bytes
            // from one encoding to the next. The same compression and tiles, in increasing
            // order (the exr crate sorts what its threads compress), are the same bytes always.
            use exr::prelude::{
                AttributeValue, Blocks, Compression, Encoding, Image, Layer, LayerAttributes,
                LineOrder, SpecificChannels, Text, Vec2, WritableImage,
            };
            let encoding = Encoding {
                compression: Compression::RLE,
                blocks: Blocks::Tiles(Vec2(64, 64)),
                line_order: LineOrder::Increasing,
            };
            let width = w as usize;
            // OpenEXR's text is bytes; UTF-8 is what readers take it for.
            let text = |v: &str| Text::from_slice_unchecked(v.as_bytes());
            let mut attributes = LayerAttributes::default();
            if !meta.software.is_empty() {
                attributes.software_name = Some(text(&meta.software));
            }
            if !meta.raytile.is_empty() {
                attributes
                    .other
                    .insert(text("raytile"), AttributeValue::Text(text(&meta.raytile)));
            }
            // RGB, or RGBA with the colour premultiplied by alpha (OpenEXR's convention):
            // the two are layers of different types, written by the same steps.
            macro_rules! write_layer {
                ($channels:expr) => {{
                    let layer = Layer::new((width, h as usize), attributes, encoding, $channels);
                    Image::from_layer(layer)
                        .write()
                        .to_buffered(&mut out)
                        .map_err(|e| FilmError::Encode {
                            format: "OpenEXR",
                            message: e.to_string(),
                        })?
                }};
            }
            match &alpha {
                None => write_layer!(SpecificChannels::rgb(|at: Vec2<usize>| {
                    let [r, g, b] = px[at.y() * width + at.x()];
                    (r, g, b)
                })),
                Some(a) => write_layer!(SpecificChannels::rgba(|at: Vec2<usize>| {
                    let i = at.y() * width + at.x();
                    let [r, g, b] = px[i];
                    (r, g, b, a[i])
                })),
            }
        }
        ImageFormat::Hdr => {
            // Radiance files have no alpha channel: a film with one is written as its
            // premultiplied colour (the image laid over black).
            // RGBE keeps a pixel's shared exponent in one byte, from 2^-128 up: a pixel whose
            // brightest channel is below f32's normal range would wrap it around (and read
            // back near 10^38). Such a pixel is black.
            let data: Vec<image::Rgb<f32>> = px
                .iter()
                .map(|p| {
                    let p = p.map(|v| v.max(0.0));
                    if p[0].max(p[1]).max(p[2]) < f32::MIN_POSITIVE {
                        image::Rgb([0.0; 3])
                    } else {
                        image::Rgb(p)
                    }
                })
                .collect();
            if w > HDR_RLE_WIDTH {
                write_flat_hdr(&mut out, &data, w, h).map_err(|e| FilmError::Encode {
                    format: "HDR",
                    message: e.to_string(),
                })?;
            } else {
                image::codecs::hdr::HdrEncoder::new(&mut out)
                    .encode(&data, w as usize, h as usize)
                    .map_err(err("HDR"))?;
            }
            if !meta.is_empty() {
                // Header lines go after the first (`#?RADIANCE`), before the blank line.
                let mut bytes = out.into_inner();
                let first = bytes.iter().position(|&b| b == b'\n').map_or(0, |i| i + 1);
                bytes.splice(first..first, meta.hdr_lines().into_bytes());
                out = Cursor::new(bytes);
            }
        }
        ImageFormat::Png => {
            let scale = opts.exposure.exp2();
            let byte = |v: f32| {
                let v = (v * scale).max(0.0);
                let v = match opts.tonemap {
                    ToneMap::Clamp => v.min(1.0),
                    ToneMap::Aces => aces(v),
                };
                (linear_to_srgb(v) * 255.0 + 0.5) as u8
            };
            let bytes: Vec<u8> = match &alpha {
                None => px.iter().flatten().map(|&v| byte(v)).collect(),
                // PNG's alpha is straight: the colour is divided by alpha before it is exposed,
                // tone-mapped and encoded (colour where alpha is 0, which only `bdpt`'s light
                // paths joined to the camera can leave, cannot be kept: EXR keeps it).
                Some(a) => px
                    .iter()
                    .zip(a)
                    .flat_map(|(p, &a)| {
                        let c = p.map(|v| if a > 0.0 { byte(v / a) } else { 0 });
                        let a = (a.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
                        [c[0], c[1], c[2], a]
                    })
                    .collect(),
            };
            let colour = if alpha.is_some() {
                png::ColorType::Rgba
            } else {
                png::ColorType::Rgb
            };
            write_png(&mut out, &bytes, colour, w, h, meta).map_err(|e| FilmError::Encode {
                format: "PNG",
                message: e.to_string(),
            })?;
        }
    }
    Ok(out.into_inner())
}

/// An 8-bit PNG of `data` (RGB or RGBA, as `colour` says), marked sRGB (an `sRGB` chunk, with
/// the `gAMA` and `cHRM` that readers without colour management use), with `meta` in `iTXt`
/// chunks.
fn write_png(
    out: &mut impl std::io::Write,
    data: &[u8],
    colour: png::ColorType,
    w: u32,
    h: u32,
    meta: &Metadata,
) -> Result<(), png::EncodingError> {
    let mut enc = png::Encoder::new(out, w, h);
    enc.set_color(colour);
    enc.set_depth(png::BitDepth::Eight);
    // What the image crate's encoder used: fast deflate, adaptive filters (and no dependence
    // on which zlib backend the build links).
    enc.set_compression(png::Compression::Fast);
    enc.set_filter(png::Filter::Adaptive);
    enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
    // The fallback for readers without colour management: the png crate writes gAMA and cHRM
    // beside sRGB only when they hold exactly sRGB's values (PNG 1.2, 11.3.3.5).
    enc.set_source_gamma(png::ScaledFloat::from_scaled(45_455));
    enc.set_source_chromaticities(png::SourceChromaticities {
        white: (
            png::ScaledFloat::from_scaled(31_270),
            png::ScaledFloat::from_scaled(32_900),
        ),
        red: (
            png::ScaledFloat::from_scaled(64_000),
            png::ScaledFloat::from_scaled(33_000),
        ),
        green: (
            png::ScaledFloat::from_scaled(30_000),
            png::ScaledFloat::from_scaled(60_000),
        ),
        blue: (
            png::ScaledFloat::from_scaled(15_000),
            png::ScaledFloat::from_scaled(6_000),
        ),
    });
    if !meta.software.is_empty() {
        enc.add_itxt_chunk("Software".into(), meta.software.clone())?;
    }
    if !meta.raytile.is_empty() {
        enc.add_itxt_chunk("raytile".into(), meta.raytile.clone())?;
    }
    let mut writer = enc.write_header()?;
    writer.write_image_data(data)?;
    writer.finish()
}

/// Checks, before a render, that its image can be written to `path`: not a folder, in a folder
/// that exists, where a file can be opened for writing (an existing file is left unchanged; a
/// new one is created and removed). A render that would fail only when it is done fails now;
/// a full disk is still found only when the image is written.
pub fn check_writable(path: &Path) -> Result<(), FilmError> {
    let io = |source| FilmError::Io {
        path: path.display().to_string(),
        source,
    };
    if path.is_dir() {
        return Err(io(std::io::Error::new(
            std::io::ErrorKind::IsADirectory,
            "it is a folder",
        )));
    }
    if path.symlink_metadata().is_ok() && !path.exists() {
        // A link to a file yet to be made: writing creates its target; nothing to try here.
        return Ok(());
    }
    let mut open = std::fs::OpenOptions::new();
    open.write(true);
    if path.exists() {
        open.open(path).map_err(io)?;
    } else {
        open.create_new(true).open(path).map_err(io)?;
        std::fs::remove_file(path).map_err(io)?;
    }
    Ok(())
}

/// Writes the film to `path`, the format chosen by its extension, with `meta` in its header.
pub fn save(
    film: &Film,
    path: &Path,
    opts: &OutputOptions,
    meta: &Metadata,
) -> Result<(), FilmError> {
    let format = ImageFormat::from_path(path)?;
    let bytes = encode_with(film, format, opts, meta)?;
    std::fs::write(path, bytes).map_err(|source| FilmError::Io {
        path: path.display().to_string(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ACES maps every bright value to white, however bright (x² used to overflow to NaN,
    /// written as black, above about 10¹⁹).
    #[test]
    fn aces_is_white_for_any_bright_value() {
        for x in [10.0, 1e6, 1e9, 1e19, 1e30, f32::MAX] {
            assert_eq!(aces(x), 1.0, "{x}");
        }
        assert_eq!(aces(0.0), 0.0);
        assert!(aces(0.18) > 0.1 && aces(0.18) < 0.3);
    }
    use crate::{Tile, TileAccum};
    use rayon::prelude::*;

    /// Every format carries the metadata in its header, readable by other readers, and the
    /// pixels are those of the file without it; a PNG says it is sRGB.
    #[test]
    fn files_say_how_they_were_made() {
        let f = film();
        let settings = crate::RenderSettings {
            spp: 4,
            environment: Some(crate::EnvironmentChoice::Map(
                "/far/away/maps/sky.hdr".into(),
            )),
            ..Default::default()
        };
        let meta = Metadata::of_render(&settings, &f);
        assert!(meta.software.starts_with("raytile "), "{meta:?}");
        let json: serde_json::Value = serde_json::from_str(&meta.raytile).unwrap();
        assert_eq!(json["render_version"], crate::RENDER_VERSION);
        assert_eq!(json["settings"]["spp"], 4);
        assert_eq!(json["settings"]["environment"], "sky.hdr", "no folders");
        assert!(
            json["settings"].get("tile_size").is_none(),
            "scheduling only"
        );
        assert_eq!(json["samples_per_pixel"], 1.0);
        assert_eq!(json["dropped_samples"], 0);
        // Another tile size or map folder: the same metadata (the same file bytes).
        let other = crate::RenderSettings {
            tile_size: 7,
            environment: Some(crate::EnvironmentChoice::Map("environment/sky.hdr".into())),
            ..settings.clone()
        };
        assert_eq!(Metadata::of_render(&other, &f), meta);

        let opts = OutputOptions::default();
        let png = encode_with(&f, ImageFormat::Png, &opts, &meta).unwrap();
        let mut reader = png::Decoder::new(Cursor::new(&png)).read_info().unwrap();
        let info = reader.info();
        assert!(info.srgb.is_some(), "an sRGB chunk");
        assert_eq!(
            info.gama_chunk.map(|g| g.into_scaled()),
            Some(45_455),
            "a gAMA chunk"
        );
        assert!(info.chrm_chunk.is_some(), "a cHRM chunk");
        let texts: Vec<(String, String)> = info
            .utf8_text
            .iter()
            .map(|t| (t.keyword.clone(), t.get_text().unwrap()))
            .collect();
        assert!(
            texts.contains(&("Software".into(), meta.software.clone())),
            "{texts:?}"
        );
        assert!(
            texts.contains(&("raytile".into(), meta.raytile.clone())),
            "{texts:?}"
        );
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut buf).unwrap();
        let plain = image::load_from_memory(&encode(&f, ImageFormat::Png, &opts).unwrap())
            .unwrap()
            .to_rgb8();
        assert_eq!(buf, plain.into_raw(), "the same pixels");

        let exr = encode_with(&f, ImageFormat::Exr, &opts, &meta).unwrap();
        let read = exr::meta::MetaData::read_from_buffered(Cursor::new(&exr), false).unwrap();
        let attrs = &read.headers[0].own_attributes;
        assert_eq!(
            attrs.software_name.as_ref().map(|t| t.to_string()),
            Some(meta.software.clone())
        );
        let key = exr::prelude::Text::from("raytile");
        match attrs.other.get(&key) {
            Some(exr::meta::attribute::AttributeValue::Text(t)) => {
                assert_eq!(t.to_string(), meta.raytile)
            }
            other => panic!("{other:?}"),
        }
        let rgb = |bytes: &[u8]| {
            image::load_from_memory(bytes)
                .unwrap()
                .to_rgb32f()
                .into_raw()
        };
        let plain = encode(&f, ImageFormat::Exr, &opts).unwrap();
        assert_eq!(rgb(&exr), rgb(&plain));

        let hdr = encode_with(&f, ImageFormat::Hdr, &opts, &meta).unwrap();
        let head = String::from_utf8_lossy(&hdr[..hdr.len().min(600)]).into_owned();
        assert!(head.starts_with("#?RADIANCE\nSOFTWARE=raytile "), "{head}");
        assert!(head.contains("\nraytile={\""), "{head}");
        let plain = encode(&f, ImageFormat::Hdr, &opts).unwrap();
        assert_eq!(rgb(&hdr), rgb(&plain));
    }

    #[test]
    fn an_output_that_cannot_be_written_is_found_before_the_render() {
        let dir = std::env::temp_dir().join(format!("raytile-writable-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let new = dir.join("new.png");
        check_writable(&new).unwrap();
        assert!(!new.exists(), "the probe file is removed");
        std::fs::write(&new, b"old").unwrap();
        check_writable(&new).unwrap();
        assert_eq!(
            std::fs::read(&new).unwrap(),
            b"old",
            "an existing file is left as it is"
        );
        for bad in [dir.join("missing/x.png"), dir.clone()] {
            let e = check_writable(&bad).unwrap_err();
            let FilmError::Io { path, .. } = &e else {
                panic!("{e}");
            };
            assert_eq!(path, &bad.display().to_string());
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn film() -> Film {
        let mut f = Film::new(3, 2);
        f.add_tile(&TileAccum {
            tile: Tile {
                x0: 0,
                y0: 0,
                x1: 3,
                y1: 2,
            },
            pixels: (0..6).map(|i| [i as f32 * 0.25, 0.5, 2.0, 1.0]).collect(),
            bad_samples: 0,
            splats: Vec::new(),
            coverage: Vec::new(),
        })
        .unwrap();
        f
    }

    /// A film with an alpha channel: pixel i has weight 4 and coverage i mod 5 (alpha 0, ¼,
    /// ½, ¾, 1, 0), its premultiplied colour that alpha times (0.8, 0.4, 0.1).
    fn film_with_alpha() -> Film {
        let mut f = Film::with_alpha(3, 2, true);
        let coverage: Vec<f32> = (0..6).map(|i| (i % 5) as f32).collect();
        f.add_tile(&TileAccum {
            tile: Tile {
                x0: 0,
                y0: 0,
                x1: 3,
                y1: 2,
            },
            pixels: coverage
                .iter()
                .map(|&c| [0.8 * c, 0.4 * c, 0.1 * c, 4.0])
                .collect(),
            bad_samples: 0,
            splats: Vec::new(),
            coverage,
        })
        .unwrap();
        f
    }

    /// EXR files carry alpha beside the premultiplied colour, PNG files a straight alpha (the
    /// colour divided by it before it is encoded), Radiance files the premultiplied colour.
    #[test]
    fn alpha_reaches_every_file_as_its_format_keeps_it() {
        let f = film_with_alpha();
        assert_eq!(
            f.alpha().unwrap(),
            [0.0, 0.25, 0.5, 0.75, 1.0, 0.0],
            "coverage over weight"
        );
        let opts = OutputOptions::default();
        let exr = encode(&f, ImageFormat::Exr, &opts).unwrap();
        let img = image::load_from_memory_with_format(&exr, image::ImageFormat::OpenExr)
            .unwrap()
            .into_rgba32f();
        for (i, p) in img.pixels().enumerate() {
            let a = f.alpha().unwrap()[i];
            assert_eq!(p.0, [0.8 * a, 0.4 * a, 0.1 * a, a], "pixel {i}");
        }
        let png = encode(&f, ImageFormat::Png, &opts).unwrap();
        let decoder = png::Decoder::new(std::io::Cursor::new(&png));
        let reader = decoder.read_info().unwrap();
        assert_eq!(reader.info().color_type, png::ColorType::Rgba);
        let img = image::load_from_memory(&png).unwrap().into_rgba8();
        let straight = |v: f32| (linear_to_srgb(v) * 255.0 + 0.5) as u8;
        for (i, p) in img.pixels().enumerate() {
            let a = f.alpha().unwrap()[i];
            let want = if a > 0.0 {
                [
                    straight(0.8),
                    straight(0.4),
                    straight(0.1),
                    (a * 255.0 + 0.5) as u8,
                ]
            } else {
                [0; 4]
            };
            assert_eq!(p.0, want, "pixel {i}");
        }
        let hdr = encode(&f, ImageFormat::Hdr, &opts).unwrap();
        let img = image::load_from_memory(&hdr).unwrap().into_rgb32f();
        let p = img.get_pixel(2, 0).0;
        // RGBE keeps 8 bits of mantissa for the brightest channel.
        assert!(
            (p[0] - 0.4).abs() < 0.01 && (p[2] - 0.05).abs() < 0.003,
            "{p:?}"
        );
        // Without an alpha channel the files are RGB as before.
        let png = encode(&film(), ImageFormat::Png, &opts).unwrap();
        let reader = png::Decoder::new(std::io::Cursor::new(&png))
            .read_info()
            .unwrap();
        assert_eq!(reader.info().color_type, png::ColorType::Rgb);
    }

    #[test]
    fn exr_round_trips_exactly() {
        let bytes = encode(&film(), ImageFormat::Exr, &OutputOptions::default()).unwrap();
        let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::OpenExr)
            .unwrap()
            .into_rgb32f();
        assert_eq!(img.dimensions(), (3, 2));
        assert_eq!(img.get_pixel(2, 1).0, [1.25, 0.5, 2.0]);
    }

    /// A frame of many tiles encodes to the same bytes every time, whatever the threads do:
    /// the tiles are written in increasing order.
    #[test]
    fn exr_bytes_are_the_same_every_time() {
        let (w, h) = (300, 200);
        let mut f = Film::new(w, h);
        f.add_tile(&TileAccum {
            tile: Tile {
                x0: 0,
                y0: 0,
                x1: w,
                y1: h,
            },
            pixels: (0..w * h)
                .map(|i| [(i % 7) as f32, (i % 13) as f32 * 0.5, (i / w) as f32, 1.0])
                .collect(),
            bad_samples: 0,
            splats: Vec::new(),
            coverage: Vec::new(),
        })
        .unwrap();
        let once = encode(&f, ImageFormat::Exr, &OutputOptions::default()).unwrap();
        let img = image::load_from_memory_with_format(&once, image::ImageFormat::OpenExr)
            .unwrap()
            .into_rgb32f();
        assert_eq!(
            img.get_pixel(299, 199).0,
            [(59999 % 7) as f32, 0.5 * (59999 % 13) as f32, 199.0]
        );
        let again: Vec<Vec<u8>> = (0..16)
            .into_par_iter()
            .map(|_| encode(&f, ImageFormat::Exr, &OutputOptions::default()).unwrap())
            .collect();
        assert!(again.iter().all(|b| *b == once));
    }

    /// `.hdr` files read back as the film, within RGBE's 8-bit mantissa: a pixel too dim for
    /// its exponent byte is black (not 10^38), and the widest frame is written flat (run-length
    /// encoding cannot state a scanline of 32,768 pixels).
    #[test]
    fn hdr_keeps_dim_pixels_black_and_the_widest_frames_readable() {
        let values = [1.0e-39f32, 3.0, 1.5e-38, 2.0e30, 0.0, 0.7];
        for w in [6u32, 32_768] {
            let mut f = Film::new(w, 1);
            for (i, p) in f.pixels.iter_mut().enumerate() {
                let v = values[i % values.len()];
                *p = [v, v * 0.5, 0.0, 1.0];
            }
            let hdr = encode(&f, ImageFormat::Hdr, &OutputOptions::default()).unwrap();
            let img = image::load_from_memory_with_format(&hdr, image::ImageFormat::Hdr)
                .unwrap()
                .into_rgb32f();
            assert_eq!(img.dimensions(), (w, 1));
            for (x, want) in values.iter().cycle().take(w.min(60) as usize).enumerate() {
                let got = img.get_pixel(x as u32, 0).0;
                let want = if *want < f32::MIN_POSITIVE {
                    0.0
                } else {
                    *want
                };
                assert!(
                    (got[0] - want).abs() <= want / 64.0
                        && (got[1] - want * 0.5).abs() <= want / 64.0,
                    "width {w}, pixel {x}: {got:?}, want {want}"
                );
            }
        }
    }

    #[test]
    fn png_and_hdr_encode() {
        let png = encode(
            &film(),
            ImageFormat::Png,
            &OutputOptions {
                exposure: 0.0,
                tonemap: ToneMap::Aces,
            },
        )
        .unwrap();
        let img = image::load_from_memory(&png).unwrap().into_rgb8();
        assert_eq!(img.get_pixel(0, 0).0[0], 0);
        let hdr = encode(&film(), ImageFormat::Hdr, &OutputOptions::default()).unwrap();
        assert!(hdr.starts_with(b"#?RADIANCE"));
        assert!(ImageFormat::from_path(Path::new("x.jpg")).is_err());
        for f in ImageFormat::ALL {
            let upper = format!("x.{}", f.name().to_ascii_uppercase());
            assert_eq!(ImageFormat::from_path(Path::new(&upper)).unwrap(), f);
        }
    }
}
