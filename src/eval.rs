//! Accuracy against the truth: index error, thickness errors, silent failures, and the
//! reproduced colour (spectral RMSE, CIE76, CIEDE2000) at every angle.
//!
//! Colour is compared on the film model over the whole visible range (380-780 nm, D65,
//! CIE 1931 2 deg, with [`FilmColour`], the model the renders use): the true film (true index with its dispersion, true thickness) against
//! the estimated one, pixel by pixel, at each angle of the sweep. The spectral RMSE (method.md
//! eq. 16) compares the two band-averaged spectra over the capture's own bands.

use std::path::Path;

use filmscope_core::colour::{
    delta_e2000, delta_e76, spectral_rmse, Colorimetry, Illuminant, D65_WHITE_XYZ,
};
use filmscope_core::optics::{Dispersion, FilmStack, Polarization};
use serde::Serialize;

use crate::appearance::spectral::{capture_passbands, BandSpectrum, FilmColour};
use crate::estimate::Run;
use crate::io::read_cube;

/// Thickness errors above this are failures (nm).
pub const SILENT_FAILURE_NM: f64 = 20.0;

/// What is true about a sweep.
#[derive(Clone, Debug)]
pub struct Truth {
    /// The film's index (with dispersion).
    pub film: Dispersion,
    /// Substrate index.
    pub substrate_index: f64,
    /// Ambient index.
    pub ambient_index: f64,
    /// Polarisation.
    pub polarization: Polarization,
    /// Thickness per pixel, row-major, nm.
    pub thickness_nm: Vec<f32>,
}

impl Truth {
    /// The truth of a scene.
    pub fn of_scene(scene: &firmware_sim::Scene) -> Self {
        Self {
            film: scene.stack.film,
            substrate_index: scene.stack.substrate.index_at(550.0),
            ambient_index: scene.stack.ambient_index,
            polarization: scene.stack.polarization,
            thickness_nm: scene.thickness_nm.clone(),
        }
    }

    /// The truth written beside a simulated capture (`truth.json`, `truth/thickness_nm.hdr`).
    pub fn of_capture_dir(dir: &Path) -> Result<Self, String> {
        let path = dir.join("truth.json");
        let text =
            std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let v: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        let num = |k: &str| v.get(k).and_then(serde_json::Value::as_f64);
        let bad = |what: &str| format!("{}: {what}", path.display());
        let n = num("refractive_index").ok_or_else(|| bad("no refractive_index"))?;
        let film = match v.get("dispersion") {
            None | Some(serde_json::Value::Null) => Dispersion::constant(n),
            Some(d) => parse_dispersion(d)
                .ok_or_else(|| bad("dispersion is neither null, cauchy nor sellmeier"))?,
        };
        let pol = v
            .get("polarization")
            .and_then(|p| p.as_str())
            .and_then(Polarization::from_name)
            .unwrap_or(Polarization::S);
        let map = dir.join("truth").join("thickness_nm.hdr");
        let cube = read_cube(&map).map_err(|e| e.to_string())?;
        Ok(Self {
            film,
            substrate_index: num("substrate_index").ok_or_else(|| bad("no substrate_index"))?,
            ambient_index: num("ambient_index").unwrap_or(1.0),
            polarization: pol,
            thickness_nm: cube.data,
        })
    }
}

/// Parses a `dispersion` object of a summary or truth file (`cauchy` or `sellmeier`).
pub(crate) fn parse_dispersion(d: &serde_json::Value) -> Option<Dispersion> {
    let f = |k: &str| d.get(k).and_then(serde_json::Value::as_f64);
    let arr = |k: &str| -> Option<[f64; 3]> {
        let a = d.get(k)?.as_array()?;
        let mut out = [0.0; 3];
        for (o, x) in out.iter_mut().zip(a) {
            *o = x.as_f64()?;
        }
        Some(out)
    };
    match d.get("model")?.as_str()? {
        "cauchy" => Some(Dispersion::Cauchy {
            a: f("a")?,
            b_um2: f("b_um2")?,
            c_um4: f("c_um4").unwrap_or(0.0),
        }),
        "sellmeier" => Some(Dispersion::Sellmeier {
            a: f("a")?,
            b: arr("b")?,
            c_um: arr("c_um")?,
        }),
        _ => None,
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
    pub field_model_choice: serde_json::Value,
}

/// Compares a run with the truth.
pub fn evaluate(scene: &str, truth: &Truth, run: &Run) -> EvalReport {
    let r = &run.result;
    let n_px = truth.thickness_nm.len().min(r.thickness_nm.len());
    let est_film = r.index.dispersion();
    let true_stack = FilmStack {
        ambient_index: truth.ambient_index,
        film: truth.film,
        substrate: Dispersion::constant(truth.substrate_index),
        polarization: truth.polarization,
    };
    let est_stack = FilmStack {
        film: est_film,
        ..true_stack
    };
    let mut errs = Vec::new();
    let mut silent = 0usize;
    let mut valid_px = Vec::new();
    for i in 0..n_px {
        let (t, e) = (
            f64::from(truth.thickness_nm[i]),
            f64::from(r.thickness_nm[i]),
        );
        if e.is_finite() {
            let d = (e - t).abs();
            if d > SILENT_FAILURE_NM {
                silent += 1;
            }
            errs.push(d);
            valid_px.push(i);
        }
    }
    let nv = errs.len().max(1) as f64;
    let mae = errs.iter().sum::<f64>() / nv;
    let rmse = (errs.iter().map(|e| e * e).sum::<f64>() / nv).sqrt();
    let max = errs.iter().copied().fold(0.0, f64::max);
    // Colour and spectra on at most ~4000 valid pixels (evenly strided) per angle.
    let stride = (valid_px.len() / 4000).max(1);
    let sample: Vec<usize> = valid_px.iter().copied().step_by(stride).collect();
    let bands = capture_passbands(&run.spec.bands_nm, &run.spec.fwhm_nm);
    let visible = Colorimetry::full(Illuminant::D65);
    let (mut de76_all, mut de00_all, mut rmse_all) = (Vec::new(), Vec::new(), Vec::new());
    let (mut de76_angle, mut de00_angle) = (Vec::new(), Vec::new());
    let (mut r_true, mut r_est) = (vec![0.0; bands.len()], vec![0.0; bands.len()]);
    for &deg in &run.angles_deg {
        let (true_bands, est_bands) = (
            BandSpectrum::new(true_stack, deg, &bands),
            BandSpectrum::new(est_stack, deg, &bands),
        );
        let (true_colour, est_colour) = (
            FilmColour::new(true_stack, deg, visible),
            FilmColour::new(est_stack, deg, visible),
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
    EvalReport {
        scene: scene.to_owned(),
        method: r.method.name().to_owned(),
        index_true: n_true,
        index_estimated: n_est,
        index_error: n_est - n_true,
        thickness_mae_nm: if errs.is_empty() { f64::NAN } else { mae },
        thickness_rmse_nm: if errs.is_empty() { f64::NAN } else { rmse },
        thickness_max_error_nm: if errs.is_empty() { f64::NAN } else { max },
        valid_fraction: errs.len() as f64 / n_px.max(1) as f64,
        silent_failure_rate: silent as f64 / n_px.max(1) as f64,
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
