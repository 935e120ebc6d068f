//! Property: on random small instances the resolver never lets two robots collide, and it
//! never deadlocks where a solution exists (a breadth-first search over joint states, written
//! here from the rules, decides whether one does).

mod common;

use common::run;
use mapf::check::conflicts;
use mapf::{Instance, Status, WorldConfig, check};
use planner::{Cell, Grid};
use proptest::prelude::*;
use std::collections::VecDeque;

/// Whether every agent can reach its goal together: BFS over joint configurations where each
/// agent waits or steps to a free 4-neighbour, with no vertex and no swap conflict.
fn solvable(grid: &Grid, starts: &[Cell], goals: &[Cell]) -> bool {
    let n = starts.len();
    let cells = grid.len();
    // each cell's options: itself, then its free neighbours
    let options: Vec<Vec<usize>> = (0..cells)
        .map(|i| {
            let c = grid.cell(i);
            let mut o = vec![i];
            for (dx, dy) in [(0i64, -1i64), (1, 0), (0, 1), (-1, 0)] {
                let (x, y) = (i64::from(c.x) + dx, i64::from(c.y) + dy);
                if grid.contains(x, y) && grid.is_free(Cell::new(x as u16, y as u16)) {
                    o.push(grid.index(Cell::new(x as u16, y as u16)));
                }
            }
            o
        })
        .collect();
    let code = |cfg: &[usize]| cfg.iter().fold(0usize, |acc, &c| acc * cells + c);
    let start: Vec<usize> = starts.iter().map(|&c| grid.index(c)).collect();
    let goal: Vec<usize> = goals.iter().map(|&c| grid.index(c)).collect();
    let mut seen = vec![false; cells.pow(n as u32)];
    seen[code(&start)] = true;
    let mut queue = VecDeque::from([start]);
    let mut next = vec![0usize; n];
    while let Some(cfg) = queue.pop_front() {
        if cfg == goal {
            return true;
        }
        // depth-first over the agents' choices, pruning conflicts as they appear
        fn choose(
            k: usize,
            cfg: &[usize],
            next: &mut [usize],
            options: &[Vec<usize>],
            out: &mut dyn FnMut(&[usize]),
        ) {
            if k == cfg.len() {
                out(next);
                return;
            }
            for &v in &options[cfg[k]] {
                let clash = (0..k)
                    .any(|j| next[j] == v || (next[j] == cfg[k] && v == cfg[j] && v != cfg[k]));
                if !clash {
                    next[k] = v;
                    choose(k + 1, cfg, next, options, out);
                }
            }
        }
        choose(0, &cfg, &mut next, &options, &mut |nx: &[usize]| {
            let c = code(nx);
            if !seen[c] {
                seen[c] = true;
                queue.push_back(nx.to_vec());
            }
        });
    }
    false
}

/// A random small instance: a grid of 3x3 to 5x4 with a few walls and 2 to 4 agents.
fn instance() -> impl Strategy<Value = (Grid, Vec<Cell>, Vec<Cell>)> {
    (3usize..=5, 3usize..=4, 2usize..=4).prop_flat_map(|(w, h, n)| {
        (
            proptest::collection::vec(prop::bool::weighted(0.8), w * h),
            proptest::sample::subsequence((0..w * h).collect::<Vec<_>>(), 2 * n),
            Just((w, h)),
        )
            .prop_flat_map(|(free, cells, wh)| {
                (
                    Just(free),
                    Just(wh),
                    Just(cells.clone()),
                    Just(cells).prop_shuffle(),
                )
            })
            .prop_map(move |(mut free, (w, h), _, cells)| {
                for &c in &cells {
                    free[c] = true; // starts and goals are free
                }
                let grid = Grid::new(w, h, free).unwrap();
                let at = |i: usize| Cell::new((i % w) as u16, (i / w) as u16);
                let starts = cells[..n].iter().map(|&i| at(i)).collect();
                let goals = cells[n..].iter().map(|&i| at(i)).collect();
                (grid, starts, goals)
            })
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    #[test]
    fn never_a_conflict_and_never_a_deadlock_where_a_solution_exists(
        (grid, starts, goals) in instance(),
        plan_ahead in any::<bool>(),
    ) {
        let Ok(inst) = Instance::new(grid.clone(), starts.clone(), goals.clone()) else {
            // an unreachable goal: refused before anything runs
            return Ok(());
        };
        let config = WorldConfig { stall_ticks: 8, plan_ahead, ..WorldConfig::default() };
        let r = run(&inst, config, 400);
        let paths = r.world.paths();
        match check(&grid, &starts, &goals, &paths) {
            Ok(_) => prop_assert!(r.world.all_arrived()),
            Err(v) => prop_assert_eq!(conflicts(&v), 0, "{:?}", v),
        }
        let possible = solvable(&grid, &starts, &goals);
        if possible {
            prop_assert!(r.world.all_arrived(), "solvable but {:?} after {} ticks", r.last, r.ticks);
        } else {
            prop_assert!(!r.world.all_arrived());
            prop_assert!(
                matches!(r.last, Status::Unsolvable | Status::Stalled),
                "unsolvable but {:?} after {} ticks", r.last, r.ticks
            );
        }
    }
}

#[test]
fn the_joint_search_knows_a_corridor_swap_is_impossible() {
    let g = Grid::new(3, 1, vec![true; 3]).unwrap();
    let (a, b) = (Cell::new(0, 0), Cell::new(2, 0));
    assert!(!solvable(&g, &[a, b], &[b, a]));
    let g = Grid::new(3, 2, vec![true, true, true, false, true, false]).unwrap();
    assert!(solvable(&g, &[a, b], &[b, a]));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    /// With a robot going silent for a while and another removed mid-run, every tick is still
    /// collision-free, the silent robot never moves, and the removed one's cell is free.
    #[test]
    fn silent_and_removed_robots_never_cause_a_conflict(
        (grid, starts, goals) in instance(),
        hang_from in 0u32..10,
        hang_for in 0u32..30,
        remove_at in 0u32..40,
        plan_ahead in any::<bool>(),
    ) {
        let Ok(inst) = Instance::new(grid.clone(), starts, goals) else { return Ok(()) };
        let config = WorldConfig { stall_ticks: 8, plan_ahead, ..WorldConfig::default() };
        let mut w = mapf::World::new(&inst, config);
        let mut intents = vec![None; inst.agents()];
        let last = inst.agents() - 1;
        for t in 0..150u32 {
            if t == remove_at {
                prop_assert!(w.remove(last));
            }
            common::greedy(&inst, w.positions(), &mut intents);
            let silent = (hang_from..hang_from + hang_for).contains(&t);
            if silent {
                intents[0] = None;
            }
            let before = w.positions().to_vec();
            w.step(&intents).unwrap();
            let after = w.positions();
            if silent {
                prop_assert_eq!(after[0], before[0], "a silent robot moved at tick {}", t);
            }
            for a in 0..after.len() {
                let Some(p) = after[a] else { continue };
                prop_assert!(grid.is_free(p));
                if let Some(q) = before[a] {
                    prop_assert!(p.manhattan(q) <= 1, "agent {} jumped", a);
                }
                for b in a + 1..after.len() {
                    let Some(r) = after[b] else { continue };
                    prop_assert_ne!(p, r, "vertex conflict at tick {}", t + 1);
                    let swap = before[a] == Some(r) && before[b] == Some(p) && p != r;
                    prop_assert!(!swap, "swap conflict at tick {}", t);
                }
            }
        }
    }
}
