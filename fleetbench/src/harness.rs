//! The orchestrator: starts the child processes of each row, collects their reports and
//! histograms, checks that nothing was left in shared memory, and builds the [`Report`].

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use ::report::hist::{new_hist, read_binary};
use bus::bus_schema::QHintBatch;
use bus::bus_schema::names::iceoryx_prefix;
use contract::coordinator::WaitStrategy;
use hdrhistogram::Histogram;

use crate::report::{Report, Row, ScaleRow};
use crate::spec::{ChildReport, Plan, REPORT_PREFIX, RoleSpec};
use crate::{BenchError, Machine};

/// The labels of the latency rows, in the order they run and are printed.
pub const ROW_LABELS: [&str; 8] = [
    "iox2-raw-spin",
    "iox2-raw-event",
    "loop-spin",
    "loop-event",
    "loop-hybrid",
    "uds-loop-blocking",
    "uds-loop-spin",
    "crossbeam",
];

/// How to start a child process: `program args… --role <json>`.
#[derive(Debug, Clone)]
pub struct Launcher {
    /// The executable (for `qfleet bench`: `std::env::current_exe()`).
    pub program: PathBuf,
    /// Arguments before `--role` (for `qfleet bench`: `["bench"]`).
    pub args: Vec<String>,
}

/// What to measure and how much.
#[derive(Debug, Clone)]
pub struct Options {
    /// Measure the latency rows.
    pub rows: bool,
    /// Measure the fleet-scale section.
    pub scale: bool,
    /// Only these row labels (empty: all of [`ROW_LABELS`]).
    pub only: Vec<String>,
    /// Recorded round trips per row (after warm-up).
    pub samples: u64,
    /// Warm-up round trips per row.
    pub warmup: u64,
    /// Idle time after each row's measurement during which the peer's CPU is sampled, ms.
    pub idle_ms: u64,
    /// Map of the loop rows.
    pub map: String,
    /// Hybrid wait: µs the coordinator spins after the last message; `None`: what a run
    /// would use ([`contract::spin_us_for`]: 200 on one host, 0 beside a bridge hub).
    pub spin_us: Option<u64>,
    /// Cross-host rows: µs each bridge keeps looking after a message moved; `None`:
    /// `bridge::SPIN_AFTER`, what a run uses.
    pub bridge_spin_us: Option<u64>,
    /// Fleet sizes of the scale section (batch = `scale_main_batch`).
    pub scale_robots: Vec<u32>,
    /// Hint batch sizes of the scale section (at `scale_batch_robots` robots).
    pub scale_batches: Vec<u32>,
    /// Batch size of the fleet-size sweep.
    pub scale_main_batch: u32,
    /// Fleet size of the batch-size sweep.
    pub scale_batch_robots: u32,
    /// How long the robots of one scale point emit, ms.
    pub scale_ms: u64,
    /// Map of the scale section; `generated` = an obstacle-free map just large enough that
    /// every robot's batch covers cells of its own.
    pub scale_map: String,
    /// Scale robots: hint batches in flight (sent, not yet seen merged) before a robot waits.
    pub scale_in_flight: u32,
    /// Scale robots notify the coordinator at most once per this many µs (0 = every batch).
    pub scale_notify_gap_us: u64,
    /// Pin the two sides of each latency row to different CPUs (0 and 1), so every row
    /// measures a cross-CPU round trip whatever else the machine runs; in the cross-host rows,
    /// the measuring thread to CPU 0 and every other thread of both hosts to CPU 1
    /// ([`crate::cpu::keep_apart`]). On by default with two CPUs or more.
    pub pin: bool,
    /// Shortest measurement window per row, ms (fast rows record more than `samples`).
    pub min_window_ms: u64,
    /// Print progress lines on stderr.
    pub progress: bool,
    /// Measure the cross-host rows (`crate::crosshost`, needs root) instead of the others.
    pub cross_host: bool,
}

impl Options {
    /// The full run: ≥100k samples per row after 10k warm-up, and the scale section.
    pub fn full() -> Self {
        Options {
            rows: true,
            scale: true,
            only: Vec::new(),
            samples: 100_000,
            warmup: 10_000,
            idle_ms: 1_000,
            map: "builtin:paper-20".into(),
            spin_us: None,
            bridge_spin_us: None,
            scale_robots: vec![1, 2, 4, 8, 16, 32, 64],
            scale_batches: vec![1, 16, 64, 256],
            scale_main_batch: 256,
            scale_batch_robots: 4,
            scale_ms: 2_000,
            scale_map: "generated".into(),
            scale_in_flight: 8,
            scale_notify_gap_us: 0,
            min_window_ms: 2_000,
            pin: std::thread::available_parallelism().is_ok_and(|n| n.get() >= 2),
            progress: true,
            cross_host: false,
        }
    }

    /// `--quick`: a few thousand samples per row, no scale section (under a minute).
    pub fn quick() -> Self {
        Options {
            scale: false,
            samples: 5_000,
            warmup: 1_000,
            idle_ms: 300,
            min_window_ms: 300,
            scale_robots: vec![1, 4, 16],
            scale_batches: vec![16, 256],
            scale_ms: 500,
            ..Self::full()
        }
    }

    /// The sections `qfleet bench` measures: `--quick` or the full set, then `scale` (only the
    /// scale section), `no_scale`, `only` (those rows, and no scale section unless `scale`),
    /// `cross_host` (only the cross-host rows).
    pub fn chosen(
        quick: bool,
        scale: bool,
        no_scale: bool,
        only: Vec<String>,
        cross_host: bool,
    ) -> Self {
        let mut opts = if quick { Self::quick() } else { Self::full() };
        if scale {
            (opts.rows, opts.scale) = (false, true);
        }
        if no_scale || (!only.is_empty() && !scale) {
            opts.scale = false;
        }
        opts.only = only;
        if cross_host {
            (opts.cross_host, opts.rows, opts.scale) = (true, false, false);
        }
        opts
    }

    pub(crate) fn plan(&self) -> Plan {
        Plan {
            warmup: self.warmup,
            samples: self.samples,
            idle_ms: self.idle_ms,
            timeout_ms: 10_000,
            min_window_ms: self.min_window_ms,
        }
    }

    fn wants(&self, label: &str) -> bool {
        if self.cross_host {
            return false;
        }
        self.only.is_empty() || self.only.iter().any(|o| o == label)
    }
}

/// Runs the benchmarks `opts` asks for, starting child processes with `launcher`.
pub fn run(opts: &Options, launcher: &Launcher) -> Result<Report, BenchError> {
    for o in &opts.only {
        if !ROW_LABELS.contains(&o.as_str())
            && !crate::crosshost::XHOST_LABELS.contains(&o.as_str())
        {
            return Err(BenchError::Input(format!(
                "unknown row {o:?}; rows are {}",
                ROW_LABELS.join(", ")
            )));
        }
    }
    if opts.samples == 0 {
        return Err(BenchError::Input("samples must be at least 1".into()));
    }
    let tmp = std::env::temp_dir().join(format!(
        "qfleet-bench-{}",
        bus::unique_run_id("h").replace('-', "")
    ));
    std::fs::create_dir_all(&tmp).map_err(|source| BenchError::Io {
        what: format!("create {}", tmp.display()),
        source,
    })?;
    let result = run_in(opts, launcher, &tmp);
    let _ = std::fs::remove_dir_all(&tmp);
    result
}

fn run_in(opts: &Options, launcher: &Launcher, tmp: &Path) -> Result<Report, BenchError> {
    let mut report = Report {
        machine: Machine::detect(),
        rows: Vec::new(),
        scale: Vec::new(),
    };
    if opts.cross_host {
        report
            .rows
            .extend(crate::crosshost::rows(opts, launcher, tmp)?);
    }
    if opts.rows {
        for label in ROW_LABELS.iter().filter(|l| opts.wants(l)) {
            let row = progress(label, opts, || run_row(label, opts, launcher, tmp))?;
            report.rows.push(row);
        }
    }
    if opts.scale {
        let mut points: Vec<(u32, u32)> = opts
            .scale_robots
            .iter()
            .map(|&n| (n, opts.scale_main_batch))
            .collect();
        for &b in &opts.scale_batches {
            if !points.contains(&(opts.scale_batch_robots, b)) {
                points.push((opts.scale_batch_robots, b));
            }
        }
        let mut opts = opts.clone();
        if opts.scale_map == "generated" {
            let needed = points
                .iter()
                .map(|(n, b)| *n as usize * (*b as usize).div_ceil(4))
                .max()
                .unwrap_or(64);
            opts.scale_map = write_open_map(tmp, needed)?;
        }
        let opts = &opts;
        for (n, b) in points {
            if opts.progress {
                report::log_line!("qfleet bench: scale {n} robots, batch {b} …");
            }
            let row = scale_point(n, b, opts, launcher, tmp);
            if opts.progress {
                match &row.error {
                    None => report::log_line!(
                        "qfleet bench: scale {n}×{b}: {:.1} M Q-updates merged/s ({} of {} sent)",
                        row.merged_per_s / 1e6,
                        row.updates_merged,
                        row.updates_sent
                    ),
                    Some(e) => report::log_line!("qfleet bench: scale {n}×{b} failed: {e}"),
                }
            }
            report.scale.push(row);
        }
    }
    Ok(report)
}

/// Writes an obstacle-free ASCII map of at least `cells` cells (64 wide), start top-left,
/// goal bottom-right; returns its path.
fn write_open_map(dir: &Path, cells: usize) -> Result<String, BenchError> {
    let width = 64;
    let height = cells.div_ceil(width).max(2);
    let mut text = String::with_capacity((width + 1) * height);
    for y in 0..height {
        for x in 0..width {
            text.push(match (x, y) {
                (0, 0) => 'S',
                (x, y) if x == width - 1 && y == height - 1 => 'G',
                _ => '.',
            });
        }
        text.push('\n');
    }
    let path = dir.join("scale-map.txt");
    std::fs::write(&path, text).map_err(|source| BenchError::Io {
        what: format!("write {}", path.display()),
        source,
    })?;
    Ok(path.display().to_string())
}

/// A started child process, its stdout collected by a thread.
pub(crate) struct Child {
    role: &'static str,
    child: std::process::Child,
    stdout: Option<std::thread::JoinHandle<String>>,
}

impl Child {
    pub(crate) fn id(&self) -> u32 {
        self.child.id()
    }

    /// Waits up to `timeout` for the child to exit (kills it after) and parses its report.
    pub(crate) fn wait(mut self, timeout: Duration) -> Result<ChildReport, BenchError> {
        let deadline = Instant::now() + timeout;
        let status = loop {
            match self.child.try_wait() {
                Ok(Some(status)) => break status,
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(5));
                }
                Ok(None) => {
                    self.kill();
                    return Err(BenchError::Child {
                        role: self.role.to_string(),
                        detail: format!("still running after {timeout:?}; killed"),
                    });
                }
                Err(e) => {
                    return Err(BenchError::Child {
                        role: self.role.to_string(),
                        detail: format!("cannot wait for it: {e}"),
                    });
                }
            }
        };
        let out = self
            .stdout
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default();
        if !status.success() {
            return Err(BenchError::Child {
                role: self.role.to_string(),
                detail: format!("{status} (its error is on stderr above)"),
            });
        }
        let line = out
            .lines()
            .find_map(|l| l.strip_prefix(REPORT_PREFIX))
            .ok_or_else(|| BenchError::Child {
                role: self.role.to_string(),
                detail: "exited without a report line".into(),
            })?;
        serde_json::from_str(line).map_err(|e| BenchError::Child {
            role: self.role.to_string(),
            detail: format!("unreadable report: {e}"),
        })
    }

    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Child {
    fn drop(&mut self) {
        // a child still running here belongs to a failed row: do not leave it behind
        if let Ok(None) = self.child.try_wait() {
            self.kill();
        }
    }
}

fn spawn(launcher: &Launcher, spec: &RoleSpec) -> Result<Child, BenchError> {
    spawn_on(launcher, spec, None)
}

/// Starts the child process of `spec` (pinned to `cpus` when given) as the launcher starts a
/// run's processes ([`launcher::spawn::bind_to_launcher`]): in its own process group and
/// killed by the kernel when this process dies, so a benchmark killed mid-row leaves no role
/// process behind.
pub(crate) fn spawn_on(
    launcher: &Launcher,
    spec: &RoleSpec,
    cpus: Option<&str>,
) -> Result<Child, BenchError> {
    let json = serde_json::to_string(spec).map_err(|e| BenchError::Spec(e.to_string()))?;
    let mut cmd = Command::new(&launcher.program);
    match cpus {
        Some(c) => cmd.env(crate::cpu::CPUS_ENV, c),
        None => cmd.env_remove(crate::cpu::CPUS_ENV),
    };
    let mut child = launcher::spawn::bind_to_launcher(&mut cmd)
        .args(&launcher.args)
        .arg("--role")
        .arg(json)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|source| BenchError::Io {
            what: format!("start {}", launcher.program.display()),
            source,
        })?;
    let stdout = child.stdout.take().map(|mut s| {
        std::thread::spawn(move || {
            let mut out = String::new();
            let _ = s.read_to_string(&mut out);
            out
        })
    });
    Ok(Child {
        role: spec.role(),
        child,
        stdout,
    })
}

/// Removes what a row left in shared memory and fails if anything stays.
fn check_clean(label: &str, run_id: &str) -> Result<(), BenchError> {
    let prefix = iceoryx_prefix(run_id);
    bus::clean_stale(&prefix)?;
    let left = bus::leftover_files(&prefix);
    if left.is_empty() {
        Ok(())
    } else {
        Err(BenchError::Leftovers {
            label: label.to_string(),
            files: left.iter().map(|p| p.display().to_string()).collect(),
        })
    }
}

pub(crate) fn row_timeout(plan: &Plan) -> Duration {
    // the slowest rows take ~100 µs a round trip; allow ten times that plus start-up
    Duration::from_millis(60_000 + plan.idle_ms + (plan.warmup + plan.samples) / 5)
}

/// The directory of row `label` under `tmp`, created, and its histogram file's path.
pub(crate) fn row_dir(tmp: &Path, label: &str) -> Result<(PathBuf, PathBuf), BenchError> {
    let dir = tmp.join(label);
    std::fs::create_dir_all(&dir).map_err(|source| BenchError::Io {
        what: format!("create {}", dir.display()),
        source,
    })?;
    let hist_path = dir.join("latency.bin");
    Ok((dir, hist_path))
}

/// Measures one row with `measure`, saying on stderr (with `opts.progress`) which row starts
/// and what it measured: the rows of one host and the cross-host rows alike.
pub(crate) fn progress(
    label: &str,
    opts: &Options,
    measure: impl FnOnce() -> Result<Row, BenchError>,
) -> Result<Row, BenchError> {
    if opts.progress {
        report::log_line!("qfleet bench: {label} …");
    }
    let row = measure()?;
    if opts.progress {
        report::log_line!(
            "qfleet bench: {label}: p50 {:.2} µs, p99.9 {:.2} µs, n = {}",
            row.p50_ns as f64 / 1e3,
            row.p999_ns as f64 / 1e3,
            row.count
        );
    }
    Ok(row)
}

fn run_row(label: &str, opts: &Options, l: &Launcher, tmp: &Path) -> Result<Row, BenchError> {
    let plan = opts.plan();
    // crossbeam's process pins its two threads itself: main to the first, pong to the second
    let (meas_cpu, peer_cpu) = match (opts.pin, label) {
        (false, _) => (None, None),
        (true, "crossbeam") => (Some("0,1"), None),
        (true, _) => (Some("0"), Some("1")),
    };
    let run_id = bus::unique_run_id(&format!("bench-{}", label.replace("-loop", "")));
    let (dir, hist_path) = row_dir(tmp, label)?;
    let timeout = row_timeout(&plan);
    let quiet_ms = plan.timeout_ms + plan.idle_ms + 5_000;
    let cells = crate::roles::fleet::task(&opts.map)?.grid.len() as u32;
    // bytes = the request's payload (the answer is a MergedHintBatch, 6176 bytes)
    let bytes = size_of::<QHintBatch>();
    let names = match label {
        "iox2-raw-spin" | "iox2-raw-event" => ["ping", "pong"],
        l if l.starts_with("loop-") => ["robots", "coordinator"],
        l if l.starts_with("uds-") => ["robot", "server"],
        _ => ["ping+pong threads", ""],
    };
    let (peer, measurer) = match label {
        "iox2-raw-spin" | "iox2-raw-event" => {
            let event = label.ends_with("event");
            let peer = spawn_on(
                l,
                &RoleSpec::RawPong {
                    run_id: run_id.clone(),
                    event,
                    timeout_ms: quiet_ms,
                },
                peer_cpu,
            )?;
            let m = spawn_on(
                l,
                &RoleSpec::RawPing {
                    run_id: run_id.clone(),
                    event,
                    plan,
                    peer_pid: peer.id(),
                    hist_path: hist_path.clone(),
                },
                meas_cpu,
            )?;
            (Some(peer), m)
        }
        "loop-spin" | "loop-event" | "loop-hybrid" => {
            let wait = match label {
                "loop-spin" => WaitStrategy::Spin,
                "loop-event" => WaitStrategy::Event,
                _ => WaitStrategy::Hybrid,
            };
            let peer = spawn_on(
                l,
                &RoleSpec::Coordinator {
                    run_id: run_id.clone(),
                    robots: 2,
                    wait,
                    spin_us: contract::spin_us_for(opts.spin_us, 0),
                    map: opts.map.clone(),
                    out: dir.join("coordinator"),
                    timeout_s: quiet_ms as f64 / 1e3,
                },
                peer_cpu,
            )?;
            let m = spawn_on(
                l,
                &RoleSpec::LoopRobots {
                    run_id: run_id.clone(),
                    map: opts.map.clone(),
                    notify: wait != WaitStrategy::Spin,
                    plan,
                    peer_pid: peer.id(),
                    hist_path: hist_path.clone(),
                },
                meas_cpu,
            )?;
            (Some(peer), m)
        }
        "uds-loop-blocking" | "uds-loop-spin" => {
            let spin = label.ends_with("spin");
            let path = dir.join("loop.sock");
            let peer = spawn_on(
                l,
                &RoleSpec::UdsServer {
                    path: path.clone(),
                    spin,
                    cells,
                    timeout_ms: quiet_ms,
                },
                peer_cpu,
            )?;
            let m = spawn_on(
                l,
                &RoleSpec::UdsClient {
                    path,
                    spin,
                    cells,
                    plan,
                    peer_pid: peer.id(),
                    hist_path: hist_path.clone(),
                },
                meas_cpu,
            )?;
            (Some(peer), m)
        }
        _ => {
            let m = spawn_on(
                l,
                &RoleSpec::Crossbeam {
                    plan,
                    hist_path: hist_path.clone(),
                },
                meas_cpu,
            )?;
            (None, m)
        }
    };
    let measured = measurer.wait(timeout);
    let peer_report = peer.map(|p| p.wait(Duration::from_secs(60)));
    let clean = check_clean(label, &run_id);
    let m = measured?;
    if let Some(p) = peer_report {
        p?;
    }
    clean?;
    let hist = read_binary(&hist_path)?;
    Ok(Row::of_pair(label, bytes, hist, &m, names))
}

fn scale_point(n: u32, batch: u32, opts: &Options, l: &Launcher, tmp: &Path) -> ScaleRow {
    let mut row = ScaleRow {
        robots: n,
        batch,
        ..ScaleRow::default()
    };
    match scale_point_inner(n, batch, opts, l, tmp, &mut row) {
        Ok(()) => row.completed = true,
        Err(e) => row.error = Some(e.to_string()),
    }
    row
}

fn scale_point_inner(
    n: u32,
    batch: u32,
    opts: &Options,
    l: &Launcher,
    tmp: &Path,
    row: &mut ScaleRow,
) -> Result<(), BenchError> {
    let run_id = bus::unique_run_id(&format!("scale-{n}x{batch}"));
    let dir = tmp.join(format!("scale-{n}x{batch}"));
    std::fs::create_dir_all(&dir).map_err(|source| BenchError::Io {
        what: format!("create {}", dir.display()),
        source,
    })?;
    let timeout_ms = 60_000;
    let coord = spawn(
        l,
        &RoleSpec::Coordinator {
            run_id: run_id.clone(),
            robots: n,
            wait: WaitStrategy::Hybrid,
            spin_us: contract::spin_us_for(opts.spin_us, 0),
            map: opts.scale_map.clone(),
            out: dir.join("coordinator"),
            timeout_s: timeout_ms as f64 / 1e3,
        },
    )?;
    let mut robots = Vec::new();
    for id in 0..n {
        robots.push(spawn(
            l,
            &RoleSpec::ScaleRobot {
                run_id: run_id.clone(),
                map: opts.scale_map.clone(),
                robot_id: id,
                robots: n,
                batch,
                duration_ms: opts.scale_ms,
                in_flight: opts.scale_in_flight,
                notify_gap_us: opts.scale_notify_gap_us,
                timeout_ms,
                peer_pid: (id == 0).then(|| coord.id()),
                hist_path: dir.join(format!("robot-{id}.bin")),
            },
        )?);
    }
    let wait = Duration::from_millis(opts.scale_ms + 2 * timeout_ms);
    let mut reports = Vec::new();
    let mut first_err = None;
    for r in robots {
        match r.wait(wait) {
            Ok(rep) => reports.push(rep),
            Err(e) => {
                first_err.get_or_insert(e);
            }
        }
    }
    let coord_report = coord.wait(Duration::from_millis(2 * timeout_ms));
    let clean = check_clean(&format!("scale {n}×{batch}"), &run_id);
    if let Some(e) = first_err {
        return Err(e);
    }
    let c = coord_report?;
    clean?;
    let mut h: Histogram<u64> = new_hist();
    for id in 0..n {
        let x = read_binary(&dir.join(format!("robot-{id}.bin")))?;
        let _ = h.add(&x);
    }
    let wall_ns = reports.iter().map(|r| r.wall_ns).max().unwrap_or(0);
    let robots_cpu: u64 = reports.iter().map(|r| r.self_cpu_ns).sum();
    // the coordinator role process only waits: its child's CPU is the coordinator's (robot
    // 0's `peer_cpu_ns` is the waiting role process's, which said 0 %)
    let coord_cpu = c.self_cpu_ns;
    let sent: u64 = reports.iter().map(|r| r.updates_sent).sum();
    row.merged_per_s = c.merged_per_s;
    row.reports = c.reports;
    row.without_path = c.without_path;
    row.rejected = c.rejected;
    row.updates_sent = sent;
    row.updates_merged = c.samples;
    row.batches_lost = reports.iter().map(|r| r.batches_lost).sum();
    row.offered_per_s = if wall_ns > 0 {
        sent as f64 * 1e9 / wall_ns as f64
    } else {
        0.0
    };
    row.loop_count = h.len();
    if !h.is_empty() {
        row.loop_p50_ns = h.value_at_quantile(0.5);
        row.loop_p99_ns = h.value_at_quantile(0.99);
    }
    row.cpu_robots_pct = crate::cpu::pct(robots_cpu, wall_ns);
    row.cpu_coordinator_pct = crate::cpu::pct(coord_cpu, c.wall_ns.max(wall_ns));
    row.cpu_pct = row.cpu_robots_pct + row.cpu_coordinator_pct;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_command_line_chooses_the_sections() {
        let o = Options::chosen(true, false, false, vec![], false);
        assert!(o.rows && !o.scale && !o.cross_host && o.samples == 5_000);
        let o = Options::chosen(false, false, false, vec![], false);
        assert!(o.rows && o.scale);
        let o = Options::chosen(false, true, false, vec![], false);
        assert!(!o.rows && o.scale);
        let o = Options::chosen(false, false, false, vec!["uds-loop".into()], false);
        assert!(o.rows && !o.scale && o.only == ["uds-loop"]);
        assert!(!Options::chosen(false, false, true, vec![], false).scale);
        let o = Options::chosen(false, false, false, vec![], true);
        assert!(o.cross_host && !o.rows && !o.scale);
    }
}
