//! Refractive index against wavelength: constant, Cauchy and Sellmeier, in the formula forms
//! of refractiveindex.info, so a scene is modelled no richer than it needs, and measured
//! tables of `n` and `k` (silicon) used as tables.

/// A refractive index as a function of vacuum wavelength: real, or `n + i k` for a table
/// with an extinction coefficient.
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
    /// A measured table, rows `[wavelength_um, n, k]` in increasing wavelength, interpolated
    /// linearly (held at its ends): refractiveindex.info's `tabulated nk` (or `tabulated n`,
    /// `k` 0), used as published rather than refitted.
    Table {
        /// The rows.
        rows: &'static [[f64; 3]],
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
            Self::Table { rows } => interpolate(rows, l_um, 1),
        }
    }

    /// The extinction coefficient `k` at vacuum wavelength `wavelength_nm`: a table's, 0 for a
    /// formula (a clear material).
    #[inline]
    pub fn extinction_at(&self, wavelength_nm: f64) -> f64 {
        match *self {
            Self::Table { rows } => interpolate(rows, wavelength_nm * 1e-3, 2).max(0.0),
            _ => 0.0,
        }
    }

    /// True when the index does not change with wavelength.
    pub fn is_constant(&self) -> bool {
        matches!(self, Self::Constant { .. })
    }
}

/// Column `col` of `rows` (`[wavelength_um, n, k]`, increasing wavelength) at `l_um`, linear
/// between rows and held at the ends; NaN for no rows.
fn interpolate(rows: &[[f64; 3]], l_um: f64, col: usize) -> f64 {
    let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
        return f64::NAN;
    };
    if l_um <= first[0] {
        return first[col];
    }
    if l_um >= last[0] {
        return last[col];
    }
    let i = rows.partition_point(|r| r[0] <= l_um);
    let (a, b) = (rows[i - 1], rows[i]);
    let t = (l_um - a[0]) / (b[0] - a[0]);
    a[col] + t * (b[col] - a[col])
}

/// Published dispersion formulas of coating materials, as listed by refractiveindex.info
/// (lambda in micrometres throughout), and a lookup by name ([`materials::by_name`]).
///
/// Every formula is held in the [`Dispersion::Sellmeier`] or [`Dispersion::Cauchy`] form:
/// refractiveindex.info's formula 2 (`B l^2 / (l^2 - C)`) has `c_um = sqrt(C)`, and a
/// formula 4 term `B / (l^2 - C^2)` is `(B / C^2) (l^2 / (l^2 - C^2) - 1)`, its
/// `-B / C^2` going into the constant `a`. The n at 550 nm given with each is the formula's
/// own (checked in the unit tests).
pub mod materials {
    use super::Dispersion;

    /// A formula 4 term `B / (l^2 - C^2)` as a Sellmeier oscillator: `(b, c_um)` and the
    /// constant it moves `a` by.
    fn pole(b_over: f64, c_um: f64) -> (f64, f64, f64) {
        let b = b_over / (c_um * c_um);
        (b, c_um, -b)
    }

    /// ZnS (cubic), Debenham 1984 (Appl. Opt. 23, 2238), 0.405-13 um, as listed by
    /// refractiveindex.info: `n^2 = 8.393 + 0.14383 / (l^2 - 0.2421^2) + 4430.99 / (l^2 - 36.71^2)`.
    /// Rewritten in the Sellmeier form using `B / (l^2 - C^2) = (B / C^2) (l^2 / (l^2 - C^2) - 1)`.
    /// n = 2.3862 at 550 nm, 2.55 at 400 nm, 2.33 at 720 nm.
    pub fn zns_debenham() -> Dispersion {
        let (b1, c1, a1) = pole(0.14383, 0.2421);
        let (b2, c2, a2) = pole(4430.99, 36.71);
        Dispersion::Sellmeier {
            a: 8.393 + a1 + a2,
            b: [b1, b2, 0.0],
            c_um: [c1, c2, 0.0],
        }
    }

    /// MgF2 ordinary ray, Dodge 1984 (Appl. Opt. 23, 1980), 0.2-7 um:
    /// `n^2 - 1 = 0.48755108 l^2/(l^2-0.04338408^2) + 0.39875031 l^2/(l^2-0.09461442^2) +
    /// 2.3120353 l^2/(l^2-23.793604^2)`. n = 1.3785 at 550 nm (bulk crystal; evaporated
    /// films are less dense, the paper uses 1.37).
    pub const MGF2_DODGE_O: Dispersion = Dispersion::Sellmeier {
        a: 1.0,
        b: [0.48755108, 0.39875031, 2.3120353],
        c_um: [0.04338408, 0.09461442, 23.793604],
    };

    /// CaF2, Malitson 1963 (Appl. Opt. 2, 1103), 0.23-9.7 um, 24 C:
    /// `n^2 - 1 = 0.5675888 l^2/(l^2-0.050263605^2) + 0.4710914 l^2/(l^2-0.1003909^2) +
    /// 3.8484723 l^2/(l^2-34.649040^2)`. n = 1.4348 at 550 nm.
    pub const CAF2_MALITSON: Dispersion = Dispersion::Sellmeier {
        a: 1.0,
        b: [0.5675888, 0.4710914, 3.8484723],
        c_um: [0.050263605, 0.1003909, 34.649040],
    };

    /// Fused silica (SiO2), Malitson 1965 (J. Opt. Soc. Am. 55, 1205), 0.21-6.7 um, 20 C:
    /// `n^2 - 1 = 0.6961663 l^2/(l^2-0.0684043^2) + 0.4079426 l^2/(l^2-0.1162414^2) +
    /// 0.8974794 l^2/(l^2-9.896161^2)`. n = 1.4599 at 550 nm.
    pub const SIO2_MALITSON: Dispersion = Dispersion::Sellmeier {
        a: 1.0,
        b: [0.6961663, 0.4079426, 0.8974794],
        c_um: [0.0684043, 0.1162414, 9.896161],
    };

    /// Al2O3 (sapphire) ordinary ray, Malitson and Dodge 1972 (J. Opt. Soc. Am. 62, 1405;
    /// the formula from Dodge 1986, Handbook of Laser Science and Technology IV, CRC Press),
    /// 0.2-5 um, 20 C: `n^2 - 1 = 1.4313493 l^2/(l^2-0.0726631^2) + 0.65054713
    /// l^2/(l^2-0.1193242^2) + 5.3414021 l^2/(l^2-18.028251^2)`. n = 1.7704 at 550 nm.
    pub const AL2O3_MALITSON_O: Dispersion = Dispersion::Sellmeier {
        a: 1.0,
        b: [1.4313493, 0.65054713, 5.3414021],
        c_um: [0.0726631, 0.1193242, 18.028251],
    };

    /// Y2O3, Nigara 1968 (Jpn. J. Appl. Phys. 7, 404), 0.25-9.6 um:
    /// `n^2 - 1 = 2.578 l^2/(l^2-0.1387^2) + 3.935 l^2/(l^2-22.936^2)`. n = 1.9367 at 550 nm.
    pub const Y2O3_NIGARA: Dispersion = Dispersion::Sellmeier {
        a: 1.0,
        b: [2.578, 3.935, 0.0],
        c_um: [0.1387, 22.936, 0.0],
    };

    /// HfO2 (cubic, stabilised with 9.8 mol % Y2O3), Wood, Nassau, Kometani and Nash 1990
    /// (Appl. Opt. 29, 604), 0.365-5 um: `n^2 - 1 = 1.9558 l^2/(l^2-0.15494^2) + 1.345
    /// l^2/(l^2-0.0634^2) + 10.41 l^2/(l^2-27.12^2)`. n = 2.1174 at 550 nm.
    pub const HFO2_WOOD: Dispersion = Dispersion::Sellmeier {
        a: 1.0,
        b: [1.9558, 1.345, 10.41],
        c_um: [0.15494, 0.0634, 27.12],
    };

    /// HfO2 thin film (electron-beam evaporated), Al-Kuhaili 2004 (Opt. Mater. 27, 383),
    /// 0.2-2 um, a Cauchy formula (refractiveindex.info formula 5): `n = 1.875 + 6.28e-3
    /// l^-2 + 5.80e-4 l^-4`. n = 1.9021 at 550 nm.
    pub const HFO2_FILM_AL_KUHAILI: Dispersion = Dispersion::Cauchy {
        a: 1.875,
        b_um2: 6.28e-3,
        c_um4: 5.80e-4,
    };

    /// ZrO2 (cubic, stabilised with 12 mol % Y2O3), Wood and Nassau 1982 (Appl. Opt. 21,
    /// 2978), 0.361-5.1 um, 25 C: `n^2 - 1 = 1.347091 l^2/(l^2-0.062543^2) + 2.117788
    /// l^2/(l^2-0.166739^2) + 9.452943 l^2/(l^2-24.320570^2)`. n = 2.1661 at 550 nm.
    pub const ZRO2_WOOD: Dispersion = Dispersion::Sellmeier {
        a: 1.0,
        b: [1.347091, 2.117788, 9.452943],
        c_um: [0.062543, 0.166739, 24.320570],
    };

    /// Si3N4 (LPCVD film), Luke, Okawachi, Lamont, Gaeta and Lipson 2015 (Opt. Lett. 40,
    /// 4823), 0.31-5.5 um: `n^2 - 1 = 3.0249 l^2/(l^2-0.1353406^2) + 40314
    /// l^2/(l^2-1239.842^2)`. n = 2.0523 at 550 nm.
    pub const SI3N4_LUKE: Dispersion = Dispersion::Sellmeier {
        a: 1.0,
        b: [3.0249, 40314.0, 0.0],
        c_um: [0.1353406, 1239.842, 0.0],
    };

    /// Ta2O5 thin film (400 nm, ion-assisted electron-beam deposition), Gao, Lemarchand and
    /// Lequime 2012 (Opt. Express 20, 15734). refractiveindex.info lists the paper's n, k
    /// as a table (0.35-1.8 um, k < 5e-4 above 0.38 um); this is a one-oscillator Sellmeier
    /// fitted here to that table over 0.38-0.78 um, within 2e-5 of every tabulated n there:
    /// `n^2 = 1.77767 + 2.53289 l^2/(l^2-0.19^2)`. n = 2.1573 at 550 nm (table: 2.157262).
    pub const TA2O5_GAO: Dispersion = Dispersion::Sellmeier {
        a: 1.77767,
        b: [2.53289, 0.0, 0.0],
        c_um: [0.19, 0.0, 0.0],
    };

    /// Nb2O5 thin film (500 nm, magnetron sputtered), Lemarchand 2013 (measured by the
    /// method of Gao, Lemarchand and Lequime 2012, Opt. Express 20, 15734), tabulated by
    /// refractiveindex.info (0.25-2.5 um, k < 4e-3 above 0.38 um); this is a one-oscillator
    /// Sellmeier fitted here to that table over 0.38-0.78 um, within 1e-3 of every tabulated
    /// n there: `n^2 = 2.65783 + 2.29571 l^2/(l^2-0.2527^2)`. n = 2.3596 at 550 nm (table:
    /// 2.360317).
    pub const NB2O5_LEMARCHAND: Dispersion = Dispersion::Sellmeier {
        a: 2.65783,
        b: [2.29571, 0.0, 0.0],
        c_um: [0.2527, 0.0, 0.0],
    };

    /// TiO2 (rutile) ordinary ray, Devore 1951 (J. Opt. Soc. Am. 41, 416), 0.43-1.53 um:
    /// `n^2 = 5.913 + 0.2441 / (l^2 - 0.0803)` (refractiveindex.info formula 4). n = 2.6479
    /// at 550 nm.
    pub fn tio2_devore_o() -> Dispersion {
        let (b, c, a) = pole(0.2441, libm::sqrt(0.0803));
        Dispersion::Sellmeier {
            a: 5.913 + a,
            b: [b, 0.0, 0.0],
            c_um: [c, 0.0, 0.0],
        }
    }

    /// PMMA, Sultanova, Kasarova and Nikolov 2009 (Acta Phys. Pol. A 116, 585; Sellmeier
    /// fit by M. Polyanskiy), 0.437-1.052 um, 20 C: `n^2 - 1 = 1.1819 l^2/(l^2-0.011313)`
    /// (refractiveindex.info formula 2). n = 1.4926 at 550 nm.
    pub fn pmma_sultanova() -> Dispersion {
        Dispersion::Sellmeier {
            a: 1.0,
            b: [1.1819, 0.0, 0.0],
            c_um: [libm::sqrt(0.011313), 0.0, 0.0],
        }
    }

    /// Polycarbonate, Sultanova, Kasarova and Nikolov 2009 (Acta Phys. Pol. A 116, 585;
    /// Sellmeier fit by M. Polyanskiy), 0.437-1.052 um, 20 C: `n^2 - 1 = 1.4182
    /// l^2/(l^2-0.021304)` (refractiveindex.info formula 2). n = 1.5892 at 550 nm.
    pub fn polycarbonate_sultanova() -> Dispersion {
        Dispersion::Sellmeier {
            a: 1.0,
            b: [1.4182, 0.0, 0.0],
            c_um: [libm::sqrt(0.021304), 0.0, 0.0],
        }
    }

    /// N-BK7 borosilicate crown glass, SCHOTT datasheet, 0.3-2.5 um (refractiveindex.info
    /// formula 2): `n^2 - 1 = 1.03961212 l^2/(l^2-0.00600069867) + 0.231792344
    /// l^2/(l^2-0.0200179144) + 1.01046945 l^2/(l^2-103.560653)`. n = 1.5185 at 550 nm. A
    /// substrate (by [`by_name`] as `bk7` or `n-bk7`), not among the films of [`NAMES`].
    pub fn bk7_schott() -> Dispersion {
        Dispersion::Sellmeier {
            a: 1.0,
            b: [1.03961212, 0.231792344, 1.01046945],
            c_um: [
                libm::sqrt(0.00600069867),
                libm::sqrt(0.0200179144),
                libm::sqrt(103.560653),
            ],
        }
    }

    /// The library's names, lowercase, in order of rising n at 550 nm ([`by_name`] takes
    /// each, and the older `zns-debenham` and `mgf2-dodge`).
    pub const NAMES: [&str; 15] = [
        "mgf2",
        "caf2",
        "sio2",
        "pmma",
        "polycarbonate",
        "al2o3",
        "hfo2-film",
        "y2o3",
        "si3n4",
        "hfo2",
        "ta2o5",
        "zro2",
        "nb2o5",
        "zns",
        "tio2",
    ];

    /// Crystalline silicon, intrinsic, 300 K: M. A. Green, "Self-consistent optical parameters
    /// of intrinsic silicon at 300 K including temperature coefficients", Sol. Energ. Mat.
    /// Sol. Cells 92, 1305-1310 (2008), Table 1, as refractiveindex.info lists it (CC0),
    /// 0.25-1.0 um at 10 nm and on to 1.1 um: n 4.077, k 0.028 at 550 nm. A table, used as
    /// one (interpolated linearly).
    pub const SI_GREEN: Dispersion = Dispersion::Table {
        rows: &SI_GREEN_ROWS,
    };

    const SI_GREEN_ROWS: [[f64; 3]; 78] = [
        [0.25, 1.6650, 3.6650e+00],
        [0.26, 1.7570, 4.0840e+00],
        [0.27, 2.0680, 4.6800e+00],
        [0.28, 2.9590, 5.2870e+00],
        [0.29, 4.3560, 5.2860e+00],
        [0.30, 4.9760, 4.2340e+00],
        [0.31, 5.1210, 3.5980e+00],
        [0.32, 5.1120, 3.3030e+00],
        [0.33, 5.1950, 3.1000e+00],
        [0.34, 5.3010, 2.9770e+00],
        [0.35, 5.4940, 2.9380e+00],
        [0.36, 6.0260, 2.9660e+00],
        [0.37, 6.8910, 2.1710e+00],
        [0.38, 6.6160, 9.4600e-01],
        [0.39, 6.0390, 4.4500e-01],
        [0.40, 5.6130, 2.9600e-01],
        [0.41, 5.3300, 2.2700e-01],
        [0.42, 5.1190, 1.7600e-01],
        [0.43, 4.9490, 1.3800e-01],
        [0.44, 4.8120, 1.0700e-01],
        [0.45, 4.6910, 8.6302e-02],
        [0.46, 4.5870, 7.1381e-02],
        [0.47, 4.4970, 6.2086e-02],
        [0.48, 4.4190, 5.5004e-02],
        [0.49, 4.3500, 4.9131e-02],
        [0.50, 4.2940, 4.4165e-02],
        [0.51, 4.2410, 3.9367e-02],
        [0.52, 4.1930, 3.6415e-02],
        [0.53, 4.1510, 3.3108e-02],
        [0.54, 4.1120, 3.0295e-02],
        [0.55, 4.0770, 2.7968e-02],
        [0.56, 4.0450, 2.5758e-02],
        [0.57, 4.0150, 2.4131e-02],
        [0.58, 3.9880, 2.2524e-02],
        [0.59, 3.9630, 2.1081e-02],
        [0.60, 3.9400, 1.9934e-02],
        [0.61, 3.9180, 1.8446e-02],
        [0.62, 3.8980, 1.7367e-02],
        [0.63, 3.8790, 1.6444e-02],
        [0.64, 3.8610, 1.5432e-02],
        [0.65, 3.8440, 1.4431e-02],
        [0.66, 3.8280, 1.3498e-02],
        [0.67, 3.8130, 1.2743e-02],
        [0.68, 3.7980, 1.1905e-02],
        [0.69, 3.7840, 1.1201e-02],
        [0.70, 3.7720, 1.0528e-02],
        [0.71, 3.7590, 1.0057e-02],
        [0.72, 3.7480, 9.6257e-03],
        [0.73, 3.7370, 8.9461e-03],
        [0.74, 3.7270, 8.3620e-03],
        [0.75, 3.7170, 7.8185e-03],
        [0.76, 3.7080, 7.1970e-03],
        [0.77, 3.6990, 6.7402e-03],
        [0.78, 3.6910, 6.3933e-03],
        [0.79, 3.6830, 5.8340e-03],
        [0.80, 3.6750, 5.4113e-03],
        [0.81, 3.6680, 4.9955e-03],
        [0.82, 3.6610, 4.6134e-03],
        [0.83, 3.6540, 4.2734e-03],
        [0.84, 3.6470, 3.9439e-03],
        [0.85, 3.6410, 3.6120e-03],
        [0.86, 3.6350, 3.2781e-03],
        [0.87, 3.6300, 2.9839e-03],
        [0.88, 3.6240, 2.6821e-03],
        [0.89, 3.6190, 2.4293e-03],
        [0.90, 3.6140, 2.1701e-03],
        [0.91, 3.6090, 1.9625e-03],
        [0.92, 3.6040, 1.7571e-03],
        [0.93, 3.6000, 1.5467e-03],
        [0.94, 3.5950, 1.3689e-03],
        [0.95, 3.5910, 1.1793e-03],
        [0.96, 3.5870, 1.0237e-03],
        [0.97, 3.5830, 8.7225e-04],
        [0.98, 3.5790, 7.4866e-04],
        [0.99, 3.5750, 6.2238e-04],
        [1.00, 3.5720, 5.0930e-04],
        [1.05, 3.5560, 1.3620e-04],
        [1.10, 3.5420, 3.0637e-05],
    ];

    /// Every name of the library ([`NAMES`]).
    pub fn names() -> &'static [&'static str] {
        &NAMES
    }

    /// The material called `name` (case ignored): one of [`NAMES`], or `zns-debenham`,
    /// `mgf2-dodge`, `pc` (polycarbonate), or the substrates `bk7` (`n-bk7`) and `si`
    /// (`silicon`, absorbing: [`SI_GREEN`]).
    pub fn by_name(name: &str) -> Option<Dispersion> {
        let is = |s: &str| name.eq_ignore_ascii_case(s);
        Some(if is("mgf2") || is("mgf2-dodge") {
            MGF2_DODGE_O
        } else if is("caf2") {
            CAF2_MALITSON
        } else if is("sio2") {
            SIO2_MALITSON
        } else if is("pmma") {
            pmma_sultanova()
        } else if is("polycarbonate") || is("pc") {
            polycarbonate_sultanova()
        } else if is("al2o3") {
            AL2O3_MALITSON_O
        } else if is("hfo2-film") {
            HFO2_FILM_AL_KUHAILI
        } else if is("y2o3") {
            Y2O3_NIGARA
        } else if is("si3n4") {
            SI3N4_LUKE
        } else if is("hfo2") {
            HFO2_WOOD
        } else if is("ta2o5") {
            TA2O5_GAO
        } else if is("zro2") {
            ZRO2_WOOD
        } else if is("nb2o5") {
            NB2O5_LEMARCHAND
        } else if is("zns") || is("zns-debenham") {
            zns_debenham()
        } else if is("tio2") {
            tio2_devore_o()
        } else if is("bk7") || is("n-bk7") {
            bk7_schott()
        } else if is("si") || is("silicon") {
            SI_GREEN
        } else {
            return None;
        })
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        /// n at 550 nm of every material, each worked out by hand from the formula in its
        /// doc comment (in f64, in a separate script), to 1e-6.
        #[test]
        fn every_material_gives_its_formulas_n_at_550_nm() {
            let expected = [
                ("mgf2", 1.378506),
                ("caf2", 1.434826),
                ("sio2", 1.459911),
                ("pmma", 1.492588),
                ("polycarbonate", 1.589228),
                ("al2o3", 1.770446),
                ("hfo2-film", 1.902099),
                ("y2o3", 1.936703),
                ("si3n4", 2.052301),
                ("hfo2", 2.117362),
                ("ta2o5", 2.157265),
                ("zro2", 2.166109),
                ("nb2o5", 2.359627),
                ("zns", 2.386210),
                ("tio2", 2.647935),
            ];
            assert_eq!(expected.len(), NAMES.len());
            let mut last = 0.0;
            for ((name, n), listed) in expected.iter().zip(NAMES) {
                assert_eq!(*name, listed, "NAMES is in the order of the table");
                let got = by_name(name).expect(name).index_at(550.0);
                assert!((got - n).abs() < 1e-6, "{name}: {got} against {n}");
                assert!(got > last, "{name}: NAMES rise in n(550)");
                last = got;
            }
        }

        /// Normal dispersion over the visible for every material, names are case-blind, the
        /// older names still work, and an unknown name is `None`.
        #[test]
        fn lookup_and_normal_dispersion() {
            for name in NAMES {
                let d = by_name(name).expect(name);
                assert!(d.index_at(400.0) > d.index_at(550.0), "{name}");
                assert!(d.index_at(550.0) > d.index_at(760.0), "{name}");
            }
            assert_eq!(by_name("TiO2"), by_name("tio2"));
            assert_eq!(by_name("zns-debenham"), Some(zns_debenham()));
            assert_eq!(by_name("mgf2-dodge"), Some(MGF2_DODGE_O));
            assert_eq!(by_name("pc"), Some(polycarbonate_sultanova()));
            assert_eq!(by_name("unobtainium"), None);
            let bk7 = by_name("N-BK7").expect("bk7");
            // SCHOTT's datasheet: n_d = 1.5168 at 587.6 nm.
            assert!((bk7.index_at(587.56) - 1.5168).abs() < 1e-4);
        }

        /// The Gao 2012 Ta2O5 and Lemarchand 2013 Nb2O5 fits against their tables' values.
        #[test]
        fn thin_film_fits_match_their_tables() {
            for (d, table) in [
                (
                    TA2O5_GAO,
                    [(400.0, 2.246896), (550.0, 2.157262), (700.0, 2.124149)],
                ),
                (
                    NB2O5_LEMARCHAND,
                    [(400.0, 2.544428), (550.0, 2.360317), (700.0, 2.301291)],
                ),
            ] {
                for (l, n) in table {
                    assert!((d.index_at(l) - n).abs() < 1.2e-3, "{l}: {}", d.index_at(l));
                }
            }
        }
    }
}
