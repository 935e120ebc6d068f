//! The launcher's promises under attack from outside (issue 10), each a test with real
//! processes, named after the promise: an exclusive run id, results never mixed or lost, a
//! temporary directory nobody can redirect, a fleet that dies with its launcher, a failed
//! restart that stops the fleet, a closed or full stdout that is no panic, run ids that cannot
//! pass for flags, and a robot that dies before it registers.
//!
//! Every test uses its own run id (or a unique invalid one), bounds every process in time, and
//! leaves nothing in `/dev/shm` or `/tmp/iceoryx2`.

use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use qfleet_suite::{
    PROCESS_TIMEOUT, bin, describe, leftovers, pid_with_arg, pids_of_run, run_bounded, run_id,
    scratch, skip, spawn, wait_bounded, wait_until,
};
use serde_json::Value;

/// A run of a few seconds: long enough to overlap a second launcher or to be killed mid-way.
const SECONDS: [&str; 6] = [
    "--map",
    "builtin:paper-20",
    "--episodes",
    "3000",
    "--robots",
    "2",
];

/// A run that never ends by itself.
const ENDLESS: [&str; 6] = [
    "--map",
    "builtin:paper-20",
    "--episodes",
    "1000000",
    "--robots",
    "2",
];

/// A short run.
const SHORT: [&str; 6] = [
    "--map",
    "builtin:paper-10",
    "--episodes",
    "100",
    "--robots",
    "2",
];

fn qfleet_run(id: &str, extra: &[&str]) -> Command {
    let mut c = Command::new(bin("qfleet"));
    c.args(["run", "--json", "--run-id", id]).args(extra);
    c
}

fn code(out: &Output) -> Option<i32> {
    out.status.code()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn assert_clean(id: &str) {
    let left = leftovers(id);
    assert!(left.is_empty(), "files of run {id} left behind: {left:?}");
}

/// Waits until `n` processes of run `id` other than `launcher` are alive.
fn wait_children(id: &str, launcher: u32, n: usize) {
    assert!(
        wait_until(PROCESS_TIMEOUT, || {
            pids_of_run(id)
                .iter()
                .filter(|&&p| p != launcher as i32)
                .count()
                >= n
        }),
        "the {n} processes of run {id} never came up"
    );
}

fn kill(pid: i32, sig: libc::c_int) {
    // SAFETY: kill(2) on a process this test started (directly or through qfleet run).
    unsafe {
        libc::kill(pid, sig);
    }
}

/// Kills whatever of run `id` is still alive (a failing test must not leave a fleet behind).
fn kill_run(id: &str) {
    for p in pids_of_run(id) {
        kill(p, libc::SIGKILL);
    }
}

#[test]
fn one_run_id_launched_twice_at_the_same_moment_runs_once_and_the_other_refuses() {
    let id = run_id("claim");
    let dir = scratch("hl-claim");
    let launch = |n: u32| {
        spawn(
            qfleet_run(&id, &SECONDS)
                .arg("--out")
                .arg(dir.join(format!("out-{n}"))),
        )
    };
    let (a, b) = (launch(0), launch(1));
    let (a, b) = (
        wait_bounded(a, PROCESS_TIMEOUT),
        wait_bounded(b, PROCESS_TIMEOUT),
    );
    let mut codes = [code(&a), code(&b)];
    codes.sort();
    assert_eq!(
        codes,
        [Some(0), Some(2)],
        "one must run, the other refuse:\n{}\n{}",
        describe(&a),
        describe(&b)
    );
    let loser = if code(&a) == Some(2) { &a } else { &b };
    assert!(stderr(loser).contains("in use"), "{}", describe(loser));
    let winner = if code(&a) == Some(0) { &a } else { &b };
    let r: Value = serde_json::from_slice(&winner.stdout).expect("the winner's result");
    assert_eq!(r["robots"].as_array().map(Vec::len), Some(2), "{r}");
    assert_clean(&id);
}

#[test]
fn out_onto_a_non_empty_directory_is_refused_unless_force() {
    let id = run_id("outforce");
    let dir = scratch("hl-outforce");
    std::fs::write(dir.join("result.json"), "another run's result").unwrap();
    std::fs::write(dir.join("robot-7.json"), "another run's robot").unwrap();
    let out = run_bounded(qfleet_run(&id, &SHORT).arg("--out").arg(&dir));
    assert_eq!(code(&out), Some(2), "{}", describe(&out));
    assert!(stderr(&out).contains("--force"), "{}", describe(&out));
    assert_eq!(
        std::fs::read_to_string(dir.join("result.json")).unwrap(),
        "another run's result",
        "a refused run touched the directory"
    );
    let out = run_bounded(
        qfleet_run(&id, &SHORT)
            .arg("--force")
            .arg("--out")
            .arg(&dir),
    );
    assert!(out.status.success(), "{}", describe(&out));
    let r: Value = serde_json::from_str(&std::fs::read_to_string(dir.join("result.json")).unwrap())
        .expect("the new result");
    assert_eq!(r["run_id"], id.as_str(), "{r}");
    assert!(
        dir.join("robot-7.json").exists(),
        "--force deleted a file the run did not write"
    );
    assert_clean(&id);
}

#[test]
fn without_out_the_temporary_directory_is_new_and_a_planted_symlink_is_never_followed() {
    let id = run_id("tmpdir");
    let dir = scratch("hl-tmpdir");
    let tmp = dir.join("tmp");
    let victim = dir.join("victim");
    std::fs::create_dir_all(&tmp).unwrap();
    std::fs::create_dir_all(&victim).unwrap();
    std::fs::write(victim.join("precious"), "keep me").unwrap();
    // what the old launcher would have used, planted by "another user"
    let planted = tmp.join(format!("qfleet-{id}"));
    std::os::unix::fs::symlink(&victim, &planted).unwrap();
    let out = run_bounded(qfleet_run(&id, &SHORT).env("TMPDIR", &tmp));
    assert!(out.status.success(), "{}", describe(&out));
    assert_eq!(
        std::fs::read_to_string(victim.join("precious")).unwrap(),
        "keep me"
    );
    let victim_files: Vec<_> = std::fs::read_dir(&victim).unwrap().flatten().collect();
    assert_eq!(victim_files.len(), 1, "the run wrote through the symlink");
    // the run's own temporary directory is gone, the planted link is untouched
    let names: Vec<String> = std::fs::read_dir(&tmp)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, vec![format!("qfleet-{id}")], "{names:?}");
    assert!(
        std::fs::symlink_metadata(&planted)
            .unwrap()
            .file_type()
            .is_symlink()
    );
    assert_clean(&id);
}

/// Unmounts the test's tmpfs however the test ends.
struct Mount(std::path::PathBuf);

impl Drop for Mount {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

#[test]
fn a_full_disk_under_out_is_an_error_naming_what_was_kept_never_a_panic() {
    const NAME: &str = "a_full_disk_under_out_is_an_error_naming_what_was_kept_never_a_panic";
    // SAFETY: geteuid(2) cannot fail.
    if unsafe { libc::geteuid() } != 0 {
        skip(NAME, "mounting a tiny tmpfs needs root");
        return;
    }
    let id = run_id("enospc");
    let dir = scratch("hl-enospc");
    let mnt = dir.join("mnt");
    std::fs::create_dir_all(&mnt).unwrap();
    let mounted = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=48k", "qfleet-test"])
        .arg(&mnt)
        .stderr(Stdio::piped())
        .output();
    match mounted {
        Ok(o) if o.status.success() => {}
        Ok(o) => {
            skip(
                NAME,
                &format!("mount -t tmpfs failed: {}", stderr(&o).trim()),
            );
            return;
        }
        Err(e) => {
            skip(NAME, &format!("cannot run mount: {e}"));
            return;
        }
    }
    let _mount = Mount(mnt.clone());
    // full to the last block: not even a log line fits (a run that only fills it up itself
    // leaves room for its logs until late)
    {
        use std::io::Write as _;
        let mut filler = std::fs::File::create(mnt.join("filler")).unwrap();
        while filler.write_all(&[0u8; 512]).is_ok() {}
    }
    let out_dir = mnt.join("out");
    let out = run_bounded(
        qfleet_run(
            &id,
            &[
                "--map",
                "builtin:paper-20",
                "--episodes",
                "4000",
                "--robots",
                "4",
            ],
        )
        .args(["--restart", "on-failure"])
        .arg("--out")
        .arg(&out_dir),
    );
    kill_run(&id);
    assert_eq!(code(&out), Some(1), "{}", describe(&out));
    // a robot that reported but could not write its files is not restarted: it would learn
    // again only to fail the same way
    assert!(
        !stderr(&out).contains("restarting"),
        "finished robots were restarted: {}",
        describe(&out)
    );
    let err = stderr(&out);
    assert!(
        err.contains(&format!("kept in {}", out_dir.display())),
        "the error must name what was kept: {}",
        describe(&out)
    );
    assert!(!err.contains("panicked"), "{}", describe(&out));
    // nor did any process of the run panic: a log line on a full disk is dropped, not fatal
    // (`eprintln!` panicked there, exit 101 with an empty log)
    assert!(!err.contains("exit code 101"), "{}", describe(&out));
    // and the run's result is not lost with the disk: the robots still reported, and the
    // coordinator handed the result it could not write to the launcher, which prints it
    let r: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("no result on stdout ({e}): {}", describe(&out)));
    let robots = r["robots"].as_array().expect("robots");
    assert_eq!(robots.len(), 4, "{r}");
    assert!(
        robots.iter().all(|x| x["status"] == "finished"),
        "every robot's report arrived: {r}"
    );
    assert_clean(&id);
}

#[test]
fn killing_the_launcher_kills_its_fleet_and_frees_the_run_id() {
    let id = run_id("orphans");
    let dir = scratch("hl-orphans");
    let mut launcher = spawn(
        qfleet_run(&id, &ENDLESS)
            .arg("--out")
            .arg(dir.join("a"))
            .process_group(0),
    );
    wait_children(&id, launcher.id(), 3);
    let fleet: Vec<i32> = pids_of_run(&id)
        .into_iter()
        .filter(|&p| p != launcher.id() as i32)
        .collect();
    let t = Instant::now();
    launcher.kill().unwrap();
    let _ = launcher.wait();
    let gone = wait_until(Duration::from_secs(20), || pids_of_run(&id).is_empty());
    let survivors = pids_of_run(&id);
    kill_run(&id);
    assert!(
        gone,
        "orphans of the killed launcher: {survivors:?} (fleet was {fleet:?})"
    );
    eprintln!(
        "fleet of {} gone {:?} after kill -9 of its launcher",
        fleet.len(),
        t.elapsed()
    );
    // the id is free again at once: a new run with it completes
    let out = run_bounded(qfleet_run(&id, &SHORT).arg("--out").arg(dir.join("b")));
    assert!(out.status.success(), "{}", describe(&out));
    assert_clean(&id);
}

#[test]
fn a_restart_that_cannot_create_its_log_stops_the_fleet_with_an_error() {
    let id = run_id("badrestart");
    let dir = scratch("hl-badrestart");
    let out_dir = dir.join("out");
    let launcher = spawn(
        qfleet_run(&id, &ENDLESS)
            .args(["--restart", "on-failure", "--grace", "2"])
            .arg("--out")
            .arg(&out_dir)
            .process_group(0),
    );
    let lid = launcher.id();
    wait_children(&id, lid, 3);
    // a child is counted from its fork, its arguments are readable from its exec
    let mut robot = None;
    assert!(
        wait_until(PROCESS_TIMEOUT, || {
            robot = pid_with_arg(&id, "--robot-id", "1");
            robot.is_some()
        }),
        "robot 1 never came up"
    );
    let robot = robot.unwrap_or_default();
    // its log cannot be created again: a directory takes its place
    let log = out_dir.join("robot-1.log");
    std::fs::remove_file(&log).unwrap();
    std::fs::create_dir(&log).unwrap();
    kill(robot, libc::SIGKILL);
    let out = wait_bounded(launcher, PROCESS_TIMEOUT);
    let survivors: Vec<i32> = pids_of_run(&id);
    kill_run(&id);
    assert_eq!(code(&out), Some(1), "{}", describe(&out));
    assert!(
        stderr(&out).contains("restarting robot-agent 1: creating the log file"),
        "{}",
        describe(&out)
    );
    assert!(
        survivors.is_empty(),
        "unsupervised after the launcher exited: {survivors:?}"
    );
    assert_clean(&id);
}

#[test]
fn a_closed_or_full_stdout_or_stderr_is_a_clean_exit_never_a_panic() {
    // `qfleet clean | head -0`: the reader is gone before the first line
    let mut c = Command::new(bin("qfleet"))
        .args(["clean", "--dry-run"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    drop(c.stdout.take());
    let out = wait_bounded(c, PROCESS_TIMEOUT);
    assert_eq!(
        code(&out),
        Some(0),
        "EPIPE must be a quiet exit: {}",
        describe(&out)
    );
    // the same for a command that prints its result (`qfleet learn --json | true`)
    let mut c = Command::new(bin("qfleet"))
        .args([
            "learn",
            "--map",
            "builtin:paper-10",
            "--episodes",
            "5",
            "--json",
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    drop(c.stdout.take());
    let out = wait_bounded(c, PROCESS_TIMEOUT);
    assert_eq!(code(&out), Some(0), "{}", describe(&out));

    let full = || std::fs::OpenOptions::new().write(true).open("/dev/full");
    let Ok(dev_full) = full() else {
        skip(
            "a_closed_or_full_stdout_or_stderr_is_a_clean_exit_never_a_panic",
            "/dev/full is missing",
        );
        return;
    };
    // stdout on a full device: the result cannot be printed, a runtime failure
    let id = run_id("devfull-out");
    let out = wait_bounded(
        qfleet_run(&id, &SHORT)
            .stdin(Stdio::null())
            .stdout(dev_full)
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn"),
        PROCESS_TIMEOUT,
    );
    assert_eq!(code(&out), Some(1), "{}", describe(&out));
    assert!(
        stderr(&out).contains("writing to stdout"),
        "{}",
        describe(&out)
    );
    assert_clean(&id);
    // stderr on a full device: nothing to say there, the run itself succeeds
    let id = run_id("devfull-err");
    let out = wait_bounded(
        qfleet_run(&id, &SHORT)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(full().unwrap())
            .spawn()
            .expect("spawn"),
        PROCESS_TIMEOUT,
    );
    assert_eq!(code(&out), Some(0), "{}", describe(&out));
    let _: Value = serde_json::from_slice(&out.stdout).expect("the result on stdout");
    assert_clean(&id);
}

#[test]
fn run_ids_that_are_not_plain_names_are_refused_before_anything_starts() {
    let dir = scratch("hl-runid");
    for bad in ["-x", "--robots", "_x", "a/b", "a.b", "", &"a".repeat(65)] {
        for cmd in [
            vec!["run".to_string(), format!("--run-id={bad}")],
            vec![
                "clean".to_string(),
                "--dry-run".into(),
                format!("--run-id={bad}"),
            ],
        ] {
            let out = run_bounded(
                Command::new(bin("qfleet"))
                    .args(&cmd)
                    .arg("--out")
                    .arg(dir.join("never"))
                    .env("TMPDIR", &dir),
            );
            // clean has no --out: clap refuses that first (also exit 2)
            assert_eq!(code(&out), Some(2), "{cmd:?}: {}", describe(&out));
            if cmd[0] == "run" {
                assert!(
                    stderr(&out).contains("invalid run id"),
                    "{cmd:?}: {}",
                    describe(&out)
                );
                assert!(!dir.join("never").exists(), "{cmd:?} created its --out");
            }
        }
        let out = run_bounded(
            Command::new(bin("qfleet"))
                .args(["clean", "--dry-run"])
                .arg(format!("--run-id={bad}")),
        );
        assert_eq!(code(&out), Some(2), "clean {bad:?}: {}", describe(&out));
    }
    let out = run_bounded(
        Command::new(bin("qfleet"))
            .args(["experiment", "--run-id=-x"])
            .arg(
                Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/three-goals-six-robots.toml"),
            ),
    );
    assert_eq!(code(&out), Some(2), "{}", describe(&out));
    assert!(
        stderr(&out).contains("invalid run id"),
        "{}",
        describe(&out)
    );
}

#[test]
fn a_robot_killed_before_it_registers_is_reported_lost_and_the_run_completes() {
    let id = run_id("prereg");
    let dir = scratch("hl-prereg");
    let t = Instant::now();
    let launcher = spawn(
        qfleet_run(
            &id,
            &[
                "--map",
                "builtin:paper-10",
                "--episodes",
                "300",
                "--robots",
                "3",
            ],
        )
        .arg("--out")
        .arg(dir.join("out")),
    );
    let mut robot = None;
    assert!(wait_until(PROCESS_TIMEOUT, || {
        robot = pid_with_arg(&id, "--robot-id", "1");
        robot.is_some()
    }));
    std::thread::sleep(Duration::from_millis(30));
    kill(robot.unwrap(), libc::SIGKILL);
    let out = wait_bounded(launcher, PROCESS_TIMEOUT);
    eprintln!(
        "run with a robot killed before registering ended after {:?}",
        t.elapsed()
    );
    let r: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("no result ({e}): {}", describe(&out)));
    let lost = r["robots"]
        .as_array()
        .and_then(|a| a.iter().find(|x| x["robot_id"] == 1))
        .map(|x| x["status"].clone());
    assert_eq!(lost, Some(Value::from("lost")), "{r}");
    assert_clean(&id);
}

/// Item 20 (last part): a time limit that passes while the fleet is still starting stops every
/// robot with SIGTERM — also when the coordinator ends before it could stop them — so nothing
/// has to be killed after the grace period.
#[test]
fn a_tiny_time_limit_still_stops_every_robot_with_sigterm() {
    for limit in ["0.001", "0.2"] {
        let id = run_id("tinylimit");
        let dir = scratch(&format!("hl-tinylimit-{limit}"));
        // a grace far longer than a stop takes: a robot left to it would be killed and say so
        let out = run_bounded(
            qfleet_run(&id, &ENDLESS)
                .args(["--time-limit", limit, "--grace", "60"])
                .arg("--out")
                .arg(dir.join("out")),
        );
        let err = stderr(&out);
        assert_eq!(code(&out), Some(1), "{}", describe(&out));
        assert!(err.contains("time limit of"), "{}", describe(&out));
        assert!(
            !err.contains("did not stop within the grace period") && !err.contains("signal 9"),
            "--time-limit {limit}: a process was not stopped by SIGTERM: {}",
            describe(&out)
        );
        assert!(!err.contains("panicked"), "{}", describe(&out));
        assert!(pids_of_run(&id).is_empty(), "{:?}", pids_of_run(&id));
        assert_clean(&id);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
