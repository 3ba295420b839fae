//! The forward model the fits share: each site's measured value with the nuisance terms
//! taken out, and its band reflectance over the passband's quadrature nodes, with or
//! without the derivatives the least squares need.

use super::{
    ModelKind, Node, Nodes, Problem, SiteModel, INDEX_STEP, NOISE_ANGLES, SIDE_LOBE_WIDTH,
};
use crate::optics::{FilmAtAngle, Indices, LossyFilm, Polarization};
use crate::solve::refine::{absorption_shape, passband_phase_span, passband_rule};

impl Problem<'_> {
    /// Site `k`'s measured value at angle `a`, band `b`: the side lobes' light, the flare and
    /// its angle's scale and offset taken out (NaN: none). The side lobes pass the share `s`
    /// of the light from a wide band, whose reflectance the measured neighbouring bands give
    /// ([`Problem::wide_at`]): `y = (1 - s) R + s wide(R)`, so `R = (y - s wide(y)) / (1 - s)`
    /// to first order in `s` (the flare, in both, comes out the same).
    #[inline]
    pub(super) fn measured(&self, bands: usize, k: usize, a: usize, b: usize) -> f64 {
        let mut y = f64::from(self.spectra.centre_at(bands, k, a, b));
        if self.side_lobes > 0.0 {
            let s = self.side_lobes;
            let wide = match self
                .wide
                .get((k * self.geo.angles_deg.len() + a) * bands + b)
            {
                Some(&w) => f64::from(w),
                None => self.wide_at(bands, k, a, b),
            };
            y = (y - s * wide) / (1.0 - s);
        }
        let a = a.min(NOISE_ANGLES - 1);
        (y - self.flare - self.terms.offset[a]) / self.terms.scale[a]
    }

    /// Every site's [`Problem::wide_at`] into `out` (`[site][angle][band]`, at least
    /// sites x angles x bands long), which [`Problem::wide`] may then hold.
    pub(super) fn fill_wide(&self, out: &mut [f32]) {
        let (na, nb) = (self.geo.angles_deg.len(), self.geo.bands_nm.len());
        for k in 0..self.usable.len() {
            for a in 0..na {
                for b in 0..nb {
                    out[(k * na + a) * nb + b] = self.wide_at(nb, k, a, b) as f32;
                }
            }
        }
    }

    /// Site `k`'s measured reflectance at angle `a` averaged over the side lobes' band around
    /// band `b` (a Gaussian [`SIDE_LOBE_WIDTH`] times the band's FWHM, truncated at 1.5 of
    /// its FWHM), over the bands measured there.
    pub(super) fn wide_at(&self, bands: usize, k: usize, a: usize, b: usize) -> f64 {
        let l0 = self.geo.bands_nm[b];
        let fwhm = SIDE_LOBE_WIDTH * self.geo.fwhm_nm[b];
        let inv_2s2 = 4.0 * core::f64::consts::LN_2 / (fwhm * fwhm);
        let (mut sum, mut weight) = (0.0, 0.0);
        for (j, &l) in self.geo.bands_nm.iter().enumerate() {
            let x = l - l0;
            if libm::fabs(x) > 1.5 * fwhm {
                continue;
            }
            let v = f64::from(self.spectra.centre_at(bands, k, a, j));
            if v.is_finite() {
                let w = libm::exp(-x * x * inv_2s2);
                sum += w * v;
                weight += w;
            }
        }
        sum / weight
    }

    /// The indices at vacuum wavelength `l_nm`, the film's being `film`.
    pub(super) fn indices(&self, film: f64, l_nm: f64) -> Indices {
        Indices {
            ambient: self.geo.ambient_index,
            film,
            substrate: self.geo.substrate.index_at(l_nm),
            substrate_k: self.geo.substrate.extinction_at(l_nm),
            back_face: self.geo.back_face,
        }
    }

    /// The passband quadrature nodes of band `b` at angle `a` under model `(kind, p)` for
    /// films up to `d_max` ([`passband_rule`]), made in `out` (a caller's buffer: the nodes
    /// are large, and returned by value their copies cost more than the models they serve);
    /// `None` where a wave does not propagate.
    pub(super) fn nodes<'n>(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        a: usize,
        b: usize,
        d_max: f64,
        out: &'n mut Nodes,
    ) -> Option<&'n [Node]> {
        let (l0, fwhm) = (self.geo.bands_nm[b] + self.shift_nm, self.geo.fwhm_nm[b]);
        let deg = self.geo.angles_deg[a] + self.stage_deg;
        let pol = self.geo.polarization;
        let phase_per_nm = |l: f64| {
            let n = kind.eval(p, l * 1e-3).0;
            let f = FilmAtAngle::new(self.indices(n, l), deg, pol)?;
            Some(4.0 * core::f64::consts::PI * f.kz_film / l)
        };
        let span = passband_phase_span(l0, fwhm, d_max, phase_per_nm);
        let (rule, count) = passband_rule(l0, fwhm, span);
        let node = |(l, w): (f64, f64)| -> Option<Node> {
            let (n, dn_dp) = kind.eval(p, l * 1e-3);
            if !n.is_finite() {
                return None;
            }
            let film = FilmAtAngle::new(self.indices(n, l), deg, pol)?;
            let film_up = FilmAtAngle::new(self.indices(n + INDEX_STEP, l), deg, pol)?;
            let other = match pol {
                Polarization::S => Polarization::P,
                Polarization::P => Polarization::S,
                Polarization::Unpolarized => Polarization::Unpolarized,
            };
            let film_other = if self.leak > 0.0 && self.film_k == 0.0 {
                FilmAtAngle::new(self.indices(n, l), deg, other)?
            } else {
                film
            };
            let lossy = if self.film_k > 0.0 {
                let k = self.film_k * absorption_shape(l);
                [
                    LossyFilm::new(self.indices(n, l), k, deg, pol, l)?,
                    LossyFilm::new(self.indices(n + INDEX_STEP, l), k, deg, pol, l)?,
                    LossyFilm::new(self.indices(n, l), k, deg, other, l)?,
                ]
            } else {
                [LossyFilm::default(); 3]
            };
            Some(Node {
                weight: w,
                phase_per_nm: 4.0 * core::f64::consts::PI * film.kz_film / l,
                phase_up_per_nm: 4.0 * core::f64::consts::PI * film_up.kz_film / l,
                phase0: film.phase_offset(),
                phase0_up: film_up.phase_offset(),
                film,
                film_up,
                dn_dp,
                film_other,
                lossy,
            })
        };
        out.clear();
        for &r in &rule[..count] {
            let _ = out.push(node(r)?);
        }
        Some(out)
    }

    /// A site's band reflectance at thickness `d` over a band's passband `nodes`, without
    /// the derivatives [`Problem::site_model`] adds (half its cost, where only the value is
    /// read: residuals, reflectance terms, the slopes taken by a step).
    pub(super) fn site_value(&self, nodes: &[Node], d: f64) -> f64 {
        let e = self.leak;
        let mut m = 0.0;
        if self.film_k == 0.0 {
            for nd in nodes {
                let mut r = nd
                    .film
                    .reflectance_at_cos(libm::cos(nd.phase_per_nm * d + nd.phase0));
                if e > 0.0 {
                    let ph_o = nd.phase_per_nm * d + nd.film_other.phase_offset();
                    r = (1.0 - e) * r + e * nd.film_other.reflectance_at_cos(libm::cos(ph_o));
                }
                m += nd.weight * r;
            }
            return m;
        }
        for nd in nodes {
            let [film, _, other] = &nd.lossy;
            let (delta, a) = film.round_trip(d);
            let (sn, cs) = (libm::sin(delta), libm::cos(delta));
            let mut r = film.reflectance(cs, sn, a).0;
            if e > 0.0 {
                r = (1.0 - e) * r + e * other.reflectance(cs, sn, a).0;
            }
            m += nd.weight * r;
        }
        m
    }

    /// A site's band reflectance at thickness `d` over a band's passband `nodes`, with its
    /// derivatives, the film absorbing as [`Problem::film_k`] says ([`LossyFilm`]) and the
    /// polariser leaking as [`Problem::leak`] says.
    pub(super) fn site_model(&self, nodes: &[Node], d: f64) -> SiteModel {
        let mut out = SiteModel::default();
        if self.film_k == 0.0 {
            // A clear film: the lossless form, exact, and the other polarisation's for a leak.
            let e = self.leak;
            for nd in nodes {
                let ph = nd.phase_per_nm * d + nd.phase0;
                let (own, own_dc) = nd.film.reflectance_and_slope_at_cos(libm::cos(ph));
                let mut dr_dd = own_dc * -libm::sin(ph) * nd.phase_per_nm;
                let mut r = own;
                if e > 0.0 {
                    let ph_o = nd.phase_per_nm * d + nd.film_other.phase_offset();
                    let (o, o_dc) = nd.film_other.reflectance_and_slope_at_cos(libm::cos(ph_o));
                    r = (1.0 - e) * own + e * o;
                    dr_dd = (1.0 - e) * dr_dd + e * o_dc * -libm::sin(ph_o) * nd.phase_per_nm;
                }
                out.m += nd.weight * r;
                out.dm_dd += nd.weight * dr_dd;
                let r_up = nd
                    .film_up
                    .reflectance_at_cos(libm::cos(nd.phase_up_per_nm * d + nd.phase0_up));
                // The index's slope from the measured polarisation alone (the leak is small).
                for (q, j) in out.dm_dp.iter_mut().enumerate() {
                    *j += nd.weight * (r_up - own) / INDEX_STEP * (1.0 - e) * nd.dn_dp[q];
                }
            }
            return out;
        }
        for nd in nodes {
            let [film, up, other] = &nd.lossy;
            let (delta, a) = film.round_trip(d);
            let (sn, cs) = (libm::sin(delta), libm::cos(delta));
            let (own, own_dd, own_da) = film.reflectance(cs, sn, a);
            let (r, dr_ddelta, dr_da) = if self.leak > 0.0 {
                // The same film in the other polarisation: the same round trip.
                let (o, o_dd, o_da) = other.reflectance(cs, sn, a);
                let e = self.leak;
                (
                    (1.0 - e) * own + e * o,
                    (1.0 - e) * own_dd + e * o_dd,
                    (1.0 - e) * own_da + e * o_da,
                )
            } else {
                (own, own_dd, own_da)
            };
            out.m += nd.weight * r;
            out.dm_dd += nd.weight * (dr_ddelta * film.phase_per_nm - dr_da * film.loss_per_nm * a);
            let (delta_up, a_up) = up.round_trip(d);
            let r_up = up
                .reflectance(libm::cos(delta_up), libm::sin(delta_up), a_up)
                .0;
            // The index's slope from the measured polarisation alone (the leak is small).
            let dr_dn = (r_up - own) / INDEX_STEP * (1.0 - self.leak);
            for (q, j) in out.dm_dp.iter_mut().enumerate() {
                *j += nd.weight * dr_dn * nd.dn_dp[q];
            }
        }
        out
    }
}
