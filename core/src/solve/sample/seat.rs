//! Seating thicknesses under a given index: every usable site's thickness (the dictionary,
//! then Gauss-Newton with the passband in full), and the pixels the streaming pass could
//! not settle, each by its full spectra.

use super::noise::Noise;
#[cfg(doc)]
use super::SampleFit;
use super::{
    workspace_len, Geometry, ModelKind, Nuisance, Parallel, Problem, SiteSums, Spectra, Terms,
    MAX_BANDS, MAX_SITES, NOISE_ANGLES,
};

/// One pixel's thickness under a given index ([`seat_pixels`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Seat {
    /// Thickness, nm (NaN: too few samples).
    pub thickness_nm: f64,
    /// Its 1-sigma uncertainty, nm (scaled by the reduced chi-square when above 1).
    pub sigma_nm: f64,
    /// Reduced chi-square of the pixel's full spectra at that thickness, in units of the
    /// given noise.
    pub chi2_nu: f64,
    /// How much worse (chi-square, noise units) the best thickness in another order's
    /// basin fits, on the search's bands.
    pub margin_chi2: f64,
}

/// Each pixel's thickness from its full spectra under the index `(kind, params)` by the
/// sample fit's own search (a dictionary over the thickness range, then Gauss-Newton with
/// the passband quadrature): for pixels whose order the streaming pass could not settle.
/// `spectra` holds one pixel per site (`run` 1); `noise_sigma` is the image's and
/// `model_error` the model's (the sample fit's: [`SampleFit::noise_sigma`],
/// [`SampleFit::model_error`]), the chi-squares in units of both; `nuisance` the terms the
/// sample's fit took ([`SampleFit::nuisance`]). `scratch` holds at least [`workspace_len`] values; `out` one entry per site.
#[allow(clippy::too_many_arguments)]
pub fn seat_pixels(
    geo: &Geometry<'_>,
    spectra: &Spectra<'_>,
    kind: ModelKind,
    params: [f64; 3],
    noise_sigma: f64,
    model_error: f64,
    nuisance: &Nuisance,
    scratch: &mut [f32],
    out: &mut [Seat],
    par: &dyn Parallel,
) {
    let (na, nb) = (geo.angles_deg.len(), geo.bands_nm.len());
    let sites = spectra.sites.min(MAX_SITES).min(out.len());
    let nan = Seat {
        thickness_nm: f64::NAN,
        sigma_nm: f64::NAN,
        chi2_nu: f64::NAN,
        margin_chi2: f64::NAN,
    };
    out.iter_mut().for_each(|o| *o = nan);
    if na < 1
        || !(8..=MAX_BANDS).contains(&nb)
        || sites == 0
        || noise_sigma.is_nan()
        || noise_sigma <= 0.0
        || scratch.len() < workspace_len(sites, na, nb)
    {
        return;
    }
    let usable = complete_sites(spectra, sites, na, nb);
    let mut terms = Terms::NONE;
    for (a, &(scale, offset)) in nuisance.terms.iter().enumerate().take(NOISE_ANGLES) {
        (terms.scale[a], terms.offset[a]) = (scale, offset);
    }
    let problem = Problem {
        geo,
        spectra,
        usable: &usable[..sites],
        noise: Noise {
            model2: model_error * model_error,
            ..Noise::uniform(noise_sigma)
        },
        terms,
        retry: false,
        film_k: nuisance.film_k,
        leak: nuisance.leak,
        stage_deg: nuisance.stage_deg,
        shift_nm: nuisance.shift_nm,
        flare: nuisance.flare,
        side_lobes: nuisance.side_lobes,
        wide: &[],
        par,
    };
    let Some((t, sums, margin)) = problem.seat(kind, &params, scratch) else {
        return;
    };
    for (k, o) in out.iter_mut().enumerate().take(sites) {
        let s = &sums[k];
        if !usable[k] || s.jdd <= 0.0 || s.n < 2 {
            continue;
        }
        let chi2_nu = s.sse / (s.n - 1) as f64;
        *o = Seat {
            thickness_nm: t[k],
            sigma_nm: libm::sqrt(chi2_nu.max(1.0) / s.jdd),
            chi2_nu,
            margin_chi2: margin[k],
        };
    }
}

/// The first `sites` sites with at most a tenth of their own pixel's `angles x bands` samples
/// missing.
pub(super) fn complete_sites(
    spectra: &Spectra<'_>,
    sites: usize,
    angles: usize,
    bands: usize,
) -> [bool; MAX_SITES] {
    let mut usable = [false; MAX_SITES];
    for (k, u) in usable.iter_mut().enumerate().take(sites) {
        let bad = (0..angles)
            .flat_map(|a| (0..bands).map(move |b| (a, b)))
            .filter(|&(a, b)| !spectra.centre_at(bands, k, a, b).is_finite())
            .count();
        *u = bad * 10 <= angles * bands;
    }
    usable
}

impl Problem<'_> {
    /// Every usable site's thickness under `(kind, p)` held: the best of the dictionary over
    /// the thickness range on every band, then Gauss-Newton on each thickness with the
    /// passband's quadrature in full. The thicknesses, the sites' sums at them and each
    /// site's margin (how much worse, chi-square, the best thickness in another order's
    /// basin fits); `None` when a model cannot be evaluated.
    pub(super) fn seat(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        scratch: &mut [f32],
    ) -> Option<([f64; MAX_SITES], [SiteSums; MAX_SITES], [f64; MAX_SITES])> {
        let all: [usize; MAX_SITES] = core::array::from_fn(|k| k);
        let sites = self.usable.len();
        let mut t = [f64::NAN; MAX_SITES];
        let mut margin = [f64::NAN; MAX_SITES];
        self.score_point(
            kind,
            p,
            &all[..sites],
            self.geo.bands_nm.len(),
            0,
            scratch,
            Some(&mut t),
            Some(&mut margin),
        )?;
        let mut sums = [SiteSums::default(); MAX_SITES];
        // The index is held: the thickness's sums alone.
        for _ in 0..4 {
            self.normal::<false>(kind, p, &t, &mut sums)?;
            for (k, s) in sums.iter().enumerate().take(sites) {
                if self.usable[k] && s.jdd > 0.0 {
                    t[k] += (s.gd / s.jdd).clamp(-5.0, 5.0);
                }
            }
        }
        self.normal::<false>(kind, p, &t, &mut sums)?;
        Some((t, sums, margin))
    }
}
