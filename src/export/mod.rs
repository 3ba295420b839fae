//! Pictures: map previews (PNG), colour maps and charts.
pub(crate) mod canvas;
pub mod colormap;
pub mod plot;
pub mod png;
