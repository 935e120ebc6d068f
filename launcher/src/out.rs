//! The output directory of a run, and writing results into it.
//!
//! - `--out DIR` onto a directory that is not empty is refused (results of two runs would mix,
//!   and an old `result.json` could be read as the new run's) unless `--force` is given; then
//!   files of the same names are replaced and other files are left as they are.
//! - Without `--out`, the directory is created like `mkdtemp(3)`: a new, randomly named, 0700
//!   directory under `$TMPDIR` (no existing path is reused, no symlink followed); it is removed
//!   afterwards, and it is the only thing the launcher ever removes.
//! - Results are written atomically ([`write_atomic`]: a temporary file in the same directory,
//!   synced, then renamed), so a reader never sees half a file and a full disk leaves the old
//!   file (if any) intact; [`inventory`] names what a failed run kept.

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

/// Why an output directory cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum OutError {
    /// `--out` names a non-empty directory and `--force` was not given.
    #[error(
        "--out {} is not empty ({entries} entries, e.g. {example}); pick an empty or new directory, or pass --force to write into it",
        path.display()
    )]
    NotEmpty {
        /// The directory.
        path: PathBuf,
        /// Number of entries in it.
        entries: usize,
        /// One of them.
        example: String,
    },
    /// `--out` names something that is not a directory.
    #[error("--out {} exists and is not a directory", path.display())]
    NotADirectory {
        /// The path.
        path: PathBuf,
    },
    /// Creating or reading the directory failed.
    #[error("{what} {}", path.display())]
    Io {
        /// What was being done.
        what: &'static str,
        /// The path.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

/// A run's output directory: the user's (kept) or a temporary one (removed on drop).
#[derive(Debug)]
pub struct OutDir {
    path: PathBuf,
    temp: Option<tempfile::TempDir>,
}

/// `--out DIR` and `--force`, as `qfleet run`, `experiment` and `join` take them; each says in
/// its own `--out` help (`mut_arg`) what goes into the directory.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct OutArgs {
    /// Directory for the command's files (default: a new private temporary directory). A
    /// directory that is not empty is refused unless `--force`.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write into a non-empty `--out` directory, replacing files of the same names.
    #[arg(long)]
    pub force: bool,
}

/// [`OutArgs`] and `--ignore-memory`, as `qfleet run` and `qfleet experiment` take them (each
/// says in its own help, `mut_arg`, what goes into the directory and what the memory is for).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RunOutArgs {
    /// `--out` and `--force`.
    #[command(flatten)]
    pub dir: OutArgs,
    /// Start even if the estimated memory (robots and coordinator, from the map's size)
    /// exceeds the memory available now.
    #[arg(long)]
    pub ignore_memory: bool,
}

impl OutArgs {
    /// The directory these options ask for ([`OutDir::prepare`]; a temporary one named after
    /// `tag` without `--out`).
    pub fn prepare(&self, tag: &str) -> Result<OutDir, OutError> {
        OutDir::prepare(self.out.as_deref(), self.force, tag)
    }
}

impl OutError {
    /// Whether the command line asked for something refused (exit code 2), not a system
    /// failure: an `--out` that is not empty or not a directory.
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, OutError::Io { .. })
    }
}

impl OutDir {
    /// Prepares `--out` (`Some`) or a fresh temporary directory named `qfleet-<tag>-XXXXXX`.
    pub fn prepare(out: Option<&Path>, force: bool, tag: &str) -> Result<OutDir, OutError> {
        match out {
            Some(p) => Self::user(p, force),
            None => {
                let base = std::env::temp_dir();
                let temp = tempfile::Builder::new()
                    .prefix(&format!("qfleet-{tag}-"))
                    .permissions(std::fs::Permissions::from_mode(0o700))
                    .tempdir_in(&base)
                    .map_err(|source| OutError::Io {
                        what: "creating a temporary directory in",
                        path: base,
                        source,
                    })?;
                Ok(OutDir {
                    path: temp.path().to_path_buf(),
                    temp: Some(temp),
                })
            }
        }
    }

    fn user(p: &Path, force: bool) -> Result<OutDir, OutError> {
        let io = |what, source| OutError::Io {
            what,
            path: p.to_path_buf(),
            source,
        };
        match std::fs::metadata(p) {
            Ok(m) if !m.is_dir() => {
                return Err(OutError::NotADirectory {
                    path: p.to_path_buf(),
                });
            }
            Ok(_) => {
                let mut names: Vec<String> = std::fs::read_dir(p)
                    .map_err(|e| io("reading", e))?
                    .filter_map(|e| e.ok())
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .collect();
                if !names.is_empty() && !force {
                    names.sort();
                    return Err(OutError::NotEmpty {
                        path: p.to_path_buf(),
                        entries: names.len(),
                        example: names.swap_remove(0),
                    });
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                std::fs::create_dir_all(p).map_err(|e| io("creating", e))?;
            }
            Err(e) => return Err(io("reading", e)),
        }
        Ok(OutDir {
            path: p.to_path_buf(),
            temp: None,
        })
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Keeps the directory (a temporary one is then not removed) and returns its path.
    pub fn keep(self) -> PathBuf {
        match self.temp {
            Some(t) => t.keep(),
            None => self.path,
        }
    }

    /// Whether it is a temporary directory (removed when this value is dropped).
    pub fn is_temp(&self) -> bool {
        self.temp.is_some()
    }
}

/// Writes `bytes` to `path` atomically (temp file beside it, synced, renamed over it): the one
/// writer of the workspace, `report::write_atomic`, re-exported for the launcher's callers.
pub use report::write_atomic;

/// What a directory holds, for an error message: `N files (a, b, c …)` or `nothing`.
pub fn inventory(dir: &Path) -> String {
    let mut names: Vec<String> = match std::fs::read_dir(dir) {
        Ok(rd) => rd
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| !n.starts_with(".tmp-"))
            .collect(),
        Err(e) => return format!("nothing readable ({e})"),
    };
    if names.is_empty() {
        return "nothing".into();
    }
    names.sort();
    let n = names.len();
    let shown: Vec<&str> = names.iter().take(8).map(String::as_str).collect();
    format!(
        "{n} file(s) ({}{})",
        shown.join(", "),
        if n > 8 { ", …" } else { "" }
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_non_empty_out_dir_is_refused_without_force() {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("result.json"), "old").unwrap();
        let e = OutDir::prepare(Some(d.path()), false, "t").unwrap_err();
        assert!(matches!(e, OutError::NotEmpty { entries: 1, .. }), "{e}");
        assert!(e.to_string().contains("--force"), "{e}");
        let o = OutDir::prepare(Some(d.path()), true, "t").unwrap();
        assert!(!o.is_temp());
        drop(o);
        assert_eq!(
            std::fs::read_to_string(d.path().join("result.json")).unwrap(),
            "old"
        );
    }

    #[test]
    fn a_missing_out_dir_is_created_and_a_file_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let new = d.path().join("a/b");
        OutDir::prepare(Some(&new), false, "t").unwrap();
        assert!(new.is_dir());
        let f = d.path().join("f");
        std::fs::write(&f, "").unwrap();
        let e = OutDir::prepare(Some(&f), true, "t").unwrap_err();
        assert!(matches!(e, OutError::NotADirectory { .. }), "{e}");
    }

    #[test]
    fn a_temporary_dir_is_new_private_and_removed_on_drop() {
        let a = OutDir::prepare(None, false, "tag").unwrap();
        let b = OutDir::prepare(None, false, "tag").unwrap();
        assert_ne!(a.path(), b.path());
        assert!(a.is_temp());
        let mode = std::fs::metadata(a.path()).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o700, "{mode:o}");
        let p = a.path().to_path_buf();
        std::fs::write(p.join("x"), "1").unwrap();
        drop(a);
        assert!(!p.exists());
        let kept = b.keep();
        assert!(kept.is_dir());
        std::fs::remove_dir(kept).unwrap();
    }

    #[test]
    fn atomic_writes_replace_whole_files_and_leave_no_temporaries() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("result.json");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "two");
        assert_eq!(inventory(d.path()), "1 file(s) (result.json)");
        let e = write_atomic(&d.path().join("missing/x.json"), b"x");
        assert!(e.is_err());
    }
}
