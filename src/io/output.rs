//! A result folder written as one unit: filled beside its target, then swapped in whole.
//!
//! [`OutputDir::begin`] takes the target's lock (`OUT.lock`, created exclusively, holding
//! the writer's pid), puts back or removes what a killed writer left (see below) and
//! creates a fresh staging folder `OUT.tmp-PID-N` beside the target. The run writes every
//! file there. [`OutputDir::commit`] flushes them to disk, renames the old `OUT` aside
//! (`OUT.old-PID-N`), renames the staging folder to `OUT`, removes the old one and
//! flushes the parent folder. Whatever stops the process, `OUT` holds the old result or
//! the new one, complete: never files of both.
//!
//! A writer killed between the two renames leaves no `OUT` and an `OUT.old-PID-N` of a
//! process no longer running: the next [`OutputDir::begin`] on the same target renames it
//! back. Staging folders and locks of processes no longer running are removed.
//!
//! Only what filmscope wrote is replaced. Every entry of the previous `OUT` that the new
//! result does not write and that is not a filmscope file (a user's `notes.txt`, a folder
//! of their own) is moved into the new `OUT` after the swap. The previous result's
//! filmscope files the new one does not write (`report.html` and `pixel-X-Y.png`/`.csv` of
//! `filmscope report`, which describe the previous maps) are removed, and named in one
//! note on stderr. A writer killed after the swap but before its move leaves the user's
//! entries in `OUT.old-PID-N`; the next [`OutputDir::begin`] moves them in then.
//!
//! A second writer while the first runs is refused with one line naming the first's pid.
//! A target that exists but holds something other than a filmscope result (no
//! `summary.json`, `acquisition.json` or `capture` folder, and not empty) is refused
//! rather than written into.

use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Distinguishes staging folders created by one process.
static COUNTER: AtomicU64 = AtomicU64::new(0);

/// Names whose presence marks a folder as a filmscope result (or a partial acquisition).
const RESULT_MARKERS: [&str; 4] = [
    "summary.json",
    "acquisition.json",
    "capture",
    "capture.toml",
];

/// Files and folders a filmscope result consists of (`estimate`, `acquire`).
const RESULT_FILES: [&str; 16] = [
    "summary.json",
    "acquisition.json",
    "capture",
    "capture.toml",
    "thickness_nm.hdr",
    "thickness_nm.img",
    "thickness_nm.png",
    "thickness_sigma_nm.hdr",
    "thickness_sigma_nm.img",
    "confidence.hdr",
    "confidence.img",
    "flags.hdr",
    "flags.img",
    "index.csv",
    "index.yml",
    "report.html",
];

/// Whether `name` is a file filmscope writes into a result folder: one of
/// [`RESULT_FILES`] or a `pixel-X-Y.png`/`.csv` of `filmscope report --pixel`.
fn is_filmscope_file(name: &str) -> bool {
    if RESULT_FILES.contains(&name) {
        return true;
    }
    let Some(stem) = name
        .strip_suffix(".png")
        .or_else(|| name.strip_suffix(".csv"))
    else {
        return false;
    };
    let Some((x, y)) = stem.strip_prefix("pixel-").and_then(|r| r.split_once('-')) else {
        return false;
    };
    let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
    digits(x) && digits(y)
}

/// What a commit did with the previous result's entries the new one does not write.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Replaced {
    /// Entries not written by filmscope, moved into the new result (sorted).
    pub kept: Vec<String>,
    /// filmscope files of the previous result the new one does not write, removed
    /// (sorted): its `report.html` and `pixel-X-Y` files.
    pub removed: Vec<String>,
}

impl Replaced {
    /// One line for stderr when previous filmscope files were removed, naming them.
    pub fn note(&self, target: &Path) -> Option<String> {
        if self.removed.is_empty() {
            return None;
        }
        let mut line = format!(
            "{}: removed {} of the previous result (they described its maps; run `filmscope report` again)",
            target.display(),
            self.removed.join(", ")
        );
        if !self.kept.is_empty() {
            line.push_str(&format!("; kept {}", self.kept.join(", ")));
        }
        Some(line)
    }
}

/// Moves every entry of `old` that `new` does not hold and that is not a filmscope file
/// into `new`; lists the filmscope files of `old` that `new` does not hold (removed with
/// `old` by the caller).
fn carry_over(old: &Path, new: &Path) -> io::Result<Replaced> {
    let mut done = Replaced::default();
    let mut names: Vec<_> = fs::read_dir(old)?
        .map(|e| e.map(|e| e.file_name()))
        .collect::<io::Result<_>>()?;
    names.sort();
    for name in names {
        let to = new.join(&name);
        if fs::symlink_metadata(&to).is_ok() {
            continue;
        }
        let text = name.to_string_lossy().into_owned();
        if is_filmscope_file(&text) {
            done.removed.push(text);
        } else {
            fs::rename(old.join(&name), &to)?;
            done.kept.push(text);
        }
    }
    Ok(done)
}

/// A result folder that cannot be written, one line: `PATH: problem`.
#[derive(Debug, thiserror::Error)]
#[error("{}: {message}", .path.display())]
pub struct OutputDirError {
    /// The folder or file concerned.
    pub path: PathBuf,
    /// What went wrong.
    pub message: String,
}

fn fail(path: &Path, message: impl std::fmt::Display) -> OutputDirError {
    OutputDirError {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

/// A result folder being written: see the [module docs](self).
#[derive(Debug)]
pub struct OutputDir {
    target: PathBuf,
    staging: PathBuf,
    lock: PathBuf,
    done: bool,
}

/// `NAME.KIND-PID-N` beside `target`.
fn sibling(target: &Path, kind: &str, pid: u32, n: u64) -> PathBuf {
    let mut name = target.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".{kind}-{pid}-{n}"));
    target.with_file_name(name)
}

/// The pid in a sibling name `NAME.KIND-PID-N`, if `entry` is one of `target`'s.
fn sibling_owner(name: &str, target_name: &str, kind: &str) -> Option<u32> {
    let rest = name.strip_prefix(target_name)?.strip_prefix('.')?;
    let rest = rest.strip_prefix(kind)?.strip_prefix('-')?;
    let (pid, n) = rest.split_once('-')?;
    n.parse::<u64>().ok()?;
    pid.parse().ok()
}

/// Whether process `pid` is running (`true` where that cannot be told: nothing is then
/// taken for stale).
fn alive(pid: u32) -> bool {
    let proc_dir = Path::new("/proc");
    if !proc_dir.join("self").exists() {
        return true;
    }
    pid == std::process::id() || proc_dir.join(pid.to_string()).exists()
}

/// `target` made absolute without requiring it to exist (its parent must).
fn absolute(target: &Path) -> io::Result<PathBuf> {
    let name = target
        .file_name()
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "no folder name"))?;
    let parent = match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    Ok(fs::canonicalize(parent)?.join(name))
}

impl OutputDir {
    /// Locks `target`, cleans what killed writers left, and creates the staging folder
    /// (the target's parent folders are created too). Fails with one line when another
    /// process holds the lock, when the target is not a folder or holds something other
    /// than a result, or when its folder cannot be written: before any computation.
    pub fn begin(target: &Path) -> Result<Self, OutputDirError> {
        let name = target
            .file_name()
            .and_then(|n| n.to_str())
            .filter(|n| !n.is_empty() && *n != "." && *n != "..")
            .ok_or_else(|| fail(target, "the output folder needs a plain (UTF-8) name"))?
            .to_owned();
        if let Some(parent) = target.parent().filter(|p| !p.as_os_str().is_empty()) {
            fs::create_dir_all(parent).map_err(|e| fail(parent, format!("cannot create: {e}")))?;
        }
        let target = absolute(target).map_err(|e| fail(target, e))?;
        let lock = target.with_file_name(format!("{name}.lock"));
        take_lock(&lock)?;
        let mut out = Self {
            staging: PathBuf::new(),
            target,
            lock,
            done: false,
        };
        out.recover(&name)?;
        match fs::symlink_metadata(&out.target) {
            Ok(m) if m.file_type().is_symlink() => {
                return Err(fail(
                    &out.target,
                    "is a symbolic link; give the folder it points to",
                ))
            }
            Ok(m) if !m.is_dir() => {
                return Err(fail(&out.target, "exists and is not a folder"));
            }
            Ok(_) => {
                if let Some(other) = foreign_entry(&out.target) {
                    return Err(fail(
                        &out.target,
                        format!(
                            "holds {other:?}, which is not part of a filmscope result: choose a new or empty folder"
                        ),
                    ));
                }
            }
            Err(_) => {}
        }
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let staging = sibling(&out.target, "tmp", std::process::id(), n);
        fs::create_dir(&staging)
            .map_err(|e| fail(&staging, format!("cannot create the output: {e}")))?;
        out.staging = staging;
        Ok(out)
    }

    /// Puts back a result a killed writer had renamed aside, and removes staging and old
    /// folders of writers no longer running.
    fn recover(&self, name: &str) -> Result<(), OutputDirError> {
        let Some(parent) = self.target.parent() else {
            return Ok(());
        };
        let Ok(entries) = fs::read_dir(parent) else {
            return Ok(());
        };
        let mut olds = Vec::new();
        for entry in entries.filter_map(Result::ok) {
            let file_name = entry.file_name();
            let Some(entry_name) = file_name.to_str() else {
                continue;
            };
            if let Some(pid) = sibling_owner(entry_name, name, "tmp") {
                if !alive(pid) {
                    let _ = fs::remove_dir_all(entry.path());
                }
            } else if let Some(pid) = sibling_owner(entry_name, name, "old") {
                if !alive(pid) {
                    olds.push(entry.path());
                }
            }
        }
        for old in olds {
            if self.target.exists() {
                // Killed after the swap: the user's entries may still be aside.
                carry_over(&old, &self.target).map_err(|e| {
                    fail(
                        &old,
                        format!(
                            "cannot move the files kept from the previous result into {}: {e}",
                            self.target.display()
                        ),
                    )
                })?;
                sync_dir(&self.target);
                let _ = fs::remove_dir_all(&old);
            } else {
                fs::rename(&old, &self.target)
                    .map_err(|e| fail(&old, format!("cannot put the previous result back: {e}")))?;
            }
        }
        Ok(())
    }

    /// The staging folder: write every file of the result here.
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// The folder the result becomes (absolute).
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Whether the target holds a result (or anything) now.
    pub fn target_holds_result(&self) -> bool {
        fs::read_dir(&self.target).is_ok_and(|mut d| d.next().is_some())
    }

    /// Flushes the staging folder to disk and swaps it in for the target; then moves the
    /// previous result's entries that are not filmscope's into it (see the
    /// [module docs](self)) and prints one note on stderr naming the previous filmscope
    /// files removed, if any.
    pub fn commit(mut self) -> Result<Replaced, OutputDirError> {
        sync_tree(&self.staging).map_err(|e| fail(&self.staging, format!("cannot flush: {e}")))?;
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let old = sibling(&self.target, "old", std::process::id(), n);
        let had_old = match fs::rename(&self.target, &old) {
            Ok(()) => true,
            Err(e) if e.kind() == io::ErrorKind::NotFound => false,
            Err(e) => {
                return Err(fail(
                    &self.target,
                    format!("cannot move the previous result aside: {e}"),
                ))
            }
        };
        if let Err(e) = fs::rename(&self.staging, &self.target) {
            if had_old {
                let _ = fs::rename(&old, &self.target);
            }
            return Err(fail(
                &self.target,
                format!("cannot move the result in: {e}"),
            ));
        }
        self.done = true;
        sync_dir(self.target.parent().unwrap_or(Path::new(".")));
        let mut replaced = Replaced::default();
        if had_old {
            replaced = carry_over(&old, &self.target).map_err(|e| {
                fail(
                    &old,
                    format!(
                        "the new result is in {}, but the files kept from the previous one could not be moved there ({e}); they stay here",
                        self.target.display()
                    ),
                )
            })?;
            sync_dir(&self.target);
            let _ = fs::remove_dir_all(&old);
        }
        if let Some(note) = replaced.note(&self.target) {
            log::info!("filmscope: note: {note}");
        }
        Ok(replaced)
    }

    /// Commits a partial result (an interrupted acquisition): into the target when it
    /// holds no result, else beside it as `OUT.partial` (replacing an older partial), so a
    /// failed run never replaces a complete one. Returns where it went.
    pub fn commit_partial(mut self) -> Result<PathBuf, OutputDirError> {
        if !self.target_holds_result() {
            let target = self.target.clone();
            self.commit()?;
            return Ok(target);
        }
        sync_tree(&self.staging).map_err(|e| fail(&self.staging, format!("cannot flush: {e}")))?;
        let mut name = self.target.file_name().unwrap_or_default().to_os_string();
        name.push(".partial");
        let partial = self.target.with_file_name(name);
        if partial.exists() {
            fs::remove_dir_all(&partial)
                .map_err(|e| fail(&partial, format!("cannot replace: {e}")))?;
        }
        fs::rename(&self.staging, &partial)
            .map_err(|e| fail(&partial, format!("cannot move the partial result in: {e}")))?;
        self.done = true;
        sync_dir(self.target.parent().unwrap_or(Path::new(".")));
        Ok(partial)
    }
}

impl Drop for OutputDir {
    fn drop(&mut self) {
        if !self.done && !self.staging.as_os_str().is_empty() {
            let _ = fs::remove_dir_all(&self.staging);
        }
        let _ = fs::remove_file(&self.lock);
    }
}

/// Times a lock is tried (20 ms apart while another writer is still writing its pid).
const LOCK_TRIES: usize = 50;

/// Creates `lock` exclusively with this process's pid; a lock of a process no longer
/// running is taken over, one of a running process refused.
fn take_lock(lock: &Path) -> Result<(), OutputDirError> {
    for _ in 0..LOCK_TRIES {
        match OpenOptions::new().write(true).create_new(true).open(lock) {
            Ok(mut f) => {
                let _ = writeln!(f, "{}", std::process::id());
                return Ok(());
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                let text = fs::read_to_string(lock).unwrap_or_default();
                match text.trim().parse::<u32>() {
                    Ok(pid) if !alive(pid) => {
                        let _ = fs::remove_file(lock);
                    }
                    Ok(pid) => {
                        return Err(fail(
                            lock,
                            format!(
                                "another filmscope (pid {pid}) is writing this output; wait for it to finish"
                            ),
                        ))
                    }
                    // Being created this instant: its pid follows within moments.
                    Err(_) if text.trim().is_empty() => {
                        std::thread::sleep(std::time::Duration::from_millis(20));
                    }
                    // Not ours: not taken over.
                    Err(_) => {
                        return Err(fail(
                            lock,
                            "the output is locked (remove this file if no filmscope is running)",
                        ))
                    }
                }
            }
            Err(e) => return Err(fail(lock, format!("cannot create the lock: {e}"))),
        }
    }
    Err(fail(lock, "the output lock keeps changing hands"))
}

/// The first entry of `dir` that no filmscope result holds, when `dir` holds no result
/// marker at all (an empty folder or a result folder gives `None`).
fn foreign_entry(dir: &Path) -> Option<String> {
    let entries: Vec<String> = fs::read_dir(dir)
        .ok()?
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    if entries.iter().any(|e| RESULT_MARKERS.contains(&e.as_str())) {
        return None;
    }
    entries.into_iter().min()
}

/// Flushes every file and folder under `dir` to disk.
fn sync_tree(dir: &Path) -> io::Result<()> {
    for entry in fs::read_dir(dir)? {
        let entry = entry?;
        let kind = entry.file_type()?;
        if kind.is_dir() {
            sync_tree(&entry.path())?;
        } else if kind.is_file() {
            File::open(entry.path())?.sync_all()?;
        }
    }
    sync_dir(dir);
    Ok(())
}

/// Flushes a folder's entries (best effort: not every platform can).
fn sync_dir(dir: &Path) {
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Refuses an output folder that would replace an input: `out` may not be or lie inside
/// any of `folders` (a capture folder), and may not contain any of `files` or `folders`
/// (swapping it would remove them). `what` names the option (`--out`).
pub fn check_outside_inputs(
    what: &str,
    out: &Path,
    files: &[PathBuf],
    folders: &[PathBuf],
) -> Result<(), OutputDirError> {
    let Ok(out_abs) = absolute(out) else {
        // A parent that does not exist yet cannot hold any input.
        return Ok(());
    };
    let out_abs = fs::canonicalize(&out_abs).unwrap_or(out_abs);
    for folder in folders {
        let Ok(f) = fs::canonicalize(folder) else {
            continue;
        };
        if out_abs.starts_with(&f) {
            return Err(fail(
                out,
                format!(
                    "{what} is the input folder {} or inside it: the result would replace its files; choose another folder",
                    folder.display()
                ),
            ));
        }
    }
    for input in files.iter().chain(folders) {
        let Ok(f) = fs::canonicalize(input) else {
            continue;
        };
        if f.starts_with(&out_abs) {
            return Err(fail(
                out,
                format!(
                    "{what} holds the input {}: writing the result there would replace it; choose another folder",
                    input.display()
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commit_swaps_whole_and_drop_leaves_the_old() -> Result<(), Box<dyn std::error::Error>> {
        let dir = tempfile::tempdir()?;
        let out = dir.path().join("maps");
        let w = OutputDir::begin(&out)?;
        fs::write(w.path().join("summary.json"), "1")?;
        w.commit()?;
        let w = OutputDir::begin(&out)?;
        fs::write(w.path().join("summary.json"), "2")?;
        drop(w);
        assert_eq!(fs::read_to_string(out.join("summary.json"))?, "1");
        let names: Vec<_> = fs::read_dir(dir.path())?.filter_map(Result::ok).collect();
        assert_eq!(names.len(), 1, "no staging folder or lock left");
        Ok(())
    }

    #[test]
    fn a_result_renamed_aside_by_a_dead_writer_is_put_back(
    ) -> Result<(), Box<dyn std::error::Error>> {
        let dir = tempfile::tempdir()?;
        let out = dir.path().join("maps");
        // PIDs above the kernel's maximum (4194304) never run.
        let old = dir.path().join("maps.old-4999999-0");
        fs::create_dir(&old)?;
        fs::write(old.join("summary.json"), "old")?;
        fs::create_dir(dir.path().join("maps.tmp-4999999-1"))?;
        fs::write(dir.path().join("maps.lock"), "4999999\n")?;
        let w = OutputDir::begin(&out)?;
        if Path::new("/proc/self").exists() {
            assert_eq!(fs::read_to_string(out.join("summary.json"))?, "old");
            assert!(!dir.path().join("maps.tmp-4999999-1").exists());
        }
        drop(w);
        Ok(())
    }

    #[test]
    fn a_users_files_are_kept_and_only_filmscope_files_replaced(
    ) -> Result<(), Box<dyn std::error::Error>> {
        let dir = tempfile::tempdir()?;
        let out = dir.path().join("maps");
        let w = OutputDir::begin(&out)?;
        fs::write(w.path().join("summary.json"), "1")?;
        fs::write(w.path().join("index.csv"), "1")?;
        w.commit()?;
        fs::write(out.join("notes.txt"), "mine")?;
        fs::create_dir(out.join("photos"))?;
        fs::write(out.join("photos").join("a.jpg"), "jpg")?;
        fs::write(out.join("report.html"), "old report")?;
        fs::write(out.join("pixel-3-14.png"), "old")?;
        fs::write(out.join("pixel-3-14.csv"), "old")?;
        fs::write(out.join("pixel-3.csv"), "not a pixel file")?;
        let w = OutputDir::begin(&out)?;
        fs::write(w.path().join("summary.json"), "2")?;
        let replaced = w.commit()?;
        assert_eq!(fs::read_to_string(out.join("summary.json"))?, "2");
        assert_eq!(fs::read_to_string(out.join("notes.txt"))?, "mine");
        assert_eq!(fs::read_to_string(out.join("photos").join("a.jpg"))?, "jpg");
        assert_eq!(
            fs::read_to_string(out.join("pixel-3.csv"))?,
            "not a pixel file"
        );
        assert_eq!(replaced.kept, ["notes.txt", "photos", "pixel-3.csv"]);
        assert_eq!(
            replaced.removed,
            [
                "index.csv",
                "pixel-3-14.csv",
                "pixel-3-14.png",
                "report.html"
            ]
        );
        assert!(!out.join("report.html").exists() && !out.join("index.csv").exists());
        let note = replaced.note(&out).ok_or("no note")?;
        assert!(
            note.contains("report.html") && note.contains("notes.txt"),
            "{note}"
        );
        let names: Vec<_> = fs::read_dir(dir.path())?.filter_map(Result::ok).collect();
        assert_eq!(names.len(), 1, "no old folder or lock left");
        Ok(())
    }

    #[test]
    fn a_users_files_left_aside_by_a_dead_writer_are_moved_in(
    ) -> Result<(), Box<dyn std::error::Error>> {
        if !Path::new("/proc/self").exists() {
            return Ok(());
        }
        let dir = tempfile::tempdir()?;
        let out = dir.path().join("maps");
        fs::create_dir(&out)?;
        fs::write(out.join("summary.json"), "new")?;
        // Killed after the swap, before the move: the user's file is still aside.
        let old = dir.path().join("maps.old-4999999-0");
        fs::create_dir(&old)?;
        fs::write(old.join("summary.json"), "old")?;
        fs::write(old.join("notes.txt"), "mine")?;
        let w = OutputDir::begin(&out)?;
        assert_eq!(fs::read_to_string(out.join("notes.txt"))?, "mine");
        assert_eq!(fs::read_to_string(out.join("summary.json"))?, "new");
        assert!(!old.exists());
        drop(w);
        Ok(())
    }

    #[test]
    fn a_folder_of_other_files_is_not_replaced() -> Result<(), Box<dyn std::error::Error>> {
        let dir = tempfile::tempdir()?;
        fs::write(dir.path().join("thesis.tex"), "x")?;
        let e = OutputDir::begin(dir.path()).err().ok_or("accepted")?;
        assert!(e.to_string().contains("thesis.tex"), "{e}");
        Ok(())
    }
}
