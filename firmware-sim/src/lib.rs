//! The software rig filmscope is tested on: simulated thin-film scenes and the camera that
//! looks at them through an LCTF (with, later, the filter and stage protocol fakes).
//!
//! - [`scene`]: scene files (`config/scenes/*.toml`): the film, its thickness map, the rig's
//!   angles and bands, and the sensor.
//! - [`camera`]: renders band frames row by row, as raw counts with noise or as true band
//!   reflectance, in any row order with the same result.
//! - [`rng`]: the deterministic generator behind thickness maps and noise.

pub mod camera;
pub mod rng;
pub mod scene;

pub use camera::{Defect, SoftwareCamera};
pub use scene::{Scene, SceneError, Sensor};
