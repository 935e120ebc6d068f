//! Which host each robot of a run ran on, and what the link to each other host did: the
//! `hosts` entry of a result ([`HostEntry`]), empty (and not written) for a run on one host.
//!
//! The `bridge` crate fills a [`HostLink`] per joined host; `qfleet run` and `qfleet experiment`
//! put the local host first ([`HostEntry::local`]) and the joined hosts after it into the result
//! before it is written, so `result.json` and `--json` say the same.

use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};

/// Percentiles of a link latency histogram, ns.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkPercentiles {
    /// Samples.
    pub count: u64,
    /// Median.
    pub p50: u64,
    /// 99th percentile.
    pub p99: u64,
    /// 99.9th percentile.
    pub p999: u64,
    /// Largest.
    pub max: u64,
}

impl LinkPercentiles {
    /// Of a histogram (all zero when empty).
    pub fn of(h: &Histogram<u64>) -> Self {
        if h.is_empty() {
            return Self::default();
        }
        LinkPercentiles {
            count: h.len(),
            p50: h.value_at_quantile(0.5),
            p99: h.value_at_quantile(0.99),
            p999: h.value_at_quantile(0.999),
            max: h.max(),
        }
    }
}

/// A host's state at the end of the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HostState {
    /// The coordinator's own host.
    Local,
    /// Joined, but no heartbeat was heard from it.
    Joining,
    /// Heartbeats arrived until the end.
    Up,
    /// Silent for longer than the down threshold at the end.
    Down,
    /// Silent past the deadline: given up on, its robots reported lost.
    Lost,
}

/// What one bridge saw of the link to one other host.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct HostLink {
    /// Times the link came back after heartbeats had stopped (`--link-down-ms` of silence).
    pub reconnects: u64,
    /// Milliseconds the link was down in all.
    pub down_ms: u64,
    /// Estimated clock offset `that host − this host`, ns (error ≤ `best_rtt_ns / 2`).
    pub clock_offset_ns: i64,
    /// Fastest heartbeat round trip.
    pub best_rtt_ns: u64,
    /// Heartbeat round trips (bridge to bridge, no clocks involved).
    pub rtt_ns: LinkPercentiles,
    /// One-way latency of the messages that arrived from that host, sender's send time (moved
    /// onto this host's clock) to delivery here.
    pub one_way_in_ns: LinkPercentiles,
    /// Frames sent.
    pub frames_out: u64,
    /// Frames received.
    pub frames_in: u64,
    /// Lossless frames sent again.
    pub resent: u64,
    /// Resent frames that had already arrived (skipped).
    pub duplicates: u64,
    /// Frames that could not be read or named a robot of another host (dropped).
    pub rejected: u64,
    /// Latest-wins messages that could not be delivered here (dropped).
    pub dropped: u64,
    /// What the peer sent past a cap and was not kept: lossless frames beyond the pending
    /// queue (not acknowledged, so sent again later), gone reports naming robots that are not
    /// the host's or were reported already.
    #[serde(default)]
    pub capped: u64,
    /// Frames that did not open with the host's key (tampered, forged, another host's or a
    /// stranger's) or that were replayed: dropped before anything in them was read.
    #[serde(default)]
    pub forged: u64,
}

/// One host of a run: its name, the robot ids it ran, and (for a joined host) the link to it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HostEntry {
    /// `local` for the coordinator's host, else the name the host joined with.
    pub host: String,
    /// Robot ids it ran.
    pub robots: Vec<u32>,
    /// Its state at the end.
    pub state: HostState,
    /// The link figures (joined hosts only), written beside the fields above.
    #[serde(flatten, default, skip_serializing_if = "Option::is_none")]
    pub link: Option<HostLink>,
}

impl HostEntry {
    /// The coordinator's host running robots `0..robots`.
    pub fn local(robots: u32) -> Self {
        HostEntry {
            host: "local".into(),
            robots: (0..robots).collect(),
            state: HostState::Local,
            link: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hosts_read_back_as_written_and_the_local_host_has_no_link_fields() {
        let joined = HostEntry {
            host: "host-b".into(),
            robots: vec![1, 2],
            state: HostState::Up,
            link: Some(HostLink {
                reconnects: 1,
                down_ms: 2012,
                clock_offset_ns: -41,
                best_rtt_ns: 180_000,
                rtt_ns: LinkPercentiles {
                    count: 40,
                    p50: 250_000,
                    p99: 900_000,
                    p999: 1_200_000,
                    max: 1_300_000,
                },
                frames_out: 10,
                frames_in: 12,
                resent: 3,
                ..HostLink::default()
            }),
        };
        let hosts = vec![HostEntry::local(1), joined];
        let json = serde_json::to_value(&hosts).unwrap();
        // the link figures sit beside host/robots/state, as the result's readers expect
        assert_eq!(json[1]["reconnects"], 1, "{json}");
        assert_eq!(json[1]["rtt_ns"]["p50"], 250_000, "{json}");
        assert_eq!(json[1]["state"], "up", "{json}");
        assert_eq!(
            json[0],
            serde_json::json!({"host": "local", "robots": [0], "state": "local"})
        );
        let back: Vec<HostEntry> = serde_json::from_value(json).unwrap();
        assert_eq!(back, hosts);
    }
}
