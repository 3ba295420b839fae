//! PNG previews: colour-mapped scalar maps with a legend, and plain colour images.
//!
//! [`render_map_png`] turns a map of `f32` values (a thickness or index map, row-major,
//! NaN where there is no estimate) into an RGB8 PNG held in memory:
//!
//! ```text
//!  Title
//!  +----------------------+    +--+- 421.9 nm
//!  |                      |    |  |
//!  |  map, upscaled by an |    |  |- 404.5 nm      colour bar (viridis) with five
//!  |  integer factor,     |    |  |                tick labels: min, quartiles, max
//!  |  nearest neighbour   |    |  |- 387.1 nm
//!  +----------------------+    +--+
//!                              [ ] grey = no estimate
//! ```
//!
//! - Colours come from [`viridis`]; the range is the one given in [`MapPreview::range`]
//!   or else the 1st..99th percentile of the finite values (values outside the range are
//!   clamped to its ends). Non-finite values (NaN, and also +-inf, which no estimator
//!   produces as a real result) are drawn in the "no data" grey [`NO_DATA`].
//! - The map is upscaled by the smallest integer factor that makes it at least
//!   [`MIN_MAP_WIDTH`] pixels wide, unless that would make it taller than
//!   [`MAX_MAP_HEIGHT`] (then the largest factor that fits, but at least 1).
//! - Text uses a built-in 5x7 pixel font (printable ASCII plus `µ`, `°`, `±`; anything
//!   else is drawn as `?`), so no font files or font crates are involved.
//! - A map without a single finite value still renders: all grey, with "no valid pixels"
//!   written across it.
//!
//! [`render_rgb_png`] encodes a plain colour image (e.g. a render of the film's colour),
//! upscaled by a given factor. The `write_*` variants write the PNG with
//! [`write_atomic`](crate::io::write_atomic), so an interrupted run never leaves a
//! truncated file behind.
//!
//! No function here panics on any input: mismatched sizes, absurd dimensions and invalid
//! ranges are reported as [`PreviewError`]s.

use std::path::Path;

pub use super::canvas::{PreviewError, MAX_PIXELS};

use super::canvas::{
    fit_text, text_width, write_png, Canvas, BACKGROUND, CAP_ROWS, FRAME_INK, GLYPH_ROWS, INK,
};
use super::colormap::{viridis, NO_DATA};

/// The map part of a preview is upscaled to be at least this many pixels wide.
pub const MIN_MAP_WIDTH: usize = 384;

/// Upscaling stops before the map part of a preview gets taller than this many pixels
/// (a map that is already taller is drawn at its own size).
pub const MAX_MAP_HEIGHT: usize = 4096;

/// A scalar map to preview, e.g. a thickness map in nanometres.
#[derive(Clone, Copy, Debug)]
pub struct MapPreview<'a> {
    /// Map width in pixels (samples per line).
    pub width: usize,
    /// Map height in pixels (lines).
    pub height: usize,
    /// `width * height` values, row-major (line by line); NaN where there is no estimate.
    pub values: &'a [f32],
    /// Drawn above the map, e.g. "Thickness, sample 3".
    pub title: &'a str,
    /// Appended to the legend's tick labels, e.g. "nm"; may be empty.
    pub unit: &'a str,
    /// The values mapped to the two ends of the colour bar, `(low, high)`; `None` uses
    /// the 1st and 99th percentile of the finite values.
    pub range: Option<(f64, f64)>,
}

/// Renders `p` as an RGB8 PNG in memory: the colour-mapped map, the title above it and a
/// colour bar with tick labels to its right (see the [module docs](self) for the layout).
///
/// Errors: [`PreviewError::Empty`] for a 0-pixel map, [`PreviewError::SizeMismatch`] if
/// `values` does not hold `width * height` entries, [`PreviewError::InvalidRange`] for a
/// non-finite or reversed `range`, [`PreviewError::TooLarge`] beyond [`MAX_PIXELS`].
pub fn render_map_png(p: &MapPreview) -> Result<Vec<u8>, PreviewError> {
    let (w, h) = (p.width, p.height);
    check_size(w, h, p.values.len())?;
    let range = resolve_range(p.values, p.range)?;
    let any_finite = p.values.iter().any(|v| v.is_finite());

    let mut k = MIN_MAP_WIDTH.div_ceil(w).max(1);
    if h.saturating_mul(k) > MAX_MAP_HEIGHT {
        k = (MAX_MAP_HEIGHT / h).max(1);
    }
    let too_large = PreviewError::TooLarge {
        width: w,
        height: h,
        scale: k,
        limit: MAX_PIXELS,
    };
    let (map_w, map_h) = match (w.checked_mul(k), h.checked_mul(k)) {
        (Some(mw), Some(mh)) if mw.checked_mul(mh).is_some_and(|n| n <= MAX_PIXELS) => (mw, mh),
        _ => return Err(too_large),
    };

    // Legend text, measured before the canvas is sized.
    let ticks: Vec<(f64, String)> = match range {
        Some((lo, hi)) => {
            let decimals = tick_decimals(hi - lo);
            TICK_FRACTIONS
                .iter()
                .map(|&f| {
                    let v = lo + (hi - lo) * f;
                    (f, with_unit(&format_value(v, decimals), p.unit))
                })
                .collect()
        }
        None => Vec::new(),
    };
    let label_w = ticks
        .iter()
        .map(|(_, s)| text_width(s, LABEL_SCALE))
        .max()
        .unwrap_or(0);

    // Layout, top to bottom and left to right.
    let title_h = GLYPH_ROWS * TITLE_SCALE;
    let map_x = MARGIN + FRAME;
    let map_y = MARGIN + title_h + GAP + FRAME;
    let half_label = CAP_ROWS * LABEL_SCALE / 2;
    let bar_x = map_x + map_w + FRAME + LEGEND_GAP;
    let bar_y = map_y + half_label;
    let bar_h = map_h.saturating_sub(2 * half_label).max(MIN_BAR_HEIGHT);
    let label_x = bar_x + BAR_WIDTH + FRAME + TICK_LEN + TICK_GAP;
    let note_y = bar_y + bar_h + FRAME + half_label + GAP;
    let note_w = NOTE_SWATCH * NOTE_SCALE + 6 + text_width(NOTE, NOTE_SCALE);
    let legend_right = (label_x + label_w).max(bar_x + note_w);
    let img_w = legend_right + MARGIN;
    let img_h = (map_y + map_h + FRAME).max(note_y + GLYPH_ROWS * NOTE_SCALE) + MARGIN;
    if img_w.checked_mul(img_h).is_none_or(|n| n > MAX_PIXELS) {
        return Err(too_large);
    }
    let mut c = Canvas::new(img_w, img_h, BACKGROUND);

    // Title: full size if it fits, else small, else cut short.
    let avail = img_w - 2 * MARGIN;
    if text_width(p.title, TITLE_SCALE) <= avail {
        c.text(MARGIN, MARGIN, p.title, TITLE_SCALE, INK);
    } else {
        let small = fit_text(p.title, avail, 1);
        c.text(MARGIN, MARGIN + title_h - GLYPH_ROWS, &small, 1, INK);
    }

    // The map, with a frame.
    c.frame(
        map_x - FRAME,
        map_y - FRAME,
        map_w + 2 * FRAME,
        map_h + 2 * FRAME,
        FRAME_INK,
    );
    let mut row = vec![0u8; map_w * 3];
    for (y, line) in p.values.chunks_exact(w).enumerate() {
        for (x, &v) in line.iter().enumerate() {
            let colour = match range {
                Some((lo, hi)) if v.is_finite() => viridis((f64::from(v) - lo) / (hi - lo)),
                _ => NO_DATA,
            };
            for px in row[x * k * 3..(x + 1) * k * 3].chunks_exact_mut(3) {
                px.copy_from_slice(&colour);
            }
        }
        for dy in 0..k {
            c.put_row(map_x, map_y + y * k + dy, &row);
        }
    }
    if !any_finite {
        c.message_box(map_x, map_y, map_w, map_h, "no valid pixels");
    }

    // Colour bar: high values at the top.
    c.colour_bar(bar_x, bar_y, BAR_WIDTH, bar_h, range.is_some());
    for (f, label) in &ticks {
        let y = bar_y + ((1.0 - f) * (bar_h - 1) as f64).round() as usize;
        c.fill(bar_x + BAR_WIDTH + FRAME, y, TICK_LEN, 1, FRAME_INK);
        c.text(
            label_x,
            y.saturating_sub(half_label),
            label,
            LABEL_SCALE,
            INK,
        );
    }

    // "grey = no estimate", with a grey swatch.
    let sw = NOTE_SWATCH * NOTE_SCALE;
    c.fill(bar_x, note_y, sw, sw, NO_DATA);
    c.frame(bar_x, note_y, sw, sw, FRAME_INK);
    let text_y = note_y + sw.saturating_sub(CAP_ROWS * NOTE_SCALE) / 2;
    c.text(bar_x + sw + 6, text_y, NOTE, NOTE_SCALE, INK);

    c.encode()
}

/// Renders `p` like [`render_map_png`] and writes it to `path` atomically (temporary
/// file + rename, see [`write_atomic`](crate::io::write_atomic)).
///
/// Errors: those of [`render_map_png`], and [`PreviewError::Write`] (naming `path`) if
/// the file cannot be written.
pub fn write_map_png(path: &Path, p: &MapPreview) -> Result<(), PreviewError> {
    let png = render_map_png(p)?;
    write_png(path, &png)
}

/// Encodes a plain `width x height` colour image (row-major `rgb`, e.g. a render of the
/// film's colour) as an RGB8 PNG in memory, each pixel enlarged to a `scale x scale`
/// block (nearest neighbour). No legend or text is added.
///
/// Errors: [`PreviewError::Empty`], [`PreviewError::SizeMismatch`],
/// [`PreviewError::ZeroScale`], [`PreviewError::TooLarge`] beyond [`MAX_PIXELS`].
pub fn render_rgb_png(
    width: usize,
    height: usize,
    rgb: &[[u8; 3]],
    scale: usize,
) -> Result<Vec<u8>, PreviewError> {
    check_size(width, height, rgb.len())?;
    if scale == 0 {
        return Err(PreviewError::ZeroScale);
    }
    let (out_w, out_h) = match (width.checked_mul(scale), height.checked_mul(scale)) {
        (Some(ow), Some(oh)) if ow.checked_mul(oh).is_some_and(|n| n <= MAX_PIXELS) => (ow, oh),
        _ => {
            return Err(PreviewError::TooLarge {
                width,
                height,
                scale,
                limit: MAX_PIXELS,
            })
        }
    };
    let mut c = Canvas::new(out_w, out_h, BACKGROUND);
    let mut row = vec![0u8; out_w * 3];
    for (y, line) in rgb.chunks_exact(width).enumerate() {
        for (block, colour) in row.chunks_exact_mut(scale * 3).zip(line) {
            for px in block.chunks_exact_mut(3) {
                px.copy_from_slice(colour);
            }
        }
        for dy in 0..scale {
            c.put_row(0, y * scale + dy, &row);
        }
    }
    c.encode()
}

/// Renders like [`render_rgb_png`] and writes the PNG to `path` atomically (temporary
/// file + rename, see [`write_atomic`](crate::io::write_atomic)).
///
/// Errors: those of [`render_rgb_png`], and [`PreviewError::Write`] (naming `path`) if
/// the file cannot be written.
pub fn write_rgb_png(
    path: &Path,
    width: usize,
    height: usize,
    rgb: &[[u8; 3]],
    scale: usize,
) -> Result<(), PreviewError> {
    let png = render_rgb_png(width, height, rgb, scale)?;
    write_png(path, &png)
}

// ---------------------------------------------------------------------------------------
// Layout and colours.

/// Space around the whole image.
const MARGIN: usize = 12;
/// Vertical space between the title and the map, and above the legend note.
const GAP: usize = 10;
/// Thickness of the frames around the map, the colour bar and the swatch.
const FRAME: usize = 1;
/// Space between the map and the colour bar.
const LEGEND_GAP: usize = 24;
/// Width of the colour bar.
const BAR_WIDTH: usize = 24;
/// The colour bar is at least this tall, even beside a flat map.
const MIN_BAR_HEIGHT: usize = 160;
/// Length of the tick marks right of the colour bar.
const TICK_LEN: usize = 5;
/// Space between a tick mark and its label (wide, so a tick never reads as a minus).
const TICK_GAP: usize = 9;
/// Where the tick labels sit along the bar (0 = low end, 1 = high end).
const TICK_FRACTIONS: [f64; 5] = [0.0, 0.25, 0.5, 0.75, 1.0];
/// Font scale of the title.
const TITLE_SCALE: usize = 2;
/// Font scale of the tick labels.
const LABEL_SCALE: usize = 2;
/// Font scale of the note under the bar.
const NOTE_SCALE: usize = 1;
/// Side of the grey swatch before the note, in font pixels.
const NOTE_SWATCH: usize = 9;
/// The note under the colour bar.
const NOTE: &str = "grey = no estimate";

/// Checks that a `width x height` image has pixels and that `len` matches.
pub(super) fn check_size(width: usize, height: usize, len: usize) -> Result<(), PreviewError> {
    if width == 0 || height == 0 {
        return Err(PreviewError::Empty { width, height });
    }
    let expected = width.checked_mul(height).ok_or(PreviewError::TooLarge {
        width,
        height,
        scale: 1,
        limit: MAX_PIXELS,
    })?;
    if len != expected {
        return Err(PreviewError::SizeMismatch {
            width,
            height,
            expected,
            actual: len,
        });
    }
    Ok(())
}

/// The colour range: `given` (validated) or the 1st..99th percentile of the finite
/// values; `None` when nothing is given and no value is finite. An empty range
/// (low == high, e.g. a flat map) is widened by 1% of the value (or by 1 around 0) so
/// that the map shows the middle colour and the ticks stay distinct.
fn resolve_range(
    values: &[f32],
    given: Option<(f64, f64)>,
) -> Result<Option<(f64, f64)>, PreviewError> {
    let (lo, hi) = match given {
        Some((low, high)) => {
            if !(low.is_finite() && high.is_finite() && low <= high && (high - low).is_finite()) {
                return Err(PreviewError::InvalidRange { low, high });
            }
            (low, high)
        }
        None => {
            let mut finite: Vec<f64> = values
                .iter()
                .filter(|v| v.is_finite())
                .map(|&v| f64::from(v))
                .collect();
            if finite.is_empty() {
                return Ok(None);
            }
            finite.sort_unstable_by(f64::total_cmp);
            (percentile(&finite, 0.01), percentile(&finite, 0.99))
        }
    };
    if hi > lo {
        return Ok(Some((lo, hi)));
    }
    let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.01 };
    Ok(Some((lo - d, hi + d)))
}

/// The `q` quantile (0..=1) of sorted, non-empty `v`, interpolating linearly.
fn percentile(v: &[f64], q: f64) -> f64 {
    let pos = q * (v.len() - 1) as f64;
    let i = (pos.floor() as usize).min(v.len() - 1);
    let j = (i + 1).min(v.len() - 1);
    let frac = pos - i as f64;
    v[i] + (v[j] - v[i]) * frac
}

/// Decimals for tick labels over a span: enough to resolve 0.5% of it, at most 6.
pub(super) fn tick_decimals(span: f64) -> usize {
    let d = (-(span / 200.0).log10()).ceil();
    if d.is_finite() {
        d.clamp(0.0, 6.0) as usize
    } else {
        2
    }
}

/// Formats a tick value: fixed point with `decimals`, or scientific for magnitudes at
/// or above 1e6 and below 1e-3; never "-0".
pub(super) fn format_value(v: f64, decimals: usize) -> String {
    let a = v.abs();
    let s = if a != 0.0 && !(1e-3..1e6).contains(&a) {
        format!("{v:.2e}")
    } else {
        format!("{v:.decimals$}")
    };
    match s.strip_prefix('-') {
        Some(rest) if rest.chars().all(|ch| ch == '0' || ch == '.') => rest.to_string(),
        _ => s,
    }
}

/// `"412.5"` + `"nm"` -> `"412.5 nm"`; no unit -> the number alone.
fn with_unit(number: &str, unit: &str) -> String {
    let unit = unit.trim();
    if unit.is_empty() {
        number.to_string()
    } else {
        format!("{number} {unit}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_values_are_formatted_to_the_span() {
        assert_eq!(format_value(412.5, tick_decimals(34.6)), "412.5");
        assert_eq!(format_value(400.0, tick_decimals(300.0)), "400");
        assert_eq!(format_value(1.4567, tick_decimals(0.1)), "1.4567");
        assert_eq!(format_value(-0.00001, 2), "-1.00e-5");
        assert_eq!(format_value(-0.001, 2), "0.00");
        assert_eq!(format_value(2.5e7, 0), "2.50e7");
        assert_eq!(with_unit("3.0", " nm "), "3.0 nm");
        assert_eq!(with_unit("3.0", ""), "3.0");
    }

    #[test]
    fn percentiles_interpolate() {
        let v: Vec<f64> = (0..=100).map(f64::from).collect();
        assert_eq!(percentile(&v, 0.01), 1.0);
        assert_eq!(percentile(&v, 0.99), 99.0);
        assert_eq!(percentile(&[5.0], 0.99), 5.0);
    }

    #[test]
    fn flat_and_given_ranges() {
        assert_eq!(resolve_range(&[f32::NAN; 4], None).ok(), Some(None));
        let flat = resolve_range(&[200.0; 4], None).ok().flatten();
        assert_eq!(flat, Some((198.0, 202.0)));
        assert!(resolve_range(&[1.0], Some((2.0, 1.0))).is_err());
        assert!(resolve_range(&[1.0], Some((f64::NAN, 1.0))).is_err());
        assert!(resolve_range(&[1.0], Some((-f64::MAX, f64::MAX))).is_err());
    }
}
