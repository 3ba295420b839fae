//! Clocks for the simulated devices: a virtual clock that only moves when told (tests: a
//! two-second stage move costs nothing), and a wall clock that may run faster than real
//! time (the `firmware-sim` binary).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use filmscope_core::hw::Clock;

/// A clock shared by the simulated devices and the host under test; `delay_us` advances it.
#[derive(Clone, Debug, Default)]
pub struct VirtualClock(Arc<AtomicU64>);

impl VirtualClock {
    /// A clock at 0.
    pub fn new() -> Self {
        Self::default()
    }

    /// Moves the clock forward by `us`.
    pub fn advance(&self, us: u64) {
        self.0.fetch_add(us, Ordering::SeqCst);
    }
}

impl Clock for VirtualClock {
    fn now_us(&self) -> u64 {
        self.0.load(Ordering::SeqCst)
    }

    fn delay_us(&mut self, us: u64) {
        self.advance(us);
    }
}

/// Wall time since creation, multiplied by `speed` (1.0: real time).
#[derive(Clone, Copy, Debug)]
pub struct ScaledClock {
    start: Instant,
    speed: f64,
}

impl ScaledClock {
    /// A clock starting now, running `speed` times faster than real time.
    pub fn new(speed: f64) -> Self {
        Self {
            start: Instant::now(),
            speed: if speed > 0.0 { speed } else { 1.0 },
        }
    }

    /// Simulated microseconds since creation.
    pub fn now_us(&self) -> u64 {
        (self.start.elapsed().as_secs_f64() * 1e6 * self.speed) as u64
    }
}

impl Clock for ScaledClock {
    fn now_us(&self) -> u64 {
        ScaledClock::now_us(self)
    }

    fn delay_us(&mut self, us: u64) {
        std::thread::sleep(std::time::Duration::from_secs_f64(
            us as f64 * 1e-6 / self.speed,
        ));
    }
}
