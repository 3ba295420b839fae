//! The commands behind the command line.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use clap::ValueEnum as _;
use firmware_sim::random::Draw;
use firmware_sim::{Scene, SoftwareCamera};

use super::progress::{rows_bar, Progress};
use filmscope::appearance::gltf;
use filmscope::appearance::{
    compare::{compare_stream, open_capture},
    render::{render_png, RenderOptions},
    SampleFilm,
};
use filmscope::estimate::baseline::BruteGrid;
use filmscope::estimate::method::Method;
use filmscope::estimate::FieldConfig;
use filmscope::estimate::{Run, RunConfig};
use filmscope::io::{write_atomic, ByteOrder, Interleave};
use filmscope::jobs;
use filmscope::lab::eval::{evaluate, Ablation, Truth};
use filmscope::lab::scene::{SceneFile, PAPER_SCENES};
use filmscope::pipeline::PipelineConfig;
use filmscope::simulate::{write_capture, SimulateOptions};
use filmscope::source::{SimSource, Source};
use filmscope_core::colour::Illuminant;
use filmscope_core::optics::{FieldOfView, Polarization};
use filmscope_core::solve::sweep::SolverOptions;

/// The paper's Table 1: estimated index, thickness error (nm), mean dE*ab, RMSE.
const PAPER_TABLE: [(f64, f64, f64, f64); 3] = [
    (1.374, 30.0, 0.72, 0.04),
    (1.367, 49.0, 1.21, 0.07),
    (2.674, 41.0, 5.63, 0.18),
];

impl super::MethodArgs {
    /// The run configuration these arguments give, with `pipeline` and the wide field
    /// model's settings `wide`; every value checked.
    fn run_config(&self, pipeline: PipelineConfig, wide: FieldConfig) -> Result<RunConfig> {
        check_index_args(self.index)?;
        if let Some(m) = self.index.model_error {
            if let Some(p) = filmscope::io::capture::model_error_problem(m) {
                bail!("--model-error {m}: {p}");
            }
        }
        if let Some(t) = self.index.rig_tolerance {
            if let Some(p) = filmscope::io::capture::rig_tolerance_problem(t) {
                bail!("--rig-tolerance {t}: {p}");
            }
        }
        filmscope::limits::check_cli(
            pipeline.workers,
            pipeline.channel_capacity,
            self.index_pixels,
            self.brute_index_steps,
            self.brute_thickness_step,
        )
        .map_err(|e| anyhow!(e))?;
        Ok(RunConfig {
            method: self.method,
            model_error: self.index.model_error,
            rig_tolerance: self.index.rig_tolerance,
            pipeline: PipelineConfig {
                solver: SolverOptions {
                    index_pixels: self.index_pixels,
                    ..pipeline.solver
                },
                ..pipeline
            },
            brute_grid: BruteGrid {
                index_steps: self.brute_index_steps,
                thickness_step_nm: self.brute_thickness_step,
            },
            field: FieldConfig {
                choice: self.field,
                strips: self.field_strips,
                ..wide
            },
            sample_sites: self.index.sample_sites,
            one_pass: self.index.one_pass,
        })
    }
}

fn run_with_bar(source: &mut dyn Source, config: &RunConfig, label: &str) -> Result<Run> {
    run_in_field_with_bar(source, config, None, label)
}

fn run_in_field_with_bar(
    source: &mut dyn Source,
    config: &RunConfig,
    field_of_view: Option<FieldOfView>,
    label: &str,
) -> Result<Run> {
    let settings = jobs::Settings {
        config: *config,
        film: None,
    };
    Ok(jobs::estimate::run(
        source,
        &settings,
        field_of_view,
        label,
        &Progress::new(),
    )?)
}

/// `filmscope simulate`.
pub fn simulate(
    scene_path: &Path,
    out: &Path,
    noise_free: bool,
    (interleave, byte_order): (Interleave, ByteOrder),
    seed: Option<u64>,
) -> Result<()> {
    let scene = Scene::load_seeded(scene_path, seed)?;
    let total = (scene.angles_deg.len() * scene.bands_nm.len() * scene.sensor.height) as u64;
    let bar = rows_bar(total, &scene.name);
    let toml = write_capture(
        &scene,
        out,
        SimulateOptions {
            noise_free,
            interleave,
            byte_order,
            float_reflectance: false,
        },
        &|n| bar.inc(n),
    )?;
    bar.finish_and_clear();
    println!(
        "wrote {} ({}x{} px, {} bands, {} angles)",
        toml.display(),
        scene.sensor.width,
        scene.sensor.height,
        scene.bands_nm.len(),
        scene.angles_deg.len()
    );
    Ok(())
}

/// `--sample-sites` must hold enough sites to fit an index and no more than the fit holds.
fn check_index_args(index: super::IndexArgs) -> Result<()> {
    let max = filmscope_core::solve::sample::MAX_SITES;
    if !(4..=max).contains(&index.sample_sites) {
        bail!("--sample-sites {}: must be 4 to {max}", index.sample_sites);
    }
    Ok(())
}

/// The `--max-memory` budget, if given.
fn memory_budget(max_memory: Option<&str>) -> Result<Option<u64>> {
    max_memory
        .map(filmscope::limits::parse_bytes)
        .transpose()
        .map_err(|e| anyhow!(e))
}

/// `filmscope estimate` ([`jobs::estimate::estimate_capture`]) with a bar and its lines.
pub fn estimate(
    capture: &Path,
    out: &Path,
    method: &super::MethodArgs,
    (workers, channel_capacity): (usize, usize),
    max_memory: Option<&str>,
    film_index: Option<&str>,
) -> Result<()> {
    let pipeline = PipelineConfig {
        workers,
        channel_capacity,
        ..PipelineConfig::default()
    };
    let config = method.run_config(pipeline, FieldConfig::default())?;
    let film = film_index
        .map(|m| {
            filmscope::material::from_arg(m)
                .map(|dispersion| jobs::GivenIndex {
                    name: m.to_owned(),
                    dispersion,
                })
                .map_err(|e| anyhow!("--film-index {m:?}: {e}"))
        })
        .transpose()?;
    let request = jobs::EstimateRequest {
        capture: capture.to_path_buf(),
        out: out.to_path_buf(),
        out_option: "--out",
        film_option: "--film-index",
        settings: jobs::Settings { config, film },
        memory_budget: memory_budget(max_memory)?,
    };
    let jobs::Outcome { run, summary } =
        jobs::estimate::estimate_capture(&request, &Progress::new())?;
    for note in &run.result.notes {
        log::info!("filmscope: note: {note}");
    }
    if let Some(line) = field_line(&run) {
        println!("{line}");
    }
    println!(
        "{}: n = {:.4}, thickness median {} nm, valid {:.1} %, {:.2} s; maps in {}",
        request.settings.config.method.name(),
        run.result.index.at(550.0),
        summary
            .thickness_nm
            .median
            .map_or("-".into(), |m| format!("{m:.1}")),
        100.0 * summary.valid_fraction,
        run.seconds,
        out.display()
    );
    Ok(())
}

/// The field model chosen and why, in one line, when the lens's field of view made it a
/// choice (streaming method); a capture without one has a single model to speak of.
fn field_line(run: &Run) -> Option<String> {
    let c = run.field_model_choice.as_ref()?;
    c.geometry.horizontal_fov_deg?;
    let strips = match (c.chosen.as_str(), c.geometry.strips) {
        ("wide", Some(k)) => format!(", {k} strips"),
        _ => String::new(),
    };
    Some(format!(
        "field model: {}{strips} ({}): {}",
        c.chosen, c.requested, c.reason
    ))
}

/// `eval --random`'s set: its size, seed, where to save the drawn scenes, and the rows to
/// run (all when `None`).
pub struct RandomSet {
    /// Scenes in the set.
    pub count: usize,
    /// The set's seed.
    pub seed: u64,
    /// Where the drawn scene files go.
    pub save_scenes: Option<PathBuf>,
    /// The rows to run.
    pub rows: Option<Vec<usize>>,
}

/// `filmscope eval`.
pub fn eval(
    inputs: &[PathBuf],
    random: Option<RandomSet>,
    kind: Draw,
    seed: Option<u64>,
    method: &super::MethodArgs,
    json: bool,
    ablate: &[Ablation],
) -> Result<()> {
    match (inputs.is_empty(), &random) {
        (true, None) => {
            bail!("eval needs at least one scene file or capture directory, or --random N")
        }
        (false, Some(_)) => bail!("eval --random draws its own scenes: give no inputs"),
        _ => {}
    }
    if let (Some(s), None) = (seed, &random) {
        if let Some(cap) = inputs
            .iter()
            .find(|p| !matches!(filmscope::lab::eval::input_kind(p), Some(true)))
        {
            bail!(
                "--seed {s}: {} is not a scene file (a capture's noise is recorded; --seed applies to scene files)",
                cap.display()
            );
        }
    }
    let (solver, wide) = filmscope::lab::eval::ablated(ablate);
    let pipeline = PipelineConfig {
        solver,
        ..PipelineConfig::default()
    };
    let config = method.run_config(pipeline, wide)?;
    if let Some(r) = random {
        return eval_random(
            r.count,
            r.seed,
            &config,
            json,
            r.save_scenes.as_deref(),
            kind,
            r.rows.as_deref(),
        );
    }
    if !json {
        println!(
            "{:<22} {:<9} {:>8} {:>9} {:>8} {:>8} {:>7} {:>8} {:>7} {:>7} {:>7} {:>7}",
            "scene",
            "method",
            "n",
            "n err",
            "MAE nm",
            "RMSE nm",
            "valid",
            "silent",
            "sp.RMSE",
            "dE76",
            "dE00",
            "s"
        );
    }
    // An ablated run is labelled by what was switched off.
    let label = |method: &str| {
        if ablate.is_empty() {
            method.to_owned()
        } else {
            let names: Vec<String> = ablate
                .iter()
                .filter_map(|a| a.to_possible_value())
                .map(|v| v.get_name().to_owned())
                .collect();
            format!("-{}", names.join(",-"))
        }
    };
    for path in inputs {
        let (r, run) = filmscope::lab::eval::eval_one(path, &config, seed, &Progress::new())
            .with_context(|| path.display().to_string())?;
        if json {
            println!("{}", serde_json::to_string(&r)?);
        } else {
            // Runs whose lens has a field of view also say which field model was used.
            let field = match &run.field_model_choice {
                Some(c) if c.geometry.horizontal_fov_deg.is_some() => match c.chosen.as_str() {
                    "wide" => format!(
                        "  wide/{} ({})",
                        c.geometry.strips.unwrap_or(0),
                        c.requested
                    ),
                    model => format!("  {model} ({})", c.requested),
                },
                _ => String::new(),
            };
            println!(
                "{:<22} {:<9} {:>8.4} {:>+9.4} {:>8.2} {:>8.2} {:>6.1}% {:>7.2}% {:>7.4} {:>7.3} {:>7.3} {:>7.2}{field}",
                r.scene,
                label(&r.method),
                r.index_estimated,
                r.index_error,
                r.thickness_mae_nm,
                r.thickness_rmse_nm,
                100.0 * r.valid_fraction,
                100.0 * r.silent_failure_rate,
                r.spectral_rmse,
                r.delta_e76_mean,
                r.delta_e2000_mean,
                r.seconds
            );
        }
    }
    Ok(())
}

/// `filmscope eval --random N --seed S`: the rows as they are done, then the closing line
/// (or, with `json`, one JSON object at the end).
fn eval_random(
    count: usize,
    seed: u64,
    config: &RunConfig,
    json: bool,
    save_scenes: Option<&Path>,
    kind: Draw,
    rows: Option<&[usize]>,
) -> Result<()> {
    if let Some(dir) = save_scenes {
        filmscope::lab::eval::save_random_scenes(dir, count, seed, kind)?;
    }
    let work = filmscope::lab::eval::random_work_dir(seed)?;
    if !json {
        println!("{}", filmscope::lab::eval::RandomRow::table_header());
    }
    let result = filmscope::lab::eval::random_eval(
        count,
        seed,
        config,
        work.path(),
        kind,
        rows,
        &mut |row| {
            if !json {
                println!("{}", row.table_row());
            }
        },
    );
    drop(work);
    if json {
        println!("{}", serde_json::to_string(&result)?);
    } else {
        println!(
            "{} ({:.1} s, seed {seed})",
            result.closing_line(),
            result.seconds
        );
        println!("{}", result.coverage_line());
    }
    Ok(())
}

/// `filmscope acquire`: the rig file checked in full, the output checked against the
/// inputs and the memory needed against the budget, before any device moves. Ctrl-C stops
/// the sweep at the next band and keeps the angles taken.
pub fn acquire(rig: Option<&Path>, out: &Path, sim: bool, max_memory: Option<&str>) -> Result<()> {
    let budget = memory_budget(max_memory)?;
    let config = filmscope::rig::RigConfig::load_or_builtin(rig)?;
    let rig = rig.unwrap_or(Path::new("config/rig.toml"));
    let s = &config.sweep;
    let mut inputs = vec![rig.to_path_buf()];
    inputs.extend(config.sim.as_ref().map(|s| s.scene.clone()));
    filmscope::io::check_outside_inputs("--out", out, &inputs, &[])?;
    let c = &config.camera;
    filmscope::limits::check_memory(
        &format!(
            "{}: camera {} x {} px, {} bands, {} angles",
            rig.display(),
            c.width,
            c.height,
            s.bands().len(),
            s.angles_deg.len()
        ),
        filmscope::limits::run_bytes(
            u64::from(c.width) * u64::from(c.height),
            s.bands().len() as u64,
            s.angles_deg.len() as u64,
            false,
        ),
        budget,
    )
    .map_err(|e| anyhow!(e))?;
    filmscope::source::live::stop_on_ctrl_c().context("signal handler")?;
    let summary = jobs::acquire::run(
        &config,
        out,
        sim,
        &jobs::Settings::default(),
        &Progress::new(),
    )
    .map_err(|e| anyhow!(e))?;
    let lost = summary.acquisition.as_ref().map_or(0, |a| a.link.rows_lost);
    println!(
        "acquired {} angles x {} bands into {}: n = {:.4}, thickness median {:.1} nm, valid {:.1}%, {} row(s) lost on the link",
        s.angles_deg.len(),
        s.bands().len(),
        out.join("capture").display(),
        summary.refractive_index.unwrap_or(f64::NAN),
        summary.thickness_nm.median.unwrap_or(f64::NAN),
        100.0 * summary.valid_fraction,
        lost
    );
    Ok(())
}

/// `filmscope demo`.
pub fn demo(out: &Path, with_paper: bool) -> Result<()> {
    println!("filmscope demo: the paper's three samples on the software rig (raw 12-bit counts, white/dark references, 5 angles x 151 bands), streamed through the pipeline.\n");
    let mut rows = Vec::new();
    for (i, (name, text)) in PAPER_SCENES.iter().enumerate() {
        let scene = Scene::from_toml(text, name)?;
        let truth = Truth::of_scene(&scene);
        let mut source =
            SimSource::new(SoftwareCamera::new(scene.clone()), false, 1).map_err(|e| anyhow!(e))?;
        let run = run_with_bar(&mut source, &RunConfig::default(), name)?;
        let dir = out.join(name);
        jobs::estimate::write(&dir, &run, &format!("software camera, scene {name}"))?;
        let ours = evaluate(name, &truth, &run);
        let theirs = if with_paper {
            let mut source = SimSource::new(SoftwareCamera::new(scene.clone()), false, 1)
                .map_err(|e| anyhow!(e))?;
            let cfg = RunConfig {
                method: Method::Paper,
                ..RunConfig::default()
            };
            let run = run_with_bar(&mut source, &cfg, &format!("{name} (paper)"))?;
            jobs::estimate::write(
                &out.join(format!("{name}-paper")),
                &run,
                &format!("software camera, scene {name}"),
            )?;
            Some(evaluate(name, &truth, &run))
        } else {
            None
        };
        rows.push((i, scene, ours, theirs, run));
    }
    println!(
        "{:<14} {:>7} | {:>22} | {:>22} | {:>14} | {:>14} | {:>7} {:>7} {:>9}",
        "sample",
        "true n",
        "estimated n",
        "thickness error nm",
        "mean dE*ab",
        "spectral RMSE",
        "valid",
        "silent",
        "latency"
    );
    println!("{:<14} {:>7} | {:>6} {:>7} {:>7} | {:>6} {:>7} {:>7} | {:>6} {:>7} | {:>6} {:>7} | {:>7} {:>7} {:>9}", "", "", "paper", "ours", "paper*", "paper", "ours", "paper*", "paper", "ours", "paper", "ours", "", "", "ms");
    for (i, scene, ours, theirs, run) in &rows {
        let (pn, pd, pe, pr) = PAPER_TABLE[*i];
        let star = |v: Option<f64>, p: usize| v.map_or("-".to_owned(), |x| format!("{x:.p$}"));
        println!(
            "{:<14} {:>7.3} | {:>6.3} {:>7.4} {:>7} | {:>6.0} {:>7.2} {:>7} | {:>6.2} {:>7.3} | {:>6.2} {:>7.4} | {:>6.1}% {:>6.2}% {:>9.1}",
            scene.name,
            ours.index_true,
            pn,
            ours.index_estimated,
            star(theirs.as_ref().map(|t| t.index_estimated), 3),
            pd,
            ours.thickness_mae_nm,
            star(theirs.as_ref().map(|t| t.thickness_mae_nm), 1),
            pe,
            ours.delta_e76_mean,
            pr,
            ours.spectral_rmse,
            100.0 * ours.valid_fraction,
            100.0 * ours.silent_failure_rate,
            run.solve_latency_ms.unwrap_or(f64::NAN)
        );
    }
    println!("\npaper = Kobayashi et al., Table 1 (their rig); ours = filmscope on the simulated rig (thickness error: mean absolute error per pixel);");
    if with_paper {
        println!("paper* = the paper's method as implemented in filmscope (`--method paper`), on the same simulated data.");
    } else {
        println!(
            "run `filmscope demo --with-paper` to add the paper's method run on the same data."
        );
    }
    println!(
        "Maps, previews and summary.json per sample in {}",
        out.display()
    );
    Ok(())
}

/// `filmscope bench`.
pub fn bench(scene: &SceneFile, quick: bool, json: bool, out: Option<&Path>) -> Result<()> {
    let report = filmscope::lab::bench::run_bench(scene, quick, &|what| {
        if !json {
            log::info!("bench: {what}");
        }
    })?;
    let table = filmscope::lab::bench::format_table(&report);
    let text = serde_json::to_string(&report)?;
    if json {
        println!("{text}");
    } else {
        print!("{table}");
    }
    if let Some(dir) = out {
        let (md, js) = filmscope::lab::bench::write_dated(dir, quick, &table, &text)?;
        log::info!("bench: wrote {} and {}", md.display(), js.display());
    }
    Ok(())
}

/// `filmscope man`: the manual pages, `filmscope.1` and `filmscope-COMMAND.1` for each
/// command, generated from the command line's own definition into `out`.
pub fn man(out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("{}: cannot create", out.display()))?;
    let cmd = <super::Cli as clap::CommandFactory>::command();
    clap_mangen::generate_to(cmd, out)
        .with_context(|| format!("{}: cannot write", out.display()))?;
    println!("man: pages in {}", out.display());
    Ok(())
}

/// `filmscope soak`: prints one line per tenth sweep and a last line of figures.
pub fn soak(scene: Option<PathBuf>, sweeps: usize) -> Result<()> {
    let scene = scene.map_or(SceneFile::RIG_TINY, SceneFile::Path);
    let scene = filmscope::lab::bench::soak_scene(&scene)?;
    let t0 = std::time::Instant::now();
    let points = filmscope::lab::bench::soak(
        &scene,
        sweeps,
        10,
        filmscope::pipeline::PipelineConfig::default(),
        |p| {
            println!(
                "soak: sweep {}: RSS {:.1} MB (peak {:.1} MB)",
                p.sweep, p.rss_mb, p.peak_rss_mb
            )
        },
    )?;
    if let (Some(first), Some(last)) = (points.first(), points.last()) {
        println!(
            "soak: {sweeps} sweeps in {:.0} s, RSS after sweep {} {:.1} MB, after sweep {} {:.1} MB ({:+.1} MB), peak {:.1} MB",
            t0.elapsed().as_secs_f64(),
            first.sweep,
            first.rss_mb,
            last.sweep,
            last.rss_mb,
            last.rss_mb - first.rss_mb,
            last.peak_rss_mb
        );
    }
    Ok(())
}

/// `filmscope chart`.
pub fn chart(scene: &SceneFile, out: &Path, quick: bool) -> Result<()> {
    let png = filmscope::lab::chart::speed_accuracy(scene, out, quick, &mut |points| {
        for p in points {
            println!(
                "{:<10} {:<12} {:>12.2} s/Mpix  MAE {:>8.2} nm  |n err| {:.4}  valid {:>5.1}%",
                p.method,
                p.label,
                p.seconds_per_mpix,
                p.thickness_mae_nm,
                p.index_error_abs,
                100.0 * p.valid_fraction
            );
        }
    })?;
    println!("wrote {}", png.display());
    Ok(())
}

/// `filmscope stability`.
pub fn stability(out: &Path, quick: bool, only: &[String]) -> Result<()> {
    use filmscope::lab::chart::StabilityStep;
    let done = filmscope::lab::chart::stability(out, quick, only, &mut |step| match step {
        StabilityStep::Measured(run) => print!("{}", filmscope::lab::chart::summary(run)),
        StabilityStep::Wrote(p) => println!("wrote {}", p.display()),
    })?;
    let cells: usize = done
        .runs
        .iter()
        .map(|r| r.cells.len() / done.settings)
        .sum();
    println!(
        "{} maps, {cells} cells x {} settings in {:.0} s",
        done.runs.len(),
        done.settings,
        done.seconds
    );
    Ok(())
}

/// `filmscope stability --cell MAP:X:Y`: the cell's scene file, written into `out`.
pub fn stability_cell(out: &Path, quick: bool, cell: &str, seed: Option<u64>) -> Result<()> {
    let (path, scene) = filmscope::lab::chart::write_cell_scene(out, quick, cell, seed)?;
    println!("wrote {} ({})", path.display(), scene.describe(&[]));
    Ok(())
}

/// `--illuminant`: a name of [`Illuminant::ALL`].
pub(super) fn illuminant(name: &str) -> Result<Illuminant, String> {
    Illuminant::from_name(name).ok_or_else(|| {
        let names: Vec<&str> = Illuminant::ALL.iter().map(|i| i.name()).collect();
        format!("unknown illuminant {name:?}: use {}", names.join(", "))
    })
}

/// `--polarization`: s, p or unpolarized.
pub(super) fn polarization(name: &str) -> Result<Polarization, String> {
    Polarization::from_name(name)
        .ok_or_else(|| format!("unknown polarization {name:?}: use s, p or unpolarized"))
}

/// `filmscope render`.
pub fn render(
    maps: &Path,
    out: &Path,
    angle_deg: f64,
    illuminant: Illuminant,
    exposure: Option<f64>,
    polarization: Option<Polarization>,
    capture: Option<&Path>,
) -> Result<()> {
    if !(0.0..90.0).contains(&angle_deg) {
        bail!("--angle {angle_deg}: the incidence angle must be in [0, 90) degrees");
    }
    if exposure.is_some_and(|e| !(e.is_finite() && e > 0.0)) {
        bail!("--exposure must be a positive number");
    }
    let mut film = SampleFilm::load(maps, capture)?;
    if let Some(p) = polarization {
        film.stack.polarization = p;
    }
    let opts = RenderOptions {
        incidence_deg: angle_deg,
        illuminant,
        exposure,
    };
    let (png, info) = render_png(&film, &opts)?;
    write_atomic(out, &png).with_context(|| format!("{}: cannot write", out.display()))?;
    println!(
        "render: {} at {angle_deg}°, {}, exposure x{:.2}; {}x{} px in {}",
        film.describe(),
        opts.illuminant.name(),
        info.exposure,
        info.width,
        info.height,
        out.display()
    );
    Ok(())
}

/// `filmscope compare`.
pub fn compare(
    maps: &Path,
    out: Option<&Path>,
    ill: Illuminant,
    capture: Option<&Path>,
    envi: bool,
) -> Result<()> {
    let film = SampleFilm::load(maps, capture)?;
    let cap = film.capture.clone().ok_or_else(|| {
        anyhow!(
            "{}: the capture is unknown (pass --capture)",
            maps.join("summary.json").display()
        )
    })?;
    let mut source = open_capture(&cap)?;
    let dir = out.unwrap_or(maps);
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    let (cmp, _) = compare_stream(&film, &mut source, ill, None, envi.then_some(dir))?;
    let png_path = dir.join("compare.png");
    write_atomic(&png_path, &cmp.to_png()?)
        .with_context(|| format!("{}: cannot write", png_path.display()))?;
    if envi {
        for p in cmp.write_envi(dir)? {
            println!("wrote {}", p.display());
        }
    }
    let json_path = dir.join("compare.json");
    let text = serde_json::to_string_pretty(&cmp.record())?;
    write_atomic(&json_path, text.as_bytes())
        .with_context(|| format!("{}: cannot write", json_path.display()))?;
    let (lo, hi) = cmp.colorimetry.range_nm();
    println!(
        "measured vs reproduced, CIEDE2000 over {lo:.0}-{hi:.0} nm under {}:",
        ill.name()
    );
    for a in &cmp.angles {
        println!(
            "  {:>5.1}°  mean {:.3}  p95 {:.3}  ({} px)",
            a.incidence_deg, a.stats.mean, a.stats.p95, a.stats.pixels
        );
    }
    println!(
        "  all     mean {:.3}  p95 {:.3}; {} and {}",
        cmp.overall.mean,
        cmp.overall.p95,
        png_path.display(),
        json_path.display()
    );
    Ok(())
}

/// `filmscope export-gltf`.
pub fn export_gltf(maps: &Path, out: &Path, width_m: f64, capture: Option<&Path>) -> Result<()> {
    if !(width_m.is_finite() && width_m > 0.0) {
        bail!("--width-m must be a positive number of metres");
    }
    let film = SampleFilm::load(maps, capture)?;
    let glb = gltf::film_glb(&film, width_m)?;
    write_atomic(out, &glb.bytes).with_context(|| format!("{}: cannot write", out.display()))?;
    println!(
        "glTF: iridescenceIor {:.4}, thickness {:.1}-{:.1} nm, ior {:.3}; {} bytes in {}",
        glb.iridescence_ior,
        glb.thickness_min_nm,
        glb.thickness_max_nm,
        glb.substrate_ior,
        glb.bytes.len(),
        out.display()
    );
    Ok(())
}

/// `filmscope report RUN --pixel X,Y`: the fit at one pixel, printed, plotted and tabled.
pub fn report_pixel(
    run: &Path,
    out: Option<&Path>,
    capture: Option<&Path>,
    xy: &str,
) -> Result<()> {
    let parse = |s: Option<&str>| s.and_then(|v| v.trim().parse::<usize>().ok());
    let mut parts = xy.split(',');
    let (Some(x), Some(y), None) = (parse(parts.next()), parse(parts.next()), parts.next()) else {
        bail!("--pixel {xy:?}: expected X,Y (column and row, from 0)");
    };
    let film = SampleFilm::load(run, capture)?;
    let cap = film.capture.clone().ok_or_else(|| {
        anyhow!(
            "{}: the capture is unknown (pass --capture)",
            run.join("summary.json").display()
        )
    })?;
    let mut source = open_capture(&cap)?;
    let fit = filmscope::appearance::pixel::pixel_fit(&film, &mut source, x, y)?;
    print!("{}", fit.table());
    let dir = match out {
        Some(o) => o
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."))
            .to_path_buf(),
        None => run.to_path_buf(),
    };
    let stem = out.and_then(|o| o.file_stem()).map_or_else(
        || format!("pixel-{x}-{y}"),
        |s| s.to_string_lossy().into_owned(),
    );
    let png = dir.join(format!("{stem}.png"));
    write_atomic(&png, &fit.to_png()?).with_context(|| format!("{}", png.display()))?;
    let csv = dir.join(format!("{stem}.csv"));
    write_atomic(&csv, fit.to_csv().as_bytes()).with_context(|| format!("{}", csv.display()))?;
    println!("wrote {} and {}", png.display(), csv.display());
    Ok(())
}

/// `filmscope report`.
pub fn report(run: &Path, out: Option<&Path>, capture: Option<&Path>) -> Result<()> {
    let path = out.map_or_else(|| run.join("report.html"), Path::to_path_buf);
    let made = filmscope::report::write_report(run, &path, capture)?;
    for note in &made.notes {
        log::info!("filmscope: note: {note}");
    }
    println!(
        "report: {} images, {} bytes in {}",
        made.images,
        made.bytes,
        path.display()
    );
    Ok(())
}

/// `filmscope results OUT --csv`: the line's results log as CSV on stdout
/// ([`filmscope::line::results`]).
pub fn results(out: &Path, alarms: bool) -> Result<()> {
    let stdout = std::io::stdout();
    let mut w = std::io::BufWriter::new(stdout.lock());
    let skipped =
        filmscope::line::results::write_csv(out, alarms, &mut w).map_err(anyhow::Error::msg)?;
    std::io::Write::flush(&mut w).context("writing the CSV")?;
    if skipped > 0 {
        log::warn!("{skipped} lines of the log are not records (skipped)");
    }
    Ok(())
}
