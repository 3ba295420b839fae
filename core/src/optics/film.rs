//! A film on a substrate as a whole: indices with their dispersion, and the polarisation the
//! camera sees. This is the BRDF model of method.md: `(n, d)` give the colour at any angle.

use super::airy::{film_reflectance, BackFace, FilmAtAngle, Indices};
use super::dispersion::Dispersion;
use super::passband::Passband;
use super::Polarization;

/// Ambient, film and substrate materials, and the polarisation of the measured light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FilmStack {
    /// Ambient index (air = 1.0).
    pub ambient_index: f64,
    /// The film's index against wavelength.
    pub film: Dispersion,
    /// The substrate's index against wavelength.
    pub substrate: Dispersion,
    /// The substrate's back face.
    pub back_face: BackFace,
    /// Polarisation of the measured light.
    pub polarization: Polarization,
}

impl FilmStack {
    /// The three indices at one wavelength.
    #[inline]
    pub fn indices_at(&self, wavelength_nm: f64) -> Indices {
        Indices {
            ambient: self.ambient_index,
            film: self.film.index_at(wavelength_nm),
            substrate: self.substrate.index_at(wavelength_nm),
            substrate_k: self.substrate.extinction_at(wavelength_nm),
            back_face: self.back_face,
        }
    }

    /// Reflectance at one wavelength (general Airy sum, total internal reflection included).
    pub fn reflectance(&self, thickness_nm: f64, incidence_deg: f64, wavelength_nm: f64) -> f64 {
        film_reflectance(
            self.indices_at(wavelength_nm),
            thickness_nm,
            incidence_deg,
            wavelength_nm,
            self.polarization,
        )
    }

    /// Reflectance averaged over a passband, the film's dispersion followed inside the band.
    pub fn band_reflectance(&self, thickness_nm: f64, incidence_deg: f64, band: &Passband) -> f64 {
        let constant = self.film.is_constant() && self.substrate.is_constant();
        let fast = if constant {
            FilmAtAngle::new(
                self.indices_at(band.center_nm),
                incidence_deg,
                self.polarization,
            )
        } else {
            None
        };
        match fast {
            Some(f) => band.average(|l| f.reflectance(thickness_nm, l)),
            None => band.average(|l| self.reflectance(thickness_nm, incidence_deg, l)),
        }
    }
}

/// The model of one band at one angle, precomputed so that evaluating it for many thicknesses
/// costs a few cosines per quadrature node: the indices (with dispersion) are fixed per node.
#[derive(Clone, Copy, Debug)]
pub struct BandModel {
    stack: FilmStack,
    incidence_deg: f64,
    band: Passband,
    fast: [Option<FilmAtAngle>; super::passband::MAX_NODES],
}

impl BandModel {
    /// Precomputes `stack` seen at `incidence_deg` through `band`.
    pub fn new(stack: FilmStack, incidence_deg: f64, band: Passband) -> Self {
        let mut fast = [None; super::passband::MAX_NODES];
        for (slot, (l, _)) in fast.iter_mut().zip(band.nodes()) {
            *slot = FilmAtAngle::new(stack.indices_at(l), incidence_deg, stack.polarization);
        }
        Self {
            stack,
            incidence_deg,
            band,
            fast,
        }
    }

    /// The passband.
    pub fn band(&self) -> &Passband {
        &self.band
    }

    /// Band-averaged reflectance of a film of `thickness_nm`.
    #[inline]
    pub fn reflectance(&self, thickness_nm: f64) -> f64 {
        let mut sum = 0.0;
        for (i, (l, w)) in self.band.nodes().enumerate() {
            let r = match &self.fast[i] {
                Some(f) => f.reflectance(thickness_nm, l),
                None => self.stack.reflectance(thickness_nm, self.incidence_deg, l),
            };
            sum += w * r;
        }
        sum
    }

    /// Band-averaged reflectance of a film of `thickness_nm` and its derivative with respect
    /// to the thickness, per nm: what a cubic Hermite table of the band over thickness needs
    /// at its nodes. Analytic at the quadrature nodes where the film and substrate waves
    /// propagate; a central difference of the general Airy sum (step 1e-3 nm, error far
    /// below 1e-9 per nm for fringes of period above 10 nm) where one is evanescent.
    pub fn reflectance_and_slope(&self, thickness_nm: f64) -> (f64, f64) {
        const STEP_NM: f64 = 1e-3;
        let (mut sum, mut slope) = (0.0, 0.0);
        for (i, (l, w)) in self.band.nodes().enumerate() {
            let (r, dr) = match &self.fast[i] {
                Some(f) => {
                    // Delta = 4 pi d kz / l; R = g(cos Delta); dR/dd = g'(c) (-sin Delta) 4 pi kz / l.
                    let k = 4.0 * core::f64::consts::PI * f.kz_film / l;
                    let delta = k * thickness_nm + f.phase_offset();
                    let (s, c) = (libm::sin(delta), libm::cos(delta));
                    let (r, dr_dc) = f.reflectance_and_slope_at_cos(c);
                    (r, -dr_dc * s * k)
                }
                None => {
                    let at = |d: f64| self.stack.reflectance(d, self.incidence_deg, l);
                    let up = at(thickness_nm + STEP_NM);
                    let down = at(thickness_nm - STEP_NM);
                    (at(thickness_nm), (up - down) / (2.0 * STEP_NM))
                }
            };
            sum += w * r;
            slope += w * dr;
        }
        (sum, slope)
    }
}
