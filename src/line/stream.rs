//! The result stream: `results.jsonl` (one JSON object a line, fsynced, rotated past a
//! size, rebuilt after a crash) and the same records published over MQTT.

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use rumqttc::{Client, Event, MqttOptions, Packet, QoS, RecvTimeoutError};
use serde_json::Value;

use super::recipe::MqttSpec;

/// A stream that cannot be written or published to.
#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    /// A file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The MQTT client.
    #[error("mqtt {0}")]
    Mqtt(String),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> StreamError + '_ {
    move |source| StreamError::Io {
        path: path.to_owned(),
        source,
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
    pub records: std::collections::VecDeque<Value>,
    /// Records read back.
    pub read: usize,
    /// The highest `counter` of the records read back.
    pub max_counter: u64,
    /// The counters of the sample records read back.
    pub sample_counters: std::collections::HashSet<u64>,
    /// The lowest `counter` of the records read back: every sample above it has its
    /// record among them unless it is missing from the log.
    pub oldest_counter: Option<u64>,
    /// Bytes of a torn last line cut off.
    pub torn_bytes: u64,
    /// Bytes read back from the results files (their tails, not the whole files).
    pub bytes_read: u64,
    /// Lines that were not JSON (skipped).
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
    pub fn append(&mut self, record: &Value) -> Result<(), StreamError> {
        if self.dirty {
            self.file.set_len(self.size).map_err(io(&self.path))?;
            self.dirty = false;
        }
        let mut line = record.to_string();
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

fn rotated(path: &Path, k: usize) -> PathBuf {
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
    let mut end = len;
    // The bytes after the chunk just read that begin a line not yet complete.
    let mut carry: Vec<u8> = Vec::new();
    let mut skipping = false;
    while end > 0 && rec.sample_counters.len() < keep_samples {
        let n = end.min(TAIL_CHUNK);
        let start = end - n;
        let mut chunk = vec![0u8; n as usize];
        f.seek(SeekFrom::Start(start))?;
        f.read_exact(&mut chunk)?;
        rec.bytes_read += n;
        chunk.extend_from_slice(&carry);
        let mut upto = chunk.len();
        // Every line that starts inside this chunk after a newline is complete.
        while let Some(i) = chunk
            .get(..upto)
            .and_then(|c| c.iter().rposition(|&b| b == b'\n'))
        {
            if skipping {
                skipping = false;
            } else {
                take_line(chunk.get(i + 1..upto).unwrap_or_default(), rec);
            }
            upto = i;
            if rec.sample_counters.len() >= keep_samples {
                return Ok(());
            }
        }
        carry = chunk.get(..upto).unwrap_or_default().to_vec();
        if carry.len() > MAX_LINE {
            // Not a record: skip to its start without holding it.
            rec.bad_lines += 1;
            carry.clear();
            skipping = true;
        }
        end = start;
    }
    if end == 0 && !skipping && rec.sample_counters.len() < keep_samples {
        take_line(&carry, rec);
    }
    Ok(())
}

/// One line read back (newest first).
fn take_line(line: &[u8], rec: &mut Recovered) {
    if line.iter().all(u8::is_ascii_whitespace) {
        return;
    }
    match serde_json::from_slice::<Value>(line) {
        Ok(v) => {
            rec.read += 1;
            if let Some(c) = v["counter"].as_u64() {
                rec.max_counter = rec.max_counter.max(c);
                rec.oldest_counter = Some(rec.oldest_counter.map_or(c, |o| o.min(c)));
                if v["kind"] == "sample" {
                    rec.sample_counters.insert(c);
                }
            }
            rec.records.push_front(v);
        }
        Err(_) => rec.bad_lines += 1,
    }
}

/// Publishes records to an MQTT broker (QoS 1), counting the broker's acknowledgements.
pub struct MqttPublisher {
    client: Option<Client>,
    topic: String,
    sent: u64,
    acked: Arc<AtomicU64>,
    connected: Arc<AtomicBool>,
    last_error: Arc<Mutex<Option<String>>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl MqttPublisher {
    /// Connects in the background to the broker of `spec`; publishing starts at once (records
    /// wait in the client's queue until the broker is reached).
    pub fn connect(spec: &MqttSpec) -> Self {
        let mut o = MqttOptions::new(spec.client_id.clone(), spec.host.clone(), spec.port);
        o.set_keep_alive(Duration::from_secs(15));
        o.set_max_packet_size(1 << 20, 1 << 20);
        let (client, mut conn) = Client::new(o, 1024);
        let acked = Arc::new(AtomicU64::new(0));
        let connected = Arc::new(AtomicBool::new(false));
        let last_error = Arc::new(Mutex::new(None));
        let stop = Arc::new(AtomicBool::new(false));
        let (a, c, e, st) = (
            acked.clone(),
            connected.clone(),
            last_error.clone(),
            stop.clone(),
        );
        let thread = std::thread::Builder::new()
            .name("mqtt".into())
            .spawn(move || loop {
                if st.load(Ordering::SeqCst) {
                    break;
                }
                match conn.recv_timeout(Duration::from_millis(200)) {
                    Ok(Ok(Event::Incoming(Packet::PubAck(_)))) => {
                        a.fetch_add(1, Ordering::SeqCst);
                    }
                    Ok(Ok(Event::Incoming(Packet::ConnAck(_)))) => {
                        c.store(true, Ordering::SeqCst);
                    }
                    Ok(Ok(_)) => {}
                    Ok(Err(err)) => {
                        c.store(false, Ordering::SeqCst);
                        *e.lock().unwrap_or_else(|p| p.into_inner()) = Some(err.to_string());
                        std::thread::sleep(Duration::from_millis(300));
                    }
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => break,
                }
            })
            .ok();
        Self {
            client: Some(client),
            topic: spec.topic.clone(),
            sent: 0,
            acked,
            connected,
            last_error,
            stop,
            thread,
        }
    }

    /// Queues one record (never blocks: a full queue is an error).
    pub fn publish(&mut self, record: &Value) -> Result<(), StreamError> {
        let client = self
            .client
            .as_ref()
            .ok_or_else(|| StreamError::Mqtt("client closed".into()))?;
        client
            .try_publish(
                self.topic.clone(),
                QoS::AtLeastOnce,
                false,
                record.to_string().into_bytes(),
            )
            .map_err(|e| StreamError::Mqtt(e.to_string()))?;
        self.sent += 1;
        Ok(())
    }

    /// Records queued.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// Records the broker acknowledged.
    pub fn acked(&self) -> u64 {
        self.acked.load(Ordering::SeqCst)
    }

    /// Whether the broker accepted the connection (and it has not failed since).
    pub fn connected(&self) -> bool {
        self.connected.load(Ordering::SeqCst)
    }

    /// The last connection error, taken.
    pub fn take_error(&self) -> Option<String> {
        self.last_error
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take()
    }

    /// Waits up to `timeout` for the broker to acknowledge every record; whether it did.
    pub fn flush(&self, timeout: Duration) -> bool {
        let t0 = Instant::now();
        while self.acked() < self.sent {
            if t0.elapsed() > timeout {
                return false;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        true
    }
}

impl Drop for MqttPublisher {
    fn drop(&mut self) {
        if let Some(c) = self.client.take() {
            let _ = c.try_disconnect();
            drop(c);
        }
        // Give the disconnect a moment to go out, then stop polling.
        let t0 = Instant::now();
        while self.connected() && t0.elapsed() < Duration::from_millis(300) {
            std::thread::sleep(Duration::from_millis(10));
        }
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn torn_last_line_is_cut_and_appending_goes_on() {
        let dir = tempfile::tempdir().expect("dir");
        let p = ResultsLog::path_in(dir.path());
        std::fs::write(&p, "{\"a\":1}\n{\"a\":2}\n{\"a\":").expect("write");
        let (mut log, rec) = ResultsLog::open(dir.path(), 1 << 20, 2, 100).expect("open");
        assert_eq!(rec.records.len(), 2);
        assert_eq!(rec.torn_bytes, 5);
        log.append(&json!({"a": 3})).expect("append");
        let text = std::fs::read_to_string(&p).expect("read");
        assert_eq!(text, "{\"a\":1}\n{\"a\":2}\n{\"a\":3}\n");
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
        let rec = |c: u64| json!({"kind": "sample", "counter": c, "pad": "x".repeat(40)});
        log.append(&rec(1)).expect("append");
        // The disk fills half-way through the second record.
        room.store(20, Ordering::SeqCst);
        let e = log.append(&rec(2)).expect_err("disk full");
        let StreamError::Io { source, .. } = &e else {
            panic!("{e}")
        };
        assert!(is_disk_full(source), "{e}");
        assert!(e.to_string().contains("No space left on device"), "{e}");
        let p = ResultsLog::path_in(dir.path());
        let text = std::fs::read_to_string(&p).expect("read");
        assert_eq!(
            text,
            format!("{}\n", rec(1)),
            "rolled back to the last whole line"
        );
        room.store(1 << 20, Ordering::SeqCst);
        log.append(&rec(2)).expect("append");
        log.append(&rec(3)).expect("append");
        let (_, back) = ResultsLog::open(dir.path(), 1 << 20, 2, 100).expect("reopen");
        assert_eq!((back.read, back.bad_lines, back.torn_bytes), (3, 0, 0));
        let counters: Vec<u64> = back
            .records
            .iter()
            .filter_map(|r| r["counter"].as_u64())
            .collect();
        assert_eq!(counters, vec![1, 2, 3]);
    }

    #[test]
    fn the_tail_is_read_back_from_the_end_across_chunks_and_rotations() {
        let dir = tempfile::tempdir().expect("dir");
        let (mut log, _) = ResultsLog::open(dir.path(), 200_000, 3, 100).expect("open");
        for c in 1..=1000u64 {
            log.append(&json!({"kind": "sample", "counter": c, "pad": "y".repeat(300)}))
                .expect("append");
            if c % 10 == 0 {
                log.append(&json!({"kind": "alarm", "counter": c}))
                    .expect("append");
            }
        }
        let p = ResultsLog::path_in(dir.path());
        assert!(rotated(&p, 1).exists());
        let (_, back) = ResultsLog::open(dir.path(), 200_000, 3, 700).expect("reopen");
        let samples: Vec<u64> = back
            .records
            .iter()
            .filter(|r| r["kind"] == "sample")
            .filter_map(|r| r["counter"].as_u64())
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
            log.append(&json!({"kind": "sample", "counter": c, "pad": "z".repeat(300)}))
                .expect("append");
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
    fn rotation_keeps_k_files_and_reads_back_in_order() {
        let dir = tempfile::tempdir().expect("dir");
        let (mut log, _) = ResultsLog::open(dir.path(), 40, 2, 100).expect("open");
        for i in 0..10 {
            log.append(&json!({"i": i, "pad": "xxxxxxxxxx"}))
                .expect("append");
        }
        let p = ResultsLog::path_in(dir.path());
        assert!(rotated(&p, 1).exists() && rotated(&p, 2).exists());
        assert!(!rotated(&p, 3).exists());
        let (_, rec) = ResultsLog::open(dir.path(), 40, 2, 100).expect("reopen");
        let ids: Vec<i64> = rec.records.iter().filter_map(|r| r["i"].as_i64()).collect();
        assert_eq!(ids, vec![7, 8, 9]);
        assert_eq!(rec.read, 3);
    }
}
