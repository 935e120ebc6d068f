//! The robot's side of a coordinator-driven experiment (`robot-agent --experiment`).
//!
//! # Protocol
//! 1. Register as in a plain run.
//! 2. Before each phase `p` the coordinator sends `AssignGoal` to this robot (`goal_id`, goal
//!    cell, `phase = p`, `episodes`), then `Start` (phase 0) or `Phase` (later phases) to all.
//! 3. The robot learns `episodes` episodes towards its goal, sharing by `--share` (Q hints and
//!    discoveries tagged with the goal id), and stops the phase early after the episode whose
//!    greedy path is optimal when `--stop-at-optimum` is given.
//! 4. It flushes its hints, waits until its discoveries are acknowledged, writes
//!    `robot-<id>-phase-<p>.json` (the per-episode log the coordinator reads) and sends one
//!    `FinalReport` for the phase (`status` Finished, or Failed if stopped).
//! 5. Until the next `Phase` or `Stop` it keeps applying merged hints of its goal.
//!
//! # Q-tables per goal
//! The robot keeps one Q-table per goal. A phase starts a fresh learner (its schedule and
//! pseudo-target removal run over the phase's episodes) whose table is the robot's table for that
//! goal so far: coming back to a goal resumes what was learned. Relayed discoveries are kept per
//! goal and become pseudo targets of every later learner on that goal (`--share
//! discoveries|both`).

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::bus_schema::{Command, PseudoTargetDiscovery, Register, RobotStatus, SCHEMA_VERSION};
use bus::{BusConfig, BusError, RobotBus, check_nodes, monotonic_ns};
use hdrhistogram::Histogram;
use planner::task::Task;
use planner::{Cell, EpisodeRecord, Learner, QTable, Summary};
use report::hist::{LatencyStats, new_hist};
use report::{Counters, EndStatus, OutDir, OutFile, PhaseDetail, RobotResult};

use crate::agent::{AgentArgs, AgentError, ReportHead, final_report};
use crate::share::{ApplyCtx, HintBatcher, apply_merged};

struct Exp<'a> {
    args: &'a AgentArgs,
    bus: RobotBus,
    base: Task,
    tables: BTreeMap<u32, QTable>,
    relayed: BTreeMap<u32, Vec<(u32, f32)>>,
    c: Counters,
    disc_next: u64,
    unacked: VecDeque<(u64, PseudoTargetDiscovery, Instant)>,
    acked_up_to: Option<u64>,
    state_seq: u64,
    hint_seq: u64,
    last_merged_seq: Option<u64>,
    loop_hist: Histogram<u64>,
    stop: Arc<AtomicBool>,
    stopped: bool,
    /// Next phase to run (goal id, goal cell, phase, episodes), set by controls.
    assigned: Option<(u32, Cell, u32, u32)>,
    go: bool,
}

/// Runs one robot of an experiment to the coordinator's `Stop`.
pub fn run(args: &AgentArgs, stop: Arc<AtomicBool>) -> Result<RobotResult, AgentError> {
    let timeout = Duration::try_from_secs_f64(args.timeout)
        .ok()
        .filter(|d| !d.is_zero())
        .ok_or_else(|| AgentError::Input("--timeout must be positive".into()))?;
    args.share.validate().map_err(AgentError::Input)?;
    let base = args
        .map
        .task()
        .map_err(|e| AgentError::Input(e.to_string()))?;
    let cfg = args
        .learner
        .config()
        .map_err(|e| AgentError::Input(e.to_string()))?;
    let (Ok(width), Ok(height)) = (
        u16::try_from(base.grid.width()),
        u16::try_from(base.grid.height()),
    ) else {
        return Err(AgentError::Input(
            "maps larger than 65535 cells a side are not supported".into(),
        ));
    };
    if args.robot_id >= args.robots {
        return Err(AgentError::Input(format!(
            "--robot-id {} is outside 0..{}",
            args.robot_id, args.robots
        )));
    }
    let bus_cfg = BusConfig::new(args.run_id.clone(), args.robots)?;
    let bus = RobotBus::open(&bus_cfg, args.robot_id, timeout)?;
    let reg = Register {
        schema_version: args.schema_version_override.unwrap_or(SCHEMA_VERSION),
        robot_id: args.robot_id,
        pid: std::process::id(),
        episodes: cfg.episodes,
        width,
        height,
        start_x: base.start.x,
        start_y: base.start.y,
        map_hash: bus::bus_schema::map_fingerprint(
            base.grid.width(),
            base.grid.height(),
            base.grid.free_flags(),
        ),
        seed: cfg.seed,
        ..Register::ZEROED
    };
    match bus.register(&reg, timeout) {
        Ok(_) => {}
        Err(e @ BusError::Refused { .. }) => return Err(AgentError::Refused(e)),
        Err(e) => return Err(e.into()),
    }
    let mut e = Exp {
        args,
        bus,
        base,
        tables: BTreeMap::new(),
        relayed: BTreeMap::new(),
        c: Counters::default(),
        disc_next: 0,
        unacked: VecDeque::new(),
        acked_up_to: None,
        state_seq: 0,
        hint_seq: 0,
        last_merged_seq: None,
        loop_hist: new_hist(),
        stop,
        stopped: false,
        assigned: None,
        go: false,
    };
    let out = e.run_all(timeout);
    let closed = e.bus.close();
    let out = out?;
    closed?;
    Ok(out)
}

impl Exp<'_> {
    fn run_all(&mut self, timeout: Duration) -> Result<RobotResult, AgentError> {
        let mut last: Option<(PhaseDetail, f64)> = None;
        loop {
            // wait for an assignment and its Start/Phase
            let deadline = Instant::now() + timeout;
            let mut last_liveness = Instant::now();
            while !(self.stopped || (self.go && self.assigned.is_some())) {
                self.poll(None)?;
                if self.stopped || (self.go && self.assigned.is_some()) {
                    break;
                }
                let now = Instant::now();
                if now >= deadline {
                    return Err(BusError::Timeout {
                        what: "the coordinator's next phase or Stop".into(),
                        timeout,
                    }
                    .into());
                }
                if now.duration_since(last_liveness) >= Duration::from_millis(250) {
                    last_liveness = now;
                    let report = check_nodes(self.bus.config(), false)?;
                    if !report.alive().any(|n| n.name == "qfleet-coordinator") {
                        return Err(AgentError::CoordinatorGone(
                            self.bus.config().run_id.clone(),
                        ));
                    }
                }
                self.bus.control.wait(Duration::from_millis(2))?;
            }
            if self.stopped {
                break;
            }
            let Some((goal_id, cell, phase, episodes)) = self.assigned.take() else {
                continue;
            };
            self.go = false;
            let t0 = Instant::now();
            let detail = self.phase(goal_id, cell, phase, episodes, timeout)?;
            last = Some((detail, t0.elapsed().as_secs_f64()));
        }
        let (d, learn_s) = last.unwrap_or_else(|| {
            (
                PhaseDetail {
                    robot_id: self.args.robot_id,
                    phase: 0,
                    goal_id: 0,
                    start: self.base.start.to_string(),
                    goal: self.base.goal.to_string(),
                    episodes: 0,
                    env_steps: 0,
                    avg_steps: 0.0,
                    optimal_path_len: self.base.optimal_len,
                    final_path_len: None,
                    first_optimal_episode: None,
                    steps_to_optimal: None,
                    time_to_optimal_s: None,
                    start_ns: 0,
                    episode_end_ns: Vec::new(),
                    episode_cum_steps: Vec::new(),
                    discoveries_sent: 0,
                    relays_applied: 0,
                    hints_applied: 0,
                    finished: false,
                },
                0.0,
            )
        });
        Ok(RobotResult {
            robot_id: self.args.robot_id,
            status: if d.finished {
                EndStatus::Finished
            } else {
                EndStatus::Stopped
            },
            map: self.base.map_name.clone(),
            learner: self.args.learner.learner.to_string(),
            seed: self.args.learner.seed,
            goal_id: d.goal_id,
            start: d.start.clone(),
            goal: d.goal.clone(),
            episodes: d.episodes,
            optimal_path_len: d.optimal_path_len,
            final_path_len: d.final_path_len,
            own_final_path_len: d.final_path_len,
            avg_steps: d.avg_steps,
            max_steps: 0,
            first_optimal_episode: d.first_optimal_episode,
            env_steps: d.env_steps,
            outcomes: [0; 3],
            learn_s,
            share: self.args.share.share,
            counters: self.c,
            loop_latency_ns: LatencyStats::of(&self.loop_hist),
            merged_latency_ns: LatencyStats::default(),
        })
    }

    /// Takes in controls, merged hints (applied to `learner` if given), relays and acks.
    fn poll(
        &mut self,
        mut learner: Option<(&mut Learner, &mut HintBatcher, u32)>,
    ) -> Result<(), AgentError> {
        while let Some(sample) = self.bus.merged.receive_sample()? {
            if let Some((l, b, goal_id)) = learner.as_mut()
                && self.args.share.share.hints()
            {
                let ctx = ApplyCtx {
                    robot_id: self.args.robot_id,
                    robots: self.args.robots,
                    goal_id: *goal_id,
                    rule: self.args.share.apply,
                };
                apply_merged(
                    sample.payload(),
                    &ctx,
                    l.q_mut(),
                    b.visits(),
                    monotonic_ns(),
                    &mut self.loop_hist,
                    &mut self.last_merged_seq,
                    &mut self.c.merged,
                );
            }
        }
        while let Some(r) = self.bus.relay.receive()? {
            self.c.relays_received += 1;
            if !self.args.share.share.discoveries()
                || r.origin_robot == self.args.robot_id
                || (r.cell_x as usize) >= self.base.grid.width()
                || (r.cell_y as usize) >= self.base.grid.height()
                || !r.value.is_finite()
            {
                continue;
            }
            let cell = self.base.grid.index(Cell::new(r.cell_x, r.cell_y)) as u32;
            self.relayed
                .entry(r.goal_id)
                .or_default()
                .push((cell, r.value));
            if let Some((l, _, goal_id)) = learner.as_mut()
                && *goal_id == r.goal_id
                && l.add_pseudo_target(cell, r.value)
            {
                self.c.relays_applied += 1;
            }
        }
        while let Some(ack) = self.bus.ack.receive()? {
            if ack.robot_id != self.args.robot_id || ack.up_to_seq >= self.disc_next {
                continue;
            }
            if self.acked_up_to.is_none_or(|a| ack.up_to_seq > a) {
                self.acked_up_to = Some(ack.up_to_seq);
                self.c.discoveries_acked = ack.up_to_seq + 1;
                while self
                    .unacked
                    .front()
                    .is_some_and(|(s, _, _)| *s <= ack.up_to_seq)
                {
                    self.unacked.pop_front();
                }
            }
        }
        while let Some(ctl) = self.bus.recv_control()? {
            match Command::try_from(ctl.command) {
                Ok(Command::Stop) => self.stopped = true,
                Ok(Command::AssignGoal) => {
                    self.assigned = Some((
                        ctl.goal_id,
                        Cell::new(ctl.goal_x, ctl.goal_y),
                        ctl.phase,
                        ctl.episodes,
                    ));
                }
                Ok(Command::Start | Command::Phase) => self.go = true,
                Ok(_) => {}
                Err(_) => self.c.rejected += 1,
            }
        }
        if self.stop.load(Ordering::Relaxed) {
            self.stopped = true;
        }
        Ok(())
    }

    fn phase(
        &mut self,
        goal_id: u32,
        cell: Cell,
        phase: u32,
        episodes: u32,
        timeout: Duration,
    ) -> Result<PhaseDetail, AgentError> {
        let mut m = self.args.map.clone();
        m.goal = Some(cell);
        let task = m
            .task()
            .map_err(|e| AgentError::Input(format!("assigned goal {cell} is unusable: {e}")))?;
        let mut cfg = self
            .args
            .learner
            .config()
            .map_err(|e| AgentError::Input(e.to_string()))?;
        if episodes > 0 {
            cfg.episodes = episodes;
        }
        cfg.seed = cfg
            .seed
            .wrapping_add(u64::from(phase).wrapping_mul(0x9E37_79B9));
        let mut learner = Learner::new(&task, cfg).map_err(|e| AgentError::Input(e.to_string()))?;
        if let Some(q) = self.tables.get(&goal_id) {
            *learner.q_mut() = q.clone();
        }
        let mut relays_applied = 0;
        for &(c, v) in self.relayed.get(&goal_id).map_or(&[][..], |v| &v[..]) {
            relays_applied += u64::from(learner.add_pseudo_target(c, v));
        }
        let share = self.args.share.share.hints();
        let mut batcher = HintBatcher::new(
            task.grid.len(),
            self.args.share.hint_batch as usize,
            self.args.share.hint_min_change,
        );
        let poll_every = u64::from(self.args.share.poll_every);
        let flush_steps = u64::from(self.args.share.hint_flush_steps);
        let state_every = u64::from(self.args.share.state_every);
        let (relays0, hints0, disc0) = (
            self.c.relays_applied,
            self.c.merged.entries_applied,
            self.c.discoveries_sent,
        );
        let t0 = Instant::now();
        let start_ns = monotonic_ns();
        let mut records: Vec<EpisodeRecord> = Vec::new();
        let (mut end_ns, mut cum) = (Vec::new(), Vec::new());
        let mut steps: u64 = 0;
        let (mut steps_opt, mut time_opt) = (None, None);
        let optimal = learner.optimal_len();
        while !learner.finished() && !self.stopped {
            learner.begin_episode();
            loop {
                let info = learner.step();
                steps += 1;
                if share && batcher.note(info.state, info.action, info.q, steps, monotonic_ns) {
                    self.send_hints(&mut batcher, goal_id);
                }
                if steps.is_multiple_of(state_every) {
                    self.send_state(goal_id, learner.episodes_done(), RobotStatus::Running);
                }
                if steps.is_multiple_of(poll_every) {
                    if share && batcher.due(steps, flush_steps) {
                        self.send_hints(&mut batcher, goal_id);
                    }
                    self.poll(Some((&mut learner, &mut batcher, goal_id)))?;
                    if self.stopped {
                        break;
                    }
                }
                if info.done {
                    records.push(learner.end_episode(info.transition));
                    break;
                }
            }
            end_ns.push(monotonic_ns());
            cum.push(steps);
            for (c, v) in learner.take_new_pseudo_targets() {
                self.queue_discovery(goal_id, c, v, records.len() as u32);
            }
            self.resend_discoveries();
            if steps_opt.is_none() && learner.greedy_path_len() == Some(optimal) {
                steps_opt = Some(steps);
                time_opt = Some(t0.elapsed().as_secs_f64());
                if self.args.stop_at_optimum {
                    break;
                }
            }
        }
        if share && !batcher.is_empty() {
            self.send_hints(&mut batcher, goal_id);
        }
        let deadline = Instant::now() + timeout;
        while !self.unacked.is_empty() && !self.stop.load(Ordering::Relaxed) {
            self.poll(Some((&mut learner, &mut batcher, goal_id)))?;
            self.resend_discoveries();
            if Instant::now() >= deadline {
                break;
            }
            self.bus.ack.wait(Duration::from_millis(5))?;
        }
        let finished = !self.stopped;
        let final_len = learner.greedy_path_len();
        let s = Summary::from_records(&records, optimal, final_len);
        self.tables.insert(goal_id, learner.q().clone());
        let d = PhaseDetail {
            robot_id: self.args.robot_id,
            phase,
            goal_id,
            start: task.start.to_string(),
            goal: task.goal.to_string(),
            episodes: s.episodes,
            env_steps: s.env_steps,
            avg_steps: s.avg_steps,
            optimal_path_len: optimal,
            final_path_len: final_len,
            first_optimal_episode: s.first_optimal_episode,
            steps_to_optimal: steps_opt,
            time_to_optimal_s: time_opt,
            start_ns,
            episode_end_ns: end_ns,
            episode_cum_steps: cum,
            discoveries_sent: self.c.discoveries_sent - disc0,
            relays_applied: self.c.relays_applied - relays0 + relays_applied,
            hints_applied: self.c.merged.entries_applied - hints0,
            finished,
        };
        if let Some(dir) = &self.args.out {
            let dir = OutDir::new(dir);
            dir.create()?;
            let robot = self.args.robot_id;
            dir.write_json(OutFile::RobotPhase { robot, phase }, &d)?;
        }
        self.send_state(goal_id, s.episodes, RobotStatus::Finished);
        let head = ReportHead {
            robot_id: self.args.robot_id,
            goal_id,
            final_path_len: final_len,
            optimal_path_len: optimal,
        };
        let rep = final_report(head, &s, finished, t0, &self.c, &self.loop_hist);
        match self.bus.report.send_and_notify(&rep) {
            Ok(_) | Err(BusError::NoSubscriber { .. }) if self.stopped => {}
            Ok(_) => {}
            Err(e) => return Err(e.into()),
        }
        Ok(d)
    }

    fn send_state(&mut self, goal_id: u32, episode: u32, status: RobotStatus) {
        let (robot_id, seq) = (self.args.robot_id, self.state_seq);
        self.state_seq += 1;
        let sent = self.bus.state.send_with(|m| {
            m.robot_id = robot_id;
            m.goal_id = goal_id;
            m.episode = episode;
            m.status = status.as_u8();
            m.seq = seq;
            m.send_time_ns = monotonic_ns();
        });
        match sent {
            Ok(_) => self.c.states_sent += 1,
            Err(_) => self.c.send_errors += 1,
        }
    }

    fn send_hints(&mut self, batcher: &mut HintBatcher, goal_id: u32) {
        let (robot_id, seq) = (self.args.robot_id, self.hint_seq);
        self.hint_seq += 1;
        let mut n = 0;
        let sent = self.bus.hints.send_batch(|b| {
            b.robot_id = robot_id;
            b.goal_id = goal_id;
            b.seq = seq;
            n = batcher.fill(b);
            b.send_time_ns = monotonic_ns();
        });
        if n == 0 {
            batcher.clear_shared();
        }
        match sent {
            Ok(_) => {
                self.c.hint_batches_sent += 1;
                self.c.hint_entries_sent += n as u64;
                let _ = self.bus.hints.notify();
            }
            Err(_) => self.c.send_errors += 1,
        }
    }

    fn queue_discovery(&mut self, goal_id: u32, cell: u32, value: f32, episode: u32) {
        let c = self.base.grid.cell(cell as usize);
        let seq = self.disc_next;
        self.disc_next += 1;
        let d = PseudoTargetDiscovery {
            robot_id: self.args.robot_id,
            goal_id,
            cell_x: c.x,
            cell_y: c.y,
            value,
            seq,
            time_ns: monotonic_ns(),
            episode,
            ..PseudoTargetDiscovery::ZEROED
        };
        self.c.discoveries_sent += 1;
        if self
            .bus
            .discovery
            .send_with(|m| {
                *m = d;
                m.send_time_ns = monotonic_ns();
            })
            .is_err()
        {
            self.c.discovery_send_errors += 1;
        }
        self.unacked.push_back((seq, d, Instant::now()));
        let _ = self.bus.discovery.notify();
    }

    fn resend_discoveries(&mut self) {
        if crate::agent::resend_due(&self.bus, &mut self.unacked, &mut self.c) {
            let _ = self.bus.discovery.notify();
        }
    }
}
