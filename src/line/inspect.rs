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

use std::collections::VecDeque;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use super::plc::{self, LineState, PlcServer};
use super::recipe::{IndexMode, Recipe};
use super::retention;
use super::spc::{self, History, Point};
use super::status::{HistoryBody, StatusBoard, StatusServer, DEFAULT_STALE_AFTER_S, SNAPSHOT_FILE};
use super::stream::{AckState, MqttPublisher, Recovered, ResultsLog, Unsent};
use super::verdict::{self, Verdict};
use crate::estimate::{write_outputs_into, Run};
use crate::io::{counter_of, sample_id, utc_iso};
use crate::io::{write_atomic, Capture};
use crate::jobs::{self, Observer, Quiet, Settings};
use crate::record::acquisition::AcquisitionLog;
use crate::record::finite;
use crate::record::line::{
    AlarmRecord, AlarmVariable, LineFault, Reading, Record, ReferenceRecord, SampleRecord,
};
use crate::rig::config::SearchConfig;
use crate::rig::sim::{open_sim_with, sim_options};
use crate::rig::RigConfig;
use crate::source::live::Acquisition;
use crate::source::{CaptureSource, DEFAULT_INDEX_RANGE};
use firmware_sim::line::{SampleKind, SampleSequence};

mod files;
mod lock;
mod records;

pub use files::overlay_png;
use files::write_mask;
use lock::{take_lock, DirLock};

/// An inspection that cannot go on: one line.
#[derive(Debug, thiserror::Error)]
pub enum InspectError {
    /// SIGINT or SIGTERM stopped the start-up.
    #[error("stopped by a signal during start-up; nothing measured")]
    Interrupted,
    /// The disk is full or below the recipe's free-space floor: measuring stops, no record
    /// is lost (those not appended wait in memory).
    #[error("disk full: {0}")]
    DiskFull(String),
    /// Anything else that stops the line (a recipe, a device, a file, a port), named.
    #[error("{0}")]
    Stopped(String),
}

/// Samples whose latencies the closing summary's median and p95 are taken over (8 bytes
/// each: the window, not the run's length, bounds the memory).
const LATENCY_WINDOW: usize = 4096;

impl InspectError {
    /// Whether start-up was stopped by SIGINT/SIGTERM.
    pub fn is_interrupted(&self) -> bool {
        matches!(self, Self::Interrupted)
    }

    /// Whether the line stopped because its disk is full or below its free-space floor.
    pub fn is_disk_full(&self) -> bool {
        matches!(self, Self::DiskFull(_))
    }
}

/// Bytes free to an unprivileged writer on the file system holding `path`.
pub fn available_bytes(path: &Path) -> std::io::Result<u64> {
    let st = rustix::fs::statvfs(path)?;
    Ok(st.f_bavail.saturating_mul(st.f_frsize))
}

fn ie(what: &str) -> impl FnOnce(&dyn std::fmt::Display) -> InspectError + '_ {
    move |e| InspectError::Stopped(format!("{what}: {e}"))
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
    pub record: SampleRecord,
    /// Alarm records it raised.
    pub alarms: Vec<AlarmRecord>,
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
    unlogged: VecDeque<Record>,
    /// Samples measured by this process.
    pub measured: u64,
    /// The last [`LATENCY_WINDOW`] samples' latencies, ms, oldest first (a line runs for
    /// months: the median and p95 are the recent ones').
    latencies_ms: VecDeque<f64>,
    /// The longest latency since start, ms.
    latency_max_ms: f64,
    alarms_raised: u64,
    passed: u64,
    _lock: DirLock,
}

/// A sample's sweep, estimated.
struct Swept {
    run: Run,
    /// When the sweep's last row arrived.
    last_row: Instant,
    /// What the acquisition did.
    log: AcquisitionLog,
    /// Whether a held index disagreed and the recorded sweep was solved again.
    resolved: bool,
    /// Which of firmware-sim's samples it was (`--sim`; none for the reference).
    sim: Option<SampleKind>,
}

/// What [`Line::open`] finds and takes in the output folder before anything else.
struct Opened {
    samples_dir: PathBuf,
    lock: DirLock,
    logfile: File,
    log: ResultsLog,
    recovered: Recovered,
}

/// Fails with the interrupted start-up's error once `stop` is set.
fn go_on(stop: &AtomicBool) -> Result<(), InspectError> {
    if stop.load(Ordering::SeqCst) {
        Err(InspectError::Interrupted)
    } else {
        Ok(())
    }
}

impl Opened {
    /// Takes `opts.out` (its lock and log) after checking the recipe fits the sensor, and
    /// reads the results log back from its end until a full history of samples is found.
    fn take(opts: &InspectOptions) -> Result<Self, InspectError> {
        let out = &opts.out;
        let samples_dir = out.join("samples");
        std::fs::create_dir_all(&samples_dir)
            .map_err(|e| ie(&samples_dir.display().to_string())(&e))?;
        let lock = take_lock(out)?;
        go_on(&opts.stop)?;
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
            .map_err(|e| InspectError::Stopped(format!("{}: {e}", opts.recipe_path.display())))?;
        let r = &opts.recipe.retention;
        let (log, recovered) = ResultsLog::open(
            out,
            r.results_rotate_bytes,
            r.results_keep,
            opts.recipe.spc.history,
        )
        .map_err(|e| InspectError::Stopped(e.to_string()))?;
        Ok(Self {
            samples_dir,
            lock,
            logfile,
            log,
            recovered,
        })
    }
}

impl Line {
    /// Opens `opts.out`, recovering what a crash left, and starts the MQTT client and the
    /// status page the recipe names.
    pub fn open(opts: InspectOptions) -> Result<Self, InspectError> {
        go_on(&opts.stop)?;
        let opened = Opened::take(&opts)?;
        go_on(&opts.stop)?;
        let mut rec = opened.recovered;
        let mut line = Self {
            samples_dir: opened.samples_dir,
            logfile: opened.logfile,
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
            unlogged: VecDeque::new(),
            measured: 0,
            latencies_ms: VecDeque::new(),
            latency_max_ms: f64::NAN,
            alarms_raised: 0,
            passed: 0,
            log: opened.log,
            _lock: opened.lock,
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
        go_on(&line.opts.stop)?;
        line.replay(&records);
        line.sequence = line.sim_sequence()?;
        go_on(&line.opts.stop)?;
        if let Some(mut m) = line.opts.recipe.mqtt.clone() {
            if let Some(p) = line.opts.mqtt_port {
                m.port = p;
            }
            line.start_mqtt(&m)?;
        }
        go_on(&line.opts.stop)?;
        line.start_modbus()?;
        line.start_status()?;
        Ok(line)
    }

    /// Takes up the records read back: the counter, the trend history and the index they
    /// reached; the page (and its snapshot) shows the last sample until a new one comes.
    fn replay(&mut self, records: &VecDeque<Record>) {
        for r in records {
            if let Some(c) = r.counter() {
                self.counter = self.counter.max(c);
            }
            if let Some(s) = r.as_sample() {
                self.push_history(s);
            }
        }
        if let Some(last) = records.iter().rev().find_map(Record::as_sample) {
            self.board.show_last(last, &self.opts.out);
        }
    }

    /// firmware-sim's line of samples (`--sim`), from the rig's `[sim]` scene and the
    /// recipe's `[sim]` settings.
    fn sim_sequence(&self) -> Result<Option<SampleSequence>, InspectError> {
        if !self.opts.sim {
            return Ok(None);
        }
        let sim = self.opts.rig.sim.clone().ok_or_else(|| {
            InspectError::Stopped("--sim needs a [sim] table in the rig file".into())
        })?;
        let o = sim_options(&self.opts.rig, &sim.scene, sim.speed)
            .map_err(|e| InspectError::Stopped(e.to_string()))?;
        let s = &self.opts.recipe.sim;
        let mut seq = SampleSequence::new(o.scene, s.seed);
        seq.drift_nm_per_sample = s.drift_nm_per_sample;
        seq.defect_every = s.defect_every;
        Ok(Some(seq))
    }

    /// Starts the Modbus server (`--modbus`, else the recipe's `[modbus]`), if any.
    fn start_modbus(&mut self) -> Result<(), InspectError> {
        let bind = match (&self.opts.recipe.modbus, &self.opts.modbus) {
            (_, Some(b)) => b.clone(),
            (Some(mb), None) => mb.bind.clone(),
            (None, None) => return Ok(()),
        };
        match PlcServer::start(&bind) {
            Ok(server) => {
                self.say(&format!("modbus: listening on {}", server.addr()));
                self.plc = Some(server);
                Ok(())
            }
            Err(e) => {
                self.say(&format!("stop: {e}"));
                Err(InspectError::Stopped(e.to_string()))
            }
        }
    }

    /// Labels the board and serves the status page (`--status-port`, else the recipe's
    /// `[status]`), if any.
    fn start_status(&mut self) -> Result<(), InspectError> {
        let status = match (&self.opts.recipe.status, self.opts.status_port) {
            (Some(s), p) => Some((s.bind.clone(), p.unwrap_or(s.port), s.stale_after_s)),
            (None, Some(p)) => Some(("127.0.0.1".to_owned(), p, DEFAULT_STALE_AFTER_S)),
            (None, None) => None,
        };
        go_on(&self.opts.stop)?;
        let stale_after_s = status.as_ref().map_or(DEFAULT_STALE_AFTER_S, |s| s.2);
        self.board.set_stale_after(stale_after_s);
        let recipe_file = self
            .opts
            .recipe_path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        self.board.set_labels(&self.opts.recipe.line, &recipe_file);
        self.refresh_status_history();
        let Some((bind, port, _)) = status else {
            return Ok(());
        };
        match StatusServer::serve(&bind, port, self.board.clone()) {
            Ok(server) => {
                self.say(&format!("status page: {}", server.url()));
                self.status = Some(server);
                Ok(())
            }
            // A page the recipe asks for and nobody could reach would go unnoticed.
            Err(e) => {
                self.say(&format!("stop: {e}"));
                Err(InspectError::Stopped(e.to_string()))
            }
        }
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
        let acked = match AckState::load(&out).map_err(|e| InspectError::Stopped(e.to_string()))? {
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
        let publisher = MqttPublisher::connect(m, &out, acked)
            .map_err(|e| InspectError::Stopped(e.to_string()))?;
        let r = &self.opts.recipe.retention;
        let (backlog, left_out) =
            super::stream::records_after(&out, r.results_keep, acked, m.spool_records)
                .map_err(|e| InspectError::Stopped(e.to_string()))?;
        if !backlog.is_empty() {
            self.say(&format!(
                "mqtt: {} record(s) not acknowledged before the last stop queued again (seq {} to {}){}",
                backlog.len(),
                backlog.front().and_then(Record::seq).unwrap_or(0),
                backlog.back().and_then(Record::seq).unwrap_or(0),
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
                let alarm = self.fault_alarm(
                    AlarmVariable::Mqtt,
                    LineFault::NoAcknowledgement,
                    text,
                    Some(Reading::Count(n as u64)),
                );
                self.raise_alarm(alarm);
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

    /// An alarm record of no sample: to `results.jsonl`, MQTT, the status page and the log.
    fn raise_alarm(&mut self, alarm: AlarmRecord) {
        self.say(&format!("alarm {}", alarm.text));
        let mut record = Record::Alarm(alarm);
        if self.log_append(&mut record).is_ok() {
            self.publish(&record);
        }
        if let Record::Alarm(a) = &record {
            self.board.publish_alarm(a);
        }
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
    fn log_append(&mut self, record: &mut Record) -> Result<(), super::stream::StreamError> {
        record.set_seq(self.seq + 1);
        self.log.append(record)?;
        self.seq += 1;
        Ok(())
    }

    /// The highest sample counter so far.
    pub fn counter(&self) -> u64 {
        self.counter
    }

    /// Appends a UTC-stamped line to `inspect.log`.
    pub fn say(&mut self, text: &str) {
        let line = format!("{} {text}\n", utc_iso(SystemTime::now()));
        let _ = self.logfile.write_all(line.as_bytes());
        let _ = self.logfile.flush();
    }

    fn recover_folders(
        &mut self,
        records: &mut VecDeque<Record>,
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
                return Err(InspectError::Interrupted);
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
                .and_then(|t| serde_json::from_str::<Record>(&t).ok())
            {
                Some(mut r) => {
                    self.log_append(&mut r)
                        .map_err(|e| InspectError::Stopped(e.to_string()))?;
                    self.say(&format!("recovered: record of {n} appended"));
                    records.push_back(r);
                }
                None => self.say(&format!("recovered: {n} has no record.json; left as is")),
            }
        }
        Ok(())
    }

    fn push_history(&mut self, r: &SampleRecord) {
        let point = Point::of(r);
        if point.index.is_finite() {
            self.last_index = Some(point.index);
        }
        self.history.push(point);
    }

    /// `/api/history`'s body: points, limits, capability, the recipe's limits.
    pub fn history_json(&self) -> serde_json::Value {
        HistoryBody::new(&self.history, &self.opts.recipe).to_value()
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
                let f = |v: Option<f64>| v.map_or(f32::NAN, |x| x as f32);
                let rec = &o.record;
                let alarms = !o.alarms.is_empty();
                self.plc_update(|s| {
                    s.state = LineState::Between;
                    s.counter = rec.counter as u32;
                    s.pass = Some(rec.verdict.passed());
                    s.thickness_nm = [
                        f(rec.thickness_nm.mean),
                        f(rec.thickness_nm.min),
                        f(rec.thickness_nm.max),
                    ];
                    s.index_550 = f(rec.refractive_index);
                    s.valid_fraction = rec.valid_fraction as f32;
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
        let reason = format!(
            "{} has {free} bytes free, below retention.min_free_bytes = {floor}; measuring stopped (free space, then restart)",
            self.opts.out.display()
        );
        let text = InspectError::DiskFull(reason.clone()).to_string();
        let alarm = AlarmRecord {
            floor: Some(floor),
            ..self.fault_alarm(
                AlarmVariable::DiskFreeBytes,
                LineFault::FreeSpaceFloor,
                text.clone(),
                Some(Reading::Count(free)),
            )
        };
        self.plc_update(|s| {
            s.alarm_bits |= plc::alarm_bit::DISK_FLOOR;
            s.last_error = plc::ErrorCode::DiskFull;
        });
        self.raise_alarm(alarm);
        Err(InspectError::DiskFull(reason))
    }

    /// Appends the records a full disk held back, oldest first.
    fn append_unlogged(&mut self) -> Result<(), InspectError> {
        while let Some(mut r) = self.unlogged.front().cloned() {
            self.log_append(&mut r)
                .map_err(|e| InspectError::Stopped(format!("records wait to be appended: {e}")))?;
            self.unlogged.pop_front();
            self.say(&format!(
                "recovered: record of {} appended",
                r.sample_id().unwrap_or("?")
            ));
            self.publish(&r);
            if let Some(s) = r.as_sample() {
                self.push_history(s);
            }
        }
        Ok(())
    }

    /// Appends a record and publishes it; its `seq`.
    fn append_and_publish(&mut self, mut record: Record) -> Result<Option<u64>, InspectError> {
        self.append_record(&mut record)?;
        self.publish(&record);
        Ok(record.seq())
    }

    /// Appends a record, or keeps it for later (and fails) when it cannot be appended.
    fn append_record(&mut self, record: &mut Record) -> Result<(), InspectError> {
        if !self.unlogged.is_empty() {
            self.unlogged.push_back(record.clone());
            return Err(InspectError::Stopped(
                "records wait to be appended before this one".into(),
            ));
        }
        self.log_append(record).map_err(|e| {
            self.unlogged.push_back(record.clone());
            InspectError::Stopped(e.to_string())
        })
    }

    /// `e`, named a disk-full error when the disk is full or below its floor.
    fn name_disk_full(&self, e: InspectError) -> InspectError {
        if e.is_disk_full() {
            return e;
        }
        let floor = self.opts.recipe.retention.min_free_bytes;
        let free = available_bytes(&self.opts.out).ok();
        let message = e.to_string();
        let enospc = message.contains("os error 28") || message.contains("No space left");
        if enospc || free.is_some_and(|f| f < floor) {
            let free = free.map_or("an unknown number of".into(), |f| f.to_string());
            InspectError::DiskFull(format!(
                "{} has {free} bytes free (floor {floor}): {e}",
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
    pub fn check_reference(&mut self) -> Result<ReferenceRecord, InspectError> {
        let spec = self.opts.recipe.reference.clone().ok_or_else(|| {
            InspectError::Stopped(format!(
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
        let Swept { run, .. } = self.sweep(None, &tmp).inspect_err(|e| {
            let _ = std::fs::remove_dir_all(&tmp);
            self.say(&format!("device error: reference {}: {e}", spec.name));
        })?;
        write_outputs_into(&tmp, &run, &format!("inspect reference {}", spec.name))
            .map_err(|e| InspectError::Stopped(e.to_string()))?;
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
        let mut record = self.reference_record(&spec, id, t, &run, mean, valid.len());
        let within = record.within;
        record.seq = self.append_and_publish(Record::Reference(record.clone()))?;
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
            let mut alarm = AlarmRecord {
                index_drift: Some(finite(dn)),
                ..self.fault_alarm(
                    AlarmVariable::Reference,
                    LineFault::ReferenceDrift,
                    text.clone(),
                    finite(dd).map(Reading::Real),
                )
            };
            self.say(&format!("alarm {text}"));
            alarm.seq = self.append_and_publish(Record::Alarm(alarm.clone()))?;
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
        let tmp = self.samples_dir.join(format!(".tmp-{id}"));
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(&tmp).map_err(|e| ie(&tmp.display().to_string())(&e))?;
        let swept = match self.sweep(Some(counter), &tmp) {
            Ok(x) => x,
            Err(e) => {
                let _ = std::fs::remove_dir_all(&tmp);
                // Every counter is accounted for in the log: this one by its alarm.
                let text = format!("device error: sample {id}: {e}; not measured");
                let alarm = AlarmRecord {
                    sample_id: Some(id),
                    ..self.fault_alarm(AlarmVariable::Device, LineFault::SampleFailed, text, None)
                };
                self.raise_alarm(alarm);
                return Err(e);
            }
        };
        let run = &swept.run;
        let index = run.result.index.at(550.0);
        let (w, h) = (run.spec.width, run.spec.height);
        let v = verdict::judge(&self.opts.recipe, w, h, &run.result.thickness_nm, index);
        let mut record = self.sample_record(&id, counter, t, &v, &swept);
        let png = self.stage_sample(&tmp, &swept, &v, &record)?;
        record.latency_ms = swept.last_row.elapsed().as_secs_f64() * 1e3;
        let rp = tmp.join("record.json");
        let text = crate::record::to_json(&record).map_err(|e| ie("record.json")(&e))?;
        write_atomic(&rp, text.as_bytes()).map_err(|e| ie(&rp.display().to_string())(&e))?;
        let folder = self.samples_dir.join(&id);
        std::fs::rename(&tmp, &folder).map_err(|e| ie(&folder.display().to_string())(&e))?;
        sync_dir(&self.samples_dir);
        // The record, then the alarms, on disk and on the wire.
        record.seq = self.append_and_publish(Record::Sample(Box::new(record.clone())))?;
        self.push_history(&record);
        let alarms = self.spc_alarms(&id)?;
        let history = self.history_json();
        self.board
            .publish_sample(&record, Some(png), history, &alarms);
        let published_ms = swept.last_row.elapsed().as_secs_f64() * 1e3;
        self.tally(published_ms, v.pass, alarms.len());
        self.write_snapshot();
        self.log_sample(&record, &v, published_ms, &alarms);
        self.enforce_raw_budget();
        Ok(SampleOutcome {
            record,
            alarms,
            published_ms,
            folder,
        })
    }

    /// Writes into the sample's staging folder `tmp` (renamed in when complete) its maps
    /// beside the sweep's capture, its `summary.json` with the line's record of it, the
    /// verdict's mask and overlay, and keeps its raw sweep (as uint16 references) or
    /// deletes it; the overlay PNG.
    fn stage_sample(
        &self,
        tmp: &Path,
        swept: &Swept,
        v: &Verdict,
        record: &SampleRecord,
    ) -> Result<Vec<u8>, InspectError> {
        let run = &swept.run;
        let (w, h) = (run.spec.width, run.spec.height);
        let label = format!("inspect sample {}", record.sample_id);
        let mut summary = write_outputs_into(tmp, run, &label)
            .map_err(|e| InspectError::Stopped(e.to_string()))?;
        write_mask(tmp, w, h, v)?;
        let png = overlay_png(&self.opts.recipe, w, h, &run.result.thickness_nm, v)?;
        let png_path = tmp.join("overlay.png");
        write_atomic(&png_path, &png).map_err(|e| ie(&png_path.display().to_string())(&e))?;
        self.complete_summary(&mut summary, record, v, swept.log.clone());
        summary
            .write(tmp)
            .map_err(|e| InspectError::Stopped(e.to_string()))?;
        let capture = tmp.join("capture");
        if record.raw_kept {
            retention::references_to_u16(&capture)
                .map_err(|e| InspectError::Stopped(e.to_string()))?;
        } else {
            let _ = std::fs::remove_dir_all(&capture);
        }
        Ok(png)
    }

    /// The control-chart alarms the newest sample, `id`, raises: appended and published.
    fn spc_alarms(&mut self, id: &str) -> Result<Vec<AlarmRecord>, InspectError> {
        let s = &self.opts.recipe.spc;
        let mut alarms = Vec::new();
        for a in spc::alarms(&self.history, s.baseline, s.min_points) {
            let mut alarm = self.spc_alarm_record(id, &a);
            alarm.seq = self.append_and_publish(Record::Alarm(alarm.clone()))?;
            alarms.push(alarm);
        }
        Ok(alarms)
    }

    /// Counts a sample published `published_ms` after its last row.
    fn tally(&mut self, published_ms: f64, pass: bool, alarms: usize) {
        if self.latencies_ms.len() == LATENCY_WINDOW {
            self.latencies_ms.pop_front();
        }
        self.latencies_ms.push_back(published_ms);
        self.latency_max_ms = self.latency_max_ms.max(published_ms);
        self.measured += 1;
        self.passed += u64::from(pass);
        self.alarms_raised += alarms as u64;
    }

    /// The sample's lines in `inspect.log`: its verdict and figures, then its alarms.
    fn log_sample(
        &mut self,
        r: &SampleRecord,
        v: &Verdict,
        published_ms: f64,
        alarms: &[AlarmRecord],
    ) {
        let id = &r.sample_id;
        self.say(&format!(
            "sample {id} {} n={} thickness mean {:.1} std {:.2} min {:.1} max {:.1} nm valid {:.1}% latency {:.1} ms (verdict {:.1} ms){}{}",
            v.word(),
            fmt4(r.refractive_index.unwrap_or(f64::NAN)),
            v.thickness.mean,
            v.thickness.std,
            v.thickness.min,
            v.thickness.max,
            100.0 * v.valid_fraction,
            published_ms,
            r.latency_ms,
            if r.index_resolved { " index re-solved" } else { "" },
            if v.reasons.is_empty() {
                String::new()
            } else {
                format!(": {}", v.reasons.join("; "))
            }
        ));
        for a in alarms {
            let f = |x: Option<f64>| x.unwrap_or(f64::NAN);
            self.say(&format!(
                "alarm {id} {} rule {}: {} (value {}, centre {:.4}, limits {:.4}..{:.4})",
                a.variable.name(),
                a.rule,
                a.text,
                a.value.map_or_else(|| "null".into(), |x| x.to_string()),
                f(a.center),
                f(a.lcl),
                f(a.ucl)
            ));
        }
    }

    /// Deletes the oldest raw sweeps beyond the recipe's budget (when any are kept).
    fn enforce_raw_budget(&mut self) {
        if self.opts.recipe.retention.raw == super::recipe::RawPolicy::None {
            return;
        }
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

    fn publish(&mut self, record: &Record) {
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
    fn sweep(&mut self, counter: Option<u64>, tmp: &Path) -> Result<Swept, InspectError> {
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
            let scene = match counter {
                Some(c) => {
                    let (scene, kind) = seq.scene(c - 1);
                    sim_kind = Some(kind);
                    scene
                }
                None => seq.reference(),
            };
            let sim = cfg
                .sim
                .clone()
                .ok_or_else(|| InspectError::Stopped("no [sim]".into()))?;
            let mut o = firmware_sim::serve::RigOptions::new(scene);
            o.speed = sim.speed;
            o.steps_per_deg = cfg.stage.steps_per_deg;
            o.stage_limits_deg = cfg.stage.limits_deg;
            let (sim_rig, rig) =
                open_sim_with(&mut cfg, o).map_err(|e| InspectError::Stopped(e.to_string()))?;
            _sim = Some(sim_rig);
            rig
        } else {
            let wheel: Option<Box<dyn crate::rig::HidTransport + Send>> = match &cfg.wheel {
                Some(_) => Some(Box::new(
                    crate::rig::wheel::HidapiTransport::open().map_err(|e| ie("wheel")(&e))?,
                )),
                None => None,
            };
            crate::rig::open(&cfg, wheel).map_err(|e| InspectError::Stopped(e.to_string()))?
        };
        let total = (cfg.sweep.angles_deg.len()
            * cfg.sweep.bands().len()
            * cfg.camera.height as usize) as u64;
        let capture_dir = tmp.join("capture");
        let mut acq = Acquisition::new(rig, cfg, &capture_dir)
            .map_err(|e| InspectError::Stopped(e.to_string()))?;
        let last_row = LastRow::new(total);
        let run = jobs::estimate::run(
            &mut acq,
            &Settings::default(),
            None,
            "acquisition",
            &last_row,
        )
        .map_err(|e| {
            let cause = e.cause();
            InspectError::Stopped(format!(
                "acquisition stopped: {cause}; {} complete angle(s)",
                acq.log.angles_done_deg.len()
            ))
        })?;
        drop(_sim);
        let last = last_row.at();
        let log = std::mem::take(&mut acq.log);
        drop(acq);
        let n = run.result.index.at(550.0);
        let disagree =
            centre.is_some_and(|c| !n.is_finite() || (n - c).abs() > ix.resolve_above / 2.0);
        let mut swept = Swept {
            run,
            last_row: last,
            log,
            resolved: false,
            sim: sim_kind,
        };
        if !disagree {
            return Ok(swept);
        }
        let mut cap =
            Capture::load(&capture_dir).map_err(|e| InspectError::Stopped(e.to_string()))?;
        cap.search.index_range = Some(full);
        let mut src = CaptureSource::new(cap).map_err(|e| InspectError::Stopped(e.to_string()))?;
        let label = capture_dir.display().to_string();
        swept.run = jobs::estimate::run(&mut src, &Settings::default(), None, &label, &Quiet)
            .map_err(|e| InspectError::Stopped(format!("re-solve: {e}")))?;
        swept.resolved = true;
        Ok(swept)
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

/// The estimator's observer in a sample's sweep: when the last row of the sweep went
/// through (the sample's latency runs from then).
struct LastRow {
    total: u64,
    seen: AtomicU64,
    at: Mutex<Option<Instant>>,
}

impl LastRow {
    fn new(total: u64) -> Self {
        Self {
            total,
            seen: AtomicU64::new(0),
            at: Mutex::new(None),
        }
    }

    /// When the last row went through (now, if it has not).
    fn at(&self) -> Instant {
        let at = self.at.lock().unwrap_or_else(|p| p.into_inner());
        at.unwrap_or_else(Instant::now)
    }
}

impl Observer for LastRow {
    fn rows(&self, n: u64) {
        if self.seen.fetch_add(n, Ordering::SeqCst) + n >= self.total {
            let mut at = self.at.lock().unwrap_or_else(|p| p.into_inner());
            at.get_or_insert_with(Instant::now);
        }
    }
}
