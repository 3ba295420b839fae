//! What a fitted model leaves on the sample's own pixels: the residual's RMS against the
//! noise, its correlation along the band and across the sites, each angle's share, and the
//! model error the misfit beyond the noise amounts to.

use super::{ModelKind, Nodes, Problem, MAX_SITES};

/// Steps of the model-error grid a [`Residual`] solves on, a factor 10^(1/4) apart from
/// 1e-5 (the first step is 0).
const MODEL_ERROR_STEPS: usize = 24;

/// The model error of grid step `j`: 0, then 1e-5 rising by 10^(1/4) a step (to 0.56 at the
/// last).
#[inline]
fn model_error_step(j: usize) -> f64 {
    if j == 0 {
        0.0
    } else {
        1e-5 * libm::pow(10.0, (j - 1) as f64 / 4.0)
    }
}

/// The model error `m` at which the residual's chi-square in units of each sample's noise
/// plus `m` (`chi2[j]` at [`model_error_step`] `j`, falling with `j`) equals its degrees of
/// freedom: 0 when it fits within the noise alone, interpolated between the grid's steps
/// (log-linear in `m`), the last step when even that misses.
fn model_error_for(chi2: &[f64; MODEL_ERROR_STEPS + 1], dof: f64) -> f64 {
    if chi2[0] <= dof {
        return 0.0;
    }
    for j in 1..chi2.len() {
        if chi2[j] <= dof {
            let (m0, m1) = (model_error_step(j - 1).max(1e-6), model_error_step(j));
            let f = ((chi2[j - 1] - dof) / (chi2[j - 1] - chi2[j])).clamp(0.0, 1.0);
            return m0 * libm::pow(m1 / m0, f);
        }
    }
    model_error_step(MODEL_ERROR_STEPS)
}

/// Most angles a [`Residual`] reports one by one.
pub const RESIDUAL_ANGLES: usize = 32;

/// One angle's share of a [`Residual`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AngleResidual {
    /// RMS of the residual (measured minus model), reflectance.
    pub rms: f64,
    /// Mean of the residual (an offset the model misses), reflectance.
    pub mean: f64,
    /// RMS of the noise the samples carry, reflectance.
    pub noise_rms: f64,
}

/// What a fit leaves over the sites' own pixels: the residual's size and its shape across
/// bands and angles, so a reader can tell noise (white, at the noise's size) from the
/// model's misfit (larger, smooth along the band, a part of the band or an angle).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Residual {
    /// RMS of the residual, reflectance.
    pub rms: f64,
    /// The samples' noise as their weights give it (the RMS of the typical sample:
    /// `sqrt(n / sum 1/sigma^2)`), reflectance.
    pub noise_rms: f64,
    /// The misfit beyond the noise: the model error that, added to each sample's noise,
    /// brings the residual's reduced chi-square to 1 (0 when it fits within the noise).
    pub model_rms: f64,
    /// Correlation of neighbouring bands' residuals (about 0 for noise, towards 1 for a
    /// smooth misfit).
    pub band_correlation: f64,
    /// Correlation of different sites' residuals at the same band and angle (about 0 for
    /// noise and for misfits of each site's own, towards 1 for one misfit common to all).
    pub site_correlation: f64,
    /// RMS over the band's blue third and its red third.
    pub blue_rms: f64,
    /// RMS over the band's red third.
    pub red_rms: f64,
    /// Each angle's, in streaming order (the first [`RESIDUAL_ANGLES`]).
    pub per_angle: heapless::Vec<AngleResidual, RESIDUAL_ANGLES>,
}

impl Residual {
    /// The factor by which this residual widens the parameters' standard errors beyond what
    /// independent samples of its size give: its misfit beyond the noise, correlated along
    /// the band as `r` (the neighbouring bands' covariance over the misfit's variance), is
    /// `(1 - r) / (1 + r)` as many independent samples (an AR(1) misfit), the noise's share
    /// is not: `sqrt(f_noise + f_model (1 + r) / (1 - r))` by the two shares of the variance.
    pub fn correlation_factor(&self) -> f64 {
        let (total, model) = (self.rms * self.rms, self.model_rms * self.model_rms);
        if !(total > 0.0 && model > 0.0) {
            return 1.0;
        }
        let r = (self.band_correlation * total / model).clamp(0.0, 0.99);
        let share = (model / total).min(1.0);
        libm::sqrt(1.0 - share + share * (1.0 + r) / (1.0 - r))
    }

    /// [`Residual::correlation_factor`] for a parameter every one of `sites` sites shares,
    /// the index: the noise averages down over the sites, a misfit common to them does not
    /// (a rig's or a sample's departure from the model, the same at every site, pulls the
    /// index the same way). With the misfit's correlation `q` between sites (the residuals'
    /// [`Residual::site_correlation`] over the misfit's share), the sites are
    /// `sites / (1 + (sites - 1) q)` independent ones, so the misfit's share counts
    /// `1 + (sites - 1) q` times more: `sqrt(f_noise + f_model (1 + (sites - 1) q) (1 + r) /
    /// (1 - r))`.
    pub fn shared_factor(&self, sites: usize) -> f64 {
        let own = self.correlation_factor();
        let (total, model) = (self.rms * self.rms, self.model_rms * self.model_rms);
        if !(total > 0.0 && model > 0.0 && self.site_correlation.is_finite()) {
            return own;
        }
        let share = (model / total).min(1.0);
        let q = (self.site_correlation * total / model).clamp(0.0, 1.0);
        let correlated = (own * own - (1.0 - share)).max(0.0);
        let many = 1.0 + sites.saturating_sub(1) as f64 * q;
        libm::sqrt(1.0 - share + correlated * many)
    }
}

/// [`Residual`]'s sums over some of the angles ([`Problem::residual_sums`]), added in
/// angle order.
#[derive(Clone, Debug, Default)]
struct ResidualSums {
    /// Samples, and their residuals' squares and inverse noise variances summed.
    n: usize,
    r2: f64,
    s2: f64,
    /// Products of each site's residuals at neighbouring bands, and their squares' mean.
    lag: f64,
    lag_r2: f64,
    /// Squares and counts over the band's blue and red thirds.
    blue2: f64,
    nblue: usize,
    red2: f64,
    nred: usize,
    /// Products of different sites' residuals at the same band and angle, and their
    /// squares' share of them: the residuals' correlation between sites.
    cross: f64,
    cross_r2: f64,
    /// `chi2[j]`: the residual in units of the noise plus a model error
    /// [`model_error_step`]`(j)`.
    chi2: [f64; MODEL_ERROR_STEPS + 1],
    per_angle: heapless::Vec<AngleResidual, RESIDUAL_ANGLES>,
}

impl ResidualSums {
    /// `other`'s sums (of the angles after these) added.
    fn add(&mut self, other: &Self) {
        self.n += other.n;
        self.r2 += other.r2;
        self.s2 += other.s2;
        self.lag += other.lag;
        self.lag_r2 += other.lag_r2;
        self.blue2 += other.blue2;
        self.nblue += other.nblue;
        self.red2 += other.red2;
        self.nred += other.nred;
        self.cross += other.cross;
        self.cross_r2 += other.cross_r2;
        for (c, o) in self.chi2.iter_mut().zip(&other.chi2) {
            *c += o;
        }
        for &r in &other.per_angle {
            let _ = self.per_angle.push(r);
        }
    }
}

impl Problem<'_> {
    /// What `(kind, p)` at the sites' thicknesses `t` leaves on their own pixels (`None`
    /// when the model cannot be evaluated): the angles in two halves, each summed on its own
    /// ([`Problem::residual_sums`], run by [`Problem::par`]) and added in angle order.
    pub(super) fn residual(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        t: &[f64; MAX_SITES],
    ) -> Option<Residual> {
        let na = self.geo.angles_deg.len();
        let mid = na.div_ceil(2);
        let (mut first, mut second) = (None, None);
        {
            let mut a = || first = self.residual_sums(kind, p, t, 0..mid);
            let mut b = || second = self.residual_sums(kind, p, t, mid..na);
            self.par.run(&mut [&mut a, &mut b]);
        }
        let mut sums = first?;
        sums.add(&second?);
        let ResidualSums {
            n,
            r2,
            s2,
            lag,
            lag_r2,
            blue2,
            nblue,
            red2,
            nred,
            cross,
            cross_r2,
            chi2,
            per_angle,
        } = sums;
        if n == 0 {
            return None;
        }
        // The fit's own parameters absorb a little of the noise: the residual's mean square
        // over the degrees of freedom.
        let used = self.usable.iter().filter(|&&u| u).count();
        let dof = n.saturating_sub(used + kind.params()).max(1) as f64;
        Some(Residual {
            rms: libm::sqrt(r2 / dof),
            noise_rms: libm::sqrt(n as f64 / s2.max(f64::MIN_POSITIVE)),
            model_rms: model_error_for(&chi2, dof),
            band_correlation: if lag_r2 > 0.0 { lag / lag_r2 } else { 0.0 },
            site_correlation: if cross_r2 > 0.0 {
                cross / cross_r2
            } else {
                0.0
            },
            blue_rms: libm::sqrt(blue2 / nblue.max(1) as f64),
            red_rms: libm::sqrt(red2 / nred.max(1) as f64),
            per_angle,
        })
    }

    /// [`Problem::residual`]'s sums over the angles `angles`.
    fn residual_sums(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        t: &[f64; MAX_SITES],
        angles: core::ops::Range<usize>,
    ) -> Option<ResidualSums> {
        let nb = self.geo.bands_nm.len();
        let sites = self.usable.len();
        let d_max = self.thickest(t);
        let (lo, hi) = self.band_span();
        let (blue, red) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
        let mut out = ResidualSums::default();
        let grid2: [f64; MODEL_ERROR_STEPS + 1] = core::array::from_fn(|j| {
            let m = model_error_step(j);
            m * m
        });
        let mut buf = Nodes::new();
        for a in angles {
            let mut prev = [f64::NAN; MAX_SITES];
            let (mut an, mut ar, mut ar2, mut as2) = (0usize, 0.0, 0.0, 0.0);
            for b in 0..nb {
                let nodes = self.nodes(kind, p, a, b, d_max, &mut buf)?;
                let l = self.geo.bands_nm[b];
                let (mut sum, mut sum2, mut ns) = (0.0, 0.0, 0usize);
                for k in (0..sites).filter(|&k| self.usable[k]) {
                    let y = self.measured(nb, k, a, b);
                    if !y.is_finite() {
                        prev[k] = f64::NAN;
                        continue;
                    }
                    let r = y - self.site_value(nodes, t[k]);
                    let r2 = r * r;
                    (sum, sum2, ns) = (sum + r, sum2 + r2, ns + 1);
                    let v = self.noise.noise2(k, a, b);
                    (an, ar, ar2, as2) = (an + 1, ar + r, ar2 + r2, as2 + 1.0 / v);
                    for (c, m2) in out.chi2.iter_mut().zip(&grid2) {
                        *c += r2 / (v + m2);
                    }
                    if prev[k].is_finite() {
                        out.lag += prev[k] * r;
                        out.lag_r2 += 0.5 * (prev[k] * prev[k] + r2);
                    }
                    prev[k] = r;
                    if l <= blue {
                        (out.blue2, out.nblue) = (out.blue2 + r2, out.nblue + 1);
                    } else if l >= red {
                        (out.red2, out.nred) = (out.red2 + r2, out.nred + 1);
                    }
                }
                if ns > 1 {
                    out.cross += sum * sum - sum2;
                    out.cross_r2 += (ns - 1) as f64 * sum2;
                }
            }
            (out.n, out.r2, out.s2) = (out.n + an, out.r2 + ar2, out.s2 + as2);
            let per = an.max(1) as f64;
            let _ = out.per_angle.push(AngleResidual {
                rms: libm::sqrt(ar2 / per),
                mean: ar / per,
                noise_rms: libm::sqrt(per / as2.max(f64::MIN_POSITIVE)),
            });
        }
        Some(out)
    }
}
