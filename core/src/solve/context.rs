//! What the shards read of the sweep's state at an angle's phases: [`SweepContext`], owned by
//! the solver (which derefs to it) and read-only to everything else. Shards take it, never
//! the solver, so that the solver drives shards and not the other way round, and a
//! pipeline can hand its workers a snapshot of it instead of the whole solver.

use crate::optics::{FilmAtAngle, Indices};

use super::index::{PairGeometry, RatioWindows};
use super::spec::SweepSpec;
use super::IndexModel;

/// A fit residual above this many times the pixels' noise (plus the floor) means the film
/// model does not explain the spectra.
pub const MISMATCH_RATIO: f64 = 1.5;
/// Absolute allowance of the mismatch test (reflectance).
pub const MISMATCH_FLOOR: f64 = 0.001;
/// An index step above this at an angle's end makes every pixel choose its order again.
pub const REORDER_INDEX_STEP: f64 = 0.01;

/// The sweep's state as the shards read it: the sweep's spec, the current and next index,
/// the angle pair's geometry and ratio window, and the image-wide statistics of the last
/// angle end. The solver updates it between the angle-end phases; each phase reads it as it
/// stands then.
#[derive(Clone, Debug)]
pub struct SweepContext {
    pub(super) spec: SweepSpec,
    pub(super) index: Option<IndexModel>,
    /// Covariance of the index's basis coefficients ([`IndexModel::to_basis`]; zero beyond
    /// the model's terms), when an estimate gave one: its `(0, 0)` is the index sigma's
    /// square.
    pub(super) index_cov: Option<[[f64; 3]; 3]>,
    pub(super) anchor_deg: Option<f64>,
    pub(super) angle_deg: f64,
    pub(super) pair_geom: Option<PairGeometry>,
    pub(super) window: Option<RatioWindows>,
    pub(super) rms_median: Option<f32>,
    pub(super) noise_median: Option<f32>,
    pub(super) pending_dp: [f64; 3],
    pub(super) next_index: Option<IndexModel>,
    pub(super) residual_sigma: Option<f64>,
    /// Whether the index is held for the sweep (the solver's `with_held_index`).
    pub(super) held_index: bool,
    /// Whether an external index was ever given (then it, not the extremum shifts, is judged).
    pub(super) external_index: bool,
}

impl SweepContext {
    /// The state before a sweep of `spec`, from the index `prior` if any.
    pub(super) fn new(spec: SweepSpec, prior: Option<IndexModel>) -> Self {
        Self {
            spec,
            index: prior,
            index_cov: None,
            anchor_deg: None,
            angle_deg: f64::NAN,
            pair_geom: None,
            window: None,
            rms_median: None,
            noise_median: None,
            pending_dp: [0.0; 3],
            next_index: None,
            residual_sigma: None,
            held_index: false,
            external_index: false,
        }
    }

    /// The sweep's description.
    pub fn spec(&self) -> &SweepSpec {
        &self.spec
    }

    /// The current index model, if one has been estimated.
    pub fn index(&self) -> Option<IndexModel> {
        self.index
    }

    /// Standard error of the index.
    pub fn index_sigma(&self) -> f64 {
        self.index_cov
            .map_or(f64::INFINITY, |c| libm::sqrt(c[0][0]))
    }

    /// Covariance of the index's basis coefficients (`p0` the index at 550 nm, then the
    /// dispersion terms; zero beyond the model's terms), when an estimate gave one: what the
    /// index's own uncertainty adds to each pixel's thickness ([`super::refine::GnSums::thickness_sigma_nm`]).
    /// `None` when unknown or not finite.
    pub fn index_covariance(&self) -> Option<[[f64; 3]; 3]> {
        self.index_cov
            .filter(|c| c.iter().flatten().all(|v| v.is_finite()))
    }

    /// The typical per-pixel RMS residual of the full-spectrum fit (the noise level).
    pub fn residual_sigma(&self) -> Option<f64> {
        self.residual_sigma
    }

    /// The reference (first) angle, degrees.
    pub fn anchor_deg(&self) -> Option<f64> {
        self.anchor_deg
    }

    /// The current angle, degrees.
    pub fn angle_deg(&self) -> f64 {
        self.angle_deg
    }

    /// The pair geometry of the current angle against the reference, if votes are taken.
    pub fn pair_geometry(&self) -> Option<&PairGeometry> {
        self.pair_geom.as_ref()
    }

    /// The accepted ratio windows of the current pair.
    pub fn ratio_window(&self) -> Option<&RatioWindows> {
        self.window.as_ref()
    }

    /// The median RMS residual of the last angle (for outlier rejection).
    pub fn rms_median(&self) -> Option<f32> {
        self.rms_median
    }

    /// The index step decided at this angle's end, in basis coefficients
    /// ([`IndexModel::to_basis`]).
    pub fn pending_index_step(&self) -> [f64; 3] {
        self.pending_dp
    }

    /// The index model shards must use in `update` (the one after this angle).
    pub fn next_index(&self) -> Option<IndexModel> {
        self.next_index
    }

    /// Order offset of the peaks (0 or 1/2) at `incidence_deg` with index `index`.
    pub fn peak_offset(&self, index: IndexModel, incidence_deg: f64) -> f64 {
        if !self.spec.options.half_order {
            return 0.0;
        }
        let mid = self.spec.bands_nm[self.spec.bands_nm.len() / 2];
        FilmAtAngle::new(
            Indices {
                ambient: self.spec.ambient_index,
                film: index.at(mid),
                substrate: self.spec.substrate.index_at(mid),
                substrate_k: self.spec.substrate.extinction_at(mid),
                back_face: self.spec.back_face,
            },
            incidence_deg,
            self.spec.polarization,
        )
        .map_or(0.0, |f| f.peak_phase_offset())
    }

    pub(super) fn band_span_nm(&self) -> [f64; 2] {
        let b = &self.spec.bands_nm;
        let (lo, hi) = b
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &l| {
                (lo.min(l), hi.max(l))
            });
        [lo, hi]
    }

    /// The image's typical noise (median of the pixels' own estimates at the last angle).
    pub fn noise_sigma(&self) -> Option<f32> {
        self.noise_median
    }

    /// Whether the index moved so much at this angle's end (more than
    /// [`REORDER_INDEX_STEP`]) that every pixel chooses its order again (its sums restart).
    pub fn reorders(&self) -> bool {
        libm::fabs(self.pending_dp[0]) > REORDER_INDEX_STEP
    }

    /// Whether the full-spectrum fit is much worse than the noise: residual RMS above
    /// [`MISMATCH_RATIO`] times the pixels' median noise plus [`MISMATCH_FLOOR`]. The film
    /// model (index, dispersion) then does not explain the spectra: every pixel is flagged
    /// [`super::flags::MODEL_MISMATCH`] and its confidence scaled down.
    pub fn model_mismatch(&self) -> bool {
        if self.held_index || self.external_index {
            // A held or external index was judged where it was fitted (the full spectra of a pixel
            // sample, against their own noise, [`super::sample`]); the pixels' typical
            // residual here also carries the per-pixel model's quadrature error, which a
            // thick, high-index film under a wide passband makes larger than the noise.
            return false;
        }
        match (self.residual_sigma, self.noise_median) {
            (Some(r), Some(n)) => r > MISMATCH_RATIO * f64::from(n) + MISMATCH_FLOOR,
            _ => false,
        }
    }
}
