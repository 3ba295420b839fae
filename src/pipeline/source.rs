//! Sources of sweep streams: the software camera and ENVI captures replayed row by row.

use std::path::PathBuf;

use crossbeam_channel::Sender;
use filmscope_core::solve::SweepSpec;
use firmware_sim::SoftwareCamera;

use super::msg::{RowBlock, Samples, StreamMsg};
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
    /// Streams the sweep into `tx` as [`Source::stream`] does, but only the image rows in
    /// `rows` (sorted) need be sent: for a consumer that reads a few pixels' spectra. A
    /// source that cannot skip rows streams them all (the consumer ignores the rest).
    fn stream_rows(&mut self, tx: &Sender<StreamMsg>, rows: &[usize]) {
        let _ = rows;
        self.stream(tx);
    }
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

    fn stream_rows(&mut self, tx: &Sender<StreamMsg>, rows: &[usize]) {
        let scene = self.camera.scene();
        let runs = row_runs(self.camera.height(), Some(rows), self.rows_per_block);
        stream_runs(
            tx,
            &scene.angles_deg,
            scene.bands_nm.len(),
            &runs,
            |a, b, r0, rows| self.block(a, b, r0, rows),
        );
    }
}

/// Runs of consecutive image rows `(first, rows)` of a `height`-row frame, each at most
/// `per_run` long: every row, or only those in `only` (sorted).
pub fn row_runs(height: usize, only: Option<&[usize]>, per_run: usize) -> Vec<(usize, usize)> {
    let per_run = per_run.max(1);
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut push = |r: usize| match runs.last_mut() {
        Some((first, n)) if *first + *n == r && *n < per_run => *n += 1,
        _ => runs.push((r, 1)),
    };
    match only {
        None => (0..height).for_each(&mut push),
        Some(rows) => {
            let mut last = None;
            for &r in rows.iter().filter(|&&r| r < height) {
                if last.is_none_or(|l| r > l) {
                    push(r);
                    last = Some(r);
                }
            }
        }
    }
    runs
}

/// [`stream_band_sequential`] over the row runs `runs` only (from [`row_runs`]).
pub fn stream_runs(
    tx: &Sender<StreamMsg>,
    angles_deg: &[f64],
    bands: usize,
    runs: &[(usize, usize)],
    mut block: impl FnMut(usize, usize, usize, usize) -> Samples,
) {
    for (a, &deg) in angles_deg.iter().enumerate() {
        if tx.send(StreamMsg::Angle { incidence_deg: deg }).is_err() {
            return;
        }
        for b in 0..bands {
            for &(r0, rows) in runs {
                let msg = StreamMsg::Rows(RowBlock {
                    band: b as u16,
                    first_row: r0 as u32,
                    rows: rows as u32,
                    samples: block(a, b, r0, rows),
                });
                if tx.send(msg).is_err() {
                    return;
                }
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
    block: impl FnMut(usize, usize, usize, usize) -> Samples,
) {
    let runs = row_runs(height, None, rows_per_block);
    stream_runs(tx, angles_deg, bands, &runs, block);
}

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
                        if let (Some(r), Some(v)) = (white.as_mut(), wv.as_mut()) {
                            let line = ref_line(r, r0 + k);
                            r.read_band_row(b, line, &mut v[s.clone()]).map_err(err)?;
                        }
                        if let (Some(r), Some(v)) = (dark.as_mut(), dv.as_mut()) {
                            let line = ref_line(r, r0 + k);
                            r.read_band_row(b, line, &mut v[s]).map_err(err)?;
                        }
                    }
                    let msg = StreamMsg::Rows(RowBlock {
                        band: b as u16,
                        first_row: r0 as u32,
                        rows: n as u32,
                        samples: block(counts, wv, dv),
                    });
                    if tx.send(msg).is_err() {
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
                let msg = StreamMsg::Rows(RowBlock {
                    band: b as u16,
                    first_row: r0 as u32,
                    rows: n as u32,
                    samples: block(c, wb, db),
                });
                if tx.send(msg).is_err() {
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
}
