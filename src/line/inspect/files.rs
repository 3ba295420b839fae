//! The verdict's files in a sample's folder: the out-of-tolerance mask (ENVI) and the
//! overlay (PNG).

use std::path::Path;

use super::{ie, InspectError};
use crate::io::write_atomic;
use crate::line::recipe::Recipe;
use crate::line::verdict::{self, Verdict};

/// Writes `oot_mask.hdr`/`.img`: ENVI uint8 (data type 1), the verdict's mask.
pub(super) fn write_mask(dir: &Path, w: usize, h: usize, v: &Verdict) -> Result<(), InspectError> {
    let img = dir.join("oot_mask.img");
    write_atomic(&img, &v.mask).map_err(|e| ie(&img.display().to_string())(&e))?;
    let hdr = format!(
        "ENVI\ndescription = {{\n  out-of-tolerance mask: 0=within 1=out of tolerance 2=no thickness 3=outside the regions of interest}}\nsamples = {w}\nlines = {h}\nbands = 1\nheader offset = 0\nfile type = ENVI Standard\ndata type = 1\ninterleave = bsq\nbyte order = 0\n"
    );
    let hp = dir.join("oot_mask.hdr");
    write_atomic(&hp, hdr.as_bytes()).map_err(|e| ie(&hp.display().to_string())(&e))
}

/// The thickness preview (viridis over the recipe's tolerance band) with out-of-tolerance
/// pixels in red, pixels without a thickness black and pixels outside the regions of
/// interest dimmed; 8x enlarged.
pub fn overlay_png(
    recipe: &Recipe,
    w: usize,
    h: usize,
    thickness: &[f32],
    v: &Verdict,
) -> Result<Vec<u8>, InspectError> {
    let [lo, hi] = recipe.thickness.limits();
    let rgb: Vec<[u8; 3]> = (0..w * h)
        .map(|i| {
            let t = f64::from(thickness.get(i).copied().unwrap_or(f32::NAN));
            let base = if t.is_finite() {
                crate::export::colormap::viridis(((t - lo) / (hi - lo)).clamp(0.0, 1.0))
            } else {
                [0, 0, 0]
            };
            match v.mask.get(i).copied().unwrap_or(verdict::MASK_IGNORED) {
                verdict::MASK_OUT => [230, 20, 20],
                verdict::MASK_IGNORED => base.map(|c| c / 3),
                _ => base,
            }
        })
        .collect();
    let scale = (320 / w.max(1)).clamp(1, 16);
    crate::export::png::render_rgb_png(w, h, &rgb, scale)
        .map_err(|e| InspectError::Stopped(format!("overlay: {e}")))
}
