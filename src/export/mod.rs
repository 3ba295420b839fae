//! Outputs: map previews, charts and exports.
pub(crate) mod canvas;
pub mod colormap;
pub mod gltf;
pub mod plot;
pub mod png;
