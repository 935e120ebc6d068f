//! The Zenoh session and the settings that decide the link's latency floor.
//!
//! One peer-to-peer session per host: on the coordinator's host the session listens on an
//! ephemeral loopback port behind the front door, which owns the `--listen` address
//! ([`listen_address`], [`crate::relay::FrontDoor`]) and relays the connections it admits,
//! and on an ephemeral direct port of the `--listen` address that only hosts the door
//! admitted can reach ([`listen_behind_door`], [`crate::admit`]); a joining host probes
//! `--listen` and connects to the direct port it is told, or to `--listen`. Multicast scouting and gossip are off, so a bridge
//! talks only to the endpoint it was given (never to whatever else is on the network), and a
//! joining host does not listen at all. Zenoh's own reliability (TCP) carries frames while a
//! session lasts; what a broken session loses, [`crate::reliable`] resends.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, sync_channel};
use std::time::{Duration, Instant};

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
    /// How long a bridge loop keeps looking at both sides after a message moved, yielding its
    /// CPU, before it waits ([`SPIN_AFTER`]; `qfleet bench --cross-host --bridge-spin-us`).
    pub spin: Duration,
}

impl Default for Tuning {
    /// Express on, low-latency transport off (it must match on both hosts and gives up
    /// priorities; see BENCHMARKS.md for what each moves), [`SPIN_AFTER`].
    fn default() -> Self {
        Tuning {
            express: true,
            lowlatency: false,
            spin: SPIN_AFTER,
        }
    }
}

/// Zenoh's runtime threads as the bridge wants them, in the syntax of Zenoh's `ZENOH_RUNTIME`
/// environment variable: one receiving worker thread instead of Zenoh's two.
///
/// Measured on 2 vCPUs (`qfleet bench --cross-host`, BENCHMARKS.md "Across machines"): the
/// cross-host update loop's p50 67.5 / 70.7 µs against 82.5 / 99.1 µs with two in alternated runs,
/// its p99 133 / 141 µs against 300 / 699 µs (every two-thread run of that session: p50 70–99
/// µs); a second thread only competes with the bridge loops for the same two cores.
pub const RUNTIME_THREADS: &str = "(rx: (worker_threads: 1))";

/// Sets `ZENOH_RUNTIME` to [`RUNTIME_THREADS`] unless the user set it; Zenoh reads it once, when
/// its runtimes first start, so this must run before any Zenoh call.
///
/// # Safety
/// Changes the process environment: call it before the process has started any other thread
/// (first thing in `main`), as [`std::env::set_var`] requires.
pub unsafe fn prefer_runtime_threads() {
    if std::env::var_os("ZENOH_RUNTIME").is_none() {
        // SAFETY: the caller guarantees that no other thread exists yet
        unsafe { std::env::set_var("ZENOH_RUNTIME", RUNTIME_THREADS) };
    }
}

/// Zenoh's user–password authentication for the run's sessions (issue 27): the hub's session
/// accepts only a peer that answers its nonce with an HMAC of the password
/// [`Secret::session_password`](crate::seal::Secret::session_password) derives from the join
/// secret, so a stranger's TCP connection is closed at Zenoh's handshake: it never gets a
/// session to subscribe, query or publish on, and cannot hold one of the session slots.
/// Before that, every connection passes the hub's front door ([`crate::relay::FrontDoor`]):
/// per-source limits, and a connection silent for a second never reaches Zenoh.
#[derive(Clone)]
pub struct SessionAuth {
    password: String,
}

impl std::fmt::Debug for SessionAuth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SessionAuth(<hidden>)")
    }
}

/// The user name both hosts give Zenoh (the password is what counts).
const SESSION_USER: &str = "qfleet";

impl SessionAuth {
    /// The authentication of the run `secret` is for.
    pub fn of(secret: &crate::seal::Secret) -> Self {
        SessionAuth {
            password: secret.session_password(),
        }
    }

    /// Sets the credentials this session presents; a listening one also gets the dictionary
    /// file it checks peers against (Zenoh reads it when the session opens: the caller removes
    /// it right after).
    fn apply(&self, c: &mut zenoh::Config, dictionary: Option<&Path>) -> Result<(), BridgeError> {
        let mut set = |k: &str, v: String| {
            c.insert_json5(k, &v).map_err(|e| BridgeError::Zenoh {
                what: format!("setting {k}"),
                detail: crate::zenoh_text(&e),
            })
        };
        set("transport/auth/usrpwd/user", json_str(SESSION_USER))?;
        set("transport/auth/usrpwd/password", json_str(&self.password))?;
        if let Some(d) = dictionary {
            set(
                "transport/auth/usrpwd/dictionary_file",
                json_str(&d.display().to_string()),
            )?;
        }
        Ok(())
    }
}

fn json_str(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_default()
}

/// The listener's dictionary (`user:password`, one line) in a file only this user can read,
/// removed when dropped.
struct Dictionary(PathBuf);

impl Dictionary {
    fn write(auth: &SessionAuth) -> Result<Dictionary, BridgeError> {
        use std::io::Write;
        use std::os::unix::fs::OpenOptionsExt;
        let mut nonce = [0u8; 8];
        crate::seal::random(&mut nonce).map_err(|e| BridgeError::Thread(e.to_string()))?;
        let path = std::env::temp_dir().join(format!(
            "qfleet-zenoh-auth-{}-{}",
            std::process::id(),
            crate::seal::hex(&nonce)
        ));
        let io = |e: std::io::Error| BridgeError::Zenoh {
            what: format!("writing the session dictionary {}", path.display()),
            detail: e.to_string(),
        };
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(&path)
            .map_err(io)?;
        let d = Dictionary(path.clone());
        writeln!(f, "{SESSION_USER}:{}", auth.password).map_err(io)?;
        Ok(d)
    }
}

impl Drop for Dictionary {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
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
    // nobody but the run's hosts has anything to ask this session (issue 27: the admin space
    // told a stranger who the peers are)
    set("adminspace/enabled", "false")?;
    set("adminspace/permissions/read", "false")?;
    // a connection that has not finished Zenoh's handshake within a second is dropped, and
    // enough may wait that a burst of half-open ones does not shut the real host out;
    // sessions are capped (a run has at most a few hundred hosts). On the hub these are the
    // second line: its front door limits connections per source first (`crate::door`)
    set("transport/unicast/accept_timeout", "1000")?;
    set("transport/unicast/accept_pending", "1024")?;
    set("transport/unicast/max_sessions", "512")?;
    set("transport/unicast/max_links", "1")?;
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

/// The socket address the front door binds for a `--listen` endpoint: `tcp/ADDR:PORT` (a
/// host name is resolved; the first address is taken), without Zenoh's `?`/`#` options, which
/// the door could not honour.
pub fn listen_address(endpoint: &str) -> Result<std::net::SocketAddr, BridgeError> {
    use std::net::ToSocketAddrs;
    let bad = |detail: String| BridgeError::Endpoint {
        endpoint: endpoint.to_string(),
        detail,
    };
    let ep = endpoint
        .parse::<zenoh::config::EndPoint>()
        .map_err(|e| bad(crate::zenoh_text(&e)))?;
    if ep.protocol().as_str() != "tcp" {
        return Err(bad("only tcp/ADDR:PORT can be listened on".into()));
    }
    if !ep.metadata().as_str().is_empty() || !ep.config().as_str().is_empty() {
        return Err(bad(
            "options after `?` or `#` are not supported on --listen".into(),
        ));
    }
    let address = ep.address();
    let mut found = address
        .as_str()
        .to_socket_addrs()
        .map_err(|e| bad(format!("resolving {}: {e}", address.as_str())))?;
    found
        .next()
        .ok_or_else(|| bad(format!("{} resolves to no address", address.as_str())))
}

/// A session for the front door to relay to: listening on a loopback port nobody else chose,
/// admitting only peers holding `auth`. Zenoh cannot say which port it bound, so a free one is
/// found first (bound and let go); if another process takes it in between, another is tried.
pub fn listen_loopback(
    tuning: Tuning,
    auth: &SessionAuth,
) -> Result<(zenoh::Session, std::net::SocketAddr), BridgeError> {
    listen_behind_door(tuning, auth, None).map(|(s, relay, _)| (s, relay))
}

/// A free TCP port on `ip` (bound and let go at once).
fn free_port(ip: std::net::IpAddr) -> Result<std::net::SocketAddr, BridgeError> {
    std::net::TcpListener::bind((ip, 0))
        .and_then(|l| l.local_addr())
        .map_err(|e| BridgeError::Door {
            what: format!("finding a free port on {ip} for the hub's session"),
            source: e,
        })
}

/// [`listen_loopback`], and with `direct` also on a free port of that address: the direct
/// listener, which the caller closes to everyone at once ([`crate::admit::AdmitList::on`])
/// and opens to the hosts that prove the join secret to the front door. Returns the session,
/// the loopback address the door relays to, and the direct listener's address.
pub fn listen_behind_door(
    tuning: Tuning,
    auth: &SessionAuth,
    direct: Option<std::net::IpAddr>,
) -> Result<(zenoh::Session, SocketAddr, Option<SocketAddr>), BridgeError> {
    const TRIES: usize = 8;
    let mut last = None;
    for _ in 0..TRIES {
        let relay = free_port(std::net::Ipv4Addr::LOCALHOST.into())?;
        let direct = direct.map(free_port).transpose()?;
        let mut endpoints = vec![format!("tcp/{relay}")];
        endpoints.extend(direct.map(|d| format!("tcp/{d}")));
        match listen_on(&endpoints, tuning, auth) {
            Ok(session) => return Ok((session, relay, direct)),
            Err(e) => last = Some(e),
        }
    }
    Err(last.unwrap_or_else(|| BridgeError::Link("no loopback port for the hub".into())))
}

/// A session listening on `endpoint` that admits only peers holding `auth`; fails at once if
/// it cannot bind. The hub listens through [`listen_behind_door`], behind its front door.
pub fn listen(
    endpoint: &str,
    tuning: Tuning,
    auth: &SessionAuth,
) -> Result<zenoh::Session, BridgeError> {
    listen_on(&[endpoint.to_string()], tuning, auth)
}

fn listen_on(
    endpoints: &[String],
    tuning: Tuning,
    auth: &SessionAuth,
) -> Result<zenoh::Session, BridgeError> {
    for e in endpoints {
        check_endpoint(e)?;
    }
    let named = endpoints.join(", ");
    let mut c = base_config(tuning)?;
    let dictionary = Dictionary::write(auth)?;
    auth.apply(&mut c, Some(&dictionary.0))?;
    let list = serde_json::to_string(endpoints).unwrap_or_default();
    c.insert_json5("listen/endpoints", &list)
        .map_err(|e| BridgeError::Endpoint {
            endpoint: named.clone(),
            detail: crate::zenoh_text(&e),
        })?;
    zenoh::open(c).wait().map_err(|e| BridgeError::Zenoh {
        what: format!("listening on {named}"),
        detail: crate::zenoh_text(&e),
    })
}

/// The endpoint of the hub's direct listener for a host that joins `endpoint` (`tcp/HOST:PORT`
/// without options): the same host, `port`. `None` for anything else (then the relay).
pub fn direct_endpoint(endpoint: &str, port: u16) -> Option<String> {
    let ep = endpoint.parse::<zenoh::config::EndPoint>().ok()?;
    if ep.protocol().as_str() != "tcp"
        || !ep.metadata().as_str().is_empty()
        || !ep.config().as_str().is_empty()
    {
        return None;
    }
    let (host, _) = ep.address().as_str().rsplit_once(':')?;
    if host.is_empty() {
        return None;
    }
    Some(format!("tcp/{host}:{port}"))
}

/// A session connected to `endpoint` (a joining host) presenting `auth`, giving up after
/// `timeout`.
pub fn connect(
    endpoint: &str,
    timeout: Duration,
    tuning: Tuning,
    auth: &SessionAuth,
) -> Result<zenoh::Session, BridgeError> {
    check_endpoint(endpoint)?;
    let mut c = base_config(tuning)?;
    auth.apply(&mut c, None)?;
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

/// A Zenoh handler (`.with(…)` of a subscriber or queryable): Zenoh's callback pushes each item
/// into a channel of `depth`, then wakes the bridge loop's `WaitSet` through `waker`; the loop
/// reads the returned receiver. While the channel is full the callback waits (as Zenoh's FIFO
/// handler does), or, when `lossy`, drops the item: join queries are lossy, so a flood of them
/// never holds up Zenoh's receiving thread and the joined hosts' frames keep moving (a real
/// host asks again).
pub fn waking<T: Send + 'static>(
    depth: usize,
    waker: bus::Waker,
    lossy: bool,
) -> (impl Fn(T) + Send + Sync + 'static, Receiver<T>) {
    let (tx, rx) = sync_channel(depth);
    let push = move |t: T| {
        let pushed = if lossy {
            tx.try_send(t).is_ok()
        } else {
            tx.send(t).is_ok()
        };
        if pushed {
            waker.wake();
        }
    };
    (push, rx)
}

/// Publishes one frame; a failure is returned for counting (the frame is resent if lossless).
/// Zenoh takes its payload owned: this is the one copy of a frame per publish.
pub fn put(publisher: &zenoh::pubsub::Publisher<'static>, frame: &[u8]) -> bool {
    publisher.put(frame.to_vec()).wait().is_ok()
}

impl crate::end::Sink for zenoh::pubsub::Publisher<'static> {
    fn put(&mut self, frame: &[u8]) -> bool {
        put(self, frame)
    }
}

/// After a message moved, a bridge loop keeps looking at both sides (yielding its CPU between
/// looks) this long before it waits.
pub const SPIN_AFTER: Duration = Duration::from_micros(100);

/// After the hub wrote something into the coordinator's inboxes, it looks for the answer every
/// [`REPLY_NAP`] for this long before it blocks: the coordinator sends merged hints and
/// discovery acks without notifying (so no `WaitSet` wakes on them), in answer to what it was
/// just given.
pub const REPLY_WINDOW: Duration = Duration::from_millis(2);

/// The hub's nap between looks inside [`REPLY_WINDOW`] (a sleep, not a `WaitSet` wait: those
/// wait in whole milliseconds).
pub const REPLY_NAP: Duration = Duration::from_micros(50);

/// While messages move, the longest a blocked bridge loop waits before it looks at its host's
/// bus again for messages whose sender did not notify (an iceoryx2 `WaitSet` waits in whole
/// milliseconds).
pub const POLL_WHILE_ACTIVE: Duration = Duration::from_millis(1);

/// How long after the last message the loop keeps that poll; then it blocks until an event
/// (a notified message, a frame, a join) or the next heartbeat.
pub const ACTIVE_FOR: Duration = Duration::from_secs(1);

/// How long a bridge loop may block now: until the next periodic work is `due`, shortened to
/// [`POLL_WHILE_ACTIVE`] within [`ACTIVE_FOR`] of the last message (`last_data`).
pub fn wait_for(now: Instant, due: Instant, last_data: Instant) -> Duration {
    let until = due.saturating_duration_since(now);
    if now.duration_since(last_data) < ACTIVE_FOR {
        until.min(POLL_WHILE_ACTIVE)
    } else {
        until
    }
}

/// What a bridge loop does after a pass over both sides: the idle decision the hub and the
/// joining side share, free of IO so it is tested as a specification ([`Pacing::after_pass`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Next {
    /// Something moved, or periodic work is due: pass again at once.
    Again,
    /// Idle for less than the spin time: yield the CPU, then pass again.
    Yield,
    /// Waiting for an answer that comes without a wakeup: sleep this long, then pass again.
    Nap(Duration),
    /// Block on the `WaitSet` for at most this long.
    Block(Duration),
}

/// The state behind [`Next`]: when the loop last moved anything, last moved a message, and until
/// when an un-notified answer is expected.
#[derive(Debug, Clone, Copy)]
pub struct Pacing {
    spin: Duration,
    last_busy: Instant,
    last_data: Instant,
    expect_until: Instant,
}

impl Pacing {
    /// A loop starting at `now` that spins `spin` after each busy pass and naps for expected
    /// answers ([`expect_reply`](Self::expect_reply)).
    pub fn new(now: Instant, spin: Duration) -> Self {
        Pacing {
            spin,
            last_busy: now,
            last_data: now.checked_sub(ACTIVE_FOR).unwrap_or(now),
            expect_until: now,
        }
    }

    /// Something was handed on at `now` whose answer comes without a wakeup: look for it
    /// every [`REPLY_NAP`] for [`REPLY_WINDOW`].
    pub fn expect_reply(&mut self, now: Instant) {
        self.expect_until = now + REPLY_WINDOW;
    }

    /// After a pass at `now` that handled frames or joins (`busy`) and/or moved messages
    /// (`data`), with the next periodic work `due`: what to do next.
    pub fn after_pass(&mut self, now: Instant, busy: bool, data: bool, due: Instant) -> Next {
        if data {
            self.last_data = now;
        }
        if busy || data {
            self.last_busy = now;
            return Next::Again;
        }
        if now.duration_since(self.last_busy) < self.spin {
            return Next::Yield;
        }
        if now < self.expect_until {
            return Next::Nap(REPLY_NAP);
        }
        match wait_for(now, due, self.last_data) {
            t if t.is_zero() => Next::Again,
            t => Next::Block(t),
        }
    }
}

/// Carries out the part of `next` that needs no `WaitSet`: yields or naps, and returns how long
/// to block for when `next` says so (`None`: pass again).
pub fn rest(next: Next) -> Option<Duration> {
    match next {
        Next::Again => None,
        Next::Yield => {
            std::thread::yield_now();
            None
        }
        Next::Nap(d) => {
            std::thread::sleep(d);
            None
        }
        Next::Block(t) => Some(t),
    }
}

/// Makes this thread's timed waits end on time: Linux lets a sleeping thread's wakeup slip by
/// its timer slack (50 µs by default), which the hub's [`REPLY_NAP`]s would pay on every look.
/// Best effort: without it the waits are only later.
pub fn tighten_timer_slack() {
    // SAFETY: prctl(PR_SET_TIMERSLACK) changes only the calling thread's timer slack
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_direct_endpoint_is_the_joined_host_on_the_direct_port() {
        assert_eq!(
            direct_endpoint("tcp/10.77.0.1:7447", 40001).as_deref(),
            Some("tcp/10.77.0.1:40001")
        );
        assert_eq!(
            direct_endpoint("tcp/hub.example:7447", 40001).as_deref(),
            Some("tcp/hub.example:40001")
        );
        assert_eq!(
            direct_endpoint("tcp/[fd00::1]:7447", 40001).as_deref(),
            Some("tcp/[fd00::1]:40001")
        );
        // options the direct endpoint could not honour the same way: the relay
        assert_eq!(
            direct_endpoint("tcp/10.77.0.1:7447#bind=10.77.0.2:0", 1),
            None
        );
        assert_eq!(direct_endpoint("udp/10.77.0.1:7447", 1), None);
        assert_eq!(direct_endpoint("nonsense", 1), None);
    }

    #[test]
    fn an_idle_loop_spins_then_naps_for_an_expected_answer_then_blocks() {
        let t0 = Instant::now();
        let us = Duration::from_micros;
        let beat = t0 + Duration::from_millis(40);
        let mut p = Pacing::new(t0, us(100));
        // anything moved: pass again at once
        assert_eq!(p.after_pass(t0, true, false, beat), Next::Again);
        assert_eq!(p.after_pass(t0, false, true, beat), Next::Again);
        p.expect_reply(t0);
        // idle, within the spin time: yield
        assert_eq!(p.after_pass(t0 + us(50), false, false, beat), Next::Yield);
        // past the spin time, inside the reply window: nap
        assert_eq!(
            p.after_pass(t0 + us(500), false, false, beat),
            Next::Nap(REPLY_NAP)
        );
        // past the reply window, a message moved within ACTIVE_FOR: block a millisecond
        let later = t0 + REPLY_WINDOW + us(1);
        assert_eq!(
            p.after_pass(later, false, false, beat),
            Next::Block(POLL_WHILE_ACTIVE)
        );
        // quiet past ACTIVE_FOR: block until the periodic work; once it is due: pass again
        let quiet = t0 + ACTIVE_FOR + us(1);
        let beat = quiet + Duration::from_millis(40);
        assert_eq!(
            p.after_pass(quiet, false, false, beat),
            Next::Block(Duration::from_millis(40))
        );
        assert_eq!(p.after_pass(beat, false, false, beat), Next::Again);
    }

    #[test]
    fn a_loop_expecting_no_answer_blocks_and_a_fresh_one_blocks_to_the_heartbeat() {
        let t0 = Instant::now();
        let mut p = Pacing::new(t0, Duration::ZERO);
        // a message moved, but nothing was handed on that answers without a wakeup
        p.after_pass(t0, false, true, t0);
        let now = t0 + Duration::from_micros(10);
        let beat = now + Duration::from_millis(40);
        assert_eq!(
            p.after_pass(now, false, false, beat),
            Next::Block(POLL_WHILE_ACTIVE)
        );
        // a fresh loop has moved nothing: it blocks to the heartbeat, not to the 1 ms poll
        let mut fresh = Pacing::new(now, Duration::ZERO);
        assert_eq!(
            fresh.after_pass(now, false, false, beat),
            Next::Block(Duration::from_millis(40))
        );
    }

    #[test]
    fn a_blocked_loop_polls_each_millisecond_while_messages_move_and_sleeps_to_the_heartbeat_after()
    {
        let now = Instant::now();
        let beat = now + Duration::from_millis(40);
        // messages moved just now: the un-notified ones are looked for every millisecond
        assert_eq!(wait_for(now, beat, now), POLL_WHILE_ACTIVE);
        // quiet for longer than ACTIVE_FOR: only the heartbeat wakes it
        let quiet = now - ACTIVE_FOR;
        assert_eq!(wait_for(now, beat, quiet), Duration::from_millis(40));
        // work already due: no wait at all
        assert_eq!(wait_for(now, now, quiet), Duration::ZERO);
        assert_eq!(
            wait_for(now + Duration::from_millis(1), now, now),
            Duration::ZERO
        );
    }
}
