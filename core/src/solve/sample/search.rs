//! The global search: a grid over the index at 550 nm and a Cauchy slope, each point scored
//! by every search site's best thickness from a dictionary over the thickness range, so the
//! joint fit starts in the right fringe order.

use super::{
    dot, ModelKind, Problem, Starts, L0_UM, MAX_DICTIONARY, MAX_SITES, SEARCH_ANGLES, SEARCH_BANDS,
    SEARCH_SITES, SEAT_BANDS,
};
use crate::optics::{FilmAtAngle, Polarization};

/// Columns of [`Problem::score_point`]'s dictionary at most: angles times bands.
const COLUMNS: usize = SEARCH_ANGLES * SEAT_BANDS;

/// The dictionary's rows (`rows`: `nv` columns each, a row a thickness) and each row's sum
/// of squares (`m2`), for a film of `P` polarisations: each column's phase advances by a
/// rotation and its passband damping by a ratio that itself shrinks geometrically (`st`,
/// `rot`), so no row needs a cosine or an exponential; its reflectance is
/// [`FilmAtAngle::reflectance_at_cos`]'s from the column's `terms`, bit for bit.
#[inline(always)]
fn dictionary_rows<const P: usize>(
    rows: &mut [f32],
    nv: usize,
    m2: &mut [f64],
    st: &mut [[f64; COLUMNS]; 5],
    rot: &[[f64; COLUMNS]; 2],
    terms: &[[[f64; COLUMNS]; 3]; 2],
) {
    let mut m = [0.0f64; COLUMNS];
    let m = &mut m[..nv];
    for (row, m2) in rows.chunks_exact_mut(nv.max(1)).zip(m2.iter_mut()) {
        let [c, s, damp, ratio, shrink] = st;
        let (c, s, damp) = (&mut c[..nv], &mut s[..nv], &mut damp[..nv]);
        let (ratio, shrink) = (&mut ratio[..nv], &shrink[..nv]);
        let (cd, sd) = (&rot[0][..nv], &rot[1][..nv]);
        for j in 0..nv {
            let x = damp[j] * c[j];
            let mut sum = 0.0;
            for t in &terms[..P] {
                let b = t[1][j] * x;
                sum += (t[0][j] + b) / (t[2][j] + b);
            }
            m[j] = sum / P as f64;
            (c[j], s[j]) = (c[j] * cd[j] - s[j] * sd[j], s[j] * cd[j] + c[j] * sd[j]);
            damp[j] *= ratio[j];
            ratio[j] *= shrink[j];
        }
        let mut sum = 0.0;
        for (v, &mj) in row.iter_mut().zip(m.iter()) {
            *v = mj as f32;
            sum += mj * mj;
        }
        *m2 = sum;
    }
}

/// Slopes of the search's grid (Cauchy `b` from 0 in steps of 0.02 um^2).
const B_STEPS: usize = 7;

/// The search's grid of scores: a row an index at 550 nm, a column a slope.
type Grid = [[f64; B_STEPS]; 201];

/// The grid's axes: row `i` of `steps` the index `lo + (hi - lo) i / steps` at 550 nm,
/// column `j` the slope `0.02 j`.
#[derive(Clone, Copy)]
struct Axes {
    lo: f64,
    hi: f64,
    steps: usize,
}

impl Axes {
    /// Grid point `(i, j)` as Cauchy parameters.
    fn point(self, i: usize, j: usize) -> [f64; 3] {
        let n550 = self.lo + (self.hi - self.lo) * i as f64 / self.steps as f64;
        let b = 0.02 * j as f64;
        [n550 - b / (L0_UM * L0_UM), b, 0.0]
    }
}

impl Problem<'_> {
    /// Each usable site's best thickness under `(kind, p)` over the thickness range, on the
    /// search bands; the summed chi-square (noise units).
    pub(super) fn start_thicknesses(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        t: &mut [f64; MAX_SITES],
        scratch: &mut [f32],
    ) -> Option<f64> {
        let all: [usize; MAX_SITES] = core::array::from_fn(|k| k);
        let n = self.usable.len();
        let sites = &all[..n];
        self.score_point(
            kind,
            p,
            sites,
            self.geo.bands_nm.len(),
            0,
            scratch,
            Some(t),
            None,
        )
    }

    /// The global search over `(n550, b)` on bands `from..bands` (every so many): the best
    /// grid point refined locally, as Cauchy parameters, and the fringes its best site
    /// thickness puts across the whole band.
    pub(super) fn search(
        &self,
        bands: usize,
        from: usize,
        scratch: &mut [f32],
    ) -> Option<(Starts, f64)> {
        // The search's sites: usable ones, spread over the sample.
        let mut chosen: heapless::Vec<usize, SEARCH_SITES> = heapless::Vec::new();
        let used: heapless::Vec<usize, MAX_SITES> =
            (0..self.usable.len()).filter(|&k| self.usable[k]).collect();
        let step = used.len().div_ceil(SEARCH_SITES).max(1);
        for &k in used.iter().step_by(step) {
            if chosen.push(k).is_err() {
                break;
            }
        }
        let [lo, hi] = self.geo.index_range;
        let n_steps = (libm::ceil((hi - lo) / 0.05) as usize).clamp(1, 200);
        let axes = Axes {
            lo,
            hi,
            steps: n_steps,
        };
        let mut grid = [[f64::INFINITY; B_STEPS]; 201];
        self.score_grid(&mut grid, axes, &chosen, bands, from, scratch);
        // The three deepest local minima, each refined on a finer grid.
        let mut minima = local_minima(&grid, n_steps);
        minima.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let mut found: Starts = heapless::Vec::new();
        for &(_, i, j) in minima.iter().take(3) {
            let c = axes.point(i, j);
            if let Some((score, p)) = self.refine_minimum(c, axes, &chosen, bands, from, scratch) {
                let _ = found.push((score, p));
            }
        }
        found.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let (_, p) = *found.first()?;
        let fringes = self.fringes(&p, &chosen, bands, from, scratch)?;
        Some((found, fringes))
    }

    /// Scores every grid point with the sites `chosen`, the rows in two halves run in parallel
    /// (each with half of `scratch`); a point far above the index range stays infinite.
    fn score_grid(
        &self,
        grid: &mut Grid,
        axes: Axes,
        chosen: &[usize],
        bands: usize,
        from: usize,
        scratch: &mut [f32],
    ) {
        let (hi, n_steps) = (axes.hi, axes.steps);
        // Rows of the grid in two halves, each with half the workspace.
        let half = (n_steps + 1).div_ceil(2);
        let (top, bottom) = grid.split_at_mut(half);
        let split = scratch.len() / 2;
        let (s1, s2) = scratch.split_at_mut(split);
        let score_rows = |rows: &mut [[f64; B_STEPS]], first: usize, scratch: &mut [f32]| {
            for (r, row) in rows.iter_mut().enumerate() {
                let i = first + r;
                if i > n_steps {
                    break;
                }
                for (j, cell) in row.iter_mut().enumerate() {
                    let p = axes.point(i, j);
                    let l_lo = self.geo.bands_nm[from];
                    if ModelKind::Cauchy2.eval(&p, l_lo * 1e-3).0 > hi + 0.3 {
                        continue;
                    }
                    if let Some(s) = self.score_point(
                        ModelKind::Cauchy2,
                        &p,
                        chosen,
                        bands,
                        from,
                        scratch,
                        None,
                        None,
                    ) {
                        *cell = s;
                    }
                }
            }
        };
        let mut a = || score_rows(top, 0, s1);
        let mut b = || score_rows(bottom, half, s2);
        self.par.run(&mut [&mut a, &mut b]);
    }

    /// The best point of a finer grid (index steps 0.01, slope steps 0.005) about the minimum `c`,
    /// so a start is not bound to the coarse grid's spacing.
    fn refine_minimum(
        &self,
        c: [f64; 3],
        Axes { lo, hi, .. }: Axes,
        chosen: &[usize],
        bands: usize,
        from: usize,
        scratch: &mut [f32],
    ) -> Option<(f64, [f64; 3])> {
        let mut best: Option<(f64, [f64; 3])> = None;
        let (n0, b0) = (c[0] + c[1] / (L0_UM * L0_UM), c[1]);
        for di in -5i32..=5 {
            for dj in -4i32..=4 {
                let n550 = n0 + 0.01 * f64::from(di);
                let b = b0 + 0.005 * f64::from(dj);
                if b < 0.0 || n550 < lo || n550 > hi {
                    continue;
                }
                let p = [n550 - b / (L0_UM * L0_UM), b, 0.0];
                if let Some(s) = self.score_point(
                    ModelKind::Cauchy2,
                    &p,
                    chosen,
                    bands,
                    from,
                    scratch,
                    None,
                    None,
                ) {
                    if best.is_none_or(|(bs, _)| s < bs) {
                        best = Some((s, p));
                    }
                }
            }
        }
        best
    }

    /// Fringes across the whole band under `p` at the median seated thickness of `chosen`, which
    /// says whether the capture resolves the film's fringes.
    fn fringes(
        &self,
        p: &[f64; 3],
        chosen: &[usize],
        bands: usize,
        from: usize,
        scratch: &mut [f32],
    ) -> Option<f64> {
        // Fringes across the whole band at the search sites' median thickness.
        let mut t = [f64::NAN; MAX_SITES];
        self.score_point(
            ModelKind::Cauchy2,
            p,
            chosen,
            bands,
            from,
            scratch,
            Some(&mut t),
            None,
        )?;
        let mut ts: heapless::Vec<f64, MAX_SITES> = chosen
            .iter()
            .map(|&k| t[k])
            .filter(|x| x.is_finite())
            .collect();
        ts.sort_unstable_by(f64::total_cmp);
        let d = *ts.get(ts.len() / 2)?;
        let b = &self.geo.bands_nm;
        let (l_lo, l_hi) = (b[0].min(b[b.len() - 1]), b[0].max(b[b.len() - 1]));
        let n = ModelKind::Cauchy2.eval(p, L0_UM).0;
        let fringes = 2.0 * n * d * (1.0 / l_lo - 1.0 / l_hi);
        Some(fringes)
    }

    /// Summed chi-square (noise units) of `sites`, each at its best thickness under
    /// `(kind, p)`, on every so many of bands `from..bands` (at most [`SEARCH_BANDS`], or
    /// [`SEAT_BANDS`] when the thicknesses are wanted) with passband-damped centre
    /// wavelengths; writes the thicknesses into `t` when given.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn score_point(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        sites: &[usize],
        bands: usize,
        from: usize,
        scratch: &mut [f32],
        mut t: Option<&mut [f64; MAX_SITES]>,
        mut margin: Option<&mut [f64; MAX_SITES]>,
    ) -> Option<f64> {
        let geo = self.geo;
        let span = bands - from;
        // Scoring a grid point takes the search's bands; seating sites, more of them.
        let max_bands = if t.is_some() {
            SEAT_BANDS
        } else {
            SEARCH_BANDS
        };
        let stride = span.div_ceil(max_bands).max(1);
        let picked: heapless::Vec<usize, SEAT_BANDS> = (from..bands).step_by(stride).collect();
        let mut columns = Columns::new();
        let films = self.columns(kind, p, &picked, &mut columns)?;
        let nv = films.len();
        let [t_lo, t_hi] = geo.thickness_range_nm;
        let mut m2 = [0.0f64; MAX_DICTIONARY];
        let (count, h) = self.dictionary(films, scratch, &mut m2)?;
        // Half the shortest order step (where another order's basin begins).
        let l_min = geo.bands_nm.iter().copied().fold(f64::INFINITY, f64::min);
        let excluded_nm = l_min / (4.0 * kind.eval(p, l_min * 1e-3).0);
        let mut total = 0.0;
        let mut y = [0.0f32; SEARCH_ANGLES * SEAT_BANDS];
        for &k in sites {
            if !self.usable[k] {
                continue;
            }
            let y2 = self.site_columns(k, &picked, &mut y[..nv]);
            let mut sses = [f64::INFINITY; MAX_DICTIONARY];
            let best = best_row(
                &scratch[..count * nv],
                &m2[..count],
                &y[..nv],
                y2,
                &mut sses,
            );
            if let Some(m) = margin.as_deref_mut() {
                // The best thickness outside the chosen one's basin (half the shortest
                // order step either side): how much worse it fits, in noise units.
                let far = libm::ceil(excluded_nm / h) as usize;
                let alt = sses
                    .iter()
                    .enumerate()
                    .take(count)
                    .filter(|&(i, _)| i.abs_diff(best.1) > far)
                    .map(|(_, &v)| v)
                    .fold(f64::INFINITY, f64::min);
                m[k] = (alt - best.0) * self.noise.site_weight(k);
            }
            if t.is_none() {
                // Scoring a grid point: the minimum between dictionary rows.
                total += between_rows(&sses[..count], best) * self.noise.site_weight(k);
                continue;
            }
            // Seating a site: two Gauss-Newton steps on the thickness.
            let d = t_lo + h * best.1 as f64;
            let (d, sse) = gauss_newton(films, &y[..nv], (d, best.0), h, [t_lo, t_hi]);
            if let Some(t) = t.as_deref_mut() {
                t[k] = d;
            }
            total += sse * self.noise.site_weight(k);
        }
        Some(total)
    }

    /// The dictionary's columns under `(kind, p)`: the search's angles at the `picked` bands,
    /// angle-major (`None` where the model has no index or a wave does not propagate).
    fn columns<'c>(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        picked: &[usize],
        out: &'c mut Columns,
    ) -> Option<&'c [Column]> {
        let geo = self.geo;
        let na = geo.angles_deg.len();
        // Films and passband damping per (angle, band).
        for a in 0..na.min(SEARCH_ANGLES) {
            for &b in picked {
                let l = geo.bands_nm[b] + self.shift_nm;
                let n = kind.eval(p, l * 1e-3).0;
                if !n.is_finite() {
                    return None;
                }
                let deg = geo.angles_deg[a] + self.stage_deg;
                let f = FilmAtAngle::new(self.indices(n, l), deg, geo.polarization)?;
                let k = 4.0 * core::f64::consts::PI * f.kz_film / l;
                let s_l = geo.fwhm_nm[b] / 2.354_82;
                let _ = out.push((f, k, s_l / l));
            }
        }
        Some(out)
    }

    /// The dictionary's rows into `scratch` and their sums of squares into `m2`, for the columns
    /// `films`: the rows' count and step, nm (`None` when `scratch` cannot hold them).
    fn dictionary(
        &self,
        films: &[Column],
        scratch: &mut [f32],
        m2: &mut [f64; MAX_DICTIONARY],
    ) -> Option<(usize, f64)> {
        let geo = self.geo;
        let nv = films.len();
        let [t_lo, t_hi] = geo.thickness_range_nm;
        let k_max = films.iter().map(|f| f.1).fold(0.0, f64::max);
        let mut h = 0.5 / k_max.max(1e-9);
        let mut count = ((t_hi - t_lo) / h) as usize + 1;
        if count > MAX_DICTIONARY {
            count = MAX_DICTIONARY;
            h = (t_hi - t_lo) / (count - 1) as f64;
        }
        if scratch.len() < count * nv {
            return None;
        }
        // The dictionary, row by row of thickness: each column's phase advances by a
        // rotation and its passband damping by a ratio that itself shrinks geometrically,
        // so no row needs a cosine or an exponential.
        // Each column's state as arrays (cosine, sine, damping, its ratio and the ratio's
        // ratio; the rotation's cosine and sine; each polarisation's `(A, B, E)`), so that a
        // row's columns are computed in vector instructions.
        let mut st = [[0.0f64; COLUMNS]; 5];
        let mut rot = [[0.0f64; COLUMNS]; 2];
        let mut terms = [[[0.0f64; COLUMNS]; 3]; 2];
        for (j, f) in films.iter().enumerate() {
            let (p0, dp, s2) = (f.1 * t_lo, f.1 * h, f.2 * f.2);
            let psi = f.0.phase_offset();
            st[0][j] = libm::cos(p0 + psi);
            st[1][j] = libm::sin(p0 + psi);
            st[2][j] = libm::exp(-0.5 * s2 * p0 * p0);
            st[3][j] = libm::exp(-0.5 * s2 * (2.0 * p0 * dp + dp * dp));
            st[4][j] = libm::exp(-s2 * dp * dp);
            rot[0][j] = libm::cos(f.1 * h);
            rot[1][j] = libm::sin(f.1 * h);
            for (pol, t) in terms.iter_mut().enumerate() {
                (t[0][j], t[1][j], t[2][j]) = f.0.cos_terms(pol);
            }
        }
        let rows = &mut scratch[..count * nv];
        let m2_rows = &mut m2[..count];
        crate::simd::wide(
            true,
            #[inline(always)]
            || {
                if geo.polarization == Polarization::Unpolarized {
                    dictionary_rows::<2>(rows, nv, m2_rows, &mut st, &rot, &terms);
                } else {
                    dictionary_rows::<1>(rows, nv, m2_rows, &mut st, &rot, &terms);
                }
            },
        );
        Some((count, h))
    }

    /// Site `k`'s measured values at the dictionary's columns into `y`, a missing one filled with
    /// the site's mean (a constant on every row's score); their sum of squares.
    fn site_columns(&self, k: usize, picked: &[usize], y: &mut [f32]) -> f64 {
        let (na, nb) = (self.geo.angles_deg.len(), self.geo.bands_nm.len());
        let nbs = picked.len();
        let mut y2 = 0.0;
        let mut missing = false;
        for a in 0..na.min(SEARCH_ANGLES) {
            for (jb, &b) in picked.iter().enumerate() {
                let v = self.measured(nb, k, a, b) as f32;
                y[a * nbs + jb] = v;
                if !v.is_finite() {
                    missing = true;
                }
                y2 += f64::from(v) * f64::from(v);
            }
        }
        if missing {
            // Fill a missing value with the site's mean: it adds a constant to every
            // thickness's score.
            let (mut s, mut c) = (0.0, 0);
            for v in y.iter() {
                if v.is_finite() {
                    s += f64::from(*v);
                    c += 1;
                }
            }
            let mean = if c > 0 { (s / c as f64) as f32 } else { 0.0 };
            y2 = 0.0;
            for v in y.iter_mut() {
                if !v.is_finite() {
                    *v = mean;
                }
                y2 += f64::from(*v) * f64::from(*v);
            }
        }
        y2
    }
}

/// The grid's local minima (no neighbour below) as `(score, row, column)` in grid order,
/// the candidates for the finer search.
fn local_minima(grid: &Grid, n_steps: usize) -> heapless::Vec<(f64, usize, usize), 64> {
    let mut minima: heapless::Vec<(f64, usize, usize), 64> = heapless::Vec::new();
    for i in 0..=n_steps {
        for j in 0..B_STEPS {
            let v = grid[i][j];
            if !v.is_finite() {
                continue;
            }
            let mut is_min = true;
            for di in -1i32..=1 {
                for dj in -1i32..=1 {
                    let (ii, jj) = (i as i32 + di, j as i32 + dj);
                    if (di, dj) == (0, 0)
                        || ii < 0
                        || jj < 0
                        || ii > n_steps as i32
                        || jj >= B_STEPS as i32
                    {
                        continue;
                    }
                    if grid[ii as usize][jj as usize] < v {
                        is_min = false;
                    }
                }
            }
            if is_min && minima.push((v, i, j)).is_err() {
                break;
            }
        }
    }
    minima
}

/// One column of the dictionary: the film at an (angle, band), its phase per nm of
/// thickness and its passband's sigma over its wavelength (which damps the fringes).
type Column = (FilmAtAngle, f64, f64);

/// The dictionary's columns ([`Problem::columns`]).
type Columns = heapless::Vec<Column, { SEARCH_ANGLES * SEAT_BANDS }>;

/// Each dictionary row's sum of squared differences from the site's values `y` into `sses`;
/// the best row's `(sum, row)`.
fn best_row(
    rows: &[f32],
    m2: &[f64],
    y: &[f32],
    y2: f64,
    sses: &mut [f64; MAX_DICTIONARY],
) -> (f64, usize) {
    let (count, nv) = (m2.len(), y.len());
    crate::simd::wide(
        true,
        #[inline(always)]
        || {
            for (i, sse) in sses.iter_mut().enumerate().take(count) {
                *sse = m2[i] - 2.0 * dot(&rows[i * nv..(i + 1) * nv], y) + y2;
            }
        },
    );
    let mut best = (f64::INFINITY, 0usize);
    for (i, &sse) in sses.iter().enumerate().take(count) {
        if sse < best.0 {
            best = (sse, i);
        }
    }
    best
}

/// The least sum of squares between rows: the parabola's through the best row and its
/// neighbours, so a grid point's score does not depend on the row spacing.
fn between_rows(sses: &[f64], (mut sse, i): (f64, usize)) -> f64 {
    if i > 0 && i + 1 < sses.len() {
        let (a, c) = (sses[i - 1], sses[i + 1]);
        let curv = a - 2.0 * sse + c;
        if curv > 0.0 {
            sse = (sse - (c - a) * (c - a) / (8.0 * curv)).max(0.0);
        }
    }
    sse
}

/// A column's reflectance at thickness `d`, nm, its fringes damped by its passband.
fn column_model(f: &Column, d: f64) -> f64 {
    let ph = f.1 * d;
    let damp = libm::exp(-0.5 * (ph * f.2) * (ph * f.2));
    f.0.reflectance_at_cos(damp * libm::cos(ph + f.0.phase_offset()))
}

/// Two Gauss-Newton steps on a site's thickness from the dictionary's best `(d, sse)`, each at
/// most the row step `h` and inside `[t_lo, t_hi]`: the thickness and its sum of squares.
fn gauss_newton(
    films: &[Column],
    y: &[f32],
    (mut d, mut sse): (f64, f64),
    h: f64,
    [t_lo, t_hi]: [f64; 2],
) -> (f64, f64) {
    for _ in 0..2 {
        let (mut jj, mut jr, mut s2) = (0.0f64, 0.0f64, 0.0f64);
        for (f, v) in films.iter().zip(y) {
            let m = column_model(f, d);
            let dm = (column_model(f, d + 0.01) - m) / 0.01;
            let r = f64::from(*v) - m;
            jj += dm * dm;
            jr += dm * r;
            s2 += r * r;
        }
        sse = s2;
        if jj <= 0.0 {
            break;
        }
        let step = (jr / jj).clamp(-h, h);
        let d_new = (d + step).clamp(t_lo, t_hi);
        let s_new: f64 = films
            .iter()
            .zip(y)
            .map(|(f, v)| {
                let r = f64::from(*v) - column_model(f, d_new);
                r * r
            })
            .sum();
        if s_new < sse {
            d = d_new;
            sse = s_new;
        } else {
            break;
        }
    }
    (d, sse)
}
