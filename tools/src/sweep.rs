//! `qfleet sweep`: the measured value of sharing ([`studies::sweep`]); this side starts each
//! fleet run (a coordinator and robot-agents, as `qfleet experiment` does) and prints.

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;

use anyhow::Result;
use clap::Args;
use contract::Rules;
use qfleet_args::Plan;
use report::ExperimentResult;
use studies::sweep::{DEFAULT_PACE, Fleet, FleetRun, SweepError, SweepOptions, replot, sweep};

use crate::experiment::run_once;
use crate::term::{self, out};
use launcher::Supervision;

/// Options of `qfleet sweep`.
#[derive(Debug, Args)]
pub struct SweepCmd {
    /// Manifests (one per map); a manifest whose map or scenario file is missing is skipped.
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Fleet sizes.
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8,16")]
    robots: Vec<u32>,
    /// Sharing modes to compare (the first N = 1 run without sharing is the baseline).
    #[arg(long, value_delimiter = ',', default_value = "none,hints")]
    sharing: Vec<String>,
    /// Seeds (one repetition each).
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    seeds: Vec<u64>,
    /// Seeds of the lone-robot baseline (N = 1, no sharing) when it needs more repetitions
    /// than the other cells (its spread sets the error of every ratio); default: `--seeds`.
    #[arg(long, value_delimiter = ',')]
    baseline_seeds: Vec<u64>,
    /// Sharing rules `APPLY/MERGE` to compare for the modes that share hints (apply: max,
    /// min, blend, latest; merge: max, min, mean, latest; `auto` = the rules that fit the
    /// learner: min/min for planning, max/max for the paper's learners); modes without hints
    /// run once.
    #[arg(long, value_delimiter = ',', default_value = "auto")]
    rules: Vec<Rules>,
    /// Learner of every run, overriding the manifests' `[learner] kind` (its other options
    /// stay).
    #[arg(long)]
    learner: Option<planner::LearnerKind>,
    /// Slow every robot of a run that shares to this many environment steps per second
    /// (robot-agent `--pace`), so that the robots of a run learn at the same time, as a fleet
    /// does: unpaced, a planning robot reaches its optimum within a few scheduler time slices,
    /// and N robots on 2 cores learn mostly one after another (the later ones warm-started from
    /// the earlier ones' fleet table). Runs without sharing are never paced: nothing passes
    /// between their robots, so their env steps are the same at any pace.
    #[arg(long, value_name = "STEPS_PER_S", value_parser = qfleet_args::parse_pace,
          default_value_t = DEFAULT_PACE)]
    pace: f64,
    /// Run every robot as fast as it can (no `--pace`).
    #[arg(long, conflicts_with = "pace")]
    unpaced: bool,
    /// Directory for the runs' files, sweep.json and sweep.md.
    #[arg(long, default_value = "results/sweep")]
    out: PathBuf,
    /// Where to write the SVG plot of speedup against N (default: `speedup.svg` beside
    /// sweep.json).
    #[arg(long)]
    svg: Option<PathBuf>,
    /// Run nothing: redraw the table and the plot from a previous sweep's `sweep.json`.
    #[arg(long)]
    replot: Option<PathBuf>,
}

/// An error of a fleet run or a manifest, kept whole so that its exit code survives the sweep.
#[derive(Debug)]
pub struct RunFailed(anyhow::Error);

impl std::fmt::Display for RunFailed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:#}", self.0)
    }
}

impl std::error::Error for RunFailed {}

/// The sweep's fleet: each run is one repetition of `qfleet experiment` ([`run_once`]).
struct Processes;

impl Fleet<Rules> for Processes {
    type Error = RunFailed;

    fn load(&mut self, file: &Path) -> Result<Plan, RunFailed> {
        Plan::load(file).map_err(|e| RunFailed(e.into()))
    }

    fn run(&mut self, run: &FleetRun<'_, Rules>) -> Result<ExperimentResult, RunFailed> {
        let sup = Supervision {
            pace: run.pace,
            ..Supervision::default()
        };
        let id = launcher::run_id::repetition(Some("sw"), &run.id_tag);
        run_once(run.plan, run.seed, run.rules, &id, run.dir, sup, None, None).map_err(RunFailed)
    }

    fn stopping(&self) -> bool {
        crate::STOP.load(Ordering::SeqCst)
    }

    fn note(&mut self, line: &str) {
        term::warn(line);
    }
}

impl SweepCmd {
    /// Runs the sweep.
    pub fn run(self) -> Result<()> {
        if let Some(json) = &self.replot {
            let done = replot(json, self.svg.as_deref())
                .map_err(|e| crate::classify(e, |e| e.is_bad_input()))?;
            out!("{}", done.markdown.trim_end())?;
            out!("wrote {}", done.svg.display())?;
            return Ok(());
        }
        let opts = SweepOptions {
            files: self.files,
            robots: self.robots,
            sharing: self.sharing,
            seeds: self.seeds,
            baseline_seeds: self.baseline_seeds,
            rules: self.rules,
            learner: self.learner,
            pace: (!self.unpaced).then_some(self.pace),
            out: self.out,
            svg: self.svg,
        };
        let done = sweep(&opts, &mut Processes).map_err(|e| match e {
            // the run's own error, with its exit class (interrupted, bad input, failure)
            SweepError::Run { run, source } => source.0.context(run),
            e => crate::classify(e, |e| e.is_bad_input()),
        })?;
        out!("{}", done.markdown.trim_end())?;
        out!(
            "wrote {}/sweep.{{md,json}} and {}",
            opts.out.display(),
            done.svg.display()
        )?;
        Ok(())
    }
}
