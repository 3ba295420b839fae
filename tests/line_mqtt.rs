//! `filmscope inspect` against a real Mosquitto with a password file and TLS (certificates
//! made here by rcgen): a wrong password refused with one line, the retained last result
//! and the online/offline status a fresh subscriber sees (the last will after a kill -9),
//! a client certificate, records of a broker outage and of a stopped `inspect` delivered
//! after they come back (once each, by `seq`), a broker that never acknowledges, TLS files
//! checked when the recipe is read.
//!
//! The broker is `FILMSCOPE_MOSQUITTO` if set, else `mosquitto` in /usr/sbin or /usr/bin,
//! started on free loopback ports; with `FILMSCOPE_REQUIRE_MOSQUITTO=1` a missing broker is
//! a failure, otherwise the broker tests say why they skipped.

use crate::common;

use std::collections::{BTreeMap, BTreeSet};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{filmscope, s, tempdir};
use filmscope::line::stream::AckState;
use filmscope::record::line::{AlarmRule, AlarmVariable, LineFault, Record, SampleRecord};
use rumqttc::{Client, Event, MqttOptions, Packet, QoS, TlsConfiguration, Transport};

const DEMO: &str = include_str!("../config/recipes/demo.toml");
/// `mosquitto_passwd -b -c pw line1 s3cret-line1`.
const PASSWD: &str = "line1:$7$101$dcSKF8Dw1vknRO1t$H1/55oVo7IhWLqx9Y/+VpkXxG9/GbVJ+DJiXtvJwCJiGgQR5hvKh1JldSpphC0qzqldcbpsdHaXTGJ7m6pdVew==\n";
const PREFIX: &str = "plant/line1";

fn rig() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/rig.toml")
}

/// The demo recipe without its `[mqtt]` table and with the status page on any free port,
/// then `mqtt` (a whole `[mqtt]` table).
fn recipe(dir: &Path, mqtt: &str) -> PathBuf {
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
    out.push_str(mqtt);
    let p = dir.join("recipe.toml");
    std::fs::write(&p, out).expect("recipe");
    p
}

/// A `[mqtt]` table for the test broker's TLS listener `port`.
fn mqtt_table(port: u16, password: &str, extra: &str) -> String {
    format!(
        "[mqtt]\nhost = \"127.0.0.1\"\nport = {port}\nprefix = \"{PREFIX}\"\nclient_id = \"line1\"\nusername = \"line1\"\npassword = \"{password}\"\nca_file = \"ca.pem\"\nack_timeout_s = 3.0\n{extra}"
    )
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
    .args(extra)
    .stdout(Stdio::null())
    .stderr(Stdio::piped());
    c
}

fn records(out: &Path) -> Vec<Record> {
    std::fs::read_to_string(out.join("results.jsonl"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

fn samples_in(out: &Path) -> usize {
    records(out)
        .iter()
        .filter(|r| r.as_sample().is_some())
        .count()
}

/// Waits (bounded) until `cond` holds; `what` names it in the failure.
fn wait_until(what: &str, mut cond: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !cond() {
        assert!(t0.elapsed() < Duration::from_secs(60), "never: {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

// ------------------------------------------------------------ certificates, broker

struct Pki {
    dir: PathBuf,
}

/// A CA, a server certificate for 127.0.0.1 and localhost, a client certificate, all PEM
/// files in `dir` (`ca.pem`, `server.pem`, `server.key`, `client.pem`, `client.key`).
fn pki(dir: &Path) -> Pki {
    use rcgen::{
        BasicConstraints, CertificateParams, DnType, ExtendedKeyUsagePurpose, IsCa, KeyPair,
    };
    let ca_key = KeyPair::generate().expect("key");
    let mut ca = CertificateParams::new(Vec::<String>::new()).expect("params");
    ca.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    ca.distinguished_name
        .push(DnType::CommonName, "filmscope test CA");
    let ca_cert = ca.self_signed(&ca_key).expect("ca");
    let leaf = |names: Vec<String>, usage: ExtendedKeyUsagePurpose, stem: &str| {
        let key = KeyPair::generate().expect("key");
        let mut p = CertificateParams::new(names).expect("params");
        p.extended_key_usages = vec![usage];
        p.distinguished_name.push(DnType::CommonName, stem);
        let cert = p.signed_by(&key, &ca_cert, &ca_key).expect("sign");
        std::fs::write(dir.join(format!("{stem}.pem")), cert.pem()).expect("pem");
        std::fs::write(dir.join(format!("{stem}.key")), key.serialize_pem()).expect("key");
    };
    std::fs::write(dir.join("ca.pem"), ca_cert.pem()).expect("ca.pem");
    leaf(
        vec!["127.0.0.1".into(), "localhost".into()],
        ExtendedKeyUsagePurpose::ServerAuth,
        "server",
    );
    leaf(
        vec!["line1".into()],
        ExtendedKeyUsagePurpose::ClientAuth,
        "client",
    );
    Pki {
        dir: dir.to_owned(),
    }
}

struct Broker {
    child: Child,
    /// TLS, password.
    port: u16,
    /// TLS, password and a client certificate.
    mtls_port: u16,
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Broker {
    /// Stops it as a restart would (SIGTERM: its sessions and queued messages saved).
    fn restart_stop(mut self) {
        let pid = self.child.id().to_string();
        let _ = Command::new("kill").args(["-TERM", &pid]).status();
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

/// Mosquitto with a password file and two TLS listeners (`ports`: any free ones if none),
/// its sessions and queued messages kept in `pki.dir` across its restarts.
fn broker(pki: &Pki, bin: &Path, ports: Option<(u16, u16)>) -> Broker {
    let (port, mtls_port) = ports.unwrap_or_else(|| (free_port(), free_port()));
    let d = &pki.dir;
    std::fs::write(d.join("passwd"), PASSWD).expect("passwd");
    let tls = format!(
        "cafile {}\ncertfile {}\nkeyfile {}\n",
        d.join("ca.pem").display(),
        d.join("server.pem").display(),
        d.join("server.key").display()
    );
    let conf = d.join("mosquitto.conf");
    std::fs::write(
        &conf,
        format!(
            "user root\npersistence true\npersistence_location {}/\nallow_anonymous false\npassword_file {}\nlistener {port} 127.0.0.1\n{tls}listener {mtls_port} 127.0.0.1\n{tls}require_certificate true\n",
            d.display(),
            d.join("passwd").display()
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
    wait_until("mosquitto listens", || {
        std::net::TcpStream::connect(("127.0.0.1", port)).is_ok()
            && std::net::TcpStream::connect(("127.0.0.1", mtls_port)).is_ok()
    });
    Broker {
        child,
        port,
        mtls_port,
    }
}

// ------------------------------------------------------------ a subscriber

/// A message received: topic, payload, retained flag.
type Msg = (String, String, bool);

struct Subscriber {
    got: Arc<Mutex<Vec<Msg>>>,
    subscribed: Arc<AtomicUsize>,
    stop: Arc<AtomicBool>,
}

impl Drop for Subscriber {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

impl Subscriber {
    fn messages(&self) -> Vec<Msg> {
        self.got.lock().expect("lock").clone()
    }

    /// The record payloads received live (not as the retained last result a new
    /// subscription is handed) on `sample` and `alarm`.
    fn records(&self) -> Vec<Record> {
        self.messages()
            .iter()
            .filter(|(t, _, retained)| !t.ends_with("/status") && !retained)
            .filter_map(|(_, p, _)| serde_json::from_str(p).ok())
            .collect()
    }
}

/// Subscribes (over TLS, as line1) to `PREFIX/#` on `port`, again after every reconnection,
/// in a session the broker keeps while it is away.
fn subscribe(pki: &Pki, port: u16, id: &str) -> Subscriber {
    let tls = filmscope::line::tls::client_config(&pki.dir.join("ca.pem"), None).expect("tls");
    let mut o = MqttOptions::new(id, "127.0.0.1", port);
    o.set_credentials("line1", "s3cret-line1");
    o.set_transport(Transport::Tls(TlsConfiguration::Rustls(tls)));
    o.set_max_packet_size(1 << 20, 1 << 20);
    o.set_clean_session(false);
    let (client, mut conn) = Client::new(o, 16);
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
                    got.lock().expect("lock").push((
                        p.topic.clone(),
                        String::from_utf8_lossy(&p.payload).into_owned(),
                        p.retain,
                    ));
                }
                Ok(Ok(_)) | Err(_) => {}
                Ok(Err(_)) => std::thread::sleep(Duration::from_millis(100)),
            }
        }
    });
    wait_until("the subscriber subscribed", || {
        sub.subscribed.load(Ordering::SeqCst) > 0
    });
    sub
}

/// Every record of `out`'s log received once after de-duplication by `seq`; the number of
/// duplicates received.
fn check_delivered_once(out: &Path, sub: &Subscriber) -> usize {
    let logged: BTreeMap<u64, Record> = records(out)
        .into_iter()
        .filter_map(|r| Some((r.seq()?, r)))
        .collect();
    wait_until("every logged record received", || {
        let got: BTreeSet<u64> = sub.records().iter().filter_map(Record::seq).collect();
        logged.keys().all(|k| got.contains(k))
    });
    let got = sub.records();
    let mut by_seq: BTreeMap<u64, Record> = BTreeMap::new();
    let mut duplicates = 0;
    for r in got {
        let seq = r.seq().expect("seq");
        if let Some(prev) = by_seq.insert(seq, r.clone()) {
            assert_eq!(prev, r, "a duplicate is the same record");
            duplicates += 1;
        }
    }
    assert_eq!(by_seq, logged, "received = logged, by seq");
    duplicates
}

fn stderr_of(child: Child) -> (bool, String) {
    let o = child.wait_with_output().expect("wait");
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

// ------------------------------------------------------------ the tests

#[test]
fn a_wrong_password_is_refused_with_one_line() {
    let Some(bin) = mosquitto_bin() else { return };
    let dir = tempdir();
    let pki = pki(dir.path());
    let b = broker(&pki, &bin, None);
    let rec = recipe(dir.path(), &mqtt_table(b.port, "wrong", ""));
    let out = dir.path().join("line");
    let (ok, err) = stderr_of(
        inspect(&rec, &out, &["--samples", "2"])
            .spawn()
            .expect("run"),
    );
    assert!(!ok, "{err}");
    let last = err.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("filmscope: mqtt: ")
            && last.contains("refused the connection")
            && last.contains("mqtt.username and mqtt.password"),
        "{err}"
    );
}

/// The password in a file of its own (`mqtt.password_file`, owner-only): the line connects,
/// and no sample's summary (which records the recipe's settings) holds the secret; a file
/// others may read is refused at start with one line naming it.
#[test]
fn a_password_file_keeps_the_secret_out_of_the_recipe_and_the_records() {
    use std::os::unix::fs::PermissionsExt as _;
    let Some(bin) = mosquitto_bin() else { return };
    let dir = tempdir();
    let pki = pki(dir.path());
    let b = broker(&pki, &bin, None);
    let secret = dir.path().join("mqtt.pass");
    std::fs::write(&secret, "s3cret-line1\n").expect("password file");
    std::fs::set_permissions(&secret, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    let table =
        mqtt_table(b.port, "", "").replace("password = \"\"\n", "password_file = \"mqtt.pass\"\n");
    let rec = recipe(dir.path(), &table);
    let out = dir.path().join("line");
    let (ok, err) = stderr_of(
        inspect(&rec, &out, &["--samples", "1"])
            .spawn()
            .expect("run"),
    );
    assert!(ok, "{err}");
    let log = std::fs::read_to_string(out.join("inspect.log")).expect("log");
    assert!(log.contains("over TLS under plant/line1/"), "{log}");
    let mut summaries = 0;
    for entry in walk(&out) {
        if entry.file_name().is_some_and(|n| n == "summary.json") {
            let text = std::fs::read_to_string(&entry).expect("summary");
            assert!(!text.contains("s3cret"), "{}: {text}", entry.display());
            summaries += 1;
        }
    }
    assert!(summaries >= 1, "no sample summary under {}", out.display());

    std::fs::set_permissions(&secret, std::fs::Permissions::from_mode(0o644)).expect("chmod");
    let (ok, err) = stderr_of(
        inspect(&rec, &dir.path().join("line2"), &["--samples", "1"])
            .spawn()
            .expect("run"),
    );
    assert!(!ok, "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("mqtt.password_file")
            && err.contains("mqtt.pass")
            && err.contains("chmod 600"),
        "{err}"
    );
}

/// Every file under `dir`.
fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                todo.push(p);
            } else {
                out.push(p);
            }
        }
    }
    out
}

#[test]
fn tls_retained_last_result_online_offline_and_the_last_will() {
    let Some(bin) = mosquitto_bin() else { return };
    let dir = tempdir();
    let pki = pki(dir.path());
    let b = broker(&pki, &bin, None);
    let watcher = subscribe(&pki, b.port, "watcher");
    let rec = recipe(dir.path(), &mqtt_table(b.port, "s3cret-line1", ""));
    let out = dir.path().join("line");
    let (ok, err) = stderr_of(
        inspect(&rec, &out, &["--samples", "2"])
            .spawn()
            .expect("run"),
    );
    assert!(ok, "{err}");
    let log = std::fs::read_to_string(out.join("inspect.log")).expect("log");
    assert!(log.contains("over TLS under plant/line1/"), "{log}");
    let status_seen = |sub: &Subscriber| -> Vec<String> {
        sub.messages()
            .into_iter()
            .filter(|(t, _, _)| t == &format!("{PREFIX}/status"))
            .map(|(_, p, _)| p)
            .collect()
    };
    wait_until("online then offline", || {
        status_seen(&watcher) == ["online", "offline"]
    });
    check_delivered_once(&out, &watcher);

    // A fresh subscriber: the last result and the status, retained.
    let fresh = subscribe(&pki, b.port, "fresh");
    wait_until("two retained messages", || fresh.messages().len() >= 2);
    let msgs = fresh.messages();
    let last_sample = records(&out)
        .into_iter()
        .rfind(|r| r.as_sample().is_some())
        .expect("a sample");
    let retained_sample = msgs
        .iter()
        .find(|(t, _, _)| t == &format!("{PREFIX}/sample"))
        .expect("retained sample");
    assert!(retained_sample.2, "retained flag");
    assert_eq!(
        serde_json::from_str::<Record>(&retained_sample.1).expect("a record"),
        last_sample
    );
    assert!(msgs.contains(&(format!("{PREFIX}/status"), "offline".into(), true)));

    // The last will: killed (-9) while connected, the broker says offline.
    let mut child = inspect(&rec, &out, &[]).spawn().expect("run");
    wait_until("online again", || {
        status_seen(&watcher).last().map(String::as_str) == Some("online")
    });
    let before = samples_in(&out);
    wait_until("a sample", || samples_in(&out) > before);
    child.kill().expect("kill -9");
    let _ = child.wait();
    wait_until("offline by the last will", || {
        status_seen(&watcher).last().map(String::as_str) == Some("offline")
    });
    let fresh = subscribe(&pki, b.port, "fresh-2");
    wait_until("offline retained", || {
        fresh
            .messages()
            .contains(&(format!("{PREFIX}/status"), "offline".into(), true))
    });

    // A client certificate on the listener that requires one.
    let rec = recipe(
        dir.path(),
        &mqtt_table(
            b.mtls_port,
            "s3cret-line1",
            "client_cert_file = \"client.pem\"\nclient_key_file = \"client.key\"\n",
        ),
    );
    let (ok, err) = stderr_of(
        inspect(&rec, &out, &["--samples", "1"])
            .spawn()
            .expect("run"),
    );
    assert!(ok, "with a client certificate: {err}");
    check_delivered_once(&out, &watcher);
}

/// The broker stops, comes back, stops again; `inspect` stops with records unsent (an
/// error), then starts again: every record reaches a subscriber, once after
/// de-duplication by `seq` (the duplicates are counted and printed).
#[test]
fn records_of_a_broker_outage_and_of_a_stopped_inspect_arrive_once() {
    let Some(bin) = mosquitto_bin() else { return };
    let dir = tempdir();
    let pki = pki(dir.path());
    let b = broker(&pki, &bin, None);
    let ports = Some((b.port, b.mtls_port));
    let sub = subscribe(&pki, b.port, "collector");
    let rec = recipe(dir.path(), &mqtt_table(b.port, "s3cret-line1", ""));
    let out = dir.path().join("line");
    let child = inspect(&rec, &out, &[]).spawn().expect("run");
    wait_until("2 samples", || samples_in(&out) >= 2);
    b.restart_stop();
    let n = samples_in(&out);
    wait_until("2 samples while the broker is down", || {
        samples_in(&out) >= n + 2
    });
    let subs = sub.subscribed.load(Ordering::SeqCst);
    let b = broker(&pki, &bin, ports);
    wait_until("the collector subscribed again", || {
        sub.subscribed.load(Ordering::SeqCst) > subs
    });
    let n = samples_in(&out);
    wait_until("2 samples after the broker came back", || {
        samples_in(&out) >= n + 2
    });
    b.restart_stop();
    let n = samples_in(&out);
    wait_until("a sample while the broker is down again", || {
        samples_in(&out) > n
    });
    // SIGTERM: the sample under way is finished; the unsent records are an error.
    let pid = child.id().to_string();
    Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .expect("kill");
    let (ok, err) = stderr_of(child);
    assert!(!ok, "unsent records at exit: a non-zero exit");
    assert!(
        err.contains("record(s) not acknowledged") && err.contains("sent after the next start"),
        "{err}"
    );
    let acked = AckState::load(&out)
        .expect("state")
        .expect("mqtt-acked.json")
        .acked_seq;
    let last = records(&out).last().and_then(Record::seq);
    assert!(Some(acked) < last, "{acked} {last:?}");

    let subs = sub.subscribed.load(Ordering::SeqCst);
    let _b = broker(&pki, &bin, ports);
    wait_until("the collector subscribed again", || {
        sub.subscribed.load(Ordering::SeqCst) > subs
    });
    let (ok, err) = stderr_of(
        inspect(&rec, &out, &["--samples", "1"])
            .spawn()
            .expect("restart"),
    );
    assert!(ok, "{err}");
    let log = std::fs::read_to_string(out.join("inspect.log")).expect("log");
    assert!(
        log.contains("not acknowledged before the last stop queued again"),
        "{log}"
    );
    let duplicates = check_delivered_once(&out, &sub);
    eprintln!(
        "measured: {} records logged, all received; {duplicates} duplicate(s) removed by seq",
        records(&out).len()
    );
}

/// A fake broker that accepts the connection (CONNACK) and then reads everything without a
/// word: the records are never acknowledged.
fn silent_broker() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = l.local_addr().expect("addr").port();
    std::thread::spawn(move || {
        for s in l.incoming().flatten() {
            std::thread::spawn(move || {
                let mut s = s;
                let mut buf = [0u8; 4096];
                // CONNECT arrives first: answer it, then say nothing more.
                if s.read(&mut buf).is_ok_and(|n| n > 0) {
                    let _ = s.write_all(&[0x20, 0x02, 0x00, 0x00]);
                }
                while s.read(&mut buf).is_ok_and(|n| n > 0) {}
            });
        }
    });
    port
}

#[test]
fn a_broker_that_never_acknowledges_raises_an_alarm_and_fails_the_exit() {
    let dir = tempdir();
    let port = silent_broker();
    let rec = recipe(
        dir.path(),
        &format!("[mqtt]\nport = {port}\nprefix = \"{PREFIX}\"\nack_timeout_s = 1.0\n"),
    );
    let out = dir.path().join("line");
    let (ok, err) = stderr_of(
        inspect(&rec, &out, &["--samples", "1"])
            .spawn()
            .expect("run"),
    );
    assert!(!ok, "{err}");
    assert!(
        err.contains("the broker accepted the connection but did not acknowledge them"),
        "{err}"
    );
    let alarms: Vec<Record> = records(&out)
        .into_iter()
        .filter(|r| matches!(r, Record::Alarm(a) if a.variable == AlarmVariable::Mqtt))
        .collect();
    assert_eq!(alarms.len(), 1, "{alarms:?}");
    assert!(
        matches!(&alarms[0], Record::Alarm(a) if a.rule == AlarmRule::Fault(LineFault::NoAcknowledgement)),
        "{alarms:?}"
    );
}

#[test]
fn tls_files_are_checked_when_the_recipe_is_read() {
    let dir = tempdir();
    std::fs::write(dir.path().join("ca.pem"), "not a certificate\n").expect("ca");
    for (table, expect) in [
        (
            "[mqtt]\nca_file = \"missing.pem\"\n".to_owned(),
            "missing.pem\": cannot read: No such file or directory",
        ),
        (
            "[mqtt]\nca_file = \"ca.pem\"\n".to_owned(),
            "ca.pem\": no PEM certificate in it",
        ),
        (
            "[mqtt]\npassword = \"x\"\n".to_owned(),
            "mqtt.password: given without mqtt.username",
        ),
        (
            "[mqtt]\nprefix = \"plant/#\"\n".to_owned(),
            "mqtt.prefix = \"plant/#\": a topic prefix without wildcards",
        ),
        (
            "[mqtt]\nack_timeout_s = 0\n".to_owned(),
            "mqtt.ack_timeout_s = 0: expected 0.1 to 3600",
        ),
    ] {
        let rec = recipe(dir.path(), &table);
        let o = inspect(&rec, &dir.path().join("line"), &["--samples", "1"])
            .output()
            .expect("run");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success());
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(
            err.starts_with(&format!("filmscope: {}: ", rec.display())) && err.contains(expect),
            "{err}"
        );
    }
}

/// A kill -9 between a sample's folder and its line in `results.jsonl` (so its record was
/// never published): the restart appends the record from the folder and publishes it.
#[test]
fn a_record_restored_after_a_crash_is_published() {
    let Some(bin) = mosquitto_bin() else { return };
    let dir = tempdir();
    let pki = pki(dir.path());
    let b = broker(&pki, &bin, None);
    let rec = recipe(dir.path(), &mqtt_table(b.port, "s3cret-line1", ""));
    let out = dir.path().join("line");
    let (ok, err) = stderr_of(
        inspect(&rec, &out, &["--samples", "2"])
            .spawn()
            .expect("run"),
    );
    assert!(ok, "{err}");
    // The state as the crash leaves it: the last record neither in the log nor sent.
    let text = std::fs::read_to_string(out.join("results.jsonl")).expect("log");
    let mut lines: Vec<&str> = text.lines().collect();
    let lost: SampleRecord =
        serde_json::from_str(lines.pop().expect("a line")).expect("a sample record");
    std::fs::write(out.join("results.jsonl"), lines.join("\n") + "\n").expect("cut");
    let seq = lost.seq.expect("seq");
    AckState { acked_seq: seq - 1 }.store(&out).expect("state");
    let sub = subscribe(&pki, b.port, "after-crash");
    let (ok, err) = stderr_of(
        inspect(&rec, &out, &["--samples", "1"])
            .spawn()
            .expect("restart"),
    );
    assert!(ok, "{err}");
    wait_until("the restored record and the new sample", || {
        sub.records().len() >= 2
    });
    let got = sub.records();
    assert_eq!(got[0].sample_id(), Some(lost.sample_id.as_str()), "{got:?}");
    assert_eq!(
        got[0].seq(),
        Some(seq),
        "the restored record takes the free seq"
    );
    assert_eq!(got[1].counter(), Some(lost.counter + 1));
}
