//! Goal-path discoveries of the planning learner: "from this cell the goal is reached along a
//! known path, with this return".
//!
//! The paper's pseudo targets ([`crate::pseudo`]) make cells near the goal terminal; the
//! planning learner, whose values are upper bounds of Q* (optimistic start), gains nothing from
//! that (it needs 3.8× the steps with them, docs/learner.md). What another robot *can* use is a
//! lower bound: a path that a robot has found from cell `c` to the goal is a path on the same
//! deterministic grid for every robot, so its discounted return `v` is a lower bound of V*(c)
//! for all of them. A robot whose own upper bound at `c` has come down to `v` knows that its
//! value at `c` is exact: the rest of its greedy walk from `c` follows exact values to the goal
//! and can tell it nothing new. So:
//!
//! - **Publishing** ([`PathPublisher`]): when a learner's greedy path from its start first
//!   reaches the goal, and each time it gets shorter, up to [`PathPublisher::PER_PATH`] of its
//!   cells (evenly spaced, the goal excluded) not published before are handed out with their
//!   return along that path, at most [`PathPublisher::CAP`] per phase (the relay topic is
//!   sized for a few dozen discoveries per goal).
//! - **Using** ([`KnownReturns`]): a receiving learner keeps the highest return heard per cell
//!   and ends its episode when it enters such a cell where (1) its own value (max over actions)
//!   is not above that return ([`KnownReturns::exact_at`]: an upper bound down to a lower bound,
//!   the value is exact) and (2) its greedy walk on from there reaches the goal by moves it
//!   knows with a return not below it ([`KnownReturns::certifies`]). Without (2) a greedy
//!   action at the cell that *ties* with the known path (an untried action as many moves away
//!   as the goal has the same optimistic value) would never be explored, every episode ending
//!   there, and the greedy path from the start would never reach the goal. The move into the
//!   cell is backed up as any other move (no terminal reward is imposed, so no value is ever set
//!   from a discovery): a wrong or stale discovery can end an episode early, never bend a value.
//!
//! Both are free of IO and of the learner, and tested below as the specification.

/// Relative slack of [`KnownReturns::ends_episode`]: the values of two robots along the same
/// path are the same f32 operations (`r + γ·v`, from the goal back), so they agree to the last
/// bit; the slack only absorbs a different order of the same backups. One move at γ = 0.99
/// changes a value by 1 %, four orders of magnitude above it.
pub const EXACT_SLACK: f32 = 1e-6;

/// Per cell, the highest return of a known path from it to the goal (see the module docs).
#[derive(Debug, Clone)]
pub struct KnownReturns {
    /// `NEG_INFINITY`: nothing known.
    ret: Vec<f32>,
    known: u32,
    /// The largest return any path can have (the goal reward when moves cost nothing): a
    /// discovery above it is not a return of this task.
    ceiling: f32,
}

impl KnownReturns {
    /// Nothing known yet, for a grid of `cells` cells whose returns are at most `ceiling`.
    pub fn new(cells: usize, ceiling: f32) -> Self {
        KnownReturns {
            ret: vec![f32::NEG_INFINITY; cells],
            known: 0,
            ceiling,
        }
    }

    /// Takes a discovered return `v` of cell `cell`; returns whether it raised what is known
    /// there. Refused: a cell off the grid, a value that is not finite or above the ceiling.
    pub fn offer(&mut self, cell: u32, v: f32) -> bool {
        let Some(r) = self.ret.get_mut(cell as usize) else {
            return false;
        };
        if !v.is_finite() || v > self.ceiling || v <= *r {
            return false;
        }
        if *r == f32::NEG_INFINITY {
            self.known += 1;
        }
        *r = v;
        true
    }

    /// The known return of `cell`, if any.
    pub fn get(&self, cell: u32) -> Option<f32> {
        self.ret
            .get(cell as usize)
            .copied()
            .filter(|v| *v != f32::NEG_INFINITY)
    }

    /// Cells with a known return.
    pub fn len(&self) -> u32 {
        self.known
    }

    /// Whether nothing is known.
    pub fn is_empty(&self) -> bool {
        self.known == 0
    }

    /// Whether the value `value` (max over actions, an upper bound of V*) of a learner at `cell`
    /// is exact: a return is known there and the value is not above it (up to
    /// [`EXACT_SLACK`]). The cheap first test of an episode's end, made on every step.
    #[inline(always)]
    pub fn exact_at(&self, cell: u32, value: f32) -> bool {
        let r = self.ret[cell as usize];
        value <= r + r.abs() * EXACT_SLACK
    }

    /// Whether a learner whose value at `cell` is exact ([`exact_at`](Self::exact_at)) ends its
    /// episode there: its greedy walk on from `cell` reaches the goal by known moves with return
    /// `walk` (`None`: it does not) not below the known return, so that walk is optimal and
    /// would tell the learner nothing.
    pub fn certifies(&self, cell: u32, walk: Option<f32>) -> bool {
        let r = self.ret[cell as usize];
        walk.is_some_and(|w| w >= r - r.abs() * EXACT_SLACK)
    }
}

/// The return of a path of `moves` moves (at least 1) into the goal, computed as a learner's
/// backups compute it, from the goal back: the last move earns `goal`, every other one `step`
/// plus `gamma` times the rest.
pub fn path_return(moves: u32, goal: f32, step: f32, gamma: f32) -> f32 {
    let mut v = goal;
    for _ in 1..moves {
        v = step + gamma * v;
    }
    v
}

/// Which cells of a found path a learner publishes (see the module docs).
#[derive(Debug, Clone)]
pub struct PathPublisher {
    published: Vec<bool>,
    count: u32,
    /// The shortest path published so far, in moves.
    best: Option<u32>,
}

impl PathPublisher {
    /// Cells published per path found.
    pub const PER_PATH: usize = 8;
    /// Cells published per phase at most.
    pub const CAP: u32 = 32;

    /// Nothing published yet, for a grid of `cells` cells.
    pub fn new(cells: usize) -> Self {
        PathPublisher {
            published: vec![false; cells],
            count: 0,
            best: None,
        }
    }

    /// Whether a path of `len` moves would be published (the first, or shorter than every path
    /// published so far, while the cap is not reached).
    pub fn wants(&self, len: u32) -> bool {
        self.count < Self::CAP && self.best.is_none_or(|b| len < b)
    }

    /// Publishes a found path: `path` its cells from the start to the goal (the goal last),
    /// `returns[i]` the return from `path[i]` along it. Pushes onto `out` up to
    /// [`PER_PATH`](Self::PER_PATH) (cell, return) pairs of cells never published, evenly
    /// spaced from the start to the cell before the goal; nothing if [`wants`](Self::wants) is
    /// false. Returns how many.
    pub fn publish(&mut self, path: &[u32], returns: &[f32], out: &mut Vec<(u32, f32)>) -> usize {
        let moves = path.len().saturating_sub(1);
        if moves == 0 || returns.len() < moves || !self.wants(moves as u32) {
            return 0;
        }
        self.best = Some(moves as u32);
        let want = Self::PER_PATH
            .min(moves)
            .min((Self::CAP - self.count) as usize);
        let mut n = 0;
        // `want` positions over 0..moves, evenly spaced, the start included
        for k in 0..want {
            let i = k * moves / want;
            let c = path[i] as usize;
            if c < self.published.len() && !self.published[c] {
                self.published[c] = true;
                out.push((path[i], returns[i]));
                n += 1;
            }
        }
        self.count += n as u32;
        n
    }

    /// Cells published so far.
    pub fn published(&self) -> u32 {
        self.count
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_known_return_keeps_the_highest_offer_and_refuses_nonsense() {
        let mut k = KnownReturns::new(10, 1.0);
        assert!(k.is_empty());
        assert!(k.offer(3, 0.5));
        assert!(!k.offer(3, 0.4), "a lower return adds nothing");
        assert!(k.offer(3, 0.6));
        assert_eq!(k.get(3), Some(0.6));
        assert!(!k.offer(10, 0.5), "off the grid");
        assert!(!k.offer(4, f32::NAN));
        assert!(!k.offer(4, f32::INFINITY));
        assert!(!k.offer(4, 1.5), "above what any path returns");
        assert_eq!((k.len(), k.get(4)), (1, None));
    }

    #[test]
    fn a_value_is_exact_only_where_it_has_come_down_to_the_known_return() {
        let mut k = KnownReturns::new(4, 1.0);
        let v = path_return(41, 1.0, 0.0, 0.99);
        k.offer(1, v);
        assert!(k.exact_at(1, v), "exact value");
        assert!(k.exact_at(1, v * (1.0 + 1e-7)), "rounding");
        assert!(
            !k.exact_at(1, v / 0.99),
            "a value one move better: something untried may be shorter"
        );
        assert!(!k.exact_at(1, 1.0), "optimistic, untried");
        assert!(!k.exact_at(0, -5.0), "nothing known there");
    }

    #[test]
    fn an_episode_ends_only_where_the_greedy_walk_on_is_as_good_as_the_known_path() {
        let mut k = KnownReturns::new(4, 1.0);
        let v = path_return(41, 1.0, 0.0, 0.99);
        k.offer(1, v);
        assert!(k.certifies(1, Some(v)), "the same length");
        assert!(
            k.certifies(1, Some(path_return(40, 1.0, 0.0, 0.99))),
            "shorter"
        );
        assert!(
            !k.certifies(1, Some(path_return(42, 1.0, 0.0, 0.99))),
            "one move longer: the greedy walk is not the optimum, it must be walked and learned"
        );
        assert!(
            !k.certifies(1, None),
            "a walk into an untried action or a loop: a tie with the known path, not the path"
        );
    }

    #[test]
    fn negative_returns_get_the_slack_on_the_right_side() {
        let mut k = KnownReturns::new(2, 1.0);
        k.offer(0, -2.0);
        assert!(k.exact_at(0, -2.0));
        assert!(k.exact_at(0, -2.0 + 1e-6));
        assert!(!k.exact_at(0, -1.9));
        assert!(k.certifies(0, Some(-2.0)));
        assert!(!k.certifies(0, Some(-2.1)));
    }

    #[test]
    fn a_path_return_is_the_backups_arithmetic() {
        assert_eq!(path_return(1, 1.0, 0.0, 0.99), 1.0);
        assert_eq!(path_return(2, 1.0, 0.0, 0.99), 0.99);
        assert_eq!(path_return(3, 1.0, -0.1, 0.5), -0.1 + 0.5 * (-0.1 + 0.5));
        // bit for bit what `r + γ·v` from the goal back gives
        let mut v = 1.0f32;
        for _ in 1..200 {
            v = 0.0 + 0.99 * v;
        }
        assert_eq!(path_return(200, 1.0, 0.0, 0.99), v);
    }

    fn path(n: u32) -> (Vec<u32>, Vec<f32>) {
        let cells: Vec<u32> = (0..=n).collect();
        let rets = (0..=n).map(|i| 0.99f32.powi((n - i) as i32)).collect();
        (cells, rets)
    }

    #[test]
    fn a_first_path_publishes_evenly_spaced_cells_with_their_returns_never_the_goal() {
        let mut p = PathPublisher::new(100);
        let (cells, rets) = path(40);
        let mut out = Vec::new();
        assert_eq!(p.publish(&cells, &rets, &mut out), PathPublisher::PER_PATH);
        let at: Vec<u32> = out.iter().map(|x| x.0).collect();
        assert_eq!(at, [0, 5, 10, 15, 20, 25, 30, 35]);
        assert!(out.iter().all(|&(c, v)| v == rets[c as usize]));
        assert!(!at.contains(&40));
    }

    #[test]
    fn a_short_path_publishes_each_of_its_cells_once() {
        let mut p = PathPublisher::new(10);
        let (cells, rets) = path(3);
        let mut out = Vec::new();
        assert_eq!(p.publish(&cells, &rets, &mut out), 3);
        assert_eq!(out.iter().map(|x| x.0).collect::<Vec<_>>(), [0, 1, 2]);
        // a start that is the goal: nothing to publish
        assert_eq!(p.publish(&[5], &[1.0], &mut out), 0);
    }

    #[test]
    fn only_a_shorter_path_publishes_again_and_never_a_cell_twice() {
        let mut p = PathPublisher::new(100);
        let mut out = Vec::new();
        let (cells, rets) = path(40);
        p.publish(&cells, &rets, &mut out);
        assert!(!p.wants(40) && !p.wants(41) && p.wants(39));
        assert_eq!(p.publish(&cells, &rets, &mut out), 0, "same length");
        let (short, srets) = path(16);
        out.clear();
        let n = p.publish(&short, &srets, &mut out);
        // cells 0 and 10 went out with the first path
        assert_eq!(
            out.iter().map(|x| x.0).collect::<Vec<_>>(),
            [2, 4, 6, 8, 12, 14]
        );
        assert_eq!((n, p.published()), (6, 14));
    }

    #[test]
    fn a_phase_publishes_at_most_the_cap() {
        let mut p = PathPublisher::new(10_000);
        let mut out = Vec::new();
        for n in (100..200).rev() {
            // disjoint cells each time: the cap, not the dedup, stops it
            let cells: Vec<u32> = (0..=n).map(|i| n * 50 + i).collect();
            let rets = vec![0.5; cells.len()];
            p.publish(&cells, &rets, &mut out);
        }
        assert_eq!(out.len(), PathPublisher::CAP as usize);
        assert!(!p.wants(1));
    }
}
