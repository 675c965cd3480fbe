//! An exclusive lock on an output folder, so that two commands writing the same files into it
//! (two renders, two reports) cannot mix them: the second is refused.

use std::path::Path;

use anyhow::{bail, Context, Result};

/// An exclusive lock on `<dir>/<name>` (released when the file is dropped or the process ends,
/// however it ends): a second `command` into the same folder is refused instead of mixing its
/// files with the first's. Errors: the lock is held, or `<dir>/<name>` is not a regular file
/// or cannot be opened.
pub(crate) fn lock_folder(dir: &Path, name: &str, command: &str) -> Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    let path = dir.join(name);
    let not_a_file = || {
        anyhow::anyhow!(
            "{} is not a regular file (a pipe, device or link?): remove it, or choose another \
             --out",
            path.display()
        )
    };
    if std::fs::symlink_metadata(&path).is_ok_and(|m| !m.is_file()) {
        return Err(not_a_file());
    }
    // Non-blocking and not through a link: what appears under the name after the check above
    // fails to open or is refused below instead of blocking the open.
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .custom_flags(nix::libc::O_NONBLOCK | nix::libc::O_NOFOLLOW)
        .open(&path)
        .with_context(|| format!("opening {}", path.display()))?;
    if !file.metadata().is_ok_and(|m| m.is_file()) {
        return Err(not_a_file());
    }
    exclusive(file, &path, dir, command)
}

/// An exclusive lock on the folder `dir` itself (`flock` of the folder, no file made in it;
/// released when the handle is dropped or the process ends): a second `command` into the same
/// folder is refused. Errors: the lock is held, or the folder cannot be opened.
pub(crate) fn lock_dir(dir: &Path, command: &str) -> Result<std::fs::File> {
    let handle = std::fs::File::open(dir).with_context(|| format!("opening {}", dir.display()))?;
    exclusive(handle, dir, dir, command)
}

/// Takes the exclusive lock of `file` (opened from `path`) without waiting: held elsewhere, it
/// refuses a second `command` into `dir`.
fn exclusive(file: std::fs::File, path: &Path, dir: &Path, command: &str) -> Result<std::fs::File> {
    match file.try_lock() {
        Ok(()) => Ok(file),
        Err(std::fs::TryLockError::WouldBlock) => bail!(
            "another {command} is writing into {}; wait for it or choose another --out",
            dir.display()
        ),
        Err(std::fs::TryLockError::Error(e)) => {
            Err(e).with_context(|| format!("locking {}", path.display()))
        }
    }
}
