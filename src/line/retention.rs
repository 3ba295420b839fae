//! Bounded disk: which raw sweeps are kept, their references as uint16 counts, and a byte
//! budget over the kept sweeps, the oldest deleted first.

use super::folder::FolderError;
use std::path::{Path, PathBuf};

use super::recipe::{RawPolicy, RetentionSpec};
use crate::io::{DataType, EnviHeader, EnviReader, EnviWriter};

/// Whether sample number `counter` (1-based) keeps its raw sweep.
pub fn keeps_raw(spec: &RetentionSpec, counter: u64, pass: bool) -> bool {
    match spec.raw {
        RawPolicy::None => false,
        RawPolicy::Failed => !pass,
        RawPolicy::EveryNth => !pass || counter % spec.every_n.max(1) == 0,
        RawPolicy::All => true,
    }
}

/// Which of the kept sweeps (oldest first: name and bytes) to delete, oldest first, so the
/// rest fit `budget` bytes.
pub fn over_budget(kept: &[(String, u64)], budget: u64) -> Vec<&str> {
    let mut total: u64 = kept.iter().map(|(_, b)| b).sum();
    let mut out = Vec::new();
    for (name, bytes) in kept {
        if total <= budget {
            break;
        }
        total -= bytes;
        out.push(name.as_str());
    }
    out
}

/// Bytes of the files under `path` (recursively).
pub fn bytes_under(path: &Path) -> u64 {
    let Ok(meta) = std::fs::symlink_metadata(path) else {
        return 0;
    };
    if !meta.is_dir() {
        return meta.len();
    }
    std::fs::read_dir(path)
        .map(|rd| rd.flatten().map(|e| bytes_under(&e.path())).sum())
        .unwrap_or(0)
}

/// The kept raw sweeps under `samples` (`<sample>/capture`), oldest first, with their bytes.
pub fn kept_sweeps(samples: &Path) -> Vec<(String, u64)> {
    let mut names: Vec<String> = std::fs::read_dir(samples)
        .map(|rd| {
            rd.flatten()
                .filter_map(|e| e.file_name().into_string().ok())
                .filter(|n| !n.starts_with('.'))
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
        .into_iter()
        .filter_map(|n| {
            let c = samples.join(&n).join("capture");
            c.is_dir().then(|| (n, bytes_under(&c)))
        })
        .collect()
}

/// Deletes the oldest kept raw sweeps under `samples` until they fit `budget`; returns the
/// samples whose sweeps went.
pub fn enforce_budget(samples: &Path, budget: u64) -> std::io::Result<Vec<String>> {
    let kept = kept_sweeps(samples);
    let mut gone = Vec::new();
    for name in over_budget(&kept, budget) {
        std::fs::remove_dir_all(samples.join(name).join("capture"))?;
        gone.push(name.to_owned());
    }
    Ok(gone)
}

/// Rewrites a capture's float32 white and dark references (`white*.hdr`, `dark*.hdr`) as
/// uint16 counts, in place (each file written to a temporary, renamed over the old one). A pixel whose white is not
/// finite (a row the link lost) gets 0 in both, so it still calibrates to NaN. Returns the
/// files rewritten.
pub fn references_to_u16(capture: &Path) -> Result<Vec<PathBuf>, FolderError> {
    let mut done = Vec::new();
    let mut names: Vec<PathBuf> = std::fs::read_dir(capture)
        .map_err(|e| FolderError::new(capture, e))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.extension().is_some_and(|x| x == "hdr")
                && p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("white") || n.starts_with("dark"))
        })
        .collect();
    names.sort();
    // Whites first: a dark's lost rows are those of the white of the same angle.
    let mut lost: std::collections::HashMap<String, Vec<bool>> = Default::default();
    names.sort_by_key(|p| !p.to_string_lossy().contains("white"));
    for hdr in names {
        let name = hdr
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default()
            .to_owned();
        let tag = name
            .trim_start_matches("white")
            .trim_start_matches("dark")
            .to_owned();
        let e = |x: crate::io::EnviError| FolderError::new(&hdr, x);
        let mut r = EnviReader::open(&hdr).map_err(e)?;
        if r.header().data_type == DataType::U16 {
            continue;
        }
        let h0: EnviHeader = r.header().clone();
        let mut h = h0.clone();
        h.data_type = DataType::U16;
        // The writer writes to temporaries and renames them over the old files at the end.
        let mut w = EnviWriter::create(&hdr, &h).map_err(e)?;
        let is_white = name.starts_with("white");
        let mut row = vec![0f32; h0.samples];
        let mut mask = if is_white {
            Vec::new()
        } else {
            lost.remove(&tag).unwrap_or_default()
        };
        let mut k = 0usize;
        while let Some(at) = r.next_band_row(&mut row).map_err(e)? {
            for v in row.iter_mut() {
                let bad = if is_white {
                    let b = !v.is_finite();
                    mask.push(b);
                    b
                } else {
                    mask.get(k).copied().unwrap_or(false)
                };
                k += 1;
                *v = if bad || !v.is_finite() {
                    0.0
                } else {
                    v.round().clamp(0.0, 65535.0)
                };
            }
            w.write_band_row(at.band, at.line, &row).map_err(e)?;
        }
        w.finish().map_err(e)?;
        if is_white {
            lost.insert(tag, mask);
        }
        done.push(hdr);
    }
    Ok(done)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(raw: RawPolicy) -> RetentionSpec {
        RetentionSpec {
            raw,
            every_n: 3,
            ..RetentionSpec::default()
        }
    }

    #[test]
    fn policies() {
        assert!(!keeps_raw(&spec(RawPolicy::None), 1, false));
        assert!(keeps_raw(&spec(RawPolicy::Failed), 1, false));
        assert!(!keeps_raw(&spec(RawPolicy::Failed), 1, true));
        let kept: Vec<u64> = (1..=9)
            .filter(|&c| keeps_raw(&spec(RawPolicy::EveryNth), c, true))
            .collect();
        assert_eq!(kept, vec![3, 6, 9]);
        assert!(keeps_raw(&spec(RawPolicy::EveryNth), 4, false));
        assert!(keeps_raw(&spec(RawPolicy::All), 4, true));
    }

    #[test]
    fn oldest_go_first_until_under_budget() {
        let kept: Vec<(String, u64)> = [("a", 40), ("b", 30), ("c", 20), ("d", 10)]
            .iter()
            .map(|(n, b)| ((*n).to_owned(), *b))
            .collect();
        assert_eq!(over_budget(&kept, 100), Vec::<&str>::new());
        assert_eq!(over_budget(&kept, 60), vec!["a"]);
        assert_eq!(over_budget(&kept, 29), vec!["a", "b", "c"]);
        assert_eq!(over_budget(&kept, 0), vec!["a", "b", "c", "d"]);
    }
}
