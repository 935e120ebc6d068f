//! File output of the coordinator: `result.json` (written atomically through the `report`
//! crate: a temporary file in the same directory, then a rename, so a reader never sees half a
//! result) and one `latency-<path>.hgrm` per measured latency path.

use report::hist;
use report::{OutDir, OutFile};
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
