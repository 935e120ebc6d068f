//! The coordinator's side: admit joining hosts, stand in for their robots on this host's bus,
//! and carry every message across.
//!
//! The hub is a thread of `qfleet run` (and of `qfleet experiment`). For each remote robot it holds a **proxy**: a
//! [`RobotBus`] opened under the robot's own id, so its iceoryx2 node is named
//! `qfleet-robot-<id>` like the robot's would be. The coordinator therefore needs no change: it
//! admits, acks and watches remote robots exactly as local ones. A proxy publishes what its
//! robot sends over the link, and its subscribers receive what the coordinator sends; the hub
//! forwards that to the robot's host (control and acks only to the host whose robot is
//! addressed, broadcasts once per host). A proxy is dropped — its node disappears, and the
//! coordinator's liveness check reports the robot `lost` unless its final report came first —
//! when the joining host says the robot's process is gone, or when the host stays silent past
//! the deadline.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bus::bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, MergedHintBatch, PseudoTargetDiscovery,
    QHintBatch, ROBOT_ID_ALL, Register, RobotState, Topic,
};
use std::sync::mpsc::Receiver;

use bus::iceoryx2::prelude::{CallbackProgression, SignalHandlingMode, WaitSetBuilder, ipc};
use bus::{BusConfig, BusError, RobotBus, WakeListener, Waker, monotonic_ns, wake_pair};
use hdrhistogram::Histogram;
use serde::Serialize;
use zenoh::Wait;
use zenoh::pubsub::Subscriber;
use zenoh::query::{Query, Queryable};
use zenoh::sample::Sample;

use crate::health::{ClockSync, LinkEvent, LinkState, LinkWatch};
use crate::join::{Admission, JOIN_KEY, JoinPlan, JoinReply, JoinRequest, RefusedLog, RemotePlan};
use crate::link::{self, Tuning, Tx};
use crate::reliable::{Arrival, Incoming, Outgoing, Pending};
use crate::stats::{HostEntry, HostReport, Percentiles, new_hist, record};
use crate::topics::{FromRobot, ToRobot};
use crate::wire::{self, HEADER, Heartbeat, Kind};
use crate::{BridgeError, HEARTBEAT_EVERY, down_key, up_key_all};

/// How the hub runs.
#[derive(Debug, Clone)]
pub struct HubOptions {
    /// Zenoh endpoint to listen on, e.g. `tcp/10.0.0.1:7447`.
    pub listen: String,
    /// The run's side of the join.
    pub plan: RemotePlan,
    /// Heartbeat silence after which a host's link counts as down.
    pub down_after: Duration,
    /// Silence after which a host is lost: its robots are reported lost, the run goes on.
    pub deadline: Duration,
    /// Zenoh settings.
    pub tuning: Tuning,
    /// A joined host whose robots have not all registered this long after its join is given
    /// up: its robot ids go back to the open slots.
    pub start_within: Duration,
    /// After this long from the hub's start no host may join any more: robot ids no host
    /// holds then are given up, and the coordinator goes on without them.
    pub join_within: Duration,
    /// The run's out directory: a given-up robot id gets the note `robot-<id>.exited` there
    /// (what the launcher leaves for a robot that died before it registered), so the
    /// coordinator's start does not wait for it.
    pub out: Option<PathBuf>,
}

/// What the hub saw, for the run's result.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct HubReport {
    /// The endpoint it listened on.
    pub listen: String,
    /// Remote robots the run waited for.
    pub remote_robots: u32,
    /// Remote robots that joined.
    pub joined_robots: u32,
    /// Joins refused, with their reasons (the first [`RefusedLog::KEEP`] kept).
    pub refused: Vec<String>,
    /// Joins refused in all.
    pub refused_total: u64,
    /// Frames on a joined host's key for a host index that never joined, or unparsable keys.
    pub foreign_frames: u64,
    /// Hosts that joined but did not start their robots within `start_within`.
    pub expired_hosts: u32,
    /// Robot ids no host ran: the run went on without them.
    pub given_up: Vec<u32>,
    /// One entry per joined host.
    pub hosts: Vec<HostReport>,
}

impl HubReport {
    /// A result's `hosts`: this host first (robots `0..local`), then every joined host.
    pub fn entries(&self, local: u32) -> Vec<HostEntry> {
        std::iter::once(HostEntry::local(local))
            .chain(self.hosts.iter().map(HostReport::entry))
            .collect()
    }
}

/// The running hub; [`Hub::finish`] stops it and returns its report.
#[derive(Debug)]
pub struct Hub {
    stop: Arc<AtomicBool>,
    /// Ends the hub thread's wait at once when the hub is stopped.
    waker: Waker,
    thread: Option<JoinHandle<Result<HubReport, BridgeError>>>,
}

impl Hub {
    /// Listens on `opts.listen` (an error at once if it cannot) and starts the hub thread.
    pub fn start(opts: HubOptions) -> Result<Hub, BridgeError> {
        let session = link::listen(&opts.listen, opts.tuning)?;
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let (waker, wakes) = wake_pair()?;
        let w = waker.clone();
        let thread = std::thread::Builder::new()
            .name("qfleet-hub".into())
            .spawn(move || {
                let r = run(&session, &opts, &flag, w, &wakes);
                let _ = session.close().wait();
                r
            })
            .map_err(|e| BridgeError::Thread(e.to_string()))?;
        Ok(Hub {
            stop,
            waker,
            thread: Some(thread),
        })
    }

    /// Tells the joined hosts the run is over, drops every proxy and returns the report.
    pub fn finish(mut self) -> Result<HubReport, BridgeError> {
        self.stop.store(true, Ordering::SeqCst);
        self.waker.wake();
        match self.thread.take() {
            Some(t) => t
                .join()
                .map_err(|_| BridgeError::Thread("the hub thread panicked".into()))?,
            None => Ok(HubReport::default()),
        }
    }
}

impl Drop for Hub {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        self.waker.wake();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A remote robot's stand-in on this host, and which of its topics need a wakeup.
struct Proxy {
    bus: RobotBus,
    wake: [bool; 5],
}

/// Robots a host reported gone, each applied once every frame that host sent before the
/// report is delivered. Only the host's own ids are taken, each once, so whatever a peer sends
/// this holds at most one entry per robot of that host; the rest is counted as dropped.
#[derive(Debug, Default)]
pub struct GoneQueue {
    waiting: Vec<(u64, u32)>,
    /// Robots whose gone report was applied.
    pub applied: BTreeSet<u32>,
}

impl GoneQueue {
    /// `ids` gone after the host's lossless frame `after`: takes those of `own` not reported
    /// yet; returns how many were dropped (other hosts' ids, repeats).
    pub fn report(&mut self, after: u64, ids: &[u32], own: &[u32]) -> u64 {
        let mut dropped = 0;
        for &id in ids {
            let known = self.applied.contains(&id) || self.waiting.iter().any(|(_, w)| *w == id);
            if known || !own.contains(&id) {
                dropped += 1;
            } else {
                self.waiting.push((after, id));
            }
        }
        dropped
    }

    /// Robots whose report is due now that `delivered` frames are delivered (each returned once).
    pub fn due(&mut self, delivered: u64) -> Vec<u32> {
        let mut out = Vec::new();
        self.waiting.retain(|&(after, id)| {
            let go = after <= delivered;
            if go {
                out.push(id);
            }
            !go
        });
        self.applied.extend(&out);
        out
    }

    /// Entries waiting.
    pub fn waiting(&self) -> usize {
        self.waiting.len()
    }
}

/// One joined host.
struct Host {
    name: String,
    ids: Vec<u32>,
    tx: Tx,
    out: Outgoing,
    inc: Incoming,
    watch: LinkWatch,
    clock: ClockSync,
    /// The last heartbeat's `t_ns` and when it arrived (our clock), to echo.
    echo: (u64, u64),
    last_beat: Instant,
    /// Lossless frames in order, waiting to be written into this host's bus.
    pending: Pending,
    proxies: BTreeMap<u32, Proxy>,
    /// Robots the host reported gone, applied once every frame it sent before is delivered.
    gone_after: GoneQueue,
    gone: BTreeSet<u32>,
    /// When it joined, and which of its robots registered since: a host that does not start
    /// its robots within `start_within` is given up.
    joined_at: Instant,
    registered: BTreeSet<u32>,
    expired: bool,
    last_control: Option<u64>,
    last_relay: Option<u64>,
    left: bool,
    deadline: Duration,
    rtt: Histogram<u64>,
    one_way: Histogram<u64>,
    report: HostReport,
}

fn waitset_error(e: impl std::fmt::Debug) -> BridgeError {
    BridgeError::Bus(BusError::Event {
        service: "WaitSet".into(),
        detail: format!("{e:?}"),
    })
}

fn run(
    session: &zenoh::Session,
    opts: &HubOptions,
    stop: &AtomicBool,
    waker: Waker,
    wakes: &WakeListener,
) -> Result<HubReport, BridgeError> {
    let plan = &opts.plan;
    let zerr = |what: &str| {
        let what = what.to_string();
        move |e: zenoh::Error| BridgeError::Zenoh {
            what: what.clone(),
            detail: crate::zenoh_text(&e),
        }
    };
    let mut cfg = BusConfig::new(plan.run_id.clone(), plan.robots_total)?;
    cfg.hint_buffer = plan.hint_buffer;
    cfg.merged_buffer = plan.merged_buffer;
    // joins and frames arrive on Zenoh's threads: each is pushed into a channel and wakes this
    // thread's WaitSet, which also holds the wake listeners of the coordinator's topics
    let joins: Queryable<Receiver<Query>> = session
        .declare_queryable(JOIN_KEY)
        .with(link::waking(64, waker.clone()))
        .wait()
        .map_err(zerr("declaring the join queryable"))?;
    let frames: Subscriber<Receiver<Sample>> = session
        .declare_subscriber(up_key_all(&plan.run_id))
        .with(link::waking(link::SUBSCRIBER_DEPTH, waker))
        .wait()
        .map_err(zerr("subscribing to the joined hosts"))?;
    // iceoryx2's own SIGINT/SIGTERM handler would replace the process's: keep it off
    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(waitset_error)?;
    let _wake_guard = wakes.attach(&waitset)?;
    let remote = plan.robots_total - plan.first_remote;
    let mut admission = Admission::new(plan.first_remote, plan.robots_total);
    let mut refused = RefusedLog::default();
    let started = Instant::now();
    let mut hosts: Vec<Host> = Vec::new();
    let mut report = HubReport {
        listen: opts.listen.clone(),
        remote_robots: remote,
        ..HubReport::default()
    };
    report::log_line!(
        "qfleet: waiting for {remote} robot(s) from other hosts on {}: run `qfleet join {} --robots N` there",
        opts.listen,
        crate::join::join_hint(&opts.listen)
    );
    let mut pacing = link::Pacing::new(Instant::now(), opts.tuning.spin);
    link::tighten_timer_slack();
    loop {
        let mut busy = false;
        let now = Instant::now();
        // joins
        while let Ok(q) = joins.try_recv() {
            busy = true;
            answer_join(session, &q, opts, &mut admission, &mut hosts, &mut refused);
        }
        // frames from the joined hosts
        for _ in 0..4096 {
            let Ok(sample) = frames.try_recv() else {
                break;
            };
            busy = true;
            let key = sample.key_expr().as_str();
            let host = key
                .rsplit('/')
                .next()
                .and_then(|s| s.parse::<usize>().ok())
                .and_then(|h| hosts.get_mut(h));
            match host {
                Some(host) => host.on_frame(&sample.payload().to_bytes(), now, &cfg),
                None => report.foreign_frames += 1,
            }
        }
        // hosts that did not start their robots in time give their slots back; once the join
        // window is over, slots no host holds are given up and the run goes on without them
        for host in &mut hosts {
            if let Some(ids) = host.expire_if_late(now, opts.start_within) {
                report.expired_hosts += 1;
                admission.release(&ids);
            }
        }
        if !admission.is_closed() && now.duration_since(started) >= opts.join_within {
            let ids = admission.close();
            if !ids.is_empty() {
                report::log_line!(
                    "qfleet: no host runs robots {ids:?} {:?} after the start: the run goes on without them",
                    opts.join_within
                );
                give_up(opts.out.as_deref(), &ids);
                report.given_up.extend(ids);
            }
        }
        if admission.is_closed() && admission.open_slots() > 0 {
            let ids = admission.close();
            give_up(opts.out.as_deref(), &ids);
            report.given_up.extend(ids);
        }
        let mut data = false;
        for host in &mut hosts {
            data |= host.deliver_in_order(&cfg);
            host.apply_gone();
            data |= host.forward_down(now);
            host.tick(now);
            if host.wake() {
                // the coordinator answers hints and discoveries without a wakeup
                pacing.expect_reply(now);
            }
        }
        if stop.load(Ordering::SeqCst) {
            break;
        }
        // idle: keep looking a little (the coordinator's replies to what was just delivered
        // come without a wakeup), then block on the WaitSet until a frame, a join, a notified
        // message or the next periodic work
        let due = hosts
            .iter()
            .filter(|h| !h.lost())
            .map(|h| h.last_beat + HEARTBEAT_EVERY)
            .min()
            .unwrap_or(now + HEARTBEAT_EVERY);
        let Some(timeout) = link::rest(pacing.after_pass(now, busy, data, due)) else {
            continue;
        };
        // one proxy's inboxes are enough to hear the coordinator: a notify wakes every
        // listener of a topic, and every proxy subscribes to every coordinator topic
        let anchor = hosts.iter().find_map(|h| h.proxies.values().next());
        let guards = match anchor {
            Some(p) => p
                .bus
                .listeners()
                .into_iter()
                .map(|(_, l)| waitset.attach_notification(l).map_err(waitset_error))
                .collect::<Result<Vec<_>, _>>()?,
            None => Vec::new(),
        };
        waitset
            .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, timeout)
            .map_err(waitset_error)?;
        drop(guards);
        // before the channels are drained: whatever is pushed after this wakes the next wait
        wakes.clear();
        if let Some(p) = anchor {
            for inbox_wakeups in [
                p.bus.control.clear_wakeups(),
                p.bus.merged.clear_wakeups(),
                p.bus.ack.clear_wakeups(),
                p.bus.relay.clear_wakeups(),
            ] {
                inbox_wakeups?;
            }
        }
    }
    for host in &mut hosts {
        host.tx.send(true, &wire::goodbye_frame());
    }
    report.joined_robots = hosts
        .iter()
        .filter(|h| !h.expired)
        .map(|h| h.ids.len() as u32)
        .sum();
    report.refused_total = refused.total;
    report.refused = refused.reasons;
    report.hosts = hosts.into_iter().map(Host::into_report).collect();
    Ok(report)
}

/// Leaves `robot-<id>.exited` in the run's out directory for robot ids no host runs, so the
/// coordinator's start goes on without them (as for a robot that died before it registered).
fn give_up(out: Option<&std::path::Path>, ids: &[u32]) {
    let Some(out) = out else {
        return;
    };
    for &id in ids {
        let path = out.join(format!("robot-{id}.exited"));
        if let Err(e) = std::fs::write(&path, b"no host ran this robot\n") {
            report::log_line!("qfleet: warning: writing {}: {e}", path.display());
        }
    }
}

fn answer_join(
    session: &zenoh::Session,
    q: &Query,
    opts: &HubOptions,
    admission: &mut Admission,
    hosts: &mut Vec<Host>,
    refused: &mut RefusedLog,
) {
    let plan = &opts.plan;
    let reply = |r: &JoinReply| {
        let body = serde_json::to_vec(r).unwrap_or_default();
        if let Err(e) = q.reply(JOIN_KEY, body).wait() {
            report::log_line!("qfleet: warning: answering a join: {e}");
        }
    };
    let req: JoinRequest = match q.payload().map(|p| serde_json::from_slice(&p.to_bytes())) {
        Some(Ok(r)) => r,
        other => {
            let reason = match other {
                Some(Err(e)) => format!("unreadable join request ({e}): another qfleet version?"),
                _ => "empty join request".to_string(),
            };
            if refused.push(&reason) {
                report::log_line!("qfleet: refused a join: {}", report::escape(&reason));
            }
            reply(&JoinReply::Refused { reason });
            return;
        }
    };
    let (index, ids) = match admission.admit(&req) {
        Ok(x) => x,
        Err(reason) => {
            if refused.push(&reason) {
                let host: String = req.host.chars().take(crate::join::MAX_HOST_NAME).collect();
                report::log_line!(
                    "qfleet: refused the join of host {}: {}",
                    report::escape(&host),
                    report::escape(&reason)
                );
            }
            reply(&JoinReply::Refused { reason });
            return;
        }
    };
    let publisher = match link::publisher(session, down_key(&plan.run_id, index), opts.tuning) {
        Ok(p) => p,
        Err(e) => {
            let reason = format!("the coordinator's host could not open the link: {e}");
            admission.release(&ids);
            refused.push(&reason);
            reply(&JoinReply::Refused { reason });
            return;
        }
    };
    let now = Instant::now();
    let accepted = JoinPlan {
        run_id: plan.run_id.clone(),
        host_index: index,
        robots_total: plan.robots_total,
        robot_ids: ids.clone(),
        robot_args: ids
            .iter()
            .map(|&id| {
                plan.robot_args
                    .get(id as usize)
                    .cloned()
                    .unwrap_or_default()
            })
            .collect(),
        files: plan.files.clone(),
        hint_buffer: plan.hint_buffer,
        merged_buffer: plan.merged_buffer,
        down_after_ms: opts.down_after.as_millis() as u64,
        deadline_ms: opts.deadline.as_millis() as u64,
        t_ns: monotonic_ns(),
    };
    reply(&JoinReply::Accepted(accepted));
    report::log_line!(
        "qfleet: host {} joined with robots {ids:?} ({} of {} remote robots now)",
        report::escape(&req.host),
        plan.robots_total - plan.first_remote - admission.open_slots(),
        plan.robots_total - plan.first_remote
    );
    let mut watch = LinkWatch::new(now, opts.down_after, opts.deadline);
    watch.heard(now);
    hosts.push(Host {
        report: HostReport {
            host: req.host.clone(),
            robots: ids.clone(),
            ..HostReport::default()
        },
        name: req.host,
        ids,
        tx: Tx::new(publisher),
        out: Outgoing::default(),
        inc: Incoming::default(),
        watch,
        clock: ClockSync::default(),
        echo: (0, 0),
        last_beat: now - HEARTBEAT_EVERY,
        pending: Pending::default(),
        proxies: BTreeMap::new(),
        gone_after: GoneQueue::default(),
        gone: BTreeSet::new(),
        joined_at: now,
        registered: BTreeSet::new(),
        expired: false,
        last_control: None,
        last_relay: None,
        left: false,
        deadline: opts.deadline,
        rtt: new_hist(),
        one_way: new_hist(),
    });
}

/// What became of a message written into the bus.
enum Put {
    Done,
    /// Try again later (the coordinator's buffer is full, or it is not there yet).
    Later,
    Rejected,
}

impl Host {
    fn lost(&self) -> bool {
        self.watch.state() == LinkState::Lost
    }

    fn on_frame(&mut self, frame: &[u8], now: Instant, cfg: &BusConfig) {
        if self.lost() || self.expired {
            return;
        }
        self.report.link.frames_in += 1;
        let h = match wire::header(frame) {
            Ok(h) => h,
            Err(_) => {
                self.report.link.rejected += 1;
                return;
            }
        };
        if let Some(LinkEvent::CameBack) = self.watch.heard(now) {
            report::log_line!(
                "qfleet: host {} is back; resending what it missed",
                report::escape(&self.name)
            );
            self.resend(now, true);
        }
        match h.kind {
            Kind::Heartbeat => {
                let Ok(hb) = wire::read_heartbeat(&frame[HEADER..]) else {
                    self.report.link.rejected += 1;
                    return;
                };
                let t = monotonic_ns();
                if let Some(rtt) = self.clock.sample(hb.t_ns, hb.echo_ns, hb.hold_ns, t) {
                    record(&mut self.rtt, rtt);
                }
                self.echo = (hb.t_ns, t);
                if !self.out.ack(hb.acked, now) {
                    self.report.link.rejected += 1;
                }
                if !hb.gone.is_empty() {
                    self.report.link.capped += self.gone_after.report(hb.sent, &hb.gone, &self.ids);
                }
            }
            Kind::Lossless => {
                if self.pending.is_full() {
                    // not taken, not acknowledged: the host sends it again later
                    self.report.link.capped += 1;
                } else if self.inc.arrive(h.seq) == Arrival::Next {
                    self.pending.push(frame);
                }
            }
            Kind::Latest => {
                let _ = self.put(h.topic, &frame[HEADER..], cfg);
            }
            Kind::Goodbye => {
                self.left = true;
                let after = self.inc.acked();
                let ids = self.ids.clone();
                self.gone_after.report(after, &ids, &ids);
            }
        }
    }

    /// Writes the in-order lossless frames into the bus until one has to wait.
    fn deliver_in_order(&mut self, cfg: &BusConfig) -> bool {
        let mut pending = std::mem::take(&mut self.pending);
        let any = pending.deliver(|frame| match wire::header(frame) {
            Ok(h) => !matches!(self.put(h.topic, &frame[HEADER..], cfg), Put::Later),
            Err(_) => true,
        });
        self.pending = pending;
        any
    }

    fn put(&mut self, topic: Topic, payload: &[u8], cfg: &BusConfig) -> Put {
        match topic {
            Topic::Register => self.put_as::<Register>(payload, cfg, 0),
            Topic::RobotState => self.put_as::<RobotState>(payload, cfg, 1),
            Topic::Discovery => self.put_as::<PseudoTargetDiscovery>(payload, cfg, 2),
            Topic::Hints => self.put_as::<QHintBatch>(payload, cfg, 3),
            Topic::Report => self.put_as::<FinalReport>(payload, cfg, 4),
            // coordinator topics never come from a joined host
            _ => {
                self.report.link.rejected += 1;
                Put::Rejected
            }
        }
    }

    fn put_as<T: FromRobot>(&mut self, payload: &[u8], cfg: &BusConfig, slot: usize) -> Put {
        let mut m = T::default();
        if wire::read_into(payload, &mut m).is_err() || !self.ids.contains(&m.robot_id()) {
            // a robot of another host (or of this one) cannot be impersonated from there
            self.report.link.rejected += 1;
            return Put::Rejected;
        }
        m.shift(self.clock.to_local());
        let id = m.robot_id();
        if self.gone.contains(&id) {
            return Put::Rejected;
        }
        let proxy = match self.proxies.entry(id) {
            std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::btree_map::Entry::Vacant(e) => {
                match RobotBus::open(cfg, id, Duration::from_millis(200)) {
                    Ok(bus) => e.insert(Proxy {
                        bus,
                        wake: [false; 5],
                    }),
                    Err(BusError::Timeout { .. }) => return Put::Later,
                    Err(err) => {
                        report::log_line!(
                            "qfleet: warning: cannot stand in for remote robot {id}: {err}"
                        );
                        return Put::Later;
                    }
                }
            }
        };
        let lossless = T::TOPIC.delivery() == bus::bus_schema::Delivery::Lossless;
        match T::outbox(&proxy.bus).send(&m) {
            Ok(_) => {
                proxy.wake[slot] = true;
                if T::TOPIC == Topic::Register {
                    self.registered.insert(id);
                }
                let t = monotonic_ns();
                let sent = m.send_ns();
                if sent != 0 && sent <= t {
                    record(&mut self.one_way, t - sent);
                }
                Put::Done
            }
            Err(_) if lossless => Put::Later,
            Err(_) => {
                self.report.link.dropped += 1;
                Put::Rejected
            }
        }
    }

    /// Drops proxies of robots the host reported gone, once their last frames are delivered.
    fn apply_gone(&mut self) {
        let delivered = self.inc.acked() - self.pending.len() as u64;
        for id in self.gone_after.due(delivered) {
            if self.gone.insert(id) {
                self.proxies.remove(&id);
            }
        }
    }

    /// Gives the host up when its robots have not all registered within `within` of its join:
    /// its proxies go, nothing more is taken from it, and its robot ids are returned for
    /// another host (or for the run to go on without them).
    fn expire_if_late(&mut self, now: Instant, within: Duration) -> Option<Vec<u32>> {
        let late = !self.expired
            && !self.lost()
            && self.registered.len() < self.ids.len()
            && now.duration_since(self.joined_at) >= within;
        if !late {
            return None;
        }
        report::log_line!(
            "qfleet: host {} did not start its robots {:?} within {within:?} of its join: its slots are open again",
            report::escape(&self.name),
            self.ids
        );
        self.expired = true;
        self.proxies.clear();
        self.gone.extend(self.ids.iter().copied());
        self.report.robots.clear();
        Some(self.ids.clone())
    }

    /// Reads what the coordinator sent through the proxies and publishes it to the host
    /// straight from the proxies' shared memory (one reused frame buffer; lossless frames are
    /// kept in the resend window's reused buffers).
    fn forward_down(&mut self, now: Instant) -> bool {
        if self.proxies.is_empty() || self.lost() || self.expired {
            return false;
        }
        let up = self.watch.state() == LinkState::Up;
        let Host {
            ids,
            tx,
            out,
            proxies,
            last_control,
            last_relay,
            name,
            ..
        } = self;
        let mut any = false;
        let mut overflow = None;
        for (i, proxy) in proxies.values().enumerate() {
            let reader = i == 0;
            drain::<Control>(&proxy.bus, |c| {
                let mine = c.robot_id == ROBOT_ID_ALL || ids.contains(&c.robot_id);
                if mine && last_control.is_none_or(|s| c.seq > s) {
                    *last_control = Some(c.seq);
                    any = true;
                    if let Err(e) = tx.lossless(up, out, c, now) {
                        overflow = Some(e);
                    }
                }
            });
            drain::<DiscoveryRelay>(&proxy.bus, |r| {
                if last_relay.is_none_or(|s| r.relay_seq > s) {
                    *last_relay = Some(r.relay_seq);
                    any = true;
                    if let Err(e) = tx.lossless(up, out, r, now) {
                        overflow = Some(e);
                    }
                }
            });
            drain::<MergedHintBatch>(&proxy.bus, |m| {
                if reader {
                    any = true;
                    tx.latest(up, m);
                }
            });
            drain::<DiscoveryAck>(&proxy.bus, |a| {
                if reader && ids.contains(&a.robot_id) {
                    any = true;
                    tx.latest(up, a);
                }
            });
        }
        if let Some(e) = overflow {
            report::log_line!("qfleet: warning: host {}: {e}", report::escape(name));
        }
        any
    }

    fn resend(&mut self, now: Instant, force: bool) {
        let up = self.watch.state() == LinkState::Up;
        self.tx.resend(up, &mut self.out, now, force);
    }

    /// Heartbeat, resends, and the link's state.
    fn tick(&mut self, now: Instant) {
        if self.lost() || self.expired {
            return;
        }
        match self.watch.tick(now) {
            Some(LinkEvent::WentDown) => report::log_line!(
                "qfleet: host {} is silent; its robots' lossless messages are kept for it",
                report::escape(&self.name)
            ),
            Some(LinkEvent::Lost) => {
                let ids: Vec<u32> = self.ids.clone();
                report::log_line!(
                    "qfleet: host {} silent for {:?}: given up, its robots {ids:?} are reported lost",
                    report::escape(&self.name),
                    self.deadline
                );
                self.proxies.clear();
                self.gone.extend(ids);
                return;
            }
            _ => {}
        }
        if now.duration_since(self.last_beat) >= HEARTBEAT_EVERY {
            self.last_beat = now;
            let hb = Heartbeat::at(
                monotonic_ns(),
                self.echo,
                self.inc.acked(),
                self.out.next_seq(),
                Vec::new(),
            );
            // heartbeats go even while the link looks down: they are how it comes back
            self.tx.send(true, &wire::heartbeat_frame(&hb));
        }
        self.resend(now, false);
    }

    /// Notifies the coordinator of what was written into the proxies; whether anything was.
    fn wake(&mut self) -> bool {
        let mut any = false;
        for p in self.proxies.values_mut() {
            let b = &p.bus;
            let w = std::mem::take(&mut p.wake);
            any |= w.contains(&true);
            let r = [
                w[0].then(|| b.register.notify()),
                w[1].then(|| b.state.notify()),
                w[2].then(|| b.discovery.notify()),
                w[3].then(|| b.hints.notify()),
                w[4].then(|| b.report.notify()),
            ];
            drop(r);
        }
        any
    }

    fn into_report(self) -> HostReport {
        let mut r = self.report;
        r.link.frames_out = self.tx.frames_out;
        r.state = Some(if self.expired {
            LinkState::Lost
        } else {
            self.watch.state()
        });
        r.link.reconnects = self.watch.reconnects;
        r.link.down_ms = self.watch.down_for.as_millis() as u64;
        r.link.clock_offset_ns = self.clock.offset_ns();
        r.link.best_rtt_ns = self.clock.best_rtt_ns().unwrap_or(0);
        r.link.rtt_ns = Percentiles::of(&self.rtt);
        r.link.one_way_in_ns = Percentiles::of(&self.one_way);
        r.link.resent = self.out.resent;
        r.link.duplicates = self.inc.duplicates;
        r
    }
}

/// Takes every message waiting in a proxy's inbox of `T`.
fn drain<T: ToRobot>(bus: &RobotBus, mut f: impl FnMut(&T)) {
    let _ = T::inbox(bus).drain(usize::MAX, |m| f(m));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{Heartbeat, heartbeat_frame, read_heartbeat};

    #[test]
    fn gone_reports_hold_one_entry_per_own_robot_whatever_a_peer_sends() {
        let own = [4, 5];
        let mut q = GoneQueue::default();
        let mut dropped = 0;
        // a flood of heartbeats naming the host's robots again and again, and others' ids
        for i in 0..10_000u64 {
            let hb = Heartbeat {
                sent: 1_000_000 + i,
                gone: vec![0, 4, 5, 6, 4, u32::MAX],
                ..Heartbeat::default()
            };
            let f = heartbeat_frame(&hb);
            let hb = read_heartbeat(&f[wire::HEADER..]).unwrap();
            dropped += q.report(hb.sent, &hb.gone, &own);
        }
        assert_eq!(q.waiting(), 2, "one entry per robot of the host");
        assert_eq!(dropped, 10_000 * 6 - 2);
        // nothing applies before the frames sent before the report are delivered
        assert!(q.due(999_999).is_empty());
        assert_eq!(q.due(1_000_000), vec![4, 5]);
        assert_eq!(q.waiting(), 0);
        // applied robots are not queued again
        assert_eq!(q.report(0, &[4], &own), 1);
        assert!(q.due(u64::MAX).is_empty());
    }
}
