//! Analytic limits of the optics model.

use super::*;

const AIR_PET_MGF2: Indices = Indices {
    back_face: BackFace::None,
    ambient: 1.0,
    film: 1.37,
    substrate: 1.65,
    substrate_k: 0.0,
};

#[test]
fn zero_thickness_gives_bare_substrate() {
    for pol in [Polarization::S, Polarization::P, Polarization::Unpolarized] {
        for angle in [0.0, 10.0, 45.0, 70.0] {
            let r = film_reflectance(AIR_PET_MGF2, 0.0, angle, 550.0, pol);
            let bare = film_reflectance(
                Indices {
                    film: 1.65,
                    ..AIR_PET_MGF2
                },
                123.0,
                angle,
                550.0,
                pol,
            );
            assert!((r - bare).abs() < 1e-14, "{pol:?} {angle}: {r} vs {bare}");
        }
    }
    // Normal incidence: ((1 - n) / (1 + n))^2.
    let r = film_reflectance(AIR_PET_MGF2, 0.0, 0.0, 500.0, Polarization::S);
    assert!((r - (0.65f64 / 2.65).powi(2)).abs() < 1e-15);
}

#[test]
fn quarter_wave_of_geometric_mean_index_is_antireflective() {
    let ns = 1.65f64;
    let n = ns.sqrt();
    let design_nm = 550.0;
    let idx = Indices {
        back_face: BackFace::None,
        ambient: 1.0,
        film: n,
        substrate: ns,
        substrate_k: 0.0,
    };
    let r = film_reflectance(idx, design_nm / (4.0 * n), 0.0, design_nm, Polarization::S);
    assert!(r < 1e-28, "R = {r}");
}

#[test]
fn reflectance_stays_in_unit_interval() {
    let mut seed = 0x1234_5678_u64;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..20_000 {
        let idx = Indices {
            back_face: BackFace::None,
            ambient: 1.0 + next() * 0.8,
            film: 1.0 + next() * 2.5,
            substrate: 1.0 + next() * 2.0,
            substrate_k: 0.0,
        };
        let pol = [Polarization::S, Polarization::P, Polarization::Unpolarized]
            [(next() * 3.0) as usize % 3];
        let r = film_reflectance(
            idx,
            next() * 3000.0,
            next() * 89.0,
            350.0 + next() * 800.0,
            pol,
        );
        assert!((0.0..=1.0 + 1e-12).contains(&r), "R = {r} for {idx:?}");
    }
}

#[test]
fn fast_path_matches_general_airy_sum() {
    for (film, pol) in [
        (1.37, Polarization::S),
        (2.37, Polarization::S),
        (2.37, Polarization::P),
        (1.9, Polarization::Unpolarized),
    ] {
        let idx = Indices {
            film,
            ..AIR_PET_MGF2
        };
        for angle in [0.0, 25.0, 50.0, 80.0] {
            let fast = FilmAtAngle::new(idx, angle, pol).expect("propagating");
            for d in [0.0, 80.0, 500.0, 1999.0] {
                for l in [400.0, 555.5, 720.0] {
                    let a = fast.reflectance(d, l);
                    let b = film_reflectance(idx, d, angle, l, pol);
                    assert!((a - b).abs() < 1e-13, "{a} vs {b}");
                }
            }
        }
    }
}

#[test]
fn half_order_peaks_for_film_above_substrate() {
    // ZnS on PET, S light: peaks at phi = (m + 1/2) lambda; MgF2 on PET: at phi = m lambda.
    for (film, offset) in [(2.37, 0.5), (1.37, 0.0)] {
        let idx = Indices {
            film,
            ..AIR_PET_MGF2
        };
        let f = FilmAtAngle::new(idx, 30.0, Polarization::S).expect("propagating");
        assert_eq!(f.peak_phase_offset(), offset);
        let d = 500.0;
        let phi = f.optical_path_nm(d);
        let m = 3.0;
        let peak_nm = phi / (m + offset);
        let r0 = f.reflectance(d, peak_nm);
        assert!(r0 > f.reflectance(d, peak_nm * 1.01) && r0 > f.reflectance(d, peak_nm * 0.99));
    }
}

#[test]
fn total_internal_reflection_reflects_everything() {
    let idx = Indices {
        back_face: BackFace::None,
        ambient: 1.6,
        film: 1.3,
        substrate: 1.4,
        substrate_k: 0.0,
    };
    // Beyond the critical angle at the ambient/film interface (asin(1.3/1.6) = 54.3 deg), a
    // thick film lets no light through.
    let r = film_reflectance(idx, 5000.0, 70.0, 500.0, Polarization::S);
    assert!((r - 1.0).abs() < 1e-9, "R = {r}");
    assert!(FilmAtAngle::new(idx, 70.0, Polarization::S).is_none());
}

#[test]
fn passband_weights_are_normalised_and_narrow_band_converges() {
    let b = Passband::gaussian(550.0, 4.0);
    let total: f64 = b.nodes().map(|(_, w)| w).sum();
    assert!((total - 1.0).abs() < 1e-14);
    let stack = FilmStack {
        back_face: BackFace::None,
        ambient_index: 1.0,
        film: Dispersion::constant(1.37),
        substrate: Dispersion::constant(1.65),
        polarization: Polarization::S,
    };
    let narrow = stack.band_reflectance(400.0, 10.0, &Passband::gaussian(550.0, 1e-3));
    let mono = stack.reflectance(400.0, 10.0, 550.0);
    assert!((narrow - mono).abs() < 1e-9);
}

#[test]
fn dispersion_formulas_match_published_values() {
    let zns = materials::zns_debenham();
    assert!(
        (zns.index_at(550.0) - 2.386).abs() < 2e-3,
        "{}",
        zns.index_at(550.0)
    );
    assert!(zns.index_at(400.0) - zns.index_at(720.0) > 0.2);
    let mgf2 = materials::MGF2_DODGE_O;
    assert!(
        (mgf2.index_at(550.0) - 1.3790).abs() < 5e-4,
        "{}",
        mgf2.index_at(550.0)
    );
    let c = Dispersion::cauchy(1.5, 0.01);
    assert!((c.index_at(500.0) - 1.54).abs() < 1e-12);
}

/// The band model's slope over thickness is the derivative of its reflectance, analytic or
/// by central difference (evanescent film: an ambient denser than the film at a steep
/// angle), for every polarisation and a dispersive film.
#[test]
fn band_slope_is_the_derivative_of_the_band_reflectance() {
    let cauchy = Dispersion::Cauchy {
        a: 2.2,
        b_um2: 0.03,
        c_um4: 0.0,
    };
    for (ambient, film, angle) in [
        (1.0, Dispersion::constant(1.38), 30.0),
        (1.0, cauchy, 65.0),
        (1.7, Dispersion::constant(1.38), 55.0),
    ] {
        for pol in [Polarization::S, Polarization::P, Polarization::Unpolarized] {
            let stack = FilmStack {
                back_face: BackFace::None,
                ambient_index: ambient,
                film,
                substrate: Dispersion::constant(1.52),
                polarization: pol,
            };
            let model = BandModel::new(stack, angle, Passband::gaussian(480.0, 6.0));
            for d in [5.0, 137.0, 612.5, 1800.0] {
                let (r, slope) = model.reflectance_and_slope(d);
                assert!(
                    (r - model.reflectance(d)).abs() < 1e-15,
                    "{pol:?} {angle} {d}"
                );
                let h = 1e-3;
                let numeric = (model.reflectance(d + h) - model.reflectance(d - h)) / (2.0 * h);
                assert!(
                    (slope - numeric).abs() < 1e-8,
                    "{pol:?} {angle} {d}: {slope} vs {numeric}"
                );
            }
        }
    }
}
