//! Outputs: map previews and exports.
pub mod colormap;
pub mod png;
