//! The camera's side of the camera link: answers each trigger with a frame of `FSCL`
//! messages (leader, rows, trailer) rendered by the [`SoftwareCamera`] at the angle and
//! wavelength the simulated stage and filter are at, with injectable transport faults.

use filmscope_core::hw::FrameKind;
use filmscope_core::proto::fscl::{self, kind, Header, Leader, RowHeader, Trailer, Trigger};

use crate::camera::SoftwareCamera;
use crate::world::World;

/// A frame, counted from 1 in trigger order, and a row of it.
pub type FrameRow = (u64, u32);

/// Transport faults to inject.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CameraFaults {
    /// Rows never sent (a sequence gap).
    pub drop_rows: Vec<FrameRow>,
    /// Rows sent with a flipped payload bit (a CRC error).
    pub corrupt_rows: Vec<FrameRow>,
    /// Rows sent twice.
    pub duplicate_rows: Vec<FrameRow>,
    /// Rows sent after the row that follows them.
    pub swap_rows: Vec<FrameRow>,
    /// Frames cut short: only this many rows, then a trailer saying so.
    pub partial: Vec<FrameRow>,
    /// A frame that stops after this many rows, with no trailer (a stall).
    pub stall: Option<FrameRow>,
    /// Line noise before these frames' leaders.
    pub garbage_before: Vec<u64>,
    /// The camera disappears when this frame is triggered.
    pub vanish_at: Option<u64>,
    /// From this frame on, every byte comes alone, this many wall milliseconds after the
    /// one before (under the host's read timeout, so no single read times out).
    pub trickle: Option<(u64, u64)>,
    /// From this frame on, frames are tagged for another frame id and sent again and again
    /// until the host says something.
    pub wrong_frame_id: Option<u64>,
    /// From this frame on, the camera answers with its leader alone, again and again, and
    /// never sends a row.
    pub leaders_without_rows: Option<u64>,
}

/// What to do after sending a frame's bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum After {
    /// Carry on.
    Continue,
    /// Close the connection and stop serving.
    Vanish,
    /// Send the bytes one at a time, this long apart.
    Trickle(std::time::Duration),
    /// Send the bytes again every this long until the host sends something.
    Repeat(std::time::Duration),
}

/// How often a repeating camera sends its bytes again.
const REPEAT_EVERY: std::time::Duration = std::time::Duration::from_millis(20);

/// The camera firmware.
pub struct CameraFirmware {
    camera: SoftwareCamera,
    world: World,
    faults: CameraFaults,
    seq: u32,
    frames: u64,
    exposure_us: u32,
}

impl CameraFirmware {
    /// A camera rendering `camera`'s scene at `world`'s angle and wavelength.
    pub fn new(camera: SoftwareCamera, world: World, faults: CameraFaults) -> Self {
        Self {
            camera,
            world,
            faults,
            seq: 0,
            frames: 0,
            exposure_us: 2000,
        }
    }

    /// Frames triggered so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    fn nearest(values: &[f64], x: f64) -> usize {
        let mut best = 0;
        for (i, v) in values.iter().enumerate() {
            if (v - x).abs() < (values[best] - x).abs() {
                best = i;
            }
        }
        best
    }

    fn push(&mut self, out: &mut Vec<u8>, kind: u8, flags: u16, frame_id: u64, payload: &[u8]) {
        let header = Header {
            kind,
            flags,
            seq: self.seq,
            frame_id,
        };
        self.seq = self.seq.wrapping_add(1);
        let at = out.len();
        out.resize(at + fscl::message_len(payload.len()), 0);
        let _ = fscl::encode(&mut out[at..], header, payload);
    }

    /// The bytes answering one host message (`header` + `payload`, already CRC-checked);
    /// anything but a trigger gets an error message.
    pub fn answer(&mut self, header: Header, payload: &[u8], now_us: u64) -> (Vec<u8>, After) {
        let mut out = Vec::new();
        let (Ok(trigger), kind::TRIGGER, Some(frame_kind)) = (
            Trigger::parse(payload),
            header.kind,
            fscl::frame_kind(header.flags),
        ) else {
            self.push(&mut out, kind::ERROR, 0, header.frame_id, b"bad request");
            return (out, After::Continue);
        };
        self.frames += 1;
        let n = self.frames;
        if self.faults.vanish_at == Some(n) {
            return (out, After::Vanish);
        }
        if self.faults.garbage_before.contains(&n) {
            out.extend_from_slice(b"FS\x00garbage\xff");
        }
        let scene = self.camera.scene();
        let state = self.world.get();
        let angle = Self::nearest(&scene.angles_deg, state.stage_deg);
        let band = Self::nearest(&scene.bands_nm, state.lambda_nm);
        let (w, h) = (self.camera.width(), self.camera.height());
        let from = |f: Option<u64>| f.is_some_and(|f| n >= f);
        let frame_id = if from(self.faults.wrong_frame_id) {
            header.frame_id.wrapping_add(1000)
        } else {
            header.frame_id
        };
        let t_ns = now_us * 1000;
        let leader = Leader {
            pixel_format: fscl::MONO16,
            width: w as u32,
            expected_rows: h as u32,
            t_ns,
            angle_mdeg: trigger.angle_mdeg,
            wavelength_pm: trigger.wavelength_pm,
            band: trigger.band,
        };
        self.push(
            &mut out,
            kind::LEADER,
            header.flags & 3,
            frame_id,
            &leader.to_bytes(),
        );
        if from(self.faults.leaders_without_rows) {
            return (out, After::Repeat(REPEAT_EVERY));
        }
        let has = |list: &[FrameRow], r: u32| list.contains(&(n, r));
        let rows_sent = self
            .faults
            .partial
            .iter()
            .find(|(f, _)| *f == n)
            .map_or(h as u32, |&(_, k)| k.min(h as u32));
        let stall_at = self.faults.stall.filter(|(f, _)| *f == n).map(|(_, k)| k);
        let mut order: Vec<u32> = (0..rows_sent).collect();
        for r in 0..rows_sent.saturating_sub(1) {
            if has(&self.faults.swap_rows, r) {
                order.swap(r as usize, r as usize + 1);
            }
        }
        let mut raw = vec![0u16; w];
        let mut refs = vec![0f32; w];
        for (k, &r) in order.iter().enumerate() {
            if stall_at == Some(k as u32) {
                return (out, After::Continue);
            }
            let row = r as usize;
            match frame_kind {
                FrameKind::Sample => self.camera.raw_row(angle, band, row, &mut raw),
                FrameKind::Dark | FrameKind::White => {
                    if frame_kind == FrameKind::Dark {
                        self.camera.dark_row(angle, band, row, &mut refs);
                    } else {
                        self.camera.white_row(angle, band, row, &mut refs);
                    }
                    for (o, v) in raw.iter_mut().zip(&refs) {
                        *o = v.round().clamp(0.0, 65535.0) as u16;
                    }
                }
            }
            let mut payload = RowHeader {
                row: r,
                exposure_us: self.exposure_us,
                t_ns: t_ns + u64::from(r) * 10_000,
            }
            .to_bytes()
            .to_vec();
            for v in &raw {
                payload.extend_from_slice(&v.to_le_bytes());
            }
            if has(&self.faults.drop_rows, r) {
                self.seq = self.seq.wrapping_add(1); // sent, and lost on the way
                continue;
            }
            let at = out.len();
            self.push(&mut out, kind::ROW, 0, frame_id, &payload);
            if has(&self.faults.corrupt_rows, r) {
                let i = at + fscl::HEADER_LEN + fscl::ROW_PREFIX + 1;
                if let Some(b) = out.get_mut(i) {
                    *b ^= 0x10;
                }
            }
            if has(&self.faults.duplicate_rows, r) {
                let copy = out[at..].to_vec();
                out.extend_from_slice(&copy);
            }
        }
        let trailer = Trailer {
            rows_sent,
            status: if rows_sent < h as u32 {
                fscl::STATUS_PARTIAL
            } else {
                fscl::STATUS_COMPLETE
            },
        };
        self.push(&mut out, kind::TRAILER, 0, frame_id, &trailer.to_bytes());
        match self.faults.trickle {
            Some((f, ms)) if n >= f => (out, After::Trickle(std::time::Duration::from_millis(ms))),
            _ if from(self.faults.wrong_frame_id) => (out, After::Repeat(REPEAT_EVERY)),
            _ => (out, After::Continue),
        }
    }
}
