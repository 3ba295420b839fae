//! `filmscope inspect` end to end on firmware-sim: verdicts and masks, the records on a real
//! MQTT broker (Debian's mosquitto), restarts after kill -9 and SIGTERM, the disk budget,
//! uint16 references.
//!
//! The broker is `FILMSCOPE_MOSQUITTO` if set, else `mosquitto` on the PATH or in
//! /usr/sbin, started on a free loopback port. With `FILMSCOPE_REQUIRE_MOSQUITTO=1` (set by
//! `.ci/run` once it installed it) a missing broker is a failure; otherwise the MQTT checks
//! say why they skipped.

use crate::common;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{filmscope, s, tempdir};
use filmscope::record::line::{
    AlarmRule, AlarmVariable, LineFault, LineSummary, PassFail, Record, SampleRecord,
};
use filmscope::summary::Summary;

const DEMO: &str = include_str!("../config/recipes/demo.toml");

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn rig() -> PathBuf {
    root().join("config/rig.toml")
}

/// The demo recipe with the status page on any free port and MQTT on `mqtt_port` (none:
/// without the `[mqtt]` table), `extra` appended.
fn recipe(dir: &Path, mqtt_port: Option<u16>, retention: &str) -> PathBuf {
    let mut out = String::new();
    let mut skip = false;
    for line in DEMO.lines() {
        if line.starts_with('[') {
            skip = (line.starts_with("[mqtt]") && mqtt_port.is_none())
                || (line.starts_with("[retention]") && !retention.is_empty());
        }
        if skip {
            continue;
        }
        let line = match line.trim_start() {
            l if l.starts_with("port = 8088") => "port = 0".to_owned(),
            l if l.starts_with("port = 1883") => format!("port = {}", mqtt_port.unwrap_or(0)),
            _ => line.to_owned(),
        };
        out.push_str(&line);
        out.push('\n');
    }
    out.push_str(retention);
    let p = dir.join("recipe.toml");
    std::fs::write(&p, out).expect("recipe");
    p
}

fn records(out: &Path) -> Vec<Record> {
    std::fs::read_to_string(out.join("results.jsonl"))
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: not a record: {l}")))
        .collect()
}

fn samples(out: &Path) -> Vec<SampleRecord> {
    records(out)
        .into_iter()
        .filter_map(|r| match r {
            Record::Sample(s) => Some(*s),
            _ => None,
        })
        .collect()
}

fn folders(out: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(out.join("samples"))
        .expect("samples")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn inspect(recipe: &Path, out: &Path, extra: &[&str]) -> Command {
    let mut c = filmscope();
    c.args([
        "inspect",
        "--rig",
        s(&rig()),
        "--sim",
        "--recipe",
        s(recipe),
        "--out",
        s(out),
    ])
    .args(extra);
    c
}

/// [`inspect`] run to its end, which must succeed (its stderr shown otherwise).
fn inspect_ok(recipe: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let run = inspect(recipe, out, extra).output().expect("run inspect");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    run
}

// ---------------------------------------------------------------- the broker

struct Broker {
    child: Child,
    port: u16,
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("free port")
}

fn mosquitto_bin() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("FILMSCOPE_MOSQUITTO") {
        return Some(PathBuf::from(p));
    }
    ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"]
        .iter()
        .map(PathBuf::from)
        .find(|p| p.exists())
}

/// Starts mosquitto on a free loopback port, or says why not (a failure when required).
fn broker(dir: &Path) -> Option<Broker> {
    let Some(bin) = mosquitto_bin() else {
        let required = std::env::var("FILMSCOPE_REQUIRE_MOSQUITTO").is_ok_and(|v| v == "1");
        assert!(
            !required,
            "FILMSCOPE_REQUIRE_MOSQUITTO=1 but no mosquitto binary"
        );
        eprintln!("skipped: no mosquitto (apt-get install mosquitto, or FILMSCOPE_MOSQUITTO)");
        return None;
    };
    let port = free_port();
    let conf = dir.join("mosquitto.conf");
    std::fs::write(
        &conf,
        format!("listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n"),
    )
    .expect("conf");
    let child = Command::new(&bin)
        .arg("-c")
        .arg(&conf)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start mosquitto");
    let t0 = Instant::now();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "mosquitto did not listen"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    Some(Broker { child, port })
}

/// Subscribes to `topic`; returns the payloads as they arrive.
fn subscribe(port: u16, topic: &str) -> Arc<Mutex<Vec<String>>> {
    use rumqttc::{Client, Event, MqttOptions, Packet, QoS};
    let got = Arc::new(Mutex::new(Vec::new()));
    let mut o = MqttOptions::new("filmscope-test-sub", "127.0.0.1", port);
    o.set_max_packet_size(1 << 20, 1 << 20);
    let (client, mut conn) = Client::new(o, 16);
    client
        .subscribe(topic, QoS::AtLeastOnce)
        .expect("subscribe");
    let (tx, rx) = std::sync::mpsc::channel();
    let g = got.clone();
    std::thread::spawn(move || {
        let _client = client;
        for ev in conn.iter() {
            match ev {
                Ok(Event::Incoming(Packet::SubAck(_))) => {
                    let _ = tx.send(());
                }
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    g.lock()
                        .expect("lock")
                        .push(String::from_utf8_lossy(&p.payload).into_owned());
                }
                Ok(_) => {}
                Err(_) => std::thread::sleep(Duration::from_millis(100)),
            }
        }
    });
    rx.recv_timeout(Duration::from_secs(10)).expect("suback");
    got
}

// ---------------------------------------------------------------- the tests

/// The "done": three samples, at least one PASS and one FAIL, the fields, three
/// folders with their maps, masks and overlays, and the same records on the broker.
#[test]
fn three_simulated_samples_judged_written_and_published() {
    let dir = tempdir();
    let broker = broker(dir.path());
    let port = broker.as_ref().map(|b| b.port);
    let got = port.map(|p| subscribe(p, "filmscope/line1/+"));
    let rec = recipe(dir.path(), port, "");
    let out = dir.path().join("line");
    let run = inspect_ok(
        &rec,
        &out,
        &[
            "--samples",
            "3",
            "--json",
            "--lot",
            "L-42",
            "--operator",
            "Ann, B.",
        ],
    );
    let summary: LineSummary =
        serde_json::from_slice(run.stdout.split(|&b| b == b'\n').next().expect("line"))
            .expect("summary json");
    assert_eq!(summary.samples, 3);
    assert!(summary.latency_ms.max.expect("latency") > 0.0);

    let recs = samples(&out);
    assert_eq!(recs.len(), 3);
    // The log as a spreadsheet opens it: a header and one row per sample, in order.
    let csv = filmscope()
        .args(["results", s(&out), "--csv"])
        .output()
        .expect("results");
    assert!(csv.status.success(), "{csv:?}");
    let csv = String::from_utf8(csv.stdout).expect("utf-8");
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 4, "{csv}");
    assert!(rows[0].starts_with("counter,sample_id,timestamp,lot,operator,recipe,film,verdict"));
    for (r, rec) in rows[1..].iter().zip(&recs) {
        assert!(r.contains(&format!(",{},", rec.sample_id)), "{r}");
        assert!(r.contains(",L-42,\"Ann, B.\","), "{r}");
    }
    for r in &recs {
        assert!(!r.sample_id.is_empty() && !r.timestamp.is_empty(), "{r:?}");
        assert!(r.refractive_index.is_some(), "{r:?}");
        let t = r.thickness_nm;
        assert!(
            [t.mean, t.std, t.min, t.max].iter().all(Option::is_some),
            "{t:?}"
        );
        assert_eq!(
            (r.lot.as_deref(), r.operator.as_deref()),
            (Some("L-42"), Some("Ann, B."))
        );
        assert_eq!(r.reasons.is_empty(), r.verdict.passed());
    }
    let verdicts: Vec<PassFail> = recs.iter().map(|r| r.verdict).collect();
    assert!(
        verdicts.contains(&PassFail::Pass) && verdicts.contains(&PassFail::Fail),
        "{verdicts:?}"
    );
    // The second is firmware-sim's defect: an 8 x 8 patch 150 nm too thick.
    let fail = &recs[1];
    assert_eq!(fail.verdict, PassFail::Fail);
    assert_eq!(fail.regions[0].area_px, 64);
    assert_eq!(fail.regions[0].width, 8);
    assert!(fail.raw_kept, "failed samples keep their raw sweep");
    assert!(!recs[0].raw_kept);

    let names = folders(&out);
    assert_eq!(names.len(), 3, "{names:?}");
    let ids: Vec<&str> = recs.iter().map(|r| r.sample_id.as_str()).collect();
    assert_eq!(names, ids, "one folder per record, named by its id");
    for (i, id) in ids.iter().enumerate() {
        let f = out.join("samples").join(id);
        for file in [
            "summary.json",
            "thickness_nm.hdr",
            "thickness_nm.png",
            "oot_mask.hdr",
            "oot_mask.img",
            "overlay.png",
            "record.json",
        ] {
            assert!(f.join(file).exists(), "{id}/{file}");
        }
        let sum = Summary::read(&f).expect("summary");
        let line = sum.line.as_ref().expect("the line's record");
        assert_eq!(line.sample_id, *id);
        assert_eq!(sum.timestamp.as_ref(), Some(&recs[i].timestamp));
        assert!(sum.version.is_some() && !line.recipe.film.is_empty());
        assert_eq!(line.verdict.verdict, recs[i].verdict);
        assert!(sum.acquisition.as_ref().is_some_and(|a| a.complete));
        let mask = std::fs::read(f.join("oot_mask.img")).expect("mask");
        assert_eq!(mask.len(), 32 * 24);
        let out_px = mask.iter().filter(|&&m| m == 1).count();
        assert_eq!(out_px, recs[i].out_of_tolerance_px);
        let hdr = std::fs::read_to_string(f.join("oot_mask.hdr")).expect("hdr");
        assert!(hdr.contains("data type = 1"));
    }
    let fail_dir = out.join("samples").join(ids[1]).join("capture");
    let white = std::fs::read_to_string(fail_dir.join("white00.hdr")).expect("white");
    assert!(white.contains("data type = 12"), "references as uint16");
    let log = std::fs::read_to_string(out.join("inspect.log")).expect("log");
    assert_eq!(log.lines().filter(|l| l.contains(" sample S")).count(), 3);
    assert!(
        log.lines().all(|l| l.as_bytes().get(23) == Some(&b'Z')),
        "{log}"
    );

    if let Some(got) = got {
        // Records; `online`/`offline` on the status topic aside.
        let on_wire = || -> Vec<Record> {
            got.lock()
                .expect("lock")
                .iter()
                .filter(|p| p.starts_with('{'))
                .map(|p| serde_json::from_str::<Record>(p).expect("a record"))
                .collect()
        };
        let t0 = Instant::now();
        while on_wire().len() < records(&out).len() && t0.elapsed() < Duration::from_secs(10) {
            std::thread::sleep(Duration::from_millis(50));
        }
        assert_eq!(
            on_wire(),
            records(&out),
            "the broker got the records of results.jsonl"
        );
    }
}

/// Sample records of a results.jsonl being written: a line still being written is skipped.
fn samples_so_far(out: &Path) -> usize {
    std::fs::read_to_string(out.join("results.jsonl"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str::<Record>(l).ok())
        .filter(|r| r.as_sample().is_some())
        .count()
}

fn wait_for_samples(out: &Path, n: usize, child: &mut Child) {
    let t0 = Instant::now();
    while samples_so_far(out) < n {
        assert!(
            child.try_wait().expect("wait").is_none(),
            "inspect ended early"
        );
        assert!(t0.elapsed() < Duration::from_secs(120), "no samples");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// kill -9 mid-run, a torn line, a restart: numbering goes on, nothing lost or duplicated.
#[test]
fn restart_after_kill_9_continues_numbering() {
    let dir = tempdir();
    let rec = recipe(dir.path(), None, "");
    let out = dir.path().join("line");
    let mut child = inspect(&rec, &out, &[])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn");
    wait_for_samples(&out, 2, &mut child);
    // A second inspect on the same folder is refused while the first runs.
    let second = inspect(&rec, &out, &["--samples", "1"])
        .output()
        .expect("second");
    assert!(!second.status.success());
    assert!(String::from_utf8_lossy(&second.stderr).contains("another inspect"));
    // Let it get into the next sample, then SIGKILL.
    std::thread::sleep(Duration::from_millis(400));
    child.kill().expect("kill -9");
    child.wait().expect("reap");
    let before = samples(&out).len();
    // A crash in the middle of a line.
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(out.join("results.jsonl"))
        .expect("open");
    f.write_all(b"{\"kind\":\"sample\",\"sample_id\":\"S9")
        .expect("torn");
    drop(f);
    inspect_ok(&rec, &out, &["--samples", "2"]);
    let recs = samples(&out);
    assert!(recs.len() >= before + 2, "{} then {}", before, recs.len());
    let counters: Vec<u64> = recs.iter().map(|r| r.counter).collect();
    assert!(counters.windows(2).all(|w| w[1] > w[0]), "{counters:?}");
    let ids: Vec<&str> = recs.iter().map(|r| r.sample_id.as_str()).collect();
    let names = folders(&out);
    assert!(names.iter().all(|n| !n.starts_with(".tmp")), "{names:?}");
    assert_eq!(names, ids, "every folder has its record, once");
    let log = std::fs::read_to_string(out.join("inspect.log")).expect("log");
    assert!(log.contains("torn last line"), "{log}");
}

/// SIGTERM finishes the sample under way and exits 0.
#[test]
fn sigterm_finishes_the_sample_and_exits_0() {
    let dir = tempdir();
    let rec = recipe(dir.path(), None, "");
    let out = dir.path().join("line");
    let mut child = inspect(&rec, &out, &[])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    wait_for_samples(&out, 1, &mut child);
    std::thread::sleep(Duration::from_millis(200));
    let ok = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(ok.success());
    let t0 = Instant::now();
    let status = loop {
        if let Some(st) = child.try_wait().expect("wait") {
            break st;
        }
        assert!(t0.elapsed() < Duration::from_secs(60), "did not stop");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "{status:?}");
    let recs = samples(&out);
    assert_eq!(
        folders(&out).len(),
        recs.len(),
        "the sample under way was finished"
    );
    let log = std::fs::read_to_string(out.join("inspect.log")).expect("log");
    assert!(log.contains("\"stopped_by_signal\":true"), "{log}");
}

/// 200 samples' raw sweeps against a budget: kept sweeps never exceed it, newest kept.
#[test]
fn retention_keeps_raw_sweeps_under_budget_over_200_samples() {
    use filmscope::line::recipe::{RawPolicy, RetentionSpec};
    use filmscope::line::retention::{enforce_budget, keeps_raw, kept_sweeps};
    let dir = tempdir();
    let samples = dir.path().join("samples");
    let spec = RetentionSpec {
        raw: RawPolicy::EveryNth,
        every_n: 3,
        raw_budget_bytes: 200_000,
        ..RetentionSpec::default()
    };
    let mut kept_total = 0;
    for counter in 1..=200u64 {
        let pass = counter % 7 != 2;
        let f = samples.join(format!("S{counter:06}-20261125T000000Z"));
        std::fs::create_dir_all(&f).expect("folder");
        std::fs::write(f.join("summary.json"), b"{}").expect("summary");
        if keeps_raw(&spec, counter, pass) {
            kept_total += 1;
            let c = f.join("capture");
            std::fs::create_dir_all(&c).expect("capture");
            std::fs::write(
                c.join("a00.img"),
                vec![0u8; 10_000 + (counter as usize * 37) % 20_000],
            )
            .expect("raw");
        }
        enforce_budget(&samples, spec.raw_budget_bytes).expect("budget");
        let kept = kept_sweeps(&samples);
        let bytes: u64 = kept.iter().map(|(_, b)| b).sum();
        assert!(
            bytes <= spec.raw_budget_bytes,
            "{bytes} after sample {counter}"
        );
    }
    let kept = kept_sweeps(&samples);
    assert!(kept_total > 70, "{kept_total}");
    assert!(kept.len() >= 5 && kept.len() < kept_total, "{}", kept.len());
    // The newest kept sweep survives; the summaries of every sample stay.
    assert!(kept
        .last()
        .is_some_and(|(n, _)| n.starts_with("S000200") || n.starts_with("S000198")));
    assert_eq!(folders(dir.path()).len(), 200);
}

/// References rewritten as uint16 counts: rounded, and a lost row (NaN white) zero in both
/// white and dark so it still calibrates to NaN.
#[test]
fn references_become_uint16_counts() {
    use filmscope::io::{DataType, EnviHeader, EnviReader, EnviWriter, Interleave};
    let dir = tempdir();
    let (w, h, b) = (4, 3, 2);
    for (name, base) in [("white00", 3000.4f32), ("dark00", 60.6)] {
        let hd = EnviHeader::new(w, h, b, DataType::F32, Interleave::Bsq);
        let mut wr = EnviWriter::create(dir.path().join(format!("{name}.hdr")), &hd).expect("w");
        for band in 0..b {
            for row in 0..h {
                let mut v = vec![base; w];
                if name == "white00" && row == 1 && band == 1 {
                    v[2] = f32::NAN;
                }
                wr.write_band_row(band, row, &v).expect("row");
            }
        }
        wr.finish().expect("finish");
    }
    let done = filmscope::line::retention::references_to_u16(dir.path()).expect("convert");
    assert_eq!(done.len(), 2);
    for (name, want) in [("white00", 3000.0f32), ("dark00", 61.0)] {
        let mut r = EnviReader::open(dir.path().join(format!("{name}.hdr"))).expect("open");
        assert_eq!(r.header().data_type, DataType::U16);
        let mut row = vec![0f32; w];
        while let Some(at) = r.next_band_row(&mut row).expect("row") {
            for (x, &v) in row.iter().enumerate() {
                let lost = at.band == 1 && at.line == 1 && x == 2;
                assert_eq!(v, if lost { 0.0 } else { want }, "{name} {at} x {x}");
            }
        }
    }
}

/// Recipe errors reach the command line as one line naming the file and key.
#[test]
fn a_bad_recipe_is_one_line_naming_file_and_key() {
    let dir = tempdir();
    let p = dir.path().join("bad.toml");
    std::fs::write(&p, DEMO.replace("tolerance = 0.03", "tolerance = 0")).expect("write");
    let run = inspect(&p, &dir.path().join("o"), &["--samples", "1"])
        .output()
        .expect("run");
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains("bad.toml: index.tolerance = 0: must be a positive number"),
        "{err}"
    );
}

/// The hostile values of a recipe (a billion rotated files, a history of 1e9 or 1e18
/// samples, rotation past 1e18 bytes) are refused at load with one line naming the file,
/// the key, the value and its range, before anything is opened.
#[test]
fn hostile_recipe_values_are_refused_with_one_line() {
    let dir = tempdir();
    for (from, to, says) in [
        (
            "results_keep = 8",
            "results_keep = 1_000_000_000",
            "retention.results_keep = 1000000000: expected 1 to 1000",
        ),
        (
            "history = 500",
            "history = 1_000_000_000",
            "spc.history = 1000000000: expected 2 to 10000",
        ),
        (
            "history = 500",
            "history = 1_000_000_000_000_000_000",
            "spc.history = 1000000000000000000: expected 2 to 10000",
        ),
        ("history = 500", "history = 1e18", "spc.history"),
        (
            "results_rotate_bytes = 67_108_864",
            "results_rotate_bytes = 1_000_000_000_000_000_000",
            "retention.results_rotate_bytes = 1000000000000000000: expected 4096 to 1073741824",
        ),
    ] {
        let p = dir.path().join("hostile.toml");
        assert!(DEMO.contains(from), "{from}");
        std::fs::write(&p, DEMO.replace(from, to)).expect("write");
        let out = dir.path().join("o");
        let run = inspect(&p, &out, &["--samples", "1"])
            .output()
            .expect("run");
        assert!(!run.status.success(), "{to}");
        let err = String::from_utf8_lossy(&run.stderr);
        assert_eq!(err.lines().count(), 1, "{to}: {err}");
        assert!(
            err.contains("hostile.toml") && err.contains(says),
            "{to}: {err}"
        );
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists(), "nothing opened");
    }
}

/// A start-up that SIGINT/SIGTERM stopped (the flag set) ends before its next step with an
/// error saying so, measures nothing and leaves no lock.
#[test]
fn a_signal_stops_start_up() {
    use filmscope::line::inspect::{InspectOptions, Line};
    use filmscope::line::recipe::Recipe;
    let dir = tempdir();
    let rec = recipe(dir.path(), None, "");
    let out = dir.path().join("line");
    let opts = InspectOptions {
        rig: filmscope::rig::RigConfig::load(&rig()).expect("rig"),
        recipe: Recipe::load(&rec).expect("recipe"),
        recipe_path: rec.clone(),
        out: out.clone(),
        sim: true,
        status_port: None,
        mqtt_port: None,
        modbus: None,
        stop: Arc::new(std::sync::atomic::AtomicBool::new(true)),
    };
    let e = Line::open(opts).err().expect("stopped");
    assert!(e.is_interrupted(), "{e}");
    assert!(!out.join("inspect.lock").exists());
    assert!(!out.join("samples").exists(), "nothing opened");
}

/// A held index the film disagrees with is re-solved over the rig's whole range, and the
/// sample fails on its index; `solve` searches the whole range at once.
#[test]
fn a_disagreeing_held_index_is_re_solved() {
    let dir = tempdir();
    let base = recipe(dir.path(), None, "");
    let text = std::fs::read_to_string(&base).expect("recipe");
    let hold = dir.path().join("hold.toml");
    std::fs::write(
        &hold,
        text.replace("nominal = 2.10 ", "nominal = 2.05 ")
            .replace("mode = \"carry\"", "mode = \"hold\""),
    )
    .expect("write");
    let out = dir.path().join("hold");
    inspect_ok(&hold, &out, &["--samples", "1"]);
    let r = &samples(&out)[0];
    assert!(r.index_resolved, "{r:?}");
    let n = r.refractive_index.expect("index");
    assert!((n - 2.10).abs() < 0.01, "re-solved index {n}");
    assert_eq!(r.verdict, PassFail::Fail);
    assert!(r.reasons[0].starts_with("index 2.1"), "{r:?}");
    let solve = dir.path().join("solve.toml");
    std::fs::write(&solve, text.replace("mode = \"carry\"", "mode = \"solve\"")).expect("write");
    let out = dir.path().join("solve");
    inspect_ok(&solve, &out, &["--samples", "1"]);
    let r = &samples(&out)[0];
    assert!(!r.index_resolved);
    assert_eq!(r.verdict, PassFail::Pass, "{r:?}");
}

/// A crash after a sample's folder was renamed into place but before its line was
/// appended: the restart appends the record from the folder's record.json, once.
#[test]
fn a_folder_without_its_line_gets_it_on_restart() {
    let dir = tempdir();
    let rec = recipe(dir.path(), None, "");
    let out = dir.path().join("line");
    inspect_ok(&rec, &out, &["--samples", "2"]);
    let text = std::fs::read_to_string(out.join("results.jsonl")).expect("results");
    let first_line = text.lines().next().expect("line");
    let lost: SampleRecord =
        serde_json::from_str(text.lines().last().expect("last")).expect("a sample record");
    std::fs::write(out.join("results.jsonl"), format!("{first_line}\n")).expect("cut");
    inspect_ok(&rec, &out, &["--samples", "1"]);
    let recs = samples(&out);
    let counters: Vec<u64> = recs.iter().map(|r| r.counter).collect();
    assert_eq!(counters, vec![1, 2, 3]);
    assert_eq!(recs[1], lost, "the record came back as it was");
    let log = std::fs::read_to_string(out.join("inspect.log")).expect("log");
    assert!(log.contains("recovered: record of S000002"), "{log}");
}

/// A record missing from the middle of the log (an append a full disk failed, the line
/// went on): the restart appends it from the folder's record.json, once, though later
/// samples have their records.
#[test]
fn a_record_missing_below_the_last_counter_is_reconciled_on_restart() {
    let dir = tempdir();
    let rec = recipe(dir.path(), None, "");
    let out = dir.path().join("line");
    inspect_ok(&rec, &out, &["--samples", "3"]);
    let text = std::fs::read_to_string(out.join("results.jsonl")).expect("results");
    let (lost, kept): (Vec<&str>, Vec<&str>) = text
        .lines()
        .partition(|l| l.contains("\"counter\":2,") && l.contains("\"kind\":\"sample\""));
    assert_eq!(lost.len(), 1, "{text}");
    let lost: SampleRecord = serde_json::from_str(lost[0]).expect("a sample record");
    std::fs::write(out.join("results.jsonl"), kept.join("\n") + "\n").expect("cut");
    inspect_ok(&rec, &out, &["--samples", "1"]);
    let recs = samples(&out);
    let mut counters: Vec<u64> = recs.iter().map(|r| r.counter).collect();
    assert_eq!(
        counters,
        vec![1, 3, 2, 4],
        "appended at restart, before the next sample"
    );
    counters.sort_unstable();
    counters.dedup();
    assert_eq!(counters.len(), 4, "each once");
    // As it was but for `seq`, its new place in the log.
    let strip = |v: SampleRecord| SampleRecord { seq: None, ..v };
    assert_eq!(
        strip(recs[2].clone()),
        strip(lost),
        "the record came back as it was"
    );
    let log = std::fs::read_to_string(out.join("inspect.log")).expect("log");
    assert!(log.contains("recovered: record of S000002"), "{log}");
}

/// Below the recipe's free-space floor no sample is measured: an alarm record names the
/// free bytes and the floor, and the run stops at once with one line saying the disk is
/// full (not that the rig failed).
#[test]
fn below_the_free_space_floor_the_line_stops_with_an_alarm() {
    let dir = tempdir();
    let rec = recipe(
        dir.path(),
        None,
        "[retention]\nmin_free_bytes = 1_000_000_000_000_000\n",
    );
    let out = dir.path().join("line");
    let run = inspect(&rec, &out, &["--samples", "3"])
        .output()
        .expect("run");
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    let errors: Vec<_> = err
        .lines()
        .filter(|l| l.starts_with("filmscope:"))
        .collect();
    assert_eq!(errors.len(), 1, "{err}");
    assert!(
        errors[0].contains("disk full") && errors[0].contains("retention.min_free_bytes"),
        "{err}"
    );
    assert!(!err.contains("rig"), "{err}");
    let recs = records(&out);
    assert_eq!(recs.len(), 1, "{recs:?}");
    let Record::Alarm(alarm) = &recs[0] else {
        panic!("not an alarm: {recs:?}");
    };
    assert_eq!(alarm.variable, AlarmVariable::DiskFreeBytes);
    assert!(
        alarm.sample_id.is_none() && alarm.floor.is_some(),
        "{alarm:?}"
    );
    assert!(folders(&out).is_empty(), "nothing measured");
}

/// Without `--sim` and without the devices, each sample's sweep fails: the log gets a
/// device error line a sample, `results.jsonl` a `sample_failed` alarm for each counter and
/// no sample record, no folder is written, and three in a row stop the run with an error.
#[test]
fn device_errors_are_logged_and_three_in_a_row_stop() {
    let dir = tempdir();
    let rec = recipe(dir.path(), None, "");
    let out = dir.path().join("line");
    let run = filmscope()
        .args([
            "inspect",
            "--rig",
            s(&rig()),
            "--recipe",
            s(&rec),
            "--out",
            s(&out),
        ])
        .output()
        .expect("run");
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("three samples in a row failed"), "{err}");
    let log = std::fs::read_to_string(out.join("inspect.log")).expect("log");
    assert_eq!(log.matches(" device error: sample S").count(), 3, "{log}");
    assert!(samples(&out).is_empty());
    let failed: Vec<(u64, bool)> = records(&out)
        .into_iter()
        .filter_map(|r| match r {
            Record::Alarm(a) if a.rule.to_string() == "sample_failed" => {
                Some((a.counter, a.sample_id.is_some_and(|i| i.starts_with('S'))))
            }
            _ => None,
        })
        .collect();
    assert_eq!(failed, [(1, true), (2, true), (3, true)]);
    assert!(folders(&out).is_empty(), "no half-written folder left");
}

/// `inspect --reference` measures the recipe's certified sample first: within tolerance a
/// `reference` record with its drift; certified 20 nm off, the same plus an alarm.
#[test]
fn a_reference_check_records_its_drift_and_alarms_beyond_tolerance() {
    let dir = tempdir();
    for (certified, within) in [(620.0, true), (600.0, false)] {
        let rec = recipe(dir.path(), None, "");
        let mut text = std::fs::read_to_string(&rec).expect("recipe");
        text.push_str(&format!(
            "\n[reference]\nname = \"REF-620\"\nthickness_nm = {certified:?}\nindex = 2.1\ntolerance_nm = 3.0\ntolerance_index = 0.01\n"
        ));
        std::fs::write(&rec, text).expect("recipe");
        let out = dir.path().join(format!("line-{certified}"));
        inspect_ok(&rec, &out, &["--samples", "1", "--reference"]);
        let all = records(&out);
        let r = all
            .iter()
            .find_map(|r| match r {
                Record::Reference(r) => Some(r),
                _ => None,
            })
            .expect("a reference record");
        assert_eq!(r.within, within, "{r:?}");
        let drift = r.drift.thickness_nm.expect("drift");
        assert!((drift - (620.0 - certified)).abs() < 3.0, "{r:?}");
        assert!(r.drift.index.expect("index drift").abs() < 0.01);
        assert!(out.join(&r.folder).join("summary.json").is_file());
        let alarm = all.iter().any(|a| {
            matches!(a, Record::Alarm(a) if a.rule == AlarmRule::Fault(LineFault::ReferenceDrift))
        });
        assert_eq!(alarm, !within, "{all:?}");
        assert_eq!(samples(&out).len(), 1);
    }
    // Without a [reference] table the flag is one line naming the recipe.
    let rec = recipe(dir.path(), None, "");
    let run = inspect(
        &rec,
        &dir.path().join("none"),
        &["--samples", "1", "--reference"],
    )
    .output()
    .expect("run");
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.contains("recipe.toml: --reference needs a [reference] table"),
        "{err}"
    );
}
