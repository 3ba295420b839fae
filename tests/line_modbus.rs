//! A PLC and `filmscope inspect` over Modbus TCP on a free loopback port: with
//! `[modbus] trigger = "modbus"` nothing is measured until the trigger coil is set, the coil
//! is cleared when the measurement starts, and the registers carry the record's counter,
//! verdict and figures (the register map of `src/line/plc.rs`). The PLC is tokio-modbus's
//! client, and pymodbus (`tests/interop/modbus_plc.py`) where python3 imports it: skipped
//! with a message otherwise, a failure with `FILMSCOPE_REQUIRE_PYMODBUS=1` (set by
//! `.ci/run` once it installed it).

use crate::common;

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{filmscope, s, tempdir};
use filmscope::record::line::{PassFail, Record, SampleRecord};
use serde_json::Value;

const DEMO: &str = include_str!("../config/recipes/demo.toml");

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The demo recipe without MQTT, the status page on any free port, `[modbus]` on any free
/// port waiting for the trigger.
fn recipe(dir: &Path) -> PathBuf {
    let mut out = String::new();
    let mut skip = false;
    for line in DEMO.lines() {
        if line.starts_with('[') {
            skip = line.starts_with("[mqtt]");
        }
        if skip {
            continue;
        }
        if line.trim_start().starts_with("port = 8088") {
            out.push_str("port = 0\n");
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    out.push_str("[modbus]\nbind = \"127.0.0.1:0\"\ntrigger = \"modbus\"\n");
    let p = dir.join("recipe.toml");
    std::fs::write(&p, out).expect("recipe");
    p
}

/// `inspect` running until stopped, and the Modbus address it printed.
fn start(dir: &Path) -> (Child, std::net::SocketAddr, PathBuf) {
    let rec = recipe(dir);
    let out = dir.join("line");
    let mut child = filmscope()
        .args([
            "inspect",
            "--rig",
            s(&root().join("config/rig.toml")),
            "--sim",
            "--recipe",
            s(&rec),
            "--out",
            s(&out),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run");
    let stderr = child.stderr.take().expect("stderr");
    let mut lines = std::io::BufReader::new(stderr).lines();
    let addr = loop {
        let line = lines
            .next()
            .expect("inspect printed its Modbus address")
            .expect("line");
        if let Some(a) = line.strip_prefix("modbus: listening on ") {
            break a.parse().expect("address");
        }
    };
    std::thread::spawn(move || for _ in lines {});
    (child, addr, out)
}

fn sigterm_and_wait(mut child: Child) {
    let pid = child.id().to_string();
    Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .expect("kill");
    let status = child.wait().expect("wait");
    assert!(status.success(), "{status}");
}

fn samples(out: &Path) -> Vec<SampleRecord> {
    std::fs::read_to_string(out.join("results.jsonl"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str::<Record>(l).ok())
        .filter_map(|r| r.as_sample().cloned())
        .collect()
}

fn f32_of(v: Option<f64>) -> f32 {
    v.map_or(f32::NAN, |x| x as f32)
}

fn f32_at(r: &[u16], i: usize) -> f32 {
    f32::from_bits((u32::from(r[i]) << 16) | u32::from(r[i + 1]))
}

/// A number of the pymodbus client's report.
fn as_f32(v: &Value) -> f32 {
    v.as_f64().map_or(f32::NAN, |x| x as f32)
}

/// Reads the map until `cond` holds (bounded); the registers then.
async fn wait(
    plc: &mut tokio_modbus::client::Context,
    what: &str,
    cond: impl Fn(&[u16]) -> bool,
) -> Vec<u16> {
    use tokio_modbus::prelude::*;
    let t0 = Instant::now();
    loop {
        let r = plc
            .read_holding_registers(0, 18)
            .await
            .expect("io")
            .expect("no exception");
        if cond(&r) {
            return r;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "never: {what}: {r:?}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[test]
fn a_plc_triggers_each_sample_and_reads_its_verdict() {
    use tokio_modbus::prelude::*;
    let dir = tempdir();
    let (child, addr, out) = start(dir.path());
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let mut plc = tcp::connect(addr).await.expect("connect");
        let r = wait(&mut plc, "waiting for the trigger", |r| r[1] == 1).await;
        assert_eq!((r[2], r[3], r[4]), (0, 0, 0), "no sample yet: {r:?}");
        assert!(f32_at(&r, 6).is_nan());
        assert!(
            samples(&out).is_empty(),
            "nothing measured before the trigger"
        );
        for n in 1..=2u16 {
            plc.write_single_coil(0, true)
                .await
                .expect("io")
                .expect("no exception");
            let r = wait(&mut plc, "the sample", |r| r[3] == n).await;
            let coil = plc
                .read_coils(0, 1)
                .await
                .expect("io")
                .expect("no exception");
            assert_eq!(
                coil.first(),
                Some(&false),
                "cleared when the measurement started"
            );
            let rec = samples(&out).pop().expect("a record");
            assert_eq!(rec.counter, u64::from(n));
            let verdict = if rec.verdict.passed() { 1 } else { 2 };
            assert_eq!(r[4], verdict, "{rec:?}");
            let t = &rec.thickness_nm;
            assert_eq!(f32_at(&r, 6), f32_of(t.mean));
            assert_eq!(f32_at(&r, 8), f32_of(t.min));
            assert_eq!(f32_at(&r, 10), f32_of(t.max));
            assert_eq!(f32_at(&r, 12), f32_of(rec.refractive_index));
            assert_eq!(f32_at(&r, 14), rec.valid_fraction as f32);
            assert_eq!((r[16], r[17]), (0, n), "no error; triggers counted");
            let inputs = plc
                .read_input_registers(2, 15)
                .await
                .expect("io")
                .expect("no exception");
            assert_eq!(inputs, r[2..17], "function 04 reads the same map");
        }
        // The firmware-sim line's second sample is its defect.
        assert_eq!(samples(&out)[1].verdict, PassFail::Fail);
        let e = plc.read_holding_registers(10, 9).await.expect("io");
        assert_eq!(e, Err(ExceptionCode::IllegalDataAddress), "past the map");
        let e = plc.write_single_register(1, 5).await.expect("io");
        assert_eq!(e, Err(ExceptionCode::IllegalDataAddress), "read-only");
    });
    sigterm_and_wait(child);
    assert_eq!(samples(&out).len(), 2, "one sample a trigger");
}

#[test]
fn pymodbus_triggers_and_reads_as_a_plc_would() {
    let has = Command::new("python3")
        .args(["-c", "import pymodbus"])
        .status()
        .is_ok_and(|s| s.success());
    if !has {
        let required = std::env::var("FILMSCOPE_REQUIRE_PYMODBUS").is_ok_and(|v| v == "1");
        assert!(
            !required,
            "FILMSCOPE_REQUIRE_PYMODBUS=1 but python3 cannot import pymodbus"
        );
        eprintln!("skipped: python3 cannot import pymodbus (pip install pymodbus)");
        return;
    }
    let dir = tempdir();
    let (child, addr, out) = start(dir.path());
    let run = Command::new("python3")
        .arg(root().join("tests/interop/modbus_plc.py"))
        .args([addr.ip().to_string(), addr.port().to_string(), "2".into()])
        .output()
        .expect("python3");
    sigterm_and_wait(child);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let seen: Vec<Value> = String::from_utf8_lossy(&run.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("json"))
        .collect();
    let recs = samples(&out);
    assert_eq!((seen.len(), recs.len()), (2, 2));
    for (p, rec) in seen.iter().zip(&recs) {
        assert_eq!(p["counter"], rec.counter);
        let verdict = if rec.verdict.passed() { 1 } else { 2 };
        assert_eq!(p["verdict"], verdict);
        assert_eq!(as_f32(&p["thickness_mean"]), f32_of(rec.thickness_nm.mean));
        assert_eq!(as_f32(&p["index"]), f32_of(rec.refractive_index));
        assert_eq!(p["coil_cleared"], true);
        assert_eq!(p["inputs_match"], true);
    }
    eprintln!("pymodbus read: {seen:?}");
}

#[test]
fn a_modbus_port_in_use_stops_inspect_at_start_with_one_line() {
    let dir = tempdir();
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = taken.local_addr().expect("addr").to_string();
    let rec = recipe(dir.path());
    let o = filmscope()
        .args([
            "inspect",
            "--rig",
            s(&root().join("config/rig.toml")),
            "--sim",
            "--recipe",
            s(&rec),
            "--out",
            s(&dir.path().join("line")),
            "--modbus",
            &addr,
        ])
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert_eq!(
        err.trim_end(),
        format!("filmscope: modbus server on {addr}: cannot listen: Address already in use (os error 98)")
    );
}

/// Sixteen clients at once are served; a seventeenth is closed as it comes, the sixteen keep
/// their answers, and a slot freed by one leaving serves the next client.
#[test]
fn sixteen_clients_are_served_and_the_seventeenth_is_closed() {
    use tokio_modbus::prelude::*;
    let dir = tempdir();
    let (child, addr, _out) = start(dir.path());
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let mut clients = Vec::new();
        for _ in 0..filmscope::line::plc::MAX_CONNECTIONS {
            let mut c = tcp::connect(addr).await.expect("connect");
            let r = c.read_holding_registers(0, 2).await.expect("io");
            assert!(r.is_ok(), "{r:?}");
            clients.push(c);
        }
        let mut extra = tcp::connect(addr).await.expect("tcp accepts");
        let r = tokio::time::timeout(Duration::from_secs(5), extra.read_holding_registers(0, 2))
            .await
            .expect("answered or closed within 5 s");
        assert!(r.is_err(), "the seventeenth is closed: {r:?}");
        for c in &mut clients {
            let r = c.read_holding_registers(0, 2).await.expect("io");
            assert!(r.is_ok(), "{r:?}");
        }
        drop(clients.pop());
        let r = async {
            for _ in 0..100 {
                let mut c = tcp::connect(addr).await.expect("connect");
                if let Ok(Ok(r)) = c.read_holding_registers(0, 2).await {
                    return Some(r);
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            None
        }
        .await;
        assert!(r.is_some(), "a freed slot serves the next client");
    });
    sigterm_and_wait(child);
}
