//! The thickness map of a film whose complex index is given (`estimate --film-index` with
//! a material that absorbs over the band: a refractiveindex.info `tabulated nk` entry, a
//! formula with its `tabulated k`, the library's `si`).
//!
//! An absorbing film's reflectance is not the lossless film's `(A + B c) / (E + B c)` in
//! the phase alone (its numerator and denominator peak at different phases, and the round
//! trip loses amplitude with the thickness), so the streaming estimator's kernels cannot
//! take it. With n and k both known there is one unknown per pixel, which this module fits
//! on the whole sweep held in memory: every `(angle, band)`'s passband-averaged reflectance
//! ([`LossyFilm`], exact) tabulated over a thickness grid an eighth of the shortest fringe
//! period apart, each pixel's best grid thickness by least squares over all its samples,
//! then Gauss-Newton on the exact model. A pixel is NaN with a flag when its fit is much
//! worse than the image's typical fit (`POOR_FIT`), when another order fits nearly as well
//! (`AMBIGUOUS_ORDER`), or when it sits at an end of the range (`OUT_OF_RANGE`); every
//! pixel is NaN with `MODEL_MISMATCH` when the typical fit misses by more than the
//! tolerated model error (the given n and k, or the capture's metadata, are wrong).

use std::time::Instant;

use crate::record::finite;
use crate::record::index_choice::{AbsorbingChoice, IndexModelChoice};
use filmscope_core::optics::{Dispersion, Indices, LossyFilm};
use filmscope_core::solve::refine::{passband_phase_span, passband_rule, MAX_BAND_NODES};
use filmscope_core::solve::{flags, IndexModel, SweepSpec};

use crate::estimate::baseline::defect_flags;
use crate::estimate::method::{Method, MethodResult};
use crate::estimate::run::{Run, RunConfig};
use crate::pipeline::{collect_sweep, PipelineError};
use crate::source::{Source, SweepCube};

/// Grid points per shortest fringe period of thickness.
const POINTS_PER_FRINGE: f64 = 8.0;
/// Most grid points (a wider range takes a coarser grid).
const MAX_GRID: usize = 20_000;
/// Gauss-Newton steps from the best grid point.
const STEPS: usize = 12;
/// A pixel whose RMS residual exceeds this many times the image's median is `POOR_FIT`.
const POOR_FIT_RATIO: f64 = 3.0;
/// A pixel whose best fit half a fringe or more away has a sum of squares within this
/// factor of its best is `AMBIGUOUS_ORDER`.
const AMBIGUOUS_RATIO: f64 = 1.5;

/// Whether `film` absorbs over `bands_nm` (k of [`crate::material::CLEAR_K`] or more at
/// some band).
pub fn absorbs(film: &Dispersion, bands_nm: &[f64]) -> bool {
    bands_nm
        .iter()
        .any(|&l| film.extinction_at(l) >= crate::material::CLEAR_K)
}

/// One `(angle, band)`'s passband: its quadrature nodes' weights and films.
struct Column {
    nodes: Vec<(f64, LossyFilm)>,
}

impl Column {
    /// The band reflectance at `d_nm` and its slope in `d`.
    fn model(&self, d_nm: f64) -> (f64, f64) {
        let (mut r, mut slope) = (0.0, 0.0);
        for (w, f) in &self.nodes {
            let (delta, a) = f.round_trip(d_nm);
            let (v, dv_delta, dv_a) = f.reflectance(delta.cos(), delta.sin(), a);
            r += w * v;
            slope += w * (dv_delta * f.phase_per_nm - dv_a * f.loss_per_nm * a);
        }
        (r, slope)
    }
}

/// The columns of `cube`'s sweep (angle-major, as its data) for the film `film` on `spec`'s
/// stack, their quadrature fine enough for films up to `d_max` nm.
fn columns(
    spec: &SweepSpec,
    cube: &SweepCube,
    film: &Dispersion,
    d_max: f64,
) -> Option<Vec<Column>> {
    let pol = spec.polarization;
    let indices = |l: f64| Indices {
        ambient: spec.ambient_index,
        film: film.index_at(l),
        substrate: spec.substrate.index_at(l),
        substrate_k: spec.substrate.extinction_at(l),
        back_face: spec.back_face,
    };
    let mut out = Vec::with_capacity(cube.angles_deg.len() * cube.bands_nm.len());
    for &deg in &cube.angles_deg {
        for (&l0, &fwhm) in cube.bands_nm.iter().zip(&cube.fwhm_nm) {
            let film_at = |l: f64| LossyFilm::new(indices(l), film.extinction_at(l), deg, pol, l);
            let span = passband_phase_span(l0, fwhm, d_max, |l| Some(film_at(l)?.phase_per_nm));
            let (rule, count) = passband_rule(l0, fwhm, span);
            let nodes = rule[..count.min(MAX_BAND_NODES)]
                .iter()
                .map(|&(l, w)| Some((w, film_at(l)?)))
                .collect::<Option<Vec<_>>>()?;
            out.push(Column { nodes });
        }
    }
    Some(out)
}

/// One pixel's fit: thickness, its 1-sigma, RMS residual and flags.
#[derive(Clone, Copy)]
struct PixelFit {
    d: f64,
    sigma: f64,
    rms: f64,
    flags: u16,
}

impl PixelFit {
    /// No fit.
    const NONE: Self = Self {
        d: f64::NAN,
        sigma: f64::NAN,
        rms: f64::NAN,
        flags: 0,
    };
}

/// Fits one pixel's samples `y` (NaN: missing) over the grid `table` (`grid.len()` rows of
/// `columns.len()` values), then by Gauss-Newton on the exact model.
fn fit_pixel(
    y: &[f32],
    grid: &[f64],
    table: &[f32],
    columns: &[Column],
    half_fringe: f64,
) -> PixelFit {
    let nc = columns.len();
    let used = y.iter().filter(|v| v.is_finite()).count();
    let defects = defect_flags(y);
    if defects != 0 || used < 2 {
        return PixelFit {
            flags: defects | if used < 2 { flags::DEAD } else { 0 },
            ..PixelFit::NONE
        };
    }
    let sse_at = |g: usize| -> f64 {
        let row = &table[g * nc..(g + 1) * nc];
        row.iter()
            .zip(y)
            .filter(|(_, v)| v.is_finite())
            .map(|(&m, &v)| {
                let r = f64::from(v) - f64::from(m);
                r * r
            })
            .sum()
    };
    let sses: Vec<f64> = (0..grid.len()).map(sse_at).collect();
    let Some((best, &best_sse)) = sses.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)) else {
        return PixelFit::NONE;
    };
    let rival = sses
        .iter()
        .zip(grid)
        .filter(|(_, &d)| (d - grid[best]).abs() >= half_fringe)
        .map(|(s, _)| *s)
        .fold(f64::INFINITY, f64::min);
    let (lo, hi) = (grid[0], grid[grid.len() - 1]);
    let mut d = grid[best];
    let (mut sse, mut jj) = (best_sse, 0.0);
    for _ in 0..STEPS {
        let (mut jr, mut jtj, mut s) = (0.0, 0.0, 0.0);
        for (c, &v) in columns.iter().zip(y) {
            if !v.is_finite() {
                continue;
            }
            let (m, slope) = c.model(d);
            let r = f64::from(v) - m;
            jr += slope * r;
            jtj += slope * slope;
            s += r * r;
        }
        sse = s;
        jj = jtj;
        if jtj <= 0.0 {
            break;
        }
        let step = (jr / jtj).clamp(-half_fringe * 0.5, half_fringe * 0.5);
        d = (d + step).clamp(lo, hi);
        if step.abs() < 1e-4 {
            break;
        }
    }
    let mut f = 0;
    if d <= lo || d >= hi {
        f |= flags::OUT_OF_RANGE;
    }
    if rival < AMBIGUOUS_RATIO * best_sse {
        f |= flags::AMBIGUOUS_ORDER;
    }
    let dof = (used - 1).max(1) as f64;
    PixelFit {
        d,
        sigma: (sse / dof / jj).sqrt(),
        rms: (sse / used as f64).sqrt(),
        flags: f,
    }
}

/// Most pixel pairs [`noise_of`] looks at.
const NOISE_PAIRS: usize = 4096;

/// The samples' noise: the RMS difference of neighbouring pixels' residuals (each at its own
/// fitted thickness) over `sqrt(2)`, the median over up to [`NOISE_PAIRS`] pairs along the
/// rows; the model's own misfit, shared by neighbours, cancels.
fn noise_of(cube: &SweepCube, fits: &[PixelFit], columns: &[Column]) -> f64 {
    let (w, h, nb) = (cube.width, cube.height, cube.bands_nm.len());
    let pairs: Vec<usize> = (0..w * h)
        .filter(|&p| p % w + 1 < w && fits[p].d.is_finite() && fits[p + 1].d.is_finite())
        .collect();
    let stride = pairs.len().div_ceil(NOISE_PAIRS).max(1);
    let mut per_pair: Vec<f64> = pairs
        .iter()
        .step_by(stride)
        .filter_map(|&p| {
            let (row, col) = (p / w, p % w);
            let (mut sum, mut n) = (0.0, 0usize);
            for (a, data) in cube.data.iter().enumerate() {
                for b in 0..nb {
                    let c = &columns[a * nb + b];
                    let (y0, y1) = (
                        data[(b * h + row) * w + col],
                        data[(b * h + row) * w + col + 1],
                    );
                    if y0.is_finite() && y1.is_finite() {
                        let r0 = f64::from(y0) - c.model(fits[p].d).0;
                        let r1 = f64::from(y1) - c.model(fits[p + 1].d).0;
                        sum += (r0 - r1) * (r0 - r1);
                        n += 1;
                    }
                }
            }
            (n > 0).then(|| (sum / n as f64 / 2.0).sqrt())
        })
        .collect();
    per_pair.sort_by(f64::total_cmp);
    per_pair.get(per_pair.len() / 2).copied().unwrap_or(0.0)
}

/// Measures the thickness map of `film` (given n and k, named `name`) from `source`'s
/// sweep: the whole sweep held in memory, each pixel fitted alone ([`fit_pixel`]); the
/// result reports `index`, the model that holds the film's real index over the bands.
pub fn run_absorbing(
    source: &mut dyn Source,
    config: &RunConfig,
    film: &Dispersion,
    index: IndexModel,
    name: &str,
) -> Result<Run, PipelineError> {
    let t0 = Instant::now();
    let spec = config.fitted_spec(source.spec());
    let angles_deg = source.angles_deg();
    let cube = collect_sweep(source)?;
    let model = Tabulated::new(&spec, &cube, film, name)?;
    let fits = model.fit_pixels(&cube, config.pipeline.workers.max(1));
    let mut rms: Vec<f64> = fits
        .iter()
        .map(|f| f.rms)
        .filter(|r| r.is_finite())
        .collect();
    rms.sort_by(f64::total_cmp);
    let typical = rms.get(rms.len() / 2).copied().unwrap_or(f64::NAN);
    let noise = noise_of(&cube, &fits, &model.columns);
    let tolerated = (2.0 * noise * noise + spec.model_error * spec.model_error).sqrt();
    let mismatch = typical.is_nan() || typical > tolerated;
    let mut result = judged(index, &fits, typical, mismatch);
    if mismatch {
        result.notes.push(format!(
            "the given film {name:?} (n and k) does not explain the spectra: the typical pixel misses by {typical:.1e} RMS, beyond its noise {noise:.1e} and the tolerated model error {:.1e} ([fit] model_error); every pixel is NaN",
            spec.model_error
        ));
    }
    let samples = cube.samples();
    Ok(Run {
        result,
        angles_deg,
        seconds: t0.elapsed().as_secs_f64(),
        solve_latency_ms: None,
        state_bytes_per_pixel: None,
        samples,
        angle_reports: Vec::new(),
        model_choice: Some(IndexModelChoice::Absorbing(AbsorbingChoice {
            given: name.to_owned(),
            reason: "the film's n and k were given (--film-index, an absorbing material): each pixel's thickness fitted on the whole sweep with the absorbing film's exact reflectance".to_owned(),
            absorbing: true,
            k_550nm: finite(film.extinction_at(550.0)),
            grid_step_nm: finite(model.step),
            typical_rms: finite(typical),
            noise_sigma: finite(noise),
        })),
        field_model: None,
        field_model_choice: None,
        spec,
    })
}

/// The absorbing film's model over the sweep: every `(angle, band)`'s reflectance tabulated
/// on a thickness grid an eighth of the shortest fringe period apart.
struct Tabulated {
    /// The grid's thicknesses, nm, over the spec's thickness range.
    grid: Vec<f64>,
    /// The grid's step, nm.
    step: f64,
    /// The shortest fringe period in thickness over the band, nm.
    period: f64,
    /// Every `(angle, band)`'s passband, angle-major.
    columns: Vec<Column>,
    /// `grid.len()` rows of `columns.len()` reflectances.
    table: Vec<f32>,
}

impl Tabulated {
    /// The model of `film` (named `name`) for `cube`'s angles and bands; an error if the
    /// film does not pass light at some angle and band.
    fn new(
        spec: &SweepSpec,
        cube: &SweepCube,
        film: &Dispersion,
        name: &str,
    ) -> Result<Self, PipelineError> {
        let [lo, hi] = spec.thickness_range_nm;
        let n_max = cube
            .bands_nm
            .iter()
            .map(|&l| film.index_at(l))
            .fold(1.0, f64::max);
        let l_min = cube.bands_nm.iter().copied().fold(f64::INFINITY, f64::min);
        // A fringe's period in thickness at normal incidence, the shortest over the band.
        let period = l_min / (2.0 * n_max);
        let step = (period / POINTS_PER_FRINGE).max((hi - lo) / (MAX_GRID - 1) as f64);
        let grid: Vec<f64> = (0..)
            .map(|i| lo + step * f64::from(i))
            .take_while(|&d| d <= hi)
            .collect();
        let columns = columns(spec, cube, film, hi).ok_or_else(|| {
            PipelineError::Setup(format!(
                "the film {name:?} does not pass light at every angle and band (an evanescent wave)"
            ))
        })?;
        let nc = columns.len();
        let mut table = vec![0f32; grid.len() * nc];
        for (row, &d) in table.chunks_mut(nc).zip(&grid) {
            for (v, c) in row.iter_mut().zip(&columns) {
                *v = c.model(d).0 as f32;
            }
        }
        Ok(Self {
            grid,
            step,
            period,
            columns,
            table,
        })
    }

    /// Every pixel of `cube` fitted alone ([`fit_pixel`]), the rows shared between
    /// `workers` threads.
    fn fit_pixels(&self, cube: &SweepCube, workers: usize) -> Vec<PixelFit> {
        let (w, h, nb) = (cube.width, cube.height, cube.bands_nm.len());
        let nc = self.columns.len();
        let rows_per = h.div_ceil(workers).max(1);
        let mut fits = vec![PixelFit::NONE; w * h];
        std::thread::scope(|scope| {
            for (chunk_index, chunk) in fits.chunks_mut(rows_per * w).enumerate() {
                scope.spawn(move || {
                    let mut y = vec![f32::NAN; nc];
                    for (i, out) in chunk.iter_mut().enumerate() {
                        let p = chunk_index * rows_per * w + i;
                        let (row, col) = (p / w, p % w);
                        for (a, data) in cube.data.iter().enumerate() {
                            for b in 0..nb {
                                y[a * nb + b] = data[(b * h + row) * w + col];
                            }
                        }
                        *out = fit_pixel(
                            &y,
                            &self.grid,
                            &self.table,
                            &self.columns,
                            0.5 * self.period,
                        );
                    }
                });
            }
        });
        fits
    }
}

/// The maps of the pixel fits `fits`, each pixel NaN with a flag when its own fit says so,
/// when it misses by more than [`POOR_FIT_RATIO`] times the `typical` fit, or (`mismatch`)
/// when the typical fit misses by more than the tolerated model error.
fn judged(index: IndexModel, fits: &[PixelFit], typical: f64, mismatch: bool) -> MethodResult {
    let n = fits.len();
    let mut result = MethodResult {
        method: Method::Filmscope,
        index,
        index_sigma: None,
        thickness_nm: Vec::with_capacity(n),
        confidence: Vec::with_capacity(n),
        thickness_sigma_nm: Vec::with_capacity(n),
        flags: Vec::with_capacity(n),
        notes: Vec::new(),
    };
    for f in fits {
        let mut fl = f.flags;
        if f.rms > POOR_FIT_RATIO * typical {
            fl |= flags::POOR_FIT;
        }
        if mismatch && f.rms.is_finite() {
            fl |= flags::MODEL_MISMATCH;
        }
        let ok = fl == 0 && f.d.is_finite();
        result
            .thickness_nm
            .push(if ok { f.d as f32 } else { f32::NAN });
        result
            .thickness_sigma_nm
            .push(if ok { f.sigma as f32 } else { f32::NAN });
        result.confidence.push(if ok { 1.0 } else { 0.0 });
        result.flags.push(fl);
    }
    result
}
