//! Running a method on a source and writing its outputs per capture-format.md.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use filmscope_core::solve::shard::MAX_THICKNESS_SIGMA_NM;
use filmscope_core::solve::sweep::{
    MAX_DISPERSION, MAX_DISPERSION_PER_EXCESS, MISMATCH_FLOOR, MISMATCH_RATIO, SPECTRAL_TERM_CHI2,
};
use filmscope_core::solve::thin::{SampleGrid, SampledSpectra, ThinFit};
use filmscope_core::solve::{flags, IndexModel, SweepSpec};
use serde_json::json;

use crate::baseline::{brute, paper, BruteGrid};
use crate::export::png::{write_map_png, MapPreview};
use crate::field::{FieldConfig, FieldModel};
use crate::io::{write_atomic, write_f32_map, DataType, EnviHeader, EnviWriter, Interleave};
use crate::pipeline::{
    collect_sweep, for_each_calibrated, run_sweep, Calibrated, PipelineConfig, PipelineError,
    Prior, PriorUpdate, Source, SweepOutput,
};
use filmscope_core::optics::FieldOfView;

/// Most passes over a replayable source (the first from the extremum shifts, the others with
/// the index from the full spectra).
pub const MAX_PASSES: usize = 5;
use crate::simulate::dispersion_json;
use crate::sweep::{Method, MethodResult};

/// An index step from the full spectra below this (at 550 nm) is at rest.
pub const SETTLED_INDEX_STEP: f64 = 2e-3;

/// Whether a full-spectrum pass ended with its index at rest: the last step moved it by
/// less than [`SETTLED_INDEX_STEP`] and no pixel had to choose its order again.
fn settled(out: &SweepOutput) -> bool {
    out.angles
        .last()
        .is_some_and(|a| a.refined && a.spectral_index_step.abs() < SETTLED_INDEX_STEP)
}

/// A full-spectrum index step at least this large (at 550 nm) at the end of an
/// extremum-shift pass calls for a pass with the index from the full spectra.
pub const DISAGREE_INDEX_STEP: f64 = 1e-3;

/// Whether the full spectra, at the sweep's end, would move the extremum-shift index by
/// [`DISAGREE_INDEX_STEP`] or more: the extremum shifts of few pixels (a small sensor or
/// region) give a noisy index, which the pixels' thicknesses then absorb (measured on a
/// 24 x 16 crop of paper-sample1: index error 0.0064, thickness MAE 2.8 nm; from the full
/// spectra 0.0004, 0.28 nm; paper-sample3 0.0011, 0.26 nm -> 0.0001, 0.09 nm).
fn disagrees(out: &SweepOutput) -> bool {
    out.angles
        .last()
        .is_some_and(|a| a.refined && a.spectral_index_step.abs() >= DISAGREE_INDEX_STEP)
}

/// The pass to run after `last` (the `passes`-th), if any:
/// - an index that arrived only with the last angle left the orders unconfirmed by the full
///   spectra: after the first pass, pass again with it held, so every pixel is refined;
/// - spectra the extremum-shift index does not explain (real dispersion, a high index), or
///   whose full-spectrum step would move it measurably ([`disagrees`]): pass again with the
///   index from the full spectra, starting where the last pass's full-spectrum step
///   pointed, until it settles. The pass that fits best is kept.
fn next_pass(last: &SweepOutput, passes: usize) -> Option<Prior> {
    if passes == 1 && unrefined(last) {
        return last
            .index
            .map(|index| Prior::new(index, PriorUpdate::Hold, None));
    }
    let again = last.model_mismatch
        || (!last.spectral_index && (underfit(last) || disagrees(last)))
        || (last.spectral_index && !settled(last));
    let index = last.spectral_candidate.or(last.index).filter(|_| again)?;
    Some(Prior::new(index, PriorUpdate::FullSpectra, None))
}

/// Share of the pixels with fringes left unrefined (their orders unconfirmed by the full
/// spectra, so flagged) above which a pass with the index held follows. Measured: at a 1 nm
/// band step a 700 nm film of index 1.38 got its index only at the third angle and left
/// 61 of 192 pixels unrefined (67.7 % valid); most was the threshold then.
pub const UNREFINED_SHARE: f64 = 0.1;

/// Whether more than [`UNREFINED_SHARE`] of the pixels with fringes were never refined on
/// the full spectra (the index came too late in the sweep).
fn unrefined(out: &SweepOutput) -> bool {
    let with_fringes = out
        .results
        .iter()
        .filter(|r| r.flags & flags::NO_FRINGE == 0);
    let (mut n, mut not_refined) = (0usize, 0usize);
    for r in with_fringes {
        n += 1;
        if r.flags & flags::NOT_REFINED != 0 {
            not_refined += 1;
        }
    }
    n > 0 && not_refined as f64 > UNREFINED_SHARE * n as f64
}

/// A fit residual above this many times the pixels' own noise asks for a richer index
/// model (well-modelled scenes measure 0.83-1.03; a held two-term Cauchy index on real ZnS
/// 1.39).
pub const UNDERFIT_RATIO: f64 = 1.25;

/// Whether the spectra are fitted clearly worse than their noise allows (though not so badly
/// that the model is wrong): a full-spectrum pass may find a better index.
fn underfit(out: &SweepOutput) -> bool {
    match (out.residual_sigma, out.noise_sigma) {
        (Some(r), Some(n)) => r > UNDERFIT_RATIO * f64::from(n),
        _ => false,
    }
}

/// Share of pixels with an order (`ordered_fraction`) below which a first pass is thought
/// to have missed a film without fringe pairs and the global search on sampled spectra
/// ([`filmscope_core::solve::thin`]) is tried.
pub const THIN_SEARCH_BELOW_VALID: f64 = 0.5;

fn valid_fraction(out: &SweepOutput) -> f64 {
    let valid = out
        .results
        .iter()
        .filter(|r| r.flags & flags::INVALID == 0)
        .count();
    valid as f64 / out.results.len().max(1) as f64
}

/// Share of the pixels valid or flagged only `imprecise`: with an order whose thickness
/// only the shared index's uncertainty blurs (a thick high-index film's first pass, whose
/// extremum-shift index is loose: measured, n 2.8 / 2000 nm on 1.52 went through the
/// search for films without a fringe pair and came out 0.0101 low in index).
fn ordered_fraction(out: &SweepOutput) -> f64 {
    let ordered = out
        .results
        .iter()
        .filter(|r| r.flags & flags::INVALID & !flags::IMPRECISE == 0)
        .count();
    ordered as f64 / out.results.len().max(1) as f64
}

/// The start of a pass for a film without fringe pairs: the index and a thickness map from
/// the global (index, thickness) search on a grid of sampled pixels' spectra (streamed once
/// more from the source; at most [`thin::MAX_SAMPLED_PIXELS`] spectra held), if its fit is as
/// good as the pixels' noise allows (the [`SweepSolver::model_mismatch`] rule).
fn thin_start(
    source: &mut dyn Source,
    last: &SweepOutput,
) -> Result<Option<(ThinFit, Option<Prior>)>, PipelineError> {
    let spec = last.spec.clone();
    let (w, h, nb) = (spec.width, spec.height, spec.bands_nm.len());
    let grid = SampleGrid::for_image(w, h);
    let px = grid.len();
    let mut angles = Vec::new();
    let mut values: Vec<f32> = Vec::new();
    for_each_calibrated(source, |event| match event {
        Calibrated::Angle(deg) => {
            angles.push(deg);
            values.resize(angles.len() * nb * px, f32::NAN);
        }
        Calibrated::Rows {
            angle,
            band,
            first_row,
            rows,
            values: v,
        } => {
            for k in 0..px {
                let (x, y) = grid.pixel(k);
                if (first_row..first_row + rows).contains(&y) {
                    values[(angle * nb + band) * px + k] = v[(y - first_row) * w + x];
                }
            }
        }
    })?;
    let sample = SampledSpectra {
        spec: &spec,
        angles_deg: &angles,
        pixels: px,
        values: &values,
    };
    let mut sse = vec![0.0; sample.scratch_len()];
    let mut thickness = vec![f32::NAN; px];
    let Some(fit) = sample.fit(&mut sse, &mut thickness) else {
        return Ok(None);
    };
    let noise = last.noise_sigma.map_or(0.0, f64::from);
    if fit.rms > MISMATCH_RATIO * noise + MISMATCH_FLOOR {
        return Ok(Some((fit, None)));
    }
    let mut seed = vec![f32::NAN; w * h];
    // A sample in another basin than its neighbours (a quarter of an order away) would
    // spread its wrong order to the pixels around it.
    let mid = spec.bands_nm[nb / 2];
    grid.reject_outliers(&mut thickness, (mid / (8.0 * fit.index)) as f32);
    grid.interpolate(&thickness, &mut seed);
    let prior = Prior::new(
        IndexModel::constant(fit.index),
        PriorUpdate::FullSpectra,
        Some(Arc::new(seed)),
    );
    Ok(Some((fit, Some(prior))))
}

/// The next seeded pass's thickness map: this pass's thickness where it has one, else the
/// old seed.
fn carry_seed(seed: &[f32], pass: &SweepOutput) -> Arc<Vec<f32>> {
    Arc::new(
        seed.iter()
            .zip(&pass.results)
            .map(|(&s, r)| {
                if r.thickness_nm.is_finite() {
                    r.thickness_nm
                } else {
                    s
                }
            })
            .collect(),
    )
}

/// Orders passes: a pass the model explains before one it does not, then by residual.
fn fit_rank(out: &SweepOutput) -> (bool, f64) {
    (
        out.model_mismatch,
        out.residual_sigma.unwrap_or(f64::INFINITY),
    )
}

/// What the passes over one sweep ended with.
pub struct Passes {
    /// The pass kept.
    pub out: SweepOutput,
    /// Passes run.
    pub passes: usize,
    /// The spectrum search's fit and whether its passes were kept.
    pub search: Option<(ThinFit, bool)>,
    /// The thickness map later passes started from (a film without fringe pairs).
    pub seed: Option<Arc<Vec<f32>>>,
    /// The test of the index model's last term, if the passes ended with more than one.
    pub term_check: Option<TermCheck>,
}

/// The test of a richer index model on sums linearised at its own result
/// (`polish`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TermCheck {
    /// Terms of the model tested.
    pub terms: usize,
    /// The Wald chi-square of its last term ([`SweepSolver::term_chi2`](filmscope_core::solve::sweep::SweepSolver::term_chi2)).
    pub chi2: f64,
    /// Whether the term stayed (else the passes after the test ran without it).
    pub kept: bool,
}

/// Whether a check pass confirms the last term of the model it held: a chi-square of at
/// least [`SPECTRAL_TERM_CHI2`] (or none computed: nothing to judge by).
fn term_confirmed(check: &SweepOutput) -> (f64, bool) {
    let chi2 = check.angles.last().map_or(f64::NAN, |a| a.term_chi2);
    (chi2, chi2.is_nan() || chi2 >= SPECTRAL_TERM_CHI2)
}

/// Flags a polishing pass keeps from the pass before: whether the spectrum search seeded
/// the pixel, and what the extremum tracker found, which a polishing pass does not run for
/// the pixels it holds.
const CARRIED_FLAGS: u16 = flags::FROM_SPECTRUM_SEARCH | flags::TRACKER_OVERFLOW;

/// Most Gauss-Newton iterations on the whole spectra (`polish`) after the passes.
pub const MAX_POLISH: usize = 3;

/// A polishing step of the index (at 550 nm) below this ends the iterations.
pub const POLISHED_INDEX_STEP: f64 = 1e-3;

/// Gauss-Newton iterations on the whole spectra from where the passes ended, each a pass with
/// the index and every pixel's thickness held at the last result ([`PriorUpdate::Frozen`]):
/// its sums are all linearised there, and its last angle tests the index model's last term
/// and takes one step.
///
/// A streaming pass adds each angle's sums at the thicknesses and index of its time; the
/// thicknesses step as the angles arrive, so the earlier angles' sums stay linearised where
/// they were. For a thin film, whose index and thickness trade, that bias is large against
/// the index's own sigma (measured: n 1.6 / 50 nm on 1.52, camera seed 10, thickness steps
/// of 0.16 nm on average halved the reduced index gradient; the full-spectrum pass took a
/// Cauchy term its sums put at chi-square 47 while the whole spectra at its result put it
/// at 3.5, and ended 0.0065 low). A term that fails the test is dropped and the passes run
/// again without it (at most as many terms) until the index settles, then are polished.
fn polish(
    source: &mut dyn Source,
    config: &RunConfig,
    passes: &mut Passes,
) -> Result<(), PipelineError> {
    let mut iterations = 0;
    while iterations < MAX_POLISH {
        let Some(index) = passes.out.index.filter(|_| !passes.out.model_mismatch) else {
            return Ok(());
        };
        let map: Vec<f32> = passes.out.results.iter().map(|r| r.thickness_nm).collect();
        let frozen = Prior {
            noise_sigma: passes.out.noise_sigma,
            ..Prior::new(index, PriorUpdate::Frozen, Some(Arc::new(map)))
        };
        let mut pass = run_sweep(source, config.pipeline, Some(frozen), &|_| {})?;
        passes.passes += 1;
        iterations += 1;
        if index.terms() > 1 {
            let (chi2, kept) = term_confirmed(&pass);
            passes.term_check = Some(TermCheck {
                terms: index.terms(),
                chi2,
                kept,
            });
            if !kept {
                drop_term(source, config, passes, index)?;
                continue;
            }
        }
        if pass.model_mismatch || valid_fraction(&pass) < valid_fraction(&passes.out) {
            return Ok(());
        }
        // Every pixel was seeded here, only the search's seeds say so; and the held pixels'
        // extrema were not tracked: what the pass before found of them stands.
        for (r, before) in pass.results.iter_mut().zip(&passes.out.results) {
            r.flags = (r.flags & !CARRIED_FLAGS) | (before.flags & CARRIED_FLAGS);
        }
        for (a, before) in pass.angles.iter_mut().zip(&passes.out.angles) {
            a.pair = before.pair;
        }
        pass.index_fit = passes.out.index_fit;
        let step = pass.angles.last().map_or(0.0, |a| a.spectral_index_step);
        if let Some(s) = &passes.seed {
            passes.seed = Some(carry_seed(s, &pass));
        }
        passes.out = pass;
        if step.abs() < POLISHED_INDEX_STEP {
            break;
        }
    }
    Ok(())
}

/// Runs full-spectrum passes with `index`'s last term dropped (and no more terms than
/// that) until the index settles; the last is kept.
fn drop_term(
    source: &mut dyn Source,
    config: &RunConfig,
    passes: &mut Passes,
    index: IndexModel,
) -> Result<(), PipelineError> {
    let terms = index.terms() - 1;
    let mut prior = Prior {
        max_terms: Some(terms),
        ..Prior::new(
            index.truncated(terms),
            PriorUpdate::FullSpectra,
            passes.seed.clone(),
        )
    };
    for _ in 0..MAX_PASSES {
        let pass = run_sweep(source, config.pipeline, Some(prior.clone()), &|_| {})?;
        passes.passes += 1;
        if let Some(s) = &passes.seed {
            passes.seed = Some(carry_seed(s, &pass));
            prior.seed = passes.seed.clone();
        }
        let next = pass.spectral_candidate.or(pass.index);
        let done = settled(&pass) || pass.model_mismatch;
        passes.out = pass;
        match next {
            Some(index) if !done => prior.index = index,
            _ => break,
        }
    }
    Ok(())
}

/// The streaming estimator's passes over `source` with one incidence angle per frame: the
/// first pass, the spectrum search for a film without fringe pairs, and the passes
/// `next_pass` asks for; `on_rows` is told of the first pass's rows.
pub fn filmscope_passes(
    source: &mut dyn Source,
    config: &RunConfig,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<Passes, PipelineError> {
    let mut out = run_sweep(source, config.pipeline, None, on_rows)?;
    let mut passes = 1;
    // Further passes over the same data (`next_pass`); `latest` is the last pass when
    // it is not the best, which `out` keeps.
    let mut latest: Option<SweepOutput> = None;
    let can_pass = config.pipeline.solver.refine && source.replayable();
    // A film without fringe pairs: every later pass starts its pixels from a
    // thickness map (the search's, then the last pass's).
    let mut seed: Option<Arc<Vec<f32>>> = None;
    // The search's fit and whether its passes were kept.
    let mut search: Option<(ThinFit, bool)> = None;
    // Also after a model mismatch: the extremum shifts may have found an index from noise
    // extrema (a thick film next to the substrate's index, whose fringes drown in the
    // noise); the search's pass is kept only if it explains the spectra and solves more.
    if can_pass && ordered_fraction(&out) < THIN_SEARCH_BELOW_VALID {
        if let Some((fit, start)) = thin_start(source, &out)? {
            search = Some((fit, false));
            if let Some(prior) = start {
                let pass = run_sweep(source, config.pipeline, Some(prior.clone()), &|_| {})?;
                passes += 1;
                if !pass.model_mismatch && valid_fraction(&pass) > valid_fraction(&out) {
                    seed = prior.seed.map(|s| carry_seed(&s, &pass));
                    search = Some((fit, true));
                    out = pass;
                }
            }
        }
    }
    while can_pass && passes < MAX_PASSES {
        let Some(mut prior) = next_pass(latest.as_ref().unwrap_or(&out), passes) else {
            break;
        };
        if let Some(s) = &seed {
            prior.seed = Some(s.clone());
            prior.update = PriorUpdate::FullSpectra;
        }
        let pass = run_sweep(source, config.pipeline, Some(prior.clone()), &|_| {})?;
        passes += 1;
        if let Some(s) = &seed {
            seed = Some(carry_seed(s, &pass));
        }
        if prior.update == PriorUpdate::Hold || fit_rank(&pass) < fit_rank(&out) {
            out = pass;
            latest = None;
        } else {
            latest = Some(pass);
        }
    }
    let mut passes = Passes {
        out,
        passes,
        search,
        seed,
        term_check: None,
    };
    if can_pass && config.polish {
        polish(source, config, &mut passes)?;
    }
    Ok(passes)
}

/// The per-angle progress of a pass, as JSON (`summary.json` `angle_reports`).
pub fn angle_reports(out: &SweepOutput) -> serde_json::Value {
    let reports: Vec<_> = out
        .angles
        .iter()
        .map(|a| {
            json!({
                "incidence_deg": a.incidence_deg,
                "index": a.index,
                "index_sigma": if a.index_sigma.is_finite() { Some(a.index_sigma) } else { None },
                "pair_index": a.pair.map(|p| p.index),
                "refined": a.refined,
                "spectral_index_step": a.spectral_index_step,
                "dispersive": a.index_terms > 1,
                "index_terms": a.index_terms,
                "index_from_full_spectra": a.spectral_index,
            })
        })
        .collect();
    serde_json::Value::Array(reports)
}

/// The index model chosen and its evidence, for `summary.json` (null without an index).
pub fn model_choice(
    out: &SweepOutput,
    passes: usize,
    search: Option<(ThinFit, bool)>,
    term_check: Option<TermCheck>,
) -> serde_json::Value {
    let Some(index) = out.index else {
        return serde_json::Value::Null;
    };
    let finite = |x: f64| x.is_finite().then_some(x);
    let f = out.index_fit;
    let seeded = search.is_some_and(|(_, kept)| kept);
    json!({
        "residual_sigma": out.residual_sigma,
        "noise_sigma": out.noise_sigma,
        "passes": passes,
        "index_source": match (seeded, out.spectral_index) {
            (true, _) => "spectrum search, then full spectra",
            (false, true) => "full spectra",
            (false, false) => "extremum shifts",
        },
        "spectrum_search": search.map(|(t, kept)| json!({
            "index": t.index,
            "rms": t.rms,
            "sampled_pixels": t.pixels,
            "kept": kept,
            "criterion": format!("tried when fewer than {THIN_SEARCH_BELOW_VALID} of the pixels are valid or flagged only imprecise after the first pass; its passes run if its fit residual is within {MISMATCH_RATIO} x the pixels' noise + {MISMATCH_FLOOR}, and are kept if they leave more pixels valid"),
        })),
        "full_spectrum_chi2_gains": out.spectral_gains.map(finite),
        "term_check": term_check.map(|c| json!({
            "terms": c.terms,
            "chi2": finite(c.chi2),
            "kept": c.kept,
            "criterion": format!("a pass held at the model and seeded with its thicknesses (every sum linearised at the result): the last term stays if its Wald chi-square is at least {SPECTRAL_TERM_CHI2}, else the passes run again without it"),
        })),
        "full_spectrum_criterion": format!("another pass holds the index when it came too late to refine more than {UNREFINED_SHARE} of the pixels with fringes; a pass takes it from the full spectra when the fit residual exceeds {UNDERFIT_RATIO} x the pixels' noise or the full spectra would move the extremum-shift index by {DISAGREE_INDEX_STEP} or more; an extra Cauchy term enters only once the simpler model has settled, if it lowers the chi-square by {SPECTRAL_TERM_CHI2} (5 sigma) and keeps the dispersion physical (normal, at most {MAX_DISPERSION} and {MAX_DISPERSION_PER_EXCESS} x (n - 1) across the band)"),
        "chosen": (["constant", "cauchy", "cauchy3"])[index.terms() - 1],
        "extremum_fit_chosen": f.map(|f| if f.dispersive { "cauchy" } else { "constant" }),
        "chi2_constant": f.map(|f| f.chi2_constant),
        "chi2_cauchy": f.and_then(|f| finite(f.chi2_cauchy)),
        "wavelength_bins": f.map(|f| f.bins),
        "criterion": "Cauchy only if its chi-square gain, in units of its own reduced chi-square, exceeds 25, the constant model's reduced chi-square exceeds 2, and 0 <= b <= 0.2 um^2 with n inside the search range across the band",
    })
}

/// How to run a method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunConfig {
    /// Which estimator.
    pub method: Method,
    /// Pipeline shape (streaming method only).
    pub pipeline: PipelineConfig,
    /// Grid of the brute-force baseline.
    pub brute_grid: BruteGrid,
    /// The field model of the streaming method: chosen from the data (default), or forced,
    /// and the wide model's settings.
    pub field: FieldConfig,
    /// End a replayable estimate with Gauss-Newton iterations on the whole spectra
    /// (`polish`; off: `--ablate polish`, one pass fewer).
    pub polish: bool,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            method: Method::Filmscope,
            pipeline: PipelineConfig::default(),
            brute_grid: BruteGrid::default(),
            field: FieldConfig::default(),
            polish: true,
        }
    }
}

/// One method's run over one sweep.
#[derive(Clone, Debug)]
pub struct Run {
    /// The maps and the index.
    pub result: MethodResult,
    /// The sweep.
    pub spec: SweepSpec,
    /// Incidence angles in streaming order, degrees.
    pub angles_deg: Vec<f64>,
    /// Wall time of the whole run, seconds.
    pub seconds: f64,
    /// Time from the last row to the maps (streaming method), ms.
    pub solve_latency_ms: Option<f64>,
    /// Bytes of per-pixel state (streaming method).
    pub state_bytes_per_pixel: Option<usize>,
    /// Band samples processed.
    pub samples: u64,
    /// Per-angle progress of the streaming solver, as JSON.
    pub angle_reports: serde_json::Value,
    /// How the index model was chosen (streaming method), as JSON.
    pub model_choice: serde_json::Value,
    /// The field model used (streaming method).
    pub field_model: Option<FieldModel>,
    /// How the field model was chosen and its evidence (streaming method), as JSON.
    pub field_model_choice: serde_json::Value,
}

/// The streaming estimator's output as a [`MethodResult`].
pub fn result_from_sweep(out: &SweepOutput) -> MethodResult {
    let mut notes = Vec::new();
    if out.index.is_none() {
        notes.push("no angle pair resolved the fringe shift: no index, no thickness".to_owned());
    }
    if out.model_mismatch {
        notes.push(format!(
            "model mismatch: the film model leaves residuals of {:.4} against a noise of {:.4}; the index is unreliable and every pixel is flagged",
            out.residual_sigma.unwrap_or(f64::NAN),
            out.noise_sigma.map_or(f64::NAN, f64::from)
        ));
    }
    let dead = out
        .results
        .iter()
        .filter(|r| r.flags & flags::DEAD != 0)
        .count();
    if dead * 2 > out.results.len() {
        notes.push(format!(
            "{dead} of {} pixels lack usable samples in over a tenth of their bands (NaN or infinite reflectance: a white reference at or below its dark, or bad values in a cube)",
            out.results.len()
        ));
    }
    MethodResult {
        method: Method::Filmscope,
        index: out.index.unwrap_or(IndexModel::constant(f64::NAN)),
        index_sigma: out.index.map(|_| out.index_sigma),
        thickness_nm: out.results.iter().map(|r| r.thickness_nm).collect(),
        confidence: out.results.iter().map(|r| r.confidence).collect(),
        thickness_sigma_nm: out.results.iter().map(|r| r.thickness_sigma_nm).collect(),
        flags: out.results.iter().map(|r| r.flags).collect(),
        notes,
    }
}

/// Runs `config.method` on `source`, whose lens's field of view is not known (so the
/// streaming method takes one incidence angle per frame); `on_rows` is told of rows
/// streamed.
pub fn run_method(
    source: &mut dyn Source,
    config: &RunConfig,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<Run, PipelineError> {
    run_method_in_field(source, config, None, on_rows)
}

/// Runs `config.method` on `source` seen through a lens of horizontal field of view
/// `field_of_view` (`None`: unknown); the streaming method chooses its field model
/// ([`crate::field`]) by `config.field`. `on_rows` is told of rows streamed.
pub fn run_method_in_field(
    source: &mut dyn Source,
    config: &RunConfig,
    field_of_view: Option<FieldOfView>,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<Run, PipelineError> {
    let spec = source.spec().clone();
    let angles_deg = source.angles_deg();
    let t0 = Instant::now();
    match config.method {
        Method::Filmscope => crate::field::run_filmscope(source, config, field_of_view, on_rows),
        Method::Paper | Method::Brute => {
            let cube = collect_sweep(source)?;
            on_rows((cube.height * cube.bands_nm.len() * cube.angles_deg.len()) as u64);
            let result = if config.method == Method::Paper {
                paper(&cube)
            } else {
                brute(&cube, config.brute_grid)
            };
            let samples =
                (cube.width * cube.height * cube.bands_nm.len() * cube.angles_deg.len()) as u64;
            Ok(Run {
                result,
                spec,
                angles_deg,
                seconds: t0.elapsed().as_secs_f64(),
                solve_latency_ms: None,
                state_bytes_per_pixel: None,
                samples,
                angle_reports: serde_json::Value::Null,
                model_choice: serde_json::Value::Null,
                field_model: None,
                field_model_choice: serde_json::Value::Null,
            })
        }
    }
}

/// Statistics of the finite values.
pub fn stats(values: &[f32]) -> serde_json::Value {
    let mut v: Vec<f64> = values
        .iter()
        .filter(|x| x.is_finite())
        .map(|&x| f64::from(x))
        .collect();
    if v.is_empty() {
        return json!({"mean": null, "median": null, "std": null, "min": null, "max": null});
    }
    v.sort_by(f64::total_cmp);
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
    let median = if v.len() % 2 == 1 {
        v[v.len() / 2]
    } else {
        0.5 * (v[v.len() / 2 - 1] + v[v.len() / 2])
    };
    json!({"mean": mean, "median": median, "std": var.sqrt(), "min": v[0], "max": v[v.len() - 1]})
}

/// The thickness uncertainty of the reported (valid) pixels: statistics, the 90th
/// percentile and the limit above which a pixel is flagged `imprecise`.
fn sigma_summary(r: &MethodResult) -> serde_json::Value {
    let mut valid: Vec<f32> = r
        .thickness_sigma_nm
        .iter()
        .zip(&r.thickness_nm)
        .filter(|(s, d)| s.is_finite() && d.is_finite())
        .map(|(&s, _)| s)
        .collect();
    let mut out = stats(&valid);
    valid.sort_by(f32::total_cmp);
    let p90 = valid
        .get((valid.len() * 9).div_ceil(10).saturating_sub(1))
        .copied();
    out["p90"] = json!(p90);
    out["imprecise_above"] = json!(MAX_THICKNESS_SIGMA_NM);
    out
}

/// Counts of each flag over the map.
pub fn flag_counts(map: &[u16]) -> serde_json::Value {
    let mut o = serde_json::Map::new();
    for (bit, name) in flags::NAMES {
        let n = map.iter().filter(|&&f| f & bit != 0).count();
        o.insert(name.to_owned(), json!(n));
    }
    serde_json::Value::Object(o)
}

/// An output that could not be written, naming the file.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct OutputError(pub String);

/// Writes the maps, the preview and `summary.json` as one unit into the folder `dir`
/// ([`crate::io::OutputDir`]: written beside it, then swapped in whole, one writer at a
/// time). Returns the summary.
pub fn write_outputs(
    dir: &Path,
    run: &Run,
    source_label: &str,
) -> Result<serde_json::Value, OutputError> {
    let out = crate::io::OutputDir::begin(dir).map_err(|e| OutputError(e.to_string()))?;
    let summary = write_outputs_into(out.path(), run, source_label)?;
    out.commit().map_err(|e| OutputError(e.to_string()))?;
    Ok(summary)
}

/// Writes the maps, the preview and `summary.json` into the existing folder `dir` (a
/// staging folder of [`crate::io::OutputDir`]). Returns the summary.
pub fn write_outputs_into(
    dir: &Path,
    run: &Run,
    source_label: &str,
) -> Result<serde_json::Value, OutputError> {
    let err = |p: &Path, e: &dyn std::fmt::Display| OutputError(format!("{}: {e}", p.display()));
    let (w, h) = (run.spec.width, run.spec.height);
    let r = &run.result;
    let thick = dir.join("thickness_nm.hdr");
    write_f32_map(
        &thick,
        w,
        h,
        &r.thickness_nm,
        Some("film thickness, nm (NaN: no reliable estimate)"),
        &[],
    )
    .map_err(|e| err(&thick, &e))?;
    let conf = dir.join("confidence.hdr");
    write_f32_map(
        &conf,
        w,
        h,
        &r.confidence,
        Some("confidence of the thickness, 0..1"),
        &[],
    )
    .map_err(|e| err(&conf, &e))?;
    let sigma = dir.join("thickness_sigma_nm.hdr");
    write_f32_map(
        &sigma,
        w,
        h,
        &r.thickness_sigma_nm,
        Some(&format!(
            "1-sigma thickness uncertainty from the pixel's own full-spectrum fit and the shared index's covariance, nm; given for flagged pixels too (above {MAX_THICKNESS_SIGMA_NM} nm: flag imprecise); NaN: no fit"
        )),
        &[],
    )
    .map_err(|e| err(&sigma, &e))?;
    let flags_path = dir.join("flags.hdr");
    let mut fh = EnviHeader::new(w, h, 1, DataType::U16, Interleave::Bsq);
    let names: Vec<String> = flags::NAMES
        .iter()
        .map(|(b, n)| format!("{b}={n}"))
        .collect();
    fh.description = Some(format!("filmscope pixel flags (bits): {}", names.join(" ")));
    let mut fw = EnviWriter::create(&flags_path, &fh).map_err(|e| err(&flags_path, &e))?;
    for row in 0..h {
        let vals: Vec<f32> = r.flags[row * w..(row + 1) * w]
            .iter()
            .map(|&f| f32::from(f))
            .collect();
        fw.write_band_row(0, row, &vals)
            .map_err(|e| err(&flags_path, &e))?;
    }
    fw.finish().map_err(|e| err(&flags_path, &e))?;
    let png = dir.join("thickness_nm.png");
    let title = format!(
        "thickness, n = {:.4} ({})",
        r.index.at(550.0),
        r.method.name()
    );
    write_map_png(
        &png,
        &MapPreview {
            width: w,
            height: h,
            values: &r.thickness_nm,
            title: &title,
            unit: "nm",
            range: None,
        },
    )
    .map_err(|e| err(&png, &e))?;
    let valid = r.thickness_nm.iter().filter(|x| x.is_finite()).count();
    let summary = json!({
        "refractive_index": r.index.at(550.0),
        "refractive_index_sigma": r.index_sigma,
        "dispersion": dispersion_json(&r.index.dispersion()),
        "index_model": (["constant", "cauchy", "cauchy3"])[r.index.terms() - 1],
        "index_model_choice": run.model_choice,
        "field_model": run.field_model.map(FieldModel::name),
        "field_model_choice": run.field_model_choice,
        "thickness_nm": stats(&r.thickness_nm),
        "thickness_sigma_nm": sigma_summary(r),
        "valid_fraction": valid as f64 / (w * h).max(1) as f64,
        "width": w,
        "height": h,
        "sample": {
            "ambient_index": run.spec.ambient_index,
            "substrate_index": run.spec.substrate_index,
            "polarization": run.spec.polarization.name(),
        },
        "method": r.method.name(),
        "source": source_label,
        "angles_deg": run.angles_deg,
        "bands": run.spec.bands_nm.len(),
        "flags": flag_counts(&r.flags),
        "angle_reports": run.angle_reports,
        "timing": {
            "seconds": run.seconds,
            "solve_latency_ms": run.solve_latency_ms,
            "samples": run.samples,
            "samples_per_s": run.samples as f64 / run.seconds.max(1e-9),
        },
        "state_bytes_per_pixel": run.state_bytes_per_pixel,
        "notes": r.notes,
        "files": {
            "thickness": "thickness_nm.hdr",
            "confidence": "confidence.hdr",
            "thickness_sigma": "thickness_sigma_nm.hdr",
            "flags": "flags.hdr",
            "preview": "thickness_nm.png",
        },
    });
    let path = dir.join("summary.json");
    let text = serde_json::to_string_pretty(&summary).map_err(|e| err(&path, &e))?;
    write_atomic(&path, text.as_bytes()).map_err(|e| err(&path, &e))?;
    Ok(summary)
}
