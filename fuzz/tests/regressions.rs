//! Replays every seed and every saved crash through its target: a crash the fuzzer found
//! stays fixed. Also checks the two-byte SX wheel reports exhaustively.

use std::path::Path;

use filmscope_fuzz::{run_caught, target, TARGETS};

#[test]
fn every_seed_and_saved_crash_runs_without_panicking() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut failures = Vec::new();
    let mut replayed = 0;
    for t in TARGETS {
        let mut files: Vec<_> = std::fs::read_dir(root.join("corpus").join(t.name))
            .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
            .unwrap_or_default();
        files.extend(
            std::fs::read_dir(root.join("crashes"))
                .map(|d| {
                    d.filter_map(|e| e.ok().map(|e| e.path()))
                        .filter(|p| {
                            p.file_name()
                                .and_then(|n| n.to_str())
                                .is_some_and(|n| n.starts_with(&format!("{}-", t.name)))
                        })
                        .collect::<Vec<_>>()
                })
                .unwrap_or_default(),
        );
        for f in files {
            let bytes = std::fs::read(&f).expect("read corpus file");
            replayed += 1;
            if let Err(msg) = run_caught(t, &bytes) {
                failures.push(format!("{}: {msg}", f.display()));
            }
        }
    }
    assert!(replayed >= TARGETS.len(), "no corpus found");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn every_sx_wheel_report_decodes() {
    let t = target("sxwheel").expect("target");
    let all: Vec<u8> = (0..=u16::MAX).flat_map(|v| v.to_le_bytes()).collect();
    assert!(run_caught(t, &all).is_ok());
}
