//! filmscope: thin-film index and thickness maps from hyperspectral angle sweeps, as a
//! streaming processor.
//!
//! The no_std core ([`filmscope_core`], re-exported here: [`optics`], [`colour`],
//! [`calibrate`], [`track`], [`solve`]) does the computing; this crate adds, behind the `std`
//! feature, what touches the world. Its modules, each importing only those above it:
//!
//! - [`limits`], [`material`] (index models by name, JSON, refractiveindex.info YAML),
//!   [`io`] (ENVI cubes streamed row by row in any interleave, `capture.toml`, atomic
//!   writes, output folders, wall-clock stamps), [`record`] (the types of every record
//!   written to disk or sent to the line: `results.jsonl`, `truth.json`, `acquisition.json`)
//!   and [`summary`] (`summary.json`, one type);
//! - [`source`]: where band frames come from (the software camera, a capture on disk, a
//!   replayed set of frames), the messages they stream and a whole sweep in memory;
//! - [`simulate`]: a scene written as a capture with its truth;
//! - [`pipeline`]: bounded stages on crossbeam channels (calibrate, tracker and solver
//!   workers) driving the core's state machines;
//! - [`export`]: map previews, colour maps and charts as PNG;
//! - [`estimate`]: the methods over a source: filmscope's passes, the pixel sample's index
//!   fit, the field model, the known-index run and the paper's and brute-force baselines,
//!   and the maps and `summary.json` they write;
//! - [`appearance`]: the film's colour from the estimate (renders, measured against
//!   reproduced, glTF), and [`report`], one HTML page of it all;
//! - [`rig`]: the devices of a real rig and the acquisition; [`line`](mod@line): inspection on a
//!   production line;
//! - [`lab`]: the measuring lab: accuracy against the truth, speed and memory, speed against
//!   accuracy, stability maps, the Python peers. No module of the library imports it.
//!
//! The `filmscope` command line (arguments, printing, progress, one-line errors) is the
//! binary's own (`src/main.rs`, `src/cli/`): the library's errors are typed, `anyhow` is the
//! binary's only.
#![cfg_attr(not(feature = "std"), no_std)]

pub use filmscope_core::*;

#[cfg(feature = "std")]
pub mod appearance;
#[cfg(feature = "std")]
pub mod estimate;
#[cfg(feature = "std")]
pub mod export;
#[cfg(feature = "std")]
pub mod io;
#[cfg(feature = "std")]
pub mod jobs;
#[cfg(feature = "std")]
pub mod lab;
#[cfg(feature = "std")]
pub mod limits;
#[cfg(feature = "std")]
pub mod line;
#[cfg(feature = "std")]
pub mod material;
#[cfg(feature = "std")]
pub mod pipeline;
#[cfg(feature = "std")]
pub mod record;
#[cfg(feature = "std")]
pub mod report;
#[cfg(feature = "std")]
pub mod rig;
#[cfg(feature = "std")]
pub mod simulate;
#[cfg(feature = "std")]
pub mod source;
#[cfg(feature = "std")]
pub mod summary;
