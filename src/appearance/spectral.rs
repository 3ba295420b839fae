//! The film's colour from its reflectance model: the Airy sum of the estimated stack,
//! summed to CIE XYZ (whole visible spectrum for renders, the capture's bands through
//! their passbands for comparisons with measurements).

use filmscope_core::colour::{Colorimetry, Xyz};
use filmscope_core::optics::{BandModel, FilmStack, Passband};

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

/// A stack's reflectance at one angle through a set of passbands, precomputed so that
/// each thickness costs a few cosines per node.
#[derive(Clone, Debug)]
pub struct BandSpectrum {
    models: Vec<BandModel>,
}

impl BandSpectrum {
    /// `stack` seen at `incidence_deg` through `bands`.
    pub fn new(stack: FilmStack, incidence_deg: f64, bands: &[Passband]) -> Self {
        Self {
            models: bands
                .iter()
                .map(|b| BandModel::new(stack, incidence_deg, *b))
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
    /// `stack` seen at `incidence_deg`, summed with `colorimetry`.
    pub fn new(stack: FilmStack, incidence_deg: f64, colorimetry: Colorimetry) -> Self {
        let bands: Vec<Passband> = colorimetry
            .wavelengths_nm()
            .map(Passband::monochromatic)
            .collect();
        Self {
            spectrum: BandSpectrum::new(stack, incidence_deg, &bands),
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
