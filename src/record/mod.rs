//! The types of every record filmscope writes to disk or sends to the line, each written
//! and read through one serde type:
//!
//! - [`line`]: what `inspect` writes and publishes: the sample, alarm and reference
//!   records of `results.jsonl` (and `record.json`, MQTT and the status page), the verdict
//!   and recipe a sample's `summary.json` carries, and the closing summary of a run;
//! - [`truth`]: `truth.json`, what `simulate` put into a capture, read by `eval`;
//! - [`acquisition`]: `acquisition.json`, what a rig's sweep did;
//! - [`method`]: the method and field model a run used, by their names;
//! - [`index_choice`]: how an estimate chose its index model, the evidence `summary.json`
//!   carries as `index_model_choice`.
//!
//! `summary.json` has its own module, [`crate::summary`].
//!
//! A record's JSON has the keys of every object in alphabetical order ([`to_json`],
//! [`to_json_pretty`], and [`sorted`] for a record inside another file's JSON), whatever
//! order its type declares them in: the same record is the same bytes in every file and
//! message that carries it.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

pub mod acquisition;
pub mod index_choice;
pub mod line;
pub mod method;
pub mod truth;

pub use acquisition::{AcquisitionFile, AcquisitionLog, LinkStats, LostRows};
pub use index_choice::IndexModelChoice;
pub use line::{AlarmRecord, LineSummary, Record, ReferenceRecord, SampleRecord};
pub use truth::TruthRecord;

/// A record file that cannot be read or written, one line: `PATH: problem`.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", .path.display())]
pub struct RecordError {
    /// The file.
    pub path: PathBuf,
    /// What went wrong.
    pub problem: RecordProblem,
}

/// What went wrong with a record file.
#[derive(Debug, thiserror::Error)]
pub enum RecordProblem {
    /// It cannot be read or written.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// It is not the record's JSON.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// An estimate's output was looked for in the capture folder it names.
    #[error("no such file: {0} is a capture, not an estimate's output (run `filmscope estimate {0} --out MAPS` first)")]
    ACapture(String),
}

impl RecordError {
    /// `problem` of the file `path`.
    pub fn new(path: &Path, problem: impl Into<RecordProblem>) -> Self {
        Self {
            path: path.to_path_buf(),
            problem: problem.into(),
        }
    }
}

impl From<RecordError> for String {
    fn from(e: RecordError) -> Self {
        e.to_string()
    }
}

/// Reads the record in the JSON file `path`.
pub fn read<T: DeserializeOwned>(path: &Path) -> Result<T, RecordError> {
    let text = std::fs::read_to_string(path).map_err(|e| RecordError::new(path, e))?;
    serde_json::from_str(&text).map_err(|e| RecordError::new(path, e))
}

/// Writes `text` (a record's JSON) to `path` atomically.
pub fn write_text(path: &Path, text: &str) -> Result<(), RecordError> {
    crate::io::write_atomic(path, text.as_bytes()).map_err(|e| RecordError::new(path, e))
}

/// Writes `record` to `path` atomically as indented JSON, its keys in alphabetical order.
pub fn write<T: Serialize + ?Sized>(path: &Path, record: &T) -> Result<(), RecordError> {
    let text = to_json_pretty(record).map_err(|e| RecordError::new(path, e))?;
    write_text(path, &text)
}

/// `record` as one line of JSON, the keys of every object in alphabetical order.
pub fn to_json<T: Serialize + ?Sized>(record: &T) -> serde_json::Result<String> {
    Ok(serde_json::to_value(record)?.to_string())
}

/// `record` as indented JSON, the keys of every object in alphabetical order.
pub fn to_json_pretty<T: Serialize + ?Sized>(record: &T) -> serde_json::Result<String> {
    serde_json::to_string_pretty(&serde_json::to_value(record)?)
}

/// Serialises `record` with the keys of every object in alphabetical order: for
/// `#[serde(serialize_with = "crate::record::sorted")]` on a member holding a record.
pub fn sorted<T: Serialize + ?Sized, S: Serializer>(record: &T, s: S) -> Result<S::Ok, S::Error> {
    serde_json::to_value(record)
        .map_err(serde::ser::Error::custom)?
        .serialize(s)
}

/// `v` when it is finite, else none (a record's null).
pub fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// Reads a member that is present as `Some`, its null included: with `default` and
/// `skip_serializing_if = "Option::is_none"` on an `Option<Option<T>>`, a member that some
/// records carry, null or not, and others leave out.
fn present<'de, D: Deserializer<'de>, T: Deserialize<'de>>(
    d: D,
) -> Result<Option<Option<T>>, D::Error> {
    Option::<T>::deserialize(d).map(Some)
}
