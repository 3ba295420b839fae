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
#[error("{0}")]
pub struct AppearanceError(pub String);

impl AppearanceError {
    /// `path: what`.
    pub fn new(path: &Path, what: impl Display) -> Self {
        Self(format!("{}: {what}", path.display()))
    }
}
