//! `filmscope simulate`: writes a scene as a capture directory per capture-format.md, with
//! its truth beside it.
//!
//! Layout: `capture.toml`; per angle `aNN.hdr/.img` (raw 12-bit counts as uint16, BIL, with
//! `whiteNN` and `darkNN` float32 references averaged over the scene's `white_frames`), or,
//! noise-free or as [`SimulateOptions::float_reflectance`], float32 reflectance without
//! references; any interleave and byte order; `truth/thickness_nm.hdr/.img` and
//! `truth.json`. A scene with a lens field of view writes it as `[lens] horizontal_fov_deg`
//! (filmscope's extension of the capture format).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use filmscope_core::optics::BackFace;
use firmware_sim::{Scene, SoftwareCamera};

use crate::io::{
    write_atomic, write_f32_map, Angle, ByteOrder, Capture, DataType, EnviHeader, EnviWriter,
    Interleave, Lens, Sample, Search,
};
use crate::material::DispersionRecord;
use crate::record::truth::TruthRecord;

/// A capture that could not be written, with the file at fault.
#[derive(Debug, thiserror::Error)]
pub enum SimulateError {
    /// A cube, a reference, the truth map or a folder.
    #[error("{}: {cause}", .path.display())]
    File {
        /// The file or folder.
        path: PathBuf,
        /// Why (the cube writer's or the system's error; in the message, not a source:
        /// one line, said once).
        cause: Box<dyn std::error::Error + Send + Sync>,
    },
    /// `capture.toml`.
    #[error(transparent)]
    Capture(#[from] crate::io::CaptureError),
    /// `truth.json`.
    #[error(transparent)]
    Truth(#[from] crate::record::RecordError),
    /// Rows of an angle reached the writers after that angle was finished (a defect).
    #[error("angle {0} written after its end")]
    AngleAfterEnd(usize),
}

/// How to write the capture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimulateOptions {
    /// Float32 reflectance without noise, defects or vignetting (and no references).
    pub noise_free: bool,
    /// Interleave of the cubes.
    pub interleave: Interleave,
    /// Byte order of the cubes' values.
    pub byte_order: ByteOrder,
    /// Float32 reflectance without references, each sample being its counts over the
    /// references' (`(raw - dark) / (white - dark)`, noise and all; NaN where white does
    /// not exceed dark), instead of raw counts with white and dark references. With the
    /// scene's `reflectance_noise_percent` this is the true reflectance plus that noise.
    /// Ignored with `noise_free`.
    pub float_reflectance: bool,
}

impl Default for SimulateOptions {
    fn default() -> Self {
        Self {
            noise_free: false,
            interleave: Interleave::Bil,
            byte_order: ByteOrder::Little,
            float_reflectance: false,
        }
    }
}

fn header(
    scene: &Scene,
    data_type: DataType,
    opts: SimulateOptions,
    description: &str,
) -> EnviHeader {
    let s = &scene.sensor;
    let mut h = EnviHeader::new(
        s.width,
        s.height,
        scene.bands_nm.len(),
        data_type,
        opts.interleave,
    );
    h.byte_order = opts.byte_order;
    h.wavelength_nm = Some(scene.bands_nm.clone());
    h.fwhm_nm = Some(vec![scene.fwhm_nm; scene.bands_nm.len()]);
    h.description = Some(description.to_owned());
    h
}

/// What a capture's cube holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum RowKind {
    /// True band reflectance ([`SoftwareCamera::reflectance_row`]).
    NoiseFree,
    /// Counts over the references' (`(raw - dark) / (white - dark)`).
    FloatReflectance,
    /// Raw counts, with the white and dark reference rows beside them.
    Raw,
}

/// Threads that render rows: every core.
fn render_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Rows of one render job: about a quarter of a million samples, at least one row.
fn job_rows(width: usize) -> usize {
    ((1 << 18) / width.max(1)).max(1)
}

/// Batches per render thread that exist at once (being rendered, waiting their turn, being
/// written): the memory [`render_in_order`] holds, and how far rendering may run ahead of a
/// writer that stalls.
const BATCHES_PER_THREAD: usize = 4;

/// The `(band, row)`s of one angle in the order the cube's file holds them, so that the
/// writer goes through its file front to back: band by band for BSQ, row by row (every
/// band) for BIL and BIP. Under a lens field of view, band by band whatever the interleave:
/// the camera keeps one `(angle, band)`'s per-column models at a time.
fn row_order(scene: &Scene, interleave: Interleave) -> Vec<(usize, usize)> {
    let (bands, h) = (scene.bands_nm.len(), scene.sensor.height);
    if interleave == Interleave::Bsq || scene.field_of_view.is_some() {
        (0..bands)
            .flat_map(|b| (0..h).map(move |r| (b, r)))
            .collect()
    } else {
        (0..h)
            .flat_map(|r| (0..bands).map(move |b| (b, r)))
            .collect()
    }
}

/// One job's rows of one angle, rendered: each row from its own seed, so the result is the
/// same on any thread and in any order.
struct RowBatch {
    kind: RowKind,
    width: usize,
    cube: Vec<f32>,
    white: Vec<f32>,
    dark: Vec<f32>,
}

impl RowBatch {
    fn new(kind: RowKind, width: usize, capacity: usize) -> Self {
        let refs = if kind == RowKind::Raw {
            capacity * width
        } else {
            0
        };
        Self {
            kind,
            width,
            cube: vec![0.0; capacity * width],
            white: vec![0.0; refs],
            dark: vec![0.0; refs],
        }
    }

    /// Renders `rows` (`(band, row)`s, at most the capacity) of angle `angle`.
    fn render(&mut self, camera: &SoftwareCamera, angle: usize, rows: &[(usize, usize)]) {
        let n = rows.len() * self.width;
        let (white, dark) = if self.kind == RowKind::Raw {
            (&mut self.white[..n], &mut self.dark[..n])
        } else {
            (&mut [][..], &mut [][..])
        };
        render_rows(
            camera,
            self.kind,
            angle,
            rows,
            &mut self.cube[..n],
            white,
            dark,
        );
    }

    fn cube_row(&self, k: usize) -> &[f32] {
        &self.cube[k * self.width..(k + 1) * self.width]
    }

    fn white_row(&self, k: usize) -> &[f32] {
        &self.white[k * self.width..(k + 1) * self.width]
    }

    fn dark_row(&self, k: usize) -> &[f32] {
        &self.dark[k * self.width..(k + 1) * self.width]
    }
}

/// The render jobs of `angles` angles whose rows are `order`: each angle's rows in runs of
/// `capacity`, angle after angle.
fn angle_jobs(
    order: &[(usize, usize)],
    angles: usize,
    capacity: usize,
) -> Vec<(usize, &[(usize, usize)])> {
    (0..angles)
        .flat_map(|a| order.chunks(capacity).map(move |part| (a, part)))
        .collect()
}

/// Renders `jobs` (each an angle and up to `capacity` of its `(band, row)`s) on `threads`
/// threads and hands each batch to `consume` on the calling thread, in job order, while the
/// threads go on with the jobs that follow. At most `threads * BATCHES_PER_THREAD` batches
/// exist at once. An error from `consume` stops the rendering and is returned.
fn render_in_order<E>(
    camera: &SoftwareCamera,
    kind: RowKind,
    jobs: &[(usize, &[(usize, usize)])],
    capacity: usize,
    threads: usize,
    mut consume: impl FnMut(usize, &RowBatch) -> Result<(), E>,
) -> Result<(), E> {
    let threads = threads.clamp(1, jobs.len().max(1));
    let batches = (threads * BATCHES_PER_THREAD).min(jobs.len());
    let (free_tx, free_rx) = crossbeam_channel::bounded::<RowBatch>(batches);
    for _ in 0..batches {
        // Cannot fail: the channel holds them all and its receiver is alive.
        let _ = free_tx.send(RowBatch::new(kind, camera.width(), capacity));
    }
    // `None`: a render thread panicked (its job will never come).
    let (done_tx, done_rx) = crossbeam_channel::bounded::<Option<(usize, RowBatch)>>(batches);
    let next = AtomicUsize::new(0);
    std::thread::scope(|s| {
        for _ in 0..threads {
            let (free_rx, next) = (free_rx.clone(), &next);
            let done = PanicNotice(done_tx.clone());
            s.spawn(move || {
                // A free batch first, then a job: the first job not yet handed over is then
                // always being rendered, whatever the batches waiting behind it.
                while let Ok(mut batch) = free_rx.recv() {
                    let j = next.fetch_add(1, Ordering::Relaxed);
                    let Some(&(angle, rows)) = jobs.get(j) else {
                        break;
                    };
                    batch.render(camera, angle, rows);
                    if done.0.send(Some((j, batch))).is_err() {
                        break;
                    }
                }
            });
        }
        drop((free_rx, done_tx));
        let mut waiting: BTreeMap<usize, RowBatch> = BTreeMap::new();
        let mut handed = || -> Result<(), E> {
            for j in 0..jobs.len() {
                let batch = loop {
                    if let Some(batch) = waiting.remove(&j) {
                        break batch;
                    }
                    match done_rx.recv() {
                        Ok(Some((k, batch))) => {
                            waiting.insert(k, batch);
                        }
                        // A thread panicked: the scope passes its panic on once the others
                        // have stopped.
                        Ok(None) | Err(_) => return Ok(()),
                    }
                };
                consume(j, &batch)?;
                let _ = free_tx.send(batch);
            }
            Ok(())
        };
        let result = handed();
        // Threads still rendering stop at their next hand-over.
        drop((free_tx, done_rx));
        result
    })
}

/// Held by a render thread: tells the writer if the thread panics, so that it stops waiting
/// for the thread's job.
struct PanicNotice(crossbeam_channel::Sender<Option<(usize, RowBatch)>>);

impl Drop for PanicNotice {
    fn drop(&mut self) {
        if std::thread::panicking() {
            let _ = self.0.send(None);
        }
    }
}

/// Renders `rows` of angle `angle` into consecutive rows of `cube` (and, for raw counts, of
/// `white` and `dark`).
fn render_rows(
    camera: &SoftwareCamera,
    kind: RowKind,
    angle: usize,
    rows: &[(usize, usize)],
    cube: &mut [f32],
    white: &mut [f32],
    dark: &mut [f32],
) {
    let w = camera.width();
    let mut raw16 = vec![0u16; w];
    let (mut wb, mut db) = (vec![0f32; w], vec![0f32; w]);
    for (k, &(b, r)) in rows.iter().enumerate() {
        let out = &mut cube[k * w..(k + 1) * w];
        match kind {
            RowKind::NoiseFree => camera.reflectance_row(angle, b, r, out),
            RowKind::FloatReflectance => {
                camera.raw_row(angle, b, r, &mut raw16);
                camera.white_row(angle, b, r, &mut wb);
                camera.dark_row(angle, b, r, &mut db);
                for (((o, &c), &wh), &dk) in out.iter_mut().zip(&raw16).zip(&wb).zip(&db) {
                    let span = wh - dk;
                    *o = if span > 0.0 {
                        (f32::from(c) - dk) / span
                    } else {
                        f32::NAN
                    };
                }
            }
            RowKind::Raw => {
                camera.raw_row(angle, b, r, &mut raw16);
                for (o, &c) in out.iter_mut().zip(&raw16) {
                    *o = f32::from(c);
                }
                camera.white_row(angle, b, r, &mut white[k * w..(k + 1) * w]);
                camera.dark_row(angle, b, r, &mut dark[k * w..(k + 1) * w]);
            }
        }
    }
}

/// Samples per second the software camera renders a raw capture of `scene` at (its first
/// `rows` rows, every angle and band; each sample's white and dark reference samples
/// rendered with it, as `filmscope simulate` does), on every core and without writing; the
/// camera's preparation (its band models and tables) counted in.
pub fn camera_samples_per_s(scene: &Scene, rows: usize) -> f64 {
    let t0 = std::time::Instant::now();
    let camera = SoftwareCamera::new(scene.clone());
    let (w, rows) = (camera.width(), rows.clamp(1, camera.height()));
    let order: Vec<(usize, usize)> = (0..rows)
        .flat_map(|r| (0..scene.bands_nm.len()).map(move |b| (b, r)))
        .collect();
    let capacity = job_rows(w);
    let jobs = angle_jobs(&order, scene.angles_deg.len(), capacity);
    let Ok(()) = render_in_order(
        &camera,
        RowKind::Raw,
        &jobs,
        capacity,
        render_threads(),
        |_, batch| {
            std::hint::black_box(&batch.cube);
            Ok::<(), std::convert::Infallible>(())
        },
    );
    (order.len() * scene.angles_deg.len() * w) as f64 / t0.elapsed().as_secs_f64()
}

/// One angle's files while its rows are written: the cube and, for raw counts, the white
/// and dark references.
struct AngleFiles {
    cube: (PathBuf, EnviWriter),
    refs: Option<[(PathBuf, EnviWriter); 2]>,
}

impl AngleFiles {
    /// Writes row `k` of `batch` as band row `(band, row)`.
    fn write(
        &mut self,
        band: usize,
        row: usize,
        batch: &RowBatch,
        k: usize,
    ) -> Result<(), SimulateError> {
        let (path, cube) = &mut self.cube;
        cube.write_band_row(band, row, batch.cube_row(k))
            .map_err(|e| path_err(path, e))?;
        if let Some([(white_path, white), (dark_path, dark)]) = self.refs.as_mut() {
            white
                .write_band_row(band, row, batch.white_row(k))
                .map_err(|e| path_err(white_path, e))?;
            dark.write_band_row(band, row, batch.dark_row(k))
                .map_err(|e| path_err(dark_path, e))?;
        }
        Ok(())
    }

    /// Writes the headers and renames every file into place (the data flushed to disk
    /// first).
    fn finish(self) -> Result<(), SimulateError> {
        let (path, cube) = self.cube;
        cube.finish().map_err(|e| path_err(&path, e))?;
        for (path, writer) in self.refs.into_iter().flatten() {
            writer.finish().map_err(|e| path_err(&path, e))?;
        }
        Ok(())
    }
}

fn path_err(p: &Path, e: impl Into<Box<dyn std::error::Error + Send + Sync>>) -> SimulateError {
    SimulateError::File {
        path: p.to_owned(),
        cause: e.into(),
    }
}

/// Writes `scene` as a capture in `out_dir` (created if needed); returns the capture.toml
/// path. `on_rows` is told of every band row written (for a progress bar). Rows are
/// rendered on every core, in jobs written in each cube's file order while the following
/// jobs render; an angle's files are flushed and renamed into place on a thread of their
/// own while the next angle is written.
pub fn write_capture(
    scene: &Scene,
    out_dir: &Path,
    opts: SimulateOptions,
    on_rows: &dyn Fn(u64),
) -> Result<PathBuf, SimulateError> {
    std::fs::create_dir_all(out_dir.join("truth")).map_err(|e| path_err(out_dir, e))?;
    let camera = SoftwareCamera::new(scene.clone());
    let (w, h) = (camera.width(), camera.height());
    let kind = if opts.noise_free {
        RowKind::NoiseFree
    } else if opts.float_reflectance {
        RowKind::FloatReflectance
    } else {
        RowKind::Raw
    };
    let mut angles = Vec::new();
    let mut files = Vec::new();
    for &deg in &scene.angles_deg {
        let (angle, angle_files) = AngleFiles::create(scene, out_dir, opts, kind, deg)?;
        angles.push(angle);
        files.push(Some(angle_files));
    }
    write_cubes(&camera, kind, opts.interleave, files, on_rows)?;
    let truth_map = out_dir.join("truth").join("thickness_nm.hdr");
    write_f32_map(
        &truth_map,
        w,
        h,
        &scene.thickness_nm,
        Some("true film thickness, nm"),
        &[],
    )
    .map_err(|e| path_err(&truth_map, e))?;
    let toml_path = out_dir.join("capture.toml");
    let capture = Capture {
        path: toml_path.clone(),
        sample: Sample {
            ambient_index: scene.stack.ambient_index,
            substrate_index: scene.stack.substrate.index_at(550.0),
            substrate: write_substrate(scene, out_dir)?,
            polarization: scene.stack.polarization,
            back_face: scene.stack.back_face,
        },
        search: Search {
            index_range: scene.index_range,
            thickness_range_nm: scene.thickness_range_nm,
        },
        lens: Lens {
            horizontal_fov_deg: scene.field_of_view.map(|f| f.horizontal_deg()),
        },
        angles,
        fit: Default::default(),
        unknown_keys: Vec::new(),
    };
    capture.write_toml(&toml_path)?;
    truth_record(scene, opts, w, h).write(out_dir)?;
    Ok(toml_path)
}

impl AngleFiles {
    /// Creates the files of the angle at `deg` (`aNN.hdr`, and for raw counts `whiteNN.hdr`
    /// and `darkNN.hdr`) and the capture's entry for it.
    fn create(
        scene: &Scene,
        out_dir: &Path,
        opts: SimulateOptions,
        kind: RowKind,
        deg: f64,
    ) -> Result<(Angle, Self), SimulateError> {
        let tag = format!("{:02}", deg.round() as i64);
        let cube_path = out_dir.join(format!("a{tag}.hdr"));
        let desc = format!("filmscope simulate: {} at {deg} deg", scene.name);
        let data_type = match kind {
            RowKind::Raw => DataType::U16,
            RowKind::NoiseFree | RowKind::FloatReflectance => DataType::F32,
        };
        let mut hd = header(scene, data_type, opts, &desc);
        if kind == RowKind::Raw {
            let sat = format!("{}", scene.sensor.saturation_counts());
            hd.extra.push(("saturation counts".into(), sat));
        }
        let cube = EnviWriter::create(&cube_path, &hd).map_err(|e| path_err(&cube_path, e))?;
        let reference = |name: &str| {
            let path = out_dir.join(format!("{name}{tag}.hdr"));
            let desc = format!("{name} reference (averaged counts)");
            let href = header(scene, DataType::F32, opts, &desc);
            let writer = EnviWriter::create(&path, &href).map_err(|e| path_err(&path, e))?;
            Ok::<_, SimulateError>((path, writer))
        };
        let refs = if kind == RowKind::Raw {
            Some([reference("white")?, reference("dark")?])
        } else {
            None
        };
        let ref_path = |k: usize| refs.as_ref().map(|r| r[k].0.clone());
        let angle = Angle {
            incidence_deg: deg,
            cube: cube_path.clone(),
            white: ref_path(0),
            dark: ref_path(1),
            white_reflectance: 1.0,
        };
        Ok((
            angle,
            Self {
                cube: (cube_path, cube),
                refs,
            },
        ))
    }
}

/// Renders every angle's rows into `files` (one per angle, in the scene's order), in the
/// cubes' file order for `interleave`, finishing each angle's files on a thread of its own
/// once its last row is written. Every angle's files are finished (or, after an error,
/// their temporary files removed) before this returns.
fn write_cubes(
    camera: &SoftwareCamera,
    kind: RowKind,
    interleave: Interleave,
    mut files: Vec<Option<AngleFiles>>,
    on_rows: &dyn Fn(u64),
) -> Result<(), SimulateError> {
    let scene = camera.scene();
    let order = row_order(scene, interleave);
    let capacity = job_rows(camera.width());
    let per_angle = order.len().div_ceil(capacity);
    let jobs = angle_jobs(&order, scene.angles_deg.len(), capacity);
    let mut finishing = Vec::new();
    let written: Result<(), SimulateError> = render_in_order(
        camera,
        kind,
        &jobs,
        capacity,
        render_threads(),
        |j, batch| {
            let (a, rows) = jobs[j];
            let angle = files[a].as_mut().ok_or(SimulateError::AngleAfterEnd(a))?;
            for (k, &(b, r)) in rows.iter().enumerate() {
                angle.write(b, r, batch, k)?;
            }
            on_rows(rows.len() as u64);
            if (j + 1) % per_angle == 0 {
                if let Some(done) = files[a].take() {
                    finishing.push(std::thread::spawn(move || done.finish()));
                }
            }
            Ok(())
        },
    );
    let finished: Vec<Result<(), SimulateError>> = finishing
        .into_iter()
        .map(|t| t.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
        .collect();
    written?;
    finished.into_iter().collect::<Result<(), _>>()?;
    // Angles without rows (a scene without bands or rows) have nothing to wait for.
    for angle in files.into_iter().flatten() {
        angle.finish()?;
    }
    Ok(())
}

/// A dispersive substrate travels with the capture as a refractiveindex.info entry
/// (`substrate.yml` in `out_dir`, written here); a constant one needs none.
fn write_substrate(
    scene: &Scene,
    out_dir: &Path,
) -> Result<Option<crate::io::SubstrateMaterial>, SimulateError> {
    if scene.stack.substrate.is_constant() {
        return Ok(None);
    }
    let name = "substrate.yml";
    let path = out_dir.join(name);
    let text = crate::material::to_rii_yaml(
        &scene.stack.substrate,
        [
            scene.bands_nm.first().copied().unwrap_or(380.0),
            scene.bands_nm.last().copied().unwrap_or(780.0),
        ],
        &format!("substrate of scene {}", scene.name),
    );
    write_atomic(&path, text.as_bytes()).map_err(|e| path_err(&path, e))?;
    Ok(Some(crate::io::SubstrateMaterial {
        name: name.into(),
        dispersion: scene.stack.substrate,
    }))
}

/// What `truth.json` says of the scene a `w` x `h` capture was simulated from.
fn truth_record(scene: &Scene, opts: SimulateOptions, w: usize, h: usize) -> TruthRecord {
    TruthRecord {
        scene: scene.name.clone(),
        description: scene.description.clone(),
        refractive_index: scene.stack.film.index_at(550.0),
        dispersion: DispersionRecord::dispersive(&scene.stack.film),
        substrate_index: scene.stack.substrate.index_at(550.0),
        substrate_dispersion: DispersionRecord::dispersive(&scene.stack.substrate),
        ambient_index: scene.stack.ambient_index,
        polarization: scene.stack.polarization.into(),
        back_face: if scene.imperfections.bare_back_face {
            BackFace::Bare
        } else {
            BackFace::None
        }
        .into(),
        angles_deg: scene.angles_deg.clone(),
        noise_free: opts.noise_free,
        thickness_map: "truth/thickness_nm.hdr".into(),
        width: w,
        height: h,
        // Only a scene with a lens says so.
        horizontal_fov_deg: scene.field_of_view.map(|f| f.horizontal_deg()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tiny rig scene and its camera.
    fn tiny() -> (Scene, SoftwareCamera) {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/scenes/rig-tiny.toml");
        let scene = Scene::load(Path::new(path)).expect("scene");
        let camera = SoftwareCamera::new(scene.clone());
        (scene, camera)
    }

    /// Rows rendered on one thread, on three, and one by one through the camera's own
    /// calls are the same bits, handed over in job order: every row has its own seed.
    #[test]
    fn batches_are_the_same_on_any_number_of_threads() {
        let (scene, camera) = tiny();
        let w = camera.width();
        let order = row_order(&scene, Interleave::Bil);
        let rows = &order[..order.len().min(40)];
        let jobs: Vec<(usize, &[(usize, usize)])> = rows.chunks(3).map(|part| (1, part)).collect();
        let render = |threads| {
            let (mut cube, mut white, mut dark) = (Vec::new(), Vec::new(), Vec::new());
            let mut seen = Vec::new();
            render_in_order(&camera, RowKind::Raw, &jobs, 3, threads, |j, batch| {
                seen.push(j);
                for k in 0..jobs[j].1.len() {
                    cube.extend_from_slice(batch.cube_row(k));
                    white.extend_from_slice(batch.white_row(k));
                    dark.extend_from_slice(batch.dark_row(k));
                }
                Ok::<(), ()>(())
            })
            .expect("rendered");
            assert_eq!(seen, (0..jobs.len()).collect::<Vec<_>>());
            (cube, white, dark)
        };
        let (one, three) = (render(1), render(3));
        assert!(one == three, "one thread and three differ");
        let (mut raw, mut white, mut dark) = (vec![0u16; w], vec![0f32; w], vec![0f32; w]);
        for (k, &(b, r)) in rows.iter().enumerate() {
            camera.raw_row(1, b, r, &mut raw);
            camera.white_row(1, b, r, &mut white);
            camera.dark_row(1, b, r, &mut dark);
            let counts: Vec<f32> = raw.iter().map(|&c| f32::from(c)).collect();
            assert_eq!(&one.0[k * w..(k + 1) * w], &counts[..]);
            assert_eq!(&one.1[k * w..(k + 1) * w], &white[..]);
            assert_eq!(&one.2[k * w..(k + 1) * w], &dark[..]);
        }
    }

    /// An error from the consumer stops the rendering and comes back; the threads end.
    #[test]
    fn a_failing_consumer_stops_the_rendering() {
        let (scene, camera) = tiny();
        let order = row_order(&scene, Interleave::Bil);
        let jobs: Vec<(usize, &[(usize, usize)])> = order.chunks(2).map(|p| (0, p)).collect();
        let mut calls = 0;
        let got = render_in_order(&camera, RowKind::Raw, &jobs, 2, 2, |j, _| {
            calls += 1;
            if j == 3 {
                Err(j)
            } else {
                Ok(())
            }
        });
        assert_eq!(got, Err(3));
        assert_eq!(calls, 4);
    }

    /// A render thread that panics passes its panic on instead of leaving the writer
    /// waiting for its job.
    #[test]
    fn a_panicking_render_thread_panics_the_caller() {
        let (scene, camera) = tiny();
        let order = row_order(&scene, Interleave::Bil);
        // A row beyond the sensor: the camera panics on it.
        let bad = [(0, scene.sensor.height + 5)];
        let mut jobs: Vec<(usize, &[(usize, usize)])> = order.chunks(2).map(|p| (0, p)).collect();
        jobs.insert(3, (0, &bad[..]));
        let got = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            render_in_order(&camera, RowKind::Raw, &jobs, 2, 2, |_, _| Ok::<(), ()>(()))
        }));
        assert!(got.is_err());
    }
}
