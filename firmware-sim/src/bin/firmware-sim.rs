//! `firmware-sim SCENE [--speed X] [--unix PATH] [--limits LO,HI]`: the simulated rig behind
//! real transports. Opens a pty for the stage (Zaber ASCII) and one for the LCTF (Kurios),
//! a socket for the camera link, prints their paths, and serves until stdin closes.
//!
//! Point a `rig.toml` at the printed paths (its `[sweep]` should match the scene's angles
//! and bands, which the camera renders) and run `filmscope acquire` as on hardware.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use firmware_sim::serve::{start, RigOptions};
use firmware_sim::Scene;

fn run() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let mut scene = None;
    let mut speed = 1.0;
    let mut unix = None;
    let mut limits = None;
    while let Some(a) = args.next() {
        let mut value = |name: &str| args.next().ok_or(format!("{name} needs a value"));
        match a.as_str() {
            "--speed" => {
                speed = value("--speed")?
                    .parse()
                    .map_err(|_| "--speed: a number".to_owned())?
            }
            "--unix" => unix = Some(PathBuf::from(value("--unix")?)),
            "--limits" => {
                let v = value("--limits")?;
                let (lo, hi) = v.split_once(',').ok_or("--limits LO,HI")?;
                let p = |s: &str| s.trim().parse::<f64>().map_err(|_| "--limits LO,HI");
                limits = Some([p(lo)?, p(hi)?]);
            }
            "-h" | "--help" => {
                println!("firmware-sim SCENE [--speed X] [--unix PATH] [--limits LO,HI]");
                return Ok(());
            }
            s if scene.is_none() && !s.starts_with('-') => scene = Some(PathBuf::from(s)),
            s => return Err(format!("unexpected argument {s:?}")),
        }
    }
    let scene_path = scene.ok_or("usage: firmware-sim SCENE [--speed X] [--unix PATH]")?;
    let scene = Scene::load(Path::new(&scene_path)).map_err(|e| e.to_string())?;
    let mut options = RigOptions::new(scene);
    options.speed = speed;
    options.unix_socket = unix;
    if let Some(l) = limits {
        options.stage_limits_deg = l;
    }
    let rig = start(options).map_err(|e| format!("cannot start: {e}"))?;
    println!("stage  {}", rig.stage_port);
    println!("filter {}", rig.filter_port);
    println!("camera {}", rig.camera);
    println!("(HID filter wheel: in process only; leave [wheel] out of rig.toml)");
    // Serve until stdin closes (Ctrl-D, or the parent process going away).
    let mut sink = Vec::new();
    let _ = std::io::stdin().read_to_end(&mut sink);
    drop(rig);
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("firmware-sim: {e}");
            ExitCode::FAILURE
        }
    }
}
