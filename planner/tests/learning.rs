//! Behaviour of the learners: the update rule, collisions, determinism and convergence.

use planner::map::builtin;
use planner::path::shortest_moves;
use planner::task::{Task, resolve_task};
use planner::{Action, Cell, Grid, Learner, LearnerConfig, Outcome, PolicyConfig, Transition};
use proptest::prelude::*;

fn paper(name: &str) -> Task {
    resolve_task(&builtin(name).expect("builtin map"), None, None).expect("task")
}

fn corridor() -> Task {
    // S . . G   on a 4x1 grid: three moves.
    let grid = Grid::new(4, 1, vec![true; 4]).unwrap();
    Task {
        map_name: "corridor".into(),
        grid,
        start: Cell::new(0, 0),
        goal: Cell::new(3, 0),
        optimal_len: 3,
    }
}

#[test]
fn update_rule_is_textbook_q_learning() {
    let task = corridor();
    let cfg = LearnerConfig {
        policy: PolicyConfig::TRADITIONAL,
        ..LearnerConfig::traditional(10, 3)
    };
    let mut l = Learner::new(&task, cfg).unwrap();
    l.begin_episode();
    // Put a value on the next cell so the bootstrap term is visible.
    l.q_mut().row_mut(1)[Action::Right as usize] = 0.5;
    let before = *l.q().row(0);
    let s = l.step();
    let a = s.action as usize;
    let (alpha, gamma) = (0.1f32, 0.6f32);
    let expected = match s.transition {
        Transition::Collided => {
            before[a]
                + alpha
                    * (-1.0 + gamma * before.iter().cloned().fold(f32::MIN, f32::max) - before[a])
        }
        Transition::Moved => before[a] + alpha * (0.0 + gamma * 0.5 - before[a]),
        t => panic!("unexpected {t:?}"),
    };
    assert!(
        (s.q - expected).abs() < 1e-7,
        "q {} expected {}",
        s.q,
        expected
    );
    assert_eq!(l.q().row(0)[a], s.q);
}

#[test]
fn terminal_update_does_not_bootstrap() {
    let task = corridor();
    let mut l = Learner::new(&task, LearnerConfig::traditional(1, 1)).unwrap();
    l.q_mut().row_mut(3)[0] = 100.0; // the goal's own row must not matter
    l.begin_episode();
    loop {
        let s = l.step();
        if s.transition == Transition::Goal {
            assert!(
                (s.q - 0.1).abs() < 1e-6,
                "first goal update is alpha * reward, got {}",
                s.q
            );
            break;
        }
        assert!(!s.done);
    }
}

#[test]
fn collisions_keep_position_and_do_not_end_the_episode() {
    let task = paper("paper-10");
    let mut l = Learner::new(&task, LearnerConfig::traditional(5, 9)).unwrap();
    let mut saw_collision = false;
    for _ in 0..5 {
        l.begin_episode();
        loop {
            let s = l.step();
            if s.transition == Transition::Collided {
                saw_collision = true;
                assert_eq!(s.state, s.next);
                assert!(!s.done || l.max_steps() > 0);
            }
            if s.done {
                let rec = l.end_episode(s.transition);
                assert_ne!(rec.outcome, Outcome::Pseudo);
                break;
            }
        }
    }
    assert!(
        saw_collision,
        "a random walk on paper-10 bumps into something"
    );
}

#[test]
fn same_seed_same_episodes() {
    let task = paper("paper-20");
    for cfg in [
        LearnerConfig::traditional(60, 42),
        LearnerConfig::improved(60, 42),
    ] {
        let (a, sa) = Learner::new(&task, cfg).unwrap().run(|_| {});
        let (b, sb) = Learner::new(&task, cfg).unwrap().run(|_| {});
        assert_eq!(a, b);
        assert_eq!(sa, sb);
        let (c, _) = Learner::new(&task, LearnerConfig { seed: 43, ..cfg })
            .unwrap()
            .run(|_| {});
        assert_ne!(a, c, "another seed gives another run");
    }
}

#[test]
fn improved_learner_finds_the_optimum_on_paper_10() {
    let task = paper("paper-10");
    let mut optimal = 0;
    for seed in 0..5 {
        let (_, s) = Learner::new(&task, LearnerConfig::improved(300, seed))
            .unwrap()
            .run(|_| {});
        optimal += (s.final_path_len == Some(task.optimal_len)) as u32;
        assert!(s.final_path_len.is_some(), "seed {seed}: final path loops");
    }
    assert!(
        optimal >= 4,
        "only {optimal}/5 seeds end on the optimal path"
    );
}

#[test]
fn pseudo_targets_appear_after_the_goal_and_are_removed() {
    let task = paper("paper-10");
    let pseudo = planner::PseudoConfig {
        remove_at: 0.5,
        ..Default::default()
    };
    let mut l = Learner::new(
        &task,
        LearnerConfig {
            pseudo: Some(pseudo),
            ..LearnerConfig::improved(40, 5)
        },
    )
    .unwrap();
    let mut first_goal = None;
    let mut pseudo_endings = 0;
    while !l.finished() {
        let r = l.run_episode();
        if r.outcome == Outcome::Goal && first_goal.is_none() {
            first_goal = Some(r.episode);
            let found = l.take_new_pseudo_targets();
            assert!(
                !found.is_empty(),
                "the robot visited cells near the goal on its way in"
            );
            let goal = task.goal;
            for (c, v) in found {
                let d = task.grid.cell(c as usize).manhattan(goal);
                assert!((1..=3).contains(&d), "pseudo target at distance {d}");
                assert!(v > 0.0 && v < 1.0);
            }
        }
        if r.outcome == Outcome::Pseudo {
            assert!(
                first_goal.is_some(),
                "no pseudo target before the goal is found"
            );
            assert!(r.episode < 20, "pseudo targets are removed at N/2");
            pseudo_endings += 1;
        }
    }
    assert!(first_goal.is_some());
    assert!(pseudo_endings > 0);
    assert!(l.pseudo_targets().is_empty());
}

#[test]
fn bad_parameters_are_rejected() {
    let task = corridor();
    for cfg in [
        LearnerConfig {
            alpha: 0.0,
            ..LearnerConfig::improved(10, 0)
        },
        LearnerConfig {
            alpha: 1.5,
            ..LearnerConfig::improved(10, 0)
        },
        LearnerConfig {
            gamma: 1.0,
            ..LearnerConfig::improved(10, 0)
        },
        LearnerConfig {
            gamma: -0.1,
            ..LearnerConfig::improved(10, 0)
        },
        LearnerConfig {
            episodes: 0,
            ..LearnerConfig::improved(10, 0)
        },
        LearnerConfig {
            alpha: f32::NAN,
            ..LearnerConfig::improved(10, 0)
        },
    ] {
        assert!(Learner::new(&task, cfg).is_err(), "{cfg:?}");
    }
}

/// A random small map with a reachable goal: (grid, start, goal, optimum).
fn small_map() -> impl Strategy<Value = (Grid, Cell, Cell, u32)> {
    (
        4usize..8,
        4usize..8,
        proptest::collection::vec(0u8..100, 64),
    )
        .prop_filter_map("goal reachable", |(w, h, noise)| {
            let free: Vec<bool> = (0..w * h).map(|i| noise[i % 64] >= 18).collect();
            let mut free = free;
            free[0] = true;
            free[w * h - 1] = true;
            let grid = Grid::new(w, h, free).ok()?;
            let (s, g) = (Cell::new(0, 0), Cell::new(w as u16 - 1, h as u16 - 1));
            let opt = shortest_moves(&grid, s, g)?;
            Some((grid, s, g, opt))
        })
}

proptest! {
    // Q-learning reaches the optimum only in the limit: on roughly 1 map in 1000 a detour
    // survives even 5000 episodes (an alternative route whose first steps the mostly-greedy late
    // policy rarely explores). The seed is fixed so CI checks the same 64 maps every run.
    #![proptest_config(ProptestConfig {
        cases: 64,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed),
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn improved_learner_ends_on_the_bfs_optimum((grid, start, goal, opt) in small_map(), seed in 0u64..1000) {
        let task = Task { map_name: "random".into(), grid, start, goal, optimal_len: opt };
        let (_, s) = Learner::new(&task, LearnerConfig::improved(3000, seed)).unwrap().run(|_| {});
        prop_assert_eq!(s.final_path_len, Some(opt));
    }
}

/// Says that a test skipped, and why: a copy of `qfleet_suite::skip` (`tests/support/lib.rs`
/// says why it looks so; `tests/skips.rs` keeps every copy identical).
fn skip(test: &str, reason: &str) {
    use std::io::Write;
    let line = format!("SKIPPED: {test}: {reason}\n");
    let _ = std::io::stderr().lock().write_all(line.as_bytes());
}

/// The shared MovingAI maps, when this checkout sits beside `shared/`.
fn movingai_dir(test: &str) -> Option<std::path::PathBuf> {
    let d = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/movingai");
    if d.is_dir() {
        Some(d)
    } else {
        skip(
            &format!("planner learning::{test}"),
            &format!("{} not found", d.display()),
        );
        None
    }
}

#[test]
fn learns_the_optimum_on_movingai_maps() {
    let Some(dir) = movingai_dir("learns_the_optimum_on_movingai_maps") else {
        return;
    };
    let empty = planner::map::load_map(dir.join("empty-8-8.map").to_str().unwrap()).unwrap();
    let task = resolve_task(&empty, Some(Cell::new(0, 0)), Some(Cell::new(7, 7))).unwrap();
    let (_, s) = Learner::new(&task, LearnerConfig::improved(300, 1))
        .unwrap()
        .run(|_| {});
    assert_eq!(s.final_path_len, Some(14));

    let map = planner::map::load_map(dir.join("random-32-32-10.map").to_str().unwrap()).unwrap();
    let scen = planner::map::load_scen(&dir.join("random-32-32-10-random-1.scen")).unwrap();
    // A scenario of moderate length (bucket 2): long enough to be a real search.
    let index = scen.iter().position(|s| s.bucket == 2).unwrap();
    let task = planner::task::resolve_scenario(&map, &scen, index).unwrap();
    // Q-learning converges only in the limit: a seed may keep a 2-move detour (see the
    // property test), so the promise is "most seeds", with every seed reaching the goal.
    let mut optimal = 0;
    for seed in 1..=5 {
        let (_, s) = Learner::new(&task, LearnerConfig::improved(3000, seed))
            .unwrap()
            .run(|_| {});
        let len = s
            .final_path_len
            .expect("final greedy path reaches the goal");
        assert!(
            len <= task.optimal_len + 2,
            "seed {seed}: {len} moves, optimum {}",
            task.optimal_len
        );
        optimal += (len == task.optimal_len) as u32;
    }
    assert!(
        optimal >= 3,
        "scenario {index}: only {optimal}/5 seeds optimal"
    );
}
