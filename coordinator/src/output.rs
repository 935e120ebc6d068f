//! File output of the coordinator: `result.json` (written atomically: a temporary file in the
//! same directory, then a rename, so a reader never sees half a result) and one
//! `latency-<path>.hgrm` per measured latency path.

use std::path::{Path, PathBuf};

use robot_agent::hist;
use serde::Serialize;

use crate::assemble::FleetHists;
use crate::engine::Engine;
use crate::options::CoordError;

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CoordError + '_ {
    move |source| CoordError::Output {
        path: path.to_path_buf(),
        source,
    }
}

/// Creates the output directory (and its parents).
pub(crate) fn create_dir(dir: &Path) -> Result<(), CoordError> {
    std::fs::create_dir_all(dir).map_err(io(dir))
}

/// Writes `value` as pretty JSON to `path` atomically (temporary file + rename).
pub fn write_json_atomic(path: &Path, value: &impl Serialize) -> Result<(), CoordError> {
    let json = serde_json::to_string_pretty(value)?;
    let mut tmp = PathBuf::from(path);
    tmp.as_mut_os_string().push(".tmp");
    std::fs::write(&tmp, json).map_err(io(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io(path))
}

/// Writes a run's `result.json` and its `.hgrm` latency files into `dir`.
pub(crate) fn write_run(
    dir: &Path,
    result: &impl Serialize,
    engine: &Engine,
    hists: &FleetHists,
) -> Result<(), CoordError> {
    write_json_atomic(&dir.join("result.json"), result)?;
    for (k, h) in hists.paths(engine) {
        hist::write_hgrm(h, &dir.join(format!("latency-{k}.hgrm")))?;
    }
    Ok(())
}
