//! The per-sample state of a row of pixels at once: thickness, order step, sample counters
//! and full-spectrum sums ([`GnSums`]) of [`LANES`] pixels as arrays over the pixels
//! (structure of arrays), like the tracker's [`crate::track::row::TrackerLanes`].
//!
//! A band's row reaches all the block's pixels together, so the table positions, the
//! interpolation and a pixel's own eight sums are computed lane by lane in loops the
//! compiler vectorises; only fetching each pixel's knots is one lane at a time. The index's
//! eight sums go to [`IndexLanes`] for the pixels [`IndexSampling`] picks: lane by lane too
//! where every pixel keeps them, else from each lane's index derivative and residual for
//! the few that do. A pixel whose thickness or order neighbours fall outside the band's
//! table, or a band without a table, takes the computed model one lane at a time
//! ([`BandCoef::eval`]): both give the sums [`GnSums::add`] gives, bit for bit.

// The lane loops index parallel arrays by lane: that is the form that vectorises.
#![allow(clippy::needless_range_loop)]

use crate::track::row::LANES;
use crate::track::usable;

use super::refine::{
    BandCoef, GnSums, Knot, SampleModel, TableSpan, G_D_TERM, INDEX_TERMS, PIXEL_TERMS, SSE_TERM,
};

/// A block's thicknesses and sums after an angle end's step ([`FitLanes::steps`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LaneSteps {
    /// Thickness after the step, nm.
    pub thickness_nm: [f32; LANES],
    /// The thickness gradient after it.
    pub g_d: [f32; LANES],
    /// The squared error after it.
    pub sse: [f32; LANES],
}

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
    /// Saturated samples (`+inf` from calibration), up to [`BAD_COUNT_MAX`].
    pub saturated: u8,
    /// Samples without a usable reference (NaN from calibration, or a finite value far
    /// outside any reflectance), up to [`BAD_COUNT_MAX`].
    pub dead: u8,
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
/// shared (45 bytes per pixel): all but the index's sums, which [`IndexLanes`] keep for a
/// sample of the pixels.
#[derive(Clone, Copy, Debug)]
pub struct FitLanes {
    thickness_nm: [f32; LANES],
    order_step_nm: [f32; LANES],
    /// `sums[k][i]`: sum `k` ([`GnSums::to_pixel_terms`]' order) of lane `i`.
    sums: [[f32; LANES]; PIXEL_TERMS],
    gn_samples: [u16; LANES],
    saturated: [u8; LANES],
    dead: [u8; LANES],
    /// Samples seen by every lane (saturates).
    samples: u16,
}

impl Default for FitLanes {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// Where the thickness-index cross terms (`h_dp`) are in [`GnSums::to_pixel_terms`]' array.
const CROSS_TERMS: core::ops::RangeInclusive<usize> = 1..=3;

/// The samples of one block, padded to [`LANES`].
type Lanes = [f32; LANES];

/// Where a pixel's saturated and dead counts stop: a byte each (2 bytes a pixel fewer than
/// `u16`). A count that reached it is "this many or more", which the results flag whatever
/// the share of the samples (the share of [`BAD_COUNT_MAX`] of 2550 or more samples would
/// not be above a tenth; a pixel with 255 unusable samples is not to be trusted anyway).
pub const BAD_COUNT_MAX: u8 = u8::MAX;

/// Pixels that keep the index's sums in a large image by default
/// (the solver options' `index_pixels`): about this many (a 1 Mpix sensor's
/// index step from one pixel in 16; every pixel of a sensor under 131072).
pub const INDEX_PIXELS: usize = 65_536;

/// Which pixels keep the shared index's sums ([`IndexLanes`]): one in `stride` (a power of
/// two), on the diagonals `(row + col) % stride == 0`, so that every row and every column
/// of the image has its share (a film in a narrow strip of either is sampled). The index's
/// step is the least-squares step of these pixels (their thickness eliminated); every
/// pixel's thickness steps with it. The same pixels give the image-wide statistics: the
/// extremum-ratio votes and window sums, the RMS median and the pooled noise. A row's
/// sampled pixels are packed, in column order, into
/// [`IndexSampling::blocks_per_row`] blocks; with `stride` 1 a pixel's place in them is its
/// place in the row's [`FitLanes`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IndexSampling {
    /// `log2(stride)`.
    shift: u32,
}

impl Default for IndexSampling {
    /// Every pixel.
    fn default() -> Self {
        Self::ALL
    }
}

impl IndexSampling {
    /// Every pixel.
    pub const ALL: Self = Self { shift: 0 };

    /// One pixel in `stride` rounded down to a power of two (at least 1).
    pub fn one_in(stride: usize) -> Self {
        Self {
            shift: stride.max(1).ilog2(),
        }
    }

    /// About `pixels` of a `width` x `height` sensor (at least that many, fewer than twice as
    /// many; every pixel of a sensor with fewer than twice as many).
    pub fn for_sensor(width: usize, height: usize, pixels: usize) -> Self {
        Self::one_in(width.saturating_mul(height) / pixels.max(1))
    }

    /// One pixel in this many keeps the sums.
    pub fn stride(&self) -> usize {
        1 << self.shift
    }

    /// `stride - 1`, for the remainders.
    fn mask(&self) -> usize {
        self.stride() - 1
    }

    /// Places for sampled pixels in a row of `width` (enough for the row with the most).
    pub fn slots_per_row(&self, width: usize) -> usize {
        (width + self.mask()) >> self.shift
    }

    /// [`IndexLanes`] blocks per row of `width`.
    pub fn blocks_per_row(&self, width: usize) -> usize {
        self.slots_per_row(width).div_ceil(LANES)
    }

    /// The first sampled column of image row `row`.
    pub fn first_col(&self, row: usize) -> usize {
        row.wrapping_neg() & self.mask()
    }

    /// The sampled columns of image row `row` of a row of `width`, in order.
    pub fn cols(&self, row: usize, width: usize) -> core::iter::StepBy<core::ops::Range<usize>> {
        (self.first_col(row).min(width)..width).step_by(self.stride())
    }

    /// The place of pixel (`row`, `col`) among its row's sampled pixels, if it is one.
    #[inline]
    pub fn slot(&self, row: usize, col: usize) -> Option<usize> {
        ((row + col) & self.mask() == 0).then(|| col >> self.shift)
    }

    /// Where block `block` of image row `row` keeps its sampled pixels' sums, given the
    /// row's index blocks `row_blocks` (`lanes` of the block in use).
    fn block<'a>(
        &self,
        row_blocks: &'a mut [IndexLanes],
        row: usize,
        block: usize,
        lanes: usize,
    ) -> BlockIndex<'a> {
        if self.shift == 0 {
            return row_blocks
                .get_mut(block)
                .map_or(BlockIndex::None, BlockIndex::Lanes);
        }
        let start = block * LANES;
        // The block's first sampled column.
        let col =
            start + ((self.first_col(row) + self.stride() - (start & self.mask())) & self.mask());
        if col >= start + lanes {
            return BlockIndex::None;
        }
        BlockIndex::Slots {
            row: row_blocks,
            lane: col - start,
            stride: self.stride(),
            slot: col >> self.shift,
        }
    }
}

/// The index's sums ([`GnSums::to_index_terms`]) of [`LANES`] sampled pixels, as arrays over
/// the pixels (32 bytes a pixel).
#[derive(Clone, Copy, Debug)]
pub struct IndexLanes {
    /// `sums[k][i]`: sum `k` of lane `i`.
    sums: [[f32; LANES]; INDEX_TERMS],
}

impl Default for IndexLanes {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl IndexLanes {
    /// A block of pixels that have seen nothing.
    pub const EMPTY: Self = Self {
        sums: [[0.0; LANES]; INDEX_TERMS],
    };

    /// Lane `i`'s sums.
    pub fn terms(&self, i: usize) -> [f32; INDEX_TERMS] {
        core::array::from_fn(|k| self.sums[k][i])
    }

    /// Sets lane `i`'s sums.
    pub fn set_terms(&mut self, i: usize, t: [f32; INDEX_TERMS]) {
        for (k, t) in t.into_iter().enumerate() {
            self.sums[k][i] = t;
        }
    }

    fn add(&mut self, i: usize, t: [f32; INDEX_TERMS]) {
        for (k, t) in t.into_iter().enumerate() {
            self.sums[k][i] += t;
        }
    }
}

/// Where a block of a row keeps its pixels' index sums ([`IndexSampling`]).
pub enum BlockIndex<'a> {
    /// None of its pixels keeps them.
    None,
    /// Every pixel, lane for lane.
    Lanes(&'a mut IndexLanes),
    /// Lanes `lane`, `lane + stride`, ... (packed from place `slot` of the row's blocks
    /// `row` on; `stride` a power of two).
    Slots {
        /// The row's index blocks.
        row: &'a mut [IndexLanes],
        /// The block's first sampled lane.
        lane: usize,
        /// Lanes between sampled ones.
        stride: usize,
        /// Its place in `row`.
        slot: usize,
    },
}

impl BlockIndex<'_> {
    /// Adds `t` to lane `i`'s sums if it keeps them.
    #[inline]
    fn add(&mut self, i: usize, t: [f32; INDEX_TERMS]) {
        match self {
            Self::None => {}
            Self::Lanes(b) => b.add(i, t),
            Self::Slots {
                row,
                lane,
                stride,
                slot,
            } => {
                if i >= *lane && (i - *lane) & (*stride - 1) == 0 {
                    let at = *slot + (i - *lane) / *stride;
                    if let Some(b) = row.get_mut(at / LANES) {
                        b.add(at % LANES, t);
                    }
                }
            }
        }
    }
}

/// A lane mask: 1 for the lanes in it, else 0 (not `bool`: a mask of the lanes' width
/// vectorises).
type Mask = [u32; LANES];

/// Each lane's knots (value and slope) at one table position: the knot before and after.
#[derive(Clone, Copy)]
struct Pairs {
    m: [Lanes; 2],
    slope_h: [Lanes; 2],
}

/// The lanes' knots at their three table positions and the index derivative at the
/// thickness's two, gathered for one block at a time: the caller keeps one across a row's
/// blocks ([`push_row`]), so that it is not zeroed for every block. A lane's stale or
/// clamped knots are never added: only lanes inside the table are.
#[derive(Clone, Copy)]
pub struct KnotGather {
    pairs: [Pairs; 3],
    j_n: [Lanes; 2],
    /// Whether the knots are read with AVX2.
    avx2: bool,
}

impl KnotGather {
    /// Nothing gathered yet; the knots read with AVX2 if `wide` and the CPU has it (as
    /// [`crate::simd::wide`] decides its build: the portable one reads them lane by lane).
    pub fn new(wide: bool) -> Self {
        Self {
            pairs: [Pairs::ZERO; 3],
            j_n: [[0.0; LANES]; 2],
            avx2: wide && crate::simd::has_avx2_fma(),
        }
    }
}

/// The lanes' knots at their three table positions, as [`FitLanes::add_from`] takes them.
struct Tabled<'a> {
    /// At the thickness, one order thinner, one order thicker.
    pairs: &'a [Pairs; 3],
    /// The index derivative at the thickness's two knots.
    j_n: &'a [Lanes; 2],
    /// The fractions of the three positions.
    frac: &'a [Lanes; 3],
    /// The band's knots per nm.
    inv_h: f32,
}

impl Pairs {
    const ZERO: Self = Self {
        m: [[0.0; LANES]; 2],
        slope_h: [[0.0; LANES]; 2],
    };

    /// Lane `i`'s two knots, `j_n` their index derivatives.
    #[inline(always)]
    fn knots(&self, i: usize, j_n: [f32; 2]) -> Knot {
        Knot {
            m: [self.m[0][i], self.m[1][i]],
            slope_h: [self.slope_h[0][i], self.slope_h[1][i]],
            j_n,
        }
    }
}

impl FitLanes {
    /// A block of pixels that have seen nothing.
    pub const EMPTY: Self = Self {
        thickness_nm: [f32::NAN; LANES],
        order_step_nm: [f32::NAN; LANES],
        sums: [[0.0; LANES]; PIXEL_TERMS],
        gn_samples: [0; LANES],
        saturated: [0; LANES],
        dead: [0; LANES],
        samples: 0,
    };

    /// Lane `i` (a copy), with the index's sums `index` (zeros for a pixel that keeps none).
    pub fn pixel(&self, i: usize, index: [f32; INDEX_TERMS]) -> PixelFit {
        PixelFit {
            thickness_nm: self.thickness_nm[i],
            order_step_nm: self.order_step_nm[i],
            gn: GnSums::from_terms(
                core::array::from_fn(|k| self.sums[k][i]),
                index,
                self.gn_samples[i],
            ),
            samples: self.samples,
            saturated: self.saturated[i],
            dead: self.dead[i],
        }
    }

    /// Every lane's thickness, `g_d` and squared error after the angle end's step with the
    /// index step `dp`, as [`GnSums::thickness_step`] (clamped to a quarter of the lane's
    /// order step) and [`GnSums::shift`] give them for a pixel without index sums, the same
    /// operations in the same order (the same results but for the sign of a zero). One loop
    /// whose lanes do not wait on each other: pixel by pixel, each step's chain of dependent
    /// `f64` operations made half the update pass (criterion, `end_update_*_1in4`). A lane
    /// without a thickness, samples or slope gets a meaningless step: the caller picks.
    pub fn steps(&self, dp: [f64; 3]) -> LaneSteps {
        let mut out = LaneSteps {
            thickness_nm: [f32::NAN; LANES],
            g_d: [0.0; LANES],
            sse: [0.0; LANES],
        };
        let s = &self.sums;
        for i in 0..LANES {
            let h_dd = f64::from(s[0][i]);
            let h_dp = [s[1][i], s[2][i], s[3][i]].map(f64::from);
            let g_d = f64::from(s[G_D_TERM][i]);
            let mut g = g_d;
            for (h, d) in h_dp.iter().zip(dp) {
                g -= h * d;
            }
            let quarter = 0.25 * f64::from(self.order_step_nm[i]);
            let step = g / h_dd;
            let dd = if step < -quarter {
                -quarter
            } else if step > quarter {
                quarter
            } else {
                step
            };
            out.thickness_nm[i] = (f64::from(self.thickness_nm[i]) + dd) as f32;
            let mut sse = f64::from(s[SSE_TERM][i]) - 2.0 * g_d * dd + h_dd * dd * dd;
            let mut new_g_d = g_d - h_dd * dd;
            for k in 0..3 {
                sse += 2.0 * h_dp[k] * dd * dp[k];
                new_g_d -= h_dp[k] * dp[k];
            }
            out.g_d[i] = new_g_d as f32;
            out.sse[i] = sse.max(0.0) as f32;
        }
        out
    }

    /// Stores lane `i`'s thickness, `g_d` and squared error after a step
    /// ([`FitLanes::steps`]), the rest of it unchanged.
    pub fn set_step(&mut self, i: usize, thickness_nm: f32, g_d: f32, sse: f32) {
        self.thickness_nm[i] = thickness_nm;
        self.sums[G_D_TERM][i] = g_d;
        self.sums[SSE_TERM][i] = sse;
    }

    /// Lane `i`'s RMS residual at its linearisation point, `None` without samples in its
    /// sums (what `self.pixel(i).gn.rms()` gives, without copying the other sums).
    pub fn rms(&self, i: usize) -> Option<f32> {
        let n = self.gn_samples[i];
        (n > 0).then(|| libm::sqrtf(self.sums[SSE_TERM][i] / f32::from(n)))
    }

    /// Starts lane `i` at `thickness_nm`, one order `order_step_nm` thick (the rest of it
    /// unchanged).
    pub fn seed(&mut self, i: usize, thickness_nm: f32, order_step_nm: f32) {
        self.thickness_nm[i] = thickness_nm;
        self.order_step_nm[i] = order_step_nm;
    }

    /// Stores `p` in lane `i` (all but the shared sample count and the index's sums).
    pub fn set_pixel(&mut self, i: usize, p: &PixelFit) {
        self.thickness_nm[i] = p.thickness_nm;
        self.order_step_nm[i] = p.order_step_nm;
        for (k, t) in p.gn.to_pixel_terms().into_iter().enumerate() {
            self.sums[k][i] = t;
        }
        self.gn_samples[i] = p.gn.samples;
        self.saturated[i] = p.saturated;
        self.dead[i] = p.dead;
    }

    /// Feeds one band's samples of the block's pixels (`values.len() <= LANES`; `+inf` a
    /// saturated sample, NaN one without a usable reference): counts them, and with the
    /// band's model (`coef` and the angle's `knots`) adds every usable sample of a pixel with
    /// a thickness to its sums, as [`GnSums::add`] does (the index's sums to `index`'s).
    /// `gather` is scratch space, kept across a row's blocks.
    ///
    /// Without `INDEX` (a held index: nothing steps it), the samples add neither the
    /// index's sums nor the thickness-index cross terms (`h_dp` stays as it is) and the index
    /// derivative is not fetched.
    #[inline(always)]
    pub fn push<const INDEX: bool>(
        &mut self,
        values: &[f32],
        model: Option<(&BandCoef, &[Knot])>,
        mut index: BlockIndex<'_>,
        gather: &mut KnotGather,
    ) {
        // A whole block copied as one array (a copy of a slice's length is a call to
        // `memmove`: a twentieth of the kernel); a row's last, short one padded.
        let v = match <&Lanes>::try_from(values) {
            Ok(whole) => *whole,
            Err(_) => {
                let mut v = [0.0; LANES];
                let n = values.len().min(LANES);
                v[..n].copy_from_slice(&values[..n]);
                v
            }
        };
        self.samples = self.samples.saturating_add(1);
        if !v.iter().fold(true, |a, &x| a & usable(x)) {
            self.count_bad(&v);
        }
        let mut ok = [0; LANES];
        for i in 0..LANES {
            ok[i] = u32::from(usable(v[i]) & self.thickness_nm[i].is_finite());
        }
        let Some((coef, knots)) = model else {
            return;
        };
        if ok.iter().fold(0, |a, &o| a | o) == 0 {
            return;
        }
        let u = coef.u as f32;
        // The lanes left to the computed model.
        let mut rest = ok;
        if let Some((span, k)) = coef.table().and_then(|t| Some((t, t.knots(knots)?))) {
            let inside = self.add_tabled::<INDEX>((span, k), &ok, &v, u, &mut index, gather);
            for i in 0..LANES {
                rest[i] = ok[i] & !inside[i];
            }
        }
        if rest.iter().fold(0, |a, &o| a | o) == 0 {
            return;
        }
        for i in (0..LANES).filter(|&i| rest[i] != 0) {
            let e = coef.eval(
                knots,
                f64::from(self.thickness_nm[i]),
                f64::from(self.order_step_nm[i]),
            );
            let s: SampleModel = e.into();
            for (k, t) in GnSums::pixel_terms(s, v[i], u).into_iter().enumerate() {
                if INDEX || !CROSS_TERMS.contains(&k) {
                    self.sums[k][i] += t;
                }
            }
            if INDEX {
                index.add(i, GnSums::index_terms(s.j_n, v[i] - s.m, u));
            }
            self.gn_samples[i] = self.gn_samples[i].saturating_add(1);
        }
    }

    /// Counts the saturated and dead samples of `v`.
    #[inline(never)]
    fn count_bad(&mut self, v: &Lanes) {
        for i in 0..LANES {
            let saturated = v[i].is_infinite();
            let dead = !usable(v[i]) && !saturated;
            self.saturated[i] = self.saturated[i].saturating_add(u8::from(saturated));
            self.dead[i] = self.dead[i].saturating_add(u8::from(dead));
        }
    }

    /// Adds the samples `v` of the lanes `ok` (1, else 0) whose thickness and neighbouring
    /// orders all fall inside the band's table (`span`, its knots `k`) from the table;
    /// returns which (1, else 0).
    #[inline(always)]
    fn add_tabled<const INDEX: bool>(
        &mut self,
        (span, k): (TableSpan, &[Knot]),
        ok: &Mask,
        v: &Lanes,
        u: f32,
        index: &mut BlockIndex<'_>,
        gather: &mut KnotGather,
    ) -> Mask {
        // A table of under two knots has no lane inside.
        let Some(last) = k.len().checked_sub(2) else {
            return [0; LANES];
        };
        // Positions of the thickness and the orders either side: knot and fraction.
        // (Separate arrays, each zeroed in place: one struct of them would be zeroed by a
        // call to `memset`, moved by one to `memcpy`.)
        let mut frac = [[0.0; LANES]; 3];
        let mut knot = [[0u32; LANES]; 3];
        let mut inside = [0; LANES];
        for i in 0..LANES {
            let (d, s) = (self.thickness_nm[i], self.order_step_nm[i]);
            // In f32: the f64 difference of two f32 values rounded to f32, as
            // [`BandCoef::eval`] takes it, is the f32 difference (53 >= 2 x 24 + 2 bits).
            let x = [span.position(d), span.position(d - s), span.position(d + s)];
            let all = (ok[i] != 0) & span.covers(x[0]) & span.covers(x[1]) & span.covers(x[2]);
            inside[i] = u32::from(all);
            for p in 0..3 {
                // Lanes not inside: the first knot.
                let (j, f) = knot_of(if all { x[p] } else { 0.0 });
                knot[p][i] = j;
                frac[p][i] = f;
            }
        }
        // Each lane's knots, its knot clamped to the table rather than checked (a branch per
        // lane and position cost an eighth of the kernel): a lane outside reads the last
        // pair, which is never added.
        let KnotGather { pairs, j_n, avx2 } = gather;
        for p in 0..3 {
            for i in 0..LANES {
                knot[p][i] = knot[p][i].min(last as u32);
            }
        }
        for p in 0..3 {
            read_pairs(k, &knot[p], &mut pairs[p], *avx2);
        }
        if INDEX {
            for i in 0..LANES {
                let r = &k[knot[0][i] as usize];
                j_n[0][i] = r.j_n[0];
                j_n[1][i] = r.j_n[1];
            }
        }
        let at = Tabled {
            pairs,
            j_n,
            frac: &frac,
            inv_h: span.inv_h(),
        };
        let all = inside.iter().fold(1, |a, &i| a & i) == 1;
        if !INDEX {
            self.add_with::<false, 0>(all, &at, &inside, v, u, &mut []);
            return inside;
        }
        match index {
            BlockIndex::Lanes(x) => self.add_with::<true, _>(all, &at, &inside, v, u, &mut x.sums),
            BlockIndex::None => self.add_with::<true, 0>(all, &at, &inside, v, u, &mut []),
            BlockIndex::Slots { .. } => {
                // A few lanes keep the index's sums: those from each lane's index derivative
                // and residual, kept by the lane loop.
                let mut kept = [[0.0; LANES]; 2];
                self.add_with::<true, 2>(all, &at, &inside, v, u, &mut kept);
                if let BlockIndex::Slots { lane, stride, .. } = *index {
                    for i in (lane..LANES).step_by(stride).filter(|&i| inside[i] != 0) {
                        index.add(i, GnSums::index_terms(kept[0][i], kept[1][i], u));
                    }
                }
            }
        }
        inside
    }

    /// [`FitLanes::add_from`], unmasked if `all` lanes are inside.
    #[inline(always)]
    fn add_with<const INDEX: bool, const N: usize>(
        &mut self,
        all: bool,
        at: &Tabled<'_>,
        inside: &Mask,
        v: &Lanes,
        u: f32,
        x: &mut [Lanes; N],
    ) {
        if all {
            self.add_from::<false, INDEX, N>(at, inside, v, u, x);
        } else {
            self.add_from::<true, INDEX, N>(at, inside, v, u, x);
        }
    }

    /// Adds the samples `v` from the lanes' knots `at`. `MASKED`: only the lanes `inside`
    /// (1, else 0); the others keep their sums (an added zero could change a zero's sign).
    /// Without `INDEX`, no cross terms (and `N` is 0).
    /// The index's: with [`INDEX_TERMS`] rows, `x` gets them lane for lane; with two, each
    /// lane's index derivative and residual; with none, nothing.
    #[inline(always)]
    fn add_from<const MASKED: bool, const INDEX: bool, const N: usize>(
        &mut self,
        at: &Tabled<'_>,
        inside: &Mask,
        v: &Lanes,
        u: f32,
        x: &mut [Lanes; N],
    ) {
        let [c, lo, hi] = at.pairs;
        // The lanes' models first, then their sums: two short loops vectorise where one
        // long one was left scalar.
        let mut model = [[0.0; LANES]; 5];
        for i in 0..LANES {
            let s = SampleModel::from_knots(
                c.knots(i, [at.j_n[0][i], at.j_n[1][i]]),
                at.frac[0][i],
                (lo.knots(i, [0.0; 2]), at.frac[1][i]),
                (hi.knots(i, [0.0; 2]), at.frac[2][i]),
                at.inv_h,
            );
            model[0][i] = s.m;
            model[1][i] = s.j_d;
            model[2][i] = s.j_n;
            model[3][i] = s.m_minus;
            model[4][i] = s.m_plus;
        }
        for i in 0..LANES {
            let s = SampleModel {
                m: model[0][i],
                j_d: model[1][i],
                j_n: model[2][i],
                m_minus: model[3][i],
                m_plus: model[4][i],
            };
            let add = !MASKED || inside[i] != 0;
            for (k, t) in GnSums::pixel_terms(s, v[i], u).into_iter().enumerate() {
                if INDEX || !CROSS_TERMS.contains(&k) {
                    let sum = self.sums[k][i];
                    self.sums[k][i] = if add { sum + t } else { sum };
                }
            }
            let r = v[i] - s.m;
            if N == INDEX_TERMS {
                for (k, t) in GnSums::index_terms(s.j_n, r, u).into_iter().enumerate() {
                    let sum = x[k][i];
                    x[k][i] = if add { sum + t } else { sum };
                }
            } else if N == 2 {
                x[0][i] = s.j_n;
                x[1][i] = r;
            }
        }
        for i in 0..LANES {
            let add = !MASKED || inside[i] != 0;
            self.gn_samples[i] = self.gn_samples[i].saturating_add(u16::from(add));
        }
    }
}

/// Each lane's value and slope at both ends of its interval `knot[i]` (below `k.len() - 1`)
/// into `pair`: with AVX2 ([`read_avx2`]) if `avx2` (the CPU has it), else lane by lane.
#[inline(always)]
fn read_pairs(k: &[Knot], knot: &[u32; LANES], pair: &mut Pairs, avx2: bool) {
    #[cfg(all(feature = "std", target_arch = "x86_64"))]
    if avx2 {
        // SAFETY: AVX2 was found ([`KnotGather::new`]); every knot indexes `k`.
        #[allow(unsafe_code)]
        unsafe {
            read_avx2(k, knot, pair);
        }
        return;
    }
    let _ = avx2;
    for i in 0..LANES {
        let r = &k[knot[i] as usize];
        pair.m[0][i] = r.m[0];
        pair.slope_h[0][i] = r.slope_h[0];
        pair.m[1][i] = r.m[1];
        pair.slope_h[1][i] = r.slope_h[1];
    }
}

/// Reads the value and slope at both ends of the intervals `knot` (each below
/// `k.len() - 1`) of all lanes into `pair`: each lane's record is one 16-byte read, four lanes'
/// records a 4 x 4 transposition in registers (lane by lane, each of the four values took a
/// read and a write of its own, most of the per-sample work).
///
/// # Safety
/// The CPU has AVX2 and every `knot[i]` indexes `k`.
#[cfg(all(feature = "std", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
#[inline]
unsafe fn read_avx2(k: &[Knot], knot: &[u32; LANES], pair: &mut Pairs) {
    use core::arch::x86_64::*;
    let base = k.as_ptr();
    for g in (0..LANES).step_by(8) {
        // SAFETY: `knot[g + l]` indexes `k` (the caller's promise); a `Knot` is 32-byte
        // aligned and starts with the four values (`repr(C)`).
        let read = |l: usize| unsafe { _mm_load_ps(base.add(knot[g + l] as usize).cast()) };
        // Lanes l and l + 4 side by side, each `[m0, m1, s0, s1]` (the record's order).
        let q = [0, 1, 2, 3].map(|l| _mm256_set_m128(read(l + 4), read(l)));
        let m01 = _mm256_unpacklo_ps(q[0], q[1]);
        let s01 = _mm256_unpackhi_ps(q[0], q[1]);
        let m23 = _mm256_unpacklo_ps(q[2], q[3]);
        let s23 = _mm256_unpackhi_ps(q[2], q[3]);
        let pd = _mm256_castps_pd;
        let ps = _mm256_castpd_ps;
        let m0 = ps(_mm256_unpacklo_pd(pd(m01), pd(m23)));
        let m1 = ps(_mm256_unpackhi_pd(pd(m01), pd(m23)));
        let s0 = ps(_mm256_unpacklo_pd(pd(s01), pd(s23)));
        let s1 = ps(_mm256_unpackhi_pd(pd(s01), pd(s23)));
        // SAFETY: `g + 8 <= LANES`: eight floats of each array.
        unsafe {
            _mm256_storeu_ps(pair.m[0][g..].as_mut_ptr(), m0);
            _mm256_storeu_ps(pair.slope_h[0][g..].as_mut_ptr(), s0);
            _mm256_storeu_ps(pair.m[1][g..].as_mut_ptr(), m1);
            _mm256_storeu_ps(pair.slope_h[1][g..].as_mut_ptr(), s1);
        }
    }
}

/// The knot and fraction of a table position `0 <= x < 2^22`: `(x as u32, x - knot as f32)`
/// (what [`BandCoef::eval`] computes), without a float-to-integer conversion, which would
/// keep the lane loop from vectorising: `x + 2^23` is rounded to an integer (the f32 spacing
/// there is 1) whose bits, less those of `2^23`, are that integer; one less where it rounded
/// up.
#[inline(always)]
fn knot_of(x: f32) -> (u32, f32) {
    const TWO_23: f32 = 8_388_608.0;
    let r = x + TWO_23;
    let near = r - TWO_23;
    let up = near > x;
    let floor = if up { near - 1.0 } else { near };
    let j = (r.to_bits() - TWO_23.to_bits()) - u32::from(up);
    (j, x - floor)
}

/// The least thickness less its order step and the greatest plus it over the lanes of
/// `blocks` with both finite (`[inf, -inf]` if none): where their samples read the models.
/// Kept lane by lane and reduced at the end, so that the loop vectorises (one pass over a
/// 1 MP image's blocks took 9.6 ms lane by lane with `f32::min`).
pub fn thickness_span(blocks: &[FitLanes]) -> [f32; 2] {
    let mut lo = [f32::INFINITY; LANES];
    let mut hi = [f32::NEG_INFINITY; LANES];
    for b in blocks {
        for i in 0..LANES {
            let (d, s) = (b.thickness_nm[i], b.order_step_nm[i]);
            let (a, z) = (d - s, d + s);
            // Finite only if both are (NaN and infinities give NaN or infinity).
            let keep = (z - a).is_finite();
            lo[i] = if keep && a < lo[i] { a } else { lo[i] };
            hi[i] = if keep && z > hi[i] { z } else { hi[i] };
        }
    }
    let min = lo
        .iter()
        .fold(f32::INFINITY, |m, &x| if x < m { x } else { m });
    let max = hi
        .iter()
        .fold(f32::NEG_INFINITY, |m, &x| if x > m { x } else { m });
    [min, max]
}

/// Feeds band samples `values` of image row `row` to the row's blocks
/// (`values.len().div_ceil(LANES)` of them): [`FitLanes::push`] for each block, the
/// index's sums of the pixels `sampling` picks to the row's index blocks `index` (`None`:
/// the index is held, no pixel adds them, [`FitLanes::push`] without `INDEX`). `wide`: as
/// [`crate::simd::wide`] was asked to run (the table's knots read with AVX2 in its build).
#[inline(always)]
pub fn push_row(
    blocks: &mut [FitLanes],
    values: &[f32],
    model: Option<(&BandCoef, &[Knot])>,
    index: Option<(IndexSampling, usize, &mut [IndexLanes])>,
    wide: bool,
) {
    let mut gather = KnotGather::new(wide);
    let rows = blocks.iter_mut().zip(values.chunks(LANES));
    match index {
        Some((sampling, row, index)) => {
            for (b, (block, v)) in rows.enumerate() {
                let at = sampling.block(index, row, b, v.len());
                block.push::<true>(v, model, at, &mut gather);
            }
        }
        None => {
            for (block, v) in rows {
                block.push::<false>(v, model, BlockIndex::None, &mut gather);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::Polarization;
    use crate::solve::IndexModel;

    #[test]
    fn knot_of_is_the_conversion() {
        for k in 0..200_000u32 {
            let x = k as f32 * 0.081_93 + (k % 7) as f32 * 1e-4;
            let j = x as u32;
            assert_eq!(knot_of(x), (j, x - j as f32), "{x}");
        }
        assert_eq!(knot_of(0.0), (0, 0.0));
    }

    /// The block's steps are the scalar step and shift of each pixel without index sums,
    /// bit for bit: steps inside a quarter order, clamped either way, and lanes with and
    /// without a first-order slope of the index.
    #[test]
    fn lane_steps_are_the_scalar_steps() {
        let dp = [2e-3, -7e-4, 3e-5];
        let mut block = FitLanes::EMPTY;
        let mut fits = [PixelFit::default(); LANES];
        for (i, f) in fits.iter_mut().enumerate() {
            let x = i as f32;
            f.thickness_nm = 300.0 + 37.0 * x;
            f.order_step_nm = 180.0 + x;
            f.gn = GnSums {
                h_dd: 0.5 + 0.01 * x,
                h_dp: [
                    40.0 - 3.0 * x,
                    if i % 3 == 0 { 0.0 } else { -8.0 + x },
                    0.25 * x,
                ],
                // Steps from well inside a quarter order to 4 times beyond it, both signs.
                g_d: (x - 15.5) * (0.05 + 2.0 * (i % 5) as f32),
                sse: 0.5 + 0.1 * x,
                sse_minus: 1.0,
                sse_plus: 2.0,
                samples: 100,
                ..GnSums::default()
            };
            block.set_pixel(i, f);
        }
        let steps = block.steps(dp);
        let mut clamped = 0;
        for (i, f) in fits.iter().enumerate() {
            let quarter = 0.25 * f64::from(f.order_step_nm);
            let free = f.gn.thickness_step(dp);
            clamped += usize::from(free.abs() > quarter);
            let dd = free.clamp(-quarter, quarter);
            let mut g = f.gn;
            g.shift(dd, dp);
            let d = (f64::from(f.thickness_nm) + dd) as f32;
            assert_eq!(steps.thickness_nm[i].to_bits(), d.to_bits(), "lane {i}");
            assert_eq!(steps.g_d[i].to_bits(), g.g_d.to_bits(), "lane {i}");
            assert_eq!(steps.sse[i].to_bits(), g.sse.to_bits(), "lane {i}");
        }
        assert!(clamped > 4 && clamped < LANES - 4, "{clamped} clamped");
    }

    /// A row block gives every pixel the sums, counts and sample numbers the scalar
    /// [`GnSums::add`] gives it, bit for bit (the index's sums to the pixels that keep them,
    /// every pixel, one in 2, 4 or 64 of them; with the index held, none, and no cross
    /// terms either): pixels inside the table, at and beyond its
    /// ends (computed), without a thickness, and samples saturated, dead or corrupted.
    #[test]
    fn lanes_match_the_scalar_sums() {
        for wide in [false, true] {
            for (stride, row) in [(1, 0), (2, 1), (4, 0), (4, 7), (64, 5), (64, 40)] {
                lanes_match_the_scalar_sums_with(Some(IndexSampling::one_in(stride)), row, wide);
            }
            lanes_match_the_scalar_sums_with(None, 0, wide);
        }
    }

    /// Feeds `values` of image row `row` to a one-block row (`lanes`, its index blocks
    /// `index`) under `sampling`, with the band's model, and the same samples to `scalar`
    /// the scalar way (counts, and [`GnSums::add`] for a usable sample of a pixel with a
    /// thickness).
    fn feed(
        (lanes, index): (&mut [FitLanes; 1], &mut [IndexLanes; 1]),
        scalar: &mut [PixelFit],
        values: &[f32],
        (coef, knots): (&BandCoef, &[Knot]),
        (sampling, row, wide): (Option<IndexSampling>, usize, bool),
    ) {
        let index = sampling.map(|s| (s, row, &mut index[..s.blocks_per_row(values.len())]));
        push_row(lanes, values, Some((coef, knots)), index, wide);
        for (p, &v) in scalar.iter_mut().zip(values) {
            p.samples += 1;
            if v.is_infinite() {
                p.saturated = p.saturated.saturating_add(1);
            } else if !usable(v) {
                p.dead = p.dead.saturating_add(1);
            } else if p.thickness_nm.is_finite() {
                let (d, o) = (f64::from(p.thickness_nm), f64::from(p.order_step_nm));
                p.gn.add(coef, knots, d, o, f64::from(v));
            }
        }
    }

    /// Lane `i` of `lanes` with its index sums as `row`'s index blocks `index` keep them
    /// (zeros where they do not; with the index held, `None`, what pixel `i`'s place would
    /// hold under every pixel's).
    fn lane(
        lanes: &FitLanes,
        sampling: Option<IndexSampling>,
        row: usize,
        i: usize,
        index: &[IndexLanes],
    ) -> PixelFit {
        let terms = sampling
            .unwrap_or(IndexSampling::ALL)
            .slot(row, i)
            .map_or([0.0; INDEX_TERMS], |k| index[k / LANES].terms(k % LANES));
        lanes.pixel(i, terms)
    }

    /// The sums a pixel of `row` keeps under `sampling`, of the scalar's `p`: with the index
    /// held (`None`), neither the index's nor the cross terms.
    fn kept(p: &PixelFit, sampling: Option<IndexSampling>, row: usize, i: usize) -> [u32; 16] {
        let index = match sampling.and_then(|s| s.slot(row, i)) {
            Some(_) => p.gn.to_index_terms(),
            None => [0.0; INDEX_TERMS],
        };
        let mut pixel = p.gn.to_pixel_terms();
        if sampling.is_none() {
            for k in CROSS_TERMS {
                pixel[k] = 0.0;
            }
        }
        let mut t = [0; 16];
        t[..8].copy_from_slice(&pixel.map(f32::to_bits));
        t[8..].copy_from_slice(&index.map(f32::to_bits));
        t
    }

    fn lanes_match_the_scalar_sums_with(sampling: Option<IndexSampling>, row: usize, wide: bool) {
        let (coefs, knots, first) = bands();
        let knots = &knots[..first];
        let n = 29;
        let step = 130.0f32;
        let thickness: [f32; 29] = core::array::from_fn(|i| match i {
            3 => f32::NAN,
            5 => 100.0 + step,
            6 => 100.0 + step - 0.01,
            7 => 900.0 - step,
            8 => 2000.0,
            _ => 240.0 + 17.3 * i as f32,
        });
        let mut lanes = [FitLanes::EMPTY];
        let mut index = [IndexLanes::EMPTY; 1];
        let mut scalar = [PixelFit::default(); 29];
        for i in 0..n {
            scalar[i].thickness_nm = thickness[i];
            scalar[i].order_step_nm = step;
            lanes[0].set_pixel(i, &scalar[i]);
        }
        for s in 0..12 {
            let coef = coefs[s % 3].as_ref().expect("a band");
            let values: [f32; 29] = core::array::from_fn(|i| match (i + s) % 11 {
                0 if i % 4 == 0 => f32::INFINITY,
                1 if i % 5 == 0 => f32::NAN,
                2 if i % 6 == 0 => 3e7,
                _ => 0.1 + 0.01 * ((i * 7 + s * 3) % 13) as f32,
            });
            let (block, model) = ((&mut lanes, &mut index), (coef, knots));
            feed(block, &mut scalar, &values, model, (sampling, row, wide));
        }
        for (i, p) in scalar.iter().enumerate() {
            let l = lane(&lanes[0], sampling, row, i, &index);
            let bits = |f: &PixelFit| {
                let t = [f.thickness_nm, f.order_step_nm].map(f32::to_bits);
                (
                    t,
                    [f.samples, f.saturated.into(), f.dead.into(), f.gn.samples],
                )
            };
            assert_eq!(bits(&l), bits(p), "pixel {i}, {sampling:?}, wide {wide}");
            assert_eq!(
                kept(&l, sampling, row, i),
                kept(p, sampling, row, i),
                "pixel {i}, {sampling:?}, wide {wide}"
            );
        }
        assert!(scalar.iter().filter(|p| p.gn.samples > 0).count() > 20);
        if sampling.is_none() {
            held_adds_no_index_terms(&lanes[0], &index[0]);
        }
        // The sampled pixels (and only they) have index sums.
        let with_sums =
            (0..n).filter(|&i| lane(&lanes[0], sampling, row, i, &index).gn.h_pp[0] != 0.0);
        let sampled = (0..n).filter(|&i| {
            sampling.is_some_and(|s| s.slot(row, i).is_some()) && scalar[i].gn.samples > 0
        });
        assert_eq!(
            with_sums.collect::<Vec<_>>(),
            sampled.collect::<Vec<_>>(),
            "{sampling:?}"
        );
    }

    /// Three bands of n 1.9 on 1.52 at 35 degrees, the first two tabulated over 100-900 nm:
    /// the bands, the knots and how many of them are used.
    fn bands() -> ([Option<BandCoef>; 3], [Knot; 4096], usize) {
        let range = [100.0, 900.0];
        let mut knots = [Knot::default(); 4096];
        let mut coefs = [None; 3];
        let mut first = 0;
        for (b, c) in coefs.iter_mut().enumerate() {
            let l = 450.0 + 110.0 * b as f64;
            let mut coef = BandCoef::new(
                IndexModel::constant(1.9),
                crate::solve::refine::FilmTerms::NONE,
                1.0,
                1.52,
                0.0,
                crate::optics::BackFace::None,
                Polarization::S,
                35.0,
                l,
                4.0,
                900.0,
            )
            .expect("propagating");
            if b < 2 {
                let (_, count) = coef.knots_for(range).expect("a table");
                coef.tabulate(range, first, &mut knots[first..first + count]);
                first += count;
            }
            *c = Some(coef);
        }
        (coefs, knots, first)
    }

    /// A full block whose every lane is inside the band's table with a usable sample (the
    /// unmasked path the pipeline runs on most blocks) gives [`GnSums::add`]'s sums bit for
    /// bit (the index's to every pixel, to one in 4, or, the index held, to none).
    #[test]
    fn a_full_block_inside_the_table_matches_the_scalar_sums() {
        for wide in [false, true] {
            for stride in [1, 4] {
                a_full_block_matches_with(Some(IndexSampling::one_in(stride)), wide);
            }
            a_full_block_matches_with(None, wide);
        }
    }

    fn a_full_block_matches_with(sampling: Option<IndexSampling>, wide: bool) {
        let (coefs, knots, first) = bands();
        let knots = &knots[..first];
        let step = 130.0f32;
        let mut lanes = [FitLanes::EMPTY];
        let mut index = [IndexLanes::EMPTY; 1];
        let row = 3;
        let mut scalar = [PixelFit::default(); LANES];
        for (i, p) in scalar.iter_mut().enumerate() {
            p.thickness_nm = 250.0 + 11.7 * i as f32;
            p.order_step_nm = step;
            lanes[0].set_pixel(i, p);
        }
        for s in 0..10 {
            // The tabulated bands only.
            let coef = coefs[s % 2].as_ref().expect("a band");
            let values: [f32; LANES] =
                core::array::from_fn(|i| 0.05 + 0.013 * ((i * 5 + s * 7) % 17) as f32);
            let (block, model) = ((&mut lanes, &mut index), (coef, knots));
            feed(block, &mut scalar, &values, model, (sampling, row, wide));
        }
        for (i, p) in scalar.iter().enumerate() {
            let l = lane(&lanes[0], sampling, row, i, &index);
            assert_eq!(
                kept(&l, sampling, row, i),
                kept(p, sampling, row, i),
                "pixel {i}"
            );
            assert_eq!((l.gn.samples, l.samples), (10, 10), "pixel {i}");
            // The lane's RMS read in place is the copied sums' (and none without samples).
            assert_eq!(
                lanes[0].rms(i).map(f32::to_bits),
                Some(l.gn.rms().to_bits())
            );
        }
        assert_eq!(FitLanes::EMPTY.rms(0), None);
        if sampling.is_none() {
            held_adds_no_index_terms(&lanes[0], &index[0]);
        }
    }

    /// With the index held, no lane has cross terms and the index blocks are untouched.
    fn held_adds_no_index_terms(lanes: &FitLanes, index: &IndexLanes) {
        for i in 0..LANES {
            let p = lanes.pixel(i, [0.0; INDEX_TERMS]);
            assert_eq!(p.gn.h_dp.map(f32::to_bits), [0; 3], "lane {i}");
            assert_eq!(
                index.terms(i).map(f32::to_bits),
                [0; INDEX_TERMS],
                "lane {i}"
            );
        }
    }
}
