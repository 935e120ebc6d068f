//! Surviving the coordinator: notice that it is gone, learn alone meanwhile, and re-register
//! with a restarted one.
//!
//! Every 250 ms (checked between learning steps, never blocking them) the robot lists the run's
//! iceoryx2 nodes. When no coordinator is alive the robot is *alone*: it cleans up the dead
//! coordinator's resources (so lossless sends stop waiting on its full buffers), keeps learning,
//! and holds back discovery sends — they stay queued until acknowledged. When a coordinator with
//! another process id is alive, the robot re-sends its `Register` every 250 ms until that
//! coordinator acknowledges it; then every discovery it ever made is replayed (the new
//! coordinator has none of them; duplicates are dropped by sequence number there), so nothing
//! found while the coordinator was down is lost.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::Origin;
use bus::bus_schema::{COORDINATOR_NODE_NAME, Command, Control, Register};
use bus::{BusError, RobotBus, SendError, check_nodes, monotonic_ns, reason};

use crate::gate::{ControlGate, Verdict};
pub use report::LinkCounters;

/// How often the robot looks for its coordinator.
const CHECK_EVERY: Duration = Duration::from_millis(250);

/// How often a `Register` is re-sent to a new coordinator until it answers.
const REGISTER_EVERY: Duration = Duration::from_millis(250);

/// What a control message meant for the link.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkEvent {
    /// A restarted coordinator accepted this robot: replay unacknowledged state.
    Rejoined,
    /// A restarted coordinator refused this robot.
    Refused(String),
}

/// The robot's view of its coordinator.
#[derive(Debug)]
pub struct Link {
    reg: Register,
    coordinator_pid: Option<i32>,
    alone_since: Option<Instant>,
    /// A coordinator with this pid is up and has not acknowledged us yet.
    rejoining: Option<i32>,
    asked_ns: u64,
    last_check: Instant,
    last_register: Option<Instant>,
    /// Link counters.
    pub counters: LinkCounters,
}

impl Link {
    /// A link for a robot that just registered with `reg`.
    pub fn new(reg: Register) -> Self {
        Link {
            reg,
            coordinator_pid: None,
            alone_since: None,
            rejoining: None,
            asked_ns: 0,
            // look at once, so the coordinator we registered with is known early
            last_check: Instant::now() - CHECK_EVERY,
            last_register: None,
            counters: LinkCounters::default(),
        }
    }

    /// Whether there is no coordinator that accepted this robot (gone, or restarted and not
    /// acknowledged yet): hold back lossless sends.
    pub fn alone(&self) -> bool {
        self.alone_since.is_some() || self.rejoining.is_some()
    }

    /// The periodic check; cheap when called more often than every 250 ms.
    pub fn tick(&mut self, bus: &RobotBus) -> Result<(), BusError> {
        let now = Instant::now();
        if now.duration_since(self.last_check) >= CHECK_EVERY {
            self.last_check = now;
            self.look(bus, false)?;
        }
        if self.rejoining.is_some()
            && self
                .last_register
                .is_none_or(|t| t.elapsed() >= REGISTER_EVERY)
        {
            self.last_register = Some(now);
            let reg = self.reg;
            match bus.register.send_with(|m| {
                *m = reg;
                m.send_time_ns = monotonic_ns();
            }) {
                Ok(_) => {
                    bus.register.notify()?;
                }
                // its subscriber is not there yet, or it died again: the next round retries
                Err(SendError::NoSubscriber { .. } | SendError::DeliveryTimeout { .. }) => {}
                Err(e) => return Err(e.into()),
            }
        }
        Ok(())
    }

    /// Looks for the coordinator now, by a full listing of the run's nodes, instead of at the
    /// next periodic check; returns whether the robot is alone after it.
    ///
    /// For a lossless send that reached nobody: the coordinator may have died since the last
    /// look (up to 250 ms ago), and its process may still exist as a zombie, which the periodic
    /// check's `/proc` test would take for alive.
    pub fn look_now(&mut self, bus: &RobotBus) -> Result<bool, BusError> {
        self.last_check = Instant::now();
        self.look(bus, true)?;
        Ok(self.alone())
    }

    fn look(&mut self, bus: &RobotBus, full: bool) -> Result<(), BusError> {
        // the usual case costs one stat(2): listing the run's nodes reads a file per node, and
        // with many robots on few cores that would eat a robot's whole share of the CPU
        if !full
            && let Some(pid) = self.coordinator_pid
            && !self.alone()
            && Path::new(&format!("/proc/{pid}")).exists()
        {
            return Ok(());
        }
        let nodes = check_nodes(bus.config(), false)?;
        let alive = nodes
            .alive()
            .find(|n| n.name == COORDINATOR_NODE_NAME)
            .and_then(|n| n.pid);
        let id = bus.robot_id();
        match alive {
            None if self.alone_since.is_none() => {
                self.alone_since = Some(Instant::now());
                self.rejoining = None;
                self.counters.coordinator_losses += 1;
                report::log_line!(
                    "robot-agent {id}: the coordinator is gone; learning alone, discoveries kept \
                     until a coordinator acknowledges them"
                );
                // free its ports, so nothing waits on a buffer that nobody drains any more
                if let Err(e) = check_nodes(bus.config(), true) {
                    report::log_line!(
                        "robot-agent {id}: warning: cleaning up the dead coordinator: {e}"
                    );
                }
            }
            None => {}
            Some(pid) if self.coordinator_pid.is_none() && !self.alone() => {
                self.coordinator_pid = Some(pid);
            }
            Some(pid) if Some(pid) != self.coordinator_pid && self.rejoining != Some(pid) => {
                report::log_line!(
                    "robot-agent {id}: a new coordinator (pid {pid}) is up; re-registering"
                );
                if self.alone_since.is_none() {
                    // replaced before we even saw the old one gone: still a loss
                    self.alone_since = Some(Instant::now());
                    self.counters.coordinator_losses += 1;
                }
                self.rejoining = Some(pid);
                self.asked_ns = monotonic_ns();
                self.last_register = None;
            }
            Some(_) => {}
        }
        Ok(())
    }

    /// Looks at a control addressed to this robot; `Some` when it answered a re-registration.
    pub fn on_control(&mut self, ctl: &Control) -> Option<LinkEvent> {
        let pid = self.rejoining?;
        if ctl.robot_id != self.reg.robot_id || ctl.time_ns < self.asked_ns {
            return None;
        }
        match Command::try_from(ctl.command) {
            Ok(Command::Ack) => {
                if let Some(t) = self.alone_since.take() {
                    self.counters.alone_ms += t.elapsed().as_millis() as u64;
                }
                self.coordinator_pid = Some(pid);
                self.rejoining = None;
                self.counters.rejoins += 1;
                report::log_line!(
                    "robot-agent {}: re-joined the restarted coordinator (pid {pid})",
                    self.reg.robot_id
                );
                Some(LinkEvent::Rejoined)
            }
            Ok(Command::Refuse) => Some(LinkEvent::Refused(reason(ctl))),
            _ => None,
        }
    }
}

/// Longest single wait of the start handshake between looks at the stop flag.
const HANDSHAKE_SLICE: Duration = Duration::from_millis(250);

/// [`RobotBus::register`] that gives up early when `stop` is set (SIGINT/SIGTERM during the
/// start handshake), with [`BusError::Interrupted`].
pub fn register_until(
    bus: &RobotBus,
    reg: &Register,
    timeout: Duration,
    stop: &AtomicBool,
) -> Result<Control, BusError> {
    let deadline = Instant::now() + timeout;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match bus.register(reg, left.min(HANDSHAKE_SLICE)) {
            // a dead coordinator's full register buffer: retry (it is cleaned meanwhile)
            Err(BusError::Send(SendError::DeliveryTimeout { .. })) if Instant::now() < deadline => {
            }
            Err(BusError::Timeout { what, .. }) => {
                if stop.load(Ordering::Relaxed) {
                    return Err(BusError::Interrupted);
                }
                if Instant::now() >= deadline {
                    return Err(BusError::Timeout { what, timeout });
                }
            }
            other => return other,
        }
    }
}

/// The start handshake: [`register_until`], then a wait for `Start` (`Phase`, or `Stop`) in slices that
/// look at the stop flag (giving up with [`BusError::Interrupted`]) and at the coordinator: if
/// it dies before sending `Start`, its resources are cleaned and the robot registers again,
/// with whatever coordinator comes up next (`qfleet run --restart on-failure` starts one).
///
/// The publisher whose `Ack` accepted the registration becomes the `gate`'s coordinator;
/// controls from any other publisher are dropped (and counted by the gate), the others before
/// `Start` go to `on_other`.
pub fn handshake(
    bus: &RobotBus,
    reg: &Register,
    timeout: Duration,
    stop: &AtomicBool,
    gate: &mut ControlGate<Origin>,
    mut on_other: impl FnMut(&Control),
) -> Result<Control, BusError> {
    let deadline = Instant::now() + timeout;
    let id = bus.robot_id();
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        register_until(bus, reg, left, stop)?;
        if let Some(id) = bus.accepted_by() {
            gate.accept(id);
        }
        let coordinator = check_nodes(bus.config(), false)?
            .alive()
            .find(|n| n.name == COORDINATOR_NODE_NAME)
            .and_then(|n| n.pid);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match wait_start(bus, left.min(HANDSHAKE_SLICE), gate, &mut on_other) {
                Err(BusError::Timeout { what, .. }) => {
                    if stop.load(Ordering::Relaxed) {
                        return Err(BusError::Interrupted);
                    }
                    if Instant::now() >= deadline {
                        return Err(BusError::Timeout { what, timeout });
                    }
                    if coordinator.is_some_and(|p| !Path::new(&format!("/proc/{p}")).exists()) {
                        report::log_line!(
                            "robot-agent {id}: the coordinator died before Start; registering again"
                        );
                        check_nodes(bus.config(), true)?;
                        break;
                    }
                }
                other => return other,
            }
        }
    }
}

/// Waits up to `timeout` for `Start` (or `Phase`, the start command of a later phase) or
/// `Stop` from the gate's coordinator; the coordinator's
/// other controls go to `on_other`, everyone else's are dropped.
fn wait_start(
    bus: &RobotBus,
    timeout: Duration,
    gate: &mut ControlGate<Origin>,
    on_other: &mut impl FnMut(&Control),
) -> Result<Control, BusError> {
    let deadline = Instant::now() + timeout;
    loop {
        while let Some((ctl, from)) = bus.recv_control_from()? {
            if gate.check(from) == Verdict::Drop {
                continue;
            }
            match Command::try_from(ctl.command) {
                // `Phase`: a robot (re)started during a later phase of an experiment
                Ok(Command::Start | Command::Phase | Command::Stop) => return Ok(ctl),
                _ => on_other(&ctl),
            }
        }
        let now = Instant::now();
        if now >= deadline {
            return Err(BusError::Timeout {
                what: "the coordinator's Start".into(),
                timeout,
            });
        }
        bus.control.wait(deadline - now)?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bus::{BusConfig, CoordinatorBus, leftover_files, unique_run_id};

    #[test]
    fn a_coordinator_gone_since_the_last_look_is_seen_at_once_by_look_now() {
        let cfg = BusConfig::new(unique_run_id("looknow"), 1).unwrap();
        let coordinator = CoordinatorBus::create(&cfg).unwrap();
        let robot = RobotBus::open(&cfg, 0, Duration::from_secs(20)).unwrap();
        let mut link = Link::new(Register {
            robot_id: 0,
            ..Register::ZEROED
        });
        link.tick(&robot).unwrap();
        assert!(!link.alone(), "the first look finds the coordinator");
        coordinator.close().unwrap();
        // the periodic check looks again only after CHECK_EVERY, and then only at /proc (the
        // coordinator here is this very process, alive, like a zombie would look)
        link.tick(&robot).unwrap();
        assert!(!link.alone());
        assert!(
            link.look_now(&robot).unwrap(),
            "the full listing finds no coordinator"
        );
        assert!(link.alone());
        assert_eq!(link.counters.coordinator_losses, 1);
        drop(robot);
        // the last node of the run to leave was a robot's, which does not clean up after itself
        bus::clean_run(&cfg).unwrap();
        assert_eq!(
            leftover_files(&cfg.prefix()),
            Vec::<std::path::PathBuf>::new()
        );
    }
}
