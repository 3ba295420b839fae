//! The joint least squares (Levenberg-Marquardt) over every usable site, angle and band:
//! the model linearised at the index and each site's thickness, the normal equations
//! reduced to the index parameters, and the step that refines them.

use super::{
    Candidate, ModelKind, Nodes, Problem, SiteSums, CONSTANT_PREFERENCE, INDEX_STEP, L0_UM,
    MAX_SITES, MODEL_PENALTY,
};
#[cfg(doc)]
use crate::optics::FilmAtAngle;
use crate::optics::Polarization;
use nalgebra::{Matrix3, Vector3};

/// `(sin x, cos x)` of a film's phase (`|x|` under a million radians: a phase is a few
/// thousand at most), without a branch, so that a loop over many phases vectorises:
/// Cody-Waite reduction by pi/2 (the quotient below 2^20, so its product with the first
/// 33 bits of pi/2 is exact) and fdlibm's polynomials on `|r| <= pi/4`. Within 2 units in
/// the last place of `libm::sincos` (tested).
#[inline(always)]
#[allow(clippy::excessive_precision)] // fdlibm's constants as it prints them
pub(super) fn sincos_phase(x: f64) -> (f64, f64) {
    // Adding 1.5 * 2^52 rounds to an integer, which lands in the low bits.
    const TOINT: f64 = 6_755_399_441_055_744.0;
    const PIO2_1: f64 = 1.570_796_326_734_125_614_17;
    const PIO2_1T: f64 = 6.077_100_506_506_192_249_32e-11;
    const S: [f64; 6] = [
        -1.666_666_666_666_663_243_48e-1,
        8.333_333_333_322_489_461_24e-3,
        -1.984_126_982_985_794_931_34e-4,
        2.755_731_370_707_006_767_89e-6,
        -2.505_076_025_340_686_341_95e-8,
        1.589_690_995_211_550_102_21e-10,
    ];
    const C: [f64; 6] = [
        4.166_666_666_666_660_190_37e-2,
        -1.388_888_888_887_410_957_49e-3,
        2.480_158_728_947_672_941_78e-5,
        -2.755_731_435_139_066_330_35e-7,
        2.087_572_321_298_174_827_90e-9,
        -1.135_964_755_778_819_482_65e-11,
    ];
    let shifted = x * core::f64::consts::FRAC_2_PI + TOINT;
    let k = shifted - TOINT;
    let quadrant = shifted.to_bits();
    let r = (x - k * PIO2_1) - k * PIO2_1T;
    let z = r * r;
    let sp = S[1] + z * (S[2] + z * (S[3] + z * (S[4] + z * S[5])));
    let s = r + r * z * (S[0] + z * sp);
    let cp = z * (C[0] + z * (C[1] + z * (C[2] + z * (C[3] + z * (C[4] + z * C[5])))));
    let hz = 0.5 * z;
    let w = 1.0 - hz;
    let c = w + (((1.0 - w) - hz) + z * cp);
    let (sin, cos) = if quadrant & 1 == 0 { (s, c) } else { (c, s) };
    let sin = if quadrant & 2 == 0 { sin } else { -sin };
    let cos = if quadrant.wrapping_add(1) & 2 == 0 {
        cos
    } else {
        -cos
    };
    (sin, cos)
}

/// Where [`Problem::normal`] linearises the model: the index model and its parameters,
/// each site's thickness, and the thickest (which sets the passband quadrature's nodes).
#[derive(Clone, Copy)]
struct Linearisation<'a> {
    kind: ModelKind,
    p: &'a [f64; 3],
    t: &'a [f64; MAX_SITES],
    d_max: f64,
}

impl Problem<'_> {
    /// [`Problem::normal`]'s sums over sites `first..first + sites.len()` at `at`: theirs
    /// into `sites`, the index blocks returned (with `INDEX`; else only the thickness's sums
    /// are made, the index's derivatives skipped, and the blocks are zero). The sites'
    /// models are made a block at a time, node by node, in loops of fixed length that
    /// compile to vector instructions (AVX2 where the CPU has it): each site's sums take the
    /// nodes in the same order as one site at a time would.
    fn normal_part<const INDEX: bool>(
        &self,
        at: Linearisation<'_>,
        first: usize,
        sites: &mut [SiteSums],
    ) -> Option<(Matrix3<f64>, Vector3<f64>)> {
        if self.film_k > 0.0 || self.leak > 0.0 {
            return self.normal_absorbing::<INDEX>(at, first, sites);
        }
        crate::simd::wide(
            true,
            #[inline(always)]
            || match self.geo.polarization {
                Polarization::Unpolarized => self.normal_blocks::<INDEX, 2>(at, first, sites),
                _ => self.normal_blocks::<INDEX, 1>(at, first, sites),
            },
        )
    }

    /// [`Problem::normal_part`] for a film of `P` polarisations
    /// ([`FilmAtAngle::polarizations`]).
    #[inline(always)]
    fn normal_blocks<const INDEX: bool, const P: usize>(
        &self,
        Linearisation { kind, p, t, d_max }: Linearisation<'_>,
        first: usize,
        sites: &mut [SiteSums],
    ) -> Option<(Matrix3<f64>, Vector3<f64>)> {
        const BLOCK: usize = 16;
        let mut hpp = Matrix3::zeros();
        let mut gp = Vector3::zeros();
        if sites.is_empty() {
            return Some((hpp, gp));
        }
        let (na, nb) = (self.geo.angles_deg.len(), self.geo.bands_nm.len());
        let mut buf = Nodes::new();
        for a in 0..na {
            for b in 0..nb {
                let nodes = self.nodes(kind, p, a, b, d_max, &mut buf)?;
                for (blk, block) in sites.chunks_mut(BLOCK).enumerate() {
                    let base = first + blk * BLOCK;
                    let mut d = [0.0; BLOCK];
                    for (j, dj) in d.iter_mut().enumerate().take(block.len()) {
                        *dj = t[base + j];
                    }
                    let (mut m, mut jd) = ([0.0; BLOCK], [0.0; BLOCK]);
                    let mut jp = [[0.0; BLOCK]; 3];
                    for nd in nodes {
                        for j in 0..BLOCK {
                            let ph = nd.phase_per_nm * d[j] + nd.phase0;
                            let (sn, cs) = sincos_phase(ph);
                            let (r, dr_dc) = nd.film.reflectance_and_slope_at_cos_of::<P>(cs);
                            m[j] += nd.weight * r;
                            jd[j] += nd.weight * dr_dc * -sn * nd.phase_per_nm;
                            if INDEX {
                                // The raised index's phase is a small step `e` away: its
                                // cosine by the angle sum, `cos e` and `sin e` by their series.
                                let e = (nd.phase_up_per_nm - nd.phase_per_nm) * d[j]
                                    + (nd.phase0_up - nd.phase0);
                                let (ce, se) = (1.0 - 0.5 * e * e, e - e * e * e / 6.0);
                                let r_up = nd.film_up.reflectance_at_cos_of::<P>(cs * ce - sn * se);
                                let dr_dn = (r_up - r) / INDEX_STEP;
                                for (q, jq) in jp.iter_mut().enumerate() {
                                    jq[j] += nd.weight * dr_dn * nd.dn_dp[q];
                                }
                            }
                        }
                    }
                    for (j, s) in block.iter_mut().enumerate() {
                        let k = base + j;
                        if !self.usable[k] {
                            continue;
                        }
                        let y = self.measured(nb, k, a, b);
                        if !y.is_finite() {
                            continue;
                        }
                        let w = self.noise.weight(k, a, b);
                        let jp = Vector3::new(jp[0][j], jp[1][j], jp[2][j]);
                        s.add::<INDEX>(w, y - m[j], jd[j], jp, (&mut hpp, &mut gp));
                    }
                }
            }
        }
        Some((hpp, gp))
    }

    /// [`Problem::normal_part`] for an absorbing film ([`Problem::film_k`]), one site and
    /// node at a time ([`Problem::site_model`]).
    fn normal_absorbing<const INDEX: bool>(
        &self,
        Linearisation { kind, p, t, d_max }: Linearisation<'_>,
        first: usize,
        sites: &mut [SiteSums],
    ) -> Option<(Matrix3<f64>, Vector3<f64>)> {
        let mut hpp = Matrix3::zeros();
        let mut gp = Vector3::zeros();
        let (na, nb) = (self.geo.angles_deg.len(), self.geo.bands_nm.len());
        let mut buf = Nodes::new();
        for a in 0..na {
            for b in 0..nb {
                let nodes = self.nodes(kind, p, a, b, d_max, &mut buf)?;
                for (j, s) in sites.iter_mut().enumerate() {
                    let k = first + j;
                    if !self.usable[k] {
                        continue;
                    }
                    let y = self.measured(nb, k, a, b);
                    if !y.is_finite() {
                        continue;
                    }
                    let fit = self.site_model(nodes, t[k]);
                    let w = self.noise.weight(k, a, b);
                    let jp = Vector3::from(fit.dm_dp);
                    s.add::<INDEX>(w, y - fit.m, fit.dm_dd, jp, (&mut hpp, &mut gp));
                }
            }
        }
        Some((hpp, gp))
    }

    /// One pass computing the full normal equations: per-site sums and the pooled index
    /// blocks `(H_pp, g_p)`, chi-square (in noise units) and residual count; without `INDEX`
    /// (the index held) the thickness's sums only, the blocks and `jdp` zero.
    pub(super) fn normal<const INDEX: bool>(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        t: &[f64; MAX_SITES],
        sites: &mut [SiteSums; MAX_SITES],
    ) -> Option<(Matrix3<f64>, Vector3<f64>, f64, usize)> {
        *sites = [SiteSums::default(); MAX_SITES];
        let d_max = self.thickest(t);
        // The sites in two halves, each with its own index blocks, added in a fixed order.
        let n = self.usable.len();
        let half = n.div_ceil(2);
        let (lo, hi) = sites.split_at_mut(half);
        let (mut first, mut second) = (None, None);
        {
            let at = Linearisation { kind, p, t, d_max };
            let mut a = || first = self.normal_part::<INDEX>(at, 0, &mut lo[..half]);
            let mut b = || second = self.normal_part::<INDEX>(at, half, &mut hi[..n - half]);
            self.par.run(&mut [&mut a, &mut b]);
        }
        let ((h1, g1), (h2, g2)) = (first?, second?);
        let (hpp, gp) = (h1 + h2, g1 + g2);
        let (mut sse, mut n) = (0.0, 0);
        for s in sites.iter() {
            sse += s.sse;
            n += s.n;
        }
        Some((hpp, gp, sse, n))
    }

    /// The thickest usable site's thickness of `t` (which sets the passband quadrature's
    /// nodes), nm.
    pub(super) fn thickest(&self, t: &[f64; MAX_SITES]) -> f64 {
        (0..self.usable.len())
            .filter(|&k| self.usable[k])
            .map(|k| t[k])
            .fold(0.0, f64::max)
    }

    /// The band's shortest and longest centre wavelengths, nm.
    pub(super) fn band_span(&self) -> (f64, f64) {
        let b = self.geo.bands_nm;
        (
            b.iter().copied().fold(f64::INFINITY, f64::min),
            b.iter().copied().fold(0.0, f64::max),
        )
    }

    /// Levenberg-Marquardt on every usable site from `(kind, p)` and thicknesses `t`
    /// (updated in place).
    pub(super) fn refine(
        &self,
        kind: ModelKind,
        mut p: [f64; 3],
        t: &mut [f64; MAX_SITES],
        steps: usize,
    ) -> Option<Candidate> {
        let np = kind.params();
        let mut sites = [SiteSums::default(); MAX_SITES];
        let (mut hpp, mut gp, mut chi2, mut n) = self.normal::<true>(kind, &p, t, &mut sites)?;
        let mut lambda = 1e-3;
        for _ in 0..steps {
            let Some(dp) = self.damped_step(np, &sites, (&hpp, &gp), lambda) else {
                lambda *= 10.0;
                continue;
            };
            let mut p_new = p;
            for q in 0..np {
                p_new[q] += dp[q];
            }
            let trial = match self.stepped_thicknesses(&sites, &dp, lambda, t) {
                Some(t_new) => {
                    let mut trial_sites = [SiteSums::default(); MAX_SITES];
                    self.normal::<true>(kind, &p_new, &t_new, &mut trial_sites)
                        .map(|r| (r, trial_sites, t_new))
                }
                None => None,
            };
            match trial {
                Some(((h2, g2, c2, n2), s2, t_new)) if c2 < chi2 => {
                    let gain = chi2 - c2;
                    p = p_new;
                    *t = t_new;
                    (hpp, gp, chi2, n, sites) = (h2, g2, c2, n2, s2);
                    lambda = (lambda * 0.3).max(1e-7);
                    // A gain this small changes no model choice (a parameter costs
                    // MODEL_PENALTY) nor any index digit reported.
                    if gain < 0.05 + 1e-7 * chi2 {
                        break;
                    }
                }
                _ => {
                    lambda *= 10.0;
                    if lambda > 1e8 {
                        break;
                    }
                }
            }
        }
        Some(self.candidate(kind, p, &hpp, &sites, (chi2, n)))
    }

    /// The index parameters' step damped by `lambda`: the normal equations reduced to them (Schur
    /// complement of the thicknesses) and solved (`None` when not positive definite).
    fn damped_step(
        &self,
        np: usize,
        sites: &[SiteSums; MAX_SITES],
        (hpp, gp): (&Matrix3<f64>, &Vector3<f64>),
        lambda: f64,
    ) -> Option<Vector3<f64>> {
        // Reduce to the index parameters (Schur complement of the thickness block).
        let mut h = *hpp;
        let mut g = *gp;
        for (k, s) in sites.iter().enumerate().take(self.usable.len()) {
            if !self.usable[k] || s.jdd <= 0.0 {
                continue;
            }
            let jdd = s.jdd * (1.0 + lambda);
            let jdp = Vector3::from(s.jdp);
            h -= jdp * jdp.transpose() / jdd;
            g -= jdp * (s.gd / jdd);
        }
        let mut hd = Matrix3::identity();
        for i in 0..np {
            for j in 0..np {
                hd[(i, j)] = h[(i, j)];
            }
            hd[(i, i)] = h[(i, i)] * (1.0 + lambda) + 1e-12;
        }
        let gr = Vector3::new(
            g[0],
            if np > 1 { g[1] } else { 0.0 },
            if np > 2 { g[2] } else { 0.0 },
        );
        hd.cholesky().map(|c| c.solve(&gr))
    }

    /// Each usable site's thickness moved by its damped step given the index step `dp` (`None`
    /// when a thickness is no longer positive).
    fn stepped_thicknesses(
        &self,
        sites: &[SiteSums; MAX_SITES],
        dp: &Vector3<f64>,
        lambda: f64,
        t: &[f64; MAX_SITES],
    ) -> Option<[f64; MAX_SITES]> {
        let mut t_new = *t;
        let mut ok = true;
        for (k, s) in sites.iter().enumerate().take(self.usable.len()) {
            if !self.usable[k] || s.jdd <= 0.0 {
                continue;
            }
            let jdd = s.jdd * (1.0 + lambda);
            let jdp = Vector3::from(s.jdp);
            let step = (s.gd - jdp.dot(dp)) / jdd;
            t_new[k] = t[k] + step;
            if t_new[k].is_nan() || t_new[k] <= 0.0 {
                ok = false;
            }
        }
        ok.then_some(t_new)
    }

    /// The refined `(kind, p)` as a candidate: its chi-square, score, physicality and index sigma
    /// at 550 nm from the undamped Schur complement at the solution.
    fn candidate(
        &self,
        kind: ModelKind,
        p: [f64; 3],
        hpp: &Matrix3<f64>,
        sites: &[SiteSums; MAX_SITES],
        (chi2, n): (f64, usize),
    ) -> Candidate {
        let np = kind.params();
        let mut cov = Matrix3::zeros();
        // Covariance of the index parameters at the solution (undamped Schur complement).
        let mut h = *hpp;
        for (k, s) in sites.iter().enumerate().take(self.usable.len()) {
            if !self.usable[k] || s.jdd <= 0.0 {
                continue;
            }
            let jdp = Vector3::from(s.jdp);
            h -= jdp * jdp.transpose() / s.jdd;
        }
        let mut hd = Matrix3::identity();
        for i in 0..np {
            for j in 0..np {
                hd[(i, j)] = h[(i, j)];
            }
        }
        if let Some(inv) = hd.try_inverse() {
            cov = inv;
        }
        let used = self.usable.iter().filter(|&&u| u).count();
        let dof = n.saturating_sub(np + used).max(1);
        let chi2_nu = chi2 / dof as f64;
        let (_, g550) = kind.eval(&p, L0_UM);
        let gv = Vector3::from(g550);
        let mut var = 0.0;
        for i in 0..np {
            for j in 0..np {
                var += gv[i] * cov[(i, j)] * gv[j];
            }
        }
        // Scale by the reduced chi-square when the fit is worse than the noise.
        let n550_sigma = libm::sqrt(var.max(0.0) * chi2_nu.max(1.0));
        let (lo, hi) = self.band_span();
        Candidate {
            kind,
            params: p,
            chi2,
            chi2_nu,
            // A constant index is the two-term Cauchy model with its slope held at zero: it
            // saves no penalty against the evidence of a weak but real dispersion (held
            // constant, a 180 nm MgF2 film's index came out 0.0035 low, free 0.0005), only
            // a slope that gains less than CONSTANT_PREFERENCE.
            score: chi2 + MODEL_PENALTY * np.max(2) as f64
                - if np == 1 { CONSTANT_PREFERENCE } else { 0.0 },
            n550_sigma,
            physical: kind.physical(&p, lo, hi, self.geo.index_range),
        }
    }
}
