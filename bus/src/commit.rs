//! Shared memory committed when it is created, so a `/dev/shm` that fills up mid-run is never a
//! SIGBUS.
//!
//! iceoryx2 0.10 maps its segments lazily: `ftruncate` on tmpfs reserves nothing, and a page is
//! taken from `/dev/shm` the first time a process touches it. Data segments are zeroed at creation
//! under iceoryx2's own SIGBUS guard, but its dynamic storage (service configs, connections,
//! management segments) is created with `zero_memory(false)`, so their pages were first touched
//! mid-run; with `/dev/shm` full by then (another program filling it), the touching process died
//! of SIGBUS: the coordinator and every robot, no result (issue 27, reproduced by
//! `tests/hardening_bus.rs`).
//!
//! [`commit_run_shm`] reserves every page of every file of a run's prefix in `/dev/shm` with
//! `posix_fallocate` (tmpfs allocates the pages, or fails with `ENOSPC` and keeps nothing). Each
//! process calls it right after it created its node and ports, before any message flows; a page
//! committed once is never taken from `/dev/shm` again. Files the run creates later (a connection
//! made when a restarted robot comes back, an observer's ports) are committed by the
//! coordinator's [`Committer`], which looks every few hundred milliseconds and says when it could
//! not: the coordinator then ends the run with the results it has rather than wait for a SIGBUS.
//!
//! Committing costs what the run's shared memory would take anyway (the preflight has already
//! checked that `/dev/shm` has room for it, [`crate::check_shm_space`]).

use std::collections::HashSet;
use std::fs::File;
use std::os::fd::AsRawFd;
use std::os::unix::fs::{MetadataExt, OpenOptionsExt};
use std::path::Path;

use crate::BusError;
use crate::files::free_bytes;
use crate::liveness::SHM_DIR;

/// What one [`commit_run_shm`] pass did.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Committed {
    /// Files whose pages were reserved in this pass.
    pub files: usize,
    /// Their bytes.
    pub bytes: u64,
    /// Files skipped: another user's, gone meanwhile, or on a filesystem without `fallocate`.
    pub skipped: usize,
}

/// Reserves every page of every regular file of `prefix` in `/dev/shm` (see the module docs).
///
/// [`BusError::ShmCommit`] when `/dev/shm` has no room for a file's pages; files removed
/// meanwhile, symlinks, other users' files and filesystems without `fallocate` are skipped and
/// counted.
pub fn commit_run_shm(prefix: &str) -> Result<Committed, BusError> {
    Committer::new(prefix).pass()
}

/// Commits the files of one run's prefix, each once: the coordinator keeps one and calls
/// [`Committer::pass`] now and then, so connections made after the start are committed too.
#[derive(Debug)]
pub struct Committer {
    prefix: String,
    /// (device, inode) of the files committed already: a pass only opens the new ones.
    done: HashSet<(u64, u64)>,
}

impl Committer {
    /// A committer of the files of `prefix` (a run's iceoryx2 prefix, e.g. `qfleet.run7.`).
    pub fn new(prefix: &str) -> Self {
        Self {
            prefix: prefix.to_string(),
            done: HashSet::new(),
        }
    }

    /// Commits every file of the prefix not committed by this committer before.
    pub fn pass(&mut self) -> Result<Committed, BusError> {
        self.pass_in(Path::new(SHM_DIR))
    }

    fn pass_in(&mut self, dir: &Path) -> Result<Committed, BusError> {
        let mut c = Committed::default();
        let Ok(entries) = std::fs::read_dir(dir) else {
            return Ok(c);
        };
        // SAFETY: geteuid cannot fail.
        let me = unsafe { libc::geteuid() };
        for entry in entries.flatten() {
            if !entry
                .file_name()
                .to_string_lossy()
                .starts_with(&self.prefix)
            {
                continue;
            }
            let Ok(meta) = entry.metadata() else {
                c.skipped += 1; // removed meanwhile
                continue;
            };
            let key = (meta.dev(), meta.ino());
            if !meta.file_type().is_file() || meta.uid() != me {
                c.skipped += 1;
                continue;
            }
            if self.done.contains(&key) {
                continue;
            }
            match commit_file(&entry.path())? {
                Some(bytes) => {
                    c.files += 1;
                    c.bytes += bytes;
                    self.done.insert(key);
                }
                None => c.skipped += 1,
            }
        }
        Ok(c)
    }
}

/// Reserves the pages of one file: `Some(bytes)`, `None` when it cannot be committed for a
/// reason that is not a lack of space (gone, not ours to write, no `fallocate` there).
fn commit_file(path: &Path) -> Result<Option<u64>, BusError> {
    let file = match std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
        .open(path)
    {
        Ok(f) => f,
        Err(_) => return Ok(None),
    };
    let size = match file.metadata() {
        Ok(m) if m.len() > 0 => m.len(),
        _ => return Ok(None),
    };
    reserve(&file, size).map_err(|e| BusError::ShmCommit {
        path: path.display().to_string(),
        bytes: size,
        have: free_bytes(Path::new(SHM_DIR)).unwrap_or(0),
        source: e,
    })
}

/// `posix_fallocate` over the whole file; `Ok(None)` where the filesystem has no `fallocate`.
fn reserve(file: &File, size: u64) -> Result<Option<u64>, std::io::Error> {
    let Ok(len) = libc::off_t::try_from(size) else {
        return Ok(None);
    };
    loop {
        // SAFETY: a valid open descriptor; posix_fallocate returns the error number.
        let rc = unsafe { libc::posix_fallocate(file.as_raw_fd(), 0, len) };
        match rc {
            0 => return Ok(Some(size)),
            libc::EINTR => continue,
            libc::EOPNOTSUPP | libc::EINVAL | libc::ENODEV => return Ok(None),
            e => return Err(std::io::Error::from_raw_os_error(e)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(tag: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("qfleet-commit-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn allocated(path: &Path) -> u64 {
        std::fs::metadata(path).unwrap().blocks() * 512
    }

    #[test]
    fn a_pass_reserves_every_page_of_the_prefix_files_and_only_those() {
        let d = scratch("pages");
        let mine = d.join("qfleet.t1.seg");
        let other = d.join("qfleet.t2.seg");
        for p in [&mine, &other] {
            File::create(p).unwrap().set_len(256 * 1024).unwrap();
        }
        assert_eq!(allocated(&mine), 0, "a truncated file reserves nothing");
        let mut c = Committer::new("qfleet.t1.");
        let first = c.pass_in(&d).unwrap();
        assert_eq!((first.files, first.bytes), (1, 256 * 1024));
        assert!(allocated(&mine) >= 256 * 1024);
        assert_eq!(allocated(&other), 0, "another prefix's file is left alone");
        // a second pass opens nothing it committed before
        assert_eq!(c.pass_in(&d).unwrap(), Committed::default());
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn symlinks_and_directories_of_the_prefix_are_skipped_not_followed() {
        let d = scratch("links");
        let target = d.join("elsewhere");
        File::create(&target).unwrap().set_len(64 * 1024).unwrap();
        std::os::unix::fs::symlink(&target, d.join("qfleet.t3.link")).unwrap();
        std::fs::create_dir(d.join("qfleet.t3.dir")).unwrap();
        let c = Committer::new("qfleet.t3.").pass_in(&d).unwrap();
        assert_eq!((c.files, c.skipped), (0, 2));
        assert_eq!(allocated(&target), 0, "the link's target was not touched");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_missing_directory_is_an_empty_pass() {
        let c = Committer::new("x.").pass_in(Path::new("/nonexistent/qfleet-commit"));
        assert_eq!(c.unwrap(), Committed::default());
    }
}
