use super::*;

fn run(samples: impl Iterator<Item = f32>) -> (ExtremaList, PixelTracker) {
    let mut t = PixelTracker::default();
    let mut out = ExtremaList::new();
    for (b, v) in samples.enumerate() {
        t.push(b as u16, v, true, &mut out);
    }
    (out, t)
}

#[test]
fn finds_the_extrema_of_a_clean_cosine_to_a_tenth_of_a_band() {
    // Period 40 bands: peaks at 20, 60, 100; valleys at 40, 80.
    let f = |b: f32| 0.1 + 0.05 * libm::cosf(2.0 * core::f32::consts::PI * (b - 20.0) / 40.0);
    let (out, _) = run((0..120).map(|b| f(b as f32)));
    let want = [
        (20.0, Kind::Peak),
        (40.0, Kind::Valley),
        (60.0, Kind::Peak),
        (80.0, Kind::Valley),
        (100.0, Kind::Peak),
    ];
    assert_eq!(out.len(), want.len(), "{out:?}");
    for (e, (pos, kind)) in out.iter().zip(want) {
        assert_eq!(e.kind(), kind);
        assert!((e.band() - pos).abs() < 0.1, "{e:?} vs {pos}");
    }
}

#[test]
fn noise_on_a_broad_top_does_not_split_the_peak() {
    let mut seed = 7u32;
    let mut noise = || {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        // Sum of 4 uniforms: roughly normal, sigma ~ 0.003.
        let mut s = 0.0;
        for _ in 0..4 {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            s += (seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5;
        }
        s * 0.0052
    };
    // One broad fringe (period 200 bands), amplitude 0.03, peak at 80, valley at 180.
    let f = |b: f32| 0.05 + 0.03 * libm::cosf(2.0 * core::f32::consts::PI * (b - 80.0) / 200.0);
    let (out, t) = run((0..170).map(|b| f(b as f32) + noise()));
    assert!(
        (t.noise_sigma() - 0.003).abs() < 0.001,
        "sigma {}",
        t.noise_sigma()
    );
    assert_eq!(out.len(), 1, "{out:?}");
    assert_eq!(out[0].kind(), Kind::Peak);
    assert!((out[0].band() - 80.0).abs() < 12.0, "{:?}", out[0]);
}

#[test]
fn edges_are_not_extrema_and_bad_samples_are_counted() {
    let (out, t) = run((0..60).map(|b| if b == 30 { f32::NAN } else { b as f32 * 0.01 }));
    assert!(out.is_empty(), "{out:?}");
    assert_eq!(t.bad_samples, 1);
}

#[test]
fn state_size_is_fixed() {
    assert!(
        core::mem::size_of::<PixelTracker>() <= 76,
        "{}",
        core::mem::size_of::<PixelTracker>()
    );
}

/// Found by the property tests: a huge finite sample (bad bytes in a float cube) overflowed
/// the smoothing sums and placed an extremum at NaN (band 0), out of order.
#[test]
fn proptest_huge_finite_samples_are_bad_samples() {
    let mut s = [0.0f32; 12];
    s[2] = 0.775;
    s[3] = f32::NAN;
    s[10] = -1.124_262_1e38;
    let (out, t) = run(s.iter().copied());
    assert_eq!(t.bad_samples, 2);
    assert!(out.windows(2).all(|w| w[0].band() <= w[1].band()));
    assert!(t.noise_sigma().is_finite());
}

/// Found by the property tests: spikes less than two bands apart gave extrema out of band
/// order (sub-band vertices move up to a band either way).
#[test]
fn proptest_close_spikes_keep_extrema_in_band_order() {
    let mut s = [0.0f32; 116];
    s[102] = 0.986;
    s[105] = 0.731;
    s[111] = -1421.911;
    let (out, _) = run(s.iter().copied());
    assert!(
        out.windows(2).all(|w| w[0].band() <= w[1].band()),
        "{:?}",
        out.iter().map(|e| e.band()).collect::<Vec<_>>()
    );
}

/// The carried moments give the 9-point quadratic Savitzky-Golay smoothing, slope and
/// curvature (the weights of Savitzky & Golay's tables: smoothing -21 14 39 54 59 ... / 231,
/// slope -4..4 / 60, curvature 28 7 -8 -17 -20 ... / 462) over a long noisy stream, the
/// recursion's rounding kept in check by the exact recompute at each wrap.
#[test]
fn carried_moments_match_the_savitzky_golay_weights() {
    const SMOOTH: [f32; 9] = [-21.0, 14.0, 39.0, 54.0, 59.0, 54.0, 39.0, 14.0, -21.0];
    const CURV: [f32; 9] = [28.0, 7.0, -8.0, -17.0, -20.0, -17.0, -8.0, 7.0, 28.0];
    let mut seed = 11u32;
    let mut t = PixelTracker::default();
    let mut out = ExtremaList::new();
    let mut hist = vec![];
    for b in 0..1000u16 {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let v = 0.3 + 0.2 * libm::sinf(f32::from(b) * 0.21) + (seed >> 8) as f32 * 1e-9;
        hist.push(v);
        t.push(b, v, true, &mut out);
        if hist.len() >= WINDOW {
            let w = &hist[hist.len() - WINDOW..];
            let dot = |c: &[f32; 9]| w.iter().zip(c).map(|(x, c)| x * c).sum::<f32>();
            let slope: f32 = w
                .iter()
                .enumerate()
                .map(|(k, x)| (k as f32 - 4.0) * x)
                .sum();
            let [m0, m1, m2] = t.moments;
            assert!(((59.0 * m0 - 5.0 * m2) / 231.0 - dot(&SMOOTH) / 231.0).abs() < 2e-6);
            assert!((m1 / 60.0 - slope / 60.0).abs() < 2e-6);
            assert!(((3.0 * m2 - 20.0 * m0) / 462.0 - dot(&CURV) / 462.0).abs() < 2e-6);
        }
    }
}
