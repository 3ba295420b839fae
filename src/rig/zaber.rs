//! Zaber ASCII rotation stage driver, generic over the transport (`Read + Write`: a serial
//! port, a pty, an in-memory fake) and the clock.
//!
//! Every command carries a message id and a checksum; a reply with another id is a late
//! answer to an earlier attempt and is skipped. All commands sent are idempotent (`home`,
//! `move abs`, `get pos`), so a timeout or a garbled reply is retried. Moves outside the
//! configured limits are refused before anything is sent.

use std::io::{Read, Write};

use filmscope_core::hw::{Clock, ErrorKind, ErrorType, Stage};
use filmscope_core::proto::zaber;

use super::error::{retry, RigError};
use super::line::LineIo;

/// How the stage is set up.
#[derive(Clone, Debug, PartialEq)]
pub struct ZaberConfig {
    /// Device address.
    pub device: u8,
    /// Axis.
    pub axis: u8,
    /// Microsteps per degree (4266.67 on a typical rotary stage; read it from the stage's
    /// data sheet).
    pub steps_per_deg: f64,
    /// Travel allowed, degrees; moves outside are refused.
    pub limits_deg: [f64; 2],
    /// Interval between status polls while moving, microseconds.
    pub poll_us: u64,
    /// Longest motion (homing included), microseconds.
    pub motion_timeout_us: u64,
    /// Attempts per command on timeouts and garbled replies.
    pub attempts: u32,
    /// Longest exchange (one command and its reply, whatever the stage sends meanwhile),
    /// ms of wall time.
    pub exchange_timeout_ms: u64,
}

/// Most lines (info lines, alerts, late replies) skipped while waiting for one reply.
const MAX_SKIPPED_LINES: usize = 64;

impl Default for ZaberConfig {
    fn default() -> Self {
        Self {
            device: 1,
            axis: 1,
            steps_per_deg: 4_266.666_666_666_667,
            limits_deg: [0.0, 90.0],
            poll_us: 20_000,
            motion_timeout_us: 60_000_000,
            attempts: 3,
            exchange_timeout_ms: 2_000,
        }
    }
}

/// A reply, owned.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ZaberReply {
    /// `OK`.
    pub accepted: bool,
    /// `BUSY`.
    pub busy: bool,
    /// Warning flag (`--` none).
    pub warning: String,
    /// Data field.
    pub data: String,
}

/// The stage driver.
pub struct Zaber<T, C> {
    io: LineIo<T>,
    clock: C,
    config: ZaberConfig,
    next_id: u8,
}

impl<T: Read + Write, C: Clock> Zaber<T, C> {
    /// A driver over `port` (called `name` in errors).
    pub fn new(port: T, name: &str, clock: C, config: ZaberConfig) -> Self {
        Self {
            io: LineIo::new(port, name),
            clock,
            config,
            next_id: 0,
        }
    }

    fn err(&self, kind: ErrorKind, message: impl Into<String>) -> RigError {
        RigError::new(self.io.name(), kind, message)
    }

    fn once(&mut self, text: &str) -> Result<ZaberReply, RigError> {
        self.next_id = self.next_id % 99 + 1;
        let id = self.next_id;
        let c = &self.config;
        let line = zaber::command(c.device, c.axis, Some(id), text)
            .ok_or_else(|| self.err(ErrorKind::OutOfRange, format!("command too long: {text}")))?;
        self.io.send(line.as_bytes())?;
        self.io.begin(self.config.exchange_timeout_ms);
        let mut skipped = 0;
        loop {
            let line = self.io.read_until(b"\n")?;
            match zaber::parse(&line) {
                Ok(zaber::Message::Reply(r))
                    if r.id == Some(id) && (r.device != c.device || r.axis != c.axis) =>
                {
                    self.io.discard();
                    return Err(self.err(
                        ErrorKind::Protocol,
                        format!(
                            "the reply to `{text}` comes from device {} axis {}, not device {} axis {} (rig.toml stage.device, stage.axis)",
                            r.device, r.axis, c.device, c.axis
                        ),
                    ));
                }
                Ok(zaber::Message::Reply(r)) if r.id == Some(id) => {
                    return Ok(ZaberReply {
                        accepted: r.accepted,
                        busy: r.busy,
                        warning: r.warning_str().to_owned(),
                        data: r.data.to_owned(),
                    })
                }
                // A late reply to an earlier attempt, an info line, an alert, a blank: a few
                // are normal, an endless stream is a fault.
                Ok(_) | Err(zaber::ParseError::Empty) => {
                    skipped += 1;
                    if skipped >= MAX_SKIPPED_LINES {
                        self.io.discard();
                        return Err(self.err(
                            ErrorKind::Fault,
                            format!(
                                "sent {skipped} lines without the reply to `{text}` (last: {:?})",
                                crate::limits::printable(line.trim())
                            ),
                        ));
                    }
                }
                Err(e) => {
                    self.io.discard();
                    return Err(self.err(
                        ErrorKind::Protocol,
                        format!("bad reply to `{text}` ({e:?}): {}", line.trim()),
                    ));
                }
            }
        }
    }

    /// Sends `text` (retrying timeouts and garbled replies) and returns the accepted reply;
    /// a refusal is a [`ErrorKind::Rejected`] error naming the reason.
    pub fn request(&mut self, text: &str) -> Result<ZaberReply, RigError> {
        let attempts = self.config.attempts;
        let r = retry(attempts, || self.once(text))?;
        if !r.accepted {
            return Err(self.err(
                ErrorKind::Rejected,
                format!("stage refused `{text}`: {}", r.data),
            ));
        }
        Ok(r)
    }

    /// Polls until the stage is idle; returns the position (microsteps), refusing fault,
    /// interrupted-motion and no-reference flags.
    fn wait_idle(&mut self, what: &str) -> Result<i64, RigError> {
        let t0 = self.clock.now_us();
        loop {
            let r = self.request("get pos")?;
            if !r.busy {
                let problem = match r.warning.as_str() {
                    w if w.starts_with('F') => Some(format!("stage fault {w} during {what}")),
                    "NI" => Some(format!("motion interrupted during {what} (NI)")),
                    "WR" => Some(format!(
                        "no reference position after {what} (WR): home first"
                    )),
                    _ => None,
                };
                if let Some(p) = problem {
                    return Err(self.err(ErrorKind::Fault, p));
                }
                return r.data.trim().parse().map_err(|_| {
                    self.err(
                        ErrorKind::Protocol,
                        format!("position not a number: {}", r.data),
                    )
                });
            }
            if self.clock.now_us().saturating_sub(t0) > self.config.motion_timeout_us {
                let _ = self.request("stop");
                return Err(self.err(
                    ErrorKind::Timeout,
                    format!(
                        "{what} not finished after {} s; stage stopped",
                        self.config.motion_timeout_us / 1_000_000
                    ),
                ));
            }
            self.clock.delay_us(self.config.poll_us);
        }
    }

    /// The clock (for tests that inspect the virtual time).
    pub fn clock(&self) -> &C {
        &self.clock
    }
}

impl<T: Read + Write, C: Clock> ErrorType for Zaber<T, C> {
    type Error = RigError;
}

impl<T: Read + Write, C: Clock> Stage for Zaber<T, C> {
    fn home(&mut self) -> Result<(), RigError> {
        self.request("home")?;
        self.wait_idle("homing")?;
        Ok(())
    }

    fn move_to_deg(&mut self, deg: f64) -> Result<f64, RigError> {
        let [lo, hi] = self.config.limits_deg;
        if !(deg.is_finite() && deg >= lo && deg <= hi) {
            return Err(self.err(
                ErrorKind::OutOfRange,
                format!("{deg} deg is outside the stage limits [{lo}, {hi}] deg; not moved"),
            ));
        }
        let steps = (deg * self.config.steps_per_deg).round() as i64;
        self.request(&format!("move abs {steps}"))?;
        let pos = self.wait_idle(&format!("the move to {deg} deg"))?;
        if (pos - steps).abs() > 2 {
            return Err(self.err(
                ErrorKind::Fault,
                format!("stage stopped at {pos} instead of {steps} microsteps"),
            ));
        }
        Ok(pos as f64 / self.config.steps_per_deg)
    }

    fn position_deg(&mut self) -> Result<f64, RigError> {
        let r = self.request("get pos")?;
        let pos: i64 = r.data.trim().parse().map_err(|_| {
            self.err(
                ErrorKind::Protocol,
                format!("position not a number: {}", r.data),
            )
        })?;
        Ok(pos as f64 / self.config.steps_per_deg)
    }

    fn limits_deg(&self) -> [f64; 2] {
        self.config.limits_deg
    }
}
