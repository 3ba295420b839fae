//! Crash-safe file output: write a temporary file beside the target, then rename it over.
//!
//! A rename within one directory is atomic on the file systems filmscope targets, so a
//! reader (or a user after a crash or Ctrl-C) sees either the previous file or the complete
//! new one, never a partly written file. The temporary file lives in the target's directory
//! (a rename across file systems would not be atomic) under a hidden name
//! `.NAME.PID-N.tmp`, and is removed again if it is dropped without
//! [`TempFile::persist`].
//!
//! Use [`write_atomic`] when the whole content is in memory (JSON summaries, headers), and
//! [`TempFile`] when the output is produced piecewise (cube data, PNG encoders: it
//! implements [`Write`] and [`Seek`]). A temporary file a killed process left behind lies
//! in a result's staging folder, which [`crate::io::OutputDir`] removes whole.

use std::fs::{self, File, OpenOptions};
use std::io::{self, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Distinguishes temporary files created by one process.
static COUNTER: AtomicU64 = AtomicU64::new(0);

/// How many temporary names to try before giving up (another process may hold one).
const NAME_ATTEMPTS: u32 = 16;

/// Writes `bytes` to `path` atomically: the file at `path` is either left as it was or
/// replaced by exactly `bytes`.
///
/// The data is flushed to disk (`fsync`) before the rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut tmp = TempFile::create(path)?;
    tmp.write_all(bytes)?;
    tmp.persist()
}

/// A temporary file that becomes `target` on [`persist`](TempFile::persist) and is deleted
/// if dropped before that.
#[derive(Debug)]
pub struct TempFile {
    file: File,
    guard: RemoveOnDrop,
}

/// Deletes the temporary path on drop unless disarmed.
#[derive(Debug)]
struct RemoveOnDrop {
    tmp_path: PathBuf,
    target: PathBuf,
    armed: bool,
}

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        if self.armed {
            // Best effort: the file may already be gone, and a drop cannot report errors.
            let _ = fs::remove_file(&self.tmp_path);
        }
    }
}

impl TempFile {
    /// Creates an empty temporary file (read and write) in `target`'s directory.
    ///
    /// Fails if `target` has no file name or its directory cannot be written.
    pub fn create(target: &Path) -> io::Result<Self> {
        let name = target.file_name().ok_or_else(|| {
            io::Error::new(io::ErrorKind::InvalidInput, "output path has no file name")
        })?;
        let dir = match target.parent() {
            Some(parent) if !parent.as_os_str().is_empty() => parent.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let pid = std::process::id();
        let mut last_err = None;
        for _ in 0..NAME_ATTEMPTS {
            let n = COUNTER.fetch_add(1, Ordering::Relaxed);
            let mut tmp_name = std::ffi::OsString::from(".");
            tmp_name.push(name);
            tmp_name.push(format!(".{pid}-{n}.tmp"));
            let tmp_path = dir.join(tmp_name);
            match OpenOptions::new()
                .read(true)
                .write(true)
                .create_new(true)
                .open(&tmp_path)
            {
                Ok(file) => {
                    return Ok(Self {
                        file,
                        guard: RemoveOnDrop {
                            tmp_path,
                            target: target.to_path_buf(),
                            armed: true,
                        },
                    })
                }
                Err(err) if err.kind() == io::ErrorKind::AlreadyExists => last_err = Some(err),
                Err(err) => return Err(err),
            }
        }
        Err(last_err.unwrap_or_else(|| io::Error::other("no free temporary file name")))
    }

    /// The open temporary file, for reading back, seeking or `set_len`.
    pub fn file_mut(&mut self) -> &mut File {
        &mut self.file
    }

    /// Where the data is written until [`persist`](TempFile::persist).
    pub fn temp_path(&self) -> &Path {
        &self.guard.tmp_path
    }

    /// The path the file takes on [`persist`](TempFile::persist).
    pub fn target(&self) -> &Path {
        &self.guard.target
    }

    /// Flushes the data to disk and renames the temporary file onto the target, replacing
    /// any file there. On error the temporary file is removed and the target is untouched.
    pub fn persist(self) -> io::Result<()> {
        let Self {
            mut file,
            mut guard,
        } = self;
        file.flush()?;
        file.sync_all()?;
        // Close before renaming: some platforms refuse to rename an open file.
        drop(file);
        fs::rename(&guard.tmp_path, &guard.target)?;
        guard.armed = false;
        sync_parent_dir(&guard.target);
        Ok(())
    }
}

/// Makes the rename itself durable where the platform allows it (best effort).
fn sync_parent_dir(target: &Path) {
    #[cfg(unix)]
    {
        let dir = match target.parent() {
            Some(parent) if !parent.as_os_str().is_empty() => parent,
            _ => Path::new("."),
        };
        if let Ok(dir) = File::open(dir) {
            let _ = dir.sync_all();
        }
    }
    #[cfg(not(unix))]
    let _ = target;
}

impl Write for TempFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.file.write(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.file.flush()
    }
}

impl Seek for TempFile {
    fn seek(&mut self, pos: SeekFrom) -> io::Result<u64> {
        self.file.seek(pos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_files_in(dir: &Path) -> usize {
        fs::read_dir(dir)
            .map(|entries| {
                entries
                    .filter_map(Result::ok)
                    .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
                    .count()
            })
            .unwrap_or(0)
    }

    #[test]
    fn write_atomic_replaces_and_leaves_no_temporaries() -> io::Result<()> {
        let dir = tempfile::tempdir()?;
        let path = dir.path().join("summary.json");
        write_atomic(&path, b"old")?;
        write_atomic(&path, b"new")?;
        assert_eq!(fs::read(&path)?, b"new");
        assert_eq!(temp_files_in(dir.path()), 0);
        Ok(())
    }

    #[test]
    fn dropped_temp_file_leaves_old_target() -> io::Result<()> {
        let dir = tempfile::tempdir()?;
        let path = dir.path().join("map.img");
        write_atomic(&path, b"old")?;
        {
            let mut tmp = TempFile::create(&path)?;
            tmp.write_all(b"half of the new cont")?;
            assert!(tmp.temp_path().exists());
            assert_eq!(tmp.target(), path.as_path());
        }
        assert_eq!(fs::read(&path)?, b"old");
        assert_eq!(temp_files_in(dir.path()), 0);
        Ok(())
    }

    #[test]
    fn missing_directory_is_an_error() {
        let dir = match tempfile::tempdir() {
            Ok(dir) => dir,
            Err(_) => return,
        };
        let path = dir.path().join("no/such/dir/out.json");
        assert!(write_atomic(&path, b"x").is_err());
    }
}
