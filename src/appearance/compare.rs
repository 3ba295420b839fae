//! Measured against reproduced: every captured angle, as the camera measured it and as the
//! estimated film model reproduces it, with the CIEDE2000 difference per pixel.
//!
//! Both sides go through the identical band-limited colorimetry, so the comparison is fair:
//!
//! - measured: the calibrated reflectance of each pixel at the capture's bands (e.g.
//!   420..720 nm every 2 nm), linearly interpolated onto the CIE 5 nm grid;
//! - reproduced: the film model (estimated index with its dispersion, the pixel's
//!   thickness, the capture's substrate and polarisation) averaged over each band's LCTF
//!   passband, i.e. what the camera would have measured of the model film, interpolated
//!   the same way;
//! - both summed to XYZ over only the grid wavelengths inside the bands
//!   ([`Colorimetry::within`]: nothing is extrapolated outside what was measured), under
//!   the chosen illuminant, normalised so a perfect reflector has `Y = 100`; CIELAB
//!   against that band-limited white; CIEDE2000 between the two.
//!
//! A pixel takes part where its thickness is reliable and every band of its measured
//! spectrum is usable (no saturated or dead sample). The mean and 95th percentile are over
//! those pixels, per angle and over all angles.
//!
//! The capture is streamed, not loaded: each angle's measured colour is summed band by band
//! as the rows arrive ([`compare_stream`]), so memory is a few numbers per pixel and angle
//! whatever the number of bands.

use std::path::{Path, PathBuf};

use crossbeam_channel::bounded;
use filmscope_core::colour::{delta_e2000, Colorimetry, Illuminant, Xyz};
use filmscope_core::optics::{FilmStack, Passband};
use filmscope_core::solve::SweepSpec;

use super::film::SampleFilm;
use super::render::{auto_exposure, blit, display_rgb, sample_grid, swatch_note, upscale};
use super::spectral::{capture_passbands, BandSpectrum};
use super::AppearanceError;
use crate::export::canvas::{text_width, Canvas, BACKGROUND, CAP_ROWS, INK};
use crate::export::colormap::{viridis, NO_DATA};
use crate::io::{Capture, DataType, EnviHeader, EnviWriter, Interleave};
use crate::source::calibrate_block;
use crate::source::{CaptureSource, RowBlock, Source, StreamMsg};

/// One captured angle, measured against reproduced.
#[derive(Clone, Debug)]
pub struct AngleComparison {
    /// Incidence angle, degrees.
    pub incidence_deg: f64,
    /// Measured colour per pixel (row-major), NaN where the pixel takes no part.
    pub measured: Vec<Xyz>,
    /// Reproduced colour per pixel, NaN where the pixel takes no part.
    pub reproduced: Vec<Xyz>,
    /// CIEDE2000 per pixel, NaN where the pixel takes no part.
    pub delta_e2000: Vec<f32>,
    /// Statistics of the finite differences.
    pub stats: DeltaStats,
}

/// How `compare` sets the measured colour beside the reproduced one, as `compare.json`
/// states it.
const APPROACH: &str = "measured reflectance at the capture's bands and the film model averaged over the same passbands, both interpolated onto the CIE 5 nm grid and summed only within the bands (white = perfect reflector over the same range); pixels with a reliable thickness and a fully usable measured spectrum";

/// `compare.json`: what was compared and how, then the CIEDE2000 figures over all angles
/// and per angle.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CompareRecord {
    /// The colour difference, `CIEDE2000`.
    pub metric: String,
    /// The illuminant's name.
    pub illuminant: String,
    /// The standard observer.
    pub observer: String,
    /// The band the colours are summed over, nm.
    pub band_limited_nm: [f64; 2],
    /// How measured and reproduced colours are formed, in words.
    pub approach: String,
    /// Map width, pixels.
    pub width: usize,
    /// Map height, pixels.
    pub height: usize,
    /// Over every angle.
    pub overall: DeltaStats,
    /// Per incidence angle, in the capture's order.
    pub per_angle: Vec<AngleRecord>,
}

/// One angle's figures in `compare.json`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AngleRecord {
    /// Incidence angle, degrees.
    pub incidence_deg: f64,
    /// Its CIEDE2000 figures.
    #[serde(flatten)]
    pub stats: DeltaStats,
}

/// Mean, median and 95th percentile of a set of colour differences.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DeltaStats {
    /// Number of pixels compared.
    pub pixels: usize,
    /// Mean CIEDE2000 (NaN without pixels).
    pub mean: f64,
    /// Median CIEDE2000.
    pub median: f64,
    /// 95th percentile CIEDE2000 (nearest rank).
    pub p95: f64,
}

impl DeltaStats {
    /// The statistics of the finite values of `v`.
    pub fn of(v: impl Iterator<Item = f32>) -> Self {
        let mut d: Vec<f64> = v.filter(|x| x.is_finite()).map(f64::from).collect();
        if d.is_empty() {
            return Self {
                pixels: 0,
                mean: f64::NAN,
                median: f64::NAN,
                p95: f64::NAN,
            };
        }
        d.sort_by(f64::total_cmp);
        let rank = |q: f64| d[((q * d.len() as f64).ceil() as usize).clamp(1, d.len()) - 1];
        Self {
            pixels: d.len(),
            mean: d.iter().sum::<f64>() / d.len() as f64,
            median: rank(0.5),
            p95: rank(0.95),
        }
    }
}

/// Every captured angle compared.
#[derive(Clone, Debug)]
pub struct Comparison {
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The colorimetry both sides were summed with (band-limited).
    pub colorimetry: Colorimetry,
    /// Per angle, in ascending angle.
    pub angles: Vec<AngleComparison>,
    /// Over all angles and pixels.
    pub overall: DeltaStats,
}

/// Opens a capture (`capture.toml` or its directory) as a stream of calibrated rows.
pub fn open_capture(capture: &Path) -> Result<CaptureSource, AppearanceError> {
    let cap = Capture::load(capture).map_err(AppearanceError::from)?;
    CaptureSource::new(cap).map_err(AppearanceError::from)
}

/// One pixel's band reflectance at one angle, measured and modelled: `(nm, R)` pairs.
#[derive(Clone, Debug)]
pub struct PixelSpectra {
    /// Incidence angle, degrees.
    pub incidence_deg: f64,
    /// Measured (calibrated) reflectance per band (non-finite where the sample is
    /// saturated or has no usable reference).
    pub measured: Vec<(f64, f64)>,
    /// The film model averaged over each band's passband.
    pub model: Vec<(f64, f64)>,
}

/// The pixel whose reliable thickness is nearest the median (`None` without any).
pub fn median_pixel(film: &SampleFilm) -> Option<usize> {
    let median = film.median_thickness_nm()?;
    (0..film.width * film.height)
        .filter_map(|i| film.thickness_at(i).map(|d| (i, d)))
        .min_by(|a, b| (a.1 - median).abs().total_cmp(&(b.1 - median).abs()))
        .map(|(i, _)| i)
}

/// The comparison of the angle being streamed: measured XYZ summed band by band.
struct AngleAccumulator {
    incidence_deg: f64,
    /// Measured XYZ per pixel, summed as the bands arrive.
    xyz: Vec<[f64; 3]>,
    /// Pixels with a saturated or unusable sample at some band.
    unusable: Vec<bool>,
    /// The traced pixel's measured spectrum (NaN until its band arrives).
    traced: Vec<f64>,
}

/// Compares `film` with the sweep `source` streams (the capture it was estimated from),
/// under `illuminant`, angle by angle as the rows arrive: memory is a few numbers per
/// pixel and angle, never the whole sweep. Also returns the measured and modelled spectra
/// of pixel `trace` (if given) at every angle, in ascending angle.
///
/// The band-limited XYZ of a sampled spectrum (linear interpolation onto the grid, then a
/// weighted sum) is linear in the samples, so it is accumulated band by band with each
/// band's weights, the XYZ of the unit spectrum at that band: exactly
/// [`Colorimetry::xyz_sampled`] of the whole spectrum, to rounding.
///
/// With `cubes`, each angle's model and residual (measured minus model) reflectance are also
/// written there as ENVI cubes, `model-AA.hdr` and `residual-AA.hdr` (float32, band
/// sequential, NaN where a pixel has no thickness), as the rows stream.
pub fn compare_stream(
    film: &SampleFilm,
    source: &mut dyn Source,
    illuminant: Illuminant,
    trace: Option<usize>,
    cubes: Option<&Path>,
) -> Result<(Comparison, Vec<PixelSpectra>), AppearanceError> {
    let mut state = StreamedComparison::new(film, source.spec(), illuminant, trace, cubes)?;
    let (tx, rx) = bounded::<StreamMsg>(64);
    std::thread::scope(|scope| -> Result<(), AppearanceError> {
        scope.spawn(move || source.stream(&tx));
        // `rx` moves in here: dropped when this returns early, so the source's next send
        // fails and it stops instead of blocking the scope's join on a full channel.
        for msg in rx {
            match msg {
                StreamMsg::Angle { incidence_deg } => state.begin_angle(incidence_deg)?,
                StreamMsg::Rows(block) => state.add_rows(block)?,
                StreamMsg::AngleEnd => state.end_angle()?,
                StreamMsg::BandEnd { .. } => {}
                StreamMsg::SweepEnd => return Ok(()),
                StreamMsg::Abort(e) => return Err(AppearanceError::Stream(e)),
            }
        }
        Err(state.at("the capture stopped without ending the sweep".into()))
    })?;
    Ok(state.finish())
}

/// A comparison while the sweep streams: what each message needs (the sweep's size and
/// bands, the film, each band's colour weights) and what the angles so far gave.
struct StreamedComparison<'a> {
    film: &'a SampleFilm,
    /// The sweep's size: pixels per row, rows, bands.
    w: usize,
    h: usize,
    nb: usize,
    bands_nm: Vec<f64>,
    fwhm_nm: Vec<f64>,
    /// The film under the capture's polarisation.
    stack: FilmStack,
    /// Each band's passband.
    bands: Vec<Passband>,
    /// Each band's weights: the band-limited XYZ of the unit spectrum at that band.
    weights: Vec<[f64; 3]>,
    colorimetry: Colorimetry,
    /// The pixel whose spectra are kept.
    trace: Option<usize>,
    /// Where the model and residual cubes go, if they are written.
    cubes: Option<&'a Path>,
    /// The angles compared so far, and the traced pixel's spectra at them.
    angles: Vec<AngleComparison>,
    spectra: Vec<PixelSpectra>,
    /// The angle being streamed.
    current: Option<AngleAccumulator>,
    /// The model and residual cubes of the current angle, with the angle's band models.
    writers: Option<(BandSpectrum, EnviWriter, EnviWriter)>,
}

/// An ENVI cube that could not be written.
fn envi_err(e: crate::io::EnviError) -> AppearanceError {
    AppearanceError::Cube(e)
}

impl<'a> StreamedComparison<'a> {
    /// Ready to compare `film` with a sweep of `spec` under `illuminant`; an error if the
    /// sizes differ or the bands hold no CIE grid wavelength.
    fn new(
        film: &'a SampleFilm,
        spec: &SweepSpec,
        illuminant: Illuminant,
        trace: Option<usize>,
        cubes: Option<&'a Path>,
    ) -> Result<Self, AppearanceError> {
        let at = |what: String| AppearanceError::new(&film.maps_dir, what);
        let (w, h) = (spec.width, spec.height);
        if (w, h) != (film.width, film.height) {
            return Err(at(format!(
                "the maps are {}x{} but the capture is {w}x{h}",
                film.width, film.height
            )));
        }
        let bands_nm = spec.bands_nm.to_vec();
        let (first, last) = (
            bands_nm.first().copied().unwrap_or(f64::NAN),
            bands_nm.last().copied().unwrap_or(f64::NAN),
        );
        let colorimetry = Colorimetry::within(illuminant, first, last).ok_or_else(|| {
            at(format!(
                "the capture's bands {first}..{last} nm hold no 5 nm CIE grid wavelength"
            ))
        })?;
        let nb = bands_nm.len();
        let weights: Vec<[f64; 3]> = (0..nb)
            .map(|b| {
                let unit: Vec<f64> = (0..nb).map(|k| if k == b { 1.0 } else { 0.0 }).collect();
                let x = colorimetry.xyz_sampled(&bands_nm, &unit);
                [x.x, x.y, x.z]
            })
            .collect();
        let bands = capture_passbands(&bands_nm, &spec.fwhm_nm);
        let mut stack = film.stack;
        stack.polarization = spec.polarization;
        Ok(Self {
            film,
            w,
            h,
            nb,
            bands_nm,
            fwhm_nm: spec.fwhm_nm.to_vec(),
            stack,
            bands,
            weights,
            colorimetry,
            trace: trace.filter(|&p| p < w * h),
            cubes,
            angles: Vec::new(),
            spectra: Vec::new(),
            current: None,
            writers: None,
        })
    }

    /// `what` went wrong with the maps' capture.
    fn at(&self, what: String) -> AppearanceError {
        AppearanceError::new(&self.film.maps_dir, what)
    }

    /// The header of the `what` reflectance cube at `deg`.
    fn cube_header(&self, what: &str, deg: f64) -> EnviHeader {
        let mut h = EnviHeader::new(self.w, self.h, self.nb, DataType::F32, Interleave::Bsq);
        h.description = Some(format!(
            "filmscope compare: {what} reflectance at {deg} deg"
        ));
        h.wavelength_nm = Some(self.bands_nm.clone());
        h.fwhm_nm = Some(self.fwhm_nm.clone());
        h
    }

    /// An angle begins: its accumulator, and its model and residual cubes if asked for.
    fn begin_angle(&mut self, incidence_deg: f64) -> Result<(), AppearanceError> {
        if let Some(dir) = self.cubes {
            let name = |what: &str| dir.join(format!("{what}-{incidence_deg:02.0}.hdr"));
            self.writers = Some((
                BandSpectrum::new(self.stack, incidence_deg, &self.bands, self.film.terms),
                EnviWriter::create(name("model"), &self.cube_header("model", incidence_deg))
                    .map_err(envi_err)?,
                EnviWriter::create(
                    name("residual"),
                    &self.cube_header("measured minus model", incidence_deg),
                )
                .map_err(envi_err)?,
            ));
        }
        let (w, h) = (self.w, self.h);
        self.current = Some(AngleAccumulator {
            incidence_deg,
            xyz: vec![[0.0; 3]; w * h],
            unusable: vec![false; w * h],
            traced: vec![f64::NAN; self.nb],
        });
        Ok(())
    }

    /// A block of rows of one band: its calibrated reflectance added to each pixel's
    /// colour (and the traced pixel's spectrum), and the model and residual rows written.
    fn add_rows(&mut self, block: RowBlock) -> Result<(), AppearanceError> {
        let (w, h, nb) = (self.w, self.h, self.nb);
        let Some(acc) = self.current.as_mut() else {
            return Err(self.at("the capture sent rows outside an angle".into()));
        };
        let (band, first_row, rows) = (
            usize::from(block.band),
            block.first_row as usize,
            block.rows as usize,
        );
        let values = calibrate_block(block.samples, rows, w);
        if band >= nb || first_row + rows > h || values.len() != rows * w {
            return Err(AppearanceError::new(
                &self.film.maps_dir,
                format!(
                    "the capture sent band {band}, rows {first_row}..{} outside its {w}x{h}x{nb} sweep",
                    first_row + rows
                ),
            ));
        }
        let wb = self.weights[band];
        let start = first_row * w;
        for (k, &v) in values.iter().enumerate() {
            let px = start + k;
            if !v.is_finite() {
                acc.unusable[px] = true;
                continue;
            }
            let v = f64::from(v);
            for (s, c) in acc.xyz[px].iter_mut().zip(wb) {
                *s += c * v;
            }
        }
        if let Some(p) = self.trace.filter(|p| (start..start + rows * w).contains(p)) {
            acc.traced[band] = f64::from(values[p - start]);
        }
        if let Some((model, m_out, r_out)) = self.writers.as_mut() {
            let (mut m_row, mut r_row) = (vec![f32::NAN; w], vec![f32::NAN; w]);
            for (j, row) in values.chunks_exact(w).enumerate() {
                for (c, &v) in row.iter().enumerate() {
                    let d = self.film.thickness_at(start + j * w + c);
                    let m = d.map_or(f64::NAN, |d| model.band(band, d));
                    m_row[c] = m as f32;
                    r_row[c] = (f64::from(v) - m) as f32;
                }
                m_out
                    .write_band_row(band, first_row + j, &m_row)
                    .map_err(envi_err)?;
                r_out
                    .write_band_row(band, first_row + j, &r_row)
                    .map_err(envi_err)?;
            }
        }
        Ok(())
    }

    /// The angle ends: its cubes finished, its comparison (and the traced pixel's spectra)
    /// kept.
    fn end_angle(&mut self) -> Result<(), AppearanceError> {
        if let Some((_, m_out, r_out)) = self.writers.take() {
            m_out.finish().map_err(envi_err)?;
            r_out.finish().map_err(envi_err)?;
        }
        let Some(acc) = self.current.take() else {
            return Err(self.at("the capture ended an angle it never began".into()));
        };
        let (angle, traced) = finish_angle(
            self.film,
            self.stack,
            &self.bands,
            &self.weights,
            &self.colorimetry,
            acc,
            self.trace,
        );
        let incidence_deg = angle.incidence_deg;
        self.angles.push(angle);
        if let Some(model) = traced.1 {
            self.spectra.push(PixelSpectra {
                incidence_deg,
                measured: self.bands_nm.iter().copied().zip(traced.0).collect(),
                model: self.bands_nm.iter().copied().zip(model).collect(),
            });
        }
        Ok(())
    }

    /// The comparison of every angle, and the traced pixel's spectra, in ascending angle.
    fn finish(self) -> (Comparison, Vec<PixelSpectra>) {
        let (mut angles, mut spectra) = (self.angles, self.spectra);
        angles.sort_by(|a, b| a.incidence_deg.total_cmp(&b.incidence_deg));
        spectra.sort_by(|a, b| a.incidence_deg.total_cmp(&b.incidence_deg));
        let overall = DeltaStats::of(angles.iter().flat_map(|a| a.delta_e2000.iter().copied()));
        (
            Comparison {
                width: self.w,
                height: self.h,
                colorimetry: self.colorimetry,
                angles,
                overall,
            },
            spectra,
        )
    }
}

/// The model side of one streamed angle, and the differences. Returns the comparison and
/// the traced pixel's measured and (if it has a thickness) modelled spectra.
#[allow(clippy::type_complexity)]
fn finish_angle(
    film: &SampleFilm,
    stack: FilmStack,
    bands: &[Passband],
    weights: &[[f64; 3]],
    colorimetry: &Colorimetry,
    acc: AngleAccumulator,
    trace: Option<usize>,
) -> (AngleComparison, (Vec<f64>, Option<Vec<f64>>)) {
    let white = colorimetry.white();
    let model = BandSpectrum::new(stack, acc.incidence_deg, bands, film.terms);
    let n = film.width * film.height;
    let (mut measured, mut reproduced) = (vec![Xyz::NAN; n], vec![Xyz::NAN; n]);
    let mut de = vec![f32::NAN; n];
    let weighted = |r: &[f64]| {
        let mut s = [0.0; 3];
        for (v, wb) in r.iter().zip(weights) {
            for (si, c) in s.iter_mut().zip(wb) {
                *si += c * v;
            }
        }
        Xyz {
            x: s[0],
            y: s[1],
            z: s[2],
        }
    };
    // The model costs a few thousand cosines per pixel: one share of the pixels per core.
    let threads = std::thread::available_parallelism().map_or(1, |t| t.get());
    let chunk = n.div_ceil(threads).max(1);
    let (acc_ref, model_ref, weighted_ref) = (&acc, &model, &weighted);
    std::thread::scope(|scope| {
        let shares = measured
            .chunks_mut(chunk)
            .zip(reproduced.chunks_mut(chunk))
            .zip(de.chunks_mut(chunk))
            .enumerate();
        for (k, ((m_out, p_out), de_out)) in shares {
            scope.spawn(move || {
                let mut r = vec![0.0; bands.len()];
                for (j, ((m_o, p_o), de_o)) in m_out
                    .iter_mut()
                    .zip(p_out.iter_mut())
                    .zip(de_out.iter_mut())
                    .enumerate()
                {
                    let i = k * chunk + j;
                    let Some(d) = film.thickness_at(i) else {
                        continue;
                    };
                    if acc_ref.unusable[i] {
                        continue;
                    }
                    let [x, y, z] = acc_ref.xyz[i];
                    let m = Xyz { x, y, z };
                    model_ref.reflectance_into(d, &mut r);
                    let p = weighted_ref(&r);
                    *m_o = m;
                    *p_o = p;
                    *de_o = delta_e2000(m.to_lab(white), p.to_lab(white)) as f32;
                }
            });
        }
    });
    let mut r = vec![0.0; bands.len()];
    let traced_model = trace.and_then(|p| film.thickness_at(p)).map(|d| {
        model.reflectance_into(d, &mut r);
        r.clone()
    });
    let stats = DeltaStats::of(de.iter().copied());
    (
        AngleComparison {
            incidence_deg: acc.incidence_deg,
            measured,
            reproduced,
            delta_e2000: de,
            stats,
        },
        (acc.traced, traced_model),
    )
}

impl Comparison {
    /// Per angle, one ENVI raster `lab-AA.hdr/.img` (float32, band sequential): measured
    /// L\*, a\*, b\*, reproduced L\*, a\*, b\* and their CIEDE2000, NaN where a pixel takes
    /// no part; returns the headers written.
    pub fn write_envi(&self, dir: &Path) -> Result<Vec<PathBuf>, AppearanceError> {
        let white = self.colorimetry.white();
        let (w, h) = (self.width, self.height);
        let mut written = Vec::new();
        for a in &self.angles {
            let path = dir.join(format!("lab-{:02.0}.hdr", a.incidence_deg));
            let mut header = EnviHeader::new(w, h, 7, DataType::F32, Interleave::Bsq);
            header.description = Some(format!(
                "filmscope compare: measured and reproduced CIELAB and CIEDE2000 at {} deg",
                a.incidence_deg
            ));
            header.extra = vec![(
                "band names".to_owned(),
                "{L measured, a measured, b measured, L reproduced, a reproduced, b reproduced, CIEDE2000}"
                    .to_owned(),
            )];
            let err = AppearanceError::Cube;
            let mut writer = EnviWriter::create(&path, &header).map_err(err)?;
            let lab = |v: &Xyz| {
                let l = v.to_lab(white);
                [l.l as f32, l.a as f32, l.b as f32]
            };
            for band in 0..7 {
                for line in 0..h {
                    let row: Vec<f32> = (line * w..(line + 1) * w)
                        .map(|i| match band {
                            0..=2 => lab(&a.measured[i])[band],
                            3..=5 => lab(&a.reproduced[i])[band - 3],
                            _ => a.delta_e2000[i],
                        })
                        .collect();
                    writer.write_band_row(band, line, &row).map_err(err)?;
                }
            }
            writer.finish().map_err(err)?;
            written.push(path);
        }
        Ok(written)
    }

    /// The figures as `compare.json` records them.
    pub fn record(&self) -> CompareRecord {
        let (lo, hi) = self.colorimetry.range_nm();
        CompareRecord {
            metric: "CIEDE2000".into(),
            illuminant: self.colorimetry.illuminant().name().into(),
            observer: "CIE 1931 2 degree".into(),
            band_limited_nm: [lo, hi],
            approach: APPROACH.into(),
            width: self.width,
            height: self.height,
            overall: self.overall,
            per_angle: self
                .angles
                .iter()
                .map(|a| AngleRecord {
                    incidence_deg: a.incidence_deg,
                    stats: a.stats,
                })
                .collect(),
        }
    }

    /// The figure: per angle (rows), measured | reproduced | CIEDE2000 map, with one
    /// exposure for every image and one colour scale for every map.
    pub fn to_png(&self) -> Result<Vec<u8>, AppearanceError> {
        const MARGIN: usize = 12;
        const GAP: usize = 12;
        const TEXT: usize = 2;
        const LINE: usize = CAP_ROWS * TEXT + 8;
        const LABEL_W: usize = 60;
        const BAR_W: usize = 20;
        let white = self.colorimetry.white();
        let all: Vec<Xyz> = self
            .angles
            .iter()
            .flat_map(|a| a.measured.iter().chain(&a.reproduced).copied())
            .collect();
        let exposure = auto_exposure(&all);
        let (sw, sh, idx) = sample_grid(self.width, self.height, 512);
        let scale = upscale(sw, 192);
        let (pw, ph) = (sw * scale, sh * scale);
        let de_max = self
            .angles
            .iter()
            .map(|a| a.stats.p95)
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max)
            .max(0.5)
            * 1.5;
        let stats_w = text_width("mean 00.00, p95 00.00", TEXT);
        let width = MARGIN * 2 + LABEL_W + 3 * (pw + GAP) + stats_w + GAP + BAR_W + 80;
        let (lo, hi) = self.colorimetry.range_nm();
        let title = format!(
            "measured vs reproduced, {lo:.0}-{hi:.0} nm, {}, exposure x{exposure:.1}; all angles: mean {:.2}, p95 {:.2} dE00",
            self.colorimetry.illuminant().name(),
            self.overall.mean,
            self.overall.p95
        );
        let width = width.max(2 * MARGIN + text_width(&title, TEXT));
        let height = MARGIN + 2 * LINE + self.angles.len() * (ph + GAP) + LINE + MARGIN;
        if width.saturating_mul(height) > crate::export::png::MAX_PIXELS {
            return Err(AppearanceError::Mismatch(format!(
                "a {width}x{height} comparison is too large"
            )));
        }
        let mut c = Canvas::new(width, height, BACKGROUND);
        c.text(MARGIN, MARGIN, &title, TEXT, INK);
        let x0 = MARGIN + LABEL_W;
        let mut y = MARGIN + LINE;
        for (k, head) in ["measured", "reproduced", "dE00"].iter().enumerate() {
            c.text(x0 + k * (pw + GAP), y, head, TEXT, INK);
        }
        y += LINE;
        let top = y;
        for a in &self.angles {
            c.text(
                MARGIN,
                y + ph / 2,
                &format!("{:.0}°", a.incidence_deg),
                TEXT,
                INK,
            );
            let pick = |v: &[Xyz]| -> Vec<[u8; 3]> {
                idx.iter()
                    .map(|&i| display_rgb(v[i], white, exposure))
                    .collect()
            };
            blit(&mut c, x0, y, sw, &pick(&a.measured), scale);
            blit(&mut c, x0 + pw + GAP, y, sw, &pick(&a.reproduced), scale);
            let heat: Vec<[u8; 3]> = idx
                .iter()
                .map(|&i| {
                    let v = f64::from(a.delta_e2000[i]);
                    if v.is_finite() {
                        viridis((v / de_max).clamp(0.0, 1.0))
                    } else {
                        NO_DATA
                    }
                })
                .collect();
            blit(&mut c, x0 + 2 * (pw + GAP), y, sw, &heat, scale);
            let s = format!("mean {:.2}, p95 {:.2}", a.stats.mean, a.stats.p95);
            c.text(x0 + 3 * (pw + GAP), y + ph / 2, &s, TEXT, INK);
            y += ph + GAP;
        }
        let bar_x = x0 + 3 * (pw + GAP) + stats_w + GAP;
        let bar_h = y.saturating_sub(top + GAP).max(40);
        c.colour_bar(bar_x, top, BAR_W, bar_h, true);
        c.text(bar_x + BAR_W + 6, top, &format!("{de_max:.1}"), TEXT, INK);
        c.text(
            bar_x + BAR_W + 6,
            top + bar_h / 2 - CAP_ROWS,
            &format!("{:.1}", de_max / 2.0),
            TEXT,
            INK,
        );
        c.text(
            bar_x + BAR_W + 6,
            top + bar_h - CAP_ROWS * TEXT,
            "0",
            TEXT,
            INK,
        );
        swatch_note(
            &mut c,
            MARGIN,
            y,
            NO_DATA,
            "grey = not compared (no reliable thickness, or a saturated/dead band)",
        );
        c.encode().map_err(AppearanceError::from)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_use_nearest_rank_percentiles_and_skip_nan() {
        let v: Vec<f32> = (1..=100).map(|i| i as f32).chain([f32::NAN]).collect();
        let s = DeltaStats::of(v.into_iter());
        assert_eq!(s.pixels, 100);
        assert_eq!((s.median, s.p95), (50.0, 95.0));
        assert!((s.mean - 50.5).abs() < 1e-12);
        let empty = DeltaStats::of([f32::NAN].into_iter());
        assert_eq!(empty.pixels, 0);
        assert!(empty.mean.is_nan() && empty.p95.is_nan());
    }
}
