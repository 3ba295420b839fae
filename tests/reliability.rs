//! Reliability (issue 7): bad sample values are flagged pixels, not errors; a long run keeps
//! its memory; a slow consumer holds the source back instead of growing queues; a process
//! killed while writing its outputs leaves old or new complete files, never torn ones.
//!
//! (Bad files, headers and capture.toml: `envi_io`, `capture_toml`, `cli_estimate`; device
//! faults under load: `rig`; equivalence: `equivalence`; parsers under fuzzing:
//! `fuzz/tests/regressions.rs`.)

use crate::common;

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};

use filmscope::estimate::method::MethodResult;
use filmscope::estimate::{run_method, RunConfig};
use filmscope::io::{Capture, EnviReader, Interleave};
use filmscope::pipeline::{run_sweep, PipelineConfig};
use filmscope::simulate::{write_capture, SimulateOptions};
use filmscope::solve::flags;
use filmscope::source::{CaptureSource, Source, StreamMsg};

fn estimate(dir: &Path) -> MethodResult {
    let cap = Capture::load(dir).expect("capture loads");
    run_method(
        &mut CaptureSource::new(cap).expect("source"),
        &RunConfig::default(),
        &|_| {},
    )
    .expect("a capture with bad samples still runs")
    .result
}

/// Overwrites pixel `(sample, line)` of every band of the cube `name.hdr` in `dir` with
/// `value(band, old_bytes)` (bytes in the file's own type and order).
fn poke(dir: &Path, name: &str, sample: usize, line: usize, value: impl Fn(&[u8]) -> Vec<u8>) {
    let hdr = dir.join(format!("{name}.hdr"));
    let reader = EnviReader::open(&hdr).expect("cube");
    let h = reader.header().clone();
    let data = reader.data_path().to_path_buf();
    drop(reader);
    let mut bytes = std::fs::read(&data).expect("data");
    let size = h.data_type.bytes();
    for band in 0..h.bands {
        let index = match h.interleave {
            Interleave::Bsq => (band * h.lines + line) * h.samples + sample,
            Interleave::Bil => (line * h.bands + band) * h.samples + sample,
            Interleave::Bip => (line * h.samples + sample) * h.bands + band,
        };
        let at = h.header_offset as usize + index * size;
        let new = value(&bytes[at..at + size]);
        bytes[at..at + size].copy_from_slice(&new);
    }
    std::fs::write(&data, bytes).expect("write data");
}

/// Every thickness is a finite number in the search range or NaN, never +-inf.
fn maps_are_numbers_or_nan(r: &MethodResult) {
    for (i, t) in r.thickness_nm.iter().enumerate() {
        assert!(t.is_nan() || t.is_finite(), "pixel {i}: {t}");
    }
}

fn float_bytes(v: f32, big_endian: bool) -> Vec<u8> {
    if big_endian {
        v.to_be_bytes().to_vec()
    } else {
        v.to_le_bytes().to_vec()
    }
}

#[test]
fn nan_and_inf_in_a_float_cube_are_flagged_pixels_not_errors() {
    let dir = common::tempdir();
    let opts = SimulateOptions {
        noise_free: true,
        interleave: Interleave::Bil,
        ..SimulateOptions::default()
    };
    write_capture(&common::tiny_scene(), dir.path(), opts, &|_| {}).expect("capture");
    let clean = estimate(dir.path());
    let be = EnviReader::open(dir.path().join("a25.hdr"))
        .expect("cube")
        .header()
        .byte_order
        == filmscope::io::ByteOrder::Big;
    for (sample, value) in [
        (0, f32::NAN),
        (1, f32::INFINITY),
        (2, f32::NEG_INFINITY),
        (3, 1e30),
        (4, -1e30),
    ] {
        poke(dir.path(), "a25", sample, 5, |_| float_bytes(value, be));
    }
    let r = estimate(dir.path());
    maps_are_numbers_or_nan(&r);
    let w = 32;
    for sample in 0..5 {
        let i = 5 * w + sample;
        assert!(
            r.thickness_nm[i].is_nan() || r.flags[i] != 0,
            "pixel ({sample}, 5) with bad samples is neither NaN nor flagged: {} flags {:#x}",
            r.thickness_nm[i],
            r.flags[i]
        );
    }
    // The rest of the image is measured as before.
    let both = (0..r.thickness_nm.len())
        .filter(|&i| i / w != 5 || i % w >= 5)
        .filter(|&i| r.thickness_nm[i].is_finite() && clean.thickness_nm[i].is_finite())
        .count();
    assert!(both > 600, "only {both} pixels measured");
    assert!((r.index.a - clean.index.a).abs() < 1e-3, "index moved");
}

#[test]
fn white_at_or_below_dark_gives_unmeasured_pixels_and_a_whole_bad_reference_a_note() {
    let dir = common::tempdir();
    write_capture(
        &common::tiny_scene(),
        dir.path(),
        SimulateOptions::default(),
        &|_| {},
    )
    .expect("capture");
    // Pixel (0, 3): dark far above white; pixel (1, 3): dark equal to white.
    poke(dir.path(), "dark25", 0, 3, |old| vec![0xff; old.len()]);
    let white = std::fs::read(dir.path().join("white25.img")).expect("white");
    let reader = EnviReader::open(dir.path().join("white25.hdr")).expect("white");
    let (h, offset) = (
        reader.header().clone(),
        reader.header().header_offset as usize,
    );
    drop(reader);
    let size = h.data_type.bytes();
    let cell = |band: usize| match h.interleave {
        Interleave::Bil => ((3 * h.bands + band) * h.samples + 1) * size + offset,
        Interleave::Bsq => ((band * h.lines + 3) * h.samples + 1) * size + offset,
        Interleave::Bip => ((3 * h.samples + 1) * h.bands + band) * size + offset,
    };
    let band = AtomicUsize::new(0);
    poke(dir.path(), "dark25", 1, 3, |_| {
        let b = band.fetch_add(1, Ordering::Relaxed);
        white[cell(b)..cell(b) + size].to_vec()
    });
    let r = estimate(dir.path());
    maps_are_numbers_or_nan(&r);
    for i in [3 * 32, 3 * 32 + 1] {
        assert!(
            r.thickness_nm[i].is_nan() || r.flags[i] != 0,
            "pixel {i}: {} flags {:#x}",
            r.thickness_nm[i],
            r.flags[i]
        );
    }
    assert!(r.thickness_nm.iter().filter(|t| t.is_finite()).count() > 600);

    // A whole dark reference at the white level: that angle has no usable sample. The run
    // ends without panicking; every pixel is NaN or flagged, or it stops with one line.
    std::fs::copy(
        dir.path().join("white25.img"),
        dir.path().join("dark25.img"),
    )
    .expect("copy");
    let cap = Capture::load(dir.path()).expect("capture loads");
    match run_method(
        &mut CaptureSource::new(cap).expect("source"),
        &RunConfig::default(),
        &|_| {},
    ) {
        Ok(run) => {
            maps_are_numbers_or_nan(&run.result);
            let unflagged_finite = run
                .result
                .thickness_nm
                .iter()
                .zip(&run.result.flags)
                .filter(|(t, f)| t.is_finite() && **f & flags::MISSING_SAMPLES == 0)
                .count();
            eprintln!(
                "whole bad reference: {} finite, {unflagged_finite} without MISSING_SAMPLES; notes {:?}",
                run.result.thickness_nm.iter().filter(|t| t.is_finite()).count(),
                run.result.notes
            );
            assert_eq!(unflagged_finite, 0, "pixels measured without their samples");
            assert!(
                run.result
                    .notes
                    .iter()
                    .any(|n| n.contains("white reference at or below its dark")),
                "no note says why: {:?}",
                run.result.notes
            );
        }
        Err(e) => assert!(!e.to_string().contains('\n'), "{e}"),
    }
}

/// `filmscope soak` in a child process (so other tests' memory does not count): resident
/// memory after sweep 40 is within 4 MB of that after sweep 20. A leak of one sweep's spectra
/// (768 pixels x 404 samples) would add over 1 MB per sweep, 20 MB over the span; the
/// allocator's arenas settle in steps of up to about 2 MB in the first sweeps, so the child
/// runs with `MALLOC_ARENA_MAX=2` as docs/reliability.md advises for a small box.
#[test]
fn forty_sweeps_keep_resident_memory_flat() {
    let scene = format!("{}/config/scenes/rig-tiny.toml", env!("CARGO_MANIFEST_DIR"));
    let out = common::filmscope()
        .args(["soak", "--sweeps", "40", "--scene", &scene])
        .env("MALLOC_ARENA_MAX", "2")
        .output()
        .expect("run soak");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rss = |sweep: usize| -> f64 {
        let tag = format!("soak: sweep {sweep}: RSS ");
        text.lines()
            .find_map(|l| l.strip_prefix(&tag))
            .and_then(|l| l.split(' ').next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no RSS for sweep {sweep} in {text}"))
    };
    let (at20, at40) = (rss(20), rss(40));
    assert!(at40 - at20 < 4.0, "RSS grew from {at20} MB to {at40} MB");
}

/// A source over the software camera that counts the row blocks it has produced against
/// those the consumer has finished.
struct CountingSource {
    inner: filmscope::source::SimSource,
    produced: Arc<AtomicUsize>,
    consumed: Arc<AtomicUsize>,
    max_in_flight: Arc<AtomicUsize>,
}

impl Source for CountingSource {
    fn spec(&self) -> &filmscope::solve::SweepSpec {
        self.inner.spec()
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.inner.angles_deg()
    }

    fn stream(&mut self, tx: &crossbeam_channel::Sender<StreamMsg>) {
        let spec = self.inner.spec().clone();
        let angles = self.inner.angles_deg();
        let inner = &self.inner;
        let (produced, consumed, max) = (&self.produced, &self.consumed, &self.max_in_flight);
        filmscope::source::stream_band_sequential(
            tx,
            &angles,
            spec.bands_nm.len(),
            spec.height,
            1,
            |a, b, r0, rows| {
                let p = produced.fetch_add(1, Ordering::SeqCst) + 1;
                let c = consumed.load(Ordering::SeqCst);
                max.fetch_max(p.saturating_sub(c), Ordering::SeqCst);
                inner.block(a, b, r0, rows)
            },
        );
    }
}

/// A consumer that stops (its first block held until a watcher lets it go, then every block
/// slow) holds the source back: blocks produced but not consumed never exceed the channel
/// capacity plus the one the consumer holds and the one waiting to be sent. Unbounded
/// queues would let the source run the whole sweep (9696 blocks) ahead.
#[test]
fn a_slow_consumer_blocks_the_source_instead_of_growing_queues() {
    for cap in [1usize, 4] {
        let counters = (
            Arc::new(AtomicUsize::new(0)),
            Arc::new(AtomicUsize::new(0)),
            Arc::new(AtomicUsize::new(0)),
        );
        let mut source = CountingSource {
            inner: filmscope::source::SimSource::new(
                firmware_sim::SoftwareCamera::new(common::tiny_scene()),
                false,
                1,
            )
            .expect("source"),
            produced: counters.0.clone(),
            consumed: counters.1.clone(),
            max_in_flight: counters.2.clone(),
        };
        let gate = Arc::new((Mutex::new(false), Condvar::new()));
        let opener = {
            let gate = gate.clone();
            std::thread::spawn(move || {
                std::thread::sleep(std::time::Duration::from_millis(300));
                let (open, cv) = &*gate;
                *open.lock().expect("gate") = true;
                cv.notify_all();
            })
        };
        let consumed = counters.1.clone();
        let on_rows = move |_rows: u64| {
            let (open, cv) = &*gate;
            let mut is_open = open.lock().expect("gate");
            while !*is_open {
                is_open = cv.wait(is_open).expect("gate");
            }
            drop(is_open);
            consumed.fetch_add(1, Ordering::SeqCst);
        };
        let config = PipelineConfig {
            channel_capacity: cap,
            workers: 2,
            ..PipelineConfig::default()
        };
        let out = run_sweep(&mut source, config, None, &on_rows).expect("sweep");
        opener.join().expect("opener");
        let (produced, consumed, max) = (
            counters.0.load(Ordering::SeqCst),
            counters.1.load(Ordering::SeqCst),
            counters.2.load(Ordering::SeqCst),
        );
        eprintln!("backpressure: capacity {cap}: at most {max} blocks in flight of {produced}");
        assert_eq!(produced, 4 * 101 * 24);
        assert_eq!(consumed, produced);
        assert!(
            max <= cap + 2,
            "capacity {cap}: {max} blocks in flight (bound {})",
            cap + 2
        );
        assert!(
            out.results
                .iter()
                .filter(|r| r.thickness_nm.is_finite())
                .count()
                > 600
        );
    }
}

/// Kills `filmscope estimate` (SIGKILL) at spread-out moments while it rewrites its
/// outputs over an earlier run's: every output is then the earlier or the new complete
/// file (the maps are deterministic, so both equal the reference), never torn; temporaries
/// a kill leaves behind are removed by the next run.
#[test]
fn killing_estimate_mid_write_never_leaves_a_torn_output() {
    let dir = common::tempdir();
    let cap = dir.path().join("cap");
    write_capture(
        &common::tiny_scene(),
        &cap,
        SimulateOptions::default(),
        &|_| {},
    )
    .expect("capture");
    let out = dir.path().join("out");
    let estimate = || {
        common::filmscope()
            .args(["estimate", common::s(&cap), "--out", common::s(&out)])
            .stderr(std::process::Stdio::null())
            .stdout(std::process::Stdio::null())
            .spawn()
            .expect("spawn")
    };
    let t0 = std::time::Instant::now();
    assert!(estimate().wait().expect("wait").success());
    let full = t0.elapsed();
    let read = |name: &str| -> Vec<f32> {
        filmscope::io::read_cube(out.join(name))
            .unwrap_or_else(|e| panic!("{name}: {e}"))
            .data
    };
    let reference = [
        "thickness_nm.hdr",
        "confidence.hdr",
        "thickness_sigma_nm.hdr",
        "flags.hdr",
    ]
    .map(read);
    let temps = || {
        std::fs::read_dir(&out)
            .expect("out")
            .filter_map(Result::ok)
            .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
            .count()
    };
    let mut seed = 0x9e37_79b9u64;
    let (mut kills, mut left_temps) = (0, 0);
    for _ in 0..16 {
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        // From half a run (the writes come at the end) to a little past its end.
        let delay = full.mul_f64(0.5 + (seed >> 33) as f64 / f64::from(1u32 << 31) * 0.6);
        let mut child = estimate();
        std::thread::sleep(delay);
        if child.try_wait().expect("try_wait").is_none() {
            child.kill().expect("SIGKILL");
            kills += 1;
        }
        let _ = child.wait();
        for (name, want) in [
            "thickness_nm.hdr",
            "confidence.hdr",
            "thickness_sigma_nm.hdr",
            "flags.hdr",
        ]
        .iter()
        .zip(&reference)
        {
            let got = read(name);
            assert!(
                got.len() == want.len()
                    && got
                        .iter()
                        .zip(want)
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{name} differs after a kill at {delay:?}"
            );
        }
        let summary = std::fs::read_to_string(out.join("summary.json")).expect("summary");
        let v: serde_json::Value = serde_json::from_str(&summary)
            .unwrap_or_else(|e| panic!("summary.json torn after a kill at {delay:?}: {e}"));
        assert!(v["refractive_index"].is_number());
        image::open(out.join("thickness_nm.png"))
            .unwrap_or_else(|e| panic!("thickness_nm.png torn after a kill at {delay:?}: {e}"));
        left_temps += temps();
    }
    eprintln!(
        "torn-file test: {kills} kills of 16 runs, {left_temps} temporaries seen after kills"
    );
    assert!(estimate().wait().expect("wait").success());
    assert_eq!(temps(), 0, "the next run removes stale temporaries");
}

/// A source that sends one malformed block (`rows`, `first_row`) in its first angle.
struct MalformedSource {
    inner: filmscope::source::SimSource,
    first_row: u32,
    rows: u32,
}

impl Source for MalformedSource {
    fn spec(&self) -> &filmscope::solve::SweepSpec {
        self.inner.spec()
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.inner.angles_deg()
    }

    fn stream(&mut self, tx: &crossbeam_channel::Sender<StreamMsg>) {
        let _ = tx.send(StreamMsg::Angle {
            incidence_deg: 10.0,
        });
        let _ = tx.send(StreamMsg::Rows(filmscope::source::RowBlock {
            band: 0,
            first_row: self.first_row,
            rows: self.rows,
            samples: filmscope::source::Samples::Reflectance(vec![0.5; 32 * self.rows as usize]),
        }));
        let _ = tx.send(StreamMsg::AngleEnd);
        let _ = tx.send(StreamMsg::SweepEnd);
    }
}

/// A camera stream with an empty block, or rows beyond the frame, stops the sweep with a
/// one-line error (regression: an empty block at row 0 computed row `0 + 0 - 1`, an
/// overflow panic in debug builds).
#[test]
fn malformed_blocks_stop_the_sweep_with_one_line() {
    for (first_row, rows, want) in [
        (0, 0, "an empty block at row 0"),
        (20, 8, "row 27 is outside the 24-row frame"),
        (u32::MAX - 1, 1, "outside the 24-row frame"),
    ] {
        let mut source = MalformedSource {
            inner: filmscope::source::SimSource::new(
                firmware_sim::SoftwareCamera::new(common::tiny_scene()),
                false,
                1,
            )
            .expect("source"),
            first_row,
            rows,
        };
        let err = run_sweep(&mut source, PipelineConfig::default(), None, &|_| {})
            .expect_err("malformed block");
        let msg = err.to_string();
        assert!(msg.contains(want) && !msg.contains('\n'), "{msg}");
    }
}

/// A sweep whose rows of band `band` come twice at every angle (a camera link that resends
/// what it was not sure it delivered).
struct ResendingSource {
    inner: common::WholeSource,
    band: u16,
}

impl Source for ResendingSource {
    fn spec(&self) -> &filmscope::solve::SweepSpec {
        self.inner.spec()
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.inner.angles_deg()
    }

    fn stream(&mut self, tx: &crossbeam_channel::Sender<StreamMsg>) {
        let (inner_tx, inner_rx) = crossbeam_channel::unbounded();
        self.inner.stream(&inner_tx);
        drop(inner_tx);
        for msg in inner_rx {
            if matches!(&msg, StreamMsg::Rows(b) if b.band == self.band)
                && tx.send(msg.clone()).is_err()
            {
                return;
            }
            if tx.send(msg).is_err() {
                return;
            }
        }
    }
}

#[test]
fn rows_sent_twice_overfill_a_held_block_and_the_sweep_still_completes() {
    // A worker's held block is sized for its shard's rows of a block of bands; a band whose
    // rows come twice holds more than that, and the worker feeds what it holds before
    // taking the rest (`HeldBlock::fits`). Its pixels see that band twice, a small
    // disturbance: the maps stay close to the clean sweep's, nothing is silently lost.
    let scene = common::tiny_scene();
    let mut camera =
        filmscope::source::SimSource::new(firmware_sim::SoftwareCamera::new(scene), false, 4)
            .expect("source");
    let whole = common::WholeSource::collect(&mut camera, 4);
    let config = RunConfig::default();
    let clean = run_method(&mut whole.with(&whole.order.clone(), 4), &config, &|_| {})
        .expect("clean sweep")
        .result;
    let mut resending = ResendingSource {
        inner: whole.with(&whole.order.clone(), 4),
        band: 20,
    };
    let got = run_method(&mut resending, &config, &|_| {})
        .expect("a sweep with resent rows still runs")
        .result;
    maps_are_numbers_or_nan(&got);
    let valid = |r: &MethodResult| r.thickness_nm.iter().filter(|d| d.is_finite()).count();
    assert!(valid(&clean) > 600, "clean sweep: {} valid", valid(&clean));
    assert!(
        valid(&got) * 10 >= valid(&clean) * 9,
        "{} valid pixels against {} in the clean sweep",
        valid(&got),
        valid(&clean)
    );
    let mut diffs: Vec<f32> = (clean.thickness_nm.iter().zip(&got.thickness_nm))
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (a - b).abs())
        .collect();
    diffs.sort_by(f32::total_cmp);
    let median = diffs[diffs.len() / 2];
    eprintln!(
        "resent band 20: {} / {} valid, median |d - clean| {median:.3} nm, max {:.3} nm, index {:+.5}",
        valid(&got),
        valid(&clean),
        diffs[diffs.len() - 1],
        got.index.a - clean.index.a
    );
    assert!(median < 1.0, "median thickness change {median} nm");
}
