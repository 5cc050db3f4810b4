//! Tests for every BSDF, in the manner of pbrt-v4's `bsdfs_test.cpp` and Mitsuba's `chi2`:
//! pointwise consistency of `sample` with `eval`/`pdf`, chi-square goodness of fit of the
//! sampled directions against `pdf`, white-furnace energy conservation, and Fresnel identities.
//! Every property is checked over one list of configurations ([`cases`]).

use super::conductor::{fresnel_conductor, Conductor};
use super::dielectric::Dielectric;
use super::diffuse::Diffuse;
use super::mirror::Mirror;
use super::pbr::Pbr;
use super::rough_dielectric::RoughDielectric;
use super::*;
use std::f64::consts::PI;

/// Deterministic uniform numbers (SplitMix64): the tests draw the same samples on every run.
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x1234_5678)
    }
    fn next_f32(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
    fn next_2d(&mut self) -> Vec2 {
        let x = self.next_f32();
        Vec2::new(x, self.next_f32())
    }
}

/// Unit direction at polar angle `theta_deg` from +Z (negative z when `below`).
fn dir(theta_deg: f32, phi: f32, below: bool) -> Vec3A {
    let t = theta_deg.to_radians();
    let z = if below { -t.cos() } else { t.cos() };
    Vec3A::new(t.sin() * phi.cos(), t.sin() * phi.sin(), z)
}

/// Outgoing directions: normal, 45° and grazing 85°, from above and (if `both`) from below.
fn wos(both: bool) -> Vec<Vec3A> {
    let mut v = Vec::new();
    for below in [false, true] {
        if below && !both {
            continue;
        }
        for t in [0.0, 45.0, 85.0] {
            v.push(dir(t, 0.7, below));
        }
    }
    v
}

/// One configuration to test.
struct Case {
    name: String,
    bsdf: Bsdf,
    wos: Vec<Vec3A>,
    /// White parameters: the directional albedo must not exceed 1.
    white: bool,
}

fn case(name: String, bsdf: Bsdf, both: bool, white: bool) -> Case {
    Case {
        name,
        bsdf,
        wos: wos(both),
        white,
    }
}

fn gold(alpha: f32) -> Conductor {
    Conductor {
        eta: Vec3A::new(0.143, 0.374, 1.442),
        k: Vec3A::new(3.983, 2.385, 1.603),
        alpha,
    }
}

fn pbr(roughness: f32) -> Pbr {
    Pbr {
        base_color: Vec3A::ONE,
        metallic: 0.0,
        alpha: roughness * roughness,
        specular: 1.0,
        specular_color: Vec3A::ONE,
        ior: 1.5,
        transmission: 0.0,
        thin: true,
        clearcoat: 0.0,
        clearcoat_alpha: 0.0,
    }
}

/// Every BSDF variant under the parameter sets of the brief. `alpha` filters the rough ones
/// (GGX alpha for conductors and rough dielectrics, glTF roughness for `Pbr`); `None` keeps all.
fn cases(alpha: Option<f32>) -> Vec<Case> {
    let keep = |a: f32| alpha.is_none_or(|x| x == a);
    let mut v = Vec::new();
    if alpha.is_none() {
        for a in [0.5f32, 1.0] {
            let b = Bsdf::Diffuse(Diffuse {
                albedo: Vec3A::splat(a),
            });
            v.push(case(format!("diffuse {a}"), b, true, true));
        }
        let b = Bsdf::Mirror(Mirror {
            reflectance: Vec3A::ONE,
        });
        v.push(case("mirror".into(), b, true, true));
        for eta in [1.0f32, 1.33, 1.5, 2.4] {
            for thin in [false, true] {
                let b = Bsdf::Dielectric(Dielectric {
                    eta,
                    transmittance: Vec3A::ONE,
                    thin,
                });
                v.push(case(
                    format!("dielectric eta {eta} thin {thin}"),
                    b,
                    true,
                    true,
                ));
            }
        }
        let b = Bsdf::Conductor(Conductor {
            alpha: 0.0,
            ..gold(0.0)
        });
        v.push(case("smooth gold".into(), b, true, true));
        let b = Bsdf::RoughDielectric(RoughDielectric {
            eta: 1.5,
            alpha: 0.0,
            transmittance: Vec3A::ONE,
        });
        v.push(case("rough dielectric alpha 0".into(), b, true, true));
        // glTF roughness 0 must stay finite (alpha is clamped).
        for metallic in [0.0, 1.0] {
            let b = Bsdf::Pbr(Pbr {
                metallic,
                clearcoat: 1.0,
                ..pbr(0.0)
            });
            v.push(case(
                format!("pbr roughness 0 metallic {metallic}"),
                b,
                true,
                true,
            ));
        }
        let b = Bsdf::Pbr(Pbr {
            transmission: 1.0,
            thin: false,
            ..pbr(0.0)
        });
        v.push(case("pbr roughness 0 refractive".into(), b, true, true));
    }
    for a in [0.05f32, 0.3, 0.8] {
        if !keep(a) {
            continue;
        }
        let white = Conductor {
            eta: Vec3A::ZERO,
            k: Vec3A::ONE,
            alpha: a,
        };
        v.push(case(
            format!("white conductor alpha {a}"),
            Bsdf::Conductor(white),
            true,
            true,
        ));
        v.push(case(
            format!("gold alpha {a}"),
            Bsdf::Conductor(gold(a)),
            false,
            true,
        ));
        for eta in [1.33f32, 1.5, 2.4] {
            let b = Bsdf::RoughDielectric(RoughDielectric {
                eta,
                alpha: a,
                transmittance: Vec3A::ONE,
            });
            v.push(case(
                format!("rough dielectric alpha {a} eta {eta}"),
                b,
                true,
                true,
            ));
        }
        let r = a;
        v.push(case(
            format!("pbr plastic roughness {r}"),
            Bsdf::Pbr(pbr(r)),
            false,
            true,
        ));
        v.push(case(
            format!("pbr metal roughness {r}"),
            Bsdf::Pbr(Pbr {
                metallic: 1.0,
                ..pbr(r)
            }),
            false,
            true,
        ));
        v.push(case(
            format!("pbr mixed roughness {r}"),
            Bsdf::Pbr(Pbr {
                base_color: Vec3A::new(0.8, 0.5, 0.2),
                metallic: 0.5,
                specular_color: Vec3A::new(1.0, 0.5, 0.5),
                ior: 2.4,
                ..pbr(r)
            }),
            false,
            true,
        ));
        v.push(case(
            format!("pbr clearcoat roughness {r}"),
            Bsdf::Pbr(Pbr {
                base_color: Vec3A::new(0.9, 0.2, 0.1),
                clearcoat: 1.0,
                clearcoat_alpha: 0.01,
                ..pbr(r)
            }),
            false,
            true,
        ));
        v.push(case(
            format!("pbr thin transmission roughness {r}"),
            Bsdf::Pbr(Pbr {
                transmission: 1.0,
                ..pbr(r)
            }),
            true,
            true,
        ));
        for ior in [1.33f32, 2.4] {
            v.push(case(
                format!("pbr refractive transmission roughness {r} ior {ior}"),
                Bsdf::Pbr(Pbr {
                    transmission: 0.7,
                    thin: false,
                    ior,
                    ..pbr(r)
                }),
                true,
                true,
            ));
        }
    }
    // Index-matched surfaces (ior 1): a pass-through, alone or beside a diffuse base. Last, so
    // that the cases before keep their seeds.
    if alpha.is_none() {
        for (r, transmission, thin) in [
            (0.0f32, 1.0f32, false),
            (0.5, 1.0, false),
            (0.5, 0.6, false),
            (0.5, 1.0, true),
        ] {
            let b = Bsdf::Pbr(Pbr {
                transmission,
                thin,
                ior: 1.0,
                ..pbr(r)
            });
            v.push(case(
                format!("pbr index-matched roughness {r} transmission {transmission} thin {thin}"),
                b,
                true,
                true,
            ));
        }
    }
    v
}

// ---------------------------------------------------------------------------------------------
// a. Pointwise consistency of sample with eval and pdf.

fn close(a: f32, b: f32, rel: f32) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()) + 1e-6
}

#[test]
fn sample_agrees_with_eval_and_pdf() {
    for c in cases(None) {
        for (k, &wo) in c.wos.iter().enumerate() {
            let mut rng = Rng::new(k as u64);
            let mut n_ok = 0;
            for _ in 0..2000 {
                let Some(s) = c.bsdf.sample(wo, rng.next_f32(), rng.next_2d()) else {
                    continue;
                };
                assert!(
                    (s.wi.length() - 1.0).abs() < 1e-3,
                    "{}: wi not unit",
                    c.name
                );
                assert_eq!(
                    s.lobe.is_transmission(),
                    s.wi.z * wo.z < 0.0,
                    "{}: lobe side",
                    c.name
                );
                if s.lobe.is_delta() {
                    continue;
                }
                n_ok += 1;
                let f = c.bsdf.eval(wo, s.wi);
                let pdf = c.bsdf.pdf(wo, s.wi);
                for i in 0..3 {
                    assert!(
                        close(s.f[i], f[i], 1e-3),
                        "{} wo {wo} wi {}: sample f {} eval {}",
                        c.name,
                        s.wi,
                        s.f,
                        f
                    );
                }
                assert!(
                    close(s.pdf, pdf, 1e-3),
                    "{} wo {wo} wi {}: sample pdf {} pdf {}",
                    c.name,
                    s.wi,
                    s.pdf,
                    pdf
                );
            }
            if !c.bsdf.is_delta() {
                assert!(n_ok > 0, "{}: no non-delta samples at wo {wo}", c.name);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// b. Chi-square goodness of fit.

/// Polar bins (uniform in θ over [0, π]) and azimuthal bins.
const N_THETA: usize = 10;
const N_PHI: usize = 20;

fn bin_of(w: Vec3A) -> usize {
    let theta = (w.z as f64).clamp(-1.0, 1.0).acos();
    let phi = (w.y as f64).atan2(w.x as f64) + PI;
    let i = ((theta / PI * N_THETA as f64) as usize).min(N_THETA - 1);
    let j = ((phi / (2.0 * PI) * N_PHI as f64) as usize).min(N_PHI - 1);
    i * N_PHI + j
}

/// Maps s ∈ [0, 1] to a polar angle θ and dθ/ds.
type ThetaMap<'a> = &'a dyn Fn(f64) -> (f64, f64);

/// ∫ pdf over the rectangle [s0, s1] × [p0, p1] of (s, φ), θ = `theta(s)`, by 4×4 midpoints,
/// refined adaptively by quadrants. Refinement always goes two levels deep (so that a lobe
/// smaller than a bin cannot hide between the coarse midpoints) and at most `depth` levels.
fn integrate(
    pdf: &dyn Fn(Vec3A) -> f64,
    theta: ThetaMap,
    (s0, s1, p0, p1): (f64, f64, f64, f64),
    depth: u32,
) -> f64 {
    let midpoint = |s0: f64, s1: f64, p0: f64, p1: f64| {
        let (ds, dp) = ((s1 - s0) / 4.0, (p1 - p0) / 4.0);
        let mut sum = 0.0;
        for a in 0..4 {
            let (t, jac) = theta(s0 + (a as f64 + 0.5) * ds);
            let (st, ct) = t.sin_cos();
            for b in 0..4 {
                let p = p0 + (b as f64 + 0.5) * dp;
                let w = Vec3A::new((st * p.cos()) as f32, (st * p.sin()) as f32, ct as f32);
                sum += pdf(w) * st * jac;
            }
        }
        sum * ds * dp
    };
    let coarse = midpoint(s0, s1, p0, p1);
    let (sm, pm) = (0.5 * (s0 + s1), 0.5 * (p0 + p1));
    let quads = [
        (s0, sm, p0, pm),
        (sm, s1, p0, pm),
        (s0, sm, pm, p1),
        (sm, s1, pm, p1),
    ];
    let fine: f64 = quads.iter().map(|&(a, b, c, d)| midpoint(a, b, c, d)).sum();
    if depth == 0 || (depth < CHI2_DEPTH - 1 && (fine - coarse).abs() <= 3e-3 * fine.abs() + 3e-7) {
        return fine;
    }
    quads
        .iter()
        .map(|&q| integrate(pdf, theta, q, depth - 1))
        .sum()
}

/// The polar map of bin row `i`: linear inside, cubic towards the poles, where normal-incidence
/// lobes put their narrow peaks.
fn theta_map(i: usize) -> impl Fn(f64) -> (f64, f64) {
    let (t0, t1) = (
        PI * i as f64 / N_THETA as f64,
        PI * (i + 1) as f64 / N_THETA as f64,
    );
    move |s: f64| {
        if i == 0 {
            (t1 * s * s * s, 3.0 * t1 * s * s)
        } else if i == N_THETA - 1 {
            let r = 1.0 - s;
            (PI - (PI - t0) * r * r * r, 3.0 * (PI - t0) * r * r)
        } else {
            (t0 + (t1 - t0) * s, t1 - t0)
        }
    }
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7, n = 9).
fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        return (PI / (PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + 7.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Regularised upper incomplete gamma Q(a, x) (series below a + 1, Lentz's continued fraction
/// above, as in Numerical Recipes).
fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let front = (-x + a * x.ln() - ln_gamma(a)).exp();
    if x < a + 1.0 {
        let (mut ap, mut del, mut sum) = (a, 1.0 / a, 1.0 / a);
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        1.0 - sum * front
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        front * h
    }
}

/// p-value of a chi-square statistic with `dof` degrees of freedom.
fn chi2_p_value(chi2: f64, dof: usize) -> f64 {
    gamma_q(dof as f64 / 2.0, chi2 / 2.0)
}

#[test]
fn chi2_cdf_matches_tables() {
    // Critical values of the chi-square distribution (upper tail 0.05 and 0.01).
    for (x, dof, p) in [(3.841, 1, 0.05), (18.307, 10, 0.05), (135.807, 100, 0.01)] {
        let q = chi2_p_value(x, dof);
        assert!((q - p).abs() < 1e-3 * p.max(0.01), "dof {dof}: {q} vs {p}");
    }
    assert!((chi2_p_value(2.0, 2) - (-1.0f64).exp()).abs() < 1e-12);
}

const CHI2_SAMPLES: usize = 100_000;
/// Deepest refinement of a bin's integral (4^depth sub-rectangles).
const CHI2_DEPTH: u32 = 8;
/// Significance level of each chi-square test function as a whole; every check in it must pass
/// at the Šidák-corrected level 1 − (1 − α)^(1/checks), so that a correct sampler fails by
/// chance with probability α per test function, not per check.
const CHI2_ALPHA: f64 = 0.01;

fn sidak(checks: usize) -> f64 {
    1.0 - (1.0 - CHI2_ALPHA).powf(1.0 / checks.max(1) as f64)
}

/// Histograms `CHI2_SAMPLES` non-delta samples against the integrated pdf; returns the p-value
/// and checks that the pdf integrates to the fraction of non-delta samples.
fn chi2_check(name: &str, bsdf: &Bsdf, wo: Vec3A, seed: u64) -> f64 {
    let mut rng = Rng::new(seed);
    let mut observed = vec![0.0f64; N_THETA * N_PHI];
    let mut n_smooth = 0usize;
    for _ in 0..CHI2_SAMPLES {
        if let Some(s) = bsdf.sample(wo, rng.next_f32(), rng.next_2d()) {
            if !s.lobe.is_delta() {
                observed[bin_of(s.wi)] += 1.0;
                n_smooth += 1;
            }
        }
    }
    let pdf = |w: Vec3A| bsdf.pdf(wo, w) as f64;
    let mut expected = vec![0.0f64; N_THETA * N_PHI];
    for i in 0..N_THETA {
        let theta = theta_map(i);
        for j in 0..N_PHI {
            let (p0, p1) = (
                2.0 * PI * j as f64 / N_PHI as f64 - PI,
                2.0 * PI * (j + 1) as f64 / N_PHI as f64 - PI,
            );
            expected[i * N_PHI + j] =
                CHI2_SAMPLES as f64 * integrate(&pdf, &theta, (0.0, 1.0, p0, p1), CHI2_DEPTH);
        }
    }
    // The pdf integrates to the probability of a non-delta sample.
    let integral = expected.iter().sum::<f64>() / CHI2_SAMPLES as f64;
    let frac = n_smooth as f64 / CHI2_SAMPLES as f64;
    assert!(
        (integral - frac).abs() < 5e-3,
        "{name} wo {wo}: ∫pdf = {integral}, non-delta fraction {frac}"
    );
    // Pool the cells with few expected samples (Mitsuba's rule of 5).
    let (mut chi2, mut cells) = (0.0, 0usize);
    let (mut pool_o, mut pool_e) = (0.0, 0.0);
    for (&o, &e) in observed.iter().zip(&expected) {
        if e < 5.0 {
            pool_o += o;
            pool_e += e;
        } else {
            chi2 += (o - e) * (o - e) / e;
            cells += 1;
        }
    }
    if pool_e >= 5.0 {
        chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        cells += 1;
    } else {
        assert!(
            pool_o <= pool_e + 10.0,
            "{name} wo {wo}: {pool_o} samples where the pdf expects {pool_e}"
        );
    }
    if cells < 2 {
        return 1.0;
    }
    chi2_p_value(chi2, cells - 1)
}

/// Chi-square checks over every non-delta case with rough parameter `alpha` whose kind is
/// selected by `select`.
fn chi2_all(alpha: f32, select: fn(&Bsdf) -> bool) {
    let mut runs = Vec::new();
    for (k, c) in cases(Some(alpha)).into_iter().enumerate() {
        if c.bsdf.is_delta() || !select(&c.bsdf) {
            continue;
        }
        for (m, &wo) in c.wos.iter().enumerate() {
            let p = chi2_check(&c.name, &c.bsdf, wo, (k * 16 + m) as u64);
            runs.push((format!("{} wo {wo}", c.name), p));
        }
    }
    let level = sidak(runs.len());
    let failures: Vec<String> = runs
        .iter()
        .filter(|(_, p)| *p < level)
        .map(|(n, p)| format!("{n}: p = {p:.2e} < {level:.2e}"))
        .collect();
    assert!(
        failures.is_empty(),
        "chi-square failures:\n{}",
        failures.join("\n")
    );
}

fn is_rough_dielectric(b: &Bsdf) -> bool {
    matches!(b, Bsdf::RoughDielectric(_))
}

fn is_conductor(b: &Bsdf) -> bool {
    matches!(b, Bsdf::Conductor(_))
}

fn is_pbr_opaque(b: &Bsdf) -> bool {
    matches!(b, Bsdf::Pbr(p) if p.transmission == 0.0)
}

fn is_pbr_transmissive(b: &Bsdf) -> bool {
    matches!(b, Bsdf::Pbr(p) if p.transmission > 0.0)
}

#[test]
fn chi2_diffuse() {
    for c in cases(None) {
        if matches!(c.bsdf, Bsdf::Diffuse(_)) {
            for &wo in &c.wos {
                let p = chi2_check(&c.name, &c.bsdf, wo, 99);
                assert!(p >= sidak(12), "{} wo {wo}: p = {p}", c.name);
            }
        }
    }
}

#[test]
fn chi2_rough_dielectric_alpha_005() {
    chi2_all(0.05, is_rough_dielectric);
}

#[test]
fn chi2_conductor_alpha_005() {
    chi2_all(0.05, is_conductor);
}

#[test]
fn chi2_pbr_opaque_roughness_005() {
    chi2_all(0.05, is_pbr_opaque);
}

#[test]
fn chi2_pbr_transmissive_roughness_005() {
    chi2_all(0.05, is_pbr_transmissive);
}

#[test]
fn chi2_rough_dielectric_alpha_03() {
    chi2_all(0.3, is_rough_dielectric);
}

#[test]
fn chi2_conductor_alpha_03() {
    chi2_all(0.3, is_conductor);
}

#[test]
fn chi2_pbr_opaque_roughness_03() {
    chi2_all(0.3, is_pbr_opaque);
}

#[test]
fn chi2_pbr_transmissive_roughness_03() {
    chi2_all(0.3, is_pbr_transmissive);
}

#[test]
fn chi2_rough_dielectric_alpha_08() {
    chi2_all(0.8, is_rough_dielectric);
}

#[test]
fn chi2_conductor_alpha_08() {
    chi2_all(0.8, is_conductor);
}

#[test]
fn chi2_pbr_opaque_roughness_08() {
    chi2_all(0.8, is_pbr_opaque);
}

#[test]
fn chi2_pbr_transmissive_roughness_08() {
    chi2_all(0.8, is_pbr_transmissive);
}

// ---------------------------------------------------------------------------------------------
// c. Energy conservation (white furnace).

/// Mean and standard error of the flux-weighted estimator f·|cos θi|/pdf (transmission
/// multiplied back by η², i.e. without the radiance compression, which is not an energy gain).
fn albedo_estimate(bsdf: &Bsdf, wo: Vec3A, n: usize, seed: u64) -> (Vec3A, f32) {
    let mut rng = Rng::new(seed);
    let (mut sum, mut sum2) = (glam::DVec3::ZERO, 0.0f64);
    for _ in 0..n {
        if let Some(s) = bsdf.sample(wo, rng.next_f32(), rng.next_2d()) {
            let v = s.f * s.wi.z.abs() / s.pdf * (s.eta * s.eta);
            let v = glam::DVec3::new(v.x as f64, v.y as f64, v.z as f64);
            sum += v;
            sum2 += v.max_element() * v.max_element();
        }
    }
    let mean = sum / n as f64;
    let var = (sum2 / n as f64 - mean.max_element().powi(2)).max(0.0);
    (
        Vec3A::new(mean.x as f32, mean.y as f32, mean.z as f32),
        (var / n as f64).sqrt() as f32,
    )
}

#[test]
fn white_furnace_albedo_at_most_one() {
    for (k, c) in cases(None).into_iter().enumerate() {
        if !c.white {
            continue;
        }
        for &wo in &c.wos {
            let (a, sigma) = albedo_estimate(&c.bsdf, wo, 20_000, k as u64);
            assert!(
                a.max_element() <= 1.0 + 3.0 * sigma + 1e-4,
                "{} wo {wo}: albedo {a} (σ {sigma})",
                c.name
            );
            assert!(a.min_element() >= 0.0, "{}: negative albedo {a}", c.name);
        }
    }
}

/// Multiple-scattering compensation: a white rough conductor (F = 1) and a white dielectric
/// glTF material (white base, metallic 0, specular 1) reflect all the energy, for every
/// roughness and view angle, not just at most all of it.
#[test]
fn white_furnace_albedo_is_one() {
    let angles = [0.0f32, 30.0, 60.0, 75.0, 85.0];
    for (k, alpha) in [0.05f32, 0.1, 0.3, 0.5, 0.8, 1.0].into_iter().enumerate() {
        let c = Bsdf::Conductor(Conductor {
            eta: Vec3A::ZERO,
            k: Vec3A::ONE,
            alpha,
        });
        for below in [false, true] {
            for t in angles {
                let wo = dir(t, 0.4, below);
                let (a, sigma) = albedo_estimate(&c, wo, 20_000, k as u64);
                assert!(
                    (a - Vec3A::ONE).abs().max_element() < 0.01 + 3.0 * sigma,
                    "white conductor alpha {alpha} θ {t} below {below}: albedo {a} (σ {sigma})"
                );
            }
        }
    }
    for (k, r) in [0.05f32, 0.2, 0.5, 0.8, 1.0].into_iter().enumerate() {
        let p = Bsdf::Pbr(pbr(r));
        for t in angles {
            let wo = dir(t, 0.4, false);
            let (a, sigma) = albedo_estimate(&p, wo, 20_000, 100 + k as u64);
            assert!(
                (a - Vec3A::ONE).abs().max_element() < 0.015 + 3.0 * sigma,
                "white pbr roughness {r} θ {t}: albedo {a} (σ {sigma})"
            );
        }
    }
}

/// A clear glTF body (transmission 1, white base, ior 1.5) seen from inside keeps the energy
/// beyond the critical angle (41.8°): the light it cannot refract out is reflected totally.
/// Before, those paths ended, and a glass cube in a white room rendered 0.83 instead of 1.
#[test]
fn a_transmissive_body_reflects_totally_inside_beyond_the_critical_angle() {
    for (k, r) in [0.0f32, 0.1, 0.3].into_iter().enumerate() {
        let b = Bsdf::Pbr(Pbr {
            transmission: 1.0,
            thin: false,
            ..pbr(r)
        });
        for t in [20.0f32, 50.0, 70.0, 85.0] {
            let wo = dir(t, 0.4, true);
            let (a, sigma) = albedo_estimate(&b, wo, 20_000, 300 + k as u64);
            // The refraction lobe, and so its total reflection, is single scattering
            // (documented): a rough body loses what bounces between microfacets, most at
            // grazing angles (0.912 at roughness 0.3 and 85°). Before total reflection these
            // were 0.04–0.65 beyond the critical angle.
            let tol = if r <= 0.1 { 0.005 } else { 0.1 } + 3.0 * sigma;
            assert!(
                (a - Vec3A::ONE).abs().max_element() < tol,
                "clear body roughness {r}, θ {t} inside: albedo {a} (σ {sigma})"
            );
        }
    }
}

#[test]
fn furnace_exact_values() {
    let check = |b: Bsdf, expected: f32| {
        for (k, wo) in wos(true).into_iter().enumerate() {
            let (a, _) = albedo_estimate(&b, wo, 4000, k as u64);
            assert!(
                (a - Vec3A::splat(expected)).abs().max_element() < 1e-4,
                "{b:?} wo {wo}: {a} instead of {expected}"
            );
        }
    };
    check(
        Bsdf::Mirror(Mirror {
            reflectance: Vec3A::ONE,
        }),
        1.0,
    );
    check(
        Bsdf::Diffuse(Diffuse {
            albedo: Vec3A::splat(0.5),
        }),
        0.5,
    );
    for eta in [1.0, 1.33, 1.5, 2.4] {
        for thin in [false, true] {
            let d = Dielectric {
                eta,
                transmittance: Vec3A::ONE,
                thin,
            };
            // R + T = 1 for flux.
            check(Bsdf::Dielectric(d), 1.0);
            // Radiance estimate: R + T/η², η the index crossed.
            for wo in wos(true) {
                let (r, t) = if thin {
                    (0.0, 0.0)
                } else {
                    let r = fresnel_dielectric(wo.z, eta);
                    (r, 1.0 - r)
                };
                if thin {
                    continue;
                }
                // Reflection samples weigh R/P(R) = 1, transmission T/(η² P(T)) = 1/η², so the
                // expectation is R + T/η².
                let etap = if wo.z > 0.0 { eta } else { 1.0 / eta };
                let mut rng = Rng::new(5);
                for _ in 0..100 {
                    let s = d.sample(wo, rng.next_f32(), rng.next_2d()).unwrap();
                    let v = s.f.x * s.wi.z.abs() / s.pdf;
                    let (expect, p) = if s.lobe.is_transmission() {
                        (1.0 / (etap * etap), t)
                    } else {
                        (1.0, r)
                    };
                    assert!(
                        (v - expect).abs() < 1e-5,
                        "eta {eta} wo {wo}: {v} vs {expect}"
                    );
                    assert!(
                        (s.pdf - p).abs() < 1e-6,
                        "eta {eta} wo {wo}: pdf {} vs {p}",
                        s.pdf
                    );
                }
            }
        }
    }
}

#[test]
fn rough_conductor_and_glass_lose_little_energy() {
    // Single scattering GGX loses energy only through masking; at low roughness the albedo of a
    // white conductor / glass is close to one.
    let wo = dir(45.0, 0.3, false);
    let c = Bsdf::Conductor(Conductor {
        eta: Vec3A::ZERO,
        k: Vec3A::ONE,
        alpha: 0.05,
    });
    let (a, _) = albedo_estimate(&c, wo, 20_000, 1);
    assert!(a.min_element() > 0.98, "{a}");
    for below in [false, true] {
        let g = Bsdf::RoughDielectric(RoughDielectric {
            eta: 1.5,
            alpha: 0.05,
            transmittance: Vec3A::ONE,
        });
        let (a, _) = albedo_estimate(&g, dir(30.0, 0.3, below), 20_000, 2);
        assert!(a.min_element() > 0.97, "below {below}: {a}");
    }
}

// ---------------------------------------------------------------------------------------------
// d. Fresnel, reciprocity and special cases.

#[test]
fn fresnel_normal_incidence_and_total_internal_reflection() {
    for eta in [1.33f32, 1.5, 2.4] {
        let r0 = ((eta - 1.0) / (eta + 1.0)).powi(2);
        assert!((fresnel_dielectric(1.0, eta) - r0).abs() < 1e-6);
        assert!(
            (fresnel_dielectric(-1.0, eta) - r0).abs() < 1e-6,
            "from inside"
        );
        // Total internal reflection beyond the critical angle, seen from inside.
        let crit = (1.0 / eta).asin().to_degrees();
        for t in [crit + 0.5, 60.0f32.max(crit + 1.0), 89.0] {
            let wo = dir(t, 0.2, true);
            assert_eq!(fresnel_dielectric(wo.z, eta), 1.0, "eta {eta} θ {t}");
            let d = Dielectric {
                eta,
                transmittance: Vec3A::ONE,
                thin: false,
            };
            let s = d.sample(wo, 0.999, Vec2::ZERO).unwrap();
            assert_eq!(s.lobe, Lobe::SpecularReflection);
            assert_eq!(s.pdf, 1.0);
        }
        let below = dir(crit - 1.0, 0.2, true);
        assert!(fresnel_dielectric(below.z, eta) < 1.0);
        // Snell's law for the refracted direction.
        let wo = dir(40.0, 0.2, false);
        let (wt, etap) = refract(wo, Vec3A::Z, eta).unwrap();
        let sin_o = (1.0 - wo.z * wo.z).sqrt();
        let sin_t = (1.0 - wt.z * wt.z).sqrt();
        assert!((sin_o - eta * sin_t).abs() < 1e-5 && etap == eta && wt.z < 0.0);
        // From inside, the other way: the relative index crossed is 1/η; past the critical
        // angle, total internal reflection.
        let (back, etap) = refract(wt, Vec3A::Z, eta).unwrap();
        assert!((back - wo).length() < 1e-5 && etap == 1.0 / eta);
        let grazing_inside = Vec3A::new(0.9, 0.0, -(1.0f32 - 0.81).sqrt());
        assert!(refract(grazing_inside, Vec3A::Z, 1.5).is_none());
    }
    // A conductor without absorption is a dielectric; k > 0 stays in [0, 1]; grazing is 1.
    for cos in [0.1f32, 0.5, 0.9, 1.0] {
        let fc = fresnel_conductor(cos, Vec3A::splat(1.5), Vec3A::ZERO);
        assert!(
            (fc.x - fresnel_dielectric(cos, 1.5)).abs() < 1e-5,
            "cos {cos}"
        );
        let g = gold(0.0);
        let fg = fresnel_conductor(cos, g.eta, g.k);
        assert!(fg.min_element() >= 0.0 && fg.max_element() <= 1.0);
    }
    let g = gold(0.0);
    assert!(
        (fresnel_conductor(0.0, g.eta, g.k) - Vec3A::ONE)
            .abs()
            .max_element()
            < 1e-5
    );
    let f0 = Vec3A::new(0.9, 0.6, 0.3);
    let c = Conductor::from_f0(f0, 0.3);
    assert!((c.albedo() - f0).abs().max_element() < 1e-4);
}

#[test]
fn reflection_is_reciprocal_and_transmission_scales_by_eta_squared() {
    let mut rng = Rng::new(77);
    for c in cases(None) {
        if c.bsdf.is_delta() {
            continue;
        }
        // The glTF model's base lobes are not reciprocal (see `pbr`), nor is the clearcoat's
        // weighting of the layers below (1 − clearcoat · Fc(|n·v|)); its metal lobe is.
        if matches!(c.bsdf, Bsdf::Pbr(p) if p.metallic < 1.0 || p.clearcoat > 0.0) {
            continue;
        }
        for _ in 0..200 {
            let wo = uniform(&mut rng);
            let wi = uniform(&mut rng);
            let (f, b) = (c.bsdf.eval(wo, wi), c.bsdf.eval(wi, wo));
            let scale = if wo.z * wi.z > 0.0 {
                1.0
            } else if let Bsdf::RoughDielectric(r) = c.bsdf {
                let etap = if wo.z > 0.0 { r.eta } else { 1.0 / r.eta };
                etap * etap
            } else {
                1.0
            };
            for i in 0..3 {
                assert!(
                    close(f[i] * scale, b[i], 2e-3),
                    "{}: f(wo, wi) {f} · {scale} vs f(wi, wo) {b}",
                    c.name
                );
            }
        }
    }
}

fn uniform(rng: &mut Rng) -> Vec3A {
    crate::sampling::warp::uniform_sphere(rng.next_2d())
}

#[test]
fn pbr_without_specular_is_exactly_lambertian() {
    let base = Vec3A::new(0.8, 0.4, 0.1);
    for r in [0.05, 0.3, 0.8] {
        let p = Bsdf::Pbr(Pbr {
            base_color: base,
            specular: 0.0,
            ..pbr(r)
        });
        let d = Bsdf::Diffuse(Diffuse { albedo: base });
        let mut rng = Rng::new(3);
        for _ in 0..500 {
            let (wo, wi) = (uniform(&mut rng), uniform(&mut rng));
            assert_eq!(p.eval(wo, wi), d.eval(wo, wi));
            assert_eq!(p.pdf(wo, wi), d.pdf(wo, wi));
            let (uc, u) = (rng.next_f32(), rng.next_2d());
            let (sp, sd) = (p.sample(wo, uc, u), d.sample(wo, uc, u));
            assert_eq!(
                sp.map(|s| (s.wi, s.f, s.pdf)),
                sd.map(|s| (s.wi, s.f, s.pdf))
            );
        }
    }
}

#[test]
fn smooth_rough_dielectric_is_the_smooth_dielectric() {
    for eta in [1.0f32, 1.33, 2.4] {
        for alpha in [0.0f32, 1e-4, 5e-4] {
            let r = RoughDielectric {
                eta,
                alpha,
                transmittance: Vec3A::new(1.0, 0.5, 0.25),
            };
            let d = Dielectric {
                eta,
                transmittance: r.transmittance,
                thin: false,
            };
            assert!(r.is_delta());
            let mut rng = Rng::new(9);
            for wo in wos(true) {
                let (uc, u) = (rng.next_f32(), rng.next_2d());
                assert_eq!(r.sample(wo, uc, u), d.sample(wo, uc, u));
            }
        }
    }
    assert!(!Bsdf::RoughDielectric(RoughDielectric {
        eta: 1.5,
        alpha: 0.3,
        transmittance: Vec3A::ONE
    })
    .is_delta());
}

#[test]
fn is_delta_only_when_every_lobe_is() {
    let expect = |b: Bsdf, d: bool| assert_eq!(b.is_delta(), d, "{b:?}");
    expect(Bsdf::Diffuse(Diffuse { albedo: Vec3A::ONE }), false);
    expect(
        Bsdf::Mirror(Mirror {
            reflectance: Vec3A::ONE,
        }),
        true,
    );
    expect(Bsdf::Conductor(gold(0.0)), true);
    expect(Bsdf::Conductor(gold(0.3)), false);
    expect(Bsdf::Pbr(pbr(0.0)), false);
    let matched = Pbr {
        transmission: 1.0,
        thin: false,
        ior: 1.0,
        ..pbr(0.5)
    };
    expect(Bsdf::Pbr(matched), true);
    expect(
        Bsdf::Pbr(Pbr {
            transmission: 0.6,
            ..matched
        }),
        false,
    );
    expect(
        Bsdf::Pbr(Pbr {
            thin: true,
            ..matched
        }),
        true,
    );
    expect(
        Bsdf::Pbr(Pbr {
            transmission: 0.0,
            thin: true,
            ..matched
        }),
        false,
    );
    expect(
        Bsdf::Dielectric(Dielectric {
            eta: 1.5,
            transmittance: Vec3A::ONE,
            thin: true,
        }),
        true,
    );
}

#[test]
fn degenerate_inputs_never_produce_nan() {
    let bad = [
        Vec3A::ZERO,
        Vec3A::splat(f32::NAN),
        Vec3A::new(1.0, 0.0, 0.0),
        Vec3A::new(3.0, -2.0, 5.0),
        Vec3A::new(0.0, 0.0, -1e-30),
        Vec3A::splat(f32::INFINITY),
    ];
    let good = dir(30.0, 0.1, false);
    // Diffuse and Mirror (the finished examples) are left out: Diffuse returns an infinite pdf
    // for an infinite wi.
    let mut all: Vec<Case> = cases(None)
        .into_iter()
        .filter(|c| !matches!(c.bsdf, Bsdf::Diffuse(_) | Bsdf::Mirror(_)))
        .collect();
    // Parameters out of range must not produce NaN either.
    for x in [f32::NAN, 0.0, -1.0, f32::INFINITY] {
        all.push(case(
            "bad".into(),
            Bsdf::RoughDielectric(RoughDielectric {
                eta: x,
                alpha: x,
                transmittance: Vec3A::ONE,
            }),
            false,
            false,
        ));
        all.push(case(
            "bad".into(),
            Bsdf::Pbr(Pbr {
                alpha: x,
                ior: x,
                metallic: x,
                specular: x,
                transmission: x,
                ..pbr(0.5)
            }),
            false,
            false,
        ));
        all.push(case(
            "bad".into(),
            Bsdf::Conductor(Conductor {
                alpha: x,
                ..gold(0.3)
            }),
            false,
            false,
        ));
    }
    for c in all {
        for &a in bad.iter().chain([good].iter()) {
            for &b in bad.iter().chain([good, -good].iter()) {
                let f = c.bsdf.eval(a, b);
                let p = c.bsdf.pdf(a, b);
                assert!(
                    f.is_finite() && p.is_finite() && p >= 0.0,
                    "{}: {a} {b}",
                    c.name
                );
            }
            for uc in [0.0, 0.5, 0.999_999, f32::NAN] {
                if let Some(s) = c.bsdf.sample(a, uc, Vec2::new(0.3, 0.999_999)) {
                    assert!(
                        s.f.is_finite() && s.pdf.is_finite() && s.pdf > 0.0,
                        "{}",
                        c.name
                    );
                }
            }
        }
    }
}

#[test]
fn smooth_special_cases() {
    // A smooth conductor reflects exactly its Fresnel term; eta 0 is a perfect reflector.
    for wo in wos(true) {
        let s = gold(0.0).sample(wo, 0.5, Vec2::splat(0.5)).unwrap();
        assert_eq!(s.wi, Vec3A::new(-wo.x, -wo.y, wo.z));
        let g = gold(0.0);
        let expect = fresnel_conductor(wo.z.abs(), g.eta, g.k);
        assert!((s.f * s.wi.z.abs() / s.pdf - expect).abs().max_element() < 1e-5);
        let white = Conductor {
            eta: Vec3A::ZERO,
            k: Vec3A::ONE,
            alpha: 0.0,
        };
        let s = white.sample(wo, 0.5, Vec2::splat(0.5)).unwrap();
        assert!(
            (s.f * s.wi.z.abs() / s.pdf - Vec3A::ONE)
                .abs()
                .max_element()
                < 1e-5
        );
    }
    // Thin sheets transmit straight through, tinted, without bending; eta 1 is invisible.
    let tint = Vec3A::new(0.9, 0.5, 0.1);
    for (eta, thin) in [(1.5, true), (1.0, false), (1.0, true)] {
        let d = Dielectric {
            eta,
            transmittance: tint,
            thin,
        };
        for wo in wos(true) {
            let s = d.sample(wo, 0.999_999, Vec2::ZERO).unwrap();
            assert_eq!(s.lobe, Lobe::SpecularTransmission);
            assert!((s.wi + wo).length() < 1e-6, "eta {eta} thin {thin}");
            assert_eq!(s.eta, 1.0);
            let v = s.f * s.wi.z.abs() / s.pdf;
            assert!((v - tint).abs().max_element() < 1e-5, "{v}");
        }
    }
    // Thin sheets reflect more than one interface: R' = R + T²R/(1 − R²).
    let r = fresnel_dielectric(1.0, 1.5);
    let thin_r = r + (1.0 - r) * (1.0 - r) * r / (1.0 - r * r);
    let d = Dielectric {
        eta: 1.5,
        transmittance: Vec3A::ONE,
        thin: true,
    };
    let s = d.sample(Vec3A::Z, 0.0, Vec2::ZERO).unwrap();
    assert_eq!(s.lobe, Lobe::SpecularReflection);
    assert!((s.pdf - thin_r).abs() < 1e-6, "{} vs {thin_r}", s.pdf);
}

/// A body or a transmissive surface with ior 1 has no interface (pbrt-v4's dielectric at
/// η = 1), whatever its roughness:
/// a fully transmissive one passes every ray straight through with weight 1 and reflects
/// nothing; with transmission t, the pass-through carries exactly t of the energy.
#[test]
fn index_matched_pbr_body_is_a_pass_through() {
    for (r, thin) in [(0.0f32, false), (0.3, false), (1.0, false), (0.5, true)] {
        for t in [1.0f32, 0.6] {
            let b = Bsdf::Pbr(Pbr {
                transmission: t,
                thin,
                ior: 1.0,
                ..pbr(r)
            });
            let mut rng = Rng::new(7);
            for &wo in &wos(true) {
                let (mut through, n) = (0.0f32, 20_000);
                for _ in 0..n {
                    let Some(s) = b.sample(wo, rng.next_f32(), rng.next_2d()) else {
                        continue;
                    };
                    if s.lobe.is_transmission() {
                        assert_eq!(s.lobe, Lobe::SpecularTransmission, "r {r} t {t}");
                        assert!((s.wi + wo).length() < 1e-6, "not straight through");
                        assert_eq!(s.eta, 1.0);
                        through += (s.f * s.wi.z.abs() / s.pdf).x;
                    } else {
                        assert_eq!(s.lobe, Lobe::Diffuse, "r {r} t {t}: no specular reflection");
                    }
                    // Light sampling never finds the pass-through.
                    assert_eq!(b.eval(wo, -wo), Vec3A::ZERO);
                }
                let through = through / n as f32;
                assert!(
                    (through - t).abs() < 0.02,
                    "r {r} t {t} wo {wo}: pass-through carries {through}"
                );
            }
        }
    }
}
