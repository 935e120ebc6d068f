//! Lossless across the link: number every lossless frame, keep it until the peer acknowledges
//! it, and send everything unacknowledged again when the acknowledgement does not come.
//!
//! Zenoh over TCP is reliable while a session lasts, but a frame published while the link is
//! down (or while a session is being re-established) is gone. So the bridge runs its own
//! go-back-N over Zenoh: the sender ([`Outgoing`]) numbers frames 0, 1, 2, …, the receiver
//! ([`Incoming`]) takes only the next number it expects (a gap means "lost on the way": it waits
//! for the resend) and reports in every heartbeat how many it has in order; the sender drops
//! those and, when the oldest kept frame has waited [`RESEND_AFTER`] or the link came back, sends
//! all kept frames again. Duplicates are harmless: the receiver skips numbers it already has.
//! No IO here: the bridge loops feed these types and publish what they return.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// How long an unacknowledged frame waits before the whole window is resent (heartbeats, which
/// carry the acks, go every [`crate::HEARTBEAT_EVERY`]).
pub const RESEND_AFTER: Duration = Duration::from_millis(300);

/// Most frames kept unacknowledged; beyond it the sender reports the link as overflowing instead
/// of growing without bound (a peer that never acks is lost long before this).
pub const MAX_KEPT: usize = 1 << 20;

/// Most buffers of acknowledged frames kept for reuse.
const MAX_SPARE: usize = 1024;

/// The sending half of one lossless stream.
#[derive(Debug, Default)]
pub struct Outgoing {
    next: u64,
    kept: VecDeque<(u64, Vec<u8>)>,
    /// Buffers of acknowledged frames, reused by [`Outgoing::push_with`].
    spare: Vec<Vec<u8>>,
    last_send: Option<Instant>,
    /// Frames sent again (each resend of each frame counts).
    pub resent: u64,
}

/// The buffer of unacknowledged frames is full: the peer has not acknowledged anything for a
/// very long time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("{0} lossless frames unacknowledged by the other host")]
pub struct Overflow(pub usize);

impl Outgoing {
    /// The seq the next frame gets (also: how many were numbered so far).
    pub fn next_seq(&self) -> u64 {
        self.next
    }

    /// Frames kept until acknowledged.
    pub fn unacked(&self) -> usize {
        self.kept.len()
    }

    /// Numbers a frame: `build(seq)` makes it; it is kept and returned for sending now.
    pub fn push(
        &mut self,
        now: Instant,
        build: impl FnOnce(u64) -> Vec<u8>,
    ) -> Result<&[u8], Overflow> {
        if self.kept.len() >= MAX_KEPT {
            return Err(Overflow(self.kept.len()));
        }
        let seq = self.next;
        self.next += 1;
        if self.kept.is_empty() {
            self.last_send = Some(now);
        }
        self.kept.push_back((seq, build(seq)));
        Ok(self.kept.back().map_or(&[][..], |(_, f)| f.as_slice()))
    }

    /// Numbers a frame written by `fill(seq, buf)` into a reused buffer (cleared; one of an
    /// acknowledged frame when there is one, so a steady stream allocates nothing); it is kept
    /// and returned for sending now.
    pub fn push_with(
        &mut self,
        now: Instant,
        fill: impl FnOnce(u64, &mut Vec<u8>),
    ) -> Result<&[u8], Overflow> {
        let mut buf = self.spare.pop().unwrap_or_default();
        buf.clear();
        self.push(now, |seq| {
            fill(seq, &mut buf);
            buf
        })
    }

    /// The peer has every frame with seq `< acked`: forget them. An ack of frames never sent
    /// (`acked` past [`Outgoing::next_seq`]) is a forgery or garbage: ignored, false.
    pub fn ack(&mut self, acked: u64, now: Instant) -> bool {
        if acked > self.next {
            return false;
        }
        let before = self.kept.len();
        while self.kept.front().is_some_and(|(s, _)| *s < acked) {
            if let Some((_, f)) = self.kept.pop_front()
                && self.spare.len() < MAX_SPARE
            {
                self.spare.push(f);
            }
        }
        if self.kept.len() != before {
            // progress: the remaining frames get a fresh wait
            self.last_send = Some(now);
        }
        true
    }

    /// Frames to send again now: all kept ones when the oldest has waited [`RESEND_AFTER`]
    /// since the last (re)send or ack progress, or when `force` (the link just came back).
    pub fn due(&mut self, now: Instant, force: bool) -> impl Iterator<Item = &[u8]> {
        let waited = self
            .last_send
            .is_some_and(|t| now.duration_since(t) >= RESEND_AFTER);
        let go = !self.kept.is_empty() && (force || waited);
        if go {
            self.last_send = Some(now);
            self.resent += self.kept.len() as u64;
        }
        self.kept
            .iter()
            .filter(move |_| go)
            .map(|(_, f)| f.as_slice())
    }
}

/// What the receiver makes of a lossless frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Arrival {
    /// The next one: deliver it.
    Next,
    /// Already had it (a resend): skip.
    Duplicate,
    /// A frame before it was lost: skip, the sender resends from the gap.
    Gap,
}

/// The receiving half of one lossless stream.
#[derive(Debug, Default)]
pub struct Incoming {
    expected: u64,
    /// Resent frames skipped.
    pub duplicates: u64,
    /// Frames skipped because an earlier one was missing.
    pub gaps: u64,
}

impl Incoming {
    /// Frames received in order so far (what the heartbeat acknowledges).
    pub fn acked(&self) -> u64 {
        self.expected
    }

    /// Classifies the frame numbered `seq`; `Next` advances the stream.
    pub fn arrive(&mut self, seq: u64) -> Arrival {
        if seq == self.expected {
            self.expected += 1;
            Arrival::Next
        } else if seq < self.expected {
            self.duplicates += 1;
            Arrival::Duplicate
        } else {
            self.gaps += 1;
            Arrival::Gap
        }
    }
}

/// Most lossless frames one peer may have waiting in a [`Pending`] queue: past it a frame is
/// not taken (not acknowledged either), so the peer sends it again later; nothing is lost and
/// a peer cannot grow this host's memory by sending faster than the bus takes.
pub const MAX_PENDING: usize = 1 << 16;

/// Lossless frames received in order and not yet written into this host's bus (both bridge
/// ends keep one): a full inbox here delays them, never reorders or drops them.
#[derive(Debug, Default)]
pub struct Pending {
    queue: VecDeque<Vec<u8>>,
    /// Buffers of delivered frames, reused by [`Pending::push`].
    spare: Vec<Vec<u8>>,
}

impl Pending {
    /// Whether [`MAX_PENDING`] frames are waiting (take no more: see [`MAX_PENDING`]).
    pub fn is_full(&self) -> bool {
        self.queue.len() >= MAX_PENDING
    }

    /// Keeps a copy of `frame` behind the ones before it (in a reused buffer once warm).
    pub fn push(&mut self, frame: &[u8]) {
        let mut buf = self.spare.pop().unwrap_or_default();
        buf.clear();
        buf.extend_from_slice(frame);
        self.queue.push_back(buf);
    }

    /// Hands the frames to `put` in order until it says "not now" (`false`: that frame stays
    /// first, for the next call); true when any frame was handed on.
    pub fn deliver(&mut self, mut put: impl FnMut(&[u8]) -> bool) -> bool {
        let mut any = false;
        while let Some(frame) = self.queue.pop_front() {
            if !put(&frame) {
                self.queue.push_front(frame);
                break;
            }
            any = true;
            if self.spare.len() < MAX_SPARE {
                self.spare.push(frame);
            }
        }
        any
    }

    /// Frames waiting.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// Whether no frame waits.
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pending_frames_go_out_in_order_and_a_full_inbox_only_delays_them() {
        let mut p = Pending::default();
        for seq in 0..5u64 {
            p.push(&frame(seq));
        }
        // the inbox takes two, then is full: the third stays first
        let mut got = Vec::new();
        let mut room = 2;
        assert!(p.deliver(|f| {
            if room == 0 {
                return false;
            }
            room -= 1;
            got.push(seq_of(f));
            true
        }));
        assert_eq!(got, [0, 1]);
        assert_eq!(p.len(), 3);
        // still full: nothing moves, nothing is lost
        assert!(!p.deliver(|_| false));
        assert_eq!(p.len(), 3);
        // room again: the rest, in order, and frames pushed meanwhile after them
        p.push(&frame(5));
        assert!(p.deliver(|f| {
            got.push(seq_of(f));
            true
        }));
        assert_eq!(got, [0, 1, 2, 3, 4, 5]);
        assert!(p.is_empty());
        // delivered buffers are reused, not reallocated
        let spare = p.spare.len();
        p.push(&frame(6));
        assert_eq!(p.spare.len(), spare - 1);
    }

    fn frame(seq: u64) -> Vec<u8> {
        seq.to_le_bytes().to_vec()
    }

    fn seq_of(f: &[u8]) -> u64 {
        u64::from_le_bytes(f.try_into().unwrap())
    }

    /// A link that drops frames while "down" delivers every frame exactly once, in order,
    /// after it comes back: the promise the bridge makes for lossless topics.
    #[test]
    fn frames_lost_while_the_link_is_down_arrive_once_in_order_after_it_is_back() {
        let t0 = Instant::now();
        let mut out = Outgoing::default();
        let mut inc = Incoming::default();
        let mut delivered = Vec::new();
        let wire = |f: &[u8], up: bool, inc: &mut Incoming, got: &mut Vec<u64>| {
            if up && inc.arrive(seq_of(f)) == Arrival::Next {
                got.push(seq_of(f));
            }
        };
        for i in 0..10u64 {
            let up = !(3..7).contains(&i); // frames 3..7 are published into a dead link
            let f = out.push(t0, frame).unwrap().to_vec();
            wire(&f, up, &mut inc, &mut delivered);
        }
        assert_eq!(delivered, vec![0, 1, 2], "7..10 follow a gap and wait");
        out.ack(inc.acked(), t0);
        assert_eq!(out.unacked(), 7);
        // nothing is due before the resend time …
        assert_eq!(out.due(t0 + Duration::from_millis(10), false).count(), 0);
        // … then everything kept goes again
        let again: Vec<Vec<u8>> = out
            .due(t0 + RESEND_AFTER, false)
            .map(<[u8]>::to_vec)
            .collect();
        for f in &again {
            wire(f, true, &mut inc, &mut delivered);
        }
        assert_eq!(delivered, (0..10).collect::<Vec<_>>());
        out.ack(inc.acked(), t0 + RESEND_AFTER);
        assert_eq!(out.unacked(), 0);
        assert_eq!(out.resent, 7);
        assert_eq!(inc.gaps, 3);
    }

    #[test]
    fn acknowledged_frames_lend_their_buffers_to_the_next_ones() {
        let t0 = Instant::now();
        let mut out = Outgoing::default();
        let first = out
            .push_with(t0, |seq, b| b.extend_from_slice(&seq.to_le_bytes()))
            .unwrap()
            .as_ptr();
        out.ack(1, t0);
        let next = out
            .push_with(t0, |seq, b| {
                assert!(b.is_empty(), "a reused buffer starts empty");
                b.extend_from_slice(&seq.to_le_bytes());
            })
            .unwrap();
        assert_eq!(seq_of(next), 1);
        assert_eq!(
            next.as_ptr(),
            first,
            "the acknowledged frame's buffer was not reused"
        );
    }

    #[test]
    fn a_resend_of_what_arrived_is_skipped_as_duplicate() {
        let mut inc = Incoming::default();
        assert_eq!(inc.arrive(0), Arrival::Next);
        assert_eq!(inc.arrive(0), Arrival::Duplicate);
        assert_eq!(inc.arrive(2), Arrival::Gap);
        assert_eq!(inc.arrive(1), Arrival::Next);
        assert_eq!(inc.acked(), 2);
    }

    #[test]
    fn a_link_that_comes_back_resends_at_once() {
        let t0 = Instant::now();
        let mut out = Outgoing::default();
        out.push(t0, frame).unwrap();
        assert_eq!(out.due(t0, false).count(), 0);
        assert_eq!(out.due(t0, true).count(), 1);
        // an empty window never resends
        out.ack(1, t0);
        assert_eq!(out.due(t0 + RESEND_AFTER * 3, true).count(), 0);
    }

    #[test]
    fn ack_progress_restarts_the_wait() {
        let t0 = Instant::now();
        let mut out = Outgoing::default();
        out.push(t0, frame).unwrap();
        out.push(t0, frame).unwrap();
        out.ack(1, t0 + RESEND_AFTER);
        assert_eq!(out.due(t0 + RESEND_AFTER, false).count(), 0);
        assert_eq!(out.due(t0 + RESEND_AFTER * 2, false).count(), 1);
    }

    #[test]
    fn an_ack_of_frames_never_sent_is_ignored_and_nothing_is_discarded() {
        let t0 = Instant::now();
        let mut out = Outgoing::default();
        for _ in 0..3 {
            out.push(t0, frame).unwrap();
        }
        // a stranger's heartbeat claiming everything up to 1000 arrived
        assert!(!out.ack(1000, t0));
        assert_eq!(
            out.unacked(),
            3,
            "the frames the peer never got are still kept"
        );
        assert!(out.ack(2, t0));
        assert_eq!(out.unacked(), 1);
    }

    #[test]
    fn a_full_pending_queue_says_so_instead_of_growing() {
        let mut p = Pending::default();
        for seq in 0..MAX_PENDING as u64 {
            assert!(!p.is_full());
            p.push(&frame(seq));
        }
        assert!(p.is_full());
        assert_eq!(p.len(), MAX_PENDING);
        // the receiver then leaves the frame unacknowledged (see MAX_PENDING): once the bus
        // takes frames again there is room
        p.deliver(|_| true);
        assert!(!p.is_full());
    }
}
