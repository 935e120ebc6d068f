//! The human summaries `qfleet` prints of typed results, as text (the caller prints it):
//! [`run`] for a run's [`RunResult`], [`experiment`] for one seed of an experiment. Kept beside
//! the types so that a field and the line that shows it change together.

use std::fmt::Write;
use std::path::Path;

use crate::table::TextTable;
use crate::{ExperimentResult, GridEnd, GridResult, LatencyStats, LifelongResult, RunResult};

fn or_dash<T>(v: Option<T>, f: impl Fn(T) -> String) -> String {
    v.map_or_else(|| "-".to_string(), f)
}

/// `qfleet experiment`'s human output for one seed: a heading, then per phase one row per goal
/// (goal, robots, merged path vs optimum per robot, when the merged table first gave optimal
/// paths in seconds and steps per robot, robots' own steps to the optimum, average steps per
/// episode, relayed discoveries), a blank line, and on a shared grid a line per phase.
pub fn experiment(r: &ExperimentResult) -> String {
    let mut out = format!(
        "experiment {}, seed {}: {} robots on {}, sharing {}, {:.2} s ({} discoveries received, {} relayed, {} rejected)\n",
        r.name,
        r.seed,
        r.robots,
        r.map,
        r.sharing,
        r.wall_s,
        r.discoveries_received,
        r.relays_sent,
        r.rejected
    );
    for p in &r.phases {
        out.push_str(&format!(
            "  phase {} ({}): {} episodes per robot, {:.2} s\n",
            p.phase, p.name, p.episodes, p.wall_s
        ));
        let mut t = TextTable::new(&[
            "goal",
            "cell",
            "robots",
            "merged path / optimum",
            "merged optimal",
            ">at s",
            ">steps/robot",
            ">own optimum",
            ">own steps",
            ">avg steps",
            ">relayed",
        ]);
        for g in &p.goals {
            let paths: Vec<String> = g
                .merged_path_len
                .iter()
                .zip(&g.optimal_path_len)
                .map(|(m, o)| format!("{}/{o}", or_dash(*m, |v| v.to_string())))
                .collect();
            let robots: Vec<String> = g.robots.iter().map(u32::to_string).collect();
            t.row(vec![
                format!("{} {}", g.goal, g.name),
                g.cell.clone(),
                robots.join(","),
                paths.join(" "),
                if g.merged_optimal { "yes" } else { "no" }.into(),
                or_dash(g.merged_time_to_optimal_s, |v| format!("{v:.3}")),
                or_dash(g.merged_steps_per_robot, |v| format!("{v:.0}")),
                format!("{}/{}", g.robots_reached_optimal, g.robots.len()),
                or_dash(g.robot_steps_to_optimal, |v| format!("{v:.0}")),
                format!("{:.1}", g.avg_steps),
                g.relayed.to_string(),
            ]);
        }
        out.push_str(&t.render("    "));
    }
    // a blank line, then in a shared world each phase's execution, as a MAPF user reads it
    out.push('\n');
    for ph in &r.phases {
        if let Some(g) = &ph.grid {
            let _ = writeln!(
                out,
                "phase {} ({}) on the shared grid: {}",
                ph.phase,
                ph.name,
                g.line()
            );
        }
    }
    out
}

/// Why the discovery counts are what they are, after them on the summary line: relayed but not
/// used by `--share hints` (the default: on the held-out maps they did not lower the env steps
/// to the optimum beyond the spread of runs, docs/fleet.md), or none made at all.
fn discoveries_note(sent: u64, used: bool) -> &'static str {
    match (sent, used) {
        (0, _) => {
            " (none: the traditional learner makes none, the others once a robot reaches the goal)"
        }
        (_, false) => " (relayed, unused: --share hints; --share both uses them)",
        (_, true) => "",
    }
}

fn fmt_us(ns: u64) -> String {
    format!("{:.1} µs", ns as f64 / 1e3)
}

/// `qfleet run`'s human output: the run's heading, a line per robot, discoveries, the latency
/// table, throughput, the shared or lifelong grid's figures, and (unless the out directory
/// `out` is a temporary one) the files written there; `discoveries_used`: the robots took
/// relayed discoveries (`--share discoveries|both`).
pub fn run(r: &RunResult, out: &Path, temp_out: bool, discoveries_used: bool) -> String {
    let mut s = String::new();
    // one task for the fleet, or on a shared grid a start and goal per robot (its grid line)
    let task = match &r.grid {
        None => format!("{} → {}", r.start, r.goal),
        Some(g) => format!(
            "one shared grid, starts and goals from {}",
            g.scen.as_deref().unwrap_or("the scenario")
        ),
    };
    let _ = writeln!(
        s,
        "run {}: {} robots on {} ({task}), wait {}, apply {}, merge {}",
        r.run_id,
        r.robots.len(),
        r.map,
        r.wait,
        r.apply.as_deref().unwrap_or("?"),
        r.merge
    );
    for x in &r.robots {
        let p = |v: Option<u32>| v.map_or("loops".to_string(), |v| v.to_string());
        let _ = writeln!(
            s,
            "  robot {:>3}  {:8}  final path {:>5} (own {:>5}, optimal {:>5})  avg steps {:8.1}  hints applied {}",
            x.robot_id,
            x.status,
            p(x.final_path_len),
            p(x.own_final_path_len),
            p(x.optimal_path_len),
            x.avg_steps,
            x.hints_applied
        );
    }
    let _ = writeln!(
        s,
        "  all robots optimal: {}   discoveries sent {} / received {}{}",
        r.all_optimal,
        r.discoveries_sent,
        r.discoveries_received,
        discoveries_note(r.discoveries_sent, discoveries_used)
    );
    if !r.without_path.is_empty() {
        let ids: Vec<String> = r.without_path.iter().map(u32::to_string).collect();
        let _ = writeln!(
            s,
            "  without a path     robot(s) {} stopped before they found one",
            ids.join(", ")
        );
    }
    s.push_str("  latency            count      p50        p90        p99        p99.9      max\n");
    for (k, l) in &r.latency_ns {
        latency_row(&mut s, k, l);
    }
    let _ = writeln!(
        s,
        "  throughput         {:.0} messages/s, {:.0} Q-updates merged/s over {:.3} s",
        r.throughput.messages_per_s, r.throughput.q_updates_merged_per_s, r.throughput.active_s
    );
    if let Some(g) = &r.grid {
        grid(&mut s, g);
    }
    if let Some(l) = &r.lifelong {
        lifelong(&mut s, l);
    }
    if !temp_out {
        let files = match (&r.grid, &r.lifelong) {
            (Some(_), _) => ",paths.txt",
            (None, Some(_)) => ",paths.txt,lorr-output.json",
            _ => "",
        };
        let _ = writeln!(
            s,
            "  wrote              {}/{{result.json,robot-*.json,latency-*.hgrm,*.log{files}}}",
            out.display(),
        );
    }
    s
}

/// The shared grid's figures, as a MAPF user reads them.
fn grid(s: &mut String, g: &GridResult) {
    let ended = match g.ended {
        GridEnd::Arrived => "every robot arrived",
        GridEnd::TickLimit => "the tick limit (--max-ticks) passed",
        GridEnd::Unsolvable => "no plan brings every robot home (proved by search)",
        GridEnd::Stopped => "stopped",
    };
    let _ = writeln!(
        s,
        "  shared grid        {} robots: {ended} ({} of {} arrived) after {} ticks",
        g.agents, g.arrived, g.agents, g.ticks
    );
    let _ = writeln!(
        s,
        "  sum of costs       {} (lower bound {}, ratio {:.3}), makespan {}, conflicts {}",
        g.sum_of_costs, g.lower_bound, g.soc_ratio, g.makespan, g.conflicts
    );
    let _ = writeln!(
        s,
        "  moves              {} waits, {} denied moves, {} intents rejected; {:.0} ticks/s",
        g.waits, g.denied_moves, g.intents_rejected, g.ticks_per_s
    );
    for (k, l) in [
        ("tick", &g.tick_latency_ns),
        ("grant→intent", &g.intent_latency_ns),
        ("resolve", &g.resolve_latency_ns),
    ] {
        latency_row(s, k, l);
    }
}

/// A lifelong grid's figures: throughput first (the League of Robot Runners' score), then how
/// the goals spread over the fleet and what decided the moves.
fn lifelong(s: &mut String, l: &LifelongResult) {
    let ended = if l.ended == "ticks" {
        "ran its ticks"
    } else {
        "stopped early"
    };
    let _ = writeln!(
        s,
        "  lifelong grid      {} robots, {} ticks ({ended}): {} goals reached, throughput {:.3} \
         goals/tick ({:.3} in the second half)",
        l.agents, l.ticks, l.goals_reached, l.throughput, l.throughput_2nd_half
    );
    let mut goals = l.robot_goals.clone();
    goals.sort_unstable();
    let at = |q: usize| {
        goals
            .get(q * goals.len().saturating_sub(1) / 2)
            .copied()
            .unwrap_or(0)
    };
    let _ = writeln!(
        s,
        "  goals per robot    min {}, median {}, max {}; robots lost {}; conflicts {}",
        at(0),
        at(1),
        at(2),
        l.robots_lost.len(),
        l.conflicts
    );
    let g = &l.learning;
    let _ = writeln!(
        s,
        "  learning ahead     {} goals learned ({} warm-started from the fleet table of their \
         cell), {:.0} env steps per goal ({:.0} warm, {:.0} cold), {:.3} s each",
        g.goals_learned,
        g.warm_started,
        g.env_steps_per_goal,
        g.env_steps_per_warm_goal,
        g.env_steps_per_cold_goal,
        g.learn_s_per_goal
    );
    let _ = writeln!(
        s,
        "  robot-ticks        {} towards a goal already learned, {} towards one not yet (every \
         move ranked by map distance; a tick never waits for a learning robot)",
        g.ticks_goal_learned, g.ticks_goal_unlearned
    );
    let _ = writeln!(
        s,
        "  speed              {} ticks in {:.3} s ({:.0} ticks/s)",
        l.ticks, l.exec_s, l.ticks_per_s
    );
    latency_row(s, "tick", &l.tick_latency_ns);
}

/// One row of the human summary's latency table: count, p50, p90, p99, p99.9, max.
fn latency_row(s: &mut String, k: &str, l: &LatencyStats) {
    let _ = writeln!(
        s,
        "  {k:18} {:>6}  {:>10} {:>10} {:>10} {:>10} {:>10}",
        l.count,
        fmt_us(l.p50),
        fmt_us(l.p90),
        fmt_us(l.p99),
        fmt_us(l.p999),
        fmt_us(l.max)
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_experiment_table_has_no_debug_values() {
        let json = serde_json::json!({
            "name": "two", "run_id": "r", "seed": 1, "map": "paper-30", "robots": 2,
            "sharing": "both", "discoveries_received": 3, "relays_sent": 2,
            "q_updates_merged": 10, "rejected": 0, "wall_s": 1.5,
            "phases": [{
                "phase": 0, "name": "learn", "episodes": 100, "wall_s": 1.2, "robots": [],
                "goals": [{
                    "goal": 0, "name": "north", "cell": "(3,4)", "robots": [0, 1],
                    "merged_path_len": [58, null], "optimal_path_len": [58, 57],
                    "merged_optimal": false, "merged_time_to_optimal_s": null,
                    "merged_steps_per_robot": null, "robot_steps_to_optimal": 1234.4,
                    "robots_reached_optimal": 1, "robot_time_to_optimal_s": 0.5,
                    "avg_steps": 45.12, "all_robots_optimal": false, "relayed": 2
                }]
            }]
        });
        let r: ExperimentResult = serde_json::from_value(json).unwrap();
        let s = experiment(&r);
        assert!(!s.contains("Some("), "{s}");
        assert!(!s.contains('['), "{s}");
        assert!(s.contains("58/58 -/57"), "{s}");
        assert!(s.contains("0 north"), "{s}");
        assert!(s.contains("1234"), "{s}");
        assert!(!s.contains("shared grid"), "{s}");
        assert!(s.lines().all(|l| l.chars().count() < 160), "{s}");
    }

    #[test]
    fn a_latency_row_is_in_microseconds_under_its_columns() {
        let mut s = String::new();
        let l = LatencyStats {
            count: 3,
            p50: 1_500,
            p90: 2_000,
            p99: 2_500,
            p999: 3_000,
            max: 12_340,
            ..LatencyStats::default()
        };
        latency_row(&mut s, "hint", &l);
        assert_eq!(
            s,
            "  hint                    3      1.5 µs     2.0 µs     2.5 µs     3.0 µs    12.3 µs\n"
        );
    }
}
