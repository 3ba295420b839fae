//! What real samples and real rigs add to the ideal single film: the departures a careful lab
//! still has, each off by default, for scenes that test an estimator on data its own model
//! did not make.
//!
//! The film's reflectance here is this module's own: a complex-index Airy sum (the film may
//! absorb), a bare back face summed incoherently, both polarisations where the polariser
//! leaks, the passband at a shifted wavelength plus the filter's side lobes, the stage at an
//! offset angle and stray light on top. None of it shares code with the estimator's model
//! (`filmscope_core::optics::FilmAtAngle`), only the material dispersions and the passband's
//! quadrature nodes.

use num_complex::Complex64 as C;

use filmscope_core::optics::{FilmStack, Passband, Polarization, HALF_WIDTH_FWHM};

/// Where the film's extinction coefficient is quoted, nm.
pub const K_REFERENCE_NM: f64 = 450.0;

/// How much wider the filter's side lobes are than its main passband.
pub const SIDE_LOBE_WIDTH: f64 = 10.0;

/// Quadrature nodes of the main passband.
pub const BAND_NODES: usize = 17;

/// The wavelengths a rig's optics pass, nm: the light of the filter's side lobes outside them
/// never reaches the sensor (the filter's own polarisers and a hot mirror before a silicon
/// sensor cut the ultraviolet and the infrared). Inside them every material's formula holds:
/// beyond, a high-index film's (TiO2's at 283 nm) runs through its pole.
pub const OPTICS_RANGE_NM: [f64; 2] = [380.0, 780.0];

/// Phase, radians, the film may turn by between two nodes of the side lobes' sum.
const SIDE_LOBE_NODE_PHASE: f64 = 0.25;

/// Grid nodes per shortest fringe period of a [`ImperfectTable`].
const POINTS_PER_FRINGE: f64 = 48.0;

/// A sample's and a rig's departures from the ideal film (all zero or off: the ideal).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Imperfections {
    /// The film's extinction coefficient at [`K_REFERENCE_NM`] (oxides and sulfides absorb
    /// a little in the blue: 0.001-0.01).
    pub film_k: f64,
    /// The extinction's Urbach tail, nm: `k(l) = film_k exp((K_REFERENCE_NM - l) / tail)`,
    /// rising to the blue (0: flat).
    pub film_k_tail_nm: f64,
    /// The stage's angle error, degrees: the sample is seen at the declared angle plus this.
    pub stage_offset_deg: f64,
    /// The filter's wavelength error, nm: a band declared at `l` passes `l + shift`.
    pub wavelength_shift_nm: f64,
    /// Stray light, as a fraction of a perfect white's signal added to every sample.
    pub flare: f64,
    /// The polariser's leak: this fraction of the light is of the other polarisation (s or
    /// p light only).
    pub polariser_leak: f64,
    /// The filter's side lobes: this fraction of the light comes through a passband
    /// [`SIDE_LOBE_WIDTH`] times wider than the main one (within [`OPTICS_RANGE_NM`]).
    pub side_lobes: f64,
    /// The substrate's back face is bare (glass, a PET web without a black backing): its
    /// reflection adds incoherently.
    pub bare_back_face: bool,
    /// The film's material absorbs (a tabulated nk entry): its own `k` adds to
    /// [`Imperfections::film_k`]'s.
    pub film_material_k: bool,
}

/// An imperfection outside the range the software camera models.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("[imperfections] {key} = {value} is outside {lo}..{hi}")]
pub struct ImperfectionError {
    /// The scene key.
    pub key: &'static str,
    /// The value given.
    pub value: f64,
    /// The least accepted.
    pub lo: f64,
    /// The most accepted.
    pub hi: f64,
}

impl Imperfections {
    /// Whether any departure is set.
    pub fn any(&self) -> bool {
        *self != Self::default()
    }

    /// Checks the values' ranges; one line naming the key otherwise.
    pub fn check(&self) -> Result<(), ImperfectionError> {
        let within = |key: &'static str, value: f64, lo: f64, hi: f64| {
            if value.is_finite() && (lo..=hi).contains(&value) {
                Ok(())
            } else {
                Err(ImperfectionError { key, value, lo, hi })
            }
        };
        within("film_k", self.film_k, 0.0, 0.5)?;
        within("film_k_tail_nm", self.film_k_tail_nm, 0.0, 1000.0)?;
        within("stage_offset_deg", self.stage_offset_deg, -5.0, 5.0)?;
        within("wavelength_shift_nm", self.wavelength_shift_nm, -10.0, 10.0)?;
        within("flare", self.flare, 0.0, 0.2)?;
        within("polariser_leak", self.polariser_leak, 0.0, 0.5)?;
        within("side_lobes", self.side_lobes, 0.0, 0.5)
    }

    /// The film's extinction coefficient at `l_nm`.
    pub fn k_at(&self, l_nm: f64) -> f64 {
        if self.film_k_tail_nm > 0.0 {
            self.film_k * ((K_REFERENCE_NM - l_nm) / self.film_k_tail_nm).exp()
        } else {
            self.film_k
        }
    }
}

/// The normal component `sqrt(N^2 - beta^2)` on the branch whose wave decays into the medium
/// (for `N = n - i k`: imaginary part not above zero).
fn kz(n: C, beta: f64) -> C {
    let k = (n * n - C::new(beta * beta, 0.0)).sqrt();
    if k.im > 0.0 {
        -k
    } else {
        k
    }
}

/// `(R, T, R')` of a film of complex index `n2` and `d_nm` on substrate `n3c` (complex for
/// an absorbing substrate) from ambient `n1`, for one pure polarisation (`p`: true for p) at
/// Snell invariant `beta`, wavelength `l_nm`. `T` is the power into a clear substrate
/// (lossless film: `1 - R`), the same either way through; `R'` the film's reflectance seen
/// from the substrate (`R` for a lossless film).
fn film_rt(n1: f64, n2: C, n3c: C, d_nm: f64, beta: f64, l_nm: f64, p: bool) -> (f64, f64, f64) {
    let (n1c, n3) = (C::new(n1, 0.0), n3c.re);
    let (k1, k2, k3) = (kz(n1c, beta), kz(n2, beta), kz(n3c, beta));
    let r = |na: C, nb: C, ka: C, kb: C| {
        if p {
            (nb * nb * ka - na * na * kb) / (nb * nb * ka + na * na * kb)
        } else {
            (ka - kb) / (ka + kb)
        }
    };
    let t = |na: C, nb: C, ka: C, kb: C| {
        if p {
            C::new(2.0, 0.0) * na * nb * ka / (nb * nb * ka + na * na * kb)
        } else {
            C::new(2.0, 0.0) * ka / (ka + kb)
        }
    };
    let (r12, r23) = (r(n1c, n2, k1, k2), r(n2, n3c, k2, k3));
    let (t12, t23) = (t(n1c, n2, k1, k2), t(n2, n3c, k2, k3));
    let delta = k2 * (2.0 * std::f64::consts::PI * d_nm / l_nm);
    let one_way = (-C::i() * delta).exp();
    let two_way = one_way * one_way;
    let denom = C::new(1.0, 0.0) + r12 * r23 * two_way;
    let rr = (r12 + r23 * two_way) / denom;
    let tt = t12 * t23 * one_way / denom;
    // Power transmitted: s by the ratio of normal components, p by those over n^2 times
    // n^2 (the field amplitude convention above), all real media outside the film.
    let ratio = if p {
        (k3 / (n3c * n3c)).re / (k1 / (n1c * n1c)).re * (n3 * n3) / (n1 * n1)
    } else {
        k3.re / k1.re
    };
    let inside = (r23 + r12 * two_way) / denom;
    (rr.norm_sqr(), tt.norm_sqr() * ratio, inside.norm_sqr())
}

/// The Fresnel reflectance of the substrate's bare back face, from inside the substrate
/// (index `n3`) into the ambient behind it (air), at Snell invariant `beta`.
fn back_face_r(n3: f64, beta: f64, p: bool) -> f64 {
    let (n3c, air) = (C::new(n3, 0.0), C::new(1.0, 0.0));
    let (k3, k4) = (kz(n3c, beta), kz(air, beta));
    let r = if p {
        (air * air * k3 - n3c * n3c * k4) / (air * air * k3 + n3c * n3c * k4)
    } else {
        (k3 - k4) / (k3 + k4)
    };
    r.norm_sqr()
}

/// The reflectance a rig with `imp` measures of `stack`'s film `d_nm` thick at the declared
/// angle `incidence_deg` through `band` (declared centre and width).
pub fn band_reflectance(
    stack: &FilmStack,
    imp: &Imperfections,
    d_nm: f64,
    incidence_deg: f64,
    band: &Passband,
) -> f64 {
    let deg = incidence_deg + imp.stage_offset_deg;
    let beta = stack.ambient_index * deg.to_radians().sin();
    let at = |l: f64, p: bool| -> f64 {
        let n2 = C::new(
            stack.film.index_at(l),
            -(imp.k_at(l) + stack.film.extinction_at(l)),
        );
        let (n3, k3) = (
            stack.substrate.index_at(l),
            stack.substrate.extinction_at(l),
        );
        let (r, t, r_inside) = film_rt(stack.ambient_index, n2, C::new(n3, -k3), d_nm, beta, l, p);
        // An absorbing substrate is opaque: no back face returns light.
        if imp.bare_back_face && k3 == 0.0 {
            let rb = back_face_r(n3, beta, p);
            r + t * t * rb / (1.0 - r_inside * rb)
        } else {
            r
        }
    };
    let light = |l: f64| -> f64 {
        let (s, p) = (|| at(l, false), || at(l, true));
        match stack.polarization {
            Polarization::S => (1.0 - imp.polariser_leak) * s() + imp.polariser_leak * p(),
            Polarization::P => (1.0 - imp.polariser_leak) * p() + imp.polariser_leak * s(),
            Polarization::Unpolarized => 0.5 * (s() + p()),
        }
    };
    let mean = |b: &Passband| -> f64 {
        let (mut sum, mut wsum) = (0.0, 0.0);
        for (l, w) in b.nodes() {
            sum += w * light(l + imp.wavelength_shift_nm);
            wsum += w;
        }
        sum / wsum
    };
    let main = Passband::gaussian_with_nodes(band.center_nm, band.fwhm_nm, BAND_NODES);
    let mut r = mean(&main);
    if imp.side_lobes > 0.0 {
        let wide = side_lobe_mean(stack, d_nm, band, |l| light(l + imp.wavelength_shift_nm));
        r = (1.0 - imp.side_lobes) * r + imp.side_lobes * wide;
    }
    r + imp.flare
}

/// The mean of `light` over the side lobes' band: a Gaussian [`SIDE_LOBE_WIDTH`] times the
/// main band's FWHM, truncated at [`HALF_WIDTH_FWHM`] and to [`OPTICS_RANGE_NM`], summed by
/// trapezoids at most [`SIDE_LOBE_NODE_PHASE`] of the film's phase apart (a film microns
/// thick turns through dozens of fringes across it).
fn side_lobe_mean(
    stack: &FilmStack,
    d_nm: f64,
    band: &Passband,
    light: impl Fn(f64) -> f64,
) -> f64 {
    let fwhm = SIDE_LOBE_WIDTH * band.fwhm_nm;
    let half = HALF_WIDTH_FWHM * fwhm;
    let lo = (band.center_nm - half).max(OPTICS_RANGE_NM[0]);
    let hi = (band.center_nm + half).min(OPTICS_RANGE_NM[1]);
    if fwhm.is_nan() || fwhm <= 0.0 || hi <= lo {
        return light(band.center_nm);
    }
    let n_max = stack
        .film
        .index_at(lo)
        .max(stack.film.index_at(hi))
        .max(1.0);
    let span = 4.0 * std::f64::consts::PI * n_max * d_nm * (1.0 / lo - 1.0 / hi);
    let count = ((span / SIDE_LOBE_NODE_PHASE).ceil() as usize).clamp(32, 4096);
    let sigma = fwhm / (8.0 * std::f64::consts::LN_2).sqrt();
    let (mut sum, mut wsum) = (0.0, 0.0);
    for i in 0..=count {
        let l = lo + (hi - lo) * i as f64 / count as f64;
        let end = if i == 0 || i == count { 0.5 } else { 1.0 };
        let w = end * (-0.5 * ((l - band.center_nm) / sigma).powi(2)).exp();
        sum += w * light(l);
        wsum += w;
    }
    sum / wsum
}

/// One `(angle, band)`'s measured reflectance over a thickness range, sampled at
/// [`POINTS_PER_FRINGE`] nodes over the shortest fringe period and read by Catmull-Rom
/// interpolation (within 1e-5 of [`band_reflectance`]).
#[derive(Clone, Debug)]
pub struct ImperfectTable {
    first_nm: f64,
    per_nm: f64,
    values: Vec<f64>,
}

impl ImperfectTable {
    /// Tabulates [`band_reflectance`] over `[min_nm, max_nm]`, the film's largest index in
    /// the band being `max_index`.
    pub fn new(
        stack: &FilmStack,
        imp: &Imperfections,
        incidence_deg: f64,
        band: &Passband,
        [min_nm, max_nm]: [f64; 2],
        max_index: f64,
    ) -> Self {
        let l_min = band.center_nm - 2.0 * band.fwhm_nm;
        let period = (l_min.max(100.0)) / (2.0 * max_index.max(1.0));
        let step = period / POINTS_PER_FRINGE;
        let first = min_nm - 2.0 * step;
        let count = (((max_nm - min_nm) / step).ceil() as usize) + 5;
        let values = (0..count)
            .map(|i| band_reflectance(stack, imp, first + step * i as f64, incidence_deg, band))
            .collect();
        Self {
            first_nm: first,
            per_nm: 1.0 / step,
            values,
        }
    }

    /// The interpolated reflectance at `thickness_nm` (clamped to the table).
    pub fn reflectance(&self, thickness_nm: f64) -> f64 {
        let n = self.values.len();
        let t = ((thickness_nm - self.first_nm) * self.per_nm).clamp(1.0, (n - 3) as f64);
        let i = (t as usize).min(n - 3);
        let u = t - i as f64;
        let (p0, p1, p2, p3) = (
            self.values[i - 1],
            self.values[i],
            self.values[i + 1],
            self.values[i + 2],
        );
        p1 + 0.5
            * u
            * (p2 - p0
                + u * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3 + u * (3.0 * (p1 - p2) + p3 - p0)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use filmscope_core::optics::{film_reflectance, Dispersion, Indices};

    fn stack(pol: Polarization) -> FilmStack {
        FilmStack {
            back_face: filmscope_core::optics::BackFace::None,
            ambient_index: 1.0,
            film: Dispersion::constant(2.1),
            substrate: Dispersion::constant(1.52),
            polarization: pol,
        }
    }

    /// With nothing set, the film's reflectance is the ideal Airy sum (the core's), at
    /// every polarisation, angle and thickness tried, to 1e-12.
    #[test]
    fn no_imperfection_is_the_ideal_film() {
        let imp = Imperfections::default();
        for pol in [Polarization::S, Polarization::P, Polarization::Unpolarized] {
            for (d, deg, l) in [
                (120.0, 0.0, 450.0),
                (640.0, 35.0, 612.0),
                (1500.0, 65.0, 700.0),
            ] {
                let band = Passband::gaussian_with_nodes(l, 0.0, 1);
                let ours = band_reflectance(&stack(pol), &imp, d, deg, &band);
                let idx = Indices {
                    back_face: filmscope_core::optics::BackFace::None,
                    ambient: 1.0,
                    film: 2.1,
                    substrate: 1.52,
                    substrate_k: 0.0,
                };
                let core = film_reflectance(idx, d, deg, l, pol);
                assert!(
                    (ours - core).abs() < 1e-12,
                    "{pol:?} {d} {deg}: {ours} vs {core}"
                );
            }
        }
    }

    /// A lossless film conserves power (R + T = 1) at any polarisation and angle; an
    /// absorbing one loses some; a bare back face of glass at normal incidence adds its
    /// textbook 4 % to a bare substrate's 4.3 % (R + T^2 Rb / (1 - R Rb) = 8.3 %).
    #[test]
    fn power_is_conserved_and_the_back_face_adds_its_reflection() {
        for p in [false, true] {
            let (r, t, inside) = film_rt(
                1.0,
                C::new(2.1, 0.0),
                C::new(1.52, 0.0),
                333.0,
                0.6,
                555.0,
                p,
            );
            assert!((r + t - 1.0).abs() < 1e-12, "{r} + {t}");
            assert!((inside - r).abs() < 1e-12, "{inside} vs {r}");
            let (r, t, inside) = film_rt(
                1.0,
                C::new(2.1, -0.05),
                C::new(1.52, 0.0),
                333.0,
                0.6,
                555.0,
                p,
            );
            assert!(r + t < 0.99, "{r} + {t}");
            assert!((inside - r).abs() > 1e-3, "{inside} vs {r}");
        }
        let bare = FilmStack {
            film: Dispersion::constant(1.52),
            ..stack(Polarization::S)
        };
        let band = Passband::gaussian_with_nodes(550.0, 0.0, 1);
        let front = band_reflectance(&bare, &Imperfections::default(), 100.0, 0.0, &band);
        let imp = Imperfections {
            bare_back_face: true,
            ..Default::default()
        };
        let both = band_reflectance(&bare, &imp, 100.0, 0.0, &band);
        let r = (0.52f64 / 2.52).powi(2);
        assert!((front - r).abs() < 1e-12, "{front}");
        let expect = r + (1.0 - r).powi(2) * r / (1.0 - r * r);
        assert!((both - expect).abs() < 1e-12, "{both} vs {expect}");
    }

    /// The table reads the exact model to 1e-5 between its nodes.
    #[test]
    fn the_table_reads_the_model() {
        let imp = Imperfections {
            film_k: 0.005,
            film_k_tail_nm: 80.0,
            side_lobes: 0.03,
            polariser_leak: 0.01,
            bare_back_face: true,
            ..Default::default()
        };
        let st = stack(Polarization::S);
        let band = Passband::gaussian(420.0, 4.0);
        let table = ImperfectTable::new(&st, &imp, 30.0, &band, [800.0, 900.0], 2.1);
        for i in 0..200 {
            let d = 800.0 + 0.5 * f64::from(i) + 0.123;
            let exact = band_reflectance(&st, &imp, d, 30.0, &band);
            assert!((table.reflectance(d) - exact).abs() < 1e-5, "{d}");
        }
    }
}
