//! filmscope's passes over a source: the pixel sample's index fit, the per-pixel pass
//! under it, the check of the one against the other and the thickness search for the
//! pixels left unsolved.

use std::sync::Arc;
use std::time::Instant;

use filmscope_core::optics::BackFace;
use filmscope_core::solve::refine::FilmTerms;
use filmscope_core::solve::sample::{Failure, SampleFit};
use filmscope_core::solve::shard::MAX_THICKNESS_SIGMA_NM;
use filmscope_core::solve::{flags, IndexModel, SweepSpec};

use crate::estimate::index_fit::{
    choice, fringes_across_band, index_model, PixelTap, SampleTap, SEEDED_BELOW_FRINGES,
};
use crate::pipeline::{
    for_each_calibrated_rows, run_sweep, run_sweep_sampled, Calibrated, Correction, PipelineError,
    Prior, PriorUpdate, SampleHook, SweepOutput, Tap,
};
use crate::record::finite;
use crate::record::index_choice::FittedChoice;
use crate::source::Source;

use crate::estimate::method::{Method, MethodResult};
use crate::summary::AngleReport;

use super::run::RunConfig;

/// A sampled site whose per-pixel thickness is this far from the sample fit's disagrees
/// (the 20 nm at which a thickness counts as wrong).
pub const SITE_AGREEMENT_NM: f32 = 20.0;

/// Share of disagreeing sites above which the per-pixel pass is not trusted.
pub const MAX_DISAGREEING_SITES: f64 = 0.1;

/// Share of pixels flagged imprecise above which the per-pixel pass runs again from the
/// sample's map.
const MAX_IMPRECISE_SHARE: f64 = 0.1;

/// What the estimator's passes over one sweep ended with.
pub struct Passes {
    /// The per-pixel pass.
    pub out: SweepOutput,
    /// Passes over the data: the sample's stream and the per-pixel pass (one for a live
    /// source, which holds the sample as it streams).
    pub passes: usize,
    /// The index fit on the sample's full spectra (`None`: a live source's one pass).
    pub fit: Option<SampleFit>,
    /// How the index model was chosen (`summary.json` `index_model_choice`).
    pub choice: FittedChoice,
    /// What the sample's evidence says beyond the fit (a refused fit's likely cause).
    pub notes: Vec<String>,
}

/// The streaming estimator over `source` with one incidence angle per frame: the sampled
/// sites' full spectra give the shared index ([`crate::estimate::index_fit`]), and one streaming pass
/// holding that index gives every pixel its order and thickness. A replayable source streams
/// twice (the sample's rows, then every pixel); a live one once, the sample held as it
/// streams and the index refitted as each angle completes. `on_rows` is told of the rows of
/// the stream of every pixel.
pub fn filmscope_passes(
    source: &mut dyn Source,
    config: &RunConfig,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<Passes, PipelineError> {
    let spec = config.fitted_spec(source.spec());
    let mut tap = SampleTap::new(&spec, config.sample_sites, source.angles_deg().len());
    if config.one_pass || !source.replayable() {
        // A live camera streams once: the sample is held as it streams and refitted as each
        // angle completes (from the second on), warm-started from the last fit.
        let tap = std::sync::Mutex::new(tap);
        let mut last: Option<SampleFit> = None;
        let mut fit_seconds = f64::NAN;
        let total = source.angles_deg().len();
        let mut refit = |complete: usize| -> Option<IndexModel> {
            let t = tap
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .complete(complete);
            if t.angles() < 2 {
                return None;
            }
            // The last angle's refit stands between the last row and the maps: it refines
            // the model chosen so far rather than choosing again.
            let began = Instant::now();
            let fit = t.fit(&spec, last.as_ref(), t.angles() < total);
            fit_seconds = began.elapsed().as_secs_f64();
            let m = index_model(&fit);
            last = Some(fit);
            m
        };
        let hook = SampleHook {
            tap: &tap,
            refit: &mut refit,
        };
        let out = run_sweep_sampled(source, config.pipeline, hook, on_rows)?;
        let tap = tap.into_inner().unwrap_or_else(|e| e.into_inner());
        let fit = last.unwrap_or_else(|| tap.fit(&spec, None, true));
        let (out, fit, mut choice) = finish(out, fit, &tap, 1);
        choice.fit_seconds = finite(fit_seconds);
        let out = flag_if_disagreeing(&tap, &fit, out, &mut choice)?;
        return Ok(Passes {
            out,
            passes: 1,
            fit: Some(fit),
            choice,
            notes: Vec::new(),
        });
    }
    fill(source, &mut tap)?;
    let began = Instant::now();
    let fit = tap.fit(&spec, None, true);
    let fit_seconds = began.elapsed().as_secs_f64();
    let hint = back_face_evidence(&tap, &spec, &fit);
    let mut passes = passes_under(source, config, &tap, fit, fit_seconds, on_rows)?;
    passes.notes.extend(hint);
    Ok(passes)
}

/// When the sample's fit found no model (`NoFit`), the same fit with the substrate's back
/// face the other way (`bare` for `none`, `none` for `bare`): when that passes, the note
/// names the back face as the cause. The capture stays refused (its declared physics is the
/// user's to correct): a fit that passes only under another assumption is evidence, not a
/// measurement.
fn back_face_evidence(tap: &SampleTap, spec: &SweepSpec, fit: &SampleFit) -> Option<String> {
    if fit.failure != Some(Failure::NoFit) {
        return None;
    }
    let (other, fix) = match spec.back_face {
        BackFace::None => (
            BackFace::Bare,
            "if the substrate is clear and unbacked, declare sample.back_face = \"bare\"",
        ),
        BackFace::Bare => (
            BackFace::None,
            "if the back is blackened or index-matched, declare sample.back_face = \"none\"",
        ),
    };
    let alt = tap.fit(&spec.clone().with_back_face(other), None, true);
    let c = alt.best.filter(|_| alt.failure.is_none())?;
    Some(format!(
        "with the back face {} the sampled spectra fit (n(550) {:.4}, {}): {fix}",
        other.name(),
        c.kind.dispersion(&c.params).index_at(550.0),
        crate::estimate::index_fit::residual_shape(&alt.residual)
    ))
}

/// The passes of a replayable source after the sample's fit `fit` (of `tap`, taking
/// `fit_seconds`), which gives the index (fitted, or held as given): one streaming pass
/// holding it, every pixel starting from the sample's map when the film has no fringe pair;
/// again from that map where its sites disagree with the sample; the search for the pixels
/// left unsolved; every pixel flagged if the sites still disagree.
pub fn passes_under(
    source: &mut dyn Source,
    config: &RunConfig,
    tap: &SampleTap,
    fit: SampleFit,
    fit_seconds: f64,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<Passes, PipelineError> {
    let spec = source.spec().clone();
    let index = index_model(&fit);
    // One angle has no second angle to take fringe orders from: every pixel starts from the
    // sample's map, as a film without fringe pairs does.
    let one_angle = source.angles_deg().len() < 2;
    let seed = if one_angle || fringes_across_band(&spec, &fit) < SEEDED_BELOW_FRINGES {
        tap.seed_map(&fit, spec.width, spec.height).map(Arc::new)
    } else {
        None
    };
    let seeded = seed.is_some();
    let correction = correction_of(&fit);
    let prior = index.map(|i| {
        Prior::new(i, PriorUpdate::Hold, seed)
            .with_noise(fit.noise_sigma)
            .with_correction(correction.clone())
    });
    let mut out = run_sweep(source, config.pipeline, prior, on_rows)?;
    let mut passes = 2;
    // The per-pixel pass must agree with the sample's own thicknesses; where it does not
    // (orders from extrema gone wrong, or left unsolved), every pixel starts from the
    // sample's map instead. So too where many pixels came out imprecise: orders the
    // extrema settle only at the last angle leave sums of that angle's samples alone (an
    // angle near Brewster's for p light pins little); from the map every angle adds.
    if let (Some(i), false) = (index, seeded) {
        if sites_disagree(tap, &fit, &out, true) > MAX_DISAGREEING_SITES
            || imprecise_share(&out, &fit) > MAX_IMPRECISE_SHARE
        {
            if let Some(map) = tap.seed_map(&fit, spec.width, spec.height) {
                let prior = Prior::new(i, PriorUpdate::Hold, Some(Arc::new(map)))
                    .with_noise(fit.noise_sigma)
                    .with_correction(correction);
                out = run_sweep(source, config.pipeline, Some(prior), &|_| {})?;
                passes += 1;
            }
        }
    }
    let repaired = repair(source, &spec, &fit, &mut out)?;
    if repaired.is_some() {
        passes += 1;
    }
    let (out, fit, mut choice) = finish(out, fit, tap, passes);
    choice.fit_seconds = finite(fit_seconds);
    choice.pixels_searched = Some(repaired.map(|r| r.0));
    choice.pixels_solved_by_search = Some(repaired.map(|r| r.1));
    flag_if_disagreeing(tap, &fit, out, &mut choice).map(|out| Passes {
        out,
        passes,
        fit: Some(fit),
        choice,
        notes: Vec::new(),
    })
}

/// Refuses a capture whose run with `method` would need more memory than `budget` (or, with
/// none, than the machine has available), before any work: one line naming the capture.
pub fn check_capture_memory(
    cap: &crate::io::Capture,
    method: Method,
    budget: Option<u64>,
) -> Result<(), crate::source::SourceError> {
    let info = cap.check()?;
    crate::limits::check_memory(
        &format!(
            "{}: {} x {} px, {} bands, {} angles",
            cap.path.display(),
            info.samples,
            info.lines,
            info.bands,
            cap.angles.len()
        ),
        crate::limits::run_bytes(
            (info.samples as u64).saturating_mul(info.lines as u64),
            info.bands as u64,
            cap.angles.len() as u64,
            method != Method::Filmscope,
        ),
        budget,
    )?;
    Ok(())
}

/// Streams the image rows `tap` reads from `source` once into it.
pub fn fill(source: &mut dyn Source, tap: &mut dyn Tap) -> Result<(), PipelineError> {
    let rows = tap.image_rows();
    for_each_calibrated_rows(source, Some(&rows), |event| match event {
        Calibrated::Angle(deg) => tap.angle(deg),
        Calibrated::Rows {
            band,
            first_row,
            rows,
            values,
            ..
        } => {
            tap.rows(band, first_row, rows, values);
        }
    })
}

/// Flags of an unsolved pixel whose spectra may still give its thickness (not dead,
/// saturated, out of range or under a failed model).
const SEARCHABLE: u16 = flags::NO_FRINGE
    | flags::AMBIGUOUS_ORDER
    | flags::POOR_FIT
    | flags::ORDER_REJECTED
    | flags::IMPRECISE;

/// How much worse, in chi-square noise units, a searched pixel's best thickness in another
/// order's basin must fit for its own to be reported (as the streaming pass's order check).
pub const SEARCH_MARGIN_CHI2: f64 = 16.0;

/// Reduced chi-square (over the sample fit's own, when that is above 1) above which a
/// searched pixel's thickness is not reported.
pub const SEARCH_CHI2_NU: f64 = 2.0;

/// Pixels the per-pixel pass left unsolved, though their spectra may tell (flags only among
/// [`SEARCHABLE`]), each solved from its full spectra by the sample fit's thickness search
/// under the fitted index, on one more stream of the capture: a thick film's pixels whose
/// extrema overflow or leave the order open, those by a step the sample's map does not
/// see. A pixel is reported only when its fit is as good as the sample's and no other
/// order's comes near. Returns the pixels searched and those solved, or `None` when none
/// was searched.
fn repair(
    source: &mut dyn Source,
    spec: &SweepSpec,
    fit: &SampleFit,
    out: &mut SweepOutput,
) -> Result<Option<(usize, usize)>, PipelineError> {
    let Some(best) = fit.best.filter(|_| fit.failure.is_none()) else {
        return Ok(None);
    };
    let w = out.spec.width;
    let pixels: Vec<(u32, u32)> = out
        .results
        .iter()
        .enumerate()
        .filter(|(_, r)| {
            r.flags & flags::INVALID != 0 && r.flags & flags::INVALID & !SEARCHABLE == 0
        })
        .map(|(i, _)| ((i / w) as u32, (i % w) as u32))
        .collect();
    if pixels.is_empty() || !fit.noise_sigma.is_finite() {
        return Ok(None);
    }
    let mut tap = PixelTap::new(spec, &pixels, source.angles_deg().len());
    fill(source, &mut tap)?;
    let seats = tap.seat(
        spec,
        best.kind,
        best.params,
        fit.noise_sigma,
        fit.model_error,
        &fit.nuisance(),
    );
    let [d_lo, d_hi] = spec.thickness_range_nm;
    let chi2_limit = SEARCH_CHI2_NU * best.chi2_nu.max(1.0);
    let mut solved = 0;
    for (&(r, c), s) in tap.pixels().iter().zip(&seats) {
        let ok = (d_lo..=d_hi).contains(&s.thickness_nm)
            && s.chi2_nu <= chi2_limit
            && s.margin_chi2 >= SEARCH_MARGIN_CHI2
            && s.sigma_nm <= MAX_THICKNESS_SIGMA_NM;
        if !ok {
            continue;
        }
        let p = &mut out.results[r as usize * w + c as usize];
        p.flags = (p.flags & !flags::INVALID) | flags::FROM_SPECTRUM_SEARCH;
        p.thickness_nm = s.thickness_nm as f32;
        p.thickness_sigma_nm = s.sigma_nm as f32;
        p.confidence = (s.margin_chi2 / (s.margin_chi2 + 4.0 * SEARCH_MARGIN_CHI2)) as f32;
        solved += 1;
    }
    Ok(Some((tap.pixels().len(), solved)))
}

/// Share of the pixels imprecise, flagged so or to be once the sample fit's share is added
/// ([`with_sample_share`]).
fn imprecise_share(out: &SweepOutput, fit: &SampleFit) -> f64 {
    let own = fit.residual.correlation_factor();
    let n = out
        .results
        .iter()
        .filter(|r| {
            r.flags & flags::IMPRECISE != 0
                || f64::from(r.thickness_sigma_nm) * own > MAX_THICKNESS_SIGMA_NM
        })
        .count();
    n as f64 / out.results.len().max(1) as f64
}

/// Share of the sampled sites, among those the sample fit solves, whose thickness in the
/// per-pixel pass is more than [`SITE_AGREEMENT_NM`] from the sample fit's own (or, with
/// `unsolved`, missing there).
fn sites_disagree(tap: &SampleTap, fit: &SampleFit, out: &SweepOutput, unsolved: bool) -> f64 {
    let w = out.spec.width;
    let (mut compared, mut off) = (0usize, 0usize);
    for (k, (r, c)) in tap.centres().enumerate() {
        let i = r * w + c;
        let (Some(p), Some(&t)) = (out.results.get(i), fit.thickness_nm.get(k)) else {
            continue;
        };
        if t.is_finite() && (unsolved || p.thickness_nm.is_finite()) {
            compared += 1;
            if !(p.thickness_nm - t).abs().le(&SITE_AGREEMENT_NM) {
                off += 1;
            }
        }
    }
    if compared == 0 {
        0.0
    } else {
        off as f64 / compared as f64
    }
}

/// A per-pixel pass that still disagrees with the sample is not reported: every pixel NaN,
/// flagged `order_rejected`, with the figure in `index_model_choice`.
fn flag_if_disagreeing(
    tap: &SampleTap,
    fit: &SampleFit,
    mut out: SweepOutput,
    choice: &mut FittedChoice,
) -> Result<SweepOutput, PipelineError> {
    let share = sites_disagree(tap, fit, &out, false);
    choice.sites_disagreeing = share;
    if share > MAX_DISAGREEING_SITES {
        for r in &mut out.results {
            r.flags |= flags::ORDER_REJECTED;
            r.thickness_nm = f32::NAN;
            r.confidence = 0.0;
        }
        choice.per_pixel_failure = Some(format!(
            "{:.0} % of the sampled sites' per-pixel thicknesses are more than {SITE_AGREEMENT_NM} nm from the sample fit's: every pixel flagged",
            share * 100.0
        ));
    }
    Ok(out)
}

/// The per-pixel pass's output under the sample's fit: a failed fit leaves no index and
/// every pixel flagged, never a confident wrong number.
fn finish(
    mut out: SweepOutput,
    fit: SampleFit,
    tap: &SampleTap,
    passes: usize,
) -> (SweepOutput, SampleFit, FittedChoice) {
    let choice = choice(&fit, tap, passes);
    if fit.index().is_none() {
        out.index = None;
        out.model_mismatch = true;
        for r in &mut out.results {
            r.flags |= flags::MODEL_MISMATCH;
            r.thickness_nm = f32::NAN;
            r.confidence = 0.0;
        }
    } else if let Some(c) = fit.best {
        out.index_sigma = c.n550_sigma;
        with_sample_share(&mut out, &fit, c.kind.dispersion(&c.params).index_at(550.0));
    }
    (out, fit, choice)
}

/// Each solved pixel's thickness sigma with the sample fit's share added: the share common
/// to the map in proportion to the thickness ([`SampleFit::thickness_share`]: the index and
/// every nuisance term within the rig's tolerance; where not computed, the index's standard
/// error alone, carried by the fringes' optical path `d sqrt(n^2 - sin^2 theta)`, so
/// `dd/dn = -d n / (n^2 - sin^2 theta)` over the angles' mean `sin^2 theta`) and the
/// pixel's own share widened by the sample's misfit beyond the noise, correlated along the
/// band (`Residual::correlation_factor`). A pixel whose own share exceeds
/// [`MAX_THICKNESS_SIGMA_NM`] is flagged `imprecise`.
fn with_sample_share(out: &mut SweepOutput, fit: &SampleFit, n550: f64) {
    let angles = &out.angles;
    let sin2 = if angles.is_empty() {
        0.0
    } else {
        angles
            .iter()
            .map(|a| (out.spec.ambient_index * a.incidence_deg.to_radians().sin()).powi(2))
            .sum::<f64>()
            / angles.len() as f64
    };
    let slope = n550 / (n550 * n550 - sin2).max(1e-6);
    let own = fit.residual.correlation_factor();
    let common = if fit.thickness_share.is_finite() {
        fit.thickness_share
    } else {
        slope * fit.best.map_or(0.0, |c| c.n550_sigma)
    };
    for r in &mut out.results {
        let d = f64::from(r.thickness_nm);
        let s = f64::from(r.thickness_sigma_nm);
        if !(d.is_finite() && s.is_finite()) {
            continue;
        }
        let sigma = (s * own).hypot(d * common);
        r.thickness_sigma_nm = sigma as f32;
        // The common share is the whole map's (its scale, reported with the index): a pixel
        // is imprecise by its own share.
        if s * own > MAX_THICKNESS_SIGMA_NM {
            r.flags |= flags::IMPRECISE;
            r.thickness_nm = f32::NAN;
            r.confidence = 0.0;
        }
    }
}

/// What the sample fit found every pixel's data off by (its stage offset, wavelength shift,
/// flare and each angle's reflectance scale and offset), for the per-pixel passes to take
/// out, and the film's absorption and the polariser's leak, for their model to carry.
fn correction_of(fit: &SampleFit) -> Correction {
    Correction {
        angle_offset_deg: fit.stage_offset_deg.value,
        band_shift_nm: fit.wavelength_shift_nm.value,
        terms: fit
            .reflectance_terms
            .iter()
            .map(|&(s, o)| (s as f32, o as f32))
            .collect(),
        flare: fit.flare.value as f32,
        film: FilmTerms {
            film_k: fit.film_k.value,
            leak: fit.polariser_leak.value,
        },
    }
}

/// The per-angle progress of a pass (`summary.json` `angle_reports`).
pub fn angle_reports(out: &SweepOutput) -> Vec<AngleReport> {
    let finite = |x: f64| x.is_finite().then_some(x);
    out.angles
        .iter()
        .map(|a| AngleReport {
            incidence_deg: a.incidence_deg,
            index: a.index,
            index_sigma: finite(a.index_sigma),
            pair_index: a.pair.map(|p| p.index),
            refined: a.refined,
            spectral_index_step: finite(a.spectral_index_step),
            dispersive: a.index_terms > 1,
            index_terms: a.index_terms,
            index_from_full_spectra: a.spectral_index,
        })
        .collect()
}

/// The name of an index model, as `summary.json` `index_model` gives it.
pub fn index_model_name(m: &IndexModel) -> &'static str {
    match (m.pole, m.terms()) {
        (Some(p), _) if p.a == 1.0 => "sellmeier",
        (Some(_), _) => "sellmeier_constant",
        (None, 1) => "constant",
        (None, 2) => "cauchy",
        _ => "cauchy3",
    }
}

/// The streaming estimator's output as a [`MethodResult`].
pub fn result_from_sweep(out: &SweepOutput) -> MethodResult {
    let mut notes = Vec::new();
    if out.index.is_none() {
        notes.push("no index: every pixel is NaN".to_owned());
    }
    if out.model_mismatch && out.index.is_some() {
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
