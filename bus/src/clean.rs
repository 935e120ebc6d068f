//! What `qfleet clean` does with the leftovers of crashed runs, run by run ([`clean_runs`]):
//! a run with a live process is left alone and named; otherwise its dead nodes are cleaned
//! through iceoryx2 and its remaining files removed ([`crate::clean_stale`]), or with
//! `dry_run` only listed; empty node directories of killed processes go too. The launcher's
//! lock file of each run is the caller's (the launcher crate's), handled through `lock`.

use crate::{BusConfig, check_nodes, clean_stale, leftover_files};

/// What writing a line of the report can fail with (stdout closed or full).
pub type SayError = Box<dyn std::error::Error + Send + Sync>;

/// What is done about a run's launcher lock: `lock(run_id, dry_run)` says what it did or would
/// do as a line and how many files that is (0 or 1), or why it could not.
pub type LockFn<'a> = dyn FnMut(&str, bool) -> Result<Option<(String, usize)>, String> + 'a;

/// The run id of an iceoryx2 prefix `qfleet.<run-id>.` (the prefix itself if it is not one).
pub fn run_id_of(prefix: &str) -> &str {
    prefix
        .strip_prefix("qfleet.")
        .and_then(|r| r.strip_suffix('.'))
        .unwrap_or(prefix)
}

/// Cleans (or with `dry_run` lists) what the runs of `prefixes` left behind, saying each
/// line to `say`; returns the errors met on the way (one line each, for the summary), or the
/// error of writing a line.
pub fn clean_runs(
    prefixes: &[String],
    dry_run: bool,
    lock: &mut LockFn<'_>,
    say: &mut dyn FnMut(String) -> Result<(), SayError>,
) -> Result<Vec<String>, SayError> {
    let mut removed = 0usize;
    // empty node directories carry no run prefix: every clean_stale sweeps them for all runs
    let mut empty_dirs = 0usize;
    let mut live = 0usize;
    // what a dry run would remove
    let mut would = 0usize;
    let mut errors = Vec::new();
    let mut lock_said = |run_id: &str,
                         dry: bool,
                         errors: &mut Vec<String>,
                         say: &mut dyn FnMut(String) -> Result<(), SayError>|
     -> Result<usize, SayError> {
        match lock(run_id, dry) {
            Ok(Some((line, n))) => {
                say(format!("run {run_id}: {line}"))?;
                Ok(n)
            }
            Ok(None) => Ok(0),
            Err(e) => {
                errors.push(format!("run {run_id}: {e}"));
                Ok(0)
            }
        }
    };
    for prefix in prefixes {
        let files = leftover_files(prefix);
        let run_id = run_id_of(prefix);
        let nodes = match BusConfig::new(run_id, 1).and_then(|cfg| check_nodes(&cfg, false)) {
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
            say(format!(
                "run {run_id}: live ({} process(es) alive: {}), left alone",
                alive.len(),
                alive.join(", ")
            ))?;
            continue;
        }
        if dry_run {
            if !files.is_empty() {
                say(format!(
                    "run {run_id}: would remove {} file(s) ({} dead process(es)):",
                    files.len(),
                    nodes.dead().count()
                ))?;
                for f in &files {
                    say(format!("  {}", f.display()))?;
                }
                would += files.len();
            }
            would += lock_said(run_id, true, &mut errors, say)?;
            continue;
        }
        if files.is_empty() {
            removed += lock_said(run_id, false, &mut errors, say)?;
            continue;
        }
        let cleaned = clean_stale(prefix);
        if let Ok(r) = &cleaned {
            empty_dirs += r.empty_node_dirs;
        }
        match cleaned {
            Ok(r) if !r.alive.is_empty() => {
                live += 1;
                say(format!("run {run_id}: came alive meanwhile, left alone"))?;
            }
            Ok(r) => {
                // iceoryx2's dead-node cleanup removes most files itself: report every
                // file of the run that is gone now, whoever removed it
                let gone: Vec<_> = files.iter().filter(|f| !f.exists()).collect();
                say(format!(
                    "run {run_id}: removed {} file(s), cleaned {} dead process(es):",
                    gone.len(),
                    r.dead_cleaned
                ))?;
                for f in &gone {
                    say(format!("  {}", f.display()))?;
                }
                removed += gone.len();
                removed += lock_said(run_id, false, &mut errors, say)?;
            }
            Err(e) => errors.push(format!("run {run_id}: {e}")),
        }
    }
    if dry_run {
        let dirs = crate::stale_empty_node_dirs();
        if !dirs.is_empty() {
            say(format!(
                "would remove {} empty iceoryx2 node director(ies) left by killed processes:",
                dirs.len()
            ))?;
            for d in &dirs {
                say(format!("  {}", d.display()))?;
            }
            would += dirs.len();
        }
    } else {
        // also when no run had anything to clean
        empty_dirs += crate::sweep_empty_node_dirs();
        if empty_dirs > 0 {
            say(format!(
                "removed {empty_dirs} empty iceoryx2 node director(ies) left by killed processes"
            ))?;
            removed += empty_dirs;
        }
    }
    if removed == 0 && would == 0 && live == 0 {
        say("nothing to clean".to_string())?;
    }
    Ok(errors)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_prefix_names_its_run() {
        assert_eq!(run_id_of("qfleet.run-7."), "run-7");
        assert_eq!(run_id_of("other"), "other");
    }
}
