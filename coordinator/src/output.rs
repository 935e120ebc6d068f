//! File output of the coordinator: `result.json` (written atomically through the `report`
//! crate: a temporary file in the same directory, then a rename, so a reader never sees half a
//! result) and, for a run, one `latency-<path>.hgrm` per measured latency path. (An
//! experiment's `experiment-checkpoint.json` is written by its driver through the same writer.)

use report::hist;
/// The out directory and its file names, as launchers read what the coordinator wrote.
pub use report::{OutDir, OutFile};
use serde::Serialize;

use crate::assemble::FleetHists;
use crate::engine::Engine;
use crate::options::CoordError;

/// Writes `result.json` into `dir`. When that fails (a full disk), the result also goes to the
/// launcher on stdout as one `result <json>` line (`contract::lines`), so that the run's
/// result is not lost with the file; the error is returned all the same.
fn write_result(dir: &OutDir, result: &impl Serialize) -> Result<(), CoordError> {
    let Err(e) = dir.write_json(OutFile::Result, result) else {
        return Ok(());
    };
    if let Ok(json) = serde_json::to_string(result) {
        use std::io::Write as _;
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "{}", contract::lines::result_line(&json));
        let _ = out.flush();
    }
    Err(e.into())
}

/// Writes a run's `result.json` and its `.hgrm` latency files into `dir`.
pub(crate) fn write_run(
    dir: &OutDir,
    result: &impl Serialize,
    engine: &Engine,
    hists: &FleetHists,
) -> Result<(), CoordError> {
    write_result(dir, result)?;
    for (path, h) in hists.paths(engine) {
        hist::write_hgrm(h, &dir.path(OutFile::Latency(path)))?;
    }
    Ok(())
}

/// Writes an experiment's `result.json` into `dir`.
pub fn write_experiment(
    dir: &OutDir,
    result: &report::run::ExperimentResult,
) -> Result<(), CoordError> {
    write_result(dir, result)?;
    Ok(())
}
