//! The streaming pipeline: bounded stages on crossbeam channels.
//!
//! `source -> calibrate -> track + solve (one worker per shard of rows) -> maps`. The stages
//! themselves are the core's state machines ([`filmscope_core::calibrate`],
//! [`filmscope_core::solve`]); this module only wires them to threads and channels.

mod held;
mod run;
mod ties;

pub use run::{
    collect_sweep, for_each_calibrated, for_each_calibrated_rows, run_sweep, run_sweep_sampled,
    tally_parallel, update_parallel, BandModels, Calibrated, LatencyParts, PipelineConfig,
    PipelineError, Prior, PriorUpdate, SampleHook, ShardState, SweepOutput, Tap,
};
