//! The rig's error: which device (its port), what kind, what happened, in one line.

use std::io;

use filmscope_core::hw::{self, ErrorKind};

/// A device error: `PORT: problem`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{device}: {message}")]
pub struct RigError {
    /// What failed (port path, socket address, device name).
    pub device: String,
    /// The kind of failure.
    pub kind: ErrorKind,
    /// What happened, one line.
    pub message: String,
}

impl RigError {
    /// An error of `kind` on `device`. Control characters in either (a device's own text:
    /// escape sequences, NUL bytes, line ends) are escaped so the error cannot drive a
    /// terminal or split a log line ([`crate::limits::printable`]).
    pub fn new(device: &str, kind: ErrorKind, message: impl Into<String>) -> Self {
        Self {
            device: crate::limits::printable(device),
            kind,
            message: crate::limits::printable(&message.into()),
        }
    }

    /// An I/O error on `device`, classified (timeouts, hang-ups, the rest).
    pub fn io(device: &str, e: &io::Error) -> Self {
        let kind = match e.kind() {
            io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock => ErrorKind::Timeout,
            io::ErrorKind::BrokenPipe
            | io::ErrorKind::ConnectionReset
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::NotConnected
            | io::ErrorKind::UnexpectedEof => ErrorKind::Disconnected,
            // EIO: a pty whose other end closed, a USB serial adapter unplugged.
            _ if e.raw_os_error() == Some(5) => ErrorKind::Disconnected,
            _ => ErrorKind::Other,
        };
        let message = match kind {
            ErrorKind::Timeout => "no reply in time".to_owned(),
            ErrorKind::Disconnected => format!("device disconnected ({e})"),
            _ => e.to_string(),
        };
        Self::new(device, kind, message)
    }
}

impl hw::Error for RigError {
    fn kind(&self) -> ErrorKind {
        self.kind
    }
}

/// Runs `f` up to `attempts` times while it fails transiently (timeouts, garbled replies);
/// only for idempotent requests.
pub fn retry<T>(attempts: u32, mut f: impl FnMut() -> Result<T, RigError>) -> Result<T, RigError> {
    let mut left = attempts.max(1);
    loop {
        match f() {
            Err(e) if left > 1 && e.kind.is_transient() => left -= 1,
            other => return other,
        }
    }
}
