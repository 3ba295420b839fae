//! The sample's noise, measured from each site's run of pixels without any model (the
//! fourth difference across the run), and the weight every fit gives each sample by its
//! site, angle and band with the model's error added.

#[cfg(doc)]
use super::SampleFit;
use super::{Geometry, Spectra, MAX_BANDS, MAX_SITES, NOISE_ANGLES, NOISE_FLOOR, RUN};

/// The sample's noise: sample `(k, a, b)` (site, angle, band) has the variance
/// `(site[k] angle[a] band[b])^2 + model2`. Sites see different noise (vignetting, shot noise
/// at their own reflectance), bands too (a lamp dim in the blue, the filter's throughput) and
/// angles (a darker angle), so each is weighed by its own; `model2` is the model's error
/// ([`SampleFit::model_error`]) added to each.
#[derive(Clone)]
pub(super) struct Noise {
    pub(super) site: [f64; MAX_SITES],
    pub(super) angle: [f64; NOISE_ANGLES],
    pub(super) band: [f64; MAX_BANDS],
    pub(super) model2: f64,
}

impl Noise {
    /// The same noise `sigma` at every sample.
    pub(super) fn uniform(sigma: f64) -> Self {
        Self {
            site: [sigma; MAX_SITES],
            angle: [1.0; NOISE_ANGLES],
            band: [1.0; MAX_BANDS],
            model2: 0.0,
        }
    }

    /// The noise variance of sample `(k, a, b)`, without the model's error.
    #[inline]
    pub(super) fn noise2(&self, k: usize, a: usize, b: usize) -> f64 {
        let s =
            (self.site[k] * self.angle[a.min(NOISE_ANGLES - 1)] * self.band[b]).max(NOISE_FLOOR);
        s * s
    }

    /// The weight of sample `(k, a, b)`: one over its noise and model variance.
    #[inline]
    pub(super) fn weight(&self, k: usize, a: usize, b: usize) -> f64 {
        1.0 / (self.noise2(k, a, b) + self.model2)
    }

    /// Site `k`'s weight over all its samples (the search's, which weighs bands alike).
    #[inline]
    pub(super) fn site_weight(&self, k: usize) -> f64 {
        let s = self.site[k].max(NOISE_FLOOR);
        1.0 / (s * s + self.model2)
    }
}

/// The fourth difference across site `k`'s run at angle `a`, band `b` (NaN where a value is
/// missing): white noise of sigma `s` gives `sqrt(70) s`; a thickness varying smoothly over
/// five pixels nothing.
#[inline]
fn fourth_difference(spectra: &Spectra<'_>, nb: usize, k: usize, a: usize, b: usize) -> f32 {
    let v: [f32; RUN] = core::array::from_fn(|j| spectra.at(nb, k, j, a, b));
    v[0] - 4.0 * v[1] + 6.0 * v[2] - 4.0 * v[3] + v[4]
}

/// The median of `v` (reordered), NaN when empty.
pub(super) fn median(v: &mut [f32]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let n = v.len();
    let (_, m, _) = v.select_nth_unstable_by(n / 2, f32::total_cmp);
    f64::from(*m)
}

/// `|d|` of a normal deviate's median over its sigma.
const MEDIAN_ABS: f64 = 0.674_49;

/// The sample's noise from its runs' fourth differences across the row, in four passes: each
/// site's typical level (the median `|d|`), the profile across bands (the median over sites
/// and angles of `|d|` over its site's level, pooled over neighbouring bands until about 200
/// values), across angles (likewise over sites and bands), and each site's level again as
/// the RMS of its differences within 4 robust sigmas of zero (a step or a hot pixel left
/// out) once the profiles are divided out. Returns the noise (its model error 0) and the
/// median site's level.
pub(super) fn measure_noise(
    geo: &Geometry<'_>,
    spectra: &Spectra<'_>,
    scratch: &mut [f32],
) -> (Noise, f64) {
    let (na, nb) = (geo.angles_deg.len(), geo.bands_nm.len());
    let sites = spectra.sites.min(MAX_SITES);
    let mut noise = Noise::uniform(f64::NAN);
    if spectra.run != RUN {
        return (noise, f64::NAN);
    }
    let unit = MEDIAN_ABS * libm::sqrt(70.0);
    // 1. Each site's level.
    let mut level = [f64::NAN; MAX_SITES];
    for (k, out) in level.iter_mut().enumerate().take(sites) {
        let mut n = 0;
        for a in 0..na {
            for b in 0..nb {
                let d = fourth_difference(spectra, nb, k, a, b);
                if d.is_finite() {
                    scratch[n] = d.abs();
                    n += 1;
                }
            }
        }
        if n >= 16 {
            let m = median(&mut scratch[..n]) / unit;
            if m > 0.0 {
                *out = m;
            }
        }
    }
    let levelled = level.iter().take(sites).filter(|l| l.is_finite()).count();
    if levelled == 0 {
        return (noise, f64::NAN);
    }
    // 2. Across bands, pooled over neighbouring bands to about 200 values.
    let per_band = levelled * na;
    let half = (200usize.div_ceil(per_band.max(1)) / 2).min(nb / 8);
    let ratio = |k: usize, a: usize, b: usize| -> f32 {
        (f64::from(fourth_difference(spectra, nb, k, a, b).abs()) / level[k]) as f32
    };
    for b in 0..nb {
        let mut n = 0;
        for bb in b.saturating_sub(half)..(b + half + 1).min(nb) {
            for k in (0..sites).filter(|&k| level[k].is_finite()) {
                for a in 0..na {
                    let r = ratio(k, a, bb);
                    if r.is_finite() {
                        scratch[n] = r;
                        n += 1;
                    }
                }
            }
        }
        let m = median(&mut scratch[..n]) / unit;
        noise.band[b] = if m > 0.0 && m.is_finite() { m } else { 1.0 };
    }
    normalise(&mut noise.band[..nb]);
    // 3. Across angles.
    for a in 0..na.min(NOISE_ANGLES) {
        let mut n = 0;
        for k in (0..sites).filter(|&k| level[k].is_finite()) {
            for b in 0..nb {
                let r = ratio(k, a, b) / noise.band[b] as f32;
                if r.is_finite() {
                    scratch[n] = r;
                    n += 1;
                }
            }
        }
        let m = median(&mut scratch[..n]) / unit;
        noise.angle[a] = if m > 0.0 && m.is_finite() { m } else { 1.0 };
    }
    normalise(&mut noise.angle[..na.min(NOISE_ANGLES)]);
    // 4. Each site's level with the profiles divided out.
    for k in 0..sites {
        let mut n = 0;
        for a in 0..na {
            let fa = noise.angle[a.min(NOISE_ANGLES - 1)];
            for b in 0..nb {
                let d = fourth_difference(spectra, nb, k, a, b);
                if d.is_finite() {
                    scratch[n] = (f64::from(d.abs()) / (fa * noise.band[b])) as f32;
                    n += 1;
                }
            }
        }
        if n < 16 {
            continue;
        }
        let cut = 4.0 * 1.4826 * median(&mut scratch[..n]);
        let (mut sum, mut count) = (0.0, 0usize);
        for &d in &scratch[..n] {
            let d = f64::from(d);
            if d <= cut {
                sum += d * d;
                count += 1;
            }
        }
        if count > 0 {
            noise.site[k] = libm::sqrt(sum / count as f64 / 70.0).max(NOISE_FLOOR);
        }
    }
    let mut n = 0;
    for &s in noise.site.iter().take(sites) {
        if s.is_finite() {
            scratch[n] = s as f32;
            n += 1;
        }
    }
    let m = median(&mut scratch[..n]);
    (noise, m)
}

/// Scales `v` to a mean square of 1 (unchanged when it has none).
fn normalise(v: &mut [f64]) {
    let ms = v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64;
    if ms > 0.0 && ms.is_finite() {
        let s = 1.0 / libm::sqrt(ms);
        v.iter_mut().for_each(|x| *x *= s);
    }
}
