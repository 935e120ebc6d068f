//! The 4-connected occupancy grid every map turns into, and the four moves on it.

use serde::{Deserialize, Serialize};
use std::fmt;

/// Largest accepted width or height, in cells: keeps coordinates in `u16` and tables small.
pub const MAX_SIDE: usize = 4096;
/// Largest accepted number of cells: a dense Q-table of this grid is 64 MiB of `f32`.
pub const MAX_CELLS: usize = 4 * 1024 * 1024;

/// A grid cell; `x` is the column, `y` the row, (0,0) the top-left corner.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Cell {
    /// Column, counted from the left.
    pub x: u16,
    /// Row, counted from the top.
    pub y: u16,
}

impl Cell {
    /// A cell at column `x`, row `y`.
    pub const fn new(x: u16, y: u16) -> Self {
        Cell { x, y }
    }

    /// Manhattan distance: the 4-connected distance on an empty grid.
    pub fn manhattan(self, other: Cell) -> u32 {
        (self.x as i32 - other.x as i32).unsigned_abs()
            + (self.y as i32 - other.y as i32).unsigned_abs()
    }
}

impl fmt::Display for Cell {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{},{}", self.x, self.y)
    }
}

/// One of the four moves; the discriminant is the action's column in the Q-table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[repr(u8)]
pub enum Action {
    /// Towards row 0.
    Up = 0,
    /// Towards the last column.
    Right = 1,
    /// Towards the last row.
    Down = 2,
    /// Towards column 0.
    Left = 3,
}

impl Action {
    /// All four actions in Q-table column order.
    pub const ALL: [Action; 4] = [Action::Up, Action::Right, Action::Down, Action::Left];

    /// The action with Q-table column `i` (taken modulo 4).
    pub const fn from_index(i: usize) -> Action {
        Action::ALL[i & 3]
    }

    /// The (dx, dy) this action moves by.
    pub const fn delta(self) -> (i32, i32) {
        match self {
            Action::Up => (0, -1),
            Action::Right => (1, 0),
            Action::Down => (0, 1),
            Action::Left => (-1, 0),
        }
    }
}

/// Why a grid could not be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GridError {
    /// Width or height is zero.
    #[error("the grid is empty ({width}x{height})")]
    Empty {
        /// Width asked for.
        width: usize,
        /// Height asked for.
        height: usize,
    },
    /// Width or height above [`MAX_SIDE`] or cells above [`MAX_CELLS`].
    #[error(
        "the grid is {width}x{height}; at most {MAX_SIDE} cells a side and {MAX_CELLS} cells in all are supported"
    )]
    TooLarge {
        /// Width asked for.
        width: usize,
        /// Height asked for.
        height: usize,
    },
    /// The cell list does not hold width × height entries.
    #[error("a {width}x{height} grid needs {} cells, got {got}", width * height)]
    WrongCellCount {
        /// Width asked for.
        width: usize,
        /// Height asked for.
        height: usize,
        /// Cells given.
        got: usize,
    },
}

/// A rectangular 4-connected grid of free and blocked cells, stored row-major.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Grid {
    width: u16,
    height: u16,
    free: Vec<bool>,
}

impl Grid {
    /// A grid from row-major free flags (`true` = passable).
    pub fn new(width: usize, height: usize, free: Vec<bool>) -> Result<Grid, GridError> {
        if width == 0 || height == 0 {
            return Err(GridError::Empty { width, height });
        }
        if width > MAX_SIDE || height > MAX_SIDE || width * height > MAX_CELLS {
            return Err(GridError::TooLarge { width, height });
        }
        if free.len() != width * height {
            return Err(GridError::WrongCellCount {
                width,
                height,
                got: free.len(),
            });
        }
        Ok(Grid {
            width: width as u16,
            height: height as u16,
            free,
        })
    }

    /// Number of columns.
    pub fn width(&self) -> usize {
        self.width as usize
    }

    /// Number of rows.
    pub fn height(&self) -> usize {
        self.height as usize
    }

    /// Number of cells, free or not.
    pub fn len(&self) -> usize {
        self.free.len()
    }

    /// Always false: a grid has at least one cell.
    pub fn is_empty(&self) -> bool {
        self.free.is_empty()
    }

    /// Number of passable cells.
    pub fn free_count(&self) -> usize {
        self.free.iter().filter(|f| **f).count()
    }

    /// Whether (x, y) lies on the grid; takes signed values so callers can test off-grid moves.
    pub fn contains(&self, x: i64, y: i64) -> bool {
        x >= 0 && y >= 0 && x < self.width as i64 && y < self.height as i64
    }

    /// Row-major index of a cell on the grid.
    pub fn index(&self, c: Cell) -> usize {
        c.y as usize * self.width as usize + c.x as usize
    }

    /// The cell at a row-major index.
    pub fn cell(&self, idx: usize) -> Cell {
        Cell::new(
            (idx % self.width as usize) as u16,
            (idx / self.width as usize) as u16,
        )
    }

    /// Whether a cell is on the grid and passable.
    pub fn is_free(&self, c: Cell) -> bool {
        self.contains(c.x as i64, c.y as i64) && self.free[self.index(c)]
    }

    /// Row-major passability flags.
    pub fn free_flags(&self) -> &[bool] {
        &self.free
    }

    /// The cell next to `c` in direction `a`, passable or not, or `None` off the grid.
    pub fn adjacent(&self, c: Cell, a: Action) -> Option<Cell> {
        let (dx, dy) = a.delta();
        let (nx, ny) = (c.x as i64 + dx as i64, c.y as i64 + dy as i64);
        self.contains(nx, ny)
            .then(|| Cell::new(nx as u16, ny as u16))
    }

    /// The passable cell reached from `c` by `a`, or `None` at a border or obstacle.
    pub fn neighbor(&self, c: Cell, a: Action) -> Option<Cell> {
        self.adjacent(c, a).filter(|&n| self.free[self.index(n)])
    }

    /// Passable 4-neighbours of `c`, in action order.
    pub fn neighbors(&self, c: Cell) -> impl Iterator<Item = Cell> + '_ {
        Action::ALL
            .into_iter()
            .filter_map(move |a| self.neighbor(c, a))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neighbor_stops_at_border_and_obstacle() {
        let g = Grid::new(2, 2, vec![true, false, true, true]).unwrap();
        assert_eq!(g.neighbor(Cell::new(0, 0), Action::Up), None);
        assert_eq!(g.neighbor(Cell::new(0, 0), Action::Right), None);
        assert_eq!(
            g.neighbor(Cell::new(0, 0), Action::Down),
            Some(Cell::new(0, 1))
        );
        assert_eq!(g.neighbors(Cell::new(1, 1)).count(), 1);
    }

    #[test]
    fn rejects_bad_sizes() {
        assert!(matches!(
            Grid::new(0, 3, vec![]),
            Err(GridError::Empty { .. })
        ));
        assert!(matches!(
            Grid::new(5000, 1, vec![true; 5000]),
            Err(GridError::TooLarge { .. })
        ));
        assert!(matches!(
            Grid::new(2, 2, vec![true; 3]),
            Err(GridError::WrongCellCount { .. })
        ));
    }
}
