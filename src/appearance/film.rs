//! A maps directory read back as a film: the thickness map, the estimated index with its
//! dispersion, and the stack around it (ambient, substrate, polarisation).

use std::path::{Path, PathBuf};

use filmscope_core::optics::{BackFace, Dispersion, FilmStack, Polarization};
use filmscope_core::solve::flags;
use filmscope_core::solve::refine::FilmTerms;

use super::AppearanceError;
use crate::io::{read_cube, Capture};
use crate::summary::Summary;

/// An estimated film, as `filmscope estimate` wrote it into a maps directory.
#[derive(Clone, Debug)]
pub struct SampleFilm {
    /// The maps directory.
    pub maps_dir: PathBuf,
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Thickness per pixel, row-major, nm; NaN where there is no reliable estimate.
    pub thickness_nm: Vec<f32>,
    /// Pixel flags ([`flags`]), row-major; all zero when the directory has no flag map.
    pub flags: Vec<u16>,
    /// Ambient, film (the estimated index and dispersion) and substrate, and the
    /// polarisation the capture measured.
    pub stack: FilmStack,
    /// The film's absorption beyond its dispersion's own `k`, as the sample fit found it
    /// (`film_k_450nm` of the summary's nuisance terms; no polariser leak: that is the
    /// rig's, not the film's).
    pub terms: FilmTerms,
    /// The capture the maps were estimated from, when it can still be found.
    pub capture: Option<PathBuf>,
    /// `summary.json` as written.
    pub summary: Summary,
}

impl SampleFilm {
    /// Reads `maps_dir` (`summary.json`, `thickness_nm.hdr`, `flags.hdr` if present).
    ///
    /// The substrate, ambient index and polarisation come from `capture` when given (a
    /// `capture.toml` or its directory), else from the summary's `sample` entry, else from
    /// the capture the summary names as its `source`. Errors name the file at fault.
    pub fn load(maps_dir: &Path, capture: Option<&Path>) -> Result<Self, AppearanceError> {
        let summary_path = maps_dir.join(crate::summary::FILE);
        let bad = |what: String| AppearanceError::new(&summary_path, what);
        let summary = Summary::read(maps_dir).map_err(AppearanceError::from)?;
        let n = summary
            .refractive_index
            .filter(|n| n.is_finite() && *n > 0.0)
            .ok_or_else(|| bad("no finite refractive_index: the estimate found no index".into()))?;
        let film = match &summary.dispersion {
            None => Dispersion::constant(n),
            Some(d) => d
                .model
                .dispersion()
                .map_err(|e| bad(format!("dispersion: {e}")))?,
        };

        let thick_path = maps_dir.join("thickness_nm.hdr");
        let cube = read_cube(&thick_path).map_err(|e| AppearanceError::new(&thick_path, e))?;
        let (width, height) = (cube.samples, cube.lines);
        if cube.bands != 1 || width == 0 || height == 0 {
            return Err(AppearanceError::new(
                &thick_path,
                format!(
                    "expected one band of at least 1x1 pixels, found {}x{}x{}",
                    width, height, cube.bands
                ),
            ));
        }
        let flags_path = maps_dir.join("flags.hdr");
        let flags = if flags_path.exists() {
            let f = read_cube(&flags_path).map_err(|e| AppearanceError::new(&flags_path, e))?;
            if (f.samples, f.lines, f.bands) != (width, height, 1) {
                return Err(AppearanceError::new(
                    &flags_path,
                    format!(
                        "is {}x{}, the thickness map {width}x{height}",
                        f.samples, f.lines
                    ),
                ));
            }
            // Flags are small integers stored exactly in f32.
            f.data.iter().map(|&v| v as u16).collect()
        } else {
            vec![0; width * height]
        };

        let source = Some(PathBuf::from(&summary.source)).filter(|p| p.exists());
        let capture_path = capture.map(Path::to_path_buf).or(source);
        let (ambient_index, substrate, polarization, back_face) = match (capture, &summary.sample) {
            (None, Some(sample)) => {
                // A dispersive substrate is `sample.substrate`; a constant one only
                // `sample.substrate_index`.
                let substrate = match &sample.substrate {
                    Some(d) => d
                        .dispersion()
                        .map_err(|e| bad(format!("sample.substrate: {e}")))?,
                    None => Dispersion::constant(sample.substrate_index),
                };
                let pol = Polarization::from_name(&sample.polarization).ok_or_else(|| {
                    bad(format!(
                        "sample.polarization: `{}` is not s, p or unpolarized",
                        sample.polarization
                    ))
                })?;
                let back_face = BackFace::from_name(&sample.back_face).ok_or_else(|| {
                    bad(format!(
                        "sample.back_face: `{}` is not none or bare",
                        sample.back_face
                    ))
                })?;
                (sample.ambient_index, substrate, pol, back_face)
            }
            _ => {
                let path = capture_path.as_deref().ok_or_else(|| {
                    bad("no substrate index: the summary has no `sample` and its `source` capture is gone (pass --capture)".into())
                })?;
                let cap = Capture::load(path).map_err(AppearanceError::from)?;
                (
                    cap.sample.ambient_index,
                    cap.sample.substrate_dispersion(),
                    cap.sample.polarization,
                    cap.sample.back_face,
                )
            }
        };
        let found = crate::estimate::index_fit::correction_from(
            summary
                .index_model_choice
                .as_ref()
                .and_then(|c| c.nuisance_terms()),
        );
        let terms = FilmTerms {
            film_k: found.film.film_k,
            leak: 0.0,
        };
        Ok(Self {
            maps_dir: maps_dir.to_path_buf(),
            width,
            height,
            thickness_nm: cube.data,
            flags,
            stack: FilmStack {
                back_face,
                ambient_index,
                film,
                substrate,
                polarization,
            },
            terms,
            capture: capture_path,
            summary,
        })
    }

    /// The thickness of pixel `i` when it is a reliable estimate, else `None` (NaN, or a
    /// flag that makes it unreliable).
    pub fn thickness_at(&self, i: usize) -> Option<f64> {
        let d = f64::from(*self.thickness_nm.get(i)?);
        let flagged = self.flags.get(i).is_some_and(|f| f & flags::INVALID != 0);
        (d.is_finite() && !flagged).then_some(d)
    }

    /// The film's index at 550 nm.
    pub fn index_550(&self) -> f64 {
        self.stack.film.index_at(550.0)
    }

    /// The substrate's index at 550 nm.
    pub fn substrate_550(&self) -> f64 {
        self.stack.substrate.index_at(550.0)
    }

    /// The median of the reliable thicknesses, nm (`None` without any).
    pub fn median_thickness_nm(&self) -> Option<f64> {
        let mut v: Vec<f64> = (0..self.thickness_nm.len())
            .filter_map(|i| self.thickness_at(i))
            .collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        Some(v[v.len() / 2])
    }

    /// One line describing the model, for captions: index, dispersion, absorption,
    /// substrate.
    pub fn describe(&self) -> String {
        let disp = match self.stack.film {
            Dispersion::Cauchy { b_um2, .. } if b_um2 != 0.0 => {
                format!(" (Cauchy, b = {b_um2:.4} µm²)")
            }
            _ => String::new(),
        };
        let light = match self.stack.polarization {
            Polarization::S => "S-polarised",
            Polarization::P => "P-polarised",
            Polarization::Unpolarized => "unpolarised",
        };
        let k = self.stack.film.extinction_at(450.0) + self.terms.film_k;
        let k = if k > 0.0 {
            format!(", k(450 nm) = {k:.4}")
        } else {
            String::new()
        };
        format!(
            "n = {:.4}{disp}{k} on n = {:.3}, {light}",
            self.index_550(),
            self.substrate_550(),
        )
    }
}
