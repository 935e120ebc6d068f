//! The project's ASCII map format, written by hand and embedded for the built-in maps.
//!
//! ```text
//! ; a comment: any line starting with ';'
//! S..#
//! .#.G
//! ```
//!
//! `#` is an obstacle, `.` a free cell, `S` the start (free; at most one), `G` a goal (free; any
//! number). Rows must all be as wide as the first. A trailing `\r` on a line, a byte-order mark,
//! and blank lines before the first row or after the last are ignored; a blank line between rows
//! is an error, since it would silently split the map.

use super::text::lines;
use super::{GridMap, Location, MapError, name_from_source};
use crate::grid::{Cell, Grid};

/// The characters an ASCII map may hold, for error messages.
const EXPECTED: &str = "'#', '.', 'S' or 'G'";

/// Parses an ASCII map; `source` names the file in error messages and gives the map its name.
///
/// A map without `S` gets `start: None` and one without `G` gets no goals: the caller may give
/// them separately (see [`crate::task::resolve_task`]).
pub fn parse_ascii(source: &str, bytes: &[u8]) -> Result<GridMap, MapError> {
    let mut free = Vec::new();
    let mut width: Option<usize> = None;
    let mut height = 0usize;
    // (x, y, line, column) of the `S`.
    let mut start: Option<(usize, usize, usize, usize)> = None;
    let mut goals = Vec::new();
    let mut blank_after_rows: Option<usize> = None;

    for line in lines(source, bytes) {
        let line = line?;
        if line.text.starts_with(';') {
            continue;
        }
        if line.is_blank() {
            if width.is_some() && blank_after_rows.is_none() {
                blank_after_rows = Some(line.number);
            }
            continue;
        }
        if let Some(blank) = blank_after_rows {
            return Err(MapError::Ragged {
                at: Location::line(source, blank),
                found: 0,
                expected: width.unwrap_or(0),
            });
        }
        let y = height;
        let mut row_width = 0;
        for (x, ch) in line.text.chars().enumerate() {
            let column = x + 1;
            match ch {
                '#' => free.push(false),
                '.' => free.push(true),
                'S' => {
                    if let Some((_, _, first_line, first_column)) = start {
                        return Err(MapError::DuplicateStart {
                            at: Location::at(source, line.number, column),
                            first_line,
                            first_column,
                        });
                    }
                    start = Some((x, y, line.number, column));
                    free.push(true);
                }
                'G' => {
                    goals.push((x, y));
                    free.push(true);
                }
                found => {
                    return Err(MapError::UnknownChar {
                        at: Location::at(source, line.number, column),
                        found,
                        expected: EXPECTED,
                    });
                }
            }
            row_width = column;
        }
        match width {
            None => width = Some(row_width),
            Some(expected) if expected != row_width => {
                return Err(MapError::Ragged {
                    at: Location::at(source, line.number, expected.min(row_width) + 1),
                    found: row_width,
                    expected,
                });
            }
            Some(_) => {}
        }
        height += 1;
    }

    let Some(width) = width else {
        return Err(MapError::Empty {
            at: Location::file(source),
            expected: "no map rows (expected rows of '#', '.', 'S' and 'G')",
        });
    };
    let grid = Grid::new(width, height, free).map_err(|error| MapError::Grid {
        at: Location::file(source),
        error,
    })?;
    // The grid accepted the size, so every coordinate is below MAX_SIDE and fits in u16.
    let cell = |(x, y): (usize, usize)| Cell::new(x as u16, y as u16);
    Ok(GridMap {
        name: name_from_source(source),
        grid,
        start: start.map(|(x, y, _, _)| cell((x, y))),
        goals: goals.into_iter().map(cell).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridError;

    fn parse(text: &str) -> Result<GridMap, MapError> {
        parse_ascii("maps/a.txt", text.as_bytes())
    }

    fn loc(e: &MapError) -> (Option<usize>, Option<usize>) {
        let at = e.location().expect("parse errors have a location");
        assert_eq!(at.file, "maps/a.txt");
        (at.line, at.column)
    }

    #[test]
    fn parses_start_goals_comments_and_crlf() {
        let m = parse("; office\r\nS.#\r\n.#G\r\n; end\r\nG..\r\n\r\n").unwrap();
        assert_eq!(m.name, "a");
        assert_eq!((m.grid.width(), m.grid.height()), (3, 3));
        assert_eq!(m.start, Some(Cell::new(0, 0)));
        assert_eq!(m.goals, vec![Cell::new(2, 1), Cell::new(0, 2)]);
        assert!(!m.grid.is_free(Cell::new(2, 0)));
        assert!(m.grid.is_free(Cell::new(2, 1)));
        assert_eq!(m.grid.free_count(), 7);
    }

    #[test]
    fn missing_start_and_goal_are_none() {
        let m = parse("..\n.#").unwrap();
        assert_eq!(m.start, None);
        assert!(m.goals.is_empty());
    }

    #[test]
    fn tolerates_bom_and_blank_lines_around() {
        let m = parse("\u{feff}\n\nS.\n.G\n\n\n").unwrap();
        assert_eq!(m.grid.height(), 2);
        assert_eq!(m.start, Some(Cell::new(0, 0)));
    }

    #[test]
    fn unknown_character_names_line_and_column() {
        let e = parse("; c\nS...\n..x.\n").unwrap_err();
        assert!(matches!(e, MapError::UnknownChar { found: 'x', .. }), "{e}");
        assert_eq!(loc(&e), (Some(3), Some(3)));
        assert_eq!(
            e.to_string(),
            "maps/a.txt:3:3: unknown character 'x' (expected '#', '.', 'S' or 'G')"
        );
    }

    #[test]
    fn unknown_multibyte_character_counts_columns_in_characters() {
        let e = parse("..\n.é\n").unwrap_err();
        assert!(matches!(e, MapError::UnknownChar { found: 'é', .. }));
        assert_eq!(loc(&e), (Some(2), Some(2)));
    }

    #[test]
    fn non_rectangular_rows() {
        let e = parse("S...\n..\n").unwrap_err();
        assert!(
            matches!(
                e,
                MapError::Ragged {
                    found: 2,
                    expected: 4,
                    ..
                }
            ),
            "{e}"
        );
        assert_eq!(loc(&e), (Some(2), Some(3)));
        assert!(
            e.to_string()
                .starts_with("maps/a.txt:2:3: row is 2 cells wide")
        );

        let e = parse("S.\n...\n").unwrap_err();
        assert!(matches!(
            e,
            MapError::Ragged {
                found: 3,
                expected: 2,
                ..
            }
        ));
        assert_eq!(loc(&e), (Some(2), Some(3)));
    }

    #[test]
    fn blank_line_between_rows() {
        let e = parse("S.\n\n.G\n").unwrap_err();
        assert!(matches!(
            e,
            MapError::Ragged {
                found: 0,
                expected: 2,
                ..
            }
        ));
        assert_eq!(loc(&e), (Some(2), None));
    }

    #[test]
    fn several_starts() {
        let e = parse("S.\n.S\n").unwrap_err();
        assert!(
            matches!(
                e,
                MapError::DuplicateStart {
                    first_line: 1,
                    first_column: 1,
                    ..
                }
            ),
            "{e}"
        );
        assert_eq!(loc(&e), (Some(2), Some(2)));
        assert!(e.to_string().contains("line 1, column 1"));
    }

    #[test]
    fn empty_file_and_comment_only_file() {
        for text in ["", "\n\n", "; nothing\n; here\n"] {
            let e = parse(text).unwrap_err();
            assert!(matches!(e, MapError::Empty { .. }), "{e}");
            assert_eq!(loc(&e), (None, None));
            assert!(e.to_string().starts_with("maps/a.txt: empty file"));
        }
    }

    #[test]
    fn not_utf8_names_line_and_column() {
        let e = parse_ascii("maps/a.txt", b"S..\n.\xff.\n").unwrap_err();
        assert!(matches!(e, MapError::NotUtf8 { .. }));
        assert_eq!(loc(&e), (Some(2), Some(2)));
        assert!(e.to_string().starts_with("maps/a.txt:2:2: invalid UTF-8"));
    }

    #[test]
    fn too_large_maps_to_grid_error() {
        let row = ".".repeat(crate::grid::MAX_SIDE + 1);
        let e = parse(&row).unwrap_err();
        assert!(
            matches!(
                e,
                MapError::Grid {
                    error: GridError::TooLarge { .. },
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("at most 4096"));
    }
}
