//! Robot liveness beyond iceoryx2's node states: losses from node listings, heartbeat
//! deadlines (a hung robot), restarts and re-joins, as a state without IO ([`Life`], driven
//! with explicit `Instant`s and tested as a specification). The listings come from a
//! [`bus::Lister`] thread, off the receive loop.
//!
//! Every liveness event is also printed on stdout as `event <kind> <robot id> <monotonic ns>`
//! (by the engine, see [`Life::take_new`]) so the launcher can act on it (kill and restart a
//! hung robot).

use std::time::{Duration, Instant};

use bus::bus_schema::ROBOT_ID_ALL;
use bus::{CoordinatorBus, Lister, Liveness, NodeReport, monotonic_ns};

use crate::options::CoordError;

use report::RobotCheckpoint;
pub use report::run::{LivenessEvent, LivenessKind};

/// How often the liveness thread looks at the run's nodes: a re-check of their processes, and
/// a full listing at most every [`bus::lister::FULL_EVERY`].
pub(crate) const LIST_EVERY: Duration = Duration::from_millis(100);

/// Starts the coordinator's liveness thread (`qfleet-liveness`) for the run on `bus`.
pub(crate) fn start_lister(bus: &CoordinatorBus) -> Result<Lister, CoordError> {
    Lister::start(bus.config(), LIST_EVERY, false, "qfleet-liveness").map_err(|source| {
        CoordError::Thread {
            what: "liveness",
            source,
        }
    })
}

/// The node name of robot `id` (the one `bus::RobotBus::open` creates).
pub(crate) fn robot_of_node(name: &str) -> Option<usize> {
    name.strip_prefix("qfleet-robot-")?.parse().ok()
}

/// Which of robots `0..robots` a listing shows alive, or `None` when the listing proves no
/// death: a node whose files could not be read (out of file descriptors, a node half-created
/// or half-removed, another user's file) may be any robot's. A robot that really died is still
/// caught by its heartbeat deadline.
pub(crate) fn alive_in(report: &NodeReport, robots: usize) -> Option<Vec<bool>> {
    if report
        .nodes
        .iter()
        .any(|n| !matches!(n.liveness, Liveness::Alive | Liveness::Dead))
    {
        return None;
    }
    let mut alive = vec![false; robots];
    for n in report.alive() {
        if let Some(id) = robot_of_node(&n.name)
            && id < robots
        {
            alive[id] = true;
        }
    }
    Some(alive)
}

/// Per-robot liveness state.
#[derive(Debug, Clone, Copy, Default)]
struct Lifeline {
    joined_at: Option<Instant>,
    last_seen: Option<Instant>,
    hung: bool,
    lost_at: Option<Instant>,
    restarts: u32,
    warm_started: bool,
}

/// Liveness state of the whole fleet, without IO: every method takes the time it acts at.
#[derive(Debug, Clone)]
pub struct Life {
    lines: Vec<Lifeline>,
    events: Vec<LivenessEvent>,
    announced: usize,
    hang_after: Duration,
    restarts_allowed: u32,
    wait_restart: Duration,
}

impl Life {
    /// Liveness for robot ids `0..robots`: a busy robot silent for `hang_after` is hung; a
    /// lost robot holds up the end of the run for `wait_restart` while it has restarts left
    /// (`restarts_allowed` per robot).
    pub fn new(
        robots: u32,
        hang_after: Duration,
        restarts_allowed: u32,
        wait_restart: Duration,
    ) -> Self {
        Life {
            lines: vec![Lifeline::default(); robots as usize],
            events: Vec::new(),
            announced: 0,
            hang_after,
            restarts_allowed,
            wait_restart,
        }
    }

    fn push(&mut self, robot_id: u32, kind: LivenessKind, silent_ms: u64) {
        self.events.push(LivenessEvent {
            robot_id,
            kind,
            at_ns: monotonic_ns(),
            silent_ms,
        });
    }

    fn silent_ms(&self, robot_id: u32, now: Instant) -> u64 {
        self.lines
            .get(robot_id as usize)
            .and_then(|l| l.last_seen)
            .map_or(0, |t| now.saturating_duration_since(t).as_millis() as u64)
    }

    /// A robot was admitted by the start handshake (no event: that is the normal start).
    pub fn admitted(&mut self, robot_id: u32, now: Instant) {
        if let Some(l) = self.lines.get_mut(robot_id as usize) {
            l.joined_at = Some(now);
            l.last_seen = Some(now);
        }
    }

    /// A robot registered during the run: `restarted` when a new process replaced a dead one
    /// (event `restarted`), otherwise a process this coordinator had not admitted yet (a
    /// robot re-joining a restarted coordinator, or a late one: event `joined`).
    pub fn joined(&mut self, robot_id: u32, restarted: bool, now: Instant) {
        let silent = self.silent_ms(robot_id, now);
        let Some(l) = self.lines.get_mut(robot_id as usize) else {
            return;
        };
        if restarted {
            l.restarts += 1;
        }
        *l = Lifeline {
            joined_at: Some(now),
            last_seen: Some(now),
            restarts: l.restarts,
            ..Lifeline::default()
        };
        let kind = if restarted {
            LivenessKind::Restarted
        } else {
            LivenessKind::Joined
        };
        self.push(robot_id, kind, silent);
    }

    /// Whether the robot's latest process got the fleet table before its first episode.
    pub fn warm_started(&mut self, robot_id: u32, yes: bool) {
        if let Some(l) = self.lines.get_mut(robot_id as usize) {
            l.warm_started = yes;
        }
    }

    /// Whether `robot_id`'s current process registered after `t` (a node listing made before
    /// that cannot have seen it).
    pub fn joined_since(&self, robot_id: usize, t: Instant) -> bool {
        self.lines
            .get(robot_id)
            .and_then(|l| l.joined_at)
            .is_some_and(|j| j >= t)
    }

    /// A valid message from `robot_id` arrived (a hung robot that speaks again: `resumed`).
    #[inline]
    pub fn seen(&mut self, robot_id: u32, now: Instant) {
        if let Some(l) = self.lines.get_mut(robot_id as usize) {
            l.last_seen = Some(now);
            if l.hung {
                l.hung = false;
                self.push(robot_id, LivenessKind::Resumed, 0);
            }
        }
    }

    /// The robot's process died (its node is gone or dead): event `lost`.
    pub fn lost(&mut self, robot_id: u32, now: Instant) {
        let silent = self.silent_ms(robot_id, now);
        if let Some(l) = self.lines.get_mut(robot_id as usize) {
            l.lost_at = Some(now);
            l.hung = false;
        }
        self.push(robot_id, LivenessKind::Lost, silent);
    }

    /// The robot's process ended before it ever registered: event `neverregistered`.
    pub fn never_registered(&mut self, robot_id: u32, now: Instant) {
        if let Some(l) = self.lines.get_mut(robot_id as usize) {
            l.lost_at = Some(now);
        }
        self.push(robot_id, LivenessKind::NeverRegistered, 0);
    }

    /// Heartbeat deadlines: each robot for which `busy(id)` holds (neither done nor lost) and
    /// that sent nothing for the deadline becomes hung (once; event `hung`); returns them.
    /// A process that has not spoken since it joined is still starting up (a restarted robot on
    /// a loaded machine): it gets four deadlines. Call it only with every inbox drained, so a
    /// coordinator that is behind never blames a robot.
    pub fn deadlines(&mut self, now: Instant, busy: impl Fn(usize) -> bool) -> Vec<u32> {
        let mut hung = Vec::new();
        for id in 0..self.lines.len() {
            let line = self.lines[id];
            let deadline = if line.last_seen == line.joined_at {
                self.hang_after * 4
            } else {
                self.hang_after
            };
            let late = line
                .last_seen
                .is_some_and(|t| now.saturating_duration_since(t) >= deadline);
            if busy(id) && late && !line.hung {
                self.lines[id].hung = true;
                let silent = self.silent_ms(id as u32, now);
                self.push(id as u32, LivenessKind::Hung, silent);
                hung.push(id as u32);
            }
        }
        hung
    }

    /// Whether a lost or hung robot no longer holds up the end of the run: a hung one never
    /// does; a lost one does while a restart may still bring it back.
    pub fn settled(&self, robot_id: usize, lost: bool, now: Instant) -> bool {
        let Some(l) = self.lines.get(robot_id) else {
            return true;
        };
        if l.hung {
            return true;
        }
        lost && (l.restarts >= self.restarts_allowed
            || l.lost_at
                .is_none_or(|t| now.saturating_duration_since(t) >= self.wait_restart))
    }

    /// Robots currently hung.
    pub fn hung(&self) -> Vec<u32> {
        (0..self.lines.len() as u32)
            .filter(|&i| self.lines[i as usize].hung)
            .collect()
    }

    /// Whether `robot_id` is hung.
    pub fn is_hung(&self, robot_id: usize) -> bool {
        self.lines.get(robot_id).is_some_and(|l| l.hung)
    }

    /// Restarts of `robot_id` and whether its latest process got the fleet table.
    pub fn restarts(&self, robot_id: usize) -> (u32, bool) {
        self.lines
            .get(robot_id)
            .map_or((0, false), |l| (l.restarts, l.warm_started))
    }

    /// Takes over the liveness record of a coordinator that died (from its checkpoint): its
    /// events (not announced again), and per robot its restarts, whether its latest process
    /// was warm-started (a robot lost before the takeover is settled at once). Then raises
    /// `coordinatorrestarted` (robot id `ROBOT_ID_ALL`) with `silent_ms`, the time since the
    /// dead coordinator's last checkpoint.
    pub fn resume(
        &mut self,
        events: Vec<LivenessEvent>,
        robots: &[RobotCheckpoint],
        silent_ms: u64,
    ) {
        self.events = events;
        self.announced = self.events.len();
        for r in robots {
            if let Some(l) = self.lines.get_mut(r.robot_id as usize) {
                // a robot lost before the takeover keeps no loss time: it is settled at once
                // (no restart of it is waited for), and a restart that comes still joins
                *l = Lifeline {
                    restarts: r.restarts,
                    warm_started: r.warm_started,
                    ..Lifeline::default()
                };
            }
        }
        self.push(ROBOT_ID_ALL, LivenessKind::CoordinatorRestarted, silent_ms);
    }

    /// Every event so far.
    pub fn events(&self) -> &[LivenessEvent] {
        &self.events
    }

    /// The events raised since the last call (to announce on stdout).
    pub fn take_new(&mut self) -> &[LivenessEvent] {
        let from = std::mem::replace(&mut self.announced, self.events.len());
        &self.events[from..]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HANG: Duration = Duration::from_millis(100);

    fn kinds(life: &Life) -> Vec<(u32, LivenessKind)> {
        life.events().iter().map(|e| (e.robot_id, e.kind)).collect()
    }

    #[test]
    fn node_names_map_to_robot_ids() {
        assert_eq!(robot_of_node("qfleet-robot-3"), Some(3));
        assert_eq!(robot_of_node("qfleet-coordinator"), None);
        assert_eq!(robot_of_node("qfleet-robot-x"), None);
    }

    fn node(name: &str, liveness: Liveness) -> bus::NodeInfo {
        bus::NodeInfo {
            name: name.into(),
            pid: Some(1),
            executable: "robot-agent".into(),
            liveness,
            id: None,
        }
    }

    #[test]
    fn a_listing_shows_robots_alive_by_node_name_and_ignores_others() {
        let report = NodeReport {
            nodes: vec![
                node("qfleet-coordinator", Liveness::Alive),
                node("qfleet-robot-0", Liveness::Alive),
                node("qfleet-robot-2", Liveness::Dead),
                node("qfleet-robot-9", Liveness::Alive), // outside the fleet
            ],
            ..NodeReport::default()
        };
        assert_eq!(alive_in(&report, 3), Some(vec![true, false, false]));
    }

    #[test]
    fn a_listing_with_an_unreadable_node_proves_no_death() {
        // out of file descriptors, iceoryx2 cannot read a live robot's node: it must not be
        // reported lost (it once was, for the last robots of a 256-robot run)
        for unreadable in [Liveness::Inaccessible, Liveness::Undefined] {
            let report = NodeReport {
                nodes: vec![
                    node("qfleet-robot-0", Liveness::Alive),
                    node("", unreadable),
                ],
                ..NodeReport::default()
            };
            assert_eq!(alive_in(&report, 2), None, "{unreadable:?}");
        }
    }

    #[test]
    fn a_silent_busy_robot_is_hung_once_and_resumes_when_it_speaks() {
        let t0 = Instant::now();
        let mut life = Life::new(2, HANG, 0, HANG);
        life.admitted(0, t0);
        life.admitted(1, t0);
        life.seen(0, t0 + HANG / 2);
        life.seen(1, t0 + HANG / 2);
        assert!(life.deadlines(t0 + HANG, |_| true).is_empty());
        let t1 = t0 + HANG * 2;
        life.seen(1, t1);
        assert_eq!(life.deadlines(t1, |_| true), vec![0]);
        assert_eq!(
            life.deadlines(t1 + HANG, |_| true),
            vec![1],
            "0 is not raised twice"
        );
        assert!(life.is_hung(0) && life.settled(0, false, t1));
        life.seen(0, t1 + HANG);
        assert!(!life.is_hung(0));
        assert_eq!(
            kinds(&life),
            vec![
                (0, LivenessKind::Hung),
                (1, LivenessKind::Hung),
                (0, LivenessKind::Resumed)
            ]
        );
    }

    #[test]
    fn a_robot_that_is_done_or_starting_up_is_not_hung() {
        let t0 = Instant::now();
        let mut life = Life::new(1, HANG, 0, HANG);
        life.admitted(0, t0);
        assert!(
            life.deadlines(t0 + HANG * 3, |_| true).is_empty(),
            "start-up grace"
        );
        assert_eq!(life.deadlines(t0 + HANG * 4, |_| true), vec![0]);
        let mut life = Life::new(1, HANG, 0, HANG);
        life.admitted(0, t0);
        life.seen(0, t0);
        assert!(life.deadlines(t0 + HANG * 9, |_| false).is_empty());
    }

    #[test]
    fn a_lost_robot_holds_up_the_end_only_while_a_restart_may_come() {
        let t0 = Instant::now();
        let mut life = Life::new(2, HANG, 1, HANG * 10);
        life.admitted(0, t0);
        life.lost(0, t0);
        assert!(
            !life.settled(0, true, t0 + HANG),
            "a restart may still come"
        );
        assert!(life.settled(0, true, t0 + HANG * 10), "waited long enough");
        life.joined(0, true, t0 + HANG);
        assert_eq!(life.restarts(0), (1, false));
        life.lost(0, t0 + HANG * 2);
        assert!(life.settled(0, true, t0 + HANG * 2), "no restarts left");
        // without a restart policy a loss settles at once
        let mut life = Life::new(1, HANG, 0, HANG * 10);
        life.lost(0, t0);
        assert!(life.settled(0, true, t0));
        assert!(
            !life.settled(0, false, t0),
            "alive and not hung: not settled"
        );
    }

    #[test]
    fn joins_and_restarts_are_events_and_each_is_announced_once() {
        let t0 = Instant::now();
        let mut life = Life::new(2, HANG, 3, HANG);
        life.joined(1, false, t0);
        life.joined(0, true, t0);
        assert_eq!(life.take_new().len(), 2);
        assert!(life.take_new().is_empty());
        life.lost(1, t0);
        assert_eq!(life.take_new()[0].kind, LivenessKind::Lost);
        assert_eq!(
            kinds(&life),
            vec![
                (1, LivenessKind::Joined),
                (0, LivenessKind::Restarted),
                (1, LivenessKind::Lost)
            ]
        );
        assert!(life.joined_since(0, t0) && !life.joined_since(0, t0 + HANG));
    }

    #[test]
    fn a_restarted_coordinator_keeps_the_record_and_says_it_took_over() {
        let t0 = Instant::now();
        let mut before = Life::new(2, HANG, 3, HANG * 10);
        before.lost(1, t0);
        before.joined(1, true, t0);
        before.warm_started(1, true);
        before.take_new();
        let fleet = [
            RobotCheckpoint {
                robot_id: 0,
                ..RobotCheckpoint::default()
            },
            RobotCheckpoint {
                robot_id: 1,
                restarts: 1,
                warm_started: true,
                ..RobotCheckpoint::default()
            },
        ];
        let mut after = Life::new(2, HANG, 3, HANG * 10);
        after.resume(before.events().to_vec(), &fleet, 700);
        assert_eq!(after.restarts(1), (1, true));
        assert_eq!(
            kinds(&after),
            vec![
                (1, LivenessKind::Lost),
                (1, LivenessKind::Restarted),
                (ROBOT_ID_ALL, LivenessKind::CoordinatorRestarted)
            ]
        );
        let new = after.take_new();
        assert_eq!(new.len(), 1, "only the takeover is announced: {new:?}");
        assert_eq!(new[0].silent_ms, 700);
        // a robot lost before the takeover does not hold up the end
        assert!(after.settled(0, true, Instant::now()));
    }
}
