//! The per-pixel state a worker owns while an angle streams, the band models it reads, what
//! it tallies, and which rows each shard holds.

use filmscope_core::solve::extrema::SampleExtrema;
use filmscope_core::solve::fit_row::{FitLanes, IndexLanes, IndexSampling};
use filmscope_core::solve::index::RatioHistogram;
use filmscope_core::solve::refine::{AngleModels, BandCoef, Knot};
use filmscope_core::solve::sweep::FitStats;
use filmscope_core::solve::{
    tracker_blocks, IndexModel, PixelState, Shard, SweepSolver, SweepSpec,
};
use filmscope_core::track::row::{TrackerLanes, LANES};

/// A shard's angle-end pass 1 ([`Shard::tally`]): votes and fit statistics.
#[derive(Debug, Default)]
pub struct Tally {
    /// The order votes.
    pub votes: RatioHistogram,
    /// The fit statistics.
    pub fit: FitStats,
}

/// What a worker tallied of its shard by an angle's end.
#[derive(Debug, Default)]
pub struct ShardTally {
    /// The tally of the shard's rows but `untallied`.
    pub tally: Box<Tally>,
    /// Image rows left for the angle's end.
    pub untallied: Vec<usize>,
}

/// The owned state of a shard of rows: its pixels' states, their extremum trackers and their
/// thickness, counters and sums (in blocks of a row's pixels), and the index's sums of the
/// pixels that keep them.
#[derive(Clone, Debug, Default)]
pub struct ShardState {
    /// Row-major pixel states.
    pub pixels: Vec<PixelState>,
    /// The pixels' trackers.
    pub trackers: Vec<TrackerLanes>,
    /// The pixels' thickness, counters and own sums.
    pub fits: Vec<FitLanes>,
    /// Which pixels keep the index's sums.
    pub sampling: IndexSampling,
    /// Their sums.
    pub index: Vec<IndexLanes>,
    /// Their whole extremum lists.
    pub lists: Vec<SampleExtrema>,
}

impl ShardState {
    /// `rows` x `width` pixels that have seen nothing, the index's sums kept by the pixels
    /// `sampling` picks ([`SweepSpec::index_sampling`]).
    pub fn empty(rows: usize, width: usize, sampling: IndexSampling) -> Self {
        let blocks = tracker_blocks(rows * width, width);
        Self {
            pixels: vec![PixelState::default(); rows * width],
            trackers: vec![TrackerLanes::EMPTY; blocks],
            fits: vec![FitLanes::EMPTY; blocks],
            sampling,
            index: vec![IndexLanes::EMPTY; rows * sampling.blocks_per_row(width)],
            lists: vec![SampleExtrema::EMPTY; rows * sampling.blocks_per_row(width) * LANES],
        }
    }

    /// Pixels of rows of `width` from image row `first_row` on that start at the
    /// thicknesses `seed` (NaN: none) with `index` ([`Shard::seed`]).
    pub fn seeded(
        first_row: usize,
        seed: &[f32],
        width: usize,
        index: IndexModel,
        spec: &SweepSpec,
    ) -> Self {
        let rows = seed.len().checked_div(width).unwrap_or(0);
        let mut state = Self::empty(rows, width, spec.index_sampling());
        let mut shard = state.shard(first_row, width);
        for (i, &d) in seed.iter().enumerate() {
            shard.seed(i, d, index, spec);
        }
        state
    }

    /// Gives the trackers' memory back, once nothing reads them (the sweep's last angle end,
    /// after [`super::run::tally_parallel`] and [`Shard::keep_tracker_flags`]; or after the last update,
    /// which kept their flags): the results take it.
    pub fn release_trackers(&mut self) {
        self.trackers = Vec::new();
    }

    /// Trackers again for an angle after they were released (a source that streams more
    /// angles than it announced).
    pub(super) fn restore_trackers(&mut self) {
        if self.trackers.is_empty() {
            self.trackers = vec![TrackerLanes::EMPTY; self.fits.len()];
        }
    }

    /// The shard over this state, its first row `first_row`.
    pub fn shard(&mut self, first_row: usize, width: usize) -> Shard<'_> {
        Shard::new(
            first_row,
            width,
            &mut self.pixels,
            &mut self.trackers,
            &mut self.fits,
            (self.sampling, &mut self.index, &mut self.lists),
        )
    }
}

/// An angle's band models, owned: each band's coefficients and their tabulated knots.
#[derive(Clone, Debug, Default)]
pub struct BandModels {
    /// One entry per band.
    pub coefs: Vec<Option<BandCoef>>,
    /// The tabulated bands' knots.
    pub knots: Vec<Knot>,
}

impl BandModels {
    /// The models of `solver`'s current angle, every band tabulated if the sensor has
    /// enough pixels to repay it (a knot costs about what one pixel's sample does computed:
    /// tables pay from twice as many pixels as knots per band).
    ///
    /// `threads` share the tabulation (the workers wait for it: measured at 128 x 96, the
    /// five angles' tables took 41.5 ms of a 100-130 ms pass on one thread).
    pub fn of(solver: &SweepSolver, threads: usize) -> Self {
        let spec = solver.spec();
        let mut coefs = vec![None; spec.bands_nm.len()];
        solver.band_models(&mut coefs);
        let mut counts = vec![0; coefs.len()];
        solver.band_knots(&coefs, &mut counts);
        let knots: usize = counts.iter().sum();
        let bands = coefs.iter().flatten().count().max(1);
        let knots = if spec.width * spec.height >= 2 * knots / bands {
            let mut table = vec![Knot::default(); knots];
            tabulate_on(solver, threads, &counts, &mut coefs, &mut table);
            table
        } else {
            Vec::new()
        };
        Self { coefs, knots }
    }

    /// A borrowed view for [`Shard::feed_row`].
    pub fn view(&self) -> AngleModels<'_> {
        AngleModels {
            coefs: &self.coefs,
            knots: &self.knots,
        }
    }
}

/// [`SweepSolver::tabulate`] on `threads` threads, the bands split into runs of about as
/// many knots (`counts`, per band).
fn tabulate_on(
    solver: &SweepSolver,
    threads: usize,
    counts: &[usize],
    coefs: &mut [Option<BandCoef>],
    table: &mut [Knot],
) {
    let share = table.len().div_ceil(threads.max(1)).max(1);
    std::thread::scope(|scope| {
        let (mut coefs, mut counts, mut table, mut first) = (coefs, counts, table, 0);
        while !coefs.is_empty() {
            // The run's bands: up to the one that fills its share of knots.
            let (mut bands, mut knots) = (0, 0);
            while bands < coefs.len() && (knots < share || bands == 0) {
                knots += counts[bands];
                bands += 1;
            }
            let knots = knots.min(table.len());
            let (run, rest) = coefs.split_at_mut(bands);
            let (part, tail) = table.split_at_mut(knots);
            if rest.is_empty() {
                solver.tabulate(run, part, first);
            } else {
                let at = first;
                scope.spawn(move || solver.tabulate(run, part, at));
            }
            (coefs, counts, table, first) = (rest, &counts[bands..], tail, first + knots);
        }
    });
}

/// Rows `first..first + n` of shard `i` of `workers` over `height` rows.
pub(super) fn shard_rows(height: usize, workers: usize, i: usize) -> (usize, usize) {
    let first = height * i / workers;
    let last = height * (i + 1) / workers;
    (first, last - first)
}
