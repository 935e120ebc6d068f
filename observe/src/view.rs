//! The live view's state: an IO-free model of a run, fed message by message (from a live
//! [`crate::attach::Observer`] or a recording) and read by the terminal renderer.
//!
//! What it derives: each robot's latest cell, episode and step (from `robot/state`), its greedy
//! path (argmax over the Q-values the robot itself shared on `robot/hints`, else over the fleet
//! table built from `coord/merged`), whether that path is optimal (BFS on the map), discoveries
//! sent and relayed, the latency from a Q-update in a robot to the observer (through the
//! coordinator, `coord/merged` per entry) and message throughput. Robots publish their state
//! every `--state-every` steps (256), so positions are samples, not every move.

use std::collections::BTreeMap;

use bus_schema::names::Topic;
use bus_schema::{Command, HINT_BATCH_CAP, QHint, RobotStatus};
use planner::grid::{Action, Cell, Grid};

use crate::decode::Msg;
use crate::stats::{Percentiles, Rate, RecentLatency, TopicCounts};

/// Robots that keep a Q-table of their own in the view (the rest are shown with the fleet's).
pub const OWN_TABLES_MAX: usize = 64;

/// What the view knows about one robot.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RobotView {
    /// Robot id.
    pub id: u32,
    /// Whether any message of it was seen.
    pub seen: bool,
    /// Start cell (from its `Register`, else the task's).
    pub start: Option<Cell>,
    /// Goal it learns towards.
    pub goal_id: u32,
    /// Latest reported cell.
    pub cell: Option<Cell>,
    /// Latest episode (from 0).
    pub episode: u32,
    /// Step within it.
    pub step: u32,
    /// Latest status byte.
    pub status: u8,
    /// Steps of the episodes seen to end (sum, count), for the average.
    pub episode_steps: (u64, u64),
    last_counted_episode: Option<u32>,
    /// Average steps per episode: the robot's own figure once it reported, else over the
    /// episodes seen to end.
    pub avg_steps: Option<f64>,
    /// Discoveries it published.
    pub discoveries: u64,
    /// Its final report's greedy path length (-1: none), once reported.
    pub final_path_len: Option<i32>,
    /// Q-values it shared (row-major cells × 4 actions); empty until it shares one.
    q: Vec<[f32; 4]>,
}

/// The model behind the live view.
#[derive(Debug, Clone)]
pub struct ViewModel {
    /// The map.
    pub grid: Grid,
    /// Map name, for the title.
    pub map_name: String,
    default_start: Cell,
    /// Goal cells by goal id.
    pub goals: BTreeMap<u32, Cell>,
    /// Robots by id.
    pub robots: Vec<RobotView>,
    /// Fleet Q-table per goal (from `coord/merged`).
    fleet: BTreeMap<u32, Vec<[f32; 4]>>,
    /// Cells discovered as pseudo targets (from `coord/discovery`), per goal.
    pub discovered: BTreeMap<u32, Vec<Cell>>,
    /// Discoveries published by robots (`robot/discovery`).
    pub discoveries_sent: u64,
    /// Discoveries relayed by the coordinator (`coord/discovery`).
    pub relayed: u64,
    /// Messages per topic.
    pub counts: TopicCounts,
    /// Q-update → observer latency of merged entries (via the coordinator), ns.
    pub merged_latency: RecentLatency,
    /// Q-update → observer latency of robots' hint batches (oldest update), ns.
    pub hint_latency: RecentLatency,
    msg_rate: Rate,
    merged_rate: Rate,
    /// Time of the newest message, ns.
    pub now_ns: u64,
    /// The run sent `Stop`.
    pub stopped: bool,
    /// Experiment phase in effect.
    pub phase: u32,
}

impl ViewModel {
    /// A view of a run on `grid` whose robots start at `start` towards `goal` (goal id 0);
    /// `Register` and `AssignGoal` messages override both per robot/goal.
    pub fn new(map_name: &str, grid: Grid, start: Cell, goal: Cell) -> Self {
        Self {
            grid,
            map_name: map_name.to_string(),
            default_start: start,
            goals: BTreeMap::from([(0, goal)]),
            robots: Vec::new(),
            fleet: BTreeMap::new(),
            discovered: BTreeMap::new(),
            discoveries_sent: 0,
            relayed: 0,
            counts: TopicCounts::default(),
            merged_latency: RecentLatency::new(4096),
            hint_latency: RecentLatency::new(4096),
            msg_rate: Rate::new(1_000_000_000),
            merged_rate: Rate::new(1_000_000_000),
            now_ns: 0,
            stopped: false,
            phase: 0,
        }
    }

    fn cell_ok(&self, x: u16, y: u16) -> Option<Cell> {
        let c = Cell::new(x, y);
        self.grid.contains(i64::from(x), i64::from(y)).then_some(c)
    }

    fn robot(&mut self, id: u32) -> Option<&mut RobotView> {
        if id >= bus::MAX_ROBOTS {
            return None;
        }
        let i = id as usize;
        while self.robots.len() <= i {
            let id = self.robots.len() as u32;
            self.robots.push(RobotView {
                id,
                start: Some(self.default_start),
                ..RobotView::default()
            });
        }
        let r = &mut self.robots[i];
        r.seen = true;
        Some(r)
    }

    fn table_set(q: &mut Vec<[f32; 4]>, cells: usize, e: &QHint) {
        if q.is_empty() {
            q.resize(cells, [0.0; 4]);
        }
        let (c, a) = (e.cell as usize, e.action as usize);
        if c < q.len() && a < 4 && e.q.is_finite() {
            q[c][a] = e.q;
        }
    }

    /// Feeds one message received at `recv_ns` (monotonic ns, the clock of the messages' own
    /// times). Out-of-range ids, cells and counts are ignored, never a panic.
    pub fn apply(&mut self, recv_ns: u64, msg: Msg<'_>) {
        self.now_ns = self.now_ns.max(recv_ns);
        self.counts.add(msg.topic(), recv_ns);
        self.msg_rate.add(recv_ns, 1);
        let cells = self.grid.len();
        match msg {
            Msg::Register(m) => {
                let start = self.cell_ok(m.start_x, m.start_y);
                if let Some(r) = self.robot(m.robot_id) {
                    r.start = start.or(r.start);
                }
            }
            Msg::State(m) => {
                let cell = self.cell_ok(m.cell_x, m.cell_y);
                if let Some(r) = self.robot(m.robot_id) {
                    r.cell = cell.or(r.cell);
                    r.goal_id = m.goal_id;
                    r.episode = m.episode;
                    r.step = m.step;
                    r.status = m.status;
                    // the last finished episode is episode - 1: count each once
                    if m.last_episode_steps > 0 && m.episode > 0 {
                        let ep = m.episode - 1;
                        if r.last_counted_episode != Some(ep) {
                            r.last_counted_episode = Some(ep);
                            r.episode_steps.0 += u64::from(m.last_episode_steps);
                            r.episode_steps.1 += 1;
                        }
                    }
                    if r.final_path_len.is_none() && r.episode_steps.1 > 0 {
                        r.avg_steps = Some(r.episode_steps.0 as f64 / r.episode_steps.1 as f64);
                    }
                }
            }
            Msg::Discovery(m) => {
                self.discoveries_sent += 1;
                if let Some(r) = self.robot(m.robot_id) {
                    r.discoveries += 1;
                }
            }
            Msg::Hints(m) => {
                let n = (m.count as usize).min(HINT_BATCH_CAP);
                if m.oldest_update_ns > 0 {
                    self.hint_latency
                        .add(recv_ns.saturating_sub(m.oldest_update_ns));
                }
                if (m.robot_id as usize) < OWN_TABLES_MAX
                    && let Some(r) = self.robot(m.robot_id)
                {
                    r.goal_id = m.goal_id;
                    for e in &m.entries[..n] {
                        Self::table_set(&mut r.q, cells, e);
                    }
                }
            }
            Msg::Report(m) => {
                if let Some(r) = self.robot(m.robot_id) {
                    r.status = m.status;
                    r.final_path_len = Some(m.final_path_len);
                    if m.avg_steps.is_finite() {
                        r.avg_steps = Some(m.avg_steps);
                    }
                    r.episode = m.episodes;
                }
            }
            Msg::Control(m) => match Command::try_from(m.command) {
                Ok(Command::AssignGoal) => {
                    if let Some(c) = self.cell_ok(m.goal_x, m.goal_y) {
                        self.goals.insert(m.goal_id, c);
                    }
                    if m.robot_id != bus_schema::ROBOT_ID_ALL
                        && let Some(r) = self.robot(m.robot_id)
                    {
                        r.goal_id = m.goal_id;
                    }
                }
                Ok(Command::Stop) => self.stopped = true,
                Ok(Command::Phase) => self.phase = m.phase,
                _ => {}
            },
            Msg::Merged(m) => {
                let n = (m.count as usize).min(HINT_BATCH_CAP);
                self.merged_rate.add(recv_ns, n as u64);
                let table = self.fleet.entry(m.goal_id).or_default();
                for i in 0..n {
                    Self::table_set(table, cells, &m.entries[i]);
                    // a full-table resend carries no origin (robot 0xFFFFFFFF, time 0)
                    if m.origin_ns[i] > 0 && m.origin_robot[i] != u32::MAX {
                        self.merged_latency
                            .add(recv_ns.saturating_sub(m.origin_ns[i]));
                    }
                }
            }
            Msg::Ack(_) | Msg::Intent(_) | Msg::Horizon(_) => {}
            // the shared grid's authority: where every robot stands at this tick
            Msg::Grant(m) => {
                let n = (m.robots as usize).min(bus_schema::GRANT_CAP);
                for i in 0..n {
                    let cell = self.cell_ok(m.cell_x[i], m.cell_y[i]);
                    if m.present[i] != 0
                        && let Some(r) = self.robot(i as u32)
                    {
                        r.cell = cell.or(r.cell);
                        r.step = m.tick;
                    }
                }
            }
            Msg::Relay(m) => {
                self.relayed += 1;
                if let Some(c) = self.cell_ok(m.cell_x, m.cell_y) {
                    let v = self.discovered.entry(m.goal_id).or_default();
                    if !v.contains(&c) {
                        v.push(c);
                    }
                }
            }
        }
    }

    /// The greedy path of robot `id` from its start (its own shared Q-values, else the fleet's
    /// for its goal): cells visited, ending at the goal, a revisit or a dead end (all-zero Q).
    pub fn greedy_path(&self, id: u32) -> Vec<Cell> {
        let Some(r) = self.robots.get(id as usize) else {
            return Vec::new();
        };
        let (Some(start), Some(&goal)) = (r.start, self.goals.get(&r.goal_id)) else {
            return Vec::new();
        };
        let q = if r.q.is_empty() {
            match self.fleet.get(&r.goal_id) {
                Some(t) => t,
                None => return Vec::new(),
            }
        } else {
            &r.q
        };
        greedy_walk(&self.grid, q, start, goal)
    }

    /// Whether robot `id`'s greedy path reaches its goal in the fewest moves: `None` while it
    /// has no path yet.
    pub fn path_optimal(&self, id: u32) -> Option<bool> {
        let r = self.robots.get(id as usize)?;
        let goal = *self.goals.get(&r.goal_id)?;
        let path = self.greedy_path(id);
        if path.last() != Some(&goal) {
            return None;
        }
        let best = planner::path::shortest_moves(&self.grid, r.start?, goal)?;
        Some(path.len() as u32 - 1 == best)
    }

    /// Messages per second over the last second.
    pub fn message_rate(&mut self) -> f64 {
        self.msg_rate.per_s(self.now_ns)
    }

    /// Merged Q-entries per second over the last second.
    pub fn merged_rate(&mut self) -> f64 {
        self.merged_rate.per_s(self.now_ns)
    }

    /// Latency percentiles of merged entries (Q-update in a robot → observer), ns.
    pub fn latency(&self) -> Percentiles {
        self.merged_latency.percentiles()
    }

    /// How many robots reported a final status (`Finished`/`Failed`).
    pub fn finished(&self) -> usize {
        self.robots
            .iter()
            .filter(|r| {
                r.status == RobotStatus::Finished.as_u8() || r.status == RobotStatus::Failed.as_u8()
            })
            .count()
    }

    /// Messages seen on `topic`.
    pub fn count(&self, topic: Topic) -> u64 {
        self.counts.get(topic).count
    }
}

/// Follows argmax Q (first action on ties) from `start` until `goal`, a revisit, a wall/border,
/// or a cell whose Q-values are all zero (nothing learned there).
pub fn greedy_walk(grid: &Grid, q: &[[f32; 4]], start: Cell, goal: Cell) -> Vec<Cell> {
    let mut path = vec![start];
    let mut seen = vec![false; grid.len()];
    let mut c = start;
    while c != goal {
        let i = grid.index(c);
        if i >= q.len() || seen[i] {
            break;
        }
        seen[i] = true;
        let row = q[i];
        if row.iter().all(|v| *v == 0.0) {
            break;
        }
        let mut best = 0;
        for a in 1..4 {
            if row[a] > row[best] {
                best = a;
            }
        }
        match grid.neighbor(c, Action::from_index(best)) {
            Some(n) if grid.is_free(n) && !seen[grid.index(n)] => {
                path.push(n);
                c = n;
            }
            _ => break,
        }
    }
    path
}

#[cfg(test)]
mod tests {
    use super::*;
    use bus_schema::{MergedHintBatch, QHintBatch, RobotState};

    fn open(w: usize, h: usize) -> Grid {
        Grid::new(w, h, vec![true; w * h]).unwrap()
    }

    #[test]
    fn state_moves_the_robot_and_counts_each_finished_episode_once() {
        let mut v = ViewModel::new("t", open(5, 5), Cell::new(0, 0), Cell::new(4, 4));
        let s = RobotState {
            robot_id: 2,
            episode: 3,
            last_episode_steps: 10,
            cell_x: 1,
            cell_y: 2,
            status: 1,
            ..RobotState::ZEROED
        };
        v.apply(10, Msg::State(&s));
        v.apply(20, Msg::State(&s));
        let s2 = RobotState {
            episode: 4,
            last_episode_steps: 20,
            ..s
        };
        v.apply(30, Msg::State(&s2));
        let r = &v.robots[2];
        assert_eq!(v.robots.len(), 3);
        assert_eq!(r.cell, Some(Cell::new(1, 2)));
        assert_eq!(r.episode_steps, (30, 2));
        assert_eq!(r.avg_steps, Some(15.0));
        // a cell off the map and a robot id beyond the fleet limit are ignored
        let bad = RobotState { cell_x: 99, ..s2 };
        v.apply(40, Msg::State(&bad));
        assert_eq!(v.robots[2].cell, Some(Cell::new(1, 2)));
        v.apply(
            41,
            Msg::State(&RobotState {
                robot_id: u32::MAX,
                ..s2
            }),
        );
        assert_eq!(v.robots.len(), 3);
    }

    #[test]
    fn greedy_path_follows_shared_values_and_is_judged_against_bfs() {
        let g = open(3, 2);
        let mut v = ViewModel::new("t", g.clone(), Cell::new(0, 0), Cell::new(2, 0));
        // robot 0 shares: (0,0) → right, (1,0) → right
        let mut h = QHintBatch {
            robot_id: 0,
            count: 2,
            ..QHintBatch::ZEROED
        };
        h.entries[0] = QHint {
            cell: 0,
            action: 1,
            q: 0.5,
            ..QHint::ZEROED
        };
        h.entries[1] = QHint {
            cell: 1,
            action: 1,
            q: 0.9,
            ..QHint::ZEROED
        };
        v.apply(1, Msg::Hints(&h));
        assert_eq!(
            v.greedy_path(0),
            vec![Cell::new(0, 0), Cell::new(1, 0), Cell::new(2, 0)]
        );
        assert_eq!(v.path_optimal(0), Some(true));
        // robot 1 shared nothing: it is shown on the fleet table (a detour down, right, up)
        let mut m = MergedHintBatch {
            count: 4,
            ..MergedHintBatch::ZEROED
        };
        m.entries[0] = QHint {
            cell: 0,
            action: 2,
            q: 0.1,
            ..QHint::ZEROED
        };
        m.entries[1] = QHint {
            cell: 3,
            action: 1,
            q: 0.2,
            ..QHint::ZEROED
        };
        m.entries[2] = QHint {
            cell: 4,
            action: 1,
            q: 0.3,
            ..QHint::ZEROED
        };
        m.entries[3] = QHint {
            cell: 5,
            action: 0,
            q: 0.4,
            ..QHint::ZEROED
        };
        m.origin_ns[0] = 5;
        m.origin_robot[1] = u32::MAX;
        v.apply(
            100,
            Msg::State(&RobotState {
                robot_id: 1,
                ..RobotState::ZEROED
            }),
        );
        v.apply(105, Msg::Merged(&m));
        assert_eq!(v.greedy_path(1).len(), 5);
        assert_eq!(v.path_optimal(1), Some(false));
        // one entry had an origin time (latency 100 ns), the resend ones none
        assert_eq!(v.latency().count, 1);
        assert_eq!(v.latency().p50, 100);
    }

    #[test]
    fn greedy_walk_stops_on_loops_and_unlearned_cells() {
        let g = open(2, 1);
        // (0) → right, (1) → left: a loop
        let q = vec![[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
        let p = greedy_walk(&g, &q, Cell::new(0, 0), Cell::new(5, 5));
        assert_eq!(p, vec![Cell::new(0, 0), Cell::new(1, 0)]);
        let p = greedy_walk(&g, &[[0.0; 4]; 2], Cell::new(0, 0), Cell::new(1, 0));
        assert_eq!(p, vec![Cell::new(0, 0)]);
    }
}
