//! The limits a topic's publish-subscribe and wake event services are created with, from the
//! fleet's size (named `sizes`, not `limits`, beside the crate's own `limits` module).

use bus_schema::names::{Delivery, Direction, Topic};

use crate::BusConfig;
use crate::config::OBSERVER_SLOTS;

/// The limits a topic's publish-subscribe service and its wake event service are created with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TopicLimits {
    /// Publishers (and wake notifiers) the service admits.
    pub max_publishers: usize,
    /// Subscribers (and wake listeners) the service admits.
    pub max_subscribers: usize,
    /// Processes (nodes) that may open the service.
    pub max_nodes: usize,
    /// Samples buffered per publisher→subscriber connection.
    pub subscriber_buffer: usize,
    /// Samples a subscriber may hold at once.
    pub subscriber_borrowed: usize,
    /// Samples a publisher may have loaned at once.
    pub publisher_loans: usize,
    /// Last samples replayed to a subscriber that connects late.
    pub history: usize,
    /// Latest-wins (`true`) or lossless (`false`).
    pub safe_overflow: bool,
}

/// The limits of `topic` for the fleet described by `cfg` (see the crate docs for the table).
///
/// Ports and nodes are the fleet's (R robots + 1 coordinator), plus `spare_ports` for a
/// restarted process whose dead predecessor is not cleaned yet, plus [`OBSERVER_SLOTS`] for
/// outside readers: an observer that follows [`crate::Observer`]'s admission never takes a slot
/// a restart needs.
pub fn limits(cfg: &BusConfig, topic: Topic) -> TopicLimits {
    let robots = cfg.robots as usize;
    let spare = cfg.spare_ports as usize + OBSERVER_SLOTS as usize;
    let (max_publishers, max_subscribers, subscriber_borrowed) = match topic.direction() {
        Direction::RobotToCoordinator => (robots + spare, 1 + spare, 4),
        Direction::CoordinatorToRobot => (1 + spare, robots + spare, 2),
    };
    let (subscriber_buffer, history) = match topic {
        // one registration per robot, plus a few re-sends while the coordinator starts
        Topic::Register => (4, 0),
        Topic::RobotState => (cfg.state_buffer, 1),
        Topic::Discovery => (cfg.discovery_buffer, 0),
        Topic::Hints => (cfg.hint_buffer, 0),
        Topic::Report => (4, 0),
        // broadcast: the start burst — one Ack per robot, one AssignGoal per robot, Start and a
        // few Phase/Stop — passes through every robot's buffer. It must fit whole: on a loaded
        // machine a robot that registered early may not run at all while the others register,
        // and a lossless send into its full buffer would block the coordinator (issue 10 #11:
        // 64 slots failed at 256 robots with "not delivered within 1s").
        Topic::Control => (control_buffer(robots), 0),
        Topic::Merged => (cfg.merged_buffer, 1),
        // broadcast and cumulative: room for one ack per robot, twice, so a robot's own latest
        // ack is not pushed out by one round of acks to the others
        Topic::Ack => (2 * robots + 8, 0),
        // one relay per distinct (goal, cell) of the run, a few dozen per goal; as deep as the
        // discovery inbox so a burst of relays never waits for a robot between two polls
        Topic::Relay => (cfg.discovery_buffer, 0),
        // shared grid: one intent per robot per tick, answered by one grant per tick; only the
        // newest matters (an older one is for a tick already resolved), and a robot that
        // connects late reads the current configuration from the history
        Topic::Intent => (4, 0),
        // one horizon per robot per wake of the fleet (every few ticks); only the newest matters
        Topic::Horizon => (4, 0),
        Topic::Grant => (2, 1),
    };
    TopicLimits {
        max_publishers,
        max_subscribers,
        max_nodes: cfg.max_nodes(),
        subscriber_buffer,
        subscriber_borrowed,
        publisher_loans: 2,
        history,
        safe_overflow: topic.delivery() == Delivery::LatestWins,
    }
}

/// Control samples buffered per robot: the whole start burst for `robots` (see [`limits`]).
pub fn control_buffer(robots: usize) -> usize {
    2 * robots + 16
}
