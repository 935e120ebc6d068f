#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod coordinator_to_robot;
pub mod names;
pub mod robot_to_coordinator;

#[cfg(test)]
mod layout;

pub use coordinator_to_robot::{
    Command, Control, DiscoveryAck, DiscoveryRelay, GRANT_CAP, Grant, GridState, MergedHintBatch,
    REASON_LEN, ROBOT_ID_ALL,
};
pub use names::{
    COORDINATOR_NODE_NAME, Delivery, Direction, RUN_ID_MAX_LEN, Topic, map_fingerprint,
    parse_robot_node_name, robot_node_name,
};
pub use robot_to_coordinator::{
    EARLY_HORIZON_RADIUS, FinalReport, HINT_BATCH_CAP, HORIZON_CELLS, HORIZON_RADIUS_CAP,
    HORIZON_WAIT_ONLY, Intent, IntentHorizon, LatencySummary, MOVE_NAMES, PseudoTargetDiscovery,
    QHint, QHintBatch, Register, RobotState, RobotStatus,
};

/// Version of this wire contract; sent in `Register`, `Control` and `FinalReport` and checked at
/// registration, because iceoryx2 itself only compares type name, size and alignment.
///
/// Bump it together with the `v1` in every `#[type_name]` whenever any field changes meaning,
/// order or size.
pub const SCHEMA_VERSION: u32 = 1;

/// Largest fleet the bus supports: robot ids are `0..robots` with `robots ≤ 256`.
///
/// Bounded so every service can be sized in advance (iceoryx2 allocates all buffers when a
/// service or port is created): at 256 robots the largest segments, the merged-hints and ack
/// broadcasts, stay around 10 to 32 MB of shared memory each (`bus::MERGED_SEGMENT_BUDGET`).
pub const MAX_ROBOTS: u32 = 256;

/// Gives every message an all-zero constant, the natural "empty" value to start from.
macro_rules! zeroed {
    ($($ty:ty),* $(,)?) => {$(
        impl $ty {
            /// The all-zero value (every count, id, time and padding byte zero), to build
            /// messages with struct update syntax: `T { field: x, ..T::ZEROED }`.
            // SAFETY: every field of this `#[repr(C)]` type is an integer, a float, or an array
            // or struct of those (checked by the layout test), so all-zero bytes are a valid value.
            pub const ZEROED: Self = unsafe { core::mem::zeroed() };
        }

        impl Default for $ty {
            fn default() -> Self {
                Self::ZEROED
            }
        }
    )*};
}

zeroed!(
    Register,
    RobotState,
    PseudoTargetDiscovery,
    QHint,
    QHintBatch,
    LatencySummary,
    FinalReport,
    Control,
    MergedHintBatch,
    DiscoveryAck,
    DiscoveryRelay,
    Intent,
    IntentHorizon,
    Grant,
);
