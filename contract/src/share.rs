//! What robots share and the rules that fit each learner: the sharing options of a robot
//! (`--share`, `--apply`, the batching knobs), how it applies merged hints ([`ApplyRule`]) and
//! how the coordinator merges them ([`MergeRule`], [`merge_rule_for`], [`merge_fits`]), and the
//! pair a run uses ([`Rules`] as given on a command line, [`Resolved`] once decided). Which
//! rule fits depends on the side of Q* a learner's values lie on ([`ValueBound`]); the rules
//! themselves are documented with the code that applies them (robot-agent's `share` module,
//! the coordinator's `merge` module).

use bus_schema::HINT_BATCH_CAP;
use clap::{Args, ValueEnum};
use planner::LearnerConfig;
pub use qfleet_args::{ShareMode, ValueBound};
pub use report::run::MergeRule;
use serde::Serialize;

/// The merge rule that fits a learner whose values keep `bound`: `max` for lower bounds (the
/// paper's learners), `min` for upper bounds (the planning learner).
pub fn merge_rule_for(bound: ValueBound) -> MergeRule {
    match bound {
        ValueBound::Lower => MergeRule::Max,
        ValueBound::Upper => MergeRule::Min,
    }
}

/// Whether `rule` is sound for values that keep `bound`: `max` raises upper bounds to stale
/// optimism, `min` lowers lower bounds to whichever robot knows least; `mean` and `latest`
/// make no use of a bound and fit neither better nor worse.
pub fn merge_fits(rule: MergeRule, bound: ValueBound) -> bool {
    !matches!(
        (rule, bound),
        (MergeRule::Max, ValueBound::Upper) | (MergeRule::Min, ValueBound::Lower)
    )
}

/// How a robot applies a merged hint to its own Q-table (robot-agent's `share` module documents each rule).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ApplyRule {
    /// Raise to the hint for positive hints: `q = max(q, q_hint)` if `q_hint > 0`.
    Max,
    /// Visit-weighted blend towards the hint.
    Blend,
    /// Take the hint as is (can lower values): one shared table, delayed by a batch.
    Latest,
    /// Lower to the hint: `q = min(q, q_hint)` (upper-bound learners: planning).
    Min,
}

impl ApplyRule {
    /// The rule that fits a learner whose values keep `bound`: `max` for lower bounds, `min`
    /// for upper bounds.
    pub fn for_bound(bound: ValueBound) -> ApplyRule {
        match bound {
            ValueBound::Lower => ApplyRule::Max,
            ValueBound::Upper => ApplyRule::Min,
        }
    }

    /// Whether the rule is sound for values that keep `bound` (`max` raises upper bounds to
    /// stale optimism, `min` lowers lower bounds; `blend` and `latest` use no bound).
    pub fn fits(self, bound: ValueBound) -> bool {
        !matches!(
            (self, bound),
            (ApplyRule::Max, ValueBound::Upper) | (ApplyRule::Min, ValueBound::Lower)
        )
    }
}

impl std::fmt::Display for ApplyRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ApplyRule::Max => "max",
            ApplyRule::Blend => "blend",
            ApplyRule::Latest => "latest",
            ApplyRule::Min => "min",
        })
    }
}

/// Sharing options of a robot; `qfleet run` takes the same ones and forwards them.
#[derive(Debug, Clone, PartialEq, Args)]
pub struct ShareArgs {
    /// Share Q-values with the fleet (`hints`), use other robots' discoveries
    /// (`discoveries`), both (`both`), or learn alone (`none`).
    #[arg(long, value_parser = qfleet_args::choice::<ShareMode>(), default_value_t = ShareMode::Hints)]
    pub share: ShareMode,
    /// How merged hints are applied to the local Q-table (default: the rule that fits the
    /// learner, `min` for planning and `max` for the paper's learners).
    #[arg(long, value_enum)]
    pub apply: Option<ApplyRule>,
    /// Publish the robot's state every k-th step (counted over the whole run, not per episode).
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..))]
    pub state_every: u32,
    /// Look at the inbox (merged hints, acks, controls) every this many steps.
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u32).range(1..))]
    pub poll_every: u32,
    /// Entries per Q-hint batch before it is sent (1..=256).
    #[arg(long, default_value_t = HINT_BATCH_CAP as u32,
          value_parser = clap::value_parser!(u32).range(1..=HINT_BATCH_CAP as i64))]
    pub hint_batch: u32,
    /// Send a non-full hint batch once its oldest update is this many steps old.
    #[arg(long, default_value_t = 1024, value_parser = clap::value_parser!(u32).range(1..))]
    pub hint_flush_steps: u32,
    /// Share a Q-value only when it moved by more than this fraction since it was last shared.
    #[arg(long, default_value_t = 1e-3)]
    pub hint_min_change: f32,
}

impl Default for ShareArgs {
    fn default() -> Self {
        ShareArgs {
            share: ShareMode::Hints,
            apply: None,
            state_every: 256,
            poll_every: 64,
            hint_batch: HINT_BATCH_CAP as u32,
            hint_flush_steps: 1024,
            hint_min_change: 1e-3,
        }
    }
}

/// A sharing option out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ShareOptionError {
    /// `--hint-min-change` is negative, NaN or infinite.
    #[error("--hint-min-change must be a finite number >= 0, got {0}")]
    HintMinChange(f32),
}

impl ShareArgs {
    /// Checks the values clap cannot (floats).
    pub fn validate(&self) -> Result<(), ShareOptionError> {
        if !(self.hint_min_change >= 0.0 && self.hint_min_change.is_finite()) {
            return Err(ShareOptionError::HintMinChange(self.hint_min_change));
        }
        Ok(())
    }

    /// The apply rule: the one given, else the one that fits the learner's `bound`.
    pub fn apply_rule(&self, bound: ValueBound) -> ApplyRule {
        self.apply.unwrap_or(ApplyRule::for_bound(bound))
    }

    /// The options as command-line words, to forward to a robot-agent (`--apply` only when
    /// set: the robot resolves the default from its learner the same way).
    pub fn to_cli(&self) -> Vec<String> {
        let mut v: Vec<String> = vec!["--share".into(), self.share.to_string()];
        if let Some(a) = self.apply {
            v.extend(["--apply".into(), a.to_string()]);
        }
        v.extend([
            "--state-every".into(),
            self.state_every.to_string(),
            "--poll-every".into(),
            self.poll_every.to_string(),
            "--hint-batch".into(),
            self.hint_batch.to_string(),
            "--hint-flush-steps".into(),
            self.hint_flush_steps.to_string(),
            "--hint-min-change".into(),
            self.hint_min_change.to_string(),
        ]);
        v
    }
}

/// The two rules of Q-hint sharing: how the coordinator merges robots' values into the fleet
/// table, and how a robot applies the fleet's values to its own table. A rule not given is the
/// one that fits the learner ([`Rules::resolve`]): `min` for the planning learner, whose values
/// are upper bounds of Q*, `max` for the paper's learners, whose values are lower bounds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Args)]
pub struct Rules {
    /// How a robot applies merged hints (robot-agent `--apply`; default: min for planning,
    /// max for the paper's learners).
    #[arg(long, value_enum)]
    pub apply: Option<ApplyRule>,
    /// How the coordinator merges hints into the fleet table (default: min for planning, max
    /// for the paper's learners).
    #[arg(long, value_parser = qfleet_args::choice::<MergeRule>())]
    pub merge: Option<MergeRule>,
}

/// Both rules, decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Resolved {
    /// Robot side.
    pub apply: ApplyRule,
    /// Coordinator side.
    pub merge: MergeRule,
}

impl std::fmt::Display for Resolved {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.apply, self.merge)
    }
}

impl Rules {
    /// The rules for a learner: those given, and for the others the one that fits the bound
    /// its values keep.
    pub fn resolve(self, cfg: &LearnerConfig) -> Resolved {
        let b = ValueBound::of(cfg);
        Resolved {
            apply: self.apply.unwrap_or(ApplyRule::for_bound(b)),
            merge: self.merge.unwrap_or(merge_rule_for(b)),
        }
    }

    /// A warning when a rule given does not fit the learner (`max` with upper bounds, `min`
    /// with lower bounds). Not an error: measuring the wrong pairing is a legitimate ablation.
    pub fn misfit(self, cfg: &LearnerConfig) -> Option<String> {
        let b = ValueBound::of(cfg);
        let mut bad = Vec::new();
        if let Some(a) = self.apply.filter(|a| !a.fits(b)) {
            bad.push(format!("--apply {a}"));
        }
        if let Some(m) = self.merge.filter(|m| !merge_fits(*m, b)) {
            bad.push(format!("--merge {m}"));
        }
        if bad.is_empty() {
            return None;
        }
        let (kind, fit) = match b {
            ValueBound::Upper => ("upper bounds of Q* (optimistic start)", "min/min"),
            ValueBound::Lower => ("lower bounds of Q* (start at 0)", "max/max"),
        };
        let verb = if bad.len() > 1 { "do" } else { "does" };
        Some(format!(
            "warning: {} {verb} not fit this learner: its values are {kind}; the rules that fit are {fit} (running as asked)",
            bad.join(" and ")
        ))
    }
}

impl std::fmt::Display for Rules {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = self.apply.map_or("auto".to_string(), |a| a.to_string());
        let m = self.merge.map_or("auto".to_string(), |m| m.to_string());
        write!(f, "{a}/{m}")
    }
}

impl std::str::FromStr for Rules {
    type Err = String;
    /// `APPLY/MERGE`, e.g. `max/max` or `min/min`; `auto` (alone or for either side) is the
    /// rule that fits the learner.
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "auto" {
            return Ok(Rules::default());
        }
        let (a, m) = s
            .split_once('/')
            .ok_or_else(|| format!("{s:?}: expected APPLY/MERGE, e.g. min/min, or auto"))?;
        Ok(Rules {
            apply: match a {
                "auto" => None,
                _ => Some(
                    ApplyRule::from_str(a, true).map_err(|e| format!("apply rule {a:?}: {e}"))?,
                ),
            },
            merge: match m {
                "auto" => None,
                _ => Some(
                    <MergeRule as report::Word>::from_word(&m.to_ascii_lowercase())
                        .ok_or_else(|| format!("merge rule {m:?}: not max, mean, latest or min"))?,
                ),
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_rule_follows_the_learners_bound_and_a_flag_wins() {
        let planning = ValueBound::of(&LearnerConfig::planning(10, 1));
        let improved = ValueBound::of(&LearnerConfig::improved(10, 1));
        let s = ShareArgs::default();
        assert_eq!(s.apply_rule(planning), ApplyRule::Min);
        assert_eq!(s.apply_rule(improved), ApplyRule::Max);
        assert!(!s.to_cli().contains(&"--apply".to_string()));
        let s = ShareArgs {
            apply: Some(ApplyRule::Latest),
            ..ShareArgs::default()
        };
        assert_eq!(s.apply_rule(planning), ApplyRule::Latest);
        assert!(s.to_cli().windows(2).any(|w| w == ["--apply", "latest"]));
        assert!(ApplyRule::Min.fits(planning) && !ApplyRule::Max.fits(planning));
        assert!(ApplyRule::Max.fits(improved) && !ApplyRule::Min.fits(improved));
        assert!(ApplyRule::Blend.fits(planning) && ApplyRule::Latest.fits(improved));
    }

    #[test]
    fn merge_rules_fit_the_learners_bound() {
        for b in [ValueBound::Lower, ValueBound::Upper] {
            assert!(merge_fits(merge_rule_for(b), b));
        }
        assert!(!merge_fits(MergeRule::Max, ValueBound::Upper));
        assert!(!merge_fits(MergeRule::Min, ValueBound::Lower));
    }

    #[test]
    fn rules_default_to_the_learners_bound_and_a_misfit_is_named() {
        let planning = LearnerConfig::planning(10, 1);
        let improved = LearnerConfig::improved(10, 1);
        let auto: Rules = "auto".parse().unwrap();
        assert_eq!(auto, Rules::default());
        assert_eq!(auto.resolve(&planning).to_string(), "min/min");
        assert_eq!(auto.resolve(&improved).to_string(), "max/max");
        assert_eq!(auto.misfit(&planning), None);
        let half: Rules = "auto/max".parse().unwrap();
        assert_eq!(half.to_string(), "auto/max");
        assert_eq!(half.resolve(&planning).to_string(), "min/max");
        let w = half.misfit(&planning).unwrap();
        assert!(w.contains("--merge max does not fit"), "{w}");
        let both: Rules = "max/max".parse().unwrap();
        assert!(both.misfit(&planning).unwrap().contains("do not fit"));
        assert_eq!(both.misfit(&improved), None);
        let min: Rules = "min/min".parse().unwrap();
        assert!(min.misfit(&improved).unwrap().contains("max/max"));
        assert_eq!(
            "latest/mean".parse::<Rules>().unwrap().misfit(&planning),
            None
        );
        assert!("min".parse::<Rules>().is_err());
        assert!("min/most".parse::<Rules>().is_err());
    }
}
