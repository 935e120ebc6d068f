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
//! process id written in the file, without taking the lock.

use anyhow::{Context, Result, bail};
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
        let mut removed = 0usize;
        // empty node directories carry no run prefix: every clean_stale sweeps them for all runs
        let mut empty_dirs = 0usize;
        let mut live = 0usize;
        // what a dry run would remove
        let mut would = 0usize;
        let mut errors = Vec::new();
        for prefix in &prefixes {
            let files = bus::leftover_files(prefix);
            let run_id = prefix
                .strip_prefix("qfleet.")
                .and_then(|r| r.strip_suffix('.'))
                .unwrap_or(prefix);
            let nodes = match bus::BusConfig::new(run_id, 1)
                .and_then(|cfg| bus::check_nodes(&cfg, false))
            {
                Ok(n) => n,
                Err(e) => {
                    errors.push(format!("run {run_id}: {e}"));
                    continue;
                }
            };
            let alive: Vec<String> = nodes
                .alive()
                .map(|n| format!("{} (pid {})", n.name, n.pid.unwrap_or(-1)))
                .collect();
            if !alive.is_empty() {
                live += 1;
                out!(
                    "run {run_id}: live ({} process(es) alive: {}), left alone",
                    alive.len(),
                    alive.join(", ")
                )?;
                continue;
            }
            if self.dry_run {
                if !files.is_empty() {
                    out!(
                        "run {run_id}: would remove {} file(s) ({} dead process(es)):",
                        files.len(),
                        nodes.dead().count()
                    )?;
                    for f in &files {
                        out!("  {}", f.display())?;
                    }
                    would += files.len();
                }
                would += lock(run_id, true, &mut errors)?;
                continue;
            }
            if files.is_empty() {
                removed += lock(run_id, false, &mut errors)?;
                continue;
            }
            let cleaned = bus::clean_stale(prefix);
            if let Ok(r) = &cleaned {
                empty_dirs += r.empty_node_dirs;
            }
            match cleaned {
                Ok(r) if !r.alive.is_empty() => {
                    live += 1;
                    out!("run {run_id}: came alive meanwhile, left alone")?;
                }
                Ok(r) => {
                    // iceoryx2's dead-node cleanup removes most files itself: report every
                    // file of the run that is gone now, whoever removed it
                    let gone: Vec<_> = files.iter().filter(|f| !f.exists()).collect();
                    out!(
                        "run {run_id}: removed {} file(s), cleaned {} dead process(es):",
                        gone.len(),
                        r.dead_cleaned
                    )?;
                    for f in &gone {
                        out!("  {}", f.display())?;
                    }
                    removed += gone.len();
                    removed += lock(run_id, false, &mut errors)?;
                }
                Err(e) => errors.push(format!("run {run_id}: {e}")),
            }
        }
        if self.dry_run {
            let dirs = bus::stale_empty_node_dirs();
            if !dirs.is_empty() {
                out!(
                    "would remove {} empty iceoryx2 node director(ies) left by killed processes:",
                    dirs.len()
                )?;
                for d in &dirs {
                    out!("  {}", d.display())?;
                }
                would += dirs.len();
            }
        } else {
            // also when no run had anything to clean
            empty_dirs += bus::sweep_empty_node_dirs();
            if empty_dirs > 0 {
                out!(
                    "removed {empty_dirs} empty iceoryx2 node director(ies) left by killed processes"
                )?;
                removed += empty_dirs;
            }
        }
        if removed == 0 && would == 0 && live == 0 {
            out!("nothing to clean")?;
        }
        if !errors.is_empty() {
            bail!("{}", errors.join("; "));
        }
        Ok(())
    }
}

/// Run `run_id`'s launcher lock (see the module doc): with `dry_run`, what removing it would
/// do, told without taking the lock by the launcher's process id written in the file (a file
/// without one, from a launcher killed right after creating it, is removable if no launcher
/// holds it); else removes it if its launcher is gone. Prints what it did or would do and
/// returns how many files that is (0 or 1); an error is kept for the summary.
fn lock(run_id: &str, dry_run: bool, errors: &mut Vec<String>) -> Result<usize> {
    let said = if dry_run {
        launcher::run_id::lock_file(run_id).map(|found| {
            found.map(|(path, pid)| match pid {
                Some(pid) if bus::process_state(pid) == bus::ProcessState::Running => (
                    format!(
                        "its lock {} is held by a live launcher (pid {pid}), left alone",
                        path.display()
                    ),
                    0,
                ),
                Some(_) => (
                    format!("would remove its launcher's stale lock {}", path.display()),
                    1,
                ),
                None => (
                    format!(
                        "would remove its launcher's lock {} unless a live launcher holds it \
                         (no process id in it)",
                        path.display()
                    ),
                    1,
                ),
            })
        })
    } else {
        launcher::run_id::release_stale(run_id).map(|gone| {
            gone.map(|path| {
                let line = format!("removed its launcher's stale lock {}", path.display());
                (line, 1)
            })
        })
    };
    match said {
        Ok(Some((line, n))) => {
            out!("run {run_id}: {line}")?;
            Ok(n)
        }
        Ok(None) => Ok(0),
        Err(e) => {
            errors.push(format!("run {run_id}: {e}"));
            Ok(0)
        }
    }
}
