//! A robot's side of sharing: the Q-hint batcher of its hot loop and the rule that applies the
//! fleet's merged hints to its local Q-table (the options and which rule fits which learner are
//! the process contract's, `contract::share`).
//!
//! # Applying merged hints (the documented rule)
//!
//! Every entry of a `MergedHintBatch` is checked first (goal id of this robot, `count` within
//! the batch capacity, cell inside the grid, action `0..4`, a finite value, an origin robot
//! inside the fleet); a bad entry is counted as rejected and skipped, never used as an index.
//! Entries whose origin is this robot are skipped (they are its own values coming back). The
//! others are applied by [`ApplyRule`]:
//!
//! The default is the rule that fits the learner's [`ValueBound`]: `max` for the paper's
//! learners (lower bounds), `min` for the planning learner (upper bounds); `--apply` overrides
//! it ([`ApplyRule::for_bound`], [`ApplyRule::fits`]).
//!
//! - `max` (paper learners): `q_local = max(q_local, q_hint)` for positive `q_hint` only. With the
//!   planner's rewards (goal > 0, plain moves 0, collisions < 0) and pseudo-target values below
//!   the goal's discounted value, every positive Q-value a robot learns is at most the optimal
//!   Q*, so the maximum over robots is a better estimate of Q* than any single robot's and
//!   never overshoots; negative values (collisions) stay local.
//! - `blend`: `q_local += w·(q_hint − q_local)` with the visit weight
//!   `w = v_hint / (v_hint + v_local)`, `v` the number of updates each value rests on: a value
//!   learned from many visits pulls harder. Also applies negative values.
//! - `latest`: `q_local = q_hint`, positive or negative: the fleet's newest value of an entry
//!   replaces the robot's own, as if all robots updated one shared table (with the latency of
//!   a batch). Unlike `max` it can *lower* a value. That matters because the `max` argument
//!   above does not hold for pseudo targets: their value is set by Manhattan distance, so one
//!   behind a wall is worth far more than its true Q*, and after the targets are removed those
//!   overestimates must decay — under `max` every robot's decayed value is raised again by the
//!   fleet's stale maximum. Pair it with the coordinator's `--merge latest`.
//! - `min` (planning learner): `q_local = min(q_local, q_hint)`, positive or negative. Its
//!   values start optimistic and every update keeps them at or above Q*, so the smaller of two
//!   upper bounds is the better one: an action another robot has tried loses its optimism
//!   here, and this robot's own exploration goes where no robot has been (shared
//!   exploration). Pair it with the coordinator's `--merge min`.
//!
//! A learner that plans (backward replay, Dyna sweeps) changes many values after an episode
//! that no step noted; the robot offers its tried pairs' values to the batcher then
//! ([`HintBatcher::offer`]), so the fleet gets its planned values, not only its step updates.
//!
//! Every applied foreign entry also gives one sample of the end-to-end loop latency: the
//! monotonic time of the oldest robot update merged into it (`origin_ns`) to the moment this
//! robot applied it. Fleet-table resends (`origin_robot == ROBOT_ID_ALL`) carry no origin time
//! and give no sample.

use bus_schema::{HINT_BATCH_CAP, MergedHintBatch, QHint, QHintBatch, ROBOT_ID_ALL};
pub use contract::share::{ApplyRule, ValueBound};
use hdrhistogram::Histogram;
use planner::QTable;
pub use report::ApplyCounters;

use report::hist::{new_hist, record};

/// Collects the Q-values a robot changes into one pending `QHintBatch`, one entry per
/// (cell, action) — a value changed twice before sending is sent once, with its newest value.
///
/// Allocation-free after construction; `note` is the only call in the hot loop.
pub struct HintBatcher {
    entries: Box<[QHint; HINT_BATCH_CAP]>,
    len: usize,
    cap: usize,
    /// Per (cell·4 + action): position + 1 in `entries`, 0 = not pending.
    slot: Vec<u16>,
    /// Per (cell·4 + action): the value last shared (to skip insignificant changes).
    last_shared: Vec<f32>,
    /// Per (cell·4 + action): updates made to it by this robot (saturating).
    visits: Vec<u16>,
    min_change: f32,
    /// Monotonic time of the first update in the pending batch.
    oldest_ns: u64,
    /// Step counter value when the pending batch got its first entry.
    first_step: u64,
}

impl HintBatcher {
    /// A batcher for a grid of `cells` cells sending up to `cap` entries per batch.
    pub fn new(cells: usize, cap: usize, min_change: f32) -> Self {
        HintBatcher {
            entries: Box::new([QHint::ZEROED; HINT_BATCH_CAP]),
            len: 0,
            cap: cap.clamp(1, HINT_BATCH_CAP),
            slot: vec![0; cells * 4],
            last_shared: vec![0.0; cells * 4],
            visits: vec![0; cells * 4],
            min_change,
            oldest_ns: 0,
            first_step: 0,
        }
    }

    /// Records one Q update; returns true when the batch is full and must be sent.
    ///
    /// `state`, `action` come from the learner, so they are in range; `now_ns` is called only
    /// when the batch gets its first entry (a clock read costs as much as a learner step).
    #[inline]
    pub fn note(
        &mut self,
        state: u32,
        action: u8,
        q: f32,
        step: u64,
        now_ns: impl FnOnce() -> u64,
    ) -> bool {
        self.put(state, action, q, step, now_ns, true)
    }

    /// Offers a value the learner changed outside a step (replay, sweeps): queued like
    /// [`note`](Self::note) when it moved enough since last shared, but not counted as a visit
    /// (a sweep is not an experience). Returns true when the batch is full.
    #[inline]
    pub fn offer(
        &mut self,
        state: u32,
        action: u8,
        q: f32,
        step: u64,
        now_ns: impl FnOnce() -> u64,
    ) -> bool {
        self.put(state, action, q, step, now_ns, false)
    }

    #[inline(always)]
    fn put(
        &mut self,
        state: u32,
        action: u8,
        q: f32,
        step: u64,
        now_ns: impl FnOnce() -> u64,
        visit: bool,
    ) -> bool {
        let idx = state as usize * 4 + (action as usize & 3);
        let Some(v) = self.visits.get_mut(idx) else {
            return false;
        };
        if visit {
            *v = v.saturating_add(1);
        }
        let visits = *v;
        let last = self.last_shared[idx];
        if (q - last).abs() <= self.min_change * q.abs().max(last.abs()) {
            return false;
        }
        let pos = self.slot[idx];
        if pos != 0 {
            let e = &mut self.entries[pos as usize - 1];
            e.q = q;
            e.visits = visits;
            return false;
        }
        if self.len == 0 {
            self.oldest_ns = now_ns();
            self.first_step = step;
        }
        self.entries[self.len] = QHint {
            cell: state,
            action: action & 3,
            visits,
            q,
            ..QHint::ZEROED
        };
        self.len += 1;
        self.slot[idx] = self.len as u16;
        self.len >= self.cap
    }

    /// Entries waiting to be sent.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether nothing is waiting.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether the pending batch is older than `flush_steps` steps.
    #[inline]
    pub fn due(&self, step: u64, flush_steps: u64) -> bool {
        self.len > 0 && step.wrapping_sub(self.first_step) >= flush_steps
    }

    /// Updates this robot made to (cell, action), for the visit-weighted blend.
    pub fn visits(&self) -> &[u16] {
        &self.visits
    }

    /// Writes the pending entries into `out` (a zeroed, loaned batch) and empties the batcher;
    /// returns the number of entries.
    pub fn fill(&mut self, out: &mut QHintBatch) -> usize {
        let n = self.len;
        out.count = n as u32;
        out.oldest_update_ns = self.oldest_ns;
        out.entries[..n].copy_from_slice(&self.entries[..n]);
        self.clear_shared();
        n
    }

    /// Empties the batcher as if the batch had been sent.
    pub fn clear_shared(&mut self) {
        for e in &self.entries[..self.len] {
            let idx = e.cell as usize * 4 + e.action as usize;
            self.slot[idx] = 0;
            self.last_shared[idx] = e.q;
        }
        self.len = 0;
    }
}

/// Who this robot is, for checking merged batches.
#[derive(Debug, Clone, Copy)]
pub struct ApplyCtx {
    /// This robot.
    pub robot_id: u32,
    /// Fleet size (origin robots must be below it).
    pub robots: u32,
    /// Goal this robot learns.
    pub goal_id: u32,
    /// The rule.
    pub rule: ApplyRule,
}

impl ApplyCtx {
    /// Robot 1 of a fleet of two, learning goal 0 and applying by `max`: the robot whose side
    /// the latency benchmarks measure (`fleetbench`'s update-loop rows, `benches/merge.rs`), one
    /// context so they all measure the same applier.
    pub fn second_of_two() -> Self {
        ApplyCtx {
            robot_id: 1,
            robots: 2,
            goal_id: 0,
            rule: ApplyRule::Max,
        }
    }
}

/// Applies merged batches to a robot's Q-table by the documented rule (module docs): owns who
/// the robot is ([`ApplyCtx`]), the gap tracking of `coordinator_seq`, the counters and the
/// end-to-end loop-latency histogram.
///
/// Allocation-free after construction; [`apply`](Self::apply) runs in the learning loop.
#[derive(Debug, Clone)]
pub struct MergedApplier {
    ctx: ApplyCtx,
    last_seq: Option<u64>,
    counters: ApplyCounters,
    loop_hist: Histogram<u64>,
}

impl MergedApplier {
    /// An applier for the robot described by `ctx`.
    pub fn new(ctx: ApplyCtx) -> Self {
        MergedApplier {
            ctx,
            last_seq: None,
            counters: ApplyCounters::default(),
            loop_hist: new_hist(),
        }
    }

    /// The robot now learns `goal_id`: batches of other goals are skipped from here on.
    pub fn set_goal(&mut self, goal_id: u32) {
        self.ctx.goal_id = goal_id;
    }

    /// Counters so far.
    pub fn counters(&self) -> &ApplyCounters {
        &self.counters
    }

    /// Origin of a foreign Q update → applied here, one sample per applied foreign entry.
    pub fn loop_hist(&self) -> &Histogram<u64> {
        &self.loop_hist
    }

    /// Empties the loop-latency histogram: a new measurement window (benchmarks drop their
    /// warm-up samples this way).
    pub fn clear_loop_hist(&mut self) {
        self.loop_hist.reset();
    }

    /// Applies one merged batch to `q` (`visits`: this robot's updates per (cell, action), for
    /// `blend`), recording the loop latency of every foreign entry at `now_ns`.
    pub fn apply(&mut self, batch: &MergedHintBatch, q: &mut QTable, visits: &[u16], now_ns: u64) {
        let (ctx, c) = (&self.ctx, &mut self.counters);
        c.batches += 1;
        if let Some(prev) = self.last_seq
            && batch.coordinator_seq > prev + 1
        {
            c.batches_missed += batch.coordinator_seq - prev - 1;
        }
        self.last_seq = Some(batch.coordinator_seq);
        let n = batch.count as usize;
        if batch.goal_id != ctx.goal_id || n > HINT_BATCH_CAP {
            c.batches_rejected += 1;
            return;
        }
        let cells = q.cells();
        for i in 0..n {
            let h = &batch.entries[i];
            let origin = batch.origin_robot[i];
            if origin == ctx.robot_id {
                c.entries_own += 1;
                continue;
            }
            let cell = h.cell as usize;
            let action = h.action as usize;
            if cell >= cells
                || action >= 4
                || !h.q.is_finite()
                || (origin != ROBOT_ID_ALL && origin >= ctx.robots)
            {
                c.entries_rejected += 1;
                continue;
            }
            c.entries_seen += 1;
            let local = q.row(cell)[action];
            let new = match ctx.rule {
                ApplyRule::Max => {
                    if h.q > 0.0 && h.q > local {
                        h.q
                    } else {
                        local
                    }
                }
                ApplyRule::Blend => {
                    let vh = f32::from(h.visits.max(1));
                    let vl = f32::from(visits.get(cell * 4 + action).copied().unwrap_or(0));
                    local + vh / (vh + vl) * (h.q - local)
                }
                ApplyRule::Latest => h.q,
                ApplyRule::Min => local.min(h.q),
            };
            if new != local && q.set_checked(cell, action, new) {
                c.entries_applied += 1;
            }
            let origin_ns = batch.origin_ns[i];
            if origin != ROBOT_ID_ALL && origin_ns != 0 && origin_ns <= now_ns {
                record(&mut self.loop_hist, now_ns - origin_ns);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> planner::Grid {
        planner::Grid::new(4, 2, vec![true; 8]).unwrap()
    }

    #[test]
    fn batcher_dedups_and_skips_small_changes() {
        let mut b = HintBatcher::new(8, 3, 1e-3);
        let mut clock_reads = 0;
        let mut now = || {
            clock_reads += 1;
            77
        };
        assert!(!b.note(1, 2, 0.5, 10, &mut now));
        assert!(!b.note(1, 2, 0.6, 11, &mut now)); // same entry, newer value
        assert!(!b.note(2, 0, 0.0, 12, &mut now)); // 0 -> 0: nothing to share
        assert_eq!(b.len(), 1);
        assert!(!b.note(3, 1, -0.1, 13, &mut now));
        assert!(b.note(4, 3, 0.2, 14, &mut now), "third entry fills cap 3");
        assert_eq!(clock_reads, 1);
        assert!(b.due(1034, 1024) && !b.due(1033, 1024));
        let mut out = QHintBatch::ZEROED;
        assert_eq!(b.fill(&mut out), 3);
        assert_eq!((out.count, out.oldest_update_ns), (3, 77));
        assert_eq!(
            (out.entries[0].cell, out.entries[0].q, out.entries[0].visits),
            (1, 0.6, 2)
        );
        assert!(b.is_empty());
        // unchanged since shared: not sent again; a real change is
        assert!(!b.note(1, 2, 0.6, 20, || 1));
        assert!(b.is_empty());
        assert!(!b.note(1, 2, 0.7, 21, || 1));
        assert_eq!(b.len(), 1);
        assert_eq!(b.visits()[6], 4);
        // out-of-grid states are ignored rather than indexing out of bounds
        assert!(!b.note(99, 0, 1.0, 22, || 1));
    }

    fn merged(entries: &[(u32, u8, f32, u32)]) -> MergedHintBatch {
        let mut m = MergedHintBatch {
            coordinator_seq: 5,
            goal_id: 0,
            count: entries.len() as u32,
            ..MergedHintBatch::ZEROED
        };
        for (i, &(cell, action, q, origin)) in entries.iter().enumerate() {
            m.entries[i] = QHint {
                cell,
                action,
                q,
                visits: 3,
                ..QHint::ZEROED
            };
            m.origin_ns[i] = 100;
            m.origin_robot[i] = origin;
        }
        m
    }

    #[test]
    fn max_rule_raises_positive_values_only_and_validates() {
        let mut q = QTable::new(&grid());
        q.set_checked(1, 0, 0.5);
        let ctx = ApplyCtx {
            robot_id: 0,
            robots: 2,
            goal_id: 0,
            rule: ApplyRule::Max,
        };
        let m = merged(&[
            (1, 0, 0.4, 1),            // lower: kept local
            (2, 1, 0.3, 1),            // raised
            (3, 2, -0.5, 1),           // negative: ignored
            (4, 0, 0.9, 0),            // own
            (99, 0, 0.9, 1),           // cell out of range
            (5, 7, 0.9, 1),            // action out of range
            (5, 0, f32::NAN, 1),       // not finite
            (5, 0, 0.9, 9),            // origin outside the fleet
            (6, 3, 0.2, ROBOT_ID_ALL), // fleet resend: applied, no latency sample
        ]);
        let mut a = MergedApplier::new(ctx);
        let mut earlier = merged(&[]);
        earlier.coordinator_seq = 3;
        a.apply(&earlier, &mut q, &[0; 32], 1100);
        a.apply(&m, &mut q, &[0; 32], 1100);
        let (c, h) = (*a.counters(), a.loop_hist().clone());
        assert_eq!(q.row(1)[0], 0.5);
        assert_eq!(q.row(2)[1], 0.3);
        assert_eq!(q.row(3)[2], 0.0);
        assert_eq!(q.row(4)[0], 0.0);
        assert_eq!(q.row(6)[3], 0.2);
        assert_eq!(c.entries_applied, 2);
        assert_eq!(c.entries_rejected, 4);
        assert_eq!(c.entries_own, 1);
        assert_eq!(c.batches_missed, 1);
        assert_eq!(h.len(), 3);
        assert_eq!(h.max(), h.highest_equivalent(1000));
        // another goal, or a lying count: the batch is skipped whole
        let mut bad = m;
        bad.count = 10_000;
        a.apply(&bad, &mut q, &[0; 32], 1100);
        bad.count = 1;
        bad.goal_id = 4;
        a.apply(&bad, &mut q, &[0; 32], 1100);
        assert_eq!(a.counters().batches_rejected, 2);
        // after a goal change the same batch is the robot's goal again
        a.set_goal(4);
        a.apply(&bad, &mut q, &[0; 32], 1100);
        assert_eq!(a.counters().batches_rejected, 2);
    }

    #[test]
    fn min_rule_lowers_to_tighter_upper_bounds_only() {
        let g = grid();
        let mut q = QTable::new(&g);
        for c in 0..8 {
            *q.row_mut(c) = [1.0; 4]; // the planning learner's optimistic start
        }
        q.set_checked(1, 0, 0.5); // tried here already: tighter than the hint below
        let ctx = ApplyCtx {
            robot_id: 0,
            robots: 2,
            goal_id: 0,
            rule: ApplyRule::Min,
        };
        let mut a = MergedApplier::new(ctx);
        let m = merged(&[
            (1, 0, 0.7, 1),            // looser: kept local
            (2, 1, 0.3, 1),            // an action robot 1 tried: loses its optimism here
            (3, 2, -0.5, 1),           // a collision bound: taken too
            (4, 0, 0.1, 0),            // own value coming back: skipped
            (5, 0, f32::NAN, 1),       // still validated
            (6, 3, 0.4, ROBOT_ID_ALL), // fleet resend
        ]);
        a.apply(&m, &mut q, &[0; 32], 1100);
        assert_eq!(q.row(1)[0], 0.5);
        assert_eq!(q.row(2), &[1.0, 0.3, 1.0, 1.0]);
        assert_eq!(q.row(3)[2], -0.5);
        assert_eq!(q.row(4)[0], 1.0);
        assert_eq!(q.row(5)[0], 1.0);
        assert_eq!(q.row(6)[3], 0.4);
        let c = a.counters();
        assert_eq!(
            (c.entries_applied, c.entries_own, c.entries_rejected),
            (3, 1, 1)
        );
    }

    #[test]
    fn offered_planned_values_are_shared_but_not_counted_as_visits() {
        let mut b = HintBatcher::new(8, 4, 1e-3);
        assert!(!b.note(1, 2, 0.9, 1, || 5));
        assert!(!b.offer(1, 2, 0.5, 2, || 5)); // a sweep lowered it: newest value queued
        assert!(!b.offer(3, 0, 0.25, 3, || 5));
        assert!(!b.offer(4, 0, 0.0, 3, || 5)); // unchanged since (never) shared: skipped
        assert_eq!(b.len(), 2);
        assert_eq!((b.visits()[6], b.visits()[12]), (1, 0));
        let mut out = QHintBatch::ZEROED;
        assert_eq!(b.fill(&mut out), 2);
        assert_eq!((out.entries[0].q, out.entries[0].visits), (0.5, 1));
        assert_eq!((out.entries[1].q, out.entries[1].visits), (0.25, 0));
        assert!(!b.offer(3, 0, 0.25, 4, || 5));
        assert!(b.is_empty(), "already shared");
    }

    #[test]
    fn blend_rule_weights_by_visits() {
        let mut q = QTable::new(&grid());
        q.set_checked(2, 1, 1.0);
        let mut visits = [0u16; 32];
        visits[9] = 3; // cell 2, action 1: as many visits as the hint
        let ctx = ApplyCtx {
            robot_id: 0,
            robots: 2,
            goal_id: 0,
            rule: ApplyRule::Blend,
        };
        let m = merged(&[(2, 1, 0.0, 1), (3, 0, -1.0, 1)]);
        MergedApplier::new(ctx).apply(&m, &mut q, &visits, 1100);
        assert_eq!(q.row(2)[1], 0.5);
        assert_eq!(q.row(3)[0], -1.0);
    }

    #[test]
    fn latest_rule_takes_foreign_values_as_they_are() {
        let mut q = QTable::new(&grid());
        q.set_checked(1, 0, 0.5); // an overestimate the fleet has since corrected
        q.set_checked(2, 1, 0.1);
        q.set_checked(4, 0, 0.7);
        let ctx = ApplyCtx {
            robot_id: 0,
            robots: 2,
            goal_id: 0,
            rule: ApplyRule::Latest,
        };
        let mut a = MergedApplier::new(ctx);
        let m = merged(&[
            (1, 0, 0.2, 1),            // lowered
            (2, 1, 0.3, 1),            // raised
            (3, 2, -0.5, 1),           // negative: taken too
            (4, 0, 0.0, 0),            // own value coming back: skipped
            (5, 0, f32::NAN, 1),       // still validated
            (6, 3, 0.4, ROBOT_ID_ALL), // fleet resend
        ]);
        a.apply(&m, &mut q, &[0; 32], 1100);
        let c = a.counters();
        assert_eq!(q.row(1)[0], 0.2);
        assert_eq!(q.row(2)[1], 0.3);
        assert_eq!(q.row(3)[2], -0.5);
        assert_eq!(q.row(4)[0], 0.7);
        assert_eq!(q.row(5)[0], 0.0);
        assert_eq!(q.row(6)[3], 0.4);
        assert_eq!(
            (c.entries_applied, c.entries_own, c.entries_rejected),
            (4, 1, 1)
        );
    }
}
