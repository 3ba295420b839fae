//! The illuminants a spectrum can be seen under: their names and tabulated spectra.

use super::tables::{A_SPD, D50_SPD, D65_SPD, GRID_LEN};

/// A light source with a tabulated spectrum (CIE 015:2018, `tables.rs`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Illuminant {
    /// CIE standard illuminant D65: average daylight, 6504 K; the sRGB white.
    D65,
    /// CIE standard illuminant A: incandescent (tungsten) light, 2856 K.
    A,
    /// CIE illuminant D50: horizon daylight, 5003 K; the graphic arts viewing light.
    D50,
}

impl Illuminant {
    /// Every illuminant, in the order their names are listed to users.
    pub const ALL: [Illuminant; 3] = [Self::D65, Self::A, Self::D50];

    /// Relative spectral power on the 5 nm grid 380..=780 nm (100 at 560 nm).
    pub const fn spd(self) -> &'static [f64; GRID_LEN] {
        match self {
            Self::D65 => &D65_SPD,
            Self::A => &A_SPD,
            Self::D50 => &D50_SPD,
        }
    }

    /// The name used on the command line and in outputs: `D65`, `A`, `D50`.
    pub const fn name(self) -> &'static str {
        match self {
            Self::D65 => "D65",
            Self::A => "A",
            Self::D50 => "D50",
        }
    }

    /// Parses a name as [`Illuminant::name`] gives it, in any letter case.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|i| i.name().eq_ignore_ascii_case(name))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for i in Illuminant::ALL {
            assert_eq!(Illuminant::from_name(i.name()), Some(i));
        }
        assert_eq!(Illuminant::from_name("d65"), Some(Illuminant::D65));
        assert_eq!(Illuminant::from_name("F2"), None);
    }
}
