//! Supervising a run's processes for `qfleet run`: start them, follow the coordinator's
//! progress and liveness events, restart failed processes under a policy with backoff, stop
//! everything cleanly (grace period, then kill) on Ctrl-C/SIGTERM or a time limit.
//!
//! # Restart policy (`--restart on-failure --max-restarts K`)
//! - A robot-agent that dies (killed, crashed, non-zero exit) is started again after a backoff
//!   of 200 ms · 2^n (n = its restarts so far, at most 5 s), at most K times. The coordinator
//!   notices the death (node liveness), admits the new process under the same robot id and
//!   warm-starts it with its fleet table.
//! - A robot the coordinator reports hung (`event hung <id>`: silent past `--hang-ms`) is
//!   killed and then restarted the same way.
//! - A coordinator that dies is started again the same way; the running robots notice, keep
//!   learning meanwhile, and re-register with the new one.
//!
//! Without a policy (`--restart never`, the default) a dead robot is reported lost and the run
//! goes on without it; a dead coordinator ends the run.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::ValueEnum;
use std::os::unix::process::ExitStatusExt;

/// When `qfleet run` starts a failed process again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum RestartPolicy {
    /// Never: a dead robot is reported lost, a dead coordinator ends the run.
    Never,
    /// Restart a process that died, failed or hung, up to `--max-restarts` times each.
    OnFailure,
}

/// Backoff before the n-th restart (n from 0): 200 ms · 2^n, at most 5 s.
pub fn backoff(n: u32) -> Duration {
    Duration::from_millis(200u64.saturating_mul(1 << n.min(5))).min(Duration::from_secs(5))
}

/// One line the coordinator prints on stdout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CoordLine {
    /// `progress <episodes done> <total> <p50 ns> <p99 ns>`.
    Progress(u64, u64, u64, u64),
    /// `event hung <robot id> <ns>`.
    Hung(u32),
    /// Any other `event <kind> <robot id> <ns>` (lost, restarted, resumed …).
    Event(u32),
}

/// Parses one stdout line of the coordinator (`None`: not a line for the launcher).
pub fn parse_line(line: &str) -> Option<CoordLine> {
    if let Some(rest) = line.strip_prefix("progress ") {
        let v: Vec<u64> = rest.split(' ').filter_map(|x| x.parse().ok()).collect();
        return (v.len() == 4).then(|| CoordLine::Progress(v[0], v[1], v[2], v[3]));
    }
    let mut words = line.strip_prefix("event ")?.split(' ');
    let kind = words.next()?;
    let id: u32 = words.next()?.parse().ok()?;
    Some(if kind == "hung" {
        CoordLine::Hung(id)
    } else {
        CoordLine::Event(id)
    })
}

/// One supervised process (the coordinator is index 0, robot i is index i + 1).
pub struct Proc {
    /// `coordinator` or `robot-agent <id>`.
    pub name: String,
    child: Child,
    /// Its log file (stderr; appended to across restarts).
    pub log: PathBuf,
    /// Exit status of the current process, once it exited.
    pub status: Option<ExitStatus>,
    /// Restarts made so far.
    pub restarts: u32,
    /// When the next restart is due.
    restart_at: Option<Instant>,
}

impl Proc {
    fn poll(&mut self) -> Result<Option<ExitStatus>> {
        if self.status.is_none() {
            self.status = self
                .child
                .try_wait()
                .with_context(|| format!("waiting for {}", self.name))?;
        }
        Ok(self.status)
    }

    /// Sends `sig` to the process if it is still running.
    pub fn signal(&self, sig: libc::c_int) {
        if self.status.is_none() {
            // SAFETY: kill(2) on our own child's pid; at worst it fails with ESRCH.
            unsafe {
                libc::kill(self.child.id() as libc::pid_t, sig);
            }
        }
    }

    /// Whether the current process exited unsuccessfully.
    pub fn failed(&self) -> bool {
        self.status.is_some_and(|s| !s.success())
    }

    /// How the current process ended, for messages.
    pub fn describe(&self) -> String {
        let restarts = match self.restarts {
            0 => String::new(),
            n => format!(" (after {n} restarts)"),
        };
        match self.status {
            Some(s) if s.success() => format!("{} exited cleanly{restarts}", self.name),
            Some(s) => match (s.code(), s.signal()) {
                (Some(130), _) => format!("{} stopped early{restarts}", self.name),
                (Some(c), _) => format!("{} failed (exit code {c}){restarts}", self.name),
                (_, Some(sig)) => format!("{} was killed by signal {sig}{restarts}", self.name),
                _ => format!("{} failed{restarts}", self.name),
            },
            None => format!("{} is still running", self.name),
        }
    }
}

/// How to start each process of the run.
pub struct Launch<'a> {
    /// The coordinator's command (stdout must be piped).
    pub coordinator: &'a dyn Fn() -> Result<Command>,
    /// Robot `id`'s command.
    pub robot: &'a dyn Fn(u32) -> Result<Command>,
    /// Fleet size.
    pub robots: u32,
    /// Restart policy and budget.
    pub policy: RestartPolicy,
    /// Restarts allowed per process.
    pub max_restarts: u32,
    /// Grace period of a stopping process.
    pub grace: Duration,
    /// Stop the run after this long (zero: no limit).
    pub time_limit: Duration,
}

/// What a supervised run ended with.
pub struct Supervised {
    /// Failures to report (why the run stopped early, processes that failed for good).
    pub failures: Vec<String>,
    /// Restarts made, over all processes.
    pub restarts: u32,
}

fn log_file(out: &Path, name: &str, append: bool) -> Result<(PathBuf, std::fs::File)> {
    let p = out.join(format!("{name}.log"));
    let f = std::fs::OpenOptions::new()
        .create(true)
        .append(append)
        .write(true)
        .truncate(!append)
        .open(&p)
        .with_context(|| format!("creating {}", p.display()))?;
    Ok((p, f))
}

fn start(
    index: usize,
    launch: &Launch,
    out: &Path,
    tx: &mpsc::Sender<CoordLine>,
    append: bool,
) -> Result<(String, Child, PathBuf)> {
    let (name, file, mut cmd) = if index == 0 {
        (
            "coordinator".to_string(),
            "coordinator".to_string(),
            (launch.coordinator)()?,
        )
    } else {
        let id = index as u32 - 1;
        (
            format!("robot-agent {id}"),
            format!("robot-{id}"),
            (launch.robot)(id)?,
        )
    };
    let (log, f) = log_file(out, &file, append)?;
    let mut child = cmd
        .stderr(f)
        .spawn()
        .with_context(|| format!("starting {name}"))?;
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
    Ok((name, child, log))
}

/// Runs the processes of one run to their end; `on_progress` gets every progress line.
pub fn supervise(
    launch: &Launch,
    out: &Path,
    interrupts: &AtomicU32,
    mut on_progress: impl FnMut(u64, u64, u64, u64),
) -> Result<Supervised> {
    let (tx, rx) = mpsc::channel::<CoordLine>();
    let mut procs: Vec<Proc> = Vec::new();
    for index in 0..=launch.robots as usize {
        match start(index, launch, out, &tx, false) {
            Ok((name, child, log)) => procs.push(Proc {
                name,
                child,
                log,
                status: None,
                restarts: 0,
                restart_at: None,
            }),
            Err(e) => {
                for p in &mut procs {
                    p.signal(libc::SIGKILL);
                    let _ = p.child.wait();
                }
                return Err(e);
            }
        }
    }
    let restarting = launch.policy == RestartPolicy::OnFailure;
    let t0 = Instant::now();
    let mut stopping: Option<Instant> = None;
    let mut killed = false;
    let mut seen_interrupts = 0;
    let mut why_stopped: Option<String> = None;
    let mut interrupted = false;
    let mut total_restarts = 0;
    loop {
        while let Ok(line) = rx.try_recv() {
            match line {
                CoordLine::Progress(a, b, c, d) => on_progress(a, b, c, d),
                CoordLine::Hung(id) => {
                    if let Some(p) = procs.get(id as usize + 1) {
                        if restarting && p.restarts < launch.max_restarts && stopping.is_none() {
                            eprintln!("qfleet: robot-agent {id} is hung: killing it to restart it");
                            p.signal(libc::SIGKILL);
                        } else {
                            eprintln!(
                                "qfleet: robot-agent {id} is hung (not restarted: {})",
                                if restarting {
                                    "no restart left"
                                } else {
                                    "--restart never"
                                }
                            );
                        }
                    }
                }
                CoordLine::Event(_) => {}
            }
        }
        let mut all_done = true;
        for (index, p) in procs.iter_mut().enumerate() {
            let was_running = p.status.is_none();
            let status = p.poll()?;
            if status.is_none() || p.restart_at.is_some() {
                all_done = false;
            }
            // a process that just died: restart it if the policy allows
            if was_running
                && p.status.is_some_and(|s| restartable(index, s))
                && restarting
                && stopping.is_none()
                && p.restarts < launch.max_restarts
            {
                let delay = backoff(p.restarts);
                eprintln!(
                    "qfleet: {}; restarting it in {} ms ({} of {})",
                    p.describe(),
                    delay.as_millis(),
                    p.restarts + 1,
                    launch.max_restarts
                );
                p.restart_at = Some(Instant::now() + delay);
                all_done = false;
            }
        }
        if all_done {
            break;
        }
        for (index, p) in procs.iter_mut().enumerate() {
            let Some(at) = p.restart_at else { continue };
            if stopping.is_some() {
                p.restart_at = None;
                continue;
            }
            if Instant::now() < at {
                continue;
            }
            p.restart_at = None;
            let (_, child, _) = start(index, launch, out, &tx, true)?;
            p.child = child;
            p.status = None;
            p.restarts += 1;
            total_restarts += 1;
        }
        let coord_gone = procs[0].status.is_some() && procs[0].restart_at.is_none();
        let n = interrupts.load(Ordering::SeqCst);
        if n > seen_interrupts {
            seen_interrupts = n;
            interrupted = true;
            if n == 1 && stopping.is_none() {
                why_stopped = Some("interrupted (SIGINT/SIGTERM)".into());
                eprintln!("qfleet: stopping the run (Ctrl-C again to kill it now)");
                stopping = Some(Instant::now());
                procs[0].signal(libc::SIGTERM);
                if coord_gone {
                    for p in &procs[1..] {
                        p.signal(libc::SIGTERM);
                    }
                }
            } else if !killed {
                killed = true;
                for p in &procs {
                    p.signal(libc::SIGKILL);
                }
            }
        }
        if stopping.is_none() && !launch.time_limit.is_zero() && t0.elapsed() >= launch.time_limit {
            why_stopped = Some(format!("time limit of {:?} reached", launch.time_limit));
            stopping = Some(Instant::now());
            procs[0].signal(libc::SIGTERM);
        }
        if stopping.is_none() && coord_gone {
            // robots cannot finish without their coordinator: stop them
            stopping = Some(Instant::now());
            for p in &procs[1..] {
                p.signal(libc::SIGTERM);
            }
        }
        if let Some(t) = stopping
            && !killed
            && t.elapsed() >= launch.grace
        {
            killed = true;
            for p in &procs {
                p.signal(libc::SIGKILL);
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut failures: Vec<String> = Vec::new();
    if let Some(w) = why_stopped {
        failures.push(w);
    }
    for p in &procs {
        if p.failed() && !(interrupted && p.status.and_then(|s| s.code()) == Some(130)) {
            let t = tail(&p.log, 5);
            eprintln!(
                "qfleet: {} — last lines of {}:\n{t}",
                p.describe(),
                p.log.display()
            );
            failures.push(p.describe());
        } else if p.restarts > 0 {
            eprintln!("qfleet: {}", p.describe());
        }
    }
    Ok(Supervised {
        failures,
        restarts: total_restarts,
    })
}

/// Whether process `index` (0: the coordinator) ended in a way a restart can cure: killed by
/// a signal or crashed. Not a clean exit, nor bad input (2) or a refusal (3), which would only
/// repeat; nor a coordinator that ended the run with lost robots (4) or stopped early (130).
fn restartable(index: usize, status: ExitStatus) -> bool {
    match (status.code(), index) {
        (None, _) => true,
        (Some(0 | 2 | 3 | 130), _) => false,
        (Some(4), 0) => false,
        (Some(_), _) => true,
    }
}

fn tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let all: Vec<&str> = text.lines().collect();
    all[all.len().saturating_sub(lines)..].join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_progress_and_events() {
        assert_eq!(
            parse_line("progress 1 2 3 4"),
            Some(CoordLine::Progress(1, 2, 3, 4))
        );
        assert_eq!(parse_line("event hung 3 99"), Some(CoordLine::Hung(3)));
        assert_eq!(parse_line("event lost 7 99"), Some(CoordLine::Event(7)));
        for junk in ["", "progress 1 2", "event hung x 1", "hello", "event"] {
            assert_eq!(parse_line(junk), None, "{junk:?}");
        }
    }

    #[test]
    fn backoff_doubles_and_is_capped() {
        assert_eq!(backoff(0), Duration::from_millis(200));
        assert_eq!(backoff(1), Duration::from_millis(400));
        assert_eq!(backoff(10), Duration::from_secs(5));
        assert_eq!(backoff(u32::MAX), Duration::from_secs(5));
    }
}
