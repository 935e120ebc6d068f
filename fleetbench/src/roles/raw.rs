//! The raw iceoryx2 floor: two processes ping-pong the real message types (`QHintBatch` out,
//! `MergedHintBatch` back) over plain iceoryx2 publish-subscribe, no `bus` layer, no merging.
//!
//! Each send loans a slot and writes the whole message into it (`write_payload`), which is what
//! the loop does too (it zeroes the slot and fills it in place). `event` adds one event service
//! per direction: the sender notifies after sending, the receiver sleeps in a `WaitSet`.

use std::path::Path;
use std::time::Duration;

use ::report::hist::new_hist;
use bus::bus_schema::{MergedHintBatch, QHint, QHintBatch};
use bus::{BusConfig, monotonic_ns};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use super::{Deadline, Window, record_since, window_ns};
use crate::BenchError;
use crate::spec::{ChildReport, Plan};

/// Ping sequence number that tells the pong to exit.
const STOP: u64 = u64::MAX;

fn iox(what: &str, e: impl core::fmt::Debug) -> BenchError {
    BenchError::Iox(format!("{what}: {e:?}"))
}

/// One side's ports: publish `O`, subscribe `I`, optional wakeups.
struct Ports<
    I: ZeroCopySend + core::fmt::Debug + 'static,
    O: ZeroCopySend + core::fmt::Debug + 'static,
> {
    publisher: Publisher<ipc::Service, O, ()>,
    subscriber: Subscriber<ipc::Service, I, ()>,
    notifier: Option<Notifier<ipc::Service>>,
    listener: Option<Listener<ipc::Service>>,
    // dropped last
    _node: Node<ipc::Service>,
}

fn service(run_id: &str, name: &str) -> Result<ServiceName, BenchError> {
    ServiceName::new(&format!("qfleet/{run_id}/raw/{name}")).map_err(|e| iox("service name", e))
}

/// Opens both directions; `create` = this side creates the services (the pong, started
/// first), otherwise it opens them, retrying until `timeout`.
fn open<I, O>(
    run_id: &str,
    in_name: &str,
    out_name: &str,
    event: bool,
    create: bool,
    timeout: Duration,
) -> Result<Ports<I, O>, BenchError>
where
    I: ZeroCopySend + core::fmt::Debug + 'static,
    O: ZeroCopySend + core::fmt::Debug + 'static,
{
    let cfg = BusConfig::new(run_id, 1)?;
    let node = cfg.create_node(if create { "raw-pong" } else { "raw-ping" })?;
    let deadline = Deadline::new(timeout, "the raw pong to create its services", None);
    loop {
        match open_ports::<I, O>(&node, run_id, in_name, out_name, event, create) {
            Ok((publisher, subscriber, notifier, listener)) => {
                return Ok(Ports {
                    publisher,
                    subscriber,
                    notifier,
                    listener,
                    _node: node,
                });
            }
            Err(e) if !create => {
                if deadline.check().is_err() {
                    return Err(e);
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => return Err(e),
        }
    }
}

type OpenedPorts<I, O> = (
    Publisher<ipc::Service, O, ()>,
    Subscriber<ipc::Service, I, ()>,
    Option<Notifier<ipc::Service>>,
    Option<Listener<ipc::Service>>,
);

fn open_ports<I, O>(
    node: &Node<ipc::Service>,
    run_id: &str,
    in_name: &str,
    out_name: &str,
    event: bool,
    create: bool,
) -> Result<OpenedPorts<I, O>, BenchError>
where
    I: ZeroCopySend + core::fmt::Debug + 'static,
    O: ZeroCopySend + core::fmt::Debug + 'static,
{
    let pubsub_in = node
        .service_builder(&service(run_id, in_name)?)
        .publish_subscribe::<I>();
    let pubsub_out = node
        .service_builder(&service(run_id, out_name)?)
        .publish_subscribe::<O>();
    let (svc_in, svc_out) = if create {
        (
            pubsub_in.open_or_create().map_err(|e| iox("create", e))?,
            pubsub_out.open_or_create().map_err(|e| iox("create", e))?,
        )
    } else {
        (
            pubsub_in.open().map_err(|e| iox("open", e))?,
            pubsub_out.open().map_err(|e| iox("open", e))?,
        )
    };
    let subscriber = svc_in
        .subscriber_builder()
        .create()
        .map_err(|e| iox("subscriber", e))?;
    let publisher = svc_out
        .publisher_builder()
        .create()
        .map_err(|e| iox("publisher", e))?;
    let (mut notifier, mut listener) = (None, None);
    if event {
        let wake_in = node
            .service_builder(&service(run_id, &format!("{in_name}/wake"))?)
            .event();
        let wake_out = node
            .service_builder(&service(run_id, &format!("{out_name}/wake"))?)
            .event();
        let (ev_in, ev_out) = if create {
            (
                wake_in.open_or_create().map_err(|e| iox("event", e))?,
                wake_out.open_or_create().map_err(|e| iox("event", e))?,
            )
        } else {
            (
                wake_in.open().map_err(|e| iox("event", e))?,
                wake_out.open().map_err(|e| iox("event", e))?,
            )
        };
        listener = Some(
            ev_in
                .listener_builder()
                .create()
                .map_err(|e| iox("listener", e))?,
        );
        notifier = Some(
            ev_out
                .notifier_builder()
                .create()
                .map_err(|e| iox("notifier", e))?,
        );
    }
    Ok((publisher, subscriber, notifier, listener))
}

impl<I, O> Ports<I, O>
where
    I: ZeroCopySend + core::fmt::Debug + Copy + 'static,
    O: ZeroCopySend + core::fmt::Debug + Copy + 'static,
{
    #[inline]
    fn send(&self, msg: &O) -> Result<(), BenchError> {
        let sample = self.publisher.loan_uninit().map_err(|e| iox("loan", e))?;
        sample
            .write_payload(*msg)
            .send()
            .map_err(|e| iox("send", e))?;
        if let Some(n) = &self.notifier {
            n.notify().map_err(|e| iox("notify", e))?;
        }
        Ok(())
    }

    /// Waits for the next message for which `want` returns true (others are dropped).
    #[inline]
    fn wait_for(
        &self,
        waitset: Option<&WaitSet<ipc::Service>>,
        deadline: &mut Deadline,
        mut want: impl FnMut(&I) -> bool,
    ) -> Result<I, BenchError> {
        deadline.reset();
        let mut spins: u32 = 0;
        loop {
            while let Some(s) = self.subscriber.receive().map_err(|e| iox("receive", e))? {
                if want(s.payload()) {
                    return Ok(*s.payload());
                }
            }
            match (waitset, &self.listener) {
                (Some(ws), Some(l)) => {
                    ws.wait_and_process_once_with_timeout(
                        |_| CallbackProgression::Continue,
                        deadline.remaining().min(Duration::from_millis(100)),
                    )
                    .map_err(|e| iox("waitset", e))?;
                    l.try_wait(|_| {}).map_err(|e| iox("listener", e))?;
                    deadline.check()?;
                }
                _ => {
                    spins = spins.wrapping_add(1);
                    if spins.is_multiple_of(4096) {
                        deadline.check()?;
                    }
                    core::hint::spin_loop();
                }
            }
        }
    }
}

fn waitset() -> Result<WaitSet<ipc::Service>, BenchError> {
    WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| iox("waitset", e))
}

/// The echo side: answers each ping with a merged batch carrying its seq and origin time.
pub fn pong(run_id: &str, event: bool, timeout: Duration) -> Result<ChildReport, BenchError> {
    let ports: Ports<QHintBatch, MergedHintBatch> =
        open(run_id, "ping", "pong", event, true, timeout)?;
    let ws = if event { Some(waitset()?) } else { None };
    let _guard = match (&ws, &ports.listener) {
        (Some(ws), Some(l)) => Some(ws.attach_notification(l).map_err(|e| iox("attach", e))?),
        _ => None,
    };
    let mut reply = Box::new(MergedHintBatch::ZEROED);
    let mut deadline = Deadline::new(timeout, "a ping from the raw pinger", None);
    let mut r = ChildReport::default();
    let t = super::Window::start(None);
    loop {
        let ping = ports.wait_for(ws.as_ref(), &mut deadline, |_| true)?;
        if ping.seq == STOP {
            break;
        }
        reply.coordinator_seq = ping.seq;
        reply.count = 1;
        reply.entries[0] = ping.entries[0];
        reply.origin_ns[0] = ping.oldest_update_ns;
        reply.oldest_origin_ns = ping.oldest_update_ns;
        reply.send_time_ns = monotonic_ns();
        ports.send(&reply)?;
        r.samples += 1;
    }
    t.finish(&mut r);
    Ok(r)
}

/// The measuring side: `plan.warmup + plan.samples` round trips, then idle, then stop the pong.
pub fn ping(
    run_id: &str,
    event: bool,
    plan: &Plan,
    peer_pid: u32,
    hist_path: &Path,
) -> Result<ChildReport, BenchError> {
    let timeout = Duration::from_millis(plan.timeout_ms);
    let ports: Ports<MergedHintBatch, QHintBatch> =
        open(run_id, "pong", "ping", event, false, timeout)?;
    let ws = if event { Some(waitset()?) } else { None };
    let _guard = match (&ws, &ports.listener) {
        (Some(ws), Some(l)) => Some(ws.attach_notification(l).map_err(|e| iox("attach", e))?),
        _ => None,
    };
    let mut msg = Box::new(QHintBatch {
        count: 1,
        ..QHintBatch::ZEROED
    });
    msg.entries[0] = QHint {
        cell: 1,
        action: 2,
        q: 0.5,
        visits: 1,
        ..QHint::ZEROED
    };
    // handshake: re-send seq 0 until answered (a message sent before the subscriber
    // connected is dropped silently)
    let mut hs = Deadline::new(timeout, "the raw pong to answer", Some(peer_pid));
    let mut short = Deadline::new(Duration::from_millis(20), "handshake", Some(peer_pid));
    loop {
        ports.send(&msg)?;
        match ports.wait_for(ws.as_ref(), &mut short, |m| m.coordinator_seq == 0) {
            Ok(_) => break,
            Err(BenchError::PeerTimeout { died: false, .. }) => hs.check()?,
            Err(e) => return Err(e),
        }
    }
    hs.reset();
    let mut h = new_hist();
    let mut window = None;
    let mut deadline = Deadline::new(timeout, "the raw pong's answer", Some(peer_pid));
    let mut seq = 0;
    while plan.more(seq, || window_ns(&window)) {
        seq += 1;
        let measuring = seq > plan.warmup;
        if seq == plan.warmup + 1 {
            window = Some(Window::start(Some(peer_pid)));
        }
        let t0 = monotonic_ns();
        msg.seq = seq;
        msg.oldest_update_ns = t0;
        msg.send_time_ns = t0;
        ports.send(&msg)?;
        ports.wait_for(ws.as_ref(), &mut deadline, |m| m.coordinator_seq == seq)?;
        record_since(&mut h, t0, measuring);
    }
    let r = super::finish(&h, window.as_ref(), peer_pid, plan.idle_ms, hist_path)?;
    msg.seq = STOP;
    ports.send(&msg)?;
    Ok(r)
}
