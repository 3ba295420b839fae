//! Wires the stages to bounded channels and threads.
//!
//! ```text
//! source thread -> [cap] -> calibrate thread -> [cap] -> worker 1 (strips 1, 3, 5, ...)
//!                                            \-> [cap] -> worker 2 (strips 2, 4, 6, ...)
//!                                  control --> coordinator (this thread): angle ends
//! ```
//!
//! Every channel is bounded, so a slow stage slows the source and memory never grows with
//! the stream. The image's rows are dealt to the workers in strips of a few rows
//! ([`Strips`]), so that every worker has work whatever order the rows arrive in. Each
//! worker owns the per-pixel state of its strips while an angle streams, and tallies each row
//! (the first angle-end pass) once the row has seen the angle's last band (a worker behind
//! the stream leaves the rows it completes to the angle's end); at the angle's end it hands
//! the states and its tally to the coordinator, which runs the rest of the solver's angle-end
//! passes on all cores and hands the states back with the next angle.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{bounded, Receiver, Sender};
use filmscope_core::solve::fit_row::thickness_span;
use filmscope_core::solve::index::{RatioHistogram, RatioSums};
use filmscope_core::solve::sweep::SolverOptions;
use filmscope_core::solve::sweep::{FitStats, SchurSums};
use filmscope_core::solve::{AngleReport, IndexModel, PixelResult, Shard, SweepSolver, SweepSpec};

use super::calibrate::calibrate_stage;
use super::msg::{Control, Correction, Done, PipelineError, Start, Tap, WorkerMsg};
use super::state::{BandModels, ShardState, ShardTally, Strips, Tally};
use super::ties::TieSet;
use super::worker::worker;
use crate::source::{Source, StreamMsg};

/// How to run the pipeline.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PipelineConfig {
    /// Capacity of every channel, in messages (a worker's: [`WORKER_QUEUE_FACTOR`] times
    /// as many, its messages being a strip's part of a source's block).
    pub channel_capacity: usize,
    /// Worker threads.
    pub workers: usize,
    /// Rows of a strip ([`Strips`]): rows are dealt to the workers in turn, this many at a
    /// time. Fewer than a source's blocks of rows (8-16), so that each block feeds every
    /// worker: a line-scan capture's run of lines carries all its bands, and with strips as
    /// tall as the run one worker would take a whole run while the other waited.
    pub strip_rows: usize,
    /// Bands a worker holds before feeding them to its pixels row by row (at most; fewer
    /// where [`HELD_BYTES`] says): every band streams past every pixel's state, so on a
    /// sensor whose state does not fit the caches a sample costs its state's memory
    /// traffic; holding `band_block` bands divides that traffic by `band_block` at
    /// `2 * band_block` bytes per pixel of row buffers (packed samples,
    /// [`filmscope_core::track::pack_sample`]; 1: feed each row as it arrives). Over an
    /// angle's last bands the blocks shrink (`block_bands`), so that little is left to feed
    /// when its last row arrives.
    pub band_block: usize,
    /// What the solver may use.
    pub solver: SolverOptions,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            channel_capacity: 16,
            workers: 2,
            strip_rows: 4,
            band_block: 4,
            solver: SolverOptions::default(),
        }
    }
}

/// Bytes of held samples ([`PipelineConfig::band_block`]) a sweep may keep across the
/// image: a large sensor holds fewer bands, trading memory traffic for peak memory (a 4 MP
/// sweep holds one band, 8.4 MB, where four would take 34 MB; a 1 MP sweep holds four).
pub const HELD_BYTES: usize = 12 << 20;

/// A worker's queue holds this many times [`PipelineConfig::channel_capacity`] messages: a
/// source's block of up to 16 rows reaches a worker as up to this many strips' parts.
pub const WORKER_QUEUE_FACTOR: usize = 4;

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
    /// What each angle's band models were tabulated over ([`AngleTables`]).
    pub tables: Vec<AngleTables>,
}

/// An angle's band model tables ([`BandModels::of`]): where the pixels' samples read their
/// models, and how many knots cover that. A sample outside them, or an angle without
/// knots, has its model computed, many times slower: this tells whether they were used.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AngleTables {
    /// The thicknesses (nm, least and greatest) tabulated over: the pixels' thicknesses as
    /// the angle began, an order either side (`[inf, -inf]`: no pixel had one).
    pub span_nm: [f32; 2],
    /// Knots over all bands (0: every model computed, as on an image too small to repay a
    /// table, [`filmscope_core::solve::SweepSolver::band_knots`]).
    pub knots: usize,
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
    /// The image's noise (reflectance) measured beforehand (the pixel sample's), if it was.
    /// A sweep with every pixel seeded under a held index and this noise tracks no extrema
    /// ([`SolverOptions::extrema`]).
    pub noise_sigma: Option<f32>,
    /// What the sample fit found the capture's metadata and reflectance to be off by, taken
    /// out of the data before the pixels are solved.
    pub correction: Correction,
}

impl Prior {
    /// `index`, moved by `update`, from `seed`'s thicknesses where given.
    pub fn new(index: IndexModel, update: PriorUpdate, seed: Option<Arc<Vec<f32>>>) -> Self {
        Self {
            index,
            update,
            seed,
            noise_sigma: None,
            correction: Correction::default(),
        }
    }

    /// The same prior with the data corrected by `correction`.
    pub fn with_correction(mut self, correction: Correction) -> Self {
        self.correction = correction;
        self
    }

    /// The prior with the image's noise measured beforehand (ignored unless finite and
    /// positive).
    pub fn with_noise(mut self, sigma: f64) -> Self {
        self.noise_sigma = (sigma.is_finite() && sigma > 0.0).then_some(sigma as f32);
        self
    }

    /// The noise of a sweep that needs no extrema: every pixel seeded, the index held and
    /// the noise known.
    fn untracked_noise(&self, pixels: usize) -> Option<f32> {
        let seeded = self
            .seed
            .as_ref()
            .is_some_and(|m| m.len() == pixels && m.iter().all(|d| d.is_finite()));
        (seeded && self.update == PriorUpdate::Hold)
            .then_some(self.noise_sigma)
            .flatten()
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

/// [`run_sweep`] and [`run_sweep_sampled`]: the sweep set up, its stages started, each
/// angle's beginning and end coordinated as the calibrate stage reports them, and the
/// output made once the stream has ended.
fn sweep(
    source: &mut dyn Source,
    config: PipelineConfig,
    prior: Option<Prior>,
    mut hook: Option<SampleHook<'_>>,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<SweepOutput, PipelineError> {
    let tap = hook.as_ref().map(|h| h.tap);
    let (spec, correction, untracked) = sweep_spec(source, config, prior.as_ref());
    let (w, h) = (spec.width, spec.height);
    let strips = Strips::new(h, config.strip_rows, config.workers);
    let order = source.row_order();
    let workers = strips.workers();
    let cap = config.channel_capacity.max(1);
    let start = Instant::now();
    let solver = sweep_solver(&spec, prior.as_ref(), &correction, untracked);
    let seed = prior
        .as_ref()
        .and_then(|p| Some((p.seed.clone()?, p.index)));
    if seed.as_ref().is_some_and(|(map, _)| map.len() != w * h) {
        return Err(PipelineError::Setup(format!(
            "the thickness seed map does not have {w} x {h} pixels"
        )));
    }
    let angles = source.angles_deg().len();
    let mut co = Coordinator::new(solver, &spec, strips, seed.as_ref(), angles);

    std::thread::scope(|scope| -> Result<(), PipelineError> {
        let (src_tx, src_rx) = bounded::<StreamMsg>(cap);
        let (ctl_tx, ctl_rx) = bounded::<Control>(cap);
        let (done_tx, done_rx) = bounded::<Done>(workers);
        let mut worker_txs = Vec::new();
        let mut start_txs = Vec::new();
        for i in 0..workers {
            let (tx, rx) = bounded::<WorkerMsg>(cap * WORKER_QUEUE_FACTOR);
            let (start_tx, start_rx) = bounded::<Start>(1);
            worker_txs.push(tx);
            start_txs.push(start_tx);
            let done = done_tx.clone();
            let options = spec.options;
            let band_block = config
                .band_block
                .min(HELD_BYTES / (2 * w * h).max(1))
                .max(1);
            let block = [band_block, spec.bands_nm.len()];
            named(scope, format!("worker-{i}"), move || {
                worker(i, strips, w, options, block, order, start_rx, rx, done)
            })?;
        }
        drop(done_tx);
        named(scope, "source".into(), move || source.stream(&src_tx))?;
        named(scope, "calibrate".into(), move || {
            let split = (strips, spec.options.wide_simd);
            calibrate_stage(
                src_rx,
                ctl_tx,
                worker_txs,
                (w, h),
                split,
                (tap, &correction),
                on_rows,
            )
        })?;

        let mut abort = None;
        for msg in ctl_rx.iter() {
            match msg {
                Control::Angle(deg) => {
                    if !co.begin_angle(deg, &start_txs) {
                        abort = Some("a worker stopped".to_owned());
                    }
                }
                Control::AngleEnd(at) => {
                    co.last_row_at = at;
                    let (tallies, stopped) = co.hand_back(&done_rx);
                    if stopped {
                        abort = Some("a worker stopped".to_owned());
                    }
                    if abort.is_some() {
                        break;
                    }
                    co.end_angle(at, tallies, hook.as_mut());
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
            Some(e) => Err(PipelineError::Source(e)),
            None => Ok(()),
        }
    })?;
    co.finish(spec, start)
}

/// The sweep as the pipeline solves it: `source`'s, with `config`'s solver options and its
/// bands shifted by the prior's correction; the correction, and the noise of a sweep that
/// tracks no extrema ([`Prior::untracked_noise`]; then the spec's options say so).
fn sweep_spec(
    source: &dyn Source,
    config: PipelineConfig,
    prior: Option<&Prior>,
) -> (SweepSpec, Correction, Option<f32>) {
    let mut spec = source.spec().clone();
    spec.options = config.solver;
    let correction = prior.map(|p| p.correction.clone()).unwrap_or_default();
    for b in spec.bands_nm.iter_mut() {
        *b += correction.band_shift_nm;
    }
    let (w, h) = (spec.width, spec.height);
    let untracked = prior.and_then(|p| p.untracked_noise(w * h));
    if untracked.is_some() {
        spec.options.extrema = false;
    }
    (spec, correction, untracked)
}

/// The sweep's solver: from the prior's index, moved as the prior says, with the film terms
/// of `correction` and the noise `untracked` when the sweep tracks no extrema.
fn sweep_solver(
    spec: &SweepSpec,
    prior: Option<&Prior>,
    correction: &Correction,
    untracked: Option<f32>,
) -> Box<SweepSolver> {
    let mut solver =
        SweepSolver::new(spec.clone(), prior.map(|p| p.index)).with_film_terms(correction.film);
    match prior.map(|p| p.update) {
        Some(PriorUpdate::FullSpectra) => solver = solver.with_spectral_index(),
        Some(PriorUpdate::Hold) => solver = solver.with_held_index(),
        _ => {}
    }
    if let Some(sigma) = untracked {
        solver = solver.with_noise(sigma);
    }
    Box::new(solver)
}

/// Each worker's state for the first angle (seeded from `seed`'s thickness map under its
/// index where given), each made on a thread of its own (zeroing and seeding the state took
/// 2.4-6.4 ms of a 256 x 192 sweep's 150-200 on one); and the thicknesses the first angle's
/// tables cover: the seeded ones (none without a seed: no pixel has one yet).
fn first_states(
    spec: &SweepSpec,
    strips: Strips,
    seed: Option<&(Arc<Vec<f32>>, IndexModel)>,
) -> (Vec<Option<ShardState>>, [f32; 2]) {
    let workers = strips.workers();
    let mut ids: Vec<usize> = (0..workers).collect();
    let (states, spans): (Vec<Option<ShardState>>, Vec<[f32; 2]>) =
        each(&mut ids, workers, |&mut i| {
            let seed = seed.map(|(map, index)| (map.as_slice(), *index));
            let st = ShardState::for_worker(strips, i, spec, seed);
            let span = thickness_span(&st.fits);
            (Some(st), span)
        })
        .into_iter()
        .unzip();
    (states, spans.into_iter().fold(EMPTY_SPAN, widen))
}

/// The coordinator's part of a sweep: the solver, the workers' states between angles, and
/// what the output gathers as the angles end.
struct Coordinator {
    solver: Box<SweepSolver>,
    /// Worker `i`'s state while the coordinator holds it.
    states: Vec<Option<ShardState>>,
    strips: Strips,
    width: usize,
    height: usize,
    workers: usize,
    /// Angles the source announced.
    angles: usize,
    /// Bands an angle.
    bands: usize,
    /// The thicknesses the next angle's tables cover.
    table_span: [f32; 2],
    reports: Vec<AngleReport>,
    tables: Vec<AngleTables>,
    samples: u64,
    /// When the last angle's last row arrived.
    last_row_at: Instant,
    latency_parts: LatencyParts,
    results: Vec<PixelResult>,
    /// The angles done when the last angle's update made the results.
    results_at: Option<usize>,
}

impl Coordinator {
    /// The coordinator of a sweep of `spec` over `angles` angles with `solver`, its workers'
    /// first states made ([`first_states`]). The results are made by the last angle's
    /// update pass (the angles announced tell which is last), else by a pass of their own
    /// once the sweep has ended. They are allocated then, once the trackers are released
    /// (the sweep's peak memory does not hold both).
    fn new(
        solver: Box<SweepSolver>,
        spec: &SweepSpec,
        strips: Strips,
        seed: Option<&(Arc<Vec<f32>>, IndexModel)>,
        angles: usize,
    ) -> Self {
        let (states, table_span) = first_states(spec, strips, seed);
        Self {
            solver,
            states,
            strips,
            width: spec.width,
            height: spec.height,
            workers: strips.workers(),
            angles,
            bands: spec.bands_nm.len(),
            table_span,
            reports: Vec::new(),
            tables: Vec::new(),
            samples: 0,
            last_row_at: Instant::now(),
            latency_parts: LatencyParts::default(),
            results: Vec::new(),
            results_at: None,
        }
    }

    /// Angle `deg` begins: the solver's tables made over the thicknesses the pixels read,
    /// and each worker sent its state, the band models and the solver's context on `start`;
    /// `false` when a worker has stopped.
    fn begin_angle(&mut self, deg: f64, start: &[Sender<Start>]) -> bool {
        self.solver.begin_angle(deg);
        // The tables cover the thicknesses the pixels read this angle, no more
        // (those of a seeded 400 nm film are a third of the search range's).
        self.solver
            .set_table_span(Some(self.table_span.map(f64::from)));
        let snapshot = Arc::new(BandModels::of(&self.solver, self.workers));
        self.tables.push(AngleTables {
            span_nm: self.table_span,
            knots: snapshot.knots(),
        });
        let began = Arc::new(self.solver.context().clone());
        let left = self.angles.saturating_sub(self.solver.angles_done()).max(1);
        let mut sent = true;
        for (i, tx) in start.iter().enumerate() {
            let mut st = self.states[i].take().unwrap_or_default();
            st.restore_trackers();
            if tx
                .send(Start {
                    state: st,
                    models: snapshot.clone(),
                    began: began.clone(),
                    angles_left: left,
                })
                .is_err()
            {
                sent = false;
            }
        }
        sent
    }

    /// Every worker's state and tally as it hands them back on `done` at an angle's end
    /// (a tally `None` where a worker stopped); whether one stopped.
    fn hand_back(&mut self, done: &Receiver<Done>) -> (Vec<Option<ShardTally>>, bool) {
        let mut tallies: Vec<Option<ShardTally>> = (0..self.workers).map(|_| None).collect();
        let mut stopped = false;
        for _ in 0..self.workers {
            match done.recv() {
                Ok(Done {
                    worker: i,
                    state,
                    tally,
                }) => {
                    self.states[i] = Some(state);
                    tallies[i] = Some(tally);
                }
                Err(_) => stopped = true,
            }
        }
        (tallies, stopped)
    }

    /// The angle whose last row arrived `at` ends, the workers' `tallies` in hand: the
    /// hook's index taken, the angle-end passes run on all shards ([`tally_parallel`],
    /// [`update_parallel`]), and after the last angle the results made by its update.
    fn end_angle(
        &mut self,
        at: Instant,
        tallies: Vec<Option<ShardTally>>,
        hook: Option<&mut SampleHook<'_>>,
    ) {
        let (w, h, strips, workers) = (self.width, self.height, self.strips, self.workers);
        let mut owned: Vec<ShardState> = self
            .states
            .iter_mut()
            .map(|s| s.take().unwrap_or_default())
            .collect();
        let mut shards = image_shards(&mut owned, strips, w);
        let last = self.solver.angles_done() + 1 == self.angles;
        if let Some(hook) = hook {
            let complete = self.solver.angles_done() + 1;
            if let Some(m) = (hook.refit)(complete) {
                self.solver.set_external_index(m);
            }
        }
        let mut parts = LatencyParts {
            drain: at.elapsed(),
            ..LatencyParts::default()
        };
        // A worker that handed back no tally leaves all its rows.
        let tallies = tallies
            .into_iter()
            .enumerate()
            .map(|(i, t)| {
                t.unwrap_or_else(|| ShardTally {
                    tally: Box::default(),
                    untallied: strips
                        .of_worker(i)
                        .flat_map(|k| {
                            let (first, n) = strips.span(k);
                            first..first + n
                        })
                        .collect(),
                })
            })
            .collect();
        tally_parallel(&mut self.solver, &mut shards, tallies, workers, &mut parts);
        let releasing = Instant::now();
        if last {
            // The trackers are read no more: the results take their memory,
            // not memory of their own on top of the state.
            drop(shards);
            owned.iter_mut().for_each(ShardState::release_trackers);
            self.results = vec![PixelResult::UNSOLVED; w * h];
            shards = image_shards(&mut owned, strips, w);
        }
        parts.results = releasing.elapsed();
        let out = last.then_some(self.results.as_mut_slice());
        let (report, span) =
            update_parallel(&mut self.solver, &mut shards, out, workers, &mut parts);
        self.table_span = span;
        self.reports.push(report);
        self.latency_parts = parts;
        if last {
            self.results_at = Some(self.solver.angles_done());
        }
        self.samples += (w * h * self.bands) as u64;
        drop(shards);
        for (i, st) in owned.into_iter().enumerate() {
            self.states[i] = Some(st);
        }
    }

    /// The sweep's output once the stream has ended (started at `start`): every pixel's
    /// result, made here when the last angle's update did not make them (the stream ended
    /// before the angles announced); an error when not one angle completed.
    fn finish(self, spec: SweepSpec, start: Instant) -> Result<SweepOutput, PipelineError> {
        let Coordinator {
            solver,
            states,
            strips,
            width: w,
            height: h,
            workers,
            reports,
            tables,
            samples,
            last_row_at,
            latency_parts,
            mut results,
            results_at,
            ..
        } = self;
        if solver.angles_done() < 1 {
            return Err(PipelineError::Stream(format!(
                "the stream ended after {} angle(s); at least one is needed",
                solver.angles_done()
            )));
        }
        if results_at != Some(solver.angles_done()) {
            let mut owned: Vec<ShardState> =
                states.into_iter().map(Option::unwrap_or_default).collect();
            owned.iter_mut().for_each(ShardState::release_trackers);
            if results.len() != w * h {
                results = vec![PixelResult::UNSOLVED; w * h];
            }
            let mut jobs: Vec<_> = image_shards(&mut owned, strips, w)
                .into_iter()
                .zip(results.chunks_mut(strips.span(0).1 * w))
                .collect();
            each(&mut jobs, workers, |(sh, mine)| sh.finish(&solver, mine));
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
            tables,
        })
    }
}

/// Every strip's shard over the workers' states (`states[i]` worker `i`'s), in image order.
fn image_shards(states: &mut [ShardState], strips: Strips, width: usize) -> Vec<Shard<'_>> {
    let mut shards: Vec<Shard<'_>> = states
        .iter_mut()
        .enumerate()
        .flat_map(|(i, st)| st.shards(strips.spans_of(i), width))
        .collect();
    shards.sort_by_key(|s| s.first_row);
    shards
}

/// Spawns `f` on a thread of `scope` named `name` (as `top -H`, `perf` and debuggers show
/// it); a thread that cannot start is the sweep's error, not a panic.
fn named<'scope, T: Send + 'scope>(
    scope: &'scope std::thread::Scope<'scope, '_>,
    name: String,
    f: impl FnOnce() -> T + Send + 'scope,
) -> Result<std::thread::ScopedJoinHandle<'scope, T>, PipelineError> {
    std::thread::Builder::new()
        .name(name)
        .spawn_scoped(scope, f)
        .map_err(PipelineError::Thread)
}

/// `f` of every item, in order, on `threads` threads (each a run of the items, the first run
/// on this thread).
fn each<S: Send, T: Send>(
    items: &mut [S],
    threads: usize,
    f: impl Fn(&mut S) -> T + Sync,
) -> Vec<T> {
    if items.is_empty() {
        return Vec::new();
    }
    let run = items.len().div_ceil(threads.max(1));
    let mut runs = items.chunks_mut(run);
    let first = runs.next().unwrap_or_default();
    std::thread::scope(|s| {
        let f = &f;
        let handles: Vec<_> = runs
            .map(|part| s.spawn(move || part.iter_mut().map(f).collect::<Vec<T>>()))
            .collect();
        let mut out: Vec<T> = first.iter_mut().map(f).collect();
        // A thread's panic is the caller's: dropping its results would lose votes (or
        // misalign the ties) silently.
        for h in handles {
            out.extend(
                h.join()
                    .unwrap_or_else(|panic| std::panic::resume_unwind(panic)),
            );
        }
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
/// last to read the trackers (their noise): `tallies` holds what each worker tallied
/// as its rows saw their last band; the rows left are tallied here, and
/// the solver takes the votes and the fit histogram.
pub fn tally_parallel(
    solver: &mut SweepSolver,
    shards: &mut [Shard<'_>],
    tallies: Vec<ShardTally>,
    threads: usize,
    parts: &mut LatencyParts,
) {
    let mut clock = Instant::now();
    let mut hist = RatioHistogram::default();
    let mut fit = FitStats::default();
    // The rows the workers left are tallied here, on all cores (counts: the same sums in
    // any order), each by the shard that holds it (the shards in image order).
    let mut rows: Vec<(usize, usize)> = Vec::new();
    for t in &tallies {
        hist.merge(&t.tally.votes);
        fit.merge(&t.tally.fit);
        rows.extend(t.untallied.iter().filter_map(|&r| {
            let k = shards
                .partition_point(|s| s.first_row <= r)
                .checked_sub(1)?;
            shards[k].holds(r).then_some((k, r))
        }));
    }
    if !rows.is_empty() {
        let view: &[Shard<'_>] = shards;
        let mut parts: Vec<&[(usize, usize)]> =
            rows.chunks(rows.len().div_ceil(threads.max(1))).collect();
        let tallied = each(&mut parts, threads, |part| {
            let mut t = Tally::default();
            for &(k, r) in part.iter() {
                view[k].tally_rows(solver, r..r + 1, &mut t.votes, &mut t.fit);
            }
            t
        });
        for t in tallied {
            hist.merge(&t.votes);
            fit.merge(&t.fit);
        }
    }
    solver.set_votes(&hist);
    solver.set_fit_histogram(&fit);
    parts.tally = lap(&mut clock);
}

/// A span of thicknesses holding none ([`widen`] takes any other).
const EMPTY_SPAN: [f32; 2] = [f32::INFINITY, f32::NEG_INFINITY];

/// The span holding both `a` and `b`.
fn widen(a: [f32; 2], b: [f32; 2]) -> [f32; 2] {
    [a[0].min(b[0]), a[1].max(b[1])]
}

/// The angle end's passes after [`tally_parallel`], each run on `threads` threads: the
/// index's sums, the update and the ties. At the sweep's last angle, `results` (the image's,
/// row-major; the shards hold its rows in order) gets every pixel's final result
/// ([`Shard::finish`]) from the same pass that updates it. `parts` gets each pass's wall
/// time. The trackers are not read (their overflow flags are the pixels' already). Returns
/// the angle's report and where the pixels read their models at the next angle
/// ([`Shard::thickness_span`], taken by the update's threads while each shard is in cache:
/// a pass of its own took 9.6 ms over a 1 MP image).
pub fn update_parallel(
    solver: &mut SweepSolver,
    shards: &mut [Shard<'_>],
    results: Option<&mut [PixelResult]>,
    threads: usize,
    parts: &mut LatencyParts,
) -> (AngleReport, [f32; 2]) {
    let mut clock = Instant::now();
    // Per-row sums merged in row order: the same floating-point result for any sharding.
    let mut rows: Vec<(usize, RatioSums, SchurSums)> = each(shards, threads, |sh| {
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
    let updated = {
        let solver = &*solver;
        let mut jobs: Vec<_> = shards
            .iter_mut()
            .zip(
                outs.iter_mut()
                    .map(Some)
                    .chain(std::iter::repeat_with(|| None)),
            )
            .collect();
        each(&mut jobs, threads, |(sh, out)| {
            let mut ties = TieSet::new(sh.pixels.len());
            sh.update(solver, out.as_deref_mut().map(|o| &mut **o), |i| {
                ties.insert(i)
            });
            (ties, sh.thickness_span())
        })
    };
    parts.update = lap(&mut clock);
    let (ties, spans): (Vec<TieSet>, Vec<[f32; 2]>) = updated.into_iter().unzip();
    filmscope_core::solve::sweep::resolve_orders(solver, shards, |k, _| ties[k].iter());
    for ((sh, out), ties) in shards.iter().zip(outs.iter_mut()).zip(&ties) {
        sh.finish_pixels(solver, out, ties.iter());
    }
    let mut span = EMPTY_SPAN;
    for ((sh, ties), &s) in shards.iter().zip(&ties).zip(&spans) {
        // A shard whose ties took an order has moved since its update.
        let tied = ties.iter().next().is_some();
        span = widen(span, if tied { sh.thickness_span() } else { s });
    }
    let report = solver.end_angle();
    parts.ties = lap(&mut clock);
    (report, span)
}
