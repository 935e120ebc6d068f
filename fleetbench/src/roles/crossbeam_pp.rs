//! The in-process floor: two threads ping-pong the real message types over crossbeam
//! channels, both busy-polling. The messages are boxed and passed back and forth (no copy, no
//! allocation per round trip), the in-process analogue of zero-copy shared memory.

use std::path::Path;
use std::time::Duration;

use ::report::hist::new_hist;
use bus::bus_schema::{MergedHintBatch, QHintBatch};
use bus::monotonic_ns;
use crossbeam::channel::{Receiver, Sender, TryRecvError, bounded};

use super::{Deadline, Window, record_since, save, window_ns};
use crate::BenchError;
use crate::spec::{ChildReport, Plan};

type Pair = (Box<QHintBatch>, Box<MergedHintBatch>);

/// Batch sequence number that tells the pong thread to exit.
const STOP: u64 = u64::MAX;

#[inline]
fn spin_recv(rx: &Receiver<Pair>, deadline: &mut Deadline) -> Result<Pair, BenchError> {
    deadline.reset();
    let mut spins: u32 = 0;
    loop {
        match rx.try_recv() {
            Ok(p) => return Ok(p),
            Err(TryRecvError::Empty) => {
                spins = spins.wrapping_add(1);
                if spins.is_multiple_of(4096) {
                    deadline.check()?;
                }
                core::hint::spin_loop();
            }
            Err(TryRecvError::Disconnected) => {
                return Err(BenchError::PeerTimeout {
                    what: "the crossbeam pong thread".into(),
                    timeout_ms: 0,
                    died: true,
                });
            }
        }
    }
}

fn send(tx: &Sender<Pair>, p: Pair) -> Result<(), BenchError> {
    tx.send(p).map_err(|_| BenchError::PeerTimeout {
        what: "the crossbeam peer thread".into(),
        timeout_ms: 0,
        died: true,
    })
}

fn pong(rx: Receiver<Pair>, tx: Sender<Pair>, timeout: Duration) -> Result<(), BenchError> {
    let mut deadline = Deadline::new(timeout, "a crossbeam ping", None);
    loop {
        let (q, mut m) = spin_recv(&rx, &mut deadline)?;
        if q.seq == STOP {
            return Ok(());
        }
        m.coordinator_seq = q.seq;
        m.count = 1;
        m.entries[0] = q.entries[0];
        m.origin_ns[0] = q.oldest_update_ns;
        m.send_time_ns = monotonic_ns();
        send(&tx, (q, m))?;
    }
}

/// Runs the ping-pong; the process's CPU (both threads) is reported as its own.
pub fn run(plan: &Plan, hist_path: &Path) -> Result<ChildReport, BenchError> {
    let timeout = Duration::from_millis(plan.timeout_ms);
    let (tx_ping, rx_ping) = bounded::<Pair>(1);
    let (tx_pong, rx_pong) = bounded::<Pair>(1);
    let pong_cpu = crate::cpu::assigned_cpus().get(1).copied();
    let peer = std::thread::spawn(move || {
        if let Some(cpu) = pong_cpu {
            crate::cpu::pin_current_thread(cpu);
        }
        pong(rx_ping, tx_pong, timeout)
    });
    let mut pair: Pair = (
        Box::new(QHintBatch {
            count: 1,
            ..QHintBatch::ZEROED
        }),
        Box::new(MergedHintBatch::ZEROED),
    );
    let mut h = new_hist();
    let mut deadline = Deadline::new(timeout, "the crossbeam pong", None);
    let mut window = None;
    let mut seq = 0;
    while plan.more(seq, || window_ns(&window)) {
        if seq == plan.warmup {
            window = Some(Window::start(None));
        }
        let t0 = monotonic_ns();
        pair.0.seq = seq;
        pair.0.oldest_update_ns = t0;
        send(&tx_ping, pair)?;
        pair = spin_recv(&rx_pong, &mut deadline)?;
        if pair.1.coordinator_seq != seq {
            return Err(BenchError::Input(
                "crossbeam pong answered out of order".into(),
            ));
        }
        record_since(&mut h, t0, seq >= plan.warmup);
        seq += 1;
    }
    let mut r = ChildReport {
        samples: h.len(),
        ..ChildReport::default()
    };
    if let Some(w) = &window {
        w.finish(&mut r);
    }
    // the pong thread keeps spinning while the main thread sleeps: that is the idle cost
    if plan.idle_ms > 0 {
        let before = crate::cpu::self_cpu_ns();
        let t = std::time::Instant::now();
        std::thread::sleep(Duration::from_millis(plan.idle_ms));
        r.peer_idle_cpu_pct = Some(crate::cpu::pct(
            crate::cpu::self_cpu_ns().saturating_sub(before),
            t.elapsed().as_nanos() as u64,
        ));
    }
    pair.0.seq = STOP;
    send(&tx_ping, pair)?;
    match peer.join() {
        Ok(res) => res?,
        Err(_) => return Err(BenchError::Input("crossbeam pong thread panicked".into())),
    }
    save(&h, hist_path)?;
    Ok(r)
}
