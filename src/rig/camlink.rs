//! The camera-link receiver: triggers frames and reads them row by row over any byte
//! stream (TCP on 127.0.0.1, a Unix socket, a pipe), detecting every transport fault the
//! framing can show (see `docs/camera-link.md`).
//!
//! Rows are placed by their own row number, never by arrival order: a reordered row is
//! delivered at its index and counted, a duplicate is dropped and counted, a row that never
//! arrives intact (sequence gap, CRC failure, stall, partial frame) is reported as
//! [`LineEvent::Lost`] so its pixels can be flagged. A trigger that gets no leader is
//! retried (nothing has been delivered yet); a frame that stalls midway is ended with its
//! missing rows reported lost, not retried (its rows are already downstream).

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::time::{Duration, Instant};

use filmscope_core::hw::{
    ErrorKind, ErrorType, FrameInfo, FrameRequest, LineCamera, LineEvent, RowLoss,
};
use filmscope_core::proto::fscl::{
    self, kind, Decoded, Header, Leader, RowHeader, Trailer, Trigger,
};

use super::error::RigError;

pub use crate::record::acquisition::LinkStats;

struct Frame {
    id: u64,
    width: usize,
    bytes_per_pixel: usize,
    rows: u32,
    seen: Vec<bool>,
    last_row: Option<u32>,
}

/// The receiver.
pub struct CamLink<S> {
    stream: S,
    name: String,
    buf: Vec<u8>,
    tx_seq: u32,
    rx_seq: Option<u32>,
    next_frame_id: u64,
    frame: Option<Frame>,
    pending: VecDeque<LineEvent>,
    max_width: u32,
    /// Triggers per frame when no leader comes.
    pub attempts: u32,
    /// The link timeout, ms (the stream's read timeout): sizes the overall deadlines.
    pub timeout_ms: u64,
    /// Faults seen so far.
    pub stats: LinkStats,
    /// When the exchange under way must end, and what it waits for.
    deadline: Option<(Instant, &'static str)>,
    /// Messages skipped (other frames, other kinds) since the exchange began.
    skipped: u64,
    /// Bytes received since the exchange began.
    received: u64,
}

/// Most messages of other frames or kinds skipped in one exchange beyond its own rows.
const MAX_SKIPPED: u64 = 256;

impl<S: Read + Write> CamLink<S> {
    /// A receiver over `stream` (whose read timeout is the link's timeout), called `name`
    /// in errors, accepting rows up to `max_width` pixels.
    pub fn new(stream: S, name: &str, max_width: u32) -> Self {
        Self {
            stream,
            name: name.to_owned(),
            buf: Vec::new(),
            tx_seq: 0,
            rx_seq: None,
            next_frame_id: 1,
            frame: None,
            pending: VecDeque::new(),
            max_width,
            attempts: 3,
            timeout_ms: 2000,
            stats: LinkStats::default(),
            deadline: None,
            skipped: 0,
            received: 0,
        }
    }

    /// Starts an exchange that must end within `ms` milliseconds of wall time, whatever
    /// the camera sends meanwhile.
    fn begin(&mut self, ms: u64, what: &'static str) {
        self.deadline = Some((Instant::now() + Duration::from_millis(ms), what));
        self.skipped = 0;
        self.received = 0;
    }

    /// The error ending an exchange that ran past its deadline: what was awaited and what
    /// the camera did meanwhile.
    fn overdue(&self, what: &str, ms: u64) -> RigError {
        let did = if self.received == 0 {
            "sent nothing".to_owned()
        } else {
            format!(
                "sent {} bytes and {} messages of other frames or kinds",
                self.received, self.skipped
            )
        };
        self.err(
            ErrorKind::Timeout,
            format!("{what} not complete within {ms} ms: the camera {did}"),
        )
    }

    /// Counts a skipped message; too many in one exchange end it.
    fn skip(&mut self, limit: u64) -> Result<(), RigError> {
        self.stats.stale_messages += 1;
        self.skipped += 1;
        if self.skipped > limit {
            let what = self.deadline.map_or("the frame", |(_, w)| w);
            return Err(self.err(
                ErrorKind::Protocol,
                format!(
                    "{what}: the camera sent {} messages of other frames or kinds instead",
                    self.skipped
                ),
            ));
        }
        Ok(())
    }

    fn err(&self, kind: ErrorKind, message: impl Into<String>) -> RigError {
        RigError::new(&self.name, kind, message)
    }

    fn max_payload(&self) -> usize {
        fscl::ROW_PREFIX + 2 * self.max_width as usize + 64
    }

    /// The next intact message.
    fn next_message(&mut self) -> Result<(Header, Vec<u8>), RigError> {
        loop {
            if !self.buf.is_empty() {
                match fscl::decode(&self.buf, self.max_payload()) {
                    Decoded::Message {
                        header,
                        payload,
                        consumed,
                    } => {
                        let payload = payload.to_vec();
                        self.buf.drain(..consumed);
                        if let Some(want) = self.rx_seq {
                            let ahead = header.seq.wrapping_sub(want);
                            if ahead != 0 && ahead < u32::MAX / 2 {
                                self.stats.sequence_gaps += u64::from(ahead);
                            }
                        }
                        self.rx_seq = Some(header.seq.wrapping_add(1));
                        return Ok((header, payload));
                    }
                    Decoded::BadCrc { consumed } => {
                        self.stats.crc_errors += 1;
                        self.buf.drain(..consumed);
                        continue;
                    }
                    Decoded::Garbage { skip } => {
                        self.stats.garbage_bytes += skip as u64;
                        self.buf.drain(..skip);
                        continue;
                    }
                    Decoded::Incomplete { .. } => {}
                }
            }
            if let Some((at, what)) = self.deadline {
                let now = Instant::now();
                if now >= at {
                    let ms = self.timeout_ms;
                    return Err(self.overdue(what, ms));
                }
            }
            let mut chunk = [0u8; 16 * 1024];
            match self.stream.read(&mut chunk) {
                Ok(0) => {
                    return Err(self.err(
                        ErrorKind::Disconnected,
                        "camera disconnected (end of stream)",
                    ))
                }
                Ok(n) => {
                    self.received += n as u64;
                    self.buf.extend_from_slice(&chunk[..n]);
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(RigError::io(&self.name, &e)),
            }
        }
    }

    fn send_trigger(&mut self, id: u64, request: &FrameRequest) -> Result<(), RigError> {
        let t = Trigger {
            angle_mdeg: (request.angle_deg * 1000.0).round() as i32,
            wavelength_pm: (request.lambda_nm * 1000.0).round().max(0.0) as u32,
            band: request.band,
        };
        let header = Header {
            kind: kind::TRIGGER,
            flags: fscl::frame_kind_flags(request.kind),
            seq: self.tx_seq,
            frame_id: id,
        };
        self.tx_seq = self.tx_seq.wrapping_add(1);
        let mut out = [0u8; fscl::message_len(Trigger::LEN)];
        let n = fscl::encode(&mut out, header, &t.to_bytes()).unwrap_or(0);
        self.stream
            .write_all(&out[..n])
            .and_then(|()| self.stream.flush())
            .map_err(|e| RigError::io(&self.name, &e))
    }

    fn await_leader(&mut self, id: u64) -> Result<FrameInfo, RigError> {
        loop {
            let (h, p) = self.next_message()?;
            if h.frame_id != id {
                self.skip(MAX_SKIPPED)?;
                continue;
            }
            match h.kind {
                kind::LEADER => {
                    let l = Leader::parse(&p)
                        .map_err(|_| self.err(ErrorKind::Protocol, "leader of the wrong length"))?;
                    let bpp = l.bytes_per_pixel().ok_or_else(|| {
                        self.err(
                            ErrorKind::Protocol,
                            format!("pixel format {:#010x} not supported", l.pixel_format),
                        )
                    })?;
                    if l.width == 0 || l.width > self.max_width || l.expected_rows > 1 << 20 {
                        return Err(self.err(
                            ErrorKind::Protocol,
                            format!("frame of {} x {} pixels refused", l.width, l.expected_rows),
                        ));
                    }
                    self.frame = Some(Frame {
                        id,
                        width: l.width as usize,
                        bytes_per_pixel: bpp,
                        rows: l.expected_rows,
                        seen: vec![false; l.expected_rows as usize],
                        last_row: None,
                    });
                    return Ok(FrameInfo {
                        frame_id: id,
                        width: l.width,
                        rows: l.expected_rows,
                    });
                }
                kind::ERROR => {
                    return Err(self.err(
                        ErrorKind::Rejected,
                        format!(
                            "camera refused the trigger: {}",
                            String::from_utf8_lossy(&p)
                        ),
                    ))
                }
                _ => self.skip(MAX_SKIPPED)?,
            }
        }
    }

    /// Whether the exchange under way has run past its deadline.
    fn past_deadline(&self) -> bool {
        self.deadline.is_some_and(|(at, _)| Instant::now() >= at)
    }

    /// Queues `Lost` events for every row of the current frame not seen, then `End`.
    fn finish_frame(&mut self, rows_sent: Option<u32>) {
        let Some(f) = self.frame.take() else {
            self.pending.push_back(LineEvent::End);
            return;
        };
        let cause_of = |r: u32| match rows_sent {
            Some(n) if r >= n => RowLoss::Partial,
            _ => RowLoss::Missing,
        };
        let mut r = 0;
        while r < f.rows {
            if f.seen[r as usize] {
                r += 1;
                continue;
            }
            let (first, cause) = (r, cause_of(r));
            while r < f.rows && !f.seen[r as usize] && cause_of(r) == cause {
                r += 1;
            }
            self.stats.rows_lost += u64::from(r - first);
            self.pending.push_back(LineEvent::Lost {
                first,
                count: r - first,
                cause,
            });
        }
        self.pending.push_back(LineEvent::End);
    }

    fn take_row(&mut self, p: &[u8], pixels: &mut [u16]) -> Option<u32> {
        let f = self.frame.as_mut()?;
        let (rh, px) = RowHeader::parse(p).ok()?;
        if rh.row >= f.rows || px.len() != f.width * f.bytes_per_pixel || pixels.len() < f.width {
            return None;
        }
        if f.seen[rh.row as usize] {
            self.stats.duplicate_rows += 1;
            return None;
        }
        if f.last_row.is_some_and(|l| rh.row < l) {
            self.stats.out_of_order_rows += 1;
        }
        f.last_row = Some(f.last_row.map_or(rh.row, |l| l.max(rh.row)));
        f.seen[rh.row as usize] = true;
        if f.bytes_per_pixel == 1 {
            for (o, &b) in pixels.iter_mut().zip(px) {
                *o = u16::from(b);
            }
        } else {
            for (o, b) in pixels.iter_mut().zip(px.chunks_exact(2)) {
                *o = u16::from_le_bytes([b[0], b[1]]);
            }
        }
        self.stats.rows += 1;
        Some(rh.row)
    }
}

impl<S: Read + Write> ErrorType for CamLink<S> {
    type Error = RigError;
}

impl<S: Read + Write> LineCamera for CamLink<S> {
    fn trigger(&mut self, request: FrameRequest) -> Result<FrameInfo, RigError> {
        self.pending.clear();
        self.frame = None;
        let mut left = self.attempts.max(1);
        loop {
            let id = self.next_frame_id;
            self.next_frame_id += 1;
            self.send_trigger(id, &request)?;
            // An attempt ends within twice the link timeout, whatever arrives meanwhile.
            self.begin(2 * self.timeout_ms, "the leader");
            let leader = self.await_leader(id);
            if let Ok(info) = &leader {
                // The frame's rows: three link timeouts, and one more per 64 rows.
                let ms = self
                    .timeout_ms
                    .saturating_mul(3 + u64::from(info.rows) / 64);
                self.begin(ms, "the frame");
            } else {
                self.deadline = None;
            }
            match leader {
                Err(e) if e.kind == ErrorKind::Timeout && left > 1 => {
                    left -= 1;
                    self.stats.trigger_retries += 1;
                }
                Ok(info) => {
                    self.stats.frames += 1;
                    return Ok(info);
                }
                Err(e) => return Err(e),
            }
        }
    }

    fn read_line(&mut self, pixels: &mut [u16]) -> Result<LineEvent, RigError> {
        loop {
            if let Some(e) = self.pending.pop_front() {
                return Ok(e);
            }
            let Some(id) = self.frame.as_ref().map(|f| f.id) else {
                return Ok(LineEvent::End);
            };
            let (h, p) = match self.next_message() {
                Ok(m) => m,
                // A read timeout is a stall: the frame ends with its missing rows lost. A
                // frame past its overall deadline ends the exchange with an error.
                Err(e) if e.kind == ErrorKind::Timeout && !self.past_deadline() => {
                    self.stats.stalled_frames += 1;
                    self.finish_frame(None);
                    continue;
                }
                Err(e) => {
                    self.frame = None;
                    self.deadline = None;
                    return Err(e);
                }
            };
            let rows = u64::from(self.frame.as_ref().map_or(0, |f| f.rows));
            if h.frame_id != id {
                self.skip(MAX_SKIPPED + rows)?;
                continue;
            }
            match h.kind {
                kind::ROW => {
                    if let Some(row) = self.take_row(&p, pixels) {
                        return Ok(LineEvent::Row { row });
                    }
                }
                kind::TRAILER => {
                    let t = Trailer::parse(&p).ok();
                    let sent = t.map(|t| t.rows_sent);
                    if t.is_some_and(|t| t.status != fscl::STATUS_COMPLETE) {
                        self.stats.partial_frames += 1;
                    }
                    self.finish_frame(sent);
                }
                _ => self.skip(MAX_SKIPPED + rows)?,
            }
        }
    }
}
