//! The harness end to end in a tiny mode: every row runs as real child processes (this test
//! binary re-executes itself with `--role …`, like `qfleet bench` does), a few hundred samples
//! each, plus one small scale point. Asserts shapes, never wall-clock numbers.

use std::process::ExitCode;

use fleetbench::{Launcher, Options, ROW_LABELS};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == "--role") {
        // child process of the harness
        let Some(spec) = args.get(i + 1) else {
            eprintln!("--role needs a value");
            return ExitCode::FAILURE;
        };
        return match fleetbench::role_main(spec) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("child: {e}");
                ExitCode::FAILURE
            }
        };
    }
    if args.iter().any(|a| a == "--list") {
        println!("tiny_run_produces_every_row_and_leaves_nothing: test");
        return ExitCode::SUCCESS;
    }
    tiny_run_produces_every_row_and_leaves_nothing();
    println!("test tiny_run_produces_every_row_and_leaves_nothing ... ok");
    ExitCode::SUCCESS
}

/// Builds the workspace's binaries: the coordinator rows start the real `qfleet-coordinator`,
/// which `cargo test` does not build by itself. The same selection as the end-to-end tests'
/// (`tests/support`: every member, test targets and binaries), so cargo reuses what the test
/// build made instead of resolving other features.
fn build_the_binaries() {
    let exe = std::env::current_exe().expect("test binary path");
    let profile_dir = exe
        .parent()
        .and_then(std::path::Path::parent)
        .expect("target/<profile>/deps/<test>");
    let target_dir = profile_dir.parent().expect("target dir");
    let profile = profile_dir
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("debug");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = std::process::Command::new(cargo);
    cmd.current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
        .args(["build", "--workspace", "--bins", "--tests"])
        .env("CARGO_TARGET_DIR", target_dir);
    if profile != "debug" {
        cmd.args(["--profile", profile]);
    }
    let status = cmd.status().expect("running cargo build");
    assert!(status.success(), "building the qfleet binaries failed");
}

fn tiny_run_produces_every_row_and_leaves_nothing() {
    build_the_binaries();
    let launcher = Launcher {
        program: std::env::current_exe().expect("test binary path"),
        args: Vec::new(),
    };
    let opts = Options {
        samples: 300,
        warmup: 50,
        idle_ms: 50,
        min_window_ms: 0,
        scale: true,
        scale_robots: vec![2],
        scale_batches: Vec::new(),
        scale_main_batch: 16,
        scale_ms: 200,
        progress: false,
        ..Options::quick()
    };
    let before = bus::find_run_prefixes();
    let report = fleetbench::run(&opts, &launcher).expect("the tiny benchmark runs");

    let labels: Vec<&str> = report.rows.iter().map(|r| r.label.as_str()).collect();
    assert_eq!(labels, ROW_LABELS);
    for r in &report.rows {
        assert!(r.count >= 300, "{}: {} samples", r.label, r.count);
        assert!(
            r.min_ns <= r.p50_ns
                && r.p50_ns <= r.p90_ns
                && r.p90_ns <= r.p99_ns
                && r.p99_ns <= r.p999_ns
                && r.p999_ns <= r.max_ns,
            "{}: percentiles out of order: {r:?}",
            r.label
        );
        assert!(r.max_ns > 0 && r.msgs_per_s > 0.0, "{}", r.label);
        assert!(!r.processes.is_empty(), "{}: no CPU figure", r.label);
    }
    let scale = &report.scale;
    assert_eq!(scale.len(), 1);
    assert!(
        scale[0].completed,
        "scale point failed: {:?}",
        scale[0].error
    );
    assert!(scale[0].merged_per_s > 0.0 && scale[0].offered_per_s > 0.0);

    // --json: exactly the fields
    let json = report.to_json();
    let row = &json["rows"][0];
    let mut keys: Vec<&str> = row
        .as_object()
        .expect("row object")
        .keys()
        .map(String::as_str)
        .collect();
    keys.sort_unstable();
    assert_eq!(
        keys,
        [
            "count",
            "cpu_pct",
            "label",
            "max_ns",
            "msgs_per_s",
            "p50_ns",
            "p90_ns",
            "p999_ns",
            "p99_ns"
        ]
    );
    for k in ["cpu_model", "cores", "kernel", "rustc"] {
        assert!(json["machine"].get(k).is_some(), "machine.{k} missing");
    }

    // --out: CSV in dora's layout, one .hgrm per row, plots
    let dir = std::env::temp_dir().join(format!("fleetbench-tiny-{}", std::process::id()));
    report.write_dir(&dir).expect("writes the output directory");
    let csv = std::fs::read_to_string(dir.join("latency.csv")).expect("latency.csv");
    assert_eq!(csv.lines().count(), ROW_LABELS.len());
    for line in csv.lines() {
        let cols: Vec<&str> = line.split(',').collect();
        assert_eq!(cols.len(), 11, "{line}");
        assert_eq!(cols[0], "latency");
    }
    for label in ROW_LABELS {
        let hgrm = std::fs::read_to_string(dir.join(format!("{label}.hgrm"))).expect("hgrm");
        assert!(
            hgrm.contains("Percentile") && hgrm.contains("#[Max"),
            "{label}"
        );
    }
    for f in [
        "latency.svg",
        "scale.svg",
        "scale.csv",
        "report.json",
        "summary.md",
    ] {
        assert!(dir.join(f).is_file(), "{f} missing");
    }
    let _ = std::fs::remove_dir_all(&dir);

    // nothing of ours left in /dev/shm or /tmp/iceoryx2 (each row also checks its own prefix)
    let ours = format!("-{}-", std::process::id());
    let left: Vec<String> = bus::find_run_prefixes()
        .into_iter()
        .filter(|p| !before.contains(p) && p.contains(&ours))
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
}
