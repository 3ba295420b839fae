//! The Python peers of `filmscope bench` (`benches/peers/`) on a tiny capture: each reads
//! the raw capture, calibrates it and estimates every pixel it is asked to, within 0.3 nm
//! of the truth on average. Skipped, with a note, where `python3` cannot import NumPy and
//! SciPy, unless `FILMSCOPE_REQUIRE_PEERS` is set (`.ci/run` sets it once it has installed
//! them).

use filmscope::lab::peers::{run_script, unavailable};
use filmscope::lab::scene::{scene_with, SceneFile};
use filmscope::simulate::{write_capture, SimulateOptions};

#[test]
fn python_peers_measure_a_tiny_capture() {
    if let Some(why) = unavailable() {
        assert!(
            std::env::var_os("FILMSCOPE_REQUIRE_PEERS").is_none(),
            "{why}"
        );
        eprintln!("peers test {why}");
        return;
    }
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/scenes/paper-sample1.toml"
    );
    let scene = scene_with(&SceneFile::Path(path.into()), 32, 24, None).expect("scene");
    let dir = tempfile::tempdir().expect("temp dir");
    write_capture(&scene, dir.path(), SimulateOptions::default(), &|_| {}).expect("capture");
    let lut = run_script("numpy_lut.py", dir.path(), &[]).expect("numpy_lut.py");
    assert_eq!(lut.pixels, 32 * 24);
    assert!(lut.valid >= 0.99, "{lut:?}");
    assert!(lut.mae_nm < 0.3, "{lut:?}");
    let args = ["--max-pixels".to_owned(), "48".to_owned()];
    let lsq = run_script("scipy_lsq.py", dir.path(), &args).expect("scipy_lsq.py");
    assert_eq!(lsq.pixels, 48);
    assert!(lsq.valid >= 0.95, "{lsq:?}");
    assert!(lsq.mae_nm < 0.3, "{lsq:?}");
}
