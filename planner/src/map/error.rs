//! What can go wrong reading a map or scenario file, and where in the file it went wrong.

use super::BUILTIN_MAPS;
use crate::grid::GridError;
use std::fmt;
use std::io;
use std::path::PathBuf;

/// A place in a map or scenario file, printed `file:line:column` so editors can jump to it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// The file name (or other source name) the parser was given.
    pub file: String,
    /// 1-based line number, when the problem sits on one line.
    pub line: Option<usize>,
    /// 1-based column in characters, when the problem sits at one place on the line.
    pub column: Option<usize>,
}

impl Location {
    /// The whole file, for problems that belong to no single line.
    pub fn file(file: &str) -> Location {
        Location {
            file: file.to_owned(),
            line: None,
            column: None,
        }
    }

    /// A whole line (1-based), for problems such as a row of the wrong width.
    pub fn line(file: &str, line: usize) -> Location {
        Location {
            file: file.to_owned(),
            line: Some(line),
            column: None,
        }
    }

    /// One character (1-based line and column), for problems such as an unknown character.
    pub fn at(file: &str, line: usize, column: usize) -> Location {
        Location {
            file: file.to_owned(),
            line: Some(line),
            column: Some(column),
        }
    }
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.file)?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
            if let Some(column) = self.column {
                write!(f, ":{column}")?;
            }
        }
        Ok(())
    }
}

/// Why a map or scenario could not be loaded; parse errors carry the [`Location`] to fix.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// The file could not be read: missing, a directory, no permission, ...
    #[error("{}: cannot read: {source}", path.display())]
    Io {
        /// The path that was asked for.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: io::Error,
    },
    /// `builtin:NAME` names no built-in map.
    #[error("unknown built-in map '{name}' (built-in maps: {})", BUILTIN_MAPS.join(", "))]
    UnknownBuiltin {
        /// The name asked for, without the `builtin:` prefix.
        name: String,
    },
    /// `suite:SPEC` names no generated map of the suite.
    #[error(transparent)]
    Suite(#[from] crate::suite::SpecError),
    /// The file holds no map rows or no scenario header: only blank lines or comments.
    #[error("{at}: empty file: {expected}")]
    Empty {
        /// The file.
        at: Location,
        /// What the file should have held.
        expected: &'static str,
    },
    /// A byte sequence that is not UTF-8 text.
    #[error("{at}: invalid UTF-8 (map and scenario files are text)")]
    NotUtf8 {
        /// The first bad byte.
        at: Location,
    },
    /// A map character outside the format's alphabet.
    #[error("{at}: unknown character {found:?} (expected {expected})")]
    UnknownChar {
        /// The character.
        at: Location,
        /// The character found.
        found: char,
        /// The characters the format allows, for the message.
        expected: &'static str,
    },
    /// A map row wider or narrower than the first row (ASCII) or the header's width (MovingAI).
    #[error("{at}: row is {found} cells wide, expected {expected} (maps must be rectangular)")]
    Ragged {
        /// The row, and the column where it stops matching.
        at: Location,
        /// Cells in this row.
        found: usize,
        /// Cells every row must have.
        expected: usize,
    },
    /// A MovingAI map with fewer or more rows than its `height` line says.
    #[error("{at}: the header says height {declared} but the map has {found} rows")]
    RowCount {
        /// The first extra row, or the end of the file when rows are missing.
        at: Location,
        /// Rows the header promised.
        declared: usize,
        /// Rows present.
        found: usize,
    },
    /// A missing or garbled header line (`type`/`height`/`width`/`map`, or `version 1`).
    #[error("{at}: expected {expected}, found {found}")]
    Header {
        /// The offending line or token.
        at: Location,
        /// What should have been there.
        expected: &'static str,
        /// What was there, quoted, or `the end of the file`.
        found: String,
    },
    /// The map is empty or larger than [`crate::grid::MAX_SIDE`] / [`crate::grid::MAX_CELLS`].
    #[error("{at}: {error}")]
    Grid {
        /// The header line that sets the size, or the whole file.
        at: Location,
        /// The grid's own complaint.
        error: GridError,
    },
    /// An ASCII map with more than one `S`.
    #[error("{at}: a second start 'S' (the first is at line {first_line}, column {first_column})")]
    DuplicateStart {
        /// The second `S`.
        at: Location,
        /// Line of the first `S`.
        first_line: usize,
        /// Column of the first `S`.
        first_column: usize,
    },
    /// A scenario line without exactly nine fields.
    #[error(
        "{at}: expected 9 tab-separated fields (bucket, map, width, height, start_x, start_y, goal_x, goal_y, optimal_length), found {found}"
    )]
    FieldCount {
        /// The line.
        at: Location,
        /// Fields found.
        found: usize,
    },
    /// A scenario field that is not a number, or is out of range.
    #[error("{at}: {field}: {problem}")]
    BadField {
        /// The field's first character.
        at: Location,
        /// The field's name in the MovingAI format.
        field: &'static str,
        /// What is wrong with it.
        problem: String,
    },
}

impl MapError {
    /// Where in the file the problem is, for parse errors (not for I/O, unknown built-ins or
    /// suite specs).
    pub fn location(&self) -> Option<&Location> {
        match self {
            MapError::Io { .. } | MapError::UnknownBuiltin { .. } | MapError::Suite(_) => None,
            MapError::Empty { at, .. }
            | MapError::NotUtf8 { at }
            | MapError::UnknownChar { at, .. }
            | MapError::Ragged { at, .. }
            | MapError::RowCount { at, .. }
            | MapError::Header { at, .. }
            | MapError::Grid { at, .. }
            | MapError::DuplicateStart { at, .. }
            | MapError::FieldCount { at, .. }
            | MapError::BadField { at, .. } => Some(at),
        }
    }
}
