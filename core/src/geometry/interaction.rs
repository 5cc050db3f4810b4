//! Hit records: what a ray found ([`Hit`], from traversal) and everything shading needs about
//! that surface point ([`Interaction`], from the hit). As in pbrt-v4's `interaction.h`, shapes
//! and the scene fill them, materials and lights read them, integrators pass them on and spawn
//! the next rays from them.

use super::{offset_ray_origin, Ray};
use crate::sampling::warp::Frame;
use glam::{Vec2, Vec3A};

/// The nearest intersection found by the scene's closest-hit query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter.
    pub t: f32,
    /// Object index.
    pub object: u32,
    /// Triangle index within the object's mesh (0 for analytic shapes).
    pub prim: u32,
    /// Barycentric coordinate of the triangle's second vertex.
    pub b1: f32,
    /// Barycentric coordinate of the triangle's third vertex.
    pub b2: f32,
    /// BVH slot of a flattened (world-space) triangle, [`NO_SLOT`] for other primitives: lets
    /// shading read the triangle's world-space data without its mesh and transform.
    pub(crate) slot: u32,
}

/// [`Hit::slot`] of a hit that is not a flattened triangle.
pub(crate) const NO_SLOT: u32 = u32::MAX;

/// Everything about a surface point that shading needs, in world space.
#[derive(Clone, Copy, Debug)]
pub struct Interaction {
    /// Hit point.
    pub p: Vec3A,
    /// Unit geometric normal on the object's front side.
    pub ng: Vec3A,
    /// Unit shading normal (interpolated, normal-mapped), on the same side as `ng`.
    pub ns: Vec3A,
    /// Tangent for the shading frame (may be zero).
    pub dpdu: Vec3A,
    /// Texture coordinate sets 0 and 1 (zero on meshes whose material has no texture).
    pub uv: [Vec2; 2],
    /// Ray parameter of the hit.
    pub t: f32,
    /// Object index.
    pub object: u32,
    /// Triangle index within the mesh (0 for analytic shapes).
    pub prim: u32,
    /// Vertex colour at the point (glTF `COLOR_0`), multiplying the base colour; white
    /// without one.
    pub color: Vec3A,
}

impl Interaction {
    /// The frame BSDFs are evaluated in: Z along the shading normal. Every BSDF here is
    /// isotropic, so the frame's rotation about the normal does not matter and the cheap
    /// branchless one serves (an anisotropic BSDF would need `Frame::from_zx(ns, dpdu)`).
    #[inline]
    pub fn shading_frame(&self) -> Frame {
        Frame::from_z(self.ns)
    }

    /// A ray leaving this point in direction `d`, offset so it cannot hit the surface again.
    #[inline]
    pub fn spawn_ray(&self, d: Vec3A) -> Ray {
        Ray::new(offset_ray_origin(self.p, self.ng, d), d)
    }

    /// A shadow ray from this point to `target` (a point on a surface with normal `target_n`,
    /// or zero for a point in space): (ray, tmax), stopping just short of the target.
    #[inline]
    pub fn spawn_ray_to(&self, target: Vec3A, target_n: Vec3A) -> (Ray, f32) {
        let d0 = target - self.p;
        let o = offset_ray_origin(self.p, self.ng, d0);
        let t = if target_n == Vec3A::ZERO {
            target
        } else {
            offset_ray_origin(target, target_n, o - target)
        };
        let d = t - o;
        let len = d.length();
        (Ray::new(o, d / len), len * (1.0 - 1e-4))
    }
}
