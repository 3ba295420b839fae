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

use filmscope_core::optics::Dispersion;
use firmware_sim::{Scene, SoftwareCamera};
use serde_json::json;

use crate::io::{
    write_atomic, write_f32_map, Angle, ByteOrder, Capture, DataType, EnviHeader, EnviWriter,
    Interleave, Lens, Sample, Search,
};

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

/// The dispersion of a film as written in `truth.json` and `summary.json`.
pub fn dispersion_json(d: &Dispersion) -> serde_json::Value {
    match *d {
        Dispersion::Constant { .. } => serde_json::Value::Null,
        Dispersion::Cauchy { a, b_um2, c_um4 } => {
            if c_um4 == 0.0 {
                json!({"model": "cauchy", "a": a, "b_um2": b_um2})
            } else {
                json!({"model": "cauchy", "a": a, "b_um2": b_um2, "c_um4": c_um4})
            }
        }
        Dispersion::Sellmeier { a, b, c_um } => {
            json!({"model": "sellmeier", "a": a, "b": b, "c_um": c_um})
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

/// Writes `scene` as a capture in `out_dir` (created if needed); returns the capture.toml
/// path. `on_rows` is told of every band row written (for a progress bar).
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
    let bands = scene.bands_nm.len();
    let mut angles = Vec::new();
    let mut raw16 = vec![0u16; w];
    let mut row = vec![0f32; w];
    let sat = format!("{}", scene.sensor.saturation_counts());
    for (a, &deg) in scene.angles_deg.iter().enumerate() {
        let tag = format!("{:02}", deg.round() as i64);
        let cube_path = out_dir.join(format!("a{tag}.hdr"));
        let desc = format!("filmscope simulate: {} at {deg} deg", scene.name);
        if opts.noise_free {
            let hd = header(scene, DataType::F32, opts, &desc);
            let mut cube = EnviWriter::create(&cube_path, &hd).map_err(|e| err(&cube_path, &e))?;
            for b in 0..bands {
                for r in 0..h {
                    camera.reflectance_row(a, b, r, &mut row);
                    cube.write_band_row(b, r, &row)
                        .map_err(|e| err(&cube_path, &e))?;
                    on_rows(1);
                }
            }
            cube.finish().map_err(|e| err(&cube_path, &e))?;
            angles.push(Angle {
                incidence_deg: deg,
                cube: cube_path,
                white: None,
                dark: None,
                white_reflectance: 1.0,
            });
        } else if opts.float_reflectance {
            let hd = header(scene, DataType::F32, opts, &desc);
            let mut cube = EnviWriter::create(&cube_path, &hd).map_err(|e| err(&cube_path, &e))?;
            let (mut white, mut dark) = (vec![0f32; w], vec![0f32; w]);
            for b in 0..bands {
                for r in 0..h {
                    camera.raw_row(a, b, r, &mut raw16);
                    camera.white_row(a, b, r, &mut white);
                    camera.dark_row(a, b, r, &mut dark);
                    for (((o, &c), &wh), &dk) in row.iter_mut().zip(&raw16).zip(&white).zip(&dark) {
                        let span = wh - dk;
                        *o = if span > 0.0 {
                            (f32::from(c) - dk) / span
                        } else {
                            f32::NAN
                        };
                    }
                    cube.write_band_row(b, r, &row)
                        .map_err(|e| err(&cube_path, &e))?;
                    on_rows(1);
                }
            }
            cube.finish().map_err(|e| err(&cube_path, &e))?;
            angles.push(Angle {
                incidence_deg: deg,
                cube: cube_path,
                white: None,
                dark: None,
                white_reflectance: 1.0,
            });
        } else {
            let mut hd = header(scene, DataType::U16, opts, &desc);
            hd.extra.push(("saturation counts".into(), sat.clone()));
            let white_path = out_dir.join(format!("white{tag}.hdr"));
            let dark_path = out_dir.join(format!("dark{tag}.hdr"));
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
            let mut cube = EnviWriter::create(&cube_path, &hd).map_err(|e| err(&cube_path, &e))?;
            let mut white =
                EnviWriter::create(&white_path, &href).map_err(|e| err(&white_path, &e))?;
            let mut dark =
                EnviWriter::create(&dark_path, &dref).map_err(|e| err(&dark_path, &e))?;
            for b in 0..bands {
                for r in 0..h {
                    camera.raw_row(a, b, r, &mut raw16);
                    for (o, &c) in row.iter_mut().zip(&raw16) {
                        *o = f32::from(c);
                    }
                    cube.write_band_row(b, r, &row)
                        .map_err(|e| err(&cube_path, &e))?;
                    camera.white_row(a, b, r, &mut row);
                    white
                        .write_band_row(b, r, &row)
                        .map_err(|e| err(&white_path, &e))?;
                    camera.dark_row(a, b, r, &mut row);
                    dark.write_band_row(b, r, &row)
                        .map_err(|e| err(&dark_path, &e))?;
                    on_rows(1);
                }
            }
            cube.finish().map_err(|e| err(&cube_path, &e))?;
            white.finish().map_err(|e| err(&white_path, &e))?;
            dark.finish().map_err(|e| err(&dark_path, &e))?;
            angles.push(Angle {
                incidence_deg: deg,
                cube: cube_path,
                white: Some(white_path),
                dark: Some(dark_path),
                white_reflectance: 1.0,
            });
        }
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
        "dispersion": dispersion_json(&scene.stack.film),
        "substrate_index": scene.stack.substrate.index_at(550.0),
        "substrate_dispersion": dispersion_json(&scene.stack.substrate),
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
