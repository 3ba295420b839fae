//! Thin-film optics: Snell, Fresnel, the Airy sum of one film on a substrate, dispersion and
//! band averaging through the LCTF passband, and the incidence angle of each image column
//! under a lens's field of view ([`FieldOfView`]).
//!
//! Conventions: wavelengths are vacuum wavelengths in nm, angles in degrees, thicknesses in
//! nm, indices real. The model is validated against the Python `tmm` package
//! (`tests/optics_tmm.rs`) and analytic limits (unit tests below).

mod airy;
mod dispersion;
mod field;
mod film;
mod fresnel;
mod lossy;
mod passband;

pub use airy::{film_reflectance, BackFace, FilmAtAngle, Indices};
pub use dispersion::{materials, Dispersion};
pub use field::FieldOfView;
pub use film::{BandModel, FilmStack};
pub use fresnel::{
    fresnel_r, fresnel_r_real, medium_wave, normal_component, refraction_deg, snell_invariant,
};
pub use lossy::LossyFilm;
/// The complex numbers of the Airy sum and the Fresnel coefficients.
pub use num_complex::Complex64 as Complex;
pub use passband::{Passband, DEFAULT_NODES, HALF_WIDTH_FWHM, MAX_NODES};

#[cfg(test)]
mod tests;

/// Polarisation of the light that reaches the camera.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Polarization {
    /// Electric field perpendicular to the plane of incidence (the rig's LCTF passes S).
    S,
    /// Electric field in the plane of incidence.
    P,
    /// Unpolarised: the mean of the S and P reflectances.
    Unpolarized,
}

impl Polarization {
    /// Parses the names used in capture and scene files: `s`, `p`, `unpolarized`.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "s" | "S" => Some(Self::S),
            "p" | "P" => Some(Self::P),
            "unpolarized" | "unpolarised" | "u" => Some(Self::Unpolarized),
            _ => None,
        }
    }

    /// The name used in capture and scene files.
    pub fn name(self) -> &'static str {
        match self {
            Self::S => "s",
            Self::P => "p",
            Self::Unpolarized => "unpolarized",
        }
    }
}
