//! The film's appearance: what the estimated index and thickness map look like, checked
//! against what was measured, and handed to renderers.
//!
//! - [`film`]: a maps directory read back as a film ([`SampleFilm`]): thickness map, flags,
//!   the estimated index with its dispersion, and the substrate and polarisation.
//! - [`spectral`]: the film model's colour: the Airy sum of the estimated stack summed to
//!   CIE XYZ, over the whole visible grid or through a capture's passbands.
//! - [`render`]: the sample at one angle, its angle strip, as sRGB (`filmscope render`).
//! - [`compare`]: each captured angle measured against reproduced, with a CIEDE2000 map
//!   (`filmscope compare`).
//! - [`pixel`]: one pixel's spectra at every angle against the model, the residual and the
//!   neighbouring orders' fits (`filmscope report RUN --pixel X,Y`).
//! - [`gltf`]: the film as a glTF 2.0 binary for renderers (`filmscope export-gltf`).

pub mod compare;
pub mod film;
pub mod gltf;
pub mod pixel;
pub mod render;
pub mod spectral;

use std::fmt::Display;
use std::path::Path;

pub use film::SampleFilm;

/// Why an appearance output could not be made: one line naming the file and the problem.
#[derive(Debug, thiserror::Error)]
pub enum AppearanceError {
    /// A file or folder of the estimate, the capture or the output, with its problem.
    #[error("{}: {problem}", .path.display())]
    File {
        /// The file or folder.
        path: std::path::PathBuf,
        /// What is wrong, in a line.
        problem: String,
    },
    /// The capture cannot be read.
    #[error(transparent)]
    Capture(#[from] crate::io::CaptureError),
    /// The capture cannot be streamed.
    #[error(transparent)]
    Source(#[from] crate::source::SourceError),
    /// `summary.json` cannot be read.
    #[error(transparent)]
    Summary(#[from] crate::record::RecordError),
    /// A cube cannot be read or written.
    #[error(transparent)]
    Cube(#[from] crate::io::EnviError),
    /// A picture cannot be drawn or encoded.
    #[error(transparent)]
    Picture(#[from] crate::export::png::PreviewError),
    /// The glTF document cannot be encoded.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// The capture's calibrated stream stopped.
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
    /// The capture's stream broke off or did not fit the estimate.
    #[error("{0}")]
    Stream(String),
    /// What was asked does not fit the estimate (a pixel outside the map, a capture of
    /// another sweep).
    #[error("{0}")]
    Mismatch(String),
}

impl AppearanceError {
    /// `path: what`.
    pub fn new(path: &Path, what: impl Display) -> Self {
        Self::File {
            path: path.to_owned(),
            problem: what.to_string(),
        }
    }
}
