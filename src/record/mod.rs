//! The types of every record filmscope writes to disk or sends to the line, each written
//! and read through one serde type:
//!
//! - [`line`]: what `inspect` writes and publishes: the sample, alarm and reference
//!   records of `results.jsonl` (and `record.json`, MQTT and the status page), the verdict
//!   and recipe a sample's `summary.json` carries, and the closing summary of a run;
//! - [`truth`]: `truth.json`, what `simulate` put into a capture, read by `eval`;
//! - [`acquisition`]: `acquisition.json`, what a rig's sweep did.
//!
//! `summary.json` has its own module, [`crate::summary`].
//!
//! A record's JSON has the keys of every object in alphabetical order ([`to_json`],
//! [`to_json_pretty`], and [`sorted`] for a record inside another file's JSON), whatever
//! order its type declares them in: the same record is the same bytes in every file and
//! message that carries it.

use serde::{Deserialize, Deserializer, Serialize, Serializer};

pub mod acquisition;
pub mod line;
pub mod truth;

pub use acquisition::{AcquisitionFile, AcquisitionLog, LinkStats, LostRows};
pub use line::{AlarmRecord, LineSummary, Record, ReferenceRecord, SampleRecord};
pub use truth::TruthRecord;

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
