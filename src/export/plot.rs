//! Charts as PNG: scatter plots (with an optional Pareto front) and heat maps, several
//! panels side by side under a figure title, drawn with `plotters` on an RGB buffer and
//! encoded with `image`. Text is set in the embedded DejaVu Sans (`fonts/`, through
//! `ab_glyph`), so no system font or library is involved.
//!
//! A scatter panel ([`render_scatter_panels_png`]) has its title above a
//! [`PLOT_WIDTH`] x [`PLOT_HEIGHT`] plot area with light grid lines, the axis labels
//! beside the axes and the legend (and a note on points not drawn) below:
//!
//! - Axis ranges cover the drawable points plus a 5% margin on each side (on a log axis,
//!   5% of the decades spanned); a single value is widened to a visible range.
//! - Linear axes get "nice" ticks, 1, 2 or 5 times a power of ten apart. Log axes get
//!   ticks at powers of ten, labelled `0.01`, `0.1`, `1`, `10`, `100`, then `1e3`,
//!   `1e-3`, ... (every n-th power when they span more than eight decades, else each
//!   power, with grid lines at 2..9 times it); over less than three decades 2 and 5 times
//!   the powers are labelled too (`2`, `5`, `20`, `2e3`), and over less than one decade
//!   the ticks are linear ones placed logarithmically. Tick labels that would touch are
//!   thinned to every second, third, ... tick.
//! - Series are told apart by colour (the Tableau 10 palette, in order) and marker shape
//!   (circle, square, diamond, triangles).
//! - Points that cannot be drawn (a non-finite coordinate, or a value <= 0 on a log axis)
//!   are left out and counted in the note. A panel without a drawable point still
//!   renders: an empty frame with "no data" in it.
//! - Point labels are drawn small beside their point, on whichever side keeps them inside
//!   the plot area and clear of the labels already placed; a label that fits nowhere is
//!   left out rather than drawn over another.
//! - The Pareto front, taken over the drawn points of all series together, is a black
//!   staircase with its points ringed.
//!
//! A heat-map panel ([`render_heatmap_panels_png`]) is a grid of cells coloured with
//! [`viridis`], row 0 at the top (like a printed table), column 0 at the left, with its
//! colour bar to the right (labelled at its ends and middle: the range's midpoint, or with
//! `log` the geometric mean of the ends):
//!
//! - `x_ticks` label column centres, `y_ticks` row centres; each is either empty (no
//!   labels) or one label per column (row), thinned if they would touch.
//! - Cells are sized to fill about [`PLOT_WIDTH`] x [`PLOT_HEIGHT`] (at least one pixel,
//!   and big enough for the cell's text when `cell_text` is set).
//! - Non-finite values are drawn in the "no data" grey [`NO_DATA`], with a note under the
//!   panel; a heat map without a finite value still renders ("no data" across it).
//!
//! No function here panics on any input: a figure without panels, heat-map values that do
//! not fill `rows x cols`, tick-label counts that match neither, invalid colour ranges
//! and images beyond [`MAX_PIXELS`] are reported as [`PreviewError`]s; empty series and
//! all-NaN data render as "no data" panels.

use std::ops::Range;
use std::path::Path;
use std::sync::OnceLock;

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::FontStyle;

use super::canvas::{encode_rgb, write_png};
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
    /// Drawn along the y axis.
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
    /// Drawn along the row labels.
    pub y_label: &'a str,
    /// One label per column (drawn under the column's centre), or empty for none.
    pub x_ticks: &'a [String],
    /// One label per row (drawn left of the row's centre), or empty for none.
    pub y_ticks: &'a [String],
    /// Number of columns.
    pub cols: usize,
    /// Number of rows.
    pub rows: usize,
    /// `rows * cols` values, row-major, row 0 drawn at the top; non-finite = no data.
    pub values: &'a [f64],
    /// Drawn above the colour bar, e.g. "nm"; may be empty.
    pub unit: &'a str,
    /// The values mapped to the two ends of the colour bar, `(low, high)`; `None` uses the
    /// finite (with `log`, positive) values' extent.
    pub range: Option<(f64, f64)>,
    /// Colour by `log10` of the value (values <= 0 get the low end's colour).
    pub log: bool,
    /// Write each cell's value (3 significant digits) in it.
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
/// the top (see the [module docs](self)).
///
/// Errors: [`PreviewError::NoPanels`] for an empty `panels`, [`PreviewError::TooLarge`]
/// if the image would exceed [`MAX_PIXELS`], [`PreviewError::Draw`],
/// [`PreviewError::Encode`].
pub fn render_scatter_panels_png(title: &str, panels: &[Scatter]) -> Result<Vec<u8>, PreviewError> {
    font_registered()?;
    let layouts: Vec<ScatterLayout> = panels.iter().map(ScatterLayout::new).collect();
    compose(title, &layouts)
}

/// Renders like [`render_scatter_panels_png`] and writes the PNG to `path` atomically
/// (see [`write_atomic`](crate::io::write_atomic)).
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
/// in memory, `title` across the top (see the [module docs](self)).
///
/// Errors: [`PreviewError::NoPanels`] for an empty `panels`; for any panel,
/// [`PreviewError::Empty`] if it has no cells, [`PreviewError::SizeMismatch`] if
/// `values` does not hold `rows * cols` entries, [`PreviewError::TickCount`] if a tick
/// list is neither empty nor one per column (row), [`PreviewError::InvalidRange`] for a
/// `range` that is not finite with `low <= high` (and `low > 0` when `log`);
/// [`PreviewError::TooLarge`] beyond [`MAX_PIXELS`], [`PreviewError::Draw`],
/// [`PreviewError::Encode`].
pub fn render_heatmap_panels_png(title: &str, panels: &[HeatMap]) -> Result<Vec<u8>, PreviewError> {
    font_registered()?;
    let layouts = panels
        .iter()
        .map(HeatLayout::new)
        .collect::<Result<Vec<_>, _>>()?;
    compose(title, &layouts)
}

/// Renders like [`render_heatmap_panels_png`] and writes the PNG to `path` atomically
/// (see [`write_atomic`](crate::io::write_atomic)).
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
// Fonts, sizes and colours.

/// The font family every text style names; registered with plotters' `ab_glyph` backend.
const FAMILY: &str = "sans-serif";
/// The one font of every picture ([`super::canvas::FONT`]).
const FONT: &[u8] = super::canvas::FONT;

/// Registers [`FONT`] under [`FAMILY`] once; every renderer calls this first.
fn font_registered() -> Result<(), PreviewError> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE
        .get_or_init(|| plotters::style::register_font(FAMILY, FontStyle::Normal, FONT).is_ok());
    ok.then_some(())
        .ok_or_else(|| PreviewError::Draw("the embedded font cannot be read".into()))
}

/// Font sizes in pixels, all even: plotters' `ab_glyph` text sits each glyph at half the
/// size above its baseline, truncated, so an odd size lifts small glyphs like `.` by a
/// pixel.
const FIGURE_TITLE_SIZE: f64 = 26.0;
/// Panel titles.
const PANEL_TITLE_SIZE: f64 = 20.0;
/// Axis labels.
const AXIS_SIZE: f64 = 16.0;
/// Tick labels, legend entries and colour-bar labels.
const TICK_SIZE: f64 = 14.0;
/// Point labels and notes.
const SMALL_SIZE: f64 = 12.0;

/// Space around the whole image.
const MARGIN: usize = 16;
/// Height of a panel's title row.
const CAPTION: usize = 32;
/// Height below a plot area for the x tick labels and the x label.
const X_AREA: usize = 52;
/// Space right of a plot area (so the last x tick label fits).
const RIGHT: usize = 20;
/// Height of a legend row.
const LEGEND_ROW: usize = 24;
/// Height of the note row under a panel.
const NOTE_ROW: usize = 20;
/// Fraction of the data range added on each side of a scatter axis.
const AXIS_MARGIN: f64 = 0.05;
/// Least gap in pixels between two tick labels.
const LABEL_SPACING: f64 = 12.0;
/// Space between a heat map and its colour bar.
const BAR_GAP: usize = 20;
/// Width of a heat map's colour bar.
const BAR_WIDTH: usize = 18;
/// Radius of a data-point marker.
const MARKER_RADIUS: i32 = 4;
/// Radius of the rings round the Pareto front's points.
const RING_RADIUS: i32 = 8;

/// Text colour.
const INK: RGBColor = RGBColor(20, 20, 20);
/// Notes (points not drawn, missing cells).
const NOTE_INK: RGBColor = RGBColor(96, 96, 96);
/// Grid lines at the labelled ticks.
const GRID: RGBColor = RGBColor(225, 225, 225);
/// Grid lines at the other ticks.
const LIGHT_GRID: RGBColor = RGBColor(242, 242, 242);

/// Series colours: Tableau 10 (Tableau's default qualitative palette since 2016).
const PALETTE: [RGBColor; 10] = [
    RGBColor(0x4e, 0x79, 0xa7), // blue
    RGBColor(0xf2, 0x8e, 0x2b), // orange
    RGBColor(0xe1, 0x57, 0x59), // red
    RGBColor(0x76, 0xb7, 0xb2), // teal
    RGBColor(0x59, 0xa1, 0x4f), // green
    RGBColor(0xed, 0xc9, 0x48), // yellow
    RGBColor(0xb0, 0x7a, 0xa1), // purple
    RGBColor(0xff, 0x9d, 0xa7), // pink
    RGBColor(0x9c, 0x75, 0x5f), // brown
    RGBColor(0xba, 0xb0, 0xac), // grey
];

/// A data-point marker's shape.
#[derive(Clone, Copy, Debug)]
enum Marker {
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

/// Marker shapes, cycled through alongside the palette.
const SHAPES: [Marker; 5] = [
    Marker::Circle,
    Marker::Square,
    Marker::Diamond,
    Marker::TriangleUp,
    Marker::TriangleDown,
];

/// The colour and marker shape of series `i`; the shape advances once more per trip round
/// the palette, so that series 0 and 10 differ in shape.
fn series_style(i: usize) -> (RGBColor, Marker) {
    (
        PALETTE[i % PALETTE.len()],
        SHAPES[(i + i / PALETTE.len()) % SHAPES.len()],
    )
}

/// The drawing area of a whole figure.
type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// A text style of `size` pixels in `colour`.
fn font(size: f64, colour: &RGBColor) -> TextStyle<'static> {
    (FAMILY, size).into_font().color(colour)
}

/// The width and height of `text` in `size`, `(0, 0)` if it cannot be measured.
fn text_size(text: &str, size: f64) -> (usize, usize) {
    (FAMILY, size)
        .into_font()
        .box_size(text)
        .map_or((0, 0), |(w, h)| (w as usize, h as usize))
}

/// `text` cut short with "..." to at most `max_w` pixels in `size`.
fn fit(text: &str, size: f64, max_w: usize) -> String {
    if text_size(text, size).0 <= max_w {
        return text.to_string();
    }
    let mut chars: Vec<char> = text.chars().collect();
    while !chars.is_empty() {
        chars.pop();
        let s: String = chars.iter().collect::<String>() + "...";
        if text_size(&s, size).0 <= max_w {
            return s;
        }
    }
    String::new()
}

/// A drawing error as a [`PreviewError`].
fn draw_err(e: impl std::fmt::Display) -> PreviewError {
    PreviewError::Draw(e.to_string())
}

// ---------------------------------------------------------------------------------------
// Figures: panels side by side under a title.

/// A panel whose size is known, ready to be drawn at an offset.
trait Panel {
    /// `(width, height)` in pixels.
    fn size(&self) -> (usize, usize);
    /// Draws the panel with its top-left corner at `(x, y)` of `root`.
    fn draw(&self, root: &Area, x: usize, y: usize) -> Result<(), PreviewError>;
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
    let title_h = if title.is_empty() { 0 } else { 40 };
    let img_w = content_w.saturating_add(2 * MARGIN);
    let img_h = content_h.saturating_add(2 * MARGIN + title_h);
    let too_large = PreviewError::TooLarge {
        width: img_w,
        height: img_h,
        scale: 1,
        limit: MAX_PIXELS,
    };
    let (Ok(w32), Ok(h32)) = (u32::try_from(img_w), u32::try_from(img_h)) else {
        return Err(too_large);
    };
    if img_w.checked_mul(img_h).is_none_or(|n| n > MAX_PIXELS) {
        return Err(too_large);
    }
    let mut buf = vec![255u8; img_w * img_h * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w32, h32)).into_drawing_area();
        if !title.is_empty() {
            let text = fit(title, FIGURE_TITLE_SIZE, img_w - 2 * MARGIN);
            root.draw_text(
                &text,
                &font(FIGURE_TITLE_SIZE, &INK),
                (px(MARGIN), px(MARGIN)),
            )
            .map_err(draw_err)?;
        }
        let mut x = MARGIN;
        for (panel, (w, _)) in panels.iter().zip(&sizes) {
            panel.draw(&root, x, MARGIN + title_h)?;
            x = x.saturating_add(w + PANEL_GAP);
        }
        root.present().map_err(draw_err)?;
    }
    encode_rgb(img_w, img_h, &buf)
}

/// A pixel offset as plotters' `i32` (offsets are bounded by [`MAX_PIXELS`]).
fn px(v: usize) -> i32 {
    i32::try_from(v).unwrap_or(i32::MAX)
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

/// A linear axis (in axis units) whose ticks are given: plotters draws labels and grid
/// lines at `bold`, light grid lines at `light`.
struct Ticked {
    /// The visible range.
    range: Range<f64>,
    /// Labelled ticks.
    bold: Vec<f64>,
    /// All ticks.
    light: Vec<f64>,
}

impl Ticked {
    /// An axis over `range` with plotters' key points at the ticks.
    fn new(range: Range<f64>, ticks: &[Tick]) -> Self {
        Self {
            range,
            bold: ticks.iter().filter(|t| !t.minor).map(|t| t.at).collect(),
            light: ticks.iter().map(|t| t.at).collect(),
        }
    }
}

impl Ranged for Ticked {
    type FormatOption = plotters::coord::ranged1d::DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        RangedCoordf64::from(self.range.clone()).map(value, limit)
    }

    fn key_points<Hint: plotters::coord::ranged1d::KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            self.light.clone()
        } else {
            self.bold.clone()
        }
    }

    fn range(&self) -> Range<f64> {
        self.range.clone()
    }
}

/// The label of the tick at `v` among `ticks` ("" for none).
fn tick_label(ticks: &[Tick], v: f64) -> String {
    ticks
        .iter()
        .find(|t| t.at == v)
        .and_then(|t| t.label.clone())
        .unwrap_or_default()
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
// Scatter axes: plotters draws them, the ticks are chosen here (plotters' own log ticks
// label only the powers of ten, too few over two or three decades).

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
    /// A minor tick (light grid line only).
    minor: bool,
}

/// The largest magnitude an axis end may have, so that spans and pixel maps stay finite.
const AXIS_LIMIT: f64 = 1e300;

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
    /// for no values. Ends are kept within +-[`AXIS_LIMIT`].
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
        let lo = (lo - pad).clamp(-AXIS_LIMIT, AXIS_LIMIT / 2.0);
        let hi = (hi + pad).clamp(lo + lo.abs().max(1.0) * 1e-9, AXIS_LIMIT);
        Some(Self { lo, hi, log })
    }

    /// Whether `t` (axis units) lies on the axis.
    fn contains(&self, t: f64) -> bool {
        (self.lo..=self.hi).contains(&t)
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

    /// The ticks, their labels thinned to keep clear of each other along `pixels` pixels
    /// (`extent` is a label's size along the axis).
    fn thinned_ticks(&self, pixels: usize, extent: impl Fn(&str) -> usize) -> Vec<Tick> {
        let mut ticks = self.ticks();
        let span = self.hi - self.lo;
        let labelled: Vec<usize> = (0..ticks.len())
            .filter(|&i| ticks[i].label.is_some())
            .collect();
        let pos: Vec<f64> = labelled
            .iter()
            .map(|&i| (ticks[i].at - self.lo) / span * pixels as f64)
            .collect();
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

// ---------------------------------------------------------------------------------------
// Scatter panels.

/// A scatter panel, measured.
struct ScatterLayout<'a> {
    /// What to draw.
    spec: &'a Scatter<'a>,
    /// The axes; `None` when there is no drawable point.
    axes: Option<(Axis, Axis)>,
    /// Legend entries `(x offset, row, key)`: a series' index, or `None` for the Pareto
    /// front.
    legend: Vec<(usize, usize, Option<usize>)>,
    /// Number of legend rows.
    legend_rows: usize,
    /// The note on points not drawn, if any.
    note: Option<String>,
}

/// Width of the area left of a scatter plot area (y tick labels and the y label).
const Y_AREA: usize = 78;

impl<'a> ScatterLayout<'a> {
    /// Measures `spec`.
    fn new(spec: &'a Scatter<'a>) -> Self {
        let all = || spec.series.iter().flat_map(|s| s.points.iter());
        let shown: Vec<(f64, f64)> = all().filter_map(|&p| drawable(spec, p)).collect();
        let axes = Axis::covering(shown.iter().map(|p| p.0), spec.x_log)
            .zip(Axis::covering(shown.iter().map(|p| p.1), spec.y_log));

        // Legend entries left to right, wrapping at the panel's width.
        let width = Y_AREA + PLOT_WIDTH + RIGHT;
        let mut items: Vec<(Option<usize>, &str)> = spec
            .series
            .iter()
            .enumerate()
            .filter(|(_, s)| !s.name.is_empty())
            .map(|(i, s)| (Some(i), s.name))
            .collect();
        if spec.pareto && !shown.is_empty() {
            items.push((None, "Pareto front"));
        }
        let mut legend = Vec::new();
        let (mut x, mut row) = (0usize, 0usize);
        for (key, name) in items {
            let w = 28 + text_size(name, TICK_SIZE).0;
            if x > 0 && x + w > width {
                x = 0;
                row += 1;
            }
            legend.push((x, row, key));
            x += w + 20;
        }
        let legend_rows = if legend.is_empty() { 0 } else { row + 1 };

        let skipped = all().count() - shown.len();
        let note = (skipped > 0).then(|| {
            let what = if spec.x_log || spec.y_log {
                "not finite, or <= 0 on a log axis"
            } else {
                "not finite"
            };
            let points = if skipped == 1 { "point" } else { "points" };
            fit(
                &format!("{skipped} {points} not drawn: {what}"),
                SMALL_SIZE,
                width,
            )
        });
        Self {
            spec,
            axes,
            legend,
            legend_rows,
            note,
        }
    }
}

/// `p` in axis units, if it can be drawn on `spec`'s axes.
fn drawable(spec: &Scatter, (x, y): (f64, f64)) -> Option<(f64, f64)> {
    Some((Axis::to_axis(x, spec.x_log)?, Axis::to_axis(y, spec.y_log)?))
}

impl Panel for ScatterLayout<'_> {
    fn size(&self) -> (usize, usize) {
        let below = self.legend_rows * LEGEND_ROW + self.note.as_ref().map_or(0, |_| NOTE_ROW);
        (
            Y_AREA + PLOT_WIDTH + RIGHT,
            CAPTION + PLOT_HEIGHT + X_AREA + below,
        )
    }

    fn draw(&self, root: &Area, ox: usize, oy: usize) -> Result<(), PreviewError> {
        let spec = self.spec;
        let area = root.clone().shrink(
            (px(ox), px(oy)),
            (
                px(Y_AREA + PLOT_WIDTH + RIGHT),
                px(CAPTION + PLOT_HEIGHT + X_AREA),
            ),
        );
        let title = fit(spec.title, PANEL_TITLE_SIZE, PLOT_WIDTH);
        let ((x_axis, y_axis), (x_ticks, y_ticks)) = self.axes_and_ticks();
        let mut chart = ChartBuilder::on(&area)
            .caption(title, font(PANEL_TITLE_SIZE, &INK))
            .margin_right(px(RIGHT))
            .x_label_area_size(px(X_AREA))
            .y_label_area_size(px(Y_AREA))
            .build_cartesian_2d(
                Ticked::new(x_axis.lo..x_axis.hi, &x_ticks),
                Ticked::new(y_axis.lo..y_axis.hi, &y_ticks),
            )
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(spec.x_label)
            .y_desc(spec.y_label)
            .axis_desc_style(font(AXIS_SIZE, &INK))
            .label_style(font(TICK_SIZE, &INK))
            .bold_line_style(GRID)
            .light_line_style(LIGHT_GRID)
            .x_label_formatter(&|v| tick_label(&x_ticks, *v))
            .y_label_formatter(&|v| tick_label(&y_ticks, *v))
            .draw()
            .map_err(draw_err)?;
        let (xr, yr) = chart.plotting_area().get_pixel_range();
        let plot = (xr.start, yr.start, xr.end, yr.end);
        let Some((x_axis, y_axis)) = self.axes else {
            let centre = ((xr.start + xr.end) / 2, (yr.start + yr.end) / 2);
            let style = font(AXIS_SIZE, &NOTE_INK).pos(Pos::new(HPos::Center, VPos::Center));
            root.draw_text("no data", &style, centre)
                .map_err(draw_err)?;
            return self.draw_legend(root, ox, oy);
        };
        let to_px = |p: (f64, f64)| {
            let (x, y) = drawable(spec, p)?;
            (x_axis.contains(x) && y_axis.contains(y)).then(|| chart.backend_coord(&(x, y)))
        };
        self.draw_points(root, &to_px)?;
        self.draw_labels(root, &to_px, plot)?;
        self.draw_legend(root, ox, oy)
    }
}

/// Where a point is drawn: its pixel, or `None` when it falls outside the axes.
type ToPixel<'a> = dyn Fn((f64, f64)) -> Option<(i32, i32)> + 'a;

impl ScatterLayout<'_> {
    /// The axes (0 to 1 when there is no drawable point) and their thinned ticks (none
    /// then).
    fn axes_and_ticks(&self) -> ((Axis, Axis), (Vec<Tick>, Vec<Tick>)) {
        let (x_axis, y_axis) = self.axes.unwrap_or((
            Axis {
                lo: 0.0,
                hi: 1.0,
                log: false,
            },
            Axis {
                lo: 0.0,
                hi: 1.0,
                log: false,
            },
        ));
        let ticks = if self.axes.is_some() {
            (
                x_axis.thinned_ticks(PLOT_WIDTH, |s| text_size(s, TICK_SIZE).0),
                y_axis.thinned_ticks(PLOT_HEIGHT, |s| text_size(s, TICK_SIZE).1),
            )
        } else {
            (Vec::new(), Vec::new())
        };
        ((x_axis, y_axis), ticks)
    }

    /// Draws the points, the Pareto front under them and its rings over them.
    fn draw_points(&self, root: &Area, to_px: &ToPixel) -> Result<(), PreviewError> {
        let spec = self.spec;
        let all: Vec<(f64, f64)> = spec
            .series
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .filter(|&p| to_px(p).is_some())
            .collect();
        let front: Vec<(i32, i32)> = if spec.pareto {
            pareto_front(&all)
                .into_iter()
                .filter_map(|i| to_px(all[i]))
                .collect()
        } else {
            Vec::new()
        };
        let mut stairs = Vec::new();
        for (k, &p) in front.iter().enumerate() {
            if k > 0 {
                stairs.push((p.0, stairs.last().map_or(p.1, |q: &(i32, i32)| q.1)));
            }
            stairs.push(p);
        }
        root.draw(&PathElement::new(stairs, BLACK.stroke_width(2)))
            .map_err(draw_err)?;
        for (i, series) in spec.series.iter().enumerate() {
            let (colour, shape) = series_style(i);
            for &p in series.points {
                if let Some(c) = to_px(p) {
                    draw_marker(root, c, shape, colour)?;
                }
            }
        }
        for &c in &front {
            root.draw(&Circle::new(c, RING_RADIUS, BLACK.stroke_width(2)))
                .map_err(draw_err)?;
        }
        Ok(())
    }

    /// Draws the point labels, each beside its point where it fits inside the plot area
    /// `plot` `(x0, y0, x1, y1)` clear of the others.
    fn draw_labels(
        &self,
        root: &Area,
        to_px: &ToPixel,
        plot: (i32, i32, i32, i32),
    ) -> Result<(), PreviewError> {
        let mut taken: Vec<Rect> = Vec::new();
        for series in self.spec.series {
            let Some(labels) = series.labels else {
                continue;
            };
            for (&p, label) in series.points.iter().zip(labels) {
                if label.is_empty() {
                    continue;
                }
                let Some(c) = to_px(p) else {
                    continue;
                };
                if let Some(at) = place_label(c, text_size(label, SMALL_SIZE), plot, &taken) {
                    // Glyphs rise a quarter of the size above the layout box.
                    let y = at.y0 + (SMALL_SIZE / 4.0) as i32;
                    root.draw_text(label, &font(SMALL_SIZE, &INK), (at.x0, y))
                        .map_err(draw_err)?;
                    taken.push(at);
                }
            }
        }
        Ok(())
    }

    /// Draws the legend and the note under the panel at `(ox, oy)`.
    fn draw_legend(&self, root: &Area, ox: usize, oy: usize) -> Result<(), PreviewError> {
        let top = px(oy + CAPTION + PLOT_HEIGHT + X_AREA);
        let row_y = |row: usize| top + px(row * LEGEND_ROW) + px(LEGEND_ROW / 2);
        for &(x, row, key) in &self.legend {
            let (kx, ky) = (px(ox + x) + 10, row_y(row));
            let name = match key {
                Some(i) => {
                    let (colour, shape) = series_style(i);
                    draw_marker(root, (kx, ky), shape, colour)?;
                    self.spec.series[i].name
                }
                None => {
                    root.draw(&PathElement::new(
                        vec![(kx - 10, ky), (kx + 10, ky)],
                        BLACK.stroke_width(2),
                    ))
                    .map_err(draw_err)?;
                    root.draw(&Circle::new(
                        (kx, ky),
                        RING_RADIUS - 2,
                        BLACK.stroke_width(2),
                    ))
                    .map_err(draw_err)?;
                    "Pareto front"
                }
            };
            let style = font(TICK_SIZE, &INK).pos(Pos::new(HPos::Left, VPos::Center));
            root.draw_text(name, &style, (kx + 18, ky))
                .map_err(draw_err)?;
        }
        if let Some(note) = &self.note {
            let y = top + px(self.legend_rows * LEGEND_ROW) + 4;
            root.draw_text(note, &font(SMALL_SIZE, &NOTE_INK), (px(ox), y))
                .map_err(draw_err)?;
        }
        Ok(())
    }
}

/// Draws a marker of `shape` centred on pixel `c`: filled with `colour`, outlined darker.
fn draw_marker(
    root: &Area,
    c: (i32, i32),
    shape: Marker,
    colour: RGBColor,
) -> Result<(), PreviewError> {
    let RGBColor(r, g, b) = colour;
    let dark = |v: u8| (u16::from(v) * 3 / 5) as u8;
    let outline = RGBColor(dark(r), dark(g), dark(b));
    let m = MARKER_RADIUS;
    let corners: Vec<(i32, i32)> = match shape {
        Marker::Circle => {
            root.draw(&Circle::new(c, m, colour.filled()))
                .map_err(draw_err)?;
            return root
                .draw(&Circle::new(c, m, outline.stroke_width(1)))
                .map_err(draw_err);
        }
        Marker::Square => vec![(-m, -m), (m, -m), (m, m), (-m, m)],
        Marker::Diamond => vec![(0, -m - 1), (m + 1, 0), (0, m + 1), (-m - 1, 0)],
        Marker::TriangleUp => vec![(0, -m - 1), (m + 1, m), (-m - 1, m)],
        Marker::TriangleDown => vec![(0, m + 1), (m + 1, -m), (-m - 1, -m)],
    };
    let at: Vec<(i32, i32)> = corners.iter().map(|&(x, y)| (c.0 + x, c.1 + y)).collect();
    root.draw(&Polygon::new(at.clone(), colour.filled()))
        .map_err(draw_err)?;
    let mut ring = at;
    ring.push(ring[0]);
    root.draw(&PathElement::new(ring, outline.stroke_width(1)))
        .map_err(draw_err)
}

/// A rectangle in pixels, `x0..x1` by `y0..y1`.
#[derive(Clone, Copy, Debug)]
struct Rect {
    /// Left edge.
    x0: i32,
    /// Top edge.
    y0: i32,
    /// Right edge (exclusive).
    x1: i32,
    /// Bottom edge (exclusive).
    y1: i32,
}

impl Rect {
    /// Whether the two rectangles share a pixel.
    fn overlaps(&self, o: &Rect) -> bool {
        self.x0 < o.x1 && o.x0 < self.x1 && self.y0 < o.y1 && o.y0 < self.y1
    }
}

/// Where a `(w, h)` label of the point at pixel `c` goes: right of it, else left, above,
/// below, inside the plot area `(x0, y0, x1, y1)` and clear of the rectangles `taken` and
/// of the point's Pareto ring; `None` if nowhere.
fn place_label(
    c: (i32, i32),
    (w, h): (usize, usize),
    (x0, y0, x1, y1): (i32, i32, i32, i32),
    taken: &[Rect],
) -> Option<Rect> {
    let (w, h) = (px(w), px(h));
    let off = RING_RADIUS + 2;
    let candidates = [
        (c.0 + off, c.1 - off - h / 2),
        (c.0 - off - w, c.1 - off - h / 2),
        (c.0 - w / 2, c.1 - off - h),
        (c.0 - w / 2, c.1 + off),
        (c.0 + off, c.1 + off / 2),
        (c.0 - off - w, c.1 + off / 2),
    ];
    candidates
        .iter()
        .map(|&(x, y)| Rect {
            x0: x,
            y0: y,
            x1: x + w,
            y1: y + h,
        })
        .find(|r| {
            r.x0 >= x0
                && r.y0 >= y0
                && r.x1 <= x1
                && r.y1 <= y1
                && !taken.iter().any(|t| t.overlaps(r))
        })
}

// ---------------------------------------------------------------------------------------
// Heat-map panels.

/// A heat-map panel, validated and measured.
struct HeatLayout<'a> {
    /// What to draw.
    spec: &'a HeatMap<'a>,
    /// The colour range in colour units (`log10` of the value when `log`); `None` when no
    /// value can be coloured.
    range: Option<(f64, f64)>,
    /// Cell size in pixels.
    cell: (usize, usize),
    /// Font size of the cells' text (0 for none).
    cell_font: f64,
    /// Every how many columns (rows) a tick label is drawn.
    stride: (usize, usize),
    /// Colour-bar labels, top (max) to bottom (min).
    bar_labels: Vec<String>,
    /// Width of the area left of the map (row labels and the y label).
    left: usize,
    /// Width of the area right of the map (colour bar and its labels).
    right: usize,
    /// Whether some value is not finite (then a note explains the grey).
    any_missing: bool,
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
        if cols.checked_mul(rows).is_none_or(|n| n > MAX_PIXELS) {
            return Err(too_large());
        }

        // Cells fill about PLOT_WIDTH x PLOT_HEIGHT, and hold their text.
        let mut cell_w = (PLOT_WIDTH / cols).max(1);
        let mut cell_h = (PLOT_HEIGHT / rows).max(1);
        let mut cell_font = 0.0;
        if spec.cell_text {
            let widest = |size| {
                spec.values
                    .iter()
                    .filter(|v| v.is_finite())
                    .map(|&v| text_size(&format_sig(v, 3), size).0)
                    .max()
                    .unwrap_or(0)
            };
            cell_font = if cell_w >= widest(TICK_SIZE) + 8 && cell_h >= 24 {
                TICK_SIZE
            } else {
                SMALL_SIZE
            };
            cell_w = cell_w.max(widest(cell_font) + 4);
            cell_h = cell_h.max(cell_font as usize + 4);
        }
        let map_w = cols.checked_mul(cell_w).ok_or_else(too_large)?;
        let map_h = rows.checked_mul(cell_h).ok_or_else(too_large)?;
        if map_w.checked_mul(map_h).is_none_or(|n| n > MAX_PIXELS) {
            return Err(too_large());
        }

        // Tick labels thinned so that they do not touch.
        let stride = |ticks: &[String], cell: usize, extent: &dyn Fn(&str) -> usize| {
            let pos: Vec<f64> = (0..ticks.len()).map(|i| (i * cell) as f64).collect();
            let size: Vec<usize> = ticks.iter().map(|s| extent(s)).collect();
            label_stride(&pos, &size)
        };
        let x_stride = stride(spec.x_ticks, cell_w, &|s| text_size(s, TICK_SIZE).0);
        let y_stride = stride(spec.y_ticks, cell_h, &|s| text_size(s, TICK_SIZE).1);

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
        let widest = |labels: &mut dyn Iterator<Item = &String>| {
            labels.map(|s| text_size(s, TICK_SIZE).0).max().unwrap_or(0)
        };
        let left = widest(&mut spec.y_ticks.iter()) + 40;
        let right = (BAR_GAP + BAR_WIDTH + 8 + widest(&mut bar_labels.iter()))
            .max(BAR_GAP + text_size(spec.unit, TICK_SIZE).0)
            + 8;
        Ok(Self {
            spec,
            range,
            cell: (cell_w, cell_h),
            cell_font,
            stride: (x_stride, y_stride),
            bar_labels,
            left,
            right,
            any_missing: spec.values.iter().any(|v| !v.is_finite()),
        })
    }

    /// The colour of `v`.
    fn colour(&self, v: f64) -> RGBColor {
        let [r, g, b] = if !v.is_finite() {
            NO_DATA
        } else if let Some((lo, hi)) = self.range {
            let t = match (self.spec.log, v > 0.0) {
                (false, _) => v,
                (true, true) => v.log10(),
                (true, false) => lo,
            };
            viridis((t * 0.5 - lo * 0.5) / (hi * 0.5 - lo * 0.5))
        } else {
            viridis(0.0)
        };
        RGBColor(r, g, b)
    }

    /// The map's size in pixels.
    fn map_size(&self) -> (usize, usize) {
        (self.spec.cols * self.cell.0, self.spec.rows * self.cell.1)
    }
}

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
        let (map_w, map_h) = self.map_size();
        let note = if self.any_missing { NOTE_ROW } else { 0 };
        (
            self.left + map_w + self.right,
            CAPTION + map_h + X_AREA + note,
        )
    }

    fn draw(&self, root: &Area, ox: usize, oy: usize) -> Result<(), PreviewError> {
        let spec = self.spec;
        let (cols, rows) = (spec.cols, spec.rows);
        let (map_w, map_h) = self.map_size();
        let area = root.clone().shrink(
            (px(ox), px(oy)),
            (
                px(self.left + map_w + self.right),
                px(CAPTION + map_h + X_AREA),
            ),
        );
        let title = fit(spec.title, PANEL_TITLE_SIZE, self.left + map_w);
        let (x_keys, y_keys) = self.tick_keys();
        let label =
            |ticks: &[String], i: f64| ticks.get(i.max(0.0) as usize).cloned().unwrap_or_default();
        let mut chart = ChartBuilder::on(&area)
            .caption(title, font(PANEL_TITLE_SIZE, &INK))
            .margin_right(px(self.right))
            .x_label_area_size(px(X_AREA))
            .y_label_area_size(px(self.left))
            .build_cartesian_2d(
                Ticked {
                    range: 0.0..cols as f64,
                    bold: x_keys,
                    light: Vec::new(),
                },
                Ticked {
                    range: 0.0..rows as f64,
                    bold: y_keys,
                    light: Vec::new(),
                },
            )
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(spec.x_label)
            .y_desc(spec.y_label)
            .axis_desc_style(font(AXIS_SIZE, &INK))
            .label_style(font(TICK_SIZE, &INK))
            .x_label_formatter(&|v| label(spec.x_ticks, *v))
            .y_label_formatter(&|v| label(spec.y_ticks, rows as f64 - *v))
            .draw()
            .map_err(draw_err)?;
        let cells = spec.values.iter().enumerate().map(|(i, &v)| {
            let (r, c) = ((i / cols) as f64, (i % cols) as f64);
            let top = rows as f64 - r;
            Rectangle::new([(c, top), (c + 1.0, top - 1.0)], self.colour(v).filled())
        });
        chart.draw_series(cells).map_err(draw_err)?;
        if self.cell_font > 0.0 {
            self.draw_cell_text(root, &|x, y| chart.backend_coord(&(x, y)))?;
        }
        let (xr, yr) = chart.plotting_area().get_pixel_range();
        if self.range.is_none() {
            let centre = ((xr.start + xr.end) / 2, (yr.start + yr.end) / 2);
            let style = font(AXIS_SIZE, &INK).pos(Pos::new(HPos::Center, VPos::Center));
            root.draw_text("no data", &style, centre)
                .map_err(draw_err)?;
        }
        self.draw_colour_bar(root, xr.end + px(BAR_GAP), (yr.start, yr.end - 1))?;
        if self.any_missing {
            self.draw_missing_note(root, ox, px(oy + CAPTION + map_h + X_AREA) + 2)?;
        }
        Ok(())
    }
}

impl HeatLayout<'_> {
    /// Where the tick labels go: every `stride`-th column's (row's) centre in axis units
    /// (columns span x in 0..cols; row r spans y in rows-r-1..rows-r, row 0 on top); none
    /// without labels.
    fn tick_keys(&self) -> (Vec<f64>, Vec<f64>) {
        let spec = self.spec;
        let (cols, rows) = (spec.cols, spec.rows);
        let centres = |n: usize, stride: usize| -> Vec<f64> {
            (0..n).step_by(stride).map(|i| i as f64 + 0.5).collect()
        };
        let x_keys = if spec.x_ticks.is_empty() {
            Vec::new()
        } else {
            centres(cols, self.stride.0)
        };
        let y_keys: Vec<f64> = if spec.y_ticks.is_empty() {
            Vec::new()
        } else {
            centres(rows, self.stride.1)
                .into_iter()
                .map(|c| rows as f64 - c)
                .collect()
        };
        (x_keys, y_keys)
    }

    /// Writes each finite value in its cell, white on dark colours, `at` giving the pixel
    /// of an axis point.
    fn draw_cell_text(
        &self,
        root: &Area,
        at: &dyn Fn(f64, f64) -> (i32, i32),
    ) -> Result<(), PreviewError> {
        let spec = self.spec;
        let (cols, rows) = (spec.cols, spec.rows);
        for (i, &v) in spec.values.iter().enumerate() {
            if !v.is_finite() {
                continue;
            }
            let (r, c) = ((i / cols) as f64, (i % cols) as f64);
            let at = at(c + 0.5, rows as f64 - r - 0.5);
            let RGBColor(cr, cg, cb) = self.colour(v);
            let luma = 0.299 * f64::from(cr) + 0.587 * f64::from(cg) + 0.114 * f64::from(cb);
            let ink = if luma < 128.0 { WHITE } else { INK };
            let style = font(self.cell_font, &ink).pos(Pos::new(HPos::Center, VPos::Center));
            root.draw_text(&format_sig(v, 3), &style, at)
                .map_err(draw_err)?;
        }
        Ok(())
    }

    /// Draws the colour bar at `bar_x` from pixel row `top` to `bottom`, high values at the
    /// top, labelled at its ends and middle, with the unit above it.
    fn draw_colour_bar(
        &self,
        root: &Area,
        bar_x: i32,
        (top, bottom): (i32, i32),
    ) -> Result<(), PreviewError> {
        let span = (bottom - top).max(1);
        for y in top..=bottom {
            let colour = if self.range.is_some() {
                let [r, g, b] = viridis(f64::from(bottom - y) / f64::from(span));
                RGBColor(r, g, b)
            } else {
                let [r, g, b] = NO_DATA;
                RGBColor(r, g, b)
            };
            root.draw(&Rectangle::new(
                [(bar_x, y), (bar_x + px(BAR_WIDTH), y + 1)],
                colour.filled(),
            ))
            .map_err(draw_err)?;
        }
        root.draw(&Rectangle::new(
            [(bar_x - 1, top - 1), (bar_x + px(BAR_WIDTH), bottom + 1)],
            INK.stroke_width(1),
        ))
        .map_err(draw_err)?;
        let style = font(TICK_SIZE, &INK).pos(Pos::new(HPos::Left, VPos::Center));
        for (k, text) in self.bar_labels.iter().enumerate() {
            let y = top + span * px(k) / 2;
            let x = bar_x + px(BAR_WIDTH);
            root.draw(&PathElement::new(vec![(x, y), (x + 5, y)], INK))
                .map_err(draw_err)?;
            root.draw_text(text, &style, (x + 12, y))
                .map_err(draw_err)?;
        }
        let unit = font(TICK_SIZE, &INK).pos(Pos::new(HPos::Left, VPos::Bottom));
        root.draw_text(self.spec.unit, &unit, (bar_x, top - 6))
            .map_err(draw_err)
    }

    /// Draws "grey = no data", with a grey swatch, at pixel row `y` from column `ox`.
    fn draw_missing_note(&self, root: &Area, ox: usize, y: i32) -> Result<(), PreviewError> {
        let [r, g, b] = NO_DATA;
        root.draw(&Rectangle::new(
            [(px(ox), y), (px(ox) + 12, y + 12)],
            RGBColor(r, g, b).filled(),
        ))
        .map_err(draw_err)?;
        root.draw_text(
            "grey = no data",
            &font(SMALL_SIZE, &NOTE_INK),
            (px(ox) + 18, y),
        )
        .map_err(draw_err)
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

        scatter_examples(&dir);
        heatmap_examples(&dir);
        scatter_edge_examples(&dir);
    }

    /// Two methods on linear and log axes with a Pareto front, and an empty panel.
    fn scatter_examples(dir: &std::path::Path) {
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
    }

    /// A parameter sweep with cell text and its log-scaled twin; an all-NaN map and one row.
    fn heatmap_examples(dir: &std::path::Path) {
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

    /// A narrow log axis, large linear values, one point, many series.
    fn scatter_edge_examples(dir: &std::path::Path) {
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
    }
}
