//! The planning learner (the default): long paths without underflow, the optimum on small
//! generated maps of every family, determinism.

use planner::suite::{Family, generate};
use planner::task::Task;
use planner::{Cell, Grid, Learner, LearnerConfig};

/// The serpentine corridor of `planner::suite`.
fn serpentine(w: usize, h: usize) -> Task {
    planner::suite::serpentine(w, h).expect("corridor")
}

#[test]
fn a_path_of_over_1000_moves_is_learned_exactly() {
    let task = serpentine(51, 41);
    assert!(task.optimal_len >= 1000, "{}", task.optimal_len);
    let mut l = Learner::new(&task, LearnerConfig::planning(100, 1)).expect("config");
    let (_, summary) = l.run(|_| {});
    assert_eq!(summary.final_path_len, Some(task.optimal_len));
    // The start's value is γ^(moves-1) of the goal reward: far from zero in f32.
    let v = l.q().max(task.grid.index(task.start));
    assert!(v.is_normal() && v > 1e-6, "Q(start) = {v}");
}

#[test]
fn the_paper_gamma_underflows_where_the_default_does_not() {
    // Why the default's γ is 0.99: with γ = 0.6 the value 1 000 moves out is below f32's range.
    let task = serpentine(51, 41);
    let cfg = LearnerConfig {
        gamma: 0.6,
        ..LearnerConfig::planning(100, 1)
    };
    let mut l = Learner::new(&task, cfg).expect("config");
    let (_, summary) = l.run(|_| {});
    assert_ne!(summary.final_path_len, Some(task.optimal_len));
}

#[test]
fn default_learner_ends_optimal_on_small_generated_maps() {
    let (mut runs, mut optimal) = (0, 0);
    let mut misses = Vec::new();
    for size in [10, 20] {
        for family in Family::GENERATED {
            for i in 0..5 {
                let t = generate(family, size, i, 11).expect("map");
                for seed in 0..2 {
                    let mut l =
                        Learner::new(&t.task, LearnerConfig::planning(300, seed)).expect("config");
                    let (_, s) = l.run(|_| {});
                    runs += 1;
                    if s.final_path_len == Some(t.task.optimal_len) {
                        optimal += 1;
                    } else {
                        misses.push((t.id.clone(), seed, s.final_path_len, t.task.optimal_len));
                    }
                }
            }
        }
    }
    assert!(
        optimal * 100 >= runs * 95,
        "{optimal}/{runs} optimal; misses {misses:?}"
    );
}

#[test]
fn same_seed_same_episodes() {
    let t = generate(Family::Rooms, 20, 0, 3).expect("map");
    let run = |seed| {
        let mut l = Learner::new(&t.task, LearnerConfig::planning(50, seed)).expect("config");
        l.run(|_| {}).0
    };
    assert_eq!(run(4), run(4));
    assert_ne!(run(4), run(5));
}

#[test]
fn values_kept_falling_change_nothing_alone_and_keep_a_bound_set_from_outside() {
    // alone, from the optimistic start, no update raises a value: the option is a no-op
    for family in Family::GENERATED {
        let t = generate(family, 20, 1, 7).expect("map");
        let mut plain = Learner::new(&t.task, LearnerConfig::planning(100, 3)).expect("config");
        let mut falling = plain.clone();
        falling.keep_values_falling();
        assert_eq!(plain.run(|_| {}).0, falling.run(|_| {}).0, "{}", t.id);
        assert_eq!(plain.q().rows(), falling.q().rows(), "{}", t.id);
    }
    // a tighter bound set from outside (a fleet's merged hint) survives the next episode's
    // replay and sweeps only with the option; without it, backups from this learner's own
    // looser neighbours raise it again
    let t = serpentine(8, 5);
    let bound_after = |falling: bool| {
        let mut l = Learner::new(&t, LearnerConfig::planning(3, 1)).expect("config");
        if falling {
            l.keep_values_falling();
        }
        l.run_episode();
        // (0,0) moving right, the way to the goal: hint a value far below what it holds
        let before = l.q().row(0)[1];
        l.q_mut().set_checked(0, 1, 1e-6);
        l.table_changed();
        l.run_episode();
        (before, l.q().row(0)[1])
    };
    let (before, kept) = bound_after(true);
    assert!(before > 1e-6 && kept <= 1e-6, "{before} -> {kept}");
    let (_, raised) = bound_after(false);
    assert!(raised > 1e-6, "{raised}");
}

#[test]
fn a_move_made_known_from_outside_is_backed_up_by_the_sweeps() {
    // 3x3: column x = 1 is wall, so column x = 2 is free but out of the learner's reach; start
    // (0,0), goal (0,2). Only a move made known from outside can be backed up there.
    let free = vec![true, false, true, true, false, true, true, false, true];
    let task = Task {
        map_name: "split".into(),
        grid: Grid::new(3, 3, free).expect("grid"),
        start: Cell::new(0, 0),
        goal: Cell::new(0, 2),
        optimal_len: 2,
    };
    let run = |known: bool| {
        let mut l = Learner::new(&task, LearnerConfig::planning(2, 1)).expect("config");
        l.keep_values_falling();
        if known {
            // cell 2 = (2,0), action 1 = right: into the border
            assert!(l.add_known_move(2, 1));
            assert!(!l.add_known_move(2, 1), "already known");
            assert_eq!(l.tried_pairs(), &[2 * 4 + 1]);
        }
        l.run_episode();
        l.q().row(2)[1]
    };
    assert_eq!(run(false), 1.0, "untouched: still optimistic");
    let v = run(true);
    assert!(
        (v - (-1.0 + 0.99)).abs() < 1e-6,
        "backed up as a collision: {v}"
    );
    let mut l = Learner::new(&task, LearnerConfig::planning(2, 1)).expect("config");
    assert!(!l.add_known_move(99, 0), "outside the grid");
    assert!(!l.add_known_move(2, 4), "no such action");
    assert!(!l.add_known_move(1, 0), "a wall is no cell to move from");
    // a learner without a model (the paper's) has nothing to add to
    let mut t = Learner::new(&task, LearnerConfig::traditional(2, 1)).expect("config");
    assert!(!t.add_known_move(2, 1));
}

#[test]
fn sweeps_within_episodes_find_the_optimum_in_fewer_steps_and_stop_once_the_model_is_whole() {
    // env steps until the greedy path is first optimal, and the steps of the last episode
    let run = |t: &Task, sweep_every: u32, seed: u64| {
        let mut cfg = LearnerConfig::planning(200, seed);
        cfg.extras.sweep_every = sweep_every;
        let mut l = Learner::new(t, cfg).expect("config");
        let (mut steps, mut first) = (0u64, None);
        let (records, s) = l.run(|r| {
            steps += u64::from(r.steps);
            if first.is_none() && r.greedy_path_len == Some(t.optimal_len) {
                first = Some(steps);
            }
        });
        assert_eq!(
            s.final_path_len,
            Some(t.optimal_len),
            "sweep_every {sweep_every}"
        );
        (first.expect("optimal at some episode"), records.len())
    };
    for (family, i) in [(Family::Rooms, 1), (Family::Maze, 0)] {
        let t = generate(family, 64, i, 1).expect("map");
        for seed in [1, 2] {
            let (within, n) = run(&t.task, 1024, seed);
            let (after, _) = run(&t.task, 0, seed);
            assert!(
                within < after,
                "{}: {within} steps with sweeps within episodes, {after} without",
                t.id
            );
            assert_eq!(n, 200);
        }
    }
    // a learner whose model no longer changes does not sweep inside its episodes
    let t = generate(Family::Rooms, 20, 0, 3).expect("map");
    let mut cfg = LearnerConfig::planning(100, 1);
    cfg.extras.sweep_every = 1;
    let mut l = Learner::new(&t.task, cfg).expect("config");
    l.run(|_| {});
    let _ = l.take_swept_within();
    let tried = l.tried_pairs().len();
    l.begin_episode();
    while !l.step().done {}
    assert_eq!(
        l.tried_pairs().len(),
        tried,
        "this episode found no new move"
    );
    assert!(!l.take_swept_within(), "so it swept nothing");
}

#[test]
fn values_set_from_outside_after_the_last_episode_are_settled_before_a_path_is_read() {
    // a fleet robot: two episodes of its own, then half of another robot's tighter bounds (the
    // min rule's merged hints) arrive after its last episode, their moves joining its model
    let task = serpentine(21, 15);
    let mut own = Learner::new(&task, LearnerConfig::planning(2, 0)).expect("config");
    own.keep_values_falling();
    own.run(|_| {});
    let mut other = Learner::new(&task, LearnerConfig::planning(200, 7)).expect("config");
    let (_, s) = other.run(|_| {});
    assert_eq!(s.final_path_len, Some(task.optimal_len));
    for &sa in other.tried_pairs().iter().step_by(2) {
        let (cell, a) = ((sa >> 2) as usize, (sa & 3) as usize);
        let v = other.q().row(cell)[a];
        let row = own.q_mut().row_mut(cell);
        row[a] = row[a].min(v);
        own.add_known_move(cell as u32, a);
    }
    own.table_changed();
    // read before the values reached their neighbours, the greedy path loops
    assert_eq!(own.clone().greedy_path_len(), None);
    assert!(own.settle());
    assert_eq!(own.greedy_path_len(), Some(task.optimal_len));
    // settled: a second call changes nothing
    assert!(!own.settle());
}

#[test]
fn a_move_of_another_robot_reveals_both_cells_it_touched() {
    // 3x3, (1,0) a wall; cell index = y·3 + x; actions 0 up, 1 right, 2 down, 3 left
    //   0 # 2
    //   3 4 5
    //   6 7 8
    let free = vec![true, false, true, true, true, true, true, true, true];
    let task = Task {
        map_name: "wall".into(),
        grid: Grid::new(3, 3, free).expect("grid"),
        start: Cell::new(0, 2),
        goal: Cell::new(2, 2),
        optimal_len: 2,
    };
    let sorted = |l: &Learner| {
        let mut v = l.tried_pairs().to_vec();
        v.sort_unstable();
        v
    };
    let pair = |cell: u32, a: u32| cell * 4 + a;
    let mut l = Learner::new(&task, LearnerConfig::planning(2, 1)).expect("config");
    assert!(!l.settle_grid_moves(), "nothing joined yet");
    // 4 -> 3 (left): cell 4 is free (the robot stood there), so is cell 3; every move into
    // either is known, the move itself and its way back (3 -> 4, right) among them
    assert_eq!(l.add_grid_move(4, 3), 6);
    let mut want = vec![
        pair(4, 3), // the move
        pair(5, 3), // into 4 from the right
        pair(7, 0), // into 4 from below
        pair(3, 1), // into 4 from the left: the way back
        pair(0, 2), // into 3 from above
        pair(6, 0), // into 3 from below
    ];
    want.sort_unstable();
    assert_eq!(sorted(&l), want);
    assert_eq!(l.add_grid_move(4, 3), 0, "nothing new the second time");
    // 4 -> up collides: cell 1 is a wall, and every move into it a collision
    assert_eq!(l.add_grid_move(4, 0), 3);
    for sa in [pair(4, 0), pair(0, 1), pair(2, 3)] {
        assert!(l.tried_pairs().contains(&sa), "{sa}");
    }
    // off the grid: the move and the cell it left, no second cell
    assert_eq!(l.add_grid_move(0, 0), 2, "0 -> up, and 3 -> up into 0");
    assert!(l.tried_pairs().contains(&pair(3, 0)));
    // bad input adds nothing and never panics
    assert_eq!(l.add_grid_move(99, 0), 0, "outside the grid");
    assert_eq!(l.add_grid_move(u32::MAX, 0), 0, "far outside the grid");
    assert_eq!(l.add_grid_move(2, 4), 0, "no such action");
    assert_eq!(l.add_grid_move(1, 2), 0, "nobody stands on a wall");
    let mut t = Learner::new(&task, LearnerConfig::traditional(2, 1)).expect("config");
    assert_eq!(t.add_grid_move(4, 3), 0, "the paper's learner has no model");
    assert!(!t.settle_grid_moves());
    // what joined is planned with once: the collision's value is backed up, then nothing is due
    assert!(l.settle_grid_moves());
    assert!((l.q().row(4)[0] - (-1.0 + 0.99 * l.q().max(4))).abs() < 1e-6);
    assert!(!l.settle_grid_moves());
}

#[test]
fn a_learner_handed_the_grid_by_another_goals_robot_plans_its_optimal_path_before_moving() {
    // another robot learns the way back (its start is our goal and the other way round), then
    // its moves reach us as a fleet's merged hints would; we have not taken a step
    for (family, i) in [(Family::Rooms, 0), (Family::Maze, 1)] {
        let ours = generate(family, 20, i, 3).expect("map").task;
        let theirs = Task {
            start: ours.goal,
            goal: ours.start,
            ..ours.clone()
        };
        let mut other = Learner::new(&theirs, LearnerConfig::planning(100, 5)).expect("config");
        other.run(|_| {});
        let mut l = Learner::new(&ours, LearnerConfig::planning(100, 1)).expect("config");
        l.keep_values_falling();
        let mut joined = 0;
        for &sa in other.tried_pairs() {
            joined += l.add_grid_move(sa >> 2, (sa & 3) as usize);
        }
        assert_eq!(joined as usize, l.tried_pairs().len());
        assert!(l.tried_pairs().len() >= other.tried_pairs().len());
        assert!(l.settle_grid_moves(), "{family:?}");
        assert_eq!(
            l.greedy_path_len(),
            Some(ours.optimal_len),
            "{family:?}: optimal with no step of its own"
        );
        // and its first episode walks it (ε = 0.05 may add a detour, never a search)
        let r = l.run_episode();
        assert!(
            r.steps < 4 * ours.optimal_len + 20,
            "{family:?}: {} steps",
            r.steps
        );
    }
}

/// Runs `l` until it hands out discoveries (or its episodes run out); returns them.
fn first_discoveries(l: &mut Learner) -> Vec<(u32, f32)> {
    while !l.finished() {
        l.run_episode();
        let found = l.take_new_pseudo_targets();
        if !found.is_empty() {
            return found;
        }
    }
    Vec::new()
}

#[test]
fn a_planning_learner_publishes_cells_of_its_goal_path_with_returns_no_robot_can_beat() {
    for family in Family::GENERATED {
        let t = generate(family, 20, 2, 5).expect("map");
        let task = &t.task;
        let mut l = Learner::new(task, LearnerConfig::planning(300, 2)).expect("config");
        let found = first_discoveries(&mut l);
        assert!(!found.is_empty(), "{}: a path was found", t.id);
        assert!(found.len() <= planner::known::PathPublisher::PER_PATH);
        let dist = planner::path::bfs_distances(&task.grid, task.goal);
        let goal = task.grid.index(task.goal) as u32;
        for &(c, v) in &found {
            assert_ne!(c, goal, "{}: never the goal itself", t.id);
            // the return of a real path from c: at most that of the shortest one, γ^(d−1)
            let best = 0.99f32.powi(dist[c as usize] as i32 - 1);
            assert!(
                v > 0.0 && v <= best * (1.0 + 1e-6),
                "{}: {v} > {best}",
                t.id
            );
        }
        // the start is the first cell of the path, published with the path's whole return
        let start = task.grid.index(task.start) as u32;
        assert_eq!(found[0].0, start, "{}", t.id);
        // later (shorter) paths publish cells not published before, within the cap
        let mut all = found.clone();
        while !l.finished() {
            l.run_episode();
            all.extend(l.take_new_pseudo_targets());
        }
        let mut cells: Vec<u32> = all.iter().map(|x| x.0).collect();
        cells.sort_unstable();
        cells.dedup();
        assert_eq!(cells.len(), all.len(), "{}: a cell published twice", t.id);
        assert!(all.len() <= planner::known::PathPublisher::CAP as usize);
        for &(c, v) in &all {
            let best = 0.99f32.powi(dist[c as usize] as i32 - 1);
            assert!(
                v > 0.0 && v <= best * (1.0 + 1e-5),
                "{}: {v} > {best}",
                t.id
            );
        }
        // the paper's learners publish no goal path
        let mut trad = Learner::new(task, LearnerConfig::traditional(50, 2)).expect("config");
        trad.run(|_| {});
        assert!(trad.take_new_pseudo_targets().is_empty());
    }
}

#[test]
fn a_converged_learner_holds_exactly_the_returns_it_published() {
    // what makes a discovery usable by another robot: once a learner's values along a path are
    // exact they equal the published returns to the last bit (the same backups)
    let t = generate(Family::Rooms, 20, 3, 5).expect("map");
    let mut l = Learner::new(&t.task, LearnerConfig::planning(300, 1)).expect("config");
    let mut published = Vec::new();
    while !l.finished() {
        l.run_episode();
        published.extend(l.take_new_pseudo_targets());
    }
    assert_eq!(l.greedy_path_len(), Some(t.task.optimal_len));
    // the last path published is the optimal one: its cells' values are the returns
    let start = t.task.grid.index(t.task.start) as u32;
    let last = published.iter().rposition(|x| x.0 == start);
    let exact = |(c, v): (u32, f32)| l.q().max(c as usize) == v;
    match last {
        Some(i) => assert!(exact(published[i]), "{:?}", published[i]),
        None => panic!("the start is published with every first path"),
    }
    assert!(
        published.iter().copied().filter(|&x| exact(x)).count() >= 4,
        "{published:?}"
    );
}

#[test]
fn a_known_return_ends_an_episode_only_where_the_value_has_come_down_to_it() {
    // S . . G: the only way is right; no random moves
    let task = Task {
        map_name: "corridor".into(),
        grid: Grid::new(4, 1, vec![true; 4]).expect("grid"),
        start: Cell::new(0, 0),
        goal: Cell::new(3, 0),
        optimal_len: 3,
    };
    let cfg = LearnerConfig {
        policy: planner::PolicyConfig::EpsilonGreedy {
            epsilon: 0.0,
            reading: planner::EpsilonReading::Random,
        },
        ..LearnerConfig::planning(10, 1)
    };
    let episode = |cell1: Option<[f32; 4]>, known: bool| {
        let mut l = Learner::new(&task, cfg).expect("config");
        // the way on from (1,0) is known: right, right
        l.add_known_move(1, 1);
        l.add_known_move(2, 1);
        // right is the best move of the start and of (2,0)
        *l.q_mut().row_mut(0) = [-1.0, 1.0, -1.0, -1.0];
        *l.q_mut().row_mut(2) = [-1.0, 1.0, -1.0, -1.0];
        if let Some(row) = cell1 {
            *l.q_mut().row_mut(1) = row;
        }
        if known {
            // from (1,0) two moves to the goal: 0 + γ·1
            assert!(l.add_discovery(1, 0.99));
            assert!(!l.add_discovery(1, 0.5), "a lower return adds nothing");
        }
        l.run_episode()
    };
    let exact = [-1.0, 0.99, -1.0, -1.0];
    let r = episode(Some(exact), true);
    assert_eq!((r.outcome, r.steps), (planner::Outcome::Pseudo, 1));
    // untried (optimistic) there: the walk on may find something, it goes on
    let r = episode(None, true);
    assert_eq!(r.outcome, planner::Outcome::Goal);
    // nothing known: as before
    let r = episode(Some(exact), false);
    assert_eq!((r.outcome, r.steps), (planner::Outcome::Goal, 3));
    // exact there, but the way on is not known (a tie with an untried action looks the same)
    let mut l = Learner::new(&task, cfg).expect("config");
    *l.q_mut().row_mut(0) = [-1.0, 1.0, -1.0, -1.0];
    *l.q_mut().row_mut(1) = exact;
    *l.q_mut().row_mut(2) = [-1.0, 1.0, -1.0, -1.0];
    l.add_discovery(1, 0.99);
    assert_eq!(l.run_episode().outcome, planner::Outcome::Goal);
    // a cut is no terminal: the move into the cell is backed up from its value, not set
    let mut l = Learner::new(&task, cfg).expect("config");
    l.add_known_move(1, 1);
    l.add_known_move(2, 1);
    *l.q_mut().row_mut(2) = [-1.0, 1.0, -1.0, -1.0];
    *l.q_mut().row_mut(0) = [-1.0, 1.0, -1.0, -1.0];
    *l.q_mut().row_mut(1) = exact;
    l.add_discovery(1, 0.99);
    l.run_episode();
    assert_eq!(l.q().row(0)[1], 0.99 * 0.99);
    // what a discovery cannot name: the goal, a wall, a cell off the grid, no number
    assert!(!l.add_discovery(3, 0.5));
    assert!(!l.add_discovery(4, 0.5));
    assert!(!l.add_discovery(2, f32::NAN));
    assert!(!l.add_discovery(2, 2.0), "above the goal reward");
}

#[test]
fn another_robots_discoveries_save_a_robot_that_shares_its_values_env_steps_to_the_optimum() {
    // robot A learns alone for a few episodes; robot B starts from A's values and moves (what
    // merged hints carry) and, with A's discoveries, skips the walks along A's path that tell
    // it nothing. Summed over maps and seeds: single runs differ by their random moves.
    let (mut with_total, mut without_total) = (0u64, 0u64);
    for family in Family::GENERATED {
        for i in 0..3 {
            let t = generate(family, 32, i, 5).expect("map");
            let task = &t.task;
            for seed in 0..4u64 {
                let mut a =
                    Learner::new(task, LearnerConfig::planning(300, 100 + seed)).expect("config");
                let mut found = Vec::new();
                for _ in 0..2 {
                    a.run_episode();
                    found.extend(a.take_new_pseudo_targets());
                }
                let steps_to_optimum = |with: bool| {
                    let mut b =
                        Learner::new(task, LearnerConfig::planning(1000, seed)).expect("config");
                    b.keep_values_falling();
                    for (row, from_a) in b.q_mut().rows_mut().iter_mut().zip(a.q().rows()) {
                        for (q, h) in row.iter_mut().zip(from_a) {
                            *q = q.min(*h);
                        }
                    }
                    for &sa in a.tried_pairs() {
                        b.add_known_move(sa >> 2, (sa & 3) as usize);
                    }
                    b.table_changed();
                    if with {
                        for &(c, v) in &found {
                            b.add_discovery(c, v);
                        }
                    }
                    let mut steps = 0u64;
                    while !b.finished() {
                        steps += u64::from(b.run_episode().steps);
                        if b.greedy_path_len() == Some(task.optimal_len) {
                            return steps;
                        }
                    }
                    panic!("{}: B never optimal (with discoveries: {with})", t.id);
                };
                let (w, wo) = (steps_to_optimum(true), steps_to_optimum(false));
                with_total += w;
                without_total += wo;
            }
        }
    }
    eprintln!("total with {with_total} without {without_total}");
    assert!(
        with_total < without_total,
        "{with_total} >= {without_total}"
    );
}
