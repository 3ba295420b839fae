//! Snell's law and the Fresnel amplitude coefficients (method.md eqs. 6-7).
//!
//! Everything is written with the normal wave-vector component `kz = n cos(theta)`, which
//! Snell's law gives directly from the invariant `beta = n1 sin(theta1)`:
//! `kz_j = sqrt(n_j^2 - beta^2)`. Beyond the critical angle `kz_j` is imaginary (an
//! evanescent wave), which is how total internal reflection falls out without special cases.

use super::Complex;
use super::Polarization;

/// The Snell invariant `beta = n1 sin(theta1)` of light arriving from a medium of index
/// `ambient_index` at `incidence_deg`.
pub fn snell_invariant(ambient_index: f64, incidence_deg: f64) -> f64 {
    ambient_index * libm::sin(incidence_deg.to_radians())
}

/// The refraction angle in a medium of index `n` for Snell invariant `beta`, in degrees,
/// or `None` when the wave is evanescent there (total internal reflection).
pub fn refraction_deg(n: f64, beta: f64) -> Option<f64> {
    let s = beta / n;
    if s.abs() > 1.0 {
        None
    } else {
        Some(libm::asin(s).to_degrees())
    }
}

/// `n cos(theta)` in a medium of index `n`, complex when evanescent: the branch with a
/// non-negative imaginary part, a wave that decays away from the interface.
pub fn normal_component(n: f64, beta: f64) -> Complex {
    let x = n * n - beta * beta;
    if x >= 0.0 {
        Complex::new(libm::sqrt(x), 0.0)
    } else {
        Complex::new(0.0, libm::sqrt(-x))
    }
}

/// A medium of complex index `n + i k`: its permittivity `(n + i k)^2` and normal component
/// `sqrt(eps - beta^2)` on the branch with a non-negative imaginary part (a wave decaying
/// into it; evanescent beyond the critical angle when `k` is 0). The square root through
/// libm, for the same bits in every build.
pub fn medium_wave(n: f64, k: f64, beta: f64) -> (Complex, Complex) {
    if k == 0.0 {
        return (Complex::new(n * n, 0.0), normal_component(n, beta));
    }
    let eps = Complex::new(n * n - k * k, 2.0 * n * k);
    let (x, y) = (eps.re - beta * beta, eps.im);
    let r = libm::hypot(x, y);
    let re = libm::sqrt(0.5 * (r + x));
    let im = libm::copysign(libm::sqrt(0.5 * (r - x)), y);
    (eps, Complex::new(re, im))
}

/// The Fresnel amplitude reflection coefficient for light going from medium `i` to medium `j`
/// (permittivities `eps_i = n_i^2`, `eps_j = n_j^2`, complex for an absorbing medium; normal
/// components `kz_i`, `kz_j`), for S or P polarisation.
///
/// S: `(kz_i - kz_j) / (kz_i + kz_j)`, which is eq. 6 of method.md.
/// P: `(n_j^2 kz_i - n_i^2 kz_j) / (n_j^2 kz_i + n_i^2 kz_j)`, which is eq. 7 multiplied through by
/// `n_i n_j`. `pol` must be S or P; `Unpolarized` is treated as S (callers average intensities).
pub fn fresnel_r(
    pol: Polarization,
    eps_i: Complex,
    eps_j: Complex,
    kz_i: Complex,
    kz_j: Complex,
) -> Complex {
    match pol {
        Polarization::P => {
            let a = kz_i * eps_j;
            let b = kz_j * eps_i;
            (a - b) / (a + b)
        }
        Polarization::S | Polarization::Unpolarized => (kz_i - kz_j) / (kz_i + kz_j),
    }
}

/// Real Fresnel coefficient for the common case of propagating waves (`kz` real on both sides).
#[inline]
pub fn fresnel_r_real(pol: Polarization, n_i: f64, n_j: f64, kz_i: f64, kz_j: f64) -> f64 {
    match pol {
        Polarization::P => {
            let a = kz_i * n_j * n_j;
            let b = kz_j * n_i * n_i;
            (a - b) / (a + b)
        }
        Polarization::S | Polarization::Unpolarized => (kz_i - kz_j) / (kz_i + kz_j),
    }
}
