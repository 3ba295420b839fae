//! A capture on disk as a source, replayed row by row.

use std::path::PathBuf;

use crossbeam_channel::Sender;
use filmscope_core::solve::SweepSpec;

use super::{
    row_runs, sweep_spec, RowBlock, RowOrder, Samples, Source, StreamMsg, DEFAULT_INDEX_RANGE,
    DEFAULT_THICKNESS_RANGE_NM,
};
use crate::io::{Capture, EnviReader};

/// Bytes of a capture's run of lines (`bil`, `bip`) read before its rows are handed on:
/// each message then carries several rows of a band (fewer messages, and the workers feed
/// blocks of rows as from a band-sequential source).
const LINE_RUN_BYTES: usize = 16 << 20;

/// Most lines in such a run.
const MAX_RUN_LINES: usize = 16;

/// Rows of a band of a `bsq` capture in one message.
const BSQ_RUN_ROWS: usize = 16;

/// An ENVI capture replayed in each cube's own interleave.
pub struct CaptureSource {
    capture: Capture,
    spec: SweepSpec,
    saturation_counts: f32,
    /// The first cube's: `bil` and `bip` are read a run of lines at a time.
    row_order: RowOrder,
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
        let row_order = match first.header().interleave {
            crate::io::Interleave::Bsq => RowOrder::BandMajor,
            _ => RowOrder::LineMajor,
        };
        Ok(Self {
            capture,
            spec,
            saturation_counts,
            row_order,
        })
    }

    /// Streams angle `a`'s rows (those in `only`, sorted, or every one) as blocks of
    /// consecutive rows of one band: `bil` and `bip` a run of lines at a time (each line
    /// read whole, once, its bands handed on band by band), `bsq` band by band in the
    /// file's order (a run of rows of a band at a time, then the band's end).
    fn stream_angle(
        &self,
        a: usize,
        tx: &Sender<StreamMsg>,
        only: Option<&[usize]>,
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
        let block = |counts: Vec<f32>, white: Option<Vec<f32>>, dark: Option<Vec<f32>>| match white
        {
            None => Samples::Reflectance(counts),
            Some(white) => Samples::Raw {
                counts,
                dark,
                white,
                white_reflectance: angle.white_reflectance as f32,
                saturation_counts: self.saturation_counts,
            },
        };
        let err = |e: crate::io::EnviError| e.to_string();
        // Sends rows `r0..r0 + n` of band `b`; false once the pipeline stopped listening.
        let send = |b: usize, r0: usize, n: usize, samples: Samples| {
            let msg = StreamMsg::Rows(RowBlock {
                band: b as u16,
                first_row: r0 as u32,
                rows: n as u32,
                samples,
            });
            tx.send(msg).is_ok()
        };
        if cube.header().interleave == crate::io::Interleave::Bsq {
            let runs = row_runs(h, only, BSQ_RUN_ROWS);
            for b in 0..bands {
                for &(r0, n) in &runs {
                    let mut counts = vec![0f32; n * w];
                    let mut wv = white.as_ref().map(|_| vec![0f32; n * w]);
                    let mut dv = dark.as_ref().map(|_| vec![0f32; n * w]);
                    for k in 0..n {
                        let s = k * w..(k + 1) * w;
                        cube.read_band_row(b, r0 + k, &mut counts[s.clone()])
                            .map_err(err)?;
                        for (r, v) in [(white.as_mut(), wv.as_mut()), (dark.as_mut(), dv.as_mut())]
                        {
                            if let (Some(r), Some(v)) = (r, v) {
                                let line = ref_line(r, r0 + k);
                                r.read_band_row(b, line, &mut v[s.clone()]).map_err(err)?;
                            }
                        }
                    }
                    if !send(b, r0, n, block(counts, wv, dv)) {
                        return Ok(false);
                    }
                }
                if tx.send(StreamMsg::BandEnd { band: b as u16 }).is_err() {
                    return Ok(false);
                }
            }
            return Ok(true);
        }
        // A run of lines' samples, references included, about `LINE_RUN_BYTES`.
        let arrays = 1 + usize::from(white.is_some()) + usize::from(dark.is_some());
        let per_line = (arrays * bands * w * 4).max(1);
        let run_lines = (LINE_RUN_BYTES / per_line).clamp(1, MAX_RUN_LINES);
        for (r0, n) in row_runs(h, only, run_lines) {
            let mut counts: Vec<Vec<f32>> = (0..bands).map(|_| vec![0f32; n * w]).collect();
            let mut wv: Option<Vec<Vec<f32>>> = white
                .as_ref()
                .map(|_| (0..bands).map(|_| vec![0f32; n * w]).collect());
            let mut dv: Option<Vec<Vec<f32>>> = dark
                .as_ref()
                .map(|_| (0..bands).map(|_| vec![0f32; n * w]).collect());
            for k in 0..n {
                let line = r0 + k;
                let s = k * w..(k + 1) * w;
                cube.load_line(line).map_err(err)?;
                for (b, c) in counts.iter_mut().enumerate() {
                    cube.read_band_row(b, line, &mut c[s.clone()])
                        .map_err(err)?;
                }
                for (r, v) in [(white.as_mut(), wv.as_mut()), (dark.as_mut(), dv.as_mut())] {
                    if let (Some(r), Some(v)) = (r, v) {
                        let line = ref_line(r, line);
                        r.load_line(line).map_err(err)?;
                        for (b, v) in v.iter_mut().enumerate() {
                            r.read_band_row(b, line, &mut v[s.clone()]).map_err(err)?;
                        }
                    }
                }
            }
            let mut wv = wv.map(Vec::into_iter);
            let mut dv = dv.map(Vec::into_iter);
            for (b, c) in counts.into_iter().enumerate() {
                let wb = wv.as_mut().and_then(Iterator::next);
                let db = dv.as_mut().and_then(Iterator::next);
                if !send(b, r0, n, block(c, wb, db)) {
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
            match self.stream_angle(a, tx, only) {
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
}
