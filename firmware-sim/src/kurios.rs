//! A Thorlabs Kurios LCTF's firmware: the `>` prompt after power-up and every command,
//! `*IDN?`, `SP?`, `OH?`, `ST?` (warming up, then ready), `OM=`, `BW=`, `WL=`/`WL?`, and
//! `CMD_NOT_DEFINED` for anything else.

use filmscope_core::proto::kurios;

use crate::serial::LineFirmware;
use crate::world::World;

/// The filter firmware.
#[derive(Debug)]
pub struct KuriosFilter {
    range_nm: [f64; 2],
    /// Bandwidth-mode bitmask the head offers.
    modes: u8,
    warm_until_us: u64,
    lambda_nm: f64,
    bandwidth: u32,
    mode: u32,
    world: World,
}

impl KuriosFilter {
    /// A visible head (420-730 nm, black/wide/medium/narrow) ready after `warm_up_us`.
    pub fn new(warm_up_us: u64, world: World) -> Self {
        Self {
            range_nm: [420.0, 730.0],
            modes: 0x0F,
            warm_until_us: warm_up_us,
            lambda_nm: 550.0,
            bandwidth: 2,
            mode: 1,
            world,
        }
    }

    /// The wavelength the filter is tuned to, nm.
    pub fn lambda_nm(&self) -> f64 {
        self.lambda_nm
    }

    /// The bandwidth mode (1: black).
    pub fn bandwidth(&self) -> u32 {
        self.bandwidth
    }
}

impl LineFirmware for KuriosFilter {
    fn terminators(&self) -> &'static [u8] {
        b"\r"
    }

    fn banner(&self) -> String {
        ">".into()
    }

    fn respond(&mut self, line: &str, now_us: u64, reject: bool) -> String {
        let line = line.trim();
        let body = if reject {
            "CMD_NOT_DEFINED".to_owned()
        } else if let Some(v) = kurios::value(line, "WL") {
            match v.parse::<f64>() {
                Ok(nm) if nm >= self.range_nm[0] && nm <= self.range_nm[1] => {
                    self.lambda_nm = nm;
                    self.world.update(|w| w.lambda_nm = nm);
                    String::new()
                }
                _ => "Command error CMD_ARG_INVALID".into(),
            }
        } else if let Some(v) = kurios::value(line, "BW") {
            match v.parse::<u32>() {
                Ok(n) if n < 256 && n.count_ones() == 1 && u32::from(self.modes) & n != 0 => {
                    self.bandwidth = n;
                    self.world.update(|w| w.blocked = n == 1);
                    String::new()
                }
                _ => "Command error CMD_ARG_INVALID".into(),
            }
        } else if let Some(v) = kurios::value(line, "OM") {
            match v.parse::<u32>() {
                Ok(n @ 1..=3) => {
                    self.mode = n;
                    String::new()
                }
                _ => "Command error CMD_ARG_INVALID".into(),
            }
        } else {
            match line.to_ascii_uppercase().as_str() {
                "*IDN?" => "THORLABS KURIOS-VB1 SN-SIM0001 HW1.0 FW3.1 (firmware-sim)".into(),
                "SP?" => format!(
                    "WLmax={:.3}\rWLmin={:.3}",
                    self.range_nm[1], self.range_nm[0]
                ),
                "OH?" => format!("OH={}", (1u32 << 8) | u32::from(self.modes)),
                "ST?" => format!("ST={}", if now_us < self.warm_until_us { 1 } else { 2 }),
                "WL?" => format!("WL={:.3}", self.lambda_nm),
                "BW?" => format!("BW={}", self.bandwidth),
                "OM?" => format!("OM={}", self.mode),
                "TP?" => "TP=25.0".into(),
                _ => "CMD_NOT_DEFINED".into(),
            }
        };
        if body.is_empty() {
            ">".into()
        } else {
            format!("{body}\r>")
        }
    }
}
