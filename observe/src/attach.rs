//! Attaching to a live run as an outside reader: wait until the run's services exist (never
//! create a node in a run's prefix before that: `qfleet run` would then refuse the id), then
//! open one subscriber on every topic and drain them all, fast, without ever publishing.
//!
//! What an outsider costs the run: one node and one subscriber per topic, taken from the
//! spare ports the bus sizes every service with (`BusConfig::spare_ports`). A lossless send
//! never waits for an outside reader: a full buffer of ours drops that sample for us alone, so
//! [`Observer::poll`] must be called in a tight loop to see everything; it takes everything
//! buffered on every topic each time.

use std::time::{Duration, Instant};

use bus::iceoryx2::prelude::*;
use bus::{BusConfig, Inbox, monotonic_ns};
use bus_schema::names::Topic;
use bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, MergedHintBatch, PseudoTargetDiscovery,
    QHintBatch, Register, RobotState,
};

use crate::ObserveError;
use crate::decode::Msg;

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

/// An outside reader of one run: a node and one subscriber per topic.
pub struct Observer {
    // ports before the node: they are dropped first
    register: Inbox<Register>,
    state: Inbox<RobotState>,
    discovery: Inbox<PseudoTargetDiscovery>,
    hints: Inbox<QHintBatch>,
    report: Inbox<FinalReport>,
    control: Inbox<Control>,
    merged: Inbox<MergedHintBatch>,
    ack: Inbox<DiscoveryAck>,
    relay: Inbox<DiscoveryRelay>,
    _node: Node<ipc::Service>,
    run_id: String,
}

/// Most messages taken from one topic per [`Observer::poll`], so one busy topic cannot starve
/// the others; more than any topic's buffer.
const DRAIN_MAX: usize = 4096;

impl Observer {
    /// Waits (polling every 5 ms, up to `timeout`) until run `run_id`'s services exist, then
    /// joins it. `give_up` is asked between polls (e.g. "the run already ended").
    pub fn attach(
        run_id: &str,
        timeout: Duration,
        give_up: &dyn Fn() -> bool,
    ) -> Result<Self, ObserveError> {
        let t0 = Instant::now();
        loop {
            if run_services_exist(run_id)? {
                // the coordinator creates the services one after the other: a failed open
                // while it is still at it is retried
                match Self::open(run_id) {
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

    /// Joins run `run_id` now (its services must exist).
    pub fn open(run_id: &str) -> Result<Self, ObserveError> {
        let cfg = BusConfig::new(run_id, 1)?;
        let node = cfg.create_node(&format!(
            "{}{}",
            bus::OBSERVER_NODE_PREFIX,
            std::process::id()
        ))?;
        Ok(Self {
            register: Inbox::open(&node, &cfg)?,
            state: Inbox::open(&node, &cfg)?,
            discovery: Inbox::open(&node, &cfg)?,
            hints: Inbox::open(&node, &cfg)?,
            report: Inbox::open(&node, &cfg)?,
            control: Inbox::open(&node, &cfg)?,
            merged: Inbox::open(&node, &cfg)?,
            ack: Inbox::open(&node, &cfg)?,
            relay: Inbox::open(&node, &cfg)?,
            _node: node,
            run_id: run_id.to_string(),
        })
    }

    /// The run this observer reads.
    pub fn run_id(&self) -> &str {
        &self.run_id
    }

    /// Takes every buffered message of every topic and hands each to `f` with its receive
    /// time (monotonic ns); returns how many there were.
    pub fn poll(&self, mut f: impl FnMut(u64, Msg<'_>)) -> Result<usize, ObserveError> {
        let mut n = 0;
        // lossless topics first: a full buffer there loses messages for us
        n += self
            .control
            .drain(DRAIN_MAX, |m| f(monotonic_ns(), Msg::Control(m)))?;
        n += self
            .register
            .drain(DRAIN_MAX, |m| f(monotonic_ns(), Msg::Register(m)))?;
        n += self
            .discovery
            .drain(DRAIN_MAX, |m| f(monotonic_ns(), Msg::Discovery(m)))?;
        n += self
            .relay
            .drain(DRAIN_MAX, |m| f(monotonic_ns(), Msg::Relay(m)))?;
        n += self
            .report
            .drain(DRAIN_MAX, |m| f(monotonic_ns(), Msg::Report(m)))?;
        n += self
            .state
            .drain(DRAIN_MAX, |m| f(monotonic_ns(), Msg::State(m)))?;
        n += self
            .hints
            .drain(DRAIN_MAX, |m| f(monotonic_ns(), Msg::Hints(m)))?;
        n += self
            .merged
            .drain(DRAIN_MAX, |m| f(monotonic_ns(), Msg::Merged(m)))?;
        n += self
            .ack
            .drain(DRAIN_MAX, |m| f(monotonic_ns(), Msg::Ack(m)))?;
        Ok(n)
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
