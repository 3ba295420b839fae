//! The film as a glTF 2.0 binary (GLB) that renderers load: a flat quad whose material
//! uses `KHR_materials_iridescence` for the film and `KHR_materials_ior` for the substrate.
//!
//! What is written, by hand with `serde_json` (no glTF crate):
//!
//! - one node with one mesh: a quad `width_m` wide (x) and as deep (z) as the map's
//!   aspect asks, lying in the y = 0 plane facing +Y (up), centred on the origin; image
//!   row 0 is at -z, so seen from above the sample reads as the map does. Attributes
//!   `POSITION`, `NORMAL`, `TEXCOORD_0` (uv (0, 0) = the map's top-left pixel) and
//!   16-bit `indices`;
//! - one material: `KHR_materials_iridescence` with `iridescenceFactor` 1,
//!   `iridescenceIor` = the film's estimated index at 550 nm (glTF has no dispersion: the
//!   Cauchy term, if any, is in the material's `extras`), `iridescenceThicknessMinimum` and
//!   `iridescenceThicknessMaximum` = the smallest and largest reliable thickness (nm), and
//!   `iridescenceThicknessTexture` = the thickness map; `KHR_materials_ior` with `ior` =
//!   the substrate's index; a smooth black dielectric base (`metallicFactor` 0,
//!   `roughnessFactor` [`ROUGHNESS`], `baseColorFactor` [`BASE_COLOUR`]: the film's colour
//!   is all in its specular reflection);
//! - the thickness texture, a PNG inside the binary chunk: the G channel holds
//!   `(d - min) / (max - min)` in 8 bits (what the extension reads); pixels without a
//!   reliable thickness get the median thickness in G and 255 in R (a mask renderers
//!   ignore); B is 0. Linear filtering, clamped at the edges.
//!
//! Neither extension is required (`extensionsRequired` is absent): a viewer without them
//! shows the plain base.

use serde_json::json;

use crate::appearance::{AppearanceError, SampleFilm};
use crate::export::canvas::{Canvas, BACKGROUND};
use crate::material::DispersionRecord;

/// Roughness of the base: a nearly mirror-like film.
pub const ROUGHNESS: f64 = 0.05;

/// Linear base colour (RGBA): near black, so the thin-film reflection shows.
pub const BASE_COLOUR: [f64; 4] = [0.02, 0.02, 0.02, 1.0];

/// The GLB and what went into it.
#[derive(Clone, Debug)]
pub struct Glb {
    /// The file's bytes.
    pub bytes: Vec<u8>,
    /// `iridescenceIor`.
    pub iridescence_ior: f64,
    /// `iridescenceThicknessMinimum`, nm.
    pub thickness_min_nm: f64,
    /// `iridescenceThicknessMaximum`, nm.
    pub thickness_max_nm: f64,
    /// `KHR_materials_ior.ior`.
    pub substrate_ior: f64,
}

/// The thickness texture: PNG bytes, and the thickness range its G channel spans (nm).
pub fn thickness_texture(film: &SampleFilm) -> Result<(Vec<u8>, f64, f64), AppearanceError> {
    let n = film.width * film.height;
    let valid: Vec<f64> = (0..n).filter_map(|i| film.thickness_at(i)).collect();
    let fill = film.median_thickness_nm().ok_or_else(|| {
        AppearanceError::new(
            &film.maps_dir,
            "no pixel has a reliable thickness to export",
        )
    })?;
    let min = valid.iter().copied().fold(f64::INFINITY, f64::min);
    let max = valid.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let span = (max - min).max(f64::MIN_POSITIVE);
    let mut c = Canvas::new(film.width, film.height, BACKGROUND);
    let mut row = vec![0u8; film.width * 3];
    for y in 0..film.height {
        for (x, px) in row.chunks_exact_mut(3).enumerate() {
            let i = y * film.width + x;
            let (d, mask) = match film.thickness_at(i) {
                Some(d) => (d, 0),
                None => (fill, 255),
            };
            // In 0..=255 after the clamp, so the cast is exact.
            let g = (((d - min) / span).clamp(0.0, 1.0) * 255.0).round() as u8;
            px.copy_from_slice(&[mask, g, 0]);
        }
        c.put_row(0, y, &row);
    }
    let png = c
        .encode()
        .map_err(|e| AppearanceError::new(&film.maps_dir, e))?;
    Ok((png, min, max))
}

/// Appends `bytes` to `bin`, 4-byte aligned, and returns its bufferView JSON.
fn push_view(bin: &mut Vec<u8>, bytes: &[u8], target: Option<u32>) -> serde_json::Value {
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let offset = bin.len();
    bin.extend_from_slice(bytes);
    let mut v = json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()});
    if let Some(t) = target {
        v["target"] = json!(t);
    }
    v
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// glTF `ARRAY_BUFFER` and `ELEMENT_ARRAY_BUFFER` targets, `FLOAT` and `UNSIGNED_SHORT`
/// component types, `LINEAR` and `CLAMP_TO_EDGE` sampler values.
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const LINEAR: u32 = 9729;
const CLAMP_TO_EDGE: u32 = 33071;

/// GLB magic `glTF`, version, and the chunk types `JSON` and `BIN\0`.
pub const GLB_MAGIC: u32 = 0x4654_6C67;
/// The GLB container version.
pub const GLB_VERSION: u32 = 2;
/// Chunk type of the JSON chunk.
pub const CHUNK_JSON: u32 = 0x4E4F_534A;
/// Chunk type of the binary chunk.
pub const CHUNK_BIN: u32 = 0x004E_4942;

/// Builds the GLB of `film`, a quad `width_m` metres wide (see the [module docs](self)).
pub fn film_glb(film: &SampleFilm, width_m: f64) -> Result<Glb, AppearanceError> {
    let (png, min, max) = thickness_texture(film)?;
    let quad = QuadBuffer::new(film, width_m, &png);
    let (hw, hd) = (quad.half_width, quad.half_depth);
    let ior = film.index_550();
    let substrate = film.substrate_550();
    let doc = json!({
        "asset": {
            "version": "2.0",
            "generator": concat!("filmscope ", env!("CARGO_PKG_VERSION")),
        },
        "extensionsUsed": ["KHR_materials_iridescence", "KHR_materials_ior"],
        "scene": 0,
        "scenes": [{"name": "filmscope sample", "nodes": [0]}],
        "nodes": [{"name": "film sample", "mesh": 0}],
        "meshes": [{
            "name": "film sample",
            "primitives": [{
                "attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
                "indices": 3,
                "material": 0,
                "mode": 4,
            }],
        }],
        "materials": [film_material(film, [min, max])],
        "textures": [{"sampler": 0, "source": 0, "name": "thickness"}],
        "images": [{"name": "thickness", "bufferView": 4, "mimeType": "image/png"}],
        "samplers": [{
            "magFilter": LINEAR,
            "minFilter": LINEAR,
            "wrapS": CLAMP_TO_EDGE,
            "wrapT": CLAMP_TO_EDGE,
        }],
        "accessors": [
            {"bufferView": 0, "componentType": FLOAT, "count": 4, "type": "VEC3",
             "min": [-hw, 0.0, -hd], "max": [hw, 0.0, hd]},
            {"bufferView": 1, "componentType": FLOAT, "count": 4, "type": "VEC3"},
            {"bufferView": 2, "componentType": FLOAT, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": UNSIGNED_SHORT, "count": 6, "type": "SCALAR"},
        ],
        "bufferViews": quad.views,
        "buffers": [{"byteLength": quad.bin.len()}],
    });
    let bytes = glb_container(film, &doc, &quad.bin)?;
    Ok(Glb {
        bytes,
        iridescence_ior: ior,
        thickness_min_nm: min,
        thickness_max_nm: max,
        substrate_ior: substrate,
    })
}

/// The binary chunk of the quad: its positions, normals, uvs, indices and the thickness
/// texture, each a 4-byte aligned bufferView.
struct QuadBuffer {
    /// The chunk's bytes, padded to a multiple of 4.
    bin: Vec<u8>,
    /// The bufferViews, in the order above.
    views: Vec<serde_json::Value>,
    /// Half the quad's width (x) and depth (z), metres.
    half_width: f32,
    half_depth: f32,
}

impl QuadBuffer {
    /// The quad of `film`, `width_m` metres wide and as deep as the map's aspect asks,
    /// textured with the PNG `png`.
    fn new(film: &SampleFilm, width_m: f64, png: &[u8]) -> Self {
        let (hw, hd) = (
            width_m as f32 / 2.0,
            (width_m * film.height as f64 / film.width as f64) as f32 / 2.0,
        );
        let positions = [-hw, 0.0, -hd, -hw, 0.0, hd, hw, 0.0, hd, hw, 0.0, -hd];
        let normals = [
            0.0f32, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0,
        ];
        let uvs = [0.0f32, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0];
        let indices: Vec<u8> = [0u16, 1, 2, 0, 2, 3]
            .iter()
            .flat_map(|i| i.to_le_bytes())
            .collect();
        let mut bin = Vec::new();
        let views = vec![
            push_view(&mut bin, &f32_bytes(&positions), Some(ARRAY_BUFFER)),
            push_view(&mut bin, &f32_bytes(&normals), Some(ARRAY_BUFFER)),
            push_view(&mut bin, &f32_bytes(&uvs), Some(ARRAY_BUFFER)),
            push_view(&mut bin, &indices, Some(ELEMENT_ARRAY_BUFFER)),
            push_view(&mut bin, png, None),
        ];
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        Self {
            bin,
            views,
            half_width: hw,
            half_depth: hd,
        }
    }
}

/// The film's material: iridescence at the film's index over the thickness range
/// `[min, max]` (nm) of the texture, the substrate's index, a smooth black base, and the
/// dispersions glTF cannot hold in `extras`.
fn film_material(film: &SampleFilm, [min, max]: [f64; 2]) -> serde_json::Value {
    let ior = film.index_550();
    let substrate = film.substrate_550();
    json!({
        "name": "thin film",
        "pbrMetallicRoughness": {
            "baseColorFactor": BASE_COLOUR,
            "metallicFactor": 0.0,
            "roughnessFactor": ROUGHNESS,
        },
        "doubleSided": true,
        "extensions": {
            "KHR_materials_ior": {"ior": substrate},
            "KHR_materials_iridescence": {
                "iridescenceFactor": 1.0,
                "iridescenceIor": ior,
                "iridescenceThicknessMinimum": min,
                "iridescenceThicknessMaximum": max,
                "iridescenceThicknessTexture": {"index": 0},
            },
        },
        "extras": {
            "film_index_550nm": ior,
            "film_dispersion": DispersionRecord::dispersive(&film.stack.film),
            "substrate_index": substrate,
            "substrate_dispersion": DispersionRecord::dispersive(&film.stack.substrate),
            "thickness_texture": "G = (d - min) / (max - min); R = 255 where no reliable thickness (G = median there)",
        },
    })
}

/// The GLB container: its header, the JSON chunk `doc` (space-padded) and the binary chunk
/// `bin`; an error if it would exceed 4 GiB.
fn glb_container(
    film: &SampleFilm,
    doc: &serde_json::Value,
    bin: &[u8],
) -> Result<Vec<u8>, AppearanceError> {
    let mut text = serde_json::to_vec(doc).map_err(AppearanceError::from)?;
    while text.len() % 4 != 0 {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let len32 = |n: usize| {
        u32::try_from(n)
            .map_err(|_| AppearanceError::new(&film.maps_dir, "the GLB would exceed 4 GiB"))
    };
    let mut bytes = Vec::with_capacity(total);
    for word in [
        GLB_MAGIC,
        GLB_VERSION,
        len32(total)?,
        len32(text.len())?,
        CHUNK_JSON,
    ] {
        bytes.extend_from_slice(&word.to_le_bytes());
    }
    bytes.extend_from_slice(&text);
    bytes.extend_from_slice(&len32(bin.len())?.to_le_bytes());
    bytes.extend_from_slice(&CHUNK_BIN.to_le_bytes());
    bytes.extend_from_slice(bin);
    Ok(bytes)
}
