//! `qfleet learn`: one learner on one task ([`studies::learn`]), with a JSON summary, a
//! per-episode CSV and plots.

use anyhow::{Context, Result};
use clap::Args;
use launcher::Exit;
use qfleet_args::{LearnerArgs, MapArgs};
use std::path::PathBuf;
use studies::learn::{LearnOptions, learn};

use crate::term::out;

/// Options of `qfleet learn`; the learner defaults to `planning`, the winner on the map
/// suite's held-out half (README "Map suite and held-out evaluation").
#[derive(Debug, Args)]
#[command(mut_arg("learner", |a| a.default_value("planning")))]
pub struct LearnCmd {
    #[command(flatten)]
    map: MapArgs,
    #[command(flatten)]
    learner: LearnerArgs,
    /// Print one JSON object on stdout instead of a human summary.
    #[arg(long)]
    json: bool,
    /// Directory for episodes.csv, summary.json, steps.svg and path.svg.
    #[arg(long)]
    out: Option<PathBuf>,
}

impl LearnCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        // a map, scenario or learner option that does not hold is bad input (exit code 2)
        let opts = LearnOptions {
            task: self.map.task().context(Exit::BadInput)?,
            learner: self.learner.learner.to_string(),
            config: self.learner.config().context(Exit::BadInput)?,
            out: self.out.clone(),
        };
        let result = learn(&opts).map_err(|e| crate::classify(e, |e| e.is_bad_input()))?;
        if self.json {
            out!("{}", serde_json::to_string(&result)?)?;
        } else {
            let text = result.summary(self.out.as_deref());
            crate::term::write_out(format_args!("{text}"))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use planner::LearnerConfig;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        learn: LearnCmd,
    }

    #[test]
    fn learn_defaults_to_the_planning_learner() {
        let cli = Cli::try_parse_from(["x"]).unwrap();
        assert_eq!(
            cli.learn.learner.config().unwrap(),
            LearnerConfig::planning(1000, 1)
        );
        let cli = Cli::try_parse_from(["x", "--learner", "traditional"]).unwrap();
        assert_eq!(
            cli.learn.learner.config().unwrap(),
            LearnerConfig::traditional(1000, 1)
        );
    }
}
