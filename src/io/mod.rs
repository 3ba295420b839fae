//! File formats: ENVI cubes, capture descriptions, and crash-safe output.
//!
//! This is the only layer of filmscope that touches the file system for data; everything
//! here follows the on-disk contract in `spec/capture-format.md`.
//!
//! - [`envi`]: ENVI header parsing and writing ([`envi::EnviHeader`]), a streaming cube
//!   reader that walks a cube one band row at a time through a fixed buffer
//!   ([`envi::EnviReader`]), and a row-at-a-time writer ([`envi::EnviWriter`],
//!   [`envi::write_f32_map`]).
//! - [`capture`]: `capture.toml`, one angle sweep of one sample ([`capture::Capture`]),
//!   validated against the cubes it names before any pixel is read.
//! - [`atomic`]: write-to-temporary-then-rename, so an interrupted run leaves either the
//!   old file or the new one, never a torn one. Used for every single-file output.
//! - [`output`]: a result folder (maps, summary, recorded capture) as one unit: written
//!   beside its target, swapped in whole, one writer at a time ([`output::OutputDir`]).
//! - [`time`]: UTC timestamps; [`signals`]: the stop flag SIGINT and SIGTERM set, so work
//!   under way finishes and is kept.
//!
//! Errors ([`envi::EnviError`], [`capture::CaptureError`]) display as one line that names
//! the file at fault and the problem, ready for the CLI to print as is. No function here
//! panics on any input: garbage headers, empty or truncated files and absurd declared sizes
//! are all reported as errors, and nothing is allocated from a header's sizes before the
//! data file has been shown to be that large.

pub mod atomic;
pub mod capture;
pub mod envi;
pub mod output;
pub mod signals;
pub mod time;

pub use atomic::{write_atomic, TempFile};
pub use capture::{
    Angle, Capture, CaptureError, CaptureErrorKind, CubeInfo, Lens, Sample, Search,
    SubstrateMaterial,
};
pub use envi::{
    read_cube, write_f32_map, BandRow, ByteOrder, Cube, DataType, EnviError, EnviErrorKind,
    EnviHeader, EnviReader, EnviWriter, Interleave,
};
pub use output::{check_outside_inputs, OutputDir, OutputDirError, Replaced};
pub use time::{counter_of, sample_id, utc_date, utc_iso};
