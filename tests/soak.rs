//! A soak of `filmscope inspect --sim`: a real Mosquitto restarted mid-run, the disk filled
//! to its free-space floor (`inspect` stops with its alarm) and freed (a restart goes on),
//! and a slowloris client attached to the status page throughout. Every sample ends up in
//! `results.jsonl` (counters 1..=N, each once, each with its folder), every record reaches a
//! subscriber (each sample id received, none that was not logged; duplicates a QoS 1
//! redelivery may bring are counted and printed), and the resident memory of each `inspect`
//! run stays within [`RSS_GROWTH_MB`] of what it was after its first samples.
//!
//! CI runs [`SHORT_SAMPLES`] samples; `FILMSCOPE_SOAK_SAMPLES=10000 cargo test --release
//! --test soak -- --nocapture` is the long one (docs/reliability.md). The disk is a tmpfs the
//! test mounts (root), sized for the run; where none can be mounted, the floor is crossed by
//! a run whose recipe's `min_free_bytes` is above the free space instead (said on stderr).
//! The broker is `FILMSCOPE_MOSQUITTO` if set, else `mosquitto` in /usr/sbin or /usr/bin;
//! without one the test says so and passes, unless `FILMSCOPE_REQUIRE_MOSQUITTO=1`.

mod common;

use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufRead, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{filmscope, s, tempdir};
use filmscope::record::line::{AlarmRule, AlarmVariable, LineFault, Record, SampleRecord};
use rumqttc::{Client, Event, MqttOptions, Packet, QoS};

/// Samples of the CI run.
const SHORT_SAMPLES: u64 = 40;
/// Most growth of an `inspect` run's resident memory, MB.
const RSS_GROWTH_MB: f64 = 20.0;
/// Connections the slowloris client keeps trickling into the status page.
const SLOW_CONNECTIONS: usize = 64;
/// The free-space floor of the soak's recipe, bytes.
const FLOOR: u64 = 16 << 20;
const PREFIX: &str = "soak/line1";

fn samples_wanted() -> u64 {
    std::env::var("FILMSCOPE_SOAK_SAMPLES")
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&n| n >= 8)
        .unwrap_or(SHORT_SAMPLES)
}

/// Waits (bounded by `limit`) until `cond` holds; `what` names it in the failure.
fn wait_until(what: &str, limit: Duration, mut cond: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !cond() {
        assert!(t0.elapsed() < limit, "never: {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn records(out: &Path) -> Vec<Record> {
    std::fs::read_to_string(out.join("results.jsonl"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// Sample records in `out`'s log (counted by their text: this is polled).
fn samples_in(out: &Path) -> u64 {
    std::fs::read_to_string(out.join("results.jsonl"))
        .unwrap_or_default()
        .lines()
        .filter(|l| l.contains("\"kind\":\"sample\""))
        .count() as u64
}

// ------------------------------------------------------------ broker and subscriber

fn mosquitto_bin() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("FILMSCOPE_MOSQUITTO") {
        return Some(PathBuf::from(p));
    }
    let found = ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"]
        .iter()
        .map(PathBuf::from)
        .find(|p| p.exists());
    if found.is_none() {
        let required = std::env::var("FILMSCOPE_REQUIRE_MOSQUITTO").is_ok_and(|v| v == "1");
        assert!(
            !required,
            "FILMSCOPE_REQUIRE_MOSQUITTO=1 but no mosquitto binary"
        );
        eprintln!("skipped: no mosquitto (apt-get install mosquitto, or FILMSCOPE_MOSQUITTO)");
    }
    found
}

struct Broker(Child);

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Broker {
    /// Plain TCP on `port`, anonymous, its sessions and queued messages kept in `dir`
    /// across restarts.
    fn start(bin: &Path, dir: &Path, port: u16) -> Self {
        let conf = dir.join("mosquitto.conf");
        std::fs::write(
            &conf,
            format!(
                "user root\npersistence true\npersistence_location {}/\nallow_anonymous true\nlistener {port} 127.0.0.1\n",
                dir.display()
            ),
        )
        .expect("conf");
        let child = Command::new(bin)
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start mosquitto");
        wait_until("mosquitto listens", Duration::from_secs(30), || {
            TcpStream::connect(("127.0.0.1", port)).is_ok()
        });
        Self(child)
    }

    /// Stops it as a restart would (SIGTERM: sessions and queued messages saved).
    fn stop(mut self) {
        let pid = self.0.id().to_string();
        let _ = Command::new("kill").args(["-TERM", &pid]).status();
        let _ = self.0.wait();
    }
}

/// The record payloads received live on `PREFIX/sample` and `PREFIX/alarm`.
struct Subscriber {
    got: Arc<Mutex<Vec<Record>>>,
    subscribed: Arc<AtomicUsize>,
    stop: Arc<AtomicBool>,
}

impl Drop for Subscriber {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

/// Subscribes (QoS 1) to `PREFIX/#`, again after every reconnection, in a session the
/// broker keeps while it is away.
fn subscribe(port: u16) -> Subscriber {
    let mut o = MqttOptions::new("soak-collector", "127.0.0.1", port);
    o.set_max_packet_size(1 << 20, 1 << 20);
    o.set_clean_session(false);
    let (client, mut conn) = Client::new(o, 64);
    let sub = Subscriber {
        got: Arc::new(Mutex::new(Vec::new())),
        subscribed: Arc::new(AtomicUsize::new(0)),
        stop: Arc::new(AtomicBool::new(false)),
    };
    let (got, subscribed, stop) = (sub.got.clone(), sub.subscribed.clone(), sub.stop.clone());
    std::thread::spawn(move || {
        while !stop.load(Ordering::SeqCst) {
            match conn.recv_timeout(Duration::from_millis(50)) {
                Ok(Ok(Event::Incoming(Packet::ConnAck(_)))) => {
                    let _ = client.try_subscribe(format!("{PREFIX}/#"), QoS::AtLeastOnce);
                }
                Ok(Ok(Event::Incoming(Packet::SubAck(_)))) => {
                    subscribed.fetch_add(1, Ordering::SeqCst);
                }
                Ok(Ok(Event::Incoming(Packet::Publish(p)))) => {
                    if !p.retain && !p.topic.ends_with("/status") {
                        if let Ok(v) = serde_json::from_slice(&p.payload) {
                            got.lock().expect("lock").push(v);
                        }
                    }
                }
                Ok(Ok(_)) | Err(_) => {}
                Ok(Err(_)) => std::thread::sleep(Duration::from_millis(100)),
            }
        }
    });
    wait_until("the subscriber subscribed", Duration::from_secs(30), || {
        sub.subscribed.load(Ordering::SeqCst) > 0
    });
    sub
}

// ------------------------------------------------------------ slowloris

/// [`SLOW_CONNECTIONS`] requests whose head never ends, a header line every half second
/// each; a connection the server closes is opened again (counted).
struct Slowloris {
    stop: Arc<AtomicBool>,
    opened: Arc<AtomicUsize>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Slowloris {
    fn attach(addr: SocketAddr) -> Self {
        assert!(addr.ip().is_loopback());
        let stop = Arc::new(AtomicBool::new(false));
        let opened = Arc::new(AtomicUsize::new(0));
        let (st, op) = (stop.clone(), opened.clone());
        let thread = std::thread::spawn(move || {
            let mut conns: Vec<Option<TcpStream>> = (0..SLOW_CONNECTIONS).map(|_| None).collect();
            while !st.load(Ordering::SeqCst) {
                for c in &mut conns {
                    let alive = match c {
                        Some(s) => s.write_all(b"X-Slow: a\r\n").is_ok(),
                        None => false,
                    };
                    if !alive {
                        *c = TcpStream::connect_timeout(&addr, Duration::from_secs(1))
                            .ok()
                            .filter(|s| {
                                let mut w: &TcpStream = s;
                                s.set_write_timeout(Some(Duration::from_secs(1))).is_ok()
                                    && w.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n").is_ok()
                            });
                        if c.is_some() {
                            op.fetch_add(1, Ordering::SeqCst);
                        }
                    }
                }
                std::thread::sleep(Duration::from_millis(500));
            }
        });
        Self {
            stop,
            opened,
            thread: Some(thread),
        }
    }

    /// Detaches; the connections it opened in all.
    fn detach(mut self) -> usize {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.opened.load(Ordering::SeqCst)
    }
}

fn get(addr: SocketAddr, path: &str) -> String {
    let mut s = TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(30)))
        .expect("timeout");
    write!(s, "GET {path} HTTP/1.0\r\nHost: x\r\n\r\n").expect("send");
    let mut answer = String::new();
    s.read_to_string(&mut answer)
        .unwrap_or_else(|e| panic!("{path}: no answer: {e}"));
    answer
}

// ------------------------------------------------------------ the disk

/// A tmpfs mounted on a folder of its own (unmounted when dropped), if one can be.
struct Disk {
    dir: PathBuf,
    mounted: bool,
}

impl Disk {
    fn new(dir: PathBuf, bytes: u64) -> Self {
        std::fs::create_dir_all(&dir).expect("disk dir");
        let mounted = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={bytes}"), "tmpfs"])
            .arg(&dir)
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|st| st.success());
        Self { dir, mounted }
    }

    fn free(&self) -> u64 {
        filmscope::line::inspect::available_bytes(&self.dir).expect("statvfs")
    }
}

impl Drop for Disk {
    fn drop(&mut self) {
        if self.mounted {
            let _ = Command::new("umount").arg("-l").arg(&self.dir).status();
        }
    }
}

// ------------------------------------------------------------ inspect

/// A running `inspect`: its stderr lines as they come, its status page.
struct Run {
    child: Child,
    err: Arc<Mutex<Vec<String>>>,
    page: SocketAddr,
}

impl Drop for Run {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Run {
    fn start(recipe: &Path, out: &Path, samples: Option<u64>) -> Self {
        let mut c = filmscope();
        c.args([
            "inspect",
            "--rig",
            concat!(env!("CARGO_MANIFEST_DIR"), "/config/rig.toml"),
            "--sim",
            "--recipe",
            s(recipe),
            "--out",
            s(out),
        ]);
        if let Some(n) = samples {
            c.args(["--samples", &n.to_string()]);
        }
        let mut child = c
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("inspect");
        let err = Arc::new(Mutex::new(Vec::new()));
        let lines = std::io::BufReader::new(child.stderr.take().expect("stderr"));
        let e = err.clone();
        std::thread::spawn(move || {
            for l in lines.lines().map_while(Result::ok) {
                e.lock().expect("lock").push(l);
            }
        });
        let mut page = None;
        wait_until("the status page's address", Duration::from_secs(60), || {
            page = err.lock().expect("lock").iter().find_map(|l| {
                l.strip_prefix("status page: http://")
                    .and_then(|u| u.strip_suffix('/'))
                    .and_then(|u| u.parse().ok())
            });
            page.is_some()
        });
        Self {
            child,
            err,
            page: page.expect("page"),
        }
    }

    /// Waits (bounded by `limit`) until `out` holds `n` sample records; fails at once,
    /// with its stderr, if `inspect` exits before.
    fn until(&mut self, what: &str, limit: Duration, out: &Path, n: u64) {
        let t0 = Instant::now();
        while samples_in(out) < n {
            if let Some(st) = self.child.try_wait().expect("wait") {
                std::thread::sleep(Duration::from_millis(200));
                panic!(
                    "inspect exited ({st}) before {what}:\n{}",
                    self.err.lock().expect("lock").join("\n")
                );
            }
            assert!(t0.elapsed() < limit, "never: {what}");
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    /// Resident memory, MB.
    fn rss_mb(&self) -> f64 {
        let status =
            std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).expect("status");
        status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
            .map(|kb| kb / 1024.0)
            .expect("VmRSS")
    }

    /// Waits (bounded) for the exit: success and stderr.
    fn wait(mut self, limit: Duration) -> (bool, String) {
        let t0 = Instant::now();
        let status = loop {
            if let Some(st) = self.child.try_wait().expect("wait") {
                break st;
            }
            assert!(t0.elapsed() < limit, "inspect did not exit");
            std::thread::sleep(Duration::from_millis(50));
        };
        // The reader thread has the rest once the pipe closes.
        std::thread::sleep(Duration::from_millis(200));
        (status.success(), self.err.lock().expect("lock").join("\n"))
    }
}

/// The demo recipe with its status page on any free port, no raw sweeps kept, the floor
/// `floor` and a `[mqtt]` table for the test broker.
fn recipe(dir: &Path, name: &str, port: u16, floor: u64) -> PathBuf {
    let demo = include_str!("../config/recipes/demo.toml");
    let mut out = String::new();
    let mut skip = false;
    for line in demo.lines() {
        if line.starts_with('[') {
            skip = line.starts_with("[mqtt]");
        }
        let t = line.trim_start();
        if skip {
            continue;
        } else if t.starts_with("port = 8088") {
            out.push_str("port = 0\n");
        } else if t.starts_with("raw = ") {
            out.push_str("raw = \"none\"\n");
        } else if t.starts_with("min_free_bytes") {
            out.push_str(&format!("min_free_bytes = {floor}\n"));
        } else if t.starts_with("drift_nm_per_sample") {
            // No process drift: over thousands of samples the demo's 0.3 nm a sample would
            // take the film from 620 nm to several um, and the soak would measure an ever
            // thicker film instead of the line.
            out.push_str("drift_nm_per_sample = 0.0\n");
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    out.push_str(&format!(
        "[mqtt]\nhost = \"127.0.0.1\"\nport = {port}\nprefix = \"{PREFIX}\"\nclient_id = \"soak-line1\"\nack_timeout_s = 10.0\n"
    ));
    let p = dir.join(name);
    std::fs::write(&p, out).expect("recipe");
    p
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("free port")
}

// ------------------------------------------------------------ the soak

#[test]
fn soak_broker_restart_disk_floor_slowloris() {
    let Some(bin) = mosquitto_bin() else { return };
    let n = samples_wanted();
    let t0 = Instant::now();
    let dir = tempdir();
    let port = free_port();
    let broker_dir = dir.path().join("broker");
    std::fs::create_dir_all(&broker_dir).expect("broker dir");
    let broker = Broker::start(&bin, &broker_dir, port);
    let sub = subscribe(port);
    // Room for the run above the floor: a sample takes about 72 KiB of a tmpfs (its files
    // in whole pages, its records).
    let disk = Disk::new(dir.path().join("disk"), FLOOR + (32 << 20) + n * (96 << 10));
    let out = disk.dir.join("line");
    let rec = recipe(dir.path(), "recipe.toml", port, FLOOR);
    let long = Duration::from_secs(60 + 5 * n);

    // Run 1: the broker restarted a quarter in, the disk filled to its floor half-way.
    let mut run = Run::start(&rec, &out, None);
    let slow = Slowloris::attach(run.page);
    let warm = 3.min(n / 4);
    run.until("the first samples", long, &out, warm);
    let rss1 = run.rss_mb();
    run.until("a quarter of the samples", long, &out, n / 4);
    broker.stop();
    let k = samples_in(&out);
    run.until("2 samples while the broker is down", long, &out, k + 2);
    let answer = get(run.page, "/api/latest");
    assert!(
        answer.starts_with("HTTP/1.") && answer.contains(" 200 OK"),
        "the page under slowloris: {answer}"
    );
    let subs = sub.subscribed.load(Ordering::SeqCst);
    let broker = Broker::start(&bin, &broker_dir, port);
    wait_until("the collector subscribed again", long, || {
        sub.subscribed.load(Ordering::SeqCst) > subs
    });
    run.until("half the samples", long, &out, n / 2);
    let rss1_end = run.rss_mb();
    let ballast = disk.dir.join("ballast");
    let stopped_at;
    if disk.mounted {
        // Fill the disk to just below its floor: the line stops with its alarm.
        let fill = disk.free().saturating_sub(FLOOR) + (1 << 20);
        let mut f = std::fs::File::create(&ballast).expect("ballast");
        let chunk = vec![0u8; 1 << 20];
        let mut left = fill;
        while left > 0 {
            let k = left.min(chunk.len() as u64) as usize;
            f.write_all(&chunk[..k]).expect("ballast write");
            left -= k as u64;
        }
        f.sync_all().expect("sync");
        assert!(disk.free() < FLOOR, "{} free", disk.free());
        let (ok, err) = run.wait(long);
        assert!(!ok, "below the floor: a non-zero exit");
        assert!(
            err.contains("disk full") && err.contains("retention.min_free_bytes"),
            "{err}"
        );
        stopped_at = samples_in(&out);
    } else {
        eprintln!("disk: no tmpfs could be mounted here (not root?); the floor is crossed by a run whose min_free_bytes is above the free space");
        let pid = run.child.id().to_string();
        Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .expect("kill");
        let (ok, err) = run.wait(long);
        assert!(ok, "{err}");
        stopped_at = samples_in(&out);
        let free = filmscope::line::inspect::available_bytes(&disk.dir).expect("statvfs");
        let full = recipe(
            dir.path(),
            "full.toml",
            port,
            free.saturating_mul(2).min(1 << 50),
        );
        let (ok, err) = Run::start(&full, &out, Some(1)).wait(long);
        assert!(!ok && err.contains("disk full"), "{err}");
    }
    let opened = slow.detach();
    let last = records(&out).pop().expect("a record");
    assert!(
        matches!(&last, Record::Alarm(a) if a.variable == AlarmVariable::DiskFreeBytes),
        "{last:?}"
    );
    assert_eq!(
        samples_in(&out),
        stopped_at,
        "nothing measured below the floor"
    );

    // Freed: run 2 measures the rest.
    let _ = std::fs::remove_file(&ballast);
    let mut run = Run::start(&rec, &out, Some(n - stopped_at));
    let slow = Slowloris::attach(run.page);
    run.until(
        "run 2's first samples",
        long,
        &out,
        stopped_at + warm.min(n - stopped_at),
    );
    let rss2 = run.rss_mb();
    run.until("all samples but the last", long, &out, n - 1);
    let rss2_end = run.rss_mb();
    let (ok, err) = run.wait(long);
    assert!(ok, "{err}");
    let opened = opened + slow.detach();
    drop(broker);

    // Zero lost: n sample records, each counter once, each with its folder; a counter the
    // rig could not measure (a device error on a loaded machine) has its `sample_failed`
    // alarm instead, so the counters of both are 1..=n + failed.
    let recs = records(&out);
    let samples: Vec<&SampleRecord> = recs.iter().filter_map(Record::as_sample).collect();
    let counters: BTreeSet<u64> = samples.iter().map(|r| r.counter).collect();
    let failed: BTreeSet<u64> = recs
        .iter()
        .filter_map(|r| match r {
            Record::Alarm(a) if a.rule == AlarmRule::Fault(LineFault::SampleFailed) => {
                Some(a.counter)
            }
            _ => None,
        })
        .collect();
    assert_eq!(samples.len() as u64, n, "sample records");
    assert_eq!(counters.len() as u64, n, "each sample's counter once");
    let both: BTreeSet<u64> = counters.union(&failed).copied().collect();
    let all: BTreeSet<u64> = (1..=n + failed.len() as u64).collect();
    assert!(
        counters.is_disjoint(&failed) && both == all,
        "counters without a record: {:?}; failed samples: {failed:?}",
        all.difference(&both).collect::<Vec<_>>()
    );
    let folders = std::fs::read_dir(out.join("samples"))
        .expect("samples")
        .flatten()
        .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
        .count() as u64;
    assert_eq!(folders, n, "a folder a sample");

    // Published: every logged record received (by seq), each sample id once after
    // de-duplication, none that was not logged.
    let logged: BTreeMap<u64, &Record> = recs.iter().filter_map(|r| Some((r.seq()?, r))).collect();
    wait_until("every logged record received", long, || {
        let got = sub.got.lock().expect("lock");
        let seqs: BTreeSet<u64> = got.iter().filter_map(Record::seq).collect();
        logged.keys().all(|k| seqs.contains(k))
    });
    let got = sub.got.lock().expect("lock").clone();
    let ids_logged: BTreeSet<&str> = samples.iter().map(|r| r.sample_id.as_str()).collect();
    let received: Vec<&str> = got
        .iter()
        .filter_map(Record::as_sample)
        .map(|r| r.sample_id.as_str())
        .collect();
    let ids_received: BTreeSet<&str> = received.iter().copied().collect();
    assert_eq!(
        ids_received, ids_logged,
        "each sample published, none other"
    );
    let by_seq: BTreeSet<u64> = got.iter().filter_map(Record::seq).collect();
    let logged_seqs: BTreeSet<u64> = logged.keys().copied().collect();
    assert_eq!(
        by_seq, logged_seqs,
        "no record received that was not logged"
    );
    let duplicates = got.len() - by_seq.len();
    for r in &got {
        let seq = r.seq().expect("seq");
        assert_eq!(
            Some(&r),
            logged.get(&seq),
            "a record received is the one logged"
        );
    }

    // Flat memory, each run.
    for (run, a, b) in [(1, rss1, rss1_end), (2, rss2, rss2_end)] {
        assert!(
            b < a + RSS_GROWTH_MB,
            "run {run}: RSS {a:.1} MB after its first samples, {b:.1} MB at its end"
        );
    }
    // The server cut the connections that never finished their request.
    assert!(
        opened > 2 * SLOW_CONNECTIONS,
        "slowloris connections opened: {opened}"
    );
    eprintln!(
        "soak: {n} samples ({} records, {} sample(s) the rig failed to measure, each with its alarm) in {:.0} s, disk {}: none lost; {} sample ids received once each after {duplicates} duplicate(s) removed; RSS run 1 {rss1:.1} -> {rss1_end:.1} MB, run 2 {rss2:.1} -> {rss2_end:.1} MB; slowloris: {opened} connections opened ({SLOW_CONNECTIONS} held at a time)",
        recs.len(),
        failed.len(),
        t0.elapsed().as_secs_f64(),
        if disk.mounted { "a tmpfs filled to its floor" } else { "a floor above the free space" },
        ids_received.len()
    );
}
