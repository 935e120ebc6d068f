//! # fleetbench — qfleet's latency and scale benchmarks
//!
//! The harness behind `qfleet bench`: it measures, side by side in one run and on the real
//! message types, the raw iceoryx2 floor, qfleet's update loop (Q update at a robot → real
//! coordinator merge → merged hint applied at a robot) for each coordinator wait strategy, the
//! same loop over Unix sockets, and the in-process crossbeam floor; and how the fleet scales
//! with the number of robot processes and the hint batch size. Not here: the learner's own
//! throughput (`benches/learner.rs`), the coordinator and robot logic (their crates).
//!
//! Every benchmark that involves two processes runs as two real processes: the harness
//! re-executes a program (for `qfleet bench`, the `qfleet` binary itself with a hidden
//! `--role <json>` argument; see [`Launcher`] and [`role_main`]) once per side, each row on its
//! own iceoryx2 run id, and checks afterwards that the row left no file in `/dev/shm` or under
//! `/tmp/iceoryx2`.

#![deny(missing_docs)]

pub mod cpu;
pub mod crosshost;
pub mod harness;
pub mod machine;
pub mod plot;
pub mod report;
pub mod roles;
pub mod spec;

pub use harness::{Launcher, Options, ROW_LABELS, run};
pub use machine::Machine;
pub use report::{Report, Row, ScaleRow};
pub use roles::role_main;

/// Why a benchmark (or one of its child processes) failed.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// The qfleet bus failed (service creation, registration, send, receive).
    #[error(transparent)]
    Bus(#[from] bus::BusError),
    /// Plain iceoryx2 (raw rows) failed.
    #[error("iceoryx2: {0}")]
    Iox(String),
    /// A file, socket or pipe operation failed.
    #[error("{what}: {source}")]
    Io {
        /// What was being done.
        what: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// A peer process did not answer in time or died; the row is abandoned.
    #[error("waited for {what}: {}", if *died { "the process died".to_string() } else { format!("no answer within {timeout_ms} ms") })]
    PeerTimeout {
        /// What was awaited.
        what: String,
        /// The timeout, ms.
        timeout_ms: u64,
        /// Whether the peer process is gone.
        died: bool,
    },
    /// A child process failed or printed no report.
    #[error("{role} process failed: {detail}")]
    Child {
        /// The role of the child.
        role: String,
        /// Its exit status and last stderr words.
        detail: String,
    },
    /// A role argument could not be decoded (only the harness writes them).
    #[error("bad --role argument: {0}")]
    Spec(String),
    /// A latency histogram file could not be written or read.
    #[error(transparent)]
    Hist(#[from] ::report::hist::HistError),
    /// The real coordinator failed.
    #[error("coordinator: {0}")]
    Coordinator(String),
    /// Drawing a plot failed.
    #[error("plot {path}: {detail}")]
    Plot {
        /// The SVG file.
        path: String,
        /// What went wrong.
        detail: String,
    },
    /// A row left shared-memory files behind.
    #[error("row {label} left files behind: {files:?}")]
    Leftovers {
        /// The row.
        label: String,
        /// The files.
        files: Vec<String>,
    },
    /// Bad options.
    #[error("{0}")]
    Input(String),
}

/// A failed send is a bus failure ([`bus::BusError::Send`]): no benchmark row survives one.
impl From<bus::SendError> for BenchError {
    fn from(e: bus::SendError) -> Self {
        BenchError::Bus(e.into())
    }
}
