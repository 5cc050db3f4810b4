//! Image textures: lookup with wrap modes, bilinear filtering and sRGB decoding.

use glam::{Mat3, Vec2, Vec3, Vec4};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Texture addressing outside [0, 1].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WrapMode {
    /// Tile the image.
    #[default]
    Repeat,
    /// Tile the image, mirroring every other copy.
    MirroredRepeat,
    /// Use the edge texel.
    Clamp,
}

/// How a texture is looked up between and beyond its texels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TextureLookup {
    /// Addressing outside [0, 1] along u.
    pub wrap_u: WrapMode,
    /// Addressing outside [0, 1] along v.
    pub wrap_v: WrapMode,
    /// Bilinear (true) or nearest (false) magnification.
    pub bilinear: bool,
}

/// An image's RGBA texels, row by row from the top, as decoded: colour stays encoded as
/// stored (sRGB or linear), alpha is linear. Shared, not copied, by the textures that sample
/// one image in different ways (wrap modes, filters, colour or data).
#[derive(Clone, Debug, PartialEq)]
pub enum Texels {
    /// Floating-point values (HDR, EXR and 16-bit images, and images made by programs).
    F32(Arc<Vec<[f32; 4]>>),
    /// The bytes of an 8-bit image (PNG, JPEG): a quarter of the memory of `F32`. Byte `b`
    /// stands for the value `b / 255`, correctly rounded.
    Unorm8(Arc<Vec<[u8; 4]>>),
}

impl Texels {
    /// Number of texels.
    pub fn len(&self) -> usize {
        match self {
            Texels::F32(t) => t.len(),
            Texels::Unorm8(t) => t.len(),
        }
    }

    /// Whether there are no texels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Texel `i` as values.
    pub fn get(&self, i: usize) -> [f32; 4] {
        match self {
            Texels::F32(t) => t[i],
            Texels::Unorm8(t) => t[i].map(|b| UNORM8[0][b as usize]),
        }
    }

    /// Bytes the texels take (once, however many share them).
    pub fn bytes(&self) -> usize {
        match self {
            Texels::F32(t) => t.capacity() * std::mem::size_of::<[f32; 4]>(),
            Texels::Unorm8(t) => t.capacity() * std::mem::size_of::<[u8; 4]>(),
        }
    }

    /// Whether `self` and `other` are the same texels in memory (one decoded image).
    pub fn shares(&self, other: &Texels) -> bool {
        match (self, other) {
            (Texels::F32(a), Texels::F32(b)) => Arc::ptr_eq(a, b),
            (Texels::Unorm8(a), Texels::Unorm8(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

impl From<Vec<[f32; 4]>> for Texels {
    fn from(t: Vec<[f32; 4]>) -> Self {
        Texels::F32(Arc::new(t))
    }
}

impl From<Vec<[u8; 4]>> for Texels {
    fn from(t: Vec<[u8; 4]>) -> Self {
        Texels::Unorm8(Arc::new(t))
    }
}

impl FromIterator<[f32; 4]> for Texels {
    fn from_iter<I: IntoIterator<Item = [f32; 4]>>(iter: I) -> Self {
        Texels::from(iter.into_iter().collect::<Vec<_>>())
    }
}

/// What byte `b` of an 8-bit image stands for: `[0][b]` the value `b / 255` (correctly
/// rounded, as the image decoder converts RGB bytes to f32), `[1][b]` that value decoded from
/// sRGB to linear, as [`Texture::from_texels`] decodes f32 texels, so that an 8-bit texture
/// looks up the same bits whether it keeps its bytes or their values.
static UNORM8: std::sync::LazyLock<[[f32; 256]; 2]> = std::sync::LazyLock::new(|| {
    let value = std::array::from_fn(|b| b as f32 / 255.0);
    [value, value.map(|v| texel_value(srgb_to_linear(v)))]
});

/// A texel value as textures keep it: NaN and infinities become zero, negative values zero.
#[inline]
fn texel_values(v: Vec4) -> Vec4 {
    if v.is_finite() {
        v.max(Vec4::ZERO)
    } else {
        Vec4::ZERO
    }
}

/// [`texel_values`] of one channel.
fn texel_value(x: f32) -> f32 {
    texel_values(Vec4::splat(x)).x
}

/// How a texture holds its texels: shared with the textures that read the same image the
/// same way (colour or data) and only sample it differently.
#[derive(Clone, Debug)]
enum Store {
    /// Linear RGBA values (arrays rather than `Vec4`s, so the loader's buffer is reused).
    F32(Arc<Vec<[f32; 4]>>),
    /// The bytes of an 8-bit image, read on lookup through the tables of [`UNORM8`] chosen
    /// when the texture is made: `colour` (decoding sRGB, or not) and `alpha`.
    Unorm8 {
        texels: Arc<Vec<[u8; 4]>>,
        colour: &'static [f32; 256],
        alpha: &'static [f32; 256],
    },
}

/// A texture ready for lookups: texels are linear (sRGB decoded once at build time, or on
/// lookup through a table for 8-bit images, to the same bits).
#[derive(Clone, Debug)]
pub struct Texture {
    width: u32,
    height: u32,
    store: Store,
    wrap_u: WrapMode,
    wrap_v: WrapMode,
    bilinear: bool,
}

/// sRGB transfer function, decoding.
#[inline]
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        // Above about 1.2e16 (a hot texel of an HDR image marked as colour) the power
        // overflows: the largest float instead, not an infinity that becomes a black texel.
        let v = ((c + 0.055) / 1.055).powf(2.4);
        if v == f32::INFINITY && c.is_finite() {
            f32::MAX
        } else {
            v
        }
    }
}

/// sRGB transfer function, encoding.
#[inline]
pub fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

impl Texture {
    /// A `width × height` image from its RGBA texels, row by row from the top, decoding sRGB
    /// colour (not alpha) to linear once here when `srgb`. Non-finite texels become zero, and
    /// negative values zero (no texture of colour, alpha, normals or light has a meaning
    /// below it); a texel count that does not match the size gives a single white texel.
    pub fn new(
        width: u32,
        height: u32,
        texels: &[[f32; 4]],
        srgb: bool,
        lookup: TextureLookup,
    ) -> Self {
        Self::from_texels(width, height, texels.to_vec(), srgb, lookup)
    }

    /// [`Texture::new`] taking the texels by value: f32 texels are converted in place (unless
    /// other textures share them: then a converted copy is made), so a large image is held
    /// once while its texture is made, not twice; the bytes of an 8-bit image are kept as
    /// they are, shared with whatever else holds them.
    pub fn from_texels(
        width: u32,
        height: u32,
        texels: impl Into<Texels>,
        srgb: bool,
        lookup: TextureLookup,
    ) -> Self {
        let texels = texels.into();
        let expected = width as usize * height as usize;
        let (width, height, store) = if expected == 0 || texels.len() != expected {
            (1, 1, Store::F32(Arc::new(vec![[1.0; 4]])))
        } else {
            let store = match texels {
                Texels::F32(texels) => {
                    let mut texels = Arc::unwrap_or_clone(texels);
                    for t in &mut texels {
                        let [r, g, b, a] = *t;
                        let v = if srgb {
                            Vec4::new(srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b), a)
                        } else {
                            Vec4::new(r, g, b, a)
                        };
                        *t = texel_values(v).to_array();
                    }
                    texels.shrink_to_fit();
                    Store::F32(Arc::new(texels))
                }
                Texels::Unorm8(mut texels) => {
                    if let Some(t) = Arc::get_mut(&mut texels) {
                        t.shrink_to_fit();
                    }
                    let lut: &'static [[f32; 256]; 2] = &UNORM8;
                    Store::Unorm8 {
                        texels,
                        colour: &lut[usize::from(srgb)],
                        alpha: &lut[0],
                    }
                }
            };
            (width, height, store)
        };
        Self {
            width,
            height,
            store,
            wrap_u: lookup.wrap_u,
            wrap_v: lookup.wrap_v,
            bilinear: lookup.bilinear,
        }
    }

    /// The same texels (shared, not copied) looked up with `lookup`.
    pub fn with_lookup(&self, lookup: TextureLookup) -> Texture {
        Texture {
            wrap_u: lookup.wrap_u,
            wrap_v: lookup.wrap_v,
            bilinear: lookup.bilinear,
            ..self.clone()
        }
    }

    /// An address that identifies the texels in memory: textures that share their texels
    /// give the same one (so that memory is counted once).
    pub fn texels_id(&self) -> usize {
        match &self.store {
            Store::F32(t) => Arc::as_ptr(t) as usize,
            Store::Unorm8 { texels, .. } => Arc::as_ptr(texels) as usize,
        }
    }

    /// Bytes of texel memory, for cache budgets (shared texels count in full for each
    /// texture that holds them: see [`Texture::texels_id`]).
    pub fn memory_bytes(&self) -> usize {
        match &self.store {
            Store::F32(t) => t.capacity() * std::mem::size_of::<[f32; 4]>(),
            Store::Unorm8 { texels, .. } => texels.capacity() * std::mem::size_of::<[u8; 4]>(),
        }
    }

    /// Texel `i` (row by row) as linear values.
    #[inline]
    fn at(&self, i: usize) -> Vec4 {
        match &self.store {
            Store::F32(t) => Vec4::from_array(t[i]),
            Store::Unorm8 {
                texels,
                colour,
                alpha,
            } => {
                let [r, g, b, a] = texels[i];
                Vec4::new(
                    colour[r as usize],
                    colour[g as usize],
                    colour[b as usize],
                    alpha[a as usize],
                )
            }
        }
    }

    /// Width in texels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Texel (x, y) with wrapping applied to integer coordinates.
    #[inline]
    pub fn texel(&self, x: i64, y: i64) -> Vec4 {
        let x = wrap(x, self.width as i64, self.wrap_u);
        let y = wrap(y, self.height as i64, self.wrap_v);
        self.at(y as usize * self.width as usize + x as usize)
    }

    /// Filtered value at `uv` ((0,0) is the top-left corner of the image, as in glTF).
    #[inline]
    pub fn lookup(&self, uv: Vec2) -> Vec4 {
        if !uv.is_finite() {
            return self.at(0);
        }
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        if !self.bilinear {
            return self.texel((x + 0.5).floor() as i64, (y + 0.5).floor() as i64);
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        // A huge coordinate saturates to i64::MAX: its neighbour wraps (as release builds
        // always did) rather than overflowing.
        let (x0, y0) = (x0 as i64, y0 as i64);
        let (x1, y1) = (x0.wrapping_add(1), y0.wrapping_add(1));
        let a = self.texel(x0, y0).lerp(self.texel(x1, y0), fx);
        let b = self.texel(x0, y1).lerp(self.texel(x1, y1), fx);
        a.lerp(b, fy)
    }
}

#[inline]
fn wrap(i: i64, n: i64, mode: WrapMode) -> i64 {
    match mode {
        WrapMode::Clamp => i.clamp(0, n - 1),
        WrapMode::Repeat => i.rem_euclid(n),
        WrapMode::MirroredRepeat => {
            let m = i.rem_euclid(2 * n);
            if m < n {
                m
            } else {
                2 * n - 1 - m
            }
        }
    }
}

/// A texture reference resolved for lookups.
#[derive(Clone, Copy, Debug)]
pub struct TexSlot {
    /// Index into the scene's textures.
    pub texture: u32,
    /// Texture coordinate set.
    pub texcoord: u8,
    /// UV transform (None: identity, the common case, skipped).
    pub transform: Option<Mat3>,
}

impl TexSlot {
    /// Texture `texture` through coordinate set `texcoord` (0 or 1; higher sets read set 1)
    /// and the uv transform `transform` (the identity is skipped at lookup).
    pub fn new(texture: u32, texcoord: u8, transform: Mat3) -> Self {
        let identity = transform.abs_diff_eq(Mat3::IDENTITY, 0.0);
        Self {
            texture,
            texcoord: texcoord.min(1),
            transform: (!identity).then_some(transform),
        }
    }

    /// Looks the slot up given both uv sets.
    #[inline]
    pub fn lookup(&self, textures: &[Texture], uvs: &[Vec2; 2]) -> Vec4 {
        let mut uv = uvs[self.texcoord as usize];
        if let Some(m) = self.transform {
            let v = m * Vec3::new(uv.x, uv.y, 1.0);
            uv = Vec2::new(v.x, v.y);
        }
        textures[self.texture as usize].lookup(uv)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tex(srgb: bool, wrap: WrapMode, bilinear: bool) -> Texture {
        Texture::new(
            2,
            1,
            &[[0.0, 0.0, 0.0, 1.0], [0.5, 0.5, 0.5, 1.0]],
            srgb,
            TextureLookup {
                wrap_u: wrap,
                wrap_v: wrap,
                bilinear,
            },
        )
    }

    #[test]
    fn srgb_is_decoded_and_linear_is_not() {
        let s = tex(true, WrapMode::Clamp, false).lookup(Vec2::new(0.75, 0.5));
        let l = tex(false, WrapMode::Clamp, false).lookup(Vec2::new(0.75, 0.5));
        assert!((s.x - 0.214_041).abs() < 1e-4, "{s}");
        assert_eq!(l.x, 0.5);
        assert!((linear_to_srgb(srgb_to_linear(0.3)) - 0.3).abs() < 1e-5);
        // A hot HDR value decoded as colour saturates rather than overflowing to infinity
        // (which the texture would read as black).
        assert_eq!(srgb_to_linear(1.7e38), f32::MAX);
        assert!(srgb_to_linear(f32::NAN).is_nan());
    }

    /// NaN, infinite and negative texels (a few are common in real EXR files) are read as 0.
    #[test]
    fn bad_texels_are_read_as_zero() {
        let lookup = TextureLookup {
            wrap_u: WrapMode::Clamp,
            wrap_v: WrapMode::Clamp,
            bilinear: false,
        };
        let t = Texture::new(
            3,
            1,
            &[
                [f32::NAN, 0.5, 0.5, 1.0],
                [f32::INFINITY, 0.5, 0.5, 1.0],
                [-0.25, 0.5, 2.0, 1.0],
            ],
            false,
            lookup,
        );
        assert_eq!(t.texel(0, 0), Vec4::ZERO);
        assert_eq!(t.texel(1, 0), Vec4::ZERO);
        assert_eq!(t.texel(2, 0), Vec4::new(0.0, 0.5, 2.0, 1.0));
    }

    /// An 8-bit texture keeps its bytes and looks up exactly what it looked up when the
    /// decoder's f32 values were kept: every byte, both colour spaces, both filters.
    #[test]
    fn eight_bit_textures_look_up_the_bits_of_their_values() {
        let (w, h) = (17u32, 15u32);
        let bytes = image::RgbaImage::from_fn(w, h, |x, y| {
            let i = y * w + x;
            // Every byte value in some channel, alpha included.
            image::Rgba([i as u8, (i * 7 + 3) as u8, (255 - i) as u8, (i * 13) as u8])
        });
        // The decoder's own conversion of RGBA bytes gives the same values.
        let values = image::DynamicImage::ImageRgba8(bytes.clone()).into_rgba32f();
        let unorm8 = Texels::from(bytes.pixels().map(|p| p.0).collect::<Vec<_>>());
        let f32s = Texels::from(values.pixels().map(|p| p.0).collect::<Vec<_>>());
        for i in 0..unorm8.len() {
            assert_eq!(
                unorm8.get(i).map(f32::to_bits),
                f32s.get(i).map(f32::to_bits)
            );
        }
        for srgb in [false, true] {
            for bilinear in [false, true] {
                let lookup = TextureLookup {
                    wrap_u: WrapMode::Repeat,
                    wrap_v: WrapMode::MirroredRepeat,
                    bilinear,
                };
                let a = Texture::from_texels(w, h, unorm8.clone(), srgb, lookup);
                let b = Texture::from_texels(w, h, f32s.clone(), srgb, lookup);
                assert_eq!(a.memory_bytes() * 4, b.memory_bytes());
                for k in 0..2000u32 {
                    let u = crate::sampling::hash_u32(k) as f32 / u32::MAX as f32 * 3.0 - 1.0;
                    let v = crate::sampling::hash_u32(k ^ 0x5555) as f32 / u32::MAX as f32 * 3.0;
                    let uv = Vec2::new(u, v);
                    assert_eq!(
                        a.lookup(uv).to_array().map(f32::to_bits),
                        b.lookup(uv).to_array().map(f32::to_bits),
                        "srgb {srgb}, bilinear {bilinear}, uv {uv}"
                    );
                }
            }
        }
    }

    #[test]
    fn wrap_modes() {
        assert_eq!(wrap(-1, 4, WrapMode::Repeat), 3);
        assert_eq!(wrap(5, 4, WrapMode::Clamp), 3);
        assert_eq!(wrap(4, 4, WrapMode::MirroredRepeat), 3);
        assert_eq!(wrap(-1, 4, WrapMode::MirroredRepeat), 0);
        let t = tex(false, WrapMode::Repeat, false);
        assert_eq!(t.lookup(Vec2::new(1.75, 0.5)).x, 0.5);
    }

    #[test]
    fn bilinear_blends_neighbours() {
        let t = tex(false, WrapMode::Clamp, true);
        assert!((t.lookup(Vec2::new(0.5, 0.5)).x - 0.25).abs() < 1e-6);
    }
}
