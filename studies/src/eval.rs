//! Learner configurations × the map suite × seeds, on every core (`qfleet eval`), with one
//! Markdown table per family and size and a JSON file of every run.
//!
//! The suite is `planner::suite`: generated maps (deterministic from `suite_seed`) plus the
//! MovingAI maps of the `movingai` directory when it exists. [`Half::Tuning`] is where
//! defaults are chosen, [`Half::Heldout`] where figures are reported.

use crate::Progress;
use crate::files::{self, WriteError};
use crossbeam::channel;
use planner::grid::GridError;
use planner::suite::{self, Family, Split, SuiteTask};
use planner::{ConfigError, EpsilonReading, Extras, Learner, LearnerConfig, PolicyConfig};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

/// Which half of the suite to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Half {
    /// The half defaults are chosen on.
    Tuning,
    /// The half figures are reported on.
    Heldout,
    /// Both halves.
    All,
}

/// What to evaluate and where to write it.
#[derive(Debug, Clone)]
pub struct EvalOptions {
    /// Configurations to compare, by name ([`named`]).
    pub configs: Vec<String>,
    /// Which half of the suite.
    pub split: Half,
    /// Map sizes (square side) of the generated maps, 4 to 4096.
    pub sizes: Vec<usize>,
    /// Families to run (empty: all).
    pub families: Vec<Family>,
    /// Generated maps per family and size (both halves together).
    pub maps: u32,
    /// Seed of the map generator.
    pub suite_seed: u64,
    /// Learner seeds per map and configuration.
    pub seeds: u32,
    /// Episodes per run (N).
    pub episodes: u32,
    /// Directory of MovingAI `.map`/`.scen` files to add (skipped, with a note, when absent).
    pub movingai: PathBuf,
    /// Worker threads (none: all cores).
    pub threads: Option<usize>,
    /// Directory for results.json and table.md.
    pub out: PathBuf,
}

/// Why an evaluation gave no table.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A configuration name that [`named`] does not know (bad input).
    #[error("unknown configuration '{name}' (known: {known})")]
    UnknownConfig {
        /// The name given.
        name: String,
        /// The names known, comma-separated.
        known: String,
    },
    /// A map of the suite could not be generated, e.g. a size out of range (bad input).
    #[error("generating a {family} map of side {size}")]
    Generate {
        /// The family.
        family: Family,
        /// The side.
        size: usize,
        /// Why.
        #[source]
        source: GridError,
    },
    /// The MovingAI path exists but is not a directory (bad input).
    #[error("--movingai {} is not a directory of MovingAI maps", .0.display())]
    NotADirectory(PathBuf),
    /// The filters left no map (bad input).
    #[error("no maps match the filters")]
    NoMaps,
    /// A run could not start its learner.
    #[error(transparent)]
    Learner(#[from] ConfigError),
    /// A file could not be written.
    #[error(transparent)]
    Write(#[from] WriteError),
    /// The results could not be encoded as JSON.
    #[error("encoding results.json")]
    Json(#[from] serde_json::Error),
}

impl EvalError {
    /// Whether the input was refused before anything ran (the CLI's exit code 2).
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            EvalError::UnknownConfig { .. }
                | EvalError::Generate { .. }
                | EvalError::NotADirectory(_)
                | EvalError::NoMaps
        )
    }
}

/// A named learner configuration with what it tests.
pub struct Named {
    /// Name on the command line and in tables.
    pub name: &'static str,
    /// What it is (ablation row text).
    pub what: &'static str,
    /// The configuration for N episodes (seed set per run).
    pub cfg: fn(u32) -> LearnerConfig,
}

fn planning_with(n: u32, f: impl FnOnce(&mut LearnerConfig)) -> LearnerConfig {
    let mut c = LearnerConfig::planning(n, 0);
    f(&mut c);
    c
}

/// Every configuration `qfleet eval` knows: the paper's two, the default and its ablations.
pub fn named() -> Vec<Named> {
    vec![
        Named {
            name: "traditional",
            what: "the paper's ε-greedy, ε = 0.8 greedy probability",
            cfg: |n| LearnerConfig::traditional(n, 0),
        },
        Named {
            name: "trad-eps-random",
            what: "ε-greedy, ε = 0.8 random probability",
            cfg: |n| LearnerConfig {
                policy: PolicyConfig::EpsilonGreedy {
                    epsilon: 0.8,
                    reading: EpsilonReading::Random,
                },
                ..LearnerConfig::traditional(n, 0)
            },
        },
        Named {
            name: "improved",
            what: "the paper's improved learner as replicated (explore schedule, raw softmax, pseudo targets)",
            cfg: |n| LearnerConfig::paper_improved(n, 0),
        },
        Named {
            name: "planning",
            what: "the default: γ 0.99, ε 0.05, optimistic 1, 3 sweeps, replay, sweeps every 1 024 steps within episodes",
            cfg: |n| LearnerConfig::planning(n, 0),
        },
        Named {
            name: "planning-pseudo",
            what: "default with the paper's pseudo targets (R 3, δ 0.5, removed at N/10)",
            cfg: |n| planning_with(n, |c| c.pseudo = Some(planner::PseudoConfig::default())),
        },
        Named {
            name: "planning-no-sweeps",
            what: "default without Dyna sweeps",
            cfg: |n| planning_with(n, |c| c.extras.sweeps = 0),
        },
        Named {
            name: "planning-no-replay",
            what: "default without backward replay",
            cfg: |n| planning_with(n, |c| c.extras.replay = false),
        },
        Named {
            name: "planning-no-optimism",
            what: "default with untried actions at 0",
            cfg: |n| planning_with(n, |c| c.extras.optimistic = None),
        },
        Named {
            name: "planning-1-sweep",
            what: "default with one sweep per episode",
            cfg: |n| planning_with(n, |c| c.extras.sweeps = 1),
        },
        Named {
            name: "planning-10-sweeps",
            what: "default with up to ten sweeps per episode",
            cfg: |n| planning_with(n, |c| c.extras.sweeps = 10),
        },
        Named {
            name: "planning-sweep-every-256",
            what: "default with sweeps every 256 steps inside an episode (1 024)",
            cfg: |n| planning_with(n, |c| c.extras.sweep_every = 256),
        },
        Named {
            name: "planning-episode-sweeps",
            what: "default sweeping after episodes only (the default until the sweeps within episodes)",
            cfg: |n| planning_with(n, |c| c.extras.sweep_every = 0),
        },
        Named {
            name: "planning-sweep-every-4096",
            what: "default with sweeps every 4 096 steps inside an episode (1 024)",
            cfg: |n| planning_with(n, |c| c.extras.sweep_every = 4096),
        },
        Named {
            name: "planning-eps0.2",
            what: "default with ε = 0.2 (the issue's reference point)",
            cfg: |n| {
                planning_with(n, |c| {
                    c.policy = PolicyConfig::EpsilonGreedy {
                        epsilon: 0.2,
                        reading: EpsilonReading::Random,
                    }
                })
            },
        },
        Named {
            name: "planning-eps0",
            what: "default with ε = 0 (optimism alone explores)",
            cfg: |n| {
                planning_with(n, |c| {
                    c.policy = PolicyConfig::EpsilonGreedy {
                        epsilon: 0.0,
                        reading: EpsilonReading::Random,
                    }
                })
            },
        },
        Named {
            name: "planning-gamma0.6",
            what: "default with the paper's γ = 0.6 (f32 underflow past ~170 moves)",
            cfg: |n| planning_with(n, |c| c.gamma = 0.6),
        },
        Named {
            name: "planning-gamma0.95",
            what: "default with γ = 0.95",
            cfg: |n| planning_with(n, |c| c.gamma = 0.95),
        },
        Named {
            name: "trad-gamma0.99-optimistic",
            what: "traditional with γ 0.99 and optimism, no planning",
            cfg: |n| LearnerConfig {
                gamma: 0.99,
                extras: Extras {
                    optimistic: Some(1.0),
                    ..Extras::default()
                },
                ..LearnerConfig::traditional(n, 0)
            },
        },
    ]
}

/// One (map, configuration, seed) run.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunRecord {
    /// Map id.
    pub map: String,
    /// Family.
    pub family: Family,
    /// Map side.
    pub size: usize,
    /// Configuration name.
    pub config: String,
    /// Seed.
    pub seed: u64,
    /// BFS optimum.
    pub optimal: u32,
    /// Final greedy path length (None: loops).
    pub final_path: Option<u32>,
    /// Mean steps per episode.
    pub avg_steps: f64,
    /// Collisions per episode.
    pub collisions_per_episode: f64,
    /// Env steps up to the end of the first episode after which the greedy path was optimal.
    pub steps_to_optimal: Option<u64>,
    /// Wall time up to that point, seconds.
    pub secs_to_optimal: Option<f64>,
    /// Wall time of the whole run, seconds.
    pub secs: f64,
    /// Env steps of the whole run.
    pub env_steps: u64,
}

/// The aggregate of one configuration on one (family, size) cell of the table.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Cell {
    /// Runs.
    pub runs: usize,
    /// Runs whose final greedy path is the BFS optimum, in %.
    pub optimal_pct: f64,
    /// Mean of the runs' average steps per episode.
    pub avg_steps: f64,
    /// Mean collisions per episode.
    pub collisions_per_episode: f64,
    /// Median env steps to the first optimal path (None: the median run never got there).
    pub median_steps_to_optimal: Option<u64>,
    /// Median wall time to it, seconds (None as above).
    pub median_secs_to_optimal: Option<f64>,
    /// Env steps per second over the runs.
    pub env_steps_per_s: f64,
}

/// The median with runs that never reach counted as +∞: `None` when it falls on one of them.
fn median_inf<T: Copy + PartialOrd>(mut v: Vec<Option<T>>) -> Option<T> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(|a, b| match (a, b) {
        (Some(x), Some(y)) => x.partial_cmp(y).unwrap_or(std::cmp::Ordering::Equal),
        (Some(_), None) => std::cmp::Ordering::Less,
        (None, Some(_)) => std::cmp::Ordering::Greater,
        (None, None) => std::cmp::Ordering::Equal,
    });
    v[(v.len() - 1) / 2]
}

/// Aggregates runs into one table cell.
pub fn aggregate(runs: &[&RunRecord]) -> Cell {
    let n = runs.len().max(1) as f64;
    let steps: u64 = runs.iter().map(|r| r.env_steps).sum();
    let secs: f64 = runs.iter().map(|r| r.secs).sum();
    Cell {
        runs: runs.len(),
        optimal_pct: runs
            .iter()
            .filter(|r| r.final_path == Some(r.optimal))
            .count() as f64
            * 100.0
            / n,
        avg_steps: runs.iter().map(|r| r.avg_steps).sum::<f64>() / n,
        collisions_per_episode: runs.iter().map(|r| r.collisions_per_episode).sum::<f64>() / n,
        median_steps_to_optimal: median_inf(runs.iter().map(|r| r.steps_to_optimal).collect()),
        median_secs_to_optimal: median_inf(runs.iter().map(|r| r.secs_to_optimal).collect()),
        env_steps_per_s: if secs > 0.0 { steps as f64 / secs } else { 0.0 },
    }
}

/// Runs one configuration on one task with one seed.
pub fn run_one(t: &SuiteTask, name: &str, cfg: LearnerConfig) -> Result<RunRecord, EvalError> {
    let mut l = Learner::new(&t.task, cfg)?;
    let t0 = Instant::now();
    let (mut steps, mut first): (u64, Option<(u64, f64)>) = (0, None);
    let opt = t.task.optimal_len;
    let (records, summary) = l.run(|r| {
        steps += r.steps as u64;
        if first.is_none() && r.greedy_path_len == Some(opt) {
            first = Some((steps, t0.elapsed().as_secs_f64()));
        }
    });
    let secs = t0.elapsed().as_secs_f64();
    let eps = records.len().max(1) as f64;
    Ok(RunRecord {
        map: t.id.clone(),
        family: t.family,
        size: t.size,
        config: name.to_string(),
        seed: cfg.seed,
        optimal: opt,
        final_path: summary.final_path_len,
        avg_steps: summary.avg_steps,
        collisions_per_episode: summary.collisions as f64 / eps,
        steps_to_optimal: first.map(|f| f.0),
        secs_to_optimal: first.map(|f| f.1),
        secs,
        env_steps: summary.env_steps,
    })
}

/// One configuration of an evaluation as `results.json` names it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ConfigEntry {
    /// Its name.
    pub name: String,
    /// What it is.
    pub what: String,
    /// The configuration for the evaluation's episodes (seed 0).
    pub config: LearnerConfig,
}

/// An evaluation: its size, its configurations and every run (`results.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalReport {
    /// Episodes per run.
    pub episodes: u32,
    /// Seeds per map and configuration.
    pub seeds: u32,
    /// Seed of the map generator.
    pub suite_seed: u64,
    /// `tuning`, `heldout` or `all`.
    pub split: String,
    /// The configurations compared, in the order of the table.
    pub configs: Vec<ConfigEntry>,
    /// Every run.
    pub runs: Vec<RunRecord>,
}

/// A finished evaluation: its results, its table and the two files written.
#[derive(Debug, Clone)]
pub struct Evaluated {
    /// The results.
    pub report: EvalReport,
    /// The Markdown table (`table.md`).
    pub table: String,
    /// Where the table was written.
    pub table_md: PathBuf,
    /// Where the results were written.
    pub results_json: PathBuf,
}

/// The suite's tasks that `opts` selects, generated and (when the directory exists) MovingAI.
fn suite_tasks(
    opts: &EvalOptions,
    progress: &mut dyn Progress,
) -> Result<Vec<SuiteTask>, EvalError> {
    let want = |f: Family| opts.families.is_empty() || opts.families.contains(&f);
    let mut tasks: Vec<SuiteTask> = Vec::new();
    for &size in &opts.sizes {
        for family in Family::GENERATED.into_iter().filter(|f| want(*f)) {
            for i in 0..opts.maps as usize {
                tasks.push(suite::generate(family, size, i, opts.suite_seed).map_err(
                    |source| EvalError::Generate {
                        family,
                        size,
                        source,
                    },
                )?);
            }
        }
    }
    if want(Family::Movingai) {
        if opts.movingai.is_dir() {
            let (m, errors) = suite::movingai(&opts.movingai);
            for e in errors {
                progress.note(&format!("eval: skipped {e}"));
            }
            progress.note(&format!(
                "eval: {} MovingAI tasks from {}",
                m.len(),
                opts.movingai.display()
            ));
            tasks.extend(m);
        } else if opts.movingai.exists() {
            // a device or a file where a directory of maps was asked for is bad input
            return Err(EvalError::NotADirectory(opts.movingai.clone()));
        } else {
            progress.note(&format!(
                "eval: no MovingAI maps at {} (generated maps only)",
                opts.movingai.display()
            ));
        }
    }
    tasks.retain(|t| match opts.split {
        Half::All => true,
        Half::Tuning => t.split == Split::Tuning,
        Half::Heldout => t.split == Split::Heldout,
    });
    if tasks.is_empty() {
        return Err(EvalError::NoMaps);
    }
    Ok(tasks)
}

/// Runs every selected configuration on every selected map with every seed (every core unless
/// `opts.threads`), writes `results.json` and `table.md` into `opts.out`, and returns them.
pub fn eval(opts: &EvalOptions, progress: &mut dyn Progress) -> Result<Evaluated, EvalError> {
    let all = named();
    let mut configs = Vec::new();
    for name in &opts.configs {
        match all.iter().find(|c| c.name == name) {
            Some(c) => configs.push(c),
            None => {
                return Err(EvalError::UnknownConfig {
                    name: name.clone(),
                    known: all.iter().map(|c| c.name).collect::<Vec<_>>().join(", "),
                });
            }
        }
    }
    let tasks = suite_tasks(opts, progress)?;
    let threads = opts
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .max(1);
    // Largest maps first, so the long runs do not come last on one core.
    let mut jobs = Vec::new();
    for (ti, t) in tasks.iter().enumerate() {
        for ci in 0..configs.len() {
            for seed in 0..opts.seeds as u64 {
                jobs.push((t.task.grid.len(), ti, ci, seed));
            }
        }
    }
    jobs.sort_by_key(|j| std::cmp::Reverse(j.0));
    let (job_tx, job_rx) = channel::unbounded();
    for j in jobs {
        // cannot fail: the receiver is alive
        let _ = job_tx.send(j);
    }
    drop(job_tx);
    let total = tasks.len() * configs.len() * opts.seeds as usize;
    progress.start(total as u64);
    let (done_tx, done_rx) = channel::unbounded::<Result<RunRecord, EvalError>>();
    let episodes = opts.episodes;
    let mut records = Vec::with_capacity(total);
    std::thread::scope(|s| -> Result<(), EvalError> {
        for _ in 0..threads {
            let (job_rx, done_tx, tasks, configs) =
                (job_rx.clone(), done_tx.clone(), &tasks, &configs);
            s.spawn(move || {
                for (_, ti, ci, seed) in job_rx {
                    let c = configs[ci];
                    let cfg = LearnerConfig {
                        seed,
                        ..(c.cfg)(episodes)
                    };
                    if done_tx.send(run_one(&tasks[ti], c.name, cfg)).is_err() {
                        return;
                    }
                }
            });
        }
        drop(done_tx);
        for d in done_rx.iter() {
            progress.advance();
            records.push(d?);
        }
        Ok(())
    })?;
    progress.finish();
    let names: Vec<&str> = configs.iter().map(|c| c.name).collect();
    let table = render(&records, &names, opts.seeds, episodes, opts.split);
    files::create_dir(&opts.out)?;
    let report = EvalReport {
        episodes,
        seeds: opts.seeds,
        suite_seed: opts.suite_seed,
        split: format!("{:?}", opts.split).to_lowercase(),
        configs: configs
            .iter()
            .map(|c| ConfigEntry {
                name: c.name.into(),
                what: c.what.into(),
                config: (c.cfg)(episodes),
            })
            .collect(),
        runs: records,
    };
    let results_json = opts.out.join("results.json");
    // through a JSON value, as the file always was: the same key order whatever serde_json's
    // features
    let json = serde_json::to_string(&serde_json::to_value(&report)?)?;
    files::write(&results_json, json)?;
    let table_md = opts.out.join("table.md");
    files::write(&table_md, &table)?;
    Ok(Evaluated {
        report,
        table,
        table_md,
        results_json,
    })
}

fn fmt_steps(v: Option<u64>) -> String {
    match v {
        None => "∞".into(),
        Some(x) if x >= 10_000_000 => format!("{:.1} M", x as f64 / 1e6),
        Some(x) if x >= 10_000 => format!("{:.0} k", x as f64 / 1e3),
        Some(x) => x.to_string(),
    }
}

fn fmt_secs(v: Option<f64>) -> String {
    match v {
        None => "∞".into(),
        Some(x) if x < 0.01 => format!("{:.2} ms", x * 1e3),
        Some(x) => format!("{x:.2} s"),
    }
}

/// The Markdown report: one row per (family, size, configuration), then per family over all
/// sizes, with the average-steps ratio against the first configuration.
pub fn render(
    records: &[RunRecord],
    names: &[&str],
    seeds: u32,
    episodes: u32,
    split: Half,
) -> String {
    let mut groups: BTreeMap<(Family, usize), Vec<&RunRecord>> = BTreeMap::new();
    for r in records {
        groups.entry((r.family, r.size)).or_default().push(r);
    }
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Suite evaluation, {split:?} half: N = {episodes} episodes, {seeds} seeds per map. optimal = final greedy path equals the BFS optimum; steps/ep and collisions/ep are means over runs; 'to optimum' = env steps / wall time until the greedy path was first optimal, median over runs (∞: the median run never got there); ratio = avg steps / the first configuration's.\n"
    );
    let _ = writeln!(
        s,
        "| family | size | maps | config | optimal | steps/ep | ratio | collisions/ep | steps to optimum | time to optimum | M steps/s |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
    let row = |s: &mut String, fam: &str, size: &str, runs: &[&RunRecord]| {
        let maps = {
            let mut m: Vec<&str> = runs.iter().map(|r| r.map.as_str()).collect();
            m.sort();
            m.dedup();
            m.len()
        };
        let base = names.first().map(|n| {
            aggregate(
                &runs
                    .iter()
                    .copied()
                    .filter(|r| r.config == *n)
                    .collect::<Vec<_>>(),
            )
        });
        for n in names {
            let c = aggregate(
                &runs
                    .iter()
                    .copied()
                    .filter(|r| r.config == *n)
                    .collect::<Vec<_>>(),
            );
            let ratio = base
                .as_ref()
                .map_or(f64::NAN, |b| c.avg_steps / b.avg_steps);
            let _ = writeln!(
                s,
                "| {fam} | {size} | {maps} | {n} | {:.1} % | {:.1} | {:.2} | {:.2} | {} | {} | {:.1} |",
                c.optimal_pct,
                c.avg_steps,
                ratio,
                c.collisions_per_episode,
                fmt_steps(c.median_steps_to_optimal),
                fmt_secs(c.median_secs_to_optimal),
                c.env_steps_per_s / 1e6
            );
        }
    };
    for ((fam, size), runs) in &groups {
        row(&mut s, fam.as_str(), &size.to_string(), runs);
    }
    let mut fams: BTreeMap<Family, Vec<&RunRecord>> = BTreeMap::new();
    for r in records {
        fams.entry(r.family).or_default().push(r);
    }
    for (fam, runs) in &fams {
        row(&mut s, fam.as_str(), "all", runs);
    }
    let everything: Vec<&RunRecord> = records.iter().collect();
    row(&mut s, "all", "all", &everything);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_counts_never_as_infinite() {
        assert_eq!(median_inf(vec![Some(3u64), None, Some(1)]), Some(3));
        assert_eq!(median_inf(vec![Some(3u64), None, None]), None);
        assert_eq!(median_inf::<u64>(vec![]), None);
    }

    #[test]
    fn every_named_configuration_is_valid_and_names_are_unique() {
        let all = named();
        for c in &all {
            (c.cfg)(100)
                .validate()
                .unwrap_or_else(|e| panic!("{}: {e}", c.name));
        }
        let mut names: Vec<_> = all.iter().map(|c| c.name).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), all.len());
    }

    #[test]
    fn a_small_eval_runs_and_reports_each_configuration() {
        let t = suite::generate(Family::Rooms, 10, 0, 1).unwrap();
        let mut recs = Vec::new();
        for (name, cfg) in [
            ("traditional", LearnerConfig::traditional(50, 1)),
            ("planning", LearnerConfig::planning(50, 1)),
        ] {
            recs.push(run_one(&t, name, cfg).unwrap());
        }
        let table = render(&recs, &["traditional", "planning"], 1, 50, Half::All);
        assert!(table.contains("| rooms | 10 | 1 | planning |"), "{table}");
        assert!(recs.iter().all(|r| r.env_steps > 0 && r.avg_steps > 0.0));
    }
}
