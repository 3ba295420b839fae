//! Band averaging through an LCTF passband.
//!
//! A band of centre `c` and full width at half maximum `w` is modelled as a Gaussian in
//! wavelength, `exp(-4 ln2 (lambda - c)^2 / w^2)`, truncated to `|lambda - c| <= 1.5 w`
//! (99.9 % of its area) and normalised; the average is a composite Simpson sum over
//! a fixed number of nodes held in the struct (no allocation). The same definition made the
//! `tmm` reference fixture, `tests/fixtures/optics/tmm_passband.csv`.

/// Largest number of quadrature nodes a [`Passband`] holds.
pub const MAX_NODES: usize = 65;

/// Default number of nodes: band-averaged reflectance within 1e-6 of the converged value for
/// fringes of period down to about one FWHM.
pub const DEFAULT_NODES: usize = 33;

/// Half-width of the truncated Gaussian, in FWHMs.
pub const HALF_WIDTH_FWHM: f64 = 1.5;

/// A passband with its quadrature nodes and weights (weights sum to 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Passband {
    /// Centre wavelength, nm.
    pub center_nm: f64,
    /// Full width at half maximum, nm (0 for an ideal monochromatic band).
    pub fwhm_nm: f64,
    n: usize,
    lambda_nm: [f64; MAX_NODES],
    weight: [f64; MAX_NODES],
}

impl Passband {
    /// An ideal band: the reflectance at `center_nm` itself.
    pub fn monochromatic(center_nm: f64) -> Self {
        let mut lambda_nm = [0.0; MAX_NODES];
        let mut weight = [0.0; MAX_NODES];
        lambda_nm[0] = center_nm;
        weight[0] = 1.0;
        Self {
            center_nm,
            fwhm_nm: 0.0,
            n: 1,
            lambda_nm,
            weight,
        }
    }

    /// A Gaussian band with [`DEFAULT_NODES`] nodes.
    pub fn gaussian(center_nm: f64, fwhm_nm: f64) -> Self {
        Self::gaussian_with_nodes(center_nm, fwhm_nm, DEFAULT_NODES)
    }

    /// A Gaussian band with `nodes` Simpson nodes (made odd and clamped to `3..=MAX_NODES`).
    /// A zero or non-finite width gives [`Passband::monochromatic`].
    pub fn gaussian_with_nodes(center_nm: f64, fwhm_nm: f64, nodes: usize) -> Self {
        if fwhm_nm.is_nan() || fwhm_nm <= 0.0 || !fwhm_nm.is_finite() {
            return Self::monochromatic(center_nm);
        }
        let mut n = nodes.clamp(3, MAX_NODES);
        if n % 2 == 0 {
            n -= 1;
        }
        let half = HALF_WIDTH_FWHM * fwhm_nm;
        let h = 2.0 * half / (n - 1) as f64;
        let mut lambda_nm = [0.0; MAX_NODES];
        let mut weight = [0.0; MAX_NODES];
        let mut total = 0.0;
        for i in 0..n {
            let l = center_nm - half + h * i as f64;
            let simpson = if i == 0 || i == n - 1 {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            let x = (l - center_nm) / fwhm_nm;
            let w = simpson * libm::exp(-4.0 * core::f64::consts::LN_2 * x * x);
            lambda_nm[i] = l;
            weight[i] = w;
            total += w;
        }
        for w in &mut weight[..n] {
            *w /= total;
        }
        Self {
            center_nm,
            fwhm_nm,
            n,
            lambda_nm,
            weight,
        }
    }

    /// The nodes as `(wavelength_nm, weight)` pairs.
    pub fn nodes(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.lambda_nm[..self.n]
            .iter()
            .copied()
            .zip(self.weight[..self.n].iter().copied())
    }

    /// The passband-weighted mean of `f(wavelength_nm)`.
    #[inline]
    pub fn average(&self, mut f: impl FnMut(f64) -> f64) -> f64 {
        let mut s = 0.0;
        for i in 0..self.n {
            s += self.weight[i] * f(self.lambda_nm[i]);
        }
        s
    }
}
