//! `qfleet clean`: remove what crashed runs left in shared memory, never touching a live run.
//!
//! A run killed with SIGKILL (or a machine that lost power) leaves files in `/dev/shm` and under
//! iceoryx2's root (`/tmp/iceoryx2/`), all named with the run's prefix `qfleet.<run-id>.`. For
//! every such prefix (or the one of `--run-id`), the run's iceoryx2 nodes are listed first: if
//! any process of the run is alive the run is left alone and reported; otherwise dead nodes are
//! cleaned through iceoryx2 and the remaining files removed (`bus::clean_stale`). Leftovers never
//! block a new run (iceoryx2 cleans dead nodes when a node is created), but they take shared
//! memory until removed. A killed launcher also leaves its run's lock file in
//! `/tmp/qfleet-<uid>/`; a lock file nobody holds is removed with the rest (one a live launcher
//! holds is left alone), also for runs that never reached shared memory. Empty iceoryx2 node
//! directories older than `bus::EMPTY_NODE_DIR_AGE` go too (`bus::sweep_empty_node_dirs`).
//! `--dry-run` lists all of it and removes nothing; it tells a stale lock by the launcher's
//! process id written in the file, without taking the lock. The work is `bus::clean::clean_runs`,
//! the lock's part `launcher::run_id::lock_note`.

use anyhow::{Context, Result, anyhow, bail};
use clap::Args;

use crate::term::out;

/// Options of `qfleet clean`.
#[derive(Debug, Args)]
pub struct CleanCmd {
    /// Only this run (default: every qfleet run with files left).
    #[arg(long)]
    run_id: Option<String>,
    /// Print what would be removed, remove nothing.
    #[arg(long)]
    dry_run: bool,
}

impl CleanCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        let prefixes = match &self.run_id {
            Some(id) => {
                launcher::run_id::validate(id).context(launcher::Exit::BadInput)?;
                bus::validate_run_id(id)?;
                vec![bus_schema::names::iceoryx_prefix(id)]
            }
            None => {
                let mut p = bus::find_run_prefixes();
                // runs whose launcher died before any process made a file in shared memory
                for id in launcher::run_id::claimed_ids() {
                    let prefix = bus_schema::names::iceoryx_prefix(&id);
                    if !p.contains(&prefix) {
                        p.push(prefix);
                    }
                }
                p
            }
        };
        let running = |pid| bus::process_state(pid) == bus::ProcessState::Running;
        let mut lock = |run_id: &str, dry_run: bool| {
            launcher::run_id::lock_note(run_id, dry_run, &running).map_err(|e| e.to_string())
        };
        let mut say = |line: String| -> Result<(), bus::clean::SayError> { Ok(out!("{line}")?) };
        let errors = bus::clean::clean_runs(&prefixes, self.dry_run, &mut lock, &mut say)
            .map_err(|e| anyhow!(e))?;
        if !errors.is_empty() {
            bail!("{}", errors.join("; "));
        }
        Ok(())
    }
}
