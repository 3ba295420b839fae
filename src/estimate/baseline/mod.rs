//! Whole-cube baselines: the paper's method and brute force.
//!
//! Both take a whole [`SweepCube`](crate::source::SweepCube) in memory and return a
//! [`MethodResult`](crate::estimate::method::MethodResult):
//!
//! - [`paper`]: Kobayashi et al.'s method as published (peak wavelengths, eq. 12 from pairs of
//!   angles, integer orders chosen by least squares), with its weaknesses kept;
//! - [`brute`]: least squares over an `(n, d)` grid per pixel, the paper's O(m N^2) baseline.

mod brute;
mod common;

pub(crate) use common::defect_flags;
mod paper;

pub use brute::{brute, BruteGrid, DEFAULT_INDEX_STEP};
pub use paper::paper;
