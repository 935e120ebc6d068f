//! The robot: one engine for plain runs and experiments. It registers, follows the
//! coordinator's plan (the protocol in [`crate::experiment`]) phase by phase — a plain run is
//! a plan with one goal and one phase — and reports.
//!
//! # Topics, from the robot's side
//! - `robot/state` (latest-wins): every `--state-every` steps, at every `--pace` pause, at each
//!   phase's end, and every 100 ms while not learning (a heartbeat); only the newest progress
//!   matters, so a slow coordinator loses nothing of value.
//! - `robot/hints` (latest-wins): batches of changed Q-values of the current goal; a newer
//!   batch carries newer values, and a lost batch only delays sharing (the values are sent
//!   again when they change, and the coordinator resends its whole table before the end).
//! - `robot/discovery` (lossless): every pseudo target this robot finds, numbered and kept until
//!   acknowledged ([`crate::discovery`]).
//! - `robot/report` (lossless): one `FinalReport` per phase.
//! - It reads `coord/control` (lossless), `coord/merged` (latest-wins), `coord/ack`
//!   (latest-wins) and `coord/discovery` (lossless relays of other robots' discoveries).
//!
//! # Never blocking learning
//! The inbox is looked at every `--poll-every` steps without waiting; states and hints use
//! latest-wins topics that never block; only a discovery send could wait, for a full
//! 256-deep buffer at the coordinator, which a few dozen discoveries cannot fill.
//!
//! # Surviving the coordinator
//! In every phase and between phases the robot watches its coordinator ([`crate::reconnect`]):
//! without one it keeps learning alone and holds its discoveries; with a restarted one it
//! re-registers and replays every discovery it ever made; the restarted coordinator's plan for
//! the phase the robot is already in is ignored ([`Effect::Repeated`]), so the phase goes on
//! where it was. A robot process that joins a running fleet (a restarted robot) finds the
//! coordinator's fleet table of its goal waiting in its merged-hint buffer and applies it
//! before its first episode (a warm start).

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::Origin;
use bus::bus_schema::{
    Command, FinalReport, GRANT_CAP, GridState, HORIZON_CELLS, PseudoTargetDiscovery, Register,
    RobotStatus, SCHEMA_VERSION, map_fingerprint,
};
use bus::iceoryx2::prelude::PayloadHeader;
use bus::{BusConfig, BusError, RobotBus, monotonic_ns};
use hdrhistogram::Histogram;
use planner::task::Task;
use planner::{Cell, EpisodeRecord, Learner, LearnerConfig, QTable, Summary};
use report::hist::{self, LatencyStats, new_hist, record};
use report::{Counters, EndStatus, OutDir, OutFile, PhaseDetail, RobotHist, RobotResult};

use crate::args::AgentArgs;
use crate::discovery::{AckOutcome, DISCOVERY_RESEND, DiscoveryLog};
use crate::error::AgentError;
use crate::execute::{Answering, RankCache, Ranker};
use crate::experiment::{Assignment, Effect, Plan};
use crate::gate::{ControlGate, Verdict};
use crate::pace::Pacer;
use crate::reconnect::{Link, LinkEvent, handshake};
use sharing::{ApplyCtx, HintBatcher, MergedApplier};

/// How often a robot that is not learning tells the coordinator it is alive.
const HEARTBEAT: Duration = Duration::from_millis(100);

/// Runs one robot-agent to the coordinator's `Stop`; `stop` is set by a signal handler
/// (graceful stop: the phase ends, is reported, and the robot exits).
pub fn run(args: &AgentArgs, stop: Arc<AtomicBool>) -> Result<RobotResult, AgentError> {
    let timeout = Duration::try_from_secs_f64(args.timeout)
        .ok()
        .filter(|d| !d.is_zero())
        .ok_or(AgentError::Timeout(args.timeout))?;
    args.share.validate()?;
    let base = args.map.task()?;
    let cfg = args.learner.config()?;
    let (Ok(width), Ok(height)) = (
        u16::try_from(base.grid.width()),
        u16::try_from(base.grid.height()),
    ) else {
        return Err(AgentError::MapTooLarge {
            width: base.grid.width(),
            height: base.grid.height(),
        });
    };
    if args.robot_id >= args.robots {
        return Err(AgentError::RobotId {
            robot_id: args.robot_id,
            robots: args.robots,
        });
    }
    let bus_cfg = BusConfig::new(args.run_id.clone(), args.robots)?;
    let bus = RobotBus::open_until(&bus_cfg, args.robot_id, timeout, &stop)?;
    let reg = Register {
        schema_version: args.schema_version_override.unwrap_or(SCHEMA_VERSION),
        robot_id: args.robot_id,
        pid: std::process::id(),
        episodes: cfg.episodes,
        width,
        height,
        start_x: base.start.x,
        start_y: base.start.y,
        map_hash: map_fingerprint(
            base.grid.width(),
            base.grid.height(),
            base.grid.free_flags(),
        ),
        seed: cfg.seed,
        ..Register::ZEROED
    };
    // AssignGoal (and anything else) before Start is read into the plan
    let mut plan = Plan::default();
    let mut gate = ControlGate::new();
    let mut rejected = 0;
    let start = handshake(&bus, &reg, timeout, &stop, &mut gate, |c| {
        if plan.on(c) == Effect::Rejected {
            rejected += 1;
        }
    })?;
    rejected += gate.rejected();
    plan.on(&start);
    let mut robot = Robot {
        args,
        applier: MergedApplier::new(ApplyCtx {
            robot_id: args.robot_id,
            robots: args.robots,
            goal_id: 0,
            rule: args.share.apply_rule(qfleet_args::ValueBound::of(&cfg)),
        }),
        bus,
        base,
        cfg,
        link: Link::new(reg),
        gate,
        plan,
        disc: DiscoveryLog::new(args.robot_id, DISCOVERY_RESEND),
        disc_dirty: false,
        merged_hist: new_hist(),
        c: Counters {
            rejected,
            ..Counters::default()
        },
        tables: BTreeMap::new(),
        relayed: BTreeMap::new(),
        state_seq: 0,
        hint_seq: 0,
        pacer: Pacer::new(args.pace),
        stop,
        timeout,
        unwritten: None,
    };
    let result = robot.run_plan();
    let closed = robot.bus.close();
    let result = result?;
    closed?;
    Ok(result)
}

/// One robot of a run (see the module docs).
struct Robot<'a> {
    args: &'a AgentArgs,
    bus: RobotBus,
    /// The task of the command line (its goal is the implicit plan's).
    base: Task,
    cfg: LearnerConfig,
    link: Link,
    /// Which publisher on `coord/control` is the coordinator ([`crate::gate`]).
    gate: ControlGate<Origin>,
    plan: Plan,
    disc: DiscoveryLog,
    /// A discovery went out since the coordinator was last woken.
    disc_dirty: bool,
    applier: MergedApplier,
    /// Coordinator sent a merged batch → received here.
    merged_hist: Histogram<u64>,
    c: Counters,
    /// The robot's Q-table of every goal it has learned.
    tables: BTreeMap<u32, QTable>,
    /// Other robots' discoveries (cell, value) per goal.
    relayed: BTreeMap<u32, Vec<(u32, f32)>>,
    state_seq: u64,
    hint_seq: u64,
    /// `--pace` (off: never pauses).
    pacer: Pacer,
    stop: Arc<AtomicBool>,
    timeout: Duration,
    /// The first result file that could not be written (a full disk): the robot goes on so
    /// that the coordinator still gets every report, and exits with this error at the end.
    unwritten: Option<AgentError>,
}

/// One phase being learned (or just learned: its learner keeps taking merged hints until the
/// next phase or `Stop`).
struct Phase {
    a: Assignment,
    task: Task,
    learner: Learner,
    batcher: HintBatcher,
    records: Vec<EpisodeRecord>,
    steps: u64,
    episode_step: u32,
    last_episode_steps: u32,
    t0: Instant,
    start_ns: u64,
    episode_end_ns: Vec<u64>,
    episode_cum_steps: Vec<u64>,
    steps_to_optimal: Option<u64>,
    time_to_optimal_s: Option<f64>,
    /// Ran to its end (not stopped by `Stop` or a signal).
    completed: bool,
    learn_s: f64,
    /// Greedy path when its own episodes ended (before the fleet sync).
    own_final: Option<u32>,
    /// Counters when the phase started, for the phase's own figures.
    at_start: Counters,
    relays_at_start: u64,
    reported: bool,
    /// Moves of other robots named in merged hints join this learner's sweep model (planning
    /// learner, `min` rules).
    shared_model: bool,
}

impl Robot<'_> {
    fn run_plan(&mut self) -> Result<RobotResult, AgentError> {
        let mut last: Option<Phase> = None;
        loop {
            let next = self.wait_next(last.as_mut())?;
            let a = match next {
                Some(a) => a,
                // stopped before any phase: the phase it would have learned, with no episode,
                // so that the coordinator still gets a report
                None if last.is_none() => Assignment::IMPLICIT,
                None => break,
            };
            if let Some(p) = last.as_mut() {
                self.close_phase(p)?;
            }
            let mut p = match self.open_phase(a) {
                Ok(p) => p,
                Err(e @ AgentError::Goal { .. }) => {
                    // a broken or foreign sender: logged and counted, never fatal
                    report::log_line!("robot-agent {}: dropped: {e}", self.args.robot_id);
                    self.c.rejected += 1;
                    continue;
                }
                Err(e) => return Err(e),
            };
            let first = last.is_none();
            self.learn(&mut p, first)?;
            self.end_phase(&mut p)?;
            last = Some(p);
            if self.plan.stopped() {
                break;
            }
        }
        // `last` is always set here: the loop leaves only after a phase
        let Some(mut p) = last else {
            unreachable!("the plan loop ends after a phase")
        };
        // everything the coordinator sent before Stop is buffered by now
        self.poll(Some(&mut p))?;
        let result = self.result(&mut p);
        let written = self.write_files(&result, &p.records);
        self.unwritten(written);
        self.close_phase(&mut p)?;
        match self.unwritten.take() {
            Some(e) => Err(e),
            None => Ok(result),
        }
    }

    /// Keeps the first failure to write a result file for the end of the run (see
    /// [`Robot::unwritten`]) and says it now.
    fn unwritten(&mut self, written: Result<(), AgentError>) {
        if let Err(e) = written {
            report::log_line!(
                "robot-agent {}: error: {e}; the robot goes on so its report still reaches the coordinator",
                self.args.robot_id
            );
            self.unwritten.get_or_insert(e);
        }
    }

    /// `robot-<id>-phase-<n>.json`: what the robot learned in phase `p`.
    fn write_phase_file(&self, p: &mut Phase) -> Result<(), AgentError> {
        let Some(dir) = &self.args.out else {
            return Ok(());
        };
        let dir = OutDir::new(dir);
        dir.create()?;
        let f = OutFile::RobotPhase {
            robot: self.args.robot_id,
            phase: p.a.phase,
        };
        dir.write_json(f, &self.phase_detail(p))?;
        Ok(())
    }

    /// Waits for the next phase (`Some`) or `Stop` (`None`), applying merged hints to the last
    /// phase's learner meanwhile, resending discoveries and beating the heartbeat. A
    /// coordinator that died may be restarted: the wait starts again when the robot re-joins.
    fn wait_next(
        &mut self,
        mut last: Option<&mut Phase>,
    ) -> Result<Option<Assignment>, AgentError> {
        let mut deadline = Instant::now() + self.timeout;
        let mut rejoins = self.link.counters.rejoins;
        let mut beat = Instant::now();
        loop {
            self.poll(last.as_deref_mut())?;
            if let Some(horizon) = self.plan.take_execute()
                && let Some(p) = last.as_deref_mut()
            {
                self.execute(p, horizon)?;
                deadline = Instant::now() + self.timeout;
            }
            if let Some(a) = self.plan.take_next() {
                return Ok(Some(a));
            }
            if self.plan.stopped() {
                return Ok(None);
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(BusError::Timeout {
                    what: "the coordinator's next phase or Stop".into(),
                    timeout: self.timeout,
                }
                .into());
            }
            if self.link.counters.rejoins != rejoins {
                rejoins = self.link.counters.rejoins;
                deadline = now + self.timeout;
            }
            // keep the (maybe new) coordinator's view of us fresh: done, and alive
            self.resend_discoveries();
            if let Some(p) = last.as_deref_mut() {
                self.heartbeat(p, RobotStatus::Finished, &mut beat);
            }
            self.bus.control.wait(Duration::from_millis(2))?;
        }
    }

    /// Moves on the shared grid as the coordinator grants, tick by tick, until the execution
    /// ends (a grant that is not `Moving`, this robot no longer on the grid, `Stop`, a signal);
    /// see [`crate::execute`] for the protocol and the ranking.
    fn execute(&mut self, p: &mut Phase, horizon: u8) -> Result<(), AgentError> {
        // the values it ranks by, consistent with every merged hint applied so far
        p.learner.settle();
        let ranker = Ranker::new(&p.task, p.learner.tried_pairs(), p.learner.config().gamma);
        let me = self.args.robot_id as usize;
        let mut answering = Answering::new(horizon);
        let mut ranks = [0u16; HORIZON_CELLS];
        let mut cache = RankCache::new(&p.task);
        let mut answered: Option<u32> = None;
        let mut heard = Instant::now();
        let mut polled = Instant::now();
        let mut intents = 0u64;
        loop {
            // the newest grant of this robot's coordinator: only its tick, state and this
            // robot's entry matter
            let coordinator = self.gate.coordinator().map(|o| o.node);
            let mut newest: Option<(u32, u8, Cell, bool)> = None;
            while let Some(g) = self.bus.grant.receive_sample()? {
                if coordinator != Some(g.header().node_id().value()) {
                    self.c.grants_foreign += 1;
                    continue;
                }
                let g = g.payload();
                if me < GRANT_CAP && newest.is_none_or(|n| g.tick >= n.0) {
                    let cell = Cell::new(g.cell_x[me], g.cell_y[me]);
                    newest = Some((g.tick, g.state, cell, g.present[me] != 0));
                }
            }
            if let Some((tick, state, cell, present)) = newest
                && answered.is_none_or(|t| tick > t)
            {
                heard = Instant::now();
                answered = Some(tick);
                if !p.task.grid.contains(cell.x.into(), cell.y.into()) {
                    // no grant of this run's coordinator puts a robot off the map
                    self.c.rejected += 1;
                    continue;
                }
                let at = p.task.grid.index(cell) as u32;
                if state != GridState::Moving.as_u8() || !present {
                    p.episode_step = tick;
                    self.send_state(p, RobotStatus::Finished, at);
                    let _ = self.bus.state.notify();
                    break;
                }
                let robot_id = self.args.robot_id;
                let sent = match answering.due(tick, cell) {
                    // the last horizon still answers this tick here: nothing to send
                    None => None,
                    Some(_) if answering.horizon() == 0 => {
                        let (ranked, count) = ranker.rank(&p.task, p.learner.q(), cell);
                        Some(self.bus.intent.send_with(|m| {
                            m.robot_id = robot_id;
                            m.tick = tick;
                            m.cell_x = cell.x;
                            m.cell_y = cell.y;
                            m.count = count;
                            m.ranked = ranked;
                            m.send_time_ns = monotonic_ns();
                        }))
                    }
                    Some(radius) => {
                        let q = p.learner.q();
                        ranker.rank_horizon(&p.task, q, &mut cache, cell, radius, &mut ranks);
                        answering.answered(tick, cell, radius);
                        Some(self.bus.horizon.send_with(|m| {
                            m.robot_id = robot_id;
                            m.tick = tick;
                            m.cell_x = cell.x;
                            m.cell_y = cell.y;
                            m.radius = radius;
                            m.ranked = ranks;
                            m.send_time_ns = monotonic_ns();
                        }))
                    }
                };
                match sent {
                    // no wakeup: the coordinator polls while it collects a tick (a notification
                    // per robot per tick cost each robot a syscall and the coordinator one
                    // wakeup per robot)
                    Some(Ok(_)) => intents += 1,
                    Some(Err(_)) => self.c.send_errors += 1,
                    None => {}
                }
                // observers see the ticks on robot/state (no wakeup: nobody waits for it)
                p.episode_step = tick;
                self.send_state(p, RobotStatus::Running, at);
            }
            if polled.elapsed() >= Duration::from_millis(20) {
                polled = Instant::now();
                let applied = self.applier.counters().entries_applied;
                self.poll(Some(p))?;
                if self.applier.counters().entries_applied != applied {
                    // merged hints changed the values: rank anew
                    cache.clear();
                }
                if self.plan.stopped() {
                    break;
                }
            }
            if heard.elapsed() >= self.timeout {
                return Err(BusError::Timeout {
                    what: "the coordinator's next grant on the shared grid".into(),
                    timeout: self.timeout,
                }
                .into());
            }
            self.bus.grant.wait(Duration::from_millis(10))?;
        }
        report::log_line!(
            "robot-agent {}: shared grid: {intents} intents sent, last tick {}",
            self.args.robot_id,
            answered.unwrap_or(0)
        );
        Ok(())
    }

    /// A learner for assignment `a`, resuming the robot's table of that goal.
    fn open_phase(&mut self, a: Assignment) -> Result<Phase, AgentError> {
        let task = match a.goal {
            None => self.base.clone(),
            Some(cell) if cell == self.base.goal => self.base.clone(),
            Some(cell) => {
                let mut m = self.args.map.clone();
                m.goal = Some(cell);
                m.task()
                    .map_err(|source| AgentError::Goal { cell, source })?
            }
        };
        let mut cfg = self.cfg;
        if let Some(n) = a.episodes {
            cfg.episodes = n;
        }
        cfg.seed = cfg
            .seed
            .wrapping_add(u64::from(a.phase).wrapping_mul(0x9E37_79B9));
        let mut learner = Learner::new(&task, cfg)?;
        // min-sharing of upper bounds: a tighter fleet value must survive this robot's own
        // backups (see `Learner::keep_values_falling`), and the moves other robots made join
        // the model its sweeps back up
        let bound = qfleet_args::ValueBound::of(&cfg);
        let min_sharing = self.args.share.share.hints()
            && bound == qfleet_args::ValueBound::Upper
            && self.args.share.apply_rule(bound) == contract::ApplyRule::Min;
        if min_sharing {
            learner.keep_values_falling();
        }
        if let Some(q) = self.tables.get(&a.goal_id) {
            *learner.q_mut() = q.clone();
        }
        let mut relays = 0;
        for &(c, v) in self.relayed.get(&a.goal_id).map_or(&[][..], |v| &v[..]) {
            relays += u64::from(learner.add_pseudo_target(c, v));
        }
        self.applier.set_goal(a.goal_id);
        Ok(Phase {
            a,
            batcher: HintBatcher::new(
                task.grid.len(),
                self.args.share.hint_batch as usize,
                self.args.share.hint_min_change,
            ),
            task,
            learner,
            // grown on demand: preallocating N records costs gigabytes for very long runs
            records: Vec::new(),
            steps: 0,
            episode_step: 0,
            last_episode_steps: 0,
            t0: Instant::now(),
            start_ns: monotonic_ns(),
            episode_end_ns: Vec::new(),
            episode_cum_steps: Vec::new(),
            steps_to_optimal: None,
            time_to_optimal_s: None,
            completed: false,
            learn_s: 0.0,
            own_final: None,
            at_start: self.counters(),
            relays_at_start: relays,
            reported: false,
            shared_model: min_sharing && cfg.extras.needs_model(),
        })
    }

    /// Learns one phase's episodes (or until `Stop`, or the optimum with `--stop-at-optimum`).
    fn learn(&mut self, p: &mut Phase, first: bool) -> Result<(), AgentError> {
        let share = self.args.share.share.hints();
        let state_every = u64::from(self.args.share.state_every);
        let poll_every = u64::from(self.args.share.poll_every);
        let flush_steps = u64::from(self.args.share.hint_flush_steps);
        // warm start: a robot (re)admitted during a run finds the coordinator's fleet table
        // waiting in its merged-hint buffer (sent before its Start)
        self.poll(Some(p))?;
        if first {
            self.c.warm_start_entries = self.applier.counters().entries_applied;
        }
        let optimal = p.learner.optimal_len();
        while !p.learner.finished() && !self.plan.stopped() {
            p.learner.begin_episode();
            p.episode_step = 0;
            loop {
                let info = p.learner.step();
                p.steps += 1;
                p.episode_step += 1;
                if share
                    && p.batcher
                        .note(info.state, info.action, info.q, p.steps, monotonic_ns)
                {
                    self.send_hints(p);
                }
                if p.steps.is_multiple_of(state_every) {
                    self.send_state(p, RobotStatus::Running, info.next);
                }
                if p.steps.is_multiple_of(poll_every) {
                    if share && p.batcher.due(p.steps, flush_steps) {
                        self.send_hints(p);
                    }
                    self.poll(Some(p))?;
                    // sweeps inside the episode (`--sweep-every`) changed values no step noted
                    if share && p.learner.take_swept_within() {
                        self.offer_planned(p);
                    }
                    if self.plan.stopped() {
                        break;
                    }
                }
                // --pace: a pause every few steps (when off, a countdown that never runs out)
                if self.pacer.step() {
                    self.pause(p, info.next)?;
                    if self.plan.stopped() {
                        break;
                    }
                }
                if info.done {
                    let rec = p.learner.end_episode(info.transition);
                    p.last_episode_steps = rec.steps;
                    p.records.push(rec);
                    if share && p.learner.planned() {
                        self.offer_planned(p);
                        // the merged batches that piled up during replay and sweeps: drained
                        // now, before the latest-wins buffer overwrites them
                        self.poll(Some(p))?;
                    }
                    break;
                }
            }
            p.episode_end_ns.push(monotonic_ns());
            p.episode_cum_steps.push(p.steps);
            for (cell, value) in p.learner.take_new_pseudo_targets() {
                self.queue_discovery(p, cell, value);
            }
            self.resend_discoveries();
            if p.steps_to_optimal.is_none() && p.learner.greedy_path_len() == Some(optimal) {
                p.steps_to_optimal = Some(p.steps);
                p.time_to_optimal_s = Some(p.t0.elapsed().as_secs_f64());
                if self.args.stop_at_optimum {
                    break;
                }
            }
        }
        p.completed = !self.plan.stopped();
        p.learn_s = p.t0.elapsed().as_secs_f64();
        p.own_final = p.learner.greedy_path_len();
        Ok(())
    }

    /// After an episode whose replay or sweeps changed values no step noted: offers every tried
    /// pair's value to the batcher (unchanged ones are skipped there) and sends the batch.
    fn offer_planned(&mut self, p: &mut Phase) {
        for i in 0..p.learner.tried_pairs().len() {
            let sa = p.learner.tried_pairs()[i];
            let (s, a) = (sa >> 2, (sa & 3) as u8);
            let q = p.learner.q().row(s as usize)[a as usize];
            if p.batcher.offer(s, a, q, p.steps, monotonic_ns) {
                self.send_hints(p);
            }
        }
        // what planning learned goes out now, not `--hint-flush-steps` later
        if !p.batcher.is_empty() {
            self.send_hints(p);
        }
    }

    /// A `--pace` pause: sleeps what the pacer says, then shows where the robot is, shares what
    /// it learned and reads its inbox (a slow pace pauses up to a second per step: a stop must
    /// not wait for the next `--poll-every`, nor the coordinator take the robot for hung).
    fn pause(&mut self, p: &mut Phase, at: u32) -> Result<(), AgentError> {
        let nap = self.pacer.pause(monotonic_ns());
        if !nap.is_zero() {
            std::thread::sleep(nap);
        }
        if self.args.share.share.hints() && !p.batcher.is_empty() {
            self.send_hints(p);
        }
        self.send_state(p, RobotStatus::Running, at);
        let _ = self.bus.state.notify();
        self.poll(Some(p))
    }

    /// The end of a phase's learning: flush hints, get every discovery acknowledged, write the
    /// phase detail, report (a phase of an experiment) and say `Finished`.
    fn end_phase(&mut self, p: &mut Phase) -> Result<(), AgentError> {
        if self.args.share.share.hints() && !p.batcher.is_empty() {
            self.send_hints(p);
        }
        // make sure every discovery reached the coordinator before saying "finished"
        let deadline = Instant::now() + self.timeout;
        let mut beat = Instant::now();
        while !self.disc.settled() && !self.stop.load(Ordering::Relaxed) {
            self.poll(Some(p))?;
            self.resend_discoveries();
            self.heartbeat(p, RobotStatus::Running, &mut beat);
            if Instant::now() >= deadline {
                report::log_line!(
                    "robot-agent {}: {} discoveries still unacknowledged after {:?}",
                    self.args.robot_id,
                    self.disc.unacked(),
                    self.timeout
                );
                break;
            }
            self.bus.control.wait(Duration::from_millis(5))?;
        }
        self.tables.insert(p.a.goal_id, p.learner.q().clone());
        let written = self.write_phase_file(p);
        self.unwritten(written);
        let at = p.learner.env().start();
        self.send_state(p, RobotStatus::Finished, at);
        let _ = self.bus.state.notify();
        if p.a.report_at_end {
            self.send_report(p)?;
        }
        Ok(())
    }

    /// A phase is over for good (the next one starts, or `Stop`): keep its table with the
    /// fleet's hints applied since, and report it if that was not done at its end.
    fn close_phase(&mut self, p: &mut Phase) -> Result<(), AgentError> {
        self.tables.insert(p.a.goal_id, p.learner.q().clone());
        if !p.reported {
            self.send_report(p)?;
        }
        Ok(())
    }

    fn summary(p: &mut Phase) -> Summary {
        // merged hints applied since the last episode reach the values they bound first (a
        // path read from unpropagated bounds could loop)
        p.learner.settle();
        let final_len = p.learner.greedy_path_len();
        Summary::from_records(&p.records, p.learner.optimal_len(), final_len)
    }

    fn phase_detail(&self, p: &mut Phase) -> PhaseDetail {
        let s = Self::summary(p);
        let now = self.counters();
        PhaseDetail {
            robot_id: self.args.robot_id,
            phase: p.a.phase,
            goal_id: p.a.goal_id,
            start: p.task.start.to_string(),
            goal: p.task.goal.to_string(),
            episodes: s.episodes,
            env_steps: s.env_steps,
            avg_steps: s.avg_steps,
            optimal_path_len: s.optimal_path_len,
            final_path_len: s.final_path_len,
            first_optimal_episode: s.first_optimal_episode,
            steps_to_optimal: p.steps_to_optimal,
            time_to_optimal_s: p.time_to_optimal_s,
            start_ns: p.start_ns,
            episode_end_ns: p.episode_end_ns.clone(),
            episode_cum_steps: p.episode_cum_steps.clone(),
            discoveries_sent: now.discoveries_sent - p.at_start.discoveries_sent,
            relays_applied: now.relays_applied - p.at_start.relays_applied + p.relays_at_start,
            hints_applied: now.merged.entries_applied - p.at_start.merged.entries_applied,
            finished: p.completed,
        }
    }

    /// The counters with the applier's and the link's folded in.
    fn counters(&self) -> Counters {
        Counters {
            merged: *self.applier.counters(),
            link: self.link.counters,
            ..self.c
        }
    }

    /// The phase's `FinalReport`: learning summary, counters, loop latency. A report that
    /// reaches nobody after `Stop` (the coordinator already left) or while the coordinator is
    /// gone is not an error.
    fn send_report(&mut self, p: &mut Phase) -> Result<(), AgentError> {
        p.reported = true;
        let s = Self::summary(p);
        let to_i32 = |v: Option<u32>| v.map_or(-1, |x| x.min(i32::MAX as u32) as i32);
        let c = self.counters();
        let rep = FinalReport {
            robot_id: self.args.robot_id,
            schema_version: SCHEMA_VERSION,
            goal_id: p.a.goal_id,
            episodes: s.episodes,
            final_path_len: to_i32(s.final_path_len),
            optimal_path_len: to_i32(Some(s.optimal_path_len)),
            first_optimal_episode: to_i32(s.first_optimal_episode),
            max_steps: s.max_steps,
            status: if p.completed {
                RobotStatus::Finished
            } else {
                RobotStatus::Failed
            }
            .as_u8(),
            avg_steps: s.avg_steps,
            env_steps: s.env_steps,
            elapsed_ns: p.t0.elapsed().as_nanos().min(u128::from(u64::MAX)) as u64,
            discoveries_sent: c.discoveries_sent,
            discoveries_acked: c.discoveries_acked,
            hints_sent: c.hint_batches_sent,
            hints_received: c.merged.batches,
            hints_applied: c.merged.entries_applied,
            merged_latency: hist::summary(self.applier.loop_hist()),
            send_time_ns: monotonic_ns(),
            ..FinalReport::ZEROED
        };
        match self.bus.report.send_and_notify(&rep) {
            Ok(_) => Ok(()),
            // without a coordinator the report waits for the restarted one's repeat of the
            // phase (see the protocol in `crate::experiment`); one that died since the last
            // periodic look is looked for now (CI: a robot ending its phase just after the
            // coordinator was killed exited with "reached no subscriber")
            Err(e @ (BusError::NoSubscriber { .. } | BusError::DeliveryTimeout { .. })) => {
                let nobody = matches!(e, BusError::NoSubscriber { .. })
                    && (self.plan.stopped() || self.link.alone());
                if nobody || self.link.look_now(&self.bus)? {
                    Ok(())
                } else {
                    Err(e.into())
                }
            }
            Err(e) => Err(e.into()),
        }
    }

    fn result(&self, p: &mut Phase) -> RobotResult {
        let s = Self::summary(p);
        RobotResult {
            robot_id: self.args.robot_id,
            status: if p.completed {
                EndStatus::Finished
            } else {
                EndStatus::Stopped
            },
            map: self.base.map_name.clone(),
            learner: self.args.learner.learner.to_string(),
            seed: p.learner.config().seed,
            goal_id: p.a.goal_id,
            start: p.task.start.to_string(),
            goal: p.task.goal.to_string(),
            episodes: s.episodes,
            optimal_path_len: s.optimal_path_len,
            final_path_len: s.final_path_len,
            own_final_path_len: p.own_final,
            avg_steps: s.avg_steps,
            max_steps: s.max_steps,
            first_optimal_episode: s.first_optimal_episode,
            env_steps: s.env_steps,
            outcomes: [s.goal_episodes, s.pseudo_episodes, s.capped_episodes],
            learn_s: p.learn_s,
            share: self.args.share.share,
            counters: self.counters(),
            loop_latency_ns: LatencyStats::of(self.applier.loop_hist()),
            merged_latency_ns: LatencyStats::of(&self.merged_hist),
        }
    }

    /// `robot-<id>.json`, the last phase's episodes and the two latency histograms.
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
            (RobotHist::Loop, self.applier.loop_hist()),
            (RobotHist::Merged, &self.merged_hist),
        ] {
            hist::write_binary(h, &dir.path(OutFile::RobotHist { robot, kind }))?;
        }
        Ok(())
    }

    fn send_state(&mut self, p: &Phase, status: RobotStatus, cell_idx: u32) {
        let cell = p.task.grid.cell(cell_idx as usize);
        let (robot_id, goal_id, episode, step, last, seq) = (
            self.args.robot_id,
            p.a.goal_id,
            p.learner.episodes_done(),
            p.episode_step,
            p.last_episode_steps,
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

    /// A state now and then while not learning (waiting for acks or for the next phase), so
    /// the coordinator's heartbeat deadline does not take a waiting robot for a hung one.
    fn heartbeat(&mut self, p: &Phase, status: RobotStatus, last: &mut Instant) {
        if last.elapsed() >= HEARTBEAT {
            *last = Instant::now();
            let at = p.learner.env().start();
            self.send_state(p, status, at);
            let _ = self.bus.state.notify();
        }
    }

    fn send_hints(&mut self, p: &mut Phase) {
        let (robot_id, goal_id, seq) = (self.args.robot_id, p.a.goal_id, self.hint_seq);
        let batcher = &mut p.batcher;
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

    fn queue_discovery(&mut self, p: &Phase, cell: u32, value: f32) {
        let c = p.task.grid.cell(cell as usize);
        let d = PseudoTargetDiscovery {
            goal_id: p.a.goal_id,
            cell_x: c.x,
            cell_y: c.y,
            value,
            time_ns: monotonic_ns(),
            episode: p.records.len() as u32,
            ..PseudoTargetDiscovery::ZEROED
        };
        self.c.discoveries_sent += 1;
        // first send happens now (unless no coordinator is there to take it); a failure
        // leaves it for the re-send timer
        let alone = self.link.alone();
        let d = self.disc.record(d, Instant::now(), !alone);
        if alone {
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
        self.disc_dirty = true;
    }

    fn resend_discoveries(&mut self) {
        if self.link.alone() {
            return; // kept until a coordinator is back and acknowledges them
        }
        let (bus, c) = (&self.bus, &mut self.c);
        let n = self.disc.due(Instant::now(), |d| {
            let sent = bus.discovery.send_with(|m| {
                *m = *d;
                m.send_time_ns = monotonic_ns();
            });
            match sent {
                Ok(_) => c.discoveries_resent += 1,
                Err(_) => c.discovery_send_errors += 1,
            }
        });
        if n > 0 || std::mem::take(&mut self.disc_dirty) {
            let _ = self.bus.discovery.notify();
        }
    }

    /// A restarted coordinator accepted this robot: it knows none of our discoveries, so all
    /// of them go out again (it drops duplicates by seq).
    fn on_link(&mut self, ev: LinkEvent) -> Result<(), AgentError> {
        match ev {
            LinkEvent::Rejoined => {
                self.disc.replay();
                self.c.discoveries_acked = self.disc.acked();
                self.resend_discoveries();
                Ok(())
            }
            LinkEvent::Refused(why) => Err(AgentError::Refused(BusError::Refused {
                robot_id: self.args.robot_id,
                reason: why,
            })),
        }
    }

    /// Takes in everything waiting: merged hints (applied to `phase`'s learner if there is
    /// one), relayed discoveries, acks and controls; never blocks.
    fn poll(&mut self, mut phase: Option<&mut Phase>) -> Result<(), AgentError> {
        self.link.tick(&self.bus)?;
        let share = self.args.share.share.hints();
        // merged hints: applied in place, straight from shared memory; before the first phase
        // they stay buffered for it (the warm start from the fleet table)
        while phase.is_some()
            && let Some(sample) = self.bus.merged.receive_sample()?
        {
            let m = sample.payload();
            let now = monotonic_ns();
            if m.send_time_ns != 0 && m.send_time_ns <= now {
                record(&mut self.merged_hist, now - m.send_time_ns);
            }
            if share
                && let Some(p) = phase.as_deref_mut()
                && p.shared_model
                && m.goal_id != p.a.goal_id
            {
                // another goal's values say nothing of ours, but the moves behind them are the
                // grid's: they join this learner's model, so it never explores a wall another
                // robot found (robots with different goals on one grid)
                let n = (m.count as usize).min(m.entries.len());
                let mut known = 0;
                for (h, &origin) in m.entries[..n].iter().zip(&m.origin_robot[..n]) {
                    if origin != self.args.robot_id
                        && p.learner.add_known_move(h.cell, usize::from(h.action))
                    {
                        known += 1;
                    }
                }
                self.c.moves_learned_from_others += known;
                continue;
            }
            if share && let Some(p) = phase.as_deref_mut() {
                let before = self.applier.counters().entries_applied;
                self.applier
                    .apply(m, p.learner.q_mut(), p.batcher.visits(), now);
                if self.applier.counters().entries_applied != before {
                    // the planning learner's sweeps carry the new values to their predecessors
                    p.learner.table_changed();
                    if p.shared_model {
                        // and back up the moves other robots made, as their own
                        let n = (m.count as usize).min(m.entries.len());
                        for (h, &origin) in m.entries[..n].iter().zip(&m.origin_robot[..n]) {
                            if origin != self.args.robot_id {
                                p.learner.add_known_move(h.cell, usize::from(h.action));
                            }
                        }
                    }
                }
            }
        }
        // discoveries of other robots, relayed by the coordinator (lossless: always drained)
        let grid = &self.base.grid;
        while let Some(r) = self.bus.relay.receive()? {
            self.c.relays_received += 1;
            if !self.args.share.share.discoveries()
                || r.origin_robot == self.args.robot_id
                || (r.cell_x as usize) >= grid.width()
                || (r.cell_y as usize) >= grid.height()
                || !r.value.is_finite()
            {
                continue;
            }
            let cell = grid.index(Cell::new(r.cell_x, r.cell_y)) as u32;
            self.relayed
                .entry(r.goal_id)
                .or_default()
                .push((cell, r.value));
            if let Some(p) = phase.as_deref_mut()
                && p.a.goal_id == r.goal_id
                && p.learner.add_pseudo_target(cell, r.value)
            {
                self.c.relays_applied += 1;
            }
        }
        while let Some(ack) = self.bus.ack.receive()? {
            if ack.robot_id != self.args.robot_id {
                continue;
            }
            if self.disc.on_ack(ack.up_to_seq) == AckOutcome::Rejected {
                self.c.rejected += 1; // acks something never sent
            }
            self.c.discoveries_acked = self.disc.acked();
        }
        while let Some((ctl, from)) = self.bus.recv_control_from()? {
            // a restarted coordinator's answer to our re-registration moves the gate to it
            if let Some(ev) = self.link.on_control(&ctl) {
                if ev == LinkEvent::Rejoined {
                    self.gate.accept(from);
                }
                self.on_link(ev)?;
                continue;
            }
            if self.gate.check(from) == Verdict::Drop {
                self.c.rejected += 1; // not from our coordinator: a forged or stale control
                continue;
            }
            match self.plan.on(&ctl) {
                Effect::Rejected => self.c.rejected += 1,
                // a restarted coordinator's plan for the phase we are in (or finished): that
                // phase goes on, with its discovery log and sequence numbers; a phase reported
                // already is reported again (the new coordinator never got it)
                Effect::Repeated => {
                    self.link.counters.plan_repeats += 1;
                    if let Some(p) = phase.as_deref_mut()
                        && p.reported
                        && p.a.phase == ctl.phase
                        && ctl.command == Command::AssignGoal.as_u8()
                    {
                        self.send_report(p)?;
                    }
                }
                _ => {}
            }
        }
        if self.stop.load(Ordering::Relaxed) {
            self.plan.stop();
        }
        Ok(())
    }
}
