//! Wire types of the raytile farm, shared by the coordinator, the workers, the CLI and any other
//! client of the API. This crate does not depend on the tracer: the tracer depends on it for the
//! settings types and re-exports them.
//!
//! - [`settings`]: `RenderSettings` as a job carries it, the `RenderOverrides` users give, and
//!   their validation.
//! - [`api`]: every JSON request and response body of the HTTP API.
//! - [`json`]: reading JSON people write: structs from objects only, serde's messages in JSON's words.
//! - [`tile`]: the binary tile-result format workers upload (little-endian, length-checked).
//! - [`scene`]: scene packages: format detection; with the `package` feature, content ids, safe
//!   archive extraction and packing.
//! - `client` (feature `client`): the HTTP client of the API, one for workers and the CLI.
//! - `shutdown_signal` (feature `signal`): Ctrl-C or SIGTERM, for the service binaries.
//!
//! How the wire format may change between releases is in `docs/farm.md`, "Compatibility".

pub mod api;
#[cfg(feature = "client")]
pub mod client;
pub mod json;
pub mod scene;
pub mod settings;
#[cfg(feature = "signal")]
mod signal;
pub mod tile;

pub use api::*;
pub use settings::{
    EnvironmentChoice, FilterKind, IntegratorKind, RenderOverrides, RenderSettings, SettingsError,
    Tile,
};
#[cfg(feature = "signal")]
pub use signal::shutdown_signal;
pub use tile::TileAccum;
