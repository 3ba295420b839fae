//! Colour: CIE 1931 tables, spectrum -> XYZ -> CIELAB, colour differences, sRGB.
//!
//! The pipeline used to colour a measured or modelled reflectance spectrum:
//!
//! 1. [`reflectance_to_xyz`] (sampled spectrum) or [`reflectance_fn_to_xyz`]
//!    (closure) integrates reflectance x D65 x CIE 1931 2-degree colour matching
//!    functions over the 5 nm grid 380..=780 nm, normalised so that a perfect
//!    reflector has `Y = 100` (its XYZ is [`D65_WHITE_XYZ`]).
//! 2. [`Xyz::to_lab`] converts to CIE 1976 L\*a\*b\* relative to a white.
//! 3. [`delta_e76`] / [`delta_e2000`] compare two colours; [`spectral_rmse`]
//!    compares the spectra themselves.
//! 4. [`xyz_to_srgb`] and [`srgb_to_u8`] give a displayable swatch.
//!
//! Beyond D65 and the whole visible grid: [`Colorimetry`] sums a spectrum under any
//! [`Illuminant`] (D65, A, D50) and over the whole grid or only a measured range (camera
//! bands), and [`bradford_adapt`] carries a colour seen under one light to the sRGB white,
//! as a white-balanced camera would.
//!
//! Everything is `no_std` (maths through `libm`).

mod adapt;
mod difference;
mod illuminant;
mod lab;
mod srgb;
pub mod tables;
mod xyz;

pub use adapt::bradford_adapt;
pub use difference::{delta_e2000, delta_e76, spectral_rmse};
pub use illuminant::Illuminant;
pub use lab::Lab;
pub use srgb::{srgb_to_u8, xyz_to_srgb, xyz_to_srgb_balanced};
pub use xyz::{
    d65_white, reflectance_fn_to_xyz, reflectance_to_xyz, Colorimetry, Xyz, D65_WHITE_XYZ,
};
