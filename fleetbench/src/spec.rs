//! What a child process of the harness is asked to do ([`RoleSpec`], passed as one JSON
//! argument) and what it answers ([`ChildReport`], one JSON line on stdout).

use std::path::PathBuf;

use contract::coordinator::WaitStrategy;
use serde::{Deserialize, Serialize};

/// Prefix of the one stdout line a child writes its [`ChildReport`] on.
pub const REPORT_PREFIX: &str = "FLEETBENCH-REPORT ";

/// Sample counts and timing of one measuring side.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
pub struct Plan {
    /// Round trips before measuring (not recorded).
    pub warmup: u64,
    /// Round trips recorded.
    pub samples: u64,
    /// Milliseconds to stay idle after measuring while the peer's CPU is sampled.
    pub idle_ms: u64,
    /// Milliseconds any single wait may take before the peer counts as dead.
    pub timeout_ms: u64,
    /// Keep measuring past `samples` until the window is at least this long, ms (CPU times
    /// of other processes have 10 ms resolution, so short windows would misstate them).
    pub min_window_ms: u64,
}

impl Plan {
    /// Whether round trip number `i` (0-based, warm-up included) should run, given the time
    /// the measurement window has lasted so far (checked every 256 round trips).
    #[inline]
    pub fn more(&self, i: u64, window_ns: impl FnOnce() -> u64) -> bool {
        let total = self.warmup + self.samples;
        if i < total || !(i - total).is_multiple_of(256) {
            return true;
        }
        window_ns() < self.min_window_ms.saturating_mul(1_000_000)
    }
}

/// One process role of the harness.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(tag = "role", rename_all = "kebab-case")]
pub enum RoleSpec {
    /// Raw iceoryx2 echo: answers every `QHintBatch` ping with a `MergedHintBatch`.
    RawPong {
        /// Run id (services and iceoryx2 prefix).
        run_id: String,
        /// Block in a WaitSet (true) or busy-poll (false).
        event: bool,
        /// Exit with an error after this long without a message.
        timeout_ms: u64,
    },
    /// Raw iceoryx2 pinger: measures the round trip.
    RawPing {
        /// Run id.
        run_id: String,
        /// Block in a WaitSet (true) or busy-poll (false).
        event: bool,
        /// Counts and timing.
        plan: Plan,
        /// Process id of the pong (for its CPU time and liveness).
        peer_pid: u32,
        /// Where to write the latency histogram (hdrhistogram V2).
        hist_path: PathBuf,
    },
    /// The real coordinator (`coordinator::run`) with the given wait strategy.
    Coordinator {
        /// Run id.
        run_id: String,
        /// Fleet size.
        robots: u32,
        /// Wait strategy.
        wait: WaitStrategy,
        /// Hybrid: µs to spin after the last message.
        spin_us: u64,
        /// Map (e.g. `builtin:paper-20`).
        map: String,
        /// Directory for the coordinator's result.json and .hgrm files.
        out: PathBuf,
        /// Registration/report timeout, s.
        timeout_s: f64,
    },
    /// Two robots in one process against the coordinator: robot 0 makes Q updates and sends
    /// them as hint batches, robot 1 applies the merged hints; latency = update → applied.
    LoopRobots {
        /// Run id.
        run_id: String,
        /// Map (must be the coordinator's).
        map: String,
        /// Wake the coordinator after each hint batch (needed by `event` and `hybrid`).
        notify: bool,
        /// Counts and timing.
        plan: Plan,
        /// Process id of the coordinator.
        peer_pid: u32,
        /// Where to write the latency histogram.
        hist_path: PathBuf,
    },
    /// Unix-socket coordinator: reads `QHintBatch` bytes, merges with the real fleet table,
    /// writes `MergedHintBatch` bytes.
    UdsServer {
        /// Socket path.
        path: PathBuf,
        /// Busy-poll (nonblocking + spin) instead of blocking reads.
        spin: bool,
        /// Cells of the fleet table.
        cells: u32,
        /// Exit with an error after this long without a message.
        timeout_ms: u64,
    },
    /// Unix-socket robot: the same loop as `LoopRobots`, over the socket.
    UdsClient {
        /// Socket path.
        path: PathBuf,
        /// Busy-poll instead of blocking reads.
        spin: bool,
        /// Cells of the Q-tables.
        cells: u32,
        /// Counts and timing.
        plan: Plan,
        /// Process id of the server.
        peer_pid: u32,
        /// Where to write the latency histogram.
        hist_path: PathBuf,
    },
    /// Two threads ping-ponging the real message types (boxed) over crossbeam channels.
    Crossbeam {
        /// Counts and timing.
        plan: Plan,
        /// Where to write the latency histogram.
        hist_path: PathBuf,
    },
    /// Cross-host floor: TCP echo on the coordinator's host.
    TcpEcho {
        /// `ADDR:PORT` to listen on.
        addr: String,
        /// Give up after this long without a peer, ms.
        timeout_ms: u64,
    },
    /// Cross-host floor: TCP ping (measures) on the robots' host.
    TcpPing {
        /// The echo's `ADDR:PORT`.
        addr: String,
        /// Samples and limits.
        plan: Plan,
        /// The echo's pid.
        peer_pid: u32,
        /// Where to write the latency histogram.
        hist_path: PathBuf,
    },
    /// Cross-host floor: Zenoh pong on the coordinator's host.
    ZenohPong {
        /// Zenoh endpoint to listen on.
        listen: String,
        /// Publish express.
        express: bool,
        /// Zenoh's low-latency transport.
        lowlatency: bool,
        /// Give up after this long without a ping, ms.
        timeout_ms: u64,
    },
    /// Cross-host floor: Zenoh ping (measures) on the robots' host.
    ZenohPing {
        /// The pong's endpoint.
        endpoint: String,
        /// Publish express.
        express: bool,
        /// Zenoh's low-latency transport.
        lowlatency: bool,
        /// Samples and limits.
        plan: Plan,
        /// The pong's pid.
        peer_pid: u32,
        /// Where to write the latency histogram.
        hist_path: PathBuf,
    },
    /// Cross-host loop: the real coordinator plus a bridge hub listening on `listen`.
    BridgedCoordinator {
        /// The coordinator's own spec ([`RoleSpec::Coordinator`]).
        inner: Box<RoleSpec>,
        /// Zenoh endpoint the hub listens on.
        listen: String,
        /// Publish express.
        express: bool,
        /// Zenoh's low-latency transport.
        lowlatency: bool,
        /// µs the bridge keeps looking after a message moved (`bridge::Tuning::spin`).
        bridge_spin_us: u64,
        /// The run's join secret, in a file (mode 0600) both hosts read.
        secret_file: PathBuf,
        /// Frames unsealed (`--insecure-plain`).
        plain: bool,
        /// How the robots' host reaches the hub's session (the front door, or none).
        door: bridge::DoorMode,
    },
    /// Cross-host loop: the loop robots plus a joining bridge (measures).
    BridgedRobots {
        /// The robots' own spec ([`RoleSpec::LoopRobots`]).
        inner: Box<RoleSpec>,
        /// The hub's endpoint.
        endpoint: String,
        /// Publish express.
        express: bool,
        /// Zenoh's low-latency transport.
        lowlatency: bool,
        /// µs the bridge keeps looking after a message moved (`bridge::Tuning::spin`).
        bridge_spin_us: u64,
        /// The run's join secret, in a file (mode 0600) both hosts read.
        secret_file: PathBuf,
        /// Frames unsealed (`--insecure-plain`).
        plain: bool,
    },
    /// A lightweight robot of the scale benchmark: emits hint batches as fast as the
    /// coordinator's buffer allows and applies the fleet's merged hints.
    ScaleRobot {
        /// Run id.
        run_id: String,
        /// Map (must be the coordinator's).
        map: String,
        /// This robot.
        robot_id: u32,
        /// Fleet size.
        robots: u32,
        /// Entries per hint batch (1..=256).
        batch: u32,
        /// How long to emit, ms (from Start).
        duration_ms: u64,
        /// Hint batches sent but not yet seen merged before the robot waits (yielding its
        /// CPU); keeps the coordinator's latest-wins buffer from overflowing.
        in_flight: u32,
        /// Notify the coordinator after a batch only if the last notify is at least this many
        /// µs old (0 = after every batch, as the robot-agent does).
        notify_gap_us: u64,
        /// Registration and Stop timeout, ms.
        timeout_ms: u64,
        /// Coordinator pid whose CPU time this robot samples over its window (robot 0 only).
        peer_pid: Option<u32>,
        /// Where to write the loop-latency histogram.
        hist_path: PathBuf,
    },
}

impl RoleSpec {
    /// The role's name, as its JSON tag spells it (`raw-pong`, `coordinator`, …): names the
    /// child process in the harness's errors.
    pub fn role(&self) -> &'static str {
        match self {
            RoleSpec::RawPong { .. } => "raw-pong",
            RoleSpec::RawPing { .. } => "raw-ping",
            RoleSpec::Coordinator { .. } => "coordinator",
            RoleSpec::LoopRobots { .. } => "loop-robots",
            RoleSpec::UdsServer { .. } => "uds-server",
            RoleSpec::UdsClient { .. } => "uds-client",
            RoleSpec::Crossbeam { .. } => "crossbeam",
            RoleSpec::TcpEcho { .. } => "tcp-echo",
            RoleSpec::TcpPing { .. } => "tcp-ping",
            RoleSpec::ZenohPong { .. } => "zenoh-pong",
            RoleSpec::ZenohPing { .. } => "zenoh-ping",
            RoleSpec::BridgedCoordinator { .. } => "bridged-coordinator",
            RoleSpec::BridgedRobots { .. } => "bridged-robots",
            RoleSpec::ScaleRobot { .. } => "scale-robot",
        }
    }
}

/// What a child reports on its one `FLEETBENCH-REPORT` stdout line.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct ChildReport {
    /// Round trips (or loop samples) recorded.
    pub samples: u64,
    /// Wall time of the measurement window, ns.
    pub wall_ns: u64,
    /// This process's CPU time during the window, ns.
    pub self_cpu_ns: u64,
    /// The peer process's CPU time during the window, ns (if it has one and it was readable).
    pub peer_cpu_ns: Option<u64>,
    /// The peer's CPU use while this side was idle after measuring, % of a core.
    pub peer_idle_cpu_pct: Option<f64>,
    /// Hint batches sent (scale robots).
    pub batches_sent: u64,
    /// Q-updates sent in those batches (scale robots).
    pub updates_sent: u64,
    /// Batches never seen merged: within 20 ms (scale robots' flow control gave up on them),
    /// or within [`crate::roles::fleet::LOOP_RETRY`] (a loop's round trip, sent again).
    pub batches_lost: u64,
    /// Merged entries applied or looked at (loop samples from foreign robots).
    pub merged_seen: u64,
    /// Coordinator: Q-updates merged per second over its active time (its own figure).
    pub merged_per_s: f64,
    /// Coordinator: robots whose final report arrived and was accepted.
    #[serde(default)]
    pub reports: u64,
    /// Coordinator: of those, robots that stopped without a path (`without_path`).
    #[serde(default)]
    pub without_path: u64,
    /// Coordinator: messages it rejected as invalid (`rejected` of its result).
    #[serde(default)]
    pub rejected: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One spec of every role (the match in [`RoleSpec::role`] makes a new role add a name).
    fn every_role() -> Vec<RoleSpec> {
        let plan = Plan {
            warmup: 1,
            samples: 2,
            idle_ms: 3,
            timeout_ms: 4,
            min_window_ms: 5,
        };
        let (run_id, p) = (String::from("r"), PathBuf::from("h"));
        let coordinator = RoleSpec::Coordinator {
            run_id: run_id.clone(),
            robots: 2,
            wait: WaitStrategy::Spin,
            spin_us: 0,
            map: "m".into(),
            out: p.clone(),
            timeout_s: 1.0,
        };
        let robots = RoleSpec::LoopRobots {
            run_id: run_id.clone(),
            map: "m".into(),
            notify: true,
            plan,
            peer_pid: 1,
            hist_path: p.clone(),
        };
        vec![
            RoleSpec::RawPong {
                run_id: run_id.clone(),
                event: true,
                timeout_ms: 1,
            },
            RoleSpec::RawPing {
                run_id: run_id.clone(),
                event: true,
                plan,
                peer_pid: 1,
                hist_path: p.clone(),
            },
            coordinator.clone(),
            robots.clone(),
            RoleSpec::UdsServer {
                path: p.clone(),
                spin: false,
                cells: 1,
                timeout_ms: 1,
            },
            RoleSpec::UdsClient {
                path: p.clone(),
                spin: false,
                cells: 1,
                plan,
                peer_pid: 1,
                hist_path: p.clone(),
            },
            RoleSpec::Crossbeam {
                plan,
                hist_path: p.clone(),
            },
            RoleSpec::TcpEcho {
                addr: "a".into(),
                timeout_ms: 1,
            },
            RoleSpec::TcpPing {
                addr: "a".into(),
                plan,
                peer_pid: 1,
                hist_path: p.clone(),
            },
            RoleSpec::ZenohPong {
                listen: "l".into(),
                express: true,
                lowlatency: false,
                timeout_ms: 1,
            },
            RoleSpec::ZenohPing {
                endpoint: "e".into(),
                express: true,
                lowlatency: false,
                plan,
                peer_pid: 1,
                hist_path: p.clone(),
            },
            RoleSpec::BridgedCoordinator {
                inner: Box::new(coordinator),
                listen: "l".into(),
                express: true,
                lowlatency: false,
                bridge_spin_us: 0,
                secret_file: p.clone(),
                plain: false,
                door: bridge::DoorMode::default(),
            },
            RoleSpec::BridgedRobots {
                inner: Box::new(robots),
                endpoint: "e".into(),
                express: true,
                lowlatency: false,
                bridge_spin_us: 0,
                secret_file: p.clone(),
                plain: false,
            },
            RoleSpec::ScaleRobot {
                run_id,
                map: "m".into(),
                robot_id: 0,
                robots: 2,
                batch: 1,
                duration_ms: 1,
                in_flight: 1,
                notify_gap_us: 0,
                timeout_ms: 1,
                peer_pid: None,
                hist_path: p,
            },
        ]
    }

    #[test]
    fn a_role_is_named_as_its_json_tag() {
        for spec in every_role() {
            let json = serde_json::to_value(&spec).unwrap();
            assert_eq!(json["role"], spec.role(), "{json}");
        }
    }
}
