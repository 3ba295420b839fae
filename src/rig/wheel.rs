//! Starlight Xpress filter wheel over USB HID, behind a two-method transport trait: the
//! [`HidapiTransport`] is the only code that touches hidapi; tests use the firmware
//! simulator's wheel ([`SimWheelTransport`]).

use std::sync::{Arc, Mutex};

use filmscope_core::hw::{Clock, ErrorKind, ErrorType, FilterWheel};
use filmscope_core::proto::sxwheel;
use firmware_sim::wheel::SxWheelFirmware;

use super::error::RigError;

/// A HID device: write a report (report id first), read one with a timeout.
pub trait HidTransport {
    /// Writes `report` (report id first).
    fn write_report(&mut self, report: &[u8]) -> Result<(), RigError>;
    /// Reads one report into `buf` within `timeout_ms`; `Ok(0)` when none came.
    fn read_report(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, RigError>;
}

/// The real wheel through hidapi (Linux: hidraw, found through sysfs without libudev).
pub struct HidapiTransport {
    device: hidapi::HidDevice,
    name: String,
}

impl HidapiTransport {
    /// Opens the first wheel (VID 0x1278, PID 0x0920).
    pub fn open() -> Result<Self, RigError> {
        let name = format!("hid {:04x}:{:04x}", sxwheel::VENDOR_ID, sxwheel::PRODUCT_ID);
        let api = hidapi::HidApi::new()
            .map_err(|e| RigError::new(&name, ErrorKind::Other, e.to_string()))?;
        let device = api
            .open(sxwheel::VENDOR_ID, sxwheel::PRODUCT_ID)
            .map_err(|e| {
                RigError::new(&name, ErrorKind::Disconnected, format!("not found ({e})"))
            })?;
        Ok(Self { device, name })
    }
}

impl HidTransport for HidapiTransport {
    fn write_report(&mut self, report: &[u8]) -> Result<(), RigError> {
        self.device
            .write(report)
            .map(|_| ())
            .map_err(|e| RigError::new(&self.name, ErrorKind::Disconnected, e.to_string()))
    }

    fn read_report(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, RigError> {
        self.device
            .read_timeout(buf, timeout_ms)
            .map_err(|e| RigError::new(&self.name, ErrorKind::Disconnected, e.to_string()))
    }
}

/// The simulated wheel of `firmware-sim`, reached in process (HID cannot go over a pty).
pub struct SimWheelTransport<C> {
    wheel: Arc<Mutex<SxWheelFirmware>>,
    clock: C,
}

impl<C: Clock> SimWheelTransport<C> {
    /// A transport to `wheel`, on `clock`.
    pub fn new(wheel: Arc<Mutex<SxWheelFirmware>>, clock: C) -> Self {
        Self { wheel, clock }
    }
}

impl<C: Clock> HidTransport for SimWheelTransport<C> {
    fn write_report(&mut self, report: &[u8]) -> Result<(), RigError> {
        let now = self.clock.now_us();
        let mut w = self.wheel.lock().unwrap_or_else(|p| p.into_inner());
        if w.write_report(report, now) {
            Ok(())
        } else {
            Err(RigError::new(
                "sim wheel",
                ErrorKind::Disconnected,
                "device disconnected",
            ))
        }
    }

    fn read_report(&mut self, buf: &mut [u8], _timeout_ms: i32) -> Result<usize, RigError> {
        let mut w = self.wheel.lock().unwrap_or_else(|p| p.into_inner());
        if w.gone {
            return Err(RigError::new(
                "sim wheel",
                ErrorKind::Disconnected,
                "device disconnected",
            ));
        }
        match w.read_report() {
            Some(r) if buf.len() >= 2 => {
                buf[..2].copy_from_slice(&r);
                Ok(2)
            }
            _ => Ok(0),
        }
    }
}

/// The wheel driver.
pub struct SxWheel<T, C> {
    transport: T,
    clock: C,
    name: String,
    count: Option<u8>,
    /// Longest turn, microseconds.
    pub timeout_us: u64,
}

impl<T: HidTransport, C: Clock> SxWheel<T, C> {
    /// A driver over `transport`.
    pub fn new(transport: T, name: &str, clock: C) -> Self {
        Self {
            transport,
            clock,
            name: name.to_owned(),
            count: None,
            timeout_us: 10_000_000,
        }
    }

    fn status(&mut self) -> Result<sxwheel::Status, RigError> {
        self.transport.write_report(&sxwheel::QUERY)?;
        let mut buf = [0u8; 8];
        let n = self.transport.read_report(&mut buf, 500)?;
        if n < 2 {
            return Err(RigError::new(
                &self.name,
                ErrorKind::Timeout,
                "no status report",
            ));
        }
        Ok(sxwheel::status([buf[0], buf[1]]))
    }
}

impl<T: HidTransport, C: Clock> ErrorType for SxWheel<T, C> {
    type Error = RigError;
}

impl<T: HidTransport, C: Clock> FilterWheel for SxWheel<T, C> {
    fn slots(&mut self) -> Result<u8, RigError> {
        if let Some(n) = self.count {
            return Ok(n);
        }
        let t0 = self.clock.now_us();
        loop {
            let s = self.status()?;
            if s.slot.is_some() && s.count > 0 {
                self.count = Some(s.count);
                return Ok(s.count);
            }
            if self.clock.now_us().saturating_sub(t0) > self.timeout_us {
                return Err(RigError::new(
                    &self.name,
                    ErrorKind::Timeout,
                    "wheel never settled",
                ));
            }
            self.clock.delay_us(50_000);
        }
    }

    fn select(&mut self, slot: u8) -> Result<(), RigError> {
        let count = self.slots()?;
        let report = sxwheel::select(slot)
            .filter(|_| slot < count)
            .ok_or_else(|| {
                RigError::new(
                    &self.name,
                    ErrorKind::OutOfRange,
                    format!("slot {slot} does not exist (the wheel has {count})"),
                )
            })?;
        self.transport.write_report(&report)?;
        let t0 = self.clock.now_us();
        loop {
            self.clock.delay_us(50_000);
            if self.status()?.slot == Some(slot) {
                return Ok(());
            }
            if self.clock.now_us().saturating_sub(t0) > self.timeout_us {
                return Err(RigError::new(
                    &self.name,
                    ErrorKind::Timeout,
                    format!("wheel did not reach slot {slot}"),
                ));
            }
        }
    }

    fn current(&mut self) -> Result<Option<u8>, RigError> {
        Ok(self.status()?.slot)
    }
}
