//! The line's records of what it measured and raised: a sample's record and the line's
//! part of its `summary.json`, alarms, the reference check's record and the closing
//! summary (their types: [`crate::record::line`]).

use std::time::SystemTime;

use super::{Line, Swept};
use crate::estimate::Run;
use crate::io::utc_iso;
use crate::line::recipe::ReferenceSpec;
use crate::line::retention;
use crate::line::spc;
use crate::line::verdict::Verdict;
use crate::record::acquisition::AcquisitionLog;
use crate::record::finite;
use crate::record::line::{
    AlarmRecord, AlarmRule, AlarmVariable, LatencySummary, LineFault, LineSummary, MeasuredDrift,
    MqttCounts, Reading, RecipeRecord, ReferenceMeasured, ReferenceRecord, SampleRecord,
    ThicknessIndex,
};
use crate::summary::{LineRecord, Summary};

/// filmscope's version, in every record.
const VERSION: &str = env!("CARGO_PKG_VERSION");

/// Regions a sample record lists (its `summary.json` lists them all).
const RECORD_REGIONS: usize = 20;

impl Line {
    /// The record of sample `id` (number `counter`, swept at `t`) judged `v`; its latency is
    /// set when its folder is complete.
    pub(super) fn sample_record(
        &self,
        id: &str,
        counter: u64,
        t: SystemTime,
        v: &Verdict,
        swept: &Swept,
    ) -> SampleRecord {
        let recipe = &self.opts.recipe;
        SampleRecord {
            seq: None,
            sample_id: id.to_owned(),
            counter,
            timestamp: utc_iso(t),
            film: recipe.film.clone(),
            recipe: self
                .opts
                .recipe_path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            lot: recipe.lot.clone(),
            operator: recipe.operator.clone(),
            verdict: v.pass_fail(),
            reasons: v.reasons.clone(),
            refractive_index: finite(swept.run.result.index.at(550.0)),
            index_mode: recipe.index.mode,
            index_resolved: swept.resolved,
            thickness_nm: v.thickness.summary(),
            valid_fraction: v.valid_fraction,
            out_of_tolerance_px: v.out_of_tolerance_px,
            regions: v.regions.iter().take(RECORD_REGIONS).copied().collect(),
            raw_kept: retention::keeps_raw(&recipe.retention, counter, v.pass),
            folder: format!("samples/{id}"),
            latency_ms: f64::NAN,
            version: VERSION.into(),
            sim_sample: swept.sim.map(Into::into),
        }
    }

    /// Adds to a sample's `summary.json` what the line knows of it: when, the version, the
    /// recipe, the verdict and the acquisition's log.
    pub(super) fn complete_summary(
        &self,
        summary: &mut Summary,
        record: &SampleRecord,
        v: &Verdict,
        log: AcquisitionLog,
    ) {
        let recipe = &self.opts.recipe;
        summary.timestamp = Some(record.timestamp.clone());
        summary.version = Some(VERSION.into());
        summary.line = Some(LineRecord {
            sample_id: record.sample_id.clone(),
            recipe: RecipeRecord {
                file: self.opts.recipe_path.display().to_string(),
                film: recipe.film.clone(),
                settings: serde_json::to_value(recipe).unwrap_or_default(),
            },
            verdict: v.record(),
        });
        summary.acquisition = Some(log);
    }

    /// An alarm of no sample at the current counter: a fault of the line.
    pub(super) fn fault_alarm(
        &self,
        variable: AlarmVariable,
        fault: LineFault,
        text: String,
        value: Option<Reading>,
    ) -> AlarmRecord {
        AlarmRecord {
            seq: None,
            sample_id: None,
            counter: self.counter,
            timestamp: utc_iso(SystemTime::now()),
            variable,
            rule: AlarmRule::Fault(fault),
            text,
            value,
            center: None,
            ucl: None,
            lcl: None,
            floor: None,
            index_drift: None,
        }
    }

    /// The alarm of control-chart rule `a` broken by sample `id`, with the chart's limits.
    pub(super) fn spc_alarm_record(&self, id: &str, a: &spc::Alarm) -> AlarmRecord {
        AlarmRecord {
            seq: None,
            sample_id: Some(id.to_owned()),
            counter: self.counter,
            timestamp: utc_iso(SystemTime::now()),
            variable: a.variable.into(),
            rule: AlarmRule::Nelson(a.rule.number()),
            text: a.rule.text().into(),
            value: finite(a.value).map(Reading::Real),
            center: Some(a.limits.center),
            ucl: Some(a.limits.ucl),
            lcl: Some(a.limits.lcl),
            floor: None,
            index_drift: None,
        }
    }

    /// The record of reference check `id` (measured at `t`): `run`'s mean thickness over its
    /// `valid` pixels and its index against the certificate in `spec`.
    pub(super) fn reference_record(
        &self,
        spec: &ReferenceSpec,
        id: String,
        t: SystemTime,
        run: &Run,
        mean: f64,
        valid: usize,
    ) -> ReferenceRecord {
        let index = run.result.index.at(550.0);
        let (dd, dn) = (mean - spec.thickness_nm, index - spec.index);
        let recipe = &self.opts.recipe;
        ReferenceRecord {
            seq: None,
            reference: spec.name.clone(),
            folder: format!("references/{id}"),
            reference_id: id,
            timestamp: utc_iso(t),
            lot: recipe.lot.clone(),
            operator: recipe.operator.clone(),
            certified: ThicknessIndex {
                thickness_nm: spec.thickness_nm,
                index: spec.index,
            },
            measured: ReferenceMeasured {
                thickness_nm: finite(mean),
                index: finite(index),
                valid_fraction: valid as f64 / run.result.thickness_nm.len().max(1) as f64,
            },
            drift: MeasuredDrift {
                thickness_nm: finite(dd),
                index: finite(dn),
            },
            tolerance: ThicknessIndex {
                thickness_nm: spec.tolerance_nm,
                index: spec.tolerance_index,
            },
            within: dd.abs() <= spec.tolerance_nm && dn.abs() <= spec.tolerance_index,
            version: VERSION.into(),
        }
    }

    /// What this process did, for the closing summary.
    pub fn summary(&self) -> LineSummary {
        let mut l: Vec<f64> = self.latencies_ms.iter().copied().collect();
        l.sort_by(f64::total_cmp);
        let pct = |p: f64| {
            let last = l.len().checked_sub(1)?;
            l.get((last as f64 * p).round() as usize).copied()
        };
        LineSummary {
            samples: self.measured,
            passed: self.passed,
            failed: self.measured - self.passed,
            alarms: self.alarms_raised,
            last_counter: self.counter,
            latency_ms: LatencySummary {
                median: pct(0.5),
                p95: pct(0.95),
                max: finite(self.latency_max_ms),
                over: format!("median and p95 of the last {} samples, max of all", l.len()),
                measured: "last row of the sweep to the verdict published (results.jsonl fsynced, MQTT queued, status page updated)".into(),
            },
            mqtt: self.mqtt.as_ref().map(|m| MqttCounts {
                sent: m.sent(),
                acked: m.acked(),
            }),
            mqtt_unacknowledged: None,
            stopped_by_signal: false,
            status: self.status_url(),
            out: self.opts.out.display().to_string(),
        }
    }
}
