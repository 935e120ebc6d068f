//! Paths files: what the world records is written in the mapf-visualizer format, read back
//! unchanged, and accepted by the independent checker with the same costs.

mod common;

use common::run;
use mapf::{Instance, WorldConfig, check, parse_paths, write_paths};
use planner::Cell;
use planner::map::parse_ascii;
use proptest::prelude::*;

#[test]
fn a_run_written_and_read_back_checks_the_same() {
    let grid = parse_ascii("t", b"....\n.#..\n....\n").unwrap().grid;
    let starts = vec![Cell::new(0, 0), Cell::new(3, 0), Cell::new(0, 2)];
    let goals = vec![Cell::new(3, 2), Cell::new(0, 2), Cell::new(3, 0)];
    let inst = Instance::new(grid, starts, goals).unwrap();
    let r = run(&inst, WorldConfig::default(), 100);
    let paths = r.world.paths();
    let text = write_paths(&paths);
    assert!(text.starts_with("0:(0,0),(3,0),(0,2),\n"), "{text}");
    let back = parse_paths(&text).unwrap();
    assert_eq!(back, paths);
    let a = check(inst.grid(), inst.starts(), inst.goals(), &paths).unwrap();
    let b = check(inst.grid(), inst.starts(), inst.goals(), &back).unwrap();
    assert_eq!(a, b);
}

proptest! {
    #[test]
    fn any_paths_round_trip(
        paths in proptest::collection::vec(
            proptest::collection::vec((0u16..4096, 0u16..4096), 1..20), 1..12)
    ) {
        let paths: Vec<Vec<Cell>> = paths
            .into_iter()
            .map(|p| p.into_iter().map(|(x, y)| Cell::new(x, y)).collect())
            .collect();
        let back = parse_paths(&write_paths(&paths)).unwrap();
        let len = paths.iter().map(Vec::len).max().unwrap();
        for (p, b) in paths.iter().zip(&back) {
            prop_assert_eq!(b.len(), len);
            prop_assert_eq!(&b[..p.len()], &p[..]);
            prop_assert!(b[p.len()..].iter().all(|c| c == p.last().unwrap()));
        }
    }

    #[test]
    fn any_text_parses_or_fails_without_panicking(text in "[0-9:(),\\n -]{0,80}") {
        let _ = parse_paths(&text);
    }
}
