//! `filmscope bench`: speed, memory and the baselines' cost, measured in one run.
//!
//! Every figure is measured here, on this machine, in release builds; nothing is asserted
//! about time (tests check accuracy, this command reports speed). The spectra are real: a
//! scene is rendered by the software camera (raw counts with noise, calibrated) once, and the
//! measurements replay them from memory, so the camera's own cost (an Airy sum per sample)
//! is left out of everything but the figure that names it.
//!
//! - `tracker`: the row kernel ([`push_row`], what the workers run, into each pixel's last
//!   extrema as the workers keep them, [`ExtremaHead`]) alone, one core, pixel-band samples
//!   per second.
//! - `stream`: everything a sample costs a worker ([`filmscope_core::solve::Shard::feed_row`]: tracker and the
//!   full-spectrum sums), one core.
//! - `solve`: the angle-end passes ([`SweepSolver::end_angle_all`]: votes, index, orders,
//!   Gauss-Newton steps) and the final maps, one core, pixels per second of a whole sweep.
//! - `pipeline`: the whole bounded pipeline on two workers from a replayed source; its
//!   latency from the last row to the maps, with the source paced at half the pipeline's rate
//!   (a camera slower than the pipeline), the median of three sweeps.
//! - `methods`: `filmscope` and `paper` on the same sweep (256 x 192, 64 x 48 with
//!   `--quick`), `brute` on 128 x 96 (48 x 32), and the Python peers with the index given
//!   beside filmscope with the index given, seconds per megapixel and their accuracy.
//! - With `FILMSCOPE_BENCH_STREAM_ROWS=N` set, the `stream` figure is also measured with the
//!   kernel sweep's rows repeated to N rows (printed to stderr): whether the state still fits
//!   the caches shows in the difference.
//! - `rss`: a child process runs one sweep of a large sensor (2048 x 2048 x 161 bands x 5
//!   angles, and 4096 x 3000 x 161 x 5, unless `--quick`) and reports its peak resident
//!   memory (`VmHWM`).
//! - `end to end`: `filmscope estimate` run as a child process on a raw ENVI capture written
//!   to disk ([`end_to_end`]), the streaming method and the paper's, wall seconds.
//! - `inspect`: the production line's latency from a sample's last row to its verdict
//!   published ([`inspect_latency`]), on firmware-sim.
//!
//! [`soak`] is the reliability check beside them: the resident memory over many sweeps.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::{LabError, Result};
use filmscope_core::solve::fit_row::{IndexSampling, INDEX_PIXELS};
use filmscope_core::solve::shard::PixelResult;
use filmscope_core::solve::{state_bytes_per_pixel, SweepSolver};
use filmscope_core::track::row::{blocks_for, push_row, TrackerLanes};
use filmscope_core::track::ExtremaHead;
use firmware_sim::{Scene, SoftwareCamera};
use serde::Serialize;

use crate::estimate::method::Method;
use crate::estimate::RunConfig;
use crate::lab::chart::{measure, Point, Setting};
use crate::lab::scene::{scene_with, SceneFile};
use crate::line::inspect::{InspectError, InspectOptions, Line};
use crate::line::recipe::Recipe;
use crate::pipeline::{run_sweep, BandModels, PipelineConfig, Prior, PriorUpdate, ShardState};
use crate::rig::RigConfig;
use crate::source::{Frames, ReplaySource, SimSource};

/// Runs `f` repeatedly until at least `min` has passed; returns (calls, elapsed).
fn repeat_for(min: Duration, mut f: impl FnMut()) -> (u64, Duration) {
    let t0 = Instant::now();
    let mut n = 0;
    while n == 0 || t0.elapsed() < min {
        f();
        n += 1;
    }
    (n, t0.elapsed())
}

/// Tracker throughput on one core: samples per second of the row kernel the workers use
/// ([`push_row`], one row of the image per call, band by band, into [`ExtremaHead`]s),
/// compiled for the CPU's widest vectors if `wide` ([`filmscope_core::simd::wide`]).
pub fn tracker_rate(frames: &Frames, min: Duration, wide: bool) -> f64 {
    let w = frames.width();
    let px = w * frames.rows;
    let per_row = blocks_for(1, w);
    let mut blocks = vec![TrackerLanes::EMPTY; blocks_for(frames.rows, w)];
    let mut lists = vec![ExtremaHead::EMPTY; px];
    let (n, t) = repeat_for(min, || {
        for a in 0..frames.angles_deg.len() {
            blocks.iter_mut().for_each(TrackerLanes::reset);
            lists.iter_mut().for_each(ExtremaHead::clear);
            filmscope_core::simd::wide(wide, {
                #[inline(always)]
                || {
                    for b in 0..frames.bands() {
                        for r in 0..frames.rows {
                            push_row(
                                &mut blocks[r * per_row..(r + 1) * per_row],
                                b as u16,
                                frames.row(a, b, r),
                                true,
                                &mut lists[r * w..(r + 1) * w],
                            );
                        }
                    }
                }
            });
        }
        std::hint::black_box(&lists);
    });
    let samples = (px * frames.bands() * frames.angles_deg.len()) as f64 * n as f64;
    samples / t.as_secs_f64()
}

/// One whole sweep over `frames` (their rows repeated to `rows` rows) on one core, with the
/// streaming (tracker and sums) and the angle-end passes timed apart: `(stream samples/s,
/// solve pixels/s)`; the streaming compiled for the CPU's widest vectors if `wide`
/// ([`SolverOptions::wide_simd`](filmscope_core::solve::sweep::SolverOptions::wide_simd)).
pub fn sweep_rates(frames: &Frames, rows: usize, wide: bool) -> (f64, f64) {
    let mut spec = frames.spec.clone();
    spec.options.wide_simd = wide;
    let (w, nb) = (frames.width(), frames.bands());
    let mut spec_rows = spec.clone();
    spec_rows.height = rows;
    let mut states = ShardState::empty(rows, w, spec_rows.index_sampling());
    let mut solver = SweepSolver::new(spec_rows, None);
    let (mut stream, mut solve) = (Duration::ZERO, Duration::ZERO);
    for (a, &deg) in frames.angles_deg.iter().enumerate() {
        solver.begin_angle(deg);
        let models = BandModels::of(&solver, 1);
        let mut shard = states.shard(0, w);
        shard.begin_angle();
        let t0 = Instant::now();
        for b in 0..nb {
            for r in 0..rows {
                shard.feed_row(spec.options, models.view(), b, r, frames.row(a, b, r));
            }
        }
        stream += t0.elapsed();
        let t1 = Instant::now();
        solver.end_angle_all(&mut [shard]);
        solve += t1.elapsed();
    }
    let t2 = Instant::now();
    let mut out = vec![PixelResult::UNSOLVED; w * rows];
    states.shard(0, w).finish(&solver, &mut out);
    solve += t2.elapsed();
    std::hint::black_box(&out);
    let samples = (w * rows * nb * frames.angles_deg.len()) as f64;
    (
        samples / stream.as_secs_f64(),
        (w * rows) as f64 / solve.as_secs_f64(),
    )
}

/// Peak memory of one sweep, measured in a child process.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct RssFigures {
    /// Sensor width.
    pub width: usize,
    /// Sensor height.
    pub height: usize,
    /// Bands.
    pub bands: usize,
    /// Angles.
    pub angles: usize,
    /// Peak resident set of the child, MB (`VmHWM`).
    pub peak_rss_mb: f64,
    /// Resident set before the sweep started (frames rendered), MB.
    pub before_sweep_mb: f64,
    /// Seconds the sweep took.
    pub seconds: f64,
    /// Samples per second of that sweep.
    pub samples_per_s: f64,
}

/// Reads a `/proc/self/status` field in kB, as MB.
fn status_mb(field: &str) -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(field))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Resident memory after a number of consecutive sweeps ([`soak`]).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct SoakPoint {
    /// Sweeps done.
    pub sweep: usize,
    /// Resident set size, MB (`VmRSS`).
    pub rss_mb: f64,
    /// Peak resident set size so far, MB (`VmHWM`).
    pub peak_rss_mb: f64,
}

/// The scene `filmscope soak` runs: `scene` resized to 32 x 24 pixels, its bands 420-720
/// nm every 3 nm (101 bands).
pub fn soak_scene(scene: &SceneFile) -> Result<Scene> {
    scene_with(scene, 32, 24, Some([420.0, 720.0, 3.0]))
}

/// Runs `sweeps` consecutive sweeps of `scene` on the software camera through
/// [`run_sweep`], each starting from the last one's index as on a production line, and
/// reports the resident memory after every `every`th sweep (and the first): a long run
/// must not grow. Fails on the first sweep that fails.
pub fn soak(
    scene: &Scene,
    sweeps: usize,
    every: usize,
    config: PipelineConfig,
    mut report: impl FnMut(SoakPoint),
) -> Result<Vec<SoakPoint>> {
    let mut points = Vec::new();
    let mut prior = None;
    for i in 1..=sweeps {
        let mut source = SimSource::new(SoftwareCamera::new(scene.clone()), false, 4)
            .map_err(LabError::invalid)?;
        let out = run_sweep(&mut source, config, prior.take(), &|_| {})
            .map_err(|e| LabError::Invalid(format!("sweep {i}: {e}")))?;
        prior = out
            .index
            .map(|index| Prior::new(index, PriorUpdate::Shifts, None));
        std::hint::black_box(&out.results);
        drop(out);
        if i == 1 || i % every.max(1) == 0 || i == sweeps {
            let point = SoakPoint {
                sweep: i,
                rss_mb: status_mb("VmRSS:").unwrap_or(f64::NAN),
                peak_rss_mb: status_mb("VmHWM:").unwrap_or(f64::NAN),
            };
            report(point);
            points.push(point);
        }
    }
    Ok(points)
}

/// The child's side of the RSS measurement: one sweep of `scene_file` resized, printed as
/// JSON on stdout.
pub fn rss_child(scene_file: &SceneFile, width: usize, height: usize, angles: usize) -> Result<()> {
    let mut scene = scene_with(scene_file, width, 1, Some([400.0, 720.0, 2.0]))?;
    scene.angles_deg.truncate(angles.max(1));
    let frames = Arc::new(Frames::render(&scene, 1).map_err(LabError::invalid)?);
    let before = status_mb("VmRSS:").unwrap_or(f64::NAN);
    let mut source = ReplaySource::new(frames.clone(), height, 16);
    let t0 = Instant::now();
    let out = run_sweep(&mut source, PipelineConfig::default(), None, &|_| {})
        .map_err(LabError::invalid)?;
    let secs = t0.elapsed().as_secs_f64();
    std::hint::black_box(&out.results);
    let fig = RssFigures {
        width,
        height,
        bands: frames.bands(),
        angles: frames.angles_deg.len(),
        peak_rss_mb: status_mb("VmHWM:").unwrap_or(f64::NAN),
        before_sweep_mb: before,
        seconds: secs,
        samples_per_s: out.samples as f64 / secs,
    };
    println!("{}", serde_json::to_string(&fig)?);
    Ok(())
}

/// The streaming method with the film's index given (as the Python peers are given it:
/// `filmscope estimate --film-index`), on `scene`'s calibrated frames replayed from memory
/// (as the peers' `seconds` start from calibrated spectra): the like-for-like figure for the
/// peers' ratios. The median of three runs (a single half-second run moved by a fifth from
/// one to the next).
pub fn measure_index_given(scene: &Scene) -> Result<Point> {
    let frames = Arc::new(Frames::render(scene, scene.sensor.height).map_err(LabError::invalid)?);
    let truth = crate::lab::eval::Truth::of_scene(scene);
    let mpix = (scene.sensor.width * scene.sensor.height) as f64 / 1e6;
    let once = || -> Result<Point> {
        let mut source = ReplaySource::new(frames.clone(), scene.sensor.height, 8);
        let t0 = Instant::now();
        let run = crate::estimate::known_index::run_with_index(
            &mut source,
            &RunConfig::default(),
            &scene.stack.film,
            "scene",
            &|_| {},
        )
        .map_err(LabError::invalid)?;
        let secs = t0.elapsed().as_secs_f64();
        let r = crate::lab::eval::evaluate(&scene.name, &truth, &run);
        Ok(Point::of(
            Method::Filmscope,
            "filmscope (n given)",
            secs / mpix,
            &r,
        ))
    };
    median_of_three(once, |p| p.seconds_per_mpix)
}

/// `filmscope estimate` from an ENVI capture on disk, as a user runs it.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct EndToEnd {
    /// Sensor width.
    pub width: usize,
    /// Sensor height.
    pub height: usize,
    /// Bands.
    pub bands: usize,
    /// Angles.
    pub angles: usize,
    /// Bytes of the capture's files (cubes, white and dark references).
    pub capture_bytes: u64,
    /// Wall seconds of `filmscope estimate` (the streaming method).
    pub filmscope_seconds: f64,
    /// Wall seconds of `filmscope estimate --method paper` on the same capture.
    pub paper_seconds: Option<f64>,
    /// The streaming method's index error against the scene's.
    pub filmscope_index_error: f64,
    /// The paper method's.
    pub paper_index_error: Option<f64>,
    /// Why the paper method's run is missing, if it is.
    pub paper_error: Option<String>,
}

/// Writes `scene_file` resized to `width x height` as a raw capture (BIL u16 counts with
/// white and dark references, as `filmscope simulate` writes it) into a temporary folder,
/// runs `filmscope estimate` on it in a child process (this executable: the command line's
/// own code path, reading included) for the streaming method and the paper's, timing each
/// wall to wall, and removes the folder.
pub fn end_to_end(scene_file: &SceneFile, width: usize, height: usize) -> Result<EndToEnd> {
    let scene = scene_with(scene_file, width, height, None)?;
    let dir = std::env::temp_dir().join(format!("filmscope-bench-capture-{}", std::process::id()));
    let result = end_to_end_in(&scene, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn end_to_end_in(scene: &Scene, dir: &Path) -> Result<EndToEnd> {
    use crate::io::{ByteOrder, Interleave};
    let capture = dir.join("capture");
    let opts = crate::simulate::SimulateOptions {
        noise_free: false,
        interleave: Interleave::Bil,
        byte_order: ByteOrder::Little,
        float_reflectance: false,
    };
    crate::simulate::write_capture(scene, &capture, opts, &|_| {}).map_err(LabError::invalid)?;
    let capture_bytes = std::fs::read_dir(&capture)?
        .filter_map(|e| e.ok()?.metadata().ok())
        .filter(|m| m.is_file())
        .map(|m| m.len())
        .sum();
    let truth = scene.stack.film.index_at(550.0);
    let exe =
        std::env::current_exe().map_err(LabError::step("cannot find the filmscope executable"))?;
    let run = |method: &str| -> Result<(f64, f64)> {
        let out = dir.join(format!("out-{method}"));
        let t0 = Instant::now();
        let child = Command::new(&exe)
            .arg("estimate")
            .arg(&capture)
            .arg("--out")
            .arg(&out)
            .args(["--method", method])
            .output()
            .map_err(LabError::step("cannot start filmscope estimate"))?;
        let seconds = t0.elapsed().as_secs_f64();
        if !child.status.success() {
            return Err(LabError::Invalid(format!(
                "filmscope estimate --method {method}: {}",
                String::from_utf8_lossy(&child.stderr).trim()
            )));
        }
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json"))?)?;
        let n = summary["refractive_index"].as_f64().unwrap_or(f64::NAN);
        Ok((seconds, (n - truth).abs()))
    };
    let (filmscope_seconds, filmscope_index_error) = run("filmscope")?;
    let (paper, paper_error) = match run("paper") {
        Ok(r) => (Some(r), None),
        Err(e) => (None, Some(e.to_string())),
    };
    Ok(EndToEnd {
        width: scene.sensor.width,
        height: scene.sensor.height,
        bands: scene.bands_nm.len(),
        angles: scene.angles_deg.len(),
        capture_bytes,
        filmscope_seconds,
        paper_seconds: paper.map(|p| p.0),
        filmscope_index_error,
        paper_index_error: paper.map(|p| p.1),
        paper_error,
    })
}

/// Per-sample latencies, ms (last row to verdict published), of `samples` samples of the
/// demo recipe (`config/recipes/demo.toml`, built in, without MQTT or status page) on
/// firmware-sim behind the rig file `rig` (default: `config/rig.toml` where it exists, else
/// the same rig built in, as `inspect` takes it), through the line's own [`Line`], in a
/// temporary folder removed afterwards: the figure `filmscope bench` reports.
pub fn inspect_latency(rig: Option<&Path>, samples: u64) -> Result<Vec<f64>, InspectError> {
    let path = Path::new("config/recipes/demo.toml");
    let mut recipe = Recipe::parse(include_str!("../../config/recipes/demo.toml"), path)
        .map_err(|e| InspectError::Stopped(e.to_string()))?;
    recipe.mqtt = None;
    recipe.status = None;
    recipe.modbus = None;
    let rig = RigConfig::load_or_builtin(rig).map_err(|e| InspectError::Stopped(e.to_string()))?;
    let tmp = tempfile::Builder::new()
        .prefix("filmscope-bench-inspect-")
        .tempdir()
        .map_err(|e| InspectError::Stopped(format!("cannot create a temporary folder: {e}")))?;
    let out = tmp.path().join("out");
    let result = (|| {
        let mut line = Line::open(InspectOptions {
            rig,
            recipe,
            recipe_path: path.to_owned(),
            out: out.clone(),
            sim: true,
            status_port: None,
            mqtt_port: None,
            modbus: None,
            stop: Arc::new(AtomicBool::new(false)),
        })?;
        let mut l = Vec::new();
        for _ in 0..samples {
            l.push(line.measure()?.published_ms);
        }
        Ok(l)
    })();
    drop(tmp);
    result
}

fn rss_in_child(
    scene_file: &SceneFile,
    width: usize,
    height: usize,
    angles: usize,
) -> Result<RssFigures> {
    let exe =
        std::env::current_exe().map_err(LabError::step("cannot find the filmscope executable"))?;
    let mut child = Command::new(exe);
    child.arg("bench-rss-child");
    if let SceneFile::Path(p) = scene_file {
        child.arg("--scene").arg(p);
    }
    let out = child
        .args([width.to_string(), height.to_string(), angles.to_string()])
        .output()
        .map_err(LabError::step("cannot start the memory-measuring child"))?;
    if !out.status.success() {
        return Err(LabError::Invalid(format!(
            "memory-measuring child failed: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().last().unwrap_or_default();
    Ok(serde_json::from_str(line)?)
}

/// Everything `filmscope bench` measures.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct BenchReport {
    /// Quick mode (smaller sweeps).
    pub quick: bool,
    /// The scene the spectra come from.
    pub scene: String,
    /// Tracker alone, samples per second on one core.
    pub tracker_samples_per_s_per_core: f64,
    /// Tracker and full-spectrum sums (a worker's per-sample cost), on one core.
    pub stream_samples_per_s_per_core: f64,
    /// Whether the figures above (and the pipeline's) ran compiled for AVX2 and FMA
    /// ([`filmscope_core::simd::wide`]); the portable build's follow.
    pub wide_simd: bool,
    /// The tracker alone, portable build (SSE2 on x86-64), on one core.
    pub tracker_portable_samples_per_s_per_core: f64,
    /// Tracker and sums, portable build, on one core.
    pub stream_portable_samples_per_s_per_core: f64,
    /// The whole pipeline on two workers from a replayed source (the median of three sweeps).
    pub pipeline_samples_per_s: f64,
    /// The whole pipeline fed by the software camera (the camera's Airy sums included).
    pub pipeline_from_camera_samples_per_s: f64,
    /// The software camera alone, on every core: raw samples (each with its white and dark
    /// reference samples) rendered per second, as `filmscope simulate` renders them
    /// ([`crate::simulate::camera_samples_per_s`]), without writing.
    pub simulate_samples_per_s: f64,
    /// Sensor of `simulate_samples_per_s` (every angle and band of the scene).
    pub simulate_sensor: [usize; 2],
    /// Pixels per second of a sweep's angle-end passes and final maps, on one core.
    pub solve_pixels_per_s_per_core: f64,
    /// Time from the last row to the maps, per megapixel, ms (the median of three paced
    /// sweeps).
    pub latency_ms_per_mpix: f64,
    /// Its parts in that sweep, ms per megapixel: rows still queued (drain), tally, the results'
    /// allocation, sums, update, ties ([`crate::pipeline::LatencyParts`]).
    pub latency_parts_ms_per_mpix: [f64; 6],
    /// Sensor of the pipeline and latency figures.
    pub pipeline_sensor: [usize; 2],
    /// Bytes of solver state per pixel of the RSS figure's sensor, `state_sensor` (constant
    /// in bands, angles and sweeps; a sensor under 131072 pixels, whose every pixel keeps
    /// the index's sums, has 214 against 2048 x 2048's 105: `state_bytes_per_pixel`).
    pub state_bytes_per_pixel: usize,
    /// The sensor of `state_bytes_per_pixel`.
    pub state_sensor: [usize; 2],
    /// `filmscope estimate` from a raw ENVI capture on disk (1024 x 1024, 151 bands, 5
    /// angles; 256 x 256 with `--quick`), wall seconds per megapixel.
    pub end_to_end_s_per_mpix: Option<f64>,
    /// `filmscope estimate --method paper` on the same capture, wall seconds per megapixel.
    pub end_to_end_paper_s_per_mpix: Option<f64>,
    /// The end-to-end runs.
    pub end_to_end: Option<EndToEnd>,
    /// Why the end-to-end figures are missing, if they are.
    pub end_to_end_error: Option<String>,
    /// Peak resident memory of a 2048 x 2048 sweep, 161 bands x 5 angles, MB (`None` with
    /// `--quick`, which measures a smaller sweep: `rss`).
    pub peak_rss_mb_4mp: Option<f64>,
    /// Peak resident memory of a 4096 x 3000 sweep, 161 bands x 5 angles, MB (`None` with
    /// `--quick`).
    pub peak_rss_mb_12mp: Option<f64>,
    /// Peak memory of a large sweep (2048 x 2048 x 5 angles; 1024 x 1024 x 2 with `--quick`).
    pub rss: Option<RssFigures>,
    /// Why the memory figure is missing, if it is.
    pub rss_error: Option<String>,
    /// Peak memory of a 12 MP sweep (full run only).
    pub rss_12mp: Option<RssFigures>,
    /// Why that figure is missing, if it is.
    pub rss_12mp_error: Option<String>,
    /// What a `--quick` run measures differently from the full one.
    pub notes: Vec<String>,
    /// The three methods on the same sweep.
    pub methods: Vec<Point>,
    /// Sensor of filmscope's and the paper method's sweep.
    pub methods_sensor: [usize; 2],
    /// Sensor of brute force's sweep (its time is all per pixel: a smaller one).
    pub brute_sensor: [usize; 2],
    /// Time of `brute` over time of `filmscope`.
    pub speedup_vs_brute: f64,
    /// Time of `paper` over time of `filmscope`.
    pub speedup_vs_paper: f64,
    /// Seconds per megapixel of the NumPy look-up table (`benches/peers/`, index given) over
    /// filmscope's with the index given too (`filmscope (n given)`: both from calibrated
    /// spectra in memory, neither fitting the index), on the methods' capture; `None` when
    /// the peer did not run (`peers.note`).
    pub speedup_vs_numpy_lut: Option<f64>,
    /// The same against filmscope fitting the index itself (its `filmscope` row).
    pub speedup_vs_numpy_lut_index_fitted: Option<f64>,
    /// The same for the per-pixel SciPy `least_squares` fit.
    pub speedup_vs_scipy: Option<f64>,
    /// The Python peers' figures ([`crate::lab::peers`]).
    pub peers: crate::lab::peers::Peers,
    /// `filmscope inspect` on firmware-sim (config/rig.toml, demo recipe): last row to
    /// verdict published, ms, per sample.
    pub inspect_latency_ms: Option<Vec<f64>>,
    /// Why the inspect latency is missing, if it is.
    pub inspect_latency_error: Option<String>,
}

/// The run of `measure`'s three whose `key` is the middle one: a figure that moves from
/// run to run on a shared machine.
fn median_of_three<T>(
    mut measure: impl FnMut() -> Result<T>,
    key: impl Fn(&T) -> f64,
) -> Result<T> {
    let mut runs = vec![measure()?, measure()?, measure()?];
    runs.sort_by(|a, b| key(a).total_cmp(&key(b)));
    Ok(runs.swap_remove(1))
}

/// The kernels' rates on 256 x 32 pixels, every band and angle.
struct Kernels {
    scene: String,
    tracker: f64,
    tracker_portable: f64,
    stream: f64,
    stream_portable: f64,
    solve: f64,
}

fn bench_kernels(
    scene_file: &SceneFile,
    min: Duration,
    progress: &dyn Fn(&str),
) -> Result<Kernels> {
    progress("rendering spectra");
    let kernel_scene = scene_with(scene_file, 256, 32, None)?;
    let kernel = Frames::render(&kernel_scene, 32).map_err(LabError::invalid)?;
    progress("tracker");
    let tracker = tracker_rate(&kernel, min, true);
    let tracker_portable = tracker_rate(&kernel, min, false);
    progress("stream and solve");
    let (stream, solve) = sweep_rates(&kernel, kernel.rows, true);
    let (stream_portable, _) = sweep_rates(&kernel, kernel.rows, false);
    if std::env::var_os("FILMSCOPE_BENCH_STREAM_ROWS").is_some() {
        let rows: usize = std::env::var("FILMSCOPE_BENCH_STREAM_ROWS")
            .ok()
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| LabError::invalid("FILMSCOPE_BENCH_STREAM_ROWS: not a row count"))?;
        let (big, _) = sweep_rates(&kernel, rows, true);
        log::info!("stream 256x{rows}: {:.1} M samples/s", big / 1e6);
    }
    Ok(Kernels {
        scene: kernel_scene.name,
        tracker,
        tracker_portable,
        stream,
        stream_portable,
        solve,
    })
}

/// The pipeline's throughput and latency on a wide sensor, from replayed rows and from the
/// software camera, and the software camera's own rate.
struct Throughput {
    pipeline: f64,
    latency: f64,
    latency_parts: [f64; 6],
    sensor: [usize; 2],
    from_camera: f64,
    simulate: f64,
    simulate_sensor: [usize; 2],
}

fn bench_pipeline(
    scene_file: &SceneFile,
    quick: bool,
    progress: &dyn Fn(&str),
) -> Result<Throughput> {
    // Pipeline: a wide sensor, rows replayed.
    let (pw, ph) = if quick { (512, 256) } else { (1024, 1024) };
    progress("pipeline");
    let pipe_scene = scene_with(scene_file, pw, 16, None)?;
    let frames = Arc::new(Frames::render(&pipe_scene, 16).map_err(LabError::invalid)?);
    // One sweep's rate moved by 20 % from run to run on this 2-core machine.
    let pipeline = median_of_three(
        || {
            let mut source = ReplaySource::new(frames.clone(), ph, 16);
            let out = run_sweep(&mut source, PipelineConfig::default(), None, &|_| {})
                .map_err(LabError::invalid)?;
            Ok(out.samples as f64 / out.stream_time.as_secs_f64())
        },
        |&rate| rate,
    )?;
    // Latency: the same sweep from a camera at half that rate, slower than the pipeline (at
    // full speed the last row waits behind the queued ones: that is throughput, counted
    // above).
    progress("latency (camera at half the pipeline's rate)");
    // Streamed once, as from a live camera: the index refitted on the sample as each angle
    // completes, the last angle's refit included in the latency.
    // One sweep's latency moved by half from run to run on this 2-core virtual machine.
    let live = RunConfig {
        one_pass: true,
        ..RunConfig::default()
    };
    let (median, lp) = median_of_three(
        || {
            let mut paced = ReplaySource::new(frames.clone(), ph, 16).paced(0.5 * pipeline);
            let out = crate::estimate::filmscope_passes(&mut paced, &live, &|_| {})
                .map_err(LabError::invalid)?
                .out;
            Ok((out.solve_latency, out.latency_parts))
        },
        |s| s.0.as_secs_f64(),
    )?;
    let per_mpix = |d: Duration| d.as_secs_f64() * 1e3 / ((pw * ph) as f64 / 1e6);

    progress("pipeline from the software camera");
    let cam_scene = scene_with(scene_file, 128, if quick { 32 } else { 96 }, None)?;
    let mut sim =
        SimSource::new(SoftwareCamera::new(cam_scene), false, 8).map_err(LabError::invalid)?;
    let cam =
        run_sweep(&mut sim, PipelineConfig::default(), None, &|_| {}).map_err(LabError::invalid)?;
    progress("software camera alone");
    let (sim_w, sim_h) = if quick { (512, 32) } else { (1024, 64) };
    let simulate =
        crate::simulate::camera_samples_per_s(&scene_with(scene_file, sim_w, sim_h, None)?, sim_h);
    Ok(Throughput {
        pipeline,
        latency: per_mpix(median),
        latency_parts: [lp.drain, lp.tally, lp.results, lp.sums, lp.update, lp.ties].map(per_mpix),
        sensor: [pw, ph],
        from_camera: cam.samples as f64 / cam.stream_time.as_secs_f64(),
        simulate,
        simulate_sensor: [sim_w, sim_h],
    })
}

/// The methods' times per megapixel (filmscope and the paper's on one sensor, brute force
/// on a smaller one), and the scene the peers are measured on.
struct MethodTimes {
    methods: Vec<Point>,
    scene: Scene,
    sensor: [usize; 2],
    brute_sensor: [usize; 2],
}

impl MethodTimes {
    /// Seconds per megapixel of the method labelled `m` (NaN if not measured).
    fn time(&self, m: &str) -> f64 {
        self.methods
            .iter()
            .find(|f| f.label == m)
            .map_or(f64::NAN, |f| f.seconds_per_mpix)
    }
}

fn bench_methods(
    scene_file: &SceneFile,
    quick: bool,
    progress: &dyn Fn(&str),
) -> Result<MethodTimes> {
    progress("methods");
    // Large enough that per-megapixel times are the methods' own, not their fixed costs (the
    // sample fit, the band models' tables, thread start-up: at 128 x 96 filmscope's sample
    // fit was half its time); brute force, whose time is all per pixel, on a smaller one.
    let (mw, mh) = if quick { (64, 48) } else { (256, 192) };
    let (bw, bh) = if quick { (48, 32) } else { (128, 96) };
    let methods_scene = |w: usize, h: usize| -> Result<Scene> {
        let mut m_scene = scene_with(scene_file, w, h, None)?;
        // A constant index half a brute-force grid step off the grid (paper-sample1's 1.37
        // sits on it, which would give brute force the exact index for free).
        if m_scene.stack.film.is_constant() {
            let n = m_scene.stack.film.index_at(550.0);
            m_scene.stack.film = filmscope_core::optics::Dispersion::constant(
                n + 0.5 * crate::estimate::baseline::DEFAULT_INDEX_STEP,
            );
        }
        Ok(m_scene)
    };
    let setting = |method: Method| {
        let config = RunConfig {
            method,
            ..RunConfig::default()
        };
        Setting::new(method.name(), config)
    };
    let m_scene = methods_scene(mw, mh)?;
    let mut methods = measure(
        &m_scene,
        &[setting(Method::Filmscope), setting(Method::Paper)],
    )?;
    methods.extend(measure(&methods_scene(bw, bh)?, &[setting(Method::Brute)])?);
    Ok(MethodTimes {
        methods,
        scene: m_scene,
        sensor: [mw, mh],
        brute_sensor: [bw, bh],
    })
}

/// A measurement made in a child process: its figures, or why there are none.
fn either<T, E: std::fmt::Display>(r: std::result::Result<T, E>) -> (Option<T>, Option<String>) {
    match r {
        Ok(v) => (Some(v), None),
        Err(e) => (None, Some(e.to_string())),
    }
}

/// Runs every measurement. `scene_file` gives the spectra (the paper's MgF2 sample by default).
pub fn run_bench(
    scene_file: &SceneFile,
    quick: bool,
    progress: &dyn Fn(&str),
) -> Result<BenchReport> {
    let min = Duration::from_millis(if quick { 300 } else { 1500 });
    let kernels = bench_kernels(scene_file, min, progress)?;
    let through = bench_pipeline(scene_file, quick, progress)?;
    let times = bench_methods(scene_file, quick, progress)?;
    let [pw, ph] = through.sensor;
    let [mw, mh] = times.sensor;

    progress("peers: NumPy look-up table and SciPy least_squares (Python)");
    let peers = crate::lab::peers::run(&times.scene, if quick { 100 } else { 1000 });
    // The peers are given the index: so is filmscope for their ratios.
    progress("filmscope with the index given, on the peers' sweep");
    let given = measure_index_given(&times.scene)?;
    let given_s = given.seconds_per_mpix;
    let filmscope_s = times.time("filmscope");
    let speedup_vs_numpy_lut = crate::lab::peers::speedup(peers.numpy_lut.as_ref(), given_s);
    let speedup_vs_scipy = crate::lab::peers::speedup(peers.scipy.as_ref(), given_s);
    let speedup_vs_numpy_lut_index_fitted =
        crate::lab::peers::speedup(peers.numpy_lut.as_ref(), filmscope_s);

    progress("peak memory (child process)");
    let (rw, rh, ra) = if quick {
        (1024, 1024, 2)
    } else {
        (2048, 2048, 5)
    };
    let (rss, rss_error) = either(rss_in_child(scene_file, rw, rh, ra));
    let (rss_12mp, rss_12mp_error) = if quick {
        (None, None)
    } else {
        progress("peak memory of a 12 MP sweep (child process)");
        either(rss_in_child(scene_file, 4096, 3000, 5))
    };
    let (ew, eh) = if quick { (256, 256) } else { (1024, 1024) };
    progress("end to end: filmscope estimate on a raw capture on disk (child processes)");
    let (end_to_end, end_to_end_error) = either(end_to_end(scene_file, ew, eh));
    let mpix = (ew * eh) as f64 / 1e6;
    let mut notes = Vec::new();
    if quick {
        notes.push(format!(
            "--quick: end to end on a {ew}x{eh} capture (not 1024x1024); peak RSS of a 1024x1024 x 2-angle sweep (peak_rss_mb_4mp and peak_rss_mb_12mp not measured); pipeline {pw}x{ph}; methods {mw}x{mh}"
        ));
    }
    let (speedup_vs_brute, speedup_vs_paper) = (
        times.time("brute") / filmscope_s,
        times.time("paper") / filmscope_s,
    );
    let mut methods = times.methods;
    methods.push(given);
    progress("inspect: last row to verdict published (firmware-sim, demo recipe)");
    let (inspect_latency_ms, inspect_latency_error) =
        either(inspect_latency(None, if quick { 3 } else { 10 }));
    Ok(BenchReport {
        quick,
        scene: kernels.scene,
        tracker_samples_per_s_per_core: kernels.tracker,
        stream_samples_per_s_per_core: kernels.stream,
        wide_simd: filmscope_core::simd::has_avx2_fma(),
        tracker_portable_samples_per_s_per_core: kernels.tracker_portable,
        stream_portable_samples_per_s_per_core: kernels.stream_portable,
        pipeline_samples_per_s: through.pipeline,
        pipeline_from_camera_samples_per_s: through.from_camera,
        simulate_samples_per_s: through.simulate,
        simulate_sensor: through.simulate_sensor,
        solve_pixels_per_s_per_core: kernels.solve,
        latency_ms_per_mpix: through.latency,
        latency_parts_ms_per_mpix: through.latency_parts,
        pipeline_sensor: through.sensor,
        state_bytes_per_pixel: state_bytes_per_pixel(
            IndexSampling::for_sensor(rw, rh, INDEX_PIXELS),
            rw,
        ),
        state_sensor: [rw, rh],
        end_to_end_s_per_mpix: end_to_end.as_ref().map(|e| e.filmscope_seconds / mpix),
        end_to_end_paper_s_per_mpix: end_to_end
            .as_ref()
            .and_then(|e| e.paper_seconds)
            .map(|s| s / mpix),
        end_to_end,
        end_to_end_error,
        peak_rss_mb_4mp: rss.as_ref().filter(|_| !quick).map(|r| r.peak_rss_mb),
        peak_rss_mb_12mp: rss_12mp.as_ref().map(|r| r.peak_rss_mb),
        rss,
        rss_error,
        rss_12mp,
        rss_12mp_error,
        notes,
        methods,
        methods_sensor: times.sensor,
        brute_sensor: times.brute_sensor,
        speedup_vs_brute,
        speedup_vs_paper,
        speedup_vs_numpy_lut,
        speedup_vs_numpy_lut_index_fitted,
        speedup_vs_scipy,
        peers,
        inspect_latency_ms,
        inspect_latency_error,
    })
}

/// The bench table's rows: name, measured value, target.
struct Table(String);

impl Table {
    fn row(&mut self, name: &str, value: String, target: &str) {
        self.0
            .push_str(&format!("{name:<44} {value:>14}   {target}\n"));
    }
}

fn mega(x: f64) -> String {
    format!("{:.1} M", x / 1e6)
}

/// The kernels', the pipeline's and the software camera's rates, the latency, the state.
fn rate_rows(t: &mut Table, r: &BenchReport) {
    let (m, k) = (mega, |x: f64| format!("{:.0} k", x / 1e3));
    t.row(
        "tracker, samples/s per core",
        m(r.tracker_samples_per_s_per_core),
        ">= 200 M",
    );
    t.row(
        "tracker + sums, samples/s per core",
        m(r.stream_samples_per_s_per_core),
        "",
    );
    t.row(
        "  both, portable build (no AVX2), per core",
        format!(
            "{:.0} / {:.0} M",
            r.tracker_portable_samples_per_s_per_core / 1e6,
            r.stream_portable_samples_per_s_per_core / 1e6
        ),
        if r.wide_simd {
            "(above: AVX2 + FMA)"
        } else {
            "(CPU without AVX2: same)"
        },
    );
    t.row(
        &format!(
            "pipeline, 2 workers, samples/s ({}x{})",
            r.pipeline_sensor[0], r.pipeline_sensor[1]
        ),
        m(r.pipeline_samples_per_s),
        ">= 150 M",
    );
    t.row(
        "pipeline from the software camera, samples/s",
        m(r.pipeline_from_camera_samples_per_s),
        "(camera-bound)",
    );
    t.row(
        &format!(
            "software camera alone, samples/s ({}x{})",
            r.simulate_sensor[0], r.simulate_sensor[1]
        ),
        m(r.simulate_samples_per_s),
        ">= 50 M",
    );
    t.row(
        "solve, pixels/s per core (whole sweep)",
        k(r.solve_pixels_per_s_per_core),
        ">= 200 k",
    );
    t.row(
        "latency last row -> maps (paced), ms per Mpix",
        format!("{:.1}", r.latency_ms_per_mpix),
        "<= 50",
    );
    let [drain, tally, results, sums, update, ties] = r.latency_parts_ms_per_mpix;
    t.row(
        "  drain/tally/results/sums/update/ties",
        format!("{drain:.0}/{tally:.0}/{results:.0}/{sums:.0}/{update:.0}/{ties:.0}"),
        "",
    );
    let [sw, sh] = r.state_sensor;
    t.row(
        &format!("state, bytes per pixel ({sw}x{sh})"),
        r.state_bytes_per_pixel.to_string(),
        "(fixed in bands, angles, sweeps)",
    );
}

/// Peak resident memory of the child sweeps.
fn memory_rows(t: &mut Table, r: &BenchReport) {
    match (&r.rss, &r.rss_error) {
        (Some(x), _) => t.row(
            &format!(
                "peak RSS, {}x{} x {} bands x {} angles, MB",
                x.width, x.height, x.bands, x.angles
            ),
            format!("{:.0}", x.peak_rss_mb),
            if r.quick {
                "<= 450 (4 MP, 161 x 5; --quick: smaller)"
            } else {
                "<= 450 (4 MP, 161 x 5)"
            },
        ),
        (None, Some(e)) => t.row("peak RSS", "failed".into(), e),
        _ => {}
    }
    match (&r.rss_12mp, &r.rss_12mp_error) {
        (Some(x), _) => t.row(
            &format!(
                "peak RSS, {}x{} x {} bands x {} angles, MB",
                x.width, x.height, x.bands, x.angles
            ),
            format!("{:.0}", x.peak_rss_mb),
            "<= 1536 (12 MP, 161 x 5)",
        ),
        (None, Some(e)) => t.row("peak RSS, 12 MP", "failed".into(), e),
        _ => t.row("peak RSS, 12 MP", "-".into(), "(not measured with --quick)"),
    }
}

/// End to end from a capture on disk, filmscope and the paper's method.
fn end_to_end_rows(t: &mut Table, r: &BenchReport) {
    match (&r.end_to_end, &r.end_to_end_error) {
        (Some(e), _) => {
            let mpix = (e.width * e.height) as f64 / 1e6;
            let target = format!(
                "<= 10 ({}x{} x {} x {} raw BIL{})",
                e.width,
                e.height,
                e.bands,
                e.angles,
                if r.quick { "; --quick: not 1 MP" } else { "" }
            );
            t.row(
                "end to end from disk, s per Mpix",
                format!("{:.2}", e.filmscope_seconds / mpix),
                &target,
            );
            t.row(
                "  paper method, same capture, s per Mpix",
                e.paper_seconds
                    .map_or_else(|| "failed".into(), |s| format!("{:.2}", s / mpix)),
                e.paper_error
                    .as_deref()
                    .unwrap_or("(slower than filmscope's)"),
            );
        }
        (None, Some(e)) => t.row("end to end from disk", "failed".into(), e),
        _ => {}
    }
}

/// Speed-ups over the baselines and the peers, and the line's inspect latency.
fn speedup_rows(t: &mut Table, r: &BenchReport) {
    t.row(
        "speedup vs brute (s per Mpix)",
        format!("{:.0}x", r.speedup_vs_brute),
        ">= 100x",
    );
    t.row(
        "speedup vs paper (s per Mpix)",
        format!("{:.1}x", r.speedup_vs_paper),
        "",
    );
    let times = |x: Option<f64>| x.map_or_else(|| "-".into(), |x| format!("{x:.0}x"));
    t.row(
        "speedup vs NumPy LUT / SciPy (n given to all)",
        format!(
            "{} / {}",
            times(r.speedup_vs_numpy_lut),
            times(r.speedup_vs_scipy)
        ),
        ">= 20x / 200x",
    );
    t.row(
        "  vs NumPy LUT, filmscope fitting n itself",
        times(r.speedup_vs_numpy_lut_index_fitted),
        "",
    );
    match (&r.inspect_latency_ms, &r.inspect_latency_error) {
        (Some(l), _) if !l.is_empty() => {
            let mut v = l.clone();
            v.sort_by(f64::total_cmp);
            let target = format!("(median / max of {}; 32x24 sim)", v.len());
            t.row(
                "inspect, last row -> verdict published, ms",
                format!("{:.0} / {:.0}", v[v.len() / 2], v[v.len() - 1]),
                &target,
            );
        }
        (_, Some(e)) => t.row("inspect latency", "failed".into(), e),
        _ => {}
    }
}

/// The methods' table (time, index and thickness errors, valid pixels), the peers', notes.
fn methods_table(s: &mut String, r: &BenchReport) {
    s.push_str(&format!(
        "{:<18} {:>12} {:>10} {:>10} {:>7} {:>9}\n",
        "method", "s per Mpix", "|n err|", "MAE nm", "valid", "sensor"
    ));
    for f in &r.methods {
        let opt = |x: f64, d: usize| {
            if x.is_finite() {
                format!("{x:.d$}")
            } else {
                "-".into()
            }
        };
        let [w, h] = if f.label == "brute" {
            r.brute_sensor
        } else {
            r.methods_sensor
        };
        s.push_str(&format!(
            "{:<18} {:>12.3} {:>10} {:>10} {:>6.1}% {:>9}\n",
            f.label,
            f.seconds_per_mpix,
            opt(f.index_error_abs, 4),
            opt(f.thickness_mae_nm, 2),
            100.0 * f.valid_fraction,
            format!("{w}x{h}")
        ));
    }
    s.push_str(&crate::lab::peers::table_rows(&r.peers));
    for n in &r.notes {
        s.push_str(&format!("note: {n}\n"));
    }
}

/// The report as a table.
pub fn format_table(r: &BenchReport) -> String {
    let mut t = Table(String::new());
    t.row("figure", "measured".into(), "target");
    rate_rows(&mut t, r);
    memory_rows(&mut t, r);
    end_to_end_rows(&mut t, r);
    speedup_rows(&mut t, r);
    let mut s = t.0;
    s.push('\n');
    methods_table(&mut s, r);
    s
}

/// Writes a bench run's table and JSON as `dir/YYYY-MM-DD.md` and `.json` (today's UTC
/// date; the Markdown titled by the command, `quick` or not); returns both paths.
pub fn write_dated(dir: &Path, quick: bool, table: &str, json: &str) -> Result<(PathBuf, PathBuf)> {
    std::fs::create_dir_all(dir).map_err(LabError::file(dir, "create"))?;
    let date = crate::io::utc_date(std::time::SystemTime::now());
    let md = dir.join(format!("{date}.md"));
    let what = if quick {
        "filmscope bench --quick"
    } else {
        "filmscope bench"
    };
    let body = format!("# {what}, {date}\n\n```text\n{table}```\n");
    crate::io::write_atomic(&md, body.as_bytes()).map_err(LabError::file(&md, "write"))?;
    let js = dir.join(format!("{date}.json"));
    crate::io::write_atomic(&js, format!("{json}\n").as_bytes())
        .map_err(LabError::file(&js, "write"))?;
    Ok((md, js))
}

#[cfg(test)]
mod tests {
    /// The dated bench file's table is the table of its JSON, as `format_table` writes it.
    #[test]
    fn the_dated_table_is_its_jsons() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/bench");
        let json = std::fs::read_to_string(dir.join("2026-11-28.json")).expect("bench JSON");
        let md = std::fs::read_to_string(dir.join("2026-11-28.md")).expect("bench table");
        let report: super::BenchReport = serde_json::from_str(&json).expect("a bench report");
        let table = super::format_table(&report);
        assert!(md.contains(&table), "{table}");
    }
}
