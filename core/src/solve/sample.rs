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

use super::refine::{absorption_shape, passband_phase_span, passband_rule, MAX_BAND_NODES};
use super::IndexModel;
use crate::optics::{BackFace, Dispersion, FilmAtAngle, Indices, LossyFilm, Polarization};

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
/// Extinction coefficients at 450 nm the absorption search tries first.
const ABSORPTION_GRID: [f64; 6] = [0.001, 0.002, 0.004, 0.008, 0.016, 0.032];

/// Shares of the light the filter's side lobes pass that the search tries first: a
/// liquid-crystal filter keeps them to a few per cent, so the outermost, 8 %, is more than
/// one has ([`Problem::with_nuisance`]).
const SIDE_LOBE_GRID: [f64; 6] = [0.0025, 0.005, 0.01, 0.02, 0.04, 0.08];

/// How much wider than a band's FWHM the band its side lobes pass light from is: a
/// Gaussian of this many FWHM, truncated at 1.5 of its own FWHM either side.
pub const SIDE_LOBE_WIDTH: f64 = 10.0;

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

/// What [`Problem::marginal_n550_sigma`] finds: the index's standard error at 550 nm and
/// the sites' thickness share ([`SampleFit::thickness_share`]), both before scaling by the
/// fit's reduced chi-square.
#[derive(Clone, Copy, Debug)]
struct Marginal {
    n550_sigma: f64,
    thickness_share: f64,
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
fn complete_sites(
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

/// The sample's noise: sample `(k, a, b)` (site, angle, band) has the variance
/// `(site[k] angle[a] band[b])^2 + model2`. Sites see different noise (vignetting, shot noise
/// at their own reflectance), bands too (a lamp dim in the blue, the filter's throughput) and
/// angles (a darker angle), so each is weighed by its own; `model2` is the model's error
/// ([`SampleFit::model_error`]) added to each.
#[derive(Clone)]
struct Noise {
    site: [f64; MAX_SITES],
    angle: [f64; NOISE_ANGLES],
    band: [f64; MAX_BANDS],
    model2: f64,
}

impl Noise {
    /// The same noise `sigma` at every sample.
    fn uniform(sigma: f64) -> Self {
        Self {
            site: [sigma; MAX_SITES],
            angle: [1.0; NOISE_ANGLES],
            band: [1.0; MAX_BANDS],
            model2: 0.0,
        }
    }

    /// The noise variance of sample `(k, a, b)`, without the model's error.
    #[inline]
    fn noise2(&self, k: usize, a: usize, b: usize) -> f64 {
        let s =
            (self.site[k] * self.angle[a.min(NOISE_ANGLES - 1)] * self.band[b]).max(NOISE_FLOOR);
        s * s
    }

    /// The weight of sample `(k, a, b)`: one over its noise and model variance.
    #[inline]
    fn weight(&self, k: usize, a: usize, b: usize) -> f64 {
        1.0 / (self.noise2(k, a, b) + self.model2)
    }

    /// Site `k`'s weight over all its samples (the search's, which weighs bands alike).
    #[inline]
    fn site_weight(&self, k: usize) -> f64 {
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
fn median(v: &mut [f32]) -> f64 {
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
fn measure_noise(geo: &Geometry<'_>, spectra: &Spectra<'_>, scratch: &mut [f32]) -> (Noise, f64) {
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

/// Columns of [`Problem::score_point`]'s dictionary at most: angles times bands.
const COLUMNS: usize = SEARCH_ANGLES * SEAT_BANDS;

/// The dictionary's rows (`rows`: `nv` columns each, a row a thickness) and each row's sum
/// of squares (`m2`), for a film of `P` polarisations: each column's phase advances by a
/// rotation and its passband damping by a ratio that itself shrinks geometrically (`st`,
/// `rot`), so no row needs a cosine or an exponential; its reflectance is
/// [`FilmAtAngle::reflectance_at_cos`]'s from the column's `terms`, bit for bit.
#[inline(always)]
fn dictionary_rows<const P: usize>(
    rows: &mut [f32],
    nv: usize,
    m2: &mut [f64],
    st: &mut [[f64; COLUMNS]; 5],
    rot: &[[f64; COLUMNS]; 2],
    terms: &[[[f64; COLUMNS]; 3]; 2],
) {
    let mut m = [0.0f64; COLUMNS];
    let m = &mut m[..nv];
    for (row, m2) in rows.chunks_exact_mut(nv.max(1)).zip(m2.iter_mut()) {
        let [c, s, damp, ratio, shrink] = st;
        let (c, s, damp) = (&mut c[..nv], &mut s[..nv], &mut damp[..nv]);
        let (ratio, shrink) = (&mut ratio[..nv], &shrink[..nv]);
        let (cd, sd) = (&rot[0][..nv], &rot[1][..nv]);
        for j in 0..nv {
            let x = damp[j] * c[j];
            let mut sum = 0.0;
            for t in &terms[..P] {
                let b = t[1][j] * x;
                sum += (t[0][j] + b) / (t[2][j] + b);
            }
            m[j] = sum / P as f64;
            (c[j], s[j]) = (c[j] * cd[j] - s[j] * sd[j], s[j] * cd[j] + c[j] * sd[j]);
            damp[j] *= ratio[j];
            ratio[j] *= shrink[j];
        }
        let mut sum = 0.0;
        for (v, &mj) in row.iter_mut().zip(m.iter()) {
            *v = mj as f32;
            sum += mj * mj;
        }
        *m2 = sum;
    }
}

/// `(sin x, cos x)` of a film's phase (`|x|` under a million radians: a phase is a few
/// thousand at most), without a branch, so that a loop over many phases vectorises:
/// Cody-Waite reduction by pi/2 (the quotient below 2^20, so its product with the first
/// 33 bits of pi/2 is exact) and fdlibm's polynomials on `|r| <= pi/4`. Within 2 units in
/// the last place of `libm::sincos` (tested).
#[inline(always)]
#[allow(clippy::excessive_precision)] // fdlibm's constants as it prints them
fn sincos_phase(x: f64) -> (f64, f64) {
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

/// Most angles whose reflectance terms are fitted (the marginal covariance's size).
pub const TERM_MAX_ANGLES: usize = 12;
/// The nuisance terms besides each angle's scale and offset: the film's absorption, the
/// polariser's leak, the stage offset, the wavelength shift, the flare and the side lobes.
const TERMS: usize = 6;
/// Index parameters, two terms an angle and the [`TERMS`].
const MARGINAL: usize = 3 + 2 * TERM_MAX_ANGLES + TERMS;
/// Most sites the index sigma's tolerance marginal is made on ([`Problem::marginal_n550_sigma`]).
const TOLERANCE_SITES: usize = 8;
/// Most bands it is made on.
const TOLERANCE_BANDS: usize = 48;
/// The steps over which [`Problem::marginal_n550_sigma`] takes the model's slope along the
/// absorption (k at 450 nm), the leak, the stage offset (degrees) and the shift (nm).
const TERM_STEPS: [f64; 4] = [1e-3, 1e-3, 0.01, 0.02];

/// What a real rig and sample keep of each nuisance term without its showing in the fit
/// (1-sigma), with which the reported index sigma carries every term, taken or not
/// ([`Problem::marginal_n550_sigma`]): a white reference's error of 1 % at each angle and an
/// offset of 1e-3, k 0.004 at 450 nm, a leak of 1 %, a stage offset of 0.25 degrees, a
/// wavelength shift of 0.3 nm, a flare of 0.2 % and side lobes of 2 %.
pub struct Tolerance {
    /// Each angle's reflectance scale.
    pub scale: f64,
    /// Each angle's reflectance offset.
    pub offset: f64,
    /// The [`TERMS`] in their order.
    pub terms: [f64; TERMS],
}

/// The tolerance every capture's index sigma is reported with.
pub const TOLERANCE: Tolerance = Tolerance {
    scale: 0.01,
    offset: 1e-3,
    terms: [0.004, 0.01, 0.25, 0.3, 0.002, 0.02],
};

impl Problem<'_> {
    /// Site `k`'s measured value at angle `a`, band `b`: the side lobes' light, the flare and
    /// its angle's scale and offset taken out (NaN: none). The side lobes pass the share `s`
    /// of the light from a wide band, whose reflectance the measured neighbouring bands give
    /// ([`Problem::wide_at`]): `y = (1 - s) R + s wide(R)`, so `R = (y - s wide(y)) / (1 - s)`
    /// to first order in `s` (the flare, in both, comes out the same).
    #[inline]
    fn measured(&self, bands: usize, k: usize, a: usize, b: usize) -> f64 {
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
    fn fill_wide(&self, out: &mut [f32]) {
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
    fn wide_at(&self, bands: usize, k: usize, a: usize, b: usize) -> f64 {
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
    fn indices(&self, film: f64, l_nm: f64) -> Indices {
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
    fn nodes<'n>(
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

    /// A site's band reflectance at thickness `d` over a band's passband `nodes`, without
    /// the derivatives [`Problem::site_model`] adds (half its cost, where only the value is
    /// read: residuals, reflectance terms, the slopes taken by a step).
    fn site_value(&self, nodes: &[Node], d: f64) -> f64 {
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
    fn site_model(&self, nodes: &[Node], d: f64) -> SiteModel {
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

    /// One pass computing the full normal equations: per-site sums and the pooled index
    /// blocks `(H_pp, g_p)`, chi-square (in noise units) and residual count; without `INDEX`
    /// (the index held) the thickness's sums only, the blocks and `jdp` zero.
    fn normal<const INDEX: bool>(
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

    /// Every usable site's thickness under `(kind, p)` held: the best of the dictionary over
    /// the thickness range on every band, then Gauss-Newton on each thickness with the
    /// passband's quadrature in full. The thicknesses, the sites' sums at them and each
    /// site's margin (how much worse, chi-square, the best thickness in another order's
    /// basin fits); `None` when a model cannot be evaluated.
    fn seat(
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

    /// The thickest usable site's thickness of `t` (which sets the passband quadrature's
    /// nodes), nm.
    fn thickest(&self, t: &[f64; MAX_SITES]) -> f64 {
        (0..self.usable.len())
            .filter(|&k| self.usable[k])
            .map(|k| t[k])
            .fold(0.0, f64::max)
    }

    /// The band's shortest and longest centre wavelengths, nm.
    fn band_span(&self) -> (f64, f64) {
        let b = self.geo.bands_nm;
        (
            b.iter().copied().fold(f64::INFINITY, f64::min),
            b.iter().copied().fold(0.0, f64::max),
        )
    }

    /// Levenberg-Marquardt on every usable site from `(kind, p)` and thicknesses `t`
    /// (updated in place).
    fn refine(
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
        let mut cov = Matrix3::zeros();
        for _ in 0..steps {
            // Reduce to the index parameters (Schur complement of the thickness block).
            let mut h = hpp;
            let mut g = gp;
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
            let Some(dp) = hd.cholesky().map(|c| c.solve(&gr)) else {
                lambda *= 10.0;
                continue;
            };
            let mut p_new = p;
            for q in 0..np {
                p_new[q] += dp[q];
            }
            let mut t_new = *t;
            let mut ok = true;
            for (k, s) in sites.iter().enumerate().take(self.usable.len()) {
                if !self.usable[k] || s.jdd <= 0.0 {
                    continue;
                }
                let jdd = s.jdd * (1.0 + lambda);
                let jdp = Vector3::from(s.jdp);
                let step = (s.gd - jdp.dot(&dp)) / jdd;
                t_new[k] = t[k] + step;
                if t_new[k].is_nan() || t_new[k] <= 0.0 {
                    ok = false;
                }
            }
            let trial = if ok {
                let mut trial_sites = [SiteSums::default(); MAX_SITES];
                self.normal::<true>(kind, &p_new, &t_new, &mut trial_sites)
                    .map(|r| (r, trial_sites))
            } else {
                None
            };
            match trial {
                Some(((h2, g2, c2, n2), s2)) if c2 < chi2 => {
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
        // Covariance of the index parameters at the solution (undamped Schur complement).
        let mut h = hpp;
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
        Some(Candidate {
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
        })
    }

    /// Every model refined from the two-term Cauchy fit `base`; the simplest that the data
    /// ask for chosen, with the gate and a second start.
    fn choose(
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
    fn settle(&self, mut fit: SampleFit, mut c: Candidate, tt: &[f64; MAX_SITES]) -> SampleFit {
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

    /// What `(kind, p)` at the sites' thicknesses `t` leaves on their own pixels (`None`
    /// when the model cannot be evaluated): the angles in two halves, each summed on its own
    /// ([`Problem::residual_sums`], run by [`Problem::par`]) and added in angle order.
    fn residual(&self, kind: ModelKind, p: &[f64; 3], t: &[f64; MAX_SITES]) -> Option<Residual> {
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

    /// `fit` again when it misses the gate against the noise alone: the sites that fit far
    /// worse than the rest ([`OUTLIER_SITE_RATIO`], at most a quarter) set aside; with angle
    /// leverage ([`TERM_ANGLES`] angles over [`TERM_SPAN_DEG`]), each angle's reflectance
    /// scale and offset fitted with the index and kept when their chi-square gain beats
    /// their BIC penalty; the misfit still beyond the noise taken as the model's error and
    /// added to every sample's variance; and the index fitted and its model chosen again
    /// under them (`held`: seated again under the given index). `fit` as it is when it
    /// passed, on a second try, when no model error is tolerated, or when the misfit is more
    /// than twice the tolerated one.
    fn with_model_error(
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
        let mut sums = [SiteSums::default(); MAX_SITES];
        if self
            .normal::<false>(best.kind, &best.params, &tt, &mut sums)
            .is_none()
        {
            return fit;
        }
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
        // Forward stepwise: each round every term not yet taken is fitted with the index and
        // thicknesses, and the one whose chi-square falls furthest is taken (when it pays its
        // BIC penalty, [`Problem::with_nuisance`]); a fixed order let the first term mop up
        // another's misfit and bend the index. The terms, as [`SampleFit`] reports them:
        // film absorption, polariser leak, stage offset, wavelength shift, flare, side lobes.
        let mut found = [Term::NONE; 6];
        if held.is_none() {
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
                    let (mut b, mut d) = (best, tt);
                    let (b_, d_) = (&mut b, &mut d);
                    let got = match t {
                        0 => kept.with_nuisance(b_, d_, &ABSORPTION_GRID, |p, v| p.film_k = v),
                        1 => kept.with_nuisance(b_, d_, &LEAK_GRID, |p, v| p.leak = v),
                        2 => kept.with_nuisance(b_, d_, &STAGE_GRID, |p, v| p.stage_deg = v),
                        3 => kept.with_nuisance(b_, d_, &SHIFT_GRID, |p, v| p.shift_nm = v),
                        4 => kept.with_nuisance(b_, d_, &FLARE_GRID, |p, v| p.flare = v),
                        _ => kept.with_nuisance(b_, d_, &SIDE_LOBE_GRID, |p, v| p.side_lobes = v),
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
                    0 => kept.film_k = term.value,
                    1 => kept.leak = term.value,
                    2 => kept.stage_deg = term.value,
                    3 => kept.shift_nm = term.value,
                    4 => kept.flare = term.value,
                    _ => kept.side_lobes = term.value,
                }
                found[t] = term;
                (best, tt) = (b, d);
            }
        }
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

    /// The standard error of the index at 550 nm of `(kind, p)` at the sites' thicknesses
    /// `t` with the nuisance terms free: the information matrix over the index parameters,
    /// the terms and the thicknesses, the thicknesses and the terms eliminated; before any
    /// scaling by the fit's reduced chi-square. Without `tolerance`, the terms the fit took
    /// but the stage offset and the wavelength shift (each angle's reflectance scale and
    /// offset, the film's absorption, the polariser's leak, the flare, the side lobes); with it,
    /// every term, each also held to what a rig keeps without it showing ([`TOLERANCE`] times
    /// [`Geometry::rig_tolerance`]):
    /// the index's accuracy on a real rig, not its precision under the terms the evidence
    /// took. The absorption, leak, stage offset and shift enter by their model's slope over
    /// a small step ([`TERM_STEPS`]).
    fn marginal_n550_sigma(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        t: &[f64; MAX_SITES],
        tolerance: bool,
    ) -> Option<Marginal> {
        type M = nalgebra::SMatrix<f64, MARGINAL, MARGINAL>;
        let (na, nb) = (self.geo.angles_deg.len(), self.geo.bands_nm.len());
        let fitted = self.terms.fitted();
        let per_angle = (fitted || tolerance) && na <= TERM_MAX_ANGLES;
        if fitted && !per_angle {
            return None;
        }
        let sites = self.usable.len();
        let d_max = self.thickest(t);
        let np = kind.params();
        let slot = |term: usize| MARGINAL - TERMS + term;
        let polarised = self.geo.polarization != Polarization::Unpolarized;
        // Which of the six terms are in play (absorption, leak, stage, shift, flare, side
        // lobes); the flare's share is each angle's offset when those are.
        let taken = [
            self.film_k > 0.0,
            self.leak > 0.0,
            false,
            false,
            self.flare > 0.0,
            self.side_lobes > 0.0,
        ];
        // The stage offset and the shift, whose profiled sigmas gauge them, enter with the
        // tolerance only: the precision the gate judges is under the others.
        let on: [bool; TERMS] = core::array::from_fn(|i| match i {
            1 => polarised && (taken[1] || tolerance),
            2 | 3 => tolerance,
            4 => !per_angle && (taken[4] || tolerance),
            _ => taken[i] || tolerance,
        });
        // The problem a step along each stepped term (absorption, leak, stage, shift).
        let stepped: [Option<Problem<'_>>; 4] = core::array::from_fn(|i| {
            on[i].then(|| {
                let mut q = Problem {
                    noise: self.noise.clone(),
                    ..*self
                };
                match i {
                    0 => q.film_k += TERM_STEPS[0],
                    1 => q.leak += TERM_STEPS[1],
                    2 => q.stage_deg += TERM_STEPS[2],
                    _ => q.shift_nm += TERM_STEPS[3],
                }
                q
            })
        });
        // Only the parameters in play, each term held to its tolerance when asked; `pos`
        // maps a slot to its place among them.
        let mut keep: heapless::Vec<(usize, f64), MARGINAL> = (0..np).map(|q| (q, 0.0)).collect();
        if per_angle {
            for a in 0..na {
                let _ = keep.push((3 + 2 * a, TOLERANCE.scale));
                let _ = keep.push((3 + 2 * a + 1, TOLERANCE.offset));
            }
        }
        for (i, &on) in on.iter().enumerate() {
            if on {
                let _ = keep.push((slot(i), TOLERANCE.terms[i]));
            }
        }
        let mut pos = [usize::MAX; MARGINAL];
        for (i, &(k, _)) in keep.iter().enumerate() {
            pos[k] = i;
        }
        // With the tolerance, every `stride`-th usable site and `band_stride`-th band (at
        // most [`TOLERANCE_SITES`] and [`TOLERANCE_BANDS`]), the information scaled up to all
        // of them: sites and neighbouring bands are alike, and the term slopes cost five site
        // models a sample.
        let usable: heapless::Vec<usize, MAX_SITES> =
            (0..sites).filter(|&k| self.usable[k]).collect();
        let stride = if tolerance {
            usable.len().div_ceil(TOLERANCE_SITES).max(1)
        } else {
            1
        };
        let chosen: heapless::Vec<usize, MAX_SITES> =
            usable.iter().copied().step_by(stride).collect();
        let band_stride = if tolerance {
            nb.div_ceil(TOLERANCE_BANDS).max(1)
        } else {
            1
        };
        let up = usable.len() as f64 / chosen.len().max(1) as f64 * nb as f64
            / nb.div_ceil(band_stride) as f64;
        // The information over the kept parameters (upper triangle) and each site's
        // thickness row, accumulated over each sample's few nonzero slopes (an angle's
        // reflectance terms touch its own samples only).
        let mut h = [[0.0f64; MARGINAL]; MARGINAL];
        let mut jdd = [0.0; MAX_SITES];
        let mut cross = [[0.0f64; MARGINAL]; MAX_SITES];
        let mut buf = Nodes::new();
        let mut stepped_nodes: [Nodes; 4] = Default::default();
        for a in 0..na {
            let g = self.terms.scale[a.min(NOISE_ANGLES - 1)];
            for b in (0..nb).step_by(band_stride) {
                let nodes = self.nodes(kind, p, a, b, d_max, &mut buf)?;
                for (out, q) in stepped_nodes.iter_mut().zip(&stepped) {
                    if let Some(q) = q {
                        q.nodes(kind, p, a, b, d_max, out)?;
                    }
                }
                for &k in &chosen {
                    if !self.spectra.centre_at(nb, k, a, b).is_finite() {
                        continue;
                    }
                    let fit = self.site_model(nodes, t[k]);
                    let w = self.noise.weight(k, a, b);
                    // (place among the kept, slope), in slot order.
                    let mut u: heapless::Vec<(usize, f64), { 3 + 2 + TERMS }> =
                        heapless::Vec::new();
                    let mut put = |s: usize, v: f64| {
                        if pos[s] != usize::MAX {
                            let _ = u.push((pos[s], v));
                        }
                    };
                    for q in 0..np {
                        put(q, g * fit.dm_dp[q]);
                    }
                    if per_angle {
                        put(3 + 2 * a, fit.m);
                        put(3 + 2 * a + 1, 1.0);
                    }
                    for i in 0..4 {
                        if let Some(q) = &stepped[i] {
                            let m = q.site_value(&stepped_nodes[i], t[k]);
                            put(slot(i), g * (m - fit.m) / TERM_STEPS[i]);
                        }
                    }
                    put(slot(4), 1.0);
                    if on[5] {
                        // The measured value's slope along the side lobes' share, as the
                        // model's the other way.
                        let y = f64::from(self.spectra.centre_at(nb, k, a, b));
                        let s = self.side_lobes;
                        put(
                            slot(5),
                            (self.wide_at(nb, k, a, b) - y) / ((1.0 - s) * (1.0 - s)),
                        );
                    }
                    let wd = w * g * fit.dm_dd;
                    for (x, &(i, ui)) in u.iter().enumerate() {
                        let wi = w * ui;
                        for &(j, uj) in &u[x..] {
                            h[i][j] += wi * uj;
                        }
                        cross[k][i] += wd * ui;
                    }
                    jdd[k] += wd * g * fit.dm_dd;
                }
            }
        }
        let dim = keep.len();
        let mut sub = M::identity();
        for i in 0..dim {
            for j in i..dim {
                let mut v = h[i][j];
                for &k in &chosen {
                    if jdd[k] > 0.0 {
                        v -= cross[k][i] * cross[k][j] / jdd[k];
                    }
                }
                sub[(i, j)] = v * up;
                sub[(j, i)] = v * up;
            }
            let held = keep[i].1 * self.geo.rig_tolerance;
            if tolerance && held > 0.0 {
                sub[(i, i)] += 1.0 / (held * held);
            }
        }
        let inv = sub.try_inverse()?;
        let (_, g550) = kind.eval(p, L0_UM);
        let mut var = 0.0;
        for i in 0..np {
            for j in 0..np {
                var += g550[i] * inv[(i, j)] * g550[j];
            }
        }
        // A site's thickness moves with the parameters by `-cross / jdd` each: its variance
        // from them (a ratio the bands' subsampling leaves alone), relative to the thickness.
        let mut shares: heapless::Vec<f32, MAX_SITES> = heapless::Vec::new();
        for &k in &chosen {
            if jdd[k] > 0.0 && t[k] > 0.0 {
                let mut v = 0.0;
                for i in 0..dim {
                    for j in 0..dim {
                        v += cross[k][i] * inv[(i, j)] * cross[k][j];
                    }
                }
                let _ = shares.push((libm::sqrt(v.max(0.0)) / jdd[k] / t[k]) as f32);
            }
        }
        let share = if shares.is_empty() {
            f64::NAN
        } else {
            median(&mut shares)
        };
        (var > 0.0).then(|| Marginal {
            n550_sigma: libm::sqrt(var),
            thickness_share: share,
        })
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

    /// Each usable site's best thickness under `(kind, p)` over the thickness range, on the
    /// search bands; the summed chi-square (noise units).
    fn start_thicknesses(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        t: &mut [f64; MAX_SITES],
        scratch: &mut [f32],
    ) -> Option<f64> {
        let all: [usize; MAX_SITES] = core::array::from_fn(|k| k);
        let n = self.usable.len();
        let sites = &all[..n];
        self.score_point(
            kind,
            p,
            sites,
            self.geo.bands_nm.len(),
            0,
            scratch,
            Some(t),
            None,
        )
    }

    /// The global search over `(n550, b)` on bands `from..bands` (every so many): the best
    /// grid point refined locally, as Cauchy parameters, and the fringes its best site
    /// thickness puts across the whole band.
    fn search(&self, bands: usize, from: usize, scratch: &mut [f32]) -> Option<(Starts, f64)> {
        // The search's sites: usable ones, spread over the sample.
        let mut chosen: heapless::Vec<usize, SEARCH_SITES> = heapless::Vec::new();
        let used: heapless::Vec<usize, MAX_SITES> =
            (0..self.usable.len()).filter(|&k| self.usable[k]).collect();
        let step = used.len().div_ceil(SEARCH_SITES).max(1);
        for &k in used.iter().step_by(step) {
            if chosen.push(k).is_err() {
                break;
            }
        }
        let [lo, hi] = self.geo.index_range;
        let n_steps = (libm::ceil((hi - lo) / 0.05) as usize).clamp(1, 200);
        const B_STEPS: usize = 7;
        let mut grid = [[f64::INFINITY; B_STEPS]; 201];
        let point = |i: usize, j: usize| -> [f64; 3] {
            let n550 = lo + (hi - lo) * i as f64 / n_steps as f64;
            let b = 0.02 * j as f64;
            [n550 - b / (L0_UM * L0_UM), b, 0.0]
        };
        {
            // Rows of the grid in two halves, each with half the workspace.
            let half = (n_steps + 1).div_ceil(2);
            let (top, bottom) = grid.split_at_mut(half);
            let split = scratch.len() / 2;
            let (s1, s2) = scratch.split_at_mut(split);
            let chosen = &chosen;
            let score_rows = |rows: &mut [[f64; B_STEPS]], first: usize, scratch: &mut [f32]| {
                for (r, row) in rows.iter_mut().enumerate() {
                    let i = first + r;
                    if i > n_steps {
                        break;
                    }
                    for (j, cell) in row.iter_mut().enumerate() {
                        let p = point(i, j);
                        let l_lo = self.geo.bands_nm[from];
                        if ModelKind::Cauchy2.eval(&p, l_lo * 1e-3).0 > hi + 0.3 {
                            continue;
                        }
                        if let Some(s) = self.score_point(
                            ModelKind::Cauchy2,
                            &p,
                            chosen,
                            bands,
                            from,
                            scratch,
                            None,
                            None,
                        ) {
                            *cell = s;
                        }
                    }
                }
            };
            let mut a = || score_rows(top, 0, s1);
            let mut b = || score_rows(bottom, half, s2);
            self.par.run(&mut [&mut a, &mut b]);
        }
        // The three deepest local minima, each refined on a finer grid.
        let mut minima: heapless::Vec<(f64, usize, usize), 64> = heapless::Vec::new();
        for i in 0..=n_steps {
            for j in 0..B_STEPS {
                let v = grid[i][j];
                if !v.is_finite() {
                    continue;
                }
                let mut is_min = true;
                for di in -1i32..=1 {
                    for dj in -1i32..=1 {
                        let (ii, jj) = (i as i32 + di, j as i32 + dj);
                        if (di, dj) == (0, 0)
                            || ii < 0
                            || jj < 0
                            || ii > n_steps as i32
                            || jj >= B_STEPS as i32
                        {
                            continue;
                        }
                        if grid[ii as usize][jj as usize] < v {
                            is_min = false;
                        }
                    }
                }
                if is_min && minima.push((v, i, j)).is_err() {
                    break;
                }
            }
        }
        minima.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let mut found: Starts = heapless::Vec::new();
        for &(_, i, j) in minima.iter().take(3) {
            let mut best: Option<(f64, [f64; 3])> = None;
            let c = point(i, j);
            let (n0, b0) = (c[0] + c[1] / (L0_UM * L0_UM), c[1]);
            for di in -5i32..=5 {
                for dj in -4i32..=4 {
                    let n550 = n0 + 0.01 * f64::from(di);
                    let b = b0 + 0.005 * f64::from(dj);
                    if b < 0.0 || n550 < lo || n550 > hi {
                        continue;
                    }
                    let p = [n550 - b / (L0_UM * L0_UM), b, 0.0];
                    if let Some(s) = self.score_point(
                        ModelKind::Cauchy2,
                        &p,
                        &chosen,
                        bands,
                        from,
                        scratch,
                        None,
                        None,
                    ) {
                        if best.is_none_or(|(bs, _)| s < bs) {
                            best = Some((s, p));
                        }
                    }
                }
            }
            if let Some((score, p)) = best {
                let _ = found.push((score, p));
            }
        }
        found.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let (_, p) = *found.first()?;
        // Fringes across the whole band at the search sites' median thickness.
        let mut t = [f64::NAN; MAX_SITES];
        self.score_point(
            ModelKind::Cauchy2,
            &p,
            &chosen,
            bands,
            from,
            scratch,
            Some(&mut t),
            None,
        )?;
        let mut ts: heapless::Vec<f64, MAX_SITES> = chosen
            .iter()
            .map(|&k| t[k])
            .filter(|x| x.is_finite())
            .collect();
        ts.sort_unstable_by(f64::total_cmp);
        let d = *ts.get(ts.len() / 2)?;
        let b = &self.geo.bands_nm;
        let (l_lo, l_hi) = (b[0].min(b[b.len() - 1]), b[0].max(b[b.len() - 1]));
        let n = ModelKind::Cauchy2.eval(&p, L0_UM).0;
        let fringes = 2.0 * n * d * (1.0 / l_lo - 1.0 / l_hi);
        Some((found, fringes))
    }

    /// Summed chi-square (noise units) of `sites`, each at its best thickness under
    /// `(kind, p)`, on every so many of bands `from..bands` (at most [`SEARCH_BANDS`], or
    /// [`SEAT_BANDS`] when the thicknesses are wanted) with passband-damped centre
    /// wavelengths; writes the thicknesses into `t` when given.
    #[allow(clippy::too_many_arguments)]
    fn score_point(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        sites: &[usize],
        bands: usize,
        from: usize,
        scratch: &mut [f32],
        mut t: Option<&mut [f64; MAX_SITES]>,
        mut margin: Option<&mut [f64; MAX_SITES]>,
    ) -> Option<f64> {
        let geo = self.geo;
        let (na, nb) = (geo.angles_deg.len(), geo.bands_nm.len());
        let span = bands - from;
        // Scoring a grid point takes the search's bands; seating sites, more of them.
        let max_bands = if t.is_some() {
            SEAT_BANDS
        } else {
            SEARCH_BANDS
        };
        let stride = span.div_ceil(max_bands).max(1);
        let picked: heapless::Vec<usize, SEAT_BANDS> = (from..bands).step_by(stride).collect();
        let nbs = picked.len();
        // Films and passband damping per (angle, band).
        let mut films: heapless::Vec<(FilmAtAngle, f64, f64), { SEARCH_ANGLES * SEAT_BANDS }> =
            heapless::Vec::new();
        for a in 0..na.min(SEARCH_ANGLES) {
            for &b in &picked {
                let l = geo.bands_nm[b] + self.shift_nm;
                let n = kind.eval(p, l * 1e-3).0;
                if !n.is_finite() {
                    return None;
                }
                let deg = geo.angles_deg[a] + self.stage_deg;
                let f = FilmAtAngle::new(self.indices(n, l), deg, geo.polarization)?;
                let k = 4.0 * core::f64::consts::PI * f.kz_film / l;
                let s_l = geo.fwhm_nm[b] / 2.354_82;
                let _ = films.push((f, k, s_l / l));
            }
        }
        let nv = films.len();
        let [t_lo, t_hi] = geo.thickness_range_nm;
        let k_max = films.iter().map(|f| f.1).fold(0.0, f64::max);
        let mut h = 0.5 / k_max.max(1e-9);
        let mut count = ((t_hi - t_lo) / h) as usize + 1;
        if count > MAX_DICTIONARY {
            count = MAX_DICTIONARY;
            h = (t_hi - t_lo) / (count - 1) as f64;
        }
        if scratch.len() < count * nv {
            return None;
        }
        // Half the shortest order step (where another order's basin begins).
        let l_min = geo.bands_nm.iter().copied().fold(f64::INFINITY, f64::min);
        let excluded_nm = l_min / (4.0 * kind.eval(p, l_min * 1e-3).0);
        let model = |f: &(FilmAtAngle, f64, f64), d: f64| -> f64 {
            let ph = f.1 * d;
            let damp = libm::exp(-0.5 * (ph * f.2) * (ph * f.2));
            f.0.reflectance_at_cos(damp * libm::cos(ph + f.0.phase_offset()))
        };
        // The dictionary, row by row of thickness: each column's phase advances by a
        // rotation and its passband damping by a ratio that itself shrinks geometrically,
        // so no row needs a cosine or an exponential.
        let mut m2 = [0.0f64; MAX_DICTIONARY];
        // Each column's state as arrays (cosine, sine, damping, its ratio and the ratio's
        // ratio; the rotation's cosine and sine; each polarisation's `(A, B, E)`), so that a
        // row's columns are computed in vector instructions.
        let mut st = [[0.0f64; COLUMNS]; 5];
        let mut rot = [[0.0f64; COLUMNS]; 2];
        let mut terms = [[[0.0f64; COLUMNS]; 3]; 2];
        for (j, f) in films.iter().enumerate() {
            let (p0, dp, s2) = (f.1 * t_lo, f.1 * h, f.2 * f.2);
            let psi = f.0.phase_offset();
            st[0][j] = libm::cos(p0 + psi);
            st[1][j] = libm::sin(p0 + psi);
            st[2][j] = libm::exp(-0.5 * s2 * p0 * p0);
            st[3][j] = libm::exp(-0.5 * s2 * (2.0 * p0 * dp + dp * dp));
            st[4][j] = libm::exp(-s2 * dp * dp);
            rot[0][j] = libm::cos(f.1 * h);
            rot[1][j] = libm::sin(f.1 * h);
            for (pol, t) in terms.iter_mut().enumerate() {
                (t[0][j], t[1][j], t[2][j]) = f.0.cos_terms(pol);
            }
        }
        let rows = &mut scratch[..count * nv];
        let m2_rows = &mut m2[..count];
        crate::simd::wide(
            true,
            #[inline(always)]
            || {
                if geo.polarization == Polarization::Unpolarized {
                    dictionary_rows::<2>(rows, nv, m2_rows, &mut st, &rot, &terms);
                } else {
                    dictionary_rows::<1>(rows, nv, m2_rows, &mut st, &rot, &terms);
                }
            },
        );
        let mut total = 0.0;
        let mut y = [0.0f32; SEARCH_ANGLES * SEAT_BANDS];
        for &k in sites {
            if !self.usable[k] {
                continue;
            }
            let mut y2 = 0.0;
            let mut missing = false;
            for a in 0..na.min(SEARCH_ANGLES) {
                for (jb, &b) in picked.iter().enumerate() {
                    let v = self.measured(nb, k, a, b) as f32;
                    y[a * nbs + jb] = v;
                    if !v.is_finite() {
                        missing = true;
                    }
                    y2 += f64::from(v) * f64::from(v);
                }
            }
            if missing {
                // Fill a missing value with the site's mean: it adds a constant to every
                // thickness's score.
                let (mut s, mut c) = (0.0, 0);
                for v in &y[..nv] {
                    if v.is_finite() {
                        s += f64::from(*v);
                        c += 1;
                    }
                }
                let mean = if c > 0 { (s / c as f64) as f32 } else { 0.0 };
                y2 = 0.0;
                for v in &mut y[..nv] {
                    if !v.is_finite() {
                        *v = mean;
                    }
                    y2 += f64::from(*v) * f64::from(*v);
                }
            }
            let mut sses = [f64::INFINITY; MAX_DICTIONARY];
            crate::simd::wide(
                true,
                #[inline(always)]
                || {
                    for (i, sse) in sses.iter_mut().enumerate().take(count) {
                        *sse = m2[i] - 2.0 * dot(&scratch[i * nv..(i + 1) * nv], &y[..nv]) + y2;
                    }
                },
            );
            let mut best = (f64::INFINITY, 0usize);
            for (i, &sse) in sses.iter().enumerate().take(count) {
                if sse < best.0 {
                    best = (sse, i);
                }
            }
            if let Some(m) = margin.as_deref_mut() {
                // The best thickness outside the chosen one's basin (half the shortest
                // order step either side): how much worse it fits, in noise units.
                let far = libm::ceil(excluded_nm / h) as usize;
                let alt = sses
                    .iter()
                    .enumerate()
                    .take(count)
                    .filter(|&(i, _)| i.abs_diff(best.1) > far)
                    .map(|(_, &v)| v)
                    .fold(f64::INFINITY, f64::min);
                m[k] = (alt - best.0) * self.noise.site_weight(k);
            }
            if t.is_none() {
                // Scoring a grid point: the minimum between dictionary rows from the
                // parabola through the best row and its neighbours.
                let i = best.1;
                let mut sse = best.0;
                if i > 0 && i + 1 < count {
                    let (a, c) = (sses[i - 1], sses[i + 1]);
                    let curv = a - 2.0 * sse + c;
                    if curv > 0.0 {
                        sse = (sse - (c - a) * (c - a) / (8.0 * curv)).max(0.0);
                    }
                }
                total += sse * self.noise.site_weight(k);
                continue;
            }
            // Seating a site: two Gauss-Newton steps on the thickness.
            let mut d = t_lo + h * best.1 as f64;
            let mut sse = best.0;
            for _ in 0..2 {
                let (mut jj, mut jr, mut s2) = (0.0f64, 0.0f64, 0.0f64);
                for (f, v) in films.iter().zip(&y[..nv]) {
                    let m = model(f, d);
                    let dm = (model(f, d + 0.01) - m) / 0.01;
                    let r = f64::from(*v) - m;
                    jj += dm * dm;
                    jr += dm * r;
                    s2 += r * r;
                }
                sse = s2;
                if jj <= 0.0 {
                    break;
                }
                let step = (jr / jj).clamp(-h, h);
                let d_new = (d + step).clamp(t_lo, t_hi);
                let s_new: f64 = films
                    .iter()
                    .zip(&y[..nv])
                    .map(|(f, v)| {
                        let r = f64::from(*v) - model(f, d_new);
                        r * r
                    })
                    .sum();
                if s_new < sse {
                    d = d_new;
                    sse = s_new;
                } else {
                    break;
                }
            }
            if let Some(t) = t.as_deref_mut() {
                t[k] = d;
            }
            total += sse * self.noise.site_weight(k);
        }
        Some(total)
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

#[cfg(test)]
mod tests {
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
