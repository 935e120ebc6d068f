//! The paper's Table 1 and learning-curve figures, regenerated (`qfleet replicate`).
//!
//! Both learners (and, with `ablation`, every named reading of the paper's ambiguous parts)
//! run on paper-10, paper-20 and paper-30 over several seeds, on every core; the table shows
//! the paper's figures beside ours as mean ± sd, whichever way the comparison falls.

use crate::Progress;
use crate::files::{self, WriteError};
use crate::plots::{self, PlotError, Series};
use crossbeam::channel;
use planner::map::{self, MapError};
use planner::task::{self, Task, TaskError};
use planner::{
    EpsilonReading, Learner, LearnerConfig, PolicyConfig, PseudoConfig, QScale, Schedule, Summary,
};
use serde::{Deserialize, Deserializer, Serialize};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

/// What to replicate and where to write it.
#[derive(Debug, Clone)]
pub struct ReplicateOptions {
    /// Seeds per map and learner.
    pub seeds: u32,
    /// Episodes per run (N).
    pub episodes: u32,
    /// Also run every named reading of the paper's ambiguous parts (the ablation table).
    pub ablation: bool,
    /// Maps: built-in names or map files.
    pub maps: Vec<String>,
    /// Worker threads (none: all cores).
    pub threads: Option<usize>,
    /// Directory for results.json, table.md and the SVG figures.
    pub out: PathBuf,
}

/// Why the replication gave no table.
#[derive(Debug, thiserror::Error)]
pub enum ReplicateError {
    /// A map could not be loaded (bad input).
    #[error(transparent)]
    Map(#[from] MapError),
    /// A map has no start/goal pair to learn (bad input).
    #[error(transparent)]
    Task(#[from] TaskError),
    /// No map was given (bad input).
    #[error("no maps given")]
    NoMaps,
    /// Some runs of a variant ended without a result.
    #[error("{missing} runs of {variant} on {map} did not finish")]
    Unfinished {
        /// Runs missing.
        missing: usize,
        /// The variant.
        variant: String,
        /// The map.
        map: String,
    },
    /// A file could not be written.
    #[error(transparent)]
    Write(#[from] WriteError),
    /// A figure could not be drawn.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// The results could not be encoded as JSON.
    #[error("encoding results.json")]
    Json(#[from] serde_json::Error),
}

impl ReplicateError {
    /// Whether the input was refused before anything ran (the CLI's exit code 2).
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            ReplicateError::Map(_) | ReplicateError::Task(_) | ReplicateError::NoMaps
        )
    }
}

/// The paper's Table 1: (max steps, final path steps, average steps) per map size.
const PAPER: [(&str, [f64; 3], [f64; 3]); 3] = [
    ("paper-10", [756.0, 19.0, 51.24], [780.0, 19.0, 36.79]),
    ("paper-20", [1832.0, 44.0, 121.25], [1445.0, 39.0, 97.92]),
    ("paper-30", [6906.0, 70.0, 373.24], [5474.0, 58.0, 213.60]),
];

/// A named learner configuration.
#[derive(Debug, Clone)]
struct Variant {
    name: &'static str,
    what: &'static str,
    cfg: fn(u32) -> LearnerConfig,
}

fn variants(ablation: bool) -> Vec<Variant> {
    let mut v = vec![
        Variant {
            name: "traditional",
            what: "ε-greedy, ε = 0.8 greedy probability",
            cfg: |n| LearnerConfig::traditional(n, 0),
        },
        Variant {
            name: "improved",
            what: "the paper's improved learner as replicated",
            cfg: |n| LearnerConfig::paper_improved(n, 0),
        },
        Variant {
            name: "planning",
            what: "the default learner (not the paper's): optimism + Dyna sweeps + replay",
            cfg: |n| LearnerConfig::planning(n, 0),
        },
    ];
    if ablation {
        v.extend([
            Variant {
                name: "trad-eps-random",
                what: "ε-greedy, ε = 0.8 random probability (the paper's words)",
                cfg: |n| LearnerConfig {
                    policy: PolicyConfig::EpsilonGreedy {
                        epsilon: 0.8,
                        reading: EpsilonReading::Random,
                    },
                    ..LearnerConfig::traditional(n, 0)
                },
            },
            Variant {
                name: "imp-literal-raw",
                what: "softmax β = ε(k) on raw Q (the paper read literally)",
                cfg: |n| LearnerConfig {
                    policy: PolicyConfig::Softmax {
                        schedule: Schedule::Literal,
                        scale: QScale::Raw,
                        horizon: 8.0,
                    },
                    ..LearnerConfig::improved(n, 0)
                },
            },
            Variant {
                name: "imp-temp-raw",
                what: "softmax β = 1/ε(k) on raw Q",
                cfg: |n| LearnerConfig {
                    policy: PolicyConfig::Softmax {
                        schedule: Schedule::Temperature,
                        scale: QScale::Raw,
                        horizon: 8.0,
                    },
                    ..LearnerConfig::improved(n, 0)
                },
            },
            Variant {
                name: "imp-temp-range",
                what: "softmax β = 1/ε(k) on per-state range-normalised Q",
                cfg: |n| LearnerConfig {
                    policy: PolicyConfig::Softmax {
                        schedule: Schedule::Temperature,
                        scale: QScale::Range,
                        horizon: 8.0,
                    },
                    ..LearnerConfig::improved(n, 0)
                },
            },
            Variant {
                name: "imp-temp-log",
                what: "softmax β = 1/ε(k) on moves-behind-best (log) Q",
                cfg: |n| LearnerConfig {
                    policy: PolicyConfig::Softmax {
                        schedule: Schedule::Temperature,
                        scale: QScale::Log,
                        horizon: 8.0,
                    },
                    ..LearnerConfig::improved(n, 0)
                },
            },
            Variant {
                name: "imp-explore-raw",
                what: "ε(k) = exploration probability, softmax(raw Q) exploration",
                cfg: |n| LearnerConfig {
                    policy: PolicyConfig::Softmax {
                        schedule: Schedule::Explore,
                        scale: QScale::Raw,
                        horizon: 8.0,
                    },
                    ..LearnerConfig::improved(n, 0)
                },
            },
            Variant {
                name: "imp-explore-range",
                what: "ε(k) = exploration probability, softmax(range Q) exploration",
                cfg: |n| LearnerConfig {
                    policy: PolicyConfig::Softmax {
                        schedule: Schedule::Explore,
                        scale: QScale::Range,
                        horizon: 8.0,
                    },
                    ..LearnerConfig::improved(n, 0)
                },
            },
            Variant {
                name: "imp-pseudo-half",
                what: "the improved learner with pseudo targets kept until N/2",
                cfg: |n| LearnerConfig {
                    pseudo: Some(PseudoConfig {
                        remove_at: 0.5,
                        ..PseudoConfig::default()
                    }),
                    ..LearnerConfig::improved(n, 0)
                },
            },
            Variant {
                name: "imp-no-pseudo",
                what: "the improved learner without pseudo targets",
                cfg: |n| LearnerConfig {
                    pseudo: None,
                    ..LearnerConfig::improved(n, 0)
                },
            },
        ]);
    }
    v
}

/// Mean and sample standard deviation.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct Stat {
    /// Mean (NaN without values, `null` in JSON).
    #[serde(deserialize_with = "nan_if_null")]
    pub mean: f64,
    /// Sample standard deviation (0 for one value).
    pub sd: f64,
    /// Number of values.
    pub n: usize,
}

impl Stat {
    fn of(xs: impl IntoIterator<Item = f64>) -> Stat {
        let v: Vec<f64> = xs.into_iter().collect();
        let n = v.len();
        if n == 0 {
            return Stat {
                mean: f64::NAN,
                sd: 0.0,
                n,
            };
        }
        let mean = v.iter().sum::<f64>() / n as f64;
        let sd = if n > 1 {
            (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
        } else {
            0.0
        };
        Stat { mean, sd, n }
    }

    fn show(&self, digits: usize) -> String {
        if self.n == 0 {
            "-".into()
        } else {
            format!("{:.*} ± {:.*}", digits, self.mean, digits, self.sd)
        }
    }
}

/// A number that JSON wrote as `null` (serde_json writes NaN so) reads back as NaN.
fn nan_if_null<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// Results of one variant on one map over all seeds.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct VariantResult {
    /// Variant name.
    pub name: String,
    /// What it is.
    pub description: String,
    /// Policy in words.
    pub policy: String,
    /// Largest steps of an episode.
    pub max_steps: Stat,
    /// Final greedy path moves over the seeds whose path reaches the goal.
    pub final_path: Stat,
    /// Seeds whose final greedy path is the BFS optimum.
    pub final_optimal: usize,
    /// Seeds whose final greedy path loops.
    pub final_loops: usize,
    /// Mean steps per episode.
    pub avg_steps: Stat,
    /// Collisions per episode.
    pub collisions: Stat,
    /// First episode with an optimal greedy path, over the seeds that reach it.
    pub first_optimal_episode: Stat,
    /// Learning throughput over the whole variant.
    pub env_steps_per_s: f64,
    /// Mean steps per episode across seeds, per episode (the learning curve).
    #[serde(skip)]
    pub curve: Vec<f64>,
    /// Seed 0's final greedy path.
    #[serde(skip)]
    pub path0: Option<Vec<planner::Cell>>,
}

/// Results of all variants on one map.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MapResult {
    /// Map name.
    pub map: String,
    /// BFS optimum in moves.
    pub optimal_path_len: u32,
    /// Per variant.
    pub variants: Vec<VariantResult>,
    /// The paper's traditional and improved (max, final, average) when the map is one of its sizes.
    pub paper: Option<([f64; 3], [f64; 3])>,
}

/// The replication: its size and every map's results (`results.json`, the `--json` output).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ReplicateReport {
    /// Episodes per run.
    pub episodes: u32,
    /// Seeds per map and variant.
    pub seeds: u32,
    /// Per map.
    pub maps: Vec<MapResult>,
}

/// A finished replication: its results and the Markdown table written to `table.md`.
#[derive(Debug, Clone)]
pub struct Replicated {
    /// The results.
    pub report: ReplicateReport,
    /// The report as JSON, exactly as `results.json` holds it.
    pub json: serde_json::Value,
    /// Table 1 and the per-variant table, in Markdown.
    pub table: String,
}

struct Job {
    map: usize,
    variant: usize,
    seed: u32,
}

struct Done {
    map: usize,
    variant: usize,
    seed: u32,
    summary: Summary,
    steps: Vec<u32>,
    path: Option<Vec<planner::Cell>>,
    secs: f64,
}

/// Runs the replication (every core unless `opts.threads`), writes `results.json`, `table.md`
/// and per map `steps-<map>.svg` and `path-<map>.svg` into `opts.out`, and returns the results.
pub fn replicate(
    opts: &ReplicateOptions,
    progress: &mut dyn Progress,
) -> Result<Replicated, ReplicateError> {
    {
        let tasks: Vec<Task> = opts
            .maps
            .iter()
            .map(|m| {
                let spec = if map::builtin(m).is_some() {
                    format!("builtin:{m}")
                } else {
                    m.clone()
                };
                let gm = map::load_map(&spec)?;
                Ok(task::resolve_task(&gm, None, None)?)
            })
            .collect::<Result<_, ReplicateError>>()?;
        if tasks.is_empty() {
            return Err(ReplicateError::NoMaps);
        }
        let vars = variants(opts.ablation);
        let threads = opts
            .threads
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
            .max(1);
        let total = tasks.len() * vars.len() * opts.seeds as usize;
        let (job_tx, job_rx) = channel::unbounded::<Job>();
        let (done_tx, done_rx) = channel::unbounded::<Done>();
        for map in 0..tasks.len() {
            for variant in 0..vars.len() {
                for seed in 0..opts.seeds {
                    // cannot fail: the receiver is alive
                    let _ = job_tx.send(Job { map, variant, seed });
                }
            }
        }
        drop(job_tx);
        progress.start(total as u64);
        let episodes = opts.episodes;
        let mut results: Vec<Vec<Vec<Option<Done>>>> = (0..tasks.len())
            .map(|_| {
                (0..vars.len())
                    .map(|_| (0..opts.seeds).map(|_| None).collect())
                    .collect()
            })
            .collect();
        std::thread::scope(|s| {
            for _ in 0..threads {
                let (job_rx, done_tx, tasks, vars) =
                    (job_rx.clone(), done_tx.clone(), &tasks, &vars);
                s.spawn(move || {
                    for job in job_rx {
                        let cfg = LearnerConfig {
                            seed: job.seed as u64,
                            ..(vars[job.variant].cfg)(episodes)
                        };
                        let Ok(mut learner) = Learner::new(&tasks[job.map], cfg) else {
                            continue;
                        };
                        let t0 = Instant::now();
                        let (records, summary) = learner.run(|_| {});
                        let secs = t0.elapsed().as_secs_f64();
                        let path = if job.seed == 0 {
                            learner.greedy_path()
                        } else {
                            None
                        };
                        let steps = records.iter().map(|r| r.steps).collect();
                        if done_tx
                            .send(Done {
                                map: job.map,
                                variant: job.variant,
                                seed: job.seed,
                                summary,
                                steps,
                                path,
                                secs,
                            })
                            .is_err()
                        {
                            return;
                        }
                    }
                });
            }
            drop(done_tx);
            for d in done_rx.iter() {
                progress.advance();
                let (m, v, s) = (d.map, d.variant, d.seed as usize);
                results[m][v][s] = Some(d);
            }
        });
        progress.finish();

        let mut maps_out = Vec::new();
        for (mi, t) in tasks.iter().enumerate() {
            let mut vr = Vec::new();
            for (vi, var) in vars.iter().enumerate() {
                let runs: Vec<&Done> = results[mi][vi].iter().flatten().collect();
                if runs.len() != opts.seeds as usize {
                    return Err(ReplicateError::Unfinished {
                        missing: opts.seeds as usize - runs.len(),
                        variant: var.name.into(),
                        map: t.map_name.clone(),
                    });
                }
                let steps: u64 = runs.iter().map(|d| d.summary.env_steps).sum();
                let secs: f64 = runs.iter().map(|d| d.secs).sum();
                let n = runs.iter().map(|d| d.steps.len()).max().unwrap_or(0);
                let curve = (0..n)
                    .map(|e| {
                        runs.iter()
                            .map(|d| d.steps.get(e).copied().unwrap_or(0) as f64)
                            .sum::<f64>()
                            / runs.len() as f64
                    })
                    .collect();
                vr.push(VariantResult {
                    name: var.name.into(),
                    description: var.what.into(),
                    policy: (var.cfg)(episodes).policy_label(),
                    max_steps: Stat::of(runs.iter().map(|d| d.summary.max_steps as f64)),
                    final_path: Stat::of(
                        runs.iter()
                            .filter_map(|d| d.summary.final_path_len.map(f64::from)),
                    ),
                    final_optimal: runs
                        .iter()
                        .filter(|d| d.summary.final_path_len == Some(t.optimal_len))
                        .count(),
                    final_loops: runs
                        .iter()
                        .filter(|d| d.summary.final_path_len.is_none())
                        .count(),
                    avg_steps: Stat::of(runs.iter().map(|d| d.summary.avg_steps)),
                    collisions: Stat::of(
                        runs.iter().map(|d| {
                            d.summary.collisions as f64 / d.summary.episodes.max(1) as f64
                        }),
                    ),
                    first_optimal_episode: Stat::of(
                        runs.iter()
                            .filter_map(|d| d.summary.first_optimal_episode.map(f64::from)),
                    ),
                    env_steps_per_s: if secs > 0.0 { steps as f64 / secs } else { 0.0 },
                    curve,
                    path0: runs
                        .iter()
                        .find(|d| d.seed == 0)
                        .and_then(|d| d.path.clone()),
                });
            }
            let paper = PAPER.iter().find(|p| p.0 == t.map_name).map(|p| (p.1, p.2));
            maps_out.push(MapResult {
                map: t.map_name.clone(),
                optimal_path_len: t.optimal_len,
                variants: vr,
                paper,
            });
        }

        files::create_dir(&opts.out)?;
        for (mr, t) in maps_out.iter().zip(&tasks) {
            let series: Vec<Series> = mr
                .variants
                .iter()
                .map(|v| Series {
                    label: &v.name,
                    values: &v.curve,
                })
                .collect();
            plots::line_chart(
                &opts.out.join(format!("steps-{}.svg", mr.map)),
                &format!(
                    "{}: steps per episode (mean of {} seeds)",
                    mr.map, opts.seeds
                ),
                "episode",
                "steps",
                &series,
            )?;
            let bfs = planner::path::bfs_path(&t.grid, t.start, t.goal).unwrap_or_default();
            let mut paths: Vec<(&str, &[planner::Cell])> = vec![("BFS optimum", &bfs)];
            for v in mr.variants.iter().take(2) {
                if let Some(p) = &v.path0 {
                    paths.push((&v.name, p));
                }
            }
            plots::paths_on_grid(
                &opts.out.join(format!("path-{}.svg", mr.map)),
                &format!("{}: final greedy paths (seed 0)", mr.map),
                &t.grid,
                t.start,
                t.goal,
                &paths,
            )?;
        }
        let table = render_table(&maps_out, opts.seeds, episodes);
        let report = ReplicateReport {
            episodes,
            seeds: opts.seeds,
            maps: maps_out,
        };
        // through a JSON value, as the file always was: the same key order whatever serde_json's
        // features
        let json = serde_json::to_value(&report)?;
        let results = opts.out.join("results.json");
        files::write(&results, serde_json::to_string_pretty(&json)?)?;
        let table_md = opts.out.join("table.md");
        files::write(&table_md, &table)?;
        Ok(Replicated {
            report,
            json,
            table,
        })
    }
}

fn render_table(maps: &[MapResult], seeds: u32, episodes: u32) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Table 1, regenerated: {episodes} episodes, {seeds} seeds, mean ± sd. Steps are actions (collisions count); path lengths are moves.\n"
    );
    let _ = writeln!(
        s,
        "| map | metric | paper traditional | ours traditional | paper improved | ours improved | paper Δ | ours Δ |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    for m in maps {
        let (Some(tr), Some(im)) = (
            m.variants.iter().find(|v| v.name == "traditional"),
            m.variants.iter().find(|v| v.name == "improved"),
        ) else {
            continue;
        };
        let paper = m.paper.unwrap_or(([f64::NAN; 3], [f64::NAN; 3]));
        let rows: [(&str, Stat, Stat, usize); 4] = [
            ("max steps", tr.max_steps, im.max_steps, 0),
            ("final path", tr.final_path, im.final_path, 1),
            ("avg steps", tr.avg_steps, im.avg_steps, 2),
            ("collisions / episode", tr.collisions, im.collisions, 3),
        ];
        for (name, a, b, i) in rows {
            // The paper gives no collision figures: index 3 shows "-".
            let (p0, p1) = (
                paper.0.get(i).copied().unwrap_or(f64::NAN),
                paper.1.get(i).copied().unwrap_or(f64::NAN),
            );
            let pd = (p0 - p1) / p0 * 100.0;
            let od = (a.mean - b.mean) / a.mean * 100.0;
            let show = |x: f64| {
                if x.is_nan() {
                    "-".to_string()
                } else {
                    format!("{x}")
                }
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} | {:+.1}% |",
                m.map,
                name,
                show(p0),
                a.show(1),
                show(p1),
                b.show(1),
                if pd.is_nan() {
                    "-".into()
                } else {
                    format!("{pd:+.1}%")
                },
                od
            );
        }
        let _ = writeln!(
            s,
            "| {} | optimal final path (BFS {}) | | {}/{} seeds | | {}/{} seeds | | |",
            m.map, m.optimal_path_len, tr.final_optimal, seeds, im.final_optimal, seeds
        );
    }
    let _ = writeln!(
        s,
        "\nΔ = reduction from traditional to improved (positive: improved needs fewer steps).\n"
    );
    let _ = writeln!(
        s,
        "| map | variant | avg steps | collisions / episode | max steps | final path | optimal | loops | first optimal episode | M steps/s | what |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
    for m in maps {
        for v in &m.variants {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {}/{} | {} | {} | {:.1} | {} |",
                m.map,
                v.name,
                v.avg_steps.show(1),
                v.collisions.show(2),
                v.max_steps.show(0),
                v.final_path.show(1),
                v.final_optimal,
                seeds,
                v.final_loops,
                v.first_optimal_episode.show(0),
                v.env_steps_per_s / 1e6,
                v.description
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn options(maps: &[&str], out: &Path) -> ReplicateOptions {
        ReplicateOptions {
            seeds: 2,
            episodes: 30,
            ablation: false,
            maps: maps.iter().map(|m| m.to_string()).collect(),
            threads: Some(2),
            out: out.to_path_buf(),
        }
    }

    #[test]
    fn a_small_replication_writes_its_table_and_results_that_read_back() {
        let out = std::env::temp_dir().join(format!("studies-replicate-{}", std::process::id()));
        let done = replicate(&options(&["paper-10"], &out), &mut ()).unwrap();
        assert_eq!(done.report.maps.len(), 1);
        let m = &done.report.maps[0];
        assert_eq!(m.variants.len(), 3);
        assert!(m.paper.is_some());
        assert!(
            done.table.contains("| paper-10 | max steps |"),
            "{}",
            done.table
        );
        for f in [
            "results.json",
            "table.md",
            "steps-paper-10.svg",
            "path-paper-10.svg",
        ] {
            assert!(out.join(f).is_file(), "{f}");
        }
        let text = std::fs::read_to_string(out.join("results.json")).unwrap();
        let back: ReplicateReport = serde_json::from_str(&text).unwrap();
        assert_eq!(back.maps[0].variants[1].avg_steps.n, 2);
        let _ = std::fs::remove_dir_all(&out);
    }

    #[test]
    fn an_unknown_map_is_bad_input_and_an_empty_stat_reads_back() {
        let out = std::env::temp_dir().join("studies-replicate-never-written");
        let e = replicate(&options(&["builtin:nope"], &out), &mut ()).unwrap_err();
        assert!(e.is_bad_input(), "{e}");
        let empty = Stat::of([]);
        let back: Stat = serde_json::from_str(&serde_json::to_string(&empty).unwrap()).unwrap();
        assert!(back.mean.is_nan() && back.n == 0);
    }
}
