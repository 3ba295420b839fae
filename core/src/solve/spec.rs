//! What the solver must know about a sweep before it starts.

use heapless::Vec as HVec;

use crate::optics::{BackFace, Dispersion, Polarization};

/// Most bands per angle.
pub const MAX_BANDS: usize = 1024;

/// What the solver must know about a sweep before it starts.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepSpec {
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Band centres in streaming order, nm.
    pub bands_nm: HVec<f64, MAX_BANDS>,
    /// Band FWHM, nm (one per band).
    pub fwhm_nm: HVec<f64, MAX_BANDS>,
    /// Ambient index.
    pub ambient_index: f64,
    /// Substrate index at 550 nm, as reports give it.
    pub substrate_index: f64,
    /// The substrate's index against wavelength, which the model uses (a constant
    /// `substrate_index` for most samples; a glass's Sellmeier formula for a dispersive one).
    pub substrate: Dispersion,
    /// The substrate's back face (`sample.back_face` in a capture).
    pub back_face: BackFace,
    /// Polarisation of the measured light.
    pub polarization: Polarization,
    /// Film index search range.
    pub index_range: [f64; 2],
    /// Thickness search range, nm.
    pub thickness_range_nm: [f64; 2],
    /// The model error the index fit tolerates, RMS reflectance
    /// ([`super::sample::DEFAULT_MODEL_ERROR`]; `[fit] model_error` in a capture).
    pub model_error: f64,
    /// How far the reported index sigma carries the nuisance terms a rig keeps, as a
    /// multiple of [`super::sample::TOLERANCE`] (1; `[fit] rig_tolerance` in a capture; 0:
    /// the statistical sigma under the terms the fit took).
    pub rig_tolerance: f64,
    /// What the solver may use (all on by default; off only to measure what each is worth).
    pub options: SolverOptions,
}

/// The solver's improvements over the published method, each switchable so its worth can be
/// measured (`filmscope eval --ablate ...`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SolverOptions {
    /// Full-spectrum Gauss-Newton refinement of the thickness (off: extrema only).
    pub refine: bool,
    /// The half-order reflection phase of films above the substrate's index (off: integer
    /// orders, as the paper's eq. 9).
    pub half_order: bool,
    /// Neighbours decide orders a pixel alone cannot (off: such pixels stay unresolved).
    pub neighbours: bool,
    /// Extrema placed to a fraction of a band (off: at the band centre).
    pub subband: bool,
    /// About how many pixels keep the shared index's sums, the rest only their own
    /// ([`super::fit_row::IndexSampling`]; 32 bytes a pixel that keeps them): the index's
    /// step is theirs, and so are the ratio votes, the RMS median and the pooled noise.
    /// Every pixel of a sensor with fewer than twice as many.
    pub index_pixels: usize,
    /// The per-sample work and the order search compiled for the widest vector
    /// instructions the CPU has (AVX2 and FMA on x86-64, [`crate::simd::wide`]); off: the
    /// portable build's. The same results bit for bit either way.
    pub wide_simd: bool,
    /// Every pixel's fringe extrema tracked. Off only for a sweep whose every pixel starts
    /// seeded under a held index ([`crate::solve::shard::Shard::seed`]): no order is chosen
    /// from extrema and no index moved by them, so the tracker's work (over half of the
    /// per-sample kernels' time in `filmscope bench`) is skipped, and the image's noise is
    /// the solver's given one ([`crate::solve::sweep::SweepSolver::with_noise`]).
    pub extrema: bool,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            refine: true,
            half_order: true,
            neighbours: true,
            subband: true,
            index_pixels: super::fit_row::INDEX_PIXELS,
            wide_simd: true,
            extrema: true,
        }
    }
}

impl SweepSpec {
    /// The same sweep on the substrate `substrate` (`substrate_index` becomes its index at
    /// 550 nm).
    pub fn with_substrate(mut self, substrate: Dispersion) -> Self {
        self.substrate_index = substrate.index_at(550.0);
        self.substrate = substrate;
        self
    }

    /// The same sweep with the substrate's back face `back_face`.
    pub fn with_back_face(mut self, back_face: BackFace) -> Self {
        self.back_face = back_face;
        self
    }

    /// Wavelength of a fractional band position (linear between band centres).
    #[inline]
    pub fn wavelength_at(&self, band: f32) -> f64 {
        let b = self.bands_nm.as_slice();
        if b.len() < 2 {
            return b.first().copied().unwrap_or(f64::NAN);
        }
        let x = f64::from(band).clamp(0.0, (b.len() - 1) as f64);
        let i = (x as usize).min(b.len() - 2);
        b[i] + (b[i + 1] - b[i]) * (x - i as f64)
    }

    /// `(n_ambient sin theta)^2`.
    pub fn x_of(&self, incidence_deg: f64) -> f64 {
        let s = self.ambient_index * libm::sin(incidence_deg.to_radians());
        s * s
    }

    /// Which pixels keep the shared index's sums ([`super::fit_row::IndexSampling`]).
    pub fn index_sampling(&self) -> super::fit_row::IndexSampling {
        super::fit_row::IndexSampling::for_sensor(
            self.width,
            self.height,
            self.options.index_pixels,
        )
    }

    /// The wavelength range in which the tracker reliably finds extrema (clear of the
    /// smoothing window at either end).
    pub fn reliable_range_nm(&self) -> [f64; 2] {
        let a = self.wavelength_at(crate::track::WINDOW as f32);
        let b = self.wavelength_at(self.last_reliable_band());
        [a.min(b), a.max(b)]
    }

    /// The last band of [`SweepSpec::reliable_range_nm`]: the smoothing window's length
    /// before the last band, never before its first, [`crate::track::WINDOW`] (a sweep of
    /// fewer than `2 WINDOW + 1` bands has that one band: [`crate::track::ExtremaHead`]
    /// counts the range so).
    pub fn last_reliable_band(&self) -> f32 {
        let w = crate::track::WINDOW as f32;
        (self.bands_nm.len() as f32 - 1.0 - w).max(w)
    }
}

/// A sweep of `width` x `height` pixels on the paper's rig (420-720 nm in 2 nm bands, 4 nm
/// FWHM, s-polarised, a film on 1.52 glass), for unit tests.
#[cfg(test)]
pub(crate) fn paper_rig_spec(width: usize, height: usize) -> SweepSpec {
    let mut s = SweepSpec {
        back_face: BackFace::None,
        width,
        height,
        bands_nm: HVec::new(),
        fwhm_nm: HVec::new(),
        ambient_index: 1.0,
        substrate_index: 1.52,
        substrate: Dispersion::constant(1.52),
        polarization: Polarization::S,
        index_range: [1.2, 2.8],
        thickness_range_nm: [30.0, 2000.0],
        model_error: super::sample::DEFAULT_MODEL_ERROR,
        rig_tolerance: 1.0,
        options: SolverOptions::default(),
    };
    for b in 0..151 {
        let _ = s.bands_nm.push(420.0 + 2.0 * f64::from(b));
        let _ = s.fwhm_nm.push(4.0);
    }
    s
}
