//! Deterministic sample sequences and warps from the unit square to useful distributions.

pub mod detmath;
pub mod distrib;
pub mod sequence;
pub mod warp;

pub use sequence::{hash_u32, Sampler, SOBOL_SAMPLES};
