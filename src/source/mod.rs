//! Where band frames come from: the software camera and ENVI captures replayed row by row,
//! the messages they stream ([`msg`]) and a sweep held whole ([`SweepCube`]).

mod cube;
mod msg;
mod replay;

pub use cube::SweepCube;
pub use msg::{calibrate_block, RowBlock, Samples, StreamMsg};
pub use replay::{Frames, ReplaySource};

use std::path::PathBuf;

use crossbeam_channel::Sender;
use filmscope_core::solve::SweepSpec;
use firmware_sim::SoftwareCamera;

use crate::io::{Capture, EnviReader};

/// A producer of one sweep's stream. `stream` runs on its own thread and must end the stream
/// with `SweepEnd` or `Abort`; a send error means the pipeline stopped listening.
pub trait Source: Send {
    /// The sweep's geometry and optics, known before the first row.
    fn spec(&self) -> &SweepSpec;
    /// Incidence angles in streaming order, degrees (for progress and reports).
    fn angles_deg(&self) -> Vec<f64>;
    /// Streams the sweep into `tx`.
    fn stream(&mut self, tx: &Sender<StreamMsg>);
    /// Whether [`Source::stream`] may be called again for the same data (a capture on disk,
    /// the software camera; not a live camera).
    fn replayable(&self) -> bool {
        true
    }
}

/// Builds a [`SweepSpec`] from band lists and the sample's optics.
#[allow(clippy::too_many_arguments)]
pub fn sweep_spec(
    width: usize,
    height: usize,
    bands_nm: &[f64],
    fwhm_nm: Option<&[f64]>,
    ambient_index: f64,
    substrate_index: f64,
    polarization: filmscope_core::optics::Polarization,
    index_range: [f64; 2],
    thickness_range_nm: [f64; 2],
) -> Result<SweepSpec, String> {
    // Every source passes here: bounded ranges keep the search finite in time and memory.
    crate::limits::check_index_range("search.index_range", index_range)?;
    crate::limits::check_thickness_range("search.thickness_range_nm", thickness_range_nm)?;
    crate::limits::check_bands("wavelength", bands_nm, "fwhm", fwhm_nm)?;
    if bands_nm.len() < 16 {
        return Err(format!(
            "{} bands: at least 16 are needed to find fringes",
            bands_nm.len()
        ));
    }
    let bands: heapless::Vec<f64, { filmscope_core::solve::sweep::MAX_BANDS }> =
        heapless::Vec::from_slice(bands_nm).map_err(|()| {
            format!(
                "{} bands: at most {} are supported",
                bands_nm.len(),
                filmscope_core::solve::sweep::MAX_BANDS
            )
        })?;
    let mut fwhm = heapless::Vec::new();
    for i in 0..bands.len() {
        let w = match fwhm_nm {
            Some(f) => f[i],
            // No fwhm: a passband as narrow as the band spacing (capture-format.md).
            None => {
                let j = if i + 1 < bands.len() { i + 1 } else { i - 1 };
                (bands[j] - bands[i]).abs()
            }
        };
        let _ = fwhm.push(w);
    }
    Ok(SweepSpec {
        width,
        height,
        bands_nm: bands,
        fwhm_nm: fwhm,
        ambient_index,
        substrate_index,
        substrate: filmscope_core::optics::Dispersion::constant(substrate_index),
        polarization,
        index_range,
        thickness_range_nm,
        options: Default::default(),
    })
}

/// Default search ranges when a capture gives none.
pub const DEFAULT_INDEX_RANGE: [f64; 2] = [1.2, 3.0];
/// Default thickness search range, nm.
pub const DEFAULT_THICKNESS_RANGE_NM: [f64; 2] = [50.0, 2000.0];

/// The software camera as a source: raw counts with references, or noise-free reflectance.
pub struct SimSource {
    camera: SoftwareCamera,
    spec: SweepSpec,
    noise_free: bool,
    rows_per_block: usize,
}

impl SimSource {
    /// A source over `camera`; `rows_per_block` rows per message.
    pub fn new(
        camera: SoftwareCamera,
        noise_free: bool,
        rows_per_block: usize,
    ) -> Result<Self, String> {
        let scene = camera.scene();
        let spec = sweep_spec(
            camera.width(),
            camera.height(),
            &scene.bands_nm,
            Some(&vec![scene.fwhm_nm; scene.bands_nm.len()]),
            scene.stack.ambient_index,
            scene.stack.substrate.index_at(550.0),
            scene.stack.polarization,
            scene.index_range.unwrap_or(DEFAULT_INDEX_RANGE),
            scene
                .thickness_range_nm
                .unwrap_or(DEFAULT_THICKNESS_RANGE_NM),
        )?
        .with_substrate(scene.stack.substrate);
        Ok(Self {
            camera,
            spec,
            noise_free,
            rows_per_block: rows_per_block.max(1),
        })
    }
}

impl SimSource {
    /// Rows `first_row..first_row + rows` of band `band` at angle `angle` as the camera
    /// delivers them: raw counts with their white and dark references, or noise-free
    /// reflectance.
    pub fn block(&self, angle: usize, band: usize, first_row: usize, rows: usize) -> Samples {
        let cam = &self.camera;
        let w = cam.width();
        if self.noise_free {
            let mut v = vec![0f32; rows * w];
            for (k, chunk) in v.chunks_mut(w).enumerate() {
                cam.reflectance_row(angle, band, first_row + k, chunk);
            }
            return Samples::Reflectance(v);
        }
        let mut raw16 = vec![0u16; w];
        let mut counts = vec![0f32; rows * w];
        let mut white = vec![0f32; rows * w];
        let mut dark = vec![0f32; rows * w];
        for k in 0..rows {
            let row = first_row + k;
            cam.raw_row(angle, band, row, &mut raw16);
            for (o, &c) in counts[k * w..(k + 1) * w].iter_mut().zip(&raw16) {
                *o = f32::from(c);
            }
            cam.white_row(angle, band, row, &mut white[k * w..(k + 1) * w]);
            cam.dark_row(angle, band, row, &mut dark[k * w..(k + 1) * w]);
        }
        Samples::Raw {
            counts,
            dark: Some(dark),
            white,
            white_reflectance: 1.0,
            saturation_counts: cam.scene().sensor.saturation_counts() as f32,
        }
    }
}

impl Source for SimSource {
    fn spec(&self) -> &SweepSpec {
        &self.spec
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.camera.scene().angles_deg.clone()
    }

    fn stream(&mut self, tx: &Sender<StreamMsg>) {
        let scene = self.camera.scene();
        stream_band_sequential(
            tx,
            &scene.angles_deg,
            scene.bands_nm.len(),
            self.camera.height(),
            self.rows_per_block,
            |a, b, r0, rows| self.block(a, b, r0, rows),
        );
    }
}

/// Streams a band-sequential sweep into `tx`: per angle, every band's `height` rows in blocks
/// of `rows_per_block`, the samples of a block made by `block(angle, band, first_row, rows)`,
/// then the band's and the angle's end, and the sweep's end. Stops quietly when the receiver
/// is gone.
pub fn stream_band_sequential(
    tx: &Sender<StreamMsg>,
    angles_deg: &[f64],
    bands: usize,
    height: usize,
    rows_per_block: usize,
    mut block: impl FnMut(usize, usize, usize, usize) -> Samples,
) {
    let per_block = rows_per_block.max(1);
    for (a, &deg) in angles_deg.iter().enumerate() {
        if tx.send(StreamMsg::Angle { incidence_deg: deg }).is_err() {
            return;
        }
        for b in 0..bands {
            let mut r0 = 0;
            while r0 < height {
                let rows = per_block.min(height - r0);
                let msg = StreamMsg::Rows(RowBlock {
                    band: b as u16,
                    first_row: r0 as u32,
                    rows: rows as u32,
                    samples: block(a, b, r0, rows),
                });
                if tx.send(msg).is_err() {
                    return;
                }
                r0 += rows;
            }
            if tx.send(StreamMsg::BandEnd { band: b as u16 }).is_err() {
                return;
            }
        }
        if tx.send(StreamMsg::AngleEnd).is_err() {
            return;
        }
    }
    let _ = tx.send(StreamMsg::SweepEnd);
}

/// An ENVI capture replayed row by row in each cube's own interleave.
pub struct CaptureSource {
    capture: Capture,
    spec: SweepSpec,
    saturation_counts: f32,
}

impl CaptureSource {
    /// Opens a loaded capture (its cubes were checked by [`Capture::load`]). Its angles are
    /// streamed by increasing incidence, whatever their order in capture.toml: the streaming
    /// solver's result depends on the order angles arrive in, and a capture's maps must not
    /// depend on how its file lists them.
    pub fn new(mut capture: Capture) -> Result<Self, String> {
        let info = capture.check().map_err(|e| e.to_string())?;
        capture
            .angles
            .sort_by(|a, b| a.incidence_deg.total_cmp(&b.incidence_deg));
        let bands = info.wavelength_nm.clone().ok_or_else(|| {
            format!(
                "{}: the cubes have no `wavelength` list; filmscope needs each band's wavelength",
                capture.angles[0].cube.display()
            )
        })?;
        let range_i = capture.search.index_range.unwrap_or(DEFAULT_INDEX_RANGE);
        let range_d = capture
            .search
            .thickness_range_nm
            .unwrap_or(DEFAULT_THICKNESS_RANGE_NM);
        let spec = sweep_spec(
            info.samples,
            info.lines,
            &bands,
            info.fwhm_nm.as_deref(),
            capture.sample.ambient_index,
            capture.sample.substrate_index,
            capture.sample.polarization,
            range_i,
            range_d,
        )
        .map_err(|e| format!("{}: {e}", capture.path.display()))?
        .with_substrate(capture.sample.substrate_dispersion());
        // Raw counts saturate at the ADC's full scale: the header's `saturation counts` (a
        // filmscope extension of ENVI) when given, else the u16 maximum.
        let first = EnviReader::open(&capture.angles[0].cube).map_err(|e| e.to_string())?;
        let declared = first
            .header()
            .extra
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case("saturation counts"))
            .and_then(|(_, v)| v.trim().parse::<f32>().ok());
        let saturation_counts = match (info.data_type, declared) {
            (_, Some(s)) => s,
            (crate::io::DataType::U16, None) => 65535.0,
            _ => f32::INFINITY,
        };
        Ok(Self {
            capture,
            spec,
            saturation_counts,
        })
    }

    fn stream_angle(&self, a: usize, tx: &Sender<StreamMsg>) -> Result<bool, String> {
        let angle = &self.capture.angles[a];
        let w = self.spec.width;
        let mut cube = EnviReader::open(&angle.cube).map_err(|e| e.to_string())?;
        let mut white = match &angle.white {
            Some(p) => Some(EnviReader::open(p).map_err(|e| e.to_string())?),
            None => None,
        };
        let mut dark = match &angle.dark {
            Some(p) => Some(EnviReader::open(p).map_err(|e| e.to_string())?),
            None => None,
        };
        let mut buf = vec![0f32; w];
        let band_sequential = cube.header().interleave == crate::io::Interleave::Bsq;
        let mut last_band = None;
        while let Some(at) = cube.next_band_row(&mut buf).map_err(|e| e.to_string())? {
            if band_sequential && last_band.is_some_and(|b| b != at.band) {
                if let Some(b) = last_band {
                    if tx.send(StreamMsg::BandEnd { band: b as u16 }).is_err() {
                        return Ok(false);
                    }
                }
            }
            last_band = Some(at.band);
            let samples = match white.as_mut() {
                None => Samples::Reflectance(buf.clone()),
                Some(wr) => {
                    let mut wv = vec![0f32; w];
                    let line = if wr.header().lines == 1 { 0 } else { at.line };
                    wr.read_band_row(at.band, line, &mut wv)
                        .map_err(|e| e.to_string())?;
                    let dv = match dark.as_mut() {
                        Some(dr) => {
                            let mut dv = vec![0f32; w];
                            let line = if dr.header().lines == 1 { 0 } else { at.line };
                            dr.read_band_row(at.band, line, &mut dv)
                                .map_err(|e| e.to_string())?;
                            Some(dv)
                        }
                        None => None,
                    };
                    Samples::Raw {
                        counts: buf.clone(),
                        dark: dv,
                        white: wv,
                        white_reflectance: angle.white_reflectance as f32,
                        saturation_counts: self.saturation_counts,
                    }
                }
            };
            let block = RowBlock {
                band: at.band as u16,
                first_row: at.line as u32,
                rows: 1,
                samples,
            };
            if tx.send(StreamMsg::Rows(block)).is_err() {
                return Ok(false);
            }
        }
        if let (true, Some(b)) = (band_sequential, last_band) {
            if tx.send(StreamMsg::BandEnd { band: b as u16 }).is_err() {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// The capture file.
    pub fn path(&self) -> PathBuf {
        self.capture.path.clone()
    }
}

impl Source for CaptureSource {
    fn spec(&self) -> &SweepSpec {
        &self.spec
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.capture
            .angles
            .iter()
            .map(|a| a.incidence_deg)
            .collect()
    }

    fn stream(&mut self, tx: &Sender<StreamMsg>) {
        for a in 0..self.capture.angles.len() {
            let deg = self.capture.angles[a].incidence_deg;
            if tx.send(StreamMsg::Angle { incidence_deg: deg }).is_err() {
                return;
            }
            match self.stream_angle(a, tx) {
                Ok(true) => {}
                Ok(false) => return,
                Err(e) => {
                    let _ = tx.send(StreamMsg::Abort(e));
                    return;
                }
            }
            if tx.send(StreamMsg::AngleEnd).is_err() {
                return;
            }
        }
        let _ = tx.send(StreamMsg::SweepEnd);
    }
}
