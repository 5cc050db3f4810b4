//! What f32 can invert: the one test of a transform's linear part that scene objects, glTF
//! nodes and the placements of density grids share.

use glam::{Affine3A, Mat4};

/// Smallest |det| / (product of the axes' lengths) a transform may have: how far its axes
/// may lean onto one another (1 for perpendicular axes; a shear of 10⁶ is the limit).
const MIN_SPREAD: f64 = 1e-6;

/// Largest entry a transform or its inverse may have: squares and sums of three of them stay
/// finite in f32 (normals and directions are transformed and normalised that way).
const MAX_ENTRY: f32 = 1e18;

/// Why a finite transform cannot be inverted in f32 without losing the result.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Degenerate {
    /// An axis of zero length: a zero scale (glTF hides nodes that way).
    ZeroAxis,
    /// The axes (nearly) lie in one plane.
    Flat,
    /// The determinant is below f32's normal range, or the inverse has an entry above
    /// [`MAX_ENTRY`]: scales below about 10⁻¹².
    TooSmall,
    /// The determinant or an entry is above f32's range or [`MAX_ENTRY`]: scales above about
    /// 10¹².
    TooLarge,
}

impl Degenerate {
    /// What keeps the linear part of the finite transform `m` from being inverted, if
    /// anything. The test does not depend on the overall scale: a model in centimetres under a
    /// centimetre-to-metre node (a scale of 10⁻⁴, a determinant of 10⁻¹²) passes, as it must.
    pub fn of(m: &Mat4) -> Option<Degenerate> {
        let axes = [m.x_axis, m.y_axis, m.z_axis].map(|c| c.truncate().as_dvec3());
        let lengths = axes.map(|a| a.length());
        if lengths.contains(&0.0) {
            return Some(Degenerate::ZeroAxis);
        }
        let det = axes[0].dot(axes[1].cross(axes[2]));
        if !(det.abs() / (lengths[0] * lengths[1] * lengths[2]) >= MIN_SPREAD) {
            return Some(Degenerate::Flat);
        }
        let m3 = glam::Mat3::from_mat4(*m);
        let largest = |m: &glam::Mat3| m.abs().to_cols_array().into_iter().fold(0.0f32, f32::max);
        let det32 = m3.determinant();
        if !det32.is_finite() || largest(&m3) > MAX_ENTRY {
            return Some(Degenerate::TooLarge);
        }
        let inv = m3.inverse();
        if !det32.is_normal() || !inv.is_finite() || largest(&inv) > MAX_ENTRY {
            return Some(Degenerate::TooSmall);
        }
        None
    }
}

impl std::fmt::Display for Degenerate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Degenerate::ZeroAxis => "transform is singular (a zero scale)",
            Degenerate::Flat => "transform is singular: its axes (nearly) lie in one plane",
            Degenerate::TooSmall => {
                "transform's scale is too small to invert in f32 (raytile takes scales from \
                 about 1e-12 to 1e12)"
            }
            Degenerate::TooLarge => {
                "transform's scale is too large (raytile takes scales from about 1e-12 to 1e12)"
            }
        })
    }
}

impl Degenerate {
    /// [`Degenerate::of`] for an affine map.
    pub fn of_affine(m: &Affine3A) -> Option<Degenerate> {
        Degenerate::of(&Mat4::from(*m))
    }
}
