//! The joining side: ask to join, stand in for the coordinator on this host's bus, and carry
//! every message across.
//!
//! [`request`] connects to the coordinator's host and returns the [`JoinPlan`]. [`Joiner::new`]
//! then creates this host's services with a coordinator stand-in — an iceoryx2 node named
//! `qfleet-coordinator`, whose process is `qfleet join` itself — so local robots register,
//! watch their coordinator's pid and reconnect exactly as they do on one host; the caller starts
//! the robots and calls [`Joiner::serve`]. A robot whose process is gone — it ended, or a node
//! listing says so ([`crate::roster`]) — is reported to the hub in the next heartbeat. While
//! the link is down the robots keep learning; their lossless messages wait here and are resent
//! when it is back.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

use bus::bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, Grant, Intent, IntentHorizon,
    MergedHintBatch, PseudoTargetDiscovery, QHintBatch, Register, RobotState, Topic,
};
use bus::iceoryx2::prelude::{CallbackProgression, SignalHandlingMode, WaitSetBuilder, ipc};
use bus::{
    BusConfig, BusError, CoordinatorBus, Lister, Listing, Liveness, SendError, WakeListener,
    monotonic_ns, wake_pair,
};
use zenoh::Wait;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;

use crate::end::{Got, LinkEnd, Meta, Put};
use crate::health::{ClockSync, LinkEvent};
use crate::join::{JOIN_KEY, JoinAsk, JoinPlan, JoinReply, JoinRequest, Knocker};
use crate::link::{self, Tuning};
use crate::roster::{Listed, Roster};
use crate::seal::{HostKeys, Secret};
use crate::stats::HostReport;
use crate::topics::{FromRobot, ToRobot};
use crate::wire::Kind;
use crate::{BridgeError, HEARTBEAT_EVERY};

/// How often the joining side looks at this host's robot processes (a full listing at most
/// every [`bus::lister::FULL_EVERY`]).
const LIST_EVERY: Duration = Duration::from_millis(200);

/// What an accepted join leaves for [`Joiner::new`].
pub struct Joined {
    /// The session to the coordinator's host.
    pub session: zenoh::Session,
    /// The endpoint the session connected to: the hub's direct listener, or `endpoint` (its
    /// front door, which relays).
    pub via: String,
    /// The plan, opened and checked to be for the run the secret names.
    pub plan: JoinPlan,
    /// The clock offset seeded by the exchange.
    pub clock: ClockSync,
    /// The keys of this join (the link's seal and Zenoh keys).
    pub keys: HostKeys,
}

impl std::fmt::Debug for Joined {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Joined")
            .field("via", &self.via)
            .field("plan", &self.plan)
            .finish()
    }
}

/// How long a joining host tries the hub's direct listener before it goes through the door:
/// the hub is a probe's round trip away, and the door has just opened it to this host.
pub const DIRECT_WITHIN: Duration = Duration::from_secs(2);

/// How long a joining host waits before it probes a door that refused the connection again.
const PROBE_AGAIN: Duration = Duration::from_millis(200);

/// One query on the join key: the answer, or None when nobody answered (yet).
fn ask(
    session: &zenoh::Session,
    endpoint: &str,
    ask: &JoinAsk,
) -> Result<Option<JoinReply>, BridgeError> {
    let body = serde_json::to_vec(ask).map_err(|e| BridgeError::Join(e.to_string()))?;
    let replies = session
        .get(JOIN_KEY)
        .payload(body)
        .timeout(Duration::from_secs(1))
        .wait()
        .map_err(|e| BridgeError::Zenoh {
            what: format!("asking {endpoint} to join"),
            detail: crate::zenoh_text(&e),
        })?;
    let Ok(reply) = replies.recv() else {
        return Ok(None);
    };
    let sample = reply
        .into_result()
        .map_err(|e| BridgeError::Join(format!("{endpoint} answered with an error: {e:?}")))?;
    serde_json::from_slice(&sample.payload().to_bytes())
        .map(Some)
        .map_err(|e| {
            BridgeError::Join(format!(
                "unreadable answer from {endpoint} ({e}): another qfleet version?"
            ))
        })
}

/// Asks `endpoint` to let `req.robots` robots join the run `secret` is for: proves the secret
/// (challenge–response; it never crosses the wire), opens the sealed plan (which proves the
/// other host holds it too) and refuses a plan of another run. The session stays open for
/// [`Joiner`].
pub fn request(
    endpoint: &str,
    req: &JoinRequest,
    secret: &Secret,
    timeout: Duration,
    tuning: Tuning,
) -> Result<Joined, BridgeError> {
    // a wrong secret is said in seconds; a door that does not answer leaves it to Zenoh
    let mut direct = None;
    let started = Instant::now();
    if let Ok(door) = link::listen_address(endpoint) {
        let within = crate::probe::PROBE_WITHIN.min(timeout);
        loop {
            match crate::probe::knock_direct(door, secret, within) {
                (crate::probe::Probe::Refused, _) => {
                    return Err(BridgeError::Credentials {
                        endpoint: endpoint.to_string(),
                    });
                }
                // the run's hub is not up yet (both started at once): ask again while the join
                // may wait, so this host gets the direct port instead of the relay; Zenoh keeps
                // a second of the timeout to say what it finds
                (crate::probe::Probe::NotListening, _)
                    if started.elapsed() + PROBE_AGAIN + Duration::from_secs(1) < timeout =>
                {
                    std::thread::sleep(PROBE_AGAIN);
                }
                (_, port) => {
                    direct = port.and_then(|p| link::direct_endpoint(endpoint, p));
                    break;
                }
            }
        }
    }
    let timeout = timeout
        .saturating_sub(started.elapsed())
        .max(Duration::from_secs(1));
    let auth = link::SessionAuth::of(secret);
    // the door opened its direct listener to this host: the session goes there, without the
    // relay hop; if it cannot be reached (a firewall that lets only `endpoint` through), the
    // relay, as before
    let direct_session = direct.as_ref().and_then(|d| {
        match link::connect(d, DIRECT_WITHIN.min(timeout), tuning, &auth) {
            Ok(s) => Some(s),
            Err(e) => {
                report::log_line!(
                    "qfleet: the hub's direct port {d} did not answer ({e}); joining through its front door {endpoint} instead (a relay hop more per message)"
                );
                None
            }
        }
    });
    let via = match (&direct, &direct_session) {
        (Some(d), Some(_)) => d.clone(),
        _ => endpoint.to_string(),
    };
    let session = match direct_session {
        Some(s) => s,
        None => link::connect(endpoint, timeout, tuning, &auth)?,
    };
    let deadline = Instant::now() + timeout;
    let knocker = Knocker::new(secret.clone())?;
    loop {
        let cookie = match ask(&session, endpoint, &knocker.hello())? {
            Some(JoinReply::Challenge { cookie }) => Some(cookie),
            Some(JoinReply::Refused { reason }) => return Err(BridgeError::Refused(reason)),
            Some(JoinReply::Accepted { .. }) => {
                return Err(BridgeError::Join(format!(
                    "{endpoint} accepted a hello: not a qfleet run of this version"
                )));
            }
            // connected but the hub's queryable is not known here yet (or no run listens there)
            None => None,
        };
        if let Some(cookie) = cookie {
            let mut req = req.clone();
            req.t_ns = monotonic_ns();
            let (join, keys) = knocker.join(&cookie, req.clone())?;
            match ask(&session, endpoint, &join)? {
                Some(JoinReply::Accepted { plan }) => {
                    let got = monotonic_ns();
                    let plan = knocker.open(&keys, &plan).map_err(BridgeError::Refused)?;
                    let mut clock = ClockSync::default();
                    clock.seed(req.t_ns, plan.t_ns, got);
                    return Ok(Joined {
                        session,
                        via,
                        plan,
                        clock,
                        keys,
                    });
                }
                Some(JoinReply::Refused { reason }) => return Err(BridgeError::Refused(reason)),
                Some(JoinReply::Challenge { .. }) | None => {}
            }
        }
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
    local: Local,
    publisher: zenoh::pubsub::Publisher<'static>,
    end: LinkEnd,
    frames: Subscriber<Receiver<Sample>>,
    /// Rung by the subscriber's callback after each frame (taken by [`Joiner::serve`]).
    wakes: Option<WakeListener>,
    /// This host's robots: which are gone (reported in every heartbeat).
    roster: Roster,
    /// How many of the roster's gone robots were logged.
    logged_gone: usize,
    report: HostReport,
    /// How long the loop keeps looking after a message moved ([`Tuning::spin`]).
    spin: Duration,
}

/// This host's bus as the robots' coordinator, and which of its topics need a wakeup.
struct Local {
    bus: CoordinatorBus,
    /// Control, merged, ack, relay, grant.
    wake: [bool; 5],
    /// The run's fleet size (what a message's robot ids and counts are checked against).
    fleet: u32,
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

impl Ending {
    /// How the joining host's run ended for its exit (`qfleet join`): an error line when the
    /// coordinator's host at `endpoint` was lost, when it was stopped, or when robots `failed`.
    pub fn verdict(&self, endpoint: &str, failed: &[u32]) -> Result<(), String> {
        match self {
            Ending::Lost => Err(format!(
                "lost the coordinator's host {endpoint} (silent past the deadline); robots stopped"
            )),
            Ending::Stopped => Err("interrupted".into()),
            Ending::Done | Ending::RunOver if !failed.is_empty() => Err(format!(
                "robots {failed:?} exited with an error (see their logs)"
            )),
            Ending::Done | Ending::RunOver => Ok(()),
        }
    }
}

impl Joiner {
    /// Creates this host's services for the plan (before any robot starts).
    pub fn new(joined: Joined, host: &str, tuning: Tuning) -> Result<Self, BridgeError> {
        let Joined {
            session,
            via: _,
            plan,
            clock,
            keys,
        } = joined;
        let mut cfg = BusConfig::new(plan.run_id.clone(), plan.robots_total)?;
        cfg.hint_buffer = plan.hint_buffer;
        cfg.merged_buffer = plan.merged_buffer;
        cfg.send_timeout = Duration::from_secs(1);
        cfg.validate()?;
        let bus = CoordinatorBus::create(&cfg)?;
        let publisher = link::publisher(&session, keys.up_key(plan.host_index), tuning)?;
        let (waker, wakes) = wake_pair()?;
        let frames = session
            .declare_subscriber(keys.down_key(plan.host_index))
            .with(link::waking(link::SUBSCRIBER_DEPTH, waker, false))
            .wait()
            .map_err(|e| BridgeError::Zenoh {
                what: "subscribing to the coordinator's host".into(),
                detail: crate::zenoh_text(&e),
            })?;
        let end = LinkEnd::new(
            Instant::now(),
            Duration::from_millis(plan.down_after_ms),
            Duration::from_millis(plan.deadline_ms),
            clock,
            (!plan.plain).then(|| keys.host_end(plan.host_index)),
        );
        let report = HostReport {
            host: host.to_string(),
            robots: plan.robot_ids.clone(),
            ..HostReport::default()
        };
        Ok(Joiner {
            roster: Roster::new(&plan.robot_ids),
            session,
            local: Local {
                bus,
                wake: [false; 5],
                fleet: plan.robots_total,
            },
            plan,
            publisher,
            end,
            frames,
            wakes: Some(wakes),
            logged_gone: 0,
            report,
            spin: tuning.spin,
        })
    }

    /// The plan this host runs.
    pub fn plan(&self) -> &JoinPlan {
        &self.plan
    }

    /// Carries messages until the robots are done and nothing is unacknowledged, the
    /// coordinator's host says goodbye or is lost, or `stop` is set.
    ///
    /// `robots(exited)` is asked before every heartbeat: it calls `exited(id)` for each robot
    /// whose process has ended (again and again is fine) and returns whether all are done. An
    /// ended robot is reported gone in that heartbeat and every one after — the surest sign,
    /// which does not depend on a node listing ever having shown the robot (see
    /// [`crate::roster`]). A caller without processes calls nothing and says when it is done.
    pub fn serve(
        &mut self,
        stop: &AtomicBool,
        mut robots: impl FnMut(&mut dyn FnMut(u32)) -> bool,
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
        let lister = Lister::start(
            self.local.bus.config(),
            LIST_EVERY,
            true,
            "qfleet-join-live",
        )
        .map_err(|e| BridgeError::Thread(format!("starting the liveness thread: {e}")))?;
        let mut last_list = Instant::now();
        let mut pacing = link::Pacing::new(Instant::now(), self.spin);
        let mut done_at: Option<Instant> = None;
        let mut robots_done = false;
        link::tighten_timer_slack();
        let ending = loop {
            let now = Instant::now();
            let mut busy = false;
            let mut over = false;
            // who went, before this pass drains what the robots sent: whatever a robot wrote
            // before it ended goes up ahead of the heartbeat that says it is gone (the hub
            // drops its proxy only after delivering what came before)
            let beat = now >= self.end.next_beat();
            if beat {
                let roster = &mut self.roster;
                let mut went = false;
                robots_done = robots(&mut |id| went |= roster.exited(id));
                if went {
                    self.log_gone("its process ended");
                }
            }
            if now.duration_since(last_list) >= LIST_EVERY {
                last_list = now;
                if let Some(listing) = lister.poll() {
                    self.robots_listed(listing)?;
                }
            }
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
            if self.wake_robots() {
                // the robots answer a woken grant with intents they do not notify
                pacing.expect_reply(now);
            }
            let gone: &[u32] = if beat { self.roster.gone() } else { &[] };
            match self
                .end
                .tick(now, monotonic_ns(), gone, &mut self.publisher)
            {
                Some(LinkEvent::WentDown) => report::log_line!(
                    "qfleet join: the coordinator's host is silent; robots keep learning, their \
                     lossless messages are kept"
                ),
                Some(LinkEvent::Lost) => break Ending::Lost,
                _ => {}
            }
            if over {
                break Ending::RunOver;
            }
            if stop.load(Ordering::SeqCst) {
                break Ending::Stopped;
            }
            if robots_done {
                // the last reports must be acknowledged; a robot's "gone" must reach the hub
                let t = *done_at.get_or_insert(now);
                if self.end.unacked() == 0 && now.duration_since(t) >= HEARTBEAT_EVERY * 3 {
                    break Ending::Done;
                }
            }
            // idle: keep looking a little, then block on the WaitSet until a frame, a robot's
            // notified message, or the next heartbeat / robot listing
            let due = self.end.next_beat().min(last_list + LIST_EVERY);
            let Some(timeout) = link::rest(pacing.after_pass(now, busy, data, due)) else {
                continue;
            };
            {
                let _guards = self.local.bus.attach_all(&waitset)?;
                waitset
                    .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, timeout)
                    .map_err(|e| waitset_error(&e))?;
            }
            // before the channel is drained: whatever is pushed after this wakes the next wait
            wakes.clear();
            self.local.bus.clear_wakeups()?;
        };
        drop(wake_guard);
        self.wakes = Some(wakes);
        if ending != Ending::Lost {
            self.end.goodbye(&mut self.publisher);
        }
        Ok(ending)
    }

    /// The figures of the link, and closes it.
    pub fn finish(self) -> HostReport {
        let mut r = self.report;
        self.end.report(&mut r);
        drop(self.frames);
        drop(self.publisher);
        let _ = self.local.bus.close();
        let _ = self.session.close().wait();
        r
    }

    /// Handles one frame; true when the hub said goodbye.
    fn on_frame(&mut self, frame: &[u8], now: Instant) -> bool {
        let local = &mut self.local;
        let put = |t, b: &[u8], meta| local.put(t, b, meta);
        match self
            .end
            .on_frame(frame, now, monotonic_ns(), &mut self.publisher, put)
        {
            (Got::Goodbye { .. }, _) => true,
            (_, true) => {
                report::log_line!(
                    "qfleet join: the coordinator's host is back; resending what it missed"
                );
                false
            }
            _ => false,
        }
    }

    fn deliver_in_order(&mut self) -> bool {
        let local = &mut self.local;
        self.end
            .deliver(monotonic_ns(), |t, b, meta| local.put(t, b, meta))
    }

    /// Notifies the robots of what was written for them; whether a grant woke them.
    fn wake_robots(&mut self) -> bool {
        let w = std::mem::take(&mut self.local.wake);
        let b = &self.local.bus;
        let r = [
            w[0].then(|| b.control.notify()),
            w[1].then(|| b.merged.notify()),
            w[2].then(|| b.ack.notify()),
            w[3].then(|| b.relay.notify()),
            w[4].then(|| b.grant.notify()),
        ];
        drop(r);
        w[4]
    }

    /// Reads what the robots sent and publishes it to the hub straight from shared memory
    /// (one reused frame buffer; lossless frames are kept in the resend window's reused
    /// buffers).
    fn forward_up(&mut self, now: Instant) -> Result<bool, BridgeError> {
        let Joiner {
            local,
            end,
            publisher,
            ..
        } = self;
        let bus = &local.bus;
        let mut sent = Sent {
            end,
            publisher,
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
        up::<Intent>(bus, &mut sent, |_| {});
        up::<IntentHorizon>(bus, &mut sent, |_| {});
        match sent.overflow {
            Some(e) => Err(BridgeError::Link(e.to_string())),
            None => Ok(sent.any),
        }
    }

    /// Takes a listing of this host's robot nodes (the lister cleans up after dead ones): a
    /// robot listed dead, or seen alive before and not alive now, is gone ([`Roster::listed`]).
    fn robots_listed(&mut self, listing: Listing) -> Result<(), BridgeError> {
        let nodes = listing.report?;
        let state = |id: u32| {
            let mut listed = Listed::Absent;
            for n in &nodes.nodes {
                if robot_of_node(&n.name) == Some(id) {
                    match n.liveness {
                        Liveness::Alive => return Listed::Alive,
                        Liveness::Dead => listed = Listed::Dead,
                        _ => {}
                    }
                }
            }
            listed
        };
        if self.roster.listed(state) > 0 {
            self.log_gone("its node is dead or gone");
        }
        Ok(())
    }

    /// Logs the robots that went since the last call (`why`).
    fn log_gone(&mut self, why: &str) {
        let gone = self.roster.gone();
        for id in &gone[self.logged_gone.min(gone.len())..] {
            report::log_line!(
                "qfleet join: robot {id} is gone ({why}); the coordinator's host is told"
            );
        }
        self.logged_gone = gone.len();
    }
}

/// The robot id of node `name` (`qfleet-robot-<id>`, the name `bus::RobotBus::open` gives).
fn robot_of_node(name: &str) -> Option<u32> {
    name.strip_prefix("qfleet-robot-")?.parse().ok()
}

impl Local {
    /// Writes a coordinator message into this host's bus; `meta.shift` moves its times onto
    /// this host's clock. A grant wakes the robots only when the coordinator woke its own
    /// readers with it (`meta.wake`): the others they read when they look.
    fn put(&mut self, topic: Topic, payload: &[u8], meta: Meta) -> Put {
        match topic {
            Topic::Control => self.put_as::<Control>(payload, meta, Some(0)),
            Topic::Merged => self.put_as::<MergedHintBatch>(payload, meta, Some(1)),
            Topic::Ack => self.put_as::<DiscoveryAck>(payload, meta, Some(2)),
            Topic::Relay => self.put_as::<DiscoveryRelay>(payload, meta, Some(3)),
            Topic::Grant => self.put_as::<Grant>(payload, meta, meta.wake.then_some(4)),
            _ => Put::Rejected,
        }
    }

    fn put_as<T: ToRobot>(&mut self, payload: &[u8], meta: Meta, slot: Option<usize>) -> Put {
        let mut m = T::default();
        if crate::wire::read_into(payload, &mut m).is_err() || m.check(self.fleet).is_err() {
            return Put::Rejected;
        }
        m.shift(meta.shift);
        match T::outbox(&self.bus).send(&m) {
            Ok(_) => {
                if let Some(i) = slot {
                    self.wake[i] = true;
                }
                Put::Done {
                    sent_ns: m.send_ns(),
                }
            }
            // nobody here to tell (the robots left): as the coordinator does, not an error
            Err(SendError::NoSubscriber { .. }) => Put::Skipped,
            Err(_) if T::TOPIC.delivery() == bus::bus_schema::Delivery::Lossless => Put::Later,
            Err(_) => Put::Dropped,
        }
    }
}

/// Where [`up`] publishes: the link's end and publisher, and what happened.
struct Sent<'a> {
    end: &'a mut LinkEnd,
    publisher: &'a mut zenoh::pubsub::Publisher<'static>,
    now: Instant,
    any: bool,
    overflow: Option<crate::reliable::Overflow>,
}

/// Drains one robot topic and publishes each message.
fn up<T: FromRobot>(bus: &CoordinatorBus, sent: &mut Sent<'_>, mut seen: impl FnMut(&T)) {
    let lossless = crate::wire::link_kind(T::TOPIC) == Kind::Lossless;
    let _ = T::inbox(bus).drain(usize::MAX, |m| {
        seen(m);
        sent.any = true;
        if !lossless {
            sent.end.send_latest(m, sent.publisher);
        } else if let Err(e) = sent.end.send_lossless(m, sent.now, sent.publisher) {
            sent.overflow = Some(e);
        }
    });
}
