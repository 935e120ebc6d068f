//! Whose messages an observer shows: the run's own processes only, without IO.
//!
//! Anything of the same user can publish in a run's prefix (README "Threat model"); a live view
//! or a recording that showed every sample as the run's own drew a phantom robot for a stray
//! process's `RobotState` (issue 27). [`Members`] decides per message from its sender (the
//! iceoryx2 node id in the sample's header) and, for a robot's messages, its robot id:
//!
//! - a sender is the run's own when its node belongs to a process the launcher started (the
//!   IO side resolves a node id once, from the node listing: [`origin_of`]);
//! - a robot's message (registration, state, discovery, hints, report, intent) must also name
//!   a robot id of the fleet (`< robots`), and the robot id is bound to the first own node that
//!   sent for it: a second node of the run sending for the same id (a restart) takes it over
//!   only once it registers;
//! - the rest are dropped and counted per topic ([`Members::others`]).
//!
//! A recording keeps no sender, so `replay` applies the robot-id part alone
//! ([`robot_of`], `crate::replay`).

use std::collections::HashMap;

use bus::NodeInfo;
use bus_schema::names::Topic;

use crate::decode::Msg;
use crate::stats::topic_index;

/// Where a sender's node belongs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// A process of the run (started by its launcher).
    Own,
    /// Any other process that publishes in the run's prefix.
    Other,
}

/// The verdict on one message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Show (and record) it.
    Show,
    /// Drop it; counted as another process's.
    Other,
    /// Its sender is not known yet: resolve it ([`origin_of`]), [`Members::learn`] and ask
    /// again.
    Resolve,
}

/// The robot id a robot's message names (`None` for the coordinator's messages).
pub fn robot_of(m: &Msg<'_>) -> Option<u32> {
    match m {
        Msg::Register(x) => Some(x.robot_id),
        Msg::State(x) => Some(x.robot_id),
        Msg::Discovery(x) => Some(x.robot_id),
        Msg::Hints(x) => Some(x.robot_id),
        Msg::Report(x) => Some(x.robot_id),
        Msg::Intent(x) => Some(x.robot_id),
        Msg::Horizon(x) => Some(x.robot_id),
        Msg::Control(_) | Msg::Merged(_) | Msg::Ack(_) | Msg::Relay(_) | Msg::Grant(_) => None,
    }
}

/// The origin of node `id` from a node listing: own when its process is `launcher` itself (a
/// bridge it runs for robots on other hosts) or was started by it (its parent,
/// `parent_of(pid)`); other when it is listed under another parent;
/// other as well when it is not in the listing at all (a node that left before it could be
/// asked about proves nothing, and a run's own robot is listed while it sends).
pub fn origin_of<'a>(
    id: u128,
    listing: impl IntoIterator<Item = &'a NodeInfo>,
    launcher: i32,
    parent_of: impl Fn(i32) -> Option<i32>,
) -> Origin {
    let pid = listing
        .into_iter()
        .find(|n| n.id == Some(id))
        .and_then(|n| n.pid);
    match pid {
        Some(pid) if pid == launcher || parent_of(pid) == Some(launcher) => Origin::Own,
        _ => Origin::Other,
    }
}

/// The parent of process `pid` (`/proc/<pid>/stat`), if it is alive.
pub fn parent_of(pid: i32) -> Option<i32> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // the fields after the ")" that closes the command name: state, ppid, …
    let (_, rest) = stat.rsplit_once(')')?;
    rest.split_whitespace().nth(1)?.parse().ok()
}

/// The observer's view of who belongs to the run (see the module documentation).
#[derive(Debug, Clone)]
pub struct Members {
    robots: u32,
    nodes: HashMap<u128, Origin>,
    /// Robot id → the own node that sends for it.
    holder: HashMap<u32, u128>,
    others: [u64; Topic::ALL.len()],
}

impl Members {
    /// A run of `robots` robots, no sender known yet.
    pub fn new(robots: u32) -> Self {
        Self {
            robots,
            nodes: HashMap::new(),
            holder: HashMap::new(),
            others: [0; Topic::ALL.len()],
        }
    }

    /// Remembers where node `id` belongs.
    pub fn learn(&mut self, id: u128, origin: Origin) {
        self.nodes.insert(id, origin);
    }

    /// The verdict on `m` from node `sender`; a dropped message is counted.
    pub fn judge(&mut self, sender: u128, m: &Msg<'_>) -> Verdict {
        let Some(&origin) = self.nodes.get(&sender) else {
            return Verdict::Resolve;
        };
        let show = origin == Origin::Own
            && match robot_of(m) {
                None => true,
                Some(r) if r >= self.robots => false,
                Some(r) => match self.holder.get(&r) {
                    None => {
                        self.holder.insert(r, sender);
                        true
                    }
                    Some(&h) if h == sender => true,
                    // a restarted robot (a new process, a new node) takes its id over when it
                    // registers; another own node's other messages for that id are not shown
                    Some(_) if matches!(m, Msg::Register(_)) => {
                        self.holder.insert(r, sender);
                        true
                    }
                    Some(_) => false,
                },
            };
        if show {
            Verdict::Show
        } else {
            self.others[topic_index(m.topic())] += 1;
            Verdict::Other
        }
    }

    /// Messages dropped as other processes', per topic (in [`Topic::ALL`]'s order).
    pub fn others(&self) -> [u64; Topic::ALL.len()] {
        self.others
    }

    /// Messages dropped as other processes', in all.
    pub fn others_total(&self) -> u64 {
        self.others.iter().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bus::Liveness;
    use bus_schema::{Control, Register, RobotState};

    const OWN: u128 = 11;
    const OWN2: u128 = 12;
    const STRAY: u128 = 99;

    fn state(robot_id: u32) -> RobotState {
        RobotState {
            robot_id,
            ..RobotState::ZEROED
        }
    }

    fn members() -> Members {
        let mut m = Members::new(4);
        m.learn(OWN, Origin::Own);
        m.learn(OWN2, Origin::Own);
        m.learn(STRAY, Origin::Other);
        m
    }

    #[test]
    fn a_stray_process_in_the_prefix_is_never_shown_and_is_counted() {
        let mut m = members();
        // a phantom robot (an id outside the fleet) and a forged fleet id, from a stray node
        assert_eq!(m.judge(STRAY, &Msg::State(&state(7))), Verdict::Other);
        assert_eq!(m.judge(STRAY, &Msg::State(&state(1))), Verdict::Other);
        assert_eq!(
            m.judge(STRAY, &Msg::Control(&Control::ZEROED)),
            Verdict::Other
        );
        assert_eq!(m.others_total(), 3);
        assert_eq!(m.others()[topic_index(Topic::RobotState)], 2);
        assert_eq!(m.others()[topic_index(Topic::Control)], 1);
    }

    #[test]
    fn the_runs_own_processes_are_shown_within_the_fleet_only() {
        let mut m = members();
        assert_eq!(m.judge(OWN, &Msg::State(&state(1))), Verdict::Show);
        assert_eq!(m.judge(OWN, &Msg::Control(&Control::ZEROED)), Verdict::Show);
        // even an own process cannot show a robot the fleet does not have
        assert_eq!(m.judge(OWN, &Msg::State(&state(4))), Verdict::Other);
        assert_eq!(m.others_total(), 1);
    }

    #[test]
    fn a_robot_id_belongs_to_the_node_that_sent_for_it_until_a_new_one_registers() {
        let mut m = members();
        assert_eq!(m.judge(OWN, &Msg::State(&state(2))), Verdict::Show);
        assert_eq!(m.judge(OWN2, &Msg::State(&state(2))), Verdict::Other);
        // a restart: the new process registers and holds the id from then on
        let reg = Register {
            robot_id: 2,
            ..Register::ZEROED
        };
        assert_eq!(m.judge(OWN2, &Msg::Register(&reg)), Verdict::Show);
        assert_eq!(m.judge(OWN2, &Msg::State(&state(2))), Verdict::Show);
        assert_eq!(m.judge(OWN, &Msg::State(&state(2))), Verdict::Other);
    }

    #[test]
    fn an_unknown_sender_is_resolved_before_anything_is_shown() {
        let mut m = Members::new(4);
        assert_eq!(m.judge(5, &Msg::State(&state(0))), Verdict::Resolve);
        assert_eq!(m.others_total(), 0, "not counted before it is known");
    }

    #[test]
    fn a_node_is_own_only_when_the_launcher_started_its_process() {
        let node = |id, pid| NodeInfo {
            name: "qfleet-robot-0".into(),
            pid: Some(pid),
            executable: "robot-agent".into(),
            liveness: Liveness::Alive,
            id: Some(id),
        };
        let listing = [node(1, 100), node(2, 200), node(4, 42)];
        let parent = |pid| match pid {
            100 => Some(42),
            200 => Some(7),
            _ => None,
        };
        assert_eq!(origin_of(1, &listing, 42, parent), Origin::Own);
        // named like a robot, started by someone else
        assert_eq!(origin_of(2, &listing, 42, parent), Origin::Other);
        // not listed (left already): nothing proves it is the run's
        assert_eq!(origin_of(3, &listing, 42, parent), Origin::Other);
        // the launcher's own node (its bridge to other hosts)
        assert_eq!(origin_of(4, &listing, 42, parent), Origin::Own);
    }

    #[test]
    fn the_parent_of_this_process_is_read_from_proc() {
        let me = std::process::id() as i32;
        // SAFETY: getppid has no preconditions.
        let parent = unsafe { libc::getppid() };
        assert_eq!(parent_of(me), Some(parent));
    }
}
