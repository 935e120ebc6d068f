//! One end of a link: what the hub keeps once per joined host and a joining host keeps once —
//! frame handling, sealing, in-order delivery of lossless frames, heartbeats, resends, the
//! link's state and its figures. No IO: frames come in as bytes, go out through a [`Sink`];
//! messages reach the host's bus through the caller's callback, which says what became of each
//! ([`Put`]), and what else a frame means is handed back ([`Got`]).
//!
//! A frame is first opened with the peer's key ([`crate::seal`]; with `--insecure-plain` links,
//! taken as it is). Only a frame that opens counts: it keeps the link up, its heartbeat's
//! acknowledgement moves the resend window, its goodbye ends the link; anything else is
//! dropped and counted (`forged`) before a byte of it is read.

use std::time::{Duration, Instant};

use bus::Message;
use bus::bus_schema::Topic;
use hdrhistogram::Histogram;

use crate::HEARTBEAT_EVERY;
use crate::health::{ClockSync, LinkEvent, LinkState, LinkWatch};
use crate::reliable::{Arrival, Incoming, Outgoing, Overflow, Pending};
use crate::seal::{Opener, Seal, Sealer};
use crate::stats::{HostLink, HostReport, Percentiles, new_hist, record};
use crate::wire::{self, HEADER, Heartbeat, Kind};

/// Where a link end's frames go (a Zenoh publisher; a `Vec` of frames in tests).
pub trait Sink {
    /// Sends one frame; whether it went out.
    fn put(&mut self, frame: &[u8]) -> bool;
}

impl Sink for Vec<Vec<u8>> {
    fn put(&mut self, frame: &[u8]) -> bool {
        self.push(frame.to_vec());
        true
    }
}

/// What became of a message the caller was to write into its host's bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Put {
    /// Written; it was sent at `sent_ns` (moved onto this host's clock; 0 = no time).
    Done {
        /// Its send time.
        sent_ns: u64,
    },
    /// Not now (the bus is full, or its reader is not there yet): a lossless message stays
    /// first in line; a latest-wins one is gone.
    Later,
    /// Not acceptable (unreadable, another host's robot, a topic that never comes from
    /// there): dropped, counted in `rejected`.
    Rejected,
    /// Could not be written (a latest-wins message into a full bus): counted in `dropped`.
    Dropped,
    /// Not wanted (a robot gone, nobody to read it): dropped, not counted.
    Skipped,
}

/// What a data frame says besides its message, for the caller that writes the message into
/// its host's bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Meta {
    /// What to add to the peer's times to move them onto this host's clock.
    pub shift: i64,
    /// The sender's bus woke the message's readers ([`wire::FLAG_WAKE`]): wake them here too.
    pub wake: bool,
}

/// What a received frame asks of the caller besides its messages.
#[derive(Debug, PartialEq, Eq)]
pub enum Got {
    /// Nothing more: a heartbeat taken, a message handed on or queued for
    /// [`LinkEnd::deliver`], a duplicate skipped, or a frame dropped and counted.
    Nothing,
    /// The peer says these robots are gone, after its lossless frame `after`.
    Gone {
        /// The peer's lossless frames sent before the report.
        after: u64,
        /// Robot ids, as sent (the caller keeps only its own).
        ids: Vec<u32>,
    },
    /// The peer is leaving; `after` of its lossless frames arrived in order before.
    Goodbye {
        /// Frames in order so far.
        after: u64,
    },
}

/// One end of a link.
pub struct LinkEnd {
    out: Outgoing,
    inc: Incoming,
    pending: Pending,
    watch: LinkWatch,
    clock: ClockSync,
    /// The last heartbeat's `t_ns` and when it arrived (this host's clock), to echo.
    echo: (u64, u64),
    last_beat: Instant,
    sealer: Option<Sealer>,
    opener: Option<Opener>,
    scratch: Vec<u8>,
    rtt: Histogram<u64>,
    one_way: Histogram<u64>,
    /// Frame counts (`frames_in`, `frames_out`, `rejected`, `forged`, `capped`, `dropped`);
    /// the rest of the figures are filled in by [`LinkEnd::report`].
    pub counts: HostLink,
}

impl LinkEnd {
    /// A link heard at `now` (the join), down after `down_after` of silence and lost after
    /// `deadline`, with the clock estimate of the join, sealed with `seal` (None: plain
    /// frames, `--insecure-plain`). The first heartbeat is due at once.
    pub fn new(
        now: Instant,
        down_after: Duration,
        deadline: Duration,
        clock: ClockSync,
        seal: Option<Seal>,
    ) -> LinkEnd {
        let mut watch = LinkWatch::new(now, down_after, deadline);
        watch.heard(now);
        let (sealer, opener) = match seal {
            Some(s) => (Some(s.tx), Some(s.rx)),
            None => (None, None),
        };
        LinkEnd {
            out: Outgoing::default(),
            inc: Incoming::default(),
            pending: Pending::default(),
            watch,
            clock,
            echo: (0, 0),
            last_beat: now.checked_sub(HEARTBEAT_EVERY).unwrap_or(now),
            sealer,
            opener,
            scratch: Vec::new(),
            rtt: new_hist(),
            one_way: new_hist(),
            counts: HostLink::default(),
        }
    }

    /// The link's state.
    pub fn state(&self) -> LinkState {
        self.watch.state()
    }

    /// Whether the link is given up on.
    pub fn lost(&self) -> bool {
        self.state() == LinkState::Lost
    }

    fn up(&self) -> bool {
        self.state() == LinkState::Up
    }

    /// Lossless frames sent and not acknowledged yet.
    pub fn unacked(&self) -> usize {
        self.out.unacked()
    }

    /// Lossless frames of the peer handed to [`LinkEnd::deliver`]'s callback so far.
    pub fn delivered(&self) -> u64 {
        self.inc.acked() - self.pending.len() as u64
    }

    /// What to add to a time of the peer's clock to get this host's.
    pub fn to_local(&self) -> i64 {
        self.clock.to_local()
    }

    /// When the next heartbeat is due.
    pub fn next_beat(&self) -> Instant {
        self.last_beat + HEARTBEAT_EVERY
    }

    /// Takes one frame that arrived at `now` (`t_ns` on the monotonic clock of the messages).
    /// A frame that does not open, or is not a frame, is dropped and counted. A latest-wins
    /// message goes to `latest(topic, bytes, meta)` at once ([`Meta`]: the clock shift and the
    /// wake flag); a lossless one waits for
    /// [`LinkEnd::deliver`]. The first frame after a silence brings the link back: everything
    /// unacknowledged goes again at once through `sink`, and the returned flag is set for the
    /// caller to say so.
    pub fn on_frame(
        &mut self,
        sealed: &[u8],
        now: Instant,
        t_ns: u64,
        sink: &mut impl Sink,
        latest: impl FnOnce(Topic, &[u8], Meta) -> Put,
    ) -> (Got, bool) {
        self.counts.frames_in += 1;
        let frame: &[u8] = match &mut self.opener {
            Some(o) => match o.open(sealed) {
                Ok(f) => f,
                Err(_) => {
                    self.counts.forged += 1;
                    return (Got::Nothing, false);
                }
            },
            None => sealed,
        };
        let Ok(h) = wire::header(frame) else {
            self.counts.rejected += 1;
            return (Got::Nothing, false);
        };
        let came_back = self.watch.heard(now) == Some(LinkEvent::CameBack);
        if came_back {
            let up = self.watch.state() == LinkState::Up;
            for f in self.out.due(now, true) {
                emit(&mut self.sealer, &mut self.counts, sink, up, f);
            }
        }
        let got = match h.kind {
            Kind::Heartbeat => {
                let Ok(hb) = wire::read_heartbeat(&frame[HEADER..]) else {
                    self.counts.rejected += 1;
                    return (Got::Nothing, came_back);
                };
                if let Some(rtt) = self.clock.sample(hb.t_ns, hb.echo_ns, hb.hold_ns, t_ns) {
                    record(&mut self.rtt, rtt);
                }
                self.echo = (hb.t_ns, t_ns);
                if !self.out.ack(hb.acked, now) {
                    self.counts.rejected += 1;
                }
                if hb.gone.is_empty() {
                    Got::Nothing
                } else {
                    Got::Gone {
                        after: hb.sent,
                        ids: hb.gone,
                    }
                }
            }
            Kind::Lossless => {
                if self.pending.is_full() {
                    // not taken, not acknowledged: the peer sends it again later
                    self.counts.capped += 1;
                } else if self.inc.arrive(h.seq) == Arrival::Next {
                    self.pending.push(frame);
                }
                Got::Nothing
            }
            Kind::Latest => {
                let meta = Meta {
                    shift: self.clock.to_local(),
                    wake: h.wake,
                };
                let put = latest(h.topic, &frame[HEADER..], meta);
                count(&mut self.counts, &mut self.one_way, put, t_ns);
                Got::Nothing
            }
            Kind::Goodbye => Got::Goodbye {
                after: self.inc.acked(),
            },
        };
        (got, came_back)
    }

    /// Hands the lossless frames received in order to `put(topic, bytes, meta)` until it
    /// says [`Put::Later`] (that frame stays first, for the next call); `t_ns` is now on the
    /// messages' clock. Whether any was handed on.
    pub fn deliver(&mut self, t_ns: u64, mut put: impl FnMut(Topic, &[u8], Meta) -> Put) -> bool {
        let shift = self.clock.to_local();
        let LinkEnd {
            pending,
            counts,
            one_way,
            ..
        } = self;
        pending.deliver(|frame| match wire::header(frame) {
            Ok(h) => {
                let meta = Meta {
                    shift,
                    wake: h.wake,
                };
                let p = put(h.topic, &frame[HEADER..], meta);
                count(counts, one_way, p, t_ns);
                p != Put::Later
            }
            // checked when it arrived; never here
            Err(_) => true,
        })
    }

    /// Sends a latest-wins message (once, may drop; not while the link is down).
    pub fn send_latest<T: Message>(&mut self, m: &T, sink: &mut impl Sink) {
        if self.up() {
            wire::write_data_frame_as(&mut self.scratch, Kind::Latest, m, 0, false);
            self.emit_scratch(sink);
        }
    }

    /// Sends a message the way [`wire::link_kind`] says its topic crosses, flagged
    /// [`wire::FLAG_WAKE`] when `wake` (the receiving host then wakes its readers).
    pub fn send<T: Message>(
        &mut self,
        m: &T,
        wake: bool,
        now: Instant,
        sink: &mut impl Sink,
    ) -> Result<(), Overflow> {
        match wire::link_kind(T::TOPIC) {
            Kind::Lossless => self.send_lossless_flagged(m, wake, now, sink),
            _ => {
                if self.up() {
                    wire::write_data_frame_as(&mut self.scratch, Kind::Latest, m, 0, wake);
                    self.emit_scratch(sink);
                }
                Ok(())
            }
        }
    }

    /// Numbers a lossless message, keeps it until acknowledged and sends it (while the link is
    /// up; otherwise it goes with the resend when the link is back).
    pub fn send_lossless<T: Message>(
        &mut self,
        m: &T,
        now: Instant,
        sink: &mut impl Sink,
    ) -> Result<(), Overflow> {
        self.send_lossless_flagged(m, false, now, sink)
    }

    fn send_lossless_flagged<T: Message>(
        &mut self,
        m: &T,
        wake: bool,
        now: Instant,
        sink: &mut impl Sink,
    ) -> Result<(), Overflow> {
        let up = self.up();
        let f = self.out.push_with(now, |seq, buf| {
            wire::write_data_frame_as(buf, Kind::Lossless, m, seq, wake)
        })?;
        emit(&mut self.sealer, &mut self.counts, sink, up, f);
        Ok(())
    }

    /// The periodic work, every loop turn: the link's state from the silence (returned when it
    /// changed), a heartbeat when due (it goes even while the link looks down: it is how the
    /// link comes back) naming `gone` robots, and the resends that are due. Nothing once lost.
    pub fn tick(
        &mut self,
        now: Instant,
        t_ns: u64,
        gone: &[u32],
        sink: &mut impl Sink,
    ) -> Option<LinkEvent> {
        if self.lost() {
            return None;
        }
        let event = self.watch.tick(now);
        if self.lost() {
            return event;
        }
        if now.duration_since(self.last_beat) >= HEARTBEAT_EVERY {
            self.last_beat = now;
            let hb = Heartbeat::at(
                t_ns,
                self.echo,
                self.inc.acked(),
                self.out.next_seq(),
                gone.to_vec(),
            );
            wire::write_heartbeat(&mut self.scratch, &hb);
            self.emit_scratch(sink);
        }
        // while the link is down nothing is resent (nor counted): it all goes when it is back
        if self.up() {
            for f in self.out.due(now, false) {
                emit(&mut self.sealer, &mut self.counts, sink, true, f);
            }
        }
        event
    }

    /// Sends the frame written into `scratch`.
    fn emit_scratch(&mut self, sink: &mut impl Sink) {
        emit(
            &mut self.sealer,
            &mut self.counts,
            sink,
            true,
            &self.scratch,
        );
    }

    /// Tells the peer this end is leaving.
    pub fn goodbye(&mut self, sink: &mut impl Sink) {
        let f = wire::goodbye_frame();
        emit(&mut self.sealer, &mut self.counts, sink, true, &f);
    }

    /// The link's figures into `r`: counts, state, reconnects, time down, clock, round trips,
    /// one-way latency, resends and duplicates.
    pub fn report(&self, r: &mut HostReport) {
        r.link = HostLink {
            reconnects: self.watch.reconnects,
            down_ms: self.watch.down_for.as_millis() as u64,
            clock_offset_ns: self.clock.offset_ns(),
            best_rtt_ns: self.clock.best_rtt_ns().unwrap_or(0),
            rtt_ns: Percentiles::of(&self.rtt),
            one_way_in_ns: Percentiles::of(&self.one_way),
            resent: self.out.resent,
            duplicates: self.inc.duplicates,
            ..self.counts.clone()
        };
        r.state = Some(self.state());
    }
}

/// Counts what became of a message; records the one-way latency of one written at `t_ns`.
fn count(counts: &mut HostLink, one_way: &mut Histogram<u64>, put: Put, t_ns: u64) {
    match put {
        Put::Done { sent_ns } if sent_ns != 0 && sent_ns <= t_ns => {
            record(one_way, t_ns - sent_ns);
        }
        Put::Rejected => counts.rejected += 1,
        Put::Dropped => counts.dropped += 1,
        _ => {}
    }
}

/// Sends `frame` (sealed when the link is) if `up`, counting what went out.
fn emit(
    sealer: &mut Option<Sealer>,
    counts: &mut HostLink,
    sink: &mut impl Sink,
    up: bool,
    frame: &[u8],
) {
    if !up {
        return;
    }
    let bytes = match sealer {
        Some(s) => s.seal(frame),
        None => frame,
    };
    if sink.put(bytes) {
        counts.frames_out += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::seal::{COOKIE_BYTES, HostKeys, NONCE_BYTES, SECRET_BYTES, Secret};
    use bus::bus_schema::{Control, DiscoveryRelay, MergedHintBatch, Register};

    const MS: Duration = Duration::from_millis(1);

    fn skip(_: Topic, _: &[u8], _: Meta) -> Put {
        Put::Skipped
    }

    fn keys(secret: u8) -> HostKeys {
        HostKeys::new(
            &Secret::new("run-1", [secret; SECRET_BYTES]),
            &[5; COOKIE_BYTES],
            &[6; NONCE_BYTES],
        )
    }

    /// The hub's end and host 0's end of one link, sealed, joined at `t0`.
    fn pair(t0: Instant) -> (LinkEnd, LinkEnd) {
        let k = keys(1);
        let end = |s| LinkEnd::new(t0, 500 * MS, 5000 * MS, ClockSync::default(), Some(s));
        (end(k.hub_end(0)), end(k.host_end(0)))
    }

    fn control(seq: u64) -> Control {
        Control {
            seq,
            ..Control::ZEROED
        }
    }

    /// Feeds every frame of `wire` to `end`, returning what each asked for (owned).
    fn feed(end: &mut LinkEnd, wire: &mut Vec<Vec<u8>>, now: Instant) -> Vec<String> {
        let mut back = Vec::new();
        let mut asked = Vec::new();
        for f in std::mem::take(wire) {
            let mut latest = None;
            let (got, _) = end.on_frame(&f, now, 1_000, &mut back, |t, _, _| {
                latest = Some(t);
                Put::Done { sent_ns: 0 }
            });
            match latest {
                Some(t) => asked.push(format!("Latest({t:?})")),
                None => asked.push(format!("{got:?}")),
            }
        }
        asked
    }

    fn delivered(end: &mut LinkEnd) -> Vec<(Topic, u64)> {
        let mut got = Vec::new();
        end.deliver(1, |t, b, _| {
            let mut c = Control::ZEROED;
            if t == Topic::Control {
                wire::read_into(b, &mut c).unwrap();
            }
            got.push((t, c.seq));
            Put::Done { sent_ns: 0 }
        });
        got
    }

    #[test]
    fn lossless_messages_arrive_once_in_order_and_latest_ones_at_once() {
        let t0 = Instant::now();
        let (mut hub, mut host) = pair(t0);
        let mut wire: Vec<Vec<u8>> = Vec::new();
        for s in 0..3 {
            hub.send_lossless(&control(s), t0, &mut wire).unwrap();
        }
        hub.send_latest(&MergedHintBatch::ZEROED, &mut wire);
        let asked = feed(&mut host, &mut wire.clone(), t0);
        assert_eq!(asked[..3], ["Nothing", "Nothing", "Nothing"]);
        assert_eq!(asked[3], "Latest(Merged)");
        assert_eq!(
            delivered(&mut host),
            [
                (Topic::Control, 0),
                (Topic::Control, 1),
                (Topic::Control, 2)
            ]
        );
        assert_eq!(host.delivered(), 3);
        // the same frames again (a replay, or a resend sealed twice) deliver nothing more
        feed(&mut host, &mut wire, t0);
        assert!(delivered(&mut host).is_empty());
        assert_eq!(host.counts.forged, 4, "replays are dropped before reading");
        assert_eq!(host.counts.frames_in, 8);
    }

    #[test]
    fn grid_messages_go_lossless_in_order_with_the_senders_wake() {
        use bus::bus_schema::{Grant, Intent};
        let t0 = Instant::now();
        let (mut hub, mut host) = pair(t0);
        let mut wire = Vec::new();
        for (tick, wake) in [(0, true), (1, false), (2, false), (3, true)] {
            let g = Grant {
                tick,
                ..Grant::ZEROED
            };
            hub.send(&g, wake, t0, &mut wire).unwrap();
        }
        assert_eq!(hub.unacked(), 4, "kept until acknowledged, as control is");
        // the second grant is lost on the way: nothing after it is delivered before the resend
        wire.remove(1);
        feed(&mut host, &mut wire, t0);
        let mut got = Vec::new();
        let take = |host: &mut LinkEnd, got: &mut Vec<(u32, bool)>| {
            host.deliver(1, |t, b, meta| {
                assert_eq!(t, Topic::Grant);
                let mut g = Grant::ZEROED;
                wire::read_into(b, &mut g).unwrap();
                got.push((g.tick, meta.wake));
                Put::Done { sent_ns: 0 }
            });
        };
        take(&mut host, &mut got);
        assert_eq!(got, [(0, true)]);
        // the resend (sealed anew, with a heartbeat) brings the rest, in order
        let mut again = Vec::new();
        hub.tick(t0 + crate::reliable::RESEND_AFTER, 1, &[], &mut again);
        feed(&mut host, &mut again, t0);
        take(&mut host, &mut got);
        assert_eq!(got, [(0, true), (1, false), (2, false), (3, true)]);
        // the robots' answers go the same way, never flagged
        let mut up = Vec::new();
        host.send(&Intent::ZEROED, false, t0, &mut up).unwrap();
        assert_eq!(host.unacked(), 1);
        assert_eq!(feed(&mut hub, &mut up, t0), ["Nothing"]);
    }

    #[test]
    fn a_full_bus_delays_lossless_messages_without_losing_or_reordering_them() {
        let t0 = Instant::now();
        let (mut hub, mut host) = pair(t0);
        let mut wire = Vec::new();
        for s in 0..4 {
            hub.send_lossless(&control(s), t0, &mut wire).unwrap();
        }
        feed(&mut host, &mut wire, t0);
        let mut room = 1;
        let mut got = Vec::new();
        host.deliver(1, |_, b, _| {
            if room == 0 {
                return Put::Later;
            }
            room -= 1;
            let mut c = Control::ZEROED;
            wire::read_into(b, &mut c).unwrap();
            got.push(c.seq);
            Put::Done { sent_ns: 0 }
        });
        assert_eq!(got, [0]);
        assert_eq!(host.delivered(), 1);
        let rest: Vec<u64> = delivered(&mut host).iter().map(|(_, s)| *s).collect();
        assert_eq!(rest, [1, 2, 3]);
    }

    #[test]
    fn heartbeats_acknowledge_and_a_silent_link_resends_everything_when_it_is_back() {
        let t0 = Instant::now();
        let (mut hub, mut host) = pair(t0);
        let mut down = Vec::new();
        let mut up = Vec::new();
        hub.send_lossless(&control(0), t0, &mut down).unwrap();
        // the frame is lost on the way; host B's heartbeat acknowledges nothing
        down.clear();
        host.tick(t0, 1, &[], &mut up);
        assert_eq!(up.len(), 1, "a heartbeat at once");
        feed(&mut hub, &mut up, t0);
        assert_eq!(hub.unacked(), 1);
        // silence: the hub's link to the host goes down, lossless frames wait
        assert_eq!(
            hub.tick(t0 + 600 * MS, 2, &[], &mut down),
            Some(LinkEvent::WentDown)
        );
        down.clear();
        hub.send_lossless(&control(1), t0 + 700 * MS, &mut down)
            .unwrap();
        assert!(down.is_empty(), "nothing is published into a down link");
        // the host is heard again: both frames go at once, and arrive in order
        host.tick(t0 + 800 * MS, 3, &[], &mut up);
        let mut back = Vec::new();
        let (got, came_back) = hub.on_frame(&up[0], t0 + 800 * MS, 3, &mut back, skip);
        assert_eq!((got, came_back), (Got::Nothing, true));
        assert_eq!(back.len(), 2);
        feed(&mut host, &mut back, t0 + 800 * MS);
        let seqs: Vec<u64> = delivered(&mut host).iter().map(|(_, s)| *s).collect();
        assert_eq!(seqs, [0, 1]);
        // the next heartbeat acknowledges them
        let mut up = Vec::new();
        host.tick(t0 + 900 * MS, 4, &[], &mut up);
        feed(&mut hub, &mut up, t0 + 900 * MS);
        assert_eq!(hub.unacked(), 0);
        let mut r = HostReport::default();
        hub.report(&mut r);
        assert_eq!((r.link.reconnects, r.link.resent), (1, 2));
        assert_eq!(r.state, Some(LinkState::Up));
    }

    #[test]
    fn a_forged_ack_does_not_discard_what_the_peer_never_got() {
        let t0 = Instant::now();
        let (mut hub, _) = pair(t0);
        let mut down = Vec::new();
        for s in 0..3 {
            hub.send_lossless(&control(s), t0, &mut down).unwrap();
        }
        // a heartbeat claiming everything arrived, from a stranger (no key, or another
        // secret), and in plain bytes as the old links sent them
        let hb = Heartbeat {
            acked: 3,
            ..Heartbeat::default()
        };
        let plain = wire::heartbeat_frame(&hb);
        let mut stranger = keys(2).host_end(0);
        let mut other_host = keys(1).host_end(1);
        for f in [
            plain.clone(),
            stranger.seal(&plain).to_vec(),
            other_host.seal(&plain).to_vec(),
        ] {
            let (got, _) = hub.on_frame(&f, t0, 1, &mut Vec::new(), skip);
            assert_eq!(got, Got::Nothing);
        }
        assert_eq!(hub.unacked(), 3, "nothing discarded");
        assert_eq!(hub.counts.forged, 3);
        // an authenticated ack of frames never sent is refused too
        let mut host = keys(1).host_end(0);
        let hb = Heartbeat {
            acked: 1000,
            ..Heartbeat::default()
        };
        hub.on_frame(
            host.seal(&wire::heartbeat_frame(&hb)),
            t0,
            1,
            &mut Vec::new(),
            skip,
        );
        assert_eq!((hub.unacked(), hub.counts.rejected), (3, 1));
    }

    #[test]
    fn a_goodbye_or_gone_report_counts_only_from_the_peers_key() {
        let t0 = Instant::now();
        let (mut hub, mut host) = pair(t0);
        let mut up = Vec::new();
        // forged goodbye: a stranger's key, or the plain frame
        let mut stranger = keys(9).host_end(0);
        let bye = wire::goodbye_frame();
        for f in [bye.clone(), stranger.seal(&bye).to_vec()] {
            assert_eq!(hub.on_frame(&f, t0, 1, &mut up, skip).0, Got::Nothing);
        }
        // the host's own goodbye and gone reports go through
        host.send_lossless(&Register::ZEROED, t0, &mut up).unwrap();
        host.tick(t0, 1, &[4, 5], &mut up);
        host.goodbye(&mut up);
        let asked = feed(&mut hub, &mut up, t0);
        assert_eq!(
            asked,
            [
                "Nothing",
                "Gone { after: 1, ids: [4, 5] }",
                "Goodbye { after: 1 }"
            ]
        );
    }

    #[test]
    fn silence_past_the_deadline_loses_the_link_and_forged_frames_do_not_keep_it_up() {
        let t0 = Instant::now();
        let (mut hub, _) = pair(t0);
        let mut stranger = keys(9).host_end(0);
        let mut out = Vec::new();
        for i in 1..=60u32 {
            let now = t0 + 100 * MS * i;
            let hb = wire::heartbeat_frame(&Heartbeat::default());
            hub.on_frame(stranger.seal(&hb), now, 1, &mut out, skip);
            hub.tick(now, 1, &[], &mut out);
        }
        assert!(hub.lost());
        assert_eq!(hub.tick(t0 + 10_000 * MS, 1, &[], &mut out), None);
        let n = out.len();
        hub.send_latest(&DiscoveryRelay::ZEROED, &mut out);
        assert_eq!(out.len(), n, "nothing is sent into a lost link");
    }

    #[test]
    fn the_stranger_on_the_wire_sees_no_message_bytes() {
        let t0 = Instant::now();
        let (mut hub, _) = pair(t0);
        let mut wire = Vec::new();
        let c = Control {
            seq: 0x1122_3344_5566_7788,
            ..Control::ZEROED
        };
        hub.send_lossless(&c, t0, &mut wire).unwrap();
        hub.tick(t0, 0x0abc_def0_1234, &[], &mut wire);
        let plain = wire::data_frame(&c, 0);
        for f in &wire {
            assert!(
                !f.windows(8)
                    .any(|w| w == 0x1122_3344_5566_7788u64.to_le_bytes())
            );
            assert!(!f.windows(5).any(|w| w == b"t_ns\""));
            assert_ne!(
                f[8..8 + HEADER],
                plain[..HEADER],
                "the header is sealed too"
            );
        }
    }

    #[test]
    fn a_plain_link_still_works_end_to_end() {
        let t0 = Instant::now();
        let end = || LinkEnd::new(t0, 500 * MS, 5000 * MS, ClockSync::default(), None);
        let (mut a, mut b) = (end(), end());
        let mut wire = Vec::new();
        a.send_lossless(&control(7), t0, &mut wire).unwrap();
        assert_eq!(wire[0], wire::data_frame(&control(7), 0));
        feed(&mut b, &mut wire, t0);
        assert_eq!(delivered(&mut b), [(Topic::Control, 7)]);
    }
}
