//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use firmware_sim::Scene;

/// A scene file of this repository.
pub fn scene(name: &str) -> Scene {
    let p = format!("{}/config/scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    Scene::load(Path::new(&p)).expect("scene loads")
}

/// A small scene (32 x 24 px, 101 bands) for fast tests: ZnS-like film above the substrate.
pub fn tiny_scene() -> Scene {
    let text = r#"
name = "tiny"
seed = 7
[film]
index = 2.1
[film.thickness]
base_nm = 620.0
gradient_nm = [30.0, -20.0]
random_bumps = { count = 2, height_nm = 8.0, sigma = 0.3 }
[substrate]
index = 1.52
[rig]
angles_deg = [10.0, 25.0, 40.0, 55.0]
bands_nm = [420.0, 720.0, 3.0]
fwhm_nm = 5.0
[sensor]
width = 32
height = 24
dead_pixels = 2
hot_pixels = 1
"#;
    Scene::from_toml(text, "tiny").expect("tiny scene")
}

/// A fresh temporary directory.
pub fn tempdir() -> tempfile::TempDir {
    tempfile::tempdir().expect("temp dir")
}

/// The filmscope binary.
pub fn filmscope() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_filmscope"))
}

/// Path as &str.
pub fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// `dir/name`.
pub fn join(dir: &Path, name: &str) -> PathBuf {
    dir.join(name)
}

/// Simulates [`tiny_scene`] into `dir/cap` (`noise_free` as `simulate --noise-free`) and
/// estimates it into `dir/est` with the binary; returns both paths.
pub fn estimated_tiny(dir: &Path, noise_free: bool) -> (PathBuf, PathBuf) {
    let (cap, est) = (dir.join("cap"), dir.join("est"));
    filmscope::simulate::write_capture(
        &tiny_scene(),
        &cap,
        filmscope::simulate::SimulateOptions {
            noise_free,
            ..Default::default()
        },
        &|_| {},
    )
    .expect("capture");
    run_ok(&["estimate", s(&cap), "--out", s(&est)]);
    (cap, est)
}

/// Data rows of a CSV in `tests/fixtures/colour/`: '#' comment lines, blank lines and the
/// header line skipped, cells trimmed.
pub fn colour_fixture_rows(name: &str) -> Vec<Vec<String>> {
    let path: PathBuf = [
        env!("CARGO_MANIFEST_DIR"),
        "tests",
        "fixtures",
        "colour",
        name,
    ]
    .iter()
    .collect();
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    text.lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').map(|s| s.trim().to_string()).collect())
        .collect()
}

/// Runs the binary with `args` and asserts it succeeded (printing its stderr if not).
pub fn run_ok(args: &[&str]) -> std::process::Output {
    let run = filmscope().args(args).output().expect("run filmscope");
    assert!(
        run.status.success(),
        "filmscope {args:?}: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    run
}
