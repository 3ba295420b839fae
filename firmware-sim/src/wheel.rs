//! A Starlight Xpress filter wheel's HID firmware: 2-byte reports, turning takes (virtual)
//! time during which the position reads 0, and it can disappear (unplugged).

use filmscope_core::proto::sxwheel;

/// The wheel firmware, report by report.
#[derive(Debug)]
pub struct SxWheelFirmware {
    count: u8,
    slot: u8,
    busy_until_us: u64,
    us_per_slot: u64,
    reply: Option<[u8; 2]>,
    /// Reports received (without report id), for transcripts.
    pub transcript: Vec<[u8; 2]>,
    /// Unplugged: every report fails.
    pub gone: bool,
}

impl SxWheelFirmware {
    /// A wheel of `count` filters at slot 0, `us_per_slot` to turn one slot.
    pub fn new(count: u8, us_per_slot: u64) -> Self {
        Self {
            count,
            slot: 0,
            busy_until_us: 0,
            us_per_slot,
            reply: None,
            transcript: Vec::new(),
            gone: false,
        }
    }

    /// The slot the wheel is at or turning to.
    pub fn slot(&self) -> u8 {
        self.slot
    }

    /// A report from the host (report id first); `false` if it was not accepted.
    pub fn write_report(&mut self, report: &[u8], now_us: u64) -> bool {
        if self.gone {
            return false;
        }
        let body = match report {
            [0, a, b, ..] => [*a, *b],
            _ => return false,
        };
        self.transcript.push(body);
        match sxwheel::decode_command(body) {
            Some(Some(slot)) if slot < self.count => {
                let dist = u64::from(slot.abs_diff(self.slot));
                self.slot = slot;
                self.busy_until_us = now_us + dist * self.us_per_slot + 1;
                self.reply = None;
                true
            }
            Some(None) => {
                let moving = now_us < self.busy_until_us;
                self.reply = Some([if moving { 0 } else { self.slot + 1 }, self.count]);
                true
            }
            // A slot beyond the count: the real wheel misbehaves; this one ignores it.
            _ => true,
        }
    }

    /// The pending status report, if any.
    pub fn read_report(&mut self) -> Option<[u8; 2]> {
        if self.gone {
            return None;
        }
        self.reply.take()
    }
}
