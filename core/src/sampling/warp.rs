//! Warps from uniform numbers in [0,1)ⁿ to directions and points, with their densities.

use glam::{Vec2, Vec3A, Vec4};
use std::f32::consts::{FRAC_1_PI, FRAC_PI_4, PI};

/// sin and cos of `a`, |a| ≤ π/4, from minimax polynomials (Cephes' `sinf`/`cosf` kernels;
/// error about 1 ulp there). Plain arithmetic, unlike the C library's `sinf`, which glibc picks
/// per CPU at load time (an FMA variant or not) and which may round differently between the
/// machines of one farm: sampling must not depend on the machine.
#[inline]
fn sincos_quarter(a: f32) -> (f32, f32) {
    let z = a * a;
    let s = ((-1.951_529_6e-4 * z + 8.332_161e-3) * z - 1.666_665_5e-1) * z * a + a;
    let c = ((2.443_315_7e-5 * z - 1.388_731_6e-3) * z + 4.166_664_6e-2) * z * z - 0.5 * z + 1.0;
    (s, c)
}

/// sin and cos of 2π`u` for `u` in [0, 1] (any finite `u`, in fact), deterministic across
/// machines (see [`sincos_quarter`]): the turn is split into the nearest quarter, exactly, and
/// a remainder of at most an eighth of a turn.
#[inline]
pub fn sincos_2pi(u: f32) -> (f32, f32) {
    let q = (4.0 * u).round();
    let a = (u - 0.25 * q) * (2.0 * PI);
    let (s, c) = sincos_quarter(a);
    match (q as i32) & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// Uniform point on the unit disk (Shirley–Chiu concentric map: low distortion, so
/// stratification survives).
#[inline]
pub fn concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    // |x| > |y|: θ = a = π/4 · y/x, r = x. Else θ = π/2 − a with a = π/4 · x/y, r = y, and
    // cos θ = sin a, sin θ = cos a. The case is a coin flip per sample: chosen with SIMD
    // masks (compiled without a branch; scalar selects became mispredicted branches).
    let x_major = Vec4::splat(o.x.abs()).cmpgt(Vec4::splat(o.y.abs()));
    let nr = Vec4::select(
        x_major,
        Vec4::new(o.y, o.x, 0.0, 0.0),
        Vec4::new(o.x, o.y, 0.0, 0.0),
    );
    let (s, c) = sincos_quarter(FRAC_PI_4 * (nr.x / nr.y));
    let cs = Vec4::select(
        x_major,
        Vec4::new(c, s, 0.0, 0.0),
        Vec4::new(s, c, 0.0, 0.0),
    );
    Vec2::new(cs.x, cs.y) * nr.y
}

/// Cosine-weighted direction about +Z.
#[inline]
pub fn cosine_hemisphere(u: Vec2) -> Vec3A {
    let d = concentric_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3A::new(d.x, d.y, z)
}

/// Density of [`cosine_hemisphere`].
#[inline]
pub fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    cos_theta.max(0.0) * FRAC_1_PI
}

/// Uniform direction on the unit sphere.
#[inline]
pub fn uniform_sphere(u: Vec2) -> Vec3A {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (sin_phi, cos_phi) = sincos_2pi(u.y);
    Vec3A::new(r * cos_phi, r * sin_phi, z)
}

/// Density of [`uniform_sphere`].
pub const UNIFORM_SPHERE_PDF: f32 = 1.0 / (4.0 * PI);

/// Uniform direction in the cone of half-angle acos(`cos_max`) about +Z.
#[inline]
pub fn uniform_cone(u: Vec2, cos_max: f32) -> Vec3A {
    let cos_t = (1.0 - u.x) + u.x * cos_max;
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let (sin_phi, cos_phi) = sincos_2pi(u.y);
    Vec3A::new(sin_t * cos_phi, sin_t * sin_phi, cos_t)
}

/// Uniform barycentric coordinates (b0, b1) on a triangle (Heitz's low-distortion map).
#[inline]
pub fn uniform_triangle(u: Vec2) -> (f32, f32) {
    // u.x < u.y: b0 = u.x / 2, b1 = u.y − b0; else b1 = u.y / 2, b0 = u.x − b1. The case is
    // a coin flip per sample: chosen with SIMD masks, without a branch.
    let x_first = Vec4::splat(u.x).cmplt(Vec4::splat(u.y));
    let v = Vec4::select(
        x_first,
        Vec4::new(u.x, u.y, 0.0, 0.0),
        Vec4::new(u.y, u.x, 0.0, 0.0),
    );
    let h = v.x / 2.0;
    let rest = v.y - h;
    let b = Vec4::select(
        x_first,
        Vec4::new(h, rest, 0.0, 0.0),
        Vec4::new(rest, h, 0.0, 0.0),
    );
    (b.x, b.y)
}

/// An orthonormal basis whose Z axis is `n` (Duff et al. 2017, branchless and continuous).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// Tangent.
    pub x: Vec3A,
    /// Bitangent.
    pub y: Vec3A,
    /// Normal.
    pub z: Vec3A,
}

impl Frame {
    /// Any frame around unit `n`.
    #[inline]
    pub fn from_z(n: Vec3A) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let x = Vec3A::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let y = Vec3A::new(b, sign + n.y * n.y * a, -n.y);
        Self { x, y, z: n }
    }

    /// A frame around unit `n` whose X axis follows tangent `t` (Gram–Schmidt); falls back to
    /// [`Frame::from_z`] when `t` is degenerate or parallel to `n`.
    #[inline]
    pub fn from_zx(n: Vec3A, t: Vec3A) -> Self {
        let x = t - n * n.dot(t);
        let len2 = x.length_squared();
        if !(len2 > 1e-12) {
            return Self::from_z(n);
        }
        let x = x / len2.sqrt();
        Self {
            x,
            y: n.cross(x),
            z: n,
        }
    }

    /// World to local.
    #[inline]
    pub fn to_local(&self, v: Vec3A) -> Vec3A {
        Vec3A::new(v.dot(self.x), v.dot(self.y), v.dot(self.z))
    }

    /// Local to world.
    #[inline]
    pub fn to_world(&self, v: Vec3A) -> Vec3A {
        self.x * v.x + self.y * v.y + self.z * v.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sincos_2pi_is_accurate_everywhere() {
        let mut worst = 0.0f64;
        for i in 0..=100_000 {
            let u = i as f32 / 100_000.0;
            let (s, c) = sincos_2pi(u);
            let phi = 2.0 * std::f64::consts::PI * u as f64;
            worst = worst
                .max((s as f64 - phi.sin()).abs())
                .max((c as f64 - phi.cos()).abs());
        }
        assert!(worst < 3e-7, "worst error {worst}");
        // Exact at the quarter turns.
        assert_eq!(sincos_2pi(0.0), (0.0, 1.0));
        assert_eq!(sincos_2pi(0.25), (1.0, 0.0));
        assert_eq!(sincos_2pi(0.5), (-0.0, -1.0));
        assert_eq!(sincos_2pi(0.75), (-1.0, 0.0));
    }

    #[test]
    fn concentric_disk_matches_the_trigonometric_map() {
        for i in 0..200 {
            for j in 0..200 {
                let u = Vec2::new((i as f32 + 0.5) / 200.0, (j as f32 + 0.5) / 200.0);
                let o = 2.0 * u - Vec2::ONE;
                let (r, theta) = if o.x.abs() > o.y.abs() {
                    (o.x as f64, std::f64::consts::FRAC_PI_4 * (o.y / o.x) as f64)
                } else {
                    (
                        o.y as f64,
                        std::f64::consts::FRAC_PI_2
                            - std::f64::consts::FRAC_PI_4 * (o.x / o.y) as f64,
                    )
                };
                let d = concentric_disk(u);
                assert!((d.x as f64 - r * theta.cos()).abs() < 3e-7, "{u}");
                assert!((d.y as f64 - r * theta.sin()).abs() < 3e-7, "{u}");
                assert!(d.length_squared() <= 1.0);
            }
        }
    }

    #[test]
    fn frames_are_orthonormal() {
        for n in [
            Vec3A::Z,
            -Vec3A::Z,
            Vec3A::X,
            Vec3A::new(0.3, -0.5, 0.8).normalize(),
        ] {
            let f = Frame::from_z(n);
            assert!((f.x.length() - 1.0).abs() < 1e-5 && (f.y.length() - 1.0).abs() < 1e-5);
            assert!(f.x.dot(f.y).abs() < 1e-5 && f.x.dot(n).abs() < 1e-5);
            assert!((f.x.cross(f.y) - n).length() < 1e-4, "right-handed");
            let v = Vec3A::new(0.2, 0.7, -0.1);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-5);
        }
    }

    #[test]
    fn warps_stay_in_their_domains() {
        for i in 0..64 {
            let u = Vec2::new((i as f32 + 0.5) / 64.0, ((i * 37) % 64) as f32 / 64.0);
            assert!(concentric_disk(u).length() <= 1.0 + 1e-6);
            assert!(cosine_hemisphere(u).z >= 0.0);
            assert!((uniform_sphere(u).length() - 1.0).abs() < 1e-5);
            assert!(uniform_cone(u, 0.9).z >= 0.9 - 1e-6);
            let (b0, b1) = uniform_triangle(u);
            assert!(b0 >= 0.0 && b1 >= 0.0 && b0 + b1 <= 1.0 + 1e-6);
        }
    }
}
