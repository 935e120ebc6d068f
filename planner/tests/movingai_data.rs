//! The real MovingAI benchmark files in `shared/data/movingai` (beside the workspace), when
//! present: every map parses, and the scenario file's 4-connected optima match a reference BFS.

use planner::map::{load_map, load_scen};
use planner::path::bfs_distances;
use planner::task::resolve_scenario;
use std::collections::VecDeque;
use std::path::PathBuf;

/// Says that a test skipped, and why: a copy of `qfleet_suite::skip` (`tests/support/lib.rs`
/// says why it looks so; `tests/skips.rs` keeps every copy identical).
fn skip(test: &str, reason: &str) {
    use std::io::Write;
    let line = format!("SKIPPED: {test}: {reason}\n");
    let _ = std::io::stderr().lock().write_all(line.as_bytes());
}

fn data_dir(test: &str) -> Option<PathBuf> {
    let dir = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/movingai"
    ));
    if dir.is_dir() {
        Some(dir)
    } else {
        skip(
            &format!("planner movingai_data::{test}"),
            &format!("no MovingAI data at {}", dir.display()),
        );
        None
    }
}

/// Moves from (sx, sy) to (gx, gy) on row-major `free` flags by a plain queue BFS.
fn reference_moves(
    w: usize,
    h: usize,
    free: &[bool],
    s: (usize, usize),
    g: (usize, usize),
) -> Option<u32> {
    let mut dist = vec![u32::MAX; w * h];
    let (start, goal) = (s.1 * w + s.0, g.1 * w + g.0);
    if !free[start] || !free[goal] {
        return None;
    }
    dist[start] = 0;
    let mut queue = VecDeque::from([start]);
    while let Some(i) = queue.pop_front() {
        if i == goal {
            return Some(dist[i]);
        }
        let (x, y) = (i % w, i / w);
        let candidates = [
            (x > 0).then(|| i - 1),
            (x + 1 < w).then(|| i + 1),
            (y > 0).then(|| i - w),
            (y + 1 < h).then(|| i + w),
        ];
        for j in candidates.into_iter().flatten() {
            if free[j] && dist[j] == u32::MAX {
                dist[j] = dist[i] + 1;
                queue.push_back(j);
            }
        }
    }
    None
}

#[test]
fn every_map_parses_with_its_stated_size() {
    let Some(dir) = data_dir("every_map_parses_with_its_stated_size") else {
        return;
    };
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "map") {
            continue;
        }
        let m = load_map(path.to_str().unwrap()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(m.start, None);
        assert!(m.goals.is_empty());
        assert!(m.grid.free_count() > 0, "{}", m.name);
        // Names like random-32-32-10 carry the width and height.
        let parts: Vec<&str> = m.name.split('-').collect();
        if let [_, w, h, ..] = parts.as_slice()
            && let (Ok(w), Ok(h)) = (w.parse::<usize>(), h.parse::<usize>())
            && m.name != "warehouse-10-20-10-2-1"
        {
            assert_eq!((m.grid.width(), m.grid.height()), (w, h), "{}", m.name);
        }
        if m.name == "empty-8-8" {
            assert_eq!(m.grid.free_count(), 64);
        }
        count += 1;
    }
    assert!(count >= 1, "no .map files in {}", dir.display());
}

#[test]
fn scenarios_match_a_reference_bfs() {
    let Some(dir) = data_dir("scenarios_match_a_reference_bfs") else {
        return;
    };
    let scen = load_scen(&dir.join("random-32-32-10-random-1.scen")).unwrap();
    assert_eq!(scen.len(), 461);
    let map = load_map(dir.join("random-32-32-10.map").to_str().unwrap()).unwrap();
    let (w, h) = (map.grid.width(), map.grid.height());
    assert_eq!((w, h), (32, 32));
    for (i, s) in scen.iter().enumerate() {
        assert_eq!(s.map, "random-32-32-10.map");
        let task = resolve_scenario(&map, &scen, i).unwrap_or_else(|e| panic!("scenario {i}: {e}"));
        // Four-connected paths are octile paths too, so the octile optimum is never longer.
        assert!(
            s.optimal_octile <= task.optimal_len as f64 + 1e-6,
            "scenario {i}: octile {} > 4-connected {}",
            s.optimal_octile,
            task.optimal_len
        );
        assert!(task.optimal_len >= task.start.manhattan(task.goal));
        if i < 20 {
            let reference = reference_moves(
                w,
                h,
                map.grid.free_flags(),
                (s.start.x as usize, s.start.y as usize),
                (s.goal.x as usize, s.goal.y as usize),
            );
            assert_eq!(Some(task.optimal_len), reference, "scenario {i}");
            let dist = bfs_distances(&map.grid, task.goal);
            assert_eq!(
                dist[map.grid.index(task.start)],
                task.optimal_len,
                "scenario {i}"
            );
        }
    }
}
