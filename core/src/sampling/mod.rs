//! Deterministic sample sequences and warps from the unit square to useful distributions.

pub mod detmath;
pub mod distrib;
pub mod sequence;
pub mod warp;

pub use sequence::{hash_u32, Sampler, SOBOL_SAMPLES};

/// The power heuristic (β = 2): the multiple-importance weight of a sample drawn by a strategy
/// with density `f` against another strategy with density `g` for the same sample.
#[inline]
pub fn power_heuristic(f: f32, g: f32) -> f32 {
    let (f2, g2) = (f * f, g * g);
    if f2.is_infinite() {
        return 1.0;
    }
    if f2 + g2 <= 0.0 {
        0.0
    } else {
        f2 / (f2 + g2)
    }
}
