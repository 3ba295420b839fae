//! Raw counts to reflectance, one row at a time (capture-format.md):
//! `R = white_reflectance * (raw - dark) / (white - dark)`.
//!
//! Unusable samples are marked in the value itself so the stream needs no side channel:
//! `+inf` for a saturated sample (raw at or above the ADC's full scale) and NaN for a sample
//! without a usable reference (`white - dark` not positive: a dead pixel or a bad white).

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
    for (i, o) in out.iter_mut().enumerate() {
        let r = raw.get(i).copied().unwrap_or(f32::NAN);
        let w = white.get(i).copied().unwrap_or(f32::NAN);
        let d = dark.map_or(0.0, |d| d.get(i).copied().unwrap_or(f32::NAN));
        let span = w - d;
        *o = if r >= saturation_counts {
            f32::INFINITY
        } else if span > 1e-3 && r.is_finite() && d.is_finite() {
            white_reflectance * (r - d) / span
        } else {
            f32::NAN
        };
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
}
