//! The measured value of sharing (`qfleet sweep`). For every manifest (one per map), for N
//! robots in `robots`, every sharing mode in `sharing` and every seed: one single-phase
//! experiment with all robots on the manifest's first goal from the first robot's start, each
//! robot ending its run after the episode in which its own greedy path became optimal. Reports
//! env steps per robot and wall time until the optimum (own table and merged table), average
//! steps per episode, and the speedup against a lone robot without sharing; writes a Markdown
//! table, a JSON file and an SVG plot of speedup against N.
//!
//! The fleet runs themselves are the caller's ([`Fleet`]): this crate decides which runs to
//! make and what they measured, never starts a process.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use contract::ApplyRule;
use contract::coordinator::MergeRule;
use planner::{LearnerConfig, LearnerKind};
use plotters::prelude::*;
use qfleet_args::{ArgsError, Plan, ShareMode};
use report::ExperimentResult;
use serde::{Deserialize, Serialize};

use crate::files::{self, WriteError};
use crate::plots::{PALETTE, PlotError, at};

/// The two rules of Q-hint sharing a sweep compares (`APPLY/MERGE`, or `auto`: the ones that
/// fit the learner); the caller's type, which also starts the runs with them.
pub trait ShareRules: Copy + Default {
    /// The apply and merge rules a run of this learner uses.
    fn resolve(&self, learner: &LearnerConfig) -> (ApplyRule, MergeRule);
    /// A warning when a rule given does not fit the learner (the run goes on as asked).
    fn misfit(&self, learner: &LearnerConfig) -> Option<String>;
}

impl ShareRules for contract::Rules {
    fn resolve(&self, learner: &LearnerConfig) -> (ApplyRule, MergeRule) {
        let r = contract::Rules::resolve(*self, learner);
        (r.apply, r.merge)
    }

    fn misfit(&self, learner: &LearnerConfig) -> Option<String> {
        contract::Rules::misfit(*self, learner)
    }
}

/// One fleet run a sweep asks for.
#[derive(Debug)]
pub struct FleetRun<'a, R> {
    /// The plan: the manifest cut to one phase, one goal and N robots from one start.
    pub plan: &'a Plan,
    /// The seed.
    pub seed: u64,
    /// The sharing rules.
    pub rules: R,
    /// A short tag unique within the sweep, for the run id (`n4s2`, `n4s2r1` when retried).
    pub id_tag: String,
    /// The run's own out directory (emptied before each attempt).
    pub dir: &'a Path,
    /// Steps per second each robot is paced to (none: unpaced).
    pub pace: Option<f64>,
}

/// What runs a sweep's fleets: loads a manifest, runs one experiment, says when to stop, shows
/// notes. The CLI's implementation starts a coordinator and robot-agents per run.
pub trait Fleet<R: ShareRules> {
    /// Why a manifest could not be loaded or a run failed.
    type Error: std::error::Error + Send + Sync + 'static;
    /// Loads a manifest and resolves it relative to its directory.
    fn load(&mut self, file: &Path) -> Result<Plan, Self::Error>;
    /// Runs one experiment and returns the coordinator's result.
    fn run(&mut self, run: &FleetRun<'_, R>) -> Result<ExperimentResult, Self::Error>;
    /// Whether the sweep was asked to stop (a failed run is then not tried again).
    fn stopping(&self) -> bool;
    /// A line for the person watching (skipped manifests, retries, each run's outcome).
    fn note(&mut self, line: &str);
}

/// What to sweep and where to write it.
#[derive(Debug, Clone)]
pub struct SweepOptions<R> {
    /// Manifests (one per map); a manifest that cannot be loaded is skipped.
    pub files: Vec<PathBuf>,
    /// Fleet sizes.
    pub robots: Vec<u32>,
    /// Sharing modes to compare, as the CLI spells them (`none`, `hints`, …).
    pub sharing: Vec<String>,
    /// Seeds (one repetition each).
    pub seeds: Vec<u64>,
    /// Seeds of the lone-robot baseline (empty: `seeds`).
    pub baseline_seeds: Vec<u64>,
    /// Sharing rules to compare for the modes that share hints.
    pub rules: Vec<R>,
    /// Learner of every run, overriding the manifests' (its other options stay).
    pub learner: Option<LearnerKind>,
    /// Steps per second the robots of a run that shares are paced to (none: unpaced).
    pub pace: Option<f64>,
    /// Directory for the runs' files, sweep.json and sweep.md.
    pub out: PathBuf,
    /// The SVG plot of speedup against N (none: `speedup.svg` in `out`).
    pub svg: Option<PathBuf>,
}

/// Why a sweep gave no table.
#[derive(Debug, thiserror::Error)]
pub enum SweepError<E: std::error::Error + 'static> {
    /// A sharing mode that does not exist (bad input).
    #[error("--sharing: unknown mode {0:?}")]
    Mode(String),
    /// No manifest could be loaded (bad input).
    #[error("no manifest could be loaded ({0})")]
    NoManifest(String),
    /// A manifest's learner options do not hold.
    #[error(transparent)]
    Learner(#[from] ArgsError),
    /// A run failed for good (after its retries); `run` names it (`<map> <tag>`).
    #[error("{run}")]
    Run {
        /// The map and the run's tag.
        run: String,
        /// The fleet's error.
        #[source]
        source: E,
    },
    /// A file could not be written.
    #[error(transparent)]
    Write(#[from] WriteError),
    /// The plot could not be drawn.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// The rows could not be encoded as JSON.
    #[error("encoding sweep.json")]
    Json(#[from] serde_json::Error),
}

impl<E: std::error::Error + 'static> SweepError<E> {
    /// Whether the input was refused before anything ran (the CLI's exit code 2).
    pub fn is_bad_input(&self) -> bool {
        matches!(self, SweepError::Mode(_) | SweepError::NoManifest(_))
    }
}

/// Why a previous sweep could not be redrawn.
#[derive(Debug, thiserror::Error)]
pub enum ReplotError {
    /// Its `sweep.json` could not be read.
    #[error("reading {}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// Its `sweep.json` is not a sweep's rows.
    #[error("parsing {}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: serde_json::Error,
    },
    /// The plot could not be drawn.
    #[error(transparent)]
    Plot(#[from] PlotError),
}

impl ReplotError {
    /// Whether the input was refused (the CLI's exit code 2): a sweep.json that cannot be read
    /// or is not one.
    pub fn is_bad_input(&self) -> bool {
        matches!(self, ReplotError::Read { .. } | ReplotError::Parse { .. })
    }
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

/// One (map, N, sharing) cell of the sweep, averaged over seeds (a row of `sweep.json`).
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

/// A finished sweep: its rows, its table and the files written.
#[derive(Debug, Clone)]
pub struct Swept {
    /// One row per (map, N, sharing, rules).
    pub rows: Vec<Row>,
    /// The Markdown table (`sweep.md`), with a line per skipped manifest.
    pub markdown: String,
    /// The SVG plot written.
    pub svg: PathBuf,
}

/// A redrawn sweep: its rows, its table and the plot written.
#[derive(Debug, Clone)]
pub struct Replotted {
    /// The rows read back.
    pub rows: Vec<Row>,
    /// The Markdown table.
    pub markdown: String,
    /// The SVG plot written.
    pub svg: PathBuf,
}

/// Redraws the table and the plot of a previous sweep from its `sweep.json` (plot: `svg`, or
/// `speedup.svg` beside the JSON file).
pub fn replot(json: &Path, svg: Option<&Path>) -> Result<Replotted, ReplotError> {
    let text = std::fs::read_to_string(json).map_err(|source| ReplotError::Read {
        path: json.to_path_buf(),
        source,
    })?;
    let rows: Vec<Row> = serde_json::from_str(&text).map_err(|source| ReplotError::Parse {
        path: json.to_path_buf(),
        source,
    })?;
    let svg = svg.map_or_else(
        || json.parent().unwrap_or(Path::new(".")).join("speedup.svg"),
        Path::to_path_buf,
    );
    plot(&svg, &rows)?;
    Ok(Replotted {
        markdown: markdown(&rows, &[]),
        rows,
        svg,
    })
}

/// Accumulates the runs of one (map, N, sharing, rules) cell.
#[derive(Default)]
struct CellRuns {
    own: Vec<f64>,
    merged: Vec<f64>,
    own_t: Vec<f64>,
    merged_t: Vec<f64>,
    avg: Vec<f64>,
    /// Every robot's steps to its own optimum, never = ∞.
    all: Vec<f64>,
    robots_optimal: usize,
    retries: usize,
}

impl CellRuns {
    /// Adds one run's result; returns its first goal's own and merged steps per robot (`None`
    /// if the result has no goal).
    fn add(&mut self, r: &ExperimentResult) -> Option<(Option<f64>, Option<f64>)> {
        let gp = r.phases.first().and_then(|p| p.goals.first())?;
        self.robots_optimal += gp.robots_reached_optimal;
        if let Some(p) = r.phases.first() {
            self.all.extend(
                p.robots
                    .iter()
                    .map(|x| x.steps_to_optimal.map_or(f64::INFINITY, |s| s as f64)),
            );
        }
        self.own.extend(gp.robot_steps_to_optimal);
        self.own_t.extend(gp.robot_time_to_optimal_s);
        self.merged.extend(gp.merged_steps_per_robot);
        self.merged_t.extend(gp.merged_time_to_optimal_s);
        self.avg.push(gp.avg_steps);
        Some((gp.robot_steps_to_optimal, gp.merged_steps_per_robot))
    }
}

/// Runs the sweep through `fleet`, writes `sweep.md`, `sweep.json` and the plot, and returns
/// them.
pub fn sweep<R: ShareRules, F: Fleet<R>>(
    opts: &SweepOptions<R>,
    fleet: &mut F,
) -> Result<Swept, SweepError<F::Error>> {
    let svg = opts
        .svg
        .clone()
        .unwrap_or_else(|| opts.out.join("speedup.svg"));
    let mut modes = Vec::new();
    for s in &opts.sharing {
        modes.push(ShareMode::parse(s).ok_or_else(|| SweepError::Mode(s.clone()))?);
    }
    files::create_dir(&opts.out)?;
    let mut rows: Vec<Row> = Vec::new();
    let mut skipped = Vec::new();
    for file in &opts.files {
        let base = match fleet.load(file) {
            Ok(mut p) => {
                if let Some(k) = opts.learner {
                    p.manifest.learner.learner = k;
                }
                p
            }
            Err(e) => {
                fleet.note(&format!("sweep: skipping {}: {e}", file.display()));
                skipped.push(format!("{}: {e}", file.display()));
                continue;
            }
        };
        // one label per manifest: two tasks on one map must not share a results directory
        let map = task_label(file, &base.map.name);
        let mut baseline: Option<f64> = None;
        let mut baseline_median: Option<f64> = None;
        for &n in &opts.robots {
            let cells: Vec<(ShareMode, Option<R>)> = modes
                .iter()
                .flat_map(|&mode| -> Vec<(ShareMode, Option<R>)> {
                    if matches!(mode, ShareMode::Hints | ShareMode::Both) {
                        opts.rules.iter().map(|&r| (mode, Some(r))).collect()
                    } else {
                        vec![(mode, None)]
                    }
                })
                .collect();
            for (mode, rules) in cells {
                let lone = n == 1 && mode == ShareMode::None;
                let seeds = if lone && !opts.baseline_seeds.is_empty() {
                    &opts.baseline_seeds
                } else {
                    &opts.seeds
                };
                let learner_cfg = base.manifest.learner.config()?;
                if let Some(w) = rules.and_then(|r| r.misfit(&learner_cfg)) {
                    fleet.note(&format!("sweep: {map}: {w}"));
                }
                let resolved = rules.map(|r| r.resolve(&learner_cfg));
                let label = match resolved {
                    Some((apply, merge)) => format!("{}-{apply}-{merge}", mode.as_cli()),
                    None => mode.as_cli().to_string(),
                };
                let plan = one_goal(&base, n, mode);
                let mut cell = CellRuns::default();
                for &seed in seeds {
                    let tag = format!("n{n}-{label}-s{seed}");
                    let dir = opts.out.join(&map).join(&tag);
                    let _ = std::fs::remove_dir_all(&dir);
                    let mut run = FleetRun {
                        plan: &plan,
                        seed,
                        rules: rules.unwrap_or_default(),
                        // short: a run id is truncated, its unique tail first
                        id_tag: format!("n{n}s{seed}"),
                        dir: &dir,
                        pace: pace_for(mode, opts.pace),
                    };
                    let mut attempt = 0;
                    let r = loop {
                        match fleet.run(&run) {
                            Ok(r) => break r,
                            // a run that failed on the bus (not in the learning) is run
                            // again, up to twice, with a fresh run id; retries are reported
                            Err(e) if attempt < 2 && !fleet.stopping() => {
                                attempt += 1;
                                cell.retries += 1;
                                fleet.note(&format!("sweep: {map} {tag} failed ({e}); retrying"));
                                std::thread::sleep(std::time::Duration::from_secs(1));
                                run.id_tag = format!("n{n}s{seed}r{attempt}");
                                let _ = std::fs::remove_dir_all(&dir);
                            }
                            Err(source) => {
                                return Err(SweepError::Run {
                                    run: format!("{map} {tag}"),
                                    source,
                                });
                            }
                        }
                    };
                    let _ =
                        std::fs::write(dir.join("result.json"), serde_json::to_string_pretty(&r)?);
                    let Some((own, merged)) = cell.add(&r) else {
                        continue;
                    };
                    fleet.note(&progress_line(
                        &format!("{map} N={n} {label} seed {seed}"),
                        own,
                        merged,
                    ));
                }
                let robot_steps = mean(&cell.own);
                let median_steps = median(&mut cell.all);
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
                    rules: resolved.map_or("-".into(), |(apply, merge)| format!("{apply}/{merge}")),
                    runs: seeds.len(),
                    retries: cell.retries,
                    robots_optimal: cell.robots_optimal,
                    robots_total: seeds.len() * n as usize,
                    robot_steps,
                    median_steps,
                    median_ratio,
                    merged_steps: mean(&cell.merged),
                    robot_time_s: mean(&cell.own_t),
                    merged_time_s: mean(&cell.merged_t),
                    avg_steps: mean(&cell.avg).unwrap_or(0.0),
                    speedup,
                    step_ratio: speedup.map(|s| 1.0 / s),
                    pace: pace_for(mode, opts.pace),
                });
            }
        }
    }
    if rows.is_empty() && !skipped.is_empty() {
        // every manifest was skipped: nothing was measured
        return Err(SweepError::NoManifest(skipped.join("; ")));
    }
    let md = markdown(&rows, &skipped);
    let md_path = opts.out.join("sweep.md");
    files::write(&md_path, &md)?;
    let json_path = opts.out.join("sweep.json");
    files::write(&json_path, serde_json::to_string_pretty(&rows)?)?;
    if let Some(dir) = svg.parent() {
        files::create_dir(dir)?;
    }
    plot(&svg, &rows)?;
    Ok(Swept {
        rows,
        markdown: md,
        svg,
    })
}

/// `base` cut to what one cell of the sweep runs: `n` robots sharing by `mode` on the first
/// phase's first goal from the first robot's start, each stopping at its own optimum.
fn one_goal(base: &Plan, n: u32, mode: ShareMode) -> Plan {
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
    plan
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

fn plot(path: &Path, rows: &[Row]) -> Result<(), PlotError> {
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
    root.fill(&WHITE).map_err(at(path))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Value of sharing: lone robot's median env steps to optimum / the fleet's",
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(-0.2f64..xmax + 0.2, 0f64..ymax)
        .map_err(at(path))?;
    chart
        .configure_mesh()
        .x_desc("robots N")
        .y_desc("speedup (median env steps per robot)")
        .x_labels(((xmax as usize) + 1).max(2))
        .x_label_formatter(&|x| format!("{}", 2f64.powf(x.round()) as u32))
        .draw()
        .map_err(at(path))?;
    chart
        .draw_series(LineSeries::new(
            [(-0.2, 2.5), (xmax + 0.2, 2.5)],
            BLACK.mix(0.3),
        ))
        .map_err(at(path))?
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
            .draw_series(segs)
            .map_err(at(path))?
            .label(label.clone())
            .legend(crate::plots::legend_mark(c, 2));
        chart
            .draw_series(pts.iter().map(|p| Circle::new(*p, 4, c.filled())))
            .map_err(at(path))?;
    }
    crate::plots::finish(&root, &mut chart, SeriesLabelPosition::UpperLeft, path)
}

/// One run's line for the person watching: when the robots' own tables and the merged table first gave the
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
    use super::*;

    /// `auto` rules: min/min, whatever the learner.
    #[derive(Debug, Clone, Copy, Default)]
    struct Auto;

    impl ShareRules for Auto {
        fn resolve(&self, _: &LearnerConfig) -> (ApplyRule, MergeRule) {
            (ApplyRule::Min, MergeRule::Min)
        }
        fn misfit(&self, _: &LearnerConfig) -> Option<String> {
            None
        }
    }

    #[derive(Debug, thiserror::Error)]
    #[error("bus gone")]
    struct BusGone;

    /// A fleet whose runs fail `fail` times in a row, then report robot steps `steps`.
    struct Fake {
        fail: u32,
        ids: Vec<String>,
        notes: Vec<String>,
    }

    impl Fleet<Auto> for Fake {
        type Error = BusGone;
        fn load(&mut self, file: &Path) -> Result<Plan, BusGone> {
            let m = qfleet_args::load_manifest(file).map_err(|_| BusGone)?;
            m.resolve(file.parent().unwrap()).map_err(|_| BusGone)
        }
        fn run(&mut self, run: &FleetRun<'_, Auto>) -> Result<ExperimentResult, BusGone> {
            self.ids.push(run.id_tag.clone());
            if self.fail > 0 {
                self.fail -= 1;
                return Err(BusGone);
            }
            let n = run.plan.manifest.robots;
            Ok(serde_json::from_value(serde_json::json!({
                "name": "s", "run_id": "r", "seed": run.seed, "map": "paper-10", "robots": n,
                "sharing": "none", "discoveries_received": 0, "relays_sent": 0,
                "q_updates_merged": 0, "rejected": 0, "wall_s": 1.0,
                "phases": [{
                    "phase": 0, "name": "learn", "episodes": 10, "wall_s": 1.0, "robots": [],
                    "goals": [{
                        "goal": 0, "name": "g", "cell": "(1,1)", "robots": [0],
                        "merged_path_len": [18], "optimal_path_len": [18],
                        "merged_optimal": true, "merged_time_to_optimal_s": 0.5,
                        "merged_steps_per_robot": 800.0 / f64::from(n),
                        "robot_steps_to_optimal": 1000.0 / f64::from(n),
                        "robots_reached_optimal": n, "robot_time_to_optimal_s": 0.5,
                        "avg_steps": 20.0, "all_robots_optimal": true, "relayed": 0
                    }]
                }]
            }))
            .unwrap())
        }
        fn stopping(&self) -> bool {
            false
        }
        fn note(&mut self, line: &str) {
            self.notes.push(line.to_string());
        }
    }

    fn options(files: Vec<PathBuf>, out: &Path) -> SweepOptions<Auto> {
        SweepOptions {
            files,
            robots: vec![1, 2],
            sharing: vec!["none".into()],
            seeds: vec![1],
            baseline_seeds: Vec::new(),
            rules: vec![Auto],
            learner: None,
            pace: Some(DEFAULT_PACE),
            out: out.to_path_buf(),
            svg: None,
        }
    }

    fn scratch(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("studies-{name}-{}", std::process::id()))
    }

    #[test]
    fn a_failed_run_is_retried_with_a_fresh_id_and_the_speedup_is_against_the_lone_robot() {
        let out = scratch("sweep-retry");
        let manifest = PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/sharing-paper-30.toml"
        ));
        let mut fleet = Fake {
            fail: 1,
            ids: Vec::new(),
            notes: Vec::new(),
        };
        let swept = sweep(&options(vec![manifest], &out), &mut fleet).unwrap();
        assert_eq!(fleet.ids, ["n1s1", "n1s1r1", "n2s1"]);
        assert!(
            fleet.notes[0].contains("failed (bus gone); retrying"),
            "{:?}",
            fleet.notes
        );
        let [lone, two] = &swept.rows[..] else {
            panic!("{:?}", swept.rows)
        };
        assert_eq!((lone.retries, lone.speedup), (1, Some(1.0)));
        assert_eq!((two.retries, two.speedup, two.pace), (0, Some(2.0), None));
        assert!(
            swept.markdown.contains("| paper-30 | 2 |"),
            "{}",
            swept.markdown
        );
        for f in ["sweep.md", "sweep.json", "speedup.svg"] {
            assert!(out.join(f).is_file(), "{f}");
        }
        let again = replot(&out.join("sweep.json"), Some(&out.join("again.svg"))).unwrap();
        assert_eq!(again.markdown, markdown(&swept.rows, &[]));
        let _ = std::fs::remove_dir_all(&out);
    }

    #[test]
    fn a_sweep_whose_every_manifest_is_skipped_is_bad_input() {
        let out = scratch("sweep-none");
        let mut fleet = Fake {
            fail: 0,
            ids: Vec::new(),
            notes: Vec::new(),
        };
        let e = sweep(&options(vec![out.join("missing.toml")], &out), &mut fleet).unwrap_err();
        assert!(e.is_bad_input(), "{e}");
        assert!(fleet.ids.is_empty());
        let mut opts = options(Vec::new(), &out);
        opts.sharing = vec!["nope".into()];
        assert!(sweep(&opts, &mut fleet).unwrap_err().is_bad_input());
        let _ = std::fs::remove_dir_all(&out);
    }

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
