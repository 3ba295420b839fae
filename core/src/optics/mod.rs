//! Thin-film optics: Snell, Fresnel, the Airy sum of one film on a substrate, dispersion, passbands.

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
