//! The coordinator as the authority of a shared grid (`--world shared`): after every robot
//! learned its own goal, it drives the execution tick by tick and keeps the fleet free of
//! collisions. The robot's side of the protocol is `robot_agent::execute`.
//!
//! The execution's first look-ahead plan is made before it, while the robots learn, on a
//! thread of its own (`prepare_while`); the execution waits for it if they finish first.
//!
//! # A tick
//! 1. Publish a `Grant` with every robot's cell at tick `t` (tick 0: the starts) and wake the
//!    robots.
//! 2. Collect one `Intent` per robot on the grid ([`Round`]): its moves ranked by its own
//!    learned values. Each is checked ([`accept`]): the sender is the robot's own node, the tick
//!    is `t`, the cell is where the coordinator put the robot, the move codes are valid.
//!
//!    With an intent horizon (`--intent-horizon H`, carried in `Execute`'s `episodes`), a robot
//!    answers with an `IntentHorizon` instead: its rankings for every cell it may reach within
//!    `r` ticks ([`accept_horizon`], kept in [`Horizons`]). Every tick the horizon still
//!    answers ([`Coverage::answers`]), at the cell the robot stands on, is taken from there
//!    without asking; the grant wakes the robots only when some robot on the grid has to
//!    answer anew (robots align their horizons, so that is at most once per `H + 1` ticks) and
//!    at the end. Only robots that moved off the center of their last full horizon answer
//!    then: one parked on its goal or queued behind another keeps its horizon.
//!
//!    Tick 0 is usually answered before it: robots started with `--shared-grid` send their
//!    first horizon while they wait for `Execute` (`robot_agent::execute`, "The first tick,
//!    answered early"); those sent since the phase began (the engine's `phase_ns`) are kept
//!    when the execution starts, and the first grant wakes nobody when they answer it.
//! 3. When every robot on the grid answered, or the rest are past the heartbeat deadline
//!    (`--hang-ms`; they are *hung*: obstacles that wait and are never pushed, not waited for
//!    again until they answer), resolve the tick with [`mapf::World`] (PIBT on the intents, a
//!    look-ahead plan, a complete search when it stalls) and go on with `t + 1`.
//!
//! The execution ends when every robot on the grid stands on its goal (`Arrived`), when the
//! resolver proves no plan exists (`Unsolvable`), at `--max-ticks`, or on a stop request; the
//! last grant says so. A robot whose process dies (the liveness listing) leaves the grid: its
//! cell is free from the next tick, and it counts as not arrived.
//!
//! The executed paths are checked again by [`mapf::check`](mod@mapf::check), code that shares nothing with the
//! resolver: the vertex and swap conflicts it finds among the robots that stayed on the grid are
//! the result's `conflicts` (0 unless something is broken). A robot that left stays on its last
//! cell in `paths.txt` (the format has no "gone"), where others may pass later.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::bus_schema::{
    self, Command, GRANT_CAP, Grant, GridState, HORIZON_CELLS, HORIZON_RADIUS_CAP, IntentHorizon,
    ROBOT_ID_ALL,
};
use bus::iceoryx2::prelude::*;
use bus::{CoordinatorBus, Lister, SendError, monotonic_ns};
use hdrhistogram::Histogram;
use mapf::horizon::{diamond_len, unpack};
use mapf::{Coverage, Instance, Status, World, WorldConfig};
use planner::Cell;
use report::hist::{new_hist, record};
use report::{GridEnd, GridResult, GridRobot, LatencyStats, OutDir, OutFile};

use crate::admission::Sender;
use crate::engine::{Engine, tolerate};
use crate::options::CoordError;

/// The coordinator's nap between two looks at the intent inbox while it collects a tick.
const POLL_NAP: Duration = Duration::from_micros(50);

/// A shared-grid execution to drive: the instance and its limits.
#[derive(Debug, Clone)]
pub struct GridPlan {
    /// Starts, goals and the map.
    pub instance: Instance,
    /// Ticks after which the execution ends even if robots are under way.
    pub max_ticks: u32,
    /// The scenario file, for the result.
    pub scen: Option<String>,
    /// Shortest time per tick (`--tick-ms`: a pace a person can follow; zero: none).
    pub tick_min: Duration,
    /// The intent horizon asked of the robots (`--intent-horizon`; 0: one intent per tick).
    pub horizon: u8,
    /// The paths file to write into the out directory: `paths.txt` for a run,
    /// `paths-phase-<p>.txt` for phase `p` of an experiment.
    pub paths: OutFile,
}

impl GridPlan {
    /// The default tick limit of `instance`: room for every robot to go the longest way several
    /// times over and for the resolver's detours, never endless.
    pub fn default_max_ticks(instance: &Instance) -> u32 {
        let longest = (0..instance.agents())
            .map(|a| instance.dist_from(a, instance.starts()[a]))
            .filter(|&d| d != u32::MAX)
            .max()
            .unwrap_or(0);
        longest
            .saturating_mul(8)
            .saturating_add(4 * instance.agents() as u32)
            .saturating_add(256)
    }
}

/// Why an intent was not taken.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reject {
    /// A robot id outside the fleet.
    Robot(u32),
    /// The intent answers another tick (an old one, or a forged one).
    Tick {
        /// The tick being collected.
        want: u32,
        /// The intent's.
        got: u32,
    },
    /// The robot says it stands elsewhere than the coordinator put it.
    Cell {
        /// The coordinator's record.
        want: Cell,
        /// The intent's.
        got: Cell,
    },
    /// The robot is not on the grid (it left).
    Absent(u32),
    /// Bad move codes.
    Moves(mapf::IntentError),
    /// A horizon past the wire's capacity.
    Radius(u8),
    /// A horizon with rankings past its diamond (they must be zero).
    Tail(usize),
}

/// Checks one intent against the tick being collected and the coordinator's positions; the
/// robot and its ranked moves if it holds.
pub fn accept(
    m: &bus_schema::Intent,
    tick: u32,
    positions: &[Option<Cell>],
) -> Result<(usize, mapf::Intent), Reject> {
    let id = m.robot_id as usize;
    let Some(at) = positions.get(id) else {
        return Err(Reject::Robot(m.robot_id));
    };
    let Some(at) = *at else {
        return Err(Reject::Absent(m.robot_id));
    };
    if m.tick != tick {
        return Err(Reject::Tick {
            want: tick,
            got: m.tick,
        });
    }
    let got = Cell::new(m.cell_x, m.cell_y);
    if got != at {
        return Err(Reject::Cell { want: at, got });
    }
    let n = usize::from(m.count).min(m.ranked.len());
    let intent = mapf::Intent::from_bytes(&m.ranked[..n]).map_err(Reject::Moves)?;
    Ok((id, intent))
}

/// Checks one horizon against the tick being collected and the coordinator's positions; its
/// robot and coverage if it holds, with its rankings unpacked into `out` (the first
/// `diamond_len(radius)` entries).
///
/// A horizon answers the tick being collected if it was made for it (its center must then be
/// the robot's cell), or for an earlier tick it still answers on the fleet's horizon `h`
/// ([`Coverage::answers`]: a robot that answered late); one that no longer answers it is late
/// (`Reject::Tick` with `got < want`), one for a tick not granted yet is refused.
pub fn accept_horizon(
    m: &IntentHorizon,
    h: u8,
    tick: u32,
    positions: &[Option<Cell>],
    out: &mut [mapf::Intent; HORIZON_CELLS],
) -> Result<(usize, Coverage), Reject> {
    let id = m.robot_id as usize;
    let Some(at) = positions.get(id) else {
        return Err(Reject::Robot(m.robot_id));
    };
    let Some(at) = *at else {
        return Err(Reject::Absent(m.robot_id));
    };
    if m.radius > HORIZON_RADIUS_CAP {
        return Err(Reject::Radius(m.radius));
    }
    let center = Cell::new(m.cell_x, m.cell_y);
    let cov = Coverage {
        from: m.tick,
        center,
        radius: m.radius,
    };
    if m.tick > tick {
        return Err(Reject::Tick {
            want: tick,
            got: m.tick,
        });
    }
    if m.tick == tick && center != at {
        return Err(Reject::Cell {
            want: at,
            got: center,
        });
    }
    if cov.answers(h, tick, at).is_none() {
        // made for an earlier tick it no longer answers: late, not wrong
        return Err(Reject::Tick {
            want: tick,
            got: m.tick,
        });
    }
    let n = diamond_len(m.radius);
    if let Some(i) = m.ranked[n..].iter().position(|&b| b != 0) {
        return Err(Reject::Tail(n + i));
    }
    for (slot, &bits) in out.iter_mut().zip(&m.ranked[..n]) {
        *slot = unpack(bits).map_err(Reject::Moves)?;
    }
    Ok((id, cov))
}

/// Every robot's last horizon: its coverage and its rankings per diamond cell (IO-free; sized
/// once, a tick allocates nothing).
#[derive(Debug, Clone)]
pub struct Horizons {
    /// The fleet's horizon (`Execute`'s), which decides how long a horizon answers.
    h: u8,
    cover: Vec<Option<Coverage>>,
    ranks: Vec<[mapf::Intent; HORIZON_CELLS]>,
    /// Where [`accept_horizon`] unpacks before the horizon is kept.
    pub scratch: [mapf::Intent; HORIZON_CELLS],
}

impl Horizons {
    /// Room for `robots` robots on the fleet's horizon `h`, none with a horizon yet.
    pub fn new(robots: usize, h: u8) -> Self {
        Horizons {
            h,
            cover: vec![None; robots],
            ranks: vec![[mapf::Intent::NONE; HORIZON_CELLS]; robots],
            scratch: [mapf::Intent::NONE; HORIZON_CELLS],
        }
    }

    /// Keeps robot `id`'s horizon `cov` with the rankings in [`scratch`](Self::scratch).
    pub fn keep(&mut self, id: usize, cov: Coverage) {
        if let (Some(c), Some(r)) = (self.cover.get_mut(id), self.ranks.get_mut(id)) {
            *c = Some(cov);
            r.copy_from_slice(&self.scratch);
        }
    }

    /// Forgets robot `id`'s horizon (it left the grid).
    pub fn forget(&mut self, id: usize) {
        if let Some(c) = self.cover.get_mut(id) {
            *c = None;
        }
    }

    /// Robot `id`'s ranking for `tick` standing on `cell`, if its horizon answers it
    /// ([`Coverage::answers`]).
    pub fn intent_at(&self, id: usize, tick: u32, cell: Cell) -> Option<mapf::Intent> {
        let cov = (*self.cover.get(id)?)?;
        let i = cov.answers(self.h, tick, cell)?;
        Some(self.ranks[id][i])
    }
}

/// The intents of one tick as they come in: who answered, who is waited for, who is hung.
#[derive(Debug, Clone)]
pub struct Round {
    intents: Vec<Option<mapf::Intent>>,
    /// Robots not waited for: silent past the deadline before (until they answer again).
    hung: Vec<bool>,
    missing: usize,
}

impl Round {
    /// A round for `robots` robots, nobody hung.
    pub fn new(robots: usize) -> Self {
        Round {
            intents: vec![None; robots],
            hung: vec![false; robots],
            missing: 0,
        }
    }

    /// Starts collecting a tick: every robot on the grid (`present`) that is not hung is
    /// waited for.
    pub fn begin(&mut self, present: impl Fn(usize) -> bool) {
        self.intents.fill(None);
        self.missing = (0..self.intents.len())
            .filter(|&i| present(i) && !self.hung[i])
            .count();
    }

    /// Takes robot `id`'s intent; true if it was new this tick. A hung robot that answers is
    /// not hung any more.
    pub fn take(&mut self, id: usize, intent: mapf::Intent) -> bool {
        let Some(slot) = self.intents.get_mut(id) else {
            return false;
        };
        if slot.is_some() {
            return false;
        }
        *slot = Some(intent);
        if std::mem::replace(&mut self.hung[id], false) {
            // answered again: waited for from the next tick on, not counted as missing now
        } else {
            self.missing = self.missing.saturating_sub(1);
        }
        true
    }

    /// Whether every robot waited for answered.
    pub fn complete(&self) -> bool {
        self.missing == 0
    }

    /// The deadline passed: every robot on the grid still silent is hung (an obstacle that
    /// waits) from now on; returns them.
    pub fn expire(&mut self, present: impl Fn(usize) -> bool) -> Vec<usize> {
        let mut newly = Vec::new();
        for i in 0..self.intents.len() {
            if present(i) && self.intents[i].is_none() && !self.hung[i] {
                self.hung[i] = true;
                newly.push(i);
            }
        }
        self.missing = 0;
        newly
    }

    /// A robot left the grid: not waited for.
    pub fn left(&mut self, id: usize) {
        if let Some(slot) = self.intents.get(id)
            && slot.is_none()
            && !self.hung[id]
        {
            self.missing = self.missing.saturating_sub(1);
        }
        if let Some(h) = self.hung.get_mut(id) {
            *h = false;
        }
    }

    /// The intents of the tick, one slot per robot (`None`: silent or gone).
    pub fn intents(&self) -> &[Option<mapf::Intent>] {
        &self.intents
    }
}

/// The world of `plan` with its first look-ahead plan made and refined ([`World::prepare`]:
/// rounds of `WorldConfig::prepare_refine` A* expansions of large neighbourhood search on top
/// of the plan a tick would make, while a round gains, up to `prepare_refine_max`; one round
/// is about 0.2 s at 128 robots on random-32-32-10 in a release build, see `mapf/README.md`). The coordinator makes it while the robots learn
/// ([`prepare_while`]).
pub(crate) fn prepare(plan: &GridPlan) -> World {
    let mut world = World::new(&plan.instance, WorldConfig::default());
    world.prepare();
    world
}

/// Runs `learn` (the coordinator's message loop while the robots learn) on this thread while
/// a thread of its own makes `plan`'s world ([`prepare`]), so a long preparation never stalls
/// the message loop; returns both once both are done. If the robots finish learning first,
/// this waits for the preparation: the execution starts on the prepared plan, never on a
/// half-made one (the preparation is bounded by A* expansions, not a clock, so its plan is
/// the same on a fast or a slow host). Without a thread (the OS refused one) the world is
/// prepared here after `learn`.
pub(crate) fn prepare_while<T>(
    plan: Option<&GridPlan>,
    learn: impl FnOnce() -> T,
) -> (T, Option<World>) {
    std::thread::scope(|s| {
        let preparing = plan.map(|p| {
            let spawned = std::thread::Builder::new()
                .name("qfleet-prepare".into())
                .spawn_scoped(s, move || prepare(p));
            (p, spawned.ok())
        });
        let learned = learn();
        let world = preparing.map(|(p, handle)| match handle {
            Some(h) => h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)),
            None => prepare(p),
        });
        (learned, world)
    })
}

/// Drives one shared-grid execution on the bus (see the module docs) and returns its result
/// and where it left every robot (by robot id; a robot that left the grid: its last cell);
/// writes the plan's paths file into `out`. `world` is [`prepare`]'s for `plan`. An experiment
/// calls it once per phase, on the same engine and bus.
#[allow(clippy::too_many_arguments)]
pub(crate) fn execute(
    engine: &mut Engine,
    bus: &CoordinatorBus,
    lister: &Lister,
    plan: &GridPlan,
    mut world: World,
    spin: Duration,
    hang: Duration,
    stop: &AtomicBool,
    out: &OutDir,
) -> Result<(GridResult, Vec<Cell>), CoordError> {
    let inst = &plan.instance;
    let n = inst.agents();
    // robots the coordinator lost before the execution never stand on the grid
    for (id, slot) in engine.robots.iter().enumerate() {
        if slot.lost || !slot.accepted {
            world.remove(id);
        }
    }
    bus.connect_all()?;
    // answers to an earlier execution (the phase before, in an experiment) are not this one's;
    // a robot's answer to the first tick sent since this phase began (while it waited for
    // `Execute`, see `robot_agent::execute`) is kept for that tick
    while bus.intent.receive_sample()?.is_some() {}
    let h = plan.horizon.min(HORIZON_RADIUS_CAP);
    let mut horizons = Horizons::new(n, h);
    let first = world.tick();
    while let Some(s) = bus.horizon.receive_sample()? {
        let m = s.payload();
        // (not with one intent per tick, `h = 0`: that asks every robot every tick); one
        // centered elsewhere (an experiment's phase that starts where the one before ended) is
        // not an answer
        if h > 0 && m.tick == first && m.send_time_ns >= engine.phase_ns {
            let from = s.header().node_id().value();
            let _ = take_horizon(engine, &world, &mut horizons, first, from, m);
        }
    }
    let early_answers = (0..n)
        .filter(|&i| {
            world.positions()[i].is_some_and(|at| horizons.intent_at(i, first, at).is_some())
        })
        .count();
    report::log_line!(
        "qfleet-coordinator: shared grid: {} robots move from their starts (at most {} ticks)",
        n,
        plan.max_ticks
    );
    // `episodes` carries the horizon asked for (a robot that knows none answers every tick)
    let mut go = bus::control(Command::Execute, ROBOT_ID_ALL);
    go.episodes = u32::from(h);
    tolerate(bus.send_control(go))?;
    let mut round = Round::new(n);
    let mut wakes = 0u64;
    let mut tick_hist = new_hist();
    let mut intent_hist = new_hist();
    let mut resolve_hist = new_hist();
    let mut rejected = 0u64;
    let t0 = Instant::now();
    let ended = loop {
        let tick = world.tick();
        let state = if world.all_arrived() {
            GridState::Arrived
        } else {
            GridState::Moving
        };
        let start = Instant::now();
        if state == GridState::Arrived {
            publish(bus, &world, tick, state, true)?;
            break GridEnd::Arrived;
        }
        // a robot whose process is gone leaves even while the others answer without waiting
        // for it (a hung robot is not waited for, so the wait below may never look)
        if let Some(listing) = lister.poll() {
            engine.liveness(bus, listing)?;
            leave_lost(engine, &mut world, &mut horizons, tick, |_| {});
        }
        round.begin(|i| world.positions()[i].is_some());
        // what the robots' horizons already answer is not asked again
        for (i, p) in world.positions().iter().enumerate() {
            if let Some(at) = *p
                && let Some(intent) = horizons.intent_at(i, tick, at)
            {
                round.take(i, intent);
            }
        }
        let wake = !round.complete();
        wakes += u64::from(wake);
        let sent_ns = publish(bus, &world, tick, state, wake)?;
        let mut first = true;
        let mut last = Instant::now();
        // at least one look at the inbox a tick: a robot that was slow may answer any time
        while first || !round.complete() {
            first = false;
            let took = collect(
                engine,
                bus,
                &world,
                &mut round,
                &mut horizons,
                tick,
                sent_ns,
                &mut intent_hist,
                &mut rejected,
            )?;
            if round.complete() {
                break;
            }
            if took > 0 {
                last = Instant::now();
                continue;
            }
            if let Some(listing) = lister.poll() {
                engine.liveness(bus, listing)?;
                leave_lost(engine, &mut world, &mut horizons, tick, |id| round.left(id));
            }
            if stop.load(Ordering::Relaxed) || engine.halted() {
                break;
            }
            if start.elapsed() >= hang {
                for id in round.expire(|i| world.positions()[i].is_some()) {
                    report::log_line!(
                        "qfleet-coordinator: robot {id} sent no intent for tick {tick} within \
                         {hang:?}: an obstacle until it answers or leaves the grid"
                    );
                }
                break;
            }
            // robots do not wake the coordinator (see `robot_agent::execute`): after the spin
            // it polls with short naps, leaving the CPUs to the robots answering
            if last.elapsed() >= spin {
                std::thread::sleep(POLL_NAP);
            } else {
                std::hint::spin_loop();
            }
        }
        if stop.load(Ordering::Relaxed) || engine.halted() {
            publish(bus, &world, tick, GridState::Ended, true)?;
            break GridEnd::Stopped;
        }
        let resolving = Instant::now();
        let step = world
            .step(round.intents())
            .map_err(|e| CoordError::Grid(e.to_string()))?;
        record(&mut resolve_hist, resolving.elapsed().as_nanos() as u64);
        record(&mut tick_hist, start.elapsed().as_nanos() as u64);
        if let Some(rest) = plan.tick_min.checked_sub(start.elapsed()) {
            std::thread::sleep(rest);
        }
        if step.status == Status::Unsolvable {
            publish(bus, &world, step.tick, GridState::Ended, true)?;
            break GridEnd::Unsolvable;
        }
        if step.tick >= plan.max_ticks && !world.all_arrived() {
            publish(bus, &world, step.tick, GridState::Ended, true)?;
            break GridEnd::TickLimit;
        }
    };
    let exec_s = t0.elapsed().as_secs_f64();
    report::log_line!(
        "qfleet-coordinator: shared grid: {} ticks, the robots were woken on {wakes} of them \
         (horizon {}; {early_answers} of {n} robots answered the first tick before it)",
        world.tick(),
        plan.horizon
    );
    let paths = world.paths();
    let paths_file = match out.write(plan.paths, mapf::write_paths(&paths).as_bytes()) {
        Ok(_) => Some(plan.paths.name()),
        Err(e) => {
            report::log_line!("qfleet-coordinator: warning: {e}");
            None
        }
    };
    let at = paths
        .iter()
        .zip(inst.starts())
        .map(|(p, &s)| p.last().copied().unwrap_or(s))
        .collect();
    let result = summarize(
        plan,
        &world,
        &paths,
        ended,
        Figures {
            exec_s,
            rejected,
            tick: &tick_hist,
            intent: &intent_hist,
            resolve: &resolve_hist,
            paths_file,
        },
    );
    Ok((result, at))
}

/// Takes what waits in the intent inbox into the round; returns how many messages it took.
#[allow(clippy::too_many_arguments)]
fn collect(
    engine: &mut Engine,
    bus: &CoordinatorBus,
    world: &World,
    round: &mut Round,
    horizons: &mut Horizons,
    tick: u32,
    sent_ns: u64,
    hist: &mut Histogram<u64>,
    rejected: &mut u64,
) -> Result<usize, CoordError> {
    let mut n = 0;
    while let Some(s) = bus.horizon.receive_sample()? {
        n += 1;
        let from: Sender = s.header().node_id().value();
        let m = s.payload();
        match take_horizon(engine, world, horizons, tick, from, m) {
            Ok(id) => {
                if let Some(at) = world.positions()[id]
                    && let Some(intent) = horizons.intent_at(id, tick, at)
                    && round.take(id, intent)
                {
                    record(hist, monotonic_ns().saturating_sub(sent_ns));
                }
            }
            Err(None) => *rejected += 1,
            Err(Some(Reject::Tick { got, want })) if got < want => {}
            Err(Some(why)) => {
                *rejected += 1;
                report::log_line!(
                    "qfleet-coordinator: dropped a horizon of robot {}: {why:?}",
                    m.robot_id
                );
            }
        }
    }
    while let Some(s) = bus.intent.receive_sample()? {
        n += 1;
        let from: Sender = s.header().node_id().value();
        let m = s.payload();
        if engine.trusted(m.robot_id, from).is_none() {
            *rejected += 1;
            continue;
        }
        match accept(m, tick, world.positions()) {
            Ok((id, intent)) => {
                if round.take(id, intent) {
                    let now = monotonic_ns();
                    record(hist, now.saturating_sub(sent_ns));
                }
            }
            // an answer to an older grant is late, not wrong
            Err(Reject::Tick { got, want }) if got < want => {}
            Err(why) => {
                *rejected += 1;
                report::log_line!(
                    "qfleet-coordinator: dropped an intent of robot {}: {why:?}",
                    m.robot_id
                );
            }
        }
    }
    engine.messages += n as u64;
    Ok(n)
}

/// Keeps robot `m.robot_id`'s horizon `m` from node `from` if it is the robot's own and
/// [`accept_horizon`] accepts it for `tick`; returns the robot's index, or why not (`None`:
/// not its node).
fn take_horizon(
    engine: &mut Engine,
    world: &World,
    horizons: &mut Horizons,
    tick: u32,
    from: Sender,
    m: &IntentHorizon,
) -> Result<usize, Option<Reject>> {
    if engine.trusted(m.robot_id, from).is_none() {
        return Err(None);
    }
    let (id, cov) = accept_horizon(
        m,
        horizons.h,
        tick,
        world.positions(),
        &mut horizons.scratch,
    )
    .map_err(Some)?;
    horizons.keep(id, cov);
    Ok(id)
}

/// Takes every robot the engine declared lost off the grid (its cell is free from the next
/// tick) and forgets its horizon; `left` hears each one.
fn leave_lost(
    engine: &Engine,
    world: &mut World,
    horizons: &mut Horizons,
    tick: u32,
    mut left: impl FnMut(usize),
) {
    for (id, slot) in engine.robots.iter().enumerate() {
        if slot.lost && world.remove(id) {
            left(id);
            horizons.forget(id);
            report::log_line!(
                "qfleet-coordinator: robot {id} left the shared grid at tick {tick} (its process \
                 is gone)"
            );
        }
    }
}

/// Publishes the configuration of `tick` with `state` and, if `wake`, wakes the robots;
/// returns the send time.
fn publish(
    bus: &CoordinatorBus,
    world: &World,
    tick: u32,
    state: GridState,
    wake: bool,
) -> Result<u64, CoordError> {
    let pos = world.positions();
    let mut sent_ns = 0;
    let r = bus.grant.send_with(|g: &mut Grant| {
        g.tick = tick;
        g.robots = pos.len().min(GRANT_CAP) as u32;
        g.state = state.as_u8();
        g.seq = u64::from(tick);
        for (i, p) in pos.iter().take(GRANT_CAP).enumerate() {
            if let Some(c) = p {
                g.cell_x[i] = c.x;
                g.cell_y[i] = c.y;
                g.present[i] = 1;
            }
        }
        sent_ns = monotonic_ns();
        g.send_time_ns = sent_ns;
    });
    match r {
        // every robot already gone: nothing to tell, the execution still ends as it does
        Ok(_) | Err(SendError::NoSubscriber { .. }) => {}
        Err(e) => return Err(e.into()),
    }
    if wake {
        bus.grant.notify()?;
    }
    Ok(sent_ns)
}

/// What the loop measured, for [`summarize`].
struct Figures<'a> {
    exec_s: f64,
    rejected: u64,
    tick: &'a Histogram<u64>,
    intent: &'a Histogram<u64>,
    resolve: &'a Histogram<u64>,
    paths_file: Option<String>,
}

/// The result of an execution from its paths, checked independently of the resolver.
fn summarize(
    plan: &GridPlan,
    world: &World,
    paths: &[Vec<Cell>],
    ended: GridEnd,
    f: Figures<'_>,
) -> GridResult {
    let inst = &plan.instance;
    let (starts, goals) = (inst.starts(), inst.goals());
    let last_tick = world.tick();
    let present = world.positions();
    // a robot that left the grid stays on its last cell in the paths file; the check covers
    // the robots on the grid to the end (the resolver never put two robots on one cell)
    let stayed: Vec<usize> = (0..inst.agents())
        .filter(|&i| present[i].is_some())
        .collect();
    let pick = |v: &[Cell]| stayed.iter().map(|&i| v[i]).collect::<Vec<_>>();
    let stayed_paths: Vec<Vec<Cell>> = stayed.iter().map(|&i| paths[i].clone()).collect();
    let conflicts = match mapf::check(inst.grid(), &pick(starts), &pick(goals), &stayed_paths) {
        Ok(_) => 0,
        Err(v) => mapf::check::conflicts(&v) as u64,
    };
    let robots: Vec<GridRobot> = (0..inst.agents())
        .map(|i| {
            let path = &paths[i];
            let on_goal_from = settled_at(path, goals[i]);
            let stats = world.stats()[i];
            let until = on_goal_from.map_or(path.len(), |t| t as usize);
            let waits = path[..until.min(path.len())]
                .windows(2)
                .filter(|w| w[0] == w[1])
                .count() as u64;
            GridRobot {
                robot_id: i as u32,
                start: starts[i].to_string(),
                goal: goals[i].to_string(),
                shortest: inst.dist_from(i, starts[i]),
                arrived_at: on_goal_from.filter(|_| present[i].is_some()),
                waits,
                denied: u64::from(stats.denied),
                left: present[i].is_none(),
            }
        })
        .collect();
    let costs: Vec<u32> = robots
        .iter()
        .map(|r| r.arrived_at.unwrap_or(last_tick))
        .collect();
    let sum_of_costs: u64 = costs.iter().map(|&c| u64::from(c)).sum();
    let lower_bound = inst.lower_bound();
    let arrived = robots.iter().filter(|r| r.arrived_at.is_some()).count() as u32;
    GridResult {
        agents: inst.agents() as u32,
        scen: plan.scen.clone(),
        ended,
        all_arrived: arrived as usize == inst.agents(),
        arrived,
        sum_of_costs,
        makespan: costs.iter().copied().max().unwrap_or(0),
        lower_bound,
        soc_ratio: if lower_bound > 0 {
            sum_of_costs as f64 / lower_bound as f64
        } else {
            1.0
        },
        ticks: last_tick,
        waits: robots.iter().map(|r| r.waits).sum(),
        denied_moves: robots.iter().map(|r| r.denied).sum(),
        conflicts,
        intents_rejected: f.rejected,
        exec_s: f.exec_s,
        ticks_per_s: if f.exec_s > 0.0 {
            f64::from(last_tick) / f.exec_s
        } else {
            0.0
        },
        tick_latency_ns: LatencyStats::of(f.tick),
        intent_latency_ns: LatencyStats::of(f.intent),
        resolve_latency_ns: LatencyStats::of(f.resolve),
        paths_file: f.paths_file,
        robots,
    }
}

/// The tick from which `path` stays on `goal` to its end; `None` if it does not end there.
pub fn settled_at(path: &[Cell], goal: Cell) -> Option<u32> {
    if path.last() != Some(&goal) {
        return None;
    }
    let away = path.iter().rposition(|&c| c != goal);
    Some(away.map_or(0, |i| i as u32 + 1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapf::Move;

    fn intent(robot_id: u32, tick: u32, at: Cell, ranked: &[u8]) -> bus_schema::Intent {
        let mut m = bus_schema::Intent {
            robot_id,
            tick,
            cell_x: at.x,
            cell_y: at.y,
            count: ranked.len() as u8,
            ..bus_schema::Intent::ZEROED
        };
        m.ranked[..ranked.len()].copy_from_slice(ranked);
        m
    }

    #[test]
    fn an_intent_counts_only_for_its_robot_tick_and_cell() {
        let pos = [Some(Cell::new(1, 1)), None];
        let ok = accept(&intent(0, 3, Cell::new(1, 1), &[2, 0]), 3, &pos).unwrap();
        assert_eq!(ok.0, 0);
        assert_eq!(ok.1.first(), Some(Move::Right));
        assert_eq!(
            accept(&intent(0, 2, Cell::new(1, 1), &[2]), 3, &pos),
            Err(Reject::Tick { want: 3, got: 2 })
        );
        assert_eq!(
            accept(&intent(0, 3, Cell::new(2, 1), &[2]), 3, &pos),
            Err(Reject::Cell {
                want: Cell::new(1, 1),
                got: Cell::new(2, 1)
            })
        );
        assert_eq!(
            accept(&intent(1, 3, Cell::new(0, 0), &[0]), 3, &pos),
            Err(Reject::Absent(1))
        );
        assert_eq!(
            accept(&intent(7, 3, Cell::new(0, 0), &[0]), 3, &pos),
            Err(Reject::Robot(7))
        );
        assert!(matches!(
            accept(&intent(0, 3, Cell::new(1, 1), &[9]), 3, &pos),
            Err(Reject::Moves(_))
        ));
        assert!(matches!(
            accept(&intent(0, 3, Cell::new(1, 1), &[2, 2]), 3, &pos),
            Err(Reject::Moves(_))
        ));
    }

    #[test]
    fn a_round_waits_for_present_robots_and_not_for_hung_ones() {
        let wait = mapf::Intent::new(&[Move::Wait]).unwrap();
        let mut r = Round::new(3);
        let present = |i: usize| i != 2;
        r.begin(present);
        assert!(!r.complete());
        assert!(r.take(0, wait));
        assert!(!r.take(0, wait), "a second intent of one tick is not new");
        assert!(!r.complete());
        // robot 1 is silent past the deadline: hung, an obstacle
        assert_eq!(r.expire(present), vec![1]);
        assert!(r.complete());
        // the next tick does not wait for it
        r.begin(present);
        assert!(r.take(0, wait));
        assert!(r.complete());
        // it answers again: taken, and waited for from then on
        assert!(r.take(1, wait));
        r.begin(present);
        assert!(r.take(0, wait));
        assert!(!r.complete());
        r.left(1);
        assert!(r.complete(), "a robot that left the grid is not waited for");
    }

    fn horizon(robot_id: u32, tick: u32, at: Cell, radius: u8, each: &[Move]) -> IntentHorizon {
        let mut m = IntentHorizon {
            robot_id,
            tick,
            cell_x: at.x,
            cell_y: at.y,
            radius,
            ..IntentHorizon::ZEROED
        };
        let bits = mapf::horizon::pack(&mapf::Intent::new(each).unwrap());
        for r in m.ranked.iter_mut().take(diamond_len(radius)) {
            *r = bits;
        }
        m
    }

    #[test]
    fn a_horizon_answers_the_ticks_and_cells_it_covers_and_nothing_else() {
        let at = Cell::new(3, 3);
        let pos = [Some(at), None];
        // the fleet's horizon 2: periods of 3 ticks (3..=5, 6..=8)
        let mut h = Horizons::new(2, 2);
        let right = [Move::Right, Move::Wait];
        // made for this tick, at a period's start
        let (id, cov) =
            accept_horizon(&horizon(0, 3, at, 2, &right), 2, 3, &pos, &mut h.scratch).unwrap();
        assert_eq!((id, cov.until()), (0, 5));
        h.keep(id, cov);
        let want = mapf::Intent::new(&right).unwrap();
        assert_eq!(h.intent_at(0, 3, at), Some(want));
        assert_eq!(h.intent_at(0, 5, Cell::new(5, 3)), Some(want));
        assert_eq!(
            h.intent_at(0, 6, Cell::new(4, 3)),
            None,
            "used up by a robot that moved: it answers anew"
        );
        assert_eq!(
            h.intent_at(0, 6, at),
            Some(want),
            "kept by a robot that did not move"
        );
        assert_eq!(
            h.intent_at(0, 4, Cell::new(5, 4)),
            None,
            "outside its diamond"
        );
        // made for an earlier tick it still answers (a robot that answered late)
        let s = &mut h.scratch;
        assert!(accept_horizon(&horizon(0, 3, at, 2, &right), 2, 4, &pos, s).is_ok());
        // late: no longer answers the tick; not an error
        assert_eq!(
            accept_horizon(&horizon(0, 1, at, 1, &right), 2, 6, &pos, s),
            Err(Reject::Tick { want: 6, got: 1 })
        );
        // a tick not granted yet, a center that is not the robot's cell
        assert_eq!(
            accept_horizon(&horizon(0, 6, at, 2, &right), 2, 5, &pos, s),
            Err(Reject::Tick { want: 5, got: 6 })
        );
        assert!(matches!(
            accept_horizon(&horizon(0, 5, Cell::new(3, 4), 2, &right), 2, 5, &pos, s),
            Err(Reject::Cell { .. })
        ));
        // the wire's capacity, rankings past the diamond, bad rankings, absent robots
        assert_eq!(
            accept_horizon(&horizon(0, 5, at, 9, &right), 2, 5, &pos, s),
            Err(Reject::Radius(9))
        );
        let mut tail = horizon(0, 5, at, 1, &right);
        tail.ranked[diamond_len(1)] = 1;
        assert_eq!(
            accept_horizon(&tail, 2, 5, &pos, s),
            Err(Reject::Tail(diamond_len(1)))
        );
        let mut bad = horizon(0, 5, at, 1, &right);
        bad.ranked[2] = 7;
        assert!(matches!(
            accept_horizon(&bad, 2, 5, &pos, s),
            Err(Reject::Moves(_))
        ));
        assert_eq!(
            accept_horizon(&horizon(1, 5, at, 1, &right), 2, 5, &pos, s),
            Err(Reject::Absent(1))
        );
        assert_eq!(
            accept_horizon(&horizon(4, 5, at, 1, &right), 2, 5, &pos, s),
            Err(Reject::Robot(4))
        );
        h.forget(0);
        assert_eq!(h.intent_at(0, 5, at), None);
    }

    #[test]
    fn settled_is_the_last_arrival_on_the_goal() {
        let g = Cell::new(2, 0);
        let p = |xs: &[u16]| xs.iter().map(|&x| Cell::new(x, 0)).collect::<Vec<_>>();
        assert_eq!(settled_at(&p(&[0, 1, 2, 2]), g), Some(2));
        assert_eq!(settled_at(&p(&[0, 1, 2, 1, 2]), g), Some(4));
        assert_eq!(settled_at(&p(&[2, 2]), g), Some(0));
        assert_eq!(settled_at(&p(&[0, 1]), g), None);
    }
}
