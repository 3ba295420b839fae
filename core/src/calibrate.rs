//! Raw counts to reflectance, one row at a time (capture-format.md):
//! `R = white_reflectance * (raw - dark) / (white - dark)`.
//!
//! Unusable samples are marked in the value itself so the stream needs no side channel:
//! `+inf` for a saturated sample (raw at or above the ADC's full scale) and NaN for a sample
//! without a usable reference (`white - dark` not positive: a dead pixel or a bad white; or
//! a white or dark at the full scale: clipped, so its true level, and the sample's
//! reflectance, are unknown; taken as it is, a clipped white reads the sample high).

/// Calibrates one row. `dark` may be absent (zero), `white` is required; all slices have the
/// row's width. `saturation_counts` is the ADC's full scale (`f32::INFINITY` if unknown).
pub fn calibrate_row(
    raw: &[f32],
    dark: Option<&[f32]>,
    white: &[f32],
    white_reflectance: f32,
    saturation_counts: f32,
    out: &mut [f32],
) {
    let n = out.len();
    // Full-length rows take the branch-free loop the compiler vectorises; a short input's
    // missing samples are NaN.
    match dark {
        Some(d) if raw.len() >= n && white.len() >= n && d.len() >= n => {
            for (((o, &r), &w), &d) in out.iter_mut().zip(raw).zip(white).zip(d) {
                *o = calibrated(r, d, w, white_reflectance, saturation_counts);
            }
        }
        None if raw.len() >= n && white.len() >= n => {
            for ((o, &r), &w) in out.iter_mut().zip(raw).zip(white) {
                *o = calibrated(r, 0.0, w, white_reflectance, saturation_counts);
            }
        }
        _ => {
            for (i, o) in out.iter_mut().enumerate() {
                let r = raw.get(i).copied().unwrap_or(f32::NAN);
                let w = white.get(i).copied().unwrap_or(f32::NAN);
                let d = dark.map_or(0.0, |d| d.get(i).copied().unwrap_or(f32::NAN));
                *o = calibrated(r, d, w, white_reflectance, saturation_counts);
            }
        }
    }
}

/// Whether a reference level (white or dark, counts) is clipped: at or above
/// `saturation_counts`, the ADC's full scale, so its true level is unknown.
#[inline(always)]
pub fn clipped(reference: f32, saturation_counts: f32) -> bool {
    reference >= saturation_counts
}

/// One sample: `+inf` at or above `saturation_counts`, NaN without a usable reference or
/// count, else the reflectance.
#[inline(always)]
fn calibrated(r: f32, d: f32, w: f32, white_reflectance: f32, saturation_counts: f32) -> f32 {
    let span = w - d;
    let value = white_reflectance * (r - d) / span;
    let usable =
        span > 1e-3 && r.is_finite() && d.is_finite() && !clipped(w.max(d), saturation_counts);
    if r >= saturation_counts {
        f32::INFINITY
    } else if usable {
        value
    } else {
        f32::NAN
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calibrates_and_marks_bad_samples() {
        let mut out = [0.0; 4];
        calibrate_row(
            &[1064.0, 4095.0, 64.0, 500.0],
            Some(&[64.0, 64.0, 64.0, 64.0]),
            &[2064.0, 2064.0, 64.0, 2064.0],
            0.99,
            4095.0,
            &mut out,
        );
        assert!((out[0] - 0.495).abs() < 1e-6);
        assert_eq!(out[1], f32::INFINITY);
        assert!(out[2].is_nan());
        assert!((out[3] - 0.99 * 436.0 / 2000.0).abs() < 1e-6);
    }

    /// A white (or dark) reference at the ADC's full scale is clipped: the sample has no
    /// usable reference (NaN), not a reflectance read high against the clipped level; just
    /// below full scale it is a reference like any other.
    #[test]
    fn a_clipped_reference_is_no_reference() {
        let mut out = [0.0; 4];
        calibrate_row(
            &[3000.0, 3000.0, 3000.0, 3000.0],
            Some(&[64.0, 64.0, 4095.0, 64.0]),
            &[4095.0, 4094.5, 4095.0, 5000.0],
            1.0,
            4095.0,
            &mut out,
        );
        assert!(out[0].is_nan());
        assert!((out[1] - 2936.0 / 4030.5).abs() < 1e-6);
        assert!(out[2].is_nan());
        assert!(out[3].is_nan());
    }
}
