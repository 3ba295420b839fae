//! The integer interference order of a pixel, from its extrema and the model (all of them,
//! or each angle's last ones with the whole list's count inside the reliable range:
//! [`OrderContext::resolve_seen`]).
//!
//! With the index known, an extremum at `lambda` and incidence `x = (n0 sin theta)^2` sits at
//! order `q = d u`, `u = 2 sqrt(n(lambda)^2 - x) / lambda`, and `q` must be `o + m` for a peak
//! and `o + m + 1/2` for a valley (`o = 1/2` when one reflection flips phase and the other does
//! not: a film above the substrate's index). Each candidate order of one extremum gives a
//! thickness; every extremum of every angle then votes on it (how far its own `q` is from an
//! allowed value) and so does the number of extrema the candidate predicts inside the band.

use crate::track::Kind;

use super::IndexModel;

/// Most candidate orders tried per pixel.
const MAX_CANDIDATES: usize = 48;

/// Most observations the order search uses: a pixel's two extremum lists.
pub const MAX_OBSERVATIONS: usize = 2 * crate::track::MAX_EXTREMA;

/// Cost of each extremum predicted but not seen, or seen but not predicted, inside the
/// reliable part of the band.
const COUNT_PENALTY: f64 = 0.5;

/// One extremum with what the order search needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Wavelength, nm.
    pub wavelength_nm: f64,
    /// Peak or valley.
    pub kind: Kind,
    /// Which angle of the pair (0 or 1) it belongs to.
    pub angle: usize,
}

/// What the order search knows besides the extrema.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrderContext {
    /// The index model.
    pub index: IndexModel,
    /// `x = (n0 sin theta)^2` of the (up to two) angles the observations come from.
    pub x: [f64; 2],
    /// How many of `x` are in use.
    pub angles: usize,
    /// Order offset of peaks at each angle: 0 or 0.5 (see
    /// [`crate::optics::FilmAtAngle::peak_phase_offset`]).
    pub peak_offset: [f64; 2],
    /// Thickness search range, nm.
    pub thickness_range_nm: [f64; 2],
    /// Wavelength range in which the tracker reliably finds extrema, nm.
    pub reliable_nm: [f64; 2],
    /// The candidates scored in the widest vector instructions the CPU has
    /// ([`crate::simd::wide`]; the solver's `wide_simd`): the same choices either way.
    pub wide: bool,
}

/// The best order's thickness and how clearly it won.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrderChoice {
    /// Thickness of the best order, nm (least squares over all extrema).
    pub thickness_nm: f64,
    /// Its cost (sum of squared order misfits plus count penalties).
    pub cost: f64,
    /// Thickness and cost of the best candidate of another order (`INFINITY` cost if none).
    pub runner_up_nm: f64,
    /// See `runner_up_nm`.
    pub runner_up_cost: f64,
    /// The thickness change that moves every extremum by one order, nm.
    pub order_step_nm: f64,
}

/// `2^52`: at and above it every `f64` is an integer.
const TWO_52: f64 = 4_503_599_627_370_496.0;

/// `libm::floor(x)` for `0 <= x < 2^52`, exactly and without a branch: adding and taking
/// away `2^52` rounds to the nearest integer, one too many where that rounded up.
#[inline(always)]
fn floor_small(x: f64) -> f64 {
    let r = (x + TWO_52) - TWO_52;
    if r > x {
        r - 1.0
    } else {
        r
    }
}

/// `libm::round(x)` (halves away from zero), bit for bit, without its call or a branch:
/// the order search rounds every extremum's order for every candidate, a loop over the
/// candidates that compiles to vector instructions. `|x|`'s floor and fraction are exact
/// below `2^52`; at and above it `x` is already an integer (or infinite, or NaN).
#[inline(always)]
fn round(x: f64) -> f64 {
    let a = x.abs();
    let t = floor_small(a);
    let r = if a - t >= 0.5 { t + 1.0 } else { t };
    // A zero keeps the sign of `x` (-0.3 rounds to -0.0).
    let r = r.copysign(x);
    if a < TWO_52 {
        r
    } else {
        x
    }
}

/// `libm::floor(x)` for `|x| < 2^52` (what an extremum count needs), without a branch.
#[inline(always)]
fn floor_f(x: f64) -> f64 {
    let t = floor_small(x.abs());
    // Below zero the floor of `x` is minus the ceiling of `|x|`.
    if x >= 0.0 {
        t
    } else if t < x.abs() {
        -t - 1.0
    } else {
        -t
    }
}

/// `libm::ceil(x)` for `|x| < 2^52`, without a branch.
#[inline(always)]
fn ceil_f(x: f64) -> f64 {
    -floor_f(-x)
}

impl OrderContext {
    fn u(&self, o: &Observation) -> f64 {
        let n = self.index.at(o.wavelength_nm);
        2.0 * libm::sqrt((n * n - self.x[o.angle]).max(1e-9)) / o.wavelength_nm
    }

    fn parity(&self, kind: Kind, angle: usize) -> f64 {
        match kind {
            Kind::Peak => self.peak_offset[angle],
            Kind::Valley => self.peak_offset[angle] + 0.5,
        }
    }

    /// Extrema a film of `thickness_nm` shows at angle `a` inside the reliable range, given
    /// `root[a]`: `sqrt(n^2 - x)` at the reliable range's long and short ends (a whole
    /// number, as a float: the counts of real films are far below `2^52`).
    #[inline(always)]
    fn predicted_count(&self, thickness_nm: f64, a: usize, root: &[[f64; 2]; 2]) -> f64 {
        let at = |l: f64, r: f64| thickness_nm * 2.0 * r / l;
        let (q_lo, q_hi) = (
            at(self.reliable_nm[1], root[a][0]),
            at(self.reliable_nm[0], root[a][1]),
        );
        // Extrema sit at q = peak_offset + k / 2.
        let offset = self.peak_offset[a];
        let first = ceil_f((q_lo - offset) * 2.0);
        let last = floor_f((q_hi - offset) * 2.0);
        let first = first.max(1.0 - floor_f(2.0 * offset));
        (last - first + 1.0).max(0.0)
    }

    /// Scores the thicknesses `d0[..n]`: assigns each extremum (`(u, parity)`, see
    /// [`OrderContext::resolve`]) its nearest allowed order, refits the thickness by least
    /// squares; `(thickness, cost)` of each into `out[..n]`; `seen[a]` extrema of angle `a`
    /// lie inside the reliable range. The candidates are the inner loops (in blocks of
    /// four), each candidate's sums taking the extrema in order.
    #[inline(always)]
    fn score_all(
        &self,
        d0: &[f64; MAX_CANDIDATES],
        n: usize,
        obs: &[(f64, f64)],
        seen: [i64; 2],
        root: &[[f64; 2]; 2],
        out: &mut [[f64; MAX_CANDIDATES]; 2],
    ) {
        let n = n.next_multiple_of(4).min(MAX_CANDIDATES);
        let mut suq = [0.0; MAX_CANDIDATES];
        let mut suu = 0.0;
        for &(u, p) in obs {
            for (s, &d) in suq[..n].iter_mut().zip(&d0[..n]) {
                let q = p + round(d * u - p);
                *s += u * q;
            }
            suu += u * u;
        }
        let [ds, costs] = out;
        for (d, s) in ds[..n].iter_mut().zip(&suq[..n]) {
            *d = s / suu;
        }
        costs[..n].fill(0.0);
        for &(u, p) in obs {
            for (cost, &d) in costs[..n].iter_mut().zip(&ds[..n]) {
                let e = d * u - p;
                let r = e - round(e);
                *cost += r * r;
            }
        }
        for (a, &seen) in seen.iter().enumerate().take(self.angles) {
            for (cost, &d) in costs[..n].iter_mut().zip(&ds[..n]) {
                *cost += COUNT_PENALTY * (self.predicted_count(d, a, root) - seen as f64).abs();
            }
        }
    }

    /// Finds the best order for the observations (the first [`MAX_OBSERVATIONS`]; a pixel's
    /// two extremum lists hold at most that many); `None` without observations.
    pub fn resolve(&self, obs: &[Observation]) -> Option<OrderChoice> {
        self.resolve_seen(obs, [None; 2])
    }

    /// [`OrderContext::resolve`], an angle's count of extrema inside the reliable range
    /// given (`counts[angle]`) where its observations are only some of them.
    pub fn resolve_seen(
        &self,
        obs: &[Observation],
        counts: [Option<i64>; 2],
    ) -> Option<OrderChoice> {
        let obs = &obs[..obs.len().min(MAX_OBSERVATIONS)];
        // What every candidate needs of each observation: its order per nm of thickness and
        // its parity, and how many of each angle's lie inside the reliable range.
        let mut prepared = [(0.0, 0.0); MAX_OBSERVATIONS];
        let mut seen = [0i64; 2];
        for (o, slot) in obs.iter().zip(prepared.iter_mut()) {
            *slot = (self.u(o), self.parity(o.kind, o.angle));
            let reliable =
                o.wavelength_nm >= self.reliable_nm[0] && o.wavelength_nm <= self.reliable_nm[1];
            if reliable && o.angle < 2 {
                seen[o.angle] += 1;
            }
        }
        for (seen, count) in seen.iter_mut().zip(counts) {
            if let Some(n) = count {
                *seen = n;
            }
        }
        let prepared = &prepared[..obs.len()];
        let mut root = [[0.0; 2]; 2];
        for (a, r) in root.iter_mut().enumerate().take(self.angles) {
            *r = [self.reliable_nm[1], self.reliable_nm[0]].map(|l| {
                let n = self.index.at(l);
                libm::sqrt((n * n - self.x[a]).max(1e-9))
            });
        }
        // Candidates from the longest-wavelength extremum (the lowest order).
        let (k0, _) = obs
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.wavelength_nm.total_cmp(&b.1.wavelength_nm))?;
        let (u0, p0) = prepared[k0];
        let mean_u = prepared.iter().map(|o| o.0).sum::<f64>() / obs.len() as f64;
        let order_step_nm = 1.0 / mean_u;
        let [d_lo, d_hi] = self.thickness_range_nm;
        // The candidates' thicknesses, then their scores in one batch.
        let mut d0s = [0.0; MAX_CANDIDATES];
        let mut n = 0;
        let mut m = libm::ceil(d_lo * u0 - p0 - 0.5).max(0.0);
        while n < MAX_CANDIDATES {
            let q = p0 + m;
            m += 1.0;
            if q <= 0.0 {
                continue;
            }
            let d0 = q / u0;
            if d0 > d_hi * 1.05 + order_step_nm {
                break;
            }
            d0s[n] = d0;
            n += 1;
        }
        let mut scored = [[0.0; MAX_CANDIDATES]; 2];
        crate::simd::wide(
            self.wide,
            #[inline(always)]
            || self.score_all(&d0s, n, prepared, seen, &root, &mut scored),
        );
        let mut best = (f64::NAN, f64::INFINITY);
        let mut second = (f64::NAN, f64::INFINITY);
        for (&d, &cost) in scored[0][..n].iter().zip(&scored[1][..n]) {
            if !(d.is_finite() && d > 0.0) {
                continue;
            }
            if (d - best.0).abs() < 0.5 * order_step_nm {
                if cost < best.1 {
                    best = (d, cost);
                }
            } else if cost < best.1 {
                second = best;
                best = (d, cost);
            } else if cost < second.1 && (d - best.0).abs() >= 0.5 * order_step_nm {
                second = (d, cost);
            }
        }
        best.0.is_finite().then_some(OrderChoice {
            thickness_nm: best.0,
            cost: best.1,
            runner_up_nm: second.0,
            runner_up_cost: second.1,
            order_step_nm,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values the order search's roundings must treat as `libm` does: halves, their
    /// neighbours, signed zeros, the ends of the exact range, infinities, NaN, and a spread
    /// over every exponent.
    fn rounding_cases() -> impl Iterator<Item = f64> {
        let two_52 = 4_503_599_627_370_496.0f64;
        let special = [
            0.0,
            -0.0,
            0.5,
            -0.5,
            0.49999999999999994,
            -0.49999999999999994,
            1.5,
            -2.5,
            two_52 - 0.5,
            -(two_52 - 0.5),
            two_52,
            two_52 + 1.0,
            9.3e18,
            -9.3e18,
            f64::MAX,
            f64::MIN_POSITIVE,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        let halves = (-4000..4000).flat_map(|k| {
            let x = f64::from(k) * 0.25;
            [
                x,
                f64::from_bits(x.to_bits() + 1),
                f64::from_bits(x.to_bits().max(1) - 1),
            ]
        });
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let spread = core::iter::from_fn(move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            Some(f64::from_bits(state))
        })
        .take(200_000);
        special.into_iter().chain(halves).chain(spread)
    }

    #[test]
    fn roundings_are_libms_bit_for_bit() {
        for x in rounding_cases() {
            let (a, b) = (round(x), libm::round(x));
            assert!(
                a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                "round({x:e})"
            );
            if x.abs() < TWO_52 {
                assert_eq!(ceil_f(x), libm::ceil(x), "ceil({x:e})");
                assert_eq!(floor_f(x), libm::floor(x), "floor({x:e})");
            }
        }
    }

    fn observe(ctx: &OrderContext, d: f64, offset: f64) -> heapless::Vec<Observation, 32> {
        // Exact extrema of a film of thickness d inside 420..720.
        let mut out = heapless::Vec::new();
        for a in 0..ctx.angles {
            for k in 0..80 {
                let q = offset + 0.5 * k as f64;
                if q <= 0.0 {
                    continue;
                }
                // Solve d u(lambda) = q for lambda (constant index).
                let n = ctx.index.a;
                let l = 2.0 * d * libm::sqrt(n * n - ctx.x[a]) / q;
                if (ctx.reliable_nm[0]..=ctx.reliable_nm[1]).contains(&l) {
                    let kind = if k % 2 == 0 { Kind::Peak } else { Kind::Valley };
                    let _ = out.push(Observation {
                        wavelength_nm: l,
                        kind,
                        angle: a,
                    });
                }
            }
        }
        out
    }

    fn ctx(n: f64, offset: f64) -> OrderContext {
        let x = |deg: f64| libm::sin(deg.to_radians()).powi(2);
        OrderContext {
            index: IndexModel::constant(n),
            x: [x(10.0), x(40.0)],
            angles: 2,
            peak_offset: [offset; 2],
            thickness_range_nm: [50.0, 2000.0],
            reliable_nm: [430.0, 700.0],
            wide: true,
        }
    }

    /// Each angle's longest-wavelength four extrema and its whole list's count choose what
    /// the whole lists do, one angle's head or both; the counts are what the order search
    /// uses (a wrong one costs).
    #[test]
    fn four_extrema_of_each_angle_and_their_counts_choose_as_the_whole_lists() {
        for (n, offset) in [(1.37, 0.0), (2.37, 0.5)] {
            let c = ctx(n, offset);
            for d in [250.0, 600.0, 1234.0, 1900.0] {
                let obs = observe(&c, d, offset);
                let whole = c.resolve(&obs).expect("a choice");
                let angle = |a: usize| -> heapless::Vec<Observation, 32> {
                    obs.iter().copied().filter(|o| o.angle == a).collect()
                };
                let head = |a: usize| {
                    let mut h = angle(a);
                    h.sort_by(|a, b| b.wavelength_nm.total_cmp(&a.wavelength_nm));
                    h.truncate(4);
                    h
                };
                let counts = [0, 1].map(|a| angle(a).len() as i64);
                for heads in [[true, false], [false, true], [true, true]] {
                    let mut some: heapless::Vec<Observation, 32> = heapless::Vec::new();
                    for (a, &kept) in heads.iter().enumerate() {
                        some.extend(if kept { head(a) } else { angle(a) });
                    }
                    let given = |extra: i64| [0, 1].map(|a| heads[a].then(|| counts[a] + extra));
                    let r = c.resolve_seen(&some, given(0)).expect("a choice");
                    let case = format!("n {n} d {d} heads {heads:?}");
                    assert!((r.thickness_nm - d).abs() < 1e-6, "{case}: {r:?}");
                    assert!(
                        (r.cost - whole.cost).abs() < 1e-9,
                        "{case}: {r:?} {whole:?}"
                    );
                    assert!(r.runner_up_cost > r.cost + 0.05, "{case}: {r:?}");
                    let wrong = c.resolve_seen(&some, given(3)).expect("a choice");
                    assert!(wrong.cost > r.cost, "{case}: {wrong:?}");
                }
            }
        }
    }

    #[test]
    fn recovers_the_thickness_of_exact_extrema() {
        for (n, offset) in [(1.37, 0.0), (2.37, 0.5)] {
            let c = ctx(n, offset);
            for d in [250.0, 400.0, 600.0, 1234.0, 1900.0] {
                let obs = observe(&c, d, offset);
                if obs.is_empty() {
                    continue;
                }
                let r = c.resolve(&obs).expect("a choice");
                assert!((r.thickness_nm - d).abs() < 1e-6, "n {n} d {d}: {r:?}");
                assert!(r.runner_up_cost > r.cost + 0.05, "n {n} d {d}: {r:?}");
            }
        }
    }
}
