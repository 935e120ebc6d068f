//! Node listings off the hot loops, and cheap between full ones.
//!
//! A full listing of a run's iceoryx2 nodes ([`check_nodes`]) is expensive: iceoryx2 formats
//! paths for its error messages and parses every node's TOML details, ~150 µs for two nodes
//! (`cargo bench --bench bus -- liveness`) and 0.5–1.5 ms in a run beside its other processes.
//! A coordinator that listed every 100 ms, even on a thread of its own and even at the lowest
//! scheduling class, put one such burst of CPU on the cores its bridge hub polls on, and the
//! cross-host update loop's p99.9 rose from 0.22–0.31 ms (no listings) to 0.60–0.77 ms
//! (BENCHMARKS.md "Across machines", "The poller on a CPU of its own, and listings that do not
//! burst").
//!
//! So a [`Lister`] thread makes a full listing only every [`FULL_EVERY`] (and at once when
//! asked, after a death, or while a node's state is unclear); in between it re-checks the
//! processes of the nodes the last full listing saw, one `/proc/<pid>/stat` read each
//! ([`recheck`]), which sees a death as soon as a listing would (a zombie counts as dead).
//! When a process the listing saw alive is not visible in this host's `/proc` (another PID
//! namespace), only full listings are made. What to do next is decided by [`Schedule`], a
//! type without IO tested as a specification.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam::channel::{Receiver, TrySendError, bounded};

use crate::liveness::{Liveness, NodeReport, check_nodes};
use crate::{BusConfig, BusError, Committer};

/// Longest time between two full listings while the re-checks find nothing new.
pub const FULL_EVERY: Duration = Duration::from_secs(1);

/// One listing of the run's nodes, made by the [`Lister`] thread.
#[derive(Debug)]
pub struct Listing {
    /// When the newest full listing behind it started: a node created after it cannot be in it
    /// (a re-check only updates the liveness of the nodes that listing found).
    pub at: Instant,
    /// The nodes, or why they could not be listed.
    pub report: Result<NodeReport, BusError>,
    /// Whether this is a full listing (else a re-check of the last one's processes).
    pub full: bool,
    /// A segment of the run whose pages `/dev/shm` could not reserve ([`crate::Committer`],
    /// tried on every full listing): the first process to touch it would die of SIGBUS, so the
    /// run should end now, with what it has.
    pub shm: Option<BusError>,
}

/// What one process looks like in `/proc`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProcessState {
    /// Running (or sleeping, stopped, …).
    Running,
    /// Gone, or a zombie: it will never send again.
    Ended,
    /// `/proc` could not tell (not readable).
    Unknown,
}

/// The state of process `pid` in this host's `/proc`.
pub fn process_state(pid: i32) -> ProcessState {
    if pid <= 0 {
        return ProcessState::Unknown;
    }
    match std::fs::read(format!("/proc/{pid}/stat")) {
        // the state is the first field after the command name, which may hold ')' itself
        Ok(stat) => match stat.iter().rposition(|&b| b == b')') {
            Some(i) => match stat.get(i + 2) {
                Some(b'Z' | b'X' | b'x') => ProcessState::Ended,
                Some(_) => ProcessState::Running,
                None => ProcessState::Unknown,
            },
            None => ProcessState::Unknown,
        },
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => ProcessState::Ended,
        Err(_) => ProcessState::Unknown,
    }
}

/// `last` with every node that was alive re-checked through `state` (a process id to its
/// [`ProcessState`]): an ended process makes its node dead; anything else keeps the node as it
/// was. Returns the updated report and whether any node died.
pub fn recheck(last: &NodeReport, state: impl Fn(i32) -> ProcessState) -> (NodeReport, bool) {
    let mut report = last.clone();
    report.cleaned = 0;
    report.cleanup_failed = 0;
    let mut died = false;
    for n in &mut report.nodes {
        if n.liveness == Liveness::Alive
            && let Some(pid) = n.pid
            && state(pid) == ProcessState::Ended
        {
            n.liveness = Liveness::Dead;
            died = true;
        }
    }
    (report, died)
}

/// When the [`Lister`] makes a full listing and when a re-check is enough: the decision,
/// without IO.
#[derive(Debug, Clone)]
pub struct Schedule {
    full_every: Duration,
    /// The last full listing: when it started and what it found (`None`: none yet, or it
    /// failed).
    last: Option<(Instant, NodeReport)>,
    /// A full listing is wanted at the next round (asked for, a death seen, a node unclear).
    want_full: bool,
    /// Every process the last full listing saw alive is visible in `/proc`.
    pids_visible: bool,
}

impl Schedule {
    /// A schedule whose first round is a full listing, then one at least every `full_every`.
    pub fn new(full_every: Duration) -> Self {
        Schedule {
            full_every,
            last: None,
            want_full: true,
            pids_visible: false,
        }
    }

    /// Asks for a full listing at the next round (a peer was reported dead).
    pub fn ask(&mut self) {
        self.want_full = true;
    }

    /// Whether the round at `now` must be a full listing.
    pub fn full_due(&self, now: Instant) -> bool {
        match &self.last {
            None => true,
            Some((at, _)) => {
                self.want_full
                    || !self.pids_visible
                    || now.saturating_duration_since(*at) >= self.full_every
            }
        }
    }

    /// Takes a full listing started at `at`; `state` tells whether its alive processes are
    /// visible here. A failed listing is tried again next round.
    pub fn full_done(
        &mut self,
        at: Instant,
        report: &Result<NodeReport, BusError>,
        state: impl Fn(i32) -> ProcessState,
    ) {
        match report {
            Ok(r) => {
                // a node whose state iceoryx2 could not read may be any process: look again
                self.want_full = r
                    .nodes
                    .iter()
                    .any(|n| !matches!(n.liveness, Liveness::Alive | Liveness::Dead));
                self.pids_visible = r
                    .alive()
                    .all(|n| n.pid.is_some_and(|pid| state(pid) == ProcessState::Running));
                self.last = Some((at, r.clone()));
            }
            Err(_) => {
                self.want_full = true;
                self.last = None;
            }
        }
    }

    /// A re-check of the last full listing through `state`: the listing to hand on (`None`
    /// when there was no full listing to re-check). A death makes the next round full, which
    /// confirms it (and cleans up, for a lister that cleans).
    pub fn recheck(&mut self, state: impl Fn(i32) -> ProcessState) -> Option<Listing> {
        let (at, last) = self.last.as_ref()?;
        let (report, died) = recheck(last, state);
        self.want_full |= died;
        Some(Listing {
            at: *at,
            report: Ok(report),
            full: false,
            shm: None,
        })
    }
}

/// Lists the run's nodes on a thread of its own, every `every` (and at once after
/// [`Lister::now`]), and hands the newest listing to the loop that owns it: full listings at
/// most every [`FULL_EVERY`], cheap re-checks in between (see the module doc).
///
/// The loop only polls a channel ([`Lister::poll`], one atomic load when nothing is there). The
/// channel holds one listing: a newer one replaces an unread older one.
pub struct Lister {
    rx: Receiver<Listing>,
    stop: Arc<AtomicBool>,
    asked: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Lister {
    /// Starts the thread (named `name`); its first listing is a full one, made right away.
    /// With `clean_dead`, full listings also remove dead nodes' stale resources.
    pub fn start(
        cfg: &BusConfig,
        every: Duration,
        clean_dead: bool,
        name: &str,
    ) -> std::io::Result<Self> {
        let (tx, rx) = bounded::<Listing>(1);
        let stale = rx.clone();
        let stop = Arc::new(AtomicBool::new(false));
        let asked = Arc::new(AtomicBool::new(false));
        let (stopped, ask) = (Arc::clone(&stop), Arc::clone(&asked));
        let cfg = cfg.clone();
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                let mut schedule = Schedule::new(FULL_EVERY);
                // segments created after the start (a restarted robot's connections, an
                // observer's ports) get their pages reserved here, within a full listing's time
                let mut committer = Committer::new(&cfg.prefix());
                while !stopped.load(Ordering::Relaxed) {
                    let at = Instant::now();
                    if ask.swap(false, Ordering::Relaxed) {
                        schedule.ask();
                    }
                    let listing = if schedule.full_due(at) {
                        let report = check_nodes(&cfg, clean_dead);
                        schedule.full_done(at, &report, process_state);
                        Some(Listing {
                            at,
                            report,
                            full: true,
                            shm: committer.pass().err(),
                        })
                    } else {
                        schedule.recheck(process_state)
                    };
                    if let Some(mut listing) = listing {
                        // latest wins: drop an unread older listing
                        loop {
                            match tx.try_send(listing) {
                                Ok(()) => break,
                                Err(TrySendError::Full(l)) => {
                                    listing = l;
                                    let _ = stale.try_recv();
                                }
                                Err(TrySendError::Disconnected(_)) => return,
                            }
                        }
                    }
                    // `now` unparks: a peer-death notice is answered without waiting
                    std::thread::park_timeout(every);
                }
            })?;
        Ok(Lister {
            rx,
            stop,
            asked,
            thread: Some(thread),
        })
    }

    /// The newest listing not yet taken, if any (never blocks).
    #[inline]
    pub fn poll(&self) -> Option<Listing> {
        self.rx.try_recv().ok()
    }

    /// Asks for a full listing now (a wake service reported a dead peer).
    pub fn now(&self) {
        self.asked.store(true, Ordering::Relaxed);
        if let Some(t) = &self.thread {
            t.thread().unpark();
        }
    }
}

impl Drop for Lister {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::liveness::NodeInfo;

    fn node(name: &str, pid: i32, liveness: Liveness) -> NodeInfo {
        NodeInfo {
            name: name.into(),
            pid: Some(pid),
            executable: "qfleet".into(),
            liveness,
            id: None,
        }
    }

    fn report(nodes: Vec<NodeInfo>) -> NodeReport {
        NodeReport {
            nodes,
            ..NodeReport::default()
        }
    }

    fn running(_: i32) -> ProcessState {
        ProcessState::Running
    }

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn the_first_round_is_full_then_rechecks_until_full_every_has_passed() {
        let t0 = Instant::now();
        let mut s = Schedule::new(1000 * MS);
        assert!(s.full_due(t0));
        assert!(s.recheck(running).is_none(), "nothing to re-check yet");
        let r = Ok(report(vec![node("qfleet-robot-0", 10, Liveness::Alive)]));
        s.full_done(t0, &r, running);
        assert!(!s.full_due(t0 + 100 * MS));
        let l = s.recheck(running).unwrap();
        assert!(!l.full);
        assert_eq!(
            l.at, t0,
            "a re-check is as old as the full listing behind it"
        );
        assert_eq!(l.report.unwrap().alive().count(), 1);
        assert!(!s.full_due(t0 + 999 * MS));
        assert!(s.full_due(t0 + 1000 * MS));
    }

    #[test]
    fn a_death_seen_by_a_recheck_is_handed_on_and_makes_the_next_round_full() {
        let t0 = Instant::now();
        let mut s = Schedule::new(1000 * MS);
        let r = Ok(report(vec![
            node("qfleet-coordinator", 1, Liveness::Alive),
            node("qfleet-robot-0", 10, Liveness::Alive),
            node("qfleet-robot-1", 11, Liveness::Dead),
        ]));
        s.full_done(t0, &r, running);
        let l = s
            .recheck(|pid| {
                if pid == 10 {
                    ProcessState::Ended
                } else {
                    ProcessState::Running
                }
            })
            .unwrap();
        let rep = l.report.unwrap();
        let dead: Vec<&str> = rep.dead().map(|n| n.name.as_str()).collect();
        assert_eq!(dead, ["qfleet-robot-0", "qfleet-robot-1"]);
        assert!(
            s.full_due(t0 + MS),
            "a death is confirmed by a full listing"
        );
        // an unknown state (unreadable /proc) proves nothing
        s.full_done(t0 + MS, &r, running);
        let l = s.recheck(|_| ProcessState::Unknown).unwrap();
        assert_eq!(l.report.unwrap().alive().count(), 2);
        assert!(!s.full_due(t0 + 2 * MS));
    }

    #[test]
    fn only_full_listings_when_a_process_is_not_visible_here_or_a_node_is_unclear() {
        let t0 = Instant::now();
        let mut s = Schedule::new(1000 * MS);
        let r = Ok(report(vec![node("qfleet-robot-0", 10, Liveness::Alive)]));
        // another PID namespace: /proc here does not show it, so a re-check would call it dead
        s.full_done(t0, &r, |_| ProcessState::Ended);
        assert!(s.full_due(t0 + MS));
        let unclear = Ok(report(vec![
            node("qfleet-robot-0", 10, Liveness::Alive),
            node("", 0, Liveness::Undefined),
        ]));
        s.full_done(t0, &unclear, running);
        assert!(s.full_due(t0 + MS));
        let mut without_pid = report(vec![node("qfleet-robot-0", 10, Liveness::Alive)]);
        without_pid.nodes[0].pid = None;
        s.full_done(t0, &Ok(without_pid), running);
        assert!(s.full_due(t0 + MS));
        s.full_done(t0, &r, running);
        assert!(!s.full_due(t0 + MS));
    }

    #[test]
    fn asking_or_a_failed_listing_makes_the_next_round_full() {
        let t0 = Instant::now();
        let mut s = Schedule::new(1000 * MS);
        let r = Ok(report(vec![node("qfleet-robot-0", 10, Liveness::Alive)]));
        s.full_done(t0, &r, running);
        s.ask();
        assert!(s.full_due(t0 + MS));
        s.full_done(t0 + MS, &r, running);
        assert!(!s.full_due(t0 + 2 * MS));
        let failed = Err(BusError::Liveness {
            prefix: "p".into(),
            detail: "cannot list nodes".into(),
        });
        s.full_done(t0 + 2 * MS, &failed, running);
        assert!(s.full_due(t0 + 3 * MS));
        assert!(s.recheck(running).is_none(), "no listing to re-check");
    }

    #[test]
    fn this_process_runs_and_an_unused_pid_has_ended() {
        assert_eq!(
            process_state(std::process::id() as i32),
            ProcessState::Running
        );
        // above the kernel's largest pid_max (4 194 304): never a process
        assert_eq!(process_state(i32::MAX), ProcessState::Ended);
        assert_eq!(process_state(0), ProcessState::Unknown);
    }

    /// Says that a test skipped, and why: a copy of `qfleet_suite::skip` (`tests/support/lib.rs`
    /// says why it looks so; `tests/skips.rs` keeps every copy identical).
    fn skip(test: &str, reason: &str) {
        use std::io::Write;
        let line = format!("SKIPPED: {test}: {reason}\n");
        let _ = std::io::stderr().lock().write_all(line.as_bytes());
    }

    #[test]
    fn a_zombie_has_ended() {
        // a child that exited and was not waited for stays a zombie until it is
        let Ok(mut child) = std::process::Command::new("true").spawn() else {
            skip(
                "bus lister::tests::a_zombie_has_ended",
                "cannot start `true`",
            );
            return;
        };
        let pid = child.id() as i32;
        let deadline = Instant::now() + Duration::from_secs(10);
        while process_state(pid) == ProcessState::Running && Instant::now() < deadline {
            std::thread::sleep(MS);
        }
        assert_eq!(process_state(pid), ProcessState::Ended);
        let _ = child.wait();
    }
}
