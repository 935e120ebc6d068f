//! The launcher library of qfleet: everything `qfleet run`, `qfleet experiment` and `qfleet
//! sweep` do to start, watch and stop the processes of a run, each in one place.
//!
//! - [`run_id`]: what a run id may be, default ids, and the exclusive claim of an id (a `flock`ed
//!   lock file in the user's private directory, released by the kernel when the launcher dies);
//! - [`seed`]: the seed of each robot process, derived from the run's seed;
//! - [`out`]: the output directory (refuses to mix results, creates temporary ones safely,
//!   deletes only what it created), atomic result writes, and an inventory of what was kept;
//! - [`spawn`]: starting a child that dies with its launcher (`PR_SET_PDEATHSIG`) in its own
//!   process group, and finding the sibling binaries;
//! - the line protocol between the coordinator's stdout and the launcher is the process
//!   contract's (`contract::lines`);
//! - [`supervise`]: the restart policy, backoff, stopping with a grace period, and the loop
//!   that applies them to a fleet of processes;
//! - [`exit`]: the exit codes of every qfleet command and how children's codes map onto them.
//!
//! What it is not: it knows nothing of the bus, the learner or the result schema; the commands
//! build the processes' command lines and read their results.

pub mod exit;
pub mod out;
pub mod run_id;
pub mod seed;
pub mod spawn;
pub mod supervise;
pub mod timeouts;

pub use exit::Exit;
pub use supervise::{Fleet, RestartPolicy, Supervised, Supervision, supervise};
