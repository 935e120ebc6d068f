//! The child processes of the harness. Each role runs in its own process (the `qfleet` binary
//! re-executed with a hidden `--role <json>` argument), measures or serves, and prints one
//! [`ChildReport`] line on stdout.

use std::path::Path;
use std::time::{Duration, Instant};

use ::report::hist;
use bus::monotonic_ns;
use hdrhistogram::Histogram;

use crate::BenchError;
use crate::spec::{ChildReport, REPORT_PREFIX, RoleSpec};

pub mod crossbeam_pp;
pub mod fleet;
pub mod raw;
pub mod uds;
pub mod xhost;

/// Runs the role described by `spec_json` (a serialized [`RoleSpec`]) in this process and
/// prints its report; what `qfleet bench --role …` calls.
pub fn role_main(spec_json: &str) -> Result<(), BenchError> {
    let spec: RoleSpec =
        serde_json::from_str(spec_json).map_err(|e| BenchError::Spec(e.to_string()))?;
    // iceoryx2 warns once per process that it read no config file (qfleet builds its config
    // in code); keep children quiet unless IOX2_LOG_LEVEL asks for more
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    if let Some(&cpu) = crate::cpu::assigned_cpus().first() {
        crate::cpu::pin_current_thread(cpu);
    }
    let report = match spec {
        RoleSpec::RawPong {
            run_id,
            event,
            timeout_ms,
        } => raw::pong(&run_id, event, Duration::from_millis(timeout_ms))?,
        RoleSpec::RawPing {
            run_id,
            event,
            plan,
            peer_pid,
            hist_path,
        } => raw::ping(&run_id, event, &plan, peer_pid, &hist_path)?,
        RoleSpec::Coordinator { .. } => fleet::coordinator(&spec)?,
        RoleSpec::LoopRobots { .. } => fleet::loop_robots(&spec)?,
        RoleSpec::ScaleRobot { .. } => fleet::scale_robot(&spec)?,
        RoleSpec::UdsServer {
            path,
            spin,
            cells,
            timeout_ms,
        } => uds::server(&path, spin, cells, Duration::from_millis(timeout_ms))?,
        RoleSpec::UdsClient {
            path,
            spin,
            cells,
            plan,
            peer_pid,
            hist_path,
        } => uds::client(&path, spin, cells, &plan, peer_pid, &hist_path)?,
        RoleSpec::Crossbeam { plan, hist_path } => crossbeam_pp::run(&plan, &hist_path)?,
        RoleSpec::TcpEcho { addr, timeout_ms } => {
            xhost::tcp_echo(&addr, Duration::from_millis(timeout_ms))?
        }
        RoleSpec::TcpPing {
            addr,
            plan,
            peer_pid,
            hist_path,
        } => xhost::tcp_ping(&addr, &plan, peer_pid, &hist_path)?,
        RoleSpec::ZenohPong {
            listen,
            express,
            lowlatency,
            timeout_ms,
        } => xhost::zenoh_pong(
            &listen,
            bridge::Tuning {
                express,
                lowlatency,
                ..bridge::Tuning::default()
            },
            Duration::from_millis(timeout_ms),
        )?,
        RoleSpec::ZenohPing {
            endpoint,
            express,
            lowlatency,
            plan,
            peer_pid,
            hist_path,
        } => xhost::zenoh_ping(
            &endpoint,
            bridge::Tuning {
                express,
                lowlatency,
                ..bridge::Tuning::default()
            },
            &plan,
            peer_pid,
            &hist_path,
        )?,
        RoleSpec::BridgedCoordinator {
            inner,
            listen,
            express,
            lowlatency,
            bridge_spin_us,
            secret_file,
            plain,
            door,
        } => xhost::bridged_coordinator(
            &inner,
            &listen,
            bridge::Tuning {
                express,
                lowlatency,
                spin: Duration::from_micros(bridge_spin_us),
            },
            &xhost::Auth::read(&secret_file, plain)?,
            door,
        )?,
        RoleSpec::BridgedRobots {
            inner,
            endpoint,
            express,
            lowlatency,
            bridge_spin_us,
            secret_file,
            plain,
        } => xhost::bridged_robots(
            &inner,
            &endpoint,
            bridge::Tuning {
                express,
                lowlatency,
                spin: Duration::from_micros(bridge_spin_us),
            },
            &xhost::Auth::read(&secret_file, plain)?,
        )?,
    };
    let line = serde_json::to_string(&report).map_err(|e| BenchError::Spec(e.to_string()))?;
    // the parent reads this line; one that left has nobody to tell
    use std::io::Write as _;
    let _ = writeln!(std::io::stdout().lock(), "{REPORT_PREFIX}{line}");
    Ok(())
}

/// The synthetic Q updates every loop uses: entries (cell, action) cycle over the first
/// `cells` cells (at most 64), and each visit alternates the value between 0.5 and 0.75, so
/// every update changes the fleet table and produces a merged hint.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Updates {
    entries: u64,
    offset: u64,
}

impl Updates {
    /// Updates over up to `limit` cells starting at cell `first` (wrapping inside `cells`).
    pub(crate) fn new(cells: u32, limit: u32, first: u32) -> Self {
        let used = cells.clamp(1, limit.max(1));
        Updates {
            entries: u64::from(used) * 4,
            offset: u64::from(first % cells.max(1)) * 4,
        }
    }

    /// The `i`-th update: (cell, action, q).
    #[inline]
    pub(crate) fn get(&self, i: u64, cells: u32) -> (u32, u8, f32) {
        let idx = (i % self.entries + self.offset) % (u64::from(cells.max(1)) * 4);
        let q = if (i / self.entries).is_multiple_of(2) {
            0.5
        } else {
            0.75
        };
        ((idx / 4) as u32, (idx % 4) as u8, q)
    }
}

/// Measurement-window bookkeeping shared by the measuring roles.
pub(crate) struct Window {
    t0: Instant,
    self0: u64,
    peer0: Option<u64>,
    peer: Option<u32>,
}

impl Window {
    /// Starts the window now.
    pub(crate) fn start(peer: Option<u32>) -> Self {
        Window {
            t0: Instant::now(),
            self0: crate::cpu::self_cpu_ns(),
            peer0: peer.and_then(crate::cpu::pid_cpu_ns),
            peer,
        }
    }

    /// Nanoseconds since the window started.
    #[inline]
    pub(crate) fn elapsed_ns(&self) -> u64 {
        self.t0.elapsed().as_nanos() as u64
    }

    /// Ends the window: fills wall time and CPU times into `r`.
    pub(crate) fn finish(&self, r: &mut ChildReport) {
        r.wall_ns = self.t0.elapsed().as_nanos() as u64;
        r.self_cpu_ns = crate::cpu::self_cpu_ns().saturating_sub(self.self0);
        r.peer_cpu_ns = match (self.peer0, self.peer.and_then(crate::cpu::pid_cpu_ns)) {
            (Some(a), Some(b)) => Some(b.saturating_sub(a)),
            _ => None,
        };
    }
}

/// Sleeps `idle_ms` and returns the CPU use of `peer` meanwhile (% of a core).
pub(crate) fn idle_peer_cpu(peer: u32, idle_ms: u64) -> Option<f64> {
    if idle_ms == 0 {
        return None;
    }
    let a = crate::cpu::pid_cpu_ns(peer)?;
    let t = Instant::now();
    std::thread::sleep(Duration::from_millis(idle_ms));
    let b = crate::cpu::pid_cpu_ns(peer)?;
    Some(crate::cpu::pct(
        b.saturating_sub(a),
        t.elapsed().as_nanos() as u64,
    ))
}

/// A deadline for one wait: how long a peer may stay silent before it counts as dead.
pub(crate) struct Deadline {
    until: Instant,
    timeout: Duration,
    what: &'static str,
    peer: Option<u32>,
}

impl Deadline {
    /// Starts a deadline of `timeout` for waiting on `what`.
    pub(crate) fn new(timeout: Duration, what: &'static str, peer: Option<u32>) -> Self {
        Deadline {
            until: Instant::now() + timeout,
            timeout,
            what,
            peer,
        }
    }

    /// Restarts the same deadline from now.
    #[inline]
    pub(crate) fn reset(&mut self) {
        self.until = Instant::now() + self.timeout;
    }

    /// Error if the deadline passed or the peer process is gone.
    pub(crate) fn check(&self) -> Result<(), BenchError> {
        let dead = self.peer.is_some_and(|p| !crate::cpu::pid_alive(p));
        if dead || Instant::now() >= self.until {
            return Err(BenchError::PeerTimeout {
                what: self.what.to_string(),
                timeout_ms: self.timeout.as_millis() as u64,
                died: dead,
            });
        }
        Ok(())
    }

    /// Remaining time (zero when passed).
    pub(crate) fn remaining(&self) -> Duration {
        self.until.saturating_duration_since(Instant::now())
    }
}

/// Records a round trip that started at `t0_ns` into `h`, or nowhere during warm-up.
#[inline]
pub(crate) fn record_since(h: &mut Histogram<u64>, t0_ns: u64, measuring: bool) {
    if measuring {
        hist::record(h, monotonic_ns().saturating_sub(t0_ns));
    }
}

/// Writes the histogram for the parent.
/// A measuring child's report once its loop ended: the sample count, the window's CPU figures,
/// the peer's CPU while idle (measured over `idle_ms`), and the histogram saved to `hist_path`.
pub(crate) fn finish(
    h: &Histogram<u64>,
    window: Option<&Window>,
    peer_pid: u32,
    idle_ms: u64,
    hist_path: &Path,
) -> Result<ChildReport, BenchError> {
    let mut r = ChildReport {
        samples: h.len(),
        ..ChildReport::default()
    };
    if let Some(w) = window {
        w.finish(&mut r);
    }
    r.peer_idle_cpu_pct = idle_peer_cpu(peer_pid, idle_ms);
    save(h, hist_path)?;
    Ok(r)
}

pub(crate) fn save(h: &Histogram<u64>, path: &Path) -> Result<(), BenchError> {
    Ok(hist::write_binary(h, path)?)
}

/// Nanoseconds the (optional) window has lasted; 0 before it started.
#[inline]
pub(crate) fn window_ns(w: &Option<Window>) -> u64 {
    w.as_ref().map_or(0, Window::elapsed_ns)
}
