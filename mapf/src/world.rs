//! The online resolver the coordinator drives once per tick: every robot sends its intent (its
//! moves ranked best first), [`World::step`] grants every robot one move so that the fleet
//! stays collision-free.
//!
//! # Rules (the MAPF benchmark's usual one-shot rules)
//!
//! - Each tick an agent waits or moves to a passable 4-neighbour.
//! - No vertex conflict: two agents never share a cell.
//! - No swap conflict: two agents never exchange cells in one tick.
//! - Following is allowed: an agent may enter a cell whose occupant leaves in the same tick, and
//!   so are rotations of cycles of four or more agents (a 4-connected grid has no 3-cycles).
//! - An agent on its goal stays there unless pushed aside; it then comes back.
//! - A robot with no intent (`None`: hung, silent) waits and is an immovable obstacle: nobody
//!   pushes it. [`World::remove`] takes a lost robot off the grid; its cell is free from then on.
//!
//! # How a tick is resolved
//!
//! PIBT (priority inheritance with backtracking, Okumura et al.): agents are taken in priority
//! order, each takes its best candidate cell that is not yet reserved and would not swap, and an
//! agent standing on that cell inherits the priority and must move first (recursively; when it
//! cannot, the taker tries its next candidate). Priorities are the standard dynamic ones: ticks
//! since the agent was last on its goal, then distance to goal (farther first), then id.
//!
//! **How the intent is used.** An agent's candidate order is its intent's ranking: illegal moves
//! (walls, off-grid) are skipped, and the moves the intent does not name come after the named
//! ones, nearest to the goal (by BFS) first, wire order breaking ties. With
//! [`WorldConfig::plan_ahead`] the coordinator, which knows every goal, also keeps a look-ahead
//! plan: prioritized planning (space-time A* for each agent in turn from the current
//! configuration, agents the previous plan could not route first, then nearest to goal first;
//! among equally short ways, the one spending the fewest ticks on other agents' goal cells,
//! [`WorldConfig::plan_avoid_goals`]),
//! tried in up to [`WorldConfig::plan_orders`] priority orders (the agents a try could not route
//! move to the front, distances get a small pseudo-random jitter) keeping the cheapest plan,
//! then improved by large neighbourhood search (a few agents at a time forget their paths and
//! are replanned; kept only if cheaper): [`WorldConfig::plan_refine`] A* expansions when the
//! plan is made and [`WorldConfig::refine_tick`] on every tick it is followed; the first plan,
//! made ahead by [`World::prepare`] before the first tick, starts from the complete search's
//! plan when prioritized planning leaves agents unrouted ([`WorldConfig::prepare_complete`])
//! and gets [`WorldConfig::prepare_refine`] more (the neighbourhoods are chosen adaptively,
//! [`WorldConfig::refine_adaptive`], except on ticks: [`WorldConfig::refine_tick_adaptive`]).
//! The plan may step an agent away from its goal (a detour, [`WorldConfig::plan_detours`])
//! when waiting for its way to clear would cost more. The plan changes the candidate order in
//! these ways only:
//!
//! 1. **The plan leads a robot heading its shortest way** ([`WorldConfig::plan_first`]). When
//!    the robot's first choice is as near its goal as any move it has (what a robot with
//!    converged values always sends: it asks for its shortest way), the plan's move goes
//!    first: the robot is held, or takes the plan's detour, while its own way is taken by the
//!    plan's other agents now or later. **This overrides the robot's ranking**, and it is the
//!    only place that does: the coordinator sees every robot's goal and the plan, a robot sees
//!    neither, and a robot that only asks for its shortest way is held at a door or sent
//!    round the other agents when that is cheaper for the fleet. Measured on the tuning set
//!    (mapf/README.md), this lowered sum of costs / lower bound on generated rooms and mazes at
//!    48 agents from 1.15–1.58 to 1.05–1.12; without it, robots stepping off the plan towards
//!    their goals made it be recomputed almost every tick.
//! 2. **Otherwise, reservations.** A robot whose first choice is *not* its shortest way (a
//!    learner whose values disagree with BFS, a robot that asks for a detour) keeps its own
//!    ranking: a candidate ranked above the plan's move is passed over only when the plan
//!    gives its cell to another agent next tick (or it would swap with one); it is then tried
//!    after the plan's move, as if already taken (the robot is held, or stepped aside when the
//!    plan needs its own cell).
//! 3. **And ties.** For such a robot, among the candidates just above the plan's move that are
//!    exactly as near the goal (BFS) as it, the plan's move goes first.
//!
//! With [`WorldConfig::free_first`] (off by default) one more tie rule applies before those:
//! among candidates equally near the goal, cells nobody stands on now come first.
//!
//! So a robot asking for its shortest way follows the plan (PIBT grants a conflict-free plan
//! unchanged: it is every agent's first candidate); a robot asking for anything else gets its
//! first choice unless it conflicts with a robot of higher priority now or with the plan next
//! tick, or a move exactly as near its goal is what the plan prefers. Agents the plan could not
//! route keep their ranking and PIBT's pushing. Whenever the granted moves leave the plan (or
//! some agent has none), it is recomputed at the next tick.
//!
//! **Never deadlock.** If the sum of distances to goal makes no new minimum for
//! [`WorldConfig::stall_ticks`] ticks, the world runs a complete search (LaCAM over
//! configurations with PIBT as its generator, bounded by [`WorldConfig::fallback_nodes`]
//! generator calls, no clock) from the current configuration and then follows its plan,
//! intents aside, until every agent is on its goal (a hung robot or a removal cancels it). If
//! the search exhausts every reachable configuration the instance is [`Status::Unsolvable`]
//! (with the hung robots as they are), which stays so until a robot is removed or its hung
//! state changes; the same verdict comes at once, without a search, when the silent robots cut
//! an agent off from its goal. If the budget runs out first the world reports
//! [`Status::Stalled`] and tries again later, waiting twice as many ticks each time until the
//! fleet makes progress again.
//!
//! After [`World::new`] a tick allocates nothing, except the complete search when it runs.

use crate::instance::Instance;
use crate::moves::{Intent, Move};
use crate::pibt::{NIL, Pibt};
use crate::plan::{Fleet, Planner};
use crate::search::{Outcome, Problem, lacam};
use planner::{Cell, Grid};

/// A first-ranked move into a wall or off the grid: never granted, so always "denied".
const INTO_WALL: u32 = NIL - 1;

/// Tuning of the resolver; [`WorldConfig::default`] is what the coordinator should use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WorldConfig {
    /// Ticks without a new minimum of the summed distance to goal before the complete search.
    pub stall_ticks: u32,
    /// Generator calls (PIBT steps) the complete search may spend each time it runs; its memory
    /// is about `fallback_nodes × agents × 4` bytes at most.
    pub fallback_nodes: u64,
    /// Whether to keep a prioritized look-ahead plan (see the module docs).
    pub plan_ahead: bool,
    /// A* expansions each agent's look-ahead search may spend.
    pub plan_nodes: u32,
    /// A* expansions one priority order's plan may spend; further orders are tried only while
    /// the replan's total is below it (a replan spends at most about 2 × `plan_total` +
    /// `plan_refine`, a tick following the plan `refine_tick`: bounds a tick's work).
    pub plan_total: u64,
    /// Extra ticks beyond the longest remaining distance a look-ahead plan may use.
    pub plan_slack: u32,
    /// Whether the look-ahead plan may step an agent away from its goal when it could wait
    /// (a detour round agents that would hold it up longer).
    pub plan_detours: bool,
    /// Whether a look-ahead search, among an agent's shortest ways (given the agents planned
    /// before it), takes the one spending the fewest ticks on other agents' goal cells: a
    /// robot passing a cell where another will rest makes that one arrive after it passed.
    pub plan_avoid_goals: bool,
    /// Whether the plan's move goes first for a robot whose first choice is its shortest way
    /// (the one place the coordinator overrides a ranking; see the module docs).
    pub plan_first: bool,
    /// Priority orders each replan tries while `plan_total` lasts; the cheapest plan is kept.
    pub plan_orders: u32,
    /// Largest pseudo-random jitter added to an agent's distance in the extra priority orders.
    pub plan_jitter: u32,
    /// A* expansions each replan spends improving its plan (large neighbourhood search).
    pub plan_refine: u64,
    /// A* expansions each tick spends improving the plan being followed (0 = none).
    pub refine_tick: u64,
    /// A* expansions one agent's search may spend while improving a plan on a replan or a
    /// tick (a search that cannot succeed spends all of it, so it bounds a tick's work).
    pub refine_nodes: u32,
    /// A* expansions one agent's search may spend while [`World::prepare`] improves the first
    /// plan: its budget is large, and `refine_nodes` left agents of maze-like maps unrouted (a
    /// way round the others is long in space-time); on the tuning mazes 20 000 to 400 000
    /// measured alike.
    pub prepare_nodes: u32,
    /// A* expansions [`World::prepare`] spends at least improving the first plan on top of
    /// `plan_refine` (it runs before the execution, while the robots learn, so it may spend
    /// far more than a tick).
    pub prepare_refine: u64,
    /// A* expansions [`World::prepare`] may spend at most: past `prepare_refine` it goes on
    /// in rounds of `prepare_refine` while the last round lowered the plan's cost and the
    /// plan is above the lower bound (so an easy instance stops at the minimum, a hard one
    /// keeps improving while it gains).
    pub prepare_refine_max: u64,
    /// Whether [`World::prepare`] replaces a first plan that leaves agents unrouted by the
    /// complete search's (every agent routed, within the horizon) before refining it: from
    /// unrouted agents the refinement routes them one neighbourhood at a time and was left
    /// with agents unrouted and a replan on most ticks on tuning mazes at 48 agents. The
    /// search is the stall fallback's, with its budget and memory (`fallback_nodes`).
    pub prepare_complete: bool,
    /// Whether the refinement chooses its neighbourhoods adaptively among the delayed agent's
    /// way, a junction's agents and random agents (MAPF-LNS's adaptive LNS), else always the
    /// delayed agent's way.
    pub refine_adaptive: bool,
    /// Whether a tick's refinement (`refine_tick`) chooses adaptively too; else it works on the
    /// delayed agent's way alone, which often finds nothing to do and ends early, so a tick
    /// costs less.
    pub refine_tick_adaptive: bool,
    /// Whether, among candidates equally near the goal, cells nobody stands on come first (as
    /// PIBT's reference implementation breaks ties). Off by default: with the look-ahead it
    /// measured slightly worse on the tuning instance; it helps plain PIBT a lot.
    pub free_first: bool,
    /// Whether to record every tick's positions for [`World::paths`] (the only per-tick
    /// growth: `agents` × 4 bytes a tick, amortized).
    pub record: bool,
    /// Seed of the complete search's tie-breaking.
    pub seed: u64,
}

impl Default for WorldConfig {
    fn default() -> Self {
        WorldConfig {
            stall_ticks: 32,
            fallback_nodes: 100_000,
            plan_ahead: true,
            plan_nodes: 20_000,
            plan_total: 500_000,
            plan_slack: 64,
            plan_detours: true,
            plan_avoid_goals: true,
            plan_first: true,
            plan_orders: 4,
            plan_jitter: 16,
            plan_refine: 50_000,
            refine_tick: 1_000,
            refine_nodes: 4_000,
            prepare_nodes: 20_000,
            prepare_refine: 1_000_000,
            prepare_refine_max: 16_000_000,
            prepare_complete: true,
            refine_adaptive: true,
            refine_tick_adaptive: false,
            free_first: false,
            record: true,
            seed: 0x9e37_79b9_7f4a_7c15,
        }
    }
}

/// Per-agent counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AgentStats {
    /// Ticks the agent stayed where it was.
    pub waits: u32,
    /// Ticks its first-ranked move was not granted (including a first move into a wall).
    pub denied: u32,
    /// Ticks it changed cell.
    pub moves: u32,
}

/// Where the run stands after a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Status {
    /// Agents are under way.
    Running,
    /// Every present agent is on its goal.
    Arrived,
    /// The world follows the complete search's plan.
    Following,
    /// The complete search ran out of budget (and the fleet has made no progress since); PIBT
    /// goes on and the search runs again later.
    Stalled,
    /// The complete search explored every reachable configuration: no agent can complete.
    Unsolvable,
}

/// What one step granted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tick {
    /// The tick reached (1 after the first step).
    pub tick: u32,
    /// Agents that changed cell.
    pub moved: u32,
    /// Present agents that stayed.
    pub waited: u32,
    /// Agents whose first-ranked move was not granted.
    pub denied: u32,
    /// Where the run stands now.
    pub status: Status,
}

/// Why a step was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WorldError {
    /// One intent slot per agent is required.
    #[error("{got} intents for {agents} agents: one slot per agent (None for a silent robot)")]
    IntentCount {
        /// Slots given.
        got: usize,
        /// Agents in the world.
        agents: usize,
    },
}

/// The shared grid's state and the resolver's tables.
#[derive(Debug, Clone)]
pub struct World {
    grid: Grid,
    config: WorldConfig,
    nbr: Vec<[u32; 4]>,
    goal: Vec<u32>,
    dist: Vec<Vec<u32>>,
    pos: Vec<u32>,
    hung: Vec<bool>,
    elapsed: Vec<u32>,
    stats: Vec<AgentStats>,
    out: Vec<Option<Cell>>,
    tick: u32,
    pibt: Pibt,
    order: Vec<u32>,
    first: Vec<u32>,
    planner: Planner,
    plan_tick: u32,
    plan_valid: bool,
    boost: Vec<bool>,
    lift: Vec<bool>,
    replans: u32,
    following: Vec<u32>,
    follow_at: usize,
    best: u64,
    since_best: u32,
    unsolvable: bool,
    stalled: bool,
    stall_window: u32,
    searches: u32,
    history: Vec<u32>,
}

impl World {
    /// A world with every agent on its start at tick 0.
    pub fn new(instance: &Instance, config: WorldConfig) -> World {
        let grid = instance.grid().clone();
        let cells = grid.len();
        let idx = |c: Cell| grid.index(c) as u32;
        let nbr = neighbour_table(&grid);
        let n = instance.agents();
        let pos: Vec<u32> = instance.starts().iter().map(|&c| idx(c)).collect();
        let goal: Vec<u32> = instance.goals().iter().map(|&c| idx(c)).collect();
        let dist = instance.dist_tables().to_vec();
        let longest = (0..n).map(|i| dist[i][pos[i] as usize]).max().unwrap_or(0);
        // the look-ahead's space-time tables: at most 2^22 slots (11 bytes each)
        let horizon = if config.plan_ahead {
            (longest as usize + config.plan_slack as usize).min((1 << 22) / cells.max(1))
        } else {
            0
        };
        let mut planner = Planner::new(
            if config.plan_ahead { n } else { 0 },
            cells,
            horizon,
            config.plan_nodes,
        );
        planner.seed(config.seed);
        planner.adaptive = config.refine_adaptive;
        planner.set_junctions(&nbr);
        planner.set_goals(&goal);
        planner.avoid_goals = config.plan_avoid_goals;
        let mut w = World {
            out: instance.starts().iter().map(|&c| Some(c)).collect(),
            grid,
            config,
            nbr,
            goal,
            dist,
            hung: vec![false; n],
            elapsed: vec![0; n],
            stats: vec![AgentStats::default(); n],
            tick: 0,
            pibt: Pibt::new(n, cells),
            order: Vec::with_capacity(n),
            first: vec![NIL; n],
            planner,
            plan_tick: 0,
            plan_valid: false,
            boost: vec![false; n],
            lift: vec![false; n],
            replans: 0,
            following: Vec::new(),
            follow_at: 0,
            best: u64::MAX,
            since_best: 0,
            unsolvable: false,
            stalled: false,
            stall_window: config.stall_ticks,
            searches: 0,
            history: Vec::new(),
            pos,
        };
        if config.record {
            w.history.extend_from_slice(&w.pos);
        }
        w
    }

    /// Number of agents (present or removed).
    pub fn agents(&self) -> usize {
        self.pos.len()
    }

    /// Ticks stepped so far.
    pub fn tick(&self) -> u32 {
        self.tick
    }

    /// Every agent's cell, `None` once removed.
    pub fn positions(&self) -> &[Option<Cell>] {
        &self.out
    }

    /// Every agent's counters.
    pub fn stats(&self) -> &[AgentStats] {
        &self.stats
    }

    /// How often the look-ahead plan was (re)computed.
    pub fn replans(&self) -> u32 {
        self.replans
    }

    /// While a look-ahead plan is kept: its sum of costs over the agents it routes (the tick
    /// each arrives for good if the plan is followed, counted from tick 0) and how many agents
    /// it could not route.
    pub fn planned_cost(&self) -> Option<(u64, usize)> {
        self.plan_valid.then(|| {
            let (u, soc) = self.plan_cost();
            (
                soc + u64::from(self.plan_tick) * (self.pos.len() - u) as u64,
                u,
            )
        })
    }

    /// How often the complete search ran.
    pub fn searches(&self) -> u32 {
        self.searches
    }

    /// Whether every present agent is on its goal.
    pub fn all_arrived(&self) -> bool {
        self.pos
            .iter()
            .zip(&self.goal)
            .all(|(&p, &g)| p == NIL || p == g)
    }

    /// Takes a lost robot off the grid; its cell is free from the next step. False if the agent
    /// is unknown or already removed.
    pub fn remove(&mut self, agent: usize) -> bool {
        match self.pos.get(agent) {
            Some(&p) if p != NIL => {
                self.pos[agent] = NIL;
                self.out[agent] = None;
                self.hung[agent] = false;
                self.changed();
                true
            }
            _ => false,
        }
    }

    /// Every agent's path, `paths[agent][tick]`, from the recorded ticks (empty without
    /// [`WorldConfig::record`]); a removed agent stays where it left the grid.
    pub fn paths(&self) -> Vec<Vec<Cell>> {
        let n = self.pos.len();
        let ticks = self.history.len() / n.max(1);
        let mut out = vec![Vec::with_capacity(ticks); n];
        for t in 0..ticks {
            for (i, p) in out.iter_mut().enumerate() {
                let v = self.history[t * n + i];
                let c = if v == NIL {
                    p.last().copied().unwrap_or(Cell::new(0, 0))
                } else {
                    self.grid.cell(v as usize)
                };
                p.push(c);
            }
        }
        out
    }

    /// The fleet changed (a removal, a robot hung or back): plans and verdicts start over.
    fn changed(&mut self) {
        self.plan_valid = false;
        self.following.clear();
        self.unsolvable = false;
        self.best = u64::MAX;
        self.since_best = 0;
        self.stall_window = self.config.stall_ticks;
        self.stalled = false;
    }

    /// The target cell of move `m` from cell `v`, NIL if blocked.
    fn target(&self, v: u32, m: Move) -> u32 {
        match m {
            Move::Wait => v,
            _ => self.nbr[v as usize][m as usize - 1],
        }
    }

    /// Grants every agent one move from its intent (`None` = a silent robot, which waits and
    /// is not pushed); see the module docs for the rules and how intents are used.
    pub fn step(&mut self, intents: &[Option<Intent>]) -> Result<Tick, WorldError> {
        let n = self.pos.len();
        if intents.len() != n {
            return Err(WorldError::IntentCount {
                got: intents.len(),
                agents: n,
            });
        }
        let mut changed = false;
        for (i, intent) in intents.iter().enumerate() {
            let h = self.pos[i] != NIL && intent.is_none();
            if h != self.hung[i] {
                self.hung[i] = h;
                changed = true;
            }
        }
        if changed {
            self.changed();
        }
        // the complete search when the resolver has stalled
        if self.following.is_empty()
            && !self.unsolvable
            && self.since_best >= self.stall_window
            && !self.all_arrived_movable()
        {
            self.search();
        }
        let following = !self.following.is_empty();
        if !following && self.config.plan_ahead && !self.plan_valid {
            self.replan();
        } else if !following && self.plan_valid && self.config.refine_tick > 0 {
            // every agent is on the plan: improve the rest of it a little
            let adaptive = self.config.refine_adaptive && self.config.refine_tick_adaptive;
            self.refine(
                (self.tick - self.plan_tick) as usize,
                self.config.refine_tick,
                self.config.refine_nodes,
                adaptive,
            );
        }
        // candidates (they look at who stands where)
        self.pibt.begin(&self.pos);
        for (i, intent) in intents.iter().enumerate() {
            self.candidates(i, intent.as_ref(), following);
        }
        // priority order: hung robots are fixed first, the rest by PIBT's dynamic priority
        self.order.clear();
        self.order
            .extend((0..n as u32).filter(|&i| self.pos[i as usize] != NIL));
        let (elapsed, dist, pos) = (&self.elapsed, &self.dist, &self.pos);
        self.order.sort_unstable_by_key(|&i| {
            let i = i as usize;
            (
                std::cmp::Reverse(elapsed[i]),
                std::cmp::Reverse(dist[i][pos[i] as usize]),
                i,
            )
        });
        for i in 0..n {
            if self.hung[i] {
                let here = self.pos[i];
                self.pibt.fix(&self.pos, i, here);
            }
        }
        for k in 0..self.order.len() {
            let i = self.order[k] as usize;
            if self.pibt.next[i] == NIL {
                self.pibt.run(&self.pos, i);
            }
        }
        // apply
        let mut tick = Tick {
            tick: self.tick.saturating_add(1),
            moved: 0,
            waited: 0,
            denied: 0,
            status: Status::Running,
        };
        let plan_t = (self.tick - self.plan_tick + 1) as usize;
        let mut off_plan = false;
        for i in 0..n {
            let from = self.pos[i];
            if from == NIL {
                continue;
            }
            let to = self.pibt.next[i];
            if to == from {
                tick.waited += 1;
                self.stats[i].waits += 1;
            } else {
                tick.moved += 1;
                self.stats[i].moves += 1;
            }
            if self.first[i] != NIL && self.first[i] != to {
                tick.denied += 1;
                self.stats[i].denied += 1;
            }
            if self.plan_valid && !following {
                let planned = self.planner.at(i, plan_t);
                if planned == NIL || planned != to {
                    off_plan = true;
                }
            }
        }
        self.pibt.end(&self.pos);
        for i in 0..n {
            if self.pos[i] != NIL {
                let to = self.pibt.next[i];
                self.pos[i] = to;
                self.out[i] = Some(self.grid.cell(to as usize));
                self.elapsed[i] = if to == self.goal[i] {
                    self.boost[i] = false;
                    0
                } else {
                    self.elapsed[i].saturating_add(1)
                };
            }
        }
        self.tick = self.tick.saturating_add(1);
        if off_plan {
            self.plan_valid = false;
        }
        if following {
            self.follow_at += 1;
            let base = self.follow_at * n;
            let on_track = base + n <= self.following.len()
                && (0..n).all(|i| self.pos[i] == NIL || self.following[base + i] == self.pos[i]);
            if !on_track || base + n >= self.following.len() {
                self.following.clear();
                self.plan_valid = false;
            }
        }
        if self.config.record {
            self.history.extend_from_slice(&self.pos);
        }
        // progress: a new minimum of the summed distance of the movable agents
        let sum: u64 = (0..n)
            .filter(|&i| self.pos[i] != NIL && !self.hung[i])
            .map(|i| u64::from(self.dist[i][self.pos[i] as usize]))
            .sum();
        if sum < self.best {
            self.best = sum;
            self.since_best = 0;
            self.stall_window = self.config.stall_ticks;
            self.stalled = false;
        } else {
            self.since_best = self.since_best.saturating_add(1);
        }
        tick.status = if self.all_arrived() {
            Status::Arrived
        } else if self.unsolvable {
            Status::Unsolvable
        } else if self.stalled {
            Status::Stalled
        } else if following {
            Status::Following
        } else {
            Status::Running
        };
        Ok(tick)
    }

    /// Whether every present agent that can move is on its goal.
    fn all_arrived_movable(&self) -> bool {
        (0..self.pos.len())
            .all(|i| self.pos[i] == NIL || self.hung[i] || self.pos[i] == self.goal[i])
    }

    /// Fills agent `i`'s candidate cells (see the module docs) and its first-ranked target.
    fn candidates(&mut self, i: usize, intent: Option<&Intent>, following: bool) {
        let here = self.pos[i];
        self.first[i] = NIL;
        if here == NIL {
            self.pibt.ncand[i] = 0;
            return;
        }
        let mut list = [NIL; 5];
        let mut len = 0usize;
        let push = |list: &mut [u32; 5], len: &mut usize, v: u32| {
            if v != NIL && !list[..*len].contains(&v) {
                list[*len] = v;
                *len += 1;
            }
        };
        let Some(intent) = intent else {
            self.pibt.cand[i] = [here, NIL, NIL, NIL, NIL];
            self.pibt.ncand[i] = 1;
            return;
        };
        if let Some(m) = intent.first() {
            self.first[i] = self.target(here, m);
            if self.first[i] == NIL {
                self.first[i] = INTO_WALL;
            }
        }
        if following {
            let next = self.following[(self.follow_at + 1) * self.pos.len() + i];
            self.pibt.cand[i] = [next, NIL, NIL, NIL, NIL];
            self.pibt.ncand[i] = 1;
            return;
        }
        for &m in intent.moves() {
            push(&mut list, &mut len, self.target(here, m));
        }
        // the unnamed moves: nearest to the goal first, wire order breaking ties
        let mut rest = [(u32::MAX, NIL); 5];
        let mut r = 0;
        for m in Move::ALL {
            if intent.rank(m).is_none() {
                let v = self.target(here, m);
                if v != NIL {
                    rest[r] = (self.dist[i][v as usize], v);
                    r += 1;
                }
            }
        }
        rest[..r].sort_by_key(|e| e.0);
        for e in &rest[..r] {
            push(&mut list, &mut len, e.1);
        }
        if self.config.free_first {
            self.free_first(i, &mut list[..len]);
        }
        if self.plan_valid {
            self.follow_plan(i, &mut list[..len]);
        }
        self.pibt.cand[i] = list;
        self.pibt.ncand[i] = len as u8;
    }

    /// Within each run of consecutive candidates equally near the goal (the robot's ties), puts
    /// the cells nobody stands on first, keeping the order otherwise (as PIBT's reference
    /// implementation breaks ties).
    fn free_first(&self, i: usize, list: &mut [u32]) {
        let mut start = 0;
        while start < list.len() {
            let d = self.dist[i][list[start] as usize];
            let mut end = start + 1;
            while end < list.len() && self.dist[i][list[end] as usize] == d {
                end += 1;
            }
            let occ = &self.pibt.occ_now;
            list[start..end].sort_by_key(|&v| {
                let o = occ[v as usize];
                o != NIL && o as usize != i
            });
            start = end;
        }
    }

    /// Reorders agent `i`'s candidates (intent order) by the look-ahead plan: cells the plan
    /// gives to other agents next tick (or that would swap with one) go after the plan's
    /// cell, and the plan's cell goes first among the candidates just above it that are as
    /// near the goal as it is (the robot's ties).
    fn follow_plan(&self, i: usize, list: &mut [u32]) {
        let here = self.pos[i];
        let t = (self.tick - self.plan_tick + 1) as usize;
        let planned = self.planner.at(i, t);
        let Some(k) = list.iter().position(|&v| v == planned) else {
            return;
        };
        // a robot heading its shortest way (its first choice as near its goal as any move)
        // leaves the way to the plan; one asking for something else keeps its ranking
        let d = &self.dist[i];
        if self.config.plan_first && list.iter().all(|&v| d[v as usize] >= d[list[0] as usize]) {
            list[..=k].rotate_right(1);
            return;
        }
        let taken = |v: u32| {
            let o = self.planner.occupant(t, v);
            if o != NIL && o as usize != i {
                return true;
            }
            // a swap: whoever the plan has on v now comes to our cell
            let now = self.planner.occupant(t - 1, v);
            v != here && now != NIL && now as usize != i && self.planner.at(now as usize, t) == here
        };
        // stable partition of list[..k]: the free ones, then the plan's cell, then the taken ones
        let mut buf = [NIL; 5];
        let mut demoted = [NIL; 5];
        let (mut nb, mut nd) = (0, 0);
        for &v in &list[..k] {
            if taken(v) {
                demoted[nd] = v;
                nd += 1;
            } else {
                buf[nb] = v;
                nb += 1;
            }
        }
        // the plan's cell before the equally near candidates just above it
        let d = self.dist[i][planned as usize];
        let mut at = nb;
        while at > 0 && self.dist[i][buf[at - 1] as usize] == d {
            at -= 1;
        }
        let mut out = [NIL; 5];
        let mut n = 0;
        for &v in buf[..at]
            .iter()
            .chain(std::iter::once(&planned))
            .chain(&buf[at..nb])
            .chain(&demoted[..nd])
        {
            out[n] = v;
            n += 1;
        }
        list[..n].copy_from_slice(&out[..n]);
    }

    /// Makes the look-ahead plan for the current configuration now, if one is kept and none
    /// is valid (what the next [`World::step`] would do first), replaces it by the complete
    /// search's when it leaves agents unrouted ([`WorldConfig::prepare_complete`]), and
    /// improves it by large neighbourhood search: [`WorldConfig::prepare_refine`] A*
    /// expansions, then more rounds of as many while the last one lowered the plan's cost and
    /// the plan is above the lower bound, up to [`WorldConfig::prepare_refine_max`]. A
    /// coordinator calls it while the robots are still learning, so the first tick does not
    /// wait for it and the plan the fleet starts on is better than a tick could afford. Its
    /// work is bounded by A* expansion and generator-call budgets, never by a clock: the plan
    /// it makes is deterministic. Returns the expansions the refinement spent.
    pub fn prepare(&mut self) -> u64 {
        if !(self.config.plan_ahead && !self.plan_valid && self.following.is_empty()) {
            return 0;
        }
        self.replan();
        if self.config.prepare_complete && self.plan_cost().0 > 0 {
            self.plan_complete();
        }
        let round = self.config.prepare_refine;
        if round == 0 {
            return 0;
        }
        let bound: u64 = (0..self.pos.len())
            .filter(|&i| self.pos[i] != NIL && !self.hung[i])
            .map(|i| u64::from(self.dist[i][self.pos[i] as usize]))
            .sum();
        let mut spent = 0u64;
        let mut cost = self.plan_cost();
        loop {
            spent += self.refine(
                0,
                round,
                self.config.prepare_nodes,
                self.config.refine_adaptive,
            );
            let now = self.plan_cost();
            let gained = now < cost;
            cost = now;
            if !gained
                || (cost.0 == 0 && cost.1 <= bound)
                || spent.saturating_add(round) > self.config.prepare_refine_max
            {
                return spent;
            }
        }
    }

    /// Replaces a look-ahead plan that leaves agents unrouted by the complete search's, when
    /// it finds one within the horizon: every agent routed, the refinement then only lowers
    /// its cost (from a plan with unrouted agents it first has to route them, one
    /// neighbourhood at a time).
    fn plan_complete(&mut self) {
        if let Outcome::Solved(configs) = self.complete_search(self.config.seed ^ 0x5eed) {
            let (planner, _, fleet) = self.planning();
            planner.load(&configs, &fleet);
        }
    }

    /// The complete search (LaCAM) from the current configuration, within
    /// [`WorldConfig::fallback_nodes`] generator calls, ties broken by `seed`.
    fn complete_search(&mut self, seed: u64) -> Outcome {
        let problem = Problem {
            goal: &self.goal,
            fixed: &self.hung,
            nbr: &self.nbr,
            dist: &self.dist,
        };
        lacam(
            &mut self.pibt,
            &problem,
            &self.pos,
            self.config.fallback_nodes,
            seed,
        )
    }

    /// Recomputes the look-ahead plan from the current configuration.
    fn replan(&mut self) {
        // several priority orders while the budget lasts; the cheapest plan is kept
        let mut best = (usize::MAX, u64::MAX, 0u32);
        let (mut spent, mut last) = (0u64, 0u32);
        self.lift.fill(false);
        for r in 0..self.config.plan_orders.max(1) {
            if r > 0 && (spent >= self.config.plan_total || best.1 == 0) {
                break;
            }
            spent += self.plan_in_order(r);
            last = r;
            let cost = self.plan_cost();
            if (cost.0, cost.1) < (best.0, best.1) {
                best = (cost.0, cost.1, r);
                if r + 1 < self.config.plan_orders {
                    self.planner.save();
                }
            }
            for i in 0..self.pos.len() {
                if self.pos[i] != NIL && !self.hung[i] && self.planner.arrive[i] == NIL {
                    self.lift[i] = true;
                }
            }
        }
        if best.2 != last {
            self.planner.restore();
        }
        if self.config.plan_refine > 0 {
            let nodes = self.config.refine_nodes;
            self.refine(
                0,
                self.config.plan_refine,
                nodes,
                self.config.refine_adaptive,
            );
        }
        self.plan_tick = self.tick;
        self.plan_valid = true;
        self.replans += 1;
        for i in 0..self.pos.len() {
            if self.pos[i] != NIL && !self.hung[i] && self.planner.arrive[i] == NIL {
                self.boost[i] = true;
            }
        }
    }

    /// The planner, the priority order and what the planner reads of the world, borrowed
    /// together.
    fn planning(&mut self) -> (&mut Planner, &[u32], Fleet<'_>) {
        let fleet = Fleet {
            pos: &self.pos,
            goal: &self.goal,
            fixed: &self.hung,
            nbr: &self.nbr,
            dist: &self.dist,
        };
        (&mut self.planner, &self.order, fleet)
    }

    /// Improves the plan from its time index `t0` on, spending about `budget` A* expansions
    /// and at most `nodes` on one agent's search, choosing neighbourhoods adaptively if
    /// `adaptive`; returns the expansions spent.
    fn refine(&mut self, t0: usize, budget: u64, nodes: u32, adaptive: bool) -> u64 {
        self.planner.adaptive = adaptive;
        let (planner, _, fleet) = self.planning();
        planner.refine(t0, &fleet, nodes, budget)
    }

    /// Plans every agent in priority order number `r`: agents the previous plan could not
    /// route first, then nearest to their goals first (measured best on the tuning set); order
    /// `r > 0` adds a pseudo-random jitter below `plan_jitter` to each distance.
    fn plan_in_order(&mut self, r: u32) -> u64 {
        self.order.clear();
        self.order
            .extend((0..self.pos.len() as u32).filter(|&i| self.pos[i as usize] != NIL));
        let (dist, pos, boost, lift) = (&self.dist, &self.pos, &self.boost, &self.lift);
        let jitter = u64::from(self.config.plan_jitter.max(1));
        let salt = self.config.seed ^ (u64::from(r) << 40) ^ u64::from(self.replans);
        self.order.sort_unstable_by_key(|&i| {
            let d = u64::from(dist[i as usize][pos[i as usize] as usize]);
            let j = if r == 0 {
                0
            } else {
                mix(salt ^ u64::from(i)) % jitter
            };
            (!(boost[i as usize] || lift[i as usize]), d + j, i)
        });
        self.planner.voluntary_detours = self.config.plan_detours;
        let (nodes, total) = (self.config.plan_nodes, self.config.plan_total);
        let (planner, order, fleet) = self.planning();
        planner.plan(order, &fleet, nodes, total)
    }

    /// The current plan's cost: agents it could not route, then its summed arrival.
    fn plan_cost(&self) -> (usize, u64) {
        let mut unplanned = 0;
        let mut soc = 0u64;
        for i in 0..self.pos.len() {
            if self.pos[i] == NIL || self.hung[i] {
                continue;
            }
            match self.planner.arrive[i] {
                NIL => unplanned += 1,
                t => soc += u64::from(t),
            }
        }
        (unplanned, soc)
    }

    /// Whether some movable agent is cut off from its goal by the silent robots (which never
    /// move): then nothing can complete, and no search is needed to say so.
    fn cut_off_by_hung(&self) -> bool {
        if !self.hung.iter().any(|h| *h) {
            return false; // validated instances have every goal reachable
        }
        let cells = self.nbr.len();
        let mut seen = vec![false; cells];
        let mut queue = std::collections::VecDeque::new();
        for (i, &h) in self.hung.iter().enumerate() {
            if h {
                seen[self.pos[i] as usize] = true;
            }
        }
        let walls = seen.clone();
        for i in 0..self.pos.len() {
            if self.pos[i] == NIL || self.hung[i] {
                continue;
            }
            seen.copy_from_slice(&walls);
            let g = self.goal[i] as usize;
            if seen[g] {
                return true;
            }
            seen[g] = true;
            queue.clear();
            queue.push_back(g as u32);
            let mut reached = false;
            while let Some(v) = queue.pop_front() {
                if v == self.pos[i] {
                    reached = true;
                    break;
                }
                for &u in &self.nbr[v as usize] {
                    if u != NIL && !seen[u as usize] {
                        seen[u as usize] = true;
                        queue.push_back(u);
                    }
                }
            }
            if !reached {
                return true;
            }
        }
        false
    }

    /// Runs the complete search from the current configuration.
    fn search(&mut self) {
        self.since_best = 0;
        if self.cut_off_by_hung() {
            self.unsolvable = true;
            return;
        }
        self.searches += 1;
        let seed = self.config.seed ^ u64::from(self.searches);
        match self.complete_search(seed) {
            Outcome::Solved(configs) => {
                self.stalled = false;
                self.following = configs;
                self.follow_at = 0;
                if self.following.len() <= self.pos.len() {
                    self.following.clear();
                }
            }
            Outcome::Exhausted => self.unsolvable = true,
            Outcome::OutOfBudget => {
                // try again later, each time waiting twice as long
                self.stalled = true;
                self.stall_window = self.stall_window.saturating_mul(2).max(1);
            }
        }
    }
}

/// Each cell's passable neighbours in [`Move::STEPS`] order (NIL where none, and for every
/// slot of a blocked cell): the table the resolver and the planner walk.
pub(crate) fn neighbour_table(grid: &Grid) -> Vec<[u32; 4]> {
    (0..grid.len())
        .map(|i| {
            let c = grid.cell(i);
            let mut out = [NIL; 4];
            if grid.is_free(c) {
                for (k, m) in Move::STEPS.into_iter().enumerate() {
                    if let Some(n) = m.apply(grid, c) {
                        out[k] = grid.index(n) as u32;
                    }
                }
            }
            out
        })
        .collect()
}

/// SplitMix64's finaliser: a well-mixed hash of `x`.
fn mix(mut x: u64) -> u64 {
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}
