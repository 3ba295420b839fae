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
    let run = filmscope()
        .args(["estimate", s(&cap), "--out", s(&est)])
        .output()
        .expect("run estimate");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    (cap, est)
}
