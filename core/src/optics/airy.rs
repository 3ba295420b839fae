//! The Airy sum: reflectance of one film on a substrate (method.md eqs. 2-5).
//!
//! `r = (r12 + r23 e^{i Delta}) / (1 + r12 r23 e^{i Delta})`, `Delta = 4 pi d kz2 / lambda` with
//! `kz2 = n2 cos(theta2)`, and `R = |r|^2`. The reflection phases are carried by the signs of
//! `r12` and `r23`, so a film whose index is above the substrate's (ZnS on PET) gets its
//! half-order peaks, `(m + 1/2) lambda = phi`, by construction: nothing here assumes where the
//! peaks sit.

use super::fresnel::{fresnel_r, fresnel_r_real, medium_wave, normal_component, snell_invariant};
use super::{Complex, Polarization};

/// The indices of an ambient / film / substrate stack at one wavelength (the substrate's
/// complex, `substrate + i substrate_k`), and whether light comes back from the substrate's far
/// side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Indices {
    /// Ambient medium (air = 1.0).
    pub ambient: f64,
    /// The film.
    pub film: f64,
    /// The substrate's (real) index.
    pub substrate: f64,
    /// The substrate's extinction coefficient: 0 for a clear substrate, above 0 for an
    /// absorbing one such as silicon (then taken as opaque: no back face returns light).
    pub substrate_k: f64,
    /// The substrate's back face.
    pub back_face: BackFace,
}

/// The substrate's back face: what becomes of the light the film lets through.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BackFace {
    /// Nothing returns: an index-matched or blackened back, or a substrate thick and lossy
    /// enough to be semi-infinite.
    #[default]
    None,
    /// A bare, flat back face into the ambient medium, the substrate transparent and much
    /// thicker than the coherence length: the light it reflects adds to the film's in
    /// intensity (incoherently), after any number of round trips.
    Bare,
}

impl BackFace {
    /// Parses the names used in capture and scene files: `none`, `bare`.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "none" => Some(Self::None),
            "bare" => Some(Self::Bare),
            _ => None,
        }
    }

    /// The name used in capture and scene files.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Bare => "bare",
        }
    }
}

/// The back face's reflectance `rb` for one pure polarisation (0 without one, and 0 for an
/// absorbing substrate, which no light crosses): the substrate-to-ambient interface at the
/// substrate's own angle. It is never beyond the critical angle, the light having entered
/// from the same ambient.
pub(super) fn back_reflectance(idx: Indices, beta: f64, pol: Polarization) -> f64 {
    if idx.back_face == BackFace::None || idx.substrate_k > 0.0 {
        return 0.0;
    }
    let k3 = idx.substrate * idx.substrate - beta * beta;
    let k4 = idx.ambient * idx.ambient - beta * beta;
    if k3 <= 0.0 || k4 <= 0.0 {
        return 0.0;
    }
    let r = fresnel_r_real(
        pol,
        idx.substrate,
        idx.ambient,
        libm::sqrt(k3),
        libm::sqrt(k4),
    );
    r * r
}

/// The film's reflectance `r` with the back face's `rb` added incoherently:
/// `r + (1 - r)^2 rb / (1 - r rb) = (r (1 - 2 rb) + rb) / (1 - r rb)` (a lossless film
/// transmits `1 - r` and reflects `r` from either side).
#[inline]
fn with_back(r: f64, rb: f64) -> f64 {
    (r * (1.0 - 2.0 * rb) + rb) / (1.0 - r * rb)
}

/// The substrate's permittivity and normal component ([`medium_wave`]).
fn substrate_wave(idx: Indices, beta: f64) -> (Complex, Complex) {
    medium_wave(idx.substrate, idx.substrate_k, beta)
}

/// `r23 = rho e^{i psi}` as a signed real `rho` and a phase `psi` in `(-pi/2, pi/2]`: `(r23, 0)`
/// exactly for a real `r23`.
fn signed_polar(r: Complex) -> (f64, f64) {
    if r.im == 0.0 {
        return (r.re, 0.0);
    }
    let rho = libm::hypot(r.re, r.im);
    if r.re >= 0.0 {
        (rho, libm::atan2(r.im, r.re))
    } else {
        (-rho, libm::atan2(-r.im, -r.re))
    }
}

/// Reflectance of the stack for one pure polarisation (S or P), general case: evanescent waves
/// (total internal reflection) are handled through complex normal components.
fn reflectance_pure(
    idx: Indices,
    thickness_nm: f64,
    incidence_deg: f64,
    wavelength_nm: f64,
    pol: Polarization,
) -> f64 {
    let beta = snell_invariant(idx.ambient, incidence_deg);
    let kz1 = normal_component(idx.ambient, beta);
    let kz2 = normal_component(idx.film, beta);
    let (eps1, eps2) = (idx.ambient * idx.ambient, idx.film * idx.film);
    let (eps3, kz3) = substrate_wave(idx, beta);
    let real = |e: f64| Complex::new(e, 0.0);
    let r12 = fresnel_r(pol, real(eps1), real(eps2), kz1, kz2);
    let r23 = fresnel_r(pol, real(eps2), eps3, kz2, kz3);
    // i * Delta, with Delta = 4 pi d kz2 / lambda (complex when the film wave is evanescent).
    let k = 4.0 * core::f64::consts::PI * thickness_nm / wavelength_nm;
    // e^{i Delta} through libm (not `Complex::exp`, whose exp, cos and sin are std's or
    // libm's depending on num-traits' features): the same bits in every build.
    let (re, im) = (-kz2.im * k, kz2.re * k);
    let m = libm::exp(re);
    let phase = Complex::new(m * libm::cos(im), m * libm::sin(im));
    let one = Complex::new(1.0, 0.0);
    let r = (r12 + r23 * phase) / (one + r12 * r23 * phase);
    with_back(r.norm_sqr(), back_reflectance(idx, beta, pol))
}

/// Reflectance `R` of a film of `thickness_nm` on its substrate, for light arriving at
/// `incidence_deg` from the ambient medium, at vacuum wavelength `wavelength_nm`.
///
/// `Unpolarized` is the mean of the S and P reflectances. Valid for any real indices and any
/// angle in `[0, 90)` degrees, total internal reflection included. `thickness_nm = 0` gives the
/// bare ambient/substrate interface (with the back face's return when it has one).
pub fn film_reflectance(
    idx: Indices,
    thickness_nm: f64,
    incidence_deg: f64,
    wavelength_nm: f64,
    pol: Polarization,
) -> f64 {
    match pol {
        Polarization::Unpolarized => {
            0.5 * (reflectance_pure(
                idx,
                thickness_nm,
                incidence_deg,
                wavelength_nm,
                Polarization::S,
            ) + reflectance_pure(
                idx,
                thickness_nm,
                incidence_deg,
                wavelength_nm,
                Polarization::P,
            ))
        }
        p => reflectance_pure(idx, thickness_nm, incidence_deg, wavelength_nm, p),
    }
}

/// The interface coefficients of one film at one angle, precomputed for fast evaluation over
/// many thicknesses and wavelengths (a real film index, propagating waves only).
///
/// For real `r12`, `r23` the Airy sum reduces to
/// `R = (r12^2 + r23^2 + 2 r12 r23 cos Delta) / (1 + r12^2 r23^2 + 2 r12 r23 cos Delta)`, a
/// monotonic function of `cos Delta`: peaks sit at `cos Delta = +1` when `r12 r23 > 0` and at
/// `cos Delta = -1` when `r12 r23 < 0` (see [`FilmAtAngle::peak_phase_offset`]). That is
/// `(A + B c) / (E + B c)`, and a bare back face keeps the form: its incoherent return is a
/// Moebius map of `R` with the same `c` coefficient in numerator and denominator,
/// `A' = (1 - 2 rb) A + rb E`, `B' = (1 - rb) B`, `E' = E - rb A`.
///
/// An absorbing substrate makes `r23 = rho e^{i psi}` complex; `R` is then the same function
/// of `c = cos(Delta + psi)` with `rho` for `r23`, so every caller evaluates the film at the
/// phase `Delta + `[`FilmAtAngle::phase_offset`]. Exact for S or P light; for unpolarised
/// light S and P have their own `psi` and one offset, their fringe-weighted mean, stands for
/// both (on silicon at 60 degrees they differ by 0.012 rad at 400 nm: 0.3 nm of an oxide's
/// thickness, 0.09 nm at 550 nm; 0 at normal incidence).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FilmAtAngle {
    /// `n2 cos(theta2)`: the optical path is `phi = 2 d kz_film`.
    pub kz_film: f64,
    /// `(r12, r23, rb)` for S, then P (P used only for unpolarised light): the interfaces'
    /// amplitude coefficients (`r23`'s signed modulus when complex) and the back face's
    /// reflectance (0 without one).
    coeffs: [(f64, f64, f64); 2],
    /// The phase `psi` of a complex `r23` added to `Delta` (0 on a clear substrate).
    psi: f64,
    /// 1 for S or P, 2 for unpolarised (mean of both).
    n_pol: usize,
}

impl FilmAtAngle {
    /// Precomputes the stack at one angle; `None` when a wave is evanescent in the film or
    /// (clear) substrate (use [`film_reflectance`] there).
    pub fn new(idx: Indices, incidence_deg: f64, pol: Polarization) -> Option<Self> {
        let beta = snell_invariant(idx.ambient, incidence_deg);
        let k1 = idx.ambient * idx.ambient - beta * beta;
        let k2 = idx.film * idx.film - beta * beta;
        let k3 = idx.substrate * idx.substrate - beta * beta;
        if k1 <= 0.0 || k2 <= 0.0 || (k3 <= 0.0 && idx.substrate_k == 0.0) {
            return None;
        }
        let (kz1, kz2) = (libm::sqrt(k1), libm::sqrt(k2));
        let (eps3, kz3) = substrate_wave(idx, beta);
        let eps2 = idx.film * idx.film;
        // `r23` and its phase: real (`psi` 0) on a clear substrate.
        let r23_of = |p| {
            if idx.substrate_k == 0.0 {
                (fresnel_r_real(p, idx.film, idx.substrate, kz2, kz3.re), 0.0)
            } else {
                let real = |e: f64| Complex::new(e, 0.0);
                signed_polar(fresnel_r(p, real(eps2), eps3, real(kz2), kz3))
            }
        };
        let pols = match pol {
            Polarization::Unpolarized => [Polarization::S, Polarization::P],
            p => [p, p],
        };
        let mut psi = [0.0; 2];
        let mut coeffs = [(0.0, 0.0, 0.0); 2];
        for ((c, ps), p) in coeffs.iter_mut().zip(&mut psi).zip(pols) {
            let (r23, phase) = r23_of(p);
            let r12 = fresnel_r_real(p, idx.ambient, idx.film, kz1, kz2);
            *c = (r12, r23, back_reflectance(idx, beta, p));
            *ps = phase;
        }
        let n_pol = if pol == Polarization::Unpolarized {
            2
        } else {
            1
        };
        // One phase for both polarisations: their mean weighted by each fringe's amplitude.
        let psi = if n_pol == 1 || psi[0] == psi[1] {
            psi[0]
        } else {
            let w = coeffs.map(|(r12, r23, _)| libm::fabs(r12 * r23));
            if w[0] + w[1] > 0.0 {
                (w[0] * psi[0] + w[1] * psi[1]) / (w[0] + w[1])
            } else {
                0.5 * (psi[0] + psi[1])
            }
        };
        Some(Self {
            kz_film: kz2,
            coeffs,
            psi,
            n_pol,
        })
    }

    /// The phase a caller adds to `Delta` before taking `c = cos(Delta + psi)` for
    /// [`FilmAtAngle::reflectance_at_cos`] and its kin: that of an absorbing substrate's
    /// `r23`, 0 on a clear one.
    #[inline]
    pub fn phase_offset(&self) -> f64 {
        self.psi
    }

    /// `(A, B, E)` of one polarisation's `(r12, r23, rb)`, the back face folded in (the
    /// fold skipped without one, which keeps the film-only results bit for bit).
    #[inline(always)]
    fn terms_of(&(r12, r23, rb): &(f64, f64, f64)) -> (f64, f64, f64) {
        let (a, b, e) = (
            r12 * r12 + r23 * r23,
            2.0 * r12 * r23,
            1.0 + r12 * r12 * r23 * r23,
        );
        if rb == 0.0 {
            (a, b, e)
        } else {
            ((1.0 - 2.0 * rb) * a + rb * e, (1.0 - rb) * b, e - rb * a)
        }
    }

    /// The optical path difference `phi = 2 d n2 cos(theta2)` in nm (eq. 8).
    #[inline]
    pub fn optical_path_nm(&self, thickness_nm: f64) -> f64 {
        2.0 * thickness_nm * self.kz_film
    }

    /// Reflectance at phase `Delta = 2 pi phi / lambda` (the substrate's phase added here).
    #[inline]
    pub fn reflectance_at_phase(&self, delta: f64) -> f64 {
        self.reflectance_at_cos(libm::cos(delta + self.psi))
    }

    /// How many polarisations the reflectance averages: 1 (S or P) or 2 (unpolarised).
    #[inline]
    pub fn polarizations(&self) -> usize {
        self.n_pol
    }

    /// Polarisation `pol`'s reflectance as `(A + B c) / (E + B c)` at `c = cos(Delta)`:
    /// `(A, B, E)`, each as [`FilmAtAngle::reflectance_at_cos`] computes it (the same
    /// results from them, bit for bit).
    #[inline]
    pub fn cos_terms(&self, pol: usize) -> (f64, f64, f64) {
        Self::terms_of(&self.coeffs[pol])
    }

    /// [`FilmAtAngle::reflectance_at_cos`] of a film of `P` [`FilmAtAngle::polarizations`],
    /// in a loop of fixed length, which a caller's loop over many `c` can vectorise.
    #[inline(always)]
    pub fn reflectance_at_cos_of<const P: usize>(&self, c: f64) -> f64 {
        let mut sum = 0.0;
        for t in &self.coeffs[..P] {
            let (a, b, e) = Self::terms_of(t);
            let bc = b * c;
            sum += (a + bc) / (e + bc);
        }
        sum / P as f64
    }

    /// [`FilmAtAngle::reflectance_and_slope_at_cos`] of a film of `P`
    /// [`FilmAtAngle::polarizations`], as [`FilmAtAngle::reflectance_at_cos_of`].
    #[inline(always)]
    pub fn reflectance_and_slope_at_cos_of<const P: usize>(&self, c: f64) -> (f64, f64) {
        let (mut r, mut slope) = (0.0, 0.0);
        for t in &self.coeffs[..P] {
            let (a, b, e) = Self::terms_of(t);
            let inv = 1.0 / (e + b * c);
            r += (a + b * c) * inv;
            slope += b * (e - a) * inv * inv;
        }
        let k = 1.0 / P as f64;
        (r * k, slope * k)
    }

    /// Reflectance as a function of `c = cos(Delta)` (or of a passband-damped `D cos(Delta)`).
    #[inline]
    pub fn reflectance_at_cos(&self, c: f64) -> f64 {
        if self.n_pol == 1 {
            self.reflectance_at_cos_of::<1>(c)
        } else {
            self.reflectance_at_cos_of::<2>(c)
        }
    }

    /// Reflectance and `d R / d c` at `c = cos(Delta)`, sharing each polarisation's
    /// denominator.
    #[inline]
    pub fn reflectance_and_slope_at_cos(&self, c: f64) -> (f64, f64) {
        if self.n_pol == 1 {
            self.reflectance_and_slope_at_cos_of::<1>(c)
        } else {
            self.reflectance_and_slope_at_cos_of::<2>(c)
        }
    }

    /// Reflectance of a film of `thickness_nm` at vacuum wavelength `wavelength_nm`.
    #[inline]
    pub fn reflectance(&self, thickness_nm: f64, wavelength_nm: f64) -> f64 {
        let delta =
            2.0 * core::f64::consts::PI * self.optical_path_nm(thickness_nm) / wavelength_nm;
        self.reflectance_at_phase(delta)
    }

    /// Where the reflectance peaks sit: `0.0` when peaks are at `phi = m lambda` (both
    /// reflections flip phase, or neither), `0.5` when they are at `phi = (m + 1/2) lambda`
    /// (film index above the substrate's, for S light). Valleys sit half an order away.
    /// Decided by the sign of `r12 r23` of the first polarisation (S for unpolarised light,
    /// whose S part dominates the fringe contrast away from normal incidence).
    pub fn peak_phase_offset(&self) -> f64 {
        let (r12, r23, _) = self.coeffs[0];
        if r12 * r23 >= 0.0 {
            0.0
        } else {
            0.5
        }
    }

    /// Fringe contrast: `R_max - R_min` over a full order (zero when the film is index-matched
    /// to either neighbour: no fringes to find).
    pub fn fringe_contrast(&self) -> f64 {
        (self.reflectance_at_cos(1.0) - self.reflectance_at_cos(-1.0)).abs()
    }
}
