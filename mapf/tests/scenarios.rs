//! Small hand-made situations, each a specification of the resolver's behaviour.

mod common;

use common::{checked, greedy, run};
use mapf::{Instance, Intent, Move, Status, World, WorldConfig, WorldError, check};
use planner::Cell;
use planner::map::parse_ascii;

fn c(x: u16, y: u16) -> Cell {
    Cell::new(x, y)
}

fn inst(map: &str, starts: &[Cell], goals: &[Cell]) -> Instance {
    let grid = parse_ascii("t", map.as_bytes()).unwrap().grid;
    Instance::new(grid, starts.to_vec(), goals.to_vec()).unwrap()
}

/// Small stall window so the fallback comes quickly on tiny maps.
fn quick() -> WorldConfig {
    WorldConfig {
        stall_ticks: 6,
        ..WorldConfig::default()
    }
}

#[test]
fn two_robots_pass_in_a_corridor_with_one_side_pocket() {
    let map = "###.###\n.......\n";
    let i = inst(map, &[c(0, 1), c(6, 1)], &[c(6, 1), c(0, 1)]);
    for config in [
        quick(),
        WorldConfig {
            plan_ahead: false,
            ..quick()
        },
    ] {
        let r = run(&i, config, 200);
        assert!(
            r.world.all_arrived(),
            "{:?} after {} ticks",
            r.last,
            r.ticks
        );
        assert_eq!(r.last, Status::Arrived);
        let costs = checked(&i, &r.world);
        assert!(costs.makespan <= 12, "{costs:?}");
    }
}

#[test]
fn a_robot_parked_on_anothers_only_path_steps_aside_and_comes_back() {
    // agent 0's goal (2,1) is on agent 1's only way; the pocket (2,0) lets it step aside
    let map = "##.###\n......\n";
    let i = inst(map, &[c(3, 1), c(0, 1)], &[c(2, 1), c(5, 1)]);
    for plan_ahead in [true, false] {
        let r = run(
            &i,
            WorldConfig {
                plan_ahead,
                ..quick()
            },
            200,
        );
        assert!(
            r.world.all_arrived(),
            "plan_ahead {plan_ahead}: {:?}",
            r.last
        );
        let costs = checked(&i, &r.world);
        let p0 = &r.world.paths()[0];
        assert!(p0.contains(&c(2, 0)), "agent 0 used the pocket: {p0:?}");
        assert!(
            costs.per_agent[0] > 1,
            "agent 0 left its goal and came back"
        );
    }
}

#[test]
fn a_corridor_without_pocket_is_unsolvable_quickly() {
    let i = inst(".....\n", &[c(0, 0), c(4, 0)], &[c(4, 0), c(0, 0)]);
    let r = run(&i, quick(), 500);
    assert_eq!(r.last, Status::Unsolvable, "after {} ticks", r.ticks);
    assert!(r.ticks < 50, "{} ticks", r.ticks);
    assert_eq!(r.world.searches(), 1);
    // still no conflict on the way
    let paths = r.world.paths();
    let v = check(i.grid(), i.starts(), i.goals(), &paths).unwrap_err();
    assert_eq!(mapf::check::conflicts(&v), 0, "{v:?}");
}

#[test]
fn a_removed_robot_frees_its_cell_for_the_others() {
    // agent 1 sits on its goal in a pocketless corridor: agent 0 cannot pass until it is gone
    let i = inst("......\n", &[c(0, 0), c(3, 0)], &[c(5, 0), c(3, 0)]);
    let mut w = World::new(&i, quick());
    let mut intents = vec![None; 2];
    let mut last = Status::Running;
    while w.tick() < 100 && last != Status::Unsolvable {
        greedy(&i, w.positions(), &mut intents);
        last = w.step(&intents).unwrap().status;
    }
    assert_eq!(last, Status::Unsolvable);
    let old = w.positions()[1].unwrap();
    assert!(w.remove(1));
    assert!(!w.remove(1), "removing twice is a no-op");
    assert!(!w.remove(7), "an unknown agent is a no-op");
    assert_eq!(w.positions()[1], None);
    let mut through = false;
    while w.tick() < 200 && !w.all_arrived() {
        greedy(&i, w.positions(), &mut intents);
        assert_eq!(intents[1], None);
        let t = w.step(&intents).unwrap();
        through |= w.positions()[0] == Some(old);
        assert_ne!(t.status, Status::Unsolvable);
    }
    assert!(w.all_arrived());
    assert!(through, "agent 0 passed the removed robot's cell");
    assert_eq!(w.positions()[0], Some(c(5, 0)));
}

#[test]
fn a_hung_robot_is_an_obstacle_nobody_pushes() {
    // agent 1 hangs on (1,1), the middle of agent 0's straight way; agent 2 wants its cell
    let map = "...\n...\n...\n";
    let i = inst(
        map,
        &[c(1, 0), c(1, 1), c(0, 1)],
        &[c(1, 2), c(0, 0), c(2, 1)],
    );
    let mut w = World::new(&i, quick());
    let mut intents = vec![None; 3];
    for _ in 0..40 {
        greedy(&i, w.positions(), &mut intents);
        intents[1] = None;
        w.step(&intents).unwrap();
        assert_eq!(
            w.positions()[1],
            Some(c(1, 1)),
            "the hung robot never moves"
        );
    }
    assert_eq!(w.positions()[0], Some(c(1, 2)));
    assert_eq!(w.positions()[2], Some(c(2, 1)));
    assert!(!w.all_arrived(), "the hung robot is not on its goal");
    let paths = w.paths();
    for (a, p) in paths.iter().enumerate().filter(|(a, _)| *a != 1) {
        assert!(
            !p.contains(&c(1, 1)),
            "agent {a} entered the hung robot's cell"
        );
    }
    assert!(w.stats()[1].waits >= 40);
}

#[test]
fn a_hung_robot_on_anothers_goal_makes_it_unsolvable_until_it_wakes() {
    let i = inst("...\n...\n", &[c(0, 0), c(2, 0)], &[c(2, 1), c(0, 0)]);
    let mut w = World::new(&i, quick());
    let mut intents = vec![None; 2];
    let mut last = Status::Running;
    // agent 0 hangs at once on its start (0,0), which is agent 1's goal
    while w.tick() < 60 && last != Status::Unsolvable {
        greedy(&i, w.positions(), &mut intents);
        intents[0] = None;
        last = w.step(&intents).unwrap().status;
    }
    assert_eq!(last, Status::Unsolvable, "agent 0 sits on agent 1's goal");
    assert_eq!(
        w.searches(),
        0,
        "seen without a search: the goal is walled off"
    );
    // it wakes up: the verdict is dropped and everyone arrives
    let mut t = last;
    while w.tick() < 200 && !w.all_arrived() {
        greedy(&i, w.positions(), &mut intents);
        t = w.step(&intents).unwrap().status;
    }
    assert_eq!(t, Status::Arrived);
}

#[test]
fn the_robots_first_choice_is_granted_when_free_and_counters_add_up() {
    let i = inst("....\n....\n", &[c(0, 0), c(3, 1)], &[c(3, 0), c(0, 1)]);
    let mut w = World::new(&i, WorldConfig::default());
    // agent 0 asks for Down first (a detour): free, so it is granted as asked
    let down = Intent::new(&[Move::Down, Move::Right, Move::Wait]).unwrap();
    let wall = Intent::new(&[Move::Down, Move::Left]).unwrap(); // agent 1 at the bottom row
    let t = w.step(&[Some(down), Some(wall)]).unwrap();
    assert_eq!(w.positions()[0], Some(c(0, 1)));
    assert_eq!(w.positions()[1], Some(c(2, 1)));
    assert_eq!(t.tick, 1);
    assert_eq!(t.moved, 2);
    assert_eq!(t.denied, 1, "a first move into the wall is never granted");
    assert_eq!(w.stats()[1].denied, 1);
    assert_eq!(w.stats()[0].denied, 0);
    assert_eq!(
        w.step(&[None]),
        Err(WorldError::IntentCount { got: 1, agents: 2 })
    );
}

#[test]
fn a_swap_is_never_granted_even_when_both_ask_for_it() {
    let i = inst("..\n", &[c(0, 0), c(1, 0)], &[c(1, 0), c(0, 0)]);
    let mut w = World::new(&i, WorldConfig::default());
    let r = Intent::new(&[Move::Right]).unwrap();
    let l = Intent::new(&[Move::Left]).unwrap();
    for _ in 0..5 {
        w.step(&[Some(r), Some(l)]).unwrap();
        let p = w.positions();
        assert_ne!(p[0], p[1]);
        assert_eq!(p, &[Some(c(0, 0)), Some(c(1, 0))]);
    }
}

#[test]
fn a_rotation_of_four_is_granted() {
    let i = inst(
        "..\n..\n",
        &[c(0, 0), c(1, 0), c(1, 1), c(0, 1)],
        &[c(1, 0), c(1, 1), c(0, 1), c(0, 0)],
    );
    let r = run(&i, WorldConfig::default(), 50);
    assert!(r.world.all_arrived());
    let costs = checked(&i, &r.world);
    assert_eq!(costs.soc, 4, "one tick each: {costs:?}");
}

#[test]
fn every_tick_of_a_dense_run_is_collision_free() {
    // 6 agents on a 4x3 room with one wall: crowded, solved, checked
    let map = "....\n.#..\n....\n";
    let starts = [c(0, 0), c(1, 0), c(2, 0), c(3, 0), c(0, 2), c(3, 2)];
    let goals = [c(3, 2), c(0, 2), c(3, 0), c(2, 2), c(0, 0), c(1, 0)];
    let i = inst(map, &starts, &goals);
    let r = run(&i, quick(), 500);
    assert!(r.world.all_arrived(), "{:?} after {}", r.last, r.ticks);
    checked(&i, &r.world);
}

#[test]
fn a_search_out_of_budget_reports_stalled_and_backs_off() {
    let i = inst(".....\n", &[c(0, 0), c(4, 0)], &[c(4, 0), c(0, 0)]);
    let config = WorldConfig {
        stall_ticks: 4,
        fallback_nodes: 1,
        ..WorldConfig::default()
    };
    let mut w = World::new(&i, config);
    let mut intents = vec![None; 2];
    let mut stalled = 0;
    for _ in 0..200 {
        greedy(&i, w.positions(), &mut intents);
        let s = w.step(&intents).unwrap().status;
        assert_ne!(
            s,
            Status::Unsolvable,
            "a search out of budget proves nothing"
        );
        stalled += usize::from(s == Status::Stalled);
    }
    assert!(stalled > 0);
    // windows of 4, 8, 16, 32, 64, 128 ticks: at most 6 searches in 200 ticks
    assert!((2..=6).contains(&w.searches()), "{} searches", w.searches());
}

/// A world whose first plan was made ahead ([`World::prepare`], what the coordinator does while
/// the robots learn) without the extra refinement moves exactly as one that makes it at its
/// first step, and does not plan again at that step.
#[test]
fn a_plan_made_ahead_is_the_one_the_first_step_would_make() {
    let map = ".....\n.#.#.\n.....\n.#.#.\n.....\n";
    let (s, g) = (
        [c(0, 0), c(4, 0), c(0, 4), c(4, 4), c(2, 2)],
        [c(4, 4), c(0, 4), c(4, 0), c(0, 0), c(2, 0)],
    );
    let i = inst(map, &s, &g);
    let config = WorldConfig {
        prepare_refine: 0,
        ..WorldConfig::default()
    };
    let lazy = run(&i, config, 100);
    let mut w = World::new(&i, config);
    w.prepare();
    assert_eq!(w.replans(), 1);
    w.prepare();
    assert_eq!(w.replans(), 1, "a valid plan is not made again");
    let mut intents = vec![None; i.agents()];
    greedy(&i, w.positions(), &mut intents);
    w.step(&intents).unwrap();
    assert_eq!(w.replans(), 1, "the first step follows the plan made ahead");
    while w.tick() < 100 && !w.all_arrived() {
        greedy(&i, w.positions(), &mut intents);
        w.step(&intents).unwrap();
    }
    assert!(w.all_arrived());
    assert_eq!(w.paths(), lazy.world.paths());
    checked(&i, &w);
}

/// A 12x12 room with a wall across the middle (two doors) and 20 agents crossing it.
fn two_doors() -> Instance {
    let mut map = String::new();
    for y in 0..12 {
        for x in 0..12 {
            map.push(if y == 6 && x != 3 && x != 8 { '#' } else { '.' });
        }
        map.push('\n');
    }
    let starts: Vec<Cell> = (0..20).map(|k| c(k % 12, k / 12)).collect();
    let goals: Vec<Cell> = (0..20).map(|k| c(11 - k % 12, 11 - k / 12)).collect();
    inst(&map, &starts, &goals)
}

/// The refinement a plan made ahead gets ([`WorldConfig::prepare_refine`]) never makes it
/// costlier, is deterministic (expansions, not a clock), and the fleet follows it to the goals.
#[test]
fn a_plan_made_ahead_is_refined_deterministically_and_never_costlier() {
    let i = two_doors();
    let made = |prepare_refine| {
        let mut w = World::new(
            &i,
            WorldConfig {
                prepare_refine,
                ..WorldConfig::default()
            },
        );
        w.prepare();
        w
    };
    let (plain, refined) = (made(0), made(200_000));
    let (p, r) = (
        plain.planned_cost().unwrap(),
        refined.planned_cost().unwrap(),
    );
    assert_eq!((p.1, r.1), (0, 0), "every agent routed");
    assert!(r.0 <= p.0, "refined {r:?} > {p:?}");
    assert!(r.0 >= i.lower_bound());
    let again = made(200_000);
    assert_eq!(again.planned_cost(), refined.planned_cost());
    let runs: Vec<_> = [refined, again]
        .into_iter()
        .map(|w| common::run_world(&i, w, 300))
        .collect();
    assert!(runs[0].world.all_arrived());
    assert_eq!(runs[0].world.paths(), runs[1].world.paths());
    let costs = checked(&i, &runs[0].world);
    assert!(
        costs.soc <= r.0,
        "the run costs {} > the plan's {}",
        costs.soc,
        r.0
    );
}

/// The plan made ahead keeps refining in rounds only while a round lowers its cost: a fleet
/// already planned at the lower bound stops after the first round; a crowded one never spends
/// more than [`WorldConfig::prepare_refine_max`], ends no costlier than after one round, and
/// spends the same on every run (expansions, not a clock).
#[test]
fn a_plan_made_ahead_refines_in_rounds_while_it_gains_and_within_its_cap() {
    // two agents that never meet: planned at the lower bound at once
    let open = ".....\n.....\n.....\n";
    let easy = inst(open, &[c(0, 0), c(0, 2)], &[c(4, 0), c(4, 2)]);
    let round = 10_000;
    let config = WorldConfig {
        prepare_refine: round,
        prepare_refine_max: 100 * round,
        ..WorldConfig::default()
    };
    let mut w = World::new(&easy, config);
    let spent = w.prepare();
    assert!(
        spent <= round + 64,
        "an instance at its bound spent {spent}"
    );
    assert_eq!(w.planned_cost(), Some((easy.lower_bound(), 0)));

    let crowded = two_doors();
    let capped = |max| {
        let mut w = World::new(
            &crowded,
            WorldConfig {
                prepare_refine: round,
                prepare_refine_max: max,
                ..WorldConfig::default()
            },
        );
        let spent = w.prepare();
        (spent, w.planned_cost().unwrap())
    };
    let (one, one_cost) = capped(round);
    let (many, many_cost) = capped(100 * round);
    // a round may overshoot its budget by the one search it ends in
    let slack = u64::from(WorldConfig::default().prepare_nodes) + 64;
    assert!(one <= round + slack, "a cap of one round spent {one}");
    assert!(many <= 100 * round + slack, "spent {many} over its cap");
    assert!(many_cost.0 <= one_cost.0, "{many_cost:?} > {one_cost:?}");
    assert!(many_cost.0 >= crowded.lower_bound());
    assert_eq!(capped(100 * round), (many, many_cost), "deterministic");
}
