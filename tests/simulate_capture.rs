//! `filmscope simulate`: the capture it writes follows the contract, and the noise-free
//! capture matches an independent thin-film computation (Abeles characteristic matrices,
//! written here, not filmscope's Airy code) averaged over the passband by Simpson's rule.

use std::path::{Path, PathBuf};
use std::process::Command;

use filmscope::io::{read_cube, Capture, DataType, EnviReader};
use filmscope::record::truth::{PolarizationRecord, TruthRecord};
use filmscope::simulate::{write_capture, SimulateOptions};
use firmware_sim::Scene;

fn scene(name: &str) -> Scene {
    let p = format!("{}/config/scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    Scene::load(Path::new(&p)).expect("scene loads")
}

fn tempdir() -> tempfile::TempDir {
    tempfile::tempdir().expect("temp dir")
}

/// S-polarised reflectance of one film by the characteristic-matrix method.
fn abeles_s(n0: f64, n1: f64, ns: f64, d_nm: f64, theta0_deg: f64, lambda_nm: f64) -> f64 {
    let s0 = theta0_deg.to_radians().sin() * n0;
    let eta = |n: f64| (n * n - s0 * s0).sqrt(); // n cos(theta), real here
    let (e0, e1, es) = (eta(n0), eta(n1), eta(ns));
    let delta = 2.0 * std::f64::consts::PI * e1 * d_nm / lambda_nm;
    let (c, s) = (delta.cos(), delta.sin());
    // M = [[c, i s / e1], [i e1 s, c]]; r = (e0 B - C) / (e0 B + C) with
    // [B, C] = M [1, es]: B = c + i s es / e1, C = i e1 s + c es.
    let (b_re, b_im) = (c, s * es / e1);
    let (c_re, c_im) = (c * es, e1 * s);
    let (num_re, num_im) = (e0 * b_re - c_re, e0 * b_im - c_im);
    let (den_re, den_im) = (e0 * b_re + c_re, e0 * b_im + c_im);
    (num_re * num_re + num_im * num_im) / (den_re * den_re + den_im * den_im)
}

/// Gaussian passband (FWHM, truncated at 1.5 FWHM) by Simpson's rule on 2001 points.
fn band_average(f: impl Fn(f64) -> f64, centre: f64, fwhm: f64) -> f64 {
    let n = 2001;
    let (a, b) = (centre - 1.5 * fwhm, centre + 1.5 * fwhm);
    let h = (b - a) / (n - 1) as f64;
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..n {
        let l = a + h * i as f64;
        let k = if i == 0 || i == n - 1 {
            1.0
        } else if i % 2 == 1 {
            4.0
        } else {
            2.0
        };
        let w = k * (-4.0 * std::f64::consts::LN_2 * ((l - centre) / fwhm).powi(2)).exp();
        num += w * f(l);
        den += w;
    }
    num / den
}

#[test]
fn noise_free_capture_matches_an_independent_thin_film_model_to_1e4() {
    let sc = scene("paper-sample1");
    let dir = tempdir();
    let opts = SimulateOptions {
        noise_free: true,
        ..SimulateOptions::default()
    };
    let toml = write_capture(&sc, dir.path(), opts, &|_| {}).expect("capture written");
    let cap = Capture::load(&toml).expect("capture loads");
    assert_eq!(cap.angles.len(), 5);
    let truth = read_cube(dir.path().join("truth/thickness_nm.hdr")).expect("truth map");
    let (w, h) = (sc.sensor.width, sc.sensor.height);
    let mut worst = 0.0f64;
    for (a, angle) in cap.angles.iter().enumerate() {
        let cube = read_cube(&angle.cube).expect("cube");
        assert_eq!(cube.header.data_type, DataType::F32);
        let wl = cube.header.wavelength_nm.clone().expect("wavelengths");
        let fwhm = cube.header.fwhm_nm.clone().expect("fwhm");
        for k in 0..12 {
            let (col, row) = ((k * 37 + a * 11) % w, (k * 23 + a * 5) % h);
            let d = f64::from(truth.get(0, row, col).expect("truth pixel"));
            for b in (0..wl.len()).step_by(5) {
                let want = band_average(
                    |l| abeles_s(1.0, 1.37, 1.65, d, angle.incidence_deg, l),
                    wl[b],
                    fwhm[b],
                );
                let got = f64::from(cube.get(b, row, col).expect("pixel"));
                worst = worst.max((got - want).abs());
                assert!(
                    (got - want).abs() < 1e-4,
                    "angle {a} band {b} px ({col},{row}): {got} vs {want}"
                );
            }
        }
    }
    eprintln!("worst |R_sim - R_independent| = {worst:.2e}");
}

#[test]
fn raw_capture_has_counts_references_and_truth() {
    let mut sc = scene("thin-80nm");
    sc.angles_deg.truncate(2);
    let dir = tempdir();
    let toml = write_capture(&sc, dir.path(), SimulateOptions::default(), &|_| {})
        .expect("capture written");
    let cap = Capture::load(&toml).expect("capture loads");
    let info = cap.check().expect("cubes agree");
    assert_eq!(info.data_type, DataType::U16);
    for angle in &cap.angles {
        assert!(angle.white.is_some() && angle.dark.is_some());
        let r = EnviReader::open(&angle.cube).expect("cube opens");
        assert!(r
            .header()
            .extra
            .iter()
            .any(|(k, v)| k.eq_ignore_ascii_case("saturation counts") && v == "4095"));
    }
    // The file names every member, a constant index's model as null.
    let text = std::fs::read_to_string(dir.path().join("truth.json")).expect("truth.json");
    let members: serde_json::Map<String, serde_json::Value> =
        serde_json::from_str(&text).expect("an object");
    for key in [
        "refractive_index",
        "dispersion",
        "substrate_index",
        "polarization",
    ] {
        assert!(members.contains_key(key), "truth.json lacks {key}");
    }
    let truth = TruthRecord::read(dir.path()).expect("truth.json");
    assert!((truth.refractive_index - 1.45).abs() < 1e-12);
    assert_eq!(
        truth.polarization,
        PolarizationRecord::from(sc.stack.polarization)
    );
    assert_eq!(
        (truth.width, truth.height),
        (sc.sensor.width, sc.sensor.height)
    );
}

fn filmscope() -> Command {
    Command::new(env!("CARGO_BIN_EXE_filmscope"))
}

#[test]
fn bad_scene_files_get_one_line_naming_the_file() {
    let dir = tempdir();
    let cases: [(&str, &str); 4] = [
        ("garbage.toml", "this is = = not toml"),
        ("no-film.toml", "[substrate]\nindex = 1.65\n[rig]\nangles_deg = [10.0, 20.0]\nbands_nm = [420.0, 720.0, 2.0]\nfwhm_nm = 4.0\n"),
        ("no-angle.toml", "[film]\nindex = 1.4\n[film.thickness]\nbase_nm = 300.0\n[substrate]\nindex = 1.65\n[rig]\nangles_deg = []\nbands_nm = [420.0, 720.0, 2.0]\nfwhm_nm = 4.0\n"),
        ("empty.toml", ""),
    ];
    for (name, text) in cases {
        let path: PathBuf = dir.path().join(name);
        std::fs::write(&path, text).expect("write scene");
        let out = filmscope()
            .args(["simulate", path.to_str().expect("utf-8"), "--out"])
            .arg(dir.path().join("out"))
            .output()
            .expect("run filmscope");
        assert!(!out.status.success(), "{name} was accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim_end().lines().count(), 1, "{name}: {err}");
        assert!(err.contains(name), "{name}: {err}");
        assert!(!err.contains("panicked"), "{name}: {err}");
    }
    let missing = filmscope()
        .args(["simulate", "/nonexistent/scene.toml", "--out", "/tmp/x"])
        .output()
        .expect("run");
    assert!(!missing.status.success());
    assert!(String::from_utf8_lossy(&missing.stderr).contains("/nonexistent/scene.toml"));
}

/// A float-reflectance capture (`SimulateOptions::float_reflectance`) of a scene with
/// reflectance noise 0 holds the true band reflectance to the ADC's rounding, without
/// references; written big endian in any interleave it reads back the same values.
#[test]
fn float_reflectance_capture_holds_the_reflectance_in_any_layout() {
    use filmscope::io::{ByteOrder, Interleave};
    let text = r#"
name = "float"
seed = 3
[film.dispersion]
model = "material"
name = "ta2o5"
[film.thickness]
base_nm = 300.0
gradient_nm = [40.0, 0.0]
[substrate]
index = 1.52
[rig]
angles_deg = [10.0, 40.0]
bands_nm = [420.0, 720.0, 10.0]
fwhm_nm = 5.0
[sensor]
width = 12
height = 8
reflectance_noise_percent = 0.0
"#;
    let sc = Scene::from_toml(text, "float").expect("scene");
    let camera = firmware_sim::SoftwareCamera::new(sc.clone());
    let mut first: Option<Vec<f32>> = None;
    for interleave in [Interleave::Bsq, Interleave::Bil, Interleave::Bip] {
        for byte_order in [ByteOrder::Little, ByteOrder::Big] {
            let dir = tempdir();
            let opts = SimulateOptions {
                interleave,
                byte_order,
                float_reflectance: true,
                ..SimulateOptions::default()
            };
            write_capture(&sc, dir.path(), opts, &|_| {}).expect("capture");
            let cap = Capture::load(dir.path()).expect("capture loads");
            assert!(cap
                .angles
                .iter()
                .all(|a| a.white.is_none() && a.dark.is_none()));
            let cube = read_cube(dir.path().join("a40.hdr")).expect("cube");
            assert_eq!(cube.header.data_type, DataType::F32);
            assert_eq!(cube.header.byte_order, byte_order);
            assert_eq!(cube.header.interleave, interleave);
            let mut row = vec![0f32; cube.samples];
            for b in 0..cube.bands {
                for l in 0..cube.lines {
                    camera.reflectance_row(1, b, l, &mut row);
                    let start = (b * cube.lines + l) * cube.samples;
                    for (got, want) in cube.data[start..start + cube.samples].iter().zip(&row) {
                        // One count of rounding over at least ~2500 counts of white.
                        assert!(
                            (got - want).abs() < 1e-3,
                            "band {b} line {l}: {got} vs {want}"
                        );
                    }
                }
            }
            match &first {
                None => first = Some(cube.data),
                Some(f) => assert_eq!(f, &cube.data, "{interleave:?} {byte_order:?}"),
            }
        }
    }
}
