//! Property tests of the tracker and the solvers: state stays bounded, finite input never
//! gives NaN, and the order of angles (or of what they contribute) does not matter.

use filmscope_core::solve::index::{combine, PairEstimate, PairGeometry};
use filmscope_core::solve::order::{Observation, OrderContext};
use filmscope_core::solve::IndexModel;
use filmscope_core::track::row::{blocks_for, pixel, push_row, TrackerLanes};
use filmscope_core::track::{ExtremaList, Kind, PixelTracker, MAX_EXTREMA};
use proptest::prelude::*;

/// Any f32 at all, NaN and infinities included, weighted towards reflectance-like values.
fn any_sample() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => 0.0f32..1.0,
        1 => proptest::num::f32::ANY,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
    ]
}

fn track(samples: &[f32]) -> (ExtremaList, PixelTracker) {
    let mut t = PixelTracker::default();
    let mut out = ExtremaList::new();
    for (b, &v) in samples.iter().enumerate() {
        t.push(b as u16, v, true, &mut out);
    }
    (out, t)
}

proptest! {
    // 2000 cases each (PROPTEST_CASES overrides, e.g. for a long run).
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(2000),
        ..ProptestConfig::default()
    })]

    /// Whatever it is fed, the tracker keeps at most MAX_EXTREMA extrema, in increasing
    /// band order, inside the bands seen, and never panics; its state is 52 bytes.
    #[test]
    fn tracker_state_is_bounded(samples in proptest::collection::vec(any_sample(), 0..1100)) {
        let (out, t) = track(&samples);
        prop_assert!(out.len() <= MAX_EXTREMA);
        prop_assert!(out.windows(2).all(|w| w[0].band() <= w[1].band()));
        prop_assert!(out.iter().all(|e| e.band() >= 0.0 && e.band() <= samples.len() as f32));
        prop_assert!(out.windows(2).all(|w| w[0].kind() != w[1].kind()), "peaks and valleys alternate");
        prop_assert!(!t.noise_sigma().is_nan());
        prop_assert_eq!(std::mem::size_of::<PixelTracker>(), 52);
    }

    /// The row kernel the workers run finds what the scalar tracker finds, pixel by pixel,
    /// whatever the samples (NaN, infinities, huge values, any row width and band count).
    #[test]
    fn row_kernel_matches_the_scalar_tracker(
        width in 1usize..80,
        rows in proptest::collection::vec(proptest::collection::vec(any_sample(), 80), 0..160),
        subband in any::<bool>(),
    ) {
        let mut blocks = vec![TrackerLanes::EMPTY; blocks_for(1, width)];
        let mut lists = vec![ExtremaList::new(); width];
        let mut scalar = vec![PixelTracker::default(); width];
        let mut scalar_lists = vec![ExtremaList::new(); width];
        for (b, row) in rows.iter().enumerate() {
            push_row(&mut blocks, b as u16, &row[..width], subband, &mut lists);
            for ((t, l), &v) in scalar.iter_mut().zip(&mut scalar_lists).zip(row) {
                t.push(b as u16, v, subband, l);
            }
        }
        for (i, t) in scalar.iter().enumerate() {
            let r = pixel(&blocks, width, i);
            prop_assert_eq!(&*lists[i], &*scalar_lists[i], "pixel {}", i);
            prop_assert_eq!(r.noise_sigma().to_bits(), t.noise_sigma().to_bits());
        }
    }

    /// Finite samples give a finite noise estimate and finite extrema positions.
    #[test]
    fn tracker_gives_no_nan_from_finite_input(
        samples in proptest::collection::vec(-1e6f32..1e6, 3..600),
    ) {
        let (out, t) = track(&samples);
        prop_assert!(t.noise_sigma().is_finite(), "noise {}", t.noise_sigma());
        prop_assert!(out.iter().all(|e| e.band().is_finite()));
    }

    /// The pair geometry inverts its own ratio for every physical index, at any two
    /// distinct angles, and gives no NaN for finite input.
    #[test]
    fn pair_geometry_round_trips_the_index(
        a in 0.0f64..80.0,
        b in 0.0f64..80.0,
        n in 1.3f64..3.0,
    ) {
        if let Some(g) = PairGeometry::new(1.0, a, b, [1.2, 3.2], [420.0, 720.0]) {
            let rho = g.ratio(n);
            prop_assert!(rho.is_finite());
            let back = g.index_from_ratio(rho);
            prop_assert!(back.is_some_and(|m| (m - n).abs() < 1e-6 * n), "{n} -> {rho} -> {back:?}");
            prop_assert!(g.index_slope(rho).is_finite());
        }
    }

    /// Combining per-angle-pair estimates does not depend on their order (the angles may
    /// arrive in any order), and finite estimates give a finite index.
    #[test]
    fn combined_index_does_not_depend_on_angle_order(
        est in proptest::collection::vec((1.3f64..3.0, 1e-4f64..0.1, 1.0f64..100.0), 1..8),
        rot in 0usize..8,
    ) {
        let e: Vec<PairEstimate> = est
            .iter()
            .map(|&(index, sigma, votes)| PairEstimate { index, sigma, votes })
            .collect();
        let mut r = e.clone();
        r.reverse();
        let k = rot % r.len();
        r.rotate_left(k);
        let (x, y) = (combine(&e), combine(&r));
        match (x, y) {
            (Some((n1, s1)), Some((n2, s2))) => {
                prop_assert!(n1.is_finite() && s1.is_finite());
                prop_assert!((n1 - n2).abs() < 1e-9 * n1, "{n1} vs {n2}");
                prop_assert!((s1 - s2).abs() < 1e-9 * s1 + 1e-15, "{s1} vs {s2}");
            }
            (x, y) => prop_assert!(false, "{x:?} vs {y:?}"),
        }
    }

    /// The order search never panics, gives finite thicknesses, does not depend on the
    /// order its observations are listed in, and chooses the same in the portable build.
    #[test]
    fn order_search_is_finite_and_order_free(
        obs in proptest::collection::vec((420.0f64..720.0, any::<bool>(), 0usize..2), 0..20),
        n in 1.3f64..2.8,
        a0 in 0.0f64..40.0,
        a1 in 41.0f64..70.0,
    ) {
        let ctx = OrderContext {
            index: IndexModel::constant(n),
            x: [a0, a1].map(|d: f64| d.to_radians().sin().powi(2)),
            angles: 2,
            peak_offset: [0.0, 0.0],
            thickness_range_nm: [50.0, 2000.0],
            reliable_nm: [430.0, 710.0],
            wide: true,
        };
        let o: Vec<Observation> = obs
            .iter()
            .map(|&(wavelength_nm, peak, angle)| Observation {
                wavelength_nm,
                kind: if peak { Kind::Peak } else { Kind::Valley },
                angle,
            })
            .collect();
        let mut rev = o.clone();
        rev.reverse();
        let (x, y) = (ctx.resolve(&o), ctx.resolve(&rev));
        // The portable build's choice, bit for bit (NaN runners-up compared as printed).
        let portable = OrderContext { wide: false, ..ctx }.resolve(&o);
        prop_assert_eq!(format!("{portable:?}"), format!("{x:?}"));
        if let Some(c) = x {
            prop_assert!(c.thickness_nm.is_finite() && c.cost.is_finite(), "{c:?}");
        }
        match (x, y) {
            (Some(p), Some(q)) => prop_assert!(
                (p.thickness_nm - q.thickness_nm).abs() < 1e-6 * p.thickness_nm.abs().max(1.0)
                    || (p.cost - p.runner_up_cost).abs() < 1e-9,
                "{p:?} vs {q:?}"
            ),
            (None, None) => {}
            (p, q) => prop_assert!(false, "{p:?} vs {q:?}"),
        }
    }
}
