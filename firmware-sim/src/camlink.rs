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
        let frame = self.frame(n, header.frame_id, frame_kind, now_us);
        self.push_leader(&mut out, &frame, &trigger, header.flags);
        if frame.reached(self.faults.leaders_without_rows) {
            return (out, After::Repeat(REPEAT_EVERY));
        }
        let rows_sent = self.rows_sent(&frame);
        if !self.push_rows(&mut out, &frame, rows_sent) {
            return (out, After::Continue);
        }
        let trailer = Trailer {
            rows_sent,
            status: if rows_sent < frame.height as u32 {
                fscl::STATUS_PARTIAL
            } else {
                fscl::STATUS_COMPLETE
            },
        };
        self.push(&mut out, kind::TRAILER, 0, frame.id, &trailer.to_bytes());
        match self.faults.trickle {
            Some((f, ms)) if n >= f => (out, After::Trickle(std::time::Duration::from_millis(ms))),
            _ if frame.reached(self.faults.wrong_frame_id) => (out, After::Repeat(REPEAT_EVERY)),
            _ => (out, After::Continue),
        }
    }

    /// Frame `n` as the stage and filter are now: the angle and band to render, and the
    /// frame id to tag it with (another one's, under the wrong-frame-id fault).
    fn frame(&self, n: u64, frame_id: u64, kind: FrameKind, now_us: u64) -> Frame {
        let scene = self.camera.scene();
        let state = self.world.get();
        let mut frame = Frame {
            n,
            id: frame_id,
            kind,
            angle: Self::nearest(&scene.angles_deg, state.stage_deg),
            band: Self::nearest(&scene.bands_nm, state.lambda_nm),
            width: self.camera.width(),
            height: self.camera.height(),
            t_ns: now_us * 1000,
        };
        if frame.reached(self.faults.wrong_frame_id) {
            frame.id = frame_id.wrapping_add(1000);
        }
        frame
    }

    /// Appends the frame's leader, echoing the trigger's angle, wavelength and band.
    fn push_leader(&mut self, out: &mut Vec<u8>, frame: &Frame, trigger: &Trigger, flags: u16) {
        let leader = Leader {
            pixel_format: fscl::MONO16,
            width: frame.width as u32,
            expected_rows: frame.height as u32,
            t_ns: frame.t_ns,
            angle_mdeg: trigger.angle_mdeg,
            wavelength_pm: trigger.wavelength_pm,
            band: trigger.band,
        };
        self.push(out, kind::LEADER, flags & 3, frame.id, &leader.to_bytes());
    }

    /// How many rows the frame sends: all of them, unless a partial-frame fault cuts it
    /// short.
    fn rows_sent(&self, frame: &Frame) -> u32 {
        let h = frame.height as u32;
        self.faults
            .partial
            .iter()
            .find(|(f, _)| *f == frame.n)
            .map_or(h, |&(_, k)| k.min(h))
    }

    /// Appends the frame's first `rows_sent` rows, in the order and with the losses,
    /// corruptions and duplicates the faults ask for; false if the frame stalls before
    /// its trailer.
    fn push_rows(&mut self, out: &mut Vec<u8>, frame: &Frame, rows_sent: u32) -> bool {
        let n = frame.n;
        let stall_at = self.faults.stall.filter(|(f, _)| *f == n).map(|(_, k)| k);
        let mut order: Vec<u32> = (0..rows_sent).collect();
        for r in 0..rows_sent.saturating_sub(1) {
            if self.faults.swap_rows.contains(&(n, r)) {
                order.swap(r as usize, r as usize + 1);
            }
        }
        let mut raw = vec![0u16; frame.width];
        let mut refs = vec![0f32; frame.width];
        for (k, &r) in order.iter().enumerate() {
            if stall_at == Some(k as u32) {
                return false;
            }
            self.render_row(frame, r as usize, &mut raw, &mut refs);
            let mut payload = RowHeader {
                row: r,
                exposure_us: self.exposure_us,
                t_ns: frame.t_ns + u64::from(r) * 10_000,
            }
            .to_bytes()
            .to_vec();
            for v in &raw {
                payload.extend_from_slice(&v.to_le_bytes());
            }
            self.push_row(out, frame, r, &payload);
        }
        true
    }

    /// Renders row `row` of the frame into `raw`: the sample's raw counts, or the dark or
    /// white reference rounded to counts (`refs` is scratch for the reference).
    fn render_row(&self, frame: &Frame, row: usize, raw: &mut [u16], refs: &mut [f32]) {
        let (angle, band) = (frame.angle, frame.band);
        match frame.kind {
            FrameKind::Sample => self.camera.raw_row(angle, band, row, raw),
            FrameKind::Dark | FrameKind::White => {
                if frame.kind == FrameKind::Dark {
                    self.camera.dark_row(angle, band, row, refs);
                } else {
                    self.camera.white_row(angle, band, row, refs);
                }
                for (o, v) in raw.iter_mut().zip(refs.iter()) {
                    *o = v.round().clamp(0.0, 65535.0) as u16;
                }
            }
        }
    }

    /// Appends row `r`'s message, or loses it on the way, flips a bit of it or sends it
    /// twice, as the faults say.
    fn push_row(&mut self, out: &mut Vec<u8>, frame: &Frame, r: u32, payload: &[u8]) {
        let has = |list: &[FrameRow]| list.contains(&(frame.n, r));
        if has(&self.faults.drop_rows) {
            self.seq = self.seq.wrapping_add(1); // sent, and lost on the way
            return;
        }
        let at = out.len();
        self.push(out, kind::ROW, 0, frame.id, payload);
        if has(&self.faults.corrupt_rows) {
            let i = at + fscl::HEADER_LEN + fscl::ROW_PREFIX + 1;
            if let Some(b) = out.get_mut(i) {
                *b ^= 0x10;
            }
        }
        if has(&self.faults.duplicate_rows) {
            let copy = out[at..].to_vec();
            out.extend_from_slice(&copy);
        }
    }
}

/// One triggered frame: what its leader, rows and trailer are made from.
struct Frame {
    /// The frame's count, from 1 in trigger order (what the faults are keyed by).
    n: u64,
    /// The frame id its messages are tagged with.
    id: u64,
    /// Sample, dark or white.
    kind: FrameKind,
    /// The scene angle and band rendered.
    angle: usize,
    band: usize,
    /// The camera's size in pixels.
    width: usize,
    height: usize,
    /// When the frame was triggered.
    t_ns: u64,
}

impl Frame {
    /// Whether a fault that starts at frame `from` applies to this frame.
    fn reached(&self, from: Option<u64>) -> bool {
        from.is_some_and(|f| self.n >= f)
    }
}
