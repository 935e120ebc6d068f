//! End-to-end: a shared grid (`qfleet run --world shared`). Real processes learn their own
//! starts and goals, then move tick by tick as the coordinator grants; every result is checked
//! by `qfleet_suite::mapf_check`, a validator written from the MAPF benchmark's rules that shares
//! no code with the project (starts, goals, legal moves, vertex and swap conflicts, costs).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use qfleet_suite::mapf_check::{self, Map, validate};
use qfleet_suite::{
    PROCESS_TIMEOUT, bin, describe, leftovers, pid_with_arg, run_bounded, run_id, scratch, skip,
    spawn, wait_bounded, wait_until,
};
use serde_json::Value;

/// An open 12x8 room with a wall segment: small enough to learn in a moment, room to pass.
const ROOM: &str = "type octile\nheight 8\nwidth 12\nmap\n\
............\n\
............\n\
....@@@@....\n\
............\n\
............\n\
....@@@@....\n\
............\n\
............\n";

/// One scenario line: start x, y, goal x, y.
type Pair = (u16, u16, u16, u16);

/// Scenario lines (start x, y → goal x, y) for the room: robots cross each other's ways.
const ROOM_PAIRS: [Pair; 6] = [
    (0, 0, 11, 7),
    (11, 7, 0, 0),
    (0, 7, 11, 0),
    (11, 0, 0, 7),
    (5, 3, 6, 4),
    (6, 4, 5, 3),
];

fn scen_text(map: &str, w: usize, h: usize, pairs: &[Pair]) -> String {
    let mut s = String::from("version 1\n");
    for &(sx, sy, gx, gy) in pairs {
        s.push_str(&format!(
            "0\t{map}\t{w}\t{h}\t{sx}\t{sy}\t{gx}\t{gy}\t1.0\n"
        ));
    }
    s
}

/// Writes `room.map` and `room.scen` into `dir`.
fn room(dir: &Path, pairs: &[Pair]) -> (PathBuf, PathBuf) {
    let map = dir.join("room.map");
    let scen = dir.join("room.scen");
    std::fs::write(&map, ROOM).unwrap();
    std::fs::write(&scen, scen_text("room.map", 12, 8, pairs)).unwrap();
    (map, scen)
}

fn qfleet(args: &[&str]) -> std::process::Output {
    run_bounded(Command::new(bin("qfleet")).args(args))
}

/// `qfleet run --json --world shared` of run `id` on `map`/`scen` with `agents` robots learning
/// `episodes` episodes into `out`, plus `extra`.
fn shared_run(
    id: &str,
    map: &Path,
    scen: &Path,
    agents: u32,
    out: &Path,
    extra: &[&str],
) -> Command {
    let mut cmd = Command::new(bin("qfleet"));
    cmd.args(["run", "--json", "--run-id", id, "--world", "shared"])
        .arg("--map")
        .arg(map)
        .arg("--scen")
        .arg(scen)
        .args(["--agents", &agents.to_string(), "--episodes", "300"])
        .arg("--out")
        .arg(out)
        .args(extra);
    cmd
}

#[test]
fn robots_crossing_a_room_all_arrive_without_a_conflict() {
    let dir = scratch("grid-room");
    let (map, scen) = room(&dir, &ROOM_PAIRS);
    let out = dir.join("out");
    let id = run_id("grid-room");
    let o = run_bounded(&mut shared_run(&id, &map, &scen, 6, &out, &[]));
    assert!(o.status.success(), "{}", describe(&o));
    let r: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(r["robots"].as_array().unwrap().len(), 6);
    let g = &r["grid"];
    assert_eq!(g["ended"], "arrived", "{g}");
    assert_eq!(g["all_arrived"], true, "{g}");
    assert_eq!(g["agents"], 6);
    validate(&out, &map, &scen, 6, g);
    // robots 4 and 5 swap neighbouring cells: one of them had to step aside
    assert!(g["soc_ratio"].as_f64().unwrap() >= 1.0);
    assert!(g["tick_latency_ns"]["count"].as_u64().unwrap() > 0, "{g}");
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}

#[test]
fn with_and_without_the_intent_horizon_every_robot_arrives() {
    // horizon 0: every robot answers every grant; horizon 8: robots answer for their next
    // ticks at once and are woken once per 9 ticks
    let dir = scratch("grid-horizon");
    let (map, scen) = room(&dir, &ROOM_PAIRS);
    for h in ["0", "8"] {
        let out = dir.join(format!("out-{h}"));
        let id = run_id("grid-horizon");
        let o = run_bounded(&mut shared_run(
            &id,
            &map,
            &scen,
            6,
            &out,
            &["--intent-horizon", h],
        ));
        assert!(o.status.success(), "{}", describe(&o));
        let r: Value = serde_json::from_slice(&o.stdout).unwrap();
        let g = &r["grid"];
        assert_eq!(g["all_arrived"], true, "horizon {h}: {g}");
        assert_eq!(g["intents_rejected"], 0, "horizon {h}: {g}");
        validate(&out, &map, &scen, 6, g);
        let log = std::fs::read_to_string(out.join("coordinator.log")).unwrap_or_default();
        let woken = log
            .lines()
            .find_map(|l| l.split("woken on ").nth(1))
            .and_then(|w| w.split(' ').next())
            .and_then(|w| w.parse::<u64>().ok());
        let ticks = g["ticks"].as_u64().unwrap();
        match h {
            "0" => assert_eq!(woken, Some(ticks), "horizon 0 wakes every tick: {log}"),
            _ => {
                assert!(
                    woken.is_some_and(|w| w <= ticks.div_ceil(9) + 1),
                    "horizon 8 wakes once per 9 ticks: {woken:?} of {ticks}"
                );
                // robots answer the first tick while they wait for `Execute`: those that
                // finished learning before the last one surely did before the execution began
                let early = log
                    .lines()
                    .find_map(|l| l.split("; ").nth(1))
                    .and_then(|w| w.split(' ').next())
                    .and_then(|w| w.parse::<u64>().ok());
                assert!(
                    early.is_some_and(|e| e >= 1),
                    "early answers {early:?}: {log}"
                );
            }
        }
        assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
    }
}

#[test]
fn an_instance_that_cannot_run_is_refused_before_anything_starts() {
    let dir = scratch("grid-bad");
    let cases: [(&str, Vec<Pair>, &str); 4] = [
        ("one start", vec![(0, 0, 5, 0), (0, 0, 7, 0)], "start"),
        ("one goal", vec![(0, 0, 5, 0), (1, 0, 5, 0)], "goal"),
        // (4, 2) is a wall
        ("walled", vec![(0, 0, 4, 2), (1, 0, 5, 0)], "4,2"),
        (
            "start on goal",
            vec![(0, 0, 5, 0), (3, 3, 3, 3)],
            "starts on its goal",
        ),
    ];
    for (name, pairs, needle) in cases {
        let (map, scen) = room(&dir, &pairs);
        let id = run_id("grid-bad");
        let o = qfleet(&[
            "run",
            "--run-id",
            &id,
            "--world",
            "shared",
            "--map",
            map.to_str().unwrap(),
            "--scen",
            scen.to_str().unwrap(),
            "--agents",
            "2",
        ]);
        assert_eq!(o.status.code(), Some(2), "{name}: {}", describe(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(needle), "{name}: {err}");
        assert!(pid_with_arg(&id, "--run-id", &id).is_none());
    }
    // more agents than scenario lines, and --agents without a shared world; with robots of
    // other hosts: the agents are the whole fleet's (checked as one instance), this host's
    // robots and theirs must make the agents, and one robot runs here
    let (map, scen) = room(&dir, &ROOM_PAIRS[..2]);
    let far = ["--listen", "tcp/127.0.0.1:1"];
    for extra in [
        &["--world", "shared", "--agents", "3"][..],
        &["--agents", "2"][..],
        &["--world", "shared", "--agents", "2", "--robots", "3"][..],
        &[
            &["--world", "shared", "--agents", "3", "--remote-robots", "1"][..],
            &far,
        ]
        .concat(),
        &[
            &["--world", "shared", "--robots", "2", "--remote-robots", "1"][..],
            &far,
        ]
        .concat(),
        &[
            &["--world", "shared", "--agents", "2", "--robots", "2"][..],
            &["--remote-robots", "1"],
            &far,
        ]
        .concat(),
        &[
            &["--world", "shared", "--agents", "2", "--remote-robots", "2"][..],
            &far,
        ]
        .concat(),
    ] {
        let o = qfleet(
            &[
                &["run", "--map", map.to_str().unwrap()][..],
                &["--scen", scen.to_str().unwrap()][..],
                extra,
            ]
            .concat(),
        );
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {}", describe(&o));
    }
}

#[test]
fn a_robot_killed_while_the_fleet_moves_leaves_the_grid_and_the_others_arrive() {
    let dir = scratch("grid-kill");
    let (map, scen) = room(&dir, &ROOM_PAIRS[..4]);
    let out = dir.join("out");
    let id = run_id("grid-kill");
    // 60 ms a tick: the execution lasts seconds, time to kill robot 2 in the middle of it
    let child = spawn(&mut shared_run(
        &id,
        &map,
        &scen,
        4,
        &out,
        &["--tick-ms", "60"],
    ));
    let log = out.join("coordinator.log");
    let moving = wait_until(PROCESS_TIMEOUT, || {
        std::fs::read_to_string(&log).is_ok_and(|l| l.contains("shared grid:"))
    });
    assert!(moving, "the execution never started");
    std::thread::sleep(Duration::from_millis(300));
    let pid = pid_with_arg(&id, "--robot-id", "2").expect("robot 2 alive");
    // SAFETY: a plain kill(2) of a process of this test's run.
    unsafe { libc::kill(pid, libc::SIGKILL) };
    let o = wait_bounded(child, PROCESS_TIMEOUT);
    // a lost robot is a run that completed without all its robots: exit 1 with the result
    assert!(!o.status.success(), "{}", describe(&o));
    let r: Value = serde_json::from_slice(&o.stdout).expect("the result is printed");
    let g = &r["grid"];
    assert_eq!(g["robots"][2]["left"], true, "{g}");
    assert_eq!(g["all_arrived"], false, "{g}");
    for i in [0, 1, 3] {
        assert!(g["robots"][i]["arrived_at"].as_u64().is_some(), "{g}");
    }
    assert_eq!(g["conflicts"], 0, "{g}");
    // the paths up to the kill hold no conflict either (robot 2 stays where it left)
    let m = Map::parse(ROOM);
    let pairs = mapf_check::scen_pairs(&std::fs::read_to_string(&scen).unwrap(), 4);
    let paths = mapf_check::parse_paths(&std::fs::read_to_string(out.join("paths.txt")).unwrap());
    let c = mapf_check::check(&m, &pairs, &paths);
    assert_eq!((c.swap, c.illegal, c.bad_start), (0, 0, 0), "{c:?}");
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}

/// MovingAI's random-32-32-10 with the first N pairs of its random-1 scenario, when the shared
/// data is there.
fn movingai() -> Option<(PathBuf, PathBuf)> {
    let d = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/movingai");
    let map = d.join("random-32-32-10.map");
    let scen = d.join("random-32-32-10-random-1.scen");
    (map.exists() && scen.exists()).then_some((map, scen))
}

#[test]
fn sixteen_robots_on_a_movingai_instance_arrive_near_the_lower_bound() {
    let Some((map, scen)) = movingai() else {
        skip(
            "sixteen_robots_on_a_movingai_instance_arrive_near_the_lower_bound",
            "../shared/data/movingai is not there",
        );
        return;
    };
    let dir = scratch("grid-movingai");
    let out = dir.join("out");
    let id = run_id("grid-mai");
    let o = run_bounded(&mut shared_run(&id, &map, &scen, 16, &out, &[]));
    assert!(o.status.success(), "{}", describe(&o));
    let r: Value = serde_json::from_slice(&o.stdout).unwrap();
    let g = &r["grid"];
    assert_eq!(g["all_arrived"], true, "{g}");
    validate(&out, &map, &scen, 16, g);
    assert!(g["soc_ratio"].as_f64().unwrap() <= 1.10, "{g}");
}

#[test]
fn two_robots_that_must_swap_in_a_corridor_end_unsolvable_not_hung() {
    // a corridor with no pocket: no plan exists, and the run says so within its ticks
    let dir = scratch("grid-corridor");
    let map = dir.join("corridor.map");
    let scen = dir.join("corridor.scen");
    std::fs::write(&map, "type octile\nheight 1\nwidth 6\nmap\n......\n").unwrap();
    std::fs::write(
        &scen,
        scen_text("corridor.map", 6, 1, &[(0, 0, 5, 0), (5, 0, 0, 0)]),
    )
    .unwrap();
    let out = dir.join("out");
    let id = run_id("grid-corr");
    let o = run_bounded(&mut shared_run(&id, &map, &scen, 2, &out, &[]));
    assert!(o.status.success(), "{}", describe(&o));
    let r: Value = serde_json::from_slice(&o.stdout).unwrap();
    let g = &r["grid"];
    assert_eq!(g["ended"], "unsolvable", "{g}");
    assert_eq!(g["all_arrived"], false, "{g}");
    assert_eq!(g["conflicts"], 0, "{g}");
    assert!(g["ticks"].as_u64().unwrap() < 1000, "{g}");
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}

// ---- experiments on one shared grid (`world = "shared"` in a manifest) ----

/// The repository's example manifest of a two-phase shared-grid experiment.
fn example_manifest() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/grid/warehouse-two-phases.toml")
}

/// Checks phase `phase`'s paths file of an experiment against its own (start, goal) pairs.
fn validate_phase(
    seed_dir: &Path,
    map: &Map,
    pairs: &[(mapf_check::Xy, mapf_check::Xy)],
    phase: &Value,
) {
    let p = phase["phase"].as_u64().unwrap();
    let g = &phase["grid"];
    assert_eq!(g["paths_file"], format!("paths-phase-{p}.txt"), "{g}");
    let text = std::fs::read_to_string(seed_dir.join(format!("paths-phase-{p}.txt"))).unwrap();
    let paths = mapf_check::parse_paths(&text);
    let c = mapf_check::check(map, pairs, &paths);
    assert_eq!(
        (c.vertex, c.swap, c.illegal, c.bad_start, c.not_arrived),
        (0, 0, 0, 0, 0),
        "phase {p}: {c:?}"
    );
    assert_eq!(g["conflicts"], 0, "{g}");
    assert_eq!(g["all_arrived"], true, "phase {p}: {g}");
    assert_eq!(g["sum_of_costs"].as_u64(), Some(c.sum_of_costs), "{g}");
    assert_eq!(g["makespan"].as_u64(), Some(c.makespan), "{g}");
    assert_eq!(g["lower_bound"].as_u64(), Some(c.lower_bound), "{g}");
    assert_eq!(paths[0].len() as u64, c.makespan + 1);
}

/// Runs `qfleet experiment --json` on `manifest` into `out`; its one result.
fn shared_experiment(tag: &str, manifest: &Path, out: &Path) -> Value {
    let id = run_id(tag);
    let o = run_bounded(
        Command::new(bin("qfleet"))
            .args(["experiment", "--json", "--run-id", &id, "--out"])
            .arg(out)
            .arg(manifest),
    );
    assert!(o.status.success(), "{}", describe(&o));
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    v[0].clone()
}

#[test]
fn a_two_phase_shared_world_experiment_arrives_in_both_phases_without_a_conflict() {
    let dir = scratch("grid-exp");
    let grid = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/grid");
    let m = Map::parse(&std::fs::read_to_string(grid.join("warehouse.map")).unwrap());
    let text = std::fs::read_to_string(grid.join("warehouse.scen")).unwrap();
    let lines = mapf_check::scen_pairs(&text, 6);
    // the example: every phase from the scenario's starts, phase 1 to the next robot's goal
    let out = dir.join("out");
    let r = shared_experiment("grid-exp", &example_manifest(), &out);
    let phases = r["phases"].as_array().unwrap();
    assert_eq!(phases.len(), 2, "{r}");
    let next: Vec<(mapf_check::Xy, mapf_check::Xy)> =
        (0..6).map(|i| (lines[i].0, lines[(i + 1) % 6].1)).collect();
    validate_phase(&out.join("seed-1"), &m, &lines, &phases[0]);
    validate_phase(&out.join("seed-1"), &m, &next, &phases[1]);
    // robots learned each phase's goal: goal ids are per robot, rotated in phase 1
    for (i, rp) in phases[1]["robots"].as_array().unwrap().iter().enumerate() {
        assert_eq!(rp["goal"].as_u64(), Some(((i + 1) % 6) as u64), "{rp}");
    }
    // phase_start = "previous": phase 1 goes from where phase 0 left the robots (its goals)
    let manifest = dir.join("previous.toml");
    let example = std::fs::read_to_string(example_manifest()).unwrap();
    let previous = example
        .replacen(
            "world = \"shared\"",
            "world = \"shared\"\nphase_start = \"previous\"",
            1,
        )
        .replace("\"warehouse.", &format!("\"{}/warehouse.", grid.display()));
    std::fs::write(&manifest, previous).unwrap();
    let out = dir.join("out-previous");
    let r = shared_experiment("grid-exp-prev", &manifest, &out);
    let phases = r["phases"].as_array().unwrap();
    let onward: Vec<(mapf_check::Xy, mapf_check::Xy)> =
        (0..6).map(|i| (lines[i].1, lines[(i + 1) % 6].1)).collect();
    validate_phase(&out.join("seed-1"), &m, &lines, &phases[0]);
    validate_phase(&out.join("seed-1"), &m, &onward, &phases[1]);
}

/// A manifest on the room map of these tests (`room.map` beside it) with `body` after the map.
fn room_manifest(dir: &Path, name: &str, body: &str) -> PathBuf {
    room(dir, &ROOM_PAIRS);
    let file = dir.join(format!("{name}.toml"));
    let text = format!(
        "world = \"shared\"\nepisodes = 20\n[map]\nsource = \"room.map\"\nscen = \"room.scen\"\n{body}"
    );
    std::fs::write(&file, text).unwrap();
    file
}

#[test]
fn a_shared_world_manifest_that_cannot_run_is_refused_before_anything_starts() {
    let dir = scratch("grid-exp-bad");
    // (4, 2) is a wall of the room; (11, 4) below is walled in by the extra wall written below
    let cases: [(&str, &str, &[&str]); 7] = [
        (
            "one start",
            "[robots]\ncount = 2\nstarts = [[0, 0], [0, 0]]\ngoals = [[5, 0], [7, 0]]\n",
            &["phases[0]", "robots 0 and 1 both start at (0,0)"],
        ),
        (
            "one goal in a phase",
            "[robots]\ncount = 3\n[[phases]]\n[[phases]]\npolicy = \"fixed\"\nassign = [2, 2, 2]\n",
            &["phases[1]", "robots 0 and 1 both have their goal at (11,0)"],
        ),
        (
            "walled in",
            "[robots]\ncount = 2\nstarts = [[0, 0], [1, 0]]\ngoals = [[11, 3], [5, 0]]\n",
            &["phases[0]", "robot 0: goal (11,3) cannot be reached"],
        ),
        (
            "on a wall",
            "[robots]\ncount = 2\nstarts = [[0, 0], [1, 0]]\ngoals = [[4, 2], [5, 0]]\n",
            &["robot 0: goal (4,2) is on a wall"],
        ),
        (
            "a policy gives two robots one goal",
            "[[goals]]\ncell = [9, 6]\n[robots]\ncount = 2\nstarts = [[0, 0], [1, 0]]\n",
            &[
                "phases[0]",
                "robots 0 and 1 both have their goal at (9,6)",
                "round-robin",
            ],
        ),
        (
            "more robots than a grid takes",
            "[robots]\ncount = 257\n",
            &["robots.count", "at most 256"],
        ),
        (
            "a goal on the learning start",
            "[robots]\ncount = 2\nstarts = [[0, 0], [1, 0]]\ngoals = [[5, 0], [1, 0]]\n",
            &["robot 1's goal (1,0) is its start"],
        ),
    ];
    for (name, body, needles) in cases {
        let file = room_manifest(&dir, "bad", body);
        if name == "walled in" {
            // wall (11, 3) in: (10, 3), (11, 2) and (11, 4) blocked
            let walled = ROOM.replace(
                "....@@@@....\n............\n............\n....@@@@....\n",
                "....@@@@...@\n..........@.\n...........@\n....@@@@....\n",
            );
            std::fs::write(dir.join("room.map"), walled).unwrap();
        }
        let id = run_id("grid-exp-bad");
        let out = dir.join(format!("out-{}", name.replace(' ', "-")));
        let o = run_bounded(
            Command::new(bin("qfleet"))
                .args(["experiment", "--run-id", &id, "--out"])
                .arg(&out)
                .arg(&file),
        );
        assert_eq!(o.status.code(), Some(2), "{name}: {}", describe(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        for n in needles {
            assert!(err.contains(n), "{name}: {n:?} not in {err}");
        }
        // nothing started: no process of the run, no file of it, no out directory
        assert!(pid_with_arg(&id, "--run-id", &id).is_none(), "{name}");
        assert!(leftovers(&id).is_empty(), "{name}: {:?}", leftovers(&id));
        assert!(
            !out.join("seed-1").exists(),
            "{name}: a seed directory was made"
        );
    }
    // with robots of other hosts the instance is checked the same, before anything starts
    // (robots across hosts on one grid: tests/multihost.rs)
    let (name, body, needles) = cases[0];
    let file = room_manifest(&dir, "bad", body);
    let id = run_id("grid-exp-bad");
    let out = dir.join("out-remote");
    let o = run_bounded(
        Command::new(bin("qfleet"))
            .args(["experiment", "--run-id", &id, "--remote-robots", "1"])
            .args(["--listen", "tcp/127.0.0.1:1", "--out"])
            .arg(&out)
            .arg(&file),
    );
    assert_eq!(o.status.code(), Some(2), "{name}: {}", describe(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    for n in needles {
        assert!(err.contains(n), "{name}: {n:?} not in {err}");
    }
    assert!(pid_with_arg(&id, "--run-id", &id).is_none());
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
    assert!(!out.join("seed-1").exists(), "a seed directory was made");
}
