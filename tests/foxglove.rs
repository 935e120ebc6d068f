//! End-to-end: a run seen from Foxglove's side by a client that shares no code with qfleet
//! (`tests/foxglove_check.py`, Python's `websockets` and `mcap` packages): live over
//! `--foxglove` (serverInfo, the advertised schema names, the map as a grid of the map file's
//! size and cells, every robot on a free cell) and in a `--record` file (the well-known schema
//! channels, every message decodes, the grid's cells match the map file).
//!
//! Needs python3 with `websockets` and `mcap` (`.ci/run` installs them into a venv and points
//! `QFLEET_PYTHON` at it); without them each test says `SKIPPED …` and passes.

use std::path::{Path, PathBuf};
use std::process::Command;

use qfleet_suite::{
    bin, describe, leftovers, run_bounded, run_id, scratch, skip, spawn, wait_bounded,
};

/// The Python to run the checker with (`QFLEET_PYTHON`, else `python3`), if it has `modules`.
fn python_with(test: &str, modules: &[&str]) -> Option<PathBuf> {
    let py =
        std::env::var_os("QFLEET_PYTHON").map_or_else(|| PathBuf::from("python3"), PathBuf::from);
    let import = format!("import {}", modules.join(", "));
    match Command::new(&py).args(["-c", &import]).output() {
        Err(e) => {
            skip(test, &format!("{} cannot be run ({e})", py.display()));
            None
        }
        Ok(o) if !o.status.success() => {
            skip(
                test,
                &format!(
                    "{} lacks {} (python3 -m pip install websockets mcap, or set QFLEET_PYTHON)",
                    py.display(),
                    modules.join(", ")
                ),
            );
            None
        }
        Ok(_) => Some(py),
    }
}

fn checker() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/foxglove_check.py")
}

/// A TCP port on loopback that was free a moment ago.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

#[test]
fn a_foxglove_client_sees_the_map_and_every_robot_on_a_free_cell() {
    let test = "a_foxglove_client_sees_the_map_and_every_robot_on_a_free_cell";
    let Some(py) = python_with(test, &["websockets"]) else {
        return;
    };
    let id = run_id("fox");
    let dir = scratch(&id);
    let map = dir.join("paper-10.txt");
    std::fs::write(&map, planner::map::PAPER_10).unwrap();
    let port = free_port().to_string();
    // paced so that the run lasts a few seconds while the client looks
    let run = spawn(Command::new(bin("qfleet")).args([
        "run",
        "--robots",
        "2",
        "--map",
        "builtin:paper-10",
        "--episodes",
        "300",
        "--pace",
        "3000",
        "--json",
        "--run-id",
        &id,
        "--foxglove",
        &format!("127.0.0.1:{port}"),
    ]));
    let client = run_bounded(
        Command::new(&py)
            .arg(checker())
            .args([
                "live",
                "--port",
                &port,
                "--robots",
                "2",
                "--timeout",
                "60",
                "--map",
            ])
            .arg(&map),
    );
    let run = wait_bounded(run, qfleet_suite::PROCESS_TIMEOUT);
    assert!(client.status.success(), "{}", describe(&client));
    assert!(run.status.success(), "{}", describe(&run));
    let seen: serde_json::Value = serde_json::from_slice(&client.stdout).unwrap();
    assert_eq!(seen["grid"]["width"], 10, "{seen}");
    assert_eq!(seen["grid"]["height"], 10, "{seen}");
    for r in ["0", "1"] {
        assert!(seen["robot_updates"][r].as_u64() >= Some(3), "{seen}");
    }
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        stderr.contains("foxglove: serving on ws://127.0.0.1:"),
        "{stderr}"
    );
    assert!(stderr.contains("foxglove: 1 client(s)"), "{stderr}");
    // the run's result is that of an unobserved run: every robot finished
    let result: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    for r in result["robots"].as_array().unwrap() {
        assert_eq!(r["status"], "finished", "{result}");
    }
    let left = leftovers(&id);
    assert!(left.is_empty(), "files of the run left: {left:?}");
}

#[test]
fn a_recording_carries_foxglove_schemas_that_python_mcap_decodes() {
    let test = "a_recording_carries_foxglove_schemas_that_python_mcap_decodes";
    let Some(py) = python_with(test, &["mcap"]) else {
        return;
    };
    let id = run_id("foxrec");
    let dir = scratch(&id);
    let map = dir.join("paper-10.txt");
    std::fs::write(&map, planner::map::PAPER_10).unwrap();
    let file = dir.join("run.mcap");
    let run = run_bounded(
        Command::new(bin("qfleet"))
            .args([
                "run",
                "--robots",
                "2",
                "--map",
                "builtin:paper-10",
                "--json",
                "--run-id",
                &id,
                "--record",
            ])
            .arg(&file),
    );
    assert!(run.status.success(), "{}", describe(&run));
    let check = run_bounded(
        Command::new(&py)
            .arg(checker())
            .args(["mcap", "--robots", "2", "--file"])
            .arg(&file)
            .arg("--map")
            .arg(&map),
    );
    assert!(check.status.success(), "{}", describe(&check));
    let seen: serde_json::Value = serde_json::from_slice(&check.stdout).unwrap();
    assert_eq!(seen["grid"]["width"], 10, "{seen}");
    assert_eq!(seen["counts"]["/map"], 1, "{seen}");
    assert!(seen["counts"]["/robot_stats"].as_u64() > Some(0), "{seen}");
}

/// `--foxglove` on a port that is taken, or an address that is not ADDR:PORT: exit 2, a
/// message that says which, and no run started (no result, nothing in shared memory).
#[test]
fn a_foxglove_port_in_use_or_a_bad_address_is_bad_input() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    for (arg, says) in [
        (addr.as_str(), "cannot listen on"),
        ("not-an-address", "ADDR:PORT"),
    ] {
        let id = run_id("foxbad");
        let out = run_bounded(Command::new(bin("qfleet")).args([
            "run",
            "--robots",
            "1",
            "--map",
            "builtin:paper-10",
            "--run-id",
            &id,
            "--foxglove",
            arg,
        ]));
        assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(says), "{stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
        assert!(leftovers(&id).is_empty());
    }
}

/// `qfleet replay FILE --foxglove ADDR:PORT`: the recording of a paced run, served at its
/// pace (sped up) once the client connects, shows the same map and both robots on free cells.
#[test]
fn a_recording_replays_to_a_foxglove_client() {
    let test = "a_recording_replays_to_a_foxglove_client";
    let Some(py) = python_with(test, &["websockets"]) else {
        return;
    };
    let id = run_id("foxrep");
    let dir = scratch(&id);
    let map = dir.join("paper-10.txt");
    std::fs::write(&map, planner::map::PAPER_10).unwrap();
    let file = dir.join("run.mcap");
    let run = run_bounded(
        Command::new(bin("qfleet"))
            .args([
                "run",
                "--robots",
                "2",
                "--map",
                "builtin:paper-10",
                "--episodes",
                "100",
                "--pace",
                "3000",
                "--json",
                "--run-id",
                &id,
                "--record",
            ])
            .arg(&file),
    );
    assert!(run.status.success(), "{}", describe(&run));
    let port = free_port().to_string();
    let replay = spawn(Command::new(bin("qfleet")).arg("replay").arg(&file).args([
        "--speed",
        "2",
        "--foxglove",
        &format!("127.0.0.1:{port}"),
    ]));
    let client = run_bounded(
        Command::new(&py)
            .arg(checker())
            .args([
                "live",
                "--port",
                &port,
                "--robots",
                "2",
                "--timeout",
                "60",
                "--map",
            ])
            .arg(&map),
    );
    let replay = wait_bounded(replay, qfleet_suite::PROCESS_TIMEOUT);
    assert!(client.status.success(), "{}", describe(&client));
    assert!(replay.status.success(), "{}", describe(&replay));
    let seen: serde_json::Value = serde_json::from_slice(&client.stdout).unwrap();
    assert_eq!(seen["grid"]["width"], 10, "{seen}");
    assert!(seen["robot_updates"]["1"].as_u64() >= Some(1), "{seen}");
}
