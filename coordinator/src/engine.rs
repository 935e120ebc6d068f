//! The coordinator engine both drivers (a run, an experiment) share: the start handshake,
//! draining every inbox with each message checked against its sender and its fields, discovery
//! acks and relays, one fleet table per goal with merged batches going out, late
//! registrations (a restarted robot warm-started from its goal's table), node liveness from the
//! [`bus::Lister`] thread, heartbeat deadlines.
//!
//! The decisions live in IO-free types ([`Roster`], [`Discoveries`], [`validate`], [`Life`]);
//! the engine only carries them out on the bus. A plain run is a one-goal, one-phase plan: its
//! driver sets one [`Assignment`] per robot, as the experiment driver does per phase.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use bus::bus_schema::{
    Command, Control, DiscoveryAck, FinalReport, MergedHintBatch, PseudoTargetDiscovery,
    QHintBatch, ROBOT_ID_ALL, Register, RobotState, RobotStatus,
};
use bus::iceoryx2::prelude::*;
use bus::{
    BusConfig, BusError, CoordinatorBus, Expected, Inbox, Listing, Message, SendError, check_nodes,
    monotonic_ns,
};
use hdrhistogram::Histogram;
use planner::Cell;
use report::hist::{new_hist, record};
use report::{CoordinatorCheckpoint, RobotCheckpoint};

use crate::admission::{Roster, Sender, Verdict};
use crate::discovery::{Discoveries, Seen};
use crate::liveness::{Life, alive_in, robot_of_node};
use crate::options::CoordError;
use crate::validate::{self, Shape};
use contract::coordinator::MergeRule;
use sharing::FleetTable;

/// Messages taken from one inbox per drain, so periodic work still runs under a flood.
const DRAIN_MAX: usize = 256;

/// Latency histograms measured at the coordinator (one-way, robot → coordinator).
pub(crate) struct Hists {
    pub(crate) state: Histogram<u64>,
    pub(crate) discovery: Histogram<u64>,
    pub(crate) hints: Histogram<u64>,
    pub(crate) hint_age: Histogram<u64>,
    pub(crate) report: Histogram<u64>,
}

/// What the coordinator knows of one robot id in the current phase.
#[derive(Debug, Default, Clone, Copy)]
pub(crate) struct Slot {
    /// Admitted (by the handshake or later).
    pub(crate) accepted: bool,
    /// Episodes it registered with.
    pub(crate) episodes_total: u32,
    /// Its seed.
    pub(crate) seed: u64,
    /// Newest episode it announced.
    pub(crate) episode: u32,
    /// It announced `Finished`.
    pub(crate) finished: bool,
    /// Its process died.
    pub(crate) lost: bool,
    /// Its node was alive at the last listing.
    pub(crate) alive: bool,
    /// It died before it ever registered.
    pub(crate) never_registered: bool,
    /// Its validated final report of the phase.
    pub(crate) report: Option<FinalReport>,
    /// Distinct discoveries received from its processes that were lost without a report.
    pub(crate) disc_from_lost: u64,
}

/// Which goal a robot learns in the current phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Assignment {
    /// Goal id.
    pub(crate) goal: u32,
    /// Goal cell.
    pub(crate) cell: Cell,
    /// Phase number.
    pub(crate) phase: u32,
    /// Episodes of the phase (0: the robot's own `--episodes`).
    pub(crate) episodes: u32,
}

/// The shared coordinator state and its IO around the bus.
pub(crate) struct Engine {
    pub(crate) shape: Shape,
    /// The BFS optimum of each robot's task on this coordinator's map, `[robot][goal]`
    /// (empty: unknown); a report must agree with it (`validate::report`).
    pub(crate) optimum: Vec<Vec<u32>>,
    pub(crate) roster: Roster,
    pub(crate) robots: Vec<Slot>,
    pub(crate) tables: Vec<FleetTable>,
    /// Goals whose table changed since the driver last looked.
    pub(crate) touched: Vec<bool>,
    pub(crate) assignment: Vec<Assignment>,
    /// The command that started the current phase (`Start`, `Phase`); `None` before the start.
    pub(crate) go: Option<Command>,
    pub(crate) disc: Discoveries,
    pub(crate) life: Life,
    pub(crate) h: Hists,
    pub(crate) messages: u64,
    pub(crate) q_merged: u64,
    pub(crate) merged_seq: u64,
    pub(crate) merged_sent: u64,
    pub(crate) relays_sent: u64,
    pub(crate) rejected: u64,
    pub(crate) checks: u64,
    /// Coordinator processes that took over this run from a checkpoint before (and including)
    /// this one.
    pub(crate) coordinator_restarts: u32,
    /// CLOCK_MONOTONIC ns when the run's first coordinator started.
    pub(crate) began_ns: u64,
    /// CLOCK_MONOTONIC ns of the run's `Start` (a resumed run: the first coordinator's).
    pub(crate) started_ns: Option<u64>,
    /// A shared grid: where each robot must start (a robot registering elsewhere is refused).
    pub(crate) starts: Option<Vec<Cell>>,
    /// CLOCK_MONOTONIC ns when this coordinator began the current phase (sent its assignments;
    /// a restarted coordinator sends them again): a robot's early answer to the execution's
    /// first tick counts from then on.
    pub(crate) phase_ns: u64,
    /// Fleet-table changes counted by the coordinators before this one.
    changes_before: u64,
    merged_buffer: usize,
    /// Where the launcher leaves `robot-<id>.exited` for a robot process that ended.
    out: PathBuf,
    began: SystemTime,
    cleaner: Option<JoinHandle<()>>,
    /// Merged values go out as they change (true), or only as whole tables when the driver
    /// resends one (a lifelong run: every robot learns another goal, so a change of one goal's
    /// values is news to nobody, and 128 robots' changes broadcast to all would drown the
    /// whole-table warm starts in the robots' latest-wins buffers).
    pub(crate) live_merges: bool,
    /// Why the run must end now, if it must: a segment of the run whose pages `/dev/shm` could
    /// not reserve ([`bus::Listing::shm`]); the serving loops end as if interrupted.
    pub(crate) halt: Option<String>,
}

/// The node id of a sample's publisher.
fn sender<T: Message>(s: &bus::iceoryx2::sample::Sample<ipc::Service, T, ()>) -> Sender {
    s.header().node_id().value()
}

/// Takes up to `max` samples of `inbox`, handing each with its sender to `f`.
fn take<T: Message>(
    inbox: &Inbox<T>,
    max: usize,
    mut f: impl FnMut(&T, Sender) -> Result<(), CoordError>,
) -> Result<usize, CoordError> {
    let mut n = 0;
    while n < max {
        let Some(s) = inbox.receive_sample()? else {
            break;
        };
        f(s.payload(), sender(&s))?;
        n += 1;
    }
    Ok(n)
}

/// A lossless control send that timed out (a stopped robot does not drain) or reached nobody
/// (the robot died meanwhile) must not end the run: the liveness checks deal with that robot.
pub(crate) fn tolerate(r: Result<usize, BusError>) -> Result<(), CoordError> {
    match r {
        Ok(_) => Ok(()),
        Err(
            e @ BusError::Send(SendError::DeliveryTimeout { .. } | SendError::NoSubscriber { .. }),
        ) => {
            report::log_line!("qfleet-coordinator: warning: {e}");
            Ok(())
        }
        Err(e) => Err(e.into()),
    }
}

/// The launcher's note that robot `id`'s process ended (see `Engine::exited_early`).
pub fn exited_file(out: &std::path::Path, id: u32) -> PathBuf {
    out.join(format!("robot-{id}.exited"))
}

impl Engine {
    /// A fresh engine: no robot admitted, one table per goal of `shape`.
    pub(crate) fn new(
        expected: Expected,
        goals: u32,
        merge: MergeRule,
        life: Life,
        merged_buffer: usize,
        out: PathBuf,
    ) -> Self {
        let shape = Shape {
            width: expected.width,
            height: expected.height,
            goals,
        };
        let robots = expected.robots;
        Engine {
            shape,
            optimum: Vec::new(),
            roster: Roster::new(expected),
            robots: vec![Slot::default(); robots as usize],
            tables: (0..goals)
                .map(|_| FleetTable::lazy(shape.cells(), merge))
                .collect(),
            touched: vec![false; goals as usize],
            assignment: Vec::new(),
            go: None,
            phase_ns: 0,
            disc: Discoveries::new(robots),
            life,
            h: Hists {
                state: new_hist(),
                discovery: new_hist(),
                hints: new_hist(),
                hint_age: new_hist(),
                report: new_hist(),
            },
            messages: 0,
            q_merged: 0,
            merged_seq: 0,
            merged_sent: 0,
            relays_sent: 0,
            rejected: 0,
            checks: 0,
            coordinator_restarts: 0,
            began_ns: monotonic_ns(),
            started_ns: None,
            starts: None,
            changes_before: 0,
            merged_buffer,
            out,
            began: SystemTime::now(),
            cleaner: None,
            live_merges: true,
            halt: None,
        }
    }

    /// Whether the run must end now (see [`Engine::halt`]), checked with the stop flag.
    pub(crate) fn halted(&self) -> bool {
        self.halt.is_some()
    }

    /// Fleet-table entries changed by merging, over the run (coordinators before this one
    /// included).
    pub(crate) fn fleet_changes(&self) -> u64 {
        self.changes_before + self.tables.iter().map(|t| t.changes).sum::<u64>()
    }

    /// What a coordinator taking over this run needs (see [`report::checkpoint`]).
    pub(crate) fn checkpoint(&self, run_id: &str, complete: bool) -> CoordinatorCheckpoint {
        CoordinatorCheckpoint {
            run_id: run_id.to_string(),
            robots: self.robots.len() as u32,
            launcher_pid: std::os::unix::process::parent_id(),
            complete,
            coordinator_restarts: self.coordinator_restarts,
            began_ns: self.began_ns,
            started_ns: self.started_ns.unwrap_or(0),
            written_ns: monotonic_ns(),
            messages: self.messages,
            q_updates_merged: self.q_merged,
            fleet_changes: self.fleet_changes(),
            merged_batches_sent: self.merged_sent,
            merged_seq: self.merged_seq,
            relays_sent: self.relays_sent,
            rejected: self.rejected,
            checks: self.checks,
            discovery_duplicates: self.disc.duplicates(),
            discoveries_from_dead: self.disc.from_dead(),
            relayed: self.disc.relayed_pairs(),
            fleet: self
                .robots
                .iter()
                .enumerate()
                .map(|(id, r)| {
                    let (restarts, warm_started) = self.life.restarts(id);
                    RobotCheckpoint {
                        robot_id: id as u32,
                        lost: r.lost && r.report.is_none(),
                        restarts,
                        warm_started,
                        discoveries_from_lost: r.disc_from_lost,
                    }
                })
                .collect(),
            events: self.life.events().to_vec(),
        }
    }

    /// Takes over from the checkpoint of a coordinator of this run that died (the caller
    /// checked [`CoordinatorCheckpoint::resumable`]): its counters, its liveness record, the
    /// robots it had lost (not waited for again), the pairs it relayed; raises the
    /// `coordinatorrestarted` event. What it does not carry comes back from the robots: they
    /// re-register and replay their discovery logs, and their hints fill the fleet tables.
    pub(crate) fn resume(&mut self, cp: CoordinatorCheckpoint) {
        self.coordinator_restarts = cp.coordinator_restarts + 1;
        self.began_ns = cp.began_ns;
        self.started_ns = (cp.started_ns != 0).then_some(cp.started_ns);
        self.messages = cp.messages;
        self.q_merged = cp.q_updates_merged;
        self.changes_before = cp.fleet_changes;
        self.merged_sent = cp.merged_batches_sent;
        self.merged_seq = cp.merged_seq;
        self.relays_sent = cp.relays_sent;
        self.rejected = cp.rejected;
        self.checks = cp.checks;
        self.disc.resume(
            cp.discovery_duplicates,
            cp.discoveries_from_dead,
            &cp.relayed,
        );
        for r in &cp.fleet {
            if let Some(slot) = self.robots.get_mut(r.robot_id as usize) {
                slot.disc_from_lost = r.discoveries_from_lost;
                if r.lost {
                    slot.accepted = true;
                    slot.lost = true;
                }
            }
        }
        let silent_ms = monotonic_ns().saturating_sub(cp.written_ns) / 1_000_000;
        self.life.resume(cp.events, &cp.fleet, silent_ms);
        self.announce();
    }

    /// Prints the liveness events raised since the last call as `event <kind> <id> <ns>`.
    pub(crate) fn announce(&mut self) {
        use std::io::Write;
        let new = self.life.take_new();
        if new.is_empty() {
            return;
        }
        let mut out = std::io::stdout().lock();
        for ev in new {
            let _ = writeln!(
                out,
                "{}",
                contract::lines::event_line(ev.kind, ev.robot_id, ev.at_ns)
            );
        }
        let _ = out.flush();
    }

    /// Whether the launcher noted that robot `id`'s process ended during this coordinator's
    /// life (`robot-<id>.exited` in the out directory, newer than the coordinator).
    fn exited_early(&self, id: u32) -> bool {
        std::fs::metadata(exited_file(&self.out, id))
            .and_then(|m| m.modified())
            .is_ok_and(|t| t >= self.began)
    }

    /// The start handshake: admits registrations until every robot id is admitted or known
    /// dead before it registered (the launcher's `robot-<id>.exited`, or its node dead), so a
    /// robot killed during start-up does not stall the run; refuses mismatched ones (the run
    /// fails with [`CoordError::Refused`] half a second later, so the robot reads its answer).
    pub(crate) fn admit_fleet(
        &mut self,
        bus: &CoordinatorBus,
        stop: &AtomicBool,
        timeout: Duration,
    ) -> Result<(), CoordError> {
        let deadline = Instant::now() + timeout;
        let mut refused: Option<(u32, String, Instant)> = None;
        let mut last_look = Instant::now();
        loop {
            take(&bus.register, usize::MAX, |reg, from| {
                self.messages += 1;
                if let Verdict::Refuse(why) = self.on_register(bus, reg, from)? {
                    refused.get_or_insert((reg.robot_id, why, Instant::now()));
                }
                Ok(())
            })?;
            // not waited for: robots that died before they registered, or that a coordinator
            // this one took over from had lost
            let waiting: Vec<u32> = self
                .roster
                .missing()
                .into_iter()
                .filter(|&id| !self.robots[id as usize].lost)
                .collect();
            if waiting.is_empty() {
                break;
            }
            if let Some((robot_id, reason, at)) = &refused
                && at.elapsed() > Duration::from_millis(500)
            {
                return Err(CoordError::Refused {
                    robot_id: *robot_id,
                    reason: reason.clone(),
                });
            }
            if stop.load(Ordering::Relaxed) {
                return Err(CoordError::Interrupted("waiting for robots to register"));
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(BusError::Timeout {
                    what: format!("robots {waiting:?} to register"),
                    timeout,
                }
                .into());
            }
            if now.duration_since(last_look) >= Duration::from_millis(100) {
                last_look = now;
                self.notice_unregistered_deaths(bus, &waiting)?;
            }
            bus.register.wait(Duration::from_millis(20))?;
        }
        let now = Instant::now();
        for id in 0..self.robots.len() as u32 {
            if self.roster.is_member(id) {
                self.life.admitted(id, now);
            }
        }
        self.announce();
        if self.roster.members() == 0 {
            return Err(BusError::Timeout {
                what: "any robot to register (every robot process ended)".into(),
                timeout,
            }
            .into());
        }
        Ok(())
    }

    /// Robots not yet registered whose process is known to have ended: the launcher's note,
    /// or a dead node of theirs. They are reported lost (event `neverregistered`); a restart
    /// that registers later joins as usual.
    fn notice_unregistered_deaths(
        &mut self,
        bus: &CoordinatorBus,
        waiting: &[u32],
    ) -> Result<(), CoordError> {
        let nodes = check_nodes(bus.config(), false).ok();
        let now = Instant::now();
        for &id in waiting {
            let dead_node = nodes.as_ref().is_some_and(|r| {
                r.dead()
                    .any(|n| robot_of_node(&n.name) == Some(id as usize))
            });
            if dead_node || self.exited_early(id) {
                let slot = &mut self.robots[id as usize];
                slot.never_registered = true;
                slot.lost = true;
                self.life.never_registered(id, now);
                report::log_line!(
                    "qfleet-coordinator: robot {id} ended before it registered; going on without it"
                );
            }
        }
        self.announce();
        Ok(())
    }

    /// A `Register`: decided by the [`Roster`], carried out here. A robot admitted after the
    /// start gets its goal, the whole table of that goal (warm start) and the phase's start
    /// command.
    pub(crate) fn on_register(
        &mut self,
        bus: &CoordinatorBus,
        reg: &Register,
        from: Sender,
    ) -> Result<Verdict, CoordError> {
        let id = reg.robot_id;
        if let Some(want) = self.starts.as_ref().and_then(|s| s.get(id as usize))
            && (reg.start_x, reg.start_y) != (want.x, want.y)
        {
            let why = format!(
                "robot {id} starts at {},{} but the shared grid's instance puts it at {want}",
                reg.start_x, reg.start_y
            );
            self.rejected += 1;
            // a member of that id would read a Refuse as its own: a stranger's is dropped
            if self.roster.is_member(id) {
                report::log_line!("qfleet-coordinator: dropped a registration: {why}");
                return Ok(Verdict::Drop(why));
            }
            report::log_line!("qfleet-coordinator: refused robot {id}: {why}");
            tolerate(bus.refuse(id, &why))?;
            return Ok(Verdict::Refuse(why));
        }
        let cfg = bus.config().clone();
        let verdict = self.roster.on_register(reg, from, |pid| {
            // is the holder's process really still there? (clean it up if not, so its ports
            // are freed for the new one)
            check_nodes(&cfg, true).is_ok_and(|nodes| {
                nodes.alive().any(|n| {
                    robot_of_node(&n.name) == Some(id as usize) && n.pid == Some(pid as i32)
                })
            })
        });
        match &verdict {
            Verdict::Refuse(why) => {
                self.rejected += 1;
                report::log_line!("qfleet-coordinator: refused robot {id}: {why}");
                tolerate(bus.refuse(id, why))?;
            }
            Verdict::Drop(why) => {
                self.rejected += 1;
                report::log_line!(
                    "qfleet-coordinator: dropped a registration of robot {id}: {why}"
                );
            }
            Verdict::AckAgain => tolerate(bus.send_control(bus::control(Command::Ack, id)))?,
            Verdict::Joined | Verdict::Restarted => self.join(bus, reg, &verdict)?,
        }
        Ok(verdict)
    }

    fn join(
        &mut self,
        bus: &CoordinatorBus,
        reg: &Register,
        v: &Verdict,
    ) -> Result<(), CoordError> {
        let id = reg.robot_id;
        let restarted = *v == Verdict::Restarted;
        let old = self.robots[id as usize];
        if restarted {
            self.disc.restarted(id);
        }
        self.robots[id as usize] = Slot {
            accepted: true,
            alive: true,
            episodes_total: reg.episodes,
            seed: reg.seed,
            disc_from_lost: old.disc_from_lost,
            ..Slot::default()
        };
        bus.connect_all()?;
        tolerate(bus.send_control(bus::control(Command::Ack, id)))?;
        let Some(go) = self.go else {
            return Ok(()); // the start handshake: the driver starts everyone together
        };
        self.life
            .joined(id, restarted || old.never_registered, Instant::now());
        self.announce();
        report::log_line!(
            "qfleet-coordinator: robot {id} (pid {}) {} the run",
            reg.pid,
            if restarted {
                "restarted and rejoined"
            } else {
                "joined"
            }
        );
        let Some(a) = self.assignment.get(id as usize).copied() else {
            return Ok(());
        };
        tolerate(bus.send_control(assign(id, &a)))?;
        // warm start: the whole table of its goal, before its start command
        let batches = self.resend_table(bus, a.goal)?;
        self.life.warm_started(id, batches > 0);
        tolerate(bus.send_control(Control {
            phase: a.phase,
            episodes: a.episodes,
            ..bus::control(go, id)
        }))
    }

    /// Sends each robot its goal for the phase, then `go` to all.
    pub(crate) fn start_phase(
        &mut self,
        bus: &CoordinatorBus,
        assignment: Vec<Assignment>,
        go: Command,
    ) -> Result<(), CoordError> {
        self.assignment = assignment;
        self.phase_ns = monotonic_ns();
        for r in &mut self.robots {
            r.report = None;
            r.finished = false;
            r.episode = 0;
        }
        for (id, a) in self.assignment.iter().enumerate() {
            if self.robots[id].accepted && !self.robots[id].lost {
                tolerate(bus.send_control(assign(id as u32, a)))?;
            }
        }
        let a0 = self.assignment.first().copied();
        bus.send_control(Control {
            phase: a0.map_or(0, |a| a.phase),
            episodes: a0.map_or(0, |a| a.episodes),
            ..bus::control(go, ROBOT_ID_ALL)
        })?;
        self.go = Some(go);
        Ok(())
    }

    /// Takes what is waiting in every inbox (at most [`DRAIN_MAX`] per inbox), acks and relays
    /// discoveries, merges hints and sends the merged batches; returns the number of messages.
    pub(crate) fn drain(&mut self, bus: &CoordinatorBus) -> Result<usize, CoordError> {
        let mut n = take(&bus.register, DRAIN_MAX, |reg, from| {
            self.on_register(bus, reg, from).map(drop)
        })?;
        n += take(&bus.state, DRAIN_MAX, |s, from| {
            self.on_state(s, from);
            Ok(())
        })?;
        n += take(&bus.discovery, DRAIN_MAX, |d, from| {
            self.on_discovery(d, from);
            Ok(())
        })?;
        self.send_acks(bus)?;
        self.send_relays(bus)?;
        n += take(&bus.hints, DRAIN_MAX, |b, from| self.on_hints(bus, b, from))?;
        if self.live_merges {
            for g in 0..self.tables.len() {
                self.flush(bus, g as u32)?;
            }
        }
        n += take(&bus.report, DRAIN_MAX, |r, from| {
            self.on_report(r, from);
            Ok(())
        })?;
        self.messages += n as u64;
        self.announce();
        Ok(n)
    }

    /// A message for `robot_id` from node `from`: a member's, from its own node?
    pub(crate) fn trusted(&mut self, robot_id: u32, from: Sender) -> Option<&mut Slot> {
        if self.roster.check_sender(robot_id, from).is_err() {
            self.rejected += 1;
            return None;
        }
        self.life.seen(robot_id, Instant::now());
        self.robots.get_mut(robot_id as usize)
    }

    fn assigned(&self, robot_id: u32) -> Option<u32> {
        self.assignment.get(robot_id as usize).map(|a| a.goal)
    }

    fn on_state(&mut self, s: &RobotState, from: Sender) {
        let now = monotonic_ns();
        if validate::state(s, &self.shape, None).is_err() {
            self.rejected += 1;
            return;
        }
        let Some(slot) = self.trusted(s.robot_id, from) else {
            return;
        };
        slot.episode = slot.episode.max(s.episode);
        if s.status == RobotStatus::Finished.as_u8() {
            slot.finished = true;
        }
        if s.send_time_ns != 0 && s.send_time_ns <= now {
            record(&mut self.h.state, now - s.send_time_ns);
        }
    }

    fn on_discovery(&mut self, d: &PseudoTargetDiscovery, from: Sender) {
        let now = monotonic_ns();
        let Ok(cell) = validate::discovery(d, &self.shape, None) else {
            self.rejected += 1;
            return;
        };
        if self.trusted(d.robot_id, from).is_none() {
            return;
        }
        if let Seen::New { .. } = self.disc.on(d, cell)
            && d.send_time_ns != 0
            && d.send_time_ns <= now
        {
            record(&mut self.h.discovery, now - d.send_time_ns);
        }
    }

    fn send_acks(&mut self, bus: &CoordinatorBus) -> Result<(), CoordError> {
        for (robot_id, up_to_seq) in self.disc.take_acks() {
            bus.ack.send(&DiscoveryAck {
                robot_id,
                up_to_seq,
                time_ns: monotonic_ns(),
                ..DiscoveryAck::ZEROED
            })?;
        }
        Ok(())
    }

    /// Relays new distinct discoveries to every robot (lossless; a fleet that already left
    /// is nobody to tell, which is not an error).
    fn send_relays(&mut self, bus: &CoordinatorBus) -> Result<(), CoordError> {
        let relays = self.disc.take_relays();
        if relays.is_empty() {
            return Ok(());
        }
        for mut r in relays {
            r.relay_seq = self.relays_sent;
            r.send_time_ns = monotonic_ns();
            match bus.relay.send(&r) {
                Ok(_) | Err(SendError::NoSubscriber { .. }) => self.relays_sent += 1,
                Err(e) => return Err(e.into()),
            }
        }
        bus.relay.notify()?;
        Ok(())
    }

    fn on_hints(
        &mut self,
        bus: &CoordinatorBus,
        b: &QHintBatch,
        from: Sender,
    ) -> Result<(), CoordError> {
        let now = monotonic_ns();
        let Ok(entries) = validate::hint_batch(b, &self.shape, None) else {
            self.rejected += 1;
            return Ok(());
        };
        if self.trusted(b.robot_id, from).is_none() {
            return Ok(());
        }
        if b.send_time_ns != 0 && b.send_time_ns <= now {
            record(&mut self.h.hints, now - b.send_time_ns);
        }
        if b.oldest_update_ns != 0 && b.oldest_update_ns <= now {
            record(&mut self.h.hint_age, now - b.oldest_update_ns);
        }
        let g = b.goal_id;
        self.tables[g as usize].reserve();
        let cells = self.shape.cells();
        for h in entries {
            if validate::hint(h, cells).is_err() {
                self.rejected += 1;
                continue;
            }
            self.q_merged += 1;
            self.touched[g as usize] = true;
            if self.tables[g as usize].merge(b.robot_id, h, b.oldest_update_ns) {
                if self.live_merges {
                    self.flush(bus, g)?;
                } else {
                    self.tables[g as usize].drop_pending();
                }
            }
        }
        Ok(())
    }

    /// Sends goal `g`'s pending merged batch, if any (only what it holds is written).
    pub(crate) fn flush(&mut self, bus: &CoordinatorBus, g: u32) -> Result<(), CoordError> {
        let table = &mut self.tables[g as usize];
        if table.pending() == 0 {
            return Ok(());
        }
        let seq = self.merged_seq;
        bus.merged.send_batch(|m| {
            table.take_into(m);
            m.coordinator_seq = seq;
            m.goal_id = g;
            m.send_time_ns = monotonic_ns();
        })?;
        self.merged_seq += 1;
        self.merged_sent += 1;
        Ok(())
    }

    /// Sends goal `g`'s whole fleet table (after whatever is pending) as merged batches to
    /// every robot, pacing rounds of half a merged buffer so the robots' latest-wins buffers
    /// keep up (not in a lifelong run, between ticks); returns the batches sent.
    pub(crate) fn resend_table(&mut self, bus: &CoordinatorBus, g: u32) -> Result<u64, CoordError> {
        self.flush(bus, g)?;
        // a lifelong run's warm starts go out between ticks: no pause there (no tick waits)
        let live = self.live_merges;
        let round = (self.merged_buffer / 2).max(1);
        let mut in_round = 0;
        let mut err = None;
        let mut seq = self.merged_seq;
        let mut sent = 0;
        self.tables[g as usize].resend_all(|t| {
            if err.is_some() {
                let mut sink = MergedHintBatch::ZEROED;
                t.take_into(&mut sink);
                return;
            }
            if let Err(e) = bus.merged.send_batch(|m| {
                t.take_into(m);
                m.coordinator_seq = seq;
                m.goal_id = g;
                m.send_time_ns = monotonic_ns();
            }) {
                err = Some(e);
            }
            seq += 1;
            sent += 1;
            in_round += 1;
            if in_round >= round && live {
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

    fn on_report(&mut self, r: &FinalReport, from: Sender) {
        let now = monotonic_ns();
        let assigned = self.assigned(r.robot_id);
        let max_episodes = match self.assignment.get(r.robot_id as usize) {
            Some(a) if a.episodes > 0 => a.episodes,
            _ => self
                .robots
                .get(r.robot_id as usize)
                .map_or(0, |s| s.episodes_total),
        };
        let optimum = self
            .optimum
            .get(r.robot_id as usize)
            .and_then(|g| g.get(r.goal_id as usize))
            .copied();
        if let Err(why) = validate::report(r, &self.shape, assigned, max_episodes, optimum) {
            self.rejected += 1;
            report::log_line!(
                "qfleet-coordinator: rejected a report for robot {}: {why}",
                r.robot_id
            );
            return;
        }
        let Some(slot) = self.trusted(r.robot_id, from) else {
            report::log_line!(
                "qfleet-coordinator: rejected a report for robot {} from a node that did not \
                 register it",
                r.robot_id
            );
            return;
        };
        // a robot that computes no optimum (-1) is judged against ours: the result shows ours
        let mut kept = *r;
        if let (-1, Some(o)) = (kept.optimal_path_len, optimum) {
            kept.optimal_path_len = i32::try_from(o).unwrap_or(-1);
        }
        slot.report = Some(kept);
        if r.send_time_ns != 0 && r.send_time_ns <= now {
            record(&mut self.h.report, now - r.send_time_ns);
        }
    }

    /// Removes dead nodes' resources on a background thread, one cleanup at a time (it takes
    /// a few hundred ms and must not stall the loop).
    fn clean_dead(&mut self, cfg: &BusConfig) {
        if self.cleaner.as_ref().is_some_and(|h| !h.is_finished()) {
            return;
        }
        if let Some(h) = self.cleaner.take() {
            let _ = h.join();
        }
        let cfg = cfg.clone();
        self.cleaner = Some(std::thread::spawn(move || {
            if let Err(e) = check_nodes(&cfg, true) {
                report::log_line!("qfleet-coordinator: warning: cleaning up dead nodes: {e}");
            }
        }));
    }

    /// Takes a node listing of the `Lister` thread: losses, cleanup of dead nodes (in the
    /// background), heartbeat deadlines.
    pub(crate) fn liveness(
        &mut self,
        bus: &CoordinatorBus,
        listing: Listing,
    ) -> Result<(), CoordError> {
        let listed_at = listing.at;
        if let Some(e) = listing.shm
            && self.halt.is_none()
        {
            report::log_line!(
                "qfleet-coordinator: ending the run with the results it has (a process touching \
                 that segment would die of SIGBUS): {e}"
            );
            self.halt = Some(e.to_string());
        }
        let report = listing.report?;
        if report.dead().next().is_some() {
            self.clean_dead(bus.config());
        }
        self.checks += 1;
        // None: the listing proves no death (an unreadable node may be any robot's)
        let alive = alive_in(&report, self.robots.len());
        // a report that arrived before the process went away is not a loss
        self.drain(bus)?;
        let now = Instant::now();
        for (id, slot) in self.robots.iter_mut().enumerate() {
            if self.life.joined_since(id, listed_at) {
                continue; // a new process that registered after the listing
            }
            let Some(alive) = &alive else { continue };
            slot.alive = alive[id];
            if slot.accepted && !alive[id] && slot.report.is_none() && !slot.lost {
                slot.lost = true;
                slot.disc_from_lost += self.disc.received_from(id as u32);
                self.roster.lost(id as u32);
                self.life.lost(id as u32, now);
                report::log_line!(
                    "qfleet-coordinator: robot {id} is gone (its process died) without a final report"
                );
            }
        }
        // messages still waiting: a silence may be our own backlog, not a hung robot
        if !bus.has_samples()? {
            let robots = &self.robots;
            for id in self.life.deadlines(now, |i| {
                let s = &robots[i];
                s.accepted && !s.lost && !s.finished && s.report.is_none()
            }) {
                report::log_line!(
                    "qfleet-coordinator: robot {id} is hung: nothing from it in time"
                );
            }
        }
        self.announce();
        Ok(())
    }

    /// Whether robot `id` no longer holds up the phase: reported, finished, settled (lost
    /// without a restart to wait for, or hung), or never admitted.
    pub(crate) fn done(&self, id: usize, now: Instant) -> bool {
        let r = &self.robots[id];
        r.finished || r.report.is_some() || !r.accepted || self.life.settled(id, r.lost, now)
    }

    /// Whether robot `id` has nothing more to send this phase: its report is in, or it is
    /// settled (lost with no restart to wait for, or hung), or it was never admitted.
    pub(crate) fn phase_done(&self, id: usize, now: Instant) -> bool {
        let r = &self.robots[id];
        r.report.is_some() || !r.accepted || self.life.settled(id, r.lost, now)
    }

    /// After `Stop`: whether robot `id` can send nothing more (its report is in, or it is
    /// lost, hung, or never admitted).
    pub(crate) fn reported(&self, id: usize) -> bool {
        let r = &self.robots[id];
        r.report.is_some() || !r.accepted || r.lost || self.life.is_hung(id)
    }
}

/// The `AssignGoal` control for robot `id`.
fn assign(id: u32, a: &Assignment) -> Control {
    Control {
        goal_id: a.goal,
        goal_x: a.cell.x,
        goal_y: a.cell.y,
        phase: a.phase,
        episodes: a.episodes,
        ..bus::control(Command::AssignGoal, id)
    }
}
