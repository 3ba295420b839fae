//! Estimating a film: the estimator run on a source ([`run`]), its maps and summary written
//! as one unit ([`write`]), and the whole of `filmscope estimate` on a capture on disk
//! ([`estimate_capture`]): every input checked before any pixel is read, the output folder
//! checked against the inputs and locked, the result swapped in whole.

use std::path::{Path, PathBuf};

use filmscope_core::optics::{Dispersion, FieldOfView};

use super::Observer;
use crate::estimate::method::Method;
use crate::estimate::{OutputError, Run, RunConfig};
use crate::io::output::OutputDirError;
use crate::io::{Capture, CaptureError, OutputDir};
use crate::material::MaterialError;
use crate::pipeline::PipelineError;
use crate::source::{CaptureSource, Source, SourceError};
use crate::summary::Summary;

/// A film index given instead of fitted.
#[derive(Clone, Debug)]
pub struct GivenIndex {
    /// How the caller named it (a material's name, a file, a number).
    pub name: String,
    /// The index.
    pub dispersion: Dispersion,
}

/// How to estimate: the method's configuration and, if given, the film's index.
#[derive(Clone, Debug, Default)]
pub struct Settings {
    /// The method and its options.
    pub config: RunConfig,
    /// The film's index, held instead of fitted (the filmscope method only).
    pub film: Option<GivenIndex>,
}

impl Settings {
    /// Refuses an index given to a method that fits its own (only filmscope holds one);
    /// `film_option` names the index as the caller does (`--film-index`, `film_index`).
    pub fn check(&self, film_option: &'static str) -> Result<(), EstimateError> {
        if self.film.is_some() && self.config.method != Method::Filmscope {
            return Err(EstimateError::IndexNotTaken {
                option: film_option,
            });
        }
        Ok(())
    }
}

/// `filmscope estimate`'s request: a capture on disk, where to write, how.
#[derive(Clone, Debug)]
pub struct EstimateRequest {
    /// The capture: its `capture.toml` or the folder holding it.
    pub capture: PathBuf,
    /// The output folder, replaced whole.
    pub out: PathBuf,
    /// How the caller names the output folder in its messages (`--out`, `out`).
    pub out_option: &'static str,
    /// How the caller names the given index in its messages (`--film-index`, `film_index`).
    pub film_option: &'static str,
    /// How to estimate.
    pub settings: Settings,
    /// The most memory the estimate may take, bytes (`None`: no budget).
    pub memory_budget: Option<u64>,
}

/// What an estimate made.
pub struct Outcome {
    /// The maps, the index and the notes.
    pub run: Run,
    /// The summary as written.
    pub summary: Summary,
}

/// Why an estimate did not finish, one line naming the file, option or value at fault.
#[derive(Debug, thiserror::Error)]
pub enum EstimateError {
    /// The capture cannot be read.
    #[error(transparent)]
    Capture(#[from] CaptureError),
    /// The output folder cannot be used.
    #[error(transparent)]
    OutputDir(#[from] OutputDirError),
    /// The outputs cannot be written.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// The capture cannot be streamed, or needs more memory than allowed.
    #[error(transparent)]
    Source(#[from] SourceError),
    /// The given film index cannot be used over the capture's band.
    #[error("{option} {name:?}: {cause}")]
    FilmIndex {
        /// How the caller names the option.
        option: &'static str,
        /// The index as given.
        name: String,
        /// Its problem (in the message, not a source: one line, said once).
        cause: MaterialError,
    },
    /// A given index with a method that fits its own.
    #[error("{option}: only the filmscope method takes a given index")]
    IndexNotTaken {
        /// How the caller names the option.
        option: &'static str,
    },
    /// The capture's substrate cannot be used over its band.
    #[error("{label}: sample.substrate = {name:?}: {cause}")]
    Substrate {
        /// The capture.
        label: String,
        /// The substrate's name.
        name: String,
        /// Its problem (in the message, not a source: one line, said once).
        cause: MaterialError,
    },
    /// The sweep could not be estimated.
    #[error("{label}: {cause}")]
    Run {
        /// The source.
        label: String,
        /// What stopped it (in the message, not a source: one line, said once).
        cause: PipelineError,
    },
}

impl EstimateError {
    /// The error without the source's name in front, for a caller that names the source
    /// its own way.
    pub fn cause(&self) -> String {
        match self {
            Self::Run { cause, .. } => cause.to_string(),
            e => e.to_string(),
        }
    }
}

/// Runs the estimator on `source`, seen through a lens of field of view `field_of_view`
/// (`None`: unknown): the index fitted, or held at `settings.film`; the source's own notes
/// (a clipped reference, say) added to the result's. `label` names the source in errors.
pub fn run(
    source: &mut dyn Source,
    settings: &Settings,
    field_of_view: Option<FieldOfView>,
    label: &str,
    observer: &dyn Observer,
) -> Result<Run, EstimateError> {
    let spec = source.spec();
    let angles = source.angles_deg().len();
    log::debug!(
        "{label}: {} x {} px, {} bands, {angles} angles; method {}{}",
        spec.width,
        spec.height,
        spec.bands_nm.len(),
        settings.config.method.name(),
        settings
            .film
            .as_ref()
            .map_or(String::new(), |f| format!(", index held at {}", f.name))
    );
    observer.begin(label, (spec.height * spec.bands_nm.len() * angles) as u64);
    let on_rows = |n: u64| observer.rows(n);
    let config = &settings.config;
    let result = match &settings.film {
        None => crate::estimate::run_method_in_field(source, config, field_of_view, &on_rows),
        Some(film) => crate::estimate::known_index::run_with_index(
            source,
            config,
            &film.dispersion,
            &film.name,
            &on_rows,
        ),
    };
    observer.end();
    let mut run = result.map_err(|cause| EstimateError::Run {
        label: label.to_owned(),
        cause,
    })?;
    run.result.notes.extend(source.notes());
    log::debug!(
        "{label}: estimated in {:.2} s, n(550 nm) = {:.4}",
        run.seconds,
        run.result.index.at(550.0)
    );
    Ok(run)
}

/// Writes `run`'s maps, preview and summary into the folder `dir` as one unit
/// ([`OutputDir`]: written beside it, then swapped in whole, one writer at a time).
pub fn write(dir: &Path, run: &Run, label: &str) -> Result<Summary, EstimateError> {
    let out = OutputDir::begin(dir)?;
    let summary = crate::estimate::write_outputs_into(out.path(), run, label)?;
    out.commit()?;
    log::debug!("{label}: maps and summary in {}", dir.display());
    Ok(summary)
}

/// `filmscope estimate`: the capture at `request.capture` estimated into `request.out`.
/// Every value is checked, the output folder checked against the inputs and locked, and
/// the memory needed compared with the budget, before any pixel is read.
pub fn estimate_capture(
    request: &EstimateRequest,
    observer: &dyn Observer,
) -> Result<Outcome, EstimateError> {
    let settings = &request.settings;
    let given = |name: &str, cause: MaterialError| EstimateError::FilmIndex {
        option: request.film_option,
        name: name.to_owned(),
        cause,
    };
    settings.check(request.film_option)?;
    let cap = Capture::load(&request.capture)?;
    for key in &cap.unknown_keys {
        observer.warning(&format!(
            "{}: unknown key {} (ignored)",
            cap.path.display(),
            crate::limits::printable(key)
        ));
    }
    cap.check_output_outside(request.out_option, &request.out)?;
    crate::estimate::check_capture_memory(&cap, settings.config.method, request.memory_budget)?;
    let out_dir = OutputDir::begin(&request.out)?;
    let label = cap.path.display().to_string();
    let fov = cap.lens.field_of_view();
    let ambient = cap.sample.ambient_index;
    let substrate = cap.sample.substrate.clone();
    let mut source = CaptureSource::new(cap)?;
    // Materials hold over the whole captured band, not only at 550 nm.
    let bands = source.spec().bands_nm.clone();
    if let Some(film) = &settings.film {
        crate::material::check_over_band(&film.dispersion, &bands, ambient)
            .map_err(|e| given(&film.name, e))?;
        crate::estimate::known_index::held_index(&film.dispersion, &bands)
            .map_err(|e| given(&film.name, e))?;
    }
    if let Some(s) = &substrate {
        crate::material::check_over_band(&s.dispersion, &bands, ambient).map_err(|cause| {
            EstimateError::Substrate {
                label: label.clone(),
                name: s.name.clone(),
                cause,
            }
        })?;
    }
    let run = run(&mut source, settings, fov, &label, observer)?;
    let summary = crate::estimate::write_outputs_into(out_dir.path(), &run, &label)?;
    out_dir.commit()?;
    log::debug!("{label}: maps and summary in {}", request.out.display());
    Ok(Outcome { run, summary })
}
