//! Plain-text tables for people: column-aligned, with a header, no Rust `Debug` values; and the
//! per-phase, per-goal table `qfleet experiment` prints.

use report::ExperimentResult;

/// A table of strings, left-aligned text and right-aligned numbers, two spaces apart.
pub struct TextTable {
    header: Vec<String>,
    right: Vec<bool>,
    rows: Vec<Vec<String>>,
}

impl TextTable {
    /// A table with these column headers; a header starting with `>` is right-aligned (the
    /// `>` is not printed).
    pub fn new(header: &[&str]) -> Self {
        Self {
            right: header.iter().map(|h| h.starts_with('>')).collect(),
            header: header
                .iter()
                .map(|h| h.trim_start_matches('>').to_string())
                .collect(),
            rows: Vec::new(),
        }
    }

    /// Adds a row (missing cells are blank, extra ones dropped).
    pub fn row(&mut self, cells: Vec<String>) {
        let mut cells = cells;
        cells.resize(self.header.len(), String::new());
        self.rows.push(cells);
    }

    /// The table as lines, each prefixed with `indent`.
    pub fn render(&self, indent: &str) -> String {
        let n = self.header.len();
        let width = |i: usize| {
            std::iter::once(&self.header[i])
                .chain(self.rows.iter().map(|r| &r[i]))
                .map(|s| s.chars().count())
                .max()
                .unwrap_or(0)
        };
        let widths: Vec<usize> = (0..n).map(width).collect();
        let line = |cells: &[String]| {
            let mut s = String::from(indent);
            for (i, c) in cells.iter().enumerate() {
                let pad = widths[i].saturating_sub(c.chars().count());
                if i > 0 {
                    s.push_str("  ");
                }
                if self.right[i] {
                    s.push_str(&" ".repeat(pad));
                    s.push_str(c);
                } else {
                    s.push_str(c);
                    if i + 1 < n {
                        s.push_str(&" ".repeat(pad));
                    }
                }
            }
            s.trim_end().to_string() + "\n"
        };
        let mut out = line(&self.header);
        for r in &self.rows {
            out.push_str(&line(r));
        }
        out
    }
}

fn or_dash<T>(v: Option<T>, f: impl Fn(T) -> String) -> String {
    v.map_or_else(|| "-".to_string(), f)
}

/// `qfleet experiment`'s human output for one seed: a heading, then per phase one row per goal
/// (goal, robots, merged path vs optimum per robot, when the merged table first gave optimal
/// paths in seconds and steps per robot, robots' own steps to the optimum, average steps per
/// episode, relayed discoveries).
pub fn experiment_table(r: &ExperimentResult) -> String {
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
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_align_and_numbers_are_right_aligned() {
        let mut t = TextTable::new(&["name", ">n"]);
        t.row(vec!["a".into(), "1".into()]);
        t.row(vec!["long name".into(), "100".into()]);
        let s = t.render("");
        let lines: Vec<&str> = s.lines().collect();
        assert_eq!(lines[0], "name         n");
        assert_eq!(lines[1], "a            1");
        assert_eq!(lines[2], "long name  100");
    }

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
        let s = experiment_table(&r);
        assert!(!s.contains("Some("), "{s}");
        assert!(!s.contains('['), "{s}");
        assert!(s.contains("58/58 -/57"), "{s}");
        assert!(s.contains("0 north"), "{s}");
        assert!(s.contains("1234"), "{s}");
        assert!(s.lines().all(|l| l.chars().count() < 160), "{s}");
    }
}
