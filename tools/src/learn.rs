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
        let result = learn(&opts).map_err(|e| {
            let bad = e.is_bad_input();
            crate::classify(e, bad)
        })?;
        if self.json {
            out!("{}", serde_json::to_string(&result)?)?;
        } else {
            let fmt_opt = |v: Option<u32>| v.map_or("none (loops)".to_string(), |x| x.to_string());
            out!(
                "map {}  learner {} [{}]  episodes {}  seed {}",
                result.map,
                result.learner,
                result.policy,
                result.episodes,
                result.seed
            )?;
            out!(
                "  optimal path      {} moves (BFS)",
                result.optimal_path_len
            )?;
            out!("  final path        {}", fmt_opt(result.final_path_len))?;
            out!(
                "  avg / max steps   {:.2} / {}",
                result.avg_steps,
                result.max_steps
            )?;
            out!(
                "  collisions        {:.2} per episode ({} in all)",
                result.collisions_per_episode,
                result.collisions
            )?;
            out!(
                "  first optimal     episode {}",
                result
                    .first_optimal_episode
                    .map_or("never".into(), |e| e.to_string())
            )?;
            out!(
                "  env steps         {} in {:.3} s ({:.1} M steps/s)",
                result.env_steps,
                result.elapsed_s,
                result.env_steps_per_s / 1e6
            )?;
            if let Some(dir) = &self.out {
                out!(
                    "  wrote             {}/{{episodes.csv,summary.json,steps.svg,path.svg}}",
                    dir.display()
                )?;
            }
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
