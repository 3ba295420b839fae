//! The software rig: `firmware-sim` started on ptys and a socket for a rig configuration,
//! and the rig opened on it.

use std::path::Path;

use super::{Rig, RigConfig};

/// Starts `firmware-sim` for `config` (its `[sim]` scene, re-gridded to the sweep's angles
/// and bands) and points `config` at its ptys and socket.
pub fn open_sim(config: &mut RigConfig) -> Result<(firmware_sim::serve::SimRig, Rig), String> {
    let sim = config
        .sim
        .clone()
        .ok_or("--sim needs a [sim] table with the scene to look at")?;
    let options = sim_options(config, &sim.scene, sim.speed)?;
    open_sim_with(config, options)
}

/// Starts `firmware-sim` with `options` and points `config` at it.
pub fn open_sim_with(
    config: &mut RigConfig,
    options: firmware_sim::serve::RigOptions,
) -> Result<(firmware_sim::serve::SimRig, Rig), String> {
    let sim_rig = firmware_sim::serve::start(options).map_err(|e| format!("firmware-sim: {e}"))?;
    config.stage.port = sim_rig.stage_port.clone();
    config.filter.port = sim_rig.filter_port.clone();
    config.camera.address = sim_rig.camera.to_string();
    let wheel: Option<Box<dyn super::HidTransport + Send>> = Some(Box::new(
        super::wheel::SimWheelTransport::new(sim_rig.wheel.clone(), sim_rig.clock),
    ));
    let rig = super::open_with_clock(config, wheel, sim_rig.clock).map_err(|e| e.to_string())?;
    Ok((sim_rig, rig))
}

/// The simulator options for `config`, looking at `scene_path`.
pub fn sim_options(
    config: &RigConfig,
    scene_path: &Path,
    speed: f64,
) -> Result<firmware_sim::serve::RigOptions, String> {
    let mut scene = if config.builtin && !scene_path.exists() {
        firmware_sim::Scene::from_toml(super::config::BUILTIN_SIM_SCENE, "rig-tiny")
    } else {
        firmware_sim::Scene::load(scene_path)
    }
    .map_err(|e| e.to_string())?;
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
        return Err(format!(
            "{}: sensor {} x {} but rig.toml's camera is {} x {}",
            scene_path.display(),
            scene.sensor.width,
            scene.sensor.height,
            c.width,
            c.height
        ));
    }
    let mut o = firmware_sim::serve::RigOptions::new(scene);
    o.speed = speed;
    o.steps_per_deg = config.stage.steps_per_deg;
    o.stage_limits_deg = config.stage.limits_deg;
    Ok(o)
}
