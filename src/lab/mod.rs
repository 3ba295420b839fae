//! The measuring lab: how well and how fast the methods work, against the truth of
//! simulated scenes and beside outside baselines. The `eval`, `bench`, `chart`, `stability`
//! and `soak` commands print what it measures; only the command line imports it.
//!
//! - [`scene`]: the scenes the measurements run on, resized;
//! - [`eval`]: accuracy against the truth (index, thickness, colour) of scene files,
//!   captures and random sets judged PASS or FAIL, with improvements switched off;
//! - [`chart`]: speed against accuracy over methods and settings, and the stability maps;
//! - [`peers`]: the Python peers `bench` sets filmscope beside;
//! - [`bench`](mod@bench): speed and memory, the baselines' cost, the line's inspect latency, and the
//!   resident memory of a long run.

pub mod bench;
pub mod chart;
pub mod eval;
pub mod peers;
pub mod scene;
