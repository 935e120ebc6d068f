//! The bus's errors: every variant says what went wrong and what to do about it.
//!
//! [`BusError`] is the error of every operation but one. A send on an
//! [`Outbox`](crate::Outbox) returns its own [`SendError`], because its callers act on how it
//! failed: a lossless send that reached no subscriber or timed out waiting for a full buffer
//! means a peer is gone or stuck (the coordinator logs it and goes on, a robot without its
//! coordinator retries or looks for a new one, the bridge skips or re-queues the message),
//! while a failed loan or an iceoryx2 send error means the bus itself is broken.
//! `From<SendError> for BusError` (the variant [`BusError::Send`], transparent: same text,
//! same source) keeps `?` working for callers that do not care.
//!
//! The other operations keep the one enum, after reading how the workspace's callers match:
//! - the start handshake's outcomes (`Refused`, `Timeout`, `Interrupted`) are each acted on
//!   (exit codes 3 and 130, retrying in slices), but `Timeout` and `Interrupted` are not the
//!   handshake's alone — opening a robot's bus, waiting for `Start`, the coordinator's and the
//!   robot's own waits end the same way — and a handshake also fails with any receive, event
//!   or send error, so a `HandshakeError` would need a boxed `BusError` inside it and callers
//!   would look for a timeout in two places;
//! - opening services (`ServiceMissing`, `SchemaMismatch`, `IncompatibleService`, `Service`,
//!   `Port`): only the bus itself acts on the difference (a robot retries a missing service; a
//!   full `/dev/shm` explains an open failure), and outside it only tests look at a variant;
//! - the rest (config, files, liveness, resources) are each raised by one operation and
//!   reported, not matched, apart from the coordinator's exit code for `OpenFiles`.

use std::time::Duration;

/// Everything that can go wrong on the bus.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    /// The run id is empty, too long, or has characters outside `A-Z a-z 0-9 _ -`.
    #[error("invalid run id {run_id:?}: {reason}")]
    InvalidRunId {
        /// The offending run id.
        run_id: String,
        /// Why it was rejected.
        reason: String,
    },

    /// A `BusConfig` value is out of range.
    #[error("invalid bus configuration: {0}")]
    InvalidConfig(String),

    /// The iceoryx2 node (the process's handle on the run) could not be created.
    #[error("cannot create the iceoryx2 node {node:?} for run prefix {prefix:?}: {detail}")]
    Node {
        /// Node name.
        node: String,
        /// iceoryx2 prefix of the run.
        prefix: String,
        /// iceoryx2's error.
        detail: String,
    },

    /// A peer opened the service with another payload type name, size or alignment.
    #[error(
        "service {service:?} carries a different payload type than this process's {type_name:?} \
         ({size} bytes, align {align}): the two sides were built from different bus-schema \
         versions (this process speaks schema v{schema_version}). Rebuild every qfleet binary \
         of the run from the same source; set IOX2_LOG_LEVEL=Debug to see iceoryx2's detail"
    )]
    SchemaMismatch {
        /// Service name.
        service: String,
        /// This process's type name.
        type_name: &'static str,
        /// This process's payload size.
        size: usize,
        /// This process's payload alignment.
        align: usize,
        /// This process's `SCHEMA_VERSION`.
        schema_version: u32,
    },

    /// The service exists with smaller limits or another overflow mode than this process needs.
    #[error(
        "service {service:?} exists with incompatible settings ({detail}); a process of the \
         same run was started with a different fleet size or bus configuration — start every \
         process of a run with the same settings, or use a fresh run id"
    )]
    IncompatibleService {
        /// Service name.
        service: String,
        /// iceoryx2's error.
        detail: String,
    },

    /// The service does not exist (yet): the coordinator has not created it.
    #[error("service {service:?} does not exist; is the coordinator of this run running?")]
    ServiceMissing {
        /// Service name.
        service: String,
    },

    /// Any other failure while creating or opening a service.
    #[error("cannot open or create service {service:?}: {detail}")]
    Service {
        /// Service name.
        service: String,
        /// iceoryx2's error.
        detail: String,
    },

    /// A publisher, subscriber, notifier or listener could not be created.
    #[error(
        "cannot create a {port} on {service:?}: {detail} (too many processes for the limits the service was created with?)"
    )]
    Port {
        /// Kind of port.
        port: &'static str,
        /// Service name.
        service: String,
        /// iceoryx2's error.
        detail: String,
    },

    /// A send on an [`Outbox`](crate::Outbox) failed; [`SendError`] says how, for the callers
    /// that treat a peer that is gone or stuck apart from a broken bus.
    #[error(transparent)]
    Send(#[from] SendError),

    /// Receiving failed inside iceoryx2.
    #[error("cannot receive on {service:?}: {detail}")]
    Receive {
        /// Service name.
        service: String,
        /// iceoryx2's error.
        detail: String,
    },

    /// Notifying or waiting on an event service failed.
    #[error("event on {service:?} failed: {detail}")]
    Event {
        /// Event service name.
        service: String,
        /// iceoryx2's error.
        detail: String,
    },

    /// The coordinator refused this robot's registration.
    #[error("registration of robot {robot_id} refused by the coordinator: {reason}")]
    Refused {
        /// This robot.
        robot_id: u32,
        /// The coordinator's reason text.
        reason: String,
    },

    /// A handshake step did not complete in time.
    #[error("timed out after {timeout:?} waiting for {what}")]
    Timeout {
        /// What was awaited.
        what: String,
        /// How long.
        timeout: Duration,
    },

    /// The wait was interrupted by SIGINT/SIGTERM (with `handle_signals`, or the stop flag of
    /// [`crate::RobotBus::open_until`]).
    #[error("interrupted by a termination signal")]
    Interrupted,

    /// Listing or cleaning the nodes of a run failed.
    #[error("node liveness check for prefix {prefix:?} failed: {detail}")]
    Liveness {
        /// iceoryx2 prefix.
        prefix: String,
        /// What failed.
        detail: String,
    },

    /// Removing leftover files failed.
    #[error("cannot remove {path}: {source}")]
    Cleanup {
        /// File that could not be removed.
        path: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },

    /// A file under the run's prefix belongs to another user: iceoryx2 would open and trust it.
    #[error(
        "{path} belongs to uid {owner}, not to this user (uid {user}): another user created a \
         file of this run; pick another run id (or have uid {owner} or root remove it)"
    )]
    ForeignFile {
        /// The file.
        path: String,
        /// Its owner.
        owner: u32,
        /// This process's effective uid.
        user: u32,
    },

    /// A file of the run could not be narrowed to owner-only access.
    #[error("cannot restrict {path} to its owner: {source}")]
    Permissions {
        /// The file.
        path: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },

    /// iceoryx2's root directory exists but this user cannot create files in it.
    #[error(
        "iceoryx2's directory {path} belongs to uid {owner} (mode {mode:o}) and this user (uid \
         {user}) cannot create files in it, so no process of the run could start; remove it \
         as its owner once no iceoryx2 process runs (e.g. `sudo rm -rf {path}`), or run as uid \
         {owner}"
    )]
    UnusableRoot {
        /// The directory.
        path: String,
        /// Its owner.
        owner: u32,
        /// Its mode bits.
        mode: u32,
        /// This process's effective uid.
        user: u32,
    },

    /// `/dev/shm` has too little room for the run's shared memory.
    #[error(
        "no space in /dev/shm: need ~{need_mib} MiB, have {have_mib} MiB; free some (`qfleet \
         clean`, `df -h /dev/shm`) or run fewer robots"
    )]
    NoShmSpace {
        /// Estimated need of the run, MiB.
        need_mib: f64,
        /// Free space now, MiB.
        have_mib: f64,
    },

    /// `/dev/shm` could not reserve the pages of one of the run's segments (see `commit`): the
    /// run stops here with a clear error instead of dying of SIGBUS when the page is touched.
    #[error(
        "no space in /dev/shm for the {bytes} bytes of {path} ({have} bytes free): free some \
         (`df -h /dev/shm`, `qfleet clean`) or run fewer robots: {source}"
    )]
    ShmCommit {
        /// The segment.
        path: String,
        /// Its size.
        bytes: u64,
        /// Free bytes of `/dev/shm` when it failed.
        have: u64,
        /// What `posix_fallocate` said.
        #[source]
        source: std::io::Error,
    },

    /// The coordinator of the fleet would run out of file descriptors.
    #[error(
        "a run of {robots} robots needs ~{need} open files in its coordinator, and this system \
         allows {soft} (hard limit {hard}, `ulimit -Hn`); raise the limit (`ulimit -n {need}` \
         as root, or LimitNOFILE= in a systemd unit) or run fewer robots"
    )]
    OpenFiles {
        /// Robots of the run.
        robots: u32,
        /// Open files the coordinator needs ([`crate::limits::coordinator_files`]).
        need: u64,
        /// The soft limit after raising it.
        soft: u64,
        /// The hard limit.
        hard: u64,
    },

    /// Every observer slot of the run is taken by live outside readers.
    #[error(
        "run {run_id} already has {slots} outside readers, all the slots it keeps for them; \
         stop one (the remaining ports are kept for restarts of the fleet)"
    )]
    NoObserverSlot {
        /// The run.
        run_id: String,
        /// Observer slots per run.
        slots: u32,
    },
}

/// How one send on an [`Outbox`](crate::Outbox) failed (`send`, `send_with`, `send_batch`).
///
/// `DeliveryTimeout` and `NoSubscriber` (lossless topics only) mean the message reached no
/// fleet subscriber because a peer is stuck, dead or not connected yet: the bus still works,
/// and the caller decides whether that is fatal. `Loan` and `Failed` mean the bus itself
/// failed.
#[derive(Debug, thiserror::Error)]
pub enum SendError {
    /// No shared-memory sample could be loaned for sending.
    #[error("cannot loan a sample on {service:?}: {detail}")]
    Loan {
        /// Service name.
        service: String,
        /// iceoryx2's error.
        detail: String,
    },

    /// Sending failed inside iceoryx2.
    #[error("cannot send on {service:?}: {detail}")]
    Failed {
        /// Service name.
        service: String,
        /// iceoryx2's error.
        detail: String,
    },

    /// A lossless send gave up: the subscriber's buffer stayed full for the whole send timeout.
    #[error(
        "lossless send on {service:?} not delivered within {timeout:?}: the subscriber does not \
         drain its buffer (stuck or dead?)"
    )]
    DeliveryTimeout {
        /// Service name.
        service: String,
        /// The configured send timeout.
        timeout: Duration,
    },

    /// A lossless send reached no subscriber at all, so it was not delivered.
    #[error(
        "lossless send on {service:?} reached no subscriber (peer not started, gone, or not yet connected)"
    )]
    NoSubscriber {
        /// Service name.
        service: String,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_send_error_keeps_its_text_and_variant_inside_a_bus_error() {
        let e = SendError::DeliveryTimeout {
            service: "qfleet/r/coord/control".into(),
            timeout: Duration::from_millis(200),
        };
        let text = e.to_string();
        let bus = BusError::from(e);
        assert_eq!(bus.to_string(), text);
        assert!(matches!(
            bus,
            BusError::Send(SendError::DeliveryTimeout { .. })
        ));
    }
}
