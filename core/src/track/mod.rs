//! The per-pixel running extremum tracker.
//!
//! Bands of one angle stream past a pixel in increasing wavelength. The tracker smooths them
//! with a 9-sample Savitzky-Golay quadratic (so it needs the last 9 samples only), follows the
//! smoothed spectrum with hysteresis (a peak is declared only once the spectrum has fallen a
//! prominence `tau` below it, so noise on a broad fringe top does not split it), and places
//! each extremum to a fraction of a band from the local quadratic's vertex. `tau` follows the
//! pixel's own noise, estimated on the fly from the mean absolute second difference.
//!
//! State is a fixed-size [`PixelTracker`] per pixel, reset at each angle, whatever the number of
//! bands; found extrema go to a caller-owned [`ExtremaList`] of fixed capacity (overflow is a
//! flag, never growth).

use heapless::Vec as HVec;

/// Samples in the smoothing window (odd).
pub const WINDOW: usize = 9;
const HALF: usize = WINDOW / 2;

/// Savitzky-Golay quadratic smoothing weights for 9 samples (sum 231).
const SG_SMOOTH: [f32; WINDOW] = [-21.0, 14.0, 39.0, 54.0, 59.0, 54.0, 39.0, 14.0, -21.0];
const SG_SMOOTH_NORM: f32 = 231.0;
/// First-derivative weights (per band) for 9 samples (sum of squares 60).
const SG_SLOPE: [f32; WINDOW] = [-4.0, -3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0, 4.0];
const SG_SLOPE_NORM: f32 = 60.0;
/// Second-derivative weights for 9 samples (quadratic coefficient * 2).
const SG_CURV: [f32; WINDOW] = [28.0, 7.0, -8.0, -17.0, -20.0, -17.0, -8.0, 7.0, 28.0];
const SG_CURV_NORM: f32 = 462.0;

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

/// Peak or valley.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A reflectance maximum.
    Peak,
    /// A reflectance minimum.
    Valley,
}

/// One extremum of one pixel's spectrum at one angle: 4 bytes, its position kept in
/// 1/64 band (0.03 nm at a 2 nm band step, well below the location noise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Extremum {
    pos: u16,
    /// Peak or valley.
    pub kind: Kind,
}

/// Position steps per band of [`Extremum`].
const POS_PER_BAND: f32 = 64.0;

impl Extremum {
    /// An extremum at fractional band `band` (clamped to `0..1024`).
    pub fn new(band: f32, kind: Kind) -> Self {
        let max = f32::from(u16::MAX) / POS_PER_BAND;
        Self {
            pos: libm::roundf(band.clamp(0.0, max) * POS_PER_BAND) as u16,
            kind,
        }
    }

    /// Position in (fractional) band index.
    #[inline]
    pub fn band(&self) -> f32 {
        f32::from(self.pos) / POS_PER_BAND
    }
}

/// The extrema of one pixel at one angle, in increasing band order.
pub type ExtremaList = HVec<Extremum, MAX_EXTREMA>;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
enum Mode {
    #[default]
    Start,
    SeekMax,
    SeekMin,
}

/// Tracker state of one pixel for one angle: 64 bytes, independent of bands and angles.
#[derive(Clone, Copy, Debug, Default)]
pub struct PixelTracker {
    ring: [f32; WINDOW],
    /// Samples seen this angle (saturates).
    seen: u16,
    mode: Mode,
    /// Overflow or bad samples seen.
    pub overflow: bool,
    /// Non-finite samples seen this angle (saturated or dead).
    pub bad_samples: u16,
    /// Current running extreme (smoothed value) and its fractional band.
    ext_val: f32,
    ext_pos: f32,
    /// In `Start` mode: the running minimum (the running maximum is in `ext_*`); a NaN
    /// position marks an extreme still at the band edge.
    min_val: f32,
    min_pos: f32,
    /// Sum of |second difference| and its count, for the noise estimate.
    d2_sum: f32,
    d2_n: u16,
}

impl PixelTracker {
    /// Forgets everything: call at the start of each angle.
    pub fn reset(&mut self) {
        *self = Self::default();
    }

    /// The pixel's noise estimate (1 sigma, reflectance), from the mean absolute second
    /// difference of the raw samples (`E|x[i+1] - 2 x[i] + x[i-1]| = sqrt(6) sqrt(2/pi) sigma
    /// = 1.954 sigma` for white noise).
    pub fn noise_sigma(&self) -> f32 {
        if self.d2_n == 0 {
            f32::INFINITY
        } else {
            self.d2_sum / f32::from(self.d2_n) / 1.954
        }
    }

    /// Feeds the sample of band `band` (bands must come in increasing order, one per call).
    /// Unusable samples (saturated, dead, beyond [`MAX_SAMPLE`]) are counted and bridged by
    /// repeating the last good sample. Confirmed extrema are pushed to `out`, placed to a fraction of a band when
    /// `subband` (else at the band of the smoothed extreme).
    #[inline]
    pub fn push(&mut self, band: u16, value: f32, subband: bool, out: &mut ExtremaList) {
        let v = if usable(value) {
            value
        } else {
            self.bad_samples = self.bad_samples.saturating_add(1);
            if self.seen == 0 {
                return;
            }
            self.ring[(usize::from(self.seen) - 1) % WINDOW]
        };
        let slot = usize::from(self.seen) % WINDOW;
        self.ring[slot] = v;
        if self.seen >= 2 {
            let a = self.ring[(usize::from(self.seen) - 2) % WINDOW];
            let b = self.ring[(usize::from(self.seen) - 1) % WINDOW];
            self.d2_sum += (v - 2.0 * b + a).abs();
            self.d2_n = self.d2_n.saturating_add(1);
        }
        self.seen = self.seen.saturating_add(1);
        if usize::from(self.seen) < WINDOW {
            return;
        }
        // Smoothed value, slope and curvature at the window centre (band - HALF).
        let oldest = usize::from(self.seen) % WINDOW;
        let (mut s, mut d1, mut d2) = (0.0f32, 0.0f32, 0.0f32);
        for k in 0..WINDOW {
            let x = self.ring[(oldest + k) % WINDOW];
            s += SG_SMOOTH[k] * x;
            d1 += SG_SLOPE[k] * x;
            d2 += SG_CURV[k] * x;
        }
        s /= SG_SMOOTH_NORM;
        d1 /= SG_SLOPE_NORM;
        d2 /= SG_CURV_NORM;
        let centre = f32::from(band) - HALF as f32;
        let vertex = if subband && d2.abs() > 1e-12 {
            centre + (-d1 / (2.0 * d2)).clamp(-1.0, 1.0)
        } else {
            centre
        };
        // The smoothed spectrum's noise is about half the raw noise.
        let tau = PROMINENCE_SIGMA * 0.5 * self.noise_sigma();
        match self.mode {
            Mode::Start => {
                if usize::from(self.seen) == WINDOW {
                    // The first smoothed sample: an extreme here is the band edge, not a fringe.
                    self.ext_val = s;
                    self.ext_pos = f32::NAN;
                    self.min_val = s;
                    self.min_pos = f32::NAN;
                    return;
                }
                if s > self.ext_val {
                    self.ext_val = s;
                    self.ext_pos = vertex;
                }
                if s < self.min_val {
                    self.min_val = s;
                    self.min_pos = vertex;
                }
                if s >= self.min_val + tau {
                    // Rising: the minimum behind us is a valley unless it is the band edge.
                    if self.min_pos.is_finite() {
                        self.emit(self.min_pos, Kind::Valley, out);
                    }
                    self.mode = Mode::SeekMax;
                    self.ext_val = s;
                    self.ext_pos = vertex;
                } else if s <= self.ext_val - tau {
                    if self.ext_pos.is_finite() {
                        self.emit(self.ext_pos, Kind::Peak, out);
                    }
                    self.mode = Mode::SeekMin;
                    self.ext_val = s;
                    self.ext_pos = vertex;
                }
            }
            Mode::SeekMax => {
                if s > self.ext_val {
                    self.ext_val = s;
                    self.ext_pos = vertex;
                } else if s < self.ext_val - tau {
                    self.emit(self.ext_pos, Kind::Peak, out);
                    self.mode = Mode::SeekMin;
                    self.ext_val = s;
                    self.ext_pos = vertex;
                }
            }
            Mode::SeekMin => {
                if s < self.ext_val {
                    self.ext_val = s;
                    self.ext_pos = vertex;
                } else if s > self.ext_val + tau {
                    self.emit(self.ext_pos, Kind::Valley, out);
                    self.mode = Mode::SeekMax;
                    self.ext_val = s;
                    self.ext_pos = vertex;
                }
            }
        }
    }

    fn emit(&mut self, band: f32, kind: Kind, out: &mut ExtremaList) {
        // Sub-band vertices move up to a band either way, so two extrema of a spiky spectrum
        // less than two bands apart could come out of order (found by the property tests):
        // the list stays in increasing band order.
        let band = out.last().map_or(band, |last| band.max(last.band()));
        if out.push(Extremum::new(band, kind)).is_err() {
            self.overflow = true;
        }
    }
}

#[cfg(test)]
mod tests;
