//! Reading a recording back: the run's metadata and map, every message in log-time order as
//! its JSON value and as a typed message (for the live view), and a per-topic summary.

use std::collections::{BTreeMap, HashMap};
use std::io::{BufReader, Cursor, Read, Seek};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use bus_schema::names::Topic;
use bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, GRANT_CAP, Grant, HINT_BATCH_CAP, Intent,
    IntentHorizon, LatencySummary, MergedHintBatch, PseudoTargetDiscovery, QHint, QHintBatch,
    REASON_LEN, Register, RobotState,
};
use serde::Serialize;
use serde_json::Value;

use crate::ObserveError;
pub use crate::decode::Owned;
use crate::decode::topic_by_name;
use crate::record::{MAP_ATTACHMENT, RUN_METADATA};
use crate::stats::{TopicCounts, topic_index};
use crate::walk::{self, Damage, End, Item, WalkError, Walker, Want};

/// A recording, opened: its metadata and map read, its messages read on demand from the file
/// ([`Recording::messages`]), never the whole file in memory (see [`crate::walk`]).
pub struct Recording {
    source: Source,
    file_bytes: u64,
    /// The `qfleet.run` metadata (run id, map, start, goal, clock pair, settings).
    pub meta: BTreeMap<String, String>,
    /// The map attachment (MovingAI text), if present.
    pub map_text: Option<String>,
    /// Set when the recorder did not finish the file (killed, or its disk filled): what was
    /// read of it. The messages are those before the damage.
    pub cut_short: Option<CutShort>,
}

/// Where a recording's bytes are: a file held open (read with `pread`, so each reader keeps
/// its own position and a file removed after opening is still read), or bytes in memory.
enum Source {
    File(PathBuf, Arc<std::fs::File>),
    Bytes(Arc<[u8]>),
}

/// A reader of a shared open file at a position of its own.
struct At {
    file: Arc<std::fs::File>,
    pos: u64,
}

impl Read for At {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        use std::os::unix::fs::FileExt;
        let n = self.file.read_at(buf, self.pos)?;
        self.pos += n as u64;
        Ok(n)
    }
}

impl Seek for At {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        let base = match pos {
            std::io::SeekFrom::Start(n) => Some(n),
            std::io::SeekFrom::Current(d) => self.pos.checked_add_signed(d),
            std::io::SeekFrom::End(d) => self.file.metadata()?.len().checked_add_signed(d),
        };
        self.pos = base.ok_or_else(|| std::io::Error::from(std::io::ErrorKind::InvalidInput))?;
        Ok(self.pos)
    }
}

trait ReadSeek: Read + Seek {}
impl<T: Read + Seek> ReadSeek for T {}

/// How much of a recording that was not finished could be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct CutShort {
    /// Bytes read from the start of the file: every complete record.
    pub read_bytes: u64,
    /// The file's size.
    pub file_bytes: u64,
}

/// One message of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Message {
    /// Its MCAP log time (the observer's receive time, wall-clock ns).
    pub log_time: u64,
    /// Its topic.
    pub topic: Topic,
    /// The message as JSON.
    pub json: Value,
}

/// The messages of a recording, read from its file one at a time (see
/// [`Recording::messages`]).
pub struct Messages {
    walker: Walker<Box<dyn ReadSeek>>,
    /// Channel id → its qfleet topic (None: another channel, e.g. the scene's).
    channels: HashMap<u16, Option<Topic>>,
    read: u64,
    /// The fleet's size (the `robots` metadata), if the recording says it.
    robots: Option<u64>,
    others: u64,
}

/// Whether `topic` carries a robot's own messages (which name it by `robot_id`): every
/// robot→coordinator topic, `robot/horizon` included.
fn robot_topic(topic: Topic) -> bool {
    topic.direction() == bus_schema::names::Direction::RobotToCoordinator
}

impl Messages {
    /// Messages skipped so far as not the run's own: a robot's message naming a robot id the
    /// fleet (metadata `robots`) does not have.
    pub fn others(&self) -> u64 {
        self.others
    }

    /// The next message of a qfleet topic, in file order (the recorder writes in receive
    /// order); `None` at the end of the data (of what was written, for a file cut short). A
    /// damaged record is [`ObserveError::Damaged`] with its byte offset.
    pub fn next_message(&mut self) -> Result<Option<Message>, ObserveError> {
        let file_bytes = self.walker.file_len();
        let read = self.read;
        let damaged = |d: Damage| ObserveError::Damaged {
            at: d.at,
            file_bytes,
            what: d.what,
            messages: read,
        };
        loop {
            let channels = &self.channels;
            let item = self.walker.next(|c| match channels.get(&c) {
                Some(Some(_)) => Want::Load,
                Some(None) => Want::Skip,
                None => Want::Unknown,
            });
            let item = match item {
                Ok(Some(item)) => item,
                Ok(None) => return Ok(None),
                Err(WalkError::Damaged(d)) => return Err(damaged(d)),
                Err(WalkError::Io(e)) => return Err(ObserveError::Read(e)),
            };
            match item {
                Item::Record { op, at, body } if op == walk::op::CHANNEL => {
                    let (id, topic) = walk::channel_of(at, &body).map_err(damaged)?;
                    self.channels.insert(id, topic_by_name(&topic));
                }
                Item::Record { .. } => {}
                Item::Message {
                    channel,
                    log_time,
                    at,
                    data,
                } => {
                    let Some(&Some(topic)) = self.channels.get(&channel) else {
                        continue;
                    };
                    let json: Value = serde_json::from_slice(&data).map_err(|e| {
                        damaged(Damage {
                            at,
                            what: format!("a message on {} that is not JSON: {e}", topic.path()),
                        })
                    })?;
                    self.read += 1;
                    // a robot the fleet does not have (an outside process's message in an
                    // older recording): not the run's, counted
                    if let Some(robots) = self.robots
                        && robot_topic(topic)
                        && json
                            .get("robot_id")
                            .and_then(Value::as_u64)
                            .is_none_or(|r| r >= robots)
                    {
                        self.others += 1;
                        continue;
                    }
                    return Ok(Some(Message {
                        log_time,
                        topic,
                        json,
                    }));
                }
            }
        }
    }
}

/// One topic in a [`Summary`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TopicSummary {
    /// MCAP topic (the service name).
    pub topic: String,
    /// Messages.
    pub count: u64,
    /// First message, s after the recording's first message.
    pub first_s: Option<f64>,
    /// Last message, s after the recording's first message.
    pub last_s: Option<f64>,
    /// Mean rate between its first and last message, messages/s.
    pub rate_per_s: f64,
}

/// What `qfleet replay` prints.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    /// Run id.
    pub run_id: String,
    /// Map name.
    pub map: String,
    /// Messages in all.
    pub messages: u64,
    /// From the first to the last message, s.
    pub duration_s: f64,
    /// Per topic, in the bus's topic order.
    pub topics: Vec<TopicSummary>,
    /// The recording's run metadata.
    pub metadata: BTreeMap<String, String>,
    /// Null for a finished recording; how much was read of one whose recorder did not finish.
    pub cut_short: Option<CutShort>,
    /// Messages left out as not the run's own (a robot id the fleet does not have).
    pub others: u64,
}

impl Summary {
    /// How many messages over how long, as `qfleet replay` says it: "no messages", "1
    /// message", "N messages over 2.500 s" (or ms, µs, "at one instant": never "over 0.000 s").
    pub fn span(&self) -> String {
        match self.messages {
            0 => "no messages".to_string(),
            1 => "1 message".to_string(),
            n => format!("{n} messages {}", span_text(self.duration_s)),
        }
    }
}

/// "over 2.500 s", "over 3.2 ms", "over 41 µs", "at one instant" (messages logged in the same
/// nanosecond): never "over 0.000 s".
fn span_text(s: f64) -> String {
    if s >= 1.0 {
        format!("over {s:.3} s")
    } else if s >= 1e-3 {
        format!("over {:.1} ms", s * 1e3)
    } else if s > 0.0 {
        format!("over {:.0} µs", (s * 1e6).max(1.0))
    } else {
        "at one instant".to_string()
    }
}

impl Recording {
    /// Opens `path`: reads its metadata and map and finds where its data ends (seeking past
    /// the chunks of messages: memory stays bounded whatever the file's size). A file that is
    /// not MCAP or is damaged is an error that says at which byte.
    pub fn open(path: &Path) -> Result<Self, ObserveError> {
        let io = |e| ObserveError::Io {
            path: path.display().to_string(),
            source: e,
        };
        let file = std::fs::File::open(path).map_err(io)?;
        if !file.metadata().map_err(io)?.is_file() {
            return Err(ObserveError::Mcap(format!(
                "{} is not a regular file",
                path.display()
            )));
        }
        Self::with_source(Source::File(path.to_path_buf(), Arc::new(file)))
    }

    /// A recording from its bytes (held, not copied, while it is read).
    pub fn from_bytes(bytes: Vec<u8>) -> Result<Self, ObserveError> {
        Self::with_source(Source::Bytes(bytes.into()))
    }

    fn reader(source: &Source) -> Result<(Box<dyn ReadSeek>, u64), ObserveError> {
        match source {
            Source::File(path, file) => {
                let len = file
                    .metadata()
                    .map_err(|e| ObserveError::Io {
                        path: path.display().to_string(),
                        source: e,
                    })?
                    .len();
                let at = At {
                    file: Arc::clone(file),
                    pos: 0,
                };
                Ok((Box::new(BufReader::with_capacity(128 << 10, at)), len))
            }
            Source::Bytes(b) => Ok((Box::new(Cursor::new(Arc::clone(b))), b.len() as u64)),
        }
    }

    fn with_source(source: Source) -> Result<Self, ObserveError> {
        let (r, file_bytes) = Self::reader(&source)?;
        let mut meta = BTreeMap::new();
        let mut map_text = None;
        let damaged = |d: Damage| ObserveError::Damaged {
            at: d.at,
            file_bytes,
            what: d.what,
            messages: 0,
        };
        let end = walk::outline(r, file_bytes, |op, at, body| {
            match op {
                walk::op::METADATA => {
                    let (name, m) = walk::metadata_of(at, body)?;
                    if name == RUN_METADATA {
                        meta = m;
                    }
                }
                walk::op::ATTACHMENT => {
                    let (name, data) = walk::attachment_of(at, body)?;
                    if name == MAP_ATTACHMENT {
                        map_text = Some(String::from_utf8_lossy(data).into_owned());
                    }
                }
                _ => {}
            }
            Ok(())
        })
        .map_err(|e| match e {
            WalkError::Damaged(d) => damaged(d),
            WalkError::Io(e) => ObserveError::Read(e),
        })?;
        let cut_short = match end {
            End::Finished {
                end_magic: true, ..
            } => None,
            End::Finished { at, .. } | End::Cut { at } => Some(CutShort {
                read_bytes: at,
                file_bytes,
            }),
        };
        Ok(Self {
            source,
            file_bytes,
            meta,
            map_text,
            cut_short,
        })
    }

    /// The file's size.
    pub fn file_bytes(&self) -> u64 {
        self.file_bytes
    }

    /// The messages, read from the file one at a time.
    pub fn messages(&self) -> Result<Messages, ObserveError> {
        let (r, len) = Self::reader(&self.source)?;
        let walker = Walker::new(r, len, true).map_err(|e| match e {
            WalkError::Damaged(d) => ObserveError::Damaged {
                at: d.at,
                file_bytes: len,
                what: d.what,
                messages: 0,
            },
            WalkError::Io(e) => ObserveError::Read(e),
        })?;
        Ok(Messages {
            walker,
            channels: HashMap::new(),
            read: 0,
            robots: self.meta.get("robots").and_then(|r| r.parse().ok()),
            others: 0,
        })
    }

    /// The monotonic ns a log time stands for (see [`crate::record`]); the log time itself if
    /// the recording has no clock pair.
    pub fn mono_of(&self, log_time: u64) -> u64 {
        let get = |k: &str| self.meta.get(k).and_then(|v| v.parse::<u64>().ok());
        match (get("clock_wall_ns"), get("clock_mono_ns")) {
            (Some(w), Some(m)) => m.saturating_add(log_time.saturating_sub(w)),
            _ => log_time,
        }
    }

    /// Calls `f(log_time, topic, json)` for every message of a qfleet topic, in file order
    /// (the recorder writes in receive order). Messages of other topics are skipped; a message
    /// that is not JSON, or any damaged record, is an error.
    pub fn for_each(
        &self,
        mut f: impl FnMut(u64, Topic, &Value) -> Result<(), ObserveError>,
    ) -> Result<(), ObserveError> {
        let mut messages = self.messages()?;
        while let Some(m) = messages.next_message()? {
            f(m.log_time, m.topic, &m.json)?;
        }
        Ok(())
    }

    /// Counts, first/last times and rates per topic.
    pub fn summary(&self) -> Result<Summary, ObserveError> {
        let mut counts = TopicCounts::default();
        let mut names: Vec<String> = Vec::new();
        let run_id = self.meta.get("run_id").cloned().unwrap_or_default();
        let mut messages = self.messages()?;
        while let Some(m) = messages.next_message()? {
            counts.add(m.topic, m.log_time);
        }
        let t0 = counts
            .0
            .iter()
            .filter(|c| c.count > 0)
            .map(|c| c.first_ns)
            .min()
            .unwrap_or(0);
        let t1 = counts.0.iter().map(|c| c.last_ns).max().unwrap_or(0);
        let rel = |ns: u64| ns.saturating_sub(t0) as f64 / 1e9;
        for t in Topic::ALL {
            names.push(t.service_name(&run_id));
        }
        let topics = Topic::ALL
            .iter()
            .zip(names)
            .map(|(&t, topic)| {
                let c = counts.get(t);
                TopicSummary {
                    topic,
                    count: c.count,
                    first_s: (c.count > 0).then(|| rel(c.first_ns)),
                    last_s: (c.count > 0).then(|| rel(c.last_ns)),
                    rate_per_s: c.mean_rate(),
                }
            })
            .collect();
        Ok(Summary {
            run_id,
            map: self.meta.get("map").cloned().unwrap_or_default(),
            messages: counts.total(),
            duration_s: rel(t1),
            topics,
            metadata: self.meta.clone(),
            cut_short: self.cut_short,
            others: messages.others(),
        })
    }

    /// The `(x, y)` of metadata key `key` (`"start"`, `"goal"`).
    pub fn cell(&self, key: &str) -> Option<(u16, u16)> {
        let (x, y) = self.meta.get(key)?.split_once(',')?;
        Some((x.trim().parse().ok()?, y.trim().parse().ok()?))
    }
}

struct J<'a>(&'a Value);

impl J<'_> {
    fn u(&self, k: &str) -> u64 {
        self.0.get(k).and_then(Value::as_u64).unwrap_or(0)
    }
    fn u32(&self, k: &str) -> u32 {
        u32::try_from(self.u(k)).unwrap_or(u32::MAX)
    }
    fn u16(&self, k: &str) -> u16 {
        u16::try_from(self.u(k)).unwrap_or(u16::MAX)
    }
    fn u8(&self, k: &str) -> u8 {
        u8::try_from(self.u(k)).unwrap_or(u8::MAX)
    }
    fn i32(&self, k: &str) -> i32 {
        self.0
            .get(k)
            .and_then(Value::as_i64)
            .and_then(|v| i32::try_from(v).ok())
            .unwrap_or(-1)
    }
    fn f(&self, k: &str) -> f64 {
        self.0.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN)
    }
    fn entries(&self) -> Vec<&Value> {
        self.list("entries", HINT_BATCH_CAP)
    }
    /// The first `cap` elements of array `k` (none if it is not an array).
    fn list(&self, k: &str, cap: usize) -> Vec<&Value> {
        self.0
            .get(k)
            .and_then(Value::as_array)
            .map(|a| a.iter().take(cap).collect())
            .unwrap_or_default()
    }
}

fn hint(e: &Value) -> QHint {
    let j = J(e);
    QHint {
        cell: j.u32("cell"),
        action: j.u8("action"),
        visits: j.u16("visits"),
        q: j.f("q") as f32,
        ..QHint::ZEROED
    }
}

/// Rebuilds the message of `topic` from its JSON form (missing fields become zero, or NaN/-1
/// where the wire type has a "none" value); the inverse of [`Msg::to_json`].
pub fn from_json(topic: Topic, v: &Value) -> Owned {
    let j = J(v);
    match topic {
        Topic::Register => Owned::Register(Register {
            schema_version: j.u32("schema_version"),
            robot_id: j.u32("robot_id"),
            pid: j.u32("pid"),
            episodes: j.u32("episodes"),
            width: j.u16("width"),
            height: j.u16("height"),
            start_x: j.u16("start_x"),
            start_y: j.u16("start_y"),
            map_hash: j.u("map_hash"),
            seed: j.u("seed"),
            send_time_ns: j.u("send_time_ns"),
        }),
        Topic::RobotState => Owned::State(RobotState {
            robot_id: j.u32("robot_id"),
            goal_id: j.u32("goal_id"),
            episode: j.u32("episode"),
            step: j.u32("step"),
            last_episode_steps: j.u32("last_episode_steps"),
            cell_x: j.u16("cell_x"),
            cell_y: j.u16("cell_y"),
            status: j.u8("status"),
            seq: j.u("seq"),
            send_time_ns: j.u("send_time_ns"),
            ..RobotState::ZEROED
        }),
        Topic::Discovery => Owned::Discovery(PseudoTargetDiscovery {
            robot_id: j.u32("robot_id"),
            goal_id: j.u32("goal_id"),
            cell_x: j.u16("cell_x"),
            cell_y: j.u16("cell_y"),
            value: j.f("value") as f32,
            seq: j.u("seq"),
            time_ns: j.u("time_ns"),
            episode: j.u32("episode"),
            send_time_ns: j.u("send_time_ns"),
            ..PseudoTargetDiscovery::ZEROED
        }),
        Topic::Hints => {
            let mut m = Box::new(QHintBatch {
                robot_id: j.u32("robot_id"),
                goal_id: j.u32("goal_id"),
                seq: j.u("seq"),
                oldest_update_ns: j.u("oldest_update_ns"),
                send_time_ns: j.u("send_time_ns"),
                ..QHintBatch::ZEROED
            });
            let e = j.entries();
            m.count = e.len() as u32;
            for (i, e) in e.into_iter().enumerate() {
                m.entries[i] = hint(e);
            }
            Owned::Hints(m)
        }
        Topic::Report => {
            let l = v.get("merged_latency").unwrap_or(&Value::Null);
            let l = J(l);
            Owned::Report(FinalReport {
                robot_id: j.u32("robot_id"),
                schema_version: j.u32("schema_version"),
                goal_id: j.u32("goal_id"),
                episodes: j.u32("episodes"),
                final_path_len: j.i32("final_path_len"),
                optimal_path_len: j.i32("optimal_path_len"),
                first_optimal_episode: j.i32("first_optimal_episode"),
                max_steps: j.u32("max_steps"),
                status: j.u8("status"),
                avg_steps: j.f("avg_steps"),
                env_steps: j.u("env_steps"),
                elapsed_ns: j.u("elapsed_ns"),
                discoveries_sent: j.u("discoveries_sent"),
                discoveries_acked: j.u("discoveries_acked"),
                hints_sent: j.u("hints_sent"),
                hints_received: j.u("hints_received"),
                hints_applied: j.u("hints_applied"),
                merged_latency: LatencySummary {
                    count: l.u("count"),
                    min_ns: l.u("min_ns"),
                    mean_ns: l.u("mean_ns"),
                    p50_ns: l.u("p50_ns"),
                    p90_ns: l.u("p90_ns"),
                    p99_ns: l.u("p99_ns"),
                    p999_ns: l.u("p999_ns"),
                    max_ns: l.u("max_ns"),
                },
                send_time_ns: j.u("send_time_ns"),
                ..FinalReport::ZEROED
            })
        }
        Topic::Control => {
            let mut m = Control {
                command: j.u8("command"),
                robot_id: j.u32("robot_id"),
                goal_id: j.u32("goal_id"),
                goal_x: j.u16("goal_x"),
                goal_y: j.u16("goal_y"),
                phase: j.u32("phase"),
                episodes: j.u32("episodes"),
                schema_version: j.u32("schema_version"),
                seq: j.u("seq"),
                time_ns: j.u("time_ns"),
                ..Control::ZEROED
            };
            let r = v.get("reason").and_then(Value::as_str).unwrap_or("");
            let mut n = r.len().min(REASON_LEN);
            while !r.is_char_boundary(n) {
                n -= 1;
            }
            m.reason[..n].copy_from_slice(&r.as_bytes()[..n]);
            m.reason_len = n as u32;
            Owned::Control(m)
        }
        Topic::Merged => {
            let mut m = Box::new(MergedHintBatch {
                coordinator_seq: j.u("coordinator_seq"),
                goal_id: j.u32("goal_id"),
                oldest_origin_ns: j.u("oldest_origin_ns"),
                send_time_ns: j.u("send_time_ns"),
                ..MergedHintBatch::ZEROED
            });
            let e = j.entries();
            m.count = e.len() as u32;
            for (i, e) in e.into_iter().enumerate() {
                m.entries[i] = hint(e);
                m.origin_ns[i] = J(e).u("origin_ns");
                m.origin_robot[i] = J(e).u32("origin_robot");
            }
            Owned::Merged(m)
        }
        Topic::Ack => Owned::Ack(DiscoveryAck {
            robot_id: j.u32("robot_id"),
            up_to_seq: j.u("up_to_seq"),
            time_ns: j.u("time_ns"),
            ..DiscoveryAck::ZEROED
        }),
        Topic::Relay => Owned::Relay(DiscoveryRelay {
            relay_seq: j.u("relay_seq"),
            origin_robot: j.u32("origin_robot"),
            goal_id: j.u32("goal_id"),
            cell_x: j.u16("cell_x"),
            cell_y: j.u16("cell_y"),
            value: j.f("value") as f32,
            origin_seq: j.u("origin_seq"),
            origin_ns: j.u("origin_ns"),
            send_time_ns: j.u("send_time_ns"),
        }),
        Topic::Intent => {
            let mut m = Intent {
                robot_id: j.u32("robot_id"),
                tick: j.u32("tick"),
                cell_x: j.u16("cell_x"),
                cell_y: j.u16("cell_y"),
                send_time_ns: j.u("send_time_ns"),
                ..Intent::ZEROED
            };
            let ranked = j.list("ranked", m.ranked.len());
            m.count = ranked.len() as u8;
            for (slot, r) in m.ranked.iter_mut().zip(ranked) {
                *slot = u8::try_from(r.as_u64().unwrap_or(u64::MAX)).unwrap_or(u8::MAX);
            }
            Owned::Intent(m)
        }
        Topic::Horizon => {
            let mut m = Box::new(IntentHorizon {
                robot_id: j.u32("robot_id"),
                tick: j.u32("tick"),
                cell_x: j.u16("cell_x"),
                cell_y: j.u16("cell_y"),
                radius: j.u8("radius"),
                send_time_ns: j.u("send_time_ns"),
                ..IntentHorizon::ZEROED
            });
            let ranked = j.list("ranked", m.ranked.len());
            for (slot, r) in m.ranked.iter_mut().zip(ranked) {
                *slot = u16::try_from(r.as_u64().unwrap_or(u64::MAX)).unwrap_or(u16::MAX);
            }
            Owned::Horizon(m)
        }
        Topic::Grant => {
            let mut m = Box::new(Grant {
                tick: j.u32("tick"),
                state: j.u8("state"),
                seq: j.u("seq"),
                send_time_ns: j.u("send_time_ns"),
                ..Grant::ZEROED
            });
            let cells = j.list("cells", GRANT_CAP);
            m.robots = cells.len() as u32;
            for (i, c) in cells.into_iter().enumerate() {
                let c = J(c);
                m.cell_x[i] = c.u16("x");
                m.cell_y[i] = c.u16("y");
                m.present[i] = c.u8("present");
            }
            Owned::Grant(m)
        }
    }
}

/// Index of `topic` among the recording's counts (re-exported for callers that tabulate).
pub fn index_of(topic: Topic) -> usize {
    topic_index(topic)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_span_is_never_printed_as_zero_seconds() {
        assert_eq!(span_text(2.5), "over 2.500 s");
        assert_eq!(span_text(0.0032), "over 3.2 ms");
        assert_eq!(span_text(0.000041), "over 41 µs");
        assert_eq!(span_text(2e-9), "over 1 µs");
        assert_eq!(span_text(0.0), "at one instant");
    }
    use crate::record::{Recorder, RunInfo};
    use crate::walk::MAX_MESSAGE_BYTES;

    fn sample_msgs() -> Vec<Owned> {
        let mut hints = Box::new(QHintBatch {
            robot_id: 1,
            goal_id: 0,
            count: 2,
            seq: 9,
            oldest_update_ns: 5,
            ..QHintBatch::ZEROED
        });
        hints.entries[1] = QHint {
            cell: 7,
            action: 3,
            visits: 2,
            q: 0.5,
            ..QHint::ZEROED
        };
        let mut merged = Box::new(MergedHintBatch {
            count: 1,
            coordinator_seq: 4,
            ..MergedHintBatch::ZEROED
        });
        merged.origin_robot[0] = 2;
        merged.origin_ns[0] = 77;
        let mut control = Control {
            command: 6,
            reason_len: 3,
            seq: 1,
            ..Control::ZEROED
        };
        control.reason[..3].copy_from_slice(b"bad");
        vec![
            Owned::Register(Register {
                robot_id: 3,
                start_x: 1,
                start_y: 2,
                map_hash: u64::MAX,
                ..Register::ZEROED
            }),
            Owned::State(RobotState {
                robot_id: 1,
                episode: 5,
                status: 1,
                ..RobotState::ZEROED
            }),
            Owned::Discovery(PseudoTargetDiscovery {
                value: 0.25,
                seq: 3,
                ..PseudoTargetDiscovery::ZEROED
            }),
            Owned::Hints(hints),
            Owned::Report(FinalReport {
                final_path_len: -1,
                optimal_path_len: 58,
                first_optimal_episode: -1,
                avg_steps: 12.5,
                ..FinalReport::ZEROED
            }),
            Owned::Control(control),
            Owned::Merged(merged),
            Owned::Ack(DiscoveryAck {
                up_to_seq: 8,
                ..DiscoveryAck::ZEROED
            }),
            Owned::Relay(DiscoveryRelay {
                relay_seq: 2,
                value: 1.5,
                ..DiscoveryRelay::ZEROED
            }),
        ]
    }

    /// A shared grid's two messages (kept out of `sample_msgs`, whose count other tests use).
    fn grid_msgs() -> Vec<Owned> {
        let mut grant = Box::new(Grant {
            tick: 7,
            robots: 2,
            state: 1,
            seq: 7,
            send_time_ns: 99,
            ..Grant::ZEROED
        });
        grant.cell_x[..2].copy_from_slice(&[3, 4]);
        grant.cell_y[..2].copy_from_slice(&[1, 0]);
        grant.present[0] = 1;
        vec![
            Owned::Intent(Intent {
                robot_id: 1,
                tick: 6,
                cell_x: 4,
                cell_y: 0,
                count: 3,
                ranked: [2, 0, 4, 0, 0],
                send_time_ns: 98,
                ..Intent::ZEROED
            }),
            Owned::Grant(grant),
            Owned::Horizon(Box::new({
                let mut h = IntentHorizon {
                    robot_id: 1,
                    tick: 9,
                    cell_x: 4,
                    cell_y: 2,
                    radius: 1,
                    send_time_ns: 97,
                    ..IntentHorizon::ZEROED
                };
                h.ranked[..5].copy_from_slice(&[1, 3 | (1 << 3), 2, 5, 4]);
                h
            })),
        ]
    }

    #[test]
    fn json_round_trips_every_message() {
        for m in sample_msgs().into_iter().chain(grid_msgs()) {
            let msg = m.as_msg();
            let back = from_json(msg.topic(), &msg.to_json());
            assert_eq!(back, m, "{:?}", msg.topic());
        }
    }

    #[test]
    fn a_recording_reads_back_with_its_channels_metadata_map_and_counts() {
        let info = RunInfo {
            run_id: "rec-1".into(),
            map_name: "tiny".into(),
            map_text: "type octile\nheight 1\nwidth 2\nmap\n..\n".into(),
            start: (0, 0),
            goal: (1, 0),
            config: BTreeMap::from([("robots".to_string(), "4".to_string())]),
        };
        let mut rec = Recorder::new(Cursor::new(Vec::new()), &info).unwrap();
        let msgs = sample_msgs();
        let t0 = bus::monotonic_ns();
        for (i, m) in msgs.iter().enumerate() {
            rec.record(t0 + i as u64 * 1_000_000, m.as_msg()).unwrap();
        }
        // a second State to have a rate
        rec.record(t0 + 20_000_000, msgs[1].as_msg()).unwrap();
        assert_eq!(rec.written(), 10);
        rec.record(t0 + 30_000_000, msgs[8].as_msg()).unwrap();
        assert_eq!(rec.written(), 11);
        let bytes = rec.finish().unwrap().into_inner();
        let summary_idx = mcap::Summary::read(&bytes).unwrap().unwrap();
        // the run's raw topics, and the scene's channels in Foxglove's well-known schemas
        let scene = crate::scene::Channel::ALL;
        assert_eq!(summary_idx.channels.len(), Topic::ALL.len() + scene.len());
        for ch in summary_idx.channels.values() {
            let s = ch.schema.as_ref().unwrap();
            assert_eq!(s.encoding, "jsonschema");
            assert_eq!(ch.message_encoding, "json");
            match scene.iter().find(|c| c.topic() == ch.topic) {
                Some(c) => assert_eq!(s.name, c.schema_name()),
                None => assert!(ch.topic.starts_with("qfleet/rec-1/"), "{}", ch.topic),
            }
            let schema: Value = serde_json::from_slice(&s.data).unwrap();
            assert_eq!(schema["title"], s.name);
        }
        let r = Recording::from_bytes(bytes).unwrap();
        assert_eq!(r.meta["robots"], "4");
        assert_eq!(r.cell("goal"), Some((1, 0)));
        assert!(r.map_text.as_deref().unwrap().contains("width 2"));
        let s = r.summary().unwrap();
        assert_eq!(s.messages, 11);
        let state = &s.topics[index_of(Topic::RobotState)];
        assert_eq!(state.count, 2);
        assert!(
            (state.rate_per_s - 1.0 / 0.019).abs() < 1.0,
            "{}",
            state.rate_per_s
        );
        assert_eq!(s.topics[index_of(Topic::Relay)].count, 2);
        // log times map back to the monotonic clock the messages were received on
        let mut first = None;
        r.for_each(|t, _, _| {
            first.get_or_insert(r.mono_of(t));
            Ok(())
        })
        .unwrap();
        assert!(first.unwrap().abs_diff(t0) < 1_000_000);
    }

    #[test]
    fn a_background_recorder_writes_every_message_handed_over_in_order() {
        let path = std::env::temp_dir().join(format!(
            "qfleet-observe-bg-{}-{}.mcap",
            std::process::id(),
            bus::monotonic_ns()
        ));
        let info = RunInfo {
            run_id: "rec-bg".into(),
            ..RunInfo::default()
        };
        let mut rec =
            crate::record::BackgroundRecorder::start(Recorder::create(&path, &info).unwrap())
                .unwrap();
        let msgs = sample_msgs();
        let t0 = bus::monotonic_ns();
        let rounds = 500;
        for k in 0..rounds {
            for (i, m) in msgs.iter().enumerate() {
                rec.record(t0 + (k * msgs.len() + i) as u64, m.as_msg());
            }
        }
        assert_eq!(rec.finish().unwrap(), (rounds * msgs.len()) as u64);
        let r = Recording::open(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        let mut n = 0;
        r.for_each(|_, topic, v| {
            assert_eq!(from_json(topic, v), msgs[n % msgs.len()], "message {n}");
            n += 1;
            Ok(())
        })
        .unwrap();
        assert_eq!(n, rounds * msgs.len());
    }

    /// A file on a disk with `room` bytes left: writes past it fail as a full disk does.
    struct SmallDisk {
        file: Cursor<Vec<u8>>,
        room: u64,
    }

    impl std::io::Write for SmallDisk {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            if self.file.position() + buf.len() as u64 > self.room {
                return Err(std::io::Error::from(std::io::ErrorKind::StorageFull));
            }
            self.file.write(buf)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl std::io::Seek for SmallDisk {
        fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
            self.file.seek(pos)
        }
    }

    #[test]
    fn a_full_disk_ends_the_recording_with_an_error_that_says_so() {
        let disk = SmallDisk {
            file: Cursor::new(Vec::new()),
            room: 64 << 10,
        };
        let rec = Recorder::new(std::io::BufWriter::new(disk), &RunInfo::default()).unwrap();
        let mut rec = crate::record::BackgroundRecorder::start(rec).unwrap();
        let msgs = sample_msgs();
        for k in 0..2000 {
            for m in &msgs {
                rec.record(k, m.as_msg());
            }
        }
        let e = rec.finish().expect_err("the disk is full");
        let chain: Vec<String> =
            std::iter::successors(Some(&e as &dyn std::error::Error), |e| e.source())
                .map(ToString::to_string)
                .collect();
        assert!(
            chain.iter().any(|m| m.contains("no storage space")),
            "the cause is kept: {chain:?}"
        );
    }

    /// A finished recording of `rounds` rounds of [`sample_msgs`], and those messages.
    fn finished_recording(rounds: usize) -> (Vec<u8>, Vec<Owned>) {
        let mut rec = Recorder::new(Cursor::new(Vec::new()), &RunInfo::default()).unwrap();
        let mut sent = Vec::new();
        for k in 0..rounds {
            for m in sample_msgs() {
                rec.record(k as u64, m.as_msg()).unwrap();
                sent.push(m);
            }
        }
        (rec.finish().unwrap().into_inner(), sent)
    }

    /// Every message a recording yields, rebuilt.
    fn messages(r: &Recording) -> Vec<Owned> {
        let mut got = Vec::new();
        r.for_each(|_, topic, v| {
            got.push(from_json(topic, v));
            Ok(())
        })
        .unwrap();
        got
    }

    #[test]
    fn a_recording_cut_anywhere_gives_back_the_messages_before_the_cut() {
        let (file, sent) = finished_recording(40);
        let mut before = 0;
        // every cut point through the file, a few bytes apart
        for cut in (8..file.len()).step_by(7) {
            let r = Recording::from_bytes(file[..cut].to_vec()).expect("a cut file opens");
            let c = r.cut_short.expect("said to be cut short");
            assert!(
                c.read_bytes <= cut as u64,
                "read {c:?} of a file cut at {cut}"
            );
            assert_eq!(c.file_bytes, cut as u64);
            let got = messages(&r);
            assert_eq!(
                got[..],
                sent[..got.len()],
                "a prefix, in order (cut at {cut})"
            );
            assert!(
                got.len() >= before,
                "a longer file never gives fewer messages"
            );
            before = got.len();
        }
        assert_eq!(before, sent.len(), "all of them before the summary");
    }

    /// Offsets of the message records of the qfleet topics in `file`, in file order.
    fn message_offsets(file: &[u8]) -> Vec<u64> {
        let len = file.len() as u64;
        let mut w = Walker::new(Cursor::new(file), len, true).unwrap();
        let mut channels = HashMap::new();
        let mut at = Vec::new();
        while let Some(item) = w
            .next(|c| match channels.get(&c) {
                Some(true) => Want::Load,
                _ => Want::Skip,
            })
            .unwrap()
        {
            match item {
                Item::Record { op, at, body } if op == walk::op::CHANNEL => {
                    let (id, topic) = walk::channel_of(at, &body).unwrap();
                    channels.insert(id, topic_by_name(&topic).is_some());
                }
                Item::Message { at: a, .. } => at.push(a),
                Item::Record { .. } => {}
            }
        }
        at
    }

    #[test]
    fn a_damaged_recording_is_an_error_that_says_at_which_byte_it_broke() {
        let (mut file, sent) = finished_recording(10);
        let at = message_offsets(&file);
        assert_eq!(at.len(), sent.len());
        // the 25th message's length field now claims more than its chunk holds
        let k = 24;
        let bad = at[k] as usize;
        file[bad + 1..bad + 9].copy_from_slice(&(1u64 << 40).to_le_bytes());
        let len = file.len() as u64;
        let r = Recording::from_bytes(file).expect("its outline is whole");
        assert_eq!(r.cut_short, None, "a finished file is not cut short");
        let mut got = 0;
        let e = r
            .for_each(|_, _, _| {
                got += 1;
                Ok(())
            })
            .expect_err("damaged");
        match e {
            ObserveError::Damaged {
                at,
                file_bytes,
                messages,
                ref what,
            } => {
                assert_eq!(at, bad as u64, "{e}");
                assert_eq!(file_bytes, len);
                assert_eq!(messages, k as u64);
                assert!(what.contains("past the end of its chunk"), "{e}");
            }
            e => panic!("not said to be damaged: {e}"),
        }
        assert_eq!(got, k, "the messages before the damage were read");
        // damage in the file's outline is found when it is opened
        let (mut file, _) = finished_recording(2);
        file[8] = 0x42;
        let e = Recording::from_bytes(file).err().expect("damaged");
        assert!(
            e.to_string().contains("damaged at byte 8 of") && e.to_string().contains("0x42"),
            "{e}"
        );
    }

    #[test]
    fn a_message_too_big_for_qfleet_is_refused_unread_and_other_channels_are_skipped_unread() {
        // a recording without chunks whose last message claims 240 MB: a sparse file, so the
        // test writes (and a reader could read) only what it must
        let topic = Topic::RobotState.service_name("huge");
        let mut w = mcap::WriteOptions::new()
            .use_chunks(false)
            .create(Cursor::new(Vec::new()))
            .unwrap();
        let schema = w.add_schema("s", "jsonschema", b"{}").unwrap();
        let scene = w
            .add_channel(schema, "/map", "json", &BTreeMap::new())
            .unwrap();
        let state = w
            .add_channel(schema, &topic, "json", &BTreeMap::new())
            .unwrap();
        let header = |channel_id, sequence| mcap::records::MessageHeader {
            channel_id,
            sequence,
            log_time: 1,
            publish_time: 1,
        };
        w.write_to_known_channel(&header(scene, 0), b"not even json: skipped unread")
            .unwrap();
        w.write_to_known_channel(&header(state, 0), br#"{"robot_id": 1}"#)
            .unwrap();
        w.write_to_known_channel(&header(state, 1), br#"{"robot_id": 2}"#)
            .unwrap();
        w.finish().unwrap();
        let file = w.into_inner().into_inner();
        let at = message_offsets(&file);
        let sent = at.len();
        assert_eq!(sent, 2);
        let path = std::env::temp_dir().join(format!(
            "qfleet-observe-huge-{}-{}.mcap",
            std::process::id(),
            bus::monotonic_ns()
        ));
        {
            use std::io::Write;
            let mut f = std::fs::File::create(&path).unwrap();
            let last = *at.last().unwrap() as usize;
            f.write_all(&file[..last]).unwrap();
            let huge: u64 = 240 << 20;
            let mut head = vec![walk::op::MESSAGE];
            head.extend_from_slice(&(huge + 22).to_le_bytes());
            // the same channel as the record it replaces
            head.extend_from_slice(&file[last + 9..last + 9 + 22]);
            f.write_all(&head).unwrap();
            f.set_len((last + head.len()) as u64 + huge).unwrap();
        }
        let r = Recording::open(&path);
        let _ = std::fs::remove_file(&path);
        let r = r.expect("opens: its messages are not read yet");
        let e = r.for_each(|_, _, _| Ok(())).expect_err("refused");
        let text = e.to_string();
        assert!(
            text.contains(&format!("damaged at byte {}", at.last().unwrap()))
                && text.contains(&format!("at most {MAX_MESSAGE_BYTES} bytes"))
                && text.contains(&format!("{} message(s) read before it", sent - 1)),
            "{text}"
        );
    }

    #[test]
    fn the_biggest_qfleet_message_is_far_under_the_message_cap() {
        let mut merged = Box::new(MergedHintBatch {
            coordinator_seq: u64::MAX,
            goal_id: u32::MAX,
            count: HINT_BATCH_CAP as u32,
            oldest_origin_ns: u64::MAX,
            send_time_ns: u64::MAX,
            ..MergedHintBatch::ZEROED
        });
        for i in 0..HINT_BATCH_CAP {
            merged.entries[i] = QHint {
                cell: u32::MAX,
                action: u8::MAX,
                visits: u16::MAX,
                q: -f32::MAX,
                ..QHint::ZEROED
            };
            merged.origin_robot[i] = u32::MAX;
            merged.origin_ns[i] = u64::MAX;
        }
        let mut grant = Box::new(Grant {
            tick: u32::MAX,
            robots: GRANT_CAP as u32,
            state: u8::MAX,
            seq: u64::MAX,
            send_time_ns: u64::MAX,
            ..Grant::ZEROED
        });
        grant.cell_x.fill(u16::MAX);
        grant.cell_y.fill(u16::MAX);
        grant.present.fill(u8::MAX);
        for m in [Owned::Merged(merged), Owned::Grant(grant)] {
            let n = serde_json::to_vec(&m.as_msg().to_json()).unwrap().len() as u64;
            assert!(n * 16 < MAX_MESSAGE_BYTES, "{n} bytes");
        }
    }

    /// A `Write + Seek` into a buffer that outlives the writer (the test keeps a handle).
    #[derive(Clone, Default)]
    struct Shared(std::sync::Arc<std::sync::Mutex<Cursor<Vec<u8>>>>);

    impl std::io::Write for Shared {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().write(buf)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl std::io::Seek for Shared {
        fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
            self.0.lock().unwrap().seek(pos)
        }
    }

    #[test]
    fn a_killed_recorders_file_is_read_up_to_its_last_whole_message() {
        let file = Shared::default();
        let mut rec = Recorder::new(file.clone(), &RunInfo::default()).unwrap();
        let mut sent = Vec::new();
        for k in 0..300 {
            for m in sample_msgs() {
                rec.record(k, m.as_msg()).unwrap();
                sent.push(m);
            }
        }
        // killed: nothing after this point is written, no chunk is closed
        std::mem::forget(rec);
        let bytes = file.0.lock().unwrap().get_ref().clone();
        let path = std::env::temp_dir().join(format!(
            "qfleet-observe-killed-{}-{}.mcap",
            std::process::id(),
            bus::monotonic_ns()
        ));
        std::fs::write(&path, &bytes).unwrap();
        let r = Recording::open(&path);
        let _ = std::fs::remove_file(&path);
        let r = r.expect("salvaged");
        let cut = r.cut_short.expect("said to be cut short");
        assert_eq!(cut.file_bytes, bytes.len() as u64);
        let got = messages(&r);
        assert_eq!(got[..], sent[..got.len()], "a prefix, in order");
        // the open chunk's messages are lifted out of it: at most the last one is lost
        assert!(
            got.len() + 1 >= sent.len(),
            "{} of {}",
            got.len(),
            sent.len()
        );
        assert_eq!(r.summary().unwrap().cut_short, Some(cut));
    }

    #[test]
    fn a_finished_recording_is_not_cut_short_and_other_files_are_not_salvaged() {
        let (file, sent) = finished_recording(3);
        let r = Recording::from_bytes(file).unwrap();
        assert_eq!(r.cut_short, None);
        assert_eq!(messages(&r), sent);
        for other in [&b"type octile\nheight 3\n"[..], b""] {
            let e = Recording::from_bytes(other.to_vec())
                .err()
                .expect("not MCAP");
            assert!(e.to_string().contains("not an MCAP file"), "{e}");
        }
    }

    proptest::proptest! {
        #[test]
        fn reading_a_damaged_recording_never_panics(
            cut in 0usize..20_000,
            flips in proptest::collection::vec((0usize..20_000, proptest::num::u8::ANY), 0..8),
        ) {
            let (mut file, _) = finished_recording(20);
            for (at, b) in flips {
                let n = file.len();
                file[at % n] ^= b;
            }
            file.truncate(cut.min(file.len()));
            if let Ok(r) = Recording::from_bytes(file) {
                let _ = r.for_each(|_, _, _| Ok(()));
            }
        }
    }

    #[test]
    fn an_owned_copy_is_the_message_it_copied() {
        for m in sample_msgs() {
            assert_eq!(Owned::of(m.as_msg()), m);
        }
    }
}
