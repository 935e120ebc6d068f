//! Skips that show: a test that cannot run here says so on a line `.ci/run` counts, through one
//! helper. `qfleet_suite::skip` is that helper; crates with tests of their own (which cannot
//! depend on this package) carry a copy of it, and this test keeps every copy word for word the
//! same and finds any other way of saying "skipped" (an `eprintln!`, which the test harness
//! captures, or another format, which `.ci/run` would not count).

use qfleet_suite::workspace_files;

/// The helper's body, the same in every copy.
const BODY: &str = "fn skip(test: &str, reason: &str) {
    use std::io::Write;
    let line = format!(\"SKIPPED: {test}: {reason}\\n\");
    let _ = std::io::stderr().lock().write_all(line.as_bytes());
}";

/// What `.ci/run` counts: a line that starts with `SKIPPED` and a space or a colon.
fn counted_by_ci(line: &str) -> bool {
    line.starts_with("SKIPPED ") || line.starts_with("SKIPPED:")
}

#[test]
fn every_skip_goes_through_one_helper_whose_copies_are_identical() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let marker = concat!("\"", "SKIP");
    let mut copies = Vec::new();
    let mut stray = Vec::new();
    for file in workspace_files(".rs") {
        if file.ends_with("tests/skips.rs") {
            continue;
        }
        let text = std::fs::read_to_string(root.join(&file)).unwrap();
        if !text.contains(marker) {
            continue;
        }
        // the body, dedented, must be one of the copies; no other "SKIP… literal
        let dedented: String = text
            .lines()
            .map(|l| l.trim_start())
            .collect::<Vec<_>>()
            .join("\n");
        let body: String = BODY
            .lines()
            .map(|l| l.trim_start())
            .collect::<Vec<_>>()
            .join("\n");
        let defines = dedented.contains(&body);
        for (n, line) in text.lines().enumerate() {
            if line.contains(marker)
                && !(defines
                    && line.trim() == "let line = format!(\"SKIPPED: {test}: {reason}\\n\");")
            {
                stray.push(format!("{}:{}: {}", file.display(), n + 1, line.trim()));
            }
        }
        if defines {
            copies.push(file.display().to_string());
        }
    }
    assert!(
        stray.is_empty(),
        "say a skip with `skip(test, reason)` (qfleet_suite::skip or its copy), not:\n{}",
        stray.join("\n")
    );
    // tests/support/lib.rs and the copies in bus, report, fleetbench, qfleet-args, planner (2),
    // mapf: a new copy is fine, a lost one means a skip went another way
    assert!(
        copies.iter().any(|c| c == "tests/support/lib.rs") && copies.len() >= 8,
        "the helper and its copies: {copies:#?}"
    );
}

/// `.ci/run`'s closing line, from its own awk program run over a log like `cargo test`'s.
#[test]
fn ci_counts_a_skipped_test_as_skipped_not_passed() {
    let ci = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/.ci/run")).unwrap();
    let program = ci
        .split("\nawk '")
        .nth(1)
        .and_then(|rest| rest.split("' \"$log\"").next())
        .expect("the closing awk program in .ci/run");
    let skipped = |test: &str| format!("SKIPPED: {test}: tmux is not installed\n");
    let log = [
        "running 3 tests\n".to_string(),
        skipped("tui::one"),
        skipped("tui::one"), // the same line twice is one skip
        skipped("multihost::two"),
        "test result: ok. 3 passed; 0 failed; 0 ignored; 0 measured; 0 filtered out\n".into(),
        "test result: FAILED. 4 passed; 1 failed; 0 ignored; 0 measured; 0 filtered out\n".into(),
        "   Doc-tests x\ntest result: ok. 0 passed; 0 failed; 0 ignored\n".into(),
    ]
    .concat();
    let dir = qfleet_suite::scratch("skips-ci");
    let path = dir.join("log");
    std::fs::write(&path, log).unwrap();
    let out = std::process::Command::new("awk")
        .arg(program)
        .arg(&path)
        .output()
        .expect("awk");
    assert_eq!(
        String::from_utf8_lossy(&out.stdout),
        "5 passed, 1 failed, 2 skipped\n",
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn the_helpers_line_is_one_ci_counts() {
    let line = format!("SKIPPED: {}: {}\n", "tui::a_test", "tmux is not installed");
    assert!(counted_by_ci(&line));
    assert_eq!(line.lines().count(), 1);
    // the format string in BODY is the one formatted here
    assert!(BODY.contains("\"SKIPPED: {test}: {reason}\\n\""));
}
