//! The grid world the learner acts in: moves, collisions, rewards and terminal cells.
//!
//! Moving into an obstacle or off the grid leaves the robot where it is, costs the collision
//! reward and does **not** end the episode (the paper's "no restart"). Entering the goal, or an
//! active pseudo target, ends it.

use crate::grid::{Action, Cell, Grid};
use serde::{Deserialize, Serialize};

/// Marker in the move table for a move that collides.
const BLOCKED: u32 = u32::MAX;

/// Rewards of the three kinds of transition.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rewards {
    /// Reward for entering the goal: the value every learned Q-value is a discounted share of.
    pub goal: f32,
    /// Reward for bumping into an obstacle or the border (the robot stays put).
    pub collision: f32,
    /// Reward for any other move.
    pub step: f32,
}

impl Default for Rewards {
    fn default() -> Self {
        Rewards {
            goal: 1.0,
            collision: -1.0,
            step: 0.0,
        }
    }
}

/// What a cell does when the robot enters it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum CellKind {
    /// An ordinary free cell.
    Plain = 0,
    /// The true goal: ends the episode with the goal reward.
    Goal = 1,
    /// An active pseudo target: ends the episode with its own value.
    Pseudo = 2,
}

/// How a transition ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Transition {
    /// Moved to a plain cell.
    Moved,
    /// Hit an obstacle or the border and stayed.
    Collided,
    /// Entered the goal.
    Goal,
    /// Entered an active pseudo target.
    Pseudo,
}

/// The environment: a precomputed move table, cell kinds and terminal values.
#[derive(Debug, Clone)]
pub struct Env {
    grid: Grid,
    next: Vec<u32>,
    kind: Vec<CellKind>,
    terminal_value: Vec<f32>,
    start: u32,
    goal: u32,
    rewards: Rewards,
}

impl Env {
    /// An environment for a grid with start and goal (both must be free cells on the grid).
    pub fn new(grid: &Grid, start: Cell, goal: Cell, rewards: Rewards) -> Env {
        let n = grid.len();
        let mut next = vec![BLOCKED; n * 4];
        for idx in 0..n {
            let c = grid.cell(idx);
            if !grid.is_free(c) {
                continue;
            }
            for a in Action::ALL {
                if let Some(nc) = grid.neighbor(c, a) {
                    next[idx * 4 + a as usize] = grid.index(nc) as u32;
                }
            }
        }
        let mut kind = vec![CellKind::Plain; n];
        let mut terminal_value = vec![0.0; n];
        let g = grid.index(goal);
        kind[g] = CellKind::Goal;
        terminal_value[g] = rewards.goal;
        Env {
            grid: grid.clone(),
            next,
            kind,
            terminal_value,
            start: grid.index(start) as u32,
            goal: g as u32,
            rewards,
        }
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Start cell index.
    pub fn start(&self) -> u32 {
        self.start
    }

    /// Goal cell index.
    pub fn goal(&self) -> u32 {
        self.goal
    }

    /// The rewards in force.
    pub fn rewards(&self) -> Rewards {
        self.rewards
    }

    /// Takes action `a` in cell `s`: the next cell, the reward and how it ended.
    #[inline(always)]
    pub fn step(&self, s: u32, a: usize) -> (u32, f32, Transition) {
        let n = self.next[s as usize * 4 + a];
        if n == BLOCKED {
            return (s, self.rewards.collision, Transition::Collided);
        }
        match self.kind[n as usize] {
            CellKind::Plain => (n, self.rewards.step, Transition::Moved),
            CellKind::Goal => (n, self.terminal_value[n as usize], Transition::Goal),
            CellKind::Pseudo => (n, self.terminal_value[n as usize], Transition::Pseudo),
        }
    }

    /// The cell reached by `a` from `s`, or `None` when the move collides.
    #[inline(always)]
    pub fn peek(&self, s: u32, a: usize) -> Option<u32> {
        let n = self.next[s as usize * 4 + a];
        (n != BLOCKED).then_some(n)
    }

    /// The kind of a cell index.
    pub fn kind(&self, idx: u32) -> CellKind {
        self.kind[idx as usize]
    }

    /// Marks a free, non-goal cell as a terminal pseudo target of the given value; false if not allowed.
    pub fn set_pseudo(&mut self, idx: u32, value: f32) -> bool {
        let i = idx as usize;
        if i >= self.kind.len()
            || !self.grid.free_flags()[i]
            || self.kind[i] == CellKind::Goal
            || i == self.start as usize
            || !value.is_finite()
        {
            return false;
        }
        self.kind[i] = CellKind::Pseudo;
        self.terminal_value[i] = value;
        true
    }

    /// Turns a pseudo target back into a plain cell.
    pub fn clear_pseudo(&mut self, idx: u32) {
        let i = idx as usize;
        if self.kind.get(i) == Some(&CellKind::Pseudo) {
            self.kind[i] = CellKind::Plain;
            self.terminal_value[i] = 0.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env() -> Env {
        // . #
        // . G
        let g = Grid::new(2, 2, vec![true, false, true, true]).unwrap();
        Env::new(&g, Cell::new(0, 0), Cell::new(1, 1), Rewards::default())
    }

    #[test]
    fn collision_keeps_position_and_does_not_end() {
        let e = env();
        let (n, r, t) = e.step(0, Action::Right as usize);
        assert_eq!((n, t), (0, Transition::Collided));
        assert_eq!(r, -1.0);
        let (n, _, t) = e.step(0, Action::Up as usize);
        assert_eq!((n, t), (0, Transition::Collided));
    }

    #[test]
    fn goal_and_pseudo_are_terminal() {
        let mut e = env();
        let (n, r, t) = e.step(2, Action::Right as usize);
        assert_eq!((n, r, t), (3, 1.0, Transition::Goal));
        assert!(e.set_pseudo(2, 0.25));
        assert_eq!(
            e.step(0, Action::Down as usize),
            (2, 0.25, Transition::Pseudo)
        );
        assert!(!e.set_pseudo(1, 0.25), "an obstacle is never a target");
        assert!(!e.set_pseudo(3, 0.25), "the goal stays the goal");
        e.clear_pseudo(2);
        assert_eq!(
            e.step(0, Action::Down as usize),
            (2, 0.0, Transition::Moved)
        );
    }
}
