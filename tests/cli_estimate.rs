//! `filmscope estimate` per the contract: the outputs it writes, and one-line errors with a
//! non-zero exit for captures that cannot be read.

use crate::common;

use std::path::Path;

use common::{filmscope, s, tempdir};
use filmscope::io::read_cube;
use filmscope::simulate::{write_capture, SimulateOptions};

fn capture(dir: &Path) {
    write_capture(
        &common::tiny_scene(),
        dir,
        SimulateOptions::default(),
        &|_| {},
    )
    .expect("capture");
}

#[test]
fn estimate_writes_the_contract_outputs() {
    let dir = tempdir();
    let cap = dir.path().join("cap");
    capture(&cap);
    let out = dir.path().join("est");
    let run = filmscope()
        .args(["estimate", s(&cap), "--out", s(&out)])
        .output()
        .expect("run");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary"))
            .expect("json");
    let n = summary["refractive_index"].as_f64().expect("index");
    assert!((n - 2.1).abs() < 0.01, "n = {n}");
    assert!(summary.get("dispersion").is_some());
    for k in ["mean", "median", "std", "min", "max"] {
        assert!(summary["thickness_nm"][k].is_number(), "thickness_nm.{k}");
    }
    let valid = summary["valid_fraction"].as_f64().expect("valid_fraction");
    assert!(valid > 0.9, "valid {valid}");
    assert_eq!(summary["width"], 32);
    assert_eq!(summary["height"], 24);
    let map = read_cube(out.join("thickness_nm.hdr")).expect("thickness map");
    assert_eq!((map.samples, map.lines, map.bands), (32, 24, 1));
    let finite = map.data.iter().filter(|x| x.is_finite()).count() as f64 / map.data.len() as f64;
    assert!((finite - valid).abs() < 1e-12);
    // The dead and hot pixels are NaN, never a number.
    assert!(map.data.iter().filter(|x| x.is_nan()).count() >= 3);
    let conf = read_cube(out.join("confidence.hdr")).expect("confidence map");
    assert!(conf.data.iter().all(|c| (0.0..=1.0).contains(c)));
    let flags = read_cube(out.join("flags.hdr")).expect("flags map");
    assert_eq!(flags.data.len(), 32 * 24);
    // Every reported thickness has its sigma, within the limit the summary names.
    let sigma = read_cube(out.join("thickness_sigma_nm.hdr")).expect("sigma map");
    let limit = summary["thickness_sigma_nm"]["imprecise_above"]
        .as_f64()
        .expect("imprecise_above");
    for (d, s) in map.data.iter().zip(&sigma.data) {
        assert!(
            !d.is_finite() || (*s > 0.0 && f64::from(*s) <= limit),
            "thickness {d} with sigma {s}"
        );
    }
    let p90 = summary["thickness_sigma_nm"]["p90"].as_f64().expect("p90");
    assert!(p90 > 0.0 && p90 <= limit, "p90 {p90}");
    let png = std::fs::read(out.join("thickness_nm.png")).expect("preview");
    assert_eq!(&png[1..4], b"PNG");
    // No temporary files left behind.
    for e in std::fs::read_dir(&out).expect("out dir") {
        let name = e.expect("entry").file_name().to_string_lossy().into_owned();
        assert!(
            !name.starts_with('.') && !name.contains("tmp"),
            "left over: {name}"
        );
    }
}

#[test]
fn paper_and_brute_methods_run_from_the_command_line() {
    let dir = tempdir();
    let cap = dir.path().join("cap");
    capture(&cap);
    for (method, extra) in [
        ("paper", vec![]),
        (
            "brute",
            vec!["--brute-index-steps", "41", "--brute-thickness-step", "4"],
        ),
    ] {
        let out = dir.path().join(method);
        let run = filmscope()
            .args(["estimate", s(&cap), "--out", s(&out), "--method", method])
            .args(extra)
            .output()
            .expect("run");
        assert!(
            run.status.success(),
            "{method}: {}",
            String::from_utf8_lossy(&run.stderr)
        );
        let summary: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("summary.json")).expect("summary"),
        )
        .expect("json");
        assert_eq!(summary["method"], method);
    }
}

fn fails_with_one_line(args: &[&str], must_name: &str) {
    let run = filmscope().args(args).output().expect("run");
    assert!(!run.status.success(), "{args:?} succeeded");
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
    assert!(
        err.contains(must_name),
        "{args:?}: {err} does not name {must_name}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn unreadable_captures_fail_with_one_line_naming_the_file() {
    let dir = tempdir();
    let cap = dir.path().join("cap");
    capture(&cap);
    let out = dir.path().join("out");
    // Missing capture.
    fails_with_one_line(
        &["estimate", "/nonexistent/capture", "--out", s(&out)],
        "/nonexistent/capture",
    );
    // Truncated cube data.
    let img = cap.join("a25.img");
    let bytes = std::fs::read(&img).expect("cube");
    std::fs::write(&img, &bytes[..bytes.len() / 2]).expect("truncate");
    fails_with_one_line(&["estimate", s(&cap), "--out", s(&out)], "a25.img");
    std::fs::write(&img, &bytes).expect("restore");
    // No angle.
    let toml = cap.join("capture.toml");
    let text = std::fs::read_to_string(&toml).expect("toml");
    let first_angle = text.find("[[angle]]").expect("an angle");
    std::fs::write(&toml, &text[..first_angle]).expect("no angle");
    fails_with_one_line(&["estimate", s(&cap), "--out", s(&out)], "capture.toml");
    // Garbage, and an empty file.
    std::fs::write(&toml, "[[[ not toml").expect("garbage");
    fails_with_one_line(&["estimate", s(&cap), "--out", s(&out)], "capture.toml");
    std::fs::write(&toml, "").expect("empty");
    fails_with_one_line(&["estimate", s(&cap), "--out", s(&out)], "capture.toml");
    assert!(
        !out.join("summary.json").exists(),
        "no summary for a failed run"
    );
    // Unknown method.
    std::fs::write(&toml, &text).expect("restore toml");
    fails_with_one_line(
        &["estimate", s(&cap), "--out", s(&out), "--method", "magic"],
        "magic",
    );
}

/// A reader that stops listening (`filmscope eval ... | head -1`) ends the program quietly
/// with exit status 141 (128 + SIGPIPE), not with a panic.
#[test]
fn a_closed_stdout_ends_quietly_not_with_a_panic() {
    let dir = tempdir();
    let scene = dir.path().join("scene.toml");
    std::fs::copy(
        concat!(env!("CARGO_MANIFEST_DIR"), "/config/scenes/rig-tiny.toml"),
        &scene,
    )
    .expect("scene");
    let mut child = filmscope()
        .args(["eval", s(&scene)])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    // Nobody reads: the first line written meets a broken pipe.
    drop(child.stdout.take());
    let out = child.wait_with_output().expect("wait");
    let stderr = String::from_utf8_lossy(&out.stderr);
    // 128 + SIGPIPE, as a shell tool ends.
    assert_eq!(out.status.code(), Some(141), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// Over-exposes every white reference of the capture in `dir`: its brightest tenth (the red
/// end of the band, the image centre) reads the 12-bit full scale, as a saturated white
/// does. Returns the white cubes' headers.
fn clip_whites(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut headers = Vec::new();
    for entry in std::fs::read_dir(dir).expect("capture folder") {
        let img = entry.expect("entry").path();
        let name = img.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if !(name.starts_with("white") && name.ends_with(".img")) {
            continue;
        }
        let hdr = img.with_extension("hdr");
        let text = std::fs::read_to_string(&hdr).expect("white header");
        assert!(text.contains("data type = 4"), "{text}");
        let big = text.contains("byte order = 1");
        let mut bytes = std::fs::read(&img).expect("white data");
        let of = |b: &[u8]| {
            let a = [b[0], b[1], b[2], b[3]];
            if big {
                f32::from_be_bytes(a)
            } else {
                f32::from_le_bytes(a)
            }
        };
        let mut values: Vec<f32> = bytes.chunks_exact(4).map(of).collect();
        values.sort_by(f32::total_cmp);
        let level = values[values.len() * 9 / 10];
        let full: f32 = 4095.0;
        for b in bytes.chunks_exact_mut(4) {
            if of(b) >= level {
                b.copy_from_slice(&if big {
                    full.to_be_bytes()
                } else {
                    full.to_le_bytes()
                });
            }
        }
        std::fs::write(&img, bytes).expect("write white");
        headers.push(hdr);
    }
    headers
}

/// A white reference clipped at the ADC's full scale (over-exposed) is no reference: its
/// samples are not used, so a thin film's index (measured through the reflectance level)
/// stays the film's, and `estimate` names each clipped white and its bands in a note, on
/// stderr and in summary.json. (Read against the clipped level, those samples were up to a
/// tenth too bright.)
#[test]
fn a_clipped_white_is_named_and_its_samples_are_not_used() {
    let dir = tempdir();
    let cap = dir.path().join("cap");
    let thin = common::TINY_SCENE.replace("base_nm = 620.0", "base_nm = 120.0");
    let scene = firmware_sim::Scene::from_toml(&thin, "thin").expect("scene");
    write_capture(&scene, &cap, SimulateOptions::default(), &|_| {}).expect("capture");
    let whites = clip_whites(&cap);
    assert_eq!(whites.len(), 4);
    let out = dir.path().join("est");
    let run = filmscope()
        .args(["estimate", s(&cap), "--out", s(&out)])
        .output()
        .expect("run");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary"))
            .expect("json");
    let n = summary["refractive_index"].as_f64().expect("index");
    assert!((n - 2.1).abs() < 0.003, "n = {n}");
    let notes: Vec<&str> = summary["notes"]
        .as_array()
        .expect("notes")
        .iter()
        .filter_map(|v| v.as_str())
        .filter(|n| n.contains("white reference is at full scale"))
        .collect();
    assert_eq!(notes.len(), whites.len(), "{notes:?}");
    for hdr in &whites {
        let named = |text: &str| text.contains(&format!("{}: the white reference", s(hdr)));
        assert!(notes.iter().any(|n| named(n)), "{notes:?}");
        assert!(stderr.lines().any(named), "{stderr}");
    }
    assert!(notes.iter().all(|n| n.contains("720.0 nm")), "{notes:?}");
}

#[test]
fn estimate_into_a_results_folder_keeps_the_users_files() {
    let dir = tempdir();
    let cap = dir.path().join("cap");
    capture(&cap);
    let out = dir.path().join("est");
    let estimate = || {
        let run = filmscope()
            .args(["estimate", s(&cap), "--out", s(&out)])
            .output()
            .expect("run");
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        String::from_utf8_lossy(&run.stderr).into_owned()
    };
    estimate();
    for args in [
        vec!["report", s(&out)],
        vec!["report", s(&out), "--pixel", "3,4"],
    ] {
        let run = filmscope().args(&args).output().expect("run");
        assert!(run.status.success(), "{args:?}: {run:?}");
    }
    assert!(out.join("report.html").exists() && out.join("pixel-3-4.png").exists());
    std::fs::write(out.join("notes.txt"), "lot 7, wiped twice").expect("notes");
    std::fs::create_dir(out.join("photos")).expect("folder");
    std::fs::write(out.join("photos").join("edge.jpg"), "jpeg").expect("photo");
    let err = estimate();
    // The user's files stay, untouched.
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).expect("notes kept"),
        "lot 7, wiped twice"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("photos").join("edge.jpg")).expect("photo kept"),
        "jpeg"
    );
    // The report of the previous maps is removed, and named in one note.
    let notes: Vec<_> = err.lines().filter(|l| l.contains("removed")).collect();
    assert_eq!(notes.len(), 1, "{err}");
    for name in ["report.html", "pixel-3-4.png", "pixel-3-4.csv", "notes.txt"] {
        assert!(notes[0].contains(name), "{err}");
    }
    assert!(!out.join("report.html").exists());
    assert!(out.join("summary.json").exists() && out.join("thickness_nm.hdr").exists());
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        left.iter().all(|n| n == "cap" || n == "est"),
        "left over: {left:?}"
    );
}

/// Shell completions and manual pages come from the command line's own definition: every
/// public command is in them (the hidden ones have no page); and the lab commands that need a
/// scene (`soak`) run from any folder on the scene built in.
#[test]
fn completions_man_pages_and_built_in_scenes_work_from_any_folder() {
    let dir = tempdir();
    let run = filmscope()
        .args(["completions", "bash"])
        .current_dir(dir.path())
        .output()
        .expect("run");
    assert!(run.status.success());
    let bash = String::from_utf8_lossy(&run.stdout);
    for cmd in ["estimate", "inspect", "export-gltf", "completions"] {
        assert!(bash.contains(cmd), "{cmd} not in the bash completions");
    }
    let man = dir.path().join("man");
    let run = filmscope()
        .args(["man", "--out", s(&man)])
        .output()
        .expect("run");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let page = std::fs::read_to_string(man.join("filmscope-estimate.1")).expect("page");
    assert!(
        page.starts_with(".ie") || page.contains(".TH filmscope-estimate"),
        "{page}"
    );
    assert!(
        page.contains("film\\-index"),
        "--film-index not in the page"
    );
    assert!(man.join("filmscope.1").exists() && !man.join("filmscope-soak.1").exists());
    let run = filmscope()
        .args(["soak", "--sweeps", "1"])
        .current_dir(dir.path())
        .output()
        .expect("run");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
}

/// `summary.json` of `dir` without what differs from one run to the next (its timings,
/// at any depth) and the name of its source.
fn summary_of_run(dir: &Path) -> serde_json::Value {
    fn strip(v: &mut serde_json::Value) {
        match v {
            serde_json::Value::Object(o) => {
                o.retain(|k, _| !matches!(k.as_str(), "timing" | "seconds" | "fit_seconds"));
                o.values_mut().for_each(strip);
            }
            serde_json::Value::Array(a) => a.iter_mut().for_each(strip),
            _ => {}
        }
    }
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json");
    let mut v: serde_json::Value = serde_json::from_str(&text).expect("summary JSON");
    v.as_object_mut().expect("an object").remove("source");
    strip(&mut v);
    v
}

/// One estimate path: `filmscope estimate`, the job the Python package runs
/// (`jobs::estimate::estimate_capture`) and `eval` (on the capture, and on the software
/// camera's stream of its scene) give byte-identical maps and equal summaries on each of
/// the paper's scenes.
#[test]
fn every_application_estimates_through_one_path() {
    use filmscope::jobs::{self, EstimateRequest, Quiet, Settings};
    for name in ["paper-sample1", "paper-sample2", "paper-sample3"] {
        let dir = tempdir();
        let cap = dir.path().join("cap");
        let scene = common::scene(name);
        write_capture(&scene, &cap, SimulateOptions::default(), &|_| {}).expect("capture");
        let cli = dir.path().join("cli");
        common::run_ok(&["estimate", s(&cap), "--out", s(&cli)]);
        let job = dir.path().join("job");
        jobs::estimate::estimate_capture(
            &EstimateRequest {
                capture: cap.clone(),
                out: job.clone(),
                out_option: "out",
                film_option: "film_index",
                settings: Settings::default(),
                memory_budget: None,
            },
            &Quiet,
        )
        .expect("the job");
        let config = filmscope::estimate::RunConfig::default();
        let scene_file = format!("{}/config/scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
        // Written under the CLI's name for the source: the index files name it.
        let summary: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(cli.join("summary.json")).expect("summary.json"),
        )
        .expect("summary JSON");
        let label = summary["source"].as_str().expect("the source's name");
        let mut evals = Vec::new();
        for (what, input) in [
            ("eval-capture", cap.clone()),
            ("eval-stream", scene_file.into()),
        ] {
            let (_, run) =
                filmscope::lab::eval::eval_one(&input, &config, None, &Quiet).expect("eval");
            let out = dir.path().join(what);
            jobs::estimate::write(&out, &run, label).expect("eval's maps");
            evals.push(out);
        }
        let mut files: Vec<_> = std::fs::read_dir(&cli)
            .expect("the CLI's folder")
            .map(|e| e.expect("entry").file_name())
            .filter(|f| f != "summary.json")
            .collect();
        files.sort();
        assert!(files.len() >= 9, "{files:?}");
        for other in [&job].into_iter().chain(&evals) {
            for file in &files {
                let (a, b) = (cli.join(file), other.join(file));
                assert!(
                    std::fs::read(&a).expect("map") == std::fs::read(&b).expect("map"),
                    "{name}: {} differs from {}",
                    b.display(),
                    a.display()
                );
            }
            assert!(
                summary_of_run(&cli) == summary_of_run(other),
                "{name}: {}'s summary differs from the CLI's",
                other.display()
            );
        }
    }
}

/// `--quiet` leaves standard error empty on success (no notes, no bars); `-v` adds the
/// steps of the job; the default prints neither the steps nor anything else here.
#[test]
fn quiet_and_verbose_set_what_standard_error_carries() {
    let dir = tempdir();
    let (cap, _) = common::estimated_tiny(dir.path(), false);
    let run = |flag: Option<&str>, out: &str| {
        let mut c = filmscope();
        c.arg("estimate").arg(s(&cap)).args(["--out", out]);
        c.args(flag);
        let o = c.output().expect("runs");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let out = |n: &str| dir.path().join(n).display().to_string();
    let quiet = run(Some("--quiet"), &out("q"));
    assert!(quiet.is_empty(), "{quiet}");
    let plain = run(None, &out("p"));
    assert!(!plain.contains("px,"), "{plain}");
    let verbose = run(Some("-v"), &out("v"));
    assert!(
        verbose.contains("32 x 24 px, 101 bands, 4 angles; method filmscope")
            && verbose.contains("maps and summary in"),
        "{verbose}"
    );
}
