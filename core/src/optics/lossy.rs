//! A film that absorbs: its reflectance, exact, as a function of the round trip's phase and
//! amplitude.
//!
//! A film of complex index `n + i k` has complex Fresnel coefficients `r12 = rho12 e^{i phi12}`
//! and `r23 = rho23 e^{i phi23}`, and its round trip multiplies a wave by `a e^{i Delta}`
//! (`Delta = 4 pi d Re(kz2) / lambda`, `a = exp(-4 pi d Im(kz2) / lambda)`). Then
//!
//! ```text
//! R = (rho12^2 + a^2 rho23^2 + 2 a rho12 rho23 cos(Delta + phi23 - phi12))
//!   / (1 + a^2 rho12^2 rho23^2 + 2 a rho12 rho23 cos(Delta + phi23 + phi12)),
//! ```
//!
//! whose numerator and denominator peak at different phases: the lossless films' form
//! `(A + B c) / (E + B c)` ([`super::FilmAtAngle`]) cannot hold it. A bare back face behind a
//! clear substrate returns `T^2 rb / (1 - R' rb)`, the film passing `T = kt a / D` of the
//! power each way (`D` the denominator above) and reflecting
//! `R' = (rho23^2 + a^2 rho12^2 + 2 a rho12 rho23 cos(Delta + phi12 - phi23)) / D` from the
//! substrate's side. Exact for S and P; unpolarised light is their mean. Validated against
//! `tmm` (`tests/optics_tmm.rs`).

use super::airy::back_reflectance;
use super::fresnel::{fresnel_r, medium_wave, snell_invariant};
use super::{Complex, Indices, Polarization};

/// One polarisation's coefficients of a [`LossyFilm`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Coefficients {
    rho12: f64,
    rho23: f64,
    /// `cos` and `sin` of `phi23 - phi12` (the numerator's phase) and of `phi23 + phi12`
    /// (the denominator's).
    num_phase: (f64, f64),
    den_phase: (f64, f64),
    /// The back face's reflectance (0 without one or on an absorbing substrate).
    rb: f64,
    /// `|t12 t23|^2 kz3 / kz1`: the power the film passes is `kt a / D`.
    kt: f64,
}

/// A film of complex index at one angle and wavelength ([`LossyFilm::new`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossyFilm {
    /// `Delta` per nm of thickness: `4 pi Re(kz2) / lambda`.
    pub phase_per_nm: f64,
    /// `-ln a` per nm of thickness: `4 pi Im(kz2) / lambda`.
    pub loss_per_nm: f64,
    coeffs: [Coefficients; 2],
    /// Each coefficient set's share of the light (S or P: `[1, 0]`; unpolarised: halves;
    /// a leaking polariser: `[1 - e, e]`).
    weights: [f64; 2],
    /// Coefficient sets with a share (1 or 2).
    n_pol: usize,
}

impl LossyFilm {
    /// The stack `idx` with the film's extinction coefficient `film_k` (`n + i k`, `k >= 0`)
    /// at `incidence_deg` and vacuum wavelength `wavelength_nm`; `None` where a wave does not
    /// propagate in the ambient or (clear) substrate.
    pub fn new(
        idx: Indices,
        film_k: f64,
        incidence_deg: f64,
        pol: Polarization,
        wavelength_nm: f64,
    ) -> Option<Self> {
        Self::with_leak(idx, film_k, incidence_deg, pol, wavelength_nm, 0.0)
    }

    /// [`LossyFilm::new`] in S or P light with the share `leak` of the other polarisation
    /// (a polariser's finite extinction; ignored for unpolarised light): both cross the same
    /// film, each with its own coefficients.
    pub fn with_leak(
        idx: Indices,
        film_k: f64,
        incidence_deg: f64,
        pol: Polarization,
        wavelength_nm: f64,
        leak: f64,
    ) -> Option<Self> {
        let beta = snell_invariant(idx.ambient, incidence_deg);
        let k1 = idx.ambient * idx.ambient - beta * beta;
        let k3 = idx.substrate * idx.substrate - beta * beta;
        if k1 <= 0.0
            || (k3 <= 0.0 && idx.substrate_k == 0.0)
            || film_k.is_nan()
            || film_k < 0.0
            || !(0.0..=1.0).contains(&leak)
        {
            return None;
        }
        let (eps1, kz1) = medium_wave(idx.ambient, 0.0, beta);
        let (eps2, kz2) = medium_wave(idx.film, film_k, beta);
        let (eps3, kz3) = medium_wave(idx.substrate, idx.substrate_k, beta);
        let (pols, weights) = match pol {
            Polarization::Unpolarized => ([Polarization::S, Polarization::P], [0.5, 0.5]),
            Polarization::S => ([Polarization::S, Polarization::P], [1.0 - leak, leak]),
            Polarization::P => ([Polarization::P, Polarization::S], [1.0 - leak, leak]),
        };
        let mut coeffs = [Coefficients::default(); 2];
        for (c, p) in coeffs.iter_mut().zip(pols) {
            let r12 = fresnel_r(p, eps1, eps2, kz1, kz2);
            let r23 = fresnel_r(p, eps2, eps3, kz2, kz3);
            // t = 1 + r for S; for P, in the convention of `fresnel_r`, t = (1 + r) n_i / n_j.
            let t = |r: Complex, n_i: Complex, n_j: Complex| match p {
                Polarization::P => (Complex::new(1.0, 0.0) + r) * n_i / n_j,
                _ => Complex::new(1.0, 0.0) + r,
            };
            let (n1, n2, n3) = (
                Complex::new(idx.ambient, 0.0),
                Complex::new(idx.film, film_k),
                Complex::new(idx.substrate, idx.substrate_k),
            );
            let (t12, t23) = (t(r12, n1, n2), t(r23, n2, n3));
            let arg = |z: Complex| libm::atan2(z.im, z.re);
            let (phi12, phi23) = (arg(r12), arg(r23));
            let rb = back_reflectance(idx, beta, p);
            *c = Coefficients {
                rho12: libm::hypot(r12.re, r12.im),
                rho23: libm::hypot(r23.re, r23.im),
                num_phase: (libm::cos(phi23 - phi12), libm::sin(phi23 - phi12)),
                den_phase: (libm::cos(phi23 + phi12), libm::sin(phi23 + phi12)),
                rb,
                kt: if rb > 0.0 {
                    t12.norm_sqr() * t23.norm_sqr() * kz3.re / kz1.re
                } else {
                    0.0
                },
            };
        }
        let per_nm = 4.0 * core::f64::consts::PI / wavelength_nm;
        Some(Self {
            phase_per_nm: per_nm * kz2.re,
            loss_per_nm: per_nm * kz2.im,
            coeffs,
            weights,
            n_pol: if weights[1] > 0.0 { 2 } else { 1 },
        })
    }

    /// The round trip's phase `Delta` and amplitude `a` through `d_nm` of the film.
    #[inline]
    pub fn round_trip(&self, d_nm: f64) -> (f64, f64) {
        (
            self.phase_per_nm * d_nm,
            libm::exp(-self.loss_per_nm * d_nm),
        )
    }

    /// The reflectance at the round trip's phase `Delta` (given as its cosine `c` and sine
    /// `s`) and amplitude `a`, with `dR / dDelta` and `dR / da`.
    #[inline]
    pub fn reflectance(&self, c: f64, s: f64, a: f64) -> (f64, f64, f64) {
        let (mut r, mut d_delta, mut d_a) = (0.0, 0.0, 0.0);
        for (k, &w) in self.coeffs[..self.n_pol].iter().zip(&self.weights) {
            let g = 2.0 * k.rho12 * k.rho23;
            let (r12s, r23s) = (k.rho12 * k.rho12, k.rho23 * k.rho23);
            // cos and sin of Delta shifted by a phase.
            let shifted = |(cp, sp): (f64, f64)| (c * cp - s * sp, s * cp + c * sp);
            let (c_num, s_num) = shifted(k.num_phase);
            let (c_den, s_den) = shifted(k.den_phase);
            let num = r12s + a * a * r23s + g * a * c_num;
            let den = 1.0 + a * a * r12s * r23s + g * a * c_den;
            let inv = 1.0 / den;
            let (num_d, num_a) = (-g * a * s_num, 2.0 * a * r23s + g * c_num);
            let (den_d, den_a) = (-g * a * s_den, 2.0 * a * r12s * r23s + g * c_den);
            let quotient = |n: f64, n_x: f64, d_x: f64| (n_x * den - n * d_x) * inv * inv;
            let mut value = num * inv;
            let mut slope_d = quotient(num, num_d, den_d);
            let mut slope_a = quotient(num, num_a, den_a);
            if k.rb > 0.0 {
                // The substrate side's reflectance peaks at Delta - (phi23 - phi12).
                let (c_in, s_in) = shifted((k.num_phase.0, -k.num_phase.1));
                let inner = r23s + a * a * r12s + g * a * c_in;
                let (inner_d, inner_a) = (-g * a * s_in, 2.0 * a * r12s + g * c_in);
                let back = inner * inv;
                let (back_d, back_a) = (
                    quotient(inner, inner_d, den_d),
                    quotient(inner, inner_a, den_a),
                );
                let t = k.kt * a * inv;
                let (t_d, t_a) = (
                    -k.kt * a * den_d * inv * inv,
                    k.kt * inv - k.kt * a * den_a * inv * inv,
                );
                let h = 1.0 / (1.0 - back * k.rb);
                let ret = |t_x: f64, back_x: f64| {
                    k.rb * (2.0 * t * t_x * h + t * t * h * h * k.rb * back_x)
                };
                value += t * t * k.rb * h;
                slope_d += ret(t_d, back_d);
                slope_a += ret(t_a, back_a);
            }
            r += w * value;
            d_delta += w * slope_d;
            d_a += w * slope_a;
        }
        (r, d_delta, d_a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::BackFace;

    /// The slopes match central differences, with and without a back face, on a clear and
    /// an absorbing substrate; with `k = 0` on a clear substrate the reflectance is the
    /// lossless film's.
    #[test]
    fn slopes_match_differences_and_a_clear_film_is_the_lossless_one() {
        for (back_face, substrate_k) in [
            (BackFace::None, 0.0),
            (BackFace::Bare, 0.0),
            (BackFace::None, 0.3),
        ] {
            let idx = Indices {
                ambient: 1.0,
                film: 2.1,
                substrate: 1.52,
                substrate_k,
                back_face,
            };
            for pol in [Polarization::S, Polarization::P, Polarization::Unpolarized] {
                let film = LossyFilm::new(idx, 0.01, 40.0, pol, 480.0).expect("propagating");
                let at = |delta: f64, a: f64| film.reflectance(delta.cos(), delta.sin(), a);
                let (delta, a, h) = (2.3, 0.9, 1e-6);
                let (_, d_delta, d_a) = at(delta, a);
                let fd_delta = (at(delta + h, a).0 - at(delta - h, a).0) / (2.0 * h);
                let fd_a = (at(delta, a + h).0 - at(delta, a - h).0) / (2.0 * h);
                assert!((d_delta - fd_delta).abs() < 1e-8, "{pol:?} {back_face:?}");
                assert!((d_a - fd_a).abs() < 1e-8, "{pol:?} {back_face:?}");
                if substrate_k == 0.0 {
                    let clear = LossyFilm::new(idx, 0.0, 40.0, pol, 480.0).expect("propagating");
                    let lossless =
                        crate::optics::FilmAtAngle::new(idx, 40.0, pol).expect("propagating");
                    let r = clear.reflectance(delta.cos(), delta.sin(), 1.0).0;
                    assert!((r - lossless.reflectance_at_cos(delta.cos())).abs() < 1e-14);
                }
            }
        }
    }
}
