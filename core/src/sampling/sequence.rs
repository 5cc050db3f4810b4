//! Deterministic random numbers: sample `i` of pixel (x, y) with seed `s` always draws the same
//! numbers, whatever the tile, thread or machine.
//!
//! The first [`sobol_burley::NUM_DIMENSIONS`] dimensions of a path come from an Owen-scrambled
//! Sobol sequence (Burley 2020), seeded per pixel so that neighbouring pixels are decorrelated;
//! later dimensions (very long paths) and sample indices beyond the sequence's range fall back to
//! a counter-based hash, which is just as deterministic.

use glam::Vec2;
use sobol_burley::parts;

/// Largest sample index the Sobol sequence covers; later indices use the hash.
const SOBOL_MAX_INDEX: u32 = 1 << 16;

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
        if d < sobol_burley::NUM_DIMENSIONS && self.index < SOBOL_MAX_INDEX {
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
        let sobol = parts::sobol_int4_rev(self.shuffled_rev_index, set);
        let seed = self.pixel_seed.wrapping_mul(0x9c8f_2d3b) ^ set;
        let scramble: parts::Int4 = [
            seed ^ 0x912f_69ba,
            seed ^ 0x174f_18ab,
            seed ^ 0x691e_72ca,
            seed ^ 0xb40c_c1b8,
        ]
        .into();
        parts::owen_scramble_int4_rev(sobol, parts::hash_int4(scramble))
            .reverse_bits()
            .to_f32_norm()
    }

    /// Skips to the start of the next group of four dimensions, so that the pairs drawn after
    /// it come from one 4D Sobol set (jointly stratified).
    #[inline]
    pub fn align4(&mut self) {
        self.dimension = self.dimension.next_multiple_of(4);
    }

    /// Three numbers in [0, 1) from a hash of (pixel, sample index, current dimension), not from
    /// the Sobol sequence: for choices that gain little from stratification (light selection,
    /// BSDF lobe, Russian roulette). Does not advance the dimension.
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
