//! Render settings: everything about a render that is not the scene.
//!
//! The types are defined in the wire crate (`raytile-proto`), which does not depend on the
//! tracer, so that a job's settings mean the same on every machine of a farm and in every client
//! of its API; they are re-exported here. The one merge of a scene's own render settings with the
//! user's overrides is [`crate::scene::desc::RenderDefaults::resolve`].

pub use raytile_proto::settings::{
    EnvironmentChoice, FilterKind, IntegratorKind, RenderOverrides, RenderSettings, SettingsError,
    Tile, MAX_DEPTH, MAX_EDGE, MAX_PIXELS, MAX_SPP, MAX_TILE_EDGE,
};
