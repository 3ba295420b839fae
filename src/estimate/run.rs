//! How a method is asked to run ([`RunConfig`]) and what its run gives ([`Run`]).

use filmscope_core::solve::SweepSpec;

use crate::estimate::baseline::BruteGrid;
use crate::pipeline::PipelineConfig;
pub use crate::record::method::FieldModel;
use crate::record::IndexModelChoice;

use crate::estimate::method::{Method, MethodResult};
use crate::summary::{AngleReport, FieldModelChoice};

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
    /// Sites whose full spectra give the shared index ([`crate::estimate::index_fit`]).
    pub sample_sites: usize,
    /// Stream once, as from a live camera, even when the source could be replayed (the
    /// index refitted on the sample as each angle completes).
    pub one_pass: bool,
    /// The model error the index fit tolerates, RMS reflectance, over the capture's own
    /// (`[fit] model_error`) when given.
    pub model_error: Option<f64>,
    /// The rig's nuisance terms in the index sigma, over the capture's own
    /// (`[fit] rig_tolerance`) when given.
    pub rig_tolerance: Option<f64>,
}

impl RunConfig {
    /// `spec` as this run fits it: its tolerated model error and rig tolerance replaced when
    /// the run gives them.
    pub fn fitted_spec(&self, spec: &SweepSpec) -> SweepSpec {
        let mut spec = spec.clone();
        if let Some(m) = self.model_error {
            spec.model_error = m;
        }
        if let Some(t) = self.rig_tolerance {
            spec.rig_tolerance = t;
        }
        spec
    }
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            method: Method::Filmscope,
            pipeline: PipelineConfig::default(),
            brute_grid: BruteGrid::default(),
            field: FieldConfig::default(),
            sample_sites: crate::estimate::index_fit::DEFAULT_SITES,
            one_pass: false,
            model_error: None,
            rig_tolerance: None,
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
    /// Per-angle progress of the streaming solver.
    pub angle_reports: Vec<AngleReport>,
    /// How the index model was chosen (streaming method; none for the baselines).
    pub model_choice: Option<IndexModelChoice>,
    /// The field model used (streaming method).
    pub field_model: Option<FieldModel>,
    /// How the field model was chosen and its evidence (streaming method).
    pub field_model_choice: Option<FieldModelChoice>,
}

/// How the field model is chosen (`--field`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FieldChoice {
    /// The simplest model the data do not contradict (default).
    Auto,
    /// Forced: one incidence angle per frame.
    Narrow,
    /// Forced: the angle varies with the column (needs the lens's field of view).
    Wide,
}

impl FieldChoice {
    /// Parses `auto`, `narrow` or `wide`.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "auto" => Some(Self::Auto),
            "narrow" => Some(Self::Narrow),
            "wide" => Some(Self::Wide),
            _ => None,
        }
    }

    /// The choice's name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Narrow => "narrow",
            Self::Wide => "wide",
        }
    }
}

/// How the field model is chosen and what the wide model does (`RunConfig::field`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FieldConfig {
    /// Auto, or a forced model (`--field`).
    pub choice: FieldChoice,
    /// Strips of the wide model (`--field-strips`; `None`: [`super::field::strips_for`]).
    pub strips: Option<usize>,
    /// Map each pixel's thickness from its strip's angles to its column's own
    /// ([`super::field::column_factor`]); off only to measure what it is worth (`--ablate column-map`).
    pub column_map: bool,
    /// Run the [`super::field::SHARED_ROUNDS`] that give the strips one index (`--ablate shared-index` to
    /// measure their worth; without them each strip keeps its own index).
    pub shared_rounds: bool,
}

impl Default for FieldConfig {
    fn default() -> Self {
        Self {
            choice: FieldChoice::Auto,
            strips: None,
            column_map: true,
            shared_rounds: true,
        }
    }
}
