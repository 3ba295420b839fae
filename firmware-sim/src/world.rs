//! What the simulated devices share: where the stage points and what the filter passes, so
//! the camera renders what the host actually set up.

use std::sync::{Arc, Mutex};

/// The physical state of the simulated rig.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WorldState {
    /// Stage angle, degrees.
    pub stage_deg: f64,
    /// Filter centre wavelength, nm.
    pub lambda_nm: f64,
    /// Whether the filter blocks (black mode).
    pub blocked: bool,
}

/// The shared world.
#[derive(Clone, Debug, Default)]
pub struct World(Arc<Mutex<WorldState>>);

impl World {
    /// A world at rest.
    pub fn new() -> Self {
        Self::default()
    }

    /// A copy of the state.
    pub fn get(&self) -> WorldState {
        *self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Changes the state.
    pub fn update(&self, f: impl FnOnce(&mut WorldState)) {
        f(&mut self.0.lock().unwrap_or_else(|p| p.into_inner()));
    }
}
