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
//!   (a camera slower than the pipeline: nothing queued).
//! - `methods`: `filmscope`, `paper` and `brute` on the same sweep (128 x 96, 48 x 32 with
//!   `--quick`), seconds per megapixel and their accuracy.
//! - With `FILMSCOPE_BENCH_STREAM_ROWS=N` set, the `stream` figure is also measured with the
//!   kernel sweep's rows repeated to N rows (printed to stderr): whether the state still fits
//!   the caches shows in the difference.
//! - `rss`: a child process runs one sweep of a large sensor (2048 x 2048 x 161 bands x 5
//!   angles unless `--quick`) and reports its peak resident memory (`VmHWM`).

use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context, Result};
use filmscope_core::solve::fit_row::{IndexSampling, INDEX_PIXELS};
use filmscope_core::solve::shard::PixelResult;
use filmscope_core::solve::{state_bytes_per_pixel, SweepSolver};
use filmscope_core::track::row::{blocks_for, push_row, TrackerLanes};
use filmscope_core::track::ExtremaHead;
use firmware_sim::{Scene, SoftwareCamera};
use serde::Serialize;

use crate::cli::chart::{measure, Point, Setting};
use crate::estimate::method::Method;
use crate::estimate::RunConfig;
use crate::pipeline::{run_sweep, BandModels, PipelineConfig, Prior, PriorUpdate, ShardState};
use crate::source::{Frames, ReplaySource, SimSource};

/// `scene_path` with its sensor resized (the thickness map is regenerated at the new size)
/// and, if given, its bands replaced by `[first, last, step]` nm.
pub fn scene_with(
    scene_path: &Path,
    width: usize,
    height: usize,
    bands: Option<[f64; 3]>,
) -> Result<Scene> {
    let text = std::fs::read_to_string(scene_path)
        .with_context(|| format!("{}: cannot read", scene_path.display()))?;
    let mut doc: toml::Table = text
        .parse()
        .with_context(|| format!("{}: not TOML", scene_path.display()))?;
    let sensor = doc
        .entry("sensor")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let Some(t) = sensor.as_table_mut() {
        t.insert("width".into(), toml::Value::Integer(width as i64));
        t.insert("height".into(), toml::Value::Integer(height as i64));
    }
    if let (Some(b), Some(rig)) = (bands, doc.get_mut("rig").and_then(|r| r.as_table_mut())) {
        rig.insert(
            "bands_nm".into(),
            toml::Value::Array(b.iter().map(|&x| toml::Value::Float(x)).collect()),
        );
    }
    let name = scene_path
        .file_stem()
        .map_or_else(|| "scene".into(), |s| s.to_string_lossy().into_owned());
    Scene::from_toml(&doc.to_string(), &name)
        .map_err(|e| anyhow!("{}: {}", scene_path.display(), e.problem))
}

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
            .map_err(|e| anyhow!("{e}"))?;
        let out = run_sweep(&mut source, config, prior.take(), &|_| {})
            .map_err(|e| anyhow!("sweep {i}: {e}"))?;
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

/// The child's side of the RSS measurement: one sweep of `scene_path` resized, printed as
/// JSON on stdout.
pub fn rss_child(scene_path: &Path, width: usize, height: usize, angles: usize) -> Result<()> {
    let mut scene = scene_with(scene_path, width, 1, Some([400.0, 720.0, 2.0]))?;
    scene.angles_deg.truncate(angles.max(1));
    let frames = Arc::new(Frames::render(&scene, 1).map_err(|e| anyhow!(e))?);
    let before = status_mb("VmRSS:").unwrap_or(f64::NAN);
    let mut source = ReplaySource::new(frames.clone(), height, 16);
    let t0 = Instant::now();
    let out = run_sweep(&mut source, PipelineConfig::default(), None, &|_| {})
        .map_err(|e| anyhow!("{e}"))?;
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

fn rss_in_child(
    scene_path: &Path,
    width: usize,
    height: usize,
    angles: usize,
) -> Result<RssFigures> {
    let exe = std::env::current_exe().context("cannot find the filmscope executable")?;
    let out = Command::new(exe)
        .args(["bench-rss-child", &scene_path.to_string_lossy()])
        .args([width.to_string(), height.to_string(), angles.to_string()])
        .output()
        .context("cannot start the memory-measuring child")?;
    if !out.status.success() {
        return Err(anyhow!(
            "memory-measuring child failed: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().last().unwrap_or_default();
    Ok(serde_json::from_str(line)?)
}

/// Everything `filmscope bench` measures.
#[derive(Clone, Debug, Serialize)]
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
    /// The whole pipeline on two workers from a replayed source.
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
    /// Time from the last row to the maps, per megapixel, ms.
    pub latency_ms_per_mpix: f64,
    /// Its parts, ms per megapixel: rows still queued (drain), tally, the results'
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
    /// Peak memory of a large sweep.
    pub rss: Option<RssFigures>,
    /// Why the memory figure is missing, if it is.
    pub rss_error: Option<String>,
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
    /// filmscope's, on the methods' capture; `None` when the peer did not run (`peers.note`).
    pub speedup_vs_numpy_lut: Option<f64>,
    /// The same for the per-pixel SciPy `least_squares` fit.
    pub speedup_vs_scipy: Option<f64>,
    /// The Python peers' figures ([`crate::cli::peers`]).
    pub peers: crate::cli::peers::Peers,
    /// `filmscope inspect` on firmware-sim (config/rig.toml, demo recipe): last row to
    /// verdict published, ms, per sample.
    pub inspect_latency_ms: Option<Vec<f64>>,
    /// Why the inspect latency is missing, if it is.
    pub inspect_latency_error: Option<String>,
}

/// Runs every measurement. `scene_path` gives the spectra (the paper's MgF2 sample by default).
pub fn run_bench(scene_path: &Path, quick: bool, progress: &dyn Fn(&str)) -> Result<BenchReport> {
    let min = Duration::from_millis(if quick { 300 } else { 1500 });
    // Kernels: 256 x 32 pixels, every band and angle.
    progress("rendering spectra");
    let kernel_scene = scene_with(scene_path, 256, 32, None)?;
    let kernel = Frames::render(&kernel_scene, 32).map_err(|e| anyhow!(e))?;
    progress("tracker");
    let tracker = tracker_rate(&kernel, min, true);
    let tracker_portable = tracker_rate(&kernel, min, false);
    progress("stream and solve");
    let (stream, solve) = sweep_rates(&kernel, kernel.rows, true);
    let (stream_portable, _) = sweep_rates(&kernel, kernel.rows, false);
    if std::env::var_os("FILMSCOPE_BENCH_STREAM_ROWS").is_some() {
        let rows: usize = std::env::var("FILMSCOPE_BENCH_STREAM_ROWS")?.parse()?;
        let (big, _) = sweep_rates(&kernel, rows, true);
        eprintln!("stream 256x{rows}: {:.1} M samples/s", big / 1e6);
    }

    // Pipeline: a wide sensor, rows replayed.
    let (pw, ph) = if quick { (512, 256) } else { (1024, 1024) };
    progress("pipeline");
    let pipe_scene = scene_with(scene_path, pw, 16, None)?;
    let frames = Arc::new(Frames::render(&pipe_scene, 16).map_err(|e| anyhow!(e))?);
    let mut source = ReplaySource::new(frames.clone(), ph, 16);
    let out = run_sweep(&mut source, PipelineConfig::default(), None, &|_| {})
        .map_err(|e| anyhow!("{e}"))?;
    let pipeline = out.samples as f64 / out.stream_time.as_secs_f64();
    // Latency: the same sweep from a camera at half that rate, so no rows queue up (at full
    // speed the last row waits behind the queued ones: that is throughput, counted above).
    progress("latency (camera at half the pipeline's rate)");
    // Streamed once, as from a live camera: the index refitted on the sample as each angle
    // completes, the last angle's refit included in the latency.
    let mut paced = ReplaySource::new(frames, ph, 16).paced(0.5 * pipeline);
    let live = RunConfig {
        one_pass: true,
        ..RunConfig::default()
    };
    let slow = crate::estimate::filmscope_passes(&mut paced, &live, &|_| {})
        .map_err(|e| anyhow!("{e}"))?
        .out;
    let per_mpix = |d: Duration| d.as_secs_f64() * 1e3 / ((pw * ph) as f64 / 1e6);
    let latency = per_mpix(slow.solve_latency);
    let lp = slow.latency_parts;
    let latency_parts = [lp.drain, lp.tally, lp.results, lp.sums, lp.update, lp.ties].map(per_mpix);

    progress("pipeline from the software camera");
    let cam_scene = scene_with(scene_path, 128, if quick { 32 } else { 96 }, None)?;
    let mut sim =
        SimSource::new(SoftwareCamera::new(cam_scene), false, 8).map_err(|e| anyhow!("{e}"))?;
    let cam = run_sweep(&mut sim, PipelineConfig::default(), None, &|_| {})
        .map_err(|e| anyhow!("{e}"))?;
    let from_camera = cam.samples as f64 / cam.stream_time.as_secs_f64();
    progress("software camera alone");
    let (sim_w, sim_h) = if quick { (512, 32) } else { (1024, 64) };
    let simulate =
        crate::simulate::camera_samples_per_s(&scene_with(scene_path, sim_w, sim_h, None)?, sim_h);

    progress("methods");
    // Large enough that per-megapixel times are the methods' own, not their fixed costs (the
    // sample fit, the band models' tables, thread start-up: at 128 x 96 filmscope's sample
    // fit was half its time); brute force, whose time is all per pixel, on a smaller one.
    let (mw, mh) = if quick { (64, 48) } else { (256, 192) };
    let (bw, bh) = if quick { (48, 32) } else { (128, 96) };
    let methods_scene = |w: usize, h: usize| -> Result<Scene> {
        let mut m_scene = scene_with(scene_path, w, h, None)?;
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
    let time = |m: &str| {
        methods
            .iter()
            .find(|f| f.label == m)
            .map_or(f64::NAN, |f| f.seconds_per_mpix)
    };

    progress("peers: NumPy look-up table and SciPy least_squares (Python)");
    let peers = crate::cli::peers::run(&m_scene, if quick { 100 } else { 1000 });
    let filmscope_s = time("filmscope");
    let speedup_vs_numpy_lut = crate::cli::peers::speedup(peers.numpy_lut.as_ref(), filmscope_s);
    let speedup_vs_scipy = crate::cli::peers::speedup(peers.scipy.as_ref(), filmscope_s);

    progress("peak memory (child process)");
    let (rw, rh, ra) = if quick {
        (1024, 1024, 2)
    } else {
        (2048, 2048, 5)
    };
    let (rss, rss_error) = match rss_in_child(scene_path, rw, rh, ra) {
        Ok(r) => (Some(r), None),
        Err(e) => (None, Some(e.to_string())),
    };
    let (speedup_vs_brute, speedup_vs_paper) = (
        time("brute") / time("filmscope"),
        time("paper") / time("filmscope"),
    );
    progress("inspect: last row to verdict published (firmware-sim, demo recipe)");
    let (inspect_latency_ms, inspect_latency_error) = match crate::line::inspect::bench_latency(
        Path::new("config/rig.toml"),
        if quick { 3 } else { 10 },
    ) {
        Ok(l) => (Some(l), None),
        Err(e) => (None, Some(e.to_string())),
    };
    Ok(BenchReport {
        quick,
        scene: kernel_scene.name.clone(),
        tracker_samples_per_s_per_core: tracker,
        stream_samples_per_s_per_core: stream,
        wide_simd: filmscope_core::simd::has_avx2_fma(),
        tracker_portable_samples_per_s_per_core: tracker_portable,
        stream_portable_samples_per_s_per_core: stream_portable,
        pipeline_samples_per_s: pipeline,
        pipeline_from_camera_samples_per_s: from_camera,
        simulate_samples_per_s: simulate,
        simulate_sensor: [sim_w, sim_h],
        solve_pixels_per_s_per_core: solve,
        latency_ms_per_mpix: latency,
        latency_parts_ms_per_mpix: latency_parts,
        pipeline_sensor: [pw, ph],
        state_bytes_per_pixel: state_bytes_per_pixel(
            IndexSampling::for_sensor(rw, rh, INDEX_PIXELS),
            rw,
        ),
        state_sensor: [rw, rh],
        rss,
        rss_error,
        methods,
        methods_sensor: [mw, mh],
        brute_sensor: [bw, bh],
        speedup_vs_brute,
        speedup_vs_paper,
        speedup_vs_numpy_lut,
        speedup_vs_scipy,
        peers,
        inspect_latency_ms,
        inspect_latency_error,
    })
}

/// The report as a table.
pub fn format_table(r: &BenchReport) -> String {
    let m = |x: f64| format!("{:.1} M", x / 1e6);
    let k = |x: f64| format!("{:.0} k", x / 1e3);
    let mut s = String::new();
    let mut row = |name: &str, value: String, target: &str| {
        s.push_str(&format!("{name:<44} {value:>14}   {target}\n"));
    };
    row("figure", "measured".into(), "target");
    row(
        "tracker, samples/s per core",
        m(r.tracker_samples_per_s_per_core),
        ">= 200 M",
    );
    row(
        "tracker + sums, samples/s per core",
        m(r.stream_samples_per_s_per_core),
        "",
    );
    row(
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
    row(
        &format!(
            "pipeline, 2 workers, samples/s ({}x{})",
            r.pipeline_sensor[0], r.pipeline_sensor[1]
        ),
        m(r.pipeline_samples_per_s),
        ">= 150 M",
    );
    row(
        "pipeline from the software camera, samples/s",
        m(r.pipeline_from_camera_samples_per_s),
        "(camera-bound)",
    );
    row(
        &format!(
            "software camera alone, samples/s ({}x{})",
            r.simulate_sensor[0], r.simulate_sensor[1]
        ),
        m(r.simulate_samples_per_s),
        ">= 50 M",
    );
    row(
        "solve, pixels/s per core (whole sweep)",
        k(r.solve_pixels_per_s_per_core),
        ">= 200 k",
    );
    row(
        "latency last row -> maps (paced), ms per Mpix",
        format!("{:.1}", r.latency_ms_per_mpix),
        "<= 50",
    );
    let [drain, tally, results, sums, update, ties] = r.latency_parts_ms_per_mpix;
    row(
        "  drain/tally/results/sums/update/ties",
        format!("{drain:.0}/{tally:.0}/{results:.0}/{sums:.0}/{update:.0}/{ties:.0}"),
        "",
    );
    let [sw, sh] = r.state_sensor;
    row(
        &format!("state, bytes per pixel ({sw}x{sh})"),
        r.state_bytes_per_pixel.to_string(),
        "<= 64",
    );
    match (&r.rss, &r.rss_error) {
        (Some(x), _) => row(
            &format!(
                "peak RSS, {}x{} x {} bands x {} angles, MB",
                x.width, x.height, x.bands, x.angles
            ),
            format!("{:.0}", x.peak_rss_mb),
            "<= 400 (4 MP, 161 x 5)",
        ),
        (None, Some(e)) => row("peak RSS", "failed".into(), e),
        _ => {}
    }
    row(
        "speedup vs brute (s per Mpix)",
        format!("{:.0}x", r.speedup_vs_brute),
        ">= 100x",
    );
    row(
        "speedup vs paper (s per Mpix)",
        format!("{:.1}x", r.speedup_vs_paper),
        "",
    );
    let times = |x: Option<f64>| x.map_or_else(|| "-".into(), |x| format!("{x:.0}x"));
    row(
        "speedup vs NumPy LUT / SciPy (Python peers)",
        format!(
            "{} / {}",
            times(r.speedup_vs_numpy_lut),
            times(r.speedup_vs_scipy)
        ),
        ">= 20x / 200x",
    );
    match (&r.inspect_latency_ms, &r.inspect_latency_error) {
        (Some(l), _) if !l.is_empty() => {
            let mut v = l.clone();
            v.sort_by(f64::total_cmp);
            let target = format!("(median / max of {}; 32x24 sim)", v.len());
            row(
                "inspect, last row -> verdict published, ms",
                format!("{:.0} / {:.0}", v[v.len() / 2], v[v.len() - 1]),
                &target,
            );
        }
        (_, Some(e)) => row("inspect latency", "failed".into(), e),
        _ => {}
    }
    s.push('\n');
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
    s.push_str(&crate::cli::peers::table_rows(&r.peers));
    s
}
