//! `filmscope._native`: the estimator, the forward model and the simulator for Python.
//!
//! The pure-Python package `filmscope` (python/filmscope) wraps these functions: it turns
//! NumPy arrays into bytes and back and JSON text into dicts, so this module needs no NumPy
//! bindings. Maps cross as native-endian bytes (`float32`, flags `uint16`); every error is a
//! `filmscope.FilmscopeError` (a `ValueError`) with one line naming the file, key or value
//! at fault. The estimator and the forward model run with the GIL released.

use std::path::PathBuf;

use crossbeam_channel::Sender;
use filmscope::estimate::method::Method;
use filmscope::estimate::{FieldChoice, FieldConfig};
use filmscope::estimate::{Run, RunConfig};
use filmscope::io::{ByteOrder, Capture, Interleave};
use filmscope::jobs::{self, GivenIndex, Quiet, Settings};
use filmscope::pipeline::PipelineConfig;
use filmscope::simulate::{write_capture, SimulateOptions};
use filmscope::source::{
    stream_band_sequential, sweep_spec, CaptureSource, Samples, Source, StreamMsg,
    DEFAULT_INDEX_RANGE,
};
use filmscope::summary::Summary;
use filmscope_core::optics::{BackFace, Dispersion, FilmStack, Passband, Polarization};
use filmscope_core::solve::SweepSpec;
use firmware_sim::{Scene, SoftwareCamera};
use pyo3::create_exception;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

create_exception!(
    _native,
    FilmscopeError,
    PyValueError,
    "A capture, scene, material or option filmscope cannot use; the message names it."
);

fn fail(message: impl std::fmt::Display) -> PyErr {
    FilmscopeError::new_err(message.to_string())
}

/// How to run the estimator, from the keyword options of `filmscope.estimate`.
#[derive(Clone, Copy)]
struct Options<'a> {
    method: &'a str,
    workers: usize,
    channel_capacity: usize,
    index_pixels: usize,
    sample_sites: usize,
    one_pass: bool,
    field: &'a str,
    model_error: Option<f64>,
    rig_tolerance: Option<f64>,
}

impl Options<'_> {
    /// The run configuration, checked as the command line checks it.
    fn config(&self) -> Result<RunConfig, String> {
        let method = Method::from_name(self.method)
            .ok_or_else(|| format!("method {:?}: use filmscope, paper or brute", self.method))?;
        let choice = FieldChoice::from_name(self.field)
            .ok_or_else(|| format!("field {:?}: use auto, narrow or wide", self.field))?;
        if let Some(m) = self.model_error {
            if let Some(p) = filmscope::io::capture::model_error_problem(m) {
                return Err(format!("model_error {m}: {p}"));
            }
        }
        if let Some(t) = self.rig_tolerance {
            if let Some(p) = filmscope::io::capture::rig_tolerance_problem(t) {
                return Err(format!("rig_tolerance {t}: {p}"));
            }
        }
        let max = filmscope_core::solve::sample::MAX_SITES;
        if !(4..=max).contains(&self.sample_sites) {
            return Err(format!(
                "sample_sites {}: must be 4 to {max}",
                self.sample_sites
            ));
        }
        let brute = filmscope::estimate::baseline::BruteGrid::default();
        filmscope::limits::check_cli(
            self.workers,
            self.channel_capacity,
            self.index_pixels,
            brute.index_steps,
            brute.thickness_step_nm,
        )?;
        let mut pipeline = PipelineConfig {
            channel_capacity: self.channel_capacity,
            workers: self.workers,
            ..PipelineConfig::default()
        };
        pipeline.solver.index_pixels = self.index_pixels;
        Ok(RunConfig {
            method,
            pipeline,
            brute_grid: brute,
            field: FieldConfig {
                choice,
                ..FieldConfig::default()
            },
            sample_sites: self.sample_sites,
            one_pass: self.one_pass,
            model_error: self.model_error,
            rig_tolerance: self.rig_tolerance,
        })
    }
}

/// A folder under the system's temporary folder for outputs nobody asked to keep, removed
/// when dropped.
struct Scratch(PathBuf);

impl Scratch {
    fn new() -> Result<Self, String> {
        use std::sync::atomic::{AtomicUsize, Ordering};
        static COUNT: AtomicUsize = AtomicUsize::new(0);
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let dir = std::env::temp_dir().join(format!(
            "filmscope-py-{}-{nanos}-{}",
            std::process::id(),
            COUNT.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        Ok(Self(dir))
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// `out`, or a folder in a new scratch folder (returned too: removed when dropped) for
/// outputs nobody asked to keep.
fn out_or_scratch(out: Option<PathBuf>) -> Result<(PathBuf, Option<Scratch>), String> {
    match out {
        Some(out) => Ok((out, None)),
        None => {
            let scratch = Scratch::new()?;
            Ok((scratch.0.join("estimate"), Some(scratch)))
        }
    }
}

/// Writes the run's outputs into `out` (or a scratch folder) and returns the summary.
fn outputs(run: &Run, out: Option<PathBuf>, label: &str) -> Result<Summary, String> {
    let (dir, _scratch) = out_or_scratch(out)?;
    jobs::estimate::write(&dir, run, label).map_err(|e| e.to_string())
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_ne_bytes()).collect()
}

/// The run's maps and summary as the dict `filmscope.estimate` unpacks.
fn result_dict<'py>(py: Python<'py>, run: &Run, summary: &Summary) -> PyResult<Bound<'py, PyDict>> {
    let r = &run.result;
    let d = PyDict::new(py);
    d.set_item("width", run.spec.width)?;
    d.set_item("height", run.spec.height)?;
    d.set_item(
        "thickness_nm",
        PyBytes::new(py, &f32_bytes(&r.thickness_nm)),
    )?;
    d.set_item("confidence", PyBytes::new(py, &f32_bytes(&r.confidence)))?;
    d.set_item(
        "sigma_nm",
        PyBytes::new(py, &f32_bytes(&r.thickness_sigma_nm)),
    )?;
    let flags: Vec<u8> = r.flags.iter().flat_map(|f| f.to_ne_bytes()).collect();
    d.set_item("flags", PyBytes::new(py, &flags))?;
    let summary = serde_json::to_string(summary)
        .map_err(|e| FilmscopeError::new_err(format!("summary: {e}")))?;
    d.set_item("summary", summary)?;
    Ok(d)
}

/// Runs the estimator on the capture at `path` (a folder or its capture.toml), as
/// `filmscope estimate` does; writes the outputs into `out` when given.
#[pyfunction]
#[pyo3(signature = (path, out, method, workers, channel_capacity, index_pixels, sample_sites, one_pass, field, film_index, model_error, rig_tolerance))]
#[allow(clippy::too_many_arguments)]
fn estimate_capture<'py>(
    py: Python<'py>,
    path: PathBuf,
    out: Option<PathBuf>,
    method: &str,
    workers: usize,
    channel_capacity: usize,
    index_pixels: usize,
    sample_sites: usize,
    one_pass: bool,
    field: &str,
    film_index: Option<&str>,
    model_error: Option<f64>,
    rig_tolerance: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let opts = Options {
        method,
        workers,
        channel_capacity,
        index_pixels,
        sample_sites,
        one_pass,
        field,
        model_error,
        rig_tolerance,
    };
    let config = opts.config().map_err(fail)?;
    let film = given_index(film_index)?;
    let (run, summary) = py
        .detach(|| -> Result<(Run, Summary), String> {
            let (out, _scratch) = out_or_scratch(out)?;
            let request = jobs::EstimateRequest {
                capture: path,
                out,
                out_option: "out",
                film_option: "film_index",
                settings: Settings { config, film },
                memory_budget: None,
            };
            let outcome =
                jobs::estimate::estimate_capture(&request, &Quiet).map_err(|e| e.to_string())?;
            Ok((outcome.run, outcome.summary))
        })
        .map_err(fail)?;
    result_dict(py, &run, &summary)
}

/// The film's given index (`film_index`, JSON text as [`dispersion`] reads it); the job's
/// [`Settings::check`] refuses it with a method other than filmscope.
fn given_index(film_index: Option<&str>) -> PyResult<Option<GivenIndex>> {
    let Some(text) = film_index else {
        return Ok(None);
    };
    let dispersion = dispersion(text, "film_index").map_err(fail)?;
    Ok(Some(GivenIndex {
        name: text.trim_matches('"').to_owned(),
        dispersion,
    }))
}

/// A sweep of calibrated reflectance held in memory, `(angles, lines, samples, bands)` in
/// C order, streamed band by band with its angles in increasing incidence (as a capture on
/// disk streams).
struct ArraySource {
    data: Vec<f32>,
    shape: [usize; 4],
    /// Indices into the array's angle axis, by increasing incidence.
    order: Vec<usize>,
    angles_deg: Vec<f64>,
    spec: SweepSpec,
}

impl Source for ArraySource {
    fn spec(&self) -> &SweepSpec {
        &self.spec
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.order.iter().map(|&a| self.angles_deg[a]).collect()
    }

    fn stream(&mut self, tx: &Sender<StreamMsg>) {
        let [_, lines, samples, bands] = self.shape;
        let angles = self.angles_deg();
        let (data, order) = (&self.data, &self.order);
        stream_band_sequential(tx, &angles, bands, lines, 16, |a, b, r0, rows| {
            let a = order[a];
            let mut v = Vec::with_capacity(rows * samples);
            for r in r0..r0 + rows {
                let base = (a * lines + r) * samples * bands;
                v.extend((0..samples).map(|s| data[base + s * bands + b]));
            }
            Samples::Reflectance(v)
        });
    }
}

/// The sample around the film, as `filmscope.estimate` and `filmscope.reflectance` take it.
fn polarization(name: &str) -> Result<Polarization, String> {
    Polarization::from_name(&name.trim().to_lowercase())
        .ok_or_else(|| format!("polarization {name:?}: expected \"s\", \"p\" or \"unpolarized\""))
}

/// The substrate's back face by name, `"none"` or `"bare"`.
fn back_face(name: &str) -> Result<BackFace, String> {
    BackFace::from_name(&name.trim().to_lowercase())
        .ok_or_else(|| format!("back_face {name:?}: expected \"none\" or \"bare\""))
}

/// Runs the estimator on a reflectance array: `data` the native-endian `float32` bytes of
/// a C-ordered `(angles, lines, samples, bands)` array.
#[pyfunction]
#[pyo3(signature = (data, shape, wavelengths_nm, angles_deg, fwhm_nm, ambient_index, substrate, polarization_name, back_face_name, index_range, thickness_range_nm, out, method, workers, channel_capacity, index_pixels, sample_sites, one_pass, film_index, model_error, rig_tolerance))]
#[allow(clippy::too_many_arguments)]
fn estimate_array<'py>(
    py: Python<'py>,
    data: &[u8],
    shape: [usize; 4],
    wavelengths_nm: Vec<f64>,
    angles_deg: Vec<f64>,
    fwhm_nm: Option<Vec<f64>>,
    ambient_index: f64,
    substrate: &str,
    polarization_name: &str,
    back_face_name: &str,
    index_range: Option<[f64; 2]>,
    thickness_range_nm: Option<[f64; 2]>,
    out: Option<PathBuf>,
    method: &str,
    workers: usize,
    channel_capacity: usize,
    index_pixels: usize,
    sample_sites: usize,
    one_pass: bool,
    film_index: Option<&str>,
    model_error: Option<f64>,
    rig_tolerance: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let opts = Options {
        method,
        workers,
        channel_capacity,
        index_pixels,
        sample_sites,
        one_pass,
        field: "narrow",
        model_error,
        rig_tolerance,
    };
    let config = opts.config().map_err(fail)?;
    let film = given_index(film_index)?;
    let axes = ArrayAxes {
        shape,
        wavelengths_nm: &wavelengths_nm,
        angles_deg: &angles_deg,
        fwhm_nm: fwhm_nm.as_deref(),
    };
    axes.check(data.len()).map_err(fail)?;
    let sample = ArraySample {
        ambient_index,
        substrate,
        polarization_name,
        back_face_name,
        index_range,
        thickness_range_nm,
    };
    let spec = sample.spec(&axes).map_err(fail)?;
    let values: Vec<f32> = data
        .chunks_exact(4)
        .map(|c| f32::from_ne_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let order = axes.order().map_err(fail)?;
    let mut source = ArraySource {
        data: values,
        shape,
        order,
        angles_deg,
        spec,
    };
    let (run, summary) = py
        .detach(|| -> Result<(Run, Summary), String> {
            let settings = Settings { config, film };
            settings.check("film_index").map_err(|e| e.to_string())?;
            let run = jobs::estimate::run(&mut source, &settings, None, "array", &Quiet)
                .map_err(|e| e.to_string())?;
            let summary = outputs(&run, out, "array")?;
            Ok((run, summary))
        })
        .map_err(fail)?;
    result_dict(py, &run, &summary)
}

/// The shape and axes `filmscope.estimate` gives with a reflectance array.
struct ArrayAxes<'a> {
    /// `(angles, lines, samples, bands)`.
    shape: [usize; 4],
    wavelengths_nm: &'a [f64],
    angles_deg: &'a [f64],
    fwhm_nm: Option<&'a [f64]>,
}

impl ArrayAxes<'_> {
    /// Checks that an array of `bytes` bytes has the shape, that every axis has a value per
    /// index of its dimension, and that there is an angle and every angle is in [0, 90).
    fn check(&self, bytes: usize) -> Result<(), String> {
        let shape = self.shape;
        let [na, lines, samples, bands] = shape;
        if bytes != na * lines * samples * bands * 4 {
            return Err(format!(
                "array: {} bytes for shape {shape:?} (expected {})",
                bytes,
                na * lines * samples * bands * 4
            ));
        }
        if self.wavelengths_nm.len() != bands {
            return Err(format!(
                "wavelengths_nm: {} values for {bands} bands (the array's last axis)",
                self.wavelengths_nm.len()
            ));
        }
        if self.angles_deg.len() != na {
            return Err(format!(
                "angles_deg: {} values for {na} angles (the array's first axis)",
                self.angles_deg.len()
            ));
        }
        if let Some(f) = self.fwhm_nm {
            if f.len() != bands {
                return Err(format!("fwhm_nm: {} values for {bands} bands", f.len()));
            }
        }
        if na < 1 {
            return Err("array: at least one angle is needed".to_owned());
        }
        for &a in self.angles_deg {
            if !(a.is_finite() && (0.0..90.0).contains(&a)) {
                return Err(format!("angles_deg: {a} is outside [0, 90)"));
            }
        }
        Ok(())
    }

    /// The indices of the angle axis by increasing incidence; an error if an angle appears
    /// twice.
    fn order(&self) -> Result<Vec<usize>, String> {
        let angles_deg = self.angles_deg;
        let mut order: Vec<usize> = (0..angles_deg.len()).collect();
        order.sort_by(|&a, &b| angles_deg[a].total_cmp(&angles_deg[b]));
        for w in order.windows(2) {
            if (angles_deg[w[0]] - angles_deg[w[1]]).abs() < 1e-6 {
                return Err(format!("angles_deg: {} appears twice", angles_deg[w[0]]));
            }
        }
        Ok(order)
    }
}

/// The sample around the film and the search ranges `filmscope.estimate` gives with a
/// reflectance array.
struct ArraySample<'a> {
    ambient_index: f64,
    /// The substrate, JSON text as [`dispersion`] reads it.
    substrate: &'a str,
    polarization_name: &'a str,
    back_face_name: &'a str,
    index_range: Option<[f64; 2]>,
    thickness_range_nm: Option<[f64; 2]>,
}

impl ArraySample<'_> {
    /// The sweep's spec: the array's size and bands with this sample, checked as a
    /// capture's are.
    fn spec(&self, axes: &ArrayAxes) -> Result<SweepSpec, String> {
        let [_, lines, samples, _] = axes.shape;
        let substrate_d = dispersion(self.substrate, "substrate")?;
        let pol = polarization(self.polarization_name)?;
        filmscope::limits::check_sample(
            "ambient_index",
            self.ambient_index,
            "substrate",
            substrate_d.index_at(550.0),
        )
        .map_err(|e| e.to_string())?;
        Ok(sweep_spec(
            samples,
            lines,
            axes.wavelengths_nm,
            axes.fwhm_nm,
            self.ambient_index,
            substrate_d.index_at(550.0),
            pol,
            self.index_range.unwrap_or(DEFAULT_INDEX_RANGE),
            self.thickness_range_nm,
        )
        .map_err(|e| e.to_string())?
        .with_substrate(substrate_d)
        .with_back_face(back_face(self.back_face_name)?))
    }
}

/// The dispersion given as JSON text (a number, a name or path string, or an object).
fn dispersion(json_text: &str, what: &str) -> Result<Dispersion, String> {
    let v: serde_json::Value =
        serde_json::from_str(json_text).map_err(|e| format!("{what}: {e}"))?;
    filmscope::material::dispersion_from_json(&v).map_err(|e| format!("{what}: {e}"))
}

/// The index of a material (JSON text as [`dispersion`] reads it) at each wavelength.
#[pyfunction]
fn index_at(material: &str, wavelengths_nm: Vec<f64>) -> PyResult<Vec<f64>> {
    let d = dispersion(material, "n_model").map_err(fail)?;
    Ok(wavelengths_nm.iter().map(|&l| d.index_at(l)).collect())
}

/// The forward model at every `(thickness, angle)` pair and wavelength: native-endian
/// `float64` bytes, pair-major.
#[pyfunction]
#[pyo3(signature = (film, thickness_nm, angles_deg, wavelengths_nm, fwhm_nm, substrate, ambient_index, polarization_name, back_face_name))]
#[allow(clippy::too_many_arguments)]
fn reflectance<'py>(
    py: Python<'py>,
    film: &str,
    thickness_nm: Vec<f64>,
    angles_deg: Vec<f64>,
    wavelengths_nm: Vec<f64>,
    fwhm_nm: f64,
    substrate: &str,
    ambient_index: f64,
    polarization_name: &str,
    back_face_name: &str,
) -> PyResult<Bound<'py, PyBytes>> {
    let stack = FilmStack {
        back_face: back_face(back_face_name).map_err(fail)?,
        ambient_index,
        film: dispersion(film, "n_model").map_err(fail)?,
        substrate: dispersion(substrate, "substrate").map_err(fail)?,
        polarization: polarization(polarization_name).map_err(fail)?,
    };
    if thickness_nm.len() != angles_deg.len() {
        return Err(fail("thickness_nm and angles_deg must pair up"));
    }
    if !(ambient_index.is_finite() && ambient_index >= 1.0) {
        return Err(fail(format!("ambient_index {ambient_index}: must be >= 1")));
    }
    if !(fwhm_nm.is_finite() && fwhm_nm >= 0.0) {
        return Err(fail(format!("fwhm_nm {fwhm_nm}: must be >= 0")));
    }
    for &a in &angles_deg {
        if !(a.is_finite() && (0.0..90.0).contains(&a)) {
            return Err(fail(format!("angles_deg: {a} is outside [0, 90)")));
        }
    }
    for &l in &wavelengths_nm {
        if !(l.is_finite() && l > 0.0) {
            return Err(fail(format!("wavelengths_nm: {l} must be positive")));
        }
    }
    let out = py.detach(|| {
        let bands: Vec<Passband> = wavelengths_nm
            .iter()
            .map(|&l| Passband::gaussian(l, fwhm_nm))
            .collect();
        let mut out = Vec::with_capacity(thickness_nm.len() * bands.len() * 8);
        for (&d, &a) in thickness_nm.iter().zip(&angles_deg) {
            for band in &bands {
                let r = if fwhm_nm == 0.0 {
                    stack.reflectance(d, a, band.center_nm)
                } else {
                    stack.band_reflectance(d, a, band)
                };
                out.extend_from_slice(&r.to_ne_bytes());
            }
        }
        out
    });
    Ok(PyBytes::new(py, &out))
}

/// The scene from a TOML file or TOML text, its seed replaced when `seed` is given.
fn scene(path: Option<PathBuf>, text: Option<String>, seed: Option<u64>) -> Result<Scene, String> {
    match (path, text) {
        (Some(p), None) => Scene::load_seeded(&p, seed).map_err(|e| e.to_string()),
        (None, Some(t)) => Scene::from_toml_seeded(&t, "scene", seed).map_err(|e| e.to_string()),
        _ => Err("simulate: give a scene file or a scene".into()),
    }
}

/// Simulates a scene (a TOML file or TOML text): written as a capture into `out`, or, with
/// no `out`, returned as a float32 reflectance cube `(angles, lines, samples, bands)` with
/// the truth.
#[pyfunction]
#[pyo3(signature = (path, text, out, noise_free, interleave, byte_order, float_reflectance, seed))]
#[allow(clippy::too_many_arguments)]
fn simulate<'py>(
    py: Python<'py>,
    path: Option<PathBuf>,
    text: Option<String>,
    out: Option<PathBuf>,
    noise_free: bool,
    interleave: &str,
    byte_order: &str,
    float_reflectance: bool,
    seed: Option<u64>,
) -> PyResult<Bound<'py, PyDict>> {
    let scene = scene(path, text, seed).map_err(fail)?;
    let d = PyDict::new(py);
    d.set_item("name", &scene.name)?;
    if let Some(out) = out {
        let opts = SimulateOptions {
            noise_free,
            interleave: Interleave::from_name(interleave)
                .ok_or_else(|| fail(format!("interleave {interleave:?}: use bil, bsq or bip")))?,
            byte_order: match byte_order {
                "little" => ByteOrder::Little,
                "big" => ByteOrder::Big,
                other => return Err(fail(format!("byte_order {other:?}: use little or big"))),
            },
            float_reflectance,
        };
        let toml = py
            .detach(|| write_capture(&scene, &out, opts, &|_| {}))
            .map_err(fail)?;
        d.set_item("capture", toml)?;
        return Ok(d);
    }
    let camera = SoftwareCamera::new(scene.clone());
    let (w, h, nb) = (camera.width(), camera.height(), scene.bands_nm.len());
    let na = scene.angles_deg.len();
    let cube = py.detach(|| {
        let mut cube = vec![0f32; na * h * w * nb];
        let mut row = vec![0f32; w];
        let mut raw = vec![0u16; w];
        let (mut white, mut dark) = (vec![0f32; w], vec![0f32; w]);
        for a in 0..na {
            for b in 0..nb {
                for r in 0..h {
                    if noise_free {
                        camera.reflectance_row(a, b, r, &mut row);
                    } else {
                        camera.raw_row(a, b, r, &mut raw);
                        camera.white_row(a, b, r, &mut white);
                        camera.dark_row(a, b, r, &mut dark);
                        for (((o, &c), &wh), &dk) in row.iter_mut().zip(&raw).zip(&white).zip(&dark)
                        {
                            let span = wh - dk;
                            *o = if span > 0.0 {
                                (f32::from(c) - dk) / span
                            } else {
                                f32::NAN
                            };
                        }
                    }
                    for (s, &v) in row.iter().enumerate() {
                        cube[((a * h + r) * w + s) * nb + b] = v;
                    }
                }
            }
        }
        cube
    });
    d.set_item("reflectance", PyBytes::new(py, &f32_bytes(&cube)))?;
    d.set_item("shape", (na, h, w, nb))?;
    d.set_item("wavelengths_nm", scene.bands_nm.clone())?;
    d.set_item("angles_deg", scene.angles_deg.clone())?;
    d.set_item("fwhm_nm", scene.fwhm_nm)?;
    d.set_item(
        "thickness_nm",
        PyBytes::new(py, &f32_bytes(&scene.thickness_nm)),
    )?;
    d.set_item("ambient_index", scene.stack.ambient_index)?;
    d.set_item(
        "substrate",
        serde_json::to_string(&filmscope::material::DispersionRecord::from(
            scene.stack.substrate,
        ))
        .unwrap_or_default(),
    )?;
    d.set_item(
        "film",
        serde_json::to_string(&filmscope::material::DispersionRecord::from(
            scene.stack.film,
        ))
        .unwrap_or_default(),
    )?;
    d.set_item("polarization", scene.stack.polarization.name())?;
    Ok(d)
}

/// Writes a material as a refractiveindex.info YAML entry valid over `[lo_nm, hi_nm]`
/// (`.yml`, `.yaml`) or as a `wavelength_nm,n` CSV table at 1 nm steps over it (`.csv`).
#[pyfunction]
fn write_material(material: &str, path: PathBuf, lo_nm: f64, hi_nm: f64) -> PyResult<()> {
    let d = dispersion(material, "n_model").map_err(fail)?;
    if !(lo_nm.is_finite() && hi_nm.is_finite() && 0.0 < lo_nm && lo_nm < hi_nm) {
        return Err(fail(format!(
            "range_nm [{lo_nm}, {hi_nm}]: expected 0 < low < high"
        )));
    }
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let text = match ext.as_str() {
        "yml" | "yaml" => filmscope::material::to_rii_yaml(&d, [lo_nm, hi_nm], "filmscope"),
        "csv" => {
            let n = (hi_nm - lo_nm).floor() as usize;
            let wl: Vec<f64> = (0..=n).map(|i| lo_nm + i as f64).collect();
            filmscope::material::to_csv(&d, &wl)
        }
        _ => {
            return Err(fail(format!(
                "{}: expected a .yml, .yaml or .csv file name",
                path.display()
            )))
        }
    };
    filmscope::io::write_atomic(&path, text.as_bytes())
        .map_err(|e| fail(format!("{}: {e}", path.display())))
}

/// The calibrated spectra of pixel `(x, y)` of a capture and its sample: a dict of
/// `angles_deg`, `wavelengths_nm`, `fwhm_nm`, `measured` (`float64` bytes, `[angle][band]`),
/// `substrate` (JSON), `ambient_index`, `polarization`.
#[pyfunction]
fn capture_spectra<'py>(
    py: Python<'py>,
    path: PathBuf,
    x: usize,
    y: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let (spec, angles, measured) = py
        .detach(|| -> Result<_, String> {
            let cap = Capture::load(&path).map_err(|e| e.to_string())?;
            let mut source = CaptureSource::new(cap)?;
            let spec = source.spec().clone();
            let (angles, measured) =
                filmscope::appearance::pixel::measured_spectra(&mut source, x, y)
                    .map_err(|e| e.to_string())?;
            Ok((spec, angles, measured))
        })
        .map_err(fail)?;
    let d = PyDict::new(py);
    d.set_item("angles_deg", angles)?;
    d.set_item("wavelengths_nm", spec.bands_nm.to_vec())?;
    d.set_item("fwhm_nm", spec.fwhm_nm.to_vec())?;
    let flat: Vec<u8> = measured
        .iter()
        .flatten()
        .flat_map(|v| v.to_ne_bytes())
        .collect();
    d.set_item("measured", PyBytes::new(py, &flat))?;
    d.set_item(
        "substrate",
        serde_json::to_string(&filmscope::material::DispersionRecord::from(spec.substrate))
            .unwrap_or_default(),
    )?;
    d.set_item("ambient_index", spec.ambient_index)?;
    d.set_item("polarization", spec.polarization.name())?;
    d.set_item("back_face", spec.back_face.name())?;
    Ok(d)
}

/// The fit of a film (JSON) at `thickness_nm` (NaN: none; the candidates' scan centres on
/// `fallback_nm`) to one pixel's `measured` spectra (`float64` bytes, `[angle][band]`,
/// angles in streaming order), with the sample fit's `nuisance_terms` (`summary.json`'s,
/// as JSON; `null`: none) applied as the per-pixel passes apply them: a dict of
/// `angles_deg` (increasing), `measured` (corrected) and `model` (bytes, `[angle][band]`)
/// and `candidates` (`thickness_nm`, `rms`, `model`).
#[pyfunction]
#[pyo3(signature = (film, substrate, ambient_index, polarization_name, back_face_name, wavelengths_nm, fwhm_nm, angles_deg, measured, thickness_nm, fallback_nm, x, y, nuisance_terms))]
#[allow(clippy::too_many_arguments)]
fn pixel_fit<'py>(
    py: Python<'py>,
    film: &str,
    substrate: &str,
    ambient_index: f64,
    polarization_name: &str,
    back_face_name: &str,
    wavelengths_nm: Vec<f64>,
    fwhm_nm: Vec<f64>,
    angles_deg: Vec<f64>,
    measured: &[u8],
    thickness_nm: f64,
    fallback_nm: f64,
    x: usize,
    y: usize,
    nuisance_terms: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let terms: Option<filmscope::record::index_choice::NuisanceTerms> =
        serde_json::from_str(nuisance_terms)
            .map_err(|e| fail(format!("pixel_fit: nuisance_terms: {e}")))?;
    let correction = filmscope::estimate::index_fit::correction_from(terms.as_ref());
    let stack = FilmStack {
        back_face: back_face(back_face_name).map_err(fail)?,
        ambient_index,
        film: dispersion(film, "n_model").map_err(fail)?,
        substrate: dispersion(substrate, "substrate").map_err(fail)?,
        polarization: polarization(polarization_name).map_err(fail)?,
    };
    let (na, nb) = (angles_deg.len(), wavelengths_nm.len());
    if measured.len() != na * nb * 8 || fwhm_nm.len() != nb {
        return Err(fail(format!(
            "pixel_fit: {} bytes of spectra and {} widths for {na} angles x {nb} bands",
            measured.len(),
            fwhm_nm.len()
        )));
    }
    let values: Vec<f64> = measured
        .chunks_exact(8)
        .map(|c| f64::from_ne_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
        .collect();
    let rows: Vec<Vec<f64>> = values.chunks(nb.max(1)).map(<[f64]>::to_vec).collect();
    let bands: Vec<Passband> = wavelengths_nm
        .iter()
        .zip(&fwhm_nm)
        .map(|(&l, &w)| Passband::gaussian(l, w))
        .collect();
    let fit = py.detach(|| {
        filmscope::appearance::pixel::fit_pixel(
            (x, y),
            &stack,
            &bands,
            &angles_deg,
            rows,
            thickness_nm,
            fallback_nm,
            &correction,
        )
    });
    let bytes =
        |m: &[Vec<f64>]| -> Vec<u8> { m.iter().flatten().flat_map(|v| v.to_ne_bytes()).collect() };
    let d = PyDict::new(py);
    d.set_item("angles_deg", fit.angles_deg.clone())?;
    d.set_item("measured", PyBytes::new(py, &bytes(&fit.measured)))?;
    d.set_item("model", PyBytes::new(py, &bytes(&fit.model)))?;
    let cands = pyo3::types::PyList::empty(py);
    for c in &fit.candidates {
        let cd = PyDict::new(py);
        cd.set_item("thickness_nm", c.thickness_nm)?;
        cd.set_item("rms", c.rms)?;
        cd.set_item("model", PyBytes::new(py, &bytes(&c.model)))?;
        cands.append(cd)?;
    }
    d.set_item("candidates", cands)?;
    Ok(d)
}

/// The names of the built-in material library.
#[pyfunction]
fn material_names() -> Vec<&'static str> {
    filmscope_core::optics::materials::NAMES.to_vec()
}

/// The native module.
#[pymodule]
#[pyo3(name = "_native")]
fn native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("FilmscopeError", m.py().get_type::<FilmscopeError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add(
        "DEFAULT_INDEX_PIXELS",
        filmscope_core::solve::fit_row::INDEX_PIXELS,
    )?;
    m.add(
        "DEFAULT_SAMPLE_SITES",
        filmscope::estimate::index_fit::DEFAULT_SITES,
    )?;
    m.add_function(wrap_pyfunction!(estimate_capture, m)?)?;
    m.add_function(wrap_pyfunction!(estimate_array, m)?)?;
    m.add_function(wrap_pyfunction!(reflectance, m)?)?;
    m.add_function(wrap_pyfunction!(index_at, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(material_names, m)?)?;
    m.add_function(wrap_pyfunction!(write_material, m)?)?;
    m.add_function(wrap_pyfunction!(capture_spectra, m)?)?;
    m.add_function(wrap_pyfunction!(pixel_fit, m)?)?;
    Ok(())
}
