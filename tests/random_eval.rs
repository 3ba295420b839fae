//! The random evaluation (`filmscope eval --random`): its scoring and verdicts on hand-made
//! figures, and every drawn scene of a small set simulated, written, read back and estimated
//! without an error. (Whether today's estimator passes the scenes is the evaluation's own
//! output, not asserted here.)

use crate::common;

use filmscope::estimate::{run_method, RunConfig};
use filmscope::io::Capture;
use filmscope::lab::eval::{
    evaluate, random_eval, thickness_errors, Score, Truth, RANDOM_CRITERIA, SILENT_FAILURE_NM,
};
use filmscope::simulate::{write_capture, SimulateOptions};
use filmscope::source::CaptureSource;
use filmscope_core::optics::Dispersion;
use filmscope_core::solve::IndexModel;
use firmware_sim::random::Draw;

fn perfect() -> Score {
    Score {
        index_error: 0.0,
        thickness_mae_nm: 0.0,
        valid_fraction: 1.0,
        silent_failure_rate: 0.0,
        delta_e2000_mean: 0.0,
    }
}

/// A criterion's name, how to set its figure, a value at its limit and one just past it.
type Case = (&'static str, fn(&mut Score, f64), f64, f64);

/// A perfect score passes; each criterion fails alone at just past its limit and passes at
/// it; NaN figures fail.
#[test]
fn verdicts_follow_the_criteria() {
    let c = RANDOM_CRITERIA;
    let v = c.judge(&perfect(), 500.0);
    assert!(v.passed && v.failed.is_empty() && !v.index_silently_wrong);
    let cases: [Case; 5] = [
        ("index", |s, x| s.index_error = x, 0.005, 0.0051),
        ("MAE", |s, x| s.thickness_mae_nm = x, 2.0, 2.01),
        ("valid", |s, x| s.valid_fraction = x, 0.95, 0.949),
        ("silent", |s, x| s.silent_failure_rate = x, 0.001, 0.0011),
        ("dE00", |s, x| s.delta_e2000_mean = x, 1.0, 1.01),
    ];
    for (name, set, ok, bad) in cases {
        let mut s = perfect();
        set(&mut s, ok);
        assert!(c.judge(&s, 500.0).passed, "{name} at its limit");
        set(&mut s, bad);
        let v = c.judge(&s, 500.0);
        assert_eq!(v.failed, vec![name.to_owned()], "{name} past its limit");
        set(&mut s, f64::NAN);
        assert_eq!(
            c.judge(&s, 500.0).failed,
            vec![name.to_owned()],
            "{name} NaN"
        );
    }
    // Films under 100 nm get 0.02 on the index.
    let s = Score {
        index_error: -0.015,
        ..perfect()
    };
    assert!(c.judge(&s, 99.0).passed);
    assert_eq!(c.judge(&s, 100.0).failed, vec!["index".to_owned()]);
}

/// An index 0.03 off with valid pixels is "index silently wrong", even on a thin film whose
/// index tolerance is 0.02; with no pixel valid it is not (nothing was claimed).
#[test]
fn an_index_off_by_003_with_valid_pixels_is_silently_wrong() {
    let c = RANDOM_CRITERIA;
    let s = Score {
        index_error: 0.03,
        ..perfect()
    };
    for base in [80.0, 800.0] {
        let v = c.judge(&s, base);
        assert!(v.index_silently_wrong && !v.passed, "{base}");
        assert_eq!(v.failed, vec!["index".to_owned()]);
    }
    let none_valid = Score {
        index_error: -0.03,
        valid_fraction: 0.0,
        thickness_mae_nm: f64::NAN,
        ..perfect()
    };
    assert!(!c.judge(&none_valid, 800.0).index_silently_wrong);
    let close = Score {
        index_error: 0.019,
        ..perfect()
    };
    assert!(!c.judge(&close, 800.0).index_silently_wrong);
}

/// MAE, RMSE, largest error, valid and silent shares on a hand-made example.
#[test]
fn thickness_errors_by_hand() {
    let truth = [100.0f32, 200.0, 300.0, 400.0, 500.0];
    let estimate = [101.0f32, f32::NAN, 330.0, 398.0, f32::INFINITY];
    let e = thickness_errors(&truth, &estimate);
    // Valid: 101 (1 off), 330 (30 off: silent), 398 (2 off).
    assert!((e.mae_nm - 11.0).abs() < 1e-9, "{}", e.mae_nm);
    assert!((e.rmse_nm - (905.0f64 / 3.0).sqrt()).abs() < 1e-9);
    assert!((e.max_nm - 30.0).abs() < 1e-9);
    assert!((e.valid_fraction - 0.6).abs() < 1e-12);
    assert!((e.silent_failure_rate - 0.2).abs() < 1e-12);
    const { assert!(30.0 > SILENT_FAILURE_NM) };
    let none = thickness_errors(&truth, &[f32::NAN; 5]);
    assert!(none.mae_nm.is_nan() && none.valid_fraction == 0.0 && none.silent_failure_rate == 0.0);
}

/// `evaluate` on a real run whose result is replaced by the truth scores perfectly and
/// passes; the same with the index 0.03 high is failed on the index and counted silently
/// wrong, with a colour difference.
#[test]
fn evaluate_scores_a_perfect_result_as_passing() {
    let drawn = firmware_sim::random::draw(1, 0);
    let dir = common::tempdir();
    let toml = write_capture(
        &drawn.scene,
        dir.path(),
        SimulateOptions::default(),
        &|_| {},
    )
    .expect("capture");
    let cap = Capture::load(&toml).expect("capture loads");
    let mut source = CaptureSource::new(cap).expect("source");
    let mut run = run_method(&mut source, &RunConfig::default(), &|_| {}).expect("run");
    let n = 1.9;
    let truth = Truth {
        back_face: Default::default(),
        film: Dispersion::constant(n),
        substrate: drawn.scene.stack.substrate,
        ambient_index: 1.0,
        polarization: drawn.scene.stack.polarization,
        thickness_nm: drawn.scene.thickness_nm.clone(),
    };
    run.result.thickness_nm = truth.thickness_nm.clone();
    run.result.index = IndexModel::constant(n);
    let report = evaluate("perfect", &truth, &run);
    let score = Score::of(&report);
    assert_eq!(score.index_error, 0.0);
    assert_eq!(score.thickness_mae_nm, 0.0);
    assert_eq!(score.valid_fraction, 1.0);
    assert_eq!(score.silent_failure_rate, 0.0);
    assert!(
        score.delta_e2000_mean.abs() < 1e-9,
        "{}",
        score.delta_e2000_mean
    );
    let v = RANDOM_CRITERIA.judge(&score, drawn.base_thickness_nm);
    assert!(v.passed && !v.index_silently_wrong, "{v:?}");

    run.result.index = IndexModel::constant(n + 0.03);
    let off = Score::of(&evaluate("off", &truth, &run));
    assert!((off.index_error - 0.03).abs() < 1e-12);
    assert!(off.delta_e2000_mean > 0.0);
    let v = RANDOM_CRITERIA.judge(&off, drawn.base_thickness_nm);
    assert!(!v.passed && v.index_silently_wrong);
    assert!(v.failed.contains(&"index".to_owned()));
}

/// Every scene of a small fixed set is drawn, written (raw and float, several interleaves
/// and both byte orders), read back and estimated without an error or panic, passes every
/// criterion of `eval --random`; the rows and the closing line are printable and
/// serialisable.
#[test]
fn every_drawn_scene_simulates_and_estimates() {
    let dir = common::tempdir();
    let (seed, count) = (3, 4);
    let mut seen = 0;
    let result = random_eval(
        count,
        seed,
        &RunConfig::default(),
        dir.path(),
        Draw::Plain,
        None,
        &mut |_| seen += 1,
    );
    assert_eq!(seen, count);
    assert_eq!(result.rows.len(), count);
    for row in &result.rows {
        assert_eq!(row.note, None, "{}", row.table_row());
        let s = row.score.expect("a score");
        assert!(s.index_error.is_finite(), "{}", row.table_row());
        assert!(s.valid_fraction > 0.0, "{}", row.table_row());
        assert!(s.thickness_mae_nm.is_finite() && s.delta_e2000_mean.is_finite());
        assert_eq!(row.passed, row.failed.is_empty());
        assert!(!row.table_row().is_empty());
    }
    let kinds: std::collections::HashSet<_> = result
        .rows
        .iter()
        .map(|r| (r.sensor.clone(), r.interleave.clone(), r.byte_order.clone()))
        .collect();
    assert!(kinds.len() >= 3, "{kinds:?}");
    // The estimator meets every criterion on every scene of the set, and no index is wrong
    // with pixels reported.
    let failed: Vec<String> = result
        .rows
        .iter()
        .filter(|r| !r.passed)
        .map(|r| r.table_row())
        .collect();
    assert!(failed.is_empty(), "{failed:#?}");
    assert_eq!(result.index_silently_wrong, 0);
    assert!(result.rows.iter().any(|r| r.sensor == "raw"));
    assert!(result.rows.iter().any(|r| r.sensor == "float"));
    assert_eq!(
        result.closing_line(),
        format!(
            "random eval: {} of {count} passed, {} index silently wrong",
            result.passed, result.index_silently_wrong
        )
    );
    let json = serde_json::to_value(&result).expect("json");
    assert_eq!(json["rows"].as_array().map(Vec::len), Some(count));
    // The captures are removed after each scene.
    assert_eq!(std::fs::read_dir(dir.path()).expect("dir").count(), 0);
}

/// Thick high-index films with a step in the map and few angles (TiO2 1.74 um on 3 angles,
/// Nb2O5 1.53 um on 5, both drawn by `eval --random 100 --seed 2`): 20 or more extrema per
/// spectrum overflow the per-pixel lists and the sample's map runs across the step, so the
/// streaming pass leaves pixels unsolved (only 85 and 90 % valid before); the thickness
/// search on their full spectra solves every one of them, none silently wrong.
#[test]
fn thick_high_index_films_with_a_step_have_every_pixel_solved() {
    let dir = common::tempdir();
    for i in [3, 49] {
        let row = filmscope::lab::eval::random_scene(
            2,
            i,
            &RunConfig::default(),
            dir.path(),
            Draw::Plain,
        );
        assert!(row.passed, "{}", row.table_row());
        let s = row.score.expect("a score");
        assert!(s.valid_fraction >= 0.99, "{}", row.table_row());
        assert_eq!(s.silent_failure_rate, 0.0, "{}", row.table_row());
    }
}

/// Films thicker than the old fixed 2000 nm search range and thinner than its 50 nm start,
/// with no range given (`eval --random 100 --seed 3 --thick`: Ta2O5 4.94 um and CaF2 4.74 um
/// on two angles, Si3N4 40 nm): the default range follows what the bands resolve and reaches
/// each; every pixel valid, none silently wrong.
#[test]
fn thick_and_thin_films_are_reached_without_a_range() {
    let dir = common::tempdir();
    for i in [24, 27, 68] {
        let drawn = firmware_sim::random::draw_thick(3, i);
        assert!(!drawn.toml.contains("thickness_range_nm"), "{}", drawn.toml);
        let row = filmscope::lab::eval::random_scene(
            3,
            i,
            &RunConfig::default(),
            dir.path(),
            Draw::Thick,
        );
        assert!(row.passed, "{}", row.table_row());
        let s = row.score.expect("a score");
        assert!(s.valid_fraction >= 0.99, "{}", row.table_row());
        assert_eq!(s.silent_failure_rate, 0.0, "{}", row.table_row());
    }
}
