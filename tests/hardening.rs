//! Hardening (issue 27): results are one unit, bad values and inputs are refused up front
//! with one line naming the file, key and value, and every case ends in bounded time. The
//! device cases (deadlines, escaping, rig.toml, Ctrl-C) are in `tests/rig.rs`.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::{Duration, Instant};

use filmscope::simulate::{write_capture, SimulateOptions};

/// A fresh simulated capture (tiny scene) in `dir/name`.
fn capture(dir: &Path, name: &str) -> PathBuf {
    let cap = dir.join(name);
    write_capture(
        &common::tiny_scene(),
        &cap,
        SimulateOptions::default(),
        &|_| {},
    )
    .expect("capture");
    cap
}

/// A copy of the capture folder `from` as `dir/name` (cheaper than simulating again).
fn copy_capture(from: &Path, dir: &Path, name: &str) -> PathBuf {
    let to = dir.join(name);
    std::fs::create_dir(&to).expect("dir");
    for e in std::fs::read_dir(from).expect("dir").filter_map(Result::ok) {
        if e.path().is_file() {
            std::fs::copy(e.path(), to.join(e.file_name())).expect("copy");
        }
    }
    to
}

/// Runs filmscope with `args`, which must end within `seconds`.
fn run(args: &[&str], seconds: f64) -> Output {
    let t0 = Instant::now();
    let out = common::filmscope().args(args).output().expect("run");
    let took = t0.elapsed().as_secs_f64();
    assert!(took < seconds, "{args:?} took {took:.1} s");
    out
}

/// `args` must fail with exactly one line on stderr containing each of `must`.
fn refused(args: &[&str], must: &[&str]) -> String {
    let out = run(args, 10.0);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
    assert!(!err.contains("panicked"), "{err}");
    for m in must {
        assert!(err.contains(m), "{args:?}: {err:?} lacks {m:?}");
    }
    err
}

/// Rewrites `path` through `edit`.
fn edit(path: &Path, edit: impl Fn(String) -> String) {
    let text = std::fs::read_to_string(path).expect("read");
    std::fs::write(path, edit(text)).expect("write");
}

/// Every `.hdr` of a capture rewritten through `f`.
fn edit_headers(cap: &Path, f: impl Fn(String) -> String) {
    for e in std::fs::read_dir(cap).expect("dir").filter_map(Result::ok) {
        if e.path().extension().is_some_and(|x| x == "hdr") {
            edit(&e.path(), &f);
        }
    }
}

/// Names in `dir` starting with `prefix` other than `prefix` itself.
fn siblings(dir: &Path, prefix: &str) -> Vec<String> {
    std::fs::read_dir(dir)
        .expect("dir")
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(prefix) && n != prefix)
        .collect()
}

#[test]
fn hardening_result_is_one_unit_and_a_second_writer_is_refused() {
    let dir = common::tempdir();
    let cap = capture(dir.path(), "cap");
    let out = dir.path().join("est");
    let (c, o) = (common::s(&cap), common::s(&out));
    assert!(run(&["estimate", c, "--out", o], 60.0).status.success());
    let summary = std::fs::read(out.join("summary.json")).expect("summary");
    // A writer holding the lock (this test process, alive) refuses a second one.
    let lock = dir.path().join("est.lock");
    std::fs::write(&lock, format!("{}\n", std::process::id())).expect("lock");
    refused(
        &["estimate", c, "--out", o],
        &["est.lock", &format!("pid {}", std::process::id())],
    );
    assert_eq!(
        std::fs::read(out.join("summary.json")).expect("kept"),
        summary
    );
    // A lock and a staging folder of a process no longer running are cleaned up.
    std::fs::write(&lock, "4999999\n").expect("stale lock");
    std::fs::create_dir(dir.path().join("est.tmp-4999999-0")).expect("stale staging");
    assert!(run(&["estimate", c, "--out", o], 60.0).status.success());
    assert!(
        siblings(dir.path(), "est").is_empty(),
        "{:?}",
        siblings(dir.path(), "est")
    );
    // Two writers at once: one wins, the other is refused with one line, and the folder
    // holds one complete result.
    let spawn = || {
        common::filmscope()
            .args(["estimate", c, "--out", o])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("spawn")
    };
    let (a, b) = (spawn(), spawn());
    let results = [
        a.wait_with_output().expect("a"),
        b.wait_with_output().expect("b"),
    ];
    assert!(results.iter().any(|r| r.status.success()));
    for r in &results {
        if !r.status.success() {
            let err = String::from_utf8_lossy(&r.stderr);
            assert!(
                err.contains("is writing this output") && err.trim_end().lines().count() == 1,
                "{err}"
            );
        }
    }
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).expect("summary"))
            .expect("json");
    assert!(s["refractive_index"].is_number());
    for name in ["thickness_nm.hdr", "confidence.hdr", "flags.hdr"] {
        filmscope::io::read_cube(out.join(name)).expect(name);
    }
    assert!(
        siblings(dir.path(), "est").is_empty(),
        "{:?}",
        siblings(dir.path(), "est")
    );
}

#[test]
fn hardening_unbounded_search_ranges_are_refused() {
    let dir = common::tempdir();
    let cap = capture(dir.path(), "cap");
    let toml = cap.join("capture.toml");
    let original = std::fs::read_to_string(&toml).expect("toml");
    for (search, want) in [
        (
            "index_range = [1.2, 1e300]",
            "search.index_range = [1.2, 1e300]",
        ),
        (
            "thickness_range_nm = [50.0, 1e12]",
            "search.thickness_range_nm = [50.0, 1000000000000.0]",
        ),
        (
            "index_range = [0.5, 2.0]",
            "search.index_range = [0.5, 2.0]",
        ),
    ] {
        std::fs::write(&toml, format!("{original}\n[search]\n{search}\n")).expect("write");
        let out = dir.path().join("est");
        refused(
            &["estimate", common::s(&cap), "--out", common::s(&out)],
            &["capture.toml", want],
        );
        assert!(!out.exists(), "nothing written");
    }
}

#[test]
fn hardening_huge_header_is_refused_before_allocating() {
    let dir = common::tempdir();
    let cap = dir.path().join("huge");
    std::fs::create_dir(&cap).expect("dir");
    let bands: Vec<String> = (0..16).map(|i| format!("{}", 450 + 10 * i)).collect();
    let (w, h) = (100_000u64, 100_000u64);
    for name in ["a", "b"] {
        std::fs::write(
            cap.join(format!("{name}.hdr")),
            format!(
                "ENVI\nsamples = {w}\nlines = {h}\nbands = 16\nheader offset = 0\ndata type = 4\ninterleave = bsq\nbyte order = 0\nwavelength units = Nanometers\nwavelength = {{ {} }}\n",
                bands.join(", ")
            ),
        )
        .expect("hdr");
        // A sparse file of the declared size: the size check passes, nothing is stored.
        let f = std::fs::File::create(cap.join(format!("{name}.img"))).expect("img");
        f.set_len(w * h * 16 * 4).expect("sparse file");
    }
    std::fs::write(
        cap.join("capture.toml"),
        "[sample]\nsubstrate_index = 1.52\n\n[[angle]]\nincidence_deg = 10.0\ncube = \"a.hdr\"\n\n[[angle]]\nincidence_deg = 30.0\ncube = \"b.hdr\"\n",
    )
    .expect("toml");
    let out = dir.path().join("est");
    let (c, o) = (common::s(&cap), common::s(&out));
    refused(
        &["estimate", c, "--out", o],
        &["100000 x 100000 px", "needs about", "memory available"],
    );
    refused(
        &["estimate", c, "--out", o, "--max-memory", "64G"],
        &["100000 x 100000 px", "the --max-memory budget of 64.0 GiB"],
    );
    refused(
        &["estimate", c, "--out", o, "--max-memory", "lots"],
        &["--max-memory = lots"],
    );
    assert!(!out.exists());
}

#[test]
fn hardening_silent_values_are_refused() {
    let dir = common::tempdir();
    let out = dir.path().join("est");
    let o = common::s(&out);
    let good = capture(dir.path(), "cap");
    // capture.toml values.
    for (from, to, want) in [
        (
            "ambient_index = 1.0",
            "ambient_index = 1e9",
            "sample.ambient_index = 1000000000.0",
        ),
        (
            "ambient_index = 1.0",
            "ambient_index = 1.6",
            "sample.ambient_index = 1.6 is above sample.substrate_index = 1.52",
        ),
        (
            "substrate_index = 1.52",
            "substrate_index = -1.52",
            "sample.substrate_index = -1.52",
        ),
    ] {
        let cap = copy_capture(&good, dir.path(), "cap-toml");
        edit(&cap.join("capture.toml"), |t| t.replacen(from, to, 1));
        refused(
            &["estimate", common::s(&cap), "--out", o],
            &["capture.toml", want],
        );
        std::fs::remove_dir_all(&cap).expect("clean");
    }
    // Header values: every header of the capture carries the same bands.
    for (from, to, want) in [
        (
            "wavelength = { 420,",
            "wavelength = { 0,",
            "wavelength[0] = 0.0",
        ),
        (
            "wavelength = { 420,",
            "wavelength = { -420,",
            "wavelength[0] = -420.0",
        ),
        (
            "wavelength = { 420, 423,",
            "wavelength = { 423, 420,",
            "wavelength[1] = 420.0: expected wavelengths in increasing order",
        ),
        ("fwhm = { 5,", "fwhm = { 0,", "fwhm[0] = 0.0"),
        ("fwhm = { 5,", "fwhm = { -5,", "fwhm[0] = -5.0"),
    ] {
        let cap = copy_capture(&good, dir.path(), "cap-hdr");
        edit_headers(&cap, |t| t.replacen(from, to, 1));
        refused(
            &["estimate", common::s(&cap), "--out", o],
            &["a10.hdr", want],
        );
        std::fs::remove_dir_all(&cap).expect("clean");
    }
    // Command-line values.
    let c = common::s(&good);
    for (args, want) in [
        (vec!["--index-pixels", "0"], "--index-pixels = 0"),
        (
            vec!["--method", "brute", "--brute-thickness-step", "1e-9"],
            "--brute-thickness-step = 1e-9",
        ),
        (vec!["--workers", "0"], "--workers = 0"),
        (
            vec!["--brute-index-steps", "100000000"],
            "--brute-index-steps = 100000000",
        ),
    ] {
        let mut a = vec!["estimate", c, "--out", o];
        a.extend(args);
        refused(&a, &[want]);
    }
    // 10,000 angles: refused from capture.toml alone, before any cube is opened.
    let many = dir.path().join("many");
    std::fs::create_dir(&many).expect("dir");
    let mut text = String::from("[sample]\nsubstrate_index = 1.52\n");
    for i in 0..10_000 {
        text.push_str(&format!(
            "\n[[angle]]\nincidence_deg = {}\ncube = \"a{i}.hdr\"\n",
            f64::from(i) * 0.008
        ));
    }
    std::fs::write(many.join("capture.toml"), text).expect("toml");
    refused(
        &["estimate", common::s(&many), "--out", o],
        &["capture.toml", "[[angle]] = 10000 angles"],
    );
    assert!(!out.exists());
}

/// The bytes of every file under `dir`, by relative path.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).expect("dir").filter_map(Result::ok) {
        let p = e.path();
        if p.is_dir() {
            v.extend(snapshot(&p));
        } else {
            v.push((p.clone(), std::fs::read(&p).expect("read")));
        }
    }
    v.sort();
    v
}

#[test]
fn hardening_out_never_overwrites_inputs() {
    let dir = common::tempdir();
    let cap = capture(dir.path(), "cap");
    let before = snapshot(&cap);
    let c = common::s(&cap);
    let truth = cap.join("truth");
    for out in [
        cap.clone(),
        truth,
        cap.join("new"),
        dir.path().to_path_buf(),
    ] {
        refused(
            &["estimate", c, "--out", common::s(&out)],
            &["--out", "choose another folder"],
        );
    }
    // Through the capture.toml path too.
    let toml = cap.join("capture.toml");
    refused(
        &["estimate", common::s(&toml), "--out", c],
        &["is the input folder"],
    );
    assert!(snapshot(&cap) == before, "the capture changed");
}

#[test]
fn hardening_fifo_and_device_inputs_are_refused_and_out_is_checked_first() {
    let dir = common::tempdir();
    let fifo_dir = dir.path().join("fifo-cap");
    std::fs::create_dir(&fifo_dir).expect("dir");
    let fifo = fifo_dir.join("capture.toml");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .is_ok_and(|s| s.success());
    let out = dir.path().join("out");
    let o = common::s(&out);
    if made {
        refused(
            &["estimate", common::s(&fifo_dir), "--out", o],
            &["capture.toml", "not a regular file"],
        );
        refused(
            &["acquire", "--rig", common::s(&fifo), "--out", o],
            &["capture.toml", "not a regular file"],
        );
    }
    refused(
        &["acquire", "--rig", "/dev/zero", "--out", o],
        &["/dev/zero", "not a regular file"],
    );
    // An --out that cannot be created is refused before the computation: the run ends
    // long before an estimate would.
    let cap = capture(dir.path(), "cap");
    let file = dir.path().join("plain-file");
    std::fs::write(&file, "x").expect("file");
    let bad_out = file.join("out");
    let t0 = Instant::now();
    refused(
        &["estimate", common::s(&cap), "--out", common::s(&bad_out)],
        &["plain-file", "cannot create"],
    );
    assert!(t0.elapsed() < Duration::from_secs(5));
    refused(
        &["estimate", common::s(&cap), "--out", common::s(&file)],
        &["plain-file", "not a folder"],
    );
}
