//! # bridge — a qfleet run across machines, over Zenoh
//!
//! Each host keeps iceoryx2 zero-copy shared memory for its own processes; this crate carries a
//! run's topics between hosts over one Zenoh session per joined host. The coordinator's host
//! runs a [`Hub`] (a thread of `qfleet run|experiment … --remote-robots K --listen ENDPOINT`); every other
//! host runs a [`Joiner`] (`qfleet join ENDPOINT --robots N`), which receives the whole
//! configuration at the join ([`join`]) and starts its robots.
//!
//! Neither the coordinator nor the robots know about the link: on the coordinator's host the hub
//! holds a proxy node per remote robot named as that robot's node, and on a joining host the
//! joiner's node is the robots' `qfleet-coordinator`. Lossless topics stay lossless across the
//! link ([`reliable`]: link sequence numbers, acks in heartbeats, go-back-N resends); latest-wins
//! topics are sent once. Heartbeats also tell when the link is down, came back (counted as a
//! reconnect) or is lost past a deadline ([`health`]), and estimate the two clocks' offset so
//! every time stamp is moved onto the receiving host's clock ([`wire`]).
//!
//! Strangers' TCP connections meet a front door first ([`relay::FrontDoor`], deciding with
//! [`door::Gate`]): per-source limits on connections, so a flood from one address cannot take
//! the slots a real host needs; admitted connections are relayed to the Zenoh session, which
//! listens on loopback only.
//!
//! Every host proves it holds the run's join secret before it gets a slot, and every frame after
//! the join is sealed with keys of that host and direction ([`seal`]); the frame handling,
//! ordering and figures both sides share are one [`end::LinkEnd`]. What the listening run
//! decides around its hub (fleet total, hang deadline, the plan's shipped files, the secret
//! file, the hub report's lines) is [`listen`].
//!
//! Not here: a transport (Zenoh is the transport), process spawning (the `qfleet` CLI), the
//! coordinator's or the robots' logic.

#![deny(missing_docs)]

pub mod admit;
pub mod door;
pub mod end;
pub mod health;
pub mod hub;
pub mod join;
pub mod link;
pub mod listen;
pub mod probe;
pub mod relay;
pub mod reliable;
pub mod remote;
pub mod roster;
pub mod seal;
pub mod stats;
pub mod topics;
pub mod wire;

use std::time::Duration;

pub use door::{DoorReport, Limits as DoorLimits};
pub use end::{Got, LinkEnd, Meta, Sink};
pub use health::{ClockSync, LinkState, LinkWatch};
pub use hub::{DoorMode, Hub, HubOptions, HubReport};
pub use join::{JoinPlan, JoinReply, JoinRequest, PlanError, RemotePlan};
pub use link::{RUNTIME_THREADS, SPIN_AFTER, Tuning, prefer_runtime_threads};
pub use remote::{Ending, Joined, Joiner, request};
pub use roster::{Listed, Roster};
pub use seal::Secret;
pub use stats::{HostEntry, HostLink, HostReport, HostState, Percentiles};

/// How often each side sends a heartbeat (acks, clock echo, robots gone).
pub const HEARTBEAT_EVERY: Duration = Duration::from_millis(50);

/// Default heartbeat silence after which a link counts as down (then a reconnect is counted
/// when it is heard again).
pub const DEFAULT_DOWN_AFTER: Duration = Duration::from_millis(500);

/// Default silence after which a host is given up on.
pub const DEFAULT_DEADLINE: Duration = Duration::from_secs(10);

/// Default time a joined host has to start (register) its robots before its slots open again.
pub const DEFAULT_START_WITHIN: Duration = Duration::from_secs(10);

/// Default time after the hub's start during which hosts may join (before the coordinator's
/// 30 s registration timeout, so a run whose remote slots stay empty still completes).
pub const DEFAULT_JOIN_WITHIN: Duration = Duration::from_secs(15);

/// What can go wrong in a bridge.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// This host's iceoryx2 bus.
    #[error(transparent)]
    Bus(#[from] bus::BusError),
    /// The endpoint is not a Zenoh endpoint.
    #[error("{endpoint:?} is not a Zenoh endpoint (expected e.g. tcp/10.0.0.1:7447): {detail}")]
    Endpoint {
        /// What was given.
        endpoint: String,
        /// Zenoh's reason.
        detail: String,
    },
    /// A Zenoh call failed.
    #[error("zenoh: {what}: {detail}")]
    Zenoh {
        /// What was being done.
        what: String,
        /// Zenoh's error (its error type is not `std::error::Error`, so kept as text).
        detail: String,
    },
    /// The coordinator's host refused the join.
    #[error("join refused by the coordinator's host: {0}")]
    Refused(String),
    /// The coordinator's host's front door checked this host's proof of the join secret and
    /// refused it: the secret is not the run's.
    #[error(
        "{endpoint} refused this host's credentials: the join secret is not the one of the run \
         listening there"
    )]
    Credentials {
        /// The coordinator's host.
        endpoint: String,
    },
    /// The join exchange failed.
    #[error("join failed: {0}")]
    Join(String),
    /// The join secret, the challenge or a sealed answer.
    #[error(transparent)]
    Auth(#[from] seal::AuthError),
    /// The link itself failed.
    #[error("link: {0}")]
    Link(String),
    /// A bridge thread.
    #[error("bridge thread: {0}")]
    Thread(String),
    /// The front door: binding the `--listen` address, or starting its runtime.
    #[error("front door: {what}: {source}")]
    Door {
        /// What was being done.
        what: String,
        /// The system's error.
        source: std::io::Error,
    },
}

/// Zenoh's error text without the source location it appends (` at /…/src/lib.rs:62.`), which
/// means nothing to a user.
pub(crate) fn zenoh_text(e: &impl std::fmt::Display) -> String {
    let s = e.to_string();
    match s.find(" at /") {
        Some(i) => s[..i].to_string(),
        None => s,
    }
}
