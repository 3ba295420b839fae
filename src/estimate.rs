//! Running a method on a source and writing its outputs per capture-format.md.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use filmscope_core::solve::sample::SampleFit;
use filmscope_core::solve::shard::MAX_THICKNESS_SIGMA_NM;
use filmscope_core::solve::{flags, IndexModel, SweepSpec};
use serde_json::json;

use crate::baseline::{brute, paper, BruteGrid};
use crate::export::png::{write_map_png, MapPreview};
use crate::field::{FieldConfig, FieldModel};
use crate::index_fit::{
    choice_json, fringes_across_band, index_model, PixelTap, SampleTap, Tap, SEEDED_BELOW_FRINGES,
};
use crate::io::{write_atomic, write_f32_map, DataType, EnviHeader, EnviWriter, Interleave};
use crate::pipeline::{
    collect_sweep, for_each_calibrated_rows, run_sweep, run_sweep_sampled, Calibrated,
    PipelineConfig, PipelineError, Prior, PriorUpdate, SampleHook, Source, SweepOutput,
};
use filmscope_core::optics::FieldOfView;

use crate::sweep::{Method, MethodResult};

/// A sampled site whose per-pixel thickness is this far from the sample fit's disagrees
/// (the 20 nm at which a thickness counts as wrong).
pub const SITE_AGREEMENT_NM: f32 = 20.0;

/// Share of disagreeing sites above which the per-pixel pass is not trusted.
pub const MAX_DISAGREEING_SITES: f64 = 0.1;

/// What the estimator's passes over one sweep ended with.
pub struct Passes {
    /// The per-pixel pass.
    pub out: SweepOutput,
    /// Passes over the data: the sample's stream and the per-pixel pass (one for a live
    /// source, which holds the sample as it streams).
    pub passes: usize,
    /// The index fit on the sample's full spectra (`None`: a live source's one pass).
    pub fit: Option<SampleFit>,
    /// How the index model was chosen, as JSON (`summary.json` `index_model_choice`).
    pub choice: serde_json::Value,
}

/// The streaming estimator over `source` with one incidence angle per frame: the sampled
/// sites' full spectra give the shared index ([`crate::index_fit`]), and one streaming pass
/// holding that index gives every pixel its order and thickness. A replayable source streams
/// twice (the sample's rows, then every pixel); a live one once, the sample held as it
/// streams and the index refitted as each angle completes. `on_rows` is told of the rows of
/// the stream of every pixel.
pub fn filmscope_passes(
    source: &mut dyn Source,
    config: &RunConfig,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<Passes, PipelineError> {
    let spec = source.spec().clone();
    let mut tap = SampleTap::new(&spec, config.sample_sites, source.angles_deg().len());
    if config.one_pass || !source.replayable() {
        // A live camera streams once: the sample is held as it streams and refitted as each
        // angle completes (from the second on), warm-started from the last fit.
        let tap = std::sync::Mutex::new(tap);
        let mut last: Option<SampleFit> = None;
        let mut fit_seconds = f64::NAN;
        let total = source.angles_deg().len();
        let mut refit = |t: &SampleTap| -> Option<IndexModel> {
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
        choice["fit_seconds"] = json!(fit_seconds.is_finite().then_some(fit_seconds));
        let out = flag_if_disagreeing(&tap, &fit, out, &mut choice)?;
        return Ok(Passes {
            out,
            passes: 1,
            fit: Some(fit),
            choice,
        });
    }
    fill(source, &mut tap)?;
    let began = Instant::now();
    let fit = tap.fit(&spec, None, true);
    let fit_seconds = began.elapsed().as_secs_f64();
    let index = index_model(&fit);
    let seed = if fringes_across_band(&spec, &fit) < SEEDED_BELOW_FRINGES {
        tap.seed_map(&fit, spec.width, spec.height).map(Arc::new)
    } else {
        None
    };
    let seeded = seed.is_some();
    let prior = index.map(|i| Prior::new(i, PriorUpdate::Hold, seed));
    let mut out = run_sweep(source, config.pipeline, prior, on_rows)?;
    let mut passes = 2;
    // The per-pixel pass must agree with the sample's own thicknesses; where it does not
    // (orders from extrema gone wrong, or left unsolved), every pixel starts from the
    // sample's map instead.
    if let (Some(i), false) = (index, seeded) {
        if sites_disagree(&tap, &fit, &out, true) > MAX_DISAGREEING_SITES {
            if let Some(map) = tap.seed_map(&fit, spec.width, spec.height) {
                let prior = Prior::new(i, PriorUpdate::Hold, Some(Arc::new(map)));
                out = run_sweep(source, config.pipeline, Some(prior), &|_| {})?;
                passes += 1;
            }
        }
    }
    let repaired = repair(source, &spec, &fit, &mut out)?;
    if repaired.is_some() {
        passes += 1;
    }
    let (out, fit, mut choice) = finish(out, fit, &tap, passes);
    choice["fit_seconds"] = json!(fit_seconds);
    choice["pixels_searched"] = json!(repaired.map(|r| r.0));
    choice["pixels_solved_by_search"] = json!(repaired.map(|r| r.1));
    flag_if_disagreeing(&tap, &fit, out, &mut choice).map(|out| Passes {
        out,
        passes,
        fit: Some(fit),
        choice,
    })
}

/// Refuses a capture whose run with `method` would need more memory than `budget` (or, with
/// none, than the machine has available), before any work: one line naming the capture.
pub fn check_capture_memory(
    cap: &crate::io::Capture,
    method: Method,
    budget: Option<u64>,
) -> Result<(), String> {
    let info = cap.check().map_err(|e| e.to_string())?;
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
    )
}

/// Streams the image rows `tap` reads from `source` once into it.
fn fill(source: &mut dyn Source, tap: &mut dyn Tap) -> Result<(), PipelineError> {
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
    let seats = tap.seat(spec, best.kind, best.params, fit.noise_sigma);
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
    choice: &mut serde_json::Value,
) -> Result<SweepOutput, PipelineError> {
    let share = sites_disagree(tap, fit, &out, false);
    choice["sites_disagreeing"] = json!(share);
    if share > MAX_DISAGREEING_SITES {
        for r in &mut out.results {
            r.flags |= flags::ORDER_REJECTED;
            r.thickness_nm = f32::NAN;
            r.confidence = 0.0;
        }
        choice["per_pixel_failure"] = json!(format!(
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
) -> (SweepOutput, SampleFit, serde_json::Value) {
    let choice = choice_json(&fit, tap, passes);
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
    }
    (out, fit, choice)
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
    /// Sites whose full spectra give the shared index ([`crate::index_fit`]).
    pub sample_sites: usize,
    /// Stream once, as from a live camera, even when the source could be replayed (the
    /// index refitted on the sample as each angle completes).
    pub one_pass: bool,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            method: Method::Filmscope,
            pipeline: PipelineConfig::default(),
            brute_grid: BruteGrid::default(),
            field: FieldConfig::default(),
            sample_sites: crate::index_fit::DEFAULT_SITES,
            one_pass: false,
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
        "dispersion": crate::index_fit::dispersion_json(r.index.dispersion(), &run.spec.bands_nm),
        "index_model": index_model_name(&r.index),
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
    let mut summary = summary;
    if !run.spec.substrate.is_constant() {
        summary["sample"]["substrate"] = crate::material::dispersion_to_json(&run.spec.substrate);
    }
    let comment = format!("{} estimate of {source_label}", r.method.name());
    if crate::material::write_index_files(dir, &r.index.dispersion(), &run.spec.bands_nm, &comment)
        .map_err(OutputError)?
    {
        summary["files"]["index_csv"] = json!(crate::material::INDEX_FILES[0]);
        summary["files"]["index_yml"] = json!(crate::material::INDEX_FILES[1]);
    }
    let path = dir.join("summary.json");
    let text = serde_json::to_string_pretty(&summary).map_err(|e| err(&path, &e))?;
    write_atomic(&path, text.as_bytes()).map_err(|e| err(&path, &e))?;
    Ok(summary)
}
