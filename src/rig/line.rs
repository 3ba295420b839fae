//! Line-oriented reading over any `Read + Write` transport (a serial port, a pty, an
//! in-memory fake), with the buffering the drivers share.

use std::io::{Read, Write};

use filmscope_core::hw::ErrorKind;

use super::error::RigError;

/// Longest line accepted before the input is called garbage.
const MAX_LINE: usize = 1024;

/// A transport with a read buffer.
pub struct LineIo<T> {
    port: T,
    name: String,
    buf: Vec<u8>,
    /// When the exchange under way must end (wall time), and its length in ms.
    deadline: Option<(std::time::Instant, u64)>,
}

impl<T: Read + Write> LineIo<T> {
    /// Wraps `port`, called `name` in errors.
    pub fn new(port: T, name: &str) -> Self {
        Self {
            port,
            name: name.to_owned(),
            buf: Vec::new(),
            deadline: None,
        }
    }

    /// Starts an exchange that must end within `ms` milliseconds of wall time: a device
    /// sending a byte now and then, each under the port's read timeout, cannot hold it
    /// longer. `0` lifts the deadline.
    pub fn begin(&mut self, ms: u64) {
        self.deadline = (ms > 0).then(|| {
            (
                std::time::Instant::now() + std::time::Duration::from_millis(ms),
                ms,
            )
        });
    }

    /// The port's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Sends `bytes`.
    pub fn send(&mut self, bytes: &[u8]) -> Result<(), RigError> {
        self.port
            .write_all(bytes)
            .and_then(|()| self.port.flush())
            .map_err(|e| RigError::io(&self.name, &e))
    }

    fn fill(&mut self) -> Result<(), RigError> {
        if let Some((at, ms)) = self.deadline {
            if std::time::Instant::now() >= at {
                let got = crate::limits::printable(&String::from_utf8_lossy(
                    &self.buf[..self.buf.len().min(40)],
                ));
                return Err(RigError::new(
                    &self.name,
                    ErrorKind::Timeout,
                    format!(
                        "no complete reply within {ms} ms ({} bytes of an unfinished line: {got:?})",
                        self.buf.len()
                    ),
                ));
            }
        }
        let mut chunk = [0u8; 256];
        match self.port.read(&mut chunk) {
            Ok(0) => Err(RigError::new(
                &self.name,
                ErrorKind::Disconnected,
                "device disconnected (end of stream)",
            )),
            Ok(n) => {
                self.buf.extend_from_slice(&chunk[..n]);
                Ok(())
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(()),
            Err(e) => Err(RigError::io(&self.name, &e)),
        }
    }

    /// Reads through the first byte in `ends`; returns what came before it. A read that
    /// times out before is a [`ErrorKind::Timeout`].
    pub fn read_until(&mut self, ends: &[u8]) -> Result<String, RigError> {
        loop {
            if let Some(i) = self.buf.iter().position(|b| ends.contains(b)) {
                let line: Vec<u8> = self.buf.drain(..=i).collect();
                return Ok(String::from_utf8_lossy(&line[..i]).into_owned());
            }
            if self.buf.len() > MAX_LINE {
                self.buf.clear();
                return Err(RigError::new(
                    &self.name,
                    ErrorKind::Protocol,
                    format!("more than {MAX_LINE} bytes without a line end"),
                ));
            }
            self.fill()?;
        }
    }

    /// Drops whatever is buffered (after a timeout, a late reply must not be taken for the
    /// next one).
    pub fn discard(&mut self) {
        self.buf.clear();
    }
}
