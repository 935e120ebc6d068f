//! The two typed endpoints: everything the coordinator or a robot needs, made by one call.

use std::cell::{Cell, RefCell};
use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus_schema::names::Topic;
use bus_schema::{
    Command, Control, DiscoveryAck, DiscoveryRelay, FinalReport, Grant, Intent, IntentHorizon,
    MergedHintBatch, PseudoTargetDiscovery, QHintBatch, ROBOT_ID_ALL, Register, RobotState,
    SCHEMA_VERSION,
};
use iceoryx2::identifiers::UniquePublisherId;
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;

use crate::clock::monotonic_ns;
use crate::files::{no_space, restrict_run_files, shm_exhausted};
use crate::handshake::{Admission, Expected, check_register, control, reason, set_reason};
use crate::liveness::{CleanReport, clean_stale};
use crate::topic::{Inbox, Outbox, Role, Wakeups};
use crate::{BusConfig, BusError, SendError};

/// How often a robot re-sends its `Register` while no answer has come.
const REGISTER_RESEND: Duration = Duration::from_millis(250);

/// Longest single sleep inside the handshake loops (they re-check their deadline after it).
const HANDSHAKE_TICK: Duration = Duration::from_millis(20);

/// The coordinator's side of a run: subscribers for all robot→coordinator topics, publishers
/// for all coordinator→robot topics, each with its wake event port.
///
/// Fields are public so a caller can borrow several at once (e.g. attach the inbox listeners to
/// a `WaitSet` while publishing). Like all iceoryx2 `ipc` ports it stays on the thread that
/// created it.
pub struct CoordinatorBus {
    /// Robot registrations (lossless).
    pub register: Inbox<Register>,
    /// Robot progress (latest-wins).
    pub state: Inbox<RobotState>,
    /// Pseudo-target discoveries (lossless).
    pub discovery: Inbox<PseudoTargetDiscovery>,
    /// Q-hint batches (latest-wins).
    pub hints: Inbox<QHintBatch>,
    /// Final reports (lossless).
    pub report: Inbox<FinalReport>,
    /// Shared grid: the robots' ranked moves, one per tick (latest-wins).
    pub intent: Inbox<Intent>,
    /// Shared grid: the robots' rankings for their next few ticks (latest-wins).
    pub horizon: Inbox<IntentHorizon>,
    /// Commands to robots (lossless); prefer [`CoordinatorBus::send_control`].
    pub control: Outbox<Control>,
    /// Merged hints to all robots (latest-wins).
    pub merged: Outbox<MergedHintBatch>,
    /// Cumulative discovery acks (latest-wins).
    pub ack: Outbox<DiscoveryAck>,
    /// Discoveries relayed to every robot (lossless).
    pub relay: Outbox<DiscoveryRelay>,
    /// Shared grid: every robot's granted cell, one per tick (latest-wins, broadcast).
    pub grant: Outbox<Grant>,
    control_seq: Cell<u64>,
    /// When the last `Ack` to each robot id was sent (monotonic ns), to skip re-acks of stale
    /// registration re-sends.
    acked_ns: RefCell<BTreeMap<u32, u64>>,
    config: BusConfig,
    // Declared last so it is dropped after every port.
    node: Node<ipc::Service>,
}

impl CoordinatorBus {
    /// Creates the coordinator's node and every service of the run, sized for the fleet.
    ///
    /// Subscribers are created before anything else happens, so they exist before any robot
    /// can publish (the first half of the start handshake).
    pub fn create(config: &BusConfig) -> Result<Self, BusError> {
        // a fleet past the open-file limit fails here, clearly, not robot by robot later
        crate::limits::check_open_files(config.robots)?;
        let node = config.create_node(bus_schema::COORDINATOR_NODE_NAME)?;
        let r = Role::Creator;
        let bus = Self::create_ports(config, node, r).map_err(|e| explain_no_space(config, e))?;
        // the services' files exist now: narrow them to this user before any robot starts
        restrict_run_files(&config.prefix())?;
        // and their pages reserved: a /dev/shm filled later is never a SIGBUS here
        crate::commit_run_shm(&config.prefix())?;
        Ok(bus)
    }

    fn create_ports(
        config: &BusConfig,
        node: Node<ipc::Service>,
        r: Role,
    ) -> Result<Self, BusError> {
        Ok(Self {
            register: Inbox::create(&node, config, r)?,
            state: Inbox::create(&node, config, r)?,
            discovery: Inbox::create(&node, config, r)?,
            hints: Inbox::create(&node, config, r)?,
            report: Inbox::create(&node, config, r)?,
            intent: Inbox::create(&node, config, r)?,
            horizon: Inbox::create(&node, config, r)?,
            control: Outbox::create(&node, config, r)?,
            merged: Outbox::create(&node, config, r)?,
            ack: Outbox::create(&node, config, r)?,
            relay: Outbox::create(&node, config, r)?,
            grant: Outbox::create(&node, config, r)?,
            control_seq: Cell::new(0),
            acked_ns: RefCell::new(BTreeMap::new()),
            config: config.clone(),
            node,
        })
    }

    /// The configuration the run was created with.
    pub fn config(&self) -> &BusConfig {
        &self.config
    }

    /// The coordinator's iceoryx2 node.
    pub fn node(&self) -> &Node<ipc::Service> {
        &self.node
    }

    /// Connects every port to peers that appeared since; after this, lossless topics from every
    /// robot whose publishers already exist are guaranteed lossless.
    pub fn connect_all(&self) -> Result<(), BusError> {
        self.register.connect()?;
        self.state.connect()?;
        self.discovery.connect()?;
        self.hints.connect()?;
        self.report.connect()?;
        self.intent.connect()?;
        self.horizon.connect()?;
        self.control.connect()?;
        self.merged.connect()?;
        self.ack.connect()?;
        self.relay.connect()?;
        self.grant.connect()
    }

    /// Sends a control message (seq, time and schema version filled in) and wakes the robots;
    /// returns the number of robots reached.
    pub fn send_control(&self, mut ctl: Control) -> Result<usize, BusError> {
        ctl.seq = self.control_seq.get();
        ctl.schema_version = SCHEMA_VERSION;
        ctl.time_ns = monotonic_ns();
        let n = self.control.send(&ctl)?;
        self.control_seq.set(ctl.seq + 1);
        self.control.notify()?;
        Ok(n)
    }

    /// Sends `Start` to `robot_id` (or `ROBOT_ID_ALL`) with the episode count (0 = keep).
    pub fn start(&self, robot_id: u32, episodes: u32) -> Result<usize, BusError> {
        self.send_control(Control {
            episodes,
            ..control(Command::Start, robot_id)
        })
    }

    /// Sends `Stop` to `robot_id` (or `ROBOT_ID_ALL`).
    pub fn stop(&self, robot_id: u32) -> Result<usize, BusError> {
        self.send_control(control(Command::Stop, robot_id))
    }

    /// Sends `Refuse` with a readable reason to `robot_id`.
    pub fn refuse(&self, robot_id: u32, why: &str) -> Result<usize, BusError> {
        let mut ctl = control(Command::Refuse, robot_id);
        set_reason(&mut ctl, why);
        self.send_control(ctl)
    }

    /// Decides about one `Register`, answers the robot (`Ack` or `Refuse`) and records it.
    ///
    /// Before acknowledging it connects all subscribers, so the robot's lossless topics are
    /// connected by the time it can learn it was accepted.
    ///
    /// A repeated registration of an accepted robot (same id and pid) that the robot sent
    /// *before* its last `Ack` went out is a re-send that crossed that `Ack`: the `Ack` is
    /// already in the robot's (lossless, connected) buffer, so it is not acknowledged again
    /// ([`Admission::Reaccepted`] all the same). On a loaded machine the coordinator drains
    /// such re-sends in bulk, and re-acking each one broadcast up to 4 `Ack`s per robot
    /// through every robot's control buffer (issue 10 #11). A registration sent after the
    /// last `Ack` (the robot asks again) is answered.
    pub fn admit(
        &self,
        reg: &Register,
        expected: &Expected,
        accepted: &mut BTreeMap<u32, Register>,
    ) -> Result<Admission, BusError> {
        let verdict = match (check_register(reg, expected), accepted.get(&reg.robot_id)) {
            (Err(why), _) => Err(why),
            (Ok(()), Some(prev)) if prev.pid != reg.pid => Err(format!(
                "robot id {} already taken by pid {}",
                reg.robot_id, prev.pid
            )),
            (Ok(()), Some(_)) => {
                let last = self.acked_ns.borrow().get(&reg.robot_id).copied();
                if last.is_some_and(|t| reg.send_time_ns < t) {
                    // a re-send that crossed our Ack: that Ack answers it, send nothing
                    return Ok(Admission::Reaccepted);
                }
                // asked again after our last Ack: answer again (below)
                Ok(Admission::Reaccepted)
            }
            (Ok(()), None) => Ok(Admission::Accepted),
        };
        match verdict {
            Err(why) => {
                match self.refuse(reg.robot_id, &why) {
                    // the refused robot (and every other) is already gone: nobody to tell
                    Ok(_) | Err(BusError::Send(SendError::NoSubscriber { .. })) => {}
                    Err(e) => return Err(e),
                }
                Ok(Admission::Refused(why))
            }
            Ok(admission) => {
                self.connect_all()?;
                let ack = control(Command::Ack, reg.robot_id);
                match self.send_control(ack) {
                    Ok(_) => {
                        self.acked_ns.borrow_mut().insert(reg.robot_id, ack.time_ns);
                        accepted.insert(reg.robot_id, *reg);
                        Ok(admission)
                    }
                    Err(BusError::Send(SendError::NoSubscriber { .. })) => Ok(Admission::Gone),
                    Err(e) => Err(e),
                }
            }
        }
    }

    /// Runs the coordinator's half of the start handshake: admits registrations until all
    /// `expected.robots` robots are accepted, refusing mismatched ones; returns them by id.
    ///
    /// Send goal assignments and then [`start`](Self::start) afterwards; robots publish
    /// learning traffic only after `Start`.
    pub fn accept_fleet(
        &self,
        expected: &Expected,
        timeout: Duration,
    ) -> Result<BTreeMap<u32, Register>, BusError> {
        let deadline = Instant::now() + timeout;
        let mut accepted = BTreeMap::new();
        while (accepted.len() as u32) < expected.robots {
            while let Some(reg) = self.register.receive()? {
                self.admit(&reg, expected, &mut accepted)?;
            }
            if (accepted.len() as u32) >= expected.robots {
                break;
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(BusError::Timeout {
                    what: format!(
                        "{} of {} robots to register (have {:?})",
                        expected.robots - accepted.len() as u32,
                        expected.robots,
                        accepted.keys().collect::<Vec<_>>()
                    ),
                    timeout,
                });
            }
            self.register.wait((deadline - now).min(HANDSHAKE_TICK))?;
        }
        Ok(accepted)
    }

    /// The wake listeners of the five inboxes, to build a `WaitSet` or block on one.
    pub fn listeners(&self) -> [(Topic, &Listener<ipc::Service>); 5] {
        [
            (Topic::Register, self.register.listener()),
            (Topic::RobotState, self.state.listener()),
            (Topic::Discovery, self.discovery.listener()),
            (Topic::Hints, self.hints.listener()),
            (Topic::Report, self.report.listener()),
        ]
    }

    /// Attaches every inbox listener to `waitset` (for the `event` and `hybrid` strategies);
    /// keep the returned guards alive as long as the attachment should last.
    pub fn attach_all<'w, 'a>(
        &'a self,
        waitset: &'w WaitSet<ipc::Service>,
    ) -> Result<Vec<WaitSetGuard<'w, 'a, ipc::Service>>, BusError> {
        self.listeners()
            .into_iter()
            .map(|(topic, l)| {
                waitset.attach_notification(l).map_err(|e| BusError::Event {
                    service: topic.wake_service_name(&self.config.run_id),
                    detail: format!("cannot attach to the WaitSet: {e:?}"),
                })
            })
            .collect()
    }

    /// Shuts the coordinator's side down and, if no other process of the run is still alive,
    /// removes every file the run left (see [`crate::clean_stale`]).
    pub fn close(self) -> Result<CleanReport, BusError> {
        let prefix = self.config.prefix();
        drop(self);
        clean_stale(&prefix)
    }

    /// Consumes the pending wakeups of all five inboxes (call after a `WaitSet` wakeup, or it
    /// fires again); returns them summed.
    pub fn clear_wakeups(&self) -> Result<Wakeups, BusError> {
        let mut all = Wakeups::default();
        for w in [
            self.register.clear_wakeups()?,
            self.state.clear_wakeups()?,
            self.discovery.clear_wakeups()?,
            self.hints.clear_wakeups()?,
            self.report.clear_wakeups()?,
        ] {
            all.data += w.data;
            all.peer_dead |= w.peer_dead;
        }
        Ok(all)
    }

    /// Whether any inbox holds a message (what a spinning coordinator polls).
    pub fn has_samples(&self) -> Result<bool, BusError> {
        Ok(self.register.has_samples()?
            || self.state.has_samples()?
            || self.discovery.has_samples()?
            || self.hints.has_samples()?
            || self.report.has_samples()?)
    }
}

/// A robot's side of a run: publishers for all robot→coordinator topics, subscribers for all
/// coordinator→robot topics, each with its wake event port.
pub struct RobotBus {
    /// Registration (lossless); prefer [`RobotBus::register`].
    pub register: Outbox<Register>,
    /// Progress (latest-wins).
    pub state: Outbox<RobotState>,
    /// Discoveries (lossless).
    pub discovery: Outbox<PseudoTargetDiscovery>,
    /// Q-hint batches (latest-wins).
    pub hints: Outbox<QHintBatch>,
    /// Final report (lossless).
    pub report: Outbox<FinalReport>,
    /// Shared grid: this robot's ranked moves, one per tick (latest-wins).
    pub intent: Outbox<Intent>,
    /// Shared grid: this robot's rankings for the cells of its next few ticks (latest-wins).
    pub horizon: Outbox<IntentHorizon>,
    /// Commands (lossless, broadcast); prefer [`RobotBus::recv_control`], which filters.
    pub control: Inbox<Control>,
    /// Merged hints (latest-wins, broadcast).
    pub merged: Inbox<MergedHintBatch>,
    /// Discovery acks (latest-wins, broadcast: check `robot_id`).
    pub ack: Inbox<DiscoveryAck>,
    /// Discoveries of other robots relayed by the coordinator (lossless, broadcast).
    pub relay: Inbox<DiscoveryRelay>,
    /// Shared grid: every robot's granted cell, one per tick (latest-wins, broadcast).
    pub grant: Inbox<Grant>,
    robot_id: u32,
    /// Controls read during `register` before its answer, with their publisher.
    pending: RefCell<VecDeque<(Control, Origin)>>,
    /// The publisher whose `Ack` answered the last `register` (the coordinator's control port).
    accepted_by: Cell<Option<Origin>>,
    config: BusConfig,
    // Declared last so it is dropped after every port.
    node: Node<ipc::Service>,
}

impl RobotBus {
    /// Creates the robot's node and opens the run's services, waiting up to `wait` for the
    /// coordinator to create them.
    ///
    /// Subscribers are opened before publishers and nothing is published, so the coordinator
    /// can connect to this robot before it sends anything (the start handshake).
    pub fn open(config: &BusConfig, robot_id: u32, wait: Duration) -> Result<Self, BusError> {
        Self::open_until(config, robot_id, wait, &AtomicBool::new(false))
    }

    /// [`RobotBus::open`] that gives up with [`BusError::Interrupted`] when `stop` is set
    /// (SIGINT/SIGTERM while the coordinator's services do not exist yet, or while a stopping
    /// coordinator removes them).
    pub fn open_until(
        config: &BusConfig,
        robot_id: u32,
        wait: Duration,
        stop: &AtomicBool,
    ) -> Result<Self, BusError> {
        if robot_id >= config.robots {
            return Err(BusError::InvalidConfig(format!(
                "robot id {robot_id} outside 0..{}",
                config.robots
            )));
        }
        let node = config.create_robot_node(&bus_schema::robot_node_name(robot_id))?;
        let deadline = Instant::now() + wait;
        loop {
            match Self::open_ports(&node, config, robot_id) {
                Ok(ports) => {
                    restrict_run_files(&config.prefix())?;
                    crate::commit_run_shm(&config.prefix())?;
                    return Ok(ports.with_node(node));
                }
                Err(_) if stop.load(Ordering::Relaxed) => return Err(BusError::Interrupted),
                Err(BusError::ServiceMissing { service }) => {
                    if Instant::now() >= deadline {
                        return Err(BusError::Timeout {
                            what: format!("the coordinator to create {service:?}"),
                            timeout: wait,
                        });
                    }
                    std::thread::sleep(HANDSHAKE_TICK);
                }
                Err(e) => return Err(explain_no_space(config, e)),
            }
        }
    }

    fn open_ports(
        node: &Node<ipc::Service>,
        config: &BusConfig,
        robot_id: u32,
    ) -> Result<RobotPorts, BusError> {
        let r = Role::Opener;
        let control = Inbox::create(node, config, r)?;
        let merged = Inbox::create(node, config, r)?;
        let ack = Inbox::create(node, config, r)?;
        let relay = Inbox::create(node, config, r)?;
        let grant = Inbox::create(node, config, r)?;
        Ok(RobotPorts {
            register: Outbox::create(node, config, r)?,
            state: Outbox::create(node, config, r)?,
            discovery: Outbox::create(node, config, r)?,
            hints: Outbox::create(node, config, r)?,
            report: Outbox::create(node, config, r)?,
            intent: Outbox::create(node, config, r)?,
            horizon: Outbox::create(node, config, r)?,
            control,
            merged,
            ack,
            relay,
            grant,
            robot_id,
            config: config.clone(),
        })
    }

    /// This robot's id.
    pub fn robot_id(&self) -> u32 {
        self.robot_id
    }

    /// The run's configuration.
    pub fn config(&self) -> &BusConfig {
        &self.config
    }

    /// The robot's iceoryx2 node.
    pub fn node(&self) -> &Node<ipc::Service> {
        &self.node
    }

    /// Registers and waits for the coordinator's answer: `Ok(Ack)`, or
    /// [`BusError::Refused`] with the coordinator's reason.
    ///
    /// Re-sends the registration every 250 ms until answered (the coordinator re-acks a
    /// repeated registration from the same pid), so start order does not matter. `send_time_ns`
    /// is filled in.
    pub fn register(&self, reg: &Register, timeout: Duration) -> Result<Control, BusError> {
        let deadline = Instant::now() + timeout;
        // answers to an earlier registration (re-sends are answered too) are older than this
        let asked_ns = monotonic_ns();
        let mut last_sent: Option<Instant> = None;
        loop {
            if last_sent.is_none_or(|t| t.elapsed() >= REGISTER_RESEND) {
                last_sent = Some(Instant::now());
                let sent = self.register.send_with(|m| {
                    *m = *reg;
                    m.send_time_ns = monotonic_ns();
                });
                match sent {
                    Ok(_) => {
                        self.register.notify()?;
                    }
                    // the coordinator's subscriber is not there yet: try again later
                    Err(SendError::NoSubscriber { .. }) => {}
                    Err(e) => return Err(e.into()),
                }
            }
            while let Some((ctl, from)) = self.next_control_from_bus()? {
                let answer = ctl.robot_id == self.robot_id && ctl.time_ns >= asked_ns;
                match Command::try_from(ctl.command) {
                    Ok(Command::Ack | Command::Refuse) if !answer => {}
                    Ok(Command::Ack) => {
                        if ctl.schema_version != SCHEMA_VERSION {
                            return Err(BusError::Refused {
                                robot_id: self.robot_id,
                                reason: format!(
                                    "coordinator speaks schema v{}, this robot v{SCHEMA_VERSION}",
                                    ctl.schema_version
                                ),
                            });
                        }
                        self.accepted_by.set(Some(from));
                        return Ok(ctl);
                    }
                    Ok(Command::Refuse) => {
                        return Err(BusError::Refused {
                            robot_id: self.robot_id,
                            reason: reason(&ctl),
                        });
                    }
                    _ => self.pending.borrow_mut().push_back((ctl, from)),
                }
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(BusError::Timeout {
                    what: format!(
                        "the coordinator to answer robot {}'s registration",
                        self.robot_id
                    ),
                    timeout,
                });
            }
            self.control.wait((deadline - now).min(HANDSHAKE_TICK))?;
        }
    }

    /// The next control addressed to this robot or to all, without blocking.
    pub fn recv_control(&self) -> Result<Option<Control>, BusError> {
        Ok(self.recv_control_from()?.map(|(ctl, _)| ctl))
    }

    /// [`recv_control`](Self::recv_control) with the id of the publisher that sent the
    /// control, so a robot can obey only its coordinator (compare with
    /// [`accepted_by`](Self::accepted_by)).
    pub fn recv_control_from(&self) -> Result<Option<(Control, Origin)>, BusError> {
        if let Some(c) = self.pending.borrow_mut().pop_front() {
            return Ok(Some(c));
        }
        self.next_control_from_bus()
    }

    /// The publisher whose `Ack` answered the last [`register`](Self::register): the control
    /// port of the coordinator that accepted this robot (`None` before).
    pub fn accepted_by(&self) -> Option<Origin> {
        self.accepted_by.get()
    }

    fn next_control_from_bus(&self) -> Result<Option<(Control, Origin)>, BusError> {
        while let Some(sample) = self.control.receive_sample()? {
            let ctl = *sample.payload();
            if ctl.robot_id == self.robot_id || ctl.robot_id == ROBOT_ID_ALL {
                let h = sample.header();
                let from = Origin {
                    publisher: h.publisher_id(),
                    node: h.node_id().value(),
                };
                return Ok(Some((ctl, from)));
            }
        }
        Ok(None)
    }

    /// Blocks until a control for this robot makes `done` return true (it sees every control
    /// in order, so it can also apply `AssignGoal`/`Phase`), then returns that control.
    pub fn wait_control(
        &self,
        timeout: Duration,
        mut done: impl FnMut(&Control) -> bool,
    ) -> Result<Control, BusError> {
        let deadline = Instant::now() + timeout;
        loop {
            while let Some(ctl) = self.recv_control()? {
                if done(&ctl) {
                    return Ok(ctl);
                }
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(BusError::Timeout {
                    what: format!("a control message for robot {}", self.robot_id),
                    timeout,
                });
            }
            self.control.wait((deadline - now).min(HANDSHAKE_TICK))?;
        }
    }

    /// The robot's half of the start handshake after [`register`](Self::register): waits for
    /// `Start` (or `Stop`, if the run ends before it starts), handing every other control to
    /// `on_other`. Publish learning traffic only after this returned `Start`.
    pub fn wait_start(
        &self,
        timeout: Duration,
        mut on_other: impl FnMut(&Control),
    ) -> Result<Control, BusError> {
        self.wait_control(timeout, |c| match Command::try_from(c.command) {
            Ok(Command::Start | Command::Stop) => true,
            _ => {
                on_other(c);
                false
            }
        })
    }

    /// Shuts the robot's side down and, if it was the last process of the run alive, removes
    /// every file the run left (see [`crate::clean_stale`]).
    pub fn close(self) -> Result<CleanReport, BusError> {
        let prefix = self.config.prefix();
        drop(self);
        clean_stale(&prefix)
    }

    /// The wake listeners of the four inboxes.
    pub fn listeners(&self) -> [(Topic, &Listener<ipc::Service>); 4] {
        [
            (Topic::Control, self.control.listener()),
            (Topic::Merged, self.merged.listener()),
            (Topic::Ack, self.ack.listener()),
            (Topic::Relay, self.relay.listener()),
        ]
    }
}

/// Who sent a control: the publisher port and its node. The control gate compares both; the
/// node is also the coordinator's identity on its other topics (a grant from another node is
/// not the coordinator's).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Origin {
    /// The publisher port that sent the sample.
    pub publisher: UniquePublisherId,
    /// The id (`NodeId::value`) of the node that port belongs to.
    pub node: u128,
}

/// A `RobotBus` without its node, so opening can be retried on one node.
struct RobotPorts {
    register: Outbox<Register>,
    state: Outbox<RobotState>,
    discovery: Outbox<PseudoTargetDiscovery>,
    hints: Outbox<QHintBatch>,
    report: Outbox<FinalReport>,
    intent: Outbox<Intent>,
    horizon: Outbox<IntentHorizon>,
    control: Inbox<Control>,
    merged: Inbox<MergedHintBatch>,
    ack: Inbox<DiscoveryAck>,
    relay: Inbox<DiscoveryRelay>,
    grant: Inbox<Grant>,
    robot_id: u32,
    config: BusConfig,
}

impl RobotPorts {
    fn with_node(self, node: Node<ipc::Service>) -> RobotBus {
        RobotBus {
            register: self.register,
            state: self.state,
            discovery: self.discovery,
            hints: self.hints,
            report: self.report,
            intent: self.intent,
            horizon: self.horizon,
            control: self.control,
            merged: self.merged,
            ack: self.ack,
            relay: self.relay,
            grant: self.grant,
            robot_id: self.robot_id,
            pending: RefCell::new(VecDeque::new()),
            accepted_by: Cell::new(None),
            config: self.config,
            node,
        }
    }
}

/// An iceoryx2 failure while creating services or ports with `/dev/shm` full is a lack of space
/// ([`BusError::NoShmSpace`]), whatever iceoryx2 called it.
fn explain_no_space(config: &BusConfig, e: BusError) -> BusError {
    match e {
        BusError::Service { .. }
        | BusError::Port { .. }
        | BusError::Send(SendError::Loan { .. })
            if shm_exhausted() =>
        {
            no_space(config)
        }
        other => other,
    }
}
