//! The per-sample state of a row of pixels at once: thickness, order step, sample counters
//! and full-spectrum sums ([`GnSums`]) of [`LANES`] pixels as arrays over the pixels
//! (structure of arrays), like the tracker's [`crate::track::row::TrackerLanes`].
//!
//! A band's row reaches all the block's pixels together, so the table positions, the
//! interpolation and the sixteen sums are computed lane by lane in loops the compiler
//! vectorises; only fetching each pixel's knots is one lane at a time. A pixel whose
//! thickness or order neighbours fall outside the band's table, or a band without a table,
//! takes the computed model one lane at a time ([`BandCoef::eval`]): both give the sums
//! [`GnSums::add`] gives, bit for bit.

// The lane loops index parallel arrays by lane: that is the form that vectorises.
#![allow(clippy::needless_range_loop)]

use crate::track::row::LANES;
use crate::track::usable;

use super::refine::{BandCoef, GnSums, Knot, SampleModel, TableSpan, TERMS};

/// What the solver keeps of one pixel between samples but its extrema and flags: a copy
/// out of (or into) its [`FitLanes`] block.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelFit {
    /// Thickness (the Gauss-Newton linearisation point), NaN until the order is known.
    pub thickness_nm: f32,
    /// Thickness change of one interference order, nm.
    pub order_step_nm: f32,
    /// Full-spectrum sums.
    pub gn: GnSums,
    /// Samples seen (the same for every pixel of a row; not stored by
    /// [`FitLanes::set_pixel`]).
    pub samples: u16,
    /// Saturated samples (`+inf` from calibration).
    pub saturated: u16,
    /// Samples without a usable reference (NaN from calibration, or a finite value far
    /// outside any reflectance).
    pub dead: u16,
}

impl Default for PixelFit {
    fn default() -> Self {
        Self {
            thickness_nm: f32::NAN,
            order_step_nm: f32::NAN,
            gn: GnSums::default(),
            samples: 0,
            saturated: 0,
            dead: 0,
        }
    }
}

/// [`PixelFit`] of [`LANES`] pixels of one row as arrays over the pixels, the sample count
/// shared (79 bytes per pixel).
#[derive(Clone, Copy, Debug)]
pub struct FitLanes {
    thickness_nm: [f32; LANES],
    order_step_nm: [f32; LANES],
    /// `sums[k][i]`: sum `k` ([`GnSums::to_terms`]' order) of lane `i`.
    sums: [[f32; LANES]; TERMS],
    gn_samples: [u16; LANES],
    saturated: [u16; LANES],
    dead: [u16; LANES],
    /// Samples seen by every lane (saturates).
    samples: u16,
}

impl Default for FitLanes {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// The samples of one block, padded to [`LANES`].
type Lanes = [f32; LANES];

/// A band's table positions of each lane's thickness and its orders either side: knot and
/// fraction.
struct Positions {
    knot: [[usize; LANES]; 3],
    frac: [Lanes; 3],
}

impl FitLanes {
    /// A block of pixels that have seen nothing.
    pub const EMPTY: Self = Self {
        thickness_nm: [f32::NAN; LANES],
        order_step_nm: [f32::NAN; LANES],
        sums: [[0.0; LANES]; TERMS],
        gn_samples: [0; LANES],
        saturated: [0; LANES],
        dead: [0; LANES],
        samples: 0,
    };

    /// Lane `i` (a copy).
    pub fn pixel(&self, i: usize) -> PixelFit {
        PixelFit {
            thickness_nm: self.thickness_nm[i],
            order_step_nm: self.order_step_nm[i],
            gn: GnSums::from_terms(
                core::array::from_fn(|k| self.sums[k][i]),
                self.gn_samples[i],
            ),
            samples: self.samples,
            saturated: self.saturated[i],
            dead: self.dead[i],
        }
    }

    /// Stores `p` in lane `i` (all but the shared sample count).
    pub fn set_pixel(&mut self, i: usize, p: &PixelFit) {
        self.thickness_nm[i] = p.thickness_nm;
        self.order_step_nm[i] = p.order_step_nm;
        for (k, t) in p.gn.to_terms().into_iter().enumerate() {
            self.sums[k][i] = t;
        }
        self.gn_samples[i] = p.gn.samples;
        self.saturated[i] = p.saturated;
        self.dead[i] = p.dead;
    }

    /// Feeds one band's samples of the block's pixels (`values.len() <= LANES`; `+inf` a
    /// saturated sample, NaN one without a usable reference): counts them, and with the
    /// band's model (`coef` and the angle's `knots`) adds every usable sample of a pixel with
    /// a thickness to its sums, as [`GnSums::add`] does.
    pub fn push(&mut self, values: &[f32], model: Option<(&BandCoef, &[Knot])>) {
        let mut v = [0.0; LANES];
        let n = values.len().min(LANES);
        v[..n].copy_from_slice(&values[..n]);
        self.samples = self.samples.saturating_add(1);
        let mut ok = [false; LANES];
        for i in 0..LANES {
            let x = v[i];
            let good = usable(x);
            let saturated = x.is_infinite();
            self.saturated[i] = self.saturated[i].saturating_add(u16::from(saturated));
            self.dead[i] = self.dead[i].saturating_add(u16::from(!good && !saturated));
            ok[i] = good && self.thickness_nm[i].is_finite();
        }
        let Some((coef, knots)) = model else {
            return;
        };
        if !ok.iter().any(|&o| o) {
            return;
        }
        let u = coef.u as f32;
        // The lanes left to the computed model.
        let mut rest = ok;
        if let Some((span, k)) = coef.table().and_then(|t| Some((t, t.knots(knots)?))) {
            let (at, inside) = self.positions(span, &ok);
            if inside.iter().all(|&i| i) {
                self.add_tabled::<false>(span, k, &at, &inside, &v, u);
            } else {
                self.add_tabled::<true>(span, k, &at, &inside, &v, u);
            }
            for i in 0..LANES {
                rest[i] = ok[i] && !inside[i];
            }
        }
        for i in (0..LANES).filter(|&i| rest[i]) {
            let e = coef.eval(
                knots,
                f64::from(self.thickness_nm[i]),
                f64::from(self.order_step_nm[i]),
            );
            let t = GnSums::terms(e.into(), v[i], u);
            for (k, t) in t.into_iter().enumerate() {
                self.sums[k][i] += t;
            }
            self.gn_samples[i] = self.gn_samples[i].saturating_add(1);
        }
    }

    /// The positions in the band's table of the lanes `ok`, and which lanes have all three
    /// inside it (the others' positions are the first knot's).
    #[inline(always)]
    fn positions(&self, span: TableSpan, ok: &[bool; LANES]) -> (Positions, [bool; LANES]) {
        let mut x = [[0.0; LANES]; 3];
        let mut inside = [false; LANES];
        for i in 0..LANES {
            let (d, s) = (self.thickness_nm[i], self.order_step_nm[i]);
            // In f32: the f64 difference of two f32 values rounded to f32, as
            // [`BandCoef::eval`] takes it, is the f32 difference (53 >= 2 x 24 + 2 bits).
            let d = [d, d - s, d + s];
            let mut all = ok[i];
            for k in 0..3 {
                x[k][i] = span.position(d[k]);
                all &= span.covers(x[k][i]);
            }
            inside[i] = all;
        }
        let mut at = Positions {
            knot: [[0; LANES]; 3],
            frac: [[0.0; LANES]; 3],
        };
        for k in 0..3 {
            for i in 0..LANES {
                let x = if inside[i] { x[k][i] } else { 0.0 };
                let j = x as i32;
                at.knot[k][i] = j as usize;
                at.frac[k][i] = x - j as f32;
            }
        }
        (at, inside)
    }

    /// Adds the samples `v` of the lanes `inside` from the band's knots `k` at positions
    /// `at`. `MASKED`: whether some lanes are not `inside` (their sums are left as they were).
    #[inline(always)]
    fn add_tabled<const MASKED: bool>(
        &mut self,
        span: TableSpan,
        k: &[Knot],
        at: &Positions,
        inside: &[bool; LANES],
        v: &Lanes,
        u: f32,
    ) {
        let pair = |j: usize| match k.get(j..j + 2) {
            Some(&[a, b]) => [a, b],
            _ => [Knot::default(); 2],
        };
        let mut knots = [[[Knot::default(); 2]; LANES]; 3];
        for i in 0..LANES {
            for p in 0..3 {
                knots[p][i] = pair(at.knot[p][i]);
            }
        }
        for i in 0..LANES {
            let s = SampleModel::from_knots(
                knots[0][i],
                at.frac[0][i],
                (knots[1][i], at.frac[1][i]),
                (knots[2][i], at.frac[2][i]),
                span.inv_h(),
            );
            let t = GnSums::terms(s, v[i], u);
            let add = !MASKED || inside[i];
            for (k, t) in t.into_iter().enumerate() {
                let sum = self.sums[k][i];
                self.sums[k][i] = if add { sum + t } else { sum };
            }
            self.gn_samples[i] = self.gn_samples[i].saturating_add(u16::from(add));
        }
    }
}

/// Feeds band samples `values` of one row to the row's blocks
/// (`values.len().div_ceil(LANES)` of them): [`FitLanes::push`] for each block.
pub fn push_row(blocks: &mut [FitLanes], values: &[f32], model: Option<(&BandCoef, &[Knot])>) {
    for (block, v) in blocks.iter_mut().zip(values.chunks(LANES)) {
        block.push(v, model);
    }
}
