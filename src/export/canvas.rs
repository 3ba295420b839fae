//! The drawing surface of the map previews ([`png`](super::png)) and the appearance
//! renders: an RGB8 [`Canvas`] with clipped rectangles, a colour bar and text, PNG encoding
//! through `image`, and the atomic PNG writer.
//!
//! Kept hand-made (charts use `plotters`): these images are only filled rectangles and
//! short labels. The text is the charts' font, DejaVu Sans ([`FONT`]), rasterised by
//! `ab_glyph` at a size set by an integer `scale` (capitals [`CAP_ROWS`] x `scale` pixels
//! high) and blended into the canvas by coverage: every picture filmscope draws speaks in
//! one face, and the previews `estimate` writes stay byte-for-byte reproducible.
//!
//! Coordinates are pixels with the origin at the top-left corner, x to the right and y
//! down. Everything is clipped to the image: no drawing call panics, whatever its
//! arguments. A character the font lacks is drawn as its missing-glyph box.

use std::io;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ab_glyph::{point, Font, FontRef, PxScale, ScaleFont};
use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder};

use super::colormap::{viridis, NO_DATA};
use crate::io::write_atomic;

/// The largest image, in pixels (width x height), that the renderers produce.
pub const MAX_PIXELS: usize = 1 << 26;

/// Why a preview could not be rendered or written. Displays as one line.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PreviewError {
    /// The image has no pixels.
    #[error("image has no pixels ({width}x{height})")]
    Empty {
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
    },
    /// The pixel slice does not hold `width * height` entries.
    #[error("a {width}x{height} image needs {expected} pixels but {actual} were given")]
    SizeMismatch {
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
        /// `width * height`.
        expected: usize,
        /// The length of the slice given.
        actual: usize,
    },
    /// An upscale factor of 0 was given.
    #[error("the upscale factor must be at least 1, got 0")]
    ZeroScale,
    /// The given colour range is not two finite values with `low <= high`.
    #[error("colour range {low}..{high} is invalid (need finite values with low <= high)")]
    InvalidRange {
        /// The given low end.
        low: f64,
        /// The given high end.
        high: f64,
    },
    /// The output image would exceed [`MAX_PIXELS`].
    #[error("a {width}x{height} image upscaled {scale}x exceeds the limit of {limit} pixels")]
    TooLarge {
        /// Source width in pixels.
        width: usize,
        /// Source height in pixels.
        height: usize,
        /// The upscale factor.
        scale: usize,
        /// [`MAX_PIXELS`].
        limit: usize,
    },
    /// A multi-panel figure was asked for with no panels.
    #[error("a figure needs at least one panel, got none")]
    NoPanels,
    /// A heat map's tick labels are neither absent nor one per column (or row).
    #[error("{axis} axis: {expected} tick labels needed (one per cell) but {actual} were given")]
    TickCount {
        /// `"x"` or `"y"`.
        axis: &'static str,
        /// The number of columns (x) or rows (y).
        expected: usize,
        /// The number of labels given.
        actual: usize,
    },
    /// A chart could not be drawn.
    #[error("cannot draw chart: {0}")]
    Draw(String),
    /// The PNG encoder failed.
    #[error("cannot encode PNG: {err}")]
    Encode {
        /// The encoder's error (not a `source`: its text is already in this message).
        err: image::ImageError,
    },
    /// The PNG could not be written to `path`.
    #[error("{}: cannot write PNG: {err}", .path.display())]
    Write {
        /// The file that was being written.
        path: PathBuf,
        /// The underlying error (not a `source`: its text is already in this message).
        err: io::Error,
    },
}

/// Image background.
pub(crate) const BACKGROUND: [u8; 3] = [255, 255, 255];
/// Text colour.
pub(crate) const INK: [u8; 3] = [20, 20, 20];
/// Frame and tick colour.
pub(crate) const FRAME_INK: [u8; 3] = [70, 70, 70];

/// An RGB8 image being drawn; all drawing is clipped to its bounds.
pub(crate) struct Canvas {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

impl Canvas {
    /// A `width x height` canvas filled with `bg` (the caller has checked the size).
    pub(crate) fn new(width: usize, height: usize, bg: [u8; 3]) -> Self {
        let mut data = vec![0u8; width * height * 3];
        for px in data.chunks_exact_mut(3) {
            px.copy_from_slice(&bg);
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// The colour of the pixel at `(x, y)`, `None` outside the canvas.
    pub(crate) fn pixel(&self, x: usize, y: usize) -> Option<[u8; 3]> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let i = (y * self.width + x) * 3;
        Some([self.data[i], self.data[i + 1], self.data[i + 2]])
    }

    /// Copies a row of RGB bytes to `(x, y)`, clipped.
    pub(crate) fn put_row(&mut self, x: usize, y: usize, rgb: &[u8]) {
        if y >= self.height || x >= self.width {
            return;
        }
        let n = rgb.len().min((self.width - x) * 3);
        let start = (y * self.width + x) * 3;
        self.data[start..start + n].copy_from_slice(&rgb[..n]);
    }

    /// Fills a rectangle, clipped.
    pub(crate) fn fill(&mut self, x: usize, y: usize, w: usize, h: usize, colour: [u8; 3]) {
        let x_end = x.saturating_add(w).min(self.width);
        let y_end = y.saturating_add(h).min(self.height);
        for yy in y..y_end {
            for xx in x..x_end {
                let i = (yy * self.width + xx) * 3;
                self.data[i..i + 3].copy_from_slice(&colour);
            }
        }
    }

    /// Draws a one-pixel outline of a rectangle, clipped.
    pub(crate) fn frame(&mut self, x: usize, y: usize, w: usize, h: usize, colour: [u8; 3]) {
        if w == 0 || h == 0 {
            return;
        }
        self.fill(x, y, w, 1, colour);
        self.fill(x, y.saturating_add(h - 1), w, 1, colour);
        self.fill(x, y, 1, h, colour);
        self.fill(x.saturating_add(w - 1), y, 1, h, colour);
    }

    /// Draws `text` with its top-left corner (the top of a capital) at `(x, y)`, capitals
    /// [`CAP_ROWS`] x `scale` pixels high.
    pub(crate) fn text(&mut self, x: usize, y: usize, text: &str, scale: usize, colour: [u8; 3]) {
        let Some((font, per_cap_px)) = font() else {
            return;
        };
        let px = font_px(*per_cap_px, scale);
        let font = font.as_scaled(px);
        let baseline = y as f32 + CAP_ROWS.saturating_mul(scale) as f32;
        let mut pen = x as f32;
        let mut last = None;
        for ch in text.chars() {
            let id = font.glyph_id(ch);
            if let Some(prev) = last {
                pen += font.kern(prev, id);
            }
            let glyph = id.with_scale_and_position(px, point(pen, baseline));
            pen += font.h_advance(id);
            last = Some(id);
            let Some(outline) = font.outline_glyph(glyph) else {
                continue;
            };
            let bounds = outline.px_bounds();
            let visible = bounds.min.x < self.width as f32
                && bounds.min.y < self.height as f32
                && bounds.max.x > 0.0
                && bounds.max.y > 0.0;
            // A glyph larger than any canvas is not rasterised (its buffer would be).
            if !visible || bounds.width() * bounds.height() > MAX_PIXELS as f32 {
                continue;
            }
            outline.draw(|gx, gy, coverage| {
                let gx = f64::from(bounds.min.x) + f64::from(gx);
                let gy = f64::from(bounds.min.y) + f64::from(gy);
                if (0.0..usize::MAX as f64).contains(&gx) && (0.0..usize::MAX as f64).contains(&gy)
                {
                    self.blend(gx as usize, gy as usize, colour, coverage);
                }
            });
        }
    }

    /// Mixes `colour` into the pixel at `(x, y)` by `alpha` in [0, 1] (outside: nothing).
    fn blend(&mut self, x: usize, y: usize, colour: [u8; 3], alpha: f32) {
        let Some(old) = self.pixel(x, y) else {
            return;
        };
        let a = alpha.clamp(0.0, 1.0);
        let mix = |o: u8, c: u8| (f32::from(o) + (f32::from(c) - f32::from(o)) * a).round() as u8;
        let i = (y * self.width + x) * 3;
        self.data[i..i + 3].copy_from_slice(&[
            mix(old[0], colour[0]),
            mix(old[1], colour[1]),
            mix(old[2], colour[2]),
        ]);
    }

    /// Writes `msg` in a framed white box centred in the rectangle `(x, y, w, h)`: at
    /// twice the font size if that fits, else at font size.
    pub(crate) fn message_box(&mut self, x: usize, y: usize, w: usize, h: usize, msg: &str) {
        let scale = if text_width(msg, 2) + 16 <= w { 2 } else { 1 };
        let (tw, th) = (text_width(msg, scale), CAP_ROWS * scale);
        let (bw, bh) = (tw + 12, th + 12);
        let bx = x.saturating_add(w.saturating_sub(bw) / 2);
        let by = y.saturating_add(h.saturating_sub(bh) / 2);
        self.fill(bx, by, bw, bh, BACKGROUND);
        self.frame(bx, by, bw, bh, FRAME_INK);
        self.text(bx + 6, by + 6, msg, scale, INK);
    }

    /// Draws a vertical [`viridis`] colour bar filling `(x, y, w, h)`, high values at the
    /// top, with a one-pixel frame around it; all [`NO_DATA`] grey unless `ranged`.
    pub(crate) fn colour_bar(&mut self, x: usize, y: usize, w: usize, h: usize, ranged: bool) {
        self.frame(
            x.saturating_sub(1),
            y.saturating_sub(1),
            w + 2,
            h + 2,
            FRAME_INK,
        );
        for r in 0..h {
            let colour = if ranged {
                viridis(1.0 - r as f64 / (h - 1).max(1) as f64)
            } else {
                NO_DATA
            };
            self.fill(x, y + r, w, 1, colour);
        }
    }

    /// Encodes the canvas as an RGB8 PNG.
    pub(crate) fn encode(&self) -> Result<Vec<u8>, PreviewError> {
        encode_rgb(self.width, self.height, &self.data)
    }
}

/// Encodes `width x height` row-major RGB8 bytes as a PNG.
pub(crate) fn encode_rgb(width: usize, height: usize, rgb: &[u8]) -> Result<Vec<u8>, PreviewError> {
    let too_large = || PreviewError::TooLarge {
        width,
        height,
        scale: 1,
        limit: MAX_PIXELS,
    };
    let w = u32::try_from(width).map_err(|_| too_large())?;
    let h = u32::try_from(height).map_err(|_| too_large())?;
    let mut out = Vec::new();
    PngEncoder::new(&mut out)
        .write_image(rgb, w, h, ExtendedColorType::Rgb8)
        .map_err(|err| PreviewError::Encode { err })?;
    Ok(out)
}

/// Writes encoded PNG bytes to `path` atomically.
pub(crate) fn write_png(path: &Path, png: &[u8]) -> Result<(), PreviewError> {
    write_atomic(path, png).map_err(|err| PreviewError::Write {
        path: path.to_path_buf(),
        err,
    })
}

/// `text` cut short with "..." so that it is at most `max_w` pixels wide at `scale`.
pub(crate) fn fit_text(text: &str, max_w: usize, scale: usize) -> String {
    if text_width(text, scale) <= max_w {
        return text.to_string();
    }
    let mut s = text.to_string();
    while !s.is_empty() && text_width(&format!("{s}..."), scale) > max_w {
        s.pop();
    }
    s.push_str("...");
    s
}

// ---------------------------------------------------------------------------------------
// The font.

/// DejaVu Sans 2.37 (Bitstream Vera licence, `fonts/DejaVuSans-LICENSE.txt`): the text of
/// every picture, charts included.
pub(crate) const FONT: &[u8] = include_bytes!("fonts/DejaVuSans.ttf");

/// Line height in units of `scale`: capitals and the descenders below them.
pub(crate) const GLYPH_ROWS: usize = 9;
/// Height of capitals and digits in units of `scale`, pixels.
pub(crate) const CAP_ROWS: usize = 7;
/// [`FONT`], parsed once, with its size per pixel of capital height (`ab_glyph` sizes a
/// font by its ascent less its descent; a capital is the height of `H`). `None` only if
/// the embedded file were broken (a build defect the canvas tests catch): text is then
/// left out rather than the process stopped.
fn font() -> Option<&'static (FontRef<'static>, f32)> {
    static PARSED: OnceLock<Option<(FontRef<'static>, f32)>> = OnceLock::new();
    PARSED
        .get_or_init(|| {
            let font = FontRef::try_from_slice(FONT).ok()?;
            let cap = font
                .outline(font.glyph_id('H'))
                .map_or(0.7 * font.height_unscaled(), |o| o.bounds.height().abs());
            let per_cap_px = font.height_unscaled() / cap.max(1.0);
            Some((font, per_cap_px))
        })
        .as_ref()
}

/// The font's size at which capitals are [`CAP_ROWS`] x `scale` pixels high.
fn font_px(per_cap_px: f32, scale: usize) -> PxScale {
    PxScale::from(CAP_ROWS.saturating_mul(scale.max(1)) as f32 * per_cap_px)
}

/// Width in pixels of `text` drawn at `scale`: its advances and kerning.
pub(crate) fn text_width(text: &str, scale: usize) -> usize {
    let Some((font, per_cap_px)) = font() else {
        return 0;
    };
    let font = font.as_scaled(font_px(*per_cap_px, scale));
    let mut width = 0.0;
    let mut last = None;
    for ch in text.chars() {
        let id = font.glyph_id(ch);
        if let Some(prev) = last {
            width += font.kern(prev, id);
        }
        width += font.h_advance(id);
        last = Some(id);
    }
    width.ceil().max(0.0) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The embedded font parses, and text lands where its width and cap height say: ink
    /// inside the box, none beyond its width, the tallest capitals reaching its top.
    #[test]
    fn text_is_drawn_within_its_measured_box() {
        assert!(font().is_some(), "the embedded font does not parse");
        for scale in 1..=3 {
            let text = "E 1.37 nm µ ± °";
            let (w, h) = (text_width(text, scale), CAP_ROWS * scale);
            let mut c = Canvas::new(w + 20, h * 2 + 20, BACKGROUND);
            c.text(10, 10, text, scale, INK);
            let inked = |x: usize, y: usize| c.pixel(x, y) != Some(BACKGROUND);
            let columns: Vec<usize> = (0..c.width)
                .filter(|&x| (0..c.height).any(|y| inked(x, y)))
                .collect();
            let rows: Vec<usize> = (0..c.height)
                .filter(|&y| (0..c.width).any(|x| inked(x, y)))
                .collect();
            let (x0, x1) = (columns[0], columns[columns.len() - 1]);
            let y0 = rows[0];
            assert!(
                x0 >= 9 && x1 <= 10 + w,
                "scale {scale}: ink from {x0} to {x1}, width {w}"
            );
            assert!(
                x1 + 3 * scale >= 10 + w,
                "scale {scale}: ink ends at {x1}, width {w}"
            );
            assert!(
                (9..=11).contains(&y0),
                "scale {scale}: ink starts at row {y0}"
            );
        }
        assert!(
            text_width("\u{1F600}", 1) > 0,
            "a missing glyph still takes room"
        );
    }

    #[test]
    fn drawing_off_the_canvas_is_clipped_without_panicking() {
        let mut c = Canvas::new(10, 8, BACKGROUND);
        c.fill(8, 6, 5, 5, INK);
        assert_eq!(c.pixel(9, 7), Some(INK));
        c.frame(usize::MAX - 1, 2, usize::MAX, 3, INK);
        c.put_row(7, 3, &[0u8; 30]);
        assert_eq!(c.pixel(9, 3), Some([0, 0, 0]));
        c.put_row(10, 3, &[0u8; 3]);
        c.text(8, 6, "clipped text", 3, INK);
        c.text(usize::MAX, usize::MAX, "x", usize::MAX, INK);
        c.fill(usize::MAX, 2, usize::MAX, 3, INK);
        c.message_box(0, 0, 10, 8, "a message far wider than the canvas");
        c.colour_bar(6, 1, 20, 20, true);
        c.colour_bar(0, 0, 1, 1, false);
    }

    #[test]
    fn long_text_is_cut_to_fit() {
        assert_eq!(fit_text("short", 100, 1), "short");
        let cut = fit_text("a rather long title for a small image", 60, 1);
        assert!(cut.ends_with("..."));
        assert!(text_width(&cut, 1) <= 60, "{cut}");
        assert_eq!(text_width("", 2), 0);
        assert!(text_width("ab", 2) > text_width("ab", 1));
    }
}
