//! Colour differences (CIE76, CIEDE2000) and spectral RMSE.

use super::lab::Lab;
use core::f64::consts::PI;

/// CIE 1976 colour difference `dE*ab = sqrt(dL*^2 + da*^2 + db*^2)`
/// (dimensionless, CIELAB units).
pub fn delta_e76(a: Lab, b: Lab) -> f64 {
    let dl = a.l - b.l;
    let da = a.a - b.a;
    let db = a.b - b.b;
    libm::sqrt(dl * dl + da * da + db * db)
}

/// Degrees to radians.
fn rad(deg: f64) -> f64 {
    deg * (PI / 180.0)
}

/// Hue angle `atan2(b, a)` in degrees, in `[0, 360)`; 0 when `a = b = 0`.
fn hue_deg(b: f64, a: f64) -> f64 {
    if a == 0.0 && b == 0.0 {
        return 0.0;
    }
    let h = libm::atan2(b, a).to_degrees();
    if h < 0.0 {
        h + 360.0
    } else {
        h
    }
}

/// `25^7`, the constant in the chroma compensation `G` and rotation `R_C`.
const POW25_7: f64 = 6_103_515_625.0;

/// CIEDE2000 colour difference `dE00` (dimensionless) with parametric factors
/// `kL = kC = kH = 1`, implemented exactly as in G. Sharma, W. Wu, E. N. Dalal,
/// "The CIEDE2000 color-difference formula: implementation notes, supplementary
/// test data, and mathematical observations", Color Res. Appl. 30(1), 2005,
/// eqs. (1)-(17), including the hue edge cases: hue angle 0 for zero chroma,
/// `dh' = 0` and mean hue `h1' + h2'` when either chroma `C'` is zero.
/// Symmetric in its arguments.
pub fn delta_e2000(a: Lab, b: Lab) -> f64 {
    let (l1, a1, b1) = (a.l, a.a, a.b);
    let (l2, a2, b2) = (b.l, b.a, b.b);

    // (2)-(7): a' with chroma compensation G, C', h'.
    let c1 = libm::sqrt(a1 * a1 + b1 * b1);
    let c2 = libm::sqrt(a2 * a2 + b2 * b2);
    let c_bar = 0.5 * (c1 + c2);
    let c_bar7 = libm::pow(c_bar, 7.0);
    let g = 0.5 * (1.0 - libm::sqrt(c_bar7 / (c_bar7 + POW25_7)));
    let a1p = (1.0 + g) * a1;
    let a2p = (1.0 + g) * a2;
    let c1p = libm::sqrt(a1p * a1p + b1 * b1);
    let c2p = libm::sqrt(a2p * a2p + b2 * b2);
    let h1p = hue_deg(b1, a1p);
    let h2p = hue_deg(b2, a2p);

    // (8)-(10): differences.
    let dlp = l2 - l1;
    let dcp = c2p - c1p;
    let chroma_product = c1p * c2p;
    let dhp_deg = if chroma_product == 0.0 {
        0.0
    } else {
        let d = h2p - h1p;
        if d > 180.0 {
            d - 360.0
        } else if d < -180.0 {
            d + 360.0
        } else {
            d
        }
    };
    let dhp_big = 2.0 * libm::sqrt(chroma_product) * libm::sin(rad(dhp_deg) / 2.0);

    // (11)-(14): means.
    let lp_bar = 0.5 * (l1 + l2);
    let cp_bar = 0.5 * (c1p + c2p);
    let hp_bar = if chroma_product == 0.0 {
        h1p + h2p
    } else if libm::fabs(h1p - h2p) <= 180.0 {
        0.5 * (h1p + h2p)
    } else if h1p + h2p < 360.0 {
        0.5 * (h1p + h2p + 360.0)
    } else {
        0.5 * (h1p + h2p - 360.0)
    };

    // (15)-(17): weighting functions and rotation term.
    let t = 1.0 - 0.17 * libm::cos(rad(hp_bar - 30.0))
        + 0.24 * libm::cos(rad(2.0 * hp_bar))
        + 0.32 * libm::cos(rad(3.0 * hp_bar + 6.0))
        - 0.20 * libm::cos(rad(4.0 * hp_bar - 63.0));
    let d_theta_deg = 30.0 * libm::exp(-libm::pow((hp_bar - 275.0) / 25.0, 2.0));
    let cp_bar7 = libm::pow(cp_bar, 7.0);
    let r_c = 2.0 * libm::sqrt(cp_bar7 / (cp_bar7 + POW25_7));
    let l50 = (lp_bar - 50.0) * (lp_bar - 50.0);
    let s_l = 1.0 + 0.015 * l50 / libm::sqrt(20.0 + l50);
    let s_c = 1.0 + 0.045 * cp_bar;
    let s_h = 1.0 + 0.015 * cp_bar * t;
    let r_t = -libm::sin(rad(2.0 * d_theta_deg)) * r_c;

    let tl = dlp / s_l;
    let tc = dcp / s_c;
    let th = dhp_big / s_h;
    libm::sqrt(tl * tl + tc * tc + th * th + r_t * tc * th)
}

/// Root-mean-square difference of two spectra sampled on the same wavelengths,
/// `sqrt(sum (a_i - b_i)^2 / N)`, in the units of the samples (e.g. reflectance).
/// NaN if the slices are empty or of different lengths.
pub fn spectral_rmse(a: &[f64], b: &[f64]) -> f64 {
    if a.is_empty() || a.len() != b.len() {
        return f64::NAN;
    }
    let sum_sq: f64 = a.iter().zip(b).map(|(p, q)| (p - q) * (p - q)).sum();
    libm::sqrt(sum_sq / a.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    const A: Lab = Lab {
        l: 50.0,
        a: 2.6772,
        b: -79.7751,
    };
    const B: Lab = Lab {
        l: 50.0,
        a: 0.0,
        b: -82.7485,
    };

    #[test]
    fn identical_colours_have_zero_difference() {
        assert_eq!(delta_e76(A, A), 0.0);
        assert_eq!(delta_e2000(A, A), 0.0);
        let grey = Lab {
            l: 40.0,
            a: 0.0,
            b: 0.0,
        };
        assert_eq!(delta_e2000(grey, grey), 0.0);
    }

    #[test]
    fn delta_e76_is_euclidean() {
        let p = Lab {
            l: 1.0,
            a: 2.0,
            b: 3.0,
        };
        let q = Lab {
            l: 4.0,
            a: 6.0,
            b: 15.0,
        };
        assert!((delta_e76(p, q) - 13.0).abs() < 1e-12);
    }

    #[test]
    fn sharma_pair_1() {
        assert!((delta_e2000(A, B) - 2.0425).abs() < 1e-4);
        assert_eq!(delta_e2000(A, B), delta_e2000(B, A));
    }

    #[test]
    fn lightness_only_difference() {
        // At L' mean 50, S_L = 1, so dE00 equals |dL|.
        let p = Lab {
            l: 49.0,
            a: 0.0,
            b: 0.0,
        };
        let q = Lab {
            l: 51.0,
            a: 0.0,
            b: 0.0,
        };
        assert!((delta_e2000(p, q) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn rmse() {
        assert_eq!(spectral_rmse(&[1.0, 2.0], &[1.0, 2.0]), 0.0);
        assert!((spectral_rmse(&[0.0, 0.0], &[3.0, 4.0]) - 12.5f64.sqrt()).abs() < 1e-12);
        assert!(spectral_rmse(&[], &[]).is_nan());
        assert!(spectral_rmse(&[1.0], &[1.0, 2.0]).is_nan());
    }
}
