//! Refractive index against wavelength: constant, Cauchy and Sellmeier, in the formula forms
//! of refractiveindex.info, so a scene is modelled no richer than it needs.

/// A real refractive index as a function of vacuum wavelength.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Dispersion {
    /// The same index at every wavelength.
    Constant {
        /// The index.
        n: f64,
    },
    /// Cauchy: `n = a + b / lambda^2 + c / lambda^4`, lambda in micrometres
    /// (refractiveindex.info formula 5 with exponents -2 and -4).
    Cauchy {
        /// Constant term.
        a: f64,
        /// Coefficient of `lambda^-2`, in um^2.
        b_um2: f64,
        /// Coefficient of `lambda^-4`, in um^4.
        c_um4: f64,
    },
    /// Sellmeier: `n^2 = a + sum_i b_i lambda^2 / (lambda^2 - c_i^2)`, lambda and `c_i` in
    /// micrometres (refractiveindex.info formula 1 with `a = 1 + A`). Unused terms have `b = 0`.
    Sellmeier {
        /// Constant term of `n^2` (1 for the classic form).
        a: f64,
        /// Oscillator strengths.
        b: [f64; 3],
        /// Resonance wavelengths, in um.
        c_um: [f64; 3],
    },
}

impl Dispersion {
    /// A constant index.
    pub const fn constant(n: f64) -> Self {
        Self::Constant { n }
    }

    /// A two-term Cauchy model `n = a + b_um2 / lambda_um^2`.
    pub const fn cauchy(a: f64, b_um2: f64) -> Self {
        Self::Cauchy {
            a,
            b_um2,
            c_um4: 0.0,
        }
    }

    /// The index at vacuum wavelength `wavelength_nm`.
    #[inline]
    pub fn index_at(&self, wavelength_nm: f64) -> f64 {
        let l_um = wavelength_nm * 1e-3;
        match *self {
            Self::Constant { n } => n,
            Self::Cauchy { a, b_um2, c_um4 } => {
                let l2 = l_um * l_um;
                a + b_um2 / l2 + c_um4 / (l2 * l2)
            }
            Self::Sellmeier { a, b, c_um } => {
                let l2 = l_um * l_um;
                let mut n2 = a;
                for i in 0..3 {
                    if b[i] != 0.0 {
                        n2 += b[i] * l2 / (l2 - c_um[i] * c_um[i]);
                    }
                }
                libm::sqrt(n2)
            }
        }
    }

    /// True when the index does not change with wavelength.
    pub fn is_constant(&self) -> bool {
        matches!(self, Self::Constant { .. })
    }
}

/// Published dispersion formulas for the materials in the paper's samples.
pub mod materials {
    use super::Dispersion;

    /// ZnS (cubic), Debenham 1984 (Appl. Opt. 23, 2238), 0.405-13 um, as listed by
    /// refractiveindex.info: `n^2 = 8.393 + 0.14383 / (l^2 - 0.2421^2) + 4430.99 / (l^2 - 36.71^2)`.
    /// Rewritten in the Sellmeier form using `B / (l^2 - C^2) = (B / C^2) (l^2 / (l^2 - C^2) - 1)`.
    /// n = 2.386 at 550 nm, 2.55 at 400 nm, 2.33 at 720 nm.
    pub fn zns_debenham() -> Dispersion {
        let b1 = 0.14383 / (0.2421 * 0.2421);
        let b2 = 4430.99 / (36.71 * 36.71);
        Dispersion::Sellmeier {
            a: 8.393 - b1 - b2,
            b: [b1, b2, 0.0],
            c_um: [0.2421, 36.71, 0.0],
        }
    }

    /// MgF2 ordinary ray, Dodge 1984 (Appl. Opt. 23, 1980), 0.2-7 um:
    /// `n^2 - 1 = 0.48755108 l^2/(l^2-0.04338408^2) + 0.39875031 l^2/(l^2-0.09461442^2) +
    /// 2.3120353 l^2/(l^2-23.793604^2)`. n = 1.3790 at 550 nm (bulk crystal; evaporated
    /// films are less dense, the paper uses 1.37).
    pub const MGF2_DODGE_O: Dispersion = Dispersion::Sellmeier {
        a: 1.0,
        b: [0.48755108, 0.39875031, 2.3120353],
        c_um: [0.04338408, 0.09461442, 23.793604],
    };
}
