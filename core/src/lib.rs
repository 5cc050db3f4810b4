//! raytile-core: the path tracer behind the raytile render farm.
//!
//! The crate reads like the lecture it comes from: [`geometry`] (rays, hit records and shapes),
//! [`accel`] (the bounding-volume hierarchy), [`camera`], [`sampling`], [`material`]
//! (materials and BSDFs), [`light`], [`integrator`] (Whitted, path tracing, bdpt, sppm, debug outputs,
//! `render_tile`), [`scene`] (descriptions, the JSON and glTF front ends, the builder, and the
//! scene at render time) and [`film`] (accumulation, filters, output).
//!
//! A render is a [`Scene`], built once from a description and kept as long as wanted, and a
//! [`RenderJob`], what one render adds (settings, camera, environment, light selection):
//!
//! ```no_run
//! # fn main() -> Result<(), raytile_core::SceneError> {
//! use raytile_core::{load_scene, render, RenderJob, RenderSettings, Scene};
//! let scene = Scene::build(&load_scene("scene.gltf".as_ref())?)?;
//! let job = RenderJob::new(&scene, &RenderSettings::default())?;
//! let film = render(&scene, &job, &());
//! # let _ = film;
//! # Ok(())
//! # }
//! ```
//!
//! Modules import only from layers below their own (ARCHITECTURE.md; `tests/layers.rs`).
//!
//! Invariants: no network, no serde on the hot path, no allocation per ray; file IO only in
//! scene loading and image output. Random numbers depend only on (pixel, sample index, seed).

// `!(x > 0.0)` is used on purpose: it is true for NaN, which must fail every such check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod accel;
pub mod alloc;
pub mod camera;
pub mod cpu;
pub mod film;
pub mod geometry;
pub mod integrator;
pub mod light;
pub mod material;
pub mod medium;
pub mod sampling;
pub mod scene;
pub mod settings;
pub mod texture;

pub use film::{Film, TileAccum};
pub use integrator::{render, render_tile, Cancel, Cancelled, RenderProgress};
pub use scene::{load_scene, load_scene_with, RenderJob, Scene, SceneError};
pub use settings::{
    EnvironmentChoice, IntegratorKind, RenderOverrides, RenderSettings, SettingsError, Tile,
};

/// Version of the renderer's arithmetic: raised whenever a change to the tracer changes the
/// bits of any image (sampling, intersection, shading). Workers send it when they register and
/// the coordinator refuses workers whose version differs from its own, so that every tile of a
/// frame comes from the same arithmetic and the frame stays bit-identical to a local render.
/// The golden-image test (`core/tests/golden.rs`) fails when image bits change, as a reminder.
///
/// 2: one 4D Sobol set per bounce (2026-11-30).
/// 3: shading frame about the normal alone, sin/cos by our own polynomials, flat triangles
/// shaded from world-space data, small scenes' BVH built with the thorough preset (2026-11-30).
/// 4: the `volpath` integrator and scene media; a job's own environment (`environment`,
/// `environment_rotation`, `environment_strength` settings); index-matched glTF transmission
/// passes straight through; glTF `COLOR_0` is used (2026-12-01).
/// 5: the `bdpt` integrator, and tile results that carry splats (2026-12-01); other
/// integrators' images unchanged.
/// 6: the `sppm` integrator; absorption inside bodies (glass, `KHR_materials_volume`) through
/// the deterministic `detmath::exp` instead of the C library's, which may round differently on
/// CPUs with FMA (2026-12-02).
/// 7: scenes of more than 65,536 primitives are built with the binned-SAH builder (another
/// slot order, so another winner where two primitives are hit at exactly the same distance);
/// smaller scenes' images unchanged (2026-12-02).
/// 8: the light of next-event estimation is chosen by the first number of the light's 2D
/// Sobol point, stretched back for the point on it, instead of by a hashed number (`path`,
/// `volpath`, `sppm`; 2026-12-02).
/// 9: that first number is refined below the Sobol grid by a hashed number before it picks
/// and is stretched, so a light with a tiny share still gets a continuum of points (2026-12-03).
/// 10: 8-bit textures keep their bytes, and every byte b reads b / 255 correctly rounded; grey
/// 8-bit images had read some bytes one unit in the last place away (2026-12-05). Images of
/// other scenes unchanged.
/// 11: `bdpt` and `sppm` with an unbounded plane under a directional light or an environment:
/// light rays that start in the plane's shadow carry nothing, and the MIS weights leave out the
/// light's strategies where its rays cannot reach; `bdpt` runs next-event estimation when its
/// light subpath is empty (2026-12-06). Images of other scenes unchanged.
/// 12 (2026-12-06): `sppm`'s initial search radius is two pixel widths where the camera's rays
/// meet the scene, not two pixels' worth of the scene's extent: every `sppm` image changes.
/// The debug integrators (`normals`, `albedo`, `depth`, `ao`) pass through `interface`
/// surfaces (medium boundaries), as `path` does, and their occlusion rays too: their images of
/// scenes with interfaces change. A 6-channel `.vol` voxel's mean is summed in f64: densities
/// read from such files may move by a unit in the last place.
/// 13 (2026-12-06): next-event estimation gives each light at infinity (the environment, a
/// directional light) as many light samples as all the finite lights together, where a scene
/// has both, instead of choosing by power alone ([`light::LightSet`]): `path`, `volpath` and
/// `sppm` images of such scenes change; `bdpt` and scenes with lights of one kind do not.
/// 14 (2026-12-07): tangents that raytile generates for a glTF normal map (a primitive without
/// TANGENT) have the bitangent sign glTF's downward texture coordinates need: images of such
/// models change (their normal maps' green channel bent normals the wrong way). Also changed:
/// glTF cameras in frames a parent's non-uniform scale shears look along their frame's −Z
/// ([`camera::unsheared`]); an sRGB-encoded HDR texel above about 1.2e16 saturates instead of
/// reading black; scenes of under 65,537 primitives with some 2,000 or more copies of one
/// bounding box are built by the binned builder (its tree may break ties between coincident
/// primitives differently). Other images unchanged.
/// 15 (2026-12-07): `sppm` bounds the whole path by `max_depth`: a visible point reached
/// through k mirror or glass bounces gathers only photons of fewer than `max_depth` − k
/// bounces (it had taken every photon, so images of scenes with mirrors or glass were too
/// bright at low depths). And an `sppm` iteration whose photons leave more than
/// [`integrator::sppm::MAP_DEPOSITS`] deposits is gathered from several photon maps, one after
/// another, instead of one map as large as it takes: such iterations (images of a million
/// pixels or more, or long photon paths in bright closed rooms) sum their flux in another
/// order. Other images unchanged.
/// 16 (2026-12-07): glTF's `KHR_texture_transform` rotation turns textures the way the sample
/// asset TextureTransformTest and other viewers do (the transpose of the extension's GLSL
/// listing, which v-down texture coordinates need); normal maps on a mirroring node bend
/// normals as on the mesh unmirrored (the bitangent's sign follows the transform's
/// determinant); `BLEND` surfaces draw their stochastic threshold from the hit's barycentrics
/// too, so rays that cross one at a common distance (toward a directional light, from an
/// orthographic camera) no longer pass or stop together; an environment map's `rotation` turns
/// it by the right-hand rule about +Y, as an object's rotation turns the object (it turned the
/// other way: images of maps with a rotation other than 0 or 180 degrees change); inside a
/// glTF body with transmission, light that cannot refract out through a microfacet (beyond
/// the critical angle) is reflected totally instead of ending the path; the JSON format's
/// cylinders, cones, paraboloids and hyperboloids take texture coordinate v from the height
/// (it was the angle from +Y seen from the clip box's centre); light samples on an emissive
/// glTF MASK or BLEND surface count by its alpha, as the rays that find it do (they counted
/// in full, cut-out texels and all); `sppm` carries its camera paths on through nearly
/// specular surfaces (smooth `pbr` glass and metal, GGX alpha up to 0.0625, no diffuse part),
/// taking a light sample there for point, spot and directional lights alone, instead of
/// gathering photons on them. Images of other scenes unchanged.
///
/// 17 (2026-12-07): every integrator tracks the solid transmissive bodies a path is in
/// (`scene::bodies`), so a body's absorption (a `dielectric`'s `absorption`, glTF's
/// `KHR_materials_volume`) attenuates every stretch of a path within it: to an object immersed in
/// it, and a light sample's shadow ray to a light in it, as well as the stretch to the body's own
/// surface (only that one was attenuated before; `bdpt` and `sppm` attenuated a part of the rest),
/// and light that escapes to the sky from inside an open body. Images of scenes with such a body
/// change where objects, lights or the camera sit inside it; in `volpath`, a `dielectric` whose
/// object bounds only an `exterior` medium keeps its absorption (one that bounds an `interior`
/// absorbs through that medium alone). `sppm`'s light sample on a near-specular surface picks among
/// the point, spot and directional lights alone (it picked among all the lights and kept only
/// those): the same image on average, less noise, different bits where a scene has such a surface
/// and area lights or a sky besides. Images of other scenes are unchanged.
///
/// 18 (2026-12-07): `bdpt`'s splats (light paths joined to the camera) are summed in i128 at
/// 2^56 instead of i64 at 2^28 (tile result format 2), so they no longer round away below about
/// 4·10⁻⁹ nor saturate above 3.4·10¹⁰ per pixel: a scene lit by emitters of radiance 10⁻⁸ or
/// 10¹² (or the sun's 10⁹ at thousands of samples) lost up to 60 % of its light in `bdpt`.
/// `bdpt` images change in their last bits everywhere. The denoiser buffers take Open Image
/// Denoise's ranges: `normals` are the world-space normal in [-1, 1] (they were mapped to
/// [0, 1], so where no surface was seen they read as (-1, -1, -1)), and `albedo` is in [0, 1]
/// (an emitter's, and the sky's, was its radiance; now its colour scaled to at most one).
/// Other integrators are unchanged.
///
/// 19 (2026-12-07): the `alpha` setting (an alpha channel: the environment seen straight from
/// the camera transparent, colours premultiplied) and tile results that carry coverage (format
/// 3). A worker of version 18 would not know the setting, so the versions must not mix; the
/// pixels of jobs without `alpha` are unchanged (their files' metadata now lists
/// `"alpha": false` among the settings).
pub const RENDER_VERSION: u32 = 19;
