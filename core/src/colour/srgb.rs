//! CIE XYZ -> sRGB (IEC 61966-2-1).

use super::adapt::bradford_adapt;
use super::xyz::{Xyz, D65_WHITE_XYZ};

/// XYZ -> linear sRGB matrix of IEC 61966-2-1:1999 (D65 white, as published, to
/// four decimals; rows R, G, B).
const XYZ_TO_LINEAR_SRGB: [[f64; 3]; 3] = [
    [3.2406, -1.5372, -0.4986],
    [-0.9689, 1.8758, 0.0415],
    [0.0557, -0.2040, 1.0570],
];

/// sRGB transfer function (linear -> gamma-encoded), IEC 61966-2-1.
fn encode(linear: f64) -> f64 {
    if linear <= 0.003_130_8 {
        12.92 * linear
    } else {
        1.055 * libm::pow(linear, 1.0 / 2.4) - 0.055
    }
}

/// Clips to `0..=1`, mapping NaN to 0.
fn clip_unit(v: f64) -> f64 {
    if v.is_nan() {
        0.0
    } else {
        v.clamp(0.0, 1.0)
    }
}

/// Gamma-encoded sRGB `[R, G, B]`, each clipped to `0..=1`, of an XYZ colour on
/// the scale where the white has `Y = 100` (as returned by
/// [`reflectance_to_xyz`](super::reflectance_to_xyz)).
///
/// XYZ / 100 goes through the IEC 61966-2-1 matrix (no chromatic adaptation:
/// the data are already D65), linear values are clipped to `0..=1`, then the
/// sRGB transfer curve is applied. NaN components give 0.
pub fn xyz_to_srgb(xyz: Xyz) -> [f64; 3] {
    let v = [xyz.x / 100.0, xyz.y / 100.0, xyz.z / 100.0];
    let mut out = [0.0; 3];
    for (o, row) in out.iter_mut().zip(XYZ_TO_LINEAR_SRGB.iter()) {
        let linear = row[0] * v[0] + row[1] * v[1] + row[2] * v[2];
        *o = encode(clip_unit(linear));
    }
    out
}

/// Gamma-encoded sRGB, as [`xyz_to_srgb`], of a colour seen under a light whose white
/// is `white` (`Y = 100`), white-balanced to D65 first with [`bradford_adapt`]: what a
/// camera set to that light's white balance shows. `white` equal to
/// [`D65_WHITE_XYZ`] gives exactly [`xyz_to_srgb`].
pub fn xyz_to_srgb_balanced(xyz: Xyz, white: Xyz) -> [f64; 3] {
    xyz_to_srgb(bradford_adapt(xyz, white, D65_WHITE_XYZ))
}

/// Quantises gamma-encoded sRGB in `0..=1` to 8 bits per channel
/// (round to nearest; out-of-range values are clipped, NaN gives 0).
pub fn srgb_to_u8(rgb: [f64; 3]) -> [u8; 3] {
    // In 0.0..=255.0 after clipping, so the cast is exact.
    rgb.map(|c| libm::round(clip_unit(c) * 255.0) as u8)
}

#[cfg(test)]
mod tests {
    use super::super::D65_WHITE_XYZ;
    use super::*;

    #[test]
    fn white_and_black() {
        let w = srgb_to_u8(xyz_to_srgb(D65_WHITE_XYZ));
        assert_eq!(w, [255, 255, 255]);
        let k = xyz_to_srgb(Xyz {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        });
        assert_eq!(k, [0.0, 0.0, 0.0]);
        assert_eq!(srgb_to_u8(k), [0, 0, 0]);
    }

    #[test]
    fn nan_and_out_of_range_are_clipped() {
        let rgb = xyz_to_srgb(Xyz::NAN);
        assert_eq!(rgb, [0.0, 0.0, 0.0]);
        assert_eq!(srgb_to_u8([-1.0, 2.0, f64::NAN]), [0, 255, 0]);
    }

    #[test]
    fn transfer_curve_is_continuous() {
        let x = 0.003_130_8;
        let lin = 12.92 * x;
        let pow = 1.055 * libm::pow(x, 1.0 / 2.4) - 0.055;
        assert!((lin - pow).abs() < 1e-6);
    }
}
