//! Figures a bridge reports per host: link state, reconnects, round trips, clock offset and
//! one-way latency of the messages it carried across.

use hdrhistogram::Histogram;
use serde::Serialize;

use crate::health::LinkState;

/// Percentiles of a latency histogram, ns.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Percentiles {
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

impl Percentiles {
    /// Of a histogram (all zero when empty).
    pub fn of(h: &Histogram<u64>) -> Self {
        if h.is_empty() {
            return Self::default();
        }
        Percentiles {
            count: h.len(),
            p50: h.value_at_quantile(0.5),
            p99: h.value_at_quantile(0.99),
            p999: h.value_at_quantile(0.999),
            max: h.max(),
        }
    }
}

/// A latency histogram from 1 ns to 100 s, 3 significant digits.
pub fn new_hist() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 100_000_000_000, 3).expect("constant bounds are valid")
}

/// Records `v` (clamped into the histogram's range).
pub fn record(h: &mut Histogram<u64>, v: u64) {
    let _ = h.record(v.clamp(1, 100_000_000_000));
}

/// What one bridge saw of the link to one other host.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct HostReport {
    /// The host's name (as it joined).
    pub host: String,
    /// Robot ids it ran.
    pub robots: Vec<u32>,
    /// Final link state (`lost` = given up after the deadline).
    pub state: Option<LinkState>,
    /// Times the link came back after heartbeats had stopped (`--link-down-ms` of silence).
    pub reconnects: u64,
    /// Milliseconds the link was down in all.
    pub down_ms: u64,
    /// Estimated clock offset `that host − this host`, ns (error ≤ `best_rtt_ns / 2`).
    pub clock_offset_ns: i64,
    /// Fastest heartbeat round trip.
    pub best_rtt_ns: u64,
    /// Heartbeat round trips (bridge to bridge, no clocks involved).
    pub rtt_ns: Percentiles,
    /// One-way latency of the messages that arrived from that host, sender's send time (moved
    /// onto this host's clock) to delivery here.
    pub one_way_in_ns: Percentiles,
    /// Frames sent / received.
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
}
