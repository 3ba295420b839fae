//! ENVI cubes: header parsing and writing, a streaming reader and a row-at-a-time writer.
//!
//! An ENVI cube is a text header `NAME.hdr` beside a raw binary data file (`NAME.img`,
//! `NAME.raw`, `NAME.dat` or `NAME`). The header gives the geometry (`samples` pixels per
//! line, `lines`, `bands`), the value type, the byte order and the interleave, i.e. the
//! order in which `(band, line, sample)` values follow each other in the data file:
//!
//! | interleave | file order (outer to inner)  |
//! |------------|------------------------------|
//! | `bsq`      | band, line, sample           |
//! | `bil`      | line, band, sample           |
//! | `bip`      | line, sample, band           |
//!
//! The unit this module hands out is the *band row*: the `samples` values of one band on
//! one line, as `f32`.
//!
//! - [`EnviHeader`] parses a header ([`EnviHeader::parse`], [`EnviHeader::read`]) and
//!   validates it once: after that its sizes are known not to overflow, and its wavelength
//!   and FWHM lists (in nanometres) have one entry per band.
//! - [`EnviReader`] checks the data file's size against the header before allocating
//!   anything sized from the header, then streams band rows in the file's native order
//!   ([`EnviReader::next_band_row`]) through one buffer of one line (`bil`, `bip`) or one
//!   row (`bsq`), or reads any row at random ([`EnviReader::read_band_row`]).
//!   [`read_cube`] loads a whole (small) cube for tests and tools.
//! - [`EnviWriter`] writes float32 or uint16 cubes in any interleave, band rows in any
//!   order, and renames the finished files into place ([`crate::io::atomic`]);
//!   [`write_f32_map`] writes the one-band float32 maps filmscope outputs.
//!
//! Every error is an [`EnviError`]: the file at fault plus an [`EnviErrorKind`], shown on
//! one line.

mod codec;
mod header;
mod reader;
mod writer;

use std::io;
use std::path::{Path, PathBuf};

pub use header::{ByteOrder, DataType, EnviHeader, Interleave};
pub use reader::{read_cube, BandRow, Cube, EnviReader};
pub use writer::{write_f32_map, EnviWriter};

/// An ENVI problem, tied to the file it concerns.
///
/// Displays as one line: `PATH: PROBLEM`, e.g.
/// `a10.img: data is 1200 bytes but a10.hdr declares 64x32x3 float32 (24576 bytes)`.
#[derive(Debug, thiserror::Error)]
#[error("{}: {kind}", .path.display())]
pub struct EnviError {
    path: PathBuf,
    kind: EnviErrorKind,
}

impl EnviError {
    /// Ties `kind` to the file `path`.
    pub fn new(path: impl Into<PathBuf>, kind: EnviErrorKind) -> Self {
        Self {
            path: path.into(),
            kind,
        }
    }

    /// The file the problem concerns (a header or a data file).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What went wrong.
    pub fn kind(&self) -> &EnviErrorKind {
        &self.kind
    }

    /// Consumes the error, returning what went wrong.
    pub fn into_kind(self) -> EnviErrorKind {
        self.kind
    }
}

/// What went wrong with an ENVI file; each variant displays as one line without the path.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EnviErrorKind {
    /// The operating system refused an operation (`action` says which).
    #[error("{action}: {err}")]
    Io {
        /// What was being done, e.g. "cannot read header".
        action: &'static str,
        /// The underlying error (not a `source`, its text is already in this message).
        err: io::Error,
    },
    /// The header file is empty.
    #[error("empty file, not an ENVI header")]
    EmptyHeader,
    /// The header's first line is not `ENVI`.
    #[error("not an ENVI header (the first line must be `ENVI`)")]
    NotEnvi,
    /// The header is larger than any plausible header.
    #[error("header is over {limit} bytes, not an ENVI header")]
    HeaderTooLarge {
        /// The size limit in bytes.
        limit: u64,
    },
    /// A `{` list is never closed.
    #[error("line {line}: the `{{` opened by `{key}` is never closed")]
    UnclosedBrace {
        /// The key whose value is unclosed.
        key: String,
        /// 1-based line of the key.
        line: usize,
    },
    /// A required key is absent.
    #[error("missing required key `{key}`")]
    MissingKey {
        /// The key, as ENVI spells it.
        key: &'static str,
    },
    /// A value does not parse or is out of range.
    #[error("`{key} = {value}`: expected {expected}")]
    BadValue {
        /// The key.
        key: String,
        /// The value as found (shortened to one line).
        value: String,
        /// What would have been accepted.
        expected: &'static str,
    },
    /// `data type` names a type filmscope does not read.
    #[error("data type {code}{} is not supported (expected 2 int16, 4 float32, 5 float64 or 12 uint16)", DataType::envi_type_name(.code).map(|n| format!(" ({n})")).unwrap_or_default())]
    UnsupportedDataType {
        /// The value of `data type`.
        code: String,
    },
    /// `interleave` is not `bsq`, `bil` or `bip`.
    #[error("unknown interleave `{value}` (expected bsq, bil or bip)")]
    UnknownInterleave {
        /// The value of `interleave`.
        value: String,
    },
    /// `wavelength units` is not a length unit filmscope knows.
    #[error("unsupported wavelength units `{value}` (expected Nanometers or Micrometers)")]
    UnknownUnits {
        /// The value of `wavelength units`.
        value: String,
    },
    /// `samples`, `lines` or `bands` is zero.
    #[error("`{key}` must be positive, got 0")]
    ZeroDimension {
        /// The key.
        key: &'static str,
    },
    /// A per-band list has the wrong length.
    #[error("`{key}` lists {count} values but `bands` is {bands}")]
    CountMismatch {
        /// `wavelength` or `fwhm`.
        key: &'static str,
        /// Values in the list.
        count: usize,
        /// The header's band count.
        bands: usize,
    },
    /// The declared size does not fit in 64 bits (or in memory addresses).
    #[error("declares {samples}x{lines}x{bands} {data_type}, which overflows a 64-bit size")]
    TooLarge {
        /// Declared samples.
        samples: usize,
        /// Declared lines.
        lines: usize,
        /// Declared bands.
        bands: usize,
        /// Value type name.
        data_type: &'static str,
    },
    /// No data file beside the header.
    #[error("no data file found beside the header (tried {tried})")]
    DataNotFound {
        /// The candidate names, comma separated.
        tried: String,
    },
    /// The data file's size disagrees with the header.
    #[error("data is {actual} bytes but {header} declares {samples}x{lines}x{bands} {data_type}{} ({expected} bytes)", offset_text(*.offset))]
    SizeMismatch {
        /// Actual data file size.
        actual: u64,
        /// Header file name.
        header: String,
        /// Declared samples.
        samples: usize,
        /// Declared lines.
        lines: usize,
        /// Declared bands.
        bands: usize,
        /// Value type name.
        data_type: &'static str,
        /// Declared header offset.
        offset: u64,
        /// Expected data file size, offset included.
        expected: u64,
    },
    /// The header path does not end in `.hdr`.
    #[error("expected an ENVI header path ending in `.hdr`")]
    NotAHeaderPath,
    /// A band or line index is outside the cube.
    #[error("band {band}, line {line} is outside the cube ({bands} bands x {lines} lines)")]
    OutOfRange {
        /// Requested band.
        band: usize,
        /// Requested line.
        line: usize,
        /// Bands in the cube.
        bands: usize,
        /// Lines in the cube.
        lines: usize,
    },
    /// A caller's row buffer has the wrong length.
    #[error("row buffer holds {got} values but the cube has {expected} samples per row")]
    BufferLength {
        /// `samples`.
        expected: usize,
        /// The buffer's length.
        got: usize,
    },
    /// A map's data does not match its declared size.
    #[error("map data holds {got} values but {samples}x{lines} needs {expected}")]
    MapLength {
        /// Declared samples.
        samples: usize,
        /// Declared lines.
        lines: usize,
        /// samples x lines.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// The writer only writes float32 and uint16.
    #[error("writing {data_type} is not supported (float32 or uint16 only)")]
    UnsupportedWrite {
        /// Value type name.
        data_type: &'static str,
    },
    /// An extra key cannot be written back as a header line.
    #[error("extra key `{key}` cannot be written back (empty key, `=`, newline or brace in the key, or a multi-line value outside `{{...}}`)")]
    BadExtraKey {
        /// The key.
        key: String,
    },
    /// A buffer sized from the header could not be allocated.
    #[error("cannot allocate a {bytes}-byte buffer")]
    OutOfMemory {
        /// The buffer's size.
        bytes: usize,
    },
}

fn offset_text(offset: u64) -> String {
    if offset == 0 {
        String::new()
    } else {
        format!(" after a {offset}-byte header offset")
    }
}

impl EnviErrorKind {
    /// Wraps an I/O error with what was being done.
    pub(crate) fn io(action: &'static str, err: io::Error) -> Self {
        Self::Io { action, err }
    }

    /// Ties this problem to `path`.
    pub(crate) fn at(self, path: &Path) -> EnviError {
        EnviError::new(path, self)
    }
}

/// Shortens a value for an error message: first line only, at most 40 characters.
pub(crate) fn shorten(value: &str) -> String {
    let first = value.lines().next().unwrap_or("");
    let mut out: String = first.chars().take(40).collect();
    if out.len() < value.len() {
        out.push_str("...");
    }
    out
}

/// File name of `path` for messages that mention a second file.
pub(crate) fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string())
}

/// A zeroed buffer of `len` elements, or an error instead of an allocation failure abort.
pub(crate) fn zeroed<T: Clone + Default>(len: usize) -> Result<Vec<T>, EnviErrorKind> {
    let bytes = len.saturating_mul(std::mem::size_of::<T>());
    // An overcommitting kernel grants any reservation and kills the process when the
    // zeros are written: compare with the memory the machine has first.
    if bytes > 64 << 20
        && crate::limits::available_memory().is_some_and(|avail| bytes as u64 > avail)
    {
        return Err(EnviErrorKind::OutOfMemory { bytes });
    }
    let mut buf = Vec::new();
    buf.try_reserve_exact(len)
        .map_err(|_| EnviErrorKind::OutOfMemory {
            bytes: len.saturating_mul(std::mem::size_of::<T>()),
        })?;
    buf.resize(len, T::default());
    Ok(buf)
}
