//! `filmscope inspect`: the command-line glue around [`filmscope::line::inspect::Line`].

use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{anyhow, Context, Result};

use filmscope::line::inspect::{InspectOptions, Line, SampleOutcome};
use filmscope::line::recipe::Recipe;
use filmscope::line::status::{StatusBoard, StatusServer, StatusState, SNAPSHOT_FILE};
use filmscope::record::line::{LineSummary, ReferenceRecord};

/// What `inspect` is told on the command line.
pub struct Args<'a> {
    /// Rig file.
    pub rig: Option<&'a Path>,
    /// Recipe file.
    pub recipe: &'a Path,
    /// Output folder.
    pub out: &'a Path,
    /// firmware-sim's line of samples.
    pub sim: bool,
    /// Stop after this many samples.
    pub samples: Option<u64>,
    /// Status page port override.
    pub status_port: Option<u16>,
    /// MQTT port override.
    pub mqtt_port: Option<u16>,
    /// Modbus server address (`host:port`) override.
    pub modbus: Option<String>,
    /// Closing summary as JSON.
    pub json: bool,
    /// The lot every record names, instead of the recipe's.
    pub lot: Option<String>,
    /// The operator every record names, instead of the recipe's.
    pub operator: Option<String>,
    /// Measure the recipe's reference sample first.
    pub reference: bool,
}

/// Runs `filmscope inspect` until `samples` are done or SIGINT/SIGTERM (the sample under
/// way is finished first).
pub fn inspect(a: &Args<'_>) -> Result<()> {
    // The first signal stops the line cleanly, a second ends the process at once.
    let stop = filmscope::io::signals::stop_flag(true).context("signal handler")?;
    let Some(mut line) = open_line(a, &stop)? else {
        return Ok(());
    };
    if let Some(url) = line.status_url() {
        log::info!("status page: {url}");
    }
    if let Some(addr) = line.modbus_addr() {
        log::info!("modbus: listening on {addr}");
    }
    if a.reference {
        let r = line.check_reference().map_err(|e| anyhow!(e))?;
        if !a.json {
            print_reference(&r);
        }
    }
    measure_until_stopped(a, &mut line, &stop)?;
    line.stopped();
    close(a, &mut line, &stop)
}

/// The line of `a`'s rig, recipe and folder; none when a signal stopped its start-up.
fn open_line(a: &Args<'_>, stop: &Arc<AtomicBool>) -> Result<Option<Line>> {
    let rig = filmscope::rig::RigConfig::load_or_builtin(a.rig)?;
    let recipe = Recipe::load(a.recipe)?.with_labels(a.lot.clone(), a.operator.clone())?;
    let line = Line::open(InspectOptions {
        rig,
        recipe,
        recipe_path: a.recipe.to_owned(),
        out: a.out.to_owned(),
        sim: a.sim,
        status_port: a.status_port,
        mqtt_port: a.mqtt_port,
        modbus: a.modbus.clone(),
        stop: stop.clone(),
    });
    match line {
        Ok(line) => Ok(Some(line)),
        Err(e) if e.is_interrupted() => {
            log::error!("{e}");
            Ok(None)
        }
        Err(e) => Err(anyhow!(e)),
    }
}

/// Measures samples (each on the PLC's trigger when it gives them) until `a.samples` are
/// done or `stop` is set. A broker refusing the login, a full disk or three device errors
/// in a row stop it with an error.
fn measure_until_stopped(a: &Args<'_>, line: &mut Line, stop: &AtomicBool) -> Result<()> {
    let trigger = line.waits_for_trigger();
    let mut errors_in_a_row = 0;
    while a.samples.is_none_or(|n| line.measured < n) && !stop.load(Ordering::SeqCst) {
        if let Some(why) = line.mqtt_refused() {
            line.say(&format!("stop: mqtt: {why}"));
            return Err(anyhow!(
                "mqtt: {why}; check mqtt.username and mqtt.password in {}",
                a.recipe.display()
            ));
        }
        if trigger && !line.wait_for_trigger(stop) {
            break;
        }
        match line.measure() {
            Ok(o) => {
                errors_in_a_row = 0;
                if !a.json {
                    print_sample(&o);
                }
            }
            Err(e) if e.is_disk_full() => {
                line.say(&format!("stop: {e}"));
                return Err(anyhow!(e));
            }
            Err(e) => {
                errors_in_a_row += 1;
                log::error!("{e}");
                if errors_in_a_row >= 3 {
                    return Err(anyhow!(
                        "three samples in a row failed; stopping (last: {e})"
                    ));
                }
                std::thread::sleep(Duration::from_secs(1));
            }
        }
    }
    Ok(())
}

/// Waits for the broker's acknowledgements, logs and prints the run's summary (one JSON
/// line with `--json`), and fails naming the records the broker left unacknowledged.
fn close(a: &Args<'_>, line: &mut Line, stop: &AtomicBool) -> Result<()> {
    let unsent = line.flush();
    let summary = LineSummary {
        mqtt_unacknowledged: unsent.as_ref().map(|u| u.records),
        stopped_by_signal: stop.load(Ordering::SeqCst),
        ..line.summary()
    };
    let json = filmscope::record::to_json(&summary)?;
    line.say(&format!("stop: {json}"));
    if a.json {
        println!("{json}");
    } else {
        let l = &summary.latency_ms;
        let ms = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.1}"));
        println!(
            "{} sample(s): {} passed, {} failed, {} alarm(s); latency (last row to verdict published) median {} ms, max {} ms; results in {}",
            summary.samples, summary.passed, summary.failed, summary.alarms,
            ms(l.median),
            ms(l.max),
            a.out.join("results.jsonl").display()
        );
    }
    let Some(u) = unsent else {
        return Ok(());
    };
    let why = match line.mqtt_refused() {
        Some(r) => format!(
            "{r}; check mqtt.username and mqtt.password in {}",
            a.recipe.display()
        ),
        None if u.connected => {
            "the broker accepted the connection but did not acknowledge them".into()
        }
        None => "the broker was not reachable".into(),
    };
    let text = format!(
        "mqtt: {} record(s) not acknowledged (from seq {}): {why}; they stay in {} and are sent after the next start",
        u.records,
        u.first_seq,
        a.out.join("results.jsonl").display()
    );
    line.say(&format!("stop: {text}"));
    Err(anyhow!(text))
}

/// A reference check's line on standard output.
fn print_reference(r: &ReferenceRecord) {
    let f = |v: Option<f64>| v.unwrap_or(f64::NAN);
    println!(
        "reference {}: thickness {:.2} nm (drift {:+.2}), n={:.4} (drift {:+.4}): {}",
        r.reference,
        f(r.measured.thickness_nm),
        f(r.drift.thickness_nm),
        f(r.measured.index),
        f(r.drift.index),
        if r.within {
            "within tolerance"
        } else {
            "BEYOND tolerance (alarm)"
        }
    );
}

/// A measured sample's line on standard output, and one line for each alarm it raised.
fn print_sample(o: &SampleOutcome) {
    let r = &o.record;
    let t = &r.thickness_nm;
    let f = |v: Option<f64>| v.unwrap_or(f64::NAN);
    println!(
        "{} {} n={:.4} thickness {:.1} +- {:.2} nm [{:.1}..{:.1}] valid {:.1}% latency {:.1} ms{}",
        r.sample_id,
        r.verdict,
        f(r.refractive_index),
        f(t.mean),
        f(t.std),
        f(t.min),
        f(t.max),
        100.0 * r.valid_fraction,
        o.published_ms,
        if r.reasons.is_empty() {
            String::new()
        } else {
            format!(": {}", r.reasons.join("; "))
        }
    );
    for al in &o.alarms {
        println!(
            "  alarm: {} rule {} ({})",
            al.variable.name(),
            al.rule,
            al.text
        );
    }
}

/// `ADDR:PORT` (an IPv6 address in brackets) as the address and the port.
fn host_port(listen: &str) -> Result<(String, u16)> {
    let bad =
        || anyhow!("--listen {listen:?}: expected ADDR:PORT, e.g. 127.0.0.1:8088 or [::1]:8088");
    let (host, port) = listen.rsplit_once(':').ok_or_else(bad)?;
    let host = host
        .strip_prefix('[')
        .and_then(|h| h.strip_suffix(']'))
        .unwrap_or(host);
    if host.is_empty() || host.contains(char::is_whitespace) {
        return Err(bad());
    }
    Ok((host.to_owned(), port.parse().map_err(|_| bad())?))
}

/// What tells a folder changed: the snapshot's and the results log's length and time.
fn folder_stamp(out: &Path) -> Vec<Option<(u64, std::time::SystemTime)>> {
    [SNAPSHOT_FILE, "results.jsonl"]
        .iter()
        .map(|n| {
            let m = std::fs::metadata(out.join(n)).ok()?;
            Some((m.len(), m.modified().ok()?))
        })
        .collect()
}

/// Runs `filmscope status OUT --listen ADDR:PORT` until SIGINT/SIGTERM: the page of the
/// state `inspect` left in `out`, read again whenever the folder changes.
pub fn status(out: &Path, listen: &str) -> Result<()> {
    let (host, port) = host_port(listen)?;
    let stop = filmscope::io::signals::stop_flag(false).context("signal handler")?;
    let mut stamp = folder_stamp(out);
    let state = StatusState::load(out).map_err(|e| anyhow!(e))?;
    let server = StatusServer::serve(&host, port, StatusBoard::from_state(state))?;
    // What follows the start is said only to whoever still listens: a closed standard
    // error must not stop the page.
    let say = |text: &str| {
        let _ = writeln!(std::io::stderr(), "{text}");
    };
    say(&format!("status page: {}", server.url()));
    say(&format!(
        "showing {} of {}",
        server.latest_id().unwrap_or_else(|| "no sample yet".into()),
        out.display()
    ));
    let mut failing = false;
    while !stop.load(Ordering::SeqCst) {
        std::thread::sleep(Duration::from_millis(250));
        let now = folder_stamp(out);
        if now == stamp {
            continue;
        }
        match StatusState::load(out) {
            Ok(state) => {
                stamp = now;
                server.show(state);
                failing = false;
            }
            // Said once; the last state read stays on the page.
            Err(e) if !failing => {
                say(&format!(
                    "filmscope: {e} (the page shows the last state read)"
                ));
                failing = true;
            }
            Err(_) => {}
        }
    }
    Ok(())
}
