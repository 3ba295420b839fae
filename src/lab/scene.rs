//! The scenes lab measurements run on.

use std::path::Path;

use anyhow::{anyhow, Context, Result};
use firmware_sim::Scene;

/// `scene_path` with its sensor resized (the thickness map is regenerated at the new size)
/// and, if given, its bands replaced by `[first, last, step]` nm.
pub fn scene_with(
    scene_path: &Path,
    width: usize,
    height: usize,
    bands: Option<[f64; 3]>,
) -> Result<Scene> {
    let text = std::fs::read_to_string(scene_path)
        .with_context(|| format!("{}: cannot read", scene_path.display()))?;
    let mut doc: toml::Table = text
        .parse()
        .with_context(|| format!("{}: not TOML", scene_path.display()))?;
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
    let name = scene_path
        .file_stem()
        .map_or_else(|| "scene".into(), |s| s.to_string_lossy().into_owned());
    Scene::from_toml(&doc.to_string(), &name)
        .map_err(|e| anyhow!("{}: {}", scene_path.display(), e.problem))
}
