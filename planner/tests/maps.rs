//! Built-in maps, format round trips and file loading, through the public API only.

use planner::map::{
    BUILTIN_MAPS, GridMap, MapError, PAPER_10, PAPER_20, PAPER_30, builtin, builtin_text, load_map,
    load_scen, parse_ascii, parse_movingai_map, parse_scen,
};
use planner::path::{bfs_distances, bfs_path};
use planner::task::{resolve_scenario, resolve_task};
use planner::{Cell, Grid};
use std::path::PathBuf;

/// The paper's shortest path lengths, in moves.
const PAPER: [(&str, usize, u32); 3] = [
    ("paper-10", 10, 19),
    ("paper-20", 20, 39),
    ("paper-30", 30, 58),
];

fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("planner-maps-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Whether a straight route (along `first` then `second`) is free of obstacles.
fn route_free(g: &Grid, cells: impl IntoIterator<Item = Cell>) -> bool {
    cells.into_iter().all(|c| g.is_free(c))
}

#[test]
fn builtin_names_and_texts_match() {
    assert_eq!(BUILTIN_MAPS, ["paper-10", "paper-20", "paper-30"]);
    assert_eq!(builtin_text("paper-10"), Some(PAPER_10));
    assert_eq!(builtin_text("paper-20"), Some(PAPER_20));
    assert_eq!(builtin_text("paper-30"), Some(PAPER_30));
    assert_eq!(builtin_text("paper-40"), None);
    assert!(builtin("paper-40").is_none());
    for name in BUILTIN_MAPS {
        assert_eq!(
            load_map(&format!("builtin:{name}")).unwrap(),
            builtin(name).unwrap()
        );
    }
}

#[test]
fn builtin_maps_have_the_papers_shortest_paths_in_moves() {
    for (name, side, moves) in PAPER {
        let m = builtin(name).unwrap();
        assert_eq!(m.name, name);
        assert_eq!((m.grid.width(), m.grid.height()), (side, side), "{name}");
        let task = resolve_task(&m, None, None).unwrap();
        assert_eq!(task.optimal_len, moves, "{name}");
        let path = bfs_path(&m.grid, task.start, task.goal).unwrap();
        assert_eq!(
            path.len() as u32,
            moves + 1,
            "{name}: a path of n moves visits n + 1 cells"
        );
        let dist = bfs_distances(&m.grid, task.goal);
        assert_eq!(dist[m.grid.index(task.start)], moves, "{name}");
    }
}

#[test]
fn builtin_maps_have_about_a_fifth_obstacles() {
    for (name, _, _) in PAPER {
        let f = builtin(name).unwrap().obstacle_fraction();
        assert!((0.18..=0.22).contains(&f), "{name}: obstacle fraction {f}");
    }
}

#[test]
fn builtin_maps_run_corner_to_corner() {
    for (name, side, _) in PAPER {
        let m = builtin(name).unwrap();
        let s = m.start.unwrap();
        assert_eq!(m.goals.len(), 1, "{name}");
        let g = m.goals[0];
        let far = side as u16 - 1;
        assert!(
            s.x <= 1 && s.y <= 1,
            "{name}: start {s} is not at the top-left corner"
        );
        assert!(
            g.x + 1 >= far && g.y + 1 >= far,
            "{name}: goal {g} is not at the bottom-right corner"
        );
    }
}

#[test]
fn builtin_maps_block_the_border_routes_and_have_no_dead_space() {
    for (name, _, moves) in PAPER {
        let m = builtin(name).unwrap();
        let (s, g) = (m.start.unwrap(), m.goals[0]);
        let along_top = (s.x..=g.x)
            .map(|x| Cell::new(x, s.y))
            .chain((s.y..=g.y).map(|y| Cell::new(g.x, y)));
        let along_left = (s.y..=g.y)
            .map(|y| Cell::new(s.x, y))
            .chain((s.x..=g.x).map(|x| Cell::new(x, g.y)));
        assert!(
            !route_free(&m.grid, along_top),
            "{name}: the top/right border route is open"
        );
        assert!(
            !route_free(&m.grid, along_left),
            "{name}: the left/bottom border route is open"
        );
        // paper-10 and paper-20 need a step back; paper-30 has a monotone route inside.
        let detour = moves - s.manhattan(g);
        assert_eq!(detour, if name == "paper-30" { 0 } else { 2 }, "{name}");
        // Every free cell can be reached: no sealed-off rooms to waste exploration on.
        let dist = bfs_distances(&m.grid, g);
        let reachable = dist.iter().filter(|d| **d != u32::MAX).count();
        assert_eq!(reachable, m.grid.free_count(), "{name}");
    }
}

#[test]
fn ascii_round_trips() {
    let text = "; a small office\nS..#\n.#..\n..#G\nG...\n";
    let m = parse_ascii("office.txt", text.as_bytes()).unwrap();
    let again = parse_ascii("office.txt", m.to_ascii().as_bytes()).unwrap();
    assert_eq!(again, m);
    assert_eq!(m.to_ascii(), "S..#\n.#..\n..#G\nG...\n");
    for name in BUILTIN_MAPS {
        let m = builtin(name).unwrap();
        assert_eq!(parse_ascii(name, m.to_ascii().as_bytes()).unwrap(), m);
    }
}

#[test]
fn movingai_round_trips_and_matches_ascii() {
    let text = "type octile\nheight 3\nwidth 5\nmap\n..@T.\nO.W..\n.G.S.\n";
    let m = parse_movingai_map("x.map", text.as_bytes()).unwrap();
    let again = parse_movingai_map("x.map", m.to_movingai().as_bytes()).unwrap();
    assert_eq!(again, m);
    let ascii = parse_ascii("x.txt", b"..##.\n#.#..\n.....\n").unwrap();
    assert_eq!(ascii.grid, m.grid);
    for name in BUILTIN_MAPS {
        let m = builtin(name).unwrap();
        let back = parse_movingai_map(name, m.to_movingai().as_bytes()).unwrap();
        assert_eq!(back.grid, m.grid);
        assert_eq!((back.start, back.goals.len()), (None, 0));
    }
}

#[test]
fn loads_files_of_both_formats_and_scenarios() {
    let dir = scratch("load");
    let ascii = dir.join("room.txt");
    std::fs::write(&ascii, "S.#\r\n..G\r\n").unwrap();
    let m = load_map(ascii.to_str().unwrap()).unwrap();
    assert_eq!(
        (m.name.as_str(), m.start, m.goals.clone()),
        ("room", Some(Cell::new(0, 0)), vec![Cell::new(2, 1)])
    );

    let map = dir.join("room.map");
    std::fs::write(&map, m.to_movingai()).unwrap();
    let mm = load_map(map.to_str().unwrap()).unwrap();
    assert_eq!(mm.grid, m.grid);
    assert_eq!(mm.start, None);

    let scen = dir.join("room.scen");
    std::fs::write(&scen, "version 1\n0\troom.map\t3\t2\t0\t0\t2\t1\t3\n").unwrap();
    let s = load_scen(&scen).unwrap();
    assert_eq!(s.len(), 1);
    let t = resolve_scenario(&mm, &s, 0).unwrap();
    assert_eq!(t.optimal_len, 3);
    assert_eq!(t.map_name, "room");

    // Errors name the path the user gave.
    let bad = dir.join("bad.txt");
    std::fs::write(&bad, "S.\n.x\n").unwrap();
    let e = load_map(bad.to_str().unwrap()).unwrap_err();
    assert!(matches!(e, MapError::UnknownChar { .. }));
    assert_eq!(
        e.to_string(),
        format!(
            "{}:2:2: unknown character 'x' (expected '#', '.', 'S' or 'G')",
            bad.display()
        )
    );
    let e = load_scen(&bad).unwrap_err();
    assert!(matches!(e, MapError::Header { .. }), "{e}");
    assert!(
        e.to_string()
            .starts_with(&format!("{}:1: expected 'version 1'", bad.display())),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn scenario_lines_keep_octile_lengths_apart_from_bfs() {
    let m: GridMap = parse_ascii("open.txt", b".....\n.....\n.....\n").unwrap();
    let s = parse_scen(
        "open.scen",
        b"version 1\n1\topen.map\t5\t3\t0\t0\t4\t2\t4.82842712\n",
    )
    .unwrap();
    let t = resolve_scenario(&m, &s, 0).unwrap();
    // Octile (diagonals allowed) is 2 * sqrt2 + 2; four-connected moves need 6.
    assert_eq!(t.optimal_len, 6);
    assert!((s[0].optimal_octile - 4.82842712).abs() < 1e-9);
}
