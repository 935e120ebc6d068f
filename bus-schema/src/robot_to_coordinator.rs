//! Messages a robot-agent publishes and the coordinator subscribes to.
//!
//! Every type is `#[repr(C)]`, fixed size, without pointers or implicit padding (padding is
//! spelled out as `_pad*` fields that are always zero), and carries a versioned iceoryx2 type
//! name. Times are `CLOCK_MONOTONIC` nanoseconds taken on the sending machine.

use iceoryx2::prelude::ZeroCopySend;

/// Number of [`QHint`] entries a [`QHintBatch`] (and a merged batch) can carry.
///
/// 256 entries × 12 bytes keep a batch at about 3 KiB: large enough that a robot can ship all
/// Q-values it changed during one episode on the paper's maps in one or two batches, small enough
/// that the per-subscriber buffers for a full fleet of `MAX_ROBOTS` stay in the low megabytes of
/// shared memory. Only the first `count` entries of a batch are meaningful.
pub const HINT_BATCH_CAP: usize = 256;

/// Lifecycle state of a robot, carried as a `u8` in [`RobotState::status`] and
/// [`FinalReport::status`].
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RobotStatus {
    /// Registered and waiting for a `Start` control (no learning traffic yet).
    Waiting = 0,
    /// Learning: inside an episode.
    Running = 1,
    /// The episode in `episode` just ended; the next one starts soon.
    EpisodeDone = 2,
    /// All episodes done; a [`FinalReport`] follows.
    Finished = 3,
    /// The robot gave up (error, refused, or stopped early); see its log.
    Failed = 4,
}

impl RobotStatus {
    /// The byte written on the wire for this status.
    pub const fn as_u8(self) -> u8 {
        self as u8
    }
}

impl TryFrom<u8> for RobotStatus {
    type Error = u8;

    /// Decodes a wire byte; an unknown value is returned as the error so it can be reported.
    fn try_from(value: u8) -> Result<Self, u8> {
        match value {
            0 => Ok(Self::Waiting),
            1 => Ok(Self::Running),
            2 => Ok(Self::EpisodeDone),
            3 => Ok(Self::Finished),
            4 => Ok(Self::Failed),
            other => Err(other),
        }
    }
}

/// First message of a robot: who it is and which map it learns on (lossless).
///
/// The coordinator answers with a `Control` of command `Ack` or `Refuse` addressed to
/// `robot_id`; a robot whose `schema_version` or `map_hash` differs from the coordinator's is
/// refused with a readable reason.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::Register")]
pub struct Register {
    /// The robot's `SCHEMA_VERSION`; the coordinator refuses a different one.
    pub schema_version: u32,
    /// Fleet-unique robot id, `0..robots`.
    pub robot_id: u32,
    /// Operating-system process id of the robot (for logs and liveness checks).
    pub pid: u32,
    /// Number of episodes the robot intends to learn.
    pub episodes: u32,
    /// Grid width in cells.
    pub width: u16,
    /// Grid height in cells.
    pub height: u16,
    /// Start cell column.
    pub start_x: u16,
    /// Start cell row.
    pub start_y: u16,
    /// 64-bit fingerprint of the grid (size and walls) so a robot on another map is refused.
    pub map_hash: u64,
    /// Seed of the robot's random number generator (for reproducing a run).
    pub seed: u64,
    /// Monotonic time the message was written.
    pub send_time_ns: u64,
}

/// Latest progress of a robot (latest-wins: the coordinator only needs the newest one).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::RobotState")]
pub struct RobotState {
    /// Sending robot.
    pub robot_id: u32,
    /// Goal the robot is currently learning towards.
    pub goal_id: u32,
    /// Current episode, counted from 0.
    pub episode: u32,
    /// Step within the current episode.
    pub step: u32,
    /// Number of steps the last finished episode took (0 before the first one ends).
    pub last_episode_steps: u32,
    /// Current cell column.
    pub cell_x: u16,
    /// Current cell row.
    pub cell_y: u16,
    /// A [`RobotStatus`] as `u8`.
    pub status: u8,
    /// Explicit padding, always zero.
    pub _pad0: [u8; 7],
    /// Per-robot sequence number of state messages, starting at 0; gaps show overwritten states.
    pub seq: u64,
    /// Monotonic time the message was written.
    pub send_time_ns: u64,
}

/// A robot found a cell whose value is worth sharing (lossless): a pseudo target near the goal
/// (the paper's improved learner), or a cell of a path to the goal it found, with that path's
/// return from the cell (the planning learner: a lower bound of the cell's value for every robot
/// on the map, see the planner's `known` module).
///
/// Discoveries are sent with a per-robot `seq` starting at 0 and increasing by one; the
/// coordinator acknowledges them cumulatively with `DiscoveryAck`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::PseudoTargetDiscovery")]
pub struct PseudoTargetDiscovery {
    /// Discovering robot.
    pub robot_id: u32,
    /// Goal the value refers to.
    pub goal_id: u32,
    /// Cell column.
    pub cell_x: u16,
    /// Cell row.
    pub cell_y: u16,
    /// Value of the cell: a pseudo target's value (improved learner), or the discounted return
    /// of the found goal path from the cell (planning learner).
    pub value: f32,
    /// Per-robot discovery sequence number: 0, 1, 2, … without gaps.
    pub seq: u64,
    /// Monotonic time of the discovery in the learner.
    pub time_ns: u64,
    /// Episode in which it was discovered.
    pub episode: u32,
    /// Explicit padding, always zero.
    pub _pad0: [u8; 4],
    /// Monotonic time the message was written (≥ `time_ns`).
    pub send_time_ns: u64,
}

/// One Q-table entry shared between robots, 12 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::QHint")]
pub struct QHint {
    /// Row-major cell index: `y * width + x`.
    pub cell: u32,
    /// Action index (the planner's action order).
    pub action: u8,
    /// Explicit padding, always zero.
    pub _pad0: u8,
    /// How many updates this value is based on (saturating), a confidence weight for merging.
    pub visits: u16,
    /// The Q-value.
    pub q: f32,
}

/// A batch of Q-values a robot changed (latest-wins: a newer batch supersedes older ones).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::QHintBatch")]
pub struct QHintBatch {
    /// Sending robot.
    pub robot_id: u32,
    /// Goal the Q-values refer to.
    pub goal_id: u32,
    /// Number of valid entries at the start of `entries` (≤ [`HINT_BATCH_CAP`]).
    pub count: u32,
    /// Explicit padding, always zero.
    pub _pad0: [u8; 4],
    /// Per-robot batch sequence number; gaps show batches overwritten in the buffer.
    pub seq: u64,
    /// Monotonic time of the oldest Q-update contained in this batch (origin of its latency).
    pub oldest_update_ns: u64,
    /// Monotonic time the message was written.
    pub send_time_ns: u64,
    /// The entries; only `entries[..count]` are meaningful, the rest are zero.
    pub entries: [QHint; HINT_BATCH_CAP],
}

/// Fixed-size summary of a latency histogram, in nanoseconds (count 0 = no samples).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::LatencySummary")]
pub struct LatencySummary {
    /// Number of samples.
    pub count: u64,
    /// Smallest sample.
    pub min_ns: u64,
    /// Arithmetic mean, rounded down.
    pub mean_ns: u64,
    /// Median.
    pub p50_ns: u64,
    /// 90th percentile.
    pub p90_ns: u64,
    /// 99th percentile.
    pub p99_ns: u64,
    /// 99.9th percentile.
    pub p999_ns: u64,
    /// Largest sample.
    pub max_ns: u64,
}

/// Last message of a robot: what it learned and how the bus behaved for it (lossless).
///
/// The full latency histogram does not fit a fixed-size message; the robot writes it to a file
/// next to its log and only the summary travels here.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::FinalReport")]
pub struct FinalReport {
    /// Reporting robot.
    pub robot_id: u32,
    /// The robot's `SCHEMA_VERSION`.
    pub schema_version: u32,
    /// Goal the report is about.
    pub goal_id: u32,
    /// Episodes actually run.
    pub episodes: u32,
    /// Length of the greedy path after learning; -1 = the greedy policy loops or finds no path.
    pub final_path_len: i32,
    /// Length of the shortest path on the map; -1 = unknown / unreachable.
    pub optimal_path_len: i32,
    /// First episode whose greedy path was optimal; -1 = never.
    pub first_optimal_episode: i32,
    /// Most steps any episode took.
    pub max_steps: u32,
    /// A [`RobotStatus`] as `u8`: normally `Finished`, `Failed` if it gave up.
    pub status: u8,
    /// Explicit padding, always zero.
    pub _pad0: [u8; 7],
    /// Mean steps per episode.
    pub avg_steps: f64,
    /// Environment steps taken in total.
    pub env_steps: u64,
    /// Wall time from `Start` to the report.
    pub elapsed_ns: u64,
    /// Discoveries published.
    pub discoveries_sent: u64,
    /// Discoveries the coordinator acknowledged.
    pub discoveries_acked: u64,
    /// Hint batches published.
    pub hints_sent: u64,
    /// Merged hint batches received.
    pub hints_received: u64,
    /// Merged hint entries applied to the robot's Q-table.
    pub hints_applied: u64,
    /// Latency from a hint's origin (`origin_ns`) to its arrival at this robot.
    pub merged_latency: LatencySummary,
    /// Monotonic time the message was written.
    pub send_time_ns: u64,
}

const _: () = assert!(size_of::<Register>() == 48 && align_of::<Register>() == 8);
const _: () = assert!(size_of::<RobotState>() == 48 && align_of::<RobotState>() == 8);
const _: () =
    assert!(size_of::<PseudoTargetDiscovery>() == 48 && align_of::<PseudoTargetDiscovery>() == 8);
const _: () = assert!(size_of::<QHint>() == 12 && align_of::<QHint>() == 4);
const _: () = assert!(size_of::<QHintBatch>() == 3112 && align_of::<QHintBatch>() == 8);
const _: () = assert!(size_of::<LatencySummary>() == 64 && align_of::<LatencySummary>() == 8);
const _: () = assert!(size_of::<FinalReport>() == 176 && align_of::<FinalReport>() == 8);

/// A robot's ranked wish for its next move in a shared grid (latest-wins).
///
/// Sent once per [`Grant`](crate::Grant) while the robot executes: the answer to the grant of
/// tick `tick`, asking for the move from that tick to the next. `ranked[..count]` are move codes,
/// best first — 0 wait, 1 up (y − 1), 2 right (x + 1), 3 down (y + 1), 4 left (x − 1) —
/// ordered by the robot's own learned values; the coordinator grants one of them (or a wait)
/// so that no two robots ever hold one cell or swap cells. `cell_x`/`cell_y` is where the robot
/// stands (it must equal the coordinator's record). Robots send `count` 1 to 5 distinct codes;
/// the coordinator reads at most 5, takes `count` 0 as "no preference" and drops an intent
/// with a repeated or unknown code; `ranked[count..]` is zero.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::Intent")]
pub struct Intent {
    /// Sending robot.
    pub robot_id: u32,
    /// The grant's tick this intent answers.
    pub tick: u32,
    /// The robot's cell column at `tick`.
    pub cell_x: u16,
    /// The robot's cell row at `tick`.
    pub cell_y: u16,
    /// Number of valid move codes in `ranked` (1 to 5).
    pub count: u8,
    /// Move codes, best first (0 wait, 1 up, 2 right, 3 down, 4 left), each at most once.
    pub ranked: [u8; 5],
    /// Explicit padding, always zero.
    pub _pad0: [u8; 6],
    /// Monotonic time the message was written.
    pub send_time_ns: u64,
}

const _: () = assert!(size_of::<Intent>() == 32 && align_of::<Intent>() == 8);

/// Largest radius an [`IntentHorizon`] carries (cells within 8 moves of the robot).
pub const HORIZON_RADIUS_CAP: u8 = 8;

/// Cells of the largest horizon: the diamond of radius [`HORIZON_RADIUS_CAP`], `2r² + 2r + 1`.
pub const HORIZON_CELLS: usize = 145;

/// Radius of the early [`IntentHorizon`] for tick 0 that a robot sends at its start while it
/// waits for `Execute`: the widest, so it answers tick 0 whatever horizon the fleet is asked
/// for (the aligned-radius rule does not apply to it).
pub const EARLY_HORIZON_RADIUS: u8 = HORIZON_RADIUS_CAP;

/// Names of the move codes of [`Intent::ranked`] and [`IntentHorizon::ranked`], the code being
/// the index: what a decoder prints, and what the README's code table is made from.
pub const MOVE_NAMES: [&str; 5] = [
    "wait",
    "up (y − 1)",
    "right (x + 1)",
    "down (y + 1)",
    "left (x − 1)",
];

/// The packed ranking "wait only" (move code 0 + 1 in the first group), which a horizon carries
/// at a diamond cell that is a wall or off the map: a robot is never there, and the entry must
/// still be a valid ranking.
pub const HORIZON_WAIT_ONLY: u16 = 1;

/// A robot's rankings for every cell it may stand on within the next `radius` ticks, so the
/// coordinator can resolve `radius + 1` ticks before it needs this robot again (latest-wins).
///
/// The answer to the grant of tick `tick`, sent instead of an [`Intent`] when the coordinator's
/// `Execute` asked for a horizon. `ranked[i]` is the robot's ranking (the same as an
/// [`Intent`]'s, from its own learned values) at the `i`-th cell of the diamond of radius
/// `radius` around (`cell_x`, `cell_y`): rows from `dy = −radius` to `radius`, each from
/// `dx = −(radius − |dy|)` to `radius − |dy|`. A ranking is packed into 16 bits: per rank, best
/// first from the low bits, the move code + 1 in three bits; a zero group ends it (0: no
/// preference). Only the first `2·radius² + 2·radius + 1` entries are meaningful, the rest are
/// zero (the coordinator drops a horizon with anything else there). A diamond cell that is a
/// wall or off the map carries [`HORIZON_WAIT_ONLY`]. It answers ticks `tick ..= tick + radius`
/// while the robot stands inside the diamond. The early horizon for tick 0 (radius
/// [`EARLY_HORIZON_RADIUS`] at the robot's start, sent while it waits for `Execute`) is the one
/// exception to the aligned-radius rule of the README.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("qfleet::v1::IntentHorizon")]
pub struct IntentHorizon {
    /// Sending robot.
    pub robot_id: u32,
    /// The grant's tick this horizon answers first.
    pub tick: u32,
    /// The robot's cell column at `tick` (the diamond's center).
    pub cell_x: u16,
    /// The robot's cell row at `tick`.
    pub cell_y: u16,
    /// The diamond's radius, 0 to [`HORIZON_RADIUS_CAP`].
    pub radius: u8,
    /// Explicit padding, always zero.
    pub _pad0: [u8; 3],
    /// Monotonic time the message was written.
    pub send_time_ns: u64,
    /// Packed rankings, one per diamond cell (the type's docs; the README's "The shared grid, field
    /// by field").
    pub ranked: [u16; HORIZON_CELLS],
    /// Explicit padding, always zero.
    pub _pad1: [u8; 6],
}

const _: () = assert!(size_of::<IntentHorizon>() == 320 && align_of::<IntentHorizon>() == 8);
const _: () = assert!(
    HORIZON_CELLS
        == 2 * (HORIZON_RADIUS_CAP as usize) * (HORIZON_RADIUS_CAP as usize)
            + 2 * (HORIZON_RADIUS_CAP as usize)
            + 1
);
