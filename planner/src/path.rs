//! Shortest 4-connected paths on a [`Grid`], the yardstick learned paths are measured against.
//!
//! Lengths are counted in moves: a path of `n` cells is `n - 1` moves long. The searches come
//! from the `pathfinding` crate; this module only adapts the grid to them.

use crate::grid::{Cell, Grid};
use pathfinding::prelude::bfs;

/// A shortest 4-connected path from `start` to `goal`, both included; `None` if either end is
/// off the grid or blocked, or the goal cannot be reached.
pub fn bfs_path(grid: &Grid, start: Cell, goal: Cell) -> Option<Vec<Cell>> {
    if !grid.is_free(start) || !grid.is_free(goal) {
        return None;
    }
    bfs(&start, |c| grid.neighbors(*c), |c| *c == goal)
}

/// The number of moves on a shortest path from `start` to `goal`, or `None` as for [`bfs_path`].
pub fn shortest_moves(grid: &Grid, start: Cell, goal: Cell) -> Option<u32> {
    bfs_path(grid, start, goal).map(|p| (p.len() - 1) as u32)
}

/// For every cell in row-major order, the moves of a shortest path from it to `goal`;
/// `u32::MAX` for blocked cells and cells that cannot reach the goal (all of them if the goal is
/// blocked or off the grid).
///
/// Moves are reversible, so this is one search outward from the goal: a distance map for
/// judging learned paths or shaping rewards on every cell at once.
///
/// A plain breadth-first pass over the grid's index (a queue as long as the grid, no hashing):
/// `pathfinding`'s `dijkstra_reach` hashed every cell and took ~150 µs on a 32 × 32 map, which
/// every robot of a shared grid paid at once when the execution began.
pub fn bfs_distances(grid: &Grid, goal: Cell) -> Vec<u32> {
    let mut dist = vec![u32::MAX; grid.len()];
    if !grid.is_free(goal) {
        return dist;
    }
    let mut queue = Vec::with_capacity(grid.len());
    dist[grid.index(goal)] = 0;
    queue.push(goal);
    let mut head = 0;
    while let Some(&c) = queue.get(head) {
        head += 1;
        let next = dist[grid.index(c)] + 1;
        for n in grid.neighbors(c) {
            let d = &mut dist[grid.index(n)];
            if *d == u32::MAX {
                *d = next;
                queue.push(n);
            }
        }
    }
    dist
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::parse_ascii;

    fn grid(text: &str) -> Grid {
        parse_ascii("t", text.as_bytes()).unwrap().grid
    }

    #[test]
    fn distances_are_the_shortest_paths_of_every_cell() {
        for name in ["builtin:paper-20", "suite:maze-21-1", "suite:rooms-32-2"] {
            let g = crate::map::load_map(name).unwrap().grid;
            let goals = (0..g.len()).map(|i| g.cell(i)).filter(|c| g.is_free(*c));
            for goal in goals.step_by(97) {
                let d = bfs_distances(&g, goal);
                for (i, &got) in d.iter().enumerate() {
                    let want = shortest_moves(&g, g.cell(i), goal).unwrap_or(u32::MAX);
                    assert_eq!(got, want, "{name}: cell {:?} to {goal:?}", g.cell(i));
                }
            }
        }
        let g = grid("..#\n.##\n...\n");
        assert_eq!(
            bfs_distances(&g, Cell::new(0, 0))[g.index(Cell::new(2, 2))],
            4
        );
        assert!(
            bfs_distances(&g, Cell::new(1, 1))
                .iter()
                .all(|&d| d == u32::MAX),
            "a wall"
        );
        assert!(
            bfs_distances(&g, Cell::new(9, 9))
                .iter()
                .all(|&d| d == u32::MAX),
            "off the grid"
        );
    }

    #[test]
    fn path_goes_around_a_wall() {
        let g = grid("...\n##.\n...\n");
        let p = bfs_path(&g, Cell::new(0, 0), Cell::new(0, 2)).unwrap();
        assert_eq!(p.len(), 7);
        assert_eq!(p.first(), Some(&Cell::new(0, 0)));
        assert_eq!(p.last(), Some(&Cell::new(0, 2)));
        for w in p.windows(2) {
            assert_eq!(w[0].manhattan(w[1]), 1);
            assert!(g.is_free(w[1]));
        }
        assert_eq!(
            shortest_moves(&g, Cell::new(0, 0), Cell::new(0, 2)),
            Some(6)
        );
    }

    #[test]
    fn same_cell_is_zero_moves() {
        let g = grid("..\n..\n");
        assert_eq!(
            bfs_path(&g, Cell::new(1, 1), Cell::new(1, 1)),
            Some(vec![Cell::new(1, 1)])
        );
    }

    #[test]
    fn blocked_off_grid_and_unreachable_ends() {
        let g = grid(".#.\n.#.\n");
        assert_eq!(bfs_path(&g, Cell::new(0, 0), Cell::new(2, 0)), None);
        assert_eq!(bfs_path(&g, Cell::new(0, 0), Cell::new(1, 0)), None);
        assert_eq!(bfs_path(&g, Cell::new(1, 0), Cell::new(0, 0)), None);
        assert_eq!(bfs_path(&g, Cell::new(0, 0), Cell::new(9, 9)), None);
    }

    #[test]
    fn distances_from_every_cell() {
        let g = grid("...\n##.\n...\n.#.\n");
        let d = bfs_distances(&g, Cell::new(0, 2));
        let m = u32::MAX;
        assert_eq!(d, vec![6, 5, 4, m, m, 3, 0, 1, 2, 1, m, 3]);
        assert!(bfs_distances(&g, Cell::new(0, 1)).iter().all(|v| *v == m));
        assert!(bfs_distances(&g, Cell::new(7, 7)).iter().all(|v| *v == m));
    }
}
