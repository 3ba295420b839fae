//! What the baselines share: cube checks, pixel defect flags, medians, the model stack.

use filmscope_core::optics::{Dispersion, FilmAtAngle, FilmStack, Passband};
use filmscope_core::solve::{flags, IndexModel};

use crate::estimate::method::{Method, MethodResult};
use crate::source::SweepCube;

/// Fraction of non-finite samples above which a pixel is not used (flagged SATURATED / DEAD).
pub(crate) const MAX_BAD_FRACTION: f64 = 0.1;

/// Checks that the cube's arrays agree with its sizes, so that indexing cannot go out of
/// bounds; `Err` names the first problem.
pub(crate) fn check_cube(cube: &SweepCube) -> Result<(), String> {
    let plane = cube.width * cube.height;
    let bands = cube.bands_nm.len();
    if plane == 0 {
        return Err(format!("empty image ({}x{})", cube.width, cube.height));
    }
    if bands < 3 {
        return Err(format!("{bands} bands: at least 3 are needed"));
    }
    if cube.bands_nm.windows(2).any(|w| w[1] <= w[0]) {
        return Err("band centres must increase strictly".into());
    }
    if cube.fwhm_nm.len() != bands {
        return Err(format!(
            "{} band widths for {bands} bands",
            cube.fwhm_nm.len()
        ));
    }
    if cube.angles_deg.is_empty() || cube.data.len() != cube.angles_deg.len() {
        return Err(format!(
            "{} angle cubes for {} angles",
            cube.data.len(),
            cube.angles_deg.len()
        ));
    }
    for (a, d) in cube.data.iter().enumerate() {
        if d.len() != plane * bands {
            return Err(format!(
                "angle {a}: {} samples, expected {plane} x {bands}",
                d.len()
            ));
        }
    }
    let ok = |x: &[f64]| x.iter().all(|v| v.is_finite());
    if !ok(&cube.bands_nm) || !ok(&cube.angles_deg) || !ok(&cube.index_range) {
        return Err("non-finite band, angle or index range".into());
    }
    if !(cube.thickness_range_nm[0].is_finite()
        && cube.thickness_range_nm[1].is_finite()
        && cube.thickness_range_nm[1] > cube.thickness_range_nm[0]
        && cube.index_range[1] >= cube.index_range[0])
    {
        return Err("empty index or thickness range".into());
    }
    Ok(())
}

/// The result for a cube that cannot be processed: every pixel NaN and flagged DEAD.
pub(crate) fn unusable(method: Method, cube: &SweepCube, problem: &str) -> MethodResult {
    let n = cube.width * cube.height;
    MethodResult {
        method,
        index: IndexModel::constant(f64::NAN),
        index_sigma: None,
        thickness_nm: vec![f32::NAN; n],
        confidence: vec![0.0; n],
        thickness_sigma_nm: vec![f32::NAN; n],
        flags: vec![flags::DEAD; n],
        notes: vec![format!("{}: unusable cube: {problem}", method.name())],
    }
}

/// The angle indices sorted by incidence angle (smallest first).
pub(crate) fn angles_by_incidence(cube: &SweepCube) -> Vec<usize> {
    let mut order: Vec<usize> = (0..cube.angles_deg.len()).collect();
    order.sort_by(|&a, &b| cube.angles_deg[a].total_cmp(&cube.angles_deg[b]));
    order
}

/// SATURATED or DEAD when more than [`MAX_BAD_FRACTION`] of `samples` are not finite
/// (SATURATED when `+inf` samples are the majority of them), else 0.
pub(crate) fn defect_flags(samples: &[f32]) -> u16 {
    let inf = samples.iter().filter(|v| **v == f32::INFINITY).count();
    let bad = samples.iter().filter(|v| !v.is_finite()).count();
    if (bad as f64) <= MAX_BAD_FRACTION * samples.len() as f64 {
        0
    } else if 2 * inf >= bad {
        flags::SATURATED
    } else {
        flags::DEAD
    }
}

/// The median of the finite values (mean of the middle two for an even count).
pub(crate) fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(values[n / 2]),
        _ => Some(0.5 * (values[n / 2 - 1] + values[n / 2])),
    }
}

/// The film stack of the cube with a constant film index `n`.
pub(crate) fn stack(cube: &SweepCube, n: f64) -> FilmStack {
    FilmStack {
        back_face: cube.back_face,
        ambient_index: cube.ambient_index,
        film: Dispersion::constant(n),
        substrate: Dispersion::constant(cube.substrate_index),
        polarization: cube.polarization,
    }
}

/// All spectra of pixel `(col, row)`, angle-major (`out[a * bands + b]`), in the cube's angle
/// order.
pub(crate) fn pixel_spectra(cube: &SweepCube, col: usize, row: usize, out: &mut [f32]) {
    let bands = cube.bands_nm.len();
    for (a, chunk) in out.chunks_exact_mut(bands).enumerate() {
        cube.spectrum_into(a, col, row, chunk);
    }
}

/// Fills a row-major table of `rows` rows (`table.len() / rows` values each) with
/// `fill(row, out)`, the rows shared between two threads.
pub(crate) fn fill_rows_parallel(
    table: &mut [f32],
    row_len: usize,
    fill: impl Fn(usize, &mut [f32]) + Sync,
) {
    if row_len == 0 {
        return;
    }
    let rows = table.len() / row_len;
    let half = rows.div_ceil(2).max(1);
    let fill = &fill;
    std::thread::scope(|s| {
        for (k, chunk) in table.chunks_mut(half * row_len).enumerate() {
            s.spawn(move || {
                for (i, out) in chunk.chunks_exact_mut(row_len).enumerate() {
                    fill(k * half + i, out);
                }
            });
        }
    });
}

/// Model spectra of a film of constant index `n` on the cube's substrate, for the thicknesses
/// `d_lo + step * j`, `j < rows`: row-major, `table[j * na * nb + a * nb + b]`, angles in the
/// cube's order.
///
/// Each band is the passband-weighted mean of the monochromatic Airy reflectance over
/// `nodes` Simpson nodes of a Gaussian of the band's FWHM (`nodes = 1`: the band centre only);
/// with [`filmscope_core::optics::DEFAULT_NODES`] this is exactly what
/// [`filmscope_core::optics::BandModel`] computes. Fast: with constant indices one
/// [`FilmAtAngle`] per angle serves every band and node, and the phase `4 pi d kz / lambda`
/// advances by a fixed rotation from one thickness to the next, so the table costs one
/// complex multiplication and one rational function per node and entry (no cosines). Two
/// threads share the bands.
pub(crate) fn model_table(
    cube: &SweepCube,
    n: f64,
    d_lo: f64,
    step: f64,
    rows: usize,
    nodes: usize,
) -> Vec<f32> {
    let nb = cube.bands_nm.len();
    let na = cube.angles_deg.len();
    let nab = na * nb;
    let film = stack(cube, n);
    let fast: Vec<Option<FilmAtAngle>> = cube
        .angles_deg
        .iter()
        .map(|&t| FilmAtAngle::new(film.indices_at(cube.bands_nm[0]), t, cube.polarization))
        .collect();
    // Column-major first (one column per angle and band, along the thicknesses), then
    // transposed.
    let mut columns = vec![0f32; nab * rows];
    fill_rows_parallel(&mut columns, rows, |ab, out| {
        let (a, b) = (ab / nb, ab % nb);
        let band = if nodes <= 1 {
            Passband::monochromatic(cube.bands_nm[b])
        } else {
            Passband::gaussian_with_nodes(cube.bands_nm[b], cube.fwhm_nm[b], nodes)
        };
        let mut acc = vec![0f64; out.len()];
        match &fast[a] {
            Some(f) => {
                for (l, wt) in band.nodes() {
                    let k = 4.0 * core::f64::consts::PI * f.kz_film / l;
                    let p0 = k * d_lo + f.phase_offset();
                    let (mut c, mut s) = (p0.cos(), p0.sin());
                    let (cr, sr) = ((k * step).cos(), (k * step).sin());
                    for v in acc.iter_mut() {
                        *v += wt * f.reflectance_at_cos(c);
                        (c, s) = (c * cr - s * sr, c * sr + s * cr);
                    }
                }
            }
            None => {
                // Evanescent wave in the film or substrate: the general Airy sum.
                for (j, v) in acc.iter_mut().enumerate() {
                    let d = d_lo + step * j as f64;
                    *v = band.average(|l| film.reflectance(d, cube.angles_deg[a], l));
                }
            }
        }
        for (o, v) in out.iter_mut().zip(&acc) {
            *o = *v as f32;
        }
    });
    let mut table = vec![0f32; rows * nab];
    for (ab, col) in columns.chunks_exact(rows.max(1)).enumerate() {
        for (j, &v) in col.iter().enumerate() {
            table[j * nab + ab] = v;
        }
    }
    table
}

#[cfg(test)]
mod tests {
    use super::*;
    use filmscope_core::optics::{BandModel, Polarization, DEFAULT_NODES};

    fn cube(n_bands: usize) -> SweepCube {
        let bands_nm: Vec<f64> = (0..n_bands).map(|b| 420.0 + 2.0 * b as f64).collect();
        SweepCube {
            back_face: Default::default(),
            width: 1,
            height: 1,
            fwhm_nm: vec![4.0; n_bands],
            bands_nm,
            angles_deg: vec![10.0, 50.0],
            ambient_index: 1.0,
            substrate_index: 1.65,
            polarization: Polarization::S,
            index_range: [1.2, 3.0],
            thickness_range_nm: [50.0, 2000.0],
            data: vec![vec![0.0; n_bands]; 2],
        }
    }

    #[test]
    fn model_table_is_the_band_model() {
        let c = cube(151);
        let (n, d_lo, step, rows) = (2.37, 50.0, 1.5, 1301);
        let table = model_table(&c, n, d_lo, step, rows, DEFAULT_NODES);
        let film = stack(&c, n);
        let nab = 2 * 151;
        let mut worst = 0f64;
        for a in 0..2 {
            for b in (0..151).step_by(10) {
                let band = Passband::gaussian(c.bands_nm[b], 4.0);
                let m = BandModel::new(film, c.angles_deg[a], band);
                for j in (0..rows).step_by(97).chain([rows - 1]) {
                    let exact = m.reflectance(d_lo + step * j as f64);
                    let got = f64::from(table[j * nab + a * 151 + b]);
                    worst = worst.max((exact - got).abs());
                }
            }
        }
        assert!(worst < 1e-6, "worst {worst}");
    }

    #[test]
    fn nine_nodes_are_close_to_33() {
        // ZnS up to 2 um: fringes down to ~19 nm period at 420 nm, 4 nm FWHM.
        let c = cube(151);
        let fine = model_table(&c, 2.37, 50.0, 2.0, 976, DEFAULT_NODES);
        let coarse = model_table(&c, 2.37, 50.0, 2.0, 976, 9);
        let worst = fine
            .iter()
            .zip(&coarse)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(worst < 1e-3, "worst {worst}");
    }

    #[test]
    fn defects_and_medians() {
        let mut s = [0.1f32; 20];
        assert_eq!(defect_flags(&s), 0);
        s[..2].fill(f32::NAN);
        assert_eq!(defect_flags(&s), 0);
        s[2] = f32::INFINITY;
        assert_eq!(defect_flags(&s), flags::DEAD);
        s[3..5].fill(f32::INFINITY);
        assert_eq!(defect_flags(&s), flags::SATURATED);
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, 2.0, 3.0]), Some(2.5));
        assert_eq!(median(&mut []), None);
    }
}
