//! The production line's records: one line of `results.jsonl` each ([`Record`]: a sample,
//! an alarm or a reference check, tagged by `kind`), also the sample folder's
//! `record.json`, the MQTT messages and what the status page shows; the verdict and recipe a
//! sample's `summary.json` carries ([`VerdictRecord`], [`RecipeRecord`]); and the summary
//! `inspect` prints and logs when it stops ([`LineSummary`]).
//!
//! Members that records written by earlier versions lack (`seq`, `lot`, `operator`) are
//! read as none.

use std::fmt;

use serde::{Deserialize, Serialize};

/// One record of the line's results log, told apart by its `kind` (which each record
/// type writes itself, wherever it is written).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged, from = "TaggedRecord")]
pub enum Record {
    /// A measured sample.
    Sample(Box<SampleRecord>),
    /// A control-chart rule broken, or a fault of the line.
    Alarm(AlarmRecord),
    /// A reference sample measured against its certificate.
    Reference(ReferenceRecord),
}

/// [`Record`] as read: by its `kind`.
#[derive(Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
enum TaggedRecord {
    Sample(Box<SampleRecord>),
    Alarm(AlarmRecord),
    Reference(ReferenceRecord),
}

impl From<TaggedRecord> for Record {
    fn from(r: TaggedRecord) -> Self {
        match r {
            TaggedRecord::Sample(s) => Self::Sample(s),
            TaggedRecord::Alarm(a) => Self::Alarm(a),
            TaggedRecord::Reference(r) => Self::Reference(r),
        }
    }
}

impl Record {
    /// The record's place in the log, counted from 1 (none before it is appended, and in
    /// logs written before records were numbered).
    pub fn seq(&self) -> Option<u64> {
        match self {
            Self::Sample(r) => r.seq,
            Self::Alarm(r) => r.seq,
            Self::Reference(r) => r.seq,
        }
    }

    /// Numbers the record: its place in the log.
    pub fn set_seq(&mut self, seq: u64) {
        let s = match self {
            Self::Sample(r) => &mut r.seq,
            Self::Alarm(r) => &mut r.seq,
            Self::Reference(r) => &mut r.seq,
        };
        *s = Some(seq);
    }

    /// The sample counter the record belongs to (a reference check has none).
    pub fn counter(&self) -> Option<u64> {
        match self {
            Self::Sample(r) => Some(r.counter),
            Self::Alarm(r) => Some(r.counter),
            Self::Reference(_) => None,
        }
    }

    /// The sample's id: of a sample record, or of the sample an alarm belongs to.
    pub fn sample_id(&self) -> Option<&str> {
        match self {
            Self::Sample(r) => Some(&r.sample_id),
            Self::Alarm(r) => r.sample_id.as_deref(),
            Self::Reference(_) => None,
        }
    }

    /// The sample record, if it is one.
    pub fn as_sample(&self) -> Option<&SampleRecord> {
        match self {
            Self::Sample(r) => Some(r),
            _ => None,
        }
    }

    /// The kind's name: `sample`, `alarm` or `reference` (also the MQTT topic's last level).
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Sample(_) => "sample",
            Self::Alarm(_) => "alarm",
            Self::Reference(_) => "reference",
        }
    }

    /// One line of JSON (without its newline), as the log and MQTT carry it.
    pub fn to_line(&self) -> String {
        super::to_json(self).unwrap_or_default()
    }
}

/// PASS or FAIL.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum PassFail {
    /// Every check passed.
    Pass,
    /// At least one check failed (the reasons say which).
    Fail,
}

impl PassFail {
    /// `Pass` when `pass`.
    pub fn of(pass: bool) -> Self {
        if pass {
            Self::Pass
        } else {
            Self::Fail
        }
    }

    /// Whether it passed.
    pub fn passed(self) -> bool {
        self == Self::Pass
    }

    /// `PASS` or `FAIL`.
    pub fn word(self) -> &'static str {
        match self {
            Self::Pass => "PASS",
            Self::Fail => "FAIL",
        }
    }
}

impl fmt::Display for PassFail {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.word())
    }
}

/// How the index is obtained for each sample (the recipe's `index.mode`).
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum IndexMode {
    /// The search is held around the recipe's nominal index.
    Hold,
    /// The search is held around the last sample's index.
    Carry,
    /// The index is searched over the rig's whole range every time.
    Solve,
}

/// Which of firmware-sim's line of samples was measured (`inspect --sim`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SimSample {
    /// The nominal film.
    Nominal,
    /// A thick patch.
    Defect,
    /// A film too thick all over.
    Shifted,
}

impl From<firmware_sim::line::SampleKind> for SimSample {
    fn from(k: firmware_sim::line::SampleKind) -> Self {
        use firmware_sim::line::SampleKind as K;
        match k {
            K::Nominal => Self::Nominal,
            K::Defect => Self::Defect,
            K::Shifted => Self::Shifted,
        }
    }
}

/// Thickness statistics of a sample over its judged pixels with a thickness, nm; null
/// members when no pixel has one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ThicknessSummary {
    /// Mean.
    pub mean: Option<f64>,
    /// Population standard deviation.
    pub std: Option<f64>,
    /// Smallest.
    pub min: Option<f64>,
    /// Largest.
    pub max: Option<f64>,
}

/// A connected out-of-tolerance region (4-connected).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Region {
    /// Bounding box: first column.
    pub x: usize,
    /// Bounding box: first row.
    pub y: usize,
    /// Bounding box width.
    pub width: usize,
    /// Bounding box height.
    pub height: usize,
    /// Pixels in the region.
    pub area_px: usize,
}

/// A measured sample: its verdict, index and thickness, where its folder is (`kind`
/// `sample`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename = "sample")]
pub struct SampleRecord {
    /// Place in the log, counted from 1 across restarts and rotations (none in
    /// `record.json`, written before the record is appended).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seq: Option<u64>,
    /// The sample's id: counter and UTC time (`S000002-20261125T225313Z`).
    pub sample_id: String,
    /// The sample's number on this line.
    pub counter: u64,
    /// When it was measured, UTC ISO 8601.
    pub timestamp: String,
    /// The recipe's film.
    pub film: String,
    /// The recipe's file name.
    pub recipe: String,
    /// The production lot (null when neither the recipe nor `--lot` gives one).
    #[serde(default)]
    pub lot: Option<String>,
    /// The operator (null when neither the recipe nor `--operator` gives one).
    #[serde(default)]
    pub operator: Option<String>,
    /// PASS or FAIL.
    pub verdict: PassFail,
    /// Every failed check, in words with the numbers.
    pub reasons: Vec<String>,
    /// The film's index at 550 nm; null when none was found.
    pub refractive_index: Option<f64>,
    /// How the index was obtained.
    pub index_mode: IndexMode,
    /// Whether a held index disagreed and the sweep was solved again over the whole range.
    pub index_resolved: bool,
    /// Thickness statistics, nm.
    pub thickness_nm: ThicknessSummary,
    /// Share of judged pixels with a thickness.
    pub valid_fraction: f64,
    /// Out-of-tolerance pixels.
    pub out_of_tolerance_px: usize,
    /// The largest out-of-tolerance regions, at most 20, largest first.
    pub regions: Vec<Region>,
    /// Whether the raw sweep was kept in the folder.
    pub raw_kept: bool,
    /// The sample's folder, relative to the output folder.
    pub folder: String,
    /// Last row of the sweep to the verdict, ms.
    pub latency_ms: f64,
    /// filmscope's version.
    pub version: String,
    /// Which of firmware-sim's samples it was (`inspect --sim` only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sim_sample: Option<SimSample>,
}

/// The variable an alarm is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AlarmVariable {
    /// The index at 550 nm (a control-chart rule).
    RefractiveIndex,
    /// The mean thickness (a control-chart rule).
    ThicknessMeanNm,
    /// The thickness spread (a control-chart rule).
    ThicknessStdNm,
    /// Free space on the output's disk, below the recipe's floor.
    DiskFreeBytes,
    /// Records the MQTT broker does not acknowledge.
    Mqtt,
    /// The reference sample's drift.
    Reference,
    /// The rig: a sample it could not measure.
    Device,
}

impl AlarmVariable {
    /// Its name in records.
    pub fn name(self) -> &'static str {
        match self {
            Self::RefractiveIndex => "refractive_index",
            Self::ThicknessMeanNm => "thickness_mean_nm",
            Self::ThicknessStdNm => "thickness_std_nm",
            Self::DiskFreeBytes => "disk_free_bytes",
            Self::Mqtt => "mqtt",
            Self::Reference => "reference",
            Self::Device => "device",
        }
    }
}

/// A fault of the line an alarm names by its rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LineFault {
    /// The disk is below `retention.min_free_bytes`.
    FreeSpaceFloor,
    /// The connected broker leaves records unacknowledged beyond `mqtt.ack_timeout_s`.
    NoAcknowledgement,
    /// The reference sample drifted beyond its tolerance.
    ReferenceDrift,
    /// A sample could not be measured (a device error): its counter has this alarm and no
    /// sample record.
    SampleFailed,
}

impl LineFault {
    /// Its name in records.
    pub fn name(self) -> &'static str {
        match self {
            Self::FreeSpaceFloor => "free_space_floor",
            Self::NoAcknowledgement => "no_acknowledgement",
            Self::ReferenceDrift => "reference_drift",
            Self::SampleFailed => "sample_failed",
        }
    }
}

/// The rule an alarm raises: a Nelson rule's number (1-4), or a fault of the line by name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum AlarmRule {
    /// Nelson's rule 1 to 4 on a control chart.
    Nelson(u8),
    /// A fault of the line.
    Fault(LineFault),
}

impl fmt::Display for AlarmRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Nelson(n) => write!(f, "{n}"),
            Self::Fault(x) => f.write_str(x.name()),
        }
    }
}

/// An alarm's value: a count (bytes free, records unacknowledged) or a measurement.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Reading {
    /// A whole number.
    Count(u64),
    /// A measurement.
    Real(f64),
}

impl fmt::Display for Reading {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Count(n) => write!(f, "{n}"),
            Self::Real(x) => f.write_str(&serde_json::to_string(x).unwrap_or_default()),
        }
    }
}

/// An alarm: a control-chart rule the newest sample broke, or a fault of the line
/// (`sample_id` null; `kind` `alarm`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename = "alarm")]
pub struct AlarmRecord {
    /// Place in the log, counted from 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seq: Option<u64>,
    /// The sample it belongs to; null for a fault of the line.
    pub sample_id: Option<String>,
    /// The line's sample counter when it was raised.
    pub counter: u64,
    /// When, UTC ISO 8601.
    pub timestamp: String,
    /// What it is about.
    pub variable: AlarmVariable,
    /// The rule.
    pub rule: AlarmRule,
    /// In words.
    pub text: String,
    /// The value that raised it; null when there is none.
    pub value: Option<Reading>,
    /// The control chart's centre line (control-chart rules).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center: Option<f64>,
    /// Its upper control limit (control-chart rules).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ucl: Option<f64>,
    /// Its lower control limit (control-chart rules).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lcl: Option<f64>,
    /// The recipe's free-space floor, bytes (`free_space_floor`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub floor: Option<u64>,
    /// The reference's index drift (`reference_drift`; null when no index was measured).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "super::present"
    )]
    pub index_drift: Option<Option<f64>>,
}

/// A thickness and an index at 550 nm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ThicknessIndex {
    /// Thickness, nm.
    pub thickness_nm: f64,
    /// Index at 550 nm.
    pub index: f64,
}

/// A thickness and an index at 550 nm as measured: null when not found.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeasuredDrift {
    /// Thickness, nm.
    pub thickness_nm: Option<f64>,
    /// Index at 550 nm.
    pub index: Option<f64>,
}

/// What the reference sample measured.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferenceMeasured {
    /// Mean thickness over the valid pixels, nm; null when none.
    pub thickness_nm: Option<f64>,
    /// Index at 550 nm; null when none.
    pub index: Option<f64>,
    /// Share of pixels with a thickness.
    pub valid_fraction: f64,
}

/// A reference check: the reference sample measured against its certificate (`kind`
/// `reference`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename = "reference")]
pub struct ReferenceRecord {
    /// Place in the log, counted from 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seq: Option<u64>,
    /// The reference's name (the recipe's `[reference] name`).
    pub reference: String,
    /// The check's id (`R` and the UTC time).
    pub reference_id: String,
    /// When, UTC ISO 8601.
    pub timestamp: String,
    /// The production lot.
    #[serde(default)]
    pub lot: Option<String>,
    /// The operator.
    #[serde(default)]
    pub operator: Option<String>,
    /// The certified values.
    pub certified: ThicknessIndex,
    /// What was measured.
    pub measured: ReferenceMeasured,
    /// Measured minus certified.
    pub drift: MeasuredDrift,
    /// The drift allowed.
    pub tolerance: ThicknessIndex,
    /// Whether both drifts are within tolerance.
    pub within: bool,
    /// The check's folder, relative to the output folder.
    pub folder: String,
    /// filmscope's version.
    pub version: String,
}

/// The verdict a sample's `summary.json` carries, with every region and the files of the
/// mask and the overlay.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VerdictRecord {
    /// PASS or FAIL.
    pub verdict: PassFail,
    /// Every failed check, in words with the numbers.
    pub reasons: Vec<String>,
    /// Thickness statistics, nm.
    pub thickness_nm: ThicknessSummary,
    /// Share of judged pixels with a thickness.
    pub valid_fraction: f64,
    /// Judged pixels.
    pub judged_px: usize,
    /// Out-of-tolerance pixels.
    pub out_of_tolerance_px: usize,
    /// Every out-of-tolerance region, largest first.
    pub regions: Vec<Region>,
    /// The out-of-tolerance mask (ENVI header).
    pub mask: String,
    /// The overlay (PNG).
    pub overlay: String,
}

/// The recipe a sample was judged against, as its `summary.json` carries it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RecipeRecord {
    /// The recipe's file.
    pub file: String,
    /// Its film.
    pub film: String,
    /// Every setting, as the recipe gave it (its password left out), for people.
    pub settings: serde_json::Value,
}

/// The latencies of a run, ms: last row of the sweep to the verdict published.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LatencySummary {
    /// Median of the recent samples; null without a sample.
    pub median: Option<f64>,
    /// 95th percentile of the recent samples; null without a sample.
    pub p95: Option<f64>,
    /// Longest since start; null without a sample.
    pub max: Option<f64>,
    /// The samples the figures are taken over, in words.
    pub over: String,
    /// What is measured, in words.
    pub measured: String,
}

/// Records handed to the MQTT client and acknowledged by the broker.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct MqttCounts {
    /// Queued by this process.
    pub sent: u64,
    /// Acknowledged by the broker.
    pub acked: u64,
}

/// What a run of `inspect` did, printed (`--json`) and logged when it stops.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LineSummary {
    /// Samples measured by this process.
    pub samples: u64,
    /// Of which passed.
    pub passed: u64,
    /// Of which failed.
    pub failed: u64,
    /// Control-chart alarms raised.
    pub alarms: u64,
    /// The highest sample counter of the line.
    pub last_counter: u64,
    /// Latencies.
    pub latency_ms: LatencySummary,
    /// MQTT counts; null without MQTT.
    pub mqtt: Option<MqttCounts>,
    /// Records the broker left unacknowledged at the stop; null when none or without MQTT.
    #[serde(default)]
    pub mqtt_unacknowledged: Option<u64>,
    /// Whether SIGINT or SIGTERM stopped the run.
    #[serde(default)]
    pub stopped_by_signal: bool,
    /// The status page's URL; null when not served.
    pub status: Option<String>,
    /// The output folder.
    pub out: String,
}

#[cfg(test)]
impl SampleRecord {
    /// A passing sample numbered `counter`, for tests.
    pub(crate) fn example(counter: u64) -> Self {
        Self {
            seq: None,
            sample_id: format!("S{counter:06}-20261125T225313Z"),
            counter,
            timestamp: "2026-11-25T22:53:13.000Z".into(),
            film: "ZnS AR coat".into(),
            recipe: "demo.toml".into(),
            lot: None,
            operator: None,
            verdict: PassFail::Pass,
            reasons: Vec::new(),
            refractive_index: Some(2.1),
            index_mode: IndexMode::Hold,
            index_resolved: false,
            thickness_nm: ThicknessSummary {
                mean: Some(620.0),
                std: Some(3.0),
                min: Some(611.0),
                max: Some(629.0),
            },
            valid_fraction: 1.0,
            out_of_tolerance_px: 0,
            regions: Vec::new(),
            raw_kept: false,
            folder: format!("samples/S{counter:06}-20261125T225313Z"),
            latency_ms: 40.0,
            version: "0.1.0".into(),
            sim_sample: None,
        }
    }
}

#[cfg(test)]
impl AlarmRecord {
    /// A rule 1 alarm on the mean thickness of sample `counter`, for tests.
    pub(crate) fn example(counter: u64) -> Self {
        Self {
            seq: None,
            sample_id: Some(format!("S{counter:06}-20261125T225313Z")),
            counter,
            timestamp: "2026-11-25T22:53:14.000Z".into(),
            variable: AlarmVariable::ThicknessMeanNm,
            rule: AlarmRule::Nelson(1),
            text: "a point beyond 3 sigma".into(),
            value: Some(Reading::Real(640.0)),
            center: Some(620.0),
            ucl: Some(626.0),
            lcl: Some(614.0),
            floor: None,
            index_drift: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every kind of record reads back as written, numbers keeping their type.
    #[test]
    fn records_round_trip() {
        let mut disk = AlarmRecord::example(3);
        disk.sample_id = None;
        disk.variable = AlarmVariable::DiskFreeBytes;
        disk.rule = AlarmRule::Fault(LineFault::FreeSpaceFloor);
        disk.value = Some(Reading::Count(12_345_678_901));
        (disk.center, disk.ucl, disk.lcl) = (None, None, None);
        disk.floor = Some(1 << 40);
        let mut drift = AlarmRecord::example(3);
        drift.rule = AlarmRule::Fault(LineFault::ReferenceDrift);
        drift.index_drift = Some(None);
        for r in [
            Record::Sample(Box::new(SampleRecord::example(7))),
            Record::Alarm(AlarmRecord::example(7)),
            Record::Alarm(disk),
            Record::Alarm(drift),
        ] {
            let line = r.to_line();
            let back: Record = serde_json::from_str(&line).expect("reads");
            assert_eq!(back, r, "{line}");
            assert_eq!(back.to_line(), line);
        }
    }

    /// A record alone (the status page's latest sample, its alarms) carries its kind too,
    /// and a line of another kind is not read as a sample.
    #[test]
    fn each_record_carries_its_kind() {
        let s = crate::record::to_json(&SampleRecord::example(2)).expect("json");
        assert!(s.contains(r#""kind":"sample""#), "{s}");
        let a = crate::record::to_json(&AlarmRecord::example(2)).expect("json");
        assert!(a.contains(r#""kind":"alarm""#), "{a}");
        let back: Record = serde_json::from_str(&a).expect("reads");
        assert!(matches!(back, Record::Alarm(_)));
        let wrong = a.replace(r#""kind":"alarm""#, r#""kind":"sample""#);
        assert!(serde_json::from_str::<Record>(&wrong).is_err());
    }

    /// The wire form: kind, the verdict's word, a count as an integer, the rule by number
    /// or name, an index drift present though null, absent members left out.
    #[test]
    fn the_json_is_the_documented_one() {
        let s = Record::Sample(Box::new(SampleRecord::example(1))).to_line();
        assert!(
            s.starts_with(r#"{"counter":1,"film":"ZnS AR coat","folder":"#),
            "{s}"
        );
        assert!(s.contains(r#""kind":"sample""#) && s.contains(r#""verdict":"PASS""#));
        assert!(s.contains(r#""index_mode":"hold""#) && s.contains(r#""lot":null"#));
        assert!(!s.contains("seq") && !s.contains("sim_sample"), "{s}");
        let mut a = AlarmRecord::example(1);
        a.rule = AlarmRule::Fault(LineFault::ReferenceDrift);
        a.value = Some(Reading::Count(3));
        a.index_drift = Some(None);
        a.seq = Some(9);
        let t = Record::Alarm(a).to_line();
        for part in [
            r#""rule":"reference_drift""#,
            r#""value":3,"#,
            r#""index_drift":null"#,
            r#""seq":9"#,
            r#""kind":"alarm""#,
        ] {
            assert!(t.contains(part), "{part} in {t}");
        }
        let old = r#"{"kind":"alarm","sample_id":"S1","counter":1,"timestamp":"t","variable":"refractive_index","rule":2,"text":"x","value":null,"center":1.0,"ucl":2.0,"lcl":0.0}"#;
        let Record::Alarm(back) = serde_json::from_str(old).expect("an alarm") else {
            panic!("not an alarm");
        };
        assert_eq!(
            (back.rule, back.value, back.seq),
            (AlarmRule::Nelson(2), None, None)
        );
        assert_eq!(back.index_drift, None);
    }
}
