//! Attaching to a live run as an outside reader: wait until the run's services exist (never
//! create a node in a run's prefix before that: `qfleet run` would then refuse the id), then
//! open one subscriber on every topic of a [`Topics`] and drain them all, fast, without ever
//! publishing.
//!
//! What an outsider costs the run: one node and one subscriber per topic, taken from the
//! spare ports the bus sizes every service with (`BusConfig::spare_ports`). A lossless send
//! never waits for an outside reader: a full buffer of ours drops that sample for us alone, so
//! [`Observer::poll`] must be called in a tight loop to see everything; it takes everything
//! buffered on every topic each time.
//!
//! A reader sees a publisher's samples only once one of its receives has connected to that
//! publisher; samples of a publisher that left before then are gone for it (iceoryx2 keeps a
//! *connected* publisher's undelivered samples readable after it left, never an unconnected
//! one's). A reader that may not run for a while (the recorder's idle-class thread) therefore
//! reads the lossless topics with a second observer ([`Topics::Lossless`]) on a thread that
//! blocks on their wake events ([`Observer::attach_all`]) and so runs within a wakeup of every
//! lossless send (see [`crate::watch`]).

use std::time::{Duration, Instant};

use bus::iceoryx2::port::listener::Listener;
use bus::iceoryx2::prelude::*;
use bus::{BusConfig, Inbox, Message, monotonic_ns};
use bus_schema::names::{Delivery, Topic};
use bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, Grant, Intent, IntentHorizon,
    MergedHintBatch, PseudoTargetDiscovery, QHintBatch, Register, RobotState,
};

use std::cell::RefCell;

use crate::ObserveError;
use crate::decode::Msg;
use crate::members::{self, Members, Origin, Verdict};

/// `qfleet topic list`: the topics of run `run_id` (all, or `only`) with their service name,
/// type, delivery and payload size, and whether the run is `live`: a JSON array (`json`), or
/// a line saying the run's state and a table.
pub fn topic_list(run_id: &str, only: Option<Topic>, live: bool, json: bool) -> String {
    let topics = Topic::ALL
        .into_iter()
        .filter(|x| only.is_none_or(|o| o == *x));
    if json {
        let v: Vec<_> = topics
            .map(|x| {
                serde_json::json!({
                    "topic": x.service_name(run_id), "type": x.type_name(),
                    "delivery": format!("{:?}", x.delivery()), "direction": format!("{:?}", x.direction()),
                    "payload_bytes": x.payload_size(), "live": live,
                })
            })
            .collect();
        return format!("{}\n", serde_json::Value::Array(v));
    }
    let mut tab = report::TextTable::new(&["topic", "type", "delivery", ">bytes"]);
    for x in topics {
        tab.row(vec![
            x.service_name(run_id),
            x.type_name().to_string(),
            format!("{:?}", x.delivery()),
            x.payload_size().to_string(),
        ]);
    }
    let state = if live {
        "running"
    } else {
        "not running (no services)"
    };
    format!("run {run_id}: {state}\n{}", tab.render(""))
}

/// Whether every publish-subscribe service of run `run_id` exists (a read of iceoryx2's
/// bookkeeping; creates nothing in the run's prefix).
pub fn run_services_exist(run_id: &str) -> Result<bool, ObserveError> {
    let cfg = BusConfig::new(run_id, 1)?;
    let config = cfg.iceoryx_config()?;
    for t in Topic::ALL {
        let name = t.service_name(run_id);
        let sn =
            ServiceName::new(&name).map_err(|e| ObserveError::Bus(format!("{name}: {e:?}")))?;
        let exists = ipc::Service::does_exist(&sn, &config, MessagingPattern::PublishSubscribe)
            .map_err(|e| ObserveError::Bus(format!("{name}: {e:?}")))?;
        if !exists {
            return Ok(false);
        }
    }
    Ok(true)
}

/// Which of a run's topics an [`Observer`] subscribes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topics {
    /// All eleven.
    All,
    /// The lossless ones (registrations, discoveries, reports, control, relays): few messages,
    /// each of which must be seen.
    Lossless,
    /// The latest-wins ones (states, hints, merged hints, acks, intents, grants): the many
    /// messages a reader may fall behind on.
    LatestWins,
}

impl Topics {
    /// Whether `topic` is among these.
    pub fn has(self, topic: Topic) -> bool {
        match self {
            Topics::All => true,
            Topics::Lossless => topic.delivery() == Delivery::Lossless,
            Topics::LatestWins => topic.delivery() == Delivery::LatestWins,
        }
    }
}

/// An outside reader of one run: a node and one subscriber on each topic of a [`Topics`].
pub struct Observer {
    // ports before the node: they are dropped first
    register: Option<Inbox<Register>>,
    state: Option<Inbox<RobotState>>,
    discovery: Option<Inbox<PseudoTargetDiscovery>>,
    hints: Option<Inbox<QHintBatch>>,
    report: Option<Inbox<FinalReport>>,
    control: Option<Inbox<Control>>,
    merged: Option<Inbox<MergedHintBatch>>,
    ack: Option<Inbox<DiscoveryAck>>,
    relay: Option<Inbox<DiscoveryRelay>>,
    intent: Option<Inbox<Intent>>,
    horizon: Option<Inbox<IntentHorizon>>,
    grant: Option<Inbox<Grant>>,
    _node: Node<ipc::Service>,
    run_id: String,
    own: Option<RefCell<OwnOnly>>,
}

/// Most messages taken from one topic per [`Observer::poll`], so one busy topic cannot starve
/// the others; more than any topic's buffer.
const DRAIN_MAX: usize = 4096;

/// Who the observer shows: the run's own processes ([`crate::members`]), resolved against
/// the run's node listing.
struct OwnOnly {
    members: Members,
    /// The launcher's pid: the run's processes are its children.
    launcher: i32,
    cfg: BusConfig,
}

impl OwnOnly {
    /// The verdict on `m` from `sender`, resolving an unknown sender from the node listing
    /// (once per new node: every node listed is learned).
    fn judge(&mut self, sender: u128, m: &Msg<'_>) -> Verdict {
        match self.members.judge(sender, m) {
            Verdict::Resolve => {
                let listing = self.learn_listed();
                if !listing.iter().any(|n| n.id == Some(sender)) {
                    self.members.learn(sender, Origin::Other);
                }
                self.members.judge(sender, m)
            }
            v => v,
        }
    }

    /// Learns the origin of every node of the run listed now; returns the listing.
    fn learn_listed(&mut self) -> Vec<bus::NodeInfo> {
        let listing = bus::check_nodes(&self.cfg, false)
            .map(|r| r.nodes)
            .unwrap_or_default();
        for n in &listing {
            if let Some(id) = n.id {
                let origin = members::origin_of(id, &listing, self.launcher, members::parent_of);
                self.members.learn(id, origin);
            }
        }
        listing
    }
}

/// Takes up to [`DRAIN_MAX`] messages of `inbox` (if this observer has it) into `f`; with
/// `own`, only those of the run's own processes (the others are counted there). Returns how
/// many were taken (shown or not).
fn drain<T: Message>(
    inbox: &Option<Inbox<T>>,
    own: &Option<RefCell<OwnOnly>>,
    f: &mut impl FnMut(u64, Msg<'_>),
    wrap: impl for<'m> Fn(&'m T) -> Msg<'m>,
) -> Result<usize, ObserveError> {
    match (inbox, own) {
        (Some(i), None) => Ok(i.drain(DRAIN_MAX, |m| f(monotonic_ns(), wrap(m)))?),
        (Some(i), Some(own)) => Ok(i.drain_from(DRAIN_MAX, |sender, m| {
            let m = wrap(m);
            if own.borrow_mut().judge(sender, &m) == Verdict::Show {
                f(monotonic_ns(), m);
            }
        })?),
        (None, _) => Ok(0),
    }
}

impl Observer {
    /// Waits (polling every 5 ms, up to `timeout`) until run `run_id`'s services exist, then
    /// joins it on `topics`. `give_up` is asked between polls (e.g. "the run already ended").
    pub fn attach(
        run_id: &str,
        topics: Topics,
        timeout: Duration,
        give_up: &dyn Fn() -> bool,
    ) -> Result<Self, ObserveError> {
        let t0 = Instant::now();
        loop {
            if run_services_exist(run_id)? {
                // the coordinator creates the services one after the other: a failed open
                // while it is still at it is retried
                match Self::open(run_id, topics) {
                    Ok(o) => return Ok(o),
                    Err(e) if t0.elapsed() >= timeout => return Err(e),
                    Err(_) => {}
                }
            }
            if give_up() {
                return Err(ObserveError::NotRunning(run_id.to_string()));
            }
            if t0.elapsed() >= timeout {
                return Err(ObserveError::Timeout {
                    run_id: run_id.to_string(),
                    waited: timeout,
                });
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Joins run `run_id` now (its services must exist) on `topics`, with a node named
    /// `qfleet-observer-<pid>` (`…-lossless` for [`Topics::Lossless`]).
    pub fn open(run_id: &str, topics: Topics) -> Result<Self, ObserveError> {
        fn inbox<T: Message>(
            topics: Topics,
            node: &Node<ipc::Service>,
            cfg: &BusConfig,
        ) -> Result<Option<Inbox<T>>, ObserveError> {
            if topics.has(T::TOPIC) {
                Ok(Some(Inbox::open(node, cfg)?))
            } else {
                Ok(None)
            }
        }
        let suffix = match topics {
            Topics::Lossless => "-lossless",
            Topics::All | Topics::LatestWins => "",
        };
        let cfg = BusConfig::new(run_id, 1)?;
        let node = cfg.create_node(&format!(
            "{}{}{suffix}",
            bus::OBSERVER_NODE_PREFIX,
            std::process::id()
        ))?;
        Ok(Self {
            register: inbox(topics, &node, &cfg)?,
            state: inbox(topics, &node, &cfg)?,
            discovery: inbox(topics, &node, &cfg)?,
            hints: inbox(topics, &node, &cfg)?,
            report: inbox(topics, &node, &cfg)?,
            control: inbox(topics, &node, &cfg)?,
            merged: inbox(topics, &node, &cfg)?,
            ack: inbox(topics, &node, &cfg)?,
            relay: inbox(topics, &node, &cfg)?,
            intent: inbox(topics, &node, &cfg)?,
            horizon: inbox(topics, &node, &cfg)?,
            grant: inbox(topics, &node, &cfg)?,
            _node: node,
            run_id: run_id.to_string(),
            own: None,
        })
    }

    /// The run this observer reads.
    pub fn run_id(&self) -> &str {
        &self.run_id
    }

    /// From now on, shows only the messages of the run's own processes — those whose parent
    /// is `launcher` — and, of a robot's messages, only those naming one of its `robots` robot
    /// ids; the others are counted ([`Observer::others`]). See [`crate::members`].
    pub fn only_own(mut self, robots: u32, launcher: i32) -> Result<Self, ObserveError> {
        self.own = Some(RefCell::new(OwnOnly {
            members: Members::new(robots),
            launcher,
            cfg: BusConfig::new(&self.run_id, robots.max(1))?,
        }));
        Ok(self)
    }

    /// Messages not shown because another process sent them, per topic (in
    /// [`Topic::ALL`]'s order); zeros without [`Observer::only_own`].
    pub fn others(&self) -> [u64; Topic::ALL.len()] {
        self.own
            .as_ref()
            .map_or([0; Topic::ALL.len()], |o| o.borrow().members.others())
    }

    /// Takes every buffered message of every topic it has and hands each to `f` with its
    /// receive time (monotonic ns); returns how many there were.
    pub fn poll(&self, mut f: impl FnMut(u64, Msg<'_>)) -> Result<usize, ObserveError> {
        let f = &mut f;
        // lossless topics first: a full buffer there loses messages for us
        let o = &self.own;
        Ok(drain(&self.control, o, f, |m| Msg::Control(m))?
            + drain(&self.register, o, f, |m| Msg::Register(m))?
            + drain(&self.discovery, o, f, |m| Msg::Discovery(m))?
            + drain(&self.relay, o, f, |m| Msg::Relay(m))?
            + drain(&self.report, o, f, |m| Msg::Report(m))?
            + drain(&self.state, o, f, |m| Msg::State(m))?
            + drain(&self.hints, o, f, |m| Msg::Hints(m))?
            + drain(&self.merged, o, f, |m| Msg::Merged(m))?
            + drain(&self.ack, o, f, |m| Msg::Ack(m))?
            + drain(&self.grant, o, f, |m| Msg::Grant(m))?
            + drain(&self.intent, o, f, |m| Msg::Intent(m))?
            + drain(&self.horizon, o, f, |m| Msg::Horizon(m))?)
    }

    /// With [`only_own`](Self::only_own), learns now whose every node of the run listed now is,
    /// so that their samples read after they left are still told apart (a node no longer
    /// listed when first read proves nothing and is not shown); else nothing.
    pub fn learn_senders(&self) {
        if let Some(own) = &self.own {
            own.borrow_mut().learn_listed();
        }
    }

    /// Connects every subscriber of this observer to the publishers that appeared since its
    /// last receive (a receive does it for its own topic): from then on their samples stay
    /// readable, even after they leave.
    pub fn connect_all(&self) -> Result<(), ObserveError> {
        fn connect<T: Message>(inbox: &Option<Inbox<T>>) -> Result<(), ObserveError> {
            match inbox {
                Some(i) => Ok(i.connect()?),
                None => Ok(()),
            }
        }
        connect(&self.register)?;
        connect(&self.state)?;
        connect(&self.discovery)?;
        connect(&self.hints)?;
        connect(&self.report)?;
        connect(&self.control)?;
        connect(&self.merged)?;
        connect(&self.ack)?;
        connect(&self.relay)?;
        connect(&self.intent)?;
        connect(&self.horizon)?;
        connect(&self.grant)
    }

    /// Attaches the wake listeners of this observer's topics to `waitset` (publishers notify
    /// them after every lossless send), so a reader can block until there is something to
    /// read; keep the guards as long as the attachment should last, and call
    /// [`clear_wakeups`](Self::clear_wakeups) after every wakeup.
    pub fn attach_all<'w, 'a>(
        &'a self,
        waitset: &'w WaitSet<ipc::Service>,
    ) -> Result<Vec<WaitSetGuard<'w, 'a, ipc::Service>>, ObserveError> {
        self.listeners()
            .into_iter()
            .map(|l| {
                waitset
                    .attach_notification(l)
                    .map_err(|e| ObserveError::Bus(format!("cannot attach to the WaitSet: {e:?}")))
            })
            .collect()
    }

    /// Consumes the pending wakeups of every topic this observer has, without blocking.
    pub fn clear_wakeups(&self) -> Result<(), ObserveError> {
        for l in self.listeners() {
            l.try_wait(|_| {})
                .map_err(|e| ObserveError::Bus(format!("wake listener: {e:?}")))?;
        }
        Ok(())
    }

    /// The wake listeners of the topics this observer has.
    fn listeners(&self) -> Vec<&Listener<ipc::Service>> {
        let all = [
            self.register.as_ref().map(Inbox::listener),
            self.state.as_ref().map(Inbox::listener),
            self.discovery.as_ref().map(Inbox::listener),
            self.hints.as_ref().map(Inbox::listener),
            self.report.as_ref().map(Inbox::listener),
            self.control.as_ref().map(Inbox::listener),
            self.merged.as_ref().map(Inbox::listener),
            self.ack.as_ref().map(Inbox::listener),
            self.relay.as_ref().map(Inbox::listener),
            self.intent.as_ref().map(Inbox::listener),
            self.horizon.as_ref().map(Inbox::listener),
            self.grant.as_ref().map(Inbox::listener),
        ];
        all.into_iter().flatten().collect()
    }

    /// Whether any process of the run is alive, outside readers (this one and others) not
    /// counted: false once the run ended, even while another `topic echo` is still attached
    /// (then drop the observer and call [`leave`]).
    pub fn run_alive(&self) -> bool {
        let Ok(cfg) = BusConfig::new(&self.run_id, 1) else {
            return false;
        };
        match bus::check_nodes(&cfg, false) {
            Ok(r) => r
                .alive()
                .any(|n| !n.name.starts_with(bus::OBSERVER_NODE_PREFIX)),
            // unreadable bookkeeping: assume alive, the caller's stop flag still ends the loop
            Err(_) => true,
        }
    }
}

/// Called after the [`Observer`] of a run was dropped: if the run ended while we were attached
/// (so the last process to leave was us), remove the run's remaining files, exactly as the
/// launcher does; a live run is left alone.
pub fn leave(run_id: &str) -> Result<(), ObserveError> {
    bus::clean_stale(&bus_schema::names::iceoryx_prefix(run_id))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_topic_list_is_a_table_or_json() {
        let t = Topic::ALL[0];
        let text = topic_list("r1", Some(t), false, false);
        assert!(
            text.starts_with("run r1: not running (no services)\ntopic"),
            "{text}"
        );
        assert_eq!(text.lines().count(), 3);
        assert!(text.contains(&t.service_name("r1")), "{text}");
        let all = topic_list("r1", None, true, true);
        let v: serde_json::Value = serde_json::from_str(&all).unwrap();
        assert_eq!(v.as_array().unwrap().len(), Topic::ALL.len());
        assert_eq!(v[0]["live"], true);
    }
}
