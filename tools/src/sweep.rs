//! `qfleet sweep`: the measured value of sharing. For every manifest (one per map), for N robots
//! in `--robots`, every sharing mode in `--sharing` and every seed: one single-phase experiment
//! with all robots on the manifest's first goal from the first robot's start, each robot ending
//! its run after the episode in which its own greedy path became optimal. Reports env steps per
//! robot and wall time until the optimum (own table and merged table), average steps per episode,
//! and the speedup against a lone robot without sharing; writes a Markdown table, a JSON file and
//! an SVG plot of speedup against N.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use plotters::prelude::*;
use qfleet_args::ShareMode;
use serde::{Deserialize, Serialize};

use crate::experiment::{Rules, Supervision, load_plan, make_run_id, run_once};
use crate::plots::PALETTE;
use crate::term::{self, out};

/// Options of `qfleet sweep`.
#[derive(Debug, Args)]
pub struct SweepCmd {
    /// Manifests (one per map); a manifest whose map or scenario file is missing is skipped.
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Fleet sizes.
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8,16")]
    robots: Vec<u32>,
    /// Sharing modes to compare (the first N = 1 run without sharing is the baseline).
    #[arg(long, value_delimiter = ',', default_value = "none,hints")]
    sharing: Vec<String>,
    /// Seeds (one repetition each).
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    seeds: Vec<u64>,
    /// Seeds of the lone-robot baseline (N = 1, no sharing) when it needs more repetitions
    /// than the other cells (its spread sets the error of every ratio); default: `--seeds`.
    #[arg(long, value_delimiter = ',')]
    baseline_seeds: Vec<u64>,
    /// Sharing rules `APPLY/MERGE` to compare for the modes that share hints (apply: max,
    /// min, blend, latest; merge: max, min, mean, latest; `auto` = the rules that fit the
    /// learner: min/min for planning, max/max for the paper's learners); modes without hints
    /// run once.
    #[arg(long, value_delimiter = ',', default_value = "auto")]
    rules: Vec<Rules>,
    /// Learner of every run, overriding the manifests' `[learner] kind` (its other options
    /// stay).
    #[arg(long)]
    learner: Option<planner::LearnerKind>,
    /// Slow every robot of a run that shares to this many environment steps per second
    /// (robot-agent `--pace`), so that the robots of a run learn at the same time, as a fleet
    /// does: unpaced, a planning robot reaches its optimum within a few scheduler time slices,
    /// and N robots on 2 cores learn mostly one after another (the later ones warm-started from
    /// the earlier ones' fleet table). Runs without sharing are never paced: nothing passes
    /// between their robots, so their env steps are the same at any pace.
    #[arg(long, value_name = "STEPS_PER_S", value_parser = qfleet_args::parse_pace,
          default_value_t = DEFAULT_PACE)]
    pace: f64,
    /// Run every robot as fast as it can (no `--pace`).
    #[arg(long, conflicts_with = "pace")]
    unpaced: bool,
    /// Directory for the runs' files, sweep.json and sweep.md.
    #[arg(long, default_value = "results/sweep")]
    out: PathBuf,
    /// Where to write the SVG plot of speedup against N (default: `speedup.svg` beside
    /// sweep.json).
    #[arg(long)]
    svg: Option<PathBuf>,
    /// Run nothing: redraw the table and the plot from a previous sweep's `sweep.json`.
    #[arg(long)]
    replot: Option<PathBuf>,
}

/// The sweep's `--pace`, chosen on the suite's tuning half (BENCHMARKS.md, "Value of
/// sharing"): slow enough that four robots and the coordinator share two cores without
/// waiting for one another, fast enough that a lone robot's far pair on a 64×64 map takes
/// seconds, not minutes.
pub const DEFAULT_PACE: f64 = 100_000.0;

/// The pace of one run: `pace` for a run that shares (hints or discoveries), none for a run
/// that does not (its robots learn alone, so their env steps do not depend on the pace).
pub fn pace_for(mode: ShareMode, pace: Option<f64>) -> Option<f64> {
    if mode == ShareMode::None { None } else { pace }
}

/// One (map, N, sharing) cell of the sweep, averaged over seeds.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Row {
    /// Map name.
    pub map: String,
    /// Robots.
    pub robots: u32,
    /// Sharing mode.
    pub sharing: String,
    /// Apply/merge rules (`-` when no hints are shared).
    pub rules: String,
    /// Runs (seeds).
    pub runs: usize,
    /// Runs that failed on the bus and were run again.
    pub retries: usize,
    /// Robots (over all runs) whose own greedy path became optimal.
    pub robots_optimal: usize,
    /// Robots over all runs.
    pub robots_total: usize,
    /// Mean env steps per robot until its own greedy path was optimal, over the robots that
    /// got there (a survivor mean: read it with `robots_optimal`).
    pub robot_steps: Option<f64>,
    /// Median over all robots of the env steps until the own greedy path was optimal, a robot
    /// that never got there counting as infinitely many (`None` when half or more never did).
    pub median_steps: Option<f64>,
    /// `median_steps` / the lone robot's `median_steps`.
    pub median_ratio: Option<f64>,
    /// Mean env steps per robot until the merged table's greedy path was optimal.
    pub merged_steps: Option<f64>,
    /// Mean seconds until a robot's own greedy path was optimal.
    pub robot_time_s: Option<f64>,
    /// Mean seconds until the merged table's greedy path was optimal.
    pub merged_time_s: Option<f64>,
    /// Mean steps per episode.
    pub avg_steps: f64,
    /// Lone robot's steps (N = 1, no sharing) / `robot_steps`.
    pub speedup: Option<f64>,
    /// `robot_steps` / lone robot's steps.
    pub step_ratio: Option<f64>,
    /// Steps per second each robot was paced to (`None`: unpaced).
    #[serde(default)]
    pub pace: Option<f64>,
}

/// The table label of a manifest: its file stem without a `sweep-`/`sharing-` prefix (e.g.
/// `room-32-32-4-d35`), or the map name.
fn task_label(file: &Path, map: &str) -> String {
    file.file_stem()
        .and_then(|s| s.to_str())
        .map(|s| {
            s.trim_start_matches("sweep-")
                .trim_start_matches("sharing-")
        })
        .filter(|s| !s.is_empty())
        .map_or_else(|| map.to_string(), str::to_string)
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The median of `v` (sorted in place), `None` if empty or if it is infinite (half or more of
/// the values are `f64::INFINITY`, robots that never reached the optimum).
fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let m = if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    };
    m.is_finite().then_some(m)
}

impl SweepCmd {
    /// Runs the sweep.
    pub fn run(self) -> Result<()> {
        let pace = (!self.unpaced).then_some(self.pace);
        if let Some(json) = &self.replot {
            let text = std::fs::read_to_string(json)
                .with_context(|| format!("reading {}", json.display()))?;
            let rows: Vec<Row> = serde_json::from_str(&text)
                .with_context(|| format!("parsing {}", json.display()))?;
            let svg = self
                .svg
                .clone()
                .unwrap_or_else(|| json.parent().unwrap_or(Path::new(".")).join("speedup.svg"));
            plot(&svg, &rows)?;
            out!("{}", markdown(&rows, &[]).trim_end())?;
            out!("wrote {}", svg.display())?;
            return Ok(());
        }
        let svg = self
            .svg
            .clone()
            .unwrap_or_else(|| self.out.join("speedup.svg"));
        let mut modes = Vec::new();
        for s in &self.sharing {
            modes.push(
                ShareMode::parse(s).with_context(|| format!("--sharing: unknown mode {s:?}"))?,
            );
        }
        std::fs::create_dir_all(&self.out)?;
        let mut rows: Vec<Row> = Vec::new();
        let mut skipped = Vec::new();
        for file in &self.files {
            let base = match load_plan(file) {
                Ok(mut p) => {
                    if let Some(k) = self.learner {
                        p.manifest.learner.learner = k;
                    }
                    p
                }
                Err(e) => {
                    term::warn(&format!("sweep: skipping {}: {e:#}", file.display()));
                    skipped.push(format!("{}: {e:#}", file.display()));
                    continue;
                }
            };
            // one label per manifest: two tasks on one map must not share a results directory
            let map = task_label(file, &base.map.name);
            let mut baseline: Option<f64> = None;
            let mut baseline_median: Option<f64> = None;
            for &n in &self.robots {
                let cells: Vec<(ShareMode, Option<Rules>)> = modes
                    .iter()
                    .flat_map(|&mode| -> Vec<(ShareMode, Option<Rules>)> {
                        if matches!(mode, ShareMode::Hints | ShareMode::Both) {
                            self.rules.iter().map(|&r| (mode, Some(r))).collect()
                        } else {
                            vec![(mode, None)]
                        }
                    })
                    .collect();
                for (mode, rules) in cells {
                    let lone = n == 1 && mode == ShareMode::None;
                    let seeds = if lone && !self.baseline_seeds.is_empty() {
                        &self.baseline_seeds
                    } else {
                        &self.seeds
                    };
                    let learner_cfg = base.manifest.learner.config()?;
                    if let Some(w) = rules.and_then(|r| r.misfit(&learner_cfg)) {
                        term::warn(&format!("sweep: {map}: {w}"));
                    }
                    let resolved = rules.map(|r| r.resolve(&learner_cfg));
                    let label = match resolved {
                        Some(r) => format!("{}-{}-{}", mode.as_cli(), r.apply, r.merge),
                        None => mode.as_cli().to_string(),
                    };
                    let mut plan = base.clone();
                    let m = &mut plan.manifest;
                    m.robots = n;
                    m.sharing = mode;
                    m.stop_at_optimum = true;
                    m.phases.truncate(1);
                    m.starts = vec![Some(base.starts[0]); n as usize];
                    let g = base.assignment[0][0];
                    plan.starts = vec![base.starts[0]; n as usize];
                    plan.optimal = vec![base.optimal[0].clone(); n as usize];
                    plan.assignment = vec![vec![g; n as usize]];
                    let (mut own, mut merged, mut own_t, mut merged_t, mut avg) =
                        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
                    let mut ok = 0;
                    let mut retries = 0;
                    let mut all: Vec<f64> = Vec::new();
                    for &seed in seeds {
                        let tag = format!("n{n}-{label}-s{seed}");
                        // short: a run id is truncated to RUN_ID_MAX_LEN, its unique tail first
                        let mut id = make_run_id(Some("sw"), &format!("n{n}s{seed}"));
                        let dir = self.out.join(&map).join(&tag);
                        let _ = std::fs::remove_dir_all(&dir);
                        let rules = rules.unwrap_or_default();
                        let mut attempt = 0;
                        let r = loop {
                            let sup = Supervision {
                                pace: pace_for(mode, pace),
                                ..Supervision::default()
                            };
                            match run_once(&plan, seed, rules, &id, &dir, sup, None, None) {
                                Ok(r) => break r,
                                // a run that failed on the bus (not in the learning) is run
                                // again, up to twice, with a fresh run id; retries are reported
                                Err(e)
                                    if attempt < 2
                                        && !crate::STOP
                                            .load(std::sync::atomic::Ordering::SeqCst) =>
                                {
                                    attempt += 1;
                                    retries += 1;
                                    term::warn(&format!(
                                        "sweep: {map} {tag} failed ({e:#}); retrying"
                                    ));
                                    std::thread::sleep(std::time::Duration::from_secs(1));
                                    id = make_run_id(Some("sw"), &format!("n{n}s{seed}r{attempt}"));
                                    let _ = std::fs::remove_dir_all(&dir);
                                }
                                Err(e) => return Err(e.context(format!("{map} {tag}"))),
                            }
                        };
                        let _ = std::fs::write(
                            dir.join("result.json"),
                            serde_json::to_string_pretty(&r)?,
                        );
                        let Some(gp) = r.phases.first().and_then(|p| p.goals.first()) else {
                            continue;
                        };
                        ok += gp.robots_reached_optimal;
                        if let Some(p) = r.phases.first() {
                            all.extend(
                                p.robots.iter().map(|x| {
                                    x.steps_to_optimal.map_or(f64::INFINITY, |s| s as f64)
                                }),
                            );
                        }
                        if let Some(s) = gp.robot_steps_to_optimal {
                            own.push(s);
                        }
                        if let Some(t) = gp.robot_time_to_optimal_s {
                            own_t.push(t);
                        }
                        if let Some(s) = gp.merged_steps_per_robot {
                            merged.push(s);
                        }
                        if let Some(t) = gp.merged_time_to_optimal_s {
                            merged_t.push(t);
                        }
                        avg.push(gp.avg_steps);
                        term::warn(&progress_line(
                            &format!("{map} N={n} {label} seed {seed}"),
                            gp.robot_steps_to_optimal,
                            gp.merged_steps_per_robot,
                        ));
                    }
                    let robot_steps = mean(&own);
                    let median_steps = median(&mut all);
                    if lone {
                        baseline = robot_steps;
                        baseline_median = median_steps;
                    }
                    let median_ratio = match (baseline_median, median_steps) {
                        (Some(b), Some(s)) if b > 0.0 => Some(s / b),
                        _ => None,
                    };
                    let speedup = match (baseline, robot_steps) {
                        (Some(b), Some(s)) if s > 0.0 => Some(b / s),
                        _ => None,
                    };
                    rows.push(Row {
                        map: map.clone(),
                        robots: n,
                        sharing: mode.as_cli().into(),
                        rules: resolved.map_or("-".into(), |r| r.to_string()),
                        runs: seeds.len(),
                        retries,
                        robots_optimal: ok,
                        robots_total: seeds.len() * n as usize,
                        robot_steps,
                        median_steps,
                        median_ratio,
                        merged_steps: mean(&merged),
                        robot_time_s: mean(&own_t),
                        merged_time_s: mean(&merged_t),
                        avg_steps: mean(&avg).unwrap_or(0.0),
                        speedup,
                        step_ratio: speedup.map(|s| 1.0 / s),
                        pace: pace_for(mode, pace),
                    });
                }
            }
        }
        if rows.is_empty() && !skipped.is_empty() {
            // every manifest was skipped: nothing was measured
            return Err(
                anyhow::anyhow!("no manifest could be loaded ({})", skipped.join("; "))
                    .context(launcher::Exit::BadInput),
            );
        }
        let md = markdown(&rows, &skipped);
        std::fs::write(self.out.join("sweep.md"), &md)?;
        std::fs::write(
            self.out.join("sweep.json"),
            serde_json::to_string_pretty(&rows)?,
        )?;
        if let Some(dir) = svg.parent() {
            std::fs::create_dir_all(dir)?;
        }
        plot(&svg, &rows)?;
        out!("{}", md.trim_end())?;
        out!(
            "wrote {}/sweep.{{md,json}} and {}",
            self.out.display(),
            svg.display()
        )?;
        Ok(())
    }
}

fn f(v: Option<f64>, digits: usize) -> String {
    v.map_or("—".into(), |v| format!("{v:.digits$}"))
}

fn markdown(rows: &[Row], skipped: &[String]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| map | N | sharing | apply/merge | runs | median env steps/robot to own optimum (never = ∞) | ÷ lone robot | mean over robots that got there | ÷ lone robot | speedup (means) | env steps/robot to merged optimum | s to own optimum | s to merged optimum | avg steps/episode | robots optimal | pace (steps/s) |"
    );
    let _ = writeln!(
        s,
        "|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.0} | {}/{} | {} |",
            r.map,
            r.robots,
            r.sharing,
            r.rules,
            if r.retries > 0 {
                format!("{} ({} retried)", r.runs, r.retries)
            } else {
                r.runs.to_string()
            },
            f(r.median_steps, 0),
            r.median_ratio
                .map_or("—".into(), |v| format!("{:.0}%", v * 100.0)),
            f(r.robot_steps, 0),
            r.step_ratio
                .map_or("—".into(), |v| format!("{:.0}%", v * 100.0)),
            f(r.speedup, 2),
            f(r.merged_steps, 0),
            f(r.robot_time_s, 3),
            f(r.merged_time_s, 3),
            r.avg_steps,
            r.robots_optimal,
            r.robots_total,
            f(r.pace, 0)
        );
    }
    for k in skipped {
        let _ = writeln!(s, "\nskipped: {k}");
    }
    s
}

fn plot(path: &Path, rows: &[Row]) -> Result<()> {
    let mut series: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    for r in rows {
        // the median counts robots that never got there; the survivor mean would hide them
        let Some(sp) = r.median_ratio.filter(|v| *v > 0.0).map(|v| 1.0 / v) else {
            continue;
        };
        let key = if r.rules == "-" {
            format!("{} {}", r.map, r.sharing)
        } else {
            format!("{} {} {}", r.map, r.sharing, r.rules)
        };
        let x = f64::from(r.robots).log2();
        match series.iter_mut().find(|(k, _)| *k == key) {
            Some((_, v)) => v.push((x, sp)),
            None => series.push((key, vec![(x, sp)])),
        }
    }
    let ymax = series
        .iter()
        .flat_map(|(_, v)| v.iter().map(|p| p.1))
        .fold(2.0f64, f64::max)
        * 1.15;
    let xmax = rows
        .iter()
        .map(|r| f64::from(r.robots).log2())
        .fold(1.0f64, f64::max);
    let root = SVGBackend::new(path, (900, 540)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Value of sharing: lone robot's median env steps to optimum / the fleet's",
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(-0.2f64..xmax + 0.2, 0f64..ymax)?;
    chart
        .configure_mesh()
        .x_desc("robots N")
        .y_desc("speedup (median env steps per robot)")
        .x_labels(((xmax as usize) + 1).max(2))
        .x_label_formatter(&|x| format!("{}", 2f64.powf(x.round()) as u32))
        .draw()?;
    chart
        .draw_series(LineSeries::new(
            [(-0.2, 2.5), (xmax + 0.2, 2.5)],
            BLACK.mix(0.3),
        ))?
        .label("2.5× (= 40% of the steps)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK.mix(0.3)));
    let mut sizes: Vec<f64> = rows.iter().map(|r| f64::from(r.robots).log2()).collect();
    sizes.sort_by(f64::total_cmp);
    sizes.dedup();
    for (i, (label, pts)) in series.iter().enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        // a line only between neighbouring fleet sizes: a missing median (half or more of the
        // robots never optimal) leaves a gap rather than a line across it
        let segs: Vec<PathElement<(f64, f64)>> = pts
            .windows(2)
            .filter(|w| {
                let (a, b) = (
                    sizes.iter().position(|s| *s == w[0].0),
                    sizes.iter().position(|s| *s == w[1].0),
                );
                matches!((a, b), (Some(a), Some(b)) if b == a + 1)
            })
            .map(|w| PathElement::new(vec![w[0], w[1]], c.stroke_width(2)))
            .collect();
        chart
            .draw_series(segs)?
            .label(label.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
        chart.draw_series(pts.iter().map(|p| Circle::new(*p, 4, c.filled())))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

/// One run's line on stderr: when the robots' own tables and the merged table first gave the
/// optimal path, in env steps per robot (words, not `-`, when never).
fn progress_line(run: &str, own: Option<f64>, merged: Option<f64>) -> String {
    let when = |v: Option<f64>| {
        v.map_or("never reached".into(), |s| {
            format!("after {s:.0} steps/robot")
        })
    };
    format!(
        "sweep: {run}: own optimum {}, merged optimum {}",
        when(own),
        when(merged)
    )
}

#[cfg(test)]
mod tests {
    use super::{DEFAULT_PACE, ShareMode, median, pace_for};

    #[test]
    fn median_counts_robots_that_never_got_there() {
        assert_eq!(median(&mut []), None);
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, f64::INFINITY]), Some(4.0));
        assert_eq!(median(&mut [1.0, f64::INFINITY]), None);
        assert_eq!(median(&mut [1.0, 2.0, 3.0, f64::INFINITY]), Some(2.5));
    }

    #[test]
    fn only_runs_that_share_are_paced() {
        assert_eq!(pace_for(ShareMode::None, Some(1e5)), None);
        for m in [ShareMode::Hints, ShareMode::Discoveries, ShareMode::Both] {
            assert_eq!(pace_for(m, Some(1e5)), Some(1e5));
            assert_eq!(pace_for(m, None), None);
        }
        assert!(qfleet_args::parse_pace(&DEFAULT_PACE.to_string()).is_ok());
    }

    #[test]
    fn a_progress_line_says_never_in_words() {
        let s = super::progress_line("m N=2 none seed 1", Some(461_430.4), None);
        assert_eq!(
            s,
            "sweep: m N=2 none seed 1: own optimum after 461430 steps/robot, merged optimum never reached"
        );
        assert!(!s.contains(" - ") && !s.contains("Some("), "{s}");
    }
}
