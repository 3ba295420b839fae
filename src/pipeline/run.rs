//! Wires the stages to bounded channels and threads.
//!
//! ```text
//! source thread -> [cap] -> calibrate thread -> [cap] -> worker 1 (rows of shard 1)
//!                                            \-> [cap] -> worker 2 (rows of shard 2)
//!                                  control --> coordinator (this thread): angle ends
//! ```
//!
//! Every channel is bounded, so a slow stage slows the source and memory never grows with
//! the stream. Each worker owns the per-pixel state of its rows while an angle streams, and
//! tallies each row (the first angle-end pass) once the row has seen the angle's last band
//! (the last shard, whose rows arrive last, leaves the rows it completes while behind the
//! stream to the angle's end); at the angle's end it hands the state and its tally to the
//! coordinator, which runs the rest of the solver's angle-end passes on all cores (one scoped
//! thread per shard) and hands the state back with the next angle.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{bounded, Receiver, Sender};
use filmscope_core::solve::extrema::SampleExtrema;
use filmscope_core::solve::fit_row::{FitLanes, IndexLanes, IndexSampling};
use filmscope_core::solve::index::{RatioHistogram, RatioSums};
use filmscope_core::solve::refine::{AngleModels, BandCoef, Knot};
use filmscope_core::solve::sweep::SolverOptions;
use filmscope_core::solve::sweep::{FitStats, SchurSums};
use filmscope_core::solve::{
    tracker_blocks, AngleReport, IndexModel, PixelResult, PixelState, Shard, SweepContext,
    SweepSolver, SweepSpec,
};
use filmscope_core::track::row::{TrackerLanes, LANES};
use filmscope_core::track::{pack_sample, unpack_sample};

use super::held::HeldBlock;
use super::ties::TieSet;
use crate::source::{calibrate_block, Source, StreamMsg};

/// How to run the pipeline.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PipelineConfig {
    /// Capacity of every channel, in messages.
    pub channel_capacity: usize,
    /// Worker threads (shards of rows).
    pub workers: usize,
    /// Bands a worker holds before feeding them to its pixels row by row: every band streams
    /// past every pixel's state, so on a sensor whose state does not fit the caches a sample
    /// costs its state's memory traffic; holding `band_block` bands divides that traffic by
    /// `band_block` at `2 * band_block` bytes per pixel of row buffers (packed samples,
    /// [`pack_sample`]; 1: feed each row as it arrives). Over an angle's last bands the
    /// blocks shrink (`block_bands`), so that little is left to feed when its last row
    /// arrives. Four: on a 4 MP sweep the same pace as eight (the software camera's 131-134
    /// M samples/s either way; two: 119 M), at 8 bytes a pixel of peak memory fewer
    /// (`filmscope bench-rss-child`: 540.5 -> 508.8 MB; two 492.8).
    pub band_block: usize,
    /// What the solver may use.
    pub solver: SolverOptions,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            channel_capacity: 64,
            workers: 2,
            band_block: 4,
            solver: SolverOptions::default(),
        }
    }
}

/// What the pipeline produced for one sweep.
#[derive(Clone, Debug)]
pub struct SweepOutput {
    /// The sweep.
    pub spec: SweepSpec,
    /// Per-pixel results, row-major.
    pub results: Vec<PixelResult>,
    /// The final index model.
    pub index: Option<IndexModel>,
    /// Its standard error.
    pub index_sigma: f64,
    /// The typical RMS residual of the full-spectrum fit.
    pub residual_sigma: Option<f64>,
    /// The image's typical noise, from the spectra themselves.
    pub noise_sigma: Option<f32>,
    /// What each angle added.
    pub angles: Vec<AngleReport>,
    /// The final index fit: model choice and its evidence.
    pub index_fit: Option<filmscope_core::solve::index::IndexFit>,
    /// Whether the film model failed to explain the spectra (every pixel flagged).
    pub model_mismatch: bool,
    /// Whether the index came from the full spectra (else from the extremum shifts).
    pub spectral_index: bool,
    /// The largest chi-square gains of the full-spectrum steps with 1, 2, 3 index terms.
    pub spectral_gains: [f64; 3],
    /// The index after the last full-spectrum step, taken or not (where another pass starts).
    pub spectral_candidate: Option<IndexModel>,
    /// Wall time from the first message to the maps being ready.
    pub stream_time: Duration,
    /// Wall time from the last row of the last angle to the maps being ready.
    pub solve_latency: Duration,
    /// Where that time went ([`LatencyParts`]).
    pub latency_parts: LatencyParts,
    /// Band samples processed.
    pub samples: u64,
    /// Bytes of solver state per pixel.
    pub state_bytes_per_pixel: usize,
}

/// The last angle's end, pass by pass: from its last row to the workers' hand-over
/// (`drain`: rows still queued or being fed and tallied), then [`tally_parallel`]'s pass,
/// the results' allocation and [`update_parallel`]'s passes.
#[derive(Clone, Copy, Debug, Default)]
pub struct LatencyParts {
    /// Last row to every worker's state handed over.
    pub drain: Duration,
    /// The rows the workers left untallied, and the votes and fit statistics set.
    pub tally: Duration,
    /// The sweep's last angle: the trackers given back and the results allocated (their
    /// pages faulted in).
    pub results: Duration,
    /// Window and Schur sums, and the index step.
    pub sums: Duration,
    /// Every pixel's update and result.
    pub update: Duration,
    /// Ties resolved in image order, their results, the solver's angle end.
    pub ties: Duration,
}

/// A sweep that could not be completed.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct PipelineError(pub String);

/// Rows for a worker, on the data channel (from the calibrate stage).
enum WorkerMsg {
    /// `(band, first row, rows, packed samples)` ([`pack_sample`]).
    Rows(u16, u32, u32, Vec<u16>),
    End,
}

/// The state of an angle for a worker, on its own channel (from the coordinator): rows are
/// read only after it, so rows of the next angle can never reach the previous one's state.
/// The solver's context as the angle began tallies the rows that have seen the angle's last
/// band.
/// The last element: the angles left in the sweep, this one included (the worker sizes its
/// held block for the next angle, or gives it back after the last: [`HeldBlock`]).
type Start = (ShardState, Arc<BandModels>, Arc<SweepContext>, usize);

/// A shard's angle-end pass 1 ([`Shard::tally`]): votes and fit statistics.
pub type Tally = (RatioHistogram, FitStats);

/// What a worker tallied of its shard by an angle's end.
#[derive(Debug, Default)]
pub struct ShardTally {
    /// The tally of the shard's rows but `untallied`.
    pub tally: Box<Tally>,
    /// Image rows left for the angle's end.
    pub untallied: Vec<usize>,
}

/// What a worker hands back at an angle's end: its state and what it tallied of it.
type Done = (usize, ShardState, ShardTally);

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
    /// after [`tally_parallel`] and [`Shard::keep_tracker_flags`]; or after the last update,
    /// which kept their flags): the results take it.
    pub fn release_trackers(&mut self) {
        self.trackers = Vec::new();
    }

    /// Trackers again for an angle after they were released (a source that streams more
    /// angles than it announced).
    fn restore_trackers(&mut self) {
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

enum Control {
    Angle(f64),
    AngleEnd(Instant),
    SweepEnd,
    Abort(String),
}

/// Rows `first..first + n` of shard `i` of `workers` over `height` rows.
fn shard_rows(height: usize, workers: usize, i: usize) -> (usize, usize) {
    let first = height * i / workers;
    let last = height * (i + 1) / workers;
    (first, last - first)
}

/// What a sweep starts from: the index of an earlier pass over the same capture or of the
/// last sweep on a production line, and what moves it.
#[derive(Clone, Debug, PartialEq)]
pub struct Prior {
    /// The starting index.
    pub index: IndexModel,
    /// What moves it during the sweep.
    pub update: PriorUpdate,
    /// Every pixel's starting thickness, row-major (a film without fringe pairs, from the
    /// global search on sampled spectra): such pixels need no extrema. The map the sweep's
    /// output replaces, not per-pixel state.
    pub seed: Option<Arc<Vec<f32>>>,
}

impl Prior {
    /// `index`, moved by `update`, from `seed`'s thicknesses where given.
    pub fn new(index: IndexModel, update: PriorUpdate, seed: Option<Arc<Vec<f32>>>) -> Self {
        Self {
            index,
            update,
            seed,
        }
    }
}

/// How a sweep treats its prior index.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PriorUpdate {
    /// The extremum shifts re-estimate it as the angles arrive (a production line's next
    /// sweep).
    Shifts,
    /// It is held (a second pass over the same data, whose first pass estimated it from
    /// every angle: the early angles' partial estimates would only move it away), so every
    /// pixel is refined from the second angle on ([`SweepSolver::with_held_index`]).
    Hold,
    /// The full spectra move it ([`SweepSolver::with_spectral_index`]).
    FullSpectra,
}

/// Runs one sweep from `source` through the pipeline; `on_rows` is told of every block of
/// rows calibrated (for progress bars). `prior` seeds the index (e.g. the last sweep's).
pub fn run_sweep(
    source: &mut dyn Source,
    config: PipelineConfig,
    prior: Option<Prior>,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<SweepOutput, PipelineError> {
    sweep(source, config, prior, None, on_rows)
}

/// What the calibrate stage hands calibrated rows to, besides the workers: the estimator's
/// pixel sample, which keeps the rows it wants.
pub trait Tap {
    /// An angle starts.
    fn angle(&mut self, incidence_deg: f64);
    /// Calibrated rows `first_row..first_row + rows` of `band` at the current angle.
    fn rows(&mut self, band: usize, first_row: usize, rows: usize, values: &[f32]);
    /// The image rows it reads, sorted and distinct (a stream may skip the others).
    fn image_rows(&self) -> Vec<usize>;
}

/// A pixel sample held as the sweep streams and what the caller makes of it as each angle
/// completes.
pub struct SampleHook<'a> {
    /// The sample the calibrate stage feeds with every calibrated block.
    pub tap: &'a Mutex<dyn Tap + Send>,
    /// Called at each angle's end (before the solver's) with the number of angles complete
    /// (the stream goes on meanwhile): the index the solver takes from then on, if any
    /// ([`SweepSolver::set_external_index`]).
    pub refit: &'a mut dyn FnMut(usize) -> Option<IndexModel>,
}

/// [`run_sweep`] for a source that streams once: the index comes from `hook`'s sample,
/// refitted as each angle completes, instead of from the extremum shifts.
pub fn run_sweep_sampled(
    source: &mut dyn Source,
    config: PipelineConfig,
    hook: SampleHook<'_>,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<SweepOutput, PipelineError> {
    sweep(source, config, None, Some(hook), on_rows)
}

fn sweep(
    source: &mut dyn Source,
    config: PipelineConfig,
    prior: Option<Prior>,
    mut hook: Option<SampleHook<'_>>,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<SweepOutput, PipelineError> {
    let tap = hook.as_ref().map(|h| h.tap);
    let mut spec = source.spec().clone();
    spec.options = config.solver;
    let (w, h) = (spec.width, spec.height);
    let workers = config.workers.clamp(1, h.max(1));
    let cap = config.channel_capacity.max(1);
    let start = Instant::now();
    let mut solver = SweepSolver::new(spec.clone(), prior.as_ref().map(|p| p.index));
    match prior.as_ref().map(|p| p.update) {
        Some(PriorUpdate::FullSpectra) => solver = solver.with_spectral_index(),
        Some(PriorUpdate::Hold) => solver = solver.with_held_index(),
        _ => {}
    }
    let mut solver = Box::new(solver);
    let seed = prior
        .as_ref()
        .and_then(|p| Some((p.seed.clone()?, p.index)));
    if seed.as_ref().is_some_and(|(map, _)| map.len() != w * h) {
        return Err(PipelineError(format!(
            "the thickness seed map does not have {w} x {h} pixels"
        )));
    }
    let mut states: Vec<Option<ShardState>> = (0..workers)
        .map(|i| {
            let (first, rows) = shard_rows(h, workers, i);
            Some(match &seed {
                Some((map, index)) => {
                    ShardState::seeded(first, &map[first * w..(first + rows) * w], w, *index, &spec)
                }
                None => ShardState::empty(rows, w, spec.index_sampling()),
            })
        })
        .collect();
    let mut reports = Vec::new();
    let mut samples = 0u64;
    let mut last_row_at = Instant::now();
    let mut latency_parts = LatencyParts::default();
    // The results are made by the last angle's update pass (the angles announced tell which
    // is last), else by a pass of their own once the sweep has ended. They are allocated
    // then, once the trackers are released (the sweep's peak memory does not hold both).
    let angles = source.angles_deg().len();
    let mut results = Vec::new();
    let mut results_at = None;

    std::thread::scope(|scope| -> Result<(), PipelineError> {
        let (src_tx, src_rx) = bounded::<StreamMsg>(cap);
        let (ctl_tx, ctl_rx) = bounded::<Control>(cap);
        let (done_tx, done_rx) = bounded::<Done>(workers);
        let mut worker_txs = Vec::new();
        let mut start_txs = Vec::new();
        for i in 0..workers {
            let (tx, rx) = bounded::<WorkerMsg>(cap);
            let (start_tx, start_rx) = bounded::<Start>(1);
            worker_txs.push(tx);
            start_txs.push(start_tx);
            let done = done_tx.clone();
            let (first, _) = shard_rows(h, workers, i);
            let options = spec.options;
            let band_block = config.band_block.max(1);
            let block = [band_block, spec.bands_nm.len()];
            // The last shard's rows are the last to arrive: it leaves those it cannot keep up
            // with to the angle's end, where all cores tally them (the others have time).
            let last_shard = i + 1 == workers;
            scope
                .spawn(move || worker(i, first, w, options, block, last_shard, start_rx, rx, done));
        }
        drop(done_tx);
        scope.spawn(move || source.stream(&src_tx));
        scope.spawn(move || {
            calibrate_stage(src_rx, ctl_tx, worker_txs, (w, h), workers, tap, on_rows)
        });

        let mut abort = None;
        for msg in ctl_rx.iter() {
            match msg {
                Control::Angle(deg) => {
                    solver.begin_angle(deg);
                    let snapshot = Arc::new(BandModels::of(&solver, workers));
                    let began = Arc::new(solver.context().clone());
                    let left = angles.saturating_sub(solver.angles_done()).max(1);
                    for (i, tx) in start_txs.iter().enumerate() {
                        let mut st = states[i].take().unwrap_or_default();
                        st.restore_trackers();
                        if tx
                            .send((st, snapshot.clone(), began.clone(), left))
                            .is_err()
                        {
                            abort = Some("a worker stopped".to_owned());
                        }
                    }
                }
                Control::AngleEnd(at) => {
                    last_row_at = at;
                    let mut tallies: Vec<Option<ShardTally>> = (0..workers).map(|_| None).collect();
                    for _ in 0..workers {
                        match done_rx.recv() {
                            Ok((i, st, tally)) => {
                                states[i] = Some(st);
                                tallies[i] = Some(tally);
                            }
                            Err(_) => abort = Some("a worker stopped".to_owned()),
                        }
                    }
                    if abort.is_some() {
                        break;
                    }
                    let mut owned: Vec<ShardState> = states
                        .iter_mut()
                        .map(|s| s.take().unwrap_or_default())
                        .collect();
                    let mut shards: Vec<Shard<'_>> = owned
                        .iter_mut()
                        .enumerate()
                        .map(|(i, st)| st.shard(shard_rows(h, workers, i).0, w))
                        .collect();
                    let last = solver.angles_done() + 1 == angles;
                    if let Some(hook) = hook.as_mut() {
                        let complete = solver.angles_done() + 1;
                        if let Some(m) = (hook.refit)(complete) {
                            solver.set_external_index(m);
                        }
                    }
                    let mut parts = LatencyParts {
                        drain: at.elapsed(),
                        ..LatencyParts::default()
                    };
                    tally_parallel(&mut solver, &mut shards, tallies, &mut parts);
                    let releasing = Instant::now();
                    if last {
                        // The trackers are read no more (their flags kept): the results
                        // take their memory, not memory of their own on top of the state.
                        each(&mut shards, Shard::keep_tracker_flags);
                        drop(shards);
                        owned.iter_mut().for_each(ShardState::release_trackers);
                        results = vec![PixelResult::UNSOLVED; w * h];
                        shards = owned
                            .iter_mut()
                            .enumerate()
                            .map(|(i, st)| st.shard(shard_rows(h, workers, i).0, w))
                            .collect();
                    }
                    parts.results = releasing.elapsed();
                    let out = last.then_some(results.as_mut_slice());
                    let report = update_parallel(&mut solver, &mut shards, out, &mut parts);
                    reports.push(report);
                    latency_parts = parts;
                    if last {
                        results_at = Some(solver.angles_done());
                    }
                    samples += (w * h * spec.bands_nm.len()) as u64;
                    drop(shards);
                    for (i, st) in owned.into_iter().enumerate() {
                        states[i] = Some(st);
                    }
                }
                Control::SweepEnd => break,
                Control::Abort(e) => {
                    abort = Some(e);
                    break;
                }
            }
        }
        // Closing the start channels ends the workers.
        drop(start_txs);
        drop(ctl_rx);
        match abort {
            Some(e) => Err(PipelineError(e)),
            None => Ok(()),
        }
    })?;

    if solver.angles_done() < 2 {
        return Err(PipelineError(format!(
            "the stream ended after {} angle(s); at least two are needed",
            solver.angles_done()
        )));
    }
    if results_at != Some(solver.angles_done()) {
        let mut owned: Vec<ShardState> =
            states.into_iter().map(Option::unwrap_or_default).collect();
        // The last update kept the trackers' flags in the pixels'.
        owned.iter_mut().for_each(ShardState::release_trackers);
        if results.len() != w * h {
            results = vec![PixelResult::UNSOLVED; w * h];
        }
        std::thread::scope(|scope| {
            let mut rest = results.as_mut_slice();
            for (i, st) in owned.iter_mut().enumerate() {
                let (first, rows) = shard_rows(h, workers, i);
                let (mine, tail) = rest.split_at_mut(rows * w);
                rest = tail;
                let solver = &solver;
                scope.spawn(move || st.shard(first, w).finish(solver, mine));
            }
        });
    }
    let done = Instant::now();
    let state_bytes_per_pixel =
        filmscope_core::solve::state_bytes_per_pixel(spec.index_sampling(), spec.width);
    Ok(SweepOutput {
        spec,
        results,
        index: solver.index(),
        index_sigma: solver.index_sigma(),
        index_fit: solver.index_fit(),
        model_mismatch: solver.model_mismatch(),
        spectral_index: solver.spectral_index(),
        spectral_gains: solver.spectral_gains(),
        spectral_candidate: solver.spectral_candidate(),
        residual_sigma: solver.residual_sigma(),
        noise_sigma: solver.noise_sigma(),
        angles: reports,
        stream_time: done - start,
        solve_latency: done - last_row_at,
        latency_parts,
        samples,
        state_bytes_per_pixel,
    })
}

/// Bands of the block that starts at `band` of an angle's `bands`: `band_block`, but at most
/// half of the bands left (rounded up) and at least [`FINAL_BLOCK_BANDS`] (or what is left).
/// A block is fed once its last band has arrived, so whatever is still to feed when the
/// angle's last row arrives is latency: with the blocks halving towards the end, each is fed
/// while the next (half as many bands) arrives, and the angle's last block is fed row by row
/// as its last band arrives ([`streams_rows`]).
pub fn block_bands(band: usize, bands: usize, band_block: usize) -> usize {
    let left = bands.saturating_sub(band);
    band_block
        .min(left.div_ceil(2))
        .max(FINAL_BLOCK_BANDS.min(band_block))
        .min(left)
        .max(1)
}

/// Bands of an angle's last block. Feeding a block costs one pass over its pixels' state
/// (memory traffic, the same for any number of bands) and each band's arithmetic; the last
/// block is fed as its last band's rows arrive, so what is left when the angle's last row
/// arrives is the part of that pass the band's arrival did not cover. One band a block (one
/// pass a band) left the workers a band behind; four let the block before it be fed while
/// its first three arrive.
pub const FINAL_BLOCK_BANDS: usize = 4;

/// Whether the block of `limit` bands that starts at `first` is the angle's last (of
/// `bands`): its rows are fed as its last band's rows arrive (in row order), each row of
/// every band it holds at once.
pub fn streams_rows(first: usize, limit: usize, bands: usize) -> bool {
    first + limit >= bands
}

/// A worker: `block` is `[band_block, bands per angle]`;
/// `last_shard`: whether its rows are the last of each band (it defers the tally of rows it
/// cannot keep up with).
#[allow(clippy::too_many_arguments)]
fn worker(
    index: usize,
    first_row: usize,
    width: usize,
    options: SolverOptions,
    block: [usize; 2],
    last_shard: bool,
    start: Receiver<Start>,
    rows: Receiver<WorkerMsg>,
    done: Sender<Done>,
) {
    let [band_block, bands] = block;
    let mut held = HeldBlock::default();
    for (mut st, models, began, angles_left) in start.iter() {
        let mut shard = st.shard(first_row, width);
        shard.begin_angle();
        let shard_rows = shard.rows();
        held.size_for(band_block * shard_rows * width);
        let mut tally = RowTally::new(began, bands, shard_rows, last_shard);
        let (mut bands_held, mut rows_of_band, mut limit) = (0, 0, band_block);
        // The block's first band, and the image row below which its held rows were fed
        // (the angle's last block: [`streams_rows`]).
        let (mut first_band, mut fed_to) = (0, shard.first_row);
        loop {
            match rows.recv() {
                Ok(WorkerMsg::Rows(band, row, n, values)) => {
                    // Rows waiting: the worker is behind the stream.
                    let behind = !rows.is_empty();
                    if !held.fits(values.len()) {
                        // Only rows sent twice overfill a block: feed what it holds.
                        feed_rest(
                            &mut shard, options, &models, &mut held, fed_to, &mut tally, behind,
                        );
                        bands_held = 0;
                    }
                    if held.last_band().is_none_or(|b| b != band) {
                        if bands_held == limit {
                            feed_rest(
                                &mut shard, options, &models, &mut held, fed_to, &mut tally, behind,
                            );
                            bands_held = 0;
                        }
                        if bands_held == 0 {
                            first_band = usize::from(band);
                            limit = block_bands(first_band, bands, band_block);
                            fed_to = shard.first_row;
                        }
                        bands_held += 1;
                        rows_of_band = 0;
                    }
                    rows_of_band += n as usize;
                    let rows_in = row as usize..(row + n) as usize;
                    held.push(band, row, n, &values);
                    // The message's memory goes back before the block is fed.
                    drop(values);
                    if limit == 1 || (bands_held == limit && rows_of_band >= shard_rows) {
                        // A full block is fed at once, not when the next band starts (a block
                        // of one band as its rows arrive): the rows still held when the angle
                        // ends are latency.
                        feed_rest(
                            &mut shard, options, &models, &mut held, fed_to, &mut tally, behind,
                        );
                        bands_held = 0;
                    } else if bands_held == limit
                        && rows_in.start == fed_to
                        && streams_rows(first_band, limit, bands)
                    {
                        let part = fed_to..rows_in.end;
                        feed_held(
                            &mut shard, options, &models, &held, part, &mut tally, behind,
                        );
                        fed_to = rows_in.end;
                    }
                }
                Ok(WorkerMsg::End) => break,
                // The calibrate stage stopped mid-angle: hand back what we have.
                Err(_) => break,
            }
        }
        feed_rest(
            &mut shard, options, &models, &mut held, fed_to, &mut tally, true,
        );
        // After the last angle, given back before the state is: the coordinator allocates
        // the results then.
        if angles_left <= 1 {
            held.release();
        }
        let tally = tally.finish(&shard);
        if done.send((index, st, tally)).is_err() {
            return;
        }
    }
}

/// Bands before a row's last at which its extrema so far are voted ([`Shard::vote_rows`]):
/// the halving blocks of an angle's end ([`block_bands`]) span about twice the band block,
/// and an extremum is confirmed a few bands after it, so most of a row's extrema are voted
/// while the angle streams and few are left to its tally.
const VOTE_AHEAD_BANDS: u32 = 16;

/// A worker's angle-end pass 1 made row by row: a row is tallied ([`Shard::tally_rows`]) as
/// soon as it has seen the angle's last band, its state in cache and later rows still
/// streaming, so that after the angle's last row little is left to tally.
struct RowTally {
    /// The solver's context as the angle began (the pair geometry).
    solver: Arc<SweepContext>,
    /// Bands per angle.
    bands: u32,
    /// Bands fed to each row of the shard.
    fed: Vec<u32>,
    tally: Box<Tally>,
    /// Votes of the extrema found before each row's last [`VOTE_AHEAD_BANDS`] bands
    /// ([`Shard::vote_rows`]): kept apart, as they count whether or not the rows' tallies do.
    early_votes: Box<RatioHistogram>,
    /// Whether a row completed while rows wait in the queue is left to the angle's end.
    defer_if_behind: bool,
    /// Rows left to the angle's end.
    deferred: Vec<usize>,
}

impl RowTally {
    fn new(solver: Arc<SweepContext>, bands: usize, rows: usize, defer_if_behind: bool) -> Self {
        Self {
            solver,
            bands: bands as u32,
            fed: vec![0; rows],
            tally: Box::default(),
            early_votes: Box::default(),
            defer_if_behind,
            deferred: Vec::new(),
        }
    }

    /// Counts a band fed to image row `row` of `shard`, votes the row's extrema so far
    /// [`VOTE_AHEAD_BANDS`] bands before its last, and tallies the row when that was its
    /// last (or defers it, if `behind`: rows wait in the worker's queue).
    fn fed(&mut self, shard: &mut Shard<'_>, row: usize, behind: bool) {
        let Some(n) = row
            .checked_sub(shard.first_row)
            .and_then(|k| self.fed.get_mut(k))
        else {
            return;
        };
        *n += 1;
        if *n + VOTE_AHEAD_BANDS == self.bands {
            shard.vote_rows(&self.solver, row..row + 1, &mut self.early_votes);
        }
        if *n == self.bands {
            if behind && self.defer_if_behind {
                self.deferred.push(row);
            } else {
                let (votes, fit) = &mut *self.tally;
                shard.tally_rows(&self.solver, row..row + 1, votes, fit);
            }
        }
    }

    /// What was tallied of `shard`: when every row was fed the angle's band count (each was
    /// tallied or deferred at its last feed), the tally and the deferred rows; if any row was
    /// fed more or fewer times, no row's tally counts and the whole shard is left (the early
    /// votes count either way).
    fn finish(self, shard: &Shard<'_>) -> ShardTally {
        let (mut tally, untallied) = if self.fed.iter().all(|&n| n == self.bands) {
            (self.tally, self.deferred)
        } else {
            let all = (shard.first_row..shard.first_row + shard.rows()).collect();
            (Box::default(), all)
        };
        // The early votes count either way: a row's tally votes only the extrema after them.
        tally.0.merge(&self.early_votes);
        ShardTally { tally, untallied }
    }
}

/// Feeds the held rows from image row `from` on ([`feed_held`]) and empties `held`: a block
/// done (its rows before `from` were fed as they arrived, [`streams_rows`]).
fn feed_rest(
    shard: &mut Shard<'_>,
    options: SolverOptions,
    models: &BandModels,
    held: &mut HeldBlock,
    from: usize,
    tally: &mut RowTally,
    behind: bool,
) {
    feed_held(
        shard,
        options,
        models,
        held,
        from..usize::MAX,
        tally,
        behind,
    );
    held.clear();
}

/// Feeds the held rows of image rows `rows` to the shard a block of rows at a time, each
/// block's bands in the order they arrived (so every pixel sees its bands in order); each
/// row's last band of the angle tallies it.
fn feed_held(
    shard: &mut Shard<'_>,
    options: SolverOptions,
    models: &BandModels,
    held: &HeldBlock,
    rows: std::ops::Range<usize>,
    tally: &mut RowTally,
    behind: bool,
) {
    /// Bytes of pixel state a block of rows should keep in cache while its bands pass.
    const BLOCK_BYTES: usize = 256 * 1024;
    let width = shard.width;
    let bytes = filmscope_core::solve::state_bytes_per_pixel(shard.sampling(), width);
    let block_rows = (BLOCK_BYTES / (width * bytes).max(1)).max(1);
    let (Some(lo), Some(hi)) = (
        held.entries().iter().map(|h| h.image_rows().start).min(),
        held.entries().iter().map(|h| h.image_rows().end).max(),
    ) else {
        return;
    };
    let (lo, hi) = (lo.max(rows.start), hi.min(rows.end));
    let mut unpacked = vec![0.0; width];
    for block in (lo..hi).step_by(block_rows) {
        let block_end = (block + block_rows).min(hi);
        for e in held.entries() {
            let image_rows = e.image_rows();
            for r in image_rows.start.max(block)..image_rows.end.min(block_end) {
                let k = r - image_rows.start;
                for (x, &q) in unpacked.iter_mut().zip(held.row(e, k, width)) {
                    *x = unpack_sample(q);
                }
                shard.feed_row(options, models.view(), usize::from(e.band), r, &unpacked);
                tally.fed(shard, r, behind);
            }
        }
    }
}

fn calibrate_stage(
    rx: Receiver<StreamMsg>,
    control: Sender<Control>,
    workers: Vec<Sender<WorkerMsg>>,
    (width, height): (usize, usize),
    n_workers: usize,
    tap: Option<&Mutex<dyn Tap + Send>>,
    on_rows: &(dyn Fn(u64) + Sync),
) {
    let owner = |row: usize| {
        // The shard whose range holds `row`.
        let mut i = (row * n_workers / height.max(1)).min(n_workers - 1);
        while i > 0 && shard_rows(height, n_workers, i).0 > row {
            i -= 1;
        }
        while i + 1 < n_workers && shard_rows(height, n_workers, i + 1).0 <= row {
            i += 1;
        }
        i
    };
    let mut in_angle = false;
    for msg in rx.iter() {
        match msg {
            StreamMsg::Angle { incidence_deg } => {
                in_angle = true;
                if let Some(t) = tap {
                    t.lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .angle(incidence_deg);
                }
                if control.send(Control::Angle(incidence_deg)).is_err() {
                    return;
                }
            }
            StreamMsg::Rows(block) => {
                if !in_angle {
                    let _ = control.send(Control::Abort("rows arrived outside an angle".into()));
                    return;
                }
                let rows = block.rows as usize;
                let first = block.first_row as usize;
                if rows == 0 || first + rows > height {
                    let what = if rows == 0 {
                        format!("an empty block at row {first}")
                    } else {
                        format!("row {} is outside the {height}-row frame", first + rows - 1)
                    };
                    let _ = control.send(Control::Abort(what));
                    return;
                }
                let values = calibrate_block(block.samples, rows, width);
                if values.len() != rows * width {
                    let _ = control.send(Control::Abort(format!(
                        "a block of {rows} rows holds {} samples, not {}",
                        values.len(),
                        rows * width
                    )));
                    return;
                }
                if let Some(t) = tap {
                    t.lock().unwrap_or_else(|e| e.into_inner()).rows(
                        usize::from(block.band),
                        first,
                        rows,
                        &values,
                    );
                }
                // Split the block at shard boundaries.
                let mut k = 0;
                while k < rows {
                    let i = owner(first + k);
                    let (s_first, s_rows) = shard_rows(height, n_workers, i);
                    let n = (s_first + s_rows - (first + k)).min(rows - k);
                    let part: Vec<u16> = values[k * width..(k + n) * width]
                        .iter()
                        .map(|&v| pack_sample(v))
                        .collect();
                    if workers[i]
                        .send(WorkerMsg::Rows(
                            block.band,
                            (first + k) as u32,
                            n as u32,
                            part,
                        ))
                        .is_err()
                    {
                        return;
                    }
                    k += n;
                }
                on_rows(rows as u64);
            }
            // Band ends carry nothing the solver needs: each pixel's tracker sees its bands in
            // order whatever the interleave.
            StreamMsg::BandEnd { .. } => {}
            StreamMsg::AngleEnd => {
                in_angle = false;
                let at = Instant::now();
                for tx in &workers {
                    if tx.send(WorkerMsg::End).is_err() {
                        return;
                    }
                }
                if control.send(Control::AngleEnd(at)).is_err() {
                    return;
                }
            }
            StreamMsg::SweepEnd => {
                let _ = control.send(Control::SweepEnd);
                return;
            }
            StreamMsg::Abort(e) => {
                let _ = control.send(Control::Abort(e));
                return;
            }
        }
    }
    let _ = control.send(Control::Abort(
        "the source stopped without ending the sweep".into(),
    ));
}

/// What [`for_each_calibrated`] hands on.
#[derive(Debug)]
pub enum Calibrated<'a> {
    /// An angle starts (degrees).
    Angle(f64),
    /// Calibrated reflectance of rows `first_row..first_row + rows` of `band` at angle
    /// number `angle` (row-major).
    Rows {
        /// Angle number (0 for the first).
        angle: usize,
        /// Band.
        band: usize,
        /// First row.
        first_row: usize,
        /// Rows.
        rows: usize,
        /// `rows * width` values.
        values: &'a [f32],
    },
}

/// Streams `source` and hands every angle start and block of calibrated rows to `f`, on this
/// thread.
pub fn for_each_calibrated(
    source: &mut dyn Source,
    f: impl FnMut(Calibrated<'_>),
) -> Result<(), PipelineError> {
    for_each_calibrated_rows(source, None, f)
}

/// [`for_each_calibrated`] of only the image rows in `rows` (sorted; `None`: every row),
/// for a consumer of a few pixels ([`Source::stream_rows`]: a source may still send others).
pub fn for_each_calibrated_rows(
    source: &mut dyn Source,
    rows: Option<&[usize]>,
    mut f: impl FnMut(Calibrated<'_>),
) -> Result<(), PipelineError> {
    let spec = source.spec().clone();
    let (w, h, nb) = (spec.width, spec.height, spec.bands_nm.len());
    let (tx, rx) = bounded::<StreamMsg>(64);
    std::thread::scope(|scope| -> Result<(), PipelineError> {
        scope.spawn(move || match rows {
            Some(rows) => source.stream_rows(&tx, rows),
            None => source.stream(&tx),
        });
        let mut angle = None;
        for msg in rx.iter() {
            match msg {
                StreamMsg::Angle { incidence_deg } => {
                    angle = Some(angle.map_or(0, |a| a + 1));
                    f(Calibrated::Angle(incidence_deg));
                }
                StreamMsg::Rows(b) => {
                    let (band, first, rows) =
                        (usize::from(b.band), b.first_row as usize, b.rows as usize);
                    let a = angle
                        .ok_or_else(|| PipelineError("rows arrived outside an angle".into()))?;
                    if band >= nb || first + rows > h {
                        return Err(PipelineError(format!(
                            "band {band}, rows {first}..{} are outside the sweep",
                            first + rows
                        )));
                    }
                    let v = calibrate_block(b.samples, rows, w);
                    if v.len() != rows * w {
                        return Err(PipelineError(format!(
                            "a block of {rows} rows holds {} samples, not {}",
                            v.len(),
                            rows * w
                        )));
                    }
                    f(Calibrated::Rows {
                        angle: a,
                        band,
                        first_row: first,
                        rows,
                        values: &v,
                    });
                }
                StreamMsg::AngleEnd | StreamMsg::BandEnd { .. } => {}
                StreamMsg::SweepEnd => return Ok(()),
                StreamMsg::Abort(e) => return Err(PipelineError(e)),
            }
        }
        Err(PipelineError(
            "the source stopped without ending the sweep".into(),
        ))
    })
}

/// Streams `source` and keeps every calibrated sample: the whole sweep in memory, for the
/// whole-cube baselines and for evaluation (not for the streaming estimator).
pub fn collect_sweep(source: &mut dyn Source) -> Result<crate::source::SweepCube, PipelineError> {
    let spec = source.spec().clone();
    let (w, h, nb) = (spec.width, spec.height, spec.bands_nm.len());
    let mut angles = Vec::new();
    let mut data: Vec<Vec<f32>> = Vec::new();
    for_each_calibrated(source, |event| match event {
        Calibrated::Angle(deg) => {
            angles.push(deg);
            data.push(vec![f32::NAN; w * h * nb]);
        }
        Calibrated::Rows {
            angle,
            band,
            first_row,
            rows,
            values,
        } => {
            let at = (band * h + first_row) * w;
            data[angle][at..at + rows * w].copy_from_slice(values);
        }
    })?;
    Ok(crate::source::SweepCube {
        width: w,
        height: h,
        bands_nm: spec.bands_nm.to_vec(),
        fwhm_nm: spec.fwhm_nm.to_vec(),
        angles_deg: angles,
        ambient_index: spec.ambient_index,
        substrate_index: spec.substrate_index,
        polarization: spec.polarization,
        index_range: spec.index_range,
        thickness_range_nm: spec.thickness_range_nm,
        data,
    })
}

/// `f` of every shard, in shard order, the first on this thread.
fn each<S: Send, T: Send>(shards: &mut [S], f: impl Fn(&mut S) -> T + Sync) -> Vec<T> {
    let Some((first, rest)) = shards.split_first_mut() else {
        return Vec::new();
    };
    std::thread::scope(|s| {
        let f = &f;
        let handles: Vec<_> = rest.iter_mut().map(|sh| s.spawn(move || f(sh))).collect();
        let mut out = vec![f(first)];
        // A worker's panic is the caller's: dropping its result would lose its votes
        // (or misalign the ties) silently.
        out.extend(handles.into_iter().map(|h| {
            h.join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
        }));
        out
    })
}

/// The time since `clock`, which moves on to now.
fn lap(clock: &mut Instant) -> std::time::Duration {
    let now = Instant::now();
    let t = now - *clock;
    *clock = now;
    t
}

/// The angle end's first pass, run on all shards at once (then [`update_parallel`]), the
/// last to read the trackers (their noise): `tallies` holds what each shard's worker tallied
/// as its rows saw their last band (`None`: nothing); the rows left are tallied here, and
/// the solver takes the votes and the fit histogram.
pub fn tally_parallel(
    solver: &mut SweepSolver,
    shards: &mut [Shard<'_>],
    tallies: Vec<Option<ShardTally>>,
    parts: &mut LatencyParts,
) {
    let mut clock = Instant::now();
    let mut hist = RatioHistogram::default();
    let mut fit = FitStats::default();
    // The rows the workers left (all of a shard without its tally) are tallied here, on
    // all cores (counts: the same sums in any order).
    let mut rows: Vec<(usize, usize)> = Vec::new();
    for (k, sh) in shards.iter().enumerate() {
        match tallies.get(k).and_then(Option::as_ref) {
            Some(t) => {
                hist.merge(&t.tally.0);
                fit.merge(&t.tally.1);
                rows.extend(t.untallied.iter().map(|&r| (k, r)));
            }
            None => rows.extend((sh.first_row..sh.first_row + sh.rows()).map(|r| (k, r))),
        }
    }
    if !rows.is_empty() {
        let view: &[Shard<'_>] = shards;
        let mut parts: Vec<&[(usize, usize)]> =
            rows.chunks(rows.len().div_ceil(view.len())).collect();
        let tallied = each(&mut parts, |part| {
            let mut t = Tally::default();
            for &(k, r) in part.iter() {
                view[k].tally_rows(solver, r..r + 1, &mut t.0, &mut t.1);
            }
            t
        });
        for (h, f) in tallied {
            hist.merge(&h);
            fit.merge(&f);
        }
    }
    solver.set_votes(&hist);
    solver.set_fit_histogram(&fit);
    parts.tally = lap(&mut clock);
}

/// The angle end's passes after [`tally_parallel`], each run on all shards at once: the
/// index's sums, the update and the ties. At the sweep's last angle, `results` (the image's,
/// row-major; the shards hold its rows in order) gets every pixel's final result
/// ([`Shard::finish`]) from the same pass that updates it. `parts` gets each pass's wall
/// time. The trackers are not read but for their overflow flags, which a shard whose
/// trackers were released holds in its pixels' flags already
/// ([`Shard::keep_tracker_flags`]).
pub fn update_parallel(
    solver: &mut SweepSolver,
    shards: &mut [Shard<'_>],
    results: Option<&mut [PixelResult]>,
    parts: &mut LatencyParts,
) -> AngleReport {
    let mut clock = Instant::now();
    // Per-row sums merged in row order: the same floating-point result for any sharding.
    let mut rows: Vec<(usize, RatioSums, SchurSums)> = each(shards, |sh| {
        let mut v = Vec::with_capacity(sh.rows());
        sh.sums(solver, |r, w, s| v.push((r, w, s)));
        v
    })
    .into_iter()
    .flatten()
    .collect();
    rows.sort_by_key(|(r, _, _)| *r);
    let (mut sums, mut schur) = (RatioSums::default(), SchurSums::default());
    for (_, w, s) in &rows {
        sums.merge(w);
        schur.merge(s);
    }
    solver.set_window_sums(&sums);
    solver.set_schur(&schur);
    parts.sums = lap(&mut clock);
    // Each shard's part of `results`.
    let mut outs: Vec<&mut [PixelResult]> = Vec::new();
    if let Some(mut rest) = results {
        for sh in shards.iter() {
            let n = sh.pixels.len().min(rest.len());
            let (mine, tail) = std::mem::take(&mut rest).split_at_mut(n);
            outs.push(mine);
            rest = tail;
        }
    }
    let ties = {
        let solver = &*solver;
        let mut jobs: Vec<_> = shards
            .iter_mut()
            .zip(
                outs.iter_mut()
                    .map(Some)
                    .chain(std::iter::repeat_with(|| None)),
            )
            .collect();
        each(&mut jobs, |(sh, out)| {
            let mut ties = TieSet::new(sh.pixels.len());
            sh.update(solver, out.as_deref_mut().map(|o| &mut **o), |i| {
                ties.insert(i)
            });
            ties
        })
    };
    parts.update = lap(&mut clock);
    filmscope_core::solve::sweep::resolve_orders(solver, shards, |k, _| ties[k].iter());
    for ((sh, out), ties) in shards.iter().zip(outs.iter_mut()).zip(&ties) {
        sh.finish_pixels(solver, out, ties.iter());
    }
    let report = solver.end_angle();
    parts.ties = lap(&mut clock);
    report
}

#[cfg(test)]
mod tests {
    use super::{block_bands, streams_rows, FINAL_BLOCK_BANDS};

    /// The blocks an angle of `bands` bands is fed in, as `(first band, bands)`.
    fn blocks(bands: usize, band_block: usize) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        let mut band = 0;
        while band < bands {
            let n = block_bands(band, bands, band_block);
            out.push((band, n));
            band += n;
        }
        out
    }

    #[test]
    fn blocks_shrink_towards_an_angle_end_and_only_the_last_streams() {
        let b = blocks(161, 8);
        let mut expected: Vec<_> = (0..19).map(|k| (8 * k, 8)).collect();
        expected.extend([(152, 5), (157, FINAL_BLOCK_BANDS)]);
        assert_eq!(b, expected);
        let streams: Vec<_> = b.iter().map(|&(f, n)| streams_rows(f, n, 161)).collect();
        assert_eq!(streams.iter().filter(|&&s| s).count(), 1);
        assert!(streams[streams.len() - 1]);
        // Short angles and small blocks: every band once, in order, no empty block.
        for bands in 1..40 {
            for band_block in [1, 2, 3, 4, 8, 64] {
                let b = blocks(bands, band_block);
                assert!(b.iter().all(|&(_, n)| (1..=band_block).contains(&n)));
                assert_eq!(b.iter().map(|&(_, n)| n).sum::<usize>(), bands);
            }
        }
        assert_eq!(blocks(161, 1).len(), 161);
    }
}
