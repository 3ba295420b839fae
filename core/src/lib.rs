//! filmscope's core: everything that computes, nothing that does I/O. It needs only `core`,
//! `libm` and `heapless` (`--no-default-features` builds it without std; the `std` feature
//! only adds `std::error::Error` impls).
//!
//! From the light to the maps:
//!
//! - [`optics`]: Snell, Fresnel, the Airy sum of one film on a substrate (any polarisation,
//!   total internal reflection included), dispersion (constant, Cauchy, Sellmeier) and the
//!   LCTF passband. Validated against the Python `tmm` package and analytic limits.
//! - [`colour`]: CIE 1931 tables, spectrum to XYZ to CIELAB, CIE76 and CIEDE2000, sRGB.
//! - [`calibrate`]: raw counts to reflectance with white and dark references, row by row.
//! - [`track`]: the per-pixel running extremum tracker (fixed state per pixel).
//! - [`solve`]: the streaming estimator: shared index from pooled extremum shifts, order per
//!   pixel, full-spectrum Gauss-Newton thickness, flags and confidence.
//!
//! And the rig, from the traits down to the bytes:
//!
//! - [`hw`]: hardware traits (stage, tunable filter, filter wheel, line camera, clock) with
//!   errors that say their kind.
//! - [`proto`]: the devices' wire codecs (Zaber ASCII, Kurios, Starlight Xpress HID reports,
//!   the `FSCL` camera link), pure functions over caller-owned buffers.
#![cfg_attr(not(feature = "std"), no_std)]

pub mod calibrate;
pub mod colour;
pub mod hw;
pub mod optics;
pub mod proto;
pub mod simd;
pub mod solve;
pub mod track;
