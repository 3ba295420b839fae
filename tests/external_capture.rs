//! Accuracy on captures filmscope did not make (tests/fixtures/external/): reflectance from
//! the `tmm` Python package, cubes written by Spectral Python, so a mistake shared by
//! filmscope's simulator and its solver cannot hide. `make_captures.py` in that folder writes
//! them; its README says what each one exercises (raw counts with a one-line white and a
//! dark, shuffled angles, a dispersive film; big-endian BSQ in micrometres; BIP without fwhm).
//!
//! Bounds are about 1.5-2x what was measured when this was written, never looser than 0.02
//! in the index or 10 nm in thickness. Where filmscope falls short of what a good tool should
//! meet, the test keeps that bound and is ignored as a known failure, with the measured
//! figures in the reason (run them with `-- --ignored`).

use std::path::PathBuf;

use filmscope::estimate::{flag_counts, run_method, RunConfig};
use filmscope::io::Capture;
use filmscope::lab::eval::{evaluate, EvalReport, Truth};
use filmscope::source::CaptureSource;

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
    // What the solver decided, to read a failure without rerunning anything.
    eprintln!(
        "{name}: model {:?} | flags {:?} | notes {:?}\n{name}: angles {:?}",
        run.model_choice,
        flag_counts(&run.result.flags),
        run.result.notes,
        run.angle_reports
    );
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
    assert!(
        r.valid_fraction >= b.valid_fraction,
        "{}: valid {}",
        r.scene,
        r.valid_fraction
    );
}

// Measured: index error -0.0010, MAE 0.30 nm, valid 99.2 %, silent 0, spectral RMSE 0.0002.
// Three angles only: the index arrives with the second, so a second pass holds it and refines
// every pixel (one pass: +0.0056, MAE 1.89 nm).
#[test]
fn low_index_film_on_high_index_substrate_bip_without_fwhm() {
    check(
        &eval("sio2-on-si-like-high-substrate"),
        &Bounds {
            index_error: 0.003,
            mae_nm: 1.0,
            valid_fraction: 0.95,
            spectral_rmse: 0.001,
        },
    );
}

// Measured: index error +0.0010, MAE 1.45 nm, valid 94.2 %, silent 0, spectral RMSE 0.0003
// (before the extremum lists held 20: +0.0015, 2.39 nm, 85.0 %). The accuracy on the pixels it solves is good; how many it
// solves is not (next test), so the valid floor here only guards against a collapse.
#[test]
fn thick_mgf2_float_bsq_big_endian_micrometres_is_accurate_where_solved() {
    check(
        &eval("mgf2-thick-float-bsq"),
        &Bounds {
            index_error: 0.003,
            mae_nm: 4.0,
            valid_fraction: 0.8,
            spectral_rmse: 0.001,
        },
    );
}

#[test]
#[ignore = "known failure: 7 of 120 pixels (5.8 %, the thickest) flagged poor_fit + \
            order_rejected; measured valid 0.942 (n err +0.0010, MAE 1.45 nm); filmscope's own 12 x 10 simulation of this film solves 97.5-100 %"]
fn thick_mgf2_float_bsq_big_endian_micrometres_solves_nearly_every_pixel() {
    let r = eval("mgf2-thick-float-bsq");
    assert!(r.valid_fraction >= 0.95, "valid {}", r.valid_fraction);
}

// The raw path (uint16 BIL counts, a one-line float32 white, a dark, angles out of order)
// with Debenham's Sellmeier ZnS made by tmm. Measured: index error -0.0003, MAE 0.04 nm, valid
// 100 %, spectral RMSE 0.0004 (two passes, three-term Cauchy). Before the full-spectrum pass:
// error -0.037, every pixel flagged model_mismatch.
#[test]
fn zns_with_sellmeier_dispersion_from_raw_counts() {
    let r = eval("zns-sellmeier-raw");
    check(
        &r,
        &Bounds {
            index_error: 0.003,
            mae_nm: 1.0,
            valid_fraction: 0.98,
            spectral_rmse: 0.002,
        },
    );
    assert!(
        r.silent_failure_rate <= 0.001,
        "silent failures {}",
        r.silent_failure_rate
    );
}

// Films without a fringe pair in the band, made by tmm (s light, 4 angles, float32): their
// index and thickness are in the reflectance level and shape alone. Measured: n 1.46 70-100 nm
// on PET (BSQ) index error +0.0000, MAE 0.15 nm; n 2.30 60-90 nm on glass (BIL) -0.0001,
// 0.02 nm; both valid 100 %, spectral RMSE 0.0001 (the global search on sampled spectra, then
// one seeded full-spectrum pass). Before the search: every pixel flagged.
#[test]
fn thin_films_without_fringe_pairs_above_and_below_the_substrate() {
    for name in ["thin-low-index-on-pet", "thin-high-index-on-glass"] {
        check(
            &eval(name),
            &Bounds {
                index_error: 0.003,
                mae_nm: 1.0,
                valid_fraction: 0.98,
                spectral_rmse: 0.001,
            },
        );
    }
}
