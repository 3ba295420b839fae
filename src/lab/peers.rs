//! The peers `filmscope bench` sets filmscope beside: two Python scripts of the kind
//! researchers write (`benches/peers/`), run on the capture of the bench's methods scene
//! with the film's true index given.
//!
//! - `numpy_lut.py`: a vectorised NumPy look-up table of the model's spectra (every angle
//!   and band) over a 1 nm thickness grid, each pixel matched by least squares and refined
//!   by a parabola.
//! - `scipy_lsq.py`: a SciPy `least_squares` fit per pixel, started from a 5 nm table's
//!   nearest thickness; on an evenly strided subset of the pixels (its time is per pixel
//!   fitted).
//!
//! Each prints `{seconds, load_seconds, pixels, mae_nm, valid}`; `seconds` leaves out
//! reading and calibrating the capture, as filmscope's methods figure starts from
//! calibrated frames in memory. The peers run where `python3` imports NumPy and SciPy;
//! elsewhere the report says why they were skipped.

use std::path::{Path, PathBuf};
use std::process::Command;

use super::{LabError, Result};
use firmware_sim::Scene;
use serde::{Deserialize, Serialize};

use crate::simulate::{write_capture, SimulateOptions};

/// What a peer script prints.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PeerRun {
    /// Seconds of its table and match or fits (after reading and calibrating).
    pub seconds: f64,
    /// Seconds it took to read and calibrate the capture.
    pub load_seconds: f64,
    /// Pixels it estimated.
    pub pixels: usize,
    /// Thickness mean absolute error over its valid pixels, nm.
    pub mae_nm: f64,
    /// Its valid fraction.
    pub valid: f64,
}

impl PeerRun {
    /// Seconds per megapixel.
    pub fn seconds_per_mpix(&self) -> f64 {
        self.seconds / (self.pixels.max(1) as f64 / 1e6)
    }
}

/// Both peers on one capture, or why they did not run.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
pub struct Peers {
    /// `numpy_lut.py`.
    pub numpy_lut: Option<PeerRun>,
    /// `scipy_lsq.py`.
    pub scipy: Option<PeerRun>,
    /// Pixels `scipy_lsq.py` was asked to fit at most.
    pub scipy_max_pixels: usize,
    /// Why a peer is missing, if one is.
    pub note: Option<String>,
}

/// Where the scripts are: `FILMSCOPE_PEERS_DIR`, else `benches/peers` under the working
/// directory, else under the source tree this binary was built from.
fn scripts_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("FILMSCOPE_PEERS_DIR") {
        return dir.into();
    }
    let here = Path::new("benches/peers");
    if here.join("numpy_lut.py").exists() {
        return here.to_path_buf();
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/peers")
}

/// Why the peers cannot run here, or `None` when `python3` imports NumPy and SciPy.
pub fn unavailable() -> Option<String> {
    match Command::new("python3")
        .args(["-c", "import numpy, scipy"])
        .output()
    {
        Err(e) => Some(format!("skipped: python3 not found ({e})")),
        Ok(o) if !o.status.success() => Some(format!(
            "skipped: python3 cannot import numpy and scipy ({})",
            String::from_utf8_lossy(&o.stderr)
                .lines()
                .last()
                .unwrap_or("")
                .trim()
        )),
        Ok(_) => None,
    }
}

/// Runs `script` (in `benches/peers`) on the capture `capture_dir` with `args`.
pub fn run_script(script: &str, capture_dir: &Path, args: &[String]) -> Result<PeerRun> {
    let path = scripts_dir().join(script);
    let out = Command::new("python3")
        .arg(&path)
        .arg(capture_dir)
        .args(args)
        .output()
        .map_err(LabError::step(format!(
            "cannot start python3 {}",
            path.display()
        )))?;
    if !out.status.success() {
        return Err(LabError::Invalid(format!(
            "{script} failed: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().last().unwrap_or_default();
    serde_json::from_str(line).map_err(LabError::step(format!("{script} printed {line:?}")))
}

/// Writes `scene` as a raw capture (counts with white and dark references) in a scratch
/// folder and runs both peers on it; `scipy_max_pixels` bounds the SciPy fit's pixels.
pub fn run(scene: &Scene, scipy_max_pixels: usize) -> Peers {
    let mut peers = Peers {
        scipy_max_pixels,
        ..Peers::default()
    };
    if let Some(why) = unavailable() {
        peers.note = Some(why);
        return peers;
    }
    let result = (|| -> Result<()> {
        let tmp = tempfile::Builder::new()
            .prefix(&format!("filmscope-peers-{}-", scene.seed))
            .tempdir()?;
        let dir = tmp.path().join("capture");
        write_capture(scene, &dir, SimulateOptions::default(), &|_| {})?;
        let mut notes = Vec::new();
        match run_script("numpy_lut.py", &dir, &[]) {
            Ok(r) => peers.numpy_lut = Some(r),
            Err(e) => notes.push(e.to_string()),
        }
        let max = ["--max-pixels".to_owned(), scipy_max_pixels.to_string()];
        match run_script("scipy_lsq.py", &dir, &max) {
            Ok(r) => peers.scipy = Some(r),
            Err(e) => notes.push(e.to_string()),
        }
        if !notes.is_empty() {
            peers.note = Some(notes.join("; "));
        }
        Ok(())
    })();
    if let Err(e) = result {
        peers.note = Some(format!("peers not run: {e}"));
    }
    peers
}

/// A peer's seconds per megapixel over filmscope's (`filmscope_s_per_mpix`).
pub fn speedup(peer: Option<&PeerRun>, filmscope_s_per_mpix: f64) -> Option<f64> {
    peer.map(|p| p.seconds_per_mpix() / filmscope_s_per_mpix)
}

/// The peers' rows for the bench's methods table (`method`, s per Mpix, |n err|, MAE,
/// valid), and a line for a missing peer.
pub fn table_rows(peers: &Peers) -> String {
    let mut s = String::new();
    for (label, run) in [
        ("numpy-lut (n given)", &peers.numpy_lut),
        ("scipy-lsq (n given)", &peers.scipy),
    ] {
        if let Some(r) = run {
            s.push_str(&format!(
                "{:<18} {:>12.3} {:>10} {:>10.2} {:>6.1}%\n",
                label,
                r.seconds_per_mpix(),
                "-",
                r.mae_nm,
                100.0 * r.valid
            ));
        }
    }
    if let Some(note) = &peers.note {
        s.push_str(&format!("peers: {note}\n"));
    }
    s
}
