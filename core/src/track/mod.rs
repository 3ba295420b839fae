//! The per-pixel running extremum tracker.
//!
//! Bands of one angle stream past a pixel in increasing wavelength. The tracker smooths them
//! with a 9-sample Savitzky-Golay quadratic (so it needs the last 9 samples only), follows the
//! smoothed spectrum with hysteresis (a peak is declared only once the spectrum has fallen a
//! prominence `tau` below it, so noise on a broad fringe top does not split it), and places
//! each extremum to a fraction of a band from the local quadratic's vertex. `tau` follows the
//! pixel's own noise, estimated on the fly from the mean absolute second difference.
//!
//! State is a fixed-size [`PixelTracker`] per pixel, reset at each angle, whatever the number
//! of bands; found extrema go to a caller-owned [`ExtremumSink`] of fixed capacity (a full
//! sink refuses an extremum and its owner flags the overflow: never growth): a whole
//! [`ExtremaList`] or its last extrema, an [`ExtremaHead`]. The workers run [`row`], the
//! same tracker over a row's pixels at once (structure of arrays, vectorised, the same
//! results bit for bit); [`PixelTracker`] is its reference and handles its rare events.

/// Samples in the smoothing window (odd).
pub const WINDOW: usize = 9;
const HALF: usize = WINDOW / 2;

/// Prominence of an extremum, in units of the pixel's noise (1 sigma).
pub const PROMINENCE_SIGMA: f32 = 6.0;

/// Most extrema kept per pixel and angle.
pub const MAX_EXTREMA: usize = 20;

/// Largest sample magnitude taken as a measurement: reflectance lies near 0..1, so a
/// larger value is a corrupted sample (bad bytes in a float cube), treated like a dead one.
/// Bounding it keeps the smoothing sums finite (found by the property tests: a sample of
/// -1.1e38 overflowed them and placed an extremum at NaN, out of band order).
pub const MAX_SAMPLE: f32 = 1e6;

/// Whether `v` is a usable sample: finite and at most [`MAX_SAMPLE`] in magnitude.
#[inline]
pub fn usable(v: f32) -> bool {
    v.abs() <= MAX_SAMPLE
}

/// The tracker works on its samples as steps of `2^-15` from -0.5 ([`to_step`]):
/// reflectance -0.5 to 1.49997 in steps of 3.1e-5, whose rounding (8.8e-6 RMS) is a
/// hundredth of a camera's noise (1e-3 at its best). Its ring holds a sample in 2 bytes
/// instead of 4, and its window sums, sums of whole steps below `2^24`, are exact in `f32`.
/// The full-spectrum sums take the samples as they came.
const RING_STEPS_PER_UNIT: f32 = 32_768.0;
/// The reflectance of ring step 0.
const RING_ORIGIN: f32 = -0.5;

/// `2^23`: `y + 2^23` (`0 <= y < 2^16`) is `y` rounded to a whole number (ties to even), and
/// its bits, less those of `2^23`, are that number: a float to a small integer without a
/// float-to-integer conversion, so that a lane loop vectorises ([`to_step`], [`pos_code`],
/// [`whole_u16`]).
const TWO_23: f32 = 8_388_608.0;

/// A whole number `w` (`0 <= w < 2^16`, a float) as `u16`, by [`TWO_23`]'s trick.
#[inline(always)]
fn whole_u16(w: f32) -> u16 {
    ((w + TWO_23).to_bits() - TWO_23.to_bits()) as u16
}

/// A usable sample `v` as a ring step, as a float (a whole number) and as the ring holds it:
/// rounded to the nearest step (ties to even), clamped to the ring's range, by [`TWO_23`]'s
/// trick.
#[inline(always)]
fn to_step(v: f32) -> (f32, u16) {
    const TOP: f32 = 65_535.0 / RING_STEPS_PER_UNIT + RING_ORIGIN;
    // (Selects, not `clamp`: each is one `maxps` / `minps` in a lane loop.)
    let v = if v < RING_ORIGIN { RING_ORIGIN } else { v };
    let v = if v > TOP { TOP } else { v };
    let r = (v - RING_ORIGIN) * RING_STEPS_PER_UNIT + TWO_23;
    (r - TWO_23, (r.to_bits() - TWO_23.to_bits()) as u16)
}

/// [`pack_sample`]'s code of a saturated sample (infinite).
const PACKED_SATURATED: u16 = u16::MAX;
/// [`pack_sample`]'s code of a sample without a usable value (NaN, or beyond
/// [`MAX_SAMPLE`]).
const PACKED_DEAD: u16 = u16::MAX - 1;

/// A calibrated sample in 2 bytes, as the pipeline holds a block of bands before the
/// tracker and the full-spectrum sums take them: its ring step (steps of `2^-15` from
/// -0.5, the rounding the tracker gives it anyway; the sums see it too, 8.8e-6 RMS),
/// clamped below the two codes kept for a saturated sample (infinite) and one without a
/// usable value, which [`unpack_sample`] gives back as `+inf` and NaN. Lane loops of it vectorise (no branch, no
/// float-to-integer conversion).
#[inline(always)]
pub fn pack_sample(v: f32) -> u16 {
    let q = to_step(v).1.min(PACKED_DEAD - 1);
    let q = if usable(v) { q } else { PACKED_DEAD };
    if v.is_infinite() {
        PACKED_SATURATED
    } else {
        q
    }
}

/// The sample [`pack_sample`] packed as `q`: a ring step's reflectance (exact), `+inf` for a
/// saturated one, NaN for one without a usable value.
#[inline(always)]
pub fn unpack_sample(q: u16) -> f32 {
    // Selects, not branches: lane loops of it vectorise.
    let v = f32::from(q) * (1.0 / RING_STEPS_PER_UNIT) + RING_ORIGIN;
    let v = if q == PACKED_DEAD { f32::NAN } else { v };
    if q == PACKED_SATURATED {
        f32::INFINITY
    } else {
        v
    }
}

/// [`pack_sample`] of every value of `values` into `out` (as many as both hold), compiled
/// for AVX2 if `wide` ([`crate::simd::wide`]).
pub fn pack_samples(values: &[f32], out: &mut [u16], wide: bool) {
    crate::simd::wide(wide, {
        #[inline(always)]
        || {
            for (q, &v) in out.iter_mut().zip(values) {
                *q = pack_sample(v);
            }
        }
    });
}

/// [`unpack_sample`] of every code of `packed` into `out` (as many as both hold), compiled
/// for AVX2 if `wide` ([`crate::simd::wide`]).
pub fn unpack_samples(packed: &[u16], out: &mut [f32], wide: bool) {
    crate::simd::wide(wide, {
        #[inline(always)]
        || {
            for (x, &q) in out.iter_mut().zip(packed) {
                *x = unpack_sample(q);
            }
        }
    });
}

/// [`to_step`]'s ring step.
#[cfg(test)]
fn to_ring(v: f32) -> u16 {
    to_step(v).1
}

/// The reflectance of ring step `q` (exact: a power-of-two scale).
#[cfg(test)]
fn from_ring(q: u16) -> f32 {
    f32::from(q) * (1.0 / RING_STEPS_PER_UNIT) + RING_ORIGIN
}

/// Peak or valley.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A reflectance maximum.
    Peak,
    /// A reflectance minimum.
    Valley,
}

/// One extremum of one pixel's spectrum at one angle: 2 bytes, its kind in the top bit and
/// its position in 1/32 band below (0.06 nm at a 2 nm band step, well below the location
/// noise; positions up to band 1023.97).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Extremum(u16);

/// Position steps per band of [`Extremum`].
const POS_PER_BAND: f32 = 32.0;
/// The bit of [`Extremum`] that marks a valley.
const VALLEY_BIT: u16 = 1 << 15;

impl Extremum {
    /// A peak at band 0: what an unused slot of a list holds.
    pub const ZERO: Self = Self(0);

    /// An extremum at fractional band `band` (clamped to `0..1024`, rounded to the nearest
    /// 1/32 band, ties away from zero).
    pub fn new(band: f32, kind: Kind) -> Self {
        Self::at(to_pos(band), kind)
    }

    /// An extremum at position `pos` ([`to_pos`]'s code, below [`EDGE`]).
    #[inline]
    fn at(pos: u16, kind: Kind) -> Self {
        let pos = pos & !VALLEY_BIT;
        Self(match kind {
            Kind::Peak => pos,
            Kind::Valley => pos | VALLEY_BIT,
        })
    }

    /// Its position as [`to_pos`] codes it.
    #[inline]
    fn pos(&self) -> u16 {
        self.0 & !VALLEY_BIT
    }

    /// Position in (fractional) band index.
    #[inline]
    pub fn band(&self) -> f32 {
        f32::from(self.0 & !VALLEY_BIT) / POS_PER_BAND
    }

    /// Peak or valley.
    #[inline]
    pub fn kind(&self) -> Kind {
        if self.0 & VALLEY_BIT == 0 {
            Kind::Peak
        } else {
            Kind::Valley
        }
    }
}

/// The code of a running extreme still at the band edge (no extremum there): above every
/// position [`to_pos`] gives.
const EDGE: u16 = u16::MAX;

/// A fractional band as the tracker keeps a running extreme's position and [`Extremum`]
/// holds it: in 1/32 band, clamped to `0..1024`, rounded to the nearest, ties away from zero
/// as `libm::roundf` rounds them (noise-free spectra's whole-number moments put vertices on
/// ties).
#[inline(always)]
fn to_pos(band: f32) -> u16 {
    whole_u16(pos_code(band))
}

/// [`to_pos`]'s code as a float (a whole number), written without a float-to-integer
/// conversion ([`TWO_23`]'s rounding, then the tie it rounded down moved up) so that a lane
/// loop vectorises; the row kernel narrows a block's codes to `u16` in a loop of their own.
#[inline(always)]
fn pos_code(band: f32) -> f32 {
    const MAX: f32 = (VALLEY_BIT - 1) as f32 / POS_PER_BAND;
    let b = if band > 0.0 { band } else { 0.0 };
    let b = if b < MAX { b } else { MAX };
    let x = b * POS_PER_BAND;
    let q = (x + TWO_23) - TWO_23;
    if q - x == -0.5 {
        q + 1.0
    } else {
        q
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[repr(u8)]
enum Mode {
    #[default]
    Start,
    SeekMax,
    SeekMin,
}

impl Mode {
    /// The mode stored as `mode as u8`.
    #[inline]
    fn from_u8(m: u8) -> Self {
        match m {
            1 => Self::SeekMax,
            2 => Self::SeekMin,
            _ => Self::Start,
        }
    }
}

/// `PROMINENCE_SIGMA` halved (the smoothed spectrum's noise is about half the raw noise)
/// over the white-noise factor of the mean absolute second difference (see
/// [`PixelTracker::noise_sigma`]): `tau = TAU_PER_D2 * mean |second difference|`.
const TAU_PER_D2: f32 = PROMINENCE_SIGMA * 0.5 / 1.954;

/// Tracker state of one pixel for one angle: 52 bytes, independent of bands and angles
/// (bad samples are bridged here and counted by the solver's full-spectrum sums).
///
/// The smoothing window's three moments (`sum q`, `sum k q`, `sum k^2 q` of the ring steps
/// `q`, with `k = -4..4` from the window centre) are carried from sample to sample in a few
/// operations instead of three 9-tap dot products. They are whole numbers below `2^24`
/// (at most 9, 20 and 60 times 65535, and the carry's terms too), so `f32` carries them
/// exactly and no rounding accumulates (the update is a marginally stable recursion: an
/// error in `sum q` would grow quadratically in `sum k^2 q`; the tracker on unrounded
/// samples recomputed them at every wrap of the ring). Smoothed values and the prominence
/// are in steps; [`PixelTracker::noise_sigma`] is in reflectance.
#[derive(Clone, Copy, Debug, Default)]
pub struct PixelTracker {
    /// The last 9 samples as ring steps ([`to_step`]); `head` is the oldest (the next to be
    /// overwritten).
    ring: [u16; WINDOW],
    /// `sum q`, `sum k q`, `sum k^2 q` over the ring, whole numbers.
    moments: [f32; 3],
    /// Current running extreme (smoothed value, ring steps) and its position ([`to_pos`]:
    /// the 1/32 band an emitted extremum is rounded to anyway).
    ext_val: f32,
    ext_pos: u16,
    /// In `Start` mode: the running minimum (the running maximum is in `ext_*`); [`EDGE`]
    /// marks an extreme still at the band edge.
    min_val: f32,
    min_pos: u16,
    /// Sum of |second difference|, steps, for the noise estimate.
    d2_sum: f32,
    /// Samples seen this angle (saturates).
    seen: u16,
    head: u8,
    mode: Mode,
}

/// `|a - 2 b + v|` of three steps (exact): one term of the noise estimate.
#[inline(always)]
fn abs_d2(a: f32, b: f32, v: f32) -> f32 {
    (v - 2.0 * b + a).abs()
}

/// The window's moments carried one sample on (each sample's `k` one less): `old` (at
/// `k = -4`) leaves, `v` enters at `k = 4`. From a ring of zeros, the moments of a full
/// window are its own.
#[inline(always)]
fn carry_moments([s0, s1, s2]: [f32; 3], old: f32, v: f32) -> [f32; 3] {
    [
        s0 - old + v,
        s1 - s0 + 5.0 * old + 4.0 * v,
        s2 - 2.0 * s1 + s0 - 25.0 * old + 16.0 * v,
    ]
}

/// The window's moments (`sum q`, `sum k q`, `sum k^2 q`, `k = -4..4`) of its samples `w`,
/// oldest first: what [`carry_moments`] carries, computed afresh (the row kernel's form, which
/// keeps no moments per pixel). The samples are whole ring steps, so every partial sum is a
/// whole number below `2^24` and `f32` gives the carried moments exactly, in any order.
#[inline(always)]
fn window_moments(w: [f32; WINDOW]) -> [f32; 3] {
    // Pairs about the centre: `p_k = q_k + q_-k`, `d_k = q_k - q_-k`.
    // (Written out: `array::map` is not always inlined in the wide build's lane loops.)
    let p = [w[5] + w[3], w[6] + w[2], w[7] + w[1], w[8] + w[0]];
    let d = [w[5] - w[3], w[6] - w[2], w[7] - w[1], w[8] - w[0]];
    [
        w[HALF] + ((p[0] + p[1]) + (p[2] + p[3])),
        (d[0] + 2.0 * d[1]) + (3.0 * d[2] + 4.0 * d[3]),
        (p[0] + 4.0 * p[1]) + (9.0 * p[2] + 16.0 * p[3]),
    ]
}

/// Smoothed value at the window centre, steps: the 9-point quadratic Savitzky-Golay weights
/// are `59 - 5 k^2` (sum 231).
#[inline(always)]
fn smoothed([m0, _, m2]: [f32; 3]) -> f32 {
    (59.0 * m0 - 5.0 * m2) * (1.0 / 231.0)
}

/// The local quadratic's vertex for the window ending at band `band`, within a band of the
/// window centre (the centre itself unless `subband`), as [`to_pos`] codes it.
#[inline(always)]
fn vertex(band: u16, m: [f32; 3], subband: bool) -> u16 {
    to_pos(vertex_band(band, m, subband))
}

/// [`vertex`] as a fractional band (what [`pos_code`] codes).
#[inline(always)]
fn vertex_band(band: u16, [m0, m1, m2]: [f32; 3], subband: bool) -> f32 {
    let centre = f32::from(band) - HALF as f32;
    // Slope weights k (sum of squares 60); curvature 3 k^2 - 20 (times 2 / 462).
    let d1 = m1 * (1.0 / 60.0);
    let d2 = (3.0 * m2 - 20.0 * m0) * (1.0 / 462.0);
    // Written as `centre + (offset or 0)` (`centre` is never -0, so adding 0 leaves it as it
    // is), the offset computed either way: a select the compiler vectorises in the row kernel.
    let offset = (-d1 / (2.0 * d2)).clamp(-1.0, 1.0);
    centre
        + if subband && d2.abs() > 1e-12 {
            offset
        } else {
            0.0
        }
}

/// The ring slot before `i` (mod [`WINDOW`]).
#[inline]
fn before(i: u8) -> usize {
    if i == 0 {
        WINDOW - 1
    } else {
        usize::from(i) - 1
    }
}

impl PixelTracker {
    /// Forgets everything: call at the start of each angle.
    pub fn reset(&mut self) {
        *self = Self::default();
    }

    /// Second differences summed so far.
    fn d2_count(&self) -> u16 {
        self.seen.saturating_sub(2)
    }

    /// The pixel's noise estimate (1 sigma, reflectance), from the mean absolute second
    /// difference of the raw samples (`E|x[i+1] - 2 x[i] + x[i-1]| = sqrt(6) sqrt(2/pi) sigma
    /// = 1.954 sigma` for white noise).
    pub fn noise_sigma(&self) -> f32 {
        match self.d2_count() {
            0 => f32::INFINITY,
            n => self.d2_sum / f32::from(n) / 1.954 * (1.0 / RING_STEPS_PER_UNIT),
        }
    }

    /// Feeds the sample of band `band` (bands must come in increasing order, one per call).
    /// Unusable samples (saturated, dead, beyond [`MAX_SAMPLE`]) are counted and bridged by
    /// repeating the last good sample. Confirmed extrema are pushed to `out`, placed to a
    /// fraction of a band when `subband` (else at the band of the smoothed extreme).
    #[inline]
    pub fn push(&mut self, band: u16, value: f32, subband: bool, out: &mut impl ExtremumSink) {
        if self.advance(value) {
            self.decide(band, subband, out);
        }
    }

    /// The smoothing window's half of [`PixelTracker::push`]: takes the sample into the ring,
    /// the moments and the noise sums. Returns whether the window is full (the smoothed
    /// spectrum is defined).
    #[inline]
    fn advance(&mut self, value: f32) -> bool {
        let last = before(self.head);
        let (v, q) = if usable(value) {
            to_step(value)
        } else {
            if self.seen == 0 {
                return false;
            }
            (f32::from(self.ring[last]), self.ring[last])
        };
        let slot = usize::from(self.head);
        if self.seen >= 2 {
            let a = f32::from(self.ring[before(last as u8)]);
            self.d2_sum += abs_d2(a, f32::from(self.ring[last]), v);
        }
        let old = f32::from(self.ring[slot]);
        self.ring[slot] = q;
        self.head = if slot + 1 == WINDOW {
            0
        } else {
            slot as u8 + 1
        };
        self.moments = carry_moments(self.moments, old, v);
        self.seen = self.seen.saturating_add(1);
        usize::from(self.seen) >= WINDOW
    }

    /// The state machine's half of [`PixelTracker::push`], once the window is full: follows
    /// the smoothed spectrum and emits confirmed extrema.
    #[inline]
    fn decide(&mut self, band: u16, subband: bool, out: &mut impl ExtremumSink) {
        let m = self.moments;
        let s = smoothed(m);
        // Its vertex ([`to_pos`]'s code), computed only where an extreme moves.
        let vertex = || vertex(band, m, subband);
        // The prominence `tau = TAU_PER_D2 * d2_sum / n` is compared as `x * n > tau * n`:
        // no division per sample.
        let n = f32::from(self.d2_count());
        let tau_n = TAU_PER_D2 * self.d2_sum;
        match self.mode {
            Mode::SeekMax => {
                if s > self.ext_val {
                    self.ext_val = s;
                    self.ext_pos = vertex();
                } else if (self.ext_val - s) * n > tau_n {
                    self.emit(self.ext_pos, Kind::Peak, out);
                    self.mode = Mode::SeekMin;
                    self.ext_val = s;
                    self.ext_pos = vertex();
                }
            }
            Mode::SeekMin => {
                if s < self.ext_val {
                    self.ext_val = s;
                    self.ext_pos = vertex();
                } else if (s - self.ext_val) * n > tau_n {
                    self.emit(self.ext_pos, Kind::Valley, out);
                    self.mode = Mode::SeekMax;
                    self.ext_val = s;
                    self.ext_pos = vertex();
                }
            }
            Mode::Start => self.start(s, tau_n / n, vertex, out),
        }
    }

    /// Before the first extremum: follows both the running maximum and minimum until the
    /// spectrum has moved `tau` away from one of them.
    fn start(&mut self, s: f32, tau: f32, vertex: impl Fn() -> u16, out: &mut impl ExtremumSink) {
        if usize::from(self.seen) == WINDOW {
            // The first smoothed sample: an extreme here is the band edge, not a fringe.
            self.ext_val = s;
            self.ext_pos = EDGE;
            self.min_val = s;
            self.min_pos = EDGE;
            return;
        }
        if s > self.ext_val {
            self.ext_val = s;
            self.ext_pos = vertex();
        }
        if s < self.min_val {
            self.min_val = s;
            self.min_pos = vertex();
        }
        if s >= self.min_val + tau {
            // Rising: the minimum behind us is a valley unless it is the band edge.
            if self.min_pos != EDGE {
                self.emit(self.min_pos, Kind::Valley, out);
            }
            self.mode = Mode::SeekMax;
            self.ext_val = s;
            self.ext_pos = vertex();
        } else if s <= self.ext_val - tau {
            if self.ext_pos != EDGE {
                self.emit(self.ext_pos, Kind::Peak, out);
            }
            self.mode = Mode::SeekMin;
            self.ext_val = s;
            self.ext_pos = vertex();
        }
    }

    fn emit(&mut self, pos: u16, kind: Kind, out: &mut impl ExtremumSink) {
        // Sub-band vertices move up to a band either way, so two extrema of a spiky spectrum
        // less than two bands apart could come out of order (found by the property tests):
        // the list stays in increasing band order.
        let pos = out.last_extremum().map_or(pos, |last| pos.max(last.pos()));
        // A full sink refuses it: its owner flags the overflow.
        let _ = out.push(Extremum::at(pos, kind));
    }
}

mod lists;
pub mod row;

pub use lists::{ExtremaHead, ExtremaList, ExtremumSink, LaneSinks, HEAD};

#[cfg(test)]
mod tests;
