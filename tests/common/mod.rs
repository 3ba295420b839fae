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

/// A whole sweep held in memory ([`filmscope::sweep::SweepCube`]) replayed through the
/// pipeline: every band of an angle as blocks of `rows_per_block` rows (the whole frame
/// when it equals the height), its angles in the order `order` gives.
pub struct WholeSource {
    pub cube: std::sync::Arc<filmscope::sweep::SweepCube>,
    pub spec: filmscope::solve::SweepSpec,
    pub order: Vec<usize>,
    pub rows_per_block: usize,
}

impl WholeSource {
    /// Collects `source` whole, to replay in file order in blocks of `rows_per_block` rows.
    pub fn collect(source: &mut dyn filmscope::pipeline::Source, rows_per_block: usize) -> Self {
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

impl filmscope::pipeline::Source for WholeSource {
    fn spec(&self) -> &filmscope::solve::SweepSpec {
        &self.spec
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.order
            .iter()
            .map(|&a| self.cube.angles_deg[a])
            .collect()
    }

    fn stream(&mut self, tx: &crossbeam_channel::Sender<filmscope::pipeline::StreamMsg>) {
        let (w, h) = (self.cube.width, self.cube.height);
        let cube = self.cube.clone();
        let order = self.order.clone();
        filmscope::pipeline::stream_band_sequential(
            tx,
            &self.angles_deg(),
            self.cube.bands_nm.len(),
            h,
            self.rows_per_block,
            |a, b, r0, rows| {
                let plane = &cube.data[order[a]][b * w * h..(b + 1) * w * h];
                filmscope::pipeline::Samples::Reflectance(plane[r0 * w..(r0 + rows) * w].to_vec())
            },
        );
    }
}
