//! `DIR/inspect.lock`: one `inspect` writes an output folder at a time.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};

use super::{ie, InspectError};

/// `DIR/inspect.lock`, holding the pid of the `inspect` that writes `DIR`; removed when the
/// line is dropped. A lock whose process is gone (a kill -9) is taken over.
pub(super) struct DirLock(PathBuf);

impl Drop for DirLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

pub(super) fn take_lock(out: &Path) -> Result<DirLock, InspectError> {
    let path = out.join("inspect.lock");
    let me = std::process::id();
    for _ in 0..2 {
        match OpenOptions::new().write(true).create_new(true).open(&path) {
            Ok(mut f) => {
                let _ = writeln!(f, "{me}");
                let _ = f.sync_all();
                return Ok(DirLock(path));
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                let pid = std::fs::read_to_string(&path)
                    .ok()
                    .and_then(|t| t.trim().parse::<u32>().ok());
                let alive = pid.is_some_and(|p| {
                    p != me
                        && std::fs::read(format!("/proc/{p}/cmdline"))
                            .is_ok_and(|c| String::from_utf8_lossy(&c).contains("inspect"))
                });
                if alive {
                    return Err(InspectError::Stopped(format!(
                        "{}: another inspect (pid {}) writes this folder",
                        path.display(),
                        pid.unwrap_or(0)
                    )));
                }
                // Left by a process that is gone: take it over.
                let _ = std::fs::remove_file(&path);
            }
            Err(e) => return Err(ie(&path.display().to_string())(&e)),
        }
    }
    Err(InspectError::Stopped(format!(
        "{}: cannot take the lock",
        path.display()
    )))
}
