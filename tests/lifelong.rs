//! End-to-end: a lifelong shared grid (`qfleet run --world shared --lorr PROBLEM.json`). Real
//! robot processes stand on one grid while the coordinator deals each robot its next goal the
//! tick it reaches one, for exactly `--ticks` ticks. Every run is checked by
//! `qfleet_suite::mapf_check`, which reads the League of Robot Runners files itself and shares
//! no code with the project: starts, legal moves, no vertex or swap conflict, and the goals the
//! paths reach by the round-robin rule equal the result's, robot by robot, and PlanViz's output.

use std::path::{Path, PathBuf};
use std::process::Command;

use qfleet_suite::mapf_check::validate_lifelong;
use qfleet_suite::{bin, describe, leftovers, pid_with_arg, run_bounded, run_id, scratch};
use serde_json::Value;

/// The tour's problem: 12 robots in the example warehouse, 60 tasks beside its shelves.
fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/lifelong/warehouse.json")
}

/// `qfleet run --json --world shared --lorr problem --ticks ticks --out out` as run `id`.
fn lifelong_run(id: &str, problem: &Path, ticks: u32, out: &Path) -> std::process::Output {
    run_bounded(
        Command::new(bin("qfleet"))
            .args([
                "run", "--json", "--run-id", id, "--world", "shared", "--lorr",
            ])
            .arg(problem)
            .args(["--ticks", &ticks.to_string(), "--out"])
            .arg(out),
    )
}

#[test]
fn a_lifelong_run_keeps_dealing_goals_until_its_last_tick_and_its_paths_check_out() {
    let dir = scratch("lifelong-run");
    let out = dir.join("out");
    let id = run_id("lifelong-run");
    let problem = example();
    let o = lifelong_run(&id, &problem, 300, &out);
    assert!(o.status.success(), "{}", describe(&o));
    let r: Value = serde_json::from_slice(&o.stdout).unwrap();
    let l = &r["lifelong"];
    assert_eq!(l["ended"], "ticks", "{l}");
    assert_eq!(l["ticks"], 300, "{l}");
    assert_eq!(l["agents"], 12, "{l}");
    assert_eq!(l["robots_lost"].as_array().map(Vec::len), Some(0), "{l}");
    validate_lifelong(&out, &problem, l);
    // the fleet never stops: every robot reaches goals, and goals keep being reached late on
    // (a run that ended on arrival, or a deadlocked fleet, reaches none in its second half)
    let goals: Vec<u64> = l["robot_goals"]
        .as_array()
        .unwrap()
        .iter()
        .map(|g| g.as_u64().unwrap())
        .collect();
    assert!(goals.iter().all(|&g| g >= 2), "goals per robot {goals:?}");
    assert!(l["throughput_2nd_half"].as_f64().unwrap() > 0.1, "{l}");
    let by = l["ticks_by_values"].as_u64().unwrap() + l["ticks_by_distance"].as_u64().unwrap();
    assert_eq!(
        by,
        12 * 300,
        "every robot-tick is ranked one way or the other: {l}"
    );
    // no tick waits for learning (these 300 ticks take milliseconds): every robot-tick walks
    // towards a goal learned or not, and is counted once
    let g = &l["learning"];
    let n = |k: &str| g[k].as_u64().unwrap_or_else(|| panic!("{k} in {g}"));
    assert_eq!(
        n("ticks_goal_learned") + n("ticks_goal_unlearned"),
        12 * 300,
        "{g}"
    );
    assert!(n("warm_started") <= n("goals_learned"), "{g}");
    assert_eq!(l["paths_file"], "paths.txt");
    assert_eq!(l["lorr_file"], "lorr-output.json");
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}

#[test]
fn a_goal_cell_learned_before_warm_starts_the_robot_sent_there_again_unless_sharing_is_off() {
    // 8 x 6, open: robot 0 is dealt cells 0 and 47 in turn, robot 1 cells 7 and 40, so each
    // robot is sent again and again to a cell whose fleet table it filled itself
    let rows = ["........"; 6];
    for (share, warm) in [("hints", true), ("none", false)] {
        let dir = scratch("lifelong-warm");
        let out = dir.join("out");
        let p = problem_in(&dir, &rows, &[9, 14], &[0, 7, 47, 40], "roundrobin");
        let id = run_id("lifelong-warm");
        let o = run_bounded(
            Command::new(bin("qfleet"))
                .args([
                    "run", "--json", "--run-id", &id, "--world", "shared", "--lorr",
                ])
                .arg(&p)
                .args([
                    "--ticks",
                    "300",
                    "--tick-ms",
                    "5",
                    "--share",
                    share,
                    "--out",
                ])
                .arg(&out),
        );
        assert!(o.status.success(), "--share {share}: {}", describe(&o));
        let r: Value = serde_json::from_slice(&o.stdout).unwrap();
        let l = &r["lifelong"];
        validate_lifelong(&out, &p, l);
        let g = &l["learning"];
        let n = |k: &str| g[k].as_u64().unwrap_or_else(|| panic!("{k} in {g}"));
        // 300 ticks of 5 ms: the robots learn ahead while they walk
        assert!(n("goals_learned") >= 4, "--share {share}: {g}");
        assert!(n("env_steps") > 0, "--share {share}: {g}");
        assert!(n("ticks_goal_learned") > 0, "--share {share}: {g}");
        let ticks = n("ticks_goal_learned") + n("ticks_goal_unlearned");
        assert_eq!(ticks, 2 * 300, "--share {share}: {g}");
        if warm {
            assert!(n("warm_started") > 0, "--share {share}: {g}");
        } else {
            assert_eq!(n("warm_started"), 0, "--share {share}: {g}");
        }
        assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
    }
}

/// Writes a lifelong problem into `dir`: `map` (MovingAI rows), the start and task cell ids,
/// the strategy, a team of 2; returns the problem file.
fn problem_in(dir: &Path, rows: &[&str], starts: &[u32], tasks: &[u32], strategy: &str) -> PathBuf {
    let cells = |ids: &[u32]| {
        let mut s = format!("{}\n", ids.len());
        for id in ids {
            s.push_str(&format!("{id}\n"));
        }
        s
    };
    let map = format!(
        "type octile\nheight {}\nwidth {}\nmap\n{}\n",
        rows.len(),
        rows[0].len(),
        rows.join("\n")
    );
    std::fs::write(dir.join("m.map"), map).unwrap();
    std::fs::write(dir.join("a.agents"), cells(starts)).unwrap();
    std::fs::write(dir.join("t.tasks"), cells(tasks)).unwrap();
    let p = dir.join("p.json");
    let spec = serde_json::json!({
        "mapFile": "m.map", "agentFile": "a.agents", "teamSize": 2, "taskFile": "t.tasks",
        "numTasksReveal": 1, "taskAssignmentStrategy": strategy,
    });
    std::fs::write(&p, spec.to_string()).unwrap();
    p
}

#[test]
fn a_bad_lifelong_problem_is_refused_with_exit_2_before_anything_starts() {
    // 6 x 4; (3,1) = id 9 is a wall, (5,3) = id 23 is walled in by (4,3) and (5,2)
    let rows = ["......", "...@..", ".....@", "....@."];
    // (what is wrong, starts, tasks, strategy, what the error names); the team is 2
    type Case<'a> = (&'a str, &'a [u32], &'a [u32], &'a str, &'a str);
    let rr = "roundrobin";
    let cases: [Case; 8] = [
        ("id out of range", &[0, 1], &[2, 24], rr, "24"),
        ("blocked start", &[9, 1], &[2, 3], rr, "9"),
        ("blocked task", &[0, 1], &[2, 9], rr, "9"),
        ("shared start", &[0, 0], &[2, 3], rr, "0"),
        ("few starts", &[0], &[2, 3], rr, "team"),
        ("no tasks", &[0, 1], &[], rr, "task"),
        ("unknown strategy", &[0, 1], &[2, 3], "greedy", "greedy"),
        ("unreachable goal", &[0, 1], &[2, 23], rr, "never reach"),
    ];
    for (name, starts, tasks, strategy, needle) in cases {
        let dir = scratch("lifelong-bad");
        let p = problem_in(&dir, &rows, starts, tasks, strategy);
        let id = run_id("lifelong-bad");
        let o = lifelong_run(&id, &p, 10, &dir.join("out"));
        assert_eq!(o.status.code(), Some(2), "{name}: {}", describe(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(needle), "{name}: {err}");
        assert!(pid_with_arg(&id, "--run-id", &id).is_none(), "{name}");
        assert!(!dir.join("out/result.json").exists(), "{name}: nothing ran");
    }
    // a problem file that is not there, and one whose map is not there
    let dir = scratch("lifelong-missing");
    let id = run_id("lifelong-missing");
    let o = lifelong_run(&id, &dir.join("nowhere.json"), 10, &dir.join("out"));
    assert_eq!(o.status.code(), Some(2), "{}", describe(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("nowhere.json"));
    let p = problem_in(&dir, &rows, &[0, 1], &[2, 3], "roundrobin");
    std::fs::remove_file(dir.join("m.map")).unwrap();
    let o = lifelong_run(&id, &p, 10, &dir.join("out"));
    assert_eq!(o.status.code(), Some(2), "{}", describe(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("m.map"));
}
