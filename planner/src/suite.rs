//! The map suite: generated maps of four families and several sizes, each with a far
//! start/goal pair, split into a tuning half and a held-out half by a fixed rule.
//!
//! Everything is a pure function of the suite seed: the same seed gives the same maps, pairs
//! and split on every machine. Learner defaults are chosen on the tuning half; figures are
//! reported on the held-out half (`qfleet eval`). Every map has a path from start to goal by
//! construction (both ends are picked inside one connected component), and the suite tests
//! check it with a BFS. Not here: running learners over the suite (that is `qfleet eval`).

use crate::grid::{Cell, Grid, GridError};
use crate::map::{GridMap, load_map, load_scen};
use crate::path::bfs_distances;
use crate::rng::LearnRng;
use crate::task::{Task, resolve_scenario};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;

/// The generated map families.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Family {
    /// Uniform random obstacles at 10, 20 or 30 % density.
    Random,
    /// Rooms in a grid, walls between them with one or two doors each.
    Rooms,
    /// A corridor maze (recursive backtracker) with a few walls knocked out to make loops.
    Maze,
    /// Open space crossed by a few long walls, each with a gap.
    Walls,
    /// A MovingAI benchmark map from `shared/data/movingai` (not generated).
    Movingai,
}

impl Family {
    /// The four generated families.
    pub const GENERATED: [Family; 4] = [Family::Random, Family::Rooms, Family::Maze, Family::Walls];

    /// Lower-case name, as in map ids and on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Family::Random => "random",
            Family::Rooms => "rooms",
            Family::Maze => "maze",
            Family::Walls => "walls",
            Family::Movingai => "movingai",
        }
    }
}

impl fmt::Display for Family {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for Family {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "random" => Ok(Family::Random),
            "rooms" => Ok(Family::Rooms),
            "maze" => Ok(Family::Maze),
            "walls" => Ok(Family::Walls),
            "movingai" => Ok(Family::Movingai),
            _ => Err(format!(
                "unknown family '{s}' (expected random, rooms, maze, walls or movingai)"
            )),
        }
    }
}

/// Which half of the suite a map belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Split {
    /// Maps on which defaults may be chosen.
    Tuning,
    /// Maps on which figures are reported; never used to choose anything.
    Heldout,
}

impl Split {
    /// The half of a map id: the low bit of its FNV-1a hash (a fixed rule, independent of the
    /// suite seed, so a map's half never changes).
    pub fn of(id: &str) -> Split {
        if fnv1a(id.as_bytes()) & 1 == 0 {
            Split::Tuning
        } else {
            Split::Heldout
        }
    }
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Split::Tuning => "tuning",
            Split::Heldout => "heldout",
        })
    }
}

/// FNV-1a, 64 bit: a fixed, portable hash for the split and for per-map seeds.
pub fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= *b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// The sizes (square side, cells) the suite generates by default: the paper's three, the
/// MovingAI benchmark's 32, and two larger bands whose far pairs are hundreds of moves long.
pub const SIZES: [usize; 6] = [10, 20, 30, 32, 64, 128];

/// Maps per family and size by default: 4 families × 5 = 20 maps per size band.
pub const MAPS_PER_FAMILY: usize = 5;

/// One task of the suite: a map with a far start/goal pair, and where it comes from.
#[derive(Debug, Clone)]
pub struct SuiteTask {
    /// Unique id, e.g. `rooms-32-3` or `movingai-room-32-32-4-scen0`.
    pub id: String,
    /// Family.
    pub family: Family,
    /// Side of the (square) map; for MovingAI maps the larger side.
    pub size: usize,
    /// Tuning or held-out half.
    pub split: Split,
    /// The task (grid, start, goal, BFS optimum).
    pub task: Task,
}

/// Generates one map of a family and size (4 to [`crate::grid::MAX_SIDE`]) from a seed, with
/// its far start/goal pair.
pub fn generate(
    family: Family,
    size: usize,
    index: usize,
    suite_seed: u64,
) -> Result<SuiteTask, GridError> {
    let id = format!("{family}-{size}-{index}");
    let mut rng = LearnRng::new(suite_seed ^ fnv1a(id.as_bytes()));
    if !(4..=crate::grid::MAX_SIDE).contains(&size) {
        return Err(GridError::TooLarge {
            width: size,
            height: size,
        });
    }
    let free = match family {
        Family::Random => {
            let density = [0.1, 0.2, 0.3][index % 3];
            random_obstacles(size, density, &mut rng)
        }
        Family::Rooms => rooms(size, &mut rng),
        Family::Maze => maze(size, &mut rng),
        Family::Walls | Family::Movingai => walls(size, &mut rng),
    };
    let grid = Grid::new(size, size, free)?;
    let (start, goal, optimal_len) = far_pair(&grid, &mut rng);
    Ok(SuiteTask {
        split: Split::of(&id),
        task: Task {
            map_name: id.clone(),
            grid,
            start,
            goal,
            optimal_len,
        },
        id,
        family,
        size,
    })
}

/// The suite seed of `qfleet eval` and of a `suite:` map spec that names none.
pub const DEFAULT_SUITE_SEED: u64 = 1;

/// Largest side a `suite:` spec may name: its square must fit [`crate::grid::MAX_CELLS`], so a
/// too large spec is refused before anything is generated.
pub const SPEC_MAX_SIDE: usize = crate::grid::MAX_CELLS.isqrt();

/// Why a `suite:` map spec names no generated map.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SpecError {
    /// Not `FAMILY-SIZE-INDEX[@SEED]`, or a part out of range.
    #[error(
        "'suite:{spec}': {why} (expected suite:FAMILY-SIZE-INDEX[@SEED], e.g. suite:rooms-64-3, \
         FAMILY one of random, rooms, maze, walls, SIZE 4 to {max}, INDEX 0 to 999999)",
        max = SPEC_MAX_SIDE
    )]
    Bad {
        /// The spec after `suite:`.
        spec: String,
        /// What is wrong with it.
        why: String,
    },
}

/// The generated map a `suite:` spec names (`FAMILY-SIZE-INDEX`, the id `qfleet eval` prints,
/// optionally `@SEED`, default [`DEFAULT_SUITE_SEED`]): the same map, start and goal as in the
/// suite, so a map of the suite can be run with `learn`, `run`, `experiment` or `sweep`.
pub fn from_spec(spec: &str) -> Result<SuiteTask, SpecError> {
    let bad = |why: String| SpecError::Bad {
        spec: spec.to_owned(),
        why,
    };
    let (id, seed) = match spec.split_once('@') {
        Some((id, seed)) => (
            id,
            seed.parse::<u64>()
                .map_err(|_| bad(format!("seed '{seed}' is not a whole number")))?,
        ),
        None => (spec, DEFAULT_SUITE_SEED),
    };
    let mut parts = id.split('-');
    let (Some(family), Some(size), Some(index), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(bad("not three parts joined by '-'".into()));
    };
    let family: Family = family.parse().map_err(bad)?;
    if family == Family::Movingai {
        return Err(bad(
            "movingai maps are files: give the .map path instead".into()
        ));
    }
    let size: usize = size
        .parse()
        .ok()
        .filter(|s| (4..=SPEC_MAX_SIDE).contains(s))
        .ok_or_else(|| bad(format!("size '{size}' is not 4 to {SPEC_MAX_SIDE}")))?;
    let index: usize = index
        .parse()
        .ok()
        .filter(|i| *i < 1_000_000)
        .ok_or_else(|| bad(format!("index '{index}' is not 0 to 999999")))?;
    generate(family, size, index, seed).map_err(|e| bad(e.to_string()))
}

/// The whole generated suite: every family × size × index, in that order.
pub fn generated(
    sizes: &[usize],
    per_family: usize,
    suite_seed: u64,
) -> Result<Vec<SuiteTask>, GridError> {
    let mut v = Vec::new();
    for &size in sizes {
        for family in Family::GENERATED {
            for i in 0..per_family {
                v.push(generate(family, size, i, suite_seed)?);
            }
        }
    }
    Ok(v)
}

fn below(rng: &mut LearnRng, n: usize) -> usize {
    (((rng.bits() >> 32) * n as u64) >> 32) as usize
}

fn random_obstacles(size: usize, density: f32, rng: &mut LearnRng) -> Vec<bool> {
    (0..size * size).map(|_| rng.unit() >= density).collect()
}

fn rooms(size: usize, rng: &mut LearnRng) -> Vec<bool> {
    let mut free = vec![true; size * size];
    // Rooms of about 5..8 cells a side.
    let room = 5 + below(rng, 4);
    let walls_at: Vec<usize> = (1..)
        .map(|k| k * room)
        .take_while(|&w| w + 2 < size)
        .collect();
    for &w in &walls_at {
        for t in 0..size {
            free[w * size + t] = false; // horizontal wall at row w
            free[t * size + w] = false; // vertical wall at column w
        }
    }
    // Doors: each wall segment between two crossings gets one door (two with probability 1/3).
    let mut bounds = vec![0usize];
    bounds.extend(walls_at.iter().copied());
    bounds.push(size);
    for &w in &walls_at {
        for seg in bounds.windows(2) {
            let (lo, hi) = (seg[0] + usize::from(seg[0] > 0), seg[1]);
            if hi <= lo {
                continue;
            }
            let doors = if below(rng, 3) == 0 { 2 } else { 1 };
            for _ in 0..doors {
                let t = lo + below(rng, hi - lo);
                free[w * size + t] = true;
                let t = lo + below(rng, hi - lo);
                free[t * size + w] = true;
            }
        }
    }
    // A little clutter inside rooms.
    for c in free.iter_mut() {
        if *c && rng.unit() < 0.05 {
            *c = false;
        }
    }
    free
}

fn maze(size: usize, rng: &mut LearnRng) -> Vec<bool> {
    let mut free = vec![false; size * size];
    // Cells at odd coordinates; carve by an iterative recursive backtracker.
    let cells = (size - 1) / 2;
    if cells == 0 {
        return vec![true; size * size];
    }
    let at = |cx: usize, cy: usize| (2 * cy + 1) * size + 2 * cx + 1;
    let mut seen = vec![false; cells * cells];
    let mut stack = vec![(0usize, 0usize)];
    seen[0] = true;
    free[at(0, 0)] = true;
    while let Some(&(cx, cy)) = stack.last() {
        let mut options = [(0usize, 0usize); 4];
        let mut n = 0;
        let dirs: [(i64, i64); 4] = [(0, -1), (1, 0), (0, 1), (-1, 0)];
        for (dx, dy) in dirs {
            let (nx, ny) = (cx as i64 + dx, cy as i64 + dy);
            if nx >= 0 && ny >= 0 && (nx as usize) < cells && (ny as usize) < cells {
                let (nx, ny) = (nx as usize, ny as usize);
                if !seen[ny * cells + nx] {
                    options[n] = (nx, ny);
                    n += 1;
                }
            }
        }
        if n == 0 {
            stack.pop();
            continue;
        }
        let (nx, ny) = options[below(rng, n)];
        seen[ny * cells + nx] = true;
        free[at(nx, ny)] = true;
        free[(cy + ny + 1) * size + cx + nx + 1] = true; // the wall between them
        stack.push((nx, ny));
    }
    // Knock out about 8 % of the interior walls between two corridors: loops and detours.
    for y in 1..size - 1 {
        for x in 1..size - 1 {
            let i = y * size + x;
            if free[i] {
                continue;
            }
            let horiz = free[i - 1] && free[i + 1] && !free[i - size] && !free[i + size];
            let vert = free[i - size] && free[i + size] && !free[i - 1] && !free[i + 1];
            if (horiz || vert) && rng.unit() < 0.08 {
                free[i] = true;
            }
        }
    }
    free
}

fn walls(size: usize, rng: &mut LearnRng) -> Vec<bool> {
    let mut free = vec![true; size * size];
    let count = 2 + below(rng, 3);
    for k in 0..count {
        let horizontal = k.is_multiple_of(2);
        let at = 1 + below(rng, size - 2);
        let len = size * 3 / 4;
        let from_low = below(rng, 2) == 0;
        let gap = below(rng, len.max(1));
        for t in 0..len {
            if t == gap {
                continue;
            }
            let u = if from_low { t } else { size - 1 - t };
            let i = if horizontal {
                at * size + u
            } else {
                u * size + at
            };
            free[i] = false;
        }
    }
    free
}

/// A serpentine corridor `w` cells wide and `h` high: free rows at even y joined at alternating
/// ends, from (0, 0) to the far end of the last row: the longest path a map of that size holds
/// (1 090 moves at 51×41), for long-path tests and benchmarks. `None` when the grid is invalid.
pub fn serpentine(w: usize, h: usize) -> Option<Task> {
    let mut free = vec![false; w.checked_mul(h)?];
    for y in (0..h).step_by(2) {
        for x in 0..w {
            free[y * w + x] = true;
        }
        if y + 1 < h {
            let x = if (y / 2).is_multiple_of(2) { w - 1 } else { 0 };
            free[(y + 1) * w + x] = true;
        }
    }
    let grid = Grid::new(w, h, free).ok()?;
    let goal_x = if ((h - 1) / 2).is_multiple_of(2) {
        w - 1
    } else {
        0
    };
    let goal = Cell::new(u16::try_from(goal_x).ok()?, u16::try_from(h - 1).ok()?);
    let optimal_len = crate::path::shortest_moves(&grid, Cell::new(0, 0), goal)?;
    Some(Task {
        map_name: "serpentine".into(),
        grid,
        start: Cell::new(0, 0),
        goal,
        optimal_len,
    })
}

/// A far start/goal pair by a fixed rule: from a random free cell of the largest component,
/// the farthest cell becomes the start, and the farthest cell from it the goal (two BFS
/// sweeps: close to the component's diameter).
pub fn far_pair(grid: &Grid, rng: &mut LearnRng) -> (Cell, Cell, u32) {
    let free: Vec<usize> = (0..grid.len()).filter(|&i| grid.free_flags()[i]).collect();
    if free.is_empty() {
        return (Cell::new(0, 0), Cell::new(0, 0), 0);
    }
    // Largest component: try a few random seeds, keep the one reaching the most cells.
    let mut best: Option<(usize, Vec<u32>)> = None;
    for _ in 0..4 {
        let c = free[below(rng, free.len())];
        let d = bfs_distances(grid, grid.cell(c));
        let reach = d.iter().filter(|v| **v != u32::MAX).count();
        if best.as_ref().is_none_or(|(r, _)| reach > *r) {
            best = Some((reach, d));
        }
    }
    let d0 = best.map(|(_, d)| d).unwrap_or_default();
    let farthest = |d: &[u32]| {
        d.iter()
            .enumerate()
            .filter(|(_, v)| **v != u32::MAX)
            .max_by_key(|(i, v)| (**v, std::cmp::Reverse(*i)))
            .map(|(i, v)| (i, *v))
            .unwrap_or((0, 0))
    };
    let (s, _) = farthest(&d0);
    let start = grid.cell(s);
    let d1 = bfs_distances(grid, start);
    let (g, len) = farthest(&d1);
    (start, grid.cell(g), len)
}

/// The MovingAI maps of a directory as suite tasks: for a map with a `.scen` file beside it
/// (`NAME-*.scen`), scenario lines 0 and the last; otherwise the far pair
/// of [`far_pair`] with a seed from the map's name. Unreadable files are returned as errors
/// with their path, readable ones as tasks; a missing directory gives an empty list.
pub fn movingai(dir: &Path) -> (Vec<SuiteTask>, Vec<String>) {
    let mut tasks = Vec::new();
    let mut errors = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return (tasks, errors);
    };
    let mut maps: Vec<_> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "map"))
        .collect();
    maps.sort();
    let scens: Vec<_> = match std::fs::read_dir(dir) {
        Ok(e) => {
            let mut v: Vec<_> = e
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "scen"))
                .collect();
            v.sort();
            v
        }
        Err(_) => Vec::new(),
    };
    for path in maps {
        let spec = path.display().to_string();
        let m: GridMap = match load_map(&spec) {
            Ok(m) => m,
            Err(e) => {
                errors.push(format!("{spec}: {e}"));
                continue;
            }
        };
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let size = m.grid.width().max(m.grid.height());
        let scen = scens.iter().find(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with(&format!("{stem}-")))
        });
        let mut push = |id: String, task: Task| {
            tasks.push(SuiteTask {
                split: Split::of(&id),
                id,
                family: Family::Movingai,
                size,
                task,
            })
        };
        match scen.map(|p| load_scen(p)) {
            Some(Ok(lines)) if !lines.is_empty() => {
                let last = lines.len() - 1;
                for i in [0, last] {
                    match resolve_scenario(&m, &lines, i) {
                        Ok(t) => push(format!("movingai-{stem}-scen{i}"), t),
                        Err(e) => errors.push(format!("{spec} scenario {i}: {e}")),
                    }
                }
            }
            Some(Err(e)) => errors.push(format!("{}: {e}", spec)),
            _ => {
                let mut rng = LearnRng::new(fnv1a(stem.as_bytes()));
                let (start, goal, len) = far_pair(&m.grid, &mut rng);
                if len > 0 {
                    push(
                        format!("movingai-{stem}-far"),
                        Task {
                            map_name: stem.clone(),
                            grid: m.grid.clone(),
                            start,
                            goal,
                            optimal_len: len,
                        },
                    );
                }
            }
        }
    }
    (tasks, errors)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::path::shortest_moves;

    #[test]
    fn same_seed_same_suite_and_every_map_solvable() {
        let a = generated(&[10, 20, 30, 32, 64], 5, 7).unwrap();
        let b = generated(&[10, 20, 30, 32, 64], 5, 7).unwrap();
        assert_eq!(a.len(), 5 * 4 * 5);
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(x.id, y.id);
            assert_eq!(x.task, y.task, "{}", x.id);
        }
        for t in &a {
            let bfs = shortest_moves(&t.task.grid, t.task.start, t.task.goal);
            assert_eq!(bfs, Some(t.task.optimal_len), "{}", t.id);
            assert!(
                t.task.optimal_len as usize >= t.size,
                "{}: far pair spans the map ({} moves on side {})",
                t.id,
                t.task.optimal_len,
                t.size
            );
        }
        let c = generated(&[20], 5, 8).unwrap();
        assert!(
            c.iter().zip(&a[20..40]).any(|(x, y)| x.task != y.task),
            "another seed gives other maps"
        );
    }

    #[test]
    fn split_is_fixed_and_both_halves_are_used() {
        let all = generated(&[10, 20, 30, 32, 64], 5, 1).unwrap();
        let tuning = all.iter().filter(|t| t.split == Split::Tuning).count();
        assert!(tuning > 30 && tuning < 70, "{tuning} of 100 in tuning");
        assert!(
            generate(Family::Rooms, 3, 0, 1).is_err(),
            "too small is an error"
        );
        assert_eq!(Split::of("rooms-32-3"), Split::of("rooms-32-3"));
    }

    #[test]
    fn large_maps_have_long_paths() {
        let t = generate(Family::Maze, 128, 0, 1).unwrap();
        assert!(t.task.optimal_len > 300, "{}", t.task.optimal_len);
        let t = generate(Family::Walls, 128, 1, 1).unwrap();
        assert!(t.task.optimal_len >= 254, "{}", t.task.optimal_len);
    }

    #[test]
    fn a_suite_spec_names_the_same_map_pair_and_seed_as_the_suite() {
        let t = from_spec("rooms-64-3").unwrap();
        let g = generate(Family::Rooms, 64, 3, DEFAULT_SUITE_SEED).unwrap();
        assert_eq!((t.id.as_str(), &t.task), ("rooms-64-3", &g.task));
        let t7 = from_spec("rooms-64-3@7").unwrap();
        assert_eq!(t7.task, generate(Family::Rooms, 64, 3, 7).unwrap().task);
        assert_ne!(t7.task, g.task, "the seed is used");
        let m = crate::map::load_map("suite:maze-32-0").unwrap();
        let g = generate(Family::Maze, 32, 0, DEFAULT_SUITE_SEED).unwrap();
        assert_eq!(m.name, "maze-32-0");
        assert_eq!(m.grid, g.task.grid);
        assert_eq!(
            (m.start, m.goals.as_slice()),
            (Some(g.task.start), &[g.task.goal][..])
        );
    }

    #[test]
    fn a_bad_suite_spec_says_what_is_wrong() {
        for (spec, says) in [
            ("rooms-64", "three parts"),
            ("rooms-64-3-1", "three parts"),
            ("hills-64-3", "unknown family 'hills'"),
            ("movingai-64-3", "give the .map path"),
            ("rooms-3-0", "size '3'"),
            ("rooms-99999-0", "size '99999'"),
            ("maze-4096-0", "size '4096' is not 4 to 2048"),
            ("rooms-64-x", "index 'x'"),
            ("rooms-64-1000000", "index '1000000'"),
            ("rooms-64-1@-2", "seed '-2'"),
            ("", "three parts"),
        ] {
            let e = crate::map::load_map(&format!("suite:{spec}")).unwrap_err();
            let text = e.to_string();
            assert!(text.contains(says), "{spec}: {text}");
            assert!(text.contains("suite:FAMILY-SIZE-INDEX"), "{spec}: {text}");
        }
    }
}
