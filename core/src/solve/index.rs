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

use nalgebra::{Matrix2, Vector2};

use crate::track::{Extremum, MAX_EXTREMA};

/// Bins of a ratio histogram.
pub const BINS: usize = 512;

/// The geometry of one angle pair: which ratios the search range allows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairGeometry {
    x_ref: f64,
    x_cur: f64,
    rho_lo: f64,
    rho_hi: f64,
    band_nm: [f64; 2],
}

impl PairGeometry {
    /// The pair (reference angle, current angle), both in degrees, for indices within
    /// `index_range` (widened a little so the true ratio is not at the histogram's edge).
    /// `None` when the two angles are too close for a shift to be measured. `band_nm` is the
    /// wavelength span of the bands (for the per-wavelength sums).
    pub fn new(
        ambient_index: f64,
        ref_deg: f64,
        cur_deg: f64,
        index_range: [f64; 2],
        band_nm: [f64; 2],
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
            band_nm,
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
        (0.0..1.0)
            .contains(&u)
            .then_some((u * BINS as f64) as usize)
    }

    fn bin_centre(&self, bin: f64) -> f64 {
        self.rho_lo + (bin + 0.5) / BINS as f64 * (self.rho_hi - self.rho_lo)
    }
}

/// Votes of one angle pair, summed over pixels (shards merge by adding): in total, and per
/// wavelength bin of the reference extremum (a dispersive film's ratio depends on it).
#[derive(Clone, Debug, PartialEq)]
pub struct RatioHistogram {
    /// Votes per ratio bin.
    pub counts: [u32; BINS],
    /// Votes per wavelength bin and ratio bin.
    pub by_lambda: [[u32; BINS]; LAMBDA_BINS],
}

impl Default for RatioHistogram {
    fn default() -> Self {
        Self {
            counts: [0; BINS],
            by_lambda: [[0; BINS]; LAMBDA_BINS],
        }
    }
}

/// The accepted ratio windows of one pair: around the overall mode, and around each
/// wavelength bin's own mode near it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RatioWindows {
    /// Around the mode of all votes.
    pub all: (f64, f64),
    /// Per wavelength bin of the reference extremum.
    pub per_bin: [(f64, f64); LAMBDA_BINS],
}

impl PairGeometry {
    /// The wavelength bin of a reference extremum at `lambda_nm`.
    pub fn lambda_bin(&self, lambda_nm: f64) -> usize {
        let [lo, hi] = self.band_nm;
        ((lambda_nm - lo) / (hi - lo) * LAMBDA_BINS as f64).clamp(0.0, LAMBDA_BINS as f64 - 1.0)
            as usize
    }
}

/// A 17-bin running sum.
fn smoothed(counts: &[u32; BINS]) -> [u64; BINS] {
    const K: usize = 8;
    let mut smooth = [0u64; BINS];
    for (i, s) in smooth.iter_mut().enumerate() {
        let lo = i.saturating_sub(K);
        let hi = (i + K).min(BINS - 1);
        *s = counts[lo..=hi].iter().map(|&c| u64::from(c)).sum();
    }
    smooth
}

/// Wavelength bins of the per-wavelength ratio sums (for dispersion).
pub const LAMBDA_BINS: usize = 8;

/// Sums of the log ratios of one wavelength bin.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BinSums {
    /// Count.
    pub n: f64,
    /// Sum of `ln(rho)`.
    pub sum: f64,
    /// Sum of `ln(rho)^2`.
    pub sum_sq: f64,
    /// Sum of the reference wavelengths, nm.
    pub sum_lambda: f64,
}

impl BinSums {
    fn add(&mut self, l: f64, lambda: f64) {
        self.n += 1.0;
        self.sum += l;
        self.sum_sq += l * l;
        self.sum_lambda += lambda;
    }

    fn merge(&mut self, o: &Self) {
        self.n += o.n;
        self.sum += o.sum;
        self.sum_sq += o.sum_sq;
        self.sum_lambda += o.sum_lambda;
    }
}

/// Running sums of the log ratios inside the accepted window (logs, so that the noise of the
/// two wavelengths biases neither way), in total and per reference-wavelength bin.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RatioSums {
    /// Count.
    pub n: f64,
    /// Sum of `ln(rho)`.
    pub sum: f64,
    /// Sum of `ln(rho)^2`.
    pub sum_sq: f64,
    /// The same per wavelength bin of the reference extremum.
    pub bins: [BinSums; LAMBDA_BINS],
}

impl RatioSums {
    /// Adds another shard's sums.
    pub fn merge(&mut self, o: &Self) {
        self.n += o.n;
        self.sum += o.sum;
        self.sum_sq += o.sum_sq;
        for (a, b) in self.bins.iter_mut().zip(o.bins.iter()) {
            a.merge(b);
        }
    }
}

/// Calls `f(rho, lambda_ref_nm)` for every same-kind pairing of a pixel's extrema whose ratio the pair
/// geometry allows, reference extremum by reference extremum. `wavelength_nm` maps a fractional band to its wavelength.
pub fn for_each_ratio<'r>(
    geom: &PairGeometry,
    reference: impl IntoIterator<Item = &'r Extremum>,
    current: &[Extremum],
    wavelength_nm: impl Fn(f32) -> f64,
    mut f: impl FnMut(f64, f64),
) {
    // The current extrema's wavelengths once, not once per reference extremum (every pixel of
    // the index's sample pairs its lists at every angle's end); a list longer than an
    // `ExtremaList` looks its tail up as it goes.
    let mut known = [0.0f64; MAX_EXTREMA];
    for (l, c) in known.iter_mut().zip(current) {
        *l = wavelength_nm(c.band());
    }
    let lambda = |k: usize| {
        known
            .get(k)
            .copied()
            .unwrap_or_else(|| wavelength_nm(current[k].band()))
    };
    for r in reference {
        let lr = wavelength_nm(r.band());
        for (k, c) in current.iter().enumerate() {
            if c.kind() != r.kind() {
                continue;
            }
            let rho = lambda(k) / lr;
            if rho > geom.rho_lo && rho < geom.rho_hi {
                f(rho, lr);
            }
        }
    }
}

impl RatioHistogram {
    /// Adds a pixel's votes.
    pub fn vote<'r>(
        &mut self,
        geom: &PairGeometry,
        reference: impl IntoIterator<Item = &'r Extremum>,
        current: &[Extremum],
        wavelength_nm: impl Fn(f32) -> f64,
    ) {
        for_each_ratio(geom, reference, current, wavelength_nm, |rho, lambda| {
            if let Some(b) = geom.bin(rho) {
                self.counts[b] = self.counts[b].saturating_add(1);
                let l = &mut self.by_lambda[geom.lambda_bin(lambda)][b];
                *l = l.saturating_add(1);
            }
        });
    }

    /// Adds another shard's votes.
    pub fn merge(&mut self, o: &Self) {
        for (a, b) in self.counts.iter_mut().zip(o.counts.iter()) {
            *a = a.saturating_add(*b);
        }
        for (la, lb) in self.by_lambda.iter_mut().zip(o.by_lambda.iter()) {
            for (a, b) in la.iter_mut().zip(lb.iter()) {
                *a = a.saturating_add(*b);
            }
        }
    }

    /// The overall window ([`RatioHistogram::mode_window`]) and, per wavelength bin with
    /// enough votes, a window of the same width around that bin's own mode within a window's
    /// width of the overall one (dispersion moves the ratio with wavelength; a single window
    /// would cut the bins at either end of the band and bias their means).
    pub fn windows(&self, geom: &PairGeometry) -> Option<RatioWindows> {
        let all = self.mode_window(geom)?;
        let to_bin =
            |rho: f64| (rho - geom.rho_lo) / (geom.rho_hi - geom.rho_lo) * BINS as f64 - 0.5;
        let (a, b) = (to_bin(all.0), to_bin(all.1));
        let width = b - a;
        let mut per_bin = [all; LAMBDA_BINS];
        for (w, counts) in per_bin.iter_mut().zip(self.by_lambda.iter()) {
            let total: u32 = counts.iter().sum();
            if total < 32 {
                continue;
            }
            let smooth = smoothed(counts);
            let lo = (a - width).max(0.0) as usize;
            let hi = ((b + width) as usize).min(BINS - 1);
            if let Some((best, _)) = smooth[lo..=hi].iter().enumerate().max_by_key(|&(_, v)| *v) {
                let centre = (lo + best) as f64;
                *w = (
                    geom.bin_centre(centre - width / 2.0),
                    geom.bin_centre(centre + width / 2.0),
                );
            }
        }
        Some(RatioWindows { all, per_bin })
    }

    /// The ratio window around the histogram's mode: the mode of a 17-bin running sum, its
    /// half width where the smoothed votes fall halfway from the mode to the background (the
    /// lower quartile), doubled. `None` without enough votes, or when the votes do not pile up
    /// clearly inside the range: a mode not well above the background, holding less than a
    /// quarter of the votes or less than 1.5 times as high as any other peak, wider than a third of the range, or whose window is cut by its edge means the shift between the two angles is lost in the
    /// extremum noise, and this pair gives no index.
    pub fn mode_window(&self, geom: &PairGeometry) -> Option<(f64, f64)> {
        let total: u64 = self.counts.iter().map(|&c| u64::from(c)).sum();
        if total < 32 {
            return None;
        }
        let smooth = smoothed(&self.counts);
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
        // The mode must stand out: hold a quarter of the votes, and tower over every other
        // peak (a broad hump with a noise spike on top is not a mode; for thick films the
        // pairings with the neighbouring orders pile up too, but smeared, since their ratio
        // depends on the order).
        let a = (centre - 2.0 * half_width) as usize;
        let b = (centre + 2.0 * half_width) as usize;
        let inside: u64 = self.counts[a..=b].iter().map(|&c| u64::from(c)).sum();
        let guard = (2.0 * half_width) as usize;
        let elsewhere = smooth
            .iter()
            .enumerate()
            .filter(|&(i, _)| i + guard < a || i > b + guard)
            .map(|(_, &v)| v)
            .max()
            .unwrap_or(0);
        if 4 * inside < total || 2 * peak < 3 * elsewhere {
            return None;
        }
        Some((
            geom.bin_centre(centre - 2.0 * half_width),
            geom.bin_centre(centre + 2.0 * half_width),
        ))
    }
}

/// Adds a pixel's ratios to `sums`: to the totals inside the overall window, to the
/// wavelength bins inside each bin's own window.
pub fn accumulate_window<'r>(
    sums: &mut RatioSums,
    geom: &PairGeometry,
    windows: &RatioWindows,
    reference: impl IntoIterator<Item = &'r Extremum>,
    current: &[Extremum],
    wavelength_nm: impl Fn(f32) -> f64,
) {
    for_each_ratio(geom, reference, current, wavelength_nm, |rho, lambda| {
        let in_all = rho >= windows.all.0 && rho <= windows.all.1;
        let k = geom.lambda_bin(lambda);
        let window = windows.per_bin[k];
        let in_bin = rho >= window.0 && rho <= window.1;
        // Most pairings (other orders) fall outside both windows: no logarithm for them.
        if !(in_all || in_bin) {
            return;
        }
        let l = libm::log(rho);
        if in_all {
            sums.n += 1.0;
            sums.sum += l;
            sums.sum_sq += l * l;
        }
        if in_bin {
            sums.bins[k].add(l, lambda);
        }
    });
}

/// Systematic error floor of a pair's mean ratio (see [`pair_estimate`]).
pub const RATIO_FLOOR: f64 = 1e-3;

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
    // The spread's standard error, and a floor for what averaging cannot remove: a
    // systematic error of the ratio of [`RATIO_FLOOR`] (about 0.5 nm in 500), which weighs
    // a poorly conditioned pair (small angle difference, high index) down.
    let sigma =
        libm::fabs(geom.index_slope(mean)) * libm::sqrt(se * se + RATIO_FLOOR * RATIO_FLOOR);
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

/// Inverse-variance mean of pair estimates, robust to a pair whose mode was the wrong one:
/// `(index, sigma)`. An estimate more than [`OUTLIER_SIGMA`] of its own sigma from the mean of
/// the others is left out (with two that disagree so, the better conditioned one is kept).
pub fn combine(estimates: &[PairEstimate]) -> Option<(f64, f64)> {
    let mean_of = |skip: Option<usize>| -> Option<(f64, f64)> {
        let mut sw = 0.0;
        let mut swx = 0.0;
        for (i, e) in estimates.iter().enumerate() {
            if Some(i) == skip || !e.sigma.is_finite() {
                continue;
            }
            let w = 1.0 / (e.sigma * e.sigma);
            sw += w;
            swx += w * e.index;
        }
        (sw > 0.0).then(|| (swx / sw, libm::sqrt(1.0 / sw)))
    };
    // Leave out the worst outlier, if any, once (pairs are few: one per angle).
    let mut worst: Option<(usize, f64)> = None;
    for (i, e) in estimates.iter().enumerate() {
        if let Some((m, s)) = mean_of(Some(i)) {
            let z = libm::fabs(e.index - m) / libm::sqrt(e.sigma * e.sigma + s * s);
            if z > OUTLIER_SIGMA && worst.is_none_or(|(_, wz)| z > wz) {
                worst = Some((i, z));
            }
        }
    }
    match worst {
        Some((i, _)) if estimates.len() >= 3 => mean_of(Some(i)),
        Some(_) => {
            // Two that disagree: keep the better conditioned.
            let best = estimates
                .iter()
                .filter(|e| e.sigma.is_finite())
                .min_by(|a, b| a.sigma.total_cmp(&b.sigma))?;
            Some((best.index, best.sigma))
        }
        None => mean_of(None),
    }
}

/// How far (in sigmas) a pair estimate may sit from the others' mean.
pub const OUTLIER_SIGMA: f64 = 4.0;

/// One pair's per-wavelength evidence, kept by the solver for the index fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairBins {
    /// `(n0 sin theta)^2` at the reference angle.
    pub x_ref: f64,
    /// The same at the other angle.
    pub x_cur: f64,
    /// Per bin: `(mean reference wavelength nm, mean ln rho, standard error of ln rho, count)`.
    pub bins: [(f64, f64, f64, f64); LAMBDA_BINS],
}

/// Fewest ratios a wavelength bin needs to enter the fit.
const MIN_BIN_VOTES: f64 = 8.0;
/// Floor on a bin's standard error (log units, about 0.15 nm at 500 nm): the extremum
/// locations' systematic error, which averaging over pixels does not remove.
const SE_FLOOR: f64 = 3e-4;

impl PairBins {
    /// Keeps the per-bin means of a pair's window sums.
    pub fn from_sums(geom: &PairGeometry, sums: &RatioSums) -> Self {
        let mut bins = [(0.0, 0.0, 0.0, 0.0); LAMBDA_BINS];
        for (o, b) in bins.iter_mut().zip(sums.bins.iter()) {
            if b.n >= MIN_BIN_VOTES {
                let mean = b.sum / b.n;
                let var = (b.sum_sq / b.n - mean * mean).max(0.0);
                let se = libm::sqrt(var / b.n).max(SE_FLOOR);
                *o = (b.sum_lambda / b.n, mean, se, b.n);
            }
        }
        Self {
            x_ref: geom.x_ref,
            x_cur: geom.x_cur,
            bins,
        }
    }
}

/// The log ratio a film of index model `model` predicts for an extremum at `lambda_nm` at the
/// reference angle: the order is kept, so `lambda' = lambda sqrt((n(lambda')^2 - x') /
/// (n(lambda)^2 - x))`, solved by fixed-point iteration.
pub fn predicted_log_ratio(
    model: super::IndexModel,
    lambda_nm: f64,
    x_ref: f64,
    x_cur: f64,
) -> f64 {
    let n_ref = model.at(lambda_nm);
    let base = n_ref * n_ref - x_ref;
    let mut l = lambda_nm;
    for _ in 0..8 {
        let n = model.at(l);
        l = lambda_nm * libm::sqrt(((n * n - x_cur) / base).max(1e-12));
    }
    libm::log(l / lambda_nm)
}

/// The index fitted to every pair's per-wavelength log ratios.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexFit {
    /// The chosen model.
    pub model: super::IndexModel,
    /// Standard error of the index at 550 nm.
    pub sigma: f64,
    /// Chi-square of the best constant index.
    pub chi2_constant: f64,
    /// Chi-square of the best Cauchy model (NaN if not fitted).
    pub chi2_cauchy: f64,
    /// Wavelength bins used.
    pub bins: usize,
    /// Whether the Cauchy model was chosen.
    pub dispersive: bool,
}

/// The test the Cauchy model must pass to replace a constant index (one more parameter): its
/// chi-square improvement, in units of its own reduced chi-square (so scatter the model does
/// not explain raises the bar, as in an F test), must exceed 25 (a 5-sigma improvement); the
/// constant model must itself fail to explain the data (reduced chi-square above 2); and the
/// fitted dispersion must be physical (normal, `0 <= b <= 0.2 um^2`, the index inside the
/// search range across the band). The simpler model wins otherwise.
pub const CAUCHY_DELTA_CHI2: f64 = 25.0;

fn chi2(pairs: &[PairBins], model: super::IndexModel) -> (f64, usize) {
    let mut c = 0.0;
    let mut k = 0;
    for p in pairs {
        for &(lambda, mean, se, n) in &p.bins {
            if n >= MIN_BIN_VOTES {
                let r = (mean - predicted_log_ratio(model, lambda, p.x_ref, p.x_cur)) / se;
                c += r * r;
                k += 1;
            }
        }
    }
    (c, k)
}

/// Chooses between a constant index and a two-term Cauchy model fitted (Gauss-Newton) to the
/// pairs' per-wavelength evidence, keeping the simpler one unless the richer is clearly
/// better (see [`CAUCHY_DELTA_CHI2`]). The constant index is `constant = (n, sigma)`, the
/// pooled estimate of all votes ([`combine`]): per-wavelength means weight the few bins that
/// hold extrema too unevenly to estimate it better.
pub fn fit_index(
    pairs: &[PairBins],
    constant: (f64, f64),
    index_range: [f64; 2],
    band_nm: [f64; 2],
) -> Option<IndexFit> {
    let (a, sigma) = constant;
    let model = super::IndexModel::constant(a);
    let (chi2_c, bins) = chi2(pairs, model);
    if !a.is_finite() {
        return None;
    }
    let dof_c = bins.saturating_sub(1).max(1) as f64;
    let mut fit = IndexFit {
        model,
        sigma,
        chi2_constant: chi2_c,
        chi2_cauchy: f64::NAN,
        bins,
        dispersive: false,
    };
    // Cauchy needs bins spread over wavelength.
    if bins < 4 {
        return Some(fit);
    }
    let mut m = super::IndexModel::constant(a);
    let mut cov = [[0.0; 2]; 2];
    for _ in 0..30 {
        let Some((step, c)) = normal_2d(pairs, m) else {
            break;
        };
        cov = c;
        m.a += step[0].clamp(-0.1, 0.1);
        m.b_um2 += step[1].clamp(-0.05, 0.05);
        if libm::fabs(step[0]) < 1e-9 && libm::fabs(step[1]) < 1e-9 {
            break;
        }
    }
    let (chi2_d, _) = chi2(pairs, m);
    fit.chi2_cauchy = chi2_d;
    let dof_d = bins.saturating_sub(2).max(1) as f64;
    let scale = (chi2_d / dof_d).max(1.0);
    let physical = (0.0..=0.2).contains(&m.b_um2)
        && [band_nm[0], band_nm[1], 550.0]
            .iter()
            .all(|&l| (index_range[0]..=index_range[1]).contains(&m.at(l)));
    if (chi2_c - chi2_d) / scale > CAUCHY_DELTA_CHI2 && chi2_c / dof_c > 2.0 && physical {
        // Variance of n(550) = a + b / 0.3025.
        let g = [1.0, 1.0 / 0.3025];
        let var = g[0] * (cov[0][0] * g[0] + cov[0][1] * g[1])
            + g[1] * (cov[1][0] * g[0] + cov[1][1] * g[1]);
        fit.model = m;
        fit.sigma = libm::sqrt((var * scale).max(0.0));
        fit.dispersive = true;
    }
    Some(fit)
}

/// The dispersion slope `p1` (of `n = p0 + p1 u`, [`super::IndexModel::to_basis`]) that
/// best explains the pairs' per-wavelength log ratios when the index at 550 nm is known to be
/// `p0` (from the full spectra). The extremum shifts measure about `n n_g`, the product of the
/// index and the group index, so given `n` they pin the dispersion well, where alone they
/// cannot separate the two. `None` without enough bins.
pub fn fit_slope_at(pairs: &[PairBins], p0: f64) -> Option<f64> {
    let (_, bins) = chi2(pairs, super::IndexModel::constant(p0));
    if bins < 2 {
        return None;
    }
    let model = |p1: f64| super::IndexModel::from_basis([p0, p1, 0.0]);
    let mut p1 = 0.0;
    let h = 1e-6;
    for _ in 0..20 {
        let (mut jj, mut jr) = (0.0, 0.0);
        for p in pairs {
            for &(lambda, mean, se, n) in &p.bins {
                if n < MIN_BIN_VOTES {
                    continue;
                }
                let r0 = predicted_log_ratio(model(p1), lambda, p.x_ref, p.x_cur);
                let r1 = predicted_log_ratio(model(p1 + h), lambda, p.x_ref, p.x_cur);
                let j = (r1 - r0) / h / se;
                jj += j * j;
                jr += j * (mean - r0) / se;
            }
        }
        if jj.is_nan() || jj <= 0.0 {
            return None;
        }
        let step = (jr / jj).clamp(-0.1, 0.1);
        p1 += step;
        if libm::fabs(step) < 1e-7 {
            break;
        }
    }
    p1.is_finite().then_some(p1)
}

fn residuals_and_jacobian(
    pairs: &[PairBins],
    m: super::IndexModel,
    mut f: impl FnMut(f64, [f64; 2]),
) {
    let h = 1e-6;
    for p in pairs {
        for &(lambda, mean, se, n) in &p.bins {
            if n < MIN_BIN_VOTES {
                continue;
            }
            let r0 = predicted_log_ratio(m, lambda, p.x_ref, p.x_cur);
            let ra = predicted_log_ratio(
                super::IndexModel { a: m.a + h, ..m },
                lambda,
                p.x_ref,
                p.x_cur,
            );
            let rb = predicted_log_ratio(
                super::IndexModel {
                    b_um2: m.b_um2 + h,
                    ..m
                },
                lambda,
                p.x_ref,
                p.x_cur,
            );
            f((mean - r0) / se, [(ra - r0) / h / se, (rb - r0) / h / se]);
        }
    }
}

/// One Gauss-Newton step of the Cauchy fit and the inverse of its normal matrix (the
/// coefficients' covariance up to the reduced chi-square), or `None` unless that matrix is
/// positive definite.
fn normal_2d(pairs: &[PairBins], m: super::IndexModel) -> Option<([f64; 2], [[f64; 2]; 2])> {
    let mut h = Matrix2::<f64>::zeros();
    let mut g = Vector2::<f64>::zeros();
    residuals_and_jacobian(pairs, m, |r, j| {
        for i in 0..2 {
            g[i] += j[i] * r;
            for k in 0..2 {
                h[(i, k)] += j[i] * j[k];
            }
        }
    });
    let det = h.determinant();
    if !(det.is_finite() && det > 0.0) {
        return None;
    }
    let inv = h.try_inverse()?;
    let step = inv * g;
    Some((step.into(), inv.transpose().into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn est(index: f64, sigma: f64) -> PairEstimate {
        PairEstimate {
            index,
            sigma,
            votes: 1000.0,
        }
    }

    #[test]
    fn a_pair_that_locked_on_the_wrong_mode_is_left_out() {
        // Seed 4 of paper-sample1: the 10/30 pair's mode was wrong.
        let (n, _) = combine(&[
            est(1.4513, 0.0129),
            est(1.3694, 0.0054),
            est(1.3703, 0.0031),
        ])
        .expect("estimate");
        assert!((n - 1.3701).abs() < 5e-4, "{n}");
        let (n, _) = combine(&[est(1.4513, 0.0129), est(1.3703, 0.0031)]).expect("estimate");
        assert!((n - 1.3703).abs() < 1e-12, "{n}");
        let (n, s) = combine(&[est(1.37, 0.002), est(1.372, 0.002)]).expect("estimate");
        assert!((n - 1.371).abs() < 1e-12 && (s - 0.002 / 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn predicted_ratio_of_a_constant_index_is_eq_12() {
        let (xr, xc) = (0.03f64, 0.5f64);
        let n = 1.5;
        let l = predicted_log_ratio(super::super::IndexModel::constant(n), 550.0, xr, xc);
        let want = 0.5 * ((n * n - xc) / (n * n - xr)).ln();
        assert!((l - want).abs() < 1e-12);
    }
}
