//! qfleet's typed results contract: what a run leaves in its `--out` directory and how it
//! gets there.
//!
//! - [`robot`]: what a robot reports about itself ([`RobotResult`], [`PhaseDetail`],
//!   [`Counters`], [`EndStatus`]), `Serialize + Deserialize` both ways, so readers get types,
//!   not untyped JSON;
//! - [`hist`]: the latency-histogram shape every process records, its summaries and files;
//! - [`outdir`]: every file name of an out directory ([`OutFile`]) and the directory that reads
//!   and writes them ([`OutDir`]);
//! - [`run`]: what the coordinator reports about a run or an experiment ([`RunResult`],
//!   [`ExperimentResult`], [`RobotOutcome`], [`LivenessEvent`]);
//! - [`grid`]: what a shared-grid run reports ([`GridResult`]: sum of costs, makespan, the
//!   lower bound, conflicts, ticks per second);
//! - [`hosts`]: which host each robot ran on and the link to each joined host ([`HostEntry`],
//!   [`HostLink`]), the `hosts` of a result across machines;
//! - [`checkpoint`]: what a restarted coordinator resumes from ([`CoordinatorCheckpoint`]);
//! - [`summary`]: the human summaries of a run and of an experiment's seed, as text; [`table`]:
//!   the column-aligned [`TextTable`] they are made of;
//! - [`text`]: text from outside escaped before it reaches a terminal ([`escape`]);
//! - [`log`]: the processes' log lines ([`log_line!`]: `eprintln!` that never panics on a
//!   full disk);
//! - [`atomic`]: the one writer ([`write_atomic`]: temp file, `fsync`, rename), whose errors
//!   name the file and keep the OS error (a full disk is an error, never a panic).
//!
//! Not here: the bus, the learner, or any decision about a run; this crate only describes and
//! stores results.

pub mod atomic;
pub mod checkpoint;
pub mod grid;
pub mod hist;
pub mod hosts;
pub mod lifelong;
pub mod log;
pub mod outdir;
pub mod robot;
pub mod run;
pub mod summary;
pub mod table;
pub mod text;
pub mod words;

pub use atomic::{
    Durability, WriteError, WriteStep, write_atomic, write_atomic_with, write_json_atomic,
    write_json_atomic_with,
};
pub use checkpoint::{CoordinatorCheckpoint, NotResumed, RobotCheckpoint};
pub use grid::{GridEnd, GridResult, GridRobot};
pub use hist::{HistError, LatencyStats};
pub use hosts::{HostEntry, HostLink, HostState, LinkPercentiles};
pub use lifelong::{LifelongLearning, LifelongResult};
pub use outdir::{LatencyPath, OutDir, OutFile, ReadError, RobotHist};
pub use robot::{ApplyCounters, Counters, EndStatus, LinkCounters, PhaseDetail, RobotResult};
pub use run::{
    ExperimentResult, GoalPhase, LivenessEvent, LivenessKind, LivenessReport, MergeRule,
    PhaseResult, RobotEntry, RobotOutcome, RobotPhase, RunResult, Throughput, WaitStrategy,
};
pub use table::TextTable;
pub use text::escape;
pub use words::{ShareMode, Word};
