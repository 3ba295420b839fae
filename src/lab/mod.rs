//! The measuring lab: how well and how fast the methods work, against the truth of
//! simulated scenes and beside outside baselines. The `eval`, `bench`, `chart`, `stability`
//! and `soak` commands print what it measures; only the command line imports it.
//!
//! - [`scene`]: the scenes the measurements run on, resized;
//! - [`eval`]: accuracy against the truth (index, thickness, colour) of scene files,
//!   captures and random sets judged PASS or FAIL, with improvements switched off;
//! - [`chart`]: speed against accuracy over methods and settings, and the stability maps;
//! - [`peers`]: the Python peers `bench` sets filmscope beside;
//! - [`bench`](mod@bench): speed and memory, the baselines' cost, the line's inspect latency, and the
//!   resident memory of a long run.

pub mod bench;
pub mod chart;
pub mod eval;
pub mod peers;
pub mod scene;

use std::path::{Path, PathBuf};

/// A lab result, [`LabError`] by default.
pub type Result<T, E = LabError> = std::result::Result<T, E>;

/// Why a lab measurement could not be made, one line each at the command line (its
/// sources follow it, `: `-joined).
#[derive(Debug, thiserror::Error)]
pub enum LabError {
    /// A file or folder could not be read, written or created.
    #[error("{}: cannot {action}", path.display())]
    File {
        /// The file or folder.
        path: PathBuf,
        /// What was tried: `read`, `write`, `create`.
        action: &'static str,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// A step that failed for a reason of its own (`cannot start python3 ...`).
    #[error("{what}")]
    Step {
        /// The step, in the words the user reads.
        what: String,
        /// Why.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// An input, scene or result the lab cannot use, named with its problem.
    #[error("{0}")]
    Invalid(String),
    /// The system refused an operation on no file in particular.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// A JSON document (a child's figures, a summary) could not be read or written.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// A scene file could not be used.
    #[error(transparent)]
    Scene(#[from] firmware_sim::SceneError),
    /// A capture could not be read.
    #[error(transparent)]
    Capture(#[from] crate::io::capture::CaptureError),
    /// A scene's capture could not be written.
    #[error(transparent)]
    Simulate(#[from] crate::simulate::SimulateError),
    /// The estimate of a scene failed.
    #[error(transparent)]
    Estimate(#[from] crate::jobs::estimate::EstimateError),
}

impl LabError {
    /// `path: cannot <action>` with the system's reason, for `map_err`.
    pub fn file<'a>(
        path: &'a Path,
        action: &'static str,
    ) -> impl FnOnce(std::io::Error) -> Self + 'a {
        move |source| Self::File {
            path: path.to_owned(),
            action,
            source,
        }
    }

    /// `what` with the error that stopped it as its source, for `map_err`.
    pub fn step<E: Into<Box<dyn std::error::Error + Send + Sync>>>(
        what: impl Into<String>,
    ) -> impl FnOnce(E) -> Self {
        let what = what.into();
        move |e| Self::Step {
            what,
            source: e.into(),
        }
    }

    /// An error shown as it reads (`e`'s own line), for `map_err`.
    pub fn invalid(e: impl std::fmt::Display) -> Self {
        Self::Invalid(e.to_string())
    }
}
