//! Pseudo-target discoveries at the coordinator: per-robot ordering and dedup by sequence
//! number, cumulative acks, and the relay of each distinct (goal, cell) once to the fleet.
//!
//! Robots publish discoveries losslessly with a per-process sequence number and resend what is
//! not acked; the coordinator acks the highest sequence number below which it has everything
//! (`up_to_seq`), so a resend of an acked discovery is a duplicate, counted and dropped. One
//! dedup key for relays in runs and experiments alike: (goal id, row-major cell index).

use std::collections::BTreeSet;

use bus::bus_schema::{DiscoveryRelay, PseudoTargetDiscovery};

/// One robot process's discovery stream.
#[derive(Debug, Clone, Default)]
struct Stream {
    /// Every sequence number below this one was received.
    next: u64,
    /// Received sequence numbers above a gap.
    ahead: BTreeSet<u64>,
    /// Distinct discoveries received from this process.
    received: u64,
    /// An ack is due (something arrived since the last one).
    ack_due: bool,
}

/// What one discovery was.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Seen {
    /// New; `relayed` if its (goal, cell) was new to the fleet and a relay is queued.
    New {
        /// Whether a relay was queued.
        relayed: bool,
    },
    /// Already received (a resend): counted and dropped, but acked again.
    Duplicate,
}

/// The coordinator's discovery bookkeeping for the whole fleet.
#[derive(Debug, Clone)]
pub struct Discoveries {
    streams: Vec<Stream>,
    relayed: BTreeSet<(u32, u32)>,
    pending: Vec<DiscoveryRelay>,
    duplicates: u64,
    from_dead: u64,
}

impl Discoveries {
    /// Bookkeeping for robot ids `0..robots`.
    pub fn new(robots: u32) -> Self {
        Discoveries {
            streams: vec![Stream::default(); robots as usize],
            relayed: BTreeSet::new(),
            pending: Vec::new(),
            duplicates: 0,
            from_dead: 0,
        }
    }

    /// Takes one validated discovery whose cell has row-major index `cell` (see
    /// [`validate::discovery`](crate::validate::discovery)). Robot ids outside the fleet are
    /// the caller's to reject; here they are ignored as duplicates.
    pub fn on(&mut self, d: &PseudoTargetDiscovery, cell: u32) -> Seen {
        let Some(s) = self.streams.get_mut(d.robot_id as usize) else {
            return Seen::Duplicate;
        };
        s.ack_due = true;
        if d.seq < s.next || !s.ahead.insert(d.seq) {
            self.duplicates += 1;
            return Seen::Duplicate;
        }
        while s.ahead.remove(&s.next) {
            s.next += 1;
        }
        s.received += 1;
        let relayed = self.relayed.insert((d.goal_id, cell));
        if relayed {
            self.pending.push(DiscoveryRelay {
                origin_robot: d.robot_id,
                goal_id: d.goal_id,
                cell_x: d.cell_x,
                cell_y: d.cell_y,
                value: d.value,
                origin_seq: d.seq,
                origin_ns: d.time_ns,
                ..DiscoveryRelay::ZEROED
            });
        }
        Seen::New { relayed }
    }

    /// The acks due, as (robot id, `up_to_seq`), each once; a robot whose first discovery is
    /// still missing gets none (there is nothing contiguous to ack).
    pub fn take_acks(&mut self) -> impl Iterator<Item = (u32, u64)> + '_ {
        self.streams.iter_mut().enumerate().filter_map(|(id, s)| {
            (std::mem::take(&mut s.ack_due) && s.next > 0).then(|| (id as u32, s.next - 1))
        })
    }

    /// The relays queued since the last call, in the order their discoveries arrived.
    pub fn take_relays(&mut self) -> Vec<DiscoveryRelay> {
        std::mem::take(&mut self.pending)
    }

    /// A new process took `robot_id`'s place: it numbers from 0 again. What the dead one sent
    /// is moved to [`from_dead`](Self::from_dead) (it reports only its own).
    pub fn restarted(&mut self, robot_id: u32) {
        if let Some(s) = self.streams.get_mut(robot_id as usize) {
            self.from_dead += s.received;
            *s = Stream::default();
        }
    }

    /// The distinct (goal id, cell index) pairs relayed so far (for a checkpoint).
    pub fn relayed_pairs(&self) -> Vec<(u32, u32)> {
        self.relayed.iter().copied().collect()
    }

    /// Takes over from a coordinator that died: its duplicate and dead-process counts, and
    /// the pairs it relayed (not relayed again when the robots replay their discoveries).
    /// The streams start empty: every live robot replays its whole log to the new coordinator.
    pub fn resume(&mut self, duplicates: u64, from_dead: u64, relayed: &[(u32, u32)]) {
        self.duplicates = duplicates;
        self.from_dead = from_dead;
        self.relayed.extend(relayed.iter().copied());
    }

    /// Distinct discoveries received from the current processes.
    pub fn received(&self) -> u64 {
        self.streams.iter().map(|s| s.received).sum()
    }

    /// Distinct discoveries received from `robot_id`'s current process.
    pub fn received_from(&self, robot_id: u32) -> u64 {
        self.streams
            .get(robot_id as usize)
            .map_or(0, |s| s.received)
    }

    /// Resends dropped as duplicates.
    pub fn duplicates(&self) -> u64 {
        self.duplicates
    }

    /// Discoveries received from processes that died and were replaced.
    pub fn from_dead(&self) -> u64 {
        self.from_dead
    }

    /// Distinct (goal, cell) pairs relayed.
    pub fn relayed(&self) -> usize {
        self.relayed.len()
    }

    /// Distinct cells relayed for `goal`.
    pub fn relayed_for(&self, goal: u32) -> usize {
        self.relayed.range((goal, 0)..=(goal, u32::MAX)).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disc(robot_id: u32, seq: u64, goal_id: u32, x: u16) -> PseudoTargetDiscovery {
        PseudoTargetDiscovery {
            robot_id,
            goal_id,
            seq,
            cell_x: x,
            value: 0.5,
            ..PseudoTargetDiscovery::ZEROED
        }
    }

    #[test]
    fn in_order_discoveries_are_new_and_acked_cumulatively() {
        let mut d = Discoveries::new(2);
        assert_eq!(d.on(&disc(0, 0, 0, 1), 1), Seen::New { relayed: true });
        assert_eq!(d.on(&disc(0, 1, 0, 2), 2), Seen::New { relayed: true });
        assert_eq!(d.take_acks().collect::<Vec<_>>(), vec![(0, 1)]);
        assert_eq!(d.take_acks().count(), 0, "an ack goes out once");
        assert_eq!(d.received(), 2);
    }

    #[test]
    fn a_gap_holds_the_ack_back_until_it_is_filled() {
        let mut d = Discoveries::new(1);
        d.on(&disc(0, 1, 0, 1), 1);
        assert_eq!(d.take_acks().count(), 0, "seq 0 is missing");
        d.on(&disc(0, 0, 0, 2), 2);
        assert_eq!(d.take_acks().collect::<Vec<_>>(), vec![(0, 1)]);
        assert_eq!(d.received(), 2);
    }

    #[test]
    fn resends_are_duplicates_but_acked_again() {
        let mut d = Discoveries::new(1);
        d.on(&disc(0, 0, 0, 1), 1);
        d.take_acks().count();
        assert_eq!(d.on(&disc(0, 0, 0, 1), 1), Seen::Duplicate);
        d.on(&disc(0, 2, 0, 3), 3);
        assert_eq!(
            d.on(&disc(0, 2, 0, 3), 3),
            Seen::Duplicate,
            "above a gap too"
        );
        assert_eq!(d.duplicates(), 2);
        assert_eq!(d.take_acks().collect::<Vec<_>>(), vec![(0, 0)]);
    }

    #[test]
    fn each_goal_and_cell_is_relayed_once_across_robots() {
        let mut d = Discoveries::new(2);
        d.on(&disc(0, 0, 0, 1), 1);
        assert_eq!(d.on(&disc(1, 0, 0, 1), 1), Seen::New { relayed: false });
        assert_eq!(d.on(&disc(1, 1, 1, 1), 1), Seen::New { relayed: true });
        let relays = d.take_relays();
        assert_eq!(relays.len(), 2);
        assert_eq!((relays[0].origin_robot, relays[0].goal_id), (0, 0));
        assert_eq!((relays[1].origin_robot, relays[1].goal_id), (1, 1));
        assert!(d.take_relays().is_empty());
        assert_eq!((d.relayed_for(0), d.relayed_for(1), d.relayed()), (1, 1, 2));
    }

    #[test]
    fn a_restarted_process_numbers_from_zero_and_the_dead_ones_count_moves() {
        let mut d = Discoveries::new(1);
        d.on(&disc(0, 0, 0, 1), 1);
        d.on(&disc(0, 1, 0, 2), 2);
        d.restarted(0);
        assert_eq!((d.received(), d.from_dead()), (0, 2));
        assert_eq!(d.on(&disc(0, 0, 0, 5), 5), Seen::New { relayed: true });
        assert_eq!(d.received_from(0), 1);
    }

    #[test]
    fn a_resumed_coordinator_counts_replays_as_new_but_does_not_relay_them_again() {
        let mut before = Discoveries::new(2);
        before.on(&disc(0, 0, 0, 1), 1);
        before.on(&disc(0, 0, 0, 1), 1);
        before.on(&disc(1, 0, 0, 4), 4);
        before.take_relays();
        let mut after = Discoveries::new(2);
        after.resume(
            before.duplicates(),
            before.from_dead(),
            &before.relayed_pairs(),
        );
        // robot 0 re-joined and replays its log from seq 0; then finds one more
        assert_eq!(after.on(&disc(0, 0, 0, 1), 1), Seen::New { relayed: false });
        assert_eq!(after.on(&disc(0, 1, 0, 9), 9), Seen::New { relayed: true });
        assert_eq!(after.received(), 2);
        assert_eq!(
            after.duplicates(),
            1,
            "the dead coordinator's count is kept"
        );
        assert_eq!(after.relayed(), 3);
        assert_eq!(after.take_relays().len(), 1);
        assert_eq!(after.take_acks().collect::<Vec<_>>(), vec![(0, 1)]);
    }

    #[test]
    fn robot_ids_outside_the_fleet_change_nothing() {
        let mut d = Discoveries::new(1);
        assert_eq!(d.on(&disc(7, 0, 0, 1), 1), Seen::Duplicate);
        assert_eq!(d.received(), 0);
        assert!(d.take_relays().is_empty());
    }
}
