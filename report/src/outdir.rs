//! Every file name of a run's `--out` directory, in one place.
//!
//! | file                          | written by    | what                                         |
//! |-------------------------------|---------------|----------------------------------------------|
//! | `result.json`                 | coordinator   | the run's result (the launcher reads it)     |
//! | `plan.json`                   | launcher      | an experiment's resolved plan (coordinator `--plan`) |
//! | `experiment-checkpoint.json`  | coordinator   | an experiment's progress: phases done, their results |
//! | `robot-<id>.json`             | robot         | [`RobotResult`](crate::RobotResult)          |
//! | `robot-<id>-phase-<p>.json`   | robot         | [`PhaseDetail`](crate::PhaseDetail) of a phase |
//! | `robot-<id>-episodes.csv`     | robot         | one line per episode                         |
//! | `robot-<id>-loop.hdr`         | robot         | loop latency, hdrhistogram V2 binary         |
//! | `robot-<id>-merged.hdr`       | robot         | merged-batch latency, V2 binary              |
//! | `latency-<path>.hgrm`         | coordinator   | percentile file of one measured path         |
//! | `coordinator-checkpoint.json` | coordinator   | [`CoordinatorCheckpoint`](crate::CoordinatorCheckpoint): what a restarted run coordinator resumes from |
//! | `coordinator.log`             | launcher      | the coordinator's stderr                     |
//! | `robot-<id>.log`              | launcher      | a robot's stderr                             |
//! | `latency.svg`, `steps.svg`    | launcher      | figures of the run                           |
//! | `seed-<seed>/`                | launcher      | one repetition of an experiment (an `OutDir`) |
//!
//! [`OutFile`] names them ([`OutFile::name`]) and recognises them ([`OutFile::parse`]), so a
//! reader that scans a directory and a writer that fills it cannot disagree. [`OutDir`] joins
//! them to a directory and reads and writes them: writes go through
//! [`write_atomic`](crate::write_atomic), reads come back typed.

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::atomic::{WriteError, write_atomic, write_json_atomic};

/// Which latency histogram a robot hands to the coordinator (`robot-<id>-<kind>.hdr`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RobotHist {
    /// Origin of a Q update at another robot → applied here.
    Loop,
    /// Coordinator sent a merged batch → received here.
    Merged,
}

impl RobotHist {
    /// Both kinds.
    pub const ALL: [RobotHist; 2] = [RobotHist::Loop, RobotHist::Merged];

    /// The word in the file name.
    pub const fn as_str(self) -> &'static str {
        match self {
            RobotHist::Loop => "loop",
            RobotHist::Merged => "merged",
        }
    }
}

/// A measured latency path of a run (`latency-<path>.hgrm`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LatencyPath {
    /// Robot state sent → received by the coordinator.
    StateOneWay,
    /// Discovery sent → received by the coordinator.
    DiscoveryOneWay,
    /// Hint batch sent → received by the coordinator.
    HintsOneWay,
    /// Age of a hint (its oldest update) when the coordinator merged it.
    HintAgeAtMerge,
    /// Final report sent → received by the coordinator.
    ReportOneWay,
    /// Merged batch sent → received by a robot (all robots added up).
    MergedOneWay,
    /// A Q update at one robot → applied at another (all robots added up).
    Loop,
}

impl LatencyPath {
    /// Every path, in the order the coordinator writes them.
    pub const ALL: [LatencyPath; 7] = [
        LatencyPath::StateOneWay,
        LatencyPath::DiscoveryOneWay,
        LatencyPath::HintsOneWay,
        LatencyPath::HintAgeAtMerge,
        LatencyPath::ReportOneWay,
        LatencyPath::MergedOneWay,
        LatencyPath::Loop,
    ];

    /// The word in the file name (also the key in `result.json`'s latency table).
    pub const fn as_str(self) -> &'static str {
        match self {
            LatencyPath::StateOneWay => "state_one_way",
            LatencyPath::DiscoveryOneWay => "discovery_one_way",
            LatencyPath::HintsOneWay => "hints_one_way",
            LatencyPath::HintAgeAtMerge => "hint_age_at_merge",
            LatencyPath::ReportOneWay => "report_one_way",
            LatencyPath::MergedOneWay => "merged_one_way",
            LatencyPath::Loop => "loop",
        }
    }

    /// The path named `word`, if any.
    pub fn parse(word: &str) -> Option<LatencyPath> {
        LatencyPath::ALL.into_iter().find(|p| p.as_str() == word)
    }
}

/// One file of a run's out directory (see the module table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum OutFile {
    /// `result.json`.
    Result,
    /// `plan.json`.
    Plan,
    /// `experiment-checkpoint.json`.
    ExperimentCheckpoint,
    /// `robot-<id>.json`.
    Robot(u32),
    /// `robot-<id>-phase-<p>.json`.
    RobotPhase {
        /// Robot id.
        robot: u32,
        /// Phase number.
        phase: u32,
    },
    /// `robot-<id>-episodes.csv`.
    RobotEpisodes(u32),
    /// `robot-<id>-loop.hdr` / `robot-<id>-merged.hdr`.
    RobotHist {
        /// Robot id.
        robot: u32,
        /// Which histogram.
        kind: RobotHist,
    },
    /// `latency-<path>.hgrm`.
    Latency(LatencyPath),
    /// `coordinator.log`.
    CoordinatorLog,
    /// `coordinator-checkpoint.json`.
    CoordinatorCheckpoint,
    /// `robot-<id>.log`.
    RobotLog(u32),
    /// `latency.svg`.
    LatencyPlot,
    /// `steps.svg`.
    StepsPlot,
    /// `paths.txt`: a shared grid's paths in the mapf-visualizer format.
    Paths,
    /// `paths-phase-<p>.txt`: the paths of phase `p` of an experiment on a shared grid.
    PhasePaths(u32),
    /// `lorr-output.json`: a lifelong run in the League of Robot Runners' output format (its
    /// visualiser, PlanViz, opens it).
    LorrOutput,
}

impl OutFile {
    /// The file name.
    pub fn name(self) -> String {
        match self {
            OutFile::Result => "result.json".into(),
            OutFile::Plan => "plan.json".into(),
            OutFile::ExperimentCheckpoint => "experiment-checkpoint.json".into(),
            OutFile::Robot(id) => format!("robot-{id}.json"),
            OutFile::RobotPhase { robot, phase } => format!("robot-{robot}-phase-{phase}.json"),
            OutFile::RobotEpisodes(id) => format!("robot-{id}-episodes.csv"),
            OutFile::RobotHist { robot, kind } => format!("robot-{robot}-{}.hdr", kind.as_str()),
            OutFile::Latency(p) => format!("latency-{}.hgrm", p.as_str()),
            OutFile::CoordinatorLog => "coordinator.log".into(),
            OutFile::CoordinatorCheckpoint => "coordinator-checkpoint.json".into(),
            OutFile::RobotLog(id) => format!("robot-{id}.log"),
            OutFile::LatencyPlot => "latency.svg".into(),
            OutFile::StepsPlot => "steps.svg".into(),
            OutFile::Paths => "paths.txt".into(),
            OutFile::PhasePaths(p) => format!("paths-phase-{p}.txt"),
            OutFile::LorrOutput => "lorr-output.json".into(),
        }
    }

    /// The file a name stands for; `None` for a name no qfleet process writes.
    pub fn parse(name: &str) -> Option<OutFile> {
        match name {
            "result.json" => return Some(OutFile::Result),
            "plan.json" => return Some(OutFile::Plan),
            "lorr-output.json" => return Some(OutFile::LorrOutput),
            "experiment-checkpoint.json" => return Some(OutFile::ExperimentCheckpoint),
            "coordinator.log" => return Some(OutFile::CoordinatorLog),
            "coordinator-checkpoint.json" => return Some(OutFile::CoordinatorCheckpoint),
            "latency.svg" => return Some(OutFile::LatencyPlot),
            "steps.svg" => return Some(OutFile::StepsPlot),
            "paths.txt" => return Some(OutFile::Paths),
            _ => {}
        }
        if let Some(p) = name
            .strip_prefix("paths-phase-")
            .and_then(|n| n.strip_suffix(".txt"))
        {
            return number(p).map(OutFile::PhasePaths);
        }
        if let Some(p) = name
            .strip_prefix("latency-")
            .and_then(|n| n.strip_suffix(".hgrm"))
        {
            return LatencyPath::parse(p).map(OutFile::Latency);
        }
        let rest = name.strip_prefix("robot-")?;
        let digits = rest
            .find(|c: char| !c.is_ascii_digit())
            .unwrap_or(rest.len());
        let robot = number(&rest[..digits])?;
        match &rest[digits..] {
            ".json" => Some(OutFile::Robot(robot)),
            ".log" => Some(OutFile::RobotLog(robot)),
            "-episodes.csv" => Some(OutFile::RobotEpisodes(robot)),
            tail => {
                if let Some(p) = tail
                    .strip_prefix("-phase-")
                    .and_then(|t| t.strip_suffix(".json"))
                {
                    return Some(OutFile::RobotPhase {
                        robot,
                        phase: number(p)?,
                    });
                }
                let kind = tail.strip_prefix('-')?.strip_suffix(".hdr")?;
                let kind = RobotHist::ALL.into_iter().find(|k| k.as_str() == kind)?;
                Some(OutFile::RobotHist { robot, kind })
            }
        }
    }
}

/// A decimal number as the writer prints it: digits only, no sign, no leading zero.
fn number(s: &str) -> Option<u32> {
    if s.is_empty() || (s.len() > 1 && s.starts_with('0')) || !s.bytes().all(|b| b.is_ascii_digit())
    {
        return None;
    }
    s.parse().ok()
}

/// Why a result file could not be read back.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file is missing or unreadable.
    #[error("reading {}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The file is not the JSON of the expected type.
    #[error("{} is not a valid {what}: {source}", path.display())]
    Json {
        /// The file.
        path: PathBuf,
        /// The type expected.
        what: &'static str,
        /// The decoder's error.
        #[source]
        source: serde_json::Error,
    },
}

/// A run's out directory: its files by [`OutFile`], written atomically, read back typed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutDir {
    root: PathBuf,
}

impl OutDir {
    /// The out directory at `root` (nothing is created yet).
    pub fn new(root: impl Into<PathBuf>) -> Self {
        OutDir { root: root.into() }
    }

    /// The directory itself.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The path of one of its files.
    pub fn path(&self, f: OutFile) -> PathBuf {
        self.root.join(f.name())
    }

    /// The directory of one repetition of an experiment (`seed-<seed>/`).
    pub fn seed_dir(&self, seed: u64) -> OutDir {
        OutDir::new(self.root.join(format!("seed-{seed}")))
    }

    /// Creates the directory (and its parents) if it does not exist.
    pub fn create(&self) -> Result<(), WriteError> {
        std::fs::create_dir_all(&self.root).map_err(|source| WriteError {
            path: self.root.clone(),
            step: crate::atomic::WriteStep::Create,
            source,
        })
    }

    /// Writes `bytes` to file `f` atomically; returns its path.
    pub fn write(&self, f: OutFile, bytes: &[u8]) -> Result<PathBuf, WriteError> {
        let path = self.path(f);
        write_atomic(&path, bytes)?;
        Ok(path)
    }

    /// Writes `value` as pretty JSON to file `f` atomically; returns its path.
    pub fn write_json<T: Serialize + ?Sized>(
        &self,
        f: OutFile,
        value: &T,
    ) -> Result<PathBuf, WriteError> {
        let path = self.path(f);
        write_json_atomic(&path, value)?;
        Ok(path)
    }

    /// Reads file `f` as the JSON of a `T`.
    pub fn read_json<T: DeserializeOwned>(&self, f: OutFile) -> Result<T, ReadError> {
        let path = self.path(f);
        let text = std::fs::read_to_string(&path).map_err(|source| ReadError::Io {
            path: path.clone(),
            source,
        })?;
        serde_json::from_str(&text).map_err(|source| ReadError::Json {
            path,
            what: std::any::type_name::<T>()
                .rsplit("::")
                .next()
                .unwrap_or("value"),
            source,
        })
    }

    /// The files of this directory a qfleet process writes (anything else is left out).
    pub fn list(&self) -> Result<Vec<OutFile>, ReadError> {
        let io = |source| ReadError::Io {
            path: self.root.clone(),
            source,
        };
        let mut out = Vec::new();
        for e in std::fs::read_dir(&self.root).map_err(io)? {
            let e = e.map_err(io)?;
            if let Some(f) = e.file_name().to_str().and_then(OutFile::parse) {
                out.push(f);
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{EndStatus, PhaseDetail};

    fn every_kind() -> Vec<OutFile> {
        let mut v = vec![
            OutFile::Result,
            OutFile::Plan,
            OutFile::ExperimentCheckpoint,
            OutFile::Robot(0),
            OutFile::Robot(255),
            OutFile::RobotPhase {
                robot: 3,
                phase: 12,
            },
            OutFile::RobotEpisodes(7),
            OutFile::CoordinatorLog,
            OutFile::CoordinatorCheckpoint,
            OutFile::RobotLog(10),
            OutFile::LatencyPlot,
            OutFile::StepsPlot,
            OutFile::Paths,
            OutFile::LorrOutput,
            OutFile::PhasePaths(0),
            OutFile::PhasePaths(12),
        ];
        v.extend(LatencyPath::ALL.map(OutFile::Latency));
        v.extend(RobotHist::ALL.map(|kind| OutFile::RobotHist { robot: 1, kind }));
        v
    }

    #[test]
    fn every_name_written_is_recognised_as_the_same_file() {
        for f in every_kind() {
            assert_eq!(OutFile::parse(&f.name()), Some(f), "{}", f.name());
        }
    }

    #[test]
    fn the_names_are_the_ones_readers_and_docs_use() {
        assert_eq!(OutFile::Robot(3).name(), "robot-3.json");
        assert_eq!(
            OutFile::RobotPhase { robot: 3, phase: 1 }.name(),
            "robot-3-phase-1.json"
        );
        assert_eq!(OutFile::RobotEpisodes(3).name(), "robot-3-episodes.csv");
        assert_eq!(
            OutFile::RobotHist {
                robot: 3,
                kind: RobotHist::Merged
            }
            .name(),
            "robot-3-merged.hdr"
        );
        assert_eq!(
            OutFile::Latency(LatencyPath::HintsOneWay).name(),
            "latency-hints_one_way.hgrm"
        );
        assert_eq!(OutFile::RobotLog(2).name(), "robot-2.log");
    }

    #[test]
    fn foreign_names_are_not_taken_for_run_files() {
        for name in [
            "notes.txt",
            "robot-.json",
            "robot-x.json",
            "robot-01.json",
            "robot--1.json",
            "robot-1-phase-.json",
            "robot-1-phase-2.txt",
            "robot-1-fast.hdr",
            "robot-99999999999.json",
            "latency-made_up.hgrm",
            ".result.json.tmp-1-0",
        ] {
            assert_eq!(OutFile::parse(name), None, "{name}");
        }
    }

    #[test]
    fn a_written_file_reads_back_typed_and_a_bad_one_says_which_and_why() {
        let root = std::env::temp_dir().join(format!("qfleet-outdir-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let dir = OutDir::new(&root).seed_dir(4);
        dir.create().unwrap();
        let d = PhaseDetail {
            robot_id: 1,
            phase: 2,
            goal_id: 0,
            start: "0,0".into(),
            goal: "1,1".into(),
            episodes: 3,
            env_steps: 30,
            avg_steps: 10.0,
            optimal_path_len: 2,
            final_path_len: Some(2),
            first_optimal_episode: Some(1),
            steps_to_optimal: Some(20),
            time_to_optimal_s: Some(0.1),
            start_ns: 5,
            episode_end_ns: vec![6, 7, 8],
            episode_cum_steps: vec![10, 20, 30],
            discoveries_sent: 0,
            relays_applied: 0,
            hints_applied: 4,
            finished: true,
        };
        let f = OutFile::RobotPhase { robot: 1, phase: 2 };
        let path = dir.write_json(f, &d).unwrap();
        assert_eq!(path, root.join("seed-4").join("robot-1-phase-2.json"));
        assert_eq!(dir.read_json::<PhaseDetail>(f).unwrap(), d);
        dir.write(OutFile::Robot(1), b"{\"status\": \"finished\"}")
            .unwrap();
        std::fs::write(dir.root().join("unrelated.txt"), "x").unwrap();
        let mut listed = dir.list().unwrap();
        listed.sort_by_key(|f| f.name());
        assert_eq!(
            listed,
            [
                OutFile::RobotPhase { robot: 1, phase: 2 },
                OutFile::Robot(1)
            ]
        );
        let e = dir
            .read_json::<crate::RobotResult>(OutFile::Robot(1))
            .unwrap_err();
        assert!(matches!(e, ReadError::Json { .. }), "{e}");
        assert!(e.to_string().contains("robot-1.json"), "{e}");
        let e = dir.read_json::<EndStatus>(OutFile::Robot(2)).unwrap_err();
        assert!(matches!(e, ReadError::Io { .. }), "{e}");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
