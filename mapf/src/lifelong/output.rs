//! A lifelong run in the League of Robot Runners 2023 output format, the one its visualiser
//! PlanViz (MAPF-Competition/PlanViz, `script/plan_config.py`) loads: `actionModel` `"MAPF"`
//! (4-connected moves and wait, no rotation), `start` as `[row, col, "E"]`, each robot's moves
//! as one comma-separated string (PlanViz's MAPF codes: `R` col + 1, `L` col − 1, `U` row + 1,
//! `D` row − 1, `W` wait), `events` per robot as `[task id, tick, "assigned" | "finished"]` and
//! `tasks` as `[task id, row, col]`, indexed by task id. Robot `k`'s `c`-th goal is task id
//! `c * teamSize + k` (the round-robin deal, so an id names one dealing even when the task list
//! wraps round).

use planner::Cell;
use serde_json::{Value, json};

use super::Problem;

/// PlanViz's code of the move from `a` to `b` (one tick, 4-connected or wait).
fn code(a: Cell, b: Cell) -> &'static str {
    match (
        i32::from(b.x) - i32::from(a.x),
        i32::from(b.y) - i32::from(a.y),
    ) {
        (1, 0) => "R",
        (-1, 0) => "L",
        (0, 1) => "U",
        (0, -1) => "D",
        _ => "W",
    }
}

/// The competition's output JSON of a run of `problem`: `paths[k]` is robot `k`'s cell at ticks
/// 0..=T, `finished[k]` the ticks at which it reached its goals (in order), `planner_times` the
/// seconds each tick's resolution took.
pub fn competition_output(
    problem: &Problem,
    paths: &[Vec<Cell>],
    finished: &[Vec<u32>],
    planner_times: &[f64],
) -> Value {
    let team = problem.team();
    let ticks = paths.first().map_or(0, |p| p.len().saturating_sub(1));
    let reveal = u64::from(problem.reveal());
    let moves: Vec<String> = paths
        .iter()
        .map(|p| {
            p.windows(2)
                .map(|w| code(w[0], w[1]))
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect();
    let mut max_id = 0u64;
    let events: Vec<Vec<Value>> = (0..team)
        .map(|k| {
            let done = finished.get(k).map_or(&[][..], Vec::as_slice);
            let mut ev = Vec::new();
            // goal c is revealed at the start for c < reveal, else when goal c - reveal is done
            let dealt = done.len() as u64 + reveal;
            for c in 0..dealt {
                let at = if c < reveal {
                    0
                } else {
                    done[(c - reveal) as usize]
                };
                let id = c * team as u64 + k as u64;
                max_id = max_id.max(id);
                ev.push(json!([id, at, "assigned"]));
                if let Some(&t) = done.get(c as usize) {
                    ev.push(json!([id, t, "finished"]));
                }
            }
            ev.sort_by_key(|e| e[1].as_u64());
            ev
        })
        .collect();
    let tasks: Vec<Value> = (0..=max_id)
        .map(|id| {
            let c = problem.tasks()[(id % problem.tasks().len() as u64) as usize];
            json!([id, c.y, c.x])
        })
        .collect();
    let start: Vec<Value> = problem
        .starts()
        .iter()
        .map(|c| json!([c.y, c.x, "E"]))
        .collect();
    let reached: usize = finished.iter().map(Vec::len).sum();
    json!({
        "actionModel": "MAPF",
        "AllValid": "Yes",
        "teamSize": team,
        "start": start,
        "numTaskFinished": reached,
        "sumOfCost": team * ticks,
        "makespan": ticks,
        "actualPaths": moves,
        "plannerPaths": moves,
        "plannerTimes": planner_times,
        "errors": [],
        "events": events,
        "tasks": tasks,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use planner::map::parse_ascii;

    #[test]
    fn moves_events_and_tasks_read_as_planviz_reads_them() {
        let g = parse_ascii("t", b"...\n...\n").unwrap().grid;
        let p = Problem::new(
            g,
            &[Cell::new(0, 0)],
            1,
            vec![Cell::new(1, 1), Cell::new(0, 0)],
            1,
        )
        .unwrap();
        let path = vec![
            Cell::new(0, 0),
            Cell::new(1, 0),
            Cell::new(1, 1),
            Cell::new(1, 1),
        ];
        let v = competition_output(&p, &[path], &[vec![2]], &[0.1, 0.1, 0.1]);
        assert_eq!(
            v["actualPaths"][0], "R,U,W",
            "U is row + 1 in PlanViz's MAPF model"
        );
        assert_eq!(v["start"][0], json!([0, 0, "E"]));
        assert_eq!(v["makespan"], 3);
        assert_eq!(v["numTaskFinished"], 1);
        assert_eq!(
            v["events"][0],
            json!([[0, 0, "assigned"], [0, 2, "finished"], [1, 2, "assigned"]])
        );
        // PlanViz asserts tasks[tid][0] == tid and reads (row, col)
        assert_eq!(v["tasks"], json!([[0, 1, 1], [1, 0, 0]]));
    }
}
