//! Roles of the cross-host rows (`qfleet bench --cross-host`): the plain floors of the link —
//! a blocking TCP ping-pong and a Zenoh pub/sub ping-pong, 64 bytes each way — and the real
//! update loop with the `bridge` crate between the coordinator's host and the robots' host.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use ::report::hist::new_hist;
use bridge::{JoinRequest, Tuning};
use bus::monotonic_ns;
use zenoh::Wait;
use zenoh::handlers::FifoChannel;

use super::{Deadline, Window, record_since, window_ns};
use crate::BenchError;
use crate::spec::{ChildReport, Plan, RoleSpec};

/// Bytes each way in the floor rows.
pub const PING_BYTES: usize = 64;

fn io(what: &str) -> impl Fn(std::io::Error) -> BenchError + '_ {
    move |source| BenchError::Io {
        what: what.to_string(),
        source,
    }
}

fn zerr(what: &str) -> impl Fn(zenoh::Error) -> BenchError + '_ {
    move |e| BenchError::Input(format!("zenoh: {what}: {e}"))
}

/// TCP echo: accepts one connection and answers every 64-byte message until it closes.
pub fn tcp_echo(addr: &str, timeout: Duration) -> Result<ChildReport, BenchError> {
    let listener = TcpListener::bind(addr).map_err(io("bind the TCP echo"))?;
    listener
        .set_nonblocking(true)
        .map_err(io("set non-blocking"))?;
    let until = Instant::now() + timeout;
    let mut conn = loop {
        match listener.accept() {
            Ok((c, _)) => break c,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock && Instant::now() < until => {
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => return Err(io("accept the TCP ping")(e)),
        }
    };
    conn.set_nonblocking(false).map_err(io("set blocking"))?;
    conn.set_nodelay(true).map_err(io("TCP_NODELAY"))?;
    let mut buf = [0u8; PING_BYTES];
    while conn.read_exact(&mut buf).is_ok() {
        conn.write_all(&buf).map_err(io("TCP echo write"))?;
    }
    Ok(ChildReport::default())
}

/// TCP ping: blocking round trips of 64 bytes.
pub fn tcp_ping(
    addr: &str,
    plan: &Plan,
    peer_pid: u32,
    hist_path: &Path,
) -> Result<ChildReport, BenchError> {
    let timeout = Duration::from_millis(plan.timeout_ms);
    let hs = Deadline::new(timeout, "the TCP echo to listen", Some(peer_pid));
    let mut conn = loop {
        match TcpStream::connect(addr) {
            Ok(c) => break c,
            Err(_) => {
                hs.check()?;
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    };
    conn.set_nodelay(true).map_err(io("TCP_NODELAY"))?;
    let mut buf = [7u8; PING_BYTES];
    let mut h = new_hist();
    let mut window = None;
    let mut i = 0;
    while plan.more(i, || window_ns(&window)) {
        if i == plan.warmup {
            // helper threads (Zenoh's) away from this busy-polling one, if the harness says
            crate::cpu::keep_apart();
            window = Some(Window::start(Some(peer_pid)));
        }
        let t0 = monotonic_ns();
        conn.write_all(&buf).map_err(io("TCP ping write"))?;
        conn.read_exact(&mut buf).map_err(io("TCP ping read"))?;
        record_since(&mut h, t0, i >= plan.warmup);
        i += 1;
    }
    super::finish(&h, window.as_ref(), peer_pid, plan.idle_ms, hist_path)
}

const PING_KEY: &str = "qfleet/bench/ping";

/// The floor's sessions authenticate as a run's do (a fixed bench secret: the handshake is
/// the same, and it costs nothing per message).
fn floor_auth() -> bridge::link::SessionAuth {
    bridge::link::SessionAuth::of(&bridge::Secret::new("bench-floor", [7; 32]))
}
const PONG_KEY: &str = "qfleet/bench/pong";

/// Zenoh pong: listens on `listen`, answers every ping on the pong key; an empty message ends.
pub fn zenoh_pong(
    listen: &str,
    tuning: Tuning,
    timeout: Duration,
) -> Result<ChildReport, BenchError> {
    let session = bridge::link::listen(listen, tuning, &floor_auth())
        .map_err(|e| BenchError::Input(e.to_string()))?;
    let publisher = bridge::link::publisher(&session, PONG_KEY.into(), tuning)
        .map_err(|e| BenchError::Input(e.to_string()))?;
    let sub = session
        .declare_subscriber(PING_KEY)
        .with(FifoChannel::new(1024))
        .wait()
        .map_err(zerr("subscribe to pings"))?;
    loop {
        match sub.recv_timeout(timeout) {
            Ok(Some(s)) => {
                let p = s.payload().to_bytes();
                if p.is_empty() {
                    break;
                }
                publisher.put(p.to_vec()).wait().map_err(zerr("pong"))?;
            }
            _ => return Err(BenchError::Input(format!("no ping within {timeout:?}"))),
        }
    }
    let _ = session.close().wait();
    Ok(ChildReport::default())
}

/// Zenoh ping: connects to `endpoint`, publishes 64 bytes, waits for the pong (busy polling
/// the subscriber's channel, as the bridge loop does), repeats.
pub fn zenoh_ping(
    endpoint: &str,
    tuning: Tuning,
    plan: &Plan,
    peer_pid: u32,
    hist_path: &Path,
) -> Result<ChildReport, BenchError> {
    let timeout = Duration::from_millis(plan.timeout_ms);
    let session = bridge::link::connect(endpoint, timeout, tuning, &floor_auth())
        .map_err(|e| BenchError::Input(e.to_string()))?;
    let publisher = bridge::link::publisher(&session, PING_KEY.into(), tuning)
        .map_err(|e| BenchError::Input(e.to_string()))?;
    let sub = session
        .declare_subscriber(PONG_KEY)
        .with(FifoChannel::new(1024))
        .wait()
        .map_err(zerr("subscribe to pongs"))?;
    let mut msg = vec![7u8; PING_BYTES];
    // handshake: until the routes exist, pings vanish; resend until one comes back
    let hs = Deadline::new(timeout, "the Zenoh pong", Some(peer_pid));
    loop {
        publisher.put(msg.clone()).wait().map_err(zerr("ping"))?;
        if let Ok(Some(_)) = sub.recv_timeout(Duration::from_millis(50)) {
            break;
        }
        hs.check()?;
    }
    std::thread::sleep(Duration::from_millis(100));
    while let Ok(Some(_)) = sub.try_recv() {}
    let mut h = new_hist();
    let mut window = None;
    let mut deadline = Deadline::new(timeout, "a Zenoh pong", Some(peer_pid));
    let mut i: u64 = 0;
    while plan.more(i, || window_ns(&window)) {
        if i == plan.warmup {
            // helper threads (Zenoh's) away from this busy-polling one, if the harness says
            crate::cpu::keep_apart();
            window = Some(Window::start(Some(peer_pid)));
        }
        msg[..8].copy_from_slice(&i.to_le_bytes());
        let t0 = monotonic_ns();
        publisher.put(msg.clone()).wait().map_err(zerr("ping"))?;
        deadline.reset();
        loop {
            match sub.try_recv() {
                Ok(Some(s)) if s.payload().to_bytes().get(..8) == Some(&i.to_le_bytes()[..]) => {
                    break;
                }
                Ok(Some(_)) => {}
                _ => {
                    deadline.check()?;
                    std::hint::spin_loop();
                }
            }
        }
        record_since(&mut h, t0, i >= plan.warmup);
        i += 1;
    }
    let _ = publisher.put(Vec::<u8>::new()).wait();
    let r = super::finish(&h, window.as_ref(), peer_pid, plan.idle_ms, hist_path);
    let _ = session.close().wait();
    r
}

/// How a loop row's hosts authenticate: the run's secret (read from a file both hosts are
/// given, never from the command line) and whether frames travel unsealed.
pub struct Auth {
    /// The join secret.
    pub secret: bridge::Secret,
    /// `--insecure-plain`.
    pub plain: bool,
}

impl Auth {
    /// Reads the secret from `file`.
    pub fn read(file: &std::path::Path, plain: bool) -> Result<Auth, BenchError> {
        let text = std::fs::read_to_string(file).map_err(io("read the join secret"))?;
        let secret = bridge::Secret::parse(&text).map_err(|e| BenchError::Input(e.to_string()))?;
        Ok(Auth { secret, plain })
    }
}

/// The coordinator of a loop row with a hub listening on `listen` for the robots' host.
pub fn bridged_coordinator(
    inner: &RoleSpec,
    listen: &str,
    tuning: Tuning,
    auth: &Auth,
    door_mode: bridge::DoorMode,
) -> Result<ChildReport, BenchError> {
    let RoleSpec::Coordinator { run_id, robots, .. } = inner else {
        return Err(BenchError::Spec("not a coordinator spec".into()));
    };
    let plan = bridge::RemotePlan {
        run_id: run_id.clone(),
        robots_total: *robots,
        first_remote: 0,
        robot_args: Vec::new(),
        files: Default::default(),
        hint_buffer: 64,
        merged_buffer: bus::merged_buffer_for(*robots),
    };
    let hub = bridge::Hub::start(bridge::HubOptions {
        listen: listen.to_string(),
        plan,
        down_after: bridge::DEFAULT_DOWN_AFTER,
        deadline: bridge::DEFAULT_DEADLINE,
        tuning,
        start_within: bridge::DEFAULT_START_WITHIN,
        join_within: bridge::DEFAULT_JOIN_WITHIN,
        out: None,
        secret: auth.secret.clone(),
        plain: auth.plain,
        door: bridge::DoorLimits::default(),
        door_mode,
    })
    .map_err(|e| BenchError::Input(e.to_string()))?;
    let r = super::fleet::coordinator(inner);
    hub.finish().map_err(|e| BenchError::Input(e.to_string()))?;
    r
}

/// The loop's robots on the joining host: join `endpoint`, serve the bridge on a thread, and
/// measure the loop (robot 0's Q update → coordinator on the other host → applied at robot 1).
pub fn bridged_robots(
    inner: &RoleSpec,
    endpoint: &str,
    tuning: Tuning,
    auth: &Auth,
) -> Result<ChildReport, BenchError> {
    let RoleSpec::LoopRobots { plan, .. } = inner else {
        return Err(BenchError::Spec("not a loop-robots spec".into()));
    };
    let timeout = Duration::from_millis(plan.timeout_ms);
    let req = JoinRequest::new("bench-robots".into(), 2, 0);
    let joined = bridge::request(endpoint, &req, &auth.secret, timeout, tuning)
        .map_err(|e| BenchError::Input(e.to_string()))?;
    // which way the session went: the hub's direct listener, or its front door's relay
    report::log_line!("fleetbench: the robots' host joined via {}", joined.via);
    if joined.plan.plain != auth.plain {
        return Err(BenchError::Input(
            "the hub's link is not sealed as asked".into(),
        ));
    }
    let done = Arc::new(AtomicBool::new(false));
    let stop = Arc::new(AtomicBool::new(false));
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let serving = {
        let (done, stop) = (Arc::clone(&done), Arc::clone(&stop));
        std::thread::spawn(move || -> Result<(), String> {
            let j = bridge::Joiner::new(joined, "bench-robots", tuning).map_err(|e| e.to_string());
            let _ = ready_tx.send(j.as_ref().map(|_| ()).map_err(Clone::clone));
            let mut j = j?;
            // iceoryx2 ports belong to the thread that made them: serve here
            let r = j.serve(&stop, |_| done.load(Ordering::SeqCst));
            j.finish();
            r.map(drop).map_err(|e| e.to_string())
        })
    };
    ready_rx
        .recv()
        .map_err(|_| BenchError::Input("the joining bridge thread died".into()))?
        .map_err(BenchError::Input)?;
    let r = super::fleet::loop_robots(inner);
    done.store(true, Ordering::SeqCst);
    if r.is_err() {
        stop.store(true, Ordering::SeqCst);
    }
    let served = serving
        .join()
        .map_err(|_| BenchError::Input("the joining bridge thread panicked".into()))?;
    let r = r?;
    served.map_err(BenchError::Input)?;
    Ok(r)
}
