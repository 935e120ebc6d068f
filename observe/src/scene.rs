//! A run in Foxglove's well-known schemas: the map as a `foxglove.Grid`, the robots, their
//! greedy paths and the goals/discoveries as `foxglove.SceneUpdate`s, a `foxglove.FrameTransform`
//! that centres the map in the 3D panel, per-robot numbers for the Plot panel and the
//! coordinator's commands as `foxglove.Log` lines. The recorder ([`crate::record`]) and the
//! WebSocket server ([`crate::foxglove`]) both write what this builds.
//!
//! Pure: no IO, no clock. State in ([`Scene::apply`] with each message of the run), JSON
//! messages out ([`SceneMsg`]), JSON encoding (`json` message encoding, `jsonschema` schemas).
//!
//! Frames: `map` has x along the map's columns and y up, z up, one unit per cell, its origin
//! at the map's bottom-left corner: cell (x, y) of the map file (row y from the top) is the
//! unit square whose centre is (x + 0.5, height − y − 0.5), so the map reads as in the file
//! when seen from above. `world` is the 3D panel's root; the transform `world` → `map` puts
//! the map's centre at the world's origin, where the panel's camera looks first.

use std::collections::{BTreeMap, VecDeque};

use bus_schema::{Command, RobotStatus};
use planner::grid::{Cell, Grid};
use serde_json::{Value, json};

use crate::decode::{Msg, command_name, status_name};
use crate::view::ViewModel;

/// The root frame of the scene.
pub const FRAME_WORLD: &str = "world";
/// The map's frame (see the module doc).
pub const FRAME_MAP: &str = "map";

/// The Foxglove channels a run is shown on, besides its raw topics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Channel {
    /// `/tf`: `world` → `map` (`foxglove.FrameTransform`), once at the start.
    Tf,
    /// `/map`: the map (`foxglove.Grid`), once at the start.
    Map,
    /// `/robots`: a cube and an id label per robot at its cell (`foxglove.SceneUpdate`).
    Robots,
    /// `/paths`: each robot's greedy path, or its trail while it has none
    /// (`foxglove.SceneUpdate`).
    Paths,
    /// `/markers`: starts, goals and relayed discoveries (`foxglove.SceneUpdate`).
    Markers,
    /// `/robot_stats`: per-robot numbers for the Plot panel (`qfleet.RobotStats`).
    Stats,
    /// `/log`: the coordinator's commands and the robots' final reports (`foxglove.Log`).
    Log,
}

impl Channel {
    /// Every channel, in advertising order.
    pub const ALL: [Channel; 7] = [
        Channel::Tf,
        Channel::Map,
        Channel::Robots,
        Channel::Paths,
        Channel::Markers,
        Channel::Stats,
        Channel::Log,
    ];

    /// The topic name.
    pub fn topic(self) -> &'static str {
        match self {
            Channel::Tf => "/tf",
            Channel::Map => "/map",
            Channel::Robots => "/robots",
            Channel::Paths => "/paths",
            Channel::Markers => "/markers",
            Channel::Stats => "/robot_stats",
            Channel::Log => "/log",
        }
    }

    /// The schema name (Foxglove's well-known names, or `qfleet.RobotStats`).
    pub fn schema_name(self) -> &'static str {
        match self {
            Channel::Tf => "foxglove.FrameTransform",
            Channel::Map => "foxglove.Grid",
            Channel::Robots | Channel::Paths | Channel::Markers => "foxglove.SceneUpdate",
            Channel::Stats => "qfleet.RobotStats",
            Channel::Log => "foxglove.Log",
        }
    }

    /// Whether a client that subscribes late should get the channel's latest messages at once
    /// (the map, the transform and the scene's entities: state, not events).
    pub fn latched(self) -> bool {
        !matches!(self, Channel::Stats | Channel::Log)
    }

    /// The channel's JSON schema (`jsonschema` encoding).
    pub fn schema(self) -> Value {
        let mut s = match self {
            Channel::Tf => frame_transform_schema(),
            Channel::Map => grid_schema(),
            Channel::Robots | Channel::Paths | Channel::Markers => scene_update_schema(),
            Channel::Stats => stats_schema(),
            Channel::Log => log_schema(),
        };
        s["title"] = json!(self.schema_name());
        s
    }
}

/// One message built by a [`Scene`].
#[derive(Debug, Clone, PartialEq)]
pub struct SceneMsg {
    /// Where it goes.
    pub channel: Channel,
    /// What it replaces on a latched channel: the entity id (`robot-3`), or the channel name
    /// for a channel of one message.
    pub key: String,
    /// The message.
    pub json: Value,
}

/// Cells of a robot's trail kept (shown while it has no greedy path).
pub const TRAIL_CELLS: usize = 64;
/// Least time between two path updates of one robot, ns of message time: a path recomputed on
/// every hint batch would cost more than it shows.
pub const PATH_EVERY_NS: u64 = 200_000_000;

/// What was last sent about one robot.
#[derive(Debug, Clone, Default)]
struct Sent {
    cell: Option<Cell>,
    status: u8,
    path: Vec<Cell>,
    path_at_ns: u64,
    path_dirty: bool,
    trail: VecDeque<Cell>,
    stats_episode: Option<u32>,
    last_episode_steps: Option<u32>,
    hint_latency_ns: Option<u64>,
}

/// The scene of one run: a [`ViewModel`] plus what was last sent, so only changes go out.
#[derive(Debug, Clone)]
pub struct Scene {
    vm: ViewModel,
    sent: Vec<Sent>,
    goals_sent: BTreeMap<u32, Cell>,
    starts_sent: Vec<Cell>,
    discovered_sent: BTreeMap<u32, usize>,
}

impl Scene {
    /// The scene of a run on `grid` whose robots start at `start` towards `goal` (goal id 0)
    /// until their own registrations and goal assignments say otherwise.
    pub fn new(map_name: &str, grid: Grid, start: Cell, goal: Cell) -> Self {
        Self {
            vm: ViewModel::new(map_name, grid, start, goal),
            sent: Vec::new(),
            goals_sent: BTreeMap::new(),
            starts_sent: Vec::new(),
            discovered_sent: BTreeMap::new(),
        }
    }

    /// The model behind it.
    pub fn view(&self) -> &ViewModel {
        &self.vm
    }

    /// The messages of the start of the run (log time `t_ns`, wall ns): the transform, the
    /// map, the task's start and goal.
    pub fn start(&mut self, t_ns: u64, out: &mut Vec<SceneMsg>) {
        out.push(SceneMsg {
            channel: Channel::Tf,
            key: Channel::Tf.topic().into(),
            json: self.frame_transform(t_ns),
        });
        out.push(SceneMsg {
            channel: Channel::Map,
            key: Channel::Map.topic().into(),
            json: grid_json(&self.vm.grid, t_ns),
        });
        self.markers(t_ns, out);
    }

    /// Feeds one message of the run, logged at `t_ns` (wall ns) and received at `recv_ns`
    /// (monotonic ns, the clock of the messages' own times); pushes what changed to `out`.
    /// Ids, cells and counts out of range are ignored, never a panic.
    pub fn apply(&mut self, t_ns: u64, recv_ns: u64, msg: Msg<'_>, out: &mut Vec<SceneMsg>) {
        self.vm.apply(recv_ns, msg);
        match msg {
            Msg::Register(m) => {
                self.robot_moved(t_ns, m.robot_id, out);
                self.markers(t_ns, out);
            }
            Msg::State(m) => {
                let id = m.robot_id;
                let cell = cell_in(&self.vm.grid, m.cell_x, m.cell_y);
                if let Some(s) = self.sent_mut(id)
                    && m.last_episode_steps > 0
                {
                    s.last_episode_steps = Some(m.last_episode_steps);
                }
                if let Some(s) = self.sent_mut(id)
                    && let Some(c) = cell
                    && s.trail.back() != Some(&c)
                {
                    if s.trail.len() == TRAIL_CELLS {
                        s.trail.pop_front();
                    }
                    s.trail.push_back(c);
                    s.path_dirty = true;
                }
                self.robot_moved(t_ns, id, out);
                self.stats(t_ns, id, None, out);
            }
            Msg::Hints(m) => {
                let id = m.robot_id;
                if let Some(s) = self.sent_mut(id) {
                    s.path_dirty = true;
                    if m.oldest_update_ns > 0 {
                        s.hint_latency_ns = Some(recv_ns.saturating_sub(m.oldest_update_ns));
                    }
                }
            }
            Msg::Merged(_) => {
                // robots without a table of their own follow the fleet's for their goal
                for s in self.sent.iter_mut() {
                    s.path_dirty = true;
                }
            }
            Msg::Report(m) => {
                let id = m.robot_id;
                if let Some(s) = self.sent_mut(id) {
                    s.path_at_ns = 0;
                    s.path_dirty = true;
                }
                self.robot_moved(t_ns, id, out);
                self.stats(t_ns, id, Some(m), out);
                let name = status_name(m.status);
                let path = match m.final_path_len {
                    l if l >= 0 => format!("greedy path {l} moves"),
                    _ => "no greedy path to the goal".to_string(),
                };
                out.push(log_msg(
                    t_ns,
                    if m.status == RobotStatus::Failed.as_u8() {
                        4
                    } else {
                        2
                    },
                    &format!("robot-{id}"),
                    &format!("robot {id} {name} after {} episodes, {path}", m.episodes),
                ));
            }
            Msg::Control(m) => {
                let cmd = command_name(m.command);
                let who = if m.robot_id == bus_schema::ROBOT_ID_ALL {
                    "all robots".to_string()
                } else {
                    format!("robot {}", m.robot_id)
                };
                let text = match Command::try_from(m.command) {
                    Ok(Command::AssignGoal) => format!(
                        "assign goal {} at ({}, {}) to {who}",
                        m.goal_id, m.goal_x, m.goal_y
                    ),
                    Ok(Command::Phase) => format!("phase {} ({} episodes)", m.phase, m.episodes),
                    Ok(Command::Refuse) => {
                        let n = (m.reason_len as usize).min(m.reason.len());
                        format!("refuse {who}: {}", String::from_utf8_lossy(&m.reason[..n]))
                    }
                    _ => format!("{cmd} {who}"),
                };
                let level = if m.command == Command::Refuse.as_u8() {
                    3
                } else {
                    2
                };
                out.push(log_msg(t_ns, level, "coordinator", &text));
                self.markers(t_ns, out);
            }
            Msg::Relay(_) => self.markers(t_ns, out),
            // positions come from `robot/state` alone (in a shared grid too: robots keep
            // publishing their cell there tick by tick)
            Msg::Discovery(_) | Msg::Ack(_) | Msg::Intent(_) | Msg::Horizon(_) | Msg::Grant(_) => {}
        }
        self.paths(t_ns, out);
    }

    /// The send record of robot `id`, grown to it (none for an id the view ignores).
    fn sent_mut(&mut self, id: u32) -> Option<&mut Sent> {
        if id as usize >= self.vm.robots.len() {
            return None;
        }
        while self.sent.len() < self.vm.robots.len() {
            self.sent.push(Sent::default());
        }
        self.sent.get_mut(id as usize)
    }

    /// A robot's entity when its cell or status changed since it was last sent.
    fn robot_moved(&mut self, t_ns: u64, id: u32, out: &mut Vec<SceneMsg>) {
        let Some(r) = self.vm.robots.get(id as usize) else {
            return;
        };
        let (cell, status) = (r.cell.or(r.start), r.status);
        let Some(s) = self.sent_mut(id) else {
            return;
        };
        if s.cell == cell && s.status == status {
            return;
        }
        s.cell = cell;
        s.status = status;
        let Some(c) = cell else {
            return;
        };
        let h = self.vm.grid.height();
        let (x, y) = centre(h, c);
        let done = status == RobotStatus::Finished.as_u8() || status == RobotStatus::Failed.as_u8();
        let rgb = palette(id);
        let a = if done { 0.5 } else { 1.0 };
        let entity = json!({
            "timestamp": time(t_ns), "frame_id": FRAME_MAP, "id": format!("robot-{id}"),
            "lifetime": time(0), "frame_locked": false,
            "metadata": [
                {"key": "robot_id", "value": id.to_string()},
                {"key": "cell", "value": format!("{},{}", c.x, c.y)},
                {"key": "status", "value": status_name(status)},
            ],
            "arrows": [], "spheres": [], "cylinders": [], "lines": [], "triangles": [], "models": [],
            "cubes": [cube(x, y, 0.35, 0.7, 0.7, 0.7, rgb, a)],
            "texts": [text(x, y, 1.1, &id.to_string(), [1.0, 1.0, 1.0], 1.0)],
        });
        out.push(update(Channel::Robots, format!("robot-{id}"), entity));
    }

    /// The stats line of robot `id`: once per episode seen to end, and at its report.
    fn stats(
        &mut self,
        t_ns: u64,
        id: u32,
        report: Option<&bus_schema::FinalReport>,
        out: &mut Vec<SceneMsg>,
    ) {
        let Some(r) = self.vm.robots.get(id as usize).cloned() else {
            return;
        };
        let path = self.vm.greedy_path(id);
        let goal = self.vm.goals.get(&r.goal_id).copied();
        let path_len = (path.len() > 1 && path.last().copied() == goal).then(|| path.len() - 1);
        let Some(s) = self.sent_mut(id) else {
            return;
        };
        // the step count of the episode that just ended travels with the next state
        let ended = r.episode.checked_sub(1);
        if report.is_none()
            && (ended.is_none() || s.stats_episode == ended || s.last_episode_steps.is_none())
        {
            return;
        }
        s.stats_episode = ended;
        let ms = |ns: u64| ns as f64 / 1e6;
        let mut v = json!({
            "timestamp": time(t_ns),
            "robot_id": id,
            "goal_id": r.goal_id,
            "episode": r.episode,
            "status": status_name(r.status),
            "avg_steps": r.avg_steps.and_then(finite),
            "greedy_path_len": path_len,
            "hint_latency_ms": s.hint_latency_ns.map(ms),
        });
        if let Some(m) = report {
            v["final_path_len"] = (m.final_path_len >= 0).then_some(m.final_path_len).into();
            v["loop_latency_p50_ms"] = (m.merged_latency.count > 0)
                .then(|| ms(m.merged_latency.p50_ns))
                .into();
        } else {
            v["last_episode_steps"] = s.last_episode_steps.into();
        }
        out.push(SceneMsg {
            channel: Channel::Stats,
            key: format!("robot-{id}"),
            json: v,
        });
    }

    /// Path updates of the robots whose path may have changed, at most one per robot per
    /// [`PATH_EVERY_NS`].
    fn paths(&mut self, t_ns: u64, out: &mut Vec<SceneMsg>) {
        let h = self.vm.grid.height();
        for id in 0..self.sent.len() as u32 {
            let due = {
                let s = &self.sent[id as usize];
                s.path_dirty && t_ns.saturating_sub(s.path_at_ns) >= PATH_EVERY_NS
            };
            if !due {
                continue;
            }
            let greedy = self.vm.greedy_path(id);
            let s = &mut self.sent[id as usize];
            s.path_dirty = false;
            s.path_at_ns = t_ns;
            let (cells, kind): (Vec<Cell>, &str) = if greedy.len() > 1 {
                (greedy, "greedy")
            } else {
                (s.trail.iter().copied().collect(), "trail")
            };
            if cells == s.path || cells.len() < 2 {
                continue;
            }
            s.path = cells;
            let rgb = palette(id);
            let points: Vec<Value> = s
                .path
                .iter()
                .map(|&c| {
                    let (x, y) = centre(h, c);
                    json!({"x": x, "y": y, "z": 0.05})
                })
                .collect();
            let line = json!({
                "type": 0, "pose": pose(0.0, 0.0, 0.0), "thickness": if kind == "greedy" { 0.15 } else { 0.06 },
                "scale_invariant": false, "points": points,
                "color": color(rgb, if kind == "greedy" { 0.9 } else { 0.5 }),
                "colors": [], "indices": [],
            });
            let entity = json!({
                "timestamp": time(t_ns), "frame_id": FRAME_MAP, "id": format!("path-{id}"),
                "lifetime": time(0), "frame_locked": false,
                "metadata": [
                    {"key": "robot_id", "value": id.to_string()},
                    {"key": "kind", "value": kind},
                    {"key": "cells", "value": s.path.len().to_string()},
                ],
                "arrows": [], "cubes": [], "spheres": [], "cylinders": [], "triangles": [],
                "texts": [], "models": [], "lines": [line],
            });
            out.push(update(Channel::Paths, format!("path-{id}"), entity));
        }
    }

    /// Start, goal and discovery markers that changed since they were last sent.
    fn markers(&mut self, t_ns: u64, out: &mut Vec<SceneMsg>) {
        let h = self.vm.grid.height();
        let mut starts: Vec<Cell> = self.vm.robots.iter().filter_map(|r| r.start).collect();
        starts.sort_by_key(|c| (c.y, c.x));
        starts.dedup();
        if starts.is_empty() {
            starts = self
                .vm
                .robots
                .first()
                .and_then(|r| r.start)
                .into_iter()
                .collect();
        }
        if starts != self.starts_sent && !starts.is_empty() {
            self.starts_sent = starts.clone();
            let cubes: Vec<Value> = starts
                .iter()
                .map(|&c| {
                    let (x, y) = centre(h, c);
                    cube(x, y, 0.02, 0.9, 0.9, 0.04, [0.3, 0.5, 1.0], 0.8)
                })
                .collect();
            out.push(update(
                Channel::Markers,
                "starts".into(),
                entity("starts", t_ns, cubes, Vec::new()),
            ));
        }
        for (&gid, &c) in &self.vm.goals {
            if self.goals_sent.get(&gid) == Some(&c) {
                continue;
            }
            self.goals_sent.insert(gid, c);
            let (x, y) = centre(h, c);
            let id = format!("goal-{gid}");
            out.push(update(
                Channel::Markers,
                id.clone(),
                entity(
                    &id,
                    t_ns,
                    vec![cube(x, y, 0.02, 0.9, 0.9, 0.04, [0.1, 0.9, 0.2], 0.9)],
                    vec![text(
                        x,
                        y,
                        0.6,
                        &format!("goal {gid}"),
                        [0.1, 0.9, 0.2],
                        1.0,
                    )],
                ),
            ));
        }
        for (&gid, cells) in &self.vm.discovered {
            if self.discovered_sent.get(&gid) == Some(&cells.len()) {
                continue;
            }
            self.discovered_sent.insert(gid, cells.len());
            let cubes = cells
                .iter()
                .map(|&c| {
                    let (x, y) = centre(h, c);
                    cube(x, y, 0.1, 0.3, 0.3, 0.2, [1.0, 0.85, 0.1], 0.9)
                })
                .collect();
            let id = format!("discoveries-{gid}");
            out.push(update(
                Channel::Markers,
                id.clone(),
                entity(&id, t_ns, cubes, Vec::new()),
            ));
        }
    }

    fn frame_transform(&self, t_ns: u64) -> Value {
        let (w, h) = (self.vm.grid.width() as f64, self.vm.grid.height() as f64);
        json!({
            "timestamp": time(t_ns), "parent_frame_id": FRAME_WORLD, "child_frame_id": FRAME_MAP,
            "translation": {"x": -w / 2.0, "y": -h / 2.0, "z": 0.0},
            "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        })
    }
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

fn cell_in(grid: &Grid, x: u16, y: u16) -> Option<Cell> {
    grid.contains(i64::from(x), i64::from(y))
        .then(|| Cell::new(x, y))
}

/// The centre of cell `c` in the `map` frame of a map `height` cells high.
pub fn centre(height: usize, c: Cell) -> (f64, f64) {
    (f64::from(c.x) + 0.5, height as f64 - f64::from(c.y) - 0.5)
}

/// The colour of robot `id` (r, g, b in 0..1): a fixed palette, repeated.
pub fn palette(id: u32) -> [f64; 3] {
    const P: [[f64; 3]; 8] = [
        [0.90, 0.25, 0.20],
        [0.20, 0.55, 0.95],
        [0.95, 0.60, 0.10],
        [0.60, 0.30, 0.85],
        [0.10, 0.75, 0.70],
        [0.95, 0.40, 0.70],
        [0.55, 0.75, 0.15],
        [0.65, 0.45, 0.30],
    ];
    P[id as usize % P.len()]
}

fn time(ns: u64) -> Value {
    json!({"sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000})
}

fn pose(x: f64, y: f64, z: f64) -> Value {
    json!({"position": {"x": x, "y": y, "z": z}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}})
}

fn color(rgb: [f64; 3], a: f64) -> Value {
    json!({"r": rgb[0], "g": rgb[1], "b": rgb[2], "a": a})
}

#[allow(clippy::too_many_arguments)]
fn cube(x: f64, y: f64, z: f64, sx: f64, sy: f64, sz: f64, rgb: [f64; 3], a: f64) -> Value {
    json!({"pose": pose(x, y, z), "size": {"x": sx, "y": sy, "z": sz}, "color": color(rgb, a)})
}

fn text(x: f64, y: f64, z: f64, s: &str, rgb: [f64; 3], a: f64) -> Value {
    json!({
        "pose": pose(x, y, z), "billboard": true, "font_size": 14.0, "scale_invariant": true,
        "color": color(rgb, a), "text": s,
    })
}

fn entity(id: &str, t_ns: u64, cubes: Vec<Value>, texts: Vec<Value>) -> Value {
    json!({
        "timestamp": time(t_ns), "frame_id": FRAME_MAP, "id": id, "lifetime": time(0),
        "frame_locked": false, "metadata": [],
        "arrows": [], "spheres": [], "cylinders": [], "lines": [], "triangles": [], "models": [],
        "cubes": cubes, "texts": texts,
    })
}

fn update(channel: Channel, key: String, entity: Value) -> SceneMsg {
    SceneMsg {
        channel,
        key,
        json: json!({"deletions": [], "entities": [entity]}),
    }
}

fn log_msg(t_ns: u64, level: u8, name: &str, message: &str) -> SceneMsg {
    SceneMsg {
        channel: Channel::Log,
        key: String::new(),
        json: json!({
            "timestamp": time(t_ns), "level": level, "message": message, "name": name,
            "file": "", "line": 0,
        }),
    }
}

/// Bytes per cell of the map grid: `wall` (0 free, 1 wall), then `red`, `green`, `blue`,
/// `alpha` (the 3D panel colours a grid with these fields as they say).
pub const GRID_CELL_BYTES: usize = 5;

/// The map as a `foxglove.Grid` in the `map` frame: one cell per map cell, row 0 of its data
/// the map's bottom row (the file's last), fields `wall`, `red`, `green`, `blue`, `alpha`.
pub fn grid_json(grid: &Grid, t_ns: u64) -> Value {
    let (w, h) = (grid.width(), grid.height());
    let mut data = Vec::with_capacity(w * h * GRID_CELL_BYTES);
    for row in 0..h {
        let y = h - 1 - row;
        for x in 0..w {
            let free = grid.is_free(Cell::new(x as u16, y as u16));
            data.extend_from_slice(if free {
                &[0, 235, 235, 235, 255]
            } else {
                &[1, 40, 40, 48, 255]
            });
        }
    }
    let field = |name: &str, offset: usize| json!({"name": name, "offset": offset, "type": 1});
    json!({
        "timestamp": time(t_ns), "frame_id": FRAME_MAP, "pose": pose(0.0, 0.0, 0.0),
        "column_count": w, "cell_size": {"x": 1.0, "y": 1.0},
        "row_stride": w * GRID_CELL_BYTES, "cell_stride": GRID_CELL_BYTES,
        "fields": [field("wall", 0), field("red", 1), field("green", 2), field("blue", 3), field("alpha", 4)],
        "data": base64(&data),
    })
}

/// Standard base64 (RFC 4648, with padding): how JSON carries a `bytes` field.
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                s.push(A[(n >> (18 - 6 * i)) as usize & 63] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

// ---- JSON schemas (written from the schemas' documented fields) ----

fn obj(props: Value) -> Value {
    json!({"type": "object", "properties": props})
}

fn num() -> Value {
    json!({"type": "number"})
}

fn int() -> Value {
    json!({"type": "integer"})
}

fn time_schema() -> Value {
    json!({"type": "object", "title": "time", "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}})
}

fn vec3_schema() -> Value {
    let mut s = obj(json!({"x": num(), "y": num(), "z": num()}));
    s["title"] = json!("foxglove.Vector3");
    s
}

fn quat_schema() -> Value {
    let mut s = obj(json!({"x": num(), "y": num(), "z": num(), "w": num()}));
    s["title"] = json!("foxglove.Quaternion");
    s
}

fn pose_schema() -> Value {
    let mut s = obj(json!({"position": vec3_schema(), "orientation": quat_schema()}));
    s["title"] = json!("foxglove.Pose");
    s
}

fn color_schema() -> Value {
    let mut s = obj(json!({"r": num(), "g": num(), "b": num(), "a": num()}));
    s["title"] = json!("foxglove.Color");
    s
}

fn array_of(items: Value) -> Value {
    json!({"type": "array", "items": items})
}

fn titled(title: &str, mut s: Value) -> Value {
    s["title"] = json!(title);
    s
}

fn frame_transform_schema() -> Value {
    obj(json!({
        "timestamp": time_schema(), "parent_frame_id": {"type": "string"},
        "child_frame_id": {"type": "string"}, "translation": vec3_schema(),
        "rotation": quat_schema(),
    }))
}

fn grid_schema() -> Value {
    obj(json!({
        "timestamp": time_schema(), "frame_id": {"type": "string"}, "pose": pose_schema(),
        "column_count": int(),
        "cell_size": titled("foxglove.Vector2", obj(json!({"x": num(), "y": num()}))),
        "row_stride": int(), "cell_stride": int(),
        "fields": array_of(titled("foxglove.PackedElementField", obj(json!({
            "name": {"type": "string"}, "offset": int(),
            "type": {"title": "foxglove.NumericType", "type": "integer", "description": "1 UINT8, 2 INT8, 3 UINT16, 4 INT16, 5 UINT32, 6 INT32, 7 FLOAT32, 8 FLOAT64"},
        })))),
        "data": {"type": "string", "contentEncoding": "base64"},
    }))
}

fn scene_update_schema() -> Value {
    let cube = titled(
        "foxglove.CubePrimitive",
        obj(json!({"pose": pose_schema(), "size": vec3_schema(), "color": color_schema()})),
    );
    let text = titled(
        "foxglove.TextPrimitive",
        obj(json!({
            "pose": pose_schema(), "billboard": {"type": "boolean"}, "font_size": num(),
            "scale_invariant": {"type": "boolean"}, "color": color_schema(),
            "text": {"type": "string"},
        })),
    );
    let line = titled(
        "foxglove.LinePrimitive",
        obj(json!({
            "type": {"title": "foxglove.LineType", "type": "integer", "description": "0 LINE_STRIP, 1 LINE_LOOP, 2 LINE_LIST"},
            "pose": pose_schema(), "thickness": num(), "scale_invariant": {"type": "boolean"},
            "points": array_of(titled("foxglove.Point3", obj(json!({"x": num(), "y": num(), "z": num()})))),
            "color": color_schema(), "colors": array_of(color_schema()), "indices": array_of(int()),
        })),
    );
    let any = json!({"type": "object"});
    let entity = titled(
        "foxglove.SceneEntity",
        obj(json!({
            "timestamp": time_schema(), "frame_id": {"type": "string"}, "id": {"type": "string"},
            "lifetime": {"type": "object", "title": "duration", "properties": {"sec": int(), "nsec": int()}},
            "frame_locked": {"type": "boolean"},
            "metadata": array_of(titled("foxglove.KeyValuePair", obj(json!({"key": {"type": "string"}, "value": {"type": "string"}})))),
            "arrows": array_of(any.clone()), "cubes": array_of(cube), "spheres": array_of(any.clone()),
            "cylinders": array_of(any.clone()), "lines": array_of(line),
            "triangles": array_of(any.clone()), "texts": array_of(text), "models": array_of(any),
        })),
    );
    let deletion = titled(
        "foxglove.SceneEntityDeletion",
        obj(
            json!({"timestamp": time_schema(), "type": {"type": "integer", "description": "0 MATCHING_ID, 1 ALL"}, "id": {"type": "string"}}),
        ),
    );
    obj(json!({"deletions": array_of(deletion), "entities": array_of(entity)}))
}

fn stats_schema() -> Value {
    let opt = |ty: &str, d: &str| json!({"type": [ty, "null"], "description": d});
    let mut s = obj(json!({
        "timestamp": time_schema(), "robot_id": int(), "goal_id": int(), "episode": int(),
        "status": {"type": "string"},
        "last_episode_steps": opt("integer", "steps of the last episode seen to end"),
        "avg_steps": opt("number", "mean steps per episode so far"),
        "greedy_path_len": opt("integer", "moves of the greedy path, when it reaches the goal"),
        "hint_latency_ms": opt("number", "Q-update in the robot to the observer, via its hint batch"),
        "final_path_len": opt("integer", "the final report's greedy path length"),
        "loop_latency_p50_ms": opt("number", "the robot's update-loop latency (final report), median"),
    }));
    s["description"] = json!("per-robot numbers of a qfleet run, for the Plot panel");
    s
}

fn log_schema() -> Value {
    obj(json!({
        "timestamp": time_schema(),
        "level": {"title": "foxglove.LogLevel", "type": "integer", "description": "0 UNKNOWN, 1 DEBUG, 2 INFO, 3 WARNING, 4 ERROR, 5 FATAL"},
        "message": {"type": "string"}, "name": {"type": "string"}, "file": {"type": "string"},
        "line": {"type": "integer", "minimum": 0},
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use bus_schema::{
        Control, DiscoveryRelay, FinalReport, QHint, QHintBatch, Register, RobotState,
    };

    /// 4 wide, 3 high; walls at (1, 0) and (2, 2).
    fn grid() -> Grid {
        let mut free = vec![true; 12];
        free[1] = false;
        free[2 * 4 + 2] = false;
        Grid::new(4, 3, free).unwrap()
    }

    fn unbase64(s: &str) -> Vec<u8> {
        const A: &str = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut bits = 0u32;
        let mut n = 0;
        let mut out = Vec::new();
        for ch in s.chars().filter(|c| *c != '=') {
            bits = (bits << 6) | A.find(ch).unwrap() as u32;
            n += 6;
            if n >= 8 {
                n -= 8;
                out.push((bits >> n) as u8);
            }
        }
        out
    }

    fn on(out: &[SceneMsg], c: Channel) -> Vec<&SceneMsg> {
        out.iter().filter(|m| m.channel == c).collect()
    }

    fn state(id: u32, x: u16, y: u16, episode: u32, last: u32) -> RobotState {
        RobotState {
            robot_id: id,
            cell_x: x,
            cell_y: y,
            episode,
            last_episode_steps: last,
            status: RobotStatus::Running.as_u8(),
            ..RobotState::ZEROED
        }
    }

    #[test]
    fn base64_is_the_standard_alphabet_with_padding() {
        for (raw, enc) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(raw.as_bytes()), enc);
            assert_eq!(unbase64(enc), raw.as_bytes());
        }
        assert_eq!(base64(&[0xff, 0xfe]), "//4=");
    }

    #[test]
    fn the_map_grid_matches_the_map_cell_for_cell() {
        let g = grid();
        let v = grid_json(&g, 1_500_000_000);
        assert_eq!(v["column_count"], 4);
        assert_eq!(v["cell_stride"], GRID_CELL_BYTES);
        assert_eq!(v["row_stride"], 4 * GRID_CELL_BYTES);
        assert_eq!(v["timestamp"], json!({"sec": 1, "nsec": 500_000_000}));
        assert_eq!(v["fields"][0]["name"], "wall");
        let data = unbase64(v["data"].as_str().unwrap());
        assert_eq!(data.len(), 12 * GRID_CELL_BYTES);
        // data row 0 is the map's bottom row (y = 2)
        for row in 0..3 {
            for x in 0..4 {
                let y = 2 - row;
                let wall = data[(row * 4 + x) * GRID_CELL_BYTES];
                let free = g.is_free(Cell::new(x as u16, y as u16));
                assert_eq!(wall, u8::from(!free), "cell ({x}, {y})");
            }
        }
        assert_eq!(centre(3, Cell::new(1, 0)), (1.5, 2.5));
    }

    #[test]
    fn the_start_sends_transform_map_and_task_markers() {
        let mut s = Scene::new("t", grid(), Cell::new(0, 0), Cell::new(3, 2));
        let mut out = Vec::new();
        s.start(7, &mut out);
        let tf = &on(&out, Channel::Tf)[0].json;
        assert_eq!(tf["parent_frame_id"], FRAME_WORLD);
        assert_eq!(tf["child_frame_id"], FRAME_MAP);
        assert_eq!(tf["translation"]["x"], -2.0);
        assert_eq!(on(&out, Channel::Map).len(), 1);
        let markers = on(&out, Channel::Markers);
        let goal = markers.iter().find(|m| m.key == "goal-0").unwrap();
        let cube = &goal.json["entities"][0]["cubes"][0]["pose"]["position"];
        assert_eq!(
            (cube["x"].as_f64(), cube["y"].as_f64()),
            (Some(3.5), Some(0.5))
        );
    }

    #[test]
    fn a_robot_is_sent_when_it_moves_and_bad_cells_are_ignored() {
        let mut s = Scene::new("t", grid(), Cell::new(0, 0), Cell::new(3, 2));
        let mut out = Vec::new();
        let reg = Register {
            robot_id: 1,
            start_x: 0,
            start_y: 2,
            ..Register::ZEROED
        };
        s.apply(10, 10, Msg::Register(&reg), &mut out);
        let r = on(&out, Channel::Robots);
        assert_eq!(r.len(), 1, "{out:?}");
        let e = &r[0].json["entities"][0];
        assert_eq!(e["id"], "robot-1");
        assert_eq!(e["frame_id"], FRAME_MAP);
        assert_eq!(e["texts"][0]["text"], "1");
        assert_eq!(e["cubes"][0]["pose"]["position"]["x"], 0.5);
        assert_eq!(e["cubes"][0]["pose"]["position"]["y"], 0.5);
        out.clear();
        s.apply(20, 20, Msg::State(&state(1, 3, 0, 0, 0)), &mut out);
        s.apply(30, 30, Msg::State(&state(1, 3, 0, 0, 0)), &mut out);
        assert_eq!(
            on(&out, Channel::Robots).len(),
            1,
            "the same cell again is not sent"
        );
        out.clear();
        s.apply(40, 40, Msg::State(&state(1, 99, 0, 0, 0)), &mut out);
        s.apply(41, 41, Msg::State(&state(u32::MAX, 1, 1, 0, 0)), &mut out);
        assert!(on(&out, Channel::Robots).is_empty(), "{out:?}");
    }

    #[test]
    fn a_path_is_the_trail_until_shared_values_give_a_greedy_path() {
        let g = Grid::new(3, 1, vec![true; 3]).unwrap();
        let mut s = Scene::new("t", g, Cell::new(0, 0), Cell::new(2, 0));
        let mut out = Vec::new();
        let t = |i: u64| i * PATH_EVERY_NS;
        s.apply(t(1), 1, Msg::State(&state(0, 0, 0, 0, 0)), &mut out);
        s.apply(t(2), 2, Msg::State(&state(0, 1, 0, 0, 0)), &mut out);
        let p = on(&out, Channel::Paths);
        assert_eq!(p.len(), 1, "{out:?}");
        assert_eq!(p[0].json["entities"][0]["metadata"][1]["value"], "trail");
        assert_eq!(
            p[0].json["entities"][0]["lines"][0]["points"]
                .as_array()
                .unwrap()
                .len(),
            2
        );
        // within the throttle window a change waits; it goes out with the next message after
        out.clear();
        let mut h = QHintBatch {
            robot_id: 0,
            count: 2,
            oldest_update_ns: 1,
            ..QHintBatch::ZEROED
        };
        for (i, cell) in [0u32, 1].into_iter().enumerate() {
            h.entries[i] = QHint {
                cell,
                action: 1,
                q: 1.0,
                ..QHint::ZEROED
            };
        }
        s.apply(t(2) + 1, 3, Msg::Hints(&h), &mut out);
        assert!(on(&out, Channel::Paths).is_empty());
        s.apply(t(4), 4, Msg::State(&state(0, 1, 0, 0, 0)), &mut out);
        let p = on(&out, Channel::Paths);
        assert_eq!(p.len(), 1, "{out:?}");
        let e = &p[0].json["entities"][0];
        assert_eq!(e["metadata"][1]["value"], "greedy");
        assert_eq!(e["lines"][0]["points"].as_array().unwrap().len(), 3);
    }

    #[test]
    fn stats_go_out_once_per_episode_seen_to_end_and_at_the_report() {
        let mut s = Scene::new("t", grid(), Cell::new(0, 0), Cell::new(3, 2));
        let mut out = Vec::new();
        s.apply(1, 1, Msg::State(&state(0, 0, 0, 0, 0)), &mut out);
        assert!(on(&out, Channel::Stats).is_empty(), "no episode ended yet");
        s.apply(2, 2, Msg::State(&state(0, 0, 0, 1, 12)), &mut out);
        s.apply(3, 3, Msg::State(&state(0, 3, 0, 1, 12)), &mut out);
        let st = on(&out, Channel::Stats);
        assert_eq!(st.len(), 1, "{out:?}");
        assert_eq!(st[0].json["last_episode_steps"], 12);
        assert_eq!(st[0].json["avg_steps"], 12.0);
        out.clear();
        let mut rep = FinalReport {
            robot_id: 0,
            episodes: 5,
            final_path_len: 5,
            status: RobotStatus::Finished.as_u8(),
            avg_steps: 9.5,
            ..FinalReport::ZEROED
        };
        rep.merged_latency.count = 3;
        rep.merged_latency.p50_ns = 2_000_000;
        s.apply(4, 4, Msg::Report(&rep), &mut out);
        let st = on(&out, Channel::Stats);
        assert_eq!(st[0].json["final_path_len"], 5);
        assert_eq!(st[0].json["loop_latency_p50_ms"], 2.0);
        let log = on(&out, Channel::Log);
        assert!(
            log[0].json["message"]
                .as_str()
                .unwrap()
                .contains("robot 0 finished after 5 episodes"),
            "{log:?}"
        );
    }

    #[test]
    fn goals_and_relayed_discoveries_become_markers() {
        let mut s = Scene::new("t", grid(), Cell::new(0, 0), Cell::new(3, 2));
        let mut out = Vec::new();
        s.start(0, &mut out);
        out.clear();
        let assign = Control {
            command: Command::AssignGoal.as_u8(),
            robot_id: 0,
            goal_id: 2,
            goal_x: 3,
            goal_y: 0,
            ..Control::ZEROED
        };
        s.apply(1, 1, Msg::Control(&assign), &mut out);
        assert!(on(&out, Channel::Markers).iter().any(|m| m.key == "goal-2"));
        assert!(
            on(&out, Channel::Log)[0].json["message"]
                .as_str()
                .unwrap()
                .contains("assign goal 2 at (3, 0)")
        );
        out.clear();
        let relay = DiscoveryRelay {
            goal_id: 0,
            cell_x: 2,
            cell_y: 1,
            ..DiscoveryRelay::ZEROED
        };
        s.apply(2, 2, Msg::Relay(&relay), &mut out);
        s.apply(3, 3, Msg::Relay(&relay), &mut out);
        let d = on(&out, Channel::Markers);
        assert_eq!(d.len(), 1, "one cell, sent once: {out:?}");
        assert_eq!(d[0].key, "discoveries-0");
    }

    #[test]
    fn every_message_fits_its_channels_schema() {
        let mut s = Scene::new("t", grid(), Cell::new(0, 0), Cell::new(3, 2));
        let mut out = Vec::new();
        s.start(0, &mut out);
        s.apply(1, 1, Msg::State(&state(0, 0, 0, 0, 0)), &mut out);
        s.apply(
            PATH_EVERY_NS,
            2,
            Msg::State(&state(0, 0, 1, 1, 4)),
            &mut out,
        );
        let rep = FinalReport {
            status: RobotStatus::Failed.as_u8(),
            ..FinalReport::ZEROED
        };
        s.apply(PATH_EVERY_NS * 3, 3, Msg::Report(&rep), &mut out);
        let seen: std::collections::BTreeSet<Channel> = out.iter().map(|m| m.channel).collect();
        assert_eq!(seen.len(), Channel::ALL.len(), "{seen:?}");
        for m in &out {
            let schema = m.channel.schema();
            assert_eq!(schema["title"], m.channel.schema_name());
            let props = schema["properties"].as_object().unwrap();
            for k in m.json.as_object().unwrap().keys() {
                assert!(
                    props.contains_key(k),
                    "{:?}: {k} not in its schema",
                    m.channel
                );
            }
        }
        for c in Channel::ALL {
            assert!(c.topic().starts_with('/'));
        }
    }
}
