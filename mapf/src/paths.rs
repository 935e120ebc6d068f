//! The mapf-visualizer path format (what PIBT/LaCAM's reference implementations write and
//! Kei18/mapf-visualizer reads): one line per tick from 0 to the makespan,
//! `t:(x,y),(x,y),...,` with agents in id order, x the column and y the row.
//!
//! Parsing takes untrusted text: sizes are bounded and every error names its line.

use crate::instance::MAX_AGENTS;
use planner::Cell;
use planner::grid::MAX_SIDE;
use std::fmt::Write as _;

/// The most ticks (lines) a paths file may hold.
pub const MAX_TICKS: usize = 1 << 20;
/// The most bytes a paths text may hold.
pub const MAX_PATHS_BYTES: usize = 64 << 20;

/// Why a paths text could not be read; line numbers count from 1.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PathsError {
    /// The text is larger than [`MAX_PATHS_BYTES`].
    #[error("the paths text is {bytes} bytes; at most {MAX_PATHS_BYTES} are read")]
    TooLarge {
        /// Its size.
        bytes: usize,
    },
    /// No tick line at all.
    #[error("the paths text holds no tick line")]
    Empty,
    /// More lines than [`MAX_TICKS`].
    #[error("line {line}: more than {MAX_TICKS} ticks")]
    TooManyTicks {
        /// The first line over the limit.
        line: usize,
    },
    /// A line that does not start `t:` with the expected tick number.
    #[error("line {line}: expected tick {expected} as '{expected}:', found '{found}'")]
    BadTick {
        /// The line.
        line: usize,
        /// The tick number expected there.
        expected: usize,
        /// What the line starts with (cut short).
        found: String,
    },
    /// A position that is not `(x,y)` with whole numbers on the grid's coordinate range.
    #[error(
        "line {line}: agent {agent}: expected '(x,y)' with 0 <= x, y < {MAX_SIDE}, found '{found}'"
    )]
    BadCell {
        /// The line.
        line: usize,
        /// The agent (position on the line, from 0).
        agent: usize,
        /// The text found (cut short).
        found: String,
    },
    /// A line with another number of agents than the first.
    #[error("line {line}: {found} agents, but line 1 has {expected}")]
    AgentCount {
        /// The line.
        line: usize,
        /// Agents on line 1.
        expected: usize,
        /// Agents on this line.
        found: usize,
    },
    /// More agents on a line than [`MAX_AGENTS`], or none.
    #[error("line {line}: {found} agents; a paths file holds 1 to {MAX_AGENTS}")]
    BadAgentCount {
        /// The line.
        line: usize,
        /// Agents found.
        found: usize,
    },
}

/// Writes `paths` (`paths[agent][tick]`) in the mapf-visualizer format, one line per tick up to
/// the longest path; shorter paths stay on their last cell. Empty input gives an empty string.
pub fn write_paths(paths: &[Vec<Cell>]) -> String {
    let len = paths.iter().map(Vec::len).max().unwrap_or(0);
    let mut out = String::with_capacity(len * (paths.len() * 9 + 8));
    for t in 0..len {
        let _ = write!(out, "{t}:");
        for p in paths {
            if let Some(c) = p.get(t).or(p.last()) {
                let _ = write!(out, "({},{}),", c.x, c.y);
            }
        }
        out.push('\n');
    }
    out
}

/// A short excerpt of untrusted text for a message.
fn excerpt(s: &str) -> String {
    let mut e: String = s.chars().take(24).collect();
    if s.chars().nth(24).is_some() {
        e.push('…');
    }
    e
}

/// Parses one coordinate, refusing anything but digits in the grid's range.
fn coord(s: &str) -> Option<u16> {
    let s = s.trim();
    if s.is_empty() || s.len() > 5 || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let v: usize = s.parse().ok()?;
    (v < MAX_SIDE).then_some(v as u16)
}

/// Parses mapf-visualizer text into `paths[agent][tick]`; blank lines are skipped, ticks must
/// count up from 0, and every line must hold the same number of agents.
pub fn parse_paths(text: &str) -> Result<Vec<Vec<Cell>>, PathsError> {
    if text.len() > MAX_PATHS_BYTES {
        return Err(PathsError::TooLarge { bytes: text.len() });
    }
    let mut paths: Vec<Vec<Cell>> = Vec::new();
    let mut tick = 0usize;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.trim();
        if l.is_empty() {
            continue;
        }
        if tick >= MAX_TICKS {
            return Err(PathsError::TooManyTicks { line });
        }
        let bad_tick = || PathsError::BadTick {
            line,
            expected: tick,
            found: excerpt(l),
        };
        let (head, rest) = l.split_once(':').ok_or_else(bad_tick)?;
        if head.trim().parse::<usize>().ok() != Some(tick) {
            return Err(bad_tick());
        }
        let mut agent = 0usize;
        let mut rest = rest.trim_start();
        while !rest.is_empty() {
            let bad_cell = |found: &str| PathsError::BadCell {
                line,
                agent,
                found: excerpt(found),
            };
            let Some(body) = rest.strip_prefix('(') else {
                return Err(bad_cell(rest));
            };
            let Some(close) = body.find(')') else {
                return Err(bad_cell(rest));
            };
            let cell = body[..close]
                .split_once(',')
                .and_then(|(x, y)| Some(Cell::new(coord(x)?, coord(y)?)))
                .ok_or_else(|| bad_cell(&rest[..close + 2]))?;
            if agent >= MAX_AGENTS {
                return Err(PathsError::BadAgentCount {
                    line,
                    found: agent + 1,
                });
            }
            if tick == 0 {
                paths.push(Vec::new());
            } else if agent >= paths.len() {
                return Err(PathsError::AgentCount {
                    line,
                    expected: paths.len(),
                    found: agent + 1,
                });
            }
            paths[agent].push(cell);
            agent += 1;
            rest = body[close + 1..].trim_start();
            rest = rest.strip_prefix(',').unwrap_or(rest).trim_start();
        }
        if agent == 0 {
            return Err(PathsError::BadAgentCount { line, found: 0 });
        }
        if agent != paths.len() {
            return Err(PathsError::AgentCount {
                line,
                expected: paths.len(),
                found: agent,
            });
        }
        tick += 1;
    }
    if tick == 0 {
        return Err(PathsError::Empty);
    }
    Ok(paths)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(x: u16, y: u16) -> Cell {
        Cell::new(x, y)
    }

    #[test]
    fn writes_the_visualizer_format_and_reads_it_back() {
        let paths = vec![vec![c(0, 0), c(1, 0), c(2, 0)], vec![c(5, 7), c(5, 6)]];
        let text = write_paths(&paths);
        assert_eq!(text, "0:(0,0),(5,7),\n1:(1,0),(5,6),\n2:(2,0),(5,6),\n");
        let back = parse_paths(&text).unwrap();
        assert_eq!(back[0], paths[0]);
        assert_eq!(back[1], vec![c(5, 7), c(5, 6), c(5, 6)]);
        // no trailing comma, spaces and blank lines are fine
        let back = parse_paths("0: (1,2), (3,4)\n\n1:(1,3),(3,4)\n").unwrap();
        assert_eq!(back, vec![vec![c(1, 2), c(1, 3)], vec![c(3, 4), c(3, 4)]]);
    }

    #[test]
    fn errors_name_the_line() {
        let e = |t: &str| parse_paths(t).unwrap_err().to_string();
        assert_eq!(e(""), "the paths text holds no tick line");
        assert_eq!(
            e("0:(1,1),\n2:(1,1),\n"),
            "line 2: expected tick 1 as '1:', found '2:(1,1),'"
        );
        assert_eq!(
            e("0:(1,1),(2,2),\n1:(1,1),\n"),
            "line 2: 1 agents, but line 1 has 2"
        );
        assert_eq!(
            e("0:(1,1),\n1:(1,1),(2,2),\n"),
            "line 2: 2 agents, but line 1 has 1"
        );
        assert!(e("0:(1,-1),\n").starts_with("line 1: agent 0: expected '(x,y)'"));
        assert!(e("0:(1,1),(99999,1)\n").starts_with("line 1: agent 1: expected"));
        assert!(e("0:(1,1),x\n").contains("found 'x'"));
        assert!(e("0:(1,1\n").starts_with("line 1: agent 0"));
        assert_eq!(e("0:\n"), "line 1: 0 agents; a paths file holds 1 to 256");
        let many: String = std::iter::once("0:".to_owned())
            .chain((0..257).map(|i| format!("({},0),", i)))
            .collect();
        assert_eq!(e(&many), "line 1: 257 agents; a paths file holds 1 to 256");
        assert!(e("zz\n").starts_with("line 1: expected tick 0"));
        assert!(e("0:(1,1)\n1:(1,1)\nx:(1,1)").starts_with("line 3"));
    }
}
