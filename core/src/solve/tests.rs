//! Shards driven through angle ends by the solver: what only the two together show.

use super::extrema::{self, SampleExtrema};
use super::fit_row::{FitLanes, IndexLanes, IndexSampling};
use super::index::RatioHistogram;
use super::refine::AngleModels;
use super::spec::paper_rig_spec;
use super::{flags, IndexModel, PixelResult, PixelState, Shard, SweepSolver};
use crate::track::row::{self, TrackerLanes};

/// Storage of a one-row shard of two lane blocks, for unit tests.
struct OneRow {
    pixels: [PixelState; ONE_ROW],
    trackers: [TrackerLanes; 2],
    fits: [FitLanes; 2],
    index: [IndexLanes; 2],
    lists: [SampleExtrema; 2 * row::LANES],
}

/// Pixels of a [`OneRow`].
const ONE_ROW: usize = 2 * row::LANES;

impl OneRow {
    fn new() -> Self {
        Self {
            pixels: [(); ONE_ROW].map(|_| PixelState::default()),
            trackers: [TrackerLanes::EMPTY; 2],
            fits: [FitLanes::EMPTY; 2],
            index: [IndexLanes::EMPTY; 2],
            lists: [SampleExtrema::EMPTY; 2 * row::LANES],
        }
    }

    fn shard(&mut self) -> Shard<'_> {
        self.sampled(IndexSampling::ALL)
    }

    /// The row as a shard whose pixels of `sampling` keep the index's sums.
    fn sampled(&mut self, sampling: IndexSampling) -> Shard<'_> {
        Shard::new(
            0,
            ONE_ROW,
            &mut self.pixels,
            &mut self.trackers,
            &mut self.fits,
            (
                sampling,
                &mut self.index[..sampling.blocks_per_row(ONE_ROW)],
                &mut self.lists[..sampling.blocks_per_row(ONE_ROW) * row::LANES],
            ),
        )
    }
}

mod release_tests {
    use super::*;

    const W: usize = ONE_ROW;

    /// Feeds one angle to a one-row shard: fringes every 40 bands, but pixel 3 every 12
    /// (more extrema than a list holds: its tracker overflows).
    fn feed(shard: &mut Shard<'_>, solver: &SweepSolver) {
        let spec = solver.spec().clone();
        shard.begin_angle();
        let models = AngleModels {
            coefs: &[],
            knots: &[],
            index_held: solver.index_held(),
        };
        for b in 0..spec.bands_nm.len() {
            let values: [f32; W] = core::array::from_fn(|i| {
                let period = if i == 3 { 12.0 } else { 40.0 };
                let x = b as f32 * core::f32::consts::TAU / period;
                0.05 + 0.03 * libm::cosf(x) + 1e-4 * libm::sinf(7.3 * (b * W + i) as f32)
            });
            shard.feed_row(spec.options, models, b, 0, &values);
        }
    }

    /// An overflow found at the sweep's last angle reaches the results whether the trackers
    /// are kept through the update or released before it (a shard without trackers): the
    /// pixel's flags hold it from the moment it happens.
    #[test]
    fn a_released_tracker_leaves_its_overflow_in_the_results() {
        let mut solver = SweepSolver::new(paper_rig_spec(W, 1), Some(IndexModel::constant(1.38)));
        solver.begin_angle(10.0);
        let run = |release: bool| {
            let mut storage = OneRow::new();
            let mut out = [PixelResult::UNSOLVED; W];
            feed(&mut storage.shard(), &solver);
            if release {
                let mut shard = Shard::new(
                    0,
                    W,
                    &mut storage.pixels,
                    &mut [],
                    &mut storage.fits,
                    (IndexSampling::ALL, &mut storage.index, &mut storage.lists),
                );
                shard.update(&solver, Some(&mut out), |_| {});
            } else {
                storage.shard().update(&solver, Some(&mut out), |_| {});
            }
            out.map(|r| r.flags)
        };
        let (kept, released) = (run(false), run(true));
        assert_eq!(kept, released);
        let overflow = |f: u16| f & flags::TRACKER_OVERFLOW != 0;
        assert!(overflow(released[3]), "{:#x}", released[3]);
        assert_eq!(released.iter().filter(|&&f| overflow(f)).count(), 1);
    }
}

mod vote_tests {
    use super::*;

    const W: usize = ONE_ROW;

    /// One angle of a 800 nm film of 1.38 (two-beam fringes, a ripple that differs pixel by
    /// pixel) fed to `shard`, its extrema so far voted into `early` `ahead` bands before the
    /// last (none if `early` is `None`).
    fn feed(
        shard: &mut Shard<'_>,
        solver: &SweepSolver,
        deg: f64,
        ahead: usize,
        mut early: Option<&mut RatioHistogram>,
    ) {
        let spec = solver.spec().clone();
        let cos_t = libm::sqrt(1.0 - spec.x_of(deg) / (1.38 * 1.38));
        let models = AngleModels {
            coefs: &[],
            knots: &[],
            index_held: solver.index_held(),
        };
        let bands = spec.bands_nm.len();
        for (b, &l) in spec.bands_nm.iter().enumerate() {
            let phase = 4.0 * core::f64::consts::PI * 1.38 * 800.0 * cos_t / l;
            let values: [f32; W] = core::array::from_fn(|i| {
                (0.05 + 0.03 * libm::cos(phase)) as f32
                    + 2e-4 * libm::sinf(7.3 * (b * W + i) as f32)
            });
            shard.feed_row(spec.options, models, b, 0, &values);
            if b + 1 + ahead == bands {
                if let Some(votes) = early.as_deref_mut() {
                    shard.vote_rows(solver, 0..1, votes);
                }
            }
        }
    }

    /// Only the index's sample of pixels votes and pools its noise: the votes are those of
    /// its pixels' extrema, count for count, and fewer than every pixel's.
    #[test]
    fn the_tally_counts_the_index_sample_only() {
        let spec = paper_rig_spec(W, 1);
        let mut every = None;
        for stride in [1, 4] {
            let mut solver = SweepSolver::new(spec.clone(), None);
            let mut storage = OneRow::new();
            let mut shard = storage.sampled(IndexSampling::one_in(stride));
            solver.begin_angle(10.0);
            shard.begin_angle();
            feed(&mut shard, &solver, 10.0, 0, None);
            solver.end_angle_all(core::slice::from_mut(&mut shard));
            solver.begin_angle(40.0);
            shard.begin_angle();
            feed(&mut shard, &solver, 40.0, 0, None);
            let (votes, fit) = shard.tally(&solver);
            let g = solver.pair_geometry().expect("a pair");
            let mut own = RatioHistogram::default();
            for c in (0..W).step_by(stride) {
                let lists = shard.lists_at(0, c).expect("a sampled pixel");
                let reference = extrema::reference(&shard.pixels[c].anchor, Some(lists));
                own.vote(g, reference, lists.unvoted(), |b| spec.wavelength_at(b));
            }
            assert!(votes == own, "stride {stride}: not the sample's votes");
            let pooled: u32 = fit.noise.counts.iter().sum();
            assert_eq!(pooled as usize, W / stride, "stride {stride}");
            let total: u32 = votes.counts.iter().sum();
            match every {
                None => every = Some(total),
                Some(all) => assert!(4 * total <= all + W as u32, "{total} of {all}"),
            }
        }
    }

    /// Votes taken while the angle streams and the tally's of the extrema found since add up
    /// to the tally's of all of them, whenever the early vote is taken: the histogram is the
    /// same count for count.
    #[test]
    fn early_votes_and_the_tally_count_every_extremum_once() {
        let spec = paper_rig_spec(W, 1);
        for ahead in [0, 5, 16, 60, 150] {
            let mut whole = None;
            for early in [false, true] {
                let mut solver = SweepSolver::new(spec.clone(), None);
                let mut storage = OneRow::new();
                let mut shard = storage.shard();
                solver.begin_angle(10.0);
                shard.begin_angle();
                feed(&mut shard, &solver, 10.0, ahead, None);
                solver.end_angle_all(core::slice::from_mut(&mut shard));
                solver.begin_angle(40.0);
                shard.begin_angle();
                let mut votes = RatioHistogram::default();
                feed(
                    &mut shard,
                    &solver,
                    40.0,
                    ahead,
                    early.then_some(&mut votes),
                );
                let (tallied, _) = shard.tally(&solver);
                let early_total: u32 = votes.counts.iter().sum();
                votes.merge(&tallied);
                let total: u32 = votes.counts.iter().sum();
                assert!(total >= 2 * W as u32, "ahead {ahead}: {total} votes");
                if early && (16..=60).contains(&ahead) {
                    assert!(
                        2 * early_total > total,
                        "ahead {ahead}: {early_total} of {total}"
                    );
                }
                match &whole {
                    None => whole = Some(votes),
                    Some(w) => assert!(*w == votes, "ahead {ahead}: the counts differ"),
                }
            }
        }
    }
}
