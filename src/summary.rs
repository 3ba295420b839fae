//! `summary.json`: what an estimate found, written and read through one type, [`Summary`].
//!
//! The estimator fills it ([`crate::estimate::write_outputs_into`]), the rig and the line
//! add their records, and the appearance, report and command line read it back. Its two
//! `*_choice` members are the evidence behind the index and field models, for people: the
//! field model's is typed here (the command line prints from it); the index model's, whose
//! shape differs by how the index came, in [`crate::record::index_choice`] (the appearance
//! reads its nuisance terms).

use std::collections::BTreeMap;
use std::path::Path;

use filmscope_core::optics::Dispersion;
use serde::{Deserialize, Serialize};

pub use crate::material::DispersionRecord;
use crate::record::acquisition::AcquisitionLog;
use crate::record::index_choice::IndexModelChoice;
use crate::record::line::{RecipeRecord, VerdictRecord};
use crate::record::method::{FieldModel, Method};
use crate::record::{RecordError, RecordProblem};

/// The file name.
pub const FILE: &str = "summary.json";

/// `summary.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Summary {
    /// The film's index at 550 nm; null when no index was found.
    pub refractive_index: Option<f64>,
    /// Its 1-sigma; null when not measured.
    pub refractive_index_sigma: Option<f64>,
    /// The index model with a table over the capture's bands; null when no index.
    pub dispersion: Option<IndexRecord>,
    /// `constant`, `cauchy`, `cauchy3`, `sellmeier` or `sellmeier_constant`.
    pub index_model: String,
    /// How the index model was chosen: candidates, criterion, timings (for people); null
    /// for the baselines. Its keys in alphabetical order.
    #[serde(serialize_with = "crate::record::sorted")]
    pub index_model_choice: Option<IndexModelChoice>,
    /// `narrow` or `wide`, for the streaming method.
    pub field_model: Option<FieldModel>,
    /// How the field model was chosen (streaming method).
    pub field_model_choice: Option<FieldModelChoice>,
    /// Statistics of the valid thicknesses, nm.
    pub thickness_nm: Stats,
    /// Statistics of the valid pixels' thickness 1-sigma, nm.
    pub thickness_sigma_nm: SigmaStats,
    /// Share of pixels with a thickness.
    pub valid_fraction: f64,
    /// Map width, pixels.
    pub width: usize,
    /// Map height, pixels.
    pub height: usize,
    /// The sample's optical setting (always written; without it, readers take the
    /// setting from the capture).
    #[serde(default)]
    pub sample: Option<SampleRecord>,
    /// `filmscope`, `paper` or `brute`.
    pub method: Method,
    /// The capture (path) or scene the maps come from.
    pub source: String,
    /// Incidence angles in streaming order, degrees.
    pub angles_deg: Vec<f64>,
    /// Number of bands.
    pub bands: usize,
    /// Pixels carrying each flag, by name.
    pub flags: BTreeMap<String, u64>,
    /// Per-angle progress of the streaming solver.
    pub angle_reports: Vec<AngleReport>,
    /// Wall time and throughput.
    pub timing: Timing,
    /// Bytes of per-pixel state (streaming method).
    pub state_bytes_per_pixel: Option<usize>,
    /// Remarks of the method.
    pub notes: Vec<String>,
    /// The files beside this one.
    pub files: Files,
    /// The rig's acquisition log (`filmscope acquire`, `inspect`).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        serialize_with = "crate::record::sorted"
    )]
    pub acquisition: Option<AcquisitionLog>,
    /// When the sample was measured, UTC ISO 8601 (`acquire`, `inspect`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timestamp: Option<String>,
    /// filmscope's version (`acquire`, `inspect`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub version: Option<String>,
    /// The line's record of the sample (`inspect`): `sample_id`, `recipe`, `verdict`.
    #[serde(default, flatten, skip_serializing_if = "Option::is_none")]
    pub line: Option<LineRecord>,
}

impl Summary {
    /// Reads `dir/summary.json`; the error names the file and the problem.
    pub fn read(dir: &Path) -> Result<Self, RecordError> {
        let path = dir.join(FILE);
        if !path.exists() && dir.join("capture.toml").exists() {
            let problem = RecordProblem::ACapture(dir.display().to_string());
            return Err(RecordError::new(&path, problem));
        }
        crate::record::read(&path)
    }

    /// Writes `dir/summary.json` atomically (its keys in the order of this type).
    pub fn write(&self, dir: &Path) -> Result<(), RecordError> {
        let path = dir.join(FILE);
        let text = serde_json::to_string_pretty(self).map_err(|e| RecordError::new(&path, e))?;
        crate::record::write_text(&path, &text)
    }
}

/// Statistics of the finite values of a map; null members when there are none.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    /// Mean.
    pub mean: Option<f64>,
    /// Median.
    pub median: Option<f64>,
    /// Standard deviation (population).
    pub std: Option<f64>,
    /// Minimum.
    pub min: Option<f64>,
    /// Maximum.
    pub max: Option<f64>,
}

impl Stats {
    /// Statistics of the finite values.
    pub fn of(values: &[f32]) -> Self {
        let mut v: Vec<f64> = values
            .iter()
            .filter(|x| x.is_finite())
            .map(|&x| f64::from(x))
            .collect();
        if v.is_empty() {
            return Self::default();
        }
        v.sort_by(f64::total_cmp);
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
        let median = if v.len() % 2 == 1 {
            v[v.len() / 2]
        } else {
            0.5 * (v[v.len() / 2 - 1] + v[v.len() / 2])
        };
        Self {
            mean: Some(mean),
            median: Some(median),
            std: Some(var.sqrt()),
            min: Some(v[0]),
            max: Some(v[v.len() - 1]),
        }
    }
}

/// The thickness uncertainty of the valid pixels.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SigmaStats {
    /// Statistics, nm.
    #[serde(flatten)]
    pub stats: Stats,
    /// 90th percentile, nm.
    pub p90: Option<f64>,
    /// Above this 1-sigma a pixel is flagged `imprecise`, nm.
    pub imprecise_above: f64,
}

/// The sample's optical setting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleRecord {
    /// Ambient index.
    pub ambient_index: f64,
    /// Substrate index at 550 nm.
    pub substrate_index: f64,
    /// `s`, `p` or `unpolarized`.
    pub polarization: String,
    /// The substrate's dispersion, when it is not a constant.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub substrate: Option<DispersionRecord>,
    /// The substrate's back face as the model took it: `none` or `bare`.
    #[serde(default = "no_back_face")]
    pub back_face: String,
}

fn no_back_face() -> String {
    "none".into()
}

/// The film's index model with its value at 550 nm and a table over the capture's bands.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IndexRecord {
    /// The model.
    #[serde(flatten)]
    pub model: DispersionRecord,
    /// n at 550 nm (always written; derived from the model, so optional on read).
    #[serde(default)]
    pub n_550: Option<f64>,
    /// n over the capture's band range, at most 10 nm apart (always written; optional on
    /// read).
    #[serde(default)]
    pub n_table: Option<IndexTable>,
}

impl IndexRecord {
    /// The record of `d` over the band range of `bands_nm`.
    pub fn new(d: Dispersion, bands_nm: &[f64]) -> Self {
        let lo = bands_nm.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = bands_nm.iter().copied().fold(0.0, f64::max);
        let step = if bands_nm.len() > 1 {
            ((hi - lo) / (bands_nm.len() - 1) as f64).clamp(1.0, 10.0)
        } else {
            1.0
        };
        let count = if lo.is_finite() {
            ((hi - lo) / step).floor() as usize + 1
        } else {
            0
        };
        let wavelength_nm: Vec<f64> = (0..count).map(|i| lo + step * i as f64).collect();
        let n = wavelength_nm.iter().map(|&l| d.index_at(l)).collect();
        Self {
            model: d.into(),
            n_550: Some(d.index_at(550.0)),
            n_table: Some(IndexTable { wavelength_nm, n }),
        }
    }
}

/// n tabulated over wavelength.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IndexTable {
    /// Wavelengths, nm.
    pub wavelength_nm: Vec<f64>,
    /// n at each.
    pub n: Vec<f64>,
}

/// One angle's progress in the streaming solver.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AngleReport {
    /// Incidence angle, degrees.
    pub incidence_deg: f64,
    /// The index at 550 nm after this angle.
    pub index: Option<f64>,
    /// Its 1-sigma.
    pub index_sigma: Option<f64>,
    /// The index from this angle's extremum pair, if any.
    pub pair_index: Option<f64>,
    /// Whether the full-spectrum refinement ran.
    pub refined: bool,
    /// The index's change from the full spectra at this angle.
    pub spectral_index_step: Option<f64>,
    /// Whether the model had more than one term.
    pub dispersive: bool,
    /// Terms of the index model.
    pub index_terms: usize,
    /// Whether the index came from the full spectra.
    pub index_from_full_spectra: bool,
}

/// Wall time and throughput of the run.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    /// Wall seconds.
    pub seconds: f64,
    /// From the last row to the maps, ms (streaming method).
    pub solve_latency_ms: Option<f64>,
    /// Band samples processed.
    pub samples: u64,
    /// Samples a second.
    pub samples_per_s: f64,
}

/// The files an estimate writes beside `summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Files {
    /// Thickness map (ENVI), nm.
    pub thickness: String,
    /// Confidence map (ENVI).
    pub confidence: String,
    /// Thickness 1-sigma map (ENVI), nm.
    pub thickness_sigma: String,
    /// Flag map (ENVI).
    pub flags: String,
    /// Thickness preview (PNG).
    pub preview: String,
    /// The index as a table (CSV), when written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub index_csv: Option<String>,
    /// The index as refractiveindex.info YAML, when written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub index_yml: Option<String>,
}

/// How the field model was chosen and each model's evidence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FieldModelChoice {
    /// The model used.
    pub chosen: String,
    /// `auto`, `narrow` or `wide`.
    pub requested: String,
    /// Why, in words.
    pub reason: String,
    /// The rule `auto` follows.
    pub criterion: String,
    /// The lens and strip geometry.
    pub geometry: FieldGeometry,
    /// The thickness error the narrow model makes at the image's left and right edges, nm.
    pub narrow_edge_error_nm: Option<[f64; 2]>,
    /// The narrow model's fit, when run.
    pub narrow: Option<NarrowEvidence>,
    /// The wide model's fit, when run.
    pub wide: Option<WideEvidence>,
}

/// The lens and strip geometry behind the field model.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FieldGeometry {
    /// The lens's horizontal field of view, degrees, when the capture gives it.
    pub horizontal_fov_deg: Option<f64>,
    /// Spread of incidence angles across the image, degrees.
    pub angle_spread_deg: Option<f64>,
    /// Strips of columns in the wide model.
    pub strips: Option<usize>,
    /// Largest spread within one strip, degrees.
    pub strip_spread_deg: Option<f64>,
    /// The spread allowed within a strip, degrees.
    pub strip_spread_tolerance_deg: f64,
    /// Whether thicknesses are corrected per column.
    pub column_map: bool,
}

/// The narrow model's fit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NarrowEvidence {
    /// Index at 550 nm.
    pub index: Option<f64>,
    /// Its 1-sigma.
    pub index_sigma: Option<f64>,
    /// Fit residual, reflectance.
    pub residual_sigma: Option<f64>,
    /// Pixel noise, reflectance.
    pub noise_sigma: Option<f64>,
    /// Whether the model fails to explain the spectra.
    pub model_mismatch: bool,
    /// Share of valid pixels.
    pub valid_fraction: f64,
    /// Passes over the data.
    pub passes: usize,
    /// Wall seconds.
    pub seconds: f64,
}

/// The wide model's fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WideEvidence {
    /// Combined index at 550 nm.
    pub index: Option<f64>,
    /// Its 1-sigma.
    pub index_sigma: Option<f64>,
    /// Chi-square of the strips' indices about the combination.
    pub strip_index_chi2: Option<f64>,
    /// Strips in the combination.
    pub strips_combined: Option<usize>,
    /// Fit residual, reflectance.
    pub residual_sigma: Option<f64>,
    /// Pixel noise, reflectance.
    pub noise_sigma: Option<f64>,
    /// Whether the model fails to explain the spectra.
    pub model_mismatch: bool,
    /// Share of valid pixels.
    pub valid_fraction: f64,
    /// Wall seconds.
    pub seconds: f64,
    /// Each strip's fit.
    pub strips: Vec<StripEvidence>,
}

/// One strip's fit in the wide model.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StripEvidence {
    /// First and one-past-last column.
    pub columns: [usize; 2],
    /// Its angle offset from the axis, degrees.
    pub offset_deg: f64,
    /// Its spread of angles, degrees.
    pub spread_deg: f64,
    /// Its own index at 550 nm.
    pub index: Option<f64>,
    /// Its 1-sigma.
    pub index_sigma: Option<f64>,
    /// Whether it entered the combination.
    pub index_combined: Option<bool>,
    /// Its own passes.
    pub passes: usize,
    /// Residual of its own fit.
    pub own_residual_sigma: Option<f64>,
    /// Whether its own fit mismatched.
    pub own_model_mismatch: bool,
    /// Whether the shared rounds' result was kept.
    pub shared_rounds_kept: bool,
    /// Residual after the shared rounds.
    pub residual_sigma: Option<f64>,
    /// Whether it mismatched after the shared rounds.
    pub model_mismatch: bool,
}

/// The production line's record of a sample (`inspect`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LineRecord {
    /// The sample's id.
    pub sample_id: String,
    /// The recipe file, film and settings.
    #[serde(serialize_with = "crate::record::sorted")]
    pub recipe: RecipeRecord,
    /// The verdict, its reasons and regions.
    #[serde(serialize_with = "crate::record::sorted")]
    pub verdict: VerdictRecord,
}

#[cfg(test)]
mod tests {
    use super::*;
    use filmscope_core::optics::materials;

    /// Every model reads back as written.
    #[test]
    fn dispersion_records_round_trip() {
        for d in [
            Dispersion::constant(1.46),
            Dispersion::Cauchy {
                a: 1.45,
                b_um2: 0.0042,
                c_um4: 0.00011,
            },
            materials::zns_debenham(),
            materials::TA2O5_GAO,
        ] {
            let text = serde_json::to_string(&IndexRecord::new(d, &[400.0, 550.0, 700.0]))
                .expect("serialises");
            let back: IndexRecord = serde_json::from_str(&text).expect("parses");
            let m = back.model.dispersion().expect("a model");
            for l in [400.0, 550.0, 700.0] {
                assert!((m.index_at(l) - d.index_at(l)).abs() < 1e-12, "{text}");
            }
        }
    }

    /// A Sellmeier model with more than three terms is refused, naming the members.
    #[test]
    fn sellmeier_with_four_terms_is_refused() {
        let r: DispersionRecord = serde_json::from_str(
            r#"{"model":"sellmeier","a":1,"b":[1,1,1,1],"c_um":[0.1,0.1,0.1,0.1]}"#,
        )
        .expect("parses");
        let e = r.dispersion().expect_err("four terms").to_string();
        assert!(e.contains("`b` as `c_um`"), "{e}");
    }
}
