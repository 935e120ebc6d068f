//! The complete fallback: LaCAM (Okumura, "LaCAM: Search-Based Algorithm for Quick Multi-Agent
//! Pathfinding", AAAI 2023), a depth-first search over configurations whose successors come
//! from PIBT under a lazily grown tree of constraints ("agent i goes to cell v"). Every
//! successor of every reached configuration is eventually generated, so when the search runs
//! out of configurations no solution exists; with LaCAM*'s re-insertion of revisited
//! configurations it finds one quickly when one does.
//!
//! The budget counts generator calls (one PIBT step each), never time. The search allocates
//! (its node tables grow with the budget); it runs only when the per-tick resolver stalls.

use crate::pibt::{NIL, Pibt};
use std::collections::{HashMap, VecDeque};

/// How a search ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Outcome {
    /// A plan: configurations from the start one (included) to the goal one, `agents` each.
    Solved(Vec<u32>),
    /// Every reachable configuration was explored: no solution exists.
    Exhausted,
    /// The budget ran out first.
    OutOfBudget,
}

/// One configuration in the search.
struct HNode {
    /// Offset of its configuration in the arena.
    at: usize,
    /// The node it was generated from (NIL for the root).
    parent: u32,
    /// The next node with the same configuration hash.
    chain: u32,
    /// Constraint nodes still to try, as arena ids.
    tree: VecDeque<u32>,
}

/// One constraint node: "agent `who` goes to `to`", on top of its parent's constraints.
#[derive(Clone, Copy)]
struct LNode {
    parent: u32,
    who: u32,
    to: u32,
    depth: u32,
}

/// A small deterministic generator for tie-breaking.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 32) as u32
    }
}

/// The FNV-1a hash of a configuration.
fn hash(cfg: &[u32]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for &c in cfg {
        h ^= u64::from(c);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// What the search needs to know about the instance.
pub(crate) struct Problem<'a> {
    /// Goal cell of each agent.
    pub goal: &'a [u32],
    /// Agents that never move (hung robots).
    pub fixed: &'a [bool],
    /// Passable neighbours of each cell (NIL where none), slots up, right, down, left.
    pub nbr: &'a [[u32; 4]],
    /// Each agent's distance table.
    pub dist: &'a [Vec<u32>],
}

impl Problem<'_> {
    /// Whether every movable present agent is on its goal.
    fn is_goal(&self, cfg: &[u32]) -> bool {
        cfg.iter()
            .enumerate()
            .all(|(i, &c)| c == NIL || self.fixed[i] || c == self.goal[i])
    }

    /// Movable present agents, farthest from their goals first.
    fn order(&self, cfg: &[u32], out: &mut Vec<u32>) {
        out.clear();
        out.extend(
            (0..cfg.len() as u32).filter(|&i| cfg[i as usize] != NIL && !self.fixed[i as usize]),
        );
        out.sort_by_key(|&i| {
            let d = self.dist[i as usize][cfg[i as usize] as usize];
            (std::cmp::Reverse(d), i)
        });
    }
}

/// Searches from `start` (NIL = absent agent) for a configuration with every movable agent on
/// its goal, spending at most `budget` generator calls.
pub(crate) fn lacam(
    pibt: &mut Pibt,
    p: &Problem<'_>,
    start: &[u32],
    budget: u64,
    seed: u64,
) -> Outcome {
    let n = start.len();
    let mut rng = Rng(seed | 1);
    let mut arena: Vec<u32> = start.to_vec();
    let mut lnodes: Vec<LNode> = vec![LNode {
        parent: NIL,
        who: NIL,
        to: NIL,
        depth: 0,
    }];
    let mut nodes = vec![HNode {
        at: 0,
        parent: NIL,
        chain: NIL,
        tree: VecDeque::from([0u32]),
    }];
    let mut explored: HashMap<u64, u32> = HashMap::from([(hash(start), 0u32)]);
    let mut open: Vec<u32> = vec![0];
    let mut order = Vec::with_capacity(n);
    let mut next = vec![NIL; n];
    let mut calls = 0u64;
    while let Some(&top) = open.last() {
        let top = top as usize;
        let at = nodes[top].at;
        if p.is_goal(&arena[at..at + n]) {
            let mut chain = Vec::new();
            let mut k = top as u32;
            while k != NIL {
                chain.push(k);
                k = nodes[k as usize].parent;
            }
            let mut out = Vec::with_capacity(chain.len() * n);
            for &k in chain.iter().rev() {
                let a = nodes[k as usize].at;
                out.extend_from_slice(&arena[a..a + n]);
            }
            return Outcome::Solved(out);
        }
        let Some(c) = nodes[top].tree.pop_front() else {
            open.pop();
            continue;
        };
        if calls >= budget {
            return Outcome::OutOfBudget;
        }
        calls += 1;
        let cfg = &arena[at..at + n];
        p.order(cfg, &mut order);
        let cn = lnodes[c as usize];
        if (cn.depth as usize) < order.len() {
            let i = order[cn.depth as usize] as usize;
            let here = cfg[i];
            let mut choices = [here, NIL, NIL, NIL, NIL];
            choices[1..].copy_from_slice(&p.nbr[here as usize]);
            // a random order of the choices, as LaCAM does, so no direction is favoured
            for k in (1..5).rev() {
                let j = rng.next() as usize % (k + 1);
                choices.swap(k, j);
            }
            for v in choices.into_iter().filter(|v| *v != NIL) {
                // a constraint clashing with one above it can never be met: not worth a node
                if clashes(&lnodes, c, cfg, i as u32, v) {
                    continue;
                }
                lnodes.push(LNode {
                    parent: c,
                    who: i as u32,
                    to: v,
                    depth: cn.depth + 1,
                });
                let id = (lnodes.len() - 1) as u32;
                nodes[top].tree.push_back(id);
            }
        }
        if !generate(pibt, p, cfg, &order, &lnodes, c, &mut rng, &mut next) {
            continue;
        }
        let h = hash(&next);
        let mut k = explored.get(&h).copied().unwrap_or(NIL);
        let mut found = NIL;
        while k != NIL {
            let a = nodes[k as usize].at;
            if arena[a..a + n] == next[..] {
                found = k;
                break;
            }
            k = nodes[k as usize].chain;
        }
        if found != NIL {
            // LaCAM*: continue from the known configuration
            open.push(found);
            continue;
        }
        let id = nodes.len() as u32;
        let at = arena.len();
        arena.extend_from_slice(&next);
        lnodes.push(LNode {
            parent: NIL,
            who: NIL,
            to: NIL,
            depth: 0,
        });
        let root = (lnodes.len() - 1) as u32;
        nodes.push(HNode {
            at,
            parent: top as u32,
            chain: explored.get(&h).copied().unwrap_or(NIL),
            tree: VecDeque::from([root]),
        });
        explored.insert(h, id);
        open.push(id);
    }
    Outcome::Exhausted
}

/// Whether "agent `i` goes to `v`" clashes (vertex or swap) with a constraint of node `c` or
/// its ancestors.
fn clashes(lnodes: &[LNode], mut c: u32, cfg: &[u32], i: u32, v: u32) -> bool {
    while c != NIL {
        let l = lnodes[c as usize];
        if l.who != NIL {
            let swap = v == cfg[l.who as usize] && l.to == cfg[i as usize] && v != l.to;
            if l.to == v || swap {
                return true;
            }
        }
        c = l.parent;
    }
    false
}

/// One PIBT step from `cfg` under the constraints of node `c`; the result in `out`.
#[allow(clippy::too_many_arguments)]
fn generate(
    pibt: &mut Pibt,
    p: &Problem<'_>,
    cfg: &[u32],
    order: &[u32],
    lnodes: &[LNode],
    c: u32,
    rng: &mut Rng,
    out: &mut [u32],
) -> bool {
    pibt.begin(cfg);
    for (i, &here) in cfg.iter().enumerate() {
        if here == NIL {
            pibt.ncand[i] = 0;
            continue;
        }
        let mut keyed = [(u32::MAX, 0u32, NIL); 5];
        let mut m = 0;
        for v in std::iter::once(here).chain(p.nbr[here as usize].iter().copied()) {
            if v != NIL {
                keyed[m] = (p.dist[i][v as usize], rng.next(), v);
                m += 1;
            }
        }
        keyed[..m].sort_unstable();
        for (k, e) in keyed[..m].iter().enumerate() {
            pibt.cand[i][k] = e.2;
        }
        pibt.ncand[i] = m as u8;
    }
    let mut ok = true;
    for (i, &here) in cfg.iter().enumerate() {
        if here != NIL && p.fixed[i] {
            ok &= pibt.fix(cfg, i, here);
        }
    }
    let mut k = c;
    while ok && k != NIL {
        let l = lnodes[k as usize];
        if l.who != NIL {
            ok &= pibt.fix(cfg, l.who as usize, l.to);
        }
        k = l.parent;
    }
    if ok {
        for &i in order {
            if pibt.next[i as usize] == NIL && !pibt.run(cfg, i as usize) {
                ok = false;
                break;
            }
        }
    }
    if ok {
        for (i, o) in out.iter_mut().enumerate() {
            *o = if cfg[i] == NIL { NIL } else { pibt.next[i] };
        }
    }
    pibt.end(cfg);
    ok
}
