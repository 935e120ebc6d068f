//! What robots share with the fleet: the one `ShareMode` of qfleet, read from the command line
//! (`--share`, `--sharing`), from manifests (`sharing = "both"`) and written in results
//! (`"share": "both"`), always as the same four words; and [`ValueBound`], the side of Q* a
//! learner's values lie on, which decides the sharing rules that fit it.

use planner::LearnerConfig;
pub use report::ShareMode;
use serde::{Deserialize, Serialize};

/// On which side of the optimal Q* every value of a learner's table lies, which decides how
/// values of several robots may be combined (`--apply` and `--merge` default to the rule that
/// fits; see README "The fleet").
///
/// - `Lower`: the paper's learners start Q at 0, and with the goal the only positive reward
///   every positive value they learn is at most Q*; the fleet maximum is the best estimate
///   (rules `max/max`). Pseudo targets break this for a while (see robot-agent's share docs).
/// - `Upper`: a learner whose untried actions start at an optimistic value at least as large
///   as any Q* (`optimistic >= max(reward_goal, 0)`, no positive move or collision reward, no
///   pseudo targets) holds upper bounds only: every update it makes (α-update, backward replay,
///   Dyna sweep) is a monotone backup `r + γ·max Q(s')` of upper bounds on a deterministic grid,
///   so it stays at or above Q*. Raising one to another robot's value mixes stale optimism into
///   a table its own sweeps keep lowering; the fleet minimum of upper bounds is still an upper
///   bound, and tighter (rules `min/min`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ValueBound {
    /// Learned values are at most Q* (start at 0).
    Lower,
    /// Every value is at least Q* (optimistic start).
    Upper,
}

impl ValueBound {
    /// The bound a learner configuration's values keep.
    pub fn of(cfg: &LearnerConfig) -> ValueBound {
        let r = cfg.rewards;
        match cfg.extras.optimistic {
            Some(v)
                if v >= r.goal.max(0.0)
                    && r.step <= 0.0
                    && r.collision <= 0.0
                    && cfg.pseudo.is_none() =>
            {
                ValueBound::Upper
            }
            _ => ValueBound::Lower,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn optimistic_learners_keep_upper_bounds_and_the_papers_lower_ones() {
        use planner::LearnerConfig;
        assert_eq!(
            ValueBound::of(&LearnerConfig::planning(10, 1)),
            ValueBound::Upper
        );
        assert_eq!(
            ValueBound::of(&LearnerConfig::improved(10, 1)),
            ValueBound::Lower
        );
        assert_eq!(
            ValueBound::of(&LearnerConfig::traditional(10, 1)),
            ValueBound::Lower
        );
        // optimism below the goal's reward is no upper bound: Q* near the goal is larger
        let mut c = LearnerConfig::planning(10, 1);
        c.rewards.goal = 2.0;
        assert_eq!(ValueBound::of(&c), ValueBound::Lower);
        // a positive move reward makes Q* grow with the path: no bound from 1.0 either
        let mut c = LearnerConfig::planning(10, 1);
        c.rewards.step = 0.01;
        assert_eq!(ValueBound::of(&c), ValueBound::Lower);
        // pseudo targets change the task the values belong to
        let mut c = LearnerConfig::planning(10, 1);
        c.pseudo = Some(planner::PseudoConfig::default());
        assert_eq!(ValueBound::of(&c), ValueBound::Lower);
    }
}
