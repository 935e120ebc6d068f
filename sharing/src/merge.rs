//! The fleet table: one merged Q-value per (cell, action) of a goal, and the merge rules.
//!
//! # Merge rules (selectable with `--merge`; `qfleet run` and `experiment` default to the one
//! that fits the learner, [`contract::share::merge_rule_for`])
//! - `max` (paper learners): the fleet value is the largest value any robot reported last. A new
//!   value replaces the fleet value when it is larger, or when it comes from the robot that set
//!   the current one (so a robot can correct its own value downwards). With the planner's
//!   rewards every positive learned Q-value the paper's learners learn is at most Q*, so the
//!   largest is the best estimate.
//! - `mean`: visit-weighted mean, `q ← q + v/(v + V)·(q_new − q)` with `v` the reporting robot's
//!   visit count for the entry and `V` the largest visit count seen for it; values resting on
//!   more updates weigh more, and the table still follows changes.
//! - `latest`: the newest report wins.
//! - `min`: the smallest value any robot ever reported; a larger report (the owner's
//!   included) changes nothing. For learners whose every value is an upper bound of Q*
//!   ([`ValueBound::Upper`](contract::share::ValueBound): the planning learner's optimistic start,
//!   replay and sweeps): the minimum of upper bounds is still one, and the tightest the fleet
//!   has. A robot's value can rise again after it took a lower fleet value (its next backup
//!   reads its own, looser neighbours), but the smaller report stays a true bound, so there is
//!   nothing to correct.
//!
//! [`contract::share::merge_rule_for`] picks the rule that fits a learner's bound (`max` for lower bounds, `min` for
//! upper ones); [`fits`] says whether a rule suits it.
//!
//! An entry that changes is queued for the next `MergedHintBatch` with the origin time and robot
//! of the update that changed it (the end-to-end latency is measured from there).

use bus_schema::{HINT_BATCH_CAP, MergedHintBatch, QHint, ROBOT_ID_ALL};

pub use report::run::MergeRule;

/// `owner` of an entry no robot has reported yet.
const NO_OWNER: u32 = u32::MAX;

#[derive(Debug, Clone, Copy)]
struct Entry {
    q: f32,
    visits: u16,
    owner: u32,
}

/// The merged Q-table of one goal, plus the merged batch being filled for the robots.
///
/// A table made [`lazy`](Self::lazy) takes its memory only when a robot first reports to it.
pub struct FleetTable {
    rule: MergeRule,
    cells: usize,
    /// Per (cell·4 + action); empty until [`reserve`](Self::reserve).
    entries: Vec<Entry>,
    out: Box<MergedHintBatch>,
    /// Per (cell·4 + action): position + 1 in `out`, 0 = not queued; empty until
    /// [`reserve`](Self::reserve).
    slot: Vec<u16>,
    /// Entries changed by a merge, over the run.
    pub changes: u64,
}

impl FleetTable {
    /// An empty table for a grid of `cells` cells.
    pub fn new(cells: usize, rule: MergeRule) -> Self {
        let mut t = Self::lazy(cells, rule);
        t.reserve();
        t
    }

    /// A table that takes its memory at its first [`reserve`](Self::reserve): a lifelong run
    /// keeps one per goal cell its tasks name, most of which no robot learns before the end.
    pub fn lazy(cells: usize, rule: MergeRule) -> Self {
        FleetTable {
            rule,
            cells,
            entries: Vec::new(),
            out: Box::new(MergedHintBatch::ZEROED),
            slot: Vec::new(),
            changes: 0,
        }
    }

    /// Number of cells covered.
    pub fn cells(&self) -> usize {
        self.cells
    }

    /// Whether any robot reported a value for this goal yet.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The fleet value of (cell, action), if any robot reported it.
    pub fn get(&self, cell: usize, action: usize) -> Option<f32> {
        self.entries
            .get(cell * 4 + action)
            .filter(|e| e.owner != NO_OWNER)
            .map(|e| e.q)
    }

    /// Merges one validated hint from `robot`; queues the entry for the robots when it changed.
    /// Returns true when the pending merged batch is full and must be sent before the next call.
    pub fn merge(&mut self, robot: u32, h: &QHint, origin_ns: u64) -> bool {
        let idx = h.cell as usize * 4 + h.action as usize;
        let Some(e) = self.entries.get_mut(idx) else {
            return false;
        };
        let before = e.q;
        let fresh = e.owner == NO_OWNER;
        match self.rule {
            MergeRule::Max => {
                if fresh || h.q > e.q || e.owner == robot {
                    e.q = h.q;
                    e.owner = robot;
                }
            }
            MergeRule::Mean => {
                if fresh {
                    e.q = h.q;
                } else {
                    let v = f32::from(h.visits.max(1));
                    let w = v / (v + f32::from(e.visits.max(1)));
                    e.q += w * (h.q - e.q);
                }
                e.visits = e.visits.max(h.visits);
                e.owner = robot;
            }
            MergeRule::Latest => {
                e.q = h.q;
                e.owner = robot;
            }
            MergeRule::Min => {
                if fresh || h.q < e.q {
                    e.q = h.q;
                    e.owner = robot;
                }
            }
        }
        e.visits = e.visits.max(h.visits);
        if !(fresh || e.q != before) {
            return false;
        }
        self.changes += 1;
        let (q, visits, owner) = (e.q, e.visits, e.owner);
        self.queue(idx, q, visits, origin_ns, owner)
    }

    fn queue(&mut self, idx: usize, q: f32, visits: u16, origin_ns: u64, origin: u32) -> bool {
        let out = &mut self.out;
        let pos = self.slot[idx] as usize;
        if pos != 0 {
            let i = pos - 1;
            out.entries[i].q = q;
            out.entries[i].visits = visits;
            // keep the oldest origin: the latency of the slowest update it carries
            if origin_ns < out.origin_ns[i] {
                out.origin_ns[i] = origin_ns;
                out.origin_robot[i] = origin;
            }
            return false;
        }
        let i = out.count as usize;
        out.entries[i] = QHint {
            cell: (idx / 4) as u32,
            action: (idx % 4) as u8,
            visits,
            q,
            ..QHint::ZEROED
        };
        out.origin_ns[i] = origin_ns;
        out.origin_robot[i] = origin;
        out.count += 1;
        self.slot[idx] = out.count as u16;
        out.count as usize >= HINT_BATCH_CAP
    }

    /// Takes the table's memory if it has none yet: call it before merging a batch (a table made
    /// by [`lazy`](Self::lazy) drops every hint until then). Kept off [`merge`](Self::merge):
    /// a branch per entry there cost the merge 10–20 % (`cargo bench --bench merge`).
    pub fn reserve(&mut self) {
        if self.entries.is_empty() {
            let none = Entry {
                q: 0.0,
                visits: 0,
                owner: NO_OWNER,
            };
            self.entries = vec![none; self.cells * 4];
            self.slot = vec![0; self.cells * 4];
        }
    }

    /// Empties the pending merged batch without sending it: the table keeps every value, the
    /// robots get them later as a whole ([`resend_all`](Self::resend_all)).
    pub fn drop_pending(&mut self) {
        let n = self.out.count as usize;
        for e in &self.out.entries[..n] {
            self.slot[e.cell as usize * 4 + e.action as usize] = 0;
        }
        self.out.count = 0;
    }

    /// Entries waiting in the pending merged batch.
    pub fn pending(&self) -> usize {
        self.out.count as usize
    }

    /// Copies the pending batch into `m` (a zeroed, loaned sample) and empties it; the caller
    /// sets `coordinator_seq`, `goal_id` and `send_time_ns`. Returns the number of entries.
    pub fn take_into(&mut self, m: &mut MergedHintBatch) -> usize {
        let n = self.out.count as usize;
        m.count = n as u32;
        m.entries[..n].copy_from_slice(&self.out.entries[..n]);
        m.origin_ns[..n].copy_from_slice(&self.out.origin_ns[..n]);
        m.origin_robot[..n].copy_from_slice(&self.out.origin_robot[..n]);
        m.oldest_origin_ns = self.out.origin_ns[..n].iter().copied().min().unwrap_or(0);
        for e in &self.out.entries[..n] {
            self.slot[e.cell as usize * 4 + e.action as usize] = 0;
        }
        self.out.count = 0;
        n
    }

    /// Queues every known entry (positive ones first) as a fleet-table resend: origin robot
    /// `ROBOT_ID_ALL`, origin time 0 (no latency sample). Calls `send` whenever a batch is full
    /// and once at the end; returns the number of entries resent.
    pub fn resend_all(&mut self, mut send: impl FnMut(&mut Self)) -> usize {
        let mut n = 0;
        for positive in [true, false] {
            for idx in 0..self.entries.len() {
                let e = self.entries[idx];
                if e.owner == NO_OWNER || (e.q > 0.0) != positive {
                    continue;
                }
                n += 1;
                if self.queue(idx, e.q, e.visits, 0, ROBOT_ID_ALL) {
                    send(self);
                }
            }
        }
        if self.pending() > 0 {
            send(self);
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use contract::share::{ValueBound, merge_fits, merge_rule_for};

    fn h(cell: u32, action: u8, q: f32, visits: u16) -> QHint {
        QHint {
            cell,
            action,
            q,
            visits,
            ..QHint::ZEROED
        }
    }

    #[test]
    fn max_keeps_the_largest_and_lets_the_owner_correct_it() {
        let mut t = FleetTable::new(4, MergeRule::Max);
        t.merge(0, &h(1, 2, 0.5, 1), 10);
        t.merge(1, &h(1, 2, 0.3, 1), 20);
        assert_eq!(t.get(1, 2), Some(0.5));
        t.merge(0, &h(1, 2, 0.4, 2), 30);
        assert_eq!(t.get(1, 2), Some(0.4), "owner lowers its own value");
        t.merge(1, &h(1, 2, 0.45, 2), 40);
        assert_eq!(t.get(1, 2), Some(0.45));
        assert_eq!(t.get(2, 0), None);
        // one pending entry, origin = the oldest update merged into it
        assert_eq!(t.pending(), 1);
        let mut m = MergedHintBatch::ZEROED;
        assert_eq!(t.take_into(&mut m), 1);
        assert_eq!(
            (m.entries[0].q, m.origin_ns[0], m.origin_robot[0]),
            (0.45, 10, 0)
        );
        assert_eq!(m.oldest_origin_ns, 10);
        assert!(!t.is_empty());
        assert_eq!(t.pending(), 0);
        // no change, nothing queued; out-of-range entries are ignored
        t.merge(0, &h(1, 2, 0.1, 1), 50);
        t.merge(0, &h(99, 0, 1.0, 1), 50);
        assert_eq!(t.pending(), 0);
    }

    #[test]
    fn min_keeps_the_smallest_upper_bound_and_nobody_raises_it() {
        let mut t = FleetTable::new(4, MergeRule::Min);
        t.merge(0, &h(1, 2, 0.9, 1), 10);
        assert_eq!(t.get(1, 2), Some(0.9), "the first report sets the entry");
        t.merge(1, &h(1, 2, 0.6, 1), 20);
        assert_eq!(
            t.get(1, 2),
            Some(0.6),
            "a tighter bound from another robot wins"
        );
        // the owner's value rose again (its backup read looser neighbours): the smaller
        // report is still a true upper bound, so it stays
        t.merge(1, &h(1, 2, 0.8, 2), 30);
        assert_eq!(t.get(1, 2), Some(0.6));
        t.merge(0, &h(1, 2, 0.95, 2), 40);
        assert_eq!(t.get(1, 2), Some(0.6));
        // negative values (collisions) are bounds too and merge the same way
        t.merge(0, &h(2, 0, -0.2, 1), 50);
        t.merge(1, &h(2, 0, -0.01, 1), 60);
        assert_eq!(t.get(2, 0), Some(-0.2));
        let mut m = MergedHintBatch::ZEROED;
        assert_eq!(t.take_into(&mut m), 2);
        // the queued entry carries the value and origin of its oldest change
        assert_eq!(
            (m.entries[0].q, m.origin_ns[0], m.origin_robot[0]),
            (0.6, 10, 0)
        );
        // nothing lower: nothing queued
        t.merge(0, &h(1, 2, 0.6, 3), 70);
        assert_eq!(t.pending(), 0);
        t.merge(1, &h(1, 2, 0.5, 3), 80);
        assert_eq!((t.pending(), t.get(1, 2)), (1, Some(0.5)));
    }

    #[test]
    fn the_rule_follows_the_learners_bound() {
        assert_eq!(merge_rule_for(ValueBound::Lower), MergeRule::Max);
        assert_eq!(merge_rule_for(ValueBound::Upper), MergeRule::Min);
        for b in [ValueBound::Lower, ValueBound::Upper] {
            assert!(merge_fits(merge_rule_for(b), b));
            assert!(merge_fits(MergeRule::Mean, b) && merge_fits(MergeRule::Latest, b));
        }
        assert!(!merge_fits(MergeRule::Max, ValueBound::Upper));
        assert!(!merge_fits(MergeRule::Min, ValueBound::Lower));
    }

    #[test]
    fn mean_weights_by_visits_and_latest_overwrites() {
        let mut t = FleetTable::new(2, MergeRule::Mean);
        t.merge(0, &h(0, 0, 1.0, 3), 1);
        t.merge(1, &h(0, 0, 0.0, 1), 2);
        assert_eq!(t.get(0, 0), Some(0.75));
        let mut t = FleetTable::new(2, MergeRule::Latest);
        t.merge(0, &h(0, 0, 1.0, 3), 1);
        t.merge(1, &h(0, 0, -1.0, 1), 2);
        assert_eq!(t.get(0, 0), Some(-1.0));
    }

    #[test]
    fn full_batches_are_signalled_and_resend_covers_the_table() {
        let mut t = FleetTable::new(100, MergeRule::Max);
        let mut full = 0;
        for i in 0..300u32 {
            if t.merge(0, &h(i / 4, (i % 4) as u8, 0.1 + i as f32, 1), 5) {
                full += 1;
                let mut m = MergedHintBatch::ZEROED;
                assert_eq!(t.take_into(&mut m), HINT_BATCH_CAP);
            }
        }
        assert_eq!(full, 1);
        let mut m = MergedHintBatch::ZEROED;
        t.take_into(&mut m);
        let mut sent = Vec::new();
        let n = t.resend_all(|t| {
            let mut m = MergedHintBatch::ZEROED;
            t.take_into(&mut m);
            sent.push(m);
        });
        assert_eq!(n, 300);
        assert_eq!(sent.len(), 2);
        assert!(sent.iter().all(|m| {
            m.origin_robot[..m.count as usize]
                .iter()
                .all(|r| *r == ROBOT_ID_ALL)
        }));
    }

    #[test]
    fn a_table_no_robot_reported_to_holds_nothing_and_resends_nothing() {
        let mut t = FleetTable::lazy(1 << 12, MergeRule::Min);
        assert!(t.is_empty());
        assert_eq!(t.cells(), 1 << 12);
        assert_eq!(t.resend_all(|_| panic!("nothing to send")), 0);
        // before `reserve` a hint is dropped and takes no memory
        assert!(!t.merge(0, &h(7, 1, 0.5, 1), 1));
        assert!(t.is_empty());
        t.reserve();
        assert!(!t.merge(0, &h(1 << 12, 0, 0.5, 1), 1), "off the table");
        t.merge(0, &h(7, 1, 0.5, 1), 1);
        assert_eq!((t.get(7, 1), t.get(7, 0)), (Some(0.5), None));
    }

    #[test]
    fn a_dropped_pending_batch_is_not_sent_but_its_values_stay_and_are_resent() {
        let mut t = FleetTable::new(300, MergeRule::Min);
        for cell in 0..300 {
            if t.merge(0, &h(cell, 0, 0.5, 1), 1) {
                t.drop_pending();
            }
        }
        assert_eq!(t.pending(), 300 - HINT_BATCH_CAP);
        t.drop_pending();
        assert_eq!(t.pending(), 0);
        assert_eq!(t.get(299, 0), Some(0.5));
        let (mut sent, mut sink) = (0, MergedHintBatch::ZEROED);
        assert_eq!(t.resend_all(|t| sent += t.take_into(&mut sink)), 300);
        assert_eq!(sent, 300);
    }
}
