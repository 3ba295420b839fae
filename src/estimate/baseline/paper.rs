//! Kobayashi et al.'s method as the paper describes it (method.md "Method"), without any of
//! filmscope's improvements, so that its weakness on high-index films stays visible.

use filmscope_core::optics::{snell_invariant, DEFAULT_NODES};
use filmscope_core::solve::{flags, IndexModel};

use super::common::{
    angles_by_incidence, check_cube, defect_flags, median, model_table, pixel_spectra, unusable,
};
use crate::estimate::method::{Method, MethodResult};
use crate::source::SweepCube;

/// Finest spacing of the model-spectrum thickness table, nm.
const TABLE_STEP_NM: f64 = 1.0;
/// Most rows of the model-spectrum thickness table (coarser spacing for wider ranges).
const TABLE_MAX_ROWS: usize = 4096;
/// Most candidate orders tried per pixel.
const MAX_ORDERS: f64 = 10_000.0;

/// Kobayashi et al.'s method, faithfully: reflectance peaks, eq. 12 from pairs of angles,
/// eqs. 13-14 for the thickness.
///
/// 1. **Peaks.** Each spectrum (pixel, angle) is smoothed by a 9-band moving average (over
///    its finite samples; the paper names no smoothing, but its peaks come from real, noisy
///    spectra, and a plain 3-point maximum finds about a hundred noise peaks per spectrum at
///    0.3 % noise), then every band that is the highest within 12 bands either side is a peak,
///    located at that band's centre: no sub-band interpolation. Non-finite samples are
///    ignored (never a peak nor a neighbour of one).
/// 2. **Order tracking.** Angles are sorted by incidence; each peak at one angle is matched to
///    the nearest peak at the next angle at a shorter-or-equal wavelength (same order `m`).
/// 3. **Index (eq. 12).** Each matched pair of peaks at neighbouring angles gives
///    `n = sqrt((l2^2 s1 - l1^2 s2) / (l2^2 - l1^2))` with `s = (n1 sin theta)^2`; the paper
///    assumes one index for the whole image: the median of all pair estimates that are finite
///    and inside `cube.index_range`.
/// 4. **Thickness (eqs. 13-14).** At the smallest angle with a peak, the pixel's highest peak
///    gives the candidates `d = m lambda / (2 sqrt(n^2 - s))` for *integer* `m = 1, 2, ...`
///    inside `cube.thickness_range_nm`; the candidate whose model spectra (band-averaged Airy
///    reflectance with the estimated constant index) are nearest, in least squares over all
///    angles and bands, to the measured spectra wins.
///
/// The paper's order equation `m lambda = phi` ignores the half-order phase of a film whose
/// index is above the substrate's (ZnS on PET: peaks at `(m + 1/2) lambda = phi`); this
/// baseline keeps that flaw on purpose. On such films every candidate is half an order,
/// `lambda / (4 sqrt(n^2 - s))`, away from a true thickness (the model puts a valley where the
/// film has its peak), so eq. 14 has no good candidate to choose and may pick any order: on the
/// simulated ZnS sample the thickness map is off by more than a micrometre on average even
/// without noise, while the MgF2 samples come out within a nanometre.
///
/// The model spectra (the band-averaged reflectance of
/// [`BandModel`](filmscope_core::optics::BandModel), same 33 nodes) are tabulated once per
/// run on a thickness grid (1 nm spacing, coarser when the range would need more than 4096
/// rows) and linearly interpolated between rows (error about 1e-4 in reflectance for the
/// paper's films).
///
/// Pixels with no peak at any angle get NaN and `NO_FRINGE` (plus `SATURATED` or `DEAD` when
/// more than a tenth of their samples are not finite), pixels with no candidate inside the
/// range NaN and `OUT_OF_RANGE`. Solved pixels have confidence 1 and no flags (the paper has
/// no confidence measure).
pub fn paper(cube: &SweepCube) -> MethodResult {
    if let Err(problem) = check_cube(cube) {
        return unusable(Method::Paper, cube, &problem);
    }
    let (w, h) = (cube.width, cube.height);
    let order = angles_by_incidence(cube);
    let s2: Vec<f64> = cube
        .angles_deg
        .iter()
        .map(|&t| {
            let beta = snell_invariant(cube.ambient_index, t);
            beta * beta
        })
        .collect();

    // Steps 1-3: peaks, pair estimates of the index, and each pixel's thickness anchor.
    let mut scan = PeakScan::run(cube, &order, &s2);
    let pairs_total = scan.pairs_total;
    let used = scan.estimates.len();
    let Some(n) = median(&mut scan.estimates) else {
        let mut result = unusable(Method::Paper, cube, "");
        result.flags = vec![flags::NO_FRINGE; w * h];
        result.notes = vec![format!(
            "paper: no index: 0 usable eq. 12 pair estimates of {pairs_total} matched peak pairs"
        )];
        return result;
    };
    let mad = {
        let mut dev: Vec<f64> = scan.estimates.iter().map(|e| (e - n).abs()).collect();
        median(&mut dev).unwrap_or(f64::NAN)
    };

    // Step 4: model spectra on a thickness grid, then the integer order per pixel.
    let Orders {
        thickness,
        confidence,
        solved,
        no_peak,
        out_of_range,
        step,
    } = Orders::solve(cube, n, &s2, &scan.anchors, &mut scan.pixel_flags);

    MethodResult {
        method: Method::Paper,
        index: IndexModel::constant(n),
        index_sigma: None,
        thickness_sigma_nm: vec![f32::NAN; thickness.len()],
        thickness_nm: thickness,
        confidence,
        flags: scan.pixel_flags,
        notes: vec![
            format!(
                "paper: n = {n:.4} = median of {used} eq. 12 pair estimates (of {pairs_total} \
                 matched peak pairs; the rest non-finite or outside {:?}), MAD {mad:.4}",
                cube.index_range
            ),
            format!(
                "paper: {solved} pixels solved, {no_peak} without a peak, {out_of_range} \
                 without an order inside {:?} nm",
                cube.thickness_range_nm
            ),
            format!(
                "paper: peaks = highest within +-12 bands of a 9-band moving average, at band \
                 centres; integer orders only (no half-order phase); model table step \
                 {step:.2} nm"
            ),
        ],
    }
}

/// Steps 1-3 of [`paper`] over every pixel: the eq. 12 index estimates of its matched
/// peaks, and the peak anchoring its thickness candidates.
struct PeakScan {
    /// The pair estimates that are finite and inside the cube's index range.
    estimates: Vec<f64>,
    /// Matched peak pairs, whatever their estimate.
    pairs_total: usize,
    /// Per pixel: (angle, band) of the peak that anchors the thickness candidates.
    anchors: Vec<Option<(usize, usize)>>,
    /// Per pixel: its defect flags.
    pixel_flags: Vec<u16>,
}

impl PeakScan {
    /// Scans every pixel's spectra; `order` holds the angles by incidence, `s2` their
    /// squared Snell invariants.
    fn run(cube: &SweepCube, order: &[usize], s2: &[f64]) -> Self {
        let (w, h) = (cube.width, cube.height);
        let nb = cube.bands_nm.len();
        let na = cube.angles_deg.len();
        let mut spectra = vec![0f32; na * nb];
        let mut smooth = vec![0f32; nb];
        let mut peaks: Vec<Vec<usize>> = vec![Vec::new(); na];
        let mut scan = Self {
            estimates: Vec::new(),
            pairs_total: 0,
            anchors: vec![None; w * h],
            pixel_flags: vec![0u16; w * h],
        };
        for row in 0..h {
            for col in 0..w {
                let p = row * w + col;
                pixel_spectra(cube, col, row, &mut spectra);
                scan.pixel_flags[p] = defect_flags(&spectra);
                for (a, list) in peaks.iter_mut().enumerate() {
                    smooth3(&spectra[a * nb..(a + 1) * nb], &mut smooth);
                    local_maxima(&smooth, list);
                }
                scan.pair_estimates(cube, order, s2, &peaks);
                scan.anchors[p] = order.iter().find_map(|&a| {
                    let spec = &spectra[a * nb..(a + 1) * nb];
                    smooth3(spec, &mut smooth);
                    peaks[a]
                        .iter()
                        .copied()
                        .max_by(|&x, &y| smooth[x].total_cmp(&smooth[y]))
                        .map(|b| (a, b))
                });
            }
        }
        scan
    }

    /// Matches each peak of one pixel (`peaks`, per angle) to the nearest peak at the next
    /// angle by incidence at a shorter-or-equal wavelength, and keeps the eq. 12 index of
    /// each pair that is finite and inside the cube's index range.
    fn pair_estimates(
        &mut self,
        cube: &SweepCube,
        order: &[usize],
        s2: &[f64],
        peaks: &[Vec<usize>],
    ) {
        for pair in order.windows(2) {
            let (a1, a2) = (pair[0], pair[1]);
            for &b1 in &peaks[a1] {
                let l1 = cube.bands_nm[b1];
                // Nearest peak at the next angle at a shorter-or-equal wavelength.
                let matched = peaks[a2]
                    .iter()
                    .map(|&b| cube.bands_nm[b])
                    .filter(|&l| l <= l1)
                    .max_by(f64::total_cmp);
                let Some(l2) = matched else { continue };
                self.pairs_total += 1;
                let n = eq12(l1, l2, s2[a1], s2[a2]);
                if n.is_finite() && n >= cube.index_range[0] && n <= cube.index_range[1] {
                    self.estimates.push(n);
                }
            }
        }
    }
}

/// Step 4 of [`paper`]: each pixel's thickness, the integer order whose model spectra are
/// nearest its measured ones, and the counts its notes give.
struct Orders {
    thickness: Vec<f32>,
    confidence: Vec<f32>,
    solved: usize,
    no_peak: usize,
    out_of_range: usize,
    /// The model table's thickness step, nm.
    step: f64,
}

impl Orders {
    /// Solves every pixel under the index `n` from its anchor peak (`anchors`), flagging
    /// in `pixel_flags` the pixels without a peak or without an order inside the range.
    fn solve(
        cube: &SweepCube,
        n: f64,
        s2: &[f64],
        anchors: &[Option<(usize, usize)>],
        pixel_flags: &mut [u16],
    ) -> Self {
        let (w, h) = (cube.width, cube.height);
        let nab = cube.angles_deg.len() * cube.bands_nm.len();
        let [d_lo, d_hi] = cube.thickness_range_nm;
        let step = TABLE_STEP_NM.max((d_hi - d_lo) / (TABLE_MAX_ROWS - 1) as f64);
        let rows = ((d_hi - d_lo) / step).ceil() as usize + 1;
        let table = model_table(cube, n, d_lo, step, rows, DEFAULT_NODES);

        let mut spectra = vec![0f32; nab];
        let mut orders = Self {
            thickness: vec![f32::NAN; w * h],
            confidence: vec![0f32; w * h],
            solved: 0,
            no_peak: 0,
            out_of_range: 0,
            step,
        };
        for row in 0..h {
            for col in 0..w {
                let p = row * w + col;
                let Some((a, b)) = anchors[p] else {
                    pixel_flags[p] |= flags::NO_FRINGE;
                    orders.no_peak += 1;
                    continue;
                };
                pixel_spectra(cube, col, row, &mut spectra);
                let kz = (n * n - s2[a]).sqrt();
                let lambda = cube.bands_nm[b];
                // Eq. 13 with integer orders m = 1, 2, ...: d = m lambda / (2 kz), inside the
                // range.
                let per_order = lambda / (2.0 * kz);
                let m_lo = (d_lo / per_order).ceil().max(1.0);
                let m_hi = (d_hi / per_order).floor().min(m_lo + MAX_ORDERS);
                let mut best: Option<(f64, f64)> = None;
                let mut m = m_lo;
                while m <= m_hi {
                    let d = m * per_order;
                    m += 1.0;
                    if !(d >= d_lo && d <= d_hi) {
                        continue;
                    }
                    let bound = best.map_or(f64::INFINITY, |(s, _)| s);
                    let sse = interpolated_sse(&table, nab, (d - d_lo) / step, &spectra, bound);
                    if sse < bound {
                        best = Some((sse, d));
                    }
                }
                match best {
                    Some((_, d)) => {
                        orders.thickness[p] = d as f32;
                        orders.confidence[p] = 1.0;
                        pixel_flags[p] = 0;
                        orders.solved += 1;
                    }
                    None => {
                        pixel_flags[p] |= flags::OUT_OF_RANGE;
                        orders.out_of_range += 1;
                    }
                }
            }
        }
        orders
    }
}

/// Eq. 12: the index from one order's peak wavelengths `l1`, `l2` at two angles whose squared
/// Snell invariants are `s1`, `s2` (NaN or infinite when the pair says nothing).
fn eq12(l1: f64, l2: f64, s1: f64, s2: f64) -> f64 {
    let (q1, q2) = (l1 * l1, l2 * l2);
    ((q2 * s1 - q1 * s2) / (q2 - q1)).sqrt()
}

/// Half-width of the moving average, bands.
const SMOOTH_HALF: usize = 4;
/// A peak must be the highest smoothed value within this many bands either side.
const PEAK_HALF: usize = 12;

/// The `2 SMOOTH_HALF + 1`-tap moving average of the finite samples around each finite sample
/// (NaN where the sample itself is not finite).
fn smooth3(x: &[f32], out: &mut [f32]) {
    for (i, o) in out.iter_mut().enumerate() {
        *o = if x[i].is_finite() {
            let lo = i.saturating_sub(SMOOTH_HALF);
            let hi = (i + SMOOTH_HALF + 1).min(x.len());
            let (sum, count) = x[lo..hi]
                .iter()
                .filter(|v| v.is_finite())
                .fold((0f32, 0f32), |(s, c), &v| (s + v, c + 1.0));
            sum / count
        } else {
            f32::NAN
        };
    }
}

/// The bands whose value is finite and the highest within `PEAK_HALF` bands either side (not
/// at the ends of the spectrum), into `out`.
fn local_maxima(x: &[f32], out: &mut Vec<usize>) {
    out.clear();
    for i in 1..x.len().saturating_sub(1) {
        let lo = i.saturating_sub(PEAK_HALF);
        let hi = (i + PEAK_HALF + 1).min(x.len());
        if x[i].is_finite()
            && x[i - 1].is_finite()
            && x[i + 1].is_finite()
            && x[i] > x[i - 1]
            && x[i] > x[i + 1]
            && x[lo..hi].iter().all(|&v| v.is_nan() || v <= x[i])
        {
            out.push(i);
        }
    }
}

/// Sum of squared differences between the measured spectra (finite samples only) and the
/// table's model spectra linearly interpolated at fractional row `x`; stops early (returning
/// a value `>= bound`) once the sum reaches `bound`.
fn interpolated_sse(table: &[f32], row_len: usize, x: f64, measured: &[f32], bound: f64) -> f64 {
    let rows = table.len() / row_len;
    let j = (x.floor().max(0.0) as usize).min(rows.saturating_sub(2));
    let t = (x - j as f64).clamp(0.0, 1.0) as f32;
    let r0 = &table[j * row_len..(j + 1) * row_len];
    let r1 = &table[(j + 1).min(rows - 1) * row_len..((j + 1).min(rows - 1) + 1) * row_len];
    let mut sse = 0.0;
    let chunk = 64;
    for ((c0, c1), cm) in r0
        .chunks(chunk)
        .zip(r1.chunks(chunk))
        .zip(measured.chunks(chunk))
    {
        let mut part = 0f32;
        for ((&a, &b), &m) in c0.iter().zip(c1).zip(cm) {
            if m.is_finite() {
                let e = a + t * (b - a) - m;
                part += e * e;
            }
        }
        sse += f64::from(part);
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
    fn eq12_recovers_the_index() {
        let (n, d, m) = (1.5f64, 600.0, 3.0);
        let s1 = 10f64.to_radians().sin().powi(2);
        let s2 = 30f64.to_radians().sin().powi(2);
        let l1 = 2.0 * d * (n * n - s1).sqrt() / m;
        let l2 = 2.0 * d * (n * n - s2).sqrt() / m;
        assert!((eq12(l1, l2, s1, s2) - n).abs() < 1e-9);
        assert!(!eq12(l1, l1, s1, s2).is_finite() || eq12(l1, l1, s1, s2) > 1e6);
    }

    #[test]
    fn peaks_ignore_non_finite_samples() {
        let x = [0.1, 0.3, 0.2, f32::NAN, 0.5, 0.1, f32::INFINITY, 0.4, 0.2];
        let mut s = [0f32; 9];
        smooth3(&x, &mut s);
        assert!(s[3].is_nan() && s[6].is_nan());
        // Band 1 averages the finite samples of bands 0..=5.
        assert!((s[1] - 0.24).abs() < 1e-6);
        let mut p = Vec::new();
        // 0.3 is topped by 0.5 within 12 bands; 0.5 and 0.4 sit beside non-finite samples.
        local_maxima(&x, &mut p);
        assert!(p.is_empty(), "{p:?}");
        local_maxima(&[0.1, 0.2, 0.5, 0.2, 0.1], &mut p);
        assert_eq!(p, vec![2]);
    }
}
