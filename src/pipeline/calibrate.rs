//! The calibrate stage: raw counts to reflectance (a live camera's; a capture on disk is
//! calibrated as it is read), rows split among the workers, angle ends told to the
//! coordinator; and the calibrated stream for consumers outside the pipeline.

use std::sync::Mutex;
use std::time::Instant;

use crossbeam_channel::{bounded, Receiver, Sender};
use filmscope_core::track::pack_samples;

use super::msg::{Control, Correction, PipelineError, Tap, WorkerMsg, WorkerRows};
use super::state::Strips;
use crate::source::{calibrate_block, Source, StreamMsg};

/// The stage's loop: `strips` split the rows among `workers`, their samples packed for
/// AVX2 if `wide` ([`filmscope_core::simd::wide`]).
pub(super) fn calibrate_stage(
    rx: Receiver<StreamMsg>,
    control: Sender<Control>,
    workers: Vec<Sender<WorkerMsg>>,
    (width, height): (usize, usize),
    (strips, wide): (Strips, bool),
    (tap, correction): (Option<&Mutex<dyn Tap + Send>>, &Correction),
    on_rows: &(dyn Fn(u64) + Sync),
) {
    let mut in_angle = false;
    // The angle under way, counted from 0 in streaming order.
    let mut angle: Option<usize> = None;
    for msg in rx.iter() {
        match msg {
            StreamMsg::Angle { incidence_deg } => {
                in_angle = true;
                angle = Some(angle.map_or(0, |a| a + 1));
                if let Some(t) = tap {
                    t.lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .angle(incidence_deg);
                }
                let deg = incidence_deg + correction.angle_offset_deg;
                if control.send(Control::Angle(deg)).is_err() {
                    return;
                }
            }
            StreamMsg::Rows(block) => {
                if !in_angle {
                    let _ = control.send(Control::Abort("rows arrived outside an angle".into()));
                    return;
                }
                let rows = block.rows as usize;
                let first = block.first_row as usize;
                if rows == 0 || first + rows > height {
                    let what = if rows == 0 {
                        format!("an empty block at row {first}")
                    } else {
                        format!("row {} is outside the {height}-row frame", first + rows - 1)
                    };
                    let _ = control.send(Control::Abort(what));
                    return;
                }
                let mut values = calibrate_block(block.samples, rows, width);
                if values.len() != rows * width {
                    let _ = control.send(Control::Abort(format!(
                        "a block of {rows} rows holds {} samples, not {}",
                        values.len(),
                        rows * width
                    )));
                    return;
                }
                if let Some(t) = tap {
                    t.lock().unwrap_or_else(|e| e.into_inner()).rows(
                        usize::from(block.band),
                        first,
                        rows,
                        &values,
                    );
                }
                // The solver's data corrected as the sample fit found (the tap keeps them raw).
                let terms = angle.and_then(|a| correction.terms.get(a)).copied();
                if terms.is_some() || correction.flare != 0.0 {
                    let (scale, offset) = terms.unwrap_or((1.0, 0.0));
                    let offset = offset + correction.flare;
                    for v in &mut values {
                        *v = (*v - offset) / scale;
                    }
                }
                let rows_at = (block.band, first, rows);
                if !deal(&values, rows_at, width, (strips, wide), &workers) {
                    return;
                }
                on_rows(rows as u64);
            }
            // Band ends carry nothing the solver needs: each pixel's tracker sees its bands in
            // order whatever the interleave.
            StreamMsg::BandEnd { .. } => {}
            StreamMsg::AngleEnd => {
                in_angle = false;
                let at = Instant::now();
                for tx in &workers {
                    if tx.send(WorkerMsg::End).is_err() {
                        return;
                    }
                }
                if control.send(Control::AngleEnd(at)).is_err() {
                    return;
                }
            }
            StreamMsg::SweepEnd => {
                let _ = control.send(Control::SweepEnd);
                return;
            }
            StreamMsg::Abort(e) => {
                let _ = control.send(Control::Abort(e));
                return;
            }
        }
    }
    let _ = control.send(Control::Abort(
        "the source stopped without ending the sweep".into(),
    ));
}

/// Rows `first..first + rows` of band `band` (`values`, `width` a row) split at strip
/// boundaries, each part packed (for AVX2 if `wide`) and sent to its strip's worker;
/// `false` when a worker has stopped.
fn deal(
    values: &[f32],
    (band, first, rows): (u16, usize, usize),
    width: usize,
    (strips, wide): (Strips, bool),
    workers: &[Sender<WorkerMsg>],
) -> bool {
    // Split the block at strip boundaries, each part to its strip's worker.
    let mut k = 0;
    while k < rows {
        let strip = strips.of_row(first + k);
        let (s_first, s_rows) = strips.span(strip);
        let n = (s_first + s_rows - (first + k)).min(rows - k);
        let mut part = vec![0; n * width];
        pack_samples(&values[k * width..(k + n) * width], &mut part, wide);
        if workers[strips.worker(strip)]
            .send(WorkerMsg::Rows(WorkerRows {
                band,
                first_row: (first + k) as u32,
                rows: n as u32,
                samples: part,
            }))
            .is_err()
        {
            return false;
        }
        k += n;
    }
    true
}

/// What [`for_each_calibrated`] hands on.
#[derive(Debug)]
pub enum Calibrated<'a> {
    /// An angle starts (degrees).
    Angle(f64),
    /// Calibrated reflectance of rows `first_row..first_row + rows` of `band` at angle
    /// number `angle` (row-major).
    Rows {
        /// Angle number (0 for the first).
        angle: usize,
        /// Band.
        band: usize,
        /// First row.
        first_row: usize,
        /// Rows.
        rows: usize,
        /// `rows * width` values.
        values: &'a [f32],
    },
}

/// Streams `source` and hands every angle start and block of calibrated rows to `f`, on this
/// thread.
pub fn for_each_calibrated(
    source: &mut dyn Source,
    f: impl FnMut(Calibrated<'_>),
) -> Result<(), PipelineError> {
    for_each_calibrated_rows(source, None, f)
}

/// [`for_each_calibrated`] of only the image rows in `rows` (sorted; `None`: every row),
/// for a consumer of a few pixels ([`Source::stream_rows`]: a source may still send others).
pub fn for_each_calibrated_rows(
    source: &mut dyn Source,
    rows: Option<&[usize]>,
    mut f: impl FnMut(Calibrated<'_>),
) -> Result<(), PipelineError> {
    let spec = source.spec().clone();
    let (w, h, nb) = (spec.width, spec.height, spec.bands_nm.len());
    let (tx, rx) = bounded::<StreamMsg>(64);
    std::thread::scope(|scope| -> Result<(), PipelineError> {
        scope.spawn(move || match rows {
            Some(rows) => source.stream_rows(&tx, rows),
            None => source.stream(&tx),
        });
        let mut angle = None;
        // `rx` moves in here: dropped when this returns early, so the source's next send
        // fails and it stops instead of blocking the scope's join on a full channel.
        for msg in rx {
            match msg {
                StreamMsg::Angle { incidence_deg } => {
                    angle = Some(angle.map_or(0, |a| a + 1));
                    f(Calibrated::Angle(incidence_deg));
                }
                StreamMsg::Rows(b) => {
                    let (band, first, rows) =
                        (usize::from(b.band), b.first_row as usize, b.rows as usize);
                    let a = angle.ok_or_else(|| {
                        PipelineError::Stream("rows arrived outside an angle".into())
                    })?;
                    if band >= nb || first + rows > h {
                        return Err(PipelineError::Stream(format!(
                            "band {band}, rows {first}..{} are outside the sweep",
                            first + rows
                        )));
                    }
                    let v = calibrate_block(b.samples, rows, w);
                    if v.len() != rows * w {
                        return Err(PipelineError::Stream(format!(
                            "a block of {rows} rows holds {} samples, not {}",
                            v.len(),
                            rows * w
                        )));
                    }
                    f(Calibrated::Rows {
                        angle: a,
                        band,
                        first_row: first,
                        rows,
                        values: &v,
                    });
                }
                StreamMsg::AngleEnd | StreamMsg::BandEnd { .. } => {}
                StreamMsg::SweepEnd => return Ok(()),
                StreamMsg::Abort(e) => return Err(PipelineError::Source(e)),
            }
        }
        Err(PipelineError::Stream(
            "the source stopped without ending the sweep".into(),
        ))
    })
}

/// Streams `source` and keeps every calibrated sample: the whole sweep in memory, for the
/// whole-cube baselines and for evaluation (not for the streaming estimator).
pub fn collect_sweep(source: &mut dyn Source) -> Result<crate::source::SweepCube, PipelineError> {
    let spec = source.spec().clone();
    let (w, h, nb) = (spec.width, spec.height, spec.bands_nm.len());
    let mut angles = Vec::new();
    let mut data: Vec<Vec<f32>> = Vec::new();
    for_each_calibrated(source, |event| match event {
        Calibrated::Angle(deg) => {
            angles.push(deg);
            data.push(vec![f32::NAN; w * h * nb]);
        }
        Calibrated::Rows {
            angle,
            band,
            first_row,
            rows,
            values,
        } => {
            let at = (band * h + first_row) * w;
            data[angle][at..at + rows * w].copy_from_slice(values);
        }
    })?;
    Ok(crate::source::SweepCube {
        width: w,
        height: h,
        bands_nm: spec.bands_nm.to_vec(),
        fwhm_nm: spec.fwhm_nm.to_vec(),
        angles_deg: angles,
        ambient_index: spec.ambient_index,
        substrate_index: spec.substrate_index,
        polarization: spec.polarization,
        back_face: spec.back_face,
        index_range: spec.index_range,
        thickness_range_nm: spec.thickness_range_nm,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::SimSource;
    use filmscope_core::solve::SweepSpec;
    use firmware_sim::{Scene, SoftwareCamera};

    /// A source that aborts, then goes on sending as a broken rig might.
    struct Babbler(SweepSpec);

    impl Source for Babbler {
        fn spec(&self) -> &SweepSpec {
            &self.0
        }
        fn angles_deg(&self) -> Vec<f64> {
            vec![10.0]
        }
        fn stream(&mut self, tx: &crossbeam_channel::Sender<StreamMsg>) {
            let _ = tx.send(StreamMsg::Abort("the rig broke".into()));
            for _ in 0..1000 {
                if tx.send(StreamMsg::AngleEnd).is_err() {
                    return;
                }
            }
        }
    }

    /// A consumer that stops early lets the source stop too: the error comes back, and no
    /// thread waits for ever on a full channel.
    #[test]
    fn an_early_error_does_not_block_on_the_source() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/scenes/rig-tiny.toml");
        let scene = Scene::load(std::path::Path::new(path)).expect("scene");
        let sim = SimSource::new(SoftwareCamera::new(scene), false, 1).expect("source");
        let mut source = Babbler(sim.spec().clone());
        let (done_tx, done_rx) = crossbeam_channel::bounded(1);
        std::thread::spawn(move || {
            let _ =
                done_tx.send(for_each_calibrated(&mut source, |_| {}).map_err(|e| e.to_string()));
        });
        let result = done_rx
            .recv_timeout(std::time::Duration::from_secs(30))
            .expect("the stream ended");
        assert_eq!(result, Err("the rig broke".to_owned()));
    }
}
