//! Render settings as they travel: the full [`RenderSettings`] of a job, the [`RenderOverrides`]
//! a user gives (command-line flags, job fields), and their validation.
//!
//! These are plain data. The tracer (`raytile-core`) takes them from here and re-exports them;
//! it also holds the one function that merges a scene's own render settings with overrides
//! (`RenderDefaults::resolve`), because only the tracer reads scenes.

use serde::{Deserialize, Serialize};
use std::ops::Range;

/// Which light-transport algorithm renders the image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IntegratorKind {
    /// Unidirectional path tracing with next-event estimation and MIS.
    #[default]
    Path,
    /// Volumetric path tracing (pbrt-v4's `volpath`): `path` plus participating media (fog,
    /// smoke), with delta tracking, ratio-tracked shadow rays and null-scattering MIS.
    Volpath,
    /// Bidirectional path tracing (pbrt-v4's `bdpt`): light and camera subpaths joined by
    /// every strategy, weighted by MIS; renders caustics that `path` misses. Light subpaths
    /// joined straight to the camera land in other pixels (splats).
    Bdpt,
    /// Stochastic progressive photon mapping (Hachisuka and Jensen; pbrt-v4's `sppm`): per
    /// iteration a visible point per pixel and a photon pass from the lights, the pixel's
    /// radius and flux updated with α = 2/3. Consistent rather than unbiased; renders
    /// caustics from point lights. `spp` is the number of iterations; `passes` must be 1.
    Sppm,
    /// Whitted's recursive ray tracer: shadow rays, mirror reflection and refraction.
    Whitted,
    /// World-space shading normals, each component in [-1, 1]; zero where no surface is seen
    /// (a denoiser's auxiliary buffer).
    Normals,
    /// Surface albedo in [0, 1]; an emitter's, and the sky's, is its colour scaled to at most
    /// one (a denoiser's auxiliary buffer).
    Albedo,
    /// Distance from the camera along the primary ray.
    Depth,
    /// Ambient occlusion.
    Ao,
}

impl IntegratorKind {
    /// Every integrator, for tests and help texts.
    pub const ALL: [IntegratorKind; 9] = [
        Self::Path,
        Self::Volpath,
        Self::Bdpt,
        Self::Sppm,
        Self::Whitted,
        Self::Normals,
        Self::Albedo,
        Self::Depth,
        Self::Ao,
    ];

    /// The name used on the command line and in files (the serde name too).
    pub fn name(self) -> &'static str {
        match self {
            Self::Path => "path",
            Self::Volpath => "volpath",
            Self::Bdpt => "bdpt",
            Self::Sppm => "sppm",
            Self::Whitted => "whitted",
            Self::Normals => "normals",
            Self::Albedo => "albedo",
            Self::Depth => "depth",
            Self::Ao => "ao",
        }
    }
}

impl std::str::FromStr for IntegratorKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| unknown_name("integrator", s, Self::ALL.map(Self::name)))
    }
}

/// Pixel reconstruction filter. Samples are drawn from the filter's own distribution (filter
/// importance sampling, as pbrt-v4 does), so each pixel depends only on its own samples and
/// tiles never share pixels: the result cannot depend on tiling.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FilterKind {
    /// Uniform over the pixel.
    #[default]
    Box,
    /// Truncated Gaussian, radius 1.5 px, σ = 0.5 px.
    Gaussian,
    /// Blackman–Harris window, radius 2 px.
    BlackmanHarris,
}

impl FilterKind {
    /// Every filter.
    pub const ALL: [FilterKind; 3] = [Self::Box, Self::Gaussian, Self::BlackmanHarris];

    /// The name used on the command line and in files (the serde name too).
    pub fn name(self) -> &'static str {
        match self {
            Self::Box => "box",
            Self::Gaussian => "gaussian",
            Self::BlackmanHarris => "blackman-harris",
        }
    }
}

impl std::str::FromStr for FilterKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| unknown_name("filter", s, Self::ALL.map(Self::name)))
    }
}

fn unknown_name<const N: usize>(what: &str, got: &str, names: [&str; N]) -> String {
    format!(
        "unknown {what} '{got}' (expected one of: {})",
        names.join(", ")
    )
}

/// The light a job brings, in place of the scene's own environment (and of the default light
/// of an unlit glTF model). Written as one string, on the command line as in JSON:
/// `none`, `R,G,B` (a constant linear radiance) or the path of an equirectangular map ending
/// in `.hdr` or `.exr`.
///
/// A map's path is read as given by `raytile render`; on a farm it names a file inside the
/// scene's folder (`raytile submit` packs the map with the scene and names it so).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum EnvironmentChoice {
    /// No environment: only the scene's own lights and emitters.
    None,
    /// The same radiance from every direction (linear RGB, each component finite and ≥ 0).
    Constant([f32; 3]),
    /// An equirectangular (latitude–longitude) map, importance-sampled.
    Map(String),
}

impl EnvironmentChoice {
    /// What a value may be, for error messages.
    pub const EXPECTED: &'static str = "none, R,G,B (e.g. 0.5,0.5,0.5) or a .hdr or .exr map";
}

impl std::str::FromStr for EnvironmentChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("none") {
            return Ok(EnvironmentChoice::None);
        }
        let lower = t.to_ascii_lowercase();
        if lower.ends_with(".hdr") || lower.ends_with(".exr") {
            return Ok(EnvironmentChoice::Map(t.to_string()));
        }
        let parts: Vec<&str> = t.split(',').map(str::trim).collect();
        if parts.len() == 3 {
            let mut c = [0.0f32; 3];
            for (v, p) in c.iter_mut().zip(&parts) {
                *v = p
                    .parse::<f32>()
                    .ok()
                    .filter(|v| v.is_finite() && *v >= 0.0)
                    .ok_or_else(|| {
                        format!("'{s}': each of R,G,B must be a finite number ≥ 0, got '{p}'")
                    })?;
            }
            return Ok(EnvironmentChoice::Constant(c));
        }
        Err(format!("'{s}': expected {}", Self::EXPECTED))
    }
}

impl std::fmt::Display for EnvironmentChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            EnvironmentChoice::None => f.write_str("none"),
            EnvironmentChoice::Constant([r, g, b]) => write!(f, "{r},{g},{b}"),
            EnvironmentChoice::Map(p) => f.write_str(p),
        }
    }
}

impl TryFrom<String> for EnvironmentChoice {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        s.parse()
    }
}

impl From<EnvironmentChoice> for String {
    fn from(e: EnvironmentChoice) -> String {
        e.to_string()
    }
}

/// A rectangle of pixels `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Tile {
    /// Left column (inclusive).
    pub x0: u32,
    /// Top row (inclusive).
    pub y0: u32,
    /// Right column (exclusive).
    pub x1: u32,
    /// Bottom row (exclusive).
    pub y1: u32,
}

impl Tile {
    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.x1 - self.x0
    }
    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.y1 - self.y0
    }
    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width() as usize * self.height() as usize
    }
}

/// `[x0, x1) × [y0, y1)`, as messages and docs name tiles.
impl std::fmt::Display for Tile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "[{}, {}) × [{}, {})", self.x0, self.x1, self.y0, self.y1)
    }
}

/// Settings of one render. `Default` gives raytile's defaults; a scene's own settings and then
/// [`RenderOverrides`] (command-line flags or job fields) override them.
///
/// On the wire this is what the coordinator sends: in every lease (a worker renders with it)
/// and in every job status. Unknown fields are ignored and missing ones take their default, so
/// that a client of another release can still read a job. Workers never meet a field they do
/// not know: every field is part of what is rendered, so adding one raises the renderer version
/// (`RENDER_VERSION`), and the coordinator refuses workers of another version at registration
/// (see "Compatibility" in `docs/farm.md`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RenderSettings {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Maximum number of bounces (path vertices after the camera).
    pub max_depth: u32,
    /// Light-transport algorithm.
    pub integrator: IntegratorKind,
    /// Seed of the random sequences: change it for an independent image.
    pub seed: u32,
    /// Camera name or index; `None` picks the scene's first camera.
    pub camera: Option<String>,
    /// Reconstruction filter.
    pub filter: FilterKind,
    /// Tile edge in pixels (affects scheduling only, never the result).
    pub tile_size: u32,
    /// Number of progressive passes the samples are split into. Part of the job's identity: the
    /// per-pixel sums are added pass by pass in order, so the same `passes` gives the same bits.
    pub passes: u32,
    /// Whether a glTF scene without any light gets the default white environment its loader
    /// adds (as glTF viewers do). `false` renders such a scene black.
    pub default_light: bool,
    /// The job's own environment, replacing the scene's (and the default light); `None` keeps
    /// the scene's lighting.
    pub environment: Option<EnvironmentChoice>,
    /// Rotation of the job's environment map about +Y, in degrees.
    pub environment_rotation: f32,
    /// Multiplies the job's environment (map or colour).
    pub environment_strength: f32,
    /// Whether the image has an alpha channel: a camera ray that leaves the scene without
    /// meeting a surface or scattering in a medium sees nothing (transparent) instead of the
    /// environment, which still lights the scene. The colour is then premultiplied by the
    /// pixel's alpha, ready to be laid over a background.
    pub alpha: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            width: 512,
            height: 512,
            spp: 64,
            max_depth: 16,
            integrator: IntegratorKind::Path,
            seed: 0,
            camera: None,
            filter: FilterKind::Box,
            tile_size: 32,
            passes: 1,
            default_light: true,
            environment: None,
            environment_rotation: 0.0,
            environment_strength: 1.0,
            alpha: false,
        }
    }
}

/// Largest image edge accepted, in pixels.
pub const MAX_EDGE: u32 = 1 << 15;
/// Largest image accepted, in pixels.
pub const MAX_PIXELS: u64 = 1 << 27;
/// Largest sample count accepted. The sampler draws Owen-scrambled Sobol points for the first
/// 2^16 samples of a pixel (`raytile_core::sampling::SOBOL_SAMPLES`, the sequence's length) and
/// hashed numbers for the samples after them: just as deterministic and unbiased, but not
/// stratified, so the extra samples converge at the plain Monte Carlo rate.
pub const MAX_SPP: u32 = 1 << 20;
/// Longest path accepted.
pub const MAX_DEPTH: u32 = 1024;
/// Largest tile edge accepted, in pixels (a tile result holds at most this squared).
pub const MAX_TILE_EDGE: u32 = 4096;

/// An invalid setting: the field (as named in the API, `max_depth`; the command line spells it
/// `--max-depth`) and what is allowed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct SettingsError {
    /// The offending field.
    pub field: &'static str,
    /// What is wrong, and what is allowed.
    pub message: String,
}

impl SettingsError {
    fn new(field: &'static str, message: String) -> Self {
        Self { field, message }
    }
}

fn check_range(field: &'static str, v: u32, lo: u32, hi: u32) -> Result<(), SettingsError> {
    if v < lo || v > hi {
        let allowed = if lo == 0 {
            format!("must be at most {hi}")
        } else {
            format!("must be between {lo} and {hi}")
        };
        return Err(SettingsError::new(field, format!("{allowed}, got {v}")));
    }
    Ok(())
}

impl RenderSettings {
    /// Checks every field on its own, then the fields together; the error names the field.
    pub fn validate(&self) -> Result<(), SettingsError> {
        self.to_overrides().check()?;
        if self.width as u64 * self.height as u64 > MAX_PIXELS {
            return Err(SettingsError::new(
                "width",
                format!("width × height must be at most {MAX_PIXELS} pixels"),
            ));
        }
        if self.environment.is_none() {
            let field = if self.environment_strength != 1.0 {
                Some("environment_strength")
            } else if self.environment_rotation != 0.0 {
                Some("environment_rotation")
            } else {
                None
            };
            if let Some(field) = field {
                return Err(SettingsError::new(
                    field,
                    "applies to the job's environment: give environment too".into(),
                ));
            }
        }
        if self.passes > self.spp {
            return Err(SettingsError::new(
                "passes",
                format!(
                    "must be between 1 and spp ({}), got {}",
                    self.spp, self.passes
                ),
            ));
        }
        if self.integrator == IntegratorKind::Bdpt && self.filter != FilterKind::Box {
            return Err(SettingsError::new(
                "filter",
                format!(
                    "bdpt supports only the box filter, got {}: light paths joined to the \
                     camera land on the film without a filter to spread them",
                    self.filter.name()
                ),
            ));
        }
        if self.integrator == IntegratorKind::Sppm && self.passes != 1 {
            return Err(SettingsError::new(
                "passes",
                format!(
                    "sppm renders in one pass, got {}: a pixel's estimate depends on all its \
                     iterations (spp), which are not sums that passes could add",
                    self.passes
                ),
            ));
        }
        Ok(())
    }

    /// Every field as an override: applied to any settings, they give these settings.
    pub fn to_overrides(&self) -> RenderOverrides {
        let Self {
            width,
            height,
            spp,
            max_depth,
            integrator,
            seed,
            camera,
            filter,
            tile_size,
            passes,
            default_light,
            environment,
            environment_rotation,
            environment_strength,
            alpha,
        } = self;
        RenderOverrides {
            width: Some(*width),
            height: Some(*height),
            spp: Some(*spp),
            max_depth: Some(*max_depth),
            integrator: Some(*integrator),
            seed: Some(*seed),
            camera: camera.clone(),
            filter: Some(*filter),
            tile_size: Some(*tile_size),
            passes: Some(*passes),
            default_light: Some(*default_light),
            environment: environment.clone(),
            environment_rotation: Some(*environment_rotation),
            environment_strength: Some(*environment_strength),
            alpha: Some(*alpha),
        }
    }

    /// The sample-index ranges of the progressive passes, in order: `spp` split as evenly as
    /// possible, earlier passes taking the remainder.
    pub fn pass_ranges(&self) -> Vec<Range<u32>> {
        let passes = self.passes.clamp(1, self.spp.max(1));
        let (base, extra) = (self.spp / passes, self.spp % passes);
        let mut start = 0;
        (0..passes)
            .map(|i| {
                let n = base + u32::from(i < extra);
                let r = start..start + n;
                start += n;
                r
            })
            .collect()
    }

    /// The frame cut into tiles of `tile_size`, row by row.
    pub fn tiles(&self) -> Vec<Tile> {
        let ts = self.tile_size.max(1);
        let mut out = Vec::new();
        for y0 in (0..self.height).step_by(ts as usize) {
            for x0 in (0..self.width).step_by(ts as usize) {
                out.push(Tile {
                    x0,
                    y0,
                    x1: (x0 + ts).min(self.width),
                    y1: (y0 + ts).min(self.height),
                });
            }
        }
        out
    }
}

/// What a user changes of a render: every field optional, `None` keeps the scene's own setting
/// (or raytile's default). The flags of `raytile render`, `submit` and `cluster` and the fields
/// of a job request are this one type, so they cannot drift apart.
///
/// In JSON, unknown fields are refused, so that a misspelt setting is an error rather than a
/// silently ignored wish.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct RenderOverrides {
    /// Image width in pixels.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long))]
    pub width: Option<u32>,
    /// Image height in pixels.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long))]
    pub height: Option<u32>,
    /// Samples per pixel.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long))]
    pub spp: Option<u32>,
    /// Maximum path depth (bounces).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long))]
    pub max_depth: Option<u32>,
    /// Integrator: path, volpath, bdpt, sppm (needs --passes 1), whitted, normals, albedo, depth, ao.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long))]
    pub integrator: Option<IntegratorKind>,
    /// Random seed.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long))]
    pub seed: Option<u32>,
    /// Camera name or index. In JSON a string (a name, or an index in decimal) or an integer
    /// index (`"camera": 1` is `"camera": "1"`), as `--camera` takes either.
    #[serde(
        skip_serializing_if = "Option::is_none",
        deserialize_with = "camera_name_or_index"
    )]
    #[cfg_attr(feature = "clap", arg(long))]
    pub camera: Option<String>,
    /// Pixel filter: box, gaussian, blackman-harris.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long))]
    pub filter: Option<FilterKind>,
    /// Tile edge in pixels (scheduling only; never changes the image).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long))]
    pub tile_size: Option<u32>,
    /// Progressive passes the samples are split into (part of the job: same passes, same bits).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long))]
    pub passes: Option<u32>,
    /// `false`: a glTF scene without any light renders black instead of under the default white
    /// environment (default `true`).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(
            long = "no-default-light",
            num_args = 0,
            default_missing_value = "false",
            help = "A glTF scene without any light renders black instead of under the default \
                    white environment"
        )
    )]
    pub default_light: Option<bool>,
    /// The job's light, replacing the scene's environment: `none`, `R,G,B` (constant radiance)
    /// or an equirectangular `.hdr`/`.exr` map (on a farm, a file of the scene's folder).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, value_name = "none|R,G,B|MAP.hdr|MAP.exr"))]
    pub environment: Option<EnvironmentChoice>,
    /// Rotation of the environment map about +Y, in degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "DEG", allow_negative_numbers = true, value_parser = f32_arg)
    )]
    #[serde(deserialize_with = "f32_in_range")]
    pub environment_rotation: Option<f32>,
    /// Multiplies the environment (map or colour).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(feature = "clap", arg(long, value_name = "X", value_parser = f32_arg))]
    #[serde(deserialize_with = "f32_in_range")]
    pub environment_strength: Option<f32>,
    /// `true`: an alpha channel, the environment seen straight from the camera transparent
    /// (it still lights the scene); colours premultiplied by alpha (default `false`). On the
    /// command line `--alpha`, or `--alpha=false` to turn off a scene's `render.alpha`.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[cfg_attr(
        feature = "clap",
        arg(
            long = "alpha",
            num_args = 0..=1,
            require_equals = true,
            default_missing_value = "true",
            value_name = "BOOL",
            help = "Write an alpha channel: the environment seen straight from the camera is \
                    transparent (it still lights the scene), colours are premultiplied \
                    (--alpha=false turns off a scene's own)"
        )
    )]
    pub alpha: Option<bool>,
}

/// Why a number does not fit an f32: it is finite but beyond the largest f32, which a plain
/// f32 field would read as infinity and then report as "inf" instead of what was given.
fn beyond_f32(x: f64) -> Option<String> {
    (x.is_finite() && (x as f32).is_infinite())
        .then(|| format!("{x:e} is beyond the range of a 32-bit float (about ±3.4e38)"))
}

/// Reads an optional f32 as a JSON number, refusing a finite one beyond f32's range with the
/// number as sent (the range checks that follow see only finite values or NaN).
pub fn f32_in_range<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<f32>, D::Error> {
    let v: Option<f64> = Deserialize::deserialize(d)?;
    match v.map(|x| beyond_f32(x).map_or(Ok(x as f32), Err)) {
        Some(Err(why)) => Err(serde::de::Error::custom(why)),
        Some(Ok(x)) => Ok(Some(x)),
        None => Ok(None),
    }
}

/// Reads an f32 command-line value as [`f32_in_range`] reads a JSON one.
#[cfg(feature = "clap")]
fn f32_arg(s: &str) -> Result<f32, String> {
    let x: f64 = s.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
    beyond_f32(x).map_or(Ok(x as f32), Err)
}

/// Reads a camera choice: a name (string), an index (integer ≥ 0, kept as its decimal
/// string, which the renderer reads as an index), or null for none. The scene format's
/// `render.camera` reads it the same way.
pub fn camera_name_or_index<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<Option<String>, D::Error> {
    struct Camera;
    impl<'de> serde::de::Visitor<'de> for Camera {
        type Value = Option<String>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a camera name (string) or index (integer ≥ 0)")
        }
        fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Self::Value, E> {
            Ok(Some(v.to_string()))
        }
        fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Self::Value, E> {
            Ok(Some(v.to_string()))
        }
        fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Self::Value, E> {
            u64::try_from(v)
                .map(|v| Some(v.to_string()))
                .map_err(|_| E::invalid_value(serde::de::Unexpected::Signed(v), &self))
        }
        fn visit_unit<E: serde::de::Error>(self) -> Result<Self::Value, E> {
            Ok(None)
        }
        fn visit_none<E: serde::de::Error>(self) -> Result<Self::Value, E> {
            Ok(None)
        }
        fn visit_some<D: serde::Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
            d.deserialize_any(Camera)
        }
    }
    d.deserialize_any(Camera)
}

impl RenderOverrides {
    /// The field names, as in JSON (a `--flag` on the command line, `_` spelt `-`).
    pub const FIELDS: [&'static str; 15] = [
        "width",
        "height",
        "spp",
        "max_depth",
        "integrator",
        "seed",
        "camera",
        "filter",
        "tile_size",
        "passes",
        "default_light",
        "environment",
        "environment_rotation",
        "environment_strength",
        "alpha",
    ];

    /// Checks each given field on its own (ranges), so that a wrong value is refused before
    /// anything is uploaded; [`RenderSettings::validate`] adds the checks across fields.
    pub fn check(&self) -> Result<(), SettingsError> {
        let Self {
            width,
            height,
            spp,
            max_depth,
            integrator: _,
            seed: _,
            camera: _,
            filter: _,
            tile_size,
            passes,
            default_light: _,
            environment: _,
            environment_rotation,
            environment_strength,
            alpha: _,
        } = self;
        if let Some(r) = environment_rotation {
            if !r.is_finite() {
                return Err(SettingsError::new(
                    "environment_rotation",
                    format!("must be a finite number of degrees, got {r}"),
                ));
            }
        }
        if let Some(x) = environment_strength {
            if !(x.is_finite() && *x >= 0.0) {
                return Err(SettingsError::new(
                    "environment_strength",
                    format!("must be a finite number ≥ 0, got {x}"),
                ));
            }
        }
        let checks = [
            ("width", *width, 1, MAX_EDGE),
            ("height", *height, 1, MAX_EDGE),
            ("spp", *spp, 1, MAX_SPP),
            ("max_depth", *max_depth, 0, MAX_DEPTH),
            ("tile_size", *tile_size, 1, MAX_TILE_EDGE),
            ("passes", *passes, 1, MAX_SPP),
        ];
        for (field, v, lo, hi) in checks {
            if let Some(v) = v {
                check_range(field, v, lo, hi)?;
            }
        }
        Ok(())
    }

    /// Sets every field given here in `s`; the others stay.
    pub fn apply_to(&self, s: &mut RenderSettings) {
        // Destructured, so that a new field cannot be forgotten here.
        let Self {
            width,
            height,
            spp,
            max_depth,
            integrator,
            seed,
            camera,
            filter,
            tile_size,
            passes,
            default_light,
            environment,
            environment_rotation,
            environment_strength,
            alpha,
        } = self;
        s.width = width.unwrap_or(s.width);
        s.height = height.unwrap_or(s.height);
        s.spp = spp.unwrap_or(s.spp);
        s.max_depth = max_depth.unwrap_or(s.max_depth);
        s.integrator = integrator.unwrap_or(s.integrator);
        s.seed = seed.unwrap_or(s.seed);
        if camera.is_some() {
            s.camera.clone_from(camera);
        }
        s.filter = filter.unwrap_or(s.filter);
        s.tile_size = tile_size.unwrap_or(s.tile_size);
        s.passes = passes.unwrap_or(s.passes);
        s.default_light = default_light.unwrap_or(s.default_light);
        if environment.is_some() {
            s.environment.clone_from(environment);
        }
        s.environment_rotation = environment_rotation.unwrap_or(s.environment_rotation);
        s.environment_strength = environment_strength.unwrap_or(s.environment_strength);
        s.alpha = alpha.unwrap_or(s.alpha);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passes_cover_every_sample_once() {
        for (spp, passes) in [(1, 1), (7, 3), (64, 4), (10, 10)] {
            let s = RenderSettings {
                spp,
                passes,
                ..Default::default()
            };
            let r = s.pass_ranges();
            assert_eq!(r.len() as u32, passes);
            assert_eq!(r[0].start, 0);
            assert_eq!(r.last().unwrap().end, spp);
            assert!(r
                .windows(2)
                .all(|w| w[0].end == w[1].start && !w[1].is_empty()));
        }
    }

    #[test]
    fn tiles_cover_the_frame() {
        let s = RenderSettings {
            width: 100,
            height: 37,
            tile_size: 16,
            ..Default::default()
        };
        let n: usize = s.tiles().iter().map(|t| t.pixel_count()).sum();
        assert_eq!(n, 3700);
    }

    #[test]
    fn a_camera_is_a_name_or_an_index() {
        let camera = |json: &str| {
            serde_json::from_str::<RenderOverrides>(json)
                .map(|o| o.camera)
                .map_err(|e| e.to_string())
        };
        assert_eq!(camera(r#"{"camera": "side"}"#), Ok(Some("side".into())));
        assert_eq!(camera(r#"{"camera": "1"}"#), Ok(Some("1".into())));
        assert_eq!(camera(r#"{"camera": 1}"#), Ok(Some("1".into())));
        assert_eq!(camera(r#"{"camera": null}"#), Ok(None));
        assert_eq!(camera(r#"{}"#), Ok(None));
        for bad in [
            r#"{"camera": -1}"#,
            r#"{"camera": 1.5}"#,
            r#"{"camera": [1]}"#,
        ] {
            let e = camera(bad).unwrap_err();
            assert!(e.contains("a camera name (string) or index"), "{bad}: {e}");
        }
        // What is sent is what is read.
        let o = RenderOverrides {
            camera: Some("2".into()),
            ..Default::default()
        };
        let back: RenderOverrides =
            serde_json::from_str(&serde_json::to_string(&o).unwrap()).unwrap();
        assert_eq!(back, o);
    }

    #[test]
    fn validation_names_the_field() {
        let check = |s: RenderSettings, field: &str| {
            assert_eq!(s.validate().unwrap_err().field, field, "{s:?}");
        };
        let d = RenderSettings::default;
        check(RenderSettings { spp: 0, ..d() }, "spp");
        check(
            RenderSettings {
                width: 100_000,
                ..d()
            },
            "width",
        );
        check(RenderSettings { height: 0, ..d() }, "height");
        check(
            RenderSettings {
                max_depth: 5000,
                ..d()
            },
            "max_depth",
        );
        check(
            RenderSettings {
                tile_size: 0,
                ..d()
            },
            "tile_size",
        );
        check(
            RenderSettings {
                spp: 4,
                passes: 5,
                ..d()
            },
            "passes",
        );
        let big = RenderSettings {
            width: MAX_EDGE,
            height: MAX_EDGE,
            ..d()
        };
        check(big, "width");
        check(
            RenderSettings {
                integrator: IntegratorKind::Sppm,
                spp: 8,
                passes: 2,
                ..d()
            },
            "passes",
        );
        assert_eq!(d().validate(), Ok(()));
    }

    #[test]
    fn overrides_check_each_field_alone() {
        // More passes than the default spp is fine on its own: the scene may ask for more spp.
        let o = RenderOverrides {
            passes: Some(100),
            ..Default::default()
        };
        assert_eq!(o.check(), Ok(()));
        let o = RenderOverrides {
            spp: Some(0),
            ..Default::default()
        };
        let e = o.check().unwrap_err();
        assert_eq!(e.field, "spp");
        assert_eq!(e.to_string(), "spp: must be between 1 and 1048576, got 0");
    }

    #[test]
    fn overrides_apply_only_what_they_hold() {
        let mut s = RenderSettings {
            camera: Some("side".into()),
            ..Default::default()
        };
        RenderOverrides {
            spp: Some(8),
            integrator: Some(IntegratorKind::Ao),
            default_light: Some(false),
            ..Default::default()
        }
        .apply_to(&mut s);
        assert_eq!(
            s,
            RenderSettings {
                spp: 8,
                integrator: IntegratorKind::Ao,
                default_light: false,
                camera: Some("side".into()),
                ..Default::default()
            }
        );
        // All of a settings' fields as overrides give those settings, whatever they apply to.
        let target = RenderSettings {
            width: 7,
            filter: FilterKind::Gaussian,
            camera: None,
            ..s.clone()
        };
        let mut other = RenderSettings::default();
        target.to_overrides().apply_to(&mut other);
        assert_eq!(other, target);
    }

    #[test]
    fn the_field_list_is_the_json_one() {
        let all = RenderSettings {
            camera: Some("c".into()),
            environment: Some(EnvironmentChoice::None),
            ..Default::default()
        }
        .to_overrides();
        let v = serde_json::to_value(all).unwrap();
        let keys: Vec<&str> = v.as_object().unwrap().keys().map(|k| k.as_str()).collect();
        let mut want = RenderOverrides::FIELDS.to_vec();
        want.sort_unstable();
        assert_eq!(keys, want);
    }

    /// The settings a worker renders with are pinned here. A new field is part of what is
    /// rendered: raise the renderer version (`RENDER_VERSION`) with it, so that workers of the
    /// older release are refused rather than ignore the field, and add it to "Compatibility" in
    /// docs/farm.md. Then add it to this list.
    #[test]
    fn render_settings_fields_are_pinned() {
        let v = serde_json::to_value(RenderSettings::default()).unwrap();
        let keys: Vec<&str> = v.as_object().unwrap().keys().map(|k| k.as_str()).collect();
        let want = [
            "alpha",
            "camera",
            "default_light",
            "environment",
            "environment_rotation",
            "environment_strength",
            "filter",
            "height",
            "integrator",
            "max_depth",
            "passes",
            "seed",
            "spp",
            "tile_size",
            "width",
        ];
        assert_eq!(
            keys, want,
            "RenderSettings changed: raise RENDER_VERSION and document the field"
        );
    }

    #[test]
    fn settings_read_tolerantly_overrides_strictly() {
        let s: RenderSettings =
            serde_json::from_str(r#"{"spp": 3, "from_a_newer_release": 1}"#).unwrap();
        assert_eq!(s.spp, 3);
        assert_eq!(s.width, RenderSettings::default().width);
        let e = serde_json::from_str::<RenderOverrides>(r#"{"spp": 3, "sp": 1}"#).unwrap_err();
        assert!(e.to_string().contains("unknown field `sp`"), "{e}");
    }

    #[test]
    fn names_parse_back_and_match_serde() {
        for k in IntegratorKind::ALL {
            assert_eq!(k.name().parse::<IntegratorKind>(), Ok(k));
            assert_eq!(serde_json::to_value(k).unwrap(), k.name());
        }
        for k in FilterKind::ALL {
            assert_eq!(k.name().parse::<FilterKind>(), Ok(k));
            assert_eq!(serde_json::to_value(k).unwrap(), k.name());
        }
        let e = "magic".parse::<IntegratorKind>().unwrap_err();
        assert!(e.contains("magic") && e.contains("whitted"), "{e}");
    }

    #[test]
    fn environment_choices_parse_and_round_trip() {
        let cases = [
            ("none", EnvironmentChoice::None),
            ("NONE", EnvironmentChoice::None),
            ("0.5,0.25,1", EnvironmentChoice::Constant([0.5, 0.25, 1.0])),
            (" 1, 2, 3 ", EnvironmentChoice::Constant([1.0, 2.0, 3.0])),
            ("studio.hdr", EnvironmentChoice::Map("studio.hdr".into())),
            (
                "maps/Sky.EXR",
                EnvironmentChoice::Map("maps/Sky.EXR".into()),
            ),
        ];
        for (text, want) in cases {
            let got: EnvironmentChoice = text.parse().unwrap();
            assert_eq!(got, want, "{text}");
            let json = serde_json::to_value(&got).unwrap();
            assert_eq!(
                serde_json::from_value::<EnvironmentChoice>(json).unwrap(),
                got
            );
        }
        for bad in ["", "red", "1,2", "1,2,-3", "1,nan,3", "1,inf,3", "sky.png"] {
            let e = bad.parse::<EnvironmentChoice>().unwrap_err();
            assert!(e.contains(&format!("'{bad}'")), "{e}");
        }
        let e = serde_json::from_str::<RenderOverrides>(r#"{"environment": "1,2"}"#).unwrap_err();
        assert!(e.to_string().contains(".hdr"), "{e}");
    }

    #[test]
    fn environment_strength_and_rotation_need_an_environment() {
        let d = RenderSettings::default;
        let s = RenderSettings {
            environment_strength: 2.0,
            ..d()
        };
        assert_eq!(s.validate().unwrap_err().field, "environment_strength");
        let s = RenderSettings {
            environment_rotation: 90.0,
            ..d()
        };
        assert_eq!(s.validate().unwrap_err().field, "environment_rotation");
        let s = RenderSettings {
            environment: Some(EnvironmentChoice::Map("sky.hdr".into())),
            environment_rotation: -90.0,
            environment_strength: 2.0,
            ..d()
        };
        assert_eq!(s.validate(), Ok(()));
        for (o, field) in [
            (
                RenderOverrides {
                    environment_strength: Some(-1.0),
                    ..Default::default()
                },
                "environment_strength",
            ),
            (
                RenderOverrides {
                    environment_rotation: Some(f32::NAN),
                    ..Default::default()
                },
                "environment_rotation",
            ),
        ] {
            assert_eq!(o.check().unwrap_err().field, field);
        }
    }

    /// A number beyond f32's range is refused with the number as sent, not as "inf"; numbers
    /// within it read as they did.
    #[test]
    fn numbers_beyond_f32_are_refused_as_sent() {
        let read = |j: &str| serde_json::from_str::<RenderOverrides>(j);
        let e = read(r#"{"environment_strength": 1e308}"#).unwrap_err();
        assert!(e.to_string().contains("1e308 is beyond"), "{e}");
        let e = read(r#"{"environment_rotation": -4e38}"#).unwrap_err();
        assert!(e.to_string().contains("-4e38 is beyond"), "{e}");
        let o = read(r#"{"environment_strength": 3.4e38, "environment_rotation": 0.1}"#).unwrap();
        assert_eq!(o.environment_strength, Some(3.4e38));
        assert_eq!(o.environment_rotation, Some(0.1));
        assert_eq!(read("{}").unwrap(), RenderOverrides::default());
        assert_eq!(
            read(r#"{"environment_strength": null}"#).unwrap(),
            RenderOverrides::default()
        );
        #[cfg(feature = "clap")]
        {
            assert!(f32_arg("1e308").unwrap_err().contains("1e308 is beyond"));
            assert_eq!(f32_arg("2.5"), Ok(2.5));
        }
    }
}
