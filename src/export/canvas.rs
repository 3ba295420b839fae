//! The drawing surface of the map previews ([`png`](super::png)) and the appearance
//! renders: an RGB8 [`Canvas`] with clipped rectangles, a colour bar and text in a built-in
//! 5x7 pixel font, PNG encoding through `image`, and the atomic PNG writer.
//!
//! Kept hand-made (charts use `plotters`): these images are only filled rectangles and
//! short labels, which a pixel font draws crisply at integer scales with no font file,
//! and the map previews that `estimate` writes stay byte-for-byte reproducible.
//!
//! Coordinates are pixels with the origin at the top-left corner, x to the right and y
//! down. Everything is clipped to the image: no drawing call panics, whatever its
//! arguments. The font covers printable ASCII plus `µ`, `°` and `±`; anything else is
//! drawn as `?`.

use std::io;
use std::path::{Path, PathBuf};

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
    #[cfg(test)]
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

    /// Draws `text` with its top-left corner (the top of a capital) at `(x, y)`, each
    /// font pixel a `scale x scale` block.
    pub(crate) fn text(&mut self, x: usize, y: usize, text: &str, scale: usize, colour: [u8; 3]) {
        for (n, ch) in text.chars().enumerate() {
            let gx = x.saturating_add(n.saturating_mul(ADVANCE.saturating_mul(scale)));
            for (r, bits) in glyph(ch).iter().enumerate() {
                for col in 0..GLYPH_COLS {
                    if bits & (1 << (GLYPH_COLS - 1 - col)) != 0 {
                        self.fill(
                            gx.saturating_add(col.saturating_mul(scale)),
                            y.saturating_add(r.saturating_mul(scale)),
                            scale,
                            scale,
                            colour,
                        );
                    }
                }
            }
        }
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
    let max_chars = (max_w / (ADVANCE * scale).max(1)).saturating_sub(3);
    let mut s: String = text.chars().take(max_chars).collect();
    s.push_str("...");
    s
}

// ---------------------------------------------------------------------------------------
// The built-in font: 5x7 pixel glyphs in a 5x9 cell (two rows below the baseline for
// descenders), drawn for filmscope. Each row is a byte whose low 5 bits are the pixels,
// bit 4 leftmost.

/// Glyph width in font pixels.
const GLYPH_COLS: usize = 5;
/// Glyph cell height in font pixels, including the descender rows.
pub(crate) const GLYPH_ROWS: usize = 9;
/// Height of capitals and digits in font pixels.
pub(crate) const CAP_ROWS: usize = 7;
/// Horizontal distance between characters in font pixels.
pub(crate) const ADVANCE: usize = 6;

/// Width in pixels of `text` drawn at `scale` (no trailing space).
pub(crate) fn text_width(text: &str, scale: usize) -> usize {
    let n = text.chars().count();
    n.saturating_mul(ADVANCE)
        .saturating_sub(1)
        .saturating_mul(scale)
}

/// The glyph of `ch`; characters without one are drawn as `?`.
fn glyph(ch: char) -> &'static [u8; GLYPH_ROWS] {
    const QUESTION: usize = b'?' as usize - 0x20;
    match ch {
        ' '..='~' => &ASCII[ch as usize - 0x20],
        '\u{b0}' => &DEGREE,
        '\u{b5}' => &MICRO,
        '\u{b1}' => &PLUS_MINUS,
        _ => &ASCII[QUESTION],
    }
}

/// `°`.
const DEGREE: [u8; GLYPH_ROWS] = [0x0C, 0x12, 0x12, 0x0C, 0x00, 0x00, 0x00, 0x00, 0x00];
/// `µ` (micro sign).
const MICRO: [u8; GLYPH_ROWS] = [0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x1D, 0x10, 0x10];
/// `±`.
const PLUS_MINUS: [u8; GLYPH_ROWS] = [0x04, 0x04, 0x1F, 0x04, 0x04, 0x00, 0x1F, 0x00, 0x00];

/// Glyphs for ASCII 0x20..=0x7E, in order.
const ASCII: [[u8; GLYPH_ROWS]; 95] = [
    [0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00], // ' '
    [0x04, 0x04, 0x04, 0x04, 0x04, 0x00, 0x04, 0x00, 0x00], // '!'
    [0x0A, 0x0A, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00], // '"'
    [0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A, 0x00, 0x00], // '#'
    [0x04, 0x0F, 0x14, 0x0E, 0x05, 0x1E, 0x04, 0x00, 0x00], // '$'
    [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03, 0x00, 0x00], // '%'
    [0x0C, 0x12, 0x14, 0x08, 0x15, 0x12, 0x0D, 0x00, 0x00], // '&'
    [0x04, 0x04, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00], // '\''
    [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02, 0x00, 0x00], // '('
    [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08, 0x00, 0x00], // ')'
    [0x00, 0x04, 0x15, 0x0E, 0x15, 0x04, 0x00, 0x00, 0x00], // '*'
    [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00, 0x00, 0x00], // '+'
    [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08, 0x00], // ','
    [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00, 0x00, 0x00], // '-'
    [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C, 0x00, 0x00], // '.'
    [0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00, 0x00, 0x00], // '/'
    [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E, 0x00, 0x00], // '0'
    [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E, 0x00, 0x00], // '1'
    [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F, 0x00, 0x00], // '2'
    [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E, 0x00, 0x00], // '3'
    [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02, 0x00, 0x00], // '4'
    [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E, 0x00, 0x00], // '5'
    [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E, 0x00, 0x00], // '6'
    [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08, 0x00, 0x00], // '7'
    [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E, 0x00, 0x00], // '8'
    [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C, 0x00, 0x00], // '9'
    [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00, 0x00, 0x00], // ':'
    [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x04, 0x08, 0x00, 0x00], // ';'
    [0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02, 0x00, 0x00], // '<'
    [0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00, 0x00, 0x00], // '='
    [0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08, 0x00, 0x00], // '>'
    [0x0E, 0x11, 0x01, 0x02, 0x04, 0x00, 0x04, 0x00, 0x00], // '?'
    [0x0E, 0x11, 0x01, 0x0D, 0x15, 0x15, 0x0E, 0x00, 0x00], // '@'
    [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11, 0x00, 0x00], // 'A'
    [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E, 0x00, 0x00], // 'B'
    [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E, 0x00, 0x00], // 'C'
    [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C, 0x00, 0x00], // 'D'
    [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F, 0x00, 0x00], // 'E'
    [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10, 0x00, 0x00], // 'F'
    [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F, 0x00, 0x00], // 'G'
    [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11, 0x00, 0x00], // 'H'
    [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E, 0x00, 0x00], // 'I'
    [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C, 0x00, 0x00], // 'J'
    [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11, 0x00, 0x00], // 'K'
    [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F, 0x00, 0x00], // 'L'
    [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11, 0x00, 0x00], // 'M'
    [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11, 0x00, 0x00], // 'N'
    [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E, 0x00, 0x00], // 'O'
    [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10, 0x00, 0x00], // 'P'
    [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D, 0x00, 0x00], // 'Q'
    [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11, 0x00, 0x00], // 'R'
    [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E, 0x00, 0x00], // 'S'
    [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x00, 0x00], // 'T'
    [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E, 0x00, 0x00], // 'U'
    [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04, 0x00, 0x00], // 'V'
    [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A, 0x00, 0x00], // 'W'
    [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11, 0x00, 0x00], // 'X'
    [0x11, 0x11, 0x0A, 0x04, 0x04, 0x04, 0x04, 0x00, 0x00], // 'Y'
    [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F, 0x00, 0x00], // 'Z'
    [0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E, 0x00, 0x00], // '['
    [0x00, 0x10, 0x08, 0x04, 0x02, 0x01, 0x00, 0x00, 0x00], // '\\'
    [0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E, 0x00, 0x00], // ']'
    [0x04, 0x0A, 0x11, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00], // '^'
    [0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F, 0x00], // '_'
    [0x08, 0x04, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00], // '`'
    [0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F, 0x00, 0x00], // 'a'
    [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E, 0x00, 0x00], // 'b'
    [0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E, 0x00, 0x00], // 'c'
    [0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F, 0x00, 0x00], // 'd'
    [0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E, 0x00, 0x00], // 'e'
    [0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08, 0x00, 0x00], // 'f'
    [0x00, 0x00, 0x0F, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x0E], // 'g'
    [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11, 0x00, 0x00], // 'h'
    [0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E, 0x00, 0x00], // 'i'
    [0x02, 0x00, 0x06, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C], // 'j'
    [0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12, 0x00, 0x00], // 'k'
    [0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E, 0x00, 0x00], // 'l'
    [0x00, 0x00, 0x1A, 0x15, 0x15, 0x15, 0x15, 0x00, 0x00], // 'm'
    [0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11, 0x00, 0x00], // 'n'
    [0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E, 0x00, 0x00], // 'o'
    [0x00, 0x00, 0x1E, 0x11, 0x11, 0x11, 0x1E, 0x10, 0x10], // 'p'
    [0x00, 0x00, 0x0F, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x01], // 'q'
    [0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10, 0x00, 0x00], // 'r'
    [0x00, 0x00, 0x0F, 0x10, 0x0E, 0x01, 0x1E, 0x00, 0x00], // 's'
    [0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06, 0x00, 0x00], // 't'
    [0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x0D, 0x00, 0x00], // 'u'
    [0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04, 0x00, 0x00], // 'v'
    [0x00, 0x00, 0x11, 0x11, 0x15, 0x15, 0x0A, 0x00, 0x00], // 'w'
    [0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x00, 0x00], // 'x'
    [0x00, 0x00, 0x11, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x0E], // 'y'
    [0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F, 0x00, 0x00], // 'z'
    [0x02, 0x04, 0x04, 0x08, 0x04, 0x04, 0x02, 0x00, 0x00], // '{'
    [0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x00, 0x00], // '|'
    [0x08, 0x04, 0x04, 0x02, 0x04, 0x04, 0x08, 0x00, 0x00], // '}'
    [0x00, 0x00, 0x08, 0x15, 0x02, 0x00, 0x00, 0x00, 0x00], // '~'
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_printable_character_has_a_distinct_glyph() {
        let mut seen = std::collections::HashSet::new();
        for ch in '!'..='~' {
            assert!(seen.insert(*glyph(ch)), "{ch:?} duplicates another glyph");
        }
        assert_eq!(glyph('\u{1F600}'), glyph('?'));
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
        assert_eq!(text_width("ab", 2), 22);
    }
}
