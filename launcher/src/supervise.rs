//! Supervising a run's processes: start them, follow the coordinator's progress and liveness
//! events, restart failed processes under a policy with backoff, stop everything cleanly (grace
//! period, then kill) on Ctrl-C/SIGTERM or a time limit.
//!
//! # Restart policy (`--restart on-failure --max-restarts K`)
//! - A robot-agent that dies (killed, crashed, non-zero exit) is started again after a backoff
//!   of 200 ms · 2^n (n = its restarts so far, at most 5 s), at most K times. The coordinator
//!   notices the death (node liveness), admits the new process under the same robot id and
//!   warm-starts it with its fleet table.
//! - A robot the coordinator reports hung (`event hung <id>`: silent past `--hang-ms`) is
//!   killed and then restarted the same way.
//! - A coordinator process that dies is started again the same way; the running robots notice,
//!   keep learning meanwhile, and re-register with the new one.
//! - A restart that cannot be made (its log file cannot be created, the binary is gone) stops
//!   the run cleanly: the coordinator is asked to stop, everything still running gets the
//!   grace period and is then killed; the run ends with that error. No process is ever left
//!   unsupervised.
//!
//! Without a policy (`--restart never`, the default) a dead robot is reported lost (and the
//! coordinator process is told at once, see `contract::lines`) and the run goes on without it;
//! a dead coordinator ends the run.
//!
//! # Stopping (Ctrl-C/SIGTERM, `--time-limit`, a restart that cannot be made)
//! Each child has its own process group, so a stop is delivered by the launcher: SIGTERM to the
//! coordinator process, which stops the robots over the bus and writes its result. Without a
//! coordinator process, or once it is gone (it may end before its signal handler exists, e.g.
//! a time limit that passes during start-up), the robots get SIGTERM directly, with a grace
//! period of their own. Whatever still runs `grace` after it was asked is killed. A child that
//! ends with 130 or by that SIGTERM answered the stop and is no failure.

use std::io::{BufRead, BufReader};
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use clap::ValueEnum;

use crate::exit::Exit;
use crate::spawn::bind_to_launcher;
use contract::lines::{CoordLine, exited_line, parse_line};

/// When the launcher starts a failed process again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum RestartPolicy {
    /// Never: a dead robot is reported lost, a dead coordinator ends the run.
    Never,
    /// Restart a process that died, failed or hung, up to `--max-restarts` times each.
    OnFailure,
}

impl RestartPolicy {
    /// Restarts the coordinator is told the launcher may make per process (it waits for a
    /// lost robot meanwhile): `max_restarts` with [`RestartPolicy::OnFailure`], none otherwise.
    pub fn restarts(self, max_restarts: u32) -> u32 {
        match self {
            RestartPolicy::Never => 0,
            RestartPolicy::OnFailure => max_restarts,
        }
    }
}

/// How the processes of a repetition of an experiment (or a sweep's run) are supervised.
#[derive(Debug, Clone, Copy)]
pub struct Supervision {
    /// Restart policy (robots and the coordinator).
    pub policy: RestartPolicy,
    /// Restarts allowed per process.
    pub max_restarts: u32,
    /// Grace period of a stopping process before it is killed.
    pub grace: Duration,
    /// The robots' `--pace` (steps per second), if any.
    pub pace: Option<f64>,
}

impl Default for Supervision {
    fn default() -> Self {
        Supervision {
            policy: RestartPolicy::Never,
            max_restarts: 3,
            grace: Duration::from_secs(5),
            pace: None,
        }
    }
}

/// Backoff before the n-th restart (n from 0): 200 ms · 2^n, at most 5 s.
pub fn backoff(n: u32) -> Duration {
    Duration::from_millis(200u64.saturating_mul(1 << n.min(5))).min(Duration::from_secs(5))
}

/// A process of the run could not be started at all.
#[derive(Debug, thiserror::Error)]
pub enum SuperviseError {
    /// Its log file could not be created.
    #[error("creating the log file {}", path.display())]
    Log {
        /// The log file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// The process could not be started.
    #[error("starting {name}")]
    Spawn {
        /// `coordinator` or `robot-agent <id>`.
        name: String,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

/// What the fleet is made of and how it is supervised.
pub struct Fleet<'a> {
    /// The coordinator's command (`qfleet run`, `qfleet experiment`); its stdout is piped to
    /// the supervisor. `None`: a fleet of robots alone (the supervisor's own tests), which ends
    /// when every robot has ended.
    pub coordinator: Option<&'a (dyn Fn() -> Command + Sync)>,
    /// Robot `id`'s command.
    pub robot: &'a (dyn Fn(u32) -> Command + Sync),
    /// Fleet size.
    pub robots: u32,
    /// Restart policy.
    pub policy: RestartPolicy,
    /// Restarts allowed per process under [`RestartPolicy::OnFailure`].
    pub max_restarts: u32,
    /// Grace period of a stopping process before it is killed.
    pub grace: Duration,
    /// Stop the run after this long (zero: no limit).
    pub time_limit: Duration,
    /// Directory of the process logs (`coordinator.log`, `robot-<id>.log`: stderr).
    pub logs: &'a Path,
    /// Called once between starting the coordinator and starting the robots: the launcher's
    /// outside readers (a recorder, the live view) join the run there, so that they see it
    /// from the first message a robot sends. Not called again for restarted processes.
    pub before_robots: Option<&'a (dyn Fn() + Sync)>,
}

/// What a supervised run ended with.
#[derive(Debug)]
pub struct Supervised {
    /// Failures to report (why the run stopped early, processes that failed for good).
    pub failures: Vec<String>,
    /// Restarts made, over all processes.
    pub restarts: u32,
    /// The class of the outcome (interrupted, a child's bad input, a failure, ok).
    pub exit: Exit,
    /// The result the coordinator sent on stdout because it could not write `result.json`
    /// (a full disk; see `contract::lines`), as JSON.
    pub result: Option<String>,
}

impl Supervised {
    /// The run's verdict once its observers and result are in: `quit`, whether the user
    /// stopped it with `q` in the live view (a clean user stop is a success), or why watching
    /// it failed; `has_result`, whether a result was read. Returns the failures to report (none:
    /// success) and the exit class.
    pub fn verdict(self, quit: Result<bool, String>, has_result: bool) -> (Vec<String>, Exit) {
        let (mut failures, mut exit) = (self.failures, self.exit);
        match quit {
            Ok(true) => {
                failures.retain(|f| !f.starts_with("interrupted"));
                if failures.is_empty() {
                    exit = Exit::Ok;
                }
            }
            Ok(false) => {}
            Err(e) => {
                failures.push(e);
                exit = exit.worst(Exit::Failure);
            }
        }
        if !has_result {
            failures.push("the coordinator wrote no result".into());
            exit = exit.worst(Exit::Failure);
        }
        (failures, exit)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Coordinator,
    Robot(u32),
}

impl Kind {
    fn name(self) -> String {
        match self {
            Kind::Coordinator => "coordinator".into(),
            Kind::Robot(id) => format!("robot-agent {id}"),
        }
    }
    fn log(self) -> String {
        match self {
            Kind::Coordinator => "coordinator".into(),
            Kind::Robot(id) => format!("robot-{id}"),
        }
    }
}

/// One supervised process.
struct Proc {
    kind: Kind,
    child: Child,
    log: PathBuf,
    status: Option<ExitStatus>,
    restarts: u32,
    restart_at: Option<Instant>,
}

impl Proc {
    fn poll(&mut self) {
        if self.status.is_none() {
            match self.child.try_wait() {
                Ok(s) => self.status = s,
                // cannot happen for our own child; treat it as gone rather than spin on it
                Err(_) => self.status = Some(ExitStatus::from_raw(1 << 8)),
            }
        }
    }

    fn signal(&self, sig: libc::c_int) {
        if self.status.is_none() {
            // SAFETY: kill(2) on our own unreaped child's pid; at worst it fails with ESRCH.
            unsafe {
                libc::kill(self.child.id() as libc::pid_t, sig);
            }
        }
    }

    fn failed(&self) -> bool {
        self.status.is_some_and(|s| !s.success())
    }

    fn describe(&self) -> String {
        let name = self.kind.name();
        let restarts = match self.restarts {
            0 => String::new(),
            n => format!(" (after {n} restarts)"),
        };
        match self.status {
            Some(s) if s.success() => format!("{name} exited cleanly{restarts}"),
            Some(s) => match (s.code(), s.signal()) {
                (Some(130), _) => format!("{name} stopped early{restarts}"),
                (Some(c), _) => format!("{name} failed (exit code {c}){restarts}"),
                (_, Some(sig)) => format!("{name} was killed by signal {sig}{restarts}"),
                _ => format!("{name} failed{restarts}"),
            },
            None => format!("{name} is still running"),
        }
    }
}

fn log_file(
    dir: &Path,
    name: &str,
    append: bool,
) -> Result<(PathBuf, std::fs::File), SuperviseError> {
    let path = dir.join(format!("{name}.log"));
    std::fs::OpenOptions::new()
        .create(true)
        .append(append)
        .write(true)
        .truncate(!append)
        .open(&path)
        .map(|f| (path.clone(), f))
        .map_err(|source| SuperviseError::Log { path, source })
}

fn start(
    kind: Kind,
    fleet: &Fleet,
    tx: &mpsc::Sender<CoordLine>,
    append: bool,
) -> Result<Proc, SuperviseError> {
    let mut cmd = match kind {
        Kind::Coordinator => match fleet.coordinator {
            Some(c) => c(),
            None => unreachable!("no coordinator process to start"),
        },
        Kind::Robot(id) => (fleet.robot)(id),
    };
    let (log, f) = log_file(fleet.logs, &kind.log(), append)?;
    cmd.stderr(f);
    match kind {
        Kind::Coordinator => cmd.stdin(Stdio::null()).stdout(Stdio::piped()),
        Kind::Robot(_) => cmd.stdin(Stdio::null()).stdout(Stdio::null()),
    };
    let mut child = bind_to_launcher(&mut cmd)
        .spawn()
        .map_err(|source| SuperviseError::Spawn {
            name: kind.name(),
            source,
        })?;
    if let Some(stdout) = child.stdout.take() {
        let tx = tx.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if let Some(l) = parse_line(&line)
                    && tx.send(l).is_err()
                {
                    break;
                }
            }
        });
    }
    Ok(Proc {
        kind,
        child,
        log,
        status: None,
        restarts: 0,
        restart_at: None,
    })
}

/// Whether a process ended in a way a restart can cure: killed by a signal or crashed. Not a
/// clean exit, nor bad input (2) or a refusal (3), which would only repeat; nor a coordinator
/// that ended the run with lost robots (4) or stopped early (130); nor a process that could
/// not write its result files (5: a robot reported first, a coordinator sent its result on
/// stdout; running again would end the same way).
fn restartable(kind: Kind, status: ExitStatus) -> bool {
    match (status.code(), kind) {
        (None, _) => true,
        (Some(0 | 2 | 3 | 130), _) => false,
        (Some(4), Kind::Coordinator) => false,
        (Some(5), _) => false,
        (Some(_), _) => true,
    }
}

fn tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let all: Vec<&str> = text.lines().collect();
    all[all.len().saturating_sub(lines)..].join("\n")
}

fn kill_all(procs: &mut [Proc]) {
    for p in procs.iter() {
        p.signal(libc::SIGKILL);
    }
    for p in procs.iter_mut() {
        if p.status.is_none() {
            p.status = p.child.wait().ok();
        }
    }
}

/// Runs the processes of one run to their end; `on_progress` gets every progress line and
/// `warn` every message for the user. `interrupts` counts SIGINT/SIGTERM: the first stops the
/// run gracefully, the second kills. The thread calling this must live until it returns (the
/// children die with it, see [`crate::spawn`]).
pub fn supervise(
    fleet: &Fleet,
    interrupts: &AtomicU32,
    mut on_progress: impl FnMut(u64, u64, u64, u64),
    mut warn: impl FnMut(&str),
) -> Result<Supervised, SuperviseError> {
    let (tx, rx) = mpsc::channel::<CoordLine>();
    let mut procs: Vec<Proc> = Vec::new();
    let kinds = fleet
        .coordinator
        .map(|_| Kind::Coordinator)
        .into_iter()
        .chain((0..fleet.robots).map(Kind::Robot));
    for kind in kinds {
        if kind == Kind::Robot(0)
            && let Some(f) = fleet.before_robots
        {
            f();
        }
        match start(kind, fleet, &tx, false) {
            Ok(p) => procs.push(p),
            Err(e) => {
                kill_all(&mut procs);
                return Err(e);
            }
        }
    }
    let has_coord = fleet.coordinator.is_some();
    let first_robot = usize::from(has_coord);
    let restarting = fleet.policy == RestartPolicy::OnFailure;
    let t0 = Instant::now();
    let mut stopping: Option<Instant> = None;
    // when whatever still runs is killed: `grace` after the stop, or after the robots were
    // asked directly (see below), whichever is later
    let mut kill_at: Option<Instant> = None;
    // whether the robots themselves were sent SIGTERM during this stop
    let mut robots_termed = false;
    let mut killed = false;
    let mut seen_interrupts = 0;
    let mut failures: Vec<String> = Vec::new();
    let mut interrupted = false;
    let mut total_restarts = 0;
    let mut result = None;
    // ask the run to stop: the coordinator process stops the robots; without one (or when it
    // is gone) the robots are asked directly. True when the robots were signalled.
    let stop = |procs: &[Proc]| -> bool {
        let coord_alive = has_coord && procs[0].status.is_none();
        if coord_alive {
            procs[0].signal(libc::SIGTERM);
            false
        } else {
            for p in &procs[first_robot..] {
                p.signal(libc::SIGTERM);
            }
            true
        }
    };
    // starts a stop now: records when, asks the run to stop, sets the kill deadline
    let begin_stop = |procs: &[Proc],
                      stopping: &mut Option<Instant>,
                      kill_at: &mut Option<Instant>,
                      robots_termed: &mut bool| {
        let now = Instant::now();
        *stopping = Some(now);
        *kill_at = Some(now + fleet.grace);
        *robots_termed = stop(procs);
    };
    loop {
        while let Ok(line) = rx.try_recv() {
            match line {
                CoordLine::Progress(a, b, c, d) => on_progress(a, b, c, d),
                CoordLine::Hung(id) => {
                    if let Some(p) = procs.get(id as usize + first_robot) {
                        if restarting && p.restarts < fleet.max_restarts && stopping.is_none() {
                            warn(&format!(
                                "robot-agent {id} is hung: killing it to restart it"
                            ));
                            p.signal(libc::SIGKILL);
                        } else {
                            warn(&format!(
                                "robot-agent {id} is hung (not restarted: {})",
                                if restarting {
                                    "no restart left"
                                } else {
                                    "--restart never"
                                }
                            ));
                        }
                    }
                }
                CoordLine::Event(_) => {}
                CoordLine::Result(json) => result = Some(json),
            }
        }
        let mut all_done = true;
        let mut exited_robots = Vec::new();
        for p in procs.iter_mut() {
            let was_running = p.status.is_none();
            p.poll();
            if p.status.is_none() || p.restart_at.is_some() {
                all_done = false;
            }
            let Some(status) = p.status.filter(|_| was_running) else {
                continue;
            };
            if restartable(p.kind, status)
                && restarting
                && stopping.is_none()
                && p.restarts < fleet.max_restarts
            {
                let delay = backoff(p.restarts);
                warn(&format!(
                    "{}; restarting it in {} ms ({} of {})",
                    p.describe(),
                    delay.as_millis(),
                    p.restarts + 1,
                    fleet.max_restarts
                ));
                p.restart_at = Some(Instant::now() + delay);
                all_done = false;
            } else if let Kind::Robot(id) = p.kind
                && !status.success()
            {
                exited_robots.push((id, exited_line(id, status.code(), status.signal())));
            }
        }
        // tell the coordinator (a process or in-process) at once about robots that are gone
        // for good: it reads `robot-<id>.exited` in the run directory (one file, written once)
        for (id, line) in exited_robots {
            let file = fleet.logs.join(format!("robot-{id}.exited"));
            if let Err(e) = crate::out::write_atomic(&file, line.as_bytes()) {
                // only the hint is lost: the coordinator still sees the robot's node vanish
                warn(&format!("telling the coordinator robot {id} exited: {e}"));
            }
        }
        if all_done {
            break;
        }
        for i in 0..procs.len() {
            let Some(at) = procs[i].restart_at else {
                continue;
            };
            if stopping.is_some() {
                procs[i].restart_at = None;
                continue;
            }
            if Instant::now() < at {
                continue;
            }
            procs[i].restart_at = None;
            let kind = procs[i].kind;
            match start(kind, fleet, &tx, true) {
                Ok(mut fresh) => {
                    fresh.restarts = procs[i].restarts + 1;
                    procs[i] = fresh;
                    total_restarts += 1;
                }
                Err(e) => {
                    let msg = format!("restarting {}: {}", kind.name(), error_chain(&e));
                    warn(&format!("{msg}; stopping the run"));
                    failures.push(msg);
                    begin_stop(&procs, &mut stopping, &mut kill_at, &mut robots_termed);
                }
            }
        }
        let coord_gone = has_coord && procs[0].status.is_some() && procs[0].restart_at.is_none();
        let n = interrupts.load(Ordering::SeqCst);
        if n > seen_interrupts {
            seen_interrupts = n;
            interrupted = true;
            if n == 1 && stopping.is_none() {
                failures.push("interrupted (SIGINT/SIGTERM)".into());
                warn("stopping the run (Ctrl-C again to kill it now)");
                begin_stop(&procs, &mut stopping, &mut kill_at, &mut robots_termed);
            } else if !killed {
                killed = true;
                for p in &procs {
                    p.signal(libc::SIGKILL);
                }
            }
        }
        if stopping.is_none() && !fleet.time_limit.is_zero() && t0.elapsed() >= fleet.time_limit {
            failures.push(format!("time limit of {:?} reached", fleet.time_limit));
            begin_stop(&procs, &mut stopping, &mut kill_at, &mut robots_termed);
        }
        if stopping.is_none() && coord_gone {
            // robots cannot finish without their coordinator: stop them
            begin_stop(&procs, &mut stopping, &mut kill_at, &mut robots_termed);
        }
        if stopping.is_some() && coord_gone && !robots_termed && !killed {
            // the coordinator was asked to stop the robots but is gone (it may have ended
            // before its signal handler existed, e.g. a tiny `--time-limit`, or crashed): the
            // robots are asked directly, and get their own grace period
            robots_termed = stop(&procs);
            kill_at = Some(Instant::now() + fleet.grace);
        }
        if let Some(t) = kill_at
            && !killed
            && Instant::now() >= t
        {
            killed = true;
            for p in &procs {
                if p.status.is_none() {
                    warn(&format!(
                        "{} did not stop within the grace period: killing it",
                        p.kind.name()
                    ));
                }
                p.signal(libc::SIGKILL);
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    // every process ended: take in the lines their stdout readers still hold (they end at
    // the pipes' end of file; bounded, in case a grandchild keeps a pipe open)
    drop(tx);
    let until = Instant::now() + Duration::from_secs(1);
    while let Ok(line) = rx.recv_timeout(until.saturating_duration_since(Instant::now())) {
        if let CoordLine::Result(json) = line {
            result = Some(json);
        }
    }
    let mut exit = if failures.is_empty() {
        Exit::Ok
    } else {
        Exit::Failure
    };
    for p in &procs {
        let code = p.status.and_then(|s| s.code());
        // 130 is how a process answers a stop, and SIGTERM ends one that had no handler yet:
        // not a failure when the launcher asked for the stop
        let answered_stop = stopping.is_some()
            && (code == Some(130) || p.status.and_then(|s| s.signal()) == Some(libc::SIGTERM));
        if p.failed() && !answered_stop {
            let t = tail(&p.log, 5);
            warn(&format!(
                "{} — last lines of {}:\n{t}",
                p.describe(),
                p.log.display()
            ));
            failures.push(p.describe());
            // after a stop the launcher asked for, a child's code says nothing about the input
            let class = match (p.kind, code) {
                (Kind::Coordinator, Some(c)) if stopping.is_none() => Exit::of_child(c),
                _ => Exit::Failure,
            };
            exit = exit.worst(class);
        } else if p.restarts > 0 {
            warn(&p.describe());
        }
    }
    if interrupted {
        exit = Exit::Interrupted;
    }
    Ok(Supervised {
        failures,
        restarts: total_restarts,
        exit,
        result,
    })
}

/// An error and its causes on one line.
fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        s.push_str(": ");
        s.push_str(&c.to_string());
        cur = c.source();
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_user_stop_is_a_success_and_a_missing_result_a_failure() {
        let run = |failures: &[&str], exit| Supervised {
            failures: failures.iter().map(|f| f.to_string()).collect(),
            restarts: 0,
            exit,
            result: None,
        };
        let stopped = run(&["interrupted by Ctrl-C"], Exit::Interrupted);
        assert_eq!(stopped.verdict(Ok(true), true), (vec![], Exit::Ok));
        let (f, e) = run(&["interrupted", "robot 1 failed"], Exit::Failure).verdict(Ok(true), true);
        assert_eq!((f, e), (vec!["robot 1 failed".to_string()], Exit::Failure));
        let (f, e) = run(&[], Exit::Ok).verdict(Err("watching: boom".into()), false);
        assert_eq!(f, ["watching: boom", "the coordinator wrote no result"]);
        assert_eq!(e, Exit::Failure);
        let (f, e) = run(&["interrupted"], Exit::Interrupted).verdict(Ok(false), true);
        assert_eq!((f.len(), e), (1, Exit::Interrupted));
    }

    #[test]
    fn backoff_doubles_and_is_capped() {
        assert_eq!(backoff(0), Duration::from_millis(200));
        assert_eq!(backoff(1), Duration::from_millis(400));
        assert_eq!(backoff(10), Duration::from_secs(5));
        assert_eq!(backoff(u32::MAX), Duration::from_secs(5));
    }

    #[test]
    fn only_crashes_are_restartable() {
        let code = |c: i32| ExitStatus::from_raw(c << 8);
        let sig = |s: i32| ExitStatus::from_raw(s);
        assert!(restartable(Kind::Robot(0), sig(9)));
        assert!(restartable(Kind::Robot(0), code(1)));
        assert!(restartable(Kind::Robot(0), code(101)));
        assert!(restartable(Kind::Robot(0), code(4)));
        assert!(!restartable(Kind::Coordinator, code(4)));
        assert!(!restartable(Kind::Robot(0), code(5)), "files not written");
        assert!(
            !restartable(Kind::Coordinator, code(5)),
            "files not written"
        );
        for c in [0, 2, 3, 130] {
            assert!(!restartable(Kind::Robot(0), code(c)), "{c}");
            assert!(!restartable(Kind::Coordinator, code(c)), "{c}");
        }
    }

    fn sh(script: &'static str) -> impl Fn(u32) -> Command + Sync {
        move |id| {
            let mut c = Command::new("sh");
            c.args(["-c", script, "robot", &id.to_string()]);
            c
        }
    }

    fn fleet<'a>(
        robot: &'a (dyn Fn(u32) -> Command + Sync),
        logs: &'a Path,
        policy: RestartPolicy,
    ) -> Fleet<'a> {
        Fleet {
            coordinator: None,
            robot,
            robots: 2,
            policy,
            max_restarts: 2,
            grace: Duration::from_secs(5),
            time_limit: Duration::ZERO,
            logs,
            before_robots: None,
        }
    }

    #[test]
    fn a_crashing_process_is_restarted_up_to_the_budget() {
        let d = tempfile::tempdir().unwrap();
        // robot 0 crashes every time, robot 1 exits cleanly
        let robot = sh(r#"echo started >&2; [ "$1" = 0 ] && exit 1; exit 0"#);
        let f = fleet(&robot, d.path(), RestartPolicy::OnFailure);
        let s = supervise(&f, &AtomicU32::new(0), |_, _, _, _| {}, |_| {}).unwrap();
        assert_eq!(s.restarts, 2);
        assert_eq!(s.exit, Exit::Failure);
        assert_eq!(
            s.failures,
            vec!["robot-agent 0 failed (exit code 1) (after 2 restarts)"]
        );
        let log = std::fs::read_to_string(d.path().join("robot-0.log")).unwrap();
        assert_eq!(
            log.lines().count(),
            3,
            "the log is appended to across restarts"
        );
    }

    #[test]
    fn the_hook_before_the_robots_runs_once_before_the_first_robot_and_not_for_restarts() {
        let d = tempfile::tempdir().unwrap();
        // robot 0 crashes every time (two restarts), robot 1 exits cleanly
        let robot = sh(r#"[ "$1" = 0 ] && exit 1; exit 0"#);
        let calls = std::sync::atomic::AtomicU32::new(0);
        let logs = d.path().to_path_buf();
        let hook = || {
            calls.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            // no robot has been started yet: none has its log
            assert!(!logs.join("robot-0.log").exists());
            assert!(!logs.join("robot-1.log").exists());
        };
        let mut f = fleet(&robot, d.path(), RestartPolicy::OnFailure);
        f.before_robots = Some(&hook);
        let s = supervise(&f, &AtomicU32::new(0), |_, _, _, _| {}, |_| {}).unwrap();
        assert_eq!(s.restarts, 2);
        assert_eq!(calls.load(std::sync::atomic::Ordering::SeqCst), 1);
    }

    #[test]
    fn without_a_policy_nothing_is_restarted() {
        let d = tempfile::tempdir().unwrap();
        let robot = sh(r#"[ "$1" = 0 ] && kill -9 $$; exit 0"#);
        let f = fleet(&robot, d.path(), RestartPolicy::Never);
        let s = supervise(&f, &AtomicU32::new(0), |_, _, _, _| {}, |_| {}).unwrap();
        assert_eq!(s.restarts, 0);
        assert_eq!(s.failures, vec!["robot-agent 0 was killed by signal 9"]);
    }

    #[test]
    fn a_restart_that_cannot_start_stops_the_fleet_with_an_error() {
        let d = tempfile::tempdir().unwrap();
        // robot 0 removes its own log and puts a directory there, then crashes: the restart
        // cannot open its log; robot 1 would run for a minute if nobody stopped it
        let dir = d.path().to_path_buf();
        let robot = move |id: u32| {
            let mut c = Command::new("sh");
            let log = dir.join("robot-0.log");
            c.args([
                "-c",
                r#"if [ "$1" = 0 ]; then rm -f "$2" && mkdir "$2"; exit 1; fi; trap 'exit 130' TERM; sleep 60 & wait"#,
                "robot",
                &id.to_string(),
            ])
            .arg(log);
            c
        };
        let f = fleet(&robot, d.path(), RestartPolicy::OnFailure);
        let t = Instant::now();
        let s = supervise(&f, &AtomicU32::new(0), |_, _, _, _| {}, |_| {}).unwrap();
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "robot 1 was not stopped"
        );
        assert_eq!(s.exit, Exit::Failure);
        assert!(
            s.failures[0].starts_with("restarting robot-agent 0: creating the log file"),
            "{:?}",
            s.failures
        );
    }

    #[test]
    fn a_coordinator_gone_during_a_stop_hands_the_stop_to_the_robots() {
        let d = tempfile::tempdir().unwrap();
        // the coordinator has no handler (SIGTERM ends it at once, as a real one that is still
        // starting when a tiny `--time-limit` passes); the robots answer SIGTERM in their logs
        let coordinator = || {
            let mut c = Command::new("sh");
            c.args(["-c", "exec sleep 60"]);
            c
        };
        let robot =
            sh(r#"trap 'echo got SIGTERM >&2; exit 130' TERM; echo ready >&2; sleep 60 & wait"#);
        let mut f = fleet(&robot, d.path(), RestartPolicy::Never);
        f.coordinator = Some(&coordinator);
        // a grace so long that a robot left to it would fail the test
        f.grace = Duration::from_secs(60);
        let interrupts = AtomicU32::new(0);
        let logs = d.path().to_path_buf();
        let s = std::thread::scope(|scope| {
            scope.spawn(|| {
                // Ctrl-C once both robots have their handler
                let ready = |id: u32| {
                    std::fs::read_to_string(logs.join(format!("robot-{id}.log")))
                        .is_ok_and(|l| l.contains("ready"))
                };
                while !(ready(0) && ready(1)) {
                    std::thread::sleep(Duration::from_millis(10));
                }
                interrupts.fetch_add(1, Ordering::SeqCst);
            });
            supervise(&f, &interrupts, |_, _, _, _| {}, |_| {}).unwrap()
        });
        assert_eq!(s.failures, vec!["interrupted (SIGINT/SIGTERM)"]);
        assert_eq!(s.exit, Exit::Interrupted);
        for id in 0..2 {
            let log = std::fs::read_to_string(d.path().join(format!("robot-{id}.log"))).unwrap();
            assert_eq!(log, "ready\ngot SIGTERM\n", "robot {id}");
        }
    }
}
