//! The estimator with the film's index known beforehand (`estimate --film-index`): a
//! library material, a refractiveindex.info YAML file or a number, held for one streaming
//! pass that gives every pixel its order and thickness; no index is fitted.
//!
//! The estimator's index model holds a constant, a Cauchy of up to three terms or a
//! one-pole Sellmeier; a material given in another form (a Sellmeier of two or three
//! terms) is held as the three-term Cauchy fitted to it over the capture's bands by least
//! squares, and `summary.json` reports that model.

use std::time::Instant;

use filmscope_core::optics::Dispersion;
use filmscope_core::solve::IndexModel;
use serde_json::json;

use crate::estimate::passes::{angle_reports, result_from_sweep};
use crate::estimate::run::{Run, RunConfig};
use crate::pipeline::{run_sweep, PipelineError, Prior, PriorUpdate};
use crate::source::Source;

/// The index model that holds `film` over `bands_nm`: itself when the model can hold it,
/// else its least-squares three-term Cauchy over the bands.
pub fn index_model_of(film: &Dispersion, bands_nm: &[f64]) -> Result<IndexModel, String> {
    if let Some(m) = IndexModel::from_dispersion(*film) {
        return Ok(m);
    }
    let rows: Vec<(f64, f64)> = bands_nm
        .iter()
        .map(|&l| (l * 1e-3, film.index_at(l)))
        .collect();
    let fitted = crate::material::cauchy_fit(&rows)?;
    IndexModel::from_dispersion(fitted).ok_or_else(|| "no index model holds the fit".into())
}

/// Runs the streaming estimator on `source` with the film's index held at `film` (named
/// `name` in `summary.json`'s `index_model_choice`); one pass over the data.
pub fn run_with_index(
    source: &mut dyn Source,
    config: &RunConfig,
    film: &Dispersion,
    name: &str,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<Run, PipelineError> {
    let spec = source.spec().clone();
    let angles_deg = source.angles_deg();
    let t0 = Instant::now();
    let index = index_model_of(film, &spec.bands_nm).map_err(PipelineError)?;
    let out = run_sweep(
        source,
        config.pipeline,
        Some(Prior::new(index, PriorUpdate::Hold, None)),
        on_rows,
    )?;
    let samples = (spec.width * spec.height * spec.bands_nm.len() * angles_deg.len()) as u64;
    let max_err = spec
        .bands_nm
        .iter()
        .map(|&l| (index.at(l) - film.index_at(l)).abs())
        .fold(0.0, f64::max);
    let mut result = result_from_sweep(&out);
    result.index = index;
    result.index_sigma = None;
    Ok(Run {
        result,
        spec,
        angles_deg,
        seconds: t0.elapsed().as_secs_f64(),
        solve_latency_ms: Some(out.solve_latency.as_secs_f64() * 1e3),
        state_bytes_per_pixel: Some(out.state_bytes_per_pixel),
        samples,
        angle_reports: angle_reports(&out),
        model_choice: json!({
            "given": name,
            "reason": "the film's index was given (--film-index): held, not fitted",
            "largest_difference_from_given": max_err,
        }),
        field_model: None,
        field_model_choice: None,
    })
}
