//! The status page of `filmscope inspect` in headless Chromium: the page, loaded once, shows
//! a sample published after it loaded (it polls `/api/latest`), with the trend's control
//! limits; the JSON API and Prometheus `/metrics` over plain HTTP; hostile clients, also
//! under a task limit (a pids cgroup, or RLIMIT_NPROC when not root); `filmscope status`
//! serving the last state once `inspect` has stopped.
//!
//! Chromium is `FILMSCOPE_CHROMIUM` if set, else `chromium` or `chromium-browser` on the
//! PATH; with `FILMSCOPE_REQUIRE_CHROMIUM=1` a missing browser is a failure.

use crate::common;

use std::io::{Read, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use filmscope::line::status::StatusServer;
use filmscope::record::line::{
    AlarmRecord, AlarmRule, AlarmVariable, IndexMode, PassFail, Reading, SampleRecord,
    ThicknessSummary,
};
use serde_json::{json, Value};

fn chromium() -> Result<PathBuf, String> {
    if let Some(p) = std::env::var_os("FILMSCOPE_CHROMIUM") {
        return Ok(PathBuf::from(p));
    }
    for name in ["chromium", "chromium-browser"] {
        let found = Command::new(name)
            .arg("--version")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if found {
            return Ok(PathBuf::from(name));
        }
    }
    Err("neither FILMSCOPE_CHROMIUM nor chromium / chromium-browser on the PATH".into())
}

fn get(addr: std::net::SocketAddr, path: &str) -> (String, String) {
    let mut s = std::net::TcpStream::connect(addr).expect("connect");
    // A bound, so that a server that stopped answering fails the test instead of hanging it.
    s.set_read_timeout(Some(Duration::from_secs(60)))
        .expect("timeout");
    write!(s, "GET {path} HTTP/1.0\r\nHost: x\r\n\r\n").expect("send");
    let mut body = String::new();
    s.read_to_string(&mut body)
        .unwrap_or_else(|e| panic!("{path}: no answer: {e}"));
    let (head, rest) = body.split_once("\r\n\r\n").expect("http");
    (head.to_owned(), rest.to_owned())
}

fn record(id: &str, verdict: &str, mean: f64) -> SampleRecord {
    let pass = verdict == "PASS";
    SampleRecord {
        seq: None,
        sample_id: id.into(),
        counter: 1,
        timestamp: "2026-11-25T23:00:00.000Z".into(),
        film: "test film".into(),
        recipe: "demo.toml".into(),
        lot: None,
        operator: None,
        verdict: PassFail::of(pass),
        reasons: if pass {
            Vec::new()
        } else {
            vec!["mean thickness out".into()]
        },
        refractive_index: Some(2.1),
        index_mode: IndexMode::Hold,
        index_resolved: false,
        thickness_nm: ThicknessSummary {
            mean: Some(mean),
            std: Some(3.0),
            min: Some(mean - 9.0),
            max: Some(mean + 9.0),
        },
        valid_fraction: 0.99,
        out_of_tolerance_px: 0,
        regions: Vec::new(),
        raw_kept: false,
        folder: format!("samples/{id}"),
        latency_ms: 12.5,
        version: "0.1.0".into(),
        sim_sample: None,
    }
}

fn alarm(id: &str, value: f64) -> AlarmRecord {
    AlarmRecord {
        seq: None,
        sample_id: Some(id.into()),
        counter: 1,
        timestamp: "2026-11-25T23:00:00.100Z".into(),
        variable: AlarmVariable::ThicknessMeanNm,
        rule: AlarmRule::Nelson(1),
        text: "a point beyond 3 sigma".into(),
        value: Some(Reading::Real(value)),
        center: Some(620.0),
        ucl: Some(626.0),
        lcl: Some(614.0),
        floor: None,
        index_drift: None,
    }
}

fn history(means: &[f64]) -> Value {
    let points: Vec<Value> = means
        .iter()
        .enumerate()
        .map(|(i, m)| json!({"sample_id": format!("S{:06}", i + 1), "index": 2.1, "thickness_mean": m, "thickness_std": 3.0, "pass": true}))
        .collect();
    json!({"points": points,
           "limits": {"thickness_mean_nm": {"center": 620.0, "ucl": 626.0, "lcl": 614.0, "sigma": 2.0, "mr_bar": 2.256, "n": 8},
                      "refractive_index": {"center": 2.1, "ucl": 2.106, "lcl": 2.094, "sigma": 0.002, "mr_bar": 0.0023, "n": 8}},
           "capability": {"thickness_mean_nm": {"cpk": 1.5, "ppk": 1.4, "mean": 620.0, "sigma_within": 2.0, "sigma_overall": 2.1},
                          "refractive_index": {"cpk": 2.25, "ppk": 2.0, "mean": 2.1, "sigma_within": 0.002, "sigma_overall": 0.0022}},
           "spec": {"lsl": 570.0, "usl": 670.0, "index_lsl": 2.07, "index_usl": 2.13}})
}

#[test]
fn api_and_metrics_answer_over_http() {
    let server = StatusServer::start("127.0.0.1", 0, "test film").expect("server");
    assert!(server.addr().ip().is_loopback());
    let (head, body) = get(server.addr(), "/api/latest");
    assert!(
        head.starts_with("HTTP/1.") && head.contains("200"),
        "{head}"
    );
    let v: Value = serde_json::from_str(&body).expect("json");
    assert!(v["sample"].is_null());
    server.publish_sample(
        &record("S000001-A", "FAIL", 640.0),
        None,
        history(&[640.0]),
        &[alarm("S000001-A", 640.0)],
    );
    // The API's JSON, as the page and other clients read it.
    let v: Value = serde_json::from_str(&get(server.addr(), "/api/latest").1).expect("json");
    assert_eq!(v["sample"]["sample_id"], "S000001-A");
    assert_eq!(v["sample"]["kind"], "sample");
    assert_eq!(v["alarms"][0]["rule"], 1);
    assert_eq!(v["alarms"][0]["kind"], "alarm");
    let h: Value = serde_json::from_str(&get(server.addr(), "/api/history").1).expect("json");
    assert_eq!(h["points"].as_array().map(Vec::len), Some(1));
    server.set_labels("line7", "zns \"ar\".toml");
    let (_, m) = get(server.addr(), "/metrics");
    let labels = r#"{line="line7",recipe="zns \"ar\".toml"}"#;
    for line in [
        format!("filmscope_samples_total{labels} 1"),
        format!("filmscope_samples_failed_total{labels} 1"),
        format!("filmscope_alarms_total{labels} 1"),
        format!("filmscope_last_pass{labels} 0"),
        format!("filmscope_last_thickness_mean_nm{labels} 640.0"),
        format!("filmscope_thickness_cpk{labels} 1.5"),
        "# TYPE filmscope_samples_total counter".to_owned(),
        "# TYPE filmscope_latency_seconds histogram".to_owned(),
        // 12.5 ms: in the 0.025 s bucket and every one above.
        r#"filmscope_latency_seconds_bucket{line="line7",recipe="zns \"ar\".toml",le="0.01"} 0"#
            .to_owned(),
        r#"filmscope_latency_seconds_bucket{line="line7",recipe="zns \"ar\".toml",le="0.025"} 1"#
            .to_owned(),
        r#"filmscope_latency_seconds_bucket{line="line7",recipe="zns \"ar\".toml",le="+Inf"} 1"#
            .to_owned(),
        format!("filmscope_latency_seconds_count{labels} 1"),
    ] {
        assert!(m.lines().any(|l| l == line), "{line} in\n{m}");
    }
    assert!(
        m.lines()
            .any(|l| l.starts_with("filmscope_last_sample_timestamp_seconds{")),
        "{m}"
    );
    let (head, _) = get(server.addr(), "/nothing");
    assert!(head.contains("404"), "{head}");
}

#[test]
fn status_page_shows_a_new_sample_without_reload_in_chromium() {
    let browser = match chromium() {
        Ok(b) => b,
        Err(why) => {
            let required = std::env::var("FILMSCOPE_REQUIRE_CHROMIUM").is_ok_and(|v| v == "1");
            assert!(!required, "FILMSCOPE_REQUIRE_CHROMIUM=1 but {why}");
            eprintln!("skipped: no headless browser ({why})");
            return;
        }
    };
    let dir = common::tempdir();
    let server = StatusServer::start("127.0.0.1", 0, "demo film").expect("server");
    let means = [618.0, 621.0, 619.5, 622.0, 620.0, 617.0, 623.0, 620.5];
    server.publish_sample(
        &record("S000001-FIRST", "PASS", 620.0),
        None,
        history(&means),
        &[],
    );
    let url = server.url();
    let stdout_path = dir.path().join("dom.html");
    let mut child = Command::new(&browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--virtual-time-budget=15000",
            "--dump-dom",
        ])
        .arg(format!(
            "--user-data-dir={}",
            dir.path().join("profile").display()
        ))
        .arg(&url)
        .stdout(std::fs::File::create(&stdout_path).expect("stdout"))
        .stderr(Stdio::null())
        .spawn()
        .expect("start chromium");
    // The new sample arrives once the page has been served: only polling can show it.
    let t0 = Instant::now();
    while server.page_hits() == 0 {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "chromium never asked for the page"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
    let mut means2 = means.to_vec();
    means2.push(650.0);
    // An alarm whose text is markup: shown as text, not made into elements.
    let mut hostile = alarm("S000002-SECOND", 650.0);
    hostile.text = "<i>x</i> & co".into();
    server.publish_sample(
        &record("S000002-SECOND", "FAIL", 650.0),
        None,
        history(&means2),
        &[hostile],
    );
    let t0 = Instant::now();
    while child.try_wait().expect("wait").is_none() {
        if t0.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("chromium took over 120 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let dom = std::fs::read_to_string(&stdout_path).expect("dom");
    assert_eq!(server.page_hits(), 1, "the page was loaded once");
    assert!(
        dom.contains("id=\"sample-id\">S000002-SECOND<"),
        "new sample shown:\n{dom}"
    );
    assert!(dom.contains("class=\"v FAIL\""), "verdict shown");
    assert!(dom.contains("mean thickness out"), "reasons shown");
    assert!(
        dom.contains("(&lt;i&gt;x&lt;/i&gt; &amp; co)") && !dom.contains("<i>x</i>"),
        "alarm text escaped:\n{dom}"
    );
    assert!(dom.contains("id=\"trend-svg\""), "trend drawn");
    for l in ["UCL", "LCL", "CL", "USL", "LSL"] {
        assert!(
            dom.contains(&format!(">{l}</text>")),
            "{l} line on the trend"
        );
    }
    assert!(dom.contains("Cpk 1.50"), "capability shown");
    assert!(dom.contains("id=\"trend-index-svg\""), "index trend drawn");
    assert!(dom.contains("Cpk 2.25"), "index capability shown");
    assert!(
        dom.contains("2 samples since start: 1 passed, 1 failed"),
        "counts shown"
    );
    // The records are a day old: the page says the line has stopped.
    assert!(dom.contains("STALE: no sample for"), "stale banner:\n{dom}");
    let polls: u32 = dom
        .split("data-polls=\"")
        .nth(1)
        .and_then(|r| r.split('"').next())
        .and_then(|n| n.parse().ok())
        .expect("data-polls");
    assert!(polls >= 2, "polled {polls} times");
}

/// Threads of this process.
fn threads() -> usize {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find_map(|l| l.strip_prefix("Threads:"))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(0)
}

/// Connections a hostile client holds open against `addr` (loopback only): `half_open`
/// requests whose head never ends, a request announcing a 2 GB body it never sends, and
/// one whose header is 1 MiB. Returns the sockets (dropping them closes them) and what the
/// oversized header got back.
fn attack(addr: std::net::SocketAddr, half_open: usize) -> (Vec<std::net::TcpStream>, String) {
    assert!(addr.ip().is_loopback());
    let mut held = Vec::new();
    for _ in 0..half_open {
        let mut s = std::net::TcpStream::connect(addr).expect("connect");
        s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\nX-Slow: ")
            .expect("send");
        held.push(s);
    }
    for head in [
        "POST /api/latest HTTP/1.1\r\nHost: x\r\nContent-Length: 2000000000\r\n\r\n",
        "GET /api/latest HTTP/1.1\r\nHost: x\r\nContent-Length: 2000000000\r\n\r\n",
    ] {
        let mut s = std::net::TcpStream::connect(addr).expect("connect");
        s.write_all(head.as_bytes()).expect("send");
        held.push(s);
    }
    let mut big = std::net::TcpStream::connect(addr).expect("connect");
    big.set_read_timeout(Some(Duration::from_secs(30)))
        .expect("timeout");
    let mut head = b"GET / HTTP/1.1\r\nHost: x\r\nX-Big: ".to_vec();
    head.resize(head.len() + (1 << 20), b'a');
    head.extend_from_slice(b"\r\n\r\n");
    // The server stops reading at its limit: the rest may not be taken.
    let _ = big.write_all(&head);
    let mut answer = Vec::new();
    let _ = big.read_to_end(&mut answer);
    (held, String::from_utf8_lossy(&answer).into_owned())
}

/// A 2 GB `Content-Length` with no body, 300 half-open requests and a 1 MiB header: the page
/// keeps answering, the big header gets 431, and the server takes no thread per client.
#[test]
fn hostile_clients_do_not_knock_the_page_over() {
    let server = StatusServer::start("127.0.0.1", 0, "test film").expect("server");
    let before = threads();
    let (mut held, big) = attack(server.addr(), 300);
    assert!(big.is_empty() || big.starts_with("HTTP/1.1 431"), "{big}");
    for path in ["/api/latest", "/metrics", "/"] {
        let (head, _) = get(server.addr(), path);
        assert!(head.contains(" 200 "), "{path}: {head}");
    }
    // Threads do not follow the clients (other tests of this file may start a few).
    assert!(
        threads() < before + 20,
        "{} threads, {before} before",
        threads()
    );
    // The request that announced a body is answered without it, and closed.
    for s in held.iter_mut().rev().take(2) {
        s.set_read_timeout(Some(Duration::from_secs(30)))
            .expect("timeout");
        let mut answer = String::new();
        let _ = s.read_to_string(&mut answer);
        assert!(
            answer.starts_with("HTTP/1.1 200") || answer.starts_with("HTTP/1.1 405"),
            "{answer}"
        );
    }
    drop(held);
    let (head, _) = get(server.addr(), "/api/latest");
    assert!(head.contains(" 200 "), "{head}");
}

/// The demo recipe without its broker, written into `dir`.
fn recipe(dir: &std::path::Path) -> PathBuf {
    let demo = include_str!("../config/recipes/demo.toml");
    let mut out = String::new();
    let mut skip = false;
    for line in demo.lines() {
        if line.starts_with('[') {
            skip = line.starts_with("[mqtt]");
        }
        if !skip {
            out.push_str(line);
            out.push('\n');
        }
    }
    let p = dir.join("recipe.toml");
    std::fs::write(&p, out).expect("recipe");
    p
}

fn inspect(recipe: &std::path::Path, out: &std::path::Path, port: &str) -> Command {
    inspect_n(recipe, out, port, "4")
}

/// `inspect --sim` of `samples` samples with its status page on `port`.
fn inspect_n(
    recipe: &std::path::Path,
    out: &std::path::Path,
    port: &str,
    samples: &str,
) -> Command {
    let mut c = common::filmscope();
    c.args([
        "inspect",
        "--rig",
        concat!(env!("CARGO_MANIFEST_DIR"), "/config/rig.toml"),
        "--sim",
        "--recipe",
        common::s(recipe),
        "--out",
        common::s(out),
        "--samples",
        samples,
        "--status-port",
        port,
    ]);
    c
}

/// `inspect` under the same attack while it measures: every sample is measured and
/// recorded, and the page answers throughout.
#[test]
fn inspect_keeps_measuring_under_hostile_clients() {
    let dir = common::tempdir();
    let rec = recipe(dir.path());
    let out = dir.path().join("line");
    let mut child = inspect(&rec, &out, "0")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("inspect");
    let mut err = std::io::BufReader::new(child.stderr.take().expect("stderr"));
    let mut first = String::new();
    std::io::BufRead::read_line(&mut err, &mut first).expect("read");
    let url = first
        .trim()
        .strip_prefix("status page: http://")
        .and_then(|u| u.strip_suffix('/'))
        .unwrap_or_else(|| panic!("{first}"));
    let addr: std::net::SocketAddr = url.parse().expect("address");
    let (held, _) = attack(addr, 300);
    let (head, _) = get(addr, "/api/latest");
    assert!(head.contains(" 200 "), "{head}");
    // Bounded, so that an inspect that cannot stop fails the test instead of hanging it.
    let deadline = Instant::now() + Duration::from_secs(300);
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("inspect did not exit while hostile clients were connected");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let mut rest = String::new();
    let _ = err.read_to_string(&mut rest);
    assert!(status.success(), "{rest}");
    drop(held);
    let samples = std::fs::read_to_string(out.join("results.jsonl"))
        .expect("results")
        .lines()
        .filter(|l| l.contains("\"kind\":\"sample\""))
        .count();
    assert_eq!(samples, 4);
}

/// A status page that cannot listen (its port taken) stops `inspect` at start with one
/// line naming the address.
#[test]
fn a_status_page_that_cannot_listen_is_an_error_at_start() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = taken.local_addr().expect("addr").port().to_string();
    let dir = common::tempdir();
    let rec = recipe(dir.path());
    let run = inspect(&rec, &dir.path().join("line"), &port)
        .output()
        .expect("run");
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains(&format!("status page on 127.0.0.1:{port}: cannot listen")),
        "{err}"
    );
}

/// The Grafana dashboard shipped in `docs/grafana/` asks only for metrics `/metrics`
/// exposes, each with the `line` and `recipe` labels it filters on.
#[test]
fn the_grafana_dashboard_queries_metrics_the_server_exposes() {
    let path = format!(
        "{}/docs/grafana/filmscope-inspect.json",
        env!("CARGO_MANIFEST_DIR")
    );
    let dash: Value =
        serde_json::from_str(&std::fs::read_to_string(&path).expect("dashboard")).expect("json");
    let server = StatusServer::start("127.0.0.1", 0, "test film").expect("server");
    server.set_labels("line1", "demo.toml");
    server.publish_sample(
        &record("S000001-A", "PASS", 620.0),
        None,
        history(&[620.0]),
        &[],
    );
    let (_, m) = get(server.addr(), "/metrics");
    let mut asked = 0;
    for panel in dash["panels"].as_array().expect("panels") {
        for target in panel["targets"].as_array().expect("targets") {
            let expr = target["expr"].as_str().expect("expr");
            for name in expr
                .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .filter(|w| w.starts_with("filmscope_"))
            {
                asked += 1;
                let wanted = format!("{name}{{line=\"line1\",recipe=\"demo.toml\"");
                assert!(
                    m.contains(&wanted),
                    "{name} (panel {}) not in\n{m}",
                    panel["title"]
                );
            }
        }
    }
    assert!(asked >= 10, "{asked} metrics asked for");
}

/// The sample records of `out`'s results log.
fn sample_records(out: &std::path::Path) -> Vec<Value> {
    std::fs::read_to_string(out.join("results.jsonl"))
        .expect("results")
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter(|r| r["kind"] == "sample")
        .collect()
}

/// `filmscope status OUT` on any free port: the child and its address.
struct StatusChild {
    child: std::process::Child,
    addr: std::net::SocketAddr,
    /// Its standard error, kept open while it runs.
    _err: std::io::BufReader<std::process::ChildStderr>,
}

impl Drop for StatusChild {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn serve_status(out: &std::path::Path) -> StatusChild {
    let mut child = common::filmscope()
        .args(["status", common::s(out), "--listen", "127.0.0.1:0"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("status");
    let mut err = std::io::BufReader::new(child.stderr.take().expect("stderr"));
    let mut first = String::new();
    std::io::BufRead::read_line(&mut err, &mut first).expect("read");
    let addr = first
        .trim()
        .strip_prefix("status page: http://")
        .and_then(|u| u.strip_suffix('/'))
        .and_then(|u| u.parse().ok())
        .unwrap_or_else(|| panic!("{first}"));
    StatusChild {
        child,
        addr,
        _err: err,
    }
}

/// The body of `GET path` as bytes, with the response head.
fn get_bytes(addr: std::net::SocketAddr, path: &str) -> (String, Vec<u8>) {
    let mut s = std::net::TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(60)))
        .expect("timeout");
    write!(s, "GET {path} HTTP/1.0\r\nHost: x\r\n\r\n").expect("send");
    let mut all = Vec::new();
    s.read_to_end(&mut all).expect("answer");
    let at = all.windows(4).position(|w| w == b"\r\n\r\n").expect("http");
    (
        String::from_utf8_lossy(&all[..at]).into_owned(),
        all[at + 4..].to_vec(),
    )
}

/// Once `inspect` has stopped, `filmscope status OUT` serves the page, `/api/latest`,
/// `/api/history`, `/latest.png` and `/metrics` as the line left them; `inspect` leaves
/// its snapshot whole (no temporary beside it).
#[test]
fn the_page_keeps_the_last_state_after_inspect_stops() {
    let dir = common::tempdir();
    let rec = recipe(dir.path());
    let out = dir.path().join("line");
    let run = inspect(&rec, &out, "0").output().expect("inspect");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let recs = sample_records(&out);
    assert_eq!(recs.len(), 4);
    let last = recs[3]["sample_id"].as_str().expect("id").to_owned();
    let names: Vec<String> = std::fs::read_dir(&out)
        .expect("out")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().any(|n| n == "status.json"), "{names:?}");
    assert!(!names.iter().any(|n| n.starts_with('.')), "{names:?}");

    let served = serve_status(&out);
    let (head, body) = get(served.addr, "/api/latest");
    assert!(head.contains(" 200 "), "{head}");
    let latest: Value = serde_json::from_str(&body).expect("json");
    assert_eq!(latest["sample"]["sample_id"], last.as_str(), "{latest}");
    assert_eq!(latest["sample"], recs[3], "the record as logged");
    assert_eq!(latest["counts"]["samples"], 4, "{latest}");
    let (_, page) = get(served.addr, "/");
    assert!(page.contains(&last) && page.contains("ZnS-like"), "{page}");
    let (_, history) = get(served.addr, "/api/history");
    let history: Value = serde_json::from_str(&history).expect("json");
    assert_eq!(history["points"].as_array().map(Vec::len), Some(4));
    assert!(history["spec"]["lsl"].is_number(), "{history}");
    let (head, png) = get_bytes(served.addr, "/latest.png");
    assert!(
        head.contains(" 200 ") && head.contains("image/png"),
        "{head}"
    );
    let on_disk = std::fs::read(out.join("samples").join(&last).join("overlay.png")).expect("png");
    assert_eq!(png, on_disk, "the latest sample's overlay");
    let (_, m) = get(served.addr, "/metrics");
    assert!(
        m.contains("filmscope_samples_total{line=\"line1\",recipe=\"recipe.toml\"} 4"),
        "{m}"
    );
}

/// A snapshot older than the log (a stop between a record and the snapshot) is brought
/// up to date from the log; a folder without a snapshot is shown from its log alone.
#[test]
fn the_status_command_catches_up_with_the_results_log() {
    let dir = common::tempdir();
    let rec = recipe(dir.path());
    let out = dir.path().join("line");
    let run = inspect_n(&rec, &out, "0", "2").output().expect("inspect");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let older = std::fs::read(out.join("status.json")).expect("snapshot");
    let run = inspect_n(&rec, &out, "0", "1")
        .output()
        .expect("inspect again");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let recs = sample_records(&out);
    assert_eq!(recs.len(), 3);
    std::fs::write(out.join("status.json"), older).expect("older snapshot back");
    let latest = |out: &std::path::Path| -> Value {
        let served = serve_status(out);
        serde_json::from_str(&get(served.addr, "/api/latest").1).expect("json")
    };
    let l = latest(&out);
    assert_eq!(l["sample"], recs[2], "{l}");
    assert_eq!(
        l["counts"]["samples"], 3,
        "2 in the snapshot, 1 from the log: {l}"
    );
    std::fs::remove_file(out.join("status.json")).expect("rm");
    let l = latest(&out);
    assert_eq!(l["sample"], recs[2], "{l}");
    assert_eq!(l["counts"]["samples"], 3, "{l}");
}

/// A folder that is not an `inspect` output, a snapshot that is not one and an address
/// that is not one: one line each, no page.
#[test]
fn the_status_command_refuses_bad_input_with_one_line() {
    let dir = common::tempdir();
    let garbage = dir.path().join("garbage");
    std::fs::create_dir_all(&garbage).expect("mkdir");
    std::fs::write(garbage.join("status.json"), "{\"counts\": 7").expect("write");
    for (args, says) in [
        (
            vec!["status", common::s(dir.path())],
            "not a `filmscope inspect --out` folder",
        ),
        (vec!["status", common::s(&garbage)], "status.json: "),
        (
            vec!["status", common::s(&garbage), "--listen", "8088"],
            "expected ADDR:PORT",
        ),
    ] {
        let run = common::filmscope().args(&args).output().expect("run");
        assert!(!run.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&run.stderr);
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(
            err.contains(says) && !err.contains("panicked"),
            "{args:?}: {err}"
        );
    }
}

/// Tasks (threads) `inspect` may have under the task limit: its own peak is about a dozen,
/// so a server with a thread a connection could not serve [`HALF_OPEN`] of them.
const TASKS_MAX: u64 = 64;
/// Half-open connections held against the page under the task limit.
const HALF_OPEN: usize = 600;

/// A pids cgroup (what systemd's `TasksMax` sets) limited to [`TASKS_MAX`], removed when
/// dropped: cgroup v1's `pids` hierarchy or cgroup v2's root, where they can be written.
struct PidsCgroup(PathBuf);

impl PidsCgroup {
    fn new() -> Result<Self, String> {
        let name = format!("filmscope-test-{}", std::process::id());
        let v1 = PathBuf::from("/sys/fs/cgroup/pids");
        let v2 = PathBuf::from("/sys/fs/cgroup");
        let parent = if v1.join("cgroup.procs").exists() {
            v1
        } else if std::fs::read_to_string(v2.join("cgroup.controllers"))
            .is_ok_and(|c| c.split_whitespace().any(|w| w == "pids"))
        {
            let _ = std::fs::write(v2.join("cgroup.subtree_control"), "+pids");
            v2
        } else {
            return Err("no pids cgroup controller under /sys/fs/cgroup".into());
        };
        let dir = parent.join(name);
        std::fs::create_dir(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let cg = Self(dir);
        std::fs::write(cg.0.join("pids.max"), TASKS_MAX.to_string())
            .map_err(|e| format!("{}/pids.max: {e}", cg.0.display()))?;
        Ok(cg)
    }

    /// Times a task could not start for the limit (`pids.events`' `max`).
    fn refused(&self) -> u64 {
        std::fs::read_to_string(self.0.join("pids.events"))
            .unwrap_or_default()
            .lines()
            .find_map(|l| l.strip_prefix("max "))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(0)
    }
}

impl Drop for PidsCgroup {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir(&self.0);
    }
}

/// The real user id of this process and the tasks (threads) that user runs: what
/// RLIMIT_NPROC counts.
fn user_tasks() -> (u32, u64) {
    let uid_of = |status: &str| -> Option<u32> {
        status
            .lines()
            .find_map(|l| l.strip_prefix("Uid:"))
            .and_then(|v| v.split_whitespace().next())
            .and_then(|v| v.parse().ok())
    };
    let me = uid_of(&std::fs::read_to_string("/proc/self/status").unwrap_or_default()).unwrap_or(0);
    let mut tasks = 0;
    for p in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        for t in std::fs::read_dir(p.path().join("task"))
            .into_iter()
            .flatten()
            .flatten()
        {
            let status = std::fs::read_to_string(t.path().join("status")).unwrap_or_default();
            if uid_of(&status) == Some(me) {
                tasks += 1;
            }
        }
    }
    (me, tasks)
}

/// `cmd` run under a task limit: in a pids cgroup where one can be made, else (not root,
/// which RLIMIT_NPROC does not bind) under `prlimit --nproc`; the cgroup to keep while it
/// runs and how the limit is set, or why none can be.
fn under_task_limit(cmd: &Command) -> Result<(Command, Option<PidsCgroup>, String), String> {
    let program = cmd.get_program().to_owned();
    let args: Vec<_> = cmd.get_args().map(ToOwned::to_owned).collect();
    match PidsCgroup::new() {
        Ok(cg) => {
            let procs = cg.0.join("cgroup.procs");
            let mut c = Command::new("sh");
            c.arg("-c")
                .arg(format!(
                    "echo $$ > '{}' && exec \"$0\" \"$@\"",
                    procs.display()
                ))
                .arg(program)
                .args(args);
            let how = format!("pids.max = {TASKS_MAX} in {}", cg.0.display());
            Ok((c, Some(cg), how))
        }
        Err(why) => {
            let (uid, tasks) = user_tasks();
            if uid == 0 {
                return Err(format!(
                    "{why}, and RLIMIT_NPROC does not bind root (no mechanism to limit tasks here)"
                ));
            }
            let limit = tasks + TASKS_MAX;
            let mut c = Command::new("prlimit");
            c.arg(format!("--nproc={limit}:{limit}"))
                .arg("--")
                .arg(program)
                .args(args);
            Ok((
                c,
                None,
                format!("prlimit --nproc={limit} (the user runs {tasks} tasks; {why})"),
            ))
        }
    }
}

/// Threads of process `pid`.
fn threads_of(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap_or_default()
        .lines()
        .find_map(|l| l.strip_prefix("Threads:"))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(0)
}

/// Under a task limit (systemd's `TasksMax`, as a pids cgroup or RLIMIT_NPROC), 600
/// half-open connections to the status page neither stop the page nor the estimator:
/// `inspect` measures every sample and exits 0, and the page answers once they are gone.
#[test]
fn under_a_task_limit_half_open_connections_stop_nothing() {
    let dir = common::tempdir();
    let rec = recipe(dir.path());
    let out = dir.path().join("line");
    let (mut cmd, cgroup, how) = match under_task_limit(&inspect_n(&rec, &out, "0", "12")) {
        Ok(x) => x,
        Err(why) => {
            eprintln!("skipped: {why}");
            return;
        }
    };
    let mut child = cmd
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("inspect");
    let mut err = std::io::BufReader::new(child.stderr.take().expect("stderr"));
    let mut first = String::new();
    std::io::BufRead::read_line(&mut err, &mut first).expect("read");
    let addr: std::net::SocketAddr = first
        .trim()
        .strip_prefix("status page: http://")
        .and_then(|u| u.strip_suffix('/'))
        .and_then(|u| u.parse().ok())
        .unwrap_or_else(|| panic!("{first}"));
    let samples = || {
        std::fs::read_to_string(out.join("results.jsonl"))
            .unwrap_or_default()
            .lines()
            .filter(|l| l.contains("\"kind\":\"sample\""))
            .count()
    };
    let wait_for = |what: &str, n: usize| {
        let t0 = Instant::now();
        while samples() < n {
            assert!(t0.elapsed() < Duration::from_secs(300), "never: {what}");
            std::thread::sleep(Duration::from_millis(50));
        }
    };
    wait_for("the first sample", 1);
    let mut held = Vec::new();
    for _ in 0..HALF_OPEN {
        // Past the server's bound a connection is closed as it comes: counted, not fatal.
        if let Ok(mut s) = std::net::TcpStream::connect_timeout(&addr, Duration::from_secs(2)) {
            if s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\nX-Slow: ")
                .is_ok()
            {
                held.push(s);
            }
        }
    }
    let threads = threads_of(child.id());
    let k = samples();
    wait_for("2 samples while the connections are held", k + 2);
    drop(held);
    // The server sees them close at once; a bounded retry covers the moment it takes.
    let t0 = Instant::now();
    let answer = loop {
        let got = std::net::TcpStream::connect(addr).ok().and_then(|mut s| {
            s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
            write!(s, "GET /api/latest HTTP/1.0\r\nHost: x\r\n\r\n").ok()?;
            let mut a = String::new();
            s.read_to_string(&mut a).ok()?;
            Some(a)
        });
        match got {
            Some(a) if a.contains(" 200 OK") => break a,
            _ if t0.elapsed() < Duration::from_secs(30) => {
                std::thread::sleep(Duration::from_millis(100));
            }
            other => panic!("the page after the half-open connections: {other:?}"),
        }
    };
    let body = answer.split_once("\r\n\r\n").map_or("", |x| x.1);
    let latest: Value = serde_json::from_str(body).expect("json");
    assert!(
        latest["counts"]["samples"].as_u64() >= Some(k as u64 + 2),
        "{latest}"
    );
    let t0 = Instant::now();
    let status = loop {
        if let Some(st) = child.try_wait().expect("wait") {
            break st;
        }
        if t0.elapsed() > Duration::from_secs(300) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("inspect did not finish under the task limit");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let mut rest = String::new();
    let _ = err.read_to_string(&mut rest);
    assert!(status.success(), "{rest}");
    assert_eq!(samples(), 12, "every sample measured and recorded");
    eprintln!(
        "task limit ({how}): {HALF_OPEN} half-open connections, inspect at {threads} threads with them held, {} task start(s) refused by the limit; 12 samples, exit 0",
        cgroup.as_ref().map_or("-".into(), |c| c.refused().to_string())
    );
}

/// A restart that cannot measure (its disk below the floor) leaves the last sample measured
/// on the page it leaves behind, with the disk alarm.
#[test]
fn a_restart_below_the_floor_keeps_the_last_sample_on_the_page() {
    let dir = common::tempdir();
    let rec = recipe(dir.path());
    let out = dir.path().join("line");
    let run = inspect_n(&rec, &out, "0", "2").output().expect("inspect");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let text = std::fs::read_to_string(&rec).expect("recipe");
    let full = dir.path().join("full.toml");
    let floored: String = text
        .lines()
        .map(|l| {
            if l.starts_with("min_free_bytes") {
                "min_free_bytes = 1_000_000_000_000_000\n".to_owned()
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    assert_ne!(floored, text);
    std::fs::write(&full, floored).expect("recipe");
    let run = inspect_n(&full, &out, "0", "1").output().expect("inspect");
    assert!(!run.status.success());
    let recs = sample_records(&out);
    assert_eq!(recs.len(), 2);
    let served = serve_status(&out);
    let l: Value = serde_json::from_str(&get(served.addr, "/api/latest").1).expect("json");
    assert_eq!(l["sample"], recs[1], "{l}");
    assert_eq!(l["alarms"][0]["variable"], "disk_free_bytes", "{l}");
    let (head, _) = get_bytes(served.addr, "/latest.png");
    assert!(head.contains(" 200 "), "{head}");
}
