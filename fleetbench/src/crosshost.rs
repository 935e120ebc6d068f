//! The cross-host rows (`qfleet bench --cross-host`): latency between two "hosts" — two network
//! namespaces joined by a veth pair, each side with a private tmpfs on `/dev/shm` and
//! `/tmp/iceoryx2`, so the link is the only path — side by side in one run:
//!
//! - `xhost-tcp`: a blocking TCP ping-pong, 64 B each way (the link's own floor);
//! - `xhost-zenoh`, `xhost-zenoh-batched`, `xhost-zenoh-lowlatency`: a Zenoh pub/sub ping-pong,
//!   64 B, with the bridge's settings (express), without express, and with Zenoh's low-latency
//!   transport (the floor of anything built on Zenoh, and what moves it);
//! - `xhost-loop`: the real update loop with robots on one host and the coordinator on the
//!   other: robot 0's Q update → bridge → coordinator merge → bridge → applied at robot 1, timed
//!   on the robots' host (one clock); the hosts join with the run's secret and every frame is
//!   sealed, and host B's session goes to the hub's direct listener once the front door
//!   admitted it, as `qfleet run --listen` does by default;
//! - `xhost-loop-relay`: the same through the front door's relay (its mode before the direct
//!   listener: a second TCP hop per message);
//! - `xhost-loop-nodoor`: the same, sealed, without the hub's front door (its session listens
//!   on the endpoint itself: no per-source limits, no probe answers): what the door costs;
//! - `xhost-loop-plain`: the same with frames unsealed (`--insecure-plain`): what sealing costs.
//!
//! With two CPUs or more, every row runs its measuring thread (host B's ping or robot, which
//! busy-polls for the answer) alone on CPU 0 and every other thread of both hosts (Zenoh's,
//! the bridges', the coordinator's, the pong's) on CPU 1, as the local rows pin their two
//! sides: otherwise a thread woken on the poller's CPU waits for its time slice, which is not
//! what two computers do (BENCHMARKS.md "Across machines", "The poller on a CPU of its own").
//!
//! Needs root (namespaces); each row makes its own pair and removes it afterwards.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use bus::bus_schema::QHintBatch;
use contract::coordinator::WaitStrategy;

use crate::BenchError;
use crate::harness::{Launcher, Options, row_timeout, spawn_on};
use crate::report::Row;
use crate::spec::RoleSpec;

/// The cross-host rows, in the order they run.
pub const XHOST_LABELS: [&str; 8] = [
    "xhost-tcp",
    "xhost-zenoh",
    "xhost-zenoh-batched",
    "xhost-zenoh-lowlatency",
    "xhost-loop",
    "xhost-loop-relay",
    "xhost-loop-nodoor",
    "xhost-loop-plain",
];

const A_ADDR: &str = "10.77.0.1";
const MOUNTS: &str = "mount -t tmpfs qfleet-shm /dev/shm && mkdir -p /tmp/iceoryx2 && \
                      mount -t tmpfs qfleet-iox /tmp/iceoryx2 && exec \"$0\" \"$@\"";

fn sh(args: &[&str]) -> Result<(), BenchError> {
    let out = Command::new(args[0])
        .args(&args[1..])
        .output()
        .map_err(|source| BenchError::Io {
            what: format!("run {}", args[0]),
            source,
        })?;
    if out.status.success() {
        Ok(())
    } else {
        Err(BenchError::Input(format!(
            "`{}` failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        )))
    }
}

/// Two network namespaces joined by a veth pair (10.77.0.1 ↔ 10.77.0.2); removed on drop.
struct Pair {
    ns: [String; 2],
    veth: [String; 2],
}

impl Pair {
    fn new(n: usize) -> Result<Pair, BenchError> {
        // SAFETY: geteuid has no preconditions
        if unsafe { libc::geteuid() } != 0 {
            return Err(BenchError::Input(
                "the cross-host rows need root (network and mount namespaces)".into(),
            ));
        }
        let tag = format!("{}{n}", std::process::id() % 100_000);
        let p = Pair {
            ns: [format!("qba{tag}"), format!("qbb{tag}")],
            veth: [format!("qwa{tag}"), format!("qwb{tag}")],
        };
        let [na, nb] = &p.ns;
        let [va, vb] = &p.veth;
        sh(&["ip", "netns", "add", na])?;
        sh(&["ip", "netns", "add", nb])?;
        sh(&["ip", "link", "add", va, "type", "veth", "peer", "name", vb])?;
        sh(&["ip", "link", "set", va, "netns", na])?;
        sh(&["ip", "link", "set", vb, "netns", nb])?;
        for (ns, v, addr) in [(na, va, "10.77.0.1/24"), (nb, vb, "10.77.0.2/24")] {
            sh(&["ip", "-n", ns, "addr", "add", addr, "dev", v])?;
            sh(&["ip", "-n", ns, "link", "set", v, "up"])?;
            sh(&["ip", "-n", ns, "link", "set", "lo", "up"])?;
        }
        Ok(p)
    }

    /// `launcher` run inside namespace `i` with private shared memory.
    fn launcher(&self, i: usize, inner: &Launcher) -> Launcher {
        let mut args: Vec<String> = [
            "netns",
            "exec",
            &self.ns[i],
            "unshare",
            "-m",
            "--propagation",
            "private",
            "sh",
            "-c",
            MOUNTS,
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        args.push(inner.program.display().to_string());
        args.extend(inner.args.iter().cloned());
        Launcher {
            program: "ip".into(),
            args,
        }
    }
}

impl Drop for Pair {
    fn drop(&mut self) {
        for ns in &self.ns {
            let pids = Command::new("ip")
                .args(["netns", "pids", ns])
                .output()
                .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
                .unwrap_or_default();
            for pid in pids
                .split_whitespace()
                .filter_map(|p| p.parse::<i32>().ok())
            {
                // SAFETY: kill(2) on a process of our own namespace
                unsafe { libc::kill(pid, libc::SIGKILL) };
            }
        }
        for ns in &self.ns {
            let _ = sh(&["ip", "netns", "del", ns]);
        }
        for v in &self.veth {
            let _ = sh(&["ip", "link", "del", v]);
        }
    }
}

/// Runs the cross-host rows `opts.only` selects (all when empty).
pub fn rows(opts: &Options, launcher: &Launcher, tmp: &Path) -> Result<Vec<Row>, BenchError> {
    let mut rows = Vec::new();
    for (n, label) in XHOST_LABELS.iter().enumerate() {
        if !opts.only.is_empty() && !opts.only.iter().any(|o| o == label) {
            continue;
        }
        let row = crate::harness::progress(label, opts, || row(label, n, opts, launcher, tmp))?;
        rows.push(row);
    }
    Ok(rows)
}

fn row(label: &str, n: usize, opts: &Options, l: &Launcher, tmp: &Path) -> Result<Row, BenchError> {
    let pair = Pair::new(n)?;
    let (la, lb) = (pair.launcher(0, l), pair.launcher(1, l));
    let plan = opts.plan();
    let (dir, hist_path) = crate::harness::row_dir(tmp, label)?;
    // the run's join secret, in a file only root reads (never on a command line)
    let secret_file = dir.join("join.secret");
    let plain = label == "xhost-loop-plain";
    let door = match label {
        "xhost-loop-relay" => bridge::DoorMode::Relay,
        "xhost-loop-nodoor" => bridge::DoorMode::Off,
        _ => bridge::DoorMode::default(),
    };
    let secret =
        bridge::Secret::generate("bench-xhost").map_err(|e| BenchError::Input(e.to_string()))?;
    bridge::listen::write_secret(&dir, &secret).map_err(|e| match e {
        bridge::listen::ListenError::Write { source, .. } => BenchError::Io {
            what: format!("write {}", secret_file.display()),
            source,
        },
        e => BenchError::Input(e.to_string()),
    })?;
    let quiet_ms = plan.timeout_ms + plan.idle_ms + 5_000;
    let endpoint = format!("tcp/{A_ADDR}:7447");
    let bridge_spin_us = opts
        .bridge_spin_us
        .unwrap_or(bridge::SPIN_AFTER.as_micros() as u64);
    let (express, lowlatency) = match label {
        "xhost-zenoh-batched" => (false, false),
        "xhost-zenoh-lowlatency" => (true, true),
        _ => (true, false),
    };
    let (peer_spec, names, bytes): (RoleSpec, [&str; 2], usize) = match label {
        "xhost-tcp" => (
            RoleSpec::TcpEcho {
                addr: format!("{A_ADDR}:7448"),
                timeout_ms: quiet_ms,
            },
            ["tcp ping (host B)", "tcp echo (host A)"],
            crate::roles::xhost::PING_BYTES,
        ),
        "xhost-loop" | "xhost-loop-relay" | "xhost-loop-nodoor" | "xhost-loop-plain" => (
            RoleSpec::BridgedCoordinator {
                inner: Box::new(RoleSpec::Coordinator {
                    run_id: bus::unique_run_id("bench-xhost"),
                    robots: 2,
                    wait: WaitStrategy::Hybrid,
                    spin_us: contract::spin_us_for(opts.spin_us, 2),
                    map: opts.map.clone(),
                    out: dir.join("coordinator"),
                    timeout_s: quiet_ms as f64 / 1e3,
                }),
                listen: endpoint.clone(),
                express,
                lowlatency,
                bridge_spin_us,
                secret_file: secret_file.clone(),
                plain,
                door,
            },
            ["robots + bridge (host B)", "coordinator + bridge (host A)"],
            size_of::<QHintBatch>(),
        ),
        _ => (
            RoleSpec::ZenohPong {
                listen: endpoint.clone(),
                express,
                lowlatency,
                timeout_ms: quiet_ms,
            },
            ["zenoh ping (host B)", "zenoh pong (host A)"],
            crate::roles::xhost::PING_BYTES,
        ),
    };
    // with two CPUs or more: the measuring thread (it busy-polls) on CPU 0, every other thread
    // of both hosts on CPU 1, so none queues behind it (`cpu::keep_apart`)
    let (m_cpus, peer_cpus) = if opts.pin {
        (Some("0,1"), Some("1"))
    } else {
        (None, None)
    };
    let peer = spawn_on(&la, &peer_spec, peer_cpus)?;
    let m_spec = match &peer_spec {
        RoleSpec::TcpEcho { addr, .. } => RoleSpec::TcpPing {
            addr: addr.clone(),
            plan,
            peer_pid: peer.id(),
            hist_path: hist_path.clone(),
        },
        RoleSpec::BridgedCoordinator { inner, .. } => {
            let RoleSpec::Coordinator { run_id, .. } = inner.as_ref() else {
                return Err(BenchError::Spec("bridged coordinator".into()));
            };
            RoleSpec::BridgedRobots {
                inner: Box::new(RoleSpec::LoopRobots {
                    run_id: run_id.clone(),
                    map: opts.map.clone(),
                    notify: true,
                    plan,
                    peer_pid: peer.id(),
                    hist_path: hist_path.clone(),
                }),
                endpoint: endpoint.clone(),
                express,
                lowlatency,
                bridge_spin_us,
                secret_file: secret_file.clone(),
                plain,
            }
        }
        _ => RoleSpec::ZenohPing {
            endpoint: endpoint.clone(),
            express,
            lowlatency,
            plan,
            peer_pid: peer.id(),
            hist_path: hist_path.clone(),
        },
    };
    let measurer = spawn_on(&lb, &m_spec, m_cpus)?;
    let m = measurer.wait(row_timeout(&plan));
    let p = peer.wait(Duration::from_secs(60));
    let m = m?;
    p?;
    drop(pair);
    let hist = ::report::hist::read_binary(&hist_path)?;
    Ok(Row::of_pair(label, bytes, hist, &m, names))
}
