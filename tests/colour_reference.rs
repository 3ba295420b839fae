//! Colour module against independent references (fixtures made by
//! `tests/fixtures/colour/gen_colour.py` with colour-science):
//! CIEDE2000 against the 34 published pairs of Sharma, Wu & Dalal (2005),
//! spectrum -> XYZ -> Lab against colour-science, and XYZ -> sRGB.

use crate::common;

use filmscope::colour::{delta_e2000, reflectance_to_xyz, xyz_to_srgb, Lab, Xyz, D65_WHITE_XYZ};

fn rows(name: &str) -> Vec<Vec<String>> {
    common::colour_fixture_rows(name)
}

fn num(s: &str) -> f64 {
    s.parse()
        .unwrap_or_else(|e| panic!("bad number {s:?}: {e}"))
}

fn lab(v: &[f64]) -> Lab {
    Lab {
        l: v[0],
        a: v[1],
        b: v[2],
    }
}

#[test]
fn ciede2000_matches_sharma_2005_table_1() {
    let rows = rows("ciede2000_sharma.csv");
    assert_eq!(rows.len(), 34);
    for row in rows {
        let v: Vec<f64> = row[1..].iter().map(|s| num(s)).collect();
        let (p, q, expected) = (lab(&v[0..3]), lab(&v[3..6]), v[6]);
        let forward = delta_e2000(p, q);
        let reverse = delta_e2000(q, p);
        assert!(
            (forward - expected).abs() <= 1e-4,
            "pair {}: got {forward}, published {expected}",
            row[0]
        );
        assert!(
            (forward - reverse).abs() <= 1e-12,
            "pair {}: not symmetric: {forward} vs {reverse}",
            row[0]
        );
    }
}

#[test]
fn spectra_xyz_and_lab_match_colour_science() {
    let rows = rows("spectra_lab.csv");
    assert_eq!(rows.len(), 18);
    for row in rows {
        let name = &row[0];
        let (start, step, count) = (num(&row[1]), num(&row[2]), num(&row[3]) as usize);
        let v: Vec<f64> = row[4..].iter().map(|s| num(s)).collect();
        let (xyz_ref, lab_ref, r) = (&v[0..3], &v[3..6], &v[6..]);
        assert_eq!(r.len(), count, "{name}");
        let wl: Vec<f64> = (0..count).map(|i| start + step * i as f64).collect();

        let xyz = reflectance_to_xyz(&wl, r);
        for (got, want) in [xyz.x, xyz.y, xyz.z].into_iter().zip(xyz_ref) {
            assert!(
                (got - want).abs() <= 1e-6 * want.abs(),
                "{name}: XYZ {xyz:?} vs {xyz_ref:?}"
            );
        }
        let lab = xyz.to_lab(D65_WHITE_XYZ);
        for (got, want) in [lab.l, lab.a, lab.b].into_iter().zip(lab_ref) {
            assert!(
                (got - want).abs() <= 1e-4,
                "{name}: Lab {lab:?} vs {lab_ref:?}"
            );
        }
    }
}

#[test]
fn srgb_matches_colour_science() {
    let rows = rows("srgb.csv");
    assert!(rows.len() >= 5);
    for row in rows {
        let v: Vec<f64> = row.iter().map(|s| num(s)).collect();
        let xyz = Xyz {
            x: v[0],
            y: v[1],
            z: v[2],
        };
        let rgb = xyz_to_srgb(xyz);
        for (got, want) in rgb.iter().zip(&v[3..6]) {
            assert!(
                (got - want).abs() <= 1e-4,
                "{xyz:?}: {rgb:?} vs {:?}",
                &v[3..6]
            );
        }
    }
}
