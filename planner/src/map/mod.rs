//! Maps: the ASCII and MovingAI file formats, MovingAI scenarios, the built-in maps, and
//! loading any of them by name or path.
//!
//! Every parser takes the file's bytes and a source name for messages, never panics, and
//! reports problems as [`MapError`]s that name the file, line and column to fix.

mod ascii;
mod builtin;
mod error;
mod file;
mod movingai;
mod text;

pub use ascii::parse_ascii;
pub use builtin::{BUILTIN_MAPS, PAPER_10, PAPER_20, PAPER_30, builtin, builtin_text};
pub use error::{Location, MapError};
pub use file::{MAX_MAP_BYTES, MAX_SCEN_BYTES, read_bounded};
pub use movingai::{Scenario, parse_movingai_map, parse_scen};

use crate::grid::{Cell, Grid};
use std::path::Path;

/// A parsed map: the grid plus the start and goals the file marks, if any.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GridMap {
    /// A short name for reports: the built-in name, or the file name without its extension.
    pub name: String,
    /// The occupancy grid.
    pub grid: Grid,
    /// The `S` cell of an ASCII map; `None` when the file marks none (always, for MovingAI).
    pub start: Option<Cell>,
    /// The `G` cells of an ASCII map in reading order; the first is the default goal.
    pub goals: Vec<Cell>,
}

impl GridMap {
    /// The share of cells that are obstacles, in `[0, 1]`.
    pub fn obstacle_fraction(&self) -> f64 {
        let blocked = self.grid.len() - self.grid.free_count();
        blocked as f64 / self.grid.len() as f64
    }

    /// The map as ASCII text that [`parse_ascii`] reads back to the same grid, start and goals.
    ///
    /// A cell that is both start and a goal (possible only in a map built in code) is written
    /// as `S`.
    pub fn to_ascii(&self) -> String {
        let g = &self.grid;
        let mut out = String::with_capacity((g.width() + 1) * g.height());
        let mut marks = vec![None; g.len()];
        for goal in self.goals.iter().filter(|c| g.is_free(**c)) {
            marks[g.index(*goal)] = Some('G');
        }
        if let Some(s) = self.start.filter(|c| g.is_free(*c)) {
            marks[g.index(s)] = Some('S');
        }
        for (i, (free, mark)) in g.free_flags().iter().zip(&marks).enumerate() {
            out.push(match (free, mark) {
                (_, Some(m)) => *m,
                (true, None) => '.',
                (false, None) => '#',
            });
            if (i + 1) % g.width() == 0 {
                out.push('\n');
            }
        }
        out
    }

    /// The grid as a MovingAI `.map` file (`.` free, `@` blocked); start and goals are dropped.
    pub fn to_movingai(&self) -> String {
        let g = &self.grid;
        let mut out = format!(
            "type octile\nheight {}\nwidth {}\nmap\n",
            g.height(),
            g.width()
        );
        for (i, free) in g.free_flags().iter().enumerate() {
            out.push(if *free { '.' } else { '@' });
            if (i + 1) % g.width() == 0 {
                out.push('\n');
            }
        }
        out
    }
}

/// The map name for a source: the file name without directory or extension.
pub(crate) fn name_from_source(source: &str) -> String {
    Path::new(source)
        .file_stem()
        .map_or_else(|| source.to_owned(), |s| s.to_string_lossy().into_owned())
}

/// Reads a whole map or scenario file of at most `limit` bytes ([`read_bounded`]: regular
/// files only, never blocking on a FIFO), turning any failure into [`MapError::Io`].
fn read_file(path: &Path, limit: u64) -> Result<Vec<u8>, MapError> {
    read_bounded(path, limit).map_err(|source| MapError::Io {
        path: path.to_owned(),
        source,
    })
}

/// Whether a file is in the MovingAI format: a `.map` extension or a first line `type ...`.
fn is_movingai(path: &Path, bytes: &[u8]) -> bool {
    let ext_map = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("map"));
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    ext_map || bytes.starts_with(b"type ")
}

/// Loads a map from `builtin:NAME`, `suite:FAMILY-SIZE-INDEX[@SEED]` (a generated map of the
/// suite, with its far pair as start and goal) or a file path, picking the format as the user
/// would.
///
/// `.map` files and files whose first line starts with `type ` are MovingAI maps; any other file
/// is an ASCII map.
pub fn load_map(spec: &str) -> Result<GridMap, MapError> {
    if let Some(name) = spec.strip_prefix("builtin:") {
        return builtin(name).ok_or_else(|| MapError::UnknownBuiltin {
            name: name.to_owned(),
        });
    }
    if let Some(name) = spec.strip_prefix("suite:") {
        let t = crate::suite::from_spec(name)?;
        return Ok(GridMap {
            name: t.id,
            grid: t.task.grid,
            start: Some(t.task.start),
            goals: vec![t.task.goal],
        });
    }
    let path = Path::new(spec);
    let bytes = read_file(path, MAX_MAP_BYTES)?;
    if is_movingai(path, &bytes) {
        parse_movingai_map(spec, &bytes)
    } else {
        parse_ascii(spec, &bytes)
    }
}

/// Loads a MovingAI `.scen` file.
pub fn load_scen(path: &Path) -> Result<Vec<Scenario>, MapError> {
    let bytes = read_file(path, MAX_SCEN_BYTES)?;
    parse_scen(&path.display().to_string(), &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::{fs, io};

    #[test]
    fn dev_zero_and_a_fifo_as_map_or_scenario_are_refused_at_once() {
        for e in [
            load_map("/dev/zero").unwrap_err(),
            load_scen(Path::new("/dev/zero")).unwrap_err(),
        ] {
            assert!(e.to_string().contains("not a regular file"), "{e}");
        }
        #[cfg(unix)]
        {
            let dir = temp_dir("fifo");
            let fifo = dir.join("map.txt");
            let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
            // SAFETY: a valid NUL-terminated path.
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
            let e = load_map(fifo.to_str().unwrap()).unwrap_err();
            assert!(e.to_string().contains("FIFO"), "{e}");
            fs::remove_dir_all(&dir).unwrap();
        }
    }

    fn temp_dir(tag: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("planner-map-{tag}-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn loads_builtins_and_rejects_unknown_ones() {
        let m = load_map("builtin:paper-10").unwrap();
        assert_eq!(m.name, "paper-10");
        let e = load_map("builtin:paper-11").unwrap_err();
        assert!(matches!(e, MapError::UnknownBuiltin { .. }), "{e}");
        assert!(
            e.to_string().contains("paper-10, paper-20, paper-30"),
            "{e}"
        );
        assert!(e.location().is_none());
    }

    #[test]
    fn missing_file_names_the_path() {
        let e = load_map("/nonexistent/qfleet/a.txt").unwrap_err();
        assert!(matches!(e, MapError::Io { .. }), "{e}");
        assert!(
            e.to_string()
                .starts_with("/nonexistent/qfleet/a.txt: cannot read"),
            "{e}"
        );
        let e = load_scen(Path::new("/nonexistent/qfleet/a.scen")).unwrap_err();
        assert!(matches!(e, MapError::Io { .. }), "{e}");
    }

    #[test]
    fn directory_instead_of_file() {
        let dir = temp_dir("dir");
        let spec = dir.display().to_string();
        let e = load_map(&spec).unwrap_err();
        assert!(
            matches!(&e, MapError::Io { source, .. } if source.kind() == io::ErrorKind::IsADirectory),
            "{e}"
        );
        assert!(e.to_string().contains("is a directory"), "{e}");
        assert!(e.to_string().starts_with(&spec), "{e}");
        let e = load_scen(&dir).unwrap_err();
        assert!(matches!(e, MapError::Io { .. }), "{e}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn picks_the_format_by_extension_or_first_line() {
        let dir = temp_dir("fmt");
        let movingai = "type octile\nheight 1\nwidth 2\nmap\n.@\n";
        for (file, text, movingai_expected) in [
            ("a.map", movingai, true),
            ("a.MAP", movingai, true),
            ("b.txt", movingai, true),
            ("c.txt", "S#G\n", false),
            ("d", "S.G\n", false),
        ] {
            let path = dir.join(file);
            fs::write(&path, text).unwrap();
            let m = load_map(path.to_str().unwrap()).unwrap();
            assert_eq!(m.start.is_none(), movingai_expected, "{file}");
            assert_eq!(
                m.name,
                Path::new(file).file_stem().unwrap().to_str().unwrap()
            );
        }
        // A .map file in ASCII form is read as MovingAI and fails with a header error.
        let path = dir.join("e.map");
        fs::write(&path, "S.G\n").unwrap();
        let e = load_map(path.to_str().unwrap()).unwrap_err();
        assert!(matches!(e, MapError::Header { .. }), "{e}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn to_ascii_and_to_movingai_read_back() {
        for name in BUILTIN_MAPS {
            let m = builtin(name).unwrap();
            let back = parse_ascii(name, m.to_ascii().as_bytes()).unwrap();
            assert_eq!(back, m);
            let back = parse_movingai_map(name, m.to_movingai().as_bytes()).unwrap();
            assert_eq!(back.grid, m.grid);
        }
    }
}
