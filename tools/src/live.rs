//! The launcher side of `--live` and `--record FILE.mcap` (`qfleet run`, `qfleet experiment`):
//! start an `observe::watch` thread before the run's processes, finish it after they exited
//! and before the run's files are removed. Everything else lives in the `observe` crate.

use std::path::PathBuf;

use anyhow::{Context, Result};
use observe::watch::{Watch, WatchOptions, run_info, start as start_watch};
use planner::task::Task;

/// A watch thread, if `--live` or `--record` asked for one.
pub struct Hook {
    watch: Option<Watch>,
    record: Option<PathBuf>,
}

/// Starts watching run `run_id` on `task` when `live` or `record` is set; `config` goes into
/// the recording's metadata; `on_quit` is the launcher's graceful stop (what Ctrl-C does). A
/// recording file that cannot be created is bad input: nothing of the run has started yet.
pub fn start(
    run_id: &str,
    task: &Task,
    config: Vec<(String, String)>,
    live: bool,
    record: Option<PathBuf>,
    on_quit: Box<dyn Fn() + Send>,
) -> Result<Hook> {
    let opts = WatchOptions {
        live,
        record: record.clone(),
    };
    let watch = match opts.any() {
        true => Some(
            start_watch(run_id, task, run_info(run_id, task, config), opts, on_quit)
                .context("starting the recording")
                .context(launcher::Exit::BadInput)?,
        ),
        false => None,
    };
    Ok(Hook { watch, record })
}

impl Hook {
    /// Waits (up to `timeout_s` seconds, the run's start-up budget; 30 s if that is not a
    /// valid duration) until the watch thread has joined the run, so a recording or the live
    /// view misses nothing the robots send; the launcher calls it once the coordinator runs and
    /// before it starts the robots ([`launcher::Fleet::before_robots`]). A watch that could not
    /// join in time is a warning: the run goes on unobserved so far.
    pub fn wait_joined(&self, timeout_s: f64) {
        let timeout = std::time::Duration::try_from_secs_f64(timeout_s)
            .unwrap_or(std::time::Duration::from_secs(30));
        if let Some(w) = &self.watch
            && !w.wait_joined(timeout)
        {
            crate::term::warn(&format!(
                "warning: the live view / recorder did not join the run within {} s; it may miss its first messages",
                timeout.as_secs()
            ));
        }
    }
}

/// Ends the watch: returns whether the user pressed `q` in the live view, and says on stderr
/// where the recording went.
pub fn finish(hook: Hook) -> Result<bool> {
    let Some(w) = hook.watch else {
        return Ok(false);
    };
    let r = match &hook.record {
        Some(p) => w
            .finish()
            .with_context(|| format!("watching the run (recording to {})", p.display()))?,
        None => w.finish().context("watching the run")?,
    };
    if let Some(p) = &hook.record {
        crate::term::warn(&format!(
            "recorded {} messages to {}",
            r.recorded,
            p.display()
        ));
    }
    Ok(r.quit)
}

/// A task for the live view of an experiment: its map, the first robot's start and the first
/// goal (the robots' own starts and goals arrive on the bus).
pub fn experiment_task(plan: &qfleet_args::Plan) -> Task {
    let start = plan
        .starts
        .first()
        .copied()
        .unwrap_or(planner::grid::Cell::new(0, 0));
    let goal = plan.goal_cells.first().copied().unwrap_or(start);
    Task {
        map_name: plan.map.name.clone(),
        grid: plan.map.grid.clone(),
        start,
        goal,
        optimal_len: plan
            .optimal
            .first()
            .and_then(|o| o.first())
            .copied()
            .unwrap_or(1),
    }
}
