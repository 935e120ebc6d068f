//! The front door's IO: a TCP acceptor on the user's `--listen` address that asks the
//! [`Gate`] about every connection and relays each admitted one, byte for byte, to the hub's
//! Zenoh listener on loopback. Zenoh's handshake (its user–password authentication) still runs
//! end to end through the relay; the door reads no byte of it.
//!
//! One thread with a single-threaded Tokio runtime (Tokio is already in the build, through
//! Zenoh): one task per admitted connection, so what it holds is bounded by
//! [`Limits::global`]; a refused connection is closed at once with a reset, unread. A
//! connection that sends no byte within [`Limits::first_byte_within`] is closed by the door
//! and never reaches Zenoh. Both sockets of a relayed connection have `TCP_NODELAY`; bytes are
//! copied through one buffer per direction, made once per connection.
//!
//! A connection that opens with [`probe::MAGIC`] is a joining host's probe of its secret: the
//! door answers it itself ([`crate::probe`]) and never relays it. A refused proof, and a relayed
//! connection that Zenoh ended during its handshake ([`door::handshake_refused`]), count as
//! refused credentials per source, with one log line per source.
//!
//! With a direct listener ([`AdmitList`]), an accepted probe also opens it to the prober's
//! source, and the answer names its port ([`probe::direct_port`]): that host's session then
//! bypasses the relay. The relay stays for whatever comes to `--listen` as a Zenoh session
//! (a host whose direct connection failed, an older `qfleet join`, a bare Zenoh peer).

use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;

use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::BridgeError;
use crate::admit::AdmitList;
use crate::door::{self, DoorReport, Gate, Limits, Verdict};
use crate::probe::{self, Opening};
use crate::seal::{self, Secret};

/// How long the door waits for the hub's own listener to take a relayed connection (it is on
/// this host: anything slower means it is gone).
const UPSTREAM_WITHIN: Duration = Duration::from_secs(2);

/// After `accept` fails (e.g. out of file descriptors) the door waits this long before it
/// accepts again, instead of spinning.
const ACCEPT_BACKOFF: Duration = Duration::from_millis(20);

/// The running front door; [`FrontDoor::finish`] closes it and returns its report.
#[derive(Debug)]
pub struct FrontDoor {
    listen: SocketAddr,
    gate: Arc<Mutex<Gate>>,
    direct: Option<Arc<Mutex<AdmitList>>>,
    stop: Arc<Notify>,
    thread: Option<JoinHandle<()>>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn io_error(what: String) -> impl FnOnce(std::io::Error) -> BridgeError {
    move |e| BridgeError::Door { what, source: e }
}

impl FrontDoor {
    /// Binds `listen` (an error at once if it cannot) and relays what `limits` admit to
    /// `upstream`; probes are checked against `secret`, the run's, and an accepted one opens
    /// `direct` (when given) to its source.
    pub fn open(
        listen: SocketAddr,
        upstream: SocketAddr,
        limits: Limits,
        secret: Secret,
        direct: Option<AdmitList>,
    ) -> Result<FrontDoor, BridgeError> {
        let std_listener = std::net::TcpListener::bind(listen)
            .map_err(io_error(format!("listening on {listen}")))?;
        std_listener
            .set_nonblocking(true)
            .map_err(io_error(format!("listening on {listen}")))?;
        let bound = std_listener
            .local_addr()
            .map_err(io_error(format!("listening on {listen}")))?;
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_io()
            .enable_time()
            .build()
            .map_err(io_error("starting the front door's runtime".into()))?;
        let listener = {
            let _in = rt.enter();
            TcpListener::from_std(std_listener)
                .map_err(io_error(format!("listening on {listen}")))?
        };
        let gate = Arc::new(Mutex::new(Gate::new(limits)));
        let direct = direct.map(|d| Arc::new(Mutex::new(d)));
        let stop = Arc::new(Notify::new());
        let (g, s) = (Arc::clone(&gate), Arc::clone(&stop));
        let probes = Probes {
            secret,
            direct: direct.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("qfleet-door".into())
            .spawn(move || rt.block_on(accept(listener, upstream, g, s, Arc::new(probes))))
            .map_err(|e| BridgeError::Thread(e.to_string()))?;
        Ok(FrontDoor {
            listen: bound,
            gate,
            direct,
            stop,
            thread: Some(thread),
        })
    }

    /// The address it listens on (the port the system chose, if `listen` named port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.listen
    }

    /// What it did so far.
    pub fn report(&self) -> DoorReport {
        let mut r = lock(&self.gate).report(&self.listen.to_string());
        if let Some(d) = &self.direct {
            let d = lock(d);
            r.direct = d.address().to_string();
            r.direct_sources = d.admitted() as u64;
        }
        r
    }

    /// Stops accepting, closes every connection it relays and returns its report.
    pub fn finish(mut self) -> DoorReport {
        self.stop_and_join();
        self.report()
    }

    fn stop_and_join(&mut self) {
        self.stop.notify_one();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for FrontDoor {
    fn drop(&mut self) {
        self.stop_and_join();
    }
}

/// Accepts until `stop`: every connection goes to the gate; refused ones are reset unread,
/// admitted ones relayed by a task of their own.
async fn accept(
    listener: TcpListener,
    upstream: SocketAddr,
    gate: Arc<Mutex<Gate>>,
    stop: Arc<Notify>,
    probes: Arc<Probes>,
) {
    let first_byte = lock(&gate).limits().first_byte_within;
    let mut tasks = tokio::task::JoinSet::new();
    loop {
        tokio::select! {
            _ = stop.notified() => break,
            // finished relays are reaped as they end, so the set holds only live ones
            Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
            r = listener.accept() => match r {
                Ok((stream, peer)) => {
                    let src = peer.ip();
                    let verdict = lock(&gate).admit(src, Instant::now());
                    if verdict == Verdict::Admit {
                        let open = Open { gate: Arc::clone(&gate), src };
                        tasks.spawn(relay(stream, open, upstream, first_byte, Arc::clone(&probes)));
                    } else {
                        // a reset, not a FIN: nothing of it lingers on this host
                        let _ = stream.set_zero_linger();
                    }
                }
                Err(_) => tokio::time::sleep(ACCEPT_BACKOFF).await,
            },
        }
    }
    tasks.shutdown().await;
}

/// What the door answers probes with: the run's secret, and the direct listener it opens.
struct Probes {
    secret: Secret,
    direct: Option<Arc<Mutex<AdmitList>>>,
}

/// An admitted connection, counted open at the gate until dropped.
struct Open {
    gate: Arc<Mutex<Gate>>,
    src: IpAddr,
}

impl Drop for Open {
    fn drop(&mut self) {
        lock(&self.gate).closed(self.src);
    }
}

impl Open {
    /// Counts refused credentials of this connection's source; logs the first of a source.
    fn refused_credentials(&self, how: &str) {
        if lock(&self.gate).refused_credentials(self.src) {
            report::log_line!(
                "qfleet: front door: {} {how} (further refusals of it are only counted: \
                 bridge.json door.refused_credentials)",
                door::source_name(door::source_of(self.src))
            );
        }
    }
}

/// Peeks until the first bytes tell a probe from a Zenoh session; `None`: the connection
/// closed (or failed) first.
async fn opening(inbound: &TcpStream) -> Option<Opening> {
    let mut first = [0u8; probe::MAGIC.len()];
    loop {
        let n = inbound.peek(&mut first).await.ok().filter(|n| *n > 0)?;
        match probe::opening(&first[..n]) {
            Opening::Undecided => tokio::time::sleep(Duration::from_millis(5)).await,
            decided => return Some(decided),
        }
    }
}

/// Answers a probe: a nonce, then the verdict on the proof of the secret, and after an
/// accepted one the direct listener's port once it is open to `src`; `None`: the connection
/// failed or no randomness.
async fn answer_probe(inbound: &mut TcpStream, probes: &Probes, src: IpAddr) -> Option<bool> {
    let mut magic = [0u8; probe::MAGIC.len()];
    inbound.read_exact(&mut magic).await.ok()?;
    let mut nonce = [0u8; probe::NONCE_BYTES];
    seal::random(&mut nonce).ok()?;
    inbound.write_all(&nonce).await.ok()?;
    let mut proof = [0u8; probe::PROOF_BYTES];
    inbound.read_exact(&mut proof).await.ok()?;
    let ok = probes.secret.check_door_proof(&nonce, &proof);
    let mut answer = vec![if ok { probe::ACCEPTED } else { probe::REFUSED }];
    if ok && let Some(direct) = &probes.direct {
        // opened before the answer leaves, so the host's first SYN already gets through
        let mut d = lock(direct);
        if d.admit(src) {
            answer.extend_from_slice(&d.address().port().to_be_bytes());
        }
    }
    inbound.write_all(&answer).await.ok()?;
    Some(ok)
}

/// Waits for the first bytes: a probe is answered here, a Zenoh session is copied both ways
/// until either side ends; then both close.
async fn relay(
    mut inbound: TcpStream,
    open: Open,
    upstream: SocketAddr,
    first_byte: Duration,
    probes: Arc<Probes>,
) {
    let _ = inbound.set_nodelay(true);
    match tokio::time::timeout(first_byte, opening(&inbound)).await {
        Ok(Some(Opening::Probe)) => {
            let answered =
                tokio::time::timeout(first_byte, answer_probe(&mut inbound, &probes, open.src));
            if let Ok(Some(false)) = answered.await {
                open.refused_credentials("sent a probe with a wrong join secret");
            }
            return;
        }
        Ok(Some(_)) => {}
        Ok(None) => return, // closed (or failed) before a byte
        Err(_) => {
            lock(&open.gate).silent();
            let _ = inbound.set_zero_linger();
            return;
        }
    }
    let outbound = match tokio::time::timeout(UPSTREAM_WITHIN, TcpStream::connect(upstream)).await {
        Ok(Ok(s)) => s,
        _ => {
            lock(&open.gate).upstream_failed();
            return;
        }
    };
    let _ = outbound.set_nodelay(true);
    let relayed = Instant::now();
    let (mut in_r, mut in_w) = inbound.into_split();
    let (mut out_r, mut out_w) = outbound.into_split();
    // Zenoh never half-closes a link: when either direction ends, the connection is over, and
    // closing both frees the source's slot even if the other end stays silent
    let upstream_ended_first = tokio::select! {
        _ = tokio::io::copy(&mut in_r, &mut out_w) => false,
        _ = tokio::io::copy(&mut out_r, &mut in_w) => true,
    };
    if door::handshake_refused(upstream_ended_first, relayed.elapsed()) {
        open.refused_credentials(
            "was refused by Zenoh's password check (a wrong join secret, or none)",
        );
    }
    drop(open);
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{ErrorKind, Read, Write};
    use std::net::TcpStream as StdStream;

    /// An echo server on loopback standing in for the hub's listener.
    fn echo() -> SocketAddr {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap();
        std::thread::spawn(move || {
            for s in l.incoming().flatten() {
                std::thread::spawn(move || {
                    let mut s = s;
                    let mut b = [0u8; 4096];
                    while let Ok(n) = s.read(&mut b) {
                        if n == 0 || s.write_all(&b[..n]).is_err() {
                            break;
                        }
                    }
                });
            }
        });
        addr
    }

    fn run_secret() -> Secret {
        Secret::new("door-test", [7; 32])
    }

    #[test]
    fn a_probe_is_answered_by_the_door_and_a_wrong_secret_counted_once_per_source() {
        let door = FrontDoor::open(
            "127.0.0.1:0".parse().unwrap(),
            echo(),
            Limits::default(),
            run_secret(),
            None,
        )
        .unwrap();
        let at = door.local_addr();
        let within = Duration::from_secs(5);
        assert_eq!(
            probe::knock(at, &run_secret(), within),
            probe::Probe::Accepted
        );
        let wrong = Secret::new("door-test", [8; 32]);
        assert_eq!(probe::knock(at, &wrong, within), probe::Probe::Refused);
        assert_eq!(probe::knock(at, &wrong, within), probe::Probe::Refused);
        let r = door.finish();
        assert_eq!(r.refused_credentials, 2, "{r:?}");
        assert_eq!(r.refused_credentials_by_source.len(), 1, "{r:?}");
        assert_eq!(r.refused_credentials_by_source[0].source, "127.0.0.1");
        assert_eq!(r.refused_credentials_by_source[0].refused, 2);
        assert_eq!(r.refused(), 0, "a probe is no connection refusal: {r:?}");
    }

    fn closed_by_door(s: &mut StdStream) -> bool {
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        match s.read(&mut [0u8; 8]) {
            Ok(0) => true,
            Ok(_) => false,
            Err(e) => e.kind() != ErrorKind::WouldBlock && e.kind() != ErrorKind::TimedOut,
        }
    }

    #[test]
    fn admitted_bytes_cross_both_ways_and_the_rest_is_refused_or_dropped_silent() {
        let limits = Limits {
            per_source: 2,
            first_byte_within: Duration::from_millis(200),
            ..Limits::default()
        };
        let door = FrontDoor::open(
            "127.0.0.1:0".parse().unwrap(),
            echo(),
            limits,
            run_secret(),
            None,
        )
        .unwrap();
        let at = door.local_addr();
        // a client that speaks gets its bytes back through the relay
        let mut a = StdStream::connect(at).unwrap();
        a.write_all(b"hello zenoh").unwrap();
        let mut got = [0u8; 11];
        a.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        a.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"hello zenoh");
        // a silent one is closed by the door; a third one from the same source is refused
        let mut b = StdStream::connect(at).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        let mut c = StdStream::connect(at).unwrap();
        assert!(closed_by_door(&mut c));
        assert!(closed_by_door(&mut b));
        // the speaking client still works
        a.write_all(b"again").unwrap();
        let mut got = [0u8; 5];
        a.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"again");
        drop(a);
        let r = door.finish();
        assert_eq!(r.admitted, 2, "{r:?}");
        assert_eq!(r.silent, 1, "{r:?}");
        assert_eq!(r.refused_source_busy, 1, "{r:?}");
        assert_eq!(r.refused_by_source[0].source, "127.0.0.1");
    }

    #[test]
    fn a_port_in_use_is_an_error_at_once() {
        let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let e = FrontDoor::open(
            taken.local_addr().unwrap(),
            echo(),
            Limits::default(),
            run_secret(),
            None,
        );
        assert!(matches!(e, Err(BridgeError::Door { .. })), "{e:?}");
    }

    #[test]
    fn an_accepted_probe_opens_the_direct_listener_to_its_source_and_names_its_port() {
        let direct = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let direct_at = direct.local_addr().unwrap();
        let list = AdmitList::on(direct_at).unwrap();
        let door = FrontDoor::open(
            "127.0.0.1:0".parse().unwrap(),
            echo(),
            Limits::default(),
            run_secret(),
            Some(list),
        )
        .unwrap();
        let at = door.local_addr();
        let within = Duration::from_secs(5);
        let reaches = || {
            let s = StdStream::connect_timeout(&direct_at, Duration::from_millis(300));
            if s.is_ok() {
                let _ = direct.accept();
            }
            s.is_ok()
        };
        // a wrong secret opens nothing and is told no port
        let wrong = Secret::new("door-test", [8; 32]);
        assert_eq!(
            probe::knock_direct(at, &wrong, within),
            (probe::Probe::Refused, None)
        );
        assert!(!reaches(), "the direct listener is closed to a stranger");
        // the run's secret: the port, and the listener answers this source from then on
        assert_eq!(
            probe::knock_direct(at, &run_secret(), within),
            (probe::Probe::Accepted, Some(direct_at.port()))
        );
        assert!(reaches());
        let r = door.finish();
        assert_eq!(r.direct, direct_at.to_string(), "{r:?}");
        assert_eq!((r.direct_sources, r.refused_credentials), (1, 1), "{r:?}");
    }
}
