//! The temporary file beside an output: a short random name
//! (`.pgo-XXXXXXXX.tmp`), created exclusively, never more permissive than
//! the final file, and held under an exclusive `flock` while it is written;
//! and the removal of the temporaries of killed runs (those nobody holds).

use std::fs::{self, File, Metadata};
use std::io;
use std::path::Path;
use tempfile::NamedTempFile;

/// The name of a temporary: `PREFIX`, `RANDOM` letters and digits, `SUFFIX`.
const PREFIX: &str = ".pgo-";
const SUFFIX: &str = ".tmp";
const RANDOM: usize = 8;

/// How often a temporary lost to a concurrent cleanup (see [`create`]) is
/// made again before giving up.
const ATTEMPTS: usize = 8;

/// Whether `name` is the name of one of our temporaries.
pub(super) fn is_temporary_name(name: &str) -> bool {
    name.len() == PREFIX.len() + RANDOM + SUFFIX.len()
        && name.starts_with(PREFIX)
        && name.ends_with(SUFFIX)
        && name[PREFIX.len()..PREFIX.len() + RANDOM]
            .bytes()
            .all(|b| b.is_ascii_alphanumeric())
}

/// A new temporary in `dir`, locked, with the owner and mode of `like` (the
/// file it will replace) where the process may set them, else with `0666`
/// less the umask.
pub(super) fn create(dir: &Path, like: Option<&Metadata>) -> io::Result<NamedTempFile> {
    let mut builder = tempfile::Builder::new();
    builder.prefix(PREFIX).suffix(SUFFIX).rand_bytes(RANDOM);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        // Created with the final mode less the umask (never more open than
        // the final file); the exact mode is set once the owner is.
        let mode = like.map_or(0o666, |m| m.permissions().mode() & 0o666);
        builder.permissions(fs::Permissions::from_mode(mode));
    }
    for _ in 0..ATTEMPTS {
        let mut temp = builder.tempfile_in(dir)?;
        if lock_own(&temp)? {
            if let Some(like) = like {
                copy_owner_and_mode(temp.as_file(), like)?;
            }
            return Ok(temp);
        }
        // A cleanup removed it between its creation and the lock: the name
        // may be someone else's by now, so do not remove it on drop.
        temp.disable_cleanup(true);
    }
    Err(io::Error::other(format!(
        "{ATTEMPTS} temporary files were removed as soon as they were made"
    )))
}

/// Locks a new temporary; false when it was lost to a concurrent cleanup
/// (the cleanup holds it, or has removed it already).
#[cfg(unix)]
fn lock_own(temp: &NamedTempFile) -> io::Result<bool> {
    use rustix::fs::{FlockOperation, flock};
    match flock(temp.as_file(), FlockOperation::NonBlockingLockExclusive) {
        Ok(()) => {}
        Err(rustix::io::Errno::WOULDBLOCK) => return Ok(false),
        // No locks on this file system: no cleanup can lock it either, so
        // none removes it.
        Err(_) => return Ok(true),
    }
    Ok(still_linked(temp.path(), temp.as_file()))
}

#[cfg(not(unix))]
fn lock_own(_: &NamedTempFile) -> io::Result<bool> {
    Ok(true)
}

/// Whether `path` still names the file `file` (not removed or replaced).
#[cfg(unix)]
fn still_linked(path: &Path, file: &File) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (fs::symlink_metadata(path), file.metadata()) {
        (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
        _ => false,
    }
}

/// Gives `file` the owner, group and mode of `like`. Changing the owner is
/// best effort (only root may give a file away); the mode is set after it,
/// since a change of owner clears the set-id bits.
#[cfg(unix)]
fn copy_owner_and_mode(file: &File, like: &Metadata) -> io::Result<()> {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let own = file.metadata()?;
    if (own.uid(), own.gid()) != (like.uid(), like.gid())
        && std::os::unix::fs::fchown(file, Some(like.uid()), Some(like.gid())).is_err()
    {
        // Not root: the group may still be ours to set.
        let _ = std::os::unix::fs::fchown(file, None, Some(like.gid()));
    }
    file.set_permissions(fs::Permissions::from_mode(like.mode() & 0o7777))
}

#[cfg(not(unix))]
fn copy_owner_and_mode(file: &File, like: &Metadata) -> io::Result<()> {
    file.set_permissions(like.permissions())
}

/// Removes the temporaries in `dir` that no process holds: leftovers of
/// killed runs. Errors are ignored (a leftover is harmless: it is never
/// read).
pub(super) fn remove_stale(dir: &Path) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        if entry.file_name().to_str().is_some_and(is_temporary_name) {
            let _ = remove_if_stale(&entry.path());
        }
    }
}

/// Removes `path` if it is a regular file of ours (same user) that nobody
/// holds locked; never through a link, never waiting on a FIFO.
#[cfg(unix)]
fn remove_if_stale(path: &Path) -> io::Result<bool> {
    use rustix::fs::{FlockOperation, Mode, OFlags, flock};
    use std::os::unix::fs::MetadataExt;
    let flags = OFlags::RDONLY | OFlags::NOFOLLOW | OFlags::NONBLOCK | OFlags::CLOEXEC;
    let file = File::from(rustix::fs::open(path, flags, Mode::empty())?);
    let meta = file.metadata()?;
    if !meta.is_file() || meta.uid() != rustix::process::geteuid().as_raw() {
        return Ok(false);
    }
    if flock(&file, FlockOperation::NonBlockingLockExclusive).is_err() {
        return Ok(false);
    }
    // Locked by us now: remove it if the name still leads to it.
    if !still_linked(path, &file) {
        return Ok(false);
    }
    fs::remove_file(path)?;
    Ok(true)
}

#[cfg(not(unix))]
fn remove_if_stale(_: &Path) -> io::Result<bool> {
    Ok(false)
}
