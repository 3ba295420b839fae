//! The field model: one incidence angle per frame (`narrow`), or an angle that varies
//! across the image with the lens's field of view (`wide`).
//!
//! The streaming solver ([`filmscope_core::solve`]) takes one incidence angle per frame.
//! Under a wide field of view column `x` sees `theta_stage + atan((x - cx) / focal_px)`
//! ([`FieldOfView`] has the geometry and its sign convention). The wide model, with no
//! change to the solver:
//!
//! 1. cuts the image into `K` vertical strips of columns, none spanning more than
//!    [`STRIP_SPREAD_DEG`] of angle ([`strips_for`], [`plan_strips`]), and solves each as a
//!    sweep of its own whose angles are the stage's moved by the strip centre's offset (their
//!    magnitude: a planar film reflects alike at `+theta` and `-theta`). The strips crop
//!    their columns out of one source: each round streams the source once and hands every
//!    strip's pipeline its columns, so `K` strips cost one stream per pass, not `K`;
//! 2. runs the estimator's usual passes on each strip ([`filmscope_passes`]);
//! 3. combines the strips' indices ([`combine`]) and gives every strip that index in the
//!    [`SHARED_ROUNDS`], seeded by the last round's maps;
//! 4. merges the strips' maps, each pixel's thickness mapped from its strip's angles to its
//!    column's own ([`column_factor`]).
//!
//! Which model a capture gets ([`run_filmscope`], [`AUTO_CRITERION`]): narrow unless the
//! capture gives the lens's field of view, the narrow fit does not explain the spectra, and
//! the wide one fits them better. The choice and both models' figures go to `summary.json`
//! (`field_model_choice`).

use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::Instant;

use crate::record::index_choice::{IndexModelChoice, WideChoice};
use crossbeam_channel::{bounded, Sender};
use filmscope_core::optics::FieldOfView;
use filmscope_core::solve::{flags, IndexModel, PixelResult, SweepSpec};

use crate::estimate::method::{Method, MethodResult};
use crate::estimate::passes::{angle_reports, filmscope_passes, result_from_sweep, Passes};
use crate::estimate::run::{FieldChoice, FieldModel, Run, RunConfig};
use crate::pipeline::{run_sweep, PipelineConfig, PipelineError, Prior, PriorUpdate, SweepOutput};
use crate::source::{RowBlock, Samples, Source, StreamMsg};
use crate::summary::{
    FieldGeometry, FieldModelChoice, NarrowEvidence, StripEvidence, WideEvidence,
};

/// The widest angle spread (degrees, between a strip's outer column centres) the wide model
/// leaves inside one strip.
///
/// A strip's sweep models all its columns at its centre's angle; what the per-column
/// thickness mapping cannot take up stays in the fit residual, which grows about linearly
/// with the spread (noise-free 30 degree captures, one pass per strip: 0.0008 per degree of
/// spread for MgF2 400 nm, 0.0018 for ZnS, against noises of 0.0044 and 0.0084 in the noisy
/// captures). At 2 degrees that is under half the noise, adding under 10 % to the residual
/// (the narrow model's underfit criterion is 25 %). Measured (`eval --field wide
/// --field-strips K` on the two 30 degree scenes, 96 and 64 columns): 4 strips (7.5 degrees
/// each) solve nothing; 8: paper-sample1 +0.0007 / 0.35 nm, ZnS 0.10 nm; 15 (2 degrees):
/// +0.0004 / 0.24 nm, 0.07 nm; 24 and 30: +0.0002 / 0.22 and 0.21 nm, 0.07 nm, at 1.6 and
/// 2.1 times the time of 15.
pub const STRIP_SPREAD_DEG: f64 = 2.0;

/// Fewest columns a strip may have (its index pools its own pixels' fringe shifts).
pub const MIN_STRIP_COLUMNS: usize = 4;

/// One vertical strip of columns of the wide model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Strip {
    /// First column.
    pub first_col: usize,
    /// Columns.
    pub cols: usize,
    /// The strip's incidence offset from the stage angle, degrees: the offset at its centre.
    pub offset_deg: f64,
    /// Angle spread between its outer column centres, degrees.
    pub spread_deg: f64,
}

/// The angle spread across the image: between the centres of its outer columns, degrees.
pub fn angle_spread_deg(fov: FieldOfView, width: usize) -> f64 {
    if width < 2 {
        return 0.0;
    }
    fov.column_offset_deg(width - 1, width) - fov.column_offset_deg(0, width)
}

/// Strips the wide model needs so that no strip spans more than [`STRIP_SPREAD_DEG`]: 1 when
/// the whole field does not (the wide model would be the narrow one), at most one per
/// [`MIN_STRIP_COLUMNS`] columns.
pub fn strips_for(fov: FieldOfView, width: usize) -> usize {
    let k = (angle_spread_deg(fov, width) / STRIP_SPREAD_DEG).ceil();
    (k.max(1.0) as usize).clamp(1, (width / MIN_STRIP_COLUMNS).max(1))
}

/// `k` strips of equal angle width across an image `width` pixels wide (fewer if the image
/// has fewer columns).
pub fn plan_strips(fov: FieldOfView, width: usize, k: usize) -> Vec<Strip> {
    let k = k.clamp(1, width.max(1));
    let half = 0.5 * fov.horizontal_deg();
    let (focal, cx) = (fov.focal_px(width), 0.5 * width as f64);
    let mut edges = vec![0usize];
    for i in 1..k {
        let a = (-half + fov.horizontal_deg() * i as f64 / k as f64).to_radians();
        let x = (cx + focal * a.tan()).round().clamp(0.0, width as f64) as usize;
        if x > *edges.last().unwrap_or(&0) && x < width {
            edges.push(x);
        }
    }
    edges.push(width);
    edges
        .windows(2)
        .map(|e| {
            let (c0, c1) = (e[0], e[1]);
            Strip {
                first_col: c0,
                cols: c1 - c0,
                offset_deg: fov.offset_deg(0.5 * (c0 + c1) as f64, width),
                spread_deg: fov.column_offset_deg(c1 - 1, width) - fov.column_offset_deg(c0, width),
            }
        })
        .collect()
}

/// Lets strips' pipelines share one stream of the source: a round starts when every strip
/// still running waits in `StripSource::stream`, and ends when the source's stream has been
/// handed to each of them.
struct Hub {
    state: Mutex<HubState>,
    turn: Condvar,
}

struct HubState {
    /// Strips whose estimator is still running.
    live: usize,
    /// Strips waiting for the next round, with their pipelines' senders.
    waiting: Vec<(usize, Sender<StreamMsg>)>,
    /// Rounds completed.
    round: u64,
}

impl Hub {
    fn new(live: usize) -> Self {
        Self {
            state: Mutex::new(HubState {
                live,
                waiting: Vec::new(),
                round: 0,
            }),
            turn: Condvar::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, HubState> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn wait<'a>(&self, guard: MutexGuard<'a, HubState>) -> MutexGuard<'a, HubState> {
        self.turn
            .wait(guard)
            .unwrap_or_else(PoisonError::into_inner)
    }

    /// Strip `strip` waits for the next round to stream into `tx`, and returns when it has.
    fn join_round(&self, strip: usize, tx: &Sender<StreamMsg>) {
        let mut st = self.lock();
        let round = st.round;
        st.waiting.push((strip, tx.clone()));
        self.turn.notify_all();
        while st.round == round {
            st = self.wait(st);
        }
    }

    /// A strip's estimator has finished.
    fn leave(&self) {
        let mut st = self.lock();
        st.live = st.live.saturating_sub(1);
        self.turn.notify_all();
    }

    /// Waits until every running strip waits for a round, and hands them over; `None` once
    /// every strip has finished.
    fn next_round(&self) -> Option<Vec<(usize, Sender<StreamMsg>)>> {
        let mut st = self.lock();
        loop {
            if st.live == 0 {
                return None;
            }
            if !st.waiting.is_empty() && st.waiting.len() >= st.live {
                return Some(std::mem::take(&mut st.waiting));
            }
            st = self.wait(st);
        }
    }

    fn end_round(&self) {
        let mut st = self.lock();
        st.round += 1;
        self.turn.notify_all();
    }

    /// Runs rounds over `source` until every strip has finished.
    fn serve(&self, source: &mut dyn Source, strips: &[Strip], capacity: usize) {
        let width = source.spec().width;
        while let Some(mut waiters) = self.next_round() {
            let (tx, rx) = bounded::<StreamMsg>(capacity.max(1));
            std::thread::scope(|scope| {
                let inner = &mut *source;
                scope.spawn(move || inner.stream(&tx));
                for msg in rx.iter() {
                    let end = matches!(msg, StreamMsg::SweepEnd | StreamMsg::Abort(_));
                    waiters.retain(|(k, out)| out.send(crop(&msg, &strips[*k], width)).is_ok());
                    if end || waiters.is_empty() {
                        break;
                    }
                }
                // The source stops at its next send once nobody listens.
                drop(rx);
            });
            drop(waiters);
            self.end_round();
        }
    }
}

/// Tells the hub its strip has finished, however the strip's thread ends.
struct Leave<'a>(&'a Hub);

impl Drop for Leave<'_> {
    fn drop(&mut self) {
        self.0.leave();
    }
}

/// Columns `first_col..first_col + cols` of every row of a `rows x width` block (shorter if
/// the block is: the pipeline then reports its size).
fn crop_rows(v: &[f32], rows: usize, width: usize, strip: &Strip) -> Vec<f32> {
    let mut out = Vec::with_capacity(rows * strip.cols);
    for r in 0..rows {
        let at = r * width + strip.first_col;
        match v.get(at..at + strip.cols) {
            Some(part) => out.extend_from_slice(part),
            None => break,
        }
    }
    out
}

/// A strip's view of a message: its columns, and the incidence angle its centre sees
/// (the magnitude: a planar film reflects alike at `+theta` and `-theta`).
fn crop(msg: &StreamMsg, strip: &Strip, width: usize) -> StreamMsg {
    match msg {
        StreamMsg::Angle { incidence_deg } => StreamMsg::Angle {
            incidence_deg: (incidence_deg + strip.offset_deg).abs(),
        },
        StreamMsg::Rows(b) => {
            let rows = b.rows as usize;
            let c = |v: &Vec<f32>| crop_rows(v, rows, width, strip);
            let samples = match &b.samples {
                Samples::Reflectance(v) => Samples::Reflectance(c(v)),
                Samples::Raw {
                    counts,
                    dark,
                    white,
                    white_reflectance,
                    saturation_counts,
                } => Samples::Raw {
                    counts: c(counts),
                    dark: dark.as_ref().map(c),
                    white: c(white),
                    white_reflectance: *white_reflectance,
                    saturation_counts: *saturation_counts,
                },
            };
            StreamMsg::Rows(RowBlock {
                band: b.band,
                first_row: b.first_row,
                rows: b.rows,
                samples,
            })
        }
        other => other.clone(),
    }
}

/// One strip of columns of a shared source, as a source of its own: its columns, its
/// angles (the stage angles moved by the strip's offset).
pub(crate) struct StripSource<'a> {
    hub: &'a Hub,
    strip: usize,
    spec: SweepSpec,
    angles_deg: Vec<f64>,
    replayable: bool,
}

impl Source for StripSource<'_> {
    fn spec(&self) -> &SweepSpec {
        &self.spec
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.angles_deg.clone()
    }

    fn stream(&mut self, tx: &Sender<StreamMsg>) {
        self.hub.join_round(self.strip, tx);
    }

    fn replayable(&self) -> bool {
        self.replayable
    }
}

/// The index strips agree on.
#[derive(Clone, Debug)]
pub struct Combined {
    /// The combined index model.
    pub index: IndexModel,
    /// Its standard error at 550 nm (scaled up by the Birge ratio when the strips scatter
    /// more than their sigmas allow).
    pub sigma: f64,
    /// Chi-square of the combined strips' indices at 550 nm about the combined one (with
    /// their sigmas floored at [`STRIP_INDEX_FLOOR`]).
    pub chi2: f64,
    /// Which strips were combined.
    pub used: Vec<bool>,
}

/// The least a strip's index is taken to be uncertain by (at 550 nm), whatever sigma it
/// reports: a full-spectrum sigma is statistical only (measured on paper-sample1-wide-fov,
/// 8 strips: sigmas of 5e-5 to 1e-4 on indices that scatter by 0.0013, and 1.2e-4 on one
/// 0.02 off).
pub const STRIP_INDEX_FLOOR: f64 = 0.002;

/// Combines strips' indices by inverse variance (weights `1 / (sigma^2 + floor^2)` at
/// 550 nm), leaving out, one at a time while three or more remain, the strip furthest from
/// the others' mean if more than [`filmscope_core::solve::index::OUTLIER_SIGMA`] of its
/// sigma away. Strips without an index or with a model mismatch take no part. The number of
/// Cauchy terms is the one most combined strips chose (ties: fewer); each basis coefficient
/// is averaged over the combined strips that have it.
pub fn combine(outs: &[&SweepOutput]) -> Option<Combined> {
    let sig = |o: &SweepOutput| {
        let s = if o.index_sigma.is_finite() {
            o.index_sigma
        } else {
            0.0
        };
        (s * s + STRIP_INDEX_FLOOR * STRIP_INDEX_FLOOR).sqrt()
    };
    let mut used: Vec<bool> = outs
        .iter()
        .map(|o| o.index.is_some() && !o.model_mismatch)
        .collect();
    let n550 = |o: &SweepOutput| o.index.map_or(f64::NAN, |m| m.to_basis()[0]);
    let mean_of = |used: &[bool], skip: Option<usize>| -> Option<(f64, f64)> {
        let (mut sw, mut swx) = (0.0, 0.0);
        for (k, o) in outs.iter().enumerate() {
            if used[k] && Some(k) != skip {
                let w = sig(o).powi(-2);
                sw += w;
                swx += w * n550(o);
            }
        }
        (sw > 0.0).then(|| (swx / sw, sw.powf(-0.5)))
    };
    while used.iter().filter(|&&u| u).count() >= 3 {
        let mut worst: Option<(usize, f64)> = None;
        for (k, o) in outs.iter().enumerate() {
            if !used[k] {
                continue;
            }
            if let Some((m, s)) = mean_of(&used, Some(k)) {
                let z = (n550(o) - m).abs() / (sig(o).powi(2) + s * s).sqrt();
                if z > filmscope_core::solve::index::OUTLIER_SIGMA
                    && worst.is_none_or(|(_, wz)| z > wz)
                {
                    worst = Some((k, z));
                }
            }
        }
        match worst {
            Some((k, _)) => used[k] = false,
            None => break,
        }
    }
    let (mean, sigma) = mean_of(&used, None)?;
    let members: Vec<(IndexModel, f64)> = outs
        .iter()
        .zip(&used)
        .filter(|(_, &u)| u)
        .filter_map(|(o, _)| Some((o.index?, sig(o))))
        .collect();
    let mut votes = [0usize; 3];
    for (m, _) in &members {
        votes[m.terms() - 1] += 1;
    }
    let terms = (0..3).fold(0, |best, t| if votes[t] > votes[best] { t } else { best }) + 1;
    let mut p = [mean, 0.0, 0.0];
    for (j, pj) in p.iter_mut().enumerate().take(terms).skip(1) {
        let (mut sw, mut swx) = (0.0, 0.0);
        for (m, s) in members.iter().filter(|(m, _)| m.terms() > j) {
            sw += s.powi(-2);
            swx += s.powi(-2) * m.to_basis()[j];
        }
        if sw > 0.0 {
            *pj = swx / sw;
        }
    }
    let chi2: f64 = members
        .iter()
        .map(|(m, s)| ((m.to_basis()[0] - mean) / s).powi(2))
        .sum();
    let birge = if members.len() > 1 {
        (chi2 / (members.len() - 1) as f64).sqrt().max(1.0)
    } else {
        1.0
    };
    Some(Combined {
        index: IndexModel::from_basis(p),
        sigma: birge * sigma,
        chi2,
        used,
    })
}

/// Runs `job` on every strip's source, each on its own thread, the strips' streams served
/// by one stream of `source` per round (the hub, channels of `capacity` messages); `views`
/// holds each strip's sweep and angles.
fn in_rounds<T: Send>(
    source: &mut dyn Source,
    strips: &[Strip],
    views: &[(SweepSpec, Vec<f64>)],
    capacity: usize,
    job: impl Fn(usize, &mut StripSource<'_>) -> Result<T, PipelineError> + Sync,
) -> Result<Vec<T>, PipelineError> {
    let hub = Hub::new(strips.len());
    let replayable = source.replayable();
    let outs: Vec<Result<T, PipelineError>> = std::thread::scope(|scope| {
        let handles: Vec<_> = views
            .iter()
            .enumerate()
            .map(|(k, (spec, angles))| {
                let mut src = StripSource {
                    hub: &hub,
                    strip: k,
                    spec: spec.clone(),
                    angles_deg: angles.clone(),
                    replayable,
                };
                let (hub, job) = (&hub, &job);
                scope.spawn(move || {
                    let _leave = Leave(hub);
                    job(k, &mut src)
                })
            })
            .collect();
        hub.serve(source, strips, capacity);
        handles
            .into_iter()
            .map(|t| t.join().unwrap_or_else(|_| Err(PipelineError::Panicked)))
            .collect()
    });
    outs.into_iter().collect()
}

/// Columns a shared round's seed may be carried from a solved pixel in the same row into one
/// the last round left unsolved.
pub const SEED_REACH_COLUMNS: usize = 16;

/// The thickness maps a shared round starts from, one per strip: the last round's
/// thicknesses of the strips whose index took part in the combination (`used`), carried
/// along each row into the gaps (at most [`SEED_REACH_COLUMNS`]). A seeded pixel keeps the
/// order of its seed rather than choosing one again: a pass with a prior index chooses
/// orders from its first two angles alone and keeps them while the index stays put, which
/// failed for MgF2 400 nm (paper-sample1: a second pass from its own first pass's index
/// flagged every pixel `model_mismatch`, residual 0.0199 against a noise of 0.0044); the
/// full-spectrum order check still flags a seed a whole order off.
fn shared_seeds(
    strips: &[Strip],
    outs: &[&SweepOutput],
    used: &[bool],
    w: usize,
    h: usize,
) -> Vec<Vec<f32>> {
    let mut map = vec![f32::NAN; w * h];
    for (k, s) in strips.iter().enumerate() {
        if !used[k] {
            continue;
        }
        for row in 0..h {
            for c in 0..s.cols {
                map[row * w + s.first_col + c] = outs[k].results[row * s.cols + c].thickness_nm;
            }
        }
    }
    let mut filled = map.clone();
    for row in 0..h {
        let line = &map[row * w..(row + 1) * w];
        for x in 0..w {
            if line[x].is_finite() {
                continue;
            }
            let near = (1..=SEED_REACH_COLUMNS).find_map(|d| {
                let left = x.checked_sub(d).map(|i| line[i]).filter(|v| v.is_finite());
                let right = line.get(x + d).copied().filter(|v| v.is_finite());
                left.or(right)
            });
            if let Some(v) = near {
                filled[row * w + x] = v;
            }
        }
    }
    strips
        .iter()
        .map(|s| {
            (0..h)
                .flat_map(|row| {
                    filled[row * w + s.first_col..row * w + s.first_col + s.cols].to_vec()
                })
                .collect()
        })
        .collect()
}

/// By how much to scale the thickness a strip's sweep gave a pixel to get the pixel's own:
/// the strip modelled the pixel at the stage angles `stage_deg` moved by `strip_deg`, while
/// its column sees them moved by `column_deg`.
///
/// A film's fringes at incidence `theta` are fixed by its optical path `2 d c(theta)`,
/// `c(theta) = sqrt(n^2 - n0^2 sin^2 theta)` (`n` the film's index at 550 nm, `n0` the
/// ambient's). The strip's thickness `d'` matches its modelled paths `d' c(theta_i +
/// strip_deg)` to the pixel's true `d c(theta_i + column_deg)` at every angle; by least
/// squares with the angles weighted alike, `d = d' sum c_s^2 / sum c_s c_c`. First order in
/// the angle difference: what the strip's fit cannot absorb stays in its residual.
pub fn column_factor(
    index_550: f64,
    ambient_index: f64,
    stage_deg: &[f64],
    strip_deg: f64,
    column_deg: f64,
) -> f64 {
    let c = |deg: f64| {
        let s = ambient_index * deg.to_radians().sin();
        (index_550 * index_550 - s * s).max(0.0).sqrt()
    };
    let (mut ss, mut sc) = (0.0, 0.0);
    for &a in stage_deg {
        let (cs, cc) = (c(a + strip_deg), c(a + column_deg));
        ss += cs * cs;
        sc += cs * cc;
    }
    if sc > 0.0 {
        ss / sc
    } else {
        1.0
    }
}

/// What the wide model produced.
pub struct WideRun {
    /// The strips.
    pub strips: Vec<Strip>,
    /// Each strip's own passes.
    pub own: Vec<Passes>,
    /// Each strip's last kept pass of the [`SHARED_ROUNDS`] (a round's pass is not kept if it
    /// fits worse than the strip's pass before it: a model mismatch, fewer valid pixels).
    pub held: Vec<Option<SweepOutput>>,
    /// The combined index.
    pub combined: Option<Combined>,
    /// The merged per-pixel results, row-major over the whole image (thickness mapped to
    /// each column's angle).
    pub results: Vec<PixelResult>,
    /// RMS fit residual over all strips (their residuals weighted by pixels).
    pub residual_sigma: Option<f64>,
    /// Median of the strips' noise.
    pub noise_sigma: Option<f32>,
}

impl WideRun {
    /// Strip `k`'s final pass: its last kept shared round, else its own passes' best.
    pub fn last(&self, k: usize) -> &SweepOutput {
        self.held[k].as_ref().unwrap_or(&self.own[k].out)
    }

    /// Whether the strips have no index to share (none gave a usable one).
    pub fn no_index(&self) -> bool {
        self.combined.is_none()
    }

    /// Whether any strip's final pass was flagged as not explained by the film model.
    pub fn model_mismatch(&self) -> bool {
        (0..self.strips.len()).any(|k| self.last(k).model_mismatch)
    }
}

/// The rounds that give the strips one index, after their own passes: each strip passes
/// from the combined index, seeded by the last round's maps (`shared_seeds`), first with the
/// index taken from its full spectra (the strips' indices then combined again), then with
/// the combined index held. Measured on the 30 degree scenes (`--field wide`, 15 strips):
/// holding the first combination directly gave paper-sample1 +0.0021 / 0.81 nm / 95.3 %
/// valid (the extremum-shift indices of 400-pixel strips scatter), the full-spectra round
/// alone +0.0004 / 0.24 nm / 95.3 % and ZnS 0.23 nm, both rounds +0.0004 / 0.24 nm / 99.9 %
/// and ZnS -0.0001 / 0.07 nm / 100 %.
pub const SHARED_ROUNDS: [PriorUpdate; 2] = [PriorUpdate::FullSpectra, PriorUpdate::Hold];

/// Runs the wide model on `source` seen through `fov`: each strip's own passes on one shared
/// stream per round, the strips' indices combined ([`combine`]), the [`SHARED_ROUNDS`] (more
/// than one strip, a replayable source), and the strips' maps merged with each pixel's
/// thickness mapped to its column's angle ([`column_factor`]). `on_rows` is told of the first
/// strip's first-pass rows.
pub fn run_wide(
    source: &mut dyn Source,
    config: &RunConfig,
    fov: FieldOfView,
    strips: &[Strip],
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<WideRun, PipelineError> {
    let spec = source.spec().clone();
    let angles = source.angles_deg();
    let replayable = source.replayable();
    // The strips run side by side: one worker each.
    let pipeline = PipelineConfig {
        workers: 1,
        ..config.pipeline
    };
    // Strips are combined by their statistical sigmas: the rig's terms are common to them
    // (the combined index's floor, [`STRIP_INDEX_FLOOR`], stands for its accuracy).
    let strip_config = RunConfig {
        pipeline,
        rig_tolerance: Some(0.0),
        ..*config
    };
    let rounds = StripRounds::new(&spec, &angles, strips, config.pipeline.channel_capacity);
    let quiet = |_: u64| {};
    let own = rounds.run(source, |k, src| {
        let rows: &(dyn Fn(u64) + Sync) = if k == 0 { on_rows } else { &quiet };
        filmscope_passes(src, &strip_config, rows)
    })?;

    let mut combined = combine(&own.iter().map(|p| &p.out).collect::<Vec<_>>());
    let can_hold = replayable && config.pipeline.solver.refine && config.field.shared_rounds;
    let held = if can_hold && strips.len() > 1 {
        rounds.shared(source, pipeline, &own, &mut combined)?
    } else {
        vec![None; strips.len()]
    };

    let mut run = WideRun {
        strips: strips.to_vec(),
        own,
        held,
        combined,
        results: Vec::new(),
        residual_sigma: None,
        noise_sigma: None,
    };
    run.merge(fov, &spec, &angles, config.field.column_map);
    Ok(run)
}

/// The strips of one sweep, each seen as a sweep of its own, for the rounds that stream the
/// source once to all of them ([`in_rounds`]).
struct StripRounds<'a> {
    strips: &'a [Strip],
    /// Each strip's spec and incidence angles.
    views: Vec<(SweepSpec, Vec<f64>)>,
    /// Capacity of each pipeline channel, in messages.
    capacity: usize,
    /// The whole image's size.
    width: usize,
    height: usize,
}

impl<'a> StripRounds<'a> {
    /// The strips of a sweep of `spec` at the stage angles `angles`.
    fn new(spec: &SweepSpec, angles: &[f64], strips: &'a [Strip], capacity: usize) -> Self {
        let views = strips
            .iter()
            .map(|s| {
                let mut sp = spec.clone();
                sp.width = s.cols;
                let a = angles.iter().map(|a| (a + s.offset_deg).abs()).collect();
                (sp, a)
            })
            .collect();
        Self {
            strips,
            views,
            capacity,
            width: spec.width,
            height: spec.height,
        }
    }

    /// One round: `job` on every strip's source, the source streamed once.
    fn run<T: Send>(
        &self,
        source: &mut dyn Source,
        job: impl Fn(usize, &mut StripSource<'_>) -> Result<T, PipelineError> + Sync,
    ) -> Result<Vec<T>, PipelineError> {
        in_rounds(source, self.strips, &self.views, self.capacity, job)
    }

    /// The [`SHARED_ROUNDS`] after the strips' own passes `own`, from the `combined` index
    /// (updated after the full-spectra round): each strip's last kept pass.
    fn shared(
        &self,
        source: &mut dyn Source,
        pipeline: PipelineConfig,
        own: &[Passes],
        combined: &mut Option<Combined>,
    ) -> Result<Vec<Option<SweepOutput>>, PipelineError> {
        let strips = self.strips;
        let mut held: Vec<Option<SweepOutput>> = vec![None; strips.len()];
        let Some(c0) = combined.clone() else {
            return Ok(held);
        };
        let quiet = |_: u64| {};
        let (mut index, mut used) = (c0.index, c0.used.clone());
        for update in SHARED_ROUNDS {
            let last: Vec<&SweepOutput> = (0..strips.len())
                .map(|k| held[k].as_ref().unwrap_or(&own[k].out))
                .collect();
            let seeds = shared_seeds(strips, &last, &used, self.width, self.height);
            let outs = self.run(source, |k, src| {
                let prior = Prior::new(index, update, Some(Arc::new(seeds[k].clone())));
                run_sweep(src, pipeline, Some(prior), &quiet)
            })?;
            let mut next = held.clone();
            for (k, out) in outs.into_iter().enumerate() {
                let prev = last[k];
                let worse = out.model_mismatch && !prev.model_mismatch
                    || valid_fraction(&out.results) < valid_fraction(&prev.results);
                if !worse {
                    next[k] = Some(out);
                }
            }
            held = next;
            if update == PriorUpdate::FullSpectra {
                let outs: Vec<&SweepOutput> = (0..strips.len())
                    .map(|k| held[k].as_ref().unwrap_or(&own[k].out))
                    .collect();
                if let Some(c) = combine(&outs) {
                    index = c.index;
                    used = c.used.clone();
                    *combined = Some(c);
                }
            }
        }
        Ok(held)
    }
}

impl WideRun {
    /// Merges the strips' final passes into [`WideRun::results`] over the whole image of
    /// `spec` (each pixel's thickness mapped to its column's angle through `fov` when
    /// `column_map` and there is a combined index), with the residual and noise over all
    /// strips.
    fn merge(&mut self, fov: FieldOfView, spec: &SweepSpec, angles: &[f64], column_map: bool) {
        let (w, h) = (spec.width, spec.height);
        let n550 = self.combined.as_ref().map(|c| c.index.at(550.0));
        let mut results = vec![PixelResult::UNSOLVED; w * h];
        let (mut sse, mut n_px) = (0.0, 0usize);
        let mut noises = Vec::new();
        for (k, s) in self.strips.iter().enumerate() {
            let factors: Vec<f64> = (0..s.cols)
                .map(|c| match (n550, column_map) {
                    (Some(n), true) => {
                        let column_deg = fov.column_offset_deg(s.first_col + c, w);
                        column_factor(n, spec.ambient_index, angles, s.offset_deg, column_deg)
                    }
                    _ => 1.0,
                })
                .collect();
            let out = self.last(k);
            for row in 0..h {
                let from = &out.results[row * s.cols..(row + 1) * s.cols];
                let own = &self.own[k].out.results[row * s.cols..(row + 1) * s.cols];
                let at = row * w + s.first_col;
                let to = &mut results[at..at + s.cols];
                for (((t, f), o), factor) in to.iter_mut().zip(from).zip(own).zip(&factors) {
                    *t = *f;
                    t.thickness_nm = (f64::from(f.thickness_nm) * factor) as f32;
                    t.thickness_sigma_nm = (f64::from(f.thickness_sigma_nm) * factor) as f32;
                    // A held pass's seed is the strips' own map, not the spectrum search's.
                    t.flags &= !flags::FROM_SPECTRUM_SEARCH | o.flags;
                }
            }
            if let Some(r) = out.residual_sigma {
                sse += r * r * (s.cols * h) as f64;
                n_px += s.cols * h;
            }
            noises.extend(out.noise_sigma);
        }
        noises.sort_by(f32::total_cmp);
        self.results = results;
        self.residual_sigma = (n_px > 0).then(|| (sse / n_px as f64).sqrt());
        self.noise_sigma = noises.get(noises.len() / 2).copied();
    }
}

/// Whether a fit explains the spectra, as the auto choice asks: an index, no model
/// mismatch, a residual of at most [`UNDERFIT_RATIO`] times the noise. With what it measured.
fn fit_evidence(
    index: bool,
    mismatch: bool,
    residual: Option<f64>,
    noise: Option<f32>,
) -> (bool, String) {
    let (r, n) = (
        residual.unwrap_or(f64::NAN),
        noise.map_or(f64::NAN, f64::from),
    );
    let figures = format!("residual {r:.5} against a noise of {n:.5} ({:.2} x)", r / n);
    if !index {
        (false, "no index".to_owned())
    } else if mismatch {
        (false, format!("model mismatch, {figures}"))
    } else if r > UNDERFIT_RATIO * n {
        (false, figures)
    } else {
        (true, figures)
    }
}

/// Orders fits: an index before none, no model mismatch before one, then by residual over
/// noise.
fn rank(
    index: bool,
    mismatch: bool,
    residual: Option<f64>,
    noise: Option<f32>,
) -> (bool, bool, f64) {
    let ratio = match (residual, noise) {
        (Some(r), Some(n)) if n > 0.0 => r / f64::from(n),
        _ => f64::INFINITY,
    };
    (!index, mismatch, ratio)
}

/// The auto choice's rule, for `summary.json`.
pub const AUTO_CRITERION: &str = "narrow unless the capture gives the lens's field of view and the narrow fit does not explain the spectra (no index, a model mismatch, or a residual above 1.25 x the pixels' noise), and the wide model then fits them better (ranked by: an index found, no model mismatch, residual over noise)";

/// The streaming method in a field: the narrow model, the wide one, or (`--field auto`) the
/// simplest the data do not contradict, with the choice and its evidence in
/// [`Run::field_model_choice`].
pub fn run_filmscope(
    source: &mut dyn Source,
    config: &RunConfig,
    field_of_view: Option<FieldOfView>,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<Run, PipelineError> {
    let t0 = Instant::now();
    let width = source.spec().width;
    let plan = field_of_view.map(|fov| {
        let k = config
            .field
            .strips
            .unwrap_or_else(|| strips_for(fov, width));
        (fov, plan_strips(fov, width, k))
    });
    let geometry = field_geometry(
        config,
        field_of_view,
        width,
        plan.as_ref().map(|(_, s)| s.as_slice()),
    );
    let choice = config.field.choice;
    let Some((fov, strips)) = plan else {
        return run_without_lens(source, config, &geometry, on_rows, t0);
    };
    if choice == FieldChoice::Wide {
        let wide = run_wide(source, config, fov, &strips, on_rows)?;
        let mut run = wide_run(source, &wide, t0);
        let evidence = Evidence::new(source, Some(fov), None, Some((&wide, run.seconds)));
        run.field_model_choice =
            evidence.record(config, FieldModel::Wide, "forced (--field wide)", &geometry);
        return Ok(run);
    }
    let passes = filmscope_passes(source, config, on_rows)?;
    let mut run = narrow_run(source, &passes, t0);
    let narrow_s = run.seconds;
    let o = &passes.out;
    let (fits, narrow_fig) = fit_evidence(
        o.index.is_some(),
        o.model_mismatch,
        o.residual_sigma,
        o.noise_sigma,
    );
    let kept = narrow_kept(choice, fits, &narrow_fig, source.replayable(), strips.len());
    if let Some(reason) = kept {
        let evidence = Evidence::new(source, Some(fov), Some((&passes, narrow_s)), None);
        run.field_model_choice = evidence.record(config, FieldModel::Narrow, &reason, &geometry);
        return Ok(run);
    }
    let t1 = Instant::now();
    let wide = run_wide(source, config, fov, &strips, &|_| {})?;
    let wide_s = t1.elapsed().as_secs_f64();
    let (_, wide_fig) = fit_evidence(
        !wide.no_index(),
        wide.model_mismatch(),
        wide.residual_sigma,
        wide.noise_sigma,
    );
    let (model, reason) = if wide_ranks_higher(&wide, o) {
        run = wide_run(source, &wide, t0);
        (
            FieldModel::Wide,
            format!("the narrow fit does not explain the spectra ({narrow_fig}); the wide one ({} strips) does better ({wide_fig})", strips.len()),
        )
    } else {
        run.seconds = t0.elapsed().as_secs_f64();
        (
            FieldModel::Narrow,
            format!("the narrow fit does not explain the spectra ({narrow_fig}), but the wide one ({} strips) does no better ({wide_fig})", strips.len()),
        )
    };
    let evidence = Evidence::new(
        source,
        Some(fov),
        Some((&passes, narrow_s)),
        Some((&wide, wide_s)),
    );
    run.field_model_choice = evidence.record(config, model, &reason, &geometry);
    Ok(run)
}

/// Whether the wide fit `wide` ranks above the narrow fit `narrow` ([`rank`]).
fn wide_ranks_higher(wide: &WideRun, narrow: &SweepOutput) -> bool {
    rank(
        !wide.no_index(),
        wide.model_mismatch(),
        wide.residual_sigma,
        wide.noise_sigma,
    ) < rank(
        narrow.index.is_some(),
        narrow.model_mismatch,
        narrow.residual_sigma,
        narrow.noise_sigma,
    )
}

/// The field's geometry for `summary.json`: the lens's field of view and angle spread over
/// `width` columns, and the planned `strips` with their widest spread.
fn field_geometry(
    config: &RunConfig,
    field_of_view: Option<FieldOfView>,
    width: usize,
    strips: Option<&[Strip]>,
) -> FieldGeometry {
    FieldGeometry {
        horizontal_fov_deg: field_of_view.map(|f| f.horizontal_deg()),
        angle_spread_deg: field_of_view.map(|f| angle_spread_deg(f, width)),
        strips: strips.map(<[Strip]>::len),
        strip_spread_deg: strips.map(|s| s.iter().map(|x| x.spread_deg).fold(0.0, f64::max)),
        strip_spread_tolerance_deg: STRIP_SPREAD_DEG,
        column_map: config.field.column_map,
    }
}

/// The narrow model on a capture that gives no field of view (an error if the wide one is
/// forced).
fn run_without_lens(
    source: &mut dyn Source,
    config: &RunConfig,
    geometry: &FieldGeometry,
    on_rows: &(dyn Fn(u64) + Sync),
    t0: Instant,
) -> Result<Run, PipelineError> {
    let choice = config.field.choice;
    if choice == FieldChoice::Wide {
        return Err(PipelineError::Setup(
            "--field wide needs the lens's field of view (capture.toml [lens] horizontal_fov_deg)"
                .into(),
        ));
    }
    let passes = filmscope_passes(source, config, on_rows)?;
    let mut run = narrow_run(source, &passes, t0);
    let reason = if choice == FieldChoice::Narrow {
        "forced (--field narrow)"
    } else {
        "the capture gives no field of view ([lens] horizontal_fov_deg): one incidence angle per frame"
    };
    let evidence = Evidence::new(source, None, Some((&passes, run.seconds)), None);
    run.field_model_choice = evidence.record(config, FieldModel::Narrow, reason, geometry);
    Ok(run)
}

/// Why the narrow model stands without fitting the wide one, if it does: it is forced, it
/// explains the spectra (`fits`, with `narrow_fig` its figures), a live source streams
/// once, or the field needs no more than one strip.
fn narrow_kept(
    choice: FieldChoice,
    fits: bool,
    narrow_fig: &str,
    replayable: bool,
    strips: usize,
) -> Option<String> {
    if choice == FieldChoice::Narrow || fits {
        Some(if choice == FieldChoice::Narrow {
            "forced (--field narrow)".to_owned()
        } else {
            format!("the narrow fit explains the spectra: {narrow_fig}")
        })
    } else if !replayable {
        Some(format!("the narrow fit does not explain the spectra ({narrow_fig}), but a live source streams once: no second model can be fitted (force --field wide to fit the wide one alone)"))
    } else if strips < 2 {
        Some(format!("the narrow fit does not explain the spectra ({narrow_fig}), but the field's angle spread is within one strip's {STRIP_SPREAD_DEG} deg: the wide model would fit this same sweep"))
    } else {
        None
    }
}

/// A narrow-model fit residual above this many times the pixels' noise calls for the wide
/// model (well-modelled scenes measure 0.83-1.03).
pub const UNDERFIT_RATIO: f64 = 1.25;

/// The narrow model's run.
fn narrow_run(source: &dyn Source, p: &Passes, t0: Instant) -> Run {
    let mut result = result_from_sweep(&p.out);
    if let Some(fit) = p.fit.as_ref() {
        if let Some(f) = fit.failure {
            // Where the best fit's misfit lies (blue or red, which angles, an offset) points
            // to the likely cause among those the message lists.
            result.notes.push(if fit.residual.rms.is_finite() {
                format!(
                    "{}; the best fit leaves {}",
                    f.message(),
                    crate::estimate::index_fit::residual_shape(&fit.residual)
                )
            } else {
                f.message().to_owned()
            });
            result.notes.extend(p.notes.iter().cloned());
        }
    }
    Run {
        result,
        spec: source.spec().clone(),
        angles_deg: source.angles_deg(),
        seconds: t0.elapsed().as_secs_f64(),
        solve_latency_ms: Some(p.out.solve_latency.as_secs_f64() * 1e3),
        state_bytes_per_pixel: Some(p.out.state_bytes_per_pixel),
        samples: p.out.samples,
        angle_reports: angle_reports(&p.out),
        model_choice: Some(IndexModelChoice::Fitted(Box::new(p.choice.clone()))),
        field_model: Some(FieldModel::Narrow),
        field_model_choice: None,
    }
}

/// The wide model's run: the merged maps, the combined index, the strips' notes.
fn wide_run(source: &dyn Source, wide: &WideRun, t0: Instant) -> Run {
    // The strip at the image centre (its angles are the stage's) reports its angles.
    let k_mid = wide
        .strips
        .iter()
        .position(|s| s.offset_deg >= 0.0)
        .unwrap_or(0);
    let mut notes = Vec::new();
    for (k, s) in wide.strips.iter().enumerate() {
        for note in result_from_sweep(wide.last(k)).notes {
            notes.push(format!(
                "strip {} (columns {}..{}): {note}",
                k + 1,
                s.first_col,
                s.first_col + s.cols
            ));
        }
    }
    if wide.no_index() {
        notes.push("no strip gave a usable index: no index, no thickness".to_owned());
    }
    let result = MethodResult {
        method: Method::Filmscope,
        index: wide
            .combined
            .as_ref()
            .map_or(IndexModel::constant(f64::NAN), |c| c.index),
        index_sigma: wide.combined.as_ref().map(|c| c.sigma),
        thickness_nm: wide.results.iter().map(|r| r.thickness_nm).collect(),
        confidence: wide.results.iter().map(|r| r.confidence).collect(),
        thickness_sigma_nm: wide.results.iter().map(|r| r.thickness_sigma_nm).collect(),
        flags: wide.results.iter().map(|r| r.flags).collect(),
        notes,
    };
    let strips: Vec<_> = (0..wide.strips.len())
        .map(|k| wide.own[k].choice.clone())
        .collect();
    let chosen = wide
        .combined
        .as_ref()
        .map(|c| (["constant", "cauchy", "cauchy3"])[c.index.terms() - 1]);
    Run {
        result,
        spec: source.spec().clone(),
        angles_deg: source.angles_deg(),
        seconds: t0.elapsed().as_secs_f64(),
        solve_latency_ms: (0..wide.strips.len())
            .map(|k| wide.last(k).solve_latency.as_secs_f64() * 1e3)
            .reduce(f64::max),
        state_bytes_per_pixel: Some(wide.last(0).state_bytes_per_pixel),
        samples: (0..wide.strips.len()).map(|k| wide.last(k).samples).sum(),
        angle_reports: angle_reports(wide.last(k_mid)),
        model_choice: Some(IndexModelChoice::Wide(WideChoice {
            chosen: chosen.map(str::to_owned),
            combination: format!("inverse-variance mean of the strips' indices at 550 nm (sigmas floored at {STRIP_INDEX_FLOOR}; a strip more than {} sigma from the others left out; the number of Cauchy terms most strips chose, each coefficient averaged over the strips that have it), then every strip passes from it, seeded by the last maps, with the index from its full spectra (the strips' indices combined again), then with the combination held", filmscope_core::solve::index::OUTLIER_SIGMA),
            strips,
        })),
        field_model: Some(FieldModel::Wide),
        field_model_choice: None,
    }
}

/// Each model's figures, for `summary.json` `field_model_choice`.
struct Evidence<'a> {
    narrow: Option<(&'a Passes, f64)>,
    wide: Option<(&'a WideRun, f64)>,
    /// The thickness error the narrow model makes at the image's left and right edges,
    /// predicted from the lens ([`column_factor`]) at the narrow fit's index and median
    /// thickness, nm.
    narrow_edge_error_nm: Option<[f64; 2]>,
}

impl<'a> Evidence<'a> {
    fn new(
        source: &dyn Source,
        fov: Option<FieldOfView>,
        narrow: Option<(&'a Passes, f64)>,
        wide: Option<(&'a WideRun, f64)>,
    ) -> Self {
        let spec = source.spec();
        let angles = source.angles_deg();
        // The narrow fit's index and median thickness, else the wide one's.
        let narrow_index = narrow.and_then(|(p, _)| p.out.index);
        let wide_index = wide.and_then(|(w, _)| w.combined.as_ref().map(|c| c.index));
        let index = narrow_index.or(wide_index);
        let thickness = narrow
            .and_then(|(p, _)| median_thickness(&p.out.results))
            .or_else(|| wide.and_then(|(w, _)| median_thickness(&w.results)));
        let narrow_edge_error_nm = match (fov, index, thickness) {
            (Some(f), Some(n), Some(d)) => Some([-0.5, 0.5].map(|side| {
                let edge = side * f.horizontal_deg();
                let k = column_factor(n.at(550.0), spec.ambient_index, &angles, 0.0, edge);
                d / k - d
            })),
            _ => None,
        };
        Self {
            narrow,
            wide,
            narrow_edge_error_nm,
        }
    }

    fn record(
        &self,
        config: &RunConfig,
        chosen: FieldModel,
        reason: &str,
        geometry: &FieldGeometry,
    ) -> Option<FieldModelChoice> {
        let finite = |x: f64| x.is_finite().then_some(x);
        Some(FieldModelChoice {
            chosen: chosen.name().to_owned(),
            requested: config.field.choice.name().to_owned(),
            reason: reason.to_owned(),
            criterion: AUTO_CRITERION.to_owned(),
            geometry: *geometry,
            narrow_edge_error_nm: self.narrow_edge_error_nm,
            narrow: self.narrow.map(|(p, s)| NarrowEvidence {
                index: p.out.index.map(|m| m.at(550.0)),
                index_sigma: p.out.index.and_then(|_| finite(p.out.index_sigma)),
                residual_sigma: p.out.residual_sigma,
                noise_sigma: p.out.noise_sigma.map(f64::from),
                model_mismatch: p.out.model_mismatch,
                valid_fraction: valid_fraction(&p.out.results),
                passes: p.passes,
                seconds: s,
            }),
            wide: self.wide.map(|(w, s)| WideEvidence {
                index: w.combined.as_ref().map(|c| c.index.at(550.0)),
                index_sigma: w.combined.as_ref().and_then(|c| finite(c.sigma)),
                strip_index_chi2: w.combined.as_ref().and_then(|c| finite(c.chi2)),
                strips_combined: w
                    .combined
                    .as_ref()
                    .map(|c| c.used.iter().filter(|&&u| u).count()),
                residual_sigma: w.residual_sigma,
                noise_sigma: w.noise_sigma.map(f64::from),
                model_mismatch: w.model_mismatch(),
                valid_fraction: valid_fraction(&w.results),
                seconds: s,
                strips: w
                    .strips
                    .iter()
                    .enumerate()
                    .map(|(k, st)| StripEvidence {
                        columns: [st.first_col, st.first_col + st.cols],
                        offset_deg: st.offset_deg,
                        spread_deg: st.spread_deg,
                        index: w.own[k].out.index.map(|m| m.at(550.0)),
                        index_sigma: w.own[k]
                            .out
                            .index
                            .and_then(|_| finite(w.own[k].out.index_sigma)),
                        index_combined: w.combined.as_ref().map(|c| c.used[k]),
                        passes: w.own[k].passes,
                        own_residual_sigma: w.own[k].out.residual_sigma,
                        own_model_mismatch: w.own[k].out.model_mismatch,
                        shared_rounds_kept: w.held[k].is_some(),
                        residual_sigma: w.last(k).residual_sigma,
                        model_mismatch: w.last(k).model_mismatch,
                    })
                    .collect(),
            }),
        })
    }
}

/// Median of the finite thicknesses.
fn median_thickness(results: &[PixelResult]) -> Option<f64> {
    let mut v: Vec<f64> = results
        .iter()
        .map(|r| f64::from(r.thickness_nm))
        .filter(|d| d.is_finite())
        .collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

/// Share of pixels without an invalidating flag.
fn valid_fraction(results: &[PixelResult]) -> f64 {
    let valid = results
        .iter()
        .filter(|p| p.flags & flags::INVALID == 0)
        .count();
    valid as f64 / results.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_column_at_its_strips_angle_keeps_its_thickness() {
        let angles = [10.0, 25.0, 40.0, 55.0];
        assert_eq!(column_factor(2.1, 1.0, &angles, 3.0, 3.0), 1.0);
        // One angle: the ratio of the optical paths.
        let c = |deg: f64| (2.1f64.powi(2) - deg.to_radians().sin().powi(2)).sqrt();
        let f = column_factor(2.1, 1.0, &[30.0], 0.0, 5.0);
        assert!((f - c(30.0) / c(35.0)).abs() < 1e-12, "{f}");
        // A steeper column has a shorter path per nm: its thickness is larger than the
        // strip's fit says.
        assert!(column_factor(1.37, 1.0, &angles, 0.0, 1.0) > 1.0);
        assert!(column_factor(1.37, 1.0, &angles, 0.0, -1.0) < 1.0);
    }

    #[test]
    fn strips_cover_the_image_with_equal_angles() {
        let fov = FieldOfView::new(30.0).expect("fov");
        assert_eq!(strips_for(fov, 96), 15);
        assert_eq!(strips_for(FieldOfView::new(2.0).expect("fov"), 96), 1);
        // Never below MIN_STRIP_COLUMNS columns a strip.
        assert_eq!(strips_for(fov, 24), 6);
        let strips = plan_strips(fov, 96, 15);
        assert_eq!(strips.len(), 15);
        assert_eq!(strips[0].first_col, 0);
        let end = strips.last().map(|s| s.first_col + s.cols);
        assert_eq!(end, Some(96));
        for pair in strips.windows(2) {
            assert_eq!(pair[0].first_col + pair[0].cols, pair[1].first_col);
            assert!(pair[0].offset_deg < pair[1].offset_deg);
        }
        for s in &strips {
            assert!(s.spread_deg <= STRIP_SPREAD_DEG + 0.2, "{s:?}");
        }
    }

    fn output(index: f64, sigma: f64, mismatch: bool) -> SweepOutput {
        let spec = crate::source::sweep_spec(
            4,
            4,
            &(0..16)
                .map(|i| 420.0 + 20.0 * f64::from(i))
                .collect::<Vec<_>>(),
            None,
            1.0,
            1.52,
            filmscope_core::optics::Polarization::S,
            [1.2, 3.0],
            Some([50.0, 2000.0]),
        )
        .expect("spec");
        SweepOutput {
            spec,
            results: Vec::new(),
            index: Some(IndexModel::constant(index)),
            index_sigma: sigma,
            residual_sigma: None,
            noise_sigma: None,
            angles: Vec::new(),
            index_fit: None,
            model_mismatch: mismatch,
            spectral_index: false,
            spectral_gains: [f64::NAN; 3],
            spectral_candidate: None,
            stream_time: std::time::Duration::ZERO,
            solve_latency: std::time::Duration::ZERO,
            latency_parts: Default::default(),
            samples: 0,
            state_bytes_per_pixel: 0,
            tables: Vec::new(),
        }
    }

    #[test]
    fn the_combination_leaves_out_mismatched_and_outlying_strips() {
        // A tiny full-spectrum sigma on a wrong index must not win: sigmas are floored.
        let outs = [
            output(1.370, 0.004, false),
            output(1.371, 0.003, false),
            output(1.369, 0.004, false),
            output(1.393, 1e-4, false),
            output(1.300, 0.001, true),
        ];
        let c = combine(&outs.iter().collect::<Vec<_>>()).expect("combined");
        assert_eq!(c.used, [true, true, true, false, false]);
        assert!((c.index.a - 1.370).abs() < 5e-4, "{}", c.index.a);
        assert!(c.sigma > 0.0 && c.sigma < 0.003, "{}", c.sigma);
        assert!(combine(&[&output(1.3, 0.001, true)]).is_none());
    }
}
