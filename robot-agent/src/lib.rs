//! The robot-agent: one planner learner wired to the qfleet bus.
//!
//! A thin process: the learning is the `planner` crate's, the transport the `bus` crate's.
//! This crate decides what a robot shares and when ([`share`]), how it applies what the fleet
//! shares (the documented rule in [`share`]), and the life cycle of a robot's run ([`agent`]).
//! What it writes (`robot-<id>.json`, phase details, histograms) is typed in the `report` crate.

pub mod agent;
pub mod experiment;
pub mod reconnect;
pub mod share;

pub use agent::{AgentArgs, AgentError, run};
pub use share::{ApplyRule, HintBatcher, ShareArgs};
