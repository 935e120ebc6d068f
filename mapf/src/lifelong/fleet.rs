//! The lifelong resolver: every tick it grants each robot one collision-free move, counts the
//! robots standing on their goal and deals them their next one (the goal stream), so the fleet
//! never stops.
//!
//! A tick is PIBT (priority inheritance with backtracking) with the swap/pull rule of Okumura's
//! lacam3 (`is_swap_required` / `is_swap_possible`): a robot that would push another deeper into
//! a corridor or dead end it cannot leave turns round and pulls it out instead, so a robot
//! waiting beside its goal in a dead end held by another never deadlocks the pair. Priorities
//! grow by one every tick a robot is under way and fall back to a unique fraction when it reaches
//! a goal (the reference's rule). A robot's candidate moves are its ranking (what its learned
//! values say, when the caller has one) and then the rest by BFS distance to its goal; without a
//! ranking, by distance with seeded random ties, cells nobody stands on now first
//! ([`LifelongConfig::prefer_free`], LaCAM*'s tie-break).
//!
//! The look-ahead ([`LifelongConfig::rollouts`], [`LifelongConfig::horizon`]): a tick tries a
//! few PIBT first moves (different random ties), plays each on for a few ticks by PIBT, and
//! keeps the first move after which the fleet is nearest its goals (a goal reached in the
//! rollout counts its distance and the ticks left). On tuning problems from six other maps and
//! seeds 4 first moves over 5 ticks gain about 6 % on PIBT+swap for 20 PIBT passes a tick.
//!
//! Distance tables are kept per goal cell, shared by every robot sent there, in a pool bounded
//! by [`LifelongConfig::table_budget`]; a table nobody uses stays until its slot is needed, so
//! goals that recur cost one BFS. Nothing allocates in a tick once the pool is warm.

use std::collections::VecDeque;

use planner::Cell;

use super::Problem;
use crate::moves::{Intent, Move};
use crate::pibt::NIL;
use crate::world::neighbour_table;

/// How the lifelong resolver plays.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LifelongConfig {
    /// The swap/pull rule (lacam3); off: plain PIBT, which deadlocks in dead ends.
    pub swap: bool,
    /// Seed of the tie-breaks and of the robots' priority fractions.
    pub seed: u64,
    /// Most bytes of distance tables kept (at least one table per robot is always kept).
    pub table_budget: usize,
    /// Among equally near candidates, prefer a cell nobody stands on now (LaCAM*'s tie-break).
    pub prefer_free: bool,
    /// First moves tried per tick by the look-ahead (0 or 1: one PIBT pass, no look-ahead).
    pub rollouts: u8,
    /// Ticks each look-ahead rollout is played for.
    pub horizon: u8,
}

impl Default for LifelongConfig {
    fn default() -> Self {
        LifelongConfig {
            swap: true,
            seed: 0,
            table_budget: 64 << 20,
            prefer_free: true,
            rollouts: 4,
            horizon: 5,
        }
    }
}

impl LifelongConfig {
    /// The one-step baseline: PIBT with the swap rule and nothing of the look-ahead or ties.
    pub fn pibt_swap() -> LifelongConfig {
        LifelongConfig {
            swap: true,
            seed: 0,
            table_budget: 64 << 20,
            prefer_free: false,
            rollouts: 0,
            horizon: 0,
        }
    }
}

/// Distances above this sort as equal in a robot's candidates (maps have fewer cells).
const DIST_CAP: u32 = (1 << 20) - 1;

/// Distance tables per goal cell, pooled (see the module docs).
#[derive(Debug, Clone)]
struct Tables {
    cells: usize,
    slot_of: Vec<u32>,
    goal_of: Vec<u32>,
    refs: Vec<u32>,
    dist: Vec<u32>,
    idle: VecDeque<u32>,
    max_slots: usize,
    queue: Vec<u32>,
    bfs_runs: u64,
}

impl Tables {
    fn new(cells: usize, robots: usize, budget: usize) -> Tables {
        let per = cells.max(1) * 4;
        Tables {
            cells,
            slot_of: vec![NIL; cells],
            goal_of: Vec::new(),
            refs: Vec::new(),
            dist: Vec::new(),
            idle: VecDeque::new(),
            max_slots: (budget / per).max(robots + 1).min(cells.max(1)),
            queue: Vec::with_capacity(cells),
            bfs_runs: 0,
        }
    }

    fn dist(&self, slot: u32) -> &[u32] {
        let s = slot as usize * self.cells;
        &self.dist[s..s + self.cells]
    }

    /// The slot of `goal`'s table, computed if not kept; one more user.
    fn acquire(&mut self, goal: u32, nbr: &[[u32; 4]]) -> u32 {
        let kept = self.slot_of[goal as usize];
        if kept != NIL {
            self.refs[kept as usize] += 1;
            return kept;
        }
        let slot = if self.goal_of.len() < self.max_slots {
            self.goal_of.push(NIL);
            self.refs.push(0);
            self.dist.resize(self.dist.len() + self.cells, u32::MAX);
            (self.goal_of.len() - 1) as u32
        } else {
            loop {
                match self.idle.pop_front() {
                    Some(s) if self.refs[s as usize] == 0 && self.goal_of[s as usize] != NIL => {
                        self.slot_of[self.goal_of[s as usize] as usize] = NIL;
                        break s;
                    }
                    Some(_) => continue,
                    None => {
                        // every kept table is in use: grow past the budget rather than fail
                        self.goal_of.push(NIL);
                        self.refs.push(0);
                        self.dist.resize(self.dist.len() + self.cells, u32::MAX);
                        break (self.goal_of.len() - 1) as u32;
                    }
                }
            }
        };
        self.goal_of[slot as usize] = goal;
        self.slot_of[goal as usize] = slot;
        self.refs[slot as usize] = 1;
        self.bfs(slot, goal, nbr);
        slot
    }

    fn release(&mut self, slot: u32) {
        let r = &mut self.refs[slot as usize];
        *r = r.saturating_sub(1);
        if *r == 0 {
            self.idle.push_back(slot);
        }
    }

    fn bfs(&mut self, slot: u32, goal: u32, nbr: &[[u32; 4]]) {
        self.bfs_runs += 1;
        let s = slot as usize * self.cells;
        let d = &mut self.dist[s..s + self.cells];
        d.fill(u32::MAX);
        d[goal as usize] = 0;
        self.queue.clear();
        self.queue.push(goal);
        let mut head = 0;
        while head < self.queue.len() {
            let u = self.queue[head];
            head += 1;
            let du = d[u as usize] + 1;
            for &v in &nbr[u as usize] {
                if v != NIL && d[v as usize] == u32::MAX {
                    d[v as usize] = du;
                    self.queue.push(v);
                }
            }
        }
    }
}

/// The look-ahead's buffers, kept between ticks so a warm tick allocates nothing.
#[derive(Debug, Clone, Default)]
struct LookAhead {
    pos: Vec<u32>,
    prio: Vec<f64>,
    d0: Vec<u32>,
    done: Vec<u32>,
    first: Vec<u32>,
    best: Vec<u32>,
    order: Vec<u32>,
    fallen: Vec<u32>,
}

/// What one tick did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LifeTick {
    /// The tick just played (the positions are now those of `tick`).
    pub tick: u32,
    /// Goals reached in it.
    pub reached: u32,
}

/// A lifelong run's world: positions, goals, priorities and the trace (see the module docs).
#[derive(Debug, Clone)]
pub struct Lifelong {
    problem: Problem,
    config: LifelongConfig,
    nbr: Vec<[u32; 4]>,
    deg: Vec<u8>,
    pos: Vec<u32>,
    next: Vec<u32>,
    occ_now: Vec<u32>,
    occ_next: Vec<u32>,
    goal: Vec<u32>,
    slot: Vec<u32>,
    count: Vec<u64>,
    eps: Vec<f64>,
    prio: Vec<f64>,
    order: Vec<u32>,
    present: Vec<bool>,
    tables: Tables,
    rng: u64,
    la: LookAhead,
    tick: u32,
    trace: Vec<u32>,
    arrived: Vec<u32>,
    reached: u64,
}

fn splitmix(x: &mut u64) -> u64 {
    *x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = *x;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

impl Lifelong {
    /// A world at tick 0: every robot on its start, heading for its first goal.
    pub fn new(problem: &Problem, config: LifelongConfig) -> Lifelong {
        let grid = problem.grid();
        let n = problem.team();
        let cells = grid.len();
        let nbr = neighbour_table(grid);
        let deg = nbr
            .iter()
            .map(|a| a.iter().filter(|&&v| v != NIL).count() as u8)
            .collect();
        let mut rng = config.seed ^ 0x5eed_11fe;
        let eps: Vec<f64> = (0..n)
            .map(|_| (splitmix(&mut rng) >> 11) as f64 / (1u64 << 53) as f64)
            .collect();
        let pos: Vec<u32> = problem
            .starts()
            .iter()
            .map(|&c| grid.index(c) as u32)
            .collect();
        let mut occ_now = vec![NIL; cells];
        for (i, &p) in pos.iter().enumerate() {
            occ_now[p as usize] = i as u32;
        }
        let mut tables = Tables::new(cells, n, config.table_budget);
        let goal: Vec<u32> = (0..n)
            .map(|k| grid.index(problem.goal(k, 0)) as u32)
            .collect();
        let slot = goal.iter().map(|&g| tables.acquire(g, &nbr)).collect();
        let mut order: Vec<u32> = (0..n as u32).collect();
        order.sort_unstable_by(|&a, &b| eps[b as usize].total_cmp(&eps[a as usize]));
        let mut trace = Vec::with_capacity(n * 1024);
        trace.extend_from_slice(&pos);
        Lifelong {
            problem: problem.clone(),
            config,
            deg,
            pos,
            next: vec![NIL; n],
            occ_now,
            occ_next: vec![NIL; cells],
            goal,
            slot,
            count: vec![0; n],
            prio: eps.clone(),
            eps,
            order,
            present: vec![true; n],
            tables,
            rng,
            la: LookAhead::default(),
            tick: 0,
            trace,
            arrived: Vec::with_capacity(n),
            nbr,
            reached: 0,
        }
    }

    /// The problem played.
    pub fn problem(&self) -> &Problem {
        &self.problem
    }

    /// Ticks played.
    pub fn tick(&self) -> u32 {
        self.tick
    }

    /// Robot `robot`'s cell now (its last cell if it left).
    pub fn position(&self, robot: usize) -> Cell {
        self.problem.grid().cell(self.pos[robot] as usize)
    }

    /// Robot `robot`'s current goal.
    pub fn goal(&self, robot: usize) -> Cell {
        self.problem.grid().cell(self.goal[robot] as usize)
    }

    /// How many goals robot `robot` reached: its current goal is its goal number `goals_reached`.
    pub fn goals_reached(&self, robot: usize) -> u64 {
        self.count[robot]
    }

    /// Goals reached by the whole fleet.
    pub fn reached(&self) -> u64 {
        self.reached
    }

    /// The robots that reached a goal in the last tick, in robot order.
    pub fn arrived(&self) -> &[u32] {
        &self.arrived
    }

    /// Whether `robot` is still on the grid.
    pub fn present(&self, robot: usize) -> bool {
        self.present[robot]
    }

    /// BFS tables computed so far (goals that recur reuse theirs).
    pub fn bfs_runs(&self) -> u64 {
        self.tables.bfs_runs
    }

    /// Robot `robot`'s distance from its cell to its goal.
    pub fn distance_left(&self, robot: usize) -> u32 {
        self.tables.dist(self.slot[robot])[self.pos[robot] as usize]
    }

    /// Takes a robot off the grid (its process died): its cell is free from the next tick and it
    /// reaches nothing more; in the trace it stays on its last cell. False if already gone.
    pub fn remove(&mut self, robot: usize) -> bool {
        if !self.present.get(robot).copied().unwrap_or(false) {
            return false;
        }
        self.present[robot] = false;
        let p = self.pos[robot] as usize;
        if self.occ_now[p] == robot as u32 {
            self.occ_now[p] = NIL;
        }
        true
    }

    /// Every robot's path, ticks 0 to now (a robot that left stays on its last cell).
    pub fn paths(&self) -> Vec<Vec<Cell>> {
        let n = self.pos.len();
        let grid = self.problem.grid();
        (0..n)
            .map(|i| {
                self.trace
                    .chunks_exact(n)
                    .map(|t| grid.cell(t[i] as usize))
                    .collect()
            })
            .collect()
    }

    /// Plays one tick: `rankings[i]` is robot `i`'s ranking at its cell, if the caller has one
    /// (robots without one go by distance). Returns the tick and the goals reached in it.
    pub fn step(&mut self, rankings: &[Option<Intent>]) -> LifeTick {
        let n = self.pos.len();
        if self.config.rollouts > 1 && self.config.horizon > 0 {
            self.look_ahead(rankings);
        } else {
            self.plan(rankings);
        }
        self.advance();
        self.arrived.clear();
        for i in 0..n {
            if !self.present[i] {
                continue;
            }
            if self.pos[i] == self.goal[i] {
                self.arrived.push(i as u32);
                self.prio[i] = self.eps[i];
                self.count[i] += 1;
                let g = self.problem.goal(i, self.count[i]);
                let g = self.problem.grid().index(g) as u32;
                self.tables.release(self.slot[i]);
                self.goal[i] = g;
                self.slot[i] = self.tables.acquire(g, &self.nbr);
            } else {
                self.prio[i] += 1.0;
            }
        }
        self.reorder();
        self.reached += self.arrived.len() as u64;
        self.tick += 1;
        self.trace.extend_from_slice(&self.pos);
        LifeTick {
            tick: self.tick,
            reached: self.arrived.len() as u32,
        }
    }

    /// Puts `order` back in falling priority after a tick: every robot gained 1 but those that
    /// reached a goal, which fell to their fraction below 1, so the others keep their order and
    /// the fallen go last, by fraction.
    fn reorder(&mut self) {
        let prio = &self.prio;
        let tmp = &mut self.la.fallen;
        tmp.clear();
        let mut w = 0;
        for k in 0..self.order.len() {
            let i = self.order[k];
            if prio[i as usize] < 1.0 {
                tmp.push(i);
            } else {
                self.order[w] = i;
                w += 1;
            }
        }
        tmp.sort_unstable_by(|&a, &b| prio[b as usize].total_cmp(&prio[a as usize]));
        self.order[w..].copy_from_slice(tmp);
    }

    /// One PIBT pass: every present robot's `next`, highest priority first.
    fn plan(&mut self, rankings: &[Option<Intent>]) {
        for k in 0..self.order.len() {
            let i = self.order[k] as usize;
            if self.present[i] && self.next[i] == NIL {
                self.pibt(i, rankings);
            }
        }
    }

    /// Every present robot onto its `next` cell: the old cells cleared, then the new ones taken.
    fn advance(&mut self) {
        let n = self.pos.len();
        for i in 0..n {
            if !self.present[i] {
                continue;
            }
            self.occ_now[self.pos[i] as usize] = NIL;
            self.occ_next[self.next[i] as usize] = NIL;
        }
        for i in 0..n {
            if !self.present[i] {
                continue;
            }
            self.pos[i] = self.next[i];
            self.next[i] = NIL;
            self.occ_now[self.pos[i] as usize] = i as u32;
        }
    }

    /// The look-ahead: `rollouts` first moves (PIBT with different tie-breaks), each played on
    /// for `horizon` ticks by PIBT (the same tie-breaks for all, robots keeping their goal once
    /// reached); the first move whose rollout brought the fleet nearest its goals is taken.
    fn look_ahead(&mut self, rankings: &[Option<Intent>]) {
        let n = self.pos.len();
        let la = &mut self.la;
        la.pos.clear();
        la.pos.extend_from_slice(&self.pos);
        la.prio.clear();
        la.prio.extend_from_slice(&self.prio);
        la.order.clear();
        la.order.extend_from_slice(&self.order);
        la.d0.clear();
        for i in 0..n {
            la.d0
                .push(self.tables.dist(self.slot[i])[self.pos[i] as usize]);
        }
        let base_rng = self.rng;
        let tail_rng = splitmix(&mut self.rng);
        let mut best_score = i64::MIN;
        for r in 0..self.config.rollouts {
            self.rng = if r == 0 {
                base_rng
            } else {
                base_rng ^ splitmix(&mut (u64::from(r) << 32 ^ tail_rng))
            };
            self.plan(rankings);
            self.la.first.clear();
            self.la.first.extend_from_slice(&self.next);
            self.la.done.clear();
            self.la.done.resize(n, u32::MAX);
            self.rng = tail_rng;
            for t in 0..self.config.horizon {
                if t > 0 {
                    self.plan(&[]);
                }
                self.advance();
                for i in 0..n {
                    if !self.present[i] {
                        continue;
                    }
                    if self.pos[i] == self.goal[i] {
                        if self.la.done[i] == u32::MAX {
                            self.la.done[i] = u32::from(t);
                        }
                        self.prio[i] = self.eps[i];
                    } else {
                        self.prio[i] += 1.0;
                    }
                }
                self.reorder();
            }
            // the score: distance gained, a reached goal worth its distance and the ticks left
            let h = i64::from(self.config.horizon);
            let mut score = 0i64;
            for i in 0..n {
                if !self.present[i] {
                    continue;
                }
                let d0 = i64::from(self.la.d0[i]);
                score += if self.la.done[i] != u32::MAX {
                    d0 + h - i64::from(self.la.done[i])
                } else {
                    d0 - i64::from(self.tables.dist(self.slot[i])[self.pos[i] as usize])
                };
            }
            if score > best_score {
                best_score = score;
                std::mem::swap(&mut self.la.best, &mut self.la.first);
            }
            // back to now
            for i in 0..n {
                if self.present[i] {
                    self.occ_now[self.pos[i] as usize] = NIL;
                }
            }
            self.pos.copy_from_slice(&self.la.pos);
            self.prio.copy_from_slice(&self.la.prio);
            self.order.copy_from_slice(&self.la.order);
            for i in 0..n {
                if self.present[i] {
                    self.occ_now[self.pos[i] as usize] = i as u32;
                }
            }
        }
        for i in 0..n {
            if self.present[i] {
                let v = self.la.best[i];
                self.next[i] = v;
                self.occ_next[v as usize] = i as u32;
            }
        }
        self.rng = splitmix(&mut self.rng) ^ base_rng;
    }

    /// Robot `i`'s candidate cells, best first: its ranking's cells, then the rest by distance
    /// (random ties); returns how many.
    fn candidates(&mut self, i: usize, ranking: Option<&Intent>, out: &mut [u32; 5]) -> usize {
        let cur = self.pos[i];
        let d = self.tables.dist(self.slot[i]);
        let mut n = 0;
        if let Some(r) = ranking {
            for &m in r.moves() {
                let v = match m {
                    Move::Wait => cur,
                    _ => self.nbr[cur as usize][m as usize - 1],
                };
                if v != NIL && !out[..n].contains(&v) {
                    out[n] = v;
                    n += 1;
                }
            }
        }
        let named = n;
        // one key: distance (20 bits), occupied now (1 bit), a random tie-break (43 bits)
        let mut keyed = [(u64::MAX, NIL); 5];
        let mut k = 0;
        let free = self.config.prefer_free;
        for v in self.nbr[cur as usize].into_iter().chain([cur]) {
            if v != NIL && !out[..named].contains(&v) {
                let busy = free && v != cur && self.occ_now[v as usize] != NIL;
                let key = u64::from(d[v as usize].min(DIST_CAP)) << 44
                    | u64::from(busy) << 43
                    | splitmix(&mut self.rng) >> 21;
                keyed[k] = (key, v);
                k += 1;
            }
        }
        keyed[..k].sort_unstable();
        for e in &keyed[..k] {
            out[n] = e.1;
            n += 1;
        }
        n
    }

    fn pibt(&mut self, i: usize, rankings: &[Option<Intent>]) -> bool {
        let cur = self.pos[i];
        let mut cand = [NIL; 5];
        let nc = self.candidates(i, rankings.get(i).and_then(Option::as_ref), &mut cand);
        let mut sw = NIL;
        if self.config.swap {
            sw = self.swap_partner(i, cand[0]);
            if sw != NIL {
                cand[..nc].reverse();
            }
        }
        for (k, &v) in cand[..nc].iter().enumerate() {
            if self.occ_next[v as usize] != NIL {
                continue;
            }
            let j = self.occ_now[v as usize];
            if j != NIL && self.next[j as usize] == cur {
                continue;
            }
            self.next[i] = v;
            self.occ_next[v as usize] = i as u32;
            if j != NIL
                && v != cur
                && self.next[j as usize] == NIL
                && !self.pibt(j as usize, rankings)
            {
                continue;
            }
            if sw != NIL
                && k == 0
                && self.next[sw as usize] == NIL
                && self.occ_next[cur as usize] == NIL
            {
                self.next[sw as usize] = cur;
                self.occ_next[cur as usize] = sw;
            }
            return true;
        }
        self.next[i] = cur;
        self.occ_next[cur as usize] = i as u32;
        false
    }

    /// The one way on from `vl` coming from `vp` in a corridor (cells with one neighbour that
    /// are some robot's goal and held by it count as walls): `Ok(None)` at a dead end, `Err(())`
    /// at a branching cell.
    fn corridor_step(&self, vp: u32, vl: u32) -> Result<Option<u32>, ()> {
        let mut m = 0;
        let mut tmp = NIL;
        for &u in &self.nbr[vl as usize] {
            if u == NIL || u == vp {
                continue;
            }
            let k = self.occ_now[u as usize];
            if self.deg[u as usize] == 1 && k != NIL && self.goal[k as usize] == u {
                continue;
            }
            m += 1;
            tmp = u;
        }
        match m {
            0 => Ok(None),
            1 => Ok(Some(tmp)),
            _ => Err(()),
        }
    }

    /// lacam3's `is_swap_required`: `pusher` at `vp` wants `vl` (where `puller` stands) and the
    /// two must trade places, which a corridor ahead of the puller does not allow.
    fn pulls_out(&self, pusher: usize, puller: usize, mut vp: u32, mut vl: u32) -> bool {
        let dp = self.tables.dist(self.slot[pusher]);
        let dl = self.tables.dist(self.slot[puller]);
        while dp[vl as usize] < dp[vp as usize] {
            match self.corridor_step(vp, vl) {
                Err(()) => return false,
                Ok(None) => break,
                Ok(Some(t)) => {
                    vp = vl;
                    vl = t;
                }
            }
        }
        dl[vp as usize] < dl[vl as usize]
            && (dp[vp as usize] == 0 || dp[vl as usize] < dp[vp as usize])
    }

    /// lacam3's `is_swap_possible`: pulling along the corridor reaches a branching cell.
    fn room_to_swap(&self, vp0: u32, mut vl: u32) -> bool {
        let mut vp = vp0;
        while vl != vp0 {
            match self.corridor_step(vp, vl) {
                Err(()) => return true,
                Ok(None) => return false,
                Ok(Some(t)) => {
                    vp = vl;
                    vl = t;
                }
            }
        }
        false
    }

    /// The robot `i` should pull behind it instead of pushing (NIL: none).
    fn swap_partner(&self, i: usize, best: u32) -> u32 {
        let cur = self.pos[i];
        let j = self.occ_now[best as usize];
        if j != NIL
            && j as usize != i
            && self.next[j as usize] == NIL
            && self.pulls_out(i, j as usize, cur, best)
            && self.room_to_swap(best, cur)
        {
            return j;
        }
        if best != cur {
            for &u in &self.nbr[cur as usize] {
                if u == NIL {
                    continue;
                }
                let k = self.occ_now[u as usize];
                if k != NIL
                    && best != self.pos[k as usize]
                    && self.pulls_out(k as usize, i, cur, best)
                    && self.room_to_swap(best, cur)
                {
                    return k;
                }
            }
        }
        NIL
    }
}
