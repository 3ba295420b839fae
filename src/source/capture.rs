//! A capture on disk as a source, replayed row by row.

use std::path::PathBuf;

use crossbeam_channel::Sender;
use filmscope_core::solve::SweepSpec;

use super::{
    row_runs, sweep_spec, RowBlock, RowOrder, Samples, Source, SourceError, StreamMsg,
    DEFAULT_INDEX_RANGE,
};
use crate::io::{Capture, EnviReader};
use filmscope_core::calibrate::{calibrate_row, clipped};

/// One row's decoded counts and references ([`CaptureSource`] calibrates as it reads).
struct RowScratch {
    counts: Vec<f32>,
    white: Vec<f32>,
    dark: Vec<f32>,
}

impl RowScratch {
    fn new(width: usize) -> Self {
        Self {
            counts: vec![0.0; width],
            white: vec![0.0; width],
            dark: vec![0.0; width],
        }
    }
}

/// Bytes of a capture's run of lines (`bil`, `bip`, calibrated) read before its rows are
/// handed on: each message then carries several rows of a band (fewer messages, and the
/// workers feed blocks of rows as from a band-sequential source).
const LINE_RUN_BYTES: usize = 16 << 20;

/// Most lines in such a run.
const MAX_RUN_LINES: usize = 16;

/// Rows of a band of a `bsq` capture in one message.
const BSQ_RUN_ROWS: usize = 16;

/// Samples of one angle whose reference (white or dark) was at the ADC's full scale and
/// their count was not (a hot pixel, saturated in both, is the sample's own flag), and the
/// first and last band they were in.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Clipped {
    samples: u64,
    bands: [usize; 2],
}

impl Clipped {
    /// Counts the samples of band `band` whose `reference` is at or above `saturation` and
    /// whose `counts` are below it.
    fn count(&mut self, counts: &[f32], reference: &[f32], band: usize, saturation: f32) {
        let n = counts
            .iter()
            .zip(reference)
            .filter(|&(&c, &r)| clipped(r, saturation) && c < saturation)
            .count() as u64;
        if n > 0 {
            self.bands = if self.samples == 0 {
                [band, band]
            } else {
                [self.bands[0].min(band), self.bands[1].max(band)]
            };
            self.samples += n;
        }
    }
}

/// An ENVI capture replayed in each cube's own interleave.
pub struct CaptureSource {
    capture: Capture,
    spec: SweepSpec,
    saturation_counts: f32,
    /// The first cube's: `bil` and `bip` are read a run of lines at a time.
    row_order: RowOrder,
    /// Per angle (streamed order), its white's and dark's clipped samples, of the pass that
    /// read the most rows.
    clipped: Vec<[Clipped; 2]>,
}

impl CaptureSource {
    /// Opens a loaded capture (its cubes were checked by [`Capture::load`]). Its angles are
    /// streamed by increasing incidence, whatever their order in capture.toml: the streaming
    /// solver's result depends on the order angles arrive in, and a capture's maps must not
    /// depend on how its file lists them.
    pub fn new(mut capture: Capture) -> Result<Self, SourceError> {
        let info = capture.check()?;
        capture
            .angles
            .sort_by(|a, b| a.incidence_deg.total_cmp(&b.incidence_deg));
        let bands = info
            .wavelength_nm
            .clone()
            .ok_or_else(|| SourceError::NoWavelengths(capture.angles[0].cube.clone()))?;
        let range_i = capture.search.index_range.unwrap_or(DEFAULT_INDEX_RANGE);
        let range_d = capture.search.thickness_range_nm;
        let mut spec = sweep_spec(
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
        .map_err(|e| e.of(capture.path.display()))?
        .with_substrate(capture.sample.substrate_dispersion())
        .with_back_face(capture.sample.back_face);
        if let Some(m) = capture.fit.model_error {
            spec.model_error = m;
        }
        if let Some(t) = capture.fit.rig_tolerance {
            spec.rig_tolerance = t;
        }
        // Raw counts saturate at the ADC's full scale: the header's `saturation counts` (a
        // filmscope extension of ENVI) when given, else the u16 maximum.
        let first = EnviReader::open(&capture.angles[0].cube)?;
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
        let row_order = match first.header().interleave {
            crate::io::Interleave::Bsq => RowOrder::BandMajor,
            _ => RowOrder::LineMajor,
        };
        let clipped = vec![[Clipped::default(); 2]; capture.angles.len()];
        Ok(Self {
            capture,
            spec,
            saturation_counts,
            row_order,
            clipped,
        })
    }

    /// Streams angle `a`'s rows (those in `only`, sorted, or every one) as blocks of
    /// consecutive rows of one band: `bil` and `bip` a run of lines at a time (each line
    /// read whole, once, its bands handed on band by band), `bsq` band by band in the
    /// file's order (a run of rows of a band at a time, then the band's end). Raw counts
    /// are calibrated row by row as they are decoded, so the blocks carry reflectance: a
    /// run's counts and references are never held as arrays of their own (their memory
    /// traffic cost the read more than the decoding). The samples whose white or dark is
    /// clipped (and whose count is not) are counted into `clipped`.
    fn stream_angle(
        &self,
        a: usize,
        tx: &Sender<StreamMsg>,
        only: Option<&[usize]>,
        clipped: &mut [Clipped; 2],
    ) -> Result<bool, String> {
        let angle = &self.capture.angles[a];
        let (w, h) = (self.spec.width, self.spec.height);
        let bands = self.spec.bands_nm.len();
        let open = |p: &PathBuf| EnviReader::open(p).map_err(|e| e.to_string());
        let mut cube = open(&angle.cube)?;
        let mut white = angle.white.as_ref().map(open).transpose()?;
        let mut dark = angle.dark.as_ref().map(open).transpose()?;
        if cube.header().bands != bands || cube.header().samples != w {
            return Err(format!(
                "{}: not {w} samples x {bands} bands",
                angle.cube.display()
            ));
        }
        // A reference of one line serves every line.
        let ref_line = |r: &EnviReader, line: usize| if r.header().lines == 1 { 0 } else { line };
        let err = |e: crate::io::EnviError| e.to_string();
        // Sends rows `r0..r0 + n` of band `b`, calibrated; false once the pipeline stopped
        // listening.
        let send = |b: usize, r0: usize, n: usize, reflectance: Vec<f32>| {
            let msg = StreamMsg::Rows(RowBlock {
                band: b as u16,
                first_row: r0 as u32,
                rows: n as u32,
                samples: Samples::Reflectance(reflectance),
            });
            tx.send(msg).is_ok()
        };
        // One row's counts and references, decoded: a few kB that stay in cache between
        // the decoding and the calibration, rather than three arrays of a whole run.
        let mut row = RowScratch::new(w);
        let white_reflectance = angle.white_reflectance as f32;
        let saturation_counts = self.saturation_counts;
        // Band `b` of line `line`, calibrated into `out` (a reflectance cube's values as
        // they are); the readers' lines already loaded for `bil` and `bip`.
        let mut read_row = |cube: &mut EnviReader,
                            white: Option<&mut EnviReader>,
                            dark: Option<&mut EnviReader>,
                            b: usize,
                            line: usize,
                            out: &mut [f32]|
         -> Result<(), String> {
            let Some(white) = white else {
                return cube.read_band_row(b, line, out).map_err(err);
            };
            cube.read_band_row(b, line, &mut row.counts).map_err(err)?;
            let l = ref_line(white, line);
            white.read_band_row(b, l, &mut row.white).map_err(err)?;
            clipped[0].count(&row.counts, &row.white, b, saturation_counts);
            let dark = match dark {
                Some(d) => {
                    let l = ref_line(d, line);
                    d.read_band_row(b, l, &mut row.dark).map_err(err)?;
                    clipped[1].count(&row.counts, &row.dark, b, saturation_counts);
                    Some(&row.dark[..])
                }
                None => None,
            };
            calibrate_row(
                &row.counts,
                dark,
                &row.white,
                white_reflectance,
                saturation_counts,
                out,
            );
            Ok(())
        };
        if cube.header().interleave == crate::io::Interleave::Bsq {
            let runs = row_runs(h, only, BSQ_RUN_ROWS);
            for b in 0..bands {
                for &(r0, n) in &runs {
                    let mut out = vec![0f32; n * w];
                    for (k, o) in out.chunks_exact_mut(w).enumerate() {
                        read_row(&mut cube, white.as_mut(), dark.as_mut(), b, r0 + k, o)?;
                    }
                    if !send(b, r0, n, out) {
                        return Ok(false);
                    }
                }
                if tx.send(StreamMsg::BandEnd { band: b as u16 }).is_err() {
                    return Ok(false);
                }
            }
            return Ok(true);
        }
        // A run of lines' calibrated samples, about `LINE_RUN_BYTES`.
        let run_lines = (LINE_RUN_BYTES / (bands * w * 4).max(1)).clamp(1, MAX_RUN_LINES);
        for (r0, n) in row_runs(h, only, run_lines) {
            let mut out: Vec<Vec<f32>> = (0..bands).map(|_| vec![0f32; n * w]).collect();
            for k in 0..n {
                let line = r0 + k;
                cube.load_line(line).map_err(err)?;
                for r in [white.as_mut(), dark.as_mut()].into_iter().flatten() {
                    let l = ref_line(r, line);
                    r.load_line(l).map_err(err)?;
                }
                for (b, o) in out.iter_mut().enumerate() {
                    let o = &mut o[k * w..(k + 1) * w];
                    read_row(&mut cube, white.as_mut(), dark.as_mut(), b, line, o)?;
                }
            }
            for (b, o) in out.into_iter().enumerate() {
                if !send(b, r0, n, o) {
                    return Ok(false);
                }
            }
        }
        Ok(true)
    }

    /// Streams every angle, each with only the rows in `only` (sorted), or every row.
    fn stream_only(&mut self, tx: &Sender<StreamMsg>, only: Option<&[usize]>) {
        for a in 0..self.capture.angles.len() {
            let deg = self.capture.angles[a].incidence_deg;
            if tx.send(StreamMsg::Angle { incidence_deg: deg }).is_err() {
                return;
            }
            let mut clipped = [Clipped::default(); 2];
            let streamed = self.stream_angle(a, tx, only, &mut clipped);
            if let Some(kept) = self.clipped.get_mut(a) {
                for (k, c) in kept.iter_mut().zip(clipped) {
                    if c.samples > k.samples {
                        *k = c;
                    }
                }
            }
            match streamed {
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

    /// The capture file.
    pub fn path(&self) -> PathBuf {
        self.capture.path.clone()
    }

    /// One line for each reference found clipped as the capture was streamed (at the ADC's
    /// full scale, its true level unknown, where the sample's count was not): its file, how
    /// many samples, in which bands. Those samples had no usable reference (they count among
    /// the pixels' dead samples).
    fn clipped_references(&self) -> Vec<String> {
        let mut lines = Vec::new();
        for (angle, clipped) in self.capture.angles.iter().zip(&self.clipped) {
            let refs = [("white", &angle.white), ("dark", &angle.dark)];
            for ((what, file), c) in refs.into_iter().zip(clipped) {
                let (Some(file), true) = (file, c.samples > 0) else {
                    continue;
                };
                let nm = |b: usize| self.spec.bands_nm.get(b).copied().unwrap_or(f64::NAN);
                lines.push(format!(
                    "{}: the {what} reference is at full scale ({} counts) in {} samples, bands \
                     {:.1}-{:.1} nm: clipped (over-exposed), so those samples have no usable \
                     reference",
                    file.display(),
                    self.saturation_counts,
                    c.samples,
                    nm(c.bands[0]),
                    nm(c.bands[1]),
                ));
            }
        }
        lines
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
        self.stream_only(tx, None);
    }

    fn stream_rows(&mut self, tx: &Sender<StreamMsg>, rows: &[usize]) {
        self.stream_only(tx, Some(rows));
    }

    fn row_order(&self) -> RowOrder {
        self.row_order
    }

    fn notes(&self) -> Vec<String> {
        self.clipped_references()
    }
}
