//! The coordinator's run: create the run's services, admit the fleet, start it, receive and
//! merge until every robot finished, resend the fleet table, stop the robots, collect their
//! reports, write the result.
//!
//! # Wait strategies
//! - `spin`: poll every inbox in a tight loop (lowest latency, one core busy all the time).
//! - `event`: block on an iceoryx2 `WaitSet` over the inboxes' wake listeners (robots notify
//!   after each hint batch, discovery, report and their final state); no core burnt while idle,
//!   but every wakeup costs a cross-CPU wakeup (tens of µs on a VM).
//! - `hybrid` (default): after any message, keep spinning for `--spin-us`, then block like
//!   `event`. Bursts are served at spin latency, idle time costs nothing.
//!
//! All three also wake every 50 ms for the periodic work: progress lines, the end-of-run check.
//! Liveness (iceoryx2 node states) is listed every 100 ms on a thread of its own
//! (`watch::Lister`); the loop only takes the newest listing from a channel.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::bus_schema::{
    Command, Control, DiscoveryAck, FinalReport, HINT_BATCH_CAP, QHintBatch, ROBOT_ID_ALL,
    Register, RobotState, RobotStatus,
};
use bus::iceoryx2::prelude::*;
use bus::{Admission, BusConfig, BusError, CoordinatorBus, Expected, monotonic_ns};
use bus_schema::map_fingerprint;
use clap::{Args, ValueEnum};
use hdrhistogram::Histogram;
use planner::task::Task;
use qfleet_args::MapArgs;
use report::hist::{self, LatencyStats, new_hist, record};
use serde::{Deserialize, Serialize};

use crate::merge::{FleetTable, MergeRule};

mod watch;
pub use watch::LivenessEvent;

/// How the coordinator waits for messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WaitStrategy {
    /// Busy-poll all inboxes.
    Spin,
    /// Block on a WaitSet of the inboxes' wake listeners.
    Event,
    /// Spin `--spin-us` after each message, then block.
    Hybrid,
}

impl std::fmt::Display for WaitStrategy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            WaitStrategy::Spin => "spin",
            WaitStrategy::Event => "event",
            WaitStrategy::Hybrid => "hybrid",
        })
    }
}

/// Every option of the coordinator process.
#[derive(Debug, Clone, Args)]
pub struct CoordArgs {
    /// Run id shared by all processes of the run.
    #[arg(long)]
    pub run_id: String,
    /// Fleet size: robot ids `0..robots`.
    #[arg(long, default_value_t = 4)]
    pub robots: u32,
    /// Map and goal of the run (robots on another map are refused).
    #[command(flatten)]
    pub map: MapArgs,
    /// How to wait for messages.
    #[arg(long, value_enum, default_value_t = WaitStrategy::Hybrid)]
    pub wait: WaitStrategy,
    /// Hybrid: microseconds to keep spinning after the last message before blocking.
    #[arg(long, default_value_t = 200)]
    pub spin_us: u64,
    /// How Q hints are merged into the fleet table.
    #[arg(long, value_enum, default_value_t = MergeRule::Max)]
    pub merge: MergeRule,
    /// Directory for result.json and the .hgrm latency files.
    #[arg(long)]
    pub out: PathBuf,
    /// Seconds to wait for every robot to register, and for reports after `Stop`.
    #[arg(long, default_value_t = 30.0)]
    pub timeout: f64,
    /// Print `progress <episodes done> <total> <p50 ns> <p99 ns>` lines on stdout every 100 ms.
    #[arg(long)]
    pub progress: bool,
    /// Hint batches buffered per robot (latest-wins).
    #[arg(long, default_value_t = 64)]
    pub hint_buffer: usize,
    /// Merged batches buffered per robot (latest-wins); 0 = sized from the fleet.
    #[arg(long, default_value_t = 0)]
    pub merged_buffer: usize,
    /// Heartbeat deadline: a running robot silent this long (ms) is reported hung.
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u64).range(1..))]
    pub hang_ms: u64,
    /// Restarts per robot the launcher may make: the end of the run waits (up to `--timeout`)
    /// for a lost robot to come back while it has restarts left.
    #[arg(long, default_value_t = 0)]
    pub restarts: u32,
}

/// Why the coordinator failed.
#[derive(Debug, thiserror::Error)]
pub enum CoordError {
    /// A bad option or map.
    #[error("{0}")]
    Input(String),
    /// A robot was refused at registration (the run cannot go on as asked).
    #[error("refused robot {robot_id}: {reason}")]
    Refused {
        /// The robot.
        robot_id: u32,
        /// Why.
        reason: String,
    },
    /// A bus failure.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// Writing the result failed.
    #[error("writing the result: {0}")]
    Output(String),
}

/// One robot in the run result.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RobotEntry {
    /// Robot id.
    pub robot_id: u32,
    /// `finished`, `stopped` (stopped early), `lost` (its process died) or `missing` (no report).
    pub status: String,
    /// Greedy path length at the end (null: loops / unknown).
    pub final_path_len: Option<u32>,
    /// Greedy path length from the robot's own learning, before the final fleet sync.
    pub own_final_path_len: Option<u32>,
    /// BFS optimum.
    pub optimal_path_len: Option<u32>,
    /// Mean steps per episode.
    pub avg_steps: f64,
    /// Episodes run.
    pub episodes: u32,
    /// First episode with an optimal greedy path.
    pub first_optimal_episode: Option<u32>,
    /// Steps taken.
    pub env_steps: u64,
    /// Seed of the robot.
    pub seed: u64,
    /// Discoveries the robot published.
    pub discoveries_sent: u64,
    /// Of those, acknowledged by the coordinator.
    pub discoveries_acked: u64,
    /// Hint batches published.
    pub hints_sent: u64,
    /// Merged batches received.
    pub hints_received: u64,
    /// Merged entries that changed its Q-table.
    pub hints_applied: u64,
    /// End-to-end loop latency of the hints it applied.
    pub loop_latency_ns: LatencyStats,
    /// Times a new process took this robot's place (`qfleet run --restart on-failure`).
    #[serde(default)]
    pub restarts: u32,
    /// Whether its latest process was warm-started from the coordinator's fleet table.
    #[serde(default)]
    pub warm_started: bool,
    /// Fleet-table entries its latest process applied before its first episode.
    #[serde(default)]
    pub warm_start_entries: Option<u64>,
}

/// Throughput of the run, over the active time (Start → every robot finished).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Throughput {
    /// Messages received per second (all robot→coordinator topics).
    pub messages_per_s: f64,
    /// Q-hint entries merged per second.
    pub q_updates_merged_per_s: f64,
    /// Messages received.
    pub messages: u64,
    /// Q-hint entries merged.
    pub q_updates_merged: u64,
    /// Fleet-table entries changed by merging.
    pub fleet_changes: u64,
    /// Merged batches published.
    pub merged_batches_sent: u64,
    /// Seconds from Start until every robot finished.
    pub active_s: f64,
}

/// Node liveness as the coordinator saw it.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct LivenessReport {
    /// Liveness checks made.
    pub checks: u64,
    /// Robots whose process died before reporting.
    pub lost: Vec<u32>,
    /// Robot nodes alive at the last check.
    pub alive_at_end: Vec<u32>,
    /// Robots hung at the end (silent past the heartbeat deadline, process still there).
    #[serde(default)]
    pub hung: Vec<u32>,
    /// Restarts over the fleet.
    #[serde(default)]
    pub restarts: u32,
    /// Discoveries received from robot processes that died and were restarted (their
    /// successors start numbering again and report only their own).
    #[serde(default)]
    pub discoveries_from_dead: u64,
    /// Every liveness event, in order.
    #[serde(default)]
    pub events: Vec<LivenessEvent>,
}

/// The result of a run (`result.json`, and what `qfleet run --json` prints).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunResult {
    /// Run id.
    pub run_id: String,
    /// Map name.
    pub map: String,
    /// Start cell.
    pub start: String,
    /// Goal cell.
    pub goal: String,
    /// Wait strategy.
    pub wait: WaitStrategy,
    /// Merge rule.
    pub merge: MergeRule,
    /// One entry per robot id.
    pub robots: Vec<RobotEntry>,
    /// Whether every robot ended on a shortest path.
    pub all_optimal: bool,
    /// Discoveries the robots report as published.
    pub discoveries_sent: u64,
    /// Distinct discoveries the coordinator received.
    pub discoveries_received: u64,
    /// Discovery duplicates (re-sends) received and dropped.
    pub discovery_duplicates: u64,
    /// Distinct pseudo-target cells the fleet found.
    pub pseudo_targets: usize,
    /// Latency percentiles per measured path, ns.
    pub latency_ns: BTreeMap<String, LatencyStats>,
    /// Throughput.
    pub throughput: Throughput,
    /// Liveness.
    pub liveness: LivenessReport,
    /// Messages dropped as invalid (robot id, goal id, cell, count out of range).
    pub rejected: u64,
    /// Whether the run was stopped early by a signal.
    pub interrupted: bool,
    /// Wall time of the whole coordinator run, s.
    pub elapsed_s: f64,
}

/// Latency histograms measured at the coordinator.
struct Hists {
    state: Histogram<u64>,
    discovery: Histogram<u64>,
    hints: Histogram<u64>,
    hint_age: Histogram<u64>,
    report: Histogram<u64>,
}

#[derive(Default, Clone, Copy)]
struct RobotSlot {
    accepted: bool,
    episodes_total: u32,
    seed: u64,
    episode: u32,
    finished: bool,
    lost: bool,
    alive: bool,
    report: Option<FinalReport>,
    next_disc: u64,
    ack_dirty: bool,
}

struct Coord {
    args: CoordArgs,
    task: Task,
    robots: Vec<RobotSlot>,
    table: FleetTable,
    merged_seq: u64,
    h: Hists,
    messages: u64,
    q_merged: u64,
    merged_sent: u64,
    disc_received: u64,
    disc_dup: u64,
    pseudo: BTreeSet<u32>,
    rejected: u64,
    checks: u64,
    out_of_order: BTreeMap<u32, BTreeSet<u64>>,
    /// New distinct discoveries waiting to be relayed to every robot.
    relay_pending: Vec<bus::bus_schema::DiscoveryRelay>,
    relays_sent: u64,
    /// Heartbeat deadlines, losses, restarts (see `watch`).
    life: watch::Life,
}

fn secs(s: f64, what: &str) -> Result<Duration, CoordError> {
    Duration::try_from_secs_f64(s)
        .ok()
        .filter(|d| !d.is_zero())
        .ok_or_else(|| {
            CoordError::Input(format!(
                "{what} must be a positive number of seconds, got {s}"
            ))
        })
}

/// Runs the coordinator of one run; `stop` is set by a signal handler (graceful stop: robots
/// are told to stop, their reports collected and a partial result written).
pub fn run(args: CoordArgs, stop: Arc<AtomicBool>) -> Result<RunResult, CoordError> {
    let t_begin = Instant::now();
    let timeout = secs(args.timeout, "--timeout")?;
    let task = args
        .map
        .task()
        .map_err(|e| CoordError::Input(e.to_string()))?;
    let cells = task.grid.len();
    let (Ok(width), Ok(height)) = (
        u16::try_from(task.grid.width()),
        u16::try_from(task.grid.height()),
    ) else {
        return Err(CoordError::Input(
            "maps larger than 65535 cells a side are not supported".into(),
        ));
    };
    let mut cfg = BusConfig::new(args.run_id.clone(), args.robots)?;
    cfg.hint_buffer = args.hint_buffer;
    cfg.merged_buffer = if args.merged_buffer == 0 {
        (4096 / args.robots as usize).clamp(8, 64)
    } else {
        args.merged_buffer
    };
    // control is the coordinator's only lossless output; a robot that stopped draining it
    // (SIGSTOP, or killed and not cleaned up yet) must not stall the whole run for long
    cfg.send_timeout = Duration::from_secs(1);
    cfg.validate()?;
    std::fs::create_dir_all(&args.out)
        .map_err(|e| CoordError::Output(format!("{}: {e}", args.out.display())))?;
    let expected = Expected {
        robots: args.robots,
        map_hash: map_fingerprint(
            task.grid.width(),
            task.grid.height(),
            task.grid.free_flags(),
        ),
        width,
        height,
    };
    let bus = CoordinatorBus::create(&cfg)?;
    let mut c = Coord {
        robots: vec![RobotSlot::default(); args.robots as usize],
        table: FleetTable::new(cells, args.merge),
        merged_seq: 0,
        h: Hists {
            state: new_hist(),
            discovery: new_hist(),
            hints: new_hist(),
            hint_age: new_hist(),
            report: new_hist(),
        },
        messages: 0,
        q_merged: 0,
        merged_sent: 0,
        disc_received: 0,
        disc_dup: 0,
        pseudo: BTreeSet::new(),
        rejected: 0,
        checks: 0,
        out_of_order: BTreeMap::new(),
        relay_pending: Vec::new(),
        relays_sent: 0,
        life: watch::Life::new(
            expected,
            Duration::from_millis(args.hang_ms),
            args.restarts,
            timeout,
            cfg.merged_buffer,
        ),
        task,
        args,
    };
    let outcome = c.drive(&bus, &expected, &stop, timeout);
    let result = match outcome {
        Ok((active, interrupted)) => {
            let r = c.result(active, interrupted, t_begin.elapsed().as_secs_f64());
            c.write(&r).map(|_| r)
        }
        Err(e) => Err(e),
    };
    // the last process of the run removes its files; errors here must not hide the result
    if let Err(e) = bus.close() {
        eprintln!("qfleet-coordinator: warning: cleanup: {e}");
    }
    result
}

impl Coord {
    fn drive(
        &mut self,
        bus: &CoordinatorBus,
        expected: &Expected,
        stop: &AtomicBool,
        timeout: Duration,
    ) -> Result<(f64, bool), CoordError> {
        self.admit_fleet(bus, expected, stop, timeout)?;
        let lister = watch::Lister::start(bus.config(), Duration::from_millis(100))?;
        let goal = self.task.goal;
        bus.send_control(Control {
            goal_id: 0,
            goal_x: goal.x,
            goal_y: goal.y,
            ..bus::control(Command::AssignGoal, ROBOT_ID_ALL)
        })?;
        bus.start(ROBOT_ID_ALL, 0)?;
        let t_start = Instant::now();
        let interrupted = self.main_loop(bus, &lister, stop)?;
        let active = t_start.elapsed().as_secs_f64();
        // every robot is done learning (or lost): hand out the whole fleet table, then Stop
        if !interrupted && self.args.robots > 1 {
            self.resend_table(bus)?;
        } else {
            self.flush_merged(bus)?;
        }
        // a hung robot that does not drain its control buffer must not fail the run
        watch::tolerate(bus.stop(ROBOT_ID_ALL).map(drop))?;
        self.collect_reports(bus, &lister, timeout)?;
        Ok((active, interrupted))
    }

    fn admit_fleet(
        &mut self,
        bus: &CoordinatorBus,
        expected: &Expected,
        stop: &AtomicBool,
        timeout: Duration,
    ) -> Result<(), CoordError> {
        let deadline = Instant::now() + timeout;
        let mut accepted: BTreeMap<u32, Register> = BTreeMap::new();
        let mut refused: Option<(u32, String, Instant)> = None;
        while (accepted.len() as u32) < self.args.robots {
            while let Some(reg) = bus.register.receive()? {
                self.messages += 1;
                if let Admission::Refused(why) = bus.admit(&reg, expected, &mut accepted)? {
                    eprintln!("qfleet-coordinator: refused robot {}: {why}", reg.robot_id);
                    refused.get_or_insert((reg.robot_id, why, Instant::now()));
                }
            }
            if let Some((robot_id, reason, at)) = &refused {
                // give the refused robot a moment to read its answer, then fail the run
                if at.elapsed() > Duration::from_millis(500) {
                    return Err(CoordError::Refused {
                        robot_id: *robot_id,
                        reason: reason.clone(),
                    });
                }
            }
            if stop.load(Ordering::Relaxed) {
                return Err(CoordError::Input(
                    "interrupted while waiting for robots to register".into(),
                ));
            }
            if Instant::now() >= deadline {
                let missing: Vec<u32> = (0..self.args.robots)
                    .filter(|r| !accepted.contains_key(r))
                    .collect();
                return Err(BusError::Timeout {
                    what: format!("robots {missing:?} to register"),
                    timeout,
                }
                .into());
            }
            bus.register.wait(Duration::from_millis(20))?;
        }
        for (id, reg) in accepted {
            let slot = &mut self.robots[id as usize];
            slot.accepted = true;
            slot.alive = true;
            slot.episodes_total = reg.episodes;
            slot.seed = reg.seed;
            self.life.admitted(&reg);
        }
        Ok(())
    }

    /// Receives and merges until every robot finished or was lost; true if stopped by a signal.
    fn main_loop(
        &mut self,
        bus: &CoordinatorBus,
        lister: &watch::Lister,
        stop: &AtomicBool,
    ) -> Result<bool, CoordError> {
        let strategy = self.args.wait;
        let waitset = match strategy {
            WaitStrategy::Spin => None,
            _ => Some(
                // iceoryx2's own SIGINT/SIGTERM handler would replace the process's (ctrlc) one
                // and swallow the stop request: keep it off
                WaitSetBuilder::new()
                    .signal_handling_mode(SignalHandlingMode::Disabled)
                    .create::<ipc::Service>()
                    .map_err(|e| BusError::Event {
                        service: "WaitSet".into(),
                        detail: format!("{e:?}"),
                    })?,
            ),
        };
        let guards = match &waitset {
            Some(ws) => bus.attach_all(ws)?,
            None => Vec::new(),
        };
        let inboxes_wake = |i: usize| -> Result<bus::Wakeups, BusError> {
            match i {
                0 => bus.register.clear_wakeups(),
                1 => bus.state.clear_wakeups(),
                2 => bus.discovery.clear_wakeups(),
                3 => bus.hints.clear_wakeups(),
                _ => bus.report.clear_wakeups(),
            }
        };
        let spin_for = Duration::from_micros(self.args.spin_us);
        let mut last_activity = Instant::now();
        let mut last_periodic = Instant::now();
        let mut peer_dead = false;
        let mut iter: u32 = 0;
        loop {
            let n = self.drain(bus)?;
            iter = iter.wrapping_add(1);
            let check_clock = n > 0 || strategy != WaitStrategy::Spin || iter.is_multiple_of(64);
            if !check_clock {
                std::hint::spin_loop();
                continue;
            }
            if let Some(listing) = lister.poll() {
                self.liveness(bus, listing)?;
            }
            let now = Instant::now();
            if n > 0 {
                last_activity = now;
            }
            if now.duration_since(last_periodic) >= Duration::from_millis(50) || peer_dead {
                last_periodic = now;
                if std::mem::take(&mut peer_dead) {
                    lister.now();
                }
                self.progress();
                if stop.load(Ordering::Relaxed) {
                    return Ok(true);
                }
                if self.all_done() {
                    // take in whatever arrived meanwhile
                    self.drain(bus)?;
                    return Ok(false);
                }
            }
            if n > 0 {
                continue;
            }
            let block = match strategy {
                WaitStrategy::Spin => false,
                WaitStrategy::Event => true,
                WaitStrategy::Hybrid => now.duration_since(last_activity) >= spin_for,
            };
            if !block {
                std::hint::spin_loop();
                continue;
            }
            if let Some(ws) = &waitset {
                let mut err = None;
                let res = ws.wait_and_process_once_with_timeout(
                    |id| {
                        for (i, g) in guards.iter().enumerate() {
                            if id.has_event_from(g) {
                                match inboxes_wake(i) {
                                    Ok(w) => peer_dead |= w.peer_dead,
                                    Err(e) => err = Some(e),
                                }
                            }
                        }
                        CallbackProgression::Continue
                    },
                    Duration::from_millis(50),
                );
                if let Some(e) = err {
                    return Err(e.into());
                }
                if let Err(e) = res {
                    return Err(BusError::Event {
                        service: "WaitSet".into(),
                        detail: format!("{e:?}"),
                    }
                    .into());
                }
            }
        }
    }

    fn all_done(&self) -> bool {
        self.robots.iter().enumerate().all(|(i, r)| {
            r.finished || r.report.is_some() || self.life.settled(i, r.lost) || !r.accepted
        })
    }

    fn robot(&mut self, id: u32) -> Option<&mut RobotSlot> {
        let slot = self.robots.get_mut(id as usize).filter(|r| r.accepted)?;
        self.life.seen(id);
        Some(slot)
    }

    /// Takes what is waiting in every inbox, at most `DRAIN_MAX` per inbox so the periodic work
    /// (liveness, stop requests) still runs under a flood; returns the number of messages.
    fn drain(&mut self, bus: &CoordinatorBus) -> Result<usize, CoordError> {
        const DRAIN_MAX: usize = 256;
        let mut n = 0;
        // late or repeated registrations: a robot that missed its Ack, a restarted robot
        // process, a running robot re-joining a restarted coordinator (see `watch`)
        while let Some(reg) = bus.register.receive()? {
            n += 1;
            self.on_register(bus, &reg)?;
        }
        n += bus.state.drain(DRAIN_MAX, |s| self.on_state(s))?;
        let mut acks = false;
        n += bus
            .discovery
            .drain(DRAIN_MAX, |d| acks |= self.on_discovery(d))?;
        if acks {
            self.send_acks(bus)?;
        }
        self.send_relays(bus)?;
        for _ in 0..DRAIN_MAX {
            let Some(sample) = bus.hints.receive_sample()? else {
                break;
            };
            n += 1;
            self.on_hints(bus, sample.payload())?;
        }
        if self.table.pending() > 0 {
            self.flush_merged(bus)?;
        }
        while let Some(r) = bus.report.receive()? {
            n += 1;
            self.on_report(&r);
        }
        self.messages += n as u64;
        Ok(n)
    }

    fn on_state(&mut self, s: &RobotState) {
        let now = monotonic_ns();
        let Some(slot) = self.robot(s.robot_id) else {
            self.rejected += 1;
            return;
        };
        if s.goal_id != 0 {
            self.rejected += 1;
            return;
        }
        slot.episode = slot.episode.max(s.episode);
        if s.status == RobotStatus::Finished.as_u8() {
            slot.finished = true;
        }
        if s.send_time_ns != 0 && s.send_time_ns <= now {
            record(&mut self.h.state, now - s.send_time_ns);
        }
    }

    /// Records a discovery; true when an ack must go out.
    fn on_discovery(&mut self, d: &bus::bus_schema::PseudoTargetDiscovery) -> bool {
        let now = monotonic_ns();
        let cell_ok = (d.cell_x as usize) < self.task.grid.width()
            && (d.cell_y as usize) < self.task.grid.height();
        if d.goal_id != 0 || !cell_ok || !d.value.is_finite() {
            self.rejected += 1;
            return false;
        }
        let cell = self.task.grid.index(planner::Cell::new(d.cell_x, d.cell_y)) as u32;
        let id = d.robot_id as usize;
        if !self.robots.get(id).is_some_and(|r| r.accepted) {
            self.rejected += 1;
            return false;
        }
        self.life.seen(d.robot_id);
        let slot = &mut self.robots[id];
        slot.ack_dirty = true;
        if d.seq < slot.next_disc {
            self.disc_dup += 1;
            return true;
        }
        let pending = self.out_of_order.entry(d.robot_id).or_default();
        if !pending.insert(d.seq) {
            self.disc_dup += 1;
            return true;
        }
        let mut next = slot.next_disc;
        while pending.remove(&next) {
            next += 1;
        }
        slot.next_disc = next;
        self.disc_received += 1;
        if self.pseudo.insert(cell) {
            self.relay_pending.push(bus::bus_schema::DiscoveryRelay {
                origin_robot: d.robot_id,
                goal_id: d.goal_id,
                cell_x: d.cell_x,
                cell_y: d.cell_y,
                value: d.value,
                origin_seq: d.seq,
                origin_ns: d.time_ns,
                ..bus::bus_schema::DiscoveryRelay::ZEROED
            });
        }
        if d.send_time_ns != 0 && d.send_time_ns <= now {
            record(&mut self.h.discovery, now - d.send_time_ns);
        }
        true
    }

    fn send_acks(&mut self, bus: &CoordinatorBus) -> Result<(), CoordError> {
        for (id, slot) in self.robots.iter_mut().enumerate() {
            if !std::mem::take(&mut slot.ack_dirty) || slot.next_disc == 0 {
                continue;
            }
            let ack = DiscoveryAck {
                robot_id: id as u32,
                up_to_seq: slot.next_disc - 1,
                time_ns: monotonic_ns(),
                ..DiscoveryAck::ZEROED
            };
            bus.ack.send(&ack)?;
        }
        Ok(())
    }

    /// Relays new distinct discoveries to every robot (lossless; a fleet that already left
    /// is nobody to tell).
    fn send_relays(&mut self, bus: &CoordinatorBus) -> Result<(), CoordError> {
        send_relays(bus, &mut self.relay_pending, &mut self.relays_sent)
    }

    fn on_hints(&mut self, bus: &CoordinatorBus, b: &QHintBatch) -> Result<(), CoordError> {
        let now = monotonic_ns();
        let n = b.count as usize;
        if self.robot(b.robot_id).is_none() || b.goal_id != 0 || n > HINT_BATCH_CAP {
            self.rejected += 1;
            return Ok(());
        }
        if b.send_time_ns != 0 && b.send_time_ns <= now {
            record(&mut self.h.hints, now - b.send_time_ns);
        }
        if b.oldest_update_ns != 0 && b.oldest_update_ns <= now {
            record(&mut self.h.hint_age, now - b.oldest_update_ns);
        }
        let cells = self.table.cells();
        for h in &b.entries[..n] {
            if h.cell as usize >= cells || h.action >= 4 || !h.q.is_finite() {
                self.rejected += 1;
                continue;
            }
            self.q_merged += 1;
            if self.table.merge(b.robot_id, h, b.oldest_update_ns) {
                self.flush_merged(bus)?;
            }
        }
        Ok(())
    }

    fn flush_merged(&mut self, bus: &CoordinatorBus) -> Result<(), CoordError> {
        if self.table.pending() == 0 {
            return Ok(());
        }
        let seq = self.merged_seq;
        let table = &mut self.table;
        // zeroes only what the slot's last batch used, not all 6 KiB (most batches are small)
        bus.merged.send_batch(|m| {
            table.take_into(m);
            m.coordinator_seq = seq;
            m.goal_id = 0;
            m.send_time_ns = monotonic_ns();
        })?;
        self.merged_seq += 1;
        self.merged_sent += 1;
        Ok(())
    }

    fn on_report(&mut self, r: &FinalReport) {
        let now = monotonic_ns();
        let Some(slot) = self.robot(r.robot_id) else {
            self.rejected += 1;
            return;
        };
        slot.report = Some(*r);
        if r.send_time_ns != 0 && r.send_time_ns <= now {
            record(&mut self.h.report, now - r.send_time_ns);
        }
    }

    /// Takes a node listing of the `watch::Lister` thread: losses, cleanup of dead nodes (in
    /// the background), heartbeat deadlines.
    fn liveness(
        &mut self,
        bus: &CoordinatorBus,
        listing: watch::Listing,
    ) -> Result<(), CoordError> {
        let listed_at = listing.at;
        // listed without cleaning: cleaning a dead node takes ~0.3 s, so it runs in the
        // background after the loss is recorded (see `watch`)
        let report = listing.report?;
        if report.dead().next().is_some() {
            self.life.clean_dead(bus.config());
        }
        self.checks += 1;
        let mut alive = vec![false; self.robots.len()];
        for n in report.alive() {
            if let Some(id) = n
                .name
                .strip_prefix("qfleet-robot-")
                .and_then(|s| s.parse::<usize>().ok())
                && id < alive.len()
            {
                alive[id] = true;
            }
        }
        // a report that arrived before the process went away is not a loss
        self.drain(bus)?;
        for (id, slot) in self.robots.iter_mut().enumerate() {
            if self.life.joined_since(id, listed_at) {
                continue; // a new process that registered after the listing
            }
            slot.alive = alive[id];
            if slot.accepted && !alive[id] && slot.report.is_none() && !slot.lost {
                slot.lost = true;
                self.life.lost(id as u32);
                eprintln!(
                    "qfleet-coordinator: robot {id} is gone (its process died) without a final report"
                );
            }
        }
        // messages still waiting: a silence may be our own backlog, not a hung robot
        if !bus.has_samples()? {
            self.check_deadlines();
        }
        Ok(())
    }

    fn progress(&self) {
        if !self.args.progress {
            return;
        }
        let done: u64 = self
            .robots
            .iter()
            .map(|r| u64::from(r.report.map_or(r.episode, |rep| rep.episodes)))
            .sum();
        let total: u64 = self
            .robots
            .iter()
            .map(|r| u64::from(r.episodes_total))
            .sum();
        let (p50, p99) = if self.h.hint_age.is_empty() {
            (0, 0)
        } else {
            (
                self.h.hint_age.value_at_quantile(0.5),
                self.h.hint_age.value_at_quantile(0.99),
            )
        };
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "progress {done} {total} {p50} {p99}");
        let _ = out.flush();
    }

    fn collect_reports(
        &mut self,
        bus: &CoordinatorBus,
        lister: &watch::Lister,
        timeout: Duration,
    ) -> Result<(), CoordError> {
        let deadline = Instant::now() + timeout;
        loop {
            self.drain(bus)?;
            if self
                .robots
                .iter()
                .enumerate()
                .all(|(i, r)| !r.accepted || r.report.is_some() || r.lost || self.life.is_hung(i))
            {
                return Ok(());
            }
            let now = Instant::now();
            if now >= deadline {
                eprintln!(
                    "qfleet-coordinator: no final report from some robots within {timeout:?}"
                );
                return Ok(());
            }
            if let Some(listing) = lister.poll() {
                self.liveness(bus, listing)?;
            }
            bus.report.wait(Duration::from_millis(10))?;
        }
    }

    fn result(&self, active_s: f64, interrupted: bool, elapsed_s: f64) -> RunResult {
        let dir = &self.args.out;
        let mut loop_h = new_hist();
        let mut merged_h = new_hist();
        let mut robots = Vec::new();
        for (id, slot) in self.robots.iter().enumerate() {
            let detail = read_robot_json(dir, id);
            for (name, h) in [("loop", &mut loop_h), ("merged", &mut merged_h)] {
                if let Ok(r) = hist::read_binary(&dir.join(format!("robot-{id}-{name}.hdr"))) {
                    let _ = h.add(&r);
                }
            }
            let opt = |v: i32| u32::try_from(v).ok();
            let entry = match slot.report {
                Some(r) => RobotEntry {
                    robot_id: id as u32,
                    status: if r.status == RobotStatus::Finished.as_u8() {
                        "finished"
                    } else {
                        "stopped"
                    }
                    .into(),
                    final_path_len: opt(r.final_path_len),
                    own_final_path_len: detail
                        .as_ref()
                        .and_then(|d| d.get("own_final_path_len")?.as_u64())
                        .map(|v| v as u32),
                    optimal_path_len: opt(r.optimal_path_len),
                    avg_steps: r.avg_steps,
                    episodes: r.episodes,
                    first_optimal_episode: opt(r.first_optimal_episode),
                    env_steps: r.env_steps,
                    seed: slot.seed,
                    discoveries_sent: r.discoveries_sent,
                    discoveries_acked: r.discoveries_acked,
                    hints_sent: r.hints_sent,
                    hints_received: r.hints_received,
                    hints_applied: r.hints_applied,
                    loop_latency_ns: LatencyStats::from_summary(&r.merged_latency),
                    restarts: 0,
                    warm_started: false,
                    warm_start_entries: None,
                },
                None => RobotEntry {
                    robot_id: id as u32,
                    status: if slot.lost { "lost" } else { "missing" }.into(),
                    final_path_len: None,
                    own_final_path_len: None,
                    optimal_path_len: Some(self.task.optimal_len),
                    avg_steps: 0.0,
                    episodes: slot.episode,
                    first_optimal_episode: None,
                    env_steps: 0,
                    seed: slot.seed,
                    discoveries_sent: 0,
                    discoveries_acked: 0,
                    hints_sent: 0,
                    hints_received: 0,
                    hints_applied: 0,
                    loop_latency_ns: LatencyStats::default(),
                    restarts: 0,
                    warm_started: false,
                    warm_start_entries: None,
                },
            };
            let mut entry = entry;
            (entry.restarts, entry.warm_started) = self.life.restarts(id);
            entry.warm_start_entries = detail
                .as_ref()
                .and_then(|d| d.get("counters")?.get("warm_start_entries")?.as_u64());
            if entry.status == "missing" && self.life.is_hung(id) {
                entry.status = "hung".into();
            }
            robots.push(entry);
        }
        let mut latency_ns = BTreeMap::new();
        for (k, h) in [
            ("state_one_way", &self.h.state),
            ("discovery_one_way", &self.h.discovery),
            ("hints_one_way", &self.h.hints),
            ("hint_age_at_merge", &self.h.hint_age),
            ("report_one_way", &self.h.report),
            ("merged_one_way", &merged_h),
            ("loop", &loop_h),
        ] {
            latency_ns.insert(k.to_string(), LatencyStats::of(h));
        }
        let per_s = |x: u64| {
            if active_s > 0.0 {
                x as f64 / active_s
            } else {
                0.0
            }
        };
        let all_optimal = robots
            .iter()
            .all(|r| r.final_path_len.is_some() && r.final_path_len == r.optimal_path_len);
        RunResult {
            run_id: self.args.run_id.clone(),
            map: self.task.map_name.clone(),
            start: self.task.start.to_string(),
            goal: self.task.goal.to_string(),
            wait: self.args.wait,
            merge: self.args.merge,
            all_optimal,
            discoveries_sent: robots.iter().map(|r| r.discoveries_sent).sum(),
            discoveries_received: self.disc_received,
            discovery_duplicates: self.disc_dup,
            pseudo_targets: self.pseudo.len(),
            robots,
            latency_ns,
            throughput: Throughput {
                messages_per_s: per_s(self.messages),
                q_updates_merged_per_s: per_s(self.q_merged),
                messages: self.messages,
                q_updates_merged: self.q_merged,
                fleet_changes: self.table.changes,
                merged_batches_sent: self.merged_sent,
                active_s,
            },
            liveness: LivenessReport {
                checks: self.checks,
                lost: self
                    .robots
                    .iter()
                    .enumerate()
                    .filter(|(_, r)| r.lost)
                    .map(|(i, _)| i as u32)
                    .collect(),
                alive_at_end: self
                    .robots
                    .iter()
                    .enumerate()
                    .filter(|(_, r)| r.alive)
                    .map(|(i, _)| i as u32)
                    .collect(),
                hung: self.life.hung(),
                restarts: (0..self.robots.len())
                    .map(|i| self.life.restarts(i).0)
                    .sum(),
                discoveries_from_dead: self.life.disc_from_dead(),
                events: self.life.events().to_vec(),
            },
            rejected: self.rejected,
            interrupted,
            elapsed_s,
        }
    }

    fn write(&self, r: &RunResult) -> Result<(), CoordError> {
        let dir = &self.args.out;
        let out = |e: String| CoordError::Output(e);
        let json = serde_json::to_string_pretty(r).map_err(|e| out(e.to_string()))?;
        let path = dir.join("result.json");
        std::fs::write(&path, json).map_err(|e| out(format!("{}: {e}", path.display())))?;
        let mut loop_h = new_hist();
        let mut merged_h = new_hist();
        for id in 0..self.robots.len() {
            for (name, h) in [("loop", &mut loop_h), ("merged", &mut merged_h)] {
                if let Ok(x) = hist::read_binary(&dir.join(format!("robot-{id}-{name}.hdr"))) {
                    let _ = h.add(&x);
                }
            }
        }
        for (k, h) in [
            ("state_one_way", &self.h.state),
            ("discovery_one_way", &self.h.discovery),
            ("hints_one_way", &self.h.hints),
            ("hint_age_at_merge", &self.h.hint_age),
            ("report_one_way", &self.h.report),
            ("merged_one_way", &merged_h),
            ("loop", &loop_h),
        ] {
            hist::write_hgrm(h, &dir.join(format!("latency-{k}.hgrm")))
                .map_err(|e| out(e.to_string()))?;
        }
        Ok(())
    }
}

fn read_robot_json(dir: &Path, id: usize) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(dir.join(format!("robot-{id}.json"))).ok()?;
    serde_json::from_str(&text).ok()
}

/// Sends the pending relays, numbered from `relays_sent`, and wakes the robots once. Lossless;
/// a fleet that already left (no subscriber) is nobody to tell, which is not an error.
pub(crate) fn send_relays(
    bus: &CoordinatorBus,
    pending: &mut Vec<bus::bus_schema::DiscoveryRelay>,
    relays_sent: &mut u64,
) -> Result<(), CoordError> {
    if pending.is_empty() {
        return Ok(());
    }
    for mut r in std::mem::take(pending) {
        r.relay_seq = *relays_sent;
        r.send_time_ns = monotonic_ns();
        match bus.relay.send(&r) {
            Ok(_) | Err(BusError::NoSubscriber { .. }) => *relays_sent += 1,
            Err(e) => return Err(e.into()),
        }
    }
    bus.relay.notify()?;
    Ok(())
}
