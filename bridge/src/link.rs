//! The Zenoh session and the settings that decide the link's latency floor.
//!
//! One peer-to-peer session per host: the coordinator's host listens on the `--listen`
//! endpoint, a joining host connects to it. Multicast scouting and gossip are off, so a bridge
//! talks only to the endpoint it was given (never to whatever else is on the network), and a
//! joining host does not listen at all. Zenoh's own reliability (TCP) carries frames while a
//! session lasts; what a broken session loses, [`crate::reliable`] resends.

use std::time::Duration;

use zenoh::Wait;
use zenoh::qos::{CongestionControl, Priority};

use crate::BridgeError;

/// Zenoh settings that move the link's latency (measured by `qfleet bench`, BENCHMARKS.md
/// "Across machines").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tuning {
    /// Publish frames as express (no batching with other messages: sent at once).
    pub express: bool,
    /// Zenoh's low-latency transport (no QoS priorities, no batching; both ends must agree).
    pub lowlatency: bool,
}

impl Default for Tuning {
    /// Express on, low-latency transport off (it must match on both hosts and gives up
    /// priorities; see BENCHMARKS.md for what each moves).
    fn default() -> Self {
        Tuning {
            express: true,
            lowlatency: false,
        }
    }
}

fn base_config(tuning: Tuning) -> Result<zenoh::Config, BridgeError> {
    let mut c = zenoh::Config::default();
    let mut set = |k: &str, v: &str| {
        c.insert_json5(k, v).map_err(|e| BridgeError::Zenoh {
            what: format!("setting {k} = {v}"),
            detail: crate::zenoh_text(&e),
        })
    };
    set("mode", "\"peer\"")?;
    set("scouting/multicast/enabled", "false")?;
    set("scouting/gossip/enabled", "false")?;
    set("timestamping/enabled", "false")?;
    if tuning.lowlatency {
        set("transport/unicast/lowlatency", "true")?;
        set("transport/unicast/qos/enabled", "false")?;
    }
    Ok(c)
}

/// Checks that `endpoint` is a Zenoh endpoint Zenoh can parse (`tcp/ADDR:PORT`).
pub fn check_endpoint(endpoint: &str) -> Result<(), BridgeError> {
    endpoint
        .parse::<zenoh::config::EndPoint>()
        .map(drop)
        .map_err(|e| BridgeError::Endpoint {
            endpoint: endpoint.to_string(),
            detail: crate::zenoh_text(&e),
        })
}

/// A session listening on `endpoint` (the coordinator's host); fails at once if it cannot bind.
pub fn listen(endpoint: &str, tuning: Tuning) -> Result<zenoh::Session, BridgeError> {
    check_endpoint(endpoint)?;
    let mut c = base_config(tuning)?;
    let list = serde_json::to_string(&[endpoint]).unwrap_or_default();
    c.insert_json5("listen/endpoints", &list)
        .map_err(|e| BridgeError::Endpoint {
            endpoint: endpoint.to_string(),
            detail: crate::zenoh_text(&e),
        })?;
    zenoh::open(c).wait().map_err(|e| BridgeError::Zenoh {
        what: format!("listening on {endpoint}"),
        detail: crate::zenoh_text(&e),
    })
}

/// A session connected to `endpoint` (a joining host), giving up after `timeout`.
pub fn connect(
    endpoint: &str,
    timeout: Duration,
    tuning: Tuning,
) -> Result<zenoh::Session, BridgeError> {
    check_endpoint(endpoint)?;
    let mut c = base_config(tuning)?;
    let list = serde_json::to_string(&[endpoint]).unwrap_or_default();
    let ms = timeout.as_millis().max(1).to_string();
    for (k, v) in [
        ("connect/endpoints", list.as_str()),
        ("connect/timeout_ms", ms.as_str()),
        ("connect/exit_on_failure", "true"),
        ("listen/endpoints", "[]"),
    ] {
        c.insert_json5(k, v).map_err(|e| BridgeError::Zenoh {
            what: format!("setting {k} = {v}"),
            detail: crate::zenoh_text(&e),
        })?;
    }
    zenoh::open(c).wait().map_err(|e| BridgeError::Zenoh {
        what: format!("connecting to {endpoint} (is `qfleet run … --listen {endpoint}` running there, and reachable?)"),
        detail: crate::zenoh_text(&e),
    })
}

/// A publisher for frames on `key`: express as tuned, never blocking the bridge loop (a full
/// queue drops; lossless frames are resent by [`crate::reliable`]).
pub fn publisher(
    session: &zenoh::Session,
    key: String,
    tuning: Tuning,
) -> Result<zenoh::pubsub::Publisher<'static>, BridgeError> {
    session
        .declare_publisher(key.clone())
        .congestion_control(CongestionControl::Drop)
        .priority(Priority::DataHigh)
        .express(tuning.express)
        .wait()
        .map_err(|e| BridgeError::Zenoh {
            what: format!("declaring a publisher on {key}"),
            detail: crate::zenoh_text(&e),
        })
}

/// Subscriber channel depth: a burst of this many frames waits in memory for the bridge loop.
pub const SUBSCRIBER_DEPTH: usize = 1 << 14;

/// Publishes one frame; a failure is returned for counting (the frame is resent if lossless).
pub fn put(publisher: &zenoh::pubsub::Publisher<'static>, frame: &[u8]) -> bool {
    publisher.put(frame.to_vec()).wait().is_ok()
}

/// How long an idle bridge loop waits for the next frame before it looks at its host's bus
/// again (what a message from a local process may wait for the bridge, at most).
pub const IDLE_WAIT: Duration = Duration::from_micros(100);

/// Makes this thread's timed waits end on time: Linux lets a sleeping thread's wakeup slip by
/// its timer slack (50 µs by default), which the bridge's short idle waits would pay on every
/// hop. Best effort: without it the waits are only later.
pub fn tighten_timer_slack() {
    // SAFETY: prctl(PR_SET_TIMERSLACK) changes only the calling thread's timer slack
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong);
    }
}
