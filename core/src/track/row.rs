//! The tracker of a row of pixels at once: [`PixelTracker`]'s arithmetic, lane by lane.
//!
//! Every pixel of a row sees the same band at the same time, so the ring position and the
//! count of samples are the row's, not each pixel's: a block of [`LANES`] pixels keeps each
//! field of the tracker as an array over its pixels (structure of arrays) and the compiler
//! vectorises the per-sample arithmetic (ring, moments, noise sums, the smoothed value, its
//! vertex, the running extremes). The rare events, an extremum confirmed or a change of mode,
//! are found by a mask and handed to the scalar tracker's own state machine for those lanes
//! alone, so the two give the same extrema, noise and bad-sample counts bit for
//! bit (the `row` tests feed both the same spectra).
//!
//! A pixel whose first sample of an angle is unusable does not start its window with the row
//! (the scalar tracker skips leading bad samples): it is *out of step* for the rest of the angle
//! and its samples go through [`PixelTracker::push`] one by one.

// The lane loops index a dozen parallel arrays by lane: that is the form that vectorises.
#![allow(clippy::needless_range_loop)]

use super::{
    abs_d2, before, lists::Lane, pos_code, smoothed, to_step, usable, vertex_band, whole_u16,
    window_moments, ExtremumSink, LaneSinks, Mode, PixelTracker, EDGE, TAU_PER_D2, WINDOW,
};

/// Pixels per block of [`TrackerLanes`].
pub const LANES: usize = 32;

/// Ring slot `j` places after `head` (`j < 2 * WINDOW`), without a division.
#[inline(always)]
fn ring_slot(head: usize, j: usize) -> usize {
    let s = head + j;
    if s >= WINDOW {
        s - WINDOW
    } else {
        s
    }
}

/// Tracker state of [`LANES`] pixels of one row: the fields of [`PixelTracker`] as arrays over
/// the pixels, with the ring position and sample count shared (38 bytes per pixel).
#[derive(Clone, Copy, Debug)]
pub struct TrackerLanes {
    /// `ring[k][i]`: ring slot `k` of lane `i`.
    ring: [[u16; LANES]; WINDOW],
    d2_sum: [f32; LANES],
    ext_val: [f32; LANES],
    ext_pos: [u16; LANES],
    min_val: [f32; LANES],
    min_pos: [u16; LANES],
    /// The samples by which a lane's window lags the row's: 0 for a lane in step, the count
    /// of leading unusable samples for one *out of step* (its own count is `seen` less that,
    /// its ring position `head` less that, mod [`WINDOW`]).
    lag: [u16; LANES],
    /// `Mode as u8`.
    mode: [u8; LANES],
    /// Samples seen by the lanes in step (saturates).
    seen: u16,
    /// Their ring position.
    head: u8,
    /// Whether any lane is out of step.
    any_out_of_step: bool,
}

impl Default for TrackerLanes {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// The samples of one block, padded to [`LANES`].
type Lanes = [f32; LANES];

impl TrackerLanes {
    /// A block that has seen nothing (every lane a reset [`PixelTracker`]).
    pub const EMPTY: Self = Self {
        ring: [[0; LANES]; WINDOW],
        d2_sum: [0.0; LANES],
        ext_val: [0.0; LANES],
        ext_pos: [0; LANES],
        min_val: [0.0; LANES],
        min_pos: [0; LANES],
        lag: [0; LANES],
        mode: [Mode::Start as u8; LANES],
        seen: 0,
        head: 0,
        any_out_of_step: false,
    };

    /// Forgets everything: call at the start of each angle.
    pub fn reset(&mut self) {
        *self = Self::EMPTY;
    }

    /// Lane `i` as a scalar tracker (a copy).
    pub fn lane(&self, i: usize) -> PixelTracker {
        PixelTracker {
            ring: core::array::from_fn(|k| self.ring[k][i]),
            ..self.lane_but_ring(i)
        }
    }

    /// Lane `i`'s noise estimate ([`PixelTracker::noise_sigma`]), its ring not copied.
    #[inline]
    pub fn noise_sigma(&self, i: usize) -> f32 {
        self.lane_but_window(i).noise_sigma()
    }

    /// Samples by which lane `i`'s window lags the row's (0: in step).
    #[inline]
    fn lag(&self, i: usize) -> u16 {
        self.lag[i]
    }

    /// Lane `i` as a scalar tracker, its ring left empty (its window's moments computed from
    /// it).
    fn lane_but_ring(&self, i: usize) -> PixelTracker {
        let t = self.lane_but_window(i);
        let head = usize::from(t.head);
        let q = |j: usize| f32::from(self.ring[ring_slot(head, j)][i]);
        PixelTracker {
            moments: window_moments([q(0), q(1), q(2), q(3), q(4), q(5), q(6), q(7), q(8)]),
            ..t
        }
    }

    /// Lane `i` as a scalar tracker, its ring left empty and its window's moments zero.
    fn lane_but_window(&self, i: usize) -> PixelTracker {
        let lag = self.lag(i);
        let behind = usize::from(lag) % WINDOW;
        PixelTracker {
            ring: [0; WINDOW],
            moments: [0.0; 3],
            ext_val: self.ext_val[i],
            ext_pos: self.ext_pos[i],
            min_val: self.min_val[i],
            min_pos: self.min_pos[i],
            d2_sum: self.d2_sum[i],
            seen: self.seen - lag,
            head: ring_slot(usize::from(self.head), WINDOW - behind) as u8,
            mode: Mode::from_u8(self.mode[i]),
        }
    }

    /// Stores `t` in lane `i`, out of step (its window behind the row's, which has seen
    /// `self.seen` samples: [`TrackerLanes::push`] calls it once the row's count is updated).
    fn set_lane(&mut self, i: usize, t: &PixelTracker) {
        for (k, &x) in t.ring.iter().enumerate() {
            self.ring[k][i] = x;
        }
        self.d2_sum[i] = t.d2_sum;
        // At least 1: a lane out of step stays so (the row's count saturates at 65535).
        self.lag[i] = (self.seen - t.seen).max(1);
        self.set_extremes(i, t);
    }

    /// Stores what [`PixelTracker::decide`] changes of `t` in lane `i`.
    fn set_extremes(&mut self, i: usize, t: &PixelTracker) {
        self.ext_val[i] = t.ext_val;
        self.ext_pos[i] = t.ext_pos;
        self.min_val[i] = t.min_val;
        self.min_pos[i] = t.min_pos;
        self.mode[i] = t.mode as u8;
    }

    /// Feeds one band's samples of the block's pixels (`values.len() <= LANES`, lane `i`'s
    /// extrema to `sinks`' lane `i`): [`PixelTracker::push`] for each lane.
    #[inline(always)]
    pub fn push<S: LaneSinks + ?Sized>(
        &mut self,
        band: u16,
        values: &[f32],
        subband: bool,
        sinks: &mut S,
    ) {
        let mut padded = [0.0; LANES];
        let values: &Lanes = match values.try_into() {
            Ok(full) => full,
            Err(_) => {
                let n = values.len().min(LANES);
                padded[..n].copy_from_slice(&values[..n]);
                &padded
            }
        };
        // Out-of-step lanes first, one by one; the row's arithmetic below overwrites them.
        let mut own: heapless::Vec<(u8, PixelTracker), LANES> = heapless::Vec::new();
        if self.any_out_of_step {
            for i in (0..LANES).filter(|&i| self.lag(i) != 0) {
                let mut t = self.lane(i);
                t.push(band, values[i], subband, &mut Lane { sinks, i });
                let _ = own.push((i as u8, t));
            }
        }
        let seen = self.seen;
        let head = usize::from(self.head);
        if seen >= 2 {
            self.advance::<true>(head, values);
        } else {
            self.advance::<false>(head, values);
        }
        self.head = if head + 1 == WINDOW {
            0
        } else {
            head as u8 + 1
        };
        self.seen = seen.saturating_add(1);
        if seen == 0 {
            // A lane without a usable first sample stays where it was (the scalar tracker
            // returns early): out of step from now on.
            for i in (0..LANES).filter(|&i| !usable(values[i])) {
                self.set_lane(i, &PixelTracker::default());
                self.any_out_of_step = true;
            }
        } else if usize::from(self.seen) == WINDOW {
            self.first_smoothed();
        } else if usize::from(self.seen) > WINDOW {
            let mut slow = [false; LANES];
            // Once no lane in step is in `Start` mode (a few bands in), its logic is left out.
            let start = Mode::Start as u8;
            let starting = if self.any_out_of_step {
                (self.mode.iter().zip(&self.lag))
                    .fold(false, |a, (&m, &lag)| a | (m == start && lag == 0))
            } else {
                self.mode.iter().fold(false, |a, &m| a | (m == start))
            };
            let any = if starting {
                self.follow::<true>(band, subband, &mut slow)
            } else {
                self.follow::<false>(band, subband, &mut slow)
            };
            if any {
                let lag = self.lag;
                for i in (0..LANES).filter(|&i| slow[i] && lag[i] == 0) {
                    // The state machine reads no ring and writes only the extremes.
                    let mut t = self.lane_but_ring(i);
                    t.decide(band, subband, &mut Lane { sinks, i });
                    self.set_extremes(i, &t);
                }
            }
        }
        for (i, t) in own.iter() {
            self.set_lane(usize::from(*i), t);
        }
    }

    /// [`PixelTracker::advance`] for every lane in step: `D2` when two samples came before.
    #[inline(always)]
    fn advance<const D2: bool>(&mut self, head: usize, values: &Lanes) {
        // The ring's rows copied out, so the compiler sees no overlap between them.
        let a_row = self.ring[before(before(head as u8) as u8)];
        let b_row = self.ring[before(head as u8)];
        let mut q_row = [0; LANES];
        for i in 0..LANES {
            let x = values[i];
            let b = f32::from(b_row[i]);
            let (step, q) = to_step(x);
            let ok = usable(x);
            let v = if ok { step } else { b };
            q_row[i] = if ok { q } else { b_row[i] };
            if D2 {
                self.d2_sum[i] += abs_d2(f32::from(a_row[i]), b, v);
            }
        }
        self.ring[head] = q_row;
    }

    /// The first smoothed sample ([`PixelTracker::start`]'s first step): every lane in step is
    /// in `Start` mode, its extremes at the band edge.
    fn first_smoothed(&mut self) {
        let [m0, _, m2] = lane_moments(&self.ring, self.head);
        for i in 0..LANES {
            let s = smoothed([m0[i], 0.0, m2[i]]);
            self.ext_val[i] = s;
            self.ext_pos[i] = EDGE;
            self.min_val[i] = s;
            self.min_pos[i] = EDGE;
        }
    }

    /// [`PixelTracker::decide`] for every lane in step where the running extremes only move:
    /// marks in `slow` the lanes where an extremum is confirmed or the mode changes (their
    /// state is left as it was, for the scalar state machine). Returns whether any lane is
    /// marked. `START`: whether any lane may be in `Start` mode.
    #[inline(always)]
    fn follow<const START: bool>(
        &mut self,
        band: u16,
        subband: bool,
        slow: &mut [bool; LANES],
    ) -> bool {
        let n = f32::from(self.seen.saturating_sub(2));
        let mut any = false;
        let [m0, m1, m2] = lane_moments(&self.ring, self.head);
        // The positions' codes as floats, narrowed to the lanes' `u16` after the loop (a
        // narrowing inside it keeps the loop from vectorising).
        let mut ext_pos = [0.0; LANES];
        let mut min_pos = [0.0; LANES];
        for i in 0..LANES {
            let m = [m0[i], m1[i], m2[i]];
            let s = smoothed(m);
            let at = pos_code(vertex_band(band, m, subband));
            let tau_n = TAU_PER_D2 * self.d2_sum[i];
            let (ev, ep) = (self.ext_val[i], f32::from(self.ext_pos[i]));
            let seek_min = self.mode[i] == Mode::SeekMin as u8;
            // The running extreme (the maximum in `Start` and `SeekMax`) moves ...
            let up = if seek_min { s < ev } else { s > ev };
            let new_ev = if up { s } else { ev };
            let new_ep = if up { at } else { ep };
            // ... or falls `tau` behind: an extremum (never where it moved).
            let gap = if seek_min { s - ev } else { ev - s };
            let seek_event = !up && gap * n > tau_n;
            if !START {
                slow[i] = seek_event;
                any |= seek_event;
                self.ext_val[i] = new_ev;
                ext_pos[i] = new_ep;
                continue;
            }
            // In `Start`, the running minimum moves too, and either extreme may end it.
            let (mv, mp) = (self.min_val[i], f32::from(self.min_pos[i]));
            let start = self.mode[i] == Mode::Start as u8;
            let down = start && s < mv;
            let new_mv = if down { s } else { mv };
            let new_mp = if down { at } else { mp };
            let tau = tau_n / n;
            let start_event = s >= new_mv + tau || s <= new_ev - tau;
            let event = if start { start_event } else { seek_event };
            slow[i] = event;
            any |= event;
            self.ext_val[i] = if event { ev } else { new_ev };
            ext_pos[i] = if event { ep } else { new_ep };
            self.min_val[i] = if event { mv } else { new_mv };
            min_pos[i] = if event { mp } else { new_mp };
        }
        narrow(&ext_pos, &mut self.ext_pos);
        if START {
            narrow(&min_pos, &mut self.min_pos);
        }
        any
    }
}

/// Whole numbers below `2^16` (position codes) as `u16` ([`whole_u16`]: a loop that
/// vectorises).
#[inline(always)]
pub(super) fn narrow(x: &Lanes, out: &mut [u16; LANES]) {
    for i in 0..LANES {
        out[i] = whole_u16(x[i]);
    }
}

/// The window's moments ([`window_moments`]) of every lane of `ring`, `head` its oldest slot
/// (in step lanes: the row's): computed at each band from the ring (exact, so the same as the
/// scalar tracker's carried ones), 12 bytes a pixel fewer to keep.
#[inline(always)]
fn lane_moments(ring: &[[u16; LANES]; WINDOW], head: u8) -> [Lanes; 3] {
    let head = usize::from(head);
    // Written out: `array::from_fn` is not always inlined in the wide build's lane loops.
    let at = |j: usize| &ring[ring_slot(head, j)];
    let rows = [
        at(0),
        at(1),
        at(2),
        at(3),
        at(4),
        at(5),
        at(6),
        at(7),
        at(8),
    ];
    let mut m = [[0.0; LANES]; 3];
    for i in 0..LANES {
        let q = |j: usize| f32::from(rows[j][i]);
        let [m0, m1, m2] = window_moments([q(0), q(1), q(2), q(3), q(4), q(5), q(6), q(7), q(8)]);
        (m[0][i], m[1][i], m[2][i]) = (m0, m1, m2);
    }
    m
}

/// Block `i / LANES` of the `width`-pixel row holding pixel `i` of a row-major image, and the
/// pixel's lane: the blocks of a row are `width.div_ceil(LANES)` consecutive [`TrackerLanes`].
#[inline]
pub(crate) fn locate(width: usize, i: usize) -> (usize, usize) {
    let (row, col) = (i / width, i % width);
    (row * width.div_ceil(LANES) + col / LANES, col % LANES)
}

/// Blocks of [`TrackerLanes`] a `rows` x `width` image needs.
pub const fn blocks_for(rows: usize, width: usize) -> usize {
    rows * width.div_ceil(LANES)
}

/// Pixel `i` (row-major, rows of `width`) of an image whose trackers are `blocks`, as a scalar
/// tracker (a copy: its noise and bad samples).
pub fn pixel(blocks: &[TrackerLanes], width: usize, i: usize) -> PixelTracker {
    let (b, lane) = locate(width, i);
    blocks[b].lane(lane)
}

/// Every pixel's block and lane, in pixel order, of a row-major image of `width`-pixel rows
/// whose blocks of [`LANES`] pixels (trackers, or the fit's lanes) are `blocks` (for a
/// tracker, `block.lane(lane)` is the pixel's scalar tracker): a walk over the pixels without
/// [`pixel`]'s division and ring copy per pixel.
pub fn lanes<T>(blocks: &[T], width: usize) -> impl Iterator<Item = (&T, usize)> + '_ {
    blocks
        .chunks(width.div_ceil(LANES).max(1))
        .flat_map(move |row| (0..width).map(move |col| (&row[col / LANES], col % LANES)))
}

/// Feeds band `band` of one row (`values`, one sink per value) to the row's blocks
/// (`values.len().div_ceil(LANES)` of them): [`PixelTracker::push`] for each pixel.
#[inline(always)]
pub fn push_row<L: ExtremumSink>(
    blocks: &mut [TrackerLanes],
    band: u16,
    values: &[f32],
    subband: bool,
    lists: &mut [L],
) {
    for ((block, v), l) in blocks
        .iter_mut()
        .zip(values.chunks(LANES))
        .zip(lists.chunks_mut(LANES))
    {
        block.push(band, v, subband, l);
    }
}

#[cfg(test)]
mod tests;
