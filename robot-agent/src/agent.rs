//! The robot-agent's run: register, wait for `Start`, learn while exchanging with the fleet,
//! synchronise with the fleet table at the end, report.
//!
//! # Topics, from the robot's side
//! - `robot/state` (latest-wins): every `--state-every` steps and at each episode end; only the
//!   newest progress matters, so a slow coordinator loses nothing of value.
//! - `robot/hints` (latest-wins): batches of changed Q-values; a newer batch carries newer
//!   values, and a lost batch only delays sharing (the values are sent again when they change,
//!   and the coordinator resends its whole table before the end).
//! - `robot/discovery` (lossless): every pseudo target this robot finds, numbered `seq` 0, 1, …;
//!   kept until the coordinator's cumulative `DiscoveryAck` covers it and re-sent if no ack came
//!   within 100 ms. They are few (at most the cells within the pseudo-target radius).
//! - `robot/report` (lossless): the final report.
//! - It reads `coord/control` (lossless), `coord/merged` (latest-wins), `coord/ack` (latest-wins).
//!
//! # Never blocking learning
//! The inbox is looked at every `--poll-every` steps without waiting; states and hints use
//! latest-wins topics that never block; only a discovery send could wait, for a full
//! 256-deep buffer at the coordinator, which a few dozen discoveries cannot fill.
//!
//! # The end of a run
//! After its episodes the robot flushes its hints, waits for all discoveries to be
//! acknowledged, publishes `Finished`, and keeps applying merged hints until the coordinator's
//! `Stop` (sent once every robot has finished, right after the coordinator resent its merged
//! table). Its final greedy path is computed after that, so every robot ends with what the
//! whole fleet learned. The path it had on its own is reported too (`own_final_path_len`).

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::bus_schema::{
    Command, Control, FinalReport, MergedHintBatch, PseudoTargetDiscovery, Register, RobotStatus,
    SCHEMA_VERSION,
};
use bus::{BusConfig, BusError, RobotBus, monotonic_ns};
use clap::Args;
use hdrhistogram::Histogram;
use planner::task::Task;
use planner::{EpisodeRecord, Learner, Summary};
use qfleet_args::{LearnerArgs, MapArgs};
use report::hist::{self, LatencyStats, new_hist, record};
pub use report::{Counters, RobotResult};
use report::{EndStatus, OutDir, OutFile, RobotHist};

use crate::reconnect::{Link, LinkEvent};
use crate::share::{ApplyCtx, HintBatcher, ShareArgs, apply_merged};

/// Every option of the robot-agent process.
#[derive(Debug, Clone, Args)]
pub struct AgentArgs {
    /// Run id shared by all processes of the run (names its services and shared memory).
    #[arg(long)]
    pub run_id: String,
    /// This robot's id, `0..robots`.
    #[arg(long)]
    pub robot_id: u32,
    /// Fleet size.
    #[arg(long, default_value_t = 4)]
    pub robots: u32,
    /// Map and task.
    #[command(flatten)]
    pub map: MapArgs,
    /// Learner parameters (`--seed` is this robot's own seed).
    #[command(flatten)]
    pub learner: LearnerArgs,
    /// Sharing options.
    #[command(flatten)]
    pub share: ShareArgs,
    /// Directory for `robot-<id>.json` and the robot's latency histograms.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Seconds to wait for the coordinator at start-up and for its `Stop` at the end.
    #[arg(long, default_value_t = 30.0)]
    pub timeout: f64,
    /// Test hook: register with this schema version instead of the real one.
    #[arg(long, hide = true)]
    pub schema_version_override: Option<u32>,
    /// Take part in a coordinator-driven experiment: goals and phases come from the
    /// coordinator (see the `experiment` module); started by `qfleet experiment`.
    #[arg(long)]
    pub experiment: bool,
    /// Experiment: end a phase after the episode whose greedy path is optimal.
    #[arg(long, requires = "experiment")]
    pub stop_at_optimum: bool,
}

/// Why a robot-agent failed.
#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    /// A bad option, map or learner parameter.
    #[error("{0}")]
    Input(String),
    /// The coordinator refused this robot (schema version, map, id).
    #[error("{0}")]
    Refused(BusError),
    /// Any other bus failure.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The coordinator's process is gone.
    #[error("the coordinator of run {0:?} is gone (its process died or exited)")]
    CoordinatorGone(String),
    /// Writing a result file failed (full disk, missing directory, …).
    #[error("writing results: {0}")]
    Output(#[from] report::WriteError),
    /// Writing a latency histogram failed.
    #[error("writing results: {0}")]
    Hist(#[from] report::HistError),
}

/// Who a final report is from and what it is about: the fields that differ between a plain run
/// and an experiment phase.
pub(crate) struct ReportHead {
    pub(crate) robot_id: u32,
    pub(crate) goal_id: u32,
    pub(crate) final_path_len: Option<u32>,
    pub(crate) optimal_path_len: u32,
}

/// The fixed-size `FinalReport` of a run or phase: learning summary, counters, loop latency.
pub(crate) fn final_report(
    head: ReportHead,
    s: &Summary,
    finished: bool,
    t0: Instant,
    c: &Counters,
    loop_hist: &Histogram<u64>,
) -> FinalReport {
    let to_i32 = |v: Option<u32>| v.map_or(-1, |x| x.min(i32::MAX as u32) as i32);
    let status = if finished {
        RobotStatus::Finished
    } else {
        RobotStatus::Failed
    };
    FinalReport {
        robot_id: head.robot_id,
        schema_version: SCHEMA_VERSION,
        goal_id: head.goal_id,
        episodes: s.episodes,
        final_path_len: to_i32(head.final_path_len),
        optimal_path_len: to_i32(Some(head.optimal_path_len)),
        first_optimal_episode: to_i32(s.first_optimal_episode),
        max_steps: s.max_steps,
        status: status.as_u8(),
        avg_steps: s.avg_steps,
        env_steps: s.env_steps,
        elapsed_ns: t0.elapsed().as_nanos().min(u128::from(u64::MAX)) as u64,
        discoveries_sent: c.discoveries_sent,
        discoveries_acked: c.discoveries_acked,
        hints_sent: c.hint_batches_sent,
        hints_received: c.merged.batches,
        hints_applied: c.merged.entries_applied,
        merged_latency: hist::summary(loop_hist),
        send_time_ns: monotonic_ns(),
        ..FinalReport::ZEROED
    }
}

/// Re-sends every unacknowledged discovery whose last send is older than `DISCOVERY_RESEND`;
/// true if any went out (the caller notifies once).
pub(crate) fn resend_due(
    bus: &RobotBus,
    unacked: &mut VecDeque<(u64, PseudoTargetDiscovery, Instant)>,
    c: &mut Counters,
) -> bool {
    let now = Instant::now();
    let mut any = false;
    for (_, d, last) in unacked.iter_mut() {
        if now.duration_since(*last) < DISCOVERY_RESEND {
            continue;
        }
        *last = now;
        let d = *d;
        match bus.discovery.send_with(|m| {
            *m = d;
            m.send_time_ns = monotonic_ns();
        }) {
            Ok(_) => c.discoveries_resent += 1,
            Err(_) => c.discovery_send_errors += 1,
        }
        any = true;
    }
    any
}

struct Discoveries {
    /// Every discovery made, by seq: replayed to a restarted coordinator.
    all: Vec<PseudoTargetDiscovery>,
    next_seq: u64,
    /// (seq, discovery, last send time) not yet acknowledged.
    unacked: VecDeque<(u64, PseudoTargetDiscovery, Instant)>,
    acked_up_to: Option<u64>,
    /// A discovery was sent since the last wakeup of the coordinator.
    dirty: bool,
}

const DISCOVERY_RESEND: Duration = Duration::from_millis(100);

/// How often a robot that is not learning (end of run) tells the coordinator it is alive.
const HEARTBEAT: Duration = Duration::from_millis(100);

struct Agent<'a> {
    args: &'a AgentArgs,
    bus: RobotBus,
    task: Task,
    goal_id: u32,
    learner: Learner,
    batcher: HintBatcher,
    ctx: ApplyCtx,
    c: Counters,
    disc: Discoveries,
    link: Link,
    loop_hist: Histogram<u64>,
    merged_hist: Histogram<u64>,
    last_merged_seq: Option<u64>,
    state_seq: u64,
    hint_seq: u64,
    stop: Arc<AtomicBool>,
    stopped: bool,
    steps: u64,
    episode_step: u32,
    last_episode_steps: u32,
}

fn secs(s: f64) -> Result<Duration, AgentError> {
    Duration::try_from_secs_f64(s)
        .ok()
        .filter(|d| !d.is_zero())
        .ok_or_else(|| {
            AgentError::Input(format!(
                "--timeout must be a positive number of seconds, got {s}"
            ))
        })
}

/// Runs one robot-agent to the end; `stop` is set by a signal handler (graceful stop).
pub fn run(args: &AgentArgs, stop: Arc<AtomicBool>) -> Result<RobotResult, AgentError> {
    if args.experiment {
        return crate::experiment::run(args, stop);
    }
    let timeout = secs(args.timeout)?;
    args.share.validate().map_err(AgentError::Input)?;
    let mut task = args
        .map
        .task()
        .map_err(|e| AgentError::Input(e.to_string()))?;
    let cfg = args
        .learner
        .config()
        .map_err(|e| AgentError::Input(e.to_string()))?;
    let width = u16::try_from(task.grid.width())
        .map_err(|_| AgentError::Input("maps wider than 65535 cells are not supported".into()))?;
    let height = u16::try_from(task.grid.height())
        .map_err(|_| AgentError::Input("maps taller than 65535 cells are not supported".into()))?;
    let bus_cfg = BusConfig::new(args.run_id.clone(), args.robots)?;
    if args.robot_id >= args.robots {
        return Err(AgentError::Input(format!(
            "--robot-id {} is outside 0..{} (--robots)",
            args.robot_id, args.robots
        )));
    }
    let bus = RobotBus::open(&bus_cfg, args.robot_id, timeout)?;
    let reg = Register {
        schema_version: args.schema_version_override.unwrap_or(SCHEMA_VERSION),
        robot_id: args.robot_id,
        pid: std::process::id(),
        episodes: cfg.episodes,
        width,
        height,
        start_x: task.start.x,
        start_y: task.start.y,
        map_hash: bus::bus_schema::map_fingerprint(
            task.grid.width(),
            task.grid.height(),
            task.grid.free_flags(),
        ),
        seed: cfg.seed,
        ..Register::ZEROED
    };
    // a goal assignment is checked when it arrives: an unusable one (outside the map, on a
    // wall: a broken or foreign sender) is logged and dropped, never fatal
    let mut goal: Option<(Control, Option<Task>)> = None;
    let start = crate::reconnect::handshake(&bus, &reg, timeout, &stop, |c| {
        if Command::try_from(c.command) != Ok(Command::AssignGoal) {
            return;
        }
        let cell = planner::Cell::new(c.goal_x, c.goal_y);
        if cell == task.goal {
            goal = Some((*c, None));
            return;
        }
        let mut m = args.map.clone();
        m.goal = Some(cell);
        match m.task() {
            Ok(t) => goal = Some((*c, Some(t))),
            Err(e) => eprintln!(
                "robot-agent {}: dropped an unusable goal assignment ({cell}): {e}",
                args.robot_id
            ),
        }
    })
    .map_err(|e| match e {
        BusError::Refused { .. } => AgentError::Refused(e),
        e => e.into(),
    })?;
    let mut goal_id = 0;
    if let Some((g, t)) = goal {
        goal_id = g.goal_id;
        if let Some(t) = t {
            task = t;
        }
    }
    let learner = Learner::new(&task, cfg).map_err(|e| AgentError::Input(e.to_string()))?;
    let cells = task.grid.len();
    let mut agent = Agent {
        args,
        batcher: HintBatcher::new(
            cells,
            args.share.hint_batch as usize,
            args.share.hint_min_change,
        ),
        ctx: ApplyCtx {
            robot_id: args.robot_id,
            robots: args.robots,
            goal_id,
            rule: args.share.apply,
        },
        bus,
        task,
        goal_id,
        learner,
        c: Counters::default(),
        link: Link::new(reg),
        disc: Discoveries {
            all: Vec::new(),
            next_seq: 0,
            unacked: VecDeque::new(),
            acked_up_to: None,
            dirty: false,
        },
        loop_hist: new_hist(),
        merged_hist: new_hist(),
        last_merged_seq: None,
        state_seq: 0,
        hint_seq: 0,
        stop,
        stopped: Command::try_from(start.command) == Ok(Command::Stop),
        steps: 0,
        episode_step: 0,
        last_episode_steps: 0,
    };
    let result = agent.run(timeout);
    let closed = agent.close();
    let result = result?;
    closed?;
    Ok(result)
}

impl Agent<'_> {
    fn run(&mut self, timeout: Duration) -> Result<RobotResult, AgentError> {
        let t0 = Instant::now();
        // grown on demand: preallocating N records costs gigabytes for very long runs
        let mut records: Vec<EpisodeRecord> = Vec::new();
        let share = self.args.share.share.hints();
        let state_every = u64::from(self.args.share.state_every);
        let poll_every = u64::from(self.args.share.poll_every);
        let flush_steps = u64::from(self.args.share.hint_flush_steps);
        // warm start: a robot (re)admitted during a run finds the coordinator's fleet table
        // waiting in its merged-hint buffer (sent before its Start)
        self.poll_inbox(share)?;
        self.c.warm_start_entries = self.c.merged.entries_applied;
        while !self.learner.finished() && !self.stopped {
            self.learner.begin_episode();
            self.episode_step = 0;
            loop {
                let info = self.learner.step();
                self.steps += 1;
                self.episode_step += 1;
                if share
                    && self
                        .batcher
                        .note(info.state, info.action, info.q, self.steps, monotonic_ns)
                {
                    self.send_hints();
                }
                if self.steps.is_multiple_of(state_every) {
                    self.send_state(RobotStatus::Running, info.next);
                }
                if self.steps.is_multiple_of(poll_every) {
                    if share && self.batcher.due(self.steps, flush_steps) {
                        self.send_hints();
                    }
                    self.poll_inbox(share)?;
                    if self.stopped {
                        break;
                    }
                }
                if info.done {
                    let rec = self.learner.end_episode(info.transition);
                    self.last_episode_steps = rec.steps;
                    records.push(rec);
                    break;
                }
            }
            for (cell, value) in self.learner.take_new_pseudo_targets() {
                self.queue_discovery(cell, value, records.len() as u32);
            }
            self.resend_discoveries();
        }
        let learn_s = t0.elapsed().as_secs_f64();
        let own_final = self.learner.greedy_path_len();
        if share && !self.batcher.is_empty() {
            self.send_hints();
        }
        // make sure every discovery reached the coordinator before saying "finished"
        let deadline = Instant::now() + timeout;
        let mut beat = Instant::now();
        while !self.disc.unacked.is_empty() && !self.stop.load(Ordering::Relaxed) {
            self.poll_inbox(share)?;
            self.resend_discoveries();
            self.heartbeat(RobotStatus::Running, &mut beat);
            if Instant::now() >= deadline {
                eprintln!(
                    "robot-agent {}: {} discoveries still unacknowledged after {timeout:?}",
                    self.args.robot_id,
                    self.disc.unacked.len()
                );
                break;
            }
            self.wait_for_coordinator(Duration::from_millis(5))?;
        }
        let at = self.learner.env().start();
        self.send_state(RobotStatus::Finished, at);
        let _ = self.bus.state.notify();
        // fleet sync: apply merged hints until the coordinator says Stop; a coordinator that
        // died meanwhile may be restarted: wait for it (re-joining it) up to the timeout
        let mut deadline = Instant::now() + timeout;
        let mut rejoins = self.link.counters.rejoins;
        while !self.stopped {
            self.poll_inbox(share)?;
            if self.stopped {
                break;
            }
            if self.stop.load(Ordering::Relaxed) {
                break;
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(BusError::Timeout {
                    what: "the coordinator's Stop after the last episode".into(),
                    timeout,
                }
                .into());
            }
            if self.link.counters.rejoins != rejoins {
                rejoins = self.link.counters.rejoins;
                deadline = now + timeout;
            }
            // keep the (maybe new) coordinator's view of us fresh: Finished, and alive
            self.resend_discoveries();
            self.heartbeat(RobotStatus::Finished, &mut beat);
            self.wait_for_coordinator(Duration::from_millis(2))?;
        }
        self.c.link = self.link.counters;
        // everything the coordinator sent before Stop is buffered by now
        self.poll_inbox(share)?;
        let finished = self.learner.finished();
        let final_len = self.learner.greedy_path_len();
        let summary = Summary::from_records(&records, self.learner.optimal_len(), final_len);
        let result = self.result(&summary, own_final, learn_s, finished);
        self.write_files(&result, &records)?;
        self.send_report(&summary, finished, t0)?;
        Ok(result)
    }

    fn wait_for_coordinator(&self, d: Duration) -> Result<(), AgentError> {
        self.bus.control.wait(d)?;
        Ok(())
    }

    fn send_state(&mut self, status: RobotStatus, cell_idx: u32) {
        let cell = self.task.grid.cell(cell_idx as usize);
        let (robot_id, goal_id, episode, step, last, seq) = (
            self.args.robot_id,
            self.goal_id,
            self.learner.episodes_done(),
            self.episode_step,
            self.last_episode_steps,
            self.state_seq,
        );
        let sent = self.bus.state.send_with(|m| {
            m.robot_id = robot_id;
            m.goal_id = goal_id;
            m.episode = episode;
            m.step = step;
            m.last_episode_steps = last;
            m.cell_x = cell.x;
            m.cell_y = cell.y;
            m.status = status.as_u8();
            m.seq = seq;
            m.send_time_ns = monotonic_ns();
        });
        self.state_seq += 1;
        match sent {
            Ok(_) => self.c.states_sent += 1,
            Err(_) => self.c.send_errors += 1,
        }
    }

    fn send_hints(&mut self) {
        let (robot_id, goal_id, seq) = (self.args.robot_id, self.goal_id, self.hint_seq);
        let batcher = &mut self.batcher;
        let mut n = 0;
        let sent = self.bus.hints.send_batch(|b| {
            b.robot_id = robot_id;
            b.goal_id = goal_id;
            b.seq = seq;
            n = batcher.fill(b);
            b.send_time_ns = monotonic_ns();
        });
        if n == 0 {
            // the loan failed before `fill`: drop the pending values (latest-wins)
            batcher.clear_shared();
        }
        self.hint_seq += 1;
        match sent {
            Ok(_) => {
                self.c.hint_batches_sent += 1;
                self.c.hint_entries_sent += n as u64;
                // waking the coordinator costs a syscall; once per batch is cheap enough
                let _ = self.bus.hints.notify();
            }
            Err(_) => self.c.send_errors += 1,
        }
    }

    fn queue_discovery(&mut self, cell: u32, value: f32, episode: u32) {
        let c = self.task.grid.cell(cell as usize);
        let seq = self.disc.next_seq;
        self.disc.next_seq += 1;
        let d = PseudoTargetDiscovery {
            robot_id: self.args.robot_id,
            goal_id: self.goal_id,
            cell_x: c.x,
            cell_y: c.y,
            value,
            seq,
            time_ns: monotonic_ns(),
            episode,
            ..PseudoTargetDiscovery::ZEROED
        };
        self.c.discoveries_sent += 1;
        self.disc.all.push(d);
        // first send happens now (unless no coordinator is there to take it); a failure
        // leaves it for the re-send timer
        if self.link.alone() {
            self.link.counters.discoveries_while_alone += 1;
        } else {
            let sent = self.bus.discovery.send_with(|m| {
                *m = d;
                m.send_time_ns = monotonic_ns();
            });
            if sent.is_err() {
                self.c.discovery_send_errors += 1;
            }
        }
        self.disc.unacked.push_back((seq, d, Instant::now()));
        self.disc.dirty = true;
    }

    fn resend_discoveries(&mut self) {
        if self.link.alone() {
            return; // kept until a coordinator is back and acknowledges them
        }
        let any = resend_due(&self.bus, &mut self.disc.unacked, &mut self.c);
        if any || std::mem::take(&mut self.disc.dirty) {
            let _ = self.bus.discovery.notify();
        }
    }

    /// A restarted coordinator accepted this robot: it knows none of our discoveries, so all
    /// of them go out again (it drops duplicates by seq), and the Finished state if we are done.
    fn on_link(&mut self, ev: LinkEvent) -> Result<(), AgentError> {
        match ev {
            LinkEvent::Rejoined => {
                let long_ago = Instant::now() - DISCOVERY_RESEND;
                self.disc.unacked = self
                    .disc
                    .all
                    .iter()
                    .map(|d| (d.seq, *d, long_ago))
                    .collect();
                self.disc.acked_up_to = None;
                self.resend_discoveries();
                Ok(())
            }
            LinkEvent::Refused(why) => Err(AgentError::Refused(BusError::Refused {
                robot_id: self.args.robot_id,
                reason: why,
            })),
        }
    }

    /// A state now and then while not learning (waiting for acks or for `Stop`), so the
    /// coordinator's heartbeat deadline does not take a waiting robot for a hung one.
    fn heartbeat(&mut self, status: RobotStatus, last: &mut Instant) {
        if last.elapsed() >= HEARTBEAT {
            *last = Instant::now();
            let at = self.learner.env().start();
            self.send_state(status, at);
            let _ = self.bus.state.notify();
        }
    }

    fn poll_inbox(&mut self, share: bool) -> Result<(), AgentError> {
        self.link.tick(&self.bus)?;
        // merged hints: applied in place, straight from shared memory
        loop {
            let Some(sample) = self.bus.merged.receive_sample()? else {
                break;
            };
            let m: &MergedHintBatch = sample.payload();
            let now = monotonic_ns();
            if m.send_time_ns != 0 && m.send_time_ns <= now {
                record(&mut self.merged_hist, now - m.send_time_ns);
            }
            if share {
                apply_merged(
                    m,
                    &self.ctx,
                    self.learner.q_mut(),
                    self.batcher.visits(),
                    now,
                    &mut self.loop_hist,
                    &mut self.last_merged_seq,
                    &mut self.c.merged,
                );
            }
        }
        // discoveries of other robots, relayed by the coordinator (lossless: always drained)
        while let Some(r) = self.bus.relay.receive()? {
            self.c.relays_received += 1;
            if self.args.share.share.discoveries()
                && r.goal_id == self.goal_id
                && r.origin_robot != self.args.robot_id
                && (r.cell_x as usize) < self.task.grid.width()
                && (r.cell_y as usize) < self.task.grid.height()
                && r.value.is_finite()
            {
                let cell = self.task.grid.index(planner::Cell::new(r.cell_x, r.cell_y)) as u32;
                if self.learner.add_pseudo_target(cell, r.value) {
                    self.c.relays_applied += 1;
                }
            }
        }
        while let Some(ack) = self.bus.ack.receive()? {
            if ack.robot_id != self.args.robot_id {
                continue;
            }
            if ack.up_to_seq >= self.disc.next_seq {
                self.c.rejected += 1; // acks something never sent
                continue;
            }
            if self.disc.acked_up_to.is_none_or(|a| ack.up_to_seq > a) {
                self.disc.acked_up_to = Some(ack.up_to_seq);
                self.c.discoveries_acked = ack.up_to_seq + 1;
                while self
                    .disc
                    .unacked
                    .front()
                    .is_some_and(|(s, _, _)| *s <= ack.up_to_seq)
                {
                    self.disc.unacked.pop_front();
                }
            }
        }
        while let Some(ctl) = self.bus.recv_control()? {
            if let Some(ev) = self.link.on_control(&ctl) {
                self.on_link(ev)?;
                continue;
            }
            match Command::try_from(ctl.command) {
                Ok(Command::Stop) => self.stopped = true,
                Ok(Command::AssignGoal) if ctl.goal_id != self.goal_id => {
                    eprintln!(
                        "robot-agent {}: ignoring a goal change to goal {} during the run (not supported yet)",
                        self.args.robot_id, ctl.goal_id
                    );
                }
                Ok(_) => {}
                Err(_) => self.c.rejected += 1,
            }
        }
        if self.stop.load(Ordering::Relaxed) {
            self.stopped = true;
        }
        Ok(())
    }

    fn result(
        &self,
        s: &Summary,
        own_final: Option<u32>,
        learn_s: f64,
        finished: bool,
    ) -> RobotResult {
        RobotResult {
            robot_id: self.args.robot_id,
            status: if finished {
                EndStatus::Finished
            } else {
                EndStatus::Stopped
            },
            map: self.task.map_name.clone(),
            learner: self.args.learner.learner.to_string(),
            seed: self.learner.config().seed,
            goal_id: self.goal_id,
            start: self.task.start.to_string(),
            goal: self.task.goal.to_string(),
            episodes: s.episodes,
            optimal_path_len: s.optimal_path_len,
            final_path_len: s.final_path_len,
            own_final_path_len: own_final,
            avg_steps: s.avg_steps,
            max_steps: s.max_steps,
            first_optimal_episode: s.first_optimal_episode,
            env_steps: s.env_steps,
            outcomes: [s.goal_episodes, s.pseudo_episodes, s.capped_episodes],
            learn_s,
            share: self.args.share.share,
            counters: self.c,
            loop_latency_ns: LatencyStats::of(&self.loop_hist),
            merged_latency_ns: LatencyStats::of(&self.merged_hist),
        }
    }

    fn write_files(&self, r: &RobotResult, records: &[EpisodeRecord]) -> Result<(), AgentError> {
        let Some(dir) = &self.args.out else {
            return Ok(());
        };
        let dir = OutDir::new(dir);
        dir.create()?;
        let robot = self.args.robot_id;
        dir.write_json(OutFile::Robot(robot), r)?;
        let mut csv = Vec::with_capacity(records.len() * 24);
        // writing into a Vec cannot fail
        if planner::metrics::write_episodes_csv(&mut csv, records).is_ok() {
            dir.write(OutFile::RobotEpisodes(robot), &csv)?;
        }
        for (kind, h) in [
            (RobotHist::Loop, &self.loop_hist),
            (RobotHist::Merged, &self.merged_hist),
        ] {
            hist::write_binary(h, &dir.path(OutFile::RobotHist { robot, kind }))?;
        }
        Ok(())
    }

    fn send_report(&mut self, s: &Summary, finished: bool, t0: Instant) -> Result<(), AgentError> {
        let head = ReportHead {
            robot_id: self.args.robot_id,
            goal_id: self.goal_id,
            final_path_len: s.final_path_len,
            optimal_path_len: s.optimal_path_len,
        };
        let rep = final_report(head, s, finished, t0, &self.c, &self.loop_hist);
        self.bus.report.send_and_notify(&rep)?;
        Ok(())
    }

    /// Consumes the bus, cleaning up the run's files if this was its last process.
    fn close(self) -> Result<(), AgentError> {
        self.bus.close()?;
        Ok(())
    }
}
