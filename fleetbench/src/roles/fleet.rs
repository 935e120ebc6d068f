//! Roles on the real fleet path: the real coordinator process (`qfleet-coordinator`, with its own wait
//! strategies and merge), the two-robot loop process, and the scale benchmark's robots.
//!
//! Robots here are lightweight: no learner. They make Q updates with [`super::Updates`], batch
//! them with the robot-agent's own `HintBatcher` (crate `sharing`), send them with the `bus` crate exactly as
//! `robot-agent` does (`send_batch` + `fill`, then `notify`), and apply merged hints with the
//! robot-agent's own `MergedApplier::apply` into a `planner::QTable`, which records the end-to-end
//! latency (origin time of the update → applied) in the histogram this harness reports.

use std::process::{Command as Process, Stdio};
use std::time::{Duration, Instant};

use bus::bus_schema::{
    Command, FinalReport, QHintBatch, Register, RobotState, RobotStatus, SCHEMA_VERSION,
};
use bus::{BusConfig, RobotBus, monotonic_ns};
use contract::ApplyRule;
use contract::CoordArgs;
use contract::coordinator::MergeRule;
use planner::QTable;
use planner::task::Task;
use qfleet_args::MapArgs;
use report::{OutDir, OutFile, RobotOutcome, RunResult};
use sharing::{ApplyCtx, HintBatcher, MergedApplier};

use super::{Deadline, Updates, Window, idle_peer_cpu, save, window_ns};
use crate::BenchError;
use crate::spec::{ChildReport, RoleSpec};

fn map_args(map: &str) -> MapArgs {
    MapArgs {
        map: map.to_string(),
        start: None,
        goal: None,
        scen: None,
        scen_index: None,
    }
}

/// Loads the map every process of a fleet row uses.
pub(crate) fn task(map: &str) -> Result<Task, BenchError> {
    map_args(map)
        .task()
        .map_err(|e| BenchError::Input(format!("map {map}: {e}")))
}

/// Runs the real coordinator process (`qfleet-coordinator`, found beside this executable and
/// bound to it like the launcher's children) until its robots finished; reports its CPU.
pub fn coordinator(spec: &RoleSpec) -> Result<ChildReport, BenchError> {
    let RoleSpec::Coordinator {
        run_id,
        robots,
        wait,
        spin_us,
        map,
        out,
        timeout_s,
    } = spec
    else {
        return Err(BenchError::Spec("not a coordinator spec".into()));
    };
    let mut args = CoordArgs::new(run_id.clone(), out.clone());
    args.robots = *robots;
    args.map = map_args(map);
    args.wait = *wait;
    args.spin_us = *spin_us;
    args.merge = MergeRule::Max;
    args.timeout = *timeout_s;
    // the bench robots send no heartbeat states while they measure
    args.hang_ms = 600_000;
    let bin = launcher::spawn::sibling("qfleet-coordinator")
        .map_err(|e| BenchError::Coordinator(e.to_string()))?;
    let mut cmd = Process::new(&bin);
    cmd.args(args.to_args()).stdout(Stdio::null());
    launcher::spawn::bind_to_launcher(&mut cmd);
    let t = Window::start(None);
    let cpu0 = crate::cpu::children_cpu_ns();
    let status = cmd
        .spawn()
        .and_then(|mut c| c.wait())
        .map_err(|e| BenchError::Coordinator(format!("{}: {e}", bin.display())))?;
    let mut r = ChildReport::default();
    t.finish(&mut r);
    // the role process only waited: the coordinator's CPU is its child's
    r.self_cpu_ns = crate::cpu::children_cpu_ns().saturating_sub(cpu0);
    // 4: the run completed but a robot's report did not count; the merge figures are complete
    // all the same, and the row says how many reports counted (`reports`)
    if !matches!(status.code(), Some(0 | 4)) {
        return Err(BenchError::Coordinator(format!(
            "qfleet-coordinator ended with {status} (its result, if any, is in {})",
            out.display()
        )));
    }
    let result: RunResult = OutDir::new(out)
        .read_json(OutFile::Result)
        .map_err(|e| BenchError::Coordinator(e.to_string()))?;
    r.samples = result.throughput.q_updates_merged;
    r.merged_per_s = result.throughput.q_updates_merged_per_s;
    r.reports = result
        .robots
        .iter()
        .filter(|x| matches!(x.status, RobotOutcome::Finished | RobotOutcome::Stopped))
        .count() as u64;
    r.without_path = result.without_path.len() as u64;
    r.rejected = result.rejected;
    Ok(r)
}

/// Opens, registers and starts one robot of a fleet row.
fn join(
    cfg: &BusConfig,
    task: &Task,
    robot_id: u32,
    timeout: Duration,
) -> Result<RobotBus, BenchError> {
    let bus = RobotBus::open(cfg, robot_id, timeout)?;
    let reg = Register {
        schema_version: SCHEMA_VERSION,
        robot_id,
        pid: std::process::id(),
        episodes: 1,
        width: task.grid.width() as u16,
        height: task.grid.height() as u16,
        start_x: task.start.x,
        start_y: task.start.y,
        map_hash: bus_schema::map_fingerprint(
            task.grid.width(),
            task.grid.height(),
            task.grid.free_flags(),
        ),
        seed: u64::from(robot_id),
        ..Register::ZEROED
    };
    bus.register(&reg, timeout)?;
    Ok(bus)
}

fn wait_start(bus: &RobotBus, timeout: Duration) -> Result<bool, BenchError> {
    let ctl = bus.wait_start(timeout, |_| {})?;
    Ok(ctl.command == Command::Start.as_u8())
}

/// Sends the batcher's pending entries exactly like the robot-agent does.
#[inline]
fn send_hints(
    bus: &RobotBus,
    batcher: &mut HintBatcher,
    seq: u64,
    notify: bool,
) -> Result<usize, BenchError> {
    let robot_id = bus.robot_id();
    let mut n = 0;
    bus.hints.send_batch(|b: &mut QHintBatch| {
        b.robot_id = robot_id;
        b.goal_id = 0;
        b.seq = seq;
        n = batcher.fill(b);
        b.send_time_ns = monotonic_ns();
    })?;
    if notify {
        bus.hints.notify()?;
    }
    Ok(n)
}

/// Tells the coordinator these robots are done, waits for its `Stop` (merged hints meanwhile
/// are latest-wins and may be left unread), sends each final report and closes. The report is
/// an honest "no path yet": these robots learn nothing and compute no optimum (both −1), which
/// the coordinator accepts and lists in its result's `without_path`.
fn finish(buses: Vec<RobotBus>, timeout: Duration) -> Result<(), BenchError> {
    for bus in &buses {
        bus.state.send(&RobotState {
            robot_id: bus.robot_id(),
            status: RobotStatus::Finished.as_u8(),
            send_time_ns: monotonic_ns(),
            ..RobotState::ZEROED
        })?;
        bus.state.notify()?;
    }
    for bus in &buses {
        bus.wait_control(timeout, |c| c.command == Command::Stop.as_u8())?;
        bus.report.send(&FinalReport {
            robot_id: bus.robot_id(),
            schema_version: SCHEMA_VERSION,
            episodes: 1,
            status: RobotStatus::Finished.as_u8(),
            final_path_len: -1,
            optimal_path_len: -1,
            first_optimal_episode: -1,
            send_time_ns: monotonic_ns(),
            ..FinalReport::ZEROED
        })?;
        bus.report.notify()?;
    }
    for bus in buses {
        bus.close()?;
    }
    Ok(())
}

/// How long the loop waits for one update's merged answer before it counts the round trip as
/// lost and sends the next update. Hints and merged batches are latest-wins: one dropped (a full
/// buffer, or a bridge that held latest-wins frames back while its link looked down) has no
/// answer, and waiting on it stopped cross-host rows with "no answer within 10000 ms".
pub const LOOP_RETRY: Duration = Duration::from_millis(250);

/// The update loop, closed: robot 0 makes one Q update and sends it as a one-entry hint
/// batch; the coordinator merges it and publishes a merged batch; robot 1 (same process)
/// applies it; the next update is made once it was applied, or after [`LOOP_RETRY`] without
/// an answer (counted in `batches_lost`, not a sample).
pub fn loop_robots(spec: &RoleSpec) -> Result<ChildReport, BenchError> {
    let RoleSpec::LoopRobots {
        run_id,
        map,
        notify,
        plan,
        peer_pid,
        hist_path,
    } = spec
    else {
        return Err(BenchError::Spec("not a loop-robots spec".into()));
    };
    let timeout = Duration::from_millis(plan.timeout_ms);
    let task = task(map)?;
    let cells = task.grid.len() as u32;
    let cfg = BusConfig::new(run_id.clone(), 2)?;
    let r0 = join(&cfg, &task, 0, timeout)?;
    let r1 = join(&cfg, &task, 1, timeout)?;
    if !(wait_start(&r0, timeout)? && wait_start(&r1, timeout)?) {
        return Err(BenchError::Coordinator("stopped before the start".into()));
    }
    let mut batcher = HintBatcher::new(cells as usize, 1, 1e-3);
    let mut q1 = QTable::new(&task.grid);
    let visits1 = vec![0u16; cells as usize * 4];
    let mut applier = MergedApplier::new(ApplyCtx::second_of_two());
    let updates = Updates::new(cells, 64, 0);
    // no answer at all for `timeout` (every retry included) ends the row with an error
    let mut deadline = Deadline::new(timeout, "the coordinator's merged hint", Some(*peer_pid));
    let mut window = None;
    let mut lost = 0;
    let mut i = 0;
    // `n`: updates sent, so that a retried sample is a new update (a new value to merge)
    let mut n = 0;
    while plan.more(i, || window_ns(&window)) {
        if i == plan.warmup && window.is_none() {
            // across hosts: the bridge's and Zenoh's threads away from this busy-polling one
            crate::cpu::keep_apart();
            window = Some(Window::start(Some(*peer_pid)));
            applier.clear_loop_hist(); // warm-up samples are not reported
            lost = 0;
        }
        let (cell, action, q) = updates.get(n, cells);
        batcher.note(cell, action, q, n, monotonic_ns);
        send_hints(&r0, &mut batcher, n, *notify)?;
        n += 1;
        // robot 1 polls its inbox until the merged hint is applied
        let seen = applier.counters().entries_seen;
        let asked = Instant::now();
        let mut spins: u32 = 0;
        let mut answered = true;
        while applier.counters().entries_seen == seen {
            match r1.merged.receive_sample()? {
                Some(sample) => applier.apply(sample.payload(), &mut q1, &visits1, monotonic_ns()),
                None => {
                    spins = spins.wrapping_add(1);
                    if spins.is_multiple_of(4096) {
                        deadline.check()?;
                        if asked.elapsed() >= LOOP_RETRY {
                            answered = false;
                            break;
                        }
                    }
                    core::hint::spin_loop();
                }
            }
        }
        // robot 0 sees the same broadcast (its own values: skipped by a real robot)
        while r0.merged.receive_sample()?.is_some() {}
        if answered {
            deadline.reset();
            i += 1;
        } else {
            lost += 1;
        }
    }
    let h = applier.loop_hist();
    let mut r = ChildReport {
        samples: h.len(),
        merged_seen: applier.counters().entries_seen,
        batches_lost: lost,
        ..ChildReport::default()
    };
    if let Some(w) = &window {
        w.finish(&mut r);
    }
    r.peer_idle_cpu_pct = idle_peer_cpu(*peer_pid, plan.idle_ms);
    save(h, hist_path)?;
    finish(vec![r0, r1], timeout)?;
    Ok(r)
}

/// One robot of the scale benchmark: for `duration_ms` after Start, makes Q updates as fast
/// as it can, sends them in batches of `batch` entries (notifying after each, like the
/// robot-agent), and applies every merged batch it finds. Flow control: with `in_flight`
/// batches not yet seen merged (an entry of its own in a merged batch acknowledges every batch
/// up to that entry's origin time) it stops sending, spins 50 µs and then yields its CPU; after 20 ms without
/// progress it counts the oldest batch as lost and goes on.
pub fn scale_robot(spec: &RoleSpec) -> Result<ChildReport, BenchError> {
    let RoleSpec::ScaleRobot {
        run_id,
        map,
        robot_id,
        robots,
        batch,
        duration_ms,
        in_flight,
        notify_gap_us,
        timeout_ms,
        peer_pid,
        hist_path,
    } = spec
    else {
        return Err(BenchError::Spec("not a scale-robot spec".into()));
    };
    let timeout = Duration::from_millis(*timeout_ms);
    let task = task(map)?;
    let cells = task.grid.len() as u32;
    let cfg = BusConfig::new(run_id.clone(), *robots)?;
    let bus = join(&cfg, &task, *robot_id, timeout)?;
    if !wait_start(&bus, timeout)? {
        return Err(BenchError::Coordinator("stopped before the start".into()));
    }
    let mut batcher = HintBatcher::new(cells as usize, *batch as usize, 1e-3);
    let mut q = QTable::new(&task.grid);
    let ctx = ApplyCtx {
        robot_id: *robot_id,
        robots: *robots,
        goal_id: 0,
        rule: ApplyRule::Max,
    };
    // each robot owns a stretch of batch/4 cells (disjoint when the map is large enough), so
    // every batch changes the fleet table and comes back as merged entries of its own
    let span = (*batch).div_ceil(4).max(1);
    let updates = Updates::new(cells, span, robot_id.wrapping_mul(span));
    let mut applier = MergedApplier::new(ctx);
    let mut r = ChildReport::default();
    let mut pending: std::collections::VecDeque<u64> = std::collections::VecDeque::new();
    let mut acked_ns = 0u64;
    let window = Window::start(*peer_pid);
    let end = Instant::now() + Duration::from_millis(*duration_ms);
    let mut stalled_since: Option<Instant> = None;
    let (mut i, mut seq) = (0u64, 0u64);
    let me = *robot_id;
    let notify_gap = Duration::from_micros(*notify_gap_us);
    let mut last_notify = Instant::now() - notify_gap;
    loop {
        let now = Instant::now();
        if now >= end {
            break;
        }
        // take in merged hints: apply them, and see which of our batches arrived
        while let Some(sample) = bus.merged.receive_sample()? {
            let m = sample.payload();
            let n = (m.count as usize).min(m.origin_robot.len());
            for k in 0..n {
                if m.origin_robot[k] == me {
                    acked_ns = acked_ns.max(m.origin_ns[k]);
                }
            }
            applier.apply(m, &mut q, batcher.visits(), monotonic_ns());
        }
        while pending.front().is_some_and(|t| *t <= acked_ns) {
            pending.pop_front();
            stalled_since = None;
        }
        if pending.len() >= *in_flight as usize {
            let waited = now.duration_since(*stalled_since.get_or_insert(now));
            if waited >= Duration::from_millis(20) {
                pending.pop_front();
                r.batches_lost += 1;
                stalled_since = None;
            } else if waited < Duration::from_micros(50) {
                // the answer usually comes within a few µs: spin, then give the CPU away
                core::hint::spin_loop();
            } else {
                std::thread::yield_now();
            }
            continue;
        }
        for _ in 0..*batch {
            let (cell, action, v) = updates.get(i, cells);
            i += 1;
            if batcher.note(cell, action, v, i, monotonic_ns) {
                break;
            }
        }
        if !batcher.is_empty() {
            let mut oldest = 0;
            let robot_id = bus.robot_id();
            let mut n = 0;
            bus.hints.send_batch(|b: &mut QHintBatch| {
                b.robot_id = robot_id;
                b.seq = seq;
                n = batcher.fill(b);
                oldest = b.oldest_update_ns;
                b.send_time_ns = monotonic_ns();
            })?;
            if *notify_gap_us == 0 || now.duration_since(last_notify) >= notify_gap {
                bus.hints.notify()?;
                last_notify = now;
            }
            pending.push_back(oldest);
            r.updates_sent += n as u64;
            r.batches_sent += 1;
            seq += 1;
        }
    }
    window.finish(&mut r);
    r.samples = applier.loop_hist().len();
    r.merged_seen = applier.counters().entries_seen;
    save(applier.loop_hist(), hist_path)?;
    finish(vec![bus], timeout)?;
    Ok(r)
}
