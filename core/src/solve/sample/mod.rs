//! The shared film index from the full spectra of a bounded pixel sample.
//!
//! The index is a property of the film, not of a pixel, so it is fitted on a fixed sample of
//! sites spread over the image: every angle, every band of each site's centre pixel, with the
//! exact passbands, against one thickness per site. Each site also keeps its four row
//! neighbours (a run of [`RUN`] pixels), whose fourth difference across the run measures the
//! image's noise without any model (the film's thickness varies smoothly over five pixels).
//!
//! 1. **Global search** ([`fit_index`]): a grid over the index at 550 nm and a Cauchy slope,
//!    each point scored by the best thickness of each of [`SEARCH_SITES`] sites (a dictionary
//!    over the thickness range, then two Gauss-Newton steps) on a subset of bands. Films with
//!    more than three fringes across the band are searched again on the band's red half, where
//!    two parameters follow every material's dispersion closely, so the fringe order is not
//!    lost to a model too simple for the blue end.
//! 2. **Joint least squares** (Levenberg-Marquardt) over all sites, angles and bands: the
//!    index parameters and one thickness a site, the normal equations reduced to the index
//!    parameters (Schur complement; [`nalgebra`] for the small dense solve), for each model of
//!    [`ModelKind`].
//! 3. **Model choice by evidence**: the lowest `chi2 + MODEL_PENALTY x parameters`, chi-square
//!    in units of each sample's noise (per site, band and angle, from the runs).
//! 4. **Judged against what a measurement can promise**: a fit whose reduced chi-square stays
//!    above [`GATE_CHI2_NU`] after its starts sets aside the sites that fit far worse than
//!    the rest, lets in the nuisance terms the evidence pays for (film absorption, a
//!    polariser's leak, stage offset, wavelength shift, flare, side lobes, each angle's
//!    reflectance scale and offset; BIC), takes the misfit still beyond the noise as the
//!    model's error and is fitted again in those units. It is reported as failed (no index
//!    rather than a confident wrong one) when that misfit exceeds the tolerated
//!    [`Geometry::model_error`]. The index's sigma reported is marginal over every term,
//!    each within a real rig's [`TOLERANCE`], and widened by the misfit's correlation along
//!    the band and across the sites.
//!
//! Everything works on caller-owned buffers ([`workspace_len`]): nothing allocates.

use nalgebra::{Matrix3, Vector3};

#[cfg(doc)]
use super::refine::passband_rule;
use super::refine::MAX_BAND_NODES;
use super::IndexModel;
use crate::optics::{BackFace, Dispersion, FilmAtAngle, LossyFilm, Polarization};

mod choice;
mod lsq;
mod marginal;
mod model;
mod noise;
mod residual;
mod search;
mod seat;

pub use marginal::{Tolerance, TERM_MAX_ANGLES, TOLERANCE};
use noise::{measure_noise, Noise};
pub use residual::{AngleResidual, Residual, RESIDUAL_ANGLES};
use seat::complete_sites;
pub use seat::{seat_pixels, Seat};

/// Pixels a site keeps: its centre and two neighbours each side along the row.
pub const RUN: usize = 5;
/// The centre pixel of a site's run.
pub const CENTRE: usize = RUN / 2;
/// Most sites a sample holds.
pub const MAX_SITES: usize = 256;
/// Sites the global search scores each grid point with.
pub const SEARCH_SITES: usize = 24;
/// Bands the global search uses at most (an even subset of the band).
pub const SEARCH_BANDS: usize = 96;
/// Bands a site's thickness is seated on at most (the dictionary under a known model): four
/// or more a fringe for films of up to 15 fringes across the band.
pub const SEAT_BANDS: usize = 128;
/// Most angles the search and the seating use (the first ones).
const SEARCH_ANGLES: usize = 16;
/// Most thicknesses of the search's dictionary.
pub const MAX_DICTIONARY: usize = 1024;
/// Chi-square (in units of the noise) an index parameter must buy to enter the model (a
/// 5-sigma gain).
pub const MODEL_PENALTY: f64 = 25.0;
/// A reduced chi-square above this after the search means the fit failed (correct fits
/// measure about 0.9-1.1; wrong minima and wrong metadata 1.2 and up).
pub const GATE_CHI2_NU: f64 = 1.5;
/// An index whose standard error at 550 nm exceeds this is reported as under-determined.
pub const MAX_INDEX_SIGMA: f64 = 0.01;
/// The largest standard error of the index at 550 nm, the misfit common to the sites
/// included ([`Residual::shared_factor`]), with which an index is still given: beyond it a
/// systematic misfit (a thin film's level traded with a rig's stray light) may pull the
/// index further than the sites' own precision says.
pub const MAX_INDEX_ACCURACY: f64 = 0.02;
/// A model whose refined fit leaves a reduced chi-square above this has its sites seated
/// again under it and is refined once more.
pub const RESEAT_CHI2_NU: f64 = 1.2;
/// Chi-square a dispersion slope must gain over a constant index (two sigma) to be
/// preferred, the two otherwise costing the same ([`MODEL_PENALTY`] x 2).
pub const CONSTANT_PREFERENCE: f64 = 4.0;
/// Most bands the fit takes.
pub const MAX_BANDS: usize = 1024;
/// Most Levenberg-Marquardt steps of a refinement.
const MAX_STEPS: usize = 40;
/// Refinement steps at each value of a nuisance term's grid.
const GRID_STEPS: usize = 6;
/// Most starts the refinement tries before it reports a failed fit.
pub const MAX_STARTS: usize = 3;
/// Fringes across the band above which the search is repeated on the band's red half.
pub const THICK_FRINGES: f64 = 3.0;

/// Most quadrature nodes of a band's passband in the fit: the per-pixel model's rule
/// ([`passband_rule`]), for the thickest site.
const NODES: usize = MAX_BAND_NODES;
/// Least noise a site is given, in reflectance: the model's own error (passband quadrature,
/// float rounding) stands in for the noise of a noise-free capture, which would otherwise
/// fail the gate on that error alone. A 16-bit sensor's rounding is 4e-6, real captures'
/// noise 1e-3 and more.
pub const NOISE_FLOOR: f64 = 1e-4;
/// The model error tolerated by default, RMS reflectance: what a single-layer model with
/// its nuisance terms leaves on a real film and rig (slight absorption, inhomogeneity, the
/// filter's side lobes, flare, calibration errors): 1e-3 to 2e-3 on a measured HfO2 film on
/// fused silica and on the realistic evaluation's captures; gross misfits (wrong angles,
/// polarisation or substrate) leave 1e-2 and more.
pub const DEFAULT_MODEL_ERROR: f64 = 3e-3;
/// A site whose reduced chi-square exceeds this many times the sites' median is set aside
/// when the fit misses the gate (a defect, a scratch, a particle under it).
pub const OUTLIER_SITE_RATIO: f64 = 5.0;
/// Fewest angles, and their smallest span (degrees), for each angle's reflectance scale and
/// offset to be told apart from the index: with fewer, the fringes' positions across angles
/// cannot pin the index once the reflectance level is free.
pub const TERM_ANGLES: usize = 3;
/// See [`TERM_ANGLES`].
pub const TERM_SPAN_DEG: f64 = 20.0;
/// Rounds of the terms and the index fitted by turns.
const TERM_ROUNDS: usize = 4;
/// The range a reflectance scale may take: a white standard's few per cent, side lobes'
/// loss of the main band's share (wider, and the index's reflectance level trades with it).
pub const TERM_SCALE: [f64; 2] = [0.95, 1.05];
/// The range a reflectance offset may take: flare and side lobes only add light.
pub const TERM_OFFSET: [f64; 2] = [0.0, 0.02];
/// How much wider than a band's FWHM the band its side lobes pass light from is: a
/// Gaussian of this many FWHM, truncated at 1.5 of its own FWHM either side.
pub const SIDE_LOBE_WIDTH: f64 = 10.0;

/// Most angles the noise model tells apart (more share the last one's factor).
pub const NOISE_ANGLES: usize = 256;
/// Index step of the numerical `dR/dn`.
const INDEX_STEP: f64 = 1e-5;
/// Wavelength (um) at which the models' index is quoted and searched.
const L0_UM: f64 = 0.55;

/// The index models the sample is fitted with, simplest first.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelKind {
    /// `n` constant.
    Constant,
    /// `n = a + b / l^2` (l in um).
    Cauchy2,
    /// One-pole Sellmeier `n^2 = 1 + S l^2 / (l^2 - L^2)`.
    Sellmeier1,
    /// `n = a + b / l^2 + c / l^4`.
    Cauchy3,
    /// One-pole Sellmeier with a constant, `n^2 = A + S l^2 / (l^2 - L^2)`.
    Sellmeier1c,
}

impl ModelKind {
    /// Every model, simplest first.
    pub const ALL: [ModelKind; 5] = [
        Self::Constant,
        Self::Cauchy2,
        Self::Sellmeier1,
        Self::Cauchy3,
        Self::Sellmeier1c,
    ];

    /// Free parameters.
    pub fn params(self) -> usize {
        match self {
            Self::Constant => 1,
            Self::Cauchy2 | Self::Sellmeier1 => 2,
            Self::Cauchy3 | Self::Sellmeier1c => 3,
        }
    }

    /// The name reports use.
    pub fn name(self) -> &'static str {
        match self {
            Self::Constant => "constant",
            Self::Cauchy2 => "cauchy",
            Self::Sellmeier1 => "sellmeier",
            Self::Cauchy3 => "cauchy3",
            Self::Sellmeier1c => "sellmeier_constant",
        }
    }

    /// The model with parameters `p` (Cauchy: `a`, `b` um^2, `c` um^4; Sellmeier: `S`,
    /// `L^2` um^2, then `A`).
    pub fn dispersion(self, p: &[f64; 3]) -> Dispersion {
        match self {
            Self::Constant => Dispersion::constant(p[0]),
            Self::Cauchy2 => Dispersion::cauchy(p[0], p[1]),
            Self::Cauchy3 => Dispersion::Cauchy {
                a: p[0],
                b_um2: p[1],
                c_um4: p[2],
            },
            Self::Sellmeier1 | Self::Sellmeier1c => Dispersion::Sellmeier {
                a: if self == Self::Sellmeier1 { 1.0 } else { p[2] },
                b: [p[0], 0.0, 0.0],
                c_um: [libm::sqrt(p[1].max(0.0)), 0.0, 0.0],
            },
        }
    }

    /// The model and parameters holding the solver's model `m`: [`ModelKind::dispersion`]
    /// gives `m`'s dispersion back.
    pub fn of_index(m: &IndexModel) -> (Self, [f64; 3]) {
        match m.pole {
            Some(p) if p.a == 1.0 => (Self::Sellmeier1, [p.s, p.l_um * p.l_um, 0.0]),
            Some(p) => (Self::Sellmeier1c, [p.s, p.l_um * p.l_um, p.a]),
            None if m.c_um4 != 0.0 => (Self::Cauchy3, [m.a, m.b_um2, m.c_um4]),
            None if m.b_um2 != 0.0 => (Self::Cauchy2, [m.a, m.b_um2, 0.0]),
            None => (Self::Constant, [m.a, 0.0, 0.0]),
        }
    }

    /// The index at `l_um` and its derivatives by each parameter.
    fn eval(self, p: &[f64; 3], l_um: f64) -> (f64, [f64; 3]) {
        let l2 = l_um * l_um;
        match self {
            Self::Constant => (p[0], [1.0, 0.0, 0.0]),
            Self::Cauchy2 => (p[0] + p[1] / l2, [1.0, 1.0 / l2, 0.0]),
            Self::Cauchy3 => (
                p[0] + p[1] / l2 + p[2] / (l2 * l2),
                [1.0, 1.0 / l2, 1.0 / (l2 * l2)],
            ),
            Self::Sellmeier1 | Self::Sellmeier1c => {
                let a = if self == Self::Sellmeier1 { 1.0 } else { p[2] };
                let den = l2 - p[1];
                let f = l2 / den;
                let n2 = a + p[0] * f;
                if !(n2 > 0.0 && den > 0.0) {
                    return (f64::NAN, [0.0; 3]);
                }
                let n = libm::sqrt(n2);
                let h = 0.5 / n;
                let da = if self == Self::Sellmeier1 { 0.0 } else { h };
                (n, [h * f, h * p[0] * l2 / (den * den), da])
            }
        }
    }

    /// Whether `p` is a physical model over `[lo_nm, hi_nm]`: the index at 550 nm inside
    /// `range`, above 1 and falling with wavelength (normal dispersion) across the band, a
    /// Sellmeier pole below the band, and no steeper than a transparent material can be
    /// ([`STEEPEST_POLE`]).
    fn physical(self, p: &[f64; 3], lo_nm: f64, hi_nm: f64, range: [f64; 2]) -> bool {
        if let Self::Sellmeier1 | Self::Sellmeier1c = self {
            let l_lo = lo_nm * 1e-3;
            if !(p[0] > 0.0 && p[1] >= 0.0 && p[1] < 0.8 * l_lo * l_lo) {
                return false;
            }
            if self == Self::Sellmeier1c && !(0.5..=range[1] * range[1]).contains(&p[2]) {
                return false;
            }
        }
        let n550 = self.eval(p, L0_UM).0;
        if !(n550 >= range[0] && n550 <= range[1]) {
            return false;
        }
        let mut last = f64::INFINITY;
        for i in 0..=16 {
            let l = lo_nm + (hi_nm - lo_nm) * f64::from(i) / 16.0;
            let n = self.eval(p, l * 1e-3).0;
            if n.is_nan() || n <= 1.0 || n > last + 1e-9 {
                return false;
            }
            last = n;
        }
        // `n^2 - 1` grows towards the blue no faster than a single oscillator's at
        // STEEPEST_POLE x the band's bluest wavelength: (1/l0^2 - 1/l^2) / (1/l0^2 - 1/lo^2)
        // between the band's ends, which any sum of oscillators further out keeps.
        let (lo, hi) = (lo_nm * 1e-3, hi_nm * 1e-3);
        let x0 = 1.0 / (STEEPEST_POLE * STEEPEST_POLE * lo * lo);
        let steepest = (x0 - 1.0 / (hi * hi)) / (x0 - 1.0 / (lo * lo));
        let (n_lo, n_hi) = (self.eval(p, lo).0, self.eval(p, hi).0);
        n_lo * n_lo - 1.0 <= steepest * (n_hi * n_hi - 1.0)
    }
}

/// The nearest a film's absorption may sit to its band, as a fraction of the band's bluest
/// wavelength: a material transparent across the band has its oscillators (the poles of its
/// Sellmeier form) below this, which bounds how steeply its index may rise to the blue
/// ([`ModelKind::physical`]). At 0.8 (320 nm for a band from 400 nm) it leaves room for
/// rutile TiO2 (pole 283 nm, over a large background) and refuses the dispersion a wrong
/// thickness makes up (an index from 2.5 to 1.6 across the visible).
pub const STEEPEST_POLE: f64 = 0.8;

/// The sweep's geometry and optics as the sample fit needs them.
#[derive(Clone, Copy, Debug)]
pub struct Geometry<'a> {
    /// Band centres, nm.
    pub bands_nm: &'a [f64],
    /// Band FWHM, nm (one per band).
    pub fwhm_nm: &'a [f64],
    /// Incidence angles of the angles held so far, degrees, in streaming order.
    pub angles_deg: &'a [f64],
    /// Ambient index.
    pub ambient_index: f64,
    /// The substrate's index against wavelength.
    pub substrate: Dispersion,
    /// The substrate's back face.
    pub back_face: BackFace,
    /// Polarisation of the measured light.
    pub polarization: Polarization,
    /// Film index search range.
    pub index_range: [f64; 2],
    /// Thickness search range, nm.
    pub thickness_range_nm: [f64; 2],
    /// The model error tolerated, RMS reflectance: a fit that misses the spectra by more
    /// than their noise passes the gate when its misfit beyond the noise is within this
    /// ([`DEFAULT_MODEL_ERROR`]; 0: judged against the noise alone).
    pub model_error: f64,
    /// The [`TOLERANCE`]'s multiple the reported index sigma carries (1; 0: the statistical
    /// sigma under the terms the fit took).
    pub rig_tolerance: f64,
}

/// The sampled spectra: site `k`, run pixel `j`, angle `a`, band `b` at
/// `((k * RUN + j) * angle_stride + a) * bands + b` (NaN: no usable value).
#[derive(Clone, Copy, Debug)]
pub struct Spectra<'a> {
    /// The values.
    pub values: &'a [f32],
    /// Sites.
    pub sites: usize,
    /// Angles the buffer has room for (the fit reads the first `angles_deg.len()`).
    pub angle_stride: usize,
    /// Pixels per site: [`RUN`] for the index fit (its noise comes from the run), 1 for
    /// [`seat_pixels`].
    pub run: usize,
}

impl Spectra<'_> {
    #[inline]
    fn at(&self, bands: usize, k: usize, j: usize, a: usize, b: usize) -> f32 {
        self.values[((k * self.run + j) * self.angle_stride + a) * bands + b]
    }

    /// Site `k`'s own pixel (its run's centre).
    #[inline]
    fn centre_at(&self, bands: usize, k: usize, a: usize, b: usize) -> f32 {
        self.at(bands, k, self.run / 2, a, b)
    }
}

/// One model's fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// The model.
    pub kind: ModelKind,
    /// Its parameters ([`ModelKind::dispersion`]).
    pub params: [f64; 3],
    /// Chi-square in units of the noise.
    pub chi2: f64,
    /// Reduced chi-square.
    pub chi2_nu: f64,
    /// `chi2 + MODEL_PENALTY x parameters`.
    pub score: f64,
    /// Standard error of the index at 550 nm.
    pub n550_sigma: f64,
    /// Whether the model is physical over the band (only physical models are chosen).
    pub physical: bool,
}

/// Why the sample gave no index.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Failure {
    /// Fewer than two angles, or too few usable sites.
    TooLittleData,
    /// No model fits the spectra within the noise, even from a second start.
    NoFit,
    /// The index is under-determined (its standard error exceeds [`MAX_INDEX_SIGMA`], or
    /// [`MAX_INDEX_ACCURACY`] with the common misfit's share).
    Underdetermined,
    /// The given index ([`hold_index`]) does not fit the spectra within the noise.
    GivenIndexMisfit,
}

impl Failure {
    /// One line for reports.
    pub fn message(self) -> &'static str {
        match self {
            Self::TooLittleData => "too few usable sampled pixels or angles to fit an index",
            Self::NoFit => "no index model fits the sampled spectra within their noise and the tolerated model error ([fit] model_error): wrong metadata (angles, polarisation, substrate, back face), an undeclared bare back face or a second layer, or a film the single-layer model cannot describe",
            Self::Underdetermined => "the sampled spectra do not determine the index (its standard error at 550 nm exceeds 0.01, or 0.02 with the model's misfit common to the sites): a film too thin or too close to its substrate's index, or a misfit the single-layer model trades with the index",
            Self::GivenIndexMisfit => "the given film index does not fit the sampled spectra within their noise and the tolerated model error: not this film's index (fit it instead: leave out --film-index), or wrong metadata (angles, polarisation, substrate)",
        }
    }
}

/// A warm start of the fit: the last fit's model and parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Start {
    /// The model.
    pub kind: ModelKind,
    /// Its parameters ([`ModelKind::dispersion`]).
    pub params: [f64; 3],
    /// Whether every model is refitted and chosen again (else only this one is refined,
    /// and kept if it passes the gate: the fast refit a live sweep's last angle takes).
    pub reselect: bool,
    /// The same sites' thicknesses, nm, when the start is the same sample's fit on fewer
    /// angles (a site without one, NaN, sends every site through the thickness search).
    pub thickness_nm: Option<[f32; MAX_SITES]>,
}

/// What the sample fit found.
#[derive(Clone, Debug)]
pub struct SampleFit {
    /// The chosen model's fit (the best even when [`SampleFit::failure`] is set).
    pub best: Option<Candidate>,
    /// Every model tried.
    pub candidates: heapless::Vec<Candidate, 5>,
    /// Why the fit is not to be trusted, if it is not.
    pub failure: Option<Failure>,
    /// The image's noise (reflectance), from the runs' fourth differences.
    pub noise_sigma: f64,
    /// Each site's thickness under the chosen model, nm (NaN: site not used).
    pub thickness_nm: [f32; MAX_SITES],
    /// Sites used.
    pub sites_used: usize,
    /// Starts the refinement needed (1, or 2 when the first failed the gate).
    pub starts: usize,
    /// Whether the global search ran (no warm start, or the warm start failed the gate).
    pub searched: bool,
    /// What the chosen fit leaves: its size and shape across bands and angles.
    pub residual: Residual,
    /// The model error the fit was weighed with, RMS reflectance: 0 when the spectra fit
    /// within their noise, else the misfit beyond it (`residual.model_rms` of the fit under
    /// the noise alone), added to every sample's noise variance.
    pub model_error: f64,
    /// Sites set aside because they fit far worse than the rest ([`OUTLIER_SITE_RATIO`]).
    pub set_aside: [bool; MAX_SITES],
    /// The model error tolerated ([`Geometry::model_error`]).
    pub tolerated_model_error: f64,
    /// The [`TOLERANCE`]'s multiple the index sigma carries ([`Geometry::rig_tolerance`]).
    pub rig_tolerance: f64,
    /// The part of a thickness's standard error common to the whole map, relative to the
    /// thickness: what the index and every nuisance term within its tolerance leave the
    /// sites' thicknesses free to move together (the median site's), carried to the pixels
    /// in proportion to their thickness. NaN where not computed (the rig's tolerance 0, an
    /// index held or not fitted).
    pub thickness_share: f64,
    /// Each angle's reflectance `(scale, offset)` when the evidence asked for them
    /// (`measured = scale x film + offset`: a white standard's error, flare, the filter's side
    /// lobes), in streaming order; empty when not fitted.
    pub reflectance_terms: heapless::Vec<(f64, f64), RESIDUAL_ANGLES>,
    /// The film's extinction coefficient at 450 nm when the evidence asked for it (0: a
    /// transparent film), its tail to the blue [`ABSORPTION_TAIL_NM`].
    pub film_k: Term,
    /// The share of the other polarisation a leaking polariser lets through, when the
    /// evidence asked for it (0: none).
    pub polariser_leak: Term,
    /// The stage's angle offset, degrees (added to every angle), when the evidence asked for
    /// it (0: none).
    pub stage_offset_deg: Term,
    /// The filter's wavelength calibration shift, nm (added to every band's centre), when the
    /// evidence asked for it (0: none).
    pub wavelength_shift_nm: Term,
    /// Flare: one reflectance offset at every angle and band (stray light), when the evidence
    /// asked for it (0: none); each angle's own offset in
    /// [`SampleFit::reflectance_terms`] comes on top.
    pub flare: Term,
    /// The share of the light the filter's side lobes pass from a band
    /// [`SIDE_LOBE_WIDTH`] times wider, when the evidence asked for it (0: none).
    pub side_lobes: Term,
}

/// A nuisance term's value and its 1-sigma (from the chi-square's curvature over the term,
/// the index and thicknesses refitted at each value); both 0 when the term was not taken.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Term {
    /// The value.
    pub value: f64,
    /// Its 1-sigma (NaN when the curvature could not be measured).
    pub sigma: f64,
}

impl Term {
    /// Not taken.
    pub const NONE: Self = Self {
        value: 0.0,
        sigma: 0.0,
    };

    /// Whether the evidence asked for the term.
    pub fn taken(self) -> bool {
        self.value != 0.0
    }
}

impl SampleFit {
    /// No fit yet: too little data until the sites are weighed.
    const EMPTY: Self = Self {
        best: None,
        candidates: heapless::Vec::new(),
        failure: Some(Failure::TooLittleData),
        noise_sigma: f64::NAN,
        thickness_nm: [f32::NAN; MAX_SITES],
        sites_used: 0,
        starts: 0,
        searched: false,
        residual: Residual {
            rms: f64::NAN,
            noise_rms: f64::NAN,
            model_rms: f64::NAN,
            band_correlation: f64::NAN,
            site_correlation: f64::NAN,
            blue_rms: f64::NAN,
            red_rms: f64::NAN,
            per_angle: heapless::Vec::new(),
        },
        model_error: 0.0,
        set_aside: [false; MAX_SITES],
        tolerated_model_error: f64::NAN,
        rig_tolerance: f64::NAN,
        thickness_share: f64::NAN,
        reflectance_terms: heapless::Vec::new(),
        film_k: Term::NONE,
        polariser_leak: Term::NONE,
        stage_offset_deg: Term::NONE,
        wavelength_shift_nm: Term::NONE,
        flare: Term::NONE,
        side_lobes: Term::NONE,
    };

    /// What the fit found beyond the index, for pixels seated under it ([`seat_pixels`]).
    pub fn nuisance(&self) -> Nuisance {
        Nuisance {
            film_k: self.film_k.value,
            leak: self.polariser_leak.value,
            stage_deg: self.stage_offset_deg.value,
            shift_nm: self.wavelength_shift_nm.value,
            flare: self.flare.value,
            side_lobes: self.side_lobes.value,
            terms: self.reflectance_terms.clone(),
        }
    }

    /// The chosen index model, unless the fit failed.
    pub fn index(&self) -> Option<Dispersion> {
        match (self.failure, self.best) {
            (None, Some(c)) => Some(c.kind.dispersion(&c.params)),
            _ => None,
        }
    }
}

/// `f32` values of workspace [`fit_index`] needs for `sites` sites, `angles` angles and
/// `bands` bands.
pub fn workspace_len(sites: usize, angles: usize, bands: usize) -> usize {
    let noise = sites.min(MAX_SITES) * angles * bands;
    // Two dictionaries: the search scores its grid in two halves.
    let dictionary = 2 * MAX_DICTIONARY * angles.min(SEARCH_ANGLES) * SEAT_BANDS.min(bands);
    // And the sites' spectra over the side lobes' band ([`Problem::wide`]).
    noise.max(dictionary) + noise
}

/// Whether a `width x height` image's runs go down its columns (an image narrower than a
/// run, such as a strip of columns) rather than along its rows.
pub fn runs_along_columns(width: usize, height: usize) -> bool {
    width < RUN && height >= RUN
}

/// Pixel `j` of the run that starts at `(row, col)`: along the row, or down the column
/// ([`runs_along_columns`]).
pub fn run_pixel(row: usize, col: usize, j: usize, along_columns: bool) -> (usize, usize) {
    if along_columns {
        (row + j, col)
    } else {
        (row, col + j)
    }
}

/// Sites of a `width x height` image for a sample of about `sites`: a rectilinear grid with
/// the image's aspect, each site the `(row, column)` of its run's first pixel, runs inside
/// the image (along rows, or down columns, [`runs_along_columns`]). Fewer when the image is
/// too small.
pub fn site_grid(
    width: usize,
    height: usize,
    sites: usize,
) -> heapless::Vec<(u32, u32), MAX_SITES> {
    if runs_along_columns(width, height) {
        return along_rows(height, width, sites)
            .into_iter()
            .map(|(r, c)| (c, r))
            .collect();
    }
    along_rows(width, height, sites)
}

/// [`site_grid`] with runs along the rows.
fn along_rows(width: usize, height: usize, sites: usize) -> heapless::Vec<(u32, u32), MAX_SITES> {
    let mut out = heapless::Vec::new();
    if width < RUN || height == 0 || sites == 0 {
        return out;
    }
    let sites = sites.min(MAX_SITES);
    let aspect = width as f64 / height as f64;
    let mut gy = (libm::round(libm::sqrt(sites as f64 / aspect)) as usize).clamp(1, height);
    let mut gx = (sites / gy).clamp(1, width / RUN);
    while gx * gy > sites && gy > 1 {
        gy -= 1;
    }
    gx = gx.min(sites / gy).max(1);
    for iy in 0..gy {
        let row = ((2 * iy + 1) * height / (2 * gy)).min(height - 1);
        for ix in 0..gx {
            let centre = (2 * ix + 1) * width / (2 * gx);
            let first = centre.saturating_sub(CENTRE).min(width - RUN);
            let _ = out.push((row as u32, first as u32));
        }
    }
    out
}

/// Fits the shared index model to the sampled spectra. `start` warm-starts the refinement
/// (the last fit, or the last sweep's on a line); the global search runs when there is none
/// or it fails the gate. `scratch` holds at least [`workspace_len`] values; `par` runs the
/// halves of the refinement's sums.
pub fn fit_index(
    geo: &Geometry<'_>,
    spectra: &Spectra<'_>,
    start: Option<Start>,
    scratch: &mut [f32],
    par: &dyn Parallel,
) -> SampleFit {
    on_weighed_sites(geo, spectra, scratch, par, |problem, fit, scratch| {
        fit_weighed(problem, fit, start, scratch)
    })
}

/// [`fit_index`] once the sites are weighed.
fn fit_weighed(
    problem: &Problem<'_>,
    mut fit: SampleFit,
    start: Option<Start>,
    scratch: &mut [f32],
) -> SampleFit {
    let (geo, usable, sites) = (problem.geo, problem.usable, problem.usable.len());
    // Warm start first: refine and keep if it passes the gate.
    let mut thick = [f64::NAN; MAX_SITES];
    if let Some(Start {
        kind,
        params: p,
        reselect,
        thickness_nm,
    }) = start
    {
        let carried = thickness_nm.is_some_and(|t| {
            (0..sites)
                .filter(|&k| usable[k])
                .all(|k| t[k].is_finite() && t[k] > 0.0)
        });
        if let (true, Some(t)) = (carried, thickness_nm) {
            for (d, &c) in thick.iter_mut().zip(&t) {
                *d = f64::from(c);
            }
        }
        if carried
            || problem
                .start_thicknesses(kind, &p, &mut thick, scratch)
                .is_some()
        {
            let mut refined = thick;
            // Carried over from fewer angles, the fit is a step from its optimum.
            let steps = if carried && !reselect { 1 } else { MAX_STEPS };
            if let Some(cand) = problem.refine(kind, p, &mut refined, steps) {
                if cand.chi2_nu <= GATE_CHI2_NU {
                    fit.starts = 1;
                    if !reselect {
                        let _ = fit.candidates.push(cand);
                        return problem.settle(fit, cand, &refined);
                    }
                    return problem.choose(fit, cand, &refined, scratch);
                }
            }
        }
    }
    fit.searched = true;
    // Global search on the full band, then (thick films) on the red half.
    let mut starts: heapless::Vec<[f64; 3], 6> = heapless::Vec::new();
    if let Some((found, fringes)) = problem.search(geo.bands_nm.len(), 0, scratch) {
        let mut red = None;
        if fringes > THICK_FRINGES {
            let mid = geo.bands_nm.len() / 2;
            red = problem
                .search(geo.bands_nm.len(), mid, scratch)
                .map(|r| r.0);
        }
        // Interleaved, best of each search first.
        for i in 0..3 {
            for list in [Some(&found), red.as_ref()].into_iter().flatten() {
                if let Some(&(_, p)) = list.get(i) {
                    let _ = starts.push(p);
                }
            }
        }
    }
    // Each start refined as a two-term Cauchy model; the models chosen from the best, and
    // from the next while the choice fails the gate.
    let mut bases: heapless::Vec<(Candidate, [f64; MAX_SITES]), 6> = heapless::Vec::new();
    for p in &starts {
        let mut t = [f64::NAN; MAX_SITES];
        if problem
            .start_thicknesses(ModelKind::Cauchy2, p, &mut t, scratch)
            .is_none()
        {
            continue;
        }
        if let Some(c) = problem.refine(ModelKind::Cauchy2, *p, &mut t, MAX_STEPS) {
            let _ = bases.push((c, t));
        }
    }
    bases.sort_unstable_by(|a, b| a.0.chi2.total_cmp(&b.0.chi2));
    let mut result: Option<SampleFit> = None;
    for (c, t) in bases.iter().take(MAX_STARTS) {
        fit.starts += 1;
        let tried = problem.choose(fit.clone(), *c, t, scratch);
        let better = match (&result, tried.best) {
            (None, _) => true,
            (Some(r), Some(b)) => r.best.is_none_or(|rb| b.score < rb.score),
            (Some(_), None) => false,
        };
        let passed = tried.failure.is_none();
        if better {
            result = Some(tried);
        }
        if passed {
            break;
        }
    }
    match result {
        Some(mut r) => {
            r.starts = fit.starts;
            problem.with_model_error(r, None, scratch)
        }
        None => {
            fit.failure = Some(Failure::NoFit);
            fit
        }
    }
}

/// Weighs the sites of `spectra` (the noise of each sample and the usable sites) and hands their [`Problem`] and the fit so far (its noise and
/// sites used set) to `body`; a fit failed with [`Failure::TooLittleData`] when there is
/// too little to fit.
fn on_weighed_sites(
    geo: &Geometry<'_>,
    spectra: &Spectra<'_>,
    scratch: &mut [f32],
    par: &dyn Parallel,
    body: impl FnOnce(&Problem<'_>, SampleFit, &mut [f32]) -> SampleFit,
) -> SampleFit {
    let mut fit = SampleFit::EMPTY;
    fit.tolerated_model_error = geo.model_error;
    fit.rig_tolerance = geo.rig_tolerance;
    let (na, nb) = (geo.angles_deg.len(), geo.bands_nm.len());
    let sites = spectra.sites.min(MAX_SITES);
    if na < 1
        || !(8..=MAX_BANDS).contains(&nb)
        || sites == 0
        || scratch.len() < workspace_len(sites, na, nb)
    {
        return fit;
    }
    let (noise, median_sigma) = measure_noise(geo, spectra, scratch);
    fit.noise_sigma = median_sigma;
    let mut usable = complete_sites(spectra, sites, na, nb);
    for (k, u) in usable.iter_mut().enumerate().take(sites) {
        *u &= noise.site[k] > 0.0 && noise.site[k].is_finite();
    }
    fit.sites_used = usable.iter().filter(|&&u| u).count();
    if fit.sites_used < 2 {
        return fit;
    }
    let problem = Problem {
        geo,
        spectra,
        usable: &usable[..sites],
        noise,
        terms: Terms::NONE,
        retry: false,
        film_k: 0.0,
        leak: 0.0,
        stage_deg: 0.0,
        shift_nm: 0.0,
        flare: 0.0,
        side_lobes: 0.0,
        wide: &[],
        par,
    };
    body(&problem, fit, scratch)
}

/// The sample's fit with the index given rather than fitted (`estimate --film-index`): each
/// usable site seated under `(kind, params)` as [`seat_pixels`] seats a pixel, weighed by
/// its own noise; the candidate's chi-square is theirs, its `n550_sigma` zero (the index is
/// held). A reduced chi-square above [`GATE_CHI2_NU`] fails it, as it fails a fitted
/// index: thicknesses under an index that does not fit are wrong. The sites' thicknesses
/// seed and check the per-pixel pass as a fitted index's do.
pub fn hold_index(
    geo: &Geometry<'_>,
    spectra: &Spectra<'_>,
    kind: ModelKind,
    params: [f64; 3],
    scratch: &mut [f32],
    par: &dyn Parallel,
) -> SampleFit {
    on_weighed_sites(geo, spectra, scratch, par, |problem, fit, scratch| {
        hold_weighed(problem, fit, kind, params, scratch)
    })
}

/// [`hold_index`] once the sites are weighed.
fn hold_weighed(
    problem: &Problem<'_>,
    mut fit: SampleFit,
    kind: ModelKind,
    params: [f64; 3],
    scratch: &mut [f32],
) -> SampleFit {
    let Some((t, sums, _)) = problem.seat(kind, &params, scratch) else {
        fit.failure = Some(Failure::NoFit);
        return fit;
    };
    let (mut chi2, mut n) = (0.0, 0usize);
    for (s, _) in sums.iter().zip(problem.usable).filter(|(_, &u)| u) {
        chi2 += s.sse;
        n += s.n;
    }
    let chi2_nu = chi2 / n.saturating_sub(fit.sites_used).max(1) as f64;
    let (lo, hi) = problem.band_span();
    let c = Candidate {
        kind,
        params,
        chi2,
        chi2_nu,
        score: chi2,
        n550_sigma: 0.0,
        physical: kind.physical(&params, lo, hi, problem.geo.index_range),
    };
    let _ = fit.candidates.push(c);
    fit.starts = 1;
    let fit = problem.settle(fit, c, &t);
    let mut fit = problem.with_model_error(fit, Some((kind, params)), scratch);
    // The gate failed: the given index does not fit (it is not under-determined: held).
    if fit.failure.is_some() {
        fit.failure = Some(Failure::GivenIndexMisfit);
    }
    fit
}

/// A [`SampleFit`]'s nuisance terms ([`SampleFit::nuisance`]): the model and data of every
/// pixel are what the sample's were.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Nuisance {
    /// The film's extinction coefficient at 450 nm ([`SampleFit::film_k`]).
    pub film_k: f64,
    /// The polariser's leak ([`SampleFit::polariser_leak`]).
    pub leak: f64,
    /// The stage's angle offset, degrees ([`SampleFit::stage_offset_deg`]).
    pub stage_deg: f64,
    /// The wavelength shift, nm ([`SampleFit::wavelength_shift_nm`]).
    pub shift_nm: f64,
    /// Flare ([`SampleFit::flare`]).
    pub flare: f64,
    /// The filter's side lobes ([`SampleFit::side_lobes`]).
    pub side_lobes: f64,
    /// Each angle's reflectance `(scale, offset)` ([`SampleFit::reflectance_terms`]).
    pub terms: heapless::Vec<(f64, f64), RESIDUAL_ANGLES>,
}

/// Starting points of the refinement: the search's scores and Cauchy parameters, best first.
type Starts = heapless::Vec<(f64, [f64; 3]), 3>;

/// A band's quadrature nodes ([`Problem::nodes`]).
type Nodes = heapless::Vec<Node, NODES>;

/// The stack at one quadrature node: its weight, wavelength and film.
#[derive(Clone, Copy)]
struct Node {
    weight: f64,
    phase_per_nm: f64,
    /// The phase per nm one index step up.
    phase_up_per_nm: f64,
    /// The films' [`FilmAtAngle::phase_offset`]s, at the index and one step up (0 on a clear
    /// substrate; the other polarisation's film is evaluated at the first).
    phase0: f64,
    phase0_up: f64,
    film: FilmAtAngle,
    /// `dR/dn` at the node needs the film one index step up.
    film_up: FilmAtAngle,
    dn_dp: [f64; 3],
    /// With a polariser's leak and a clear film: the film in the other polarisation (s for p
    /// light, p for s; unpolarised light's own), which a leaking polariser mixes in.
    film_other: FilmAtAngle,
    /// With film absorption ([`Problem::site_model`]): the film as it absorbs, exactly, at
    /// the index, one index step up, and in the other polarisation.
    lossy: [LossyFilm; 3],
}

/// Runs jobs, on several threads where the caller has them (`std`: a scoped thread each);
/// the sample fit hands it the halves of its sites' sums, so the result does not depend on
/// how the jobs are run.
pub trait Parallel: Sync {
    /// Runs every job once.
    fn run(&self, jobs: &mut [&mut (dyn FnMut() + Send)]);
}

/// Runs the jobs one after the other (no threads: `no_std`, or one core).
pub struct Serial;

impl Parallel for Serial {
    fn run(&self, jobs: &mut [&mut (dyn FnMut() + Send)]) {
        for j in jobs.iter_mut() {
            j();
        }
    }
}

/// A fitting problem: the geometry, the spectra, the usable sites and the noise.
struct Problem<'a> {
    geo: &'a Geometry<'a>,
    spectra: &'a Spectra<'a>,
    usable: &'a [bool],
    /// Each sample's noise and the model's error.
    noise: Noise,
    /// Each angle's reflectance scale and offset (`measured = scale x true + offset`: a
    /// white standard's error, flare, the filter's side lobes), taken out of the measured
    /// spectra; `(1, 0)` unless the evidence asked for them ([`Problem::with_model_error`]).
    terms: Terms,
    /// Whether this is the fit again after a miss ([`Problem::with_model_error`]), which is
    /// not tried a third time.
    retry: bool,
    /// The film's extinction coefficient at 450 nm (0: a transparent film), its tail to the
    /// blue [`ABSORPTION_TAIL_NM`], when the evidence asked for it.
    film_k: f64,
    /// The share of the light in the other polarisation (a polariser's finite extinction;
    /// s or p light), when the evidence asked for it.
    leak: f64,
    /// The stage's angle offset, degrees, added to every angle, when the evidence asked for it.
    stage_deg: f64,
    /// The filter's wavelength shift, nm, added to every band's centre, when the evidence
    /// asked for it.
    shift_nm: f64,
    /// Flare: stray light, one reflectance offset at every angle and band, taken out of the
    /// measured spectra before each angle's terms, when the evidence asked for it.
    flare: f64,
    /// The share of the light the filter's side lobes pass, taken out of the measured
    /// spectra first ([`Problem::measured`]), when the evidence asked for it.
    side_lobes: f64,
    /// Each site's measured reflectance over the side lobes' band ([`Problem::wide_at`]),
    /// `[site][angle][band]` (empty: computed when asked).
    wide: &'a [f32],
    /// Where the two halves of the sites' sums run.
    par: &'a dyn Parallel,
}

impl SiteSums {
    /// Adds one sample of weight `w`, residual `res`, thickness derivative `jd` and index
    /// derivatives `jp` (with `INDEX`; else only the thickness's sums) to the site's sums and
    /// the pooled index blocks `(H_pp, g_p)`.
    #[inline(always)]
    fn add<const INDEX: bool>(
        &mut self,
        w: f64,
        res: f64,
        jd: f64,
        jp: Vector3<f64>,
        (hpp, gp): (&mut Matrix3<f64>, &mut Vector3<f64>),
    ) {
        self.sse += w * res * res;
        self.n += 1;
        self.jdd += w * jd * jd;
        self.gd += w * jd * res;
        if INDEX {
            for q in 0..3 {
                self.jdp[q] += w * jd * jp[q];
            }
            *hpp += jp * jp.transpose() * w;
            *gp += jp * (res * w);
        }
    }
}

/// A site's band reflectance and its derivatives ([`Problem::site_model`]).
#[derive(Clone, Copy, Default)]
struct SiteModel {
    m: f64,
    dm_dd: f64,
    dm_dp: [f64; 3],
}

/// Per-site normal-equation sums of one iteration.
#[derive(Clone, Copy, Default)]
struct SiteSums {
    sse: f64,
    n: usize,
    jdd: f64,
    jdp: [f64; 3],
    gd: f64,
}

/// Each angle's reflectance scale and offset ([`Problem::terms`]).
#[derive(Clone, Copy)]
struct Terms {
    scale: [f64; NOISE_ANGLES],
    offset: [f64; NOISE_ANGLES],
}

impl Terms {
    /// No correction.
    const NONE: Self = Self {
        scale: [1.0; NOISE_ANGLES],
        offset: [0.0; NOISE_ANGLES],
    };

    /// Whether any angle is corrected.
    fn fitted(&self) -> bool {
        self.scale.iter().any(|&s| s != 1.0) || self.offset.iter().any(|&o| o != 0.0)
    }
}

/// `a . b` with sixteen partial sums, so the compiler keeps them in vector registers (the
/// same sums in the same order with or without AVX2: [`crate::simd`]).
#[inline(always)]
fn dot(a: &[f32], b: &[f32]) -> f64 {
    const L: usize = 16;
    let mut acc = [0.0f32; L];
    let (ca, cb) = (a.chunks_exact(L), b.chunks_exact(L));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..L {
            acc[l] += x[l] * y[l];
        }
    }
    let tail: f32 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    acc.iter().map(|&v| f64::from(v)).sum::<f64>() + f64::from(tail)
}

#[cfg(test)]
mod tests {
    use super::lsq::sincos_phase;
    use super::*;
    use crate::optics::{FilmStack, Passband};

    /// The branch-free sine and cosine agree with libm's to 2 units in the last place of
    /// the larger of the result and 1e-3 (near a zero both are a rounding of `x` reduced),
    /// from 0 to 10^4 radians, at random and at multiples of pi/2 and pi/4 where the
    /// quadrant and the reduction change.
    #[test]
    fn phase_sincos_matches_libm() {
        let mut noise = Noise(0x9e37_79b9_7f4a_7c15);
        let random = (0..200_000).map(|_| 1e4 * noise.uniform().powi(3));
        let edges = (0..4000).flat_map(|k| {
            let x = k as f64 * core::f64::consts::FRAC_PI_4;
            [x, x * (1.0 + f64::EPSILON), x * (1.0 - f64::EPSILON)]
        });
        for x in random.chain(edges) {
            let (s, c) = sincos_phase(x);
            let (sr, cr) = libm::sincos(x);
            for (got, want) in [(s, sr), (c, cr)] {
                let ulp = f64::EPSILON * want.abs().max(1e-3);
                assert!(
                    (got - want).abs() <= 2.0 * ulp,
                    "x {x}: {got} against {want}"
                );
            }
        }
    }

    /// A small deterministic generator for test noise (xorshift, Box-Muller).
    struct Noise(u64);
    impl Noise {
        fn uniform(&mut self) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
        fn normal(&mut self) -> f64 {
            let (u, v) = (self.uniform().max(1e-300), self.uniform());
            libm::sqrt(-2.0 * libm::log(u)) * libm::cos(2.0 * core::f64::consts::PI * v)
        }
    }

    struct Case {
        film: Dispersion,
        substrate: f64,
        base_nm: f64,
        angles: &'static [f64],
        bands: (f64, f64, f64),
        fwhm: f64,
        pol: Polarization,
        noise: f64,
    }

    fn run(case: &Case, seed: u64) -> (SampleFit, Vec<f32>) {
        run_as(case, case.pol, seed, None)
    }

    /// Simulates `case` in `truth_pol` light and fits it as `case.pol` light, the index
    /// held at `held` when given ([`hold_index`]).
    fn run_as(
        case: &Case,
        truth_pol: Polarization,
        seed: u64,
        held: Option<(ModelKind, [f64; 3])>,
    ) -> (SampleFit, Vec<f32>) {
        let truth = Case {
            pol: truth_pol,
            ..*case
        };
        run_told(
            &truth,
            case,
            seed,
            held,
            DEFAULT_MODEL_ERROR,
            |_, _, _, _| 0.0,
        )
    }

    /// Simulates `truth` (each sample's reflectance plus `extra(site, run pixel, band nm,
    /// angle index)` and the noise) and fits it as `told` says the capture was taken (its
    /// polarisation, angles and substrate), tolerating `model_error`.
    fn run_told(
        truth: &Case,
        told: &Case,
        seed: u64,
        held: Option<(ModelKind, [f64; 3])>,
        model_error: f64,
        mut extra: impl FnMut(usize, usize, f64, usize) -> f64,
    ) -> (SampleFit, Vec<f32>) {
        let case = told;
        let mut bands = Vec::new();
        let mut l = case.bands.0;
        while l <= case.bands.1 + 1e-9 {
            bands.push(l);
            l += case.bands.2;
        }
        let fwhm = vec![case.fwhm; bands.len()];
        let stack = FilmStack {
            back_face: BackFace::None,
            ambient_index: 1.0,
            film: truth.film,
            substrate: Dispersion::constant(truth.substrate),
            polarization: truth.pol,
        };
        let sites = 32;
        let (na, nb) = (case.angles.len(), bands.len());
        let mut values = vec![0.0f32; sites * RUN * na * nb];
        let mut rng = Noise(seed | 1);
        let mut thickness = Vec::new();
        for k in 0..sites {
            let centre = truth.base_nm * (1.0 + 0.1 * (k as f64 / sites as f64 - 0.5));
            thickness.push(centre as f32);
            for j in 0..RUN {
                let d = centre + 0.3 * (j as f64 - 2.0);
                for (a, &deg) in truth.angles.iter().enumerate() {
                    for (b, &l) in bands.iter().enumerate() {
                        let r = stack.band_reflectance(d, deg, &Passband::gaussian(l, case.fwhm));
                        values[((k * RUN + j) * na + a) * nb + b] =
                            (r + extra(k, j, l, a) + truth.noise * rng.normal()) as f32;
                    }
                }
            }
        }
        let truth = thickness;
        let geo = Geometry {
            back_face: BackFace::None,
            bands_nm: &bands,
            fwhm_nm: &fwhm,
            angles_deg: case.angles,
            ambient_index: 1.0,
            substrate: Dispersion::constant(case.substrate),
            polarization: case.pol,
            index_range: [1.2, 3.0],
            thickness_range_nm: [10.0, 3000.0],
            model_error,
            rig_tolerance: 1.0,
        };
        let spectra = Spectra {
            values: &values,
            sites,
            angle_stride: na,
            run: RUN,
        };
        let mut scratch = vec![0.0f32; workspace_len(sites, na, nb)];
        let fit = match held {
            Some((kind, p)) => hold_index(&geo, &spectra, kind, p, &mut scratch, &Serial),
            None => fit_index(&geo, &spectra, None, &mut scratch, &Serial),
        };
        (fit, truth)
    }

    /// The index given rather than fitted: a real TiO2-like dispersion held (through the
    /// solver's model, as `--film-index` gives it) seats every site within 0.3 nm at a
    /// reduced chi-square near 1; held 0.02 high, the chi-square says the index is wrong
    /// and the fit fails.
    #[test]
    fn a_given_index_is_held_and_its_misfit_reported() {
        let film = Dispersion::Sellmeier {
            a: 1.0,
            b: [4.9, 0.0, 0.0],
            c_um: [0.21, 0.0, 0.0],
        };
        let case = Case {
            film,
            substrate: 1.52,
            base_nm: 180.0,
            angles: &[10.0, 30.0, 50.0, 65.0],
            bands: (400.0, 720.0, 4.0),
            fwhm: 8.0,
            pol: Polarization::P,
            noise: 0.003,
        };
        let model = IndexModel::from_dispersion(film).expect("one pole");
        let (kind, p) = ModelKind::of_index(&model);
        assert_eq!(kind, ModelKind::Sellmeier1);
        let (fit, truth) = run_as(&case, case.pol, 9, Some((kind, p)));
        assert!(fit.failure.is_none(), "{:?}", fit.failure);
        let c = fit.best.expect("a candidate");
        assert_eq!((c.kind, c.params, c.n550_sigma), (kind, p, 0.0));
        assert!(c.chi2_nu < 1.2, "{}", c.chi2_nu);
        assert_eq!(fit.sites_used, truth.len());
        for (t, d) in fit.thickness_nm.iter().zip(&truth) {
            assert!((t - d).abs() < 0.3, "{t} vs {d}");
        }
        let off = Dispersion::Sellmeier {
            a: 1.0,
            b: [4.9 * 1.02 * 1.02 + 0.04, 0.0, 0.0],
            c_um: [0.21, 0.0, 0.0],
        };
        let (kind, p) = ModelKind::of_index(&IndexModel::from_dispersion(off).expect("one pole"));
        let (wrong, _) = run_as(&case, case.pol, 9, Some((kind, p)));
        assert_eq!(wrong.failure, Some(Failure::GivenIndexMisfit));
        assert!(wrong.best.expect("a candidate").chi2_nu > 3.0, "{wrong:?}");
    }

    /// Every model's parameters survive the trip through the solver's index model.
    #[test]
    fn model_parameters_round_trip_through_the_solvers_model() {
        for (kind, p) in [
            (ModelKind::Constant, [1.46, 0.0, 0.0]),
            (ModelKind::Cauchy2, [1.45, 0.0036, 0.0]),
            (ModelKind::Cauchy3, [2.2, 0.02, 0.003]),
            (ModelKind::Sellmeier1, [4.9, 0.0441, 0.0]),
            (ModelKind::Sellmeier1c, [3.1, 0.04, 1.3]),
        ] {
            let m = IndexModel::from_dispersion(kind.dispersion(&p)).expect("a model");
            let (k2, p2) = ModelKind::of_index(&m);
            assert_eq!(k2, kind);
            for (a, b) in p.iter().zip(&p2) {
                assert!(
                    (a - b).abs() <= 1e-12 * a.abs().max(1.0),
                    "{kind:?} {p:?} {p2:?}"
                );
            }
        }
    }

    /// Pixels of a thick dispersive high-index film (20 extrema a spectrum, 3 angles) seated
    /// one by one under the true index: within 0.5 nm, chi-square near 1, every other
    /// order's basin far worse; under an index 0.02 high, the fits say so.
    #[test]
    fn pixels_are_seated_by_their_full_spectra() {
        let (a, b, c) = (2.25, 0.045, 0.0025);
        let film = Dispersion::Cauchy {
            a,
            b_um2: b,
            c_um4: c,
        };
        let angles = [8.0, 35.0, 55.0];
        let bands: Vec<f64> = (0..150).map(|i| 405.0 + 2.0 * f64::from(i)).collect();
        let fwhm = vec![6.0; bands.len()];
        let stack = FilmStack {
            back_face: BackFace::None,
            ambient_index: 1.0,
            film,
            substrate: Dispersion::constant(1.6),
            polarization: Polarization::S,
        };
        let pixels = 12;
        let (na, nb) = (angles.len(), bands.len());
        let noise = 0.003;
        let mut rng = Noise(11);
        let mut values = vec![0.0f32; pixels * na * nb];
        let truth: Vec<f64> = (0..pixels).map(|k| 1450.0 + 23.0 * k as f64).collect();
        for (k, &d) in truth.iter().enumerate() {
            for (ai, &deg) in angles.iter().enumerate() {
                for (bi, &l) in bands.iter().enumerate() {
                    let r = stack.band_reflectance(d, deg, &Passband::gaussian(l, 6.0));
                    values[(k * na + ai) * nb + bi] = (r + noise * rng.normal()) as f32;
                }
            }
        }
        let geo = Geometry {
            back_face: BackFace::None,
            bands_nm: &bands,
            fwhm_nm: &fwhm,
            angles_deg: &angles,
            ambient_index: 1.0,
            substrate: Dispersion::constant(1.6),
            polarization: Polarization::S,
            index_range: [1.2, 3.0],
            thickness_range_nm: [50.0, 2000.0],
            model_error: 0.0,
            rig_tolerance: 1.0,
        };
        let spectra = Spectra {
            values: &values,
            sites: pixels,
            angle_stride: na,
            run: 1,
        };
        let mut scratch = vec![0.0f32; workspace_len(pixels, na, nb)];
        let mut out = [Seat::default(); 12];
        seat_pixels(
            &geo,
            &spectra,
            ModelKind::Cauchy3,
            [a, b, c],
            noise,
            0.0,
            &Nuisance::default(),
            &mut scratch,
            &mut out,
            &Serial,
        );
        for (s, &d) in out.iter().zip(&truth) {
            assert!((s.thickness_nm - d).abs() < 0.5, "{s:?} vs {d}");
            assert!(s.chi2_nu < 1.3, "{s:?}");
            assert!(s.margin_chi2 > 100.0, "{s:?}");
            assert!(s.sigma_nm < 0.5, "{s:?}");
        }
        seat_pixels(
            &geo,
            &spectra,
            ModelKind::Cauchy3,
            [a + 0.02, b, c],
            noise,
            0.0,
            &Nuisance::default(),
            &mut scratch,
            &mut out,
            &Serial,
        );
        assert!(out.iter().all(|s| s.chi2_nu > 2.0), "{out:?}");
    }

    fn check(case: &Case, tol_n: f64, tol_d: f64) -> SampleFit {
        let (fit, truth) = run(case, 7);
        let n = fit.index().expect("an index").index_at(550.0);
        let err = n - case.film.index_at(550.0);
        assert!(err.abs() <= tol_n, "n(550) off by {err}: {fit:?}");
        for (k, &t) in truth.iter().enumerate() {
            assert!(
                (fit.thickness_nm[k] - t).abs() <= tol_d as f32,
                "site {k}: {} against {t}",
                fit.thickness_nm[k]
            );
        }
        let c = fit.best.expect("a best fit");
        assert!(c.chi2_nu < 1.3, "chi2/nu {}", c.chi2_nu);
        fit
    }

    #[test]
    fn noise_is_measured_from_the_runs() {
        let case = Case {
            film: Dispersion::constant(1.38),
            substrate: 1.52,
            base_nm: 400.0,
            angles: &[10.0, 30.0, 50.0],
            bands: (420.0, 720.0, 3.0),
            fwhm: 4.0,
            pol: Polarization::S,
            noise: 0.003,
        };
        let (fit, _) = run(&case, 3);
        assert!(
            (fit.noise_sigma / 0.003 - 1.0).abs() < 0.05,
            "{}",
            fit.noise_sigma
        );
    }

    #[test]
    fn a_thin_high_index_oxide_with_real_dispersion() {
        // TiO2-like: one-pole Sellmeier, 150 nm on glass, p light.
        let film = Dispersion::Sellmeier {
            a: 1.0,
            b: [4.9, 0.0, 0.0],
            c_um: [0.21, 0.0, 0.0],
        };
        let fit = check(
            &Case {
                film,
                substrate: 1.52,
                base_nm: 150.0,
                angles: &[10.0, 30.0, 50.0, 65.0],
                bands: (400.0, 720.0, 4.0),
                fwhm: 8.0,
                pol: Polarization::P,
                noise: 0.003,
            },
            0.005,
            2.0,
        );
        assert!(fit.best.is_some_and(|c| c.kind.params() >= 2));
    }

    #[test]
    fn a_thick_dispersive_film_keeps_its_fringe_order() {
        let film = Dispersion::Sellmeier {
            a: 1.0,
            b: [3.9, 0.0, 0.0],
            c_um: [0.2, 0.0, 0.0],
        };
        check(
            &Case {
                film,
                substrate: 1.6,
                base_nm: 1600.0,
                angles: &[5.0, 25.0, 45.0],
                bands: (400.0, 720.0, 2.0),
                fwhm: 4.0,
                pol: Polarization::S,
                noise: 0.003,
            },
            0.003,
            2.0,
        );
    }

    #[test]
    fn a_constant_index_stays_constant() {
        let fit = check(
            &Case {
                film: Dispersion::constant(1.37),
                substrate: 1.65,
                base_nm: 400.0,
                angles: &[10.0, 20.0, 30.0, 40.0, 50.0],
                bands: (420.0, 720.0, 2.0),
                fwhm: 4.0,
                pol: Polarization::S,
                noise: 0.003,
            },
            0.001,
            1.0,
        );
        // Constant, or a Cauchy model that bends by less than 0.002 across the band.
        let c = fit.best.expect("a fit");
        let d = c.kind.dispersion(&c.params);
        assert!(
            (d.index_at(420.0) - d.index_at(720.0)).abs() < 0.002,
            "{c:?}"
        );
    }

    #[test]
    fn wrong_metadata_is_caught_by_the_gate() {
        // Simulated in p light, fitted as s.
        let case = Case {
            film: Dispersion::constant(1.9),
            substrate: 1.52,
            base_nm: 300.0,
            angles: &[10.0, 35.0, 60.0],
            bands: (420.0, 720.0, 3.0),
            fwhm: 4.0,
            pol: Polarization::P,
            noise: 0.002,
        };
        let (fit, _) = run(&case, 5);
        assert!(fit.index().is_some());
        let wrong = Case {
            pol: Polarization::S,
            ..case
        };
        // The same spectra fitted as s light: simulate p, fit s.
        let (p_fit, _) = run_as(&wrong, Polarization::P, 5, None);
        assert_eq!(p_fit.failure, Some(Failure::NoFit), "{p_fit:?}");
    }

    /// A film measured with a good camera's low noise, for the model-error tests.
    const QUIET: Case = Case {
        film: Dispersion::Cauchy {
            a: 2.05,
            b_um2: 0.02,
            c_um4: 0.0,
        },
        substrate: 1.52,
        base_nm: 420.0,
        angles: &[10.0, 30.0, 50.0],
        bands: (420.0, 720.0, 3.0),
        fwhm: 4.0,
        pol: Polarization::S,
        noise: 3e-4,
    };

    /// A capture whose metadata are wrong misses the spectra by far more than any model
    /// error tolerated, at a good camera's low noise too: each refused, none given an index.
    #[test]
    fn gross_misfits_are_refused_at_low_noise() {
        let (fit, _) = run_told(
            &QUIET,
            &QUIET,
            3,
            None,
            DEFAULT_MODEL_ERROR,
            |_, _, _, _| 0.0,
        );
        assert!(fit.failure.is_none(), "{fit:?}");
        assert_eq!(
            fit.model_error, 0.0,
            "the right metadata fit within the noise"
        );
        let wrong = [
            (
                "polarisation",
                Case {
                    pol: Polarization::P,
                    ..QUIET
                },
            ),
            (
                "angles",
                Case {
                    angles: &[14.0, 34.0, 54.0],
                    ..QUIET
                },
            ),
            (
                "substrate",
                Case {
                    substrate: 1.65,
                    ..QUIET
                },
            ),
        ];
        for (what, told) in wrong {
            let (fit, _) = run_told(&QUIET, &told, 3, None, DEFAULT_MODEL_ERROR, |_, _, _, _| {
                0.0
            });
            assert_eq!(fit.failure, Some(Failure::NoFit), "wrong {what}: {fit:?}");
            assert!(
                fit.residual.model_rms > DEFAULT_MODEL_ERROR,
                "wrong {what}: {fit:?}"
            );
        }
    }

    /// A stage whose angles all read 0.4 degrees low at a good camera's noise: the fit takes
    /// the offset as a nuisance term by evidence, finds it within its sigma's reach, and the
    /// index comes out right; the same capture told its true angles takes no offset.
    #[test]
    fn a_stage_offset_is_found_by_evidence() {
        let truth = Case {
            angles: &[10.4, 30.4, 50.4],
            ..QUIET
        };
        let (fit, _) = run_told(
            &truth,
            &QUIET,
            5,
            None,
            DEFAULT_MODEL_ERROR,
            |_, _, _, _| 0.0,
        );
        assert!(fit.failure.is_none(), "{fit:?}");
        let o = fit.stage_offset_deg;
        assert!((o.value - 0.4).abs() < 0.1, "{o:?}");
        assert!(o.sigma > 0.0 && o.sigma < 0.1, "{o:?}");
        let n = fit.index().expect("index").index_at(550.0);
        let n_true = QUIET.film.index_at(550.0);
        assert!((n - n_true).abs() < 0.003, "n {n} against {n_true}");
        let (told_right, _) = run_told(
            &truth,
            &truth,
            5,
            None,
            DEFAULT_MODEL_ERROR,
            |_, _, _, _| 0.0,
        );
        assert!(!told_right.stage_offset_deg.taken(), "{told_right:?}");
    }

    /// A smooth misfit of a real rig (here 6e-4 RMS along the band, twice the noise) fails
    /// the noise alone but not a tolerated model error: the index comes out right, the
    /// misfit is measured and reported, and the index's sigma widens with it.
    #[test]
    fn a_small_smooth_misfit_is_carried_as_the_model_error() {
        let ripple = |_: usize, _: usize, l: f64, _: usize| 8.5e-4 * libm::sin(l / 37.0);
        let (strict, _) = run_told(&QUIET, &QUIET, 4, None, 0.0, ripple);
        assert_eq!(strict.failure, Some(Failure::NoFit), "{strict:?}");
        let (fit, _) = run_told(&QUIET, &QUIET, 4, None, DEFAULT_MODEL_ERROR, ripple);
        let (plain, _) = run_told(
            &QUIET,
            &QUIET,
            4,
            None,
            DEFAULT_MODEL_ERROR,
            |_, _, _, _| 0.0,
        );
        assert!(fit.failure.is_none(), "{fit:?}");
        let n = fit.index().expect("an index").index_at(550.0);
        let err = n - QUIET.film.index_at(550.0);
        assert!(err.abs() < 0.005, "n(550) off by {err}");
        assert!(
            (fit.residual.model_rms - 6e-4).abs() < 2e-4,
            "model_rms {}",
            fit.residual.model_rms
        );
        assert!(fit.residual.band_correlation > 0.5, "{:?}", fit.residual);
        let (s, s0) = (
            fit.best.map_or(0.0, |c| c.n550_sigma),
            plain.best.map_or(0.0, |c| c.n550_sigma),
        );
        assert!(s > 2.0 * s0, "sigma {s} against {s0} without the misfit");
    }

    /// A site whose spectra fit far worse than the rest (a particle on the film) is set
    /// aside rather than refusing the sample, and the index comes from the others.
    #[test]
    fn a_defect_site_is_set_aside() {
        let defect = |k: usize, _: usize, l: f64, _: usize| {
            if k == 5 {
                0.02 * libm::cos(l / 20.0)
            } else {
                0.0
            }
        };
        let (fit, _) = run_told(&QUIET, &QUIET, 6, None, DEFAULT_MODEL_ERROR, defect);
        assert!(fit.failure.is_none(), "{fit:?}");
        assert!(fit.set_aside[5], "{:?}", &fit.set_aside[..32]);
        assert_eq!(fit.set_aside.iter().filter(|&&a| a).count(), 1);
        let n = fit.index().expect("an index").index_at(550.0);
        let err = n - QUIET.film.index_at(550.0);
        assert!(err.abs() < 0.002, "n(550) off by {err}");
    }

    /// Noise three times higher in the blue of the band (a dim lamp's shot noise) and twice
    /// as high at one angle is measured as it is: the fit's reduced chi-square near 1 and the
    /// index right, the blue and that angle weighed down.
    #[test]
    fn noise_varying_over_bands_and_angles_is_weighed_as_it_is() {
        let case = Case {
            noise: 0.0,
            ..QUIET
        };
        let mut rng = Noise(99);
        let uneven = |_: usize, _: usize, l: f64, a: usize| {
            let blue = if l < 520.0 { 3.0 } else { 1.0 };
            let dark = if a == 1 { 2.0 } else { 1.0 };
            1e-3 * blue * dark * rng.normal()
        };
        let (fit, _) = run_told(&case, &case, 7, None, 0.0, uneven);
        assert!(fit.failure.is_none(), "{fit:?}");
        let c = fit.best.expect("a fit");
        assert!((0.85..1.15).contains(&c.chi2_nu), "chi2_nu {}", c.chi2_nu);
        let err = c.kind.dispersion(&c.params).index_at(550.0) - QUIET.film.index_at(550.0);
        assert!(err.abs() < 0.003, "n(550) off by {err}");
    }

    #[test]
    fn site_grid_spreads_runs_inside_the_image() {
        let g = site_grid(640, 480, 64);
        assert!(g.len() >= 48 && g.len() <= 64, "{}", g.len());
        for &(r, c) in &g {
            assert!((r as usize) < 480 && c as usize + RUN <= 640);
        }
        assert!(site_grid(3, 3, 16).is_empty());
        // A strip narrower than a run: runs down its columns, inside it.
        let g = site_grid(4, 60, 16);
        assert!(!g.is_empty());
        for &(r, c) in &g {
            assert!(r as usize + RUN <= 60 && (c as usize) < 4);
        }
    }
}
