//! The shared index from extremum shifts, pooled over every pixel.
//!
//! For one pixel and one interference order the extremum wavelength obeys
//! `lambda^2 = (2 d / q)^2 (n^2 - x)`, `x = (n_ambient sin theta)^2` (method.md eqs. 9-11), so
//! between a reference angle and another one every extremum of every pixel moves by the same
//! ratio `rho = sqrt((n^2 - x_cur) / (n^2 - x_ref))`, whatever its thickness or order. Each
//! same-kind pair of a pixel's extrema at the two angles votes for its ratio in a fixed
//! histogram; wrong pairings scatter, right ones pile up, and the mode (refined by a trimmed
//! mean around it) gives `n^2 = (x_cur - rho^2 x_ref) / (1 - rho^2)` (eq. 12, every pixel
//! pooled).

use crate::track::{Extremum, Kind};

/// Bins of a ratio histogram.
pub const BINS: usize = 512;

/// The geometry of one angle pair: which ratios the search range allows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairGeometry {
    x_ref: f64,
    x_cur: f64,
    rho_lo: f64,
    rho_hi: f64,
}

impl PairGeometry {
    /// The pair (reference angle, current angle), both in degrees, for indices within
    /// `index_range` (widened a little so the true ratio is not at the histogram's edge).
    /// `None` when the two angles are too close for a shift to be measured.
    pub fn new(
        ambient_index: f64,
        ref_deg: f64,
        cur_deg: f64,
        index_range: [f64; 2],
    ) -> Option<Self> {
        let sx = |deg: f64| {
            let s = ambient_index * libm::sin(deg.to_radians());
            s * s
        };
        let (x_ref, x_cur) = (sx(ref_deg), sx(cur_deg));
        if libm::fabs(x_ref - x_cur) < 1e-3 {
            return None;
        }
        let lo_n = (index_range[0] * 0.9).max(libm::sqrt(x_ref.max(x_cur)) + 0.05);
        let hi_n = index_range[1] * 1.1;
        let mut g = Self {
            x_ref,
            x_cur,
            rho_lo: 0.0,
            rho_hi: 0.0,
        };
        let (a, b) = (g.ratio(lo_n), g.ratio(hi_n));
        g.rho_lo = a.min(b);
        g.rho_hi = a.max(b);
        Some(g)
    }

    /// The extremum wavelength ratio (current / reference) of a film of index `n`.
    pub fn ratio(&self, n: f64) -> f64 {
        libm::sqrt((n * n - self.x_cur) / (n * n - self.x_ref))
    }

    /// The index that gives ratio `rho` (method.md eq. 12), if it is physical.
    pub fn index_from_ratio(&self, rho: f64) -> Option<f64> {
        let r2 = rho * rho;
        let n2 = (self.x_cur - r2 * self.x_ref) / (1.0 - r2);
        (n2.is_finite() && n2 > self.x_ref.max(self.x_cur)).then(|| libm::sqrt(n2))
    }

    /// `d n / d rho` at ratio `rho`, for error propagation.
    pub fn index_slope(&self, rho: f64) -> f64 {
        let h = 1e-6;
        match (
            self.index_from_ratio(rho + h),
            self.index_from_ratio(rho - h),
        ) {
            (Some(a), Some(b)) => (a - b) / (2.0 * h),
            _ => f64::NAN,
        }
    }

    fn bin(&self, rho: f64) -> Option<usize> {
        let u = (rho - self.rho_lo) / (self.rho_hi - self.rho_lo);
        (0.0..1.0).contains(&u).then_some((u * BINS as f64) as usize)
    }

    fn bin_centre(&self, bin: f64) -> f64 {
        self.rho_lo + (bin + 0.5) / BINS as f64 * (self.rho_hi - self.rho_lo)
    }
}

/// Votes of one angle pair, summed over pixels (shards merge by adding).
#[derive(Clone, Debug, PartialEq)]
pub struct RatioHistogram {
    /// Votes per bin.
    pub counts: [u32; BINS],
}

impl Default for RatioHistogram {
    fn default() -> Self {
        Self { counts: [0; BINS] }
    }
}

/// Running sums of the log ratios inside the accepted window (logs, so that the noise of the
/// two wavelengths biases neither way).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RatioSums {
    /// Count.
    pub n: f64,
    /// Sum of `ln(rho)`.
    pub sum: f64,
    /// Sum of `ln(rho)^2`.
    pub sum_sq: f64,
}

impl RatioSums {
    /// Adds another shard's sums.
    pub fn merge(&mut self, o: &Self) {
        self.n += o.n;
        self.sum += o.sum;
        self.sum_sq += o.sum_sq;
    }
}

/// Calls `f(rho)` for every same-kind pairing of a pixel's extrema whose ratio the pair
/// geometry allows. `wavelength_nm` maps a fractional band to its wavelength.
pub fn for_each_ratio(
    geom: &PairGeometry,
    reference: &[Extremum],
    current: &[Extremum],
    wavelength_nm: impl Fn(f32) -> f64,
    mut f: impl FnMut(f64),
) {
    for r in reference {
        let lr = wavelength_nm(r.band);
        for c in current.iter().filter(|c| c.kind == r.kind) {
            let rho = wavelength_nm(c.band) / lr;
            if rho > geom.rho_lo && rho < geom.rho_hi {
                f(rho);
            }
        }
    }
}

impl RatioHistogram {
    /// Adds a pixel's votes.
    pub fn vote(
        &mut self,
        geom: &PairGeometry,
        reference: &[Extremum],
        current: &[Extremum],
        wavelength_nm: impl Fn(f32) -> f64,
    ) {
        for_each_ratio(geom, reference, current, wavelength_nm, |rho| {
            if let Some(b) = geom.bin(rho) {
                self.counts[b] = self.counts[b].saturating_add(1);
            }
        });
    }

    /// Adds another shard's votes.
    pub fn merge(&mut self, o: &Self) {
        for (a, b) in self.counts.iter_mut().zip(o.counts.iter()) {
            *a = a.saturating_add(*b);
        }
    }

    /// The ratio window around the histogram's mode: the mode of a 17-bin running sum, its
    /// half width where the smoothed votes fall halfway from the mode to the background (the
    /// lower quartile), doubled. `None` without enough votes, or when the votes do not pile up
    /// clearly inside the range: a mode not well above the background, holding less than half
    /// the votes, wider than a third of the range, or whose window is cut by its edge means the shift between the two angles is lost in the
    /// extremum noise, and this pair gives no index.
    pub fn mode_window(&self, geom: &PairGeometry) -> Option<(f64, f64)> {
        const K: usize = 8;
        let total: u64 = self.counts.iter().map(|&c| u64::from(c)).sum();
        if total < 32 {
            return None;
        }
        let mut smooth = [0u64; BINS];
        for (i, s) in smooth.iter_mut().enumerate() {
            let lo = i.saturating_sub(K);
            let hi = (i + K).min(BINS - 1);
            *s = self.counts[lo..=hi].iter().map(|&c| u64::from(c)).sum();
        }
        let (best, &peak) = smooth.iter().enumerate().max_by_key(|&(_, v)| *v)?;
        let mut sorted = smooth;
        sorted.sort_unstable();
        let background = sorted[BINS / 4];
        let height = peak.saturating_sub(background) as f64;
        if height < 4.0 * libm::sqrt(peak as f64) || peak < 2 * background {
            return None;
        }
        let half = background as f64 + height / 2.0;
        let mut lo = best;
        while lo > 0 && smooth[lo - 1] as f64 > half {
            lo -= 1;
        }
        let mut hi = best;
        while hi + 1 < BINS && smooth[hi + 1] as f64 > half {
            hi += 1;
        }
        let centre = (lo + hi) as f64 / 2.0;
        let half_width = (hi - lo) as f64 / 2.0 + 1.0;
        if half_width > BINS as f64 / 6.0
            || centre - 2.0 * half_width < 0.0
            || centre + 2.0 * half_width >= BINS as f64
        {
            return None;
        }
        // Most votes must be in the mode: a broad hump with a noise spike on top is not one.
        let a = (centre - 2.0 * half_width) as usize;
        let b = (centre + 2.0 * half_width) as usize;
        let inside: u64 = self.counts[a..=b].iter().map(|&c| u64::from(c)).sum();
        if 2 * inside < total {
            return None;
        }
        Some((
            geom.bin_centre(centre - 2.0 * half_width),
            geom.bin_centre(centre + 2.0 * half_width),
        ))
    }
}

/// Adds a pixel's ratios inside `window` to `sums`.
pub fn accumulate_window(
    sums: &mut RatioSums,
    geom: &PairGeometry,
    window: (f64, f64),
    reference: &[Extremum],
    current: &[Extremum],
    wavelength_nm: impl Fn(f32) -> f64,
) {
    for_each_ratio(geom, reference, current, wavelength_nm, |rho| {
        if rho >= window.0 && rho <= window.1 {
            let l = libm::log(rho);
            sums.n += 1.0;
            sums.sum += l;
            sums.sum_sq += l * l;
        }
    });
}

/// One angle pair's index estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairEstimate {
    /// The index.
    pub index: f64,
    /// Its standard error (from the spread of the accepted ratios).
    pub sigma: f64,
    /// Ratios accepted.
    pub votes: f64,
}

/// Turns the window sums into an index estimate.
pub fn pair_estimate(geom: &PairGeometry, sums: &RatioSums) -> Option<PairEstimate> {
    if sums.n < 8.0 {
        return None;
    }
    let mean_log = sums.sum / sums.n;
    let var = (sums.sum_sq / sums.n - mean_log * mean_log).max(0.0);
    let mean = libm::exp(mean_log);
    let se = mean * libm::sqrt(var / sums.n);
    let index = geom.index_from_ratio(mean)?;
    let sigma = libm::fabs(geom.index_slope(mean)) * se;
    Some(PairEstimate {
        index,
        sigma: if sigma.is_finite() {
            sigma.max(1e-6)
        } else {
            f64::INFINITY
        },
        votes: sums.n,
    })
}

/// Inverse-variance mean of pair estimates: `(index, sigma)`.
pub fn combine(estimates: &[PairEstimate]) -> Option<(f64, f64)> {
    let mut sw = 0.0;
    let mut swx = 0.0;
    for e in estimates.iter().filter(|e| e.sigma.is_finite()) {
        let w = 1.0 / (e.sigma * e.sigma);
        sw += w;
        swx += w * e.index;
    }
    (sw > 0.0).then(|| (swx / sw, libm::sqrt(1.0 / sw)))
}

/// Whether an extremum list has anything to vote with.
pub fn has_kind(list: &[Extremum], kind: Kind) -> bool {
    list.iter().any(|e| e.kind == kind)
}
