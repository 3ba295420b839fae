use super::*;
use crate::track::{ExtremaList, Extremum};

/// Every field of two trackers, floats by their bits.
fn same_state(a: &PixelTracker, b: &PixelTracker) -> bool {
    let bits = |t: &PixelTracker| {
        let mut v: Vec<u32> = t.ring.iter().map(|&q| u32::from(q)).collect();
        v.extend(t.moments.iter().map(|x| x.to_bits()));
        v.extend([t.ext_val, t.min_val, t.d2_sum].iter().map(|x| x.to_bits()));
        v.extend([
            u32::from(t.ext_pos),
            u32::from(t.min_pos),
            u32::from(t.seen),
            u32::from(t.head),
            t.mode as u32,
        ]);
        v
    };
    bits(a) == bits(b)
}

/// A pixel's whole list that counts the extrema it refused (the overflow its owner flags).
#[derive(Clone, Default)]
struct Counted {
    list: ExtremaList,
    refused: usize,
}

impl ExtremumSink for Counted {
    fn last_extremum(&self) -> Option<Extremum> {
        self.list.last_extremum()
    }

    fn push(&mut self, e: Extremum) -> Result<(), Extremum> {
        self.list.push(e).inspect_err(|_| self.refused += 1)
    }
}

/// A small deterministic generator, uniform in `[0, 1)`.
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Feeds `spectra[pixel][band]` (every pixel `bands` long) to scalar trackers and to the row
/// kernel, one row of `width = spectra.len()` pixels, for two angles, and requires the same
/// state, extrema, noise, bad samples and refused extrema after every band. Returns what the
/// row covered: extrema found, lanes overflowed, lanes out of step.
fn check(spectra: &[Vec<f32>], bands: usize, subband: bool) -> [usize; 3] {
    let width = spectra.len();
    let mut scalar = vec![PixelTracker::default(); width];
    let mut scalar_lists = vec![Counted::default(); width];
    let mut blocks = vec![TrackerLanes::default(); blocks_for(1, width)];
    let mut lists = vec![Counted::default(); width];
    for angle in 0..2 {
        scalar.iter_mut().for_each(PixelTracker::reset);
        scalar_lists.fill(Counted::default());
        blocks.iter_mut().for_each(TrackerLanes::reset);
        lists.fill(Counted::default());
        for b in 0..bands {
            let row: Vec<f32> = spectra.iter().map(|s| s[b]).collect();
            for ((t, l), &v) in scalar.iter_mut().zip(&mut scalar_lists).zip(&row) {
                t.push(b as u16, v, subband, l);
            }
            push_row(&mut blocks, b as u16, &row, subband, &mut lists);
            for i in 0..width {
                let (t, r) = (&scalar[i], pixel(&blocks, width, i));
                assert!(
                    same_state(t, &r),
                    "angle {angle} band {b} pixel {i}: {t:?} vs {r:?}"
                );
                assert_eq!(*scalar_lists[i].list, *lists[i].list, "band {b} pixel {i}");
                assert_eq!(t.noise_sigma().to_bits(), r.noise_sigma().to_bits());
                assert_eq!(scalar_lists[i].refused, lists[i].refused);
            }
        }
    }
    [
        lists.iter().map(|l| l.list.len()).sum(),
        lists.iter().filter(|l| l.refused > 0).count(),
        blocks
            .iter()
            .map(|b| (0..LANES).filter(|&i| b.lag(i) != 0).count())
            .sum(),
    ]
}

/// Pixel `p` of a test row: fringes of many periods and amplitudes with noise, with bad
/// samples (NaN, infinities, huge finite values) sprinkled or leading, spikes, flat and
/// all-bad spectra, and one with more extrema than a list holds.
fn spectrum(p: usize, bands: usize, rng: &mut Lcg) -> Vec<f32> {
    let period = 6.0 + (p % 23) as f32 * 3.0;
    let amp = [0.05, 0.01, 0.2, 0.002][p % 4];
    let noise = [0.0, 0.002, 0.01, 0.03][(p / 4) % 4];
    let mut s: Vec<f32> = (0..bands)
        .map(|b| {
            let x = 2.0 * core::f32::consts::PI * b as f32 / period;
            0.3 + amp * libm::cosf(x + p as f32) + noise * (rng.next() - 0.5)
        })
        .collect();
    let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 3e7, -1.1e38];
    match p % 13 {
        // Unusable first samples: the lane falls out of step.
        0 => s.iter_mut().take(1 + p % 3).for_each(|x| *x = bad[p % 5]),
        // Sprinkled bad samples.
        1 | 2 => {
            for x in s.iter_mut() {
                if rng.next() < 0.08 {
                    *x = bad[(rng.next() * 5.0) as usize % 5];
                }
            }
        }
        // Spikes.
        3 => {
            for x in s.iter_mut() {
                if rng.next() < 0.05 {
                    *x += 5.0 * (rng.next() - 0.5);
                }
            }
        }
        4 => s.iter_mut().for_each(|x| *x = 0.25),
        5 => s.iter_mut().for_each(|x| *x = f32::NAN),
        // A lane bad now and then around the window's start.
        6 => s.iter_mut().skip(7).take(4).for_each(|x| *x = f32::NAN),
        // Very fast fringes: more extrema than the list holds.
        7 => {
            for (b, x) in s.iter_mut().enumerate() {
                *x = if b % 8 < 4 { 0.9 } else { 0.1 };
            }
        }
        // Large-magnitude but usable samples.
        8 => {
            for (b, x) in s.iter_mut().enumerate() {
                *x = 9e5 * libm::sinf(b as f32 * 0.3);
            }
        }
        _ => {}
    }
    s
}

#[test]
fn the_row_kernel_matches_the_scalar_tracker() {
    let mut rng = Lcg(5);
    // Widths below, at and across the block size; band counts shorter than the window, at it,
    // just past it and long.
    for (width, bands) in [
        (1, 200),
        (7, 8),
        (31, 9),
        (32, 10),
        (33, 11),
        (LANES, 12),
        (70, 161),
        (3 * LANES + 5, 400),
        (100, 1100),
    ] {
        let spectra: Vec<Vec<f32>> = (0..width).map(|p| spectrum(p, bands, &mut rng)).collect();
        let covered = check(&spectra, bands, true);
        check(&spectra, bands, false);
        if width >= 70 {
            // The long rows exercise every rare path.
            assert!(
                covered.iter().all(|&c| c > 0),
                "{width} x {bands}: {covered:?}"
            );
        }
    }
}

#[test]
fn a_first_bad_sample_puts_a_lane_out_of_step_and_it_stays_exact() {
    let bands = 100;
    let spectra: Vec<Vec<f32>> = (0..40)
        .map(|p| {
            (0..bands)
                .map(|b| {
                    if b < p % 5 {
                        f32::NAN
                    } else {
                        0.5 + 0.3 * libm::sinf(b as f32 * 0.2 + p as f32)
                    }
                })
                .collect()
        })
        .collect();
    let [extrema, _, out_of_step] = check(&spectra, bands, true);
    assert!(extrema > 40 && out_of_step == 32, "{extrema} {out_of_step}");
}

#[test]
fn pixels_map_to_their_lanes() {
    // Rows of 40 pixels take two blocks each.
    assert_eq!(blocks_for(3, 40), 6);
    assert_eq!(locate(40, 0), (0, 0));
    assert_eq!(locate(40, 33), (1, 1));
    assert_eq!(locate(40, 40), (2, 0));
    assert_eq!(locate(40, 119), (5, 7));
}
