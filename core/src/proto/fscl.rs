//! The camera link's framing, `FSCL` (see `docs/camera-link.md`): every message is
//!
//! ```text
//! magic "FSCL" | version u8 | type u8 | flags u16 | seq u32 | frame_id u64 | len u32
//! | payload (len bytes) | crc32 u32
//! ```
//!
//! little endian, CRC-32/IEEE over magic..payload. [`decode`] validates a message once
//! (magic, version, length bound, CRC) and returns views into the caller's buffer; the
//! payload parsers check their own lengths, so nothing after a successful decode can panic.

/// The magic bytes that start every message.
pub const MAGIC: [u8; 4] = *b"FSCL";
/// The protocol version this codec speaks.
pub const VERSION: u8 = 1;
/// Bytes before the payload.
pub const HEADER_LEN: usize = 24;
/// Bytes after the payload.
pub const CRC_LEN: usize = 4;

/// PFNC Mono8.
pub const MONO8: u32 = 0x0108_0001;
/// PFNC Mono12 (12 bits in a little-endian u16).
pub const MONO12: u32 = 0x0110_0005;
/// PFNC Mono16.
pub const MONO16: u32 = 0x0110_0007;

/// Message types.
pub mod kind {
    /// Camera to host: a frame starts.
    pub const LEADER: u8 = 1;
    /// Camera to host: one row.
    pub const ROW: u8 = 2;
    /// Camera to host: the frame ends; how many rows were sent.
    pub const TRAILER: u8 = 3;
    /// Camera to host: the camera could not do what was asked.
    pub const ERROR: u8 = 4;
    /// Host to camera (a filmscope extension): expose and send one frame.
    pub const TRIGGER: u8 = 5;
}

/// Trailer status: every row was sent.
pub const STATUS_COMPLETE: u16 = 0;
/// Trailer status: the camera's line timeout flushed a partial frame.
pub const STATUS_PARTIAL: u16 = 1;

/// CRC-32/IEEE (reflected 0xEDB88320, init and final xor 0xFFFFFFFF) of `data`.
pub fn crc32(data: &[u8]) -> u32 {
    crc32fast::hash(data)
}

/// The fixed fields of a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Message type ([`kind`]).
    pub kind: u8,
    /// Type-specific flags (leader and trigger: the frame kind in bits 0-1).
    pub flags: u16,
    /// Sequence number, +1 per message in each direction.
    pub seq: u32,
    /// The frame the message belongs to.
    pub frame_id: u64,
}

/// Bytes a message with `payload_len` bytes of payload takes.
pub const fn message_len(payload_len: usize) -> usize {
    HEADER_LEN + payload_len + CRC_LEN
}

/// Writes one message into `out`; returns its length, or `None` if `out` is too short.
pub fn encode(out: &mut [u8], header: Header, payload: &[u8]) -> Option<usize> {
    let n = message_len(payload.len());
    let len = u32::try_from(payload.len()).ok()?;
    let out = out.get_mut(..n)?;
    out[0..4].copy_from_slice(&MAGIC);
    out[4] = VERSION;
    out[5] = header.kind;
    out[6..8].copy_from_slice(&header.flags.to_le_bytes());
    out[8..12].copy_from_slice(&header.seq.to_le_bytes());
    out[12..20].copy_from_slice(&header.frame_id.to_le_bytes());
    out[20..24].copy_from_slice(&len.to_le_bytes());
    out[HEADER_LEN..HEADER_LEN + payload.len()].copy_from_slice(payload);
    let crc = crc32(&out[..HEADER_LEN + payload.len()]);
    out[n - CRC_LEN..].copy_from_slice(&crc.to_le_bytes());
    Some(n)
}

/// What [`decode`] found at the start of a buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decoded<'a> {
    /// A valid message, `consumed` bytes long.
    Message {
        /// Its header.
        header: Header,
        /// Its payload.
        payload: &'a [u8],
        /// Bytes to drop from the buffer.
        consumed: usize,
    },
    /// The buffer holds the start of a message: `needed` bytes in all are required.
    Incomplete {
        /// Total bytes needed to decide.
        needed: usize,
    },
    /// A well-framed message whose CRC does not match: its fields cannot be trusted.
    BadCrc {
        /// Bytes to drop.
        consumed: usize,
    },
    /// Bytes that do not start a message (noise, a wrong version, an absurd length): drop
    /// `skip` bytes to resynchronise on the next magic.
    Garbage {
        /// Bytes to drop.
        skip: usize,
    },
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    let mut a = [0u8; 2];
    if let Some(s) = b.get(at..at + 2) {
        a.copy_from_slice(s);
    }
    u16::from_le_bytes(a)
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    let mut a = [0u8; 4];
    if let Some(s) = b.get(at..at + 4) {
        a.copy_from_slice(s);
    }
    u32::from_le_bytes(a)
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    if let Some(s) = b.get(at..at + 8) {
        a.copy_from_slice(s);
    }
    u64::from_le_bytes(a)
}

/// Decodes the message at the start of `buf`; payloads longer than `max_payload` are
/// treated as garbage (a corrupted length must not make the receiver wait forever).
pub fn decode(buf: &[u8], max_payload: usize) -> Decoded<'_> {
    // Resynchronise: the message must start with the magic.
    let probe = buf.len().min(MAGIC.len());
    if buf[..probe] != MAGIC[..probe] {
        let skip = (1..buf.len())
            .find(|&i| {
                let tail = &buf[i..];
                let k = tail.len().min(MAGIC.len());
                tail[..k] == MAGIC[..k]
            })
            .unwrap_or(buf.len());
        return Decoded::Garbage { skip };
    }
    if buf.len() < HEADER_LEN {
        return Decoded::Incomplete { needed: HEADER_LEN };
    }
    let len = u32_at(buf, 20) as usize;
    if buf[4] != VERSION || len > max_payload {
        return Decoded::Garbage { skip: 1 };
    }
    let total = message_len(len);
    if buf.len() < total {
        return Decoded::Incomplete { needed: total };
    }
    let crc = u32_at(buf, total - CRC_LEN);
    if crc32(&buf[..HEADER_LEN + len]) != crc {
        return Decoded::BadCrc { consumed: total };
    }
    Decoded::Message {
        header: Header {
            kind: buf[5],
            flags: u16_at(buf, 6),
            seq: u32_at(buf, 8),
            frame_id: u64_at(buf, 12),
        },
        payload: &buf[HEADER_LEN..HEADER_LEN + len],
        consumed: total,
    }
}

/// A payload of the wrong length for its type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BadPayload;

/// Leader payload: what the frame will hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Leader {
    /// PFNC pixel format.
    pub pixel_format: u32,
    /// Pixels per row.
    pub width: u32,
    /// Rows the camera means to send.
    pub expected_rows: u32,
    /// Exposure start, camera clock, ns.
    pub t_ns: u64,
    /// Stage angle tag, millidegrees.
    pub angle_mdeg: i32,
    /// Wavelength tag, picometres.
    pub wavelength_pm: u32,
    /// Band tag.
    pub band: u16,
}

impl Leader {
    /// Encoded length.
    pub const LEN: usize = 30;

    /// Encodes the payload.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut b = [0u8; Self::LEN];
        b[0..4].copy_from_slice(&self.pixel_format.to_le_bytes());
        b[4..8].copy_from_slice(&self.width.to_le_bytes());
        b[8..12].copy_from_slice(&self.expected_rows.to_le_bytes());
        b[12..20].copy_from_slice(&self.t_ns.to_le_bytes());
        b[20..24].copy_from_slice(&self.angle_mdeg.to_le_bytes());
        b[24..28].copy_from_slice(&self.wavelength_pm.to_le_bytes());
        b[28..30].copy_from_slice(&self.band.to_le_bytes());
        b
    }

    /// Decodes the payload.
    pub fn parse(p: &[u8]) -> Result<Self, BadPayload> {
        if p.len() != Self::LEN {
            return Err(BadPayload);
        }
        Ok(Self {
            pixel_format: u32_at(p, 0),
            width: u32_at(p, 4),
            expected_rows: u32_at(p, 8),
            t_ns: u64_at(p, 12),
            angle_mdeg: u32_at(p, 20) as i32,
            wavelength_pm: u32_at(p, 24),
            band: u16_at(p, 28),
        })
    }

    /// Bytes per pixel of the format (`None`: a format this codec does not carry).
    pub fn bytes_per_pixel(&self) -> Option<usize> {
        match self.pixel_format {
            MONO8 => Some(1),
            MONO12 | MONO16 => Some(2),
            _ => None,
        }
    }
}

/// Bytes of a row payload before its pixels.
pub const ROW_PREFIX: usize = 16;

/// A row payload's fixed fields; the pixels follow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RowHeader {
    /// Image row.
    pub row: u32,
    /// Exposure, microseconds.
    pub exposure_us: u32,
    /// Readout time, camera clock, ns.
    pub t_ns: u64,
}

impl RowHeader {
    /// Encodes the fixed fields.
    pub fn to_bytes(&self) -> [u8; ROW_PREFIX] {
        let mut b = [0u8; ROW_PREFIX];
        b[0..4].copy_from_slice(&self.row.to_le_bytes());
        b[4..8].copy_from_slice(&self.exposure_us.to_le_bytes());
        b[8..16].copy_from_slice(&self.t_ns.to_le_bytes());
        b
    }

    /// Splits a row payload into its fixed fields and its pixel bytes.
    pub fn parse(p: &[u8]) -> Result<(Self, &[u8]), BadPayload> {
        if p.len() < ROW_PREFIX {
            return Err(BadPayload);
        }
        Ok((
            Self {
                row: u32_at(p, 0),
                exposure_us: u32_at(p, 4),
                t_ns: u64_at(p, 8),
            },
            &p[ROW_PREFIX..],
        ))
    }
}

/// Trailer payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Trailer {
    /// Rows the camera sent.
    pub rows_sent: u32,
    /// [`STATUS_COMPLETE`] or [`STATUS_PARTIAL`].
    pub status: u16,
}

impl Trailer {
    /// Encoded length.
    pub const LEN: usize = 6;

    /// Encodes the payload.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut b = [0u8; Self::LEN];
        b[0..4].copy_from_slice(&self.rows_sent.to_le_bytes());
        b[4..6].copy_from_slice(&self.status.to_le_bytes());
        b
    }

    /// Decodes the payload.
    pub fn parse(p: &[u8]) -> Result<Self, BadPayload> {
        if p.len() != Self::LEN {
            return Err(BadPayload);
        }
        Ok(Self {
            rows_sent: u32_at(p, 0),
            status: u16_at(p, 4),
        })
    }
}

/// Trigger payload (host to camera): the tags the frame is to carry back. The frame kind
/// travels in the header's flags ([`frame_kind_flags`]), the frame id in its `frame_id`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Trigger {
    /// Stage angle tag, millidegrees.
    pub angle_mdeg: i32,
    /// Wavelength tag, picometres.
    pub wavelength_pm: u32,
    /// Band tag.
    pub band: u16,
}

impl Trigger {
    /// Encoded length.
    pub const LEN: usize = 10;

    /// Encodes the payload.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut b = [0u8; Self::LEN];
        b[0..4].copy_from_slice(&self.angle_mdeg.to_le_bytes());
        b[4..8].copy_from_slice(&self.wavelength_pm.to_le_bytes());
        b[8..10].copy_from_slice(&self.band.to_le_bytes());
        b
    }

    /// Decodes the payload.
    pub fn parse(p: &[u8]) -> Result<Self, BadPayload> {
        if p.len() != Self::LEN {
            return Err(BadPayload);
        }
        Ok(Self {
            angle_mdeg: u32_at(p, 0) as i32,
            wavelength_pm: u32_at(p, 4),
            band: u16_at(p, 8),
        })
    }
}

/// The flags carrying a frame kind (bits 0-1: 0 sample, 1 dark, 2 white).
pub fn frame_kind_flags(kind: crate::hw::FrameKind) -> u16 {
    match kind {
        crate::hw::FrameKind::Sample => 0,
        crate::hw::FrameKind::Dark => 1,
        crate::hw::FrameKind::White => 2,
    }
}

/// The frame kind in `flags`, `None` for the reserved value 3.
pub fn frame_kind(flags: u16) -> Option<crate::hw::FrameKind> {
    match flags & 3 {
        0 => Some(crate::hw::FrameKind::Sample),
        1 => Some(crate::hw::FrameKind::Dark),
        2 => Some(crate::hw::FrameKind::White),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
    }

    #[test]
    fn round_trip_and_detection() {
        let mut buf = [0u8; 128];
        let h = Header {
            kind: kind::TRAILER,
            flags: 0,
            seq: 9,
            frame_id: 77,
        };
        let t = Trailer {
            rows_sent: 24,
            status: STATUS_COMPLETE,
        };
        let n = encode(&mut buf, h, &t.to_bytes()).expect("fits");
        assert_eq!(n, message_len(Trailer::LEN));
        match decode(&buf[..n], 64) {
            Decoded::Message {
                header,
                payload,
                consumed,
            } => {
                assert_eq!((header, consumed), (h, n));
                assert_eq!(Trailer::parse(payload), Ok(t));
            }
            other => panic!("{other:?}"),
        }
        for cut in [1, 3, 10, n - 1] {
            assert!(matches!(
                decode(&buf[..cut], 64),
                Decoded::Incomplete { .. }
            ));
        }
        let mut bad = buf;
        bad[HEADER_LEN] ^= 0x40;
        assert_eq!(decode(&bad[..n], 64), Decoded::BadCrc { consumed: n });
        let mut noisy = [0u8; 140];
        noisy[..5].copy_from_slice(b"xxFSx");
        noisy[5..5 + n].copy_from_slice(&buf[..n]);
        assert_eq!(decode(&noisy, 64), Decoded::Garbage { skip: 5 });
        assert_eq!(decode(b"xxFS", 64), Decoded::Garbage { skip: 2 });
        assert!(matches!(decode(&noisy[5..], 64), Decoded::Message { .. }));
        // A length beyond the bound is garbage, not a wait for 4 GB.
        assert_eq!(decode(&buf[..n], 2), Decoded::Garbage { skip: 1 });
        assert!(encode(&mut buf[..10], h, &[]).is_none());
    }

    #[test]
    fn payloads_round_trip() {
        let l = Leader {
            pixel_format: MONO12,
            width: 32,
            expected_rows: 24,
            t_ns: 5,
            angle_mdeg: -10_000,
            wavelength_pm: 550_000,
            band: 3,
        };
        assert_eq!(Leader::parse(&l.to_bytes()), Ok(l));
        assert_eq!(Leader::parse(&[0; 3]), Err(BadPayload));
        let r = RowHeader {
            row: 5,
            exposure_us: 1000,
            t_ns: 42,
        };
        let mut p = [0u8; ROW_PREFIX + 4];
        p[..ROW_PREFIX].copy_from_slice(&r.to_bytes());
        assert_eq!(
            RowHeader::parse(&p).map(|(h, px)| (h, px.len())),
            Ok((r, 4))
        );
        let t = Trigger {
            angle_mdeg: 1,
            wavelength_pm: 2,
            band: 3,
        };
        assert_eq!(Trigger::parse(&t.to_bytes()), Ok(t));
        for k in [
            crate::hw::FrameKind::Sample,
            crate::hw::FrameKind::Dark,
            crate::hw::FrameKind::White,
        ] {
            assert_eq!(frame_kind(frame_kind_flags(k)), Some(k));
        }
    }
}
