//! Hardware traits: what the sweep needs from a rig, with no vendor in sight.
//!
//! In the embedded-hal manner: every method is fallible, every error says what *kind* of
//! failure it was ([`Error::kind`]) so generic code can choose between a retry and an abort
//! without knowing the device, and no protocol detail (microsteps, command strings, report
//! bytes) appears in a signature. Drivers own their transport; the clock is passed to them,
//! so a virtual clock makes settle and motion times free in tests.
//!
//! - [`Stage`]: a rotation stage, positions in degrees.
//! - [`TunableFilter`]: a tunable band-pass filter (an LCTF), wavelengths in nanometres.
//! - [`FilterWheel`]: a wheel of fixed filters (order sorting, blocking).
//! - [`LineCamera`]: a camera that delivers a frame as a stream of rows.
//! - [`Clock`]: monotonic time and delays, in microseconds.

/// What kind of failure an error is: enough for generic code to decide what to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum ErrorKind {
    /// The device did not answer in time (it may answer later: retry only idempotent
    /// requests).
    Timeout,
    /// The device is gone (port closed, cable pulled, connection reset).
    Disconnected,
    /// The device answered with something the protocol does not allow (garbage, a bad
    /// checksum, a reply to another request).
    Protocol,
    /// The request was outside what the device or its configuration allows; nothing was
    /// sent.
    OutOfRange,
    /// The device understood the request and refused it.
    Rejected,
    /// The device reports a fault of its own (a stalled motor, an interrupted motion, not
    /// homed).
    Fault,
    /// Anything else (an I/O error of the host).
    Other,
}

impl ErrorKind {
    /// Whether repeating an idempotent request may help.
    pub fn is_transient(self) -> bool {
        matches!(self, Self::Timeout | Self::Protocol)
    }

    /// A short name for messages.
    pub fn name(self) -> &'static str {
        match self {
            Self::Timeout => "timeout",
            Self::Disconnected => "disconnected",
            Self::Protocol => "protocol error",
            Self::OutOfRange => "out of range",
            Self::Rejected => "rejected",
            Self::Fault => "device fault",
            Self::Other => "error",
        }
    }
}

/// A device error that can say what kind it is.
pub trait Error: core::fmt::Debug {
    /// The kind of failure.
    fn kind(&self) -> ErrorKind;
}

impl Error for ErrorKind {
    fn kind(&self) -> ErrorKind {
        *self
    }
}

/// The error type of a device.
pub trait ErrorType {
    /// The error every method of the device returns.
    type Error: Error;
}

/// Monotonic time and delays. A wall clock on the rig, a virtual one in tests.
pub trait Clock {
    /// Microseconds since an arbitrary origin; never decreases.
    fn now_us(&self) -> u64;
    /// Waits `us` microseconds (a virtual clock just advances).
    fn delay_us(&mut self, us: u64);
}

/// A rotation stage holding the sample; positions in degrees of the stage's own scale.
pub trait Stage: ErrorType {
    /// Finds the reference position (required before any move) and waits until it is done.
    fn home(&mut self) -> Result<(), Self::Error>;
    /// Moves to `deg`, waits until the motion ends, and returns the position read back.
    /// A position outside [`Stage::limits_deg`] is refused with [`ErrorKind::OutOfRange`]
    /// before anything is sent.
    fn move_to_deg(&mut self, deg: f64) -> Result<f64, Self::Error>;
    /// The current position, degrees.
    fn position_deg(&mut self) -> Result<f64, Self::Error>;
    /// The configured travel `[low, high]`, degrees.
    fn limits_deg(&self) -> [f64; 2];
}

/// A tunable band-pass filter (an LCTF).
pub trait TunableFilter: ErrorType {
    /// Prepares the filter for a sweep (identification, warm-up, manual mode, bandwidth)
    /// and returns its tuning range `[low, high]`, nm.
    fn prepare(&mut self) -> Result<[f64; 2], Self::Error>;
    /// Tunes to `lambda_nm`, waits for the filter to settle and returns the wavelength read
    /// back. Outside the tuning range: [`ErrorKind::OutOfRange`], nothing sent.
    fn tune_nm(&mut self, lambda_nm: f64) -> Result<f64, Self::Error>;
    /// Puts the filter in its blocking (dark) state.
    fn block(&mut self) -> Result<(), Self::Error>;
}

/// A wheel of fixed filters, slots counted from 0.
pub trait FilterWheel: ErrorType {
    /// Number of slots.
    fn slots(&mut self) -> Result<u8, Self::Error>;
    /// Turns to `slot` and waits until it is there. A slot beyond the count is refused with
    /// [`ErrorKind::OutOfRange`].
    fn select(&mut self, slot: u8) -> Result<(), Self::Error>;
    /// The current slot, `None` while turning.
    fn current(&mut self) -> Result<Option<u8>, Self::Error>;
}

/// What a frame shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameKind {
    /// The sample.
    Sample,
    /// The dark reference (no light).
    Dark,
    /// The white reference.
    White,
}

/// A frame request with the tags the frame carries back.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameRequest {
    /// What to expose.
    pub kind: FrameKind,
    /// Measured stage angle, degrees (a tag).
    pub angle_deg: f64,
    /// Measured filter wavelength, nm (a tag).
    pub lambda_nm: f64,
    /// Band index in the sweep (a tag).
    pub band: u16,
}

/// What a frame will hold, known when it starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameInfo {
    /// The camera's id of the frame.
    pub frame_id: u64,
    /// Pixels per row.
    pub width: u32,
    /// Rows the camera means to send.
    pub rows: u32,
}

/// Why rows of a frame never arrived intact.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RowLoss {
    /// Never received (a sequence gap, a CRC failure, a stall).
    Missing,
    /// The camera ended the frame early (its trailer says fewer rows were sent).
    Partial,
}

/// One event of a frame being read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LineEvent {
    /// Row `row` is in the caller's buffer.
    Row {
        /// Image row.
        row: u32,
    },
    /// Rows `first..first + count` will not come; their pixels must be flagged.
    Lost {
        /// First lost row.
        first: u32,
        /// Number of lost rows.
        count: u32,
        /// Why.
        cause: RowLoss,
    },
    /// The frame is complete (every row reported as `Row` or `Lost`).
    End,
}

/// A camera that delivers each frame row by row (a line-streaming camera link).
pub trait LineCamera: ErrorType {
    /// Starts exposing and sending one frame.
    fn trigger(&mut self, request: FrameRequest) -> Result<FrameInfo, Self::Error>;
    /// The next event of the current frame; pixels of a [`LineEvent::Row`] go to `pixels`
    /// (`width` values). Each row of the frame is reported exactly once, as a row or as
    /// lost, and never anywhere but at its own index.
    fn read_line(&mut self, pixels: &mut [u16]) -> Result<LineEvent, Self::Error>;
}
