//! The rig end to end: drivers against firmware-sim, in process on a virtual clock and over
//! real ptys and a loopback socket; the acquired maps against `estimate` on the recorded
//! capture; transcripts; and every fault the rig must survive or report.

use crate::common;

use std::path::Path;

use filmscope::estimate::{run_method, RunConfig};
use filmscope::hw::{ErrorKind, FilterWheel, Stage, TunableFilter};
use filmscope::io::Capture;
use filmscope::jobs::acquire::run_rig;
use filmscope::jobs::{Quiet, Settings};
use filmscope::record::acquisition::{AcquisitionFile, LossCause};
use filmscope::rig::sim::{open_sim_with, sim_options};
use filmscope::rig::wheel::SimWheelTransport;
use filmscope::rig::{Kurios, KuriosConfig, RigConfig, SxWheel, Zaber, ZaberConfig};
use filmscope::solve::flags;
use filmscope::source::CaptureSource;
use filmscope::summary::Summary;
use firmware_sim::camlink::CameraFaults;
use firmware_sim::clock::VirtualClock;
use firmware_sim::kurios::KuriosFilter;
use firmware_sim::serial::{lock, SerialDevice, SerialFaults, SimPort};
use firmware_sim::serve::RigOptions;
use firmware_sim::wheel::SxWheelFirmware;
use firmware_sim::world::World;
use firmware_sim::zaber::{MotionFault, ZaberStage};
use std::sync::{Arc, Mutex};

fn rig_config() -> RigConfig {
    let p = format!("{}/config/rig.toml", env!("CARGO_MANIFEST_DIR"));
    let mut c = RigConfig::load(Path::new(&p)).expect("config/rig.toml loads");
    c.camera.timeout_ms = 300;
    c
}

fn options(c: &RigConfig) -> RigOptions {
    let scene = c.sim.as_ref().expect("[sim]").scene.clone();
    sim_options(c, &scene, 500.0).expect("sim options")
}

type Stage1 = Arc<Mutex<SerialDevice<ZaberStage>>>;

fn stage(
    faults: SerialFaults,
    fault: Option<MotionFault>,
) -> (
    Zaber<SimPort<ZaberStage>, VirtualClock>,
    Stage1,
    VirtualClock,
) {
    let clock = VirtualClock::new();
    let mut fw = ZaberStage::new(1, 4_266.666_666_666_667, [0, 384_000], 20.0, World::new());
    if let Some(f) = fault {
        fw = fw.with_fault(f);
    }
    let dev = Arc::new(Mutex::new(SerialDevice::new(fw, faults)));
    let port = SimPort::new(dev.clone(), clock.clone(), 100_000);
    let cfg = ZaberConfig {
        limits_deg: [0.0, 60.0],
        ..ZaberConfig::default()
    };
    (
        Zaber::new(port, "sim-stage", clock.clone(), cfg),
        dev,
        clock,
    )
}

fn said(dev: &Stage1) -> Vec<String> {
    lock(dev)
        .transcript()
        .iter()
        .map(|s| s.to_string())
        .collect()
}

#[test]
fn zaber_transcript_home_move_and_read_back_on_a_virtual_clock() {
    let (mut st, dev, clock) = stage(SerialFaults::default(), None);
    st.home().expect("home");
    let t0 = std::time::Instant::now();
    let deg = st.move_to_deg(10.0).expect("move");
    assert!((deg - 10.0).abs() < 1e-3, "{deg}");
    assert!(
        clock_now(&clock) > 400_000,
        "the half-second move took virtual time"
    );
    assert!(t0.elapsed().as_millis() < 200, "and no wall time");
    let t = said(&dev);
    assert_eq!(t[0], "-> /1 1 1 home:64");
    assert!(t[1].starts_with("<- @01 1 1 OK BUSY -- 0:"), "{}", t[1]);
    assert!(t
        .iter()
        .any(|l| l.starts_with("-> /1 1") && l.contains("move abs 42667")));
    assert!(
        t.last().is_some_and(|l| l.contains("OK IDLE -- 42667")),
        "{t:?}"
    );
}

fn clock_now(c: &VirtualClock) -> u64 {
    use filmscope::hw::Clock;
    c.now_us()
}

#[test]
fn zaber_retries_lost_and_garbled_replies_and_survives_split_reads() {
    let faults = SerialFaults {
        swallow: vec![1],
        garbage: vec![3],
        split: Some(3),
        ..SerialFaults::default()
    };
    let (mut st, dev, _) = stage(faults, None);
    st.home().expect("home despite a lost and a garbled reply");
    let homes = said(&dev).iter().filter(|l| l.contains("home")).count();
    assert_eq!(
        homes,
        2,
        "home sent again after the timeout: {:?}",
        said(&dev)
    );
    assert!((st.move_to_deg(20.0).expect("move") - 20.0).abs() < 1e-3);
}

#[test]
fn zaber_refusals_faults_limits_and_disappearance_are_one_line_errors() {
    let (mut st, dev, _) = stage(SerialFaults::default(), None);
    st.home().expect("home");
    let n = said(&dev).len();
    let e = st.move_to_deg(75.0).expect_err("beyond the limits");
    assert_eq!(e.kind, ErrorKind::OutOfRange);
    assert_eq!(said(&dev).len(), n, "nothing sent for an out-of-range move");
    assert!(!e.to_string().contains('\n'));

    let (mut st, _, _) = stage(
        SerialFaults {
            reject: vec![1],
            ..SerialFaults::default()
        },
        None,
    );
    let e = st.home().expect_err("rejected");
    assert_eq!(e.kind, ErrorKind::Rejected);
    assert_eq!(e.to_string(), "sim-stage: stage refused `home`: BADCOMMAND");

    let (mut st, _, _) = stage(SerialFaults::default(), Some(MotionFault::Interrupted(2)));
    st.home().expect("home");
    let e = st.move_to_deg(30.0).expect_err("interrupted");
    assert_eq!(e.kind, ErrorKind::Fault);
    assert!(e.to_string().contains("NI"), "{e}");

    let (mut st, _, _) = stage(SerialFaults::default(), Some(MotionFault::Stalled(2)));
    st.home().expect("home");
    assert!(st
        .move_to_deg(30.0)
        .expect_err("stalled")
        .to_string()
        .contains("FS"));

    let (mut st, _, _) = stage(
        SerialFaults {
            vanish_after: Some(2),
            ..SerialFaults::default()
        },
        None,
    );
    assert_eq!(st.home().expect_err("gone").kind, ErrorKind::Disconnected);
}

#[test]
fn kurios_prepares_tunes_and_refuses_on_a_virtual_clock() {
    let clock = VirtualClock::new();
    let dev = Arc::new(Mutex::new(SerialDevice::new(
        KuriosFilter::new(3_000_000, World::new()),
        SerialFaults {
            split: Some(1),
            swallow: vec![2],
            ..SerialFaults::default()
        },
    )));
    let port = SimPort::new(dev.clone(), clock.clone(), 100_000);
    let mut f = Kurios::new(port, "sim-lctf", clock.clone(), KuriosConfig::default());
    let t0 = std::time::Instant::now();
    assert_eq!(f.prepare().expect("prepare"), [420.0, 730.0]);
    assert!(
        clock_now(&clock) >= 3_000_000,
        "waited the warm-up in virtual time"
    );
    assert!(t0.elapsed().as_millis() < 500);
    assert!((f.tune_nm(551.5).expect("tune") - 551.5).abs() < 1e-9);
    let e = f.tune_nm(800.0).expect_err("out of range");
    assert_eq!(e.kind, ErrorKind::OutOfRange);
    f.block().expect("block");
    let t: Vec<String> = lock(&dev)
        .transcript()
        .iter()
        .filter(|s| s.dir == firmware_sim::serial::Dir::ToDevice)
        .map(|s| s.text.clone())
        .collect();
    assert_eq!(
        &t[..3],
        ["*IDN?", "SP?", "SP?"],
        "SP? retried after its lost reply"
    );
    assert!(t.contains(&"OM=1".to_owned()) && t.contains(&"BW=8".to_owned()));
    assert!(t.contains(&"WL=551.500".to_owned()) && !t.iter().any(|l| l.contains("800")));
    assert_eq!(t.last().map(String::as_str), Some("BW=1"));
    assert_eq!(lock(&dev).firmware().bandwidth(), 1);
}

#[test]
fn sx_wheel_counts_selects_refuses_and_notices_unplugging() {
    let clock = VirtualClock::new();
    let fw = Arc::new(Mutex::new(SxWheelFirmware::new(5, 200_000)));
    let mut w = SxWheel::new(
        SimWheelTransport::new(fw.clone(), clock.clone()),
        "wheel",
        clock,
    );
    assert_eq!(w.slots().expect("count"), 5);
    w.select(3).expect("select");
    assert_eq!(w.current().expect("current"), Some(3));
    assert_eq!(
        w.select(5).expect_err("no slot 5").kind,
        ErrorKind::OutOfRange
    );
    assert!(fw.lock().expect("lock").transcript.contains(&[132, 0]));
    fw.lock().expect("lock").gone = true;
    assert_eq!(
        w.select(1).expect_err("unplugged").kind,
        ErrorKind::Disconnected
    );
}

/// The recorded capture estimated as the rig's sweep was: streamed once (`--one-pass`).
fn estimate(capture: &Path) -> filmscope::estimate::method::MethodResult {
    let cap = Capture::load(capture).expect("recorded capture loads");
    let mut src = CaptureSource::new(cap).expect("source");
    let once = RunConfig {
        one_pass: true,
        ..RunConfig::default()
    };
    run_method(&mut src, &once, &|_| {})
        .expect("estimate")
        .result
}

fn read_map(path: &Path, n: usize) -> Vec<f32> {
    let mut r = filmscope::io::EnviReader::open(path).expect("map");
    let mut out = vec![0f32; n];
    let w = r.header().samples;
    let mut row = vec![0f32; w];
    for line in 0..n / w {
        r.read_band_row(0, line, &mut row).expect("row");
        out[line * w..(line + 1) * w].copy_from_slice(&row);
    }
    out
}

fn acquire(opts: RigOptions, out: &Path) -> (Result<Summary, String>, firmware_sim::serve::SimRig) {
    acquire_with(rig_config(), opts, out)
}

fn acquire_with(
    mut c: RigConfig,
    opts: RigOptions,
    out: &Path,
) -> (Result<Summary, String>, firmware_sim::serve::SimRig) {
    let (sim, rig) = open_sim_with(&mut c, opts).expect("sim rig");
    // The summary as `summary.json` has it.
    let summary = run_rig(rig, c, out, &Settings::default(), &Quiet)
        .map(|_| Summary::read(out).expect("summary.json"))
        .map_err(|e| e.to_string());
    (summary, sim)
}

fn same_maps(out: &Path) -> filmscope::estimate::method::MethodResult {
    let offline = estimate(&out.join("capture"));
    let n = offline.thickness_nm.len();
    let live = read_map(&out.join("thickness_nm.hdr"), n);
    for (i, (a, b)) in live.iter().zip(&offline.thickness_nm).enumerate() {
        assert_eq!(
            a.to_bits(),
            b.to_bits(),
            "pixel {i}: acquired {a} vs estimate {b}"
        );
    }
    let fl = read_map(&out.join("flags.hdr"), n);
    let fl: Vec<u16> = fl.iter().map(|&f| f as u16).collect();
    assert_eq!(fl, offline.flags, "flags differ");
    offline
}

#[test]
fn acquire_over_ptys_and_tcp_matches_estimate_on_the_recorded_capture() {
    let dir = common::tempdir();
    let c = rig_config();
    let (summary, sim) = acquire(options(&c), dir.path());
    let summary = summary.expect("acquire");
    assert!(
        sim.stage_port.starts_with("/dev/pts/"),
        "{}",
        sim.stage_port
    );
    let n = summary.refractive_index.expect("index");
    assert!((n - 2.1).abs() < 0.02, "index {n}");
    assert!(summary.valid_fraction > 0.9);
    let result = same_maps(dir.path());
    assert!(result.flags.iter().all(|f| f & flags::MISSING_SAMPLES == 0));
    // The stage transcript: homed first, every move inside the limits, each read back.
    let t: Vec<String> = lock(&sim.stage)
        .transcript()
        .iter()
        .map(|s| s.to_string())
        .collect();
    assert!(t[0].contains(" home:"), "{t:?}");
    let moves: Vec<i64> = t
        .iter()
        .filter_map(|l| l.split("move abs ").nth(1))
        .filter_map(|s| s.split(':').next()?.parse().ok())
        .collect();
    assert_eq!(moves, [42667, 106667, 170667, 234667]);
    let f: Vec<String> = lock(&sim.filter)
        .transcript()
        .iter()
        .filter(|s| s.dir == firmware_sim::serial::Dir::ToDevice)
        .map(|s| s.text.clone())
        .collect();
    assert_eq!(f[..4], ["*IDN?", "SP?", "OH?", "ST?"]);
    // Every band tuned once per angle; a reply late on a loaded machine has its command
    // sent again (the same WL= twice in a row), which is the driver's retry, not a band.
    let mut tunings: Vec<&String> = f.iter().filter(|l| l.starts_with("WL=")).collect();
    tunings.dedup();
    assert_eq!(tunings.len(), 4 * 101);
    assert_eq!(
        f.last().map(String::as_str),
        Some("BW=1"),
        "filter left blocking"
    );
    assert_eq!(
        sim.wheel.lock().expect("wheel").slot(),
        0,
        "wheel on its blocking slot"
    );
}

#[test]
fn lost_corrupt_duplicated_reordered_and_partial_rows_are_reported_and_flagged() {
    let dir = common::tempdir();
    let c = rig_config();
    let mut o = options(&c);
    // Frames: 3 per band (dark, white, sample); sample frames are 3, 6, 9, ...
    o.camera_faults = CameraFaults {
        drop_rows: vec![(3, 5)],
        corrupt_rows: vec![(6, 7)],
        duplicate_rows: vec![(9, 2)],
        swap_rows: vec![(12, 10)],
        partial: vec![(15, 20)],
        garbage_before: vec![18],
        ..CameraFaults::default()
    };
    let (summary, _sim) = acquire(o, dir.path());
    let summary = summary.expect("acquire survives transport faults");
    let acq = summary.acquisition.expect("the acquisition's log");
    let link = &acq.link;
    assert_eq!(link.crc_errors, 1);
    assert_eq!(link.duplicate_rows, 1);
    assert_eq!(link.out_of_order_rows, 1);
    assert_eq!(link.partial_frames, 1);
    assert!(link.sequence_gaps >= 2);
    assert!(link.garbage_bytes > 0);
    assert_eq!(link.rows_lost, 1 + 1 + 4);
    let lost = &acq.lost_rows;
    assert_eq!(lost.len(), 3);
    assert_eq!(lost[2].cause, LossCause::Partial);
    let result = same_maps(dir.path());
    let w = 32;
    for row in [5usize, 7, 20, 21, 22, 23] {
        assert!(
            result.flags[row * w..(row + 1) * w]
                .iter()
                .all(|f| f & (flags::MISSING_SAMPLES | flags::DEAD) != 0),
            "row {row} flagged"
        );
    }
    assert!(result.flags[0..w]
        .iter()
        .all(|f| f & flags::MISSING_SAMPLES == 0));
}

#[test]
fn camera_disconnect_mid_sweep_leaves_a_re_estimable_capture_and_a_note() {
    let dir = common::tempdir();
    let c = rig_config();
    let mut o = options(&c);
    o.camera_faults.vanish_at = Some(2 * 303 + 10);
    let (result, _sim) = acquire(o, dir.path());
    let e = result.expect_err("the sweep stops");
    assert!(
        e.contains("disconnected") && e.contains("2 complete angle(s)"),
        "{e}"
    );
    assert!(!e.contains('\n'));
    let file = AcquisitionFile::read(&dir.path().join("capture")).expect("acquisition.json");
    assert!(!file.log.complete);
    assert_eq!(file.log.angles_missing_deg, [40.0, 55.0]);
    assert!(file.re_estimate.contains("complete angles"), "{file:?}");
    let cap = Capture::load(dir.path().join("capture")).expect("consistent capture");
    assert_eq!(cap.angles.len(), 2);
    let r = estimate(&dir.path().join("capture"));
    assert_eq!(r.thickness_nm.len(), 32 * 24);
}

#[test]
fn a_stalled_frame_is_ended_with_its_rows_lost_and_the_stage_never_leaves_its_limits() {
    let dir = common::tempdir();
    let c = rig_config();
    let mut o = options(&c);
    o.camera_faults.stall = Some((3, 12));
    let (summary, sim) = acquire(o, dir.path());
    let summary = summary.expect("acquire");
    let link = summary.acquisition.expect("the acquisition's log").link;
    assert_eq!(link.stalled_frames, 1);
    assert_eq!(link.rows_lost, 12);
    same_maps(dir.path());
    let lim = 90.0 * 4_266.666_666_666_667;
    for l in lock(&sim.stage).transcript() {
        if let Some(v) = l.text.split("move abs ").nth(1) {
            let steps: f64 = v
                .split(':')
                .next()
                .and_then(|s| s.parse().ok())
                .expect("steps");
            assert!((0.0..=lim).contains(&steps));
        }
    }
}

#[test]
fn a_stage_refusing_mid_sweep_stops_with_one_line_naming_the_port() {
    let dir = common::tempdir();
    let c = rig_config();
    let mut o = options(&c);
    o.motion_fault = Some(MotionFault::Interrupted(4));
    let (result, sim) = acquire(o, dir.path());
    let e = result.expect_err("stops");
    assert!(e.contains(&sim.stage_port) && e.contains("NI"), "{e}");
    assert_eq!(
        Capture::load(dir.path().join("capture"))
            .expect("capture")
            .angles
            .len(),
        2
    );
}

/// The real rig: `FILMSCOPE_RIG=path/to/rig.toml cargo test --release --test integration -- --ignored rig::`
/// (ports in the file, or FILMSCOPE_STAGE_PORT / FILMSCOPE_FILTER_PORT / FILMSCOPE_CAMERA).
#[test]
#[ignore = "needs the real devices: set FILMSCOPE_RIG"]
fn hardware_sweep() {
    let Ok(path) = std::env::var("FILMSCOPE_RIG") else {
        return;
    };
    let mut c = RigConfig::load(Path::new(&path)).expect("rig file");
    if let Ok(p) = std::env::var("FILMSCOPE_STAGE_PORT") {
        c.stage.port = p;
    }
    if let Ok(p) = std::env::var("FILMSCOPE_FILTER_PORT") {
        c.filter.port = p;
    }
    if let Ok(a) = std::env::var("FILMSCOPE_CAMERA") {
        c.camera.address = a;
    }
    let dir = common::tempdir();
    let summary =
        filmscope::jobs::acquire::run(&c, dir.path(), false, &Settings::default(), &Quiet)
            .expect("hardware sweep");
    println!("{summary:#?}");
    same_maps(dir.path());
}

#[test]
fn acquire_over_a_unix_socket_camera_too() {
    let dir = common::tempdir();
    let c = rig_config();
    let mut o = options(&c);
    o.unix_socket = Some(dir.path().join("camera.sock"));
    let (summary, sim) = acquire(o, &dir.path().join("out"));
    assert!(sim.camera.to_string().starts_with("unix:"));
    assert!(summary.expect("acquire").valid_fraction > 0.9);
}

#[test]
fn cli_acquire_sim_prints_one_line_of_figures() {
    let dir = common::tempdir();
    let out = common::filmscope()
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["acquire", "--rig", "config/rig.toml", "--sim", "--out"])
        .arg(dir.path())
        .output()
        .expect("run");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.starts_with("acquired 4 angles x 101 bands"), "{text}");
    assert!(dir.path().join("capture/capture.toml").exists());
    assert!(dir.path().join("thickness_nm.png").exists());
    let bad = common::filmscope()
        .args(["acquire", "--rig", "no/such/rig.toml", "--out"])
        .arg(dir.path())
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        !bad.status.success() && err.contains("no/such/rig.toml") && err.lines().count() == 1,
        "{err}"
    );
}

/// A seeded xorshift generator for fault plans.
struct FaultRng(u64);

impl FaultRng {
    fn below(&mut self, n: u64) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0 % n.max(1)
    }

    fn chance(&mut self, percent: u64) -> bool {
        self.below(100) < percent
    }
}

/// Random serial faults: lost and garbled replies, split reads, now and then a refusal or
/// the device disappearing.
fn random_serial_faults(rng: &mut FaultRng, commands: u64) -> SerialFaults {
    let pick = |percent, rng: &mut FaultRng| {
        if rng.chance(percent) {
            vec![rng.below(commands) as usize + 1]
        } else {
            Vec::new()
        }
    };
    SerialFaults {
        swallow: pick(25, rng),
        garbage: pick(25, rng),
        reject: pick(4, rng),
        split: rng.chance(30).then(|| rng.below(8) as usize + 1),
        vanish_after: rng.chance(4).then(|| rng.below(commands) as usize + 1),
        ..SerialFaults::default()
    }
}

/// Long simulated runs with device faults injected at random (seeded): every sweep ends
/// complete, or with a one-line error and a recorded capture that either loads (two or more
/// complete angles) or whose acquisition.json says why it cannot be estimated. Sweeps:
/// `FILMSCOPE_FAULT_SWEEPS` (default 50), seed `FILMSCOPE_FAULT_SEED`.
#[test]
fn random_device_faults_over_many_sweeps_end_complete_or_with_a_clear_error() {
    let sweeps: u64 = std::env::var("FILMSCOPE_FAULT_SWEEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(50);
    let seed: u64 = std::env::var("FILMSCOPE_FAULT_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0x5eed_f11e);
    let mut rng = FaultRng(seed | 1);
    let mut c = rig_config();
    c.sweep.angles_deg = vec![10.0, 30.0, 50.0];
    c.sweep.bands_nm = [420.0, 720.0, 12.0];
    c.stage.timeout_ms = 200;
    c.filter.timeout_ms = 200;
    let bands = c.sweep.bands().len() as u64;
    let frames = 3 * bands * c.sweep.angles_deg.len() as u64;
    let (mut complete, mut partial, mut unusable) = (0, 0, 0);
    let (mut recoverable_sweeps, mut stopped_by_recoverable) = (0, Vec::new());
    let mut errors = std::collections::BTreeMap::<String, u32>::new();
    for sweep in 0..sweeps {
        let mut o = options(&c);
        let rows = |percent, rng: &mut FaultRng| -> Vec<(u64, u32)> {
            let mut v = Vec::new();
            for _ in 0..3 {
                if rng.chance(percent) {
                    v.push((rng.below(frames) + 1, rng.below(24) as u32));
                }
            }
            v
        };
        let mut garbage_before = Vec::new();
        for _ in 0..2 {
            if rng.chance(30) {
                garbage_before.push(rng.below(frames) + 1);
            }
        }
        o.camera_faults = CameraFaults {
            drop_rows: rows(40, &mut rng),
            corrupt_rows: rows(40, &mut rng),
            duplicate_rows: rows(30, &mut rng),
            swap_rows: rows(30, &mut rng),
            partial: rows(20, &mut rng),
            stall: rng
                .chance(10)
                .then(|| (rng.below(frames) + 1, rng.below(24) as u32)),
            garbage_before,
            vanish_at: rng.chance(8).then(|| rng.below(frames) + 1),
            ..CameraFaults::default()
        };
        o.stage_faults = random_serial_faults(&mut rng, 12);
        o.filter_faults = random_serial_faults(&mut rng, 3 * bands);
        let faults = format!(
            "sweep {sweep}: camera {:?}, stage {:?}, filter {:?}",
            o.camera_faults, o.stage_faults, o.filter_faults
        );
        // Lost, garbled, split, duplicated, swapped, corrupt and partial data the host
        // retries or re-requests; a refusal, a device gone or a stalled frame stops a sweep.
        let fatal = |f: &SerialFaults| !f.reject.is_empty() || f.vanish_after.is_some();
        let recoverable = !fatal(&o.stage_faults)
            && !fatal(&o.filter_faults)
            && o.camera_faults.vanish_at.is_none()
            && o.camera_faults.stall.is_none();
        let dir = common::tempdir();
        let (result, _sim) = acquire_with(c.clone(), o, dir.path());
        let capture = dir.path().join("capture");
        if recoverable {
            recoverable_sweeps += 1;
            if let Err(e) = &result {
                stopped_by_recoverable.push(format!("{faults}: {e}"));
            }
        }
        match result {
            Ok(summary) => {
                complete += 1;
                assert!(summary.refractive_index.is_some(), "{faults}: {summary:?}");
                assert!(
                    summary.acquisition.as_ref().is_some_and(|a| a.complete),
                    "{faults}"
                );
                let cap = Capture::load(&capture).expect("complete capture loads");
                assert_eq!(cap.angles.len(), 3, "{faults}");
            }
            Err(e) => {
                assert!(!e.is_empty() && !e.contains('\n'), "{faults}: {e:?}");
                assert!(!e.contains("panicked"), "{faults}: {e}");
                // Group errors by their wording without numbers, for the figures.
                let cause = e.strip_prefix("acquisition stopped: ").unwrap_or(&e);
                let kind: String = cause
                    .split("; ")
                    .next()
                    .unwrap_or(cause)
                    .chars()
                    .filter(|ch| !ch.is_ascii_digit())
                    .take(60)
                    .collect();
                *errors.entry(kind).or_default() += 1;
                let log = AcquisitionFile::read(&capture);
                match Capture::load(&capture) {
                    Ok(cap) => {
                        partial += 1;
                        assert!(!cap.angles.is_empty(), "{faults}");
                        if let Ok(file) = &log {
                            assert!(!file.log.complete, "{faults}");
                        }
                    }
                    Err(load) => {
                        unusable += 1;
                        let file = log.unwrap_or_else(|x| {
                            panic!("{faults}: {e}; capture does not load ({load}) and no acquisition.json reads ({x})")
                        });
                        assert!(!file.log.complete, "{faults}");
                        assert!(
                            file.re_estimate.contains("no complete angle"),
                            "{faults}: {file:?}"
                        );
                    }
                }
            }
        }
    }
    eprintln!(
        "device faults: {sweeps} sweeps (seed {seed:#x}): {complete} complete ({recoverable_sweeps} had only faults the host recovers from), {partial} stopped with a loadable partial capture, {unusable} stopped with no complete angle; errors {errors:?}"
    );
    // Every sweep whose faults the host can recover from completes; and the faults drawn
    // reach each ending, so none of the checks above went unexercised.
    assert!(
        stopped_by_recoverable.is_empty(),
        "stopped by recoverable faults: {stopped_by_recoverable:#?}"
    );
    assert!(
        recoverable_sweeps > 0 && complete > 0 && partial > 0 && unusable > 0,
        "{recoverable_sweeps} recoverable, {complete} complete, {partial} partial, {unusable} unusable"
    );
}

// ---- Hardening (issue 27): every exchange bounded, bad values refused before motion ----

/// A small sweep (3 angles x 26 bands, 78 frames per angle) for the hardening tests.
fn small_config() -> RigConfig {
    let mut c = rig_config();
    c.sweep.angles_deg = vec![10.0, 30.0, 50.0];
    c.sweep.bands_nm = [420.0, 720.0, 12.0];
    c.stage.timeout_ms = 200;
    c.filter.timeout_ms = 200;
    c
}

/// The first camera frame of the third angle of [`small_config`]'s sweep.
const THIRD_ANGLE_FRAME: u64 = 2 * 78 + 1;

/// Runs a sweep with `o`'s faults, which must stop it within `seconds` with one line of
/// printable text containing every one of `must`, leaving `acquisition.json` saying what is
/// missing and (with two complete angles) a loadable capture. Returns the error and the
/// simulated rig.
fn stops_in_bounded_time(
    o: RigOptions,
    seconds: f64,
    must: &[&str],
) -> (String, firmware_sim::serve::SimRig) {
    let dir = common::tempdir();
    let t0 = std::time::Instant::now();
    let (result, sim) = acquire_with(small_config(), o, dir.path());
    let e = result.expect_err("the sweep stops");
    let took = t0.elapsed().as_secs_f64();
    assert!(took < seconds, "{took:.1} s: {e}");
    assert!(!e.chars().any(char::is_control), "{e:?}");
    for m in must {
        assert!(e.contains(m), "{e:?} lacks {m:?}");
    }
    let log = AcquisitionFile::read(&dir.path().join("capture"))
        .expect("log")
        .log;
    assert!(!log.complete, "{log:?}");
    assert!(!log.angles_missing_deg.is_empty(), "{log:?}");
    if log.angles_done_deg.len() >= 2 {
        Capture::load(dir.path().join("capture")).expect("the partial capture loads");
    }
    let leftovers: Vec<String> = std::fs::read_dir(dir.path().parent().expect("parent"))
        .expect("tmp")
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| {
            let base = dir
                .path()
                .file_name()
                .and_then(|b| b.to_str())
                .unwrap_or("");
            n.starts_with(base) && n != base
        })
        .collect();
    assert!(leftovers.is_empty(), "staging or lock left: {leftovers:?}");
    (e, sim)
}

#[test]
fn hardening_camera_trickling_bytes_under_its_timeout_hits_the_deadline() {
    let mut o = options(&small_config());
    // One byte every 150 ms: no single read of the 300 ms link timeout ever times out.
    o.camera_faults.trickle = Some((THIRD_ANGLE_FRAME, 150));
    let (e, sim) = stops_in_bounded_time(o, 8.0, &["not complete within", "the leader"]);
    assert!(e.contains(&sim.camera.to_string()), "{e}");
    assert!(e.contains("2 complete angle(s)"), "{e}");
}

#[test]
fn hardening_camera_frames_for_another_frame_id_end_with_one_line() {
    let mut o = options(&small_config());
    o.camera_faults.wrong_frame_id = Some(THIRD_ANGLE_FRAME);
    let (e, sim) = stops_in_bounded_time(o, 8.0, &["other frames"]);
    assert!(e.contains(&sim.camera.to_string()), "{e}");
}

#[test]
fn hardening_camera_leaders_without_rows_end_with_one_line() {
    let mut o = options(&small_config());
    o.camera_faults.leaders_without_rows = Some(THIRD_ANGLE_FRAME);
    let (e, sim) = stops_in_bounded_time(o, 8.0, &["the frame"]);
    assert!(e.contains(&sim.camera.to_string()), "{e}");
}

#[test]
fn hardening_stage_sending_endless_info_lines_ends_with_one_line() {
    let mut o = options(&small_config());
    o.stage_faults.babble = Some((1, "#01 0 00 endless info\r\n".into()));
    let (e, sim) = stops_in_bounded_time(o, 8.0, &["lines without the reply"]);
    assert!(e.contains(&sim.stage_port), "{e}");
}

#[test]
fn hardening_stage_replying_as_another_device_ends_with_one_line() {
    let mut o = options(&small_config());
    o.stage_reply_address = Some(2);
    let (e, sim) = stops_in_bounded_time(o, 8.0, &["from device 2", "not device 1"]);
    assert!(e.contains(&sim.stage_port), "{e}");
}

#[test]
fn hardening_filter_repeating_its_prompt_ends_with_one_line() {
    let mut o = options(&small_config());
    // Mid-sweep: prepare takes about 8 commands, each band 2.
    o.filter_faults.babble = Some((8 + 2 * 2 * 26 + 5, ">".into()));
    let (e, sim) = stops_in_bounded_time(o, 8.0, &["empty prompts"]);
    assert!(e.contains(&sim.filter_port), "{e}");
}

#[test]
fn hardening_camera_connect_has_a_deadline() {
    // A non-routable address: the connect fails at once, times out after the link
    // timeout, or (behind a proxy that answers every address) succeeds; never hangs.
    let t0 = std::time::Instant::now();
    let r = filmscope::rig::connect_camera("tcp:10.255.255.1:9", 32, 300);
    assert!(t0.elapsed().as_secs_f64() < 3.0, "{:?}", t0.elapsed());
    if let Err(e) = r {
        assert!(e.to_string().contains("tcp:10.255.255.1:9"), "{e}");
    }
    // Nothing listening: one line naming the address, at once.
    let free = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = format!("tcp:{}", free.local_addr().expect("addr"));
    drop(free);
    let e = filmscope::rig::connect_camera(&addr, 32, 300)
        .err()
        .expect("nothing listens");
    assert!(
        e.to_string().contains(&addr) && e.to_string().contains("cannot connect"),
        "{e}"
    );
}

#[test]
fn hardening_filter_reading_back_nan_is_refused() {
    let mut o = options(&small_config());
    o.filter_faults.replace = vec![("WL?".into(), "WL=NaN\r>".into())];
    let (e, sim) = stops_in_bounded_time(o, 8.0, &["reads NaN nm"]);
    assert!(e.contains(&sim.filter_port), "{e}");
}

#[test]
fn hardening_device_text_is_escaped_before_it_is_shown() {
    let mut o = options(&small_config());
    o.filter_faults.replace = vec![(
        "WL?".into(),
        "\u{1b}[2J\u{1b}[31mCommand error\0 CMD_X\u{7}\r>".into(),
    )];
    let (e, _sim) = stops_in_bounded_time(o, 8.0, &["filter refused", "\\u{1b}[2J", "\\0"]);
    assert!(!e.contains('\u{1b}') && !e.contains('\0'), "{e:?}");
}

#[test]
fn hardening_rig_toml_values_are_refused_before_any_motion() {
    let base = std::fs::read_to_string(format!("{}/config/rig.toml", env!("CARGO_MANIFEST_DIR")))
        .expect("rig.toml");
    let dir = common::tempdir();
    for (from, to, want) in [
        (
            "bands_nm = [420.0, 720.0, 3.0]",
            "bands_nm = [420.0, 720.0, 1e-300]",
            "sweep.bands_nm = [420.0, 720.0, 1e-300]",
        ),
        (
            "bands_nm = [420.0, 720.0, 3.0]",
            "bands_nm = [420.0, 720.0, 1e-9]",
            "sweep.bands_nm = [420.0, 720.0, 1e-9]",
        ),
        (
            "angles_deg = [10.0, 25.0, 40.0, 55.0]",
            "angles_deg = [10.0, 25.0, 25.0, 55.0]",
            "sweep.angles_deg[2] = 25.0: the same angle",
        ),
        (
            "angles_deg = [10.0, 25.0, 40.0, 55.0]",
            "angles_deg = [10.0, 25.0, 40.0, 95.0]",
            "sweep.angles_deg[3] = 95.0",
        ),
        (
            "substrate_index = 1.52",
            "substrate_index = -1.52",
            "sample.substrate_index = -1.52",
        ),
        (
            "thickness_range_nm = [50.0, 2000.0]",
            "thickness_range_nm = [2000.0, 50.0]",
            "search.thickness_range_nm = [2000.0, 50.0]",
        ),
        (
            "index_range = [1.2, 3.0]",
            "index_range = [1.2, 1e300]",
            "search.index_range = [1.2, 1e300]",
        ),
        (
            "ambient_index = 1.0",
            "ambient_index = 1e9",
            "sample.ambient_index = 1000000000.0",
        ),
        ("fwhm_nm = 5.0", "fwhm_nm = 0.0", "sweep.fwhm_nm = 0.0"),
        ("width = 32", "width = 0", "camera.width = 0"),
        (
            "timeout_ms = 2000",
            "timeout_ms = 0",
            "camera.timeout_ms = 0",
        ),
    ] {
        assert!(base.contains(from), "{from}");
        let path = dir.path().join("rig.toml");
        std::fs::write(&path, base.replacen(from, to, 1)).expect("write");
        let e = RigConfig::load(&path).expect_err(to).to_string();
        assert!(
            e.contains(want) && e.contains("rig.toml") && !e.contains('\n'),
            "{to}: {e}"
        );
    }
    let path = dir.path().join("angles.toml");
    let many: Vec<String> = (0..10_000)
        .map(|i| format!("{}", i as f64 * 0.008))
        .collect();
    std::fs::write(
        &path,
        base.replacen(
            "angles_deg = [10.0, 25.0, 40.0, 55.0]",
            &format!("angles_deg = [{}]", many.join(", ")),
            1,
        ),
    )
    .expect("write");
    let e = RigConfig::load(&path)
        .expect_err("10000 angles")
        .to_string();
    assert!(e.contains("sweep.angles_deg = 10000 angles"), "{e}");
}

#[test]
fn hardening_failed_rerun_never_replaces_a_complete_acquisition() {
    let dir = common::tempdir();
    let out = dir.path().join("run");
    let c = small_config();
    let (first, _sim) = acquire_with(c.clone(), options(&c), &out);
    first.expect("the first sweep completes");
    let mut o = options(&c);
    o.camera_faults.vanish_at = Some(THIRD_ANGLE_FRAME);
    let (second, _sim) = acquire_with(c, o, &out);
    let e = second.expect_err("the second sweep stops");
    assert!(e.contains("run.partial"), "{e}");
    // The complete result is untouched: its summary and its three-angle capture.
    let summary = Summary::read(&out).expect("summary");
    assert!(summary.acquisition.is_some_and(|a| a.complete));
    assert_eq!(
        Capture::load(out.join("capture"))
            .expect("capture")
            .angles
            .len(),
        3
    );
    let log = AcquisitionFile::read(&dir.path().join("run.partial/capture"))
        .expect("partial log")
        .log;
    assert!(!log.complete);
    assert_eq!(
        Capture::load(dir.path().join("run.partial/capture"))
            .expect("partial capture")
            .angles
            .len(),
        2
    );
}

#[test]
fn hardening_ctrl_c_mid_sweep_keeps_a_loadable_capture_and_its_log() {
    let dir = common::tempdir();
    let root = env!("CARGO_MANIFEST_DIR");
    let rig = std::fs::read_to_string(format!("{root}/config/rig.toml"))
        .expect("rig.toml")
        .replace(
            "scene = \"scenes/rig-tiny.toml\"",
            &format!("scene = \"{root}/config/scenes/rig-tiny.toml\""),
        )
        .replace("speed = 200.0", "speed = 50.0");
    let rig_path = dir.path().join("rig.toml");
    std::fs::write(&rig_path, rig).expect("rig");
    let out = dir.path().join("run");
    let child = common::filmscope()
        .args([
            "acquire",
            "--sim",
            "--rig",
            common::s(&rig_path),
            "--out",
            common::s(&out),
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    // Wait for the first complete angle (capture.toml in the staging folder), then Ctrl-C.
    let t0 = std::time::Instant::now();
    let staged = || {
        std::fs::read_dir(dir.path())
            .ok()
            .into_iter()
            .flatten()
            .filter_map(Result::ok)
            .any(|e| {
                e.file_name().to_string_lossy().starts_with("run.tmp-")
                    && e.path().join("capture/capture.toml").exists()
            })
    };
    while !staged() && t0.elapsed().as_secs() < 20 {
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let pid = child.id().to_string();
    let killed = std::process::Command::new("kill")
        .args(["-INT", &pid])
        .status()
        .expect("kill");
    assert!(killed.success());
    let output = child.wait_with_output().expect("wait");
    let err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{err}");
    assert!(
        err.contains("interrupted") && err.trim().lines().count() == 1,
        "{err}"
    );
    let log = AcquisitionFile::read(&out.join("capture"))
        .expect("log")
        .log;
    assert!(!log.complete);
    assert!(log
        .error
        .as_ref()
        .is_some_and(|e| e.contains("interrupted")));
    let done = log.angles_done_deg.len();
    assert!(done >= 1 && !log.angles_missing_deg.is_empty());
    if done >= 2 {
        Capture::load(out.join("capture")).expect("loads");
    }
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .expect("dir")
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        !names
            .iter()
            .any(|n| n.starts_with("run.tmp-") || n == "run.lock"),
        "{names:?}"
    );
}
