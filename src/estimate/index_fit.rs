//! The sample of pixels whose full spectra give the shared index ([`filmscope_core::solve::sample`]):
//! held as the rows stream past, fitted when an angle or the sweep completes, and turned
//! into the solver's index model, a thickness seed map and `summary.json`'s evidence.

use filmscope_core::solve::refine::ABSORPTION_TAIL_NM;
use filmscope_core::solve::sample::{
    fit_index, hold_index, run_pixel, runs_along_columns, seat_pixels, site_grid, workspace_len,
    Failure, Geometry, ModelKind, Nuisance, Parallel, Residual, SampleFit, Seat, Spectra, Start,
    Term, CENTRE, CONSTANT_PREFERENCE, GATE_CHI2_NU, MAX_SITES, MODEL_PENALTY, OUTLIER_SITE_RATIO,
    RUN, TOLERANCE,
};
use filmscope_core::solve::{IndexModel, SweepSpec};

use crate::record::finite;
use crate::record::index_choice::{
    AngleResidualRecord, Candidate, FittedChoice, NuisanceTerms, OneSigma, ReflectanceTerm,
    ResidualRecord, RigTolerance, TermRecord,
};

use crate::pipeline::Tap;

/// Sites sampled by default: more made no difference to the index's accuracy on 60 random
/// coatings, fewer leave the paper's scenes' index noisier than their 2e-4 target.
pub const DEFAULT_SITES: usize = 64;

/// Fringes across the band under which the per-pixel pass starts every pixel from the
/// sample's thickness map rather than from its own extrema (a film with no fringe pair).
pub const SEEDED_BELOW_FRINGES: f64 = 2.0;

/// The sample fit's jobs on scoped threads: the last on the calling thread, each other on
/// one of its own.
struct Threads;

impl Parallel for Threads {
    fn run(&self, jobs: &mut [&mut (dyn FnMut() + Send)]) {
        let Some((last, others)) = jobs.split_last_mut() else {
            return;
        };
        std::thread::scope(|scope| {
            for job in others.iter_mut() {
                scope.spawn(job);
            }
            last();
        });
    }
}

/// The sample fit's view of sweep `spec` at `angles_deg`.
fn geometry<'a>(spec: &'a SweepSpec, angles_deg: &'a [f64]) -> Geometry<'a> {
    Geometry {
        back_face: spec.back_face,
        bands_nm: &spec.bands_nm,
        fwhm_nm: &spec.fwhm_nm,
        angles_deg,
        ambient_index: spec.ambient_index,
        substrate: spec.substrate,
        polarization: spec.polarization,
        index_range: spec.index_range,
        thickness_range_nm: spec.thickness_range_nm,
        model_error: spec.model_error,
        rig_tolerance: spec.rig_tolerance,
    }
}

/// Angles beyond those announced re-lay the buffer with twice the room.
impl Tap for SampleTap {
    fn angle(&mut self, incidence_deg: f64) {
        self.angles_deg.push(incidence_deg);
        if self.angles_deg.len() > self.angle_stride {
            // More angles than announced: re-lay the buffer with twice the room.
            let stride = self.angle_stride * 2;
            let mut v = vec![f32::NAN; self.sites.len() * RUN * stride * self.bands];
            for kj in 0..self.sites.len() * RUN {
                for a in 0..self.angle_stride {
                    let from = (kj * self.angle_stride + a) * self.bands;
                    let to = (kj * stride + a) * self.bands;
                    v[to..to + self.bands].copy_from_slice(&self.values[from..from + self.bands]);
                }
            }
            self.values = v;
            self.angle_stride = stride;
        }
    }

    fn rows(&mut self, band: usize, first_row: usize, rows: usize, values: &[f32]) {
        let Some(a) = self.angles_deg.len().checked_sub(1) else {
            return;
        };
        if band >= self.bands {
            return;
        }
        for (k, &(r, c)) in self.sites.iter().enumerate() {
            for j in 0..RUN {
                let (y, x) = run_pixel(r as usize, c as usize, j, self.along_columns);
                if !(first_row..first_row + rows).contains(&y) || x >= self.width {
                    continue;
                }
                if let Some(&v) = values.get((y - first_row) * self.width + x) {
                    self.values[((k * RUN + j) * self.angle_stride + a) * self.bands + band] = v;
                }
            }
        }
    }

    fn image_rows(&self) -> Vec<usize> {
        let mut rows: Vec<usize> = self
            .sites
            .iter()
            .flat_map(|&(r, c)| {
                (0..RUN).map(move |j| run_pixel(r as usize, c as usize, j, self.along_columns).0)
            })
            .collect();
        rows.sort_unstable();
        rows.dedup();
        rows
    }
}

/// Angles beyond those announced are not held.
impl Tap for PixelTap {
    fn angle(&mut self, incidence_deg: f64) {
        self.angles_deg.push(incidence_deg);
    }

    fn rows(&mut self, band: usize, first_row: usize, rows: usize, values: &[f32]) {
        let Some(a) = self.angles_deg.len().checked_sub(1) else {
            return;
        };
        if band >= self.bands || a >= self.angle_stride {
            return;
        }
        let from = self
            .pixels
            .partition_point(|&(r, _)| (r as usize) < first_row);
        let to = self
            .pixels
            .partition_point(|&(r, _)| (r as usize) < first_row + rows);
        for k in from..to {
            let (r, c) = self.pixels[k];
            let i = (r as usize - first_row) * self.width + c as usize;
            if let Some(&v) = values.get(i) {
                self.values[(k * self.angle_stride + a) * self.bands + band] = v;
            }
        }
    }

    fn image_rows(&self) -> Vec<usize> {
        let mut rows: Vec<usize> = self.pixels.iter().map(|&(r, _)| r as usize).collect();
        rows.dedup();
        rows
    }
}

/// Bytes of spectra a [`PixelTap`] holds at most: the pixels it takes are thinned to fit.
pub const MAX_PIXEL_TAP_BYTES: usize = 32 << 20;

/// The calibrated spectra of chosen pixels (those the per-pixel pass left unsolved), held
/// as the sweep streams again, for [`filmscope_core::solve::sample::seat_pixels`].
#[derive(Clone, Debug)]
pub struct PixelTap {
    width: usize,
    bands: usize,
    /// `(row, column)`, sorted.
    pixels: Vec<(u32, u32)>,
    angle_stride: usize,
    angles_deg: Vec<f64>,
    values: Vec<f32>,
}

impl PixelTap {
    /// A tap for `pixels` (`(row, column)`, sorted) of sweep `spec` with `angles` angles,
    /// every so many of them when all would take more than [`MAX_PIXEL_TAP_BYTES`].
    pub fn new(spec: &SweepSpec, pixels: &[(u32, u32)], angles: usize) -> Self {
        let bands = spec.bands_nm.len();
        let angle_stride = angles.max(1);
        let per_pixel = (angle_stride * bands * 4).max(1);
        let keep = (MAX_PIXEL_TAP_BYTES / per_pixel).max(1);
        let step = pixels.len().div_ceil(keep).max(1);
        let pixels: Vec<(u32, u32)> = pixels.iter().copied().step_by(step).collect();
        Self {
            width: spec.width,
            bands,
            values: vec![f32::NAN; pixels.len() * angle_stride * bands],
            pixels,
            angle_stride,
            angles_deg: Vec::new(),
        }
    }

    /// The pixels held, `(row, column)`.
    pub fn pixels(&self) -> &[(u32, u32)] {
        &self.pixels
    }

    /// Each held pixel's thickness under the index `(kind, params)`, the image's noise, the
    /// model's error and the nuisance terms (the sample fit's).
    pub fn seat(
        &self,
        spec: &SweepSpec,
        kind: ModelKind,
        params: [f64; 3],
        noise_sigma: f64,
        model_error: f64,
        nuisance: &Nuisance,
    ) -> Vec<Seat> {
        let angles = self.angles_deg.len().min(self.angle_stride);
        let geo = geometry(spec, &self.angles_deg[..angles]);
        let per_pixel = self.angle_stride * self.bands;
        let mut scratch = vec![0.0f32; workspace_len(MAX_SITES, angles, self.bands)];
        let mut out = vec![Seat::default(); self.pixels.len()];
        for (chunk, seats) in out.chunks_mut(MAX_SITES).enumerate() {
            let first = chunk * MAX_SITES;
            let spectra = Spectra {
                values: &self.values[first * per_pixel..(first + seats.len()) * per_pixel],
                sites: seats.len(),
                angle_stride: self.angle_stride,
                run: 1,
            };
            seat_pixels(
                &geo,
                &spectra,
                kind,
                params,
                noise_sigma,
                model_error,
                nuisance,
                &mut scratch,
                seats,
                &Threads,
            );
        }
        out
    }
}

/// The sampled sites' calibrated spectra, held as the sweep streams.
#[derive(Clone, Debug)]
pub struct SampleTap {
    width: usize,
    bands: usize,
    /// Sites: the `(row, column)` of each run's first pixel.
    sites: Vec<(u32, u32)>,
    /// Whether the runs go down the columns (an image narrower than a run).
    along_columns: bool,
    angle_stride: usize,
    angles_deg: Vec<f64>,
    values: Vec<f32>,
}

impl SampleTap {
    /// A tap for `sites` sites of the sweep `spec`, with room for `angles` angles (it grows
    /// if more arrive).
    pub fn new(spec: &SweepSpec, sites: usize, angles: usize) -> Self {
        let grid = site_grid(spec.width, spec.height, sites);
        let angle_stride = angles.max(1);
        let bands = spec.bands_nm.len();
        Self {
            width: spec.width,
            bands,
            values: vec![f32::NAN; grid.len() * RUN * angle_stride * bands],
            sites: grid.to_vec(),
            along_columns: runs_along_columns(spec.width, spec.height),
            angle_stride,
            angles_deg: Vec::new(),
        }
    }

    /// The held value of site `k`'s run pixel `j` at angle `a`, band `b` (NaN: none).
    pub fn value(&self, k: usize, j: usize, a: usize, b: usize) -> f32 {
        self.values[((k * RUN + j) * self.angle_stride + a) * self.bands + b]
    }

    /// Each site's centre pixel, `(row, column)`.
    pub fn centres(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.sites
            .iter()
            .map(|&(r, c)| run_pixel(r as usize, c as usize, CENTRE, self.along_columns))
    }

    /// Bytes the held spectra take.
    pub fn bytes(&self) -> usize {
        self.values.len() * 4
    }

    /// Angles held.
    pub fn angles(&self) -> usize {
        self.angles_deg.len()
    }

    /// A copy holding only the first `angles` angles (those complete while the stream goes
    /// on into the next), so it can be fitted without holding up the stream.
    pub fn complete(&self, angles: usize) -> Self {
        let mut copy = self.clone();
        copy.angles_deg.truncate(angles);
        copy
    }

    /// Fits the index on the angles held so far, warm-started from `start` (this sample's
    /// fit on fewer angles: its sites' thicknesses carried too); `reselect`: every model
    /// refitted and chosen again from it (else only its model refined, kept if it passes
    /// the gate).
    pub fn fit(&self, spec: &SweepSpec, start: Option<&SampleFit>, reselect: bool) -> SampleFit {
        let start = start.and_then(|f| {
            f.best.map(|c| Start {
                kind: c.kind,
                params: c.params,
                reselect,
                thickness_nm: Some(f.thickness_nm),
            })
        });
        self.on_held(spec, |geo, spectra, scratch| {
            fit_index(geo, spectra, start, scratch, &Threads)
        })
    }

    /// The sites seated under the given index `(kind, params)`, held rather than fitted
    /// ([`hold_index`]).
    pub fn hold(&self, spec: &SweepSpec, kind: ModelKind, params: [f64; 3]) -> SampleFit {
        self.on_held(spec, |geo, spectra, scratch| {
            hold_index(geo, spectra, kind, params, scratch, &Threads)
        })
    }

    /// `f` on the angles held so far: their geometry, the held spectra and the fit's
    /// workspace.
    fn on_held(
        &self,
        spec: &SweepSpec,
        f: impl FnOnce(&Geometry<'_>, &Spectra<'_>, &mut [f32]) -> SampleFit,
    ) -> SampleFit {
        let geo = geometry(spec, &self.angles_deg);
        let spectra = Spectra {
            values: &self.values,
            sites: self.sites.len(),
            angle_stride: self.angle_stride,
            run: RUN,
        };
        let mut scratch =
            vec![0.0f32; workspace_len(self.sites.len(), self.angles_deg.len(), self.bands)];
        f(&geo, &spectra, &mut scratch)
    }

    /// Every pixel's starting thickness from the sites' (bilinear over the site grid, the
    /// nearest sites beyond it), for a film without fringe pairs; `None` if fewer than two
    /// sites have one.
    pub fn seed_map(&self, fit: &SampleFit, width: usize, height: usize) -> Option<Vec<f32>> {
        let n = self.sites.len();
        let finite: Vec<f32> = fit.thickness_nm[..n]
            .iter()
            .copied()
            .filter(|t| t.is_finite())
            .collect();
        if finite.len() < 2 {
            return None;
        }
        // A missing site takes the mean of the others.
        let mean = finite.iter().sum::<f32>() / finite.len() as f32;
        // The grid's distinct centre rows and columns, and each cell's site.
        let centres: Vec<(usize, usize)> = self.centres().collect();
        let mut rows: Vec<usize> = centres.iter().map(|c| c.0).collect();
        let mut cols: Vec<usize> = centres.iter().map(|c| c.1).collect();
        rows.sort_unstable();
        rows.dedup();
        cols.sort_unstable();
        cols.dedup();
        let mut cell = vec![mean; rows.len() * cols.len()];
        for (k, &(r, c)) in centres.iter().enumerate() {
            let (Ok(iy), Ok(ix)) = (rows.binary_search(&r), cols.binary_search(&c)) else {
                continue;
            };
            let t = fit.thickness_nm[k];
            if t.is_finite() {
                cell[iy * cols.len() + ix] = t;
            }
        }
        let bracket = |x: usize, pos: &[usize]| -> (usize, usize, f64) {
            match pos.iter().position(|&p| p >= x) {
                Some(0) | None if pos.len() == 1 => (0, 0, 0.0),
                Some(0) => (0, 0, 0.0),
                None => (pos.len() - 1, pos.len() - 1, 0.0),
                Some(i) => (
                    i - 1,
                    i,
                    (x - pos[i - 1]) as f64 / (pos[i] - pos[i - 1]) as f64,
                ),
            }
        };
        let at = |iy: usize, ix: usize| f64::from(cell[iy * cols.len() + ix]);
        let mut map = vec![f32::NAN; width * height];
        for y in 0..height {
            let (y0, y1, fy) = bracket(y, &rows);
            for x in 0..width {
                let (x0, x1, fx) = bracket(x, &cols);
                let top = at(y0, x0) * (1.0 - fx) + at(y0, x1) * fx;
                let bottom = at(y1, x0) * (1.0 - fx) + at(y1, x1) * fx;
                map[y * width + x] = (top * (1.0 - fy) + bottom * fy) as f32;
            }
        }
        Some(map)
    }
}

/// The fringes across the band of the median sampled film under the fit's index.
pub fn fringes_across_band(spec: &SweepSpec, fit: &SampleFit) -> f64 {
    let Some(c) = fit.best else {
        return f64::NAN;
    };
    let mut t: Vec<f32> = fit
        .thickness_nm
        .iter()
        .copied()
        .filter(|t| t.is_finite())
        .collect();
    if t.is_empty() {
        return f64::NAN;
    }
    t.sort_by(f32::total_cmp);
    let d = f64::from(t[t.len() / 2]);
    let b = &spec.bands_nm;
    let (lo, hi) = (b[0].min(b[b.len() - 1]), b[0].max(b[b.len() - 1]));
    let n = c.kind.dispersion(&c.params).index_at(550.0);
    2.0 * n * d * (1.0 / lo - 1.0 / hi)
}

/// The solver's model of the fit's index (the best candidate even when the fit failed).
pub fn index_model(fit: &SampleFit) -> Option<IndexModel> {
    let c = fit.best?;
    IndexModel::from_dispersion(c.kind.dispersion(&c.params))
}

/// How the index model was chosen, for `summary.json` `index_model_choice`: the fit's
/// evidence, the per-pixel passes' checks left for them to fill (`fit_seconds` none, no
/// search, no site disagreeing).
pub fn choice(fit: &SampleFit, tap: &SampleTap, passes: usize) -> FittedChoice {
    let candidates = fit
        .candidates
        .iter()
        .map(|c| Candidate {
            model: c.kind.name().to_owned(),
            parameters: c.kind.params(),
            chi2: finite(c.chi2),
            chi2_nu: finite(c.chi2_nu),
            score: finite(c.score),
            n_550: finite(c.kind.dispersion(&c.params).index_at(550.0)),
            n_550_sigma: finite(c.n550_sigma),
            physical: c.physical,
        })
        .collect();
    FittedChoice {
        index_source: "full spectra of a pixel sample".to_owned(),
        chosen: fit.best.map(|c| c.kind.name().to_owned()),
        failure: fit.failure.map(Failure::message).map(str::to_owned),
        chi2_nu: fit.best.and_then(|c| finite(c.chi2_nu)),
        n_550_sigma: fit.best.and_then(|c| finite(c.n550_sigma)),
        noise_sigma: finite(fit.noise_sigma),
        model_error: finite(fit.model_error),
        nuisance_terms: NuisanceTerms {
            film_k_450nm: term_record(fit.film_k),
            absorption_tail_nm: ABSORPTION_TAIL_NM,
            polariser_leak: term_record(fit.polariser_leak),
            stage_offset_deg: term_record(fit.stage_offset_deg),
            wavelength_shift_nm: term_record(fit.wavelength_shift_nm),
            flare: term_record(fit.flare),
            side_lobes: term_record(fit.side_lobes),
            side_lobe_width_fwhm: filmscope_core::solve::sample::SIDE_LOBE_WIDTH,
            reflectance_terms: fit
                .reflectance_terms
                .iter()
                .map(|&(scale, offset)| ReflectanceTerm {
                    scale: finite(scale),
                    offset: finite(offset),
                })
                .collect(),
        },
        residual: residual_record(fit),
        sites_set_aside: tap
            .centres()
            .zip(&fit.set_aside)
            .filter(|(_, &aside)| aside)
            .map(|((r, c), _)| [c, r])
            .collect(),
        sampled_sites: tap.sites.len(),
        sites_used: fit.sites_used,
        site_run_pixels: RUN,
        sample_bytes: tap.bytes(),
        searched: fit.searched,
        starts: fit.starts,
        passes,
        candidates,
        criterion: format!(
            "lowest chi2 + {MODEL_PENALTY} x parameters (a constant index counted as two, the Cauchy model with its slope held at zero, preferred unless the slope gains {CONSTANT_PREFERENCE}) among physical models (index inside the search range and falling with wavelength, a Sellmeier pole below the band), chi2 in units of the noise measured from each site's run of {RUN} pixels (per site, band and angle) plus the model error; a fit that misses the noise alone is fitted again with its misfit beyond the noise as the model error (sites fitting {OUTLIER_SITE_RATIO}x worse than the median set aside) and fails when that misfit exceeds the tolerated model error (model_error_tolerated) or its reduced chi-square exceeds {GATE_CHI2_NU}"
        ),
        model_error_tolerated: finite(fit.tolerated_model_error),
        rig_tolerance: RigTolerance {
            multiple: finite(fit.rig_tolerance),
            one_sigma: OneSigma {
                reflectance_scale: TOLERANCE.scale,
                reflectance_offset: TOLERANCE.offset,
                film_k_450nm: TOLERANCE.terms[0],
                polariser_leak: TOLERANCE.terms[1],
                stage_offset_deg: TOLERANCE.terms[2],
                wavelength_shift_nm: TOLERANCE.terms[3],
                flare: TOLERANCE.terms[4],
                side_lobes: TOLERANCE.terms[5],
            },
        },
        models: ModelKind::ALL.iter().map(|k| k.name().to_owned()).collect(),
        fit_seconds: None,
        pixels_searched: None,
        pixels_solved_by_search: None,
        sites_disagreeing: 0.0,
        per_pixel_failure: None,
    }
}

/// The correction the per-pixel passes applied, read back from `summary.json`'s
/// `index_model_choice.nuisance_terms` ([`choice`] writes it): the stage offset, the
/// wavelength shift, the flare, each angle's reflectance scale and offset, the film's
/// absorption and the polariser's leak. No terms, or null ones, are none; the side lobes,
/// which the passes do not take out, are not read.
pub fn correction_from(terms: Option<&NuisanceTerms>) -> crate::pipeline::Correction {
    let value = |t: Option<&Option<TermRecord>>| t.and_then(|t| t.as_ref()?.value).unwrap_or(0.0);
    crate::pipeline::Correction {
        angle_offset_deg: value(terms.map(|t| &t.stage_offset_deg)),
        band_shift_nm: value(terms.map(|t| &t.wavelength_shift_nm)),
        terms: terms
            .map(|t| {
                t.reflectance_terms
                    .iter()
                    .map(|t| {
                        let (s, o) = (t.scale, t.offset);
                        (s.unwrap_or(1.0) as f32, o.unwrap_or(0.0) as f32)
                    })
                    .collect()
            })
            .unwrap_or_default(),
        flare: value(terms.map(|t| &t.flare)) as f32,
        film: filmscope_core::solve::refine::FilmTerms {
            film_k: value(terms.map(|t| &t.film_k_450nm)),
            leak: value(terms.map(|t| &t.polariser_leak)),
        },
    }
}

/// A nuisance term as `summary.json` gives it: `{"value", "sigma"}`, none when not taken.
fn term_record(t: Term) -> Option<TermRecord> {
    t.taken().then(|| TermRecord {
        value: finite(t.value),
        sigma: finite(t.sigma),
    })
}

/// `summary.json`'s `index_model_choice.residual`: what the chosen fit leaves on the sampled
/// sites, its size against the noise and its shape, with a one-line reading.
fn residual_record(fit: &SampleFit) -> ResidualRecord {
    let r = &fit.residual;
    ResidualRecord {
        rms: finite(r.rms),
        noise_rms: finite(r.noise_rms),
        model_rms: finite(r.model_rms),
        band_correlation: finite(r.band_correlation),
        site_correlation: finite(r.site_correlation),
        blue_rms: finite(r.blue_rms),
        red_rms: finite(r.red_rms),
        per_angle: r
            .per_angle
            .iter()
            .map(|a| AngleResidualRecord {
                rms: finite(a.rms),
                mean: finite(a.mean),
                noise_rms: finite(a.noise_rms),
            })
            .collect(),
        shape: residual_shape(r),
    }
}

/// One line reading a fit's residual: noise, or a misfit and where it lies.
pub fn residual_shape(r: &Residual) -> String {
    if !r.rms.is_finite() {
        return "no fit".into();
    }
    if r.model_rms <= 0.5 * r.noise_rms {
        return format!(
            "within the noise (RMS {:.1e} against noise {:.1e})",
            r.rms, r.noise_rms
        );
    }
    let mut parts = vec![format!(
        "a misfit of {:.1e} beyond noise {:.1e}",
        r.model_rms, r.noise_rms
    )];
    parts.push(if r.band_correlation > 0.7 {
        format!(
            "smooth along the band (neighbour correlation {:.2})",
            r.band_correlation
        )
    } else {
        format!(
            "rough along the band (neighbour correlation {:.2})",
            r.band_correlation
        )
    });
    if r.blue_rms > 1.5 * r.red_rms {
        parts.push(format!(
            "{:.1}x larger in the blue third than the red",
            r.blue_rms / r.red_rms
        ));
    } else if r.red_rms > 1.5 * r.blue_rms {
        parts.push(format!(
            "{:.1}x larger in the red third than the blue",
            r.red_rms / r.blue_rms
        ));
    }
    let rms: Vec<f64> = r.per_angle.iter().map(|a| a.rms).collect();
    if let (Some(lo), Some(hi)) = (
        rms.iter().copied().reduce(f64::min),
        rms.iter().copied().reduce(f64::max),
    ) {
        if rms.len() > 1 && hi > 2.0 * lo {
            parts.push(format!("uneven over the angles (RMS {lo:.1e} to {hi:.1e})"));
        }
    }
    if let Some(a) = r
        .per_angle
        .iter()
        .max_by(|a, b| a.mean.abs().total_cmp(&b.mean.abs()))
    {
        if a.mean.abs() > 0.5 * r.model_rms {
            parts.push(format!("an offset of {:+.1e}", a.mean));
        }
    }
    parts.join(", ")
}
