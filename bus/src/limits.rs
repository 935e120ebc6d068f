//! Open-file limits: how many file descriptors a run's coordinator needs, and raising the
//! process's soft limit to its hard one so that a large fleet does not fail half-way.
//!
//! iceoryx2 keeps a file descriptor open for every shared-memory connection between a publisher
//! and a subscriber, every data segment it maps and every wake socket, so the coordinator of N
//! robots holds about 19 per robot (measured with `ls /proc/PID/fd` on runs of `qfleet run`:
//! 1189 at 64 robots, 4175 at 256). Linux's usual soft limit is 1024: without raising it, robots
//! past the ~50th never got through registration (the coordinator could not open their
//! connections and said nothing about why) and, near the limit, a node listing that cannot open
//! a robot's files made a live robot look dead. Raising the soft limit to the hard one is what
//! any process may do; past the hard limit only the administrator can help, so a fleet that does
//! not fit is refused before anything starts ([`check_open_files`], part of
//! [`crate::preflight`]).

use crate::BusError;

/// File descriptors the coordinator holds besides its robots' (its own services, node files,
/// logs, the node lister): a margin over the ~60 measured.
pub const COORDINATOR_FILES_BASE: u64 = 128;

/// File descriptors the coordinator holds per robot of the run (measured 16–19 with eleven
/// topics, see the module doc; `robot/horizon` adds one more connection and data segment per
/// robot), with a margin.
pub const COORDINATOR_FILES_PER_ROBOT: u64 = 24;

/// Open files the coordinator of a run of `robots` robots needs.
pub fn coordinator_files(robots: u32) -> u64 {
    COORDINATOR_FILES_BASE + COORDINATOR_FILES_PER_ROBOT * u64::from(robots)
}

/// A process's open-file limits (`RLIMIT_NOFILE`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OpenFiles {
    /// What the process may open now.
    pub soft: u64,
    /// What the soft limit may be raised to without privileges.
    pub hard: u64,
}

/// This process's open-file limits, or `None` if they cannot be read.
pub fn open_files() -> Option<OpenFiles> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes into the struct we own
    if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) } != 0 {
        return None;
    }
    Some(OpenFiles {
        soft: lim.rlim_cur,
        hard: lim.rlim_max,
    })
}

/// Raises this process's soft open-file limit to its hard limit (inherited by the processes
/// it starts), best effort; returns the limits in force afterwards.
pub fn raise_open_files() -> Option<OpenFiles> {
    let now = open_files()?;
    // an unlimited hard limit still stops at the kernel's per-process ceiling
    let target = if now.hard == libc::RLIM_INFINITY {
        std::fs::read_to_string("/proc/sys/fs/nr_open")
            .ok()
            .and_then(|s| s.trim().parse().ok())
            .unwrap_or(1 << 20)
    } else {
        now.hard
    };
    if now.soft < target {
        let lim = libc::rlimit {
            rlim_cur: target,
            rlim_max: now.hard,
        };
        // SAFETY: setrlimit reads the struct we own; raising the soft limit up to the hard
        // one needs no privilege
        unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &lim) };
    }
    open_files()
}

/// Raises the soft open-file limit and checks that the coordinator of `robots` robots fits
/// under it; [`BusError::OpenFiles`] otherwise. Limits that cannot be read pass.
pub fn check_open_files(robots: u32) -> Result<(), BusError> {
    let need = coordinator_files(robots);
    match raise_open_files() {
        Some(l) if l.soft < need => Err(BusError::OpenFiles {
            robots,
            need,
            soft: l.soft,
            hard: l.hard,
        }),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_need_grows_with_the_fleet_and_covers_what_was_measured() {
        assert!(coordinator_files(64) >= 1189);
        assert!(coordinator_files(256) >= 4175);
        assert!(
            coordinator_files(2) < 1024,
            "small runs fit the usual default"
        );
        assert!(coordinator_files(33) > coordinator_files(32));
    }

    #[test]
    fn raising_keeps_the_soft_limit_at_most_the_hard_one() {
        let l = raise_open_files().expect("limits readable on Linux");
        assert!(l.soft <= l.hard);
        assert!(
            l.soft == l.hard || l.hard == libc::RLIM_INFINITY,
            "the soft limit is raised to the hard one: {l:?}"
        );
    }
}

/// Memory one process of a run (a robot or the coordinator) needs besides what grows with the
/// map: code, iceoryx2's mappings, buffers.
pub const MEMORY_BASE: u64 = 16 << 20;

/// Memory one process needs per map cell: Q-values, visit counts, the sharing tables and the
/// map itself, about 32 bytes a cell (issue 27: 32 robots on `suite:maze-2048-1`, 4 194 304
/// cells, took 4.5 GB with the coordinator: 33.5 bytes a cell and process).
pub const MEMORY_PER_CELL: u64 = 32;

/// Estimated memory of a run of `processes` processes (robots and the coordinator) on a map of
/// `cells` cells.
pub fn memory_estimate(cells: u64, processes: u64) -> u64 {
    processes.saturating_mul(MEMORY_BASE.saturating_add(cells.saturating_mul(MEMORY_PER_CELL)))
}

/// A run that would not fit in the memory available: a launcher refuses it before any
/// process starts (unless told `--ignore-memory`) rather than let the OOM killer choose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error(
    "not enough memory: {robots} robot(s) and the coordinator on a map of {cells} cells need \
     ~{} MiB, {} MiB are available; run fewer robots or a smaller map, or pass \
     --ignore-memory",
    need >> 20,
    have >> 20
)]
pub struct MemoryShortage {
    /// Robots of this host.
    pub robots: u64,
    /// Cells of the map.
    pub cells: u64,
    /// Estimated need ([`memory_estimate`]), bytes.
    pub need: u64,
    /// Available ([`mem_available`]), bytes.
    pub have: u64,
}

/// Checks that `robots` robots and a coordinator on a map of `cells` cells fit in `available`
/// bytes (`None`: unknown, passes).
pub fn check_memory(cells: u64, robots: u64, available: Option<u64>) -> Result<(), MemoryShortage> {
    let need = memory_estimate(cells, robots.saturating_add(1));
    match available {
        Some(have) if need > have => Err(MemoryShortage {
            robots,
            cells,
            need,
            have,
        }),
        _ => Ok(()),
    }
}

/// `MemAvailable` of a `/proc/meminfo` text, bytes.
pub fn mem_available_in(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// The memory available to new processes now (`MemAvailable`), if it can be read.
pub fn mem_available() -> Option<u64> {
    mem_available_in(&std::fs::read_to_string("/proc/meminfo").ok()?)
}

#[cfg(test)]
mod memory_tests {
    use super::*;

    #[test]
    fn thirty_two_robots_on_a_2048_maze_are_estimated_at_what_they_took() {
        let cells = 2048 * 2048;
        let gb = memory_estimate(cells, 33) as f64 / 1e9;
        assert!((4.4..5.0).contains(&gb), "{gb} GB, measured 4.5");
        // a small map costs little more than the base
        assert!(memory_estimate(20 * 20, 5) < 5 * (MEMORY_BASE + (1 << 20)));
        assert_eq!(memory_estimate(u64::MAX, 2), u64::MAX);
    }

    #[test]
    fn a_run_is_refused_only_when_its_estimate_exceeds_what_is_available() {
        let cells = 2048 * 2048;
        let e = check_memory(cells, 32, Some(1 << 30)).unwrap_err();
        assert_eq!(e.need, memory_estimate(cells, 33));
        assert!(e.to_string().contains("--ignore-memory"), "{e}");
        assert!(
            check_memory(cells, 32, Some(e.need)).is_ok(),
            "exactly enough fits"
        );
        assert!(check_memory(cells, 32, None).is_ok(), "unknown passes");
    }

    #[test]
    fn mem_available_is_read_from_meminfo() {
        let text = "MemTotal:       24684404 kB\nMemFree:         6457592 kB\nMemAvailable:   22693308 kB\n";
        assert_eq!(mem_available_in(text), Some(22_693_308 * 1024));
        assert_eq!(mem_available_in("MemTotal: 1 kB\n"), None);
        assert!(mem_available().is_some());
    }
}
