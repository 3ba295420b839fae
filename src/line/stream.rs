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

/// `results.jsonl` in a folder, with its rotated predecessors `results.jsonl.1` (newest) to
/// `results.jsonl.K` (oldest).
pub struct ResultsLog {
    path: PathBuf,
    file: File,
    size: u64,
    rotate_bytes: u64,
    keep: usize,
}

/// What [`ResultsLog::open`] found.
#[derive(Debug, Default)]
pub struct Recovered {
    /// The newest readable records (at most the number asked for), oldest first.
    pub records: std::collections::VecDeque<Value>,
    /// Records read in all.
    pub read: usize,
    /// The highest `counter` of any record.
    pub max_counter: u64,
    /// Bytes of a torn last line cut off.
    pub torn_bytes: u64,
    /// Lines that were not JSON (skipped).
    pub bad_lines: usize,
}

impl ResultsLog {
    /// The log's path in `dir`.
    pub fn path_in(dir: &Path) -> PathBuf {
        dir.join("results.jsonl")
    }

    /// Opens (or creates) `dir/results.jsonl` for appending, cutting a torn last line (a
    /// write a crash interrupted), and reads back it and its rotations, keeping the newest
    /// `keep_last` records.
    pub fn open(
        dir: &Path,
        rotate_bytes: u64,
        keep: usize,
        keep_last: usize,
    ) -> Result<(Self, Recovered), StreamError> {
        let path = Self::path_in(dir);
        let mut rec = Recovered::default();
        for k in (1..=keep.max(1)).rev() {
            let p = rotated(&path, k);
            if let Ok(text) = std::fs::read_to_string(&p) {
                parse_lines(&text, &mut rec, keep_last);
            }
        }
        let mut file = OpenOptions::new()
            .read(true)
            .append(true)
            .create(true)
            .open(&path)
            .map_err(io(&path))?;
        let mut bytes = Vec::new();
        file.read_to_end(&mut bytes).map_err(io(&path))?;
        let whole = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        if whole < bytes.len() {
            rec.torn_bytes = (bytes.len() - whole) as u64;
            file.set_len(whole as u64).map_err(io(&path))?;
            file.sync_all().map_err(io(&path))?;
        }
        file.seek(SeekFrom::End(0)).map_err(io(&path))?;
        parse_lines(
            &String::from_utf8_lossy(&bytes[..whole]),
            &mut rec,
            keep_last,
        );
        Ok((
            Self {
                path,
                file,
                size: whole as u64,
                rotate_bytes,
                keep: keep.max(1),
            },
            rec,
        ))
    }

    /// Appends one record as one line and fsyncs it; rotates first if the line would take
    /// the file past its size.
    pub fn append(&mut self, record: &Value) -> Result<(), StreamError> {
        let mut line = record.to_string();
        line.push('\n');
        if self.size > 0 && self.size + line.len() as u64 > self.rotate_bytes {
            self.rotate()?;
        }
        self.file
            .write_all(line.as_bytes())
            .map_err(io(&self.path))?;
        self.file.sync_data().map_err(io(&self.path))?;
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
        self.file = OpenOptions::new()
            .append(true)
            .create(true)
            .open(&self.path)
            .map_err(io(&self.path))?;
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

fn parse_lines(text: &str, rec: &mut Recovered, keep_last: usize) {
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        match serde_json::from_str::<Value>(line) {
            Ok(v) => {
                rec.read += 1;
                if let Some(c) = v["counter"].as_u64() {
                    rec.max_counter = rec.max_counter.max(c);
                }
                rec.records.push_back(v);
                while rec.records.len() > keep_last {
                    rec.records.pop_front();
                }
            }
            Err(_) => rec.bad_lines += 1,
        }
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
        let (_, rec) = ResultsLog::open(dir.path(), 40, 2, 2).expect("reopen");
        let ids: Vec<i64> = rec.records.iter().filter_map(|r| r["i"].as_i64()).collect();
        assert_eq!((ids, rec.read), (vec![8, 9], 3));
    }
}
