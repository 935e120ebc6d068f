//! A Foxglove WebSocket server (`foxglove.websocket.v1`) for a run, live or replayed: the
//! scene channels of [`crate::scene`] (map, robots, paths, markers, transform, per-robot
//! numbers, log) and the run's raw topics as JSON, to any number of clients (the Foxglove app,
//! a browser, another machine).
//!
//! Never slows the run: the reader hands each message over with a non-blocking send into a
//! bounded queue ([`Server::offer`]; a full queue drops the message for the server, counted);
//! a thread of its own, in the idle scheduling class, builds the scene and encodes JSON (raw
//! topics only while a client is subscribed to them); each client has a thread and a bounded
//! queue of its own, and a client that does not read loses messages (counted), never holds
//! anything else up. Late subscribers get the latest map, transform and entities at once.
//!
//! Protocol subset: `serverInfo`, `advertise`/`unadvertise` (a new run in an experiment
//! advertises its raw topics anew), client `subscribe`/`unsubscribe`, binary message data
//! (opcode 1, subscription id u32 LE, timestamp u64 LE ns, then the JSON message). No client
//! publishing, parameters or services.

use std::collections::{BTreeMap, HashMap};
use std::io::ErrorKind;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use bus_schema::names::Topic;
use planner::grid::{Cell, Grid};
use serde_json::{Value, json};
use tungstenite::handshake::server::{ErrorResponse, Request, Response};
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Message, WebSocket};

use crate::decode::{Owned, json_schema};
use crate::record::wall_ns;
use crate::scene::{Channel, Scene, SceneMsg};

/// The WebSocket subprotocol spoken.
pub const SUBPROTOCOL: &str = "foxglove.websocket.v1";
/// Where `--foxglove` listens when given no address.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";
/// Messages of the run waiting for the scene thread at most; more are dropped (counted).
pub const INPUT_QUEUE: usize = 16 * 1024;
/// Frames waiting for one client at most; more are dropped for that client (counted).
pub const CLIENT_QUEUE: usize = 2048;
/// Binary opcode of message data.
pub const OP_MESSAGE_DATA: u8 = 1;

/// Why the server could not start.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The address could not be bound (in use, not local, not allowed).
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A thread could not be started.
    #[error("starting the Foxglove server's {what} thread: {source}")]
    Thread {
        /// Which thread.
        what: &'static str,
        /// Why.
        #[source]
        source: std::io::Error,
    },
}

/// What a run's scene starts from (see [`Server::begin_run`]).
#[derive(Debug, Clone)]
pub struct RunStart {
    /// Run id (names the raw topics).
    pub run_id: String,
    /// Map name.
    pub map_name: String,
    /// The map.
    pub grid: Grid,
    /// The task's start cell.
    pub start: Cell,
    /// The task's goal cell.
    pub goal: Cell,
}

enum Input {
    Begin(Box<RunStart>, u64),
    Msg(u64, u64, Owned),
}

/// What the server did, for the launcher's closing line.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServeReport {
    /// Clients that connected.
    pub clients: u64,
    /// Messages sent to clients (each client's copy counted).
    pub sent: u64,
    /// Messages of the run the server itself dropped (its input queue was full).
    pub dropped_input: u64,
    /// Messages dropped for clients that did not read fast enough.
    pub dropped_slow: u64,
}

impl std::fmt::Display for ServeReport {
    /// The launcher's closing line: clients, messages sent, and dropped where.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "foxglove: {} client(s), {} messages sent, {} dropped for slow clients, {} dropped by \
             the server",
            self.clients, self.sent, self.dropped_slow, self.dropped_input
        )
    }
}

/// A running Foxglove WebSocket server (see the module doc).
pub struct Server {
    addr: SocketAddr,
    input: Mutex<Option<SyncSender<Input>>>,
    shared: Arc<Shared>,
    threads: Mutex<Vec<JoinHandle<()>>>,
}

impl std::fmt::Debug for Server {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Server").field("addr", &self.addr).finish()
    }
}

struct Shared {
    stop: AtomicBool,
    hub: Mutex<Hub>,
    clients: AtomicU64,
    sent: AtomicU64,
    dropped_input: AtomicU64,
    dropped_slow: AtomicU64,
}

impl Shared {
    fn hub(&self) -> MutexGuard<'_, Hub> {
        // a thread that panicked holding the lock left consistent data: maps and queues only
        self.hub.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// One advertised channel.
struct ChannelInfo {
    id: u32,
    topic: String,
    schema_name: String,
    schema: String,
    latched: bool,
}

enum Frame {
    Text(String),
    Data { sub: u32, ts: u64, data: Arc<[u8]> },
}

struct ClientSlot {
    id: u64,
    tx: SyncSender<Frame>,
    /// channel id → subscription id
    subs: HashMap<u32, u32>,
}

/// A latched message: its timestamp and bytes.
type Latched = (u64, Arc<[u8]>);

#[derive(Default)]
struct Hub {
    channels: Vec<ChannelInfo>,
    scene_ids: BTreeMap<Channel, u32>,
    raw_ids: HashMap<Topic, u32>,
    next_channel: u32,
    latched: BTreeMap<(u32, String), Latched>,
    clients: Vec<ClientSlot>,
    streams: Vec<(u64, TcpStream)>,
}

impl Hub {
    fn add_channel(
        &mut self,
        topic: String,
        schema_name: &str,
        schema: &Value,
        latched: bool,
    ) -> u32 {
        self.next_channel += 1;
        let id = self.next_channel;
        self.channels.push(ChannelInfo {
            id,
            topic,
            schema_name: schema_name.to_string(),
            schema: schema.to_string(),
            latched,
        });
        id
    }

    fn advertise_json(channels: &[&ChannelInfo]) -> String {
        let list: Vec<Value> = channels
            .iter()
            .map(|c| {
                json!({"id": c.id, "topic": c.topic, "encoding": "json", "schemaName": c.schema_name,
                       "schema": c.schema, "schemaEncoding": "jsonschema"})
            })
            .collect();
        json!({"op": "advertise", "channels": list}).to_string()
    }

    /// A new run: its raw topics replace the last run's, its scene replaces the latched one.
    fn begin_run(&mut self, run_id: &str, dropped: &AtomicU64) {
        let mut added = Vec::new();
        if self.scene_ids.is_empty() {
            for c in Channel::ALL {
                let id =
                    self.add_channel(c.topic().into(), c.schema_name(), &c.schema(), c.latched());
                self.scene_ids.insert(c, id);
                added.push(id);
            }
        }
        let old: Vec<u32> = self.raw_ids.values().copied().collect();
        self.channels.retain(|c| !old.contains(&c.id));
        self.raw_ids.clear();
        for t in Topic::ALL {
            let id = self.add_channel(
                t.service_name(run_id),
                t.type_name(),
                &json_schema(t),
                false,
            );
            self.raw_ids.insert(t, id);
            added.push(id);
        }
        self.latched.clear();
        let new: Vec<&ChannelInfo> = self
            .channels
            .iter()
            .filter(|c| added.contains(&c.id))
            .collect();
        let mut frames = Vec::new();
        if !old.is_empty() {
            frames.push(json!({"op": "unadvertise", "channelIds": old}).to_string());
        }
        frames.push(Self::advertise_json(&new));
        for c in &mut self.clients {
            c.subs.retain(|ch, _| !old.contains(ch));
            for f in &frames {
                if c.tx.try_send(Frame::Text(f.clone())).is_err() {
                    dropped.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }

    fn subscribed(&self, channel: u32) -> bool {
        self.clients.iter().any(|c| c.subs.contains_key(&channel))
    }

    fn publish(
        &mut self,
        channel: u32,
        key: Option<&str>,
        ts: u64,
        data: Arc<[u8]>,
        shared: &Shared,
    ) {
        let latched = self.channels.iter().any(|c| c.id == channel && c.latched);
        for c in &self.clients {
            if let Some(&sub) = c.subs.get(&channel) {
                match c.tx.try_send(Frame::Data {
                    sub,
                    ts,
                    data: Arc::clone(&data),
                }) {
                    Ok(()) => {}
                    Err(TrySendError::Full(_)) => {
                        shared.dropped_slow.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(TrySendError::Disconnected(_)) => {}
                }
            }
        }
        if latched && let Some(k) = key {
            self.latched.insert((channel, k.to_string()), (ts, data));
        }
    }
}

impl Server {
    /// Binds `addr` and starts serving (nothing is advertised until [`begin_run`](Self::begin_run)).
    /// A port in use or an address that is not this host's is an error here, before anything
    /// of a run starts.
    pub fn bind(addr: SocketAddr) -> Result<Arc<Self>, ServeError> {
        let listener =
            TcpListener::bind(addr).map_err(|source| ServeError::Bind { addr, source })?;
        let addr = listener
            .local_addr()
            .map_err(|source| ServeError::Bind { addr, source })?;
        listener
            .set_nonblocking(true)
            .map_err(|source| ServeError::Bind { addr, source })?;
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            hub: Mutex::new(Hub::default()),
            clients: AtomicU64::new(0),
            sent: AtomicU64::new(0),
            dropped_input: AtomicU64::new(0),
            dropped_slow: AtomicU64::new(0),
        });
        let (tx, rx) = sync_channel(INPUT_QUEUE);
        let s = Arc::clone(&shared);
        let scene = std::thread::Builder::new()
            .name("qfleet-foxglove".into())
            .spawn(move || scene_thread(&rx, &s))
            .map_err(|source| ServeError::Thread {
                what: "scene",
                source,
            })?;
        let s = Arc::clone(&shared);
        let accept = std::thread::Builder::new()
            .name("qfleet-foxglove-accept".into())
            .spawn(move || accept_thread(&listener, &s))
            .map_err(|source| ServeError::Thread {
                what: "accept",
                source,
            })?;
        Ok(Arc::new(Self {
            addr,
            input: Mutex::new(Some(tx)),
            shared,
            threads: Mutex::new(vec![scene, accept]),
        }))
    }

    /// The address it listens on (the port chosen, for port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        self.shared.hub().clients.len()
    }

    fn send(&self, i: Input) {
        let guard = self.input.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(tx) = guard.as_ref()
            && tx.try_send(i).is_err()
        {
            self.shared.dropped_input.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Starts the scene of a new run (log time `t_ns`, wall ns): advertises its raw topics and
    /// sends the map, transform and task markers.
    pub fn begin_run(&self, start: RunStart, t_ns: u64) {
        self.send(Input::Begin(Box::new(start), t_ns));
    }

    /// Hands one message of the run (logged at `t_ns` wall ns, received at `recv_ns`
    /// monotonic ns) to the server; never blocks: a full queue drops it, counted.
    pub fn offer(&self, t_ns: u64, recv_ns: u64, msg: Owned) {
        self.send(Input::Msg(t_ns, recv_ns, msg));
    }

    /// Hands one message to the server as [`offer`](Self::offer) does, but waits while its
    /// queue is full (a replay, which has no run to keep up with).
    pub fn offer_wait(&self, t_ns: u64, recv_ns: u64, msg: Owned) {
        let tx = self
            .input
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .as_ref()
            .cloned();
        if let Some(tx) = tx {
            let _ = tx.send(Input::Msg(t_ns, recv_ns, msg));
        }
    }

    /// What it did so far.
    pub fn counts(&self) -> ServeReport {
        ServeReport {
            clients: self.shared.clients.load(Ordering::Relaxed),
            sent: self.shared.sent.load(Ordering::Relaxed),
            dropped_input: self.shared.dropped_input.load(Ordering::Relaxed),
            dropped_slow: self.shared.dropped_slow.load(Ordering::Relaxed),
        }
    }

    /// Stops serving: the scene thread finishes what it was handed, every client is
    /// disconnected, every thread joined; what it did.
    pub fn shutdown(&self) -> ServeReport {
        // the scene thread drains its queue, then ends when the sender is gone
        drop(self.input.lock().unwrap_or_else(|p| p.into_inner()).take());
        let mut threads =
            std::mem::take(&mut *self.threads.lock().unwrap_or_else(|p| p.into_inner()));
        if !threads.is_empty() {
            let _ = threads.remove(0).join();
        }
        // give connected clients a moment to write out what is queued for them
        if !self.shared.hub().clients.is_empty() {
            std::thread::sleep(Duration::from_millis(300));
        }
        self.shared.stop.store(true, Ordering::SeqCst);
        for (_, s) in &self.shared.hub().streams {
            let _ = s.shutdown(std::net::Shutdown::Both);
        }
        for t in threads {
            let _ = t.join();
        }
        self.counts()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if !self.shared.stop.load(Ordering::SeqCst) {
            self.shutdown();
        }
    }
}

/// `ADDR:PORT` of `--foxglove` (a name such as `localhost:8765` is resolved to its first
/// address).
pub fn parse_addr(s: &str) -> Result<SocketAddr, String> {
    use std::net::ToSocketAddrs;
    if let Ok(a) = s.parse::<SocketAddr>() {
        return Ok(a);
    }
    s.to_socket_addrs()
        .map_err(|e| format!("{s:?} is not ADDR:PORT ({e})"))?
        .next()
        .ok_or_else(|| format!("{s:?} resolves to no address"))
}

/// Whether `addr` is a loopback address (anything else is reachable from other machines).
pub fn is_loopback(addr: &SocketAddr) -> bool {
    addr.ip().is_loopback()
}

fn scene_thread(rx: &Receiver<Input>, shared: &Shared) {
    crate::record::lower_priority();
    let mut scene: Option<Scene> = None;
    let mut out: Vec<SceneMsg> = Vec::new();
    loop {
        let input = match rx.recv_timeout(Duration::from_millis(50)) {
            Ok(i) => i,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => return,
        };
        match input {
            Input::Begin(s, t_ns) => {
                shared.hub().begin_run(&s.run_id, &shared.dropped_slow);
                let mut sc = Scene::new(&s.map_name, s.grid, s.start, s.goal);
                sc.start(t_ns, &mut out);
                scene = Some(sc);
                publish_scene(&mut out, t_ns, shared);
            }
            Input::Msg(t_ns, recv_ns, m) => {
                let Some(sc) = scene.as_mut() else { continue };
                let msg = m.as_msg();
                sc.apply(t_ns, recv_ns, msg, &mut out);
                let raw = {
                    let hub = shared.hub();
                    hub.raw_ids
                        .get(&msg.topic())
                        .copied()
                        .filter(|&id| hub.subscribed(id))
                };
                if let Some(id) = raw
                    && let Ok(bytes) = serde_json::to_vec(&msg.to_json())
                {
                    shared.hub().publish(id, None, t_ns, bytes.into(), shared);
                }
                publish_scene(&mut out, t_ns, shared);
            }
        }
    }
}

fn publish_scene(out: &mut Vec<SceneMsg>, t_ns: u64, shared: &Shared) {
    for m in out.drain(..) {
        let Ok(bytes) = serde_json::to_vec(&m.json) else {
            continue;
        };
        let mut hub = shared.hub();
        let Some(&id) = hub.scene_ids.get(&m.channel) else {
            continue;
        };
        hub.publish(id, Some(&m.key), t_ns, bytes.into(), shared);
    }
}

fn accept_thread(listener: &TcpListener, shared: &Arc<Shared>) {
    let mut clients: Vec<JoinHandle<()>> = Vec::new();
    let mut next: u64 = 0;
    while !shared.stop.load(Ordering::SeqCst) {
        match listener.accept() {
            Ok((stream, _peer)) => {
                next += 1;
                let id = next;
                let Ok(clone) = stream.try_clone() else {
                    continue;
                };
                shared.hub().streams.push((id, clone));
                let s = Arc::clone(shared);
                match std::thread::Builder::new()
                    .name(format!("qfleet-foxglove-{id}"))
                    .spawn(move || {
                        client_thread(id, stream, &s);
                        let mut hub = s.hub();
                        hub.clients.retain(|c| c.id != id);
                        hub.streams.retain(|(i, _)| *i != id);
                    }) {
                    Ok(h) => clients.push(h),
                    Err(_) => shared.hub().streams.retain(|(i, _)| *i != id),
                }
                clients.retain(|h| !h.is_finished());
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(20))
            }
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
    for h in clients {
        let _ = h.join();
    }
}

/// How long a client may take to complete the WebSocket handshake.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a client's thread waits for the client's next message before it looks at its queue.
const READ_TICK: Duration = Duration::from_millis(10);
/// Frames written to one client between two looks at what it sent.
const WRITE_BATCH: usize = 256;

fn client_thread(id: u64, stream: TcpStream, shared: &Shared) {
    crate::record::lower_priority();
    let _ = stream.set_nodelay(true);
    let _ = stream.set_nonblocking(false);
    let _ = stream.set_read_timeout(Some(HANDSHAKE_TIMEOUT));
    // the signature tungstenite's handshake callback has: its error is an HTTP response
    #[allow(clippy::result_large_err)]
    let callback = |req: &Request, mut resp: Response| -> Result<Response, ErrorResponse> {
        let offered = req
            .headers()
            .get_all("Sec-WebSocket-Protocol")
            .iter()
            .filter_map(|v| v.to_str().ok())
            .flat_map(|v| v.split(','))
            .any(|p| p.trim() == SUBPROTOCOL);
        if offered && let Ok(v) = SUBPROTOCOL.parse() {
            resp.headers_mut().insert("Sec-WebSocket-Protocol", v);
        }
        Ok(resp)
    };
    let config = WebSocketConfig::default()
        .max_message_size(Some(1 << 20))
        .max_frame_size(Some(1 << 20));
    let Ok(mut ws) = tungstenite::accept_hdr_with_config(stream, callback, Some(config)) else {
        return;
    };
    let _ = ws.get_ref().set_read_timeout(Some(READ_TICK));
    shared.clients.fetch_add(1, Ordering::Relaxed);
    let (tx, rx) = sync_channel(CLIENT_QUEUE);
    let info = json!({
        "op": "serverInfo", "name": "qfleet", "capabilities": [], "supportedEncodings": [],
        "metadata": {}, "sessionId": format!("{}-{}", std::process::id(), wall_ns()),
    });
    let advertise = {
        let mut hub = shared.hub();
        hub.clients.push(ClientSlot {
            id,
            tx,
            subs: HashMap::new(),
        });
        let all: Vec<&ChannelInfo> = hub.channels.iter().collect();
        (!all.is_empty()).then(|| Hub::advertise_json(&all))
    };
    if ws.send(Message::text(info.to_string())).is_err() {
        return;
    }
    if let Some(a) = advertise
        && ws.send(Message::text(a)).is_err()
    {
        return;
    }
    let _ = serve(id, &mut ws, &rx, shared);
    let _ = ws.close(None);
    let _ = ws.flush();
}

fn serve(
    id: u64,
    ws: &mut WebSocket<TcpStream>,
    rx: &Receiver<Frame>,
    shared: &Shared,
) -> Result<(), tungstenite::Error> {
    let mut frame = Vec::with_capacity(4096);
    while !shared.stop.load(Ordering::SeqCst) {
        match ws.read() {
            Ok(Message::Text(t)) => handle_client(id, t.as_str(), shared),
            Ok(Message::Close(_)) => return Ok(()),
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(e) => return Err(e),
        }
        let mut n = 0;
        while n < WRITE_BATCH {
            let Ok(f) = rx.try_recv() else { break };
            let msg = match f {
                Frame::Text(t) => Message::text(t),
                Frame::Data { sub, ts, data } => {
                    frame.clear();
                    frame.push(OP_MESSAGE_DATA);
                    frame.extend_from_slice(&sub.to_le_bytes());
                    frame.extend_from_slice(&ts.to_le_bytes());
                    frame.extend_from_slice(&data);
                    shared.sent.fetch_add(1, Ordering::Relaxed);
                    Message::binary(frame.clone())
                }
            };
            ws.write(msg)?;
            n += 1;
        }
        if n > 0 {
            ws.flush()?;
        }
    }
    Ok(())
}

/// A client's JSON request: `subscribe` (answered with the channel's latched messages at
/// once) and `unsubscribe`; anything else is ignored.
fn handle_client(id: u64, text: &str, shared: &Shared) {
    let Ok(v) = serde_json::from_str::<Value>(text) else {
        return;
    };
    let mut hub = shared.hub();
    let hub = &mut *hub;
    let Some(slot) = hub.clients.iter_mut().find(|c| c.id == id) else {
        return;
    };
    match v.get("op").and_then(Value::as_str) {
        Some("subscribe") => {
            for s in v
                .get("subscriptions")
                .and_then(Value::as_array)
                .into_iter()
                .flatten()
            {
                let (Some(sub), Some(ch)) = (
                    s.get("id")
                        .and_then(Value::as_u64)
                        .and_then(|x| u32::try_from(x).ok()),
                    s.get("channelId")
                        .and_then(Value::as_u64)
                        .and_then(|x| u32::try_from(x).ok()),
                ) else {
                    continue;
                };
                if !hub.channels.iter().any(|c| c.id == ch) {
                    continue;
                }
                slot.subs.insert(ch, sub);
                for ((c, _), (ts, data)) in hub.latched.range((ch, String::new())..) {
                    if *c != ch {
                        break;
                    }
                    let f = Frame::Data {
                        sub,
                        ts: *ts,
                        data: Arc::clone(data),
                    };
                    if slot.tx.try_send(f).is_err() {
                        shared.dropped_slow.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        }
        Some("unsubscribe") => {
            let ids: Vec<u64> = v
                .get("subscriptionIds")
                .and_then(Value::as_array)
                .into_iter()
                .flatten()
                .filter_map(Value::as_u64)
                .collect();
            slot.subs.retain(|_, sub| !ids.contains(&u64::from(*sub)));
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_closing_line_names_every_count() {
        let r = ServeReport {
            clients: 2,
            sent: 10,
            dropped_input: 1,
            dropped_slow: 3,
        };
        assert_eq!(
            r.to_string(),
            "foxglove: 2 client(s), 10 messages sent, 3 dropped for slow clients, 1 dropped by the server"
        );
    }

    #[test]
    fn a_foxglove_address_is_addr_and_port() {
        assert_eq!(parse_addr("127.0.0.1:8765").unwrap().port(), 8765);
        assert!(parse_addr("localhost:9000").unwrap().ip().is_loopback());
        assert!(parse_addr("8765").is_err());
    }
    use bus_schema::RobotState;
    use std::io::{Read, Write};
    use std::time::Instant;
    use tungstenite::client::IntoClientRequest;

    fn server() -> Arc<Server> {
        let s = Server::bind("127.0.0.1:0".parse().unwrap()).expect("binds");
        let grid = Grid::new(3, 2, vec![true, false, true, true, true, true]).unwrap();
        s.begin_run(
            RunStart {
                run_id: "fox-test".into(),
                map_name: "t".into(),
                grid,
                start: Cell::new(0, 0),
                goal: Cell::new(2, 1),
            },
            1_000,
        );
        s
    }

    type Client = WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>;

    fn connect(addr: SocketAddr) -> Client {
        let mut req = format!("ws://{addr}/").into_client_request().unwrap();
        req.headers_mut()
            .insert("Sec-WebSocket-Protocol", SUBPROTOCOL.parse().unwrap());
        let (ws, resp) = tungstenite::connect(req).expect("connects");
        assert_eq!(
            resp.headers().get("Sec-WebSocket-Protocol").unwrap(),
            SUBPROTOCOL
        );
        ws
    }

    fn text(ws: &mut Client) -> Value {
        loop {
            if let Message::Text(t) = ws.read().unwrap() {
                return serde_json::from_str(t.as_str()).unwrap();
            }
        }
    }

    fn data(ws: &mut Client) -> (u32, u64, Value) {
        loop {
            if let Message::Binary(b) = ws.read().unwrap() {
                assert_eq!(b[0], OP_MESSAGE_DATA);
                let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
                let ts = u64::from_le_bytes(b[5..13].try_into().unwrap());
                return (sub, ts, serde_json::from_slice(&b[13..]).unwrap());
            }
        }
    }

    #[test]
    fn a_client_gets_server_info_channels_the_latched_map_and_live_robots() {
        let s = server();
        let mut ws = connect(s.local_addr());
        let info = text(&mut ws);
        assert_eq!(info["op"], "serverInfo");
        // the begin_run above may land before or after the connect: wait for every channel
        let mut channels: Vec<Value> = Vec::new();
        while channels.len() < Channel::ALL.len() + Topic::ALL.len() {
            let adv = text(&mut ws);
            assert_eq!(adv["op"], "advertise");
            channels.extend(adv["channels"].as_array().unwrap().iter().cloned());
        }
        let id_of = |topic: &str| {
            channels.iter().find(|c| c["topic"] == topic).unwrap()["id"]
                .as_u64()
                .unwrap()
        };
        let map = channels.iter().find(|c| c["topic"] == "/map").unwrap();
        assert_eq!(map["schemaName"], "foxglove.Grid");
        assert_eq!(map["encoding"], "json");
        assert_eq!(map["schemaEncoding"], "jsonschema");
        let schema: Value = serde_json::from_str(map["schema"].as_str().unwrap()).unwrap();
        assert_eq!(schema["title"], "foxglove.Grid");
        assert!(
            channels
                .iter()
                .any(|c| c["topic"] == "qfleet/fox-test/robot/state")
        );
        let sub = json!({"op": "subscribe", "subscriptions": [
            {"id": 7, "channelId": id_of("/map")}, {"id": 8, "channelId": id_of("/robots")},
        ]});
        ws.send(Message::text(sub.to_string())).unwrap();
        let (sub, ts, grid) = data(&mut ws);
        assert_eq!((sub, ts), (7, 1_000));
        assert_eq!(grid["column_count"], 3);
        // a robot's state, offered after the subscription took effect
        let t0 = Instant::now();
        let st = RobotState {
            robot_id: 0,
            cell_x: 2,
            cell_y: 1,
            ..RobotState::ZEROED
        };
        while s.counts().sent < 2 && t0.elapsed() < Duration::from_secs(10) {
            s.offer(5_000, 5_000, Owned::State(st));
            std::thread::sleep(Duration::from_millis(20));
        }
        let (sub, ts, robots) = data(&mut ws);
        assert_eq!((sub, ts), (8, 5_000));
        assert_eq!(robots["entities"][0]["id"], "robot-0");
        assert_eq!(
            robots["entities"][0]["cubes"][0]["pose"]["position"]["x"],
            2.5
        );
        let r = s.shutdown();
        assert_eq!(r.clients, 1);
        assert!(r.sent >= 2, "{r:?}");
    }

    #[test]
    fn a_client_that_never_reads_loses_messages_and_holds_nothing_up() {
        let s = server();
        // a WebSocket handshake by hand, a subscription to everything, then never a read
        let mut raw = TcpStream::connect(s.local_addr()).unwrap();
        raw.write_all(
            b"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
              Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\
              Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n",
        )
        .unwrap();
        let mut head = [0u8; 12];
        raw.read_exact(&mut head).unwrap();
        assert_eq!(&head, b"HTTP/1.1 101");
        std::thread::sleep(Duration::from_millis(200));
        let subs: Vec<Value> = (1..=16u32)
            .map(|c| json!({"id": c, "channelId": c}))
            .collect();
        let body = json!({"op": "subscribe", "subscriptions": subs}).to_string();
        let mut f = vec![0x81u8, 0xfe];
        f.extend_from_slice(&(body.len() as u16).to_be_bytes());
        f.extend_from_slice(&[0, 0, 0, 0]); // mask key 0: the payload as it is
        f.extend_from_slice(body.as_bytes());
        raw.write_all(&f).unwrap();
        std::thread::sleep(Duration::from_millis(200));
        // far more than the socket buffers and the client queue hold
        let t0 = Instant::now();
        let mut st = RobotState::ZEROED;
        for i in 0..200_000u32 {
            st.cell_x = (i % 3) as u16;
            st.episode = i;
            s.offer(u64::from(i), u64::from(i), Owned::State(st));
        }
        assert!(
            t0.elapsed() < Duration::from_secs(5),
            "offering took {:?}",
            t0.elapsed()
        );
        let deadline = Instant::now() + Duration::from_secs(60);
        while s.counts().dropped_slow == 0 && Instant::now() < deadline {
            for i in 0..1000u32 {
                st.cell_x = (i % 3) as u16;
                s.offer(u64::from(i), u64::from(i), Owned::State(st));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let r = s.shutdown();
        assert!(r.dropped_slow > 0, "{r:?}");
        drop(raw);
    }

    #[test]
    fn a_port_in_use_is_an_error_that_names_it() {
        let first = Server::bind("127.0.0.1:0".parse().unwrap()).unwrap();
        let e = Server::bind(first.local_addr()).unwrap_err();
        assert!(
            e.to_string()
                .contains(&format!("cannot listen on {}", first.local_addr())),
            "{e}"
        );
        assert!(is_loopback(&first.local_addr()));
        assert!(!is_loopback(&"0.0.0.0:1".parse().unwrap()));
    }
}
