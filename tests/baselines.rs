//! The whole-cube baselines (`paper`, `brute`) on the software camera's paper samples.
//!
//! Set `FS_DEBUG=1` to print each run's measurements.

use std::path::Path;
use std::time::Instant;

use filmscope::calibrate::calibrate_row;
use filmscope::estimate::baseline::{brute, paper, BruteGrid};
use filmscope::estimate::method::MethodResult;
use filmscope::solve::flags;
use filmscope::source::SweepCube;
use firmware_sim::{Scene, SoftwareCamera};

/// A sweep of the scene's first `height` rows and `width` columns, with the truth thickness
/// map of that crop: noisy (raw counts calibrated with the camera's white and dark
/// references) or noise-free (true band reflectance).
fn cube_from_scene(name: &str, width: usize, height: usize, noisy: bool) -> (SweepCube, Vec<f32>) {
    let path = format!("{}/config/scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    let scene = Scene::load(Path::new(&path)).expect("scene loads");
    let cam = SoftwareCamera::new(scene.clone());
    let full = cam.width();
    let (w, h) = (width.min(full), height.min(cam.height()));
    let nb = scene.bands_nm.len();
    let sat = scene.sensor.saturation_counts() as f32;
    let (mut raw16, mut raw) = (vec![0u16; full], vec![0f32; full]);
    let (mut white, mut dark, mut refl) = (vec![0f32; full], vec![0f32; full], vec![0f32; full]);
    let mut data = Vec::with_capacity(scene.angles_deg.len());
    for a in 0..scene.angles_deg.len() {
        let mut cube = vec![0f32; nb * w * h];
        for b in 0..nb {
            for r in 0..h {
                if noisy {
                    cam.raw_row(a, b, r, &mut raw16);
                    cam.white_row(a, b, r, &mut white);
                    cam.dark_row(a, b, r, &mut dark);
                    for (o, &c) in raw.iter_mut().zip(&raw16) {
                        *o = f32::from(c);
                    }
                    calibrate_row(&raw, Some(&dark), &white, 1.0, sat, &mut refl);
                } else {
                    cam.reflectance_row(a, b, r, &mut refl);
                }
                cube[(b * h + r) * w..(b * h + r + 1) * w].copy_from_slice(&refl[..w]);
            }
        }
        data.push(cube);
    }
    let truth = (0..h)
        .flat_map(|r| scene.thickness_nm[r * full..r * full + w].iter().copied())
        .collect();
    let cube = SweepCube {
        back_face: filmscope_core::optics::BackFace::None,
        width: w,
        height: h,
        bands_nm: scene.bands_nm.clone(),
        fwhm_nm: vec![scene.fwhm_nm; nb],
        angles_deg: scene.angles_deg.clone(),
        ambient_index: scene.stack.ambient_index,
        substrate_index: scene.stack.substrate.index_at(550.0),
        polarization: scene.stack.polarization,
        index_range: scene.index_range.unwrap_or([1.2, 3.0]),
        thickness_range_nm: scene.thickness_range_nm.unwrap_or([50.0, 2000.0]),
        data,
    };
    (cube, truth)
}

/// (index error, thickness MAE over solved pixels in nm, solved fraction).
fn score(result: &MethodResult, truth: &[f32], true_n: f64) -> (f64, f64, f64) {
    let errs: Vec<f64> = result
        .thickness_nm
        .iter()
        .zip(truth)
        .filter(|(d, _)| d.is_finite())
        .map(|(d, t)| f64::from(d - t).abs())
        .collect();
    let mae = errs.iter().sum::<f64>() / errs.len().max(1) as f64;
    let solved = errs.len() as f64 / truth.len() as f64;
    (result.index.a - true_n, mae, solved)
}

fn report(label: &str, result: &MethodResult, truth: &[f32], true_n: f64, secs: f64) {
    let (dn, mae, solved) = score(result, truth, true_n);
    eprintln!(
        "{label}: n = {:.4} (error {dn:+.4}), MAE {mae:.2} nm, solved {:.1} %, {secs:.2} s",
        result.index.a,
        100.0 * solved
    );
    for note in &result.notes {
        eprintln!("  {note}");
    }
}

#[test]
fn paper_solves_sample1_noise_free() {
    // Measured: n error +0.0010 (median of 24568 pair estimates), MAE 0.42 nm.
    let (cube, truth) = cube_from_scene("paper-sample1", 96, 64, false);
    let t = Instant::now();
    let result = paper(&cube);
    report(
        "paper sample1 noise-free",
        &result,
        &truth,
        1.37,
        t.elapsed().as_secs_f64(),
    );
    let (dn, mae, solved) = score(&result, &truth, 1.37);
    assert!(dn.abs() < 0.005, "index error {dn}");
    assert!(mae < 5.0, "thickness MAE {mae} nm");
    assert_eq!(solved, 1.0);
    assert!(result.flags.iter().all(|&f| f == 0));
    assert!(result.notes.iter().any(|n| n.contains("pair estimates")));
}

#[test]
fn paper_fails_on_sample3_noisy() {
    // Measured on this crop: n = 2.187 (error -0.18; whole image -0.17; the paper reports
    // +0.30 on its real sample), thickness MAE 591 nm.
    let (cube, truth) = cube_from_scene("paper-sample3", 96, 24, true);
    let t = Instant::now();
    let result = paper(&cube);
    report(
        "paper sample3 noisy",
        &result,
        &truth,
        2.37,
        t.elapsed().as_secs_f64(),
    );
    let (dn, mae, solved) = score(&result, &truth, 2.37);
    // The paper's weakness on a high-index film: its peaks shift about two bands between
    // neighbouring angles, so noise in the peak positions ruins eq. 12 from pairs of angles.
    assert!(dn.abs() > 0.02, "index error {dn}");
    // Integer orders with a wrong index: the thickness map is not usable either.
    assert!(mae > 100.0, "thickness MAE {mae} nm");
    assert!(solved > 0.99, "solved fraction {solved}");
}

#[test]
fn paper_sample3_noise_free_keeps_the_integer_order_flaw() {
    // Measured on this crop: n error +0.009 (whole image +0.017), MAE 1092 nm (whole image
    // 1242 nm). Without noise
    // the median of the pair estimates lands near the index, but eq. 13 with integer orders
    // puts a model valley where ZnS on PET has its (m + 1/2) peaks, and the least-squares
    // choice of the order then wanders off to far thicknesses.
    let (cube, truth) = cube_from_scene("paper-sample3", 96, 24, false);
    let t = Instant::now();
    let result = paper(&cube);
    report(
        "paper sample3 noise-free",
        &result,
        &truth,
        2.37,
        t.elapsed().as_secs_f64(),
    );
    let (dn, mae, _solved) = score(&result, &truth, 2.37);
    assert!(dn.abs() < 0.05, "index error {dn}");
    assert!(mae > 100.0, "thickness MAE {mae} nm");
}

#[test]
fn brute_solves_cropped_sample1_noise_free() {
    // Measured: n = 1.36 (the grid point next to 1.37), MAE 3.8 nm.
    let (cube, truth) = cube_from_scene("paper-sample1", 24, 16, false);
    let grid = BruteGrid {
        index_steps: 91, // 0.02 over 1.2..3.0
        thickness_step_nm: 4.0,
    };
    let n_step = grid.index_values(cube.index_range)[1] - cube.index_range[0];
    let t = Instant::now();
    let result = brute(&cube, grid);
    report(
        "brute sample1 noise-free 24x16",
        &result,
        &truth,
        1.37,
        t.elapsed().as_secs_f64(),
    );
    let (dn, mae, solved) = score(&result, &truth, 1.37);
    assert!(dn.abs() <= n_step + 1e-9, "index error {dn}");
    assert!(mae < 2.0 * grid.thickness_step_nm, "thickness MAE {mae} nm");
    assert_eq!(solved, 1.0);
    assert!(result.notes.iter().any(|n| n.contains("91 indices")));
}

#[test]
fn baselines_flag_unusable_pixels() {
    let (mut cube, _truth) = cube_from_scene("paper-sample1", 6, 2, false);
    let (w, h, nb) = (cube.width, cube.height, cube.bands_nm.len());
    for plane in cube.data.iter_mut() {
        for b in 0..nb {
            plane[b * w * h] = f32::INFINITY; // pixel 0: saturated throughout
            if b % 2 == 0 {
                plane[b * w * h + 1] = f32::NAN; // pixel 1: every other band dead
            }
        }
        plane[5 * w * h + 2] = f32::NAN; // pixel 2: one dead sample per angle, still usable
    }
    let grid = BruteGrid {
        index_steps: 19,
        thickness_step_nm: 10.0,
    };
    let b = brute(&cube, grid);
    assert!(b.thickness_nm[0].is_nan() && b.flags[0] == flags::SATURATED);
    assert!(b.thickness_nm[1].is_nan() && b.flags[1] == flags::DEAD);
    assert!(b.thickness_nm[2].is_finite() && b.flags[2] == 0);
    assert!(b.confidence[2] == 1.0 && b.confidence[0] == 0.0);
    let p = paper(&cube);
    assert!(p.thickness_nm[0].is_nan() && p.flags[0] == flags::NO_FRINGE | flags::SATURATED);
    assert!(p.thickness_nm[1].is_nan() && p.flags[1] == flags::NO_FRINGE | flags::DEAD);
    assert!(p.thickness_nm[2].is_finite() && p.flags[2] == 0);

    cube.data[1].pop();
    for r in [paper(&cube), brute(&cube, grid)] {
        assert!(r.thickness_nm.iter().all(|d| d.is_nan()));
        assert!(r.flags.iter().all(|&f| f == flags::DEAD));
        assert!(r.notes[0].contains("unusable cube"), "{:?}", r.notes);
    }
}

#[test]
#[ignore = "measurements for the record (slow: brute on whole images); prints, asserts nothing"]
fn measure_baselines() {
    for (scene, n, noisy, h) in [
        ("paper-sample1", 1.37, true, 64),
        ("paper-sample3", 2.37, false, 64),
        ("paper-sample3", 2.37, true, 64),
        ("paper-sample2", 1.37, false, 64),
    ] {
        let (cube, truth) = cube_from_scene(scene, 96, h, noisy);
        let t = Instant::now();
        let result = paper(&cube);
        let label = format!("paper {scene} noisy={noisy} 96x{h}");
        report(&label, &result, &truth, n, t.elapsed().as_secs_f64());
    }
    for (scene, n, noisy) in [
        ("paper-sample1", 1.37, false),
        ("paper-sample3", 2.37, true),
    ] {
        let (cube, truth) = cube_from_scene(scene, 96, 64, noisy);
        let t = Instant::now();
        let result = brute(&cube, BruteGrid::default());
        let label = format!("brute {scene} noisy={noisy} 96x64 default grid");
        report(&label, &result, &truth, n, t.elapsed().as_secs_f64());
    }
}
