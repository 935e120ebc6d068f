//! Bad input to any `qfleet` command is exit code 2 with one `qfleet: error: …` line, never 1
//! (a runtime failure), 0 or a panic (README "Exit codes"). One table over every command that
//! reads a file, a map, a learner option, a run id or a topic name.

use std::process::Command;

use qfleet_suite::{bin, scratch};

#[test]
fn bad_input_to_every_command_is_exit_code_2_with_a_clear_error() {
    let dir = scratch("exitcodes");
    let not_mcap = dir.join("not.mcap");
    std::fs::write(&not_mcap, "this is not an MCAP file\n").unwrap();
    let not_a_map = dir.join("not.map");
    std::fs::write(&not_a_map, "type octile\nheight x\n").unwrap();
    let readme = concat!(env!("CARGO_MANIFEST_DIR"), "/README.md");
    let missing = dir.join("missing.toml");
    // a recording in a directory that does not exist: refused before the run starts
    let no_dir = dir.join("no/such/dir/run.mcap");
    // `qfleet join --out` onto a non-empty directory, refused before anything connects
    let full = dir.join("full");
    std::fs::create_dir_all(&full).unwrap();
    std::fs::write(full.join("keep.txt"), "mine").unwrap();
    let full = full.to_str().unwrap().to_string();
    let (not_mcap, not_a_map, missing, no_dir) = (
        not_mcap.to_str().unwrap(),
        not_a_map.to_str().unwrap(),
        missing.to_str().unwrap(),
        no_dir.to_str().unwrap(),
    );
    let manifest = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/three-goals-six-robots.toml"
    );
    let cases: Vec<Vec<&str>> = vec![
        vec!["learn", "--map", "/dev/null"],
        vec!["learn", "--map", readme],
        vec!["learn", "--map", not_a_map],
        vec!["learn", "--map", "builtin:nope"],
        vec!["learn", "--gamma", "1.5"],
        vec!["learn", "--alpha", "nan"],
        vec!["learn", "--optimistic", "1e39"],
        vec!["eval", "--configs", "nope", "--sizes", "10"],
        vec!["eval", "--sizes", "0", "--seeds", "1"],
        vec!["replay", not_mcap],
        vec!["replay", missing],
        vec!["replay", "--speed", "0", not_mcap],
        vec!["topic", "echo", "--run-id", "../x"],
        vec!["topic", "hz", "--run-id", "x", "robot/nope"],
        vec!["topic", "list", "--run-id", "x y"],
        vec!["sweep", missing],
        vec!["run", "--map", "/dev/null"],
        vec!["run", "--gamma", "2"],
        vec![
            "run",
            "--robots",
            "1",
            "--episodes",
            "1",
            "--record",
            no_dir,
        ],
        vec!["experiment", manifest, "--record", no_dir],
        vec!["experiment", missing],
        vec!["clean", "--run-id", "../x"],
        // with a valid secret in the environment (below): the non-empty --out is refused
        vec!["join", "tcp/127.0.0.1:9", "--out", &full],
        vec!["join", "tcp/127.0.0.1:9", "--secret-file", missing],
        vec!["eval", "--families", "movingai", "--movingai", "/dev/zero"],
    ];
    let mut wrong = Vec::new();
    for args in &cases {
        let out = Command::new(bin("qfleet"))
            .args(args)
            .env(
                "QFLEET_JOIN_SECRET",
                format!("qfleet-join-v1:exit-codes:{}", "ab".repeat(32)),
            )
            .current_dir(&*dir)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        let clear = stderr.contains("error") && !stderr.contains("panicked");
        if out.status.code() != Some(2) || !clear {
            wrong.push(format!(
                "qfleet {}: exit {:?}: {}",
                args.join(" "),
                out.status.code(),
                stderr.trim()
            ));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

/// Issue 27: 32 robots on `suite:maze-2048-1` need ~4.5 GB; a run whose estimated memory
/// (`bus::limits::memory_estimate`) exceeds what is available is refused with exit 2 and what
/// to do, before any process starts. 256 robots on that map are estimated at ~38 GB; on a
/// machine with that much available the test says SKIPPED.
#[test]
fn a_fleet_that_does_not_fit_in_memory_is_refused_before_it_starts() {
    let cells = 2048 * 2048;
    let need = bus::limits::memory_estimate(cells, 257);
    if bus::limits::mem_available().is_none_or(|have| have >= need) {
        qfleet_suite::skip(
            "a_fleet_that_does_not_fit_in_memory_is_refused_before_it_starts",
            "this machine has the memory for 256 robots on a 2048 x 2048 map",
        );
        return;
    }
    let id = qfleet_suite::run_id("no-mem");
    let out = qfleet_suite::run_bounded(
        std::process::Command::new(qfleet_suite::bin("qfleet"))
            .args(["run", "--robots", "256", "--map", "suite:maze-2048-1"])
            .args(["--episodes", "1", "--run-id", &id]),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(2),
        "{}",
        qfleet_suite::describe(&out)
    );
    assert!(
        err.contains("not enough memory: 256 robot(s) and the coordinator")
            && err.contains("--ignore-memory"),
        "{err}"
    );
    assert!(qfleet_suite::leftovers(&id).is_empty());
}

/// The same preflight for `qfleet experiment` (issue 27): a manifest whose repetition does not
/// fit in memory is refused before any process starts, with what to do.
#[test]
fn an_experiment_that_does_not_fit_in_memory_is_refused_before_it_starts() {
    const NAME: &str = "an_experiment_that_does_not_fit_in_memory_is_refused_before_it_starts";
    let cells = 2048 * 2048;
    let need = bus::limits::memory_estimate(cells, 257);
    if bus::limits::mem_available().is_none_or(|have| have >= need) {
        qfleet_suite::skip(
            NAME,
            "this machine has the memory for 256 robots on a 2048 x 2048 map",
        );
        return;
    }
    let task = planner::suite::from_spec("maze-2048-1")
        .expect("a suite map")
        .task;
    let (s, g) = (task.start, task.goal);
    let dir = qfleet_suite::scratch("exp-no-mem");
    let manifest = dir.join("big.toml");
    std::fs::write(
        &manifest,
        format!(
            "name = \"too big\"\nepisodes = 1\nseeds = [1]\n[map]\nsource = \"suite:maze-2048-1\"\n\
             [[goals]]\nname = \"g\"\ncell = [{}, {}]\n[robots]\ncount = 256\nstart = [{}, {}]\n",
            g.x, g.y, s.x, s.y
        ),
    )
    .expect("write the manifest");
    let out = qfleet_suite::run_bounded(
        std::process::Command::new(qfleet_suite::bin("qfleet"))
            .arg("experiment")
            .arg(&manifest)
            .arg("--out")
            .arg(dir.join("out")),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(2),
        "{}",
        qfleet_suite::describe(&out)
    );
    assert!(
        err.contains("not enough memory: 256 robot(s) and the coordinator")
            && err.contains("--ignore-memory"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
