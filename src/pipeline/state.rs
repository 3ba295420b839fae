//! The per-pixel state a worker owns while an angle streams, the band models it reads, what
//! it tallies, and which rows each worker holds ([`Strips`]).

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

/// What a worker tallied of its strips by an angle's end.
#[derive(Debug, Default)]
pub struct ShardTally {
    /// The tally of the worker's rows but `untallied`.
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

    /// Worker `worker`'s state over its strips' rows (one allocation per array however many
    /// strips: freed at once, the memory goes back to the system for the results), its
    /// pixels starting at the thicknesses of `seed` (the image's, row-major; NaN: none) with
    /// its index, where given ([`Shard::seed`]).
    pub fn for_worker(
        strips: Strips,
        worker: usize,
        spec: &SweepSpec,
        seed: Option<(&[f32], IndexModel)>,
    ) -> Self {
        let w = spec.width;
        let mut state = Self::empty(strips.rows_of(worker), w, spec.index_sampling());
        if let Some((map, index)) = seed {
            for shard in state.shards(strips.spans_of(worker), w).iter_mut() {
                let at = shard.first_row * w;
                shard.seed(&map[at..at + shard.pixels.len()], index, spec);
            }
        }
        state
    }

    /// Gives the trackers' memory back, once nothing reads them (the sweep's last angle end,
    /// after [`super::run::tally_parallel`]; or after the last update): the results take it.
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

    /// Shards over consecutive runs of this state's rows, each run's first image row and
    /// row count given by `spans` (in the state's order; their rows the state's).
    pub fn shards(
        &mut self,
        spans: impl IntoIterator<Item = (usize, usize)>,
        width: usize,
    ) -> Vec<Shard<'_>> {
        let per_row = self.sampling.blocks_per_row(width);
        let blocks = tracker_blocks(width, width);
        let released = self.trackers.is_empty();
        let mut pixels = &mut self.pixels[..];
        let mut trackers = &mut self.trackers[..];
        let mut fits = &mut self.fits[..];
        let mut index = &mut self.index[..];
        let mut lists = &mut self.lists[..];
        /// The first `n` of `rest`, `rest` left with the others.
        fn take<'a, T>(rest: &mut &'a mut [T], n: usize) -> &'a mut [T] {
            let all = std::mem::take(rest);
            let (head, tail) = all.split_at_mut(n.min(all.len()));
            *rest = tail;
            head
        }
        spans
            .into_iter()
            .map(|(first, rows)| {
                let t = if released { 0 } else { rows * blocks };
                Shard::new(
                    first,
                    width,
                    take(&mut pixels, rows * width),
                    take(&mut trackers, t),
                    take(&mut fits, rows * blocks),
                    (
                        self.sampling,
                        take(&mut index, rows * per_row),
                        take(&mut lists, rows * per_row * LANES),
                    ),
                )
            })
            .collect()
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
    /// Whether the sweep holds its index ([`AngleModels::index_held`]).
    pub index_held: bool,
}

impl BandModels {
    /// The models of `solver`'s current angle, every band tabulated over the pixels'
    /// thicknesses if the sensor has enough pixels to repay it ([`SweepSolver::band_knots`]).
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
        let knots = if knots > 0 {
            let mut table = vec![Knot::default(); knots];
            tabulate_on(solver, threads, &counts, &mut coefs, &mut table);
            table
        } else {
            Vec::new()
        };
        Self {
            coefs,
            knots,
            index_held: solver.index_held(),
        }
    }

    /// Knots tabulated, over all bands.
    pub fn knots(&self) -> usize {
        self.knots.len()
    }

    /// A borrowed view for [`Shard::feed_row`].
    pub fn view(&self) -> AngleModels<'_> {
        AngleModels {
            coefs: &self.coefs,
            knots: &self.knots,
            index_held: self.index_held,
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

/// How the image's rows are dealt to the workers: strips of `rows` consecutive rows (a
/// [`ShardState`] each), strip `k` to worker `k % workers`. Any source's row order then keeps
/// every worker busy: a band's rows top to bottom (a camera's frames, BSQ) as much as a
/// line-scan camera's lines with all their bands (BIL, BIP), whose first half would
/// otherwise all go to one worker while the other waits. One worker takes the whole image
/// as one strip.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Strips {
    height: usize,
    rows: usize,
    workers: usize,
}

impl Strips {
    /// Strips of `rows` rows of a `height`-row image for up to `workers` workers (no more
    /// workers than strips).
    pub fn new(height: usize, rows: usize, workers: usize) -> Self {
        let height = height.max(1);
        let rows = if workers <= 1 {
            height
        } else {
            rows.clamp(1, height)
        };
        let workers = workers.clamp(1, height.div_ceil(rows));
        Self {
            height,
            rows,
            workers,
        }
    }

    /// Strips in the image.
    pub fn count(&self) -> usize {
        self.height.div_ceil(self.rows)
    }

    /// Workers.
    pub fn workers(&self) -> usize {
        self.workers
    }

    /// Strip `k`'s first row and row count.
    pub fn span(&self, k: usize) -> (usize, usize) {
        let first = (k * self.rows).min(self.height);
        (first, self.rows.min(self.height - first))
    }

    /// The strip that holds image row `row`.
    pub fn of_row(&self, row: usize) -> usize {
        row / self.rows
    }

    /// The worker of strip `k`.
    pub fn worker(&self, k: usize) -> usize {
        k % self.workers
    }

    /// Worker `i`'s strips, top to bottom.
    pub fn of_worker(&self, i: usize) -> impl Iterator<Item = usize> {
        (i..self.count()).step_by(self.workers)
    }

    /// Where worker `i` keeps image row `row`, if it is its: the place of its strip among
    /// the worker's strips.
    pub fn place(&self, i: usize, row: usize) -> Option<usize> {
        let k = self.of_row(row);
        (row < self.height && self.worker(k) == i).then_some(k / self.workers)
    }

    /// Worker `i`'s first row at or after `row` (the image's height if none).
    pub fn next_row(&self, i: usize, row: usize) -> usize {
        if self.place(i, row).is_some() {
            return row;
        }
        let k = self.of_row(row);
        let next = k + (i + self.workers - self.worker(k)) % self.workers;
        (next * self.rows).min(self.height)
    }

    /// Worker `i`'s strips as first row and row count, top to bottom.
    pub fn spans_of(&self, i: usize) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.of_worker(i).map(|k| self.span(k))
    }

    /// Rows worker `i` holds.
    pub fn rows_of(&self, i: usize) -> usize {
        self.of_worker(i).map(|k| self.span(k).1).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::Strips;

    /// Every row belongs to exactly one strip and worker, the strips of a worker are found
    /// again by `place` and `next_row`, and one worker holds the image as one strip.
    #[test]
    fn strips_deal_every_row_once() {
        for (h, rows, workers) in [(1024, 4, 2), (1000, 4, 3), (7, 4, 2), (5, 8, 4), (64, 4, 1)] {
            let s = Strips::new(h, rows, workers);
            let mut seen = vec![0; h];
            for i in 0..s.workers() {
                for (place, k) in s.of_worker(i).enumerate() {
                    let (first, n) = s.span(k);
                    for (r, count) in seen.iter_mut().enumerate().skip(first).take(n) {
                        *count += 1;
                        assert_eq!(s.place(i, r), Some(place));
                        assert_eq!(s.next_row(i, r), r);
                    }
                }
                assert_eq!(
                    s.rows_of(i),
                    (0..h).filter(|&r| s.place(i, r).is_some()).count()
                );
                for r in 0..h {
                    let next = s.next_row(i, r);
                    assert!(next >= r && (next == h || s.place(i, next).is_some()));
                    assert!((r..next).all(|q| s.place(i, q).is_none()));
                }
            }
            assert!(seen.iter().all(|&n| n == 1), "{h} {rows} {workers}");
        }
        assert_eq!(Strips::new(64, 4, 1).count(), 1);
        assert_eq!(Strips::new(5, 8, 4).workers(), 1);
    }
}
