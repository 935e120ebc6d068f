//! Control messages are obeyed only from the run's coordinator.
//!
//! Any process of the same user can open `coord/control` and publish a `Stop` (issue 10: a
//! forged `Stop` made every robot quit at 17 %). iceoryx2 stamps every sample with the unique
//! id of the publisher port that sent it; a robot records the id of the publisher whose `Ack`
//! accepted its registration (the start handshake, or a re-join after a coordinator restart)
//! and drops — and counts as `rejected` — every control from any other publisher.
//!
//! A restarted coordinator (new process, new publisher) legitimately changes the id: the robot
//! re-registers with it ([`crate::reconnect`]) and its `Ack` moves the gate to the new
//! publisher. What this does not stop: a forger that answers a registration faster than the
//! coordinator, or one that publishes from inside the coordinator's process; the threat model
//! says so (same user: everything can be forged, this only raises the bar to a race).
//!
//! [`ControlGate`] is generic over the identity, so the rule is tested without iceoryx2.

/// What the gate decided about one control.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// From the coordinator: obey it.
    Obey,
    /// From another publisher (or before any coordinator accepted this robot): drop it.
    Drop,
}

/// The robot's record of which publisher is its coordinator.
#[derive(Debug, Clone, Default)]
pub struct ControlGate<Id> {
    coordinator: Option<Id>,
    rejected: u64,
}

impl<Id: Copy + Eq> ControlGate<Id> {
    /// A gate that knows no coordinator yet (drops everything until [`accept`](Self::accept)).
    pub fn new() -> Self {
        ControlGate {
            coordinator: None,
            rejected: 0,
        }
    }

    /// The publisher `id` answered this robot's registration with `Ack`: it is the coordinator
    /// from now on (the first handshake, or a restarted coordinator after a re-join).
    pub fn accept(&mut self, id: Id) {
        self.coordinator = Some(id);
    }

    /// Whether a control from publisher `from` is obeyed; a dropped one is counted.
    pub fn check(&mut self, from: Id) -> Verdict {
        if self.coordinator == Some(from) {
            Verdict::Obey
        } else {
            self.rejected += 1;
            Verdict::Drop
        }
    }

    /// The coordinator's publisher, once known.
    pub fn coordinator(&self) -> Option<Id> {
        self.coordinator
    }

    /// Controls dropped so far.
    pub fn rejected(&self) -> u64 {
        self.rejected
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const COORDINATOR: u32 = 11;
    const FORGER: u32 = 66;
    const RESTARTED: u32 = 12;

    #[test]
    fn controls_from_the_coordinator_that_accepted_the_robot_are_obeyed() {
        let mut g = ControlGate::new();
        g.accept(COORDINATOR);
        assert_eq!(g.check(COORDINATOR), Verdict::Obey);
        assert_eq!(g.check(COORDINATOR), Verdict::Obey);
        assert_eq!(g.rejected(), 0);
    }

    #[test]
    fn a_forged_stop_from_another_publisher_is_dropped_and_counted() {
        let mut g = ControlGate::new();
        g.accept(COORDINATOR);
        assert_eq!(g.check(FORGER), Verdict::Drop);
        assert_eq!(g.check(FORGER), Verdict::Drop);
        assert_eq!(g.rejected(), 2);
        assert_eq!(
            g.coordinator(),
            Some(COORDINATOR),
            "a forger never moves the gate"
        );
    }

    #[test]
    fn nothing_is_obeyed_before_a_coordinator_accepted_the_robot() {
        let mut g = ControlGate::<u32>::new();
        assert_eq!(g.check(COORDINATOR), Verdict::Drop);
        assert_eq!(g.rejected(), 1);
    }

    #[test]
    fn a_restarted_coordinator_takes_over_once_it_accepted_the_robot_again() {
        let mut g = ControlGate::new();
        g.accept(COORDINATOR);
        // the new coordinator's controls before its Ack of our re-registration: not yet its
        assert_eq!(g.check(RESTARTED), Verdict::Drop);
        g.accept(RESTARTED);
        assert_eq!(g.check(RESTARTED), Verdict::Obey);
        // the dead one's publisher id is no longer the coordinator's
        assert_eq!(g.check(COORDINATOR), Verdict::Drop);
        assert_eq!(g.rejected(), 2);
    }
}
