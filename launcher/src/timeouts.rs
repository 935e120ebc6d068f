//! How long a run's processes wait for each other at start-up, from the fleet's size.
//!
//! Robots register one after the other as the machine starts them: on the 2-core VM a fleet of
//! 128 robots took 19 s from launch to the end of a one-episode run, and the last of 256
//! registered after the fixed 30 s the coordinator (all registrations) and the robots (their
//! `Start`) used to wait. The wait therefore grows with the fleet.

/// Seconds the coordinator waits for every registration (and for reports after `Stop`) and a
/// robot for the coordinator's `Start`: 30 s up to 32 robots, then 0.4 s more per robot
/// (32 → 30 s, 64 → 42.8 s, 256 → 119.6 s).
pub fn startup_timeout_s(robots: u32) -> f64 {
    30.0 + 0.4 * f64::from(robots.saturating_sub(32))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_fleets_keep_thirty_seconds_and_large_ones_get_more() {
        assert_eq!(startup_timeout_s(1), 30.0);
        assert_eq!(startup_timeout_s(32), 30.0);
        assert!((startup_timeout_s(64) - 42.8).abs() < 1e-9);
        assert!((startup_timeout_s(256) - 119.6).abs() < 1e-9);
        assert!(startup_timeout_s(256) > startup_timeout_s(255));
    }
}
