//! The update loop over a Unix stream socket, as a user would write it without iceoryx2: the
//! same `QHintBatch` / `MergedHintBatch` structs sent as their raw bytes (whole structs,
//! 3112 and 6176 bytes), the same batcher, merge (`sharing::FleetTable`) and apply code.
//! `spin` = nonblocking socket polled in a busy loop; otherwise blocking reads.

use std::io::{ErrorKind, Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::Path;
use std::time::Duration;

use bus::bus_schema::{HINT_BATCH_CAP, MergedHintBatch, QHintBatch};
use bus::monotonic_ns;
use contract::coordinator::MergeRule;
use planner::{Grid, QTable};
use sharing::FleetTable;
use sharing::{ApplyCtx, HintBatcher, MergedApplier};

use super::{Deadline, Updates, Window, idle_peer_cpu, save, window_ns};
use crate::BenchError;
use crate::spec::{ChildReport, Plan};

/// Batch sequence number that tells the server to exit.
const STOP: u64 = u64::MAX;

/// A wire struct that may be viewed as bytes and overwritten by any bytes.
///
/// # Safety
/// `#[repr(C)]`, no implicit padding, every field an integer, a float or an array of those
/// (so every bit pattern is a valid value).
unsafe trait Pod: Sized {}
// SAFETY: bus-schema wire types: repr(C), explicit padding only, integer/float fields only
// (the bus-schema layout test checks this).
unsafe impl Pod for QHintBatch {}
// SAFETY: as above.
unsafe impl Pod for MergedHintBatch {}

fn bytes<T: Pod>(v: &T) -> &[u8] {
    // SAFETY: T: Pod has no padding, so all size_of::<T>() bytes are initialised.
    unsafe { std::slice::from_raw_parts((v as *const T).cast::<u8>(), size_of::<T>()) }
}

fn bytes_mut<T: Pod>(v: &mut T) -> &mut [u8] {
    // SAFETY: T: Pod accepts any bit pattern, so writing arbitrary bytes keeps it valid.
    unsafe { std::slice::from_raw_parts_mut((v as *mut T).cast::<u8>(), size_of::<T>()) }
}

fn io(what: &str) -> impl Fn(std::io::Error) -> BenchError + '_ {
    move |source| BenchError::Io {
        what: what.to_string(),
        source,
    }
}

/// One end of the socket, blocking or busy-polling.
struct Conn {
    s: UnixStream,
    spin: bool,
    deadline: Deadline,
}

impl Conn {
    fn new(
        s: UnixStream,
        spin: bool,
        timeout: Duration,
        peer: Option<u32>,
    ) -> Result<Self, BenchError> {
        if spin {
            s.set_nonblocking(true).map_err(io("set_nonblocking"))?;
        } else {
            s.set_read_timeout(Some(timeout))
                .map_err(io("set_read_timeout"))?;
            s.set_write_timeout(Some(timeout))
                .map_err(io("set_write_timeout"))?;
        }
        Ok(Conn {
            s,
            spin,
            deadline: Deadline::new(timeout, "the socket peer", peer),
        })
    }

    #[inline]
    fn read_into<T: Pod>(&mut self, v: &mut T) -> Result<(), BenchError> {
        let buf = bytes_mut(v);
        let mut off = 0;
        let mut spins: u32 = 0;
        self.deadline.reset();
        while off < buf.len() {
            match self.s.read(&mut buf[off..]) {
                Ok(0) => {
                    return Err(BenchError::PeerTimeout {
                        what: "the socket peer (it closed the connection)".into(),
                        timeout_ms: 0,
                        died: true,
                    });
                }
                Ok(n) => off += n,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) if e.kind() == ErrorKind::WouldBlock && self.spin => {
                    spins = spins.wrapping_add(1);
                    if spins.is_multiple_of(4096) {
                        self.deadline.check()?;
                    }
                    core::hint::spin_loop();
                }
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    self.deadline.check()?;
                }
                Err(e) => return Err(io("socket read")(e)),
            }
        }
        Ok(())
    }

    #[inline]
    fn write_from<T: Pod>(&mut self, v: &T) -> Result<(), BenchError> {
        let buf = bytes(v);
        let mut off = 0;
        self.deadline.reset();
        while off < buf.len() {
            match self.s.write(&buf[off..]) {
                Ok(0) => return Err(io("socket write")(ErrorKind::WriteZero.into())),
                Ok(n) => off += n,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    self.deadline.check()?;
                    core::hint::spin_loop();
                }
                Err(e) => return Err(io("socket write")(e)),
            }
        }
        Ok(())
    }
}

/// The socket coordinator: accept one robot, merge every batch into the fleet table, answer
/// each with the merged batch, until told to stop.
pub fn server(
    path: &Path,
    spin: bool,
    cells: u32,
    timeout: Duration,
) -> Result<ChildReport, BenchError> {
    let _ = std::fs::remove_file(path);
    let listener = UnixListener::bind(path).map_err(io("bind"))?;
    listener
        .set_nonblocking(true)
        .map_err(io("set_nonblocking"))?;
    let accept = Deadline::new(timeout, "the socket robot to connect", None);
    let stream = loop {
        match listener.accept() {
            Ok((s, _)) => break s,
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                accept.check()?;
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(e) => return Err(io("accept")(e)),
        }
    };
    stream
        .set_nonblocking(false)
        .map_err(io("set_nonblocking"))?;
    let _ = std::fs::remove_file(path);
    let mut conn = Conn::new(stream, spin, timeout, None)?;
    let mut table = FleetTable::new(cells as usize, MergeRule::Max);
    let mut batch = Box::new(QHintBatch::ZEROED);
    let mut merged = Box::new(MergedHintBatch::ZEROED);
    let mut r = ChildReport::default();
    let t = Window::start(None);
    let mut merged_seq = 0;
    loop {
        conn.read_into(&mut *batch)?;
        if batch.seq == STOP {
            break;
        }
        let n = batch.count as usize;
        if n > HINT_BATCH_CAP {
            continue;
        }
        for h in &batch.entries[..n] {
            // the coordinator's checks (coordinator::run::on_hints)
            if h.cell >= cells || h.action >= 4 || !h.q.is_finite() {
                continue;
            }
            r.updates_sent += 1;
            table.merge(batch.robot_id, h, batch.oldest_update_ns);
        }
        if table.pending() > 0 {
            table.take_into(&mut merged);
            merged.coordinator_seq = merged_seq;
            merged.send_time_ns = monotonic_ns();
            merged_seq += 1;
            conn.write_from(&*merged)?;
        }
        r.samples += 1;
    }
    t.finish(&mut r);
    Ok(r)
}

/// The socket robot pair: make an update, send the batch, read the merged batch, apply it.
pub fn client(
    path: &Path,
    spin: bool,
    cells: u32,
    plan: &Plan,
    peer_pid: u32,
    hist_path: &Path,
) -> Result<ChildReport, BenchError> {
    let timeout = Duration::from_millis(plan.timeout_ms);
    let connect = Deadline::new(timeout, "the socket server to listen", Some(peer_pid));
    let stream = loop {
        match UnixStream::connect(path) {
            Ok(s) => break s,
            Err(_) => {
                connect.check()?;
                std::thread::sleep(Duration::from_millis(2));
            }
        }
    };
    let mut conn = Conn::new(stream, spin, timeout, Some(peer_pid))?;
    let grid = Grid::new(cells as usize, 1, vec![true; cells as usize])
        .map_err(|e| BenchError::Input(format!("grid: {e}")))?;
    let mut batcher = HintBatcher::new(cells as usize, 1, 1e-3);
    let mut q1 = QTable::new(&grid);
    let visits1 = vec![0u16; cells as usize * 4];
    let mut applier = MergedApplier::new(ApplyCtx::second_of_two());
    let updates = Updates::new(cells, 64, 0);
    let mut batch = Box::new(QHintBatch::ZEROED);
    let mut merged = Box::new(MergedHintBatch::ZEROED);
    let mut window = None;
    let mut i = 0;
    while plan.more(i, || window_ns(&window)) {
        if i == plan.warmup {
            window = Some(Window::start(Some(peer_pid)));
            applier.clear_loop_hist(); // warm-up samples are not reported
        }
        let (cell, action, q) = updates.get(i, cells);
        batcher.note(cell, action, q, i, monotonic_ns);
        batch.seq = i;
        batcher.fill(&mut batch);
        batch.send_time_ns = monotonic_ns();
        conn.write_from(&*batch)?;
        conn.read_into(&mut *merged)?;
        applier.apply(&merged, &mut q1, &visits1, monotonic_ns());
        i += 1;
    }
    let h = applier.loop_hist();
    let mut r = ChildReport {
        samples: h.len(),
        merged_seen: applier.counters().entries_seen,
        ..ChildReport::default()
    };
    if let Some(w) = &window {
        w.finish(&mut r);
    }
    r.peer_idle_cpu_pct = idle_peer_cpu(peer_pid, plan.idle_ms);
    batch.seq = STOP;
    conn.write_from(&*batch)?;
    save(h, hist_path)?;
    Ok(r)
}
