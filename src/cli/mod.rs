//! The command line: argument parsing, the commands' printing and progress bars, and the
//! calls into the library ([`filmscope::estimate`], [`filmscope::lab`], ...). `main.rs` only calls
//! [`main`].

mod commands;
mod inspect;
mod logging;
mod progress;

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use filmscope_core::colour::Illuminant;
use filmscope_core::optics::Polarization;

use filmscope::estimate::method::Method;
use filmscope::estimate::FieldChoice;
use filmscope::io::{ByteOrder, Interleave};
use filmscope::lab::eval::Ablation;
use filmscope::lab::scene::SceneFile;

/// How the streaming method gets the shared index.
#[derive(Clone, Copy, Debug, Args)]
pub struct IndexArgs {
    /// Sites (runs of five pixels spread over the image) whose full spectra give the shared
    /// index.
    #[arg(long, default_value_t = filmscope::estimate::index_fit::DEFAULT_SITES)]
    pub sample_sites: usize,
    /// Stream the capture once, as a live camera does: the index refitted on the sample as
    /// each angle completes (default: the sample's stream, then every pixel's).
    #[arg(long)]
    pub one_pass: bool,
    /// The model error the index fit tolerates, RMS reflectance (overrides the capture's
    /// `[fit] model_error`; default 0.003): a fit missing the spectra by more than their
    /// noise and this gives no index. 0 judges against the noise alone.
    #[arg(long, value_name = "RMS")]
    pub model_error: Option<f64>,
    /// How far the index sigma carries the nuisance terms a real rig keeps (a white
    /// reference's error, absorption, leak, stage offset, wavelength shift, flare, side
    /// lobes), as a multiple of the typical rig's (overrides the capture's `[fit]
    /// rig_tolerance`; default 1; 0: the statistical sigma under the terms the fit took).
    #[arg(long, value_name = "X")]
    pub rig_tolerance: Option<f64>,
}

/// The method and its settings, as `estimate` and `eval` take them.
#[derive(Clone, Debug, Args)]
pub struct MethodArgs {
    /// The estimator.
    #[arg(long, value_enum, default_value = "filmscope")]
    pub method: Method,
    /// About how many pixels keep whole extremum lists and the pooled sums (32 bytes
    /// each), the others their last extrema only; every pixel of a sensor with fewer
    /// than twice as many. The index itself comes from the pixel sample
    /// (`--sample-sites`).
    #[arg(long, default_value_t = filmscope_core::solve::fit_row::INDEX_PIXELS)]
    pub index_pixels: usize,
    /// Brute force: number of index values over the search range (0: a 0.01 step).
    #[arg(long, default_value_t = 0)]
    pub brute_index_steps: usize,
    /// Brute force: thickness grid step, nm.
    #[arg(long, default_value_t = 2.0)]
    pub brute_thickness_step: f64,
    /// Field model: auto (narrow unless the data ask for wide), narrow (one incidence angle
    /// per frame) or wide (the angle varies with the column; needs the lens's field of
    /// view).
    #[arg(long, value_enum, default_value = "auto")]
    pub field: FieldChoice,
    /// Wide field model: number of strips of columns (default: from the angle spread).
    #[arg(long)]
    pub field_strips: Option<usize>,
    /// How the streaming method gets the shared index.
    #[command(flatten)]
    pub index: IndexArgs,
}

/// filmscope: thin-film index and thickness maps from hyperspectral angle sweeps.
#[derive(Debug, Parser)]
#[command(name = "filmscope", version, about)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Only errors on standard error: no notes, warnings or progress bars.
    #[arg(short, long, global = true)]
    quiet: bool,
    /// More on standard error: -v the steps of a job, -vv everything.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The paper's three samples on the software rig, streamed through the pipeline, maps
    /// written, and a table like the paper's Table 1.
    Demo {
        /// Output folder.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
        /// Also run the paper's method on the same data.
        #[arg(long)]
        with_paper: bool,
    },
    /// Writes a scene as a capture directory (ENVI cubes, capture.toml, truth).
    Simulate {
        /// Scene file (see config/scenes).
        scene: PathBuf,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Float32 reflectance without noise, defects, vignetting or references.
        #[arg(long)]
        noise_free: bool,
        /// Cube interleave: bil (the camera link's order), bsq or bip.
        #[arg(long, value_enum, default_value = "bil")]
        interleave: Interleave,
        /// Byte order of the cubes' values.
        #[arg(long, value_enum, default_value = "little")]
        byte_order: ByteOrder,
        /// Replaces the scene's `seed` (its thickness bumps and noise).
        #[arg(long)]
        seed: Option<u64>,
    },
    /// Estimates index and thickness maps from a capture.
    Estimate {
        /// A capture.toml or the directory holding one.
        capture: PathBuf,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        method: MethodArgs,
        /// Worker threads of the streaming method.
        #[arg(long, default_value_t = 2)]
        workers: usize,
        /// Capacity of each pipeline channel, in messages.
        #[arg(long, default_value_t = 64)]
        channel_capacity: usize,
        /// Memory the run may use (bytes, or with K, M, G, T); default: what the machine
        /// has available. A capture needing more is refused before any work.
        #[arg(long)]
        max_memory: Option<String>,
        /// The film's index, known beforehand and held instead of fitted: a number, a
        /// library material name or a refractiveindex.info YAML file (filmscope method;
        /// one field model per frame). A material that absorbs (`si`, a `tabulated nk`
        /// file) is measured with its n and k, the sweep held in memory.
        #[arg(long, value_name = "MATERIAL")]
        film_index: Option<String>,
    },
    /// Sweeps a rig (stage x filter x camera), streams every frame into the estimator,
    /// records the raw sweep as a capture in OUT/capture and writes the maps into OUT.
    Acquire {
        /// The rig file (see config/rig.toml); default: config/rig.toml where it exists,
        /// else the same rig built in.
        #[arg(long)]
        rig: Option<PathBuf>,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Start firmware-sim and talk to it over real ptys and a socket.
        #[arg(long)]
        sim: bool,
        /// Memory the run may use (bytes, or with K, M, G, T); default: what the machine
        /// has available. A sweep needing more is refused before any device moves.
        #[arg(long)]
        max_memory: Option<String>,
    },
    /// On a production line: measures sample after sample against a recipe (verdict, mask,
    /// results.jsonl, MQTT, status page, trends and alarms) until --samples are done or
    /// SIGINT/SIGTERM (the sample under way is finished first).
    Inspect {
        /// The rig file (see config/rig.toml); default: config/rig.toml where it exists,
        /// else the same rig built in.
        #[arg(long)]
        rig: Option<PathBuf>,
        /// The recipe (see config/recipes/demo.toml).
        #[arg(long)]
        recipe: PathBuf,
        /// Output folder (results.jsonl, inspect.log, samples/).
        #[arg(long)]
        out: PathBuf,
        /// Drive firmware-sim's line of samples.
        #[arg(long)]
        sim: bool,
        /// Stop after this many samples (default: until stopped).
        #[arg(long)]
        samples: Option<u64>,
        /// Status page port instead of the recipe's (0: any free one).
        #[arg(long)]
        status_port: Option<u16>,
        /// MQTT broker port instead of the recipe's.
        #[arg(long)]
        mqtt_port: Option<u16>,
        /// Serve the PLC's Modbus TCP registers on HOST:PORT (port 0: any free one) instead
        /// of the recipe's `[modbus] bind`.
        #[arg(long, value_name = "HOST:PORT")]
        modbus: Option<String>,
        /// One JSON summary line at the end (and no per-sample lines).
        #[arg(long)]
        json: bool,
        /// The production lot every record names (instead of the recipe's `lot`).
        #[arg(long)]
        lot: Option<String>,
        /// The operator every record names (instead of the recipe's `operator`).
        #[arg(long)]
        operator: Option<String>,
        /// Measure the recipe's `[reference]` sample first (the start of a shift): its drift
        /// from the certified thickness and index is recorded, and alarmed beyond tolerance.
        #[arg(long)]
        reference: bool,
    },
    /// The status page of an `inspect --out` folder as the line left it (its status.json,
    /// and the records of results.jsonl after it), served by the same bounded server as
    /// `inspect`'s: the page, /api/latest, /api/history, /latest.png and /metrics keep
    /// answering once `inspect` has stopped. Follows the folder while it changes; runs
    /// until SIGINT/SIGTERM.
    Status {
        /// The `inspect --out` folder.
        out: PathBuf,
        /// Where to listen (port 0: any free one, printed).
        #[arg(long, value_name = "ADDR:PORT", default_value = "127.0.0.1:8088")]
        listen: String,
    },
    /// The line's results log (OUT/results.jsonl and its rotated files, oldest first) as a
    /// spreadsheet opens it: one CSV row per sample on stdout.
    Results {
        /// The `inspect --out` folder.
        out: PathBuf,
        /// CSV (RFC 4180: a header row, comma-separated, quoted where needed).
        #[arg(long, required = true)]
        csv: bool,
        /// Alarms too, one row each after the samples' (kind `alarm`).
        #[arg(long)]
        alarms: bool,
    },
    /// Accuracy against the truth on scene files or simulated capture directories.
    Eval {
        /// Scene files (.toml) or capture directories with truth.
        inputs: Vec<PathBuf>,
        /// Instead of inputs, N random coating scenes (a library material on a random
        /// substrate, thickness map, angles, bands, FWHM, polarisation, sensor model and
        /// capture layout), each written to a temporary capture, estimated from disk and
        /// judged PASS or FAIL; one row per scene and a closing count.
        #[arg(long, value_name = "N")]
        random: Option<usize>,
        /// With --random: the set's seed (the same seed draws the same scenes; default 1).
        /// With scene files: replaces each scene's `seed` (thickness bumps and noise).
        #[arg(long)]
        seed: Option<u64>,
        /// With --random: also write each drawn scene's file into DIR
        /// (`random-SEED-I.toml`), so a row can be run again with `eval FILE`.
        #[arg(long, value_name = "DIR", requires = "random")]
        save_scenes: Option<PathBuf>,
        /// With --random: only these rows of the set (0-based, comma-separated), each drawn
        /// and captured as in the whole set: a row run again exactly.
        #[arg(
            long,
            value_name = "I,J,...",
            requires = "random",
            value_delimiter = ','
        )]
        rows: Option<Vec<usize>>,
        /// With --random: scenes as real samples on a real rig measure them (a good
        /// camera's low noise, film absorption, stage and wavelength errors, flare,
        /// polariser leak, side lobes, some with an undeclared bare back face), judged by
        /// the realistic criteria; each row lists what was drawn.
        #[arg(long, requires = "random")]
        realistic: bool,
        /// With --random: thick films with no search range given (40-5000 nm on a
        /// dispersive substrate, two angles), judged by the realistic criteria: the default
        /// thickness range must reach them.
        #[arg(long, requires = "random", conflicts_with = "realistic")]
        thick: bool,
        #[command(flatten)]
        method: MethodArgs,
        /// One JSON object per input on stdout instead of a table (with --random: one
        /// object, every scene's row in `rows`).
        #[arg(long)]
        json: bool,
        /// Switch off filmscope improvements to measure their worth (comma-separated).
        #[arg(long, value_enum, value_delimiter = ',')]
        ablate: Vec<Ablation>,
    },
    /// Measures speed and memory (tracker, pipeline, solve, latency, state, peak RSS) and the
    /// baselines' cost on the same data, and prints one table.
    Bench {
        /// Smaller sweeps (under a minute).
        #[arg(long)]
        quick: bool,
        /// One JSON object on stdout instead of the table.
        #[arg(long)]
        json: bool,
        /// The scene whose spectra are measured (default: config/scenes/paper-sample1.toml,
        /// built into the binary).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Also write the table and the JSON as OUT/YYYY-MM-DD.md and .json (today's UTC
        /// date), e.g. `--out docs/bench`.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Speed against accuracy: every method and knob setting on one scene, charted (time per
    /// megapixel against thickness and index error, Pareto front marked).
    ///
    /// The committed figure is regenerated with `filmscope chart --out docs`.
    Chart {
        /// The scene (default: config/scenes/paper-sample1.toml, built into the binary).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Output folder (speed-accuracy.png and .json); `docs` replaces the committed
        /// figure.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Fewer settings and a smaller sensor.
        #[arg(long)]
        quick: bool,
    },
    /// Where each method works: error, flagged and silent fractions over film index,
    /// thickness, FWHM, noise, angles and band step, one heat map per method and map.
    ///
    /// The committed figures are regenerated with `filmscope stability --out docs` (all
    /// maps) or `--out docs --map NAME` (one map).
    Stability {
        /// Output folder (stability-*.png and stability.json); `docs` replaces the
        /// committed figures.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Grids of 2-3 x 2-3 cells instead of up to 10 x 8.
        #[arg(long)]
        quick: bool,
        /// Instead of drawing the maps, write one cell's scene file into --out, for `eval`
        /// or `simulate`: MAP:X:Y, the map's name and its column's and row's values (e.g.
        /// index-thickness:2000:2.8).
        #[arg(long)]
        cell: Option<String>,
        /// With --cell: the scene's noise seed (default: the maps' own).
        #[arg(long, requires = "cell")]
        seed: Option<u64>,
        /// Only the maps named (comma-separated, e.g. material-thickness); their figures
        /// go to stability-NAME.json instead of stability.json.
        #[arg(long, value_delimiter = ',', conflicts_with = "cell")]
        map: Vec<String>,
    },
    /// Renders the estimated film as a camera sees it (spectral -> XYZ -> sRGB) at one
    /// angle, with an angle strip from 0 to 70 degrees.
    Render {
        /// A maps directory written by `estimate`.
        maps: PathBuf,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// Incidence (= viewing, specular) angle of the main image, degrees.
        #[arg(long, default_value_t = 30.0)]
        angle: f64,
        /// The light (white-balanced to sRGB).
        #[arg(long, default_value = "D65", value_parser = commands::illuminant)]
        illuminant: Illuminant,
        /// Exposure factor on the reflectance (default: auto, printed in the image).
        #[arg(long)]
        exposure: Option<f64>,
        /// Polarisation of the light: s, p or unpolarized (default: the capture's).
        #[arg(long, value_parser = commands::polarization)]
        polarization: Option<Polarization>,
        /// The capture (capture.toml or its directory), if the summary does not lead to it.
        #[arg(long)]
        capture: Option<PathBuf>,
    },
    /// Measured against reproduced at every captured angle, with CIEDE2000 maps:
    /// compare.png and compare.json.
    Compare {
        /// A maps directory written by `estimate`.
        maps: PathBuf,
        /// Output directory (default: the maps directory).
        #[arg(long)]
        out: Option<PathBuf>,
        /// The light.
        #[arg(long, default_value = "D65", value_parser = commands::illuminant)]
        illuminant: Illuminant,
        /// The capture (capture.toml or its directory), if the summary does not lead to it.
        #[arg(long)]
        capture: Option<PathBuf>,
        /// Also write, per angle, ENVI files: the measured and reproduced CIELAB and the
        /// CIEDE2000 (lab-AA.hdr, 7 float32 bands), and the model and residual reflectance
        /// cubes at the capture's bands (model-AA.hdr, residual-AA.hdr).
        #[arg(long)]
        envi: bool,
    },
    /// Writes the film as a glTF 2.0 binary (.glb): a flat quad with
    /// KHR_materials_iridescence (thickness texture) and KHR_materials_ior.
    ExportGltf {
        /// A maps directory written by `estimate`.
        maps: PathBuf,
        /// Output .glb file.
        #[arg(long)]
        out: PathBuf,
        /// Width of the quad in metres (its height follows the map's aspect).
        #[arg(long, default_value_t = 0.1)]
        width_m: f64,
        /// The capture (capture.toml or its directory), if the summary does not lead to it.
        #[arg(long)]
        capture: Option<PathBuf>,
    },
    /// One self-contained HTML page: maps, render, measured vs reproduced, summary table
    /// and charts.
    Report {
        /// A maps directory written by `estimate`.
        run: PathBuf,
        /// Output HTML file (default: RUN/report.html).
        #[arg(long)]
        out: Option<PathBuf>,
        /// The capture (capture.toml or its directory), if the summary does not lead to it.
        #[arg(long)]
        capture: Option<PathBuf>,
        /// Instead of the page, the fit at pixel X,Y (column, row): prints the residual per
        /// angle and the order candidates, and writes RUN/pixel-X-Y.png (measured and model
        /// at every angle, the residual, the candidates) and RUN/pixel-X-Y.csv (or beside
        /// --out).
        #[arg(long, value_name = "X,Y")]
        pixel: Option<String>,
    },
    /// Shell completions on stdout, e.g. `filmscope completions bash >
    /// /etc/bash_completion.d/filmscope`
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
    /// The manual pages (roff): filmscope.1 and filmscope-COMMAND.1 for each command
    Man {
        /// Output directory (view with `man -l DIR/filmscope.1`).
        #[arg(long, default_value = "man")]
        out: PathBuf,
    },
    /// (reliability) Consecutive sweeps of a small scene through the pipeline, printing the
    /// resident memory every tenth sweep: memory must stay flat over a long run.
    #[command(hide = true)]
    Soak {
        /// Sweeps to run.
        #[arg(long, default_value_t = 200)]
        sweeps: usize,
        /// The scene (resized to 32 x 24 pixels, 101 bands; default: config/scenes/rig-tiny.toml
        /// as built in).
        #[arg(long)]
        scene: Option<PathBuf>,
    },
    /// (internal) One sweep in a fresh process, for `bench`'s peak-memory figure.
    #[command(hide = true)]
    BenchRssChild {
        /// The scene file (default: the built-in paper-sample1).
        #[arg(long)]
        scene: Option<PathBuf>,
        width: usize,
        height: usize,
        angles: usize,
    },
}

/// Runs the command line; returns the process exit code.
pub fn main() -> std::process::ExitCode {
    quiet_on_broken_pipe();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !e.use_stderr() => e.exit(),
        Err(e) => {
            eprintln!("filmscope: {}", usage_error(&e));
            return std::process::ExitCode::from(2);
        }
    };
    logging::init(cli.quiet, cli.verbose);
    let result = match cli.command {
        c @ (Command::Demo { .. }
        | Command::Simulate { .. }
        | Command::Estimate { .. }
        | Command::Acquire { .. }
        | Command::Inspect { .. }
        | Command::Status { .. }
        | Command::Results { .. }) => run_measure(c),
        c @ (Command::Render { .. }
        | Command::Compare { .. }
        | Command::ExportGltf { .. }
        | Command::Report { .. }) => run_colour(c),
        c @ (Command::Eval { .. }
        | Command::Bench { .. }
        | Command::Soak { .. }
        | Command::Chart { .. }
        | Command::Stability { .. }
        | Command::BenchRssChild { .. }) => run_lab(c),
        c @ (Command::Completions { .. } | Command::Man { .. }) => run_docs(c),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            log::error!("{}", one_line(&format!("{e:#}")));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The commands that measure: simulate, estimate, acquire, the production line, its
/// records.
fn run_measure(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Demo { out, with_paper } => commands::demo(&out, with_paper),
        Command::Simulate {
            scene,
            out,
            noise_free,
            interleave,
            byte_order,
            seed,
        } => commands::simulate(&scene, &out, noise_free, (interleave, byte_order), seed),
        Command::Estimate {
            capture,
            out,
            method,
            workers,
            channel_capacity,
            max_memory,
            film_index,
        } => commands::estimate(
            &capture,
            &out,
            &method,
            (workers, channel_capacity),
            max_memory.as_deref(),
            film_index.as_deref(),
        ),
        Command::Acquire {
            rig,
            out,
            sim,
            max_memory,
        } => commands::acquire(rig.as_deref(), &out, sim, max_memory.as_deref()),
        Command::Inspect {
            rig,
            recipe,
            out,
            sim,
            samples,
            status_port,
            mqtt_port,
            modbus,
            json,
            lot,
            operator,
            reference,
        } => inspect::inspect(&inspect::Args {
            rig: rig.as_deref(),
            recipe: &recipe,
            out: &out,
            sim,
            samples,
            status_port,
            mqtt_port,
            modbus,
            json,
            lot,
            operator,
            reference,
        }),
        Command::Status { out, listen } => inspect::status(&out, &listen),
        Command::Results {
            out,
            csv: _,
            alarms,
        } => commands::results(&out, alarms),
        _ => unreachable!("dispatched by main"),
    }
}

/// The commands on an estimate's colour: renders, the comparison, glTF, the report.
fn run_colour(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Render {
            maps,
            out,
            angle,
            illuminant,
            exposure,
            polarization,
            capture,
        } => commands::render(
            &maps,
            &out,
            angle,
            illuminant,
            exposure,
            polarization,
            capture.as_deref(),
        ),
        Command::Compare {
            maps,
            out,
            illuminant,
            capture,
            envi,
        } => commands::compare(&maps, out.as_deref(), illuminant, capture.as_deref(), envi),
        Command::ExportGltf {
            maps,
            out,
            width_m,
            capture,
        } => commands::export_gltf(&maps, &out, width_m, capture.as_deref()),
        Command::Report {
            run,
            out,
            capture,
            pixel: None,
        } => commands::report(&run, out.as_deref(), capture.as_deref()),
        Command::Report {
            run,
            out,
            capture,
            pixel: Some(xy),
        } => commands::report_pixel(&run, out.as_deref(), capture.as_deref(), &xy),
        _ => unreachable!("dispatched by main"),
    }
}

/// The lab's commands: accuracy, speed, charts, stability maps, the soak.
fn run_lab(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Eval {
            inputs,
            random,
            seed,
            save_scenes,
            rows,
            realistic,
            thick,
            method,
            json,
            ablate,
        } => commands::eval(
            &inputs,
            random.map(|count| commands::RandomSet {
                count,
                seed: seed.unwrap_or(1),
                save_scenes,
                rows,
            }),
            match (realistic, thick) {
                (true, _) => firmware_sim::random::Draw::Realistic,
                (_, true) => firmware_sim::random::Draw::Thick,
                _ => firmware_sim::random::Draw::Plain,
            },
            seed,
            &method,
            json,
            &ablate,
        ),
        Command::Bench {
            quick,
            json,
            scene,
            out,
        } => commands::bench(&SceneFile::from_arg(scene), quick, json, out.as_deref()),
        Command::Soak { sweeps, scene } => commands::soak(scene, sweeps),
        Command::Chart { scene, out, quick } => {
            commands::chart(&SceneFile::from_arg(scene), &out, quick)
        }
        Command::Stability {
            out,
            quick,
            cell: Some(cell),
            seed,
            ..
        } => commands::stability_cell(&out, quick, &cell, seed),
        Command::Stability {
            out, quick, map, ..
        } => commands::stability(&out, quick, &map),
        Command::BenchRssChild {
            scene,
            width,
            height,
            angles,
        } => filmscope::lab::bench::rss_child(&SceneFile::from_arg(scene), width, height, angles)
            .map_err(anyhow::Error::from),
        _ => unreachable!("dispatched by main"),
    }
}

/// Shell completions and the manual page.
fn run_docs(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Completions { shell } => {
            let mut cmd = <Cli as clap::CommandFactory>::command();
            clap_complete::generate(shell, &mut cmd, "filmscope", &mut std::io::stdout());
            Ok(())
        }
        Command::Man { out } => commands::man(&out),
        _ => unreachable!("dispatched by main"),
    }
}

/// A usage error in one line: `--field "sideways": use auto, narrow or wide` for a value
/// not among the choices, else clap's first line and where to find help.
fn usage_error(e: &clap::Error) -> String {
    use clap::error::{ContextKind, ContextValue, ErrorKind};
    let arg = e.get(ContextKind::InvalidArg).map(|a| {
        let a = a.to_string();
        a.split_whitespace().next().unwrap_or_default().to_owned()
    });
    match (
        e.kind(),
        arg,
        e.get(ContextKind::InvalidValue),
        e.get(ContextKind::ValidValue),
    ) {
        (
            ErrorKind::InvalidValue,
            Some(arg),
            Some(ContextValue::String(value)),
            Some(ContextValue::Strings(valid)),
        ) => {
            let (last, rest) = valid
                .split_last()
                .map_or(("", &[][..]), |(l, r)| (l.as_str(), r));
            let choices = if rest.is_empty() {
                last.to_owned()
            } else {
                format!("{} or {last}", rest.join(", "))
            };
            one_line(&format!("{arg} {value:?}: use {choices}"))
        }
        _ => {
            let text = e.render().to_string();
            let lines: Vec<&str> = text
                .lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && !l.starts_with("Usage:") && !l.starts_with("For more"))
                .collect();
            one_line(&format!(
                "{} (see --help)",
                lines.join(" ").trim_start_matches("error: ")
            ))
        }
    }
}

/// Exit status of a program its reader stopped listening to (128 + SIGPIPE), as a shell
/// tool's.
pub const BROKEN_PIPE_EXIT: i32 = 141;

/// A closed standard output (`filmscope eval ... | head -1`) ends the program quietly with
/// [`BROKEN_PIPE_EXIT`], as a shell tool ends, instead of the panic `println!` raises on a
/// broken pipe; every other panic is reported as before. (Rust ignores SIGPIPE, and resetting
/// it needs `unsafe`, which the workspace denies.) Outputs already written stay whole: every
/// file is written to a temporary name and renamed.
fn quiet_on_broken_pipe() {
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let message = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if message.contains("failed printing to stdout") && message.contains("Broken pipe") {
            std::process::exit(BROKEN_PIPE_EXIT);
        }
        report(info)
    }));
}

/// One line of text safe for a terminal: whitespace runs joined into single spaces, other
/// control characters escaped.
fn one_line(s: &str) -> String {
    filmscope::limits::printable(&s.split_whitespace().collect::<Vec<_>>().join(" "))
}
