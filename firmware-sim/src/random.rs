//! Random coating scenes (`filmscope eval --random`): a film of a library material
//! ([`materials::NAMES`]) on a constant-index substrate, with a thickness map, a rig and a
//! sensor drawn from fixed ranges, built as scene-file text and loaded through
//! [`Scene::from_toml`], so every drawn scene is validated like a file.
//!
//! [`draw`] is deterministic: the same `(seed, i)` gives the same scene on every machine.
//! What is drawn, per scene:
//!
//! - the material, uniformly from the library;
//! - the substrate index, uniform in [`SUBSTRATE_INDEX`], redrawn while within
//!   [`MIN_INDEX_GAP`] of the film's n at 550 nm;
//! - the base thickness, log-uniform in [`BASE_THICKNESS_NM`], with a linear gradient, up to
//!   four random bumps and, one time in three, a step;
//! - 3 to 7 distinct stage angles in [`ANGLE_DEG`], at least [`MIN_ANGLE_GAP_DEG`] apart, in
//!   rising order or (one time in three) shuffled;
//! - bands from a start in [`BAND_START_NM`] to a stop in [`BAND_STOP_NM`] at a step in
//!   [`BAND_STEP_NM`], and one FWHM in [`FWHM_NM`];
//! - the polarisation (s, p or unpolarized);
//! - the sensor model: the default raw counts with averaged white and dark references, or
//!   Gaussian reflectance noise in [`NOISE_PERCENT`] written as float reflectance
//!   ([`RandomScene::float_reflectance`]);
//! - a sensor of [`WIDTH`] by [`HEIGHT`] pixels;
//! - how a capture of it is written: interleave and byte order.
//!
//! When the thickness map leaves the estimator's default search range (50-2000 nm), the
//! scene widens `[search] thickness_range_nm` to cover it, as a user would.

use filmscope_core::optics::materials;

use crate::rng::Rng;
use crate::scene::Scene;

/// Substrate indices drawn (uniform).
pub const SUBSTRATE_INDEX: [f64; 2] = [1.45, 1.8];
/// The substrate is redrawn while closer than this to the film's n at 550 nm.
pub const MIN_INDEX_GAP: f64 = 0.08;
/// Base film thickness, nm (log-uniform).
pub const BASE_THICKNESS_NM: [f64; 2] = [60.0, 2000.0];
/// Stage angles, degrees.
pub const ANGLE_DEG: [f64; 2] = [0.0, 70.0];
/// Smallest gap between two stage angles, degrees.
pub const MIN_ANGLE_GAP_DEG: f64 = 5.0;
/// Number of stage angles (inclusive).
pub const ANGLE_COUNT: [usize; 2] = [3, 7];
/// First band centre, nm (whole nm).
pub const BAND_START_NM: [f64; 2] = [380.0, 450.0];
/// Last band centre at most this, nm (whole nm).
pub const BAND_STOP_NM: [f64; 2] = [700.0, 760.0];
/// Band step, nm (in half nm).
pub const BAND_STEP_NM: [f64; 2] = [1.0, 5.0];
/// Passband FWHM, nm.
pub const FWHM_NM: [f64; 2] = [2.0, 12.0];
/// Reflectance noise of the float scenes, percent of a perfect white.
pub const NOISE_PERCENT: [f64; 2] = [0.1, 0.6];
/// Sensor width, pixels (inclusive).
pub const WIDTH: [usize; 2] = [24, 48];
/// Sensor height, pixels (inclusive).
pub const HEIGHT: [usize; 2] = [16, 32];
/// The estimator's default thickness search range, nm: a map leaving it gets a `[search]`.
pub const DEFAULT_THICKNESS_RANGE_NM: [f64; 2] = [50.0, 2000.0];

/// The order of the values in a written cube (ENVI `interleave`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CubeInterleave {
    /// Band sequential.
    Bsq,
    /// Band interleaved by line.
    Bil,
    /// Band interleaved by pixel.
    Bip,
}

impl CubeInterleave {
    /// The ENVI name: `bsq`, `bil` or `bip`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Bsq => "bsq",
            Self::Bil => "bil",
            Self::Bip => "bip",
        }
    }
}

/// A drawn scene and how to write its capture.
#[derive(Clone, Debug)]
pub struct RandomScene {
    /// The scene, loaded from [`RandomScene::toml`].
    pub scene: Scene,
    /// The scene file's text (`filmscope eval` and `simulate` take it as a file).
    pub toml: String,
    /// The film's material, one of [`materials::NAMES`].
    pub material: &'static str,
    /// Base thickness of the map, nm (before gradient, bumps and step).
    pub base_thickness_nm: f64,
    /// True when the map has a step.
    pub has_step: bool,
    /// True: the sensor has `reflectance_noise_percent` and its capture is written as
    /// float32 reflectance; false: the default raw counts with white and dark references.
    pub float_reflectance: bool,
    /// Interleave of the written cubes.
    pub interleave: CubeInterleave,
    /// True: the cubes are written most significant byte first (`byte order = 1`).
    pub big_endian: bool,
}

/// Uniform in `[lo, hi)`.
fn uniform(rng: &mut Rng, [lo, hi]: [f64; 2]) -> f64 {
    lo + (hi - lo) * rng.uniform()
}

/// Uniform integer in `lo..=hi`.
fn integer(rng: &mut Rng, [lo, hi]: [usize; 2]) -> usize {
    lo + (rng.next_u64() % (hi - lo + 1) as u64) as usize
}

/// `x` rounded to a multiple of `1 / per_unit` (divided last, so that 61.9 prints as
/// 61.9 and not 61.900000000000006).
fn round_to(x: f64, per_unit: f64) -> f64 {
    (x * per_unit).round() / per_unit
}

/// A base thickness log-uniform in `[lo, hi]` (to 0.1 nm) and a linear gradient of up to
/// `share` of it along each axis.
fn thickness_draw(rng: &mut Rng, [lo, hi]: [f64; 2], share: f64) -> (f64, [f64; 2]) {
    let base = round_to(
        (lo.ln() + (hi.ln() - lo.ln()) * rng.uniform())
            .exp()
            .clamp(lo, hi),
        10.0,
    );
    let gradient = [
        round_to(base * uniform(rng, [-share, share]), 10.0),
        round_to(base * uniform(rng, [-share, share]), 10.0),
    ];
    (base, gradient)
}

/// Scene `i` of the random set `seed`.
pub fn draw(seed: u64, i: usize) -> RandomScene {
    draw_as(seed, i, false)
}

/// Reflectance noise of the realistic scenes, percent of a perfect white (averaged frames of
/// a good camera).
pub const REALISTIC_NOISE_PERCENT: [f64; 2] = [0.01, 0.06];
/// Each imperfection is drawn into a realistic scene with this probability.
pub const IMPERFECTION_CHANCE: f64 = 0.7;
/// A realistic scene has a bare back face its capture does not declare with this
/// probability.
pub const UNDECLARED_BACK_FACE_CHANCE: f64 = 0.15;
/// A realistic scene without an undeclared back face has a bare back face its capture
/// declares (`sample.back_face = "bare"`) with this probability.
pub const DECLARED_BACK_FACE_CHANCE: f64 = 0.15;

/// Scene `i` of the random set `seed` as a real sample on a real rig measures it
/// (`eval --random --realistic`): the same film, rig and sensor size as [`draw`]'s, written as
/// float reflectance with a good camera's low noise ([`REALISTIC_NOISE_PERCENT`]), and each
/// of these drawn with [`IMPERFECTION_CHANCE`] ([`crate::imperfect::Imperfections`]): film
/// absorption (k 0.001-0.008 at 450 nm with an Urbach tail of 60-120 nm), a stage offset
/// (+-0.4 deg), a wavelength shift (+-0.5 nm), flare (up to 0.3 % of the white), polariser
/// leak (0.5-2 % of the other polarisation, s or p light), side lobes (1-4 % of the light from
/// a band ten times wider); a bare back face the capture does not declare with
/// [`UNDECLARED_BACK_FACE_CHANCE`], else one it declares with [`DECLARED_BACK_FACE_CHANCE`].
pub fn draw_realistic(seed: u64, i: usize) -> RandomScene {
    draw_as(seed, i, true)
}

/// Base film thickness of the thick-film scenes, nm (log-uniform).
pub const THICK_BASE_THICKNESS_NM: [f64; 2] = [40.0, 5000.0];
/// Substrates of the thick-film scenes: dispersive library materials (glass, fused silica,
/// polymers, sapphire).
pub const THICK_SUBSTRATES: [&str; 5] = ["bk7", "sio2", "pmma", "polycarbonate", "al2o3"];

/// Which random set a scene belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Draw {
    /// [`draw`].
    Plain,
    /// [`draw_realistic`].
    Realistic,
    /// [`draw_thick`].
    Thick,
}

impl Draw {
    /// The set's name in scene names and closing lines: `random`, `realistic`, `thick`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Plain => "random",
            Self::Realistic => "realistic",
            Self::Thick => "thick",
        }
    }
}

/// Scene `i` of the thick-film set `seed` (`eval --random --thick`): [`draw`]'s rig and
/// sensor with the base thickness log-uniform in [`THICK_BASE_THICKNESS_NM`], two angles, a
/// dispersive substrate from [`THICK_SUBSTRATES`] and no `[search]` range: the estimator's
/// default range must reach the film.
pub fn draw_thick(seed: u64, i: usize) -> RandomScene {
    draw_kind(Draw::Thick, seed, i)
}

/// Scene `i` of set `seed` of the kind `kind`.
pub fn draw_kind(kind: Draw, seed: u64, i: usize) -> RandomScene {
    match kind {
        Draw::Plain => draw_as(seed, i, false),
        Draw::Realistic => draw_as(seed, i, true),
        Draw::Thick => draw_thick_as(seed, i),
    }
}

/// [`draw_thick`].
fn draw_thick_as(seed: u64, i: usize) -> RandomScene {
    let mut rng = Rng::from_words(&[seed, i as u64, 0x7B1C_F11D]);
    let names = materials::names();
    let material = names[integer(&mut rng, [0, names.len() - 1])];
    let film_n = materials::by_name(material)
        .map(|d| d.index_at(550.0))
        .unwrap_or(1.5);
    let substrate = loop {
        let s = THICK_SUBSTRATES[integer(&mut rng, [0, THICK_SUBSTRATES.len() - 1])];
        let n = materials::by_name(s).map_or(1.5, |d| d.index_at(550.0));
        if (n - film_n).abs() >= MIN_INDEX_GAP {
            break s;
        }
    };
    let (base, gradient) = thickness_draw(&mut rng, THICK_BASE_THICKNESS_NM, 0.1);
    let a0 = round_to(uniform(&mut rng, [0.0, 30.0]), 2.0);
    let a1 = round_to(a0 + uniform(&mut rng, [15.0, 40.0]), 2.0);
    let start = uniform(&mut rng, BAND_START_NM).round();
    let stop = uniform(&mut rng, BAND_STOP_NM).round();
    let step_nm = round_to(uniform(&mut rng, BAND_STEP_NM), 2.0);
    let fwhm = round_to(uniform(&mut rng, FWHM_NM), 10.0);
    let polarization = ["s", "p", "unpolarized"][integer(&mut rng, [0, 2])];
    let noise = round_to(uniform(&mut rng, NOISE_PERCENT), 100.0);
    let width = integer(&mut rng, WIDTH);
    let height = integer(&mut rng, HEIGHT);
    let big_endian = rng.uniform() < 0.5;
    let scene_seed = rng.next_u64() >> 16;
    let name = format!("thick-{seed}-{i}");
    let toml = format!(
        "name = {name:?}\n\
         description = \"{material} {base:?} nm on {substrate}\"\n\
         seed = {scene_seed}\n\
         polarization = {polarization:?}\n\
         \n\
         [film.dispersion]\n\
         model = \"material\"\n\
         name = {material:?}\n\
         \n\
         [film.thickness]\n\
         base_nm = {base:?}\n\
         gradient_nm = [{:?}, {:?}]\n\
         \n\
         [substrate.dispersion]\n\
         model = \"material\"\n\
         name = {substrate:?}\n\
         \n\
         [rig]\n\
         angles_deg = [{a0:?}, {a1:?}]\n\
         bands_nm = [{start:?}, {stop:?}, {step_nm:?}]\n\
         fwhm_nm = {fwhm:?}\n\
         \n\
         [sensor]\n\
         width = {width}\n\
         height = {height}\n\
         reflectance_noise_percent = {noise:?}\n",
        gradient[0], gradient[1],
    );
    let scene = Scene::from_toml(&toml, &name)
        .unwrap_or_else(|e| panic!("a drawn scene is always valid: {e}\n{toml}"));
    RandomScene {
        scene,
        toml,
        material,
        base_thickness_nm: base,
        has_step: false,
        float_reflectance: true,
        interleave: CubeInterleave::Bsq,
        big_endian,
    }
}

/// [`draw`], or [`draw_realistic`].
fn draw_as(seed: u64, i: usize, realistic: bool) -> RandomScene {
    let mut rng = Rng::from_words(&[seed, i as u64, 0x7A4D_5CE7]);
    let (material, substrate) = film_and_substrate(&mut rng);
    let thickness = ThicknessTable::draw(&mut rng);
    let rig = rig_table(&mut rng);
    let polarization = ["s", "p", "unpolarized"][integer(&mut rng, [0, 2])];
    let float_reflectance = rng.uniform() < 0.5;
    let noise = round_to(uniform(&mut rng, NOISE_PERCENT), 100.0);
    let width = integer(&mut rng, WIDTH);
    let height = integer(&mut rng, HEIGHT);
    let interleave = [
        CubeInterleave::Bsq,
        CubeInterleave::Bil,
        CubeInterleave::Bip,
    ][integer(&mut rng, [0, 2])];
    let big_endian = rng.uniform() < 0.5;
    let scene_seed = rng.next_u64() >> 16;
    let name = if realistic {
        format!("realistic-{seed}-{i}")
    } else {
        format!("random-{seed}-{i}")
    };
    let (float_reflectance, noise, imperfections) = if realistic {
        let mut more = Rng::from_words(&[seed, i as u64, 0x1DEA_1E57]);
        let noise = round_to(uniform(&mut more, REALISTIC_NOISE_PERCENT), 1000.0);
        (true, noise, imperfections_toml(&mut more, polarization))
    } else {
        (float_reflectance, noise, (String::new(), false))
    };
    let (imperfections, declared_back_face) = imperfections;
    let back_face_line = if declared_back_face {
        "back_face = \"bare\"\n"
    } else {
        ""
    };
    let noise_line = if float_reflectance {
        format!("reflectance_noise_percent = {noise:?}\n")
    } else {
        String::new()
    };
    let base = thickness.base;
    let toml = format!(
        "name = {name:?}\n\
         description = \"{material} {base:?} nm on n = {substrate:?}\"\n\
         seed = {scene_seed}\n\
         polarization = {polarization:?}\n\
         \n\
         [film.dispersion]\n\
         model = \"material\"\n\
         name = {material:?}\n\
         \n\
         [film.thickness]\n\
         {}\
         \n\
         [substrate]\n\
         index = {substrate:?}\n\
         {back_face_line}\
         \n\
         [rig]\n\
         {rig}\
         \n\
         [sensor]\n\
         width = {width}\n\
         height = {height}\n\
         {noise_line}         {imperfections}",
        thickness.table,
    );
    let (scene, toml) = with_search_range(toml, &name);
    RandomScene {
        scene,
        toml,
        material,
        base_thickness_nm: base,
        has_step: thickness.has_step,
        float_reflectance,
        interleave,
        big_endian,
    }
}

/// The film's material, uniform from the library, and the substrate's index, redrawn while
/// within [`MIN_INDEX_GAP`] of the film's n at 550 nm.
fn film_and_substrate(rng: &mut Rng) -> (&'static str, f64) {
    let names = materials::names();
    let material = names[integer(rng, [0, names.len() - 1])];
    let film_n = materials::by_name(material)
        .map(|d| d.index_at(550.0))
        .unwrap_or(1.5);
    let substrate = loop {
        let n = round_to(uniform(rng, SUBSTRATE_INDEX), 1000.0);
        if (n - film_n).abs() >= MIN_INDEX_GAP && n < SUBSTRATE_INDEX[1] {
            break n;
        }
    };
    (material, substrate)
}

/// A drawn `[film.thickness]` table and what [`RandomScene`] says of it.
struct ThicknessTable {
    /// Base thickness, nm.
    base: f64,
    /// True when the map has a step.
    has_step: bool,
    /// The table's lines, each ending in a newline.
    table: String,
}

impl ThicknessTable {
    /// A base thickness and gradient ([`thickness_draw`]), up to four random bumps and,
    /// one time in three, a step.
    fn draw(rng: &mut Rng) -> Self {
        let (base, gradient) = thickness_draw(rng, BASE_THICKNESS_NM, 0.15);
        let bumps = integer(rng, [0, 4]);
        let bump_height = round_to(1.0 + base * uniform(rng, [0.02, 0.06]), 10.0);
        let bump_sigma = round_to(uniform(rng, [0.08, 0.25]), 100.0);
        let has_step = rng.uniform() < 1.0 / 3.0;
        let step = if has_step {
            let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
            let x = round_to(uniform(rng, [0.3, 0.7]), 100.0);
            let h = round_to(sign * base * uniform(rng, [0.03, 0.12]), 10.0);
            format!("steps = [{{ x = {x:?}, height_nm = {h:?} }}]\n")
        } else {
            String::new()
        };
        let table = format!(
            "base_nm = {base:?}\n\
             gradient_nm = [{:?}, {:?}]\n\
             random_bumps = {{ count = {bumps}, height_nm = {bump_height:?}, sigma = {bump_sigma:?} }}\n\
             {step}",
            gradient[0], gradient[1],
        );
        Self {
            base,
            has_step,
            table,
        }
    }
}

/// A drawn `[rig]` table's lines: 3 to 7 distinct stage angles at least
/// [`MIN_ANGLE_GAP_DEG`] apart, rising or (one time in three) shuffled, the bands and the
/// FWHM.
fn rig_table(rng: &mut Rng) -> String {
    let n_angles = integer(rng, ANGLE_COUNT);
    let mut angles: Vec<f64> = Vec::with_capacity(n_angles);
    while angles.len() < n_angles {
        let a = round_to(uniform(rng, ANGLE_DEG), 2.0);
        if angles.iter().all(|b| (a - b).abs() >= MIN_ANGLE_GAP_DEG) {
            angles.push(a);
        }
    }
    angles.sort_by(f64::total_cmp);
    if rng.uniform() < 1.0 / 3.0 {
        for k in (1..angles.len()).rev() {
            angles.swap(k, integer(rng, [0, k]));
        }
    }
    let start = uniform(rng, BAND_START_NM).round();
    let stop = uniform(rng, BAND_STOP_NM).round();
    let step_nm = round_to(uniform(rng, BAND_STEP_NM), 2.0);
    let fwhm = round_to(uniform(rng, FWHM_NM), 10.0);
    let angle_list: Vec<String> = angles.iter().map(|a| format!("{a:?}")).collect();
    format!(
        "angles_deg = [{}]\n\
         bands_nm = [{start:?}, {stop:?}, {step_nm:?}]\n\
         fwhm_nm = {fwhm:?}\n",
        angle_list.join(", "),
    )
}

/// The scene `toml` describes, loaded as `name`; when its thickness map leaves the
/// estimator's default search range, with a `[search]` table added to `toml` that covers it.
fn with_search_range(mut toml: String, name: &str) -> (Scene, String) {
    let parse = |text: &str| {
        Scene::from_toml(text, name)
            .unwrap_or_else(|e| panic!("a drawn scene is always valid: {e}\n{text}"))
    };
    let mut scene = parse(&toml);
    let (min, max) = scene
        .thickness_nm
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), &t| {
            (lo.min(f64::from(t)), hi.max(f64::from(t)))
        });
    let [dlo, dhi] = DEFAULT_THICKNESS_RANGE_NM;
    if min < dlo || max > dhi {
        let lo = dlo.min((0.8 * min).floor()).max(1.0);
        let hi = dhi.max((1.1 * max).ceil());
        toml.push_str(&format!(
            "\n[search]\nthickness_range_nm = [{lo:?}, {hi:?}]\n"
        ));
        scene = parse(&toml);
    }
    (scene, toml)
}

/// A realistic scene's `[imperfections]` table, each effect drawn with
/// [`IMPERFECTION_CHANCE`] at its size ([`draw_realistic`]), empty when none is drawn; and
/// whether the scene has a declared bare back face.
fn imperfections_toml(rng: &mut Rng, polarization: &str) -> (String, bool) {
    let mut lines = Vec::new();
    let mut maybe = |rng: &mut Rng, line: &dyn Fn(&mut Rng) -> String| {
        if rng.uniform() < IMPERFECTION_CHANCE {
            lines.push(line(rng));
        }
    };
    maybe(rng, &|r| {
        format!(
            "film_k = {:?}\nfilm_k_tail_nm = {:?}",
            round_to(uniform(r, [0.001, 0.008]), 10000.0),
            uniform(r, [60.0, 120.0]).round()
        )
    });
    maybe(rng, &|r| {
        format!(
            "stage_offset_deg = {:?}",
            round_to(uniform(r, [-0.4, 0.4]), 100.0)
        )
    });
    maybe(rng, &|r| {
        format!(
            "wavelength_shift_nm = {:?}",
            round_to(uniform(r, [-0.5, 0.5]), 100.0)
        )
    });
    maybe(rng, &|r| {
        format!("flare = {:?}", round_to(uniform(r, [0.0, 0.003]), 10000.0))
    });
    if polarization != "unpolarized" {
        maybe(rng, &|r| {
            format!(
                "polariser_leak = {:?}",
                round_to(uniform(r, [0.005, 0.02]), 1000.0)
            )
        });
    }
    maybe(rng, &|r| {
        format!(
            "side_lobes = {:?}",
            round_to(uniform(r, [0.01, 0.04]), 1000.0)
        )
    });
    let mut declared = false;
    if rng.uniform() < UNDECLARED_BACK_FACE_CHANCE {
        lines.push("back_face = \"bare\"".to_owned());
    } else {
        declared = rng.uniform() < DECLARED_BACK_FACE_CHANCE;
    }
    if lines.is_empty() {
        return (String::new(), declared);
    }
    (
        format!("\n[imperfections]\n{}\n", lines.join("\n")),
        declared,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same `(seed, i)` gives the same scene; another seed or index another one.
    #[test]
    fn draw_is_deterministic() {
        for i in 0..20 {
            let (a, b) = (draw(7, i), draw(7, i));
            assert_eq!(a.toml, b.toml);
            assert_eq!(a.scene.thickness_nm, b.scene.thickness_nm);
            assert_eq!(
                (a.interleave, a.big_endian, a.float_reflectance),
                (b.interleave, b.big_endian, b.float_reflectance)
            );
            assert_ne!(a.toml, draw(8, i).toml);
            assert_ne!(a.toml, draw(7, i + 1).toml);
        }
    }

    /// Over 200 draws every quantity stays in its range, and every choice is made both ways.
    #[test]
    fn draws_respect_every_range() {
        let mut materials_seen = std::collections::HashSet::new();
        let (mut floats, mut bigs, mut steps, mut shuffled) = (0, 0, 0, 0);
        let mut interleaves = std::collections::HashSet::new();
        let mut polarizations = std::collections::HashSet::new();
        let n = 200;
        for i in 0..n {
            let r = draw(1, i);
            let s = &r.scene;
            materials_seen.insert(r.material);
            let film = s.stack.film.index_at(550.0);
            assert_eq!(
                Some(s.stack.film),
                materials::by_name(r.material),
                "{}",
                r.toml
            );
            let sub = s.stack.substrate.index_at(550.0);
            assert!((SUBSTRATE_INDEX[0]..SUBSTRATE_INDEX[1]).contains(&sub));
            assert!((sub - film).abs() >= MIN_INDEX_GAP, "{}", r.toml);
            assert!((BASE_THICKNESS_NM[0]..=BASE_THICKNESS_NM[1]).contains(&r.base_thickness_nm));
            assert!(s.thickness_nm.iter().all(|&t| t > 0.0));
            let (tmin, tmax) = s
                .thickness_nm
                .iter()
                .fold((f32::MAX, 0.0f32), |(a, b), &t| (a.min(t), b.max(t)));
            let [lo, hi] = s.thickness_range_nm.unwrap_or(DEFAULT_THICKNESS_RANGE_NM);
            assert!(
                f64::from(tmin) >= lo && f64::from(tmax) <= hi,
                "{tmin}..{tmax} outside the search range {lo}..{hi}"
            );
            let a = &s.angles_deg;
            assert!((ANGLE_COUNT[0]..=ANGLE_COUNT[1]).contains(&a.len()));
            for (k, x) in a.iter().enumerate() {
                assert!((ANGLE_DEG[0]..=ANGLE_DEG[1]).contains(x), "{x}");
                for y in &a[k + 1..] {
                    assert!((x - y).abs() >= MIN_ANGLE_GAP_DEG, "{a:?}");
                }
            }
            if a.windows(2).any(|w| w[1] < w[0]) {
                shuffled += 1;
            }
            let b = &s.bands_nm;
            assert!((BAND_START_NM[0]..=BAND_START_NM[1]).contains(&b[0]));
            let last = b[b.len() - 1];
            assert!(last <= BAND_STOP_NM[1]);
            assert!(last > BAND_STOP_NM[0] - BAND_STEP_NM[1]);
            let step = b[1] - b[0];
            assert!(
                (BAND_STEP_NM[0] - 1e-9..=BAND_STEP_NM[1] + 1e-9).contains(&step),
                "{step}"
            );
            assert!((FWHM_NM[0]..=FWHM_NM[1]).contains(&s.fwhm_nm));
            assert!((WIDTH[0]..=WIDTH[1]).contains(&s.sensor.width));
            assert!((HEIGHT[0]..=HEIGHT[1]).contains(&s.sensor.height));
            match s.sensor.reflectance_noise_percent {
                Some(p) => {
                    assert!(r.float_reflectance);
                    assert!((NOISE_PERCENT[0]..=NOISE_PERCENT[1]).contains(&p));
                    floats += 1;
                }
                None => assert!(!r.float_reflectance),
            }
            polarizations.insert(s.stack.polarization.name());
            interleaves.insert(r.interleave);
            bigs += usize::from(r.big_endian);
            steps += usize::from(r.has_step);
        }
        assert_eq!(materials_seen.len(), materials::NAMES.len());
        assert_eq!(polarizations.len(), 3);
        assert_eq!(interleaves.len(), 3);
        for (what, count) in [
            ("float", floats),
            ("big endian", bigs),
            ("step", steps),
            ("shuffled", shuffled),
        ] {
            assert!(count > n / 6 && count < n - n / 6, "{what}: {count} of {n}");
        }
    }
}
