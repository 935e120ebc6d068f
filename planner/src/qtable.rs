//! The dense Q-table: four action values per grid cell, zero at the start of learning.

use crate::grid::{Action, Cell, Grid};

/// Action values of every cell, row-major, one `[f32; 4]` (16 bytes) per cell.
#[derive(Debug, Clone, PartialEq)]
pub struct QTable {
    width: usize,
    values: Vec<[f32; 4]>,
}

impl QTable {
    /// A zero table for a grid.
    pub fn new(grid: &Grid) -> Self {
        QTable {
            width: grid.width(),
            values: vec![[0.0; 4]; grid.len()],
        }
    }

    /// Number of cells covered.
    pub fn cells(&self) -> usize {
        self.values.len()
    }

    /// The four action values of a cell index.
    #[inline(always)]
    pub fn row(&self, idx: usize) -> &[f32; 4] {
        &self.values[idx]
    }

    /// Mutable action values of a cell index.
    #[inline(always)]
    pub fn row_mut(&mut self, idx: usize) -> &mut [f32; 4] {
        &mut self.values[idx]
    }

    /// Q(cell, action).
    pub fn get(&self, c: Cell, a: Action) -> f32 {
        self.values[c.y as usize * self.width + c.x as usize][a as usize]
    }

    /// Sets Q(cell index, action index); out-of-range indices are ignored and reported as false.
    pub fn set_checked(&mut self, idx: usize, action: usize, q: f32) -> bool {
        match self.values.get_mut(idx) {
            Some(row) if action < 4 && q.is_finite() => {
                row[action] = q;
                true
            }
            _ => false,
        }
    }

    /// max_a Q(cell index, a).
    #[inline(always)]
    pub fn max(&self, idx: usize) -> f32 {
        max4(&self.values[idx])
    }

    /// The lowest-numbered action with the largest value: the deterministic greedy choice.
    #[inline(always)]
    pub fn argmax(&self, idx: usize) -> usize {
        argmax4(&self.values[idx])
    }

    /// All rows, row-major.
    pub fn rows(&self) -> &[[f32; 4]] {
        &self.values
    }

    /// All rows, mutable (e.g. to start from optimistic values).
    pub fn rows_mut(&mut self) -> &mut [[f32; 4]] {
        &mut self.values
    }
}

/// Larger of two values, NaN-unaware: one `maxss`, where `f32::max` spends three more
/// instructions on NaN rules. Q-values are always finite (every write path checks).
#[inline(always)]
pub fn fmax(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// Smaller of two values, NaN-unaware (see [`fmax`]).
#[inline(always)]
pub fn fmin(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

/// Largest of four values.
#[inline(always)]
pub fn max4(q: &[f32; 4]) -> f32 {
    fmax(fmax(q[0], q[1]), fmax(q[2], q[3]))
}

/// Smallest of four values.
#[inline(always)]
pub fn min4(q: &[f32; 4]) -> f32 {
    fmin(fmin(q[0], q[1]), fmin(q[2], q[3]))
}

/// Index of the first largest of four values.
#[inline(always)]
pub fn argmax4(q: &[f32; 4]) -> usize {
    let mut best = 0;
    for a in 1..4 {
        if q[a] > q[best] {
            best = a;
        }
    }
    best
}
