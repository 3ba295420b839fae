//! `filmscope results OUT --csv`: the line's results log as a spreadsheet opens it.
//!
//! Reads `OUT/results.jsonl` and its rotated files (`results.jsonl.K` .. `.1`, oldest
//! first), one CSV row per sample record (RFC 4180: a header row, fields quoted when they
//! hold a comma, a quote or a line break; numbers as written, `.` for the decimal point),
//! and the alarms after them when asked. A line that is not a record (a torn line a crash
//! left before recovery) is skipped and counted on stderr.

use std::io::{BufRead, BufReader, Write};
use std::path::Path;

use serde_json::Value;

/// The sample rows' columns: a header and the record's key (dotted for a nested one).
const SAMPLE_COLUMNS: [(&str, &str); 18] = [
    ("counter", "counter"),
    ("sample_id", "sample_id"),
    ("timestamp", "timestamp"),
    ("lot", "lot"),
    ("operator", "operator"),
    ("recipe", "recipe"),
    ("film", "film"),
    ("verdict", "verdict"),
    ("reasons", "reasons"),
    ("refractive_index", "refractive_index"),
    ("thickness_mean_nm", "thickness_nm.mean"),
    ("thickness_std_nm", "thickness_nm.std"),
    ("thickness_min_nm", "thickness_nm.min"),
    ("thickness_max_nm", "thickness_nm.max"),
    ("valid_fraction", "valid_fraction"),
    ("out_of_tolerance_px", "out_of_tolerance_px"),
    ("latency_ms", "latency_ms"),
    ("folder", "folder"),
];

/// The alarm rows' columns.
const ALARM_COLUMNS: [(&str, &str); 9] = [
    ("counter", "counter"),
    ("sample_id", "sample_id"),
    ("timestamp", "timestamp"),
    ("variable", "variable"),
    ("rule", "rule"),
    ("text", "text"),
    ("value", "value"),
    ("lcl", "lcl"),
    ("ucl", "ucl"),
];

/// Writes the results log of the `inspect --out` folder `out` as CSV into `w`: the samples'
/// rows, then (with `alarms`) a blank line, the alarms' header and their rows. Returns how
/// many lines were skipped as not records. An error names the file.
pub fn write_csv(out: &Path, alarms: bool, w: &mut dyn Write) -> Result<usize, String> {
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
        return Err(format!(
            "{}: no results log (is this an `inspect --out` folder?)",
            log.display()
        ));
    }
    let wr = |e: std::io::Error| format!("writing the CSV: {e}");
    writeln!(w, "{}", header(&SAMPLE_COLUMNS)).map_err(wr)?;
    let mut skipped = 0;
    let mut alarm_rows = Vec::new();
    for f in &files {
        let file = std::fs::File::open(f).map_err(|e| format!("{}: {e}", f.display()))?;
        for line in BufReader::new(file).lines() {
            let line = line.map_err(|e| format!("{}: {e}", f.display()))?;
            let Ok(record) = serde_json::from_str::<Value>(&line) else {
                skipped += usize::from(!line.trim().is_empty());
                continue;
            };
            match record.get("kind").and_then(Value::as_str) {
                Some("sample") => writeln!(w, "{}", row(&record, &SAMPLE_COLUMNS)).map_err(wr)?,
                Some("alarm") if alarms => alarm_rows.push(row(&record, &ALARM_COLUMNS)),
                _ => {}
            }
        }
    }
    if alarms {
        writeln!(w).map_err(wr)?;
        writeln!(w, "{}", header(&ALARM_COLUMNS)).map_err(wr)?;
        for r in alarm_rows {
            writeln!(w, "{r}").map_err(wr)?;
        }
    }
    Ok(skipped)
}

fn header(columns: &[(&str, &str)]) -> String {
    columns.iter().map(|c| c.0).collect::<Vec<_>>().join(",")
}

/// One record's fields in `columns`' order.
fn row(record: &Value, columns: &[(&str, &str)]) -> String {
    columns
        .iter()
        .map(|&(_, key)| {
            let v = key.split('.').try_fold(record, |v, k| v.get(k));
            field(v.unwrap_or(&Value::Null))
        })
        .collect::<Vec<_>>()
        .join(",")
}

/// One CSV field: empty for null, a number as written, a list joined by "; ", text quoted
/// when it must be.
fn field(v: &Value) -> String {
    let text = match v {
        Value::Null => return String::new(),
        Value::String(s) => s.clone(),
        Value::Array(items) => items
            .iter()
            .map(|i| match i {
                Value::String(s) => s.clone(),
                other => other.to_string(),
            })
            .collect::<Vec<_>>()
            .join("; "),
        other => other.to_string(),
    };
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text
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
        let sample = |c: u64, reasons: &str| {
            format!(
                r#"{{"kind":"sample","counter":{c},"sample_id":"s{c}","lot":"L7","operator":"Ann, B.","verdict":"FAIL","reasons":[{reasons}],"thickness_nm":{{"mean":601.5,"std":null}},"valid_fraction":0.99}}"#
            )
        };
        std::fs::write(format!("{}.1", log.display()), sample(1, "") + "\n").expect("write");
        std::fs::write(
            &log,
            format!(
                "{}\n{{\"kind\":\"sam\n{}\n{}\n",
                sample(2, r#""thickness \"low\"","mask""#),
                r#"{"kind":"alarm","counter":2,"rule":1,"text":"beyond 3 sigma","value":7.5}"#,
                sample(3, "")
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
        assert_eq!(lines[6], "2,,,,1,beyond 3 sigma,7.5,,");
        assert!(write_csv(&dir.path().join("none"), false, &mut Vec::new()).is_err());
    }
}
