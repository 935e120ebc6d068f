//! Multi-target search: pseudo targets around the goal once the robot has found it.
//!
//! Interpretation used here (the paper leaves details open):
//! - Discovery: at the end of the first episode that reaches the true goal, every cell the robot
//!   itself has visited so far (never a cell read off the map) whose Manhattan distance d to the
//!   goal is 1..=R becomes a pseudo target. The start never does.
//! - Value: δ·r(d)·Q(goal), with r(d) = (R + 1 − d)/(R + 1), so closer cells are worth more, and
//!   Q(goal) read as the value of arriving at the goal, the goal reward (the learned Q of the
//!   last move converges to it). With δ ≤ 1 a pseudo target is worth less than the goal.
//! - Effect: while active, entering a pseudo target ends the episode with its value as reward,
//!   so the value front spreads from a wider region and episodes end sooner.
//! - Removal: all pseudo targets are removed at the start of episode ⌈remove_at·N⌉; later
//!   learning then corrects the values they left behind.

use serde::{Deserialize, Serialize};

/// Parameters of the multi-target search.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PseudoConfig {
    /// R: the largest Manhattan distance from the goal of a pseudo target.
    pub radius: u32,
    /// δ: scale of pseudo-target values relative to the goal's.
    pub delta: f32,
    /// When pseudo targets are removed, as a fraction of the episodes (0 = never active).
    pub remove_at: f32,
}

impl Default for PseudoConfig {
    fn default() -> Self {
        PseudoConfig {
            radius: 3,
            delta: 0.5,
            remove_at: 0.1,
        }
    }
}

impl PseudoConfig {
    /// r(d): the distance factor, 1 − d/(R + 1), falling with distance and 0 beyond R.
    pub fn distance_factor(&self, d: u32) -> f32 {
        if d == 0 || d > self.radius {
            0.0
        } else {
            (self.radius + 1 - d) as f32 / (self.radius + 1) as f32
        }
    }

    /// The value of a pseudo target at distance `d` from a goal worth `goal_value`.
    pub fn value(&self, d: u32, goal_value: f32) -> f32 {
        self.delta * self.distance_factor(d) * goal_value
    }

    /// The first episode (0-based) in which pseudo targets are no longer active.
    pub fn removal_episode(&self, episodes: u32) -> u32 {
        (self.remove_at as f64 * episodes as f64)
            .ceil()
            .min(u32::MAX as f64) as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_fall_with_distance() {
        let c = PseudoConfig {
            radius: 4,
            delta: 0.5,
            remove_at: 0.5,
        };
        let v: Vec<f32> = (1..=4).map(|d| c.value(d, 1.0)).collect();
        assert!(v.windows(2).all(|w| w[0] > w[1]), "{v:?}");
        assert!(v.iter().all(|x| *x > 0.0 && *x < 1.0));
        assert_eq!(c.value(0, 1.0), 0.0);
        assert_eq!(c.value(5, 1.0), 0.0);
        assert_eq!(c.removal_episode(100), 50);
    }
}
