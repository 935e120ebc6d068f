//! The one clock all qfleet timestamps use.

/// Nanoseconds of `CLOCK_MONOTONIC`: comparable between processes on one machine, never jumps.
///
/// Every `*_ns` field of the wire contract uses this clock, so a latency is simply
/// `monotonic_ns() - msg.send_time_ns` in the receiving process. About 20–30 ns per call (vDSO).
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC exists on every Linux and BSD.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    if rc != 0 {
        // Cannot happen for CLOCK_MONOTONIC with a valid pointer; 0 is an obviously bad time.
        return 0;
    }
    (ts.tv_sec as u64)
        .saturating_mul(1_000_000_000)
        .saturating_add(ts.tv_nsec as u64)
}
