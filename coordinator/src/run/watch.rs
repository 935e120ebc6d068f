//! Robot liveness beyond iceoryx2's node states: heartbeat deadlines (a hung robot), loss and
//! restart bookkeeping, and admitting a robot that registers again during the run (a restarted
//! process, or a running robot re-joining a restarted coordinator), warm-started from the fleet
//! table.
//!
//! Every liveness event is also printed on stdout as `event <kind> <robot id> <monotonic ns>`
//! so the launcher (`qfleet run`) can act on it (kill and restart a hung robot).

use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bus::bus_schema::{Command, Control, MergedHintBatch, Register};
use bus::{
    BusConfig, BusError, CoordinatorBus, Expected, NodeReport, check_nodes, check_register,
    monotonic_ns,
};
use crossbeam::channel::{Receiver, TrySendError, bounded};
use serde::{Deserialize, Serialize};

use super::{Coord, CoordError};

/// One liveness event of the run (also printed as an `event …` line on stdout).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LivenessEvent {
    /// The robot.
    pub robot_id: u32,
    /// `lost` (its process died), `hung` (silent past the deadline), `resumed` (a hung robot
    /// spoke again), `restarted` (a new process took its place), `rejoined` (the same process
    /// registered again).
    pub kind: String,
    /// CLOCK_MONOTONIC time of the event, ns (comparable with other processes' clocks).
    pub at_ns: u64,
    /// How long the robot had been silent when the event was raised, ms.
    pub silent_ms: u64,
}

/// One listing of the run's nodes, made by the [`Lister`] thread.
pub(super) struct Listing {
    /// When the listing started: a robot that registered after it cannot be in it.
    pub(super) at: Instant,
    /// The nodes, or why they could not be listed.
    pub(super) report: Result<NodeReport, BusError>,
}

/// Lists the run's nodes on a thread of its own, every `every` (and at once after
/// [`Lister::now`]), and hands the newest listing to the coordinator's loop.
///
/// Listing (iceoryx2 `Node::list`) costs ~3.6 M instructions, about 1 ms: on the loop's own
/// thread that was a 1 ms stall every 100 ms for the spinning coordinator. The loop now only
/// polls a channel ([`Lister::poll`], one atomic load when nothing is there). The channel holds
/// one listing: a newer one replaces an unread older one.
pub(super) struct Lister {
    rx: Receiver<Listing>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Lister {
    /// Starts the thread; its first listing is made right away.
    pub(super) fn start(cfg: &BusConfig, every: Duration) -> Result<Self, CoordError> {
        let (tx, rx) = bounded::<Listing>(1);
        let stale = rx.clone();
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = Arc::clone(&stop);
        let cfg = cfg.clone();
        let thread = std::thread::Builder::new()
            .name("qfleet-liveness".into())
            .spawn(move || {
                while !stopped.load(Ordering::Relaxed) {
                    let at = Instant::now();
                    let mut listing = Listing {
                        at,
                        report: check_nodes(&cfg, false),
                    };
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
                    // `now` unparks: a peer-death notice is answered without waiting
                    std::thread::park_timeout(every);
                }
            })
            .map_err(|e| CoordError::Input(format!("cannot start the liveness thread: {e}")))?;
        Ok(Lister {
            rx,
            stop,
            thread: Some(thread),
        })
    }

    /// The newest listing not yet taken, if any (never blocks).
    #[inline]
    pub(super) fn poll(&self) -> Option<Listing> {
        self.rx.try_recv().ok()
    }

    /// Asks for a listing now (a wake service reported a dead peer).
    pub(super) fn now(&self) {
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

/// Per-robot liveness state kept next to the coordinator's robot slots.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Lifeline {
    pid: u32,
    joined_at: Option<Instant>,
    last_seen: Option<Instant>,
    hung: bool,
    lost_at: Option<Instant>,
    restarts: u32,
    warm_started: bool,
    /// Discoveries received from earlier (dead) incarnations of this robot.
    disc_from_dead: u64,
}

/// Liveness state of the whole fleet.
pub(super) struct Life {
    lines: Vec<Lifeline>,
    events: Vec<LivenessEvent>,
    expected: Expected,
    hang_after: Duration,
    restarts: u32,
    wait_restart: Duration,
    merged_buffer: usize,
    /// The background cleanup of dead nodes, while one runs.
    cleaner: Option<std::thread::JoinHandle<()>>,
}

impl Life {
    pub(super) fn new(
        expected: Expected,
        hang_after: Duration,
        restarts: u32,
        wait_restart: Duration,
        merged_buffer: usize,
    ) -> Self {
        Life {
            lines: vec![Lifeline::default(); expected.robots as usize],
            events: Vec::new(),
            expected,
            hang_after,
            restarts,
            wait_restart,
            merged_buffer,
            cleaner: None,
        }
    }

    /// Removes dead nodes' resources (their ports in every service, their shared memory) on a
    /// background thread, one cleanup at a time: it takes a few hundred ms and must not stall
    /// the coordinator's loop. Until it is done, lossless sends may wait on a dead robot's
    /// buffer, bounded by the coordinator's 1 s send timeout.
    pub(super) fn clean_dead(&mut self, cfg: &BusConfig) {
        if self.cleaner.as_ref().is_some_and(|h| !h.is_finished()) {
            return;
        }
        if let Some(h) = self.cleaner.take() {
            let _ = h.join();
        }
        let cfg = cfg.clone();
        self.cleaner = Some(std::thread::spawn(move || {
            if let Err(e) = check_nodes(&cfg, true) {
                eprintln!("qfleet-coordinator: warning: cleaning up dead nodes: {e}");
            }
        }));
    }

    /// A robot was admitted by the start handshake.
    pub(super) fn admitted(&mut self, reg: &Register) {
        if let Some(l) = self.lines.get_mut(reg.robot_id as usize) {
            l.pid = reg.pid;
            l.joined_at = Some(Instant::now());
            l.last_seen = l.joined_at;
        }
    }

    /// Whether `robot_id`'s current process registered after `t` (a node listing made before
    /// that cannot have seen it).
    pub(super) fn joined_since(&self, robot_id: usize, t: Instant) -> bool {
        self.lines
            .get(robot_id)
            .and_then(|l| l.joined_at)
            .is_some_and(|j| j >= t)
    }

    /// A valid message from `robot_id` arrived.
    #[inline]
    pub(super) fn seen(&mut self, robot_id: u32) {
        if let Some(l) = self.lines.get_mut(robot_id as usize) {
            l.last_seen = Some(Instant::now());
            if l.hung {
                l.hung = false;
                let silent = 0;
                self.push(robot_id, "resumed", silent);
            }
        }
    }

    fn push(&mut self, robot_id: u32, kind: &str, silent_ms: u64) {
        let ev = LivenessEvent {
            robot_id,
            kind: kind.to_string(),
            at_ns: monotonic_ns(),
            silent_ms,
        };
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "event {} {} {}", ev.kind, ev.robot_id, ev.at_ns);
        let _ = out.flush();
        self.events.push(ev);
    }

    fn silent_ms(&self, robot_id: u32) -> u64 {
        self.lines
            .get(robot_id as usize)
            .and_then(|l| l.last_seen)
            .map_or(0, |t| t.elapsed().as_millis() as u64)
    }

    /// The robot's process died (its node is gone or dead).
    pub(super) fn lost(&mut self, robot_id: u32) {
        let silent = self.silent_ms(robot_id);
        if let Some(l) = self.lines.get_mut(robot_id as usize) {
            l.lost_at = Some(Instant::now());
            l.hung = false;
        }
        self.push(robot_id, "lost", silent);
    }

    /// Whether a lost or hung robot no longer holds up the end of the run: a hung one never
    /// does; a lost one does while a restart may still bring it back.
    pub(super) fn settled(&self, robot_id: usize, lost: bool) -> bool {
        let Some(l) = self.lines.get(robot_id) else {
            return true;
        };
        if l.hung {
            return true;
        }
        lost && (l.restarts >= self.restarts
            || l.lost_at.is_none_or(|t| t.elapsed() >= self.wait_restart))
    }

    /// Robots currently hung.
    pub(super) fn hung(&self) -> Vec<u32> {
        (0..self.lines.len() as u32)
            .filter(|&i| self.lines[i as usize].hung)
            .collect()
    }

    /// Whether `robot_id` is hung.
    pub(super) fn is_hung(&self, robot_id: usize) -> bool {
        self.lines.get(robot_id).is_some_and(|l| l.hung)
    }

    /// Restarts of `robot_id` and whether its latest incarnation got the fleet table.
    pub(super) fn restarts(&self, robot_id: usize) -> (u32, bool) {
        self.lines
            .get(robot_id)
            .map_or((0, false), |l| (l.restarts, l.warm_started))
    }

    /// Discoveries received from dead incarnations, over the fleet.
    pub(super) fn disc_from_dead(&self) -> u64 {
        self.lines.iter().map(|l| l.disc_from_dead).sum()
    }

    /// Every event so far.
    pub(super) fn events(&self) -> &[LivenessEvent] {
        &self.events
    }
}

impl Coord {
    /// Heartbeat deadlines: a robot that is neither done nor lost and sent nothing for
    /// `--hang-ms` is reported hung (once; `resumed` if it speaks again). Called only when
    /// every inbox is drained, so a coordinator that is behind never blames a robot.
    pub(super) fn check_deadlines(&mut self) {
        let now = Instant::now();
        let hang_after = self.life.hang_after;
        for (id, slot) in self.robots.iter().enumerate() {
            let busy = slot.accepted && !slot.lost && !slot.finished && slot.report.is_none();
            let line = &mut self.life.lines[id];
            // a process that has not spoken since it joined is still starting up (a restarted
            // robot on a loaded machine): it gets four deadlines
            let deadline = if line.last_seen == line.joined_at {
                hang_after * 4
            } else {
                hang_after
            };
            let late = line
                .last_seen
                .is_some_and(|t| now.duration_since(t) >= deadline);
            if busy && late && !line.hung {
                line.hung = true;
                let silent = self.life.silent_ms(id as u32);
                eprintln!(
                    "qfleet-coordinator: robot {id} is hung: nothing from it for {silent} ms \
                     (deadline {} ms)",
                    hang_after.as_millis()
                );
                self.life.push(id as u32, "hung", silent);
            }
        }
    }

    /// A `Register` during the run: a robot that missed its `Ack` (same pid: acked again), a
    /// restarted robot process (new pid, the old one is dead: admitted and warm-started from
    /// the fleet table), or a clash with a live robot of the same id (refused).
    pub(super) fn on_register(
        &mut self,
        bus: &CoordinatorBus,
        reg: &Register,
    ) -> Result<(), CoordError> {
        let id = reg.robot_id;
        // a Refuse is addressed by robot id only: never send one that a live robot of that
        // id would read as its own (a stray or forged registration), just log and drop it
        let holder_alive = |c: &Coord| {
            c.robots
                .get(id as usize)
                .is_some_and(|s| s.accepted && !s.lost)
                && c.life.lines[id as usize].pid != reg.pid
        };
        if let Err(why) = check_register(reg, &self.life.expected) {
            self.rejected += 1;
            eprintln!("qfleet-coordinator: refused a late registration of robot {id}: {why}");
            if holder_alive(self) {
                return Ok(());
            }
            return tolerate(bus.refuse(id, &why).map(drop));
        }
        let slot = self.robots[id as usize];
        let old_pid = self.life.lines[id as usize].pid;
        if slot.accepted && old_pid == reg.pid {
            // it missed its Ack: answer again
            return tolerate(bus.send_control(bus::control(Command::Ack, id)).map(drop));
        }
        if slot.accepted && !slot.lost && old_pid != reg.pid {
            // is the old process really gone? (clean it up if so, so its ports are freed)
            let nodes = check_nodes(bus.config(), true)?;
            let name = format!("qfleet-robot-{id}");
            let old_alive = nodes
                .alive()
                .any(|n| n.name == name && n.pid == Some(old_pid as i32));
            if old_alive {
                let why = format!("robot id {id} already taken by pid {old_pid}");
                eprintln!(
                    "qfleet-coordinator: refused robot {id} (pid {}): {why}",
                    reg.pid
                );
                self.rejected += 1;
                return Ok(()); // no Refuse: robot `id` itself would read it
            }
        }
        // a new incarnation: forget the dead one's progress, keep what the fleet learned
        let silent = self.life.silent_ms(id);
        let restarted = slot.accepted;
        {
            let s = &mut self.robots[id as usize];
            if restarted {
                self.life.lines[id as usize].disc_from_dead += s.next_disc;
                self.disc_received = self.disc_received.saturating_sub(s.next_disc);
            }
            *s = super::RobotSlot {
                accepted: true,
                alive: true,
                episodes_total: reg.episodes,
                seed: reg.seed,
                ..super::RobotSlot::default()
            };
            self.out_of_order.remove(&id);
        }
        {
            let l = &mut self.life.lines[id as usize];
            if restarted {
                l.restarts += 1;
            }
            l.pid = reg.pid;
            l.joined_at = Some(Instant::now());
            l.lost_at = None;
            l.hung = false;
            l.last_seen = Some(Instant::now());
            l.warm_started = false;
        }
        self.life
            .push(id, if restarted { "restarted" } else { "joined" }, silent);
        eprintln!(
            "qfleet-coordinator: robot {id} (pid {}) {} the run",
            reg.pid,
            if restarted {
                "restarted and rejoined"
            } else {
                "joined"
            }
        );
        bus.connect_all()?;
        tolerate(bus.send_control(bus::control(Command::Ack, id)).map(drop))?;
        let goal = self.task.goal;
        tolerate(
            bus.send_control(Control {
                goal_id: 0,
                goal_x: goal.x,
                goal_y: goal.y,
                ..bus::control(Command::AssignGoal, id)
            })
            .map(drop),
        )?;
        // warm start: the whole fleet table, before Start, paced so the latest-wins buffers
        // of the robots keep up
        let batches = self.resend_table(bus)?;
        self.life.lines[id as usize].warm_started = batches > 0;
        tolerate(bus.start(id, 0).map(drop))
    }

    /// Sends the whole fleet table (after whatever is pending) as merged batches to every
    /// robot, pacing rounds of half a merged buffer; returns the batches sent.
    pub(super) fn resend_table(&mut self, bus: &CoordinatorBus) -> Result<u64, CoordError> {
        self.flush_merged(bus)?;
        let round = (self.life.merged_buffer / 2).max(1);
        let mut in_round = 0;
        let mut err = None;
        let mut seq = self.merged_seq;
        let mut sent = 0;
        self.table.resend_all(|t| {
            if err.is_some() {
                let mut sink = MergedHintBatch::ZEROED;
                t.take_into(&mut sink);
                return;
            }
            if let Err(e) = bus.merged.send_with(|m| {
                t.take_into(m);
                m.coordinator_seq = seq;
                m.send_time_ns = monotonic_ns();
            }) {
                err = Some(e);
            }
            seq += 1;
            sent += 1;
            in_round += 1;
            if in_round >= round {
                in_round = 0;
                std::thread::sleep(Duration::from_millis(5));
            }
        });
        self.merged_seq = seq;
        self.merged_sent += sent;
        match err {
            Some(e) => Err(e.into()),
            None => Ok(sent),
        }
    }
}

/// A lossless control send that timed out (a stopped robot does not drain) or reached nobody
/// (the robot died meanwhile) must not end the run: the liveness checks deal with that robot.
pub(super) fn tolerate(r: Result<(), BusError>) -> Result<(), CoordError> {
    match r {
        Ok(()) => Ok(()),
        Err(e @ (BusError::DeliveryTimeout { .. } | BusError::NoSubscriber { .. })) => {
            eprintln!("qfleet-coordinator: warning: {e}");
            Ok(())
        }
        Err(e) => Err(e.into()),
    }
}
