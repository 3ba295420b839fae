//! The streaming pipeline: bounded stages on crossbeam channels.
//!
//! `source -> calibrate -> track + solve (one worker per shard of rows) -> maps`. The stages
//! themselves are the core's state machines ([`filmscope_core::calibrate`],
//! [`filmscope_core::solve`]); this module only wires them to threads and channels:
//! [`run`] the coordinator, `calibrate` and `worker` the stages, `state` what a worker
//! owns, `msg` what flows between them.

mod calibrate;
mod held;
mod msg;
pub mod run;
mod state;
mod ties;
mod worker;

pub use calibrate::{collect_sweep, for_each_calibrated, for_each_calibrated_rows, Calibrated};
pub use msg::{Correction, PipelineError, Tap};
pub use run::{
    run_sweep, run_sweep_sampled, tally_parallel, update_parallel, AngleTables, LatencyParts,
    PipelineConfig, Prior, PriorUpdate, SampleHook, SweepOutput,
};
pub use state::{BandModels, ShardState, ShardTally, Strips, Tally};
