//! Helpers shared by the bus integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use bus::bus_schema::{Register, SCHEMA_VERSION};
use bus::{BusConfig, Expected, Inbox, Message, leftover_files, unique_run_id};

/// Generous bound for anything that should take milliseconds (CI machines are slow and shared).
pub const PATIENCE: Duration = Duration::from_secs(20);

/// A fresh configuration with a run id no other test (or test process) uses.
pub fn config(tag: &str, robots: u32) -> BusConfig {
    BusConfig::new(unique_run_id(tag), robots).expect("valid test config")
}

/// What the test coordinators expect: a 12x9 map with hash 0xC0FFEE.
pub fn expected(robots: u32) -> Expected {
    Expected {
        robots,
        map_hash: 0xC0FFEE,
        width: 12,
        height: 9,
    }
}

/// A registration that matches [`expected`].
pub fn registration(robot_id: u32) -> Register {
    Register {
        schema_version: SCHEMA_VERSION,
        robot_id,
        pid: std::process::id(),
        episodes: 100,
        width: 12,
        height: 9,
        start_x: 1,
        start_y: 2,
        map_hash: 0xC0FFEE,
        seed: 7 + u64::from(robot_id),
        ..Register::ZEROED
    }
}

/// Receives one message, waiting on the inbox's wake listener, or panics after [`PATIENCE`].
pub fn recv<T: Message>(inbox: &Inbox<T>) -> T {
    let deadline = Instant::now() + PATIENCE;
    loop {
        if let Some(m) = inbox.receive().expect("receive") {
            return m;
        }
        assert!(
            Instant::now() < deadline,
            "nothing arrived on {}",
            inbox.service()
        );
        inbox.wait(Duration::from_millis(10)).expect("wait");
    }
}

fn files_containing(dir: &Path, needle: &str, found: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        if e.file_name().to_string_lossy().contains(needle) {
            found.push(e.path());
        }
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            files_containing(&e.path(), needle, found);
        }
    }
}

/// Asserts that no file of the run is left in /dev/shm or /tmp/iceoryx2.
pub fn assert_no_leftovers(cfg: &BusConfig) {
    assert_eq!(leftover_files(&cfg.prefix()), Vec::<PathBuf>::new());
    let mut found = Vec::new();
    files_containing(Path::new("/dev/shm"), &cfg.run_id, &mut found);
    files_containing(&bus::iceoryx_root(), &cfg.run_id, &mut found);
    assert!(
        found.is_empty(),
        "files of run {} left behind: {found:#?}",
        cfg.run_id
    );
}
