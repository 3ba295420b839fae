//! The maps, previews, index files and `summary.json` a run writes (docs/capture-format.md).

use std::collections::BTreeMap;
use std::path::Path;

use filmscope_core::solve::flags;
use filmscope_core::solve::shard::MAX_THICKNESS_SIGMA_NM;

use crate::export::png::{write_map_png, MapPreview};
use crate::io::{write_atomic, write_f32_map, DataType, EnviHeader, EnviWriter, Interleave};

use crate::estimate::method::MethodResult;
use crate::summary::{Files, IndexRecord, SampleRecord, SigmaStats, Stats, Summary, Timing};

use super::passes::index_model_name;
use super::run::Run;

/// The thickness uncertainty of the reported (valid) pixels: statistics, the 90th
/// percentile and the limit above which a pixel is flagged `imprecise`.
fn sigma_summary(r: &MethodResult) -> SigmaStats {
    let mut valid: Vec<f32> = r
        .thickness_sigma_nm
        .iter()
        .zip(&r.thickness_nm)
        .filter(|(s, d)| s.is_finite() && d.is_finite())
        .map(|(&s, _)| s)
        .collect();
    let stats = Stats::of(&valid);
    valid.sort_by(f32::total_cmp);
    let p90 = valid
        .get((valid.len() * 9).div_ceil(10).saturating_sub(1))
        .map(|&x| f64::from(x));
    SigmaStats {
        stats,
        p90,
        imprecise_above: MAX_THICKNESS_SIGMA_NM,
    }
}

/// Counts of each flag over the map.
pub fn flag_counts(map: &[u16]) -> BTreeMap<String, u64> {
    flags::NAMES
        .iter()
        .map(|&(bit, name)| {
            let n = map.iter().filter(|&&f| f & bit != 0).count();
            (name.to_owned(), n as u64)
        })
        .collect()
}

/// An output that could not be written, naming the file.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// A map, preview or index file.
    #[error("{}: {cause}", .path.display())]
    File {
        /// The file.
        path: std::path::PathBuf,
        /// Why (a cube writer's, the PNG encoder's or the system's error; in the message,
        /// not a source: one line, said once).
        cause: Box<dyn std::error::Error + Send + Sync>,
    },
    /// `summary.json`.
    #[error(transparent)]
    Summary(#[from] crate::record::RecordError),
}

/// Writes the maps, the preview and `summary.json` into the existing folder `dir` (a
/// staging folder of [`crate::io::OutputDir`], opened by a job: [`crate::jobs`]). Returns
/// the summary.
pub fn write_outputs_into(
    dir: &Path,
    run: &Run,
    source_label: &str,
) -> Result<Summary, OutputError> {
    write_maps(dir, run)?;
    write_flags(dir, run)?;
    write_preview(dir, run)?;
    let index_files = write_index_files(dir, run, source_label)?;
    let summary = summary_of(run, source_label, index_files);
    summary.write(dir)?;
    Ok(summary)
}

/// The error of writing the file `p`.
fn path_err(p: &Path, e: impl Into<Box<dyn std::error::Error + Send + Sync>>) -> OutputError {
    OutputError::File {
        path: p.to_owned(),
        cause: e.into(),
    }
}

/// Writes the float maps: thickness, confidence and thickness sigma.
fn write_maps(dir: &Path, run: &Run) -> Result<(), OutputError> {
    let (w, h) = (run.spec.width, run.spec.height);
    let r = &run.result;
    let thick = dir.join("thickness_nm.hdr");
    write_f32_map(
        &thick,
        w,
        h,
        &r.thickness_nm,
        Some("film thickness, nm (NaN: no reliable estimate)"),
        &[],
    )
    .map_err(|e| path_err(&thick, e))?;
    let conf = dir.join("confidence.hdr");
    write_f32_map(
        &conf,
        w,
        h,
        &r.confidence,
        Some("confidence of the thickness, 0..1"),
        &[],
    )
    .map_err(|e| path_err(&conf, e))?;
    let sigma = dir.join("thickness_sigma_nm.hdr");
    write_f32_map(
        &sigma,
        w,
        h,
        &r.thickness_sigma_nm,
        Some(&format!(
            "1-sigma thickness uncertainty from the pixel's own full-spectrum fit and the shared index's covariance, nm; given for flagged pixels too (above {MAX_THICKNESS_SIGMA_NM} nm: flag imprecise); NaN: no fit"
        )),
        &[],
    )
    .map_err(|e| path_err(&sigma, e))?;
    Ok(())
}

/// Writes the flag map, `flags.hdr`, its header naming each bit.
fn write_flags(dir: &Path, run: &Run) -> Result<(), OutputError> {
    let (w, h) = (run.spec.width, run.spec.height);
    let flags_path = dir.join("flags.hdr");
    let mut fh = EnviHeader::new(w, h, 1, DataType::U16, Interleave::Bsq);
    let names: Vec<String> = flags::NAMES
        .iter()
        .map(|(b, n)| format!("{b}={n}"))
        .collect();
    fh.description = Some(format!("filmscope pixel flags (bits): {}", names.join(" ")));
    let mut fw = EnviWriter::create(&flags_path, &fh).map_err(|e| path_err(&flags_path, e))?;
    for row in 0..h {
        let vals: Vec<f32> = run.result.flags[row * w..(row + 1) * w]
            .iter()
            .map(|&f| f32::from(f))
            .collect();
        fw.write_band_row(0, row, &vals)
            .map_err(|e| path_err(&flags_path, e))?;
    }
    fw.finish().map_err(|e| path_err(&flags_path, e))
}

/// Writes the thickness preview, `thickness_nm.png`, titled with the index and method.
fn write_preview(dir: &Path, run: &Run) -> Result<(), OutputError> {
    let r = &run.result;
    let png = dir.join("thickness_nm.png");
    let title = format!(
        "thickness, n = {:.4} ({})",
        r.index.at(550.0),
        r.method.name()
    );
    write_map_png(
        &png,
        &MapPreview {
            width: run.spec.width,
            height: run.spec.height,
            values: &r.thickness_nm,
            title: &title,
            unit: "nm",
            range: None,
        },
    )
    .map_err(|e| path_err(&png, e))
}

/// Writes the index as `index.csv` and `index.yml` when the index model has them; true if
/// it did.
fn write_index_files(dir: &Path, run: &Run, source_label: &str) -> Result<bool, OutputError> {
    let r = &run.result;
    let comment = format!("{} estimate of {source_label}", r.method.name());
    let index_files =
        crate::material::index_files(&r.index.dispersion(), &run.spec.bands_nm, &comment);
    for (name, text) in index_files.iter().flatten() {
        let path = dir.join(name);
        write_atomic(&path, text.as_bytes()).map_err(|e| path_err(&path, e))?;
    }
    Ok(index_files.is_some())
}

/// The run's `summary.json`; `index_files`: whether the index files were written.
fn summary_of(run: &Run, source_label: &str, index_files: bool) -> Summary {
    let (w, h) = (run.spec.width, run.spec.height);
    let r = &run.result;
    let valid = r.thickness_nm.iter().filter(|x| x.is_finite()).count();
    let n_550 = r.index.at(550.0);
    let finite = |x: f64| x.is_finite().then_some(x);
    Summary {
        refractive_index: finite(n_550),
        refractive_index_sigma: r.index_sigma.and_then(finite),
        dispersion: n_550
            .is_finite()
            .then(|| IndexRecord::new(r.index.dispersion(), &run.spec.bands_nm)),
        index_model: index_model_name(&r.index).to_owned(),
        index_model_choice: run.model_choice.clone(),
        field_model: run.field_model,
        field_model_choice: run.field_model_choice.clone(),
        thickness_nm: Stats::of(&r.thickness_nm),
        thickness_sigma_nm: sigma_summary(r),
        valid_fraction: valid as f64 / (w * h).max(1) as f64,
        width: w,
        height: h,
        sample: Some(SampleRecord {
            ambient_index: run.spec.ambient_index,
            substrate_index: run.spec.substrate_index,
            polarization: run.spec.polarization.name().to_owned(),
            substrate: (!run.spec.substrate.is_constant()).then(|| run.spec.substrate.into()),
            back_face: run.spec.back_face.name().into(),
        }),
        method: r.method,
        source: source_label.to_owned(),
        angles_deg: run.angles_deg.clone(),
        bands: run.spec.bands_nm.len(),
        flags: flag_counts(&r.flags),
        angle_reports: run.angle_reports.clone(),
        timing: Timing {
            seconds: run.seconds,
            solve_latency_ms: run.solve_latency_ms,
            samples: run.samples,
            samples_per_s: run.samples as f64 / run.seconds.max(1e-9),
        },
        state_bytes_per_pixel: run.state_bytes_per_pixel,
        notes: r.notes.clone(),
        files: Files {
            thickness: "thickness_nm.hdr".into(),
            confidence: "confidence.hdr".into(),
            thickness_sigma: "thickness_sigma_nm.hdr".into(),
            flags: "flags.hdr".into(),
            preview: "thickness_nm.png".into(),
            index_csv: index_files.then(|| crate::material::INDEX_FILES[0].to_owned()),
            index_yml: index_files.then(|| crate::material::INDEX_FILES[1].to_owned()),
        },
        acquisition: None,
        timestamp: None,
        version: None,
        line: None,
    }
}
