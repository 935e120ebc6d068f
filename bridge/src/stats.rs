//! Figures a bridge reports per host: link state, reconnects, round trips, clock offset and
//! one-way latency of the messages it carried across. The figures themselves are the `report`
//! crate's ([`HostLink`]), so a result holds them typed.

use hdrhistogram::Histogram;
pub use report::hosts::{HostEntry, HostLink, HostState, LinkPercentiles as Percentiles};
use serde::Serialize;

use crate::health::LinkState;

/// A latency histogram from 1 ns to 100 s, 3 significant digits.
pub fn new_hist() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 100_000_000_000, 3).expect("constant bounds are valid")
}

/// Records `v` (clamped into the histogram's range).
pub fn record(h: &mut Histogram<u64>, v: u64) {
    let _ = h.record(v.clamp(1, 100_000_000_000));
}

/// What one bridge saw of the link to one other host: the host, its robots, the link's state
/// and its figures ([`HostLink`], the report-side type the result's `hosts` carry).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct HostReport {
    /// The host's name (as it joined).
    pub host: String,
    /// Robot ids it ran.
    pub robots: Vec<u32>,
    /// Final link state (`lost` = given up after the deadline).
    pub state: Option<LinkState>,
    /// Reconnects, time down, round trips, clock offset, frame counts.
    #[serde(flatten)]
    pub link: HostLink,
}

impl HostReport {
    /// The line a joining host logs at its end: the link to the coordinator's host at
    /// `endpoint`, its reconnects, time down, round trip and clock offset.
    pub fn link_line(&self, endpoint: &str) -> String {
        format!(
            "qfleet join: link to {endpoint}: {} reconnect(s), {} ms down, round trip p50 {:.1} µs, clock offset {} ns (±{} ns)",
            self.link.reconnects,
            self.link.down_ms,
            self.link.rtt_ns.p50 as f64 / 1e3,
            self.link.clock_offset_ns,
            self.link.best_rtt_ns / 2
        )
    }

    /// This host as an entry of a result's `hosts`.
    pub fn entry(&self) -> HostEntry {
        HostEntry {
            host: self.host.clone(),
            robots: self.robots.clone(),
            state: match self.state {
                None | Some(LinkState::Joining) => HostState::Joining,
                Some(LinkState::Up) => HostState::Up,
                Some(LinkState::Down) => HostState::Down,
                Some(LinkState::Lost) => HostState::Lost,
            },
            link: Some(self.link.clone()),
        }
    }
}
