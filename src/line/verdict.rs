//! The verdict on one sample against its recipe: PASS or FAIL with every reason, the
//! out-of-tolerance mask and its connected regions. Pure: no I/O.

use serde::Serialize;

use super::recipe::Recipe;
use crate::record::finite;
use crate::record::line::{PassFail, ThicknessSummary, VerdictRecord};

/// Mask value: judged and within tolerance.
pub const MASK_OK: u8 = 0;
/// Mask value: judged and out of tolerance.
pub const MASK_OUT: u8 = 1;
/// Mask value: judged, no thickness.
pub const MASK_INVALID: u8 = 2;
/// Mask value: outside every region of interest (not judged).
pub const MASK_IGNORED: u8 = 3;

/// Thickness statistics over the judged pixels with a thickness, nm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ThicknessStats {
    /// Mean.
    pub mean: f64,
    /// Population standard deviation.
    pub std: f64,
    /// Smallest.
    pub min: f64,
    /// Largest.
    pub max: f64,
}

pub use crate::record::line::Region;

/// The verdict on one sample.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Verdict {
    /// Whether every check passed.
    pub pass: bool,
    /// Every failed check, in words with the numbers.
    pub reasons: Vec<String>,
    /// Thickness statistics (NaN when no pixel has a thickness).
    pub thickness: ThicknessStats,
    /// Share of judged pixels with a thickness.
    pub valid_fraction: f64,
    /// Judged pixels.
    pub judged_px: usize,
    /// Out-of-tolerance pixels.
    pub out_of_tolerance_px: usize,
    /// Out-of-tolerance regions, largest first.
    pub regions: Vec<Region>,
    /// Per pixel, row-major: [`MASK_OK`], [`MASK_OUT`], [`MASK_INVALID`], [`MASK_IGNORED`].
    #[serde(skip)]
    pub mask: Vec<u8>,
}

impl Verdict {
    /// `PASS` or `FAIL`.
    pub fn word(&self) -> &'static str {
        self.pass_fail().word()
    }

    /// PASS or FAIL, as records give it.
    pub fn pass_fail(&self) -> PassFail {
        PassFail::of(self.pass)
    }

    /// The record a sample's `summary.json` carries: the verdict with every region, and
    /// the mask's and overlay's files.
    pub fn record(&self) -> VerdictRecord {
        VerdictRecord {
            verdict: self.pass_fail(),
            reasons: self.reasons.clone(),
            thickness_nm: self.thickness.summary(),
            valid_fraction: self.valid_fraction,
            judged_px: self.judged_px,
            out_of_tolerance_px: self.out_of_tolerance_px,
            regions: self.regions.clone(),
            mask: "oot_mask.hdr".into(),
            overlay: "overlay.png".into(),
        }
    }
}

impl ThicknessStats {
    /// As records give them: null where NaN (no pixel has a thickness).
    pub fn summary(&self) -> ThicknessSummary {
        ThicknessSummary {
            mean: finite(self.mean),
            std: finite(self.std),
            min: finite(self.min),
            max: finite(self.max),
        }
    }
}

/// Judges a `width` x `height` thickness map (nm, NaN: none) and its index against `recipe`.
pub fn judge(
    recipe: &Recipe,
    width: usize,
    height: usize,
    thickness: &[f32],
    index: f64,
) -> Verdict {
    let n = (width * height).min(thickness.len());
    let [lo, hi] = recipe.thickness.limits();
    let mut mask = vec![MASK_IGNORED; width * height];
    let mut vals = Vec::with_capacity(n);
    let mut judged = 0usize;
    for (i, m) in mask.iter_mut().enumerate().take(n) {
        let (x, y) = (i % width.max(1), i / width.max(1));
        if !recipe.roi.is_empty() && !recipe.roi.iter().any(|r| r.contains(x, y)) {
            continue;
        }
        judged += 1;
        let t = f64::from(thickness[i]);
        *m = if !t.is_finite() {
            MASK_INVALID
        } else {
            vals.push(t);
            if t < lo || t > hi {
                MASK_OUT
            } else {
                MASK_OK
            }
        };
    }
    let stats = stats(&vals);
    let valid_fraction = if judged == 0 {
        0.0
    } else {
        vals.len() as f64 / judged as f64
    };
    let regions = regions(&mask, width, height);
    let out_px = mask.iter().filter(|&&m| m == MASK_OUT).count();
    let mut reasons = Vec::new();
    let nominal = recipe.index.nominal;
    if !index.is_finite() {
        reasons.push("no index: the sweep did not resolve the film".to_owned());
    } else if (index - nominal).abs() > recipe.index.tolerance {
        reasons.push(format!(
            "index {index:.4} outside {nominal:.4} \u{b1} {:.4}",
            recipe.index.tolerance
        ));
    }
    if vals.is_empty() {
        reasons.push("no pixel has a thickness".to_owned());
    } else {
        if stats.mean < lo || stats.mean > hi {
            reasons.push(format!(
                "mean thickness {:.1} nm outside {:.1}..{:.1} nm",
                stats.mean, lo, hi
            ));
        }
        if let Some(max_std) = recipe.thickness.max_std_nm {
            if stats.std > max_std {
                reasons.push(format!(
                    "thickness spread {:.2} nm (std) above {max_std:.2} nm",
                    stats.std
                ));
            }
        }
    }
    if valid_fraction < recipe.acceptance.min_valid_fraction {
        reasons.push(format!(
            "valid share {:.3} below {:.3}",
            valid_fraction, recipe.acceptance.min_valid_fraction
        ));
    }
    if let Some(big) = regions.first() {
        if big.area_px > recipe.acceptance.max_defect_area_px {
            reasons.push(format!(
                "out-of-tolerance region of {} px at ({}, {}) {}x{} above {} px ({} region(s), {} px out of {lo:.1}..{hi:.1} nm)",
                big.area_px,
                big.x,
                big.y,
                big.width,
                big.height,
                recipe.acceptance.max_defect_area_px,
                regions.len(),
                out_px
            ));
        }
    }
    Verdict {
        pass: reasons.is_empty(),
        reasons,
        thickness: stats,
        valid_fraction,
        judged_px: judged,
        out_of_tolerance_px: out_px,
        regions,
        mask,
    }
}

fn stats(v: &[f64]) -> ThicknessStats {
    if v.is_empty() {
        return ThicknessStats {
            mean: f64::NAN,
            std: f64::NAN,
            min: f64::NAN,
            max: f64::NAN,
        };
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
    ThicknessStats {
        mean,
        std: var.sqrt(),
        min: v.iter().copied().fold(f64::INFINITY, f64::min),
        max: v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    }
}

/// The 4-connected regions of [`MASK_OUT`] pixels, largest first (ties: top-left first).
pub fn regions(mask: &[u8], width: usize, height: usize) -> Vec<Region> {
    let mut seen = vec![false; mask.len()];
    let mut out = Vec::new();
    let mut stack = Vec::new();
    for start in 0..mask.len().min(width * height) {
        if mask[start] != MASK_OUT || seen[start] {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let (mut x0, mut y0, mut x1, mut y1, mut area) = (usize::MAX, usize::MAX, 0, 0, 0);
        while let Some(i) = stack.pop() {
            let (x, y) = (i % width, i / width);
            area += 1;
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x);
            y1 = y1.max(y);
            let mut visit = |j: usize| {
                if mask[j] == MASK_OUT && !seen[j] {
                    seen[j] = true;
                    stack.push(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < width {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - width);
            }
            if y + 1 < height {
                visit(i + width);
            }
        }
        out.push(Region {
            x: x0,
            y: y0,
            width: x1 - x0 + 1,
            height: y1 - y0 + 1,
            area_px: area,
        });
    }
    out.sort_by_key(|r| std::cmp::Reverse(r.area_px));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::line::recipe::Recipe;
    use std::path::Path;

    fn recipe(extra: &str) -> Recipe {
        let t = format!("film = \"f\"\n[index]\nnominal = 2.1\ntolerance = 0.03\n[thickness]\nnominal_nm = 600\ntolerance_nm = 30\nmax_std_nm = 10\n[acceptance]\nmin_valid_fraction = 0.9\nmax_defect_area_px = 3\n{extra}");
        Recipe::parse(&t, Path::new("r.toml")).expect("recipe")
    }

    #[test]
    fn nominal_passes() {
        let t = vec![600.0f32; 8 * 6];
        let v = judge(&recipe(""), 8, 6, &t, 2.1);
        assert!(v.pass, "{:?}", v.reasons);
        assert_eq!(v.word(), "PASS");
        assert_eq!(v.thickness.mean, 600.0);
        assert_eq!(v.valid_fraction, 1.0);
        assert!(v.regions.is_empty());
    }

    #[test]
    fn defect_regions_are_connected_components() {
        let (w, h) = (8, 6);
        let mut t = vec![600.0f32; w * h];
        // A 2x3 patch (6 px) and a lone pixel, both too thick; one NaN.
        for y in 1..4 {
            for x in 2..4 {
                t[y * w + x] = 700.0;
            }
        }
        t[5 * w + 7] = 500.0;
        t[0] = f32::NAN;
        let v = judge(&recipe(""), w, h, &t, 2.1);
        assert!(!v.pass);
        assert_eq!(
            v.regions,
            vec![
                Region {
                    x: 2,
                    y: 1,
                    width: 2,
                    height: 3,
                    area_px: 6
                },
                Region {
                    x: 7,
                    y: 5,
                    width: 1,
                    height: 1,
                    area_px: 1
                },
            ]
        );
        assert_eq!(v.out_of_tolerance_px, 7);
        assert_eq!(v.mask[0], MASK_INVALID);
        assert_eq!(v.mask[w + 2], MASK_OUT);
        assert_eq!(v.mask[1], MASK_OK);
        assert_eq!(v.reasons.len(), 2, "{:?}", v.reasons); // region and spread
        assert!(
            v.reasons[1].starts_with("out-of-tolerance region of 6 px at (2, 1) 2x3 above 3 px")
        );
        assert!(v.reasons[0].starts_with("thickness spread"));
    }

    #[test]
    fn every_reason_is_given() {
        let t = vec![f32::NAN; 4 * 4];
        let v = judge(&recipe(""), 4, 4, &t, f64::NAN);
        assert_eq!(v.reasons.len(), 3, "{:?}", v.reasons);
        let mut t = vec![650.0f32; 4 * 4];
        t[0] = f32::NAN;
        t[1] = f32::NAN;
        let v = judge(&recipe(""), 4, 4, &t, 2.2);
        assert!(
            v.reasons[0].starts_with("index 2.2000 outside 2.1000"),
            "{:?}",
            v.reasons
        );
        assert!(v.reasons[1].starts_with("mean thickness 650.0 nm outside 570.0..630.0"));
        assert!(v.reasons[2].starts_with("valid share 0.875 below 0.900"));
        assert!(v.reasons[3].starts_with("out-of-tolerance region of 14 px"));
    }

    #[test]
    fn regions_of_interest_limit_what_is_judged() {
        let (w, h) = (8, 6);
        let mut t = vec![600.0f32; w * h];
        t[0] = 900.0; // outside the ROI: ignored
        let r = recipe("[[roi]]\nx = 2\ny = 2\nwidth = 4\nheight = 3\n");
        let v = judge(&r, w, h, &t, 2.1);
        assert!(v.pass, "{:?}", v.reasons);
        assert_eq!(v.judged_px, 12);
        assert_eq!(v.mask[0], MASK_IGNORED);
    }
}
