//! Writing outputs whole or not at all, never onto an input: the one place the tools write
//! files and dataset directories.
//!
//! - [`write_file`]: the bytes go to a temporary file beside the target, are flushed to disk,
//!   then renamed over it; a reader (or a crash) sees the old file or the new one, never a mix.
//! - [`StagedDir`]: a dataset directory is written into a fresh temporary directory beside the
//!   target, then moved into place in one step (on Linux an atomic exchange with the old one).
//!   Dropped before [`StagedDir::commit`], it removes what it wrote; a process killed before
//!   the commit leaves the old dataset as it was and a `.NAME.partial-PID-N` directory beside
//!   it, which the next write of that dataset removes once process PID is gone (on Linux).
//! - [`check_file`], [`check_files`], [`check_dataset_dir`]: what a command may write,
//!   checked before any long work: an existing file or dataset only with `force`; never an
//!   input, a path inside an input directory or a file inside any dataset directory, whatever
//!   `force` says.

use crate::{DatasetError, MANIFEST_FILE};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Distinguishes temporary names made by one process.
static COUNTER: AtomicU64 = AtomicU64::new(0);

fn refused(path: &Path, message: impl Into<String>) -> DatasetError {
    DatasetError::Refused { path: path.to_path_buf(), message: message.into() }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io { path: path.to_path_buf(), source }
}

/// A fresh name beside `path`: `.NAME.TAG-PID-N` in the same directory (so a rename is not
/// across file systems).
fn beside(path: &Path, tag: &str) -> PathBuf {
    let name = path.file_name().map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    path.with_file_name(format!(".{name}.{tag}-{}-{n}", std::process::id()))
}

/// The directory a relative or bare file name lives in.
fn parent_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Writes `bytes` to `path` whole or not at all (a temporary file beside it, flushed, then
/// renamed over it). Checks nothing: [`check_file`] says whether the path may be written.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), DatasetError> {
    if path.is_dir() {
        return Err(refused(path, "is a directory, not a file"));
    }
    let tmp = beside(path, "tmp");
    let result = (|| {
        let mut file = std::fs::File::create(&tmp).map_err(io(path))?;
        file.write_all(bytes).map_err(io(path))?;
        file.sync_all().map_err(io(path))?;
        std::fs::rename(&tmp, path).map_err(io(path))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// The canonical form of a path that may not exist yet (its parent's canonical form and its
/// name), for comparing outputs with inputs.
fn canonical(path: &Path) -> PathBuf {
    if let Ok(p) = path.canonicalize() {
        return p;
    }
    match (parent_of(path).canonicalize(), path.file_name()) {
        (Ok(parent), Some(name)) => parent.join(name),
        _ => path.to_path_buf(),
    }
}

/// Refuses `output` when it is one of `inputs` or lies inside one of them (a dataset
/// directory), or holds one (a directory about to be replaced).
fn check_not_input(output: &Path, inputs: &[&Path]) -> Result<(), DatasetError> {
    let out = canonical(output);
    for input in inputs {
        let inp = canonical(input);
        if out == inp {
            return Err(refused(output, format!("is an input of this command ({}); write elsewhere", input.display())));
        }
        if out.starts_with(&inp) {
            return Err(refused(
                output,
                format!("is inside {}, an input of this command; write elsewhere", input.display()),
            ));
        }
        if inp.starts_with(&out) {
            return Err(refused(
                output,
                format!("holds {}, an input of this command; write elsewhere", input.display()),
            ));
        }
    }
    Ok(())
}

/// Whether a command may write the file `path`: never one of `inputs` or inside one of them,
/// never inside a dataset directory (a dataset is written only as a whole); an existing file
/// only with `force`; never a directory.
pub fn check_file(path: &Path, force: bool, inputs: &[&Path]) -> Result<(), DatasetError> {
    check_not_input(path, inputs)?;
    let dir = parent_of(path);
    if dir.join(MANIFEST_FILE).is_file() {
        return Err(refused(
            path,
            format!("is inside the dataset {} (a dataset is written only as a whole); write elsewhere", dir.display()),
        ));
    }
    match std::fs::metadata(path) {
        Ok(meta) if meta.is_dir() => Err(refused(path, "is a directory, not a file")),
        Ok(_) if !force => Err(refused(path, "already exists (--force replaces it)")),
        _ => Ok(()),
    }
}

/// [`check_file`] of each of a command's `outputs`, and that no two are the same file (the
/// second would replace the first).
pub fn check_files(outputs: &[&Path], force: bool, inputs: &[&Path]) -> Result<(), DatasetError> {
    for (i, a) in outputs.iter().enumerate() {
        if let Some(b) = outputs[i + 1..].iter().find(|b| canonical(b) == canonical(a)) {
            return Err(refused(b, "is named for two outputs of this command"));
        }
        check_file(a, force, inputs)?;
    }
    Ok(())
}

/// Whether a command may write the dataset directory `dir`: a new or empty directory; one
/// holding a dataset (`manifest.json`) only with `force` (it is then replaced as a whole);
/// never a directory holding other files, never an input or one holding or inside an input.
pub fn check_dataset_dir(dir: &Path, force: bool, inputs: &[&Path]) -> Result<(), DatasetError> {
    check_not_input(dir, inputs)?;
    let meta = match std::fs::metadata(dir) {
        Ok(meta) => meta,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(source) => return Err(DatasetError::Io { path: dir.to_path_buf(), source }),
    };
    if !meta.is_dir() {
        return Err(refused(dir, "exists and is not a directory"));
    }
    let mut entries = std::fs::read_dir(dir).map_err(io(dir))?;
    if entries.next().is_none() {
        return Ok(());
    }
    if !dir.join(MANIFEST_FILE).is_file() {
        return Err(refused(dir, "holds files but no dataset (no manifest.json); choose a new or empty directory"));
    }
    if !force {
        return Err(refused(dir, "holds a dataset (--force replaces the whole directory)"));
    }
    Ok(())
}

/// A dataset directory being written: a fresh temporary directory beside the target, moved
/// into place by [`StagedDir::commit`] and removed if dropped before.
#[derive(Debug)]
pub struct StagedDir {
    target: PathBuf,
    staging: PathBuf,
    committed: bool,
}

impl StagedDir {
    /// Creates the temporary directory beside `target` (and `target`'s parent if needed),
    /// after removing those that killed writers of `target` left.
    pub fn new(target: &Path) -> Result<Self, DatasetError> {
        let parent = parent_of(target);
        std::fs::create_dir_all(parent).map_err(io(parent))?;
        remove_left_behind(target, "partial");
        let staging = beside(target, "partial");
        std::fs::create_dir(&staging).map_err(io(target))?;
        Ok(Self { target: target.to_path_buf(), staging, committed: false })
    }

    /// Where to write the files.
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// Moves the written directory into place: onto a new name, over an empty directory, or in
    /// exchange for an existing one (which is then removed).
    pub fn commit(mut self) -> Result<(), DatasetError> {
        let target = self.target.clone();
        sync_dir(&self.staging);
        // A rename replaces a missing target or an empty directory.
        let renamed = std::fs::rename(&self.staging, &target);
        if renamed.is_ok() {
            self.committed = true;
            sync_dir(parent_of(&target));
            return Ok(());
        }
        if !target.is_dir() {
            return renamed.map_err(io(&target));
        }
        // The target holds files: swap it for the new one, then remove the old.
        if exchange(&self.staging, &target).is_ok() {
            self.committed = true;
            sync_dir(parent_of(&target));
            return std::fs::remove_dir_all(&self.staging).map_err(io(&self.staging));
        }
        let old = beside(&target, "old");
        std::fs::rename(&target, &old).map_err(io(&target))?;
        if let Err(source) = std::fs::rename(&self.staging, &target) {
            let _ = std::fs::rename(&old, &target);
            return Err(DatasetError::Io { path: target, source });
        }
        self.committed = true;
        std::fs::remove_dir_all(&old).map_err(io(&old))
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
    }
}

/// Removes the `.NAME.TAG-PID-N` entries beside `target` whose process has ended (best
/// effort). Only where the system says which processes run (`/proc`); a PID in use again
/// keeps its entry.
fn remove_left_behind(target: &Path, tag: &str) {
    let proc_fs = Path::new("/proc");
    if !proc_fs.join("self").exists() {
        return;
    }
    let Some(name) = target.file_name().map(|n| n.to_string_lossy().into_owned()) else { return };
    let Ok(entries) = std::fs::read_dir(parent_of(target)) else { return };
    let prefix = format!(".{name}.{tag}-");
    for entry in entries.flatten() {
        let file_name = entry.file_name().to_string_lossy().into_owned();
        let Some(rest) = file_name.strip_prefix(&prefix) else { continue };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else { continue };
        if pid != std::process::id() && !proc_fs.join(pid.to_string()).exists() {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// Flushes a directory's entries to disk (best effort: not every platform opens directories).
fn sync_dir(dir: &Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Swaps two directories in one step (Linux `renameat2(RENAME_EXCHANGE)`).
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let a = CString::new(a.as_os_str().as_bytes())?;
    let b = CString::new(b.as_os_str().as_bytes())?;
    // SAFETY: both are NUL-terminated paths that live across the call; AT_FDCWD resolves
    // them as relative to the working directory, as `std::fs::rename` does.
    let rc = unsafe { libc::renameat2(libc::AT_FDCWD, a.as_ptr(), libc::AT_FDCWD, b.as_ptr(), libc::RENAME_EXCHANGE) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
fn exchange(_a: &Path, _b: &Path) -> std::io::Result<()> {
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

/// An error and its causes as one line, `a: b: c`, each cause once (a cause whose text its
/// error already shows, as `{path}: {source}` does, is not repeated).
pub fn error_text(error: &(dyn std::error::Error + 'static)) -> String {
    let mut text = error.to_string();
    let mut cause = error.source();
    while let Some(c) = cause {
        let part = c.to_string();
        if !text.contains(&part) {
            text.push_str(": ");
            text.push_str(&part);
        }
        cause = c.source();
    }
    text
}
