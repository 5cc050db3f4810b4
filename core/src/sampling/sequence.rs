//! Deterministic random numbers: sample `i` of pixel (x, y) with seed `s` always draws the same
//! numbers, whatever the tile, thread or machine.
//!
//! The first [`sobol_burley::NUM_DIMENSIONS`] dimensions of a path come from an Owen-scrambled
//! Sobol sequence (Burley 2020), seeded per pixel so that neighbouring pixels are decorrelated;
//! later dimensions (very long paths) and sample indices from [`SOBOL_SAMPLES`] on (the
//! sequence's length) fall back to a counter-based hash, which is just as deterministic.

use glam::Vec2;
use sobol_burley::parts;

/// Samples per pixel drawn from the Sobol sequence: indices `0..SOBOL_SAMPLES` get Sobol points,
/// later ones hashed numbers. 2^16 is the length of `sobol_burley`'s sequence and what the
/// nibble tables below cover (four nibbles of the index). The switch is deliberate: the render
/// stays deterministic and unbiased past it (up to `settings::MAX_SPP` = 2^20 samples), only the
/// extra samples are not stratified and converge at the plain Monte Carlo rate.
pub const SOBOL_SAMPLES: u32 = 1 << 16;
const _: () = assert!(
    SOBOL_SAMPLES == 1 << (4 * 4),
    "the nibble tables cover 16 index bits"
);

/// A fast, well-mixed 32-bit hash (the "lowbias32" finaliser by Chris Wellons).
#[inline]
pub fn hash_u32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

/// Hashes several words into one.
#[inline]
fn hash_words(words: &[u32]) -> u32 {
    let mut h = 0x9e37_79b9u32;
    for &w in words {
        h = hash_u32(
            h ^ w
                .wrapping_add(0x6a09_e667)
                .wrapping_add(h << 6)
                .wrapping_add(h >> 2),
        );
    }
    h
}

/// Maps 32 random bits to a float in [0, 1).
#[inline]
fn to_unit(bits: u32) -> f32 {
    (bits >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// The random numbers of one camera sample: pixel, sample index and seed fix every value.
///
/// Dimensions are drawn four at a time (`sobol_burley::sample_4d` computes a 4D set with SIMD
/// for about the price of one dimension) and handed out one by one.
#[derive(Clone, Debug)]
pub struct Sampler {
    pixel_seed: u32,
    index: u32,
    /// The sample index after the per-pixel Owen shuffle (bit-reversed), as
    /// `sobol_burley::sample_4d` computes it on every call: computed once per sample here.
    shuffled_rev_index: u32,
    dimension: u32,
    set: [f32; 4],
}

impl Sampler {
    /// The sampler for sample `index` of pixel (`x`, `y`) under `seed`.
    #[inline]
    pub fn new(x: u32, y: u32, index: u32, seed: u32) -> Self {
        let pixel_seed = hash_words(&[x, y, seed]);
        Self {
            pixel_seed,
            index,
            shuffled_rev_index: parts::owen_scramble_rev(
                index.reverse_bits(),
                parts::hash(pixel_seed ^ 0x79c6_8e4a),
            ),
            dimension: 0,
            set: [0.0; 4],
        }
    }

    /// The next number in [0, 1).
    #[inline]
    pub fn next_1d(&mut self) -> f32 {
        let d = self.dimension;
        self.dimension += 1;
        if d < sobol_burley::NUM_DIMENSIONS && self.index < SOBOL_SAMPLES {
            if d.is_multiple_of(4) {
                self.set = self.sobol_4d(d / 4);
            }
            self.set[(d % 4) as usize]
        } else {
            to_unit(hash_words(&[self.pixel_seed, self.index, d]))
        }
    }

    /// `sobol_burley::sample_4d(index, set, pixel_seed)`, to the bit (a test checks), with the
    /// index shuffle hoisted out.
    #[inline]
    fn sobol_4d(&self, set: u32) -> [f32; 4] {
        let sobol = sobol_int4_rev(self.shuffled_rev_index, set);
        let seed = self.pixel_seed.wrapping_mul(0x9c8f_2d3b) ^ set;
        let scramble = [
            seed ^ 0x912f_69ba,
            seed ^ 0x174f_18ab,
            seed ^ 0x691e_72ca,
            seed ^ 0xb40c_c1b8,
        ];
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("sse4.1") {
            // SAFETY: the CPU has SSE4.1 (checked just above).
            return unsafe { sse41::scramble_to_unit(sobol.into(), scramble) };
        }
        scramble_to_unit(sobol, scramble)
    }

    /// Skips to the start of the next group of four dimensions, so that the pairs drawn after
    /// it come from one 4D Sobol set (jointly stratified).
    #[inline]
    pub fn align4(&mut self) {
        self.dimension = self.dimension.next_multiple_of(4);
    }

    /// Three numbers in [0, 1) from a hash of (pixel, sample index, current dimension), not from
    /// the Sobol sequence: for choices that gain little from stratification (BSDF lobe, Russian
    /// roulette, the refinement of a Sobol number below its grid). Does not advance the
    /// dimension.
    #[inline]
    pub fn hashed_3(&self) -> [f32; 3] {
        let h1 = hash_words(&[self.pixel_seed, self.index, self.dimension | 0x8000_0000]);
        let h2 = hash_u32(h1 ^ 0x6a09_e667);
        let h3 = hash_u32(h2 ^ 0xbb67_ae85);
        [to_unit(h1), to_unit(h2), to_unit(h3)]
    }

    /// The next two numbers in [0, 1)².
    #[inline]
    pub fn next_2d(&mut self) -> Vec2 {
        let x = self.next_1d();
        let y = self.next_1d();
        Vec2::new(x, y)
    }
}

/// Nibble tables of the Sobol direction vectors: entry `[set][k][v]` is the (bit-reversed)
/// Sobol point of set `set` for an index whose only set bits are nibble value `v` at nibble `k`
/// of the 16 index bits used (k = 0 most significant). Sobol points are linear (XOR) in the
/// index bits, so four lookups give any point. 64 KiB, built once from `sobol_burley` itself.
type NibbleTables = [[[[u32; 4]; 16]; 4]; sobol_burley::NUM_DIMENSION_SETS_4D as usize];

static SOBOL_NIBBLES: std::sync::LazyLock<Box<NibbleTables>> = std::sync::LazyLock::new(|| {
    let sets = sobol_burley::NUM_DIMENSION_SETS_4D as usize;
    let mut t: Box<NibbleTables> = vec![[[[0u32; 4]; 16]; 4]; sets]
        .into_boxed_slice()
        .try_into()
        .expect("one table per dimension set");
    for (set, tables) in t.iter_mut().enumerate() {
        for (k, table) in tables.iter_mut().enumerate() {
            for (v, entry) in table.iter_mut().enumerate() {
                let index_rev = (v as u32) << (28 - 4 * k);
                *entry = parts::sobol_int4_rev(index_rev, set as u32).into();
            }
        }
    }
    t
});

/// `parts::sobol_int4_rev` (the same bits, a test checks) by four table lookups instead of a
/// loop over the index's set bits, whose count is random after the Owen shuffle: the loop
/// mispredicted its exit on most calls.
#[inline]
fn sobol_int4_rev(index_rev: u32, set: u32) -> parts::Int4 {
    let t = &SOBOL_NIBBLES[set as usize];
    let n = |k: usize| parts::Int4::from(t[k][((index_rev >> (28 - 4 * k)) & 15) as usize]);
    n(0) ^ n(1) ^ n(2) ^ n(3)
}

/// The end of `sobol_burley::sample_4d`: Owen-scramble the (bit-reversed) Sobol points with
/// hashed per-dimension seeds, un-reverse, map to [0, 1).
#[inline]
fn scramble_to_unit(sobol: parts::Int4, scramble: [u32; 4]) -> [f32; 4] {
    parts::owen_scramble_int4_rev(sobol, parts::hash_int4(scramble.into()))
        .reverse_bits()
        .to_f32_norm()
}

/// [`scramble_to_unit`] with SSE4.1's 32-bit multiply, chosen at run time: `sobol_burley` picks
/// its multiply when it is compiled, and for the baseline x86-64 target that is a five-instruction
/// SSE2 emulation. Integer arithmetic: the same bits on every CPU (a test checks).
#[cfg(target_arch = "x86_64")]
mod sse41 {
    use std::arch::x86_64::*;

    #[inline(always)]
    unsafe fn splat(x: u32) -> __m128i {
        _mm_set1_epi32(x as i32)
    }

    /// Swaps the bit groups selected by `mask` with those `shift` places above them.
    #[inline(always)]
    unsafe fn swap_bits<const SHIFT: i32>(n: __m128i, mask: u32) -> __m128i {
        let m = splat(mask);
        _mm_or_si128(
            _mm_and_si128(_mm_srli_epi32::<SHIFT>(n), m),
            _mm_slli_epi32::<SHIFT>(_mm_and_si128(n, m)),
        )
    }

    #[target_feature(enable = "sse4.1")]
    pub(super) unsafe fn scramble_to_unit(sobol: [u32; 4], scramble: [u32; 4]) -> [f32; 4] {
        // hash_int4
        let mut h = _mm_xor_si128(
            _mm_loadu_si128(scramble.as_ptr().cast()),
            splat(0xe6fe_3beb),
        );
        h = _mm_xor_si128(h, _mm_srli_epi32::<16>(h));
        h = _mm_mullo_epi32(h, splat(0x7feb_352d));
        h = _mm_xor_si128(h, _mm_srli_epi32::<15>(h));
        h = _mm_mullo_epi32(h, splat(0x846c_a68b));
        h = _mm_xor_si128(h, _mm_srli_epi32::<16>(h));
        // owen_scramble_int4_rev
        let mut n = _mm_loadu_si128(sobol.as_ptr().cast());
        n = _mm_xor_si128(n, _mm_mullo_epi32(n, splat(0x3d20_adea)));
        n = _mm_add_epi32(n, h);
        n = _mm_mullo_epi32(n, _mm_or_si128(_mm_srli_epi32::<16>(h), splat(1)));
        n = _mm_xor_si128(n, _mm_mullo_epi32(n, splat(0x0552_6c56)));
        n = _mm_xor_si128(n, _mm_mullo_epi32(n, splat(0x53a2_2864)));
        // reverse_bits
        n = swap_bits::<1>(n, 0x5555_5555);
        n = swap_bits::<2>(n, 0x3333_3333);
        n = swap_bits::<4>(n, 0x0f0f_0f0f);
        n = swap_bits::<8>(n, 0x00ff_00ff);
        n = _mm_or_si128(_mm_srli_epi32::<16>(n), _mm_slli_epi32::<16>(n));
        // to_f32_norm
        let f = _mm_or_si128(_mm_srli_epi32::<9>(n), splat(0x3f80_0000));
        let f = _mm_sub_ps(_mm_castsi128_ps(f), _mm_set1_ps(1.0));
        let mut out = [0.0f32; 4];
        _mm_storeu_ps(out.as_mut_ptr(), f);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_inputs_same_numbers() {
        let draw = |x, y, i, s| {
            let mut smp = Sampler::new(x, y, i, s);
            (0..300).map(|_| smp.next_1d()).collect::<Vec<_>>()
        };
        assert_eq!(draw(3, 4, 5, 6), draw(3, 4, 5, 6));
        assert_ne!(draw(3, 4, 5, 6), draw(4, 3, 5, 6));
        assert_ne!(draw(3, 4, 5, 6), draw(3, 4, 5, 7));
        assert!(draw(1, 2, 70_000, 0)
            .iter()
            .all(|&u| (0.0..1.0).contains(&u)));
    }

    #[test]
    fn hashed_numbers_are_deterministic_uniform_and_leave_the_dimension() {
        let mut s = Sampler::new(5, 7, 3, 11);
        s.next_2d();
        let a = s.hashed_3();
        assert_eq!(a, s.hashed_3(), "same inputs, same numbers");
        let next = s.next_1d();
        let mut t = Sampler::new(5, 7, 3, 11);
        t.next_2d();
        assert_eq!(t.next_1d(), next, "hashed_3 must not advance the dimension");
        let (mut sum, n) = ([0.0f64; 3], 20_000u32);
        for i in 0..n {
            let h = Sampler::new(i % 97, i / 97, i, 1).hashed_3();
            for k in 0..3 {
                assert!((0.0..1.0).contains(&h[k]));
                sum[k] += h[k] as f64;
            }
        }
        for m in sum {
            assert!((m / n as f64 - 0.5).abs() < 0.01, "mean {}", m / n as f64);
        }
    }

    #[test]
    fn hoisted_shuffle_equals_sobol_burley() {
        for (x, y, index, seed) in [(0, 0, 0, 0), (3, 9, 17, 1), (255, 1, 65_535, 42)] {
            let s = Sampler::new(x, y, index, seed);
            for set in 0..sobol_burley::NUM_DIMENSION_SETS_4D {
                let want = sobol_burley::sample_4d(index, set, s.pixel_seed);
                assert_eq!(s.sobol_4d(set).map(f32::to_bits), want.map(f32::to_bits));
            }
        }
    }

    #[test]
    fn table_sobol_equals_sobol_burley() {
        for i in 0..20_000u32 {
            let index_rev = hash_u32(i);
            for set in 0..sobol_burley::NUM_DIMENSION_SETS_4D {
                let want: [u32; 4] = parts::sobol_int4_rev(index_rev, set).into();
                let got: [u32; 4] = sobol_int4_rev(index_rev, set).into();
                assert_eq!(got, want, "index_rev {index_rev:#x}, set {set}");
            }
        }
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn sse41_scramble_equals_the_portable_one() {
        if !std::arch::is_x86_feature_detected!("sse4.1") {
            eprintln!("skipped: this CPU has no SSE4.1");
            return;
        }
        for i in 0..100_000u32 {
            let w = |k: u32| hash_u32(i.wrapping_mul(8).wrapping_add(k));
            let sobol = [w(0), w(1), w(2), w(3)];
            let scramble = [w(4), w(5), w(6), w(7)];
            // SAFETY: SSE4.1 checked above.
            let fast = unsafe { sse41::scramble_to_unit(sobol, scramble) };
            let portable = scramble_to_unit(sobol.into(), scramble);
            assert_eq!(fast.map(f32::to_bits), portable.map(f32::to_bits));
        }
    }

    #[test]
    fn four_at_a_time_equals_one_at_a_time() {
        let mut s = Sampler::new(5, 6, 77, 3);
        for d in 0..40 {
            assert_eq!(
                s.next_1d(),
                sobol_burley::sample(77, d, hash_words(&[5, 6, 3]))
            );
        }
    }

    #[test]
    fn sobol_up_to_its_length_then_hashed_numbers() {
        let (x, y, seed) = (5, 6, 3);
        let pixel_seed = hash_words(&[x, y, seed]);
        let last = SOBOL_SAMPLES - 1;
        let mut s = Sampler::new(x, y, last, seed);
        for d in 0..8 {
            assert_eq!(s.next_1d(), sobol_burley::sample(last, d, pixel_seed));
        }
        // From SOBOL_SAMPLES on: the counter-based hash of (pixel, index, dimension), as the
        // module says, in every dimension.
        for index in [
            SOBOL_SAMPLES,
            SOBOL_SAMPLES + 1,
            crate::settings::MAX_SPP - 1,
        ] {
            let mut s = Sampler::new(x, y, index, seed);
            for d in 0..8 {
                assert_eq!(
                    s.next_1d(),
                    to_unit(hash_words(&[pixel_seed, index, d])),
                    "index {index}, dimension {d}"
                );
            }
        }
        // The hashed samples are still uniform in [0, 1).
        let n = 20_000;
        let mean = (0..n)
            .map(|i| Sampler::new(x, y, SOBOL_SAMPLES + i, seed).next_1d() as f64)
            .sum::<f64>()
            / n as f64;
        assert!((mean - 0.5).abs() < 0.01, "{mean}");
    }

    #[test]
    fn sequence_is_roughly_uniform() {
        // Mean of the first dimension over 4096 samples of one pixel: Sobol is far better than
        // 1/sqrt(n), so a tight bound holds.
        let mean: f32 = (0..4096)
            .map(|i| Sampler::new(7, 9, i, 1).next_1d())
            .sum::<f32>()
            / 4096.0;
        assert!((mean - 0.5).abs() < 0.002, "{mean}");
    }
}
