//! Calibrated frames held in memory and replayed as a source of any height: what the
//! benchmarks and charts time the pipeline on, free of disk and camera.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;
use filmscope_core::solve::SweepSpec;
use firmware_sim::{Scene, SoftwareCamera};

use super::{
    calibrate_block, row_runs, stream_runs, Samples, SimSource, Source, SourceError, StreamMsg,
};

/// Calibrated reflectance frames of the first `rows` rows of a scene, every angle and band,
/// held in memory to be replayed.
pub struct Frames {
    /// The sweep as the solver sees it.
    pub spec: SweepSpec,
    /// Angles, degrees.
    pub angles_deg: Vec<f64>,
    /// Rows held.
    pub rows: usize,
    /// `[angle][band][row][col]`.
    pub data: Vec<f32>,
}

impl Frames {
    /// Renders the first `rows` rows of `scene` through the software camera (raw counts with
    /// noise, white and dark references) and calibrates them.
    pub fn render(scene: &Scene, rows: usize) -> Result<Self, SourceError> {
        let source = SimSource::new(SoftwareCamera::new(scene.clone()), false, 1)
            .map_err(|e| e.of(&scene.name))?;
        let spec = source.spec().clone();
        let w = spec.width;
        let rows = rows.clamp(1, spec.height);
        let (na, nb) = (scene.angles_deg.len(), scene.bands_nm.len());
        let mut data = Vec::with_capacity(na * nb * rows * w);
        for a in 0..na {
            for b in 0..nb {
                data.extend(calibrate_block(source.block(a, b, 0, rows), rows, w));
            }
        }
        Ok(Self {
            spec,
            angles_deg: scene.angles_deg.clone(),
            rows,
            data,
        })
    }

    /// Pixels per row.
    pub fn width(&self) -> usize {
        self.spec.width
    }

    /// Bands per angle.
    pub fn bands(&self) -> usize {
        self.spec.bands_nm.len()
    }

    /// Row `row` of band `band` at angle `angle`.
    pub fn row(&self, angle: usize, band: usize, row: usize) -> &[f32] {
        let w = self.width();
        let start = ((angle * self.bands() + band) * self.rows + row % self.rows) * w;
        &self.data[start..start + w]
    }
}

/// A source replaying [`Frames`], their rows repeated to `height` rows (band-sequential, in
/// blocks of `rows_per_block` rows of calibrated reflectance).
pub struct ReplaySource {
    frames: Arc<Frames>,
    spec: SweepSpec,
    rows_per_block: usize,
    pace: Option<f64>,
}

impl ReplaySource {
    /// A source of `height` rows.
    pub fn new(frames: Arc<Frames>, height: usize, rows_per_block: usize) -> Self {
        let mut spec = frames.spec.clone();
        spec.height = height;
        Self {
            frames,
            spec,
            rows_per_block: rows_per_block.max(1),
            pace: None,
        }
    }

    /// Delivers at most `samples_per_s` (a camera's rate), so nothing queues up in the
    /// pipeline when it is faster: the latency after the last row is then the pipeline's own.
    pub fn paced(mut self, samples_per_s: f64) -> Self {
        self.pace = Some(samples_per_s);
        self
    }
}

impl Source for ReplaySource {
    fn spec(&self) -> &SweepSpec {
        &self.spec
    }

    fn angles_deg(&self) -> Vec<f64> {
        self.frames.angles_deg.clone()
    }

    fn stream(&mut self, tx: &Sender<StreamMsg>) {
        self.stream_runs(tx, None);
    }

    fn stream_rows(&mut self, tx: &Sender<StreamMsg>, rows: &[usize]) {
        self.stream_runs(tx, Some(rows));
    }
}

impl ReplaySource {
    /// Streams every row, or only those in `only` (sorted).
    fn stream_runs(&mut self, tx: &Sender<StreamMsg>, only: Option<&[usize]>) {
        let f = &self.frames;
        let (w, h) = (self.spec.width, self.spec.height);
        let (start, pace) = (Instant::now(), self.pace);
        let mut sent = 0usize;
        let runs = row_runs(h, only, self.rows_per_block);
        stream_runs(tx, &f.angles_deg, f.bands(), &runs, |a, b, r0, rows| {
            let mut v = Vec::with_capacity(rows * w);
            for r in r0..r0 + rows {
                v.extend_from_slice(f.row(a, b, r));
            }
            sent += v.len();
            if let Some(rate) = pace {
                let due = start + Duration::from_secs_f64(sent as f64 / rate);
                std::thread::sleep(due.saturating_duration_since(Instant::now()));
            }
            Samples::Reflectance(v)
        });
    }
}
