//! Moving on a shared grid: after learning, a robot goes from its start to its goal among the
//! other robots, one tick at a time, moving only where the coordinator grants.
//!
//! # Protocol (the robot's side; the coordinator's is `coordinator::grid`)
//! 1. `Execute` on `coord/control` (after every robot finished learning).
//! 2. The coordinator publishes a `Grant` on `coord/grant` for tick 0 (the starts), then one per
//!    tick. For each grant newer than the last it answered, the robot takes its own cell from
//!    it and sends one `Intent` on `robot/intent`: its five moves ranked by its own learned
//!    values at that cell ([`Ranker`]). It wakes nobody: the coordinator polls while it
//!    collects a tick (a wakeup per robot per tick cost every robot a syscall and the
//!    coordinator one wakeup per robot). It also publishes its `robot/state` with that cell,
//!    so observers see the ticks.
//! 3. A grant whose state is not `Moving`, a grant where it is no longer present, or `Stop`
//!    ends the execution; the robot goes back to waiting for `Stop` and reports as usual.
//!
//! A robot never moves on its own: the coordinator's grant is where it is. A grant missed in
//! the latest-wins buffer is no loss, the next one carries every position.
//!
//! # Intent horizon
//! When `Execute` asks for a horizon `h > 0` (its `episodes` field), the robot answers a grant
//! with an `IntentHorizon` on `robot/horizon` instead: its ranking (the same [`Ranker`]) at
//! every cell within `r` moves of its cell, `r = h − tick mod (h + 1)`
//! ([`mapf::horizon::aligned_radius`]), so the coordinator resolves up to `r + 1` ticks without
//! it and every robot's horizon runs out on the same tick. The coordinator wakes the robots
//! only on the ticks where it needs answers; a robot reads the newest grant when woken (or
//! every 10 ms) and answers only when its last horizon no longer answers that grant
//! ([`Answering`], by [`Coverage::answers`], the rule the coordinator waits by): a robot that
//! has not moved off the center of its last full horizon (parked on its goal, queued behind
//! another) keeps it and is not asked again; one that moved answers with the fleet at the
//! start of a period. Grants it does not answer still give its cell: it publishes it on
//! `robot/state` as before.
//!
//! # The first tick, answered early
//! A robot started for a shared grid (`--shared-grid`) does not wait for `Execute` to answer
//! the first tick: while it waits after learning, it makes what it ranks with ([`Prepared`])
//! and sends the horizon of radius `EARLY_HORIZON_RADIUS` at its start for tick 0 (again when
//! merged hints change its values, but never once `Execute` came: tick 0 is then granted or
//! past, and a horizon for it is stale; [`early_answer_due`]). That horizon answers tick 0 on
//! any fleet horizon, so a
//! coordinator that has every robot's wakes nobody for tick 0 (64 robot processes woken at
//! once held the first tick to 4–11 ms on two cores). The coordinator takes only answers sent
//! since the phase began and centered where the robot starts. The robot counts it as its last
//! answer ([`Answering::answered_early`]) but still answers tick 0's grant if it reads it: an
//! early answer that was not taken then costs one wakeup, never a wait for the hang deadline.
//! With one intent per tick (horizon 0) the coordinator takes no early answer.
//!
//! Grants count only from the node whose `Ack` accepted this robot (its coordinator); others
//! are dropped and counted (`grants_foreign`).
//!
//! # Ranking
//! The intent is the robot's learned values at its cell, in the order a tabular learner acts on
//! them: moves it has tried there by Q-value (best first); waiting, valued one tick later than
//! the best of them (`γ · max Q`), so moves that gain nothing over standing still come after
//! it; then moves it never tried from that cell (a learner with a model of its moves knows
//! which), ordered by the robot's own map distance, so a robot pushed off the part of the grid
//! it explored still knows its way back. On its goal a robot prefers to wait. Walls and the
//! border are never named.

use bus::bus_schema::{EARLY_HORIZON_RADIUS, HORIZON_CELLS, HORIZON_WAIT_ONLY};
use mapf::horizon::{Coverage, aligned_radius, diamond_len, diamond_offset, offset_cell, pack};
use mapf::{Intent, Move};
use planner::task::Task;
use planner::{Action, Cell, QTable};

/// Wire code of a wait (`mapf::Move`'s codes are the wire's `Intent::ranked` codes).
pub const WAIT: u8 = Move::Wait.byte();

/// The wire code of a planner action.
pub const fn move_code(a: Action) -> u8 {
    Move::of_action(a).byte()
}

/// A robot's ranking of its moves from its learned values (see the module docs); IO-free.
#[derive(Debug, Clone)]
pub struct Ranker {
    /// The robot's own map distance to its goal per cell (`u32::MAX` unreachable or a wall).
    dist: Vec<u32>,
    /// Per cell, a bitmask of the actions the learner tried there; empty: a learner without a
    /// model, every action counts as tried.
    tried: Vec<u8>,
    goal: Cell,
    gamma: f32,
}

impl Ranker {
    /// A ranker for `task` with the learner's tried (state·4 + action) pairs and discount.
    pub fn new(task: &Task, tried_pairs: &[u32], gamma: f32) -> Self {
        let grid = &task.grid;
        let mut tried = Vec::new();
        if !tried_pairs.is_empty() {
            tried = vec![0u8; grid.len()];
            for &sa in tried_pairs {
                if let Some(t) = tried.get_mut((sa >> 2) as usize) {
                    *t |= 1 << (sa & 3);
                }
            }
        }
        Ranker {
            dist: planner::path::bfs_distances(grid, task.goal),
            tried,
            goal: task.goal,
            gamma,
        }
    }

    /// The ranked move codes at `cell` (best first) and how many there are.
    pub fn rank(&self, task: &Task, q: &QTable, cell: Cell) -> ([u8; 5], u8) {
        let grid = &task.grid;
        let mut out = [0u8; 5];
        let mut n = 0;
        let mut push = |code: u8| {
            out[n] = code;
            n += 1;
        };
        if !grid.contains(cell.x.into(), cell.y.into()) || !grid.is_free(cell) {
            push(WAIT);
            return (out, n as u8);
        }
        let s = grid.index(cell);
        let dist_of = |c: Cell| self.dist[grid.index(c)];
        // (action, next cell) for every legal move
        let mut known: [(f32, u32, u8); 4] = [(0.0, 0, 0); 4];
        let mut k = 0;
        let mut unknown: [(u32, u8); 4] = [(0, 0); 4];
        let mut u = 0;
        let row = q.row(s);
        for a in Action::ALL {
            let Some(next) = grid.neighbor(cell, a) else {
                continue;
            };
            let tried = self.tried.is_empty() || self.tried[s] & (1 << a as u8) != 0;
            if tried && cell != self.goal {
                known[k] = (row[a as usize], dist_of(next), move_code(a));
                k += 1;
            } else {
                unknown[u] = (dist_of(next), move_code(a));
                u += 1;
            }
        }
        // best value first; equal values: the shorter way on the map
        known[..k].sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
        unknown[..u].sort_by_key(|x| x.0);
        if cell == self.goal {
            push(WAIT);
            for &(_, code) in &unknown[..u] {
                push(code);
            }
            return (out, n as u8);
        }
        let here = self.dist[s];
        let wait_value = if k > 0 {
            self.gamma * known[0].0
        } else {
            f32::NAN
        };
        let mut waited = false;
        for &(value, _, code) in &known[..k] {
            if !waited && value <= wait_value {
                push(WAIT);
                waited = true;
            }
            push(code);
        }
        // nothing tried here: the map's way back first, then standing still
        for &(d, code) in &unknown[..u] {
            if !waited && (k > 0 || d >= here) {
                push(WAIT);
                waited = true;
            }
            push(code);
        }
        if !waited {
            push(WAIT);
        }
        (out, n as u8)
    }
}

/// When a robot answers a grant (IO-free): never answered, or its last answer no longer
/// answers the grant's tick at its cell ([`Coverage::answers`], the rule the coordinator
/// waits by).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Answering {
    horizon: u8,
    last: Option<Coverage>,
}

impl Answering {
    /// Bookkeeping for horizon `h` (0: one intent per tick).
    pub fn new(horizon: u8) -> Self {
        Answering {
            horizon,
            last: None,
        }
    }

    /// The horizon asked for.
    pub fn horizon(&self) -> u8 {
        self.horizon
    }

    /// The radius to answer the grant of `tick` with, the robot standing on `cell`; `None`
    /// while the last answer still answers it (nothing to send). The first tick's grant is
    /// always answered when it is read: an early answer (see [`answered_early`]) may not have
    /// been taken, and a coordinator that took every robot's wakes nobody for that tick.
    ///
    /// [`answered_early`]: Self::answered_early
    pub fn due(&self, tick: u32, cell: Cell) -> Option<u8> {
        if tick > 0
            && self
                .last
                .is_some_and(|c| c.answers(self.horizon, tick, cell).is_some())
        {
            return None;
        }
        Some(aligned_radius(self.horizon, tick))
    }

    /// The answer to the first tick went out before `Execute`: the horizon of radius
    /// [`EARLY_HORIZON_RADIUS`] at `start` (it answers tick 0 on any fleet horizon, and a robot
    /// that stays within it is not asked again, as after any answer).
    pub fn answered_early(&mut self, start: Cell) {
        self.answered(0, start, EARLY_HORIZON_RADIUS);
    }

    /// An answer for `tick` from `cell` with `radius` went out.
    pub fn answered(&mut self, tick: u32, cell: Cell, radius: u8) {
        self.last = Some(Coverage {
            from: tick,
            center: cell,
            radius,
        });
    }
}

/// Whether a robot waiting for `Execute` on a shared grid sends its early answer to the first
/// tick now (IO-free): only before the phase's execution began (`executed` false; after it,
/// tick 0 is past and a tick-0 horizon centred on the start is stale, wrong for a robot that
/// stands elsewhere, and an experiment's next phase could take it for its own first tick), and
/// then when nothing was sent for the values of now: `sent_with` is the count of merged-hint
/// entries applied when the last one was made (`None`: none sent), `applied` the count now,
/// `changed` whether settling the values just changed them.
pub fn early_answer_due(
    executed: bool,
    changed: bool,
    sent_with: Option<u64>,
    applied: u64,
) -> bool {
    !executed && (changed || sent_with != Some(applied))
}

/// A robot's packed rankings per cell of its map, each computed the first time a horizon
/// needs it (a horizon overlaps the last one in most of its cells). Cleared when the values
/// change (merged hints applied while it moves).
#[derive(Debug, Clone)]
pub struct RankCache {
    packed: Vec<u16>,
}

/// Marks a cell not ranked yet: no ranking packs to it (7 names no move).
const UNRANKED: u16 = u16::MAX;

impl RankCache {
    /// An empty cache for `task`'s map (the one allocation, before the robot moves).
    pub fn new(task: &Task) -> Self {
        RankCache {
            packed: vec![UNRANKED; task.grid.len()],
        }
    }

    /// Forgets every ranking (the values they came from changed).
    pub fn clear(&mut self) {
        self.packed.fill(UNRANKED);
    }
}

/// What a robot ranks with on a shared grid, made before `Execute` (while the robot waits for
/// it, after the values settled): the ranker (a map search) and the rankings of every cell of
/// the widest horizon around its start. 64 robots making them when `Execute` came held the
/// first tick to ~10 ms on two cores.
#[derive(Debug, Clone)]
pub struct Prepared {
    /// The ranker of the robot's values.
    pub ranker: Ranker,
    /// Rankings made so far (every cell within [`EARLY_HORIZON_RADIUS`] of the start).
    pub cache: RankCache,
    /// The horizon of radius [`EARLY_HORIZON_RADIUS`] at the start, as the wire packs it: the
    /// early answer to the first tick.
    pub first: [u16; HORIZON_CELLS],
}

impl Prepared {
    /// Ranks every cell within [`EARLY_HORIZON_RADIUS`] moves of `task`'s start by `q` (see
    /// [`Ranker::new`] for the rest).
    pub fn new(task: &Task, q: &QTable, tried_pairs: &[u32], gamma: f32) -> Self {
        let ranker = Ranker::new(task, tried_pairs, gamma);
        let mut cache = RankCache::new(task);
        let mut first = [0u16; HORIZON_CELLS];
        ranker.rank_horizon(
            task,
            q,
            &mut cache,
            task.start,
            EARLY_HORIZON_RADIUS,
            &mut first,
        );
        Prepared {
            ranker,
            cache,
            first,
        }
    }
}

impl Ranker {
    /// The packed rankings of every cell of the diamond of `radius` around `center` (the
    /// wire's `IntentHorizon::ranked`; cells off the map or on walls only wait); entries past
    /// the diamond are zero. Allocates nothing.
    pub fn rank_horizon(
        &self,
        task: &Task,
        q: &QTable,
        cache: &mut RankCache,
        center: Cell,
        radius: u8,
        out: &mut [u16; HORIZON_CELLS],
    ) {
        let n = diamond_len(radius).min(HORIZON_CELLS);
        let wait_only = HORIZON_WAIT_ONLY;
        let grid = &task.grid;
        for (i, slot) in out.iter_mut().enumerate() {
            *slot = 0;
            if i >= n {
                continue;
            }
            let Some((dx, dy)) = diamond_offset(radius, i) else {
                continue;
            };
            let Some(c) =
                offset_cell(center, dx, dy).filter(|c| grid.contains(c.x.into(), c.y.into()))
            else {
                *slot = wait_only;
                continue;
            };
            let cached = &mut cache.packed[grid.index(c)];
            if *cached == UNRANKED {
                let (codes, count) = self.rank(task, q, c);
                *cached = Intent::from_bytes(&codes[..usize::from(count)])
                    .map_or(wait_only, |i| pack(&i));
            }
            *slot = *cached;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use planner::Grid;
    use planner::map::GridMap;
    use planner::task::resolve_task;

    fn corridor() -> Task {
        // a 5x1 corridor: start at 0, goal at 4
        let map = GridMap {
            name: "corridor".into(),
            grid: Grid::new(5, 1, vec![true; 5]).unwrap(),
            start: None,
            goals: Vec::new(),
        };
        resolve_task(&map, Some(Cell::new(0, 0)), Some(Cell::new(4, 0))).unwrap()
    }

    fn ranked(r: &Ranker, t: &Task, q: &QTable, c: Cell) -> Vec<u8> {
        let (codes, n) = r.rank(t, q, c);
        codes[..usize::from(n)].to_vec()
    }

    const RIGHT: u8 = move_code(Action::Right);
    const LEFT: u8 = move_code(Action::Left);

    #[test]
    fn learned_values_lead_and_moves_away_come_after_waiting() {
        let t = corridor();
        let mut q = QTable::new(&t.grid);
        // converged values γ^(d-1) towards the goal
        for x in 0..4u16 {
            let s = t.grid.index(Cell::new(x, 0));
            let d = 4 - u32::from(x);
            q.row_mut(s)[Action::Right as usize] = 0.9f32.powi(d as i32 - 1);
            q.row_mut(s)[Action::Left as usize] = 0.9f32.powi(d as i32 + 1);
        }
        let r = Ranker::new(&t, &[], 0.9);
        assert_eq!(ranked(&r, &t, &q, Cell::new(2, 0)), vec![RIGHT, WAIT, LEFT]);
        // the border is never named
        assert_eq!(ranked(&r, &t, &q, Cell::new(0, 0)), vec![RIGHT, WAIT]);
    }

    #[test]
    fn on_its_goal_a_robot_waits_first_and_names_every_way_out() {
        let t = corridor();
        let q = QTable::new(&t.grid);
        let r = Ranker::new(&t, &[], 0.9);
        assert_eq!(ranked(&r, &t, &q, Cell::new(4, 0)), vec![WAIT, LEFT]);
    }

    #[test]
    fn moves_never_tried_come_after_tried_ones_in_map_order() {
        let t = corridor();
        let mut q = QTable::new(&t.grid);
        // optimistic untried values must not outrank what was learned
        for row in q.rows_mut() {
            *row = [1.0; 4];
        }
        let s = t.grid.index(Cell::new(2, 0));
        q.row_mut(s)[Action::Left as usize] = 0.5;
        let tried = [s as u32 * 4 + Action::Left as u32];
        let r = Ranker::new(&t, &tried, 0.9);
        // only Left was tried there: it leads, waiting is worth 0.45, then Right by the map
        assert_eq!(ranked(&r, &t, &q, Cell::new(2, 0)), vec![LEFT, WAIT, RIGHT]);
        // a cell with nothing tried: the map's way back, then waiting, then away
        assert_eq!(ranked(&r, &t, &q, Cell::new(1, 0)), vec![RIGHT, WAIT, LEFT]);
    }

    #[test]
    fn a_horizon_ranks_every_cell_of_its_diamond_as_one_intent_would() {
        let t = corridor();
        let q = QTable::new(&t.grid);
        let r = Ranker::new(&t, &[], 0.9);
        let mut out = [u16::MAX; HORIZON_CELLS];
        let mut cache = RankCache::new(&t);
        r.rank_horizon(&t, &q, &mut cache, Cell::new(1, 0), 2, &mut out);
        // the cache gives the same answer the second time
        let mut again = [0; HORIZON_CELLS];
        r.rank_horizon(&t, &q, &mut cache, Cell::new(1, 0), 2, &mut again);
        assert_eq!(out, again);
        for (i, &bits) in out.iter().enumerate() {
            let Some((dx, dy)) = diamond_offset(2, i).filter(|_| i < diamond_len(2)) else {
                assert_eq!(bits, 0, "entries past the diamond are zero");
                continue;
            };
            let got = mapf::horizon::unpack(bits).unwrap();
            let want = match offset_cell(Cell::new(1, 0), dx, dy) {
                Some(c) => ranked(&r, &t, &q, c),
                None => vec![WAIT],
            };
            let (codes, n) = got.to_bytes();
            assert_eq!(codes[..n].to_vec(), want, "offset ({dx}, {dy})");
        }
    }

    #[test]
    fn what_is_prepared_before_execute_ranks_as_what_is_made_at_execute() {
        let t = corridor();
        let mut q = QTable::new(&t.grid);
        q.row_mut(t.grid.index(Cell::new(1, 0)))[Action::Left as usize] = 0.7;
        let ready = Prepared::new(&t, &q, &[], 0.9);
        let fresh = Ranker::new(&t, &[], 0.9);
        for radius in [0, 2, EARLY_HORIZON_RADIUS] {
            let (mut a, mut b) = ([0u16; HORIZON_CELLS], [0u16; HORIZON_CELLS]);
            let mut cache = ready.cache.clone();
            ready
                .ranker
                .rank_horizon(&t, &q, &mut cache, t.start, radius, &mut a);
            fresh.rank_horizon(&t, &q, &mut RankCache::new(&t), t.start, radius, &mut b);
            assert_eq!(a, b, "radius {radius}");
        }
        // every cell of the widest horizon around the start is ranked already, and that
        // horizon is the one sent early
        assert!(ready.cache.packed.iter().all(|&c| c != UNRANKED));
        let mut widest = [0u16; HORIZON_CELLS];
        fresh.rank_horizon(
            &t,
            &q,
            &mut RankCache::new(&t),
            t.start,
            EARLY_HORIZON_RADIUS,
            &mut widest,
        );
        assert_eq!(ready.first, widest);
    }

    #[test]
    fn a_robot_answers_when_its_horizon_is_used_up_or_left() {
        let mut a = Answering::new(3);
        let at = Cell::new(5, 5);
        assert_eq!(a.due(0, at), Some(3), "never answered");
        a.answered(0, at, 3);
        assert_eq!(a.due(2, Cell::new(6, 6)), None, "inside, in time");
        assert_eq!(a.due(3, Cell::new(8, 5)), None, "the last tick it covers");
        assert_eq!(
            a.due(4, Cell::new(8, 5)),
            Some(3),
            "moved: answers with the fleet in the next period"
        );
        assert_eq!(a.due(4, at), None, "did not move: keeps its horizon");
        assert_eq!(a.due(40, at), None);
        // a late answer (a robot that was slow) ends with the others' period
        let away = Cell::new(8, 5);
        assert_eq!(a.due(6, away), Some(1));
        a.answered(6, away, 1);
        assert_eq!(a.due(7, Cell::new(10, 5)), Some(0), "left its diamond");
        assert_eq!(a.due(8, away), Some(3), "a short horizon is renewed");
        // horizon 0: every tick
        let mut b = Answering::new(0);
        b.answered(4, at, 0);
        assert_eq!(b.due(4, at), None);
        assert_eq!(b.due(5, at), Some(0));
        // an early answer: the first tick is still answered when its grant is read; later
        // ticks as after any answer of radius EARLY_HORIZON_RADIUS
        let mut e = Answering::new(3);
        e.answered_early(at);
        assert_eq!(
            e.due(0, at),
            Some(3),
            "tick 0 read: the early answer may be lost"
        );
        assert_eq!(e.due(2, Cell::new(6, 5)), None, "covered");
        assert_eq!(
            e.due(4, Cell::new(6, 6)),
            None,
            "2 + 3 ≤ 8: the next period too"
        );
        assert_eq!(e.due(4, Cell::new(9, 9)), Some(3), "moved too far");
    }

    #[test]
    fn the_early_answer_goes_out_before_execute_and_never_after_it() {
        // waiting after learning: nothing sent yet, then only when the values changed
        assert!(early_answer_due(false, false, None, 0));
        assert!(!early_answer_due(false, false, Some(7), 7));
        assert!(
            early_answer_due(false, false, Some(7), 9),
            "merged hints applied since"
        );
        assert!(
            early_answer_due(false, true, Some(7), 7),
            "settling changed the values"
        );
        // back to waiting after the execution (its final grant read): `execute` took what was
        // prepared (`None`) and hints keep arriving, yet tick 0 is past: nothing is due
        for (changed, sent_with, applied) in [
            (false, None, 0),
            (true, None, 3),
            (false, Some(1), 3),
            (true, Some(3), 3),
        ] {
            assert!(
                !early_answer_due(true, changed, sent_with, applied),
                "stale tick-0 horizon after the execution ({changed}, {sent_with:?}, {applied})"
            );
        }
    }

    #[test]
    fn the_wire_contract_names_the_codes_this_robot_packs() {
        use bus::bus_schema::MOVE_NAMES;
        assert_eq!(
            HORIZON_WAIT_ONLY,
            pack(&Intent::new(&[Move::Wait]).unwrap()),
            "a wall or off-map cell of a horizon carries the README's wait-only value"
        );
        assert_eq!(MOVE_NAMES[usize::from(WAIT)], "wait");
        for a in Action::ALL {
            let name = format!("{a:?}").to_lowercase();
            assert!(
                MOVE_NAMES[usize::from(move_code(a))].starts_with(&name),
                "{a:?} is code {}",
                move_code(a)
            );
        }
    }

    #[test]
    fn a_cell_off_the_grid_or_on_a_wall_only_waits() {
        let t = corridor();
        let q = QTable::new(&t.grid);
        let r = Ranker::new(&t, &[], 0.9);
        assert_eq!(ranked(&r, &t, &q, Cell::new(9, 9)), vec![WAIT]);
    }
}
