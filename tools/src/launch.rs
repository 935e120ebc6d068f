//! What `qfleet run` and `qfleet experiment` (each repetition) do around the supervision of a
//! run's processes, in one place: claim the run id and clear the leftovers of a crashed run
//! with the same id before any process starts, and remove every shared-memory file of the run
//! after they all ended. Both start the coordinator and the robots through the same
//! [`launcher::supervise`] with a [`launcher::Fleet`] whose coordinator is a process of its own.

use anyhow::{Context, Result, anyhow};
use launcher::Exit;
use launcher::out::{OutArgs, OutDir};
use launcher::run_id::{RunClaim, RunIdError};

use crate::term;

/// Checks `run_id`, claims it exclusively (until the claim is dropped or this process ends,
/// however it ends) and removes what an earlier crashed run with this id left behind; a run
/// id in use (claimed, or with a live process of its run) is bad input.
pub fn claim(run_id: &str) -> Result<RunClaim> {
    launcher::run_id::validate(run_id).context(Exit::BadInput)?;
    bus::validate_run_id(run_id).context(Exit::BadInput)?;
    let claim = RunClaim::acquire(run_id).map_err(|e| match e {
        RunIdError::InUse { .. } | RunIdError::Invalid { .. } => anyhow!(e).context(Exit::BadInput),
        e => anyhow!(e),
    })?;
    // an earlier run with this id that crashed may have left services half-created (iceoryx2
    // then reports them as hanging in creation forever): remove its leftovers before any
    // process of this run exists — unless a process of that run is still alive
    match bus::clean_stale(&bus_schema::names::iceoryx_prefix(run_id)) {
        Ok(r) if !r.alive.is_empty() => {
            return Err(anyhow!(
                "run id {run_id} is in use by a live run ({} process(es) alive); pick another --run-id",
                r.alive.len()
            )
            .context(Exit::BadInput));
        }
        Ok(r) if r.dead_cleaned > 0 || !r.removed.is_empty() => term::warn(&format!(
            "removed the leftovers of an earlier crashed run with id {run_id}"
        )),
        Ok(_) => {}
        Err(e) => term::warn(&format!("warning: cleaning leftovers of run {run_id}: {e}")),
    }
    Ok(claim)
}

/// The out directory of a run, an experiment or a join (`--out`, `--force`; a temporary one
/// named after `tag` without `--out`): a refused `--out` is bad input.
pub fn out_dir(out: &OutArgs, tag: &str) -> Result<OutDir> {
    out.prepare(tag)
        .map_err(|e| crate::classify(e, |e| e.is_bad_input()))
}

/// Removes every shared-memory file of `run_id` once its processes ended; says so when some
/// cannot be removed.
pub fn clean_up(run_id: &str) {
    let prefix = bus_schema::names::iceoryx_prefix(run_id);
    if let Err(e) = bus::clean_stale(&prefix) {
        term::warn(&format!("warning: cleaning up run {run_id}: {e}"));
    }
    let leftovers = bus::leftover_files(&prefix);
    if !leftovers.is_empty() {
        term::warn(&format!(
            "warning: files of run {run_id} left behind: {leftovers:?}"
        ));
    }
}
