//! The estimator's targets on the paper's scenes (issue: streaming estimator), through the
//! real pipeline from the software camera: raw 12-bit counts with white and dark references,
//! shot and read noise, a smoothly varying thickness map. Tolerances are the targets; the
//! figures measured when this was written are in the README (`filmscope eval`); those quoted
//! in comments here predate the software camera's independent noise (rows, bands and angles)
//! unless they say otherwise.

use crate::common;

use common::run_scene;

use filmscope::estimate::method::Method;
use filmscope::estimate::{index_model_name, run_method, Run, RunConfig};
use filmscope::lab::eval::{EvalReport, Truth};
use filmscope::pipeline::{run_sweep, PipelineConfig, Prior, PriorUpdate};
use filmscope::source::SimSource;
use filmscope_core::solve::flags;
use firmware_sim::SoftwareCamera;

fn eval(name: &str, method: Method) -> EvalReport {
    let config = RunConfig {
        method,
        ..RunConfig::default()
    };
    let (r, _) = run_scene(name, common::scene(name), &config);
    eprintln!("{}", serde_json::to_string(&r).expect("json"));
    r
}

/// Checks a run's index error, thickness MAE (nm) and valid share against bounds; `what`
/// names the case in a failure.
fn assert_bounds(r: &EvalReport, what: &str, max_index: f64, max_mae_nm: f64, min_valid: f64) {
    let (index, mae, valid) = (r.index_error, r.thickness_mae_nm, r.valid_fraction);
    assert!(index.abs() <= max_index, "{what}: index error {index}");
    assert!(mae <= max_mae_nm, "{what}: MAE {mae}");
    assert!(valid >= min_valid, "{what}: valid {valid}");
}

fn check(r: &EvalReport, max_index_error: f64) {
    check_valid(r, max_index_error, 0.98);
}

fn check_valid(r: &EvalReport, max_index_error: f64, min_valid: f64) {
    assert_bounds(r, &r.scene, max_index_error, 3.0, min_valid);
    assert!(
        r.delta_e76_mean <= 0.5,
        "{}: dE76 {}",
        r.scene,
        r.delta_e76_mean
    );
    assert!(
        r.spectral_rmse <= 0.01,
        "{}: RMSE {}",
        r.scene,
        r.spectral_rmse
    );
    assert!(
        r.silent_failure_rate <= 0.001,
        "{}: silent {}",
        r.scene,
        r.silent_failure_rate
    );
}

#[test]
fn paper_sample1_mgf2_400nm_meets_the_targets() {
    check(&eval("paper-sample1", Method::Filmscope), 0.003);
}

#[test]
fn paper_sample2_mgf2_600nm_meets_the_targets() {
    check(&eval("paper-sample2", Method::Filmscope), 0.003);
}

#[test]
fn paper_sample3_zns_500nm_meets_the_targets() {
    check(&eval("paper-sample3", Method::Filmscope), 0.01);
}

// Films without a fringe pair in the band: the index from the sample's full spectra, every
// pixel started from the sample's thickness map and refined on its own spectrum.
#[test]
fn films_without_fringe_pairs_are_measured_from_their_spectra() {
    check_valid(&eval("thin-80nm", Method::Filmscope), 0.005, 0.98);
    for (name, index, thickness, substrate) in [
        ("zns-80nm-on-pet", 2.35, 80.0, 1.65),
        ("mgf2-100nm-on-glass", 1.38, 100.0, 1.52),
    ] {
        let text = format!(
            r#"
name = "{name}"
seed = 11
[film]
index = {index}
[film.thickness]
base_nm = {thickness}
gradient_nm = [10.0, -6.0]
[substrate]
index = {substrate}
[rig]
angles_deg = [10.0, 20.0, 30.0, 40.0, 50.0]
bands_nm = [420.0, 720.0, 2.0]
fwhm_nm = 4.0
[sensor]
width = 32
height = 24
"#
        );
        let scene = firmware_sim::Scene::from_toml(&text, name).expect("scene");
        let (r, run) = run_scene(name, scene, &RunConfig::default());
        check_valid(&r, 0.005, 0.98);
        // A constant film: whatever model is chosen bends by less than the 0.005 claimed.
        let bend = run.result.index.at(420.0) - run.result.index.at(720.0);
        assert!(bend.abs() < 0.005, "{name}: {:?}", run.model_choice);
        let seeded = run
            .result
            .flags
            .iter()
            .filter(|&&f| f & flags::FROM_SPECTRUM_SEARCH != 0);
        assert!(
            seeded.count() * 2 > run.result.flags.len(),
            "{name}: not seeded"
        );
    }
}

#[test]
fn filmscope_is_more_accurate_than_the_paper_method_on_every_paper_sample() {
    for name in ["paper-sample1", "paper-sample2", "paper-sample3"] {
        let ours = eval(name, Method::Filmscope);
        let theirs = eval(name, Method::Paper);
        assert!(
            ours.index_error.abs() <= theirs.index_error.abs(),
            "{name}: index"
        );
        assert!(
            ours.thickness_mae_nm <= theirs.thickness_mae_nm,
            "{name}: thickness"
        );
        assert!(
            ours.delta_e76_mean <= theirs.delta_e76_mean,
            "{name}: colour"
        );
    }
    // The paper's published weakness: its index on the high-index film is far off.
    let zns = eval("paper-sample3", Method::Paper);
    assert!(
        zns.index_error.abs() > 0.05,
        "paper method on ZnS: {}",
        zns.index_error
    );
}

// Debenham's Sellmeier ZnS: the index falls by 0.19 across the band, and a two-term Cauchy
// model misses it by up to 0.0105 (a three-term one by 0.0008). The extremum shifts alone
// gave -0.10..+0.21 and every pixel flagged; the full-spectrum pass gives, measured over seeds
// 201, 1, 2, 3, 4: index error -0.0002..-0.0005, MAE 0.08-0.10 nm, valid 100 %, spectral RMSE
// 0.0006, dE2000 0.07, the three-term model chosen.
#[test]
fn real_zns_dispersion_is_measured_under_every_noise_seed() {
    for seed in [201u64, 1, 2, 3, 4] {
        let mut scene = common::scene("zns-dispersive");
        scene.seed = seed;
        let (r, run) = run_scene("zns-dispersive", scene, &RunConfig::default());
        assert!(
            r.silent_failure_rate <= 0.001,
            "seed {seed}: silent {}",
            r.silent_failure_rate
        );
        assert_bounds(&r, &format!("seed {seed}"), 0.003, 1.0, 0.98);
        assert!(
            r.spectral_rmse <= 0.002,
            "seed {seed}: RMSE {}",
            r.spectral_rmse
        );
        assert!(
            r.delta_e2000_mean <= 0.5,
            "seed {seed}: dE {}",
            r.delta_e2000_mean
        );
        let fall = run.result.index.at(420.0) - run.result.index.at(720.0);
        assert!(fall > 0.15, "seed {seed}: {:?}", run.result.index);
    }
}

#[test]
fn thick_film_wide_bands_and_shuffled_angles() {
    // 1.5 um MgF2 on glass, 10 nm FWHM, angles 65, 5, 35, 20, 50. About 3 % of the pixels
    // are flagged (their order is decided only at the last angle), none silently wrong.
    check_valid(&eval("wide-band-thick", Method::Filmscope), 0.003, 0.95);
}

#[test]
fn other_noise_seeds_keep_thickness_and_never_fail_silently() {
    // The thickness map and the noise both change with the seed. Measured index errors for
    // MgF2 400 nm over seeds 1-4: +0.0017, +0.0041, -0.0009, +0.0000 (the 0.003 target is not
    // met for every seed; see README), ZnS: -0.0008, +0.0013, +0.0010, -0.0032.
    for (name, max_index_error) in [("paper-sample1", 0.005), ("paper-sample3", 0.01)] {
        for seed in 1..=4u64 {
            let mut scene = common::scene(name);
            let text = std::fs::read_to_string(format!(
                "{}/config/scenes/{name}.toml",
                env!("CARGO_MANIFEST_DIR")
            ))
            .expect("scene file");
            let reseeded =
                text.replace(&format!("seed = {}", scene.seed), &format!("seed = {seed}"));
            scene = firmware_sim::Scene::from_toml(&reseeded, name).expect("reseeded scene");
            let (r, _) = run_scene(name, scene, &RunConfig::default());
            assert_bounds(
                &r,
                &format!("{name} seed {seed}"),
                max_index_error,
                3.0,
                0.98,
            );
            assert!(
                r.silent_failure_rate <= 0.001,
                "{name} seed {seed}: silent {}",
                r.silent_failure_rate
            );
        }
    }
}

// Model no more than a scene needs: the constant-index films keep a constant index, real
// ZnS (Debenham's Sellmeier) a model with a pole or a third Cauchy term (either follows it
// within the noise); every replayable estimate streams twice (the sample, then every pixel),
// and once more when a few pixels (under 1 %: paper-sample3 had 4 of 6144) are left for the
// thickness search.
#[test]
fn the_index_model_is_no_richer_than_the_scene_needs() {
    let expected = [
        ("paper-sample1", "constant", 2),
        ("paper-sample3", "constant", 2),
        ("wide-band-thick", "constant", 2),
        ("zns-dispersive", "sellmeier", 2),
        ("thin-80nm", "constant", 2),
    ];
    let got: Vec<(&str, &str, u64)> = expected
        .iter()
        .map(|&(name, _, _)| {
            let scene = common::scene(name);
            let mut source = SimSource::new(SoftwareCamera::new(scene), false, 8).expect("source");
            let run = run_method(&mut source, &RunConfig::default(), &|_| {}).expect("run");
            let choice = run.model_choice.as_ref();
            eprintln!(
                "{name}: {}",
                filmscope::record::to_json(&choice).expect("json")
            );
            let mut passes = choice.and_then(|c| c.passes()).unwrap_or(0) as u64;
            if let Some(searched) = choice.and_then(|c| c.pixels_searched()) {
                let searched = searched as u64;
                let pixels = run.result.thickness_nm.len() as u64;
                assert!(
                    searched * 100 < pixels,
                    "{name}: {searched} pixels searched"
                );
                passes -= 1;
            }
            let model = index_model_name(&run.result.index);
            // Real ZnS needs a third parameter; Cauchy or Sellmeier fit it alike.
            let model = match model {
                "cauchy3" | "sellmeier" | "sellmeier_constant" if name == "zns-dispersive" => {
                    "sellmeier"
                }
                m => m,
            };
            (name, model, passes)
        })
        .collect();
    assert_eq!(got, expected, "(scene, index model, passes)");
}

// A thin film whose index and thickness trade (n 1.6, 50 nm on 1.52, under half a fringe
// across the band; the stability maps' grid scene, the paper's camera): the full-spectrum
// pass's sums, added at thicknesses that stepped as the angles arrived, took a Cauchy term
// on seeds 7, 10 and 11 (index -0.0124 / -0.0065 / -0.0089, MAE 6.57 / 3.32 / 4.65 nm). The
// polishing pass, its sums all linearised at the result, drops it (seed 10: Wald chi-square
// 3.5) and steps: measured -0.0004 / +0.0007 / -0.0010, MAE 0.35 / 0.42 / 0.54 nm.
#[test]
fn a_thin_film_keeps_a_constant_index_and_its_accuracy() {
    for seed in [7, 10, 11] {
        let grid = filmscope::lab::chart::GridScene {
            index: 1.6,
            thickness_nm: 50.0,
            seed,
            ..Default::default()
        };
        let scene = grid.scene().expect("grid scene");
        let (r, run) = run_scene("n1.6-d50", scene, &RunConfig::default());
        eprintln!("seed {seed}: {}", serde_json::to_string(&r).expect("json"));
        assert_eq!(
            run.result.index.terms(),
            1,
            "seed {seed}: {:?}",
            run.model_choice
        );
        assert_bounds(&r, &format!("seed {seed}"), 0.002, 1.0, 0.98);
    }
}

/// A thick high-index film (n 2.8 / 2000 nm on 1.52, the paper's camera): its first pass's
/// extremum-shift index is loose enough that every pixel's thickness sigma (which carries
/// the index's) passes the `imprecise` limit; counted as unsolved, that sent the estimate
/// to the search for films without a fringe pair, which ended 0.0101 low in index with MAE
/// 7.42 nm (seed 7; 2.6 / 2000 nm: 0.0041, 3.25 nm). Measured with the pixels that have an
/// order counted: seed 7 +0.0011 / 0.86 nm, n 2.6 +0.0016 / 1.32 nm.
#[test]
fn a_thick_high_index_film_is_not_taken_for_one_without_fringe_pairs() {
    for index in [2.6, 2.8] {
        let grid = filmscope::lab::chart::GridScene {
            index,
            thickness_nm: 2000.0,
            seed: 7,
            ..Default::default()
        };
        let scene = grid.scene().expect("grid scene");
        let (r, run) = run_scene("thick", scene, &RunConfig::default());
        eprintln!("n {index}: {}", serde_json::to_string(&r).expect("json"));
        let choice = filmscope::record::to_json(&run.model_choice).expect("json");
        assert!(!choice.contains("spectrum search"), "n {index}: {choice}");
        assert_bounds(&r, &format!("n {index}"), 0.003, 2.0, 0.98);
    }
}

/// Scene `name` run twice: every pixel keeping the index's sums and whole extremum lists,
/// then one pixel in 16 (`index_pixels`, a large sensor's share), the second's report
/// printed. Each run's report and run, in that order.
fn every_pixel_and_one_in_16(name: &str) -> [(EvalReport, Run); 2] {
    let scene = common::scene(name);
    let pixels = scene.sensor.width * scene.sensor.height;
    let all = run_scene(name, scene.clone(), &RunConfig::default());
    let mut config = RunConfig::default();
    config.pipeline.solver.index_pixels = pixels / 16;
    let some = run_scene(&format!("{name} 1/16"), scene, &config);
    eprintln!("{}", serde_json::to_string(&some.0).expect("json"));
    [all, some]
}

/// One pixel in 16 keeping the shared sums and whole extremum lists (`index_pixels`, 32
/// bytes a pixel fewer for the rest): a large sensor's default (1 Mpix keeps 65536), here on
/// a small scene; the index comes from the pixel sample either way.
#[test]
fn the_index_from_one_pixel_in_16_keeps_the_accuracy() {
    let [(all, _), (some, _)] = every_pixel_and_one_in_16("thin-80nm");
    assert_bounds(&some, "1/16", 0.001, 0.5, 0.98);
    assert!(
        (some.index_error - all.index_error).abs() <= 5e-4,
        "{some:?}\n{all:?}"
    );
    assert!((some.thickness_mae_nm - all.thickness_mae_nm).abs() <= 0.1);
    assert!((some.valid_fraction - all.valid_fraction).abs() <= 0.005);
}

/// A high-index film (n 2.37, paper sample 3) with one pixel in 16 keeping the index's sums
/// and whole extremum lists: the other 15 choose their orders from the last four extrema of
/// each angle and the lists' counts (`ExtremaHead`). Within 0.1 nm of thickness MAE and
/// 0.5 % of valid pixels of every pixel keeping whole lists, and nothing silently wrong.
/// Measured by this test: index +0.00001, MAE 0.044 nm, 99.80 % valid, none silently
/// wrong; `filmscope eval config/scenes/paper-sample3.toml --index-pixels 192` printed
/// 99.8 % valid against 99.9 %.
#[test]
fn orders_from_the_last_extrema_keep_the_accuracy_on_a_high_index_film() {
    let [(all, _), (some, _)] = every_pixel_and_one_in_16("paper-sample3");
    assert_bounds(&some, "1/16", 0.001, 0.5, 0.98);
    assert!(
        (some.thickness_mae_nm - all.thickness_mae_nm).abs() <= 0.1,
        "{some:?}\n{all:?}"
    );
    assert!(
        (some.valid_fraction - all.valid_fraction).abs() <= 0.005,
        "{some:?}\n{all:?}"
    );
    assert!(some.silent_failure_rate <= 0.001, "{some:?}");
}

/// A sweep that starts from a prior index (a second pass, or a production line's next
/// sweep) chooses each pixel's order from its first two angles; on MgF2 400 nm those orders
/// were wrong for every pixel (residual 0.0199 against a noise of 0.0044, all flagged
/// `model_mismatch`) until pixels could move to a neighbouring order their full spectra fit
/// better. Measured now: residual 0.0040-0.0041, 6139 of 6144 pixels valid, whatever moves
/// the index.
#[test]
fn a_sweep_from_a_prior_index_finds_the_orders_on_mgf2_400nm() {
    let scene = common::scene("paper-sample1");
    let mut source = SimSource::new(SoftwareCamera::new(scene), false, 8).expect("source");
    let first = run_sweep(&mut source, PipelineConfig::default(), None, &|_| {}).expect("sweep");
    let index = first.index.expect("an index");
    for update in [
        PriorUpdate::Hold,
        PriorUpdate::Shifts,
        PriorUpdate::FullSpectra,
    ] {
        let prior = Prior::new(index, update, None);
        let out =
            run_sweep(&mut source, PipelineConfig::default(), Some(prior), &|_| {}).expect("sweep");
        let valid = out
            .results
            .iter()
            .filter(|r| r.flags & flags::INVALID == 0)
            .count();
        eprintln!(
            "{update:?}: index {:?} residual {:?} noise {:?} valid {valid}/{}",
            out.index.map(|i| i.at(550.0)),
            out.residual_sigma,
            out.noise_sigma,
            out.results.len()
        );
        assert!(!out.model_mismatch, "{update:?}");
        assert!(
            valid * 100 >= out.results.len() * 99,
            "{update:?}: {valid} valid"
        );
    }
}

/// Median of the finite values.
fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The thickness sigma map (`thickness_sigma_nm.hdr`) is the error's scale and follows the
/// noise: n 1.38, 500 nm, white Gaussian reflectance noise 0.5 and 2 % (an ideal sensor):
/// every valid pixel's sigma finite and within the `imprecise` limit, the median sigma four
/// times as large at four times the noise, and the median |error| / sigma near a normal
/// variable's 0.674. Measured (independent noise): median sigma 0.385 and 1.545 nm with the
/// index's covariance carried in (0.383 and 1.536 from the fit alone), median |error| /
/// sigma 0.61 and 0.61. (On the paper's camera, shot and read noise, paper-sample1 at
/// 192 x 128 gives 0.72, p90 1.77, against a normal variable's 0.674 and 1.645, comparing
/// `estimate`'s maps with the capture's truth map.) This is the statistical sigma
/// (`rig_tolerance` 0); by default the index's share also carries the nuisance terms a rig
/// keeps, so on this ideal sensor every pixel's sigma is at least the statistical one.
#[test]
fn the_thickness_sigma_follows_the_noise() {
    let statistical = RunConfig {
        rig_tolerance: Some(0.0),
        ..RunConfig::default()
    };
    let mut medians = Vec::new();
    for noise in [0.5, 2.0] {
        let grid = filmscope::lab::chart::GridScene {
            noise_percent: Some(noise),
            ..Default::default()
        };
        let scene = grid.scene().expect("scene");
        let truth = Truth::of_scene(&scene);
        let mut source = SimSource::new(SoftwareCamera::new(scene), false, 1).expect("source");
        let run = run_method(&mut source, &statistical, &|_| {}).expect("run");
        let r = &run.result;
        let valid: Vec<usize> = (0..r.thickness_nm.len())
            .filter(|&i| r.thickness_nm[i].is_finite())
            .collect();
        assert!(
            valid.len() * 10 >= r.thickness_nm.len() * 9,
            "noise {noise} %: valid {}",
            valid.len()
        );
        let scene = grid.scene().expect("scene");
        let mut source = SimSource::new(SoftwareCamera::new(scene), false, 1).expect("source");
        let rig = run_method(&mut source, &RunConfig::default(), &|_| {}).expect("run");
        for &i in &valid {
            let (s, wide) = (r.thickness_sigma_nm[i], rig.result.thickness_sigma_nm[i]);
            assert!(
                wide >= s * 0.999,
                "noise {noise} %: pixel {i} sigma {wide} with the rig's terms, {s} without"
            );
        }
        for &i in &valid {
            let s = r.thickness_sigma_nm[i];
            assert!(
                s.is_finite() && s > 0.0 && f64::from(s) <= flags_limit(),
                "noise {noise} %: pixel {i} sigma {s}"
            );
        }
        let sigma = median(
            valid
                .iter()
                .map(|&i| f64::from(r.thickness_sigma_nm[i]))
                .collect(),
        );
        let z = median(
            valid
                .iter()
                .map(|&i| {
                    f64::from(
                        (r.thickness_nm[i] - truth.thickness_nm[i]).abs() / r.thickness_sigma_nm[i],
                    )
                })
                .collect(),
        );
        eprintln!("noise {noise} %: median sigma {sigma:.3} nm, median |error| / sigma {z:.2}");
        assert!(
            (0.45..=0.95).contains(&z),
            "noise {noise} %: median |error| / sigma {z}"
        );
        medians.push(sigma);
    }
    let ratio = medians[1] / medians[0];
    assert!(
        (3.5..=4.5).contains(&ratio),
        "sigma at 2 % over 0.5 %: {ratio}"
    );
}

/// The sigma above which a pixel is flagged `imprecise`.
fn flags_limit() -> f64 {
    filmscope_core::solve::shard::MAX_THICKNESS_SIGMA_NM
}
