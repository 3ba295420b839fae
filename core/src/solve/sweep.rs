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
//!
//! Shards read only the solver's [`SweepContext`] (the solver derefs to it), so this module
//! imports [`Shard`] and not the other way round. [`SweepSpec`], [`SolverOptions`] and the
//! shards' sums live in their own modules and are re-exported here.

use heapless::Vec as HVec;

use super::context::SweepContext;
pub use super::context::{MISMATCH_FLOOR, MISMATCH_RATIO, REORDER_INDEX_STEP};
use super::index::{
    combine, fit_index, fit_slope_at, pair_estimate, IndexFit, PairBins, PairEstimate,
    PairGeometry, RatioHistogram, RatioSums,
};
use super::refine::{BandCoef, FilmTerms, Knot};
use super::shard::Shard;
pub use super::spec::{SolverOptions, SweepSpec, MAX_BANDS};
pub use super::sums::{FitStats, RmsHistogram, SchurSums};
use super::IndexModel;

/// Most angles per sweep whose pair estimates are kept for the report.
pub const MAX_PAIRS: usize = 64;
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

/// The global state of one sweep: the context the shards read ([`SweepContext`], which the
/// solver derefs to) and the evidence the angle ends pool.
#[derive(Clone, Debug)]
pub struct SweepSolver {
    ctx: SweepContext,
    angles_done: usize,
    pairs: HVec<PairEstimate, MAX_PAIRS>,
    pair_bins: HVec<PairBins, MAX_PAIRS>,
    fit: Option<IndexFit>,
    last_pair: Option<PairEstimate>,
    /// An index from outside the sweep's own evidence (the full spectra of a pixel sample)
    /// that the next angle end takes ([`SweepSolver::set_external_index`]).
    external: Option<IndexModel>,
    refined_steps: usize,
    last_refined: bool,
    spectral_dn: f64,
    spectral_index: bool,
    spectral_gains: [f64; 3],
    spectral_candidate: Option<IndexModel>,
    /// The thicknesses the pixels' models are read at this angle ([`SweepSolver::set_table_span`]).
    table_span: Option<[f64; 2]>,
    /// The film's absorption and the polariser's leak the pixels' models carry
    /// ([`SweepSolver::with_film_terms`]).
    film_terms: FilmTerms,
}

impl core::ops::Deref for SweepSolver {
    type Target = SweepContext;

    fn deref(&self) -> &SweepContext {
        &self.ctx
    }
}

impl SweepSolver {
    /// A solver for a sweep of `spec`; `prior` seeds the index (e.g. the last sweep's) so the
    /// full-spectrum refinement can start at the first angle.
    pub fn new(spec: SweepSpec, prior: Option<IndexModel>) -> Self {
        Self {
            ctx: SweepContext::new(spec, prior),
            angles_done: 0,
            pairs: HVec::new(),
            pair_bins: HVec::new(),
            fit: None,
            last_pair: None,
            external: None,
            refined_steps: 0,
            last_refined: false,
            spectral_dn: 0.0,
            spectral_index: false,
            spectral_gains: [f64::NAN; 3],
            spectral_candidate: None,
            table_span: None,
            film_terms: FilmTerms::NONE,
        }
    }

    /// The state the shards read ([`SweepContext`]; also what the solver derefs to): a
    /// snapshot of it is all a shard's worker needs of the solver.
    pub fn context(&self) -> &SweepContext {
        &self.ctx
    }

    /// Takes the index from the full spectra (Gauss-Newton on the pooled sums, each pixel's
    /// thickness eliminated) instead of the extremum shifts. Needs a prior index (the
    /// linearisation point); the pipeline turns it on for a second pass over a capture whose
    /// first pass the extremum-shift model did not explain ([`SweepContext::model_mismatch`]),
    /// and a production line for the sweeps after one that needed it.
    pub fn with_spectral_index(mut self) -> Self {
        self.spectral_index = self.ctx.index.is_some();
        self
    }

    /// The index this angle's end takes, from outside the sweep's own evidence (the full
    /// spectra of a pixel sample, refitted as each angle completes): it replaces the
    /// extremum-shift estimate, and pixels follow it as they follow any index step.
    pub fn set_external_index(&mut self, index: IndexModel) {
        self.external = Some(index);
        self.ctx.external_index = true;
    }

    /// Holds the prior index for the whole sweep (the extremum-shift fit is still made and
    /// reported): for a second pass over data whose first pass estimated the index from every
    /// angle.
    pub fn with_held_index(mut self) -> Self {
        self.ctx.held_index = self.ctx.index.is_some();
        self
    }

    /// Whether the index is held for the sweep ([`Self::with_held_index`]).
    pub fn index_held(&self) -> bool {
        self.ctx.held_index
    }

    /// The image's noise (reflectance) given rather than pooled from the pixels' trackers:
    /// for a sweep that tracks no extrema ([`super::SolverOptions::extrema`] off), from the
    /// pixel sample's own measure ([`super::sample::SampleFit::noise_sigma`]).
    pub fn with_noise(mut self, sigma: f32) -> Self {
        self.ctx.noise_median = Some(sigma);
        self
    }

    /// The pixels' models with the film absorbing and the polariser leaking as `terms` says
    /// (the sample fit's, [`super::sample::SampleFit::film_k`] and
    /// [`super::sample::SampleFit::polariser_leak`]).
    pub fn with_film_terms(mut self, terms: FilmTerms) -> Self {
        self.film_terms = terms;
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

    /// Full-spectrum index steps taken.
    pub fn refined_steps(&self) -> usize {
        self.refined_steps
    }

    /// Angles completed.
    pub fn angles_done(&self) -> usize {
        self.angles_done
    }

    /// Fills `out` (one entry per band, caller-owned: about 2.3 KB a band, room for the
    /// passband's Simpson nodes) with the band
    /// models of the current angle at the current index; all `None` until an index exists.
    pub fn band_models(&self, out: &mut [Option<BandCoef>]) {
        let d_max = self.table_range_nm()[1];
        for (i, o) in out.iter_mut().enumerate() {
            *o = match (self.ctx.index, self.ctx.spec.bands_nm.get(i)) {
                (Some(index), Some(&l)) => BandCoef::new(
                    index,
                    self.film_terms,
                    self.ctx.spec.ambient_index,
                    self.ctx.spec.substrate.index_at(l),
                    self.ctx.spec.substrate.extinction_at(l),
                    self.ctx.spec.back_face,
                    self.ctx.spec.polarization,
                    self.ctx.angle_deg,
                    l,
                    self.ctx.spec.fwhm_nm[i],
                    d_max,
                ),
                _ => None,
            };
        }
    }

    /// The thicknesses the band models are tabulated over: the search range widened by an
    /// interference order at the longest band and lowest index either side (the
    /// neighbouring orders' misfits look there). A thickness outside it has its models
    /// computed per sample.
    pub fn table_range_nm(&self) -> [f64; 2] {
        let [lo, hi] = self.ctx.spec.thickness_range_nm;
        let [_, l_max] = self.band_span_nm();
        let step = 1.2 * l_max / (2.0 * self.ctx.spec.index_range[0].max(1.0));
        [lo - step, hi + step]
    }

    /// Tabulates the band models (in band order, as many as `knots` holds; the rest are
    /// computed per sample), so a sample's full-spectrum sums cost interpolations instead of
    /// an Airy quadrature (see [`BandCoef::eval`]). `models` may be a run of consecutive
    /// bands whose knots start at `first` in the angle's table (`knots` the table from there
    /// on): runs split where their knots do ([`SweepSolver::band_knots`]) can be tabulated on
    /// as many threads.
    pub fn tabulate(&self, models: &mut [Option<BandCoef>], knots: &mut [Knot], first: usize) {
        let mut used = 0;
        for c in models.iter_mut().flatten() {
            let Some((range, n)) = self.band_table(c) else {
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
    /// model or a table): those over the span set ([`SweepSolver::set_table_span`]), and
    /// none at all for an image of fewer pixels than twice a band's knots over the whole
    /// table range (a knot costs about what a pixel's sample does computed, and whether the
    /// models are computed or tabulated does not depend on where the pixels are).
    pub fn band_knots(&self, models: &[Option<BandCoef>], out: &mut [usize]) {
        let full = self.table_range_nm();
        let (mut whole, mut bands) = (0, 0);
        for c in models.iter().flatten() {
            whole += c.knots_for(full).map_or(0, |(_, n)| n);
            bands += 1;
        }
        let spec = &self.ctx.spec;
        if spec.width * spec.height < 2 * whole / bands.max(1) {
            out.fill(0);
            return;
        }
        for (o, c) in out.iter_mut().zip(models) {
            *o = c
                .as_ref()
                .and_then(|c| self.band_table(c))
                .map_or(0, |(_, n)| n);
        }
    }

    /// The thicknesses band model `c` is tabulated over and its knot count: the table range
    /// ([`SweepSolver::table_range_nm`]), or the part of its knots that covers the span set
    /// ([`SweepSolver::set_table_span`]).
    fn band_table(&self, c: &BandCoef) -> Option<([f64; 2], usize)> {
        let full = self.table_range_nm();
        let range = match self.table_span {
            Some(span) => c.range_within(full, span)?,
            None => full,
        };
        c.knots_for(range).map(|(_, n)| (range, n))
    }

    /// The thicknesses at which this angle's samples read the pixels' models: over the
    /// image, from the least of a pixel's thickness less its order step to the greatest of
    /// its thickness plus it (`None`: the whole table range). The tables then cover only
    /// these ([`SweepSolver::tabulate`]; none if the span is empty, as at a first angle
    /// without seeded pixels); a thickness outside has its models computed per sample.
    pub fn set_table_span(&mut self, span: Option<[f64; 2]>) {
        self.table_span = span;
    }

    /// Starts an angle (then fill the band models with [`SweepSolver::band_models`]).
    pub fn begin_angle(&mut self, incidence_deg: f64) {
        self.ctx.angle_deg = incidence_deg;
        self.ctx.pair_geom = self.ctx.anchor_deg.and_then(|a| {
            PairGeometry::new(
                self.ctx.spec.ambient_index,
                a,
                incidence_deg,
                self.ctx.spec.index_range,
                self.band_span_nm(),
            )
        });
        self.ctx.window = None;
        self.last_pair = None;
        self.ctx.next_index = None;
        self.ctx.pending_dp = [0.0; 3];
    }

    /// The index fit over all pairs so far (model choice, chi-squares).
    pub fn index_fit(&self) -> Option<IndexFit> {
        self.fit
    }

    /// Merged votes of the current pair: fixes the window around their mode.
    pub fn set_votes(&mut self, hist: &RatioHistogram) {
        self.ctx.window = self.ctx.pair_geom.as_ref().and_then(|g| hist.windows(g));
    }

    /// Merged window sums: the pair's extrema-only index estimate.
    pub fn set_window_sums(&mut self, sums: &RatioSums) {
        let est = self
            .ctx
            .pair_geom
            .as_ref()
            .and_then(|g| pair_estimate(g, sums));
        if let (Some(e), Some(g)) = (est, self.ctx.pair_geom.as_ref()) {
            let _ = self.pairs.push(e);
            let _ = self.pair_bins.push(PairBins::from_sums(g, sums));
        }
        self.last_pair = est;
    }

    /// Merged fit-quality histogram.
    pub fn set_fit_histogram(&mut self, hist: &FitStats) {
        if let Some(m) = hist.rms.median() {
            self.ctx.rms_median = Some(m);
        }
        if let Some(m) = hist.noise.median() {
            self.ctx.noise_median = Some(m);
        }
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
    ///
    /// A held index ([`SweepSolver::with_held_index`]) takes no step: the pixels add no index
    /// sums ([`super::refine::AngleModels::index_held`]), and the residual's variance is the
    /// pixels' own (their thickness eliminated).
    pub fn set_schur(&mut self, s: &SchurSums) {
        self.last_refined = false;
        let mut spectral_next = None;
        let enough = s.pixels >= 16.0 && s.samples > s.pixels * 2.0;
        if self.ctx.held_index {
            if enough {
                let terms = self.ctx.index.map_or(1, |m| m.terms()).clamp(1, 3);
                let dof = (s.samples - s.pixels - terms as f64).max(1.0);
                self.ctx.residual_sigma = Some(libm::sqrt(s.sse.max(0.0) / dof));
                self.last_refined = true;
                self.refined_steps += 1;
            }
            self.spectral_dn = f64::NAN;
        } else if enough && s.h[0] > 0.0 {
            let steps = [s.step(1), s.step(2), s.step(3)];
            let full = steps[2].or(steps[1]).or(steps[0]);
            let dof = (s.samples - s.pixels - 3.0).max(1.0);
            let sigma2 = full.map_or(s.sse / dof, |(_, gain)| (s.sse - gain).max(0.0) / dof);
            let gains = steps.map(|st| st.map_or(f64::NAN, |(_, gain)| gain / sigma2.max(1e-30)));
            // Terms are added only once the simpler model has settled (its own step is
            // small), so that a richer model is compared with the simpler one at its best
            // rather than used to absorb a linearisation far from it, and only if the index
            // it gives is physical (normal dispersion across the band).
            let mut terms = self.ctx.index.map_or(1, |m| m.terms()).clamp(1, 3);
            // The pixels' thicknesses must have stepped twice too (three angles in): a
            // richer index would otherwise absorb their starting error, and two angles
            // barely tell a thin film's index from its thickness.
            let settled = self.refined_steps > 1
                && steps[terms - 1]
                    .is_some_and(|(x, _)| self.max_index_change(x) < SETTLED_INDEX_STEP);
            while settled && terms < 3 && gains[terms] - gains[terms - 1] > SPECTRAL_TERM_CHI2 {
                let worth = match (self.ctx.index, steps[terms]) {
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
                self.ctx.residual_sigma = Some(libm::sqrt(after.max(0.0) / dof));
                self.spectral_dn = x[0];
                for (kept, g) in self.spectral_gains.iter_mut().zip(gains) {
                    if kept.is_nan() || g > *kept {
                        *kept = g;
                    }
                }
                self.last_refined = true;
                self.refined_steps += 1;
                if let Some(index) = self.ctx.index {
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
                        self.ctx.index_cov = Some(cov.map(|row| row.map(|v| v * sigma2)));
                    } else {
                        // No usable step from the linearisation: where a fresh pass starts.
                        self.spectral_candidate = self.spectral_start(index, s);
                    }
                }
            }
        }
        let (range, span) = (self.ctx.spec.index_range, self.band_span_nm());
        self.fit = combine(&self.pairs).and_then(|c| fit_index(&self.pair_bins, c, range, span));
        self.ctx.next_index = if let Some(m) = self.external.take() {
            Some(m)
        } else if self.ctx.held_index {
            self.ctx.index
        } else if self.spectral_index {
            spectral_next.or(self.ctx.index)
        } else {
            match self.fit {
                Some(f) => {
                    let mut cov = [[0.0; 3]; 3];
                    cov[0][0] = f.sigma * f.sigma;
                    self.ctx.index_cov = Some(cov);
                    Some(f.model)
                }
                None => self.ctx.index,
            }
        };
        self.ctx.pending_dp = match (self.ctx.index, self.ctx.next_index) {
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
        let [lo, hi] = self.ctx.spec.index_range;
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
        let [n_lo, n_hi] = self.ctx.spec.index_range;
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

    /// The index step the full-spectrum sums alone would take (a consistency check).
    pub fn spectral_index_step(&self) -> f64 {
        self.spectral_dn
    }

    /// Ends the angle (after every shard's `update`).
    pub fn end_angle(&mut self) -> AngleReport {
        if self.ctx.anchor_deg.is_none() {
            self.ctx.anchor_deg = Some(self.ctx.angle_deg);
        }
        self.ctx.index = self.ctx.next_index.or(self.ctx.index);
        self.angles_done += 1;
        AngleReport {
            incidence_deg: self.ctx.angle_deg,
            index: self.ctx.index.map(|m| m.at(super::BASIS_NM)),
            index_sigma: self.index_sigma(),
            pair: self.last_pair,
            refined: self.last_refined,
            spectral_index_step: self.spectral_dn,
            spectral_index: self.spectral_index,
            index_terms: self.ctx.index.map_or(0, |m| m.terms()),
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
            let (h, f) = s.tally(&self.ctx);
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
            s.sums(&self.ctx, |_, w, r| {
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
            s.update(&self.ctx, None, |_| {});
        }
        // Every pixel as a possible tie: those with an order are skipped.
        resolve_orders(&self.ctx, shards, |_, pixels| 0..pixels);
        self.end_angle()
    }
}

/// Order resolution of the pixels [`Shard::update`] left tied, over shards in row order,
/// forward then backward, each shard seeing its neighbours' edge rows: the same result as one
/// shard over the whole image. `ties(shard, pixels)` lists the tied pixels of shard number
/// `shard` (of `pixels`) in increasing order; pixels with an order are skipped, so `0..pixels`
/// will do.
pub fn resolve_orders<I: DoubleEndedIterator<Item = usize>>(
    ctx: &SweepContext,
    shards: &mut [Shard<'_>],
    ties: impl Fn(usize, usize) -> I,
) {
    let w = ctx.spec().width;
    let mut edge = [0f32; 4096];
    let mut have = false;
    let mut pending = false;
    for (k, s) in shards.iter_mut().enumerate() {
        let above = (have && w <= edge.len()).then(|| &edge[..w]);
        pending |= s.resolve_forward(ctx, above, ties(k, s.pixels.len()));
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
        s.resolve_backward(ctx, below, ties(k, s.pixels.len()).rev());
        if w <= edge.len() {
            s.edge_row(false, &mut edge[..w]);
            have = true;
        }
    }
}
