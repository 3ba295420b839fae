//! The index's reported sigma: marginal over every nuisance term, each held to what a real
//! rig keeps without it showing ([`TOLERANCE`]), with the thicknesses eliminated.

use super::noise::median;
#[cfg(doc)]
use super::{Geometry, SampleFit};
use super::{ModelKind, Nodes, Problem, L0_UM, MAX_SITES, NOISE_ANGLES};
use crate::optics::Polarization;

/// What [`Problem::marginal_n550_sigma`] finds: the index's standard error at 550 nm and
/// the sites' thickness share ([`SampleFit::thickness_share`]), both before scaling by the
/// fit's reduced chi-square.
#[derive(Clone, Copy, Debug)]
pub(super) struct Marginal {
    pub(super) n550_sigma: f64,
    pub(super) thickness_share: f64,
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

/// The information matrix over the marginal's parameters.
type M = nalgebra::SMatrix<f64, MARGINAL, MARGINAL>;

/// The parameters the marginal keeps and the samples it is made on
/// ([`Problem::marginal_layout`]).
struct Layout {
    /// Whether each angle's reflectance scale and offset are in play.
    per_angle: bool,
    /// Which of the [`TERMS`] are in play.
    on: [bool; TERMS],
    /// The parameters in play, each a slot and its tolerance (0: none).
    keep: heapless::Vec<(usize, f64), MARGINAL>,
    /// Each slot's place among the kept (`usize::MAX`: not kept).
    pos: [usize; MARGINAL],
    /// The usable sites the information is made on.
    chosen: heapless::Vec<usize, MAX_SITES>,
    /// The information is made on every `band_stride`-th band.
    band_stride: usize,
    /// The factor that scales the information up to every usable site and band.
    up: f64,
}

/// The information over the kept parameters (upper triangle), each site's thickness
/// diagonal and its row against the kept parameters ([`Problem::information`]).
struct Information {
    h: [[f64; MARGINAL]; MARGINAL],
    jdd: [f64; MAX_SITES],
    cross: [[f64; MARGINAL]; MAX_SITES],
}

/// The slot of nuisance term `term` (after the index parameters and each angle's two).
fn slot(term: usize) -> usize {
    MARGINAL - TERMS + term
}

impl Problem<'_> {
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
    pub(super) fn marginal_n550_sigma(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        t: &[f64; MAX_SITES],
        tolerance: bool,
    ) -> Option<Marginal> {
        let na = self.geo.angles_deg.len();
        let fitted = self.terms.fitted();
        let per_angle = (fitted || tolerance) && na <= TERM_MAX_ANGLES;
        if fitted && !per_angle {
            return None;
        }
        let np = kind.params();
        let layout = self.marginal_layout(np, per_angle, tolerance);
        let mut info = Information {
            h: [[0.0f64; MARGINAL]; MARGINAL],
            jdd: [0.0; MAX_SITES],
            cross: [[0.0f64; MARGINAL]; MAX_SITES],
        };
        self.information(kind, p, t, &layout, &mut info)?;
        let inv = self.reduced(&layout, &info, tolerance).try_inverse()?;
        let (_, g550) = kind.eval(p, L0_UM);
        let mut var = 0.0;
        for i in 0..np {
            for j in 0..np {
                var += g550[i] * inv[(i, j)] * g550[j];
            }
        }
        let share = thickness_share(&layout, &info, &inv, t);
        (var > 0.0).then(|| Marginal {
            n550_sigma: libm::sqrt(var),
            thickness_share: share,
        })
    }

    /// The marginal's parameters in play (index, each angle's scale and offset, the terms) and the
    /// sites and bands it is made on.
    fn marginal_layout(&self, np: usize, per_angle: bool, tolerance: bool) -> Layout {
        let (na, nb) = (self.geo.angles_deg.len(), self.geo.bands_nm.len());
        let sites = self.usable.len();
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
        Layout {
            per_angle,
            on,
            keep,
            pos,
            chosen,
            band_stride,
            up,
        }
    }

    /// The information over `layout`'s parameters and its sites' thicknesses at `(kind, p)` and
    /// `t`, accumulated into `info` (`None` where a model cannot be evaluated).
    fn information(
        &self,
        kind: ModelKind,
        p: &[f64; 3],
        t: &[f64; MAX_SITES],
        layout: &Layout,
        info: &mut Information,
    ) -> Option<()> {
        let (na, nb) = (self.geo.angles_deg.len(), self.geo.bands_nm.len());
        let d_max = self.thickest(t);
        let np = kind.params();
        let Layout {
            per_angle,
            on,
            pos,
            chosen,
            band_stride,
            ..
        } = layout;
        let Information { h, jdd, cross } = info;
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
        let mut buf = Nodes::new();
        let mut stepped_nodes: [Nodes; 4] = Default::default();
        for a in 0..na {
            let g = self.terms.scale[a.min(NOISE_ANGLES - 1)];
            for b in (0..nb).step_by(*band_stride) {
                let nodes = self.nodes(kind, p, a, b, d_max, &mut buf)?;
                for (out, q) in stepped_nodes.iter_mut().zip(&stepped) {
                    if let Some(q) = q {
                        q.nodes(kind, p, a, b, d_max, out)?;
                    }
                }
                for &k in chosen {
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
                    if *per_angle {
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
        Some(())
    }

    /// The information with the thicknesses eliminated (Schur complement), scaled up to every site
    /// and band, each parameter held to its tolerance when `tolerance` is asked.
    fn reduced(&self, layout: &Layout, info: &Information, tolerance: bool) -> M {
        let Information { h, jdd, cross } = info;
        let dim = layout.keep.len();
        let mut sub = M::identity();
        for i in 0..dim {
            for j in i..dim {
                let mut v = h[i][j];
                for &k in &layout.chosen {
                    if jdd[k] > 0.0 {
                        v -= cross[k][i] * cross[k][j] / jdd[k];
                    }
                }
                sub[(i, j)] = v * layout.up;
                sub[(j, i)] = v * layout.up;
            }
            let held = layout.keep[i].1 * self.geo.rig_tolerance;
            if tolerance && held > 0.0 {
                sub[(i, i)] += 1.0 / (held * held);
            }
        }
        sub
    }
}

/// The median site's thickness error from the parameters' covariance `inv`, relative to its
/// thickness (NaN without a site): the share of a thickness's error common to the map.
fn thickness_share(layout: &Layout, info: &Information, inv: &M, t: &[f64; MAX_SITES]) -> f64 {
    let Information { jdd, cross, .. } = info;
    let dim = layout.keep.len();
    // A site's thickness moves with the parameters by `-cross / jdd` each: its variance
    // from them (a ratio the bands' subsampling leaves alone), relative to the thickness.
    let mut shares: heapless::Vec<f32, MAX_SITES> = heapless::Vec::new();
    for &k in &layout.chosen {
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
    if shares.is_empty() {
        f64::NAN
    } else {
        median(&mut shares)
    }
}
