//! Stability where methods fail (issue: speed against accuracy): on the coarse maps of
//! `filmscope stability --quick` (film index x thickness, FWHM x thickness, noise x index,
//! angle count x span, band step x thickness, material x thickness; 16 x 12 px), filmscope is within tolerance or
//! flags the pixel (silent failures <= 0.5 %), and is at least as accurate as the paper's
//! method wherever that works.
//!
//! Measured figures are in each test's comment (filmscope's worst cell of the map). They were
//! measured before the software camera's noise was made independent (it repeated across
//! rows, bands and angles); the tolerances hold with independent noise.

use filmscope::lab::chart::{
    cell_scene, run_map, settings, stability_maps, Axis, Cell, GridScene, MapSpec,
};

/// Filmscope's tolerances on one map, where it reports any pixel.
struct Tolerance {
    /// Thickness MAE over the valid pixels, nm.
    mae_nm: f64,
    /// Absolute index error.
    index: f64,
}

/// The `--quick` map `name`.
fn quick(name: &str) -> MapSpec {
    stability_maps(true)
        .into_iter()
        .find(|m| m.name == name)
        .expect("map")
}

/// Runs `spec` with filmscope and the paper's method and checks filmscope's cells.
fn check(spec: &MapSpec, tol: Tolerance) {
    let chosen: Vec<_> = settings(true)
        .into_iter()
        .filter(|s| s.label == "filmscope" || s.label == "paper")
        .collect();
    let map = run_map(spec, &chosen, &|_| {}).expect("map runs");
    let name = &spec.name;
    let (x, y) = (map.spec.x, map.spec.y);
    let at = |c: &Cell| format!("{name} {:?} {} {:?} {}", y, c.y, x, c.x);
    for c in &map.cells {
        let p = &c.point;
        eprintln!(
            "{:<48} {:<10} n err {:.4} MAE {:>8.2} valid {:>5.1}% silent {:.2}%",
            at(c),
            p.method,
            p.index_error_abs,
            p.thickness_mae_nm,
            100.0 * p.valid_fraction,
            100.0 * p.silent_failure_rate
        );
    }
    for c in map.cells.iter().filter(|c| c.point.method == "filmscope") {
        let p = &c.point;
        let at = at(c);
        assert!(
            p.silent_failure_rate <= 0.005,
            "{at}: silent {}",
            p.silent_failure_rate
        );
        if p.valid_fraction > 0.0 {
            assert!(
                p.thickness_mae_nm <= tol.mae_nm,
                "{at}: MAE {}",
                p.thickness_mae_nm
            );
            assert!(
                p.index_error_abs <= tol.index,
                "{at}: index {}",
                p.index_error_abs
            );
        }
        // Where the paper's method works (index within 0.01, MAE within 10 nm, most pixels
        // valid), filmscope must be at least as accurate and solve as many pixels.
        let paper = map
            .cells
            .iter()
            .find(|o| o.point.method == "paper" && o.x == c.x && o.y == c.y)
            .expect("paper cell");
        let q = &paper.point;
        if q.index_error_abs <= 0.01 && q.thickness_mae_nm <= 10.0 && q.valid_fraction >= 0.9 {
            assert!(
                p.thickness_mae_nm <= q.thickness_mae_nm,
                "{at}: MAE {} vs paper {}",
                p.thickness_mae_nm,
                q.thickness_mae_nm
            );
            assert!(p.valid_fraction >= 0.9, "{at}: valid {}", p.valid_fraction);
        }
    }
}

/// n 1.38 / 1.8 / 2.35 x 150 / 500 / 1500 nm (paper's camera, 4 nm FWHM).
/// Measured: every pixel of every cell within 20 nm; worst MAE 0.60 nm (n 1.8, 1500 nm),
/// worst index error 0.0006 (same cell; 0.0015 at n 1.8, 150 nm before the latest solver
/// changes); at least 99.0 % valid everywhere.
#[test]
fn index_thickness() {
    check(
        &quick("index-thickness"),
        Tolerance {
            mae_nm: 0.8,
            index: 0.0025,
        },
    );
}

/// FWHM 2 / 8 / 20 nm x 150 / 500 / 1500 nm at n 1.38.
/// Measured: worst MAE 1.87 nm and index error 0.0013, both at 20 nm FWHM over 1500 nm
/// (the passband washing the thick film's fringes out); at least 97.9 % valid everywhere.
#[test]
fn fwhm_thickness() {
    check(
        &quick("fwhm-thickness"),
        Tolerance {
            mae_nm: 2.5,
            index: 0.002,
        },
    );
}

/// Gaussian reflectance noise 0 / 1 / 3 % x n 1.38 / 2.35 at 500 nm (ideal 16-bit sensor).
/// Measured: noise 0 gives MAE 0.00 / 0.06 nm; 3 % gives MAE 1.97 nm (n 1.38) and
/// 0.43 nm (n 2.35), index errors <= 0.0011, every pixel valid.
#[test]
fn noise_index() {
    check(
        &quick("noise-index"),
        Tolerance {
            mae_nm: 2.5,
            index: 0.0015,
        },
    );
}

/// 2 / 5 angles from 10 deg over 10 / 40 deg, ZnS-like n 2.35 at 500 nm.
/// Measured: MAE 0.07-0.08 nm, index error <= 0.0003, every pixel valid, even with two
/// angles 10 deg apart (index error 0.0000).
#[test]
fn angles() {
    check(
        &quick("angles"),
        Tolerance {
            mae_nm: 0.15,
            index: 0.0005,
        },
    );
}

/// Band step 1 / 4 / 10 nm x 150 / 1500 nm at n 1.38, 4 nm FWHM.
/// Measured: MAE <= 0.76 nm, index error <= 0.0004, every pixel valid; a 10 nm step over
/// 1500 nm (a fringe period of about 4 steps at 420 nm) left 84.4 % valid before the
/// spectrum search covered the whole thickness range, now 100 % (MAE 0.55 nm; the paper's
/// method reports it: MAE 233.50 nm, 99.48 % silently wrong).
#[test]
fn band_step_thickness() {
    check(
        &quick("band-step-thickness"),
        Tolerance {
            mae_nm: 1.2,
            index: 0.0006,
        },
    );
}

/// Real materials with their published dispersion on glass: MgF2, Ta2O5 and TiO2 x 150 /
/// 1500 nm (paper's camera, 4 nm FWHM). Measured: index error <= 0.0011, every pixel valid,
/// none silently wrong.
#[test]
fn material_thickness() {
    check(
        &quick("material-thickness"),
        Tolerance {
            mae_nm: 1.0,
            index: 0.003,
        },
    );
}

/// Checks the one cell `x`, `y` over `base` as a cell of a map (the cases next to the
/// substrate's index below: a working cell's 3 nm MAE, and an index within 0.006).
fn check_cell(base: GridScene, x: (Axis, f64), y: (Axis, f64)) {
    let spec = MapSpec::new("near-substrate", base, (x.0, &[x.1]), (y.0, &[y.1]));
    check(
        &spec,
        Tolerance {
            mae_nm: 3.0,
            index: 0.006,
        },
    );
}

/// A film just above the substrate's index under 1 % reflectance noise: n 1.6 on 1.52,
/// 500 nm. It got a few wrong orders that neither the order choice nor the full-spectrum
/// check caught (seed 7: 2.08 % of the pixels valid and wrong; before d78b4a8 68.23 %). The
/// first pass solves under half the pixels with a model mismatch, and the spectrum search now
/// runs then too: seeds 1-4 and 7 every pixel valid, MAE 0.67-0.99 nm, index -0.0006 /
/// -0.0007 (`filmscope eval` on `GridScene::toml`).
#[test]
fn orders_near_the_substrate_index_under_one_percent_noise() {
    check_cell(GridScene::default(), (Axis::Index, 1.6), (Axis::Noise, 1.0));
}

/// Near the substrate's index under the paper's camera noise: n 1.55 on 1.52, 500 nm, seed 3
/// (measured MAE 1.12 nm, index -0.0001, every pixel valid; seeds 1, 2, 4 and 7 alike).
#[test]
fn orders_near_the_substrate_index_with_the_paper_camera() {
    let seed_3 = GridScene {
        seed: 3,
        ..GridScene::default()
    };
    check_cell(seed_3, (Axis::Index, 1.55), (Axis::Thickness, 500.0));
}

/// A thick film next to the substrate's index has faint fringes (peak to peak 4 |r12 r23| =
/// 0.5 % in reflectance at normal incidence, eq. 4, under about 0.5 % noise), so the tracker
/// finds no extremum it can trust. The spectrum search, capped at 800 nm, took it for a thin
/// one and reported every pixel (n 1.5 on 1.52, 2000 nm, seed 7: 100 % valid and wrong, MAE
/// 1900.03 nm, index +0.0093); at 1500 nm noise extrema gave the shifts n 1.48 and 47 % of the
/// pixels were silently wrong. The search now covers the whole thickness range and also runs
/// after a first pass with a model mismatch: 1000 / 1500 / 2000 nm, seeds 1-4 and 7, every
/// pixel valid, MAE 0.69-1.74 nm, index within 0.0001.
#[test]
fn a_thick_film_next_to_the_substrate_index_is_found_by_the_spectrum_search() {
    check_cell(
        GridScene::default(),
        (Axis::Index, 1.5),
        (Axis::Thickness, 2000.0),
    );
}

/// `filmscope stability --cell`: one cell's scene, with the map's base and the cell's two
/// values (any values), the maps' seed unless given; a bad name says what is wrong.
#[test]
fn a_cells_scene_is_the_maps_base_with_its_two_values() {
    let maps = stability_maps(false);
    let g = cell_scene(&maps, "index-thickness:2000:2.8", None).expect("cell");
    assert_eq!((g.index, g.thickness_nm, g.seed), (2.8, 2000.0, 7));
    let base = &maps[0].base;
    assert_eq!(
        (g.fwhm_nm, &g.angles_deg, g.size),
        (base.fwhm_nm, &base.angles_deg, base.size)
    );
    let scene = g.scene().expect("the scene file parses");
    assert!((scene.stack.film.index_at(550.0) - 2.8).abs() < 1e-12);
    let off = cell_scene(&maps, "fwhm-thickness:1234:5.5", Some(11)).expect("off-grid cell");
    assert_eq!((off.fwhm_nm, off.thickness_nm, off.seed), (5.5, 1234.0, 11));
    for (bad, says) in [
        ("index-thickness:2000", "expected MAP:X:Y"),
        ("index-thickness:2000:2.8:1", "expected MAP:X:Y"),
        ("no-such-map:1:2", "no map \"no-such-map\""),
        ("index-thickness:thick:2.8", "\"thick\" is not a number"),
        ("index-thickness:2000:NaN", "\"NaN\" is not a number"),
    ] {
        let e = cell_scene(&maps, bad, None).expect_err(bad).to_string();
        assert!(e.contains(bad) && e.contains(says), "{bad}: {e}");
    }
}
