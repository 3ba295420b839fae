//! The software camera as a source.

use crossbeam_channel::Sender;
use filmscope_core::solve::SweepSpec;
use firmware_sim::SoftwareCamera;

use super::{
    row_runs, stream_band_sequential, stream_runs, sweep_spec, Samples, Source, SourceError,
    StreamMsg, DEFAULT_INDEX_RANGE,
};

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
    ) -> Result<Self, SourceError> {
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
            scene.thickness_range_nm,
        )?
        .with_substrate(scene.stack.substrate)
        .with_back_face(scene.stack.back_face);
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
