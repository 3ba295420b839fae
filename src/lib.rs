//! filmscope: thin-film index and thickness maps from hyperspectral angle sweeps, as a
//! streaming processor.
//!
//! The no_std core ([`filmscope_core`], re-exported here: [`optics`], [`colour`],
//! [`calibrate`], [`track`], [`solve`]) does the computing; this crate adds, behind the `std`
//! feature, what touches the world:
//!
//! - [`io`]: ENVI cubes (all interleaves, types, byte orders; streamed row by row) and
//!   `capture.toml`, with atomic writes;
//! - [`pipeline`]: bounded stages on crossbeam channels (source, calibrate, tracker/solver
//!   workers), sources for the software camera and for ENVI captures;
//! - [`sweep`] and [`baseline`]: the whole-sweep types and the paper's and brute-force
//!   methods;
//! - [`estimate`], [`eval`], [`export`], [`simulate`]: outputs per the capture contract,
//!   accuracy against the truth, PNG previews, writing simulated captures;
//! - [`field`]: the field model (one incidence angle per frame, or one per strip of columns
//!   under a wide field of view) and how it is chosen;
//! - [`appearance`]: the film's colour from the estimate: renders at any angle, measured
//!   against reproduced; [`appearance::gltf`] hands it to renderers, [`report`] to people;
//! - [`known_index`]: the estimator with the film's index given, not fitted;
//! - [`material`]: index models by name, as JSON or as refractiveindex.info YAML, and
//!   the estimate written back as CSV and YAML;
//! - [`cli`]: the `filmscope` command line.
#![cfg_attr(not(feature = "std"), no_std)]

pub use filmscope_core::*;

#[cfg(feature = "std")]
pub mod appearance;
#[cfg(feature = "std")]
pub mod baseline;
#[cfg(feature = "std")]
pub mod bench;
#[cfg(feature = "std")]
pub mod chart;
#[cfg(feature = "std")]
pub mod cli;
#[cfg(feature = "std")]
pub mod estimate;
#[cfg(feature = "std")]
pub mod eval;
#[cfg(feature = "std")]
pub mod export;
#[cfg(feature = "std")]
pub mod field;
#[cfg(feature = "std")]
pub mod index_fit;
#[cfg(feature = "std")]
pub mod io;
#[cfg(feature = "std")]
pub mod known_index;
#[cfg(feature = "std")]
pub mod limits;
#[cfg(feature = "std")]
pub mod line;
#[cfg(feature = "std")]
pub mod material;
#[cfg(feature = "std")]
pub mod peers;
#[cfg(feature = "std")]
pub mod pipeline;
#[cfg(feature = "std")]
pub mod report;
#[cfg(feature = "std")]
pub mod rig;
#[cfg(feature = "std")]
pub mod simulate;
#[cfg(feature = "std")]
pub mod summary;
#[cfg(feature = "std")]
pub mod sweep;
