//! The MovingAI grid benchmark formats (N. Sturtevant, "Benchmarks for Grid-Based Pathfinding",
//! 2012): `.map` occupancy grids and `.scen` start/goal lists.
//!
//! A `.map` file is a header `type octile`, `height H`, `width W`, `map` (height and width are
//! accepted in either order), then H rows of W characters: `.`, `G`, `S` and `E` are passable
//! (`E` and `S` are the League of Robot Runners' emitter and service cells), `@`, `O`, `T` and
//! `W` are not. (0,0) is the top-left cell and x is the column. MovingAI maps have
//! no start or goal; those come from a `.scen` file or the command line.
//!
//! A `.scen` file is `version 1` (or `version 1.0`), then one line per scenario of nine
//! tab-separated fields: `bucket map width height start_x start_y goal_x goal_y optimal_length`.
//! Lines without tabs are split at whitespace instead, for hand-written files. The optimal
//! length is the octile one (diagonal moves cost √2): it is kept, but qfleet moves in four
//! directions, so the 4-connected optimum must come from a BFS ([`crate::path`]).

use super::text::{Line, lines};
use super::{GridMap, Location, MapError, name_from_source};
use crate::grid::{Cell, Grid, GridError, MAX_CELLS, MAX_SIDE};

/// The characters a MovingAI map may hold, for error messages.
const EXPECTED: &str = "'.', 'G', 'S' or 'E' (passable) or '@', 'O', 'T' or 'W' (blocked)";

/// One start/goal pair of a `.scen` file.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// The difficulty bucket (MovingAI groups scenarios by octile length / 4).
    pub bucket: u32,
    /// The map file the scenario was made for, as written in the file.
    pub map: String,
    /// The map width the scenario was made for, to catch a scenario used on another map.
    pub width: usize,
    /// The map height the scenario was made for.
    pub height: usize,
    /// Where the robot starts.
    pub start: Cell,
    /// Where it must go.
    pub goal: Cell,
    /// The octile optimum from the file: diagonal moves allowed, so never the 4-connected one.
    pub optimal_octile: f64,
}

/// The next non-blank line, or `None` at the end of the file.
fn next_content<'a>(
    it: &mut impl Iterator<Item = Result<Line<'a>, MapError>>,
) -> Result<Option<Line<'a>>, MapError> {
    for line in it {
        let line = line?;
        if !line.is_blank() {
            return Ok(Some(line));
        }
    }
    Ok(None)
}

/// `'text'` for a line that is there, `the end of the file` for one that is not.
fn quoted(line: Option<&Line<'_>>) -> String {
    line.map_or_else(
        || "the end of the file".to_owned(),
        |l| format!("'{}'", l.text.trim()),
    )
}

/// The location of a line, or of the whole file at its end.
fn where_is(source: &str, line: Option<&Line<'_>>) -> Location {
    line.map_or_else(
        || Location::file(source),
        |l| Location::line(source, l.number),
    )
}

/// Checks a header size against the grid limits before anything is allocated for it.
fn check_size(
    source: &str,
    (height, height_line): (usize, usize),
    (width, width_line): (usize, usize),
) -> Result<(), MapError> {
    let fail = |line: usize, error: GridError| {
        Err(MapError::Grid {
            at: Location::line(source, line),
            error,
        })
    };
    let empty = GridError::Empty { width, height };
    let large = GridError::TooLarge { width, height };
    if height == 0 {
        fail(height_line, empty)
    } else if width == 0 {
        fail(width_line, empty)
    } else if height > MAX_SIDE {
        fail(height_line, large)
    } else if width > MAX_SIDE {
        fail(width_line, large)
    } else if width * height > MAX_CELLS {
        fail(height_line.max(width_line), large)
    } else {
        Ok(())
    }
}

/// Parses a MovingAI `.map` file; `source` names the file in errors and gives the map its name.
pub fn parse_movingai_map(source: &str, bytes: &[u8]) -> Result<GridMap, MapError> {
    let mut it = lines(source, bytes);

    let Some(first) = next_content(&mut it)? else {
        return Err(MapError::Empty {
            at: Location::file(source),
            expected: "a MovingAI map starts with 'type octile'",
        });
    };
    let words: Vec<&str> = first.text.split_whitespace().collect();
    if !matches!(words.as_slice(), ["type", _]) {
        return Err(MapError::Header {
            at: Location::line(source, first.number),
            expected: "'type octile'",
            found: quoted(Some(&first)),
        });
    }

    // (value, line) of each size line.
    let mut height: Option<(usize, usize)> = None;
    let mut width: Option<(usize, usize)> = None;
    let (height, width, map_line) = loop {
        let expected = match (height, width) {
            (None, None) => "'height <rows>' or 'width <columns>'",
            (None, Some(_)) => "'height <rows>'",
            (Some(_), None) => "'width <columns>'",
            (Some(_), Some(_)) => "'map'",
        };
        let line = next_content(&mut it)?;
        let header_error = |line: Option<&Line<'_>>| MapError::Header {
            at: where_is(source, line),
            expected,
            found: quoted(line),
        };
        let Some(line) = line else {
            return Err(header_error(None));
        };
        let words: Vec<&str> = line.text.split_whitespace().collect();
        let (slot, value) = match (words.as_slice(), height, width) {
            (["map"], Some(h), Some(w)) => break (h, w, line.number),
            (["height", value], None, _) => (&mut height, *value),
            (["width", value], _, None) => (&mut width, *value),
            _ => return Err(header_error(Some(&line))),
        };
        let Ok(n) = value.parse::<usize>() else {
            let offset = value.as_ptr() as usize - line.text.as_ptr() as usize;
            return Err(MapError::Header {
                at: Location::at(source, line.number, line.column_of(offset)),
                expected: "a whole number of cells",
                found: format!("'{value}'"),
            });
        };
        *slot = Some((n, line.number));
    };
    check_size(source, height, width)?;
    let ((height, _), (width, _)) = (height, width);

    // The size is within MAX_CELLS; the input length caps the reservation for lying headers.
    let mut free = Vec::with_capacity((width * height).min(bytes.len()));
    let mut rows = 0usize;
    let mut last_line = map_line;
    let mut blank_after_rows: Option<usize> = None;
    while let Some(line) = it.next() {
        let line = line?;
        last_line = line.number;
        if line.is_blank() {
            blank_after_rows.get_or_insert(line.number);
            continue;
        }
        if rows == height {
            let more = it
                .filter(|l| l.as_ref().map_or(true, |l| !l.is_blank()))
                .count();
            return Err(MapError::RowCount {
                at: Location::line(source, line.number),
                declared: height,
                found: height + 1 + more,
            });
        }
        if let Some(blank) = blank_after_rows {
            return Err(MapError::Ragged {
                at: Location::line(source, blank),
                found: 0,
                expected: width,
            });
        }
        let mut row_width = 0;
        for (x, ch) in line.text.chars().enumerate() {
            match ch {
                '.' | 'G' | 'S' | 'E' => free.push(true),
                '@' | 'O' | 'T' | 'W' => free.push(false),
                found => {
                    return Err(MapError::UnknownChar {
                        at: Location::at(source, line.number, x + 1),
                        found,
                        expected: EXPECTED,
                    });
                }
            }
            row_width = x + 1;
        }
        if row_width != width {
            return Err(MapError::Ragged {
                at: Location::at(source, line.number, width.min(row_width) + 1),
                found: row_width,
                expected: width,
            });
        }
        rows += 1;
    }
    if rows < height {
        return Err(MapError::RowCount {
            at: Location::line(source, last_line),
            declared: height,
            found: rows,
        });
    }
    let grid = Grid::new(width, height, free).map_err(|error| MapError::Grid {
        at: Location::file(source),
        error,
    })?;
    Ok(GridMap {
        name: name_from_source(source),
        grid,
        start: None,
        goals: Vec::new(),
    })
}

/// The nine fields of a scenario line, in order.
const FIELDS: [&str; 9] = [
    "bucket",
    "map",
    "width",
    "height",
    "start_x",
    "start_y",
    "goal_x",
    "goal_y",
    "optimal_length",
];

/// Parses a MovingAI `.scen` file into its scenarios, in file order.
///
/// Each scenario's coordinates are checked against the width and height written on its own
/// line; whether that size matches a map is checked by [`crate::task::resolve_scenario`].
pub fn parse_scen(source: &str, bytes: &[u8]) -> Result<Vec<Scenario>, MapError> {
    let mut it = lines(source, bytes);
    let Some(first) = next_content(&mut it)? else {
        return Err(MapError::Empty {
            at: Location::file(source),
            expected: "a scenario file starts with 'version 1'",
        });
    };
    let words: Vec<&str> = first.text.split_whitespace().collect();
    if !matches!(words.as_slice(), ["version", "1" | "1.0"]) {
        return Err(MapError::Header {
            at: Location::line(source, first.number),
            expected: "'version 1'",
            found: quoted(Some(&first)),
        });
    }
    let mut out = Vec::new();
    for line in it {
        let line = line?;
        if !line.is_blank() {
            out.push(parse_scen_line(source, &line)?);
        }
    }
    Ok(out)
}

/// Parses one non-blank scenario line.
fn parse_scen_line(source: &str, line: &Line<'_>) -> Result<Scenario, MapError> {
    let text = line.text;
    let mut fields: Vec<&str> = text.split('\t').collect();
    if fields.len() == 1 {
        fields = text.split_whitespace().collect();
    }
    if fields.len() != FIELDS.len() {
        return Err(MapError::FieldCount {
            at: Location::line(source, line.number),
            found: fields.len(),
        });
    }
    let bad = |i: usize, problem: String| {
        let offset = fields[i].as_ptr() as usize - text.as_ptr() as usize;
        MapError::BadField {
            at: Location::at(source, line.number, line.column_of(offset)),
            field: FIELDS[i],
            problem,
        }
    };
    let whole = |i: usize| -> Result<usize, MapError> {
        let f = fields[i].trim();
        f.parse::<usize>()
            .map_err(|_| bad(i, format!("expected a whole number, found '{f}'")))
    };

    let bucket = fields[0].trim();
    let bucket = bucket
        .parse::<u32>()
        .map_err(|_| bad(0, format!("expected a whole number, found '{bucket}'")))?;
    let map = fields[1].trim();
    if map.is_empty() {
        return Err(bad(1, "the map name is empty".to_owned()));
    }
    let mut size = [0usize; 2];
    for (k, s) in size.iter_mut().enumerate() {
        *s = whole(2 + k)?;
        if *s == 0 || *s > MAX_SIDE {
            return Err(bad(
                2 + k,
                format!("{} is not a supported map size (1 to {MAX_SIDE})", *s),
            ));
        }
    }
    let [width, height] = size;
    let mut coords = [0u16; 4];
    for (k, c) in coords.iter_mut().enumerate() {
        let i = 4 + k;
        let v = whole(i)?;
        let (limit, side) = if k % 2 == 0 {
            (width, "wide")
        } else {
            (height, "high")
        };
        if v >= limit {
            return Err(bad(
                i,
                format!("{v} is outside the {limit}-{side} map (coordinates count from 0)"),
            ));
        }
        // v < limit <= MAX_SIDE, so it fits.
        *c = v as u16;
    }
    let optimal = fields[8].trim();
    let optimal_octile = optimal
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v >= 0.0)
        .ok_or_else(|| {
            bad(
                8,
                format!("expected a non-negative number, found '{optimal}'"),
            )
        })?;
    Ok(Scenario {
        bucket,
        map: map.to_owned(),
        width,
        height,
        start: Cell::new(coords[0], coords[1]),
        goal: Cell::new(coords[2], coords[3]),
        optimal_octile,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const MAP: &str = "type octile\nheight 3\nwidth 4\nmap\n.@..\n.TG.\nS..W\n";

    fn map(text: &str) -> Result<GridMap, MapError> {
        parse_movingai_map("maps/m.map", text.as_bytes())
    }

    fn scen(text: &str) -> Result<Vec<Scenario>, MapError> {
        parse_scen("maps/m.scen", text.as_bytes())
    }

    fn loc(e: &MapError) -> (Option<usize>, Option<usize>) {
        let at = e.location().expect("parse errors have a location");
        assert!(at.file.starts_with("maps/m."), "{at}");
        (at.line, at.column)
    }

    #[test]
    fn parses_a_map() {
        let m = map(MAP).unwrap();
        assert_eq!(m.name, "m");
        assert_eq!((m.grid.width(), m.grid.height()), (4, 3));
        assert_eq!(m.start, None);
        assert!(m.goals.is_empty());
        let blocked: Vec<Cell> = (0..m.grid.len())
            .map(|i| m.grid.cell(i))
            .filter(|c| !m.grid.is_free(*c))
            .collect();
        assert_eq!(
            blocked,
            vec![Cell::new(1, 0), Cell::new(1, 1), Cell::new(3, 2)]
        );
    }

    #[test]
    fn accepts_crlf_width_first_and_trailing_blank_lines() {
        let m = map("type octile\r\nwidth 2\r\nheight 1\r\nmap\r\n.@\r\n\r\n\r\n").unwrap();
        assert_eq!((m.grid.width(), m.grid.height()), (2, 1));
    }

    #[test]
    fn empty_file() {
        let e = map("").unwrap_err();
        assert!(matches!(e, MapError::Empty { .. }), "{e}");
        assert_eq!(loc(&e), (None, None));
    }

    #[test]
    fn missing_or_garbled_header() {
        let e = map("....\n....\n").unwrap_err();
        assert!(
            matches!(
                e,
                MapError::Header {
                    expected: "'type octile'",
                    ..
                }
            ),
            "{e}"
        );
        assert_eq!(loc(&e), (Some(1), None));

        let e = map("type octile\nhight 3\nwidth 4\nmap\n").unwrap_err();
        assert!(matches!(e, MapError::Header { .. }), "{e}");
        assert_eq!(loc(&e), (Some(2), None));
        assert!(e.to_string().contains("found 'hight 3'"), "{e}");

        let e = map("type octile\nheight three\n").unwrap_err();
        assert!(matches!(e, MapError::Header { .. }), "{e}");
        assert_eq!(loc(&e), (Some(2), Some(8)));

        let e = map("type octile\nheight 3\nmap\n").unwrap_err();
        assert!(
            matches!(
                e,
                MapError::Header {
                    expected: "'width <columns>'",
                    ..
                }
            ),
            "{e}"
        );
        assert_eq!(loc(&e), (Some(3), None));

        let e = map("type octile\nheight 3\nheight 3\n").unwrap_err();
        assert!(matches!(e, MapError::Header { .. }), "{e}");
        assert_eq!(loc(&e), (Some(3), None));

        let e = map("type octile\nheight 3\nwidth 4\n").unwrap_err();
        assert!(
            matches!(
                e,
                MapError::Header {
                    expected: "'map'",
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().ends_with("found the end of the file"), "{e}");
    }

    #[test]
    fn header_with_fewer_rows_than_height() {
        let e = map("type octile\nheight 3\nwidth 2\nmap\n..\n..\n").unwrap_err();
        assert!(
            matches!(
                e,
                MapError::RowCount {
                    declared: 3,
                    found: 2,
                    ..
                }
            ),
            "{e}"
        );
        assert_eq!(loc(&e), (Some(7), None));
    }

    #[test]
    fn header_with_more_rows_than_height() {
        let e = map("type octile\nheight 1\nwidth 2\nmap\n..\n..\n@@\n").unwrap_err();
        assert!(
            matches!(
                e,
                MapError::RowCount {
                    declared: 1,
                    found: 3,
                    ..
                }
            ),
            "{e}"
        );
        assert_eq!(loc(&e), (Some(6), None));
    }

    #[test]
    fn row_width_differs_from_header() {
        let e = map("type octile\nheight 2\nwidth 3\nmap\n...\n....\n").unwrap_err();
        assert!(
            matches!(
                e,
                MapError::Ragged {
                    found: 4,
                    expected: 3,
                    ..
                }
            ),
            "{e}"
        );
        assert_eq!(loc(&e), (Some(6), Some(4)));
    }

    #[test]
    fn blank_line_inside_the_rows() {
        let e = map("type octile\nheight 2\nwidth 3\nmap\n...\n\n...\n").unwrap_err();
        assert!(matches!(e, MapError::Ragged { found: 0, .. }), "{e}");
        assert_eq!(loc(&e), (Some(6), None));
    }

    #[test]
    fn unknown_character() {
        let e = map("type octile\nheight 1\nwidth 3\nmap\n.#.\n").unwrap_err();
        assert!(matches!(e, MapError::UnknownChar { found: '#', .. }), "{e}");
        assert_eq!(loc(&e), (Some(5), Some(2)));
    }

    #[test]
    fn not_utf8() {
        let e = parse_movingai_map(
            "maps/m.map",
            b"type octile\nheight 1\nwidth 2\nmap\n.\xc3\n",
        )
        .unwrap_err();
        assert!(matches!(e, MapError::NotUtf8 { .. }), "{e}");
        assert_eq!(loc(&e), (Some(5), Some(2)));
    }

    #[test]
    fn sizes_above_the_limits_or_zero() {
        let e = map("type octile\nheight 5000\nwidth 4\nmap\n").unwrap_err();
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
        assert_eq!(loc(&e), (Some(2), None));

        let e = map("type octile\nheight 4096\nwidth 4096\nmap\n").unwrap_err();
        assert!(matches!(
            e,
            MapError::Grid {
                error: GridError::TooLarge { .. },
                ..
            }
        ));
        assert_eq!(loc(&e), (Some(3), None));

        let e = map("type octile\nheight 2\nwidth 0\nmap\n").unwrap_err();
        assert!(matches!(
            e,
            MapError::Grid {
                error: GridError::Empty { .. },
                ..
            }
        ));
        assert_eq!(loc(&e), (Some(3), None));

        let e = map("type octile\nheight 99999999999999999999999\nwidth 1\nmap\n").unwrap_err();
        assert!(matches!(e, MapError::Header { .. }), "{e}");
    }

    #[test]
    fn parses_scenarios() {
        let s = scen("version 1\n3\tm.map\t4\t3\t0\t2\t2\t1\t3.41421356\n\n").unwrap();
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].bucket, 3);
        assert_eq!(s[0].map, "m.map");
        assert_eq!((s[0].width, s[0].height), (4, 3));
        assert_eq!(s[0].start, Cell::new(0, 2));
        assert_eq!(s[0].goal, Cell::new(2, 1));
        assert!((s[0].optimal_octile - 3.41421356).abs() < 1e-12);

        let s = scen("version 1.0\r\n0 m.map 4 3 0 0 1 1 1.4\r\n").unwrap();
        assert_eq!(s[0].goal, Cell::new(1, 1));
        assert!(scen("version 1\n").unwrap().is_empty());
    }

    #[test]
    fn scen_header_errors() {
        let e = scen("").unwrap_err();
        assert!(matches!(e, MapError::Empty { .. }), "{e}");
        let e = scen("version 2\n").unwrap_err();
        assert!(matches!(e, MapError::Header { .. }), "{e}");
        assert_eq!(loc(&e), (Some(1), None));
        let e = scen("0\tm.map\t4\t3\t0\t2\t2\t1\t3\n").unwrap_err();
        assert!(matches!(e, MapError::Header { .. }), "{e}");
    }

    #[test]
    fn scen_field_count() {
        let e = scen("version 1\n0\tm.map\t4\t3\t0\t2\t2\t1\n").unwrap_err();
        assert!(matches!(e, MapError::FieldCount { found: 8, .. }), "{e}");
        assert_eq!(loc(&e), (Some(2), None));
    }

    #[test]
    fn scen_non_numbers_name_the_field() {
        let e = scen("version 1\n0\tm.map\t4\t3\tx\t2\t2\t1\t3\n").unwrap_err();
        assert!(
            matches!(
                e,
                MapError::BadField {
                    field: "start_x",
                    ..
                }
            ),
            "{e}"
        );
        assert_eq!(loc(&e), (Some(2), Some(13)));
        assert!(
            e.to_string()
                .starts_with("maps/m.scen:2:13: start_x: expected a whole number"),
            "{e}"
        );

        let e = scen("version 1\n0\tm.map\t4\t3\t-1\t2\t2\t1\t3\n").unwrap_err();
        assert!(matches!(
            e,
            MapError::BadField {
                field: "start_x",
                ..
            }
        ));
        let e = scen("version 1\n0\tm.map\t4\t3\t0\t2\t2\t1\tNaN\n").unwrap_err();
        assert!(matches!(
            e,
            MapError::BadField {
                field: "optimal_length",
                ..
            }
        ));
        let e = scen("version 1\nb\tm.map\t4\t3\t0\t2\t2\t1\t3\n").unwrap_err();
        assert!(matches!(
            e,
            MapError::BadField {
                field: "bucket",
                ..
            }
        ));
        let e = scen("version 1\n0\t \t4\t3\t0\t2\t2\t1\t3\n").unwrap_err();
        assert!(matches!(e, MapError::BadField { field: "map", .. }));
    }

    #[test]
    fn scen_coordinates_outside_its_own_size() {
        let e = scen("version 1\n0\tm.map\t4\t3\t0\t3\t2\t1\t3\n").unwrap_err();
        assert!(
            matches!(
                e,
                MapError::BadField {
                    field: "start_y",
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("outside the 3-high map"), "{e}");
        let e = scen("version 1\n0\tm.map\t0\t3\t0\t0\t0\t1\t3\n").unwrap_err();
        assert!(
            matches!(e, MapError::BadField { field: "width", .. }),
            "{e}"
        );
        let e = scen("version 1\n0\tm.map\t5000\t3\t0\t0\t0\t1\t3\n").unwrap_err();
        assert!(
            matches!(e, MapError::BadField { field: "width", .. }),
            "{e}"
        );
    }

    #[test]
    fn scen_not_utf8() {
        let e = parse_scen("maps/m.scen", b"version 1\n0\tm\xff.map").unwrap_err();
        assert!(matches!(e, MapError::NotUtf8 { .. }));
        assert_eq!(loc(&e), (Some(2), Some(4)));
    }
}
