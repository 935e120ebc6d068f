//! Support for the end-to-end tests: builds the real binaries once, runs processes with a
//! time bound, makes unique run ids, and finds (and, for a test's own nodes, sweeps) files a run
//! left in shared memory.
//!
//! `cargo test` builds only the package under test, so the first test that needs a binary runs
//! `cargo build --bins -p robot-agent -p coordinator -p qfleet` into the same target directory
//! and profile (guarded by a `OnceLock`; cargo's own lock serialises parallel test binaries).

pub mod mapf_check;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

/// Upper bound for any process a test starts; generous, so slow CI never fails on time alone,
/// but nothing can hang forever.
pub const PROCESS_TIMEOUT: Duration = Duration::from_secs(120);

/// The directory holding the built binaries (`target/<profile>/`), building them on first use.
pub fn bin_dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        // the test executable lives in target/<profile>/deps/
        let exe = std::env::current_exe().expect("test executable path");
        let profile_dir = exe
            .parent()
            .and_then(Path::parent)
            .expect("target/<profile>/deps/<test>")
            .to_path_buf();
        let target_dir = profile_dir.parent().expect("target dir").to_path_buf();
        let profile = profile_dir
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("debug")
            .to_string();
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        // The same selection as `cargo test --workspace` (every member, test targets, so
        // dev-dependencies count) plus the binaries: cargo then resolves the same features and
        // reuses every library that test build made. `--bins -p robot-agent -p coordinator -p
        // qfleet` resolved fewer features (regex-automata, getrandom, zerocopy) and rebuilt
        // zenoh and ~40 other crates inside the first end-to-end test: 477 s of a CI run.
        cmd.current_dir(env!("CARGO_MANIFEST_DIR"))
            .args(["build", "--workspace", "--bins", "--tests"])
            .env("CARGO_TARGET_DIR", &target_dir);
        if profile != "debug" {
            cmd.args(["--profile", &profile]);
        }
        let status = cmd.status().expect("running cargo build");
        assert!(status.success(), "building the qfleet binaries failed");
        profile_dir
    })
}

/// Path of one of the built binaries (`qfleet`, `robot-agent`, `qfleet-coordinator`).
pub fn bin(name: &str) -> PathBuf {
    bin_dir().join(name)
}

/// A run id no other test or test process uses.
pub fn run_id(tag: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    format!(
        "t-{tag}-{}-{}-{t:x}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

/// A fresh scratch directory for one test, unique to this test process (two test suites on
/// one machine never share one), removed when dropped — unless the test is failing, then kept
/// for a look and its path said.
pub fn scratch(name: &str) -> Scratch {
    let d = std::env::temp_dir().join(format!("qfleet-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("scratch dir");
    Scratch(d)
}

/// A test's scratch directory (see [`scratch`]); derefs to its path.
#[derive(Debug)]
pub struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for Scratch {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if std::thread::panicking() {
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "kept for a look: {}", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// Waits for a child with a time bound; kills it (and says so) when the bound passes. Its
/// stdout and stderr are read meanwhile, on threads of their own: a child whose output outgrows
/// the pipe's buffer (a 256-robot result is 130 KB of JSON) would otherwise block in `write`
/// and never exit.
pub fn wait_bounded(mut child: Child, timeout: Duration) -> Output {
    use std::io::Read;
    fn drain(pipe: Option<impl Read + Send + 'static>) -> std::thread::JoinHandle<Vec<u8>> {
        std::thread::spawn(move || {
            let mut buf = Vec::new();
            if let Some(mut p) = pipe {
                let _ = p.read_to_end(&mut buf);
            }
            buf
        })
    }
    let out = drain(child.stdout.take());
    let err = drain(child.stderr.take());
    let deadline = Instant::now() + timeout;
    let mut stuck = String::new();
    let (status, timed_out) = loop {
        match child.try_wait().expect("try_wait") {
            Some(status) => break (status, false),
            None if Instant::now() >= deadline => {
                stuck = where_stuck(child.id());
                let _ = child.kill();
                break (child.wait().expect("wait"), true);
            }
            None => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    let output = Output {
        status,
        stdout: out.join().unwrap_or_default(),
        stderr: err.join().unwrap_or_default(),
    };
    assert!(
        !timed_out,
        "process did not finish within {timeout:?}; stderr:\n{}\nstdout:\n{}\nwhere it was:\n{stuck}",
        String::from_utf8_lossy(&output.stderr),
        String::from_utf8_lossy(&output.stdout),
    );
    output
}

/// Where a process that does not finish is stuck, for the failure message: each thread's name,
/// kernel wait channel and system call from `/proc`, and the threads' stacks when `gdb` is on
/// the PATH (a hang seen once in CI left nothing else to go on).
pub fn where_stuck(pid: u32) -> String {
    let mut said = String::new();
    let read = |p: std::path::PathBuf| std::fs::read_to_string(p).unwrap_or_default();
    if let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) {
        for t in tasks.flatten() {
            let d = t.path();
            said.push_str(&format!(
                "thread {} {}: wchan {} syscall {}\n",
                t.file_name().to_string_lossy(),
                read(d.join("comm")).trim(),
                read(d.join("wchan")).trim(),
                read(d.join("syscall")).trim()
            ));
        }
    }
    let gdb = Command::new("gdb")
        .args([
            "-p",
            &pid.to_string(),
            "-batch",
            "-ex",
            "thread apply all bt",
        ])
        .stdin(Stdio::null())
        .output();
    match gdb {
        Ok(o) => said.push_str(&String::from_utf8_lossy(&o.stdout)),
        Err(e) => said.push_str(&format!("(no stacks: gdb: {e})\n")),
    }
    said
}

/// Starts `cmd` with piped stdout/stderr.
pub fn spawn(cmd: &mut Command) -> Child {
    cmd.stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn")
}

/// Runs `cmd` to completion within [`PROCESS_TIMEOUT`].
pub fn run_bounded(cmd: &mut Command) -> Output {
    wait_bounded(spawn(cmd), PROCESS_TIMEOUT)
}

/// Every file or directory in `/dev/shm` and `/tmp/iceoryx2` whose name contains `run_id`.
pub fn leftovers(run_id: &str) -> Vec<PathBuf> {
    fn walk(dir: &Path, needle: &str, found: &mut Vec<PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().contains(needle) {
                found.push(e.path());
            } else if e.file_type().is_ok_and(|t| t.is_dir()) {
                walk(&e.path(), needle, found);
            }
        }
    }
    let mut found = Vec::new();
    walk(Path::new("/dev/shm"), run_id, &mut found);
    walk(Path::new("/tmp/iceoryx2"), run_id, &mut found);
    found
}

/// Ends a test's own iceoryx2 node of run `run_id` (with its ports, passed in `node`) the way
/// the run's own processes end theirs: drops it, then removes the run's files if no process of
/// the run is alive any more. When the run ended while the test still held a node, the run's
/// processes rightly left the files to that live node; iceoryx2 removes the node's own files on
/// drop but never the run's management segment (`…global_mgmt`), so the last one out sweeps.
pub fn leave_run<T>(node: T, run_id: &str) {
    drop(node);
    let _ = bus::clean_stale(&bus::bus_schema::names::iceoryx_prefix(run_id));
}

/// Exit status and both streams of a process, for assertion messages.
pub fn describe(out: &Output) -> String {
    format!(
        "status {:?}\n--- stdout\n{}\n--- stderr\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Whether the process exited with success.
pub fn ok(status: ExitStatus) -> bool {
    status.success()
}

/// Says that a test skipped, and why: one line `SKIPPED: <test>: <reason>`, written whole to the
/// process's real stderr handle (`eprintln!` would be captured by the test harness and shown
/// only when the test fails), so it shows in every `cargo test` run. Call it once per skipped
/// test, then return: `.ci/run` counts these lines and prints `N passed, N failed, N skipped`,
/// with each skipped test taken off the passed count.
///
/// This is the one format; crates with tests of their own carry a copy of this function
/// (they cannot depend on this package), and `tests/skips.rs` keeps every copy identical.
pub fn skip(test: &str, reason: &str) {
    use std::io::Write;
    let line = format!("SKIPPED: {test}: {reason}\n");
    let _ = std::io::stderr().lock().write_all(line.as_bytes());
}

/// Pids of every live process whose command line has `--run-id <id>` (the launcher included).
pub fn pids_of_run(id: &str) -> Vec<i32> {
    let needle = format!("--run-id\0{id}\0");
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    entries
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<i32>().ok())
        .filter(|pid| {
            let alive = std::fs::read_to_string(format!("/proc/{pid}/stat"))
                .map(|s| {
                    // state is the field after the ")" that closes the command name
                    s.rsplit_once(')')
                        .is_some_and(|(_, rest)| !rest.trim_start().starts_with('Z'))
                })
                .unwrap_or(false);
            alive
                && std::fs::read(format!("/proc/{pid}/cmdline"))
                    .is_ok_and(|c| String::from_utf8_lossy(&c).contains(&needle))
        })
        .collect()
}

/// The pid of the process of run `id` whose command line also contains `arg` and `value` as
/// consecutive arguments (e.g. `--robot-id`, `1`), if one is alive.
pub fn pid_with_arg(id: &str, arg: &str, value: &str) -> Option<i32> {
    let needle = format!("{arg}\0{value}\0");
    pids_of_run(id).into_iter().find(|pid| {
        std::fs::read(format!("/proc/{pid}/cmdline"))
            .is_ok_and(|c| String::from_utf8_lossy(&c).contains(&needle))
    })
}

/// Waits (bounded by `timeout`) until `cond` holds; false if it never did.
pub fn wait_until(timeout: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let deadline = Instant::now() + timeout;
    loop {
        if cond() {
            return true;
        }
        if Instant::now() >= deadline {
            return false;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Files of the workspace whose names end in `suffix`, relative to its root, sorted: what git
/// tracks plus what it would track (new, not ignored), or, without git, every such file outside
/// `target*/`, `results/` and hidden directories.
pub fn workspace_files(suffix: &str) -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let git = Command::new("git")
        .current_dir(root)
        .args([
            "ls-files",
            "-z",
            "--cached",
            "--others",
            "--exclude-standard",
        ])
        .output();
    let mut files: Vec<PathBuf> = match git {
        Ok(o) if o.status.success() => o
            .stdout
            .split(|b| *b == 0)
            .filter_map(|f| std::str::from_utf8(f).ok())
            .filter(|f| f.ends_with(suffix) && root.join(f).is_file())
            .map(PathBuf::from)
            .collect(),
        _ => {
            fn walk(root: &Path, dir: &Path, suffix: &str, out: &mut Vec<PathBuf>) {
                let Ok(entries) = std::fs::read_dir(dir) else {
                    return;
                };
                for e in entries.flatten() {
                    let path = e.path();
                    let name = e.file_name().to_string_lossy().into_owned();
                    if path.is_dir() {
                        if !name.starts_with('.')
                            && !name.starts_with("target")
                            && name != "results"
                        {
                            walk(root, &path, suffix, out);
                        }
                    } else if name.ends_with(suffix) {
                        out.push(path.strip_prefix(root).unwrap_or(&path).to_path_buf());
                    }
                }
            }
            let mut out = Vec::new();
            walk(root, root, suffix, &mut out);
            out
        }
    };
    files.sort();
    files
}
