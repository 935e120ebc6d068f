//! Starting a child process of a run: found next to the launcher, in its own process group
//! (a Ctrl-C in the terminal reaches only the launcher, which stops the run in order), and
//! bound to the launcher's life: `PR_SET_PDEATHSIG` makes the kernel SIGKILL the child when the
//! launching thread dies, kill -9 of the launcher included, so no coordinator or robot outlives
//! it as an orphan. The thread matters: a child must be spawned by a thread that lives as long
//! as the child should (the supervise loop's thread).

use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::Command;

/// A sibling binary that is missing.
#[derive(Debug, thiserror::Error)]
pub enum SpawnError {
    /// The launcher's own path is unknown.
    #[error("cannot locate the qfleet executable")]
    NoExe(#[source] std::io::Error),
    /// The binary is not next to the launcher.
    #[error(
        "{name} not found next to {} — build it with `cargo build --bins` (or install all qfleet binaries into one directory)",
        exe.display()
    )]
    Missing {
        /// The binary's name.
        name: String,
        /// The launcher's path.
        exe: PathBuf,
    },
}

/// The path of binary `name` in the launcher's own directory (or, for a test binary that cargo
/// put in `target/<profile>/deps`, in `target/<profile>` where cargo puts the binaries).
pub fn sibling(name: &str) -> Result<PathBuf, SpawnError> {
    let exe = std::env::current_exe().map_err(SpawnError::NoExe)?;
    let missing = || SpawnError::Missing {
        name: name.into(),
        exe: exe.clone(),
    };
    let dir = exe.parent().ok_or_else(missing)?;
    let mut dirs = vec![dir];
    if dir.file_name().is_some_and(|d| d == "deps") {
        dirs.extend(dir.parent());
    }
    dirs.into_iter()
        .map(|d| d.join(name))
        .find(|p| p.is_file())
        .ok_or_else(missing)
}

/// Makes `cmd` start in its own process group and die (SIGKILL) when the launcher dies.
pub fn bind_to_launcher(cmd: &mut Command) -> &mut Command {
    // SAFETY: getpid(2) cannot fail.
    let launcher = unsafe { libc::getpid() };
    cmd.process_group(0);
    // SAFETY: the closure runs between fork and exec and calls only async-signal-safe
    // functions (prctl, getppid); it allocates nothing.
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(
                libc::PR_SET_PDEATHSIG,
                libc::SIGKILL as libc::c_ulong,
                0,
                0,
                0,
            ) != 0
            {
                return Err(std::io::Error::last_os_error());
            }
            // the launcher died before prctl took effect: do not start an orphan
            if libc::getppid() != launcher {
                return Err(std::io::Error::other("the launcher died during the start"));
            }
            Ok(())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bound_child_runs_in_its_own_process_group() {
        let mut cmd = Command::new("sh");
        cmd.args(["-c", "ps -o pgid= -p $$"]);
        let out = bind_to_launcher(&mut cmd).output().unwrap();
        assert!(out.status.success());
        let pgid: i32 = String::from_utf8_lossy(&out.stdout).trim().parse().unwrap();
        // SAFETY: getpgrp(2) cannot fail.
        assert_ne!(pgid, unsafe { libc::getpgrp() });
    }

    #[test]
    fn a_missing_sibling_is_a_clear_error() {
        let e = sibling("no-such-qfleet-binary").unwrap_err();
        assert!(e.to_string().contains("cargo build --bins"), "{e}");
    }
}
