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
//!
//! # Where what is
//! This file holds the robot and a phase, and drives the plan: register, wait for the next
//! phase, open it, learn it (`robot/learning.rs`), end and close it. What it takes in is in
//! `inbox.rs`, what it sends in `outbox.rs`, its results and reports in `results.rs`, its files
//! in `files.rs`, and moving on a shared grid in `shared_grid.rs`.

mod files;
mod inbox;
mod learning;
mod outbox;
mod results;
mod shared_grid;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::Origin;
use bus::bus_schema::{Register, RobotStatus, SCHEMA_VERSION, map_fingerprint};
use bus::{BusConfig, BusError, RobotBus, monotonic_ns};
use hdrhistogram::Histogram;
use planner::task::Task;
use planner::{EpisodeRecord, Learner, LearnerConfig, QTable};
use report::hist::new_hist;
use report::{Counters, RobotResult};

use crate::args::AgentArgs;
use crate::discovery::{DISCOVERY_RESEND, DiscoveryLog};
use crate::error::AgentError;
use crate::experiment::{Assignment, Effect, Plan};
use crate::gate::ControlGate;
use crate::pace::Pacer;
use crate::reconnect::{Link, handshake};
use sharing::{ApplyCtx, HintBatcher, MergedApplier};

/// How often a robot waiting for the next phase or `Execute` propagates merged hints that
/// arrived meanwhile ([`Learner::settle`], nothing to do when none did).
const SETTLE_WHILE_WAITING: Duration = Duration::from_millis(50);

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
        last_goal: None,
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
    /// The goal of the last phase opened: where a `--chain-goals` robot learns the next from.
    last_goal: Option<planner::Cell>,
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
    /// What moving on a shared grid ranks with, made while the robot waits for `Execute`
    /// (see [`crate::execute::Prepared`]); `None` until then, or since the values changed.
    /// With the count of merged-hint entries applied when it was made (more since: stale).
    prepared: Option<(crate::execute::Prepared, u64)>,
    /// `Execute` came for this phase: its first tick is granted or past, so the early answer
    /// to it is not sent again ([`crate::execute::early_answer_due`]).
    executed: bool,
}

impl Phase {
    /// What moving on a shared grid ranks with, from the learner's values now.
    fn prepare(&self) -> crate::execute::Prepared {
        crate::execute::Prepared::new(
            &self.task,
            self.learner.q(),
            self.learner.tried_pairs(),
            self.learner.config().gamma,
        )
    }
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
        // the first look at once: the early answer to a shared grid's first tick goes out as
        // soon as the robot waits
        let mut settled: Option<Instant> = None;
        loop {
            self.poll(last.as_deref_mut())?;
            // merged hints applied while waiting are propagated now, a few times a second, not
            // when `Execute` comes: the shared grid's first tick waits for the slowest robot's
            // first answer, and 64 robots settling at once on two cores took it to tens of ms
            if let Some(p) = last.as_deref_mut()
                && settled.is_none_or(|t| t.elapsed() >= SETTLE_WHILE_WAITING)
            {
                settled = Some(Instant::now());
                // and what `Execute` would rank with, made now for the same reason
                self.prepare_execution(p);
            }
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

    /// A learner for assignment `a`, resuming the robot's table of that goal.
    fn open_phase(&mut self, a: Assignment) -> Result<Phase, AgentError> {
        // `--chain-goals`: learned from where the robot will stand, the last phase's goal
        let from = self.last_goal.filter(|_| self.args.chain_goals);
        let task = match (a.goal, from) {
            (None, None) => self.base.clone(),
            (Some(cell), None) if cell == self.base.goal => self.base.clone(),
            (goal, _) => {
                let cell = goal.unwrap_or(self.base.goal);
                let mut m = self.args.map.clone();
                m.goal = Some(cell);
                if from.is_some() {
                    m.start = from;
                }
                m.task()
                    .map_err(|source| AgentError::Goal { cell, source })?
            }
        };
        self.last_goal = Some(task.goal);
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
            relays += u64::from(learner.add_discovery(c, v));
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
            // a lifelong robot (`--chain-goals`) learns one known map among robots that all
            // learn other goals: their moves teach it nothing, and reading them would cost it
            // every other goal's warm start
            shared_model: min_sharing && cfg.extras.needs_model() && !self.args.chain_goals,
            prepared: None,
            executed: false,
        })
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
}
