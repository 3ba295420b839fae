//! Accuracy against the truth: index error, thickness errors, silent failures, and the
//! reproduced colour (spectral RMSE, CIE76, CIEDE2000) at every angle.
//!
//! Colour is compared on the film model over the whole visible range (380-780 nm, D65,
//! CIE 1931 2 deg, with [`FilmColour`], the model the renders use): the true film (true index with its dispersion, true thickness) against
//! the estimated one, pixel by pixel, at each angle of the sweep. The spectral RMSE (method.md
//! eq. 16) compares the two band-averaged spectra over the capture's own bands.
//!
//! [`eval_one`] judges a scene file or a capture directory, [`random_eval`] a set of random
//! scenes; [`ablated`] switches improvements off to measure their worth.

use std::path::{Path, PathBuf};

use super::{LabError, Result};
use filmscope_core::colour::{
    delta_e2000, delta_e76, spectral_rmse, Colorimetry, Illuminant, D65_WHITE_XYZ,
};
use filmscope_core::optics::{BackFace, Dispersion, FilmStack, Polarization};
use filmscope_core::solve::refine::FilmTerms;
use filmscope_core::solve::sweep::SolverOptions;
use firmware_sim::random::Draw;
use firmware_sim::{Scene, SoftwareCamera};
use serde::Serialize;

use crate::appearance::spectral::{capture_passbands, BandSpectrum, FilmColour};
use crate::estimate::{FieldConfig, Run, RunConfig};
use crate::io::{read_cube, Capture};
use crate::jobs::{Observer, Quiet, Settings};
use crate::material::DispersionRecord;
use crate::record::truth::TruthRecord;
use crate::source::{CaptureSource, SimSource};

/// Thickness errors above this are failures (nm).
pub const SILENT_FAILURE_NM: f64 = 20.0;

/// Why a capture's truth cannot be read, one line naming the file.
#[derive(Debug, thiserror::Error)]
pub enum TruthError {
    /// `truth.json` cannot be read.
    #[error(transparent)]
    Record(#[from] crate::record::RecordError),
    /// One of its indices is not one filmscope takes.
    #[error("{}: {what}: {problem}", .path.display())]
    Dispersion {
        /// `truth.json`.
        path: PathBuf,
        /// The key.
        what: &'static str,
        /// Its problem.
        problem: crate::material::MaterialError,
    },
    /// The true thickness map cannot be read.
    #[error(transparent)]
    Map(#[from] crate::io::EnviError),
}

/// What is true about a sweep.
#[derive(Clone, Debug)]
pub struct Truth {
    /// The film's index (with dispersion).
    pub film: Dispersion,
    /// The substrate's index (with dispersion).
    pub substrate: Dispersion,
    /// Ambient index.
    pub ambient_index: f64,
    /// Polarisation.
    pub polarization: Polarization,
    /// The substrate's back face as the sample has it (declared or not).
    pub back_face: BackFace,
    /// Thickness per pixel, row-major, nm.
    pub thickness_nm: Vec<f32>,
}

impl Truth {
    /// The truth of a scene.
    pub fn of_scene(scene: &firmware_sim::Scene) -> Self {
        Self {
            film: scene.stack.film,
            substrate: scene.stack.substrate,
            ambient_index: scene.stack.ambient_index,
            polarization: scene.stack.polarization,
            back_face: if scene.imperfections.bare_back_face {
                BackFace::Bare
            } else {
                BackFace::None
            },
            thickness_nm: scene.thickness_nm.clone(),
        }
    }

    /// The truth written beside a simulated capture (`truth.json`, `truth/thickness_nm.hdr`).
    pub fn of_capture_dir(dir: &Path) -> Result<Self, TruthError> {
        let t = TruthRecord::read(dir)?;
        let path = dir.join(crate::record::truth::FILE);
        let model = |d: &Option<DispersionRecord>, n: f64, what: &'static str| match d {
            None => Ok(Dispersion::constant(n)),
            Some(d) => d.dispersion().map_err(|problem| TruthError::Dispersion {
                path: path.clone(),
                what,
                problem,
            }),
        };
        let film = model(&t.dispersion, t.refractive_index, "dispersion")?;
        // A dispersive substrate is `substrate_dispersion`; a constant one (null there, or
        // a truth written before the key) `substrate_index`.
        let substrate = model(
            &t.substrate_dispersion,
            t.substrate_index,
            "substrate_dispersion",
        )?;
        let map = dir.join("truth").join("thickness_nm.hdr");
        let cube = read_cube(&map)?;
        Ok(Self {
            film,
            substrate,
            ambient_index: t.ambient_index,
            polarization: t.polarization.into(),
            back_face: t.back_face.into(),
            thickness_nm: cube.data,
        })
    }
}

/// One scene's accuracy (the `eval --json` object).
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    /// Scene or capture name.
    pub scene: String,
    /// Method name.
    pub method: String,
    /// True index at 550 nm.
    pub index_true: f64,
    /// Estimated index at 550 nm.
    pub index_estimated: f64,
    /// Estimated minus true.
    pub index_error: f64,
    /// Mean absolute thickness error over valid pixels, nm.
    pub thickness_mae_nm: f64,
    /// RMS thickness error over valid pixels, nm.
    pub thickness_rmse_nm: f64,
    /// Largest thickness error over valid pixels, nm.
    pub thickness_max_error_nm: f64,
    /// Share of pixels with a thickness.
    pub valid_fraction: f64,
    /// Share of all pixels that are valid but more than 20 nm off.
    pub silent_failure_rate: f64,
    /// Share of valid pixels whose thickness error is within their reported 1-sigma (NaN
    /// without any).
    pub thickness_within_sigma: f64,
    /// The factor the reported thickness sigmas would need to cover 68.3 % of the valid
    /// pixels' errors (the 68.3rd percentile of |error| / sigma; 1 when they are right, NaN
    /// without valid pixels).
    pub thickness_sigma_scale_68: f64,
    /// The reported 1-sigma of the index at 550 nm (NaN: none reported).
    pub index_sigma: f64,
    /// The run's notes (why there is no index, clipped references, ...).
    pub notes: Vec<String>,
    /// Mean over valid pixels and angles of the spectral RMSE (eq. 16).
    pub spectral_rmse: f64,
    /// Mean CIE76 colour difference over valid pixels and angles.
    pub delta_e76_mean: f64,
    /// Mean CIEDE2000 colour difference over valid pixels and angles.
    pub delta_e2000_mean: f64,
    /// Mean CIE76 per angle (streaming order).
    pub delta_e76_per_angle: Vec<f64>,
    /// Mean CIEDE2000 per angle.
    pub delta_e2000_per_angle: Vec<f64>,
    /// Angles, degrees.
    pub angles_deg: Vec<f64>,
    /// Wall time of the run, seconds.
    pub seconds: f64,
    /// The field model used (streaming method): `narrow` or `wide`.
    pub field_model: Option<String>,
    /// How the field model was chosen, with each model's figures (`summary.json`
    /// `field_model_choice`).
    pub field_model_choice: Option<crate::summary::FieldModelChoice>,
}

/// Thickness errors of an estimate against the truth, pixel by pixel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ThicknessErrors {
    /// Mean absolute error over valid pixels, nm (NaN without any).
    pub mae_nm: f64,
    /// RMS error over valid pixels, nm (NaN without any).
    pub rmse_nm: f64,
    /// Largest error over valid pixels, nm (NaN without any).
    pub max_nm: f64,
    /// Share of pixels with a (finite) thickness.
    pub valid_fraction: f64,
    /// Share of all pixels that are valid but more than [`SILENT_FAILURE_NM`] off.
    pub silent_failure_rate: f64,
}

/// Thickness errors of `estimate_nm` (NaN: no estimate) against `truth_nm`, pixel by pixel
/// over the pixels both have.
pub fn thickness_errors(truth_nm: &[f32], estimate_nm: &[f32]) -> ThicknessErrors {
    let n_px = truth_nm.len().min(estimate_nm.len());
    let mut errs = Vec::new();
    let mut silent = 0usize;
    for (&t, &e) in truth_nm.iter().zip(estimate_nm) {
        let (t, e) = (f64::from(t), f64::from(e));
        if e.is_finite() {
            let d = (e - t).abs();
            if d > SILENT_FAILURE_NM {
                silent += 1;
            }
            errs.push(d);
        }
    }
    let nv = errs.len().max(1) as f64;
    let none = errs.is_empty();
    let or_nan = |x: f64| if none { f64::NAN } else { x };
    ThicknessErrors {
        mae_nm: or_nan(errs.iter().sum::<f64>() / nv),
        rmse_nm: or_nan((errs.iter().map(|e| e * e).sum::<f64>() / nv).sqrt()),
        max_nm: or_nan(errs.iter().copied().fold(0.0, f64::max)),
        valid_fraction: errs.len() as f64 / n_px.max(1) as f64,
        silent_failure_rate: silent as f64 / n_px.max(1) as f64,
    }
}

/// Compares a run with the truth.
pub fn evaluate(scene: &str, truth: &Truth, run: &Run) -> EvalReport {
    let r = &run.result;
    let n_px = truth.thickness_nm.len().min(r.thickness_nm.len());
    let est_film = r.index.dispersion();
    let true_stack = FilmStack {
        back_face: truth.back_face,
        ambient_index: truth.ambient_index,
        film: truth.film,
        substrate: truth.substrate,
        polarization: truth.polarization,
    };
    let est_stack = FilmStack {
        film: est_film,
        ..true_stack
    };
    let errors = thickness_errors(&truth.thickness_nm[..n_px], &r.thickness_nm[..n_px]);
    let valid_px: Vec<usize> = (0..n_px)
        .filter(|&i| r.thickness_nm[i].is_finite())
        .collect();
    // Colour and spectra on at most ~4000 valid pixels (evenly strided) per angle: the
    // error that index and thickness make (a scene's absorption left out on both sides; a
    // tabulated film's own k kept on both).
    let stride = (valid_px.len() / 4000).max(1);
    let sample: Vec<usize> = valid_px.iter().copied().step_by(stride).collect();
    let bands = capture_passbands(&run.spec.bands_nm, &run.spec.fwhm_nm);
    let visible = Colorimetry::full(Illuminant::D65);
    let (mut de76_all, mut de00_all, mut rmse_all) = (Vec::new(), Vec::new(), Vec::new());
    let (mut de76_angle, mut de00_angle) = (Vec::new(), Vec::new());
    let (mut r_true, mut r_est) = (vec![0.0; bands.len()], vec![0.0; bands.len()]);
    for &deg in &run.angles_deg {
        let (true_bands, est_bands) = (
            BandSpectrum::new(true_stack, deg, &bands, FilmTerms::NONE),
            BandSpectrum::new(est_stack, deg, &bands, FilmTerms::NONE),
        );
        let (true_colour, est_colour) = (
            FilmColour::new(true_stack, deg, visible, FilmTerms::NONE),
            FilmColour::new(est_stack, deg, visible, FilmTerms::NONE),
        );
        let (mut s76, mut s00) = (0.0, 0.0);
        for &i in &sample {
            let (t, e) = (
                f64::from(truth.thickness_nm[i]),
                f64::from(r.thickness_nm[i]),
            );
            let lab_t = true_colour.xyz(t).to_lab(D65_WHITE_XYZ);
            let lab_e = est_colour.xyz(e).to_lab(D65_WHITE_XYZ);
            let (a, b) = (delta_e76(lab_t, lab_e), delta_e2000(lab_t, lab_e));
            s76 += a;
            s00 += b;
            de76_all.push(a);
            de00_all.push(b);
            true_bands.reflectance_into(t, &mut r_true);
            est_bands.reflectance_into(e, &mut r_est);
            rmse_all.push(spectral_rmse(&r_true, &r_est));
        }
        let k = sample.len().max(1) as f64;
        de76_angle.push(s76 / k);
        de00_angle.push(s00 / k);
    }
    let mean = |v: &[f64]| {
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    let n_true = truth.film.index_at(550.0);
    let n_est = r.index.at(550.0);
    // Each valid pixel's error in units of its reported sigma.
    let mut z: Vec<f64> = valid_px
        .iter()
        .map(|&i| {
            let err = f64::from(r.thickness_nm[i]) - f64::from(truth.thickness_nm[i]);
            r.thickness_sigma_nm
                .get(i)
                .map_or(f64::INFINITY, |&s| err.abs() / f64::from(s))
        })
        .collect();
    let within = z.iter().filter(|&&z| z <= 1.0).count();
    z.sort_by(f64::total_cmp);
    let z68 = z
        .get((z.len() as f64 * 0.6827) as usize)
        .copied()
        .unwrap_or(f64::NAN);
    EvalReport {
        scene: scene.to_owned(),
        method: r.method.name().to_owned(),
        index_true: n_true,
        index_estimated: n_est,
        index_error: n_est - n_true,
        thickness_mae_nm: errors.mae_nm,
        thickness_rmse_nm: errors.rmse_nm,
        thickness_max_error_nm: errors.max_nm,
        valid_fraction: errors.valid_fraction,
        silent_failure_rate: errors.silent_failure_rate,
        thickness_within_sigma: if valid_px.is_empty() {
            f64::NAN
        } else {
            within as f64 / valid_px.len() as f64
        },
        thickness_sigma_scale_68: z68,
        index_sigma: r.index_sigma.unwrap_or(f64::NAN),
        notes: r.notes.clone(),
        spectral_rmse: mean(&rmse_all),
        delta_e76_mean: mean(&de76_all),
        delta_e2000_mean: mean(&de00_all),
        delta_e76_per_angle: de76_angle,
        delta_e2000_per_angle: de00_angle,
        angles_deg: run.angles_deg.clone(),
        seconds: run.seconds,
        field_model: run.field_model.map(|m| m.name().to_owned()),
        field_model_choice: run.field_model_choice.clone(),
    }
}

/// The pass criteria of the random evaluation ([`random_eval`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Criteria {
    /// Largest |index error| at 550 nm.
    pub index_abs: f64,
    /// Largest |index error| at 550 nm for films thinner than [`Criteria::thin_below_nm`].
    pub index_abs_thin: f64,
    /// Base thickness under which a film counts as thin, nm.
    pub thin_below_nm: f64,
    /// Largest thickness MAE over valid pixels, nm, ...
    pub mae_nm: f64,
    /// ... plus this share of the base thickness.
    pub mae_relative: f64,
    /// Smallest valid share.
    pub valid_min: f64,
    /// Largest silently-wrong share (valid and more than [`SILENT_FAILURE_NM`] off).
    pub silent_max: f64,
    /// Largest mean CIEDE2000 over angles.
    pub delta_e2000_max: f64,
    /// An |index error| beyond this, with any pixel reported valid, is "index silently
    /// wrong".
    pub index_silently_wrong: f64,
}

/// The random evaluation's criteria: |index error| <= 0.005 (0.02 under 100 nm), MAE <= 2 nm,
/// valid >= 95 %, silent <= 0.1 %, mean CIEDE2000 <= 1; index silently wrong beyond 0.02.
pub const RANDOM_CRITERIA: Criteria = Criteria {
    index_abs: 0.005,
    index_abs_thin: 0.02,
    thin_below_nm: 100.0,
    mae_nm: 2.0,
    mae_relative: 0.0,
    valid_min: 0.95,
    silent_max: 0.001,
    delta_e2000_max: 1.0,
    index_silently_wrong: 0.02,
};

/// The realistic evaluation's criteria (`eval --random --realistic`): |index error| <= 0.01
/// (0.03 under 100 nm), MAE <= 3 nm + 0.5 % of the base thickness, valid >= 90 %, silent <= 1
/// %, no colour criterion; index silently wrong beyond 0.02. A scene whose bare back face the
/// capture does not declare also passes when it is refused (no valid pixel, a note).
pub const REALISTIC_CRITERIA: Criteria = Criteria {
    index_abs: 0.01,
    index_abs_thin: 0.03,
    thin_below_nm: 100.0,
    mae_nm: 3.0,
    mae_relative: 0.005,
    valid_min: 0.90,
    silent_max: 0.01,
    delta_e2000_max: f64::INFINITY,
    index_silently_wrong: 0.02,
};

/// The figures a verdict is drawn from.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Score {
    /// Estimated minus true index at 550 nm.
    pub index_error: f64,
    /// Thickness MAE over valid pixels, nm.
    pub thickness_mae_nm: f64,
    /// Share of pixels with a thickness.
    pub valid_fraction: f64,
    /// Share of all pixels valid but more than [`SILENT_FAILURE_NM`] off.
    pub silent_failure_rate: f64,
    /// Mean CIEDE2000 over valid pixels and angles.
    pub delta_e2000_mean: f64,
}

impl Score {
    /// The score of an evaluation.
    pub fn of(report: &EvalReport) -> Self {
        Self {
            index_error: report.index_error,
            thickness_mae_nm: report.thickness_mae_nm,
            valid_fraction: report.valid_fraction,
            silent_failure_rate: report.silent_failure_rate,
            delta_e2000_mean: report.delta_e2000_mean,
        }
    }
}

/// Whether a scene passed, and why not.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Verdict {
    /// Every criterion met.
    pub passed: bool,
    /// The criteria not met: `index`, `MAE`, `valid`, `silent`, `dE00` (a NaN figure fails
    /// its criterion).
    pub failed: Vec<String>,
    /// |index error| beyond [`Criteria::index_silently_wrong`] while some pixel is reported
    /// valid.
    pub index_silently_wrong: bool,
}

impl Criteria {
    /// The verdict on `score` for a film of base thickness `base_thickness_nm`.
    pub fn judge(&self, score: &Score, base_thickness_nm: f64) -> Verdict {
        let index_tol = if base_thickness_nm < self.thin_below_nm {
            self.index_abs_thin
        } else {
            self.index_abs
        };
        let mut failed = Vec::new();
        for (name, ok) in [
            ("index", score.index_error.abs() <= index_tol),
            (
                "MAE",
                score.thickness_mae_nm <= self.mae_nm + self.mae_relative * base_thickness_nm,
            ),
            ("valid", score.valid_fraction >= self.valid_min),
            ("silent", score.silent_failure_rate <= self.silent_max),
            (
                "dE00",
                self.delta_e2000_max == f64::INFINITY
                    || score.delta_e2000_mean <= self.delta_e2000_max,
            ),
        ] {
            if !ok {
                failed.push(name.to_owned());
            }
        }
        // A NaN index with valid pixels counts as silently wrong too.
        let index_close = score.index_error.abs() <= self.index_silently_wrong;
        Verdict {
            passed: failed.is_empty(),
            failed,
            index_silently_wrong: !index_close && score.valid_fraction > 0.0,
        }
    }
}

/// One random scene: what was drawn, its score and verdict (a row of `eval --random`).
#[derive(Clone, Debug, Serialize)]
pub struct RandomRow {
    /// Index of the scene in its set.
    pub i: usize,
    /// Scene name (`random-SEED-I`).
    pub scene: String,
    /// The film's material ([`filmscope_core::optics::materials::NAMES`]).
    pub material: String,
    /// The film's true n at 550 nm.
    pub film_index: f64,
    /// Base thickness, nm.
    pub base_thickness_nm: f64,
    /// True when the thickness map has a step.
    pub step: bool,
    /// Substrate index.
    pub substrate_index: f64,
    /// Stage angles in sweep order, degrees.
    pub angles_deg: Vec<f64>,
    /// First and last band centre and the step, nm.
    pub bands_nm: [f64; 3],
    /// Number of bands.
    pub band_count: usize,
    /// Passband FWHM, nm.
    pub fwhm_nm: f64,
    /// Polarisation: s, p or unpolarized.
    pub polarization: String,
    /// `raw` (counts with white and dark references) or `float` (reflectance with noise).
    pub sensor: String,
    /// The float scenes' reflectance noise, percent.
    pub reflectance_noise_percent: Option<f64>,
    /// Interleave of the written capture: bsq, bil or bip.
    pub interleave: String,
    /// Byte order of the written capture: little or big.
    pub byte_order: String,
    /// Sensor width and height, pixels.
    pub size: [usize; 2],
    /// Estimated index at 550 nm (absent when the scene failed before a result).
    pub index_estimated: Option<f64>,
    /// The figures judged (absent when the scene failed before a result).
    pub score: Option<Score>,
    /// Wall time of the scene (simulate, write, read, estimate, score), seconds.
    pub seconds: f64,
    /// The estimator's own time, seconds.
    pub estimate_seconds: Option<f64>,
    /// Every criterion met.
    pub passed: bool,
    /// The criteria not met (`error` when the scene failed before a result).
    pub failed: Vec<String>,
    /// |index error| > 0.02 while some pixel is reported valid.
    pub index_silently_wrong: bool,
    /// What went wrong, when the scene failed before a result.
    pub note: Option<String>,
    /// A realistic scene's imperfections, as drawn (`[imperfections]`; empty: none).
    pub imperfections: String,
    /// Share of valid pixels within their reported thickness 1-sigma (absent: none valid).
    pub thickness_within_sigma: Option<f64>,
    /// Whether the index error was within its reported 1-sigma (absent: no index).
    pub index_within_sigma: Option<bool>,
    /// The index error at 550 nm over its reported 1-sigma (absent: no index or sigma).
    pub index_error_over_sigma: Option<f64>,
    /// [`EvalReport::thickness_sigma_scale_68`] (absent: no valid pixel).
    pub thickness_sigma_scale_68: Option<f64>,
}

impl RandomRow {
    /// The column titles of [`RandomRow::table_row`].
    pub fn table_header() -> String {
        format!(
            "{:>3} {:<13} {:>7} {:>5} {:>6} {:<28} {:<13} {:>4} {:<5} {:<11} {:>8} {:>7} {:>6} {:>6} {:>6} {:>5}  {}",
            "#",
            "material",
            "d nm",
            "step",
            "sub n",
            "angles deg",
            "bands nm",
            "fwhm",
            "pol",
            "sensor",
            "n err",
            "MAE nm",
            "valid",
            "silent",
            "dE00",
            "s",
            "verdict"
        )
    }

    /// One line of the table.
    pub fn table_row(&self) -> String {
        let angles: Vec<String> = self.angles_deg.iter().map(|a| format!("{a}")).collect();
        let [first, last, step] = self.bands_nm;
        let bands = format!("{first}-{last}/{step}");
        let sensor = format!(
            "{}/{}/{}",
            self.sensor,
            self.interleave,
            if self.byte_order == "big" { "be" } else { "le" }
        );
        let pol = match self.polarization.as_str() {
            "unpolarized" => "unpol",
            p => p,
        };
        let f = |x: Option<f64>, w: usize, p: usize, pct: bool, sign: bool| match x {
            None => format!("{:>w$}", "-"),
            Some(v) if pct => format!("{:>w$.p$}", 100.0 * v),
            Some(v) if sign => format!("{v:>+w$.p$}"),
            Some(v) => format!("{v:>w$.p$}"),
        };
        let s = self.score;
        let mut verdict = if self.passed {
            "PASS".to_owned()
        } else {
            format!("FAIL {}", self.failed.join(","))
        };
        if self.index_silently_wrong {
            verdict.push_str(" INDEX-SILENTLY-WRONG");
        }
        if let Some(note) = &self.note {
            verdict.push_str(&format!(" ({note})"));
        }
        if !self.imperfections.is_empty() {
            verdict.push_str(&format!(" [{}]", self.imperfections));
        }
        format!(
            "{:>3} {:<13} {:>7.1} {:>5} {:>6.3} {:<28} {:<13} {:>4.1} {:<5} {:<11} {} {} {} {} {} {:>5.2}  {verdict}",
            self.i,
            self.material,
            self.base_thickness_nm,
            if self.step { "yes" } else { "no" },
            self.substrate_index,
            angles.join(","),
            bands,
            self.fwhm_nm,
            pol,
            sensor,
            f(s.map(|s| s.index_error), 8, 4, false, true),
            f(s.map(|s| s.thickness_mae_nm), 7, 2, false, false),
            f(s.map(|s| s.valid_fraction), 5, 1, true, false) + "%",
            f(s.map(|s| s.silent_failure_rate), 5, 2, true, false) + "%",
            f(s.map(|s| s.delta_e2000_mean), 6, 3, false, false),
            self.seconds,
        )
    }
}

/// A random evaluation: every scene's row and the totals.
#[derive(Clone, Debug, Serialize)]
pub struct RandomEval {
    /// The set's seed.
    pub seed: u64,
    /// Scenes run.
    pub count: usize,
    /// Scenes that passed.
    pub passed: usize,
    /// Scenes whose index was silently wrong.
    pub index_silently_wrong: usize,
    /// Wall time of the whole evaluation, seconds.
    pub seconds: f64,
    /// The criteria applied.
    pub criteria: Criteria,
    /// Which random set ([`firmware_sim::random::draw_kind`]), by name in JSON.
    #[serde(serialize_with = "draw_name")]
    pub kind: Draw,
    /// Mean over scenes of the share of valid pixels within their thickness 1-sigma (a
    /// 1-sigma should cover about 68 %).
    pub thickness_sigma_coverage: Option<f64>,
    /// Share of scenes with an index whose error is within its 1-sigma.
    pub index_sigma_coverage: Option<f64>,
    /// One row per scene, in order.
    pub rows: Vec<RandomRow>,
}

/// A random set's name (`random`, `realistic`, `thick`) as JSON.
fn draw_name<S: serde::Serializer>(kind: &Draw, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(kind.name())
}

impl RandomEval {
    /// `random eval: P of N passed, K index silently wrong`.
    pub fn closing_line(&self) -> String {
        format!(
            "{} eval: {} of {} passed, {} index silently wrong",
            self.kind.name(),
            self.passed,
            self.count,
            self.index_silently_wrong
        )
    }

    /// `1-sigma coverage: thickness X % of valid pixels, index Y % of scenes ...`.
    pub fn coverage_line(&self) -> String {
        let pct = |x: Option<f64>| x.map_or("-".to_owned(), |v| format!("{:.0} %", 100.0 * v));
        format!(
            "1-sigma coverage: thickness {} of valid pixels, index {} of scenes with an index",
            pct(self.thickness_sigma_coverage),
            pct(self.index_sigma_coverage)
        )
    }
}

/// The criteria a random set is judged by: the realistic ones (which scale with the
/// thickness) for realistic and thick-film scenes.
fn criteria_of(kind: Draw) -> Criteria {
    match kind {
        Draw::Plain => RANDOM_CRITERIA,
        Draw::Realistic | Draw::Thick => REALISTIC_CRITERIA,
    }
}

/// Runs random scene `i` of set `seed` as a user would: draws it
/// ([`firmware_sim::random::draw`]), writes its capture into `work_dir/scene-I` with the
/// drawn interleave, byte order and sensor model, reads it back from disk, estimates with
/// `config` and judges the result by [`RANDOM_CRITERIA`]. The capture is removed after. An
/// error or panic on the way is a failed row with a note, never an error of this function.
pub fn random_scene(
    seed: u64,
    i: usize,
    config: &RunConfig,
    work_dir: &Path,
    kind: Draw,
) -> RandomRow {
    let t0 = std::time::Instant::now();
    let drawn = firmware_sim::random::draw_kind(kind, seed, i);
    let criteria = criteria_of(kind);
    let scene = &drawn.scene;
    let dir = work_dir.join(format!("scene-{i}"));
    let attempt = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        simulate_and_estimate(&drawn, config, &dir)
    }));
    let _ = std::fs::remove_dir_all(&dir);
    let bands = &scene.bands_nm;
    let mut row = RandomRow {
        i,
        scene: scene.name.clone(),
        material: drawn.material.to_owned(),
        film_index: scene.stack.film.index_at(550.0),
        base_thickness_nm: drawn.base_thickness_nm,
        step: drawn.has_step,
        substrate_index: scene.stack.substrate.index_at(550.0),
        angles_deg: scene.angles_deg.clone(),
        bands_nm: [
            bands[0],
            bands[bands.len() - 1],
            if bands.len() > 1 {
                bands[1] - bands[0]
            } else {
                0.0
            },
        ],
        band_count: bands.len(),
        fwhm_nm: scene.fwhm_nm,
        polarization: scene.stack.polarization.name().to_owned(),
        sensor: if drawn.float_reflectance {
            "float"
        } else {
            "raw"
        }
        .to_owned(),
        reflectance_noise_percent: scene.sensor.reflectance_noise_percent,
        interleave: drawn.interleave.name().to_owned(),
        byte_order: if drawn.big_endian { "big" } else { "little" }.to_owned(),
        size: [scene.sensor.width, scene.sensor.height],
        index_estimated: None,
        score: None,
        seconds: 0.0,
        estimate_seconds: None,
        passed: false,
        failed: vec!["error".to_owned()],
        index_silently_wrong: false,
        note: None,
        imperfections: describe_imperfections(&scene.imperfections, scene.stack.back_face),
        thickness_within_sigma: None,
        index_within_sigma: None,
        index_error_over_sigma: None,
        thickness_sigma_scale_68: None,
    };
    match attempt {
        Ok(Ok(report)) => {
            let score = Score::of(&report);
            let verdict = criteria.judge(&score, drawn.base_thickness_nm);
            row.index_estimated = Some(report.index_estimated);
            row.score = Some(score);
            row.estimate_seconds = Some(report.seconds);
            row.passed = verdict.passed;
            row.failed = verdict.failed;
            row.index_silently_wrong = verdict.index_silently_wrong;
            row.thickness_within_sigma = report
                .thickness_within_sigma
                .is_finite()
                .then_some(report.thickness_within_sigma);
            row.index_within_sigma = (report.index_estimated.is_finite()
                && report.index_sigma.is_finite())
            .then(|| report.index_error.abs() <= report.index_sigma);
            row.index_error_over_sigma = row
                .index_within_sigma
                .map(|_| report.index_error / report.index_sigma);
            row.thickness_sigma_scale_68 = report
                .thickness_sigma_scale_68
                .is_finite()
                .then_some(report.thickness_sigma_scale_68);
            // An undeclared back face is outside the model: refused with a note is right.
            let refused = score.valid_fraction == 0.0 && !report.notes.is_empty();
            let undeclared =
                scene.imperfections.bare_back_face && scene.stack.back_face == BackFace::None;
            if undeclared && refused {
                row.passed = true;
                row.failed.clear();
                row.note = Some("refused: undeclared back face".to_owned());
            }
        }
        Ok(Err(e)) => row.note = Some(e),
        Err(panic) => {
            let message = panic
                .downcast_ref::<String>()
                .map(String::as_str)
                .or_else(|| panic.downcast_ref::<&str>().copied())
                .unwrap_or("?");
            row.note = Some(format!("panic: {message}"));
        }
    }
    row.seconds = t0.elapsed().as_secs_f64();
    row
}

/// A scene's imperfections in one short line (empty: none).
pub fn describe_imperfections(
    imp: &firmware_sim::imperfect::Imperfections,
    declared: BackFace,
) -> String {
    let mut parts = Vec::new();
    if imp.film_k > 0.0 {
        parts.push(format!("k {} (tail {} nm)", imp.film_k, imp.film_k_tail_nm));
    }
    if imp.stage_offset_deg != 0.0 {
        parts.push(format!("stage {:+} deg", imp.stage_offset_deg));
    }
    if imp.wavelength_shift_nm != 0.0 {
        parts.push(format!("shift {:+} nm", imp.wavelength_shift_nm));
    }
    if imp.flare > 0.0 {
        parts.push(format!("flare {}", imp.flare));
    }
    if imp.polariser_leak > 0.0 {
        parts.push(format!("leak {}", imp.polariser_leak));
    }
    if imp.side_lobes > 0.0 {
        parts.push(format!("side lobes {}", imp.side_lobes));
    }
    if imp.bare_back_face {
        parts.push(if declared == BackFace::Bare {
            "bare back face (declared)".to_owned()
        } else {
            "bare back face (undeclared)".to_owned()
        });
    }
    parts.join(", ")
}

/// Writes the drawn scene's capture into `dir`, estimates from it and evaluates.
fn simulate_and_estimate(
    drawn: &firmware_sim::random::RandomScene,
    config: &RunConfig,
    dir: &Path,
) -> Result<EvalReport, String> {
    use crate::io::{ByteOrder, Interleave};
    let scene = &drawn.scene;
    let opts = crate::simulate::SimulateOptions {
        noise_free: false,
        interleave: Interleave::from_name(drawn.interleave.name()).unwrap_or(Interleave::Bil),
        byte_order: if drawn.big_endian {
            ByteOrder::Big
        } else {
            ByteOrder::Little
        },
        float_reflectance: drawn.float_reflectance,
    };
    let toml = crate::simulate::write_capture(scene, dir, opts, &|_| {})
        .map_err(|e| format!("simulate: {e}"))?;
    let cap = Capture::load(&toml).map_err(|e| format!("read: {e}"))?;
    let fov = cap.lens.field_of_view();
    let mut source = crate::source::CaptureSource::new(cap).map_err(|e| format!("read: {e}"))?;
    let settings = Settings {
        config: *config,
        film: None,
    };
    let run = crate::jobs::estimate::run(&mut source, &settings, fov, &scene.name, &Quiet)
        .map_err(|e| format!("estimate: {e}"))?;
    Ok(evaluate(&scene.name, &Truth::of_scene(scene), &run))
}

/// Runs scenes `0..count` of random set `seed` one after another ([`random_scene`]), or
/// only those of `only` below `count`, with captures in `work_dir`; `on_row` is given every
/// row as it is done.
pub fn random_eval(
    count: usize,
    seed: u64,
    config: &RunConfig,
    work_dir: &Path,
    kind: Draw,
    only: Option<&[usize]>,
    on_row: &mut dyn FnMut(&RandomRow),
) -> RandomEval {
    let t0 = std::time::Instant::now();
    let mut rows = Vec::with_capacity(count);
    let chosen: Vec<usize> = (0..count)
        .filter(|i| only.is_none_or(|o| o.contains(i)))
        .collect();
    for &i in &chosen {
        let row = random_scene(seed, i, config, work_dir, kind);
        on_row(&row);
        rows.push(row);
    }
    let within: Vec<f64> = rows
        .iter()
        .filter_map(|r| r.thickness_within_sigma)
        .collect();
    let index_within: Vec<bool> = rows.iter().filter_map(|r| r.index_within_sigma).collect();
    RandomEval {
        seed,
        count: chosen.len(),
        kind,
        passed: rows.iter().filter(|r| r.passed).count(),
        index_silently_wrong: rows.iter().filter(|r| r.index_silently_wrong).count(),
        seconds: t0.elapsed().as_secs_f64(),
        criteria: criteria_of(kind),
        thickness_sigma_coverage: (!within.is_empty())
            .then(|| within.iter().sum::<f64>() / within.len() as f64),
        index_sigma_coverage: (!index_within.is_empty()).then(|| {
            index_within.iter().filter(|&&w| w).count() as f64 / index_within.len() as f64
        }),
        rows,
    }
}

/// An improvement `eval --ablate` switches off.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Ablation {
    /// The full-spectrum refinement.
    Refine,
    /// The half-order reflection phase.
    HalfOrder,
    /// Orders from resolved neighbours.
    Neighbours,
    /// Sub-band extremum location.
    Subband,
    /// AVX2 kernels (speed only).
    WideSimd,
    /// The wide field model's per-column thickness map.
    ColumnMap,
    /// The wide field model's shared index across strips.
    SharedIndex,
}

/// Solver options and the wide field model's settings with the named improvements switched
/// off.
pub fn ablated(list: &[Ablation]) -> (SolverOptions, FieldConfig) {
    use Ablation as A;
    let mut o = SolverOptions::default();
    let mut f = FieldConfig::default();
    for a in list {
        match a {
            A::Refine => o.refine = false,
            A::HalfOrder => o.half_order = false,
            A::Neighbours => o.neighbours = false,
            A::Subband => o.subband = false,
            A::WideSimd => o.wide_simd = false,
            A::ColumnMap => f.column_map = false,
            A::SharedIndex => f.shared_rounds = false,
        }
    }
    (o, f)
}

/// What `eval` is given: a scene file (loaded) or a capture directory with truth.
pub enum Input {
    /// A scene, simulated on the software camera.
    Scene(Box<Scene>),
    /// A capture directory.
    Capture(PathBuf),
}

/// Whether `path` names a scene file (`Some(true)`), a capture (`Some(false)`) or neither.
pub fn input_kind(path: &Path) -> Option<bool> {
    if path.is_dir() || path.file_name().is_some_and(|n| n == "capture.toml") {
        Some(false)
    } else if path.extension().is_some_and(|e| e == "toml") {
        Some(true)
    } else {
        None
    }
}

/// A scene file (its seed replaced by `seed` when given) or a capture directory.
pub fn input(path: &Path, seed: Option<u64>) -> Result<Input> {
    if path.is_dir() {
        Ok(Input::Capture(path.to_owned()))
    } else if path.extension().is_some_and(|e| e == "toml")
        && path.file_name().is_some_and(|n| n != "capture.toml")
    {
        Ok(Input::Scene(Box::new(Scene::load_seeded(path, seed)?)))
    } else if path.file_name().is_some_and(|n| n == "capture.toml") {
        Ok(Input::Capture(
            path.parent().unwrap_or(Path::new(".")).to_owned(),
        ))
    } else {
        Err(LabError::Invalid(format!(
            "{}: neither a scene file (.toml) nor a capture directory",
            path.display()
        )))
    }
}

/// Evaluates one input of `eval`: a scene file (seed replaced by `seed` when given) on the
/// software camera, or a capture directory read from disk (its memory checked first),
/// each estimated ([`crate::jobs::estimate::run`], telling `observer`) and judged against
/// its truth.
pub fn eval_one(
    path: &Path,
    config: &RunConfig,
    seed: Option<u64>,
    observer: &dyn Observer,
) -> Result<(EvalReport, Run)> {
    let settings = Settings {
        config: *config,
        film: None,
    };
    match input(path, seed)? {
        Input::Scene(scene) => {
            let truth = Truth::of_scene(&scene);
            let name = scene.name.clone();
            let fov = scene.field_of_view;
            let mut source = SimSource::new(SoftwareCamera::new(*scene), false, 1)
                .map_err(|e| LabError::Invalid(format!("{}: {e}", path.display())))?;
            let run = crate::jobs::estimate::run(&mut source, &settings, fov, &name, observer)?;
            Ok((evaluate(&name, &truth, &run), run))
        }
        Input::Capture(dir) => {
            let truth = Truth::of_capture_dir(&dir).map_err(LabError::invalid)?;
            let cap = Capture::load(&dir)?;
            crate::estimate::check_capture_memory(&cap, config.method, None)
                .map_err(LabError::invalid)?;
            let fov = cap.lens.field_of_view();
            let mut source = CaptureSource::new(cap).map_err(LabError::invalid)?;
            let name = dir.display().to_string();
            let run = crate::jobs::estimate::run(&mut source, &settings, fov, &name, observer)?;
            Ok((evaluate(&name, &truth, &run), run))
        }
    }
}

/// Writes each of random set `seed`'s first `count` scenes of draw `kind` into `dir` as
/// `random-SEED-I.toml`, so a row can be run again with `eval FILE`.
pub fn save_random_scenes(dir: &Path, count: usize, seed: u64, kind: Draw) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(LabError::file(dir, "create"))?;
    for i in 0..count {
        let drawn = firmware_sim::random::draw_kind(kind, seed, i);
        let path = dir.join(format!("{}.toml", drawn.scene.name));
        crate::io::write_atomic(&path, drawn.toml.as_bytes())
            .map_err(LabError::file(&path, "write"))?;
    }
    Ok(())
}

/// A temporary folder for random set `seed`'s captures ([`random_eval`]'s `work_dir`),
/// removed when dropped.
pub fn random_work_dir(seed: u64) -> Result<tempfile::TempDir> {
    tempfile::Builder::new()
        .prefix(&format!("filmscope-random-{seed}-"))
        .tempdir()
        .map_err(LabError::step("cannot create a temporary folder"))
}
