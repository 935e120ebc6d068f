//! Prioritized planning with space-time A* (Silver 2005; Erdmann & Lozano-Pérez 1987): the
//! coordinator's look-ahead. Agents are planned one after another from the current
//! configuration; each avoids the vertices and edges reserved by the agents planned before it
//! and then holds its goal forever. An agent whose search fails (node budget, horizon, or no
//! way around) simply has no plan. [`Planner::refine`] then improves the plan by large
//! neighbourhood search (MAPF-LNS): a few agents forget their paths and are replanned, the
//! result kept only when cheaper. Every table is sized once; replanning and refining allocate
//! nothing.

use crate::pibt::NIL;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Space-time tables and the current plan.
#[derive(Debug, Clone)]
pub(crate) struct Planner {
    cells: usize,
    /// Last time index a plan may use.
    horizon: usize,
    /// Who reserved (t, v), at `t * cells + v`.
    res: Vec<u32>,
    /// From which time a cell is held forever (an agent resting on its goal, a hung robot).
    hold: Vec<u32>,
    /// Who holds a cell forever (see `hold`).
    holder: Vec<u32>,
    /// An upper bound of the last time index any plan passes a cell (NIL = never); exact after
    /// [`Planner::plan`]'s first pass, possibly stale (too late) after refinement removed paths.
    last: Vec<u32>,
    /// Whether a plan may step away from its goal (raise its distance) when it could wait.
    pub voluntary_detours: bool,
    /// A* visited stamps, at `t * cells + v`.
    stamp: Vec<u32>,
    /// The move index (0 wait, 1..=4 the neighbour slot + 1) that reached (t, v).
    parent: Vec<u8>,
    /// The fewest ticks spent on other agents' goal cells by a path found to (t, v), at
    /// `t * cells + v` (valid where `stamp` is current).
    detained: Vec<u16>,
    generation: u32,
    /// A* open list: (f, ticks on others' goals, t, v); least f, then least ticks on others'
    /// goals, then deepest first.
    heap: BinaryHeap<(Reverse<u32>, Reverse<u16>, u32, u32)>,
    /// The agent whose goal each cell is (NIL = nobody's; [`Planner::set_goals`]).
    goal_owner: Vec<u32>,
    /// Whether a search, among its shortest paths, takes one that spends the fewest ticks on
    /// other agents' goal cells (measured on the tuning set: counting only the ticks from
    /// which the owner could rest there did worse).
    pub avoid_goals: bool,
    /// Per agent: the planned cells, `(horizon + 1)` slots each.
    pub cells_of: Vec<u32>,
    /// Per agent: the time index it arrives for good, NIL = no plan.
    pub arrive: Vec<u32>,
    /// The refinement's neighbourhood (agents replanned together).
    nb: Vec<u32>,
    /// Whether an agent is in `nb`.
    in_nb: Vec<bool>,
    /// The neighbourhood's paths before replanning them (from the start time on).
    saved: Vec<u32>,
    /// The neighbourhood's arrival times before replanning them.
    saved_arrive: Vec<u32>,
    /// The refinement's random state (xorshift64).
    rng: u64,
    /// Refinement steps that lowered the plan's cost.
    pub improved: u32,
    /// A copy of `cells_of` and `arrive` ([`Planner::save`]).
    kept_cells: Vec<u32>,
    kept_arrive: Vec<u32>,
    /// Whether refinement chooses among every [`Neighbourhood`] adaptively (else only
    /// [`Neighbourhood::Delayed`]).
    pub adaptive: bool,
    /// The adaptive choice's weight of each [`Neighbourhood`].
    weights: [f64; KINDS],
    /// Cells with three or more passable neighbours (where ways cross), set once.
    junctions: Vec<u32>,
    /// The junction neighbourhood's breadth-first queue and visited stamps.
    queue: Vec<u32>,
    seen: Vec<u32>,
    seen_gen: u32,
}

/// What the planner reads of the world: where the agents are and must go, and the grid.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Fleet<'a> {
    /// Each agent's cell (NIL = absent).
    pub pos: &'a [u32],
    /// Each agent's goal cell.
    pub goal: &'a [u32],
    /// Agents that never move (silent robots).
    pub fixed: &'a [bool],
    /// Each cell's passable neighbours (NIL where none).
    pub nbr: &'a [[u32; 4]],
    /// Each agent's distance table.
    pub dist: &'a [Vec<u32>],
}

/// Agents replanned together in one refinement step (MAPF-LNS's neighbourhood size; 4 and 16
/// measured worse on the tuning set).
const NEIGHBOURHOOD: usize = 8;

/// What an agent without a plan costs the refinement: more than any summed arrival, so a
/// refinement step never trades a routed agent for the others' arrivals (it did with a
/// penalty of 4 × the horizon: plans that left agents unrouted, recomputed at once).
const UNPLANNED: u64 = 1 << 32;

/// How a refinement step chooses the agents it replans (MAPF-LNS's neighbourhoods, Li et al.
/// 2021, chosen adaptively as there).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Neighbourhood {
    /// One of the most delayed agents and the agents planned across its shortest way.
    Delayed,
    /// The agents planned through the cells nearest a random junction.
    Junction,
    /// Agents drawn at random.
    Random,
}

const KINDS: usize = 3;
const NEIGHBOURHOODS: [Neighbourhood; KINDS] = [
    Neighbourhood::Delayed,
    Neighbourhood::Junction,
    Neighbourhood::Random,
];

/// How fast the adaptive weights follow the improvements (ALNS's reaction factor; 0.01 and 0.5
/// measured no better on the tuning set).
const REACTION: f64 = 0.1;

/// Cells the junction neighbourhood visits at most around its junction.
const JUNCTION_CELLS: usize = 64;

impl Planner {
    /// Tables for `agents` agents on `cells` cells with plans up to `horizon` ticks.
    pub fn new(agents: usize, cells: usize, horizon: usize, node_budget: u32) -> Planner {
        let slots = (horizon + 1) * cells;
        Planner {
            cells,
            horizon,
            res: vec![NIL; slots],
            hold: vec![NIL; cells],
            holder: vec![NIL; cells],
            voluntary_detours: false,
            last: vec![NIL; cells],
            stamp: vec![0; slots],
            parent: vec![0; slots],
            detained: vec![0; slots],
            goal_owner: vec![NIL; if agents == 0 { 0 } else { cells }],
            avoid_goals: false,
            generation: 0,
            // each expansion pushes at most 5 nodes
            heap: BinaryHeap::with_capacity(if agents == 0 {
                0
            } else {
                5 * node_budget as usize + 5
            }),
            cells_of: vec![NIL; agents * (horizon + 1)],
            arrive: vec![NIL; agents],
            nb: Vec::with_capacity(NEIGHBOURHOOD),
            in_nb: vec![false; agents],
            saved: vec![NIL; NEIGHBOURHOOD * (horizon + 1)],
            saved_arrive: vec![NIL; NEIGHBOURHOOD],
            rng: 0x2545_f491_4f6c_dd1d,
            improved: 0,
            kept_cells: vec![NIL; agents * (horizon + 1)],
            kept_arrive: vec![NIL; agents],
            adaptive: false,
            weights: [1.0; KINDS],
            junctions: Vec::new(),
            queue: Vec::with_capacity(if agents == 0 { 0 } else { cells }),
            seen: vec![0; if agents == 0 { 0 } else { cells }],
            seen_gen: 0,
        }
    }

    /// Notes the junctions of the grid whose passable neighbours are `nbr` (once, before any
    /// refinement: it allocates).
    pub fn set_junctions(&mut self, nbr: &[[u32; 4]]) {
        if self.arrive.is_empty() {
            return;
        }
        self.junctions = (0..nbr.len() as u32)
            .filter(|&v| nbr[v as usize].iter().filter(|&&u| u != NIL).count() >= 3)
            .collect();
    }

    /// Notes every agent's goal cell (once, before any search; goals are distinct).
    pub fn set_goals(&mut self, goal: &[u32]) {
        if self.arrive.is_empty() {
            return;
        }
        self.goal_owner.fill(NIL);
        for (a, &g) in goal.iter().enumerate() {
            self.goal_owner[g as usize] = a as u32;
        }
    }

    /// Keeps a copy of the current plan.
    pub fn save(&mut self) {
        self.kept_cells.copy_from_slice(&self.cells_of);
        self.kept_arrive.copy_from_slice(&self.arrive);
    }

    /// Makes the plan kept by [`Planner::save`] the current one again.
    pub fn restore(&mut self) {
        self.clear();
        self.cells_of.copy_from_slice(&self.kept_cells);
        self.arrive.copy_from_slice(&self.kept_arrive);
        for a in 0..self.arrive.len() {
            if self.arrive[a] != NIL {
                self.reserve_path(a, 0);
            }
        }
    }

    /// Seeds the refinement's tie-breaking.
    pub fn seed(&mut self, seed: u64) {
        self.rng = seed | 1;
    }

    /// A pseudo-random number below `n` (n > 0).
    fn below(&mut self, n: usize) -> usize {
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 7;
        self.rng ^= self.rng << 17;
        ((self.rng >> 32) as usize) % n
    }

    /// The planned cell of `agent` at time index `t` (staying on its goal after arriving), or
    /// NIL without a plan.
    pub fn at(&self, agent: usize, t: usize) -> u32 {
        let a = self.arrive[agent];
        if a == NIL {
            return NIL;
        }
        self.cells_of[agent * (self.horizon + 1) + t.min(a as usize)]
    }

    /// Forgets every plan and reservation.
    fn clear(&mut self) {
        for a in 0..self.arrive.len() {
            self.unreserve(a, 0);
        }
        self.last.fill(NIL);
        self.arrive.fill(NIL);
    }

    /// Reserves agent `a`'s planned cells from time index `t0` to its arrival, and its goal
    /// from then on.
    fn reserve_path(&mut self, a: usize, t0: usize) {
        let h = self.horizon + 1;
        let end = self.arrive[a] as usize;
        for t in t0..=end {
            let v = self.cells_of[a * h + t];
            self.reserve(a, t, v);
        }
        let g = self.cells_of[a * h + end] as usize;
        self.hold[g] = end as u32;
        self.holder[g] = a as u32;
    }

    /// Takes back what [`Planner::reserve_path`] reserved for agent `a` from `t0` on (nothing
    /// without a plan); `last` stays an upper bound.
    fn unreserve(&mut self, a: usize, t0: usize) {
        let end = self.arrive[a];
        if end == NIL {
            return;
        }
        let h = self.horizon + 1;
        for t in t0..=end as usize {
            let i = t * self.cells + self.cells_of[a * h + t] as usize;
            if self.res[i] == a as u32 {
                self.res[i] = NIL;
            }
        }
        let g = self.cells_of[a * h + end as usize] as usize;
        if self.holder[g] == a as u32 {
            self.hold[g] = NIL;
            self.holder[g] = NIL;
        }
    }

    /// Whether an agent other than `who` is planned on `v` after time index `t`.
    fn passes_after(&self, v: u32, t: usize, who: u32) -> bool {
        let l = self.last[v as usize];
        if l == NIL || l as usize <= t {
            return false;
        }
        (t + 1..=(l as usize).min(self.horizon)).any(|u| {
            let r = self.res[u * self.cells + v as usize];
            r != NIL && r != who
        })
    }

    /// Whether `v` is the goal of an agent other than `a` (one that will rest there).
    fn rests_on(&self, a: usize, v: u32) -> bool {
        let o = self.goal_owner[v as usize];
        o != NIL && o as usize != a
    }

    /// Marks (t, v) as used by `agent`.
    fn reserve(&mut self, agent: usize, t: usize, v: u32) {
        let i = t * self.cells + v as usize;
        self.res[i] = agent as u32;
        let l = &mut self.last[v as usize];
        if *l == NIL || (*l as usize) < t {
            *l = t as u32;
        }
    }

    /// The agent the plan puts on cell `v` at time index `t` (NIL = nobody); `t` past the
    /// horizon counts as the horizon.
    pub fn occupant(&self, t: usize, v: u32) -> u32 {
        let t = t.min(self.horizon);
        let r = self.res[t * self.cells + v as usize];
        if r != NIL {
            return r;
        }
        if self.hold[v as usize] as usize <= t {
            return self.holder[v as usize];
        }
        NIL
    }

    /// Whether (t, v) is taken.
    fn taken(&self, t: usize, v: u32) -> bool {
        self.res[t * self.cells + v as usize] != NIL || self.hold[v as usize] as usize <= t
    }

    /// Plans every agent in `order` from its cell in `fleet` (absent ones not; fixed ones hold
    /// their cells); each agent's search may expand `node_budget` nodes, all of them
    /// `total_budget` (agents left when it is spent get no plan). Returns the expansions spent.
    pub fn plan(
        &mut self,
        order: &[u32],
        fleet: &Fleet<'_>,
        node_budget: u32,
        total_budget: u64,
    ) -> u64 {
        let Fleet {
            pos,
            goal,
            fixed,
            nbr,
            dist,
        } = *fleet;
        self.clear();
        // robots that will not move hold their cells from now on
        for (i, &p) in pos.iter().enumerate() {
            if p != NIL && fixed[i] {
                self.hold_forever(i, p);
            }
        }
        let mut spent = 0u64;
        for &a in order {
            let a = a as usize;
            if pos[a] == NIL || fixed[a] || spent >= total_budget {
                continue;
            }
            let (found, n) = self.astar(a, pos[a], 0, goal[a], nbr, &dist[a], node_budget, NIL);
            spent += u64::from(n);
            if found {
                self.reserve_path(a, 0);
            }
        }
        spent
    }

    /// Makes the plan the configurations `configs` (each `agents` cells, the first one the
    /// agents' cells in `fleet`, the last one every movable agent on its goal): what a
    /// complete search found. Each agent arrives for good where it last reaches its goal.
    /// Returns false, leaving the current plan as it was, when they take more ticks than the
    /// horizon.
    pub fn load(&mut self, configs: &[u32], fleet: &Fleet<'_>) -> bool {
        let n = self.arrive.len();
        if n == 0 || !configs.len().is_multiple_of(n) || configs.len() / n > self.horizon + 1 {
            return false;
        }
        self.clear();
        let (h, steps) = (self.horizon + 1, configs.len() / n);
        for a in 0..n {
            let p = fleet.pos[a];
            if p == NIL {
                continue;
            }
            if fleet.fixed[a] {
                self.hold_forever(a, p);
                continue;
            }
            let at = |t: usize| configs[t * n + a];
            let mut end = steps - 1;
            while end > 0 && at(end - 1) == fleet.goal[a] {
                end -= 1;
            }
            for t in 0..=end {
                self.cells_of[a * h + t] = at(t);
            }
            self.arrive[a] = end as u32;
            self.reserve_path(a, 0);
        }
        true
    }

    /// Makes agent `a`, which never moves, hold cell `p` from time index 0 on.
    fn hold_forever(&mut self, a: usize, p: u32) {
        self.hold[p as usize] = 0;
        self.holder[p as usize] = a as u32;
        self.arrive[a] = 0;
        self.cells_of[a * (self.horizon + 1)] = p;
    }

    /// The cost refinement counts for agent `a`: its arrival, or [`UNPLANNED`] without a plan.
    fn cost(&self, a: usize) -> u64 {
        match self.arrive[a] {
            NIL => UNPLANNED,
            t => u64::from(t),
        }
    }

    /// Where agent `a` starts a refinement from `t0`: its plan's cell at `t0`, else (unplanned,
    /// `t0` = 0) its cell.
    fn start_of(&self, a: usize, t0: usize, pos: &[u32]) -> u32 {
        if self.arrive[a] == NIL {
            pos[a]
        } else {
            self.cells_of[a * (self.horizon + 1) + t0.min(self.arrive[a] as usize)]
        }
    }

    /// Whether refinement from `t0` may replan agent `a`: present, not fixed, not arrived.
    fn eligible(&self, a: usize, t0: usize, f: &Fleet<'_>) -> bool {
        f.pos[a] != NIL && !f.fixed[a] && (self.arrive[a] == NIL || self.arrive[a] as usize > t0)
    }

    /// Adds agent `a` to the neighbourhood if it is eligible and not in it yet.
    fn add(&mut self, a: u32, t0: usize, f: &Fleet<'_>) {
        if self.nb.len() < NEIGHBOURHOOD
            && !self.in_nb[a as usize]
            && self.eligible(a as usize, t0, f)
        {
            self.in_nb[a as usize] = true;
            self.nb.push(a);
        }
    }

    /// Adds the agents planned on cell `v` from `t0` on (and the one resting there) to the
    /// neighbourhood; returns the work done, in expansions.
    fn add_passing(&mut self, v: u32, t0: usize, f: &Fleet<'_>) -> u64 {
        let l = self.last[v as usize];
        let top = if l == NIL {
            t0
        } else {
            (l as usize).min(self.horizon)
        };
        for t in t0..=top {
            let r = self.res[t * self.cells + v as usize];
            if r != NIL {
                self.add(r, t0, f);
                if self.nb.len() == NEIGHBOURHOOD {
                    break;
                }
            }
        }
        let g = self.holder[v as usize];
        if g != NIL {
            self.add(g, t0, f);
        }
        1 + top.saturating_sub(t0) as u64 / 16
    }

    /// The neighbourhood of one of the most delayed of a few agents drawn at random: it and
    /// the agents planned across its shortest way (ties broken at random). Returns the work
    /// done, in expansions; leaves the neighbourhood empty when the agents drawn are on time.
    fn nb_delayed(&mut self, t0: usize, f: &Fleet<'_>) -> u64 {
        let (pos, dist) = (f.pos, f.dist);
        let n = self.arrive.len();
        let mut seed = NIL;
        let mut seed_delay = 0u64;
        for _ in 0..4 {
            let a = self.below(n);
            if !self.eligible(a, t0, f) {
                continue;
            }
            let d = self
                .cost(a)
                .saturating_sub(t0 as u64 + u64::from(dist[a][self.start_of(a, t0, pos) as usize]));
            if d > seed_delay {
                seed = a as u32;
                seed_delay = d;
            }
        }
        let mut spent = 4;
        if seed == NIL {
            return spent;
        }
        self.add(seed, t0, f);
        let s = seed as usize;
        let mut v = self.start_of(s, t0, pos);
        while v != f.goal[s] && self.nb.len() < NEIGHBOURHOOD {
            let mut best = NIL;
            let mut ties = 0;
            for &u in &f.nbr[v as usize] {
                if u != NIL && dist[s][u as usize] < dist[s][v as usize] {
                    ties += 1;
                    if self.below(ties) == 0 {
                        best = u;
                    }
                }
            }
            if best == NIL {
                break;
            }
            v = best;
            spent += self.add_passing(v, t0, f);
        }
        spent
    }

    /// The neighbourhood of a random junction: the agents planned through it and through the
    /// cells nearest it (breadth first, at most [`JUNCTION_CELLS`]). Returns the work done.
    fn nb_junction(&mut self, t0: usize, f: &Fleet<'_>) -> u64 {
        if self.junctions.is_empty() {
            return 1;
        }
        let k = self.below(self.junctions.len());
        let v0 = self.junctions[k];
        let gen_ = next_generation(&mut self.seen_gen, &mut self.seen);
        self.queue.clear();
        self.queue.push(v0);
        self.seen[v0 as usize] = gen_;
        let mut spent = 1;
        let mut head = 0;
        while head < self.queue.len() && head < JUNCTION_CELLS && self.nb.len() < NEIGHBOURHOOD {
            let v = self.queue[head];
            head += 1;
            spent += self.add_passing(v, t0, f);
            for &u in &f.nbr[v as usize] {
                if u != NIL && self.seen[u as usize] != gen_ {
                    self.seen[u as usize] = gen_;
                    self.queue.push(u);
                }
            }
        }
        spent
    }

    /// A neighbourhood of agents drawn at random. Returns the work done.
    fn nb_random(&mut self, t0: usize, f: &Fleet<'_>) -> u64 {
        let n = self.arrive.len();
        let mut spent = 0;
        while spent < 4 * NEIGHBOURHOOD as u64 && self.nb.len() < NEIGHBOURHOOD {
            let a = self.below(n) as u32;
            self.add(a, t0, f);
            spent += 1;
        }
        spent
    }

    /// The neighbourhood the next refinement step uses: drawn in proportion to the weights
    /// when adaptive, else always [`Neighbourhood::Delayed`].
    fn pick(&mut self) -> Neighbourhood {
        if !self.adaptive {
            return Neighbourhood::Delayed;
        }
        let total: f64 = self.weights.iter().sum();
        let mut x = self.below(1 << 20) as f64 / f64::from(1u32 << 20) * total;
        for (k, &w) in self.weights.iter().enumerate() {
            if x < w {
                return NEIGHBOURHOODS[k];
            }
            x -= w;
        }
        NEIGHBOURHOODS[KINDS - 1]
    }

    /// Large neighbourhood search (Li et al., "Anytime Multi-Agent Path Finding via Large
    /// Neighborhood Search", IJCAI 2021) on the plan from time index `t0` on: a few agents
    /// forget their paths and are replanned one after another in a random order; the new paths
    /// are kept only when their summed arrival is lower. The agents are chosen by one of the
    /// [`Neighbourhood`]s: with `adaptive`, each step draws one in proportion to weights that
    /// follow the cost each lowered lately (adaptive LNS), else always the delayed agent's.
    /// Spends about `budget` A* expansions; agents already arrived by `t0` and fixed ones are
    /// never touched. Returns the expansions spent.
    pub fn refine(&mut self, t0: usize, f: &Fleet<'_>, node_budget: u32, budget: u64) -> u64 {
        let Fleet {
            pos,
            goal,
            nbr,
            dist,
            ..
        } = *f;
        let h = self.horizon + 1;
        let n = self.arrive.len();
        let mut spent = 0u64;
        if t0 > self.horizon || n == 0 {
            return 0;
        }
        while spent < budget {
            self.nb.clear();
            let kind = self.pick();
            spent += match kind {
                Neighbourhood::Delayed => self.nb_delayed(t0, f),
                Neighbourhood::Junction => self.nb_junction(t0, f),
                Neighbourhood::Random => self.nb_random(t0, f),
            };
            if self.nb.is_empty() {
                continue;
            }
            // forget their paths, remembering them
            let mut before = 0u64;
            for k in 0..self.nb.len() {
                let a = self.nb[k] as usize;
                before += self.cost(a);
                self.saved_arrive[k] = self.arrive[a];
                if self.arrive[a] != NIL {
                    let end = self.arrive[a] as usize;
                    self.saved[k * h + t0..=k * h + end]
                        .copy_from_slice(&self.cells_of[a * h + t0..=a * h + end]);
                    self.unreserve(a, t0);
                }
            }
            // replan them in a random order
            let m = self.nb.len();
            for k in (1..m).rev() {
                let j = self.below(k + 1);
                self.nb.swap(k, j);
                self.saved_arrive.swap(k, j);
                for t in t0..h {
                    self.saved.swap(k * h + t, j * h + t);
                }
            }
            let mut after = 0u64;
            // the fewest ticks the agents not yet replanned could take
            let from = |p: &Planner, k: usize| {
                if p.saved_arrive[k] == NIL {
                    pos[p.nb[k] as usize]
                } else {
                    p.saved[k * h + t0]
                }
            };
            let mut rest: u64 = (0..m)
                .map(|k| t0 as u64 + u64::from(dist[self.nb[k] as usize][from(self, k) as usize]))
                .sum();
            for k in 0..m {
                let a = self.nb[k] as usize;
                let s = from(self, k);
                rest -= t0 as u64 + u64::from(dist[a][s as usize]);
                // arriving later than this cannot make the neighbourhood cheaper
                let Some(bound) = before.checked_sub(1 + after + rest) else {
                    break;
                };
                let bound = bound.min(u64::from(NIL - 1)) as u32;
                let (found, e) = self.astar(a, s, t0, goal[a], nbr, &dist[a], node_budget, bound);
                spent += u64::from(e);
                if found {
                    self.reserve_path(a, t0);
                }
                after += self.cost(a);
                if after >= before {
                    break;
                }
            }
            if self.adaptive {
                let gain = before.saturating_sub(after) as f64;
                let w = &mut self.weights[kind as usize];
                *w = (REACTION * gain + (1.0 - REACTION) * *w).max(0.01);
            }
            if after < before {
                self.improved += 1;
            } else {
                // put the old paths back
                for k in 0..m {
                    let a = self.nb[k] as usize;
                    self.unreserve(a, t0);
                    self.arrive[a] = self.saved_arrive[k];
                    if self.arrive[a] != NIL {
                        let end = self.arrive[a] as usize;
                        self.cells_of[a * h + t0..=a * h + end]
                            .copy_from_slice(&self.saved[k * h + t0..=k * h + end]);
                        self.reserve_path(a, t0);
                    }
                }
            }
            for k in 0..m {
                self.in_nb[self.nb[k] as usize] = false;
            }
        }
        spent
    }

    /// Space-time A* for agent `a` from `start` at time index `t0`: on success its path is in
    /// `cells_of` from `t0` to `arrive[a]` (not yet reserved); `arrive[a]` is NIL on failure.
    /// Returns whether it found one and the expansions spent.
    #[allow(clippy::too_many_arguments)]
    fn astar(
        &mut self,
        a: usize,
        start: u32,
        t0: usize,
        goal: u32,
        nbr: &[[u32; 4]],
        dist: &[u32],
        node_budget: u32,
        max_arrive: u32,
    ) -> (bool, u32) {
        self.arrive[a] = NIL;
        let gen_ = next_generation(&mut self.generation, &mut self.stamp);
        self.heap.clear();
        self.stamp[t0 * self.cells + start as usize] = gen_;
        self.detained[t0 * self.cells + start as usize] = 0;
        self.heap.push((
            Reverse(t0 as u32 + dist[start as usize]),
            Reverse(0),
            t0 as u32,
            start,
        ));
        let mut expanded = 0u32;
        while let Some((Reverse(f), Reverse(d), t, v)) = self.heap.pop() {
            if f > max_arrive {
                return (false, expanded);
            }
            let t = t as usize;
            if d > self.detained[t * self.cells + v as usize] {
                continue; // reached again with fewer ticks on others' goals
            }
            if v == goal && !self.passes_after(v, t, a as u32) {
                // walk back from (t, goal), writing the path
                let h = self.horizon + 1;
                let mut u = goal;
                for s in (t0..=t).rev() {
                    self.cells_of[a * h + s] = u;
                    if s > t0 {
                        let m = self.parent[s * self.cells + u as usize];
                        u = back(nbr, u, m);
                    }
                }
                self.arrive[a] = t as u32;
                return (true, expanded);
            }
            expanded += 1;
            if expanded > node_budget {
                return (false, expanded);
            }
            let nt = t + 1;
            if nt > self.horizon {
                continue;
            }
            for m in 0..5u8 {
                let u = if m == 0 {
                    v
                } else {
                    nbr[v as usize][m as usize - 1]
                };
                if u == NIL || self.taken(nt, u) {
                    continue;
                }
                if u != v {
                    // swap: whoever is on u at t must not be on v at t + 1
                    let b = self.res[t * self.cells + u as usize];
                    if b != NIL && self.res[nt * self.cells + v as usize] == b {
                        continue;
                    }
                }
                let du = dist[u as usize];
                if du == u32::MAX {
                    continue;
                }
                // a robot steps away from its goal only when it cannot stay (it is pushed)
                if !self.voluntary_detours && du > dist[v as usize] && !self.taken(nt, v) {
                    continue;
                }
                let i = nt * self.cells + u as usize;
                // a tick on another agent's goal counts against a path
                let nd = if self.avoid_goals && self.rests_on(a, u) {
                    d.saturating_add(1)
                } else {
                    d
                };
                if self.stamp[i] == gen_ && self.detained[i] <= nd {
                    continue;
                }
                self.stamp[i] = gen_;
                self.parent[i] = m;
                self.detained[i] = nd;
                // least f first, then fewest ticks on others' goals, then deeper (later)
                self.heap
                    .push((Reverse(nt as u32 + du), Reverse(nd), nt as u32, u));
            }
        }
        (false, expanded)
    }
}

/// The next visit stamp after `generation` (clearing `stamps` when it wraps to 0).
fn next_generation(generation: &mut u32, stamps: &mut [u32]) -> u32 {
    *generation = generation.wrapping_add(1);
    if *generation == 0 {
        stamps.fill(0);
        *generation = 1;
    }
    *generation
}

/// The cell a move index came from: the inverse of step `m` from `v`.
fn back(nbr: &[[u32; 4]], v: u32, m: u8) -> u32 {
    if m == 0 {
        return v;
    }
    // the opposite slot: up <-> down (0 <-> 2), right <-> left (1 <-> 3)
    let opposite = (m as usize - 1 + 2) % 4;
    nbr[v as usize][opposite]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::instance::Instance;
    use planner::{Cell, Grid};

    /// A 14×14 grid with scattered walls and 24 agents.
    fn setup(seed: u64) -> Instance {
        let (w, h) = (14usize, 14usize);
        let mut x = seed | 1;
        let mut next = move |n: usize| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 33) as usize % n
        };
        let free: Vec<bool> = (0..w * h).map(|_| next(100) >= 15).collect();
        let grid = Grid::new(w, h, free).unwrap();
        let cells: Vec<Cell> = (0..grid.len())
            .map(|i| grid.cell(i))
            .filter(|c| grid.is_free(*c))
            .collect();
        loop {
            let (mut s, mut g) = (Vec::new(), Vec::new());
            while s.len() < 24 {
                let (a, b) = (cells[next(cells.len())], cells[next(cells.len())]);
                if !s.contains(&a) && !g.contains(&b) {
                    s.push(a);
                    g.push(b);
                }
            }
            if let Ok(inst) = Instance::new(grid.clone(), s, g) {
                return inst;
            }
        }
    }

    /// Every planned path starts on the agent's cell, moves to neighbours, ends on its goal,
    /// and no two plans meet on a cell or swap (an arrived agent holds its goal).
    fn assert_valid(p: &Planner, pos: &[u32], goal: &[u32], nbr: &[[u32; 4]]) {
        let n = pos.len();
        for a in 0..n {
            if p.arrive[a] == NIL {
                continue;
            }
            assert_eq!(p.at(a, 0), pos[a]);
            assert_eq!(p.at(a, p.arrive[a] as usize), goal[a]);
            for t in 1..=p.horizon + 1 {
                let (u, v) = (p.at(a, t - 1), p.at(a, t));
                assert!(
                    u == v || nbr[u as usize].contains(&v),
                    "agent {a} jumps at {t}"
                );
            }
        }
        for t in 0..=p.horizon + 1 {
            for a in 0..n {
                for b in a + 1..n {
                    if p.arrive[a] == NIL || p.arrive[b] == NIL {
                        continue;
                    }
                    assert_ne!(p.at(a, t), p.at(b, t), "agents {a}, {b} meet at {t}");
                    if t > 0 {
                        let swap = p.at(a, t) == p.at(b, t - 1) && p.at(b, t) == p.at(a, t - 1);
                        assert!(!swap, "agents {a}, {b} swap at {t}");
                    }
                }
            }
        }
    }

    #[test]
    fn refining_keeps_every_plan_valid_and_never_raises_its_cost() {
        let mut improved = 0;
        for seed in 1..=6u64 {
            let inst = setup(seed);
            let n = inst.agents();
            let view = View::of(&inst);
            let (pos, goal, nbr, dist) = (&view.pos, &view.goal, &view.nbr, view.dist);
            let mut order: Vec<u32> = (0..n as u32).collect();
            order.sort_by_key(|&i| dist[i as usize][pos[i as usize] as usize]);
            let mut p = Planner::new(n, inst.grid().len(), 80, 5000);
            p.voluntary_detours = true;
            p.seed(seed);
            // every neighbourhood on the odd seeds, the delayed agent's alone on the even ones
            p.adaptive = seed % 2 == 1;
            p.set_junctions(nbr);
            let f = view.fleet();
            p.plan(&order, &f, 5000, 1 << 20);
            assert_valid(&p, pos, goal, nbr);
            let cost = |p: &Planner| (0..n).map(|a| p.cost(a)).sum::<u64>();
            let before = cost(&p);
            p.save();
            p.refine(0, &f, 2000, 200_000);
            assert_valid(&p, pos, goal, nbr);
            assert!(cost(&p) <= before, "seed {seed}: {} > {before}", cost(&p));
            // refining from a later time keeps the prefix and stays valid
            let prefix: Vec<u32> = (0..n).map(|a| p.at(a, 3)).collect();
            p.refine(3, &f, 2000, 100_000);
            assert_valid(&p, pos, goal, nbr);
            assert_eq!((0..n).map(|a| p.at(a, 3)).collect::<Vec<_>>(), prefix);
            // and a kept plan comes back exactly
            let after = cost(&p);
            p.restore();
            assert_valid(&p, pos, goal, nbr);
            assert_eq!(cost(&p), before);
            assert!(after <= before);
            improved += p.improved;
        }
        assert!(improved > 0, "the refinement lowered some plan's cost");
    }

    /// What the planner reads of an instance, owned: every agent on its start.
    struct View<'a> {
        pos: Vec<u32>,
        goal: Vec<u32>,
        fixed: Vec<bool>,
        nbr: Vec<[u32; 4]>,
        dist: &'a [Vec<u32>],
    }

    impl<'a> View<'a> {
        fn of(inst: &'a Instance) -> View<'a> {
            let idx = |c: Cell| inst.grid().index(c) as u32;
            View {
                pos: inst.starts().iter().map(|&c| idx(c)).collect(),
                goal: inst.goals().iter().map(|&c| idx(c)).collect(),
                fixed: vec![false; inst.agents()],
                nbr: crate::world::neighbour_table(inst.grid()),
                dist: inst.dist_tables(),
            }
        }

        fn fleet(&self) -> Fleet<'_> {
            Fleet {
                pos: &self.pos,
                goal: &self.goal,
                fixed: &self.fixed,
                nbr: &self.nbr,
                dist: self.dist,
            }
        }
    }

    #[test]
    fn a_complete_search_plan_loads_with_every_agent_routed_and_refines_validly() {
        use crate::pibt::Pibt;
        use crate::search::{Outcome, Problem, lacam};
        for seed in 1..=4u64 {
            let inst = setup(seed);
            let n = inst.agents();
            let view = View::of(&inst);
            let (pos, goal, nbr) = (&view.pos, &view.goal, &view.nbr);
            let problem = Problem {
                goal,
                fixed: &view.fixed,
                nbr,
                dist: view.dist,
            };
            let mut pibt = Pibt::new(n, inst.grid().len());
            let Outcome::Solved(configs) = lacam(&mut pibt, &problem, pos, 100_000, seed) else {
                panic!("seed {seed}: the instance is solvable");
            };
            let f = view.fleet();
            // too short a horizon for the search's plan: refused, the plan left as it was
            let steps = configs.len() / n;
            let mut short = Planner::new(n, inst.grid().len(), steps - 2, 5000);
            short.plan(&(0..n as u32).collect::<Vec<_>>(), &f, 5000, 1 << 20);
            let kept = (short.arrive.clone(), short.cells_of.clone());
            assert!(
                short.arrive.iter().any(|&a| a != NIL),
                "seed {seed}: a plan to keep"
            );
            assert!(!short.load(&configs, &f));
            assert_eq!((short.arrive.clone(), short.cells_of.clone()), kept);
            assert_valid(&short, pos, goal, nbr);
            let mut p = Planner::new(n, inst.grid().len(), steps + 20, 5000);
            p.voluntary_detours = true;
            p.seed(seed);
            p.adaptive = true;
            p.set_junctions(nbr);
            p.set_goals(goal);
            assert!(p.load(&configs, &f));
            assert!(
                p.arrive.iter().all(|&a| a != NIL),
                "seed {seed}: every agent routed"
            );
            assert_valid(&p, pos, goal, nbr);
            // each agent arrives where its last step onto its goal is in the search's plan
            for a in 0..n {
                let t = p.arrive[a] as usize;
                assert!((t..steps).all(|u| configs[u * n + a] == goal[a]));
                assert!(t == 0 || configs[(t - 1) * n + a] != goal[a]);
            }
            let cost = |p: &Planner| (0..n).map(|a| p.cost(a)).sum::<u64>();
            let before = cost(&p);
            p.refine(0, &f, 2000, 200_000);
            assert_valid(&p, pos, goal, nbr);
            assert!(cost(&p) <= before);
        }
    }

    #[test]
    fn among_equally_short_ways_a_search_avoids_other_agents_goal_cells() {
        // two lanes; agent 0 goes from the top left to the bottom right (every way takes 6
        // ticks), agent 1 rests on the bottom lane at x = 2: agent 0 keeps to the top lane past it
        let grid = planner::map::parse_ascii("lanes", b"......\n......\n")
            .unwrap()
            .grid;
        let (s0, g0) = (Cell::new(0, 0), Cell::new(5, 1));
        let (s1, g1) = (Cell::new(2, 0), Cell::new(2, 1));
        let inst = Instance::new(grid, vec![s0, s1], vec![g0, g1]).unwrap();
        let view = View::of(&inst);
        let (pos, goal, nbr) = (&view.pos, &view.goal, &view.nbr);
        let f = view.fleet();
        let on_goal_of_1 = |p: &Planner| (0..=p.arrive[0] as usize).any(|t| p.at(0, t) == goal[1]);
        for avoid in [false, true] {
            let mut p = Planner::new(2, inst.grid().len(), 12, 5000);
            p.set_goals(goal);
            p.avoid_goals = avoid;
            // agent 0 alone first: agent 1 is planned after it
            p.plan(&[0], &f, 5000, 1 << 20);
            assert_eq!(p.arrive[0], 6, "a shortest way either way");
            assert_valid(&p, pos, goal, nbr);
            if avoid {
                assert!(
                    !on_goal_of_1(&p),
                    "{:?}",
                    (0..=6).map(|t| p.at(0, t)).collect::<Vec<_>>()
                );
            } else {
                // the tie-break on depth alone takes the bottom lane (what makes the test bite)
                assert!(on_goal_of_1(&p));
            }
        }
    }
}
