//! MCAP recording of a run: one channel per topic (the service name as the MCAP topic), JSON
//! messages with a JSON schema per type (what Foxglove decodes without plug-ins), the run's
//! configuration as metadata and the map as an attachment; besides them the scene of the run
//! in Foxglove's well-known schemas ([`crate::scene`]: `/map` as a `foxglove.Grid` at the
//! start, `/robots`, `/paths` and `/markers` as `foxglove.SceneUpdate`s, `/tf`,
//! `/robot_stats`, `/log`), so the 3D panel draws the map and the robots moving.
//!
//! Times: a message's MCAP `log_time` (and `publish_time`) is its receive time in the observer
//! as wall-clock ns since the Unix epoch; the metadata record `qfleet.run` holds the pair
//! (`clock_wall_ns`, `clock_mono_ns`) taken at the start, so a reader can map log times back to
//! the `CLOCK_MONOTONIC` ns the messages themselves carry (see [`crate::replay`]). Chunks are
//! not compressed (the `mcap` crate's zstd/lz4 would pull in C libraries); Foxglove and the
//! `mcap` CLI read uncompressed chunks.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::Path;

use bus_schema::names::Topic;
use mcap::records::{MessageHeader, Metadata};
use mcap::{Attachment, WriteOptions, Writer};

use crate::ObserveError;
use crate::decode::{Msg, Owned, json_schema};
use crate::scene::{Channel, Scene, SceneMsg};
use crate::stats::topic_index;

/// Name of the metadata record with the run's configuration.
pub const RUN_METADATA: &str = "qfleet.run";
/// Name of the attachment holding the map as a MovingAI `.map` file.
pub const MAP_ATTACHMENT: &str = "map.map";
/// Name of the attachment holding the run's configuration as JSON.
pub const CONFIG_ATTACHMENT: &str = "config.json";

/// What a recording says about its run besides the messages.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunInfo {
    /// Run id.
    pub run_id: String,
    /// Map name.
    pub map_name: String,
    /// The map as a MovingAI `.map` file.
    pub map_text: String,
    /// Start cell (x, y) of the task.
    pub start: (u16, u16),
    /// Goal cell (x, y) of the task.
    pub goal: (u16, u16),
    /// Further settings (robots, learner, sharing …) as key → value, stored as metadata.
    pub config: BTreeMap<String, String>,
}

/// Writes one run into an MCAP file.
pub struct Recorder<W: Write + Seek> {
    writer: Writer<W>,
    channels: [u16; Topic::ALL.len()],
    seq: [u32; Topic::ALL.len()],
    wall0: u64,
    mono0: u64,
    buf: Vec<u8>,
    written: u64,
    scene: Option<RecordedScene>,
}

/// The scene channels of a recording and the scene that feeds them.
struct RecordedScene {
    scene: Scene,
    channels: [u16; Channel::ALL.len()],
    seq: [u32; Channel::ALL.len()],
    out: Vec<SceneMsg>,
}

/// Wall-clock ns since the Unix epoch (0 if the clock is before it).
pub fn wall_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

impl Recorder<BufWriter<File>> {
    /// Creates (or truncates) `path` and writes the header, schemas, channels, metadata and
    /// attachments.
    pub fn create(path: &Path, info: &RunInfo) -> Result<Self, ObserveError> {
        let file = File::create(path).map_err(|e| ObserveError::Io {
            path: path.display().to_string(),
            source: e,
        })?;
        Self::new(BufWriter::new(file), info)
    }
}

impl<W: Write + Seek> Recorder<W> {
    /// Starts a recording into `w`.
    pub fn new(w: W, info: &RunInfo) -> Result<Self, ObserveError> {
        let mut writer = WriteOptions::new()
            .compression(None)
            .profile("")
            .library(concat!("qfleet-observe ", env!("CARGO_PKG_VERSION")))
            .create(w)?;
        let mut channels = [0u16; Topic::ALL.len()];
        for t in Topic::ALL {
            let schema = serde_json::to_vec(&json_schema(t))?;
            let sid = writer.add_schema(t.type_name(), "jsonschema", &schema)?;
            let meta = BTreeMap::from([
                ("delivery".to_string(), format!("{:?}", t.delivery())),
                ("direction".to_string(), format!("{:?}", t.direction())),
            ]);
            channels[topic_index(t)] =
                writer.add_channel(sid, &t.service_name(&info.run_id), "json", &meta)?;
        }
        // the scene needs the map: a recording without one (a bare `RunInfo`) has raw topics only
        let scene = match planner::map::parse_movingai_map("map.map", info.map_text.as_bytes()) {
            Ok(map) => {
                let mut ch = [0u16; Channel::ALL.len()];
                for (i, c) in Channel::ALL.into_iter().enumerate() {
                    let schema = serde_json::to_vec(&c.schema())?;
                    let sid = writer.add_schema(c.schema_name(), "jsonschema", &schema)?;
                    ch[i] = writer.add_channel(sid, c.topic(), "json", &BTreeMap::new())?;
                }
                let cell = |(x, y): (u16, u16)| planner::grid::Cell::new(x, y);
                Some(RecordedScene {
                    scene: Scene::new(&info.map_name, map.grid, cell(info.start), cell(info.goal)),
                    channels: ch,
                    seq: [0; Channel::ALL.len()],
                    out: Vec::new(),
                })
            }
            Err(_) => None,
        };
        let wall0 = wall_ns();
        let mono0 = bus::monotonic_ns();
        let mut meta = info.config.clone();
        meta.insert("run_id".into(), info.run_id.clone());
        meta.insert("map".into(), info.map_name.clone());
        meta.insert("start".into(), format!("{},{}", info.start.0, info.start.1));
        meta.insert("goal".into(), format!("{},{}", info.goal.0, info.goal.1));
        meta.insert(
            "schema_version".into(),
            bus_schema::SCHEMA_VERSION.to_string(),
        );
        meta.insert("clock_wall_ns".into(), wall0.to_string());
        meta.insert("clock_mono_ns".into(), mono0.to_string());
        writer.write_metadata(&Metadata {
            name: RUN_METADATA.into(),
            metadata: meta.clone(),
        })?;
        writer.attach(&Attachment {
            log_time: wall0,
            create_time: wall0,
            name: MAP_ATTACHMENT.into(),
            media_type: "text/plain".into(),
            data: info.map_text.as_bytes().into(),
        })?;
        writer.attach(&Attachment {
            log_time: wall0,
            create_time: wall0,
            name: CONFIG_ATTACHMENT.into(),
            media_type: "application/json".into(),
            data: serde_json::to_vec_pretty(&meta)?.into(),
        })?;
        let mut rec = Self {
            writer,
            channels,
            seq: [0; Topic::ALL.len()],
            wall0,
            mono0,
            buf: Vec::with_capacity(16 * 1024),
            written: 0,
            scene,
        };
        if let Some(s) = rec.scene.as_mut() {
            s.scene.start(wall0, &mut s.out);
        }
        rec.write_scene(wall0)?;
        Ok(rec)
    }

    /// Writes what the scene built, logged at `t` (wall ns).
    fn write_scene(&mut self, t: u64) -> Result<(), ObserveError> {
        let Some(s) = self.scene.as_mut() else {
            return Ok(());
        };
        for m in s.out.drain(..) {
            let i = Channel::ALL
                .iter()
                .position(|c| *c == m.channel)
                .unwrap_or(0);
            self.buf.clear();
            serde_json::to_writer(&mut self.buf, &m.json)?;
            self.writer.write_to_known_channel(
                &MessageHeader {
                    channel_id: s.channels[i],
                    sequence: s.seq[i],
                    log_time: t,
                    publish_time: t,
                },
                &self.buf,
            )?;
            s.seq[i] = s.seq[i].wrapping_add(1);
        }
        Ok(())
    }

    /// Writes one message received at monotonic time `recv_ns`.
    pub fn record(&mut self, recv_ns: u64, msg: Msg<'_>) -> Result<(), ObserveError> {
        let i = topic_index(msg.topic());
        self.buf.clear();
        serde_json::to_writer(&mut self.buf, &msg.to_json())?;
        let t = self
            .wall0
            .saturating_add(recv_ns.saturating_sub(self.mono0));
        self.writer.write_to_known_channel(
            &MessageHeader {
                channel_id: self.channels[i],
                sequence: self.seq[i],
                log_time: t,
                publish_time: t,
            },
            &self.buf,
        )?;
        self.seq[i] = self.seq[i].wrapping_add(1);
        self.written += 1;
        if let Some(s) = self.scene.as_mut() {
            s.scene.apply(t, recv_ns, msg, &mut s.out);
            self.write_scene(t)?;
        }
        Ok(())
    }

    /// Messages of the run's topics written so far (the scene's are not counted).
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Writes the summary section, flushes, and hands back the sink.
    pub fn finish(mut self) -> Result<W, ObserveError> {
        self.writer.finish()?;
        let mut w = self.writer.into_inner();
        w.flush().map_err(|e| ObserveError::Io {
            path: "the recording".into(),
            source: e,
        })?;
        Ok(w)
    }
}

/// Waiting messages a [`BackgroundRecorder`] holds at most (bytes of their copies) before the
/// reader waits for the encoder: a run that outpaces the encoder for long loses messages for
/// the recording alone (in the observer's own buffers), never memory without bound.
pub const MAX_PENDING_BYTES: usize = 256 << 20;

/// A [`Recorder`] on a thread of its own at the lowest CPU priority (`SCHED_IDLE`). The reader only
/// copies each message out of shared memory; JSON encoding and file writes happen on the
/// encoder thread, which takes from a busy run only CPU time nobody else wants, and finishes
/// what did not fit during the run when the run ends ([`finish`](Self::finish)).
pub struct BackgroundRecorder {
    tx: Option<std::sync::mpsc::Sender<(u64, Owned)>>,
    pending: std::sync::Arc<std::sync::atomic::AtomicUsize>,
    handle: Option<std::thread::JoinHandle<Result<u64, ObserveError>>>,
}

impl BackgroundRecorder {
    /// Moves `rec` to a new low-priority encoder thread.
    pub fn start<W: Write + Seek + Send + 'static>(
        mut rec: Recorder<W>,
    ) -> Result<Self, ObserveError> {
        use std::sync::atomic::Ordering;
        let (tx, rx) = std::sync::mpsc::channel::<(u64, Owned)>();
        let pending = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let left = std::sync::Arc::clone(&pending);
        let handle = std::thread::Builder::new()
            .name("qfleet-record".into())
            .spawn(move || {
                lower_priority();
                for (t, m) in rx {
                    left.fetch_sub(m.bytes(), Ordering::AcqRel);
                    rec.record(t, m.as_msg())?;
                }
                let n = rec.written();
                rec.finish()?;
                Ok(n)
            })
            .map_err(|e| ObserveError::Io {
                path: "the recorder thread".into(),
                source: e,
            })?;
        Ok(Self {
            tx: Some(tx),
            pending,
            handle: Some(handle),
        })
    }

    /// Hands a copy of `msg` (received at monotonic `recv_ns`) to the encoder. Never fails: an
    /// encoder that stopped on an error reports it from [`finish`](Self::finish).
    pub fn record(&mut self, recv_ns: u64, msg: Msg<'_>) {
        use std::sync::atomic::Ordering;
        let m = Owned::of(msg);
        let b = m.bytes();
        while self.pending.load(Ordering::Acquire) + b > MAX_PENDING_BYTES && self.encoding() {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        if let Some(tx) = &self.tx {
            self.pending.fetch_add(b, Ordering::AcqRel);
            if tx.send((recv_ns, m)).is_err() {
                // the encoder stopped (its error comes out of finish): stop copying
                self.tx = None;
            }
        }
    }

    fn encoding(&self) -> bool {
        self.handle.as_ref().is_some_and(|h| !h.is_finished())
    }

    /// Waits until every message handed over is written and the file is closed; the number of
    /// messages written, or the encoder's error.
    pub fn finish(mut self) -> Result<u64, ObserveError> {
        self.tx = None;
        match self.handle.take().map(std::thread::JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(ObserveError::Bus("the recorder thread panicked".into())),
            None => Ok(0),
        }
    }
}

impl Drop for BackgroundRecorder {
    fn drop(&mut self) {
        self.tx = None;
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Moves the calling thread to the idle scheduling class (`SCHED_IDLE`: it runs only when no
/// normal thread wants the CPU, and never preempts one when it wakes), falling back to nice 19
/// where that is refused; Linux scheduling attributes are per thread. Best effort: a refusal of
/// both leaves the priority as it was.
pub(crate) fn lower_priority() {
    // SAFETY: gettid, sched_setscheduler and setpriority take plain integers and a pointer to
    // a local `sched_param` that outlives the call; no other memory is shared.
    unsafe {
        let tid = libc::gettid();
        let param = libc::sched_param { sched_priority: 0 };
        if libc::sched_setscheduler(tid, libc::SCHED_IDLE, &param) != 0 {
            let _ = libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, 19);
        }
    }
}
