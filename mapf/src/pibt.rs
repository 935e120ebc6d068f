//! PIBT (Okumura et al., "Priority Inheritance with Backtracking for Iterative Multi-agent Path
//! Finding", 2019/2022) over fixed candidate lists: the one-step generator both the per-tick
//! resolver and the complete search use. Cells are row-major indices; nothing allocates after
//! [`Pibt::new`].

/// "Nobody" / "nowhere" in the index tables.
pub(crate) const NIL: u32 = u32::MAX;

/// Scratch tables for one PIBT step.
#[derive(Debug, Clone)]
pub(crate) struct Pibt {
    /// Who is on each cell now.
    pub occ_now: Vec<u32>,
    /// Who has reserved each cell for the next tick.
    pub occ_next: Vec<u32>,
    /// Each agent's granted next cell (NIL = not decided yet).
    pub next: Vec<u32>,
    /// Each agent's candidate cells, best first (its current cell among them for "wait").
    pub cand: Vec<[u32; 5]>,
    /// How many of `cand` are meaningful.
    pub ncand: Vec<u8>,
}

impl Pibt {
    /// Tables for `agents` agents on `cells` cells.
    pub fn new(agents: usize, cells: usize) -> Pibt {
        Pibt {
            occ_now: vec![NIL; cells],
            occ_next: vec![NIL; cells],
            next: vec![NIL; agents],
            cand: vec![[NIL; 5]; agents],
            ncand: vec![0; agents],
        }
    }

    /// Starts a step from `pos` (NIL = agent absent).
    pub fn begin(&mut self, pos: &[u32]) {
        for (i, &p) in pos.iter().enumerate() {
            self.next[i] = NIL;
            if p != NIL {
                self.occ_now[p as usize] = i as u32;
            }
        }
    }

    /// Clears the cell tables after a step from `pos`, ready for the next `begin`.
    pub fn end(&mut self, pos: &[u32]) {
        for (i, &p) in pos.iter().enumerate() {
            if p != NIL {
                self.occ_now[p as usize] = NIL;
            }
            let n = self.next[i];
            if n != NIL {
                self.occ_next[n as usize] = NIL;
            }
        }
    }

    /// Whether `i` may go to `v`: `v` not yet reserved and no swap with the agent now on `v`.
    fn free_for(&self, pos: &[u32], i: usize, v: u32) -> bool {
        if self.occ_next[v as usize] != NIL {
            return false;
        }
        let j = self.occ_now[v as usize];
        !(j != NIL && j as usize != i && self.next[j as usize] == pos[i])
    }

    /// Fixes agent `i` to `v` before the search (a hung robot, a constraint); false on a vertex
    /// or swap conflict with what is already fixed.
    pub fn fix(&mut self, pos: &[u32], i: usize, v: u32) -> bool {
        if self.next[i] != NIL {
            return self.next[i] == v;
        }
        if !self.free_for(pos, i, v) {
            return false;
        }
        self.next[i] = v;
        self.occ_next[v as usize] = i as u32;
        true
    }

    /// PIBT for agent `i`: takes its best free candidate, pushing (recursively) the agent on it;
    /// false when every candidate failed (the agent then stays where it is).
    pub fn run(&mut self, pos: &[u32], i: usize) -> bool {
        let n = self.ncand[i] as usize;
        for k in 0..n {
            let v = self.cand[i][k];
            if !self.free_for(pos, i, v) {
                continue;
            }
            self.next[i] = v;
            self.occ_next[v as usize] = i as u32;
            let j = self.occ_now[v as usize];
            if j != NIL
                && j as usize != i
                && self.next[j as usize] == NIL
                && !self.run(pos, j as usize)
            {
                continue;
            }
            return true;
        }
        let here = pos[i];
        self.next[i] = here;
        self.occ_next[here as usize] = i as u32;
        false
    }
}
