//! `acquisition.json`: what a rig's sweep did (the angles taken and missing, the wavelengths
//! read back, every row the camera link lost and its fault counters). A sample's
//! `summary.json` carries the same log ([`AcquisitionLog`]) as its `acquisition`.
//!
//! Every member has a default, so a log written before a counter existed still reads.

use std::path::Path;

use filmscope_core::hw::{FrameKind, RowLoss};
use serde::{Deserialize, Serialize};

use super::RecordError;

/// The file name.
pub const FILE: &str = "acquisition.json";

/// `acquisition.json`: the log and what to do with the capture.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AcquisitionFile {
    /// What the sweep did.
    #[serde(flatten)]
    pub log: AcquisitionLog,
    /// Whether the capture can be estimated, in words.
    #[serde(default)]
    pub re_estimate: String,
}

impl AcquisitionFile {
    /// The file of `log`, saying whether its capture can be estimated.
    pub fn new(log: AcquisitionLog) -> Self {
        let re_estimate = if log.angles_done_deg.is_empty() {
            "no complete angle: the capture cannot be estimated"
        } else {
            "filmscope estimate on capture.toml uses the complete angles"
        };
        Self {
            log,
            re_estimate: re_estimate.into(),
        }
    }

    /// Reads `dir/acquisition.json`; the error names the file and the problem.
    pub fn read(dir: &Path) -> Result<Self, RecordError> {
        super::read(&dir.join(FILE))
    }

    /// Writes `dir/acquisition.json` atomically.
    pub fn write(&self, dir: &Path) -> Result<(), RecordError> {
        super::write(&dir.join(FILE), self)
    }
}

/// What the sweep did, for `acquisition.json`, `summary.json` and the report.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct AcquisitionLog {
    /// Whether every angle was taken.
    pub complete: bool,
    /// Why it stopped early.
    pub error: Option<String>,
    /// Measured incidence angles of the complete angles, degrees.
    pub angles_done_deg: Vec<f64>,
    /// Planned angles not (completely) taken, degrees.
    pub angles_missing_deg: Vec<f64>,
    /// Wavelengths read back, per complete angle, nm.
    pub wavelengths_read_nm: Vec<Vec<f64>>,
    /// Rows lost on the link.
    pub lost_rows: Vec<LostRows>,
    /// The link's fault counters.
    pub link: LinkStats,
}

/// Rows of one frame that did not arrive intact.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LostRows {
    /// Incidence angle, degrees.
    pub incidence_deg: f64,
    /// Band index.
    pub band: usize,
    /// The frame they belong to.
    pub frame: LostFrame,
    /// First row.
    pub first_row: u32,
    /// Rows.
    pub rows: u32,
    /// How they were lost.
    pub cause: LossCause,
}

/// The kind of frame rows were lost from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LostFrame {
    /// The sample.
    Sample,
    /// The dark reference.
    Dark,
    /// The white reference.
    White,
}

impl From<FrameKind> for LostFrame {
    fn from(k: FrameKind) -> Self {
        match k {
            FrameKind::Sample => Self::Sample,
            FrameKind::Dark => Self::Dark,
            FrameKind::White => Self::White,
        }
    }
}

/// How rows were lost.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LossCause {
    /// They never arrived (a sequence gap, a stall).
    Missing,
    /// They arrived damaged or cut short.
    Partial,
}

impl From<RowLoss> for LossCause {
    fn from(l: RowLoss) -> Self {
        match l {
            RowLoss::Missing => Self::Missing,
            RowLoss::Partial => Self::Partial,
        }
    }
}

/// Transport faults the camera link saw, for the acquisition log.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct LinkStats {
    /// Frames triggered.
    pub frames: u64,
    /// Rows delivered.
    pub rows: u64,
    /// Rows reported lost.
    pub rows_lost: u64,
    /// Messages missing according to the sequence numbers.
    pub sequence_gaps: u64,
    /// Messages that failed their CRC.
    pub crc_errors: u64,
    /// Rows received twice (the copy dropped).
    pub duplicate_rows: u64,
    /// Rows received after a later row of the same frame.
    pub out_of_order_rows: u64,
    /// Frames whose trailer said fewer rows were sent.
    pub partial_frames: u64,
    /// Frames that stopped without a trailer.
    pub stalled_frames: u64,
    /// Bytes skipped to find the next message.
    pub garbage_bytes: u64,
    /// Messages of an earlier frame, skipped.
    pub stale_messages: u64,
    /// Triggers sent again because no leader came.
    pub trigger_retries: u64,
}
