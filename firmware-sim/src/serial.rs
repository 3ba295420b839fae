//! What every simulated serial device shares: line assembly, a transcript of what was said,
//! fault injection, and an in-memory port (`Read + Write`) on a virtual clock.
//!
//! A device's firmware is a [`LineFirmware`]: it answers one command line at a time and
//! never sees bytes, time or faults except through its arguments. [`SerialDevice`] wraps
//! it with the byte stream; [`SimPort`] is the host's end for in-process tests, and the
//! `serve` module puts the same device behind a pty.

use std::collections::VecDeque;
use std::io;
use std::sync::{Arc, Mutex, MutexGuard};

use filmscope_core::hw::Clock;

use crate::clock::VirtualClock;

/// A device's firmware, one command line at a time.
pub trait LineFirmware: Send {
    /// Bytes that end a command line.
    fn terminators(&self) -> &'static [u8];
    /// What the device sends at power-up (before any command).
    fn banner(&self) -> String {
        String::new()
    }
    /// Answers `line` (without its terminator) at `now_us`; `reject` asks for a refusal of
    /// the device's own kind (fault injection).
    fn respond(&mut self, line: &str, now_us: u64, reject: bool) -> String;
}

/// Which side spoke.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dir {
    /// Host to device.
    ToDevice,
    /// Device to host.
    ToHost,
}

/// One entry of a transcript: a command line, or the whole reply to it (line ends shown as
/// `\r` and `\n`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Said {
    /// Who.
    pub dir: Dir,
    /// What.
    pub text: String,
}

impl std::fmt::Display for Said {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let arrow = match self.dir {
            Dir::ToDevice => "->",
            Dir::ToHost => "<-",
        };
        write!(f, "{arrow} {}", self.text)
    }
}

fn escaped(s: &str) -> String {
    s.replace('\r', "\\r").replace('\n', "\\n")
}

/// Faults to inject, by the 1-based ordinal of the command line they hit.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SerialFaults {
    /// These commands are refused (the device's own refusal).
    pub reject: Vec<usize>,
    /// These commands get no reply at all (the host times out).
    pub swallow: Vec<usize>,
    /// These commands get line noise instead of their reply.
    pub garbage: Vec<usize>,
    /// Replies reach the host in pieces of at most this many bytes.
    pub split: Option<usize>,
    /// The device disappears after this many commands (the port then fails).
    pub vanish_after: Option<usize>,
    /// From this command on the device never falls silent: whenever it has nothing else to
    /// send it sends this text again (a stage streaming info lines, a filter repeating its
    /// `>` prompt).
    pub babble: Option<(usize, String)>,
    /// Commands with this text (terminator excluded) get this reply instead of their own
    /// (a wrong reading, device text with control characters).
    pub replace: Vec<(String, String)>,
}

/// A serial device: firmware plus the byte stream, the transcript and the faults.
pub struct SerialDevice<F> {
    firmware: F,
    rx: Vec<u8>,
    tx: VecDeque<u8>,
    faults: SerialFaults,
    commands: usize,
    transcript: Vec<Said>,
    gone: bool,
}

impl<F: LineFirmware> SerialDevice<F> {
    /// Powers the device up (its banner is waiting to be read).
    pub fn new(firmware: F, faults: SerialFaults) -> Self {
        let banner = firmware.banner();
        Self {
            firmware,
            rx: Vec::new(),
            tx: banner.bytes().collect(),
            faults,
            commands: 0,
            transcript: Vec::new(),
            gone: false,
        }
    }

    /// The firmware (to inspect its state).
    pub fn firmware(&self) -> &F {
        &self.firmware
    }

    /// Bytes from the host.
    pub fn receive(&mut self, bytes: &[u8], now_us: u64) {
        if self.gone {
            return;
        }
        for &b in bytes {
            if !self.firmware.terminators().contains(&b) {
                if self.rx.len() < 4096 {
                    self.rx.push(b);
                }
                continue;
            }
            let line = String::from_utf8_lossy(&self.rx).into_owned();
            self.rx.clear();
            if line.is_empty() && b == b'\n' {
                continue; // the LF of a CRLF
            }
            self.command(&line, now_us);
            if self.gone {
                return;
            }
        }
    }

    fn command(&mut self, line: &str, now_us: u64) {
        self.commands += 1;
        let n = self.commands;
        self.transcript.push(Said {
            dir: Dir::ToDevice,
            text: escaped(line),
        });
        let reject = self.faults.reject.contains(&n);
        let reply = self.firmware.respond(line, now_us, reject);
        let replaced = self
            .faults
            .replace
            .iter()
            .find(|(cmd, _)| cmd.trim() == line.trim())
            .map(|(_, reply)| reply.clone());
        let reply = if let Some(r) = replaced {
            r
        } else if self.faults.swallow.contains(&n) {
            String::new()
        } else if self.faults.garbage.contains(&n) {
            "\u{7f}#~@@ xq\r\n".to_owned()
        } else {
            reply
        };
        if !reply.is_empty() {
            self.transcript.push(Said {
                dir: Dir::ToHost,
                text: escaped(&reply),
            });
        }
        self.tx.extend(reply.bytes());
        if self.faults.vanish_after.is_some_and(|v| n >= v) {
            self.gone = true;
            self.tx.clear();
        }
    }

    /// Up to `max` bytes for the host (fewer when replies are split).
    pub fn transmit(&mut self, max: usize) -> Vec<u8> {
        if self.tx.is_empty() && !self.gone {
            if let Some((from, text)) = &self.faults.babble {
                if self.commands >= *from {
                    self.tx.extend(text.bytes());
                }
            }
        }
        let n = self.faults.split.map_or(max, |s| s.max(1).min(max));
        let n = n.min(self.tx.len());
        self.tx.drain(..n).collect()
    }

    /// Whether the device has disappeared.
    pub fn is_gone(&self) -> bool {
        self.gone
    }

    /// Everything said so far.
    pub fn transcript(&self) -> &[Said] {
        &self.transcript
    }
}

/// A device shared between its port and the test that inspects it.
pub type Shared<F> = Arc<Mutex<SerialDevice<F>>>;

/// Locks a shared device, surviving a panicked holder (the state is still consistent: every
/// method leaves it so).
pub fn lock<F>(dev: &Shared<F>) -> MutexGuard<'_, SerialDevice<F>> {
    dev.lock().unwrap_or_else(|p| p.into_inner())
}

/// The host's end of a simulated serial line, in memory: what the host writes goes to the
/// device, reads return the device's output; a read with nothing to return advances the
/// virtual clock by the port's timeout and fails with `TimedOut`, like a serial port.
pub struct SimPort<F> {
    device: Shared<F>,
    clock: VirtualClock,
    timeout_us: u64,
}

impl<F: LineFirmware> SimPort<F> {
    /// A port to `device` on `clock`, with a read timeout of `timeout_us`.
    pub fn new(device: Shared<F>, clock: VirtualClock, timeout_us: u64) -> Self {
        Self {
            device,
            clock,
            timeout_us,
        }
    }
}

impl<F: LineFirmware> io::Read for SimPort<F> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let mut dev = lock(&self.device);
        if dev.is_gone() {
            return Err(io::Error::new(io::ErrorKind::BrokenPipe, "device gone"));
        }
        let bytes = dev.transmit(buf.len());
        if bytes.is_empty() {
            drop(dev);
            self.clock.advance(self.timeout_us);
            return Err(io::Error::new(io::ErrorKind::TimedOut, "read timed out"));
        }
        buf[..bytes.len()].copy_from_slice(&bytes);
        Ok(bytes.len())
    }
}

impl<F: LineFirmware> io::Write for SimPort<F> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let mut dev = lock(&self.device);
        if dev.is_gone() {
            return Err(io::Error::new(io::ErrorKind::BrokenPipe, "device gone"));
        }
        dev.receive(buf, self.clock.now_us());
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}
