//! Per-pixel state of a band of rows, and the shard-local passes of the sweep.

use crate::track::row::{self, TrackerLanes};
use crate::track::{ExtremaHead, Extremum, ExtremumSink, LaneSinks};

use super::context::SweepContext;
use super::extrema::{self, AnchorTail, SampleExtrema};
use super::fit_row::{self, FitLanes, IndexLanes, IndexSampling, PixelFit};
use super::flags;
use super::index::{accumulate_window, RatioHistogram, RatioSums};
use super::order::{Observation, OrderChoice, OrderContext};
use super::refine::{AngleModels, GnSums, INDEX_TERMS};
use super::spec::{SolverOptions, SweepSpec};
use super::sums::{FitStats, SchurSums};
use super::IndexModel;

/// Cost margin below which two orders are a tie (squared order misfits).
const AMBIGUITY_MARGIN: f64 = 0.08;
/// A pixel whose RMS residual is this many times the image's median (plus
/// [`OUTLIER_FLOOR`]) is an outlier.
const OUTLIER_RMS: f32 = 3.0;
/// Absolute allowance on the outlier limit, so a noise-free capture does not call its best
/// pixels outliers.
const OUTLIER_FLOOR: f32 = 2e-3;
/// Chi-square advantage (in units of the noise variance) the chosen order needs over its
/// neighbours to be trusted.
const ORDER_CHI2: f64 = 16.0;
/// Chi-square (in units of the image's noise variance) by which a neighbouring order must fit
/// a pixel's full spectra better, at an angle's end, for the pixel to move to it: an order
/// chosen from two close angles' extrema can be wrong, and the full spectra tell.
const ORDER_HOP_CHI2: f64 = 25.0;
/// Largest 1-sigma thickness uncertainty (nm) of a reported pixel, from its full-spectrum
/// fit: a quarter of the 20 nm at which a reported thickness counts as wrong. Measured (the
/// `thickness_sigma_nm` map) on a film next to the substrate's
/// index (n 1.5 on 1.52, 500 nm) under Gaussian reflectance noise: 4.4-5.0 nm at 1 % (no
/// pixel off by 20 nm), 8.8-9.8 nm at 2 % (8 of 61 valid pixels off by more), 9-14 nm at
/// 3 %; 0.3-0.9 nm on the paper's MgF2 sample; the errors ran to 2-4 sigma at the 90th
/// percentile (the model's curvature is not in it; the index's uncertainty was not either
/// then), hence the margin. `filmscope eval` shows the flag's effect (valid and silent shares).
pub const MAX_THICKNESS_SIGMA_NM: f64 = 5.0;
/// Largest share of unusable samples a valid pixel may have.
const BAD_SHARE: f64 = 0.1;

/// Whether `count` unusable samples (saturated, or dead) of a pixel's `samples` are too many
/// for it to be valid: more than [`BAD_SHARE`] of them, or a count that stopped at its cap
/// ([`fit_row::BAD_COUNT_MAX`]: that many or more, whatever the share).
fn too_many_bad(count: u8, samples: u16) -> bool {
    count == fit_row::BAD_COUNT_MAX || f64::from(count) > BAD_SHARE * f64::from(samples.max(1))
}

/// The bit of [`PixelState::flags`] that tells whether the pixel found an extremum at any
/// angle so far: the solver's own (a pixel without a thickness is [`flags::NO_FRINGE`]
/// without, [`flags::AMBIGUOUS_ORDER`] with), never in a result's flags. (It was a byte of
/// its own, which the struct's alignment rounded to two.)
pub const SEEN_EXTREMA: u16 = 1 << 15;
const _: () = {
    // None of the flags a result reports.
    let mut i = 0;
    while i < flags::NAMES.len() {
        assert!(flags::NAMES[i].0 & SEEN_EXTREMA == 0);
        i += 1;
    }
};

/// What the solver keeps about one pixel but its per-sample state: its flags and the last
/// extrema of its current and reference angles (the index's sample keeps the rest,
/// [`SampleExtrema`]).
/// The extremum tracker and the thickness, counters and full-spectrum sums live in the
/// shard's row blocks ([`TrackerLanes`], [`FitLanes`]), where a band's row updates them lane
/// by lane; this is touched only when an extremum is found and at angle ends. Its size is
/// fixed whatever the number of bands, angles and sweeps (see `state_bytes_per_pixel`).
#[derive(Clone, Debug)]
pub struct PixelState {
    /// Flags (see [`flags`]), and [`SEEN_EXTREMA`].
    pub flags: u16,
    /// The last extrema at the current angle.
    pub current: ExtremaHead,
    /// The last extrema at the reference (first) angle.
    pub anchor: ExtremaHead,
}

impl Default for PixelState {
    fn default() -> Self {
        Self {
            anchor: ExtremaHead::EMPTY,
            current: ExtremaHead::EMPTY,
            flags: 0,
        }
    }
}

/// The tracker's sinks of one block of a row: each pixel's [`ExtremaHead`], and the whole
/// list of those of the index's sample.
struct BlockSinks<'s> {
    /// The block's pixels.
    pixels: &'s mut [PixelState],
    /// The row's sampled pixels' lists.
    lists: &'s mut [SampleExtrema],
    /// Which pixels those are.
    sampling: IndexSampling,
    /// The image row.
    row: usize,
    /// The block's first column.
    col: usize,
}

impl LaneSinks for BlockSinks<'_> {
    #[inline]
    fn last_at(&self, i: usize) -> Option<Extremum> {
        self.pixels.get(i).and_then(|p| p.current.last_extremum())
    }

    fn push_at(&mut self, i: usize, e: Extremum) -> Result<(), Extremum> {
        let Some(p) = self.pixels.get_mut(i) else {
            return Ok(());
        };
        if let Some(slot) = self.sampling.slot(self.row, self.col + i) {
            // Takes and refuses what the head does.
            let _ = self.lists[slot].current.push(e);
        }
        // The overflow is the pixel's from the moment it happens: nothing reads the
        // tracker's own flag for the results.
        p.current
            .push(e)
            .inspect_err(|_| p.flags |= flags::TRACKER_OVERFLOW)
    }
}

/// Bytes of solver state per pixel of rows of `width` whose index's sample `sampling`
/// picks: what a row holds, over its pixels, rounded up: each pixel's [`PixelState`], the
/// row's tracker and fit blocks (one of each per [`row::LANES`] pixels, the last padded)
/// and what its sampled pixels keep besides (their index sums, [`IndexLanes`], and whole
/// extremum lists, [`SampleExtrema`]).
pub fn state_bytes_per_pixel(sampling: IndexSampling, width: usize) -> usize {
    use core::mem::size_of;
    let sample = size_of::<IndexLanes>() + row::LANES * size_of::<SampleExtrema>();
    let blocks = row::blocks_for(1, width) * (size_of::<TrackerLanes>() + size_of::<FitLanes>());
    let row_bytes =
        width * size_of::<PixelState>() + blocks + sampling.blocks_per_row(width) * sample;
    row_bytes.div_ceil(width.max(1))
}

/// Tracker blocks, and fit blocks, a shard of `pixels` pixels in rows of `width` needs
/// ([`Shard::new`]).
pub const fn tracker_blocks(pixels: usize, width: usize) -> usize {
    match pixels.checked_div(width) {
        Some(rows) => row::blocks_for(rows, width),
        None => 0,
    }
}

/// The per-pixel states of rows `first_row..first_row + pixels.len() / width`.
pub struct Shard<'a> {
    /// First image row of the shard.
    pub first_row: usize,
    /// Pixels per row.
    pub width: usize,
    /// Row-major pixel states.
    pub pixels: &'a mut [PixelState],
    /// The pixels' extremum trackers, row after row ([`tracker_blocks`] of them).
    trackers: &'a mut [TrackerLanes],
    /// The pixels' thickness, counters and own sums, in the same blocks.
    fits: &'a mut [FitLanes],
    /// Which pixels keep the index's sums.
    sampling: IndexSampling,
    /// Their sums, [`IndexSampling::blocks_per_row`] blocks a row.
    index: &'a mut [IndexLanes],
    /// Their whole extremum lists, one per lane of `index`.
    lists: &'a mut [SampleExtrema],
}

/// A pixel's final result.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelResult {
    /// Thickness, nm (NaN when invalid).
    pub thickness_nm: f32,
    /// Confidence in 0..1 (0 when invalid).
    pub confidence: f32,
    /// Flags.
    pub flags: u16,
    /// 1-sigma uncertainty of the thickness, nm, from the pixel's own full-spectrum fit and the
    /// shared index's covariance ([`GnSums::thickness_sigma_nm`]); NaN without a fit. It is
    /// statistical: a bias of the index model (a spurious dispersion term) is not in it.
    /// Given for flagged pixels too: above
    /// [`MAX_THICKNESS_SIGMA_NM`] it is why a pixel is flagged `imprecise`.
    pub thickness_sigma_nm: f32,
}

impl PixelResult {
    /// A pixel nothing was solved for (yet).
    pub const UNSOLVED: Self = Self {
        thickness_nm: f32::NAN,
        confidence: 0.0,
        flags: 0,
        thickness_sigma_nm: f32::NAN,
    };
}

impl<'a> Shard<'a> {
    /// A shard over caller-owned states, trackers, fits and what the index's sample keeps
    /// (`trackers.len()` and `fits.len()` must be [`tracker_blocks`]`(pixels.len(), width)`,
    /// or `trackers` empty once released at the sweep's last angle end, for the passes after
    /// [`Shard::tally_rows`]),
    /// `sample.1.len()` the rows times `sample.0`'s [`IndexSampling::blocks_per_row`],
    /// `sample.2.len()` [`row::LANES`] times that).
    pub fn new(
        first_row: usize,
        width: usize,
        pixels: &'a mut [PixelState],
        trackers: &'a mut [TrackerLanes],
        fits: &'a mut [FitLanes],
        sample: (IndexSampling, &'a mut [IndexLanes], &'a mut [SampleExtrema]),
    ) -> Self {
        let (sampling, index, lists) = sample;
        let blocks = tracker_blocks(pixels.len(), width);
        assert!(
            (trackers.len() == blocks || trackers.is_empty()) && fits.len() == blocks,
            "one tracker (or none) and one fit block per {} pixels of a row",
            row::LANES
        );
        let rows = pixels.len().checked_div(width).unwrap_or(0);
        assert_eq!(
            index.len(),
            rows * sampling.blocks_per_row(width),
            "the index blocks of every row"
        );
        assert_eq!(
            lists.len(),
            index.len() * row::LANES,
            "extremum lists for every index lane"
        );
        Self {
            first_row,
            width,
            pixels,
            trackers,
            fits,
            sampling,
            index,
            lists,
        }
    }

    /// Pixel `i`'s thickness, counters and sums (a copy; the index's sums are zeros where
    /// the pixel keeps none).
    pub fn fit(&self, i: usize) -> PixelFit {
        let w = self.width.max(1);
        self.fit_at(i / w, i % w)
    }

    /// [`Shard::fit`] of the pixel in the shard's row `r`, column `c`.
    fn fit_at(&self, r: usize, c: usize) -> PixelFit {
        let (fit, index) = self.lanes_at(r, c);
        let terms = index.map_or([0.0; INDEX_TERMS], |(b, l)| self.index[b].terms(l));
        self.fits[fit.0].pixel(fit.1, terms)
    }

    /// Stores pixel `i`'s thickness, counters and sums (the index's where it keeps them).
    fn set_fit(&mut self, i: usize, f: &PixelFit) {
        let w = self.width.max(1);
        self.set_fit_at(i / w, i % w, f);
    }

    /// [`Shard::set_fit`] of the pixel in the shard's row `r`, column `c`.
    fn set_fit_at(&mut self, r: usize, c: usize, f: &PixelFit) {
        let ((b, lane), index) = self.lanes_at(r, c);
        self.fits[b].set_pixel(lane, f);
        if let Some((b, l)) = index {
            self.index[b].set_terms(l, f.gn.to_index_terms());
        }
    }

    /// The fit (and tracker) block and lane of the pixel in the shard's row `r`, column `c`
    /// ([`row::locate`]'s), and its index block and lane if it keeps the index's sums: no
    /// division (the angle-end passes call this for every pixel).
    #[inline]
    fn lanes_at(&self, r: usize, c: usize) -> ((usize, usize), Option<(usize, usize)>) {
        let w = self.width.max(1);
        let fit = (r * w.div_ceil(row::LANES) + c / row::LANES, c % row::LANES);
        let index = self.sampling.slot(self.first_row + r, c).map(|slot| {
            let b = r * self.sampling.blocks_per_row(w) + slot / row::LANES;
            (b, slot % row::LANES)
        });
        (fit, index)
    }

    /// Where a pixel of the index's sample, at `lane` of the index blocks, keeps its whole
    /// extremum lists ([`SampleExtrema`]).
    fn list_slot((block, lane): (usize, usize)) -> usize {
        block * row::LANES + lane
    }

    /// The whole extremum lists of the pixel in the shard's row `r`, column `c`, if it is
    /// one of the index's sample (the others keep their last extrema only).
    pub(super) fn lists_at(&self, r: usize, c: usize) -> Option<&SampleExtrema> {
        self.lanes_at(r, c)
            .1
            .map(|lane| &self.lists[Self::list_slot(lane)])
    }

    /// Starts the shard's pixels at the thicknesses `map` (row-major, the shard's; NaN leaves
    /// a pixel as it was) with `index`, as a global search on sampled spectra put them
    /// ([`super::sample`]): they are refined from the first angle on, needing no extrema.
    pub fn seed(&mut self, map: &[f32], index: IndexModel, spec: &SweepSpec) {
        let mid = spec.bands_nm[spec.bands_nm.len() / 2];
        let order_step_nm = (mid / (2.0 * index.at(mid))) as f32;
        let w = self.width.max(1);
        for (i, &d) in map.iter().enumerate().take(self.pixels.len()) {
            if d.is_finite() {
                let ((b, lane), _) = self.lanes_at(i / w, i % w);
                self.fits[b].seed(lane, d, order_step_nm);
                let p = &mut self.pixels[i];
                p.flags = flags::FROM_SPECTRUM_SEARCH | (p.flags & SEEN_EXTREMA);
            }
        }
    }

    /// Which pixels keep the index's sums.
    pub fn sampling(&self) -> IndexSampling {
        self.sampling
    }

    /// Rows held.
    pub fn rows(&self) -> usize {
        self.pixels.len().checked_div(self.width).unwrap_or(0)
    }

    /// Whether image row `row` belongs to this shard.
    pub fn holds(&self, row: usize) -> bool {
        row >= self.first_row && row < self.first_row + self.rows()
    }

    /// Starts an angle: resets the trackers and the current extrema.
    pub fn begin_angle(&mut self) {
        self.trackers.iter_mut().for_each(TrackerLanes::reset);
        for p in self.pixels.iter_mut() {
            p.current.clear();
        }
        self.lists.iter_mut().for_each(SampleExtrema::begin_angle);
    }

    /// Votes the extrema the sampled pixels ([`IndexSampling`]) of image rows `rows` have found
    /// so far at this angle and not voted yet (their ratios against the reference angle's, as
    /// [`Shard::tally`] would count them), into `votes`, and marks them voted. Extrema are only
    /// ever appended, so a row voted before its last bands leaves its tally the few extrema
    /// found since: done while the angle streams, this takes most of the pairing off the
    /// angle's end.
    pub fn vote_rows(
        &mut self,
        sweep: &SweepContext,
        rows: core::ops::Range<usize>,
        votes: &mut RatioHistogram,
    ) {
        let Some(g) = sweep.pair_geometry() else {
            return;
        };
        let spec = sweep.spec();
        let (lo, hi) = self.local_rows(rows);
        let w = self.width;
        for r in lo..hi {
            for c in self.sampling.cols(self.first_row + r, w) {
                let lane = self.lanes_at(r, c).1.expect("a pixel of the sample");
                let slot = Self::list_slot(lane);
                let lists = &self.lists[slot];
                let reference = extrema::reference(&self.pixels[r * w + c].anchor, Some(lists));
                votes.vote(g, reference, lists.unvoted(), |b| spec.wavelength_at(b));
                self.lists[slot].voted = self.lists[slot].current.len() as u8;
            }
        }
    }

    /// The shard's rows (first, end) of the image rows `rows`, clamped to the shard.
    fn local_rows(&self, rows: core::ops::Range<usize>) -> (usize, usize) {
        let local =
            |r: usize| r.clamp(self.first_row, self.first_row + self.rows()) - self.first_row;
        (local(rows.start), local(rows.end).max(local(rows.start)))
    }

    /// Feeds one row of calibrated reflectance of band `band` (`values.len() == width`;
    /// `+inf` marks a saturated sample, NaN one without a usable reference). `models` are the
    /// angle's band models (the solver's `band_models`).
    pub fn feed_row(
        &mut self,
        options: SolverOptions,
        models: AngleModels<'_>,
        band: usize,
        row: usize,
        values: &[f32],
    ) {
        if !self.holds(row) || values.len() != self.width {
            return;
        }
        // The per-sample work, inlined into either build ([`crate::simd::wide`]).
        crate::simd::wide(options.wide_simd, {
            #[inline(always)]
            || {
                let start = (row - self.first_row) * self.width;
                let coef = models
                    .coefs
                    .get(band)
                    .and_then(Option::as_ref)
                    .filter(|_| options.refine);
                let pixels = &mut self.pixels[start..start + self.width];
                let blocks = tracker_blocks(self.width, self.width);
                let first = (row - self.first_row) * blocks;
                let trackers = &mut self.trackers[first..first + blocks];
                let fits = &mut self.fits[first..first + blocks];
                let per_row = self.sampling.blocks_per_row(self.width);
                let local = row - self.first_row;
                let index = &mut self.index[local * per_row..(local + 1) * per_row];
                let lists = &mut self.lists
                    [local * per_row * row::LANES..(local + 1) * per_row * row::LANES];
                let lanes = values.chunks(row::LANES).zip(pixels.chunks_mut(row::LANES));
                let tracked = if options.extrema { trackers.len() } else { 0 };
                for (b, (t, (v, p))) in trackers.iter_mut().zip(lanes).take(tracked).enumerate() {
                    let mut sinks = BlockSinks {
                        pixels: p,
                        lists: &mut *lists,
                        sampling: self.sampling,
                        row,
                        col: b * row::LANES,
                    };
                    t.push(band as u16, v, options.subband, &mut sinks);
                }
                let model = coef.map(|c| (c, models.knots));
                let index = (!models.index_held).then_some((self.sampling, row, index));
                fit_row::push_row(fits, values, model, index, options.wide_simd);
            }
        });
    }

    /// Where the shard's pixels read their models at the next angle
    /// ([`crate::solve::fit_row::thickness_span`]).
    pub fn thickness_span(&self) -> [f32; 2] {
        crate::solve::fit_row::thickness_span(self.fits)
    }

    /// Angle-end pass 1, over the pixels that keep the index's sums ([`IndexSampling`]; every
    /// pixel of a small sensor): their extremum ratios against the reference angle (the
    /// votes), the RMS residuals of the refined ones and their noise. Image-wide statistics
    /// (the ratio window, the RMS median, the pooled noise) need no more pixels than the
    /// index's step does, and the other pixels' state is not walked.
    pub fn tally(&self, sweep: &SweepContext) -> (RatioHistogram, FitStats) {
        let mut votes = RatioHistogram::default();
        let mut fit = FitStats::default();
        let rows = self.first_row..self.first_row + self.rows();
        self.tally_rows(sweep, rows, &mut votes, &mut fit);
        (votes, fit)
    }

    /// [`Shard::tally`] of the image rows `rows` (those of the shard), added to `votes` and
    /// `fit`: a row can be tallied once it has seen the angle's last band, while later rows
    /// still stream (the counts add up to the same whatever the rows' grouping).
    pub fn tally_rows(
        &self,
        sweep: &SweepContext,
        rows: core::ops::Range<usize>,
        votes: &mut RatioHistogram,
        fit: &mut FitStats,
    ) {
        let spec = sweep.spec();
        let geometry = sweep.pair_geometry();
        let (lo, hi) = self.local_rows(rows);
        let w = self.width;
        for r in lo..hi {
            for c in self.sampling.cols(self.first_row + r, w) {
                let ((block, lane), sample) = self.lanes_at(r, c);
                let lists = sample.map(|l| &self.lists[Self::list_slot(l)]);
                if let Some(g) = geometry {
                    let reference = extrema::reference(&self.pixels[r * w + c].anchor, lists);
                    let unvoted = lists.map_or(&[][..], SampleExtrema::unvoted);
                    votes.vote(g, reference, unvoted, |b| spec.wavelength_at(b));
                }
                if let Some(rms) = self.fits[block].rms(lane) {
                    fit.rms.add(rms);
                }
                if spec.options.extrema {
                    fit.noise.add(self.trackers[block].noise_sigma(lane));
                }
            }
        }
    }

    fn trusted(f: &PixelFit, rms_limit: f32) -> bool {
        f.thickness_nm.is_finite() && f.gn.samples > 2 && f.gn.h_dd > 0.0 && f.gn.rms() <= rms_limit
    }

    /// Angle-end pass 2, one call of `f(row, window, schur)` per image row (rows in order, so
    /// that merging them in row order gives the same floating-point result however the image
    /// is sharded), over the pixels that keep the index's sums ([`IndexSampling`]): the sums
    /// of their ratios inside the accepted window, and their contributions to the shared
    /// index step (their own thickness eliminated), outliers left out.
    pub fn sums(&self, sweep: &SweepContext, mut f: impl FnMut(usize, RatioSums, SchurSums)) {
        let spec = sweep.spec();
        let window = sweep.pair_geometry().zip(sweep.ratio_window());
        let limit = sweep
            .rms_median()
            .map_or(f32::INFINITY, |m| OUTLIER_RMS * m + OUTLIER_FLOOR);
        // A pixel about to move to a neighbouring order ([`Shard::update`]) would pull the
        // index toward its wrong order: left out.
        let (hop, d_lo) = Self::hop_margin(sweep);
        let settled =
            |f: &PixelFit| hop.is_none_or(|margin| Self::better_order(f, margin, d_lo).is_none());
        let width = self.width.max(1);
        for r in 0..self.rows() {
            let mut w = RatioSums::default();
            let mut s = SchurSums::default();
            for c in self.sampling.cols(self.first_row + r, width) {
                if let Some((g, windows)) = window {
                    let lists = self.lists_at(r, c);
                    let reference = extrema::reference(&self.pixels[r * width + c].anchor, lists);
                    let current = lists.map_or(&[][..], |l| &l.current);
                    accumulate_window(&mut w, g, windows, reference, current, |b| {
                        spec.wavelength_at(b)
                    });
                }
                let f = self.fit_at(r, c);
                if !(Self::trusted(&f, limit) && settled(&f)) {
                    continue;
                }
                let g = &f.gn;
                let h_dd = f64::from(g.h_dd);
                let h_dp = g.h_dp.map(f64::from);
                let g_d = f64::from(g.g_d);
                let mut k = 0;
                for i in 0..3 {
                    for j in i..3 {
                        s.h[k] += f64::from(g.h_pp[i + j]) - h_dp[i] * h_dp[j] / h_dd;
                        k += 1;
                    }
                    s.g[i] += f64::from(g.g_p[i]) - h_dp[i] * g_d / h_dd;
                }
                s.pixels += 1.0;
                s.sse += f64::from(g.sse) - f64::from(g.g_d) * f64::from(g.g_d) / h_dd;
                s.samples += f64::from(g.samples);
            }
            f(self.first_row + r, w, s);
        }
    }

    /// Angle-end pass 3: steps every refined pixel's thickness (with the index step), keeps
    /// the first angle's extrema, and gives every pixel without an order the one its extrema
    /// choose clearly; `tie(i)` is told of each pixel (index in the shard, in increasing
    /// order) whose two best orders are too close to call, for the solver's `resolve_orders` (a
    /// resolved neighbour decides those, in image order). At the sweep's last angle, `out`
    /// (the shard's results, row-major) gets every pixel's final result as [`Shard::finish`]
    /// gives it (the ties' to be given again once resolved: [`Shard::finish_pixels`]).
    pub fn update(
        &mut self,
        sweep: &SweepContext,
        mut out: Option<&mut [PixelResult]>,
        mut tie: impl FnMut(usize),
    ) {
        let dp = sweep.pending_index_step();
        let first_angle = sweep.anchor_deg().is_none();
        // An index that moved this much makes the orders chosen with the old one suspect:
        // every pixel chooses again (with this angle's extrema) and its sums restart.
        let reorder = sweep.reorders();
        let (hop, d_lo) = Self::hop_margin(sweep);
        let spec = sweep.spec();
        // A pixel not refined yet follows the index change at constant optical path.
        let path_ratio = match (sweep.index(), sweep.next_index()) {
            (Some(old), Some(new)) => {
                let mid = spec.bands_nm[spec.bands_nm.len() / 2];
                Some(old.at(mid) / new.at(mid))
            }
            _ => None,
        };
        let orders = Self::order_context(sweep);
        let finish = out.is_some().then(|| Finish::of(sweep));
        let w = self.width.max(1);
        let rows = self.pixels.len() / w;
        let mut steps = None;
        for (r, c) in (0..rows).flat_map(|r| (0..w).map(move |c| (r, c))) {
            let i = r * w + c;
            let mut f = self.fit_at(r, c);
            let ((block, lane), sample) = self.lanes_at(r, c);
            if lane == 0 {
                steps = None;
            }
            // Whether only the lane steps' three values changed (all the lanes need back).
            let mut stepped = false;
            let slot = sample.map(Self::list_slot);
            let p = &mut self.pixels[i];
            if !p.current.is_empty() {
                p.flags |= SEEN_EXTREMA;
            }
            // A seeded pixel has no extrema to choose its order again from: it keeps its
            // thickness and steps with the index like the others.
            let seeded = p.flags & flags::FROM_SPECTRUM_SEARCH != 0;
            if reorder && f.thickness_nm.is_finite() && !seeded {
                f.thickness_nm = f32::NAN;
                f.gn = GnSums::default();
                p.flags &= !flags::ORDER_FROM_NEIGHBOUR;
            } else if let Some(dir) = hop.and_then(|margin| Self::better_order(&f, margin, d_lo)) {
                // A whole order away: the sums restart there.
                f.thickness_nm += dir * f.order_step_nm;
                f.gn = GnSums::default();
            } else if f.thickness_nm.is_finite() && f.gn.samples > 0 && f.gn.h_dd > 0.0 {
                if sample.is_none() {
                    // The block's steps in one loop, once a pixel of it needs them.
                    let s = steps.get_or_insert_with(|| self.fits[block].steps(dp));
                    f.thickness_nm = s.thickness_nm[lane];
                    f.gn.g_d = s.g_d[lane];
                    f.gn.sse = s.sse[lane];
                    stepped = f.thickness_nm.is_finite();
                } else {
                    let g = f.gn;
                    let step = f64::from(f.order_step_nm);
                    let dd = g.thickness_step(dp).clamp(-0.25 * step, 0.25 * step);
                    f.thickness_nm = (f64::from(f.thickness_nm) + dd) as f32;
                    f.gn.shift(dd, dp);
                }
            } else if f.thickness_nm.is_finite() {
                if let Some(ratio) = path_ratio {
                    f.thickness_nm = (f64::from(f.thickness_nm) * ratio) as f32;
                }
            }
            if first_angle {
                p.anchor = p.current;
                if let Some(t) = slot {
                    self.lists[t].tail = AnchorTail::of(&self.lists[t].current);
                }
            }
            if let Some(ctx) = orders.as_ref().filter(|_| !f.thickness_nm.is_finite()) {
                if let Some(c) = Self::choose(p, slot.map(|t| &self.lists[t]), spec, ctx) {
                    if c.runner_up_cost - c.cost >= AMBIGUITY_MARGIN {
                        Self::set_thickness(p, &mut f, c.thickness_nm, c.order_step_nm, 0);
                    } else {
                        tie(i);
                    }
                }
            }
            if let (Some(fin), Some(o)) = (finish.as_ref(), out.as_mut().and_then(|o| o.get_mut(i)))
            {
                *o = fin.result(p, &f);
            }
            if stepped {
                self.fits[block].set_step(lane, f.thickness_nm, f.gn.g_d, f.gn.sse);
            } else {
                self.set_fit_at(r, c, &f);
            }
        }
    }

    /// How much better (sum of squares) a neighbouring order must fit for a pixel to move to
    /// it ([`ORDER_HOP_CHI2`] noise variances), once the image's noise is known, and the
    /// lower end of the thickness search range.
    fn hop_margin(sweep: &SweepContext) -> (Option<f64>, f64) {
        let margin = sweep
            .noise_sigma()
            .map(|n| ORDER_HOP_CHI2 * f64::from(n) * f64::from(n));
        (margin, sweep.spec().thickness_range_nm[0])
    }

    /// The neighbouring order (`-1.0` thinner, `1.0` thicker) whose full-spectrum misfit is
    /// below the pixel's own by more than `margin`, if any (thinner only within the search
    /// range and above zero).
    fn better_order(f: &PixelFit, margin: f64, d_lo: f64) -> Option<f32> {
        if !f.thickness_nm.is_finite() || f.gn.samples == 0 {
            return None;
        }
        let (alt, dir) = Self::neighbour_order(f, d_lo);
        (f64::from(f.gn.sse) - f64::from(alt) > margin).then_some(dir)
    }

    /// The better-fitting neighbouring order of a refined pixel: its full-spectrum misfit and
    /// direction (`-1.0` thinner, `1.0` thicker). One order thinner is no alternative below
    /// the search range's lower end `d_lo` (nor below zero, where the model would mirror the
    /// film's thickness).
    fn neighbour_order(f: &PixelFit, d_lo: f64) -> (f32, f32) {
        let g = &f.gn;
        let thinner = f64::from(f.thickness_nm) - f64::from(f.order_step_nm) >= d_lo.max(0.0);
        if thinner && g.sse_minus < g.sse_plus {
            (g.sse_minus, -1.0)
        } else {
            (g.sse_plus, 1.0)
        }
    }

    /// Thickness of the shard's first (`last = false`) or last row, for the neighbouring
    /// shard's order resolution.
    pub fn edge_row(&self, last: bool, out: &mut [f32]) {
        let rows = self.rows();
        if rows == 0 {
            return;
        }
        let r = if last { rows - 1 } else { 0 };
        for (c, o) in out.iter_mut().take(self.width).enumerate() {
            *o = self.fit(r * self.width + c).thickness_nm;
        }
    }

    fn order_context(sweep: &SweepContext) -> Option<OrderContext> {
        let index = sweep.next_index()?;
        let spec = sweep.spec();
        let anchor = sweep.anchor_deg()?;
        let cur = sweep.angle_deg();
        Some(OrderContext {
            index,
            x: [spec.x_of(anchor), spec.x_of(cur)],
            angles: 2,
            peak_offset: [
                sweep.peak_offset(index, anchor),
                sweep.peak_offset(index, cur),
            ],
            thickness_range_nm: spec.thickness_range_nm,
            reliable_nm: spec.reliable_range_nm(),
            wide: spec.options.wide_simd,
        })
    }

    /// The order `p`'s extrema choose: its current and reference angles' whole lists if it
    /// keeps them (`lists`: the index's sample), else their last extrema, its order search
    /// told each whole list's count inside the reliable range.
    fn choose(
        p: &PixelState,
        lists: Option<&SampleExtrema>,
        spec: &SweepSpec,
        ctx: &OrderContext,
    ) -> Option<OrderChoice> {
        let mut obs: heapless::Vec<Observation, { 2 * crate::track::MAX_EXTREMA }> =
            heapless::Vec::new();
        let last = spec.last_reliable_band();
        let (current, counts) = match lists {
            Some(l) => (&l.current[..], [None; 2]),
            None => (
                p.current.extrema(),
                [&p.anchor, &p.current].map(|h| Some(h.reliable(last) as i64)),
            ),
        };
        let both = extrema::reference(&p.anchor, lists)
            .map(|e| (0, e))
            .chain(current.iter().map(|e| (1, e)));
        for (angle, e) in both {
            let _ = obs.push(Observation {
                wavelength_nm: spec.wavelength_at(e.band()),
                kind: e.kind(),
                angle,
            });
        }
        ctx.resolve_seen(&obs, counts)
    }

    /// [`Shard::choose`] of pixel `i` of the shard.
    fn choose_at(&self, i: usize, spec: &SweepSpec, ctx: &OrderContext) -> Option<OrderChoice> {
        let w = self.width.max(1);
        Self::choose(&self.pixels[i], self.lists_at(i / w, i % w), spec, ctx)
    }

    /// Order resolution, forward (shards in row order): each pixel of `ties` (indices in the
    /// shard, increasing; pixels with an order are skipped) takes the order of a resolved
    /// neighbour to the left or above (`above`: the previous shard's last row) if it is one
    /// of its two best. Returns whether ties remain.
    pub fn resolve_forward(
        &mut self,
        sweep: &SweepContext,
        above: Option<&[f32]>,
        ties: impl Iterator<Item = usize>,
    ) -> bool {
        let Some(ctx) = Self::order_context(sweep) else {
            return false;
        };
        let w = self.width;
        let mut pending = false;
        for i in ties {
            if self.fit(i).thickness_nm.is_finite() {
                continue;
            }
            let Some(c) = self.choose_at(i, sweep.spec(), &ctx) else {
                continue;
            };
            let left = (i % w > 0).then(|| self.fit(i - 1).thickness_nm);
            let up = if i >= w {
                Some(self.fit(i - w).thickness_nm)
            } else {
                above.and_then(|a| a.get(i).copied())
            };
            if !self.adopt_neighbour(sweep, i, &c, [left, up]) {
                pending = true;
            }
        }
        pending
    }

    /// Order resolution, backward (shards in reverse order): the ties left by the forward pass
    /// (`ties` in decreasing order), by a resolved neighbour to the right or below (`below`:
    /// the next shard's first row).
    pub fn resolve_backward(
        &mut self,
        sweep: &SweepContext,
        below: Option<&[f32]>,
        ties: impl Iterator<Item = usize>,
    ) {
        let Some(ctx) = Self::order_context(sweep) else {
            return;
        };
        let w = self.width;
        let n = self.pixels.len();
        for i in ties {
            if self.fit(i).thickness_nm.is_finite() {
                continue;
            }
            if let Some(c) = self.choose_at(i, sweep.spec(), &ctx) {
                let right = (i % w + 1 < w).then(|| self.fit(i + 1).thickness_nm);
                let down = if i + w < n {
                    Some(self.fit(i + w).thickness_nm)
                } else {
                    below.and_then(|b| b.get(i % w).copied())
                };
                self.adopt_neighbour(sweep, i, &c, [right, down]);
            }
        }
    }

    fn adopt_neighbour(
        &mut self,
        sweep: &SweepContext,
        i: usize,
        c: &OrderChoice,
        neighbours: [Option<f32>; 2],
    ) -> bool {
        if !sweep.spec().options.neighbours {
            return false;
        }
        for d_n in neighbours.into_iter().flatten() {
            let d_n = f64::from(d_n);
            if !d_n.is_finite() {
                continue;
            }
            for cand in [c.thickness_nm, c.runner_up_nm] {
                if cand.is_finite() && (cand - d_n).abs() < 0.3 * c.order_step_nm {
                    let mut f = self.fit(i);
                    let flag = flags::ORDER_FROM_NEIGHBOUR;
                    Self::set_thickness(&mut self.pixels[i], &mut f, cand, c.order_step_nm, flag);
                    self.set_fit(i, &f);
                    return true;
                }
            }
        }
        false
    }

    fn set_thickness(p: &mut PixelState, f: &mut PixelFit, d: f64, step: f64, flag: u16) {
        f.thickness_nm = d as f32;
        f.order_step_nm = step as f32;
        p.flags |= flag;
        f.gn = GnSums::default();
    }

    /// The final result of every pixel, row-major, after the last angle.
    pub fn finish(&self, sweep: &SweepContext, out: &mut [PixelResult]) {
        self.finish_pixels(sweep, out, 0..self.pixels.len());
    }

    /// The final results of the pixels `pixels` (indices in the shard) into `out` (the
    /// shard's results, row-major), after the last angle.
    pub fn finish_pixels(
        &self,
        sweep: &SweepContext,
        out: &mut [PixelResult],
        pixels: impl Iterator<Item = usize>,
    ) {
        let finish = Finish::of(sweep);
        for i in pixels {
            if let (Some(p), Some(o)) = (self.pixels.get(i), out.get_mut(i)) {
                *o = finish.result(p, &self.fit(i));
            }
        }
    }
}

/// What a pixel's final result needs of the sweep.
struct Finish {
    sigma2: f64,
    index_cov: Option<[[f64; 3]; 3]>,
    rms_limit: f32,
    d_lo: f64,
    d_hi: f64,
    refine: bool,
    mismatch: bool,
    mismatch_scale: f32,
}

impl Finish {
    fn of(sweep: &SweepContext) -> Self {
        let [d_lo, d_hi] = sweep.spec().thickness_range_nm;
        let (r, n) = (
            sweep.residual_sigma().unwrap_or(1.0),
            sweep.noise_sigma().unwrap_or(0.0),
        );
        Self {
            sigma2: sweep.residual_sigma().map_or(f64::NAN, |s| s * s),
            index_cov: sweep.index_covariance(),
            rms_limit: sweep
                .rms_median()
                .map_or(f32::INFINITY, |m| OUTLIER_RMS * m + OUTLIER_FLOOR),
            d_lo,
            d_hi,
            refine: sweep.spec().options.refine,
            mismatch: sweep.model_mismatch(),
            mismatch_scale: (f64::from(n) / r).clamp(0.0, 1.0) as f32,
        }
    }

    fn result(&self, p: &PixelState, fit: &PixelFit) -> PixelResult {
        let mut f = p.flags & !SEEN_EXTREMA;
        if too_many_bad(fit.saturated, fit.samples) {
            f |= flags::SATURATED;
        }
        if too_many_bad(fit.dead, fit.samples) {
            f |= flags::DEAD;
        } else if fit.dead > 0 {
            f |= flags::MISSING_SAMPLES;
        }
        let d = f64::from(fit.thickness_nm);
        let mut confidence = 0.0f32;
        let mut sigma = f64::NAN;
        if !d.is_finite() {
            f |= if p.flags & SEEN_EXTREMA == 0 {
                flags::NO_FRINGE
            } else {
                flags::AMBIGUOUS_ORDER
            };
        } else if fit.gn.samples == 0 {
            f |= flags::NOT_REFINED;
            // Its order rests on one pair of extremum lists, unconfirmed by the full
            // spectrum (it was ambiguous until the last angle, or the index arrived or
            // moved then): measured, such orders can be wrong for every pixel at once
            // (a thin high-index film), so with refinement on they are not reported.
            if self.refine {
                f |= flags::AMBIGUOUS_ORDER;
            }
            confidence = 0.5;
        } else {
            let g = &fit.gn;
            let best = f64::from(g.sse);
            let alt = f64::from(Shard::neighbour_order(fit, self.d_lo).0);
            let chi2 = if self.sigma2 > 0.0 {
                (alt - best) / self.sigma2
            } else {
                0.0
            };
            if chi2 < ORDER_CHI2 {
                f |= flags::ORDER_REJECTED;
            }
            if g.rms() > self.rms_limit {
                f |= flags::POOR_FIT;
            }
            sigma = g.thickness_sigma_nm(self.index_cov.as_ref());
            if sigma > MAX_THICKNESS_SIGMA_NM {
                f |= flags::IMPRECISE;
            }
            confidence = (chi2 / (chi2 + 4.0 * ORDER_CHI2)).clamp(0.0, 1.0) as f32;
        }
        if d.is_finite() && !(self.d_lo..=self.d_hi).contains(&d) {
            f |= flags::OUT_OF_RANGE;
        }
        if self.mismatch {
            f |= flags::MODEL_MISMATCH;
            confidence *= self.mismatch_scale;
        }
        let valid = f & flags::INVALID == 0;
        PixelResult {
            thickness_nm: if valid { d as f32 } else { f32::NAN },
            confidence: if valid { confidence } else { 0.0 },
            flags: f,
            thickness_sigma_nm: if sigma.is_finite() {
                sigma as f32
            } else {
                f32::NAN
            },
        }
    }
}

#[cfg(test)]
mod size_tests {
    use super::*;
    use crate::track::{ExtremaList, PixelTracker};

    #[test]
    fn unusable_counts_flag_a_tenth_or_a_capped_count() {
        use super::too_many_bad;
        // 161 bands x 5 angles: a tenth is 80.5.
        assert!(!too_many_bad(80, 805) && too_many_bad(81, 805));
        assert!(!too_many_bad(0, 0) && too_many_bad(1, 0));
        // 161 bands x 25 angles: a count stopped at its cap is 255 or more, and flags,
        // though 255 is not a tenth of 4025; one below it is what it says.
        assert!(too_many_bad(255, 4025) && !too_many_bad(254, 4025));
    }

    #[test]
    fn pixel_state_size_is_fixed_and_known() {
        // Breakdown: the pixel's state: flags (with whether it saw an extremum), the current
        // and the reference angles' last four extrema with their whole lists' lengths and
        // early counts, 10 each: 22; its tracker lanes in the row blocks, 37 bytes a pixel (a
        // ring of nine 2-byte steps, the window's moments computed from it, its noise sum
        // 4, running extremes 12 (values 4 each, positions 2 each in the 1/32 band an
        // extremum keeps), its lag and overflow flag 2 and mode 1; the scalar tracker
        // carries the moments, 51 bytes, 52 with padding) and the block's shared ring
        // position and count, 37.1 a pixel (38 rounded up); its fit lanes in the row blocks:
        // thickness and order step 8, its own eight full-spectrum sums 32 (the scalar
        // `GnSums` is 68 with the index's eight, its count and padding), the sums' count 2
        // and the saturated and dead counts 2 (a byte each, capped), and the block's shared
        // sample count, 44.1 (45 rounded up); the two blocks 81.2 a pixel. The pixels of the
        // index's sample keep the index's eight sums (32 bytes), the current angle's whole
        // extremum list (42, 20 extrema of 2 bytes and a one-byte length), how many of it
        // voted (1) and the rest of the reference list (34; 78 with padding), in blocks of
        // 32 a row: every pixel of a 320 x 200 sensor (10 blocks a row, 110 bytes a pixel:
        // 214 in all, rounded up once), one in 4 of a 640 x 480 one (5 blocks, 27.5 a pixel:
        // 131), one in 64 of a 2048 x 2048 one (one block: 1.7 a pixel, 105).
        let small = IndexSampling::for_sensor(320, 200, fit_row::INDEX_PIXELS);
        let vga = IndexSampling::for_sensor(640, 480, fit_row::INDEX_PIXELS);
        let large = IndexSampling::for_sensor(2048, 2048, fit_row::INDEX_PIXELS);
        let sizes = [
            core::mem::size_of::<PixelTracker>(),
            core::mem::size_of::<TrackerLanes>().div_ceil(row::LANES),
            core::mem::size_of::<ExtremaList>(),
            core::mem::size_of::<ExtremaHead>(),
            core::mem::size_of::<SampleExtrema>(),
            core::mem::size_of::<GnSums>(),
            core::mem::size_of::<PixelState>(),
            core::mem::size_of::<FitLanes>().div_ceil(row::LANES),
            core::mem::size_of::<IndexLanes>() / row::LANES,
            state_bytes_per_pixel(small, 320),
            state_bytes_per_pixel(vga, 640),
            state_bytes_per_pixel(large, 2048),
        ];
        assert_eq!(sizes, [52, 38, 42, 10, 78, 68, 22, 45, 32, 214, 131, 105]);
        assert_eq!([small, vga, large].map(|s| s.stride()), [1, 4, 64]);
    }
}
