//! CPU time of this process (getrusage) and of another process (`/proc/<pid>/stat`).

/// User + system CPU time this process used so far, ns.
pub fn self_cpu_ns() -> u64 {
    // SAFETY: an all-zero rusage is a valid value to be overwritten; RUSAGE_SELF always exists.
    let mut ru: libc::rusage = unsafe { core::mem::zeroed() };
    // SAFETY: `ru` is a valid, writable rusage.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut ru) } != 0 {
        return 0;
    }
    let tv = |t: libc::timeval| t.tv_sec as u64 * 1_000_000_000 + t.tv_usec as u64 * 1_000;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

/// User + system CPU time of this process's children that ended and were waited for, ns.
pub fn children_cpu_ns() -> u64 {
    // SAFETY: as in `self_cpu_ns`; RUSAGE_CHILDREN always exists.
    let mut ru: libc::rusage = unsafe { core::mem::zeroed() };
    // SAFETY: `ru` is a valid, writable rusage.
    if unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut ru) } != 0 {
        return 0;
    }
    let tv = |t: libc::timeval| t.tv_sec as u64 * 1_000_000_000 + t.tv_usec as u64 * 1_000;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

/// User + system CPU time process `pid` used so far, ns (clock-tick resolution, 10 ms on
/// Linux); `None` when the process is gone or `/proc` is unreadable.
pub fn pid_cpu_ns(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // the command name (field 2) is in parentheses and may contain spaces: split after it
    let rest = &stat[stat.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // after ')' come field 3 (state) … ; utime = field 14, stime = field 15
    let utime: u64 = fields.get(11)?.parse().ok()?;
    let stime: u64 = fields.get(12)?.parse().ok()?;
    // SAFETY: sysconf has no preconditions.
    let tck = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    let tck = if tck > 0 { tck as u64 } else { 100 };
    Some((utime + stime) * (1_000_000_000 / tck))
}

/// Whether process `pid` exists and is not a zombie.
pub fn pid_alive(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Ok(stat) => stat
            .rfind(')')
            .and_then(|i| stat[i + 1..].split_whitespace().next())
            .is_some_and(|state| state != "Z" && state != "X"),
        Err(_) => false,
    }
}

/// Environment variable through which the harness gives a child its CPUs (`"0"`, `"0,1"`).
pub const CPUS_ENV: &str = "FLEETBENCH_CPUS";

/// The CPUs the harness assigned to this process (empty: not pinned).
pub fn assigned_cpus() -> Vec<usize> {
    std::env::var(CPUS_ENV)
        .map(|v| v.split(',').filter_map(|c| c.trim().parse().ok()).collect())
        .unwrap_or_default()
}

/// Pins the calling thread (and threads it starts later) to `cpu`; false if that failed.
pub fn pin_current_thread(cpu: usize) -> bool {
    pin_thread(0, cpu)
}

/// Pins the calling thread to `own` and every other thread of this process to `rest`; false if
/// a thread could not be moved.
///
/// For a measuring thread that busy-polls while its process has helper threads (a bridge,
/// Zenoh's runtime): they must not queue behind it on one CPU, as they would not on a robot's
/// own computer. Threads started afterwards inherit their starter's CPU.
pub fn pin_apart(own: usize, rest: usize) -> bool {
    // SAFETY: gettid has no preconditions
    let me = unsafe { libc::gettid() };
    let tids = thread_ids();
    let mut all = !tids.is_empty();
    for tid in tids {
        all &= pin_thread(tid, if tid == me { own } else { rest });
    }
    all
}

/// The ids of this process's threads (`/proc/self/task`; empty if it cannot be read).
fn thread_ids() -> Vec<i32> {
    std::fs::read_dir("/proc/self/task")
        .map(|tasks| {
            tasks
                .flatten()
                .filter_map(|t| t.file_name().to_str()?.parse().ok())
                .collect()
        })
        .unwrap_or_default()
}

/// [`pin_apart`] onto the two CPUs the harness assigned (`FLEETBENCH_CPUS=OWN,REST`); does
/// nothing when it assigned fewer.
pub fn keep_apart() {
    if let [own, rest] = assigned_cpus()[..] {
        pin_apart(own, rest);
    }
}

fn pin_thread(tid: i32, cpu: usize) -> bool {
    if cpu >= 8 * size_of::<libc::cpu_set_t>() {
        return false;
    }
    // SAFETY: an all-zero cpu_set_t is the empty set; CPU_SET/sched_setaffinity only touch it.
    unsafe {
        let mut set: libc::cpu_set_t = core::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(tid, size_of::<libc::cpu_set_t>(), &set) == 0
    }
}

/// CPU use as percent of one core: `cpu_ns` spent over `wall_ns`.
pub fn pct(cpu_ns: u64, wall_ns: u64) -> f64 {
    if wall_ns == 0 {
        0.0
    } else {
        cpu_ns as f64 * 100.0 / wall_ns as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_own_cpu_both_ways() {
        let t = std::time::Instant::now();
        while t.elapsed().as_millis() < 30 {
            std::hint::spin_loop();
        }
        assert!(self_cpu_ns() > 0);
        assert!(pid_cpu_ns(std::process::id()).is_some());
        assert!(pid_alive(std::process::id()));
        assert!(!pid_alive(u32::MAX - 1));
    }

    /// Says that a test skipped, and why: a copy of `qfleet_suite::skip` (`tests/support/lib.rs`
    /// says why it looks so; `tests/skips.rs` keeps every copy identical).
    fn skip(test: &str, reason: &str) {
        use std::io::Write;
        let line = format!("SKIPPED: {test}: {reason}\n");
        let _ = std::io::stderr().lock().write_all(line.as_bytes());
    }

    #[test]
    fn pin_apart_moves_the_other_threads_and_keeps_this_one() {
        // SAFETY: sched_getaffinity only writes the set it is given
        let cpus_of = |tid: i32| unsafe {
            let mut set: libc::cpu_set_t = core::mem::zeroed();
            libc::sched_getaffinity(tid, size_of::<libc::cpu_set_t>(), &mut set);
            (0..8)
                .filter(|&c| libc::CPU_ISSET(c, &set))
                .collect::<Vec<usize>>()
        };
        // SAFETY: gettid has no preconditions
        let me = unsafe { libc::gettid() };
        let allowed = cpus_of(me);
        if !(allowed.contains(&0) && allowed.contains(&1)) {
            skip(
                "fleetbench cpu::tests::pin_apart_moves_the_other_threads_and_keeps_this_one",
                &format!("this process may not use CPUs 0 and 1 ({allowed:?})"),
            );
            return;
        }
        // run on a thread of our own, so the test harness's threads are not pinned for good
        let (tid_tx, tid_rx) = std::sync::mpsc::channel();
        let (done_tx, done_rx) = std::sync::mpsc::channel::<()>();
        let helper = std::thread::spawn(move || {
            // SAFETY: as above
            let _ = tid_tx.send(unsafe { libc::gettid() });
            let _ = done_rx.recv();
        });
        let helper_tid = tid_rx.recv().unwrap();
        let checker = std::thread::spawn(move || {
            // SAFETY: as above
            let me = unsafe { libc::gettid() };
            assert!(pin_apart(0, 1));
            (cpus_of(me), cpus_of(helper_tid))
        });
        let (own, helper_cpus) = checker.join().unwrap();
        let _ = done_tx.send(());
        helper.join().unwrap();
        assert_eq!(own, [0]);
        assert_eq!(helper_cpus, [1]);
        // every thread of the test binary was moved along: give them back their CPUs
        for tid in thread_ids() {
            // SAFETY: an all-zero cpu_set_t is the empty set; the calls only touch it
            unsafe {
                let mut set: libc::cpu_set_t = core::mem::zeroed();
                for &c in &allowed {
                    libc::CPU_SET(c, &mut set);
                }
                libc::sched_setaffinity(tid, size_of::<libc::cpu_set_t>(), &set);
            }
        }
    }
}
