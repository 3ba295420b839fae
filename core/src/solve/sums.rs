//! The sums the shards send up at an angle's end, merged over shards in row order: fit
//! quality and noise ([`FitStats`]) and the shared index's Gauss-Newton sums ([`SchurSums`]).

use nalgebra::{Cholesky, Const, SMatrix, SVector};

/// `log10(x)` for positive normal `x`, within 1e-4 (a 32nd of a decade, the histogram's bin,
/// is 0.031): the exponent from the bits, the mantissa's `log2` by a quartic. Every pixel
/// adds two values at every angle's end, where `libm::log10f` took a fifth of the time.
#[inline]
fn fast_log10(x: f32) -> f32 {
    let bits = x.to_bits();
    let exponent = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    // Least-squares quartic for log2 on [1, 2) (max error 2.0e-4).
    let log2_m =
        -2.496_773_8 + m * (4.028_373 + m * (-2.081_06 + m * (0.628_815_7 - 0.079_150_37 * m)));
    (exponent as f32 + log2_m) * core::f32::consts::LOG10_2
}

/// Histogram of per-pixel RMS residuals (log bins), merged over shards.
#[derive(Clone, Debug, PartialEq)]
pub struct RmsHistogram {
    /// Pixels per bin; bin `i` covers `10^(-6 + i / 32)`.
    pub counts: [u32; 192],
}

impl Default for RmsHistogram {
    fn default() -> Self {
        Self { counts: [0; 192] }
    }
}

impl RmsHistogram {
    /// Adds one pixel's RMS residual.
    pub fn add(&mut self, rms: f32) {
        if rms.is_finite() && rms > 0.0 {
            let b = ((fast_log10(rms) + 6.0) * 32.0).clamp(0.0, 191.0) as usize;
            self.counts[b] += 1;
        }
    }

    /// Adds another shard's histogram.
    pub fn merge(&mut self, o: &Self) {
        for (a, b) in self.counts.iter_mut().zip(o.counts.iter()) {
            *a += *b;
        }
    }

    /// The median RMS, or `None` if empty.
    pub fn median(&self) -> Option<f32> {
        let total: u64 = self.counts.iter().map(|&c| u64::from(c)).sum();
        if total == 0 {
            return None;
        }
        let mut acc = 0;
        for (i, &c) in self.counts.iter().enumerate() {
            acc += u64::from(c);
            if 2 * acc >= total {
                return Some(libm::powf(10.0, (i as f32 + 0.5) / 32.0 - 6.0));
            }
        }
        None
    }
}

/// Fit quality and noise over pixels, merged over shards.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FitStats {
    /// RMS residuals of the refined pixels' full-spectrum fits.
    pub rms: RmsHistogram,
    /// Every pixel's own noise estimate (from its spectrum's second differences).
    pub noise: RmsHistogram,
}

impl FitStats {
    /// Adds another shard's histograms.
    pub fn merge(&mut self, o: &Self) {
        self.rms.merge(&o.rms);
        self.noise.merge(&o.noise);
    }
}

/// Sums for the shared index's Gauss-Newton step (each pixel's thickness eliminated), merged
/// over shards.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SchurSums {
    /// The reduced index block, upper triangle row by row: `(0,0) (0,1) (0,2) (1,1) (1,2)
    /// (2,2)` of the basis coefficients ([`super::IndexModel::to_basis`]).
    pub h: [f64; 6],
    /// The reduced index gradient.
    pub g: [f64; 3],
    /// Pixels included.
    pub pixels: f64,
    /// Sum of squared residuals of the pixels included (each at its best thickness).
    pub sse: f64,
    /// Samples of the pixels included.
    pub samples: f64,
}

impl SchurSums {
    /// Adds another shard's sums.
    pub fn merge(&mut self, o: &Self) {
        for (a, b) in self.h.iter_mut().zip(o.h) {
            *a += b;
        }
        for (a, b) in self.g.iter_mut().zip(o.g) {
            *a += b;
        }
        self.pixels += o.pixels;
        self.sse += o.sse;
        self.samples += o.samples;
    }

    fn entry(&self, i: usize, j: usize) -> f64 {
        let (i, j) = (i.min(j), i.max(j));
        self.h[[0, 3, 5][i] + j - i]
    }

    /// Cholesky factor of the leading `K x K` block, or `None` if it is singular: a pivot
    /// at or below `1e-12` of its diagonal entry (nalgebra's own test is only `> 0`).
    fn cholesky<const K: usize>(&self) -> Option<Cholesky<f64, Const<K>>> {
        let block = SMatrix::<f64, K, K>::from_fn(|i, j| self.entry(i, j));
        let c = block.cholesky()?;
        let l = c.l_dirty();
        (0..K)
            .all(|i| l[(i, i)] * l[(i, i)] > self.entry(i, i) * 1e-12)
            .then_some(c)
    }

    /// [`SchurSums::step`] in the first `K` coefficients.
    fn step_k<const K: usize>(&self) -> Option<([f64; 3], f64)> {
        let g = SVector::<f64, K>::from_fn(|i, _| self.g[i]);
        let x = self.cholesky::<K>()?.solve(&g);
        let mut out = [0.0; 3];
        out[..K].copy_from_slice(x.as_slice());
        Some((out, x.dot(&g)))
    }

    /// [`SchurSums::inverse`] of the leading `K x K` block.
    fn inverse_k<const K: usize>(&self) -> Option<[[f64; 3]; 3]> {
        let inv = self.cholesky::<K>()?.inverse();
        let mut out = [[0.0; 3]; 3];
        for (i, row) in out.iter_mut().enumerate().take(K) {
            for (j, v) in row.iter_mut().enumerate().take(K) {
                *v = inv[(i, j)];
            }
        }
        Some(out)
    }

    /// The step in the first `k` basis coefficients (the others held) and the squared-error
    /// reduction it predicts, or `None` if that block is singular (or `k` is not 1 to 3).
    pub fn step(&self, k: usize) -> Option<([f64; 3], f64)> {
        match k {
            1 => self.step_k::<1>(),
            2 => self.step_k::<2>(),
            3 => self.step_k::<3>(),
            _ => None,
        }
    }

    /// The inverse of the leading `k x k` block (zero outside it): times the residual
    /// variance, the covariance of the first `k` coefficients with every pixel's thickness
    /// free. `None` if the block is singular (or `k` is not 1 to 3).
    pub fn inverse(&self, k: usize) -> Option<[[f64; 3]; 3]> {
        match k {
            1 => self.inverse_k::<1>(),
            2 => self.inverse_k::<2>(),
            3 => self.inverse_k::<3>(),
            _ => None,
        }
    }
}

#[cfg(test)]
mod schur_tests {
    use super::SchurSums;

    /// A symmetric positive-definite block with strongly correlated coefficients (a thin
    /// film's index level and slope).
    fn sums() -> SchurSums {
        SchurSums {
            h: [4.0, 3.8, 0.5, 3.7, 0.2, 2.0],
            g: [1.0, -0.5, 0.25],
            ..SchurSums::default()
        }
    }

    #[test]
    fn the_inverse_inverts_the_leading_block() {
        let s = sums();
        for k in 1..=3 {
            let inv = s.inverse(k).expect("positive definite");
            for (i, row) in inv.iter().enumerate() {
                for (j, &v) in row.iter().enumerate() {
                    let inside = i < k && j < k;
                    let want = if inside {
                        f64::from(u8::from(i == j))
                    } else {
                        0.0
                    };
                    let got: f64 = if inside {
                        (0..k).map(|m| s.entry(i, m) * inv[m][j]).sum()
                    } else {
                        v
                    };
                    assert!((got - want).abs() < 1e-12, "k {k} ({i}, {j}): {got}");
                }
            }
            // The step is the inverse applied to the gradient.
            let (x, _) = s.step(k).expect("a step");
            for (i, xi) in x.iter().enumerate().take(k) {
                let want: f64 = (0..k).map(|m| inv[i][m] * s.g[m]).sum();
                assert!((xi - want).abs() < 1e-12, "k {k}: x{i} {xi} against {want}");
            }
        }
        // One term: the plain reciprocal; with the correlated slope free the level's variance
        // grows (here about 40-fold), which the diagonal alone does not show.
        assert_eq!(s.inverse(1).expect("one term")[0][0], 0.25);
        let two = s.inverse(2).expect("two terms")[0][0];
        assert!(two > 10.0 * 0.25, "{two}");
    }

    #[test]
    fn a_singular_block_has_no_inverse() {
        let s = SchurSums {
            h: [1.0, 1.0, 0.0, 1.0, 0.0, 1.0],
            ..SchurSums::default()
        };
        assert!(s.inverse(1).is_some());
        assert!(s.inverse(2).is_none());
    }
}

#[cfg(test)]
mod log_tests {
    #[test]
    fn fast_log10_is_within_a_small_part_of_a_bin() {
        let mut worst = 0.0f32;
        let mut x = 1e-7f32;
        while x < 1e3 {
            worst = worst.max((super::fast_log10(x) - libm::log10f(x)).abs());
            x *= 1.0137;
        }
        assert!(worst < 1e-4, "{worst}");
    }
}
