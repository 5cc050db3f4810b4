//! Rays and robust ray origins.

use glam::Vec3A;

/// A ray `o + t·d`. World-space rays from cameras, BSDFs and lights have unit `d`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Origin.
    pub o: Vec3A,
    /// Direction.
    pub d: Vec3A,
}

impl Ray {
    /// A ray from `o` along `d`.
    #[inline]
    pub fn new(o: Vec3A, d: Vec3A) -> Self {
        Self { o, d }
    }

    /// The point at parameter `t`.
    #[inline]
    pub fn at(&self, t: f32) -> Vec3A {
        self.o + self.d * t
    }
}

/// Moves a surface point off the surface along its geometric normal `n`, towards the side `w`
/// points to, far enough that a ray leaving it cannot hit the same surface again through
/// rounding, and no further (no light leaks through thin walls).
///
/// The method of Wächter and Binder ("A Fast and Robust Method for Avoiding Self-Intersection",
/// Ray Tracing Gems, ch. 6): offset by a fixed number of ulps for points far from the origin and
/// by a tiny absolute amount near it. It assumes `p` was computed accurately (barycentric
/// interpolation for triangles, re-projection for curved shapes), which every shape here does.
#[inline]
pub fn offset_ray_origin(p: Vec3A, n: Vec3A, w: Vec3A) -> Vec3A {
    const ORIGIN: f32 = 1.0 / 32.0;
    const FLOAT_SCALE: f32 = 1.0 / 65536.0;
    const INT_SCALE: f32 = 256.0;
    let n = if n.dot(w) < 0.0 { -n } else { n };
    let of_i = [
        (INT_SCALE * n.x) as i32,
        (INT_SCALE * n.y) as i32,
        (INT_SCALE * n.z) as i32,
    ];
    let pa = p.to_array();
    let na = n.to_array();
    let mut out = [0.0f32; 3];
    for k in 0..3 {
        let bits = pa[k].to_bits() as i32;
        let moved = f32::from_bits((bits + if pa[k] < 0.0 { -of_i[k] } else { of_i[k] }) as u32);
        out[k] = if pa[k].abs() < ORIGIN {
            pa[k] + FLOAT_SCALE * na[k]
        } else {
            moved
        };
    }
    Vec3A::from_array(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_moves_to_the_requested_side() {
        for p in [
            Vec3A::ZERO,
            Vec3A::splat(1000.0),
            Vec3A::new(-3.0, 0.01, 7.5),
        ] {
            let n = Vec3A::Y;
            let up = offset_ray_origin(p, n, Vec3A::Y);
            let down = offset_ray_origin(p, n, -Vec3A::Y);
            assert!(up.y > p.y && down.y < p.y, "{p} {up} {down}");
            assert!((up - p).length() < 1e-3 * (1.0 + p.length()));
        }
    }
}
