//! CIE 1976 L\*a\*b\* (CIELAB).

use super::xyz::Xyz;

/// A CIE 1976 L\*a\*b\* colour (dimensionless: L\* is 0 for black and 100 for
/// the reference white; a\*, b\* are the red-green and yellow-blue opponent axes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lab {
    /// Lightness L\*, 0..=100 for colours no lighter than the white.
    pub l: f64,
    /// Red (+) / green (-) opponent coordinate a\*.
    pub a: f64,
    /// Yellow (+) / blue (-) opponent coordinate b\*.
    pub b: f64,
}

/// `(6/29)^3 = 216/24389`: below this relative value `f` is linear.
const EPSILON: f64 = 216.0 / 24389.0;

/// CIELAB companding `f(t)`: `cbrt(t)` above [`EPSILON`], else the linear
/// segment `t / (3 (6/29)^2) + 4/29`, continuous in value and slope.
fn f(t: f64) -> f64 {
    if t > EPSILON {
        libm::cbrt(t)
    } else {
        t * (841.0 / 108.0) + 4.0 / 29.0
    }
}

impl Xyz {
    /// CIE 1976 L\*a\*b\* of this colour relative to the reference `white`
    /// (on the same scale, e.g. [`D65_WHITE_XYZ`](super::D65_WHITE_XYZ)):
    /// `L* = 116 f(Y/Yn) - 16`, `a* = 500 (f(X/Xn) - f(Y/Yn))`,
    /// `b* = 200 (f(Y/Yn) - f(Z/Zn))`, with the standard linear segment of `f`
    /// below `(6/29)^3`.
    pub fn to_lab(self, white: Xyz) -> Lab {
        let fx = f(self.x / white.x);
        let fy = f(self.y / white.y);
        let fz = f(self.z / white.z);
        Lab {
            l: 116.0 * fy - 16.0,
            a: 500.0 * (fx - fy),
            b: 200.0 * (fy - fz),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{reflectance_fn_to_xyz, D65_WHITE_XYZ};
    use super::*;

    #[test]
    fn white_is_l100_neutral() {
        let lab = reflectance_fn_to_xyz(|_| 1.0).to_lab(D65_WHITE_XYZ);
        assert!((lab.l - 100.0).abs() < 1e-12, "{lab:?}");
        assert!(lab.a.abs() < 1e-12 && lab.b.abs() < 1e-12, "{lab:?}");
    }

    #[test]
    fn black_is_l0() {
        let lab = reflectance_fn_to_xyz(|_| 0.0).to_lab(D65_WHITE_XYZ);
        assert!(lab.l.abs() < 1e-12, "{lab:?}");
        assert!(lab.a.abs() < 1e-12 && lab.b.abs() < 1e-12, "{lab:?}");
    }

    #[test]
    fn grey_18_percent_is_about_l50() {
        // Y = 18.42 gives L* = 50 (116 * cbrt(0.1842) - 16 = 50.0).
        let lab = reflectance_fn_to_xyz(|_| 0.1842).to_lab(D65_WHITE_XYZ);
        assert!((lab.l - 50.0).abs() < 0.01, "{lab:?}");
    }

    #[test]
    fn companding_is_continuous() {
        let below = f(EPSILON);
        let above = libm::cbrt(EPSILON);
        assert!((below - above).abs() < 1e-15);
    }
}
