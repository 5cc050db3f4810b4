//! raytile-core: the path tracer behind the raytile render farm.
//!
//! The crate reads like the lecture it comes from: [`geometry`] (rays and shapes), [`accel`]
//! (the bounding-volume hierarchy), [`camera`], [`sampling`], [`material`] (BSDFs), [`light`],
//! [`integrator`] (Whitted, path tracing, debug outputs, `render_tile`), [`scene`] (descriptions,
//! the JSON and glTF front ends, and the builder) and [`film`] (accumulation, filters, output).
//!
//! Invariants: no network, no serde on the hot path, no allocation per ray; file IO only in
//! scene loading and image output. Random numbers depend only on (pixel, sample index, seed).

// `!(x > 0.0)` is used on purpose: it is true for NaN, which must fail every such check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod accel;
pub mod camera;
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
pub use integrator::{render, render_tile, RenderProgress};
pub use scene::{load_scene, Scene, SceneError};
pub use settings::{IntegratorKind, RenderOverrides, RenderSettings, SettingsError, Tile};
