//! Accuracy on captures filmscope did not make (tests/fixtures/external/): reflectance from
//! the `tmm` Python package, cubes written by Spectral Python, so a mistake shared by
//! filmscope's simulator and its solver cannot hide. `make_captures.py` in that folder writes
//! them; its README lists what each one exercises. Bounds are about 1.5-2x what was measured
//! when this was written, never looser than 0.02 in the index or 10 nm in thickness.

use std::path::PathBuf;

use filmscope::estimate::{run_method, RunConfig};
use filmscope::eval::{evaluate, EvalReport, Truth};
use filmscope::io::Capture;
use filmscope::pipeline::CaptureSource;

fn dir(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/external")
        .join(name)
}

fn eval(name: &str) -> EvalReport {
    let dir = dir(name);
    let cap = Capture::load(&dir).unwrap_or_else(|e| panic!("{name}: load: {e}"));
    let mut source = CaptureSource::new(cap).expect("source");
    let run = run_method(&mut source, &RunConfig::default(), &|_| {}).expect("run");
    let truth = Truth::of_capture_dir(&dir).expect("truth");
    let r = evaluate(name, &truth, &run);
    eprintln!("{}", serde_json::to_string(&r).expect("json"));
    r
}

/// Bounds one capture must meet.
struct Bounds {
    index_error: f64,
    mae_nm: f64,
    valid_fraction: f64,
    spectral_rmse: f64,
}

fn check(r: &EvalReport, b: &Bounds) {
    assert!(
        r.silent_failure_rate <= 0.001,
        "{}: silent failures {}",
        r.scene,
        r.silent_failure_rate
    );
    assert!(
        r.valid_fraction >= b.valid_fraction,
        "{}: valid {}",
        r.scene,
        r.valid_fraction
    );
    assert!(
        r.index_error.abs() <= b.index_error,
        "{}: index error {} (estimated {}, true {})",
        r.scene,
        r.index_error,
        r.index_estimated,
        r.index_true
    );
    assert!(
        r.thickness_mae_nm <= b.mae_nm,
        "{}: MAE {} nm",
        r.scene,
        r.thickness_mae_nm
    );
    assert!(
        r.spectral_rmse <= b.spectral_rmse,
        "{}: spectral RMSE {}",
        r.scene,
        r.spectral_rmse
    );
}

#[test]
fn zns_with_sellmeier_dispersion_from_raw_counts() {
    check(
        &eval("zns-sellmeier-raw"),
        &Bounds {
            index_error: 0.02,
            mae_nm: 10.0,
            valid_fraction: 0.95,
            spectral_rmse: 0.02,
        },
    );
}

#[test]
fn thick_mgf2_float_bsq_big_endian_micrometres() {
    check(
        &eval("mgf2-thick-float-bsq"),
        &Bounds {
            index_error: 0.02,
            mae_nm: 10.0,
            valid_fraction: 0.95,
            spectral_rmse: 0.02,
        },
    );
}

#[test]
fn low_index_film_on_high_index_substrate_bip_without_fwhm() {
    check(
        &eval("sio2-on-si-like-high-substrate"),
        &Bounds {
            index_error: 0.02,
            mae_nm: 10.0,
            valid_fraction: 0.95,
            spectral_rmse: 0.02,
        },
    );
}
