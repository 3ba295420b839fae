//! The estimator with the film's index known beforehand (`estimate --film-index`): a
//! library material, a refractiveindex.info YAML file or a number, held through the
//! estimator's passes; no index is fitted.
//!
//! The estimator's index model holds a constant, a Cauchy of up to three terms or a
//! one-pole Sellmeier; a material given in another form (a Sellmeier of two or three
//! terms) is held as the three-term Cauchy fitted to it over the capture's bands by least
//! squares, and `summary.json` reports that model. A material that absorbs over the band
//! is measured by [`crate::estimate::absorbing`] with its n and k as given.

use std::time::Instant;

use filmscope_core::optics::Dispersion;
use filmscope_core::solve::sample::ModelKind;
use filmscope_core::solve::IndexModel;

use crate::estimate::index_fit::SampleTap;
use crate::estimate::passes::{angle_reports, fill, passes_under, result_from_sweep};
use crate::estimate::run::{Run, RunConfig};
use crate::pipeline::{run_sweep, PipelineError, Prior, PriorUpdate};
use crate::record::finite;
use crate::record::index_choice::{GivenChoice, HeldEvidence, IndexModelChoice};
use crate::source::Source;

/// The index model that holds `film`'s real index over `bands_nm`: itself when the model
/// can hold it, else its least-squares three-term Cauchy over the bands.
pub fn held_index(
    film: &Dispersion,
    bands_nm: &[f64],
) -> Result<IndexModel, crate::material::MaterialError> {
    if let Some(m) = IndexModel::from_dispersion(*film) {
        return Ok(m);
    }
    let rows: Vec<(f64, f64)> = bands_nm
        .iter()
        .map(|&l| (l * 1e-3, film.index_at(l)))
        .collect();
    let fitted = crate::material::cauchy_fit(&rows)?;
    IndexModel::from_dispersion(fitted).ok_or_else(|| {
        crate::material::MaterialError::Entry("no index model holds its Cauchy fit".into())
    })
}

/// Runs the streaming estimator on `source` with the film's index held at `film` (named
/// `name` in `summary.json`'s `index_model_choice`). A replayable source takes the fitted
/// index's passes ([`passes_under`]) with the sample's sites seated under the given index
/// ([`SampleTap::hold`]): a film without a fringe pair starts every pixel from their map, and
/// they check the per-pixel pass and search the pixels it leaves unsolved. A live source, or
/// a sample too small to seat, streams once.
pub fn run_with_index(
    source: &mut dyn Source,
    config: &RunConfig,
    film: &Dispersion,
    name: &str,
    on_rows: &(dyn Fn(u64) + Sync),
) -> Result<Run, PipelineError> {
    let spec = config.fitted_spec(source.spec());
    let angles_deg = source.angles_deg();
    let index =
        held_index(film, &spec.bands_nm).map_err(|e| PipelineError::Setup(e.to_string()))?;
    if crate::estimate::absorbing::absorbs(film, &spec.bands_nm) {
        return crate::estimate::absorbing::run_absorbing(source, config, film, index, name);
    }
    let t0 = Instant::now();
    let mut sample = None;
    if source.replayable() && !config.one_pass {
        let mut tap = SampleTap::new(&spec, config.sample_sites, angles_deg.len());
        fill(source, &mut tap)?;
        let began = Instant::now();
        let (kind, params) = ModelKind::of_index(&index);
        let fit = tap.hold(&spec, kind, params);
        if fit.best.is_some() {
            let fit_seconds = began.elapsed().as_secs_f64();
            sample = Some(passes_under(
                source,
                config,
                &tap,
                fit,
                fit_seconds,
                on_rows,
            )?);
        }
    }
    let out = match &sample {
        Some(p) => &p.out,
        None => &run_sweep(
            source,
            config.pipeline,
            Some(Prior::new(index, PriorUpdate::Hold, None)),
            on_rows,
        )?,
    };
    let samples = (spec.width * spec.height * spec.bands_nm.len() * angles_deg.len()) as u64;
    let max_err = spec
        .bands_nm
        .iter()
        .map(|&l| (index.at(l) - film.index_at(l)).abs())
        .fold(0.0, f64::max);
    let mut result = result_from_sweep(out);
    result.index = index;
    result.index_sigma = None;
    if let Some(why) = sample.as_ref().and_then(|p| p.fit.as_ref()?.failure) {
        // `result_from_sweep` notes no index: there is one, it does not fit.
        result.notes = vec![format!("{}: every pixel is NaN", why.message())];
    }
    // The sample's evidence under the given index: how well it fits, and the checks.
    let model_choice = IndexModelChoice::Given(GivenChoice {
        given: name.to_owned(),
        reason: "the film's index was given (--film-index): held, not fitted".to_owned(),
        largest_difference_from_given: finite(max_err),
        passes: sample.as_ref().map_or(1, |p| p.passes),
        sample: sample.as_ref().map(|p| HeldEvidence::of(&p.choice)),
    });
    Ok(Run {
        result,
        spec,
        angles_deg,
        seconds: t0.elapsed().as_secs_f64(),
        solve_latency_ms: Some(out.solve_latency.as_secs_f64() * 1e3),
        state_bytes_per_pixel: Some(out.state_bytes_per_pixel),
        samples,
        angle_reports: angle_reports(out),
        model_choice: Some(model_choice),
        field_model: None,
        field_model_choice: None,
    })
}
