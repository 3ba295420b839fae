//! Scene files: the film, the rig and the sensor that the software camera renders.
//!
//! A scene is a TOML file (see `config/scenes/`). Everything is validated on load and a bad
//! file gets one line naming the file and the problem.

use std::path::{Path, PathBuf};

use filmscope_core::optics::{
    materials, BackFace, Dispersion, FieldOfView, FilmStack, Passband, Polarization,
};
use serde::Deserialize;

use crate::rng::Rng;

/// A scene file that cannot be used, with the file it came from.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {problem}")]
pub struct SceneError {
    /// The scene file.
    pub path: PathBuf,
    /// What is wrong, in one line.
    pub problem: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    name: Option<String>,
    description: Option<String>,
    seed: Option<u64>,
    ambient_index: Option<f64>,
    polarization: Option<String>,
    film: FilmFile,
    substrate: SubstrateFile,
    rig: RigFile,
    sensor: Option<SensorFile>,
    search: Option<SearchFile>,
    imperfections: Option<ImperfectionsFile>,
}

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct ImperfectionsFile {
    film_k: Option<f64>,
    film_k_tail_nm: Option<f64>,
    stage_offset_deg: Option<f64>,
    wavelength_shift_nm: Option<f64>,
    flare: Option<f64>,
    polariser_leak: Option<f64>,
    side_lobes: Option<f64>,
    back_face: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FilmFile {
    index: Option<f64>,
    dispersion: Option<DispersionFile>,
    thickness: ThicknessFile,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, tag = "model", rename_all = "lowercase")]
enum DispersionFile {
    Cauchy {
        a: f64,
        b_um2: f64,
        #[serde(default)]
        c_um4: f64,
    },
    Sellmeier {
        #[serde(default = "one")]
        a: f64,
        b: Vec<f64>,
        c_um: Vec<f64>,
    },
    Material {
        name: String,
    },
}

fn one() -> f64 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ThicknessFile {
    base_nm: f64,
    /// Total change across the image, `[left to right, top to bottom]`.
    #[serde(default)]
    gradient_nm: [f64; 2],
    #[serde(default)]
    random_bumps: Option<RandomBumps>,
    #[serde(default)]
    bumps: Vec<Bump>,
    #[serde(default)]
    steps: Vec<Step>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RandomBumps {
    count: usize,
    height_nm: f64,
    sigma: f64,
}

#[derive(Debug, Deserialize, Clone, Copy)]
#[serde(deny_unknown_fields)]
struct Bump {
    x: f64,
    y: f64,
    sigma: f64,
    height_nm: f64,
}

#[derive(Debug, Deserialize, Clone, Copy)]
#[serde(deny_unknown_fields)]
struct Step {
    x: f64,
    height_nm: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SubstrateFile {
    index: Option<f64>,
    /// A dispersive substrate, in the film's forms (`cauchy`, `sellmeier`, `material`).
    dispersion: Option<DispersionFile>,
    /// `"bare"`: the back face reflects and the capture says so (`sample.back_face`).
    back_face: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigFile {
    angles_deg: Vec<f64>,
    bands_nm: [f64; 3],
    fwhm_nm: f64,
    /// The lens's horizontal field of view, degrees (absent: every column sees the stage
    /// angle).
    horizontal_fov_deg: Option<f64>,
}

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct SensorFile {
    width: Option<usize>,
    height: Option<usize>,
    bit_depth: Option<u32>,
    white_counts: Option<f64>,
    gain_e_per_count: Option<f64>,
    read_noise_counts: Option<f64>,
    dark_counts: Option<f64>,
    white_frames: Option<u32>,
    vignetting: Option<f64>,
    dead_pixels: Option<usize>,
    hot_pixels: Option<usize>,
    reflectance_noise_percent: Option<f64>,
    lamp_blue_ratio: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SearchFile {
    index_range: Option<[f64; 2]>,
    thickness_range_nm: Option<[f64; 2]>,
}

/// The simulated sensor.
#[derive(Clone, Debug, PartialEq)]
pub struct Sensor {
    /// Pixels per row.
    pub width: usize,
    /// Rows per frame.
    pub height: usize,
    /// ADC bits (12 for the paper's camera): counts saturate at `2^bits - 1`.
    pub bit_depth: u32,
    /// Mean counts above dark that a perfect white gives at mid-band in the image centre.
    pub white_counts: f64,
    /// Electrons per count: sets the shot noise.
    pub gain_e_per_count: f64,
    /// Read noise, counts (1 sigma).
    pub read_noise_counts: f64,
    /// Dark level, counts.
    pub dark_counts: f64,
    /// Frames averaged into the white and dark references.
    pub white_frames: u32,
    /// Fractional illumination fall-off at the image corners (0 = none).
    pub vignetting: f64,
    /// Pixels that read dark-level always.
    pub dead_pixels: usize,
    /// Pixels that read saturated always.
    pub hot_pixels: usize,
    /// Replaces the shot and read noise, if given: every sample's reflectance gets additive
    /// Gaussian noise of this standard deviation, in percent of a perfect white's (so 1.0
    /// is 0.01 in reflectance, whatever the pixel's signal), and the white and dark
    /// references are exact. 0 leaves only the ADC's rounding of the sample counts
    /// (1 / sqrt(12) count).
    pub reflectance_noise_percent: Option<f64>,
    /// The lamp x filter throughput at the band's blue end over its red end, in `(0, 1]`
    /// (default 0.6: a halogen lamp through an LCTF; 0.2 is a lamp five times dimmer in the
    /// blue, whose shot noise there is over twice the red's).
    pub lamp_blue_ratio: f64,
}

impl Sensor {
    /// The largest count the ADC gives.
    pub fn saturation_counts(&self) -> f64 {
        f64::from((1u32 << self.bit_depth) - 1)
    }

    /// Mean counts a perfect white gives where the light is brightest (the band's red end,
    /// the image centre), dark included: below [`Sensor::saturation_counts`] in a valid
    /// scene, so that the white reference is never clipped.
    pub fn peak_white_counts(&self) -> f64 {
        self.dark_counts + self.white_counts * self.throughput(1.0)
    }

    /// Lamp x filter throughput at `position` across the band (0 its blue end, 1 its red
    /// end), relative to mid-band, rising linearly from the blue to the red by
    /// [`Sensor::lamp_blue_ratio`] (the default's 0.75 at the blue end, 1.25 at the red).
    pub fn throughput(&self, position: f64) -> f64 {
        let r = self.lamp_blue_ratio;
        (r + (1.0 - r) * position) / (0.5 * (1.0 + r))
    }
}

/// A validated scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Short name (file stem unless given).
    pub name: String,
    /// Free text.
    pub description: String,
    /// Seed for the thickness map and the noise.
    pub seed: u64,
    /// The film stack and the polarisation the camera sees.
    pub stack: FilmStack,
    /// Stage angles, degrees, in the order the sweep visits them.
    pub angles_deg: Vec<f64>,
    /// LCTF band centres, nm.
    pub bands_nm: Vec<f64>,
    /// LCTF passband FWHM, nm (the same for every band).
    pub fwhm_nm: f64,
    /// The lens's horizontal field of view (`[rig] horizontal_fov_deg`): column `c` sees the
    /// stage angle plus [`FieldOfView::column_offset_deg`] (geometry and sign convention
    /// there). `None`: every column sees the stage angle (a narrow field of view).
    pub field_of_view: Option<FieldOfView>,
    /// The sensor.
    pub sensor: Sensor,
    /// Film thickness per pixel, row-major, nm.
    pub thickness_nm: Vec<f32>,
    /// Search bounds written into the capture, if the scene gives them.
    pub index_range: Option<[f64; 2]>,
    /// Search bounds written into the capture, if the scene gives them.
    pub thickness_range_nm: Option<[f64; 2]>,
    /// What the real sample and rig add to the ideal film (`[imperfections]`; none by
    /// default). The capture declares the ideal: the estimator is not told of them, except a
    /// back face the scene declares (`[substrate] back_face`, in `stack`).
    pub imperfections: crate::imperfect::Imperfections,
}

impl Scene {
    /// Loads and validates a scene file.
    pub fn load(path: &Path) -> Result<Self, SceneError> {
        Self::load_seeded(path, None)
    }

    /// Loads and validates a scene file, its `seed` (thickness bumps and noise) replaced by
    /// `seed` when given (`simulate --seed`, `eval --seed`).
    pub fn load_seeded(path: &Path, seed: Option<u64>) -> Result<Self, SceneError> {
        let err = |problem: String| SceneError {
            path: path.to_owned(),
            problem,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read: {e}")))?;
        let mut file: SceneFile = toml::from_str(&text)
            .map_err(|e| err(e.message().replace('\n', " ").trim().to_owned()))?;
        if seed.is_some() {
            file.seed = seed;
        }
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into());
        Self::from_file(file, stem).map_err(err)
    }

    /// Parses a scene from TOML text (for tests); `name` stands in for the file stem.
    pub fn from_toml(text: &str, name: &str) -> Result<Self, SceneError> {
        Self::from_toml_seeded(text, name, None)
    }

    /// [`Scene::from_toml`] with the scene's `seed` replaced by `seed` when given.
    pub fn from_toml_seeded(text: &str, name: &str, seed: Option<u64>) -> Result<Self, SceneError> {
        let err = |problem: String| SceneError {
            path: PathBuf::from(name),
            problem,
        };
        let mut file: SceneFile =
            toml::from_str(text).map_err(|e| err(e.message().replace('\n', " ")))?;
        if seed.is_some() {
            file.seed = seed;
        }
        Self::from_file(file, name.to_owned()).map_err(err)
    }

    fn from_file(mut f: SceneFile, stem: String) -> Result<Self, String> {
        let stack = film_stack(&mut f)?;
        let rig = f.rig;
        let bands_nm = rig.bands(&stack)?;
        let field_of_view = rig.field_of_view()?;
        let sensor = sensor(f.sensor.unwrap_or_default());
        check_sensor(&sensor)?;
        let seed = f.seed.unwrap_or(1);
        let thickness_nm = thickness_map(&f.film.thickness, sensor.width, sensor.height, seed)?;
        let (index_range, thickness_range_nm) = match f.search {
            Some(s) => (s.index_range, s.thickness_range_nm),
            None => (None, None),
        };
        let mut imperfections = match f.imperfections {
            None => crate::imperfect::Imperfections::default(),
            Some(m) => imperfections(m)?,
        };
        // A declared back face is rendered as an undeclared one is, by the rig model's own
        // optics ([`crate::imperfect`]), not by the estimator's.
        imperfections.bare_back_face |= stack.back_face == BackFace::Bare;
        // An absorbing film material (a tabulated nk entry) is rendered the same way.
        imperfections.film_material_k = bands_nm.iter().any(|&l| stack.film.extinction_at(l) > 0.0);
        if imperfections.any() && field_of_view.is_some() {
            return Err(
                "[imperfections], a bare back face and an absorbing film cannot go with [rig] horizontal_fov_deg"
                    .to_string(),
            );
        }
        Ok(Self {
            name: f.name.unwrap_or(stem),
            description: f.description.unwrap_or_default(),
            seed,
            stack,
            angles_deg: rig.angles_deg,
            bands_nm,
            fwhm_nm: rig.fwhm_nm,
            field_of_view,
            sensor,
            thickness_nm,
            index_range,
            thickness_range_nm,
            imperfections,
        })
    }

    /// The passband of band `b`.
    pub fn passband(&self, b: usize) -> Passband {
        Passband::gaussian(self.bands_nm[b], self.fwhm_nm)
    }

    /// The incidence angle column `col` sees when the stage is at `stage_deg`: the stage
    /// angle itself without a field of view.
    pub fn incidence_deg(&self, stage_deg: f64, col: usize) -> f64 {
        match self.field_of_view {
            Some(fov) => fov.incidence_deg(stage_deg, col, self.sensor.width),
            None => stage_deg,
        }
    }
}

/// The scene file's film stack (film, substrate, back face, ambient and polarisation), each
/// index checked at 550 nm. Takes the film's and the substrate's dispersions out of `f`.
fn film_stack(f: &mut SceneFile) -> Result<FilmStack, String> {
    let film = match (f.film.index, f.film.dispersion.take()) {
        (Some(n), None) => Dispersion::constant(n),
        (None, Some(d)) => dispersion(d, "[film.dispersion]")?,
        (Some(_), Some(_)) => return Err("[film] gives both `index` and `dispersion`".into()),
        (None, None) => return Err("[film] needs `index` or `dispersion`".into()),
    };
    let polarization = match f.polarization.as_deref() {
        None => Polarization::S,
        Some(p) => Polarization::from_name(p).ok_or_else(|| {
            format!("polarization must be \"s\", \"p\" or \"unpolarized\", not {p:?}")
        })?,
    };
    let substrate = match (f.substrate.index, f.substrate.dispersion.take()) {
        (Some(n), None) => Dispersion::constant(n),
        (None, Some(d)) => dispersion(d, "[substrate.dispersion]")?,
        (Some(_), Some(_)) => return Err("[substrate] gives both `index` and `dispersion`".into()),
        (None, None) => return Err("[substrate] needs `index` or `dispersion`".into()),
    };
    let back_face = match f.substrate.back_face.as_deref() {
        None => BackFace::None,
        Some(name) => BackFace::from_name(name)
            .ok_or_else(|| format!("[substrate] back_face = {name:?}: \"none\" or \"bare\""))?,
    };
    let stack = FilmStack {
        back_face,
        ambient_index: f.ambient_index.unwrap_or(1.0),
        film,
        substrate,
        polarization,
    };
    for (what, n) in [
        ("ambient_index", stack.ambient_index),
        ("substrate index at 550 nm", substrate.index_at(550.0)),
        ("film index at 550 nm", film.index_at(550.0)),
    ] {
        if !(n.is_finite() && (1.0..=5.0).contains(&n)) {
            return Err(format!("{what} {n} is outside 1..5"));
        }
    }
    Ok(stack)
}

impl RigFile {
    /// The band centres, after checking the angles, the band list, the passband and that
    /// the film and the substrate stay above the ambient index over the whole band.
    fn bands(&self, stack: &FilmStack) -> Result<Vec<f64>, String> {
        if self.angles_deg.is_empty() {
            return Err(format!(
                "[rig] angles_deg needs at least one angle, has {}",
                self.angles_deg.len()
            ));
        }
        for &a in &self.angles_deg {
            if !(a.is_finite() && (0.0..89.0).contains(&a)) {
                return Err(format!("[rig] angle {a} deg is outside 0..89"));
            }
        }
        let [start, stop, step] = self.bands_nm;
        if !(start > 0.0 && stop > start && step > 0.0 && (stop - start) / step <= 4096.0) {
            return Err(format!(
                "[rig] bands_nm = [start, stop, step] must be increasing with a positive step and at most 4096 bands, got {:?}",
                self.bands_nm
            ));
        }
        let n_bands = ((stop - start) / step + 1e-9).floor() as usize + 1;
        let bands_nm: Vec<f64> = (0..n_bands).map(|i| start + step * i as f64).collect();
        // Film and substrate above the ambient, finite, over the whole band (every nm).
        for (what, d) in [("[film]", &stack.film), ("[substrate]", &stack.substrate)] {
            let nm = (stop - start).ceil() as usize;
            for l in (0..=nm).map(|i| (start + i as f64).min(stop)) {
                let n = d.index_at(l);
                if !(n.is_finite() && n > stack.ambient_index) {
                    return Err(format!(
                        "{what} n({l:.1} nm) = {n:.4} is not a finite index above ambient_index {} over the band {start}-{stop} nm",
                        stack.ambient_index
                    ));
                }
            }
        }
        if !(self.fwhm_nm.is_finite() && self.fwhm_nm >= 0.0 && self.fwhm_nm < 100.0) {
            return Err(format!("[rig] fwhm_nm {} is outside 0..100", self.fwhm_nm));
        }
        Ok(bands_nm)
    }

    /// The lens's field of view, if given, checked to keep every angle's image edge below
    /// 89 degrees.
    fn field_of_view(&self) -> Result<Option<FieldOfView>, String> {
        let field_of_view = match self.horizontal_fov_deg {
            None => None,
            Some(f) => Some(
                FieldOfView::new(f)
                    .ok_or_else(|| format!("[rig] horizontal_fov_deg {f} is outside (0, 180)"))?,
            ),
        };
        if let Some(fov) = field_of_view {
            for &a in &self.angles_deg {
                let edge = a.abs() + 0.5 * fov.horizontal_deg();
                if edge >= 89.0 {
                    return Err(format!(
                        "[rig] angle {a} deg with a {} deg field of view reaches {edge} deg at the image edge (at most 89)",
                        fov.horizontal_deg()
                    ));
                }
            }
        }
        Ok(field_of_view)
    }
}

/// The sensor a `[sensor]` table describes, with the defaults for what it leaves out.
fn sensor(s: SensorFile) -> Sensor {
    Sensor {
        width: s.width.unwrap_or(96),
        height: s.height.unwrap_or(64),
        bit_depth: s.bit_depth.unwrap_or(12),
        white_counts: s.white_counts.unwrap_or(3000.0),
        gain_e_per_count: s.gain_e_per_count.unwrap_or(1.5),
        read_noise_counts: s.read_noise_counts.unwrap_or(2.0),
        dark_counts: s.dark_counts.unwrap_or(64.0),
        white_frames: s.white_frames.unwrap_or(16),
        vignetting: s.vignetting.unwrap_or(0.15),
        dead_pixels: s.dead_pixels.unwrap_or(0),
        hot_pixels: s.hot_pixels.unwrap_or(0),
        reflectance_noise_percent: s.reflectance_noise_percent,
        lamp_blue_ratio: s.lamp_blue_ratio.unwrap_or(0.6),
    }
}

/// Checks that the sensor can be simulated: its size, ADC, noise, vignetting, and a white
/// reference that does not clip.
fn check_sensor(sensor: &Sensor) -> Result<(), String> {
    if !(sensor.lamp_blue_ratio > 0.0 && sensor.lamp_blue_ratio <= 1.0) {
        return Err(format!(
            "[sensor] lamp_blue_ratio {} is outside (0, 1]",
            sensor.lamp_blue_ratio
        ));
    }
    if sensor.width == 0 || sensor.height == 0 || sensor.width * sensor.height > 1 << 24 {
        return Err(format!(
            "[sensor] {}x{} pixels: need 1..16M",
            sensor.width, sensor.height
        ));
    }
    if !(8..=16).contains(&sensor.bit_depth) {
        return Err(format!(
            "[sensor] bit_depth {} is outside 8..16",
            sensor.bit_depth
        ));
    }
    if !sensor.white_counts.is_finite() || sensor.white_counts <= 0.0 {
        return Err(format!(
            "[sensor] white_counts {} must be positive",
            sensor.white_counts
        ));
    }
    let peak = sensor.peak_white_counts();
    if !peak.is_finite() || peak >= sensor.saturation_counts() {
        return Err(format!(
            "[sensor] a perfect white reads {} counts at the band's red end (dark_counts {} \
             + white_counts {} x {}), at or above saturation ({}): the white reference \
             would clip; lower white_counts",
            peak,
            sensor.dark_counts,
            sensor.white_counts,
            sensor.throughput(1.0),
            sensor.saturation_counts()
        ));
    }
    if !(sensor.gain_e_per_count > 0.0
        && sensor.read_noise_counts >= 0.0
        && sensor.white_frames >= 1)
    {
        return Err(
            "[sensor] gain must be positive, read noise non-negative, white_frames >= 1".into(),
        );
    }
    if let Some(p) = sensor.reflectance_noise_percent {
        if !(p.is_finite() && (0.0..=100.0).contains(&p)) {
            return Err(format!(
                "[sensor] reflectance_noise_percent {p} is outside 0..100"
            ));
        }
    }
    if !(0.0..0.9).contains(&sensor.vignetting) {
        return Err(format!(
            "[sensor] vignetting {} is outside 0..0.9",
            sensor.vignetting
        ));
    }
    Ok(())
}

/// The imperfections an `[imperfections]` table asks for, checked.
fn imperfections(m: ImperfectionsFile) -> Result<crate::imperfect::Imperfections, String> {
    let bare = match m.back_face.as_deref().map(BackFace::from_name) {
        None => false,
        Some(Some(b)) => b == BackFace::Bare,
        Some(None) => {
            return Err(format!(
                "[imperfections] back_face = {:?}: \"none\" or \"bare\"",
                m.back_face.unwrap_or_default()
            ))
        }
    };
    let imp = crate::imperfect::Imperfections {
        film_k: m.film_k.unwrap_or(0.0),
        film_k_tail_nm: m.film_k_tail_nm.unwrap_or(0.0),
        stage_offset_deg: m.stage_offset_deg.unwrap_or(0.0),
        wavelength_shift_nm: m.wavelength_shift_nm.unwrap_or(0.0),
        flare: m.flare.unwrap_or(0.0),
        polariser_leak: m.polariser_leak.unwrap_or(0.0),
        side_lobes: m.side_lobes.unwrap_or(0.0),
        bare_back_face: bare,
        film_material_k: false,
    };
    imp.check().map_err(|e| e.to_string())?;
    Ok(imp)
}

fn dispersion(d: DispersionFile, what: &str) -> Result<Dispersion, String> {
    Ok(match d {
        DispersionFile::Cauchy { a, b_um2, c_um4 } => Dispersion::Cauchy { a, b_um2, c_um4 },
        DispersionFile::Sellmeier { a, b, c_um } => {
            if b.len() != c_um.len() || b.is_empty() || b.len() > 3 {
                return Err(format!(
                    "{what} sellmeier needs 1 to 3 `b` and as many `c_um`"
                ));
            }
            let mut bb = [0.0; 3];
            let mut cc = [0.0; 3];
            bb[..b.len()].copy_from_slice(&b);
            cc[..c_um.len()].copy_from_slice(&c_um);
            Dispersion::Sellmeier { a, b: bb, c_um: cc }
        }
        DispersionFile::Material { name } => materials::by_name(&name).ok_or_else(|| {
            format!(
                "{what} unknown material {name:?} (known: {}, and zns-debenham, mgf2-dodge, bk7, si)",
                materials::names().join(", ")
            )
        })?,
    })
}

/// Renders the thickness map: base + linear gradient + Gaussian bumps + steps, in nm.
fn thickness_map(t: &ThicknessFile, w: usize, h: usize, seed: u64) -> Result<Vec<f32>, String> {
    let mut bumps = t.bumps.clone();
    if let Some(r) = &t.random_bumps {
        if r.count > 64 {
            return Err("[film.thickness] random_bumps.count is at most 64".into());
        }
        let mut rng = Rng::from_words(&[seed, 0xB0B5]);
        for _ in 0..r.count {
            let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
            bumps.push(Bump {
                x: rng.uniform(),
                y: rng.uniform(),
                sigma: r.sigma * (0.6 + 0.8 * rng.uniform()),
                height_nm: sign * r.height_nm * (0.5 + 0.5 * rng.uniform()),
            });
        }
    }
    let mut map = Vec::with_capacity(w * h);
    for row in 0..h {
        for col in 0..w {
            let x = (col as f64 + 0.5) / w as f64;
            let y = (row as f64 + 0.5) / h as f64;
            let mut d = t.base_nm + t.gradient_nm[0] * (x - 0.5) + t.gradient_nm[1] * (y - 0.5);
            for b in &bumps {
                let r2 = (x - b.x).powi(2) + (y - b.y).powi(2);
                d += b.height_nm * (-0.5 * r2 / (b.sigma * b.sigma)).exp();
            }
            for s in &t.steps {
                if x >= s.x {
                    d += s.height_nm;
                }
            }
            if !(d.is_finite() && d >= 0.0) {
                return Err(format!(
                    "[film.thickness] thickness {d:.1} nm at pixel ({col}, {row}) is negative"
                ));
            }
            map.push(d as f32);
        }
    }
    Ok(map)
}
