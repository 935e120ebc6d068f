//! Messages the coordinator publishes and every robot-agent subscribes to.
//!
//! All five topics are broadcast: each robot receives every message and keeps those whose
//! `robot_id` is its own (or [`ROBOT_ID_ALL`]). Layout rules as in
//! [`robot_to_coordinator`](crate::robot_to_coordinator).

use iceoryx2::prelude::ZeroCopySend;

use crate::robot_to_coordinator::{HINT_BATCH_CAP, QHint};

/// `robot_id` value addressing every robot of the run.
pub const ROBOT_ID_ALL: u32 = u32::MAX;

/// Capacity in bytes of [`Control::reason`].
pub const REASON_LEN: usize = 64;

/// What a [`Control`] message asks for, carried as a `u8` in [`Control::command`].
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// Begin learning: publish learning traffic from now on (the end of the start handshake).
    Start = 1,
    /// Stop learning, send the `FinalReport` and exit.
    Stop = 2,
    /// Learn towards goal `goal_id` at (`goal_x`, `goal_y`).
    AssignGoal = 3,
    /// Switch to experiment phase `phase` (with `episodes` episodes, 0 = unchanged).
    Phase = 4,
    /// The registration of `robot_id` was accepted.
    Ack = 5,
    /// The registration of `robot_id` was refused; `reason` says why; the robot must exit.
    Refuse = 6,
    /// Move on the shared grid: answer every `Grant` with an `Intent` until a `Grant` whose
    /// state is not `Moving` (learning is over; a `Stop` follows).
    Execute = 7,
}

impl Command {
    /// The byte written on the wire for this command.
    pub const fn as_u8(self) -> u8 {
        self as u8
    }
}

impl TryFrom<u8> for Command {
    type Error = u8;

    /// Decodes a wire byte; an unknown value is returned as the error so it can be reported.
    fn try_from(value: u8) -> Result<Self, u8> {
        match value {
            1 => Ok(Self::Start),
            2 => Ok(Self::Stop),
            3 => Ok(Self::AssignGoal),
            4 => Ok(Self::Phase),
            5 => Ok(Self::Ack),
            6 => Ok(Self::Refuse),
            7 => Ok(Self::Execute),
            other => Err(other),
        }
    }
}

/// A command from the coordinator to one robot or all of them (lossless).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::Control")]
pub struct Control {
    /// A [`Command`] as `u8`.
    pub command: u8,
    /// Explicit padding, always zero.
    pub _pad0: [u8; 3],
    /// Addressed robot, or [`ROBOT_ID_ALL`].
    pub robot_id: u32,
    /// Goal for `AssignGoal` (and the goal in effect for the other commands).
    pub goal_id: u32,
    /// Goal cell column.
    pub goal_x: u16,
    /// Goal cell row.
    pub goal_y: u16,
    /// Experiment phase number.
    pub phase: u32,
    /// Episodes to run (for `Start`/`Phase`; 0 = keep the robot's own setting).
    pub episodes: u32,
    /// The coordinator's `SCHEMA_VERSION`.
    pub schema_version: u32,
    /// Number of valid bytes in `reason`.
    pub reason_len: u32,
    /// Coordinator-wide control sequence number: 0, 1, 2, … (lets a robot spot duplicates).
    pub seq: u64,
    /// Monotonic time the message was written.
    pub time_ns: u64,
    /// UTF-8 text for `Refuse` (and optionally others): `reason[..reason_len]`, rest zero.
    pub reason: [u8; REASON_LEN],
}

/// Q-values merged from the whole fleet, broadcast to every robot (latest-wins).
///
/// Provenance is kept **per entry**: `origin_ns[i]` is the monotonic time of the oldest robot
/// update merged into `entries[i]` and `origin_robot[i]` the robot it came from, so a robot can
/// record the true end-to-end latency of every hint it applies (not just one per batch) and skip
/// its own hints. `oldest_origin_ns` is the minimum over the batch, for quick checks.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::MergedHintBatch")]
pub struct MergedHintBatch {
    /// Coordinator-wide merged batch sequence number; gaps show overwritten batches.
    pub coordinator_seq: u64,
    /// Goal the Q-values refer to.
    pub goal_id: u32,
    /// Number of valid entries at the start of each array (≤ `HINT_BATCH_CAP`).
    pub count: u32,
    /// Minimum of `origin_ns[..count]`.
    pub oldest_origin_ns: u64,
    /// Monotonic time the message was written.
    pub send_time_ns: u64,
    /// Merged entries; only `entries[..count]` are meaningful.
    pub entries: [QHint; HINT_BATCH_CAP],
    /// Per entry: monotonic time of the oldest robot update merged into it.
    pub origin_ns: [u64; HINT_BATCH_CAP],
    /// Per entry: robot that produced that oldest update.
    pub origin_robot: [u32; HINT_BATCH_CAP],
}

/// Cumulative acknowledgement of one robot's discoveries (latest-wins).
///
/// "Every discovery of `robot_id` with `seq ≤ up_to_seq` was received." A newer ack
/// supersedes an older one, so losing one in the buffer loses no information.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::DiscoveryAck")]
pub struct DiscoveryAck {
    /// Robot whose discoveries are acknowledged.
    pub robot_id: u32,
    /// Explicit padding, always zero.
    pub _pad0: [u8; 4],
    /// Highest discovery `seq` received without gaps.
    pub up_to_seq: u64,
    /// Monotonic time the message was written.
    pub time_ns: u64,
}

/// A discovery relayed by the coordinator to every robot (lossless, broadcast).
///
/// The coordinator relays each distinct (goal, cell) once, the first time any robot reports it;
/// a robot learning goal `goal_id` that is not `origin_robot` uses it as its learner does (the
/// planner's `Learner::add_discovery`): the improved learner makes the cell a pseudo target of
/// its own, the planning learner keeps the value as a known return of the cell and ends an
/// episode there once its own value shows it exact. `relay_seq` numbers relays 0, 1, … over
/// the run, so a gap is a bug.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::DiscoveryRelay")]
pub struct DiscoveryRelay {
    /// Coordinator-wide relay sequence number: 0, 1, 2, … without gaps.
    pub relay_seq: u64,
    /// Robot that discovered the cell.
    pub origin_robot: u32,
    /// Goal the value refers to.
    pub goal_id: u32,
    /// Cell column.
    pub cell_x: u16,
    /// Cell row.
    pub cell_y: u16,
    /// The discovery's value, as the discovering robot sent it (`PseudoTargetDiscovery.value`).
    pub value: f32,
    /// The discovering robot's `seq` of this discovery.
    pub origin_seq: u64,
    /// Monotonic time of the discovery in the discovering robot's learner.
    pub origin_ns: u64,
    /// Monotonic time the relay was written.
    pub send_time_ns: u64,
}

const _: () = assert!(size_of::<Control>() == 112 && align_of::<Control>() == 8);
const _: () = assert!(size_of::<MergedHintBatch>() == 6176 && align_of::<MergedHintBatch>() == 8);
const _: () = assert!(size_of::<DiscoveryAck>() == 24 && align_of::<DiscoveryAck>() == 8);
const _: () = assert!(size_of::<DiscoveryRelay>() == 48 && align_of::<DiscoveryRelay>() == 8);

/// Robots a [`Grant`] has room for (the fleet limit, [`crate::MAX_ROBOTS`]).
pub const GRANT_CAP: usize = crate::MAX_ROBOTS as usize;

/// How a shared-grid execution stands after a [`Grant`], carried as a `u8` in [`Grant::state`].
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum GridState {
    /// Going on: every robot on the grid answers with an `Intent` for the next tick.
    Moving = 0,
    /// Every robot on the grid stands on its goal: the execution is over.
    Arrived = 1,
    /// The coordinator ended the execution before every robot arrived (tick limit, no
    /// solution, a stop request); the positions are final.
    Ended = 2,
}

impl GridState {
    /// The byte written on the wire for this state.
    pub const fn as_u8(self) -> u8 {
        self as u8
    }
}

impl TryFrom<u8> for GridState {
    type Error = u8;

    /// Decodes a wire byte; an unknown value is returned as the error so it can be reported.
    fn try_from(value: u8) -> Result<Self, u8> {
        match value {
            0 => Ok(Self::Moving),
            1 => Ok(Self::Arrived),
            2 => Ok(Self::Ended),
            other => Err(other),
        }
    }
}

/// Where every robot of a shared grid stands after tick `tick` (latest-wins, broadcast).
///
/// The coordinator is the authority of the grid: it publishes the configuration of tick 0 (the
/// starts) when the execution begins, then, once every robot on the grid sent its `Intent` for
/// the tick (or was waited for long enough), the configuration of the next tick. A robot moves
/// only to the cell granted here. Entry `i` of each array is robot `i`'s; `present[i]` is 0 for a
/// robot that left the grid (declared lost) or has no entry (`i ≥ robots`), and such an entry's
/// cell is (0, 0), not a position. `seq` equals `tick` (one grant per tick; both restart at 0 in
/// each execution: an experiment's next phase, a restarted coordinator).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::Grant")]
pub struct Grant {
    /// Tick of this configuration: 0 is the starts.
    pub tick: u32,
    /// Number of robot entries (the fleet size, ≤ [`GRANT_CAP`]).
    pub robots: u32,
    /// A [`GridState`] as `u8`.
    pub state: u8,
    /// Explicit padding, always zero.
    pub _pad0: [u8; 7],
    /// Coordinator-wide grant sequence number (one per tick, so equal to `tick` in one run).
    pub seq: u64,
    /// Monotonic time the message was written.
    pub send_time_ns: u64,
    /// Per robot: cell column.
    pub cell_x: [u16; GRANT_CAP],
    /// Per robot: cell row.
    pub cell_y: [u16; GRANT_CAP],
    /// Per robot: 1 on the grid, 0 gone (or no such robot).
    pub present: [u8; GRANT_CAP],
}

const _: () = assert!(size_of::<Grant>() == 1312 && align_of::<Grant>() == 8);
