//! A Zaber rotary stage's ASCII firmware: checksummed replies, `BUSY`/`IDLE`, the `WR`
//! warning until homed, motion that takes (virtual) time, travel limits, and injectable
//! motion faults (`NI` interrupted, `FS` stalled).

use filmscope_core::proto::zaber;

use crate::serial::LineFirmware;
use crate::world::World;

/// A motion fault to inject on the n-th `move` (1-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionFault {
    /// The motion stops halfway, warning `NI`.
    Interrupted(usize),
    /// The motor stalls halfway, fault `FS`.
    Stalled(usize),
}

/// The stage firmware.
#[derive(Debug)]
pub struct ZaberStage {
    device: u8,
    steps_per_deg: f64,
    limits: [i64; 2],
    speed_steps_per_s: f64,
    homed: bool,
    from: i64,
    to: i64,
    start_us: u64,
    end_us: u64,
    warning: &'static str,
    moves: usize,
    fault: Option<MotionFault>,
    reply_as: Option<u8>,
    world: World,
}

impl ZaberStage {
    /// A stage at address `device`, `steps_per_deg` microsteps per degree, travel `limits`
    /// (microsteps), moving at `speed_deg_s`; it updates `world` as it moves.
    pub fn new(
        device: u8,
        steps_per_deg: f64,
        limits: [i64; 2],
        speed_deg_s: f64,
        world: World,
    ) -> Self {
        Self {
            device,
            steps_per_deg,
            limits,
            speed_steps_per_s: speed_deg_s * steps_per_deg,
            homed: false,
            from: 0,
            to: 0,
            start_us: 0,
            end_us: 0,
            warning: "WR",
            moves: 0,
            fault: None,
            reply_as: None,
            world,
        }
    }

    /// Answers every command as if it were the device at `address` (a misconfigured or
    /// impersonating unit: the host must not take the reply for its own).
    pub fn with_reply_address(mut self, address: u8) -> Self {
        self.reply_as = Some(address);
        self
    }

    /// Injects a motion fault.
    pub fn with_fault(mut self, fault: MotionFault) -> Self {
        self.fault = Some(fault);
        self
    }

    /// Position at `now_us`, microsteps.
    pub fn position(&self, now_us: u64) -> i64 {
        if now_us >= self.end_us || self.end_us == self.start_us {
            return self.to;
        }
        let f = (now_us - self.start_us) as f64 / (self.end_us - self.start_us) as f64;
        self.from + ((self.to - self.from) as f64 * f) as i64
    }

    fn start_motion(&mut self, target: i64, now_us: u64) {
        self.moves += 1;
        self.from = self.position(now_us);
        let mut to = target;
        let fault = match self.fault {
            Some(MotionFault::Interrupted(n)) if n == self.moves => Some("NI"),
            Some(MotionFault::Stalled(n)) if n == self.moves => Some("FS"),
            _ => None,
        };
        if fault.is_some() {
            to = self.from + (target - self.from) / 2;
        }
        self.to = to;
        self.start_us = now_us;
        let dist = (to - self.from).unsigned_abs() as f64;
        self.end_us = now_us + (dist / self.speed_steps_per_s * 1e6) as u64 + 1000;
        // The warning shows once the motion has ended (see `status`).
        self.warning = fault.unwrap_or(if self.homed { "--" } else { "WR" });
        let deg = to as f64 / self.steps_per_deg;
        self.world.update(|w| w.stage_deg = deg);
    }

    fn busy(&self, now_us: u64) -> bool {
        now_us < self.end_us
    }

    fn shown_warning(&self, now_us: u64) -> &'static str {
        match self.warning {
            "NI" | "FS" if self.busy(now_us) => "--",
            w => w,
        }
    }
}

impl LineFirmware for ZaberStage {
    fn terminators(&self) -> &'static [u8] {
        b"\r\n"
    }

    fn respond(&mut self, line: &str, now_us: u64, reject: bool) -> String {
        let Ok(cmd) = zaber::parse_command(line) else {
            // A line that is not a command, or fails its checksum, is ignored.
            return String::new();
        };
        if cmd.device != 0 && cmd.device != self.device {
            return String::new();
        }
        if self.homed && !self.busy(now_us) && self.warning == "WR" {
            self.warning = "--";
        }
        let mut words = cmd.text.split_whitespace();
        let verb = words.next().unwrap_or("");
        let args: Vec<&str> = words.collect();
        let mut ok = true;
        let mut data = String::from("0");
        match (verb, args.as_slice()) {
            _ if reject => {
                ok = false;
                data = "BADCOMMAND".into();
            }
            ("", []) => {}
            ("home", []) => {
                self.homed = true;
                self.start_motion(0, now_us);
                self.warning = "--";
            }
            ("move", ["abs", n]) => match n.parse::<i64>() {
                Ok(_) if !self.homed => {
                    ok = false;
                    data = "NOREFERENCE".into();
                }
                Ok(n) if (self.limits[0]..=self.limits[1]).contains(&n) => {
                    self.start_motion(n, now_us)
                }
                _ => {
                    ok = false;
                    data = "BADDATA".into();
                }
            },
            ("stop", []) => {
                let here = self.position(now_us);
                self.from = here;
                self.to = here;
                self.end_us = now_us;
            }
            ("get", ["pos"]) => data = self.position(now_us).to_string(),
            ("get", ["limit.min"]) => data = self.limits[0].to_string(),
            ("get", ["limit.max"]) => data = self.limits[1].to_string(),
            _ => {
                ok = false;
                data = "BADCOMMAND".into();
            }
        }
        let busy = self.busy(now_us);
        zaber::reply_line(
            self.reply_as.unwrap_or(self.device),
            cmd.axis,
            cmd.id,
            ok,
            busy,
            self.shown_warning(now_us),
            &data,
        )
        .map(|s| s.as_str().to_owned())
        .unwrap_or_default()
    }
}
