//! Full-spectrum refinement with fixed per-pixel memory: Gauss-Newton sums.
//!
//! Once a pixel has a thickness `d` (its linearisation point) and the sweep a shared index
//! model `n(lambda) = p0 + p1 u + p2 u^2` ([`IndexModel::basis_u`]), every band sample `R`
//! adds to the pixel's normal equations for `(d, p)`: with the model `M` and its derivatives
//! `J_d` and `J_n` (so `J_pk = J_n u^k`), the sums `J_d^2`, `J_d J_n u^k` (k < 3),
//! `J_n^2 u^k` (k < 5: every entry of the index block), `J_d r`, `J_n r u^k` and `r^2`
//! (`r = R - M`). Their size does not depend on the number of bands, angles or sweeps. At each
//! angle's end the per-pixel `d` rows are eliminated (Schur complement) to move the shared
//! index, then each `d` steps (the solver's angle end).
//!
//! The model per band is the Airy reflectance averaged over the Gaussian passband by 5-point
//! Gauss-Hermite quadrature, dispersion followed node by node. Two more sums score the
//! thicknesses one order either side, so a wrong order is caught on the full spectrum.

use crate::optics::{
    BackFace, FilmAtAngle, Indices, LossyFilm, Passband, Polarization, HALF_WIDTH_FWHM,
};

use super::IndexModel;

/// Index step for the numerical `d M / d n`.
pub const INDEX_STEP: f64 = 1e-4;

/// Gauss-Hermite nodes and weights (5 points) for the Gaussian passband average.
pub(crate) const GH_X: [f64; 5] = [
    -2.020_182_870_456_086,
    -0.958_572_464_613_819,
    0.0,
    0.958_572_464_613_819,
    2.020_182_870_456_086,
];
pub(crate) const GH_W: [f64; 5] = [
    0.019_953_242_059_046,
    0.393_619_323_152_241,
    0.945_308_720_482_942,
    0.393_619_323_152_241,
    0.019_953_242_059_046,
];
/// The passband is truncated at 1.5 FWHM (3.53 sigma): its variance is 0.9946 of the
/// untruncated Gaussian's.
pub(crate) const TRUNCATED_SIGMA: f64 = 0.997_3;

/// Most nodes of a band's quadrature ([`passband_rule`]).
pub const MAX_BAND_NODES: usize = 33;

/// Fewest Simpson nodes once the 5 Gauss-Hermite ones no longer do.
const MIN_SIMPSON: usize = 17;

/// Phase a Simpson interval may span, radians.
const NODE_PHASE: f64 = 0.3;

/// The quadrature of a Gaussian passband of centre `l0` and `fwhm` over which the film's
/// phase turns by `phase_span` radians (across the truncated band, dispersion included):
/// `(wavelength nm, weight)` nodes and their count. Fringes wider than the band take the 5
/// Gauss-Hermite nodes (they hold the Gaussian's moments: paper sample 3's index came out
/// 0.0005 high with 5 Simpson nodes, 0.0002 with these); faster ones a composite Simpson
/// sum over the truncated band ([`Passband`]) with an interval per [`NODE_PHASE`]: there
/// Gauss-Hermite, blind to the truncation, errs by up to 0.01 in reflectance (a 1.6 um TiO2
/// film at 400 nm through 6 nm) whatever its order.
pub fn passband_rule(l0: f64, fwhm: f64, phase_span: f64) -> ([(f64, f64); MAX_BAND_NODES], usize) {
    let mut out = [(l0, 1.0); MAX_BAND_NODES];
    let sigma = fwhm / 2.354_82 * TRUNCATED_SIGMA;
    if sigma.is_nan() || sigma <= 0.0 {
        return (out, 1);
    }
    let simpson = if phase_span.is_finite() {
        libm::ceil(phase_span / NODE_PHASE) as usize + 1
    } else {
        MAX_BAND_NODES
    };
    if simpson <= GH_X.len() {
        for (o, (x, w)) in out.iter_mut().zip(GH_X.iter().zip(&GH_W)) {
            *o = (
                l0 + core::f64::consts::SQRT_2 * sigma * x,
                w / libm::sqrt(core::f64::consts::PI),
            );
        }
        return (out, GH_X.len());
    }
    let band = Passband::gaussian_with_nodes(l0, fwhm, simpson.clamp(MIN_SIMPSON, MAX_BAND_NODES));
    let mut count = 0;
    for (o, nd) in out.iter_mut().zip(band.nodes()) {
        *o = nd;
        count += 1;
    }
    (out, count)
}

/// The phase a film of `d_nm` turns by across the truncated passband of `(l0, fwhm)`, from
/// `phase_per_nm(l)` (`4 pi n cos(theta) / l` at wavelength `l`; `None` where no wave
/// propagates): the group index's, not the phase index's, so dispersion counts.
pub fn passband_phase_span(
    l0: f64,
    fwhm: f64,
    d_nm: f64,
    phase_per_nm: impl Fn(f64) -> Option<f64>,
) -> f64 {
    let half = HALF_WIDTH_FWHM * fwhm;
    match (phase_per_nm(l0 - half), phase_per_nm(l0 + half)) {
        (Some(a), Some(b)) => libm::fabs(a - b) * d_nm,
        _ => f64::INFINITY,
    }
}

/// The film's extinction coefficient's Urbach tail, nm: `k(l) = k450 exp((450 - l) / tail)`
/// ([`FilmTerms::film_k`] is `k` at 450 nm).
pub const ABSORPTION_TAIL_NM: f64 = 90.0;

/// `k(l) / k(450 nm)` ([`ABSORPTION_TAIL_NM`]).
pub fn absorption_shape(l_nm: f64) -> f64 {
    libm::exp((450.0 - l_nm) / ABSORPTION_TAIL_NM)
}

/// What the sample fit found the film and the light to be beyond a clear film in one
/// polarisation, for the per-pixel model to carry: without them a pixel's thickness is fitted
/// to a model the sample has shown wrong (an absorbing film's return from a bare back face,
/// lost on a thick pixel's way through it, picks the wrong order).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FilmTerms {
    /// The film's extinction coefficient at 450 nm, its tail to the blue
    /// [`ABSORPTION_TAIL_NM`] (0: a clear film).
    pub film_k: f64,
    /// The share of the other polarisation a leaking polariser lets through (0: none).
    pub leak: f64,
}

impl FilmTerms {
    /// A clear film in the light's own polarisation.
    pub const NONE: Self = Self {
        film_k: 0.0,
        leak: 0.0,
    };

    /// Whether the model needs more than the clear film's one polarisation.
    pub fn any(self) -> bool {
        self.film_k > 0.0 || self.leak > 0.0
    }
}

/// One quadrature node of a band: the stack at the node's wavelength.
#[derive(Clone, Copy, Debug)]
struct Node {
    weight: f64,
    phase_per_nm: f64,
    /// The film's [`FilmAtAngle::phase_offset`] (0 on a clear substrate; with
    /// [`FilmTerms`], in the film's coefficients).
    phase0: f64,
    film: NodeFilm,
}

/// A node's film.
#[derive(Clone, Copy, Debug)]
enum NodeFilm {
    /// A clear film in the light's own polarisation.
    Clear(FilmAtAngle),
    /// With the sample's [`FilmTerms`]: the film absorbing, the other polarisation leaking in.
    Terms(LossyFilm),
}

impl Node {
    /// The node's weighted reflectance and its weighted thickness derivative for the clear
    /// film `f` (its own), at the phase (its offset included) whose cosine and sine are `c`
    /// and `s`.
    #[inline]
    fn clear_model_and_slope(&self, f: &FilmAtAngle, c: f64, s: f64) -> (f64, f64) {
        let (r, dr_dc) = f.reflectance_and_slope_at_cos(c);
        (
            self.weight * r,
            -self.weight * dr_dc * s * self.phase_per_nm,
        )
    }

    /// The node's weighted reflectance and its weighted thickness derivative for a film of
    /// `thickness_nm`.
    #[inline]
    fn model_and_slope(&self, thickness_nm: f64) -> (f64, f64) {
        match &self.film {
            NodeFilm::Clear(f) => {
                let (s, c) = libm::sincos(self.phase_per_nm * thickness_nm + self.phase0);
                self.clear_model_and_slope(f, c, s)
            }
            NodeFilm::Terms(f) => {
                let (delta, a) = f.round_trip(thickness_nm);
                let (s, c) = libm::sincos(delta);
                let (r, dr_dd, dr_da) = f.reflectance(c, s, a);
                let slope = dr_dd * f.phase_per_nm - dr_da * f.loss_per_nm * a;
                (self.weight * r, self.weight * slope)
            }
        }
    }

    /// The node's reflectance for a film of `thickness_nm`.
    #[inline]
    fn at(&self, thickness_nm: f64) -> f64 {
        match &self.film {
            NodeFilm::Clear(f) => f.reflectance_at_phase(self.phase_per_nm * thickness_nm),
            NodeFilm::Terms(f) => {
                let (delta, a) = f.round_trip(thickness_nm);
                let (s, c) = libm::sincos(delta);
                f.reflectance(c, s, a).0
            }
        }
    }
}

/// A phase stepped knot by knot: the cosine and sine of `phase_per_nm * (d0 + h j) + phase0` at knot
/// `j`, each step a rotation by the knot's phase instead of a sine and a cosine (the
/// rotation's rounding drifts by about 1e-16 a step: 2e-12 over the most knots a band holds,
/// far under the knots' f32).
#[derive(Clone, Copy, Debug, Default)]
struct Phasor {
    c: f64,
    s: f64,
    dc: f64,
    ds: f64,
}

impl Phasor {
    fn new(phase_per_nm: f64, phase0: f64, d0: f64, h: f64) -> Self {
        let (s, c) = libm::sincos(phase_per_nm * d0 + phase0);
        let (ds, dc) = libm::sincos(phase_per_nm * h);
        Self { c, s, dc, ds }
    }

    #[inline]
    fn step(&mut self) {
        (self.c, self.s) = (
            self.c * self.dc - self.s * self.ds,
            self.s * self.dc + self.c * self.ds,
        );
    }
}

/// The model of one band at one angle: the passband-averaged Airy reflectance by 5-point
/// Gauss-Hermite quadrature (within 1e-6 of the 33-node Simpson average for fringes wider than
/// the passband), at the current index and one index step above.
#[derive(Clone, Copy, Debug)]
pub struct BandCoef {
    /// The band's index basis variable ([`IndexModel::basis_u`]).
    pub u: f64,
    nodes: [Node; MAX_BAND_NODES],
    /// The band centre at the current index and one index step above (for `d M / d n` and
    /// the neighbouring orders' misfits, which need no passband detail).
    centre: Node,
    centre_up: Node,
    count: usize,
    /// Where the band's tabulated model sits in the angle's knots, if tabulated.
    table: Option<TableSpan>,
}

/// The tabulated model of one band at one thickness knot and the next: at each, the
/// passband-averaged reflectance, its thickness derivative times the knot spacing (for cubic
/// Hermite interpolation) and its index derivative (linearly interpolated: a Jacobian's small
/// error slows Gauss-Newton a little but cannot bias where it converges, which the residual
/// alone decides). Every knot's values are held twice, by its own record and the one before,
/// so that a sample's interval is one aligned 16-byte read of the value and slope at both
/// ends: all a sample takes unless the index is fitted (read as two 12-byte knots for each of
/// a sample's three positions, the table was most of the per-sample work). The band's last
/// knot holds its own values as the next.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(32))]
pub struct Knot {
    pub(crate) m: [f32; 2],
    pub(crate) slope_h: [f32; 2],
    pub(crate) j_n: [f32; 2],
}

impl Knot {
    /// A knot's own values (the next knot's filled in by [`BandCoef::tabulate`]).
    fn of(m: f64, slope_h: f64, j_n: f64) -> Self {
        let (m, slope_h, j_n) = (m as f32, slope_h as f32, j_n as f32);
        Self {
            m: [m; 2],
            slope_h: [slope_h; 2],
            j_n: [j_n; 2],
        }
    }
}

/// Where one band's knots sit in the angle's table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct TableSpan {
    first: u32,
    count: u32,
    d0: f32,
    inv_h: f32,
}

impl TableSpan {
    /// The band's knots in the angle's table (`None` if the table is too short).
    #[inline]
    pub(crate) fn knots<'k>(&self, knots: &'k [Knot]) -> Option<&'k [Knot]> {
        knots.get(self.first as usize..(self.first + self.count) as usize)
    }

    /// Position of thickness `d` in knot units from the first knot.
    #[inline(always)]
    pub(crate) fn position(&self, d: f32) -> f32 {
        (d - self.d0) * self.inv_h
    }

    /// Knots per nm.
    #[inline(always)]
    pub(crate) fn inv_h(&self) -> f32 {
        self.inv_h
    }

    /// Whether position `x` falls between two knots (false for NaN): then its knot is
    /// `x as usize`, its fraction `x - knot as f32`.
    #[inline(always)]
    pub(crate) fn covers(&self, x: f32) -> bool {
        // `x as usize + 1 < count`, with `count` exact in f32 (at most 2^14).
        x >= 0.0 && x < (self.count - 1) as f32
    }

    /// Knot and fraction of thickness `d`, if it falls inside the table.
    #[inline(always)]
    fn locate(&self, d: f32) -> Option<(usize, f32)> {
        let x = self.position(d);
        self.covers(x).then(|| {
            let i = x as usize;
            (i, x - i as f32)
        })
    }
}

/// The tabulated model of one band at one thickness, in f32 as the table holds it and the
/// sums take it: the fields of [`BandEval`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct SampleModel {
    pub(crate) m: f32,
    pub(crate) j_d: f32,
    pub(crate) j_n: f32,
    pub(crate) m_minus: f32,
    pub(crate) m_plus: f32,
}

impl SampleModel {
    /// From the knots either side of the thickness (`k`, at fraction `u`) and of the
    /// orders either side (`lo`, `hi`: knots and fraction), `inv_h` the band's knots per nm.
    #[inline(always)]
    pub(crate) fn from_knots(
        k: Knot,
        u: f32,
        lo: (Knot, f32),
        hi: (Knot, f32),
        inv_h: f32,
    ) -> Self {
        let (m, slope) = hermite(&k, u);
        Self {
            m,
            j_d: slope * inv_h,
            j_n: k.j_n[0] + (k.j_n[1] - k.j_n[0]) * u,
            m_minus: hermite(&lo.0, lo.1).0,
            m_plus: hermite(&hi.0, hi.1).0,
        }
    }
}

impl From<BandEval> for SampleModel {
    /// In f32, as the sums are kept (the table's values are f32 already).
    #[inline(always)]
    fn from(e: BandEval) -> Self {
        Self {
            m: e.m as f32,
            j_d: e.j_d as f32,
            j_n: e.j_n as f32,
            m_minus: e.m_minus as f32,
            m_plus: e.m_plus as f32,
        }
    }
}

/// Largest phase change (radians) of a band's fastest quadrature node between two knots:
/// cubic Hermite interpolation of a sinusoid at this step errs by about
/// `KNOT_PHASE^4 / 384 = 1e-5` of the fringe amplitude.
pub const KNOT_PHASE: f64 = 0.25;
/// Most knots per band (a 1 um knot spacing would cover 8 mm).
pub const MAX_KNOTS_PER_BAND: usize = 1 << 14;

/// An angle's band models: each band's coefficients (`None` where the model has no
/// propagating wave, or before an index exists) and the knots of those that are tabulated
/// ([`BandCoef::tabulate`]).
#[derive(Clone, Copy, Debug)]
pub struct AngleModels<'a> {
    /// One entry per band.
    pub coefs: &'a [Option<BandCoef>],
    /// The tabulated bands' knots.
    pub knots: &'a [Knot],
    /// Whether the sweep holds its index ([`super::SweepSolver::index_held`]): nothing
    /// steps it, so the samples add neither its sums nor the thickness-index cross terms.
    pub index_held: bool,
}

/// The model of one band at one thickness: reflectance, its thickness and index derivatives,
/// and the reflectance one interference order either side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BandEval {
    /// Model reflectance.
    pub m: f64,
    /// `d M / d thickness`.
    pub j_d: f64,
    /// `d M / d index`.
    pub j_n: f64,
    /// Model one order thinner.
    pub m_minus: f64,
    /// Model one order thicker.
    pub m_plus: f64,
}

impl BandCoef {
    /// Builds the coefficients for films up to `d_max_nm` thick (which sets the passband's
    /// quadrature: [`passband_rule`]), the film absorbing and the polariser leaking as
    /// `terms` says, or `None` where the model has no propagating wave.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        index: IndexModel,
        terms: FilmTerms,
        ambient: f64,
        substrate: f64,
        substrate_k: f64,
        back_face: BackFace,
        polarization: Polarization,
        incidence_deg: f64,
        wavelength_nm: f64,
        fwhm_nm: f64,
        d_max_nm: f64,
    ) -> Option<Self> {
        let indices = |l: f64, dn: f64| Indices {
            ambient,
            film: index.at(l) + dn,
            substrate,
            substrate_k,
            back_face,
        };
        let film_at =
            |l: f64, dn: f64| FilmAtAngle::new(indices(l, dn), incidence_deg, polarization);
        let node = |(l, w): (f64, f64), dn: f64| -> Option<Node> {
            let film = film_at(l, dn)?;
            if !terms.any() {
                return Some(Node {
                    weight: w,
                    phase_per_nm: 4.0 * core::f64::consts::PI * film.kz_film / l,
                    phase0: film.phase_offset(),
                    film: NodeFilm::Clear(film),
                });
            }
            let k = terms.film_k * absorption_shape(l);
            let lossy = LossyFilm::with_leak(
                indices(l, dn),
                k,
                incidence_deg,
                polarization,
                l,
                terms.leak,
            )?;
            Some(Node {
                weight: w,
                phase_per_nm: lossy.phase_per_nm,
                phase0: 0.0,
                film: NodeFilm::Terms(lossy),
            })
        };
        let span = passband_phase_span(wavelength_nm, fwhm_nm, d_max_nm, |l| {
            film_at(l, 0.0).map(|f| 4.0 * core::f64::consts::PI * f.kz_film / l)
        });
        let (rule, count) = passband_rule(wavelength_nm, fwhm_nm, span);
        let first = node(rule[0], 0.0)?;
        let mut nodes = [first; MAX_BAND_NODES];
        for (n, &r) in nodes.iter_mut().zip(&rule).take(count).skip(1) {
            *n = node(r, 0.0)?;
        }
        Some(Self {
            u: IndexModel::basis_u(wavelength_nm),
            nodes,
            centre: node((wavelength_nm, 1.0), 0.0)?,
            centre_up: node((wavelength_nm, 1.0), INDEX_STEP)?,
            count,
            table: None,
        })
    }

    /// Knot spacing and count that tabulate thicknesses `range_nm` ([`KNOT_PHASE`] per knot
    /// at the fastest node, at most [`MAX_KNOTS_PER_BAND`] knots: `None` beyond).
    pub fn knots_for(&self, range_nm: [f64; 2]) -> Option<(f64, usize)> {
        let fastest = self.nodes[..self.count]
            .iter()
            .chain([&self.centre_up])
            .fold(0.0f64, |a, n| a.max(libm::fabs(n.phase_per_nm)));
        let span = range_nm[1] - range_nm[0];
        if !(fastest > 0.0 && span > 0.0 && span.is_finite()) {
            return None;
        }
        let h = KNOT_PHASE / fastest;
        let count = libm::ceil(span / h) as usize + 2;
        (count <= MAX_KNOTS_PER_BAND).then_some((h, count))
    }

    /// The part of `range_nm`'s knot grid ([`BandCoef::knots_for`]) that covers the
    /// thicknesses `within_nm`, clamped to `range_nm` (`None` if they do not meet): a table
    /// of it has the whole range's knots there, so a thickness in both interpolates the same.
    pub fn range_within(&self, range_nm: [f64; 2], within_nm: [f64; 2]) -> Option<[f64; 2]> {
        let (h, count) = self.knots_for(range_nm)?;
        let last = (count - 1) as f64;
        let lo = libm::floor((within_nm[0] - range_nm[0]) / h).max(0.0);
        let hi = libm::ceil((within_nm[1] - range_nm[0]) / h).min(last);
        (lo < hi).then(|| [range_nm[0] + lo * h, range_nm[0] + hi * h])
    }

    /// Tabulates the band's model over thicknesses `range_nm` into `knots` (which must hold
    /// [`BandCoef::knots_for`]'s count), `first` being the knots' offset in the angle's table.
    /// Each knot costs the model's quadrature with its thickness derivative and two
    /// band-centre evaluations for the index derivative, once per angle (a clear film's
    /// phases stepped by a rotation: [`BandCoef::tabulate_clear`]).
    pub fn tabulate(&mut self, range_nm: [f64; 2], first: usize, knots: &mut [Knot]) {
        let Some((h, count)) = self.knots_for(range_nm) else {
            self.table = None;
            return;
        };
        let Some(knots) = knots.get_mut(..count) else {
            self.table = None;
            return;
        };
        let d0 = range_nm[0];
        // Nodes with [`FilmTerms`] are computed from the thickness, not stepped by a rotation
        // of the clear film's phase (every node of a band is of one kind).
        if matches!(self.centre.film, NodeFilm::Terms(_)) {
            for (j, k) in knots.iter_mut().enumerate() {
                let d = d0 + h * j as f64;
                let (m, slope) = self.model_and_slope(d);
                let j_n = (self.centre_up.at(d) - self.centre.at(d)) / INDEX_STEP;
                *k = Knot::of(m, slope * h, j_n);
            }
        } else {
            self.tabulate_clear(d0, h, knots);
        }
        // Each record's next knot: the following record's own.
        for j in 1..knots.len() {
            let next = knots[j];
            let k = &mut knots[j - 1];
            k.m[1] = next.m[0];
            k.slope_h[1] = next.slope_h[0];
            k.j_n[1] = next.j_n[0];
        }
        self.table = Some(TableSpan {
            first: first as u32,
            count: count as u32,
            d0: d0 as f32,
            inv_h: (1.0 / h) as f32,
        });
    }

    /// [`BandCoef::tabulate`]'s knots for a clear film in one polarisation (every node
    /// [`NodeFilm::Clear`]), from `d0` at `h` nm: the phases step from knot to knot by a
    /// rotation, no sine or cosine per knot.
    fn tabulate_clear(&self, d0: f64, h: f64, knots: &mut [Knot]) {
        let nodes = &self.nodes[..self.count];
        let mut at_node = [Phasor::default(); MAX_BAND_NODES];
        for (p, n) in at_node.iter_mut().zip(nodes) {
            *p = Phasor::new(n.phase_per_nm, n.phase0, d0, h);
        }
        let (c, up) = (&self.centre, &self.centre_up);
        let mut centre = Phasor::new(c.phase_per_nm, c.phase0, d0, h);
        let mut centre_up = Phasor::new(up.phase_per_nm, up.phase0, d0, h);
        for k in knots.iter_mut() {
            let (mut m, mut slope) = (0.0, 0.0);
            for (p, n) in at_node.iter_mut().zip(nodes) {
                if let NodeFilm::Clear(f) = &n.film {
                    let (r, dr) = n.clear_model_and_slope(f, p.c, p.s);
                    m += r;
                    slope += dr;
                }
                p.step();
            }
            let j_n = match (&self.centre_up.film, &self.centre.film) {
                (NodeFilm::Clear(up), NodeFilm::Clear(own)) => {
                    (up.reflectance_at_cos(centre_up.c) - own.reflectance_at_cos(centre.c))
                        / INDEX_STEP
                }
                _ => f64::NAN,
            };
            centre.step();
            centre_up.step();
            *k = Knot::of(m, slope * h, j_n);
        }
    }

    /// Whether the band is tabulated.
    pub fn tabulated(&self) -> bool {
        self.table.is_some()
    }

    /// Where the band's knots sit in the angle's table, if tabulated.
    pub(crate) fn table(&self) -> Option<TableSpan> {
        self.table
    }

    /// The model at `thickness_nm` and the orders `order_step_nm` either side: from the
    /// table where it covers all three, else computed.
    #[inline]
    pub fn eval(&self, knots: &[Knot], thickness_nm: f64, order_step_nm: f64) -> BandEval {
        if let Some(t) = self.table {
            let (c, lo, hi) = (
                t.locate(thickness_nm as f32),
                t.locate((thickness_nm - order_step_nm) as f32),
                t.locate((thickness_nm + order_step_nm) as f32),
            );
            if let (Some((i, u)), Some(lo), Some(hi), Some(k)) = (c, lo, hi, t.knots(knots)) {
                let s = SampleModel::from_knots(k[i], u, (k[lo.0], lo.1), (k[hi.0], hi.1), t.inv_h);
                return BandEval {
                    m: f64::from(s.m),
                    j_d: f64::from(s.j_d),
                    j_n: f64::from(s.j_n),
                    m_minus: f64::from(s.m_minus),
                    m_plus: f64::from(s.m_plus),
                };
            }
        }
        self.eval_exact(thickness_nm, order_step_nm)
    }

    /// [`BandCoef::eval`] computed: the passband quadrature for the model and its thickness
    /// derivative; the index derivative and the neighbouring orders from the band centre
    /// (the passband's detail matters to neither: it scales the fringe contrast a little; the
    /// order misfits are whole fringes), the model's passband correction carried over.
    pub fn eval_exact(&self, thickness_nm: f64, order_step_nm: f64) -> BandEval {
        let (m, j_d) = self.model_and_slope(thickness_nm);
        let m_centre = self.centre.at(thickness_nm);
        BandEval {
            m,
            j_d,
            j_n: (self.centre_up.at(thickness_nm) - m_centre) / INDEX_STEP,
            m_minus: self.centre.at(thickness_nm - order_step_nm) + (m - m_centre),
            m_plus: self.centre.at(thickness_nm + order_step_nm) + (m - m_centre),
        }
    }

    /// Model reflectance of a film of `thickness_nm` and its derivative in thickness.
    #[inline]
    fn model_and_slope(&self, thickness_nm: f64) -> (f64, f64) {
        let (mut m, mut j) = (0.0, 0.0);
        for n in &self.nodes[..self.count] {
            let (r, dr) = n.model_and_slope(thickness_nm);
            m += r;
            j += dr;
        }
        (m, j)
    }

    #[inline]
    fn model_of(nodes: &[Node], thickness_nm: f64) -> f64 {
        nodes.iter().map(|n| n.weight * n.at(thickness_nm)).sum()
    }

    /// Model reflectance of a film of `thickness_nm`.
    #[inline]
    pub fn model(&self, thickness_nm: f64) -> f64 {
        Self::model_of(&self.nodes[..self.count], thickness_nm)
    }
}

/// Cubic Hermite interpolation between two knots at fraction `u`: the value and its
/// derivative in knot units (`d / du`).
#[inline]
fn hermite(k: &Knot, u: f32) -> (f32, f32) {
    let (u2, u3) = (u * u, u * u * u);
    let ([ma, mb], [sa, sb]) = (k.m, k.slope_h);
    let value = (2.0 * u3 - 3.0 * u2 + 1.0) * ma
        + (u3 - 2.0 * u2 + u) * sa
        + (3.0 * u2 - 2.0 * u3) * mb
        + (u3 - u2) * sb;
    let slope = (6.0 * u2 - 6.0 * u) * (ma - mb)
        + (3.0 * u2 - 4.0 * u + 1.0) * sa
        + (3.0 * u2 - 2.0 * u) * sb;
    (value, slope)
}

/// Per-pixel Gauss-Newton sums (68 bytes) for the pixel's thickness and the shared index's
/// three basis coefficients.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GnSums {
    /// Sum of `J_d^2`.
    pub h_dd: f32,
    /// Sums of `J_d J_n u^k`, k = 0..3.
    pub h_dp: [f32; 3],
    /// Sums of `J_n^2 u^k`, k = 0..5 (index block entry `(i, j)` is `h_pp[i + j]`).
    pub h_pp: [f32; 5],
    /// Sum of `J_d r`.
    pub g_d: f32,
    /// Sums of `J_n r u^k`, k = 0..3.
    pub g_p: [f32; 3],
    /// Sum of `r^2` at the linearisation point.
    pub sse: f32,
    /// Sum of squared residuals one order thinner.
    pub sse_minus: f32,
    /// Sum of squared residuals one order thicker.
    pub sse_plus: f32,
    /// Samples summed.
    pub samples: u16,
}

/// Sums every pixel keeps ([`GnSums::to_pixel_terms`]): `h_dd`, `h_dp`, `g_d`, `sse`,
/// `sse_minus`, `sse_plus`.
pub const PIXEL_TERMS: usize = 8;

/// Sums only the shared index's step needs ([`GnSums::to_index_terms`]): `h_pp`, `g_p`. A
/// sample of the pixels keeps them (the row blocks' index sampling).
pub const INDEX_TERMS: usize = 8;

/// Where `g_d` is in [`GnSums::to_pixel_terms`]' array (`h_dd` and `h_dp` before it).
pub const G_D_TERM: usize = 4;

/// Where `sse` is in [`GnSums::to_pixel_terms`]' array.
pub const SSE_TERM: usize = 5;

impl GnSums {
    /// Adds one band sample `measured` of a pixel at linearisation point `thickness_nm`
    /// (`order_step_nm` apart from the neighbouring orders), the band's model from `knots`
    /// where tabulated.
    #[inline]
    pub fn add(
        &mut self,
        coef: &BandCoef,
        knots: &[Knot],
        thickness_nm: f64,
        order_step_nm: f64,
        measured: f64,
    ) {
        let model: SampleModel = coef.eval(knots, thickness_nm, order_step_nm).into();
        let (v, u) = (measured as f32, coef.u as f32);
        let mut p = self.to_pixel_terms();
        for (s, t) in p.iter_mut().zip(Self::pixel_terms(model, v, u)) {
            *s += t;
        }
        let mut x = self.to_index_terms();
        for (s, t) in x
            .iter_mut()
            .zip(Self::index_terms(model.j_n, v - model.m, u))
        {
            *s += t;
        }
        *self = Self::from_terms(p, x, self.samples.saturating_add(1));
    }

    /// What one sample `v` of a band whose basis variable is `u` adds to each of a pixel's
    /// own sums, the model `s` at the pixel's thickness, in the order of
    /// [`GnSums::to_pixel_terms`].
    #[inline(always)]
    pub(crate) fn pixel_terms(s: SampleModel, v: f32, u: f32) -> [f32; PIXEL_TERMS] {
        let r = v - s.m;
        let jdn = s.j_d * s.j_n;
        let (rm, rp) = (v - s.m_minus, v - s.m_plus);
        [
            s.j_d * s.j_d,
            jdn,
            jdn * u,
            jdn * (u * u),
            s.j_d * r,
            r * r,
            rm * rm,
            rp * rp,
        ]
    }

    /// What one sample adds to each of the index's sums, its index derivative `j_n` and
    /// residual `r` given, in the order of [`GnSums::to_index_terms`].
    #[inline(always)]
    pub(crate) fn index_terms(j_n: f32, r: f32, u: f32) -> [f32; INDEX_TERMS] {
        let (u2, jn2, jnr) = (u * u, j_n * j_n, j_n * r);
        [
            jn2,
            jn2 * u,
            jn2 * u2,
            jn2 * u2 * u,
            jn2 * u2 * u2,
            jnr,
            jnr * u,
            jnr * u2,
        ]
    }

    /// The pixel's own sums as one array: `h_dd`, `h_dp`, `g_d`, `sse`, `sse_minus`,
    /// `sse_plus`.
    pub fn to_pixel_terms(&self) -> [f32; PIXEL_TERMS] {
        let d = self.h_dp;
        [
            self.h_dd,
            d[0],
            d[1],
            d[2],
            self.g_d,
            self.sse,
            self.sse_minus,
            self.sse_plus,
        ]
    }

    /// The index's sums as one array: `h_pp`, `g_p`.
    pub fn to_index_terms(&self) -> [f32; INDEX_TERMS] {
        let (p, g) = (self.h_pp, self.g_p);
        [p[0], p[1], p[2], p[3], p[4], g[0], g[1], g[2]]
    }

    /// The sums from [`GnSums::to_pixel_terms`]' and [`GnSums::to_index_terms`]' arrays and
    /// the count of samples.
    pub fn from_terms(p: [f32; PIXEL_TERMS], x: [f32; INDEX_TERMS], samples: u16) -> Self {
        Self {
            h_dd: p[0],
            h_dp: [p[1], p[2], p[3]],
            h_pp: [x[0], x[1], x[2], x[3], x[4]],
            g_d: p[4],
            g_p: [x[5], x[6], x[7]],
            sse: p[5],
            sse_minus: p[6],
            sse_plus: p[7],
            samples,
        }
    }

    /// 1-sigma uncertainty of the thickness, nm: the fit's own (the residual variance over
    /// `sum J_d^2`) and, given the shared index's covariance `index_cov` (basis coefficients,
    /// [`super::IndexModel::to_basis`]), the index's, carried through the thickness's
    /// dependence on it (`-h_dp / h_dd` nm per unit of each coefficient: at fixed data, the
    /// best thickness moves that much with the index). Infinite without samples or slope.
    pub fn thickness_sigma_nm(&self, index_cov: Option<&[[f64; 3]; 3]>) -> f64 {
        if self.samples < 2 || self.h_dd <= 0.0 {
            return f64::INFINITY;
        }
        let h_dd = f64::from(self.h_dd);
        let var = f64::from(self.sse) / f64::from(self.samples - 1) / h_dd;
        let from_index = index_cov.map_or(0.0, |c| {
            let v = self.h_dp.map(|h| f64::from(h) / h_dd);
            (0..3)
                .map(|i| (0..3).map(|j| v[i] * c[i][j] * v[j]).sum::<f64>())
                .sum::<f64>()
        });
        libm::sqrt(var + from_index.max(0.0))
    }

    /// Root-mean-square residual at the linearisation point.
    pub fn rms(&self) -> f32 {
        if self.samples == 0 {
            f32::NAN
        } else {
            libm::sqrtf(self.sse / f32::from(self.samples))
        }
    }

    /// The best thickness step given the index step `dp` (basis coefficients).
    pub fn thickness_step(&self, dp: [f64; 3]) -> f64 {
        let mut g = f64::from(self.g_d);
        for (h, d) in self.h_dp.iter().zip(dp) {
            g -= f64::from(*h) * d;
        }
        g / f64::from(self.h_dd)
    }

    /// Moves the linearisation point by `dd` (thickness) and `dp` (index basis coefficients):
    /// the gradients and the squared error follow the linear model. A pixel that keeps no
    /// index sums (outside the index's sample of pixels; zeros here) moves its squared error by
    /// the thickness's terms only: measured, leaving the index's out for every pixel changed
    /// no figure `filmscope eval` prints on the config scenes and the thick stability cells.
    pub fn shift(&mut self, dd: f64, dp: [f64; 3]) {
        let h = |i: usize, j: usize| f64::from(self.h_pp[i + j]);
        let h_dp = self.h_dp.map(f64::from);
        let g_p = self.g_p.map(f64::from);
        let (h_dd, g_d) = (f64::from(self.h_dd), f64::from(self.g_d));
        let mut sse = f64::from(self.sse) - 2.0 * g_d * dd + h_dd * dd * dd;
        let mut new_g_d = g_d - h_dd * dd;
        for i in 0..3 {
            sse += -2.0 * g_p[i] * dp[i] + 2.0 * h_dp[i] * dd * dp[i];
            new_g_d -= h_dp[i] * dp[i];
            let mut gi = g_p[i] - h_dp[i] * dd;
            for (j, &dj) in dp.iter().enumerate() {
                sse += h(i, j) * dp[i] * dj;
                gi -= h(i, j) * dj;
            }
            self.g_p[i] = gi as f32;
        }
        self.g_d = new_g_d as f32;
        self.sse = sse.max(0.0) as f32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_index_covariance_adds_to_the_thickness_sigma() {
        let g = GnSums {
            h_dd: 4.0,
            h_dp: [40.0, -8.0, 0.0],
            sse: 0.99,
            samples: 100,
            ..GnSums::default()
        };
        // Fit alone: sqrt(0.99 / 99 / 4) = 0.05 nm.
        let alone = g.thickness_sigma_nm(None);
        assert!((alone - 0.05).abs() < 1e-9, "{alone}");
        // dd/dp = -(10, -2, 0) nm per unit; with sigma_p0 = 0.01, sigma_p1 = 0.02 and
        // correlation 0.5: v C v = 100e-4 + 4 * 4e-4 - 2 * 20 * 0.5 * 2e-4 = 0.0076.
        let c = [[1e-4, 1e-4, 0.0], [1e-4, 4e-4, 0.0], [0.0; 3]];
        let both = g.thickness_sigma_nm(Some(&c));
        let want = (0.05f64 * 0.05 + 0.0076).sqrt();
        assert!((both - want).abs() < 1e-9, "{both} against {want}");
        assert!(g.thickness_sigma_nm(Some(&[[0.0; 3]; 3])) == alone);
    }

    #[test]
    fn model_matches_the_band_averaged_airy_sum() {
        use crate::optics::{materials, BandModel, Dispersion, FilmStack, Passband, MAX_NODES};
        let tio2 = materials::by_name("tio2").expect("in the library");
        for (film, fwhm, d, tol) in [
            (Dispersion::constant(1.37), 4.0, 400.0, 2e-5),
            (Dispersion::constant(2.37), 4.0, 500.0, 2e-5),
            (Dispersion::constant(1.38), 10.0, 1500.0, 2e-5),
            // Fast dispersive fringes at the blue end: 5 Gauss-Hermite nodes erred by 0.01.
            (tio2, 6.1, 1600.0, 2e-4),
            (tio2, 12.0, 2000.0, 2e-4),
        ] {
            let stack = FilmStack {
                back_face: BackFace::None,
                ambient_index: 1.0,
                film,
                substrate: Dispersion::constant(1.65),
                polarization: Polarization::P,
            };
            let index = IndexModel::from_dispersion(film).expect("one pole at most");
            for l in [400.0, 420.0, 550.0, 720.0] {
                let c = BandCoef::new(
                    index,
                    FilmTerms::NONE,
                    1.0,
                    1.65,
                    0.0,
                    BackFace::None,
                    Polarization::P,
                    30.0,
                    l,
                    fwhm,
                    d,
                )
                .expect("propagating");
                // The reference: the same truncated Gaussian with twice the nodes the fit
                // may use, the film's own dispersion node by node.
                let band = Passband::gaussian_with_nodes(l, fwhm, MAX_NODES);
                let exact = BandModel::new(stack, 30.0, band).reflectance(d);
                assert!(
                    (c.model(d) - exact).abs() < tol,
                    "{film:?} d {d} l {l}: {} vs {exact}",
                    c.model(d)
                );
            }
        }
    }

    /// A table over part of the range ([`BandCoef::range_within`]) has the whole range's
    /// knots there: the same models (within the stepped phases' 1e-6) at any thickness
    /// inside both, the computed model outside it; spans beyond the range are clamped to it
    /// or give none.
    #[test]
    fn a_partial_table_holds_the_whole_tables_knots() {
        let full = [-310.0, 2360.0];
        let mut whole = BandCoef::new(
            IndexModel::constant(1.38),
            FilmTerms::NONE,
            1.0,
            1.65,
            0.0,
            BackFace::None,
            Polarization::S,
            30.0,
            540.0,
            4.0,
            full[1],
        )
        .expect("propagating");
        let mut part = whole;
        let (h, count) = whole.knots_for(full).expect("a table");
        let mut knots = vec![Knot::default(); count];
        whole.tabulate(full, 0, &mut knots);
        let within = [101.3, 733.9];
        let sub = part.range_within(full, within).expect("inside");
        assert!(sub[0] <= within[0] && sub[1] >= within[1], "{sub:?}");
        assert!(sub[1] - sub[0] < within[1] - within[0] + 2.0 * h + 1e-9);
        let off = (sub[0] - full[0]) / h;
        assert!((off - off.round()).abs() < 1e-9, "{off}: not on the grid");
        let (_, n) = part.knots_for(sub).expect("a table");
        assert!(n < count / 3, "{n} of {count}");
        let mut sub_knots = vec![Knot::default(); n];
        part.tabulate(sub, 0, &mut sub_knots);
        // The thickness and both orders (80 nm either side) inside the part.
        for d in [190.0, 402.7, 640.0] {
            let (a, b) = (whole.eval(&knots, d, 80.0), part.eval(&sub_knots, d, 80.0));
            for (x, y) in [
                (a.m, b.m),
                (a.j_d, b.j_d),
                (a.m_minus, b.m_minus),
                (a.m_plus, b.m_plus),
            ] {
                assert!((x - y).abs() < 1e-6, "{d} nm: {x} vs {y}");
            }
        }
        // Outside the part: computed, as the whole range's own model.
        let e = part.eval(&sub_knots, 1500.0, 80.0);
        assert!((e.m - whole.eval_exact(1500.0, 80.0).m).abs() < 1e-12);
        assert_eq!(
            part.range_within(full, [-900.0, 50.0]).map(|r| r[0]),
            Some(full[0])
        );
        assert_eq!(part.range_within(full, [3000.0, 3100.0]), None);
        assert_eq!(
            part.range_within(full, [f64::INFINITY, f64::NEG_INFINITY]),
            None
        );
    }

    /// The knots' phases are rotated, not computed: over the most knots a band holds, the
    /// last knot is still the model computed at its thickness (value and slope within 1e-6,
    /// index derivative within 1e-5 of its size).
    #[test]
    fn stepped_knots_match_the_computed_model_to_the_table_end() {
        let mut c = BandCoef::new(
            IndexModel::constant(2.4),
            FilmTerms::NONE,
            1.0,
            1.52,
            0.0,
            BackFace::None,
            Polarization::Unpolarized,
            60.0,
            400.0,
            10.0,
            2500.0,
        )
        .expect("propagating");
        let (h, _) = c.knots_for([0.0, 1.0]).expect("a table");
        let range = [-300.0, -300.0 + h * (MAX_KNOTS_PER_BAND - 3) as f64];
        let (h, count) = c.knots_for(range).expect("a table");
        assert!(count + 2 >= MAX_KNOTS_PER_BAND, "{count}");
        let mut knots = vec![Knot::default(); count];
        c.tabulate(range, 0, &mut knots);
        for j in [0, 1, count / 2, count - 1] {
            let d = range[0] + h * j as f64;
            let (m, slope) = c.model_and_slope(d);
            let e = c.eval_exact(d, 1.0);
            // The knot's own values, and the record before's as its next.
            let mut held = vec![(knots[j].m[0], knots[j].slope_h[0], knots[j].j_n[0])];
            if j > 0 {
                let k = knots[j - 1];
                held.push((k.m[1], k.slope_h[1], k.j_n[1]));
            }
            for (km, ks, kn) in held {
                assert!((f64::from(km) - m).abs() < 1e-6, "knot {j}: {km} vs {m}");
                assert!(
                    (f64::from(ks) - slope * h).abs() < 1e-6,
                    "knot {j}: {ks} vs {}",
                    slope * h
                );
                assert!((f64::from(kn) - e.j_n).abs() < 1e-5 * e.j_n.abs().max(1.0));
            }
        }
    }

    /// The tabulated model follows the computed one: value within 5e-5 reflectance (Hermite
    /// at a quarter radian per knot; worst measured 2.1e-5, on the sharp fringes of an n 2.8
    /// film seen through a 1 nm passband), thickness slope within 0.5 % of its amplitude, and the
    /// neighbouring orders as the full passband model puts them; outside the table it is the
    /// computed model itself.
    #[test]
    fn tabulated_model_follows_the_computed_one() {
        for (n, l, fwhm) in [(1.38, 420.0, 4.0), (2.8, 420.0, 1.0), (2.35, 700.0, 10.0)] {
            let mut c = BandCoef::new(
                IndexModel::constant(n),
                FilmTerms::NONE,
                1.0,
                1.52,
                0.0,
                BackFace::None,
                Polarization::S,
                40.0,
                l,
                fwhm,
                2500.0,
            )
            .expect("propagating");
            let range = [-300.0, 2500.0];
            let (_, count) = c.knots_for(range).expect("a table");
            let mut knots = [Knot::default(); 4096];
            assert!(count <= knots.len(), "{count}");
            c.tabulate(range, 0, &mut knots[..count]);
            assert!(c.tabulated());
            let step = l / (2.0 * n);
            let at = |i: i32| 50.0 + 4.87 * f64::from(i);
            // The index derivative's local amplitude (it grows with thickness): the linear
            // interpolation errs by about (KNOT_PHASE^2 / 8) = 0.8 % of it on a sinusoidal
            // fringe, more on sharp ones (measured 2.6 % for n 2.8 at 1 nm FWHM); a Jacobian's
            // error only slows Gauss-Newton.
            let amplitude = |i: i32, f: fn(BandEval) -> f64| {
                (i - 25..i + 25)
                    .map(|k| libm::fabs(f(c.eval_exact(at(k), step))))
                    .fold(0.0, f64::max)
            };
            for i in 0..400 {
                let d = at(i);
                let t = c.eval(&knots, d, step);
                let (m, j_d) = c.model_and_slope(d);
                assert!((t.m - m).abs() < 5e-5, "n {n} d {d}: {} vs {m}", t.m);
                assert!(
                    (t.j_d - j_d).abs() < 5e-3 * amplitude(i, |e| e.j_d),
                    "{} vs {j_d}",
                    t.j_d
                );
                assert!((t.m_minus - c.model(d - step)).abs() < 5e-5);
                assert!(
                    (t.m_plus - c.model(d + step)).abs() < 5e-5,
                    "n {n} d {d}: {} vs {}",
                    t.m_plus,
                    c.model(d + step)
                );
                let e = c.eval_exact(d, step);
                assert!(
                    (t.j_n - e.j_n).abs() < 0.05 * amplitude(i, |e| e.j_n),
                    "d {d}: {} vs {}",
                    t.j_n,
                    e.j_n
                );
            }
            // Beyond the table: computed.
            assert_eq!(c.eval(&knots, 2600.0, step), c.eval_exact(2600.0, step));
        }
    }

    #[test]
    fn one_step_recovers_a_small_thickness_error() {
        let n = 1.37;
        let truth = 400.0;
        let coefs: Vec<BandCoef> = (0..151)
            .map(|b| {
                BandCoef::new(
                    IndexModel::constant(n),
                    FilmTerms::NONE,
                    1.0,
                    1.65,
                    0.0,
                    BackFace::None,
                    Polarization::S,
                    20.0,
                    420.0 + 2.0 * b as f64,
                    4.0,
                    2000.0,
                )
                .expect("propagating")
            })
            .collect();
        let start = 405.0;
        let mut gn = GnSums::default();
        for c in &coefs {
            gn.add(c, &[], start, 200.0, c.model(truth));
        }
        let step = f64::from(gn.g_d) / f64::from(gn.h_dd);
        assert!((start + step - truth).abs() < 0.3, "{}", start + step);
        assert!(gn.sse_minus > gn.sse && gn.sse_plus > gn.sse);
    }

    /// With the film absorbing and the polariser leaking, the band model is the mix of the two
    /// polarisations' reflectances through the absorbing film (leak alone: the clear film's
    /// in each polarisation, computed apart), its thickness slope the model's own, and the
    /// table follows the computed model as it does for a clear film.
    #[test]
    fn film_terms_enter_the_band_model() {
        let band = |terms: FilmTerms, fwhm: f64| {
            BandCoef::new(
                IndexModel::constant(2.1),
                terms,
                1.0,
                1.52,
                0.0,
                BackFace::Bare,
                Polarization::S,
                45.0,
                430.0,
                fwhm,
                2500.0,
            )
            .expect("propagating")
        };
        let film = |pol| {
            let idx = Indices {
                ambient: 1.0,
                film: 2.1,
                substrate: 1.52,
                substrate_k: 0.0,
                back_face: BackFace::Bare,
            };
            FilmAtAngle::new(idx, 45.0, pol).expect("propagating")
        };
        let (s, p) = (film(Polarization::S), film(Polarization::P));
        let leaky = band(
            FilmTerms {
                film_k: 0.0,
                leak: 0.03,
            },
            1e-3,
        );
        for d in [120.0, 640.0, 1890.0] {
            let want = 0.97 * s.reflectance(d, 430.0) + 0.03 * p.reflectance(d, 430.0);
            assert!(
                (leaky.model(d) - want).abs() < 1e-7,
                "d {d}: {} vs {want}",
                leaky.model(d)
            );
        }
        let terms = FilmTerms {
            film_k: 0.006,
            leak: 0.02,
        };
        let clear = band(FilmTerms::NONE, 3.0);
        let mut c = band(terms, 3.0);
        let range = [-300.0, 2500.0];
        let (_, count) = c.knots_for(range).expect("a table");
        let mut knots = vec![Knot::default(); count];
        c.tabulate(range, 0, &mut knots);
        let step = 430.0 / 4.2;
        let mut lost = 0.0f64;
        for i in 0..300 {
            let d = 20.0 + 7.77 * f64::from(i);
            let (m, j_d) = c.model_and_slope(d);
            let h = 1e-4;
            let numeric = (c.model(d + h) - c.model(d - h)) / (2.0 * h);
            assert!((j_d - numeric).abs() < 1e-6, "d {d}: {j_d} vs {numeric}");
            let t = c.eval(&knots, d, step);
            assert!((t.m - m).abs() < 5e-5, "d {d}: {} vs {m}", t.m);
            lost = lost.max(clear.model(d) - m);
        }
        // The absorbing film returns less from the back face at 430 nm (k 0.0073 there).
        assert!(lost > 1e-3, "{lost}");
    }
}
