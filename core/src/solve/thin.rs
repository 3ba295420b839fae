//! Films without fringe pairs: a global (index, thickness) search on a few pixels' spectra.
//!
//! A film a few tens of nanometres thick shows at most one broad extremum inside the band, so
//! neither the extremum shifts (no pair to compare) nor the order (nothing to count) say
//! anything. Its spectra still do: the reflectance level fixes the film's index against the
//! substrate's (a quarter-wave layer reflects `((n0 ns - n^2) / (n0 ns + n^2))^2`), the
//! spectral slope the optical thickness, and the change with angle separates the two
//! (`n d cos(theta_t)`). This module fits them by least squares over an (index, thickness)
//! grid on a small, bounded sample of pixels' full spectra (a few dozen pixels of the sweep,
//! whatever the sensor's size): the model of each grid point is computed once and scored
//! against every sampled pixel, every pixel keeps its best thickness, and the index that
//! minimises the sum of the pixels' best misfits wins. The search covers the whole thickness
//! range: a thick film whose fringes drown in the noise (next to the substrate's index) comes
//! here too, and is found. The streaming solver then starts every
//! pixel from the sample's thickness map (interpolated) with that index and refines both on
//! the full spectra ([`super::refine`]).

use super::refine::BandCoef;
use super::sweep::SweepSpec;
use super::IndexModel;

/// Index grid step of the coarse search.
pub const INDEX_STEP: f64 = 0.02;
/// Thickness grid step of the fine stage, nm: a thirtieth of the shortest fringe period the
/// search meets (420 nm light in a film of index 2.8 repeats every 75 nm of thickness).
pub const THICKNESS_STEP_NM: f64 = 2.5;
/// Most bands the coarse index grid looks at.
pub const COARSE_BANDS: usize = 40;
/// Golden-section steps refining the index around the best grid point (on the coarse
/// bands: the streaming passes refine the index on the full spectra after).
const REFINE_STEPS: usize = 14;

/// Fringe periods (at the shortest band) the fine stage's thickness window reaches beyond
/// the coarse stage's thinnest and thickest pixel: room for a pixel to move an order or two.
const WINDOW_PERIODS: f64 = 2.0;

/// The thickness grid of `spec`'s whole search range: `(first, points)`, nm. The search
/// covers the whole range: a thick film whose fringes drown in the noise (a film next to the
/// substrate's index: peak to peak `4 |r12 r23|`, eq. 4) also ends up here, and a search
/// capped below it took it for a thin one (found by the stability maps: n 1.5 on 1.52 at
/// 2000 nm reported as 100 nm, every pixel).
fn thickness_grid(spec: &SweepSpec) -> (f64, usize) {
    let lo = spec.thickness_range_nm[0].max(THICKNESS_STEP_NM);
    let hi = spec.thickness_range_nm[1].max(lo);
    (lo, libm::floor((hi - lo) / THICKNESS_STEP_NM) as usize + 1)
}

/// Grid points per fringe period (at the shortest band) the coarse stage looks at beyond
/// [`DENSE_PERIODS`]: enough for each pixel's parabola through its best three, a quarter of
/// the fine grid's on a film of index 1.5.
const COARSE_POINTS_PER_PERIOD: f64 = 12.0;
/// Fringe periods of thickness (at the shortest band) the coarse stage walks at the fine
/// step: a film thinner than a few periods has few fringes to pin its optical thickness, its
/// index and thickness trade off along a shallow valley, and a sparser grid there moved the
/// chosen index (measured: n 1.4 at 50 nm came out 1.3633 with the whole range at 12 points
/// per period, 1.4025 with these).
const DENSE_PERIODS: f64 = 4.0;

/// Points `first..first + dense` of the thickness grid, then every `stride`-th point after
/// them: `len` points in all.
#[derive(Clone, Copy, Debug)]
struct Window {
    d0: f64,
    first: usize,
    dense: usize,
    stride: usize,
    len: usize,
}

impl Window {
    /// Grid point of window point `t` (fractional between points).
    fn point(&self, t: f64) -> f64 {
        let dense = self.dense as f64;
        self.first as f64
            + if t <= dense {
                t
            } else {
                dense + (t - dense) * self.stride as f64
            }
    }

    /// Thickness of window point `t` (fractional between points), nm.
    fn at(&self, t: f64) -> f64 {
        self.d0 + self.point(t) * THICKNESS_STEP_NM
    }
}

/// Spectra of a few sampled pixels: `values[(a * bands + b) * pixels + p]` is pixel `p`'s
/// calibrated reflectance in band `b` at angle `a` (non-finite: unusable, skipped).
#[derive(Clone, Copy, Debug)]
pub struct SampledSpectra<'a> {
    /// The sweep.
    pub spec: &'a SweepSpec,
    /// Incidence angles, degrees, in the order of `values`.
    pub angles_deg: &'a [f64],
    /// Sampled pixels.
    pub pixels: usize,
    /// Reflectance, angle-major, then band, then pixel.
    pub values: &'a [f32],
}

/// The best (index, thicknesses) of a sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThinFit {
    /// The film index (constant: the streaming passes add dispersion if the data ask).
    pub index: f64,
    /// RMS residual over every usable sample at the best index and thicknesses.
    pub rms: f64,
    /// Sampled pixels with at least one usable sample.
    pub pixels: usize,
}

impl SampledSpectra<'_> {
    fn bands(&self) -> usize {
        self.spec.bands_nm.len()
    }

    /// Every sampled pixel's squared misfit at every grid thickness for index `n`, into
    /// `sse[t * pixels + p]`. `coarse`: every few bands only ([`COARSE_BANDS`] at most) and
    /// the band centres without their passbands (the spectra of the films the search is for
    /// are smooth on that scale). Returns `false` where the model has no propagating wave.
    fn misfits(&self, n: f64, window: Window, sse: &mut [f64], coarse: bool) -> bool {
        let (bands, px) = (self.bands(), self.pixels);
        let sse = &mut sse[..window.len * px];
        sse.iter_mut().for_each(|s| *s = 0.0);
        let index = IndexModel::constant(n);
        let stride = if coarse {
            bands.div_ceil(COARSE_BANDS)
        } else {
            1
        };
        for (a, &deg) in self.angles_deg.iter().enumerate() {
            for b in (0..bands).step_by(stride.max(1)) {
                let Some(coef) = BandCoef::new(
                    index,
                    self.spec.ambient_index,
                    self.spec.substrate_index,
                    self.spec.polarization,
                    deg,
                    self.spec.bands_nm[b],
                    if coarse { 0.0 } else { self.spec.fwhm_nm[b] },
                ) else {
                    return false;
                };
                let row = &self.values[(a * bands + b) * px..(a * bands + b + 1) * px];
                for t in 0..window.len {
                    let m = coef.model(window.at(t as f64));
                    for (s, &v) in sse[t * px..(t + 1) * px].iter_mut().zip(row) {
                        if v.is_finite() {
                            let r = f64::from(v) - m;
                            *s += r * r;
                        }
                    }
                }
            }
        }
        true
    }

    /// The sum over pixels of each pixel's smallest misfit in `sse` (over `window`), and
    /// (into `best`, if given) each pixel's best thickness, refined between grid points by a
    /// parabola (a NaN entry of `best` is left alone).
    fn total(&self, window: Window, sse: &[f64], mut best: Option<&mut [f32]>) -> f64 {
        let px = self.pixels;
        let steps = window.len;
        let mut total = 0.0;
        for p in 0..px {
            let at = |t: usize| sse[t * px + p];
            let mut t_best = 0;
            for t in 1..steps {
                if at(t) < at(t_best) {
                    t_best = t;
                }
            }
            // The parabola through the best grid point and its neighbours: the grid's own
            // step would otherwise make the total jump as the index moves.
            let (mut value, mut shift) = (at(t_best), 0.0);
            if t_best > 0 && t_best + 1 < steps {
                let (l, c, r) = (at(t_best - 1), at(t_best), at(t_best + 1));
                let curv = l - 2.0 * c + r;
                if curv > 0.0 {
                    shift = 0.5 * (l - r) / curv;
                    value = c - (l - r) * (l - r) / (8.0 * curv);
                }
            }
            total += value.max(0.0);
            // A pixel already NaN (no usable samples) stays so.
            if let Some(out) = best.as_deref_mut().filter(|out| !out[p].is_nan()) {
                out[p] = window.at(t_best as f64 + shift) as f32;
            }
        }
        total
    }

    /// The summed best misfits ([`Self::total`]) at index `n`; infinite where the model has
    /// no propagating wave.
    fn cost(&self, n: f64, window: Window, sse: &mut [f64], coarse: bool) -> f64 {
        if self.misfits(n, window, sse, coarse) {
            self.total(window, sse, None)
        } else {
            f64::INFINITY
        }
    }

    /// Usable samples of sampled pixel `p`.
    fn usable(&self, p: usize) -> usize {
        self.values
            .iter()
            .skip(p)
            .step_by(self.pixels.max(1))
            .filter(|v| v.is_finite())
            .count()
    }

    /// The scratch length [`SampledSpectra::fit`] needs: one misfit per pixel and grid
    /// thickness.
    pub fn scratch_len(&self) -> usize {
        thickness_grid(self.spec).1 * self.pixels
    }

    /// Searches the index over the spec's range (a grid, then golden section around its
    /// best point) with each pixel's thickness over the grid (the whole range every few
    /// points, then every point of the window the pixels took, a few fringe periods wide,
    /// and the final thicknesses on every band with its passband); writes each sampled pixel's
    /// thickness into `thickness_nm` (NaN for a pixel without usable samples). `sse` is
    /// scratch of [`SampledSpectra::scratch_len`]. `None` without usable samples or if the
    /// shapes disagree.
    pub fn fit(&self, sse: &mut [f64], thickness_nm: &mut [f32]) -> Option<ThinFit> {
        let (bands, px) = (self.bands(), self.pixels);
        if px == 0
            || self.values.len() != self.angles_deg.len() * bands * px
            || sse.len() != self.scratch_len()
            || thickness_nm.len() != px
        {
            return None;
        }
        let (mut count, mut pixels) = (0, 0);
        for (p, d) in thickness_nm.iter_mut().enumerate() {
            let k = self.usable(p);
            count += k;
            pixels += usize::from(k > 0);
            // NaN marks a pixel without samples; `total` below fills the others.
            *d = if k > 0 { 0.0 } else { f32::NAN };
        }
        if count == 0 {
            return None;
        }
        let [n_lo, n_hi] = self.spec.index_range;
        let steps = libm::ceil((n_hi - n_lo) / INDEX_STEP).max(1.0) as usize;
        let (d0, points) = thickness_grid(self.spec);
        let shortest = self
            .spec
            .bands_nm
            .iter()
            .fold(f64::INFINITY, |a, &b| a.min(b));
        // Thickness of one fringe period at the shortest band, in a film of index `n`.
        let period = |n: f64| shortest / (2.0 * n);
        // The whole range, as densely as a film of index `n` needs.
        let whole = |n: f64| {
            let period = period(n);
            let stride = libm::floor(period / COARSE_POINTS_PER_PERIOD / THICKNESS_STEP_NM)
                .clamp(1.0, points as f64) as usize;
            let dense = (libm::ceil((DENSE_PERIODS * period - d0) / THICKNESS_STEP_NM).max(0.0)
                as usize)
                .min(points);
            Window {
                d0,
                first: 0,
                dense,
                stride,
                len: dense + (points - dense).div_ceil(stride),
            }
        };
        let mut n_best = n_lo;
        let mut c_best = f64::INFINITY;
        for i in 0..=steps {
            let n = n_lo + (n_hi - n_lo) * i as f64 / steps as f64;
            let c = self.cost(n, whole(n), sse, true);
            if c < c_best {
                (n_best, c_best) = (n, c);
            }
        }
        // The index refinement and the final thicknesses look only at the thicknesses the
        // coarse stage's pixels took, and a few fringe periods either side, at every grid
        // point (the final thicknesses on every band, with its passband).
        if !self.misfits(n_best, whole(n_best), sse, true) {
            return None;
        }
        self.total(whole(n_best), sse, Some(thickness_nm));
        let (thin, thick) = thickness_nm
            .iter()
            .filter(|d| d.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &d| {
                (lo.min(f64::from(d)), hi.max(f64::from(d)))
            });
        let reach = WINDOW_PERIODS * period(n_best);
        let first = libm::floor(((thin - reach - d0) / THICKNESS_STEP_NM).max(0.0)) as usize;
        let last = (libm::ceil((thick + reach - d0) / THICKNESS_STEP_NM).max(0.0) as usize)
            .min(points - 1);
        let first = first.min(last);
        let len = last - first + 1;
        let window = Window {
            d0,
            first,
            dense: len,
            stride: 1,
            len,
        };
        let mut cost = |n: f64| self.cost(n, window, sse, true);
        let c_best = cost(n_best);
        // Golden section on the bracket around the best grid point.
        let g = 0.5 * (libm::sqrt(5.0) - 1.0);
        let (mut a, mut b) = (
            (n_best - INDEX_STEP).max(n_lo),
            (n_best + INDEX_STEP).min(n_hi),
        );
        let (mut x1, mut x2) = (b - g * (b - a), a + g * (b - a));
        let (mut f1, mut f2) = (cost(x1), cost(x2));
        for _ in 0..REFINE_STEPS {
            if f1 < f2 {
                (b, x2, f2) = (x2, x1, f1);
                x1 = b - g * (b - a);
                f1 = cost(x1);
            } else {
                (a, x1, f1) = (x1, x2, f2);
                x2 = a + g * (b - a);
                f2 = cost(x2);
            }
        }
        let (n, _) = [(x1, f1), (x2, f2), (n_best, c_best)]
            .into_iter()
            .min_by(|p, q| p.1.total_cmp(&q.1))?;
        if !self.misfits(n, window, sse, false) {
            return None;
        }
        let total = self.total(window, sse, Some(thickness_nm));
        Some(ThinFit {
            index: n,
            rms: libm::sqrt(total / count as f64),
            pixels,
        })
    }
}

/// Most pixels a sample holds: enough to pool the index over the image and follow a smooth
/// thickness map, few enough that the search takes a fraction of a second.
pub const MAX_SAMPLED_PIXELS: usize = 64;

/// A regular grid of sampled pixels over a `width x height` image: the centres of
/// `cols x rows` equal cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SampleGrid {
    /// Image width.
    pub width: usize,
    /// Image height.
    pub height: usize,
    /// Cells across.
    pub cols: usize,
    /// Cells down.
    pub rows: usize,
}

impl SampleGrid {
    /// The grid of at most [`MAX_SAMPLED_PIXELS`] cells whose shape follows the image's.
    pub fn for_image(width: usize, height: usize) -> Self {
        let (w, h) = (width.max(1), height.max(1));
        let cols_f = libm::sqrt(MAX_SAMPLED_PIXELS as f64 * w as f64 / h as f64);
        let cols = (libm::floor(cols_f) as usize).clamp(1, w.min(MAX_SAMPLED_PIXELS));
        let rows = (MAX_SAMPLED_PIXELS / cols).clamp(1, h);
        Self {
            width: w,
            height: h,
            cols,
            rows,
        }
    }

    /// Sampled pixels.
    pub fn len(&self) -> usize {
        self.cols * self.rows
    }

    /// Whether the grid is empty (never, for a non-empty image).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn centre(cell: usize, cells: usize, size: usize) -> f64 {
        (cell as f64 + 0.5) * size as f64 / cells as f64 - 0.5
    }

    /// The image pixel `(x, y)` of sample `k` (row-major over the cells).
    pub fn pixel(&self, k: usize) -> (usize, usize) {
        let (cx, cy) = (k % self.cols, k / self.cols);
        let x = libm::round(Self::centre(cx, self.cols, self.width)).max(0.0) as usize;
        let y = libm::round(Self::centre(cy, self.rows, self.height)).max(0.0) as usize;
        (x.min(self.width - 1), y.min(self.height - 1))
    }

    /// The finite sample nearest to pixel `(x, y)`, NaN if there is none.
    fn nearest_finite(&self, values: &[f32], x: usize, y: usize) -> f32 {
        let mut best = (f64::INFINITY, f32::NAN);
        for (k, &v) in values.iter().enumerate() {
            let (px, py) = self.pixel(k);
            let (dx, dy) = (px as f64 - x as f64, py as f64 - y as f64);
            let d2 = dx * dx + dy * dy;
            if v.is_finite() && d2 < best.0 {
                best = (d2, v);
            }
        }
        best.1
    }

    /// Marks NaN each finite sample more than `limit` from the median of its finite grid
    /// neighbours (at least two of the eight): a pixel the search put in another basin than
    /// the film around it (noise on a film with faint fringes: measured, one of 63 samples
    /// of n 1.5 on 1.52 at 200 nm came out at 33 nm, and interpolation spread it to its
    /// neighbours' seeds). Returns the samples rejected.
    pub fn reject_outliers(&self, values: &mut [f32], limit: f32) -> usize {
        if values.len() != self.len() || values.len() > MAX_SAMPLED_PIXELS {
            return 0;
        }
        let mut reject = [false; MAX_SAMPLED_PIXELS];
        for (k, flag) in reject.iter_mut().enumerate().take(values.len()) {
            let v = values[k];
            if !v.is_finite() {
                continue;
            }
            let (cx, cy) = ((k % self.cols) as isize, (k / self.cols) as isize);
            let mut near = [0.0f32; 8];
            let mut n = 0;
            for dy in -1..=1isize {
                for dx in -1..=1isize {
                    let (x, y) = (cx + dx, cy + dy);
                    if (dx, dy) == (0, 0)
                        || x < 0
                        || y < 0
                        || x >= self.cols as isize
                        || y >= self.rows as isize
                    {
                        continue;
                    }
                    let w = values[y as usize * self.cols + x as usize];
                    if w.is_finite() {
                        near[n] = w;
                        n += 1;
                    }
                }
            }
            if n < 2 {
                continue;
            }
            let near = &mut near[..n];
            near.sort_unstable_by(f32::total_cmp);
            let median = 0.5 * (near[(n - 1) / 2] + near[n / 2]);
            *flag = (v - median).abs() > limit;
        }
        let mut count = 0;
        for (v, &r) in values.iter_mut().zip(&reject) {
            if r {
                *v = f32::NAN;
                count += 1;
            }
        }
        count
    }

    /// Fills the `width x height` map `out` from the samples' `values` by bilinear
    /// interpolation between cell centres (constant beyond the outer centres); a NaN sample
    /// gives way to its finite neighbours, or to the nearest finite sample (NaN only if
    /// every sample is).
    pub fn interpolate(&self, values: &[f32], out: &mut [f32]) {
        if values.len() != self.len() || out.len() != self.width * self.height {
            return;
        }
        let axis = |v: usize, cells: usize, size: usize| -> (usize, usize, f64) {
            let t = ((v as f64 + 0.5) * cells as f64 / size as f64 - 0.5)
                .clamp(0.0, (cells - 1) as f64);
            let i = libm::floor(t) as usize;
            let j = (i + 1).min(cells - 1);
            (i, j, t - i as f64)
        };
        for y in 0..self.height {
            let (r0, r1, fy) = axis(y, self.rows, self.height);
            for x in 0..self.width {
                let (c0, c1, fx) = axis(x, self.cols, self.width);
                let (mut sum, mut weight) = (0.0, 0.0);
                for (r, wy) in [(r0, 1.0 - fy), (r1, fy)] {
                    for (c, wx) in [(c0, 1.0 - fx), (c1, fx)] {
                        let v = values[r * self.cols + c];
                        let wgt = wx * wy;
                        if v.is_finite() && wgt > 0.0 {
                            sum += wgt * f64::from(v);
                            weight += wgt;
                        }
                    }
                }
                out[y * self.width + x] = if weight > 0.0 {
                    (sum / weight) as f32
                } else {
                    self.nearest_finite(values, x, y)
                };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::optics::Dispersion;
    use crate::optics::{FilmStack, Passband, Polarization};

    fn spec(bands: core::ops::Range<usize>) -> SweepSpec {
        let mut s = SweepSpec {
            width: 4,
            height: 2,
            bands_nm: heapless::Vec::new(),
            fwhm_nm: heapless::Vec::new(),
            ambient_index: 1.0,
            substrate_index: 1.65,
            polarization: Polarization::Unpolarized,
            index_range: [1.2, 2.8],
            thickness_range_nm: [50.0, 2000.0],
            options: Default::default(),
        };
        for b in bands {
            let _ = s.bands_nm.push(420.0 + 2.0 * b as f64);
            let _ = s.fwhm_nm.push(4.0);
        }
        s
    }

    /// Spectra of films of `thicknesses` and index `n`, from the optics module's own stack
    /// (33-node passband), not from the search's model.
    fn spectra(spec: &SweepSpec, angles: &[f64], n: f64, thicknesses: &[f64]) -> Vec<f32> {
        let stack = FilmStack {
            ambient_index: 1.0,
            film: Dispersion::constant(n),
            substrate: Dispersion::constant(spec.substrate_index),
            polarization: Polarization::Unpolarized,
        };
        let mut v = Vec::new();
        for &a in angles {
            for (b, &l) in spec.bands_nm.iter().enumerate() {
                for &d in thicknesses {
                    let band = Passband::gaussian(l, spec.fwhm_nm[b]);
                    v.push(stack.band_reflectance(d, a, &band) as f32);
                }
            }
        }
        v
    }

    /// Fits films of index `n` and `truth` thicknesses at `angles` and checks index and
    /// thicknesses; returns the fit.
    fn fits(angles: &[f64], n: f64, truth: &[f64]) -> ThinFit {
        let spec = spec(0..151);
        let values = spectra(&spec, angles, n, truth);
        let s = SampledSpectra {
            spec: &spec,
            angles_deg: angles,
            pixels: truth.len(),
            values: &values,
        };
        let mut sse = vec![0.0; s.scratch_len()];
        let mut d = vec![0.0f32; truth.len()];
        let fit = s.fit(&mut sse, &mut d).expect("a fit");
        assert!((fit.index - n).abs() < 0.005, "index {} vs {n}", fit.index);
        for (got, want) in d.iter().zip(truth) {
            assert!(
                (f64::from(*got) - want).abs() < 1.5,
                "thickness {got} vs {want}"
            );
        }
        fit
    }

    #[test]
    fn an_80_nm_film_without_fringes_gives_its_index_and_thickness() {
        let fit = fits(
            &[10.0, 20.0, 30.0, 40.0, 50.0],
            1.45,
            &[72.0, 80.0, 88.0, 95.0],
        );
        assert!(fit.rms < 2e-4, "rms {}", fit.rms);
    }

    #[test]
    fn a_high_index_thin_film_is_found_too() {
        fits(&[10.0, 30.0, 50.0], 2.35, &[60.0, 120.0]);
    }

    #[test]
    fn unusable_pixels_get_nan_and_bad_shapes_none() {
        let spec = spec(0..40);
        let angles = [10.0, 40.0];
        let mut values = spectra(&spec, &angles, 1.6, &[100.0, 100.0]);
        for (i, v) in values.iter_mut().enumerate() {
            if i % 2 == 1 {
                *v = f32::NAN;
            }
        }
        let s = SampledSpectra {
            spec: &spec,
            angles_deg: &angles,
            pixels: 2,
            values: &values,
        };
        let mut sse = vec![0.0; s.scratch_len()];
        let mut d = vec![0.0f32; 2];
        let fit = s.fit(&mut sse, &mut d).expect("a fit");
        assert_eq!(fit.pixels, 1);
        assert!(d[1].is_nan() && d[0].is_finite());
        assert!(s.fit(&mut sse, &mut d[..1]).is_none());
    }

    #[test]
    fn the_sample_grid_spreads_over_the_image_and_interpolates() {
        let g = SampleGrid::for_image(2048, 1024);
        assert!(g.len() <= MAX_SAMPLED_PIXELS && g.len() >= MAX_SAMPLED_PIXELS / 2);
        assert!(g.cols > g.rows);
        let g = SampleGrid::for_image(32, 24);
        let mut seen: Vec<_> = (0..g.len()).map(|k| g.pixel(k)).collect();
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), g.len(), "every sample its own pixel");
        assert!(seen.iter().all(|&(x, y)| x < 32 && y < 24));
        // A plane is reproduced exactly inside the outer centres.
        let values: Vec<f32> = (0..g.len())
            .map(|k| {
                let (x, y) = g.pixel(k);
                let _ = (x, y);
                let (cx, cy) = ((k % g.cols) as f64, (k / g.cols) as f64);
                let x = (cx + 0.5) * 32.0 / g.cols as f64 - 0.5;
                let y = (cy + 0.5) * 24.0 / g.rows as f64 - 0.5;
                (100.0 + 2.0 * x + 3.0 * y) as f32
            })
            .collect();
        let mut out = vec![0.0; 32 * 24];
        g.interpolate(&values, &mut out);
        let (x, y) = (15, 11);
        assert!((f64::from(out[y * 32 + x]) - (100.0 + 30.0 + 33.0)).abs() < 1e-3);
        let mut holes = values.clone();
        holes[0] = f32::NAN;
        g.interpolate(&holes, &mut out);
        assert!(out.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn a_sample_off_its_neighbours_is_rejected_and_a_gradient_kept() {
        let grid = SampleGrid::for_image(16, 12);
        // A wedge rising 3 nm per sample across, one sample in another basin.
        let mut values: heapless::Vec<f32, 64> = (0..grid.len())
            .map(|k| 200.0 + 3.0 * (k % grid.cols) as f32)
            .collect();
        let wedge = values.clone();
        assert_eq!(grid.reject_outliers(&mut values, 40.0), 0);
        assert_eq!(values, wedge);
        values[grid.cols + 2] = 33.0;
        assert_eq!(grid.reject_outliers(&mut values, 40.0), 1);
        assert!(values[grid.cols + 2].is_nan());
        assert_eq!(
            values.iter().filter(|v| v.is_finite()).count(),
            grid.len() - 1
        );
    }
}
