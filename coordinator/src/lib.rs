//! The qfleet coordinator: admits the fleet, receives every robot's traffic, merges Q hints
//! into a fleet table per goal, relays discoveries, drives runs and experiments, measures the
//! update loop, and writes the result. It is not a learner and holds no robot logic.
//!
//! Decisions live in IO-free types tested as specifications: [`admission`] (who belongs to
//! the fleet, bound to the iceoryx2 node that registered), [`discovery`] (ordering, dedup,
//! acks, relays), [`validate`] (every message field), [`liveness`] (lost, hung, restarted),
//! [`sharing::merge`] (the fleet table), [`checkpoint`] (an experiment's progress across coordinator
//! restarts), [`grid`] (a shared grid's intents and rounds; the resolver is the `mapf`
//! crate's), [`ahead`] (which goal each robot of a lifelong run learns next). One engine (`engine`) carries them out on the bus; [`run`](mod@run) and [`experiment`]
//! are two small drivers over it; an experiment's driver reads its plan (`contract::plan`); a run with
//! `--world shared` ends with [`grid`]'s execution.

pub mod admission;
pub mod ahead;
mod assemble;
pub mod checkpoint;
pub mod cpwriter;
pub mod discovery;
mod engine;
pub mod experiment;
pub mod grid;
pub mod lifelong;
pub mod liveness;
pub mod options;
pub mod output;
pub mod run;
pub mod validate;
mod wait;

pub use contract::coordinator::MergeRule;
pub use engine::exited_file;
pub use options::{
    BRIDGED_SPIN_US, CoordArgs, CoordError, DEFAULT_SPIN_US, WaitStrategy, spin_us_for,
};
pub use report::run::{
    LivenessEvent, LivenessKind, LivenessReport, RobotEntry, RobotOutcome, RunResult, Throughput,
};
pub use run::run;
