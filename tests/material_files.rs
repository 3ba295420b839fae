//! Material files and the dispersive substrate through the command line: `estimate` writes
//! `index.csv` and `index.yml`; a capture's `substrate = "..."` (library name or
//! refractiveindex.info YAML) reaches the estimator, render and glTF export; `simulate
//! --seed` and `eval --seed`.

use crate::common;

use std::path::Path;

use common::{filmscope, s, tempdir};
use filmscope::io::{read_cube, Capture};
use filmscope::lab::eval::{evaluate, Truth};
use filmscope::material;
use filmscope::source::CaptureSource;

/// MgF2-like film on N-BK7 (the library's SCHOTT formula), 48 x 32 px, raw counts.
const BK7_SCENE: &str = r#"
name = "bk7"
seed = 21
polarization = "s"

[film]
index = 1.38

[film.thickness]
base_nm = 420.0
gradient_nm = [30.0, -10.0]

[substrate]
dispersion = { model = "material", name = "bk7" }

[rig]
angles_deg = [10.0, 25.0, 40.0, 55.0]
bands_nm = [420.0, 720.0, 2.0]
fwhm_nm = 4.0

[sensor]
width = 48
height = 32
"#;

fn run_ok(args: &[&str]) -> String {
    let out = filmscope().args(args).output().expect("run");
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Index error at 550 nm and thickness MAE of the capture in `cap` estimated as it is.
fn accuracy(cap: &Path, truth: &Truth) -> (f64, f64) {
    let capture = Capture::load(cap).expect("capture");
    let mut source = CaptureSource::new(capture).expect("source");
    let run = filmscope::estimate::run_method(
        &mut source,
        &filmscope::estimate::RunConfig::default(),
        &|_| {},
    )
    .expect("run");
    let r = evaluate("bk7", truth, &run);
    (r.index_error, r.thickness_mae_nm)
}

#[test]
fn a_dispersive_substrate_is_measured_as_well_as_a_constant_one() {
    let dir = tempdir();
    let scene_path = dir.path().join("bk7.toml");
    std::fs::write(&scene_path, BK7_SCENE).expect("scene");
    let n550 = material::resolve("bk7").expect("bk7").index_at(550.0);
    let const_path = dir.path().join("const.toml");
    std::fs::write(
        &const_path,
        BK7_SCENE.replace(
            r#"dispersion = { model = "material", name = "bk7" }"#,
            &format!("index = {n550}"),
        ),
    )
    .expect("scene");
    let (bk7, constant) = (dir.path().join("bk7"), dir.path().join("const"));
    run_ok(&["simulate", s(&scene_path), "--out", s(&bk7)]);
    run_ok(&["simulate", s(&const_path), "--out", s(&constant)]);
    let text = std::fs::read_to_string(bk7.join("capture.toml")).expect("capture.toml");
    assert!(text.contains("substrate = \"substrate.yml\""), "{text}");
    let truth = Truth::of_capture_dir(&bk7).expect("truth");
    assert!(!truth.substrate.is_constant());

    let dispersive = accuracy(&bk7, &truth);
    let constant_acc = accuracy(&constant, &Truth::of_capture_dir(&constant).expect("truth"));
    // The same capture with the substrate taken constant (its n at 550 nm).
    std::fs::write(
        bk7.join("capture.toml"),
        text.replace("substrate = \"substrate.yml\"\n", ""),
    )
    .expect("write");
    let as_constant = accuracy(&bk7, &truth);
    std::fs::write(bk7.join("capture.toml"), &text).expect("write");
    println!(
        "index error / thickness MAE: dispersive substrate {:+.5} / {:.3} nm, constant substrate {:+.5} / {:.3} nm, dispersive taken constant {:+.5} / {:.3} nm",
        dispersive.0, dispersive.1, constant_acc.0, constant_acc.1, as_constant.0, as_constant.1
    );
    assert!(dispersive.0.abs() < 0.001 && dispersive.1 < 1.0);
    assert!(dispersive.0.abs() < constant_acc.0.abs() + 0.0005);
    assert!(dispersive.1 < constant_acc.1 + 0.3);
    assert!(as_constant.1 > dispersive.1 + 0.1, "{as_constant:?}");

    // The outputs: index files, the substrate in the summary, render and glTF.
    let est = dir.path().join("est");
    run_ok(&["estimate", s(&bk7), "--out", s(&est)]);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(est.join("summary.json")).expect("summary"))
            .expect("json");
    assert_eq!(summary["sample"]["substrate"]["model"], "sellmeier");
    assert_eq!(summary["files"]["index_yml"], "index.yml");
    let yml = material::resolve(s(&est.join("index.yml"))).expect("index.yml");
    let table = &summary["dispersion"]["n_table"];
    for (l, n) in table["wavelength_nm"]
        .as_array()
        .expect("wl")
        .iter()
        .zip(table["n"].as_array().expect("n"))
    {
        let (l, n) = (l.as_f64().expect("l"), n.as_f64().expect("n"));
        assert!(
            (yml.index_at(l) - n).abs() < 1e-9,
            "{l}: {}",
            yml.index_at(l)
        );
    }
    let csv = std::fs::read_to_string(est.join("index.csv")).expect("csv");
    assert!(csv.starts_with("wavelength_nm,n\n420,"), "{csv}");
    assert_eq!(csv.lines().count(), 1 + 151);
    run_ok(&["render", s(&est), "--out", s(&dir.path().join("r.png"))]);
    run_ok(&[
        "export-gltf",
        s(&est),
        "--out",
        s(&dir.path().join("s.glb")),
    ]);
    let film = filmscope::appearance::SampleFilm::load(&est, None).expect("film");
    assert_eq!(film.stack.substrate, truth.substrate);
}

#[test]
fn a_substrate_that_cannot_be_read_is_one_line_naming_the_key() {
    let dir = tempdir();
    let cap = dir.path().join("cap");
    common::estimated_tiny(dir.path(), true);
    let text = std::fs::read_to_string(cap.join("capture.toml")).expect("capture.toml");
    for (value, says) in [
        (
            "unobtainium",
            "neither a refractiveindex.info YAML file nor",
        ),
        ("missing.yml", "cannot read"),
    ] {
        std::fs::write(
            cap.join("capture.toml"),
            text.replace(
                "[sample]\n",
                &format!("[sample]\nsubstrate = \"{value}\"\n"),
            ),
        )
        .expect("write");
        let out = filmscope()
            .args(["estimate", s(&cap), "--out", s(&dir.path().join("e2"))])
            .output()
            .expect("run");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success());
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(
            err.contains("capture.toml") && err.contains("sample.substrate") && err.contains(says),
            "{err}"
        );
    }
}

#[test]
fn simulate_and_eval_take_a_seed() {
    let dir = tempdir();
    let scene = dir.path().join("bk7.toml");
    std::fs::write(&scene, BK7_SCENE).expect("scene");
    let cap = |name: &str, seed: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec!["simulate", s(&scene), "--out", s(&out)];
        args.extend_from_slice(seed);
        run_ok(&args);
        let cube = read_cube(out.join("a10.hdr")).expect("cube").data;
        let truth = read_cube(out.join("truth/thickness_nm.hdr"))
            .expect("truth")
            .data;
        (cube, truth)
    };
    let (a, ta) = cap("a", &["--seed", "5"]);
    let (b, tb) = cap("b", &["--seed", "5"]);
    let (c, _) = cap("c", &["--seed", "6"]);
    let (d, _) = cap("d", &[]);
    assert_eq!(a, b);
    assert_eq!(ta, tb);
    assert_ne!(a, c);
    assert_ne!(a, d, "seed 5 is not the scene's own 21");
    let row = |seed: &str| {
        let out = run_ok(&["eval", s(&scene), "--seed", seed, "--json"]);
        let v: serde_json::Value = serde_json::from_str(out.trim()).expect("json row");
        v["thickness_mae_nm"].as_f64().expect("mae")
    };
    assert_eq!(row("5"), row("5"));
    let err = filmscope()
        .args(["eval", s(&dir.path().join("a")), "--seed", "3"])
        .output()
        .expect("run");
    assert!(!err.status.success());
    assert!(String::from_utf8_lossy(&err.stderr).contains("not a scene file"));
}

/// `estimate --film-index`: the film's index given (a number, a library name, a YAML file
/// written by filmscope) is held and the maps agree with the truth; under a wrong index the
/// sample's sites do not fit, and no pixel gets a thickness rather than a wrong one.
#[test]
fn a_given_film_index_is_held() {
    let dir = tempdir();
    let scene = dir.path().join("bk7.toml");
    std::fs::write(&scene, BK7_SCENE).expect("scene");
    let cap = dir.path().join("cap");
    run_ok(&["simulate", s(&scene), "--out", s(&cap)]);
    let truth = read_cube(cap.join("truth/thickness_nm.hdr"))
        .expect("truth")
        .data;
    let mae = |est: &Path| {
        let d = read_cube(est.join("thickness_nm.hdr")).expect("map").data;
        let (sum, n) = d
            .iter()
            .zip(&truth)
            .filter(|(a, _)| a.is_finite())
            .fold((0.0, 0usize), |(s, n), (a, t)| {
                (s + f64::from((a - t).abs()), n + 1)
            });
        (sum / n.max(1) as f64, n)
    };
    let yml = dir.path().join("film.yml");
    std::fs::write(
        &yml,
        material::to_rii_yaml(
            &filmscope::optics::Dispersion::constant(1.38),
            [420.0, 720.0],
            "t",
        ),
    )
    .expect("yml");
    for (given, good) in [
        ("1.38", true),
        (s(&yml), true),
        ("mgf2", true),
        ("1.6", false),
    ] {
        let est = dir.path().join(format!("e{}", given.len()));
        run_ok(&["estimate", s(&cap), "--out", s(&est), "--film-index", given]);
        let summary: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(est.join("summary.json")).expect("summary"),
        )
        .expect("json");
        let (m, n) = mae(&est);
        println!(
            "--film-index {given}: n(550) {}, thickness MAE {m:.3} nm over {n} px, sample chi2_nu {}",
            summary["refractive_index"], summary["index_model_choice"]["chi2_nu"]
        );
        assert_eq!(summary["index_model_choice"]["given"], given);
        if given == "mgf2" {
            // The library's MgF2 (Dodge, bulk crystal, 1.3785) is near enough the film's 1.38.
            assert!(m < 3.0, "{m}");
        } else if good {
            assert!((summary["refractive_index"].as_f64().expect("n") - 1.38).abs() < 1e-12);
            assert!(m < 1.0 && n > 1400, "{m} {n}");
        } else {
            // The sample's sites do not fit under it: no pixel gets a thickness.
            assert_eq!(n, 0, "{m}");
            assert!(summary["index_model_choice"]["failure"].is_string());
        }
        if good {
            let chi2_nu = summary["index_model_choice"]["chi2_nu"].as_f64();
            assert!(chi2_nu.is_some_and(|c| c < 1.5), "{chi2_nu:?}");
        }
    }
    let out = filmscope()
        .args([
            "estimate",
            s(&cap),
            "--out",
            s(&dir.path().join("x")),
            "--film-index",
            "unobtainium",
        ])
        .output()
        .expect("run");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--film-index \"unobtainium\""));
}

/// A material whose index is 2.1 at 550 nm but falls below the ambient's and turns negative
/// below 450 nm (Cauchy 3.806 - 0.1561 / l^4): `--film-index` is refused with one line naming
/// a wavelength of the captured band, and so is a scene with that film.
#[test]
fn an_index_below_the_ambient_anywhere_in_the_band_is_refused() {
    let dir = tempdir();
    let (out, run) = estimate_with_film_file(
        dir.path(),
        "sinking.yml",
        "REFERENCES: made up\nDATA:\n  - type: formula 5\n    wavelength_range: 0.3 1.0\n    coefficients: 3.806 -0.1561 -4\n",
    );
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("--film-index")
            && err.contains("sinking.yml")
            && err.contains("n(420.0 nm) = -1.2"),
        "{err}"
    );
    assert!(!out.exists(), "nothing written");
    let scene = dir.path().join("sinking.toml");
    std::fs::write(
        &scene,
        common::TINY_SCENE.replace(
            "[film]\nindex = 2.1\n",
            "[film]\ndispersion = { model = \"cauchy\", a = 3.806, b_um2 = 0.0, c_um4 = -0.1561 }\n",
        ),
    )
    .expect("scene");
    let run = filmscope()
        .args(["simulate", s(&scene), "--out", s(&dir.path().join("sim"))])
        .output()
        .expect("run");
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("[film] n(420.0 nm) = -1.2"), "{err}");
}

/// A film material that absorbs (a `tabulated nk` entry: amorphous-silicon-like k) given as
/// `--film-index` is measured with its n and k; given for a clear film it explains none of
/// the spectra: every pixel NaN and flagged, a note naming the given film and the misfit.
#[test]
fn an_absorbing_film_material_given_for_a_clear_film_is_a_misfit() {
    let dir = tempdir();
    let (out, run) = estimate_with_film_file(
        dir.path(),
        "a-si.yml",
        "DATA:\n  - type: tabulated nk\n    data: |\n        0.40 4.6 1.9\n        0.55 4.4 0.60\n        0.80 3.9 0.05\n",
    );
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    assert!(
        err.contains("does not explain the spectra") && err.contains("a-si.yml"),
        "{err}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary"))
            .expect("json");
    assert_eq!(summary["valid_fraction"], 0.0, "{summary}");
    assert_eq!(
        summary["index_model_choice"]["absorbing"], true,
        "{summary}"
    );
}

/// `estimate` of a tiny capture in `dir` with `--film-index` a file `name` holding `yaml`:
/// the output folder and the run.
fn estimate_with_film_file(
    dir: &std::path::Path,
    name: &str,
    yaml: &str,
) -> (std::path::PathBuf, std::process::Output) {
    let cap = dir.join("cap");
    filmscope::simulate::write_capture(
        &common::tiny_scene(),
        &cap,
        filmscope::simulate::SimulateOptions::default(),
        &|_| {},
    )
    .expect("capture");
    let yml = dir.join(name);
    std::fs::write(&yml, yaml).expect("yml");
    let out = dir.join("est");
    let run = filmscope()
        .args([
            "estimate",
            s(&cap),
            "--out",
            s(&out),
            "--film-index",
            s(&yml),
        ])
        .output()
        .expect("run");
    (out, run)
}
