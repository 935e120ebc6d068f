//! Reading a recording back: the run's metadata and map, every message in log-time order as
//! its JSON value and as a typed message (for the live view), and a per-topic summary.

use std::collections::BTreeMap;
use std::path::Path;

use bus_schema::names::Topic;
use bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, GRANT_CAP, Grant, HINT_BATCH_CAP, Intent,
    IntentHorizon, LatencySummary, MergedHintBatch, PseudoTargetDiscovery, QHint, QHintBatch,
    REASON_LEN, Register, RobotState,
};
use mcap::records::Record;
use serde::Serialize;
use serde_json::Value;

use crate::ObserveError;
pub use crate::decode::Owned;
use crate::decode::topic_by_name;
use crate::record::{MAP_ATTACHMENT, RUN_METADATA};
use crate::stats::{TopicCounts, topic_index};

/// Largest recording `replay` reads (it is read into memory whole).
pub const MAX_RECORDING_BYTES: u64 = 8 << 30;

/// A recording read into memory.
pub struct Recording {
    bytes: Vec<u8>,
    /// The `qfleet.run` metadata (run id, map, start, goal, clock pair, settings).
    pub meta: BTreeMap<String, String>,
    /// The map attachment (MovingAI text), if present.
    pub map_text: Option<String>,
    /// Set when the recorder did not finish the file (killed, or its disk filled): what was
    /// read of it. The messages are those before the damage.
    pub cut_short: Option<CutShort>,
}

/// How much of a recording that was not finished could be read (see [`crate::salvage`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct CutShort {
    /// Bytes read from the start of the file: every complete record.
    pub read_bytes: u64,
    /// The file's size.
    pub file_bytes: u64,
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
}

impl Recording {
    /// Reads `path` (at most [`MAX_RECORDING_BYTES`]) and its metadata and map.
    pub fn open(path: &Path) -> Result<Self, ObserveError> {
        let io = |e| ObserveError::Io {
            path: path.display().to_string(),
            source: e,
        };
        let len = std::fs::metadata(path).map_err(io)?.len();
        if len > MAX_RECORDING_BYTES {
            return Err(ObserveError::Mcap(format!(
                "{} is {len} bytes, more than the {MAX_RECORDING_BYTES} replay reads",
                path.display()
            )));
        }
        let bytes = std::fs::read(path).map_err(io)?;
        // a recorder that was killed or whose disk filled left no end: read what it wrote
        // (a file that cannot be salvaged either gets the error of reading it as it is)
        if !crate::salvage::is_finished(&bytes)
            && let Some(s) = crate::salvage::salvage(&bytes)
            && let Ok(mut r) = Self::from_bytes(s.bytes)
        {
            r.cut_short = Some(CutShort {
                read_bytes: s.kept_bytes,
                file_bytes: len,
            });
            return Ok(r);
        }
        Self::from_bytes(bytes)
    }

    /// A recording from its bytes.
    pub fn from_bytes(bytes: Vec<u8>) -> Result<Self, ObserveError> {
        let mut meta = BTreeMap::new();
        let mut map_text = None;
        let mut records = mcap::read::LinearReader::new(&bytes)?;
        while let Some(rec) = undamaged(|| records.next())? {
            match rec? {
                Record::Metadata(m) if m.name == RUN_METADATA => meta = m.metadata,
                Record::Attachment { header, data, .. } if header.name == MAP_ATTACHMENT => {
                    map_text = Some(String::from_utf8_lossy(&data).into_owned());
                }
                _ => {}
            }
        }
        Ok(Self {
            bytes,
            meta,
            map_text,
            cut_short: None,
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
    /// that is not JSON is an error.
    pub fn for_each(
        &self,
        mut f: impl FnMut(u64, Topic, &Value) -> Result<(), ObserveError>,
    ) -> Result<(), ObserveError> {
        let mut messages = mcap::MessageStream::new(&self.bytes)?;
        while let Some(m) = undamaged(|| messages.next())? {
            let m = m?;
            let Some(topic) = topic_by_name(&m.channel.topic) else {
                continue;
            };
            let v: Value = serde_json::from_slice(&m.data).map_err(|e| {
                ObserveError::Mcap(format!(
                    "message {} on {} is not JSON: {e}",
                    m.sequence, m.channel.topic
                ))
            })?;
            f(m.log_time, topic, &v)?;
        }
        Ok(())
    }

    /// Counts, first/last times and rates per topic.
    pub fn summary(&self) -> Result<Summary, ObserveError> {
        let mut counts = TopicCounts::default();
        let mut names: Vec<String> = Vec::new();
        let run_id = self.meta.get("run_id").cloned().unwrap_or_default();
        self.for_each(|t, topic, _| {
            counts.add(topic, t);
            Ok(())
        })?;
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
        })
    }

    /// The `(x, y)` of metadata key `key` (`"start"`, `"goal"`).
    pub fn cell(&self, key: &str) -> Option<(u16, u16)> {
        let (x, y) = self.meta.get(key)?.split_once(',')?;
        Some((x.trim().parse().ok()?, y.trim().parse().ok()?))
    }
}

/// Runs one step of the `mcap` crate's readers, turning a panic inside it into an error: its
/// readers trust some lengths of a damaged file and overflow on them (a proptest of ours found
/// `attempt to subtract with overflow` in mcap 0.26's linear reader), and a damaged recording
/// is bad input, never a crash. The panic message is kept off the terminal while it runs.
fn undamaged<T>(step: impl FnOnce() -> T) -> Result<T, ObserveError> {
    let quiet = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(step));
    std::panic::set_hook(quiet);
    r.map_err(|_| {
        ObserveError::Mcap("the recording is damaged: the MCAP reader gave up on it".into())
    })
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
    use crate::record::{Recorder, RunInfo};
    use std::io::Cursor;

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
        use crate::salvage::{is_finished, salvage};
        let (file, sent) = finished_recording(40);
        assert!(is_finished(&file));
        let mut before = 0;
        // every cut point through the data section, a few bytes apart
        for cut in (8..file.len()).step_by(7) {
            let s = salvage(&file[..cut]).expect("starts like MCAP");
            assert!(s.kept_bytes <= cut as u64);
            let r = Recording::from_bytes(s.bytes).expect("the salvaged file reads");
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
        assert!(
            before + sample_msgs().len() >= sent.len(),
            "nearly all before the summary"
        );
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
        assert!(
            Recording::from_bytes(bytes.clone()).is_err(),
            "unreadable as it is"
        );
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
        assert_eq!(crate::salvage::salvage(b"type octile\nheight 3\n"), None);
        assert_eq!(crate::salvage::salvage(b""), None);
    }

    proptest::proptest! {
        #[test]
        fn salvaging_a_damaged_recording_never_panics(
            cut in 0usize..20_000,
            flips in proptest::collection::vec((0usize..20_000, proptest::num::u8::ANY), 0..8),
        ) {
            let (mut file, _) = finished_recording(20);
            for (at, b) in flips {
                let n = file.len();
                file[at % n] ^= b;
            }
            file.truncate(cut.min(file.len()));
            if let Some(s) = crate::salvage::salvage(&file)
                && let Ok(r) = Recording::from_bytes(s.bytes)
            {
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
