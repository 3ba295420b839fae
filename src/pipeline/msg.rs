//! What flows between the pipeline's stages (rows to the workers, a shard's state to and
//! from the coordinator, angle ends to the coordinator), the hook the calibrate stage feeds,
//! and the error that ends a sweep.

use std::sync::Arc;
use std::time::Instant;

use filmscope_core::solve::refine::FilmTerms;
use filmscope_core::solve::SweepContext;

use super::state::{BandModels, ShardState, ShardTally};

/// A sweep that could not be completed, one line.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The source stopped the sweep (a device, a file), with its reason.
    #[error("{0}")]
    Source(String),
    /// The stream broke its contract: rows outside an angle or the sweep, a block of the
    /// wrong size, no end, too few angles.
    #[error("{0}")]
    Stream(String),
    /// What the run was given cannot be used (a seed map of another size, the wide field
    /// model without a field of view, a film that does not pass light).
    #[error("{0}")]
    Setup(String),
    /// A pipeline thread could not be started.
    #[error("cannot start a pipeline thread: {0}")]
    Thread(std::io::Error),
    /// A strip's estimator panicked (a defect; the other strips' work is dropped).
    #[error("a strip's estimator panicked")]
    Panicked,
}

/// Rows for a worker, on the data channel (from the calibrate stage).
pub(super) enum WorkerMsg {
    /// Rows of one band.
    Rows(WorkerRows),
    /// The angle's last row was sent.
    End,
}

/// Rows of one band for a worker.
pub(super) struct WorkerRows {
    /// The band.
    pub(super) band: u16,
    /// The first image row.
    pub(super) first_row: u32,
    /// Rows.
    pub(super) rows: u32,
    /// Their samples, packed ([`pack_sample`]).
    pub(super) samples: Vec<u16>,
}

/// The state of an angle for a worker, on its own channel (from the coordinator): rows are
/// read only after it, so rows of the next angle can never reach the previous one's state.
/// The solver's context as the angle began tallies the rows that have seen the angle's last
/// band.
pub(super) struct Start {
    /// The state of the worker's strips ([`ShardState::for_worker`]).
    pub(super) state: ShardState,
    /// The band models of the angle.
    pub(super) models: Arc<BandModels>,
    /// The solver's context as the angle began.
    pub(super) began: Arc<SweepContext>,
    /// The angles left in the sweep, this one included (the worker sizes its held block for
    /// the next angle, or gives it back after the last: [`HeldBlock`]).
    pub(super) angles_left: usize,
}

/// What a worker hands back at an angle's end: its state and what it tallied of it.
pub(super) struct Done {
    /// The worker.
    pub(super) worker: usize,
    /// Its strips' state.
    pub(super) state: ShardState,
    /// What it tallied.
    pub(super) tally: ShardTally,
}

pub(super) enum Control {
    Angle(f64),
    AngleEnd(Instant),
    SweepEnd,
    Abort(String),
}

/// What the calibrate stage hands calibrated rows to, besides the workers: the estimator's
/// pixel sample, which keeps the rows it wants.
pub trait Tap {
    /// An angle starts.
    fn angle(&mut self, incidence_deg: f64);
    /// Calibrated rows `first_row..first_row + rows` of `band` at the current angle.
    fn rows(&mut self, band: usize, first_row: usize, rows: usize, values: &[f32]);
    /// The image rows it reads, sorted and distinct (a stream may skip the others).
    fn image_rows(&self) -> Vec<usize>;
}

/// The sample fit's nuisance terms that apply to every pixel alike: a stage angle offset, a
/// wavelength shift, a flare and each angle's reflectance scale and offset
/// (`measured = scale x film + offset + flare`), taken out of the data; the film's
/// absorption and the polariser's leak, put into the pixels' model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Correction {
    /// Added to every measured angle, degrees.
    pub angle_offset_deg: f64,
    /// Added to every band's centre, nm.
    pub band_shift_nm: f64,
    /// Each angle's `(scale, offset)` in streaming order (empty: none; an angle past the end
    /// is left as measured).
    pub terms: Vec<(f32, f32)>,
    /// Subtracted from every measured reflectance (stray light), before the angle's terms.
    pub flare: f32,
    /// The film's absorption and the polariser's leak.
    pub film: FilmTerms,
}
