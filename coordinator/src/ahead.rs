//! Learning ahead in a lifelong run, without IO: which goal each robot learns next, from where,
//! and what the learning cost.
//!
//! # The rule
//! Robot `k` walks to its goal number `reached` (the goals it reached so far) of the problem's
//! round-robin stream; it may learn goal numbers `reached ..= reached + ahead` (`ahead` is the
//! problem's `numTasksReveal`, at least 1: the next goal is always known while it walks). It
//! learns one goal at a time, in increasing number, each **from the goal it learned before**
//! (its start for the first): where it will stand when that goal is dealt. A goal it reached
//! before its learning came round is skipped (its values would serve nobody's ranking on this
//! robot, and the fleet table of that cell is kept by whoever learned it); a goal equal to the
//! cell it would be learned from is empty, and counts as learned at no cost.
//!
//! Each learning is one phase of the robot's protocol (`AssignGoal` + `Phase` for that robot
//! alone, phases numbered 0, 1, 2, … per robot), reported at its end. The goal id of a phase is
//! the goal cell's id in [`GoalIds`]: every robot sent to one cell shares one fleet table, so the
//! values learned for a cell warm-start every robot later sent there.

use planner::{Cell, Grid};

/// Dense ids for the goal cells a lifelong problem deals: the fleet table of a cell is table
/// `id`, the same for every robot sent there.
#[derive(Debug, Clone)]
pub struct GoalIds {
    /// Per grid cell index: its goal id, or `u32::MAX` when no task names it.
    id: Vec<u32>,
    cells: Vec<Cell>,
}

impl GoalIds {
    /// The ids of `tasks`' distinct cells, in order of first appearance.
    pub fn new(grid: &Grid, tasks: &[Cell]) -> GoalIds {
        let mut id = vec![u32::MAX; grid.len()];
        let mut cells = Vec::new();
        for &c in tasks {
            let i = grid.index(c);
            if id[i] == u32::MAX {
                id[i] = cells.len() as u32;
                cells.push(c);
            }
        }
        GoalIds { id, cells }
    }

    /// The goal id of cell `c`, if a task names it.
    pub fn of(&self, grid: &Grid, c: Cell) -> Option<u32> {
        self.id
            .get(grid.index(c))
            .copied()
            .filter(|&i| i != u32::MAX)
    }

    /// Number of distinct goal cells (the fleet tables a run keeps).
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether no task names any cell.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }
}

/// One goal a robot is sent to learn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Learning {
    /// Its number in the robot's goal stream (0: the first goal dealt).
    pub number: u64,
    /// The goal cell.
    pub goal: Cell,
    /// Where the robot learns it from (the goal it learned before, or its start).
    pub from: Cell,
    /// The robot's phase that learns it.
    pub phase: u32,
}

/// One robot's learning stream.
#[derive(Debug, Clone)]
struct Stream {
    /// The next goal number to consider.
    next: u64,
    /// Where the next learning starts.
    from: Cell,
    /// Phases sent so far (the next phase's number).
    phases: u32,
    /// The learning under way, if any.
    busy: Option<Learning>,
    /// Goal numbers learned that the robot has not reached yet, ascending.
    learned: Vec<u64>,
}

/// Which goal every robot learns next (see the module docs), and what learning cost.
#[derive(Debug, Clone)]
pub struct LearnAhead {
    ahead: u64,
    robots: Vec<Stream>,
    cost: Cost,
}

/// What learning cost so far, summed over the goals learned.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Cost {
    /// Goals learned (their report came in).
    pub goals: u64,
    /// Of them, goals whose fleet table held values when the robot was sent (a warm start).
    pub warm: u64,
    /// Environment steps of all goals learned.
    pub env_steps: u64,
    /// Environment steps of the warm-started goals.
    pub warm_env_steps: u64,
    /// Seconds the robots spent learning (their reports' elapsed time).
    pub learn_s: f64,
    /// Robot-ticks walked towards a goal whose learning had come in.
    pub ticks_learned: u64,
    /// Robot-ticks walked towards a goal not learned yet (ranked by map distance all the same).
    pub ticks_unlearned: u64,
}

impl LearnAhead {
    /// Streams for robots on `starts`, each allowed `reveal` goals ahead (at least 1).
    pub fn new(starts: &[Cell], reveal: u32) -> LearnAhead {
        LearnAhead {
            ahead: u64::from(reveal.max(1)),
            robots: starts
                .iter()
                .map(|&from| Stream {
                    next: 0,
                    from,
                    phases: 0,
                    busy: None,
                    learned: Vec::new(),
                })
                .collect(),
            cost: Cost::default(),
        }
    }

    /// Goals a robot may learn beyond the one it walks to.
    pub fn ahead(&self) -> u64 {
        self.ahead
    }

    /// The goal robot `k` learns next, if it is free and one is in its window: `reached` is the
    /// goals it reached, `goal_of(c)` its goal number `c`.
    pub fn next(
        &mut self,
        k: usize,
        reached: u64,
        goal_of: impl Fn(u64) -> Cell,
    ) -> Option<Learning> {
        let ahead = self.ahead;
        let s = self.robots.get_mut(k)?;
        s.learned.retain(|&c| c >= reached);
        if s.busy.is_some() {
            return None;
        }
        let mut c = s.next.max(reached);
        while c <= reached + ahead {
            let goal = goal_of(c);
            if goal == s.from {
                // nothing to learn: the robot stands there when this goal is dealt
                s.learned.push(c);
                c += 1;
                continue;
            }
            let l = Learning {
                number: c,
                goal,
                from: s.from,
                phase: s.phases,
            };
            s.phases += 1;
            s.next = c + 1;
            s.from = goal;
            s.busy = Some(l);
            return Some(l);
        }
        s.next = c;
        None
    }

    /// The learning under way on robot `k`, if any.
    pub fn busy(&self, k: usize) -> Option<Learning> {
        self.robots.get(k).and_then(|s| s.busy)
    }

    /// Robot `k`'s report of its learning came in: `env_steps` and `learn_s` it cost, `warm`
    /// whether its fleet table held values when it was sent. Returns the learning it closes.
    pub fn done(&mut self, k: usize, env_steps: u64, learn_s: f64, warm: bool) -> Option<Learning> {
        let s = self.robots.get_mut(k)?;
        let l = s.busy.take()?;
        s.learned.push(l.number);
        let c = &mut self.cost;
        c.goals += 1;
        c.env_steps += env_steps;
        c.learn_s += learn_s;
        if warm {
            c.warm += 1;
            c.warm_env_steps += env_steps;
        }
        Some(l)
    }

    /// Counts one tick of robot `k` walking to its goal number `reached`.
    pub fn tick(&mut self, k: usize, reached: u64) {
        let Some(s) = self.robots.get(k) else {
            return;
        };
        if s.learned.contains(&reached) {
            self.cost.ticks_learned += 1;
        } else {
            self.cost.ticks_unlearned += 1;
        }
    }

    /// What learning cost so far.
    pub fn cost(&self) -> Cost {
        self.cost
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(x: u16) -> Cell {
        Cell::new(x, 0)
    }

    /// Goal number `n` is cell `10 + n`.
    fn stream(n: u64) -> Cell {
        c(10 + n as u16)
    }

    #[test]
    fn a_robot_learns_its_first_goal_from_its_start_then_each_from_the_one_before() {
        let mut a = LearnAhead::new(&[c(0)], 1);
        let first = a.next(0, 0, stream).unwrap();
        assert_eq!(
            (first.number, first.from, first.goal, first.phase),
            (0, c(0), c(10), 0)
        );
        assert_eq!(a.next(0, 0, stream), None, "one learning at a time");
        a.done(0, 100, 0.1, false);
        let second = a.next(0, 0, stream).unwrap();
        assert_eq!(
            (second.number, second.from, second.goal, second.phase),
            (1, c(10), c(11), 1)
        );
    }

    #[test]
    fn learning_stops_ahead_goals_past_the_window_and_goes_on_as_goals_are_reached() {
        let mut a = LearnAhead::new(&[c(0)], 2);
        for n in 0..3 {
            assert_eq!(a.next(0, 0, stream).unwrap().number, n);
            a.done(0, 1, 0.0, false);
        }
        assert_eq!(
            a.next(0, 0, stream),
            None,
            "goals 0, 1 and 2 known: 3 is not revealed"
        );
        assert_eq!(a.next(0, 1, stream).unwrap().number, 3);
    }

    #[test]
    fn a_reveal_of_zero_still_learns_the_next_goal() {
        let mut a = LearnAhead::new(&[c(0)], 0);
        assert_eq!(a.ahead(), 1);
        a.next(0, 0, stream).unwrap();
        a.done(0, 1, 0.0, false);
        assert_eq!(a.next(0, 0, stream).unwrap().number, 1);
        a.done(0, 1, 0.0, false);
        assert_eq!(a.next(0, 0, stream), None);
    }

    #[test]
    fn goals_reached_before_their_learning_are_skipped_and_learning_starts_from_the_last_learned() {
        let mut a = LearnAhead::new(&[c(0)], 1);
        a.next(0, 0, stream).unwrap();
        a.done(0, 1, 0.0, false);
        // the robot reached goals 0..5 meanwhile: 1 to 4 are never learned
        let l = a.next(0, 5, stream).unwrap();
        assert_eq!((l.number, l.from, l.phase), (5, c(10), 1));
    }

    #[test]
    fn a_goal_on_the_cell_it_would_be_learned_from_is_learned_at_no_cost() {
        // goal 0 is the start itself, goal 1 is cell 11
        let goal = |n: u64| if n == 0 { c(0) } else { stream(n) };
        let mut a = LearnAhead::new(&[c(0)], 1);
        let l = a.next(0, 0, goal).unwrap();
        assert_eq!((l.number, l.from, l.phase), (1, c(0), 0));
        a.tick(0, 0);
        assert_eq!(a.cost().ticks_learned, 1, "goal 0 needs no learning");
        assert_eq!(a.cost().goals, 0);
    }

    #[test]
    fn the_cost_sums_reports_and_splits_warm_starts() {
        let mut a = LearnAhead::new(&[c(0), c(1)], 1);
        a.next(0, 0, stream).unwrap();
        a.next(1, 0, |n| c(20 + n as u16)).unwrap();
        assert!(a.done(0, 300, 0.5, false).is_some());
        assert!(a.done(1, 100, 0.25, true).is_some());
        assert_eq!(
            a.done(1, 100, 0.25, true),
            None,
            "a second report closes nothing"
        );
        let cost = a.cost();
        assert_eq!(
            (cost.goals, cost.warm, cost.env_steps, cost.warm_env_steps),
            (2, 1, 400, 100)
        );
        assert_eq!(cost.learn_s, 0.75);
    }

    #[test]
    fn ticks_count_as_learned_only_while_the_goal_walked_to_was_learned() {
        let mut a = LearnAhead::new(&[c(0)], 1);
        a.next(0, 0, stream).unwrap();
        a.tick(0, 0);
        a.done(0, 1, 0.0, false);
        a.tick(0, 0);
        a.tick(0, 1);
        let cost = a.cost();
        assert_eq!((cost.ticks_learned, cost.ticks_unlearned), (1, 2));
    }

    #[test]
    fn goal_ids_are_dense_over_distinct_cells_in_order_of_appearance() {
        let grid = Grid::new(4, 1, vec![true; 4]).unwrap();
        let ids = GoalIds::new(&grid, &[c(2), c(1), c(2), c(3)]);
        assert_eq!(ids.len(), 3);
        assert_eq!(
            [c(0), c(1), c(2), c(3)].map(|x| ids.of(&grid, x)),
            [None, Some(1), Some(0), Some(2)]
        );
    }

    #[test]
    fn an_unknown_robot_gets_nothing_and_counts_nothing() {
        let mut a = LearnAhead::new(&[c(0)], 1);
        assert_eq!(a.next(3, 0, stream), None);
        assert_eq!(a.done(3, 1, 0.0, false), None);
        a.tick(3, 0);
        assert_eq!(a.cost().ticks_unlearned, 0);
    }
}
