//! Counter-based random numbers: a sample's numbers are a pure function of
//! `(seed, measurement, sample index, dimension)`, so any thread may render any sample
//! and the adjoint pass can regenerate a path exactly (DESIGN §5).
//!
//! The first dimensions of each sample come from an Owen-scrambled Sobol' sequence
//! (Burley 2020, "Practical hash-based Owen scrambling"): each 2-D pair is a (0,2)-
//! sequence scrambled by a hash of the key and the pair's index, and the sample index
//! is shuffled per pair, so pairs are stratified and decorrelated. Dimensions past
//! [`SOBOL_PAIRS`] pairs fall back to independent hashed numbers.

/// 2-D pairs per sample drawn from scrambled Sobol' points.
pub const SOBOL_PAIRS: u32 = 16;

/// The scramble seeds of the Sobol' pairs of one stream `(seed, stream)`: they do not
/// depend on the sample index, so a renderer computes them once per measurement and
/// draws every sample's [`Sampler`] from them ([`StreamSeeds::sampler`]), which gives the
/// same numbers as [`Sampler::new`] without two hashes per sample and one per pair.
#[derive(Clone, Debug)]
pub struct StreamSeeds {
    key: u64,
    pairs: [(u32, u32, u32); SOBOL_PAIRS as usize],
}

impl StreamSeeds {
    pub fn new(seed: u64, stream: u64) -> Self {
        let key = stream_key(seed, stream);
        StreamSeeds {
            key,
            pairs: std::array::from_fn(|p| pair_seeds(key, p as u32)),
        }
    }

    /// Sample `index` of this stream: [`Sampler::new`]`(seed, stream, index)`.
    #[inline]
    pub fn sampler(&self, index: u32) -> Sampler<'_> {
        Sampler {
            key: self.key,
            index,
            index_reversed: index.reverse_bits(),
            dim: 0,
            pairs: Some(&self.pairs),
        }
    }
}

impl StreamSeeds {
    /// Sobol' pair `pair` (`< SOBOL_PAIRS`) of `L` consecutive samples `first..first + L`
    /// at once, as `[xs, ys]`: lane `k` holds what the `pair`-th [`Sampler::next_2d`] of
    /// [`StreamSeeds::sampler`]`(first + k)` returns, bit for bit (the same integer hashes,
    /// written as lane loops so that they vectorise).
    #[inline]
    pub fn pair_lanes<const L: usize>(&self, pair: u32, first: u32) -> [[f32; L]; 2] {
        let (seed_index, seed_x, seed_y) = self.pairs[pair as usize];
        let index: [u32; L] = std::array::from_fn(|k| first.wrapping_add(k as u32));
        let i = index.map(|j| laine_karras(j.reverse_bits(), seed_index).reverse_bits());
        let x = i.map(|i| to_unit(laine_karras(i, seed_x).reverse_bits()));
        let y = i.map(|i| to_unit(laine_karras(sobol_dim1_reversed(i), seed_y).reverse_bits()));
        [x, y]
    }
}

/// A stateful view of one sample's stream of numbers in [0, 1).
#[derive(Clone, Debug)]
pub struct Sampler<'a> {
    key: u64,
    index: u32,
    /// `index` bit-reversed, computed once (the scramble works on reversed numbers).
    index_reversed: u32,
    dim: u32,
    /// The stream's pair seeds when computed once ([`StreamSeeds`]); else per pair.
    pairs: Option<&'a [(u32, u32, u32); SOBOL_PAIRS as usize]>,
}

impl Sampler<'static> {
    /// The stream of sample `index` of measurement `stream` under `seed`.
    pub fn new(seed: u64, stream: u64, index: u32) -> Self {
        Sampler {
            key: stream_key(seed, stream),
            index,
            index_reversed: index.reverse_bits(),
            dim: 0,
            pairs: None,
        }
    }

    /// A stream of independent (unstratified) numbers: for statistical tests of the
    /// sampling routines, which need i.i.d. input.
    pub fn independent(seed: u64, stream: u64, index: u32) -> Self {
        let mut s = Self::new(seed, stream, index);
        s.dim = 2 * SOBOL_PAIRS;
        s
    }
}

/// The key of stream `(seed, stream)`.
fn stream_key(seed: u64, stream: u64) -> u64 {
    mix64(seed ^ mix64(stream.wrapping_add(0x9E37_79B9_7F4A_7C15)))
}

/// The scramble seeds of pair `pair` of the stream with `key`: index shuffle, x, y (from
/// one 64-bit hash of the key and the pair).
#[inline]
fn pair_seeds(key: u64, pair: u32) -> (u32, u32, u32) {
    let h = mix64(key ^ (pair as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    let seed_y = (h.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32) as u32;
    (h as u32, (h >> 32) as u32, seed_y)
}

impl Sampler<'_> {
    /// Next pair of stratified numbers in [0, 1)².
    #[inline]
    pub fn next_2d(&mut self) -> [f32; 2] {
        let d = self.dim;
        self.dim += 2;
        self.pair_at(d)
    }

    /// Next single number in [0, 1) (consumes a pair's first coordinate).
    #[inline]
    pub fn next_1d(&mut self) -> f32 {
        let d = self.dim;
        self.dim += 2;
        self.first_at(d)
    }

    /// Sets the next pair aside, to be read (or not) later: the numbers after it are the
    /// same whether or not it is ever read, and reading it costs only when a path needs it
    /// (a finite spot's point, a Russian roulette decision).
    #[inline]
    pub fn reserve_2d(&mut self) -> Reserved {
        let d = self.dim;
        self.dim += 2;
        Reserved(d)
    }

    /// The pair set aside as `r`: what [`Sampler::next_2d`] would have returned then.
    #[inline]
    pub fn get_2d(&self, r: Reserved) -> [f32; 2] {
        self.pair_at(r.0)
    }

    /// The first number of the pair set aside as `r`: what [`Sampler::next_1d`] would
    /// have returned then.
    #[inline]
    pub fn get_1d(&self, r: Reserved) -> f32 {
        self.first_at(r.0)
    }

    /// The scramble seeds of pair `pair < SOBOL_PAIRS`.
    #[inline]
    fn pair_seeds(&self, pair: u32) -> (u32, u32, u32) {
        match self.pairs {
            Some(p) => p[pair as usize],
            None => pair_seeds(self.key, pair),
        }
    }

    /// The Owen-scrambled index (Burley's shuffle) of this sample for pair `pair`: the
    /// Sobol' point it reads. Scrambling works on bit-reversed numbers; Sobol' dimension
    /// 0 is the bit-reversed index, so its coordinate needs no table.
    #[inline]
    fn shuffled(&self, seed_index: u32) -> u32 {
        laine_karras(self.index_reversed, seed_index).reverse_bits()
    }

    /// Dimensions `d, d + 1`.
    #[inline]
    fn pair_at(&self, d: u32) -> [f32; 2] {
        let pair = d / 2;
        if pair < SOBOL_PAIRS {
            let (seed_index, seed_x, seed_y) = self.pair_seeds(pair);
            let i = self.shuffled(seed_index);
            let x = laine_karras(i, seed_x);
            let y = laine_karras(sobol_dim1_reversed(i), seed_y);
            [to_unit(x.reverse_bits()), to_unit(y.reverse_bits())]
        } else {
            [self.hashed(d), self.hashed(d + 1)]
        }
    }

    /// Dimension `d` alone (the first of a pair): [`Sampler::pair_at`]`(d)[0]`.
    #[inline]
    fn first_at(&self, d: u32) -> f32 {
        let pair = d / 2;
        if pair < SOBOL_PAIRS {
            let (seed_index, seed_x, _) = self.pair_seeds(pair);
            to_unit(laine_karras(self.shuffled(seed_index), seed_x).reverse_bits())
        } else {
            self.hashed(d)
        }
    }

    fn hashed(&self, d: u32) -> f32 {
        let h = mix64(self.key ^ mix64(((self.index as u64) << 32) | d as u64));
        to_unit((h >> 32) as u32)
    }
}

/// A pair of a sample's dimensions set aside by [`Sampler::reserve_2d`].
#[derive(Clone, Copy, Debug)]
pub struct Reserved(u32);

/// Maps 32 random bits to [0, 1) with 24 bits of precision (never returns 1).
fn to_unit(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Bit-reversed Sobol' dimension 1 of index `i`: XOR of the reversed direction
/// numbers of `i`'s set bits, four table lookups (one per byte).
#[inline]
fn sobol_dim1_reversed(i: u32) -> u32 {
    let t = &SOBOL1_REV_TABLE;
    t[0][(i & 0xFF) as usize]
        ^ t[1][((i >> 8) & 0xFF) as usize]
        ^ t[2][((i >> 16) & 0xFF) as usize]
        ^ t[3][(i >> 24) as usize]
}

/// Reversed direction numbers of Sobol' dimension 1 (Pascal's triangle mod 2), grouped
/// by byte: `table[k][b]` = XOR of the reversed direction numbers of the set bits of
/// `b << 8k`.
static SOBOL1_REV_TABLE: [[u32; 256]; 4] = {
    let mut v = [0u32; 32];
    let mut dir: u32 = 1 << 31;
    let mut k = 0;
    while k < 32 {
        v[k] = dir.reverse_bits();
        dir ^= dir >> 1;
        k += 1;
    }
    let mut t = [[0u32; 256]; 4];
    let mut byte = 0;
    while byte < 4 {
        let mut b = 0;
        while b < 256 {
            let mut x = 0;
            let mut bit = 0;
            while bit < 8 {
                if b & (1 << bit) != 0 {
                    x ^= v[byte * 8 + bit];
                }
                bit += 1;
            }
            t[byte][b] = x;
            b += 1;
        }
        byte += 1;
    }
    t
};

/// Laine–Karras hash permutation with Burley's constants, on a bit-reversed number:
/// each bit is flipped depending only on the bits below it (the bits above it in the
/// unreversed number), which is a nested uniform (Owen) scramble.
#[inline]
fn laine_karras(mut x: u32, seed: u32) -> u32 {
    x ^= x.wrapping_mul(0x3D20_ADEA);
    x = x.wrapping_add(seed);
    x = x.wrapping_mul((seed >> 16) | 1);
    x ^= x.wrapping_mul(0x0552_6C56);
    x ^= x.wrapping_mul(0x53A2_2864);
    x
}

/// A 64-bit finaliser with full avalanche (splitmix64's).
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_key_same_numbers() {
        let a: Vec<[f32; 2]> = (0..40).map(|_| Sampler::new(7, 3, 11).next_2d()).collect();
        assert!(a.windows(2).all(|w| w[0] == w[1]));
        let mut s = Sampler::new(7, 3, 11);
        let mut t = Sampler::new(7, 4, 11);
        assert_ne!(s.next_2d(), t.next_2d());
    }

    #[test]
    fn stream_seeds_give_the_numbers_of_new() {
        let seeds = StreamSeeds::new(7, 3);
        for index in [0u32, 1, 11, 4095, u32::MAX] {
            let (mut a, mut b) = (Sampler::new(7, 3, index), seeds.sampler(index));
            for _ in 0..(SOBOL_PAIRS + 4) {
                assert_eq!(a.next_2d(), b.next_2d());
            }
        }
    }

    #[test]
    fn lanes_give_the_numbers_of_the_samplers() {
        let seeds = StreamSeeds::new(7, 3);
        for first in [0u32, 8, 1000, u32::MAX - 7] {
            for pair in 0..SOBOL_PAIRS {
                let [x, y] = seeds.pair_lanes::<8>(pair, first);
                for k in 0..8 {
                    let mut s = seeds.sampler(first + k as u32);
                    for _ in 0..pair {
                        s.next_2d();
                    }
                    assert_eq!(s.next_2d(), [x[k], y[k]], "first {first} pair {pair}");
                }
            }
        }
    }

    #[test]
    fn reserved_pairs_read_as_the_pairs_drawn_in_their_place() {
        for index in [0u32, 5, 1000] {
            let mut a = Sampler::new(9, 2, index);
            let mut b = Sampler::new(9, 2, index);
            for _ in 0..(SOBOL_PAIRS + 3) {
                let (pair, first) = (a.next_2d(), b.clone().next_1d());
                let r = b.reserve_2d();
                assert_eq!(pair, b.get_2d(r));
                assert_eq!(first, b.get_1d(r));
                assert_eq!(pair[0], first);
            }
            assert_eq!(a.next_2d(), b.next_2d());
        }
    }

    #[test]
    fn sobol_dim1_table_matches_the_generator() {
        // Sobol' dimension 1 by its definition: direction numbers v_k with
        // v_0 = 1 << 31, v_{k+1} = v_k ^ (v_k >> 1).
        for i in [0u32, 1, 2, 3, 7, 100, 12345, 0xDEAD_BEEF, u32::MAX] {
            let (mut x, mut v, mut j) = (0u32, 1u32 << 31, i);
            while j != 0 {
                if j & 1 != 0 {
                    x ^= v;
                }
                j >>= 1;
                v ^= v >> 1;
            }
            assert_eq!(sobol_dim1_reversed(i), x.reverse_bits(), "i = {i}");
        }
    }

    #[test]
    fn pairs_are_stratified() {
        // 256 samples of one stream: every one of the 16x16 strata holds exactly one
        // point (a (0,8,2)-net), for the Sobol' pairs.
        for pair in 0..3 {
            let mut seen = vec![0u32; 256];
            for i in 0..256 {
                let mut s = Sampler::new(1, 42, i);
                for _ in 0..pair {
                    s.next_2d();
                }
                let [x, y] = s.next_2d();
                assert!((0.0..1.0).contains(&x) && (0.0..1.0).contains(&y));
                seen[(y * 16.0) as usize * 16 + (x * 16.0) as usize] += 1;
            }
            assert!(seen.iter().all(|&c| c == 1), "pair {pair}: {seen:?}");
        }
    }

    #[test]
    fn mean_and_variance_uniform() {
        let n = 20000;
        let mut sum = [0.0f64; 4];
        for i in 0..n {
            let mut s = Sampler::new(5, 9, i);
            for k in 0..(SOBOL_PAIRS + 2) {
                let [x, _] = s.next_2d();
                if k == 0 || k == SOBOL_PAIRS + 1 {
                    let j = if k == 0 { 0 } else { 2 };
                    sum[j] += x as f64;
                    sum[j + 1] += (x as f64) * (x as f64);
                }
            }
        }
        for j in [0, 2] {
            let m = sum[j] / n as f64;
            let v = sum[j + 1] / n as f64 - m * m;
            assert!((m - 0.5).abs() < 0.01, "mean {m}");
            assert!((v - 1.0 / 12.0).abs() < 0.005, "var {v}");
        }
    }
}
