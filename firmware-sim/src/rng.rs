//! A small deterministic random number generator (xoshiro256++ from `rand_xoshiro`, seeded
//! by SplitMix64), so a scene renders the same bytes on every machine and in any row order.

use std::sync::OnceLock;

use rand_xoshiro::rand_core::{Rng as _, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// xoshiro256++ and the distributions the simulator draws from it.
#[derive(Clone, Debug)]
pub struct Rng(Xoshiro256PlusPlus);

/// SplitMix64's step: advances `x` and returns its output.
fn splitmix(x: &mut u64) -> u64 {
    *x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *x;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The end of [`Rng::from_words`]'s hash chain over `words`: the SplitMix64 seed.
fn chain(words: &[u64]) -> u64 {
    let mut x = 0x5EED_F11E_u64;
    for &w in words {
        let mut counter = x ^ w;
        x = splitmix(&mut counter);
    }
    x
}

impl Rng {
    /// A generator seeded from a list of words (scene seed, angle, band, row, stream...):
    /// each word is folded into a hash chain (`x = mix(x ^ word)`, SplitMix64's output), so
    /// distinct lists give unrelated streams, and the state is SplitMix64's next four outputs
    /// from the chain's end. (Folding the words into SplitMix's counter alone,
    /// `x = (x ^ word) + golden`, is nearly linear: most rows of a sweep would repeat
    /// another's noise.)
    pub fn from_words(words: &[u64]) -> Self {
        Self(Xoshiro256PlusPlus::seed_from_u64(chain(words)))
    }

    /// The next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform in `[0, 1)`.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }

    /// Standard normal by the ziggurat method (Doornik's ZIGNOR, 128 layers, layer and
    /// abscissa from disjoint bits of one 64-bit draw): the same distribution as
    /// [`Rng::normal`], a different sequence, and for 99 % of the values one draw, a
    /// comparison and a multiplication instead of a logarithm, a square root and a cosine.
    /// The software camera's noise.
    #[inline]
    pub fn fast_normal(&mut self) -> f64 {
        let z = zignor();
        let bits = self.next_u64();
        let i = (bits & 0x7F) as usize;
        let u = 2.0 * ((bits >> 11) as f64 * (1.0 / (1u64 << 53) as f64)) - 1.0;
        if u.abs() < z.ratio[i] {
            return u * z.x[i];
        }
        self.normal_outside(z, i, u)
    }

    /// The ziggurat's draw `u` of layer `i` fell outside the layer's inner rectangle: the
    /// tail or the wedge test, then new draws until one is accepted.
    #[cold]
    #[inline(never)]
    fn normal_outside(&mut self, z: &Zignor, mut i: usize, mut u: f64) -> f64 {
        loop {
            if u.abs() < z.ratio[i] {
                return u * z.x[i];
            }
            if i == 0 {
                return normal_tail(self, ZIG_R, u < 0.0);
            }
            let x = u * z.x[i];
            let f0 = (-0.5 * (z.x[i] * z.x[i] - x * x)).exp();
            let f1 = (-0.5 * (z.x[i + 1] * z.x[i + 1] - x * x)).exp();
            if f1 + self.uniform() * (f0 - f1) < 1.0 {
                return x;
            }
            let bits = self.next_u64();
            i = (bits & 0x7F) as usize;
            u = 2.0 * ((bits >> 11) as f64 * (1.0 / (1u64 << 53) as f64)) - 1.0;
        }
    }

    /// Poisson-distributed count of mean `mean`, the distribution of [`Rng::poisson`]
    /// (exact up to a mean of 64, normal beyond) drawn faster. Up to 64 a Poisson count of
    /// mean `m` is one of mean `floor(m)` plus an independent one of mean `m - floor(m)`:
    /// the first from a Walker alias table of its whole mean (two draws, one comparison;
    /// counts whose probability is under 1e-20 left out), the second by Knuth's product of
    /// uniforms (one or two draws). Beyond 64, [`Rng::fast_normal`], inlined into the
    /// caller; up to 64, a call.
    #[inline(always)]
    pub fn fast_poisson(&mut self, mean: f64) -> f64 {
        if mean > 64.0 {
            return round_non_negative(mean + mean.sqrt() * self.fast_normal());
        }
        self.small_poisson(mean)
    }

    /// [`Rng::fast_poisson`] up to a mean of 64.
    #[inline(never)]
    fn small_poisson(&mut self, mean: f64) -> f64 {
        // Zero, negative or NaN.
        if mean.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return 0.0;
        }
        let whole = mean as usize;
        let table = &poisson_tables()[whole];
        let slot = ((u128::from(self.next_u64()) * table.len() as u128) >> 64) as usize;
        let (p, alias) = table[slot];
        let mut k = if self.uniform() < p { slot } else { alias } as f64;
        let limit = (f64::from(whole as u32) - mean).exp();
        let mut product = self.uniform();
        while product > limit {
            k += 1.0;
            product *= self.uniform();
        }
        k
    }

    /// Poisson-distributed count of mean `mean` (exact for small means, normal beyond 64).
    pub fn poisson(&mut self, mean: f64) -> f64 {
        if mean <= 0.0 {
            return 0.0;
        }
        if mean > 64.0 {
            return (mean + mean.sqrt() * self.normal()).max(0.0).round();
        }
        let l = (-mean).exp();
        let mut k = 0.0;
        let mut p = 1.0;
        loop {
            p *= self.uniform();
            if p <= l {
                return k;
            }
            k += 1.0;
        }
    }
}

/// `x.round()` for `x >= -0.5` (the nearest integer, halves away from zero) without a
/// library call: truncation of `x + 0.5`.
#[inline]
pub fn round_non_negative(x: f64) -> f64 {
    (x + 0.5).max(0.0) as i64 as f64
}

/// `ln(k!)` of a whole `k >= 0`: a table up to 1023, Stirling's series (error under 1e-15
/// relative) beyond.
fn ln_factorial(k: f64) -> f64 {
    const TABLED: usize = 1024;
    static TABLE: OnceLock<Vec<f64>> = OnceLock::new();
    let table = TABLE.get_or_init(|| {
        let mut t = vec![0.0; TABLED];
        for i in 1..TABLED {
            t[i] = t[i - 1] + (i as f64).ln();
        }
        t
    });
    if k < TABLED as f64 {
        return table[k as usize];
    }
    let n = k + 1.0;
    (n - 0.5) * n.ln() - n + 0.5 * (2.0 * std::f64::consts::PI).ln() + 1.0 / (12.0 * n)
        - 1.0 / (360.0 * n * n * n)
}

/// Walker alias tables of the Poisson distributions of whole means 0 to 64: per count `k`,
/// `(probability of keeping k, the count drawn otherwise)`.
fn poisson_tables() -> &'static [Vec<(f64, usize)>] {
    static TABLES: OnceLock<Vec<Vec<(f64, usize)>>> = OnceLock::new();
    TABLES.get_or_init(|| (0..=64).map(|m| alias_table(m as f64)).collect())
}

/// Vose's alias table of the Poisson distribution of mean `mean`, over the counts whose
/// probability is at least 1e-20 (the rest, under 1e-18 in all, left out and the others
/// renormalised).
fn alias_table(mean: f64) -> Vec<(f64, usize)> {
    let pmf = |k: usize| (-mean + k as f64 * mean.ln() - ln_factorial(k as f64)).exp();
    let mut probs: Vec<f64> = if mean == 0.0 {
        vec![1.0]
    } else {
        let top = (0..)
            .find(|&k| k as f64 > mean && pmf(k) < 1e-20)
            .unwrap_or(1);
        (0..top).map(pmf).collect()
    };
    let n = probs.len();
    let total: f64 = probs.iter().sum();
    for p in &mut probs {
        *p *= n as f64 / total;
    }
    let mut table = vec![(1.0, 0); n];
    let (mut small, mut large): (Vec<usize>, Vec<usize>) = (0..n).partition(|&k| probs[k] < 1.0);
    while let (Some(s), Some(&l)) = (small.pop(), large.last()) {
        table[s] = (probs[s], l);
        probs[l] -= 1.0 - probs[s];
        if probs[l] < 1.0 {
            large.pop();
            small.push(l);
        }
    }
    for k in small.into_iter().chain(large) {
        table[k] = (1.0, k);
    }
    table
}

/// Layers of the ziggurat.
const ZIG_LAYERS: usize = 128;
/// Where the base layer's tail starts.
const ZIG_R: f64 = 3.442_619_855_899;
/// Area of each layer.
const ZIG_V: f64 = 9.912_563_035_262_17e-3;

/// The ziggurat's layer edges `x[i]` (`x[0]` the base's pseudo-width, `x[128] = 0`) and
/// `ratio[i] = x[i + 1] / x[i]`, below which a draw is accepted at once.
struct Zignor {
    x: [f64; ZIG_LAYERS + 1],
    ratio: [f64; ZIG_LAYERS],
}

fn zignor() -> &'static Zignor {
    static TABLES: OnceLock<Zignor> = OnceLock::new();
    TABLES.get_or_init(|| {
        let mut x = [0.0; ZIG_LAYERS + 1];
        let mut f = (-0.5 * ZIG_R * ZIG_R).exp();
        x[0] = ZIG_V / f;
        x[1] = ZIG_R;
        for i in 2..ZIG_LAYERS {
            x[i] = (-2.0 * (ZIG_V / x[i - 1] + f).ln()).sqrt();
            f = (-0.5 * x[i] * x[i]).exp();
        }
        let mut ratio = [0.0; ZIG_LAYERS];
        for i in 0..ZIG_LAYERS {
            ratio[i] = x[i + 1] / x[i];
        }
        Zignor { x, ratio }
    })
}

/// A normal draw beyond `min` (Marsaglia's tail method), negative if `negative`.
fn normal_tail(rng: &mut Rng, min: f64, negative: bool) -> f64 {
    loop {
        let x = (1.0 - rng.uniform()).ln() / min;
        let y = (1.0 - rng.uniform()).ln();
        if -2.0 * y >= x * x {
            return if negative { x - min } else { min - x };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// xoshiro256++ written out (Blackman and Vigna's reference), its state SplitMix64's
    /// first four outputs from `seed`.
    fn reference(seed: u64) -> impl FnMut() -> u64 {
        let mut x = seed;
        let mut s = [0u64; 4];
        for w in &mut s {
            *w = splitmix(&mut x);
        }
        move || {
            let r = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
            let t = s[1] << 17;
            s[2] ^= s[0];
            s[3] ^= s[1];
            s[1] ^= s[2];
            s[0] ^= s[3];
            s[2] ^= t;
            s[3] = s[3].rotate_left(45);
            r
        }
    }

    /// `rand_xoshiro` seeded from the words' chain gives the reference stream, draw for draw:
    /// every simulated capture keeps its bytes.
    #[test]
    fn the_stream_is_xoshiro256_plus_plus_seeded_by_splitmix() {
        for words in [
            &[][..],
            &[0],
            &[1],
            &[7, 1, 0, 0, 0],
            &[42, 3, 4, 150, 63],
            &[u64::MAX],
        ] {
            let mut rng = Rng::from_words(words);
            let mut want = reference(chain(words));
            for k in 0..1000 {
                assert_eq!(rng.next_u64(), want(), "{words:?}: draw {k}");
            }
        }
    }

    /// Every (stream, angle, band, row) of a sweep gets its own noise: no two of 4 x 5 x 201 x
    /// 64 word lists start the same sequence or share a state word.
    #[test]
    fn distinct_words_give_distinct_streams() {
        let mut seen = std::collections::HashSet::new();
        let mut lists = 0;
        for stream in 1..=4u64 {
            for angle in 0..5u64 {
                for band in 0..201u64 {
                    for row in 0..64u64 {
                        // The state words: SplitMix64's first four from the chain's end.
                        let mut x = chain(&[7, stream, angle, band, row]);
                        for _ in 0..4 {
                            let word = splitmix(&mut x);
                            assert!(seen.insert(word), "{stream} {angle} {band} {row}");
                        }
                        lists += 1;
                    }
                }
            }
        }
        assert_eq!(seen.len(), 4 * lists);
    }

    /// Neighbouring rows' noise is uncorrelated (|r| under 4 / sqrt(n) for every pair of
    /// the first rows of one band).
    #[test]
    fn neighbouring_rows_are_uncorrelated() {
        let n = 4096;
        let draws = |row: u64| -> Vec<f64> {
            let mut rng = Rng::from_words(&[101, 1, 0, 0, row]);
            (0..n).map(|_| rng.normal()).collect()
        };
        let rows: Vec<Vec<f64>> = (0..8).map(draws).collect();
        for a in 0..rows.len() {
            for b in a + 1..rows.len() {
                let r: f64 = rows[a]
                    .iter()
                    .zip(&rows[b])
                    .map(|(x, y)| x * y)
                    .sum::<f64>()
                    / n as f64;
                assert!(r.abs() < 4.0 / (n as f64).sqrt(), "rows {a} {b}: {r}");
            }
        }
    }

    /// The ziggurat's draws are standard normal: moments, tail fractions and the largest
    /// gap between their empirical CDF and the normal's (Kolmogorov-Smirnov) on 10^6 draws.
    #[test]
    fn fast_normal_is_standard_normal() {
        let n = 1_000_000;
        let mut rng = Rng::from_words(&[3, 1, 4]);
        let mut v: Vec<f64> = (0..n).map(|_| rng.fast_normal()).collect();
        let nf = n as f64;
        let mean = v.iter().sum::<f64>() / nf;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / nf;
        let kurt = v.iter().map(|x| (x - mean).powi(4)).sum::<f64>() / nf / (var * var);
        assert!(mean.abs() < 5.0 / nf.sqrt(), "mean {mean}");
        assert!(
            (var - 1.0).abs() < 5.0 * (2.0 / nf).sqrt(),
            "variance {var}"
        );
        assert!((kurt - 3.0).abs() < 0.03, "kurtosis {kurt}");
        // Beyond the ziggurat's base (3.44) and within it.
        for (z, p) in [(1.0, 0.317_310_5), (2.0, 0.045_500_26), (3.442_62, 5.76e-4)] {
            let frac = v.iter().filter(|x| x.abs() > z).count() as f64 / nf;
            let sigma = (p * (1.0 - p) / nf).sqrt();
            assert!(
                (frac - p).abs() < 5.0 * sigma,
                "P(|z| > {z}) = {frac}, expected {p}"
            );
        }
        v.sort_by(f64::total_cmp);
        let cdf = |x: f64| 0.5 * libm::erfc(-x / std::f64::consts::SQRT_2);
        let ks = v
            .iter()
            .enumerate()
            .map(|(i, &x)| {
                let f = cdf(x);
                (f - i as f64 / nf)
                    .abs()
                    .max((f - (i + 1) as f64 / nf).abs())
            })
            .fold(0.0, f64::max);
        // The 0.1 % critical value is 1.95 / sqrt(n).
        assert!(ks < 1.95 / nf.sqrt(), "KS distance {ks}");
    }

    /// Each regime of the fast Poisson draw (Knuth, PTRS, normal) follows the Poisson
    /// probabilities: mean, variance, and every count's frequency within 5 sigma of its
    /// probability, on 200 000 draws per mean.
    #[test]
    fn fast_poisson_is_poisson() {
        let n = 200_000;
        for mean in [0.7f64, 6.5, 10.0, 23.4, 63.9] {
            let mut rng = Rng::from_words(&[9, mean.to_bits()]);
            let draws: Vec<f64> = (0..n).map(|_| rng.fast_poisson(mean)).collect();
            let nf = n as f64;
            let m = draws.iter().sum::<f64>() / nf;
            let var = draws.iter().map(|x| (x - m).powi(2)).sum::<f64>() / nf;
            assert!(
                (m - mean).abs() < 5.0 * (mean / nf).sqrt(),
                "{mean}: mean {m}"
            );
            assert!((var / mean - 1.0).abs() < 0.02, "{mean}: variance {var}");
            let mut counts = vec![0usize; 200];
            for &d in &draws {
                assert!(d >= 0.0 && d.fract() == 0.0, "{mean}: {d}");
                counts[(d as usize).min(199)] += 1;
            }
            for (k, &c) in counts.iter().enumerate().take(150) {
                let p = (-mean + k as f64 * f64::ln(mean) - ln_factorial(k as f64)).exp();
                let sigma = (p * (1.0 - p) / nf).sqrt().max(1.0 / nf);
                let f = c as f64 / nf;
                assert!(
                    (f - p).abs() < 5.0 * sigma + 1e-6,
                    "{mean}: P({k}) {f} vs {p}"
                );
            }
        }
        // Beyond 64 the normal approximation, as `poisson`.
        let mut rng = Rng::from_words(&[10]);
        let m = (0..n).map(|_| rng.fast_poisson(400.0)).sum::<f64>() / n as f64;
        assert!((m - 400.0).abs() < 5.0 * (400.0 / n as f64).sqrt(), "{m}");
    }

    #[test]
    fn ln_factorial_matches_the_product() {
        let mut exact = 0.0;
        for k in 1..3000u32 {
            exact += f64::from(k).ln();
            let got = ln_factorial(f64::from(k));
            assert!(
                (got - exact).abs() < 1e-9 * exact.max(1.0),
                "{k}: {got} vs {exact}"
            );
        }
        assert_eq!(round_non_negative(2.5), 3.0);
        assert_eq!(round_non_negative(2.49), 2.0);
        assert_eq!(round_non_negative(-0.3), 0.0);
    }
}
