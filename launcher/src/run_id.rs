//! Run ids: what an id may be, default ids, and the exclusive claim of an id.
//!
//! An id names a run's iceoryx2 prefix (`qfleet.<id>.`) and is handed to every child as the
//! value of `--run-id`, so it must be checked before anything starts: 1 to
//! [`MAX_LEN`] characters of `A-Z a-z 0-9 _ -`, starting with a letter or digit (an id such as
//! `-x` would read as a flag on a child's command line).
//!
//! Two launchers started at the same moment with the same id must not both run: [`RunClaim`]
//! takes an exclusive `flock` on `<private dir>/<id>.lock` (the private dir is
//! `/tmp/qfleet-<uid>`, 0700, owned by the user, never a symlink). The lock is not a
//! check-then-act: the kernel grants it to one process, and releases it when that process
//! exits, however it exits (kill -9 included), so a dead launcher never keeps its id.

use std::fs::File;
use std::io::Write;
use std::os::fd::AsRawFd;
use std::os::unix::fs::{DirBuilderExt, MetadataExt, OpenOptionsExt};
use std::path::{Path, PathBuf};

/// Longest run id: the bus's limit (the id is part of every shared-memory file name).
pub const MAX_LEN: usize = bus_schema::RUN_ID_MAX_LEN;

/// Why a run id cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum RunIdError {
    /// The id is not of the allowed form.
    #[error(
        "invalid run id {id:?}: {reason} (1 to {MAX_LEN} of A-Z a-z 0-9 _ -, starting with a letter or digit)"
    )]
    Invalid {
        /// The id given.
        id: String,
        /// What is wrong with it.
        reason: String,
    },
    /// Another live launcher holds the id.
    #[error("run id {id} is in use by another live qfleet launcher (lock {}); pick another --run-id", path.display())]
    InUse {
        /// The id.
        id: String,
        /// The lock file held by the other launcher.
        path: PathBuf,
    },
    /// The private directory or the lock file could not be used.
    #[error("claiming run id {id}: {what} {}", path.display())]
    Io {
        /// The id.
        id: String,
        /// What was being done.
        what: &'static str,
        /// The path it was done to.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// The private directory is not safe to use (a symlink, another owner, open to others).
    #[error("claiming run id {id}: {} is not a private directory: {reason}", path.display())]
    Unsafe {
        /// The id.
        id: String,
        /// The directory.
        path: PathBuf,
        /// Why it is refused.
        reason: String,
    },
}

/// Checks that `id` is a usable run id.
pub fn validate(id: &str) -> Result<(), RunIdError> {
    let bad = |reason: String| RunIdError::Invalid {
        id: id.to_string(),
        reason,
    };
    let Some(first) = id.chars().next() else {
        return Err(bad("it is empty".into()));
    };
    if id.len() > MAX_LEN {
        return Err(bad(format!("it is {} bytes long", id.len())));
    }
    if let Some(c) = id
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || *c == '_' || *c == '-'))
    {
        return Err(bad(format!("it contains {c:?}")));
    }
    if !first.is_ascii_alphanumeric() {
        return Err(bad(format!("it starts with {first:?}")));
    }
    Ok(())
}

/// A default id: `<tag>-<pid>-<time in µs, hex>`, cut to [`MAX_LEN`].
pub fn generate(tag: &str) -> String {
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_micros() as u64)
        .unwrap_or(0);
    let mut id = format!("{tag}-{}-{:x}", std::process::id(), t & 0xff_ffff_ffff);
    id.truncate(MAX_LEN);
    id
}

/// A run id for one repetition of an experiment: `<prefix or exp>-<tag>-<pid>-<time>`.
pub fn repetition(prefix: Option<&str>, tag: &str) -> String {
    generate(&format!("{}-{tag}", prefix.unwrap_or("exp")))
}

/// The user's private directory for lock files: `/tmp/qfleet-<uid>`, created 0700 if missing;
/// refused if it is a symlink, not a directory, owned by someone else or open to others.
pub fn private_dir(id: &str) -> Result<PathBuf, RunIdError> {
    // SAFETY: getuid(2) cannot fail.
    let uid = unsafe { libc::getuid() };
    let dir = PathBuf::from(format!("/tmp/qfleet-{uid}"));
    match std::fs::DirBuilder::new().mode(0o700).create(&dir) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
        Err(source) => {
            return Err(RunIdError::Io {
                id: id.into(),
                what: "creating",
                path: dir,
                source,
            });
        }
    }
    let meta = std::fs::symlink_metadata(&dir).map_err(|source| RunIdError::Io {
        id: id.into(),
        what: "reading",
        path: dir.clone(),
        source,
    })?;
    let unsafe_dir = |reason: String| RunIdError::Unsafe {
        id: id.into(),
        path: dir.clone(),
        reason,
    };
    if !meta.file_type().is_dir() {
        return Err(unsafe_dir("it is not a directory (or is a symlink)".into()));
    }
    if meta.uid() != uid {
        return Err(unsafe_dir(format!("it is owned by uid {}", meta.uid())));
    }
    if meta.mode() & 0o077 != 0 {
        return Err(unsafe_dir(format!(
            "its mode is {:o}, others may write to it",
            meta.mode() & 0o7777
        )));
    }
    Ok(dir)
}

/// The exclusive claim of a run id, held until dropped or until the process dies.
#[derive(Debug)]
pub struct RunClaim {
    /// Held open: the lock lives exactly as long as this descriptor.
    _file: File,
    path: PathBuf,
}

impl RunClaim {
    /// Claims `id` (validating it first); [`RunIdError::InUse`] if a live launcher holds it.
    pub fn acquire(id: &str) -> Result<RunClaim, RunIdError> {
        validate(id)?;
        let dir = private_dir(id)?;
        Self::acquire_in(id, &dir)
    }

    /// Claims `id` with its lock file in `dir` (which the caller made private).
    pub fn acquire_in(id: &str, dir: &Path) -> Result<RunClaim, RunIdError> {
        let path = dir.join(format!("{id}.lock"));
        let io = |what: &'static str, source: std::io::Error| RunIdError::Io {
            id: id.into(),
            what,
            path: path.clone(),
            source,
        };
        // a holder may unlink the file while we open it: retry on a stale inode
        for _ in 0..10 {
            let mut file = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .mode(0o600)
                .custom_flags(libc::O_NOFOLLOW)
                .open(&path)
                .map_err(|e| io("opening", e))?;
            // SAFETY: flock(2) on a descriptor we own.
            let rc = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
            if rc != 0 {
                let e = std::io::Error::last_os_error();
                if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
                    return Err(RunIdError::InUse {
                        id: id.into(),
                        path,
                    });
                }
                return Err(io("locking", e));
            }
            let held = file.metadata().map_err(|e| io("reading", e))?;
            match std::fs::symlink_metadata(&path) {
                Ok(now) if now.ino() == held.ino() && now.dev() == held.dev() => {
                    let _ = file.set_len(0);
                    let _ = writeln!(file, "{}", std::process::id());
                    return Ok(RunClaim { _file: file, path });
                }
                // unlinked (or replaced) by the previous holder: lock the new file
                _ => continue,
            }
        }
        Err(RunIdError::InUse {
            id: id.into(),
            path,
        })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Removes the lock file of run `id` that a launcher which died left behind (a SIGKILL skips
/// [`RunClaim`]'s drop): `Some(path)` when one was removed, `None` when there was none or a live
/// launcher holds it (that run is not touched). For `qfleet clean`.
pub fn release_stale(id: &str) -> Result<Option<PathBuf>, RunIdError> {
    validate(id)?;
    release_stale_in(id, &private_dir(id)?)
}

/// [`release_stale`] with the lock files in `dir`.
pub fn release_stale_in(id: &str, dir: &Path) -> Result<Option<PathBuf>, RunIdError> {
    let path = dir.join(format!("{id}.lock"));
    if std::fs::symlink_metadata(&path).is_err() {
        return Ok(None);
    }
    match RunClaim::acquire_in(id, dir) {
        // nobody held it: dropping our claim unlinks the file
        Ok(claim) => {
            drop(claim);
            Ok(Some(path))
        }
        Err(RunIdError::InUse { .. }) => Ok(None),
        Err(e) => Err(e),
    }
}

/// Run `id`'s lock file, if there is one, and the process id its launcher wrote in it (`None`:
/// unreadable, or not written yet): for `qfleet clean --dry-run`, which must not take the lock
/// to tell whether a launcher still holds it.
pub fn lock_file(id: &str) -> Result<Option<(PathBuf, Option<i32>)>, RunIdError> {
    validate(id)?;
    let path = private_dir(id)?.join(format!("{id}.lock"));
    if std::fs::symlink_metadata(&path).is_err() {
        return Ok(None);
    }
    let pid = std::fs::read_to_string(&path)
        .ok()
        .and_then(|s| s.trim().parse().ok());
    Ok(Some((path, pid)))
}

/// Run `run_id`'s launcher lock as `qfleet clean` reports it: with `dry_run`, what removing
/// it would do, told without taking the lock by the launcher's process id written in the file
/// (`running(pid)`: whether that process is alive; a file without one, from a launcher killed
/// right after creating it, is removable if no launcher holds it); else removes it if its
/// launcher is gone. The line and how many files that is (0 or 1); None when there is no lock.
pub fn lock_note(
    run_id: &str,
    dry_run: bool,
    running: &dyn Fn(i32) -> bool,
) -> Result<Option<(String, usize)>, RunIdError> {
    if !dry_run {
        let gone = release_stale(run_id)?;
        return Ok(gone.map(|path| {
            let line = format!("removed its launcher's stale lock {}", path.display());
            (line, 1)
        }));
    }
    Ok(lock_file(run_id)?.map(|(path, pid)| match pid {
        Some(pid) if running(pid) => (
            format!(
                "its lock {} is held by a live launcher (pid {pid}), left alone",
                path.display()
            ),
            0,
        ),
        Some(_) => (
            format!("would remove its launcher's stale lock {}", path.display()),
            1,
        ),
        None => (
            format!(
                "would remove its launcher's lock {} unless a live launcher holds it \
                 (no process id in it)",
                path.display()
            ),
            1,
        ),
    }))
}

/// Run ids with a lock file in the user's private directory (live or stale), for `qfleet clean`
/// to look at runs that never reached shared memory; unreadable entries and names that are not
/// valid run ids are skipped.
pub fn claimed_ids() -> Vec<String> {
    // SAFETY: getuid(2) cannot fail.
    let uid = unsafe { libc::getuid() };
    let Ok(entries) = std::fs::read_dir(format!("/tmp/qfleet-{uid}")) else {
        return Vec::new();
    };
    let mut ids: Vec<String> = entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            let id = name.strip_suffix(".lock")?;
            validate(id).ok().map(|()| id.to_string())
        })
        .collect();
    ids.sort();
    ids
}

impl Drop for RunClaim {
    fn drop(&mut self) {
        // unlink while still holding the lock; a waiter that opened the old inode re-checks it
        let _ = std::fs::remove_file(&self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lock_is_reported_by_whether_its_launcher_runs() {
        let id = repetition(Some("locknote"), "t");
        assert!(id.starts_with("locknote-t-"), "{id}");
        assert_eq!(lock_note(&id, true, &|_| true).unwrap(), None);
        let claim = RunClaim::acquire(&id).unwrap();
        let (line, n) = lock_note(&id, true, &|_| true).unwrap().unwrap();
        assert!(line.contains("held by a live launcher") && n == 0, "{line}");
        let (line, n) = lock_note(&id, true, &|_| false).unwrap().unwrap();
        assert!(
            line.starts_with("would remove its launcher's stale lock") && n == 1,
            "{line}"
        );
        // held: not removed, whatever the dry run said
        assert_eq!(lock_note(&id, false, &|_| false).unwrap(), None);
        // a launcher that ended removed its lock: nothing left to say
        drop(claim);
        assert_eq!(lock_note(&id, false, &|_| false).unwrap(), None);
    }

    #[test]
    fn a_dead_launchers_lock_is_released_and_a_live_ones_is_left_alone() {
        let dir = tempfile::tempdir().unwrap();
        // no lock file at all
        assert_eq!(release_stale_in("r1", dir.path()).unwrap(), None);
        // a lock file nobody holds (its launcher was killed)
        let stale = dir.path().join("r1.lock");
        std::fs::write(&stale, "123\n").unwrap();
        assert_eq!(
            release_stale_in("r1", dir.path()).unwrap(),
            Some(stale.clone())
        );
        assert!(!stale.exists());
        // a live launcher's claim stays, and stays held
        let claim = RunClaim::acquire_in("r2", dir.path()).unwrap();
        assert_eq!(release_stale_in("r2", dir.path()).unwrap(), None);
        assert!(claim.path().exists());
        assert!(matches!(
            RunClaim::acquire_in("r2", dir.path()),
            Err(RunIdError::InUse { .. })
        ));
    }

    #[test]
    fn valid_ids_pass() {
        for id in ["a", "run-1", "Z_9-x", &"a".repeat(MAX_LEN)] {
            validate(id).unwrap_or_else(|e| panic!("{id}: {e}"));
        }
    }

    #[test]
    fn ids_that_are_flags_paths_or_too_long_are_refused() {
        for id in [
            "",
            "-x",
            "_x",
            "--robots",
            "a/b",
            "../x",
            "a b",
            "a.b",
            "é",
            &"a".repeat(MAX_LEN + 1),
        ] {
            let e = validate(id).expect_err(id);
            assert!(e.to_string().contains("invalid run id"), "{e}");
        }
    }

    #[test]
    fn generated_ids_are_valid() {
        validate(&generate("run")).unwrap();
        validate(&generate(&"x".repeat(100))).unwrap();
    }

    #[test]
    fn a_second_claim_of_a_held_id_is_refused_and_free_again_after_drop() {
        let dir = tempfile::tempdir().unwrap();
        let a = RunClaim::acquire_in("claim-test", dir.path()).unwrap();
        let e = RunClaim::acquire_in("claim-test", dir.path()).unwrap_err();
        assert!(matches!(e, RunIdError::InUse { .. }), "{e}");
        let other = RunClaim::acquire_in("claim-other", dir.path()).unwrap();
        drop(a);
        let again = RunClaim::acquire_in("claim-test", dir.path()).unwrap();
        assert!(again.path().exists());
        drop((again, other));
    }

    #[test]
    fn a_symlinked_lock_file_is_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let victim = dir.path().join("victim");
        std::fs::write(&victim, "keep").unwrap();
        std::os::unix::fs::symlink(&victim, dir.path().join("s.lock")).unwrap();
        assert!(RunClaim::acquire_in("s", dir.path()).is_err());
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep");
    }
}
