//! glTF metallic-roughness.

use super::BsdfSample;
use glam::{Vec2, Vec3A};

/// glTF metallic-roughness with its parameters resolved at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pbr {
    /// Base colour (linear).
    pub base_color: Vec3A,
    /// Metalness.
    pub metallic: f32,
    /// GGX alpha (roughness squared).
    pub alpha: f32,
    /// KHR_materials_specular factor.
    pub specular: f32,
    /// KHR_materials_specular colour.
    pub specular_color: Vec3A,
    /// Index of refraction.
    pub ior: f32,
    /// Transmission factor.
    pub transmission: f32,
    /// Thin-walled transmission.
    pub thin: bool,
    /// Clearcoat factor.
    pub clearcoat: f32,
    /// Clearcoat GGX alpha.
    pub clearcoat_alpha: f32,
}

impl Pbr {
    /// f(wo, wi) without cosine.
    pub fn eval(&self, _wo: Vec3A, _wi: Vec3A) -> Vec3A {
        todo!()
    }
    /// Density of `sample`.
    pub fn pdf(&self, _wo: Vec3A, _wi: Vec3A) -> f32 {
        todo!()
    }
    /// Samples wi.
    pub fn sample(&self, _wo: Vec3A, _uc: f32, _u: Vec2) -> Option<BsdfSample> {
        todo!()
    }
    /// Whether all lobes are delta.
    pub fn is_delta(&self) -> bool {
        todo!()
    }
    /// Summary colour.
    pub fn albedo(&self) -> Vec3A {
        todo!()
    }
}
