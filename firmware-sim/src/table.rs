//! Band reflectance tabulated over thickness, for rendering at camera rates.
//!
//! A [`BandModel`] costs a cosine and a division per passband node (33 of them) for every
//! pixel. Over one `(angle, band)` the reflectance is a smooth function of thickness alone,
//! so the camera evaluates it once per node of a uniform grid covering the scene's thickness
//! range, with its exact derivative ([`BandModel::reflectance_and_slope`]), and interpolates
//! between nodes with the cubic Hermite polynomial of those values and slopes: a few flops a
//! pixel.
//!
//! The grid's step starts at [`POINTS_PER_FRINGE`] nodes over the shortest fringe period the
//! band can have (`lambda / (2 n)` at its bluest node and the film's highest index there),
//! and every interval's midpoint, where a Hermite cubic's error peaks, is checked against
//! the exact model: the step is halved until no midpoint is off by more than
//! [`MIDPOINT_TOLERANCE`]. The interpolation error is then below 1e-8 in reflectance
//! everywhere (`tests::table_matches_the_exact_model_on_random_thicknesses`), under the
//! resolution of the f32 reflectance a capture stores.

use filmscope_core::optics::BandModel;

/// Starting number of grid nodes per shortest fringe period.
pub const POINTS_PER_FRINGE: f64 = 160.0;

/// Largest error accepted at an interval's midpoint, in reflectance.
pub const MIDPOINT_TOLERANCE: f64 = 1e-9;

/// Halvings of the step tried before the table is given up (the caller then evaluates the
/// model itself).
const MAX_HALVINGS: u32 = 4;

/// One `(angle, band)`'s band reflectance over `[first_nm, first_nm + intervals * step_nm]`:
/// per interval the cubic `y0 + u (m0 + u (c2 + u c3))` in `u in [0, 1]`.
#[derive(Clone, Debug)]
pub struct ReflectanceTable {
    first_nm: f64,
    per_nm: f64,
    /// `[y0, m0, c2, c3]` per interval (`m0` the slope times the step).
    cubic: Vec<[f64; 4]>,
}

impl ReflectanceTable {
    /// Tabulates `model` over `[min_nm, max_nm]`, the film's largest index in the band
    /// being `max_index` and its bluest passband node `min_lambda_nm`. `None` if the table
    /// would need more than `max_nodes` nodes (evaluating the model per pixel is then
    /// cheaper) or its error could not be brought under [`MIDPOINT_TOLERANCE`].
    pub fn new(
        model: &BandModel,
        min_nm: f64,
        max_nm: f64,
        min_lambda_nm: f64,
        max_index: f64,
        max_nodes: usize,
    ) -> Option<Self> {
        if !(min_nm.is_finite() && max_nm >= min_nm && min_lambda_nm > 0.0 && max_index > 0.0) {
            return None;
        }
        let period_nm = min_lambda_nm / (2.0 * max_index);
        let mut step_nm = period_nm / POINTS_PER_FRINGE;
        for _ in 0..=MAX_HALVINGS {
            let span = max_nm - min_nm;
            let intervals = ((span / step_nm).ceil() as usize).max(1);
            if intervals + 1 > max_nodes {
                return None;
            }
            // The grid ends on `max_nm` exactly.
            let step = if span > 0.0 {
                span / intervals as f64
            } else {
                step_nm
            };
            let nodes: Vec<(f64, f64)> = (0..=intervals)
                .map(|i| {
                    let (r, slope) = model.reflectance_and_slope(min_nm + step * i as f64);
                    (r, slope * step)
                })
                .collect();
            let cubic: Vec<[f64; 4]> = nodes
                .windows(2)
                .map(|p| {
                    let ((y0, m0), (y1, m1)) = (p[0], p[1]);
                    [
                        y0,
                        m0,
                        3.0 * (y1 - y0) - 2.0 * m0 - m1,
                        2.0 * (y0 - y1) + m0 + m1,
                    ]
                })
                .collect();
            let table = Self {
                first_nm: min_nm,
                per_nm: 1.0 / step,
                cubic,
            };
            let worst = (0..intervals)
                .map(|i| {
                    let d = min_nm + step * (i as f64 + 0.5);
                    (table.reflectance(d) - model.reflectance(d)).abs()
                })
                .fold(0.0, f64::max);
            if worst <= MIDPOINT_TOLERANCE {
                return Some(table);
            }
            step_nm *= 0.5;
        }
        None
    }

    /// Nodes of the grid.
    pub fn nodes(&self) -> usize {
        self.cubic.len() + 1
    }

    /// The interpolated band reflectance at `thickness_nm` (clamped to the table's range).
    #[inline]
    pub fn reflectance(&self, thickness_nm: f64) -> f64 {
        let t = ((thickness_nm - self.first_nm) * self.per_nm).max(0.0);
        let last = self.cubic.len() - 1;
        let i = (t as usize).min(last);
        let u = t - i as f64;
        let [y0, m0, c2, c3] = self.cubic[i];
        y0 + u * (m0 + u * (c2 + u * c3))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use filmscope_core::optics::{materials, Dispersion, FilmStack, Passband, Polarization};

    /// Random stacks (every dispersion kind, s, p and unpolarised light, 0-80 degrees,
    /// FWHM 0-12 nm, ambient indices up to 1.6 so that some films are evanescent), each
    /// tabulated over a random thickness range and compared with the exact model at random
    /// thicknesses: never more than 1e-8 apart.
    #[test]
    fn table_matches_the_exact_model_on_random_thicknesses() {
        let mut rng = Rng::from_words(&[0x7AB1E]);
        let names = materials::names();
        let mut worst = 0.0f64;
        let mut tables = 0;
        for case in 0..240 {
            let film = match case % 4 {
                0 => Dispersion::constant(1.3 + 1.3 * rng.uniform()),
                1 => Dispersion::Cauchy {
                    a: 1.4 + 0.9 * rng.uniform(),
                    b_um2: 0.05 * rng.uniform(),
                    c_um4: 0.002 * rng.uniform(),
                },
                _ => {
                    let name = names[(rng.next_u64() % names.len() as u64) as usize];
                    materials::by_name(name).expect("library material")
                }
            };
            let polarization = [Polarization::S, Polarization::P, Polarization::Unpolarized]
                [(rng.next_u64() % 3) as usize];
            let stack = FilmStack {
                back_face: filmscope_core::optics::BackFace::None,
                ambient_index: if case % 5 == 0 {
                    1.0 + 0.6 * rng.uniform()
                } else {
                    1.0
                },
                film,
                substrate: Dispersion::constant(1.45 + 0.35 * rng.uniform()),
                polarization,
            };
            let angle = 80.0 * rng.uniform();
            let center = 380.0 + 380.0 * rng.uniform();
            let fwhm = if case % 7 == 0 {
                0.0
            } else {
                12.0 * rng.uniform()
            };
            let band = Passband::gaussian(center, fwhm);
            let model = BandModel::new(stack, angle, band);
            let lo = 2000.0 * rng.uniform();
            let hi = lo + 600.0 * rng.uniform();
            let min_lambda = band.nodes().map(|(l, _)| l).fold(f64::INFINITY, f64::min);
            let max_index = band
                .nodes()
                .map(|(l, _)| stack.film.index_at(l))
                .fold(0.0, f64::max);
            let table = ReflectanceTable::new(&model, lo, hi, min_lambda, max_index, 1 << 20)
                .expect("a table within its tolerance");
            tables += 1;
            for _ in 0..400 {
                let d = lo + (hi - lo) * rng.uniform();
                let err = (table.reflectance(d) - model.reflectance(d)).abs();
                worst = worst.max(err);
                assert!(
                    err < 1e-8,
                    "case {case}: {stack:?} at {angle} deg, {center} nm / {fwhm} nm, d {d}: {err}"
                );
            }
            // The range's ends are nodes: exact there.
            for d in [lo, hi] {
                assert!((table.reflectance(d) - model.reflectance(d)).abs() < 1e-12);
            }
        }
        assert_eq!(tables, 240);
        assert!(worst > 0.0);
    }

    /// A table that would need more nodes than allowed is refused (the model is then
    /// evaluated per pixel).
    #[test]
    fn a_table_larger_than_allowed_is_refused() {
        let stack = FilmStack {
            back_face: filmscope_core::optics::BackFace::None,
            ambient_index: 1.0,
            film: Dispersion::constant(2.4),
            substrate: Dispersion::constant(1.5),
            polarization: Polarization::S,
        };
        let model = BandModel::new(stack, 30.0, Passband::gaussian(400.0, 4.0));
        assert!(ReflectanceTable::new(&model, 100.0, 2000.0, 394.0, 2.4, 100).is_none());
        let t = ReflectanceTable::new(&model, 100.0, 2000.0, 394.0, 2.4, 1 << 20).expect("table");
        assert!(t.nodes() > 100);
    }
}
