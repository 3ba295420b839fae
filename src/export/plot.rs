//! Charts as PNG: scatter plots (with an optional Pareto front) and heat maps, several
//! panels side by side in one image, drawn with the built-in 5x7 pixel font shared with
//! [`png`](super::png) (no font files, no plotting crates).
//!
//! A figure is the figure title across the top, then the panels left to right, top-aligned,
//! [`PANEL_GAP`] pixels apart. A scatter panel ([`render_scatter_panels_png`]):
//!
//! ```text
//!                 Panel title
//!  y label
//!        +------------------------------+
//!   1e3 -|  .  o      o                 |    plot area PLOT_WIDTH x PLOT_HEIGHT,
//!        |     o  label                 |    light grid lines at the major ticks;
//!    10 -|   o  \_____                  |    the Pareto front (if asked for) as a
//!        |            \____o            |    black staircase, its points ringed
//!   0.1 -|                              |
//!        +------------------------------+
//!          |        |        |        |
//!         0.0      0.5      1.0      1.5
//!                    x label
//!  o series 1   [] series 2   -O- Pareto front
//!  2 points not drawn: not finite, or <= 0 on a log axis
//! ```
//!
//! - The y label is written horizontally above the y axis (the font has no vertical text).
//! - Axis ranges cover the drawable points plus a 5% margin on each side (on a log axis,
//!   5% of the decades spanned); a single value is widened to a visible range.
//! - Linear axes get "nice" ticks, 1, 2 or 5 times a power of ten apart. Log axes get
//!   ticks at powers of ten, labelled `0.01`, `0.1`, `1`, `10`, `100`, then `1e3`,
//!   `1e-3`, ... (every n-th power when they span more than eight decades, else each
//!   power, with unlabelled minor ticks at 2..9 times it); over less than three decades 2 and 5
//!   times the powers are labelled too (`2`, `5`, `20`, `2e3`), and over less than one
//!   decade the ticks are linear ones placed logarithmically. Tick labels that would touch
//!   are thinned to every second, third, ... tick.
//! - Series are told apart by colour (the Tableau 10 palette, in order) and marker shape
//!   (circle, square, diamond, triangles); the legend runs below the x label and wraps.
//! - Points that cannot be drawn (a non-finite coordinate, or a value <= 0 on a log
//!   axis) are left out and counted in a note under the legend. A panel without a single
//!   drawable point still renders: an empty frame with "no data" in it.
//! - Point labels are drawn small beside their point, on whichever side keeps them inside
//!   the plot area and clear of the labels already placed; a label that fits nowhere is
//!   left out rather than drawn over another.
//! - The Pareto front is taken over the drawn points of all series together.
//!
//! A heat-map panel ([`render_heatmap_panels_png`]):
//!
//! ```text
//!                 Panel title
//!  y label                                   unit
//!        +---------------------------+       +--+- 3.2
//!   row0 | cell | cell | cell | cell |       |  |
//!   row1 | cell | cell | cell | cell |       |  |- 2.1      viridis colour bar:
//!   row2 | cell | cell | cell | cell |       |  |           max, mid and min
//!        +---------------------------+       +--+- 1.0
//!          col0   col1   col2   col3
//!                   x label
//!  [ ] grey = no data
//! ```
//!
//! - Values are row-major, row 0 drawn at the TOP (like an image or a printed table),
//!   column 0 at the left. `x_ticks` label column centres, `y_ticks` row centres; each is
//!   either empty (no labels) or one label per column (row), thinned if they would touch.
//! - Cells are sized to fill about [`PLOT_WIDTH`] x [`PLOT_HEIGHT`] (at least one pixel,
//!   and big enough for the cell's text when `cell_text` is set).
//! - Non-finite values (NaN, +-inf) are drawn in the "no data" grey [`NO_DATA`], with a
//!   note under the panel. A heat map without a finite value still renders (all grey,
//!   "no data" written across it).
//! - The colour bar is labelled at its ends and middle: the range's low end, high end and
//!   midpoint, or with `log` the geometric mean of the ends (3 significant digits).
//!
//! No function here panics on any input: a figure without panels, heat-map values that do
//! not fill `rows x cols`, tick-label counts that match neither, invalid colour ranges
//! and images beyond [`MAX_PIXELS`] are reported as [`PreviewError`]s; empty series and
//! all-NaN data render as "no data" panels.

use std::path::Path;

use super::canvas::{
    fit_text, text_width, write_png, Canvas, Marker, BACKGROUND, CAP_ROWS, FRAME_INK, INK,
};
use super::colormap::{viridis, NO_DATA};
use super::png::{check_size, format_value, tick_decimals, PreviewError, MAX_PIXELS};

/// Width in pixels of a scatter panel's plot area (and the width a heat map's cells are
/// sized to fill).
pub const PLOT_WIDTH: usize = 520;

/// Height in pixels of a scatter panel's plot area (and the height a heat map's cells are
/// sized to fill).
pub const PLOT_HEIGHT: usize = 400;

/// Horizontal space in pixels between two panels of a figure.
pub const PANEL_GAP: usize = 48;

/// One named set of points in a [`Scatter`] panel.
#[derive(Clone, Copy, Debug)]
pub struct Series<'a> {
    /// Shown in the legend.
    pub name: &'a str,
    /// `(x, y)` data points; points that cannot be drawn (non-finite, or <= 0 on a log
    /// axis) are skipped and counted in a note.
    pub points: &'a [(f64, f64)],
    /// Optional text drawn small beside each point: `labels[i]` belongs to `points[i]`;
    /// empty strings and labels beyond the last point are ignored.
    pub labels: Option<&'a [String]>,
}

/// A scatter-plot panel: one or more [`Series`], optionally with their Pareto front.
#[derive(Clone, Copy, Debug)]
pub struct Scatter<'a> {
    /// Drawn centred above the plot area.
    pub title: &'a str,
    /// Drawn centred below the x tick labels.
    pub x_label: &'a str,
    /// Drawn horizontally above the y axis.
    pub y_label: &'a str,
    /// Logarithmic x axis (points with x <= 0 are not drawn).
    pub x_log: bool,
    /// Logarithmic y axis (points with y <= 0 are not drawn).
    pub y_log: bool,
    /// The data, one colour and marker shape per series, in legend order.
    pub series: &'a [Series<'a>],
    /// Also draw the Pareto front over the drawn points of all series together
    /// (minimising both x and y, see [`pareto_front`]; points that cannot be drawn take no
    /// part) as a black staircase with its points ringed, and list it in the legend as
    /// "Pareto front".
    pub pareto: bool,
}

/// A heat-map panel: a `rows x cols` grid of values, colour-mapped with [`viridis`].
#[derive(Clone, Copy, Debug)]
pub struct HeatMap<'a> {
    /// Drawn centred above the map.
    pub title: &'a str,
    /// Drawn centred below the column labels.
    pub x_label: &'a str,
    /// Drawn horizontally above the row labels.
    pub y_label: &'a str,
    /// One label per column (drawn under the column's centre), or empty for none.
    pub x_ticks: &'a [String],
    /// One label per row (drawn left of the row's centre, row 0 at the top), or empty
    /// for none.
    pub y_ticks: &'a [String],
    /// Number of columns.
    pub cols: usize,
    /// Number of rows.
    pub rows: usize,
    /// `rows * cols` values, row-major: `values[r * cols + c]` is row `r` (counted from
    /// the top), column `c` (from the left). Non-finite values are drawn grey.
    pub values: &'a [f64],
    /// The values' unit, written above the colour bar; may be empty.
    pub unit: &'a str,
    /// The values mapped to the two ends of the colour bar, `(low, high)`; `None` uses
    /// the smallest and largest finite value (positive value when `log`).
    pub range: Option<(f64, f64)>,
    /// Colour by `log10` of the value; values <= 0 get the colour of the range's low end.
    pub log: bool,
    /// Write each cell's value (3 significant digits) in it, black or white, whichever
    /// reads better on the cell's colour.
    pub cell_text: bool,
}

/// Indices of the points that no other point dominates, minimising both coordinates: a
/// point is dropped if another is at least as small in x and in y and smaller in one.
///
/// Points with a NaN or infinite coordinate take no part (they neither dominate nor are
/// returned). Identical points do not dominate each other, so all copies of a front point
/// are returned. The indices are sorted by x (ascending; y is then descending), ties by
/// index.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    // `+ 0.0` turns -0.0 into 0.0, so that the two compare equal in the sort as well.
    let mut order: Vec<(f64, f64, usize)> = points
        .iter()
        .enumerate()
        .filter(|(_, (x, y))| x.is_finite() && y.is_finite())
        .map(|(i, &(x, y))| (x + 0.0, y + 0.0, i))
        .collect();
    order.sort_unstable_by(|a, b| {
        a.0.total_cmp(&b.0)
            .then(a.1.total_cmp(&b.1))
            .then(a.2.cmp(&b.2))
    });
    let mut front: Vec<usize> = Vec::new();
    let mut last: Option<(f64, f64)> = None;
    for (x, y, i) in order {
        let keep = match last {
            None => true,
            // Sorted by x, so an earlier point has x no larger: this one survives only
            // with a smaller y, or as an exact copy of the last front point.
            Some((lx, ly)) => y < ly || (y == ly && x == lx),
        };
        if keep {
            front.push(i);
            last = Some((x, y));
        }
    }
    front
}

/// Renders scatter-plot panels side by side as one RGB8 PNG in memory, `title` across
/// the top (see the [module docs](self) for the layout).
///
/// Errors: [`PreviewError::NoPanels`] for an empty `panels`, [`PreviewError::TooLarge`]
/// if the image would exceed [`MAX_PIXELS`], [`PreviewError::Encode`].
pub fn render_scatter_panels_png(title: &str, panels: &[Scatter]) -> Result<Vec<u8>, PreviewError> {
    let layouts: Vec<ScatterLayout> = panels.iter().map(ScatterLayout::new).collect();
    compose(title, &layouts)
}

/// Renders like [`render_scatter_panels_png`] and writes the PNG to `path` atomically
/// (temporary file + rename, see [`write_atomic`](crate::io::write_atomic)).
///
/// Errors: those of [`render_scatter_panels_png`], and [`PreviewError::Write`] (naming
/// `path`) if the file cannot be written.
pub fn write_scatter_panels_png(
    path: &Path,
    title: &str,
    panels: &[Scatter],
) -> Result<(), PreviewError> {
    let png = render_scatter_panels_png(title, panels)?;
    write_png(path, &png)
}

/// Renders heat-map panels side by side, each with its own colour bar, as one RGB8 PNG
/// in memory, `title` across the top (see the [module docs](self) for the layout).
///
/// Errors: [`PreviewError::NoPanels`] for an empty `panels`; for any panel,
/// [`PreviewError::Empty`] if it has no cells, [`PreviewError::SizeMismatch`] if
/// `values` does not hold `rows * cols` entries, [`PreviewError::TickCount`] if a tick
/// list is neither empty nor one per column (row), [`PreviewError::InvalidRange`] for a
/// `range` that is not finite with `low <= high` (and `low > 0` when `log`);
/// [`PreviewError::TooLarge`] beyond [`MAX_PIXELS`], [`PreviewError::Encode`].
pub fn render_heatmap_panels_png(title: &str, panels: &[HeatMap]) -> Result<Vec<u8>, PreviewError> {
    let layouts = panels
        .iter()
        .map(HeatLayout::new)
        .collect::<Result<Vec<_>, _>>()?;
    compose(title, &layouts)
}

/// Renders like [`render_heatmap_panels_png`] and writes the PNG to `path` atomically
/// (temporary file + rename, see [`write_atomic`](crate::io::write_atomic)).
///
/// Errors: those of [`render_heatmap_panels_png`], and [`PreviewError::Write`] (naming
/// `path`) if the file cannot be written.
pub fn write_heatmap_panels_png(
    path: &Path,
    title: &str,
    panels: &[HeatMap],
) -> Result<(), PreviewError> {
    let png = render_heatmap_panels_png(title, panels)?;
    write_png(path, &png)
}

// ---------------------------------------------------------------------------------------
// Layout constants and colours.

/// Space around the whole image.
const MARGIN: usize = 16;
/// Vertical space between rows of text and the things they label.
const GAP: usize = 10;
/// Length of major tick marks.
const TICK_LEN: usize = 5;
/// Length of minor tick marks.
const MINOR_TICK_LEN: usize = 3;
/// Space between a tick mark and its label.
const TICK_GAP: usize = 6;
/// Least space between two neighbouring tick labels.
const LABEL_SPACING: f64 = 12.0;
/// Space between a heat map and its colour bar.
const BAR_GAP: usize = 24;
/// Width of a heat map's colour bar.
const BAR_WIDTH: usize = 20;
/// Font scale of the figure title (reduced if it does not fit).
const FIGURE_TITLE_SCALE: usize = 3;
/// Font scale of panel titles.
const PANEL_TITLE_SCALE: usize = 2;
/// Font scale of axis labels.
const AXIS_SCALE: usize = 2;
/// Font scale of tick labels.
const TICK_SCALE: usize = 2;
/// Font scale of legend entries.
const LEGEND_SCALE: usize = 2;
/// Font scale of point labels and notes.
const SMALL_SCALE: usize = 1;
/// Marker "radius": markers are `2 * MARKER_RADIUS + 1` pixels across.
const MARKER_RADIUS: usize = 3;
/// Outer radius of the rings around Pareto-front points.
const RING_RADIUS: usize = 7;
/// Width of the box a legend key is drawn in.
const KEY_WIDTH: usize = 24;
/// Space between a legend key and its text, and after an entry.
const KEY_GAP: usize = 6;
/// Space between legend entries on one row.
const ENTRY_GAP: usize = 20;
/// Height of one legend row.
const LEGEND_ROW: usize = CAP_ROWS * LEGEND_SCALE + 8;
/// Height above a panel's plot area (or map): the panel title, the y label, and room for
/// half a tick label at the top of the axis.
const HEADER: usize =
    CAP_ROWS * PANEL_TITLE_SCALE + GAP + CAP_ROWS * AXIS_SCALE + GAP + CAP_ROWS * TICK_SCALE / 2;
/// Fraction of the data range added on each side of a scatter axis.
const AXIS_MARGIN: f64 = 0.05;

/// Series colours: Tableau 10 (Tableau's default qualitative palette since 2016).
const PALETTE: [[u8; 3]; 10] = [
    [0x4e, 0x79, 0xa7], // blue
    [0xf2, 0x8e, 0x2b], // orange
    [0xe1, 0x57, 0x59], // red
    [0x76, 0xb7, 0xb2], // teal
    [0x59, 0xa1, 0x4f], // green
    [0xed, 0xc9, 0x48], // yellow
    [0xb0, 0x7a, 0xa1], // purple
    [0xff, 0x9d, 0xa7], // pink
    [0x9c, 0x75, 0x5f], // brown
    [0xba, 0xb0, 0xac], // grey
];
/// Marker shapes, cycled through alongside the palette.
const SHAPES: [Marker; 5] = [
    Marker::Circle,
    Marker::Square,
    Marker::Diamond,
    Marker::TriangleUp,
    Marker::TriangleDown,
];
/// The Pareto front's staircase and rings.
const PARETO_INK: [u8; 3] = [0, 0, 0];
/// Grid lines at the major ticks.
const GRID: [u8; 3] = [228, 228, 228];
/// Notes (points not drawn).
const NOTE_INK: [u8; 3] = [96, 96, 96];
/// Text on dark heat-map cells.
const LIGHT_TEXT: [u8; 3] = [255, 255, 255];

/// The colour and marker shape of series `i`.
fn series_style(i: usize) -> ([u8; 3], Marker) {
    // The shape advances once more per trip round the palette, so that series 0 and 10
    // differ in shape.
    (
        PALETTE[i % PALETTE.len()],
        SHAPES[(i + i / PALETTE.len()) % SHAPES.len()],
    )
}

/// `colour` darkened, for marker outlines.
fn darker(colour: [u8; 3]) -> [u8; 3] {
    colour.map(|c| (u16::from(c) * 3 / 5) as u8)
}

// ---------------------------------------------------------------------------------------
// Figures: panels side by side under a title.

/// A panel whose size is known, ready to be drawn at an offset.
trait Panel {
    /// `(width, height)` in pixels.
    fn size(&self) -> (usize, usize);
    /// Draws the panel with its top-left corner at `(x, y)`.
    fn draw(&self, c: &mut Canvas, x: usize, y: usize);
}

/// Lays `panels` out left to right under `title` and encodes the figure.
fn compose<P: Panel>(title: &str, panels: &[P]) -> Result<Vec<u8>, PreviewError> {
    if panels.is_empty() {
        return Err(PreviewError::NoPanels);
    }
    let sizes: Vec<(usize, usize)> = panels.iter().map(Panel::size).collect();
    let mut content_w = PANEL_GAP.saturating_mul(panels.len() - 1);
    let mut content_h = 0usize;
    for &(w, h) in &sizes {
        content_w = content_w.saturating_add(w);
        content_h = content_h.max(h);
    }
    let title_h = if title.is_empty() {
        0
    } else {
        CAP_ROWS * FIGURE_TITLE_SCALE + 2 * GAP
    };
    let img_w = content_w.saturating_add(2 * MARGIN);
    let img_h = content_h.saturating_add(2 * MARGIN + title_h);
    if img_w.checked_mul(img_h).is_none_or(|n| n > MAX_PIXELS) {
        return Err(PreviewError::TooLarge {
            width: img_w,
            height: img_h,
            scale: 1,
            limit: MAX_PIXELS,
        });
    }
    let mut c = Canvas::new(img_w, img_h, BACKGROUND);
    if !title.is_empty() {
        let avail = img_w - 2 * MARGIN;
        let scale = (1..=FIGURE_TITLE_SCALE)
            .rev()
            .find(|&s| text_width(title, s) <= avail)
            .unwrap_or(1);
        let text = fit_text(title, avail, scale);
        let y = MARGIN + (CAP_ROWS * FIGURE_TITLE_SCALE - CAP_ROWS * scale) / 2;
        c.text(MARGIN, y, &text, scale, INK);
    }
    let mut x = MARGIN;
    for (panel, (w, _)) in panels.iter().zip(&sizes) {
        panel.draw(&mut c, x, MARGIN + title_h);
        x = x.saturating_add(w + PANEL_GAP);
    }
    c.encode()
}

/// Draws `text` at `scale` centred on `cx`, but within `x..x + w` (cut short to fit).
fn text_centred(
    c: &mut Canvas,
    cx: usize,
    y: usize,
    text: &str,
    scale: usize,
    (x, w): (usize, usize),
) {
    let text = fit_text(text, w, scale);
    let tw = text_width(&text, scale);
    let left = cx
        .saturating_sub(tw / 2)
        .min((x + w).saturating_sub(tw))
        .max(x);
    c.text(left, y, &text, scale, INK);
}

/// The smallest stride `s` such that labels `0, s, 2s, ...`, centred at `pos` (pixels,
/// monotonic) and `size[i]` pixels long along the axis, keep [`LABEL_SPACING`] apart.
fn label_stride(pos: &[f64], size: &[usize]) -> usize {
    let n = pos.len().min(size.len());
    (1..n)
        .find(|&s| {
            (s..n).step_by(s).all(|j| {
                let i = j - s;
                (pos[j] - pos[i]).abs() >= (size[i] + size[j]) as f64 / 2.0 + LABEL_SPACING
            })
        })
        .unwrap_or(1)
}

// ---------------------------------------------------------------------------------------
// Number formatting.

/// `s` without trailing zeros after a decimal point (and without a bare point).
fn trim_fraction(s: &str) -> String {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s.to_string()
    }
}

/// `format!("{v:.decimals$e}")` with the mantissa's trailing zeros removed: `1.50e5` ->
/// `1.5e5`, `2.00e-4` -> `2e-4`; zero is `0`.
fn format_sci(v: f64, decimals: usize) -> String {
    if v == 0.0 {
        return "0".to_string();
    }
    let s = format!("{v:.decimals$e}");
    match s.split_once('e') {
        Some((mantissa, exp)) => format!("{}e{exp}", trim_fraction(mantissa)),
        None => s,
    }
}

/// `v` to `sig` significant digits, compactly: fixed point without trailing zeros for
/// magnitudes 1e-3..1e5, else scientific (`1.5e5`, `2e-4`); never "-0".
fn format_sig(v: f64, sig: usize) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    if v == 0.0 {
        return "0".to_string();
    }
    let sig = sig.max(1);
    let e = v.abs().log10().floor();
    if (-3.0..5.0).contains(&e) {
        let decimals = (sig as f64 - 1.0 - e).max(0.0) as usize;
        trim_fraction(&format!("{v:.decimals$}"))
    } else {
        format_sci(v, sig - 1)
    }
}

/// Labels for linear ticks `ticks` that are `step` apart: the same number of decimals for
/// all (enough for the step), or scientific notation when the values are very large or
/// very small.
fn linear_tick_labels(ticks: &[f64], step: f64) -> Vec<String> {
    let step_e = (step.abs().log10() + 1e-9).floor();
    let largest = ticks.iter().fold(0.0_f64, |m, t| m.max(t.abs()));
    if largest >= 1e5 || (largest > 0.0 && largest < 1e-3) {
        let digits = (largest.log10().floor() - step_e).clamp(0.0, 15.0) as usize;
        ticks.iter().map(|&t| format_sci(t + 0.0, digits)).collect()
    } else {
        let decimals = (-step_e).clamp(0.0, 15.0) as usize;
        ticks
            .iter()
            .map(|&t| format!("{:.decimals$}", t + 0.0))
            .collect()
    }
}

/// The label of `m * 10^k` on a log axis: plain for 0.01..999 (`0.05`, `1`, `200`),
/// else scientific (`1e3`, `5e-4`).
fn log_tick_label(m: u32, k: i32) -> String {
    if (-2..=2).contains(&k) {
        let decimals = usize::try_from(-k).unwrap_or(0);
        format!("{:.decimals$}", f64::from(m) * 10f64.powi(k))
    } else {
        format!("{m}e{k}")
    }
}

// ---------------------------------------------------------------------------------------
// Scatter axes.

/// One axis of a scatter panel: the visible range in axis units (`log10` of the value on a
/// log axis).
#[derive(Clone, Copy, Debug)]
struct Axis {
    /// Low end, axis units.
    lo: f64,
    /// High end, axis units.
    hi: f64,
    /// Logarithmic.
    log: bool,
}

/// A tick on an [`Axis`], in axis units; minor ticks and thinned-out ones have no label.
#[derive(Clone, Debug)]
struct Tick {
    /// Position, axis units.
    at: f64,
    /// The label, if drawn.
    label: Option<String>,
    /// A minor tick (shorter, no grid line).
    minor: bool,
}

impl Axis {
    /// `v` in axis units, if it can be drawn on this kind of axis.
    fn to_axis(v: f64, log: bool) -> Option<f64> {
        match (v.is_finite(), log) {
            (false, _) => None,
            (true, false) => Some(v),
            (true, true) => (v > 0.0).then(|| v.log10()),
        }
    }

    /// The axis covering `values` (already in axis units, finite) with a margin; `None`
    /// for no values.
    fn covering(values: impl Iterator<Item = f64>, log: bool) -> Option<Self> {
        let (lo, hi) = values.fold(None, |acc: Option<(f64, f64)>, v| match acc {
            None => Some((v, v)),
            Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
        })?;
        // Halves, so that the span of extreme values does not overflow.
        let half_span = hi * 0.5 - lo * 0.5;
        let pad = if half_span > 0.0 {
            2.0 * half_span * AXIS_MARGIN
        } else if log {
            0.5
        } else if lo == 0.0 {
            1.0
        } else {
            lo.abs() * 0.1
        };
        let lo = (lo - pad).max(-f64::MAX);
        let hi = (hi + pad).min(f64::MAX);
        Some(Self { lo, hi, log })
    }

    /// Where `t` (axis units) falls along the axis, 0 at `lo` and 1 at `hi`.
    fn frac(&self, t: f64) -> f64 {
        let span = self.hi * 0.5 - self.lo * 0.5;
        if span > 0.0 {
            (t * 0.5 - self.lo * 0.5) / span
        } else {
            0.5
        }
    }

    /// Major and minor ticks inside the range, labelled (not yet thinned).
    fn ticks(&self) -> Vec<Tick> {
        let decades = self.hi - self.lo;
        if !self.log {
            return linear_ticks(self.lo, self.hi, Some);
        }
        if decades < 1.0 {
            // Less than a decade: linear ticks in value space, placed logarithmically.
            let lo = 10f64.powf(self.lo);
            let hi = 10f64.powf(self.hi);
            return linear_ticks(lo, hi, |v| (v > 0.0).then(|| v.log10()));
        }
        let (k_lo, k_hi) = (self.lo.floor() as i32, self.hi.ceil() as i32);
        let inside = |t: f64| t >= self.lo && t <= self.hi;
        let mut ticks = Vec::new();
        if decades < 3.0 {
            for k in k_lo..=k_hi {
                for m in 1..=9u32 {
                    let at = f64::from(k) + f64::from(m).log10();
                    if inside(at) {
                        let major = matches!(m, 1 | 2 | 5);
                        ticks.push(Tick {
                            at,
                            label: major.then(|| log_tick_label(m, k)),
                            minor: !major,
                        });
                    }
                }
            }
            return ticks;
        }
        // Every `stride`-th power of ten, about eight at most.
        let stride = ((decades / 8.0).ceil() as i32).max(1);
        for k in k_lo..=k_hi {
            if inside(f64::from(k)) && k.rem_euclid(stride) == 0 {
                ticks.push(Tick {
                    at: f64::from(k),
                    label: Some(log_tick_label(1, k)),
                    minor: false,
                });
            }
            if stride == 1 {
                for m in 2..=9u32 {
                    let at = f64::from(k) + f64::from(m).log10();
                    if inside(at) {
                        ticks.push(Tick {
                            at,
                            label: None,
                            minor: true,
                        });
                    }
                }
            }
        }
        ticks
    }
}

/// "Nice" ticks (1, 2 or 5 times a power of ten apart, about six) between `lo` and `hi`,
/// each placed at `place(value)` (skipped where that is `None`).
fn linear_ticks(lo: f64, hi: f64, place: impl Fn(f64) -> Option<f64>) -> Vec<Tick> {
    let raw = (hi * 0.5 - lo * 0.5) / 3.0; // span / 6
    if !(raw > 0.0 && raw.is_finite()) {
        return Vec::new();
    }
    let mag = 10f64.powf(raw.log10().floor());
    let norm = raw / mag;
    let nice = if norm < 1.5 {
        1.0
    } else if norm < 3.5 {
        2.0
    } else if norm < 7.5 {
        5.0
    } else {
        10.0
    };
    let step = nice * mag;
    let (k0, k1) = ((lo / step).ceil(), (hi / step).floor());
    if !(step > 0.0 && step.is_finite() && k0.is_finite() && k1.is_finite() && k1 - k0 <= 50.0) {
        return Vec::new();
    }
    let values: Vec<f64> = (0..=(k1 - k0).max(-1.0) as i64)
        .map(|i| (k0 + i as f64) * step)
        .collect();
    let labels = linear_tick_labels(&values, step);
    values
        .iter()
        .zip(labels)
        .filter_map(|(&v, label)| {
            place(v).map(|at| Tick {
                at,
                label: Some(label),
                minor: false,
            })
        })
        .collect()
}

/// Drops the labels of major ticks so that those left keep [`LABEL_SPACING`] apart, given
/// each tick's pixel position and each label's extent along the axis.
fn thin_labels(ticks: &mut [Tick], pixel: impl Fn(f64) -> f64, extent: impl Fn(&str) -> usize) {
    let labelled: Vec<usize> = (0..ticks.len())
        .filter(|&i| ticks[i].label.is_some())
        .collect();
    let pos: Vec<f64> = labelled.iter().map(|&i| pixel(ticks[i].at)).collect();
    let size: Vec<usize> = labelled
        .iter()
        .map(|&i| ticks[i].label.as_deref().map_or(0, &extent))
        .collect();
    let stride = label_stride(&pos, &size);
    for (n, &i) in labelled.iter().enumerate() {
        if n % stride != 0 {
            ticks[i].label = None;
        }
    }
}

// ---------------------------------------------------------------------------------------
// Scatter panels.

/// A legend entry's key.
#[derive(Clone, Copy, Debug)]
enum Key {
    /// A series' marker.
    Marker([u8; 3], Marker),
    /// The Pareto front: a line with a ring.
    Front,
}

/// A legend entry placed on its row.
#[derive(Clone, Debug)]
struct Entry {
    /// Offset from the panel's left edge.
    x: usize,
    /// Row, from 0.
    row: usize,
    /// What to draw before the text.
    key: Key,
    /// The text.
    text: String,
}

/// A scatter panel, measured.
struct ScatterLayout<'a> {
    /// What to draw.
    spec: &'a Scatter<'a>,
    /// The axes; `None` when there is no drawable point.
    axes: Option<(Axis, Axis)>,
    /// Ticks, labels thinned.
    x_ticks: Vec<Tick>,
    /// Ticks, labels thinned.
    y_ticks: Vec<Tick>,
    /// Left edge of the plot area, from the panel's left edge.
    plot_left: usize,
    /// Top edge of the plot area, from the panel's top.
    plot_top: usize,
    /// Legend entries.
    legend: Vec<Entry>,
    /// Number of legend rows.
    legend_rows: usize,
    /// The note on points not drawn, if any.
    note: Option<String>,
    /// Panel size.
    width: usize,
    /// Panel size.
    height: usize,
}

impl<'a> ScatterLayout<'a> {
    /// Measures `spec`.
    fn new(spec: &'a Scatter<'a>) -> Self {
        let drawable = |&(x, y): &(f64, f64)| {
            Some((Axis::to_axis(x, spec.x_log)?, Axis::to_axis(y, spec.y_log)?))
        };
        let all = || spec.series.iter().flat_map(|s| s.points.iter());
        let total = all().count();
        let shown: Vec<(f64, f64)> = all().filter_map(drawable).collect();
        let axes = Axis::covering(shown.iter().map(|p| p.0), spec.x_log)
            .zip(Axis::covering(shown.iter().map(|p| p.1), spec.y_log));

        let (mut x_ticks, mut y_ticks) = match axes {
            Some((ax, ay)) => (ax.ticks(), ay.ticks()),
            None => (Vec::new(), Vec::new()),
        };
        if let Some((ax, ay)) = axes {
            let span_x = (PLOT_WIDTH - 1) as f64;
            let span_y = (PLOT_HEIGHT - 1) as f64;
            thin_labels(
                &mut x_ticks,
                |t| ax.frac(t) * span_x,
                |s| text_width(s, TICK_SCALE),
            );
            thin_labels(
                &mut y_ticks,
                |t| ay.frac(t) * span_y,
                |_| CAP_ROWS * TICK_SCALE,
            );
        }
        let label_w = |ticks: &[Tick], i: usize| {
            ticks
                .get(i)
                .and_then(|t| t.label.as_deref())
                .map_or(0, |s| text_width(s, TICK_SCALE))
        };
        let y_label_w = (0..y_ticks.len())
            .map(|i| label_w(&y_ticks, i))
            .max()
            .unwrap_or(0);
        let first_x = x_ticks.iter().position(|t| t.label.is_some());
        let last_x = x_ticks.iter().rposition(|t| t.label.is_some());
        // Half of the first x label may stick out left of the plot area, half of the last
        // one right of it.
        let overhang = |i: Option<usize>| i.map_or(0, |i| label_w(&x_ticks, i) / 2);
        let plot_left = (y_label_w + TICK_LEN + TICK_GAP)
            .max(overhang(first_x))
            .max(TICK_LEN + TICK_GAP + 2);
        let width = plot_left + PLOT_WIDTH + 1 + overhang(last_x).max(8);
        let plot_top = HEADER;

        // Legend, wrapped to the panel width.
        let mut items: Vec<(Key, &str)> = spec
            .series
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let (colour, shape) = series_style(i);
                (Key::Marker(colour, shape), s.name)
            })
            .collect();
        if spec.pareto && axes.is_some() {
            items.push((Key::Front, "Pareto front"));
        }
        let mut legend = Vec::new();
        let (mut x, mut row) = (0usize, 0usize);
        for (key, name) in items {
            let text = fit_text(
                name,
                width.saturating_sub(KEY_WIDTH + KEY_GAP),
                LEGEND_SCALE,
            );
            let w = KEY_WIDTH + KEY_GAP + text_width(&text, LEGEND_SCALE);
            if x > 0 && x + w > width {
                x = 0;
                row += 1;
            }
            legend.push(Entry { x, row, key, text });
            x += w + ENTRY_GAP;
        }
        let legend_rows = if legend.is_empty() { 0 } else { row + 1 };

        let skipped = total - shown.len();
        let note = (skipped > 0).then(|| {
            let what = if spec.x_log || spec.y_log {
                "not finite, or <= 0 on a log axis"
            } else {
                "not finite"
            };
            let points = if skipped == 1 { "point" } else { "points" };
            fit_text(
                &format!("{skipped} {points} not drawn: {what}"),
                width,
                SMALL_SCALE,
            )
        });

        let below = TICK_LEN
            + TICK_GAP
            + CAP_ROWS * TICK_SCALE
            + GAP
            + CAP_ROWS * AXIS_SCALE
            + GAP
            + legend_rows * LEGEND_ROW
            + note.as_ref().map_or(0, |_| CAP_ROWS * SMALL_SCALE + GAP);
        let height = plot_top + PLOT_HEIGHT + 1 + below;
        Self {
            spec,
            axes,
            x_ticks,
            y_ticks,
            plot_left,
            plot_top,
            legend,
            legend_rows,
            note,
            width,
            height,
        }
    }
}

impl Panel for ScatterLayout<'_> {
    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn draw(&self, c: &mut Canvas, ox: usize, oy: usize) {
        let spec = self.spec;
        let (left, top) = (ox + self.plot_left, oy + self.plot_top);
        let (right, bottom) = (left + PLOT_WIDTH - 1, top + PLOT_HEIGHT - 1);
        let centre_x = left + PLOT_WIDTH / 2;

        text_centred(
            c,
            centre_x,
            oy,
            spec.title,
            PANEL_TITLE_SCALE,
            (ox, self.width),
        );
        let y_label_y = oy + CAP_ROWS * PANEL_TITLE_SCALE + GAP;
        let y_label = fit_text(spec.y_label, self.width, AXIS_SCALE);
        c.text(ox, y_label_y, &y_label, AXIS_SCALE, INK);

        let x_tick_y = bottom + 2 + TICK_LEN + TICK_GAP;
        let x_label_y = x_tick_y + CAP_ROWS * TICK_SCALE + GAP;
        text_centred(
            c,
            centre_x,
            x_label_y,
            spec.x_label,
            AXIS_SCALE,
            (ox, self.width),
        );

        if let Some((ax, ay)) = self.axes {
            let px = |t: f64| left as f64 + ax.frac(t) * (PLOT_WIDTH - 1) as f64;
            let py = |t: f64| bottom as f64 - ay.frac(t) * (PLOT_HEIGHT - 1) as f64;
            // Grid and ticks.
            for t in &self.x_ticks {
                let x = px(t.at).round() as usize;
                if !t.minor {
                    c.fill(x, top, 1, PLOT_HEIGHT, GRID);
                }
                let len = if t.minor { MINOR_TICK_LEN } else { TICK_LEN };
                let (xf, yf) = (x as f64, (bottom + 2) as f64);
                c.line(xf, yf, xf, yf + (len - 1) as f64, FRAME_INK);
                if let Some(label) = &t.label {
                    let w = text_width(label, TICK_SCALE);
                    c.text(x.saturating_sub(w / 2), x_tick_y, label, TICK_SCALE, INK);
                }
            }
            for t in &self.y_ticks {
                let y = py(t.at).round() as usize;
                if !t.minor {
                    c.fill(left, y, PLOT_WIDTH, 1, GRID);
                }
                let len = if t.minor { MINOR_TICK_LEN } else { TICK_LEN };
                let (xf, yf) = ((left - 2) as f64, y as f64);
                c.line(xf, yf, xf - (len - 1) as f64, yf, FRAME_INK);
                if let Some(label) = &t.label {
                    let w = text_width(label, TICK_SCALE);
                    let x = left.saturating_sub(1 + TICK_LEN + TICK_GAP + w);
                    let ty = y.saturating_sub(CAP_ROWS * TICK_SCALE / 2);
                    c.text(x, ty, label, TICK_SCALE, INK);
                }
            }
            let to_px = |p: &(f64, f64)| {
                let x = Axis::to_axis(p.0, ax.log)?;
                let y = Axis::to_axis(p.1, ay.log)?;
                Some((px(x), py(y)))
            };

            // The Pareto front under the points, its rings over them.
            let mut rings = Vec::new();
            if spec.pareto {
                // Over the drawn points: a point off a log axis cannot be shown, so it
                // should not hide the points it dominates either.
                let shown: Vec<(f64, f64)> = spec
                    .series
                    .iter()
                    .flat_map(|s| s.points.iter())
                    .filter(|p| to_px(p).is_some())
                    .copied()
                    .collect();
                let front: Vec<(f64, f64)> = pareto_front(&shown)
                    .iter()
                    .filter_map(|&i| shown.get(i).and_then(to_px))
                    .collect();
                for pair in front.windows(2) {
                    let ((x0, y0), (x1, y1)) = (pair[0], pair[1]);
                    c.thick_line(x0, y0, x1, y0, 2, PARETO_INK);
                    c.thick_line(x1, y0, x1, y1, 2, PARETO_INK);
                }
                rings = front;
            }
            for (i, s) in spec.series.iter().enumerate() {
                let (colour, shape) = series_style(i);
                for (x, y) in s.points.iter().filter_map(to_px) {
                    c.marker(x, y, shape, MARKER_RADIUS, Some(colour), darker(colour));
                }
            }
            for &(x, y) in &rings {
                c.ring(x, y, RING_RADIUS, 2, PARETO_INK);
            }

            // Point labels, kept inside the plot area and clear of each other.
            let bounds = (left + 1, top + 1, right, bottom);
            let mut placed: Vec<Rect> = Vec::new();
            for s in spec.series {
                let Some(labels) = s.labels else { continue };
                for (p, label) in s.points.iter().zip(labels) {
                    if label.is_empty() {
                        continue;
                    }
                    let Some((x, y)) = to_px(p) else { continue };
                    if let Some(r) = place_label(x, y, label, bounds, &placed) {
                        c.text(r.x, r.y, label, SMALL_SCALE, INK);
                        placed.push(r);
                    }
                }
            }
        } else {
            c.message_box(left, top, PLOT_WIDTH, PLOT_HEIGHT, "no data");
        }
        c.frame(
            left - 1,
            top - 1,
            PLOT_WIDTH + 2,
            PLOT_HEIGHT + 2,
            FRAME_INK,
        );

        // Legend and note.
        let legend_y = x_label_y + CAP_ROWS * AXIS_SCALE + GAP;
        for e in &self.legend {
            let x = ox + e.x;
            let y = legend_y + e.row * LEGEND_ROW;
            let (kx, ky) = (
                (x + KEY_WIDTH / 2) as f64,
                (y + CAP_ROWS * LEGEND_SCALE / 2) as f64,
            );
            match e.key {
                Key::Marker(colour, shape) => {
                    c.marker(
                        kx,
                        ky,
                        shape,
                        MARKER_RADIUS + 1,
                        Some(colour),
                        darker(colour),
                    );
                }
                Key::Front => {
                    c.thick_line(x as f64, ky, (x + KEY_WIDTH - 1) as f64, ky, 2, PARETO_INK);
                    c.ring(kx, ky, RING_RADIUS, 2, PARETO_INK);
                }
            }
            c.text(x + KEY_WIDTH + KEY_GAP, y, &e.text, LEGEND_SCALE, INK);
        }
        if let Some(note) = &self.note {
            let y = legend_y + self.legend_rows * LEGEND_ROW + GAP / 2;
            c.text(ox, y, note, SMALL_SCALE, NOTE_INK);
        }
    }
}

/// A rectangle of pixels.
#[derive(Clone, Copy, Debug)]
struct Rect {
    /// Left edge.
    x: usize,
    /// Top edge.
    y: usize,
    /// Width.
    w: usize,
    /// Height.
    h: usize,
}

impl Rect {
    /// Whether the two rectangles share a pixel.
    fn overlaps(&self, o: &Rect) -> bool {
        self.x < o.x + o.w && o.x < self.x + self.w && self.y < o.y + o.h && o.y < self.y + self.h
    }
}

/// Where to write `label` beside the point at `(x, y)`: the first of right-above,
/// right-below, left-above, left-below that lies inside `(left, top, right, bottom)` and
/// clear of `placed`; `None` if none does.
fn place_label(
    x: f64,
    y: f64,
    label: &str,
    (left, top, right, bottom): (usize, usize, usize, usize),
    placed: &[Rect],
) -> Option<Rect> {
    let w = text_width(label, SMALL_SCALE);
    let h = CAP_ROWS * SMALL_SCALE;
    // Clear of a Pareto ring, not only of the marker.
    let off = (RING_RADIUS - 1) as f64;
    let (w_f, h_f) = (w as f64, h as f64);
    [
        (x + off, y - off - h_f),
        (x + off, y + off),
        (x - off - w_f, y - off - h_f),
        (x - off - w_f, y + off),
    ]
    .into_iter()
    .filter(|&(lx, ly)| {
        lx >= left as f64
            && ly >= top as f64
            && lx + w_f <= right as f64
            && ly + h_f <= bottom as f64
    })
    .map(|(lx, ly)| Rect {
        x: lx.round() as usize,
        y: ly.round() as usize,
        // One pixel of air around each label.
        w: w + 1,
        h: h + 1,
    })
    .find(|r| !placed.iter().any(|p| p.overlaps(r)))
}

// ---------------------------------------------------------------------------------------
// Heat-map panels.

/// A heat-map panel, measured and validated.
struct HeatLayout<'a> {
    /// What to draw.
    spec: &'a HeatMap<'a>,
    /// The colour range in colour units (`log10` of the value when `log`); `None` when no
    /// value can be coloured.
    range: Option<(f64, f64)>,
    /// Cell size.
    cell_w: usize,
    /// Cell size.
    cell_h: usize,
    /// Font scale of the cells' text (0 for none).
    cell_scale: usize,
    /// Column labels to draw (thinned).
    x_labels: Vec<(usize, &'a str)>,
    /// Row labels to draw (thinned).
    y_labels: Vec<(usize, &'a str)>,
    /// Colour-bar labels, top (max) to bottom (min).
    bar_labels: Vec<String>,
    /// Left edge of the map, from the panel's left edge.
    map_left: usize,
    /// Top edge of the map, from the panel's top.
    map_top: usize,
    /// Whether some value is not finite (then a note explains the grey).
    any_missing: bool,
    /// Panel size.
    width: usize,
    /// Panel size.
    height: usize,
}

impl<'a> HeatLayout<'a> {
    /// Validates and measures `spec`.
    fn new(spec: &'a HeatMap<'a>) -> Result<Self, PreviewError> {
        let (cols, rows) = (spec.cols, spec.rows);
        check_size(cols, rows, spec.values.len())?;
        for (axis, ticks, n) in [("x", spec.x_ticks, cols), ("y", spec.y_ticks, rows)] {
            if !ticks.is_empty() && ticks.len() != n {
                return Err(PreviewError::TickCount {
                    axis,
                    expected: n,
                    actual: ticks.len(),
                });
            }
        }
        let range = heat_range(spec)?;
        let too_large = || PreviewError::TooLarge {
            width: cols,
            height: rows,
            scale: 1,
            limit: MAX_PIXELS,
        };

        // Cells fill about PLOT_WIDTH x PLOT_HEIGHT, and hold their text.
        let mut cell_w = (PLOT_WIDTH / cols).max(1);
        let mut cell_h = (PLOT_HEIGHT / rows).max(1);
        let mut cell_scale = 0;
        if spec.cell_text {
            let text_w = spec
                .values
                .iter()
                .filter(|v| v.is_finite())
                .map(|&v| text_width(&format_sig(v, 3), 1))
                .max()
                .unwrap_or(0);
            cell_scale = if cell_w >= 2 * text_w + 16 && cell_h >= 2 * CAP_ROWS + 8 {
                2
            } else {
                1
            };
            cell_w = cell_w.max(text_w + 4);
            cell_h = cell_h.max(CAP_ROWS + 4);
        }
        let map_w = cols.checked_mul(cell_w).ok_or_else(too_large)?;
        let map_h = rows.checked_mul(cell_h).ok_or_else(too_large)?;
        if map_w.checked_mul(map_h).is_none_or(|n| n > MAX_PIXELS) {
            return Err(too_large());
        }

        // Tick labels, thinned so that they do not touch.
        let thin = |ticks: &'a [String], cell: usize, extent: &dyn Fn(&str) -> usize| {
            let pos: Vec<f64> = (0..ticks.len())
                .map(|i| (i * cell) as f64 + cell as f64 / 2.0)
                .collect();
            let size: Vec<usize> = ticks.iter().map(|s| extent(s)).collect();
            let stride = label_stride(&pos, &size);
            ticks
                .iter()
                .enumerate()
                .step_by(stride)
                .map(|(i, s)| (i, s.as_str()))
                .collect::<Vec<_>>()
        };
        let x_labels = thin(spec.x_ticks, cell_w, &|s| text_width(s, TICK_SCALE));
        let y_labels = thin(spec.y_ticks, cell_h, &|_| CAP_ROWS * TICK_SCALE);

        let bar_labels: Vec<String> = match range {
            Some((lo, hi)) => {
                let mid = lo * 0.5 + hi * 0.5;
                if spec.log {
                    [hi, mid, lo]
                        .iter()
                        .map(|&t| format_sig(10f64.powf(t), 3))
                        .collect()
                } else {
                    let decimals = tick_decimals(hi - lo);
                    [hi, mid, lo]
                        .iter()
                        .map(|&v| format_value(v, decimals))
                        .collect()
                }
            }
            None => Vec::new(),
        };

        // Horizontal layout.
        let y_label_w = y_labels
            .iter()
            .map(|(_, s)| text_width(s, TICK_SCALE))
            .max()
            .unwrap_or(0);
        let x_label_w = |i: Option<&(usize, &str)>| i.map_or(0, |(_, s)| text_width(s, TICK_SCALE));
        let first_overhang = (x_label_w(x_labels.first()) / 2).saturating_sub(cell_w / 2);
        let map_left = if y_labels.is_empty() {
            0
        } else {
            y_label_w + TICK_LEN + TICK_GAP
        }
        .max(first_overhang)
        .max(1);
        let map_right = map_left + map_w; // one past the map
        let last_right = x_labels.last().map_or(0, |&(i, s)| {
            (map_left + i * cell_w + cell_w / 2) + text_width(s, TICK_SCALE).div_ceil(2)
        });
        let bar_x = map_right + 1 + BAR_GAP;
        let bar_label_w = bar_labels
            .iter()
            .map(|s| text_width(s, TICK_SCALE))
            .max()
            .unwrap_or(0);
        let unit_w = text_width(spec.unit, AXIS_SCALE);
        let bar_right =
            (bar_x + BAR_WIDTH + 1 + TICK_LEN + TICK_GAP + bar_label_w).max(bar_x + unit_w);
        let width = bar_right.max(last_right).max(map_right + 1);

        // Vertical layout.
        let map_top = HEADER;
        let any_missing = spec.values.iter().any(|v| !v.is_finite());
        let below = TICK_LEN
            + TICK_GAP
            + CAP_ROWS * TICK_SCALE
            + GAP
            + CAP_ROWS * AXIS_SCALE
            + if any_missing { GAP + NOTE_SWATCH } else { 0 };
        let height = map_top + map_h + 1 + CAP_ROWS * TICK_SCALE / 2 + below;
        Ok(Self {
            spec,
            range,
            cell_w,
            cell_h,
            cell_scale,
            x_labels,
            y_labels,
            bar_labels,
            map_left,
            map_top,
            any_missing,
            width,
            height,
        })
    }

    /// The colour of `v`.
    fn colour(&self, v: f64) -> [u8; 3] {
        if !v.is_finite() {
            return NO_DATA;
        }
        let Some((lo, hi)) = self.range else {
            return viridis(0.0);
        };
        let t = if self.spec.log {
            if v > 0.0 {
                v.log10()
            } else {
                return viridis(0.0);
            }
        } else {
            v
        };
        let span = hi * 0.5 - lo * 0.5;
        viridis((t * 0.5 - lo * 0.5) / span)
    }
}

/// Side of the grey swatch before the "no data" note.
const NOTE_SWATCH: usize = 12;

/// The colour range of `spec` in colour units (`log10` of the value when `log`): the
/// given range (validated) or the finite (positive, when `log`) values' extent, widened
/// when it is a single value; `None` when there is nothing to colour by.
fn heat_range(spec: &HeatMap) -> Result<Option<(f64, f64)>, PreviewError> {
    let to_colour = |v: f64| Axis::to_axis(v, spec.log);
    let (lo, hi) = match spec.range {
        Some((low, high)) => {
            let ok = low.is_finite() && high.is_finite() && low <= high && (!spec.log || low > 0.0);
            let bad = PreviewError::InvalidRange { low, high };
            if !ok {
                return Err(bad);
            }
            match (to_colour(low), to_colour(high)) {
                (Some(a), Some(b)) => (a, b),
                _ => return Err(bad),
            }
        }
        None => {
            let extent = spec.values.iter().filter_map(|&v| to_colour(v)).fold(
                None,
                |acc: Option<(f64, f64)>, t| match acc {
                    None => Some((t, t)),
                    Some((lo, hi)) => Some((lo.min(t), hi.max(t))),
                },
            );
            match extent {
                Some(e) => e,
                None => return Ok(None),
            }
        }
    };
    if hi > lo {
        return Ok(Some((lo, hi)));
    }
    let d = if spec.log {
        0.1
    } else if lo == 0.0 {
        1.0
    } else {
        lo.abs() * 0.01
    };
    Ok(Some(((lo - d).max(-f64::MAX), (hi + d).min(f64::MAX))))
}

impl Panel for HeatLayout<'_> {
    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn draw(&self, c: &mut Canvas, ox: usize, oy: usize) {
        let spec = self.spec;
        let (cw, ch) = (self.cell_w, self.cell_h);
        let (map_w, map_h) = (spec.cols * cw, spec.rows * ch);
        let (left, top) = (ox + self.map_left, oy + self.map_top);
        let bottom = top + map_h; // one past the map
        let centre_x = left + map_w / 2;

        text_centred(
            c,
            centre_x,
            oy,
            spec.title,
            PANEL_TITLE_SCALE,
            (ox, self.width),
        );
        let label_y = oy + CAP_ROWS * PANEL_TITLE_SCALE + GAP;
        let y_label = fit_text(spec.y_label, left + map_w - ox, AXIS_SCALE);
        c.text(ox, label_y, &y_label, AXIS_SCALE, INK);

        // Cells, then their text.
        let mut row = vec![0u8; map_w * 3];
        for (r, line) in spec.values.chunks_exact(spec.cols).enumerate() {
            for (px, &v) in row.chunks_exact_mut(cw * 3).zip(line) {
                let colour = self.colour(v);
                for p in px.chunks_exact_mut(3) {
                    p.copy_from_slice(&colour);
                }
            }
            for dy in 0..ch {
                c.put_row(left, top + r * ch + dy, &row);
            }
        }
        if self.cell_scale > 0 {
            let s = self.cell_scale;
            for (i, &v) in spec.values.iter().enumerate() {
                if !v.is_finite() {
                    continue;
                }
                let (r, col) = (i / spec.cols, i % spec.cols);
                let text = format_sig(v, 3);
                let [red, green, blue] = self.colour(v);
                let luma =
                    0.2126 * f64::from(red) + 0.7152 * f64::from(green) + 0.0722 * f64::from(blue);
                let ink = if luma > 110.0 { INK } else { LIGHT_TEXT };
                let x = left + col * cw + (cw.saturating_sub(text_width(&text, s))) / 2;
                let y = top + r * ch + (ch.saturating_sub(CAP_ROWS * s)) / 2;
                c.text(x, y, &text, s, ink);
            }
        }
        if self.range.is_none() {
            c.message_box(left, top, map_w, map_h, "no data");
        }
        c.frame(left - 1, top - 1, map_w + 2, map_h + 2, FRAME_INK);

        // Row and column labels.
        for &(r, label) in &self.y_labels {
            let y = top + r * ch + ch / 2;
            c.fill(left - 1 - TICK_LEN, y, TICK_LEN, 1, FRAME_INK);
            let w = text_width(label, TICK_SCALE);
            let x = left.saturating_sub(1 + TICK_LEN + TICK_GAP + w);
            c.text(
                x,
                y.saturating_sub(CAP_ROWS * TICK_SCALE / 2),
                label,
                TICK_SCALE,
                INK,
            );
        }
        let x_tick_y = bottom + 1 + TICK_LEN + TICK_GAP;
        for &(col, label) in &self.x_labels {
            let x = left + col * cw + cw / 2;
            c.fill(x, bottom + 1, 1, TICK_LEN, FRAME_INK);
            let w = text_width(label, TICK_SCALE);
            c.text(x.saturating_sub(w / 2), x_tick_y, label, TICK_SCALE, INK);
        }
        let x_label_y = x_tick_y + CAP_ROWS * TICK_SCALE + GAP;
        text_centred(
            c,
            centre_x,
            x_label_y,
            spec.x_label,
            AXIS_SCALE,
            (ox, self.width),
        );

        // Colour bar, high values at the top, the unit above it.
        let bar_x = left + map_w + 1 + BAR_GAP;
        c.text(bar_x, label_y, spec.unit, AXIS_SCALE, INK);
        c.colour_bar(bar_x, top, BAR_WIDTH, map_h, self.range.is_some());
        let n = self.bar_labels.len();
        for (i, label) in self.bar_labels.iter().enumerate() {
            let y = top + (i * (map_h - 1)) / (n - 1).max(1);
            c.fill(bar_x + BAR_WIDTH + 1, y, TICK_LEN, 1, FRAME_INK);
            let x = bar_x + BAR_WIDTH + 1 + TICK_LEN + TICK_GAP;
            c.text(
                x,
                y.saturating_sub(CAP_ROWS * TICK_SCALE / 2),
                label,
                TICK_SCALE,
                INK,
            );
        }

        // "no data" note with a grey swatch.
        if self.any_missing {
            let y = x_label_y + CAP_ROWS * AXIS_SCALE + GAP;
            c.fill(ox, y, NOTE_SWATCH, NOTE_SWATCH, NO_DATA);
            c.frame(ox, y, NOTE_SWATCH, NOTE_SWATCH, FRAME_INK);
            let ty = y + (NOTE_SWATCH - CAP_ROWS * SMALL_SCALE) / 2;
            c.text(
                ox + NOTE_SWATCH + KEY_GAP,
                ty,
                "grey = no data",
                SMALL_SCALE,
                NOTE_INK,
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_drops_dominated_points() {
        let pts = [
            (1.0, 5.0),
            (2.0, 3.0),
            (3.0, 4.0),
            (4.0, 1.0),
            (2.5, 3.0),
            (5.0, 0.5),
        ];
        assert_eq!(pareto_front(&pts), vec![0, 1, 3, 5]);
        assert_eq!(pareto_front(&[]), Vec::<usize>::new());
        assert_eq!(pareto_front(&[(3.0, -2.0)]), vec![0]);
        // One point dominating all others.
        assert_eq!(pareto_front(&[(2.0, 2.0), (0.0, 0.0), (1.0, 3.0)]), vec![1]);
    }

    #[test]
    fn pareto_front_ties() {
        // Same x: only the smaller y survives; same y: only the smaller x.
        assert_eq!(pareto_front(&[(1.0, 2.0), (1.0, 1.0)]), vec![1]);
        assert_eq!(pareto_front(&[(2.0, 1.0), (1.0, 1.0)]), vec![1]);
        // Exact copies do not dominate each other; -0.0 equals 0.0.
        assert_eq!(
            pareto_front(&[(1.0, 1.0), (0.0, 3.0), (1.0, 1.0)]),
            vec![1, 0, 2]
        );
        assert_eq!(pareto_front(&[(-0.0, 1.0), (0.0, 0.5)]), vec![1]);
    }

    #[test]
    fn pareto_front_skips_non_finite_points() {
        let pts = [
            (f64::NAN, 0.0),
            (1.0, 1.0),
            (0.0, f64::NEG_INFINITY),
            (f64::INFINITY, -5.0),
            (2.0, 0.5),
        ];
        assert_eq!(pareto_front(&pts), vec![1, 4]);
        assert!(pareto_front(&[(f64::NAN, f64::NAN)]).is_empty());
    }

    #[test]
    fn numbers_are_formatted_compactly() {
        assert_eq!(format_sig(412.345, 3), "412");
        assert_eq!(format_sig(1.5, 3), "1.5");
        assert_eq!(format_sig(-0.012345, 3), "-0.0123");
        assert_eq!(format_sig(150_000.0, 3), "1.5e5");
        assert_eq!(format_sig(0.00002, 3), "2e-5");
        assert_eq!(format_sig(0.0, 3), "0");
        assert_eq!(format_sig(f64::NAN, 3), "NaN");
        assert_eq!(log_tick_label(1, -1), "0.1");
        assert_eq!(log_tick_label(1, 0), "1");
        assert_eq!(log_tick_label(1, 1), "10");
        assert_eq!(log_tick_label(1, 3), "1e3");
        assert_eq!(log_tick_label(5, -2), "0.05");
        assert_eq!(log_tick_label(2, -4), "2e-4");
        assert_eq!(
            linear_tick_labels(&[0.0, 0.5, 1.0], 0.5),
            ["0.0", "0.5", "1.0"]
        );
        assert_eq!(
            linear_tick_labels(&[-20.0, 0.0, 20.0], 20.0),
            ["-20", "0", "20"]
        );
        assert_eq!(linear_tick_labels(&[2e5, 4e5], 2e5), ["2e5", "4e5"]);
        assert_eq!(linear_tick_labels(&[1.5e5, 2e5], 5e4), ["1.5e5", "2e5"]);
        assert_eq!(linear_tick_labels(&[0.0, 2e-4], 2e-4), ["0", "2e-4"]);
    }

    #[test]
    fn ticks_are_nice() {
        let labels =
            |a: Axis| -> Vec<String> { a.ticks().into_iter().filter_map(|t| t.label).collect() };
        let lin = Axis {
            lo: -0.1,
            hi: 1.1,
            log: false,
        };
        assert_eq!(labels(lin), ["0.0", "0.2", "0.4", "0.6", "0.8", "1.0"]);
        let decades = Axis {
            lo: -1.2,
            hi: 3.3,
            log: true,
        };
        assert_eq!(labels(decades), ["0.1", "1", "10", "100", "1e3"]);
        let few = Axis {
            lo: 0.0,
            hi: 1.5,
            log: true,
        };
        assert_eq!(labels(few), ["1", "2", "5", "10", "20"]);
        let narrow = Axis {
            lo: 2.0_f64.log10(),
            hi: 4.0_f64.log10(),
            log: true,
        };
        assert!(labels(narrow).len() >= 3);
        let wide = Axis {
            lo: -300.0,
            hi: 300.0,
            log: true,
        };
        assert!(labels(wide).len() <= 9);
        let extreme = Axis {
            lo: -f64::MAX,
            hi: f64::MAX,
            log: false,
        };
        assert!(labels(extreme).len() <= 9);
    }

    fn decode(png: &[u8]) -> image::DynamicImage {
        image::load_from_memory(png).expect("the renderer produces a valid PNG")
    }

    /// Points.
    type Points = Vec<(f64, f64)>;

    fn demo_scatter() -> (Points, Points, Vec<String>) {
        let a: Vec<(f64, f64)> = (1..=12)
            .map(|i| {
                let x = f64::from(i) * 0.8;
                (x, 40.0 / x + f64::from(i % 3) * 4.0)
            })
            .collect();
        let b = vec![
            (2.0, 9.0),
            (3.5, 5.0),
            (6.0, 3.1),
            (9.0, 4.0),
            (f64::NAN, 1.0),
        ];
        let labels: Vec<String> = (0..a.len()).map(|i| format!("r{i}")).collect();
        (a, b, labels)
    }

    #[test]
    fn scatter_renders_a_png_of_the_expected_size() {
        let (a, b, labels) = demo_scatter();
        let series = [
            Series {
                name: "Tracker",
                points: &a,
                labels: Some(&labels),
            },
            Series {
                name: "Brute force",
                points: &b,
                labels: None,
            },
        ];
        let panel = Scatter {
            title: "Error vs time",
            x_label: "time per pixel (ms)",
            y_label: "RMS error (nm)",
            x_log: false,
            y_log: false,
            series: &series,
            pareto: true,
        };
        let one = decode(&render_scatter_panels_png("Methods", &[panel]).expect("renders"));
        assert!(one.width() as usize > PLOT_WIDTH && (one.width() as usize) < PLOT_WIDTH + 300);
        assert!(one.height() as usize > PLOT_HEIGHT && (one.height() as usize) < PLOT_HEIGHT + 300);
        let two = decode(&render_scatter_panels_png("Methods", &[panel, panel]).expect("renders"));
        assert!(two.width() as usize > 2 * PLOT_WIDTH + PANEL_GAP);
        assert_eq!(two.height(), one.height());
    }

    #[test]
    fn scatter_never_panics_on_odd_input() {
        let pts = [
            (-1.0, 0.0),
            (0.0, 5.0),
            (1e-300, 1e300),
            (f64::MAX, -f64::MAX),
            (3.0, 3.0),
        ];
        let nan = [(f64::NAN, f64::NAN), (f64::INFINITY, 1.0)];
        let one = [(2.0, 2.0)];
        let labels = vec![String::new(); 9];
        let series = [
            Series {
                name: "odd",
                points: &pts,
                labels: Some(&labels),
            },
            Series {
                name: "nan",
                points: &nan,
                labels: None,
            },
            Series {
                name: "one",
                points: &one,
                labels: Some(&[]),
            },
            Series {
                name: "",
                points: &[],
                labels: None,
            },
        ];
        for (x_log, y_log, pareto) in [
            (true, true, true),
            (false, true, false),
            (true, false, true),
            (false, false, true),
        ] {
            let panel = Scatter {
                title: "",
                x_label: "",
                y_label: "",
                x_log,
                y_log,
                series: &series,
                pareto,
            };
            decode(&render_scatter_panels_png("odd", &[panel]).expect("renders"));
        }
        for series in [&series[1..2], &series[2..3], &series[3..], &[]] {
            let panel = Scatter {
                title: "t",
                x_label: "x",
                y_label: "y",
                x_log: true,
                y_log: false,
                series,
                pareto: true,
            };
            decode(&render_scatter_panels_png("", &[panel]).expect("renders"));
        }
        assert!(matches!(
            render_scatter_panels_png("none", &[]),
            Err(PreviewError::NoPanels)
        ));
    }

    #[test]
    fn heatmap_renders_and_checks_sizes() {
        let values: Vec<f64> = (0..24).map(|i| f64::from(i) * 1.7 + 3.0).collect();
        let xt: Vec<String> = (0..6).map(|i| format!("{}", i * 10)).collect();
        let yt: Vec<String> = (0..4).map(|i| format!("row {i}")).collect();
        let map = HeatMap {
            title: "Error",
            x_label: "angle step",
            y_label: "pixels",
            x_ticks: &xt,
            y_ticks: &yt,
            cols: 6,
            rows: 4,
            values: &values,
            unit: "nm",
            range: None,
            log: false,
            cell_text: true,
        };
        let img = decode(&render_heatmap_panels_png("Heat", &[map, map]).expect("renders"));
        assert!(
            img.width() as usize > 2 * PLOT_WIDTH && (img.width() as usize) < 2 * PLOT_WIDTH + 500
        );
        assert!(img.height() as usize > PLOT_HEIGHT && (img.height() as usize) < PLOT_HEIGHT + 300);

        let short = HeatMap {
            values: &values[..23],
            ..map
        };
        assert!(matches!(
            render_heatmap_panels_png("", &[short]),
            Err(PreviewError::SizeMismatch { .. })
        ));
        let empty = HeatMap {
            cols: 0,
            values: &[],
            ..map
        };
        assert!(matches!(
            render_heatmap_panels_png("", &[empty]),
            Err(PreviewError::Empty { .. })
        ));
        let ticks = HeatMap {
            x_ticks: &yt,
            ..map
        };
        assert!(matches!(
            render_heatmap_panels_png("", &[ticks]),
            Err(PreviewError::TickCount { axis: "x", .. })
        ));
        let reversed = HeatMap {
            range: Some((5.0, 1.0)),
            ..map
        };
        assert!(matches!(
            render_heatmap_panels_png("", &[reversed]),
            Err(PreviewError::InvalidRange { .. })
        ));
        let log_zero = HeatMap {
            range: Some((0.0, 1.0)),
            log: true,
            ..map
        };
        assert!(matches!(
            render_heatmap_panels_png("", &[log_zero]),
            Err(PreviewError::InvalidRange { .. })
        ));
        assert!(matches!(
            render_heatmap_panels_png("", &[]),
            Err(PreviewError::NoPanels)
        ));
        let huge = HeatMap {
            cols: 1 << 40,
            rows: 1 << 40,
            ..map
        };
        assert!(render_heatmap_panels_png("", &[huge]).is_err());
    }

    #[test]
    fn heatmap_never_panics_on_odd_values() {
        let odd = [
            f64::NAN,
            -1.0,
            0.0,
            1e-300,
            f64::INFINITY,
            1e300,
            -f64::MAX,
            5.0,
            f64::NAN,
        ];
        let nan = [f64::NAN; 9];
        let flat = [7.0; 9];
        for values in [&odd[..], &nan[..], &flat[..]] {
            for log in [false, true] {
                for cell_text in [false, true] {
                    let map = HeatMap {
                        title: "odd",
                        x_label: "",
                        y_label: "",
                        x_ticks: &[],
                        y_ticks: &[],
                        cols: 3,
                        rows: 3,
                        values,
                        unit: "",
                        range: None,
                        log,
                        cell_text,
                    };
                    decode(&render_heatmap_panels_png("", &[map]).expect("renders"));
                }
            }
        }
        // Many columns: labels thinned, cells one pixel wide.
        let values: Vec<f64> = (0..2000).map(f64::from).collect();
        let xt: Vec<String> = (0..1000).map(|i| format!("{i}")).collect();
        let map = HeatMap {
            title: "",
            x_label: "",
            y_label: "",
            x_ticks: &xt,
            y_ticks: &[],
            cols: 1000,
            rows: 2,
            values: &values,
            unit: "",
            range: None,
            log: false,
            cell_text: false,
        };
        decode(&render_heatmap_panels_png("", &[map]).expect("renders"));
    }
    #[test]
    fn writers_write_decodable_files() {
        let dir = tempfile::tempdir().expect("can create a temporary directory");
        let pts = [(1.0, 2.0), (2.0, 1.0)];
        let series = [Series {
            name: "a",
            points: &pts,
            labels: None,
        }];
        let panel = Scatter {
            title: "t",
            x_label: "x",
            y_label: "y",
            x_log: false,
            y_log: false,
            series: &series,
            pareto: true,
        };
        let path = dir.path().join("scatter.png");
        write_scatter_panels_png(&path, "T", &[panel]).expect("writes");
        decode(&std::fs::read(&path).expect("file exists"));
        let values = [1.0, 2.0, 3.0, f64::NAN];
        let map = HeatMap {
            title: "h",
            x_label: "",
            y_label: "",
            x_ticks: &[],
            y_ticks: &[],
            cols: 2,
            rows: 2,
            values: &values,
            unit: "nm",
            range: Some((0.0, 4.0)),
            log: false,
            cell_text: true,
        };
        let path = dir.path().join("heat.png");
        write_heatmap_panels_png(&path, "H", &[map]).expect("writes");
        decode(&std::fs::read(&path).expect("file exists"));
        let missing = dir.path().join("no such dir").join("x.png");
        assert!(matches!(
            write_heatmap_panels_png(&missing, "H", &[map]),
            Err(PreviewError::Write { .. })
        ));
    }

    /// Writes example figures for a visual check to `$FILMSCOPE_PLOT_CHECK` (default
    /// `<temp dir>/plot-check`): `cargo test --lib plot -- --ignored`.
    #[test]
    #[ignore = "writes example PNGs for a visual check"]
    fn write_examples_for_visual_check() {
        let dir = std::env::var_os("FILMSCOPE_PLOT_CHECK")
            .map_or_else(|| std::env::temp_dir().join("plot-check"), Into::into);
        std::fs::create_dir_all(&dir).expect("can create the output directory");

        let (a, b, labels) = demo_scatter();
        let methods = [
            Series {
                name: "Tracker",
                points: &a,
                labels: Some(&labels),
            },
            Series {
                name: "Brute force",
                points: &b,
                labels: None,
            },
        ];
        let linear = Scatter {
            title: "Error vs time, linear axes",
            x_label: "time per pixel (ms)",
            y_label: "RMS thickness error (nm)",
            x_log: false,
            y_log: false,
            series: &methods,
            pareto: true,
        };
        let t: Vec<(f64, f64)> = (0..9)
            .map(|i| {
                let x = 10f64.powf(f64::from(i) * 0.45 - 1.3);
                (x, 300.0 / (1.0 + x * x).sqrt() + f64::from(i % 2) * 40.0)
            })
            .collect();
        let u = vec![
            (0.02, 900.0),
            (0.5, 20.0),
            (8.0, 3.0),
            (60.0, 0.8),
            (0.0, 5.0),
            (-1.0, 2.0),
        ];
        let v = vec![(3.0, 50.0), (200.0, 0.3)];
        let names: Vec<String> = (0..t.len()).map(|i| format!("cfg {i}")).collect();
        let three = [
            Series {
                name: "paper",
                points: &t,
                labels: Some(&names),
            },
            Series {
                name: "tracker (fast)",
                points: &u,
                labels: None,
            },
            Series {
                name: "GN refine",
                points: &v,
                labels: None,
            },
        ];
        let log = Scatter {
            title: "Log-log",
            x_label: "time (s)",
            y_label: "error (nm)",
            x_log: true,
            y_log: true,
            series: &three,
            pareto: true,
        };
        write_scatter_panels_png(
            &dir.join("scatter.png"),
            "Speed vs accuracy",
            &[linear, log],
        )
        .expect("writes");
        let nothing = Scatter {
            title: "Empty",
            series: &[],
            pareto: true,
            ..linear
        };
        write_scatter_panels_png(&dir.join("scatter-empty.png"), "No data", &[nothing])
            .expect("writes");

        let mut values: Vec<f64> = (0..6 * 5)
            .map(|i| {
                let (r, c) = (f64::from(i / 6), f64::from(i % 6));
                0.8 + 0.35 * r * r + 2.1 * c + 0.05 * r * c
            })
            .collect();
        values[7] = f64::NAN;
        let xt: Vec<String> = [0.05, 0.1, 0.2, 0.5, 1.0, 2.0]
            .iter()
            .map(|v| format!("{v}"))
            .collect();
        let yt: Vec<String> = [8, 16, 32, 64, 128]
            .iter()
            .map(|v| format!("{v} px"))
            .collect();
        let text = HeatMap {
            title: "RMS error, row 0 at the top",
            x_label: "angle step (deg)",
            y_label: "window",
            x_ticks: &xt,
            y_ticks: &yt,
            cols: 6,
            rows: 5,
            values: &values,
            unit: "nm",
            range: None,
            log: false,
            cell_text: true,
        };
        let wide: Vec<f64> = (0..40 * 30)
            .map(|i| {
                let (r, c) = (f64::from(i / 40), f64::from(i % 40));
                10f64.powf((r - 15.0) / 8.0 + (c - 20.0) / 20.0)
            })
            .collect();
        let wxt: Vec<String> = (0..40).map(|i| format!("{}", i * 25)).collect();
        let wyt: Vec<String> = (0..30)
            .map(|i| format!("{:.2}", 1.3 + f64::from(i) * 0.02))
            .collect();
        let logmap = HeatMap {
            title: "Log colours, 40 x 30",
            x_label: "thickness (nm)",
            y_label: "index",
            x_ticks: &wxt,
            y_ticks: &wyt,
            cols: 40,
            rows: 30,
            values: &wide,
            unit: "ms",
            range: None,
            log: true,
            cell_text: false,
        };
        write_heatmap_panels_png(&dir.join("heatmap.png"), "Parameter sweep", &[text, logmap])
            .expect("writes");

        // Edge cases: a narrow log axis, large linear values, one point, many series.
        let narrow: Vec<(f64, f64)> = (0..8)
            .map(|i| (2.0e6 + f64::from(i) * 1.3e5, 210.0 + f64::from(i * i) * 2.5))
            .collect();
        let single = [(2.4e6, 260.0)];
        let many: Vec<Vec<(f64, f64)>> = (0..12)
            .map(|k| vec![(2.1e6 + f64::from(k) * 7e4, 330.0 - f64::from(k) * 6.0)])
            .collect();
        let many_names: Vec<String> = (0..12).map(|k| format!("s{k}")).collect();
        let mut edge_series = vec![
            Series {
                name: "narrow",
                points: &narrow,
                labels: None,
            },
            Series {
                name: "single",
                points: &single,
                labels: None,
            },
        ];
        for (pts, name) in many.iter().zip(&many_names) {
            edge_series.push(Series {
                name,
                points: pts,
                labels: None,
            });
        }
        let edge = Scatter {
            title: "A rather long panel title that will not fit across the panel at all",
            x_label: "pixels per second",
            y_label: "latency (us), log",
            x_log: false,
            y_log: true,
            series: &edge_series,
            pareto: true,
        };
        let lone = [Series {
            name: "one point",
            points: &single,
            labels: None,
        }];
        let one = Scatter {
            title: "One point",
            series: &lone,
            x_log: true,
            ..edge
        };
        write_scatter_panels_png(&dir.join("scatter-edge.png"), "Edge cases", &[edge, one])
            .expect("writes");

        let nan = [f64::NAN; 12];
        let all_nan = HeatMap {
            title: "All NaN",
            x_ticks: &[],
            y_ticks: &[],
            cols: 4,
            rows: 3,
            values: &nan,
            cell_text: true,
            ..text
        };
        let strip: Vec<f64> = (0..8).map(|i| f64::from(i) * 1e-5 - 2e-5).collect();
        let long_ticks: Vec<String> = (0..8).map(|i| format!("config {i}")).collect();
        let one_row = HeatMap {
            title: "One row, long labels",
            x_ticks: &long_ticks,
            y_ticks: &[],
            cols: 8,
            rows: 1,
            values: &strip,
            unit: "",
            cell_text: true,
            ..text
        };
        write_heatmap_panels_png(&dir.join("heatmap-edge.png"), "", &[all_nan, one_row])
            .expect("writes");
    }
}
