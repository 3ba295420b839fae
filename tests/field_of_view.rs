//! A lens with a field of view (issue 4, part 5: model no more than a scene needs): the
//! column geometry against analytic limits and an independent ray computation, the software
//! camera's columns, the capture's `[lens]` key and its bad values, and the field model
//! `auto` chooses on a wide and a narrow field, with the other model's figures.

use crate::common;

use common::{filmscope, run_ok, s, tempdir};
use filmscope::estimate::FieldModel;
use filmscope::estimate::{run_method_in_field, RunConfig};
use filmscope::io::Capture;
use filmscope::lab::eval::{evaluate, EvalReport, Truth};
use filmscope::optics::{BandModel, FieldOfView};
use filmscope::simulate::{write_capture, SimulateOptions};
use filmscope::source::SimSource;
use firmware_sim::{Scene, SoftwareCamera};

/// The tests' small film ([`common::TINY_SCENE`]: n = 2.1, 620 nm on glass, 4 angles x 101
/// bands) on a 48 x 24 sensor, with the lens's field of view if given.
fn tiny(fov_deg: Option<f64>, seed: u64) -> Scene {
    let fov = fov_deg.map_or(String::new(), |f| format!("\nhorizontal_fov_deg = {f:?}"));
    let text = common::TINY_SCENE
        .replace("seed = 7", &format!("seed = {seed}"))
        .replace("fwhm_nm = 5.0", &format!("fwhm_nm = 5.0{fov}"))
        .replace("width = 32", "width = 48");
    Scene::from_toml(&text, "tiny-fov").expect("scene")
}

#[test]
fn the_image_centre_sees_the_stage_angle_and_its_edges_half_the_field_more() {
    for f in [2.0, 30.0, 90.0, 170.0] {
        let fov = FieldOfView::new(f).expect("fov");
        for w in [48usize, 49, 1024] {
            // The left and right edges of the image: -f/2 and +f/2.
            assert!((fov.offset_deg(0.0, w) + 0.5 * f).abs() < 1e-9, "{f} {w}");
            assert!(
                (fov.offset_deg(w as f64, w) - 0.5 * f).abs() < 1e-9,
                "{f} {w}"
            );
            // Columns mirror about the centre.
            for c in 0..w {
                let (l, r) = (
                    fov.column_offset_deg(c, w),
                    fov.column_offset_deg(w - 1 - c, w),
                );
                assert!((l + r).abs() < 1e-9, "{f} {w} column {c}: {l} vs {r}");
            }
        }
        // An odd image has a column at its centre: exactly the stage angle.
        assert_eq!(fov.incidence_deg(35.0, 24, 49), 35.0);
    }
}

#[test]
fn column_angles_match_the_ray_geometry_in_three_dimensions() {
    // Camera at the origin looking along +z, x to the right; the stage turns the sample's
    // normal about the vertical (y) axis to (sin t, 0, -cos t). The incidence angle of the
    // ray through column c is the angle between the reversed ray and the normal.
    let (w, f) = (64usize, 30.0);
    let fov = FieldOfView::new(f).expect("fov");
    let focal = (0.5 * w as f64) / (0.5 * f64::to_radians(f)).tan();
    for stage in [0.0f64, 10.0, 35.0, 60.0] {
        let t = stage.to_radians();
        let normal = [t.sin(), 0.0, -t.cos()];
        for c in 0..w {
            let x = c as f64 + 0.5 - 0.5 * w as f64;
            let len = (x * x + focal * focal).sqrt();
            let back = [-x / len, 0.0, -focal / len];
            let cos_i: f64 = back.iter().zip(&normal).map(|(a, b)| a * b).sum();
            let incidence = cos_i.clamp(-1.0, 1.0).acos().to_degrees();
            let model = fov.incidence_deg(stage, c, w).abs();
            assert!(
                (incidence - model).abs() < 1e-9,
                "stage {stage} column {c}: ray {incidence} vs model {model}"
            );
        }
    }
}

#[test]
fn a_field_of_view_outside_0_to_180_degrees_is_refused() {
    for bad in [0.0, -1.0, 180.0, 200.0, f64::NAN, f64::INFINITY] {
        assert!(FieldOfView::new(bad).is_none(), "{bad}");
    }
    for good in [1e-6, 2.0, 179.9] {
        assert!(FieldOfView::new(good).is_some(), "{good}");
    }
}

#[test]
fn the_software_camera_renders_each_column_at_its_own_angle() {
    let wide = tiny(Some(30.0), 7);
    let camera = SoftwareCamera::new(wide.clone());
    let (w, row, band) = (wide.sensor.width, 5, 40);
    let mut seen = vec![0f32; w];
    camera.reflectance_row(1, band, row, &mut seen);
    let stage = wide.angles_deg[1];
    let fov = wide.field_of_view.expect("fov");
    for c in [0, 1, w / 2, w - 1] {
        let deg = stage + fov.column_offset_deg(c, w);
        let d = f64::from(wide.thickness_nm[row * w + c]);
        let expected = BandModel::new(wide.stack, deg, wide.passband(band)).reflectance(d);
        assert!(
            (f64::from(seen[c]) - expected).abs() < 1e-6,
            "column {c}: {} vs {expected}",
            seen[c]
        );
    }
    // The edges differ from the centre's angle by a quarter of the field: measurably.
    let centre = BandModel::new(wide.stack, stage, wide.passband(band));
    let d0 = f64::from(wide.thickness_nm[row * w]);
    assert!((f64::from(seen[0]) - centre.reflectance(d0)).abs() > 1e-3);
    // Without a field of view every column sees the stage angle, as before.
    let narrow = tiny(None, 7);
    let mut plain = vec![0f32; w];
    SoftwareCamera::new(narrow.clone()).reflectance_row(1, band, row, &mut plain);
    for (c, v) in plain.iter().enumerate() {
        let d = f64::from(narrow.thickness_nm[row * w + c]);
        assert_eq!(*v, centre.reflectance(d) as f32, "column {c}");
    }
}

#[test]
fn simulate_writes_the_lens_and_estimate_reports_the_field_model() {
    let dir = tempdir();
    let (cap, est) = (dir.path().join("cap"), dir.path().join("est"));
    write_capture(
        &tiny(Some(2.0), 7),
        &cap,
        SimulateOptions::default(),
        &|_| {},
    )
    .expect("capture");
    let text = std::fs::read_to_string(cap.join("capture.toml")).expect("capture.toml");
    assert!(text.contains("[lens]\nhorizontal_fov_deg = 2.0"), "{text}");
    let loaded = Capture::load(&cap).expect("loads");
    assert_eq!(loaded.lens.horizontal_fov_deg, Some(2.0));
    assert!(loaded.unknown_keys.is_empty(), "{:?}", loaded.unknown_keys);
    let run = run_ok(&["estimate", s(&cap), "--out", s(&est), "--field", "narrow"]);
    let out = String::from_utf8_lossy(&run.stdout);
    assert!(out.contains("field model: narrow"), "{out}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(est.join("summary.json")).expect("summary"))
            .expect("json");
    assert_eq!(summary["field_model"], "narrow");
    let choice = &summary["field_model_choice"];
    assert_eq!(choice["requested"], "narrow");
    assert_eq!(choice["geometry"]["horizontal_fov_deg"], 2.0);
    assert!(
        choice["narrow"]["residual_sigma"].as_f64().is_some(),
        "{choice}"
    );
    // The lens's predicted narrow-model thickness error at the edges: about d * 0.0016 at
    // +-1 degree (n = 2.1, angles 10-55), opposite signs, the left edge thicker.
    let edge = &choice["narrow_edge_error_nm"];
    let (left, right) = (
        edge[0].as_f64().expect("left"),
        edge[1].as_f64().expect("right"),
    );
    assert!(
        left > 0.5 && left < 1.5 && right < -0.5 && right > -1.5,
        "{edge}"
    );

    // Without a lens in the capture: narrow, and it says why.
    let plain = dir.path().join("plain");
    write_capture(&tiny(None, 7), &plain, SimulateOptions::default(), &|_| {}).expect("capture");
    assert!(!std::fs::read_to_string(plain.join("capture.toml"))
        .expect("capture.toml")
        .contains("[lens]"));
    let est2 = dir.path().join("est2");
    run_ok(&["estimate", s(&plain), "--out", s(&est2)]);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(est2.join("summary.json")).expect("summary"))
            .expect("json");
    assert_eq!(summary["field_model"], "narrow");
    let reason = summary["field_model_choice"]["reason"]
        .as_str()
        .unwrap_or("");
    assert!(reason.contains("no field of view"), "{reason}");
}

/// Runs `args`, which must fail with one line naming each of `must_name`; the line.
fn fails_with_one_line(args: &[&str], must_name: &[&str]) -> String {
    let run = filmscope().args(args).output().expect("run");
    assert!(!run.status.success(), "{args:?} succeeded");
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
    for name in must_name {
        assert!(err.contains(name), "{args:?}: {err} does not name {name}");
    }
    assert!(!err.contains("panicked"), "{err}");
    err.into_owned()
}

#[test]
fn a_bad_field_of_view_is_one_line_naming_the_file_and_the_problem() {
    let dir = tempdir();
    let cap = dir.path().join("cap");
    write_capture(&tiny(None, 7), &cap, SimulateOptions::default(), &|_| {}).expect("capture");
    let toml = cap.join("capture.toml");
    let good = std::fs::read_to_string(&toml).expect("capture.toml");
    let out = dir.path().join("out");
    // `--field wide` needs a field of view, said once.
    let err = fails_with_one_line(
        &["estimate", s(&cap), "--out", s(&out), "--field", "wide"],
        &["capture.toml", "horizontal_fov_deg"],
    );
    assert_eq!(err.matches("horizontal_fov_deg").count(), 1, "{err}");
    fails_with_one_line(
        &["estimate", s(&cap), "--out", s(&out), "--field", "sideways"],
        &["--field", "sideways"],
    );
    for (value, problem) in [
        ("0.0", "inside (0, 180)"),
        ("-5.0", "inside (0, 180)"),
        ("180.0", "inside (0, 180)"),
        ("1e300", "inside (0, 180)"),
        ("nan", "inside (0, 180)"),
        // A type error names the line, as for every key of the file.
        ("\"wide\"", "expected f64"),
        // The sweep's 55 degrees plus half of 80 reaches 95 at the image edge.
        ("80.0", "reaches 95 deg"),
    ] {
        let text = format!("{good}\n[lens]\nhorizontal_fov_deg = {value}\n");
        std::fs::write(&toml, text).expect("write");
        fails_with_one_line(
            &["estimate", s(&cap), "--out", s(&out)],
            &["capture.toml", problem],
        );
    }
    assert!(
        !out.join("summary.json").exists(),
        "no output for a bad capture"
    );
}

/// Runs the streaming method (`--field auto`) on the small film through a lens of
/// `fov_deg`, and checks the model chosen and its strips.
fn auto(fov_deg: f64, model: FieldModel, strips: u64) -> (EvalReport, serde_json::Value) {
    let scene = tiny(Some(fov_deg), 7);
    let truth = Truth::of_scene(&scene);
    let fov = scene.field_of_view;
    let mut source = SimSource::new(SoftwareCamera::new(scene), false, 1).expect("source");
    let run = run_method_in_field(&mut source, &RunConfig::default(), fov, &|_| {}).expect("run");
    let choice = serde_json::to_value(&run.field_model_choice).expect("the choice as JSON");
    assert_eq!(run.field_model, Some(model), "{choice}");
    assert_eq!(choice["geometry"]["strips"], strips, "{choice}");
    (evaluate("tiny-fov", &truth, &run), choice)
}

/// Index error, MAE and valid fraction within bounds, nothing silently wrong.
fn within(r: &EvalReport, index: f64, mae_nm: f64, valid: f64) {
    assert!(r.index_error.abs() < index, "index error {}", r.index_error);
    assert!(r.thickness_mae_nm < mae_nm, "MAE {}", r.thickness_mae_nm);
    assert!(r.valid_fraction > valid, "valid {}", r.valid_fraction);
    assert_eq!(r.silent_failure_rate, 0.0);
}

// Tolerances: measured under seeds 1-4 and 7, then set with a margin. Wide (24 degrees, 12
// strips): index +0.0012..+0.0013, MAE 0.38-0.42 nm, valid 99.7 %, nothing silent; the
// narrow fit of the same data: index +0.018..+0.022, no pixel valid (every pixel flagged).
#[test]
fn a_wide_field_gets_the_wide_model_within_tolerance_and_the_narrow_one_is_flagged() {
    let (r, choice) = auto(24.0, FieldModel::Wide, 12);
    within(&r, 0.003, 0.8, 0.97);
    // The narrow model, fitted first on the same data, is measurably worse and says so.
    let narrow = &choice["narrow"];
    let valid = narrow["valid_fraction"].as_f64().expect("narrow valid");
    assert!(valid < 0.05, "narrow valid {valid}");
    let index_error = narrow["index"]
        .as_f64()
        .map_or(f64::INFINITY, |n| (n - 2.1).abs());
    assert!(index_error > 0.01, "narrow index error {index_error}");
    let narrow_residual = narrow["residual_sigma"].as_f64().unwrap_or(f64::INFINITY);
    let wide_residual = choice["wide"]["residual_sigma"]
        .as_f64()
        .expect("wide residual");
    assert!(
        wide_residual < narrow_residual,
        "{wide_residual} vs {narrow_residual}"
    );
}

// Measured under seeds 1-4 and 7 (2 degrees): index +0.0004..+0.0016, MAE 0.73-0.81 nm,
// valid 98.8-99.7 %, the narrow fit's residual 1.07-1.21 x the noise.
#[test]
fn a_narrow_field_keeps_the_narrow_model() {
    let (r, choice) = auto(2.0, FieldModel::Narrow, 1);
    assert!(
        choice["wide"].is_null(),
        "the wide model was not needed: {choice}"
    );
    within(&r, 0.004, 1.5, 0.95);
}
