//! End-to-end: a run recorded with `--record` reads back (through `qfleet replay --json`, which
//! uses the `mcap` crate) with one channel per topic and message counts equal to the run's own
//! counters, and leaves nothing of the run in shared memory.

use std::process::Command;

use qfleet_suite::bin_dir;

#[test]
fn a_recorded_run_reads_back_with_the_runs_own_counts() {
    let dir = std::env::temp_dir().join(format!("qfleet-observe-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("run.mcap");
    let run_id = format!("obs-{}", std::process::id());
    let out = Command::new(bin_dir().join("qfleet"))
        .args([
            "run",
            "--robots",
            "2",
            "--map",
            "builtin:paper-10",
            "--json",
            "--run-id",
            &run_id,
        ])
        .arg("--record")
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let result: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let replay = Command::new(bin_dir().join("qfleet"))
        .args(["replay", "--json"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        replay.status.success(),
        "{}",
        String::from_utf8_lossy(&replay.stderr)
    );
    let s: serde_json::Value = serde_json::from_slice(&replay.stdout).unwrap();
    let topics = s["topics"].as_array().unwrap();
    assert_eq!(topics.len(), 9, "one channel per topic");
    let count = |path: &str| {
        topics
            .iter()
            .find(|t| t["topic"].as_str().unwrap().ends_with(path))
            .unwrap()["count"]
            .as_u64()
            .unwrap()
    };
    assert_eq!(
        count("/robot/discovery"),
        result["discoveries_sent"].as_u64().unwrap()
    );
    assert_eq!(count("/robot/report"), 2, "one report per robot");
    assert_eq!(s["metadata"]["run_id"], run_id.as_str());
    assert_eq!(s["map"], "paper-10");
    let left: Vec<_> = std::fs::read_dir("/dev/shm")
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(&run_id))
        .collect();
    assert!(
        left.is_empty(),
        "files of the run left in /dev/shm: {left:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
