//! The coordinator's side: admit joining hosts, stand in for their robots on this host's bus,
//! and carry every message across.
//!
//! The hub is a thread of `qfleet run` (and of `qfleet experiment`). For each remote robot it holds a **proxy**: a
//! [`RobotBus`] opened under the robot's own id, so its iceoryx2 node is named
//! `qfleet-robot-<id>` like the robot's would be. The coordinator therefore needs no change: it
//! admits, acks and watches remote robots exactly as local ones. A proxy publishes what its
//! robot sends over the link, and its subscribers receive what the coordinator sends; the hub
//! forwards that to the robot's host (control and acks only to the host whose robot is
//! addressed, broadcasts once per host; a shared grid's grants once per host, with the wake
//! the coordinator gave them). A proxy is dropped — its node disappears, and the
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
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, Grant, Intent, IntentHorizon,
    MergedHintBatch, PseudoTargetDiscovery, QHintBatch, ROBOT_ID_ALL, Register, RobotState, Topic,
};
use std::sync::mpsc::Receiver;

use bus::iceoryx2::prelude::{CallbackProgression, SignalHandlingMode, WaitSetBuilder, ipc};
use bus::{BusConfig, BusError, RobotBus, WakeListener, Waker, monotonic_ns, wake_pair};
use serde::Serialize;
use zenoh::Wait;
use zenoh::pubsub::Subscriber;
use zenoh::query::{Query, Queryable};
use zenoh::sample::Sample;

use crate::admit::AdmitList;
use crate::door::{DoorReport, Limits as DoorLimits};
use crate::end::{Got, LinkEnd, Meta, Put};
use crate::health::{ClockSync, LinkEvent, LinkState};
use crate::join::{Admission, Door, JOIN_KEY, JoinPlan, JoinReply, Knock, RefusedLog, RemotePlan};
use crate::link::{self, Tuning};
use crate::relay::FrontDoor;
use crate::seal::{self, Secret};
use crate::stats::{HostEntry, HostReport};
use crate::topics::{FromRobot, ToRobot};
use crate::{BridgeError, HEARTBEAT_EVERY};

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
    /// The run's join secret: only a host that proves it holds it is given slots.
    pub secret: Secret,
    /// Frames travel unsealed (`--insecure-plain`): a host still proves the secret to join.
    pub plain: bool,
    /// The front door's per-source limits on connections to `listen`.
    pub door: DoorLimits,
    /// How joining hosts reach the hub's Zenoh session ([`DoorMode::default`]: the door).
    pub door_mode: DoorMode,
}

/// How joining hosts reach the hub's Zenoh session.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DoorMode {
    /// The front door owns `listen`; a host that proves the join secret to it
    /// ([`crate::probe`]) is let through to the session's direct listener, a port of its own
    /// on the same address that drops every other source ([`crate::admit`]), and opens its
    /// session there; anything else that speaks Zenoh to `listen` is relayed as in
    /// [`Relay`](Self::Relay). If the direct listener cannot be closed to strangers (no
    /// `/proc`, no socket filters), the hub says so and runs as [`Relay`](Self::Relay).
    #[default]
    Direct,
    /// The front door owns `listen` and relays every admitted connection, byte for byte, to
    /// the session's loopback listener ([`FrontDoor`]): a second TCP hop and two more thread
    /// wake-ups per message (issue 36 item 7).
    Relay,
    /// No front door: the session listens on `listen` itself. No per-source limits, no probe
    /// answers; only for measuring what the door costs (`qfleet bench --cross-host`).
    Off,
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
    /// Join queries dropped before any slot was looked at: unreadable, or without a valid
    /// proof of the join secret (counted, their reasons not kept).
    pub unauthenticated: u64,
    /// Whether frames travelled unsealed (`--insecure-plain`).
    pub plain: bool,
    /// Frames on a key of no joined host.
    pub foreign_frames: u64,
    /// Hosts that joined but did not start their robots within `start_within`.
    pub expired_hosts: u32,
    /// Robot ids no host ran: the run went on without them.
    pub given_up: Vec<u32>,
    /// One entry per joined host.
    pub hosts: Vec<HostReport>,
    /// Peak resident memory of this host's launcher process (the hub runs in it) when the hub
    /// finished, KiB (`getrusage`): what strangers' floods did to host A's memory shows here.
    pub peak_rss_kib: u64,
    /// What the front door on `listen` admitted and refused, per reason and per source.
    pub door: DoorReport,
}

/// This process's peak resident memory so far, KiB (0 when it cannot be read).
fn peak_rss_kib() -> u64 {
    // SAFETY: getrusage fills a plain-old-data struct; zero is a valid initial value.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: a valid out-pointer.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) } != 0 {
        return 0;
    }
    u64::try_from(u.ru_maxrss).unwrap_or(0)
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
    /// The acceptor on `listen`, relaying to the session's loopback listener.
    door: Option<FrontDoor>,
}

impl Hub {
    /// Listens on `opts.listen` (an error at once if it cannot) through the front door, which
    /// relays what it admits to the hub's session on a loopback port, and starts the hub thread.
    pub fn start(opts: HubOptions) -> Result<Hub, BridgeError> {
        let at = link::listen_address(&opts.listen)?;
        let auth = link::SessionAuth::of(&opts.secret);
        let (session, door) = match opts.door_mode {
            DoorMode::Direct => {
                let (session, upstream, direct) =
                    link::listen_behind_door(opts.tuning, &auth, Some(at.ip()))?;
                // nobody knows the direct port yet: it is closed before the door tells anyone
                match direct.map(AdmitList::on) {
                    Some(Ok(list)) => {
                        let door = FrontDoor::open(
                            at,
                            upstream,
                            opts.door,
                            opts.secret.clone(),
                            Some(list),
                        )?;
                        (session, Some(door))
                    }
                    failed => {
                        // never leave a listener open that the door cannot close: start again
                        // with the relay only
                        let why = match failed {
                            Some(Err(e)) => e.to_string(),
                            _ => "no direct listener".into(),
                        };
                        report::log_line!(
                            "qfleet: the hub's direct listener could not be closed to strangers ({why}): joining hosts go through the front door's relay (slower)"
                        );
                        let _ = session.close().wait();
                        let (session, upstream) = link::listen_loopback(opts.tuning, &auth)?;
                        let door =
                            FrontDoor::open(at, upstream, opts.door, opts.secret.clone(), None)?;
                        (session, Some(door))
                    }
                }
            }
            DoorMode::Relay => {
                let (session, upstream) = link::listen_loopback(opts.tuning, &auth)?;
                let door = FrontDoor::open(at, upstream, opts.door, opts.secret.clone(), None)?;
                (session, Some(door))
            }
            DoorMode::Off => (link::listen(&opts.listen, opts.tuning, &auth)?, None),
        };
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
            door,
        })
    }

    /// Tells the joined hosts the run is over, drops every proxy and returns the report.
    pub fn finish(mut self) -> Result<HubReport, BridgeError> {
        self.stop.store(true, Ordering::SeqCst);
        self.waker.wake();
        let mut report = match self.thread.take() {
            Some(t) => t
                .join()
                .map_err(|_| BridgeError::Thread("the hub thread panicked".into()))??,
            None => HubReport::default(),
        };
        if let Some(door) = self.door.take() {
            report.door = door.finish();
            let d = &report.door;
            if d.refused() > 0 || d.silent > 0 {
                report::log_line!(
                    "qfleet: the front door on {} refused {} connection(s) ({} from a source holding its limit, {} too fast, {} past the global cap) and closed {} silent one(s)",
                    d.listen,
                    d.refused(),
                    d.refused_source_busy,
                    d.refused_source_rate,
                    d.refused_full,
                    d.silent
                );
            }
        }
        Ok(report)
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
    /// The Zenoh key its frames arrive on (derived from the join's keys).
    up_key: String,
    publisher: zenoh::pubsub::Publisher<'static>,
    end: LinkEnd,
    stand: Stand,
    /// Robots the host reported gone, applied once every frame it sent before is delivered.
    gone_after: GoneQueue,
    /// When it joined: a host that does not start its robots within `start_within` is given up.
    joined_at: Instant,
    expired: bool,
    last_control: Option<u64>,
    last_relay: Option<u64>,
    /// Shared grid: grants were forwarded to this host, so the coordinator's grant wakeups are
    /// looked at on every pass ([`Host::forward_down`]).
    grid: bool,
    /// The last grant forwarded, sent again with the wake flag when the coordinator's wakeup
    /// for it is seen only after the grant went (it notifies after it sends).
    last_grant: Grant,
    left: bool,
    deadline: Duration,
    report: HostReport,
}

/// A joined host's robots on this host's bus: their proxies, which registered, which are gone.
struct Stand {
    ids: Vec<u32>,
    proxies: BTreeMap<u32, Proxy>,
    registered: BTreeSet<u32>,
    gone: BTreeSet<u32>,
    /// Intents or horizons were written since the last [`Host::wake`]: the coordinator's
    /// grant (not always notified) answers them.
    answered: bool,
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
        .with(link::waking(64, waker.clone(), true))
        .wait()
        .map_err(zerr("declaring the join queryable"))?;
    let frames: Subscriber<Receiver<Sample>> = session
        .declare_subscriber(seal::UP_KEYS)
        .with(link::waking(link::SUBSCRIBER_DEPTH, waker, false))
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
    let mut door = Door::new(opts.secret.clone())?;
    let started = Instant::now();
    let mut hosts: Vec<Host> = Vec::new();
    let mut report = HubReport {
        listen: opts.listen.clone(),
        remote_robots: remote,
        plain: opts.plain,
        ..HubReport::default()
    };
    report::log_line!(
        "qfleet: waiting for {remote} robot(s) from other hosts on {}: run `qfleet join {} --robots N --secret-file join.secret` there (join.secret: this run's, copied from its out directory)",
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
            let at = Joining {
                session,
                opts,
                started,
            };
            at.answer(&q, &mut door, &mut admission, &mut hosts, &mut refused);
        }
        // frames from the joined hosts
        for _ in 0..4096 {
            let Ok(sample) = frames.try_recv() else {
                break;
            };
            busy = true;
            let key = sample.key_expr().as_str();
            match hosts.iter_mut().find(|h| h.up_key == key) {
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
            .map(|h| h.end.next_beat())
            .min()
            .unwrap_or(now + HEARTBEAT_EVERY);
        let Some(timeout) = link::rest(pacing.after_pass(now, busy, data, due)) else {
            continue;
        };
        // one proxy's inboxes are enough to hear the coordinator: a notify wakes every
        // listener of a topic, and every proxy subscribes to every coordinator topic
        let anchor = hosts.iter().find_map(|h| h.stand.proxies.values().next());
        // (its grant wakeups are consumed by `forward_down`, which needs to see them)
        let guards = match anchor {
            Some(p) => p
                .bus
                .listeners()
                .into_iter()
                .map(|(_, l)| l)
                .chain([p.bus.grant.listener()])
                .map(|l| waitset.attach_notification(l).map_err(waitset_error))
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
        host.end.goodbye(&mut host.publisher);
    }
    report.joined_robots = hosts
        .iter()
        .filter(|h| !h.expired)
        .map(|h| h.stand.ids.len() as u32)
        .sum();
    report.refused_total = refused.total;
    report.unauthenticated = door.unauthenticated;
    report.refused = refused.reasons;
    report.hosts = hosts.into_iter().map(Host::into_report).collect();
    report.peak_rss_kib = peak_rss_kib();
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

/// What answering a join needs of the hub.
struct Joining<'a> {
    session: &'a zenoh::Session,
    opts: &'a HubOptions,
    started: Instant,
}

impl Joining<'_> {
    /// Answers one join query: a challenge to a hello; to a join that proves the secret, a slot
    /// decision; anything else is dropped and counted ([`Door`]) without a slot looked at.
    fn answer(
        &self,
        q: &Query,
        door: &mut Door,
        admission: &mut Admission,
        hosts: &mut Vec<Host>,
        refused: &mut RefusedLog,
    ) {
        let reply = |r: &JoinReply| {
            let body = serde_json::to_vec(r).unwrap_or_default();
            if let Err(e) = q.reply(JOIN_KEY, body).wait() {
                report::log_line!("qfleet: warning: answering a join: {e}");
            }
        };
        let payload = q.payload().map(|p| p.to_bytes()).unwrap_or_default();
        let now_ms = self.started.elapsed().as_millis() as u64;
        let (req, keys) = match door.knock(&payload, now_ms) {
            Knock::Answer(r) => return reply(&r),
            Knock::Proven { request, keys } => (request, keys),
        };
        let opts = self.opts;
        let plan = &opts.plan;
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
        let publisher = match link::publisher(self.session, keys.down_key(index), opts.tuning) {
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
            plain: opts.plain,
        };
        let body = serde_json::to_vec(&accepted).unwrap_or_default();
        reply(&JoinReply::Accepted {
            plan: seal::hex(&keys.seal_plan(&body)),
        });
        report::log_line!(
            "qfleet: host {} joined with robots {ids:?} ({} of {} remote robots now)",
            report::escape(&req.host),
            plan.robots_total - plan.first_remote - admission.open_slots(),
            plan.robots_total - plan.first_remote
        );
        let sealed = (!opts.plain).then(|| keys.hub_end(index));
        hosts.push(Host {
            report: HostReport {
                host: req.host.clone(),
                robots: ids.clone(),
                ..HostReport::default()
            },
            name: req.host,
            stand: Stand {
                ids,
                proxies: BTreeMap::new(),
                registered: BTreeSet::new(),
                gone: BTreeSet::new(),
                answered: false,
            },
            up_key: keys.up_key(index),
            publisher,
            end: LinkEnd::new(
                now,
                opts.down_after,
                opts.deadline,
                ClockSync::default(),
                sealed,
            ),
            gone_after: GoneQueue::default(),
            joined_at: now,
            expired: false,
            last_control: None,
            last_relay: None,
            grid: false,
            last_grant: Grant::ZEROED,
            left: false,
            deadline: opts.deadline,
        });
    }
}

impl Host {
    fn lost(&self) -> bool {
        self.end.lost()
    }

    fn on_frame(&mut self, frame: &[u8], now: Instant, cfg: &BusConfig) {
        if self.lost() || self.expired {
            return;
        }
        let stand = &mut self.stand;
        let (got, came_back) = self.end.on_frame(
            frame,
            now,
            monotonic_ns(),
            &mut self.publisher,
            |topic, b, meta| stand.put(topic, b, meta, cfg),
        );
        if came_back {
            report::log_line!(
                "qfleet: host {} is back; resending what it missed",
                report::escape(&self.name)
            );
        }
        match got {
            Got::Nothing => {}
            Got::Gone { after, ids } => {
                self.end.counts.capped += self.gone_after.report(after, &ids, &self.stand.ids);
            }
            Got::Goodbye { after } => {
                self.left = true;
                let ids = self.stand.ids.clone();
                self.gone_after.report(after, &ids, &ids);
            }
        }
    }

    /// Writes the in-order lossless frames into the bus until one has to wait.
    fn deliver_in_order(&mut self, cfg: &BusConfig) -> bool {
        let stand = &mut self.stand;
        self.end.deliver(monotonic_ns(), |topic, b, meta| {
            stand.put(topic, b, meta, cfg)
        })
    }

    /// Drops proxies of robots the host reported gone, once their last frames are delivered.
    fn apply_gone(&mut self) {
        for id in self.gone_after.due(self.end.delivered()) {
            if self.stand.gone.insert(id) {
                self.stand.proxies.remove(&id);
            }
        }
    }

    /// Gives the host up when its robots have not all registered within `within` of its join:
    /// its proxies go, nothing more is taken from it, and its robot ids are returned for
    /// another host (or for the run to go on without them).
    fn expire_if_late(&mut self, now: Instant, within: Duration) -> Option<Vec<u32>> {
        let stand = &mut self.stand;
        let late = !self.expired
            && !self.end.lost()
            && stand.registered.len() < stand.ids.len()
            && now.duration_since(self.joined_at) >= within;
        if !late {
            return None;
        }
        report::log_line!(
            "qfleet: host {} did not start its robots {:?} within {within:?} of its join: its slots are open again",
            report::escape(&self.name),
            stand.ids
        );
        self.expired = true;
        stand.proxies.clear();
        stand.gone.extend(stand.ids.iter().copied());
        self.report.robots.clear();
        Some(stand.ids.clone())
    }

    /// Reads what the coordinator sent through the proxies and publishes it to the host
    /// straight from the proxies' shared memory (one reused frame buffer; lossless frames are
    /// kept in the resend window's reused buffers).
    ///
    /// Grants carry the coordinator's wake: it notifies only the grants the robots must answer
    /// (the rest they read when they look), and it sends before it notifies. So the reader
    /// proxy's grant wakeups are consumed *before* its grants are drained: a wakeup seen means
    /// its grant is drained now or went before; the grants drained with it go flagged, and if
    /// none is drained the last one goes again, flagged (a robot answers a tick once: the copy
    /// only wakes it). The first grants wake too. A spurious wake costs a look; a missed one
    /// would cost a robot's 10 ms poll.
    fn forward_down(&mut self, now: Instant) -> bool {
        if self.stand.proxies.is_empty() || self.lost() || self.expired {
            return false;
        }
        let Host {
            stand,
            end,
            publisher,
            last_control,
            last_relay,
            name,
            grid,
            last_grant,
            ..
        } = self;
        let ids = &stand.ids;
        let mut any = false;
        let mut overflow = None;
        for (i, proxy) in stand.proxies.values().enumerate() {
            let reader = i == 0;
            // the grant's wake, looked at before its grants (see above); nothing to look at
            // before the first grant (a run on separate maps never pays for it)
            let owed = reader
                && (*grid || proxy.bus.grant.has_samples().unwrap_or(false))
                && proxy.bus.grant.clear_wakeups().is_ok_and(|w| w.data > 0);
            drain::<Control>(&proxy.bus, |c| {
                let mine = c.robot_id == ROBOT_ID_ALL || ids.contains(&c.robot_id);
                if mine && last_control.is_none_or(|s| c.seq > s) {
                    *last_control = Some(c.seq);
                    any = true;
                    if let Err(e) = end.send_lossless(c, now, publisher) {
                        overflow = Some(e);
                    }
                }
            });
            drain::<DiscoveryRelay>(&proxy.bus, |r| {
                if last_relay.is_none_or(|s| r.relay_seq > s) {
                    *last_relay = Some(r.relay_seq);
                    any = true;
                    if let Err(e) = end.send_lossless(r, now, publisher) {
                        overflow = Some(e);
                    }
                }
            });
            drain::<MergedHintBatch>(&proxy.bus, |m| {
                if reader {
                    any = true;
                    end.send_latest(m, publisher);
                }
            });
            drain::<DiscoveryAck>(&proxy.bus, |a| {
                if reader && ids.contains(&a.robot_id) {
                    any = true;
                    end.send_latest(a, publisher);
                }
            });
            let first = !*grid;
            let mut granted = false;
            drain::<Grant>(&proxy.bus, |g| {
                if reader {
                    any = true;
                    granted = true;
                    *grid = true;
                    *last_grant = *g;
                    if let Err(e) = end.send(g, owed || first, now, publisher) {
                        overflow = Some(e);
                    }
                }
            });
            if owed && !granted {
                any = true;
                if let Err(e) = end.send(last_grant, true, now, publisher) {
                    overflow = Some(e);
                }
            }
        }
        if let Some(e) = overflow {
            report::log_line!("qfleet: warning: host {}: {e}", report::escape(name));
        }
        any
    }

    /// Heartbeat, resends, and the link's state.
    fn tick(&mut self, now: Instant) {
        if self.lost() || self.expired {
            return;
        }
        match self.end.tick(now, monotonic_ns(), &[], &mut self.publisher) {
            Some(LinkEvent::WentDown) => report::log_line!(
                "qfleet: host {} is silent; its robots' lossless messages are kept for it",
                report::escape(&self.name)
            ),
            Some(LinkEvent::Lost) => {
                let ids: Vec<u32> = self.stand.ids.clone();
                report::log_line!(
                    "qfleet: host {} silent for {:?}: given up, its robots {ids:?} are reported lost",
                    report::escape(&self.name),
                    self.deadline
                );
                self.stand.proxies.clear();
                self.stand.gone.extend(ids);
            }
            _ => {}
        }
    }

    /// Notifies the coordinator of what was written into the proxies; whether anything was
    /// (intents and horizons are not notified: the coordinator polls for them while it
    /// collects a tick, and answers with a grant).
    fn wake(&mut self) -> bool {
        let mut any = std::mem::take(&mut self.stand.answered);
        for p in self.stand.proxies.values_mut() {
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
        self.end.report(&mut r);
        if self.expired {
            r.state = Some(LinkState::Lost);
        }
        r
    }
}

impl Stand {
    /// Writes a robot's message into its proxy (opened on its first message); `meta.shift`
    /// moves its times onto this host's clock.
    fn put(&mut self, topic: Topic, payload: &[u8], meta: Meta, cfg: &BusConfig) -> Put {
        match topic {
            Topic::Register => self.put_as::<Register>(payload, meta, cfg, Some(0)),
            Topic::RobotState => self.put_as::<RobotState>(payload, meta, cfg, Some(1)),
            Topic::Discovery => self.put_as::<PseudoTargetDiscovery>(payload, meta, cfg, Some(2)),
            Topic::Hints => self.put_as::<QHintBatch>(payload, meta, cfg, Some(3)),
            Topic::Report => self.put_as::<FinalReport>(payload, meta, cfg, Some(4)),
            // polled by the coordinator while it collects a tick: no wakeup
            Topic::Intent => self.put_as::<Intent>(payload, meta, cfg, None),
            Topic::Horizon => self.put_as::<IntentHorizon>(payload, meta, cfg, None),
            // coordinator topics never come from a joined host
            _ => Put::Rejected,
        }
    }

    /// Reads a `T` from `payload` and checks it: readable, in a shape a robot writes
    /// ([`Checked`]), and from a robot of this host. `None` when not.
    fn read<T: FromRobot>(&self, payload: &[u8], fleet: u32) -> Option<T> {
        let mut m = T::default();
        let ok = crate::wire::read_into(payload, &mut m).is_ok()
            && m.check(fleet).is_ok()
            && self.ids.contains(&m.robot_id());
        // a robot of another host (or of this one) cannot be impersonated from there
        ok.then_some(m)
    }

    fn put_as<T: FromRobot>(
        &mut self,
        payload: &[u8],
        meta: Meta,
        cfg: &BusConfig,
        slot: Option<usize>,
    ) -> Put {
        let Some(mut m) = self.read::<T>(payload, cfg.robots) else {
            return Put::Rejected;
        };
        m.shift(meta.shift);
        let id = m.robot_id();
        if self.gone.contains(&id) {
            return Put::Skipped;
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
        match T::outbox(&proxy.bus).send(&m) {
            Ok(_) => {
                match slot {
                    Some(i) => proxy.wake[i] = true,
                    None => self.answered = true,
                }
                if T::TOPIC == Topic::Register {
                    self.registered.insert(id);
                }
                Put::Done {
                    sent_ns: m.send_ns(),
                }
            }
            Err(_) if T::TOPIC.delivery() == bus::bus_schema::Delivery::Lossless => Put::Later,
            Err(_) => Put::Dropped,
        }
    }
}

/// Takes every message waiting in a proxy's inbox of `T`.
fn drain<T: ToRobot>(bus: &RobotBus, mut f: impl FnMut(&T)) {
    let _ = T::inbox(bus).drain(usize::MAX, |m| f(m));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{HEADER, Heartbeat, heartbeat_frame, read_heartbeat};

    #[test]
    fn a_host_speaks_only_for_its_own_robots_and_only_in_shapes_they_write() {
        use bus::bus_schema::{Intent, IntentHorizon};
        let cfg = BusConfig::new("hub-stand-test".to_string(), 8).unwrap();
        let mut stand = Stand {
            ids: vec![4, 5],
            proxies: BTreeMap::new(),
            registered: BTreeSet::new(),
            gone: BTreeSet::new(),
            answered: false,
        };
        let frame = |m: &dyn Fn(&mut Vec<u8>)| {
            let mut f = Vec::new();
            m(&mut f);
            f
        };
        let intent = |robot_id, count| Intent {
            robot_id,
            count,
            ranked: [1, 0, 0, 0, 0],
            ..Intent::ZEROED
        };
        for (what, m) in [
            ("a robot of this host", intent(0, 1)),
            ("a robot of another host", intent(6, 1)),
            ("a robot outside the fleet", intent(9, 1)),
            ("a robot of the host, with no move", intent(4, 0)),
        ] {
            let f = frame(&|f| crate::wire::write_data_frame(f, &m, 0));
            let put = stand.put(Topic::Intent, &f[HEADER..], Meta::default(), &cfg);
            assert_eq!(put, Put::Rejected, "{what}");
        }
        let h = IntentHorizon {
            robot_id: 5,
            radius: 9,
            ..IntentHorizon::ZEROED
        };
        let f = frame(&|f| crate::wire::write_data_frame(f, &h, 0));
        assert_eq!(
            stand.put(Topic::Horizon, &f[HEADER..], Meta::default(), &cfg),
            Put::Rejected
        );
        // a grant never comes from a joined host
        let f = frame(&|f| crate::wire::write_data_frame(f, &bus::bus_schema::Grant::ZEROED, 0));
        assert_eq!(
            stand.put(Topic::Grant, &f[HEADER..], Meta::default(), &cfg),
            Put::Rejected
        );
        assert!(
            stand.proxies.is_empty() && !stand.answered,
            "nothing reached the bus"
        );
    }

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
            let hb = read_heartbeat(&f[crate::wire::HEADER..]).unwrap();
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
