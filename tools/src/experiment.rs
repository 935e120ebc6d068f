//! `qfleet experiment FILE`: run a manifest (see `qfleet_args::manifest`). This process is the
//! coordinator (`coordinator::experiment`, in-process); the robots are `robot-agent
//! --experiment` processes found next to `qfleet`. One run per seed of the manifest.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use clap::{Args, ValueEnum};
use coordinator::MergeRule;
use coordinator::experiment::{ExperimentOptions, ExperimentResult, run_experiment};
use qfleet_args::{Plan, Sharing, load_manifest};
use robot_agent::ApplyRule;
use std::os::unix::process::CommandExt;

/// Options of `qfleet experiment`.
#[derive(Debug, Args)]
pub struct ExperimentCmd {
    /// The experiment manifest (TOML; see examples/).
    file: PathBuf,
    /// Print the results (one per seed) as a JSON array on stdout.
    #[arg(long)]
    json: bool,
    /// Directory for results, per-robot phase files and logs (default: a temporary directory).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Override the manifest's sharing mode.
    #[arg(long)]
    sharing: Option<String>,
    /// Override the manifest's seeds with this one.
    #[arg(long)]
    seed: Option<u64>,
    /// Run id prefix (default: derived from the process id and the time).
    #[arg(long)]
    run_id: Option<String>,
    /// How robots apply merged hints and how the coordinator merges them.
    #[command(flatten)]
    rules: Rules,
    /// Show the live terminal view (`q` stops like Ctrl-C, `space` pauses the view).
    #[arg(long)]
    live: bool,
    /// Record every message into this MCAP file (`NAME-seed-S.mcap` with several seeds).
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
}

/// The two rules of Q-hint sharing: how the coordinator merges robots' values into the fleet
/// table, and how a robot applies the fleet's values to its own table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Args)]
pub struct Rules {
    /// How a robot applies merged hints (robot-agent `--apply`).
    #[arg(long, value_enum, default_value_t = ApplyRule::Max)]
    pub apply: ApplyRule,
    /// How the coordinator merges hints into the fleet table.
    #[arg(long, value_enum, default_value_t = MergeRule::Max)]
    pub merge: MergeRule,
}

impl Default for Rules {
    fn default() -> Self {
        Rules {
            apply: ApplyRule::Max,
            merge: MergeRule::Max,
        }
    }
}

impl std::fmt::Display for Rules {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.apply, self.merge)
    }
}

impl std::str::FromStr for Rules {
    type Err = String;
    /// `APPLY/MERGE`, e.g. `max/max` or `latest/latest`.
    fn from_str(s: &str) -> Result<Self, String> {
        let (a, m) = s
            .split_once('/')
            .ok_or_else(|| format!("{s:?}: expected APPLY/MERGE, e.g. latest/latest"))?;
        Ok(Rules {
            apply: ApplyRule::from_str(a, true).map_err(|e| format!("apply rule {a:?}: {e}"))?,
            merge: MergeRule::from_str(m, true).map_err(|e| format!("merge rule {m:?}: {e}"))?,
        })
    }
}

/// The process-wide stop flag (Ctrl-C), installed once.
pub fn stop_flag() -> Result<Arc<AtomicBool>> {
    static FLAG: std::sync::OnceLock<Arc<AtomicBool>> = std::sync::OnceLock::new();
    if let Some(f) = FLAG.get() {
        return Ok(Arc::clone(f));
    }
    let f = Arc::new(AtomicBool::new(false));
    let g = Arc::clone(&f);
    ctrlc::set_handler(move || g.store(true, Ordering::SeqCst))
        .context("installing the Ctrl-C handler")?;
    let _ = FLAG.set(Arc::clone(&f));
    Ok(f)
}

fn sibling(name: &str) -> Result<PathBuf> {
    let exe = std::env::current_exe().context("cannot locate the qfleet executable")?;
    let path = exe
        .parent()
        .ok_or_else(|| anyhow!("{} has no parent directory", exe.display()))?
        .join(name);
    if !path.is_file() {
        bail!(
            "{name} not found next to {} — build it with `cargo build --bins`",
            exe.display()
        );
    }
    Ok(path)
}

/// A run id for one repetition.
pub fn make_run_id(prefix: Option<&str>, tag: &str) -> String {
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_micros() as u64)
        .unwrap_or(0);
    let p = prefix.unwrap_or("exp");
    let mut id = format!("{p}-{tag}-{}-{:x}", std::process::id(), t & 0xff_ffff_ffff);
    id.truncate(bus::bus_schema::RUN_ID_MAX_LEN);
    id
}

/// Loads a manifest and resolves it relative to its directory.
pub fn load_plan(file: &Path) -> Result<Plan> {
    let m = load_manifest(file)?;
    let base = file.parent().unwrap_or(Path::new("."));
    Ok(m.resolve(base)?)
}

/// Runs one repetition of `plan` with `seed` and the sharing `rules`: starts the robots,
/// coordinates, cleans up.
pub fn run_once(
    plan: &Plan,
    seed: u64,
    rules: Rules,
    run_id: &str,
    out: &Path,
) -> Result<ExperimentResult> {
    bus::validate_run_id(run_id)?;
    let robot_bin = sibling("robot-agent")?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let stop = stop_flag()?;
    let m = &plan.manifest;
    let mut children: Vec<(u32, Child)> = Vec::new();
    let mut spawn_err = None;
    for r in 0..m.robots {
        let g0 = plan.assignment[0][r as usize];
        let mut learner = m.learner.clone();
        learner.episodes = m.phases[0].episodes;
        let log = std::fs::File::create(out.join(format!("robot-{r}.log")))
            .with_context(|| format!("creating logs in {}", out.display()))?;
        let mut cmd = Command::new(&robot_bin);
        cmd.args(["--experiment", "--run-id", run_id])
            .args([
                "--robot-id",
                &r.to_string(),
                "--robots",
                &m.robots.to_string(),
            ])
            .args(plan.map_args(r as usize, g0).to_cli())
            .args(learner.to_cli())
            // seeds of different repetitions never overlap: robot r of seed s gets 1000·s + r
            .args([
                "--seed",
                &seed
                    .wrapping_mul(1000)
                    .wrapping_add(u64::from(r))
                    .to_string(),
            ])
            .args(["--share", m.sharing.as_cli()])
            .args(["--apply", &rules.apply.to_string()])
            .args(["--timeout", &m.timeout_s.to_string()])
            .arg("--out")
            .arg(out)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .process_group(0);
        if m.stop_at_optimum {
            cmd.arg("--stop-at-optimum");
        }
        match cmd.spawn() {
            Ok(c) => children.push((r, c)),
            Err(e) => {
                spawn_err = Some(e);
                break;
            }
        }
    }
    let result = match spawn_err {
        Some(e) => Err(anyhow!(e).context(format!("starting {}", robot_bin.display()))),
        None => run_experiment(
            plan,
            &ExperimentOptions {
                run_id: run_id.to_string(),
                seed,
                out: out.to_path_buf(),
                merge: rules.merge,
            },
            &stop,
        )
        .map_err(anyhow::Error::from),
    };
    // robots exit after Stop; give them a grace period, then kill
    let deadline = Instant::now() + Duration::from_secs(if result.is_ok() { 10 } else { 2 });
    let mut failed = Vec::new();
    for (r, mut c) in children {
        loop {
            match c.try_wait() {
                Ok(Some(st)) => {
                    if !st.success() {
                        failed.push(format!("robot-agent {r} exited with {st}"));
                    }
                    break;
                }
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                _ => {
                    let _ = c.kill();
                    let _ = c.wait();
                    failed.push(format!("robot-agent {r} had to be killed"));
                    break;
                }
            }
        }
    }
    let prefix = bus_schema::names::iceoryx_prefix(run_id);
    if let Err(e) = bus::clean_stale(&prefix) {
        eprintln!("qfleet: warning: cleaning up run {run_id}: {e}");
    }
    let result = result?;
    if !failed.is_empty() {
        let tails: Vec<String> = failed.iter().map(|f| f.to_string()).collect();
        bail!("{} (logs in {})", tails.join("; "), out.display());
    }
    if stop.load(Ordering::SeqCst) {
        bail!("interrupted by Ctrl-C");
    }
    Ok(result)
}

impl ExperimentCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        let mut plan = load_plan(&self.file)?;
        if let Some(s) = &self.sharing {
            plan.manifest.sharing = Sharing::parse(s)
                .ok_or_else(|| anyhow!("--sharing must be none, discoveries, hints or both"))?;
        }
        if let Some(s) = self.seed {
            plan.manifest.seeds = vec![s];
        }
        let (out, temp) = match &self.out {
            Some(d) => (d.clone(), false),
            None => (
                std::env::temp_dir().join(format!("qfleet-exp-{}", std::process::id())),
                true,
            ),
        };
        let mut results = Vec::new();
        for &seed in &plan.manifest.seeds.clone() {
            let id = make_run_id(self.run_id.as_deref(), &format!("s{seed}"));
            let dir = out.join(format!("seed-{seed}"));
            let rec = self
                .record
                .as_ref()
                .map(|p| match plan.manifest.seeds.len() {
                    1 => p.clone(),
                    _ => p.with_extension(format!("seed-{seed}.mcap")),
                });
            let stop = stop_flag()?;
            let cfg = vec![
                ("manifest".into(), self.file.display().to_string()),
                ("seed".into(), seed.to_string()),
            ];
            let watch = crate::live::start(
                &id,
                &crate::live::experiment_task(&plan),
                cfg,
                self.live,
                rec,
                Box::new(move || stop.store(true, Ordering::SeqCst)),
            );
            let r = run_once(&plan, seed, self.rules, &id, &dir);
            crate::live::finish(watch)?;
            let r = r?;
            let json = serde_json::to_string_pretty(&r)?;
            std::fs::write(dir.join("result.json"), json)?;
            if !self.json {
                print!("{}", crate::table::experiment_table(&r));
            }
            results.push(r);
        }
        if self.json {
            println!("{}", serde_json::to_string(&results)?);
        }
        if temp {
            let _ = std::fs::remove_dir_all(&out);
        } else if !self.json {
            println!("wrote {}/seed-*/result.json", out.display());
        }
        Ok(())
    }
}
