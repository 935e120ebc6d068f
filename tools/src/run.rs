//! `qfleet run`: start a coordinator and N robot-agents for one run, show progress, stop them
//! cleanly, and print the run's result.
//!
//! The processes are found next to the `qfleet` executable. Each gets its own process group, so
//! a Ctrl-C in the terminal reaches only this launcher, which then stops the run in order: the
//! first Ctrl-C asks the coordinator to stop (it tells the robots, collects their reports and
//! writes a partial result) and kills whatever is still running after `--grace` seconds; a
//! second Ctrl-C kills at once (SIGTERM to the launcher counts as a Ctrl-C). Afterwards every
//! shared-memory file of the run is removed. Restarts of failed processes: see
//! [`crate::supervise`].

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use clap::Args;
use coordinator::{MergeRule, RunResult, WaitStrategy};
use indicatif::{ProgressBar, ProgressStyle};
use qfleet_args::{LearnerArgs, MapArgs};
use robot_agent::ShareArgs;
use std::os::unix::process::CommandExt;

use crate::supervise::{Launch, RestartPolicy, supervise};

/// Options of `qfleet run`.
#[derive(Debug, Args)]
pub struct RunCmd {
    /// Number of robot-agent processes.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=bus::MAX_ROBOTS as i64))]
    robots: u32,
    #[command(flatten)]
    map: MapArgs,
    #[command(flatten)]
    learner: LearnerArgs,
    #[command(flatten)]
    share: ShareArgs,
    /// How the coordinator waits for messages.
    #[arg(long, value_enum, default_value_t = WaitStrategy::Hybrid)]
    wait: WaitStrategy,
    /// Hybrid wait: microseconds of spinning after the last message before blocking.
    #[arg(long, default_value_t = 200)]
    spin_us: u64,
    /// How the coordinator merges Q hints.
    #[arg(long, value_enum, default_value_t = MergeRule::Max)]
    merge: MergeRule,
    /// Run id (default: derived from the process id and the time).
    #[arg(long)]
    run_id: Option<String>,
    /// Print the run result as one JSON object on stdout.
    #[arg(long)]
    json: bool,
    /// Directory for result.json, per-robot results, .hgrm latency files and process logs
    /// (default: a temporary directory, removed afterwards).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Seconds a stopping process gets before it is killed.
    #[arg(long, default_value_t = 5.0)]
    grace: f64,
    /// Give up (stop the run, exit non-zero) after this many seconds; 0 = no limit.
    #[arg(long, default_value_t = 0.0)]
    time_limit: f64,
    /// Restart a robot-agent or the coordinator that died, crashed or hung (with backoff).
    #[arg(long, value_enum, default_value_t = RestartPolicy::Never)]
    restart: RestartPolicy,
    /// Restarts allowed per process with `--restart on-failure`.
    #[arg(long, default_value_t = 3)]
    max_restarts: u32,
    /// A running robot silent this many ms is reported hung (and restarted with the policy).
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u64).range(1..))]
    hang_ms: u64,
    #[command(flatten)]
    remote: crate::join::RemoteArgs,
}

pub(crate) fn sibling(name: &str) -> Result<PathBuf> {
    let exe = std::env::current_exe().context("cannot locate the qfleet executable")?;
    let dir = exe
        .parent()
        .ok_or_else(|| anyhow!("{} has no parent directory", exe.display()))?;
    let path = dir.join(name);
    if !path.is_file() {
        bail!(
            "{} not found next to {} — build it with `cargo build --bins` (or install all qfleet binaries into one directory)",
            name,
            exe.display()
        );
    }
    Ok(path)
}

fn default_run_id() -> String {
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0);
    format!("run-{}-{:x}", std::process::id(), t & 0xff_ffff_ffff)
}

impl RunCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        // check everything before starting any process
        let task = self.map.task()?;
        let cfg = self.learner.config()?;
        self.share.validate().map_err(|e| anyhow!(e))?;
        let grace = Duration::try_from_secs_f64(self.grace).map_err(|_| {
            anyhow!(
                "--grace must be a number of seconds >= 0, got {}",
                self.grace
            )
        })?;
        let time_limit = Duration::try_from_secs_f64(self.time_limit).map_err(|_| {
            anyhow!(
                "--time-limit must be a number of seconds >= 0, got {}",
                self.time_limit
            )
        })?;
        let run_id = self.run_id.clone().unwrap_or_else(default_run_id);
        bus::validate_run_id(&run_id)?;
        // an earlier run with this id that crashed may have left services half-created (iceoryx2
        // then reports them as hanging in creation forever): remove its leftovers before any
        // process of this run exists — unless a process of that run is still alive
        match bus::clean_stale(&bus_schema::names::iceoryx_prefix(&run_id)) {
            Ok(r) if !r.alive.is_empty() => bail!(
                "run id {run_id} is in use by a live run ({} process(es) alive); pick another --run-id",
                r.alive.len()
            ),
            Ok(r) if r.dead_cleaned > 0 || !r.removed.is_empty() => eprintln!(
                "qfleet: removed the leftovers of an earlier crashed run with id {run_id}"
            ),
            Ok(_) => {}
            Err(e) => eprintln!("qfleet: warning: cleaning leftovers of run {run_id}: {e}"),
        }
        let coord_bin = sibling("qfleet-coordinator")?;
        let robot_bin = sibling("robot-agent")?;
        let (out, temp_out) = match &self.out {
            Some(d) => (d.clone(), false),
            None => (std::env::temp_dir().join(format!("qfleet-{run_id}")), true),
        };
        std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
        // a result from an earlier run in the same directory must not be mistaken for ours
        let _ = std::fs::remove_file(out.join("result.json"));

        let fleet = self.remote.total(self.robots)?; // issue 12: robots on other hosts
        let hub =
            (self.remote).start_hub(&run_id, self.robots, &self.map, &self.learner, &self.share)?;
        let interrupts = Arc::new(AtomicU32::new(0));
        {
            let i = Arc::clone(&interrupts);
            ctrlc::set_handler(move || {
                i.fetch_add(1, Ordering::SeqCst);
            })
            .context("installing the Ctrl-C handler")?;
        }

        let outcome = self.supervise(
            &run_id,
            &out,
            &coord_bin,
            &robot_bin,
            &interrupts,
            grace,
            time_limit,
            &task,
            cfg.episodes,
            fleet,
        );
        let hosts = crate::join::finish_hub(hub, &out, self.robots).unwrap_or_else(|e| {
            eprintln!("qfleet: warning: {e:#}");
            None
        });
        // whatever happened: no file of the run may stay behind
        let cleaned = bus::clean_stale(&bus_schema::names::iceoryx_prefix(&run_id));
        let leftovers = bus::leftover_files(&bus_schema::names::iceoryx_prefix(&run_id));
        let result = std::fs::read_to_string(out.join("result.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<RunResult>(&t).ok());
        if temp_out {
            let _ = std::fs::remove_dir_all(&out);
        } else if result.is_some()
            && let Err(e) = crate::runplots::write(&out)
        {
            eprintln!("qfleet: warning: plotting the run: {e:#}");
        }
        let failures = outcome?;
        if let Err(e) = cleaned {
            eprintln!("qfleet: warning: cleaning up run {run_id}: {e}");
        }
        if !leftovers.is_empty() {
            eprintln!("qfleet: warning: files of run {run_id} left behind: {leftovers:?}");
        }
        match &result {
            Some(r) if self.json => {
                println!("{}", crate::join::with_hosts(r, &hosts, self.robots)?)
            }
            Some(r) => print_human(r, &out, temp_out),
            None => {}
        }
        if !failures.is_empty() {
            bail!("{}", failures.join("; "));
        }
        if result.is_none() {
            bail!("the coordinator wrote no result");
        }
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    fn supervise(
        &self,
        run_id: &str,
        out: &Path,
        coord_bin: &Path,
        robot_bin: &Path,
        interrupts: &AtomicU32,
        grace: Duration,
        time_limit: Duration,
        task: &planner::task::Task,
        episodes: u32,
        fleet: u32,
    ) -> Result<Vec<String>> {
        let restarts = match self.restart {
            RestartPolicy::Never => 0,
            RestartPolicy::OnFailure => self.max_restarts,
        };
        let coordinator = || -> Result<Command> {
            let mut cmd = Command::new(coord_bin);
            cmd.args(["--run-id", run_id, "--robots", &fleet.to_string()])
                .args(self.map.to_cli())
                .args([
                    "--wait",
                    &self.wait.to_string(),
                    "--spin-us",
                    &self.spin_us.to_string(),
                ])
                .args(["--merge", &self.merge.to_string(), "--progress"])
                .args(["--hang-ms", &self.remote.hang_ms(self.hang_ms).to_string()])
                .args(["--restarts", &restarts.to_string()])
                .arg("--out")
                .arg(out)
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .process_group(0);
            Ok(cmd)
        };
        let robot = |id: u32| -> Result<Command> {
            let mut cmd = Command::new(robot_bin);
            cmd.args(["--run-id", run_id, "--robot-id", &id.to_string()])
                .args(["--robots", &fleet.to_string()])
                .args(self.map.to_cli())
                .args(self.learner.to_cli())
                .args([
                    "--seed",
                    &self.learner.seed.wrapping_add(u64::from(id)).to_string(),
                ])
                .args(self.share.to_cli())
                .arg("--out")
                .arg(out)
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .process_group(0);
            Ok(cmd)
        };
        let launch = Launch {
            coordinator: &coordinator,
            robot: &robot,
            robots: self.robots,
            policy: self.restart,
            max_restarts: self.max_restarts,
            grace,
            time_limit,
        };
        let total = u64::from(self.robots) * u64::from(episodes);
        let bar = ProgressBar::new(total);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} {pos}/{len} episodes [{bar:30}] {msg} ({elapsed})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        bar.set_message(format!("{} robots on {}", self.robots, task.map_name));
        let done = supervise(&launch, out, interrupts, |done, tot, p50, p99| {
            if tot > 0 {
                bar.set_length(tot);
            }
            bar.set_position(done);
            bar.set_message(format!(
                "hint→coordinator p50 {:.1} µs p99 {:.1} µs",
                p50 as f64 / 1e3,
                p99 as f64 / 1e3
            ));
        });
        bar.finish_and_clear();
        let done = done?;
        if done.restarts > 0 {
            eprintln!("qfleet: {} process restarts during the run", done.restarts);
        }
        Ok(done.failures)
    }
}

fn fmt_us(ns: u64) -> String {
    format!("{:.1} µs", ns as f64 / 1e3)
}

fn print_human(r: &RunResult, out: &Path, temp_out: bool) {
    println!(
        "run {}: {} robots on {} ({} → {}), wait {}, merge {}",
        r.run_id,
        r.robots.len(),
        r.map,
        r.start,
        r.goal,
        r.wait,
        r.merge
    );
    for x in &r.robots {
        let p = |v: Option<u32>| v.map_or("loops".to_string(), |v| v.to_string());
        println!(
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
    println!(
        "  all robots optimal: {}   discoveries sent {} / received {}",
        r.all_optimal, r.discoveries_sent, r.discoveries_received
    );
    println!("  latency            count      p50        p90        p99        p99.9      max");
    for (k, s) in &r.latency_ns {
        println!(
            "  {k:18} {:>6}  {:>10} {:>10} {:>10} {:>10} {:>10}",
            s.count,
            fmt_us(s.p50),
            fmt_us(s.p90),
            fmt_us(s.p99),
            fmt_us(s.p999),
            fmt_us(s.max)
        );
    }
    println!(
        "  throughput         {:.0} messages/s, {:.0} Q-updates merged/s over {:.3} s",
        r.throughput.messages_per_s, r.throughput.q_updates_merged_per_s, r.throughput.active_s
    );
    if !temp_out {
        println!(
            "  wrote              {}/{{result.json,robot-*.json,latency-*.hgrm,*.log}}",
            out.display()
        );
    }
}
