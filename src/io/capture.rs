//! `capture.toml`: one angle sweep of one sample, and the cubes it names.
//!
//! ```toml
//! [sample]
//! ambient_index = 1.0        # optional, default 1.0
//! substrate_index = 1.65     # required, unless `substrate` is given
//! substrate = "bk7"          # optional, a filmscope extension: a dispersive substrate, by
//!                            # library name or refractiveindex.info YAML file (relative to
//!                            # capture.toml); the model uses it, substrate_index is then
//!                            # its n at 550 nm for readers that do not know the key
//! polarization = "s"         # optional: "s" (default), "p" or "unpolarized"
//!
//! [search]                   # optional
//! index_range = [1.2, 3.0]
//! thickness_range_nm = [50.0, 2000.0]
//!
//! [fit]                      # optional, a filmscope extension of the contract
//! model_error = 0.003        # RMS reflectance the model may miss by beyond the noise
//! rig_tolerance = 1.0        # the rig's nuisance terms in the index sigma, x the typical rig's
//!
//! [lens]                     # optional, a filmscope extension of the contract
//! horizontal_fov_deg = 30.0  # the lens's horizontal field of view, in (0, 180)
//!
//! [[angle]]                  # at least two, any order
//! incidence_deg = 10.0
//! cube = "a10.hdr"           # relative to capture.toml
//! white = "white10.hdr"      # optional; required when the cube holds raw counts
//! dark = "dark10.hdr"        # optional
//! white_reflectance = 0.99   # optional, default 1.0
//! ```
//!
//! [`Capture::load`] parses the file, checks every value, then opens every cube, white and
//! dark reference ([`Capture::check`]) so that a capture that cannot be processed fails
//! before any pixel is read, with a one-line [`CaptureError`] naming the file at fault.
//!
//! `[lens] horizontal_fov_deg` says the incidence angle varies across the image: the stage
//! turns about the vertical axis and column `x` sees `incidence_deg + atan((x - cx) /
//! focal_px)`, growing from left to right ([`crate::optics::FieldOfView`] has the geometry).
//! Absent, every column is taken to see the stage angle.
//!
//! Unknown keys are accepted, so captures written by newer tools with extra keys still
//! load, and are listed in [`Capture::unknown_keys`] (e.g. `angle[2].white_reflectence`) so
//! the CLI can warn about likely typos; this module prints nothing.

use std::fmt;
use std::io;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::atomic::write_atomic;
use super::envi::{file_name, DataType, EnviError, EnviErrorKind, EnviHeader, EnviReader};
use crate::optics::{BackFace, Dispersion, Polarization};

/// The file name looked for when [`Capture::load`] is given a directory.
pub const CAPTURE_FILE_NAME: &str = "capture.toml";

/// Wavelengths of two cubes closer than this (nm) are the same band.
const WAVELENGTH_TOLERANCE_NM: f64 = 1e-3;

/// Two incidence angles closer than this (degrees) are duplicates.
const ANGLE_TOLERANCE_DEG: f64 = 1e-6;

/// Largest accepted `white_reflectance` (bright references slightly above 1 exist).
const MAX_WHITE_REFLECTANCE: f64 = 1.5;

/// `capture.toml` files larger than this are refused.
const MAX_CAPTURE_BYTES: u64 = 4 << 20;

/// The `[sample]` table: the optical stack around the film.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    /// Index of the medium the light comes from (default 1.0, air).
    pub ambient_index: f64,
    /// Real index of the substrate under the film (at 550 nm when `substrate` is given).
    pub substrate_index: f64,
    /// A dispersive substrate (`sample.substrate`), which the model uses in place of
    /// `substrate_index`; `None`: the constant `substrate_index`.
    pub substrate: Option<SubstrateMaterial>,
    /// Polarisation reaching the camera (default S).
    pub polarization: Polarization,
    /// The substrate's back face (`sample.back_face`, default `"none"`): `"bare"` when the
    /// substrate is transparent and its far side reflects into the camera.
    pub back_face: BackFace,
}

/// `sample.substrate`: the substrate's material as the capture names it, and its index
/// against wavelength.
#[derive(Clone, Debug, PartialEq)]
pub struct SubstrateMaterial {
    /// A library name, or a YAML file's path as written (relative to capture.toml).
    pub name: String,
    /// The index against wavelength.
    pub dispersion: Dispersion,
}

impl Sample {
    /// The substrate's index against wavelength: `substrate` when given, else the constant
    /// `substrate_index`.
    pub fn substrate_dispersion(&self) -> Dispersion {
        self.substrate
            .as_ref()
            .map_or(Dispersion::constant(self.substrate_index), |s| s.dispersion)
    }
}

/// The optional `[search]` table: bounds the solver may assume.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Search {
    /// `[low, high]` film refractive index.
    pub index_range: Option<[f64; 2]>,
    /// `[low, high]` film thickness in nanometres.
    pub thickness_range_nm: Option<[f64; 2]>,
}

/// The optional `[fit]` table (a filmscope extension): how the index fit judges the spectra.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Fit {
    /// The model error tolerated, RMS reflectance in `[0, 0.05]`: what the single-layer
    /// model may miss the spectra by beyond their noise and still give an index (`None`: the
    /// default, [`crate::solve::sample::DEFAULT_MODEL_ERROR`]; 0: judged against the noise
    /// alone).
    pub model_error: Option<f64>,
    /// How far the reported index sigma carries the nuisance terms a real rig keeps (a white
    /// reference's error, film absorption, polariser leak, stage offset, wavelength shift,
    /// flare, side lobes), as a multiple of the typical rig's, in `[0, 10]` (`None`: 1; 0:
    /// the statistical sigma under the terms the fit took).
    pub rig_tolerance: Option<f64>,
}

/// The optional `[lens]` table (a filmscope extension of the capture contract).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Lens {
    /// The lens's horizontal field of view, degrees, in `(0, 180)`: column `c` of an image
    /// `width` pixels wide sees the stage angle plus
    /// [`crate::optics::FieldOfView::column_offset_deg`]. `None`: one incidence angle per
    /// frame.
    pub horizontal_fov_deg: Option<f64>,
}

impl Lens {
    /// The checked field of view, if the capture gives one ([`Capture::check_values`]
    /// refuses one outside `(0, 180)`).
    pub fn field_of_view(&self) -> Option<crate::optics::FieldOfView> {
        self.horizontal_fov_deg
            .and_then(crate::optics::FieldOfView::new)
    }
}

/// One `[[angle]]` entry: the cube taken at one incidence angle.
#[derive(Clone, Debug, PartialEq)]
pub struct Angle {
    /// Angle of incidence on the sample, degrees, in `[0, 90)`.
    pub incidence_deg: f64,
    /// The cube's ENVI header (resolved against the capture file's directory on load).
    pub cube: PathBuf,
    /// White-reference header, if any.
    pub white: Option<PathBuf>,
    /// Dark-reference header, if any.
    pub dark: Option<PathBuf>,
    /// Reflectance of the white reference, in `(0, 1.5]` (default 1.0).
    pub white_reflectance: f64,
}

/// A capture: sample description, solver bounds and the angle sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct Capture {
    /// The `capture.toml` this describes: errors name it, and [`Capture::load`] resolved
    /// the angles' relative paths against its directory.
    pub path: PathBuf,
    /// `[sample]`.
    pub sample: Sample,
    /// `[search]` (all `None` when absent).
    pub search: Search,
    /// `[lens]` (all `None` when absent).
    pub lens: Lens,
    /// `[fit]` (all `None` when absent).
    pub fit: Fit,
    /// `[[angle]]` entries in file order (the estimator accepts any order).
    pub angles: Vec<Angle>,
    /// Keys the format does not define, as dotted paths (`sample.foo`, `angle[1].bar`,
    /// 1-based), sorted. Never written back by [`Capture::write_toml`].
    pub unknown_keys: Vec<String>,
}

/// Geometry shared by all cubes of a checked capture.
#[derive(Clone, Debug, PartialEq)]
pub struct CubeInfo {
    /// Pixels per line.
    pub samples: usize,
    /// Lines.
    pub lines: usize,
    /// Bands.
    pub bands: usize,
    /// Value type of the first angle's cube.
    pub data_type: DataType,
    /// Band centres in nanometres, if the cubes' headers give them.
    pub wavelength_nm: Option<Vec<f64>>,
    /// Band widths in nanometres, if the first cube's header gives them.
    pub fwhm_nm: Option<Vec<f64>>,
}

/// A capture problem, tied to the file it concerns.
///
/// Displays as one line: `PATH: PROBLEM`; problems inside a cube display as the cube's
/// own [`EnviError`] (which names the cube's file).
#[derive(Debug)]
pub struct CaptureError {
    path: PathBuf,
    /// Boxed: keeps `Result<_, CaptureError>` small.
    kind: Box<CaptureErrorKind>,
}

impl CaptureError {
    /// Ties `kind` to the file `path`.
    pub fn new(path: impl Into<PathBuf>, kind: CaptureErrorKind) -> Self {
        Self {
            path: path.into(),
            kind: Box::new(kind),
        }
    }

    /// The file the problem concerns (`capture.toml` or one of its cubes).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What went wrong.
    pub fn kind(&self) -> &CaptureErrorKind {
        &self.kind
    }
}

impl fmt::Display for CaptureError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.kind.as_ref() {
            CaptureErrorKind::Envi(e) => write!(f, "{e}"),
            kind => write!(f, "{}: {kind}", self.path.display()),
        }
    }
}

impl std::error::Error for CaptureError {}

impl From<EnviError> for CaptureError {
    fn from(e: EnviError) -> Self {
        Self::new(e.path().to_path_buf(), CaptureErrorKind::Envi(e))
    }
}

/// What went wrong with a capture; each variant displays as one line without the path.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CaptureErrorKind {
    /// The operating system refused an operation.
    #[error("{action}: {err}")]
    Io {
        /// What was being done.
        action: &'static str,
        /// The underlying error (its text is in this message).
        err: io::Error,
    },
    /// The file is not valid TOML or does not have the capture's shape.
    #[error("{}{message}", .line.map(|l| format!("line {l}: ")).unwrap_or_default())]
    Toml {
        /// 1-based line of the problem, when known.
        line: Option<usize>,
        /// The parser's message, on one line.
        message: String,
    },
    /// No `[[angle]]` entry.
    #[error("needs at least one [[angle]] entry, found {found}")]
    TooFewAngles {
        /// Entries found.
        found: usize,
    },
    /// Two entries share an incidence angle.
    #[error("[[angle]] {first} and {second} both have incidence_deg = {incidence_deg}")]
    DuplicateAngle {
        /// 1-based index of the first.
        first: usize,
        /// 1-based index of the second.
        second: usize,
        /// The shared angle.
        incidence_deg: f64,
    },
    /// An incidence angle outside `[0, 90)`.
    #[error("[[angle]] {index}: incidence_deg = {incidence_deg} is outside [0, 90)")]
    AngleOutOfRange {
        /// 1-based entry index.
        index: usize,
        /// The angle.
        incidence_deg: f64,
    },
    /// A value outside the bounds [`crate::limits`] states.
    #[error(transparent)]
    Limit(#[from] crate::limits::LimitError),
    /// A value outside its bounds: the key, the value and what is expected, in one line.
    #[error("{message}")]
    BadValue {
        /// `key = value: expected ...`.
        message: String,
    },
    /// `polarization` is not `s`, `p` or `unpolarized`.
    #[error("sample.polarization = \"{value}\": expected \"s\", \"p\" or \"unpolarized\"")]
    UnknownPolarization {
        /// The value.
        value: String,
    },
    /// `lens.horizontal_fov_deg` outside `(0, 180)`.
    #[error("lens.horizontal_fov_deg = {value}: expected a field of view inside (0, 180) degrees")]
    BadFieldOfView {
        /// The value.
        value: f64,
    },
    /// An angle whose image edge, with the lens's field of view, reaches 90 degrees.
    #[error("[[angle]] {index}: incidence_deg = {incidence_deg} with lens.horizontal_fov_deg = {fov_deg} reaches {edge_deg} deg at the image edge (must stay below 90)")]
    FieldBeyondGrazing {
        /// 1-based entry index.
        index: usize,
        /// The stage angle.
        incidence_deg: f64,
        /// The field of view.
        fov_deg: f64,
        /// The incidence angle at the image edge.
        edge_deg: f64,
    },
    /// `white_reflectance` outside `(0, 1.5]`.
    #[error("[[angle]] {index}: white_reflectance = {value} is outside (0, 1.5]")]
    BadWhiteReflectance {
        /// 1-based entry index.
        index: usize,
        /// The value.
        value: f64,
    },
    /// A cube or reference header does not exist.
    #[error("{role} of [[angle]] {index} not found: {}", .path.display())]
    MissingFile {
        /// `cube`, `white` or `dark`.
        role: &'static str,
        /// 1-based entry index.
        index: usize,
        /// The resolved path.
        path: PathBuf,
    },
    /// A cube or reference could not be read (bad header, missing data, size mismatch).
    #[error("{0}")]
    Envi(EnviError),
    /// A cube's geometry differs from the first cube's.
    #[error("{what} differ from {reference} (the first cube): {found} vs {expected}")]
    CubeMismatch {
        /// What differs: `samples`, `lines`, `bands` or `wavelengths`.
        what: &'static str,
        /// This cube's value.
        found: String,
        /// The first cube's value.
        expected: String,
        /// The first cube's file name.
        reference: String,
    },
    /// A white or dark reference does not fit its cube.
    #[error("{role} reference has {what} {found} but its cube {cube} has {expected}")]
    ReferenceMismatch {
        /// `white` or `dark`.
        role: &'static str,
        /// What differs: `samples`, `bands`, `lines` or `wavelengths`.
        what: &'static str,
        /// The reference's value.
        found: String,
        /// The cube's value (and what else would do).
        expected: String,
        /// The cube's file name.
        cube: String,
    },
    /// A raw-count cube without a white reference.
    #[error(
        "[[angle]] {index}: cube {cube} holds raw counts (data type 12) but has no white reference"
    )]
    RawWithoutWhite {
        /// 1-based entry index.
        index: usize,
        /// The cube's file name.
        cube: String,
    },
    /// A path that TOML cannot hold (not UTF-8).
    #[error("path is not valid UTF-8: {}", .path.display())]
    NonUtf8Path {
        /// The path.
        path: PathBuf,
    },
    /// The capture could not be rendered as TOML.
    #[error("cannot render TOML: {message}")]
    Serialize {
        /// The serializer's message, on one line.
        message: String,
    },
}

#[derive(Deserialize, Serialize)]
struct RawCapture {
    sample: RawSample,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    search: Option<RawSearch>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    lens: Option<RawLens>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fit: Option<RawFit>,
    #[serde(default)]
    angle: Vec<RawAngle>,
}

#[derive(Deserialize, Serialize)]
struct RawFit {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    model_error: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    rig_tolerance: Option<f64>,
}

#[derive(Deserialize, Serialize)]
struct RawLens {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    horizontal_fov_deg: Option<f64>,
}

#[derive(Deserialize, Serialize)]
struct RawSample {
    #[serde(default = "one")]
    ambient_index: f64,
    #[serde(default)]
    substrate_index: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    substrate: Option<String>,
    #[serde(default = "default_polarization")]
    polarization: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    back_face: Option<String>,
}

#[derive(Deserialize, Serialize)]
struct RawSearch {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    index_range: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    thickness_range_nm: Option<[f64; 2]>,
}

#[derive(Deserialize, Serialize)]
struct RawAngle {
    incidence_deg: f64,
    cube: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    white: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    dark: Option<String>,
    #[serde(default = "one")]
    white_reflectance: f64,
}

fn one() -> f64 {
    1.0
}

fn default_polarization() -> String {
    Polarization::S.name().to_string()
}

const SAMPLE_KEYS: &[&str] = &[
    "ambient_index",
    "substrate_index",
    "substrate",
    "polarization",
    "back_face",
];
const SEARCH_KEYS: &[&str] = &["index_range", "thickness_range_nm"];
const FIT_KEYS: &[&str] = &["model_error", "rig_tolerance"];
/// The largest `fit.model_error` a capture may give, RMS reflectance.
pub const MAX_MODEL_ERROR: f64 = 0.05;
/// The largest `fit.rig_tolerance` a capture may give.
pub const MAX_RIG_TOLERANCE: f64 = 10.0;

/// What is wrong with a tolerated model error (`fit.model_error`, `--model-error`), for a
/// message that names where it came from; `None` when it is in range.
pub fn model_error_problem(value: f64) -> Option<String> {
    (!(0.0..=MAX_MODEL_ERROR).contains(&value))
        .then(|| format!("outside 0 to {MAX_MODEL_ERROR} (RMS reflectance)"))
}

/// What is wrong with a rig tolerance (`fit.rig_tolerance`, `--rig-tolerance`), as
/// [`model_error_problem`].
pub fn rig_tolerance_problem(value: f64) -> Option<String> {
    (!(0.0..=MAX_RIG_TOLERANCE).contains(&value)).then(|| {
        format!("outside 0 to {MAX_RIG_TOLERANCE} (a multiple of the typical rig's terms)")
    })
}
const LENS_KEYS: &[&str] = &["horizontal_fov_deg"];
const ANGLE_KEYS: &[&str] = &[
    "incidence_deg",
    "cube",
    "white",
    "dark",
    "white_reflectance",
];

impl Capture {
    /// Refuses an output folder `out` (named `what` in the error) that is the capture's
    /// folder, lies inside it, or holds any file the capture uses: the result replaces the
    /// folder whole.
    pub fn check_output_outside(
        &self,
        what: &str,
        out: &Path,
    ) -> Result<(), super::output::OutputDirError> {
        let mut files = vec![self.path.clone()];
        for a in &self.angles {
            files.push(a.cube.clone());
            files.extend(a.white.iter().cloned());
            files.extend(a.dark.iter().cloned());
        }
        let folder = self
            .path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."))
            .to_path_buf();
        super::output::check_outside_inputs(what, out, &files, &[folder])
    }

    /// Loads and checks a capture: `path` is a `capture.toml` or a directory holding one.
    ///
    /// Runs [`Capture::from_toml_str`] and then [`Capture::check`].
    pub fn load(path: impl AsRef<Path>) -> Result<Self, CaptureError> {
        let path = path.as_ref();
        let toml_path = if path.is_dir() {
            path.join(CAPTURE_FILE_NAME)
        } else {
            path.to_path_buf()
        };
        let text = read_text(&toml_path)?;
        let capture = Self::from_toml_str(&text, &toml_path)?;
        capture.check()?;
        Ok(capture)
    }

    /// Parses capture text as if read from `toml_path`, resolving the angles' paths
    /// against its directory and checking every value, without touching any file.
    pub fn from_toml_str(text: &str, toml_path: &Path) -> Result<Self, CaptureError> {
        let err = |kind| CaptureError::new(toml_path, kind);
        let raw: RawCapture = toml::from_str(text).map_err(|e| {
            err(CaptureErrorKind::Toml {
                line: e.span().map(|s| line_of(text, s.start)),
                message: one_line(e.message()),
            })
        })?;
        let unknown_keys = text
            .parse::<toml::Table>()
            .map(|table| unknown_keys(&table))
            .unwrap_or_default();

        let polarization = Polarization::from_name(&raw.sample.polarization.trim().to_lowercase())
            .ok_or_else(|| {
                err(CaptureErrorKind::UnknownPolarization {
                    value: raw.sample.polarization.clone(),
                })
            })?;
        let back_face = match raw.sample.back_face.as_deref() {
            None => BackFace::None,
            Some(name) => BackFace::from_name(name.trim()).ok_or_else(|| {
                err(CaptureErrorKind::BadValue {
                    message: format!("sample.back_face = {name:?}: \"none\" or \"bare\""),
                })
            })?,
        };
        let dir = toml_path.parent().unwrap_or(Path::new(""));
        let substrate = match &raw.sample.substrate {
            None => None,
            Some(name) => {
                let local = dir.join(name);
                let target = if local.is_file() {
                    local.to_string_lossy().into_owned()
                } else {
                    name.clone()
                };
                let dispersion = crate::material::resolve(&target).map_err(|e| {
                    err(CaptureErrorKind::BadValue {
                        message: format!(
                            "sample.substrate = {name:?}: {}",
                            one_line(&e.to_string())
                        ),
                    })
                })?;
                Some(SubstrateMaterial {
                    name: name.clone(),
                    dispersion,
                })
            }
        };
        let substrate_index = match (raw.sample.substrate_index, &substrate) {
            (Some(n), _) => n,
            (None, Some(s)) => s.dispersion.index_at(550.0),
            (None, None) => {
                return Err(err(CaptureErrorKind::Toml {
                    line: None,
                    message: "missing field `substrate_index`".into(),
                }))
            }
        };
        let angles = raw
            .angle
            .into_iter()
            .map(|a| Angle {
                incidence_deg: a.incidence_deg,
                cube: dir.join(a.cube),
                white: a.white.map(|p| dir.join(p)),
                dark: a.dark.map(|p| dir.join(p)),
                white_reflectance: a.white_reflectance,
            })
            .collect();
        let capture = Self {
            path: toml_path.to_path_buf(),
            sample: Sample {
                ambient_index: raw.sample.ambient_index,
                substrate_index,
                substrate,
                polarization,
                back_face,
            },
            search: raw
                .search
                .map(|s| Search {
                    index_range: s.index_range,
                    thickness_range_nm: s.thickness_range_nm,
                })
                .unwrap_or_default(),
            lens: Lens {
                horizontal_fov_deg: raw.lens.and_then(|l| l.horizontal_fov_deg),
            },
            fit: Fit {
                model_error: raw.fit.as_ref().and_then(|f| f.model_error),
                rig_tolerance: raw.fit.as_ref().and_then(|f| f.rig_tolerance),
            },
            angles,
            unknown_keys,
        };
        capture.check_values()?;
        Ok(capture)
    }

    /// Checks the values alone (no file access): indices, angles, reflectances, ranges.
    pub fn check_values(&self) -> Result<(), CaptureError> {
        let err = |kind| CaptureError::new(&self.path, kind);
        let bad = |message: String| err(CaptureErrorKind::BadValue { message });
        let limit = |e: crate::limits::LimitError| err(e.into());
        crate::limits::check_sample(
            "sample.ambient_index",
            self.sample.ambient_index,
            "sample.substrate_index",
            self.sample.substrate_index,
        )
        .map_err(limit)?;
        if let Some(r) = self.search.index_range {
            crate::limits::check_index_range("search.index_range", r).map_err(limit)?;
        }
        if let Some(r) = self.search.thickness_range_nm {
            crate::limits::check_thickness_range("search.thickness_range_nm", r).map_err(limit)?;
        }
        if let Some(value) = self.fit.model_error {
            if let Some(p) = model_error_problem(value) {
                return Err(bad(format!("fit.model_error = {value}: {p}")));
            }
        }
        if let Some(value) = self.fit.rig_tolerance {
            if let Some(p) = rig_tolerance_problem(value) {
                return Err(bad(format!("fit.rig_tolerance = {value}: {p}")));
            }
        }
        if let Some(value) = self.lens.horizontal_fov_deg {
            if crate::optics::FieldOfView::new(value).is_none() {
                return Err(err(CaptureErrorKind::BadFieldOfView { value }));
            }
        }
        if self.angles.is_empty() {
            return Err(err(CaptureErrorKind::TooFewAngles {
                found: self.angles.len(),
            }));
        }
        crate::limits::check_angle_count("[[angle]]", self.angles.len()).map_err(limit)?;
        for (i, angle) in self.angles.iter().enumerate() {
            let index = i + 1;
            let deg = angle.incidence_deg;
            if !(deg.is_finite() && (0.0..90.0).contains(&deg)) {
                return Err(err(CaptureErrorKind::AngleOutOfRange {
                    index,
                    incidence_deg: deg,
                }));
            }
            if let Some(fov_deg) = self.lens.horizontal_fov_deg {
                let edge_deg = deg + 0.5 * fov_deg;
                if edge_deg >= 90.0 {
                    return Err(err(CaptureErrorKind::FieldBeyondGrazing {
                        index,
                        incidence_deg: deg,
                        fov_deg,
                        edge_deg,
                    }));
                }
            }
            let wr = angle.white_reflectance;
            if !(wr.is_finite() && wr > 0.0 && wr <= MAX_WHITE_REFLECTANCE) {
                return Err(err(CaptureErrorKind::BadWhiteReflectance {
                    index,
                    value: wr,
                }));
            }
            if let Some(j) = self.angles[..i]
                .iter()
                .position(|a| (a.incidence_deg - deg).abs() < ANGLE_TOLERANCE_DEG)
            {
                return Err(err(CaptureErrorKind::DuplicateAngle {
                    first: j + 1,
                    second: index,
                    incidence_deg: deg,
                }));
            }
        }
        Ok(())
    }

    /// Checks the files: every cube, white and dark header exists, parses, and its data
    /// file has the declared size; all cubes agree in samples, lines, bands and
    /// wavelengths; each white or dark reference has its cube's samples and bands (and
    /// wavelengths, when both give them) and either its lines or one line; a raw-count
    /// cube (data type 12) has a white reference. Returns the shared geometry.
    ///
    /// Whether cubes carry wavelengths at all is not checked here: a tool may supply them.
    pub fn check(&self) -> Result<CubeInfo, CaptureError> {
        self.check_values()?;
        let mut first: Option<(EnviHeader, String)> = None;
        for (i, angle) in self.angles.iter().enumerate() {
            let index = i + 1;
            let cube = self.open_header("cube", index, &angle.cube)?;
            let cube_name = file_name(&angle.cube);
            match &first {
                None => first = Some((cube.clone(), cube_name.clone())),
                Some((reference, reference_name)) => {
                    if let Some((what, found, expected)) = geometry_difference(&cube, reference) {
                        return Err(CaptureError::new(
                            &angle.cube,
                            CaptureErrorKind::CubeMismatch {
                                what,
                                found,
                                expected,
                                reference: reference_name.clone(),
                            },
                        ));
                    }
                }
            }
            if cube.data_type == DataType::U16 && angle.white.is_none() {
                return Err(CaptureError::new(
                    &self.path,
                    CaptureErrorKind::RawWithoutWhite {
                        index,
                        cube: cube_name,
                    },
                ));
            }
            for (role, path) in [("white", &angle.white), ("dark", &angle.dark)] {
                if let Some(path) = path {
                    let reference = self.open_header(role, index, path)?;
                    check_reference(role, &reference, &cube, &cube_name)
                        .map_err(|kind| CaptureError::new(path, kind))?;
                }
            }
        }
        if let Some((h, _)) = &first {
            if let Some(bands) = &h.wavelength_nm {
                crate::limits::check_bands("wavelength", bands, "fwhm", h.fwhm_nm.as_deref())
                    .map_err(|e| CaptureError::new(&self.angles[0].cube, e.into()))?;
            }
        }
        match first {
            Some((h, _)) => Ok(CubeInfo {
                samples: h.samples,
                lines: h.lines,
                bands: h.bands,
                data_type: h.data_type,
                wavelength_nm: h.wavelength_nm,
                fwhm_nm: h.fwhm_nm,
            }),
            // Unreachable after `check_values`, but reported rather than assumed.
            None => Err(CaptureError::new(
                &self.path,
                CaptureErrorKind::TooFewAngles { found: 0 },
            )),
        }
    }

    /// Opens `path` as a cube (header and data size), returning its header.
    fn open_header(
        &self,
        role: &'static str,
        index: usize,
        path: &Path,
    ) -> Result<EnviHeader, CaptureError> {
        if !path.is_file() {
            return Err(CaptureError::new(
                &self.path,
                CaptureErrorKind::MissingFile {
                    role,
                    index,
                    path: path.to_path_buf(),
                },
            ));
        }
        let reader = EnviReader::open(path)?;
        Ok(reader.header().clone())
    }

    /// Writes this capture as TOML to `path` (a file, or a directory to hold
    /// `capture.toml`), atomically.
    ///
    /// Angle paths inside the target's directory are written relative to it; other paths
    /// are written as they are (so a relative one is read relative to the new file).
    /// Defaults are written out explicitly; [`Capture::unknown_keys`] are not written.
    pub fn write_toml(&self, path: impl AsRef<Path>) -> Result<(), CaptureError> {
        let path = path.as_ref();
        let toml_path = if path.is_dir() {
            path.join(CAPTURE_FILE_NAME)
        } else {
            path.to_path_buf()
        };
        let dir = toml_path.parent().unwrap_or(Path::new(""));
        let rel = |p: &Path| -> Result<String, CaptureError> {
            let p = match p.strip_prefix(dir) {
                Ok(stripped) if !dir.as_os_str().is_empty() => stripped,
                _ => p,
            };
            p.to_str().map(str::to_string).ok_or_else(|| {
                CaptureError::new(
                    &toml_path,
                    CaptureErrorKind::NonUtf8Path {
                        path: p.to_path_buf(),
                    },
                )
            })
        };
        let mut angle = Vec::with_capacity(self.angles.len());
        for a in &self.angles {
            angle.push(RawAngle {
                incidence_deg: a.incidence_deg,
                cube: rel(&a.cube)?,
                white: a.white.as_deref().map(rel).transpose()?,
                dark: a.dark.as_deref().map(rel).transpose()?,
                white_reflectance: a.white_reflectance,
            });
        }
        let search = (self.search != Search::default()).then_some(RawSearch {
            index_range: self.search.index_range,
            thickness_range_nm: self.search.thickness_range_nm,
        });
        let lens = self.lens.horizontal_fov_deg.map(|f| RawLens {
            horizontal_fov_deg: Some(f),
        });
        let fit = (self.fit != Fit::default()).then_some(RawFit {
            model_error: self.fit.model_error,
            rig_tolerance: self.fit.rig_tolerance,
        });
        let raw = RawCapture {
            sample: RawSample {
                ambient_index: self.sample.ambient_index,
                substrate_index: Some(self.sample.substrate_index),
                substrate: self.sample.substrate.as_ref().map(|s| s.name.clone()),
                polarization: self.sample.polarization.name().to_string(),
                back_face: (self.sample.back_face != BackFace::None)
                    .then(|| self.sample.back_face.name().to_string()),
            },
            search,
            lens,
            fit,
            angle,
        };
        let text = toml::to_string(&raw).map_err(|e| {
            CaptureError::new(
                &toml_path,
                CaptureErrorKind::Serialize {
                    message: one_line(&e.to_string()),
                },
            )
        })?;
        write_atomic(&toml_path, text.as_bytes()).map_err(|e| {
            CaptureError::new(
                &toml_path,
                CaptureErrorKind::Io {
                    action: "cannot write",
                    err: e,
                },
            )
        })
    }
}

/// Reads a capture file, refusing absurd sizes and anything but a regular file (a FIFO
/// would block, a device never end).
fn read_text(path: &Path) -> Result<String, CaptureError> {
    let io_err = |action, err| CaptureError::new(path, CaptureErrorKind::Io { action, err });
    std::fs::metadata(path).map_err(|e| io_err("cannot open", e))?;
    crate::limits::read_small(path, MAX_CAPTURE_BYTES).map_err(|e| io_err("cannot read", e))
}

/// 1-based line holding byte `offset` of `text`.
fn line_of(text: &str, offset: usize) -> usize {
    let end = offset.min(text.len());
    text.as_bytes()
        .get(..end)
        .map_or(0, |b| b.iter().filter(|&&c| c == b'\n').count())
        + 1
}

/// Joins a multi-line message into one line.
fn one_line(message: &str) -> String {
    message
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join("; ")
}

/// Dotted paths of keys the format does not define.
fn unknown_keys(table: &toml::Table) -> Vec<String> {
    fn check(out: &mut Vec<String>, prefix: &str, value: &toml::Value, known: &[&str]) {
        if let Some(t) = value.as_table() {
            for key in t.keys() {
                if !known.contains(&key.as_str()) {
                    out.push(format!("{prefix}.{key}"));
                }
            }
        }
    }
    let mut out = Vec::new();
    for (key, value) in table {
        match key.as_str() {
            "sample" => check(&mut out, "sample", value, SAMPLE_KEYS),
            "search" => check(&mut out, "search", value, SEARCH_KEYS),
            "lens" => check(&mut out, "lens", value, LENS_KEYS),
            "fit" => check(&mut out, "fit", value, FIT_KEYS),
            "angle" => {
                for (i, entry) in value.as_array().into_iter().flatten().enumerate() {
                    check(&mut out, &format!("angle[{}]", i + 1), entry, ANGLE_KEYS);
                }
            }
            _ => out.push(key.clone()),
        }
    }
    out
}

fn wavelengths_differ(a: &Option<Vec<f64>>, b: &Option<Vec<f64>>) -> bool {
    match (a, b) {
        (None, None) => false,
        (Some(a), Some(b)) => {
            a.len() != b.len()
                || a.iter()
                    .zip(b)
                    .any(|(x, y)| (x - y).abs() > WAVELENGTH_TOLERANCE_NM)
        }
        _ => true,
    }
}

fn describe_wavelengths(w: &Option<Vec<f64>>) -> String {
    match w {
        None => "none".to_string(),
        Some(list) => match (list.first(), list.last()) {
            (Some(a), Some(b)) => format!("{} bands {a}..{b} nm", list.len()),
            _ => "an empty list".to_string(),
        },
    }
}

/// The first geometric difference between two cubes, as (what, this, reference).
fn geometry_difference(
    cube: &EnviHeader,
    reference: &EnviHeader,
) -> Option<(&'static str, String, String)> {
    for (what, a, b) in [
        ("samples", cube.samples, reference.samples),
        ("lines", cube.lines, reference.lines),
        ("bands", cube.bands, reference.bands),
    ] {
        if a != b {
            return Some((what, a.to_string(), b.to_string()));
        }
    }
    if wavelengths_differ(&cube.wavelength_nm, &reference.wavelength_nm) {
        return Some((
            "wavelengths",
            describe_wavelengths(&cube.wavelength_nm),
            describe_wavelengths(&reference.wavelength_nm),
        ));
    }
    None
}

/// Checks a white or dark reference against its cube.
fn check_reference(
    role: &'static str,
    reference: &EnviHeader,
    cube: &EnviHeader,
    cube_name: &str,
) -> Result<(), CaptureErrorKind> {
    let mismatch = |what, found: String, expected: String| CaptureErrorKind::ReferenceMismatch {
        role,
        what,
        found,
        expected,
        cube: cube_name.to_string(),
    };
    if reference.samples != cube.samples {
        return Err(mismatch(
            "samples",
            reference.samples.to_string(),
            cube.samples.to_string(),
        ));
    }
    if reference.bands != cube.bands {
        return Err(mismatch(
            "bands",
            reference.bands.to_string(),
            cube.bands.to_string(),
        ));
    }
    if reference.lines != cube.lines && reference.lines != 1 {
        return Err(mismatch(
            "lines",
            reference.lines.to_string(),
            format!("{} (a reference may also have 1)", cube.lines),
        ));
    }
    if reference.wavelength_nm.is_some()
        && cube.wavelength_nm.is_some()
        && wavelengths_differ(&reference.wavelength_nm, &cube.wavelength_nm)
    {
        return Err(mismatch(
            "wavelengths",
            describe_wavelengths(&reference.wavelength_nm),
            describe_wavelengths(&cube.wavelength_nm),
        ));
    }
    Ok(())
}

impl CaptureErrorKind {
    /// The ENVI problem, when this is one.
    pub fn envi(&self) -> Option<&EnviErrorKind> {
        match self {
            Self::Envi(e) => Some(e.kind()),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const VALID: &str = r#"
[sample]
substrate_index = 1.65
[[angle]]
incidence_deg = 20
cube = "a20.hdr"
white = "w.hdr"
[[angle]]
incidence_deg = 10.0
cube = "sub/a10.hdr"
typo_key = 3
"#;

    #[test]
    fn parses_defaults_resolves_paths_and_lists_unknown_keys() -> Result<(), CaptureError> {
        let c = Capture::from_toml_str(VALID, Path::new("run/capture.toml"))?;
        assert_eq!(c.sample.ambient_index, 1.0);
        assert_eq!(c.sample.polarization, Polarization::S);
        assert_eq!(c.search, Search::default());
        assert_eq!(c.angles[0].incidence_deg, 20.0);
        assert_eq!(c.angles[0].white, Some(PathBuf::from("run/w.hdr")));
        assert_eq!(c.angles[1].cube, PathBuf::from("run/sub/a10.hdr"));
        assert_eq!(c.angles[1].white_reflectance, 1.0);
        assert_eq!(c.unknown_keys, vec!["angle[2].typo_key".to_string()]);
        Ok(())
    }

    #[test]
    fn the_lens_field_of_view_is_read_checked_and_written_back() -> Result<(), CaptureError> {
        let path = Path::new("run/capture.toml");
        let text = format!("{VALID}\n[lens]\nhorizontal_fov_deg = 30.0\n");
        let c = Capture::from_toml_str(&text, path)?;
        assert_eq!(c.lens.horizontal_fov_deg, Some(30.0));
        assert_eq!(c.unknown_keys, vec!["angle[2].typo_key".to_string()]);
        assert_eq!(Capture::from_toml_str(VALID, path)?.lens, Lens::default());
        for bad in ["0.0", "180.0", "-2.0", "inf"] {
            let text = format!("{VALID}\n[lens]\nhorizontal_fov_deg = {bad}\n");
            let e = Capture::from_toml_str(&text, path)
                .err()
                .map(|e| e.to_string());
            let msg = e.unwrap_or_default();
            assert!(
                msg.starts_with("run/capture.toml: lens.horizontal_fov_deg"),
                "{msg}"
            );
        }
        let dir = tempfile::tempdir().map_err(|e| {
            CaptureError::new(
                path,
                CaptureErrorKind::Io {
                    action: "tempdir",
                    err: e,
                },
            )
        })?;
        let out = dir.path().join("capture.toml");
        c.write_toml(&out)?;
        let back = std::fs::read_to_string(&out).unwrap_or_default();
        assert!(back.contains("[lens]\nhorizontal_fov_deg = 30.0"), "{back}");
        Ok(())
    }

    #[test]
    fn toml_errors_are_one_line_with_a_line_number() {
        let text = "[sample]\nsubstrate_index = \"high\"\n";
        match Capture::from_toml_str(text, Path::new("c.toml")) {
            Ok(_) => panic!("parsed"),
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.starts_with("c.toml: line 2: "), "{msg}");
                assert!(!msg.contains('\n'), "{msg}");
            }
        }
    }
}
