//! The software rig filmscope is tested on: simulated thin-film scenes, the camera that
//! looks at them through an LCTF, and the firmware of every rig device as a byte-level
//! state machine with transcripts and fault injection.
//!
//! - [`scene`]: scene files (`config/scenes/*.toml`): the film, its thickness map, the rig's
//!   angles and bands, and the sensor.
//! - [`camera`]: renders band frames row by row, as raw counts with noise or as true band
//!   reflectance, in any row order with the same result.
//! - [`random`]: random coating scenes drawn from the material library, for
//!   `filmscope eval --random`.
//! - [`rng`]: the deterministic generator behind thickness maps and noise.
//! - [`table`]: band reflectance tabulated over thickness, for rendering at camera rates.
//! - [`imperfect`]: what real samples and rigs add to the ideal film (absorption, a bare
//!   back face, stage and wavelength errors, flare, polariser leak, side lobes).
//! - [`clock`]: the virtual clock (motion and settle times cost no wall time in tests).
//! - [`world`]: where the simulated stage points and what the filter passes.
//! - [`serial`]: line assembly, transcripts, serial faults and the in-memory port.
//! - [`zaber`], [`kurios`], [`wheel`], [`camlink`]: the devices' firmware.
//! - [`serve`]: the rig behind real ptys and a socket (the `firmware-sim` binary).

pub mod camera;
pub mod camlink;
pub mod clock;
pub mod imperfect;
pub mod kurios;
pub mod line;
pub mod random;
pub mod rng;
pub mod scene;
pub mod serial;
pub mod serve;
pub mod table;
pub mod wheel;
pub mod world;
pub mod zaber;

pub use camera::{Defect, SoftwareCamera};
pub use scene::{Scene, SceneError, Sensor};
