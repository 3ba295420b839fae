//! The result stream: `results.jsonl` (one JSON object a line, fsynced, rotated past a
//! size, rebuilt after a crash) and the same records published over MQTT.

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use rumqttc::{
    AsyncClient, ConnectionError, Event, EventLoop, LastWill, MqttOptions, Packet, QoS,
    TlsConfiguration, Transport,
};
use serde::Deserialize;

use super::recipe::MqttSpec;
use crate::record::line::Record;

/// A stream that cannot be written or published to.
#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    /// A file.
    #[error("{path}: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why (in the message, not a source: one line, said once).
        cause: std::io::Error,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> StreamError + '_ {
    move |cause| StreamError::Io {
        path: path.to_owned(),
        cause,
    }
}

/// The file a [`ResultsLog`] appends to: a [`File`] on a real line; tests inject one that
/// fails part-way through a write (a disk that fills).
pub trait LogFile: Write + Send {
    /// Flushes the data written to the device (`fsync`).
    fn sync_data(&mut self) -> std::io::Result<()>;
    /// Cuts (or extends) the file to `len` bytes.
    fn set_len(&mut self, len: u64) -> std::io::Result<()>;
}

impl LogFile for File {
    fn sync_data(&mut self) -> std::io::Result<()> {
        File::sync_data(self)
    }
    fn set_len(&mut self, len: u64) -> std::io::Result<()> {
        File::set_len(self, len)
    }
}

/// Opens the log file at a path for appending (creating it); [`ResultsLog::open`] uses
/// [`append_file`].
pub type Opener = Arc<dyn Fn(&Path) -> std::io::Result<Box<dyn LogFile>> + Send + Sync>;

/// Opens `path` for appending, creating it.
pub fn append_file(path: &Path) -> std::io::Result<Box<dyn LogFile>> {
    let f = OpenOptions::new().append(true).create(true).open(path)?;
    Ok(Box::new(f))
}

/// Whether `e` says the disk (or the user's quota) is full.
pub fn is_disk_full(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::StorageFull
        || e.kind() == std::io::ErrorKind::QuotaExceeded
        || e.raw_os_error() == Some(28)
}

/// `results.jsonl` in a folder, with its rotated predecessors `results.jsonl.1` (newest) to
/// `results.jsonl.K` (oldest).
pub struct ResultsLog {
    path: PathBuf,
    file: Box<dyn LogFile>,
    /// Bytes of whole lines: the length the file is cut back to after a failed append.
    size: u64,
    /// A failed append could not be cut back yet: cut before the next one.
    dirty: bool,
    rotate_bytes: u64,
    keep: usize,
    opener: Opener,
}

/// What [`ResultsLog::open`] read back: the newest records only, read from the end of the
/// files (never a whole file).
#[derive(Debug, Default)]
pub struct Recovered {
    /// The newest readable records, up to the number of sample records asked for, oldest
    /// first (the alarms among them included).
    pub records: std::collections::VecDeque<Record>,
    /// Records read back.
    pub read: usize,
    /// The highest `counter` of the records read back.
    pub max_counter: u64,
    /// The highest `seq` (the record's place in the log, counted from 1) read back.
    pub max_seq: u64,
    /// The counters of the sample records read back.
    pub sample_counters: std::collections::HashSet<u64>,
    /// The lowest `counter` of the records read back: every sample above it has its
    /// record among them unless it is missing from the log.
    pub oldest_counter: Option<u64>,
    /// Bytes of a torn last line cut off.
    pub torn_bytes: u64,
    /// Bytes read back from the results files (their tails, not the whole files).
    pub bytes_read: u64,
    /// Lines that were not records (skipped; the numbering of those that were JSON taken
    /// into account all the same).
    pub bad_lines: usize,
}

/// Bytes read at a time from the end of a results file.
const TAIL_CHUNK: u64 = 64 << 10;
/// A line longer than this is not a record (skipped as unreadable without being held).
const MAX_LINE: usize = 16 << 20;

impl ResultsLog {
    /// The log's path in `dir`.
    pub fn path_in(dir: &Path) -> PathBuf {
        dir.join("results.jsonl")
    }

    /// Opens (or creates) `dir/results.jsonl` for appending, cutting a torn last line (a
    /// write a crash interrupted), and reads back its newest records and, while fewer than
    /// `keep_samples` sample records are found, its rotations', newest first, each from
    /// its end.
    pub fn open(
        dir: &Path,
        rotate_bytes: u64,
        keep: usize,
        keep_samples: usize,
    ) -> Result<(Self, Recovered), StreamError> {
        Self::open_with(dir, rotate_bytes, keep, keep_samples, Arc::new(append_file))
    }

    /// [`ResultsLog::open`] appending through the files `opener` gives.
    pub fn open_with(
        dir: &Path,
        rotate_bytes: u64,
        keep: usize,
        keep_samples: usize,
        opener: Opener,
    ) -> Result<(Self, Recovered), StreamError> {
        let path = Self::path_in(dir);
        let mut rec = Recovered::default();
        let whole = {
            let mut f = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(io(&path))?;
            let len = f.metadata().map_err(io(&path))?.len();
            let whole = last_line_end(&mut f, len).map_err(io(&path))?;
            if whole < len {
                rec.torn_bytes = len - whole;
                f.set_len(whole).map_err(io(&path))?;
                f.sync_all().map_err(io(&path))?;
            }
            read_tail(&mut f, whole, &mut rec, keep_samples).map_err(io(&path))?;
            whole
        };
        for k in 1..=keep.max(1) {
            if rec.sample_counters.len() >= keep_samples {
                break;
            }
            let p = rotated(&path, k);
            let Ok(mut f) = File::open(&p) else { break };
            let len = f.metadata().map_err(io(&p))?.len();
            read_tail(&mut f, len, &mut rec, keep_samples).map_err(io(&p))?;
        }
        let file = opener(&path).map_err(io(&path))?;
        Ok((
            Self {
                path,
                file,
                size: whole,
                dirty: false,
                rotate_bytes,
                keep: keep.max(1),
                opener,
            },
            rec,
        ))
    }

    /// Appends one record as one line and fsyncs it; rotates first if the line would take
    /// the file past its size. An append that fails (a short write, a full disk) is cut
    /// back to the last whole line, so the next record starts a line of its own.
    pub fn append(&mut self, record: &Record) -> Result<(), StreamError> {
        if self.dirty {
            self.file.set_len(self.size).map_err(io(&self.path))?;
            self.dirty = false;
        }
        let mut line = record.to_line();
        line.push('\n');
        if self.size > 0 && self.size + line.len() as u64 > self.rotate_bytes {
            self.rotate()?;
        }
        let written = self
            .file
            .write_all(line.as_bytes())
            .and_then(|()| self.file.sync_data());
        if let Err(e) = written {
            // Roll back: whatever part of the line reached the file is cut off.
            if self.file.set_len(self.size).is_err() {
                self.dirty = true;
            } else {
                let _ = self.file.sync_data();
            }
            return Err(io(&self.path)(e));
        }
        self.size += line.len() as u64;
        Ok(())
    }

    fn rotate(&mut self) -> Result<(), StreamError> {
        let _ = std::fs::remove_file(rotated(&self.path, self.keep));
        for k in (1..self.keep).rev() {
            let from = rotated(&self.path, k);
            if from.exists() {
                std::fs::rename(&from, rotated(&self.path, k + 1)).map_err(io(&from))?;
            }
        }
        std::fs::rename(&self.path, rotated(&self.path, 1)).map_err(io(&self.path))?;
        self.file = (self.opener)(&self.path).map_err(io(&self.path))?;
        if let Some(dir) = self.path.parent() {
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
        }
        self.size = 0;
        Ok(())
    }
}

/// The `k`-th rotated file of the log at `path` (`results.jsonl.k`; larger k older).
pub(crate) fn rotated(path: &Path, k: usize) -> PathBuf {
    let mut s = path.as_os_str().to_owned();
    s.push(format!(".{k}"));
    PathBuf::from(s)
}

/// The length of `f`'s whole lines: up to and including its last newline (0 for none).
fn last_line_end(f: &mut File, len: u64) -> std::io::Result<u64> {
    let mut end = len;
    let mut buf = vec![0u8; TAIL_CHUNK as usize];
    while end > 0 {
        let n = end.min(TAIL_CHUNK);
        let start = end - n;
        f.seek(SeekFrom::Start(start))?;
        let chunk = buf.get_mut(..n as usize).unwrap_or_default();
        f.read_exact(chunk)?;
        if let Some(i) = chunk.iter().rposition(|&b| b == b'\n') {
            return Ok(start + i as u64 + 1);
        }
        end = start;
    }
    Ok(0)
}

/// Reads the lines of `f[..len]` from the end, newest first, into `rec` until it holds
/// `keep_samples` sample records or the file's start is reached.
fn read_tail(
    f: &mut File,
    len: u64,
    rec: &mut Recovered,
    keep_samples: usize,
) -> std::io::Result<()> {
    if rec.sample_counters.len() >= keep_samples {
        return Ok(());
    }
    let mut bytes = 0;
    let mut bad = 0;
    scan_back(f, len, &mut bytes, &mut bad, &mut |line| {
        take_line(line, rec);
        rec.sample_counters.len() < keep_samples
    })?;
    rec.bytes_read += bytes;
    rec.bad_lines += bad;
    Ok(())
}

/// Hands the lines of `f[..len]` to `visit` from the end, newest first, until it returns
/// false or the file's start is reached; a line longer than [`MAX_LINE`] is counted in
/// `bad_lines` without being held. Whether `visit` stopped it.
fn scan_back(
    f: &mut File,
    len: u64,
    bytes_read: &mut u64,
    bad_lines: &mut usize,
    visit: &mut dyn FnMut(&[u8]) -> bool,
) -> std::io::Result<bool> {
    let mut end = len;
    // The bytes after the chunk just read that begin a line not yet complete.
    let mut carry: Vec<u8> = Vec::new();
    let mut skipping = false;
    while end > 0 {
        let n = end.min(TAIL_CHUNK);
        let start = end - n;
        let mut chunk = vec![0u8; n as usize];
        f.seek(SeekFrom::Start(start))?;
        f.read_exact(&mut chunk)?;
        *bytes_read += n;
        chunk.extend_from_slice(&carry);
        let mut upto = chunk.len();
        // Every line that starts inside this chunk after a newline is complete.
        while let Some(i) = chunk
            .get(..upto)
            .and_then(|c| c.iter().rposition(|&b| b == b'\n'))
        {
            if skipping {
                skipping = false;
            } else if !visit(chunk.get(i + 1..upto).unwrap_or_default()) {
                return Ok(true);
            }
            upto = i;
        }
        carry = chunk.get(..upto).unwrap_or_default().to_vec();
        if carry.len() > MAX_LINE {
            // Not a record: skip to its start without holding it.
            *bad_lines += 1;
            carry.clear();
            skipping = true;
        }
        end = start;
    }
    if !skipping && !visit(&carry) {
        return Ok(true);
    }
    Ok(false)
}

/// The records of `dir/results.jsonl` and its rotations whose `seq` is above `after`,
/// oldest first, at most `max` of them (the newest); and whether older ones above `after`
/// were left out for that bound. Read from the end, so the cost follows what is returned.
pub fn records_after(
    dir: &Path,
    keep: usize,
    after: u64,
    max: usize,
) -> Result<(std::collections::VecDeque<Record>, bool), StreamError> {
    let path = ResultsLog::path_in(dir);
    let mut out = std::collections::VecDeque::new();
    let mut left_out = false;
    for k in 0..=keep.max(1) {
        let p = if k == 0 {
            path.clone()
        } else {
            rotated(&path, k)
        };
        let Ok(mut f) = File::open(&p) else { break };
        let len = f.metadata().map_err(io(&p))?.len();
        let (mut bytes, mut bad) = (0, 0);
        let stopped = scan_back(&mut f, len, &mut bytes, &mut bad, &mut |line| {
            if line.iter().all(u8::is_ascii_whitespace) {
                return true;
            }
            let Ok(head) = serde_json::from_slice::<Head>(line) else {
                return true;
            };
            // Records written before sequence numbers: older than any spool.
            let Some(seq) = head.seq else {
                return false;
            };
            if seq <= after {
                return false;
            }
            if out.len() >= max {
                left_out = true;
                return false;
            }
            // A line this version cannot read whole is not sent.
            if let Ok(r) = serde_json::from_slice::<Record>(line) {
                out.push_front(r);
            }
            true
        })
        .map_err(io(&p))?;
        if stopped {
            break;
        }
    }
    Ok((out, left_out))
}

/// What numbers a line of the log, read from any line that is a JSON object: a line that
/// is not a whole record (written by a later version, or damaged) still moves the
/// numbering on.
#[derive(Debug, Default, Deserialize)]
struct Head {
    /// The record's kind.
    #[serde(default)]
    kind: Option<HeadKind>,
    /// Its place in the log.
    #[serde(default)]
    seq: Option<u64>,
    /// Its sample counter.
    #[serde(default)]
    counter: Option<u64>,
}

/// A record's kind as [`Head`] reads it: samples are told from everything else.
#[derive(Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
enum HeadKind {
    Sample,
    #[serde(other)]
    Other,
}

impl From<&Record> for Head {
    fn from(r: &Record) -> Self {
        Self {
            kind: Some(match r {
                Record::Sample(_) => HeadKind::Sample,
                _ => HeadKind::Other,
            }),
            seq: r.seq(),
            counter: r.counter(),
        }
    }
}

/// One line read back (newest first): a record, or a JSON object that is not one (counted
/// as a bad line, its numbering kept), or neither (a bad line).
fn take_line(line: &[u8], rec: &mut Recovered) {
    if line.iter().all(u8::is_ascii_whitespace) {
        return;
    }
    let record = serde_json::from_slice::<Record>(line).ok();
    let head = match &record {
        Some(r) => Head::from(r),
        None => {
            rec.bad_lines += 1;
            match serde_json::from_slice::<Head>(line) {
                Ok(h) => h,
                Err(_) => return,
            }
        }
    };
    if let Some(q) = head.seq {
        rec.max_seq = rec.max_seq.max(q);
    }
    if let Some(c) = head.counter {
        rec.max_counter = rec.max_counter.max(c);
        rec.oldest_counter = Some(rec.oldest_counter.map_or(c, |o| o.min(c)));
        if head.kind == Some(HeadKind::Sample) {
            rec.sample_counters.insert(c);
        }
    }
    if let Some(r) = record {
        rec.read += 1;
        rec.records.push_front(r);
    }
}

/// The topic of records of `kind` (`sample`, `alarm`, `status`) under `prefix`.
pub fn topic(prefix: &str, kind: &str) -> String {
    format!("{prefix}/{kind}")
}

/// `DIR/mqtt-acked.json`: the `seq` up to which the broker acknowledged every record.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize, PartialEq, Eq)]
pub struct AckState {
    /// Every record with a `seq` up to this one was acknowledged.
    pub acked_seq: u64,
}

impl AckState {
    /// The file in `dir`.
    pub fn path_in(dir: &Path) -> PathBuf {
        dir.join("mqtt-acked.json")
    }

    /// Reads it (none: no such file; an unreadable one is an error naming it).
    pub fn load(dir: &Path) -> Result<Option<Self>, crate::record::RecordError> {
        use crate::record::RecordError;
        let p = Self::path_in(dir);
        match crate::limits::read_small(&p, 4096) {
            Ok(t) => serde_json::from_str(&t)
                .map(Some)
                .map_err(|e| RecordError::new(&p, e)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(RecordError::new(&p, e)),
        }
    }

    /// Writes it (atomically).
    pub fn store(&self, dir: &Path) -> std::io::Result<()> {
        let text = serde_json::to_string(self).unwrap_or_default();
        crate::io::write_atomic(&Self::path_in(dir), text.as_bytes())
    }
}

/// Records waiting for the broker's acknowledgement, shared by the line and the MQTT
/// thread.
struct Spool {
    /// Unacknowledged records (and acknowledged ones behind an older unacknowledged one),
    /// `seq` ascending.
    entries: std::collections::VecDeque<Entry>,
    capacity: usize,
    /// Every record up to this `seq` is acknowledged.
    acked_seq: u64,
    /// The oldest record dropped unacknowledged (the spool was full): `acked_seq` stays
    /// below it so that the next start sends it from the log.
    dropped: Option<u64>,
    /// Records dropped unacknowledged.
    dropped_n: u64,
    /// Whether `acked_seq` changed since it was last stored.
    dirty: bool,
    connected: bool,
    refused: Option<String>,
    last_error: Option<String>,
    queued: u64,
    acked: u64,
    /// `seq` of each publish handed to rumqttc whose packet id is not known yet (0: the
    /// status message), in the order handed.
    requested: std::collections::VecDeque<u64>,
    /// Packet id to `seq` of the publishes on the wire.
    in_flight: std::collections::HashMap<u16, u64>,
}

struct Entry {
    seq: u64,
    topic: String,
    payload: Vec<u8>,
    retain: bool,
    sent: Option<Instant>,
    acked: bool,
}

impl Spool {
    fn lock(s: &Mutex<Spool>) -> std::sync::MutexGuard<'_, Spool> {
        s.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The connection is gone (or new): no publish is on the wire any more.
    fn forget_wire(&mut self) {
        self.requested.clear();
        self.in_flight.clear();
        for e in self.entries.iter_mut() {
            e.sent = None;
        }
    }

    /// Moves `acked_seq` past the acknowledged records at the front.
    fn advance(&mut self) {
        while self.entries.front().is_some_and(|e| e.acked) {
            if let Some(e) = self.entries.pop_front() {
                if self.dropped.is_none_or(|d| e.seq < d) && e.seq > self.acked_seq {
                    self.acked_seq = e.seq;
                    self.dirty = true;
                }
            }
        }
    }
}

/// What is left at exit.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Unsent {
    /// Records not acknowledged.
    pub records: u64,
    /// The lowest `seq` among them.
    pub first_seq: u64,
    /// Whether the broker was connected (so it accepted the connection but did not
    /// acknowledge).
    pub connected: bool,
}

/// Records in flight at once (below rumqttc's limit of 100, so its queue never blocks).
const WINDOW: usize = 64;

/// Publishes records to an MQTT broker, QoS 1, on topics under the recipe's prefix, and
/// keeps every record until the broker acknowledges it: a record is resent after each
/// reconnection until acknowledged, and `DIR/mqtt-acked.json` remembers how far the
/// acknowledgements reached, so a restart sends the rest from `results.jsonl`. Announces
/// `online` on `<prefix>/status` (retained) with `offline` as its last will.
pub struct MqttPublisher {
    spool: Arc<Mutex<Spool>>,
    stop: Arc<AtomicBool>,
    wake: Arc<tokio::sync::Notify>,
    halt: Arc<tokio::sync::Notify>,
    thread: Option<JoinHandle<()>>,
    prefix: String,
}

/// Why the MQTT client could not start.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    /// Its TLS settings cannot be used.
    #[error(transparent)]
    Tls(#[from] super::tls::TlsError),
    /// No thread for it.
    #[error("mqtt: no thread: {0}")]
    Thread(std::io::Error),
}

impl MqttPublisher {
    /// Connects in the background to the broker of `spec` (TLS, credentials, last will),
    /// `dir` holding the acknowledgement state; publishing starts at once (records wait in
    /// the spool until the broker is reached). `acked_seq` is where the stored
    /// acknowledgements reached.
    pub fn connect(spec: &MqttSpec, dir: &Path, acked_seq: u64) -> Result<Self, ConnectError> {
        let mut o = MqttOptions::new(spec.client_id.clone(), spec.host.clone(), spec.port);
        o.set_keep_alive(Duration::from_secs(15));
        o.set_max_packet_size(1 << 20, 1 << 20);
        o.set_clean_session(true);
        let status = topic(&spec.prefix, "status");
        o.set_last_will(LastWill::new(
            status.clone(),
            "offline",
            QoS::AtLeastOnce,
            true,
        ));
        if let Some(u) = &spec.username {
            o.set_credentials(u.clone(), spec.password.clone().unwrap_or_default());
        }
        if let Some(ca) = &spec.ca_file {
            let client = spec
                .client_cert_file
                .as_deref()
                .zip(spec.client_key_file.as_deref());
            let tls = super::tls::client_config(ca, client)?;
            o.set_transport(Transport::Tls(TlsConfiguration::Rustls(tls)));
        }
        let (client, events) = AsyncClient::new(o, 2 * WINDOW);
        let spool = Arc::new(Mutex::new(Spool {
            entries: std::collections::VecDeque::new(),
            capacity: spec.spool_records.max(1),
            acked_seq,
            dropped: None,
            dropped_n: 0,
            dirty: false,
            connected: false,
            refused: None,
            last_error: None,
            queued: 0,
            acked: 0,
            requested: std::collections::VecDeque::new(),
            in_flight: std::collections::HashMap::new(),
        }));
        let stop = Arc::new(AtomicBool::new(false));
        let wake = Arc::new(tokio::sync::Notify::new());
        let halt = Arc::new(tokio::sync::Notify::new());
        let worker = Worker {
            client,
            spool: spool.clone(),
            stop: stop.clone(),
            wake: wake.clone(),
            halt: halt.clone(),
            dir: dir.to_owned(),
            status,
        };
        let thread = std::thread::Builder::new()
            .name("mqtt".into())
            .spawn(move || worker.run(events))
            .map_err(ConnectError::Thread)?;
        Ok(Self {
            spool,
            stop,
            wake,
            halt,
            thread: Some(thread),
            prefix: spec.prefix.clone(),
        })
    }

    /// Queues one record of `results.jsonl` (with its `seq`) on the topic of its kind
    /// (never blocks). A full spool drops its oldest record, which the next start sends.
    pub fn publish(&self, record: &Record) {
        let Some(seq) = record.seq() else {
            return;
        };
        let kind = record.kind();
        let mut s = Spool::lock(&self.spool);
        if seq <= s.acked_seq || s.entries.back().is_some_and(|e| e.seq >= seq) {
            return;
        }
        if s.entries.len() >= s.capacity {
            if let Some(e) = s.entries.pop_front() {
                if !e.acked {
                    s.dropped = Some(s.dropped.map_or(e.seq, |d| d.min(e.seq)));
                    s.dropped_n += 1;
                }
            }
        }
        s.entries.push_back(Entry {
            seq,
            topic: topic(&self.prefix, kind),
            payload: record.to_line().into_bytes(),
            retain: kind == "sample",
            sent: None,
            acked: false,
        });
        s.queued += 1;
        drop(s);
        self.wake.notify_one();
    }

    /// Records queued by this process.
    pub fn sent(&self) -> u64 {
        Spool::lock(&self.spool).queued
    }

    /// Records the broker acknowledged in this process.
    pub fn acked(&self) -> u64 {
        Spool::lock(&self.spool).acked
    }

    /// Whether the broker accepted the connection (and it has not failed since).
    pub fn connected(&self) -> bool {
        Spool::lock(&self.spool).connected
    }

    /// The last connection error, taken.
    pub fn take_error(&self) -> Option<String> {
        Spool::lock(&self.spool).last_error.take()
    }

    /// Why the broker refused the connection (bad user name or password, not
    /// authorised), if it did.
    pub fn refused(&self) -> Option<String> {
        Spool::lock(&self.spool).refused.clone()
    }

    /// Records a connected broker has left unacknowledged for longer than `timeout`: their
    /// number and the oldest one's `seq`.
    pub fn stalled(&self, timeout: Duration) -> Option<(usize, u64)> {
        let s = Spool::lock(&self.spool);
        if !s.connected {
            return None;
        }
        let old = s
            .entries
            .iter()
            .filter(|e| !e.acked && e.sent.is_some_and(|t| t.elapsed() > timeout));
        let n = old.clone().count();
        old.map(|e| e.seq).min().map(|seq| (n, seq))
    }

    /// Waits up to `timeout` for the broker to acknowledge every record (returning early
    /// when it refused the connection); what is left.
    pub fn flush(&self, timeout: Duration) -> Option<Unsent> {
        let t0 = Instant::now();
        loop {
            {
                let s = Spool::lock(&self.spool);
                let left = s.entries.iter().filter(|e| !e.acked);
                let first = left.clone().map(|e| e.seq).chain(s.dropped).min();
                match first {
                    None => return None,
                    Some(first_seq) if t0.elapsed() > timeout || s.refused.is_some() => {
                        return Some(Unsent {
                            records: left.count() as u64 + s.dropped_n,
                            first_seq,
                            connected: s.connected,
                        });
                    }
                    Some(_) => {}
                }
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for MqttPublisher {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        self.wake.notify_one();
        self.halt.notify_one();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The MQTT thread: a single-threaded tokio runtime with two tasks, one driving
/// rumqttc's event loop (its `poll` is never cancelled while the client runs: a poll cut
/// short in the middle of a connection drops it), one handing it the spool's records while
/// connected. Packet ids are mapped to records in the order the publishes were handed over;
/// the two tasks interleave only at their awaits, so a disconnection is handled whole
/// before any record is handed over again.
struct Worker {
    client: AsyncClient,
    spool: Arc<Mutex<Spool>>,
    stop: Arc<AtomicBool>,
    wake: Arc<tokio::sync::Notify>,
    /// Notified once, at the stop.
    halt: Arc<tokio::sync::Notify>,
    dir: PathBuf,
    status: String,
}

impl Worker {
    fn run(self, mut events: EventLoop) {
        let Ok(rt) = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        else {
            Spool::lock(&self.spool).last_error = Some("mqtt: no runtime".into());
            return;
        };
        rt.block_on(async move {
            let me = Arc::new(self);
            let sender = {
                let me = me.clone();
                tokio::spawn(async move {
                    while !me.stop.load(Ordering::SeqCst) {
                        me.send();
                        tokio::select! {
                            _ = me.wake.notified() => {}
                            _ = tokio::time::sleep(Duration::from_millis(50)) => {}
                        }
                    }
                })
            };
            loop {
                let ev = tokio::select! {
                    ev = events.poll() => ev,
                    _ = me.halt.notified() => break,
                };
                let failed = ev.is_err();
                me.handle(ev);
                me.store();
                if failed {
                    tokio::time::sleep(Duration::from_millis(300)).await;
                }
            }
            let _ = sender.await;
            // A clean stop: `offline` (retained), then the disconnect; the will is for a crash.
            if Spool::lock(&me.spool).connected {
                let _ = me
                    .client
                    .try_publish(me.status.clone(), QoS::AtLeastOnce, true, "offline");
                let _ = me.client.try_disconnect();
                let _ = tokio::time::timeout(Duration::from_millis(500), async {
                    loop {
                        match events.poll().await {
                            Ok(Event::Outgoing(rumqttc::Outgoing::Disconnect)) | Err(_) => break,
                            ev => me.handle(ev),
                        }
                    }
                })
                .await;
            }
            me.store();
        });
    }

    /// Hands rumqttc the records not on the wire, oldest first, while connected.
    fn send(&self) {
        let mut guard = Spool::lock(&self.spool);
        let s = &mut *guard;
        if !s.connected {
            return;
        }
        let room = WINDOW.saturating_sub(s.requested.len() + s.in_flight.len());
        for e in s
            .entries
            .iter_mut()
            .filter(|e| !e.acked && e.sent.is_none())
            .take(room)
        {
            let r = self.client.try_publish(
                e.topic.clone(),
                QoS::AtLeastOnce,
                e.retain,
                e.payload.clone(),
            );
            if r.is_err() {
                break;
            }
            e.sent = Some(Instant::now());
            s.requested.push_back(e.seq);
        }
    }

    fn handle(&self, ev: Result<Event, ConnectionError>) {
        let mut guard = Spool::lock(&self.spool);
        let s = &mut *guard;
        match ev {
            Ok(Event::Outgoing(rumqttc::Outgoing::Publish(pkid))) => {
                if let Some(seq) = s.requested.pop_front() {
                    if seq > 0 {
                        s.in_flight.insert(pkid, seq);
                    }
                }
            }
            Ok(Event::Incoming(Packet::PubAck(ack))) => {
                if let Some(seq) = s.in_flight.remove(&ack.pkid) {
                    if let Some(e) = s.entries.iter_mut().find(|e| e.seq == seq && !e.acked) {
                        e.acked = true;
                        s.acked += 1;
                    }
                    s.advance();
                }
            }
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                // A clean start: whatever was on the wire is sent again.
                s.forget_wire();
                s.connected = true;
                s.refused = None;
                if self
                    .client
                    .try_publish(self.status.clone(), QoS::AtLeastOnce, true, "online")
                    .is_ok()
                {
                    s.requested.push_back(0);
                }
                drop(guard);
                self.wake.notify_one();
            }
            Ok(_) => {}
            Err(err) => {
                s.forget_wire();
                s.connected = false;
                if let ConnectionError::ConnectionRefused(code) = &err {
                    s.refused = Some(format!("the broker refused the connection: {code:?}"));
                }
                s.last_error = Some(err.to_string());
            }
        }
    }

    /// Stores the acknowledgement state when it moved.
    fn store(&self) {
        let state = {
            let mut s = Spool::lock(&self.spool);
            if !s.dirty {
                return;
            }
            s.dirty = false;
            AckState {
                acked_seq: s.acked_seq,
            }
        };
        if let Err(e) = state.store(&self.dir) {
            Spool::lock(&self.spool).last_error =
                Some(format!("{}: {e}", AckState::path_in(&self.dir).display()));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::line::{AlarmRecord, SampleRecord};
    use std::sync::atomic::AtomicU64;

    /// The record of sample `counter`, not numbered.
    fn sample(counter: u64) -> Record {
        Record::Sample(Box::new(SampleRecord::example(counter)))
    }

    /// The record of sample `counter` at place `seq` in the log.
    fn numbered(counter: u64, seq: u64) -> Record {
        let mut r = sample(counter);
        r.set_seq(seq);
        r
    }

    fn counters(records: &std::collections::VecDeque<Record>) -> Vec<u64> {
        records.iter().filter_map(Record::counter).collect()
    }

    #[test]
    fn torn_last_line_is_cut_and_appending_goes_on() {
        let dir = tempfile::tempdir().expect("dir");
        let p = ResultsLog::path_in(dir.path());
        let (one, two) = (sample(1).to_line(), sample(2).to_line());
        std::fs::write(&p, format!("{one}\n{two}\n{{\"kind\":")).expect("write");
        let (mut log, rec) = ResultsLog::open(dir.path(), 1 << 20, 2, 100).expect("open");
        assert_eq!(counters(&rec.records), vec![1, 2]);
        assert_eq!(rec.torn_bytes, 8);
        log.append(&sample(3)).expect("append");
        let text = std::fs::read_to_string(&p).expect("read");
        assert_eq!(text, format!("{one}\n{two}\n{}\n", sample(3).to_line()));
    }

    /// A line that is JSON but no record this version reads is skipped and counted, its
    /// numbering kept; a line that is not JSON is skipped and counted.
    #[test]
    fn a_line_that_is_not_a_record_is_skipped_and_its_numbering_kept() {
        let dir = tempfile::tempdir().expect("dir");
        let p = ResultsLog::path_in(dir.path());
        let lines = [
            numbered(1, 1).to_line(),
            r#"{"kind":"sample","seq":2,"counter":2,"from":"a later version"}"#.to_owned(),
            "not json".to_owned(),
            numbered(3, 4).to_line(),
        ];
        std::fs::write(&p, lines.join("\n") + "\n").expect("write");
        let (_, rec) = ResultsLog::open(dir.path(), 1 << 20, 2, 100).expect("open");
        assert_eq!(counters(&rec.records), vec![1, 3]);
        assert_eq!((rec.read, rec.bad_lines, rec.max_seq), (2, 2, 4));
        assert!(rec.sample_counters.contains(&2), "numbered though not read");
    }

    /// A file on a disk with `room` bytes left: a write past it is cut short, the next one
    /// fails with ENOSPC.
    struct FillingDisk {
        file: File,
        room: Arc<AtomicU64>,
    }

    impl Write for FillingDisk {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            let room = self.room.load(Ordering::SeqCst) as usize;
            if room == 0 {
                return Err(std::io::Error::from_raw_os_error(28));
            }
            let n = self
                .file
                .write(buf.get(..buf.len().min(room)).unwrap_or_default())?;
            self.room.fetch_sub(n as u64, Ordering::SeqCst);
            Ok(n)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            self.file.flush()
        }
    }

    impl LogFile for FillingDisk {
        fn sync_data(&mut self) -> std::io::Result<()> {
            self.file.sync_data()
        }
        fn set_len(&mut self, len: u64) -> std::io::Result<()> {
            self.file.set_len(len)
        }
    }

    #[test]
    fn a_failed_append_is_rolled_back_and_the_next_record_has_its_own_line() {
        let dir = tempfile::tempdir().expect("dir");
        let room = Arc::new(AtomicU64::new(1 << 20));
        let r = room.clone();
        let opener: Opener = Arc::new(move |p: &Path| {
            let file = OpenOptions::new().append(true).create(true).open(p)?;
            let disk = FillingDisk {
                file,
                room: r.clone(),
            };
            Ok(Box::new(disk) as Box<dyn LogFile>)
        });
        let (mut log, _) =
            ResultsLog::open_with(dir.path(), 1 << 20, 2, 100, opener).expect("open");
        let rec = sample;
        log.append(&rec(1)).expect("append");
        // The disk fills half-way through the second record.
        room.store(20, Ordering::SeqCst);
        let e = log.append(&rec(2)).expect_err("disk full");
        let StreamError::Io { cause, .. } = &e;
        assert!(is_disk_full(cause), "{e}");
        assert!(e.to_string().contains("No space left on device"), "{e}");
        let p = ResultsLog::path_in(dir.path());
        let text = std::fs::read_to_string(&p).expect("read");
        assert_eq!(
            text,
            format!("{}\n", rec(1).to_line()),
            "rolled back to the last whole line"
        );
        room.store(1 << 20, Ordering::SeqCst);
        log.append(&rec(2)).expect("append");
        log.append(&rec(3)).expect("append");
        let (_, back) = ResultsLog::open(dir.path(), 1 << 20, 2, 100).expect("reopen");
        assert_eq!((back.read, back.bad_lines, back.torn_bytes), (3, 0, 0));
        assert_eq!(counters(&back.records), vec![1, 2, 3]);
    }

    #[test]
    fn the_tail_is_read_back_from_the_end_across_chunks_and_rotations() {
        let dir = tempfile::tempdir().expect("dir");
        let (mut log, _) = ResultsLog::open(dir.path(), 200_000, 3, 100).expect("open");
        for c in 1..=1000u64 {
            log.append(&sample(c)).expect("append");
            if c % 10 == 0 {
                log.append(&Record::Alarm(AlarmRecord::example(c)))
                    .expect("append");
            }
        }
        let p = ResultsLog::path_in(dir.path());
        assert!(rotated(&p, 1).exists());
        let (_, back) = ResultsLog::open(dir.path(), 200_000, 3, 700).expect("reopen");
        let samples: Vec<u64> = back
            .records
            .iter()
            .filter_map(Record::as_sample)
            .map(|r| r.counter)
            .collect();
        assert_eq!(samples, (301..=1000).collect::<Vec<_>>());
        assert_eq!((back.max_counter, back.bad_lines), (1000, 0));
        assert_eq!(back.oldest_counter, Some(301));
        assert!(back.sample_counters.contains(&301) && !back.sample_counters.contains(&300));
    }

    #[test]
    fn start_up_reads_the_tail_not_the_whole_file() {
        let dir = tempfile::tempdir().expect("dir");
        let (mut log, _) = ResultsLog::open(dir.path(), 1 << 30, 2, 10).expect("open");
        for c in 1..=3000u64 {
            log.append(&sample(c)).expect("append");
        }
        let len = std::fs::metadata(ResultsLog::path_in(dir.path()))
            .expect("size")
            .len();
        assert!(len > 1_000_000, "{len}");
        let (_, back) = ResultsLog::open(dir.path(), 1 << 30, 2, 10).expect("reopen");
        assert_eq!(back.records.len(), 10);
        assert_eq!(back.max_counter, 3000);
        assert!(
            back.bytes_read <= TAIL_CHUNK,
            "{} of {len} bytes read",
            back.bytes_read
        );
    }

    #[test]
    fn records_after_a_seq_come_back_oldest_first_across_rotations_and_bounded() {
        let dir = tempfile::tempdir().expect("dir");
        let (mut log, _) = ResultsLog::open(dir.path(), 8192, 4, 10).expect("open");
        // Records of a log written before sequence numbers, then numbered ones.
        log.append(&sample(0)).expect("append");
        for q in 1..=50u64 {
            log.append(&numbered(q, q)).expect("append");
        }
        assert!(rotated(&ResultsLog::path_in(dir.path()), 1).exists());
        let seqs = |v: &std::collections::VecDeque<Record>| -> Vec<u64> {
            v.iter().filter_map(Record::seq).collect()
        };
        let (after, left_out) = records_after(dir.path(), 4, 40, 100).expect("read");
        assert_eq!((seqs(&after), left_out), ((41..=50).collect(), false));
        let (after, left_out) = records_after(dir.path(), 4, 10, 5).expect("read");
        assert_eq!((seqs(&after), left_out), ((46..=50).collect(), true));
        let (after, _) = records_after(dir.path(), 4, 50, 100).expect("read");
        assert!(after.is_empty());
        let (after, _) = records_after(dir.path(), 4, 0, 100).expect("read");
        assert_eq!(
            seqs(&after),
            (1..=50).collect::<Vec<_>>(),
            "stops at the unnumbered"
        );
    }

    #[test]
    fn a_full_spool_drops_its_oldest_and_keeps_the_acknowledgement_below_it() {
        let dir = tempfile::tempdir().expect("dir");
        // A port nothing listens on: the records stay unacknowledged.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .expect("port");
        let spec: MqttSpec =
            serde_json::from_str(&format!(r#"{{"port": {port}, "spool_records": 3}}"#))
                .expect("spec");
        let m = MqttPublisher::connect(&spec, dir.path(), 10).expect("client");
        for seq in 9..=15u64 {
            m.publish(&numbered(seq, seq));
        }
        // 9 and 10 were acknowledged before; 11 and 12 dropped from the full spool.
        let left = m.flush(Duration::ZERO).expect("unsent");
        assert_eq!(
            left,
            Unsent {
                records: 5,
                first_seq: 11,
                connected: false
            }
        );
        assert_eq!((m.sent(), m.acked()), (5, 0));
        drop(m);
        assert!(
            !AckState::path_in(dir.path()).exists(),
            "nothing acknowledged"
        );
    }

    #[test]
    fn rotation_keeps_k_files_and_reads_back_in_order() {
        let dir = tempfile::tempdir().expect("dir");
        let (mut log, _) = ResultsLog::open(dir.path(), 40, 2, 100).expect("open");
        for c in 0..10 {
            log.append(&sample(c)).expect("append");
        }
        let p = ResultsLog::path_in(dir.path());
        assert!(rotated(&p, 1).exists() && rotated(&p, 2).exists());
        assert!(!rotated(&p, 3).exists());
        let (_, rec) = ResultsLog::open(dir.path(), 40, 2, 100).expect("reopen");
        assert_eq!(counters(&rec.records), vec![7, 8, 9]);
        assert_eq!(rec.read, 3);
    }
}
