//! Is the other host there, and what time is it over there: link state from heartbeat silence,
//! and the clock offset from heartbeat round trips. No IO.
//!
//! Monotonic clocks of two hosts share no origin, so a time stamped on one host means nothing on
//! the other. Every heartbeat carries the sender's clock and echoes the last heartbeat it got
//! (with how long it held it), which gives a round trip `rtt` and, assuming the two directions
//! take equally long, the offset `peer − local = t_peer − (t_arrival − rtt/2)`. The estimate
//! from the fastest round trip seen so far is kept (its error is at most half that round trip),
//! the way NTP filters its samples. Each host moves the times in the messages it receives onto
//! its own clock with it ([`crate::wire::Stamped`]).

use std::time::{Duration, Instant};

/// State of the link to one host.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LinkState {
    /// No heartbeat heard yet.
    Joining,
    /// Heartbeats arrive.
    Up,
    /// Silent for longer than the down threshold: frames are kept for resending.
    Down,
    /// Silent past the deadline: given up on for the rest of the run.
    Lost,
}

/// What changed with a tick or a heartbeat.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkEvent {
    /// First heartbeat.
    Joined,
    /// Went silent.
    WentDown,
    /// Heard again after being down: a reconnect.
    CameBack,
    /// Silent past the deadline.
    Lost,
}

/// Link state from heartbeat silence.
#[derive(Debug, Clone)]
pub struct LinkWatch {
    state: LinkState,
    last_heard: Instant,
    down_after: Duration,
    deadline: Duration,
    down_since: Option<Instant>,
    /// Times the link came back after being down.
    pub reconnects: u64,
    /// Total time spent down.
    pub down_for: Duration,
}

impl LinkWatch {
    /// A link that counts as down after `down_after` of silence and as lost after `deadline`.
    pub fn new(now: Instant, down_after: Duration, deadline: Duration) -> Self {
        LinkWatch {
            state: LinkState::Joining,
            last_heard: now,
            down_after,
            deadline: deadline.max(down_after),
            down_since: None,
            reconnects: 0,
            down_for: Duration::ZERO,
        }
    }

    /// Current state.
    pub fn state(&self) -> LinkState {
        self.state
    }

    /// A heartbeat (or any frame) arrived.
    pub fn heard(&mut self, now: Instant) -> Option<LinkEvent> {
        self.last_heard = now;
        match self.state {
            LinkState::Joining => {
                self.state = LinkState::Up;
                Some(LinkEvent::Joined)
            }
            LinkState::Down => {
                self.state = LinkState::Up;
                self.reconnects += 1;
                if let Some(t) = self.down_since.take() {
                    self.down_for += now.duration_since(t);
                }
                Some(LinkEvent::CameBack)
            }
            LinkState::Up | LinkState::Lost => None,
        }
    }

    /// Looks at the silence; call it every loop turn.
    pub fn tick(&mut self, now: Instant) -> Option<LinkEvent> {
        let silent = now.saturating_duration_since(self.last_heard);
        match self.state {
            LinkState::Up if silent >= self.down_after => {
                self.state = LinkState::Down;
                self.down_since = Some(self.last_heard);
                Some(LinkEvent::WentDown)
            }
            LinkState::Down if silent >= self.deadline => {
                self.state = LinkState::Lost;
                if let Some(t) = self.down_since.take() {
                    self.down_for += now.duration_since(t);
                }
                Some(LinkEvent::Lost)
            }
            _ => None,
        }
    }
}

/// The peer's clock relative to ours, from heartbeat round trips.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ClockSync {
    best_rtt_ns: Option<u64>,
    offset_ns: i64,
}

impl ClockSync {
    /// One round trip: the peer stamped `peer_t_ns` when it sent the heartbeat that arrived at
    /// `local_now_ns`, echoing our `echo_ns` after holding it `hold_ns`. Returns the round trip
    /// (None if the echo is missing or inconsistent).
    pub fn sample(
        &mut self,
        peer_t_ns: u64,
        echo_ns: u64,
        hold_ns: u64,
        local_now_ns: u64,
    ) -> Option<u64> {
        if echo_ns == 0 || echo_ns > local_now_ns {
            return None;
        }
        let rtt = (local_now_ns - echo_ns).checked_sub(hold_ns)?;
        if self.best_rtt_ns.is_none_or(|b| rtt <= b) {
            self.best_rtt_ns = Some(rtt);
            let local_at_send = i128::from(local_now_ns) - i128::from(rtt / 2);
            self.offset_ns = (i128::from(peer_t_ns) - local_at_send) as i64;
        }
        Some(rtt)
    }

    /// Seeds the estimate from one request/reply exchange: we sent at `sent_ns`, the peer
    /// stamped `peer_t_ns`, we got the reply at `got_ns` (used until heartbeats refine it).
    pub fn seed(&mut self, sent_ns: u64, peer_t_ns: u64, got_ns: u64) {
        if got_ns < sent_ns {
            return;
        }
        let rtt = got_ns - sent_ns;
        if self.best_rtt_ns.is_none_or(|b| rtt <= b) {
            self.best_rtt_ns = Some(rtt);
            let mid = i128::from(sent_ns) + i128::from(rtt / 2);
            self.offset_ns = (i128::from(peer_t_ns) - mid) as i64;
        }
    }

    /// Estimated `peer clock − local clock`, ns (0 before any sample).
    pub fn offset_ns(&self) -> i64 {
        self.offset_ns
    }

    /// Fastest round trip seen; the offset's error is at most half of it.
    pub fn best_rtt_ns(&self) -> Option<u64> {
        self.best_rtt_ns
    }

    /// What to add to a peer's time to get our time.
    pub fn to_local(&self) -> i64 {
        self.offset_ns.wrapping_neg()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn silence_takes_the_link_down_then_lost_and_a_heartbeat_brings_it_back() {
        let t0 = Instant::now();
        let mut w = LinkWatch::new(t0, 500 * MS, 5000 * MS);
        assert_eq!(
            w.tick(t0 + 10_000 * MS),
            None,
            "not joined: no deadline yet"
        );
        assert_eq!(w.heard(t0), Some(LinkEvent::Joined));
        assert_eq!(w.tick(t0 + 400 * MS), None);
        assert_eq!(w.tick(t0 + 600 * MS), Some(LinkEvent::WentDown));
        assert_eq!(w.tick(t0 + 700 * MS), None);
        assert_eq!(w.heard(t0 + 2000 * MS), Some(LinkEvent::CameBack));
        assert_eq!(w.reconnects, 1);
        assert_eq!(w.down_for, 2000 * MS);
        assert_eq!(w.tick(t0 + 2600 * MS), Some(LinkEvent::WentDown));
        assert_eq!(w.tick(t0 + 7100 * MS), Some(LinkEvent::Lost));
        assert_eq!(w.state(), LinkState::Lost);
        assert_eq!(w.heard(t0 + 8000 * MS), None, "lost is final");
    }

    #[test]
    fn the_offset_comes_from_the_fastest_round_trip() {
        // the peer's clock is 1_000_000 ns ahead; one way takes 50 ns, then once 500 ns
        let mut c = ClockSync::default();
        // we sent at 1000 (our clock); peer got it at 1050 ours = 1_001_050 theirs, held 100,
        // sent back at 1_001_150 theirs = 1150 ours, arriving at 1200
        assert_eq!(c.sample(1_001_150, 1000, 100, 1200), Some(100));
        assert_eq!(c.offset_ns(), 1_000_000);
        // a slow, asymmetric round trip does not replace the better estimate
        assert_eq!(c.sample(2_001_150, 2000, 100, 2700), Some(600));
        assert_eq!(c.offset_ns(), 1_000_000);
        assert_eq!(c.to_local(), -1_000_000);
        assert_eq!(c.best_rtt_ns(), Some(100));
    }

    #[test]
    fn missing_or_impossible_echoes_are_ignored() {
        let mut c = ClockSync::default();
        assert_eq!(c.sample(5, 0, 0, 100), None);
        assert_eq!(c.sample(5, 200, 0, 100), None);
        assert_eq!(c.sample(5, 50, 80, 100), None);
        assert_eq!(c.best_rtt_ns(), None);
    }

    #[test]
    fn a_request_reply_seeds_the_offset() {
        let mut c = ClockSync::default();
        c.seed(1000, 5_000_500, 2000);
        assert_eq!(c.offset_ns(), 5_000_500 - 1500);
    }
}
