//! What every estimation method returns, and which method to run.

use filmscope_core::solve::IndexModel;

pub use crate::record::method::Method;

/// The maps and the index one method produced.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodResult {
    /// Which method.
    pub method: Method,
    /// The film index model (`b_um2 = 0` unless the method chose dispersion).
    pub index: IndexModel,
    /// Standard error of the index, when the method gives one.
    pub index_sigma: Option<f64>,
    /// Thickness per pixel, row-major, nm; NaN where the pixel has no reliable estimate.
    pub thickness_nm: Vec<f32>,
    /// Confidence per pixel in 0..1.
    pub confidence: Vec<f32>,
    /// 1-sigma thickness uncertainty per pixel from its own fit, nm (NaN where the method
    /// gives none: the baselines, pixels without a full-spectrum fit).
    pub thickness_sigma_nm: Vec<f32>,
    /// Flags per pixel (see [`filmscope_core::solve::flags`]).
    pub flags: Vec<u16>,
    /// Free-form notes for the summary (e.g. what the method decided).
    pub notes: Vec<String>,
}
