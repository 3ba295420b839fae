//! Brute force: least squares over an `(n, d)` grid per pixel (method.md "Method", the paper's
//! O(m N^2) baseline).

use filmscope_core::solve::{flags, IndexModel};

use super::common::{check_cube, defect_flags, model_table, pixel_spectra, unusable};
use crate::estimate::method::{Method, MethodResult};
use crate::source::SweepCube;

/// Index grid spacing used when [`BruteGrid::index_steps`] is 0.
pub const DEFAULT_INDEX_STEP: f64 = 0.01;

/// Most thickness grid points; a finer step is widened to stay within it.
const MAX_THICKNESS_STEPS: usize = 1 << 16;

/// Quadrature nodes of the band-averaged model (Simpson over +-1.5 FWHM, node spacing 0.375
/// FWHM): close to the 33-node average while the fringe period is well above the FWHM.
const BAND_NODES: usize = 9;

/// The `(n, d)` grid that [`brute`] searches.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BruteGrid {
    /// Number of index values, evenly spaced over the cube's `index_range` ends included
    /// (1: its midpoint; 0: as many as a [`DEFAULT_INDEX_STEP`] spacing needs).
    pub index_steps: usize,
    /// Thickness spacing, nm, from the low end of the cube's `thickness_range_nm`.
    pub thickness_step_nm: f64,
}

impl Default for BruteGrid {
    /// A 0.01 index step over the cube's index range and a 2 nm thickness step.
    fn default() -> Self {
        Self {
            index_steps: 0,
            thickness_step_nm: 2.0,
        }
    }
}

impl BruteGrid {
    /// The index values searched for a cube whose index range is `range`.
    pub fn index_values(&self, range: [f64; 2]) -> Vec<f64> {
        let [lo, hi] = range;
        let steps = match self.index_steps {
            0 => ((hi - lo) / DEFAULT_INDEX_STEP).round().max(0.0) as usize + 1,
            s => s,
        };
        if steps == 1 || hi <= lo {
            return vec![0.5 * (lo + hi)];
        }
        let dn = (hi - lo) / (steps - 1) as f64;
        (0..steps).map(|i| lo + dn * i as f64).collect()
    }

    /// The thickness step actually used for `range` (the given one, widened if the grid would
    /// exceed 65536 points; 2 nm if it is not a positive number).
    pub fn thickness_step_for(&self, range: [f64; 2]) -> f64 {
        let step = if self.thickness_step_nm.is_finite() && self.thickness_step_nm > 0.0 {
            self.thickness_step_nm
        } else {
            2.0
        };
        step.max((range[1] - range[0]) / (MAX_THICKNESS_STEPS - 1) as f64)
    }

    /// The thickness values searched for a cube whose thickness range is `range`, nm.
    pub fn thickness_values(&self, range: [f64; 2]) -> Vec<f64> {
        let step = self.thickness_step_for(range);
        let count = ((range[1] - range[0]) / step + 1e-9).floor().max(0.0) as usize + 1;
        (0..count).map(|j| range[0] + step * j as f64).collect()
    }
}

/// Best grid point found so far for one pixel.
#[derive(Clone, Copy, Debug)]
struct Best {
    sse: f64,
    index: usize,
    thickness: usize,
}

/// Least squares over the `(n, d)` grid, per pixel, against the model spectra over all angles
/// and bands; then one shared index and each pixel's best thickness at it.
///
/// 1. For every grid index `n` the model spectra of every grid thickness are tabulated (two
///    threads). The model is the Airy reflectance with constant film and substrate indices
///    (one [`FilmAtAngle`](filmscope_core::optics::FilmAtAngle) per angle and `n`: with
///    constant indices it serves every band): monochromatic at the band centre when every
///    band's FWHM is at most the band spacing, else averaged over a Gaussian passband of the
///    band's FWHM with 9 Simpson nodes (the
///    [`BandModel`](filmscope_core::optics::BandModel) average with 9 nodes rather than 33:
///    the same maps on the paper's samples, at a quarter of the cost).
/// 2. Each pixel (rows shared between two threads) keeps its best `(n, d)` in sum of squared
///    differences over its finite samples (exact search; a candidate is abandoned as soon as
///    its partial sum exceeds the pixel's best).
/// 3. The shared index is the median of the pixels' best `n` (the lower middle value for an
///    even count, so it stays on the grid); each pixel's thickness is its best grid `d` at
///    that index.
///
/// Pixels with more than a tenth of their samples non-finite get NaN and `SATURATED` (mostly
/// `+inf`) or `DEAD` (mostly NaN) and take no part. Solved pixels have confidence 1 and no
/// flags. Cost: pixels x grid points x samples, which is why this is the slow baseline.
pub fn brute(cube: &SweepCube, grid: BruteGrid) -> MethodResult {
    if let Err(problem) = check_cube(cube) {
        return unusable(Method::Brute, cube, &problem);
    }
    let (w, h) = (cube.width, cube.height);
    let indices = grid.index_values(cube.index_range);
    let thicknesses = grid.thickness_values(cube.thickness_range_nm);
    let nd = thicknesses.len();
    let data = Measured::of(cube);
    let valid = data.flags.iter().filter(|&&f| f == 0).count();

    let band_averaged = band_averaged(cube);
    let nodes = if band_averaged { BAND_NODES } else { 1 };
    let d_lo = cube.thickness_range_nm[0];
    let d_step = grid.thickness_step_for(cube.thickness_range_nm);
    let build = |n: f64| model_table(cube, n, d_lo, d_step, nd, nodes);

    // Pass 1: the best (n, d) of every pixel.
    let start = Best {
        sse: f64::INFINITY,
        index: 0,
        thickness: 0,
    };
    let mut best = vec![start; w * h];
    for (i, &n) in indices.iter().enumerate() {
        let table = build(n);
        data.search(&table, &mut best, i);
    }
    let mut per_pixel: Vec<usize> = best
        .iter()
        .zip(&data.flags)
        .filter(|(b, &f)| f == 0 && b.sse.is_finite())
        .map(|(b, _)| b.index)
        .collect();
    per_pixel.sort_unstable();
    let Some(&shared) = per_pixel.get(per_pixel.len().saturating_sub(1) / 2) else {
        let mut result = unusable(Method::Brute, cube, "");
        for (o, &f) in result.flags.iter_mut().zip(&data.flags) {
            *o = if f == 0 { flags::POOR_FIT } else { f };
        }
        result.notes = vec![format!(
            "brute: no pixel with usable spectra ({} of {} flagged)",
            w * h - valid,
            w * h
        )];
        return result;
    };
    let n = indices[shared];

    // Pass 2: every pixel's best thickness at the shared index.
    let table = build(n);
    let mut at_shared = vec![start; w * h];
    data.search(&table, &mut at_shared, shared);
    let mut pixel_flags = data.flags;
    let mut thickness = vec![f32::NAN; w * h];
    let mut confidence = vec![0f32; w * h];
    for (p, b) in at_shared.iter().enumerate() {
        if pixel_flags[p] == 0 && b.sse.is_finite() {
            thickness[p] = thicknesses[b.thickness] as f32;
            confidence[p] = 1.0;
        } else if pixel_flags[p] == 0 {
            pixel_flags[p] = flags::POOR_FIT;
        }
    }
    MethodResult {
        method: Method::Brute,
        index: IndexModel::constant(n),
        index_sigma: None,
        thickness_sigma_nm: vec![f32::NAN; thickness.len()],
        thickness_nm: thickness,
        confidence,
        flags: pixel_flags,
        notes: vec![
            grid_note(&indices, &thicknesses, d_step, data.row_len, band_averaged),
            format!(
                "brute: n = {n:.4} = median of the best index of {} pixels; {} pixels skipped \
                 (more than 10 % non-finite samples)",
                per_pixel.len(),
                w * h - valid
            ),
        ],
    }
}

/// Whether the model averages over each band's passband: when some band's FWHM exceeds the
/// smallest band spacing (else the band centre's reflectance serves).
fn band_averaged(cube: &SweepCube) -> bool {
    let min_spacing = cube
        .bands_nm
        .windows(2)
        .map(|x| x[1] - x[0])
        .fold(f64::INFINITY, f64::min);
    cube.fwhm_nm.iter().any(|&f| f > min_spacing)
}

/// The note describing the grid searched: its index and thickness values and steps, the
/// points and samples per pixel, and the model.
fn grid_note(
    indices: &[f64],
    thicknesses: &[f64],
    d_step: f64,
    nab: usize,
    band_averaged: bool,
) -> String {
    let nd = thicknesses.len();
    let n_step = if indices.len() > 1 {
        indices[1] - indices[0]
    } else {
        0.0
    };
    format!(
        "brute: grid {} indices {:.3}..{:.3} (step {n_step:.4}) x {nd} thicknesses \
         {:.1}..{:.1} nm (step {d_step:.2} nm) = {} points per pixel, {nab} samples each, \
         {} model",
        indices.len(),
        indices.first().copied().unwrap_or(f64::NAN),
        indices.last().copied().unwrap_or(f64::NAN),
        thicknesses.first().copied().unwrap_or(f64::NAN),
        thicknesses.last().copied().unwrap_or(f64::NAN),
        indices.len() * nd,
        if band_averaged {
            "band-averaged (9-node Gaussian passband)"
        } else {
            "monochromatic (band centre)"
        }
    )
}

/// Every pixel's measured spectra, pixel-major, with a weight per sample (0 for non-finite
/// samples, which are stored as 0) and its defect flags.
struct Measured {
    values: Vec<f32>,
    weight: Vec<f32>,
    /// Per pixel: SATURATED or DEAD, or 0 for a pixel that takes part.
    flags: Vec<u16>,
    /// Samples per pixel (angles x bands).
    row_len: usize,
    /// Pixels per image row.
    width: usize,
}

impl Measured {
    /// The cube's spectra.
    fn of(cube: &SweepCube) -> Self {
        let (w, h) = (cube.width, cube.height);
        let nab = cube.angles_deg.len() * cube.bands_nm.len();
        let mut measured = vec![0f32; w * h * nab];
        let mut weight = vec![0f32; w * h * nab];
        let mut pixel_flags = vec![0u16; w * h];
        for row in 0..h {
            for col in 0..w {
                let p = row * w + col;
                let spec = &mut measured[p * nab..(p + 1) * nab];
                pixel_spectra(cube, col, row, spec);
                pixel_flags[p] = defect_flags(spec);
                for (m, wt) in spec.iter_mut().zip(&mut weight[p * nab..(p + 1) * nab]) {
                    if m.is_finite() {
                        *wt = 1.0;
                    } else {
                        *m = 0.0;
                    }
                }
            }
        }
        Self {
            values: measured,
            weight,
            flags: pixel_flags,
            row_len: nab,
            width: w,
        }
    }

    /// Updates `best` (one entry per pixel) with the thicknesses of `table` (model spectra
    /// of grid index `index`, one row of [`Measured::row_len`] samples per grid thickness),
    /// the rows of the image shared between two threads. Pixels with flags are skipped.
    fn search(&self, table: &[f32], best: &mut [Best], index: usize) {
        let (row_len, width) = (self.row_len, self.width);
        let (measured, weight, pixel_flags) = (&self.values, &self.weight, &self.flags);
        let pixels = best.len();
        let rows = pixels / width.max(1);
        let half = rows.div_ceil(2).max(1) * width.max(1);
        std::thread::scope(|s| {
            for (k, chunk) in best.chunks_mut(half).enumerate() {
                let first = k * half;
                s.spawn(move || {
                    for (i, b) in chunk.iter_mut().enumerate() {
                        let p = first + i;
                        if pixel_flags[p] != 0 {
                            continue;
                        }
                        let m = &measured[p * row_len..(p + 1) * row_len];
                        let wt = &weight[p * row_len..(p + 1) * row_len];
                        for (j, model) in table.chunks_exact(row_len).enumerate() {
                            let sse = weighted_sse(model, m, wt, b.sse);
                            if sse < b.sse {
                                *b = Best {
                                    sse,
                                    index,
                                    thickness: j,
                                };
                            }
                        }
                    }
                });
            }
        });
    }
}

/// `sum weight (model - measured)^2`, abandoned (returning a value `>= bound`) once a partial
/// sum reaches `bound`. Eight independent lanes so that the compiler can vectorise.
fn weighted_sse(model: &[f32], measured: &[f32], weight: &[f32], bound: f64) -> f64 {
    const LANES: usize = 8;
    const CHUNK: usize = 8 * LANES;
    let mut sse = 0.0;
    for ((c, m), w) in model
        .chunks(CHUNK)
        .zip(measured.chunks(CHUNK))
        .zip(weight.chunks(CHUNK))
    {
        let mut acc = [0f32; LANES];
        let lanes = c
            .chunks_exact(LANES)
            .zip(m.chunks_exact(LANES))
            .zip(w.chunks_exact(LANES));
        for ((c, m), w) in lanes {
            for i in 0..LANES {
                let e = c[i] - m[i];
                acc[i] += w[i] * e * e;
            }
        }
        let tail = c.len() - c.len() % LANES;
        for ((&c, &m), &w) in c[tail..].iter().zip(&m[tail..]).zip(&w[tail..]) {
            let e = c - m;
            acc[0] += w * e * e;
        }
        sse += f64::from(acc.iter().sum::<f32>());
        if sse >= bound {
            break;
        }
    }
    sse
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_values() {
        let g = BruteGrid::default();
        let n = g.index_values([1.2, 3.0]);
        assert_eq!(n.len(), 181);
        assert!((n[17] - 1.37).abs() < 1e-12);
        assert!((n[180] - 3.0).abs() < 1e-12);
        let d = g.thickness_values([50.0, 2000.0]);
        assert_eq!(d.len(), 976);
        assert!((d[975] - 2000.0).abs() < 1e-9);
        let one = BruteGrid {
            index_steps: 1,
            thickness_step_nm: 0.0,
        };
        let mid = one.index_values([1.2, 1.4]);
        assert!(mid.len() == 1 && (mid[0] - 1.3).abs() < 1e-12);
        assert_eq!(one.thickness_step_for([0.0, 10.0]), 2.0);
    }
}
