//! The same sweep gives the same maps whatever path it takes: streamed from the camera or
//! replayed from a capture in any interleave, rows one at a time or in blocks, channels of
//! capacity 1 or many, one worker or several.

use crate::common;

use filmscope::estimate::method::MethodResult;
use filmscope::estimate::{run_method, RunConfig};
use filmscope::io::{Capture, Interleave};
use filmscope::pipeline::PipelineConfig;
use filmscope::simulate::{write_capture, SimulateOptions};
use filmscope::source::{CaptureSource, SimSource, Source};
use filmscope_core::solve::fit_row::INDEX_PIXELS;
use firmware_sim::SoftwareCamera;

fn run(source: &mut dyn Source, workers: usize, channel_capacity: usize) -> MethodResult {
    run_keeping(source, workers, channel_capacity, INDEX_PIXELS)
}

/// [`run`] with about `index_pixels` pixels keeping the index's sums.
fn run_keeping(
    source: &mut dyn Source,
    workers: usize,
    channel_capacity: usize,
    index_pixels: usize,
) -> MethodResult {
    let mut config = RunConfig {
        pipeline: PipelineConfig {
            channel_capacity,
            workers,
            ..PipelineConfig::default()
        },
        ..RunConfig::default()
    };
    config.pipeline.solver.index_pixels = index_pixels;
    run_method(source, &config, &|_| {}).expect("run").result
}

fn same(a: &MethodResult, b: &MethodResult, what: &str) {
    assert_eq!(
        a.index.a.to_bits(),
        b.index.a.to_bits(),
        "{what}: index {} vs {}",
        a.index.a,
        b.index.a
    );
    assert_eq!(a.flags, b.flags, "{what}: flags differ");
    for (name, x, y) in [
        ("thickness", &a.thickness_nm, &b.thickness_nm),
        ("sigma", &a.thickness_sigma_nm, &b.thickness_sigma_nm),
        ("confidence", &a.confidence, &b.confidence),
    ] {
        for (i, (x, y)) in x.iter().zip(y).enumerate() {
            assert!(
                x.to_bits() == y.to_bits(),
                "{what}: {name} of pixel {i}: {x} vs {y}"
            );
        }
    }
}

#[test]
fn maps_do_not_depend_on_rows_per_message_workers_or_channel_capacity() {
    let scene = common::tiny_scene();
    let reference = run(
        &mut SimSource::new(SoftwareCamera::new(scene.clone()), false, 1).expect("source"),
        2,
        64,
    );
    assert!(
        reference
            .thickness_nm
            .iter()
            .filter(|x| x.is_finite())
            .count()
            > 600,
        "reference solves most pixels"
    );
    same_on_every_path(
        &scene,
        &reference,
        &[(1, 1, 1), (5, 2, 1), (24, 3, 4), (7, 4, 64)],
        "",
    );
}

#[test]
fn maps_do_not_depend_on_the_band_block() {
    // Rows a few at a time, so that an angle's last block is fed in several parts as its
    // last band arrives (`streams_rows`); blocks of one band, of three (the last blocks
    // shorter than the final four), the default four, eight, and one the whole angle.
    let scene = common::tiny_scene();
    let mut source = SimSource::new(SoftwareCamera::new(scene.clone()), false, 5).expect("source");
    let reference = run(&mut source, 2, 64);
    for band_block in [1, 3, 4, 8, 400] {
        let got = run_streamed(&scene, 5, |c| c.pipeline.band_block = band_block);
        same(&reference, &got, &format!("band block {band_block}"));
    }
}

#[test]
fn the_avx2_build_gives_the_portable_builds_maps() {
    // Both builds of the per-sample loops (`filmscope_core::simd::wide`): the same
    // operations in the same order, so the same maps bit for bit. On a CPU without AVX2
    // both runs take the portable build (and the test says so).
    if !filmscope_core::simd::has_avx2_fma() {
        eprintln!("this CPU has no AVX2 and FMA: both runs are the portable build");
    }
    let scene = common::tiny_scene();
    let [wide, portable] =
        [true, false].map(|on| run_streamed(&scene, 3, |c| c.pipeline.solver.wide_simd = on));
    assert!(wide.thickness_nm.iter().filter(|x| x.is_finite()).count() > 600);
    same(&wide, &portable, "AVX2 against portable");
}

/// `scene` from the software camera, `rows` rows a message, with the default configuration
/// as `set` changes it.
fn run_streamed(
    scene: &firmware_sim::Scene,
    rows: usize,
    set: impl FnOnce(&mut RunConfig),
) -> MethodResult {
    let mut source =
        SimSource::new(SoftwareCamera::new(scene.clone()), false, rows).expect("source");
    let mut config = RunConfig::default();
    set(&mut config);
    run_method(&mut source, &config, &|_| {})
        .expect("run")
        .result
}

/// Runs `scene` streamed in blocks of `rows` rows to `workers` workers over channels of
/// capacity `cap`, for each `(rows, workers, cap)` of `paths`, and checks every run gives
/// `reference`.
fn same_on_every_path(
    scene: &firmware_sim::Scene,
    reference: &MethodResult,
    paths: &[(usize, usize, usize)],
    what: &str,
) {
    same_on_every_path_keeping(scene, reference, paths, what, INDEX_PIXELS);
}

/// [`same_on_every_path`] with about `index_pixels` pixels keeping the index's sums.
fn same_on_every_path_keeping(
    scene: &firmware_sim::Scene,
    reference: &MethodResult,
    paths: &[(usize, usize, usize)],
    what: &str,
    index_pixels: usize,
) {
    for &(rows, workers, cap) in paths {
        let mut src =
            SimSource::new(SoftwareCamera::new(scene.clone()), false, rows).expect("source");
        let got = run_keeping(&mut src, workers, cap, index_pixels);
        same(
            reference,
            &got,
            &format!("{what}rows {rows}, workers {workers}, capacity {cap}"),
        );
    }
}

/// Shards of unequal height (23 rows over 2, 5 and 7 workers, down to 3-row shards) and rows
/// that end in a partial block of lanes (45 px: 32 + 13) give the same maps as one worker:
/// the rows a worker tallies as they complete, and those it leaves to the angle's end, are
/// each counted once.
#[test]
fn uneven_shards_and_partial_lane_blocks_give_the_same_maps() {
    let scene = tiny_45x23();
    let reference = run(
        &mut SimSource::new(SoftwareCamera::new(scene.clone()), false, 1).expect("source"),
        1,
        64,
    );
    let solved = reference
        .thickness_nm
        .iter()
        .filter(|x| x.is_finite())
        .count();
    assert!(solved > 900, "reference solves most pixels: {solved}");
    same_on_every_path(
        &scene,
        &reference,
        &[(1, 2, 4), (3, 5, 2), (2, 7, 64)],
        "45x23: ",
    );
}

/// With one pixel in 8 keeping the index's sums (`index_pixels`; a large sensor's default,
/// on a small one), the pixels that keep them, and so the maps, do not depend on how the
/// rows are sharded: the sample is chosen by image row and column.
#[test]
fn the_index_sample_does_not_depend_on_the_shards() {
    let scene = tiny_45x23();
    let keep = 45 * 23 / 8;
    let camera = || SimSource::new(SoftwareCamera::new(scene.clone()), false, 1);
    let reference = run_keeping(&mut camera().expect("source"), 1, 64, keep);
    let all = run(&mut camera().expect("source"), 1, 64);
    // The index comes from the pixel sample either way.
    assert!((reference.index.at(550.0) - all.index.at(550.0)).abs() < 1e-3);
    same_on_every_path_keeping(
        &scene,
        &reference,
        &[(1, 2, 4), (3, 5, 2), (2, 7, 64)],
        "1 in 8: ",
        keep,
    );
}

/// The tiny scene at 45 x 23: shards of unequal height, rows ending in a partial lane block.
fn tiny_45x23() -> firmware_sim::Scene {
    let text = common::TINY_SCENE
        .replace("width = 32", "width = 45")
        .replace("height = 24", "height = 23");
    firmware_sim::Scene::from_toml(&text, "tiny-45x23").expect("scene")
}

#[test]
fn replayed_captures_match_the_stream_in_every_interleave() {
    let scene = common::tiny_scene();
    for noise_free in [false, true] {
        let streamed = run(
            &mut SimSource::new(SoftwareCamera::new(scene.clone()), noise_free, 3).expect("source"),
            2,
            16,
        );
        for interleave in [Interleave::Bil, Interleave::Bsq, Interleave::Bip] {
            let dir = common::tempdir();
            let opts = SimulateOptions {
                noise_free,
                interleave,
                ..SimulateOptions::default()
            };
            write_capture(&scene, dir.path(), opts, &|_| {}).expect("capture");
            let cap = Capture::load(dir.path()).expect("capture loads");
            let replayed = run(&mut CaptureSource::new(cap).expect("source"), 2, 16);
            same(
                &streamed,
                &replayed,
                &format!("{interleave:?}, noise_free {noise_free}"),
            );
        }
    }
}

/// A sweep collected whole and replayed (whole frames per message, or single rows) gives the
/// maps of the live stream.
#[test]
fn whole_sweeps_match_the_stream() {
    let scene = common::tiny_scene();
    let streamed = run(
        &mut SimSource::new(SoftwareCamera::new(scene.clone()), false, 1).expect("source"),
        2,
        64,
    );
    let whole = common::WholeSource::collect(
        &mut SimSource::new(SoftwareCamera::new(scene.clone()), false, 1).expect("source"),
        1,
    );
    let h = whole.spec.height;
    let forward: Vec<usize> = (0..whole.order.len()).collect();
    for (rows, workers, cap) in [(h, 1, 1), (1, 2, 64), (h, 2, 1), (5, 1, 4)] {
        let got = run(&mut whole.with(&forward, rows), workers, cap);
        same(
            &streamed,
            &got,
            &format!("whole sweep, rows {rows}, workers {workers}, capacity {cap}"),
        );
    }
}

/// The order capture.toml lists its angles in does not change the maps (regression: a
/// capture listing its angles in decreasing incidence gave index 2.10239 instead of 2.10302,
/// because the streaming solver's result depends on the order angles arrive in; captures are
/// now streamed by increasing incidence).
#[test]
fn capture_angle_order_does_not_change_the_maps() {
    let scene = common::tiny_scene();
    let dir = common::tempdir();
    let opts = SimulateOptions {
        noise_free: false,
        interleave: Interleave::Bil,
        ..SimulateOptions::default()
    };
    write_capture(&scene, dir.path(), opts, &|_| {}).expect("capture");
    let load = || Capture::load(dir.path()).expect("capture loads");
    let reference = run(&mut CaptureSource::new(load()).expect("source"), 2, 16);
    let n = load().angles.len();
    for order in [
        (0..n).rev().collect::<Vec<_>>(),
        (0..n).map(|i| (i * 3 + 1) % n).collect(),
    ] {
        let mut cap = load();
        let angles = cap.angles.clone();
        cap.angles = order.iter().map(|&i| angles[i].clone()).collect();
        let toml = dir.path().join("capture.toml");
        cap.write_toml(&toml).expect("toml");
        let reloaded = load();
        assert_eq!(
            reloaded.angles[0].incidence_deg, angles[order[0]].incidence_deg,
            "the file lists the angles in the new order"
        );
        let got = run(&mut CaptureSource::new(reloaded).expect("source"), 1, 1);
        same(&reference, &got, &format!("angles in file order {order:?}"));
    }
}

/// The band tables are the same however many threads share their tabulation (the runs of
/// bands split where their knots do).
#[test]
fn band_tables_do_not_depend_on_the_threads_tabulating_them() {
    let source =
        SimSource::new(SoftwareCamera::new(common::tiny_scene()), false, 1).expect("source");
    let mut spec = source.spec().clone();
    // Enough pixels for every band to be tabulated.
    (spec.width, spec.height) = (1024, 1024);
    let mut solver = filmscope::solve::SweepSolver::new(
        spec,
        Some(filmscope::solve::IndexModel::constant(1.45)),
    );
    solver.begin_angle(30.0);
    let one = filmscope::pipeline::BandModels::of(&solver, 1);
    assert!(one.knots.len() > 1000, "{} knots", one.knots.len());
    assert!(one.coefs.iter().flatten().all(|c| c.tabulated()));
    let text = |m: &filmscope::pipeline::BandModels| format!("{:?} {:?}", m.coefs, m.knots);
    for threads in [2, 3, 7, 10_000] {
        let many = filmscope::pipeline::BandModels::of(&solver, threads);
        assert!(text(&many) == text(&one), "{threads} threads");
    }
}

/// Rows dealt to the workers in strips of any height (one row, three, more than a source's
/// block, the whole image) give the same maps as one worker.
#[test]
fn strips_of_any_height_give_the_same_maps() {
    let scene = tiny_45x23();
    let source = || SimSource::new(SoftwareCamera::new(scene.clone()), false, 4).expect("source");
    let reference = run(&mut source(), 1, 64);
    for strip_rows in [1, 3, 17, 64] {
        let mut config = RunConfig {
            pipeline: PipelineConfig {
                workers: 2,
                strip_rows,
                ..PipelineConfig::default()
            },
            ..RunConfig::default()
        };
        config.pipeline.solver.index_pixels = INDEX_PIXELS;
        let got = run_method(&mut source(), &config, &|_| {})
            .expect("run")
            .result;
        same(&reference, &got, &format!("strips of {strip_rows} rows"));
    }
}

/// `scene` rendered, its thickness map 1.5 nm off the truth (a seed), and its film's index
/// as the estimator holds it.
fn seeded_under_held_index(
    scene: &firmware_sim::Scene,
) -> (
    std::sync::Arc<filmscope::source::Frames>,
    std::sync::Arc<Vec<f32>>,
    filmscope_core::solve::IndexModel,
) {
    use filmscope::source::Frames;
    use std::sync::Arc;
    let frames = Arc::new(Frames::render(scene, scene.sensor.height).expect("frames"));
    let truth = filmscope::lab::eval::Truth::of_scene(scene);
    let seed: Arc<Vec<f32>> = Arc::new(truth.thickness_nm.iter().map(|d| d + 1.5).collect());
    let index =
        filmscope::estimate::known_index::held_index(&scene.stack.film, &frames.spec.bands_nm)
            .expect("index");
    (frames, seed, index)
}

/// One sweep of `frames` (replayed 4 rows a block) from `prior`.
fn sweep_of(
    frames: &std::sync::Arc<filmscope::source::Frames>,
    prior: Option<filmscope::pipeline::Prior>,
) -> filmscope::pipeline::SweepOutput {
    let mut source = filmscope::source::ReplaySource::new(frames.clone(), frames.spec.height, 4);
    filmscope::pipeline::run_sweep(&mut source, PipelineConfig::default(), prior, &|_| {})
        .expect("sweep")
}

/// A sweep whose every pixel starts seeded under a held index, given the image's noise,
/// tracks no extrema (it makes no extremum-pair index estimate): given the noise the
/// tracked sweep pooled, its maps are the tracked sweep's bit for bit (the extrema decide
/// nothing there), on the tiny scene (dead and hot pixels included) seeded 1.5 nm off the
/// truth.
#[test]
fn a_seeded_sweep_under_a_held_index_needs_no_extrema() {
    use filmscope::pipeline::{Prior, PriorUpdate};
    let (frames, seed, index) = seeded_under_held_index(&common::tiny_scene());
    let sweep = |prior: Prior| sweep_of(&frames, Some(prior));
    let tracked = sweep(Prior::new(index, PriorUpdate::Hold, Some(seed.clone())));
    let noise = tracked.noise_sigma.expect("the trackers' noise");
    let untracked =
        sweep(Prior::new(index, PriorUpdate::Hold, Some(seed)).with_noise(f64::from(noise)));
    assert_eq!(untracked.noise_sigma, Some(noise));
    // The extrema's own index estimate (the angles' pair index) is the tracked sweep's only.
    assert!(tracked.angles.iter().any(|a| a.pair.is_some()));
    assert!(untracked.angles.iter().all(|a| a.pair.is_none()));
    let valid = tracked
        .results
        .iter()
        .filter(|r| r.thickness_nm.is_finite())
        .count();
    assert!(valid * 10 > tracked.results.len() * 9, "{valid}");
    for (i, (a, b)) in tracked.results.iter().zip(&untracked.results).enumerate() {
        assert_eq!(a.flags, b.flags, "pixel {i}");
        for (x, y) in [
            (a.thickness_nm, b.thickness_nm),
            (a.thickness_sigma_nm, b.thickness_sigma_nm),
            (a.confidence, b.confidence),
        ] {
            assert_eq!(x.to_bits(), y.to_bits(), "pixel {i}: {x} vs {y}");
        }
    }
}

/// Every angle's band tables cover the thicknesses its pixels read (the tables' span is
/// taken from the pixels as each angle ends) and hold knots: a seeded sweep's from its first
/// angle on, an unseeded one's once its pixels have orders (its first angle has none to
/// cover). A sample outside the tables has its model computed, many times slower, so a
/// sweep that stopped using them would give the same maps, only late.
#[test]
fn each_angles_tables_cover_the_pixels_thicknesses() {
    use filmscope::pipeline::{Prior, PriorUpdate, SweepOutput};
    // Enough pixels that the tables repay their knots (the tiny scene's 32 x 24 do not).
    let text = common::TINY_SCENE.replace("width = 32\nheight = 24", "width = 96\nheight = 64");
    let scene = firmware_sim::Scene::from_toml(&text, "tiny-96x64").expect("scene");
    assert_eq!(scene.sensor.width, 96);
    let (frames, seed, index) = seeded_under_held_index(&scene);
    let sweep = |prior: Option<Prior>| sweep_of(&frames, prior);
    // The share of the sweep's final thicknesses inside `span`.
    let inside = |out: &SweepOutput, span: [f32; 2]| {
        let d: Vec<f32> = out
            .results
            .iter()
            .map(|r| r.thickness_nm)
            .filter(|d| d.is_finite())
            .collect();
        assert!(d.len() * 2 > out.results.len(), "{} solved", d.len());
        d.iter().filter(|&&x| span[0] <= x && x <= span[1]).count() as f64 / d.len() as f64
    };
    let seeded = sweep(Some(Prior::new(index, PriorUpdate::Hold, Some(seed))));
    let angles = scene.angles_deg.len();
    assert_eq!(seeded.tables.len(), angles);
    for (k, t) in seeded.tables.iter().enumerate() {
        let share = inside(&seeded, t.span_nm);
        assert!(share > 0.99, "seeded, angle {k}: {t:?} holds {share}");
        assert!(t.knots > 0, "seeded, angle {k}: {t:?}");
    }
    let free = sweep(None);
    assert_eq!(free.tables.len(), angles);
    let (first, last) = (free.tables[0], free.tables[angles - 1]);
    assert!(
        first.span_nm[0] > first.span_nm[1] && first.knots == 0,
        "{first:?}"
    );
    let share = inside(&free, last.span_nm);
    assert!(share > 0.99, "unseeded, last angle: {last:?} holds {share}");
    assert!(last.knots > 0, "unseeded, last angle: {last:?}");
}
