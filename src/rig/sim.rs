//! The software rig: `firmware-sim` started on ptys and a socket for a rig configuration,
//! and the rig opened on it.

use std::path::{Path, PathBuf};

use super::{Rig, RigConfig, RigError};

/// Why the software rig could not be started or opened, one line.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// `--sim` with a rig file that names no scene.
    #[error("--sim needs a [sim] table with the scene to look at")]
    NoScene,
    /// The scene cannot be read.
    #[error(transparent)]
    Scene(#[from] firmware_sim::SceneError),
    /// The scene's sensor is not the rig's camera.
    #[error("{}: sensor {scene_width} x {scene_height} but rig.toml's camera is {camera_width} x {camera_height}", .scene.display())]
    Sensor {
        /// The scene file.
        scene: PathBuf,
        /// The scene's sensor width, pixels.
        scene_width: usize,
        /// The scene's sensor height, pixels.
        scene_height: usize,
        /// The rig's camera width, pixels.
        camera_width: u32,
        /// The rig's camera height, pixels.
        camera_height: u32,
    },
    /// The simulator could not start.
    #[error("firmware-sim: {0}")]
    Start(std::io::Error),
    /// The rig could not be opened on it.
    #[error(transparent)]
    Rig(#[from] RigError),
}

/// Starts `firmware-sim` for `config` (its `[sim]` scene, re-gridded to the sweep's angles
/// and bands) and points `config` at its ptys and socket.
pub fn open_sim(config: &mut RigConfig) -> Result<(firmware_sim::serve::SimRig, Rig), SimError> {
    let sim = config.sim.clone().ok_or(SimError::NoScene)?;
    let options = sim_options(config, &sim.scene, sim.speed)?;
    open_sim_with(config, options)
}

/// Starts `firmware-sim` with `options` and points `config` at it.
pub fn open_sim_with(
    config: &mut RigConfig,
    options: firmware_sim::serve::RigOptions,
) -> Result<(firmware_sim::serve::SimRig, Rig), SimError> {
    let sim_rig = firmware_sim::serve::start(options).map_err(SimError::Start)?;
    config.stage.port = sim_rig.stage_port.clone();
    config.filter.port = sim_rig.filter_port.clone();
    config.camera.address = sim_rig.camera.to_string();
    let wheel: Option<Box<dyn super::HidTransport + Send>> = Some(Box::new(
        super::wheel::SimWheelTransport::new(sim_rig.wheel.clone(), sim_rig.clock),
    ));
    let rig = super::open_with_clock(config, wheel, sim_rig.clock)?;
    Ok((sim_rig, rig))
}

/// The simulator options for `config`, looking at `scene_path`.
pub fn sim_options(
    config: &RigConfig,
    scene_path: &Path,
    speed: f64,
) -> Result<firmware_sim::serve::RigOptions, SimError> {
    let mut scene = if config.builtin && !scene_path.exists() {
        firmware_sim::Scene::from_toml(super::config::BUILTIN_SIM_SCENE, "rig-tiny")
    } else {
        firmware_sim::Scene::load(scene_path)
    }?;
    let s = &config.sweep;
    scene.angles_deg = s
        .angles_deg
        .iter()
        .map(|a| a + s.stage_offset_deg)
        .collect();
    scene.bands_nm = s.bands();
    scene.fwhm_nm = s.fwhm_nm;
    let c = &config.camera;
    if scene.sensor.width != c.width as usize || scene.sensor.height != c.height as usize {
        return Err(SimError::Sensor {
            scene: scene_path.to_path_buf(),
            scene_width: scene.sensor.width,
            scene_height: scene.sensor.height,
            camera_width: c.width,
            camera_height: c.height,
        });
    }
    let mut o = firmware_sim::serve::RigOptions::new(scene);
    o.speed = speed;
    o.steps_per_deg = config.stage.steps_per_deg;
    o.stage_limits_deg = config.stage.limits_deg;
    Ok(o)
}
