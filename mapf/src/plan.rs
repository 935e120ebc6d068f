//! Prioritized planning with space-time A* (Silver 2005; Erdmann & Lozano-Pérez 1987): the
//! coordinator's look-ahead. Agents are planned one after another from the current
//! configuration; each avoids the vertices and edges reserved by the agents planned before it
//! and then holds its goal forever. An agent whose search fails (node budget, horizon, or no
//! way around) simply has no plan. Every table is sized once; replanning allocates nothing.

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
    /// Indices set in `res`, to clear them.
    touched: Vec<u32>,
    /// From which time a cell is held forever (an agent resting on its goal, a hung robot).
    hold: Vec<u32>,
    /// Who holds a cell forever (see `hold`).
    holder: Vec<u32>,
    /// The last time index any plan passes a cell (NIL = never).
    last: Vec<u32>,
    /// Whether a plan may step away from its goal (raise its distance) when it could wait.
    pub voluntary_detours: bool,
    /// A* visited stamps, at `t * cells + v`.
    stamp: Vec<u32>,
    /// The move index (0 wait, 1..=4 the neighbour slot + 1) that reached (t, v).
    parent: Vec<u8>,
    generation: u32,
    heap: BinaryHeap<(Reverse<u32>, u32, u32)>,
    /// Per agent: the planned cells, `(horizon + 1)` slots each.
    pub cells_of: Vec<u32>,
    /// Per agent: the time index it arrives for good, NIL = no plan.
    pub arrive: Vec<u32>,
}

impl Planner {
    /// Tables for `agents` agents on `cells` cells with plans up to `horizon` ticks.
    pub fn new(agents: usize, cells: usize, horizon: usize, node_budget: u32) -> Planner {
        let slots = (horizon + 1) * cells;
        Planner {
            cells,
            horizon,
            res: vec![NIL; slots],
            touched: Vec::with_capacity(agents * (horizon + 3)),
            hold: vec![NIL; cells],
            holder: vec![NIL; cells],
            voluntary_detours: false,
            last: vec![NIL; cells],
            stamp: vec![0; slots],
            parent: vec![0; slots],
            generation: 0,
            // each expansion pushes at most 5 nodes
            heap: BinaryHeap::with_capacity(if agents == 0 {
                0
            } else {
                5 * node_budget as usize + 5
            }),
            cells_of: vec![NIL; agents * (horizon + 1)],
            arrive: vec![NIL; agents],
        }
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
        for &i in &self.touched {
            let i = i as usize;
            self.res[i] = NIL;
            let v = i % self.cells;
            self.hold[v] = NIL;
            self.holder[v] = NIL;
            self.last[v] = NIL;
        }
        self.touched.clear();
        self.arrive.fill(NIL);
    }

    /// Marks (t, v) as used by `agent`.
    fn reserve(&mut self, agent: usize, t: usize, v: u32) {
        let i = t * self.cells + v as usize;
        self.res[i] = agent as u32;
        self.touched.push(i as u32);
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

    /// Plans every agent in `order` from `pos` (NIL = absent); `fixed[i]` agents never move.
    /// `nbr` lists each cell's passable neighbours (NIL where none); `dist[i]` is agent i's
    /// distance table; each agent's search may expand `node_budget` nodes, all of them
    /// `total_budget` (agents left when it is spent get no plan). Returns the expansions spent.
    #[allow(clippy::too_many_arguments)]
    pub fn plan(
        &mut self,
        order: &[u32],
        pos: &[u32],
        goal: &[u32],
        fixed: &[bool],
        nbr: &[[u32; 4]],
        dist: &[Vec<u32>],
        node_budget: u32,
        total_budget: u64,
    ) -> u64 {
        self.clear();
        let h = self.horizon + 1;
        // robots that will not move hold their cells from now on
        for (i, &p) in pos.iter().enumerate() {
            if p != NIL && fixed[i] {
                self.hold[p as usize] = 0;
                self.holder[p as usize] = i as u32;
                self.touched.push(p);
                self.arrive[i] = 0;
                self.cells_of[i * h] = p;
            }
        }
        let mut spent = 0u64;
        for &a in order {
            let a = a as usize;
            if pos[a] == NIL || fixed[a] || spent >= total_budget {
                continue;
            }
            let (found, n) = self.astar(pos[a], goal[a], nbr, &dist[a], node_budget);
            spent += u64::from(n);
            let Some(t_end) = found else { continue };
            // walk back from (t_end, goal), writing the path
            let mut v = goal[a];
            for t in (0..=t_end).rev() {
                self.cells_of[a * h + t] = v;
                self.reserve(a, t, v);
                if t > 0 {
                    let m = self.parent[t * self.cells + v as usize];
                    v = back(nbr, v, m);
                }
            }
            self.hold[goal[a] as usize] = t_end as u32;
            self.holder[goal[a] as usize] = a as u32;
            self.touched.push(goal[a]);
            self.arrive[a] = t_end as u32;
        }
        spent
    }

    /// Space-time A* for one agent; the arrival time index and the expansions spent.
    fn astar(
        &mut self,
        start: u32,
        goal: u32,
        nbr: &[[u32; 4]],
        dist: &[u32],
        node_budget: u32,
    ) -> (Option<usize>, u32) {
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.stamp.fill(0);
            self.generation = 1;
        }
        let gen_ = self.generation;
        self.heap.clear();
        self.stamp[start as usize] = gen_;
        self.heap.push((Reverse(dist[start as usize]), 0, start));
        let mut expanded = 0u32;
        while let Some((_, t, v)) = self.heap.pop() {
            let t = t as usize;
            if v == goal && (self.last[v as usize] == NIL || (self.last[v as usize] as usize) < t) {
                return (Some(t), expanded);
            }
            expanded += 1;
            if expanded > node_budget {
                return (None, expanded);
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
                if self.stamp[i] == gen_ {
                    continue;
                }
                self.stamp[i] = gen_;
                self.parent[i] = m;
                // min f first, deeper (later) first among equal f
                self.heap.push((Reverse(nt as u32 + du), nt as u32, u));
            }
        }
        (None, expanded)
    }
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
