//! The wall clock, for the real rig.

use std::time::{Duration, Instant};

use filmscope_core::hw::Clock;

/// Monotonic wall time; delays sleep.
#[derive(Clone, Copy, Debug)]
pub struct SystemClock(Instant);

impl Default for SystemClock {
    fn default() -> Self {
        Self(Instant::now())
    }
}

impl Clock for SystemClock {
    fn now_us(&self) -> u64 {
        self.0.elapsed().as_micros() as u64
    }

    fn delay_us(&mut self, us: u64) {
        std::thread::sleep(Duration::from_micros(us));
    }
}
