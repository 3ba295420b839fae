//! Live acquisition: the sweep of issue 5 as a pipeline [`Source`], recording the raw sweep
//! as a capture (capture-format.md) while it streams.
//!
//! Home the stage; prepare the filter (and the wheel); for each angle: move, read the
//! position back; for each band: tune, read the wavelength back, take a dark, a white and
//! a sample frame; each sample row goes downstream with its references as soon as it
//! arrives. Only one band image of references is held at a time, never a cube.
//!
//! The capture is written band-sequentially (BSQ: the order frames arrive in), each cube
//! renamed into place when its angle is complete and `capture.toml` rewritten atomically
//! after every angle, so an interrupted sweep leaves a capture of the angles taken;
//! `acquisition.json` says what is missing and every row the link lost. A lost row is
//! recorded with counts 0 and a NaN white reference, so its pixels calibrate to NaN both
//! live and on replay, and the solver flags them.
//!
//! The first [`Source::stream`] is the live sweep; later passes (the estimator may ask for
//! more) replay the recorded capture, so the maps equal `estimate` on that capture.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

use crossbeam_channel::Sender;
use filmscope_core::hw::{FrameKind, FrameRequest, LineEvent, RowLoss};
use filmscope_core::solve::SweepSpec;

use super::{sweep_spec, CaptureSource, RowBlock, Samples, Source, StreamMsg, DEFAULT_INDEX_RANGE};
use crate::io::{
    Angle, Capture, DataType, EnviHeader, EnviWriter, Interleave, Lens, Sample, Search,
};
use crate::record::acquisition::{AcquisitionFile, AcquisitionLog, LostRows};
use crate::record::RecordError;
use crate::rig::{Rig, RigConfig, RigError};

/// Set by Ctrl-C once [`stop_on_ctrl_c`] ran: the sweep stops at the next band.
static INTERRUPTED: OnceLock<Arc<AtomicBool>> = OnceLock::new();

/// Makes Ctrl-C (SIGINT, SIGTERM) stop the sweep at the next band, keeping the angles
/// taken and writing `acquisition.json`; a second one ends the process at once (its
/// staging folder is removed by the next run into the same output).
pub fn stop_on_ctrl_c() -> std::io::Result<()> {
    if INTERRUPTED.get().is_none() {
        let _ = INTERRUPTED.set(crate::io::signals::stop_flag(true)?);
    }
    Ok(())
}

fn interrupted() -> bool {
    INTERRUPTED
        .get()
        .is_some_and(|stop| stop.load(Ordering::SeqCst))
}

/// The live sweep as a [`Source`].
pub struct Acquisition {
    rig: Rig,
    config: RigConfig,
    spec: SweepSpec,
    bands_nm: Vec<f64>,
    out: PathBuf,
    /// What happened (complete after the first stream).
    pub log: AcquisitionLog,
    acquired: bool,
}

/// Why a live sweep cannot start.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// The capture's folder cannot be created.
    #[error("{}: {cause}", .path.display())]
    Folder {
        /// The folder.
        path: PathBuf,
        /// Why (in the message, not a source: one line, said once).
        cause: std::io::Error,
    },
    /// The rig file's sweep is not one the estimator takes.
    #[error(transparent)]
    Spec(#[from] super::SourceError),
    /// The rig file's back face is unknown.
    #[error(transparent)]
    BackFace(#[from] crate::rig::config::UnknownBackFace),
}

impl Acquisition {
    /// A sweep of `rig` per `config`, recording into `out` (created).
    pub fn new(rig: Rig, config: RigConfig, out: &Path) -> Result<Self, LiveError> {
        std::fs::create_dir_all(out).map_err(|cause| LiveError::Folder {
            path: out.to_path_buf(),
            cause,
        })?;
        let bands_nm = config.sweep.bands();
        let search = config.search.clone();
        let spec = sweep_spec(
            config.camera.width as usize,
            config.camera.height as usize,
            &bands_nm,
            Some(&vec![config.sweep.fwhm_nm; bands_nm.len()]),
            config.sample.ambient_index,
            config.sample.substrate_index,
            filmscope_core::optics::Polarization::from_name(&config.sample.polarization)
                .unwrap_or(filmscope_core::optics::Polarization::S),
            search
                .as_ref()
                .and_then(|s| s.index_range)
                .unwrap_or(DEFAULT_INDEX_RANGE),
            search.as_ref().and_then(|s| s.thickness_range_nm),
        )?
        .with_back_face(config.sample.back_face()?);
        Ok(Self {
            rig,
            config,
            spec,
            bands_nm,
            out: out.to_path_buf(),
            log: AcquisitionLog::default(),
            acquired: false,
        })
    }

    /// The capture file being written.
    pub fn capture_path(&self) -> PathBuf {
        self.out.join("capture.toml")
    }

    fn header(&self, data_type: DataType, description: &str) -> EnviHeader {
        let c = &self.config.camera;
        let mut h = EnviHeader::new(
            c.width as usize,
            c.height as usize,
            self.bands_nm.len(),
            data_type,
            Interleave::Bsq,
        );
        h.wavelength_nm = Some(self.bands_nm.clone());
        h.fwhm_nm = Some(vec![self.config.sweep.fwhm_nm; self.bands_nm.len()]);
        h.description = Some(description.to_owned());
        h
    }

    fn write_capture(&self, angles: &[Angle]) -> Result<(), String> {
        let path = self.capture_path();
        let s = &self.config.sample;
        let capture = Capture {
            path: path.clone(),
            sample: Sample {
                back_face: self.spec.back_face,
                ambient_index: s.ambient_index,
                substrate_index: s.substrate_index,
                substrate: None,
                polarization: self.spec.polarization,
            },
            search: Search {
                index_range: self.config.search.as_ref().and_then(|s| s.index_range),
                thickness_range_nm: self
                    .config
                    .search
                    .as_ref()
                    .and_then(|s| s.thickness_range_nm),
            },
            lens: Lens::default(),
            angles: angles.to_vec(),
            fit: Default::default(),
            unknown_keys: Vec::new(),
        };
        capture.write_toml(&path).map_err(|e| e.to_string())
    }

    /// Reads one reference frame (dark or white) into `out` (`width * height`), NaN where
    /// rows were lost.
    fn reference(
        &mut self,
        request: FrameRequest,
        out: &mut [f32],
        incidence_deg: f64,
    ) -> Result<(), String> {
        let w = self.config.camera.width as usize;
        self.trigger(request)?;
        let mut px = vec![0u16; w];
        loop {
            match self
                .rig
                .camera
                .read_line(&mut px)
                .map_err(|e| e.to_string())?
            {
                LineEvent::Row { row } => {
                    let r = row as usize;
                    for (o, &v) in out[r * w..(r + 1) * w].iter_mut().zip(&px) {
                        *o = f32::from(v);
                    }
                }
                LineEvent::Lost {
                    first,
                    count,
                    cause,
                } => {
                    let n = out.len();
                    let (a, b) = (first as usize * w, (first + count) as usize * w);
                    out[a.min(n)..b.min(n)].fill(f32::NAN);
                    self.note_lost(incidence_deg, request, first, count, cause);
                }
                LineEvent::End => return Ok(()),
            }
        }
    }

    fn note_lost(&mut self, deg: f64, req: FrameRequest, first: u32, count: u32, cause: RowLoss) {
        self.log.lost_rows.push(LostRows {
            incidence_deg: deg,
            band: usize::from(req.band),
            frame: req.kind.into(),
            first_row: first,
            rows: count,
            cause: cause.into(),
        });
    }

    fn trigger(&mut self, request: FrameRequest) -> Result<(), String> {
        let info = self
            .rig
            .camera
            .trigger(request)
            .map_err(|e| e.to_string())?;
        let c = &self.config.camera;
        if info.width != c.width || info.rows != c.height {
            return Err(format!(
                "camera sends {} x {} frames but rig.toml says {} x {}",
                info.width, info.rows, c.width, c.height
            ));
        }
        Ok(())
    }

    /// The live sweep; `Ok(false)` when the pipeline stopped listening.
    fn sweep(&mut self, tx: &Sender<StreamMsg>) -> Result<bool, String> {
        let e = |e: RigError| e.to_string();
        let (w, h) = (
            self.config.camera.width as usize,
            self.config.camera.height as usize,
        );
        let sat = self.config.camera.saturation_counts;
        // Until an angle is complete, every planned angle is missing.
        self.log.angles_missing_deg = self.config.sweep.angles_deg.clone();
        self.rig.stage.home().map_err(e)?;
        self.rig.filter.prepare().map_err(e)?;
        if let (Some(wheel), Some(wc)) = (self.rig.wheel.as_mut(), self.config.wheel.as_ref()) {
            wheel.select(wc.slot).map_err(e)?;
        }
        let mut angles: Vec<Angle> = Vec::new();
        let plan = self.config.sweep.angles_deg.clone();
        let offset = self.config.sweep.stage_offset_deg;
        for (ai, &planned) in plan.iter().enumerate() {
            self.log.angles_missing_deg = plan[ai..].to_vec();
            let stage_deg = self.rig.stage.move_to_deg(planned + offset).map_err(e)?;
            let deg = stage_deg - offset;
            if tx.send(StreamMsg::Angle { incidence_deg: deg }).is_err() {
                return Ok(false);
            }
            let tag = format!("{ai:02}");
            let cube_path = self.out.join(format!("a{tag}.hdr"));
            let white_path = self.out.join(format!("white{tag}.hdr"));
            let dark_path = self.out.join(format!("dark{tag}.hdr"));
            let mut hd = self.header(
                DataType::U16,
                &format!("filmscope acquire: raw counts at {deg} deg"),
            );
            hd.extra
                .push(("saturation counts".into(), format!("{sat}")));
            let mut cube = EnviWriter::create(&cube_path, &hd).map_err(|x| x.to_string())?;
            let href = self.header(DataType::F32, "white reference (counts)");
            let mut white_w = EnviWriter::create(&white_path, &href).map_err(|x| x.to_string())?;
            let dref = self.header(DataType::F32, "dark reference (counts)");
            let mut dark_w = EnviWriter::create(&dark_path, &dref).map_err(|x| x.to_string())?;
            let mut dark = vec![0f32; w * h];
            let mut white = vec![0f32; w * h];
            let mut read_nm = Vec::with_capacity(self.bands_nm.len());
            for b in 0..self.bands_nm.len() {
                if interrupted() {
                    return Err("interrupted (Ctrl-C)".into());
                }
                let lambda = self.rig.filter.tune_nm(self.bands_nm[b]).map_err(e)?;
                read_nm.push(lambda);
                let req = |kind| FrameRequest {
                    kind,
                    angle_deg: stage_deg,
                    lambda_nm: lambda,
                    band: b as u16,
                };
                self.reference(req(FrameKind::Dark), &mut dark, deg)?;
                self.reference(req(FrameKind::White), &mut white, deg)?;
                for r in 0..h {
                    let (dr, wr) = (&dark[r * w..(r + 1) * w], &white[r * w..(r + 1) * w]);
                    dark_w.write_band_row(b, r, dr).map_err(|x| x.to_string())?;
                    white_w
                        .write_band_row(b, r, wr)
                        .map_err(|x| x.to_string())?;
                }
                let request = req(FrameKind::Sample);
                self.trigger(request)?;
                let refs = [&dark[..], &white[..]];
                if !self.sample_rows(tx, request, deg, refs, [&mut cube, &mut white_w])? {
                    return Ok(false);
                }
                if tx.send(StreamMsg::BandEnd { band: b as u16 }).is_err() {
                    return Ok(false);
                }
            }
            cube.finish().map_err(|x| x.to_string())?;
            white_w.finish().map_err(|x| x.to_string())?;
            dark_w.finish().map_err(|x| x.to_string())?;
            angles.push(Angle {
                incidence_deg: deg,
                cube: cube_path,
                white: Some(white_path),
                dark: Some(dark_path),
                white_reflectance: 1.0,
            });
            self.write_capture(&angles)?;
            self.log.angles_done_deg.push(deg);
            self.log.wavelengths_read_nm.push(read_nm);
            self.log.angles_missing_deg = plan[ai + 1..].to_vec();
            if tx.send(StreamMsg::AngleEnd).is_err() {
                return Ok(false);
            }
        }
        self.rig.filter.block().map_err(e)?;
        if let (Some(wheel), Some(wc)) = (self.rig.wheel.as_mut(), self.config.wheel.as_ref()) {
            wheel.select(wc.block_slot).map_err(e)?;
        }
        Ok(true)
    }

    /// Reads the sample frame `request` row by row (a lost row recorded, its pixels given
    /// no usable reference), writes each row into `files` (the cube and the white
    /// reference) and sends it downstream with its `refs` (dark, white); false when
    /// nothing downstream listens any more.
    fn sample_rows(
        &mut self,
        tx: &Sender<StreamMsg>,
        request: FrameRequest,
        deg: f64,
        [dark, white]: [&[f32]; 2],
        [cube, white_w]: [&mut EnviWriter; 2],
    ) -> Result<bool, String> {
        let (w, h) = (
            self.config.camera.width as usize,
            self.config.camera.height as usize,
        );
        let sat = self.config.camera.saturation_counts;
        let b = usize::from(request.band);
        let mut px = vec![0u16; w];
        loop {
            let (first, rows, counts, lost) = match self
                .rig
                .camera
                .read_line(&mut px)
                .map_err(|e| e.to_string())?
            {
                LineEvent::Row { row } => {
                    (row, 1, px.iter().map(|&v| f32::from(v)).collect(), false)
                }
                LineEvent::Lost {
                    first,
                    count,
                    cause,
                } => {
                    self.note_lost(deg, request, first, count, cause);
                    let count = count.min(h as u32 - first.min(h as u32));
                    (first, count, vec![0f32; count as usize * w], true)
                }
                LineEvent::End => return Ok(true),
            };
            let (a, z) = (first as usize * w, (first + rows) as usize * w);
            let mut wv = white[a..z].to_vec();
            if lost {
                // No usable reference: NaN after calibration, live and on replay.
                wv.fill(f32::NAN);
            }
            for k in 0..rows as usize {
                let r = first as usize + k;
                let row = &counts[k * w..(k + 1) * w];
                cube.write_band_row(b, r, row).map_err(|x| x.to_string())?;
                white_w
                    .write_band_row(b, r, &wv[k * w..(k + 1) * w])
                    .map_err(|x| x.to_string())?;
            }
            let msg = StreamMsg::Rows(RowBlock {
                band: request.band,
                first_row: first,
                rows,
                samples: Samples::Raw {
                    counts,
                    dark: Some(dark[a..z].to_vec()),
                    white: wv,
                    white_reflectance: 1.0,
                    saturation_counts: sat as f32,
                },
            });
            if tx.send(msg).is_err() {
                return Ok(false);
            }
        }
    }

    /// Writes `acquisition.json`.
    pub fn write_log(&self) -> Result<(), RecordError> {
        AcquisitionFile::new(self.log.clone()).write(&self.out)
    }
}

impl Source for Acquisition {
    fn spec(&self) -> &SweepSpec {
        &self.spec
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.config.sweep.angles_deg.clone()
    }

    /// A rig streams once, as it measures: the estimator holds its pixel sample as the rows
    /// pass and emits the maps when the sweep ends (a later stream replays the recording).
    fn replayable(&self) -> bool {
        false
    }

    fn stream(&mut self, tx: &Sender<StreamMsg>) {
        if self.acquired {
            // Later passes replay what was recorded.
            let replay = Capture::load(self.capture_path())
                .map_err(|x| x.to_string())
                .and_then(|c| CaptureSource::new(c).map_err(String::from));
            match replay {
                Ok(mut src) => src.stream(tx),
                Err(x) => {
                    let _ = tx.send(StreamMsg::Abort(x));
                }
            }
            return;
        }
        self.acquired = true;
        let result = self.sweep(tx);
        self.log.link = (self.rig.link_stats)();
        match result {
            Ok(true) => {
                self.log.complete = true;
                let _ = tx.send(StreamMsg::SweepEnd);
            }
            Ok(false) => {}
            Err(x) => {
                // Leave the filter dark if it still answers; the error is the one reported.
                let _ = self.rig.filter.block();
                self.log.error = Some(x.clone());
                let _ = tx.send(StreamMsg::Abort(x));
            }
        }
        if let Err(x) = self.write_log() {
            self.log.error.get_or_insert(x.to_string());
        }
    }
}
