//! Image textures: lookup with wrap modes, bilinear filtering and sRGB decoding.

use glam::{Mat3, Vec2, Vec3, Vec4};
use serde::{Deserialize, Serialize};

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

/// A texture ready for lookups: texels are linear (sRGB decoded once at build time).
#[derive(Clone, Debug)]
pub struct Texture {
    width: u32,
    height: u32,
    /// Linear RGBA, row by row (arrays rather than `Vec4`s, so the loader's buffer is reused).
    texels: Vec<[f32; 4]>,
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
        ((c + 0.055) / 1.055).powf(2.4)
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

    /// [`Texture::new`] taking the texels by value: they are converted in place, so a large
    /// image is held once while its texture is made, not twice.
    pub fn from_texels(
        width: u32,
        height: u32,
        mut texels: Vec<[f32; 4]>,
        srgb: bool,
        lookup: TextureLookup,
    ) -> Self {
        let expected = width as usize * height as usize;
        for t in &mut texels {
            let [r, g, b, a] = *t;
            let v = if srgb {
                Vec4::new(srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b), a)
            } else {
                Vec4::new(r, g, b, a)
            };
            *t = if v.is_finite() {
                v.max(Vec4::ZERO)
            } else {
                Vec4::ZERO
            }
            .to_array();
        }
        let (mut width, mut height) = (width, height);
        if expected == 0 || texels.len() != expected {
            texels = vec![[1.0; 4]];
            width = 1;
            height = 1;
        }
        texels.shrink_to_fit();
        Self {
            width,
            height,
            texels,
            wrap_u: lookup.wrap_u,
            wrap_v: lookup.wrap_v,
            bilinear: lookup.bilinear,
        }
    }

    /// Bytes of texel memory, for cache budgets.
    pub fn memory_bytes(&self) -> usize {
        self.texels.capacity() * std::mem::size_of::<[f32; 4]>()
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
        Vec4::from_array(self.texels[y as usize * self.width as usize + x as usize])
    }

    /// Filtered value at `uv` ((0,0) is the top-left corner of the image, as in glTF).
    #[inline]
    pub fn lookup(&self, uv: Vec2) -> Vec4 {
        if !uv.is_finite() {
            return Vec4::from_array(self.texels[0]);
        }
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        if !self.bilinear {
            return self.texel((x + 0.5).floor() as i64, (y + 0.5).floor() as i64);
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let a = self.texel(x0, y0).lerp(self.texel(x0 + 1, y0), fx);
        let b = self.texel(x0, y0 + 1).lerp(self.texel(x0 + 1, y0 + 1), fx);
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
