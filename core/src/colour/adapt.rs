//! Chromatic adaptation between illuminants' whites (Bradford), so a render under any light
//! can be shown on an sRGB display.

use super::xyz::Xyz;

/// The Bradford cone-response matrix (Lam 1985; as in colour-science's
/// `CAT_BRADFORD` and ICC v4), rows rho, gamma, beta.
const BRADFORD: [[f64; 3]; 3] = [
    [0.8951, 0.2664, -0.1614],
    [-0.7502, 1.7135, 0.0367],
    [0.0389, -0.0685, 1.0296],
];

/// The inverse of [`BRADFORD`], evaluated at compile time (the adjugate over the
/// determinant; the matrix is well conditioned).
const BRADFORD_INVERSE: [[f64; 3]; 3] = inverse_3x3(&BRADFORD);

/// The inverse of a 3 x 3 matrix by its adjugate: hand-made because it is a `const fn`
/// (nalgebra's inverse is not), so [`BRADFORD_INVERSE`] costs nothing at run time.
const fn inverse_3x3(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    let mut inv = [[0.0; 3]; 3];
    let mut r = 0;
    while r < 3 {
        let mut c = 0;
        while c < 3 {
            // Cofactor of element (c, r), i.e. the adjugate's (r, c).
            let (r1, r2) = ((c + 1) % 3, (c + 2) % 3);
            let (c1, c2) = ((r + 1) % 3, (r + 2) % 3);
            inv[r][c] = (m[r1][c1] * m[r2][c2] - m[r1][c2] * m[r2][c1]) / det;
            c += 1;
        }
        r += 1;
    }
    inv
}

fn apply(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}

/// A colour seen under a light whose white is `from_white`, as it looks adapted to
/// `to_white` (von Kries scaling in the Bradford cone space, the linear Bradford
/// transform of colour-science's `chromatic_adaptation(..., method="Von Kries",
/// transform="Bradford")`). What a white-balanced camera does: `from_white` itself maps
/// to `to_white`. Identical whites return `xyz` unchanged.
pub fn bradford_adapt(xyz: Xyz, from_white: Xyz, to_white: Xyz) -> Xyz {
    if from_white == to_white {
        return xyz;
    }
    let src = apply(&BRADFORD, [from_white.x, from_white.y, from_white.z]);
    let dst = apply(&BRADFORD, [to_white.x, to_white.y, to_white.z]);
    let cone = apply(&BRADFORD, [xyz.x, xyz.y, xyz.z]);
    let scaled = [
        cone[0] * dst[0] / src[0],
        cone[1] * dst[1] / src[1],
        cone[2] * dst[2] / src[2],
    ];
    let [x, y, z] = apply(&BRADFORD_INVERSE, scaled);
    Xyz { x, y, z }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::colour::Illuminant;

    #[test]
    fn the_const_inverse_is_nalgebras() {
        let m = nalgebra::Matrix3::from_fn(|i, j| BRADFORD[i][j]);
        let inv = m.try_inverse().expect("invertible");
        for (i, row) in BRADFORD_INVERSE.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                assert!((v - inv[(i, j)]).abs() < 1e-15, "({i}, {j}): {v}");
            }
        }
    }

    #[test]
    fn adaptation_maps_white_to_white_and_inverts() {
        let (a, d65) = (Illuminant::A.white(), Illuminant::D65.white());
        let w = bradford_adapt(a, a, d65);
        for (p, q) in [(w.x, d65.x), (w.y, d65.y), (w.z, d65.z)] {
            assert!((p - q).abs() < 1e-9, "{w:?}");
        }
        let c = Xyz {
            x: 20.0,
            y: 30.0,
            z: 10.0,
        };
        let back = bradford_adapt(bradford_adapt(c, a, d65), d65, a);
        for (p, q) in [(back.x, c.x), (back.y, c.y), (back.z, c.z)] {
            assert!((p - q).abs() < 1e-9, "{back:?}");
        }
        assert_eq!(bradford_adapt(c, d65, d65), c);
    }
}
