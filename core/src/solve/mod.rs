//! The streaming estimator: one shared film index and a thickness per pixel, solved with
//! fixed per-pixel memory while the sweep streams past.
//!
//! How the evidence flows (each step a pure function of state the caller owns):
//!
//! 1. [`crate::track`] finds each pixel's extrema at each angle as the bands stream.
//! 2. At the end of each angle, [`index`] pools every pixel's extremum shifts between the
//!    first angle and this one into a histogram of wavelength ratios (one ratio per
//!    pixel and same-kind extremum pair): its mode is the one index all pixels share
//!    (method.md eq. 12 with every pixel voting, robust to the pixels whose fringes were
//!    matched wrongly). This is only the starting point.
//! 3. Once an index exists, [`order`] gives each pixel its integer interference order from its
//!    extrema at two angles (the whole lists for the index's sample, the last four of each
//!    angle and each list's count for the others, [`extrema`]; parity from the model's
//!    reflection phase: half orders for a film above the substrate), with neighbours
//!    breaking ties, and so a first thickness.
//! 4. From then on every band sample adds to a few per-pixel Gauss-Newton sums ([`refine`]):
//!    the full spectrum, not just its extrema, pins the thickness to a fraction of a nm, and
//!    the sums' cross terms, pooled over all pixels (Schur complement), move the shared index.
//!    Two more sums score the neighbouring orders, so a wrong order shows up as a better fit
//!    one order away: that pixel is flagged, never reported.
//!
//! [`shard`] holds the per-pixel state of a band of rows (the pipeline gives each core one)
//! and [`sweep`] the global state and the reductions between shards. Imports point one way:
//! [`sweep`] drives shards; a shard reads the solver's read-only [`context`] (the [`spec`]
//! among it) and sends up [`sums`], and knows nothing of the solver.

pub mod context;
pub mod extrema;
pub mod fit_row;
pub mod index;
pub mod order;
pub mod refine;
pub mod sample;
pub mod shard;
pub mod spec;
pub mod sums;
pub mod sweep;
#[cfg(test)]
mod tests;

pub use context::SweepContext;
pub use shard::{state_bytes_per_pixel, tracker_blocks, PixelResult, PixelState, Shard};
pub use spec::{SolverOptions, SweepSpec};
pub use sweep::{AngleReport, SweepSolver};

/// Why a pixel has no thickness, or what to know about the one it has (bit flags).
pub mod flags {
    /// No interference extremum inside the band at any angle: the film is too thin (or too
    /// index-matched) for fringes to be seen.
    pub const NO_FRINGE: u16 = 1 << 0;
    /// Two interference orders explain the extrema about equally well and no neighbour
    /// decided it.
    pub const AMBIGUOUS_ORDER: u16 = 1 << 1;
    /// More than a tenth of the samples were saturated (or 255 or more of them: the count
    /// stops there, [`crate::solve::fit_row::BAD_COUNT_MAX`]).
    pub const SATURATED: u16 = 1 << 2;
    /// More than a tenth of the samples had no usable white reference (dead pixel; or 255
    /// or more of them, as for [`SATURATED`]).
    pub const DEAD: u16 = 1 << 3;
    /// The thickness is outside the search range.
    pub const OUT_OF_RANGE: u16 = 1 << 4;
    /// The full-spectrum fit is much worse than the image's typical fit.
    pub const POOR_FIT: u16 = 1 << 5;
    /// A neighbouring order fits the full spectrum better than the chosen one.
    pub const ORDER_REJECTED: u16 = 1 << 6;
    /// More extrema than the tracker can hold at one angle.
    pub const TRACKER_OVERFLOW: u16 = 1 << 7;
    /// Only extrema were available (no full-spectrum refinement: too few angles).
    pub const NOT_REFINED: u16 = 1 << 8;
    /// The order was taken from a neighbour.
    pub const ORDER_FROM_NEIGHBOUR: u16 = 1 << 9;
    /// The film model does not explain the image's spectra (fit residual well above the
    /// noise): the index, so every thickness, is unreliable.
    pub const MODEL_MISMATCH: u16 = 1 << 10;
    /// Some samples had no usable value (a row lost on the camera link, a bad reference
    /// sample), too few to make the pixel [`DEAD`]: the thickness stands, but is worth a look.
    pub const MISSING_SAMPLES: u16 = 1 << 11;
    /// No fringe pair: the thickness started from the global (index, thickness) search on
    /// a pixel sample's full spectra ([`super::sample`]) and was refined on the pixel's own full spectrum.
    pub const FROM_SPECTRUM_SEARCH: u16 = 1 << 12;
    /// The thickness is too uncertain to report: its 1-sigma from the full-spectrum fit
    /// (the pixel's residual over `sqrt(sum J_d^2)`) exceeds
    /// [`super::shard::MAX_THICKNESS_SIGMA_NM`] (faint fringes under heavy noise).
    pub const IMPRECISE: u16 = 1 << 13;

    /// Flags that make the thickness unreliable (NaN in the map).
    pub const INVALID: u16 = NO_FRINGE
        | AMBIGUOUS_ORDER
        | SATURATED
        | DEAD
        | OUT_OF_RANGE
        | POOR_FIT
        | ORDER_REJECTED
        | MODEL_MISMATCH
        | IMPRECISE;

    /// Names of the flags, for reports.
    pub const NAMES: [(u16, &str); 14] = [
        (NO_FRINGE, "no_fringe"),
        (AMBIGUOUS_ORDER, "ambiguous_order"),
        (SATURATED, "saturated"),
        (DEAD, "dead"),
        (OUT_OF_RANGE, "out_of_range"),
        (POOR_FIT, "poor_fit"),
        (ORDER_REJECTED, "order_rejected"),
        (TRACKER_OVERFLOW, "tracker_overflow"),
        (NOT_REFINED, "not_refined"),
        (ORDER_FROM_NEIGHBOUR, "order_from_neighbour"),
        (MODEL_MISMATCH, "model_mismatch"),
        (MISSING_SAMPLES, "missing_samples"),
        (FROM_SPECTRUM_SEARCH, "from_spectrum_search"),
        (IMPRECISE, "imprecise"),
    ];
}

/// The film index model the solver works with: Cauchy
/// `n = a + b_um2 / lambda_um^2 + c_um4 / lambda_um^4` (`b_um2 = c_um4 = 0`: a constant
/// index; `c_um4 = 0`: two terms), or a one-pole Sellmeier ([`Pole`]) when `pole` is set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexModel {
    /// Constant term.
    pub a: f64,
    /// Dispersion term, um^2.
    pub b_um2: f64,
    /// Second dispersion term, um^4.
    pub c_um4: f64,
    /// A one-pole Sellmeier model, which replaces the Cauchy terms when set (the basis
    /// functions, [`IndexModel::to_basis`] and its kin, serve Cauchy models only).
    pub pole: Option<Pole>,
}

/// One-pole Sellmeier: `n^2 = a + s lambda^2 / (lambda^2 - l_um^2)`, lambda in um.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pole {
    /// Constant term of `n^2` (1 for the classic form).
    pub a: f64,
    /// Oscillator strength.
    pub s: f64,
    /// Resonance wavelength, um.
    pub l_um: f64,
}

/// Reference wavelength of the index basis ([`IndexModel::to_basis`]), nm.
pub const BASIS_NM: f64 = 550.0;

impl IndexModel {
    /// A constant index.
    pub const fn constant(n: f64) -> Self {
        Self {
            a: n,
            b_um2: 0.0,
            c_um4: 0.0,
            pole: None,
        }
    }

    /// A two-term Cauchy model.
    pub const fn cauchy(a: f64, b_um2: f64) -> Self {
        Self {
            a,
            b_um2,
            c_um4: 0.0,
            pole: None,
        }
    }

    /// The model of an optics dispersion: constant, Cauchy, or a Sellmeier with one pole
    /// (`None` for more poles or a table).
    pub fn from_dispersion(d: crate::optics::Dispersion) -> Option<Self> {
        use crate::optics::Dispersion as D;
        match d {
            D::Constant { n } => Some(Self::constant(n)),
            D::Cauchy { a, b_um2, c_um4 } => Some(Self {
                a,
                b_um2,
                c_um4,
                pole: None,
            }),
            D::Sellmeier { a, b, c_um } => {
                if b[1] != 0.0 || b[2] != 0.0 {
                    return None;
                }
                Some(Self {
                    a: 0.0,
                    b_um2: 0.0,
                    c_um4: 0.0,
                    pole: Some(Pole {
                        a,
                        s: b[0],
                        l_um: c_um[0],
                    }),
                })
            }
            D::Table { .. } => None,
        }
    }

    /// The index at `wavelength_nm`.
    #[inline]
    pub fn at(&self, wavelength_nm: f64) -> f64 {
        let l = wavelength_nm * 1e-3;
        let l2 = l * l;
        if let Some(p) = self.pole {
            return libm::sqrt(p.a + p.s * l2 / (l2 - p.l_um * p.l_um));
        }
        self.a + self.b_um2 / l2 + self.c_um4 / (l2 * l2)
    }

    /// Terms the model uses: 1 (constant), 2 or 3 (a Sellmeier pole: 2, or 3 with a
    /// constant other than 1).
    pub fn terms(&self) -> usize {
        if let Some(p) = self.pole {
            return if p.a == 1.0 { 2 } else { 3 };
        }
        if self.c_um4 != 0.0 {
            3
        } else if self.b_um2 != 0.0 {
            2
        } else {
            1
        }
    }

    /// The basis variable of `wavelength_nm`: `u = (550 nm / lambda)^2 - 1`, 0 at 550 nm and
    /// within +-0.8 over the visible, so that the normal equations of `(1, u, u^2)` are well
    /// conditioned (those of `(1, lambda^-2, lambda^-4)` are not).
    #[inline]
    pub fn basis_u(wavelength_nm: f64) -> f64 {
        let s = BASIS_NM / wavelength_nm;
        s * s - 1.0
    }

    /// The same model as `n = p0 + p1 u + p2 u^2` ([`IndexModel::basis_u`]): `p0` is the
    /// index at 550 nm.
    pub fn to_basis(&self) -> [f64; 3] {
        if self.pole.is_some() {
            // The model's second-order expansion in `u` at 550 nm (`u = 0`), by central
            // differences: what an index step between two models means for the solver.
            let at_u = |u: f64| self.at(BASIS_NM / libm::sqrt(1.0 + u));
            let h = 0.05;
            let (m, p0, p) = (at_u(-h), at_u(0.0), at_u(h));
            return [p0, (p - m) / (2.0 * h), (p - 2.0 * p0 + m) / (2.0 * h * h)];
        }
        let l0 = BASIS_NM * 1e-3;
        let (b, c) = (self.b_um2 / (l0 * l0), self.c_um4 / (l0 * l0 * l0 * l0));
        [self.a + b + c, b + 2.0 * c, c]
    }

    /// The inverse of [`IndexModel::to_basis`].
    pub fn from_basis(p: [f64; 3]) -> Self {
        let l0 = BASIS_NM * 1e-3;
        let (l2, l4) = (l0 * l0, l0 * l0 * l0 * l0);
        let c = p[2];
        let b = p[1] - 2.0 * c;
        Self {
            a: p[0] - b - c,
            b_um2: b * l2,
            c_um4: c * l4,
            pole: None,
        }
    }

    /// The model moved by `x` in basis coefficients ([`IndexModel::to_basis`]).
    pub fn moved(&self, x: [f64; 3]) -> Self {
        let p = self.to_basis();
        Self::from_basis([p[0] + x[0], p[1] + x[1], p[2] + x[2]])
    }

    /// The model with only its first `terms` basis coefficients (the rest zero).
    pub fn truncated(&self, terms: usize) -> Self {
        let mut p = self.to_basis();
        for v in p.iter_mut().skip(terms.max(1)) {
            *v = 0.0;
        }
        Self::from_basis(p)
    }

    /// As an optics dispersion.
    pub fn dispersion(&self) -> crate::optics::Dispersion {
        if let Some(p) = self.pole {
            return crate::optics::Dispersion::Sellmeier {
                a: p.a,
                b: [p.s, 0.0, 0.0],
                c_um: [p.l_um, 0.0, 0.0],
            };
        }
        match self.terms() {
            1 => crate::optics::Dispersion::constant(self.a),
            _ => crate::optics::Dispersion::Cauchy {
                a: self.a,
                b_um2: self.b_um2,
                c_um4: self.c_um4,
            },
        }
    }
}

#[cfg(test)]
mod model_tests {
    use super::*;

    #[test]
    fn basis_round_trips_and_agrees_with_the_cauchy_form() {
        let m = IndexModel {
            a: 2.266,
            b_um2: 0.0258,
            c_um4: 0.0032,
            pole: None,
        };
        let p = m.to_basis();
        let back = IndexModel::from_basis(p);
        for l in [420.0, 550.0, 720.0] {
            let u = IndexModel::basis_u(l);
            let via_basis = p[0] + p[1] * u + p[2] * u * u;
            assert!((via_basis - m.at(l)).abs() < 1e-12, "{l}");
            assert!((back.at(l) - m.at(l)).abs() < 1e-12, "{l}");
        }
        assert!((p[0] - m.at(550.0)).abs() < 1e-12);
    }
}
