//! The lifelong resolver as a specification: no deadlock in dead ends, never a conflict, goals
//! dealt as they are reached; and (ignored, `--nocapture`) its throughput on the lifelong
//! instances of `../shared/data/lifelong/`.

use mapf::lifelong::{Lifelong, LifelongConfig, Part, Problem, Spec, parse_cells};
use planner::map::{load_map, parse_ascii};
use planner::{Cell, Grid};

fn grid(rows: &str) -> Grid {
    parse_ascii("t", rows.as_bytes()).unwrap().grid
}

/// No two robots on one cell, no swap, every move to a 4-neighbour or a wait, on free cells.
fn assert_valid(g: &Grid, paths: &[Vec<Cell>]) {
    let t_max = paths[0].len();
    for t in 0..t_max {
        let mut seen = std::collections::HashSet::new();
        for (i, p) in paths.iter().enumerate() {
            assert!(g.is_free(p[t]), "robot {i} on a wall at {t}");
            assert!(
                seen.insert(p[t]),
                "vertex conflict at tick {t} on {:?}",
                p[t]
            );
            if t > 0 {
                assert!(p[t - 1].manhattan(p[t]) <= 1, "robot {i} jumps at tick {t}");
                for (j, q) in paths.iter().enumerate() {
                    assert!(
                        i == j || !(p[t] == q[t - 1] && q[t] == p[t - 1] && p[t] != q[t]),
                        "robots {i} and {j} swap at tick {t}"
                    );
                }
            }
        }
    }
}

#[test]
fn a_robot_whose_goal_is_a_dead_end_held_by_another_gets_in() {
    // robot 0 waits beside its goal, the dead end (0,0) where robot 1 stands: robot 1 can only
    // leave through robot 0's cell. Plain PIBT holds them there for good; the swap rule pulls
    // robot 1 out and robot 0 in.
    let g = grid("..#\n#..\n#..\n");
    let tasks = vec![Cell::new(0, 0), Cell::new(2, 2)];
    let starts = [Cell::new(1, 0), Cell::new(0, 0)];
    let p = Problem::new(g.clone(), &starts, 2, tasks, 1).unwrap();
    // which robot PIBT serves first is the seed's (a unique fraction each): with robot 0 first
    // plain PIBT never gets it in; the swap rule does whatever the order
    let mut plain_stuck = 0;
    for seed in 0..16 {
        let mut plain = Lifelong::new(
            &p,
            LifelongConfig {
                swap: false,
                seed,
                ..Default::default()
            },
        );
        let mut swap = Lifelong::new(
            &p,
            LifelongConfig {
                seed,
                ..Default::default()
            },
        );
        for _ in 0..50 {
            plain.step(&[None, None]);
            swap.step(&[None, None]);
        }
        plain_stuck += usize::from(plain.goals_reached(0) == 0);
        assert!(
            swap.goals_reached(0) >= 1,
            "seed {seed}: robot 0 never reached its dead-end goal"
        );
        assert!(
            swap.reached() >= 4,
            "seed {seed}: the pair stopped serving goals: {}",
            swap.reached()
        );
        assert_valid(&g, &swap.paths());
    }
    assert!(
        plain_stuck > 0,
        "plain PIBT never deadlocked: the case is not the one this rule is for"
    );
}

#[test]
fn a_corridor_with_one_pocket_lets_two_robots_pass_for_ever() {
    let g = grid("###.###\n.......\n");
    let (a, b) = (Cell::new(0, 1), Cell::new(6, 1));
    let p = Problem::new(g.clone(), &[a, b], 2, vec![b, a], 1).unwrap();
    let mut w = Lifelong::new(&p, LifelongConfig::default());
    for _ in 0..200 {
        w.step(&[None, None]);
    }
    assert!(
        w.goals_reached(0) >= 5 && w.goals_reached(1) >= 5,
        "{} {}",
        w.goals_reached(0),
        w.goals_reached(1)
    );
    assert_valid(&g, &w.paths());
}

#[test]
fn goals_are_dealt_round_robin_as_they_are_reached() {
    let g = grid(".....\n");
    // one robot: goals 4, 0, 4, 0, ... (tasks cycle)
    let p = Problem::new(
        g.clone(),
        &[Cell::new(2, 0)],
        1,
        vec![Cell::new(4, 0), Cell::new(0, 0)],
        1,
    )
    .unwrap();
    let mut w = Lifelong::new(&p, LifelongConfig::default());
    let mut at = vec![];
    for _ in 0..20 {
        let t = w.step(&[None]);
        if t.reached > 0 {
            at.push(t.tick);
        }
    }
    // 2 ticks to (4,0), then 4 to (0,0), 4 back, ...
    assert_eq!(at, vec![2, 6, 10, 14, 18]);
    assert_eq!(w.goals_reached(0), 5);
    assert_eq!(w.goal(0), Cell::new(0, 0));
}

#[test]
fn a_ranking_is_followed_where_it_is_legal() {
    // the robot ranks "left" first although its goal is right: it is granted left
    let g = grid(".....\n");
    let p = Problem::new(g, &[Cell::new(2, 0)], 1, vec![Cell::new(4, 0)], 1).unwrap();
    let mut w = Lifelong::new(&p, LifelongConfig::default());
    let left = mapf::Intent::new(&[mapf::Move::Left]).unwrap();
    w.step(&[Some(left)]);
    assert_eq!(w.position(0), Cell::new(1, 0));
}

#[test]
fn a_removed_robot_frees_its_cell_and_reaches_nothing_more() {
    let g = grid("...\n");
    let p = Problem::new(
        g,
        &[Cell::new(0, 0), Cell::new(1, 0)],
        2,
        vec![Cell::new(2, 0), Cell::new(0, 0)],
        1,
    )
    .unwrap();
    let mut w = Lifelong::new(&p, LifelongConfig::default());
    assert!(w.remove(1));
    assert!(!w.remove(1));
    for _ in 0..10 {
        w.step(&[None, None]);
    }
    assert_eq!(w.goals_reached(1), 0);
    assert!(w.goals_reached(0) >= 3);
}

/// Reads a LoRR 2023 problem the way the CLI does (files relative to it).
pub fn load(path: &std::path::Path) -> Problem {
    let dir = path.parent().unwrap();
    let spec = Spec::parse(&std::fs::read_to_string(path).unwrap()).unwrap();
    let map = load_map(dir.join(&spec.map_file).to_str().unwrap()).unwrap();
    let read = |f: &str| std::fs::read_to_string(dir.join(f)).unwrap();
    let starts = parse_cells(&read(&spec.agent_file), Part::Agents, &map.grid).unwrap();
    let tasks = parse_cells(&read(&spec.task_file), Part::Tasks, &map.grid).unwrap();
    Problem::new(
        map.grid,
        &starts,
        spec.team_size as usize,
        tasks,
        spec.num_tasks_reveal,
    )
    .unwrap()
}

#[test]
#[ignore = "a measurement: cargo test -p mapf --release --test lifelong -- --ignored --nocapture"]
fn throughput_on_the_shared_lifelong_instances() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/lifelong");
    let Ok(rd) = std::fs::read_dir(&dir) else {
        println!(
            "SKIPPED: throughput_on_the_shared_lifelong_instances: no {}",
            dir.display()
        );
        return;
    };
    let mut files: Vec<_> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    for f in files {
        let p = load(&f);
        for swap in [false, true] {
            let mut w = Lifelong::new(
                &p,
                LifelongConfig {
                    swap,
                    ..Default::default()
                },
            );
            let none = vec![None; p.team()];
            let t0 = std::time::Instant::now();
            for _ in 0..1000 {
                w.step(&none);
            }
            println!(
                "{} swap={swap}: {} goals, throughput {:.3}, {:.3} s",
                f.file_name().unwrap().to_string_lossy(),
                w.reached(),
                w.reached() as f64 / 1000.0,
                t0.elapsed().as_secs_f64()
            );
            if swap {
                assert_valid(p.grid(), &w.paths());
            }
        }
    }
}
