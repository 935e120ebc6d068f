//! `qfleet learn`: one learner on one task, with a JSON summary, a per-episode CSV and plots.

use crate::plots::{self, Series};
use anyhow::{Context, Result};
use clap::Args;
use planner::{EpisodeRecord, Learner, LearnerConfig, Summary};
use qfleet_args::{LearnerArgs, MapArgs};
use serde::Serialize;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

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

/// The JSON result of one learning run.
#[derive(Debug, Serialize)]
pub struct LearnResult {
    /// Map name.
    pub map: String,
    /// `traditional` or `improved`.
    pub learner: String,
    /// Policy in words.
    pub policy: String,
    /// Episodes run.
    pub episodes: u32,
    /// Seed.
    pub seed: u64,
    /// Start cell `x,y`.
    pub start: String,
    /// Goal cell `x,y`.
    pub goal: String,
    /// BFS optimum in moves.
    pub optimal_path_len: u32,
    /// Greedy path moves at the end (null: it loops).
    pub final_path_len: Option<u32>,
    /// Mean steps per episode.
    pub avg_steps: f64,
    /// Largest steps in one episode.
    pub max_steps: u32,
    /// First episode after which the greedy path was optimal (null: never).
    pub first_optimal_episode: Option<u32>,
    /// Actions taken in all.
    pub env_steps: u64,
    /// Actions that hit an obstacle or the border, in all.
    pub collisions: u64,
    /// Collisions per episode (the paper's collision-avoidance claim is about this figure).
    pub collisions_per_episode: f64,
    /// Wall time of the learning loop.
    pub elapsed_s: f64,
    /// Learning throughput.
    pub env_steps_per_s: f64,
    /// Episodes that reached the goal / a pseudo target / the step cap.
    pub outcomes: Outcomes,
    /// The full learner configuration.
    pub config: LearnerConfig,
}

/// Counts of how episodes ended.
#[derive(Debug, Serialize)]
pub struct Outcomes {
    /// Reached the goal.
    pub goal: u32,
    /// Ended on a pseudo target.
    pub pseudo: u32,
    /// Hit the step cap.
    pub cap: u32,
}

impl LearnCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        // a map, scenario or learner option that does not hold is bad input (exit code 2)
        let task = self.map.task().context(launcher::Exit::BadInput)?;
        let cfg = self.learner.config().context(launcher::Exit::BadInput)?;
        let mut learner = Learner::new(&task, cfg).context(launcher::Exit::BadInput)?;
        let t0 = Instant::now();
        let (records, summary) = learner.run(|_| {});
        let elapsed = t0.elapsed().as_secs_f64();
        let result = LearnResult::new(
            &task.map_name,
            self.learner.learner.to_string(),
            &cfg,
            &task,
            &summary,
            elapsed,
        );
        if let Some(dir) = &self.out {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
            write_episodes_csv(&dir.join("episodes.csv"), &records)?;
            std::fs::write(
                dir.join("summary.json"),
                serde_json::to_string_pretty(&result)?,
            )
            .with_context(|| format!("writing {}", dir.join("summary.json").display()))?;
            let steps: Vec<f64> = records.iter().map(|r| r.steps as f64).collect();
            plots::line_chart(
                &dir.join("steps.svg"),
                &format!("{} on {}: steps per episode", result.learner, task.map_name),
                "episode",
                "steps",
                &[Series {
                    label: &result.learner,
                    values: &steps,
                }],
            )?;
            let learned = learner.greedy_path();
            let bfs =
                planner::path::bfs_path(&task.grid, task.start, task.goal).unwrap_or_default();
            let mut paths: Vec<(&str, &[planner::Cell])> = vec![("BFS optimum", &bfs)];
            if let Some(p) = &learned {
                paths.push(("learned greedy path", p));
            }
            plots::paths_on_grid(
                &dir.join("path.svg"),
                &format!("{} on {}", result.learner, task.map_name),
                &task.grid,
                task.start,
                task.goal,
                &paths,
            )?;
        }
        if self.json {
            crate::term::out!("{}", serde_json::to_string(&result)?)?;
        } else {
            let fmt_opt = |v: Option<u32>| v.map_or("none (loops)".to_string(), |x| x.to_string());
            crate::term::out!(
                "map {}  learner {} [{}]  episodes {}  seed {}",
                result.map,
                result.learner,
                result.policy,
                result.episodes,
                result.seed
            )?;
            crate::term::out!(
                "  optimal path      {} moves (BFS)",
                result.optimal_path_len
            )?;
            crate::term::out!("  final path        {}", fmt_opt(result.final_path_len))?;
            crate::term::out!(
                "  avg / max steps   {:.2} / {}",
                result.avg_steps,
                result.max_steps
            )?;
            crate::term::out!(
                "  collisions        {:.2} per episode ({} in all)",
                result.collisions_per_episode,
                result.collisions
            )?;
            crate::term::out!(
                "  first optimal     episode {}",
                result
                    .first_optimal_episode
                    .map_or("never".into(), |e| e.to_string())
            )?;
            crate::term::out!(
                "  env steps         {} in {:.3} s ({:.1} M steps/s)",
                result.env_steps,
                result.elapsed_s,
                result.env_steps_per_s / 1e6
            )?;
            if let Some(dir) = &self.out {
                crate::term::out!(
                    "  wrote             {}/{{episodes.csv,summary.json,steps.svg,path.svg}}",
                    dir.display()
                )?;
            }
        }
        Ok(())
    }
}

impl LearnResult {
    /// Builds the result of a finished run.
    pub fn new(
        map: &str,
        learner: String,
        cfg: &LearnerConfig,
        task: &planner::task::Task,
        s: &Summary,
        elapsed_s: f64,
    ) -> Self {
        LearnResult {
            map: map.to_string(),
            learner,
            policy: cfg.policy_label(),
            episodes: s.episodes,
            seed: cfg.seed,
            start: task.start.to_string(),
            goal: task.goal.to_string(),
            optimal_path_len: s.optimal_path_len,
            final_path_len: s.final_path_len,
            avg_steps: s.avg_steps,
            max_steps: s.max_steps,
            first_optimal_episode: s.first_optimal_episode,
            env_steps: s.env_steps,
            collisions: s.collisions,
            collisions_per_episode: if s.episodes > 0 {
                s.collisions as f64 / s.episodes as f64
            } else {
                0.0
            },
            elapsed_s,
            env_steps_per_s: if elapsed_s > 0.0 {
                s.env_steps as f64 / elapsed_s
            } else {
                0.0
            },
            outcomes: Outcomes {
                goal: s.goal_episodes,
                pseudo: s.pseudo_episodes,
                cap: s.capped_episodes,
            },
            config: *cfg,
        }
    }
}

/// Writes the per-episode CSV file.
pub fn write_episodes_csv(path: &Path, records: &[EpisodeRecord]) -> Result<()> {
    let f = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut w = std::io::BufWriter::new(f);
    planner::metrics::write_episodes_csv(&mut w, records)
        .and_then(|()| w.flush())
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

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
