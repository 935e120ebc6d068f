//! The joining side: ask to join, stand in for the coordinator on this host's bus, and carry
//! every message across.
//!
//! [`request`] connects to the coordinator's host and returns the [`JoinPlan`]. [`Joiner::new`]
//! then creates this host's services with a coordinator stand-in — an iceoryx2 node named
//! `qfleet-coordinator`, whose process is `qfleet join` itself — so local robots register,
//! watch their coordinator's pid and reconnect exactly as they do on one host; the caller starts
//! the robots and calls [`Joiner::serve`]. A robot whose process is gone is reported to the hub
//! in the next heartbeat. While the link is down the robots keep learning; their lossless
//! messages wait here and are resent when it is back.

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

use bus::bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, MergedHintBatch, PseudoTargetDiscovery,
    QHintBatch, Register, RobotState, Topic,
};
use bus::iceoryx2::prelude::{CallbackProgression, SignalHandlingMode, WaitSetBuilder, ipc};
use bus::{
    BusConfig, BusError, CoordinatorBus, Lister, Listing, WakeListener, monotonic_ns, wake_pair,
};
use hdrhistogram::Histogram;
use zenoh::Wait;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;

use crate::health::{ClockSync, LinkEvent, LinkState, LinkWatch};
use crate::join::{JOIN_KEY, JoinPlan, JoinReply, JoinRequest};
use crate::link::{self, Tuning, Tx};
use crate::reliable::{Arrival, Incoming, Outgoing, Pending};
use crate::stats::{HostReport, Percentiles, new_hist, record};
use crate::topics::{FromRobot, ToRobot};
use crate::wire::{self, HEADER, Heartbeat, Kind};
use crate::{BridgeError, HEARTBEAT_EVERY, down_key, up_key};

/// How often the joining side looks at this host's robot processes (a full listing at most
/// every [`bus::lister::FULL_EVERY`]).
const LIST_EVERY: Duration = Duration::from_millis(200);

/// Asks `endpoint` to let `req.robots` robots join; the session stays open for [`Joiner`].
pub fn request(
    endpoint: &str,
    req: &JoinRequest,
    timeout: Duration,
    tuning: Tuning,
) -> Result<(zenoh::Session, JoinPlan, ClockSync), BridgeError> {
    let session = link::connect(endpoint, timeout, tuning)?;
    let deadline = Instant::now() + timeout;
    loop {
        let mut req = req.clone();
        req.t_ns = monotonic_ns();
        let body = serde_json::to_vec(&req).map_err(|e| BridgeError::Join(e.to_string()))?;
        let replies = session
            .get(JOIN_KEY)
            .payload(body)
            .timeout(Duration::from_secs(1))
            .wait()
            .map_err(|e| BridgeError::Zenoh {
                what: format!("asking {endpoint} to join"),
                detail: crate::zenoh_text(&e),
            })?;
        if let Ok(reply) = replies.recv() {
            let got = monotonic_ns();
            let sample = reply.into_result().map_err(|e| {
                BridgeError::Join(format!("{endpoint} answered with an error: {e:?}"))
            })?;
            let answer: JoinReply =
                serde_json::from_slice(&sample.payload().to_bytes()).map_err(|e| {
                    BridgeError::Join(format!(
                        "unreadable answer from {endpoint} ({e}): another qfleet version?"
                    ))
                })?;
            return match answer {
                JoinReply::Accepted(plan) => {
                    let mut clock = ClockSync::default();
                    clock.seed(req.t_ns, plan.t_ns, got);
                    Ok((session, plan, clock))
                }
                JoinReply::Refused { reason } => Err(BridgeError::Refused(reason)),
            };
        }
        // connected but the hub's queryable is not known here yet (or no run listens there)
        if Instant::now() >= deadline {
            return Err(BridgeError::Join(format!(
                "no qfleet run answered on {endpoint} within {timeout:?}"
            )));
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The joining host's bridge: its bus (coordinator stand-in) and its end of the link.
pub struct Joiner {
    session: zenoh::Session,
    plan: JoinPlan,
    bus: CoordinatorBus,
    tx: Tx,
    frames: Subscriber<Receiver<Sample>>,
    /// Rung by the subscriber's callback after each frame (taken by [`Joiner::serve`]).
    wakes: Option<WakeListener>,
    out: Outgoing,
    inc: Incoming,
    watch: LinkWatch,
    clock: ClockSync,
    echo: (u64, u64),
    /// Lossless frames in order, waiting to be written into this host's bus.
    pending: Pending,
    seen: BTreeSet<u32>,
    gone: BTreeSet<u32>,
    rtt: Histogram<u64>,
    one_way: Histogram<u64>,
    wake: [bool; 4],
    report: HostReport,
    /// How long the loop keeps looking after a message moved ([`Tuning::spin`]).
    spin: Duration,
}

/// How [`Joiner::serve`] ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Ending {
    /// The robots are done and everything they sent was acknowledged.
    Done,
    /// The coordinator's host said the run is over.
    RunOver,
    /// Asked to stop (Ctrl-C).
    Stopped,
    /// The coordinator's host stayed silent past the deadline.
    Lost,
}

impl Joiner {
    /// Creates this host's services for the plan (before any robot starts).
    pub fn new(
        session: zenoh::Session,
        plan: JoinPlan,
        clock: ClockSync,
        host: &str,
        tuning: Tuning,
    ) -> Result<Self, BridgeError> {
        let mut cfg = BusConfig::new(plan.run_id.clone(), plan.robots_total)?;
        cfg.hint_buffer = plan.hint_buffer;
        cfg.merged_buffer = plan.merged_buffer;
        cfg.send_timeout = Duration::from_secs(1);
        cfg.validate()?;
        let bus = CoordinatorBus::create(&cfg)?;
        let publisher = link::publisher(&session, up_key(&plan.run_id, plan.host_index), tuning)?;
        let (waker, wakes) = wake_pair()?;
        let frames = session
            .declare_subscriber(down_key(&plan.run_id, plan.host_index))
            .with(link::waking(link::SUBSCRIBER_DEPTH, waker))
            .wait()
            .map_err(|e| BridgeError::Zenoh {
                what: "subscribing to the coordinator's host".into(),
                detail: crate::zenoh_text(&e),
            })?;
        let now = Instant::now();
        let mut watch = LinkWatch::new(
            now,
            Duration::from_millis(plan.down_after_ms),
            Duration::from_millis(plan.deadline_ms),
        );
        watch.heard(now);
        let report = HostReport {
            host: host.to_string(),
            robots: plan.robot_ids.clone(),
            ..HostReport::default()
        };
        Ok(Joiner {
            session,
            plan,
            bus,
            tx: Tx::new(publisher),
            frames,
            wakes: Some(wakes),
            out: Outgoing::default(),
            inc: Incoming::default(),
            watch,
            clock,
            echo: (0, 0),
            pending: Pending::default(),
            seen: BTreeSet::new(),
            gone: BTreeSet::new(),
            rtt: new_hist(),
            one_way: new_hist(),
            wake: [false; 4],
            report,
            spin: tuning.spin,
        })
    }

    /// The plan this host runs.
    pub fn plan(&self) -> &JoinPlan {
        &self.plan
    }

    /// Carries messages until the robots are done (`robots_done()` and nothing unacknowledged),
    /// the coordinator's host says goodbye or is lost, or `stop` is set.
    pub fn serve(
        &mut self,
        stop: &AtomicBool,
        mut robots_done: impl FnMut() -> bool,
    ) -> Result<Ending, BridgeError> {
        let waitset_error = |e: &dyn std::fmt::Debug| {
            BridgeError::Bus(BusError::Event {
                service: "WaitSet".into(),
                detail: format!("{e:?}"),
            })
        };
        // iceoryx2's own SIGINT/SIGTERM handler would replace the process's: keep it off
        let waitset = WaitSetBuilder::new()
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| waitset_error(&e))?;
        let wakes = self
            .wakes
            .take()
            .ok_or_else(|| BridgeError::Link("served twice".into()))?;
        let wake_guard = wakes.attach(&waitset)?;
        // the robots' liveness, looked at on a thread of its own: a full listing costs
        // hundreds of µs, which this loop would hold a frame up for
        let lister = Lister::start(self.bus.config(), LIST_EVERY, true, "qfleet-join-live")
            .map_err(|e| BridgeError::Thread(format!("starting the liveness thread: {e}")))?;
        let mut last_beat = Instant::now() - HEARTBEAT_EVERY;
        let mut last_list = Instant::now();
        let mut pacing = link::Pacing::new(Instant::now(), self.spin);
        let mut done_at: Option<Instant> = None;
        link::tighten_timer_slack();
        let ending = loop {
            let now = Instant::now();
            let mut busy = false;
            let mut over = false;
            for _ in 0..4096 {
                let Ok(sample) = self.frames.try_recv() else {
                    break;
                };
                busy = true;
                over |= self.on_frame(&sample.payload().to_bytes(), now);
            }
            let mut data = self.deliver_in_order();
            if self.forward_up(now)? {
                data = true;
                // the coordinator's answer (merged hints, acks, relays) comes back over the link
                pacing.expect_reply(now);
            }
            self.wake_robots();
            if now.duration_since(last_list) >= LIST_EVERY {
                last_list = now;
                if let Some(listing) = lister.poll() {
                    self.robots_listed(listing)?;
                }
            }
            match self.watch.tick(now) {
                Some(LinkEvent::WentDown) => report::log_line!(
                    "qfleet join: the coordinator's host is silent; robots keep learning, their \
                     lossless messages are kept"
                ),
                Some(LinkEvent::Lost) => break Ending::Lost,
                _ => {}
            }
            if now.duration_since(last_beat) >= HEARTBEAT_EVERY {
                last_beat = now;
                self.heartbeat();
            }
            let up = self.watch.state() == LinkState::Up;
            self.tx.resend(up, &mut self.out, now, false);
            if over {
                break Ending::RunOver;
            }
            if stop.load(Ordering::SeqCst) {
                break Ending::Stopped;
            }
            if robots_done() {
                // the last reports must be acknowledged; a robot's "gone" must reach the hub
                let t = *done_at.get_or_insert(now);
                if self.out.unacked() == 0 && now.duration_since(t) >= HEARTBEAT_EVERY * 3 {
                    break Ending::Done;
                }
            }
            // idle: keep looking a little, then block on the WaitSet until a frame, a robot's
            // notified message, or the next heartbeat / robot listing
            let due = (last_beat + HEARTBEAT_EVERY).min(last_list + LIST_EVERY);
            let Some(timeout) = link::rest(pacing.after_pass(now, busy, data, due)) else {
                continue;
            };
            {
                let _guards = self.bus.attach_all(&waitset)?;
                waitset
                    .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, timeout)
                    .map_err(|e| waitset_error(&e))?;
            }
            // before the channel is drained: whatever is pushed after this wakes the next wait
            wakes.clear();
            self.bus.clear_wakeups()?;
        };
        drop(wake_guard);
        self.wakes = Some(wakes);
        if ending != Ending::Lost {
            self.tx.send(true, &wire::goodbye_frame());
        }
        Ok(ending)
    }

    /// The figures of the link, and closes it.
    pub fn finish(self) -> HostReport {
        let mut r = self.report;
        r.state = Some(self.watch.state());
        r.link.reconnects = self.watch.reconnects;
        r.link.down_ms = self.watch.down_for.as_millis() as u64;
        r.link.clock_offset_ns = self.clock.offset_ns();
        r.link.best_rtt_ns = self.clock.best_rtt_ns().unwrap_or(0);
        r.link.rtt_ns = Percentiles::of(&self.rtt);
        r.link.one_way_in_ns = Percentiles::of(&self.one_way);
        r.link.resent = self.out.resent;
        r.link.duplicates = self.inc.duplicates;
        r.link.frames_out = self.tx.frames_out;
        drop(self.frames);
        drop(self.tx);
        let _ = self.bus.close();
        let _ = self.session.close().wait();
        r
    }

    /// Handles one frame; true when the hub said goodbye.
    fn on_frame(&mut self, frame: &[u8], now: Instant) -> bool {
        self.report.link.frames_in += 1;
        let Ok(h) = wire::header(frame) else {
            self.report.link.rejected += 1;
            return false;
        };
        if let Some(LinkEvent::CameBack) = self.watch.heard(now) {
            report::log_line!(
                "qfleet join: the coordinator's host is back; resending what it missed"
            );
            let up = self.watch.state() == LinkState::Up;
            self.tx.resend(up, &mut self.out, now, true);
        }
        match h.kind {
            Kind::Heartbeat => {
                let Ok(hb) = wire::read_heartbeat(&frame[HEADER..]) else {
                    self.report.link.rejected += 1;
                    return false;
                };
                let t = monotonic_ns();
                if let Some(rtt) = self.clock.sample(hb.t_ns, hb.echo_ns, hb.hold_ns, t) {
                    record(&mut self.rtt, rtt);
                }
                self.echo = (hb.t_ns, t);
                if !self.out.ack(hb.acked, now) {
                    self.report.link.rejected += 1;
                }
            }
            Kind::Lossless => {
                if self.pending.is_full() {
                    // not taken, not acknowledged: the hub sends it again later
                    self.report.link.capped += 1;
                } else if self.inc.arrive(h.seq) == Arrival::Next {
                    self.pending.push(frame);
                }
            }
            Kind::Latest => {
                let _ = self.put(h.topic, &frame[HEADER..]);
            }
            Kind::Goodbye => return true,
        }
        false
    }

    fn deliver_in_order(&mut self) -> bool {
        let mut pending = std::mem::take(&mut self.pending);
        let any = pending.deliver(|frame| match wire::header(frame) {
            Ok(h) => self.put(h.topic, &frame[HEADER..]) != Some(false),
            Err(_) => true,
        });
        self.pending = pending;
        any
    }

    /// Writes a coordinator message into this host's bus: Some(true) sent, Some(false) try
    /// again later, None dropped.
    fn put(&mut self, topic: Topic, payload: &[u8]) -> Option<bool> {
        match topic {
            Topic::Control => self.put_as::<Control>(payload, 0),
            Topic::Merged => self.put_as::<MergedHintBatch>(payload, 1),
            Topic::Ack => self.put_as::<DiscoveryAck>(payload, 2),
            Topic::Relay => self.put_as::<DiscoveryRelay>(payload, 3),
            _ => {
                self.report.link.rejected += 1;
                None
            }
        }
    }

    fn put_as<T: ToRobot>(&mut self, payload: &[u8], slot: usize) -> Option<bool> {
        let mut m = T::default();
        if wire::read_into(payload, &mut m).is_err() {
            self.report.link.rejected += 1;
            return None;
        }
        m.shift(self.clock.to_local());
        match T::outbox(&self.bus).send(&m) {
            Ok(_) => {
                self.wake[slot] = true;
                let t = monotonic_ns();
                let sent = m.send_ns();
                if sent != 0 && sent <= t {
                    record(&mut self.one_way, t - sent);
                }
                Some(true)
            }
            // nobody here to tell (the robots left): as the coordinator does, not an error
            Err(BusError::NoSubscriber { .. }) => None,
            Err(_) if T::TOPIC.delivery() == bus::bus_schema::Delivery::Lossless => Some(false),
            Err(_) => {
                self.report.link.dropped += 1;
                None
            }
        }
    }

    fn wake_robots(&mut self) {
        let w = std::mem::take(&mut self.wake);
        let b = &self.bus;
        let r = [
            w[0].then(|| b.control.notify()),
            w[1].then(|| b.merged.notify()),
            w[2].then(|| b.ack.notify()),
            w[3].then(|| b.relay.notify()),
        ];
        drop(r);
    }

    /// Reads what the robots sent and publishes it to the hub straight from shared memory
    /// (one reused frame buffer; lossless frames are kept in the resend window's reused
    /// buffers).
    fn forward_up(&mut self, now: Instant) -> Result<bool, BridgeError> {
        let up_now = self.watch.state() == LinkState::Up;
        let Joiner { bus, tx, out, .. } = self;
        let mut sent = Sent {
            tx,
            out,
            up: up_now,
            now,
            any: false,
            overflow: None,
        };
        let mut registered = false;
        up::<Register>(bus, &mut sent, |_| registered = true);
        if registered {
            // the start handshake: connect to the new robot's publishers before it sends
            // anything lossless (the coordinator does this when it admits a robot)
            bus.connect_all()?;
        }
        up::<RobotState>(bus, &mut sent, |_| {});
        up::<PseudoTargetDiscovery>(bus, &mut sent, |_| {});
        up::<QHintBatch>(bus, &mut sent, |_| {});
        up::<FinalReport>(bus, &mut sent, |_| {});
        match sent.overflow {
            Some(e) => Err(BridgeError::Link(e.to_string())),
            None => Ok(sent.any),
        }
    }

    fn heartbeat(&mut self) {
        let hb = Heartbeat::at(
            monotonic_ns(),
            self.echo,
            self.inc.acked(),
            self.out.next_seq(),
            self.gone.iter().copied().collect(),
        );
        self.tx.send(true, &wire::heartbeat_frame(&hb));
    }

    /// Takes a listing of this host's robot nodes (the lister cleans up after dead ones): a
    /// robot seen before and not alive now is gone.
    fn robots_listed(&mut self, listing: Listing) -> Result<(), BridgeError> {
        let nodes = listing.report?;
        let alive: BTreeSet<u32> = nodes
            .alive()
            .filter_map(|n| n.name.strip_prefix("qfleet-robot-")?.parse().ok())
            .collect();
        for id in &self.seen {
            if !alive.contains(id) {
                self.gone.insert(*id);
            }
        }
        self.seen
            .extend(alive.iter().filter(|id| !self.gone.contains(id)));
        Ok(())
    }
}

/// Where [`up`] publishes: the link's sending end and lossless window, and what happened.
struct Sent<'a> {
    tx: &'a mut Tx,
    out: &'a mut Outgoing,
    up: bool,
    now: Instant,
    any: bool,
    overflow: Option<crate::reliable::Overflow>,
}

/// Drains one robot topic and publishes each message.
fn up<T: FromRobot>(bus: &CoordinatorBus, sent: &mut Sent<'_>, mut seen: impl FnMut(&T)) {
    let lossless = T::TOPIC.delivery() == bus::bus_schema::Delivery::Lossless;
    let _ = T::inbox(bus).drain(usize::MAX, |m| {
        seen(m);
        sent.any = true;
        if !lossless {
            sent.tx.latest(sent.up, m);
        } else if let Err(e) = sent.tx.lossless(sent.up, sent.out, m, sent.now) {
            sent.overflow = Some(e);
        }
    });
}
