//! Model choice by evidence and the gate: every index model refined and the simplest the
//! data ask for kept, judged against what a measurement can promise; when it misses, the
//! nuisance terms the evidence pays for (each on its grid), the sites set aside and the
//! model's error, and the fit again under them.

use super::marginal::TERM_MAX_ANGLES;
use super::noise::{median, Noise};
use super::residual::RESIDUAL_ANGLES;
use super::{
    hold_weighed, Candidate, Failure, ModelKind, Nodes, Problem, SampleFit, SiteSums, Term, Terms,
    GATE_CHI2_NU, GRID_STEPS, MAX_INDEX_ACCURACY, MAX_INDEX_SIGMA, MAX_SITES, MAX_STEPS,
    NOISE_ANGLES, OUTLIER_SITE_RATIO, RESEAT_CHI2_NU, TERM_ANGLES, TERM_OFFSET, TERM_ROUNDS,
    TERM_SCALE, TERM_SPAN_DEG,
};
#[cfg(doc)]
use super::{Residual, TOLERANCE};
use crate::optics::{BackFace, Polarization};

/// Extinction coefficients at 450 nm the absorption search tries first.
const ABSORPTION_GRID: [f64; 6] = [0.001, 0.002, 0.004, 0.008, 0.016, 0.032];

/// Shares of the light the filter's side lobes pass that the search tries first: a
/// liquid-crystal filter keeps them to a few per cent, so the outermost, 8 %, is more than
/// one has ([`Problem::with_nuisance`]).
const SIDE_LOBE_GRID: [f64; 6] = [0.0025, 0.005, 0.01, 0.02, 0.04, 0.08];

/// Shares of the other polarisation the leak search tries first.
const LEAK_GRID: [f64; 5] = [0.0025, 0.005, 0.01, 0.02, 0.04];

/// Stage angle offsets the search tries first, degrees.
const STAGE_GRID: [f64; 6] = [-0.8, -0.4, -0.15, 0.15, 0.4, 0.8];

/// Flare (a reflectance offset shared by every angle and band) the search tries first: a rig
/// keeps it to 0.1-0.5 % of the white, so the outermost, 0.6 %, is more than one has
/// ([`Problem::with_nuisance`]): a misfit of another cause (the filter's side lobes) asking
/// for it.
const FLARE_GRID: [f64; 6] = [0.0005, 0.001, 0.002, 0.003, 0.0045, 0.006];

/// Wavelength shifts the search tries first, nm.
const SHIFT_GRID: [f64; 6] = [-1.0, -0.5, -0.2, 0.2, 0.5, 1.0];

impl Problem<'_> {
    /// Every model refined from the two-term Cauchy fit `base`; the simplest that the data
    /// ask for chosen, with the gate and a second start.
    pub(super) fn choose(
        &self,
        mut fit: SampleFit,
        base: Candidate,
        t: &[f64; MAX_SITES],
        scratch: &mut [f32],
    ) -> SampleFit {
        let (lo, hi) = self.band_span();
        let n_at = |c: &Candidate, l_nm: f64| c.kind.eval(&c.params, l_nm * 1e-3).0;
        let mut best: Option<(Candidate, [f64; MAX_SITES])> = None;
        let base = if base.kind == ModelKind::Cauchy2 {
            base
        } else {
            // A warm start of another kind: its Cauchy fit over the band.
            let mut tt = *t;
            match self.refine(
                ModelKind::Cauchy2,
                cauchy_through(&base, lo, hi),
                &mut tt,
                MAX_STEPS,
            ) {
                Some(c) => c,
                None => base,
            }
        };
        // The richest curve fitted so far: where the Sellmeier models start.
        let mut richest = base;
        if base.kind != ModelKind::Cauchy2 {
            // A warm start of another kind stands as its own candidate.
            let _ = fit.candidates.push(base);
            if base.physical {
                best = Some((base, *t));
            }
        }
        for kind in ModelKind::ALL {
            if kind == base.kind && kind != ModelKind::Cauchy2 {
                continue;
            }
            let start = match kind {
                ModelKind::Constant => [n_at(&base, 550.0), 0.0, 0.0],
                ModelKind::Cauchy2 => base.params,
                ModelKind::Cauchy3 => [base.params[0], base.params[1], 0.0],
                ModelKind::Sellmeier1 | ModelKind::Sellmeier1c => {
                    match sellmeier_through(&richest, lo, hi, kind == ModelKind::Sellmeier1c) {
                        Some(s) => s,
                        None => continue,
                    }
                }
            };
            let mut tt = *t;
            let cand = if kind == ModelKind::Cauchy2 {
                Some(base)
            } else {
                self.refine(kind, start, &mut tt, MAX_STEPS)
            };
            let Some(mut c) = cand else { continue };
            // Sites left in another fringe order by a simpler model's fit: each seated
            // again under this model (the dictionary), then refined once more.
            if kind != ModelKind::Cauchy2 && c.chi2_nu > RESEAT_CHI2_NU {
                let mut again = [f64::NAN; MAX_SITES];
                if self
                    .start_thicknesses(kind, &c.params, &mut again, scratch)
                    .is_some()
                {
                    if let Some(c2) = self.refine(kind, c.params, &mut again, MAX_STEPS) {
                        if c2.chi2 < c.chi2 {
                            c = c2;
                            tt = again;
                        }
                    }
                }
            }
            if c.chi2 < richest.chi2 {
                richest = c;
            }
            let _ = fit.candidates.push(c);
            if c.physical && best.as_ref().is_none_or(|(b, _)| c.score < b.score) {
                best = Some((c, if kind == ModelKind::Cauchy2 { *t } else { tt }));
            }
        }
        let Some((c, tt)) = best else {
            fit.failure = Some(Failure::NoFit);
            return fit;
        };
        self.settle(fit, c, &tt)
    }

    /// `fit` ending with `c` and its sites' thicknesses `tt`, with what it leaves
    /// ([`Residual`]), judged by the gate: a reduced chi-square (in units of the noise and the
    /// model error weighed) within [`GATE_CHI2_NU`], a model error within the tolerated
    /// one, an index standard error within [`MAX_INDEX_SIGMA`]. Weighed with a model error,
    /// the index's standard error is widened by the residual's correlation along the band and
    /// across the sites ([`Residual::shared_factor`]): a smooth misfit common to the sites is
    /// fewer independent samples. The gate takes the sites' own standard error (the band's
    /// widening only): whether the spectra determine the index, not how far a misfit common
    /// to the sites may pull it. The sigma reported carries every nuisance term within its
    /// [`TOLERANCE`] and the misfit beyond the noise.
    pub(super) fn settle(
        &self,
        mut fit: SampleFit,
        mut c: Candidate,
        tt: &[f64; MAX_SITES],
    ) -> SampleFit {
        for (k, slot) in fit.thickness_nm.iter_mut().enumerate() {
            *slot = if k < self.usable.len() && self.usable[k] {
                tt[k] as f32
            } else {
                f32::NAN
            };
        }
        if let Some(r) = self.residual(c.kind, &c.params, tt) {
            fit.residual = r;
        }
        fit.model_error = libm::sqrt(self.noise.model2);
        let scale = libm::sqrt(c.chi2_nu.max(1.0));
        if self.terms.fitted() || self.film_k > 0.0 || self.leak > 0.0 {
            // The terms trade with the index: its sigma with them free, not held.
            if let Some(m) = self.marginal_n550_sigma(c.kind, &c.params, tt, false) {
                c.n550_sigma = m.n550_sigma * scale;
            }
        }
        // Whether the spectra determine the index at all is the sites' own precision; what a
        // misfit common to them adds is the index's accuracy, refused beyond
        // [`MAX_INDEX_ACCURACY`].
        let (mut determined, mut accuracy) = (c.n550_sigma, c.n550_sigma);
        if fit.model_error > 0.0 {
            determined *= fit.residual.correlation_factor();
            accuracy *= fit.residual.shared_factor(fit.sites_used);
        }
        // The sigma reported: every nuisance term free within what a rig keeps, and the
        // misfit beyond the noise as the model's share, whether or not the gate needed a
        // model error to pass the fit. A given index (held: sigma 0) keeps none.
        fit.thickness_share = f64::NAN;
        if c.n550_sigma > 0.0 {
            let shared = fit.residual.shared_factor(fit.sites_used);
            if self.geo.rig_tolerance > 0.0 {
                if let Some(m) = self.marginal_n550_sigma(c.kind, &c.params, tt, true) {
                    c.n550_sigma = m.n550_sigma * scale;
                    fit.thickness_share = m.thickness_share * scale * shared;
                }
            }
            c.n550_sigma *= shared;
        }
        fit.best = Some(c);
        let within = fit.residual.model_rms <= self.geo.model_error;
        let misfit = fit.model_error > 0.0 && !within;
        fit.failure = if c.chi2_nu > GATE_CHI2_NU || misfit {
            Some(Failure::NoFit)
        } else if determined > MAX_INDEX_SIGMA || accuracy > MAX_INDEX_ACCURACY {
            Some(Failure::Underdetermined)
        } else {
            None
        };
        fit
    }

    /// `fit` again when it misses the gate against the noise alone: the sites that fit far
    /// worse than the rest ([`OUTLIER_SITE_RATIO`], at most a quarter) set aside; with angle
    /// leverage ([`TERM_ANGLES`] angles over [`TERM_SPAN_DEG`]), each angle's reflectance
    /// scale and offset fitted with the index and kept when their chi-square gain beats
    /// their BIC penalty; the misfit still beyond the noise taken as the model's error and
    /// added to every sample's variance; and the index fitted and its model chosen again
    /// under them (`held`: seated again under the given index). `fit` as it is when it
    /// passed, on a second try, when no model error is tolerated, or when the misfit is more
    /// than twice the tolerated one.
    pub(super) fn with_model_error(
        &self,
        fit: SampleFit,
        held: Option<(ModelKind, [f64; 3])>,
        scratch: &mut [f32],
    ) -> SampleFit {
        let tol = self.geo.model_error;
        let Some(mut best) = fit.best else { return fit };
        if fit.failure != Some(Failure::NoFit) || self.retry || tol.is_nan() || tol <= 0.0 {
            return fit;
        }
        let sites = self.usable.len();
        let mut tt = [f64::NAN; MAX_SITES];
        for (d, &t) in tt.iter_mut().zip(&fit.thickness_nm) {
            *d = f64::from(t);
        }
        let Some(aside) = self.outlying_sites(&best, &tt) else {
            return fit;
        };
        let mut usable = [false; MAX_SITES];
        for k in 0..sites {
            usable[k] = self.usable[k] && !aside[k];
        }
        // The sites' spectra over the side lobes' band, once, at the workspace's end.
        let wide_len = sites * self.geo.angles_deg.len() * self.geo.bands_nm.len();
        let split = scratch.len().saturating_sub(wide_len);
        let (scratch, wide) = scratch.split_at_mut(split);
        let wide: &[f32] = if wide.len() == wide_len {
            self.fill_wide(wide);
            wide
        } else {
            &[]
        };
        let mut kept = Problem {
            usable: &usable[..sites],
            noise: self.noise.clone(),
            retry: true,
            wide,
            ..*self
        };
        let found = if held.is_none() {
            kept.take_nuisance(&mut best, &mut tt)
        } else {
            [Term::NONE; 6]
        };
        let fitted_terms = if held.is_none() {
            kept.with_terms(&mut best, &mut tt)
        } else {
            None
        };
        if let Some(terms) = fitted_terms {
            kept.terms = terms;
        }
        let Some(left) = kept.residual(best.kind, &best.params, &tt) else {
            return fit;
        };
        let m = left.model_rms;
        if m.is_nan() || m > 2.0 * tol {
            return fit;
        }
        let weighed = Problem {
            noise: Noise {
                model2: m * m,
                ..self.noise.clone()
            },
            ..kept
        };
        let mut again = SampleFit {
            candidates: heapless::Vec::new(),
            sites_used: usable.iter().filter(|&&u| u).count(),
            ..fit.clone()
        };
        again = match held {
            Some((kind, params)) => hold_weighed(&weighed, again, kind, params, scratch),
            None => {
                let mut seated = tt;
                let base = weighed
                    .refine(best.kind, best.params, &mut seated, MAX_STEPS)
                    .unwrap_or(best);
                weighed.choose(again, base, &seated, scratch)
            }
        };
        if fitted_terms.is_some() {
            let na = self.geo.angles_deg.len().min(RESIDUAL_ANGLES);
            again.reflectance_terms = (0..na)
                .map(|a| (weighed.terms.scale[a], weighed.terms.offset[a]))
                .collect();
        }
        [
            again.film_k,
            again.polariser_leak,
            again.stage_offset_deg,
            again.wavelength_shift_nm,
            again.flare,
            again.side_lobes,
        ] = found;
        again.set_aside = aside;
        again.starts = fit.starts;
        again.searched = fit.searched;
        again
    }

    /// The sites that fit far worse than the rest under `best` ([`OUTLIER_SITE_RATIO`] times the
    /// median, at most a quarter), to be set aside (`None` when the model cannot be evaluated).
    fn outlying_sites(&self, best: &Candidate, tt: &[f64; MAX_SITES]) -> Option<[bool; MAX_SITES]> {
        let sites = self.usable.len();
        let mut sums = [SiteSums::default(); MAX_SITES];
        self.normal::<false>(best.kind, &best.params, tt, &mut sums)?;
        let chi2_of = |k: usize| sums[k].sse / sums[k].n.max(1) as f64;
        let mut v: heapless::Vec<f32, MAX_SITES> = (0..sites)
            .filter(|&k| self.usable[k] && sums[k].n > 0)
            .map(|k| chi2_of(k) as f32)
            .collect();
        let typical = median(&mut v);
        let mut aside = [false; MAX_SITES];
        for k in (0..sites).filter(|&k| self.usable[k]) {
            let c = chi2_of(k);
            aside[k] = c > OUTLIER_SITE_RATIO * typical && c > GATE_CHI2_NU;
        }
        let used = self.usable.iter().filter(|&&u| u).count();
        if aside.iter().filter(|&&a| a).count() * 4 > used {
            aside = [false; MAX_SITES];
        }
        Some(aside)
    }

    /// The nuisance terms taken forward stepwise (each round the one whose chi-square falls
    /// furthest, so none mops up another's misfit), set on this problem; `best`, `tt` updated.
    fn take_nuisance(&mut self, best: &mut Candidate, tt: &mut [f64; MAX_SITES]) -> [Term; 6] {
        let mut found = [Term::NONE; 6];
        let offered = |t: usize| match t {
            // At one angle the film's loss, which dims the back face's return twice over,
            // trades with the index's reflectance level (a measured HfO2 film over its
            // back face took k 0.016 and an index 0.014 high).
            0 => self.geo.back_face == BackFace::None || self.geo.angles_deg.len() > 1,
            1 => self.geo.polarization != Polarization::Unpolarized,
            // One angle cannot tell an angle offset or a flare from the index.
            2 | 4 => self.geo.angles_deg.len() > 1,
            _ => true,
        };
        let mut remaining: heapless::Vec<usize, 6> = (0..6).filter(|&t| offered(t)).collect();
        loop {
            let mut pick: Option<(usize, Candidate, [f64; MAX_SITES], Term)> = None;
            for (i, &t) in remaining.iter().enumerate() {
                let (mut b, mut d) = (*best, *tt);
                let (b_, d_) = (&mut b, &mut d);
                let got = match t {
                    0 => self.with_nuisance(b_, d_, &ABSORPTION_GRID, |p, v| p.film_k = v),
                    1 => self.with_nuisance(b_, d_, &LEAK_GRID, |p, v| p.leak = v),
                    2 => self.with_nuisance(b_, d_, &STAGE_GRID, |p, v| p.stage_deg = v),
                    3 => self.with_nuisance(b_, d_, &SHIFT_GRID, |p, v| p.shift_nm = v),
                    4 => self.with_nuisance(b_, d_, &FLARE_GRID, |p, v| p.flare = v),
                    _ => self.with_nuisance(b_, d_, &SIDE_LOBE_GRID, |p, v| p.side_lobes = v),
                };
                if let Some(term) = got {
                    if pick.as_ref().is_none_or(|p| b.chi2 < p.1.chi2) {
                        pick = Some((i, b, d, term));
                    }
                }
            }
            let Some((i, b, d, term)) = pick else { break };
            let t = remaining.remove(i);
            match t {
                0 => self.film_k = term.value,
                1 => self.leak = term.value,
                2 => self.stage_deg = term.value,
                3 => self.shift_nm = term.value,
                4 => self.flare = term.value,
                _ => self.side_lobes = term.value,
            }
            found[t] = term;
            (*best, *tt) = (b, d);
        }
        found
    }

    /// Each angle's reflectance scale and offset fitted with the index `best` and the sites'
    /// thicknesses `t` (both updated), by turns: the terms by weighted least squares of the
    /// measured spectra on the model, then the index and thicknesses under them. The terms
    /// when the capture has the angle leverage to tell them from the index and their
    /// chi-square gain exceeds their BIC penalty (`ln n` a parameter) and none sits at the
    /// end of its range ([`TERM_SCALE`], the top of [`TERM_OFFSET`]), else `None` (`best`
    /// and `t` as they were).
    fn with_terms(&self, best: &mut Candidate, t: &mut [f64; MAX_SITES]) -> Option<Terms> {
        let angles = self.geo.angles_deg;
        let na = angles.len();
        let span = angles.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            - angles.iter().copied().fold(f64::INFINITY, f64::min);
        if na < TERM_ANGLES || span < TERM_SPAN_DEG || na > TERM_MAX_ANGLES {
            return None;
        }
        let mut sums = [SiteSums::default(); MAX_SITES];
        let (_, _, before, n) = self.normal::<false>(best.kind, &best.params, t, &mut sums)?;
        let mut trial = Problem {
            noise: self.noise.clone(),
            ..*self
        };
        let (mut cand, mut tt) = (*best, *t);
        for _ in 0..TERM_ROUNDS {
            trial.terms = self.terms_for(cand.kind, &cand.params, &tt)?;
            cand = trial.refine(cand.kind, cand.params, &mut tt, MAX_STEPS)?;
        }
        // A scale at either end of its range, or an offset at its top, is the terms mopping
        // up a misfit of another cause ([`Problem::with_nuisance`]): not taken.
        let at_bound = (0..na.min(NOISE_ANGLES)).any(|a| {
            let (s, o) = (trial.terms.scale[a], trial.terms.offset[a]);
            s <= TERM_SCALE[0] || s >= TERM_SCALE[1] || o >= TERM_OFFSET[1]
        });
        let penalty = 2.0 * na as f64 * libm::log(n.max(2) as f64);
        if !at_bound && cand.chi2 + penalty < before {
            *best = cand;
            *t = tt;
            Some(trial.terms)
        } else {
            None
        }
    }

    /// One nuisance parameter (set on a copy of the problem by `apply`) fitted with the
    /// index `best` and the sites' thicknesses `t` (both updated): each value of `grid` with
    /// the index and thicknesses refined under it, then a parabola through the best and its
    /// neighbours (in log value for a grid of positive values, else in value), whose
    /// curvature gives the term's sigma (scaled by the reduced chi-square when above 1). The
    /// term when its chi-square gain exceeds its BIC penalty (`ln n`), else `None` (`best`
    /// and `t` as they were), also when the evidence asks for the grid's outermost value (the
    /// largest, or either end of a signed grid): more than a real rig or sample has, the term
    /// would be mopping up a misfit of another cause (an undeclared back face, a second layer,
    /// wrong metadata), which is left to the model error and its tolerance instead.
    fn with_nuisance(
        &self,
        best: &mut Candidate,
        t: &mut [f64; MAX_SITES],
        grid: &[f64],
        apply: impl Fn(&mut Problem<'_>, f64),
    ) -> Option<Term> {
        let mut sums = [SiteSums::default(); MAX_SITES];
        let (_, _, before, n) = self.normal::<false>(best.kind, &best.params, t, &mut sums)?;
        let at = |v: f64, steps: usize| -> Option<(Candidate, [f64; MAX_SITES])> {
            let mut trial = Problem {
                noise: self.noise.clone(),
                ..*self
            };
            apply(&mut trial, v);
            let mut tt = *t;
            let c = trial.refine(best.kind, best.params, &mut tt, steps)?;
            Some((c, tt))
        };
        let log = grid.iter().all(|&v| v > 0.0);
        let x_of = |v: f64| if log { libm::log(v) } else { v };
        let mut tried: heapless::Vec<(f64, Candidate, [f64; MAX_SITES]), 8> = heapless::Vec::new();
        // The grid's values a few steps from the fit without the term (the parabola needs
        // no more), the vertex to convergence.
        for &v in grid {
            if let Some((c, tt)) = at(v, GRID_STEPS) {
                let _ = tried.push((v, c, tt));
            }
        }
        let (i, _) = tried
            .iter()
            .enumerate()
            .min_by(|a, b| a.1 .1.chi2.total_cmp(&b.1 .1.chi2))?;
        let outermost = i + 1 == tried.len() || (!log && i == 0);
        let (mut v_best, mut c_best, mut t_best) = tried[i];
        let mut sigma = f64::NAN;
        if i > 0 && i + 1 < tried.len() {
            // The parabola through the best and its neighbours: its vertex and curvature.
            let (x0, x1, x2) = (x_of(tried[i - 1].0), x_of(tried[i].0), x_of(tried[i + 1].0));
            let (y0, y1, y2) = (tried[i - 1].1.chi2, tried[i].1.chi2, tried[i + 1].1.chi2);
            let den = (x0 - x1) * (x0 - x2) * (x1 - x2);
            let a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den;
            let b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den;
            if a > 0.0 {
                let x = -b / (2.0 * a);
                let v = if log { libm::exp(x) } else { x };
                if let Some((c, tt)) = at(v, MAX_STEPS) {
                    if c.chi2 < c_best.chi2 {
                        (v_best, c_best, t_best) = (v, c, tt);
                    }
                }
                // chi2 rises by 1 at one sigma.
                let s_x = libm::sqrt(c_best.chi2_nu.max(1.0) / a);
                sigma = if log { v_best * s_x } else { s_x };
            }
        }
        if outermost || c_best.chi2 + libm::log(n.max(2) as f64) >= before {
            return None;
        }
        *best = c_best;
        *t = t_best;
        Some(Term {
            value: v_best,
            sigma,
        })
    }

    /// Each angle's reflectance scale and offset that best map the model `(kind, p)` at the
    /// sites' thicknesses `t` onto the measured spectra (weighted least squares, within
    /// [`TERM_SCALE`] and [`TERM_OFFSET`]).
    fn terms_for(&self, kind: ModelKind, p: &[f64; 3], t: &[f64; MAX_SITES]) -> Option<Terms> {
        let (na, nb) = (self.geo.angles_deg.len(), self.geo.bands_nm.len());
        let sites = self.usable.len();
        let d_max = self.thickest(t);
        let mut terms = Terms::NONE;
        let mut buf = Nodes::new();
        for a in 0..na.min(NOISE_ANGLES) {
            let (mut sw, mut sm, mut smm, mut sy, mut smy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for b in 0..nb {
                let nodes = self.nodes(kind, p, a, b, d_max, &mut buf)?;
                for k in (0..sites).filter(|&k| self.usable[k]) {
                    let y = f64::from(self.spectra.centre_at(nb, k, a, b)) - self.flare;
                    if !y.is_finite() {
                        continue;
                    }
                    let m = self.site_value(nodes, t[k]);
                    let w = self.noise.weight(k, a, b);
                    (sw, sm, smm, sy, smy) = (
                        sw + w,
                        sm + w * m,
                        smm + w * m * m,
                        sy + w * y,
                        smy + w * m * y,
                    );
                }
            }
            let det = sw * smm - sm * sm;
            if det.is_nan() || det <= 0.0 {
                continue;
            }
            let scale = ((sw * smy - sm * sy) / det).clamp(TERM_SCALE[0], TERM_SCALE[1]);
            let offset = ((sy - scale * sm) / sw).clamp(TERM_OFFSET[0], TERM_OFFSET[1]);
            terms.scale[a] = scale;
            terms.offset[a] = offset;
        }
        Some(terms)
    }
}

/// The two-term Cauchy model closest to `c` over `[lo_nm, hi_nm]` (least squares in `n`
/// against `1 / l^2`).
fn cauchy_through(c: &Candidate, lo_nm: f64, hi_nm: f64) -> [f64; 3] {
    let (mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0);
    let m = 17;
    for i in 0..m {
        let l = (lo_nm + (hi_nm - lo_nm) * i as f64 / (m - 1) as f64) * 1e-3;
        let x = 1.0 / (l * l);
        let y = c.kind.eval(&c.params, l).0;
        sx += x;
        sy += y;
        sxx += x * x;
        sxy += x * y;
    }
    let mf = m as f64;
    let b = (mf * sxy - sx * sy) / (mf * sxx - sx * sx);
    [(sy - b * sx) / mf, b, 0.0]
}

/// The one-pole Sellmeier model closest to `c` over `[lo_nm, hi_nm]`: `n^2 = A + S l^2 /
/// (l^2 - L^2)` with `A = 1` (`with_constant` false) or free, by a scan over the pole with
/// `S` (and `A`) by linear least squares in `n^2` at each; `None` when no pole gives a
/// positive strength.
fn sellmeier_through(
    c: &Candidate,
    lo_nm: f64,
    hi_nm: f64,
    with_constant: bool,
) -> Option<[f64; 3]> {
    let m = 17;
    let l_lo = lo_nm * 1e-3;
    let at = |i: usize| (lo_nm + (hi_nm - lo_nm) * i as f64 / (m - 1) as f64) * 1e-3;
    let kind = if with_constant {
        ModelKind::Sellmeier1c
    } else {
        ModelKind::Sellmeier1
    };
    let mut best: Option<(f64, [f64; 3])> = None;
    for step in 0..80 {
        let l2p = 0.8 * l_lo * l_lo * f64::from(step) / 80.0;
        // y = n^2 = A + S f: least squares in (A, S), or S alone with A = 1.
        let (mut sf, mut sy, mut sff, mut sfy) = (0.0, 0.0, 0.0, 0.0);
        for i in 0..m {
            let l = at(i);
            let n = c.kind.eval(&c.params, l).0;
            let f = l * l / (l * l - l2p);
            let y = n * n;
            sf += f;
            sy += y;
            sff += f * f;
            sfy += f * y;
        }
        let mf = m as f64;
        let (a, s) = if with_constant {
            let det = mf * sff - sf * sf;
            if det.abs() < 1e-18 {
                continue;
            }
            let s = (mf * sfy - sf * sy) / det;
            ((sy - s * sf) / mf, s)
        } else {
            (1.0, (sfy - sf) / sff)
        };
        if s <= 0.0 || a <= 0.0 {
            continue;
        }
        let p = [s, l2p, a];
        let mut err = 0.0;
        for i in 0..m {
            let d = kind.eval(&p, at(i)).0 - c.kind.eval(&c.params, at(i)).0;
            err += d * d;
        }
        if err.is_finite() && best.is_none_or(|(e, _)| err < e) {
            best = Some((err, p));
        }
    }
    best.map(|(_, p)| p)
}
