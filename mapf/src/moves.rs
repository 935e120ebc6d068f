//! The five moves of the shared grid and a robot's *intent*: its moves ranked best first.
//!
//! On the wire a move is one byte: 0 wait, 1 up (y − 1), 2 right (x + 1), 3 down (y + 1),
//! 4 left (x − 1); any other byte is refused. An intent is at most five distinct moves, best
//! first; a move it does not name ranks after every named one (the resolver orders unnamed
//! moves by the coordinator's own BFS distance to the robot's goal).

use planner::{Action, Cell, Grid};

/// One tick's move of one agent; the discriminant is its wire byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum Move {
    /// Stay on the current cell.
    Wait = 0,
    /// Towards row 0 (y − 1).
    Up = 1,
    /// Towards the last column (x + 1).
    Right = 2,
    /// Towards the last row (y + 1).
    Down = 3,
    /// Towards column 0 (x − 1).
    Left = 4,
}

impl Move {
    /// All five moves in wire order: the fixed order ties are broken in.
    pub const ALL: [Move; 5] = [Move::Wait, Move::Up, Move::Right, Move::Down, Move::Left];
    /// The four moves that change cell, in wire order.
    pub const STEPS: [Move; 4] = [Move::Up, Move::Right, Move::Down, Move::Left];

    /// The move a wire byte stands for, or the byte back when it names none.
    pub const fn from_byte(b: u8) -> Option<Move> {
        match b {
            0 => Some(Move::Wait),
            1 => Some(Move::Up),
            2 => Some(Move::Right),
            3 => Some(Move::Down),
            4 => Some(Move::Left),
            _ => None,
        }
    }

    /// The move's wire byte.
    pub const fn byte(self) -> u8 {
        self as u8
    }

    /// The move of a planner action (a learner's Q-table column): the same direction.
    pub const fn of_action(a: Action) -> Move {
        match a {
            Action::Up => Move::Up,
            Action::Right => Move::Right,
            Action::Down => Move::Down,
            Action::Left => Move::Left,
        }
    }

    /// The (dx, dy) the move shifts by; (0, 0) for [`Move::Wait`].
    pub const fn delta(self) -> (i32, i32) {
        match self {
            Move::Wait => (0, 0),
            Move::Up => (0, -1),
            Move::Right => (1, 0),
            Move::Down => (0, 1),
            Move::Left => (-1, 0),
        }
    }

    /// The passable cell this move leads to from `c`, or `None` off the grid or into a wall.
    pub fn apply(self, grid: &Grid, c: Cell) -> Option<Cell> {
        let (dx, dy) = self.delta();
        let (x, y) = (
            i64::from(c.x) + i64::from(dx),
            i64::from(c.y) + i64::from(dy),
        );
        if !grid.contains(x, y) {
            return None;
        }
        let n = Cell::new(x as u16, y as u16);
        grid.is_free(n).then_some(n)
    }

    /// The move that leads from `a` to `b`, if they are equal or 4-neighbours.
    pub fn between(a: Cell, b: Cell) -> Option<Move> {
        let dx = i32::from(b.x) - i32::from(a.x);
        let dy = i32::from(b.y) - i32::from(a.y);
        Move::ALL.into_iter().find(|m| m.delta() == (dx, dy))
    }
}

impl TryFrom<u8> for Move {
    type Error = IntentError;

    fn try_from(b: u8) -> Result<Move, IntentError> {
        Move::from_byte(b).ok_or(IntentError::BadMove { byte: b, index: 0 })
    }
}

/// Why bytes or moves are not an intent.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum IntentError {
    /// A byte that is not a move (only 0..=4 are).
    #[error(
        "intent entry {index} is byte {byte}, not a move (0 wait, 1 up, 2 right, 3 down, 4 left)"
    )]
    BadMove {
        /// The offending byte.
        byte: u8,
        /// Its position in the intent.
        index: usize,
    },
    /// A move named twice: a ranking names each move once.
    #[error("intent names {mv:?} twice (entries {first} and {second})")]
    Duplicate {
        /// The repeated move.
        mv: Move,
        /// Where it first appears.
        first: usize,
        /// Where it appears again.
        second: usize,
    },
    /// More than five entries: there are only five moves.
    #[error("an intent ranks at most 5 moves, got {len}")]
    TooLong {
        /// Entries given.
        len: usize,
    },
}

/// A robot's ranked preference for its next move: up to five distinct moves, best first.
///
/// Fixed size and `Copy`: building, reading and passing intents never allocates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Intent {
    moves: [Move; 5],
    len: u8,
}

impl Intent {
    /// The empty intent: no preference, the resolver orders every move by distance to goal.
    pub const NONE: Intent = Intent {
        moves: [Move::Wait; 5],
        len: 0,
    };

    /// An intent from moves best first; refuses more than five or a repeated move.
    pub fn new(moves: &[Move]) -> Result<Intent, IntentError> {
        if moves.len() > 5 {
            return Err(IntentError::TooLong { len: moves.len() });
        }
        let mut out = Intent::NONE;
        for (i, &m) in moves.iter().enumerate() {
            if let Some(first) = out.rank(m) {
                return Err(IntentError::Duplicate {
                    mv: m,
                    first,
                    second: i,
                });
            }
            out.moves[i] = m;
            out.len += 1;
        }
        Ok(out)
    }

    /// An intent from wire bytes (an untrusted message): refuses bad bytes, repeats, > 5 entries.
    pub fn from_bytes(bytes: &[u8]) -> Result<Intent, IntentError> {
        if bytes.len() > 5 {
            return Err(IntentError::TooLong { len: bytes.len() });
        }
        let mut moves = [Move::Wait; 5];
        for (i, &b) in bytes.iter().enumerate() {
            moves[i] = Move::from_byte(b).ok_or(IntentError::BadMove { byte: b, index: i })?;
        }
        Intent::new(&moves[..bytes.len()])
    }

    /// The intent as wire bytes (the first `len()` entries of the array are meaningful).
    pub fn to_bytes(&self) -> ([u8; 5], usize) {
        let mut out = [0u8; 5];
        for (o, m) in out.iter_mut().zip(self.moves()) {
            *o = m.byte();
        }
        (out, self.len as usize)
    }

    /// The ranked moves, best first.
    pub fn moves(&self) -> &[Move] {
        &self.moves[..self.len as usize]
    }

    /// Number of ranked moves.
    pub fn len(&self) -> usize {
        self.len as usize
    }

    /// Whether the intent ranks nothing (no preference).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The most wanted move, if any.
    pub fn first(&self) -> Option<Move> {
        self.moves().first().copied()
    }

    /// The position of `m` in the ranking (0 = best), `None` when the intent does not name it.
    pub fn rank(&self, m: Move) -> Option<usize> {
        self.moves().iter().position(|x| *x == m)
    }

    /// The rank of `m` where unnamed moves tie for last place, after every named one.
    pub fn rank_or_last(&self, m: Move) -> usize {
        self.rank(m).unwrap_or(self.len())
    }

    /// An intent from per-move scores indexed by wire byte (higher is better, e.g. a robot's
    /// Q-values, with its own choice of a score for Wait): the scored moves best first, ties
    /// in wire order; `None` or NaN scores are left out (moves the robot does not offer).
    pub fn from_scores(scores: [Option<f32>; 5]) -> Intent {
        let mut keyed: [(f32, Move); 5] = [(0.0, Move::Wait); 5];
        let mut n = 0;
        for (m, s) in Move::ALL.into_iter().zip(scores) {
            if let Some(s) = s.filter(|s| !s.is_nan()) {
                keyed[n] = (s, m);
                n += 1;
            }
        }
        // stable: equal scores keep wire order
        keyed[..n].sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut out = Intent::NONE;
        for (i, k) in keyed[..n].iter().enumerate() {
            out.moves[i] = k.1;
        }
        out.len = n as u8;
        out
    }

    /// What a robot with converged values sends: its passable moves ranked by BFS distance to
    /// its goal (`dist`, row-major, as [`planner::path::bfs_distances`] gives), ties in wire
    /// order, [`Move::Wait`] just before the moves that increase the distance.
    ///
    /// Off-grid and wall moves are left out; an `at` off the grid gives the empty intent.
    pub fn toward(grid: &Grid, dist: &[u32], at: Cell) -> Intent {
        let d = |c: Cell| dist.get(grid.index(c)).copied().unwrap_or(u32::MAX);
        if !grid.is_free(at) {
            return Intent::NONE;
        }
        let here = d(at);
        // (class, distance, wire order): the moves that get closer, then Wait, then the rest
        let mut keyed: [(u8, u32, Move); 5] = [(3, u32::MAX, Move::Wait); 5];
        let mut n = 0;
        for m in Move::ALL {
            let Some(c) = m.apply(grid, at) else { continue };
            let dc = d(c);
            let class = match m {
                Move::Wait => 1,
                _ if dc < here => 0,
                _ => 2,
            };
            keyed[n] = (class, dc, m);
            n += 1;
        }
        keyed[..n].sort_unstable();
        let mut out = Intent::NONE;
        for (i, k) in keyed[..n].iter().enumerate() {
            out.moves[i] = k.2;
        }
        out.len = n as u8;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_planner_action_is_the_move_of_the_same_direction() {
        for a in Action::ALL {
            assert_eq!(Move::of_action(a).delta(), a.delta());
        }
    }
    use planner::map::parse_ascii;

    #[test]
    fn wire_bytes_round_trip_and_bad_bytes_are_refused() {
        for m in Move::ALL {
            assert_eq!(Move::from_byte(m.byte()), Some(m));
            assert_eq!(Move::try_from(m.byte()), Ok(m));
        }
        assert_eq!(Move::from_byte(5), None);
        assert!(Move::try_from(255).is_err());
        let i = Intent::from_bytes(&[2, 0, 1]).unwrap();
        assert_eq!(i.moves(), &[Move::Right, Move::Wait, Move::Up]);
        let (b, n) = i.to_bytes();
        assert_eq!(&b[..n], &[2, 0, 1]);
        assert_eq!(
            Intent::from_bytes(&[1, 7]),
            Err(IntentError::BadMove { byte: 7, index: 1 })
        );
        let e = Intent::from_bytes(&[1, 2, 1]).unwrap_err();
        assert_eq!(
            e,
            IntentError::Duplicate {
                mv: Move::Up,
                first: 0,
                second: 2
            }
        );
        assert!(e.to_string().contains("Up twice"), "{e}");
        assert_eq!(
            Intent::from_bytes(&[0, 1, 2, 3, 4, 0]),
            Err(IntentError::TooLong { len: 6 })
        );
        assert!(Intent::from_bytes(&[]).unwrap().is_empty());
        assert_eq!(Intent::new(&Move::ALL).unwrap().len(), 5);
    }

    #[test]
    fn ranks_and_unnamed_moves_tie_last() {
        let i = Intent::new(&[Move::Left, Move::Wait]).unwrap();
        assert_eq!(i.rank(Move::Wait), Some(1));
        assert_eq!(i.rank(Move::Up), None);
        assert_eq!(i.rank_or_last(Move::Up), 2);
        assert_eq!(i.first(), Some(Move::Left));
    }

    #[test]
    fn moves_between_and_apply() {
        let g = parse_ascii("t", b"..\n.#\n").unwrap().grid;
        let c = Cell::new(0, 0);
        assert_eq!(Move::Right.apply(&g, c), Some(Cell::new(1, 0)));
        assert_eq!(Move::Up.apply(&g, c), None);
        assert_eq!(Move::Left.apply(&g, c), None);
        assert_eq!(Move::Down.apply(&Grid::clone(&g), Cell::new(1, 0)), None);
        assert_eq!(Move::Wait.apply(&g, c), Some(c));
        assert_eq!(Move::between(c, Cell::new(0, 1)), Some(Move::Down));
        assert_eq!(Move::between(c, c), Some(Move::Wait));
        assert_eq!(Move::between(c, Cell::new(1, 1)), None);
    }

    #[test]
    fn from_scores_ranks_best_first_with_ties_in_wire_order() {
        let i = Intent::from_scores([Some(0.5), Some(1.0), None, Some(1.0), Some(f32::NAN)]);
        assert_eq!(i.moves(), &[Move::Up, Move::Down, Move::Wait]);
        assert!(Intent::from_scores([None; 5]).is_empty());
    }

    #[test]
    fn toward_ranks_by_distance_then_wait_then_away() {
        // goal at the right end of a 5x2 open grid
        let g = parse_ascii("t", b".....\n.....\n").unwrap().grid;
        let d = planner::path::bfs_distances(&g, Cell::new(4, 0));
        let i = Intent::toward(&g, &d, Cell::new(2, 1));
        // Up and Right both get closer (wire order: Up first), then Wait, then Left
        assert_eq!(i.moves(), &[Move::Up, Move::Right, Move::Wait, Move::Left]);
        let at_goal = Intent::toward(&g, &d, Cell::new(4, 0));
        assert_eq!(at_goal.moves(), &[Move::Wait, Move::Down, Move::Left]);
    }
}
