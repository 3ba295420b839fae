//! `truth.json`: what `simulate` put into a capture (the film, the substrate, the light
//! and the geometry), beside `truth/thickness_nm.hdr`; `eval` and the tests measure
//! against it.

use std::path::Path;

use filmscope_core::optics::{BackFace, Polarization};
use serde::{Deserialize, Serialize};

use super::RecordError;

use crate::material::DispersionRecord;

/// The file name.
pub const FILE: &str = "truth.json";

/// `truth.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TruthRecord {
    /// The scene's name.
    pub scene: String,
    /// The scene's description.
    #[serde(default)]
    pub description: String,
    /// The film's index at 550 nm.
    pub refractive_index: f64,
    /// The film's index model; null for a constant index.
    #[serde(default)]
    pub dispersion: Option<DispersionRecord>,
    /// The substrate's index at 550 nm.
    pub substrate_index: f64,
    /// The substrate's index model; null for a constant index (and in truths written
    /// before substrates could be dispersive).
    #[serde(default)]
    pub substrate_dispersion: Option<DispersionRecord>,
    /// The ambient medium's index.
    #[serde(default = "one")]
    pub ambient_index: f64,
    /// The light's polarisation.
    #[serde(default)]
    pub polarization: PolarizationRecord,
    /// The substrate's back face.
    #[serde(default)]
    pub back_face: BackFaceRecord,
    /// Incidence angles in the capture's order, degrees.
    #[serde(default)]
    pub angles_deg: Vec<f64>,
    /// Whether the capture was simulated without noise.
    #[serde(default)]
    pub noise_free: bool,
    /// The thickness map (ENVI), relative to the capture.
    #[serde(default = "thickness_map")]
    pub thickness_map: String,
    /// Map width, pixels.
    #[serde(default)]
    pub width: usize,
    /// Map height, pixels.
    #[serde(default)]
    pub height: usize,
    /// The lens's horizontal field of view, degrees (only a scene with a lens has one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub horizontal_fov_deg: Option<f64>,
}

fn one() -> f64 {
    1.0
}

fn thickness_map() -> String {
    "truth/thickness_nm.hdr".into()
}

impl TruthRecord {
    /// Reads `dir/truth.json`; the error names the file and the problem.
    pub fn read(dir: &Path) -> Result<Self, RecordError> {
        super::read(&dir.join(FILE))
    }

    /// Writes `dir/truth.json` atomically.
    pub fn write(&self, dir: &Path) -> Result<(), RecordError> {
        super::write(&dir.join(FILE), self)
    }
}

/// The polarisation of the light, by the names capture and scene files use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PolarizationRecord {
    /// Perpendicular to the plane of incidence.
    #[default]
    #[serde(alias = "S")]
    S,
    /// In the plane of incidence.
    #[serde(alias = "P")]
    P,
    /// The mean of S and P.
    #[serde(alias = "unpolarised")]
    Unpolarized,
}

impl From<Polarization> for PolarizationRecord {
    fn from(p: Polarization) -> Self {
        match p {
            Polarization::S => Self::S,
            Polarization::P => Self::P,
            Polarization::Unpolarized => Self::Unpolarized,
        }
    }
}

impl From<PolarizationRecord> for Polarization {
    fn from(p: PolarizationRecord) -> Self {
        match p {
            PolarizationRecord::S => Self::S,
            PolarizationRecord::P => Self::P,
            PolarizationRecord::Unpolarized => Self::Unpolarized,
        }
    }
}

/// The substrate's back face, by the names capture and scene files use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackFaceRecord {
    /// Nothing returns from it.
    #[default]
    None,
    /// A bare back face, adding its reflection incoherently.
    Bare,
}

impl From<BackFace> for BackFaceRecord {
    fn from(b: BackFace) -> Self {
        match b {
            BackFace::None => Self::None,
            BackFace::Bare => Self::Bare,
        }
    }
}

impl From<BackFaceRecord> for BackFace {
    fn from(b: BackFaceRecord) -> Self {
        match b {
            BackFaceRecord::None => Self::None,
            BackFaceRecord::Bare => Self::Bare,
        }
    }
}
