//! End-to-end: `qfleet experiment` with real `robot-agent` and `qfleet-coordinator --plan`
//! processes over iceoryx2 shared memory. Unique run ids, bounded in time, no shared-memory
//! files left behind.

use std::process::Command;

use qfleet_suite::{bin, describe, leftovers, run_bounded, run_id, scratch};
use serde_json::Value;

/// Runs `qfleet experiment` on `manifest` (written to a scratch dir) and returns the result of
/// its single seed.
fn experiment(tag: &str, manifest: &str, extra: &[&str]) -> Value {
    let dir = scratch(&format!("exp-{tag}"));
    let file = dir.join("m.toml");
    std::fs::write(&file, manifest).expect("write manifest");
    let id = run_id(tag);
    let out = run_bounded(
        Command::new(bin("qfleet"))
            .args(["experiment", "--json", "--run-id", &id, "--out"])
            .arg(dir.join("out"))
            .arg(&file)
            .args(extra),
    );
    assert!(
        out.status.success(),
        "qfleet experiment failed: {}",
        describe(&out)
    );
    let v: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {}", describe(&out)));
    let left = leftovers(&id);
    assert!(left.is_empty(), "files of run {id} left behind: {left:?}");
    let runs = v.as_array().expect("a list of seeds");
    assert_eq!(runs.len(), 1, "{v}");
    // the seed's result.json is the result printed, and every robot left its log
    let seed = runs[0]["seed"].as_u64().expect("seed");
    let seed_dir = dir.join("out").join(format!("seed-{seed}"));
    let kept: Value = serde_json::from_str(
        &std::fs::read_to_string(seed_dir.join("result.json")).expect("result.json in --out"),
    )
    .expect("result.json is JSON");
    assert_eq!(kept, runs[0], "result.json differs from the printed result");
    let robots = runs[0]["robots"].as_u64().expect("robots");
    for r in 0..robots {
        assert!(
            seed_dir.join(format!("robot-{r}.log")).is_file(),
            "robot {r} has no log in {}",
            seed_dir.display()
        );
    }
    runs[0].clone()
}

fn goal(phase: &Value, g: u64) -> &Value {
    phase["goals"]
        .as_array()
        .expect("goals")
        .iter()
        .find(|x| x["goal"] == g)
        .unwrap_or_else(|| panic!("goal {g} missing in {phase}"))
}

#[test]
fn a_small_two_goal_two_phase_manifest_runs_end_to_end() {
    let r = experiment(
        "small",
        r#"
name = "small"
sharing = "both"
episodes = 60
seeds = [5]
[learner]
kind = "improved"   # discoveries are pseudo targets: the planning default makes none
[map]
source = "builtin:paper-10"
[[goals]]
cell = [9, 9]
[[goals]]
cell = [9, 0]
[robots]
count = 4
start = [0, 0]
[[phases]]
[[phases]]
rotate = 1
episodes = 40
"#,
        &[],
    );
    let phases = r["phases"].as_array().expect("phases");
    assert_eq!(phases.len(), 2, "{r}");
    for (p, phase) in phases.iter().enumerate() {
        let robots = phase["robots"].as_array().expect("robots");
        assert_eq!(robots.len(), 4);
        for x in robots {
            assert_eq!(x["status"], "finished", "{x}");
            assert!(x["env_steps"].as_u64().unwrap() > 0, "{x}");
            // round-robin, shifted by one in phase 1
            let id = x["robot_id"].as_u64().unwrap();
            assert_eq!(x["goal"].as_u64().unwrap(), (id + p as u64) % 2, "{x}");
        }
        for g in [0, 1] {
            let gp = goal(phase, g);
            assert_eq!(gp["robots"].as_array().unwrap().len(), 2, "{gp}");
            assert!(gp["avg_steps"].as_f64().unwrap() > 0.0);
        }
    }
    assert_eq!(phases[1]["episodes"], 40);
    assert!(r["discoveries_received"].as_u64().unwrap() > 0, "{r}");
    assert!(r["relays_sent"].as_u64().unwrap() > 0, "{r}");
    assert!(r["q_updates_merged"].as_u64().unwrap() > 0, "{r}");
    assert_eq!(r["rejected"], 0, "{r}");
}

#[test]
fn the_merged_table_of_a_shared_run_reaches_the_optimum() {
    let r = experiment(
        "merged",
        r#"
sharing = "hints"
episodes = 300
seeds = [1]
[map]
source = "builtin:paper-20"
[robots]
count = 4
"#,
        &[],
    );
    let g = goal(&r["phases"][0], 0);
    assert_eq!(g["merged_optimal"], true, "{g}");
    assert!(g["merged_time_to_optimal_s"].as_f64().is_some(), "{g}");
    assert!(g["merged_steps_per_robot"].as_f64().unwrap() > 0.0, "{g}");
    assert_eq!(g["merged_path_len"][0], g["optimal_path_len"][0], "{g}");
}

#[test]
fn discoveries_reach_a_robot_that_never_reached_that_goal() {
    // phase 0: robot 0 learns goal 0, robot 1 goal 1; phase 1: robot 1 moves to goal 0 and
    // starts with robot 0's relayed pseudo targets before it has reached goal 0 itself
    let r = experiment(
        "relay",
        r#"
sharing = "discoveries"
episodes = 60
seeds = [3]
[learner]
kind = "improved"   # discoveries are pseudo targets: the planning default makes none
[map]
source = "builtin:paper-10"
[[goals]]
cell = [9, 9]
[[goals]]
cell = [9, 0]
[robots]
count = 2
start = [0, 0]
[assignment]
policy = "fixed"
goals = [0, 1]
[[phases]]
[[phases]]
assign = [0, 0]
episodes = 5
"#,
        &[],
    );
    let p0 = &r["phases"][0]["robots"];
    assert_eq!(p0[1]["goal"], 1, "{p0}");
    assert!(p0[0]["discoveries_sent"].as_u64().unwrap() > 0, "{p0}");
    let p1 = &r["phases"][1]["robots"];
    assert_eq!(p1[1]["goal"], 0, "{p1}");
    assert!(
        p1[1]["relays_applied"].as_u64().unwrap() > 0,
        "robot 1 got no pseudo targets of goal 0: {r}"
    );
}

#[test]
fn an_invalid_manifest_is_refused_with_the_field_and_reason() {
    let dir = scratch("exp-invalid");
    let file = dir.join("bad.toml");
    std::fs::write(
        &file,
        "[map]\nsource = \"builtin:paper-10\"\n[robots]\ncount = 2\n[[phases]]\nepisodes = 0\n",
    )
    .unwrap();
    let out = run_bounded(Command::new(bin("qfleet")).arg("experiment").arg(&file));
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("phases[0].episodes") && err.contains("must be 1..="),
        "{}",
        describe(&out)
    );
}

/// The pid of the live process of the experiment launched with `--run-id prefix` (its run
/// ids are `<prefix>-s<seed>-…`) whose command line has `arg value`, if any.
fn child_with_arg(prefix: &str, arg: &str, value: &str) -> Option<i32> {
    let run = format!("--run-id\0{prefix}-");
    let needle = format!("{arg}\0{value}\0");
    std::fs::read_dir("/proc")
        .ok()?
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<i32>().ok())
        .find(|pid| {
            let cmd = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
            let cmd = String::from_utf8_lossy(&cmd);
            let zombie = std::fs::read_to_string(format!("/proc/{pid}/stat"))
                .map(|s| {
                    s.rsplit_once(')')
                        .is_none_or(|(_, rest)| rest.trim_start().starts_with('Z'))
                })
                .unwrap_or(true);
            !zombie && cmd.contains(&run) && cmd.contains(&needle)
        })
}

/// The files of `dir` whose names start with `prefix` and end with `suffix`.
fn files_like(dir: &std::path::Path, prefix: &str, suffix: &str) -> Vec<String> {
    std::fs::read_dir(dir)
        .map(|d| {
            d.flatten()
                .filter_map(|e| e.file_name().into_string().ok())
                .filter(|n| n.starts_with(prefix) && n.ends_with(suffix))
                .collect()
        })
        .unwrap_or_default()
}

/// A manifest long enough to kill a robot or the coordinator in the middle of its first phase
/// (4000 episodes took 0.24 s on the 2-core machine: a kill 0.5 s after the robots started
/// learning came after the end).
const LONG_TWO_PHASES: &str = r#"
name = "long"
sharing = "both"
episodes = 100000
seeds = [2]
timeout_s = 100
[learner]
kind = "improved"   # discoveries to lose (planning makes none), and long episodes
[map]
source = "builtin:paper-20"
[robots]
count = 3
[[phases]]
[[phases]]
episodes = 200
"#;

/// The pid of robot `robot`'s live process in the experiment started with `--run-id prefix`,
/// and its run id. `qfleet experiment --run-id` takes a prefix: each seed runs under
/// `<prefix>-s<seed>-<pid>-<time>`, so the robots' command lines never hold the prefix alone.
fn experiment_robot(prefix: &str, robot: u32) -> Option<(i32, String)> {
    experiment_process(prefix, "robot-agent", &format!("--robot-id\0{robot}\0"))
}

/// The pid and run id of a live process of the experiment started with `--run-id prefix`
/// whose program is named `program` and whose command line holds `arg` (NUL-separated words).
fn experiment_process(prefix: &str, program: &str, arg: &str) -> Option<(i32, String)> {
    for e in std::fs::read_dir("/proc").ok()?.flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|n| n.parse::<i32>().ok()) else {
            continue;
        };
        let Ok(cmd) = std::fs::read(format!("/proc/{pid}/cmdline")) else {
            continue;
        };
        let args: Vec<&[u8]> = cmd.split(|&b| b == 0).collect();
        let run_id = args
            .windows(2)
            .find(|w| w[0] == b"--run-id")
            .map(|w| String::from_utf8_lossy(w[1]).into_owned());
        let zombie = std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .map(|s| {
                s.rsplit_once(')')
                    .is_none_or(|(_, rest)| rest.trim_start().starts_with('Z'))
            })
            .unwrap_or(true);
        let named = args
            .first()
            .is_some_and(|a| a.rsplit(|&b| b == b'/').next() == Some(program.as_bytes()));
        if let Some(id) = run_id
            && named
            && id.starts_with(&format!("{prefix}-"))
            && String::from_utf8_lossy(&cmd).contains(arg)
            && !zombie
        {
            return Some((pid, id));
        }
    }
    None
}

/// Waits (bounded) until robot `robot` of run `id` published a state: it is past the start
/// handshake and learning.
fn wait_learning(id: &str, robots: u32, robot: u32) {
    use bus::bus_schema::RobotState;
    let cfg = bus::BusConfig::new(id, robots).expect("config");
    let mut seen = false;
    let mut probe = None;
    assert!(
        qfleet_suite::wait_until(qfleet_suite::PROCESS_TIMEOUT, || {
            // the services exist once the coordinator is up: retry opening them
            if probe.is_none()
                && let Ok(node) = cfg.create_node("qfleet-test-probe")
                && let Ok(inbox) = bus::Inbox::<RobotState>::open(&node, &cfg)
            {
                probe = Some((node, inbox));
            }
            if let Some((_, inbox)) = &probe {
                while let Ok(Some(s)) = inbox.receive() {
                    seen |= s.robot_id == robot;
                }
            }
            seen
        }),
        "robot {robot} of run {id} never started learning"
    );
    qfleet_suite::leave_run(probe, id);
}

/// Starts `qfleet experiment` on [`LONG_TWO_PHASES`] with the restart policy in a scratch
/// directory `name` under a run-id prefix `id`, and waits until robot `robot` runs: the
/// directory, the prefix, the launcher and that robot's (pid, run id).
fn start_long_experiment(
    name: &str,
    id: &str,
    robot: u32,
) -> (
    qfleet_suite::Scratch,
    String,
    std::process::Child,
    (i32, String),
) {
    start_experiment(LONG_TWO_PHASES, name, id, robot)
}

/// [`start_long_experiment`] with another manifest.
fn start_experiment(
    manifest: &str,
    name: &str,
    id: &str,
    robot: u32,
) -> (
    qfleet_suite::Scratch,
    String,
    std::process::Child,
    (i32, String),
) {
    let dir = scratch(name);
    let file = dir.join("m.toml");
    std::fs::write(&file, manifest).expect("write manifest");
    let id = run_id(id);
    let child = qfleet_suite::spawn(
        Command::new(bin("qfleet"))
            .args(["experiment", "--json", "--run-id", &id])
            .args(["--restart", "on-failure", "--max-restarts", "2", "--out"])
            .arg(dir.join("out"))
            .arg(&file),
    );
    let mut found = None;
    assert!(
        qfleet_suite::wait_until(qfleet_suite::PROCESS_TIMEOUT, || {
            found = experiment_robot(&id, robot);
            found.is_some()
        }),
        "robot {robot} of experiment {id} never started"
    );
    (dir, id, child, found.unwrap())
}

#[test]
fn an_experiment_robot_killed_mid_phase_is_restarted_and_warm_started() {
    let (dir, id, child, (pid, run)) = start_long_experiment("exp-restart", "exprestart", 1);
    // mid-phase: learning, with hints merged into the fleet table it is warm-started from
    wait_learning(&run, 3, 1);
    std::thread::sleep(std::time::Duration::from_millis(500));
    // SAFETY: kill(2) on a robot this test started through qfleet experiment.
    unsafe {
        libc::kill(pid, libc::SIGKILL);
    }
    let out = qfleet_suite::wait_bounded(child, qfleet_suite::PROCESS_TIMEOUT);
    assert!(out.status.success(), "{}", describe(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("robot-agent 1 was killed by signal 9; restarting it"),
        "{}",
        describe(&out)
    );
    let v: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {}", describe(&out)));
    for phase in v[0]["phases"].as_array().expect("phases") {
        for x in phase["robots"].as_array().expect("robots") {
            assert_eq!(x["status"], "finished", "{x}");
        }
    }
    let live = &v[0]["liveness"];
    assert_eq!(live["restarts"], 1, "{live}");
    let restarted: Vec<&Value> = live["events"]
        .as_array()
        .expect("events")
        .iter()
        .filter(|e| e["kind"] == "restarted" && e["robot_id"] == 1)
        .collect();
    assert_eq!(restarted.len(), 1, "{live}");
    // the new process started from its goal's fleet table
    let seed = v[0]["seed"].as_u64().expect("seed");
    let own: report::RobotResult =
        report::OutDir::new(dir.join("out").join(format!("seed-{seed}")))
            .read_json(report::OutFile::Robot(1))
            .expect("robot-1.json");
    assert!(own.counters.warm_start_entries > 0, "{:?}", own.counters);
    assert!(leftovers(&id).is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_experiment_survives_a_coordinator_kill() {
    // mid-phase: every robot is learning phase 0 and none has finished it yet (no phase file)
    let (dir, id, child, (_, run)) = start_long_experiment("exp-coord-kill", "xc", 0);
    let seed_dir = dir.join("out").join("seed-2");
    for r in 0..3 {
        wait_learning(&run, 3, r);
    }
    let coord = child_with_arg(
        &id,
        "--plan",
        &seed_dir.join("plan.json").display().to_string(),
    );
    assert!(coord.is_some(), "no coordinator process of {run}");
    let done_before = files_like(&seed_dir, "robot-", "-phase-0.json");
    // SAFETY: kill(2) on the coordinator this test started through qfleet experiment.
    unsafe {
        libc::kill(coord.unwrap(), libc::SIGKILL);
    }
    assert!(
        done_before.is_empty(),
        "the kill came after phase 0 ended for {done_before:?}: make the phase longer"
    );
    let out = qfleet_suite::wait_bounded(child, qfleet_suite::PROCESS_TIMEOUT);
    assert!(out.status.success(), "{}", describe(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("coordinator was killed by signal 9; restarting it"),
        "{}",
        describe(&out)
    );
    let v: Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let r: report::run::ExperimentResult =
        serde_json::from_value(v[0].clone()).expect("an ExperimentResult");
    assert_eq!(r.coordinator_restarts, 1, "{v}");
    assert!(!r.interrupted, "{v}");
    assert_eq!(r.phases.len(), 2, "{v}");
    for phase in &r.phases {
        assert_eq!(phase.robots.len(), 3, "{v}");
        for x in &phase.robots {
            assert_eq!(x.status, report::run::RobotOutcome::Finished, "{v}");
            assert!(x.episodes > 0, "{v}");
        }
        assert_eq!(
            phase.discoveries_received, phase.discoveries_sent,
            "phase {}: {v}",
            phase.phase
        );
    }
    assert!(r.phases[0].discoveries_sent > 0, "nothing to lose: {v}");
    // every robot noticed the loss and re-joined the new coordinator
    for robot in 0..3 {
        let text = std::fs::read_to_string(seed_dir.join(format!("robot-{robot}.json")))
            .expect("robot result");
        let rr: report::RobotResult = serde_json::from_str(&text).expect("a RobotResult");
        assert_eq!(
            rr.counters.link.coordinator_losses, 1,
            "robot {robot}: {text}"
        );
        assert_eq!(rr.counters.link.rejoins, 1, "robot {robot}: {text}");
    }
    let left = leftovers(&id);
    assert!(left.is_empty(), "{left:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Two long phases of the paper's improved learner (it makes the discoveries the phases
/// count), so that a kill can land in the middle of the second one.
const LONG_BOTH_PHASES: &str = r#"
name = "long both"
sharing = "both"
episodes = 60000
seeds = [3]
timeout_s = 100
[map]
source = "builtin:paper-20"
[[goals]]
name = "corner"
cell = [19, 19]
[[goals]]
name = "edge"
cell = [19, 0]
[robots]
count = 3
[assignment]
policy = "round-robin"
[learner]
kind = "improved"
[[phases]]
[[phases]]
rotate = 1
"#;

/// Waits (bounded) until every robot of the experiment in `seed_dir` wrote its result of
/// phase `phase`.
fn wait_phase_done(seed_dir: &std::path::Path, robots: usize, phase: usize) {
    assert!(
        qfleet_suite::wait_until(qfleet_suite::PROCESS_TIMEOUT, || {
            files_like(seed_dir, "robot-", &format!("-phase-{phase}.json")).len() == robots
        }),
        "phase {phase} never ended in {}",
        seed_dir.display()
    );
}

/// The checks every resumed experiment of [`LONG_BOTH_PHASES`] must pass: exit 0, two phases
/// in which every robot finished and every discovery sent was received, nothing left.
fn both_phases_complete(out: &std::process::Output, id: &str) -> report::run::ExperimentResult {
    assert!(out.status.success(), "{}", describe(out));
    let v: Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let r: report::run::ExperimentResult =
        serde_json::from_value(v[0].clone()).expect("an ExperimentResult");
    assert!(!r.interrupted, "{v}");
    assert_eq!(r.phases.len(), 2, "{v}");
    for phase in &r.phases {
        assert_eq!(phase.robots.len(), 3, "{v}");
        for x in &phase.robots {
            assert_eq!(x.status, report::run::RobotOutcome::Finished, "{v}");
            assert!(x.episodes > 0, "{v}");
        }
        assert_eq!(
            phase.discoveries_received, phase.discoveries_sent,
            "phase {}: {v}",
            phase.phase
        );
    }
    let left = leftovers(id);
    assert!(left.is_empty(), "{left:?}");
    r
}

#[test]
fn a_robot_killed_in_a_later_phase_is_restarted_into_that_phase() {
    let (dir, id, child, (_, run)) = start_experiment(LONG_BOTH_PHASES, "exp-late-robot", "xl", 1);
    let seed_dir = dir.join("out").join("seed-3");
    wait_phase_done(&seed_dir, 3, 0);
    // phase 1 under way: robot 1 (the same process) is learning it
    wait_learning(&run, 3, 1);
    std::thread::sleep(std::time::Duration::from_millis(300));
    let (pid, _) = experiment_robot(&id, 1).expect("robot 1 alive in phase 1");
    // SAFETY: kill(2) on a robot this test started through qfleet experiment.
    unsafe {
        libc::kill(pid, libc::SIGKILL);
    }
    assert!(
        files_like(&seed_dir, "robot-1", "-phase-1.json").is_empty(),
        "robot 1 had already finished phase 1: make the phase longer"
    );
    let out = qfleet_suite::wait_bounded(child, qfleet_suite::PROCESS_TIMEOUT);
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("robot-agent 1 was killed by signal 9; restarting it"),
        "{}",
        describe(&out)
    );
    let r = both_phases_complete(&out, &id);
    assert_eq!(r.liveness.restarts, 1, "{:?}", r.liveness);
    // the new process learned phase 1's goal, not phase 0's again
    let p1: Value = serde_json::from_str(
        &std::fs::read_to_string(seed_dir.join("robot-1-phase-1.json")).expect("phase 1 file"),
    )
    .unwrap();
    let p0: Value = serde_json::from_str(
        &std::fs::read_to_string(seed_dir.join("robot-1-phase-0.json")).expect("phase 0 file"),
    )
    .unwrap();
    let plan: Value = serde_json::from_str(
        &std::fs::read_to_string(seed_dir.join("plan.json")).expect("plan.json"),
    )
    .unwrap();
    let goal_of = |phase: usize| plan["assignment"][phase][1].clone();
    assert_ne!(goal_of(0), goal_of(1), "the phases must differ for robot 1");
    assert_eq!(p1["goal_id"], goal_of(1), "{p1}");
    assert_eq!(p0["goal_id"], goal_of(0), "{p0}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_coordinator_killed_after_a_phase_ended_resumes_with_the_next_phase() {
    let (dir, id, child, _) = start_experiment(LONG_BOTH_PHASES, "exp-late-coord", "xk", 0);
    let seed_dir = dir.join("out").join("seed-3");
    wait_phase_done(&seed_dir, 3, 0);
    // the phase's result is in the checkpoint once the coordinator closed it
    let checkpoint = seed_dir.join("experiment-checkpoint.json");
    let mut phase0 = Value::Null;
    assert!(
        qfleet_suite::wait_until(qfleet_suite::PROCESS_TIMEOUT, || {
            let Ok(text) = std::fs::read_to_string(&checkpoint) else {
                return false;
            };
            let Ok(c) = serde_json::from_str::<Value>(&text) else {
                return false;
            };
            phase0 = c["phases"][0].clone();
            !phase0.is_null()
        }),
        "phase 0 never reached the checkpoint"
    );
    let (run_pid, _) =
        experiment_process(&id, "qfleet-coordinator", "--plan").expect("coordinator");
    std::thread::sleep(std::time::Duration::from_millis(300));
    // SAFETY: kill(2) on the coordinator this test started through qfleet experiment.
    unsafe {
        libc::kill(run_pid, libc::SIGKILL);
    }
    assert!(
        files_like(&seed_dir, "robot-", "-phase-1.json").len() < 3,
        "phase 1 had already ended: make it longer"
    );
    let out = qfleet_suite::wait_bounded(child, qfleet_suite::PROCESS_TIMEOUT);
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("coordinator was killed by signal 9; restarting it"),
        "{}",
        describe(&out)
    );
    let r = both_phases_complete(&out, &id);
    assert_eq!(r.coordinator_restarts, 1);
    // phase 0 was not run again: its result is the one checkpointed before the kill
    assert_eq!(
        serde_json::to_value(&r.phases[0]).unwrap(),
        phase0,
        "phase 0 changed after the restart"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
