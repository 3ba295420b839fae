//! The drawing surface shared by the PNG renderers ([`png`](super::png) and
//! [`plot`](super::plot)): an RGB8 [`Canvas`] with clipped rectangles, lines, markers and
//! text in a built-in 5x7 pixel font, its PNG encoding, and the atomic PNG writer.
//!
//! Coordinates are pixels with the origin at the top-left corner, x to the right and y
//! down. Rectangles and text take `usize` corners; lines and markers take `f64` centres
//! (rounded to the nearest pixel) so that data coordinates can be passed straight in, even
//! when they fall outside the image. Everything is clipped to the image: no drawing call
//! panics, whatever its arguments.
//!
//! The font covers printable ASCII plus `µ`, `°` and `±`; anything else is drawn as `?`.

use std::path::Path;

use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder};

use super::colormap::{viridis, NO_DATA};
use super::png::{PreviewError, MAX_PIXELS};
use crate::io::write_atomic;

/// Image background.
pub(crate) const BACKGROUND: [u8; 3] = [255, 255, 255];
/// Text colour.
pub(crate) const INK: [u8; 3] = [20, 20, 20];
/// Frame and tick colour.
pub(crate) const FRAME_INK: [u8; 3] = [70, 70, 70];

/// The shape of a data-point marker.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Marker {
    /// A disc.
    Circle,
    /// An axis-aligned square.
    Square,
    /// A square standing on a corner.
    Diamond,
    /// A triangle pointing up.
    TriangleUp,
    /// A triangle pointing down.
    TriangleDown,
}

impl Marker {
    /// Whether the pixel at offset `(dx, dy)` from the centre belongs to the marker of
    /// "radius" `r` (half the marker's width).
    fn contains(self, dx: i64, dy: i64, r: i64) -> bool {
        if r < 0 {
            return false;
        }
        let (ax, ay) = (dx.abs(), dy.abs());
        match self {
            Self::Circle => dx * dx + dy * dy <= r * r + r,
            Self::Square => ax <= r && ay <= r,
            Self::Diamond => ax + ay <= r + r / 2,
            Self::TriangleUp => ay <= r && 2 * ax <= dy + r + 1,
            Self::TriangleDown => ay <= r && 2 * ax <= r - dy + 1,
        }
    }
}

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

    /// Sets the pixel at `(x, y)`, if it is on the canvas.
    fn set(&mut self, x: i64, y: i64, colour: [u8; 3]) {
        let (Ok(x), Ok(y)) = (usize::try_from(x), usize::try_from(y)) else {
            return;
        };
        if x < self.width && y < self.height {
            let i = (y * self.width + x) * 3;
            self.data[i..i + 3].copy_from_slice(&colour);
        }
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
        self.fill(x, y + h - 1, w, 1, colour);
        self.fill(x, y, 1, h, colour);
        self.fill(x + w - 1, y, 1, h, colour);
    }

    /// Draws a one-pixel line from `(x0, y0)` to `(x1, y1)` (pixel centres, rounded),
    /// in any direction, clipped. A line with a non-finite end is not drawn.
    pub(crate) fn line(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, colour: [u8; 3]) {
        self.thick_line(x0, y0, x1, y1, 1, colour);
    }

    /// Draws a line like [`line`](Self::line), but `width` pixels thick (a square pen;
    /// 0 draws nothing).
    pub(crate) fn thick_line(
        &mut self,
        x0: f64,
        y0: f64,
        x1: f64,
        y1: f64,
        width: usize,
        colour: [u8; 3],
    ) {
        if width == 0 {
            return;
        }
        // Clip to the canvas, widened by the pen, so that the walk below stays short.
        let pad = width as f64;
        let bounds = (
            -pad,
            self.width as f64 + pad,
            -pad,
            self.height as f64 + pad,
        );
        let Some((x0, y0, x1, y1)) = clip_segment(x0, y0, x1, y1, bounds) else {
            return;
        };
        // In range after the clip, so the casts are exact.
        let (mut x, mut y) = (x0.round() as i64, y0.round() as i64);
        let (xe, ye) = (x1.round() as i64, y1.round() as i64);
        let w = i64::try_from(width).unwrap_or(i64::MAX);
        let off = (w - 1) / 2;
        // Bresenham over all octants.
        let (dx, dy) = ((xe - x).abs(), -(ye - y).abs());
        let (sx, sy) = (if x < xe { 1 } else { -1 }, if y < ye { 1 } else { -1 });
        let mut err = dx + dy;
        loop {
            for py in 0..w {
                for px in 0..w {
                    self.set(x - off + px, y - off + py, colour);
                }
            }
            if x == xe && y == ye {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// Draws a marker of `shape` centred on `(cx, cy)` (rounded), `2 * radius + 1` pixels
    /// across: filled with `fill` (if any) and outlined one pixel wide in `outline`.
    pub(crate) fn marker(
        &mut self,
        cx: f64,
        cy: f64,
        shape: Marker,
        radius: usize,
        fill: Option<[u8; 3]>,
        outline: [u8; 3],
    ) {
        let Some((cx, cy)) = self.centre(cx, cy) else {
            return;
        };
        let r = i64::try_from(radius.min(1024)).unwrap_or(0);
        for dy in -r - 1..=r + 1 {
            for dx in -r - 1..=r + 1 {
                if !shape.contains(dx, dy, r) {
                    continue;
                }
                let edge = [(1, 0), (-1, 0), (0, 1), (0, -1)]
                    .iter()
                    .any(|&(ex, ey)| !shape.contains(dx + ex, dy + ey, r));
                match (edge, fill) {
                    (true, _) => self.set(cx + dx, cy + dy, outline),
                    (false, Some(f)) => self.set(cx + dx, cy + dy, f),
                    (false, None) => {}
                }
            }
        }
    }

    /// Draws a circle `thickness` pixels wide, its outer edge `radius` pixels from
    /// `(cx, cy)` (rounded), with the inside left as it is.
    pub(crate) fn ring(
        &mut self,
        cx: f64,
        cy: f64,
        radius: usize,
        thickness: usize,
        colour: [u8; 3],
    ) {
        let Some((cx, cy)) = self.centre(cx, cy) else {
            return;
        };
        let r = i64::try_from(radius.min(1024)).unwrap_or(0);
        let inner = r - i64::try_from(thickness.min(1024)).unwrap_or(0);
        for dy in -r..=r {
            for dx in -r..=r {
                let on =
                    Marker::Circle.contains(dx, dy, r) && !Marker::Circle.contains(dx, dy, inner);
                if on {
                    self.set(cx + dx, cy + dy, colour);
                }
            }
        }
    }

    /// `(x, y)` rounded to a pixel, if it is finite and not absurdly far off the canvas
    /// (so that offsets from it cannot overflow).
    fn centre(&self, x: f64, y: f64) -> Option<(i64, i64)> {
        let far = 1e9;
        if !(x.abs() < far && y.abs() < far) {
            return None;
        }
        Some((x.round() as i64, y.round() as i64))
    }

    /// Draws `text` with its top-left corner (the top of a capital) at `(x, y)`, each
    /// font pixel a `scale x scale` block.
    pub(crate) fn text(&mut self, x: usize, y: usize, text: &str, scale: usize, colour: [u8; 3]) {
        for (n, ch) in text.chars().enumerate() {
            let gx = x.saturating_add(n.saturating_mul(ADVANCE * scale));
            for (r, bits) in glyph(ch).iter().enumerate() {
                for col in 0..GLYPH_COLS {
                    if bits & (1 << (GLYPH_COLS - 1 - col)) != 0 {
                        self.fill(
                            gx.saturating_add(col * scale),
                            y.saturating_add(r * scale),
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
        let too_large = || PreviewError::TooLarge {
            width: self.width,
            height: self.height,
            scale: 1,
            limit: MAX_PIXELS,
        };
        let w = u32::try_from(self.width).map_err(|_| too_large())?;
        let h = u32::try_from(self.height).map_err(|_| too_large())?;
        let mut out = Vec::new();
        PngEncoder::new(&mut out)
            .write_image(&self.data, w, h, ExtendedColorType::Rgb8)
            .map_err(|err| PreviewError::Encode { err })?;
        Ok(out)
    }
}

/// The part of the segment `(x0, y0)-(x1, y1)` inside `(xmin, xmax, ymin, ymax)`
/// (Cohen-Sutherland: a clipped end lies exactly on the boundary it was clipped to), or
/// `None` if there is none or an end is not finite.
fn clip_segment(
    x0: f64,
    y0: f64,
    x1: f64,
    y1: f64,
    (xmin, xmax, ymin, ymax): (f64, f64, f64, f64),
) -> Option<(f64, f64, f64, f64)> {
    const LEFT: u8 = 1;
    const RIGHT: u8 = 2;
    const BELOW: u8 = 4;
    const ABOVE: u8 = 8;
    if ![x0, y0, x1, y1].iter().all(|v| v.is_finite()) {
        return None;
    }
    let code = |x: f64, y: f64| {
        let mut c = 0;
        if x < xmin {
            c |= LEFT;
        } else if x > xmax {
            c |= RIGHT;
        }
        if y < ymin {
            c |= BELOW;
        } else if y > ymax {
            c |= ABOVE;
        }
        c
    };
    // `a + (b - a) * f` for `f` in 0..=1 without overflow, even for ends near +-f64::MAX.
    let lerp = |a: f64, b: f64, f: f64| {
        let half = (b * 0.5 - a * 0.5) * f;
        a + half + half
    };
    let (mut a, mut b) = ((x0, y0), (x1, y1));
    // Each pass moves one end onto a boundary; four per end at most, more only through
    // rounding, which then cannot matter.
    for _ in 0..8 {
        let (ca, cb) = (code(a.0, a.1), code(b.0, b.1));
        if ca | cb == 0 {
            return Some((
                a.0.clamp(xmin, xmax),
                a.1.clamp(ymin, ymax),
                b.0.clamp(xmin, xmax),
                b.1.clamp(ymin, ymax),
            ));
        }
        if ca & cb != 0 {
            return None;
        }
        let (out, other, c) = if ca != 0 { (a, b, ca) } else { (b, a, cb) };
        let frac = |from: f64, to: f64, bound: f64| {
            ((bound * 0.5 - from * 0.5) / (to * 0.5 - from * 0.5)).clamp(0.0, 1.0)
        };
        let moved = if c & LEFT != 0 {
            (xmin, lerp(out.1, other.1, frac(out.0, other.0, xmin)))
        } else if c & RIGHT != 0 {
            (xmax, lerp(out.1, other.1, frac(out.0, other.0, xmax)))
        } else if c & BELOW != 0 {
            (lerp(out.0, other.0, frac(out.1, other.1, ymin)), ymin)
        } else {
            (lerp(out.0, other.0, frac(out.1, other.1, ymax)), ymax)
        };
        if ca != 0 {
            a = moved;
        } else {
            b = moved;
        }
    }
    None
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
    fn lines_reach_both_ends_in_every_direction() {
        const RED: [u8; 3] = [255, 0, 0];
        for (x0, y0, x1, y1) in [
            (2usize, 3usize, 17usize, 9usize),
            (17, 9, 2, 3),
            (5, 18, 6, 1),
            (10, 10, 10, 10),
        ] {
            let mut c = Canvas::new(20, 20, BACKGROUND);
            c.line(x0 as f64, y0 as f64, x1 as f64, y1 as f64, RED);
            assert_eq!(c.pixel(x0, y0), Some(RED));
            assert_eq!(c.pixel(x1, y1), Some(RED));
            // One pixel per step along the major axis: no gaps, no doubling.
            let n = c.data.chunks_exact(3).filter(|p| *p == RED).count();
            assert_eq!(n, x0.abs_diff(x1).max(y0.abs_diff(y1)) + 1);
        }
    }

    #[test]
    fn drawing_off_the_canvas_is_clipped_without_panicking() {
        let mut c = Canvas::new(10, 8, BACKGROUND);
        c.line(-1e300, -5.0, 1e300, 5.0, INK);
        c.line(-1e300, 4.0, 1e300, 4.0, FRAME_INK);
        assert_eq!(c.pixel(0, 4), Some(FRAME_INK));
        assert_eq!(c.pixel(9, 4), Some(FRAME_INK));
        c.line(f64::NAN, 0.0, 3.0, 3.0, INK);
        c.line(f64::INFINITY, 0.0, 3.0, 3.0, INK);
        c.thick_line(-50.0, -50.0, 50.0, 50.0, 3, INK);
        c.line(-20.0, -20.0, -5.0, -1.0, INK);
        for shape in [
            Marker::Circle,
            Marker::Square,
            Marker::Diamond,
            Marker::TriangleUp,
            Marker::TriangleDown,
        ] {
            c.marker(-1.0, 9.0, shape, 4, Some(INK), FRAME_INK);
            c.marker(f64::NAN, 1.0, shape, 4, None, FRAME_INK);
            c.marker(1e300, -1e300, shape, usize::MAX, None, FRAME_INK);
        }
        c.ring(9.0, 0.0, 6, 2, INK);
        c.ring(-1e20, 0.0, usize::MAX, usize::MAX, INK);
        c.text(8, 6, "clipped text", 3, INK);
        c.text(usize::MAX, usize::MAX, "x", usize::MAX, INK);
        c.fill(usize::MAX, 2, usize::MAX, 3, INK);
    }

    #[test]
    fn markers_are_symmetric_and_outlined() {
        const FILL: [u8; 3] = [0, 200, 0];
        for shape in [Marker::Circle, Marker::Square, Marker::Diamond] {
            let mut c = Canvas::new(15, 15, BACKGROUND);
            c.marker(7.0, 7.0, shape, 4, Some(FILL), INK);
            assert_eq!(c.pixel(7, 7), Some(FILL), "{shape:?}");
            for y in 0..15 {
                for x in 0..15 {
                    assert_eq!(c.pixel(x, y), c.pixel(14 - x, y), "{shape:?}");
                    assert_eq!(c.pixel(x, y), c.pixel(x, 14 - y), "{shape:?}");
                }
            }
        }
        let mut c = Canvas::new(15, 15, BACKGROUND);
        c.ring(7.0, 7.0, 6, 2, INK);
        assert_eq!(c.pixel(7, 7), Some(BACKGROUND));
        assert_eq!(c.pixel(7, 1), Some(INK));
        assert_eq!(c.pixel(7, 2), Some(INK));
        assert_eq!(c.pixel(7, 3), Some(BACKGROUND));
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
