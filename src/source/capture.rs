//! A capture on disk as a source, replayed row by row.

use std::path::PathBuf;

use crossbeam_channel::Sender;
use filmscope_core::solve::SweepSpec;

use super::{
    sweep_spec, RowBlock, Samples, Source, StreamMsg, DEFAULT_INDEX_RANGE,
    DEFAULT_THICKNESS_RANGE_NM,
};
use crate::io::{Capture, EnviReader};

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
