//! `exp` and `ln` for f32 from our own polynomial kernels, so that they round alike on every
//! machine of a farm.
//!
//! Rust's `f32::exp` and `f32::ln` call the C library, and glibc picks its `expf`/`logf` per CPU
//! at load time (FMA variants or not): two workers could round a transmittance differently and
//! a frame would no longer be bit-identical to a local render. These use only `+`, `-`, `*`
//! and bit manipulation, which Rust never contracts into FMAs, with Cephes' `expf`/`logf`
//! minimax kernels (Moshier). Measured against f64 on every 97th float (tests below): `exp`
//! within 0.96 ulp over its normal range and 1 ulp in the subnormals; `ln` within 8.1e-8
//! relative (and 2 ulp near 1, where exponential sampling calls it).

use glam::Vec3A;

/// log2(e).
const LOG2_E: f32 = std::f32::consts::LOG2_E;
/// ln 2 split in two (Cody–Waite): `LN2_HI` has few significant bits, so `n · LN2_HI` is exact
/// for the `n` that occur, and `LN2_HI + LN2_LO` is ln 2 to far more than f32 precision.
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;
/// Above this `exp` overflows to infinity.
const EXP_MAX_ARG: f32 = 88.722_83;
/// Below this `exp` underflows to zero (half the smallest subnormal).
const EXP_MIN_ARG: f32 = -103.972_08;

/// 2ⁿ for integer `n` in [-149, 127], exactly (subnormal results for n < -126).
#[inline]
fn pow2i(n: i32) -> f32 {
    if n >= -126 {
        f32::from_bits(((n + 127) as u32) << 23)
    } else {
        // 2^(n + 64) is normal here; 2^-64 is exact too, and the product rounds once.
        f32::from_bits(((n + 64 + 127) as u32) << 23) * f32::from_bits(((127 - 64) as u32) << 23)
    }
}

/// eˣ, deterministic across machines (see the module documentation). `exp(0) == 1` exactly,
/// `exp(-inf) == 0`, `exp(NaN)` is NaN.
#[inline]
pub fn exp(x: f32) -> f32 {
    if !(x < EXP_MAX_ARG) {
        // NaN stays NaN, large arguments overflow.
        return if x.is_nan() { x } else { f32::INFINITY };
    }
    if x < EXP_MIN_ARG {
        return 0.0;
    }
    // x = n ln2 + r with |r| ≤ ln2 / 2; eˣ = 2ⁿ eʳ.
    // Round to the nearest integer by adding and removing 1.5 · 2²³ (|x · log2 e| < 150):
    // exact, and no call to `floor`, which baseline x86-64 (without SSE4.1) does in libm.
    const ROUND: f32 = 12_582_912.0;
    let n = (x * LOG2_E + ROUND) - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let z = r * r;
    let p = (((((1.987_569_2e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2)
        * r
        + 1.666_666_5e-1)
        * r
        + 0.5)
        * z
        + r
        + 1.0;
    let n = n as i32;
    // Split the scale so that neither factor overflows nor underflows early: the polynomial
    // lies in [0.7, 1.42], so 2ⁿ alone could be out of range where the product is not.
    if n > 127 {
        p * 2.0 * pow2i(n - 1)
    } else if n < -126 {
        // One rounding only: scale into the normal range first, then into the subnormals.
        (p * pow2i(n + 64)) * pow2i(-64)
    } else {
        p * pow2i(n)
    }
}

/// Natural logarithm, deterministic across machines (see the module documentation).
/// `ln(1) == 0` exactly, `ln(0) == -inf`, `ln(x < 0)` and `ln(NaN)` are NaN, `ln(inf) == inf`.
#[inline]
pub fn ln(x: f32) -> f32 {
    if !(x > 0.0) {
        return if x == 0.0 {
            f32::NEG_INFINITY
        } else {
            f32::NAN
        };
    }
    if x == f32::INFINITY {
        return x;
    }
    // x = m · 2ᵉ with m in [0.5, 1); subnormals are scaled up first.
    let (x, bias) = if x < f32::MIN_POSITIVE {
        (x * 8_388_608.0, -23)
    } else {
        (x, 0)
    };
    let bits = x.to_bits();
    let mut e = ((bits >> 23) & 0xff) as i32 - 126 + bias;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f00_0000);
    // Keep m in [√½, √2) around 1, where the kernel is accurate.
    let m = if m < std::f32::consts::FRAC_1_SQRT_2 {
        e -= 1;
        m + m - 1.0
    } else {
        m - 1.0
    };
    let z = m * m;
    let mut y = ((((((((7.037_683_6e-2 * m - 1.151_461e-1) * m + 1.167_699_9e-1) * m
        - 1.242_014_1e-1)
        * m
        + 1.424_932_3e-1)
        * m
        - 1.666_805_8e-1)
        * m
        + 2.000_071_4e-1)
        * m
        - 2.499_999_4e-1)
        * m
        + 3.333_333e-1)
        * m
        * z;
    let fe = e as f32;
    y += LN2_LO * fe;
    y += -0.5 * z;
    m + y + LN2_HI * fe
}

/// [`exp`] per component.
#[inline]
pub fn exp3(v: Vec3A) -> Vec3A {
    Vec3A::new(exp(v.x), exp(v.y), exp(v.z))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance in units in the last place between an f32 and the exact value (as f64).
    fn ulps(got: f32, want: f64) -> f64 {
        let w = want as f32;
        let ulp = if w == 0.0 {
            f32::from_bits(1) as f64
        } else {
            (f32::from_bits(w.abs().to_bits() + 1) - w.abs()) as f64
        };
        ((got as f64) - want).abs() / ulp
    }

    /// Every 97th f32 in [lo, hi] (about 10⁶ values over a wide range), plus the ends.
    fn sweep(lo: f32, hi: f32, mut f: impl FnMut(f32)) {
        let mut x = lo;
        while x < hi {
            f(x);
            let step = if x >= 0.0 { 97 } else { -97i32 as u32 };
            let next = f32::from_bits(x.to_bits().wrapping_add(step));
            // Crossing zero: restart from the smallest positive value.
            x = if x < 0.0 && !(next < 0.0) {
                f32::from_bits(1)
            } else {
                next
            };
        }
        f(hi);
    }

    #[test]
    fn exp_is_within_one_ulp_of_f64() {
        let mut worst = 0.0f64;
        let mut worst_at = 0.0;
        sweep(-87.0, 88.7, |x| {
            let u = ulps(exp(x), (x as f64).exp());
            if u > worst {
                worst = u;
                worst_at = x;
            }
        });
        eprintln!("exp: worst {worst} ulp at {worst_at}");
        assert!(worst <= 1.0, "worst {worst} ulp at {worst_at}");
    }

    #[test]
    fn exp_handles_subnormals_and_the_ends() {
        // Subnormal results: absolute error within one subnormal step.
        sweep(-103.9, -87.4, |x| {
            let want = (x as f64).exp();
            assert!(ulps(exp(x), want) <= 1.0, "{x}: {} vs {want}", exp(x));
        });
        assert_eq!(exp(0.0), 1.0);
        assert_eq!(exp(-0.0), 1.0);
        assert_eq!(exp(f32::NEG_INFINITY), 0.0);
        assert_eq!(exp(-200.0), 0.0);
        assert_eq!(exp(f32::INFINITY), f32::INFINITY);
        assert_eq!(exp(100.0), f32::INFINITY);
        assert!(exp(f32::NAN).is_nan());
        assert_eq!(exp3(Vec3A::new(0.0, -1.0, 1.0)).x, 1.0);
    }

    #[test]
    fn ln_is_accurate_against_f64() {
        let mut worst_rel = 0.0f64;
        let mut worst_at = 0.0;
        sweep(f32::from_bits(1), f32::MAX, |x| {
            let want = (x as f64).ln();
            let got = ln(x) as f64;
            // Near 1 the result is tiny: measure absolute error there, relative elsewhere.
            let err = if want.abs() < 0.5 {
                (got - want).abs() / 0.5
            } else {
                ((got - want) / want).abs()
            };
            if err > worst_rel {
                worst_rel = err;
                worst_at = x;
            }
            assert!(ulps(ln(x), want) <= 2.0 || want.abs() < 0.5, "{x}");
        });
        eprintln!("ln: worst relative error {worst_rel:e} at {worst_at}");
        assert!(worst_rel < 1e-7, "worst {worst_rel} at {worst_at}");
        assert_eq!(ln(1.0), 0.0);
        assert_eq!(ln(0.0), f32::NEG_INFINITY);
        assert_eq!(ln(f32::INFINITY), f32::INFINITY);
        assert!(ln(-1.0).is_nan() && ln(f32::NAN).is_nan());
    }

    #[test]
    fn ln_near_one_is_accurate_in_absolute_terms() {
        // Exponential sampling computes -ln(1 - u) for u close to 0: 1 - u close to 1.
        for i in 1..100_000u32 {
            let x = 1.0 - i as f32 * 2.0f32.powi(-24);
            let want = (x as f64).ln();
            assert!(ulps(ln(x), want) <= 2.0, "{x}: {} vs {want}", ln(x));
        }
    }

    #[test]
    fn exp_and_ln_are_inverse() {
        for i in -800..800 {
            let x = i as f32 * 0.1;
            let y = ln(exp(x));
            assert!((y - x).abs() <= 1e-5 * x.abs().max(1.0), "{x} -> {y}");
        }
    }
}
