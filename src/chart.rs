//! Speed against accuracy, and where each method works: the measurements behind
//! `filmscope chart` and `filmscope stability`.
//!
//! Every point is a real run: a scene rendered once by the software camera (raw counts with
//! noise, calibrated), replayed from memory to every method and setting, timed from the first
//! row to the maps, and scored against the scene's truth.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{anyhow, Result};
use filmscope_core::solve::sweep::SolverOptions;
use firmware_sim::Scene;
use serde::Serialize;

use crate::baseline::BruteGrid;
use crate::bench::{Frames, ReplaySource};
use crate::estimate::{run_method, RunConfig};
use crate::eval::{evaluate, Truth};
use crate::export::plot::{
    write_heatmap_panels_png, write_scatter_panels_png, HeatMap, Scatter, Series,
};
use crate::sweep::Method;

/// One method with one setting of its knobs.
#[derive(Clone, Debug)]
pub struct Setting {
    /// Short label for the chart.
    pub label: String,
    /// What to run.
    pub config: RunConfig,
}

impl Setting {
    /// A setting labelled `label`.
    pub fn new(label: &str, config: RunConfig) -> Self {
        Self {
            label: label.to_owned(),
            config,
        }
    }
}

/// The settings charted: filmscope with and without its refinements, the paper's method, and
/// brute force over coarser and finer grids.
pub fn settings(quick: bool) -> Vec<Setting> {
    let fs = |options: SolverOptions| RunConfig {
        method: Method::Filmscope,
        pipeline: crate::pipeline::PipelineConfig {
            solver: options,
            ..Default::default()
        },
        ..RunConfig::default()
    };
    let full = SolverOptions::default();
    let mut out = vec![
        Setting::new("filmscope", fs(full)),
        Setting::new(
            "-refine",
            fs(SolverOptions {
                refine: false,
                ..full
            }),
        ),
        Setting::new(
            "-subband",
            fs(SolverOptions {
                subband: false,
                ..full
            }),
        ),
        Setting::new(
            "paper",
            RunConfig {
                method: Method::Paper,
                ..RunConfig::default()
            },
        ),
    ];
    let grids: &[(usize, f64)] = if quick {
        &[(19, 8.0), (37, 2.0)]
    } else {
        &[(19, 8.0), (37, 4.0), (91, 2.0), (181, 1.0)]
    };
    for &(index_steps, thickness_step_nm) in grids {
        out.push(Setting::new(
            &format!("{index_steps}n/{thickness_step_nm}nm"),
            RunConfig {
                method: Method::Brute,
                brute_grid: BruteGrid {
                    index_steps,
                    thickness_step_nm,
                },
                ..RunConfig::default()
            },
        ));
    }
    out
}

/// One run's cost and accuracy.
#[derive(Clone, Debug, Serialize)]
pub struct Point {
    /// The method.
    pub method: String,
    /// The setting.
    pub label: String,
    /// Wall seconds per megapixel, from the first row to the maps.
    pub seconds_per_mpix: f64,
    /// Absolute index error at 550 nm (NaN without an index).
    pub index_error_abs: f64,
    /// Thickness mean absolute error over valid pixels, nm (NaN without any).
    pub thickness_mae_nm: f64,
    /// Valid fraction.
    pub valid_fraction: f64,
    /// Valid pixels more than 20 nm off, as a fraction of all pixels.
    pub silent_failure_rate: f64,
}

/// Runs every setting on `scene` (rendered once).
pub fn measure(scene: &Scene, settings: &[Setting]) -> Result<Vec<Point>> {
    let frames = Arc::new(Frames::render(scene, scene.sensor.height)?);
    let truth = Truth::of_scene(scene);
    let mpix = (scene.sensor.width * scene.sensor.height) as f64 / 1e6;
    let mut out = Vec::new();
    for s in settings {
        let mut source = ReplaySource::new(frames.clone(), scene.sensor.height, 8);
        let t0 = Instant::now();
        let run = run_method(&mut source, &s.config, &|_| {}).map_err(|e| anyhow!("{e}"))?;
        let secs = t0.elapsed().as_secs_f64();
        let r = evaluate(&scene.name, &truth, &run);
        out.push(Point {
            method: s.config.method.name().to_owned(),
            label: s.label.clone(),
            seconds_per_mpix: secs / mpix,
            index_error_abs: r.index_error.abs(),
            thickness_mae_nm: r.thickness_mae_nm,
            valid_fraction: r.valid_fraction,
            silent_failure_rate: r.silent_failure_rate,
        });
    }
    Ok(out)
}

/// A film on a substrate for the stability grids: `width x height` pixels, thickness `d_nm`
/// with a 4 % gradient, the paper's camera and noise unless `noise` scales it.
#[derive(Clone, Copy, Debug)]
pub struct GridScene {
    /// Film index.
    pub index: f64,
    /// Mean thickness, nm.
    pub thickness_nm: f64,
    /// LCTF FWHM, nm.
    pub fwhm_nm: f64,
    /// White-reference counts (signal; noise falls as it rises).
    pub white_counts: f64,
    /// Substrate index.
    pub substrate: f64,
    /// Sensor size.
    pub size: [usize; 2],
    /// Noise seed.
    pub seed: u64,
}

impl Default for GridScene {
    fn default() -> Self {
        Self {
            index: 1.38,
            thickness_nm: 500.0,
            fwhm_nm: 4.0,
            white_counts: 3000.0,
            substrate: 1.52,
            size: [16, 12],
            seed: 7,
        }
    }
}

impl GridScene {
    /// The scene.
    pub fn scene(&self) -> Result<Scene> {
        let text = format!(
            r#"
name = "n{n:.2}-d{d:.0}"
seed = {seed}
polarization = "s"
[film]
index = {n}
[film.thickness]
base_nm = {d}
gradient_nm = [{g}, 0.0]
[substrate]
index = {ns}
[rig]
angles_deg = [10.0, 20.0, 30.0, 40.0, 50.0]
bands_nm = [420.0, 720.0, 2.0]
fwhm_nm = {fwhm}
[sensor]
width = {w}
height = {h}
bit_depth = 12
white_counts = {wc}
gain_e_per_count = 1.5
read_noise_counts = 2.0
dark_counts = 64.0
white_frames = 16
[search]
index_range = [1.15, 3.0]
thickness_range_nm = [30.0, 2500.0]
"#,
            n = self.index,
            d = self.thickness_nm,
            g = 0.04 * self.thickness_nm,
            ns = self.substrate,
            fwhm = self.fwhm_nm,
            w = self.size[0],
            h = self.size[1],
            wc = self.white_counts,
            seed = self.seed,
        );
        Scene::from_toml(&text, "grid").map_err(|e| anyhow!("grid scene: {}", e.problem))
    }
}

/// One cell of a stability map.
#[derive(Clone, Debug, Serialize)]
pub struct Cell {
    /// Film index.
    pub index: f64,
    /// Thickness, nm.
    pub thickness_nm: f64,
    /// The method's figures.
    pub point: Point,
}

/// Every method's figures over a film index x thickness grid.
pub fn index_thickness_grid(
    indices: &[f64],
    thicknesses: &[f64],
    settings: &[Setting],
) -> Result<Vec<Cell>> {
    let mut out = Vec::new();
    for &n in indices {
        for &d in thicknesses {
            let scene = GridScene {
                index: n,
                thickness_nm: d,
                ..GridScene::default()
            }
            .scene()?;
            for p in measure(&scene, settings)? {
                out.push(Cell {
                    index: n,
                    thickness_nm: d,
                    point: p,
                });
            }
        }
    }
    Ok(out)
}

/// Points of one series and their labels.
type Labelled = (Vec<(f64, f64)>, Vec<String>);

/// Writes the speed-against-accuracy chart of `points`: time per megapixel (log) against
/// thickness MAE and against index error, a series per method, the Pareto front marked.
pub fn write_speed_chart(path: &Path, title: &str, points: &[Point]) -> Result<()> {
    let methods: Vec<String> = {
        let mut m: Vec<String> = points.iter().map(|p| p.method.clone()).collect();
        m.dedup();
        m
    };
    let pick = |m: &str, y: fn(&Point) -> f64| -> (Vec<(f64, f64)>, Vec<String>) {
        points
            .iter()
            .filter(|p| p.method == m)
            .map(|p| ((p.seconds_per_mpix, y(p)), p.label.clone()))
            .unzip()
    };
    let mae: Vec<_> = methods
        .iter()
        .map(|m| pick(m, |p| p.thickness_mae_nm))
        .collect();
    // A grid that holds the true index exactly gives an error of 0: drawn at 1e-5.
    let idx: Vec<_> = methods
        .iter()
        .map(|m| pick(m, |p| p.index_error_abs.max(1e-5)))
        .collect();
    fn series<'a>(data: &'a [Labelled], methods: &'a [String]) -> Vec<Series<'a>> {
        data.iter()
            .zip(methods)
            .map(|((pts, labels), name)| Series {
                name,
                points: pts,
                labels: Some(labels),
            })
            .collect()
    }
    let (s_mae, s_idx) = (series(&mae, &methods), series(&idx, &methods));
    let panels = [
        Scatter {
            title: "thickness MAE",
            x_label: "seconds per megapixel",
            y_label: "MAE, nm",
            x_log: true,
            y_log: true,
            series: &s_mae,
            pareto: true,
        },
        Scatter {
            title: "index error at 550 nm",
            x_label: "seconds per megapixel",
            y_label: "|n error|",
            x_log: true,
            y_log: true,
            series: &s_idx,
            pareto: true,
        },
    ];
    write_scatter_panels_png(path, title, &panels).map_err(|e| anyhow!("{e}"))
}

/// Writes one stability map per method of `cells` into `dir` (`stability-METHOD.png`):
/// thickness MAE, index error and flagged fraction over film index (rows, highest on top)
/// and thickness (columns). Returns the files written.
pub fn write_stability_maps(dir: &Path, cells: &[Cell]) -> Result<Vec<std::path::PathBuf>> {
    let mut indices: Vec<f64> = cells.iter().map(|c| c.index).collect();
    indices.sort_by(|a, b| b.total_cmp(a));
    indices.dedup();
    let mut thicknesses: Vec<f64> = cells.iter().map(|c| c.thickness_nm).collect();
    thicknesses.sort_by(f64::total_cmp);
    thicknesses.dedup();
    let mut labels: Vec<String> = cells.iter().map(|c| c.point.label.clone()).collect();
    labels.dedup();
    labels.sort();
    labels.dedup();
    let x_ticks: Vec<String> = thicknesses.iter().map(|d| format!("{d:.0}")).collect();
    let y_ticks: Vec<String> = indices.iter().map(|n| format!("{n:.2}")).collect();
    let mut written = Vec::new();
    for label in &labels {
        let grid = |f: fn(&Point) -> f64| -> Vec<f64> {
            let mut v = Vec::with_capacity(indices.len() * thicknesses.len());
            for &n in &indices {
                for &d in &thicknesses {
                    v.push(
                        cells
                            .iter()
                            .find(|c| {
                                &c.point.label == label && c.index == n && c.thickness_nm == d
                            })
                            .map_or(f64::NAN, |c| f(&c.point)),
                    );
                }
            }
            v
        };
        let mae = grid(|p| p.thickness_mae_nm);
        let idx = grid(|p| p.index_error_abs);
        let flagged = grid(|p| 100.0 * (1.0 - p.valid_fraction));
        let silent = grid(|p| 100.0 * p.silent_failure_rate);
        let base = HeatMap {
            title: "",
            x_label: "thickness, nm",
            y_label: "film index",
            x_ticks: &x_ticks,
            y_ticks: &y_ticks,
            cols: thicknesses.len(),
            rows: indices.len(),
            values: &mae,
            unit: "nm",
            range: Some((0.1, 1000.0)),
            log: true,
            cell_text: true,
        };
        let percent = HeatMap {
            unit: "%",
            range: Some((0.0, 100.0)),
            log: false,
            ..base
        };
        let panels = [
            HeatMap {
                title: "thickness MAE (valid px)",
                ..base
            },
            HeatMap {
                title: "index error",
                values: &idx,
                unit: "",
                range: Some((1e-4, 1.0)),
                ..base
            },
            HeatMap {
                title: "flagged",
                values: &flagged,
                ..percent
            },
            HeatMap {
                title: "silently wrong (> 20 nm)",
                values: &silent,
                ..percent
            },
        ];
        let path = dir.join(format!("stability-{}.png", label.replace('/', "-")));
        write_heatmap_panels_png(&path, &format!("{label}: where it works"), &panels)
            .map_err(|e| anyhow!("{e}"))?;
        written.push(path);
    }
    Ok(written)
}
