//! An independent checker of shared-grid results, written for the tests from the MAPF
//! benchmark's rules (`../shared/notes/mapf-conventions.md`) and sharing no code with the
//! project: it reads the MovingAI map and scenario files and the mapf-visualizer paths file
//! itself, and checks starts, goals, legal moves, vertex and swap conflicts and the costs.

use std::collections::VecDeque;
use std::path::Path;

use serde_json::Value;

/// A cell as (x, y) = (column, row).
pub type Xy = (i64, i64);

/// A MovingAI map: `free[y][x]`.
pub struct Map {
    /// Width in cells.
    pub width: usize,
    /// Height in cells.
    pub height: usize,
    free: Vec<Vec<bool>>,
}

impl Map {
    /// Parses a MovingAI `.map` (`type`, `height`, `width`, `map`, rows; `.`, `G`, `S` and the
    /// competition's `E` free).
    pub fn parse(text: &str) -> Map {
        let mut lines = text.lines();
        let (mut width, mut height) = (0, 0);
        for l in lines.by_ref() {
            let l = l.trim();
            if let Some(h) = l.strip_prefix("height ") {
                height = h.trim().parse().expect("height");
            } else if let Some(w) = l.strip_prefix("width ") {
                width = w.trim().parse().expect("width");
            } else if l == "map" {
                break;
            }
        }
        let free: Vec<Vec<bool>> = lines
            .take(height)
            .map(|row| {
                row.chars()
                    .take(width)
                    .map(|c| matches!(c, '.' | 'G' | 'S' | 'E'))
                    .collect()
            })
            .collect();
        assert_eq!(free.len(), height, "map rows");
        Map {
            width,
            height,
            free,
        }
    }

    /// Whether (x, y) is on the map and passable.
    pub fn free(&self, x: i64, y: i64) -> bool {
        x >= 0
            && y >= 0
            && (x as usize) < self.width
            && (y as usize) < self.height
            && self.free[y as usize][x as usize]
    }

    /// BFS distance from `a` to `b` in 4-connected moves.
    pub fn distance(&self, a: (i64, i64), b: (i64, i64)) -> Option<u64> {
        let mut seen = vec![vec![false; self.width]; self.height];
        let mut q = VecDeque::from([(a, 0u64)]);
        seen[a.1 as usize][a.0 as usize] = true;
        while let Some(((x, y), d)) = q.pop_front() {
            if (x, y) == b {
                return Some(d);
            }
            for (dx, dy) in [(0, -1), (1, 0), (0, 1), (-1, 0)] {
                let (nx, ny) = (x + dx, y + dy);
                if self.free(nx, ny) && !seen[ny as usize][nx as usize] {
                    seen[ny as usize][nx as usize] = true;
                    q.push_back(((nx, ny), d + 1));
                }
            }
        }
        None
    }
}

/// The first `n` (start, goal) pairs of a `.scen` file, as (x, y) = (column, row).
pub fn scen_pairs(text: &str, n: usize) -> Vec<(Xy, Xy)> {
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .take(n)
        .map(|l| {
            let f: Vec<&str> = l.split('\t').collect();
            let p = |i: usize| f[i].trim().parse::<i64>().expect("scen field");
            ((p(4), p(5)), (p(6), p(7)))
        })
        .collect()
}

/// Parses `t:(x,y),(x,y),…` lines into `paths[agent][tick]`.
pub fn parse_paths(text: &str) -> Vec<Vec<(i64, i64)>> {
    let mut paths: Vec<Vec<(i64, i64)>> = Vec::new();
    for (t, line) in text.lines().filter(|l| !l.trim().is_empty()).enumerate() {
        let (tick, rest) = line.split_once(':').expect("t:");
        assert_eq!(
            tick.trim().parse::<usize>().expect("tick"),
            t,
            "ticks in order"
        );
        let cells: Vec<(i64, i64)> = rest
            .split(')')
            .filter_map(|p| {
                let p = p.trim_start_matches(',').trim().strip_prefix('(')?;
                let (x, y) = p.split_once(',')?;
                Some((x.trim().parse().ok()?, y.trim().parse().ok()?))
            })
            .collect();
        if paths.is_empty() {
            paths = vec![Vec::new(); cells.len()];
        }
        assert_eq!(cells.len(), paths.len(), "agents on line {t}");
        for (a, c) in cells.into_iter().enumerate() {
            paths[a].push(c);
        }
    }
    paths
}

/// What the paths cost, by the benchmark's definitions.
#[derive(Debug, Clone, PartialEq)]
pub struct Checked {
    /// Vertex conflicts found.
    pub vertex: usize,
    /// Swap conflicts found.
    pub swap: usize,
    /// Illegal moves (not a wait or a unit move onto a free cell).
    pub illegal: usize,
    /// Agents that did not start on their start.
    pub bad_start: usize,
    /// Agents not on their goal at the end.
    pub not_arrived: usize,
    /// Sum over agents of the tick from which they stayed on their goal.
    pub sum_of_costs: u64,
    /// The largest of those.
    pub makespan: u64,
    /// Sum of BFS distances start → goal.
    pub lower_bound: u64,
}

/// Checks `paths` against `pairs` on `map`.
pub fn check(map: &Map, pairs: &[(Xy, Xy)], paths: &[Vec<Xy>]) -> Checked {
    assert_eq!(paths.len(), pairs.len(), "one path per agent");
    let ticks = paths.iter().map(Vec::len).max().unwrap_or(0);
    let at = |a: usize, t: usize| paths[a][t.min(paths[a].len() - 1)];
    let mut c = Checked {
        vertex: 0,
        swap: 0,
        illegal: 0,
        bad_start: 0,
        not_arrived: 0,
        sum_of_costs: 0,
        makespan: 0,
        lower_bound: 0,
    };
    for (a, &(start, goal)) in pairs.iter().enumerate() {
        c.lower_bound += map.distance(start, goal).expect("solvable pair");
        if paths[a].first() != Some(&start) {
            c.bad_start += 1;
        }
        if paths[a].last() != Some(&goal) {
            c.not_arrived += 1;
        }
        let cost = paths[a]
            .iter()
            .rposition(|&p| p != goal)
            .map_or(0, |i| i + 1) as u64;
        c.sum_of_costs += cost;
        c.makespan = c.makespan.max(cost);
        for t in 1..paths[a].len() {
            let (p, q) = (paths[a][t - 1], paths[a][t]);
            let step = (p.0 - q.0).abs() + (p.1 - q.1).abs();
            if step > 1 || !map.free(q.0, q.1) {
                c.illegal += 1;
            }
        }
    }
    for t in 0..ticks {
        for a in 0..paths.len() {
            for b in a + 1..paths.len() {
                if at(a, t) == at(b, t) {
                    c.vertex += 1;
                }
                if t + 1 < ticks && at(a, t) == at(b, t + 1) && at(b, t) == at(a, t + 1) {
                    c.swap += 1;
                }
            }
        }
    }
    c
}

/// Checks a finished shared-grid run's `paths.txt` (in `out`) independently and against its
/// result's `grid` section (used by `tests/grid.rs` and `tests/multihost.rs`).
pub fn validate(out: &Path, map: &Path, scen: &Path, agents: usize, grid: &Value) {
    let pairs = scen_pairs(&std::fs::read_to_string(scen).unwrap(), agents);
    validate_pairs(&out.join("paths.txt"), map, &pairs, grid);
}

/// Checks the paths file `paths` of a shared-grid execution whose robots went between `pairs`
/// (an experiment's phase: `paths-phase-<p>.txt`, its own starts and goals) independently and
/// against its result's `grid` section.
pub fn validate_pairs(paths: &Path, map: &Path, pairs: &[(Xy, Xy)], grid: &Value) {
    let m = Map::parse(&std::fs::read_to_string(map).unwrap());
    let text = std::fs::read_to_string(paths)
        .unwrap_or_else(|e| panic!("no paths file {} ({e})", paths.display()));
    let paths = parse_paths(&text);
    let c = check(&m, pairs, &paths);
    assert_eq!(
        (c.vertex, c.swap, c.illegal, c.bad_start),
        (0, 0, 0, 0),
        "{c:?}"
    );
    assert_eq!(grid["conflicts"], 0, "{grid}");
    if grid["all_arrived"] == true {
        assert_eq!(c.not_arrived, 0, "{c:?}");
        assert_eq!(
            grid["sum_of_costs"].as_u64(),
            Some(c.sum_of_costs),
            "{grid}"
        );
        assert_eq!(grid["makespan"].as_u64(), Some(c.makespan), "{grid}");
        // the paths file runs from tick 0 to the makespan
        assert_eq!(paths[0].len() as u64, c.makespan + 1);
    }
    assert_eq!(grid["lower_bound"].as_u64(), Some(c.lower_bound), "{grid}");
}

/// A League of Robot Runners 2023 problem, read from its JSON and the files it names.
pub struct Lorr {
    /// The map.
    pub map: Map,
    /// Robot k's start.
    pub starts: Vec<Xy>,
    /// The task cells, in file order.
    pub tasks: Vec<Xy>,
}

impl Lorr {
    /// Reads `problem` (paths in it are relative to its folder); the team is `teamSize`.
    pub fn read(problem: &Path) -> Lorr {
        let dir = problem.parent().unwrap();
        let spec: Value = serde_json::from_str(&std::fs::read_to_string(problem).unwrap()).unwrap();
        let file = |k: &str| std::fs::read_to_string(dir.join(spec[k].as_str().unwrap())).unwrap();
        let map = Map::parse(&file("mapFile"));
        let cells = |text: String| -> Vec<Xy> {
            let ids: Vec<i64> = text
                .split_whitespace()
                .map(|t| t.parse().expect("a cell id"))
                .collect();
            assert_eq!(ids[0] as usize, ids.len() - 1, "the count line");
            ids[1..]
                .iter()
                .map(|&id| (id % map.width as i64, id / map.width as i64))
                .collect()
        };
        let team = spec["teamSize"].as_u64().unwrap() as usize;
        let mut starts = cells(file("agentFile"));
        starts.truncate(team);
        let tasks = cells(file("taskFile"));
        Lorr { map, starts, tasks }
    }

    /// Robot k's c-th goal by the round-robin rule: `tasks[(c*team + k) % len]`.
    pub fn goal(&self, k: usize, c: usize) -> Xy {
        self.tasks[(c * self.starts.len() + k) % self.tasks.len()]
    }

    /// Goals each robot reached along `paths`: from tick 1 on, a robot standing on its current
    /// goal after a move has reached it and is sent to its next one.
    pub fn goals_reached(&self, paths: &[Vec<Xy>]) -> Vec<u64> {
        paths
            .iter()
            .enumerate()
            .map(|(k, path)| {
                let mut c = 0;
                for &p in &path[1..] {
                    if p == self.goal(k, c) {
                        c += 1;
                    }
                }
                c as u64
            })
            .collect()
    }
}

/// Checks a lifelong run's `paths.txt` and `lorr-output.json` (in `out`) independently and
/// against its result's `lifelong` section: starts, legal moves, no vertex or swap conflict,
/// `ticks + 1` positions a robot, and the goals the paths reach are the result's, robot by robot.
pub fn validate_lifelong(out: &Path, problem: &Path, life: &Value) {
    let l = Lorr::read(problem);
    let paths = parse_paths(&std::fs::read_to_string(out.join("paths.txt")).unwrap());
    assert_eq!(paths.len(), l.starts.len(), "one path per robot");
    let ticks = life["ticks"].as_u64().unwrap() as usize;
    assert!(
        paths.iter().all(|p| p.len() == ticks + 1),
        "ticks 0..={ticks}"
    );
    // every robot "goes" from its start to its start: only conflicts, moves and starts count
    let pairs: Vec<(Xy, Xy)> = l.starts.iter().map(|&s| (s, s)).collect();
    let c = check(&l.map, &pairs, &paths);
    assert_eq!(
        (c.vertex, c.swap, c.illegal, c.bad_start),
        (0, 0, 0, 0),
        "{c:?}"
    );
    assert_eq!(life["conflicts"], 0, "{life}");
    let goals = l.goals_reached(&paths);
    let total: u64 = goals.iter().sum();
    assert_eq!(life["goals_reached"].as_u64(), Some(total), "{life}");
    let theirs: Vec<u64> = life["robot_goals"]
        .as_array()
        .unwrap()
        .iter()
        .map(|g| g.as_u64().unwrap())
        .collect();
    assert_eq!(theirs, goals, "goals per robot");
    let lorr: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("lorr-output.json")).unwrap())
            .unwrap();
    assert_eq!(
        lorr["numTaskFinished"].as_u64(),
        Some(total),
        "lorr-output.json"
    );
    assert_eq!(lorr["teamSize"].as_u64(), Some(l.starts.len() as u64));
    assert_eq!(lorr["makespan"].as_u64(), Some(ticks as u64));
    // PlanViz's MAPF moves (R col + 1, L col - 1, U row + 1, D row - 1, W wait) from each
    // `[row, col, "E"]` start replay the paths file
    for (k, path) in paths.iter().enumerate() {
        let start = &lorr["start"][k];
        let mut at = (start[1].as_i64().unwrap(), start[0].as_i64().unwrap());
        let mut replayed = vec![at];
        for m in lorr["actualPaths"][k].as_str().unwrap().split(',') {
            match m {
                "R" => at.0 += 1,
                "L" => at.0 -= 1,
                "U" => at.1 += 1,
                "D" => at.1 -= 1,
                "W" => {}
                _ => panic!("robot {k}: move {m:?}"),
            }
            replayed.push(at);
        }
        assert_eq!(&replayed, path, "robot {k}'s actualPaths");
    }
}
