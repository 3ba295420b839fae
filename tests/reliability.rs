//! Reliability (issue 7): bad sample values are flagged pixels, not errors; a long run keeps
//! its memory; a slow consumer holds the source back instead of growing queues; a process
//! killed while writing its outputs leaves old or new complete files, never torn ones.
//!
//! (Bad files, headers and capture.toml: `envi_io`, `capture_toml`, `cli_estimate`; device
//! faults under load: `rig`; equivalence: `equivalence`; parsers under fuzzing:
//! `fuzz/tests/regressions.rs`.)

mod common;

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};

use filmscope::estimate::{run_method, RunConfig};
use filmscope::io::{Capture, EnviReader, Interleave};
use filmscope::pipeline::{run_sweep, CaptureSource, PipelineConfig, Source, StreamMsg};
use filmscope::simulate::{write_capture, SimulateOptions};
use filmscope::solve::flags;
use filmscope::sweep::MethodResult;

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
