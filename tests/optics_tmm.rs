//! The Airy model against the Python `tmm` package (an independent transfer-matrix code):
//! `tests/fixtures/optics/gen_tmm.py` made the fixtures once; see its docstring.

use filmscope::optics::{film_reflectance, Dispersion, FilmStack, Indices, Passband, Polarization};

fn rows(name: &str) -> Vec<Vec<String>> {
    let path = format!(
        "{}/tests/fixtures/optics/{name}",
        env!("CARGO_MANIFEST_DIR")
    );
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split(',').map(str::to_owned).collect())
        .collect()
}

fn num(s: &str) -> f64 {
    s.parse()
        .unwrap_or_else(|e| panic!("bad number {s:?}: {e}"))
}

fn pol(s: &str) -> Polarization {
    Polarization::from_name(s).unwrap_or_else(|| panic!("bad polarisation {s:?}"))
}

#[test]
fn airy_reflectance_matches_tmm_to_1e9() {
    let rows = rows("tmm_airy.csv");
    assert!(rows.len() > 300, "fixture has {} rows", rows.len());
    let mut worst = 0.0f64;
    let mut high_index = 0;
    for r in &rows {
        let idx = Indices {
            back_face: filmscope_core::optics::BackFace::None,
            ambient: num(&r[0]),
            film: num(&r[1]),
            substrate: num(&r[2]),
            substrate_k: 0.0,
        };
        high_index += usize::from(idx.film > idx.substrate);
        let got = film_reflectance(idx, num(&r[3]), num(&r[4]), num(&r[5]), pol(&r[6]));
        let want = num(&r[7]);
        let err = (got - want).abs();
        worst = worst.max(err);
        assert!(err < 1e-9, "row {r:?}: got {got}, tmm {want}");
    }
    assert!(high_index > 100, "high-index films must be covered");
    eprintln!("worst |R - R_tmm| over {} rows: {worst:.3e}", rows.len());
}

#[test]
fn band_averaged_reflectance_matches_tmm_passband_to_1e6() {
    let rows = rows("tmm_passband.csv");
    assert!(rows.len() > 100);
    let mut worst = 0.0f64;
    for r in &rows {
        let stack = FilmStack {
            back_face: filmscope_core::optics::BackFace::None,
            ambient_index: num(&r[0]),
            film: Dispersion::cauchy(num(&r[1]), num(&r[2])),
            substrate: Dispersion::constant(num(&r[3])),
            polarization: pol(&r[8]),
        };
        let band = Passband::gaussian(num(&r[6]), num(&r[7]));
        let got = stack.band_reflectance(num(&r[4]), num(&r[5]), &band);
        let want = num(&r[9]);
        worst = worst.max((got - want).abs());
        assert!(
            (got - want).abs() < 1e-6,
            "row {r:?}: got {got}, tmm {want}"
        );
    }
    eprintln!(
        "worst band-average error over {} rows: {worst:.3e}",
        rows.len()
    );
}

/// A bare back face (`sample.back_face = "bare"`): the general Airy sum and the fast
/// per-angle form both match tmm's incoherent stack (film coherent, 1 mm substrate
/// incoherent, air behind) over random films, angles to 75 degrees and all polarisations.
#[test]
fn a_bare_back_face_matches_tmm_incoherent_stack_to_1e9() {
    use filmscope::optics::{BackFace, FilmAtAngle};
    let rows = rows("tmm_back_face.csv");
    assert!(rows.len() >= 240, "fixture has {} rows", rows.len());
    let mut worst = 0.0f64;
    let mut added = 0.0f64;
    for r in &rows {
        let idx = Indices {
            ambient: 1.0,
            film: num(&r[0]),
            substrate: num(&r[1]),
            substrate_k: 0.0,
            back_face: BackFace::Bare,
        };
        let (d, deg, l, p) = (num(&r[2]), num(&r[3]), num(&r[4]), pol(&r[5]));
        let want = num(&r[6]);
        let got = film_reflectance(idx, d, deg, l, p);
        let fast = FilmAtAngle::new(idx, deg, p)
            .expect("propagating")
            .reflectance(d, l);
        let without = film_reflectance(
            Indices {
                back_face: BackFace::None,
                ..idx
            },
            d,
            deg,
            l,
            p,
        );
        for v in [got, fast] {
            let err = (v - want).abs();
            worst = worst.max(err);
            assert!(err < 1e-9, "row {r:?}: got {v}, tmm {want}");
        }
        added = added.max(want - without);
    }
    // The back face matters: without it the model misses by up to several percent.
    assert!(added > 0.02, "largest back-face share {added}");
    eprintln!(
        "worst |R - R_tmm| over {} rows: {worst:.3e}; back face adds up to {added:.4}",
        rows.len()
    );
}

/// An absorbing substrate (`n + i k`, silicon's range): the general Airy sum matches tmm's
/// coherent stack to 1e-9 at every polarisation, and so does the fast per-angle form
/// (`R` as a function of `cos(Delta + psi)`) for S and P light; for unpolarised light its
/// one phase for both polarisations stays within 3e-4 of tmm for k up to 0.3 (silicon's at
/// 400 nm) and angles up to 60 degrees, and the phase matters: without it the rows miss by
/// far more.
#[test]
fn an_absorbing_substrate_matches_tmm_to_1e9() {
    use filmscope::optics::{BackFace, FilmAtAngle};
    let rows = rows("tmm_absorbing.csv");
    assert!(rows.len() >= 240, "fixture has {} rows", rows.len());
    let (mut worst, mut worst_unpolarised, mut without_phase) = (0.0f64, 0.0f64, 0.0f64);
    for r in &rows {
        let idx = Indices {
            ambient: 1.0,
            film: num(&r[0]),
            substrate: num(&r[1]),
            substrate_k: num(&r[2]),
            back_face: BackFace::None,
        };
        let (d, deg, l, p) = (num(&r[3]), num(&r[4]), num(&r[5]), pol(&r[6]));
        let want = num(&r[7]);
        let got = film_reflectance(idx, d, deg, l, p);
        assert!(
            (got - want).abs() < 1e-9,
            "row {r:?}: got {got}, tmm {want}"
        );
        worst = worst.max((got - want).abs());
        let film = FilmAtAngle::new(idx, deg, p).expect("propagating");
        let fast = film.reflectance(d, l);
        let err = (fast - want).abs();
        if p == Polarization::Unpolarized {
            // One phase for both polarisations: close where silicon is in the visible (k up
            // to 0.3 at 400 nm) up to 60 degrees; the rest is reported, not bounded.
            if idx.substrate_k <= 0.3 && deg <= 60.0 {
                assert!(err < 3e-4, "row {r:?}: fast {fast}, tmm {want}");
                worst_unpolarised = worst_unpolarised.max(err);
            }
        } else {
            assert!(err < 1e-9, "row {r:?}: fast {fast}, tmm {want}");
            worst = worst.max(err);
        }
        let delta = 4.0 * std::f64::consts::PI * d * film.kz_film / l;
        let no_phase = film.reflectance_at_cos(delta.cos());
        without_phase = without_phase.max((no_phase - want).abs());
    }
    assert!(
        without_phase > 1e-2,
        "the phase changes R by {without_phase}"
    );
    eprintln!(
        "worst |R - R_tmm| over {} rows: {worst:.3e} (S, P and general), {worst_unpolarised:.3e} (unpolarised, fast form, k <= 0.3, <= 60 deg); without the phase {without_phase:.3e}",
        rows.len()
    );
}

/// A weakly absorbing film (k to 0.02, an oxide's or a polymer's in the blue), its back
/// face black or bare: [`LossyFilm`], the form the sample fit uses for film absorption,
/// matches tmm's coherent and incoherent stacks to 1e-9; the lossless form with the round
/// trip's amplitude alone on `r23` misses by far more.
#[test]
fn an_absorbing_film_matches_tmm_with_and_without_a_back_face() {
    use filmscope::optics::{BackFace, LossyFilm};
    use filmscope::solve::refine::{BandCoef, FilmTerms, ABSORPTION_TAIL_NM};
    use filmscope::solve::IndexModel;
    let rows = rows("tmm_absorbing_film.csv");
    assert!(rows.len() >= 240, "fixture has {} rows", rows.len());
    let (mut worst, mut amplitude_only, mut worst_band) = (0.0f64, 0.0f64, 0.0f64);
    for r in &rows {
        let (n, k, ns) = (num(&r[0]), num(&r[1]), num(&r[2]));
        let (d, deg, l, p) = (num(&r[3]), num(&r[4]), num(&r[5]), pol(&r[6]));
        let back_face = match r[7].as_str() {
            "bare" => BackFace::Bare,
            _ => BackFace::None,
        };
        let want = num(&r[8]);
        let idx = Indices {
            ambient: 1.0,
            film: n,
            substrate: ns,
            substrate_k: 0.0,
            back_face,
        };
        let film = LossyFilm::new(idx, k, deg, p, l).expect("propagating");
        let (phase, a) = film.round_trip(d);
        let (got, _, _) = film.reflectance(phase.cos(), phase.sin(), a);
        let err = (got - want).abs();
        worst = worst.max(err);
        assert!(err < 1e-9, "row {r:?}: got {got}, tmm {want}");
        // The per-pixel band model with the sample's absorption (its k at 450 nm set so that
        // the Urbach tail gives the row's k), through a passband too narrow to average.
        let film_k = k / ((450.0 - l) / ABSORPTION_TAIL_NM).exp();
        let band = BandCoef::new(
            IndexModel::constant(n),
            FilmTerms { film_k, leak: 0.0 },
            1.0,
            ns,
            0.0,
            back_face,
            p,
            deg,
            l,
            1e-3,
            d + 10.0,
        )
        .expect("propagating");
        let band_err = (band.model(d) - want).abs();
        worst_band = worst_band.max(band_err);
        assert!(
            band_err < 1e-6,
            "row {r:?}: band model {}, tmm {want}",
            band.model(d)
        );
        if back_face == BackFace::None {
            // The film's loss as the round trip's amplitude alone, its interfaces clear.
            let clear = LossyFilm::new(idx, 0.0, deg, p, l).expect("propagating");
            let (phase, _) = clear.round_trip(d);
            let approx = clear.reflectance(phase.cos(), phase.sin(), a).0;
            amplitude_only = amplitude_only.max((approx - want).abs());
        }
    }
    assert!(
        amplitude_only > 1e-3,
        "amplitude alone misses by {amplitude_only}"
    );
    eprintln!(
        "worst |R - R_tmm| over {} rows: {worst:.3e} (the per-pixel band model {worst_band:.3e}); the amplitude alone on r23 misses by up to {amplitude_only:.2e}",
        rows.len()
    );
}
