//! The robot's discovery log: every pseudo target it finds, numbered and kept until the
//! coordinator acknowledges it.
//!
//! Discoveries travel on a lossless topic but a coordinator may die, restart, or miss one, so
//! delivery is made sure of here, without any IO (the caller sends what this log hands out):
//! - [`DiscoveryLog::record`] numbers a discovery `seq` 0, 1, 2, … and keeps it twice: in the
//!   full history (replayed to a restarted coordinator) and in the unacknowledged queue;
//! - [`DiscoveryLog::due`] hands out the unacknowledged ones whose last send is older than the
//!   resend interval, marking them sent;
//! - [`DiscoveryLog::on_ack`] takes the coordinator's cumulative `DiscoveryAck` ("everything up
//!   to `seq`"): it drops what is covered, ignores a stale or repeated ack, and rejects an ack
//!   for a sequence number never handed out (a broken or foreign sender);
//! - [`DiscoveryLog::replay`] puts the whole history back in the queue, due at once, after the
//!   robot re-joined a restarted coordinator that knows none of it (it drops duplicates by seq).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use bus::bus_schema::PseudoTargetDiscovery;

/// How long an unacknowledged discovery waits before it is sent again.
pub const DISCOVERY_RESEND: Duration = Duration::from_millis(100);

/// What an acknowledgement did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AckOutcome {
    /// It covered new discoveries; this many left the queue.
    Advanced(usize),
    /// It covered nothing new (older than or equal to an ack already seen).
    Stale,
    /// It acknowledged a sequence number never handed out: dropped, count it as rejected.
    Rejected,
}

/// A discovery waiting for its acknowledgement.
#[derive(Debug, Clone, Copy)]
struct Pending {
    d: PseudoTargetDiscovery,
    /// When it was last handed out for sending (`None`: never).
    last_send: Option<Instant>,
}

/// The discovery log of one robot (see the module docs).
#[derive(Debug)]
pub struct DiscoveryLog {
    robot_id: u32,
    resend: Duration,
    /// Every discovery made, by seq.
    all: Vec<PseudoTargetDiscovery>,
    /// Not yet acknowledged, in seq order.
    unacked: VecDeque<Pending>,
    acked_up_to: Option<u64>,
}

impl DiscoveryLog {
    /// An empty log for `robot_id`, re-sending after `resend` without an ack.
    pub fn new(robot_id: u32, resend: Duration) -> Self {
        DiscoveryLog {
            robot_id,
            resend,
            all: Vec::new(),
            unacked: VecDeque::new(),
            acked_up_to: None,
        }
    }

    /// Numbers a new discovery and queues it; returns it, to be sent now if the robot can.
    ///
    /// `sent_now` says whether the caller will send it right away (false while no coordinator
    /// accepted this robot): a discovery not sent now is due at the next [`due`](Self::due).
    pub fn record(
        &mut self,
        mut d: PseudoTargetDiscovery,
        now: Instant,
        sent_now: bool,
    ) -> PseudoTargetDiscovery {
        d.robot_id = self.robot_id;
        d.seq = self.all.len() as u64;
        self.all.push(d);
        self.unacked.push_back(Pending {
            d,
            last_send: sent_now.then_some(now),
        });
        d
    }

    /// Hands every unacknowledged discovery whose last send is at least the resend interval
    /// old (or that was never sent) to `send`, and marks it sent at `now`; returns how many.
    pub fn due(&mut self, now: Instant, mut send: impl FnMut(&PseudoTargetDiscovery)) -> usize {
        let mut n = 0;
        for p in &mut self.unacked {
            if p.last_send
                .is_some_and(|t| now.saturating_duration_since(t) < self.resend)
            {
                continue;
            }
            p.last_send = Some(now);
            send(&p.d);
            n += 1;
        }
        n
    }

    /// Takes the coordinator's cumulative acknowledgement of everything up to `up_to_seq`.
    pub fn on_ack(&mut self, up_to_seq: u64) -> AckOutcome {
        if up_to_seq >= self.all.len() as u64 {
            return AckOutcome::Rejected;
        }
        if self.acked_up_to.is_some_and(|a| up_to_seq <= a) {
            return AckOutcome::Stale;
        }
        self.acked_up_to = Some(up_to_seq);
        let before = self.unacked.len();
        while self.unacked.front().is_some_and(|p| p.d.seq <= up_to_seq) {
            self.unacked.pop_front();
        }
        AckOutcome::Advanced(before - self.unacked.len())
    }

    /// After re-joining a restarted coordinator: everything ever found is unacknowledged again
    /// and due at once.
    pub fn replay(&mut self) {
        self.acked_up_to = None;
        self.unacked = self
            .all
            .iter()
            .map(|&d| Pending { d, last_send: None })
            .collect();
    }

    /// Discoveries made so far (the next seq).
    pub fn made(&self) -> u64 {
        self.all.len() as u64
    }

    /// Discoveries the coordinator has acknowledged (0 before the first ack).
    pub fn acked(&self) -> u64 {
        self.acked_up_to.map_or(0, |a| a + 1)
    }

    /// Discoveries still waiting for their acknowledgement.
    pub fn unacked(&self) -> usize {
        self.unacked.len()
    }

    /// Whether every discovery is acknowledged.
    pub fn settled(&self) -> bool {
        self.unacked.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn found(x: u16) -> PseudoTargetDiscovery {
        PseudoTargetDiscovery {
            cell_x: x,
            value: 0.5,
            ..PseudoTargetDiscovery::ZEROED
        }
    }

    fn log() -> (DiscoveryLog, Instant) {
        (
            DiscoveryLog::new(7, Duration::from_millis(100)),
            Instant::now(),
        )
    }

    fn due_seqs(l: &mut DiscoveryLog, at: Instant) -> Vec<u64> {
        let mut v = Vec::new();
        l.due(at, |d| v.push(d.seq));
        v
    }

    #[test]
    fn discoveries_are_numbered_from_zero_and_carry_the_robot_id() {
        let (mut l, t) = log();
        let a = l.record(found(1), t, true);
        let b = l.record(found(2), t, true);
        assert_eq!((a.seq, b.seq), (0, 1));
        assert_eq!((a.robot_id, b.robot_id, b.cell_x), (7, 7, 2));
        assert_eq!((l.made(), l.unacked(), l.acked()), (2, 2, 0));
    }

    #[test]
    fn an_unacknowledged_discovery_is_resent_after_the_interval_and_not_before() {
        let (mut l, t) = log();
        l.record(found(1), t, true);
        assert!(due_seqs(&mut l, t + Duration::from_millis(99)).is_empty());
        assert_eq!(due_seqs(&mut l, t + Duration::from_millis(100)), [0]);
        // just resent: the interval starts again
        assert!(due_seqs(&mut l, t + Duration::from_millis(150)).is_empty());
        assert_eq!(due_seqs(&mut l, t + Duration::from_millis(200)), [0]);
    }

    #[test]
    fn a_discovery_not_sent_when_made_is_due_at_once() {
        let (mut l, t) = log();
        l.record(found(1), t, false);
        assert_eq!(due_seqs(&mut l, t), [0]);
    }

    #[test]
    fn a_cumulative_ack_drops_everything_it_covers() {
        let (mut l, t) = log();
        for x in 0..4 {
            l.record(found(x), t, true);
        }
        assert_eq!(l.on_ack(1), AckOutcome::Advanced(2));
        assert_eq!((l.unacked(), l.acked()), (2, 2));
        assert_eq!(due_seqs(&mut l, t + DISCOVERY_RESEND), [2, 3]);
        assert_eq!(l.on_ack(3), AckOutcome::Advanced(2));
        assert!(l.settled());
    }

    #[test]
    fn a_stale_or_repeated_ack_changes_nothing() {
        let (mut l, t) = log();
        for x in 0..3 {
            l.record(found(x), t, true);
        }
        assert_eq!(l.on_ack(1), AckOutcome::Advanced(2));
        assert_eq!(l.on_ack(1), AckOutcome::Stale);
        assert_eq!(l.on_ack(0), AckOutcome::Stale);
        assert_eq!((l.unacked(), l.acked()), (1, 2));
    }

    #[test]
    fn an_ack_for_a_seq_never_sent_is_rejected_and_changes_nothing() {
        let (mut l, t) = log();
        assert_eq!(l.on_ack(0), AckOutcome::Rejected);
        l.record(found(1), t, true);
        assert_eq!(l.on_ack(1), AckOutcome::Rejected);
        assert_eq!(l.on_ack(u64::MAX), AckOutcome::Rejected);
        assert_eq!((l.unacked(), l.acked()), (1, 0));
    }

    #[test]
    fn a_replay_after_a_coordinator_restart_resends_the_whole_history_at_once() {
        let (mut l, t) = log();
        for x in 0..3 {
            l.record(found(x), t, true);
        }
        assert_eq!(l.on_ack(2), AckOutcome::Advanced(3));
        l.replay();
        assert_eq!((l.unacked(), l.acked()), (3, 0));
        assert_eq!(due_seqs(&mut l, t), [0, 1, 2]);
        // the new coordinator's first ack counts from scratch
        assert_eq!(l.on_ack(0), AckOutcome::Advanced(1));
    }
}
