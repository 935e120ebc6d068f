//! Who belongs to the fleet: the coordinator's admission decisions and the binding of each
//! robot id to the iceoryx2 node that registered it, without IO.
//!
//! A [`Roster`] answers every `Register` (the start handshake, a robot that missed its `Ack`, a
//! restarted process, a clash with a live robot of the same id) with a [`Verdict`] that the
//! IO loop carries out. It also remembers, per robot id, the node id of the sample that
//! registered it ([`Sender`], iceoryx2's `UniqueNodeId` from the sample header): every later
//! hint, discovery, state and report for that id is accepted only from that node
//! ([`Roster::check_sender`]), so a same-user process that publishes plausible robot ids is
//! rejected and counted. (A process of the same user can still forge the header itself: this
//! raises the bar from "write a robot id" to "write iceoryx2's shared memory by hand"; see the
//! README's threat model.)

use bus::bus_schema::Register;
use bus::{Expected, check_register};

/// The iceoryx2 node id (`UniqueNodeId::value`) a sample came from.
pub type Sender = u128;

/// One robot id's current holder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Holder {
    pid: u32,
    node: Sender,
    lost: bool,
}

/// What the coordinator does with one `Register`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// A robot id seen for the first time in this coordinator: acknowledge it.
    Joined,
    /// The same process (same pid, same node) registering again (it missed its `Ack`):
    /// acknowledge it again, nothing else changes.
    AckAgain,
    /// A new process took the place of a dead one: acknowledge it, forget the dead one's
    /// progress, warm-start it from the fleet table.
    Restarted,
    /// Refused with this reason, which is sent to the robot (`Refuse`).
    Refuse(String),
    /// Dropped and counted: no `Refuse` is sent, because a live robot holding this id would
    /// read it as its own (the `Refuse` control is addressed by robot id only).
    Drop(String),
}

impl Verdict {
    /// Whether the registering robot is (now) a member of the fleet.
    pub fn admitted(&self) -> bool {
        matches!(
            self,
            Verdict::Joined | Verdict::AckAgain | Verdict::Restarted
        )
    }
}

/// Why a message was not accepted from its sender.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SenderError {
    /// The robot id is outside the fleet or never registered.
    #[error("robot id {0} is not a registered member of the fleet")]
    NotMember(u32),
    /// The robot id is registered by another node (a forged or stray message).
    #[error("robot id {0} is registered by another node")]
    WrongNode(u32),
}

/// The fleet's members by robot id, with the node each one registered from.
#[derive(Debug, Clone)]
pub struct Roster {
    expected: Expected,
    holders: Vec<Option<Holder>>,
}

impl Roster {
    /// An empty roster for the fleet `expected` describes.
    pub fn new(expected: Expected) -> Self {
        Roster {
            expected,
            holders: vec![None; expected.robots as usize],
        }
    }

    /// What the coordinator expects of every robot.
    pub fn expected(&self) -> &Expected {
        &self.expected
    }

    /// Decides about one `Register` received from node `from`. `holder_alive(pid)` is asked
    /// (only when it matters) whether the process currently holding the id is still running.
    pub fn on_register(
        &mut self,
        reg: &Register,
        from: Sender,
        holder_alive: impl FnOnce(u32) -> bool,
    ) -> Verdict {
        let id = reg.robot_id;
        let holder = self.holders.get(id as usize).copied().flatten();
        let live_holder = holder.filter(|h| !h.lost);
        if let Err(why) = check_register(reg, &self.expected) {
            // never answer a Refuse that a live robot of that id would read as its own
            return match live_holder {
                Some(h) if h.pid != reg.pid || h.node != from => Verdict::Drop(why),
                _ => Verdict::Refuse(why),
            };
        }
        let slot = &mut self.holders[id as usize];
        let fresh = Holder {
            pid: reg.pid,
            node: from,
            lost: false,
        };
        match holder {
            None => {
                *slot = Some(fresh);
                Verdict::Joined
            }
            Some(h) if h.pid == reg.pid && h.node == from => {
                if let Some(h) = slot.as_mut() {
                    h.lost = false;
                }
                Verdict::AckAgain
            }
            Some(h) if !h.lost && holder_alive(h.pid) => Verdict::Drop(format!(
                "robot id {id} already taken by pid {} (a live process)",
                h.pid
            )),
            Some(_) => {
                *slot = Some(fresh);
                Verdict::Restarted
            }
        }
    }

    /// Whether a message for `robot_id` may be trusted when it came from node `from`.
    pub fn check_sender(&self, robot_id: u32, from: Sender) -> Result<(), SenderError> {
        match self.holders.get(robot_id as usize).copied().flatten() {
            None => Err(SenderError::NotMember(robot_id)),
            Some(h) if h.node != from => Err(SenderError::WrongNode(robot_id)),
            Some(_) => Ok(()),
        }
    }

    /// Marks `robot_id`'s process as dead (its node is gone): a new process may take the id.
    pub fn lost(&mut self, robot_id: u32) {
        if let Some(Some(h)) = self.holders.get_mut(robot_id as usize) {
            h.lost = true;
        }
    }

    /// Whether `robot_id` registered (and was not replaced by nothing since).
    pub fn is_member(&self, robot_id: u32) -> bool {
        self.holders
            .get(robot_id as usize)
            .is_some_and(Option::is_some)
    }

    /// The pid `robot_id` registered with.
    pub fn pid(&self, robot_id: u32) -> Option<u32> {
        self.holders
            .get(robot_id as usize)
            .copied()
            .flatten()
            .map(|h| h.pid)
    }

    /// Robot ids that registered.
    pub fn members(&self) -> usize {
        self.holders.iter().filter(|h| h.is_some()).count()
    }

    /// Robot ids that never registered.
    pub fn missing(&self) -> Vec<u32> {
        (0..self.expected.robots)
            .filter(|&i| !self.is_member(i))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bus::bus_schema::SCHEMA_VERSION;

    const EXPECTED: Expected = Expected {
        robots: 2,
        map_hash: 42,
        width: 10,
        height: 8,
    };

    fn reg(robot_id: u32, pid: u32) -> Register {
        Register {
            schema_version: SCHEMA_VERSION,
            robot_id,
            pid,
            width: 10,
            height: 8,
            map_hash: 42,
            ..Register::ZEROED
        }
    }

    fn never(_: u32) -> bool {
        panic!("the holder's liveness must not be asked here")
    }

    #[test]
    fn a_first_registration_joins_and_binds_the_id_to_its_node() {
        let mut r = Roster::new(EXPECTED);
        assert_eq!(r.on_register(&reg(0, 100), 7, never), Verdict::Joined);
        assert_eq!(r.check_sender(0, 7), Ok(()));
        assert_eq!(r.check_sender(0, 8), Err(SenderError::WrongNode(0)));
        assert_eq!(r.check_sender(1, 7), Err(SenderError::NotMember(1)));
        assert_eq!(r.check_sender(99, 7), Err(SenderError::NotMember(99)));
        assert_eq!(r.missing(), vec![1]);
    }

    #[test]
    fn the_same_process_registering_again_is_acked_again() {
        let mut r = Roster::new(EXPECTED);
        r.on_register(&reg(0, 100), 7, never);
        assert_eq!(r.on_register(&reg(0, 100), 7, never), Verdict::AckAgain);
        assert_eq!(r.members(), 1);
    }

    #[test]
    fn a_schema_or_map_mismatch_is_refused_with_a_reason() {
        let mut r = Roster::new(EXPECTED);
        let mut bad = reg(0, 100);
        bad.schema_version = 77;
        assert!(
            matches!(r.on_register(&bad, 7, never), Verdict::Refuse(why) if why.contains("schema"))
        );
        let mut bad = reg(0, 100);
        bad.map_hash = 43;
        assert!(
            matches!(r.on_register(&bad, 7, never), Verdict::Refuse(why) if why.contains("map hash"))
        );
        assert!(matches!(
            r.on_register(&reg(5, 100), 7, never),
            Verdict::Refuse(_)
        ));
        assert!(!r.is_member(0));
    }

    #[test]
    fn a_bad_registration_for_a_live_robots_id_is_dropped_without_a_refuse() {
        let mut r = Roster::new(EXPECTED);
        r.on_register(&reg(0, 100), 7, never);
        let mut forged = reg(0, 666);
        forged.schema_version = 77;
        assert!(matches!(r.on_register(&forged, 9, never), Verdict::Drop(_)));
        assert_eq!(r.check_sender(0, 7), Ok(()));
    }

    #[test]
    fn a_taken_id_with_a_live_holder_is_dropped() {
        let mut r = Roster::new(EXPECTED);
        r.on_register(&reg(0, 100), 7, never);
        let v = r.on_register(&reg(0, 200), 9, |pid| {
            assert_eq!(pid, 100);
            true
        });
        assert!(matches!(v, Verdict::Drop(why) if why.contains("already taken by pid 100")));
        assert_eq!(r.pid(0), Some(100));
        assert_eq!(r.check_sender(0, 9), Err(SenderError::WrongNode(0)));
    }

    #[test]
    fn a_forged_register_with_the_holders_pid_from_another_node_is_not_a_reack() {
        let mut r = Roster::new(EXPECTED);
        r.on_register(&reg(0, 100), 7, never);
        assert!(matches!(
            r.on_register(&reg(0, 100), 9, |_| true),
            Verdict::Drop(_)
        ));
        assert_eq!(r.check_sender(0, 7), Ok(()));
    }

    #[test]
    fn a_new_process_replaces_a_dead_holder_and_takes_over_the_binding() {
        let mut r = Roster::new(EXPECTED);
        r.on_register(&reg(0, 100), 7, never);
        // the old process died, the liveness check has not seen it yet
        assert_eq!(
            r.on_register(&reg(0, 200), 9, |_| false),
            Verdict::Restarted
        );
        assert_eq!(r.check_sender(0, 9), Ok(()));
        assert_eq!(r.check_sender(0, 7), Err(SenderError::WrongNode(0)));
        // once the loss is known, nobody is asked
        r.lost(0);
        assert_eq!(r.on_register(&reg(0, 300), 11, never), Verdict::Restarted);
        assert_eq!(r.pid(0), Some(300));
    }
}
