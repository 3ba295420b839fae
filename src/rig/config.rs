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
}

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
}

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
    /// Loads and checks `path`; a relative `[sim] scene` is resolved against its folder.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let err = |problem: String| ConfigError {
            path: path.to_path_buf(),
            problem,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
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
        let s = &self.sweep;
        if s.angles_deg.len() < 2 {
            return Err("[sweep] angles_deg: at least two angles".into());
        }
        let [lo, hi] = self.stage.limits_deg;
        if lo.partial_cmp(&hi) != Some(std::cmp::Ordering::Less) {
            return Err(format!(
                "[stage] limits_deg [{lo}, {hi}]: low must be below high"
            ));
        }
        for &a in &s.angles_deg {
            let stage = a + s.stage_offset_deg;
            if !(stage >= lo && stage <= hi) {
                return Err(format!(
                    "[sweep] angle {a} deg puts the stage at {stage} deg, outside its limits [{lo}, {hi}]"
                ));
            }
        }
        let [a, b, step] = s.bands_nm;
        if !(step > 0.0 && b >= a && a > 0.0) {
            return Err(format!(
                "[sweep] bands_nm [{a}, {b}, {step}]: want [first, last, step > 0]"
            ));
        }
        if self.stage.steps_per_deg.is_nan() || self.stage.steps_per_deg <= 0.0 {
            return Err("[stage] steps_per_deg must be positive".into());
        }
        if self.camera.width == 0 || self.camera.height == 0 {
            return Err("[camera] width and height must be positive".into());
        }
        if filmscope_core::optics::Polarization::from_name(&self.sample.polarization).is_none() {
            return Err(format!(
                "[sample] polarization {:?}: use s, p or unpolarized",
                self.sample.polarization
            ));
        }
        Ok(())
    }
}
