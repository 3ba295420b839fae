//! Thorlabs Kurios LCTF driver, generic over the transport and the clock.
//!
//! Every exchange reads through the `>` prompt, sets included. Queries are retried on a
//! timeout; `WL=` is idempotent and retried too. The filter gives no "settled" signal: the
//! driver waits the configured settle time after each tuning, then reads `WL?` back.

use std::io::{Read, Write};

use filmscope_core::hw::{Clock, ErrorKind, ErrorType, TunableFilter};
use filmscope_core::proto::kurios;

use super::error::{retry, RigError};
use super::line::LineIo;

/// How the filter is set up.
#[derive(Clone, Debug, PartialEq)]
pub struct KuriosConfig {
    /// Bandwidth mode for the sweep (2 wide, 4 medium, 8 narrow).
    pub bandwidth: u32,
    /// Wait after each tuning, microseconds (100 ms default, unconfirmed).
    pub settle_us: u64,
    /// Longest warm-up, microseconds.
    pub warm_up_timeout_us: u64,
    /// `ST?` value meaning ready (2, unconfirmed).
    pub ready_status: u32,
    /// Attempts per exchange on timeouts.
    pub attempts: u32,
    /// Largest difference between the wavelength asked for and read back, nm.
    pub tolerance_nm: f64,
    /// Longest exchange (one command and its reply, whatever the filter sends meanwhile),
    /// ms of wall time.
    pub exchange_timeout_ms: u64,
}

/// Most empty prompts read while waiting for the answer to one query.
const MAX_EMPTY_PROMPTS: usize = 16;

impl Default for KuriosConfig {
    fn default() -> Self {
        Self {
            bandwidth: 8,
            settle_us: 100_000,
            warm_up_timeout_us: 120_000_000,
            ready_status: 2,
            attempts: 3,
            tolerance_nm: 0.01,
            exchange_timeout_ms: 2_000,
        }
    }
}

/// The LCTF driver.
pub struct Kurios<T, C> {
    io: LineIo<T>,
    clock: C,
    config: KuriosConfig,
    range_nm: Option<[f64; 2]>,
    /// The `*IDN?` reply, once prepared.
    pub identity: String,
}

impl<T: Read + Write, C: Clock> Kurios<T, C> {
    /// A driver over `port` (called `name` in errors).
    pub fn new(port: T, name: &str, clock: C, config: KuriosConfig) -> Self {
        Self {
            io: LineIo::new(port, name),
            clock,
            config,
            range_nm: None,
            identity: String::new(),
        }
    }

    fn err(&self, kind: ErrorKind, message: impl Into<String>) -> RigError {
        RigError::new(self.io.name(), kind, message)
    }

    fn once(&mut self, command: &str) -> Result<Vec<String>, RigError> {
        self.io.send(command.as_bytes())?;
        self.io.begin(self.config.exchange_timeout_ms);
        let mut lines = Vec::new();
        let mut prompts = 0;
        // A query always has an answer: an empty one was a stray prompt (the power-up
        // prompt, or the end of a reply that timed out), so read on to the next; a filter
        // repeating its prompt without ever answering is a fault.
        while lines.is_empty() {
            prompts += 1;
            if prompts > MAX_EMPTY_PROMPTS {
                return Err(self.err(
                    ErrorKind::Fault,
                    format!(
                        "sent {MAX_EMPTY_PROMPTS} empty prompts without an answer to `{}`",
                        command.trim()
                    ),
                ));
            }
            let text = self.io.read_until(&[kurios::PROMPT])?;
            lines = text
                .split(['\r', '\n'])
                .map(str::trim)
                .filter(|l| !l.is_empty())
                .map(str::to_owned)
                .collect();
            if !command.trim_end().ends_with('?') {
                break;
            }
        }
        if let Some(bad) = lines.iter().find(|l| kurios::is_refusal(l)) {
            return Err(self.err(
                ErrorKind::Rejected,
                format!("filter refused `{}`: {bad}", command.trim()),
            ));
        }
        Ok(lines)
    }

    /// Sends `command` (CR included) and returns the reply lines before the prompt.
    pub fn exchange(&mut self, command: &str) -> Result<Vec<String>, RigError> {
        let attempts = self.config.attempts;
        retry(attempts, || {
            let r = self.once(command);
            if r.is_err() {
                self.io.discard();
            }
            r
        })
    }

    fn query_number(&mut self, key: &str) -> Result<f64, RigError> {
        let q = kurios::query(key).unwrap_or_default();
        let lines = self.exchange(&q)?;
        lines
            .iter()
            .find_map(|l| kurios::number(l, key))
            .ok_or_else(|| {
                self.err(
                    ErrorKind::Protocol,
                    format!("no {key} value in the reply {lines:?}"),
                )
            })
    }
}

impl<T: Read + Write, C: Clock> ErrorType for Kurios<T, C> {
    type Error = RigError;
}

impl<T: Read + Write, C: Clock> TunableFilter for Kurios<T, C> {
    fn prepare(&mut self) -> Result<[f64; 2], RigError> {
        // A power-up prompt may be waiting: an empty exchange would be CMD_NOT_DEFINED, so
        // just drop whatever is buffered.
        self.io.discard();
        self.identity = self.exchange("*IDN?\r")?.join(" ");
        let sp = self.exchange("SP?\r")?;
        let max = sp.iter().find_map(|l| kurios::number(l, "WLmax"));
        let min = sp.iter().find_map(|l| kurios::number(l, "WLmin"));
        let (Some(min), Some(max)) = (min, max) else {
            return Err(self.err(
                ErrorKind::Protocol,
                format!("no range in the SP? reply {sp:?}"),
            ));
        };
        let oh = self.exchange("OH?\r")?;
        let head = oh.iter().find_map(|l| kurios::head(l));
        if let Some(h) = head {
            if u32::from(h.modes) & self.config.bandwidth == 0 {
                return Err(self.err(
                    ErrorKind::OutOfRange,
                    format!(
                        "bandwidth mode {} not offered by this head (modes {:#x})",
                        self.config.bandwidth, h.modes
                    ),
                ));
            }
        }
        let t0 = self.clock.now_us();
        loop {
            let st = self.query_number("ST")?;
            if st == f64::from(self.config.ready_status) {
                break;
            }
            if self.clock.now_us().saturating_sub(t0) > self.config.warm_up_timeout_us {
                return Err(self.err(ErrorKind::Timeout, format!("still warming up (ST={st})")));
            }
            self.clock.delay_us(500_000);
        }
        self.exchange("OM=1\r")?;
        let bw = kurios::set("BW", self.config.bandwidth).unwrap_or_default();
        self.exchange(&bw)?;
        self.range_nm = Some([min, max]);
        Ok([min, max])
    }

    fn tune_nm(&mut self, lambda_nm: f64) -> Result<f64, RigError> {
        let [lo, hi] = self.range_nm.unwrap_or([f64::NEG_INFINITY, f64::INFINITY]);
        if !(lambda_nm.is_finite() && lambda_nm >= lo && lambda_nm <= hi) {
            return Err(self.err(
                ErrorKind::OutOfRange,
                format!("{lambda_nm} nm is outside the filter's range [{lo}, {hi}] nm"),
            ));
        }
        let cmd = kurios::set_wavelength(lambda_nm).unwrap_or_default();
        self.exchange(&cmd)?;
        self.clock.delay_us(self.config.settle_us);
        let got = self.query_number("WL")?;
        // NaN or infinity read back is no wavelength: refused like a wrong one.
        if !(got.is_finite() && (got - lambda_nm).abs() <= self.config.tolerance_nm) {
            return Err(self.err(
                ErrorKind::Fault,
                format!("filter reads {got} nm after tuning to {lambda_nm} nm"),
            ));
        }
        Ok(got)
    }

    fn block(&mut self) -> Result<(), RigError> {
        self.exchange("BW=1\r").map(|_| ())
    }
}
