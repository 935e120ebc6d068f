//! `qfleet bench`: thin glue over the `fleetbench` harness (options, output, files).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

/// Latency of the update loop against the raw iceoryx2 floor, Unix sockets and crossbeam,
/// and fleet scale; see BENCHMARKS.md.
#[derive(Debug, Args)]
pub struct BenchCmd {
    /// A short run (a few thousand samples per row, no scale section): under a minute.
    #[arg(long)]
    quick: bool,
    /// Print `{"machine": {...}, "rows": [...]}` on stdout instead of the tables.
    #[arg(long)]
    json: bool,
    /// Write latency.csv (dora-rs layout), one .hgrm per row, latency.svg, report.json and
    /// summary.md (plus scale.csv/scale.svg) into this directory.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Only the fleet-scale section (N robot processes, hint batch sizes).
    #[arg(long, conflicts_with = "no_scale")]
    scale: bool,
    /// Skip the fleet-scale section of a full run.
    #[arg(long)]
    no_scale: bool,
    /// Only these rows (comma-separated labels, e.g. `loop-spin,iox2-raw-spin`).
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
    /// Recorded samples per row (default 100000, --quick 5000).
    #[arg(long)]
    samples: Option<u64>,
    /// Warm-up round trips per row (default 10000, --quick 1000).
    #[arg(long)]
    warmup: Option<u64>,
    /// Hybrid wait: µs the coordinator keeps spinning after the last message [default: 200, and
    /// 0 for the cross-host loop, as `qfleet run` does with remote robots]
    #[arg(long)]
    spin_us: Option<u64>,
    /// Cross-host rows: µs each bridge keeps looking (yielding its CPU) after a message moved
    /// before it waits [default: 100, what a run uses]
    #[arg(long)]
    bridge_spin_us: Option<u64>,
    /// Fleet sizes of the scale section (comma-separated).
    #[arg(long, value_delimiter = ',')]
    robots: Vec<u32>,
    /// How long the robots of each scale point emit, ms.
    #[arg(long)]
    scale_ms: Option<u64>,
    /// Scale robots: hint batches in flight before a robot waits for the coordinator.
    #[arg(long, default_value_t = 8)]
    in_flight: u32,
    /// Scale robots: notify the coordinator at most once per this many µs (0 = every batch).
    #[arg(long, default_value_t = 0)]
    notify_gap_us: u64,
    /// Do not pin the rows' processes and threads to CPUs (by default, with two CPUs or more,
    /// each latency row's two sides run on CPUs 0 and 1; across hosts, the measuring thread on
    /// 0 and every other thread on 1).
    #[arg(long)]
    no_pin: bool,
    /// Only the cross-host rows (needs root): TCP and Zenoh ping-pong floors and the update
    /// loop across two network namespaces joined by a veth pair (BENCHMARKS.md "Across machines").
    #[arg(long, conflicts_with = "scale")]
    cross_host: bool,
    /// Internal: run one child process of the harness (JSON role spec).
    #[arg(long, hide = true)]
    role: Option<String>,
}

impl BenchCmd {
    pub fn run(self) -> Result<()> {
        if let Some(role) = &self.role {
            return fleetbench::role_main(role).context("benchmark child process");
        }
        let mut opts = fleetbench::Options::chosen(
            self.quick,
            self.scale,
            self.no_scale,
            self.only,
            self.cross_host,
        );
        if let Some(n) = self.samples {
            opts.samples = n;
        }
        if let Some(n) = self.warmup {
            opts.warmup = n;
        }
        if !self.robots.is_empty() {
            opts.scale_robots = self.robots;
        }
        if let Some(ms) = self.scale_ms {
            opts.scale_ms = ms;
        }
        if self.no_pin {
            opts.pin = false;
        }
        opts.spin_us = self.spin_us;
        opts.bridge_spin_us = self.bridge_spin_us;
        opts.scale_in_flight = self.in_flight.max(1);
        opts.scale_notify_gap_us = self.notify_gap_us;
        let launcher = fleetbench::Launcher {
            program: std::env::current_exe().context("cannot find the qfleet executable")?,
            args: vec!["bench".into()],
        };
        let report = fleetbench::run(&opts, &launcher)?;
        if let Some(dir) = &self.out {
            report
                .write_dir(dir)
                .with_context(|| format!("writing results to {}", dir.display()))?;
        }
        if self.json {
            crate::term::out!("{}", serde_json::to_string_pretty(&report.to_json())?)?;
        } else {
            crate::term::write_out(format_args!("{}", report.to_text()))?;
        }
        Ok(())
    }
}
