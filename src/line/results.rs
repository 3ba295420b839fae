//! `filmscope results OUT --csv`: the line's results log as a spreadsheet opens it.
//!
//! Reads `OUT/results.jsonl` and its rotated files (`results.jsonl.K` .. `.1`, oldest
//! first), one CSV row per sample record (RFC 4180: a header row, fields quoted when they
//! hold a comma, a quote or a line break; numbers as written, `.` for the decimal point),
//! and the alarms after them when asked. A line that is not a record (a torn line a crash
//! left before recovery) is skipped and counted on stderr.

use super::folder::{FolderError, FolderProblem};
use std::io::{BufRead, BufReader, Write};
use std::path::Path;

use serde::Serialize;

use crate::record::line::{AlarmRecord, Record, SampleRecord};

/// The sample rows' columns.
const SAMPLE_COLUMNS: [&str; 18] = [
    "counter",
    "sample_id",
    "timestamp",
    "lot",
    "operator",
    "recipe",
    "film",
    "verdict",
    "reasons",
    "refractive_index",
    "thickness_mean_nm",
    "thickness_std_nm",
    "thickness_min_nm",
    "thickness_max_nm",
    "valid_fraction",
    "out_of_tolerance_px",
    "latency_ms",
    "folder",
];

/// The alarm rows' columns.
const ALARM_COLUMNS: [&str; 9] = [
    "counter",
    "sample_id",
    "timestamp",
    "variable",
    "rule",
    "text",
    "value",
    "lcl",
    "ucl",
];

/// Why the results log could not be written as CSV.
#[derive(Debug, thiserror::Error)]
pub enum CsvError {
    /// The log cannot be read.
    #[error(transparent)]
    Read(#[from] FolderError),
    /// The CSV cannot be written.
    #[error("writing the CSV: {0}")]
    Write(std::io::Error),
}

/// Writes the results log of the `inspect --out` folder `out` as CSV into `w`: the samples'
/// rows, then (with `alarms`) a blank line, the alarms' header and their rows. Returns how
/// many lines were skipped as not records. An error names the file.
pub fn write_csv(out: &Path, alarms: bool, w: &mut dyn Write) -> Result<usize, CsvError> {
    let log = out.join("results.jsonl");
    let mut files = Vec::new();
    for k in 1.. {
        let f = super::stream::rotated(&log, k);
        if !f.is_file() {
            break;
        }
        files.push(f);
    }
    files.reverse();
    if log.is_file() {
        files.push(log.clone());
    }
    if files.is_empty() {
        return Err(FolderError::new(&log, FolderProblem::NoResultsLog).into());
    }
    let wr = CsvError::Write;
    writeln!(w, "{}", SAMPLE_COLUMNS.join(",")).map_err(wr)?;
    let mut skipped = 0;
    let mut alarm_rows = Vec::new();
    for f in &files {
        let file = std::fs::File::open(f).map_err(|e| FolderError::new(f, e))?;
        for line in BufReader::new(file).lines() {
            let line = line.map_err(|e| FolderError::new(f, e))?;
            let Ok(record) = serde_json::from_str::<Record>(&line) else {
                skipped += usize::from(!line.trim().is_empty());
                continue;
            };
            match record {
                Record::Sample(r) => writeln!(w, "{}", sample_row(&r)).map_err(wr)?,
                Record::Alarm(a) if alarms => alarm_rows.push(alarm_row(&a)),
                _ => {}
            }
        }
    }
    if alarms {
        writeln!(w).map_err(wr)?;
        writeln!(w, "{}", ALARM_COLUMNS.join(",")).map_err(wr)?;
        for r in alarm_rows {
            writeln!(w, "{r}").map_err(wr)?;
        }
    }
    Ok(skipped)
}

/// A sample record's fields in [`SAMPLE_COLUMNS`]' order.
fn sample_row(r: &SampleRecord) -> String {
    let t = &r.thickness_nm;
    [
        num(Some(r.counter)),
        text(&r.sample_id),
        text(&r.timestamp),
        r.lot.as_deref().map(text).unwrap_or_default(),
        r.operator.as_deref().map(text).unwrap_or_default(),
        text(&r.recipe),
        text(&r.film),
        text(r.verdict.word()),
        text(&r.reasons.join("; ")),
        num(r.refractive_index),
        num(t.mean),
        num(t.std),
        num(t.min),
        num(t.max),
        num(Some(r.valid_fraction)),
        num(Some(r.out_of_tolerance_px)),
        num(Some(r.latency_ms)),
        text(&r.folder),
    ]
    .join(",")
}

/// An alarm record's fields in [`ALARM_COLUMNS`]' order.
fn alarm_row(a: &AlarmRecord) -> String {
    [
        num(Some(a.counter)),
        a.sample_id.as_deref().map(text).unwrap_or_default(),
        text(&a.timestamp),
        text(a.variable.name()),
        text(&a.rule.to_string()),
        text(&a.text),
        a.value.map(|v| v.to_string()).unwrap_or_default(),
        num(a.lcl),
        num(a.ucl),
    ]
    .join(",")
}

/// A number as the log writes it; empty for none (null).
fn num<T: Serialize>(v: Option<T>) -> String {
    v.and_then(|v| serde_json::to_string(&v).ok())
        .unwrap_or_default()
}

/// Text, quoted when it must be.
fn text(t: &str) -> String {
    if t.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", t.replace('"', "\"\""))
    } else {
        t.to_owned()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rotated files come first, torn lines are skipped and counted, text is quoted.
    #[test]
    fn rows_in_order_with_quoting() {
        let dir = tempfile::tempdir().expect("dir");
        let log = dir.path().join("results.jsonl");
        let sample = |c: u64, reasons: &[&str]| {
            let mut r = SampleRecord::example(c);
            r.sample_id = format!("s{c}");
            r.timestamp = String::new();
            r.lot = Some("L7".into());
            r.operator = Some("Ann, B.".into());
            r.verdict = crate::record::line::PassFail::Fail;
            r.reasons = reasons.iter().map(|&t| t.to_owned()).collect();
            r.refractive_index = None;
            r.thickness_nm.mean = Some(601.5);
            r.thickness_nm.std = None;
            r.thickness_nm.min = None;
            r.thickness_nm.max = None;
            r.valid_fraction = 0.99;
            Record::Sample(Box::new(r)).to_line()
        };
        let mut alarm = AlarmRecord::example(2);
        alarm.value = Some(crate::record::line::Reading::Real(7.5));
        alarm.text = "beyond 3 sigma".into();
        std::fs::write(format!("{}.1", log.display()), sample(1, &[]) + "\n").expect("write");
        std::fs::write(
            &log,
            format!(
                "{}\n{{\"kind\":\"sam\n{}\n{}\n",
                sample(2, &["thickness \"low\"", "mask"]),
                Record::Alarm(alarm).to_line(),
                sample(3, &[])
            ),
        )
        .expect("write");
        let mut out = Vec::new();
        let skipped = write_csv(dir.path(), true, &mut out).expect("csv");
        let text = String::from_utf8(out).expect("utf-8");
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(skipped, 1);
        assert!(lines[0].starts_with("counter,sample_id,timestamp,lot,operator"));
        assert!(lines[1].starts_with("1,s1,,L7,\"Ann, B.\""), "{}", lines[1]);
        assert!(
            lines[2].contains(r#"FAIL,"thickness ""low""; mask",,601.5,,,,0.99"#),
            "{}",
            lines[2]
        );
        assert!(lines[3].starts_with("3,s3"));
        assert_eq!(lines[4], "");
        assert!(lines[5].starts_with("counter,sample_id,timestamp,variable,rule"));
        assert_eq!(
            lines[6],
            "2,S000002-20261125T225313Z,2026-11-25T22:53:14.000Z,thickness_mean_nm,1,beyond 3 sigma,7.5,614.0,626.0"
        );
        assert!(write_csv(&dir.path().join("none"), false, &mut Vec::new()).is_err());
    }
}
