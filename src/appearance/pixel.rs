//! The fit at one pixel: its measured band reflectance at every angle against the film
//! model at its estimated thickness, the residual, and the fits of the neighbouring
//! interference orders (`filmscope report RUN --pixel X,Y`, Python's `pixel_fit`).
//!
//! The model is the estimated film (index and dispersion) on the capture's substrate,
//! averaged over each band's passband, at each frame's incidence angle (as
//! [`super::compare`] models it), with the sample fit's nuisance terms as the per-pixel
//! passes applied them ([`crate::pipeline::Correction`]): the measured values with each
//! angle's reflectance scale and offset and the flare taken out, the model at the stage's
//! offset angle and the shifted bands, absorbing and leaking as the film terms say. Order candidates are the local minima of the RMS
//! residual against thickness over two and a half interference orders either side of the
//! estimate (of the median thickness for a pixel without one), each refined to 0.01 nm:
//! the estimate should be the deepest, and how much deeper it is says how sure its order is.

use std::fmt::Write as _;

use filmscope_core::optics::{FilmStack, Passband};

use super::spectral::BandReflectance;
use super::AppearanceError;
use crate::export::plot::{render_scatter_panels_png, Scatter, Series};
use crate::pipeline::{for_each_calibrated_rows, Calibrated, Correction};
use crate::source::Source;

/// Most order candidates reported.
pub const MAX_CANDIDATES: usize = 5;

/// Interference orders scanned either side of the estimate.
const ORDERS_EACH_SIDE: f64 = 2.5;

/// Thickness steps per order in the scan.
const STEPS_PER_ORDER: f64 = 40.0;

/// A thickness whose model is a local best fit to the pixel's spectra.
#[derive(Clone, Debug)]
pub struct OrderCandidate {
    /// The thickness, nm.
    pub thickness_nm: f64,
    /// RMS of measured minus model over the usable samples.
    pub rms: f64,
    /// The model at this thickness, `[angle][band]`.
    pub model: Vec<Vec<f64>>,
}

/// One pixel's spectra, model, residual and order candidates.
#[derive(Clone, Debug)]
pub struct PixelFit {
    /// Column.
    pub x: usize,
    /// Row.
    pub y: usize,
    /// The estimated thickness, nm (NaN: the pixel has none).
    pub thickness_nm: f64,
    /// Band centres, nm.
    pub wavelengths_nm: Vec<f64>,
    /// Incidence angles, degrees, increasing.
    pub angles_deg: Vec<f64>,
    /// Measured band reflectance, `[angle][band]` (NaN where unusable), corrected by the
    /// sample's reflectance terms and flare.
    pub measured: Vec<Vec<f64>>,
    /// The model at the estimated thickness, `[angle][band]` (NaN without one).
    pub model: Vec<Vec<f64>>,
    /// Order candidates, best (lowest RMS) first.
    pub candidates: Vec<OrderCandidate>,
}

impl PixelFit {
    /// Measured minus model, `[angle][band]`.
    pub fn residual(&self) -> Vec<Vec<f64>> {
        self.measured
            .iter()
            .zip(&self.model)
            .map(|(m, f)| m.iter().zip(f).map(|(a, b)| a - b).collect())
            .collect()
    }

    /// RMS of the residual at angle `a` over its usable samples (NaN without any).
    pub fn rms_at(&self, a: usize) -> f64 {
        rms(&self.measured[a..=a], &self.model[a..=a])
    }

    /// The text `report --pixel` prints: per angle the residual's RMS and largest value,
    /// then the order candidates.
    pub fn table(&self) -> String {
        let mut s = format!(
            "pixel ({}, {}): thickness {} nm\n{:>9} {:>8} {:>12} {:>12}\n",
            self.x,
            self.y,
            fmt_nm(self.thickness_nm),
            "angle",
            "usable",
            "RMS resid",
            "max |resid|"
        );
        for (a, deg) in self.angles_deg.iter().enumerate() {
            let r: Vec<f64> = self.measured[a]
                .iter()
                .zip(&self.model[a])
                .map(|(m, f)| m - f)
                .filter(|v| v.is_finite())
                .collect();
            let max = r.iter().fold(f64::NAN, |acc, v| acc.max(v.abs()));
            let _ = writeln!(
                s,
                "{deg:>9.2} {:>8} {:>12.6} {:>12.6}",
                r.len(),
                self.rms_at(a),
                max
            );
        }
        let _ = writeln!(s, "order candidates (RMS residual over every angle):");
        for (i, c) in self.candidates.iter().enumerate() {
            let _ = writeln!(
                s,
                "  {}. {:>9.2} nm  RMS {:.6}{}",
                i + 1,
                c.thickness_nm,
                c.rms,
                if (c.thickness_nm - self.thickness_nm).abs() < 1.0 {
                    "  (the estimate)"
                } else {
                    ""
                }
            );
        }
        s
    }

    /// `angle_deg,wavelength_nm,measured,model,residual`, one row a sample.
    pub fn to_csv(&self) -> String {
        let mut s = String::from("angle_deg,wavelength_nm,measured,model,residual\n");
        for (a, deg) in self.angles_deg.iter().enumerate() {
            for (b, l) in self.wavelengths_nm.iter().enumerate() {
                let (m, f) = (self.measured[a][b], self.model[a][b]);
                let _ = writeln!(s, "{deg},{l},{m},{f},{}", m - f);
            }
        }
        s
    }

    /// A PNG: one panel an angle (measured and model against wavelength), the residual at
    /// every angle, and the candidates' RMS against thickness.
    pub fn to_png(&self) -> Result<Vec<u8>, AppearanceError> {
        let pts = |v: &[f64]| -> Vec<(f64, f64)> {
            self.wavelengths_nm
                .iter()
                .copied()
                .zip(v.iter().copied())
                .collect()
        };
        let measured: Vec<Vec<(f64, f64)>> = self.measured.iter().map(|v| pts(v)).collect();
        let model: Vec<Vec<(f64, f64)>> = self.model.iter().map(|v| pts(v)).collect();
        let residual: Vec<Vec<(f64, f64)>> = self.residual().iter().map(|v| pts(v)).collect();
        let titles: Vec<String> = self.angles_deg.iter().map(|d| format!("{d:.1}°")).collect();
        let per_angle: Vec<[Series; 2]> = (0..self.angles_deg.len())
            .map(|a| {
                [
                    Series {
                        name: "measured",
                        points: &measured[a],
                        labels: None,
                    },
                    Series {
                        name: "model",
                        points: &model[a],
                        labels: None,
                    },
                ]
            })
            .collect();
        let resid_series: Vec<Series> = residual
            .iter()
            .zip(&titles)
            .map(|(p, t)| Series {
                name: t,
                points: p,
                labels: None,
            })
            .collect();
        let cand_pts: Vec<(f64, f64)> = self
            .candidates
            .iter()
            .map(|c| (c.thickness_nm, c.rms))
            .collect();
        let cand_labels: Vec<String> = (1..=cand_pts.len()).map(|i| i.to_string()).collect();
        let cand_series = [Series {
            name: "candidate",
            points: &cand_pts,
            labels: Some(&cand_labels),
        }];
        let mut panels: Vec<Scatter> = per_angle
            .iter()
            .zip(&titles)
            .map(|(series, t)| Scatter {
                title: t,
                x_label: "wavelength, nm",
                y_label: "reflectance",
                x_log: false,
                y_log: false,
                series,
                pareto: false,
            })
            .collect();
        panels.push(Scatter {
            title: "residual (measured - model)",
            x_label: "wavelength, nm",
            y_label: "residual",
            x_log: false,
            y_log: false,
            series: &resid_series,
            pareto: false,
        });
        panels.push(Scatter {
            title: "order candidates",
            x_label: "thickness, nm",
            y_label: "RMS residual",
            x_log: false,
            y_log: false,
            series: &cand_series,
            pareto: false,
        });
        let title = format!(
            "pixel ({}, {}), d = {} nm",
            self.x,
            self.y,
            fmt_nm(self.thickness_nm)
        );
        render_scatter_panels_png(&title, &panels).map_err(AppearanceError::from)
    }
}

fn fmt_nm(d: f64) -> String {
    if d.is_finite() {
        format!("{d:.2}")
    } else {
        "none".into()
    }
}

/// RMS of `measured - model` over the samples where both are finite.
fn rms(measured: &[Vec<f64>], model: &[Vec<f64>]) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for (m, f) in measured.iter().zip(model) {
        for (a, b) in m.iter().zip(f) {
            let r = a - b;
            if r.is_finite() {
                s += r * r;
                n += 1;
            }
        }
    }
    if n == 0 {
        f64::NAN
    } else {
        (s / n as f64).sqrt()
    }
}

/// The calibrated band reflectance of pixel `(x, y)` at every angle of `source`,
/// `(angles_deg, [angle][band])` in streaming order.
pub fn measured_spectra(
    source: &mut dyn Source,
    x: usize,
    y: usize,
) -> Result<(Vec<f64>, Vec<Vec<f64>>), AppearanceError> {
    let spec = source.spec().clone();
    let (w, h, nb) = (spec.width, spec.height, spec.bands_nm.len());
    if x >= w || y >= h {
        return Err(AppearanceError::Mismatch(format!(
            "pixel ({x}, {y}) is outside the {w}x{h} capture"
        )));
    }
    let mut angles: Vec<(f64, Vec<f64>)> = Vec::new();
    // Only row `y` is needed: a source that can skip rows reads no other.
    for_each_calibrated_rows(source, Some(&[y]), |event| match event {
        Calibrated::Angle(deg) => angles.push((deg, vec![f64::NAN; nb])),
        Calibrated::Rows {
            band,
            first_row,
            rows,
            values,
            ..
        } => {
            if (first_row..first_row + rows).contains(&y) {
                if let (Some(a), Some(&v)) =
                    (angles.last_mut(), values.get((y - first_row) * w + x))
                {
                    if let Some(slot) = a.1.get_mut(band) {
                        *slot = f64::from(v);
                    }
                }
            }
        }
    })
    .map_err(AppearanceError::from)?;
    Ok(angles.into_iter().unzip())
}

/// The fit of `stack` at thickness `thickness_nm` (NaN: none; the scan then centres on
/// `fallback_nm`) to one pixel's `measured` spectra (`[angle][band]`, angles as
/// `angles_deg` in streaming order, bands as `bands`), the sample's nuisance terms
/// `correction` applied as the per-pixel passes apply them; the fit's angles increasing.
#[allow(clippy::too_many_arguments)]
pub fn fit_pixel(
    (x, y): (usize, usize),
    stack: &FilmStack,
    bands: &[Passband],
    angles_deg: &[f64],
    measured: Vec<Vec<f64>>,
    thickness_nm: f64,
    fallback_nm: f64,
    correction: &Correction,
) -> PixelFit {
    let mut rows: Vec<(f64, Vec<f64>)> = angles_deg
        .iter()
        .zip(measured)
        .enumerate()
        .map(|(a, (&deg, row))| {
            let (scale, offset) = correction
                .terms
                .get(a)
                .map_or((1.0, 0.0), |&(s, o)| (f64::from(s), f64::from(o)));
            let offset = offset + f64::from(correction.flare);
            (deg, row.into_iter().map(|v| (v - offset) / scale).collect())
        })
        .collect();
    rows.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (angles_deg, measured): (Vec<f64>, Vec<Vec<f64>>) = rows.into_iter().unzip();
    let models: Vec<Vec<BandReflectance>> = angles_deg
        .iter()
        .map(|&a| {
            bands
                .iter()
                .map(|b| {
                    let band =
                        Passband::gaussian(b.center_nm + correction.band_shift_nm, b.fwhm_nm);
                    BandReflectance::new(
                        stack,
                        a + correction.angle_offset_deg,
                        band,
                        correction.film,
                    )
                })
                .collect()
        })
        .collect();
    let model_at = |d: f64| -> Vec<Vec<f64>> {
        models
            .iter()
            .map(|row| row.iter().map(|m| m.reflectance(d)).collect())
            .collect()
    };
    let rms_at = |d: f64| rms(&measured, &model_at(d));
    let model = if thickness_nm.is_finite() {
        model_at(thickness_nm)
    } else {
        vec![vec![f64::NAN; bands.len()]; angles_deg.len()]
    };
    // One interference order in thickness at mid-band and the first angle.
    let centre = if thickness_nm.is_finite() {
        thickness_nm
    } else {
        fallback_nm
    };
    let mut candidates = Vec::new();
    if let (Some(mid), Some(&a0)) = (bands.get(bands.len() / 2), angles_deg.first()) {
        let l = mid.center_nm;
        let n = stack.film.index_at(l);
        let beta = stack.ambient_index * a0.to_radians().sin();
        let order = l / (2.0 * (n * n - beta * beta).max(1e-6).sqrt());
        let step = order / STEPS_PER_ORDER;
        if centre.is_finite() && step.is_finite() && step > 0.0 {
            let lo = (centre - ORDERS_EACH_SIDE * order).max(0.0);
            let count = ((centre + ORDERS_EACH_SIDE * order - lo) / step).ceil() as usize + 1;
            let scan: Vec<(f64, f64)> = (0..count)
                .map(|i| {
                    let d = lo + step * i as f64;
                    (d, rms_at(d))
                })
                .collect();
            for i in 1..scan.len().saturating_sub(1) {
                let (p, c, q) = (scan[i - 1].1, scan[i].1, scan[i + 1].1);
                if c.is_finite() && c <= p && c < q {
                    let d = golden_min(&rms_at, scan[i - 1].0, scan[i + 1].0, 0.01);
                    candidates.push(OrderCandidate {
                        thickness_nm: d,
                        rms: rms_at(d),
                        model: model_at(d),
                    });
                }
            }
        }
    }
    candidates.sort_by(|a, b| a.rms.total_cmp(&b.rms));
    candidates.truncate(MAX_CANDIDATES);
    PixelFit {
        x,
        y,
        thickness_nm,
        wavelengths_nm: bands.iter().map(|b| b.center_nm).collect(),
        angles_deg,
        measured,
        model,
        candidates,
    }
}

/// The minimum of `f` on `[a, b]` by golden-section search, to `tol`.
fn golden_min(f: &dyn Fn(f64) -> f64, mut a: f64, mut b: f64, tol: f64) -> f64 {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    while b - a > tol {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    0.5 * (a + b)
}

/// The fit at pixel `(x, y)` of the maps `film` to the capture `source` they were
/// estimated from.
pub fn pixel_fit(
    film: &super::SampleFilm,
    source: &mut dyn Source,
    x: usize,
    y: usize,
) -> Result<PixelFit, AppearanceError> {
    if x >= film.width || y >= film.height {
        return Err(AppearanceError::Mismatch(format!(
            "pixel ({x}, {y}) is outside the {}x{} maps",
            film.width, film.height
        )));
    }
    let spec = source.spec().clone();
    if (spec.width, spec.height) != (film.width, film.height) {
        return Err(AppearanceError::Mismatch(format!(
            "the maps are {}x{} but the capture is {}x{}",
            film.width, film.height, spec.width, spec.height
        )));
    }
    let bands: Vec<Passband> = spec
        .bands_nm
        .iter()
        .zip(&spec.fwhm_nm)
        .map(|(&l, &w)| Passband::gaussian(l, w))
        .collect();
    let (angles, measured) = measured_spectra(source, x, y)?;
    let d = film.thickness_at(y * film.width + x).unwrap_or(f64::NAN);
    let fallback = film.median_thickness_nm().unwrap_or(f64::NAN);
    let correction = crate::estimate::index_fit::correction_from(
        film.summary
            .index_model_choice
            .as_ref()
            .and_then(|c| c.nuisance_terms()),
    );
    Ok(fit_pixel(
        (x, y),
        &film.stack,
        &bands,
        &angles,
        measured,
        d,
        fallback,
        &correction,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use filmscope_core::optics::{BackFace, Dispersion, Polarization};
    use filmscope_core::solve::refine::FilmTerms;

    /// Noise-free spectra of a known film: the estimate is the best candidate, its
    /// residual is nil, and the neighbouring orders fit worse.
    #[test]
    fn the_true_thickness_is_the_best_candidate() {
        let stack = FilmStack {
            back_face: BackFace::None,
            ambient_index: 1.0,
            film: Dispersion::constant(1.38),
            substrate: Dispersion::constant(1.65),
            polarization: Polarization::S,
        };
        let bands: Vec<Passband> = (0..151)
            .map(|i| Passband::gaussian(420.0 + 2.0 * f64::from(i), 4.0))
            .collect();
        let angles = [10.0, 30.0, 50.0];
        let truth = 612.3;
        let measured: Vec<Vec<f64>> = angles
            .iter()
            .map(|&a| {
                bands
                    .iter()
                    .map(|b| stack.band_reflectance(truth, a, b))
                    .collect()
            })
            .collect();
        let none = Correction::default();
        let fit = fit_pixel(
            (3, 4),
            &stack,
            &bands,
            &angles,
            measured,
            truth,
            f64::NAN,
            &none,
        );
        assert!(fit.rms_at(0) < 1e-9, "{}", fit.rms_at(0));
        let best = &fit.candidates[0];
        assert!(
            (best.thickness_nm - truth).abs() < 0.05,
            "{}",
            best.thickness_nm
        );
        assert!(fit.candidates.len() >= 3, "{}", fit.table());
        assert!(fit.candidates[1].rms > 1e-3);
        assert!(fit.table().contains("(the estimate)"));
        assert_eq!(fit.to_csv().lines().count(), 1 + 3 * 151);
        // Without an estimate the scan centres on the fallback and still finds it.
        let m = fit.measured.clone();
        let blind = fit_pixel((3, 4), &stack, &bands, &angles, m, f64::NAN, 650.0, &none);
        assert!((blind.candidates[0].thickness_nm - truth).abs() < 0.05);
        assert!(blind.model[0][0].is_nan());
    }

    /// Spectra a rig with a stage offset, a wavelength shift, flare and each angle's own
    /// white-reference error measured, given in streaming order (not increasing): with the
    /// sample's correction the model meets them exactly at the true thickness; without it
    /// the residual is at the terms' size.
    #[test]
    fn the_sample_terms_are_applied_as_the_passes_apply_them() {
        let stack = FilmStack {
            back_face: BackFace::None,
            ambient_index: 1.0,
            film: Dispersion::constant(2.05),
            substrate: Dispersion::constant(1.52),
            polarization: Polarization::P,
        };
        let bands: Vec<Passband> = (0..101)
            .map(|i| Passband::gaussian(420.0 + 3.0 * f64::from(i), 5.0))
            .collect();
        let angles = [40.0, 10.0, 25.0];
        let correction = Correction {
            angle_offset_deg: 0.3,
            band_shift_nm: -0.4,
            terms: vec![(1.02, 0.001), (0.99, -0.002), (1.01, 0.0)],
            flare: 0.002,
            film: FilmTerms::NONE,
        };
        let truth = 488.0;
        let measured: Vec<Vec<f64>> = angles
            .iter()
            .zip(&correction.terms)
            .map(|(&a, &(scale, offset))| {
                bands
                    .iter()
                    .map(|b| {
                        let shifted = Passband::gaussian(b.center_nm - 0.4, b.fwhm_nm);
                        let r = stack.band_reflectance(truth, a + 0.3, &shifted);
                        f64::from(scale) * r + f64::from(offset) + 0.002
                    })
                    .collect()
            })
            .collect();
        let fit = fit_pixel(
            (0, 0),
            &stack,
            &bands,
            &angles,
            measured.clone(),
            truth,
            f64::NAN,
            &correction,
        );
        assert_eq!(fit.angles_deg, vec![10.0, 25.0, 40.0]);
        for a in 0..3 {
            assert!(fit.rms_at(a) < 1e-6, "angle {a}: {}", fit.table());
        }
        assert!(
            (fit.candidates[0].thickness_nm - truth).abs() < 0.05,
            "{}",
            fit.table()
        );
        let plain = fit_pixel(
            (0, 0),
            &stack,
            &bands,
            &angles,
            measured,
            truth,
            f64::NAN,
            &Correction::default(),
        );
        assert!(plain.rms_at(0) > 1e-3, "{}", plain.table());
    }
}
