//! The one way a qfleet process writes a result file: whole or not at all.
//!
//! [`write_atomic`] writes the bytes to a fresh temporary file in the target's own directory,
//! flushes it to the disk (`fsync`), and renames it over the target; a reader (the coordinator
//! reading a robot's file, the launcher reading `result.json`, a person after a crash) sees the
//! old file or the new one, never a torn one. A full disk (`ENOSPC`), an I/O error (`EIO`) or a
//! missing directory comes back as a [`WriteError`] that names the file and the step that failed
//! and keeps the OS error as its source; the temporary file is removed again.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Which step of an atomic write failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WriteStep {
    /// Creating the temporary file next to the target.
    Create,
    /// Writing the bytes into it.
    Write,
    /// Flushing them to the disk (`fsync`).
    Sync,
    /// Renaming the temporary file over the target.
    Rename,
    /// Serialising the value to JSON (before any file is touched).
    Encode,
}

impl std::fmt::Display for WriteStep {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            WriteStep::Create => "creating a temporary file for",
            WriteStep::Write => "writing",
            WriteStep::Sync => "flushing to disk",
            WriteStep::Rename => "renaming into place",
            WriteStep::Encode => "encoding",
        })
    }
}

/// Why a result file could not be written; the target keeps its previous content (or stays
/// absent).
#[derive(Debug, thiserror::Error)]
#[error("{step} {}: {source}", path.display())]
pub struct WriteError {
    /// The file that was to be written.
    pub path: PathBuf,
    /// The step that failed.
    pub step: WriteStep,
    /// The OS error (`ENOSPC` for a full disk, `EIO`, …), or the encoder's error as an I/O error.
    #[source]
    pub source: std::io::Error,
}

impl WriteError {
    /// Whether the disk (or the user's quota) is full: a caller may say so in plain words.
    pub fn is_disk_full(&self) -> bool {
        matches!(
            self.source.kind(),
            std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded
        )
    }
}

/// What an atomic write waits for before it returns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Durability {
    /// The bytes and the rename are on the disk (`fsync` of the file and its directory): the
    /// file survives a power loss. Results.
    Disk,
    /// The rename is done (no `fsync`): the file survives the death of the writing process,
    /// not of the machine, and a write never waits for a busy disk. A checkpoint rewritten
    /// every second from a serving loop.
    Process,
}

/// Makes temporary names unique between the threads of one process (the pid separates processes).
static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Writes `bytes` to `path` atomically: temp file in the same directory, `fsync`, rename.
///
/// The directory must exist. On any error the temporary file is removed and `path` is left as
/// it was.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    write_atomic_with(path, bytes, Durability::Disk)
}

/// [`write_atomic`] with the [`Durability`] asked for.
pub fn write_atomic_with(
    path: &Path,
    bytes: &[u8],
    durability: Durability,
) -> Result<(), WriteError> {
    let err = |step: WriteStep| {
        move |source: std::io::Error| WriteError {
            path: path.to_path_buf(),
            step,
            source,
        }
    };
    let name = path.file_name().ok_or_else(|| {
        err(WriteStep::Create)(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a file name",
        ))
    })?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let n = TEMP_COUNTER.fetch_add(1, Ordering::Relaxed);
    let mut temp_name = std::ffi::OsString::from(".");
    temp_name.push(name);
    temp_name.push(format!(".tmp-{}-{n}", std::process::id()));
    let temp = dir.join(temp_name);
    // create_new: never follows or reuses a file someone planted under the temporary name
    let mut f = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&temp)
        .map_err(err(WriteStep::Create))?;
    let written = fill(&mut f, bytes, durability).and_then(|step| {
        std::fs::rename(&temp, path)
            .map_err(|e| (WriteStep::Rename, e))
            .map(|()| step)
    });
    match written {
        Ok(()) if durability == Durability::Process => Ok(()),
        Ok(()) => {
            // the rename is durable once the directory is flushed; a directory that cannot be
            // opened for that (some filesystems) leaves the file written, which is what matters
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
            Ok(())
        }
        Err((step, e)) => {
            let _ = std::fs::remove_file(&temp);
            Err(err(step)(e))
        }
    }
}

fn fill(
    f: &mut File,
    bytes: &[u8],
    durability: Durability,
) -> Result<(), (WriteStep, std::io::Error)> {
    f.write_all(bytes).map_err(|e| (WriteStep::Write, e))?;
    match durability {
        Durability::Disk => f.sync_all().map_err(|e| (WriteStep::Sync, e)),
        Durability::Process => Ok(()),
    }
}

/// Serialises `value` as pretty JSON and writes it with [`write_atomic`].
pub fn write_json_atomic<T: serde::Serialize + ?Sized>(
    path: &Path,
    value: &T,
) -> Result<(), WriteError> {
    write_json_atomic_with(path, value, Durability::Disk)
}

/// [`write_json_atomic`] with the [`Durability`] asked for.
pub fn write_json_atomic_with<T: serde::Serialize + ?Sized>(
    path: &Path,
    value: &T,
    durability: Durability,
) -> Result<(), WriteError> {
    let json = serde_json::to_vec_pretty(value).map_err(|e| WriteError {
        path: path.to_path_buf(),
        step: WriteStep::Encode,
        source: std::io::Error::other(e),
    })?;
    write_atomic_with(path, &json, durability)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("qfleet-report-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_write_without_fsync_still_replaces_the_file_whole() {
        let d = scratch("atomic-process");
        let p = d.join("cp.json");
        write_json_atomic_with(&p, &[1, 2], Durability::Process).unwrap();
        write_json_atomic_with(&p, &[3], Durability::Process).unwrap();
        let back: Vec<u32> = serde_json::from_slice(&std::fs::read(&p).unwrap()).unwrap();
        assert_eq!(back, vec![3]);
        assert_eq!(
            std::fs::read_dir(&d).unwrap().count(),
            1,
            "no temporary left"
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn replaces_the_file_whole_and_leaves_no_temporary_behind() {
        let d = scratch("atomic");
        let p = d.join("result.json");
        write_atomic(&p, b"old").unwrap();
        write_atomic(&p, b"new content").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"new content");
        let names: Vec<_> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["result.json"]);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_missing_directory_is_an_error_naming_the_file_with_its_source() {
        let d = scratch("missing");
        let p = d.join("no-such-dir").join("robot-3.json");
        let e = write_atomic(&p, b"x").unwrap_err();
        assert_eq!(e.step, WriteStep::Create);
        assert_eq!(e.path, p);
        assert_eq!(e.source.kind(), std::io::ErrorKind::NotFound);
        assert!(e.to_string().contains("robot-3.json"), "{e}");
        assert!(std::error::Error::source(&e).is_some());
        assert!(!e.is_disk_full());
        std::fs::remove_dir_all(&d).unwrap();
    }

    /// Says that a test skipped, and why: a copy of `qfleet_suite::skip` (`tests/support/lib.rs`
    /// says why it looks so; `tests/skips.rs` keeps every copy identical).
    fn skip(test: &str, reason: &str) {
        use std::io::Write;
        let line = format!("SKIPPED: {test}: {reason}\n");
        let _ = std::io::stderr().lock().write_all(line.as_bytes());
    }

    #[test]
    fn a_full_disk_is_reported_as_such() {
        // /dev/full answers every write with ENOSPC; it cannot hold a temporary file, so the
        // failing write is simulated on the step that matters: the bytes into the file
        let mut f = match OpenOptions::new().write(true).open("/dev/full") {
            Ok(f) => f,
            Err(e) => {
                skip(
                    "report atomic::tests::a_full_disk_is_reported_as_such",
                    &format!("/dev/full is not available here ({e})"),
                );
                return;
            }
        };
        let (step, source) = fill(&mut f, b"x", Durability::Disk).unwrap_err();
        assert_eq!(step, WriteStep::Write);
        let e = WriteError {
            path: "/out/result.json".into(),
            step,
            source,
        };
        assert!(e.is_disk_full(), "{e:?}");
        assert!(e.to_string().starts_with("writing /out/result.json"), "{e}");
    }
}
