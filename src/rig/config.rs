//! `rig.toml`: the sample, the sweep and where each device is (see `config/rig.toml`).
//! Every value is checked on load; a bad file gets one line naming it and the problem.

use std::path::{Path, PathBuf};

use serde::Deserialize;

/// The whole rig file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigConfig {
    /// The sample's optics.
    pub sample: SampleConfig,
    /// Optional search bounds.
    #[serde(default)]
    pub search: Option<SearchConfig>,
    /// Angles and bands.
    pub sweep: SweepConfig,
    /// The rotation stage.
    pub stage: StageConfig,
    /// The LCTF.
    pub filter: FilterConfig,
    /// The filter wheel (optional).
    #[serde(default)]
    pub wheel: Option<WheelConfig>,
    /// The camera link.
    pub camera: CameraConfig,
    /// What `--sim` runs.
    #[serde(default)]
    pub sim: Option<SimConfig>,
    /// Whether this is the built-in rig ([`RigConfig::builtin`]), whose `--sim` scene is
    /// built in too.
    #[serde(skip)]
    pub builtin: bool,
}

/// The rig `acquire` and `inspect` use without `--rig` outside the repository: the
/// repository's `config/rig.toml`, built into the binary.
pub const BUILTIN_RIG: &str = include_str!("../../config/rig.toml");

/// The `--sim` scene of [`BUILTIN_RIG`], built in.
pub const BUILTIN_SIM_SCENE: &str = include_str!("../../config/scenes/rig-tiny.toml");

/// `[sample]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SampleConfig {
    /// Substrate index.
    pub substrate_index: f64,
    /// Ambient index (default 1).
    #[serde(default = "one")]
    pub ambient_index: f64,
    /// `s`, `p` or `unpolarized`.
    #[serde(default = "s_pol")]
    pub polarization: String,
    /// The substrate's back face, `none` (default) or `bare` (as `sample.back_face` in a
    /// capture).
    #[serde(default)]
    pub back_face: Option<String>,
}

impl SampleConfig {
    /// The back face, or the name given when it names none.
    pub fn back_face(&self) -> Result<filmscope_core::optics::BackFace, UnknownBackFace> {
        match self.back_face.as_deref() {
            None => Ok(filmscope_core::optics::BackFace::None),
            Some(name) => filmscope_core::optics::BackFace::from_name(name)
                .ok_or_else(|| UnknownBackFace(name.to_owned())),
        }
    }
}

/// A `sample.back_face` that names no back face.
#[derive(Debug, thiserror::Error)]
#[error("sample.back_face = {0:?}: \"none\" or \"bare\"")]
pub struct UnknownBackFace(pub String);

fn one() -> f64 {
    1.0
}

fn s_pol() -> String {
    "s".into()
}

/// `[search]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SearchConfig {
    /// Film index range.
    pub index_range: Option<[f64; 2]>,
    /// Thickness range, nm.
    pub thickness_range_nm: Option<[f64; 2]>,
}

/// `[sweep]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepConfig {
    /// Incidence angles, degrees.
    pub angles_deg: Vec<f64>,
    /// Bands `[first, last, step]`, nm.
    pub bands_nm: [f64; 3],
    /// Passband width, nm.
    pub fwhm_nm: f64,
    /// Stage reading at normal incidence, degrees (incidence = stage - offset).
    #[serde(default)]
    pub stage_offset_deg: f64,
}

impl SweepConfig {
    /// The band centres, nm.
    pub fn bands(&self) -> Vec<f64> {
        let [a, b, step] = self.bands_nm;
        let n = ((b - a) / step + 1e-6).floor() as usize + 1;
        (0..n).map(|i| a + i as f64 * step).collect()
    }
}

/// `[stage]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageConfig {
    /// Serial port.
    #[serde(default)]
    pub port: String,
    /// Baud rate.
    #[serde(default = "baud")]
    pub baud: u32,
    /// Device address.
    #[serde(default = "one_u8")]
    pub device: u8,
    /// Axis.
    #[serde(default = "one_u8")]
    pub axis: u8,
    /// Microsteps per degree.
    pub steps_per_deg: f64,
    /// Allowed travel, degrees.
    pub limits_deg: [f64; 2],
    /// Reply timeout, ms.
    #[serde(default = "timeout_ms")]
    pub timeout_ms: u64,
    /// Status poll interval while moving, ms.
    #[serde(default = "poll_ms")]
    pub poll_ms: u64,
}

fn baud() -> u32 {
    115_200
}

fn one_u8() -> u8 {
    1
}

fn timeout_ms() -> u64 {
    500
}

fn poll_ms() -> u64 {
    20
}

/// `[filter]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilterConfig {
    /// Serial port.
    #[serde(default)]
    pub port: String,
    /// Baud rate.
    #[serde(default = "baud")]
    pub baud: u32,
    /// Bandwidth mode (2 wide, 4 medium, 8 narrow).
    #[serde(default = "narrow")]
    pub bandwidth: u32,
    /// Settle time after tuning, ms.
    #[serde(default = "settle_ms")]
    pub settle_ms: u64,
    /// Reply timeout, ms.
    #[serde(default = "timeout_ms")]
    pub timeout_ms: u64,
}

fn narrow() -> u32 {
    8
}

fn settle_ms() -> u64 {
    100
}

/// `[wheel]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WheelConfig {
    /// Slot used during the sweep (order sorting), 0-based.
    pub slot: u8,
    /// Slot that blocks the light, 0-based (set at the end).
    pub block_slot: u8,
}

/// `[camera]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// `tcp:HOST:PORT` or `unix:PATH`.
    #[serde(default)]
    pub address: String,
    /// Pixels per row.
    pub width: u32,
    /// Rows per frame.
    pub height: u32,
    /// ADC full scale, counts.
    #[serde(default = "full_scale")]
    pub saturation_counts: f64,
    /// Link timeout (no message for this long: a stall), ms.
    #[serde(default = "camera_timeout_ms")]
    pub timeout_ms: u64,
}

fn full_scale() -> f64 {
    4095.0
}

fn camera_timeout_ms() -> u64 {
    2000
}

/// `[sim]`: what `--sim` runs.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimConfig {
    /// Scene file (relative to rig.toml).
    pub scene: PathBuf,
    /// Device time per wall time.
    #[serde(default = "speed")]
    pub speed: f64,
}

fn speed() -> f64 {
    50.0
}

/// Most pixels a camera row or frame may have along one side.
const MAX_CAMERA_PIXELS: u32 = 1 << 16;

/// Largest rig file read, bytes.
const MAX_RIG_BYTES: u64 = 1 << 20;

/// `key = value` in `[lo, hi]` and finite, or one line saying it is not.
fn finite_in(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), String> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(format!(
            "{key} = {v:?}: expected a finite number in [{lo:?}, {hi:?}]"
        ))
    }
}

/// A duration in milliseconds in `[lo, hi]`, or one line saying it is not.
fn ms_in(key: &str, v: u64, lo: u64, hi: u64) -> Result<(), String> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(format!("{key} = {v:?}: expected {lo:?} to {hi:?} ms"))
    }
}

/// A rig file that cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {problem}")]
pub struct ConfigError {
    /// The file.
    pub path: PathBuf,
    /// The problem, one line.
    pub problem: String,
}

impl RigConfig {
    /// `path`, or without one `config/rig.toml` where it exists (a checkout), else the
    /// built-in rig.
    pub fn load_or_builtin(path: Option<&Path>) -> Result<Self, ConfigError> {
        let default = Path::new("config/rig.toml");
        match path {
            Some(p) => Self::load(p),
            None if default.exists() => Self::load(default),
            None => Self::builtin(),
        }
    }

    /// The built-in rig ([`BUILTIN_RIG`]).
    pub fn builtin() -> Result<Self, ConfigError> {
        let err = |problem: String| ConfigError {
            path: PathBuf::from("built-in config/rig.toml"),
            problem,
        };
        let mut c: Self = toml::from_str(BUILTIN_RIG).map_err(|e| err(e.message().to_owned()))?;
        c.builtin = true;
        c.check().map_err(err)?;
        Ok(c)
    }

    /// Loads and checks `path`; a relative `[sim] scene` is resolved against its folder.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let err = |problem: String| ConfigError {
            path: path.to_path_buf(),
            problem,
        };
        let text =
            crate::limits::read_small(path, MAX_RIG_BYTES).map_err(|e| err(e.to_string()))?;
        let mut c: Self = toml::from_str(&text)
            .map_err(|e| err(e.message().split_whitespace().collect::<Vec<_>>().join(" ")))?;
        if let Some(sim) = c.sim.as_mut() {
            if sim.scene.is_relative() {
                sim.scene = path.parent().unwrap_or(Path::new("")).join(&sim.scene);
            }
        }
        c.check().map_err(err)?;
        Ok(c)
    }

    fn check(&self) -> Result<(), String> {
        use crate::limits;
        let s = &self.sweep;
        limits::check_sample(
            "sample.ambient_index",
            self.sample.ambient_index,
            "sample.substrate_index",
            self.sample.substrate_index,
        )?;
        if filmscope_core::optics::Polarization::from_name(&self.sample.polarization).is_none() {
            return Err(format!(
                "sample.polarization = {:?}: use s, p or unpolarized",
                self.sample.polarization
            ));
        }
        if let Some(search) = &self.search {
            if let Some(r) = search.index_range {
                limits::check_index_range("search.index_range", r)?;
            }
            if let Some(r) = search.thickness_range_nm {
                limits::check_thickness_range("search.thickness_range_nm", r)?;
            }
        }
        limits::check_angle_count("sweep.angles_deg", s.angles_deg.len())?;
        finite_in("sweep.stage_offset_deg", s.stage_offset_deg, -360.0, 360.0)?;
        let [lo, hi] = self.stage.limits_deg;
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(format!(
                "stage.limits_deg = [{lo:?}, {hi:?}]: expected finite low < high"
            ));
        }
        for (i, &a) in s.angles_deg.iter().enumerate() {
            if !(a.is_finite() && (0.0..90.0).contains(&a)) {
                return Err(format!(
                    "sweep.angles_deg[{i}] = {a:?}: expected an incidence angle in [0, 90) degrees"
                ));
            }
            if let Some(j) = s.angles_deg[..i].iter().position(|&b| (b - a).abs() < 1e-6) {
                return Err(format!(
                    "sweep.angles_deg[{i}] = {a:?}: the same angle as sweep.angles_deg[{j}]"
                ));
            }
            let stage = a + s.stage_offset_deg;
            if !(stage >= lo && stage <= hi) {
                return Err(format!(
                    "sweep.angles_deg[{i}] = {a:?} puts the stage at {stage:?} deg, outside stage.limits_deg [{lo:?}, {hi:?}]"
                ));
            }
        }
        let [a, b, step] = s.bands_nm;
        let max = filmscope_core::solve::sweep::MAX_BANDS as f64;
        let count = (b - a) / step + 1.0;
        let ok = a.is_finite() && b.is_finite() && step.is_finite() && step > 0.0 && b >= a;
        if !(ok && count <= max) {
            return Err(format!(
                "sweep.bands_nm = [{a:?}, {b:?}, {step:?}]: expected [first, last, step > 0], finite, at most {max} bands"
            ));
        }
        limits::check_bands("sweep.bands_nm", &s.bands(), "sweep.fwhm_nm", None)?;
        finite_in(
            "sweep.fwhm_nm",
            s.fwhm_nm,
            f64::MIN_POSITIVE,
            limits::MAX_FWHM_NM,
        )?;
        finite_in("stage.steps_per_deg", self.stage.steps_per_deg, 1e-3, 1e7)?;
        ms_in("stage.timeout_ms", self.stage.timeout_ms, 1, 60_000)?;
        ms_in("stage.poll_ms", self.stage.poll_ms, 1, 10_000)?;
        ms_in("filter.timeout_ms", self.filter.timeout_ms, 1, 60_000)?;
        ms_in("filter.settle_ms", self.filter.settle_ms, 0, 60_000)?;
        if ![1, 2, 4, 8].contains(&self.filter.bandwidth) {
            return Err(format!(
                "filter.bandwidth = {}: expected 2 (wide), 4 (medium) or 8 (narrow)",
                self.filter.bandwidth
            ));
        }
        for (key, baud) in [
            ("stage.baud", self.stage.baud),
            ("filter.baud", self.filter.baud),
        ] {
            if !(300..=4_000_000).contains(&baud) {
                return Err(format!("{key} = {baud}: expected 300 to 4000000"));
            }
        }
        let c = &self.camera;
        for (key, v) in [("camera.width", c.width), ("camera.height", c.height)] {
            if !(1..=MAX_CAMERA_PIXELS).contains(&v) {
                return Err(format!(
                    "{key} = {v:?}: expected 1 to {MAX_CAMERA_PIXELS} pixels"
                ));
            }
        }
        finite_in(
            "camera.saturation_counts",
            c.saturation_counts,
            1.0,
            65_535.0,
        )?;
        ms_in("camera.timeout_ms", c.timeout_ms, 1, 60_000)?;
        if let Some(w) = &self.wheel {
            for (key, slot) in [("wheel.slot", w.slot), ("wheel.block_slot", w.block_slot)] {
                if slot > 15 {
                    return Err(format!("{key} = {slot}: expected a slot 0 to 15"));
                }
            }
        }
        if let Some(sim) = &self.sim {
            finite_in("sim.speed", sim.speed, 1e-3, 1e6)?;
        }
        Ok(())
    }
}
