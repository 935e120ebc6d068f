//! What a learning run measures: per-episode records and the run summary of Table 1.

use serde::{Deserialize, Serialize};

/// How an episode ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Outcome {
    /// Reached the true goal.
    Goal,
    /// Ended on an active pseudo target.
    Pseudo,
    /// Hit the step cap.
    Cap,
}

impl Outcome {
    /// Lower-case name for CSV files.
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Goal => "goal",
            Outcome::Pseudo => "pseudo",
            Outcome::Cap => "cap",
        }
    }
}

/// One episode: moves tried (collisions count as steps), collisions, how it ended, its return.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EpisodeRecord {
    /// 0-based episode number.
    pub episode: u32,
    /// Actions taken, collisions included.
    pub steps: u32,
    /// Actions that hit an obstacle or the border.
    pub collisions: u32,
    /// How the episode ended.
    pub outcome: Outcome,
    /// Undiscounted sum of rewards.
    pub ret: f32,
    /// Moves of the greedy path at the end of the episode (`None`: it loops or collides).
    pub greedy_path_len: Option<u32>,
}

/// The summary of a run: the paper's Table 1 figures plus what a user needs to judge it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Episodes run.
    pub episodes: u32,
    /// BFS shortest path in moves.
    pub optimal_path_len: u32,
    /// Moves of the final greedy path from the start (`None`: it loops).
    pub final_path_len: Option<u32>,
    /// Mean steps per episode.
    pub avg_steps: f64,
    /// Largest steps in one episode.
    pub max_steps: u32,
    /// First episode after which the greedy path was optimal (`None`: never).
    pub first_optimal_episode: Option<u32>,
    /// Episodes that reached the goal.
    pub goal_episodes: u32,
    /// Episodes that ended on a pseudo target.
    pub pseudo_episodes: u32,
    /// Episodes cut by the step cap.
    pub capped_episodes: u32,
    /// Actions taken over the run.
    pub env_steps: u64,
    /// Collisions over the run.
    pub collisions: u64,
}

impl Summary {
    /// Summarises episode records; `final_path_len` comes from the learned table.
    pub fn from_records(
        records: &[EpisodeRecord],
        optimal_path_len: u32,
        final_path_len: Option<u32>,
    ) -> Summary {
        let env_steps: u64 = records.iter().map(|r| r.steps as u64).sum();
        let count = |o| records.iter().filter(|r| r.outcome == o).count() as u32;
        Summary {
            episodes: records.len() as u32,
            optimal_path_len,
            final_path_len,
            avg_steps: if records.is_empty() {
                0.0
            } else {
                env_steps as f64 / records.len() as f64
            },
            max_steps: records.iter().map(|r| r.steps).max().unwrap_or(0),
            first_optimal_episode: records
                .iter()
                .find(|r| r.greedy_path_len == Some(optimal_path_len))
                .map(|r| r.episode),
            goal_episodes: count(Outcome::Goal),
            pseudo_episodes: count(Outcome::Pseudo),
            capped_episodes: count(Outcome::Cap),
            env_steps,
            collisions: records.iter().map(|r| r.collisions as u64).sum(),
        }
    }
}

/// Writes records as CSV, `episode,steps,collisions,outcome,return,greedy_path_len` (an empty
/// last field when the greedy path loops), for plots and spreadsheets.
pub fn write_episodes_csv(
    w: &mut impl std::io::Write,
    records: &[EpisodeRecord],
) -> std::io::Result<()> {
    writeln!(w, "episode,steps,collisions,outcome,return,greedy_path_len")?;
    for r in records {
        write!(
            w,
            "{},{},{},{},{},",
            r.episode,
            r.steps,
            r.collisions,
            r.outcome.as_str(),
            r.ret
        )?;
        match r.greedy_path_len {
            Some(g) => writeln!(w, "{g}")?,
            None => writeln!(w)?,
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_has_one_row_per_episode() {
        let r = EpisodeRecord {
            episode: 0,
            steps: 7,
            collisions: 1,
            outcome: Outcome::Goal,
            ret: 0.0,
            greedy_path_len: None,
        };
        let mut out = Vec::new();
        write_episodes_csv(
            &mut out,
            &[
                r,
                EpisodeRecord {
                    episode: 1,
                    greedy_path_len: Some(5),
                    ..r
                },
            ],
        )
        .unwrap();
        let text = String::from_utf8(out).unwrap();
        assert_eq!(
            text.lines().collect::<Vec<_>>(),
            [
                "episode,steps,collisions,outcome,return,greedy_path_len",
                "0,7,1,goal,0,",
                "1,7,1,goal,0,5"
            ]
        );
    }
}
