//! End-to-end: real `qfleet run`, `qfleet-coordinator` and `robot-agent` processes talking over
//! iceoryx2 shared memory. Every test uses its own run id and is bounded in time; none asserts a
//! wall-clock figure.

use std::process::Command;

use qfleet_suite::{
    PROCESS_TIMEOUT, bin, describe, leftovers, run_bounded, run_id, scratch, spawn, wait_bounded,
};
use serde_json::Value;

fn qfleet_run(id: &str, extra: &[&str]) -> (Value, std::process::Output) {
    let out = run_bounded(
        Command::new(bin("qfleet"))
            .args(["run", "--json", "--run-id", id])
            .args(extra),
    );
    assert!(
        out.status.success(),
        "qfleet run failed: {}",
        describe(&out)
    );
    let v: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {}", describe(&out)));
    (v, out)
}

fn u(v: &Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("{key} missing in {v}"))
}

#[test]
fn four_robots_sharing_on_paper_20_all_end_optimal() {
    let id = run_id("fleet4");
    // the improved learner: its pseudo-target discoveries exercise the discovery path too
    let (r, _) = qfleet_run(
        &id,
        &[
            "--robots",
            "4",
            "--map",
            "builtin:paper-20",
            "--share",
            "hints",
            "--learner",
            "improved",
        ],
    );
    assert_eq!((&r["apply"], &r["merge"]), (&"max".into(), &"max".into()));
    let robots = r["robots"].as_array().expect("robots list");
    assert_eq!(robots.len(), 4);
    for x in robots {
        assert_eq!(x["status"], "finished", "{x}");
        assert!(x["optimal_path_len"].as_u64().is_some(), "{x}");
        assert_eq!(
            x["final_path_len"], x["optimal_path_len"],
            "robot not on the optimal path: {x}"
        );
        assert!(u(x, "episodes") > 0 && x["avg_steps"].as_f64().is_some());
        assert_eq!(x["discoveries_acked"], x["discoveries_sent"], "{x}");
    }
    assert_eq!(r["all_optimal"], true);
    assert!(u(&r, "discoveries_sent") > 0);
    assert_eq!(u(&r, "discoveries_received"), u(&r, "discoveries_sent"));
    for path in [
        "loop",
        "hints_one_way",
        "state_one_way",
        "discovery_one_way",
        "merged_one_way",
    ] {
        let s = &r["latency_ns"][path];
        assert!(u(s, "count") > 0, "histogram {path} is empty: {s}");
        for k in ["p50", "p90", "p99", "p999", "max"] {
            assert!(s[k].as_u64().is_some(), "{path}.{k} missing");
        }
        assert!(u(s, "p50") <= u(s, "p99") && u(s, "p99") <= u(s, "max"));
    }
    assert!(r["throughput"]["messages_per_s"].as_f64().unwrap() > 0.0);
    assert!(r["throughput"]["q_updates_merged_per_s"].as_f64().unwrap() > 0.0);
    assert!(r["liveness"]["lost"].as_array().unwrap().is_empty());
    assert_eq!(
        leftovers(&id),
        Vec::<std::path::PathBuf>::new(),
        "files of the run left behind"
    );
}

/// `qfleet run` with no learner or rule options: the planning learner, the `min/min` rules that
/// fit its upper bounds (named in the result), every robot optimal; its goal-path discoveries
/// (issue 36) are published, acknowledged and received like the improved learner's.
#[test]
fn the_default_run_is_planning_with_min_rules_and_every_robot_ends_optimal() {
    let id = run_id("fleetdef");
    let (r, out) = qfleet_run(&id, &[]);
    assert_eq!((&r["apply"], &r["merge"]), (&"min".into(), &"min".into()));
    assert!(
        !String::from_utf8_lossy(&out.stderr).contains("does not fit"),
        "{}",
        describe(&out)
    );
    let robots = r["robots"].as_array().expect("robots list");
    assert_eq!(robots.len(), 4);
    for x in robots {
        assert_eq!(x["status"], "finished", "{x}");
        assert_eq!(x["final_path_len"], x["optimal_path_len"], "{x}");
        assert!(u(x, "hints_received") > 0, "nothing reached robot: {x}");
    }
    // under `min` a robot applies only values below its own: one that learned ahead of the
    // others may apply none (seen once in a loaded full run), but the fleet shares
    let applied: u64 = robots.iter().map(|x| u(x, "hints_applied")).sum();
    assert!(applied > 0, "nothing shared: {r}");
    assert_eq!(r["all_optimal"], true, "{r}");
    for x in robots {
        assert!(
            u(x, "discoveries_sent") > 0,
            "found a path, published none: {x}"
        );
        assert_eq!(x["discoveries_acked"], x["discoveries_sent"], "{x}");
    }
    assert_eq!(u(&r, "discoveries_received"), u(&r, "discoveries_sent"));
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}

/// A rule that does not fit the learner is run as asked, with a warning on stderr.
#[test]
fn a_rule_against_the_learners_bound_is_warned_about() {
    let id = run_id("fleetwarn");
    let (r, out) = qfleet_run(
        &id,
        &["--robots", "2", "--episodes", "30", "--apply", "max"],
    );
    assert_eq!((&r["apply"], &r["merge"]), (&"max".into(), &"min".into()));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--apply max does not fit this learner"),
        "{err}"
    );
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}

#[test]
fn results_and_histogram_files_land_in_the_out_dir() {
    let id = run_id("files");
    let dir = scratch(&id);
    let (r, _) = qfleet_run(
        &id,
        &[
            "--robots",
            "2",
            "--map",
            "builtin:paper-10",
            "--episodes",
            "300",
            "--wait",
            "event",
            "--out",
            dir.to_str().unwrap(),
        ],
    );
    assert_eq!(r["wait"], "event");
    for f in [
        "result.json",
        "robot-0.json",
        "robot-1.json",
        "latency-loop.hgrm",
        "latency-hints_one_way.hgrm",
        "coordinator.log",
    ] {
        assert!(dir.join(f).is_file(), "{f} missing in {}", dir.display());
    }
    let hgrm = std::fs::read_to_string(dir.join("latency-loop.hgrm")).unwrap();
    assert!(hgrm.contains("Percentile") && hgrm.contains("Total count"));
    assert!(leftovers(&id).is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn robot_of_another_schema_version_is_refused_on_both_sides() {
    let id = run_id("schema");
    let dir = scratch(&id);
    let coord = spawn(
        Command::new(bin("qfleet-coordinator"))
            .args(["--run-id", &id, "--robots", "1", "--timeout", "20", "--out"])
            .arg(&dir),
    );
    let robot = spawn(
        Command::new(bin("robot-agent"))
            .args([
                "--run-id",
                &id,
                "--robot-id",
                "0",
                "--robots",
                "1",
                "--timeout",
                "20",
            ])
            .args(["--schema-version-override", "99"]),
    );
    let r = wait_bounded(robot, PROCESS_TIMEOUT);
    let c = wait_bounded(coord, PROCESS_TIMEOUT);
    let r_err = String::from_utf8_lossy(&r.stderr);
    let c_err = String::from_utf8_lossy(&c.stderr);
    assert!(!r.status.success(), "robot must fail: {}", describe(&r));
    assert!(
        !c.status.success(),
        "coordinator must fail: {}",
        describe(&c)
    );
    assert!(
        r_err.contains("refused") && r_err.contains("schema v99"),
        "robot's message: {r_err}"
    );
    assert!(
        c_err.contains("refused robot 0") && c_err.contains("schema v99"),
        "coordinator's message: {c_err}"
    );
    assert!(!c_err.contains("panicked") && !r_err.contains("panicked"));
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn two_runs_in_parallel_do_not_see_each_other() {
    let (a, b) = (run_id("par-a"), run_id("par-b"));
    let start = |id: &str, robots: &str, map: &str| {
        spawn(
            Command::new(bin("qfleet"))
                .args([
                    "run", "--json", "--run-id", id, "--robots", robots, "--map", map,
                ])
                .args(["--episodes", "300", "--wait", "event"]),
        )
    };
    let pa = start(&a, "2", "builtin:paper-10");
    let pb = start(&b, "3", "builtin:paper-20");
    let (oa, ob) = (
        wait_bounded(pa, PROCESS_TIMEOUT),
        wait_bounded(pb, PROCESS_TIMEOUT),
    );
    assert!(oa.status.success(), "{}", describe(&oa));
    assert!(ob.status.success(), "{}", describe(&ob));
    let ra: Value = serde_json::from_slice(&oa.stdout).unwrap();
    let rb: Value = serde_json::from_slice(&ob.stdout).unwrap();
    assert_eq!(
        (ra["run_id"].as_str(), ra["map"].as_str()),
        (Some(a.as_str()), Some("paper-10"))
    );
    assert_eq!(
        (rb["run_id"].as_str(), rb["map"].as_str()),
        (Some(b.as_str()), Some("paper-20"))
    );
    assert_eq!(ra["robots"].as_array().unwrap().len(), 2);
    assert_eq!(rb["robots"].as_array().unwrap().len(), 3);
    // each coordinator saw exactly its own robots' discoveries, nothing rejected as foreign
    for r in [&ra, &rb] {
        assert_eq!(r["discoveries_received"], r["discoveries_sent"]);
        assert_eq!(r["rejected"], 0);
        assert!(
            r["robots"]
                .as_array()
                .unwrap()
                .iter()
                .all(|x| x["status"] == "finished")
        );
    }
    assert!(leftovers(&a).is_empty() && leftovers(&b).is_empty());
}

#[test]
fn bad_input_is_a_clear_error_not_a_panic() {
    for (args, needle) in [
        (vec!["run", "--map", "/nonexistent/map.txt"], "nonexistent"),
        (vec!["run", "--robots", "0"], "robots"),
        (vec!["run", "--episodes", "0"], "episodes"),
        (vec!["run", "--alpha", "1.5"], "alpha"),
        (vec!["run", "--run-id", "bad/id"], "run id"),
    ] {
        let out = run_bounded(Command::new(bin("qfleet")).args(&args));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} must fail");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    let out = run_bounded(Command::new(bin("robot-agent")).args([
        "--run-id",
        "x",
        "--robot-id",
        "7",
        "--robots",
        "2",
    ]));
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("--robot-id 7 is outside"),
        "{}",
        describe(&out)
    );
}
