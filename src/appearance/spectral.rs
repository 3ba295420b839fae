//! The film's colour from its reflectance model: the Airy sum of the estimated stack,
//! summed to CIE XYZ (whole visible spectrum for renders, the capture's bands through
//! their passbands for comparisons with measurements). A film that absorbs (a tabulated
//! `k`, or the absorption the sample fit found) is modelled with its complex index.

use filmscope_core::colour::{Colorimetry, Xyz};
use filmscope_core::optics::{BandModel, FilmStack, LossyFilm, Passband};
use filmscope_core::solve::refine::{absorption_shape, FilmTerms};

/// Quadrature nodes per passband when a band's reflectance is modelled for colour (the
/// same as the evaluation's spectral RMSE: within 1e-4 of the converged band average for
/// the 4 nm LCTF bands).
pub const PASSBAND_NODES: usize = 9;

/// The passbands of a capture's bands: Gaussian, centre and FWHM per band.
pub fn capture_passbands(bands_nm: &[f64], fwhm_nm: &[f64]) -> Vec<Passband> {
    bands_nm
        .iter()
        .zip(fwhm_nm)
        .map(|(&c, &f)| Passband::gaussian_with_nodes(c, f, PASSBAND_NODES))
        .collect()
}

/// One band's reflectance model at one angle: the clear film's Airy sum, or, where the
/// film absorbs at any of the passband's nodes or the polariser leaks, each node's
/// absorbing film ([`LossyFilm`], exact).
#[derive(Clone, Debug)]
pub enum BandReflectance {
    /// A clear film in pure light.
    Clear(Box<BandModel>),
    /// Each passband node's weight and lossy film (`None` where a wave does not propagate).
    Lossy(Vec<(f64, Option<LossyFilm>)>),
}

impl BandReflectance {
    /// `stack` at `incidence_deg` through `band`, the film's extinction being its own
    /// dispersion's (a table's `k`) plus `terms.film_k` with its tail to the blue, the
    /// other polarisation's share `terms.leak`.
    pub fn new(stack: &FilmStack, incidence_deg: f64, band: Passband, terms: FilmTerms) -> Self {
        let k_at = |l: f64| stack.film.extinction_at(l) + terms.film_k * absorption_shape(l);
        if terms.leak == 0.0 && band.nodes().all(|(l, _)| k_at(l) == 0.0) {
            return Self::Clear(Box::new(BandModel::new(*stack, incidence_deg, band)));
        }
        Self::Lossy(
            band.nodes()
                .map(|(l, w)| {
                    let film = LossyFilm::with_leak(
                        stack.indices_at(l),
                        k_at(l),
                        incidence_deg,
                        stack.polarization,
                        l,
                        terms.leak,
                    );
                    (w, film)
                })
                .collect(),
        )
    }

    /// The band's reflectance at thickness `d` nm (NaN where a wave does not propagate).
    pub fn reflectance(&self, d: f64) -> f64 {
        match self {
            Self::Clear(m) => m.reflectance(d),
            Self::Lossy(nodes) => nodes
                .iter()
                .map(|(w, f)| {
                    f.map_or(f64::NAN, |f| {
                        let (delta, a) = f.round_trip(d);
                        w * f.reflectance(delta.cos(), delta.sin(), a).0
                    })
                })
                .sum(),
        }
    }
}

/// A stack's reflectance at one angle through a set of passbands, precomputed so that
/// each thickness costs a few cosines per node.
#[derive(Clone, Debug)]
pub struct BandSpectrum {
    models: Vec<BandReflectance>,
}

impl BandSpectrum {
    /// `stack` seen at `incidence_deg` through `bands`, with the film terms `terms`
    /// ([`BandReflectance::new`]).
    pub fn new(stack: FilmStack, incidence_deg: f64, bands: &[Passband], terms: FilmTerms) -> Self {
        Self {
            models: bands
                .iter()
                .map(|b| BandReflectance::new(&stack, incidence_deg, *b, terms))
                .collect(),
        }
    }

    /// The band-averaged reflectances of a film of `thickness_nm`, into `out` (one per
    /// band; extra entries of `out` are left alone).
    pub fn reflectance_into(&self, thickness_nm: f64, out: &mut [f64]) {
        for (o, m) in out.iter_mut().zip(&self.models) {
            *o = m.reflectance(thickness_nm);
        }
    }

    /// The band-averaged reflectance of band `band` for a film of `thickness_nm` (NaN
    /// beyond the bands).
    pub fn band(&self, band: usize, thickness_nm: f64) -> f64 {
        self.models
            .get(band)
            .map_or(f64::NAN, |m| m.reflectance(thickness_nm))
    }

    /// Number of bands.
    pub fn len(&self) -> usize {
        self.models.len()
    }

    /// Whether there are no bands.
    pub fn is_empty(&self) -> bool {
        self.models.is_empty()
    }
}

/// A stack's colour at one angle: its reflectance at the grid wavelengths of a
/// [`Colorimetry`] (monochromatic: the full spectrum a camera or eye integrates), summed
/// to XYZ.
#[derive(Clone, Debug)]
pub struct FilmColour {
    spectrum: BandSpectrum,
    colorimetry: Colorimetry,
}

impl FilmColour {
    /// `stack` seen at `incidence_deg` with the film terms `terms`, summed with
    /// `colorimetry`.
    pub fn new(
        stack: FilmStack,
        incidence_deg: f64,
        colorimetry: Colorimetry,
        terms: FilmTerms,
    ) -> Self {
        let bands: Vec<Passband> = colorimetry
            .wavelengths_nm()
            .map(Passband::monochromatic)
            .collect();
        Self {
            spectrum: BandSpectrum::new(stack, incidence_deg, &bands, terms),
            colorimetry,
        }
    }

    /// XYZ of a film of `thickness_nm` (`Y = 100` for a perfect reflector);
    /// [`Xyz::NAN`] for a non-finite thickness.
    pub fn xyz(&self, thickness_nm: f64) -> Xyz {
        if !thickness_nm.is_finite() {
            return Xyz::NAN;
        }
        let mut r = [0.0; filmscope_core::colour::tables::GRID_LEN];
        let n = self.spectrum.len();
        self.spectrum.reflectance_into(thickness_nm, &mut r[..n]);
        self.colorimetry.xyz_of(&r[..n])
    }

    /// The colorimetry the colour is summed with.
    pub fn colorimetry(&self) -> &Colorimetry {
        &self.colorimetry
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use filmscope_core::optics::{BackFace, Dispersion, Polarization};

    fn stack(film: Dispersion) -> FilmStack {
        FilmStack {
            back_face: BackFace::None,
            ambient_index: 1.0,
            film,
            substrate: Dispersion::constant(1.45),
            polarization: Polarization::S,
        }
    }

    /// The absorbing, leaking film's model (the lossy film's own coefficients) meets the
    /// clear film's Airy sum as its extinction and leak go to nothing.
    #[test]
    fn the_film_terms_model_meets_the_clear_film_at_no_absorption() {
        let stack = stack(Dispersion::constant(1.62));
        let band = Passband::gaussian(530.0, 6.0);
        let clear = BandReflectance::new(&stack, 35.0, band, FilmTerms::NONE);
        let faint = BandReflectance::new(
            &stack,
            35.0,
            band,
            FilmTerms {
                film_k: 1e-12,
                leak: 0.0,
            },
        );
        assert!(matches!(faint, BandReflectance::Lossy(_)));
        for d in [50.0, 333.0, 1200.0] {
            let (c, f) = (clear.reflectance(d), faint.reflectance(d));
            assert!((c - f).abs() < 1e-9, "{d} nm: clear {c}, lossy {f}");
        }
    }

    /// A film whose table has `k` is modelled absorbing: its fringes fade with thickness,
    /// and a film too thick to return light from its back reflects as the bare absorbing
    /// surface, `((n - 1)^2 + k^2) / ((n + 1)^2 + k^2)` at normal incidence.
    #[test]
    fn a_tabulated_k_film_absorbs() {
        static ROWS: [[f64; 3]; 2] = [[0.38, 2.0, 0.05], [0.78, 2.0, 0.05]];
        let absorbing = stack(Dispersion::Table { rows: &ROWS });
        let band = Passband::monochromatic(500.0);
        let m = BandReflectance::new(&absorbing, 0.0, band, FilmTerms::NONE);
        assert!(matches!(m, BandReflectance::Lossy(_)));
        let surface = (1.0 + 0.05f64.powi(2)) / (9.0 + 0.05f64.powi(2));
        let r = m.reflectance(20_000.0);
        assert!(
            (r - surface).abs() < 1e-9,
            "thick film {r}, surface {surface}"
        );
        // Peak-to-valley of the fringes over one order near 100 nm and near 2 um.
        let swing = |d0: f64| {
            let r: Vec<f64> = (0..200)
                .map(|i| m.reflectance(d0 + f64::from(i) * 0.7))
                .collect();
            r.iter().copied().fold(f64::MIN, f64::max) - r.iter().copied().fold(f64::MAX, f64::min)
        };
        let clear = BandReflectance::new(
            &stack(Dispersion::constant(2.0)),
            0.0,
            band,
            FilmTerms::NONE,
        );
        assert!(matches!(clear, BandReflectance::Clear(_)));
        assert!(
            swing(2000.0) < 0.5 * swing(100.0),
            "{} {}",
            swing(2000.0),
            swing(100.0)
        );
    }
}
