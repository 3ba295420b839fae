//! Reflectance spectrum -> CIE 1931 XYZ (5 nm rectangle-rule sum), under D65 or any
//! [`Illuminant`], over the whole grid or a part of it ([`Colorimetry`]).

use super::illuminant::Illuminant;
use super::tables::{
    CIE1931_XBAR, CIE1931_YBAR, CIE1931_ZBAR, D65_SPD, GRID_LEN, GRID_START_NM, GRID_STEP_NM,
};

/// CIE 1931 tristimulus values (2-degree observer), on the scale where the
/// reference white has `Y = 100` (dimensionless).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Xyz {
    /// Tristimulus X.
    pub x: f64,
    /// Tristimulus Y (luminance factor x 100 for reflecting samples).
    pub y: f64,
    /// Tristimulus Z.
    pub z: f64,
}

impl Xyz {
    /// All three components NaN: the result for invalid input.
    pub const NAN: Xyz = Xyz {
        x: f64::NAN,
        y: f64::NAN,
        z: f64::NAN,
    };
}

/// Rectangle-rule ("Integration") sum over grid samples `first..end` under the
/// illuminant `spd`: `X = k * sum R(l) S(l) xbar(l)` (same for Y, Z),
/// `k = 100 / sum S(l) ybar(l)` over the same samples, so a perfect reflector has
/// `Y = 100`. The single summation used by every public entry point (and by the
/// const white). `first < end <= GRID_LEN` is the caller's invariant.
const fn integrate_range(
    reflectance: &[f64; GRID_LEN],
    spd: &[f64; GRID_LEN],
    first: usize,
    end: usize,
) -> Xyz {
    let mut denom = 0.0;
    let mut i = first;
    while i < end {
        denom += spd[i] * CIE1931_YBAR[i];
        i += 1;
    }
    let mut sx = 0.0;
    let mut sy = 0.0;
    let mut sz = 0.0;
    let mut i = first;
    while i < end {
        let rs = reflectance[i] * spd[i];
        sx += rs * CIE1931_XBAR[i];
        sy += rs * CIE1931_YBAR[i];
        sz += rs * CIE1931_ZBAR[i];
        i += 1;
    }
    let k = 100.0 / denom;
    Xyz {
        x: k * sx,
        y: k * sy,
        z: k * sz,
    }
}

/// The whole grid under D65: the convention of [`reflectance_to_xyz`].
const fn integrate(reflectance: &[f64; GRID_LEN]) -> Xyz {
    integrate_range(reflectance, &D65_SPD, 0, GRID_LEN)
}

/// XYZ of the perfect reflector (R = 1 at every wavelength) under D65, computed
/// from the tables with the same sum as [`reflectance_to_xyz`]:
/// about (95.043, 100, 108.880). This is the white point for [`Xyz::to_lab`].
pub const D65_WHITE_XYZ: Xyz = integrate(&[1.0; GRID_LEN]);

/// How spectra become XYZ: the illuminant, and the part of the 5 nm grid
/// 380..=780 nm that is summed.
///
/// [`Colorimetry::full`] sums the whole visible grid (with D65 this is exactly
/// [`reflectance_to_xyz`] / [`reflectance_fn_to_xyz`]). [`Colorimetry::within`]
/// sums only the grid wavelengths inside a sampled range, e.g. a camera's
/// 420..720 nm bands, and normalises over that same range: a perfect reflector
/// still has `Y = 100`, and [`Colorimetry::white`] is its XYZ, the white for
/// [`Xyz::to_lab`]. That is CIE colorimetry restricted to what was measured (as
/// colour-science's `sd_to_XYZ(..., method="Integration")` with the colour matching
/// functions and illuminant trimmed to the range), with nothing extrapolated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Colorimetry {
    illuminant: Illuminant,
    first: usize,
    end: usize,
}

impl Illuminant {
    /// XYZ of the perfect reflector under this illuminant over the whole grid
    /// (`Y = 100`): its white point.
    pub fn white(self) -> Xyz {
        Colorimetry::full(self).white()
    }
}

impl Colorimetry {
    /// The whole grid 380..=780 nm under `illuminant`.
    pub const fn full(illuminant: Illuminant) -> Self {
        Self {
            illuminant,
            first: 0,
            end: GRID_LEN,
        }
    }

    /// The grid wavelengths `g` with `first_nm <= g <= last_nm` under `illuminant`;
    /// `None` when the range holds no grid wavelength or is not finite.
    pub fn within(illuminant: Illuminant, first_nm: f64, last_nm: f64) -> Option<Self> {
        if !(first_nm.is_finite() && last_nm.is_finite()) {
            return None;
        }
        let first = (0..GRID_LEN).find(|&i| grid_nm(i) >= first_nm)?;
        let end = (0..GRID_LEN).rev().find(|&i| grid_nm(i) <= last_nm)? + 1;
        (first < end).then_some(Self {
            illuminant,
            first,
            end,
        })
    }

    /// The illuminant.
    pub const fn illuminant(&self) -> Illuminant {
        self.illuminant
    }

    /// The first and last grid wavelength summed, nm.
    pub fn range_nm(&self) -> (f64, f64) {
        (grid_nm(self.first), grid_nm(self.end - 1))
    }

    /// XYZ of a spectrum given on the whole grid.
    fn of_grid(&self, grid: &[f64; GRID_LEN]) -> Xyz {
        integrate_range(grid, self.illuminant.spd(), self.first, self.end)
    }

    /// XYZ of the perfect reflector: `Y = 100`; the white for [`Xyz::to_lab`].
    pub fn white(&self) -> Xyz {
        self.of_grid(&[1.0; GRID_LEN])
    }

    /// The grid wavelengths summed, in nm, ascending.
    pub fn wavelengths_nm(&self) -> impl Iterator<Item = f64> {
        (self.first..self.end).map(grid_nm)
    }

    /// XYZ of a reflectance given at exactly the wavelengths of
    /// [`Colorimetry::wavelengths_nm`], in that order; [`Xyz::NAN`] if `reflectance`
    /// has another length.
    pub fn xyz_of(&self, reflectance: &[f64]) -> Xyz {
        if reflectance.len() != self.end - self.first {
            return Xyz::NAN;
        }
        let mut grid = [0.0; GRID_LEN];
        grid[self.first..self.end].copy_from_slice(reflectance);
        self.of_grid(&grid)
    }

    /// XYZ of a reflectance given as a function of wavelength in nm, evaluated at
    /// the grid wavelengths summed.
    pub fn xyz_fn(&self, f: impl Fn(f64) -> f64) -> Xyz {
        let mut grid = [0.0; GRID_LEN];
        for (i, r) in grid.iter_mut().enumerate().take(self.end).skip(self.first) {
            *r = f(grid_nm(i));
        }
        self.of_grid(&grid)
    }

    /// XYZ of a reflectance sampled at `wavelength_nm` (strictly increasing),
    /// linearly interpolated onto the grid (edge values held outside the samples,
    /// which matters only for [`Colorimetry::full`]). [`Xyz::NAN`] for invalid input,
    /// as [`reflectance_to_xyz`].
    pub fn xyz_sampled(&self, wavelength_nm: &[f64], reflectance: &[f64]) -> Xyz {
        match resample_to_grid(wavelength_nm, reflectance) {
            Some(grid) => self.of_grid(&grid),
            None => Xyz::NAN,
        }
    }
}

/// Function form of [`D65_WHITE_XYZ`].
pub const fn d65_white() -> Xyz {
    D65_WHITE_XYZ
}

/// Wavelength of grid sample `i`, in nanometres (380, 385, ..., 780).
fn grid_nm(i: usize) -> f64 {
    GRID_START_NM + i as f64 * GRID_STEP_NM
}

/// Linearly interpolates `(wavelength_nm, reflectance)` onto the 5 nm grid,
/// holding the edge values outside the sampled range (like `numpy.interp`).
/// `None` if the lengths differ, are zero, or the wavelengths are not finite
/// and strictly increasing.
fn resample_to_grid(wavelength_nm: &[f64], reflectance: &[f64]) -> Option<[f64; GRID_LEN]> {
    let n = wavelength_nm.len();
    if n == 0 || n != reflectance.len() {
        return None;
    }
    if wavelength_nm.iter().any(|w| !w.is_finite())
        || wavelength_nm.windows(2).any(|w| w[1] <= w[0])
    {
        return None;
    }
    let (first_nm, last_nm) = (wavelength_nm[0], wavelength_nm[n - 1]);
    let mut out = [0.0; GRID_LEN];
    // Invariant inside the range: wavelength_nm[j] <= g < wavelength_nm[j + 1].
    let mut j = 0;
    for (i, o) in out.iter_mut().enumerate() {
        let g = grid_nm(i);
        *o = if g <= first_nm {
            reflectance[0]
        } else if g >= last_nm {
            reflectance[n - 1]
        } else {
            while wavelength_nm[j + 1] <= g {
                j += 1;
            }
            let (w0, w1) = (wavelength_nm[j], wavelength_nm[j + 1]);
            let (r0, r1) = (reflectance[j], reflectance[j + 1]);
            r0 + (g - w0) / (w1 - w0) * (r1 - r0)
        };
    }
    Some(out)
}

/// XYZ under D65 (2-degree observer, `Y = 100` for a perfect reflector) of a
/// reflectance spectrum sampled at `wavelength_nm` (nanometres, strictly
/// increasing, any spacing; e.g. camera bands 420..720 nm).
///
/// The spectrum is linearly interpolated onto the CIE grid 380..=780 nm every
/// 5 nm; outside the sampled range the nearest edge value is held. The XYZ is
/// then the plain sum over the grid (see [`reflectance_fn_to_xyz`]).
///
/// Returns [`Xyz::NAN`] (never panics) if the slices are empty, of different
/// lengths, or the wavelengths are not finite and strictly increasing.
pub fn reflectance_to_xyz(wavelength_nm: &[f64], reflectance: &[f64]) -> Xyz {
    match resample_to_grid(wavelength_nm, reflectance) {
        Some(grid) => integrate(&grid),
        None => Xyz::NAN,
    }
}

/// XYZ under D65 (2-degree observer, `Y = 100` for a perfect reflector) of a
/// reflectance given as a function of wavelength in nanometres, evaluated at
/// the 81 grid wavelengths 380, 385, ..., 780 nm.
///
/// `X = k * sum R(l) S(l) xbar(l)` (likewise Y, Z) with `S` = D65 and
/// `k = 100 / sum S(l) ybar(l)`: the rectangle ("Integration") rule.
pub fn reflectance_fn_to_xyz(f: impl Fn(f64) -> f64) -> Xyz {
    let mut grid = [0.0; GRID_LEN];
    for (i, r) in grid.iter_mut().enumerate() {
        *r = f(grid_nm(i));
    }
    integrate(&grid)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perfect_reflector_has_y_100() {
        let w = reflectance_fn_to_xyz(|_| 1.0);
        assert_eq!(w, D65_WHITE_XYZ);
        assert!((w.y - 100.0).abs() < 1e-12);
        // Well-known D65 2-degree white from the 5 nm tables.
        assert!((w.x - 95.04).abs() < 0.01, "{w:?}");
        assert!((w.z - 108.88).abs() < 0.01, "{w:?}");
    }

    #[test]
    fn sampled_constant_matches_closure() {
        let wl = [420.0, 500.0, 720.0];
        let r = [0.5, 0.5, 0.5];
        let a = reflectance_to_xyz(&wl, &r);
        let b = reflectance_fn_to_xyz(|_| 0.5);
        assert_eq!(a, b);
    }

    #[test]
    fn single_sample_is_constant() {
        let a = reflectance_to_xyz(&[550.0], &[0.25]);
        let b = reflectance_fn_to_xyz(|_| 0.25);
        assert_eq!(a, b);
    }

    #[test]
    fn interpolation_and_edge_hold_match_closure() {
        // A linear ramp sampled every 10 nm over 420..=720 equals the closure
        // that clamps to the same ramp.
        let ramp = |l: f64| 0.1 + 0.002 * (l.clamp(420.0, 720.0) - 420.0);
        let wl: Vec<f64> = (0..=30).map(|i| 420.0 + 10.0 * i as f64).collect();
        let r: Vec<f64> = wl.iter().map(|&l| ramp(l)).collect();
        let a = reflectance_to_xyz(&wl, &r);
        let b = reflectance_fn_to_xyz(ramp);
        for (p, q) in [(a.x, b.x), (a.y, b.y), (a.z, b.z)] {
            assert!((p - q).abs() < 1e-12, "{a:?} {b:?}");
        }
    }

    #[test]
    fn full_d65_colorimetry_is_the_default_convention() {
        let c = Colorimetry::full(Illuminant::D65);
        assert_eq!(c.white(), D65_WHITE_XYZ);
        let f = |l: f64| 0.3 + 0.2 * libm::sin(l / 37.0);
        assert_eq!(c.xyz_fn(f), reflectance_fn_to_xyz(f));
        assert_eq!(c.range_nm(), (380.0, 780.0));
    }

    #[test]
    fn within_sums_only_the_range_and_keeps_white_at_100() {
        let c = Colorimetry::within(Illuminant::A, 421.0, 720.0).expect("range");
        assert_eq!(c.range_nm(), (425.0, 720.0));
        assert!((c.white().y - 100.0).abs() < 1e-12);
        // Reflectance outside the range does not count.
        let inside = c.xyz_fn(|l| {
            if (425.0..=720.0).contains(&l) {
                0.5
            } else {
                9.0
            }
        });
        assert!((inside.y - 50.0).abs() < 1e-12, "{inside:?}");
        let wl: [f64; 60] = core::array::from_fn(|i| 425.0 + 5.0 * i as f64);
        assert!(c.wavelengths_nm().eq(wl.iter().copied()));
        assert_eq!(c.xyz_of(&[0.5; 60]), inside);
        assert!(c.xyz_of(&[0.5; 59]).y.is_nan());
        assert!(Colorimetry::within(Illuminant::D65, 381.0, 384.0).is_none());
        assert!(Colorimetry::within(Illuminant::D65, f64::NAN, 500.0).is_none());
    }

    #[test]
    fn invalid_input_gives_nan() {
        for (wl, r) in [
            (&[][..], &[][..]),
            (&[400.0, 500.0][..], &[0.1][..]),
            (&[500.0, 400.0][..], &[0.1, 0.2][..]),
            (&[500.0, 500.0][..], &[0.1, 0.2][..]),
            (&[f64::NAN][..], &[0.1][..]),
        ] {
            let x = reflectance_to_xyz(wl, r);
            assert!(x.x.is_nan() && x.y.is_nan() && x.z.is_nan());
        }
    }

    #[test]
    fn whites_are_the_known_ones() {
        // CIE 015 2-degree whites from the 5 nm tables (Y = 100).
        let a = Illuminant::A.white();
        assert!(
            (a.x - 109.85).abs() < 0.02 && (a.z - 35.58).abs() < 0.02,
            "{a:?}"
        );
        let d50 = Illuminant::D50.white();
        assert!(
            (d50.x - 96.42).abs() < 0.02 && (d50.z - 82.52).abs() < 0.02,
            "{d50:?}"
        );
    }
}
