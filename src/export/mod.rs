//! Outputs: map previews, charts and exports.
pub(crate) mod canvas;
pub mod colormap;
pub mod plot;
pub mod png;
