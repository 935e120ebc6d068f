//! One learner on one task (`qfleet learn`): the run's summary as a [`LearnResult`], and with
//! an out directory its per-episode CSV, the summary as JSON and two figures.

use crate::files::{self, WriteError, writing};
use crate::plots::{self, PlotError, Series};
use planner::task::Task;
use planner::{ConfigError, EpisodeRecord, Learner, LearnerConfig, Summary};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What to learn and where to write the files.
#[derive(Debug, Clone)]
pub struct LearnOptions {
    /// The map with its start and goal.
    pub task: Task,
    /// The learner's name as the result shows it (`planning`, `improved`, …).
    pub learner: String,
    /// The learner's configuration.
    pub config: LearnerConfig,
    /// Directory for episodes.csv, summary.json, steps.svg and path.svg (none: no files).
    pub out: Option<PathBuf>,
}

/// Why a learning run did not give a result.
#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    /// The configuration does not hold for this task (bad input).
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A file of the out directory could not be written.
    #[error(transparent)]
    Write(#[from] WriteError),
    /// A figure could not be drawn.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// The summary could not be encoded as JSON.
    #[error("encoding summary.json")]
    Json(#[from] serde_json::Error),
}

impl LearnError {
    /// Whether the input was refused before anything ran (the CLI's exit code 2).
    pub fn is_bad_input(&self) -> bool {
        matches!(self, LearnError::Config(_))
    }
}

/// The JSON result of one learning run.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Outcomes {
    /// Reached the goal.
    pub goal: u32,
    /// Ended on a pseudo target.
    pub pseudo: u32,
    /// Hit the step cap.
    pub cap: u32,
}

/// Learns `opts.task` with `opts.config` and, with an out directory, writes its files there.
pub fn learn(opts: &LearnOptions) -> Result<LearnResult, LearnError> {
    let task = &opts.task;
    let mut learner = Learner::new(task, opts.config)?;
    let t0 = Instant::now();
    let (records, summary) = learner.run(|_| {});
    let elapsed = t0.elapsed().as_secs_f64();
    let result = LearnResult::new(
        &task.map_name,
        opts.learner.clone(),
        &opts.config,
        task,
        &summary,
        elapsed,
    );
    if let Some(dir) = &opts.out {
        files::create_dir(dir)?;
        write_episodes_csv(&dir.join("episodes.csv"), &records)?;
        let summary_json = dir.join("summary.json");
        let text = serde_json::to_string_pretty(&result)?;
        files::write(&summary_json, text)?;
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
        let bfs = planner::path::bfs_path(&task.grid, task.start, task.goal).unwrap_or_default();
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
    Ok(result)
}

impl LearnResult {
    /// `qfleet learn`'s human summary: the map, learner and seed, the path found against the
    /// BFS optimum, steps, collisions, the first optimal episode, speed, and (with `out`) the
    /// files written there.
    pub fn summary(&self, out: Option<&std::path::Path>) -> String {
        use std::fmt::Write as _;
        let fmt_opt = |v: Option<u32>| v.map_or("none (loops)".to_string(), |x| x.to_string());
        let mut s = String::new();
        let _ = writeln!(
            s,
            "map {}  learner {} [{}]  episodes {}  seed {}",
            self.map, self.learner, self.policy, self.episodes, self.seed
        );
        let _ = writeln!(
            s,
            "  optimal path      {} moves (BFS)",
            self.optimal_path_len
        );
        let _ = writeln!(s, "  final path        {}", fmt_opt(self.final_path_len));
        let _ = writeln!(
            s,
            "  avg / max steps   {:.2} / {}",
            self.avg_steps, self.max_steps
        );
        let _ = writeln!(
            s,
            "  collisions        {:.2} per episode ({} in all)",
            self.collisions_per_episode, self.collisions
        );
        let first = self.first_optimal_episode;
        let _ = writeln!(
            s,
            "  first optimal     episode {}",
            first.map_or("never".into(), |e| e.to_string())
        );
        let _ = writeln!(
            s,
            "  env steps         {} in {:.3} s ({:.1} M steps/s)",
            self.env_steps,
            self.elapsed_s,
            self.env_steps_per_s / 1e6
        );
        if let Some(dir) = out {
            let _ = writeln!(
                s,
                "  wrote             {}/{{episodes.csv,summary.json,steps.svg,path.svg}}",
                dir.display()
            );
        }
        s
    }

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
pub fn write_episodes_csv(path: &Path, records: &[EpisodeRecord]) -> Result<(), LearnError> {
    let f = std::fs::File::create(path).map_err(writing(path))?;
    let mut w = std::io::BufWriter::new(f);
    planner::metrics::write_episodes_csv(&mut w, records)
        .and_then(|()| w.flush())
        .map_err(writing(path))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paper_10() -> Task {
        let map = planner::map::load_map("builtin:paper-10").unwrap();
        planner::task::resolve_task(&map, None, None).unwrap()
    }

    #[test]
    fn a_run_writes_its_four_files_and_its_summary_reads_back() {
        let dir = std::env::temp_dir().join(format!("studies-learn-{}", std::process::id()));
        let opts = LearnOptions {
            task: paper_10(),
            learner: "planning".into(),
            config: LearnerConfig::planning(50, 1),
            out: Some(dir.clone()),
        };
        let r = learn(&opts).unwrap();
        assert_eq!((r.map.as_str(), r.episodes, r.seed), ("paper-10", 50, 1));
        for f in ["episodes.csv", "summary.json", "steps.svg", "path.svg"] {
            assert!(dir.join(f).is_file(), "{f}");
        }
        let text = std::fs::read_to_string(dir.join("summary.json")).unwrap();
        let back: LearnResult = serde_json::from_str(&text).unwrap();
        assert_eq!(back.env_steps, r.env_steps);
        let s = r.summary(Some(&dir));
        assert!(s.starts_with("map paper-10  learner planning ["), "{s}");
        assert!(
            s.contains("moves (BFS)") && s.contains("/{episodes.csv,"),
            "{s}"
        );
        assert!(!r.summary(None).contains("wrote"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_configuration_that_does_not_hold_is_bad_input() {
        let opts = LearnOptions {
            task: paper_10(),
            learner: "traditional".into(),
            config: LearnerConfig {
                gamma: 1.5,
                ..LearnerConfig::traditional(10, 1)
            },
            out: None,
        };
        assert!(learn(&opts).unwrap_err().is_bad_input());
    }
}
