//! The software camera: renders the scene's band frames row by row as the rig would see
//! them through the LCTF, as raw 12-bit counts with shot and read noise, dark level,
//! vignetting, dead and hot pixels and saturation, or noise-free as true band reflectance.
//! A scene may replace the shot and read noise by Gaussian noise of a set reflectance
//! (`reflectance_noise_percent`, with exact references), for sweeps over the noise level.
//!
//! Every row is rendered from its own seed `(scene seed, angle, band, row, stream)`, so rows
//! may be asked for in any order (BSQ, BIL, a pipeline, a file writer) and on any number of
//! threads, and come out the same.
//!
//! Rendering at camera rates: a noisy row (a raw sample row, or a capture's float
//! reflectance made from one) takes its band reflectance from a [`ReflectanceTable`] of its
//! `(angle, band)`, built once per camera over the scene's thickness range (cubic Hermite,
//! within 1e-8 of the exact model, a few flops a pixel instead of 33 cosines), and its noise
//! from [`Rng::fast_normal`] (ziggurat) and [`Rng::fast_poisson`]. What that changes
//! against drawing every pixel from the exact model with Box-Muller normals: the shot and
//! read noise sequence of the sample and reference rows (the same distributions: Poisson
//! electrons, normal beyond 64 of them, Gaussian read noise, references' noise shrunk by
//! `sqrt(white_frames)`; defective pixels now take their draws too, so placing one does not
//! move its neighbours' noise) and the reflectance under the noise, by at most 1e-8.
//! Unchanged: the thickness map, the indices, the noise-free rows
//! ([`SoftwareCamera::reflectance_row`] evaluates the model itself), every reference's mean,
//! and the Gaussian reflectance noise of a `reflectance_noise_percent` sensor (the same
//! Box-Muller draws; its counts move by a count where the table's 1e-8 crosses a rounding
//! boundary).
//! A scene with a lens field of view, whose columns each see their own angle, and a scene
//! too small for a table to pay (more nodes than a quarter of a frame's pixels), evaluate
//! the exact model per pixel. The row loops are compiled for AVX2 where the CPU has it
//! ([`filmscope_core::simd::wide`]), with the same results bit for bit.

use std::sync::{Arc, Mutex, PoisonError};

use filmscope_core::optics::BandModel;

use crate::imperfect::ImperfectTable;

use crate::rng::{round_non_negative, Rng};
use crate::scene::Scene;
use crate::table::ReflectanceTable;

const STREAM_SAMPLE: u64 = 1;
const STREAM_WHITE: u64 = 2;
const STREAM_DARK: u64 = 3;
const STREAM_DEFECTS: u64 = 4;

/// What a pixel of the sensor does besides responding to light.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Defect {
    /// Reads the dark level whatever the light.
    Dead,
    /// Reads saturated whatever the light.
    Hot,
}

/// Band models of every column of the last few `(angle, band)`s under a lens field of view
/// (most recent last): rows are asked for band by band, so the last one's models serve the
/// next row, and threads rendering different bands at once each keep theirs.
#[derive(Debug, Default)]
struct ColumnModels(Mutex<Vec<ColumnEntry>>);

/// One `(angle, band)`'s per-column models.
type ColumnEntry = (usize, usize, Arc<Vec<BandModel>>);

/// `(angle, band)`s whose column models are kept.
const COLUMN_ENTRIES: usize = 8;

/// Columns [`SoftwareCamera::expose`] prepares at a time before drawing their noise.
const CHUNK: usize = 256;

impl Clone for ColumnModels {
    fn clone(&self) -> Self {
        Self::default()
    }
}

/// What [`SoftwareCamera::expose`] renders.
#[derive(Clone, Copy, Debug)]
enum Exposure {
    /// One exposure of the sample.
    Sample,
    /// A white or dark reference: the mean of `frames` exposures.
    Reference { frames: u32 },
}

/// The simulated camera behind the LCTF, looking at one scene.
#[derive(Clone, Debug)]
pub struct SoftwareCamera {
    scene: Scene,
    /// `models[angle * bands + band]`.
    models: Vec<BandModel>,
    /// Lamp x filter throughput per band, 1.0 at mid-band.
    throughput: Vec<f64>,
    /// Defective pixels, sorted by index.
    defects: Vec<(usize, Defect)>,
    /// Under a lens field of view: the last `(angle, band)`'s per-column models.
    columns: ColumnModels,
    /// `tables[angle * bands + band]`: the band reflectance over the scene's thickness
    /// range, for noisy rows; `None` where the model is evaluated per pixel instead.
    tables: Arc<Vec<Option<ReflectanceTable>>>,
    /// With the scene's imperfections, `imperfect[angle * bands + band]`: the reflectance a
    /// real rig measures, in place of the ideal models and tables.
    imperfect: Arc<Vec<ImperfectTable>>,
}

impl SoftwareCamera {
    /// Prepares the band models of every angle and band, and places the defective pixels.
    pub fn new(scene: Scene) -> Self {
        let mut models = Vec::with_capacity(scene.angles_deg.len() * scene.bands_nm.len());
        for &angle in &scene.angles_deg {
            for b in 0..scene.bands_nm.len() {
                models.push(BandModel::new(scene.stack, angle, scene.passband(b)));
            }
        }
        // A scene without bands renders nothing (no panic: a caller may build one).
        let lo = scene.bands_nm.first().copied().unwrap_or(0.0);
        let hi = *scene.bands_nm.last().unwrap_or(&lo);
        let throughput = scene
            .bands_nm
            .iter()
            .map(|&l| {
                scene
                    .sensor
                    .throughput(if hi > lo { (l - lo) / (hi - lo) } else { 0.5 })
            })
            .collect();
        let n_px = scene.sensor.width * scene.sensor.height;
        let mut rng = Rng::from_words(&[scene.seed, STREAM_DEFECTS]);
        let mut defects: Vec<(usize, Defect)> = Vec::new();
        let wanted = [
            (scene.sensor.dead_pixels, Defect::Dead),
            (scene.sensor.hot_pixels, Defect::Hot),
        ];
        for (count, kind) in wanted {
            let count = count.min(n_px / 2);
            let mut placed = 0;
            while placed < count {
                let i = (rng.next_u64() % n_px as u64) as usize;
                if defects.iter().all(|&(j, _)| j != i) {
                    defects.push((i, kind));
                    placed += 1;
                }
            }
        }
        defects.sort_unstable_by_key(|&(i, _)| i);
        let imperfect = Arc::new(imperfect_tables(&scene));
        let tables = if imperfect.is_empty() {
            Arc::new(tables(&scene, &models))
        } else {
            Arc::new(vec![None; models.len()])
        };
        Self {
            scene,
            models,
            throughput,
            defects,
            columns: ColumnModels::default(),
            tables,
            imperfect,
        }
    }

    /// How many `(angle, band)`s render their noisy rows from a [`ReflectanceTable`] (the
    /// rest evaluate the model per pixel), and their largest table's nodes.
    pub fn tabulated(&self) -> (usize, usize) {
        let tables = self.tables.iter().flatten();
        (
            tables.clone().count(),
            tables.map(ReflectanceTable::nodes).max().unwrap_or(0),
        )
    }

    /// The scene being rendered.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Pixels per row.
    pub fn width(&self) -> usize {
        self.scene.sensor.width
    }

    /// Rows per frame.
    pub fn height(&self) -> usize {
        self.scene.sensor.height
    }

    /// The defective pixels, as `(row-major index, kind)`.
    pub fn defects(&self) -> &[(usize, Defect)] {
        &self.defects
    }

    fn model(&self, angle: usize, band: usize) -> &BandModel {
        &self.models[angle * self.scene.bands_nm.len() + band]
    }

    /// True band reflectance of one row, without noise or defects (`out.len() == width`).
    /// With a lens field of view every column is seen at its own incidence angle
    /// ([`Scene::incidence_deg`]).
    pub fn reflectance_row(&self, angle: usize, band: usize, row: usize, out: &mut [f32]) {
        let w = self.width();
        let thickness = &self.scene.thickness_nm[row * w..(row + 1) * w];
        if self.scene.field_of_view.is_some() {
            let models = self.column_models(angle, band);
            for ((o, &d), model) in out.iter_mut().zip(thickness).zip(models.iter()) {
                *o = model.reflectance(f64::from(d)) as f32;
            }
            return;
        }
        if let Some(table) = self.imperfect.get(angle * self.scene.bands_nm.len() + band) {
            for (o, &d) in out.iter_mut().zip(thickness) {
                *o = table.reflectance(f64::from(d)) as f32;
            }
            return;
        }
        let model = self.model(angle, band);
        for (o, &d) in out.iter_mut().zip(thickness) {
            *o = model.reflectance(f64::from(d)) as f32;
        }
    }

    /// Under a lens field of view: the band model of every column of `(angle, band)`, kept
    /// for the rows that follow (built outside the lock, so other threads go on meanwhile).
    fn column_models(&self, angle: usize, band: usize) -> Arc<Vec<BandModel>> {
        let lock = || {
            self.columns
                .0
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
        };
        {
            let mut kept = lock();
            if let Some(i) = kept.iter().position(|e| e.0 == angle && e.1 == band) {
                let entry = kept.remove(i);
                let models = entry.2.clone();
                kept.push(entry);
                return models;
            }
        }
        let stage_deg = self.scene.angles_deg[angle];
        let passband = self.scene.passband(band);
        let models: Arc<Vec<BandModel>> = Arc::new(
            (0..self.width())
                .map(|col| {
                    let deg = self.scene.incidence_deg(stage_deg, col);
                    BandModel::new(self.scene.stack, deg, passband)
                })
                .collect(),
        );
        let mut kept = lock();
        if kept.len() >= COLUMN_ENTRIES {
            kept.remove(0);
        }
        kept.push((angle, band, models.clone()));
        models
    }

    /// The defective pixels of row `row`, as `(column, kind)`.
    fn defects_in_row(&self, row: usize) -> impl Iterator<Item = (usize, Defect)> + '_ {
        let w = self.width();
        let from = self.defects.partition_point(|&(i, _)| i < row * w);
        let to = self.defects.partition_point(|&(i, _)| i < (row + 1) * w);
        self.defects[from..to]
            .iter()
            .map(move |&(i, d)| (i - row * w, d))
    }

    /// Counts for a row of targets of reflectance `r(col)`: one noisy exposure of the
    /// sample, or the mean of a reference's exposures, handed to `emit(col, counts)`. With
    /// the scene's `reflectance_noise_percent`, the sample gets that Gaussian reflectance
    /// noise and the references none. Every pixel takes its draws in column order, then the
    /// defective ones are overwritten.
    #[inline(always)]
    fn expose(
        &self,
        band: usize,
        row: usize,
        exposure: Exposure,
        rng: &mut Rng,
        r: impl Fn(usize) -> f64,
        mut emit: impl FnMut(usize, f64),
    ) {
        let s = &self.scene.sensor;
        let sat = s.saturation_counts();
        let (w, h) = (self.width(), self.height());
        let dark = s.dark_counts;
        // Counts above dark of a perfect white at this band and pixel (vignetting included):
        // `white * (1 - vignetting * (x^2 + y^2) / 0.5)`.
        let white = s.white_counts * self.throughput[band];
        let y = (row as f64 + 0.5) / h as f64 - 0.5;
        let k = s.vignetting / 0.5;
        let inv_w = 1.0 / w as f64;
        let lit = |col: usize| {
            let x = (col as f64 + 0.5) * inv_w - 0.5;
            white * (1.0 - k * (x * x + y * y))
        };
        match (s.reflectance_noise_percent, exposure) {
            (Some(_), Exposure::Reference { .. }) => {
                for col in 0..w {
                    emit(col, dark + lit(col) * r(col));
                }
            }
            (Some(percent), Exposure::Sample) => {
                // The ideal sensor of the noise sweeps keeps its Box-Muller sequence, one
                // draw per working pixel (the stability maps and their tests were measured
                // on it).
                let sigma = 0.01 * percent;
                let defective: Vec<usize> = self.defects_in_row(row).map(|(c, _)| c).collect();
                for col in 0..w {
                    if !defective.is_empty() && defective.contains(&col) {
                        continue;
                    }
                    let noisy = r(col) + sigma * rng.normal();
                    emit(col, round_clamp(dark + lit(col) * noisy, sat));
                }
            }
            (None, Exposure::Sample) => {
                let gain = s.gain_e_per_count;
                let per_e = 1.0 / gain;
                let read = s.read_noise_counts;
                // Per chunk of columns, the mean electrons first (no draws, no branches),
                // then the draws: the generator's chain is all the second loop carries.
                let mut mean = [0f64; CHUNK];
                for start in (0..w).step_by(CHUNK) {
                    let mean = &mut mean[..CHUNK.min(w - start)];
                    for (k, m) in mean.iter_mut().enumerate() {
                        let col = start + k;
                        *m = (lit(col) * r(col)).max(0.0) * gain;
                    }
                    for (k, &m) in mean.iter().enumerate() {
                        let electrons = rng.fast_poisson(m);
                        let counts = dark + electrons * per_e + read * rng.fast_normal();
                        emit(start + k, round_clamp(counts, sat));
                    }
                }
            }
            (None, Exposure::Reference { frames }) => {
                // The mean of `frames` exposures: shot and read noise shrink by sqrt(frames);
                // drawn at once (the central limit of the per-frame Poisson and Gaussian
                // draws) rather than frame by frame. Per chunk of columns, each pixel's
                // noise-free level and deviation first, then the draws.
                let kf = f64::from(frames);
                let shot_var = 1.0 / (s.gain_e_per_count * kf);
                let read_var = s.read_noise_counts * s.read_noise_counts / kf;
                let (mut level, mut sd) = ([0f64; CHUNK], [0f64; CHUNK]);
                for start in (0..w).step_by(CHUNK) {
                    let n = CHUNK.min(w - start);
                    let (level, sd) = (&mut level[..n], &mut sd[..n]);
                    for (k, (l, d)) in level.iter_mut().zip(sd.iter_mut()).enumerate() {
                        let signal = (lit(start + k) * r(start + k)).max(0.0);
                        *d = (signal * shot_var + read_var).sqrt();
                        *l = dark + signal;
                    }
                    for (k, (&l, &d)) in level.iter().zip(sd.iter()).enumerate() {
                        emit(start + k, (l + d * rng.fast_normal()).clamp(0.0, sat));
                    }
                }
            }
        }
        for (col, defect) in self.defects_in_row(row) {
            emit(
                col,
                match defect {
                    Defect::Dead => dark,
                    Defect::Hot => sat,
                },
            );
        }
    }

    /// Raw counts of one row of the sample (one exposure), as the camera link delivers them.
    /// Its band reflectance comes from the `(angle, band)`'s table where there is one.
    pub fn raw_row(&self, angle: usize, band: usize, row: usize, out: &mut [u16]) {
        filmscope_core::simd::wide(true, {
            #[inline(always)]
            || {
                let w = self.width();
                let mut rng = self.rng(STREAM_SAMPLE, angle, band, row);
                let emit = |c: usize, v: f64| out[c] = v as u16;
                match &self.tables[angle * self.scene.bands_nm.len() + band] {
                    Some(table) => {
                        let thickness = &self.scene.thickness_nm[row * w..(row + 1) * w];
                        let r = |c: usize| table.reflectance(f64::from(thickness[c]));
                        self.expose(band, row, Exposure::Sample, &mut rng, r, emit);
                    }
                    None => {
                        let mut refl = vec![0f32; w];
                        self.reflectance_row(angle, band, row, &mut refl);
                        let r = |c: usize| f64::from(refl[c]);
                        self.expose(band, row, Exposure::Sample, &mut rng, r, emit);
                    }
                }
            }
        })
    }

    /// The white reference row (a perfect diffuse white, `white_frames` exposures averaged),
    /// in counts, dark included.
    pub fn white_row(&self, angle: usize, band: usize, row: usize, out: &mut [f32]) {
        self.reference_row(STREAM_WHITE, 1.0, [angle, band, row], out);
    }

    /// The dark reference row (shutter closed, `white_frames` exposures averaged), in counts.
    pub fn dark_row(&self, angle: usize, band: usize, row: usize, out: &mut [f32]) {
        self.reference_row(STREAM_DARK, 0.0, [angle, band, row], out);
    }

    /// A reference row of a target of reflectance `level` from noise stream `stream`.
    fn reference_row(
        &self,
        stream: u64,
        level: f64,
        [angle, band, row]: [usize; 3],
        out: &mut [f32],
    ) {
        filmscope_core::simd::wide(true, {
            #[inline(always)]
            || {
                let mut rng = self.rng(stream, angle, band, row);
                let frames = self.scene.sensor.white_frames;
                let emit = |c: usize, v: f64| out[c] = v as f32;
                self.expose(
                    band,
                    row,
                    Exposure::Reference { frames },
                    &mut rng,
                    |_| level,
                    emit,
                );
            }
        })
    }

    fn rng(&self, stream: u64, angle: usize, band: usize, row: usize) -> Rng {
        Rng::from_words(&[
            self.scene.seed,
            stream,
            angle as u64,
            band as u64,
            row as u64,
        ])
    }
}

/// `x.round().clamp(0.0, max)` for a whole `max`, without a library call.
#[inline]
fn round_clamp(x: f64, max: f64) -> f64 {
    round_non_negative(x).min(max)
}

/// The tables of every `(angle, band)` (angle-major), built on every core: none under a lens
/// field of view, and none where a table would need more nodes than a quarter of a frame's
/// pixels (evaluating the model per pixel is then as cheap).
/// Every `(angle, band)`'s [`ImperfectTable`] over the scene's thickness range when the scene
/// has imperfections (none otherwise), built on as many threads as the machine has.
fn imperfect_tables(scene: &Scene) -> Vec<ImperfectTable> {
    let imp = scene.imperfections;
    if !imp.any() || scene.thickness_nm.is_empty() {
        return Vec::new();
    }
    let (lo, hi) = thickness_span(scene);
    let range = [f64::from(lo), f64::from(hi)];
    let nb = scene.bands_nm.len();
    let jobs: Vec<(usize, usize)> = (0..scene.angles_deg.len())
        .flat_map(|a| (0..nb).map(move |b| (a, b)))
        .collect();
    let one = |&(a, b): &(usize, usize)| {
        let band = scene.passband(b);
        let lo_l = band.center_nm - 2.0 * band.fwhm_nm;
        let max_index = (0..=8)
            .map(|i| {
                scene
                    .stack
                    .film
                    .index_at(lo_l + f64::from(i) * band.fwhm_nm * 0.5)
            })
            .fold(0.0, f64::max);
        ImperfectTable::new(
            &scene.stack,
            &imp,
            scene.angles_deg[a],
            &band,
            range,
            max_index,
        )
    };
    on_threads(&jobs, one)
}

fn tables(scene: &Scene, models: &[BandModel]) -> Vec<Option<ReflectanceTable>> {
    if scene.field_of_view.is_some() || models.is_empty() {
        return vec![None; models.len()];
    }
    let (lo, hi) = thickness_span(scene);
    let max_nodes = scene.sensor.width * scene.sensor.height / 4;
    let one = |model: &BandModel| {
        let band = model.band();
        let min_lambda = band.nodes().map(|(l, _)| l).fold(f64::INFINITY, f64::min);
        let max_index = band
            .nodes()
            .map(|(l, _)| scene.stack.film.index_at(l))
            .fold(0.0, f64::max);
        ReflectanceTable::new(
            model,
            f64::from(lo),
            f64::from(hi),
            min_lambda,
            max_index,
            max_nodes,
        )
    };
    on_threads(models, one)
}

/// The scene's thinnest and thickest pixel, nm.
fn thickness_span(scene: &Scene) -> (f32, f32) {
    let t = scene.thickness_nm.iter().copied();
    (
        t.clone().fold(f32::INFINITY, f32::min),
        t.fold(0f32, f32::max),
    )
}

/// `f` of every item, in order, the items split over as many threads as the machine has.
fn on_threads<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let chunk = items.len().div_ceil(threads).max(1);
    let f = &f;
    std::thread::scope(|s| {
        let parts: Vec<_> = items
            .chunks(chunk)
            .map(|part| s.spawn(move || part.iter().map(f).collect::<Vec<_>>()))
            .collect();
        parts
            .into_iter()
            .flat_map(|p| p.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rig's scene (`config/scenes/rig-tiny.toml`) seen by a 16-bit sensor without
    /// vignetting or defects, its reflectance noise `noise_percent` (`None`: shot and read).
    fn camera(noise_percent: Option<f64>) -> SoftwareCamera {
        let mut doc: toml::Table = rig_tiny().parse().expect("TOML");
        let sensor = doc
            .get_mut("sensor")
            .and_then(|s| s.as_table_mut())
            .expect("[sensor]");
        for (key, value) in [
            ("bit_depth", toml::Value::Integer(16)),
            ("white_counts", toml::Value::Float(40000.0)),
            ("dark_counts", toml::Value::Float(8000.0)),
            ("vignetting", toml::Value::Float(0.0)),
            ("dead_pixels", toml::Value::Integer(0)),
            ("hot_pixels", toml::Value::Integer(0)),
        ] {
            sensor.insert(key.into(), value);
        }
        if let Some(p) = noise_percent {
            sensor.insert("reflectance_noise_percent".into(), toml::Value::Float(p));
        }
        SoftwareCamera::new(Scene::from_toml(&doc.to_string(), "t").expect("scene"))
    }

    /// The text of `config/scenes/rig-tiny.toml`.
    fn rig_tiny() -> String {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../config/scenes/rig-tiny.toml"
        );
        std::fs::read_to_string(path).expect("rig-tiny scene")
    }

    /// `(calibrated, true reflectance, white counts)` at every pixel of the bands `bands` of
    /// every angle.
    fn samples(cam: &SoftwareCamera, bands: std::ops::Range<usize>) -> Vec<(f64, f64, f32)> {
        let w = cam.width();
        let (mut raw, mut white, mut dark, mut truth) =
            (vec![0u16; w], vec![0f32; w], vec![0f32; w], vec![0f32; w]);
        let mut out = Vec::new();
        for a in 0..cam.scene().angles_deg.len() {
            for b in bands.clone() {
                for row in 0..cam.height() {
                    cam.raw_row(a, b, row, &mut raw);
                    cam.white_row(a, b, row, &mut white);
                    cam.dark_row(a, b, row, &mut dark);
                    cam.reflectance_row(a, b, row, &mut truth);
                    for c in 0..w {
                        let r = (f64::from(raw[c]) - f64::from(dark[c]))
                            / f64::from(white[c] - dark[c]);
                        out.push((r, f64::from(truth[c]), white[c]));
                    }
                }
            }
        }
        out
    }

    /// Calibrated minus true reflectance at every pixel of every band and angle.
    fn errors(cam: &SoftwareCamera) -> Vec<f64> {
        let bands = 0..cam.scene().bands_nm.len();
        samples(cam, bands).iter().map(|(r, t, _)| r - t).collect()
    }

    fn scene(name: &str) -> Scene {
        let path = format!(
            "{}/../config/scenes/{name}.toml",
            env!("CARGO_MANIFEST_DIR")
        );
        Scene::load(std::path::Path::new(&path)).expect("scene")
    }

    /// The default sensor (12 bits, its default white level) keeps its white reference
    /// below saturation where the lamp is brightest (the band's red end, the image centre),
    /// so the reflectance calibrated against it is unbiased there; a white that would clip
    /// is refused. (A white clipped at 4095 read every sample of the red end of a
    /// 3400-count white up to 5 % high, and thin films' indices by up to 0.004.)
    #[test]
    fn the_white_reference_never_clips() {
        let text = rig_tiny();
        let with = |extra: &str| {
            let defects = "dead_pixels = 2\nhot_pixels = 1";
            Scene::from_toml(
                &text.replace(
                    defects,
                    &format!("dead_pixels = 0\nhot_pixels = 0\n{extra}"),
                ),
                "t",
            )
        };
        let cam = SoftwareCamera::new(with("").expect("scene"));
        let sensor = cam.scene().sensor.clone();
        assert_eq!(sensor.bit_depth, 12);
        assert!(sensor.peak_white_counts() < sensor.saturation_counts());
        let last = cam.scene().bands_nm.len() - 1;
        let red = samples(&cam, last..last + 1);
        let brightest = red.iter().map(|s| s.2).fold(0f32, f32::max);
        let n = red.len() as f64;
        let sum: f64 = red.iter().map(|(r, t, _)| r / t - 1.0).sum();
        assert!(
            f64::from(brightest) < sensor.saturation_counts() - 100.0,
            "{brightest}"
        );
        // The relative error's mean: shot noise of a few percent a sample over 3072 samples.
        assert!((sum / n).abs() < 0.002, "mean relative error {}", sum / n);
        let err = with("white_counts = 3400.0").expect_err("a clipping white");
        assert!(err.to_string().contains("would clip"), "{err}");
    }

    /// The paper's sample renders every noisy row from a table, and the table's
    /// reflectance under the noise is the exact model's (the mean of many raw rows,
    /// calibrated, is the true reflectance within its standard error); a scene with a
    /// lens field of view has no table.
    #[test]
    fn noisy_rows_come_from_tables_that_keep_the_model() {
        let cam = SoftwareCamera::new(scene("paper-sample1"));
        let (angles, bands) = (cam.scene().angles_deg.len(), cam.scene().bands_nm.len());
        assert_eq!(cam.tabulated().0, angles * bands);
        let wide = SoftwareCamera::new(scene("paper-sample1-wide-fov"));
        assert_eq!(wide.tabulated(), (0, 0));
        let w = cam.width();
        let (mut raw, mut white, mut dark, mut truth) =
            (vec![0u16; w], vec![0f32; w], vec![0f32; w], vec![0f32; w]);
        let (mut sum, mut sum2, mut n) = (0.0, 0.0, 0.0);
        for b in (0..bands).step_by(10) {
            for row in 0..cam.height() {
                cam.raw_row(2, b, row, &mut raw);
                cam.white_row(2, b, row, &mut white);
                cam.dark_row(2, b, row, &mut dark);
                cam.reflectance_row(2, b, row, &mut truth);
                let defects: Vec<usize> = cam.defects_in_row(row).map(|(c, _)| c).collect();
                for c in (0..w).filter(|c| !defects.contains(c)) {
                    let r =
                        (f64::from(raw[c]) - f64::from(dark[c])) / f64::from(white[c] - dark[c]);
                    let e = r - f64::from(truth[c]);
                    sum += e;
                    sum2 += e * e;
                    n += 1.0;
                }
            }
        }
        let mean = sum / n;
        let sd = (sum2 / n - mean * mean).sqrt();
        assert!(
            mean.abs() < 4.0 * sd / n.sqrt(),
            "bias {mean} (sd {sd}, n {n})"
        );
    }

    #[test]
    fn reflectance_noise_has_the_set_sigma_and_exact_references() {
        let e = errors(&camera(Some(1.5)));
        let n = e.len() as f64;
        let mean = e.iter().sum::<f64>() / n;
        let rms = (e.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
        // 101 bands x 4 angles x 768 pixels: the rms is known to about 0.1 %.
        assert!(mean.abs() < 0.0002, "mean {mean}");
        assert!((rms - 0.015).abs() < 0.0001, "rms {rms}");
    }

    #[test]
    fn reflectance_noise_zero_leaves_only_the_adc_rounding() {
        let e = errors(&camera(Some(0.0)));
        // Half a count of the dimmest band's white (0.75 x 40000 counts).
        let half_count = 0.5 / (0.75 * 40000.0);
        let worst = e.iter().fold(0f64, |m, x| m.max(x.abs()));
        assert!(worst <= half_count * 1.001, "worst {worst}");
        // The shot-noise sensor, for contrast, is far noisier.
        let shot = errors(&camera(None));
        assert!(shot.iter().any(|x| x.abs() > 100.0 * half_count));
    }
}
