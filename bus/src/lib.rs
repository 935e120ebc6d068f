//! bus (draft docs)
#![deny(missing_docs)]

mod clock;
mod config;
mod endpoints;
mod error;
mod handshake;
mod liveness;
mod topic;

pub use bus_schema;
pub use clock::monotonic_ns;
pub use config::{
    BusConfig, MAX_BUFFER, MAX_ROBOTS, iceoryx_config_for_prefix, unique_run_id, validate_run_id,
};
pub use endpoints::{CoordinatorBus, RobotBus};
pub use error::BusError;
pub use handshake::{Admission, Expected, check_register, control, reason, set_reason};
pub use liveness::{
    CleanReport, Liveness, NodeInfo, NodeReport, check_nodes, clean_run, clean_stale,
    find_run_prefixes, iceoryx_root, leftover_files,
};
pub use topic::{
    EVENT_DATA, EVENT_PEER_DEAD, Inbox, Message, Outbox, TopicLimits, Wakeups, limits,
};
