//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use firmware_sim::Scene;

/// A scene file of this repository.
pub fn scene(name: &str) -> Scene {
    let p = format!("{}/config/scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    Scene::load(Path::new(&p)).expect("scene loads")
}

/// The text of [`tiny_scene`].
pub const TINY_SCENE: &str = r#"
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

/// A small scene (32 x 24 px, 101 bands) for fast tests: ZnS-like film above the substrate.
pub fn tiny_scene() -> Scene {
    Scene::from_toml(TINY_SCENE, "tiny").expect("tiny scene")
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

/// A whole sweep held in memory ([`filmscope::source::SweepCube`]) replayed through the
/// pipeline: every band of an angle as blocks of `rows_per_block` rows (the whole frame
/// when it equals the height), its angles in the order `order` gives.
pub struct WholeSource {
    pub cube: std::sync::Arc<filmscope::source::SweepCube>,
    pub spec: filmscope::solve::SweepSpec,
    pub order: Vec<usize>,
    pub rows_per_block: usize,
}

impl WholeSource {
    /// Collects `source` whole, to replay in file order in blocks of `rows_per_block` rows.
    pub fn collect(source: &mut dyn filmscope::source::Source, rows_per_block: usize) -> Self {
        let spec = source.spec().clone();
        let cube = filmscope::pipeline::collect_sweep(source).expect("sweep collects");
        let order = (0..cube.angles_deg.len()).collect();
        Self {
            cube: std::sync::Arc::new(cube),
            spec,
            order,
            rows_per_block,
        }
    }

    /// The same sweep, angles in `order`, blocks of `rows_per_block` rows.
    pub fn with(&self, order: &[usize], rows_per_block: usize) -> Self {
        Self {
            cube: self.cube.clone(),
            spec: self.spec.clone(),
            order: order.to_vec(),
            rows_per_block,
        }
    }
}

impl filmscope::source::Source for WholeSource {
    fn spec(&self) -> &filmscope::solve::SweepSpec {
        &self.spec
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.order
            .iter()
            .map(|&a| self.cube.angles_deg[a])
            .collect()
    }

    fn stream(&mut self, tx: &crossbeam_channel::Sender<filmscope::source::StreamMsg>) {
        let (w, h) = (self.cube.width, self.cube.height);
        let cube = self.cube.clone();
        let order = self.order.clone();
        filmscope::source::stream_band_sequential(
            tx,
            &self.angles_deg(),
            self.cube.bands_nm.len(),
            h,
            self.rows_per_block,
            |a, b, r0, rows| {
                let plane = &cube.data[order[a]][b * w * h..(b + 1) * w * h];
                filmscope::source::Samples::Reflectance(plane[r0 * w..(r0 + rows) * w].to_vec())
            },
        );
    }
}

/// `scene` from the software camera (one worker) through `config`, scored against its truth.
pub fn run_scene(
    name: &str,
    scene: Scene,
    config: &filmscope::estimate::RunConfig,
) -> (filmscope::lab::eval::EvalReport, filmscope::estimate::Run) {
    let truth = filmscope::lab::eval::Truth::of_scene(&scene);
    let camera = firmware_sim::SoftwareCamera::new(scene);
    let mut source = filmscope::source::SimSource::new(camera, false, 1).expect("source");
    let run = filmscope::estimate::run_method(&mut source, config, &|_| {}).expect("run");
    (filmscope::lab::eval::evaluate(name, &truth, &run), run)
}
