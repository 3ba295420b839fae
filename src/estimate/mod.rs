//! The methods over a source and what they write: filmscope's streaming estimator (its
//! [`passes`], the pixel sample's [`index_fit`], the [`field`] model, a [`known_index`]
//! given instead of fitted), the paper's and brute-force [`baseline`]s, the [`method`]
//! types they share and the [`output`] files.
//!
//! Imports point one way: [`method`] and [`run`] at the bottom, then [`index_fit`],
//! [`passes`], [`field`] and [`known_index`], then this file's dispatch; [`output`] reads a
//! finished [`Run`].

pub mod absorbing;
pub mod baseline;
pub mod field;
pub mod index_fit;
pub mod known_index;
pub mod method;
pub mod output;
pub mod passes;
pub mod run;

pub use output::{flag_counts, write_outputs_into, OutputError};
pub use passes::{
    angle_reports, check_capture_memory, filmscope_passes, index_model_name, result_from_sweep,
    Passes, MAX_DISAGREEING_SITES, SEARCH_CHI2_NU, SEARCH_MARGIN_CHI2, SITE_AGREEMENT_NM,
};
pub use run::{FieldChoice, FieldConfig, FieldModel, Run, RunConfig};

use std::time::Instant;

use crate::estimate::baseline::{brute, paper};
use crate::pipeline::{collect_sweep, PipelineError};
use crate::source::Source;
use filmscope_core::optics::FieldOfView;

use crate::estimate::method::Method;

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
/// ([`crate::estimate::field`]) by `config.field`. `on_rows` is told of rows streamed.
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
        Method::Filmscope => {
            crate::estimate::field::run_filmscope(source, config, field_of_view, on_rows)
        }
        Method::Paper | Method::Brute => {
            let cube = collect_sweep(source)?;
            on_rows((cube.height * cube.bands_nm.len() * cube.angles_deg.len()) as u64);
            let result = if config.method == Method::Paper {
                paper(&cube)
            } else {
                brute(&cube, config.brute_grid)
            };
            let samples = cube.samples();
            Ok(Run {
                result,
                spec,
                angles_deg,
                seconds: t0.elapsed().as_secs_f64(),
                solve_latency_ms: None,
                state_bytes_per_pixel: None,
                samples,
                angle_reports: Vec::new(),
                model_choice: None,
                field_model: None,
                field_model_choice: None,
            })
        }
    }
}
