//! Issue 10, the bus and input items, with real processes: what another user, a stalled
//! outside reader, a full `/dev/shm` and hostile input files can do to a run (a fleet of 256:
//! `tests/scale.rs`).
//!
//! Tests that need root (another user via `setpriv`, private mount namespaces via `unshare`)
//! print why they skip when they cannot run; everything else runs as any user.

use std::os::unix::fs::MetadataExt;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};

use bus::bus_schema::{
    Control, DiscoveryRelay, FinalReport, PseudoTargetDiscovery, Register, RobotState,
};
use bus::{BusConfig, DIR_MODE, FILE_MODE, Observer, leftover_files};
use qfleet_suite::{
    PROCESS_TIMEOUT, bin, describe, leftovers, run_bounded, run_id, scratch, skip, spawn,
    wait_bounded,
};
use serde_json::Value;

fn is_root() -> bool {
    // SAFETY: geteuid has no preconditions.
    unsafe { libc::geteuid() == 0 }
}

/// Whether `tool` runs here (util-linux may be missing, or namespaces forbidden).
fn works(cmd: &mut Command) -> bool {
    cmd.output().is_ok_and(|o| o.status.success())
}

fn launch(id: &str, out: &Path, extra: &[&str]) -> Child {
    spawn(
        Command::new(bin("qfleet"))
            .args(["run", "--json", "--run-id", id, "--out"])
            .arg(out)
            .args(extra)
            .process_group(0),
    )
}

fn result(out: &Output) -> Value {
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("no JSON result ({e}): {}", describe(out)))
}

fn assert_all_finished(r: &Value, robots: usize) {
    let rs = r["robots"].as_array().expect("robots");
    assert_eq!(rs.len(), robots, "{r}");
    for x in rs {
        assert_eq!(x["status"], "finished", "{x}");
    }
}

fn assert_quiet(out: &Output) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !err.contains("No config file was loaded") && !err.contains("[W]") && !err.contains("[E]"),
        "library noise on stderr:\n{err}"
    );
}

/// Items 7 & 18: every file of a live run is 0600/0700 and owned by the user; another user
/// (`nobody`) can neither read nor overwrite any of them, and the run goes on.
#[test]
fn another_user_can_neither_read_nor_overwrite_any_file_of_a_run() {
    if !is_root() {
        skip(
            "hardening_bus::another_user_can_neither_read_nor_overwrite_any_file_of_a_run",
            "needs root to act as another user with setpriv",
        );
        return;
    }
    if !works(Command::new("setpriv").args([
        "--reuid=nobody",
        "--regid=nogroup",
        "--clear-groups",
        "true",
    ])) {
        skip(
            "hardening_bus::another_user_can_neither_read_nor_overwrite_any_file_of_a_run",
            "setpriv --reuid=nobody does not work here",
        );
        return;
    }
    let id = run_id("other-user");
    let dir = scratch(&id);
    let robots = 3u32;
    let child = launch(
        &id,
        &dir,
        &[
            "--map",
            "builtin:paper-20",
            "--episodes",
            "300000",
            "--robots",
            "3",
            // slow enough that the run is still learning when the test stops it: unpaced, an
            // idle machine finished all 300 000 episodes (3.9 s) before the SIGTERM came
            "--pace",
            "200000",
        ],
    );
    let cfg = BusConfig::new(id.as_str(), robots).expect("config");
    let observer = Observer::join(&cfg, "perm-test", PROCESS_TIMEOUT).expect("join the run");
    let state = observer.inbox::<RobotState>().expect("state inbox");
    // waits until every robot published a state with seq above `after[robot]`; returns the
    // newest seq seen per robot
    let learning = |after: [Option<u64>; 3]| {
        let deadline = Instant::now() + PROCESS_TIMEOUT;
        let mut newest = [None; 3];
        while (0..3).any(|i| newest[i].is_none_or(|n| after[i].is_some_and(|a| n <= a))) {
            while let Some(s) = state.receive().expect("receive") {
                if let Some(x) = newest.get_mut(s.robot_id as usize) {
                    *x = Some(x.map_or(s.seq, |v: u64| v.max(s.seq)));
                }
            }
            assert!(Instant::now() < deadline, "robots stopped publishing state");
            std::thread::sleep(Duration::from_millis(10));
        }
        newest
    };
    let before = learning([None; 3]);
    let files = leftover_files(&cfg.prefix());
    assert!(
        files
            .iter()
            .any(|f| f.to_string_lossy().ends_with("global_mgmt")),
        "{files:#?}"
    );
    for f in &files {
        let Ok(m) = std::fs::symlink_metadata(f) else {
            continue;
        };
        let want = if m.is_dir() {
            DIR_MODE
        } else {
            m.mode() & FILE_MODE
        };
        assert_eq!(m.uid(), 0, "{}", f.display());
        assert_eq!(m.mode() & 0o7777, want, "{} is {:o}", f.display(), m.mode());
    }
    // as nobody: read each file, append to it, list each directory; nothing may succeed
    let script = r#"for f in "$@"; do
        if [ -d "$f" ]; then ls "$f" >/dev/null 2>&1 && echo "LISTED $f";
        else cat "$f" >/dev/null 2>&1 && echo "READ $f";
             (printf x >> "$f") 2>/dev/null && echo "WROTE $f"; fi
    done"#;
    let out = Command::new("setpriv")
        .args([
            "--reuid=nobody",
            "--regid=nogroup",
            "--clear-groups",
            "sh",
            "-c",
            script,
            "sh",
        ])
        .args(&files)
        .output()
        .expect("setpriv");
    let broke = String::from_utf8_lossy(&out.stdout);
    assert!(
        broke.trim().is_empty(),
        "nobody got into the run's files:\n{broke}"
    );
    eprintln!(
        "nobody could not read, write or list any of the run's {} files",
        files.len()
    );
    // the run is unaffected: every robot keeps learning, and it stops cleanly when asked
    learning(before);
    drop(state);
    drop(observer);
    // SAFETY: plain kill(2) on our own child's process group.
    unsafe { libc::kill(-(child.id() as i32), libc::SIGTERM) };
    let out = wait_bounded(child, PROCESS_TIMEOUT);
    let r = result(&out);
    assert_eq!(r["interrupted"], true, "{r}");
    assert_eq!(r["robots"].as_array().map(Vec::len), Some(3), "{r}");
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Runs `qfleet ARGS` inside a private mount namespace after `setup` (shell) ran there.
fn in_private_mounts(setup: &str, args: &[&str]) -> Output {
    let qfleet = bin("qfleet");
    let mut cmd = Command::new("unshare");
    cmd.args(["-m", "--propagation", "private", "sh", "-c"])
        .arg(format!("{setup} && exec \"$0\" \"$@\""))
        .arg(qfleet)
        .args(args);
    run_bounded(&mut cmd)
}

fn namespaces_work() -> bool {
    is_root()
        && works(Command::new("unshare").args([
            "-m",
            "--propagation",
            "private",
            "sh",
            "-c",
            "mount -t tmpfs -o size=1m tmpfs /mnt",
        ]))
}

/// Item 18: a root-owned iceoryx2 root directory is an error for an unprivileged user before
/// any process starts, saying which directory and what to do.
#[test]
fn a_root_owned_iceoryx2_dir_is_an_error_before_any_process_starts() {
    if !namespaces_work() {
        skip(
            "hardening_bus::a_root_owned_iceoryx2_dir_is_an_error_before_any_process_starts",
            "needs root and mount namespaces (unshare -m)",
        );
        return;
    }
    let id = run_id("root-dir");
    let setup = "mkdir -p /tmp/iceoryx2 && mount -t tmpfs -o mode=0755 tmpfs /tmp/iceoryx2 \
                 && exec setpriv --reuid=nobody --regid=nogroup --clear-groups \"$0\" \"$@\" && :";
    let out = in_private_mounts(
        setup,
        &[
            "run",
            "--robots",
            "2",
            "--episodes",
            "10",
            "--run-id",
            &id,
            "--out",
            "/nonexistent/never-created",
        ],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{}", describe(&out));
    assert!(
        err.contains("/tmp/iceoryx2") && err.contains("cannot create files in it"),
        "{}",
        describe(&out)
    );
    assert!(
        !err.contains("qfleet-coordinator") && !err.contains("robot-agent"),
        "no process may start: {err}"
    );
}

/// Item 16: a nearly full `/dev/shm` is "no space in /dev/shm: need ~X MiB, have Y" before
/// any process starts.
#[test]
fn a_nearly_full_dev_shm_is_a_clear_error_before_starting() {
    if !namespaces_work() {
        skip(
            "hardening_bus::a_nearly_full_dev_shm_is_a_clear_error_before_starting",
            "needs root and mount namespaces (unshare -m)",
        );
        return;
    }
    let id = run_id("no-shm");
    let out = in_private_mounts(
        "mount -t tmpfs -o size=2m tmpfs /dev/shm",
        &["run", "--robots", "64", "--episodes", "10", "--run-id", &id],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{}", describe(&out));
    assert!(
        err.contains("no space in /dev/shm: need ~") && err.contains("MiB, have"),
        "{}",
        describe(&out)
    );
    assert!(!err.contains("UnableToGenerateUniqueNodeId"), "{err}");
}

/// Item 12: an outside reader that never reads any lossless topic never aborts a 64-robot run;
/// also the library stays quiet (no iceoryx2 warnings on stderr).
#[test]
fn a_stalled_outside_reader_never_aborts_a_64_robot_run() {
    let id = run_id("stalled");
    let dir = scratch(&id);
    let child = launch(
        &id,
        &dir,
        &[
            "--map",
            "builtin:paper-10",
            "--episodes",
            "300",
            "--robots",
            "64",
        ],
    );
    let cfg = BusConfig::new(id.as_str(), 64).expect("config");
    // joins once the services exist, before robots register; never reads anything
    let observer = Observer::join(&cfg, "stalled", PROCESS_TIMEOUT).expect("join the run");
    let control = observer.inbox::<Control>().expect("control");
    let relay = observer.inbox::<DiscoveryRelay>().expect("relay");
    let register = observer.inbox::<Register>().expect("register");
    let discovery = observer
        .inbox::<PseudoTargetDiscovery>()
        .expect("discovery");
    let report = observer.inbox::<FinalReport>().expect("report");
    let out = wait_bounded(child, Duration::from_secs(300));
    assert!(out.status.success(), "{}", describe(&out));
    assert_all_finished(&result(&out), 64);
    assert_quiet(&out);
    drop((control, relay, register, discovery, report, observer));
    let _ = bus::clean_stale(&cfg.prefix());
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Item 9: `--map /dev/zero` and a FIFO are refused at once, before any process starts.
#[test]
fn a_map_on_dev_zero_or_a_fifo_is_refused_at_once() {
    let dir = scratch(&run_id("fifo"));
    let fifo = dir.join("map.txt");
    let c = std::ffi::CString::new(fifo.to_str().expect("utf-8 path")).expect("path");
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    for (map, says) in [
        (Path::new("/dev/zero"), "not a regular file"),
        (fifo.as_path(), "FIFO"),
    ] {
        let t0 = Instant::now();
        let out = run_bounded(
            Command::new(bin("qfleet"))
                .args(["run", "--robots", "2", "--map"])
                .arg(map),
        );
        assert!(!out.status.success(), "{}", describe(&out));
        assert!(
            String::from_utf8_lossy(&out.stderr).contains(says),
            "{}",
            describe(&out)
        );
        eprintln!("--map {}: refused in {:?}", map.display(), t0.elapsed());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A `qfleet run --json --run-id ID --out DIR/out ARGS` in a private mount namespace whose
/// `/dev/shm` is a 96 MiB tmpfs that `dd` fills right after `Start` (once the coordinator's
/// first checkpoint exists), then runs `after_fill` (shell); the result on stdout goes to
/// `DIR/result.json`. Prints `shm avail 0` on stderr once the tmpfs is full.
fn run_with_dev_shm_filled(id: &str, dir: &Path, args: &[&str], after_fill: &str) -> Output {
    let out_dir = dir.join("out");
    let script = format!(
        "mount -t tmpfs -o size=96m tmpfs /dev/shm || exit 90
         \"$0\" \"$@\" > {result} & run=$!
         while [ ! -e {cp} ] && kill -0 $run 2>/dev/null; do sleep 0.05; done
         dd if=/dev/zero of=/dev/shm/fill bs=1M 2>/dev/null
         echo \"shm avail $(df -k --output=avail /dev/shm | tail -1 | tr -d ' ')\" >&2
         {after_fill}
         wait $run",
        result = dir.join("result.json").display(),
        cp = out_dir.join("coordinator-checkpoint.json").display(),
    );
    run_bounded(
        Command::new("unshare")
            .args(["-m", "--propagation", "private", "sh", "-c", &script])
            .arg(bin("qfleet"))
            .args(["run", "--json", "--run-id", id, "--out"])
            .arg(&out_dir)
            .args(args),
    )
}

/// Issue 27: `/dev/shm` filling up mid-run killed the run's processes with SIGBUS and no
/// result was written: in a private mount namespace with a 96 MiB tmpfs on `/dev/shm`, a `dd`
/// that fills it right after `Start` (once the coordinator's first checkpoint exists) made the
/// launcher report "coordinator was killed by signal 7; robot-agent 1 was killed by signal 7;
/// the coordinator wrote no result". iceoryx2 0.10 maps its dynamic storage lazily
/// (`zero_memory(false)`), so pages were first touched mid-run. Every process now reserves the
/// pages of the run's segments right after creating its ports (`bus::commit_run_shm`), so the
/// same fill leaves the run to finish with its result.
#[test]
fn a_dev_shm_filled_mid_run_neither_kills_the_run_nor_loses_its_result() {
    if !namespaces_work() {
        qfleet_suite::skip(
            "a_dev_shm_filled_mid_run_neither_kills_the_run_nor_loses_its_result",
            "needs root and mount namespaces (unshare -m)",
        );
        return;
    }
    let id = run_id("shm-full");
    let dir = scratch(&id);
    let out_dir = dir.join("out");
    let out = run_with_dev_shm_filled(
        &id,
        &dir,
        &[
            "--map",
            "builtin:paper-20",
            "--episodes",
            "300000",
            "--robots",
            "2",
            "--learner",
            "improved",
        ],
        "",
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{}", describe(&out));
    assert!(
        err.contains("shm avail 0"),
        "the tmpfs was filled: {}",
        describe(&out)
    );
    let r: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("result.json")).expect("the result on stdout"),
    )
    .expect("a result");
    for x in r["robots"].as_array().expect("robots") {
        assert_eq!(x["status"], "finished", "{r}");
    }
    assert!(out_dir.join("result.json").exists(), "result.json written");
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}

/// Issue 27, the other half: segments created *after* `/dev/shm` filled up (a robot killed
/// mid-run and started again, with its new ports and connections) never kill a process with
/// SIGBUS either: iceoryx2 refuses to create what it cannot zero, the others' pages are
/// reserved when they are made ([`bus::commit_run_shm`], and the coordinator's listings,
/// [`bus::Committer`], which end the run with what it has when they cannot): the restarted
/// robot fails with "no space in /dev/shm …" and is reported lost, the run's result is
/// written and no process dies of a signal.
#[test]
fn a_robot_restarted_after_dev_shm_filled_up_is_an_error_never_a_sigbus() {
    if !namespaces_work() {
        qfleet_suite::skip(
            "a_robot_restarted_after_dev_shm_filled_up_is_an_error_never_a_sigbus",
            "needs root and mount namespaces (unshare -m)",
        );
        return;
    }
    let id = run_id("shm-full-restart");
    let dir = scratch(&id);
    let out_dir = dir.join("out");
    let kill_robot_1 = format!(
        "for p in $(pgrep -x robot-agent); do
           if tr '\\0' ' ' < /proc/$p/cmdline | grep -q -- '{id}.*--robot-id 1 \\|--robot-id 1 .*{id}'; then
             kill -9 $p && echo \"killed robot 1\" >&2
           fi
         done"
    );
    let out = run_with_dev_shm_filled(
        &id,
        &dir,
        &[
            "--map",
            "builtin:paper-20",
            "--episodes",
            "1000000",
            "--robots",
            "2",
            "--restart",
            "on-failure",
            "--max-restarts",
            "1",
            "--learner",
            "improved",
        ],
        &kill_robot_1,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("shm avail 0") && err.contains("killed robot 1"),
        "the tmpfs was filled and robot 1 killed: {}",
        describe(&out)
    );
    assert!(
        out.status.code().is_some_and(|c| c != 101) && !err.contains("signal 7"),
        "an exit code, no SIGBUS, no panic: {}",
        describe(&out)
    );
    let r: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("result.json")).expect("the result on stdout"),
    )
    .expect("a result");
    let robots = r["robots"].as_array().expect("robots");
    assert_eq!(robots.len(), 2, "{r}");
    assert_eq!(
        robots[0]["status"], "finished",
        "robot 0 was never touched: {r}"
    );
    assert!(out_dir.join("result.json").exists(), "result.json written");
    for f in ["coordinator.log", "robot-0.log", "robot-1.log"] {
        let log = std::fs::read_to_string(out_dir.join(f)).unwrap_or_default();
        assert!(!log.contains("panicked"), "{f}: {log}");
    }
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
    let _ = std::fs::remove_dir_all(&dir);
}
