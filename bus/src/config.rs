//! Run configuration: validated run id and fleet size, the iceoryx2 `Config` of the run, nodes.

use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use bus_schema::names::{RUN_ID_MAX_LEN, iceoryx_prefix};
use iceoryx2::config::Config;
use iceoryx2::prelude::*;

use crate::BusError;
use crate::clock::monotonic_ns;
use crate::files;

pub use bus_schema::MAX_ROBOTS;

/// Shared memory the merged-hints broadcast may reserve (the coordinator's publisher segment:
/// subscribers × per-robot buffer × one `MergedHintBatch`); [`merged_buffer_for`] sizes the
/// buffer from it. Reserved, not touched: tmpfs pages are used only as samples are written.
pub const MERGED_SEGMENT_BUDGET: usize = 32 << 20;

/// Merged batches buffered per robot in a fleet of `robots`: as many as fit
/// [`MERGED_SEGMENT_BUDGET`], 16 to 512 (512 at 4 robots, 77 at 64, 20 at 256).
///
/// Deep because merged batches are deltas: a batch a robot's latest-wins buffer overwrites is
/// lost to it for good, and four unpaced planning robots on two cores overflowed a 64-batch
/// buffer with about half of all merged batches (BENCHMARKS.md, "Value of sharing").
pub fn merged_buffer_for(robots: u32) -> usize {
    let subscribers =
        robots.max(1) as usize + BusConfig::DEFAULT_SPARE_PORTS as usize + OBSERVER_SLOTS as usize;
    let batch = std::mem::size_of::<bus_schema::MergedHintBatch>();
    (MERGED_SEGMENT_BUDGET / (batch * subscribers)).clamp(16, 512)
}

/// Ports and node slots every service keeps for outside readers (monitors, recorders, `iox2`,
/// Python) on top of the fleet and its `spare_ports`; see [`crate::Observer`].
pub const OBSERVER_SLOTS: u32 = 4;

/// Largest per-connection subscriber buffer accepted in a [`BusConfig`].
pub const MAX_BUFFER: usize = 4096;

/// Everything that sizes and names the services of one run; identical in every process of it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BusConfig {
    /// Run id: 1–48 characters from `A-Z a-z 0-9 _ -`; names the services and the iceoryx2
    /// prefix, so runs with different ids never see each other.
    pub run_id: String,
    /// Fleet size, `1..=MAX_ROBOTS`; robot ids are `0..robots`.
    pub robots: u32,
    /// Hint batches buffered per robot at the coordinator (latest-wins: older ones drop).
    pub hint_buffer: usize,
    /// Merged hint batches buffered per robot (latest-wins).
    pub merged_buffer: usize,
    /// States buffered per robot at the coordinator (latest-wins).
    pub state_buffer: usize,
    /// Discoveries buffered per robot at the coordinator (lossless: a full buffer makes the
    /// robot wait, so deeper means fewer stalls).
    pub discovery_buffer: usize,
    /// Extra ports and nodes per service beyond the fleet, for a restarted process whose dead
    /// predecessor is not cleaned up yet (outside readers have their own [`OBSERVER_SLOTS`]).
    pub spare_ports: u32,
    /// How long a lossless send keeps retrying into a full buffer before it reports
    /// [`SendError::DeliveryTimeout`](crate::SendError::DeliveryTimeout) instead of blocking
    /// forever on a stuck peer.
    pub send_timeout: Duration,
    /// Let iceoryx2 install SIGINT/SIGTERM handlers (off: the qfleet processes handle signals
    /// themselves, e.g. with `ctrlc`, and iceoryx2 must not compete for them).
    pub handle_signals: bool,
}

impl BusConfig {
    /// Default hint buffer per robot.
    pub const DEFAULT_HINT_BUFFER: usize = 8;
    /// Default merged-hints buffer per robot.
    pub const DEFAULT_MERGED_BUFFER: usize = 4;
    /// Default state buffer per robot.
    pub const DEFAULT_STATE_BUFFER: usize = 4;
    /// Default discovery buffer per robot.
    pub const DEFAULT_DISCOVERY_BUFFER: usize = 256;
    /// Default number of spare ports per service.
    pub const DEFAULT_SPARE_PORTS: u32 = 2;
    /// Default lossless send timeout.
    pub const DEFAULT_SEND_TIMEOUT: Duration = Duration::from_secs(5);

    /// A validated configuration with default buffer sizes.
    pub fn new(run_id: impl Into<String>, robots: u32) -> Result<Self, BusError> {
        let cfg = Self {
            run_id: run_id.into(),
            robots,
            hint_buffer: Self::DEFAULT_HINT_BUFFER,
            merged_buffer: Self::DEFAULT_MERGED_BUFFER,
            state_buffer: Self::DEFAULT_STATE_BUFFER,
            discovery_buffer: Self::DEFAULT_DISCOVERY_BUFFER,
            spare_ports: Self::DEFAULT_SPARE_PORTS,
            send_timeout: Self::DEFAULT_SEND_TIMEOUT,
            handle_signals: false,
        };
        cfg.validate()?;
        Ok(cfg)
    }

    /// Checks the run id and that every number is in range.
    pub fn validate(&self) -> Result<(), BusError> {
        validate_run_id(&self.run_id)?;
        if !(1..=MAX_ROBOTS).contains(&self.robots) {
            return Err(BusError::InvalidConfig(format!(
                "robots = {} but must be 1..={MAX_ROBOTS}",
                self.robots
            )));
        }
        for (name, value) in [
            ("hint_buffer", self.hint_buffer),
            ("merged_buffer", self.merged_buffer),
            ("state_buffer", self.state_buffer),
            ("discovery_buffer", self.discovery_buffer),
        ] {
            if !(1..=MAX_BUFFER).contains(&value) {
                return Err(BusError::InvalidConfig(format!(
                    "{name} = {value} but must be 1..={MAX_BUFFER}"
                )));
            }
        }
        if self.spare_ports > MAX_ROBOTS {
            return Err(BusError::InvalidConfig(format!(
                "spare_ports = {} but must be ≤ {MAX_ROBOTS}",
                self.spare_ports
            )));
        }
        if self.send_timeout.is_zero() {
            return Err(BusError::InvalidConfig(
                "send_timeout must be positive".into(),
            ));
        }
        Ok(())
    }

    /// The iceoryx2 `global.prefix` of this run, `qfleet.<run-id>.`.
    pub fn prefix(&self) -> String {
        iceoryx_prefix(&self.run_id)
    }

    /// The iceoryx2 `Config` of this run, built in code (no config file is read).
    ///
    /// Every subscriber keeps the unread samples of as many departed publishers as a service
    /// admits ([`Self::max_nodes`]). A robot sends its lossless final report and exits; from
    /// then on its sample lives only in the subscriber's "expired connection", of which
    /// iceoryx2 keeps 128 by default and silently discards the rest: 256 robots stopping
    /// together lost up to half their reports (`bus/tests/lossless.rs` shows it with 140).
    pub fn iceoryx_config(&self) -> Result<Config, BusError> {
        self.validate()?;
        let mut config = iceoryx_config_for_prefix(&self.prefix())?;
        let expired = &mut config
            .defaults
            .publish_subscribe
            .subscriber_expired_connection_buffer;
        *expired = (*expired).max(self.max_nodes());
        Ok(config)
    }

    /// The most processes (nodes) a service of this run admits — every robot, the coordinator,
    /// the spare ports of restarted processes and the outside readers' slots — and so a bound
    /// on the publishers or subscribers of any one topic.
    pub fn max_nodes(&self) -> usize {
        self.robots as usize + 1 + self.spare_ports as usize + OBSERVER_SLOTS as usize
    }

    /// Creates this process's iceoryx2 node in the run (one per process).
    ///
    /// Refuses a prefix holding a file of another user and an unusable iceoryx2 root first, and
    /// narrows the run's files to owner-only access after (see `files.rs`). A failure while
    /// `/dev/shm` is full is reported as [`BusError::NoShmSpace`], not as iceoryx2's
    /// `UnableToGenerateUniqueNodeId`.
    pub fn create_node(&self, name: &str) -> Result<Node<ipc::Service>, BusError> {
        self.create_node_with(name, true)
    }

    /// [`create_node`](Self::create_node) for a robot: without iceoryx2's automatic scan for
    /// dead nodes at node creation, service opening and node drop. Each scan reads every node
    /// of the run, so with it a fleet's start-up grows with the square of its size (measured:
    /// `qfleet run --robots 128 --map builtin:paper-10 --episodes 1` took 35.9 s with the scans,
    /// 18.7 s without, 2026-12-02). Dead nodes are still cleaned: by the coordinator's liveness
    /// thread (a dead robot), by the robot itself (a dead coordinator's ports), by a restarted
    /// coordinator's node creation and by the launcher's clean-up; a restarted robot whose dead
    /// predecessor still holds a port uses a spare port.
    pub fn create_robot_node(&self, name: &str) -> Result<Node<ipc::Service>, BusError> {
        self.create_node_with(name, false)
    }

    fn create_node_with(
        &self,
        name: &str,
        auto_cleanup: bool,
    ) -> Result<Node<ipc::Service>, BusError> {
        let mut config = self.iceoryx_config()?;
        config.global.node.cleanup_dead_nodes_on_creation = auto_cleanup;
        config.global.node.cleanup_dead_nodes_on_destruction = auto_cleanup;
        config.global.service.cleanup_dead_nodes_on_open = auto_cleanup;
        let node_err = |detail: String| BusError::Node {
            node: name.to_string(),
            prefix: self.prefix(),
            detail,
        };
        let node_name = NodeName::new(name).map_err(|e| node_err(format!("bad node name: {e}")))?;
        files::check_iceoryx_root()?;
        files::check_run_files(&self.prefix())?;
        let mode = if self.handle_signals {
            SignalHandlingMode::HandleTerminationRequests
        } else {
            SignalHandlingMode::Disabled
        };
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&config)
            .signal_handling_mode(mode)
            .create::<ipc::Service>()
            .map_err(|e| {
                if files::shm_exhausted() {
                    files::no_space(self)
                } else {
                    node_err(e.to_string())
                }
            })?;
        files::restrict_run_files(&self.prefix())?;
        crate::commit_run_shm(&self.prefix())?;
        Ok(node)
    }
}

/// Checks a run id: 1..=`RUN_ID_MAX_LEN` bytes of `A-Z a-z 0-9 _ -`.
///
/// The run id becomes part of service names and of file names in `/dev/shm`, so anything that
/// could be a path separator, a dot (the prefix delimiter) or invisible is refused.
pub fn validate_run_id(run_id: &str) -> Result<(), BusError> {
    let bad = |reason: String| BusError::InvalidRunId {
        run_id: run_id.to_string(),
        reason,
    };
    if run_id.is_empty() {
        return Err(bad("it is empty".into()));
    }
    if run_id.len() > RUN_ID_MAX_LEN {
        return Err(bad(format!(
            "it is {} bytes long, at most {RUN_ID_MAX_LEN} are allowed",
            run_id.len()
        )));
    }
    if let Some(c) = run_id
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || *c == '_' || *c == '-'))
    {
        return Err(bad(format!(
            "it contains {c:?}; only A-Z a-z 0-9 _ - are allowed"
        )));
    }
    Ok(())
}

/// A run id unlikely to collide with any other: `<tag>-<pid>-<counter>-<time>`.
///
/// Meant for tests and ad-hoc runs; `tag` is truncated so the result is always a valid run id
/// when `tag` itself only uses valid characters.
pub fn unique_run_id(tag: &str) -> String {
    static COUNTER: AtomicU32 = AtomicU32::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let t = (monotonic_ns() >> 10) & 0xff_ffff;
    let tag: String = tag.chars().take(20).collect();
    format!("{tag}-{}-{n}-{t:x}", std::process::id())
}

/// The iceoryx2 `Config` for an explicit prefix (used by [`crate::clean_stale`]).
///
/// Starts from iceoryx2's built-in defaults (never a config file, so a stray
/// `~/.config/iceoryx2/iceoryx2.toml` cannot change a run), sets the prefix and keeps the
/// automatic cleanup of dead nodes on node creation and service opening switched on.
/// Silences iceoryx2's own log output unless asked for ([`quiet_library_logs`]).
pub fn iceoryx_config_for_prefix(prefix: &str) -> Result<Config, BusError> {
    quiet_library_logs();
    let mut config = Config::default();
    config.global.prefix =
        FileName::new(prefix.as_bytes()).map_err(|e| BusError::InvalidRunId {
            run_id: prefix.to_string(),
            reason: format!("not a valid iceoryx2 prefix: {e}"),
        })?;
    config.global.node.cleanup_dead_nodes_on_creation = true;
    config.global.node.cleanup_dead_nodes_on_destruction = true;
    config.global.service.cleanup_dead_nodes_on_open = true;
    Ok(config)
}

/// Sets iceoryx2's log level once per process: `IOX2_LOG_LEVEL` if set (trace, debug, info,
/// warn, error, fatal), else `Warn` when `RUST_LOG` is set (the user asked for logs), else
/// `Fatal`.
///
/// iceoryx2 logs to stderr by default, at `Info` and up; warnings such as "No config file was
/// loaded" (printed whenever a default `Config` is looked up) are noise for a qfleet user,
/// since every failure they stand for comes back as a [`BusError`] that says more.
pub fn quiet_library_logs() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let default = if std::env::var_os("RUST_LOG").is_some() {
            LogLevel::Warn
        } else {
            LogLevel::Fatal
        };
        set_log_level_from_env_or(default);
    });
}

#[cfg(test)]
mod merged_buffer_tests {
    use super::*;

    #[test]
    fn the_merged_buffer_fills_its_budget_and_stays_in_bounds() {
        let batch = std::mem::size_of::<bus_schema::MergedHintBatch>();
        assert_eq!(merged_buffer_for(4), 512);
        assert_eq!(merged_buffer_for(64), 77);
        assert_eq!(merged_buffer_for(MAX_ROBOTS), 20);
        assert_eq!(merged_buffer_for(0), merged_buffer_for(1));
        for robots in 1..=MAX_ROBOTS {
            let b = merged_buffer_for(robots);
            assert!((16..=512).contains(&b) && b <= MAX_BUFFER);
            let subscribers = robots as usize + 2 + OBSERVER_SLOTS as usize;
            assert!(b == 512 || b * batch * subscribers <= MERGED_SEGMENT_BUDGET);
            assert!(b <= merged_buffer_for(robots.saturating_sub(1).max(1)));
        }
    }

    #[test]
    fn a_default_four_robot_run_fits_a_containers_default_dev_shm() {
        // Docker gives a container 64 MiB of /dev/shm unless told otherwise
        let mut cfg = BusConfig::new("shm-budget", 4).unwrap();
        cfg.hint_buffer = 64; // the coordinator's default
        cfg.merged_buffer = merged_buffer_for(4);
        let need = crate::files::shm_estimate(&cfg);
        println!("4 robots: {} MiB reserved", need >> 20);
        assert!(need < 64 << 20, "{need} bytes");
    }
}
