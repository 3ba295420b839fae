//! Speed against accuracy, and where each method works: the measurements behind
//! `filmscope chart` and `filmscope stability`.
//!
//! Every point is a real run: a scene rendered once by the software camera (raw counts with
//! noise, calibrated), replayed from memory to every method and setting, timed from the first
//! row to the maps, and scored against the scene's truth.
//!
//! A stability map ([`MapSpec`]) sweeps two knobs of a [`GridScene`] (film index, thickness,
//! FWHM, reflectance noise, number and span of the angles, band step; [`Axis`]) and runs every
//! setting in every cell ([`run_map`]); [`summary`] prints where each setting works
//! ([`Verdict`]) and [`write_stability_maps`] draws one heat-map figure per setting.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use super::{LabError, Result};
use filmscope_core::optics::materials;
use filmscope_core::solve::sweep::SolverOptions;
use firmware_sim::Scene;
use serde::Serialize;

use crate::estimate::baseline::BruteGrid;
use crate::estimate::method::Method;
use crate::estimate::{run_method, RunConfig};
use crate::export::plot::{
    write_heatmap_panels_png, write_scatter_panels_png, HeatMap, Scatter, Series,
};
use crate::lab::eval::{evaluate, EvalReport, Truth};
use crate::lab::scene::{scene_with, SceneFile};
use crate::source::{Frames, ReplaySource};

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
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
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
    let frames = Arc::new(Frames::render(scene, scene.sensor.height).map_err(LabError::invalid)?);
    let truth = Truth::of_scene(scene);
    let mpix = (scene.sensor.width * scene.sensor.height) as f64 / 1e6;
    let mut out = Vec::new();
    for s in settings {
        let mut source = ReplaySource::new(frames.clone(), scene.sensor.height, 8);
        let t0 = Instant::now();
        let run = run_method(&mut source, &s.config, &|_| {}).map_err(LabError::invalid)?;
        let secs = t0.elapsed().as_secs_f64();
        let r = evaluate(&scene.name, &truth, &run);
        out.push(Point::of(s.config.method, &s.label, secs / mpix, &r));
    }
    Ok(out)
}

impl Point {
    /// The point of a run of `method` labelled `label`, from its speed and its evaluation.
    pub fn of(method: Method, label: &str, seconds_per_mpix: f64, r: &EvalReport) -> Self {
        Self {
            method: method.name().to_owned(),
            label: label.to_owned(),
            seconds_per_mpix,
            index_error_abs: r.index_error.abs(),
            thickness_mae_nm: r.thickness_mae_nm,
            valid_fraction: r.valid_fraction,
            silent_failure_rate: r.silent_failure_rate,
        }
    }
}

/// A film on a substrate for the stability grids: `size` pixels, mean thickness
/// `thickness_nm` with a 4 % gradient left to right, bands from 420 to 720 nm.
#[derive(Clone, Debug, Serialize)]
pub struct GridScene {
    /// Film index (at 550 nm when the film is a library material).
    pub index: f64,
    /// A library material ([`materials::NAMES`]) whose published dispersion the film has,
    /// instead of the constant `index`.
    pub material: Option<&'static str>,
    /// Mean thickness, nm.
    pub thickness_nm: f64,
    /// LCTF FWHM, nm.
    pub fwhm_nm: f64,
    /// Stage angles, degrees, in the order the sweep visits them.
    pub angles_deg: Vec<f64>,
    /// LCTF band step, nm (bands from 420 nm up to 720 nm).
    pub band_step_nm: f64,
    /// `None`: the paper's camera (12 bits, shot and read noise, `white_counts`).
    /// `Some(p)`: an ideal 16-bit sensor whose only noise is additive Gaussian reflectance
    /// noise of `p` % of a perfect white (1 sigma; the scene's `reflectance_noise_percent`),
    /// with exact references; at 0 what remains is the ADC's rounding, at most 1.1e-5 in
    /// reflectance (1 sigma) at the dimmest pixel.
    pub noise_percent: Option<f64>,
    /// White-reference counts of the paper's camera (signal; noise falls as it rises).
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
            material: None,
            thickness_nm: 500.0,
            fwhm_nm: 4.0,
            angles_deg: vec![10.0, 20.0, 30.0, 40.0, 50.0],
            band_step_nm: 2.0,
            noise_percent: None,
            white_counts: 3000.0,
            substrate: 1.52,
            size: [16, 12],
            seed: 7,
        }
    }
}

/// White-reference counts of the ideal 16-bit sensor (`GridScene::noise_percent`): the
/// dimmest pixel (blue end, image corner: 0.75 x 0.85 of it) still spreads a reflectance
/// of 1 over 25 500 counts.
const IDEAL_WHITE_COUNTS: f64 = 40000.0;
/// Dark level of the ideal sensor: room below it for reflectance noise down to -0.3.
const IDEAL_DARK_COUNTS: f64 = 8000.0;

impl GridScene {
    /// One line: film, rig and sensor, leaving out the knobs in `swept`.
    pub fn describe(&self, swept: &[Axis]) -> String {
        let has = |a: Axis| swept.contains(&a);
        let mut parts = Vec::new();
        match (
            has(Axis::Index) || has(Axis::Material),
            has(Axis::Thickness),
        ) {
            (false, false) => parts.push(format!("n {} at {} nm", self.index, self.thickness_nm)),
            (false, true) => parts.push(format!("n {}", self.index)),
            (true, false) => parts.push(format!("{} nm", self.thickness_nm)),
            (true, true) => parts.push("films".to_owned()),
        }
        parts[0].push_str(&format!(" on {}", self.substrate));
        match (has(Axis::AngleCount), has(Axis::AngleSpan)) {
            (false, false) => {
                let angles: Vec<String> = self.angles_deg.iter().map(|a| format!("{a}")).collect();
                parts.push(format!("angles {} deg", angles.join("/")));
            }
            _ => parts.push(format!(
                "angles evenly from {} deg",
                self.angles_deg.first().copied().unwrap_or(f64::NAN)
            )),
        }
        if !has(Axis::Fwhm) {
            parts.push(format!("FWHM {} nm", self.fwhm_nm));
        }
        if !has(Axis::BandStep) {
            parts.push(format!("band step {} nm", self.band_step_nm));
        }
        match (has(Axis::Noise), self.noise_percent) {
            (true, _) => parts.push("ideal 16-bit sensor".to_owned()),
            (false, None) => parts.push("the paper's camera noise".to_owned()),
            (false, Some(p)) => parts.push(format!("reflectance noise {p} %")),
        }
        parts.push(format!("{}x{} px", self.size[0], self.size[1]));
        parts.join(", ")
    }

    /// The smallest shift of a fringe at `lambda_nm` between neighbouring angles (angles
    /// sorted), eqs. 17-18 of the method: `lambda (1 - sqrt(n^2 - sin^2 th2) /
    /// sqrt(n^2 - sin^2 th1))`, nm (infinite with fewer than two angles).
    pub fn neighbour_shift_nm(&self, lambda_nm: f64) -> f64 {
        let mut a = self.angles_deg.clone();
        a.sort_by(f64::total_cmp);
        let q = |deg: f64| (self.index.powi(2) - deg.to_radians().sin().powi(2)).sqrt();
        a.windows(2)
            .map(|w| lambda_nm * (1.0 - q(w[1]) / q(w[0])))
            .fold(f64::INFINITY, f64::min)
    }

    /// The scene.
    pub fn scene(&self) -> Result<Scene> {
        Scene::from_toml(&self.toml(), "grid")
            .map_err(|e| LabError::Invalid(format!("grid scene: {}", e.problem)))
    }

    /// The scene file (`config/scenes/*.toml` format; `filmscope eval` and `simulate` take it).
    pub fn toml(&self) -> String {
        let sensor = match self.noise_percent {
            None => format!(
                "bit_depth = 12\nwhite_counts = {}\ngain_e_per_count = 1.5\n\
                 read_noise_counts = 2.0\ndark_counts = 64.0\nwhite_frames = 16",
                self.white_counts
            ),
            Some(p) => format!(
                "bit_depth = 16\nwhite_counts = {IDEAL_WHITE_COUNTS}\n\
                 dark_counts = {IDEAL_DARK_COUNTS}\nreflectance_noise_percent = {p}"
            ),
        };
        let angles: Vec<String> = self.angles_deg.iter().map(|a| format!("{a:?}")).collect();
        let film = match self.material {
            Some(m) => format!("[film.dispersion]\nmodel = \"material\"\nname = \"{m}\""),
            None => format!("index = {}", self.index),
        };
        format!(
            r#"name = "n{n:.2}-d{d:.0}"
seed = {seed}
polarization = "s"
[film]
{film}
[film.thickness]
base_nm = {d}
gradient_nm = [{g}, 0.0]
[substrate]
index = {ns}
[rig]
angles_deg = [{angles}]
bands_nm = [420.0, 720.0, {step}]
fwhm_nm = {fwhm}
[sensor]
width = {w}
height = {h}
{sensor}
[search]
index_range = [1.15, 3.0]
thickness_range_nm = [30.0, 2500.0]
"#,
            n = self.index,
            d = self.thickness_nm,
            g = 0.04 * self.thickness_nm,
            ns = self.substrate,
            angles = angles.join(", "),
            step = self.band_step_nm,
            fwhm = self.fwhm_nm,
            w = self.size[0],
            h = self.size[1],
            seed = self.seed,
        )
    }
}

/// A knob of [`GridScene`] that a stability map sweeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Axis {
    /// Film index.
    Index,
    /// Mean thickness, nm.
    Thickness,
    /// LCTF FWHM, nm.
    Fwhm,
    /// Gaussian reflectance noise, % of a perfect white (1 sigma; the ideal sensor).
    Noise,
    /// Number of angles, evenly spaced from the first to the last.
    AngleCount,
    /// Span of the angles (last minus first), degrees; the first and the count stay.
    AngleSpan,
    /// LCTF band step, nm.
    BandStep,
    /// Film material: the position in [`materials::NAMES`] (rising index), with its
    /// published dispersion.
    Material,
}

impl Axis {
    /// Axis title on a map.
    pub fn label(self) -> &'static str {
        match self {
            Self::Index => "film index",
            Self::Thickness => "thickness, nm",
            Self::Fwhm => "FWHM, nm",
            Self::Noise => "noise, % (1 sigma)",
            Self::AngleCount => "number of angles",
            Self::AngleSpan => "angle span, deg",
            Self::BandStep => "band step, nm",
            Self::Material => "film material",
        }
    }

    /// A value with its name and unit, in text: `n 1.38`, `d 500 nm`, `5 angles`.
    pub fn at(self, value: f64) -> String {
        let v = self.tick(value);
        match self {
            Self::Index => format!("n {v}"),
            Self::Thickness => format!("d {v} nm"),
            Self::Fwhm => format!("FWHM {v} nm"),
            Self::Noise => format!("noise {v} %"),
            Self::AngleCount => format!("{v} angles"),
            Self::AngleSpan => format!("span {v} deg"),
            Self::BandStep => format!("step {v} nm"),
            Self::Material => v,
        }
    }

    /// A value as a tick label.
    pub fn tick(self, value: f64) -> String {
        match self {
            Self::Index => format!("{value:.2}"),
            Self::Noise => format!("{value}"),
            Self::Material => materials::NAMES
                .get(value as usize)
                .map_or_else(|| format!("{value}"), |m| (*m).to_owned()),
            _ => format!("{value:.0}"),
        }
    }

    /// Sets this knob of `scene` to `value`.
    pub fn set(self, scene: &mut GridScene, value: f64) {
        let first = scene.angles_deg.first().copied().unwrap_or(10.0);
        let last = scene.angles_deg.last().copied().unwrap_or(50.0);
        let spaced = |count: usize, span: f64| -> Vec<f64> {
            let steps = count.max(2) - 1;
            (0..=steps)
                .map(|i| first + span * i as f64 / steps as f64)
                .collect()
        };
        match self {
            Self::Index => scene.index = value,
            Self::Thickness => scene.thickness_nm = value,
            Self::Fwhm => scene.fwhm_nm = value,
            Self::Noise => scene.noise_percent = Some(value),
            Self::AngleCount => scene.angles_deg = spaced(value as usize, last - first),
            Self::AngleSpan => scene.angles_deg = spaced(scene.angles_deg.len(), value),
            Self::BandStep => scene.band_step_nm = value,
            Self::Material => {
                if let Some(&m) = materials::NAMES.get(value as usize) {
                    scene.material = Some(m);
                    if let Some(d) = materials::by_name(m) {
                        scene.index = d.index_at(550.0);
                    }
                }
            }
        }
    }
}

/// A stability map: two knobs swept over a base scene.
#[derive(Clone, Debug, Serialize)]
pub struct MapSpec {
    /// Short name, in file names (`stability-NAME-SETTING.png`) and stability.json.
    pub name: String,
    /// The scene every cell starts from.
    pub base: GridScene,
    /// The knob across (columns).
    pub x: Axis,
    /// Its values, left to right.
    pub x_values: Vec<f64>,
    /// The knob up (rows).
    pub y: Axis,
    /// Its values, drawn bottom to top.
    pub y_values: Vec<f64>,
}

impl MapSpec {
    /// A map named `name` over `base`.
    pub fn new(name: &str, base: GridScene, x: (Axis, &[f64]), y: (Axis, &[f64])) -> Self {
        Self {
            name: name.to_owned(),
            base,
            x: x.0,
            x_values: x.1.to_vec(),
            y: y.0,
            y_values: y.1.to_vec(),
        }
    }

    /// The scene of cell `(x, y)`.
    pub fn cell_scene(&self, x: f64, y: f64) -> GridScene {
        let mut g = self.base.clone();
        self.y.set(&mut g, y);
        self.x.set(&mut g, x);
        g
    }
}

/// The scene of one cell of a stability map, named `MAP:X:Y` (`index-thickness:2000:2.8`:
/// the map's name, then its column's and its row's value; any value, on the map's grid or
/// not), with the maps' noise seed or `seed`; for `filmscope eval` and `simulate` through
/// [`GridScene::toml`], to reproduce or bisect one cell's figures.
pub fn cell_scene(maps: &[MapSpec], cell: &str, seed: Option<u64>) -> Result<GridScene> {
    let names = || {
        maps.iter()
            .map(|m| m.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut parts = cell.split(':');
    let (Some(name), Some(x), Some(y), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(LabError::Invalid(format!(
            "cell {cell:?}: expected MAP:X:Y, e.g. index-thickness:2000:2.8"
        )));
    };
    let map = maps.iter().find(|m| m.name == name).ok_or_else(|| {
        LabError::Invalid(format!(
            "cell {cell:?}: no map {name:?} (maps: {})",
            names()
        ))
    })?;
    let value = |v: &str, axis: Axis| {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| {
                LabError::Invalid(format!("cell {cell:?}: {v:?} is not a number ({axis:?})"))
            })
    };
    let mut scene = map.cell_scene(value(x, map.x)?, value(y, map.y)?);
    if let Some(seed) = seed {
        scene.seed = seed;
    }
    Ok(scene)
}

/// Every library material, as the material axis's values.
const MATERIAL_AXIS: [f64; 15] = [
    0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0,
];

/// The maps `filmscope stability` draws (coarser with `quick`).
pub fn stability_maps(quick: bool) -> Vec<MapSpec> {
    let zns = GridScene {
        index: 2.35,
        ..GridScene::default()
    };
    let base = GridScene::default();
    if quick {
        return vec![
            MapSpec::new(
                "index-thickness",
                base.clone(),
                (Axis::Thickness, &[150.0, 500.0, 1500.0]),
                (Axis::Index, &[1.38, 1.8, 2.35]),
            ),
            MapSpec::new(
                "fwhm-thickness",
                base.clone(),
                (Axis::Thickness, &[150.0, 500.0, 1500.0]),
                (Axis::Fwhm, &[2.0, 8.0, 20.0]),
            ),
            MapSpec::new(
                "noise-index",
                base.clone(),
                (Axis::Index, &[1.38, 2.35]),
                (Axis::Noise, &[0.0, 1.0, 3.0]),
            ),
            MapSpec::new(
                "angles",
                zns,
                (Axis::AngleSpan, &[10.0, 40.0]),
                (Axis::AngleCount, &[2.0, 5.0]),
            ),
            MapSpec::new(
                "band-step-thickness",
                base.clone(),
                (Axis::Thickness, &[150.0, 1500.0]),
                (Axis::BandStep, &[1.0, 4.0, 10.0]),
            ),
            MapSpec::new(
                "material-thickness",
                base,
                (Axis::Thickness, &[150.0, 1500.0]),
                (Axis::Material, &[0.0, 10.0, 14.0]),
            ),
        ];
    }
    let thicknesses = [50.0, 100.0, 200.0, 400.0, 700.0, 1000.0, 1500.0, 2000.0];
    // 0.2 apart, and 1.5 next to the substrate's 1.52.
    let indices = [1.2, 1.4, 1.5, 1.6, 1.8, 2.0, 2.2, 2.4, 2.6, 2.8];
    vec![
        MapSpec::new(
            "index-thickness",
            base.clone(),
            (Axis::Thickness, &thicknesses),
            (Axis::Index, &indices),
        ),
        MapSpec::new(
            "fwhm-thickness",
            base.clone(),
            (Axis::Thickness, &thicknesses),
            (Axis::Fwhm, &[1.0, 2.0, 4.0, 7.0, 10.0, 14.0, 20.0]),
        ),
        MapSpec::new(
            "noise-index",
            base.clone(),
            (Axis::Index, &indices),
            (Axis::Noise, &[0.0, 0.25, 0.5, 1.0, 2.0, 3.0]),
        ),
        MapSpec::new(
            "angles",
            zns,
            (Axis::AngleSpan, &[10.0, 20.0, 40.0, 60.0]),
            (Axis::AngleCount, &[2.0, 3.0, 4.0, 5.0, 7.0]),
        ),
        MapSpec::new(
            "band-step-thickness",
            base.clone(),
            (Axis::Thickness, &thicknesses),
            (Axis::BandStep, &[1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0]),
        ),
        // Every library material with its published dispersion, on glass (1.52: PMMA and
        // polycarbonate are within 0.06 of it, their fringes faint).
        MapSpec::new(
            "material-thickness",
            base,
            (Axis::Thickness, &thicknesses),
            (Axis::Material, &MATERIAL_AXIS),
        ),
    ]
}

/// One cell of a stability map: one setting's figures.
#[derive(Clone, Debug, Serialize)]
pub struct Cell {
    /// The map's x knob here.
    pub x: f64,
    /// The map's y knob here.
    pub y: f64,
    /// The setting's figures.
    pub point: Point,
}

/// A stability map measured: every setting in every cell.
#[derive(Clone, Debug, Serialize)]
pub struct MapRun {
    /// What was swept.
    pub spec: MapSpec,
    /// Cells in row-major order of `(y, x)`, every setting per cell.
    pub cells: Vec<Cell>,
    /// Wall seconds for the whole map.
    pub seconds: f64,
}

/// Runs every setting in every cell of `spec`; `progress` hears of each cell done.
pub fn run_map(spec: &MapSpec, settings: &[Setting], progress: &dyn Fn(&Cell)) -> Result<MapRun> {
    let t0 = Instant::now();
    let mut cells = Vec::new();
    for &y in &spec.y_values {
        for &x in &spec.x_values {
            let scene = spec.cell_scene(x, y).scene()?;
            for point in measure(&scene, settings)? {
                let cell = Cell { x, y, point };
                progress(&cell);
                cells.push(cell);
            }
        }
    }
    Ok(MapRun {
        spec: spec.clone(),
        cells,
        seconds: t0.elapsed().as_secs_f64(),
    })
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
    write_scatter_panels_png(path, title, &panels).map_err(LabError::invalid)
}

/// How a setting fares in one cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// At least 90 % valid, MAE at most 3 nm, at most 0.5 % silently wrong.
    Works,
    /// Fewer than 90 % valid, but the valid ones within 3 nm and at most 0.5 % wrong.
    Flags,
    /// At most 0.5 % silently wrong, but the valid pixels' MAE above 3 nm.
    Inaccurate,
    /// More than 0.5 % of the pixels valid and more than 20 nm off.
    Silent,
}

impl Verdict {
    /// The verdict on `p`.
    pub fn of(p: &Point) -> Self {
        if p.silent_failure_rate > 0.005 {
            Self::Silent
        } else if p.thickness_mae_nm > 3.0 {
            Self::Inaccurate
        } else if p.valid_fraction < 0.9 {
            Self::Flags
        } else {
            Self::Works
        }
    }

    /// One letter for a text map.
    pub fn letter(self) -> char {
        match self {
            Self::Works => 'o',
            Self::Flags => 'f',
            Self::Inaccurate => 'm',
            Self::Silent => 'X',
        }
    }
}

/// The settings of `run`, in the order first measured.
fn labels(run: &MapRun) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for c in &run.cells {
        if !out.contains(&c.point.label) {
            out.push(c.point.label.clone());
        }
    }
    out
}

/// The figures of setting `label` in cell `(x, y)`.
fn point_at<'a>(run: &'a MapRun, label: &str, x: f64, y: f64) -> Option<&'a Point> {
    run.cells
        .iter()
        .find(|c| c.point.label == label && c.x == x && c.y == y)
        .map(|c| &c.point)
}

/// Lines of a text map over `spec`'s cells (highest y on top, x ticks underneath), each cell
/// `text(x, y)` right-aligned in a column as wide as the widest text or tick.
fn text_grid(spec: &MapSpec, text: impl Fn(f64, f64) -> String) -> Vec<String> {
    let x_ticks: Vec<String> = spec.x_values.iter().map(|&v| spec.x.tick(v)).collect();
    let y_ticks: Vec<String> = spec.y_values.iter().map(|&v| spec.y.tick(v)).collect();
    let cells: Vec<Vec<String>> = spec
        .y_values
        .iter()
        .map(|&y| spec.x_values.iter().map(|&x| text(x, y)).collect())
        .collect();
    let width = 1 + cells
        .iter()
        .flatten()
        .chain(&x_ticks)
        .map(String::len)
        .max()
        .unwrap_or(1);
    let margin = 2 + y_ticks.iter().map(String::len).max().unwrap_or(1);
    let mut lines: Vec<String> = cells
        .iter()
        .zip(&y_ticks)
        .rev()
        .map(|(row, yt)| {
            let mut line = format!("{yt:>margin$}");
            for c in row {
                line.push_str(&format!("{c:>width$}"));
            }
            line
        })
        .collect();
    let mut ticks = format!("{:>margin$}", "");
    for t in &x_ticks {
        ticks.push_str(&format!("{t:>width$}"));
    }
    lines.push(ticks);
    lines
}

/// A text summary of `run`: the base scene; where the map changes it, eq. 18's smallest peak
/// shift between neighbouring angles at 550 nm over the FWHM; then per setting, how many
/// cells each [`Verdict`] got and a map of verdict letters with the index error (rows as on
/// the heat maps, highest y on top), and, where at most a third of the cells do not work,
/// those cells' figures.
pub fn summary(run: &MapRun) -> String {
    use std::fmt::Write as _;
    let spec = &run.spec;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}: {} (rows) x {} (columns), {} cells, {:.0} s; {}",
        spec.name,
        spec.y.label(),
        spec.x.label(),
        spec.x_values.len() * spec.y_values.len(),
        run.seconds,
        spec.base.describe(&[spec.x, spec.y])
    );
    let ratio = |x: f64, y: f64| {
        let g = spec.cell_scene(x, y);
        g.neighbour_shift_nm(550.0) / g.fwhm_nm
    };
    let ratios: Vec<f64> = spec
        .y_values
        .iter()
        .flat_map(|&y| spec.x_values.iter().map(move |&x| ratio(x, y)))
        .collect();
    if ratios.iter().any(|r| (r - ratios[0]).abs() > 1e-9) {
        let _ = writeln!(
            s,
            "  eq. 18 peak shift between neighbouring angles at 550 nm / FWHM:"
        );
        for line in text_grid(spec, |x, y| format!("{:.2}", ratio(x, y))) {
            let _ = writeln!(s, "  {line}");
        }
    } else {
        let _ = writeln!(
            s,
            "  eq. 18 peak shift between neighbouring angles at 550 nm / FWHM: {:.2} everywhere",
            ratios[0]
        );
    }
    for label in labels(run) {
        let mut count = [0usize; 4];
        for c in run.cells.iter().filter(|c| c.point.label == label) {
            count[Verdict::of(&c.point) as usize] += 1;
        }
        let _ = writeln!(
            s,
            "  {label}: works (o) {}, flags (f) {}, MAE > 3 nm (m) {}, silently wrong (X) {}; \
             each with its |index error|",
            count[0], count[1], count[2], count[3]
        );
        let grid = text_grid(spec, |x, y| match point_at(run, &label, x, y) {
            None => ".".into(),
            Some(p) if p.index_error_abs.is_finite() => {
                format!("{} {:.4}", Verdict::of(p).letter(), p.index_error_abs)
            }
            Some(p) => format!("{}      -", Verdict::of(p).letter()),
        });
        for line in grid {
            let _ = writeln!(s, "  {line}");
        }
        // Where a setting mostly works, the cells where it does not, in full.
        let failing: Vec<&Cell> = run
            .cells
            .iter()
            .filter(|c| c.point.label == label && Verdict::of(&c.point) != Verdict::Works)
            .collect();
        if failing.len() * 3 <= spec.x_values.len() * spec.y_values.len() {
            for c in failing {
                let p = &c.point;
                let _ = writeln!(
                    s,
                    "    {}, {}: {}  n err {:.4}  MAE {:.2} nm  valid {:.1} %  silent {:.2} %",
                    spec.y.at(c.y),
                    spec.x.at(c.x),
                    Verdict::of(p).letter(),
                    p.index_error_abs,
                    p.thickness_mae_nm,
                    100.0 * p.valid_fraction,
                    100.0 * p.silent_failure_rate
                );
            }
        }
    }
    s
}

/// Writes one heat-map figure per setting of `run` into `dir`
/// (`stability-MAP-SETTING.png`): thickness MAE, index error, flagged and silently wrong
/// fractions over the map's two knobs (highest y on top). Returns the files written.
pub fn write_stability_maps(dir: &Path, run: &MapRun) -> Result<Vec<std::path::PathBuf>> {
    let spec = &run.spec;
    let x_ticks: Vec<String> = spec.x_values.iter().map(|&v| spec.x.tick(v)).collect();
    let y_ticks: Vec<String> = spec
        .y_values
        .iter()
        .rev()
        .map(|&v| spec.y.tick(v))
        .collect();
    let mut written = Vec::new();
    for label in labels(run) {
        let grid = |f: fn(&Point) -> f64| -> Vec<f64> {
            let mut v = Vec::with_capacity(spec.x_values.len() * spec.y_values.len());
            for &y in spec.y_values.iter().rev() {
                for &x in &spec.x_values {
                    v.push(point_at(run, &label, x, y).map_or(f64::NAN, f));
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
            x_label: spec.x.label(),
            y_label: spec.y.label(),
            x_ticks: &x_ticks,
            y_ticks: &y_ticks,
            cols: spec.x_values.len(),
            rows: spec.y_values.len(),
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
        let path = dir.join(format!(
            "stability-{}-{}.png",
            spec.name,
            label.replace('/', "-")
        ));
        let title = format!(
            "{label}: where it works ({}; {})",
            spec.name,
            spec.base.describe(&[spec.x, spec.y])
        );
        write_heatmap_panels_png(&path, &title, &panels).map_err(LabError::invalid)?;
        written.push(path);
    }
    Ok(written)
}

/// `filmscope chart`: every setting of [`settings`] on `scene` resized to 128 x 96 pixels
/// (48 x 32 with `quick`: as the bench's methods sweep, large enough that a setting's time
/// per megapixel is its own, not its fixed costs). `out` is created first; `on_points` is
/// given the points once measured, then the chart and the points are written as
/// `out/speed-accuracy.png` and `.json`. Returns the PNG's path.
pub fn speed_accuracy(
    scene: &SceneFile,
    out: &Path,
    quick: bool,
    on_points: &mut dyn FnMut(&[Point]),
) -> Result<PathBuf> {
    std::fs::create_dir_all(out).map_err(LabError::file(out, "create"))?;
    let size = if quick { [48, 32] } else { [128, 96] };
    let scene = scene_with(scene, size[0], size[1], None)?;
    let points = measure(&scene, &settings(quick))?;
    on_points(&points);
    let png = out.join("speed-accuracy.png");
    let title = format!(
        "{} ({}x{} px): speed against accuracy",
        scene.name, size[0], size[1]
    );
    write_speed_chart(&png, &title, &points)?;
    crate::io::write_atomic(
        &out.join("speed-accuracy.json"),
        serde_json::to_string_pretty(&points)?.as_bytes(),
    )?;
    Ok(png)
}

/// What [`stability`] measured.
#[derive(Clone, Debug)]
pub struct Stability {
    /// Every map run.
    pub runs: Vec<MapRun>,
    /// Settings run in each cell.
    pub settings: usize,
    /// Wall seconds of all the maps.
    pub seconds: f64,
}

/// What [`stability`] reports as it goes.
pub enum StabilityStep<'a> {
    /// A map measured, before its figures are drawn.
    Measured(&'a MapRun),
    /// A file written.
    Wrote(&'a Path),
}

/// `filmscope stability`: the maps of [`stability_maps`] named in `only` (every one when
/// empty; an unknown name fails before any work), each run with filmscope, the paper's
/// method and the 19n/8nm setting and drawn into `out` ([`write_stability_maps`]), then
/// every map's figures written as `out/stability.json` (`stability-NAME-....json` with
/// `only`). `on_step` hears of each map measured and each figure written.
pub fn stability(
    out: &Path,
    quick: bool,
    only: &[String],
    on_step: &mut dyn FnMut(StabilityStep<'_>),
) -> Result<Stability> {
    let maps = stability_maps(quick);
    if let Some(unknown) = only.iter().find(|n| !maps.iter().any(|m| &m.name == *n)) {
        let names: Vec<&str> = maps.iter().map(|m| m.name.as_str()).collect();
        return Err(LabError::Invalid(format!(
            "--map {unknown:?}: no such map (maps: {})",
            names.join(", ")
        )));
    }
    std::fs::create_dir_all(out).map_err(LabError::file(out, "create"))?;
    let settings: Vec<_> = settings(true)
        .into_iter()
        .filter(|s| matches!(s.label.as_str(), "filmscope" | "paper" | "19n/8nm"))
        .collect();
    let t0 = Instant::now();
    let mut runs = Vec::new();
    for spec in maps
        .into_iter()
        .filter(|m| only.is_empty() || only.contains(&m.name))
    {
        let run = run_map(&spec, &settings, &|_| {})?;
        on_step(StabilityStep::Measured(&run));
        for p in write_stability_maps(out, &run)? {
            on_step(StabilityStep::Wrote(&p));
        }
        runs.push(run);
    }
    let json = if only.is_empty() {
        "stability.json".to_owned()
    } else {
        format!("stability-{}.json", only.join("-"))
    };
    crate::io::write_atomic(
        &out.join(json),
        serde_json::to_string_pretty(&runs)?.as_bytes(),
    )?;
    Ok(Stability {
        runs,
        settings: settings.len(),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// `filmscope stability --cell MAP:X:Y`: the cell's scene ([`cell_scene`] of the maps,
/// coarser with `quick`) written into `out` as `cell-MAP-X-Y-sSEED.toml`; returns its path
/// and the scene.
pub fn write_cell_scene(
    out: &Path,
    quick: bool,
    cell: &str,
    seed: Option<u64>,
) -> Result<(PathBuf, GridScene)> {
    let maps = stability_maps(quick);
    let scene = cell_scene(&maps, cell, seed)?;
    std::fs::create_dir_all(out).map_err(LabError::file(out, "create"))?;
    let name = format!("cell-{}-s{}.toml", cell.replace(':', "-"), scene.seed);
    let path = out.join(name);
    crate::io::write_atomic(&path, scene.toml().as_bytes())?;
    Ok((path, scene))
}
