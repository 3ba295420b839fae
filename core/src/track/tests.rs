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
fn edges_are_not_extrema_and_bad_samples_are_bridged() {
    let (out, t) = run((0..60).map(|b| if b == 30 { f32::NAN } else { b as f32 * 0.01 }));
    assert!(out.is_empty(), "{out:?}");
    // The ramp's second differences are zero, the bridged sample's too (it repeats the one
    // before, so one difference of a step and its mirror).
    assert!(t.noise_sigma() < 1e-3, "{}", t.noise_sigma());
}

#[test]
fn state_size_is_fixed() {
    assert!(
        core::mem::size_of::<PixelTracker>() <= 56,
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

/// The carried moments are the window's own, exactly (integer sums of its ring steps), over
/// a long noisy stream, and give the 9-point quadratic Savitzky-Golay smoothing, slope and
/// curvature (the weights of Savitzky & Golay's tables: smoothing -21 14 39 54 59 ... / 231,
/// slope -4..4 / 60, curvature 28 7 -8 -17 -20 ... / 462).
#[test]
fn carried_moments_match_the_savitzky_golay_weights() {
    const SMOOTH: [i64; 9] = [-21, 14, 39, 54, 59, 54, 39, 14, -21];
    const CURV: [i64; 9] = [28, 7, -8, -17, -20, -17, -8, 7, 28];
    let mut seed = 11u32;
    let mut t = PixelTracker::default();
    let mut out = ExtremaList::new();
    let (mut hist, mut raw) = (vec![], vec![]);
    for b in 0..5000u16 {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let v = 0.3 + 0.2 * libm::sinf(f32::from(b) * 0.21) + (seed >> 8) as f32 * 1e-9;
        raw.push(f64::from(v));
        hist.push(i64::from(to_ring(v)));
        t.push(b, v, true, &mut out);
        if hist.len() >= WINDOW {
            let w = &hist[hist.len() - WINDOW..];
            let dot = |c: &[i64; 9]| w.iter().zip(c).map(|(x, c)| x * c).sum::<i64>();
            let k = [-4i64, -3, -2, -1, 0, 1, 2, 3, 4];
            let [m0, m1, m2] = t.moments.map(|m| m as i64);
            assert!(t.moments.iter().all(|m| m.fract() == 0.0));
            assert_eq!(m0, w.iter().sum::<i64>());
            assert_eq!(m1, dot(&k));
            assert_eq!(m2, dot(&k.map(|k| k * k)));
            assert_eq!(59 * m0 - 5 * m2, dot(&SMOOTH));
            assert_eq!(3 * m2 - 20 * m0, dot(&CURV));
        }
    }
    // The noise estimate is in reflectance: within 0.1 % of the unrounded samples' own.
    let d2: f64 = raw
        .windows(3)
        .map(|w| (w[0] - 2.0 * w[1] + w[2]).abs())
        .sum();
    let want = d2 / (raw.len() - 2) as f64 / 1.954;
    let got = f64::from(t.noise_sigma());
    assert!((got / want - 1.0).abs() < 1e-3, "{got} against {want}");
}

/// A ring step is the nearest of the grid (within half a step, 1.53e-5, of the sample), its
/// reflectance exact, and a sample beyond the ring's range is held at its end.
#[test]
fn ring_steps_round_to_the_nearest_and_clamp() {
    let step = 1.0 / RING_STEPS_PER_UNIT;
    let mut worst = 0.0f32;
    // -0.5 to 1.49, inside the ring's range.
    for k in 0..199_000u32 {
        let v = -0.5 + k as f32 * 1.0e-5 + (k % 7) as f32 * 1.3e-7;
        let q = to_ring(v);
        let back = from_ring(q);
        worst = worst.max((back - v).abs());
        // Exact: the step count read back.
        assert_eq!((back + 0.5) * RING_STEPS_PER_UNIT, f32::from(q));
    }
    // Half a step, and the f32 rounding of `v + 0.5` (an ulp of 2 is 2.4e-7).
    assert!(worst <= 0.5 * step + 2.4e-7, "{worst}");
    assert!(worst > 0.45 * step, "{worst}");
    assert_eq!(to_ring(-3.0), 0);
    assert_eq!(to_ring(2.0), u16::MAX);
    assert_eq!(to_ring(MAX_SAMPLE), u16::MAX);
    assert_eq!(from_ring(to_ring(0.25)), 0.25);
}

/// A packed sample is its ring step, so the tracker sees it as it would the sample itself;
/// saturated and unusable samples come back as `+inf` and NaN (the full-spectrum sums count
/// them apart), and nothing usable is taken for either.
#[test]
fn packed_samples_are_their_ring_steps_and_keep_saturated_and_dead_apart() {
    let mut seed = 5u32;
    for _ in 0..20_000 {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let v = -0.6 + 2.2 * (seed >> 8) as f32 / (1u32 << 24) as f32;
        let back = unpack_sample(pack_sample(v));
        assert!(usable(back) && back.is_finite(), "{v}: {back}");
        if v <= 1.4999 {
            assert_eq!(to_step(back).1, to_ring(v), "{v}");
            assert_eq!(back, from_ring(to_ring(v)), "{v}");
        } else {
            assert!((1.4999..1.5).contains(&back), "{v}: {back}");
        }
    }
    for sat in [f32::INFINITY, f32::NEG_INFINITY] {
        assert_eq!(unpack_sample(pack_sample(sat)), f32::INFINITY);
    }
    for dead in [f32::NAN, 2.0 * MAX_SAMPLE, -2.0 * MAX_SAMPLE] {
        assert!(unpack_sample(pack_sample(dead)).is_nan(), "{dead}");
    }
    assert_eq!(unpack_sample(pack_sample(0.25)), 0.25);
}

/// A running extreme's position code rounds as `Extremum` did (`libm::roundf` of the band
/// clamped to `0..1024`, in 1/32 band): ties away from zero, NaN and negatives to 0, beyond
/// the last position to it; the row kernel's narrowing gives every code back.
#[test]
fn position_codes_round_as_libm_roundf() {
    let max = f32::from(VALLEY_BIT - 1) / POS_PER_BAND;
    let old = |b: f32| libm::roundf(b.clamp(0.0, max) * POS_PER_BAND) as u16;
    let mut bands: Vec<f32> = (0..4000).map(|k| (k as f32 + 0.5) / POS_PER_BAND).collect();
    bands.extend((0..4000).map(|k| k as f32 * 0.013_7 + 0.001));
    bands.extend([0.0, -0.0, -3.0, max, max + 0.01, 1e9, f32::INFINITY]);
    for b in bands {
        assert_eq!(to_pos(b), old(b), "band {b}");
        assert_eq!(
            Extremum::new(b, Kind::Peak).band(),
            f32::from(old(b)) / POS_PER_BAND
        );
    }
    assert_eq!(to_pos(f32::NAN), 0);
    assert_eq!(to_pos(f32::NEG_INFINITY), 0);
    let codes: [f32; row::LANES] = core::array::from_fn(|i| [0, 1, 32767, 65535][i % 4] as f32);
    let mut out = [0u16; row::LANES];
    row::narrow(&codes, &mut out);
    assert!(out.iter().zip(&codes).all(|(&o, &c)| f32::from(o) == c));
}
