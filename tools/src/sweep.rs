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
use qfleet_args::Sharing;
use serde::Serialize;

use crate::experiment::{load_plan, make_run_id, run_once};
use crate::plots::PALETTE;

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
    /// Directory for the runs' files, sweep.json and sweep.md.
    #[arg(long, default_value = "results/sweep")]
    out: PathBuf,
    /// Where to write the SVG plot of speedup against N.
    #[arg(long, default_value = "docs/sharing-speedup.svg")]
    svg: PathBuf,
}

/// One (map, N, sharing) cell of the sweep, averaged over seeds.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    /// Map name.
    pub map: String,
    /// Robots.
    pub robots: u32,
    /// Sharing mode.
    pub sharing: String,
    /// Runs (seeds).
    pub runs: usize,
    /// Robots (over all runs) whose own greedy path became optimal.
    pub robots_optimal: usize,
    /// Robots over all runs.
    pub robots_total: usize,
    /// Mean env steps per robot until its own greedy path was optimal.
    pub robot_steps: Option<f64>,
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
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

impl SweepCmd {
    /// Runs the sweep.
    pub fn run(self) -> Result<()> {
        let mut modes = Vec::new();
        for s in &self.sharing {
            modes
                .push(Sharing::parse(s).with_context(|| format!("--sharing: unknown mode {s:?}"))?);
        }
        std::fs::create_dir_all(&self.out)?;
        let mut rows: Vec<Row> = Vec::new();
        let mut skipped = Vec::new();
        for file in &self.files {
            let base = match load_plan(file) {
                Ok(p) => p,
                Err(e) => {
                    eprintln!("qfleet sweep: skipping {}: {e:#}", file.display());
                    skipped.push(format!("{}: {e:#}", file.display()));
                    continue;
                }
            };
            let map = base.map.name.clone();
            let mut baseline: Option<f64> = None;
            for &n in &self.robots {
                for &mode in &modes {
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
                    for &seed in &self.seeds {
                        let tag = format!("n{n}-{}-s{seed}", mode.as_cli());
                        let id = make_run_id(Some("sw"), &tag);
                        let dir = self.out.join(&map).join(&tag);
                        let _ = std::fs::remove_dir_all(&dir);
                        let r = run_once(&plan, seed, &id, &dir)
                            .with_context(|| format!("{map} {tag}"))?;
                        let _ = std::fs::write(
                            dir.join("result.json"),
                            serde_json::to_string_pretty(&r)?,
                        );
                        let Some(gp) = r.phases.first().and_then(|p| p.goals.first()) else {
                            continue;
                        };
                        ok += gp.robots_reached_optimal;
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
                        eprintln!(
                            "qfleet sweep: {map} N={n} {} seed {seed}: own optimum after {} steps/robot, merged after {}",
                            mode.as_cli(),
                            gp.robot_steps_to_optimal
                                .map_or("-".into(), |s| format!("{s:.0}")),
                            gp.merged_steps_per_robot
                                .map_or("-".into(), |s| format!("{s:.0}")),
                        );
                    }
                    let robot_steps = mean(&own);
                    if n == 1 && mode == Sharing::None {
                        baseline = robot_steps;
                    }
                    let speedup = match (baseline, robot_steps) {
                        (Some(b), Some(s)) if s > 0.0 => Some(b / s),
                        _ => None,
                    };
                    rows.push(Row {
                        map: map.clone(),
                        robots: n,
                        sharing: mode.as_cli().into(),
                        runs: self.seeds.len(),
                        robots_optimal: ok,
                        robots_total: self.seeds.len() * n as usize,
                        robot_steps,
                        merged_steps: mean(&merged),
                        robot_time_s: mean(&own_t),
                        merged_time_s: mean(&merged_t),
                        avg_steps: mean(&avg).unwrap_or(0.0),
                        speedup,
                        step_ratio: speedup.map(|s| 1.0 / s),
                    });
                }
            }
        }
        let md = markdown(&rows, &skipped);
        std::fs::write(self.out.join("sweep.md"), &md)?;
        std::fs::write(
            self.out.join("sweep.json"),
            serde_json::to_string_pretty(&rows)?,
        )?;
        if let Some(dir) = self.svg.parent() {
            std::fs::create_dir_all(dir)?;
        }
        plot(&self.svg, &rows)?;
        print!("{md}");
        println!(
            "wrote {}/sweep.{{md,json}} and {}",
            self.out.display(),
            self.svg.display()
        );
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
        "| map | N | sharing | env steps/robot to own optimum | ÷ lone robot | speedup | env steps/robot to merged optimum | s to own optimum | s to merged optimum | avg steps/episode | robots optimal |"
    );
    let _ = writeln!(s, "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.0} | {}/{} |",
            r.map,
            r.robots,
            r.sharing,
            f(r.robot_steps, 0),
            r.step_ratio
                .map_or("—".into(), |v| format!("{:.0}%", v * 100.0)),
            f(r.speedup, 2),
            f(r.merged_steps, 0),
            f(r.robot_time_s, 3),
            f(r.merged_time_s, 3),
            r.avg_steps,
            r.robots_optimal,
            r.robots_total
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
        let Some(sp) = r.speedup else { continue };
        let key = format!("{} {}", r.map, r.sharing);
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
            "Value of sharing: lone robot's env steps to optimum / each robot's",
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(-0.2f64..xmax + 0.2, 0f64..ymax)?;
    chart
        .configure_mesh()
        .x_desc("robots N")
        .y_desc("speedup (env steps per robot)")
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
    for (i, (label, pts)) in series.iter().enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))?
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
