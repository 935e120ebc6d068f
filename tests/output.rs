//! What a person reads after `qfleet experiment` and `qfleet sweep` is tables and plain words:
//! no Rust `Debug` values (`Some(58)`, `[58, 57]`, `None`), no `- s` / `- steps` placeholders,
//! and no library noise such as iceoryx2's `No config file was loaded` (issue 13, last item).

use std::process::Command;

use qfleet_suite::{bin, describe, run_bounded, scratch};

/// Every line of `text` that a person should not have to read.
fn noise(text: &str) -> Vec<&str> {
    const BAD: [&str; 8] = [
        "Some(",
        "None",
        "[",
        "- s ",
        "- steps",
        "No config file",
        "iceoryx2",
        "ERROR",
    ];
    text.lines()
        .filter(|l| BAD.iter().any(|b| l.contains(b)))
        .collect()
}

#[test]
fn experiment_and_sweep_print_tables_without_debug_values_or_library_noise() {
    let manifest = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/three-goals-six-robots.toml"
    );
    let exp = run_bounded(
        Command::new(bin("qfleet"))
            .args(["experiment", manifest, "--seed", "1"])
            .env_remove("RUST_LOG"),
    );
    assert!(exp.status.success(), "{}", describe(&exp));
    let out = String::from_utf8_lossy(&exp.stdout);
    let err = String::from_utf8_lossy(&exp.stderr);
    assert!(
        out.contains("merged path / optimum") && out.contains("phase 2"),
        "no per-phase table: {}",
        describe(&exp)
    );
    assert!(noise(&out).is_empty(), "{:?}", noise(&out));
    assert!(noise(&err).is_empty(), "{:?}", noise(&err));

    let dir = scratch("output-sweep");
    let sweep = run_bounded(
        Command::new(bin("qfleet"))
            .args(["sweep", manifest, "--robots", "1,2", "--seeds", "1"])
            .arg("--out")
            .arg(&dir)
            .arg("--svg")
            .arg(dir.join("s.svg"))
            .env_remove("RUST_LOG"),
    );
    assert!(sweep.status.success(), "{}", describe(&sweep));
    let out = String::from_utf8_lossy(&sweep.stdout);
    let err = String::from_utf8_lossy(&sweep.stderr);
    assert!(
        out.contains("| map | N |"),
        "no table: {}",
        describe(&sweep)
    );
    assert!(noise(&out).is_empty(), "{:?}", noise(&out));
    assert!(noise(&err).is_empty(), "{:?}", noise(&err));
    let _ = std::fs::remove_dir_all(&dir);
}
