//! Starting a child process of a run: found next to the launcher, in its own process group
//! (a Ctrl-C in the terminal reaches only the launcher, which stops the run in order), and
//! bound to the launcher's life: `PR_SET_PDEATHSIG` makes the kernel SIGKILL the child when the
//! launching thread dies, kill -9 of the launcher included, so no coordinator or robot outlives
//! it as an orphan. The thread matters: a child must be spawned by a thread that lives as long
//! as the child should (the supervise loop's thread).

use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

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

/// Waits up to `grace` for the children to exit, then SIGTERMs them and, 2 s later, kills the
/// rest; returns the ids of those that exited unsuccessfully or had to be stopped (`qfleet
/// join`'s robots, which no supervise loop restarts).
pub fn stop_all(children: &mut [(u32, std::process::Child)], grace: Duration) -> Vec<u32> {
    let deadline = Instant::now() + grace;
    let mut failed = Vec::new();
    let mut termed = false;
    loop {
        let running: Vec<usize> = (0..children.len())
            .filter(|&i| matches!(children[i].1.try_wait(), Ok(None)))
            .collect();
        if running.is_empty() {
            break;
        }
        let now = Instant::now();
        if now >= deadline && !termed {
            for &i in &running {
                // SAFETY: kill(2) on a child we started and have not reaped
                unsafe { libc::kill(children[i].1.id() as i32, libc::SIGTERM) };
            }
            termed = true;
        } else if now >= deadline + Duration::from_secs(2) {
            for &i in &running {
                let _ = children[i].1.kill();
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    for (id, c) in children.iter_mut() {
        if !matches!(c.wait(), Ok(s) if s.success()) {
            failed.push(*id);
        }
    }
    failed
}

/// Whether every child has exited; `exited(id)` is told of each one that has (polled, not
/// reaped: [`stop_all`] reaps them).
pub fn all_exited(
    children: &mut [(u32, std::process::Child)],
    exited: &mut dyn FnMut(u32),
) -> bool {
    let mut all = true;
    for (id, c) in children.iter_mut() {
        if matches!(c.try_wait(), Ok(Some(_))) {
            exited(*id);
        } else {
            all = false;
        }
    }
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stopping_children_names_the_failed_and_the_stopped() {
        let start = |script: &str| Command::new("sh").args(["-c", script]).spawn().unwrap();
        let mut children = vec![
            (0, start("exit 0")),
            (1, start("exit 3")),
            (2, start("sleep 30")),
        ];
        // the sleeper keeps running: the two that exit are named, not the rest
        let mut seen = Vec::new();
        let t0 = Instant::now();
        while seen.len() < 2 && t0.elapsed() < Duration::from_secs(10) {
            seen.clear();
            assert!(!all_exited(&mut children, &mut |id| seen.push(id)));
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(seen, [0, 1]);
        let t0 = Instant::now();
        let failed = stop_all(&mut children, Duration::from_millis(200));
        assert_eq!(failed, vec![1, 2]);
        assert!(t0.elapsed() < Duration::from_secs(10));
    }

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
