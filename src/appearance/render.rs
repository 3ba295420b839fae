//! Renders: the sample as a camera sees it at one angle, and its angle strip.
//!
//! Each pixel's reflectance spectrum comes from the film model (the estimated index with
//! its dispersion, the pixel's thickness, the substrate and polarisation of the capture),
//! sampled at the CIE grid 380..=780 nm every 5 nm, summed to XYZ under the chosen
//! illuminant, white-balanced to D65 (Bradford) and encoded as sRGB.
//!
//! Exposure: films reflect a few per cent, so an absolute rendering (a perfect white at
//! sRGB 255) is nearly black. Like a camera, the render scales the light by one exposure
//! factor: by default ([`auto_exposure`]) the one that puts the 99th percentile of the
//! image's luminance at `Y = 40`; the factor is printed in the image, and `1` gives the
//! absolute rendering. One factor serves the whole figure, so the angle strip shows how
//! bright the film gets with angle.
//!
//! Pixels without a reliable thickness (NaN in the map, or an invalidating flag) are drawn
//! in [`FLAG_COLOUR`], the same neutral mid grey as "no estimate" in the map previews.

use filmscope_core::colour::{srgb_to_u8, xyz_to_srgb_balanced, Colorimetry, Illuminant, Xyz};

use super::film::SampleFilm;
use super::spectral::FilmColour;
use crate::export::canvas::{text_width, Canvas, BACKGROUND, CAP_ROWS, FRAME_INK, INK};
use crate::export::colormap::NO_DATA;

/// The colour of pixels without a reliable thickness: neutral mid grey.
pub const FLAG_COLOUR: [u8; 3] = NO_DATA;

/// The luminance (`Y`, white = 100) the automatic exposure puts the image's 99th
/// percentile at.
pub const AUTO_EXPOSURE_Y: f64 = 40.0;

/// The angles of the strip of thumbnails, degrees (as the paper's Figure 6 sweeps).
pub const STRIP_ANGLES_DEG: [f64; 8] = [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0];

/// Step of the continuous colour band of the median thickness over 0..=70 degrees.
pub const BAND_STEP_DEG: f64 = 0.5;

/// How to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// Incidence (and, specular, viewing) angle of the main image, degrees.
    pub incidence_deg: f64,
    /// The light.
    pub illuminant: Illuminant,
    /// Exposure factor on the reflectance; `None` for [`auto_exposure`].
    pub exposure: Option<f64>,
}

/// What a render used, for captions and reports.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderInfo {
    /// The exposure factor applied.
    pub exposure: f64,
    /// The PNG's size, pixels.
    pub width: usize,
    /// The PNG's size, pixels.
    pub height: usize,
}

/// The XYZ of pixels `pixels` (indices into the row-major map) of `film` at
/// `incidence_deg`, [`Xyz::NAN`] where the thickness is not reliable.
pub fn film_xyz(
    film: &SampleFilm,
    incidence_deg: f64,
    colorimetry: Colorimetry,
    pixels: &[usize],
) -> Vec<Xyz> {
    let colour = FilmColour::new(film.stack, incidence_deg, colorimetry, film.terms);
    pixels
        .iter()
        .map(|&i| film.thickness_at(i).map_or(Xyz::NAN, |d| colour.xyz(d)))
        .collect()
}

/// The exposure that puts the 99th percentile of the finite luminances at
/// [`AUTO_EXPOSURE_Y`], within `1..=100`; 1 without any finite luminance.
pub fn auto_exposure(xyz: &[Xyz]) -> f64 {
    let mut y: Vec<f64> = xyz
        .iter()
        .map(|c| c.y)
        .filter(|y| y.is_finite() && *y > 0.0)
        .collect();
    if y.is_empty() {
        return 1.0;
    }
    y.sort_by(f64::total_cmp);
    let p99 = y[((y.len() - 1) as f64 * 0.99).round() as usize];
    (AUTO_EXPOSURE_Y / p99).clamp(1.0, 100.0)
}

/// A colour for display: scaled by `exposure`, white-balanced from `white` to D65,
/// sRGB 8 bits; [`FLAG_COLOUR`] for a NaN colour.
pub fn display_rgb(xyz: Xyz, white: Xyz, exposure: f64) -> [u8; 3] {
    if xyz.y.is_nan() {
        return FLAG_COLOUR;
    }
    let scaled = Xyz {
        x: xyz.x * exposure,
        y: xyz.y * exposure,
        z: xyz.z * exposure,
    };
    srgb_to_u8(xyz_to_srgb_balanced(scaled, white))
}

/// A map of `width x height` pixels seen through at most `max_width` columns (every
/// `stride`-th pixel, nearest neighbour): the sampled size and the indices sampled.
pub fn sample_grid(width: usize, height: usize, max_width: usize) -> (usize, usize, Vec<usize>) {
    let stride = width.div_ceil(max_width.max(1)).max(1);
    let (sw, sh) = (width.div_ceil(stride), height.div_ceil(stride));
    let mut idx = Vec::with_capacity(sw * sh);
    for r in 0..sh {
        for c in 0..sw {
            idx.push(r * stride * width + c * stride);
        }
    }
    (sw, sh, idx)
}

/// Integer factor that enlarges a `width`-pixel image to at least `min_width` pixels
/// (at least 1).
pub fn upscale(width: usize, min_width: usize) -> usize {
    min_width.div_ceil(width.max(1)).max(1)
}

/// Draws a `w x h` image (row-major colours) at `(x, y)`, each pixel `scale x scale`.
pub(crate) fn blit(c: &mut Canvas, x: usize, y: usize, w: usize, rgb: &[[u8; 3]], scale: usize) {
    let mut row = vec![0u8; w * scale * 3];
    for (r, line) in rgb.chunks(w.max(1)).enumerate() {
        for (block, colour) in row.chunks_exact_mut(scale * 3).zip(line) {
            for px in block.chunks_exact_mut(3) {
                px.copy_from_slice(colour);
            }
        }
        for dy in 0..scale {
            c.put_row(x, y + r * scale + dy, &row);
        }
    }
    c.frame(
        x.saturating_sub(1),
        y.saturating_sub(1),
        w * scale + 2,
        rgb.len().div_ceil(w.max(1)) * scale + 2,
        FRAME_INK,
    );
}

/// A legend line at `(x, y)`: a square of `colour`, then `text` (font scale 2).
pub(crate) fn swatch_note(c: &mut Canvas, x: usize, y: usize, colour: [u8; 3], text: &str) {
    let side = CAP_ROWS * TEXT;
    c.fill(x, y, side, side, colour);
    c.text(x + side + 6, y, text, TEXT, INK);
}

/// Main image: at most this many columns are computed.
const MAIN_MAX_WIDTH: usize = 1024;
/// Main image: enlarged to at least this width.
const MAIN_MIN_WIDTH: usize = 384;
/// Strip thumbnails: at most this many columns.
const TILE_MAX_WIDTH: usize = 128;
/// Strip thumbnails: enlarged to at least this width.
const TILE_MIN_WIDTH: usize = 96;
const MARGIN: usize = 12;
const GAP: usize = 10;
const TEXT: usize = 2;
const LINE: usize = CAP_ROWS * TEXT + 8;
const BAND_HEIGHT: usize = 28;

/// Renders `film` as a PNG: the sample at `opts.incidence_deg`, the strip of thumbnails at
/// [`STRIP_ANGLES_DEG`], and the colour of the median thickness from 0 to 70 degrees, with
/// captions (see the [module docs](self)).
pub fn render_png(
    film: &SampleFilm,
    opts: &RenderOptions,
) -> Result<(Vec<u8>, RenderInfo), super::AppearanceError> {
    let colorimetry = Colorimetry::full(opts.illuminant);
    let white = colorimetry.white();
    let (mw, mh, main_idx) = sample_grid(film.width, film.height, MAIN_MAX_WIDTH);
    let main_xyz = film_xyz(film, opts.incidence_deg, colorimetry, &main_idx);
    let exposure = opts.exposure.unwrap_or_else(|| auto_exposure(&main_xyz));
    let main_rgb: Vec<[u8; 3]> = main_xyz
        .iter()
        .map(|&x| display_rgb(x, white, exposure))
        .collect();
    let main_scale = upscale(mw, MAIN_MIN_WIDTH);
    let strip = AngleStrip::new(film, colorimetry, exposure);
    let median = film.median_thickness_nm();
    let band = median_band(film, median, colorimetry, exposure);
    let band_px = (strip.width() / band.len()).max(1);

    let title = format!(
        "{} at {:.0}°, {}, exposure x{:.1}",
        film.describe(),
        opts.incidence_deg,
        opts.illuminant.name(),
        exposure
    );
    let content_w = (mw * main_scale)
        .max(strip.width())
        .max(text_width(&title, TEXT));
    let width = content_w + 2 * MARGIN;
    let height = MARGIN
        + LINE
        + mh * main_scale
        + GAP
        + LINE
        + strip.tile_h()
        + 4
        + LINE
        + GAP
        + LINE
        + BAND_HEIGHT
        + 4
        + LINE
        + LINE
        + MARGIN;
    if width.saturating_mul(height) > crate::export::png::MAX_PIXELS {
        return Err(super::AppearanceError::Mismatch(format!(
            "a {width}x{height} render is too large"
        )));
    }
    let mut c = Canvas::new(width, height, BACKGROUND);
    let mut y = MARGIN;
    c.text(MARGIN, y, &title, TEXT, INK);
    y += LINE;
    blit(&mut c, MARGIN, y, mw, &main_rgb, main_scale);
    y += mh * main_scale + GAP;
    y = strip.draw(&mut c, y);
    y = draw_band(&mut c, y, &band, band_px, median);
    swatch_note(
        &mut c,
        MARGIN,
        y,
        FLAG_COLOUR,
        "grey = no reliable thickness (NaN or flagged)",
    );
    let png = c.encode().map_err(super::AppearanceError::from)?;
    Ok((
        png,
        RenderInfo {
            exposure,
            width,
            height,
        },
    ))
}

/// The angle strip: a thumbnail of the sample at each of [`STRIP_ANGLES_DEG`], under the
/// main image's exposure.
struct AngleStrip {
    /// A thumbnail's sampled columns and rows, and its enlargement.
    w: usize,
    h: usize,
    scale: usize,
    /// Each thumbnail's colours, row-major.
    tiles: Vec<Vec<[u8; 3]>>,
}

impl AngleStrip {
    /// The thumbnails of `film` under `colorimetry` at `exposure`.
    fn new(film: &SampleFilm, colorimetry: Colorimetry, exposure: f64) -> Self {
        let white = colorimetry.white();
        let (w, h, idx) = sample_grid(film.width, film.height, TILE_MAX_WIDTH);
        let tiles = STRIP_ANGLES_DEG
            .iter()
            .map(|&deg| {
                film_xyz(film, deg, colorimetry, &idx)
                    .iter()
                    .map(|&x| display_rgb(x, white, exposure))
                    .collect()
            })
            .collect();
        Self {
            w,
            h,
            scale: upscale(w, TILE_MIN_WIDTH),
            tiles,
        }
    }

    /// A thumbnail's width on the canvas.
    fn tile_w(&self) -> usize {
        self.w * self.scale
    }

    /// A thumbnail's height on the canvas.
    fn tile_h(&self) -> usize {
        self.h * self.scale
    }

    /// The strip's width on the canvas.
    fn width(&self) -> usize {
        STRIP_ANGLES_DEG.len() * (self.tile_w() + GAP) - GAP
    }

    /// Draws the caption and the thumbnails, each labelled with its angle, from `y` down;
    /// returns the `y` below them.
    fn draw(&self, c: &mut Canvas, mut y: usize) -> usize {
        let (tile_w, tile_h) = (self.tile_w(), self.tile_h());
        c.text(MARGIN, y, "angle strip, 0-70°, same exposure", TEXT, INK);
        y += LINE;
        for (k, (tile, deg)) in self.tiles.iter().zip(STRIP_ANGLES_DEG).enumerate() {
            let x = MARGIN + k * (tile_w + GAP);
            blit(c, x, y, self.w, tile, self.scale);
            let label = format!("{deg:.0}°");
            c.text(
                x + tile_w.saturating_sub(text_width(&label, TEXT)) / 2,
                y + tile_h + 4,
                &label,
                TEXT,
                INK,
            );
        }
        y + tile_h + 4 + LINE + GAP
    }
}

/// The colour of the `median` thickness every [`BAND_STEP_DEG`] from 0 to the strip's
/// last angle (no data without a median).
fn median_band(
    film: &SampleFilm,
    median: Option<f64>,
    colorimetry: Colorimetry,
    exposure: f64,
) -> Vec<[u8; 3]> {
    let white = colorimetry.white();
    let steps = (STRIP_ANGLES_DEG[STRIP_ANGLES_DEG.len() - 1] / BAND_STEP_DEG).round() as usize;
    (0..=steps)
        .map(|k| {
            let deg = k as f64 * BAND_STEP_DEG;
            let xyz = median.map_or(Xyz::NAN, |d| {
                FilmColour::new(film.stack, deg, colorimetry, film.terms).xyz(d)
            });
            display_rgb(xyz, white, exposure)
        })
        .collect()
}

/// Draws the median thickness's caption, its colour `band` (`band_px` wide per step) and
/// the strip's angles under it, from `y` down; returns the `y` below them.
fn draw_band(
    c: &mut Canvas,
    mut y: usize,
    band: &[[u8; 3]],
    band_px: usize,
    median: Option<f64>,
) -> usize {
    let band_label = match median {
        Some(d) => format!("median thickness {d:.1} nm, 0-70°"),
        None => "no reliable thickness".to_owned(),
    };
    c.text(MARGIN, y, &band_label, TEXT, INK);
    y += LINE;
    for (k, colour) in band.iter().enumerate() {
        c.fill(MARGIN + k * band_px, y, band_px, BAND_HEIGHT, *colour);
    }
    c.frame(
        MARGIN - 1,
        y - 1,
        band.len() * band_px + 2,
        BAND_HEIGHT + 2,
        FRAME_INK,
    );
    y += BAND_HEIGHT + 4;
    for deg in STRIP_ANGLES_DEG {
        let label = format!("{deg:.0}");
        let x = MARGIN + (deg / BAND_STEP_DEG) as usize * band_px;
        c.text(
            x.saturating_sub(text_width(&label, TEXT) / 2),
            y,
            &label,
            TEXT,
            INK,
        );
    }
    y + LINE
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_grid_strides_large_maps_and_keeps_small_ones() {
        let (w, h, idx) = sample_grid(4, 3, 1024);
        assert_eq!((w, h), (4, 3));
        assert_eq!(idx, (0..12).collect::<Vec<_>>());
        let (w, h, idx) = sample_grid(10, 5, 4);
        // Stride 3: columns 0, 3, 6, 9 of rows 0 and 3.
        assert_eq!((w, h), (4, 2));
        assert_eq!(idx, vec![0, 3, 6, 9, 30, 33, 36, 39]);
        assert_eq!(upscale(96, 384), 4);
        assert_eq!(upscale(1000, 384), 1);
    }

    #[test]
    fn auto_exposure_targets_the_99th_percentile() {
        let xyz = |y: f64| Xyz { x: y, y, z: y };
        let mut v: Vec<Xyz> = (1..=100).map(|i| xyz(f64::from(i) * 0.1)).collect();
        v.push(Xyz::NAN);
        // The 99th percentile is 9.9: 40 / 9.9.
        assert!((auto_exposure(&v) - 40.0 / 9.9).abs() < 1e-12);
        assert_eq!(auto_exposure(&[xyz(80.0)]), 1.0);
        assert_eq!(auto_exposure(&[xyz(0.01)]), 100.0);
        assert_eq!(auto_exposure(&[Xyz::NAN]), 1.0);
    }
}
