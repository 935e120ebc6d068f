//! The robot-agent: one planner learner wired to the qfleet bus.
//!
//! A thin process: the learning is the `planner` crate's, the transport the `bus` crate's, the
//! result files the `report` crate's. This crate decides what a robot shares and when
//! (`share`), keeps its discoveries until acknowledged ([`discovery`]), reads the
//! coordinator's plan ([`experiment`]: the one control protocol of runs and experiments),
//! obeys only its coordinator ([`gate`]), moves on a shared grid as the coordinator grants
//! ([`execute`]), survives a coordinator restart ([`reconnect`]), slows
//! down on request ([`pace`]), and drives it all phase by phase ([`robot`]). Not here: merging
//! the fleet's values (the coordinator) or launching processes.

pub mod args;
pub mod discovery;
pub mod error;
pub mod execute;
pub mod experiment;
pub mod gate;
pub mod pace;
pub mod reconnect;
pub mod robot;

pub use args::AgentArgs;
pub use contract::{ApplyRule, ShareArgs};
pub use error::AgentError;
pub use robot::run;
