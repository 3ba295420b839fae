//! The sweep's global state and the reductions between shards at each angle's end.
//!
//! Per angle: [`SweepSolver::begin_angle`], then every shard's rows, then the angle-end
//! phases in this order (each a shard-local pass whose results are merged here):
//! `tally` -> [`SweepSolver::set_votes`] and [`SweepSolver::set_fit_histogram`], `sums` ->
//! [`SweepSolver::set_window_sums`] and [`SweepSolver::set_schur`], `update` (which also
//! gives the pixels their orders where their extrema choose clearly), [`resolve_orders`]
//! (the ties, by their neighbours), then [`SweepSolver::end_angle`].
//! [`SweepSolver::end_angle_all`] runs them for shards on one thread; the pipeline runs each
//! phase on all cores.

use heapless::Vec as HVec;

use crate::optics::{Dispersion, FilmAtAngle, Indices, Polarization};

use super::index::{
    combine, fit_index, fit_slope_at, pair_estimate, IndexFit, PairBins, PairEstimate,
    PairGeometry, RatioHistogram, RatioSums, RatioWindows,
};
use super::refine::{BandCoef, Knot};
use super::shard::Shard;
use super::IndexModel;

/// Most bands per angle.
pub const MAX_BANDS: usize = 1024;
/// Most angles per sweep whose pair estimates are kept for the report.
pub const MAX_PAIRS: usize = 64;
/// A fit residual above this many times the pixels' noise (plus the floor) means the film
/// model does not explain the spectra.
pub const MISMATCH_RATIO: f64 = 1.5;
/// Absolute allowance of the mismatch test (reflectance).
pub const MISMATCH_FLOOR: f64 = 0.001;
/// An index step above this at an angle's end makes every pixel choose its order again.
pub const REORDER_INDEX_STEP: f64 = 0.01;
/// Largest index fall across the band a film model may have (rutile TiO2, among the most
/// dispersive transparent films, falls by about 0.3 over 420-720 nm; ZnS by 0.19).
pub const MAX_DISPERSION: f64 = 0.4;
/// Largest index fall across the band per unit of `n - 1` (at the band's centre): a low
/// index means little dispersion (Abbe numbers). Over 420-720 nm rutile falls by about 0.19
/// (n - 1) (the 0.3 of [`MAX_DISPERSION`]); approximate literature values, not measured
/// here: Nb2O5 0.15, ZnS 0.14, Ta2O5 0.08, polycarbonate 0.055, SiO2 and MgF2 0.02-0.025.
/// Measured: at a 1 nm band step the extremum shifts of a 400 nm film of index 1.38 called
/// for a fall of 0.17 (0.45 (n - 1)), the passes started from it settled on a Cauchy model
/// (index +0.0242, MAE 12.07 nm, nothing flagged).
pub const MAX_DISPERSION_PER_EXCESS: f64 = 0.25;
/// A full-spectrum step smaller than this (anywhere in the band) means the index model has
/// settled, and a richer one may be tried.
const SETTLED_INDEX_STEP: f64 = 0.02;
/// Largest index change (anywhere in the band) one full-spectrum Gauss-Newton step may make.
const MAX_INDEX_STEP: f64 = 0.15;

/// What the solver must know about a sweep before it starts.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepSpec {
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Band centres in streaming order, nm.
    pub bands_nm: HVec<f64, MAX_BANDS>,
    /// Band FWHM, nm (one per band).
    pub fwhm_nm: HVec<f64, MAX_BANDS>,
    /// Ambient index.
    pub ambient_index: f64,
    /// Substrate index at 550 nm, as reports give it.
    pub substrate_index: f64,
    /// The substrate's index against wavelength, which the model uses (a constant
    /// `substrate_index` for most samples; a glass's Sellmeier formula for a dispersive one).
    pub substrate: Dispersion,
    /// Polarisation of the measured light.
    pub polarization: Polarization,
    /// Film index search range.
    pub index_range: [f64; 2],
    /// Thickness search range, nm.
    pub thickness_range_nm: [f64; 2],
    /// What the solver may use (all on by default; off only to measure what each is worth).
    pub options: SolverOptions,
}

/// The solver's improvements over the published method, each switchable so its worth can be
/// measured (`filmscope eval --ablate ...`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SolverOptions {
    /// Full-spectrum Gauss-Newton refinement of the thickness (off: extrema only).
    pub refine: bool,
    /// The half-order reflection phase of films above the substrate's index (off: integer
    /// orders, as the paper's eq. 9).
    pub half_order: bool,
    /// Neighbours decide orders a pixel alone cannot (off: such pixels stay unresolved).
    pub neighbours: bool,
    /// Extrema placed to a fraction of a band (off: at the band centre).
    pub subband: bool,
    /// About how many pixels keep the shared index's sums, the rest only their own
    /// ([`super::fit_row::IndexSampling`]; 32 bytes a pixel that keeps them): the index's
    /// step is theirs, and so are the ratio votes, the RMS median and the pooled noise.
    /// Every pixel of a sensor with fewer than twice as many.
    pub index_pixels: usize,
    /// The per-sample work compiled for the widest vector instructions the CPU has (AVX2
    /// and FMA on x86-64, [`crate::simd::wide`]); off: the portable build's. The same
    /// results bit for bit either way.
    pub wide_simd: bool,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            refine: true,
            half_order: true,
            neighbours: true,
            subband: true,
            index_pixels: super::fit_row::INDEX_PIXELS,
            wide_simd: true,
        }
    }
}

impl SweepSpec {
    /// The same sweep on the substrate `substrate` (`substrate_index` becomes its index at
    /// 550 nm).
    pub fn with_substrate(mut self, substrate: Dispersion) -> Self {
        self.substrate_index = substrate.index_at(550.0);
        self.substrate = substrate;
        self
    }

    /// Wavelength of a fractional band position (linear between band centres).
    #[inline]
    pub fn wavelength_at(&self, band: f32) -> f64 {
        let b = self.bands_nm.as_slice();
        if b.len() < 2 {
            return b.first().copied().unwrap_or(f64::NAN);
        }
        let x = f64::from(band).clamp(0.0, (b.len() - 1) as f64);
        let i = (x as usize).min(b.len() - 2);
        b[i] + (b[i + 1] - b[i]) * (x - i as f64)
    }

    /// `(n_ambient sin theta)^2`.
    pub fn x_of(&self, incidence_deg: f64) -> f64 {
        let s = self.ambient_index * libm::sin(incidence_deg.to_radians());
        s * s
    }

    /// Which pixels keep the shared index's sums ([`super::fit_row::IndexSampling`]).
    pub fn index_sampling(&self) -> super::fit_row::IndexSampling {
        super::fit_row::IndexSampling::for_sensor(
            self.width,
            self.height,
            self.options.index_pixels,
        )
    }

    /// The wavelength range in which the tracker reliably finds extrema (clear of the
    /// smoothing window at either end).
    pub fn reliable_range_nm(&self) -> [f64; 2] {
        let a = self.wavelength_at(crate::track::WINDOW as f32);
        let b = self.wavelength_at(self.last_reliable_band());
        [a.min(b), a.max(b)]
    }

    /// The last band of [`SweepSpec::reliable_range_nm`]: the smoothing window's length
    /// before the last band, never before its first, [`crate::track::WINDOW`] (a sweep of
    /// fewer than `2 WINDOW + 1` bands has that one band: [`crate::track::ExtremaHead`]
    /// counts the range so).
    pub fn last_reliable_band(&self) -> f32 {
        let w = crate::track::WINDOW as f32;
        (self.bands_nm.len() as f32 - 1.0 - w).max(w)
    }
}

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
    /// (2,2)` of the basis coefficients ([`IndexModel::to_basis`]).
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

    /// Cholesky factor of the leading `k x k` block, or `None` if it is singular.
    fn cholesky(&self, k: usize) -> Option<[[f64; 3]; 3]> {
        let mut l = [[0.0f64; 3]; 3];
        for i in 0..k {
            for j in 0..=i {
                let dot: f64 = l[i][..j].iter().zip(&l[j][..j]).map(|(a, b)| a * b).sum();
                let v = self.entry(i, j) - dot;
                if i == j {
                    if v <= self.entry(i, i) * 1e-12 || v <= 0.0 {
                        return None;
                    }
                    l[i][i] = libm::sqrt(v);
                } else {
                    l[i][j] = v / l[j][j];
                }
            }
        }
        Some(l)
    }

    /// Solves `L L^T x = rhs` in the first `k` coefficients.
    fn solve(l: &[[f64; 3]; 3], k: usize, rhs: [f64; 3]) -> [f64; 3] {
        let mut y = [0.0; 3];
        for i in 0..k {
            let mut v = rhs[i];
            for m in 0..i {
                v -= l[i][m] * y[m];
            }
            y[i] = v / l[i][i];
        }
        let mut x = [0.0; 3];
        for i in (0..k).rev() {
            let mut v = y[i];
            for m in i + 1..k {
                v -= l[m][i] * x[m];
            }
            x[i] = v / l[i][i];
        }
        x
    }

    /// The step in the first `k` basis coefficients (the others held) and the squared-error
    /// reduction it predicts, or `None` if that block is singular.
    pub fn step(&self, k: usize) -> Option<([f64; 3], f64)> {
        let l = self.cholesky(k)?;
        let x = Self::solve(&l, k, self.g);
        let gain = (0..k).map(|i| x[i] * self.g[i]).sum();
        Some((x, gain))
    }

    /// The inverse of the leading `k x k` block (zero outside it): times the residual
    /// variance, the covariance of the first `k` coefficients with every pixel's thickness
    /// free. `None` if the block is singular.
    pub fn inverse(&self, k: usize) -> Option<[[f64; 3]; 3]> {
        let l = self.cholesky(k)?;
        let mut inv = [[0.0; 3]; 3];
        for j in 0..k {
            let mut unit = [0.0; 3];
            unit[j] = 1.0;
            let column = Self::solve(&l, k, unit);
            for (row, v) in inv.iter_mut().zip(column).take(k) {
                row[j] = v;
            }
        }
        Some(inv)
    }
}

/// Least change an extra index term must make to the index somewhere in the band (against
/// the simpler model at its best): the index accuracy filmscope claims (issue targets
/// 0.003). A thin film measures its index through the reflectance level, so a small
/// wavelength-dependent calibration error shows up as a statistically significant but
/// physically meaningless term (measured on an 80 nm constant-index film: 0.0015).
pub const MIN_TERM_EFFECT: f64 = 0.003;

/// Chi-square gain (in units of the residual variance) an extra index term must bring to
/// enter the full-spectrum index model: a 5-sigma improvement.
pub const SPECTRAL_TERM_CHI2: f64 = 25.0;

/// What one angle added, for progress reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AngleReport {
    /// The angle, degrees.
    pub incidence_deg: f64,
    /// The index after this angle (if any yet).
    pub index: Option<f64>,
    /// Its standard error.
    pub index_sigma: f64,
    /// The extrema-only pair estimate of this angle against the reference angle.
    pub pair: Option<PairEstimate>,
    /// Whether full-spectrum sums were available at this angle's end.
    pub refined: bool,
    /// The index step (at 550 nm) the full-spectrum sums would take.
    pub spectral_index_step: f64,
    /// Whether the index came from the full spectra (else from the extremum shifts).
    pub spectral_index: bool,
    /// Terms of the index model after this angle (0: no index yet; above 1: dispersive).
    pub index_terms: usize,
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

/// The global state of one sweep.
#[derive(Clone, Debug)]
pub struct SweepSolver {
    spec: SweepSpec,
    index: Option<IndexModel>,
    /// Covariance of the index's basis coefficients ([`IndexModel::to_basis`]; zero beyond
    /// the model's terms), when an estimate gave one: its `(0, 0)` is the index sigma's
    /// square.
    index_cov: Option<[[f64; 3]; 3]>,
    anchor_deg: Option<f64>,
    angle_deg: f64,
    angles_done: usize,
    pair_geom: Option<PairGeometry>,
    window: Option<RatioWindows>,
    pairs: HVec<PairEstimate, MAX_PAIRS>,
    pair_bins: HVec<PairBins, MAX_PAIRS>,
    fit: Option<IndexFit>,
    last_pair: Option<PairEstimate>,
    rms_median: Option<f32>,
    noise_median: Option<f32>,
    pending_dp: [f64; 3],
    /// An index from outside the sweep's own evidence (the full spectra of a pixel sample)
    /// that the next angle end takes ([`SweepSolver::set_external_index`]).
    external: Option<IndexModel>,
    /// Whether an external index was ever given (then it, not the extremum shifts, is judged).
    external_index: bool,
    next_index: Option<IndexModel>,
    refined_steps: usize,
    last_refined: bool,
    residual_sigma: Option<f64>,
    spectral_dn: f64,
    spectral_index: bool,
    held_index: bool,
    spectral_gains: [f64; 3],
    spectral_candidate: Option<IndexModel>,
}

impl SweepSolver {
    /// A solver for a sweep of `spec`; `prior` seeds the index (e.g. the last sweep's) so the
    /// full-spectrum refinement can start at the first angle.
    pub fn new(spec: SweepSpec, prior: Option<IndexModel>) -> Self {
        Self {
            spec,
            index: prior,
            index_cov: None,
            anchor_deg: None,
            angle_deg: f64::NAN,
            angles_done: 0,
            pair_geom: None,
            window: None,
            pairs: HVec::new(),
            pair_bins: HVec::new(),
            fit: None,
            last_pair: None,
            rms_median: None,
            noise_median: None,
            pending_dp: [0.0; 3],
            external: None,
            external_index: false,
            next_index: None,
            refined_steps: 0,
            last_refined: false,
            residual_sigma: None,
            spectral_dn: 0.0,
            spectral_index: false,
            held_index: false,
            spectral_gains: [f64::NAN; 3],
            spectral_candidate: None,
        }
    }

    /// Takes the index from the full spectra (Gauss-Newton on the pooled sums, each pixel's
    /// thickness eliminated) instead of the extremum shifts. Needs a prior index (the
    /// linearisation point); the pipeline turns it on for a second pass over a capture whose
    /// first pass the extremum-shift model did not explain ([`SweepSolver::model_mismatch`]),
    /// and a production line for the sweeps after one that needed it.
    pub fn with_spectral_index(mut self) -> Self {
        self.spectral_index = self.index.is_some();
        self
    }

    /// The index this angle's end takes, from outside the sweep's own evidence (the full
    /// spectra of a pixel sample, refitted as each angle completes): it replaces the
    /// extremum-shift estimate, and pixels follow it as they follow any index step.
    pub fn set_external_index(&mut self, index: IndexModel) {
        self.external = Some(index);
        self.external_index = true;
    }

    /// Holds the prior index for the whole sweep (the extremum-shift fit is still made and
    /// reported): for a second pass over data whose first pass estimated the index from every
    /// angle.
    pub fn with_held_index(mut self) -> Self {
        self.held_index = self.index.is_some();
        self
    }

    /// Whether the index comes from the full spectra.
    pub fn spectral_index(&self) -> bool {
        self.spectral_index
    }

    /// The index after the last full-spectrum step (whether or not it was taken): where a
    /// further pass starts.
    pub fn spectral_candidate(&self) -> Option<IndexModel> {
        self.spectral_candidate
    }

    /// The largest chi-square gains of the sweep's full-spectrum steps with 1, 2 and 3 index
    /// terms (in units of the residual variance; NaN where not computed).
    pub fn spectral_gains(&self) -> [f64; 3] {
        self.spectral_gains
    }

    /// The sweep's description.
    pub fn spec(&self) -> &SweepSpec {
        &self.spec
    }

    /// The current index model, if one has been estimated.
    pub fn index(&self) -> Option<IndexModel> {
        self.index
    }

    /// Standard error of the index.
    pub fn index_sigma(&self) -> f64 {
        self.index_cov
            .map_or(f64::INFINITY, |c| libm::sqrt(c[0][0]))
    }

    /// Covariance of the index's basis coefficients (`p0` the index at 550 nm, then the
    /// dispersion terms; zero beyond the model's terms), when an estimate gave one: what the
    /// index's own uncertainty adds to each pixel's thickness ([`super::refine::GnSums::thickness_sigma_nm`]).
    /// `None` when unknown or not finite.
    pub fn index_covariance(&self) -> Option<[[f64; 3]; 3]> {
        self.index_cov
            .filter(|c| c.iter().flatten().all(|v| v.is_finite()))
    }

    /// Full-spectrum index steps taken.
    pub fn refined_steps(&self) -> usize {
        self.refined_steps
    }

    /// Angles completed.
    pub fn angles_done(&self) -> usize {
        self.angles_done
    }

    /// The typical per-pixel RMS residual of the full-spectrum fit (the noise level).
    pub fn residual_sigma(&self) -> Option<f64> {
        self.residual_sigma
    }

    /// Fills `out` (one entry per band, caller-owned: about 2.3 KB a band, room for the
    /// passband's Simpson nodes) with the band
    /// models of the current angle at the current index; all `None` until an index exists.
    pub fn band_models(&self, out: &mut [Option<BandCoef>]) {
        let d_max = self.table_range_nm()[1];
        for (i, o) in out.iter_mut().enumerate() {
            *o = match (self.index, self.spec.bands_nm.get(i)) {
                (Some(index), Some(&l)) => BandCoef::new(
                    index,
                    self.spec.ambient_index,
                    self.spec.substrate.index_at(l),
                    self.spec.polarization,
                    self.angle_deg,
                    l,
                    self.spec.fwhm_nm[i],
                    d_max,
                ),
                _ => None,
            };
        }
    }

    /// The thicknesses the band models are tabulated over: the search range widened by an
    /// interference
    /// order at the longest band and lowest index either side (the neighbouring orders'
    /// misfits look there). A thickness outside it has its models computed per sample.
    pub fn table_range_nm(&self) -> [f64; 2] {
        let [lo, hi] = self.spec.thickness_range_nm;
        let [_, l_max] = self.band_span_nm();
        let step = 1.2 * l_max / (2.0 * self.spec.index_range[0].max(1.0));
        [lo - step, hi + step]
    }

    /// Tabulates the band models (in band order, as many as `knots` holds; the rest are
    /// computed per sample), so a sample's full-spectrum sums cost interpolations instead of
    /// an Airy quadrature (see [`BandCoef::eval`]). `models` may be a run of consecutive
    /// bands whose knots start at `first` in the angle's table (`knots` the table from there
    /// on): runs split where their knots do ([`SweepSolver::band_knots`]) can be tabulated on
    /// as many threads.
    pub fn tabulate(&self, models: &mut [Option<BandCoef>], knots: &mut [Knot], first: usize) {
        let range = self.table_range_nm();
        let mut used = 0;
        for c in models.iter_mut().flatten() {
            let Some((_, n)) = c.knots_for(range) else {
                continue;
            };
            if used + n > knots.len() {
                break;
            }
            c.tabulate(range, first + used, &mut knots[used..used + n]);
            used += n;
        }
    }

    /// Knots each band of `models` needs ([`SweepSolver::tabulate`]; 0 for a band without a
    /// model or a table).
    pub fn band_knots(&self, models: &[Option<BandCoef>], out: &mut [usize]) {
        let range = self.table_range_nm();
        for (o, c) in out.iter_mut().zip(models) {
            *o = c
                .as_ref()
                .and_then(|c| c.knots_for(range))
                .map_or(0, |(_, n)| n);
        }
    }

    /// The reference (first) angle, degrees.
    pub fn anchor_deg(&self) -> Option<f64> {
        self.anchor_deg
    }

    /// The current angle, degrees.
    pub fn angle_deg(&self) -> f64 {
        self.angle_deg
    }

    /// The pair geometry of the current angle against the reference, if votes are taken.
    pub fn pair_geometry(&self) -> Option<&PairGeometry> {
        self.pair_geom.as_ref()
    }

    /// The accepted ratio windows of the current pair.
    pub fn ratio_window(&self) -> Option<&RatioWindows> {
        self.window.as_ref()
    }

    /// The median RMS residual of the last angle (for outlier rejection).
    pub fn rms_median(&self) -> Option<f32> {
        self.rms_median
    }

    /// The index step decided at this angle's end, in basis coefficients
    /// ([`IndexModel::to_basis`]).
    pub fn pending_index_step(&self) -> [f64; 3] {
        self.pending_dp
    }

    /// The index model shards must use in `update` (the one after this angle).
    pub fn next_index(&self) -> Option<IndexModel> {
        self.next_index
    }

    /// Order offset of the peaks (0 or 1/2) at `incidence_deg` with index `index`.
    pub fn peak_offset(&self, index: IndexModel, incidence_deg: f64) -> f64 {
        if !self.spec.options.half_order {
            return 0.0;
        }
        let mid = self.spec.bands_nm[self.spec.bands_nm.len() / 2];
        FilmAtAngle::new(
            Indices {
                ambient: self.spec.ambient_index,
                film: index.at(mid),
                substrate: self.spec.substrate.index_at(mid),
            },
            incidence_deg,
            self.spec.polarization,
        )
        .map_or(0.0, |f| f.peak_phase_offset())
    }

    /// Starts an angle (then fill the band models with [`SweepSolver::band_models`]).
    pub fn begin_angle(&mut self, incidence_deg: f64) {
        self.angle_deg = incidence_deg;
        self.pair_geom = self.anchor_deg.and_then(|a| {
            PairGeometry::new(
                self.spec.ambient_index,
                a,
                incidence_deg,
                self.spec.index_range,
                self.band_span_nm(),
            )
        });
        self.window = None;
        self.last_pair = None;
        self.next_index = None;
        self.pending_dp = [0.0; 3];
    }

    fn band_span_nm(&self) -> [f64; 2] {
        let b = &self.spec.bands_nm;
        let (lo, hi) = b
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &l| {
                (lo.min(l), hi.max(l))
            });
        [lo, hi]
    }

    /// The index fit over all pairs so far (model choice, chi-squares).
    pub fn index_fit(&self) -> Option<IndexFit> {
        self.fit
    }

    /// Merged votes of the current pair: fixes the window around their mode.
    pub fn set_votes(&mut self, hist: &RatioHistogram) {
        self.window = self.pair_geom.as_ref().and_then(|g| hist.windows(g));
    }

    /// Merged window sums: the pair's extrema-only index estimate.
    pub fn set_window_sums(&mut self, sums: &RatioSums) {
        let est = self.pair_geom.as_ref().and_then(|g| pair_estimate(g, sums));
        if let (Some(e), Some(g)) = (est, self.pair_geom.as_ref()) {
            let _ = self.pairs.push(e);
            let _ = self.pair_bins.push(PairBins::from_sums(g, sums));
        }
        self.last_pair = est;
    }

    /// Merged fit-quality histogram.
    pub fn set_fit_histogram(&mut self, hist: &FitStats) {
        if let Some(m) = hist.rms.median() {
            self.rms_median = Some(m);
        }
        if let Some(m) = hist.noise.median() {
            self.noise_median = Some(m);
        }
    }

    /// The image's typical noise (median of the pixels' own estimates at the last angle).
    pub fn noise_sigma(&self) -> Option<f32> {
        self.noise_median
    }

    /// Merged Schur sums: decides the index step and the index shards use in `update`.
    ///
    /// By default the index comes from the pooled extremum shifts ([`super::index`]): they
    /// measure it through fringe positions alone, which a model's amplitude errors cannot
    /// bias, and the full-spectrum sums pin each pixel's thickness. With
    /// [`SweepSolver::with_spectral_index`] the sums move the index too: a Gauss-Newton step in
    /// the basis coefficients with every pixel's thickness eliminated, with as many terms as
    /// the data ask for (a term enters only if it lowers the chi-square by
    /// [`SPECTRAL_TERM_CHI2`]; terms once in stay). When the index moves, each refined pixel's
    /// thickness follows through its cross terms (`update`).
    pub fn set_schur(&mut self, s: &SchurSums) {
        self.last_refined = false;
        let mut spectral_next = None;
        if s.pixels >= 16.0 && s.h[0] > 0.0 && s.samples > s.pixels * 2.0 {
            let steps = [s.step(1), s.step(2), s.step(3)];
            let full = steps[2].or(steps[1]).or(steps[0]);
            let dof = (s.samples - s.pixels - 3.0).max(1.0);
            let sigma2 = full.map_or(s.sse / dof, |(_, gain)| (s.sse - gain).max(0.0) / dof);
            let gains = steps.map(|st| st.map_or(f64::NAN, |(_, gain)| gain / sigma2.max(1e-30)));
            // Terms are added only once the simpler model has settled (its own step is
            // small), so that a richer model is compared with the simpler one at its best
            // rather than used to absorb a linearisation far from it, and only if the index
            // it gives is physical (normal dispersion across the band).
            let mut terms = self.index.map_or(1, |m| m.terms()).clamp(1, 3);
            // The pixels' thicknesses must have stepped twice too (three angles in): a
            // richer index would otherwise absorb their starting error, and two angles
            // barely tell a thin film's index from its thickness.
            let settled = self.refined_steps > 1
                && steps[terms - 1]
                    .is_some_and(|(x, _)| self.max_index_change(x) < SETTLED_INDEX_STEP);
            while settled && terms < 3 && gains[terms] - gains[terms - 1] > SPECTRAL_TERM_CHI2 {
                let worth = match (self.index, steps[terms]) {
                    (Some(index), Some((x, _))) => {
                        let next = index.moved(x);
                        self.physical(next) && self.term_effect(next, terms) >= MIN_TERM_EFFECT
                    }
                    _ => false,
                };
                if !worth {
                    break;
                }
                terms += 1;
            }
            if let Some((mut x, gain)) = steps[terms - 1] {
                let after = if self.spectral_index {
                    s.sse - gain
                } else {
                    s.sse
                };
                let dof = (s.samples - s.pixels - terms as f64).max(1.0);
                self.residual_sigma = Some(libm::sqrt(after.max(0.0) / dof));
                self.spectral_dn = x[0];
                for (kept, g) in self.spectral_gains.iter_mut().zip(gains) {
                    if kept.is_nan() || g > *kept {
                        *kept = g;
                    }
                }
                self.last_refined = true;
                self.refined_steps += 1;
                if let Some(index) = self.index {
                    let scale = self.max_index_change(x) / MAX_INDEX_STEP;
                    if scale > 1.0 {
                        x = x.map(|v| v / scale);
                    }
                    let mut next = index.moved(x);
                    // A term that no longer bends the index measurably (it entered while
                    // the pixels' thicknesses were still far from their best) leaves again;
                    // at half the entry threshold, so it cannot flicker in and out.
                    while next.terms() > 1
                        && self.term_effect(next, next.terms() - 1) < 0.5 * MIN_TERM_EFFECT
                    {
                        next = next.truncated(next.terms() - 1);
                    }
                    if self.spectral_index && self.physical(next) {
                        spectral_next = Some(next);
                        self.spectral_candidate = Some(next);
                        // The index at 550 nm with the other terms free, not held: with a
                        // dispersion term in, a thin film's index level and slope trade
                        // (measured: n 1.6 / 50 nm on 1.52, sigma 0.0003 from the diagonal
                        // alone against an error of 0.006-0.012 on three seeds of five).
                        let cov = s.inverse(next.terms()).unwrap_or_else(|| {
                            let mut c = [[0.0; 3]; 3];
                            c[0][0] = 1.0 / s.h[0].max(1e-30);
                            c
                        });
                        self.index_cov = Some(cov.map(|row| row.map(|v| v * sigma2)));
                    } else {
                        // No usable step from the linearisation: where a fresh pass starts.
                        self.spectral_candidate = self.spectral_start(index, s);
                    }
                }
            }
        }
        let (range, span) = (self.spec.index_range, self.band_span_nm());
        self.fit = combine(&self.pairs).and_then(|c| fit_index(&self.pair_bins, c, range, span));
        self.next_index = if let Some(m) = self.external.take() {
            Some(m)
        } else if self.held_index {
            self.index
        } else if self.spectral_index {
            spectral_next.or(self.index)
        } else {
            match self.fit {
                Some(f) => {
                    let mut cov = [[0.0; 3]; 3];
                    cov[0][0] = f.sigma * f.sigma;
                    self.index_cov = Some(cov);
                    Some(f.model)
                }
                None => self.index,
            }
        };
        self.pending_dp = match (self.index, self.next_index) {
            (Some(a), Some(b)) => {
                let (pa, pb) = (a.to_basis(), b.to_basis());
                [pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]]
            }
            _ => [0.0; 3],
        };
    }

    /// Where a full-spectrum pass should start after an extremum-shift pass linearised at
    /// `index`: the index at 550 nm from the full spectra (a one-term step, unclamped: far from
    /// the truth the extremum shifts give about `sqrt(n n_g)`, not `n`), and the dispersion
    /// slope the extremum shifts call for given that index ([`fit_slope_at`]), if normal.
    fn spectral_start(&self, index: IndexModel, s: &SchurSums) -> Option<IndexModel> {
        let (x, _) = s.step(1)?;
        let p0 = index.at(super::BASIS_NM) + x[0];
        let [lo, hi] = self.spec.index_range;
        if !(lo..=hi).contains(&p0) {
            return None;
        }
        // The slope only if the model it makes is physical ([`Self::physical`]: measured, at a
        // 1 nm band step the shifts of a 400 nm film of index 1.38 asked for a fall of 0.17
        // across the band, and the passes from it settled there).
        let sloped = fit_slope_at(&self.pair_bins, p0)
            .filter(|p1| *p1 > 0.0 && *p1 < 0.5)
            .map(|p1| IndexModel::from_basis([p0, p1, 0.0]))
            .filter(|m| self.physical(*m));
        Some(sloped.unwrap_or(IndexModel::from_basis([p0, 0.0, 0.0])))
    }

    /// Whether an index model is one a transparent film can have over the band: inside the
    /// search range, falling with wavelength, by at most [`MAX_DISPERSION`] and
    /// [`MAX_DISPERSION_PER_EXCESS`] times `n - 1`.
    fn physical(&self, m: IndexModel) -> bool {
        let [lo, hi] = self.band_span_nm();
        let [n_lo, n_hi] = self.spec.index_range;
        let at = |i: i32| m.at(lo + (hi - lo) * f64::from(i) / 16.0);
        (0..=16).all(|i| (n_lo..=n_hi).contains(&at(i)))
            && (0..16).all(|i| at(i + 1) <= at(i) + 1e-4)
            && at(0) - at(16) <= MAX_DISPERSION.min(MAX_DISPERSION_PER_EXCESS * (at(8) - 1.0))
    }

    /// How much basis term `k` (1 or 2) of `index` bends it across the band beyond what the
    /// lower terms could follow: the slope term's rise over the band, the quadratic term's
    /// bow against the chord.
    fn term_effect(&self, index: IndexModel, k: usize) -> f64 {
        let [lo, hi] = self.band_span_nm();
        let span = libm::fabs(IndexModel::basis_u(lo) - IndexModel::basis_u(hi));
        let p = index.to_basis();
        match k {
            1 => libm::fabs(p[1]) * span,
            2 => libm::fabs(p[2]) * span * span / 4.0,
            _ => 0.0,
        }
    }

    /// The largest index change over the band of a step `x` in basis coefficients.
    fn max_index_change(&self, x: [f64; 3]) -> f64 {
        let [lo, hi] = self.band_span_nm();
        let mut worst = 0.0f64;
        for i in 0..=8 {
            let u = IndexModel::basis_u(lo + (hi - lo) * f64::from(i) / 8.0);
            worst = worst.max(libm::fabs(x[0] + x[1] * u + x[2] * u * u));
        }
        worst
    }

    /// Whether the index moved so much at this angle's end (more than
    /// [`REORDER_INDEX_STEP`]) that every pixel chooses its order again (its sums restart).
    pub fn reorders(&self) -> bool {
        libm::fabs(self.pending_dp[0]) > REORDER_INDEX_STEP
    }

    /// Whether the full-spectrum fit is much worse than the noise: residual RMS above
    /// [`MISMATCH_RATIO`] times the pixels' median noise plus [`MISMATCH_FLOOR`]. The film
    /// model (index, dispersion) then does not explain the spectra: every pixel is flagged
    /// [`super::flags::MODEL_MISMATCH`] and its confidence scaled down.
    pub fn model_mismatch(&self) -> bool {
        if self.held_index || self.external_index {
            // A held or external index was judged where it was fitted (the full spectra of a pixel
            // sample, against their own noise, [`super::sample`]); the pixels' typical
            // residual here also carries the per-pixel model's quadrature error, which a
            // thick, high-index film under a wide passband makes larger than the noise.
            return false;
        }
        match (self.residual_sigma, self.noise_median) {
            (Some(r), Some(n)) => r > MISMATCH_RATIO * f64::from(n) + MISMATCH_FLOOR,
            _ => false,
        }
    }

    /// The index step the full-spectrum sums alone would take (a consistency check).
    pub fn spectral_index_step(&self) -> f64 {
        self.spectral_dn
    }

    /// Ends the angle (after every shard's `update`).
    pub fn end_angle(&mut self) -> AngleReport {
        if self.anchor_deg.is_none() {
            self.anchor_deg = Some(self.angle_deg);
        }
        self.index = self.next_index.or(self.index);
        self.angles_done += 1;
        AngleReport {
            incidence_deg: self.angle_deg,
            index: self.index.map(|m| m.at(super::BASIS_NM)),
            index_sigma: self.index_sigma(),
            pair: self.last_pair,
            refined: self.last_refined,
            spectral_index_step: self.spectral_dn,
            spectral_index: self.spectral_index,
            index_terms: self.index.map_or(0, |m| m.terms()),
        }
    }

    /// Runs the angle-end phases over shards on this thread (the pipeline runs the same
    /// phases on all cores, merging the per-row sums in row order, so the sums are identical):
    /// [`SweepSolver::end_tally`], [`SweepSolver::end_sums`], [`SweepSolver::end_update`].
    pub fn end_angle_all(&mut self, shards: &mut [Shard<'_>]) -> AngleReport {
        self.end_tally(shards);
        self.end_sums(shards);
        self.end_update(shards)
    }

    /// Angle-end phase 1 on this thread: every shard's votes and fit statistics
    /// ([`Shard::tally`]).
    pub fn end_tally(&mut self, shards: &[Shard<'_>]) {
        let mut hist = RatioHistogram::default();
        let mut fit = FitStats::default();
        for s in shards {
            let (h, f) = s.tally(self);
            hist.merge(&h);
            fit.merge(&f);
        }
        self.set_votes(&hist);
        self.set_fit_histogram(&fit);
    }

    /// Angle-end phase 2 on this thread: the window and Schur sums ([`Shard::sums`]).
    pub fn end_sums(&mut self, shards: &[Shard<'_>]) {
        let mut sums = RatioSums::default();
        let mut schur = SchurSums::default();
        for s in shards {
            s.sums(self, |_, w, r| {
                sums.merge(&w);
                schur.merge(&r);
            });
        }
        self.set_window_sums(&sums);
        self.set_schur(&schur);
    }

    /// Angle-end phase 3 on this thread: every pixel's update ([`Shard::update`]), the ties
    /// resolved, and the angle ended.
    pub fn end_update(&mut self, shards: &mut [Shard<'_>]) -> AngleReport {
        for s in shards.iter_mut() {
            s.update(self, None, |_| {});
        }
        // Every pixel as a possible tie: those with an order are skipped.
        resolve_orders(self, shards, |_, pixels| 0..pixels);
        self.end_angle()
    }
}

/// Order resolution of the pixels [`Shard::update`] left tied, over shards in row order,
/// forward then backward, each shard seeing its neighbours' edge rows: the same result as one
/// shard over the whole image. `ties(shard, pixels)` lists the tied pixels of shard number
/// `shard` (of `pixels`) in increasing order; pixels with an order are skipped, so `0..pixels`
/// will do.
pub fn resolve_orders<I: DoubleEndedIterator<Item = usize>>(
    solver: &SweepSolver,
    shards: &mut [Shard<'_>],
    ties: impl Fn(usize, usize) -> I,
) {
    let w = solver.spec().width;
    let mut edge = [0f32; 4096];
    let mut have = false;
    let mut pending = false;
    for (k, s) in shards.iter_mut().enumerate() {
        let above = (have && w <= edge.len()).then(|| &edge[..w]);
        pending |= s.resolve_forward(solver, above, ties(k, s.pixels.len()));
        if w <= edge.len() {
            s.edge_row(true, &mut edge[..w]);
            have = true;
        }
    }
    if !pending {
        return;
    }
    have = false;
    for (k, s) in shards.iter_mut().enumerate().rev() {
        let below = (have && w <= edge.len()).then(|| &edge[..w]);
        s.resolve_backward(solver, below, ties(k, s.pixels.len()).rev());
        if w <= edge.len() {
            s.edge_row(false, &mut edge[..w]);
            have = true;
        }
    }
}

/// A sweep of `width` x `height` pixels on the paper's rig (420-720 nm in 2 nm bands, 4 nm
/// FWHM, s-polarised, a film on 1.52 glass), for unit tests.
#[cfg(test)]
pub(crate) fn paper_rig_spec(width: usize, height: usize) -> SweepSpec {
    let mut s = SweepSpec {
        width,
        height,
        bands_nm: HVec::new(),
        fwhm_nm: HVec::new(),
        ambient_index: 1.0,
        substrate_index: 1.52,
        substrate: Dispersion::constant(1.52),
        polarization: crate::optics::Polarization::S,
        index_range: [1.2, 2.8],
        thickness_range_nm: [30.0, 2000.0],
        options: SolverOptions::default(),
    };
    for b in 0..151 {
        let _ = s.bands_nm.push(420.0 + 2.0 * f64::from(b));
        let _ = s.fwhm_nm.push(4.0);
    }
    s
}
