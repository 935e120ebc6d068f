//! Issue 10 item 11: the documented maximum fleet, 256 robots, completes on the 2-core machine.
//!
//! A test binary of its own: cargo runs test binaries one after another, so the minute of load
//! this run puts on two cores never overlaps the timing-sensitive stop tests of other files.

use std::process::Command;
use std::time::{Duration, Instant};

use qfleet_suite::{bin, describe, leftovers, run_id, scratch, skip, spawn, wait_bounded};
use serde_json::Value;

#[test]
fn two_hundred_fifty_six_robots_the_documented_maximum_complete() {
    // the coordinator of 256 robots holds ~4200 files open (bus::limits); past the hard limit
    // `qfleet run` refuses the fleet with exit 2 (tests/exit_codes.rs), so here it is a skip
    let need = bus::limits::coordinator_files(256);
    match bus::limits::raise_open_files() {
        Some(l) if l.soft < need => {
            skip(
                "two_hundred_fifty_six_robots_the_documented_maximum_complete",
                &format!(
                    "needs {need} open files, this system allows {} (`ulimit -Hn`)",
                    l.hard
                ),
            );
            return;
        }
        _ => {}
    }
    let id = run_id("r256");
    let dir = scratch(&id);
    let t0 = Instant::now();
    let out = wait_bounded(
        spawn(
            Command::new(bin("qfleet"))
                .args(["run", "--json", "--run-id", &id, "--out"])
                .arg(&dir)
                .args(["--map", "builtin:paper-10", "--episodes", "20"])
                .args(["--robots", "256"]),
        ),
        Duration::from_secs(600),
    );
    eprintln!("256 robots: {:.1} s", t0.elapsed().as_secs_f64());
    assert!(out.status.success(), "{}", describe(&out));
    let r: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("no JSON result ({e}): {}", describe(&out)));
    let robots = r["robots"].as_array().expect("robots");
    assert_eq!(robots.len(), 256, "{r}");
    for x in robots {
        assert_eq!(x["status"], "finished", "{x}");
    }
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !err.contains("No config file was loaded") && !err.contains("[W]") && !err.contains("[E]"),
        "library noise on stderr:\n{err}"
    );
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}
