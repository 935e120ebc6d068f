//! Service names, the iceoryx2 prefix of a run, and which type travels on which topic.
//!
//! Every service of a run lives under `qfleet/<run-id>/…`, and every process of the run uses the
//! iceoryx2 `global.prefix` [`iceoryx_prefix`]`(run_id)`, so two runs never see each other even
//! if they used the same service names. Run-id validation (allowed characters, length) is done by
//! the `bus` crate; the functions here only format.

use crate::coordinator_to_robot::{Control, DiscoveryAck, DiscoveryRelay, Grant, MergedHintBatch};
use crate::robot_to_coordinator::{
    FinalReport, Intent, IntentHorizon, PseudoTargetDiscovery, QHintBatch, Register, RobotState,
};

/// First element of every qfleet service name.
pub const SERVICE_ROOT: &str = "qfleet";

/// Longest run id accepted (bytes); allowed characters are `A-Z a-z 0-9 _ -`.
///
/// Short enough that `qfleet.<run-id>.` plus iceoryx2's own file names stay far below the
/// 255-byte file-name limit of `/dev/shm`.
pub const RUN_ID_MAX_LEN: usize = 48;

/// Last element appended to a topic's service name to name its wakeup event service.
pub const WAKE_SUFFIX: &str = "wake";

/// Which way a topic flows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Many robots publish, the coordinator subscribes.
    RobotToCoordinator,
    /// The coordinator publishes, every robot subscribes.
    CoordinatorToRobot,
}

/// Delivery guarantee of a topic (part of the contract: a subscriber may rely on it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Delivery {
    /// Safe overflow off, publisher retries until delivered: nothing is lost once the
    /// subscriber is connected (see the start handshake in the `bus` crate).
    Lossless,
    /// Safe overflow on: a full subscriber buffer drops its oldest sample; only the newest
    /// messages matter.
    LatestWins,
}

/// The twelve publish-subscribe topics of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Topic {
    /// `robot/register`: [`Register`].
    Register,
    /// `robot/state`: [`RobotState`].
    RobotState,
    /// `robot/discovery`: [`PseudoTargetDiscovery`].
    Discovery,
    /// `robot/hints`: [`QHintBatch`].
    Hints,
    /// `robot/report`: [`FinalReport`].
    Report,
    /// `coord/control`: [`Control`].
    Control,
    /// `coord/merged`: [`MergedHintBatch`].
    Merged,
    /// `coord/ack`: [`DiscoveryAck`].
    Ack,
    /// `coord/discovery`: [`DiscoveryRelay`].
    Relay,
    /// `robot/intent`: [`Intent`] (shared grid).
    Intent,
    /// `coord/grant`: [`Grant`] (shared grid).
    Grant,
    /// `robot/horizon`: [`IntentHorizon`] (shared grid).
    Horizon,
}

impl Topic {
    /// Every topic: the first eleven robot→coordinator first, then `Horizon`, added later and
    /// kept last so that every older topic keeps its position (the bridge's frames and
    /// recordings number topics by it).
    pub const ALL: [Topic; 12] = [
        Topic::Register,
        Topic::RobotState,
        Topic::Discovery,
        Topic::Hints,
        Topic::Report,
        Topic::Intent,
        Topic::Control,
        Topic::Merged,
        Topic::Ack,
        Topic::Relay,
        Topic::Grant,
        Topic::Horizon,
    ];

    /// The part of the service name after `qfleet/<run-id>/`.
    pub const fn path(self) -> &'static str {
        match self {
            Topic::Register => "robot/register",
            Topic::RobotState => "robot/state",
            Topic::Discovery => "robot/discovery",
            Topic::Hints => "robot/hints",
            Topic::Report => "robot/report",
            Topic::Control => "coord/control",
            Topic::Merged => "coord/merged",
            Topic::Ack => "coord/ack",
            Topic::Relay => "coord/discovery",
            Topic::Intent => "robot/intent",
            Topic::Grant => "coord/grant",
            Topic::Horizon => "robot/horizon",
        }
    }

    /// The iceoryx2 type name of the payload (what `#[type_name]` says).
    pub const fn type_name(self) -> &'static str {
        match self {
            Topic::Register => "qfleet::v1::Register",
            Topic::RobotState => "qfleet::v1::RobotState",
            Topic::Discovery => "qfleet::v1::PseudoTargetDiscovery",
            Topic::Hints => "qfleet::v1::QHintBatch",
            Topic::Report => "qfleet::v1::FinalReport",
            Topic::Control => "qfleet::v1::Control",
            Topic::Merged => "qfleet::v1::MergedHintBatch",
            Topic::Ack => "qfleet::v1::DiscoveryAck",
            Topic::Relay => "qfleet::v1::DiscoveryRelay",
            Topic::Intent => "qfleet::v1::Intent",
            Topic::Grant => "qfleet::v1::Grant",
            Topic::Horizon => "qfleet::v1::IntentHorizon",
        }
    }

    /// Payload size in bytes (iceoryx2 compares it when a port opens the service).
    pub const fn payload_size(self) -> usize {
        match self {
            Topic::Register => size_of::<Register>(),
            Topic::RobotState => size_of::<RobotState>(),
            Topic::Discovery => size_of::<PseudoTargetDiscovery>(),
            Topic::Hints => size_of::<QHintBatch>(),
            Topic::Report => size_of::<FinalReport>(),
            Topic::Control => size_of::<Control>(),
            Topic::Merged => size_of::<MergedHintBatch>(),
            Topic::Ack => size_of::<DiscoveryAck>(),
            Topic::Relay => size_of::<DiscoveryRelay>(),
            Topic::Intent => size_of::<Intent>(),
            Topic::Grant => size_of::<Grant>(),
            Topic::Horizon => size_of::<IntentHorizon>(),
        }
    }

    /// Payload alignment in bytes (also compared by iceoryx2).
    pub const fn payload_align(self) -> usize {
        match self {
            Topic::Register => align_of::<Register>(),
            Topic::RobotState => align_of::<RobotState>(),
            Topic::Discovery => align_of::<PseudoTargetDiscovery>(),
            Topic::Hints => align_of::<QHintBatch>(),
            Topic::Report => align_of::<FinalReport>(),
            Topic::Control => align_of::<Control>(),
            Topic::Merged => align_of::<MergedHintBatch>(),
            Topic::Ack => align_of::<DiscoveryAck>(),
            Topic::Relay => align_of::<DiscoveryRelay>(),
            Topic::Intent => align_of::<Intent>(),
            Topic::Grant => align_of::<Grant>(),
            Topic::Horizon => align_of::<IntentHorizon>(),
        }
    }

    /// Who publishes and who subscribes.
    pub const fn direction(self) -> Direction {
        match self {
            Topic::Register
            | Topic::RobotState
            | Topic::Discovery
            | Topic::Hints
            | Topic::Report
            | Topic::Intent
            | Topic::Horizon => Direction::RobotToCoordinator,
            Topic::Control | Topic::Merged | Topic::Ack | Topic::Relay | Topic::Grant => {
                Direction::CoordinatorToRobot
            }
        }
    }

    /// Lossless or latest-wins; see the `bus` crate documentation for the reasons.
    pub const fn delivery(self) -> Delivery {
        match self {
            Topic::Register | Topic::Discovery | Topic::Report | Topic::Control | Topic::Relay => {
                Delivery::Lossless
            }
            Topic::RobotState
            | Topic::Hints
            | Topic::Merged
            | Topic::Ack
            | Topic::Intent
            | Topic::Horizon
            | Topic::Grant => Delivery::LatestWins,
        }
    }

    /// Full publish-subscribe service name: `qfleet/<run-id>/<path>`.
    pub fn service_name(self, run_id: &str) -> String {
        format!("{}/{}", run_root(run_id), self.path())
    }

    /// Name of the event service that wakes the topic's subscribers: `qfleet/<run-id>/<path>/wake`.
    pub fn wake_service_name(self, run_id: &str) -> String {
        format!("{}/{}/{WAKE_SUFFIX}", run_root(run_id), self.path())
    }
}

/// `qfleet/<run-id>`: the common start of all service names of a run.
pub fn run_root(run_id: &str) -> String {
    format!("{SERVICE_ROOT}/{run_id}")
}

/// The iceoryx2 `global.prefix` every process of the run must use: `qfleet.<run-id>.`.
///
/// All shared-memory and bookkeeping files of the run start with it (in `/dev/shm` and under
/// iceoryx2's root path `/tmp/iceoryx2/`), which is what makes runs invisible to each other and
/// lets `qfleet clean` find leftovers. The dots cannot occur in a run id, so the run id can be
/// read back from a file name unambiguously.
pub fn iceoryx_prefix(run_id: &str) -> String {
    format!("{SERVICE_ROOT}.{run_id}.")
}

/// `qfleet/<run-id>/robot/state` ([`RobotState`], latest-wins).
pub fn robot_state(run_id: &str) -> String {
    Topic::RobotState.service_name(run_id)
}

/// `qfleet/<run-id>/robot/discovery` ([`PseudoTargetDiscovery`], lossless).
pub fn robot_discovery(run_id: &str) -> String {
    Topic::Discovery.service_name(run_id)
}

/// `qfleet/<run-id>/robot/hints` ([`QHintBatch`], latest-wins).
pub fn robot_hints(run_id: &str) -> String {
    Topic::Hints.service_name(run_id)
}

/// `qfleet/<run-id>/robot/register` ([`Register`], lossless).
pub fn robot_register(run_id: &str) -> String {
    Topic::Register.service_name(run_id)
}

/// `qfleet/<run-id>/robot/report` ([`FinalReport`], lossless).
pub fn robot_report(run_id: &str) -> String {
    Topic::Report.service_name(run_id)
}

/// `qfleet/<run-id>/coord/control` ([`Control`], lossless).
pub fn coord_control(run_id: &str) -> String {
    Topic::Control.service_name(run_id)
}

/// `qfleet/<run-id>/coord/merged` ([`MergedHintBatch`], latest-wins).
pub fn coord_merged(run_id: &str) -> String {
    Topic::Merged.service_name(run_id)
}

/// `qfleet/<run-id>/coord/ack` ([`DiscoveryAck`], latest-wins, cumulative).
pub fn coord_ack(run_id: &str) -> String {
    Topic::Ack.service_name(run_id)
}

/// `qfleet/<run-id>/coord/discovery` ([`DiscoveryRelay`], lossless, broadcast).
pub fn coord_discovery(run_id: &str) -> String {
    Topic::Relay.service_name(run_id)
}

/// `qfleet/<run-id>/robot/intent` ([`Intent`], latest-wins).
pub fn robot_intent(run_id: &str) -> String {
    Topic::Intent.service_name(run_id)
}

/// `qfleet/<run-id>/robot/horizon` ([`IntentHorizon`], latest-wins).
pub fn robot_horizon(run_id: &str) -> String {
    Topic::Horizon.service_name(run_id)
}

/// `qfleet/<run-id>/coord/grant` ([`Grant`], latest-wins, broadcast).
pub fn coord_grant(run_id: &str) -> String {
    Topic::Grant.service_name(run_id)
}

/// The iceoryx2 node name of a run's coordinator (one per run).
pub const COORDINATOR_NODE_NAME: &str = "qfleet-coordinator";

/// Start of every robot's iceoryx2 node name: `qfleet-robot-<id>`.
pub const ROBOT_NODE_PREFIX: &str = "qfleet-robot-";

/// The iceoryx2 node name of robot `robot_id`: `qfleet-robot-<id>` (what liveness checks and
/// `qfleet clean` look for).
pub fn robot_node_name(robot_id: u32) -> String {
    format!("{ROBOT_NODE_PREFIX}{robot_id}")
}

/// The robot id in a node name built by [`robot_node_name`]; `None` for any other name
/// (the coordinator, an outside node, `qfleet-robot-x`, `qfleet-robot-01`).
pub fn parse_robot_node_name(name: &str) -> Option<u32> {
    let digits = name.strip_prefix(ROBOT_NODE_PREFIX)?;
    let canonical = !digits.is_empty()
        && digits.bytes().all(|b| b.is_ascii_digit())
        && (digits == "0" || !digits.starts_with('0'));
    if canonical { digits.parse().ok() } else { None }
}

/// 64-bit FNV-1a fingerprint of a grid's size and walls (`free`, row by row: true = free cell),
/// sent in `Register` so that a robot started on another map is refused.
///
/// Takes the grid's parts rather than a planner type: the wire contract does not depend on the
/// planner. Every process computes it the same way from `Grid::width/height/free_flags`.
pub fn map_fingerprint(width: usize, height: usize, free: &[bool]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |b: u8| {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    };
    for b in (width as u64)
        .to_le_bytes()
        .into_iter()
        .chain((height as u64).to_le_bytes())
    {
        eat(b);
    }
    for &cell in free {
        eat(u8::from(cell));
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robot_node_names_round_trip_and_nothing_else_parses() {
        for id in [0, 1, 42, 255, u32::MAX] {
            assert_eq!(parse_robot_node_name(&robot_node_name(id)), Some(id));
        }
        for name in [
            COORDINATOR_NODE_NAME,
            "qfleet-robot-",
            "qfleet-robot-x",
            "qfleet-robot-01",
            "qfleet-robot--1",
            "qfleet-robot-1 ",
            "qfleet-robot-99999999999",
            "robot-1",
        ] {
            assert_eq!(parse_robot_node_name(name), None, "{name:?}");
        }
    }

    #[test]
    fn fingerprint_tells_maps_apart() {
        let open = [true; 8];
        let mut walled = open;
        walled[3] = false;
        assert_ne!(map_fingerprint(4, 2, &open), map_fingerprint(4, 2, &walled));
        assert_ne!(map_fingerprint(4, 2, &open), map_fingerprint(2, 4, &open));
        assert_eq!(
            map_fingerprint(4, 2, &open),
            map_fingerprint(4, 2, &[true; 8])
        );
    }
}
