//! The robot-agent: one planner learner wired to the qfleet bus.
//!
//! A thin process: the learning is the `planner` crate's, the transport the `bus` crate's.
//! This crate decides what a robot shares and when ([`share`]), how it applies what the fleet
//! shares (the documented rule in [`share`]), and the life cycle of a robot's run ([`agent`]).
//! [`hist`] holds the latency-histogram helpers the coordinator uses too.

pub mod agent;
pub mod experiment;
pub mod hist;
pub mod reconnect;
pub mod share;

pub use agent::{AgentArgs, AgentError, Counters, RobotResult, run};
pub use share::{ApplyRule, HintBatcher, ShareArgs, ShareMode, map_fingerprint};
