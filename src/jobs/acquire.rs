//! Acquiring a sample: a rig's live sweep ([`crate::source::live`]) recorded as a capture
//! while the estimator reads it, the capture, maps and summary written as one unit.

use std::path::{Path, PathBuf};

use super::estimate::Settings;
use super::Observer;
use crate::estimate::OutputError;
use crate::io::OutputDirError;
use crate::record::RecordError;
use crate::rig::sim::SimError;
use crate::rig::{Rig, RigConfig, RigError};
use crate::source::live::{Acquisition, LiveError};
use crate::summary::Summary;

/// Why an acquisition did not finish, one line naming what stopped it and what was kept.
#[derive(Debug, thiserror::Error)]
pub enum AcquireError {
    /// The software rig could not be started.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// A device could not be opened.
    #[error(transparent)]
    Rig(#[from] RigError),
    /// The output folder cannot be used.
    #[error(transparent)]
    OutputDir(#[from] OutputDirError),
    /// The sweep cannot start.
    #[error(transparent)]
    Live(#[from] LiveError),
    /// The sweep stopped; the complete angles were kept.
    #[error("acquisition stopped: {cause}; {kept} complete angle(s) kept in {} (see acquisition.json)", .capture.display())]
    Stopped {
        /// What stopped it.
        cause: String,
        /// Complete angles kept.
        kept: usize,
        /// Where the capture was kept.
        capture: PathBuf,
    },
    /// The sweep stopped and its partial capture could not be kept.
    #[error("acquisition stopped: {cause}; the partial capture could not be kept: {problem}")]
    NotKept {
        /// What stopped it.
        cause: String,
        /// Why it could not be kept.
        problem: OutputDirError,
    },
    /// The maps cannot be written.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// The summary cannot be written.
    #[error(transparent)]
    Record(#[from] RecordError),
}

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
) -> Result<Summary, AcquireError> {
    let mut config = config.clone();
    let mut _sim_rig = None;
    let rig = if sim {
        let (sim_rig, rig) = crate::rig::sim::open_sim(&mut config)?;
        _sim_rig = Some(sim_rig);
        rig
    } else {
        let wheel: Option<Box<dyn crate::rig::HidTransport + Send>> = match &config.wheel {
            Some(_) => Some(Box::new(crate::rig::wheel::HidapiTransport::open()?)),
            None => None,
        };
        crate::rig::open(&config, wheel)?
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
) -> Result<Summary, AcquireError> {
    let out_dir = crate::io::OutputDir::begin(out)?;
    let capture_dir = out_dir.path().join("capture");
    let final_capture = out_dir.target().join("capture");
    let mut acq = Acquisition::new(rig, config, &capture_dir)?;
    let label = final_capture.display().to_string();
    let result = super::estimate::run(&mut acq, settings, None, &label, observer);
    let run = match result {
        Ok(run) => run,
        Err(e) => {
            let cause = e.cause();
            let kept = acq.log.angles_done_deg.len();
            drop(acq);
            return Err(match out_dir.commit_partial() {
                Ok(place) => AcquireError::Stopped {
                    cause,
                    kept,
                    capture: place.join("capture"),
                },
                Err(problem) => AcquireError::NotKept { cause, problem },
            });
        }
    };
    let mut summary = crate::estimate::write_outputs_into(out_dir.path(), &run, &label)?;
    summary.acquisition = Some(acq.log.clone());
    summary.timestamp = Some(crate::io::utc_iso(std::time::SystemTime::now()));
    summary.version = Some(env!("CARGO_PKG_VERSION").to_owned());
    summary.write(out_dir.path())?;
    drop(acq);
    out_dir.commit()?;
    Ok(summary)
}
