//! Wire types shared by the raytile coordinator, the workers and the CLI.
//!
//! - [`api`]: every JSON request and response body of the HTTP API.
//! - [`tile`]: the binary tile-result format workers upload (little-endian, length-checked).
//! - [`scene`]: scene packages: format detection, content ids, safe archive extraction, packing.

pub mod api;
pub mod scene;
pub mod tile;

pub use api::*;
