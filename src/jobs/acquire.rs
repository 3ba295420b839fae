//! Acquiring a sample: a rig's live sweep ([`crate::source::live`]) recorded as a capture
//! while the estimator reads it, the capture, maps and summary written as one unit.

use std::path::Path;

use super::estimate::{EstimateError, Settings};
use super::Observer;
use crate::rig::{Rig, RigConfig};
use crate::source::live::Acquisition;

/// Runs `filmscope acquire`: opens the rig of `config` (or, with `sim`, starts
/// `firmware-sim` on ptys and a socket and opens that), records the sweep into
/// `out/capture`, estimates while it streams and writes the maps into `out`. Returns the
/// summary; on a failed sweep, the error names what stopped it and what was kept.
pub fn run(
    config: &RigConfig,
    out: &Path,
    sim: bool,
    settings: &Settings,
    observer: &dyn Observer,
) -> Result<crate::summary::Summary, String> {
    let mut config = config.clone();
    let mut _sim_rig = None;
    let rig = if sim {
        let (sim_rig, rig) = crate::rig::sim::open_sim(&mut config)?;
        _sim_rig = Some(sim_rig);
        rig
    } else {
        let wheel: Option<Box<dyn crate::rig::HidTransport + Send>> = match &config.wheel {
            Some(_) => Some(Box::new(
                crate::rig::wheel::HidapiTransport::open().map_err(|e| e.to_string())?,
            )),
            None => None,
        };
        crate::rig::open(&config, wheel).map_err(|e| e.to_string())?
    };
    run_rig(rig, config, out, settings, observer)
}

/// Sweeps an open `rig`, recording into `out/capture` and writing the maps into `out`,
/// all as one unit ([`crate::io::OutputDir`]): locked and checked for writability before
/// any device moves, swapped in whole when complete. A sweep that stops early keeps its
/// capture and `acquisition.json`: in `out` when `out` held no result, else in
/// `out.partial`, never over a complete result.
pub fn run_rig(
    rig: Rig,
    config: RigConfig,
    out: &Path,
    settings: &Settings,
    observer: &dyn Observer,
) -> Result<crate::summary::Summary, String> {
    let out_dir = crate::io::OutputDir::begin(out).map_err(|e| e.to_string())?;
    let capture_dir = out_dir.path().join("capture");
    let final_capture = out_dir.target().join("capture");
    let mut acq = Acquisition::new(rig, config, &capture_dir)?;
    let label = final_capture.display().to_string();
    let result = super::estimate::run(&mut acq, settings, None, &label, observer);
    let run = match result {
        Ok(run) => run,
        Err(e) => {
            let e = match e {
                EstimateError::Run { source, .. } => source.to_string(),
                e => e.to_string(),
            };
            let kept = acq.log.angles_done_deg.len();
            drop(acq);
            let place = out_dir.commit_partial().map_err(|x| {
                format!("acquisition stopped: {e}; the partial capture could not be kept: {x}")
            })?;
            return Err(format!(
                "acquisition stopped: {e}; {kept} complete angle(s) kept in {} (see acquisition.json)",
                place.join("capture").display()
            ));
        }
    };
    let mut summary = crate::estimate::write_outputs_into(out_dir.path(), &run, &label)
        .map_err(|e| e.to_string())?;
    summary.acquisition = Some(acq.log.clone());
    summary.timestamp = Some(crate::io::utc_iso(std::time::SystemTime::now()));
    summary.version = Some(env!("CARGO_PKG_VERSION").to_owned());
    summary.write(out_dir.path())?;
    drop(acq);
    out_dir.commit().map_err(|e| e.to_string())?;
    Ok(summary)
}
