//! The seed of each robot process, derived from the seed the user gave.
//!
//! Two derivations exist because two commands promise different things: a `qfleet run` with
//! `--seed S` gives robot i the seed S + i (so a one-robot run reproduces `qfleet learn --seed
//! S`); the repetitions of an experiment or a sweep (seeds s = 1, 2, 3, …) must never share a
//! robot seed, so robot r of repetition s gets 1000·s + r (distinct for up to 1000 robots).

/// Seed of robot `id` in a `qfleet run` with seed `base`: `base + id`.
pub fn run_robot(base: u64, id: u32) -> u64 {
    base.wrapping_add(u64::from(id))
}

/// Seed of robot `robot` in repetition `seed` of an experiment or sweep: `1000·seed + robot`.
pub fn repetition_robot(seed: u64, robot: u32) -> u64 {
    seed.wrapping_mul(1000).wrapping_add(u64::from(robot))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn a_run_offsets_the_seed_by_the_robot_id() {
        assert_eq!(run_robot(7, 0), 7);
        assert_eq!(run_robot(7, 3), 10);
        assert_eq!(run_robot(u64::MAX, 1), 0);
    }

    #[test]
    fn repetitions_never_share_a_robot_seed() {
        let mut seen = HashSet::new();
        for s in 1..=20 {
            for r in 0..256 {
                assert!(seen.insert(repetition_robot(s, r)), "seed {s} robot {r}");
            }
        }
    }
}
