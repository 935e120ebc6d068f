//! The robot's files in `--out`: a detail file per phase, its result, the last phase's episodes
//! and two latency histograms. A file that cannot be written (a full disk) does not stop the
//! robot: its reports still reach the coordinator, and it exits with the first such error.

use planner::EpisodeRecord;
use report::hist;
use report::{OutDir, OutFile, RobotHist, RobotResult};

use crate::error::AgentError;

use super::{Phase, Robot};

impl Robot<'_> {
    /// Keeps the first failure to write a result file for the end of the run (see
    /// [`Robot::unwritten`]) and says it now.
    pub(super) fn unwritten(&mut self, written: Result<(), AgentError>) {
        if let Err(e) = written {
            report::log_line!(
                "robot-agent {}: error: {e}; the robot goes on so its report still reaches the coordinator",
                self.args.robot_id
            );
            self.unwritten.get_or_insert(e);
        }
    }

    /// `robot-<id>-phase-<n>.json`: what the robot learned in phase `p`.
    pub(super) fn write_phase_file(&self, p: &mut Phase) -> Result<(), AgentError> {
        let Some(dir) = &self.args.out else {
            return Ok(());
        };
        let dir = OutDir::new(dir);
        dir.create()?;
        let f = OutFile::RobotPhase {
            robot: self.args.robot_id,
            phase: p.a.phase,
        };
        dir.write_json(f, &self.phase_detail(p))?;
        Ok(())
    }

    /// `robot-<id>.json`, the last phase's episodes and the two latency histograms.
    pub(super) fn write_files(
        &self,
        r: &RobotResult,
        records: &[EpisodeRecord],
    ) -> Result<(), AgentError> {
        let Some(dir) = &self.args.out else {
            return Ok(());
        };
        let dir = OutDir::new(dir);
        dir.create()?;
        let robot = self.args.robot_id;
        dir.write_json(OutFile::Robot(robot), r)?;
        let mut csv = Vec::with_capacity(records.len() * 24);
        // writing into a Vec cannot fail
        if planner::metrics::write_episodes_csv(&mut csv, records).is_ok() {
            dir.write(OutFile::RobotEpisodes(robot), &csv)?;
        }
        for (kind, h) in [
            (RobotHist::Loop, self.applier.loop_hist()),
            (RobotHist::Merged, &self.merged_hist),
        ] {
            hist::write_binary(h, &dir.path(OutFile::RobotHist { robot, kind }))?;
        }
        Ok(())
    }
}
