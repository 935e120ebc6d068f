//! The lifelong resolver as a specification: no deadlock in dead ends, never a conflict, goals
//! dealt as they are reached; and (ignored, `--nocapture`) its throughput on the lifelong
//! instances of `../shared/data/lifelong/`.

mod common;
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
                ..LifelongConfig::pibt_swap()
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

#[test]
fn the_look_ahead_keeps_a_dense_fleet_valid_and_moving() {
    // 16x16 with pillars, 80 robots (a third of the cells), uniform random goals
    let rows: String = (0..16)
        .map(|y| {
            (0..16)
                .map(|x| if x % 4 == 1 && y % 4 == 1 { '#' } else { '.' })
                .chain(['\n'])
                .collect::<String>()
        })
        .collect();
    let g = grid(&rows);
    let free: Vec<Cell> = (0..g.len())
        .map(|i| g.cell(i))
        .filter(|&c| g.is_free(c))
        .collect();
    let mut r = 7u64;
    let mut next = move || {
        r = r.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        (r >> 33) as usize
    };
    let starts: Vec<Cell> = free.iter().step_by(3).copied().take(80).collect();
    let tasks: Vec<Cell> = (0..4000).map(|_| free[next() % free.len()]).collect();
    let p = Problem::new(g.clone(), &starts, 80, tasks, 1).unwrap();
    let mut look = Lifelong::new(&p, LifelongConfig::default());
    let none = vec![None; 80];
    for _ in 0..400 {
        look.step(&none);
    }
    assert_valid(&g, &look.paths());
    for i in 0..80 {
        assert!(look.goals_reached(i) >= 2, "robot {i} stalled");
    }
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
        common::skip(
            "throughput_on_the_shared_lifelong_instances",
            &format!("no {}", dir.display()),
        );
        return;
    };
    let mut files: Vec<_> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    println!("instance                          PIBT+swap  default   ms/tick (PIBT+swap, default)");
    for f in files {
        let p = load(&f);
        let none = vec![None; p.team()];
        let mut row = vec![];
        for cfg in [LifelongConfig::pibt_swap(), LifelongConfig::default()] {
            let mut w = Lifelong::new(&p, cfg);
            let t0 = std::time::Instant::now();
            for _ in 0..1000 {
                w.step(&none);
            }
            let ms = t0.elapsed().as_secs_f64();
            assert_valid(p.grid(), &w.paths());
            row.push((w.reached() as f64 / 1000.0, ms));
        }
        println!(
            "{:34} {:8.3} {:8.3}   {:.3} {:.3}",
            f.file_name().unwrap().to_string_lossy(),
            row[0].0,
            row[1].0,
            row[0].1,
            row[1].1
        );
    }
}

/// A seeded random problem on `map` (MovingAI, from `shared/data/movingai`): `team` starts and
/// `team * 60` uniform random tasks, all in the largest connected part of the map.
fn tuning_problem(map: &str, team: usize, seed: u64) -> Problem {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/movingai");
    let g = load_map(dir.join(map).to_str().unwrap()).unwrap().grid;
    let mut rng = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x1234_5678;
    let mut next = move |m: usize| {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng % m as u64) as usize
    };
    // the largest component
    let mut comp = vec![usize::MAX; g.len()];
    let mut best: Vec<usize> = vec![];
    for s in 0..g.len() {
        if !g.is_free(g.cell(s)) || comp[s] != usize::MAX {
            continue;
        }
        comp[s] = s;
        let mut part = vec![s];
        let mut h = 0;
        while h < part.len() {
            let u = part[h];
            h += 1;
            for v in g.neighbors(g.cell(u)) {
                let v = g.index(v);
                if comp[v] == usize::MAX {
                    comp[v] = s;
                    part.push(v);
                }
            }
        }
        if part.len() > best.len() {
            best = part;
        }
    }
    // starts: a random permutation's first `team`
    let mut cells = best.clone();
    for k in 0..team {
        let j = k + next(cells.len() - k);
        cells.swap(k, j);
    }
    let starts: Vec<Cell> = cells[..team].iter().map(|&c| g.cell(c)).collect();
    let tasks: Vec<Cell> = (0..team * 60)
        .map(|_| g.cell(best[next(best.len())]))
        .collect();
    Problem::new(g, &starts, team, tasks, 1).unwrap()
}

/// `LIFE_TUNE="name:key=v,key=v;name2:..."`: the configurations compared (the first is the
/// baseline of the ratios).
fn tuning_configs() -> Vec<(String, LifelongConfig)> {
    let spec = std::env::var("LIFE_TUNE").unwrap_or_else(|_| "base:;new:".into());
    spec.split(';')
        .filter(|s| !s.is_empty())
        .map(|c| {
            let (name, kv) = c.split_once(':').unwrap_or((c, ""));
            let mut cfg = LifelongConfig::default();
            for e in kv.split(',').filter(|e| !e.is_empty()) {
                let (k, v) = e.split_once('=').unwrap();
                let b = v != "0";
                let n: u64 = v.parse().unwrap_or(0);
                match k {
                    "swap" => cfg.swap = b,
                    "seed" => cfg.seed = n,
                    "free" => cfg.prefer_free = b,
                    "pibt" => cfg = LifelongConfig::pibt_swap(),
                    "r" => cfg.rollouts = n as u8,
                    "h" => cfg.horizon = n as u8,
                    _ => panic!("unknown key {k}"),
                }
            }
            (name.to_string(), cfg)
        })
        .collect()
}

#[test]
#[ignore = "tuning: LIFE_TUNE=... cargo test -p mapf --release --test lifelong tuning -- --ignored --nocapture"]
fn tuning() {
    let set: &[(&str, &[usize], &[u64])] = &[
        ("random-32-32-10.map", &[64, 128, 256], &[101, 102]),
        ("room-32-32-4.map", &[64, 128], &[1]),
        ("maze-32-32-2.map", &[32, 64], &[1]),
        ("den312d.map", &[128, 256], &[1]),
        ("random-64-64-10.map", &[256], &[1]),
        ("warehouse-10-20-10-2-1.map", &[128, 256], &[1]),
    ];
    // LIFE_SET="map:team,team:seed,seed;...": another set
    let owned: Vec<(String, Vec<usize>, Vec<u64>)> = std::env::var("LIFE_SET")
        .map(|v| {
            v.split(';')
                .map(|e| {
                    let mut f = e.split(':');
                    let map = f.next().unwrap().to_string();
                    let teams = f.next().unwrap().split(',').map(|t| t.parse().unwrap());
                    let seeds = f.next().unwrap().split(',').map(|t| t.parse().unwrap());
                    (map, teams.collect(), seeds.collect())
                })
                .collect()
        })
        .unwrap_or_default();
    let owned_set: Vec<(&str, &[usize], &[u64])> = owned
        .iter()
        .map(|(m, t, s)| (m.as_str(), t.as_slice(), s.as_slice()))
        .collect();
    let set = if owned_set.is_empty() {
        set
    } else {
        &owned_set[..]
    };
    let ticks: usize = std::env::var("LIFE_TICKS")
        .ok()
        .and_then(|t| t.parse().ok())
        .unwrap_or(1000);
    let configs = tuning_configs();
    let mut log_ratio = vec![0.0f64; configs.len()];
    let mut time = vec![0.0f64; configs.len()];
    let mut count = 0;
    for &(map, teams, seeds) in set {
        for &team in teams {
            for &seed in seeds {
                let p = tuning_problem(map, team, seed);
                let none = vec![None; team];
                let mut row = vec![];
                for (c, (_, cfg)) in configs.iter().enumerate() {
                    let mut w = Lifelong::new(&p, *cfg);
                    let t0 = std::time::Instant::now();
                    for _ in 0..ticks {
                        w.step(&none);
                    }
                    time[c] += t0.elapsed().as_secs_f64();
                    row.push(w.reached() as f64 / ticks as f64);
                }
                for c in 0..configs.len() {
                    log_ratio[c] += (row[c] / row[0]).ln();
                }
                count += 1;
                let cells: Vec<String> = row.iter().map(|r| format!("{r:7.3}")).collect();
                println!("{map:28} {team:4} s{seed:<4} {}", cells.join(" "));
            }
        }
    }
    for (c, (name, _)) in configs.iter().enumerate() {
        println!(
            "{name:12} geomean ratio {:.4}  time {:.2} s",
            (log_ratio[c] / count as f64).exp(),
            time[c]
        );
    }
}
