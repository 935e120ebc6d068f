//! The results: latency rows, scale points, goal verdicts, and their text, JSON, CSV, `.hgrm`,
//! Markdown and SVG forms.

use std::fmt::Write as _;
use std::path::Path;

use hdrhistogram::Histogram;
use serde::Serialize;

use crate::spec::ChildReport;
use crate::{BenchError, Machine};

/// CPU use of one process of a row over its measurement window.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ProcessCpu {
    /// What the process does (`coordinator`, `robots`, `pong`, …).
    pub name: String,
    /// Percent of one core.
    pub cpu_pct: f64,
}

/// One latency row: a round-trip (or update-loop) distribution and what it cost.
#[derive(Debug, Clone)]
pub struct Row {
    /// `iox2-raw-spin`, `loop-hybrid`, … (see [`crate::ROW_LABELS`]).
    pub label: String,
    /// Payload bytes of the request message (`QHintBatch`).
    pub bytes: usize,
    /// The recorded latencies, ns.
    pub hist: Histogram<u64>,
    /// Samples recorded.
    pub count: u64,
    /// Round trips without an answer, given up on and sent again (not samples; see
    /// [`crate::roles::fleet::LOOP_RETRY`]).
    pub lost: u64,
    /// Smallest sample, ns.
    pub min_ns: u64,
    /// Mean, ns.
    pub mean_ns: f64,
    /// Median, ns.
    pub p50_ns: u64,
    /// 90th percentile, ns.
    pub p90_ns: u64,
    /// 95th percentile, ns.
    pub p95_ns: u64,
    /// 99th percentile, ns.
    pub p99_ns: u64,
    /// 99.9th percentile, ns.
    pub p999_ns: u64,
    /// Largest sample, ns.
    pub max_ns: u64,
    /// Messages per second over the window: two per round trip (request and answer).
    pub msgs_per_s: f64,
    /// Sum of the processes' CPU use, percent of one core.
    pub cpu_pct: f64,
    /// CPU use per process.
    pub processes: Vec<ProcessCpu>,
    /// CPU use of the serving side while the measuring side was idle, percent of one core.
    pub idle_peer_cpu_pct: Option<f64>,
}

impl Row {
    /// Builds a row of a two-process measurement: the measuring child (`names[0]`) and, when
    /// it measured one, its peer (`names[1]`), each with its share of a core.
    pub fn of_pair(
        label: &str,
        bytes: usize,
        hist: Histogram<u64>,
        m: &ChildReport,
        names: [&str; 2],
    ) -> Self {
        let mut processes = vec![ProcessCpu {
            name: names[0].to_string(),
            cpu_pct: crate::cpu::pct(m.self_cpu_ns, m.wall_ns),
        }];
        if let Some(peer_ns) = m.peer_cpu_ns {
            processes.push(ProcessCpu {
                name: names[1].to_string(),
                cpu_pct: crate::cpu::pct(peer_ns, m.wall_ns),
            });
        }
        Row::new(label, bytes, hist, m, processes)
    }

    /// Builds a row from the measuring child's report and histogram.
    pub fn new(
        label: &str,
        bytes: usize,
        hist: Histogram<u64>,
        m: &ChildReport,
        processes: Vec<ProcessCpu>,
    ) -> Self {
        let q = |p: f64| {
            if hist.is_empty() {
                0
            } else {
                hist.value_at_quantile(p)
            }
        };
        let wall_s = m.wall_ns as f64 / 1e9;
        Row {
            label: label.to_string(),
            bytes,
            count: hist.len(),
            lost: m.batches_lost,
            min_ns: if hist.is_empty() { 0 } else { hist.min() },
            mean_ns: hist.mean(),
            p50_ns: q(0.5),
            p90_ns: q(0.9),
            p95_ns: q(0.95),
            p99_ns: q(0.99),
            p999_ns: q(0.999),
            max_ns: if hist.is_empty() { 0 } else { hist.max() },
            msgs_per_s: if wall_s > 0.0 {
                2.0 * hist.len() as f64 / wall_s
            } else {
                0.0
            },
            cpu_pct: processes.iter().map(|p| p.cpu_pct).sum(),
            processes,
            idle_peer_cpu_pct: m.peer_idle_cpu_pct,
            hist,
        }
    }
}

/// One point of the scale section.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct ScaleRow {
    /// Robot processes.
    pub robots: u32,
    /// Entries per hint batch.
    pub batch: u32,
    /// Q-updates the coordinator merged per second (its own figure, over its active time).
    pub merged_per_s: f64,
    /// Q-updates the robots sent per second (latest-wins: the excess is overwritten).
    pub offered_per_s: f64,
    /// Q-updates the robots sent in total.
    pub updates_sent: u64,
    /// Q-updates the coordinator merged in total (the rest were overwritten in its buffers).
    pub updates_merged: u64,
    /// Hint batches the robots gave up waiting for (not seen merged within 20 ms).
    pub batches_lost: u64,
    /// End-to-end loop samples (update at one robot → applied at another).
    pub loop_count: u64,
    /// Loop latency median, ns.
    pub loop_p50_ns: u64,
    /// Loop latency 99th percentile, ns.
    pub loop_p99_ns: u64,
    /// CPU of all processes, percent of one core.
    pub cpu_pct: f64,
    /// CPU of the robots together.
    pub cpu_robots_pct: f64,
    /// CPU of the coordinator.
    pub cpu_coordinator_pct: f64,
    /// Robots whose final report the coordinator accepted (all `robots` when none was lost).
    pub reports: u64,
    /// Of those, robots that stopped without a path (every scale robot: they learn nothing).
    pub without_path: u64,
    /// Messages the coordinator rejected as invalid.
    pub rejected: u64,
    /// Whether every process ran to completion.
    pub completed: bool,
    /// Why not.
    pub error: Option<String>,
}

/// How a scale point went, as its status column says it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ScaleStatus {
    /// Every update sent was merged and every robot's report counted.
    Ok,
    /// Some updates were never merged (at most half), or a report did not count.
    Degraded,
    /// The point failed, or most updates sent were never merged (issue 36: "ok" was printed
    /// while 61 % were never merged).
    Missed,
}

impl ScaleRow {
    /// Percent of the updates sent that the coordinator merged (100 when none were sent).
    pub fn merged_pct(&self) -> f64 {
        if self.updates_sent == 0 {
            100.0
        } else {
            100.0 * self.updates_merged as f64 / self.updates_sent as f64
        }
    }

    /// Updates sent that the coordinator neither merged nor rejected as invalid: overwritten
    /// in its latest-wins hint buffers or still unread when the run ended.
    pub fn never_merged(&self) -> u64 {
        self.updates_sent
            .saturating_sub(self.updates_merged)
            .saturating_sub(self.rejected)
    }

    /// The status and its reason: `Missed` when the point failed or more than half of the
    /// updates sent were never merged, `Degraded` when any were or a report did not count.
    pub fn status(&self) -> (ScaleStatus, String) {
        if let Some(e) = &self.error {
            return (ScaleStatus::Missed, e.clone());
        }
        let lost = self.never_merged();
        let share = if self.updates_sent == 0 {
            0.0
        } else {
            lost as f64 / self.updates_sent as f64
        };
        let mut why = Vec::new();
        if lost > 0 {
            why.push(format!(
                "{:.0} % never merged ({lost} of {} updates: overwritten in the coordinator's \
                 latest-wins hint buffers or unread at the end)",
                (share * 100.0).max(1.0),
                self.updates_sent
            ));
        }
        if self.rejected > 0 {
            why.push(format!("{} messages rejected as invalid", self.rejected));
        }
        if self.reports < u64::from(self.robots) {
            why.push(format!(
                "{} of {} robots' reports did not count",
                u64::from(self.robots) - self.reports,
                self.robots
            ));
        }
        let status = if share > 0.5 {
            ScaleStatus::Missed
        } else if why.is_empty() {
            ScaleStatus::Ok
        } else {
            ScaleStatus::Degraded
        };
        let mut text = match status {
            ScaleStatus::Ok => "ok".to_string(),
            ScaleStatus::Degraded => format!("degraded: {}", why.join("; ")),
            ScaleStatus::Missed => format!("MISSED: {}", why.join("; ")),
        };
        let _ = write!(
            text,
            " ({} of {} merged, {} batches unacked, {} without a path)",
            self.updates_merged, self.updates_sent, self.batches_lost, self.without_path
        );
        (status, text)
    }
}

/// One goal of the issue and whether this run met it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Goal {
    /// The goal.
    pub goal: String,
    /// What was measured.
    pub measured: String,
    /// Met (`Some(true)`), missed, or not measured in this run (`None`).
    pub met: Option<bool>,
}

/// Everything one `qfleet bench` run measured.
#[derive(Debug, Clone)]
pub struct Report {
    /// The machine.
    pub machine: Machine,
    /// Latency rows.
    pub rows: Vec<Row>,
    /// Scale points.
    pub scale: Vec<ScaleRow>,
}

/// A row as `--json` prints it: exactly the fields the issue names.
#[derive(Debug, Serialize)]
struct JsonRow<'a> {
    label: &'a str,
    p50_ns: u64,
    p90_ns: u64,
    p99_ns: u64,
    p999_ns: u64,
    max_ns: u64,
    count: u64,
    msgs_per_s: f64,
    cpu_pct: f64,
}

fn us(ns: u64) -> String {
    format!("{:.2}", ns as f64 / 1e3)
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> BenchError + '_ {
    move |source| BenchError::Io {
        what: format!("write {}", path.display()),
        source,
    }
}

impl Report {
    /// One line per row that gave up on round trips (a dropped latest-wins message), empty
    /// when none did: the samples of such a row are the round trips that were answered.
    fn losses(&self) -> String {
        let mut s = String::new();
        for r in self.rows.iter().filter(|r| r.lost > 0) {
            let _ = writeln!(
                s,
                "\n{}: {} round trip(s) had no answer within {} ms and were sent again (not \
                 samples: a latest-wins hint or merged batch was dropped)",
                r.label,
                r.lost,
                crate::roles::fleet::LOOP_RETRY.as_millis()
            );
        }
        s
    }

    /// The row with this label.
    pub fn row(&self, label: &str) -> Option<&Row> {
        self.rows.iter().find(|r| r.label == label)
    }

    /// `{"machine": {...}, "rows": [...]}` (plus `"scale": [...]` when the scale section ran).
    pub fn to_json(&self) -> serde_json::Value {
        let rows: Vec<JsonRow<'_>> = self
            .rows
            .iter()
            .map(|r| JsonRow {
                label: &r.label,
                p50_ns: r.p50_ns,
                p90_ns: r.p90_ns,
                p99_ns: r.p99_ns,
                p999_ns: r.p999_ns,
                max_ns: r.max_ns,
                count: r.count,
                msgs_per_s: r.msgs_per_s,
                cpu_pct: r.cpu_pct,
            })
            .collect();
        let mut v = serde_json::json!({ "machine": self.machine, "rows": rows });
        if !self.scale.is_empty() {
            v["scale"] = serde_json::json!(self.scale);
        }
        v
    }

    /// The goals, judged on this run (ratios from rows measured side by side).
    pub fn goals(&self) -> Vec<Goal> {
        let mut g = Vec::new();
        let ratio = |a: u64, b: u64| {
            if b == 0 {
                f64::INFINITY
            } else {
                a as f64 / b as f64
            }
        };
        match (self.row("loop-spin"), self.row("iox2-raw-spin")) {
            (Some(l), Some(r)) => {
                let p50 = ratio(l.p50_ns, r.p50_ns);
                g.push(Goal {
                    goal: "spin: loop p50 ≤ 2× raw iceoryx2 spin round trip".into(),
                    measured: format!("{} / {} µs = {p50:.2}×", us(l.p50_ns), us(r.p50_ns)),
                    met: Some(p50 <= 2.0),
                });
                let p999 = ratio(l.p999_ns, r.p999_ns);
                g.push(Goal {
                    goal: "spin: loop p99.9 ≤ 5× raw iceoryx2 spin round trip".into(),
                    measured: format!("{} / {} µs = {p999:.2}×", us(l.p999_ns), us(r.p999_ns)),
                    met: Some(p999 <= 5.0),
                });
            }
            _ => g.push(Goal {
                goal: "spin ratios".into(),
                measured: "loop-spin or iox2-raw-spin not run".into(),
                met: None,
            }),
        }
        // issue 12: the update loop across hosts against the Zenoh floor with the bridge's own
        // settings (express); only when the cross-host rows ran
        if let (Some(l), Some(z)) = (self.row("xhost-loop"), self.row("xhost-zenoh")) {
            let p50 = ratio(l.p50_ns, z.p50_ns);
            g.push(Goal {
                goal: "across hosts: loop p50 ≤ 1.5× the Zenoh ping-pong".into(),
                measured: format!("{} / {} µs = {p50:.2}×", us(l.p50_ns), us(z.p50_ns)),
                met: Some(p50 <= 1.5),
            });
            let p999 = ratio(l.p999_ns, z.p999_ns);
            g.push(Goal {
                goal: "across hosts: loop p99.9 ≤ 3× the Zenoh ping-pong".into(),
                measured: format!("{} / {} µs = {p999:.2}×", us(l.p999_ns), us(z.p999_ns)),
                met: Some(p999 <= 3.0),
            });
        }
        // issue 36 item 7: what the hub's front door costs the loop, door on (its direct
        // listener; its relay) against door off in the same run, all sealed; informational,
        // the goals above judge the loop itself
        if let Some(off) = self.row("xhost-loop-nodoor") {
            let floor = self.row("xhost-zenoh");
            for (label, how) in [("xhost-loop", "direct"), ("xhost-loop-relay", "relay")] {
                let Some(on) = self.row(label) else { continue };
                let side = |v: u64, f: Option<u64>| match f {
                    Some(f) => format!("{} ({:.2}× floor)", us(v), ratio(v, f)),
                    None => us(v),
                };
                for (what, a, b, f) in [
                    ("p50", on.p50_ns, off.p50_ns, floor.map(|z| z.p50_ns)),
                    ("p99.9", on.p999_ns, off.p999_ns, floor.map(|z| z.p999_ns)),
                ] {
                    g.push(Goal {
                        goal: format!("across hosts: door on ({how}) / off, loop {what}"),
                        measured: format!(
                            "{} / {} µs = {:.2}×",
                            side(a, f),
                            side(b, f),
                            ratio(a, b)
                        ),
                        met: None,
                    });
                }
            }
        }
        match (self.row("loop-hybrid"), self.row("uds-loop-blocking")) {
            (Some(h), Some(u)) => g.push(Goal {
                goal: "hybrid: loop p50 below the blocking Unix-socket loop".into(),
                measured: format!("{} vs {} µs", us(h.p50_ns), us(u.p50_ns)),
                met: Some(h.p50_ns < u.p50_ns),
            }),
            _ => g.push(Goal {
                goal: "hybrid vs blocking UDS".into(),
                measured: "loop-hybrid or uds-loop-blocking not run".into(),
                met: None,
            }),
        }
        if let Some(h) = self.row("loop-hybrid") {
            let idle = h.idle_peer_cpu_pct;
            g.push(Goal {
                goal: "hybrid: coordinator under 10% of a core while idle".into(),
                measured: idle.map_or("not measured".into(), |c| format!("{c:.1}% of a core")),
                met: idle.map(|c| c < 10.0),
            });
        }
        let four = self
            .scale
            .iter()
            .filter(|s| s.robots == 4 && s.completed)
            .max_by(|a, b| a.merged_per_s.total_cmp(&b.merged_per_s));
        g.push(Goal {
            goal: "≥ 20 M Q-updates/s merged with 4 robots and batching".into(),
            measured: four.map_or("4-robot point not run".into(), |s| {
                format!("{:.1} M/s (batch {})", s.merged_per_s / 1e6, s.batch)
            }),
            met: four.map(|s| s.merged_per_s >= 20e6),
        });
        let big = self.scale.iter().find(|s| s.robots == 64);
        g.push(Goal {
            goal: "64 robots run to completion".into(),
            measured: big.map_or("64-robot point not run".into(), |s| {
                s.error
                    .clone()
                    .unwrap_or_else(|| "all 65 processes finished".into())
            }),
            met: big.map(|s| s.completed),
        });
        g
    }

    /// The human-readable report (header, tables, goals).
    pub fn to_text(&self) -> String {
        let m = &self.machine;
        let mut s = String::new();
        let _ = writeln!(s, "qfleet bench — {}", m.date);
        let _ = writeln!(
            s,
            "machine: {} · {} cores · Linux {} · {}",
            m.cpu_model, m.cores, m.kernel, m.rustc
        );
        if !self.rows.is_empty() {
            let _ = writeln!(
                s,
                "\n{:<18} {:>8} {:>8} {:>8} {:>8} {:>8} {:>9}  {:>10} {:>6}  {:<32} {:>9}",
                "row (µs)",
                "n",
                "p50",
                "p90",
                "p99",
                "p99.9",
                "max",
                "msgs/s",
                "cpu%",
                "per process",
                "idle cpu%"
            );
            for r in &self.rows {
                let per: Vec<String> = r
                    .processes
                    .iter()
                    .map(|p| format!("{} {:.0}", p.name, p.cpu_pct))
                    .collect();
                let _ = writeln!(
                    s,
                    "{:<18} {:>8} {:>8} {:>8} {:>8} {:>8} {:>9}  {:>10.0} {:>6.0}  {:<32} {:>9}",
                    r.label,
                    r.count,
                    us(r.p50_ns),
                    us(r.p90_ns),
                    us(r.p99_ns),
                    us(r.p999_ns),
                    us(r.max_ns),
                    r.msgs_per_s,
                    r.cpu_pct,
                    per.join(", "),
                    r.idle_peer_cpu_pct
                        .map_or("-".into(), |c| format!("{c:.1}")),
                );
            }
            s.push_str(&self.losses());
        }
        if !self.scale.is_empty() {
            let _ = writeln!(
                s,
                "\n{:>6} {:>6} {:>14} {:>14} {:>8} {:>10} {:>10} {:>8} {:>8} {:>8}  status",
                "robots",
                "batch",
                "merged/s",
                "offered/s",
                "merged%",
                "loop p50",
                "loop p99",
                "cpu%",
                "coord%",
                "robots%"
            );
            for r in &self.scale {
                let _ = writeln!(
                    s,
                    "{:>6} {:>6} {:>14.0} {:>14.0} {:>8.1} {:>10} {:>10} {:>8.0} {:>8.0} {:>8.0}  {}",
                    r.robots,
                    r.batch,
                    r.merged_per_s,
                    r.offered_per_s,
                    r.merged_pct(),
                    us(r.loop_p50_ns),
                    us(r.loop_p99_ns),
                    r.cpu_pct,
                    r.cpu_coordinator_pct,
                    r.cpu_robots_pct,
                    r.status().1
                );
            }
        }
        let _ = writeln!(s, "\ngoals:");
        for g in self.goals() {
            let verdict = match g.met {
                Some(true) => "met   ",
                Some(false) => "MISSED",
                None => "n/a   ",
            };
            let _ = writeln!(s, "  [{verdict}] {} — {}", g.goal, g.measured);
        }
        s
    }

    /// The same tables as Markdown (for BENCHMARKS.md).
    pub fn to_markdown(&self) -> String {
        let m = &self.machine;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "Measured {} on {} ({} cores), Linux {}, {}.\n",
            m.date, m.cpu_model, m.cores, m.kernel, m.rustc
        );
        if !self.rows.is_empty() {
            s.push_str("| row | n | p50 µs | p90 µs | p99 µs | p99.9 µs | max µs | msgs/s | CPU % (sum) | CPU % per process | peer idle CPU % |\n");
            s.push_str("|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|\n");
            for r in &self.rows {
                let per: Vec<String> = r
                    .processes
                    .iter()
                    .map(|p| format!("{} {:.0}", p.name, p.cpu_pct))
                    .collect();
                let _ = writeln!(
                    s,
                    "| `{}` | {} | {} | {} | {} | {} | {} | {:.0} | {:.0} | {} | {} |",
                    r.label,
                    r.count,
                    us(r.p50_ns),
                    us(r.p90_ns),
                    us(r.p99_ns),
                    us(r.p999_ns),
                    us(r.max_ns),
                    r.msgs_per_s,
                    r.cpu_pct,
                    per.join(", "),
                    r.idle_peer_cpu_pct
                        .map_or("–".into(), |c| format!("{c:.1}"))
                );
            }
            s.push_str(&self.losses());
        }
        if !self.scale.is_empty() {
            s.push_str("\n| robots | batch | Q-updates merged/s | offered/s | loop p50 µs | loop p99 µs | CPU % | coordinator % | robots % | status |\n");
            s.push_str("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n");
            for r in &self.scale {
                let _ = writeln!(
                    s,
                    "| {} | {} | {:.2} M | {:.2} M | {} | {} | {:.0} | {:.0} | {:.0} | {} |",
                    r.robots,
                    r.batch,
                    r.merged_per_s / 1e6,
                    r.offered_per_s / 1e6,
                    us(r.loop_p50_ns),
                    us(r.loop_p99_ns),
                    r.cpu_pct,
                    r.cpu_coordinator_pct,
                    r.cpu_robots_pct,
                    r.status().1
                );
            }
        }
        s.push_str("\n| goal | measured | verdict |\n|---|---|---|\n");
        for g in self.goals() {
            let v = match g.met {
                Some(true) => "met",
                Some(false) => "**missed**",
                None => "n/a",
            };
            let _ = writeln!(s, "| {} | {} | {v} |", g.goal, g.measured);
        }
        s
    }

    /// The dora-rs style CSV: one `latency,<bytes>,<label>,<n>,<avg_ns>,<p50_ns>,<p95_ns>,
    /// <p99_ns>,<p999_ns>,<min_ns>,<max_ns>` line per row, no header.
    pub fn to_csv(&self) -> String {
        let mut s = String::new();
        for r in &self.rows {
            let _ = writeln!(
                s,
                "latency,{},{},{},{:.0},{},{},{},{},{},{}",
                r.bytes,
                r.label,
                r.count,
                r.mean_ns,
                r.p50_ns,
                r.p95_ns,
                r.p99_ns,
                r.p999_ns,
                r.min_ns,
                r.max_ns
            );
        }
        s
    }

    /// Writes `latency.csv`, one `<label>.hgrm` per row, `latency.svg`, `report.json`,
    /// `summary.md` and, with a scale section, `scale.csv` and `scale.svg` into `dir`.
    pub fn write_dir(&self, dir: &Path) -> Result<(), BenchError> {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let csv = dir.join("latency.csv");
        std::fs::write(&csv, self.to_csv()).map_err(io(&csv))?;
        for r in &self.rows {
            ::report::hist::write_hgrm(&r.hist, &dir.join(format!("{}.hgrm", r.label)))?;
        }
        if !self.rows.is_empty() {
            crate::plot::percentiles(&dir.join("latency.svg"), &self.rows)?;
        }
        let mut full = self.to_json();
        full["processes"] = serde_json::json!(
            self.rows
                .iter()
                .map(|r| serde_json::json!({
                    "label": r.label,
                    "processes": r.processes,
                    "idle_peer_cpu_pct": r.idle_peer_cpu_pct,
                    "p95_ns": r.p95_ns,
                    "min_ns": r.min_ns,
                    "mean_ns": r.mean_ns,
                }))
                .collect::<Vec<_>>()
        );
        full["goals"] = serde_json::json!(self.goals());
        let json = dir.join("report.json");
        let text =
            serde_json::to_string_pretty(&full).map_err(|e| BenchError::Spec(e.to_string()))?;
        std::fs::write(&json, text).map_err(io(&json))?;
        let md = dir.join("summary.md");
        std::fs::write(&md, self.to_markdown()).map_err(io(&md))?;
        if !self.scale.is_empty() {
            let mut s = String::from(
                "robots,batch,merged_per_s,offered_per_s,loop_p50_ns,loop_p99_ns,cpu_pct,cpu_coordinator_pct,cpu_robots_pct,completed\n",
            );
            for r in &self.scale {
                let _ = writeln!(
                    s,
                    "{},{},{:.0},{:.0},{},{},{:.1},{:.1},{:.1},{}",
                    r.robots,
                    r.batch,
                    r.merged_per_s,
                    r.offered_per_s,
                    r.loop_p50_ns,
                    r.loop_p99_ns,
                    r.cpu_pct,
                    r.cpu_coordinator_pct,
                    r.cpu_robots_pct,
                    r.completed
                );
            }
            let p = dir.join("scale.csv");
            std::fs::write(&p, s).map_err(io(&p))?;
            crate::plot::scale(&dir.join("scale.svg"), &self.scale)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(sent: u64, merged: u64) -> ScaleRow {
        ScaleRow {
            robots: 256,
            batch: 256,
            updates_sent: sent,
            updates_merged: merged,
            reports: 256,
            without_path: 256,
            completed: true,
            ..ScaleRow::default()
        }
    }

    #[test]
    fn the_status_never_says_ok_while_updates_were_never_merged() {
        assert_eq!(row(1000, 1000).status().0, ScaleStatus::Ok);
        assert!(row(1000, 1000).status().1.starts_with("ok ("));
        // issue 36: 61 % never merged printed "ok"
        let (s, text) = row(1000, 390).status();
        assert_eq!(s, ScaleStatus::Missed);
        assert!(text.starts_with("MISSED: 61 % never merged"), "{text}");
        let (s, text) = row(1000, 850).status();
        assert_eq!(s, ScaleStatus::Degraded);
        assert!(text.starts_with("degraded: 15 % never merged"), "{text}");
        // one update in a million still says so
        let (s, text) = row(1_000_000, 999_999).status();
        assert_eq!(s, ScaleStatus::Degraded);
        assert!(text.contains("1 of 1000000 updates"), "{text}");
    }

    #[test]
    fn rejected_updates_and_reports_that_did_not_count_are_named() {
        let r = ScaleRow {
            rejected: 10,
            reports: 250,
            ..row(1000, 990)
        };
        let (s, text) = r.status();
        assert_eq!(s, ScaleStatus::Degraded);
        assert!(text.contains("10 messages rejected"), "{text}");
        assert!(
            text.contains("6 of 256 robots' reports did not count"),
            "{text}"
        );
        assert!(!text.contains("never merged"), "{text}");
        let failed = ScaleRow {
            error: Some("robot 3 timed out".into()),
            ..row(0, 0)
        };
        assert_eq!(
            failed.status(),
            (ScaleStatus::Missed, "robot 3 timed out".into())
        );
        assert_eq!(row(0, 0).merged_pct(), 100.0);
        assert_eq!(row(1000, 390).merged_pct(), 39.0);
    }
}
