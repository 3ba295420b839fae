//! `filmscope export-gltf`: the GLB taken apart in Rust (header, chunks, JSON, the
//! thickness texture decoded and turned back into nm), and the Khronos glTF-Validator's
//! verdict when it is installed.
//!
//! The validator runs when `FILMSCOPE_GLTF_VALIDATOR` names the folder it was installed
//! into (`npm install --prefix DIR gltf-validator`, as `.ci/run` does) and `node` is on the
//! PATH. With `FILMSCOPE_REQUIRE_GLTF_VALIDATOR=1` (set by `.ci/run` once it installed it)
//! a missing validator is a failure; otherwise the test says why it skipped.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{estimated_tiny, run_ok, s, tempdir};
use filmscope::io::read_cube;

/// A GLB taken apart: its JSON and its binary chunk.
struct Glb {
    json: serde_json::Value,
    bin: Vec<u8>,
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

/// Parses a GLB per the glTF 2.0 spec, section "Binary glTF Layout".
fn parse_glb(bytes: &[u8]) -> Glb {
    assert!(bytes.len() >= 28, "too short");
    assert_eq!(&bytes[0..4], b"glTF", "magic");
    assert_eq!(u32_at(bytes, 4), 2, "container version");
    assert_eq!(u32_at(bytes, 8) as usize, bytes.len(), "total length");
    let json_len = u32_at(bytes, 12) as usize;
    assert_eq!(&bytes[16..20], b"JSON");
    assert_eq!(json_len % 4, 0, "JSON chunk padded to 4 bytes");
    let json: serde_json::Value =
        serde_json::from_slice(&bytes[20..20 + json_len]).expect("JSON chunk parses");
    let at = 20 + json_len;
    let bin_len = u32_at(bytes, at) as usize;
    assert_eq!(&bytes[at + 4..at + 8], b"BIN\0");
    assert_eq!(bin_len % 4, 0, "BIN chunk padded to 4 bytes");
    assert_eq!(at + 8 + bin_len, bytes.len(), "nothing after the BIN chunk");
    Glb {
        json,
        bin: bytes[at + 8..].to_vec(),
    }
}

/// Packs a GLB again (after the test changed its JSON).
fn pack_glb(json: &serde_json::Value, bin: &[u8]) -> Vec<u8> {
    let mut text = serde_json::to_vec(json).expect("json");
    while text.len() % 4 != 0 {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    for w in [2, total as u32, text.len() as u32] {
        out.extend_from_slice(&w.to_le_bytes());
    }
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    out
}

fn view(glb: &Glb, index: u64) -> &[u8] {
    let v = &glb.json["bufferViews"][index as usize];
    let off = v["byteOffset"].as_u64().unwrap_or(0) as usize;
    let len = v["byteLength"].as_u64().expect("byteLength") as usize;
    &glb.bin[off..off + len]
}

fn export(est: &Path, out: &Path) {
    run_ok(&["export-gltf", s(est), "--out", s(out), "--width-m", "0.2"]);
}

#[test]
fn glb_structure_material_and_thickness_round_trip() {
    let dir = tempdir();
    let (_, est) = estimated_tiny(dir.path(), false);
    let out = dir.path().join("sample.glb");
    export(&est, &out);
    let glb = parse_glb(&std::fs::read(&out).expect("glb"));
    let j = &glb.json;
    assert_eq!(j["asset"]["version"], "2.0");
    let used: Vec<&str> = j["extensionsUsed"]
        .as_array()
        .expect("extensionsUsed")
        .iter()
        .filter_map(|v| v.as_str())
        .collect();
    assert!(used.contains(&"KHR_materials_iridescence") && used.contains(&"KHR_materials_ior"));
    assert!(j.get("extensionsRequired").is_none());

    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(est.join("summary.json")).expect("s"))
            .expect("json");
    let m = &j["materials"][0]["extensions"];
    let iri = &m["KHR_materials_iridescence"];
    assert_eq!(iri["iridescenceFactor"].as_f64(), Some(1.0));
    let n = summary["refractive_index"].as_f64().expect("n");
    assert!((iri["iridescenceIor"].as_f64().expect("ior") - n).abs() < 1e-12);
    assert!((m["KHR_materials_ior"]["ior"].as_f64().expect("ior") - 1.52).abs() < 1e-12);
    let (tmin, tmax) = (
        iri["iridescenceThicknessMinimum"].as_f64().expect("min"),
        iri["iridescenceThicknessMaximum"].as_f64().expect("max"),
    );
    let t = &summary["thickness_nm"];
    assert!(
        (tmin - t["min"].as_f64().expect("min")).abs() < 1e-3,
        "{tmin}"
    );
    assert!(
        (tmax - t["max"].as_f64().expect("max")).abs() < 1e-3,
        "{tmax}"
    );

    // The quad: 4 vertices 0.2 m wide, 0.15 m deep (32 x 24 px), facing +Y, 2 triangles.
    let acc = &j["accessors"];
    let prim = &j["meshes"][0]["primitives"][0];
    let pos = &acc[prim["attributes"]["POSITION"].as_u64().expect("pos") as usize];
    let max: Vec<f64> = pos["max"]
        .as_array()
        .expect("max")
        .iter()
        .filter_map(serde_json::Value::as_f64)
        .collect();
    assert_eq!(max.len(), 3);
    for (got, want) in max.iter().zip([0.1, 0.0, 0.075]) {
        assert!((got - want).abs() < 1e-7, "POSITION max {max:?}");
    }
    let normals = view(&glb, acc[1]["bufferView"].as_u64().expect("bv"));
    let ny: Vec<f32> = normals
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().expect("4")))
        .collect();
    assert_eq!(ny, [0.0, 1.0, 0.0].repeat(4));
    let idx = view(&glb, acc[3]["bufferView"].as_u64().expect("bv"));
    assert_eq!(idx, [0u16, 1, 2, 0, 2, 3].map(u16::to_le_bytes).concat());

    // The texture decodes and G gives back every reliable thickness to one 8-bit step.
    let tex = &j["materials"][0]["extensions"]["KHR_materials_iridescence"]
        ["iridescenceThicknessTexture"]["index"];
    let image = &j["images"][j["textures"][tex.as_u64().expect("tex") as usize]["source"]
        .as_u64()
        .expect("source") as usize];
    assert_eq!(image["mimeType"], "image/png");
    let png = image::load_from_memory(view(&glb, image["bufferView"].as_u64().expect("bv")))
        .expect("texture decodes")
        .to_rgb8();
    assert_eq!(png.dimensions(), (32, 24));
    let map = read_cube(est.join("thickness_nm.hdr")).expect("map");
    let step = (tmax - tmin) / 255.0;
    let (mut valid, mut masked) = (0, 0);
    for (i, &d) in map.data.iter().enumerate() {
        let px = png.get_pixel((i % 32) as u32, (i / 32) as u32).0;
        if d.is_finite() {
            let back = tmin + f64::from(px[1]) / 255.0 * (tmax - tmin);
            assert!(
                (back - f64::from(d)).abs() <= step,
                "pixel {i}: {back} vs {d}"
            );
            assert_eq!(px[0], 0, "pixel {i} masked");
            valid += 1;
        } else {
            assert_eq!(px[0], 255, "pixel {i}: NaN not masked");
            masked += 1;
        }
    }
    assert!(valid > 700 && masked >= 3, "{valid} valid, {masked} masked");
}

/// The folder holding `node_modules/gltf-validator`, or why there is none.
fn validator() -> Result<PathBuf, String> {
    let dir = std::env::var_os("FILMSCOPE_GLTF_VALIDATOR")
        .map(PathBuf::from)
        .ok_or("FILMSCOPE_GLTF_VALIDATOR is not set")?;
    if !dir.join("node_modules").join("gltf-validator").is_dir() {
        return Err(format!("no gltf-validator under {}", dir.display()));
    }
    match Command::new("node").arg("--version").output() {
        Ok(o) if o.status.success() => Ok(dir),
        _ => Err("node is not on the PATH".into()),
    }
}

fn validate(prefix: &Path, glb: &Path) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/interop/gltf_validate.js");
    let run = Command::new("node")
        .arg(script)
        .arg(prefix)
        .arg(glb)
        .output()
        .expect("run node");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    serde_json::from_slice(&run.stdout).expect("validator report")
}

#[test]
fn khronos_gltf_validator_reports_no_errors() {
    let prefix = match validator() {
        Ok(p) => p,
        Err(why) => {
            let required =
                std::env::var("FILMSCOPE_REQUIRE_GLTF_VALIDATOR").is_ok_and(|v| v == "1");
            assert!(!required, "FILMSCOPE_REQUIRE_GLTF_VALIDATOR=1 but {why}");
            eprintln!("skipped: glTF-Validator not available ({why})");
            return;
        }
    };
    let dir = tempdir();
    let (_, est) = estimated_tiny(dir.path(), false);
    let out = dir.path().join("sample.glb");
    export(&est, &out);
    let report = validate(&prefix, &out);
    let issues = &report["issues"];
    eprintln!(
        "glTF-Validator {}: {} errors, {} warnings, {} infos, {} hints: {}",
        report["validatorVersion"],
        issues["numErrors"],
        issues["numWarnings"],
        issues["numInfos"],
        issues["numHints"],
        issues["messages"]
    );
    assert_eq!(issues["numErrors"].as_u64(), Some(0), "{issues}");
    assert_eq!(report["info"]["totalTriangleCount"].as_u64(), Some(2));

    // The check can fail: a thickness texture that does not exist is an error.
    let mut glb = parse_glb(&std::fs::read(&out).expect("glb"));
    glb.json["materials"][0]["extensions"]["KHR_materials_iridescence"]
        ["iridescenceThicknessTexture"]["index"] = serde_json::json!(7);
    let broken = dir.path().join("broken.glb");
    std::fs::write(&broken, pack_glb(&glb.json, &glb.bin)).expect("write");
    let report = validate(&prefix, &broken);
    assert!(
        report["issues"]["numErrors"].as_u64().unwrap_or(0) > 0,
        "{}",
        report["issues"]
    );
}
