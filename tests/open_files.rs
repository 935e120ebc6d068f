//! Open-file limits (README "Limits"): the coordinator holds ~19 files per robot (bus::limits).
//! A fleet over the hard limit is refused before any process starts; one over the soft limit
//! only runs, because every qfleet process raises its soft limit to the hard one. Before, a
//! fleet of 64 under the usual soft limit of 1024 lost its last robots at registration without
//! a word, and 256 near the limit had live robots reported dead.

use std::os::unix::process::CommandExt;
use std::process::Command;
use std::time::{Duration, Instant};

use qfleet_suite::{bin, describe, leftovers, run_id, scratch, spawn, wait_bounded};
use serde_json::Value;

/// `cmd` starts with the open-file limits `soft`/`hard`.
fn with_open_files(cmd: &mut Command, soft: u64, hard: u64) -> &mut Command {
    // SAFETY: only setrlimit, async-signal-safe, between fork and exec
    unsafe {
        cmd.pre_exec(move || {
            let lim = libc::rlimit {
                rlim_cur: soft,
                rlim_max: hard,
            };
            if libc::setrlimit(libc::RLIMIT_NOFILE, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        })
    }
}

#[test]
fn a_fleet_over_the_hard_open_file_limit_is_refused_before_it_starts() {
    let id = run_id("nofile-hard");
    let dir = scratch(&id);
    let t0 = Instant::now();
    let out = wait_bounded(
        spawn(with_open_files(
            Command::new(bin("qfleet"))
                .args(["run", "--run-id", &id, "--out"])
                .arg(&dir)
                .args(["--map", "builtin:paper-10", "--episodes", "2"])
                .args(["--robots", "64"]),
            512,
            512,
        )),
        Duration::from_secs(120),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("open files") && err.contains("64 robots") && err.contains("ulimit"),
        "the error says what is short and what to do: {err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    // refused by the preflight: no robot was started, nothing waited for registration
    assert!(
        t0.elapsed() < Duration::from_secs(20),
        "refused at once, not after a start-up timeout: {:?}",
        t0.elapsed()
    );
    assert!(!err.contains("robot-agent"), "no robot was started: {err}");
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}

#[test]
fn a_fleet_over_the_soft_open_file_limit_runs_to_the_end() {
    // 64 robots need ~1400 files in the coordinator: over a soft limit of 1024, under the hard
    let id = run_id("nofile-soft");
    let dir = scratch(&id);
    let out = wait_bounded(
        spawn(with_open_files(
            Command::new(bin("qfleet"))
                .args(["run", "--json", "--run-id", &id, "--out"])
                .arg(&dir)
                .args(["--map", "builtin:paper-10", "--episodes", "5"])
                .args(["--robots", "64"]),
            1024,
            bus::limits::coordinator_files(64) + 256,
        )),
        Duration::from_secs(300),
    );
    assert!(out.status.success(), "{}", describe(&out));
    let r: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("no JSON result ({e}): {}", describe(&out)));
    let robots = r["robots"].as_array().expect("robots");
    assert_eq!(robots.len(), 64, "{r}");
    for x in robots {
        assert_eq!(x["status"], "finished", "{x}");
    }
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}
