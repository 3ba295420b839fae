//! The scenes lab measurements run on: a scene file, or the paper's first sample built into
//! the binary so `bench` and `chart` run from any folder; resized as a measurement needs.

use std::borrow::Cow;
use std::path::PathBuf;

use super::{LabError, Result};
use firmware_sim::Scene;

/// The paper's samples (name, scene file text), built in so `demo`, `bench` and `chart` run
/// from anywhere.
pub const PAPER_SCENES: [(&str, &str); 3] = [
    (
        "paper-sample1",
        include_str!("../../config/scenes/paper-sample1.toml"),
    ),
    (
        "paper-sample2",
        include_str!("../../config/scenes/paper-sample2.toml"),
    ),
    (
        "paper-sample3",
        include_str!("../../config/scenes/paper-sample3.toml"),
    ),
];

/// A scene as `bench`, `chart` and `soak` take it: a file (`--scene PATH`), or one built in.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SceneFile {
    /// A scene of `config/scenes/` built into the binary: its name and TOML text.
    Builtin(&'static str, &'static str),
    /// A scene file, read when the scene is made.
    Path(PathBuf),
}

impl SceneFile {
    /// `config/scenes/paper-sample1.toml` as built in ([`PAPER_SCENES`]).
    pub const PAPER_SAMPLE1: Self = Self::Builtin(PAPER_SCENES[0].0, PAPER_SCENES[0].1);

    /// `config/scenes/rig-tiny.toml` as built in: the demo rig's small scene.
    pub const RIG_TINY: Self = Self::Builtin(
        "rig-tiny",
        include_str!("../../config/scenes/rig-tiny.toml"),
    );

    /// `--scene`'s value for `bench` and `chart`: the file given, else the paper's first
    /// sample as built in.
    pub fn from_arg(path: Option<PathBuf>) -> Self {
        path.map_or(Self::PAPER_SAMPLE1, Self::Path)
    }

    /// The scene's name, as a file's stem gives it (`paper-sample1` for the built-in one).
    pub fn name(&self) -> String {
        match self {
            Self::Builtin(name, _) => (*name).to_owned(),
            Self::Path(p) => p
                .file_stem()
                .map_or_else(|| "scene".into(), |s| s.to_string_lossy().into_owned()),
        }
    }

    /// How messages name it: the file's path, or `built-in config/scenes/NAME.toml`.
    pub fn describe(&self) -> String {
        match self {
            Self::Builtin(name, _) => format!("built-in config/scenes/{name}.toml"),
            Self::Path(p) => p.display().to_string(),
        }
    }

    /// Its TOML text.
    pub fn text(&self) -> std::io::Result<Cow<'static, str>> {
        match self {
            Self::Builtin(_, text) => Ok(Cow::Borrowed(text)),
            Self::Path(p) => std::fs::read_to_string(p).map(Cow::Owned),
        }
    }
}

/// `scene` with its sensor resized (the thickness map is regenerated at the new size) and,
/// if given, its bands replaced by `[first, last, step]` nm.
pub fn scene_with(
    scene: &SceneFile,
    width: usize,
    height: usize,
    bands: Option<[f64; 3]>,
) -> Result<Scene> {
    let text = scene
        .text()
        .map_err(LabError::step(format!("{}: cannot read", scene.describe())))?;
    let mut doc: toml::Table = text
        .parse()
        .map_err(LabError::step(format!("{}: not TOML", scene.describe())))?;
    let sensor = doc
        .entry("sensor")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let Some(t) = sensor.as_table_mut() {
        t.insert("width".into(), toml::Value::Integer(width as i64));
        t.insert("height".into(), toml::Value::Integer(height as i64));
    }
    if let (Some(b), Some(rig)) = (bands, doc.get_mut("rig").and_then(|r| r.as_table_mut())) {
        rig.insert(
            "bands_nm".into(),
            toml::Value::Array(b.iter().map(|&x| toml::Value::Float(x)).collect()),
        );
    }
    Scene::from_toml(&doc.to_string(), &scene.name())
        .map_err(|e| LabError::Invalid(format!("{}: {}", scene.describe(), e.problem)))
}

#[cfg(test)]
mod tests {
    use super::{scene_with, SceneFile, PAPER_SCENES};

    /// The built-in scene is the repository's file, made the same way.
    #[test]
    fn the_builtin_scene_is_the_file() {
        let file = SceneFile::Path(
            concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/config/scenes/paper-sample1.toml"
            )
            .into(),
        );
        assert_eq!(file.name(), SceneFile::PAPER_SAMPLE1.name());
        assert_eq!(SceneFile::from_arg(None), SceneFile::PAPER_SAMPLE1);
        for bands in [None, Some([420.0, 720.0, 3.0])] {
            let a = scene_with(&SceneFile::PAPER_SAMPLE1, 40, 30, bands).expect("built-in");
            let b = scene_with(&file, 40, 30, bands).expect("file");
            assert_eq!(format!("{a:?}"), format!("{b:?}"));
            assert_eq!((a.name.as_str(), a.sensor.width), (PAPER_SCENES[0].0, 40));
        }
    }
}
