//! An *intent horizon*: a robot's rankings for every cell it may stand on within the next `r`
//! ticks — the diamond of radius `r` (Manhattan distance) around its cell — so the coordinator
//! can resolve `r + 1` ticks before it needs that robot again.
//!
//! A robot's ranking at a cell depends only on the cell (its learned values do not change
//! while it moves), so a horizon is just many one-cell intents. Three pure pieces both sides
//! share:
//!
//! - the diamond's cell order ([`diamond_len`], [`diamond_index`], [`diamond_offset`]): rows
//!   from `dy = −r` to `r`, each from `dx = −(r − |dy|)` to `r − |dy|`;
//! - one ranking packed into a `u16` ([`pack`], [`unpack`]): move code + 1 in three bits per
//!   rank, best first from the low bits, 0 ends the ranking;
//! - [`Coverage`]: which ticks and cells a horizon answers, and the radius a robot uses so that
//!   every robot's horizon ends on the same tick ([`aligned_radius`]): the coordinator then
//!   wakes the whole fleet once per `h + 1` ticks instead of every tick, and of the woken
//!   robots only those that moved answer ([`Coverage::answers`]: a robot still on the center
//!   of its last full horizon, parked on its goal or queued behind another, keeps it).

use crate::moves::{Intent, IntentError, Move};
use planner::Cell;

/// Number of cells in the diamond of radius `r`: `2r² + 2r + 1`.
pub const fn diamond_len(r: u8) -> usize {
    let r = r as usize;
    2 * r * r + 2 * r + 1
}

/// The position of offset (`dx`, `dy`) in the diamond of radius `r`, `None` outside it.
pub fn diamond_index(r: u8, dx: i32, dy: i32) -> Option<usize> {
    let r = i32::from(r);
    if dx.abs() + dy.abs() > r {
        return None;
    }
    // rows above dy: widths 2(r − |y|) + 1 for y in −r..dy
    let before: i32 = (-r..dy).map(|y| 2 * (r - y.abs()) + 1).sum();
    let half = r - dy.abs();
    Some((before + dx + half) as usize)
}

/// The offset (`dx`, `dy`) at position `i` of the diamond of radius `r`, `None` past its end.
pub fn diamond_offset(r: u8, i: usize) -> Option<(i32, i32)> {
    let r = i32::from(r);
    let mut left = i as i64;
    for dy in -r..=r {
        let half = r - dy.abs();
        let width = i64::from(2 * half + 1);
        if left < width {
            return Some((left as i32 - half, dy));
        }
        left -= width;
    }
    None
}

/// The cell at offset (`dx`, `dy`) from `c`, `None` off the coordinate range (negative or
/// past `u16`); the caller checks the map.
pub fn offset_cell(c: Cell, dx: i32, dy: i32) -> Option<Cell> {
    let x = u16::try_from(i32::from(c.x) + dx).ok()?;
    let y = u16::try_from(i32::from(c.y) + dy).ok()?;
    Some(Cell::new(x, y))
}

/// An intent packed into 16 bits: per rank, best first from the low bits, the move's wire
/// byte + 1 in three bits; a zero group ends it.
pub fn pack(intent: &Intent) -> u16 {
    intent.moves().iter().enumerate().fold(0u16, |acc, (i, m)| {
        acc | (u16::from(m.byte() + 1) << (3 * i))
    })
}

/// Unpacks [`pack`]'s form of an untrusted message: refuses a group that is no move (6 or
/// 7), a repeated move, and bits left after the end (so every ranking has one encoding).
pub fn unpack(bits: u16) -> Result<Intent, IntentError> {
    let mut moves = [Move::Wait; 5];
    let mut n = 0;
    let mut rest = bits;
    while rest & 7 != 0 {
        let group = (rest & 7) as u8;
        let m = Move::from_byte(group - 1).ok_or(IntentError::BadMove {
            byte: group - 1,
            index: n,
        })?;
        if n == 5 {
            return Err(IntentError::TooLong { len: 6 });
        }
        moves[n] = m;
        n += 1;
        rest >>= 3;
    }
    if rest != 0 {
        // a group after the end marker: not a form pack writes
        return Err(IntentError::TooLong { len: 6 });
    }
    Intent::new(&moves[..n])
}

/// The radius a robot answering the grant of `tick` uses with horizon `h`, so that its horizon
/// ends on the tick before the next multiple of `h + 1`: every robot's horizon runs out on the
/// same tick, and the fleet is woken together once per `h + 1` ticks.
pub const fn aligned_radius(h: u8, tick: u32) -> u8 {
    let period = h as u32 + 1;
    h - (tick % period) as u8
}

/// What one horizon answers: ticks `from..=from + radius` for the cells within `radius` of
/// `center`. IO-free; the robot uses it to know when to answer again, the coordinator to know
/// when it must wait for a robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Coverage {
    /// The tick whose grant the horizon answers.
    pub from: u32,
    /// Where the robot stood at `from`.
    pub center: Cell,
    /// The diamond's radius.
    pub radius: u8,
}

impl Coverage {
    /// The position of `cell` in the diamond if the horizon answers `tick` at `cell`.
    pub fn index(&self, tick: u32, cell: Cell) -> Option<usize> {
        if tick < self.from || tick - self.from > u32::from(self.radius) {
            return None;
        }
        let dx = i32::from(cell.x) - i32::from(self.center.x);
        let dy = i32::from(cell.y) - i32::from(self.center.y);
        diamond_index(self.radius, dx, dy)
    }

    /// Whether the horizon answers `tick` with the robot on `cell`.
    pub fn covers(&self, tick: u32, cell: Cell) -> bool {
        self.index(tick, cell).is_some()
    }

    /// The position of `cell` in the diamond if, in a fleet on horizon `h`, the horizon still
    /// answers for a robot on `cell` at `tick`: its diamond holds every cell the robot can
    /// reach (one move a tick) until the fleet's horizons end, `distance + aligned_radius(h,
    /// tick) ≤ radius`. Rankings depend only on the cell, so a robot that has not moved off
    /// the center of a full horizon keeps it into the next period and is not asked again; one
    /// that moved answers with the fleet at the period's start, never in the middle of one (a
    /// horizon that held at the start holds to its end). The robot (when to answer) and the
    /// coordinator (when to wait for an answer) decide with this same rule. `h = 0` (one
    /// intent a tick) is [`Coverage::index`]: its tick only.
    pub fn answers(&self, h: u8, tick: u32, cell: Cell) -> Option<usize> {
        if h == 0 {
            return self.index(tick, cell);
        }
        if tick < self.from {
            return None;
        }
        let dx = i32::from(cell.x) - i32::from(self.center.x);
        let dy = i32::from(cell.y) - i32::from(self.center.y);
        if dx.abs() + dy.abs() + i32::from(aligned_radius(h, tick)) > i32::from(self.radius) {
            return None;
        }
        diamond_index(self.radius, dx, dy)
    }

    /// The last tick it answers.
    pub fn until(&self) -> u32 {
        self.from.saturating_add(u32::from(self.radius))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_diamond_is_numbered_row_by_row_and_both_ways_agree() {
        for r in 0..=8u8 {
            let n = diamond_len(r);
            let mut seen = 0;
            for i in 0..n {
                let (dx, dy) = diamond_offset(r, i).unwrap();
                assert!(dx.abs() + dy.abs() <= i32::from(r));
                assert_eq!(diamond_index(r, dx, dy), Some(i));
                seen += 1;
            }
            assert_eq!(diamond_offset(r, n), None);
            assert_eq!(seen, n);
            // every offset within r is numbered, nothing outside
            let inside = (-9..=9)
                .flat_map(|dy| (-9..=9).map(move |dx| (dx, dy)))
                .filter(|&(dx, dy)| diamond_index(r, dx, dy).is_some())
                .count();
            assert_eq!(inside, n);
        }
        assert_eq!(diamond_len(8), 145);
        assert_eq!(diamond_offset(1, 0), Some((0, -1)));
        assert_eq!(diamond_index(1, 0, 0), Some(2));
        assert_eq!(diamond_index(1, 1, 1), None);
    }

    #[test]
    fn a_packed_ranking_round_trips_and_a_malformed_one_is_refused() {
        let all =
            Intent::new(&[Move::Left, Move::Wait, Move::Up, Move::Down, Move::Right]).unwrap();
        for i in [all, Intent::NONE, Intent::new(&[Move::Wait]).unwrap()] {
            assert_eq!(unpack(pack(&i)), Ok(i));
        }
        assert_eq!(pack(&Intent::NONE), 0);
        // 6 and 7 name no move
        assert!(matches!(unpack(6), Err(IntentError::BadMove { .. })));
        // a repeated move
        assert!(matches!(
            unpack(1 | (1 << 3)),
            Err(IntentError::Duplicate { .. })
        ));
        // bits after the end marker
        assert!(unpack(1 | (1 << 6)).is_err());
        // every 16-bit value either fails or round-trips: one encoding per ranking
        for bits in 0..=u16::MAX {
            if let Ok(i) = unpack(bits) {
                assert_eq!(pack(&i), bits);
            }
        }
    }

    #[test]
    fn aligned_horizons_end_together() {
        let h = 4;
        assert_eq!(aligned_radius(h, 0), 4);
        assert_eq!(aligned_radius(h, 3), 1);
        assert_eq!(aligned_radius(h, 4), 0);
        assert_eq!(aligned_radius(h, 5), 4);
        assert_eq!(aligned_radius(0, 7), 0);
        for t in 0..40 {
            let end = t + u32::from(aligned_radius(h, t));
            assert_eq!((end + 1) % 5, 0, "tick {t}");
        }
    }

    #[test]
    fn a_horizon_is_kept_by_a_robot_that_did_not_move_and_renewed_with_the_fleet_otherwise() {
        let h = 2; // periods of 3 ticks: 0..=2, 3..=5, 6..=8
        let at = Cell::new(5, 5);
        let full = Coverage {
            from: 3,
            center: at,
            radius: 2,
        };
        // inside its own period, as `index`
        assert!(full.answers(h, 3, at).is_some());
        assert!(full.answers(h, 4, Cell::new(6, 5)).is_some());
        assert!(full.answers(h, 5, Cell::new(6, 6)).is_some());
        assert_eq!(full.answers(h, 2, at), None, "before its tick");
        assert_eq!(full.answers(h, 4, Cell::new(7, 6)), None, "outside");
        // the next periods: kept on its center, renewed at the period's start once it moved
        assert_eq!(full.answers(h, 6, at), full.index(3, at));
        assert!(full.answers(h, 60, at).is_some());
        assert_eq!(
            full.answers(h, 6, Cell::new(6, 5)),
            None,
            "moved: answers anew"
        );
        // a horizon kept at a period's start holds to the period's end wherever the robot goes
        for (tick, cell) in [
            (7, Cell::new(6, 5)),
            (8, Cell::new(7, 5)),
            (8, Cell::new(5, 3)),
        ] {
            assert!(full.answers(h, tick, cell).is_some(), "{tick} {cell:?}");
        }
        // a late, short horizon (made mid-period) ends with its period
        let late = Coverage {
            from: 4,
            center: at,
            radius: aligned_radius(h, 4),
        };
        assert!(late.answers(h, 5, Cell::new(5, 6)).is_some());
        assert_eq!(late.answers(h, 6, at), None, "a short horizon is renewed");
        // every reachable cell of a period whose start kept the horizon stays answered
        for start in [3u32, 6, 9] {
            if full.answers(h, start, at).is_none() {
                continue;
            }
            for k in 0..=u32::from(h) {
                for dy in -(k as i32)..=(k as i32) {
                    let w = k as i32 - dy.abs();
                    for dx in [-w, w] {
                        let c = offset_cell(at, dx, dy).unwrap();
                        assert!(full.answers(h, start + k, c).is_some(), "{start}+{k} {c:?}");
                    }
                }
            }
        }
        // horizon 0: its own tick only
        let one = Coverage {
            from: 4,
            center: at,
            radius: 0,
        };
        assert!(one.answers(0, 4, at).is_some());
        assert_eq!(one.answers(0, 5, at), None);
    }

    #[test]
    fn coverage_answers_its_ticks_within_its_diamond() {
        let c = Coverage {
            from: 10,
            center: Cell::new(5, 5),
            radius: 2,
        };
        assert!(c.covers(10, Cell::new(5, 5)));
        assert!(c.covers(12, Cell::new(7, 5)));
        assert!(c.covers(11, Cell::new(4, 6)));
        assert!(!c.covers(13, Cell::new(5, 5)), "past its last tick");
        assert!(!c.covers(9, Cell::new(5, 5)), "before its tick");
        assert!(!c.covers(11, Cell::new(7, 6)), "outside the diamond");
        assert_eq!(c.until(), 12);
        assert_eq!(c.index(10, Cell::new(5, 5)), Some(diamond_len(2) / 2));
    }
}
