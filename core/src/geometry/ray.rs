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
    let n = if n.dot(w) < 0.0 { -n } else { n };
    #[cfg(target_arch = "x86_64")]
    {
        offset_sse2(p, n)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        offset_scalar(p, n)
    }
}

const ORIGIN: f32 = 1.0 / 32.0;
const FLOAT_SCALE: f32 = 1.0 / 65536.0;
const INT_SCALE: f32 = 256.0;

/// [`offset_ray_origin`] for `n` already on the side to move to, one coordinate at a time.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
#[inline]
fn offset_scalar(p: Vec3A, n: Vec3A) -> Vec3A {
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
        let of = if pa[k] < 0.0 { -of_i[k] } else { of_i[k] };
        let moved = f32::from_bits(bits.wrapping_add(of) as u32);
        out[k] = if pa[k].abs() < ORIGIN {
            pa[k] + FLOAT_SCALE * na[k]
        } else {
            moved
        };
    }
    Vec3A::from_array(out)
}

/// [`offset_scalar`] on all three coordinates at once with SSE2 (baseline on x86-64): the same
/// bits for every finite unit `n` (a test checks).
#[cfg(target_arch = "x86_64")]
#[inline]
fn offset_sse2(p: Vec3A, n: Vec3A) -> Vec3A {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is part of x86-64; every operation is plain lane arithmetic.
    unsafe {
        let pv: __m128 = p.into();
        let nv: __m128 = n.into();
        // Truncation, as `as i32` (|256·n| ≤ 256 for a unit normal: no saturation case).
        let of = _mm_cvttps_epi32(_mm_mul_ps(nv, _mm_set1_ps(INT_SCALE)));
        // Negate the offset where p < 0: (of ^ m) - m with m all ones there.
        let neg = _mm_castps_si128(_mm_cmplt_ps(pv, _mm_setzero_ps()));
        let of = _mm_sub_epi32(_mm_xor_si128(of, neg), neg);
        let moved = _mm_castsi128_ps(_mm_add_epi32(_mm_castps_si128(pv), of));
        let near = _mm_add_ps(pv, _mm_mul_ps(_mm_set1_ps(FLOAT_SCALE), nv));
        let abs = _mm_andnot_ps(_mm_set1_ps(-0.0), pv);
        let small = _mm_cmplt_ps(abs, _mm_set1_ps(ORIGIN));
        let out = _mm_or_ps(_mm_and_ps(small, near), _mm_andnot_ps(small, moved));
        Vec3A::from(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn simd_offset_equals_scalar_offset() {
        let mut h = 12345u32;
        let mut rnd = || {
            h = crate::sampling::hash_u32(h);
            h as f32 / u32::MAX as f32
        };
        for i in 0..200_000 {
            let scale = [1e-3, 0.02, 1.0, 30.0, 1e4][i % 5];
            let p = Vec3A::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5) * 2.0 * scale;
            let n = Vec3A::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5).normalize();
            let (a, b) = (offset_sse2(p, n), offset_scalar(p, n));
            assert_eq!(
                a.to_array().map(f32::to_bits),
                b.to_array().map(f32::to_bits),
                "{p} {n}"
            );
        }
        for p in [Vec3A::ZERO, Vec3A::splat(-0.0), Vec3A::new(-1.0, 0.0, 1.0)] {
            for n in [Vec3A::X, -Vec3A::Y, Vec3A::Z] {
                let (a, b) = (offset_sse2(p, n), offset_scalar(p, n));
                assert_eq!(
                    a.to_array().map(f32::to_bits),
                    b.to_array().map(f32::to_bits)
                );
            }
        }
    }

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
