//! Every message of a run as a borrowed typed value ([`Msg`]), its JSON form, and the JSON schema
//! of each topic (what MCAP channels carry so Foxglove can decode them).
//!
//! Pure: no IO, no clock. The JSON field names are the Rust field names of `bus-schema`; padding
//! is left out, arrays with a `count` are cut to their valid entries, enumerations travel as their
//! wire number plus a readable name (`status` 1 → `"status_name": "running"`).

use bus_schema::names::Topic;
use bus_schema::{
    Command, Control, DiscoveryAck, DiscoveryRelay, FinalReport, GRANT_CAP, Grant, GridState,
    HINT_BATCH_CAP, Intent, IntentHorizon, LatencySummary, MergedHintBatch, PseudoTargetDiscovery,
    QHint, QHintBatch, Register, RobotState, RobotStatus,
};
use serde_json::{Map, Value, json};

/// One message received on one topic, borrowed from shared memory (no copy of the 3–6 KiB
/// batches).
#[derive(Debug, Clone, Copy)]
pub enum Msg<'a> {
    /// `robot/register`.
    Register(&'a Register),
    /// `robot/state`.
    State(&'a RobotState),
    /// `robot/discovery`.
    Discovery(&'a PseudoTargetDiscovery),
    /// `robot/hints`.
    Hints(&'a QHintBatch),
    /// `robot/report`.
    Report(&'a FinalReport),
    /// `coord/control`.
    Control(&'a Control),
    /// `coord/merged`.
    Merged(&'a MergedHintBatch),
    /// `coord/ack`.
    Ack(&'a DiscoveryAck),
    /// `coord/discovery`.
    Relay(&'a DiscoveryRelay),
    /// `robot/intent` (shared grid).
    Intent(&'a Intent),
    /// `coord/grant` (shared grid).
    Grant(&'a Grant),
    /// `robot/horizon` (shared grid).
    Horizon(&'a IntentHorizon),
}

/// One message as an owned value: copied out of shared memory for a thread that handles it
/// later (the recorder's encoder), or rebuilt from its JSON form (replay); the two batch types
/// are boxed (3–6 KiB each) so that small messages stay small.
#[derive(Debug, Clone, PartialEq)]
pub enum Owned {
    /// `robot/register`.
    Register(Register),
    /// `robot/state`.
    State(RobotState),
    /// `robot/discovery`.
    Discovery(PseudoTargetDiscovery),
    /// `robot/hints`.
    Hints(Box<QHintBatch>),
    /// `robot/report`.
    Report(FinalReport),
    /// `coord/control`.
    Control(Control),
    /// `coord/merged`.
    Merged(Box<MergedHintBatch>),
    /// `coord/ack`.
    Ack(DiscoveryAck),
    /// `coord/discovery`.
    Relay(DiscoveryRelay),
    /// `robot/intent`.
    Intent(Intent),
    /// `coord/grant` (1.3 KiB, boxed).
    Grant(Box<Grant>),
    /// `robot/horizon`.
    Horizon(Box<IntentHorizon>),
}

impl Owned {
    /// A copy of `m`.
    pub fn of(m: Msg<'_>) -> Self {
        match m {
            Msg::Register(x) => Self::Register(*x),
            Msg::State(x) => Self::State(*x),
            Msg::Discovery(x) => Self::Discovery(*x),
            Msg::Hints(x) => Self::Hints(Box::new(*x)),
            Msg::Report(x) => Self::Report(*x),
            Msg::Control(x) => Self::Control(*x),
            Msg::Merged(x) => Self::Merged(Box::new(*x)),
            Msg::Ack(x) => Self::Ack(*x),
            Msg::Relay(x) => Self::Relay(*x),
            Msg::Intent(x) => Self::Intent(*x),
            Msg::Grant(x) => Self::Grant(Box::new(*x)),
            Msg::Horizon(x) => Self::Horizon(Box::new(*x)),
        }
    }

    /// The copy as a borrowed message.
    pub fn as_msg(&self) -> Msg<'_> {
        match self {
            Self::Register(x) => Msg::Register(x),
            Self::State(x) => Msg::State(x),
            Self::Discovery(x) => Msg::Discovery(x),
            Self::Hints(x) => Msg::Hints(x),
            Self::Report(x) => Msg::Report(x),
            Self::Control(x) => Msg::Control(x),
            Self::Merged(x) => Msg::Merged(x),
            Self::Ack(x) => Msg::Ack(x),
            Self::Relay(x) => Msg::Relay(x),
            Self::Intent(x) => Msg::Intent(x),
            Self::Grant(x) => Msg::Grant(x),
            Self::Horizon(x) => Msg::Horizon(x),
        }
    }

    /// Bytes this copy holds (for the recorder's bound on what waits to be encoded).
    pub fn bytes(&self) -> usize {
        std::mem::size_of::<Self>()
            + match self {
                Self::Hints(_) => std::mem::size_of::<QHintBatch>(),
                Self::Merged(_) => std::mem::size_of::<MergedHintBatch>(),
                Self::Grant(_) => std::mem::size_of::<Grant>(),
                Self::Horizon(_) => std::mem::size_of::<IntentHorizon>(),
                _ => 0,
            }
    }
}

impl Msg<'_> {
    /// The topic this message travels on.
    pub fn topic(&self) -> Topic {
        match self {
            Msg::Register(_) => Topic::Register,
            Msg::State(_) => Topic::RobotState,
            Msg::Discovery(_) => Topic::Discovery,
            Msg::Hints(_) => Topic::Hints,
            Msg::Report(_) => Topic::Report,
            Msg::Control(_) => Topic::Control,
            Msg::Merged(_) => Topic::Merged,
            Msg::Ack(_) => Topic::Ack,
            Msg::Relay(_) => Topic::Relay,
            Msg::Intent(_) => Topic::Intent,
            Msg::Grant(_) => Topic::Grant,
            Msg::Horizon(_) => Topic::Horizon,
        }
    }

    /// The message as a JSON object (see the module doc for the conventions).
    pub fn to_json(&self) -> Value {
        match *self {
            Msg::Register(m) => json!({
                "schema_version": m.schema_version, "robot_id": m.robot_id, "pid": m.pid,
                "episodes": m.episodes, "width": m.width, "height": m.height,
                "start_x": m.start_x, "start_y": m.start_y, "map_hash": m.map_hash,
                "seed": m.seed, "send_time_ns": m.send_time_ns,
            }),
            Msg::State(m) => json!({
                "robot_id": m.robot_id, "goal_id": m.goal_id, "episode": m.episode,
                "step": m.step, "last_episode_steps": m.last_episode_steps,
                "cell_x": m.cell_x, "cell_y": m.cell_y, "status": m.status,
                "status_name": status_name(m.status), "seq": m.seq,
                "send_time_ns": m.send_time_ns,
            }),
            Msg::Discovery(m) => json!({
                "robot_id": m.robot_id, "goal_id": m.goal_id, "cell_x": m.cell_x,
                "cell_y": m.cell_y, "value": finite(f64::from(m.value)), "seq": m.seq,
                "time_ns": m.time_ns, "episode": m.episode, "send_time_ns": m.send_time_ns,
            }),
            Msg::Hints(m) => json!({
                "robot_id": m.robot_id, "goal_id": m.goal_id, "count": m.count, "seq": m.seq,
                "oldest_update_ns": m.oldest_update_ns, "send_time_ns": m.send_time_ns,
                "entries": entries_json(&m.entries[..used(m.count)], None),
            }),
            Msg::Report(m) => json!({
                "robot_id": m.robot_id, "schema_version": m.schema_version,
                "goal_id": m.goal_id, "episodes": m.episodes,
                "final_path_len": m.final_path_len, "optimal_path_len": m.optimal_path_len,
                "first_optimal_episode": m.first_optimal_episode, "max_steps": m.max_steps,
                "status": m.status, "status_name": status_name(m.status),
                "avg_steps": finite(m.avg_steps), "env_steps": m.env_steps,
                "elapsed_ns": m.elapsed_ns, "discoveries_sent": m.discoveries_sent,
                "discoveries_acked": m.discoveries_acked, "hints_sent": m.hints_sent,
                "hints_received": m.hints_received, "hints_applied": m.hints_applied,
                "merged_latency": latency_json(&m.merged_latency),
                "send_time_ns": m.send_time_ns,
            }),
            Msg::Control(m) => {
                let n = (m.reason_len as usize).min(m.reason.len());
                json!({
                    "command": m.command, "command_name": command_name(m.command),
                    "robot_id": m.robot_id, "goal_id": m.goal_id, "goal_x": m.goal_x,
                    "goal_y": m.goal_y, "phase": m.phase, "episodes": m.episodes,
                    "schema_version": m.schema_version, "seq": m.seq, "time_ns": m.time_ns,
                    "reason": String::from_utf8_lossy(&m.reason[..n]),
                })
            }
            Msg::Merged(m) => {
                let n = used(m.count);
                json!({
                    "coordinator_seq": m.coordinator_seq, "goal_id": m.goal_id,
                    "count": m.count, "oldest_origin_ns": m.oldest_origin_ns,
                    "send_time_ns": m.send_time_ns,
                    "entries": entries_json(&m.entries[..n], Some((&m.origin_ns[..n], &m.origin_robot[..n]))),
                })
            }
            Msg::Ack(m) => json!({
                "robot_id": m.robot_id, "up_to_seq": m.up_to_seq, "time_ns": m.time_ns,
            }),
            Msg::Relay(m) => json!({
                "relay_seq": m.relay_seq, "origin_robot": m.origin_robot, "goal_id": m.goal_id,
                "cell_x": m.cell_x, "cell_y": m.cell_y, "value": finite(f64::from(m.value)),
                "origin_seq": m.origin_seq, "origin_ns": m.origin_ns,
                "send_time_ns": m.send_time_ns,
            }),
            Msg::Intent(m) => {
                let n = usize::from(m.count).min(m.ranked.len());
                json!({
                    "robot_id": m.robot_id, "tick": m.tick, "cell_x": m.cell_x,
                    "cell_y": m.cell_y, "count": m.count, "ranked": &m.ranked[..n],
                    "send_time_ns": m.send_time_ns,
                })
            }
            Msg::Grant(m) => {
                let n = (m.robots as usize).min(GRANT_CAP);
                let cells: Vec<Value> = (0..n)
                    .map(|i| json!({"x": m.cell_x[i], "y": m.cell_y[i], "present": m.present[i]}))
                    .collect();
                json!({
                    "tick": m.tick, "robots": m.robots, "state": m.state,
                    "state_name": grid_state_name(m.state), "seq": m.seq,
                    "send_time_ns": m.send_time_ns, "cells": cells,
                })
            }
            Msg::Horizon(m) => {
                let n = horizon_len(m.radius);
                json!({
                    "robot_id": m.robot_id, "tick": m.tick, "cell_x": m.cell_x,
                    "cell_y": m.cell_y, "radius": m.radius, "ranked": &m.ranked[..n],
                    "send_time_ns": m.send_time_ns,
                })
            }
        }
    }
}

/// Meaningful entries of an `IntentHorizon` of `radius` (the diamond's cells, at most the
/// array's capacity).
fn horizon_len(radius: u8) -> usize {
    let r = usize::from(radius);
    (2 * r * r + 2 * r + 1).min(bus_schema::HORIZON_CELLS)
}

/// The readable name of a `GridState` byte (`"unknown"` for a value outside the contract).
pub fn grid_state_name(state: u8) -> &'static str {
    match GridState::try_from(state) {
        Ok(GridState::Moving) => "moving",
        Ok(GridState::Arrived) => "arrived",
        Ok(GridState::Ended) => "ended",
        Err(_) => "unknown",
    }
}

fn used(count: u32) -> usize {
    (count as usize).min(HINT_BATCH_CAP)
}

/// A float as JSON; NaN and infinities (which JSON cannot hold) become `null`.
fn finite(v: f64) -> Value {
    serde_json::Number::from_f64(v).map_or(Value::Null, Value::Number)
}

fn entries_json(entries: &[QHint], origin: Option<(&[u64], &[u32])>) -> Value {
    let v = entries
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let mut o = Map::new();
            o.insert("cell".into(), e.cell.into());
            o.insert("action".into(), e.action.into());
            o.insert("visits".into(), e.visits.into());
            o.insert("q".into(), finite(f64::from(e.q)));
            if let Some((ns, robot)) = origin {
                o.insert("origin_ns".into(), ns[i].into());
                o.insert("origin_robot".into(), robot[i].into());
            }
            Value::Object(o)
        })
        .collect();
    Value::Array(v)
}

fn latency_json(l: &LatencySummary) -> Value {
    json!({
        "count": l.count, "min_ns": l.min_ns, "mean_ns": l.mean_ns, "p50_ns": l.p50_ns,
        "p90_ns": l.p90_ns, "p99_ns": l.p99_ns, "p999_ns": l.p999_ns, "max_ns": l.max_ns,
    })
}

/// The readable name of a `RobotStatus` byte (`"unknown"` for a value outside the contract).
pub fn status_name(status: u8) -> &'static str {
    match RobotStatus::try_from(status) {
        Ok(RobotStatus::Waiting) => "waiting",
        Ok(RobotStatus::Running) => "running",
        Ok(RobotStatus::EpisodeDone) => "episode_done",
        Ok(RobotStatus::Finished) => "finished",
        Ok(RobotStatus::Failed) => "failed",
        Err(_) => "unknown",
    }
}

/// The readable name of a `Command` byte (`"unknown"` for a value outside the contract).
pub fn command_name(command: u8) -> &'static str {
    match Command::try_from(command) {
        Ok(Command::Start) => "start",
        Ok(Command::Stop) => "stop",
        Ok(Command::AssignGoal) => "assign_goal",
        Ok(Command::Phase) => "phase",
        Ok(Command::Ack) => "ack",
        Ok(Command::Refuse) => "refuse",
        Ok(Command::Execute) => "execute",
        Err(_) => "unknown",
    }
}

/// JSON type of one field in a topic's schema.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ty {
    Int,
    Num,
    Str,
    Entries,
    MergedEntries,
    Latency,
    Ranked,
    Cells,
}

/// The fields of each topic's JSON form, in order, with their JSON types.
fn fields(topic: Topic) -> &'static [(&'static str, Ty)] {
    use Ty::*;
    match topic {
        Topic::Register => &[
            ("schema_version", Int),
            ("robot_id", Int),
            ("pid", Int),
            ("episodes", Int),
            ("width", Int),
            ("height", Int),
            ("start_x", Int),
            ("start_y", Int),
            ("map_hash", Int),
            ("seed", Int),
            ("send_time_ns", Int),
        ],
        Topic::RobotState => &[
            ("robot_id", Int),
            ("goal_id", Int),
            ("episode", Int),
            ("step", Int),
            ("last_episode_steps", Int),
            ("cell_x", Int),
            ("cell_y", Int),
            ("status", Int),
            ("status_name", Str),
            ("seq", Int),
            ("send_time_ns", Int),
        ],
        Topic::Discovery => &[
            ("robot_id", Int),
            ("goal_id", Int),
            ("cell_x", Int),
            ("cell_y", Int),
            ("value", Num),
            ("seq", Int),
            ("time_ns", Int),
            ("episode", Int),
            ("send_time_ns", Int),
        ],
        Topic::Hints => &[
            ("robot_id", Int),
            ("goal_id", Int),
            ("count", Int),
            ("seq", Int),
            ("oldest_update_ns", Int),
            ("send_time_ns", Int),
            ("entries", Entries),
        ],
        Topic::Report => &[
            ("robot_id", Int),
            ("schema_version", Int),
            ("goal_id", Int),
            ("episodes", Int),
            ("final_path_len", Int),
            ("optimal_path_len", Int),
            ("first_optimal_episode", Int),
            ("max_steps", Int),
            ("status", Int),
            ("status_name", Str),
            ("avg_steps", Num),
            ("env_steps", Int),
            ("elapsed_ns", Int),
            ("discoveries_sent", Int),
            ("discoveries_acked", Int),
            ("hints_sent", Int),
            ("hints_received", Int),
            ("hints_applied", Int),
            ("merged_latency", Latency),
            ("send_time_ns", Int),
        ],
        Topic::Control => &[
            ("command", Int),
            ("command_name", Str),
            ("robot_id", Int),
            ("goal_id", Int),
            ("goal_x", Int),
            ("goal_y", Int),
            ("phase", Int),
            ("episodes", Int),
            ("schema_version", Int),
            ("seq", Int),
            ("time_ns", Int),
            ("reason", Str),
        ],
        Topic::Merged => &[
            ("coordinator_seq", Int),
            ("goal_id", Int),
            ("count", Int),
            ("oldest_origin_ns", Int),
            ("send_time_ns", Int),
            ("entries", MergedEntries),
        ],
        Topic::Ack => &[("robot_id", Int), ("up_to_seq", Int), ("time_ns", Int)],
        Topic::Relay => &[
            ("relay_seq", Int),
            ("origin_robot", Int),
            ("goal_id", Int),
            ("cell_x", Int),
            ("cell_y", Int),
            ("value", Num),
            ("origin_seq", Int),
            ("origin_ns", Int),
            ("send_time_ns", Int),
        ],
        Topic::Intent => &[
            ("robot_id", Int),
            ("tick", Int),
            ("cell_x", Int),
            ("cell_y", Int),
            ("count", Int),
            ("ranked", Ranked),
            ("send_time_ns", Int),
        ],
        Topic::Horizon => &[
            ("robot_id", Int),
            ("tick", Int),
            ("cell_x", Int),
            ("cell_y", Int),
            ("radius", Int),
            ("ranked", Ranked),
            ("send_time_ns", Int),
        ],
        Topic::Grant => &[
            ("tick", Int),
            ("robots", Int),
            ("state", Int),
            ("state_name", Str),
            ("seq", Int),
            ("send_time_ns", Int),
            ("cells", Cells),
        ],
    }
}

fn object_schema(props: &[(&str, Value)]) -> Value {
    let mut p = Map::new();
    for (k, v) in props {
        p.insert((*k).to_string(), v.clone());
    }
    let required: Vec<&str> = props.iter().map(|(k, _)| *k).collect();
    json!({"type": "object", "properties": p, "required": required})
}

fn ty_schema(ty: Ty) -> Value {
    let int = json!({"type": "integer"});
    let num = json!({"type": ["number", "null"]});
    match ty {
        Ty::Int => int,
        Ty::Num => num,
        Ty::Str => json!({"type": "string"}),
        Ty::Entries | Ty::MergedEntries => {
            let mut e = vec![
                (
                    "cell",
                    json!({"type": "integer", "description": "row-major y * width + x"}),
                ),
                (
                    "action",
                    json!({"type": "integer", "description": "0 up, 1 right, 2 down, 3 left"}),
                ),
                ("visits", int.clone()),
                ("q", num),
            ];
            if ty == Ty::MergedEntries {
                e.push(("origin_ns", int.clone()));
                e.push(("origin_robot", int));
            }
            json!({"type": "array", "items": object_schema(&e)})
        }
        Ty::Ranked => json!({
            "type": "array",
            "items": {"type": "integer", "description": "0 wait, 1 up, 2 right, 3 down, 4 left"},
        }),
        Ty::Cells => json!({
            "type": "array",
            "items": object_schema(&[("x", int.clone()), ("y", int.clone()), ("present", int)]),
        }),
        Ty::Latency => object_schema(
            &[
                "count", "min_ns", "mean_ns", "p50_ns", "p90_ns", "p99_ns", "p999_ns", "max_ns",
            ]
            .map(|k| (k, json!({"type": "integer"}))),
        ),
    }
}

/// The JSON schema (draft 2020-12) of `topic`'s JSON form, with its type name as the title.
pub fn json_schema(topic: Topic) -> Value {
    let props: Vec<(&str, Value)> = fields(topic)
        .iter()
        .map(|&(k, ty)| (k, ty_schema(ty)))
        .collect();
    let mut s = object_schema(&props);
    if let Value::Object(o) = &mut s {
        o.insert(
            "$schema".into(),
            "https://json-schema.org/draft/2020-12/schema".into(),
        );
        o.insert("title".into(), topic.type_name().into());
    }
    s
}

/// The topic whose path (`robot/state`) or full service name (`qfleet/<run>/robot/state`) is
/// `name`, if any.
pub fn topic_by_name(name: &str) -> Option<Topic> {
    Topic::ALL
        .into_iter()
        .find(|t| name == t.path() || name.ends_with(&format!("/{}", t.path())))
}

/// The topic `name` names, or the refusal listing every topic (`qfleet topic … TOPIC`).
pub fn topic_named(name: &str) -> Result<Topic, String> {
    topic_by_name(name).ok_or_else(|| {
        let all: Vec<&str> = Topic::ALL.iter().map(|t| t.path()).collect();
        format!("unknown topic {name:?}; the topics are {}", all.join(", "))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unknown_topic_is_refused_with_the_list() {
        assert_eq!(
            topic_named("robot/state"),
            Ok(Topic::ALL[topic_index_of("robot/state")])
        );
        let e = topic_named("robot/nope").unwrap_err();
        assert!(
            e.starts_with("unknown topic \"robot/nope\"; the topics are "),
            "{e}"
        );
        assert!(e.contains("robot/state"), "{e}");
    }

    fn topic_index_of(path: &str) -> usize {
        Topic::ALL.iter().position(|t| t.path() == path).unwrap()
    }

    fn check_against_schema(topic: Topic, v: &Value) {
        let schema = json_schema(topic);
        let props = schema["properties"].as_object().unwrap();
        let obj = v.as_object().unwrap();
        let mut got: Vec<&String> = obj.keys().collect();
        let mut want: Vec<&String> = props.keys().collect();
        got.sort();
        want.sort();
        assert_eq!(got, want, "{topic:?}: JSON keys vs schema properties");
        for (k, p) in props {
            let t = &p["type"];
            let val = &obj[k];
            let ok = match t.as_str() {
                Some("integer") => val.is_u64() || val.is_i64(),
                Some("string") => val.is_string(),
                Some("array") => val.is_array(),
                Some("object") => val.is_object(),
                _ => val.is_number() || val.is_null(),
            };
            assert!(ok, "{topic:?}.{k} = {val} does not match {t}");
        }
    }

    #[test]
    fn every_topic_decodes_to_exactly_its_schema() {
        let mut hints = QHintBatch {
            count: 2,
            ..QHintBatch::ZEROED
        };
        hints.entries[1] = QHint {
            cell: 7,
            action: 3,
            visits: 2,
            q: 0.5,
            ..QHint::ZEROED
        };
        let mut merged = MergedHintBatch {
            count: 1,
            ..MergedHintBatch::ZEROED
        };
        merged.origin_robot[0] = 3;
        let mut control = Control {
            command: Command::Refuse.as_u8(),
            reason_len: 2,
            ..Control::ZEROED
        };
        control.reason[..2].copy_from_slice(b"no");
        let report = FinalReport {
            avg_steps: f64::NAN,
            ..FinalReport::ZEROED
        };
        let msgs = [
            Msg::Register(&Register::ZEROED),
            Msg::State(&RobotState::ZEROED),
            Msg::Discovery(&PseudoTargetDiscovery::ZEROED),
            Msg::Hints(&hints),
            Msg::Report(&report),
            Msg::Control(&control),
            Msg::Merged(&merged),
            Msg::Ack(&DiscoveryAck::ZEROED),
            Msg::Relay(&DiscoveryRelay::ZEROED),
        ];
        for m in msgs {
            let v = m.to_json();
            check_against_schema(m.topic(), &v);
            for key in ["entries"] {
                if let Some(a) = v.get(key).and_then(|a| a.as_array()) {
                    let item_props =
                        json_schema(m.topic())["properties"][key]["items"]["properties"]
                            .as_object()
                            .unwrap()
                            .len();
                    for e in a {
                        assert_eq!(e.as_object().unwrap().len(), item_props);
                    }
                }
            }
        }
        // only the valid entries travel; NaN becomes null; text is cut at reason_len
        assert_eq!(
            Msg::Hints(&hints).to_json()["entries"]
                .as_array()
                .unwrap()
                .len(),
            2
        );
        assert_eq!(Msg::Hints(&hints).to_json()["entries"][1]["cell"], 7);
        assert_eq!(
            Msg::Merged(&merged).to_json()["entries"][0]["origin_robot"],
            3
        );
        assert!(Msg::Report(&report).to_json()["avg_steps"].is_null());
        assert_eq!(Msg::Control(&control).to_json()["reason"], "no");
        assert_eq!(Msg::Control(&control).to_json()["command_name"], "refuse");
    }

    #[test]
    fn a_count_beyond_the_capacity_is_cut_not_a_panic() {
        let hints = QHintBatch {
            count: u32::MAX,
            ..QHintBatch::ZEROED
        };
        let n = Msg::Hints(&hints).to_json()["entries"]
            .as_array()
            .unwrap()
            .len();
        assert_eq!(n, HINT_BATCH_CAP);
        let c = Control {
            reason_len: u32::MAX,
            ..Control::ZEROED
        };
        assert_eq!(Msg::Control(&c).to_json()["command_name"], "unknown");
    }

    #[test]
    fn topics_are_found_by_path_or_service_name() {
        assert_eq!(topic_by_name("robot/state"), Some(Topic::RobotState));
        assert_eq!(
            topic_by_name("qfleet/r1/coord/discovery"),
            Some(Topic::Relay)
        );
        assert_eq!(topic_by_name("robot/nothing"), None);
        for t in Topic::ALL {
            assert_eq!(json_schema(t)["title"], t.type_name());
        }
    }
}
