//! `filmscope simulate`: writes a scene as a capture directory per capture-format.md, with
//! its truth beside it.
//!
//! Layout: `capture.toml`; per angle `aNN.hdr/.img` (raw 12-bit counts as uint16, BIL, with
//! `whiteNN` and `darkNN` float32 references averaged over the scene's `white_frames`), or,
//! noise-free or as [`SimulateOptions::float_reflectance`], float32 reflectance without
//! references; any interleave and byte order; `truth/thickness_nm.hdr/.img` and
//! `truth.json`. A scene with a lens field of view writes it as `[lens] horizontal_fov_deg`
//! (filmscope's extension of the capture format).

use std::path::{Path, PathBuf};

use firmware_sim::{Scene, SoftwareCamera};
use serde_json::json;

use crate::io::{
    write_atomic, write_f32_map, Angle, ByteOrder, Capture, DataType, EnviHeader, EnviWriter,
    Interleave, Lens, Sample, Search,
};
use crate::material::DispersionRecord;

/// A capture that could not be written, with the file at fault.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct SimulateError(pub String);

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

/// Rows rendered per batch: about a million samples, at least one row per thread.
fn batch_rows(width: usize, threads: usize) -> usize {
    ((1 << 20) / width.max(1)).max(threads)
}

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

/// A batch of one angle's rows rendered on several threads: each row is rendered from its
/// own seed, so the result is the same on any number of threads.
struct RowBatch {
    kind: RowKind,
    width: usize,
    capacity: usize,
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
            capacity,
            cube: vec![0.0; capacity * width],
            white: vec![0.0; refs],
            dark: vec![0.0; refs],
        }
    }

    fn capacity(&self) -> usize {
        self.capacity
    }

    /// Renders `rows` (`(band, row)`s, at most `capacity`) of angle `angle`.
    fn render(
        &mut self,
        camera: &SoftwareCamera,
        angle: usize,
        rows: &[(usize, usize)],
        threads: usize,
    ) {
        let (w, kind) = (self.width, self.kind);
        let per_thread = rows.len().div_ceil(threads.max(1)).max(1);
        let span = per_thread * w;
        let refs = kind == RowKind::Raw;
        let mut whites = self.white.chunks_mut(span);
        let mut darks = self.dark.chunks_mut(span);
        std::thread::scope(|s| {
            for (part, cube) in rows.chunks(per_thread).zip(self.cube.chunks_mut(span)) {
                let (white, dark) = if refs {
                    (
                        whites.next().unwrap_or_default(),
                        darks.next().unwrap_or_default(),
                    )
                } else {
                    (Default::default(), Default::default())
                };
                s.spawn(move || render_rows(camera, kind, angle, part, cube, white, dark));
            }
        });
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
    let threads = render_threads();
    let (w, rows) = (camera.width(), rows.clamp(1, camera.height()));
    let order: Vec<(usize, usize)> = (0..rows)
        .flat_map(|r| (0..scene.bands_nm.len()).map(move |b| (b, r)))
        .collect();
    let mut batch = RowBatch::new(RowKind::Raw, w, batch_rows(w, threads));
    for a in 0..scene.angles_deg.len() {
        for part in order.chunks(batch.capacity()) {
            batch.render(&camera, a, part, threads);
            std::hint::black_box(&batch.cube);
        }
    }
    (order.len() * scene.angles_deg.len() * w) as f64 / t0.elapsed().as_secs_f64()
}

/// Writes `scene` as a capture in `out_dir` (created if needed); returns the capture.toml
/// path. `on_rows` is told of every band row written (for a progress bar). Rows are
/// rendered on every core, in batches, and written in each cube's file order.
pub fn write_capture(
    scene: &Scene,
    out_dir: &Path,
    opts: SimulateOptions,
    on_rows: &dyn Fn(u64),
) -> Result<PathBuf, SimulateError> {
    let err = |p: &Path, e: &dyn std::fmt::Display| SimulateError(format!("{}: {e}", p.display()));
    std::fs::create_dir_all(out_dir.join("truth")).map_err(|e| err(out_dir, &e))?;
    let camera = SoftwareCamera::new(scene.clone());
    let (w, h) = (camera.width(), camera.height());
    let kind = if opts.noise_free {
        RowKind::NoiseFree
    } else if opts.float_reflectance {
        RowKind::FloatReflectance
    } else {
        RowKind::Raw
    };
    let threads = render_threads();
    let mut angles = Vec::new();
    let sat = format!("{}", scene.sensor.saturation_counts());
    for (a, &deg) in scene.angles_deg.iter().enumerate() {
        let tag = format!("{:02}", deg.round() as i64);
        let cube_path = out_dir.join(format!("a{tag}.hdr"));
        let desc = format!("filmscope simulate: {} at {deg} deg", scene.name);
        let data_type = match kind {
            RowKind::Raw => DataType::U16,
            RowKind::NoiseFree | RowKind::FloatReflectance => DataType::F32,
        };
        let mut hd = header(scene, data_type, opts, &desc);
        if kind == RowKind::Raw {
            hd.extra.push(("saturation counts".into(), sat.clone()));
        }
        let mut cube = EnviWriter::create(&cube_path, &hd).map_err(|e| err(&cube_path, &e))?;
        let white_path = out_dir.join(format!("white{tag}.hdr"));
        let dark_path = out_dir.join(format!("dark{tag}.hdr"));
        let mut refs = if kind == RowKind::Raw {
            let href = header(
                scene,
                DataType::F32,
                opts,
                "white reference (averaged counts)",
            );
            let dref = header(
                scene,
                DataType::F32,
                opts,
                "dark reference (averaged counts)",
            );
            Some((
                EnviWriter::create(&white_path, &href).map_err(|e| err(&white_path, &e))?,
                EnviWriter::create(&dark_path, &dref).map_err(|e| err(&dark_path, &e))?,
            ))
        } else {
            None
        };
        let order = row_order(scene, opts.interleave);
        let capacity = batch_rows(w, threads);
        let parts: Vec<&[(usize, usize)]> = order.chunks(capacity).collect();
        // Two batches: while one is written, the next is rendered.
        let mut ready = RowBatch::new(kind, w, capacity);
        let mut next = RowBatch::new(kind, w, capacity);
        if let Some(first) = parts.first() {
            ready.render(&camera, a, first, threads);
        }
        for (i, rows) in parts.iter().enumerate() {
            let written = std::thread::scope(|s| {
                if let Some(following) = parts.get(i + 1) {
                    let (camera, next) = (&camera, &mut next);
                    s.spawn(move || next.render(camera, a, following, threads));
                }
                for (k, &(b, r)) in rows.iter().enumerate() {
                    cube.write_band_row(b, r, ready.cube_row(k))
                        .map_err(|e| err(&cube_path, &e))?;
                    if let Some((white, dark)) = refs.as_mut() {
                        white
                            .write_band_row(b, r, ready.white_row(k))
                            .map_err(|e| err(&white_path, &e))?;
                        dark.write_band_row(b, r, ready.dark_row(k))
                            .map_err(|e| err(&dark_path, &e))?;
                    }
                }
                Ok::<(), SimulateError>(())
            });
            written?;
            std::mem::swap(&mut ready, &mut next);
            on_rows(rows.len() as u64);
        }
        cube.finish().map_err(|e| err(&cube_path, &e))?;
        let (white, dark) = match refs {
            Some((white, dark)) => {
                white.finish().map_err(|e| err(&white_path, &e))?;
                dark.finish().map_err(|e| err(&dark_path, &e))?;
                (Some(white_path), Some(dark_path))
            }
            None => (None, None),
        };
        angles.push(Angle {
            incidence_deg: deg,
            cube: cube_path,
            white,
            dark,
            white_reflectance: 1.0,
        });
    }
    let truth_map = out_dir.join("truth").join("thickness_nm.hdr");
    write_f32_map(
        &truth_map,
        w,
        h,
        &scene.thickness_nm,
        Some("true film thickness, nm"),
        &[],
    )
    .map_err(|e| err(&truth_map, &e))?;
    let toml_path = out_dir.join("capture.toml");
    // A dispersive substrate travels with the capture as a refractiveindex.info entry.
    let substrate = if scene.stack.substrate.is_constant() {
        None
    } else {
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
        write_atomic(&path, text.as_bytes()).map_err(|e| err(&path, &e))?;
        Some(crate::io::SubstrateMaterial {
            name: name.into(),
            dispersion: scene.stack.substrate,
        })
    };
    let capture = Capture {
        path: toml_path.clone(),
        sample: Sample {
            ambient_index: scene.stack.ambient_index,
            substrate_index: scene.stack.substrate.index_at(550.0),
            substrate,
            polarization: scene.stack.polarization,
        },
        search: Search {
            index_range: scene.index_range,
            thickness_range_nm: scene.thickness_range_nm,
        },
        lens: Lens {
            horizontal_fov_deg: scene.field_of_view.map(|f| f.horizontal_deg()),
        },
        angles,
        unknown_keys: Vec::new(),
    };
    capture
        .write_toml(&toml_path)
        .map_err(|e| SimulateError(e.to_string()))?;
    let truth = json!({
        "scene": scene.name,
        "description": scene.description,
        "refractive_index": scene.stack.film.index_at(550.0),
        "dispersion": DispersionRecord::dispersive(&scene.stack.film),
        "substrate_index": scene.stack.substrate.index_at(550.0),
        "substrate_dispersion": DispersionRecord::dispersive(&scene.stack.substrate),
        "ambient_index": scene.stack.ambient_index,
        "polarization": scene.stack.polarization.name(),
        "angles_deg": scene.angles_deg,
        "noise_free": opts.noise_free,
        "thickness_map": "truth/thickness_nm.hdr",
        "width": w,
        "height": h,
    });
    // Only a scene with a lens says so: other truths stay as they were.
    let truth = match (truth, scene.field_of_view) {
        (serde_json::Value::Object(mut o), Some(fov)) => {
            o.insert("horizontal_fov_deg".into(), json!(fov.horizontal_deg()));
            serde_json::Value::Object(o)
        }
        (t, _) => t,
    };
    let truth_path = out_dir.join("truth.json");
    let text = serde_json::to_string_pretty(&truth).map_err(|e| err(&truth_path, &e))?;
    write_atomic(&truth_path, text.as_bytes()).map_err(|e| err(&truth_path, &e))?;
    Ok(toml_path)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rows rendered on one thread, on three, and one by one through the camera's own
    /// calls are the same bits: every row has its own seed.
    #[test]
    fn batches_are_the_same_on_any_number_of_threads() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/scenes/rig-tiny.toml");
        let scene = Scene::load(Path::new(path)).expect("scene");
        let camera = SoftwareCamera::new(scene.clone());
        let w = camera.width();
        let order = row_order(&scene, Interleave::Bil);
        let rows = &order[..order.len().min(40)];
        let render = |threads| {
            let mut batch = RowBatch::new(RowKind::Raw, w, rows.len());
            batch.render(&camera, 1, rows, threads);
            batch
        };
        let (one, three) = (render(1), render(3));
        assert_eq!(one.cube, three.cube);
        assert_eq!(one.white, three.white);
        assert_eq!(one.dark, three.dark);
        let (mut raw, mut white, mut dark) = (vec![0u16; w], vec![0f32; w], vec![0f32; w]);
        for (k, &(b, r)) in rows.iter().enumerate() {
            camera.raw_row(1, b, r, &mut raw);
            camera.white_row(1, b, r, &mut white);
            camera.dark_row(1, b, r, &mut dark);
            let counts: Vec<f32> = raw.iter().map(|&c| f32::from(c)).collect();
            assert_eq!(one.cube_row(k), &counts[..]);
            assert_eq!(one.white_row(k), &white[..]);
            assert_eq!(one.dark_row(k), &dark[..]);
        }
    }
}
