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

/// Writes a run's `result.json` and its `.hgrm` latency files into `dir`.
pub(crate) fn write_run(
    dir: &OutDir,
    result: &impl Serialize,
    engine: &Engine,
    hists: &FleetHists,
) -> Result<(), CoordError> {
    dir.write_json(OutFile::Result, result)?;
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
    dir.write_json(OutFile::Result, result)?;
    Ok(())
}
