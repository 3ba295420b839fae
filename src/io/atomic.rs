//! Crash-safe file output: write a temporary file beside the target, then rename it over.
//!
//! A rename within one directory is atomic on the file systems filmscope targets, so a
//! reader (or a user after a crash or Ctrl-C) sees either the previous file or the complete
//! new one, never a partly written file. The temporary file (from the `tempfile` crate)
//! lives in the target's directory (a rename across file systems would not be atomic)
//! under a hidden name `.NAME.XXXXXX.tmp`, with the permissions a plain `File::create`
//! would give, and is removed again if it is dropped without [`TempFile::persist`].
//!
//! Use [`write_atomic`] when the whole content is in memory (JSON summaries, headers), and
//! [`TempFile`] when the output is produced piecewise (cube data, PNG encoders: it
//! implements [`Write`] and [`Seek`]). A temporary file a killed process left behind lies
//! in a result's staging folder, which [`crate::io::OutputDir`] removes whole.

use std::fs::File;
use std::io::{self, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use tempfile::NamedTempFile;

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
    tmp: NamedTempFile,
    target: PathBuf,
}

impl TempFile {
    /// Creates an empty temporary file (read and write) in `target`'s directory.
    ///
    /// Fails if `target` has no file name or its directory cannot be written.
    pub fn create(target: &Path) -> io::Result<Self> {
        let name = target.file_name().ok_or_else(|| {
            io::Error::new(io::ErrorKind::InvalidInput, "output path has no file name")
        })?;
        let mut prefix = std::ffi::OsString::from(".");
        prefix.push(name);
        prefix.push(".");
        let mut builder = tempfile::Builder::new();
        builder.prefix(&prefix).suffix(".tmp");
        // As `File::create` would: 0o666 less the umask (tempfile's default is 0o600).
        #[cfg(unix)]
        builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
        let tmp = builder.tempfile_in(parent_dir(target))?;
        Ok(Self {
            tmp,
            target: target.to_path_buf(),
        })
    }

    /// The open temporary file, for reading back, seeking or `set_len`.
    pub fn file_mut(&mut self) -> &mut File {
        self.tmp.as_file_mut()
    }

    /// Where the data is written until [`persist`](TempFile::persist).
    pub fn temp_path(&self) -> &Path {
        self.tmp.path()
    }

    /// The path the file takes on [`persist`](TempFile::persist).
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Flushes the data to disk and renames the temporary file onto the target, replacing
    /// any file there. On error the temporary file is removed and the target is untouched.
    pub fn persist(self) -> io::Result<()> {
        let Self { mut tmp, target } = self;
        tmp.flush()?;
        tmp.as_file().sync_all()?;
        // On failure the error holds the temporary file, which its drop removes.
        tmp.persist(&target).map_err(|e| e.error)?;
        sync_parent_dir(&target);
        Ok(())
    }
}

/// The directory `target` is in (`.` for a bare file name).
fn parent_dir(target: &Path) -> &Path {
    match target.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent,
        _ => Path::new("."),
    }
}

/// Makes the rename itself durable where the platform allows it (best effort).
fn sync_parent_dir(target: &Path) {
    #[cfg(unix)]
    if let Ok(dir) = File::open(parent_dir(target)) {
        let _ = dir.sync_all();
    }
    #[cfg(not(unix))]
    let _ = target;
}

impl Write for TempFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.tmp.write(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.tmp.flush()
    }
}

impl Seek for TempFile {
    fn seek(&mut self, pos: SeekFrom) -> io::Result<u64> {
        self.tmp.seek(pos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::fs;

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

    #[cfg(unix)]
    #[test]
    fn written_files_get_the_permissions_of_file_create() -> io::Result<()> {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir()?;
        let plain = dir.path().join("plain");
        File::create(&plain)?;
        let atomic = dir.path().join("atomic");
        write_atomic(&atomic, b"x")?;
        let mode = |p: &Path| fs::metadata(p).map(|m| m.permissions().mode() & 0o777);
        assert_eq!(mode(&atomic)?, mode(&plain)?);
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
