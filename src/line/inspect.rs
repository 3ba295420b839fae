//! The inspection loop: for each sample, sweep the rig (or firmware-sim's line of samples),
//! estimate while it streams, judge against the recipe, write the sample's folder (to a
//! temporary name, renamed when whole), append its record to `results.jsonl`, publish it
//! (MQTT, status page), update the trends and raise alarms, then apply the retention policy.
//! What the status page shows is left in `DIR/status.json` after every sample.
//!
//! `DIR` after a crash: folders still under a temporary name are deleted; a folder renamed
//! into place whose record is missing from the records read back (the newest
//! `spc.history` samples') gets it appended from its `record.json`, whatever its number;
//! numbering continues after the highest counter seen in folders or records.
//!
//! A record that cannot be appended (a full disk) waits in memory and is appended, in
//! order, before any later one; a restart appends it from the folder. Below the recipe's
//! free-space floor (`retention.min_free_bytes`) no sample is measured: an alarm record
//! says so and [`Line::measure`] fails with an error that [`InspectError::is_disk_full`].

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use serde_json::{json, Value};

use super::plc::{self, LineState, PlcServer};
use super::recipe::{IndexMode, Recipe};
use super::retention;
use super::spc::{self, History, Point, Variable};
use super::status::{StatusBoard, StatusServer, DEFAULT_STALE_AFTER_S, SNAPSHOT_FILE};
use super::stream::{AckState, MqttPublisher, ResultsLog, Unsent};
use super::verdict::{self, Verdict};
use crate::estimate::{run_method, write_outputs_into, Run, RunConfig};
use crate::io::{counter_of, sample_id, utc_iso};
use crate::io::{write_atomic, Capture};
use crate::record::acquisition::AcquisitionLog;
use crate::rig::acquire::{open_sim_with, sim_options, Acquisition};
use crate::rig::config::SearchConfig;
use crate::rig::RigConfig;
use crate::source::{CaptureSource, DEFAULT_INDEX_RANGE};
use crate::summary::LineRecord;
use firmware_sim::line::SampleSequence;

/// An inspection that cannot go on: one line.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct InspectError(pub String);

/// How a disk-full error begins.
const DISK_FULL: &str = "disk full";
/// The error of a start-up a signal stopped.
const INTERRUPTED: &str = "stopped by a signal during start-up; nothing measured";

/// Samples whose latencies the closing summary's median and p95 are taken over (8 bytes
/// each: the window, not the run's length, bounds the memory).
const LATENCY_WINDOW: usize = 4096;

impl InspectError {
    /// Whether start-up was stopped by SIGINT/SIGTERM.
    pub fn is_interrupted(&self) -> bool {
        self.0 == INTERRUPTED
    }

    /// Whether the line stopped because its disk is full or below its free-space floor.
    pub fn is_disk_full(&self) -> bool {
        self.0.starts_with(DISK_FULL)
    }
}

/// Bytes free to an unprivileged writer on the file system holding `path`.
pub fn available_bytes(path: &Path) -> std::io::Result<u64> {
    let st = rustix::fs::statvfs(path)?;
    Ok(st.f_bavail.saturating_mul(st.f_frsize))
}

fn ie(what: &str) -> impl FnOnce(&dyn std::fmt::Display) -> InspectError + '_ {
    move |e| InspectError(format!("{what}: {e}"))
}

/// What `inspect` is told.
#[derive(Clone, Debug)]
pub struct InspectOptions {
    /// The rig.
    pub rig: RigConfig,
    /// The recipe.
    pub recipe: Recipe,
    /// The recipe's file (named in records).
    pub recipe_path: PathBuf,
    /// Output folder.
    pub out: PathBuf,
    /// Drive firmware-sim's line of samples.
    pub sim: bool,
    /// Status page port instead of the recipe's (0: any free one).
    pub status_port: Option<u16>,
    /// MQTT broker port instead of the recipe's.
    pub mqtt_port: Option<u16>,
    /// Modbus server address (`host:port`) instead of the recipe's, or without a
    /// `[modbus]` table.
    pub modbus: Option<String>,
    /// Set by SIGINT/SIGTERM: start-up stops between any two of its steps (and between
    /// any two sample folders it recovers) with an error that
    /// [`InspectError::is_interrupted`].
    pub stop: Arc<AtomicBool>,
}

/// One measured sample.
#[derive(Clone, Debug)]
pub struct SampleOutcome {
    /// Its record (the line of `results.jsonl`).
    pub record: Value,
    /// Alarm records it raised.
    pub alarms: Vec<Value>,
    /// Last row to verdict published (results.jsonl, MQTT queue, status page), ms.
    pub published_ms: f64,
    /// Its folder.
    pub folder: PathBuf,
}

/// The line.
pub struct Line {
    opts: InspectOptions,
    samples_dir: PathBuf,
    log: ResultsLog,
    logfile: File,
    history: History,
    counter: u64,
    last_index: Option<f64>,
    mqtt: Option<MqttPublisher>,
    status: Option<StatusServer>,
    /// What the status page shows, served or not; left in `DIR/status.json` after every
    /// sample.
    board: StatusBoard,
    sequence: Option<SampleSequence>,
    mqtt_down: bool,
    /// An alarm was raised for records the connected broker does not acknowledge.
    mqtt_stalled: bool,
    /// The `seq` of the last record appended to `results.jsonl`.
    seq: u64,
    plc: Option<PlcServer>,
    /// Records not yet appended (the disk was full), oldest first.
    unlogged: std::collections::VecDeque<Value>,
    /// Samples measured by this process.
    pub measured: u64,
    /// The last [`LATENCY_WINDOW`] samples' latencies, ms, oldest first (a line runs for
    /// months: the median and p95 are the recent ones').
    latencies_ms: std::collections::VecDeque<f64>,
    /// The longest latency since start, ms.
    latency_max_ms: f64,
    alarms_raised: u64,
    passed: u64,
    _lock: DirLock,
}

/// `DIR/inspect.lock`, holding the pid of the `inspect` that writes `DIR`; removed when the
/// line is dropped. A lock whose process is gone (a kill -9) is taken over.
struct DirLock(PathBuf);

impl Drop for DirLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn take_lock(out: &Path) -> Result<DirLock, InspectError> {
    let path = out.join("inspect.lock");
    let me = std::process::id();
    for _ in 0..2 {
        match OpenOptions::new().write(true).create_new(true).open(&path) {
            Ok(mut f) => {
                let _ = writeln!(f, "{me}");
                let _ = f.sync_all();
                return Ok(DirLock(path));
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                let pid = std::fs::read_to_string(&path)
                    .ok()
                    .and_then(|t| t.trim().parse::<u32>().ok());
                let alive = pid.is_some_and(|p| {
                    p != me
                        && std::fs::read(format!("/proc/{p}/cmdline"))
                            .is_ok_and(|c| String::from_utf8_lossy(&c).contains("inspect"))
                });
                if alive {
                    return Err(InspectError(format!(
                        "{}: another inspect (pid {}) writes this folder",
                        path.display(),
                        pid.unwrap_or(0)
                    )));
                }
                // Left by a process that is gone: take it over.
                let _ = std::fs::remove_file(&path);
            }
            Err(e) => return Err(ie(&path.display().to_string())(&e)),
        }
    }
    Err(InspectError(format!(
        "{}: cannot take the lock",
        path.display()
    )))
}

impl Line {
    /// Opens `opts.out`, recovering what a crash left, and starts the MQTT client and the
    /// status page the recipe names.
    pub fn open(opts: InspectOptions) -> Result<Self, InspectError> {
        let stop = opts.stop.clone();
        let go_on = || {
            if stop.load(Ordering::SeqCst) {
                Err(InspectError(INTERRUPTED.into()))
            } else {
                Ok(())
            }
        };
        go_on()?;
        let out = opts.out.clone();
        let samples_dir = out.join("samples");
        std::fs::create_dir_all(&samples_dir)
            .map_err(|e| ie(&samples_dir.display().to_string())(&e))?;
        let lock = take_lock(&out)?;
        go_on()?;
        let logpath = out.join("inspect.log");
        let logfile = OpenOptions::new()
            .append(true)
            .create(true)
            .open(&logpath)
            .map_err(|e| ie(&logpath.display().to_string())(&e))?;
        opts.recipe
            .check_sensor(
                opts.rig.camera.width as usize,
                opts.rig.camera.height as usize,
            )
            .map_err(|e| InspectError(format!("{}: {e}", opts.recipe_path.display())))?;
        let r = &opts.recipe.retention;
        // Read back from the end until a full history of samples is found.
        let (log, mut rec) = ResultsLog::open(
            &out,
            r.results_rotate_bytes,
            r.results_keep,
            opts.recipe.spc.history,
        )
        .map_err(|e| InspectError(e.to_string()))?;
        go_on()?;
        let mut line = Self {
            samples_dir,
            logfile,
            history: History::new(opts.recipe.spc.history),
            counter: 0,
            last_index: None,
            mqtt: None,
            status: None,
            board: StatusBoard::new(&opts.recipe.film),
            sequence: None,
            mqtt_down: false,
            mqtt_stalled: false,
            seq: rec.max_seq,
            plc: None,
            unlogged: std::collections::VecDeque::new(),
            measured: 0,
            latencies_ms: std::collections::VecDeque::new(),
            latency_max_ms: f64::NAN,
            alarms_raised: 0,
            passed: 0,
            log,
            _lock: lock,
            opts,
        };
        line.say(&format!(
            "start: {} record(s) read back{}{}",
            rec.read,
            if rec.torn_bytes > 0 {
                format!(", a torn last line of {} bytes cut", rec.torn_bytes)
            } else {
                String::new()
            },
            if rec.bad_lines > 0 {
                format!(", {} unreadable line(s) skipped", rec.bad_lines)
            } else {
                String::new()
            }
        ));
        let mut records = std::mem::take(&mut rec.records);
        line.counter = rec.max_counter;
        line.recover_folders(&mut records, &rec)?;
        go_on()?;
        for r in &records {
            if let Some(c) = r["counter"].as_u64() {
                line.counter = line.counter.max(c);
            }
            if r["kind"] == "sample" {
                line.push_history(r);
            }
        }
        // The page (and its snapshot) shows the last sample measured until a new one comes.
        if let Some(last) = records.iter().rev().find(|r| r["kind"] == "sample") {
            line.board.show_last(last, &out);
        }
        if line.opts.sim {
            let sim =
                line.opts.rig.sim.clone().ok_or_else(|| {
                    InspectError("--sim needs a [sim] table in the rig file".into())
                })?;
            let o = sim_options(&line.opts.rig, &sim.scene, sim.speed).map_err(InspectError)?;
            let s = &line.opts.recipe.sim;
            let mut seq = SampleSequence::new(o.scene, s.seed);
            seq.drift_nm_per_sample = s.drift_nm_per_sample;
            seq.defect_every = s.defect_every;
            line.sequence = Some(seq);
        }
        go_on()?;
        if let Some(mut m) = line.opts.recipe.mqtt.clone() {
            if let Some(p) = line.opts.mqtt_port {
                m.port = p;
            }
            line.start_mqtt(&m)?;
        }
        go_on()?;
        let modbus = match (&line.opts.recipe.modbus, &line.opts.modbus) {
            (_, Some(b)) => Some(b.clone()),
            (Some(mb), None) => Some(mb.bind.clone()),
            (None, None) => None,
        };
        if let Some(bind) = modbus {
            match PlcServer::start(&bind) {
                Ok(server) => {
                    line.say(&format!("modbus: listening on {}", server.addr()));
                    line.plc = Some(server);
                }
                Err(e) => {
                    line.say(&format!("stop: {e}"));
                    return Err(InspectError(e.to_string()));
                }
            }
        }
        let status = match (&line.opts.recipe.status, line.opts.status_port) {
            (Some(s), p) => Some((s.bind.clone(), p.unwrap_or(s.port), s.stale_after_s)),
            (None, Some(p)) => Some(("127.0.0.1".to_owned(), p, DEFAULT_STALE_AFTER_S)),
            (None, None) => None,
        };
        go_on()?;
        let stale_after_s = status.as_ref().map_or(DEFAULT_STALE_AFTER_S, |s| s.2);
        line.board.set_stale_after(stale_after_s);
        let recipe_file = line
            .opts
            .recipe_path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        line.board.set_labels(&line.opts.recipe.line, &recipe_file);
        line.refresh_status_history();
        if let Some((bind, port, _)) = status {
            match StatusServer::serve(&bind, port, line.board.clone()) {
                Ok(server) => {
                    line.say(&format!("status page: {}", server.url()));
                    line.status = Some(server);
                }
                // A page the recipe asks for and nobody could reach would go unnoticed.
                Err(e) => {
                    line.say(&format!("stop: {e}"));
                    return Err(InspectError(e.to_string()));
                }
            }
        }
        Ok(line)
    }

    /// The status page's URL, if served.
    pub fn status_url(&self) -> Option<String> {
        self.status.as_ref().map(StatusServer::url)
    }

    /// The Modbus server's address, if served.
    pub fn modbus_addr(&self) -> Option<std::net::SocketAddr> {
        self.plc.as_ref().map(PlcServer::addr)
    }

    /// Whether each sample waits for the PLC's trigger coil.
    pub fn waits_for_trigger(&self) -> bool {
        self.plc.is_some()
            && self
                .opts
                .recipe
                .modbus
                .as_ref()
                .is_some_and(|m| m.trigger == super::recipe::Trigger::Modbus)
    }

    /// Waits until a PLC sets the trigger coil (clearing it) or `stop` is set; whether the
    /// coil was set. Checks the broker's acknowledgements meanwhile.
    pub fn wait_for_trigger(&mut self, stop: &AtomicBool) -> bool {
        self.plc_update(|s| s.state = LineState::WaitingForTrigger);
        while !stop.load(Ordering::SeqCst) {
            if self.plc.as_ref().is_some_and(PlcServer::take_trigger) {
                return true;
            }
            self.check_mqtt();
            std::thread::sleep(Duration::from_millis(20));
        }
        false
    }

    /// Tells the PLC the line stops.
    pub fn stopped(&self) {
        self.plc_update(|s| s.state = LineState::Stopped);
    }

    fn plc_update(&self, f: impl FnOnce(&mut plc::Snapshot)) {
        if let Some(p) = &self.plc {
            p.update(f);
        }
    }

    /// Starts the MQTT client and hands it the records of `results.jsonl` the broker has
    /// not acknowledged (after the last stored acknowledgement).
    fn start_mqtt(&mut self, m: &super::recipe::MqttSpec) -> Result<(), InspectError> {
        let out = self.opts.out.clone();
        let acked = match AckState::load(&out).map_err(InspectError)? {
            Some(a) => a.acked_seq.min(self.seq),
            None => {
                // MQTT newly configured: the records before it are not sent.
                let a = AckState {
                    acked_seq: self.seq,
                };
                a.store(&out)
                    .map_err(|e| ie(&AckState::path_in(&out).display().to_string())(&e))?;
                a.acked_seq
            }
        };
        self.say(&format!(
            "mqtt: publishing to {}:{}{} under {}/ (sample, alarm, status)",
            m.host,
            m.port,
            if m.ca_file.is_some() { " over TLS" } else { "" },
            m.prefix
        ));
        let publisher = MqttPublisher::connect(m, &out, acked).map_err(InspectError)?;
        let r = &self.opts.recipe.retention;
        let (backlog, left_out) =
            super::stream::records_after(&out, r.results_keep, acked, m.spool_records)
                .map_err(|e| InspectError(e.to_string()))?;
        if !backlog.is_empty() {
            self.say(&format!(
                "mqtt: {} record(s) not acknowledged before the last stop queued again (seq {} to {}){}",
                backlog.len(),
                backlog.front().and_then(|r| r["seq"].as_u64()).unwrap_or(0),
                backlog.back().and_then(|r| r["seq"].as_u64()).unwrap_or(0),
                if left_out {
                    format!("; older ones beyond mqtt.spool_records = {} are not sent", m.spool_records)
                } else {
                    String::new()
                }
            ));
        }
        for r in &backlog {
            publisher.publish(r);
        }
        self.mqtt = Some(publisher);
        Ok(())
    }

    /// Why the broker refused the login, if it did.
    pub fn mqtt_refused(&self) -> Option<String> {
        self.mqtt.as_ref().and_then(MqttPublisher::refused)
    }

    /// Raises an alarm (once, until acknowledgements resume) when the connected broker
    /// leaves records unacknowledged beyond `mqtt.ack_timeout_s`.
    fn check_mqtt(&mut self) {
        self.check_mqtt_after(None);
    }

    /// [`Line::check_mqtt`] with records unacknowledged for longer than `after` (default
    /// `mqtt.ack_timeout_s`) counted.
    fn check_mqtt_after(&mut self, after: Option<Duration>) {
        let Some(m) = &self.mqtt else { return };
        let timeout = self
            .opts
            .recipe
            .mqtt
            .as_ref()
            .map_or(10.0, |s| s.ack_timeout_s);
        let refused = m.refused();
        match m.stalled(after.unwrap_or(Duration::from_secs_f64(timeout))) {
            Some((n, seq)) if !self.mqtt_stalled => {
                self.mqtt_stalled = true;
                let text = format!(
                    "the broker accepted the connection but has not acknowledged {n} record(s) (the oldest seq {seq}) within mqtt.ack_timeout_s = {timeout} s"
                );
                self.raise_alarm("mqtt", "no_acknowledgement", &text, json!(n));
                self.plc_update(|s| {
                    s.alarm_bits |= plc::alarm_bit::MQTT_UNACKNOWLEDGED;
                    s.last_error = plc::ErrorCode::MqttUnacknowledged;
                });
            }
            None if self.mqtt_stalled => {
                self.mqtt_stalled = false;
                self.say("mqtt: the broker acknowledges again");
                self.plc_update(|s| s.alarm_bits &= !plc::alarm_bit::MQTT_UNACKNOWLEDGED);
            }
            _ => {}
        }
        if refused.is_some() {
            self.plc_update(|s| {
                s.alarm_bits |= plc::alarm_bit::MQTT_REFUSED;
                s.last_error = plc::ErrorCode::MqttRefused;
            });
        }
    }

    /// An alarm record: of sample `sample_id` (null: of none) at the current counter, its
    /// `variable`, `rule`, `text` and `value`, then the `extra` fields of its rule.
    fn alarm_record(
        &self,
        sample_id: Value,
        variable: &str,
        rule: Value,
        text: &str,
        value: Value,
        extra: &[(&str, Value)],
    ) -> Value {
        let mut alarm = json!({
            "kind": "alarm",
            "sample_id": sample_id,
            "counter": self.counter,
            "timestamp": utc_iso(SystemTime::now()),
            "variable": variable,
            "rule": rule,
            "text": text,
            "value": value,
        });
        for (k, v) in extra {
            alarm[*k] = v.clone();
        }
        alarm
    }

    /// An alarm record of no sample: to `results.jsonl`, MQTT, the status page and the log.
    fn raise_alarm(&mut self, variable: &str, rule: &str, text: &str, value: Value) {
        let mut alarm = self.alarm_record(Value::Null, variable, json!(rule), text, value, &[]);
        self.say(&format!("alarm {text}"));
        if self.log_append(&mut alarm).is_ok() {
            self.publish(&alarm);
        }
        self.board.publish_alarm(&alarm);
        self.write_snapshot();
    }

    /// Leaves what the status page shows in `DIR/status.json` (for `filmscope status` once
    /// this process is gone); a failure is logged, not fatal to the sample.
    fn write_snapshot(&mut self) {
        if let Err(e) = self.board.write_snapshot(&self.opts.out) {
            self.say(&format!("status: {SNAPSHOT_FILE} not written: {e}"));
        }
    }

    /// Appends `record` to `results.jsonl` with the next `seq`.
    fn log_append(&mut self, record: &mut Value) -> Result<(), super::stream::StreamError> {
        record["seq"] = json!(self.seq + 1);
        self.log.append(record)?;
        self.seq += 1;
        Ok(())
    }

    /// The highest sample counter so far.
    pub fn counter(&self) -> u64 {
        self.counter
    }

    /// Appends a UTC-stamped line to `inspect.log` (and standard error).
    pub fn say(&mut self, text: &str) {
        let line = format!("{} {text}\n", utc_iso(SystemTime::now()));
        let _ = self.logfile.write_all(line.as_bytes());
        let _ = self.logfile.flush();
    }

    fn recover_folders(
        &mut self,
        records: &mut std::collections::VecDeque<Value>,
        rec: &super::stream::Recovered,
    ) -> Result<(), InspectError> {
        let mut names: Vec<String> = std::fs::read_dir(&self.samples_dir)
            .map_err(|e| ie(&self.samples_dir.display().to_string())(&e))?
            .flatten()
            .filter_map(|e| e.file_name().into_string().ok())
            .collect();
        names.sort();
        for n in names {
            if self.opts.stop.load(Ordering::SeqCst) {
                return Err(InspectError(INTERRUPTED.into()));
            }
            let p = self.samples_dir.join(&n);
            if n.starts_with(".tmp-") {
                let _ = std::fs::remove_dir_all(&p);
                self.say(&format!("recovered: removed the half-written {n}"));
                continue;
            }
            let Some(c) = counter_of(&n) else { continue };
            self.counter = self.counter.max(c);
            // Older than every record read back: logged (or rotated away) long ago.
            if rec.oldest_counter.is_some_and(|o| c < o) || rec.sample_counters.contains(&c) {
                continue;
            }
            match std::fs::read_to_string(p.join("record.json"))
                .ok()
                .and_then(|t| serde_json::from_str::<Value>(&t).ok())
            {
                Some(mut r) => {
                    self.log_append(&mut r)
                        .map_err(|e| InspectError(e.to_string()))?;
                    self.say(&format!("recovered: record of {n} appended"));
                    records.push_back(r);
                }
                None => self.say(&format!("recovered: {n} has no record.json; left as is")),
            }
        }
        Ok(())
    }

    fn push_history(&mut self, r: &Value) {
        let f = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
        let index = f(&r["refractive_index"]);
        if index.is_finite() {
            self.last_index = Some(index);
        }
        self.history.push(Point {
            sample_id: r["sample_id"].as_str().unwrap_or("").to_owned(),
            index,
            thickness_mean: f(&r["thickness_nm"]["mean"]),
            thickness_std: f(&r["thickness_nm"]["std"]),
            pass: r["verdict"] == "PASS",
        });
    }

    /// `/api/history`'s body: points, limits, capability, the recipe's limits.
    pub fn history_json(&self) -> Value {
        let s = &self.opts.recipe.spc;
        let [lsl, usl] = self.opts.recipe.thickness.limits();
        let ix = &self.opts.recipe.index;
        let mut limits = serde_json::Map::new();
        let mut cap = serde_json::Map::new();
        for v in Variable::ALL {
            limits.insert(
                v.name().into(),
                json!(spc::limits_of(&self.history, v, s.baseline, s.min_points)),
            );
        }
        let series = |v| self.history.series(v);
        cap.insert(
            Variable::ThicknessMeanNm.name().into(),
            json!(spc::capability(
                &series(Variable::ThicknessMeanNm),
                lsl,
                usl
            )),
        );
        cap.insert(
            Variable::RefractiveIndex.name().into(),
            json!(spc::capability(
                &series(Variable::RefractiveIndex),
                ix.nominal - ix.tolerance,
                ix.nominal + ix.tolerance
            )),
        );
        json!({
            "points": self.history.points().collect::<Vec<_>>(),
            "limits": limits,
            "capability": cap,
            "spec": {"lsl": lsl, "usl": usl, "index_lsl": ix.nominal - ix.tolerance, "index_usl": ix.nominal + ix.tolerance},
        })
    }

    fn refresh_status_history(&mut self) {
        let h = self.history_json();
        self.board.set_history(h);
    }

    /// Measures the next sample. Fails without measuring when the disk is below the
    /// recipe's free-space floor (after an alarm record) or records wait that still cannot
    /// be appended; a failure that a full disk caused is named as such.
    pub fn measure(&mut self) -> Result<SampleOutcome, InspectError> {
        self.plc_update(|s| s.state = LineState::Measuring);
        let r = self
            .check_free_space()
            .and_then(|()| self.append_unlogged().map_err(|e| self.name_disk_full(e)))
            .and_then(|()| self.measure_one().map_err(|e| self.name_disk_full(e)));
        self.check_mqtt();
        let disk = r.as_ref().err().is_some_and(InspectError::is_disk_full);
        match &r {
            Ok(o) => {
                let f = |v: &Value| v.as_f64().map_or(f32::NAN, |x| x as f32);
                let rec = &o.record;
                let alarms = !o.alarms.is_empty();
                self.plc_update(|s| {
                    s.state = LineState::Between;
                    s.counter = rec["counter"].as_u64().unwrap_or(0) as u32;
                    s.pass = Some(rec["verdict"] == "PASS");
                    s.thickness_nm = [
                        f(&rec["thickness_nm"]["mean"]),
                        f(&rec["thickness_nm"]["min"]),
                        f(&rec["thickness_nm"]["max"]),
                    ];
                    s.index_550 = f(&rec["refractive_index"]);
                    s.valid_fraction = f(&rec["valid_fraction"]);
                    s.alarm_bits &= !(plc::alarm_bit::RUN_RULE | plc::alarm_bit::DEVICE_ERROR);
                    if alarms {
                        s.alarm_bits |= plc::alarm_bit::RUN_RULE;
                    }
                });
            }
            Err(_) => self.plc_update(|s| {
                s.state = LineState::Between;
                if disk {
                    s.alarm_bits |= plc::alarm_bit::DISK_FLOOR;
                    s.last_error = plc::ErrorCode::DiskFull;
                } else {
                    s.alarm_bits |= plc::alarm_bit::DEVICE_ERROR;
                    s.last_error = plc::ErrorCode::Device;
                }
            }),
        }
        r
    }

    /// Refuses to measure below the free-space floor, with an alarm record.
    fn check_free_space(&mut self) -> Result<(), InspectError> {
        let floor = self.opts.recipe.retention.min_free_bytes;
        let free = match available_bytes(&self.opts.out) {
            Ok(f) => f,
            Err(e) => {
                self.say(&format!("retention: free space unknown: {e}"));
                return Ok(());
            }
        };
        if free >= floor {
            return Ok(());
        }
        let text = format!(
            "{DISK_FULL}: {} has {free} bytes free, below retention.min_free_bytes = {floor}; measuring stopped (free space, then restart)",
            self.opts.out.display()
        );
        let mut alarm = self.alarm_record(
            Value::Null,
            "disk_free_bytes",
            json!("free_space_floor"),
            &text,
            json!(free),
            &[("floor", json!(floor))],
        );
        self.say(&format!("alarm {text}"));
        self.plc_update(|s| {
            s.alarm_bits |= plc::alarm_bit::DISK_FLOOR;
            s.last_error = plc::ErrorCode::DiskFull;
        });
        if self.log_append(&mut alarm).is_ok() {
            self.publish(&alarm);
        }
        self.board.publish_alarm(&alarm);
        self.write_snapshot();
        Err(InspectError(text))
    }

    /// Appends the records a full disk held back, oldest first.
    fn append_unlogged(&mut self) -> Result<(), InspectError> {
        while let Some(mut r) = self.unlogged.front().cloned() {
            self.log_append(&mut r)
                .map_err(|e| InspectError(format!("records wait to be appended: {e}")))?;
            self.unlogged.pop_front();
            self.say(&format!(
                "recovered: record of {} appended",
                r["sample_id"].as_str().unwrap_or("?")
            ));
            self.publish(&r);
            if r["kind"] == "sample" {
                self.push_history(&r);
            }
        }
        Ok(())
    }

    /// Appends a record, or keeps it for later (and fails) when it cannot be appended.
    fn append_record(&mut self, record: &mut Value) -> Result<(), InspectError> {
        if !self.unlogged.is_empty() {
            self.unlogged.push_back(record.clone());
            return Err(InspectError(
                "records wait to be appended before this one".into(),
            ));
        }
        self.log_append(record).map_err(|e| {
            self.unlogged.push_back(record.clone());
            InspectError(e.to_string())
        })
    }

    /// `e`, named a disk-full error when the disk is full or below its floor.
    fn name_disk_full(&self, e: InspectError) -> InspectError {
        if e.is_disk_full() {
            return e;
        }
        let floor = self.opts.recipe.retention.min_free_bytes;
        let free = available_bytes(&self.opts.out).ok();
        let enospc = e.0.contains("os error 28") || e.0.contains("No space left");
        if enospc || free.is_some_and(|f| f < floor) {
            let free = free.map_or("an unknown number of".into(), |f| f.to_string());
            InspectError(format!(
                "{DISK_FULL}: {} has {free} bytes free (floor {floor}): {e}",
                self.opts.out.display()
            ))
        } else {
            e
        }
    }

    /// Measures the recipe's reference sample (`inspect --reference`, at the start of a
    /// shift): its maps into `references/<id>/`, a `reference` record (certified, measured,
    /// drift, within tolerance) to `results.jsonl`, MQTT (`<prefix>/reference`) and the
    /// status page, and an alarm when the drift is beyond tolerance. The reference is solved
    /// over the rig's whole index range, not held to the line's.
    pub fn check_reference(&mut self) -> Result<Value, InspectError> {
        let spec = self.opts.recipe.reference.clone().ok_or_else(|| {
            InspectError(format!(
                "{}: --reference needs a [reference] table (name, thickness_nm, index, tolerance_nm, tolerance_index)",
                self.opts.recipe_path.display()
            ))
        })?;
        self.check_free_space()?;
        let t = SystemTime::now();
        let stamp = sample_id(0, t);
        let id = format!("R{}", stamp.split_once('-').map_or("", |s| s.1));
        let dir = self.opts.out.join("references");
        let tmp = dir.join(format!(".tmp-{id}"));
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(&tmp).map_err(|e| ie(&tmp.display().to_string())(&e))?;
        let (run, _, _, _, _) = self.sweep(None, &tmp).inspect_err(|e| {
            let _ = std::fs::remove_dir_all(&tmp);
            self.say(&format!("device error: reference {}: {e}", spec.name));
        })?;
        write_outputs_into(&tmp, &run, &format!("inspect reference {}", spec.name))
            .map_err(|e| InspectError(e.to_string()))?;
        let _ = std::fs::remove_dir_all(tmp.join("capture"));
        let folder = dir.join(&id);
        let _ = std::fs::remove_dir_all(&folder);
        std::fs::rename(&tmp, &folder).map_err(|e| ie(&folder.display().to_string())(&e))?;
        let valid: Vec<f64> = run
            .result
            .thickness_nm
            .iter()
            .filter(|v| v.is_finite())
            .map(|&v| f64::from(v))
            .collect();
        let mean = valid.iter().sum::<f64>() / valid.len().max(1) as f64;
        let mean = if valid.is_empty() { f64::NAN } else { mean };
        let index = run.result.index.at(550.0);
        let (dd, dn) = (mean - spec.thickness_nm, index - spec.index);
        let within = dd.abs() <= spec.tolerance_nm && dn.abs() <= spec.tolerance_index;
        let recipe = &self.opts.recipe;
        let mut record = json!({
            "kind": "reference",
            "reference": spec.name,
            "reference_id": id,
            "timestamp": utc_iso(t),
            "lot": recipe.lot,
            "operator": recipe.operator,
            "certified": {"thickness_nm": spec.thickness_nm, "index": spec.index},
            "measured": {
                "thickness_nm": finite(mean),
                "index": finite(index),
                "valid_fraction": valid.len() as f64 / run.result.thickness_nm.len().max(1) as f64,
            },
            "drift": {"thickness_nm": finite(dd), "index": finite(dn)},
            "tolerance": {"thickness_nm": spec.tolerance_nm, "index": spec.tolerance_index},
            "within": within,
            "folder": format!("references/{id}"),
            "version": env!("CARGO_PKG_VERSION"),
        });
        self.append_record(&mut record)?;
        self.publish(&record);
        self.board.publish_reference(&record);
        self.say(&format!(
            "reference {}: thickness {mean:.2} nm (certified {}, drift {dd:+.2}), index {index:.4} (certified {}, drift {dn:+.4}): {}",
            spec.name,
            spec.thickness_nm,
            spec.index,
            if within { "within tolerance" } else { "BEYOND tolerance" }
        ));
        if !within {
            let text = format!(
                "reference {} drifted beyond tolerance: thickness {dd:+.2} nm (tolerance {}), index {dn:+.4} (tolerance {})",
                spec.name, spec.tolerance_nm, spec.tolerance_index
            );
            let mut alarm = self.alarm_record(
                Value::Null,
                "reference",
                json!("reference_drift"),
                &text,
                json!(finite(dd)),
                &[("index_drift", json!(finite(dn)))],
            );
            self.say(&format!("alarm {text}"));
            self.append_record(&mut alarm)?;
            self.publish(&alarm);
            self.board.publish_alarm(&alarm);
        }
        self.write_snapshot();
        Ok(record)
    }

    fn measure_one(&mut self) -> Result<SampleOutcome, InspectError> {
        self.counter += 1;
        let counter = self.counter;
        let t = SystemTime::now();
        let id = sample_id(counter, t);
        let timestamp = utc_iso(t);
        let tmp = self.samples_dir.join(format!(".tmp-{id}"));
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(&tmp).map_err(|e| ie(&tmp.display().to_string())(&e))?;
        let result = self.sweep(Some(counter), &tmp);
        let (run, last_row, acq_log, resolved, sim_kind) = match result {
            Ok(x) => x,
            Err(e) => {
                let _ = std::fs::remove_dir_all(&tmp);
                self.say(&format!("device error: sample {id}: {e}"));
                return Err(e);
            }
        };
        let recipe = &self.opts.recipe;
        let (w, h) = (run.spec.width, run.spec.height);
        let index = run.result.index.at(550.0);
        let v = verdict::judge(recipe, w, h, &run.result.thickness_nm, index);
        // The sample's folder is staged as a whole (renamed in when complete): the maps go
        // into it beside the sweep's capture.
        let mut summary = write_outputs_into(&tmp, &run, &format!("inspect sample {id}"))
            .map_err(|e| InspectError(e.to_string()))?;
        write_mask(&tmp, w, h, &v)?;
        let png = overlay_png(recipe, w, h, &run.result.thickness_nm, &v)?;
        let png_path = tmp.join("overlay.png");
        write_atomic(&png_path, &png).map_err(|e| ie(&png_path.display().to_string())(&e))?;
        let keep = retention::keeps_raw(&recipe.retention, counter, v.pass);
        let recipe_name = self
            .opts
            .recipe_path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut record = json!({
            "kind": "sample",
            "sample_id": id,
            "counter": counter,
            "timestamp": timestamp,
            "film": recipe.film,
            "recipe": recipe_name,
            "lot": recipe.lot,
            "operator": recipe.operator,
            "verdict": v.word(),
            "reasons": v.reasons,
            "refractive_index": finite(index),
            "index_mode": recipe.index.mode,
            "index_resolved": resolved,
            "thickness_nm": {
                "mean": finite(v.thickness.mean),
                "std": finite(v.thickness.std),
                "min": finite(v.thickness.min),
                "max": finite(v.thickness.max),
            },
            "valid_fraction": v.valid_fraction,
            "out_of_tolerance_px": v.out_of_tolerance_px,
            "regions": v.regions.iter().take(20).collect::<Vec<_>>(),
            "raw_kept": keep,
            "folder": format!("samples/{id}"),
            "version": env!("CARGO_PKG_VERSION"),
        });
        if let Some(k) = sim_kind {
            record["sim_sample"] = json!(k);
        }
        summary.timestamp = Some(timestamp.clone());
        summary.version = Some(env!("CARGO_PKG_VERSION").to_owned());
        summary.line = Some(LineRecord {
            sample_id: id.clone(),
            recipe: json!({"file": self.opts.recipe_path.display().to_string(), "film": recipe.film, "settings": recipe}),
            verdict: json!({"verdict": v.word(), "reasons": v.reasons, "thickness_nm": v.thickness,
                   "valid_fraction": v.valid_fraction, "judged_px": v.judged_px,
                   "out_of_tolerance_px": v.out_of_tolerance_px, "regions": v.regions,
                   "mask": "oot_mask.hdr", "overlay": "overlay.png"}),
        });
        summary.acquisition = Some(acq_log);
        summary.write(&tmp).map_err(InspectError)?;
        let capture = tmp.join("capture");
        if keep {
            retention::references_to_u16(&capture).map_err(InspectError)?;
        } else {
            let _ = std::fs::remove_dir_all(&capture);
        }
        let latency_ms = last_row.elapsed().as_secs_f64() * 1e3;
        record["latency_ms"] = json!(latency_ms);
        let rp = tmp.join("record.json");
        write_atomic(&rp, record.to_string().as_bytes())
            .map_err(|e| ie(&rp.display().to_string())(&e))?;
        let folder = self.samples_dir.join(&id);
        std::fs::rename(&tmp, &folder).map_err(|e| ie(&folder.display().to_string())(&e))?;
        sync_dir(&self.samples_dir);
        // The record, then the alarms, on disk and on the wire.
        self.append_record(&mut record)?;
        self.publish(&record);
        self.push_history(&record);
        let s = &self.opts.recipe.spc;
        let mut alarms = Vec::new();
        for a in spc::alarms(&self.history, s.baseline, s.min_points) {
            let mut rec = self.alarm_record(
                json!(id),
                a.variable.name(),
                json!(a.rule.number()),
                a.rule.text(),
                json!(finite(a.value)),
                &[
                    ("center", json!(a.limits.center)),
                    ("ucl", json!(a.limits.ucl)),
                    ("lcl", json!(a.limits.lcl)),
                ],
            );
            self.append_record(&mut rec)?;
            self.publish(&rec);
            alarms.push(rec);
        }
        let history = self.history_json();
        self.board
            .publish_sample(&record, Some(png), history, &alarms);
        let published_ms = last_row.elapsed().as_secs_f64() * 1e3;
        if self.latencies_ms.len() == LATENCY_WINDOW {
            self.latencies_ms.pop_front();
        }
        self.latencies_ms.push_back(published_ms);
        self.latency_max_ms = self.latency_max_ms.max(published_ms);
        self.measured += 1;
        self.passed += u64::from(v.pass);
        self.alarms_raised += alarms.len() as u64;
        self.write_snapshot();
        self.say(&format!(
            "sample {id} {} n={} thickness mean {:.1} std {:.2} min {:.1} max {:.1} nm valid {:.1}% latency {:.1} ms (verdict {:.1} ms){}{}",
            v.word(),
            fmt4(index),
            v.thickness.mean,
            v.thickness.std,
            v.thickness.min,
            v.thickness.max,
            100.0 * v.valid_fraction,
            published_ms,
            latency_ms,
            if resolved { " index re-solved" } else { "" },
            if v.reasons.is_empty() {
                String::new()
            } else {
                format!(": {}", v.reasons.join("; "))
            }
        ));
        for a in &alarms {
            self.say(&format!(
                "alarm {id} {} rule {}: {} (value {}, centre {:.4}, limits {:.4}..{:.4})",
                a["variable"].as_str().unwrap_or(""),
                a["rule"],
                a["text"].as_str().unwrap_or(""),
                a["value"],
                a["center"].as_f64().unwrap_or(f64::NAN),
                a["lcl"].as_f64().unwrap_or(f64::NAN),
                a["ucl"].as_f64().unwrap_or(f64::NAN)
            ));
        }
        if self.opts.recipe.retention.raw != super::recipe::RawPolicy::None {
            match retention::enforce_budget(
                &self.samples_dir,
                self.opts.recipe.retention.raw_budget_bytes,
            ) {
                Ok(gone) if !gone.is_empty() => {
                    self.say(&format!(
                        "retention: raw sweeps of {} deleted (budget)",
                        gone.join(", ")
                    ));
                }
                Ok(_) => {}
                Err(e) => self.say(&format!("retention: {e}")),
            }
        }
        Ok(SampleOutcome {
            record,
            alarms,
            published_ms,
            folder,
        })
    }

    fn publish(&mut self, record: &Value) {
        let Some(m) = self.mqtt.as_ref() else { return };
        m.publish(record);
        let err = m.take_error();
        let connected = m.connected();
        match err {
            Some(e) if !self.mqtt_down => {
                self.mqtt_down = true;
                self.say(&format!(
                    "mqtt: broker unreachable: {e} (records wait in the spool and results.jsonl)"
                ));
            }
            None if self.mqtt_down && connected => {
                self.mqtt_down = false;
                self.say("mqtt: broker reached again");
            }
            _ => {}
        }
    }

    /// The sweep of sample `counter` (`None`: the recipe's reference) into `tmp/capture`,
    /// estimated as it streams, with a re-solve over the whole index range when the held
    /// index disagrees (the reference is solved over the whole range at once).
    #[allow(clippy::type_complexity)]
    fn sweep(
        &mut self,
        counter: Option<u64>,
        tmp: &Path,
    ) -> Result<(Run, Instant, AcquisitionLog, bool, Option<&'static str>), InspectError> {
        let mut cfg = self.opts.rig.clone();
        let ix = &self.opts.recipe.index;
        let full = cfg
            .search
            .as_ref()
            .and_then(|s| s.index_range)
            .unwrap_or(DEFAULT_INDEX_RANGE);
        let centre = match (ix.mode, counter) {
            (_, None) | (IndexMode::Solve, _) => None,
            (IndexMode::Hold, _) => Some(ix.nominal),
            (IndexMode::Carry, _) => Some(self.last_index.unwrap_or(ix.nominal)),
        };
        if let Some(c) = centre {
            let lo = (c - ix.resolve_above).max(full[0]);
            let hi = (c + ix.resolve_above).min(full[1]);
            if lo < hi {
                let thick = cfg.search.as_ref().and_then(|s| s.thickness_range_nm);
                cfg.search = Some(SearchConfig {
                    index_range: Some([lo, hi]),
                    thickness_range_nm: thick,
                });
            }
        }
        let mut sim_kind = None;
        let mut _sim = None;
        let rig = if let Some(seq) = &self.sequence {
            let (scene, kind) = match counter {
                Some(c) => {
                    let (scene, kind) = seq.scene(c - 1);
                    (scene, kind.name())
                }
                None => (seq.reference(), "reference"),
            };
            sim_kind = Some(kind);
            let sim = cfg
                .sim
                .clone()
                .ok_or_else(|| InspectError("no [sim]".into()))?;
            let mut o = firmware_sim::serve::RigOptions::new(scene);
            o.speed = sim.speed;
            o.steps_per_deg = cfg.stage.steps_per_deg;
            o.stage_limits_deg = cfg.stage.limits_deg;
            let (sim_rig, rig) = open_sim_with(&mut cfg, o).map_err(InspectError)?;
            _sim = Some(sim_rig);
            rig
        } else {
            let wheel: Option<Box<dyn crate::rig::HidTransport + Send>> = match &cfg.wheel {
                Some(_) => Some(Box::new(
                    crate::rig::wheel::HidapiTransport::open().map_err(|e| ie("wheel")(&e))?,
                )),
                None => None,
            };
            crate::rig::open(&cfg, wheel).map_err(|e| InspectError(e.to_string()))?
        };
        let total = (cfg.sweep.angles_deg.len()
            * cfg.sweep.bands().len()
            * cfg.camera.height as usize) as u64;
        let capture_dir = tmp.join("capture");
        let mut acq = Acquisition::new(rig, cfg, &capture_dir).map_err(InspectError)?;
        let seen = AtomicU64::new(0);
        let last_row: Mutex<Option<Instant>> = Mutex::new(None);
        let on_rows = |n: u64| {
            if seen.fetch_add(n, Ordering::SeqCst) + n >= total {
                let mut l = last_row.lock().unwrap_or_else(|p| p.into_inner());
                l.get_or_insert_with(Instant::now);
            }
        };
        let run = run_method(&mut acq, &RunConfig::default(), &on_rows).map_err(|e| {
            InspectError(format!(
                "acquisition stopped: {e}; {} complete angle(s)",
                acq.log.angles_done_deg.len()
            ))
        })?;
        drop(_sim);
        let last = last_row
            .into_inner()
            .unwrap_or_else(|p| p.into_inner())
            .unwrap_or_else(Instant::now);
        let acq_log = acq.log.clone();
        drop(acq);
        let n = run.result.index.at(550.0);
        let disagree =
            centre.is_some_and(|c| !n.is_finite() || (n - c).abs() > ix.resolve_above / 2.0);
        if !disagree {
            return Ok((run, last, acq_log, false, sim_kind));
        }
        let mut cap = Capture::load(&capture_dir).map_err(|e| InspectError(e.to_string()))?;
        cap.search.index_range = Some(full);
        let mut src = CaptureSource::new(cap).map_err(|e| InspectError(e.to_string()))?;
        let run2 = run_method(&mut src, &RunConfig::default(), &|_| {})
            .map_err(|e| InspectError(format!("re-solve: {e}")))?;
        Ok((run2, last, acq_log, true, sim_kind))
    }

    /// Waits up to `mqtt.ack_timeout_s` for the broker to acknowledge every record; what
    /// is left unacknowledged (none: everything acknowledged, or no MQTT). Records a
    /// connected broker left unacknowledged raise an alarm.
    pub fn flush(&mut self) -> Option<Unsent> {
        let timeout = self.opts.recipe.mqtt.as_ref()?.ack_timeout_s;
        let left = self
            .mqtt
            .as_ref()?
            .flush(Duration::from_secs_f64(timeout))?;
        if left.connected && !self.mqtt_stalled {
            // The wait at exit was the timeout: whatever is still unacknowledged counts.
            self.check_mqtt_after(Some(Duration::ZERO));
        }
        Some(left)
    }

    /// What this process did, for the closing summary.
    pub fn summary(&self) -> Value {
        let mut l: Vec<f64> = self.latencies_ms.iter().copied().collect();
        l.sort_by(f64::total_cmp);
        let pct = |p: f64| {
            if l.is_empty() {
                Value::Null
            } else {
                json!(l[((l.len() - 1) as f64 * p).round() as usize])
            }
        };
        json!({
            "samples": self.measured,
            "passed": self.passed,
            "failed": self.measured - self.passed,
            "alarms": self.alarms_raised,
            "last_counter": self.counter,
            "latency_ms": {"median": pct(0.5), "p95": pct(0.95), "max": finite(self.latency_max_ms),
                           "over": format!("median and p95 of the last {} samples, max of all", l.len()),
                           "measured": "last row of the sweep to the verdict published (results.jsonl fsynced, MQTT queued, status page updated)"},
            "mqtt": self.mqtt.as_ref().map(|m| json!({"sent": m.sent(), "acked": m.acked()})),
            "status": self.status_url(),
            "out": self.opts.out.display().to_string(),
        })
    }
}

fn finite(v: f64) -> Value {
    if v.is_finite() {
        json!(v)
    } else {
        Value::Null
    }
}

fn fmt4(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else {
        "none".into()
    }
}

fn sync_dir(dir: &Path) {
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Writes `oot_mask.hdr`/`.img`: ENVI uint8 (data type 1), the verdict's mask.
fn write_mask(dir: &Path, w: usize, h: usize, v: &Verdict) -> Result<(), InspectError> {
    let img = dir.join("oot_mask.img");
    write_atomic(&img, &v.mask).map_err(|e| ie(&img.display().to_string())(&e))?;
    let hdr = format!(
        "ENVI\ndescription = {{\n  out-of-tolerance mask: 0=within 1=out of tolerance 2=no thickness 3=outside the regions of interest}}\nsamples = {w}\nlines = {h}\nbands = 1\nheader offset = 0\nfile type = ENVI Standard\ndata type = 1\ninterleave = bsq\nbyte order = 0\n"
    );
    let hp = dir.join("oot_mask.hdr");
    write_atomic(&hp, hdr.as_bytes()).map_err(|e| ie(&hp.display().to_string())(&e))
}

/// The thickness preview (viridis over the recipe's tolerance band) with out-of-tolerance
/// pixels in red, pixels without a thickness black and pixels outside the regions of
/// interest dimmed; 8x enlarged.
pub fn overlay_png(
    recipe: &Recipe,
    w: usize,
    h: usize,
    thickness: &[f32],
    v: &Verdict,
) -> Result<Vec<u8>, InspectError> {
    let [lo, hi] = recipe.thickness.limits();
    let rgb: Vec<[u8; 3]> = (0..w * h)
        .map(|i| {
            let t = f64::from(thickness.get(i).copied().unwrap_or(f32::NAN));
            let base = if t.is_finite() {
                crate::export::colormap::viridis(((t - lo) / (hi - lo)).clamp(0.0, 1.0))
            } else {
                [0, 0, 0]
            };
            match v.mask.get(i).copied().unwrap_or(verdict::MASK_IGNORED) {
                verdict::MASK_OUT => [230, 20, 20],
                verdict::MASK_IGNORED => base.map(|c| c / 3),
                _ => base,
            }
        })
        .collect();
    let scale = (320 / w.max(1)).clamp(1, 16);
    crate::export::png::render_rgb_png(w, h, &rgb, scale)
        .map_err(|e| InspectError(format!("overlay: {e}")))
}
