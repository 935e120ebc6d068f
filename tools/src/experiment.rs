//! `qfleet experiment FILE`: run a manifest (see `qfleet_args::manifest`), one run per seed.
//! Each run is launched as `qfleet run` launches its run (`crate::launch`, then
//! `launcher::supervise`): the coordinator is a `qfleet-coordinator --plan plan.json` process
//! (the resolved plan of that seed, written into the seed's directory), the robots are
//! `robot-agent` processes, all found next to `qfleet` and supervised with the same restart
//! policy. A coordinator restarted after a crash resumes the experiment from the
//! `experiment-checkpoint.json` it keeps in the same directory; the result is its `result.json`.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use anyhow::{Context, Result, anyhow};
use clap::Args;
use contract::plan::ExperimentPlan;
use contract::{AgentArgs, CoordArgs, Rules, ShareArgs};
use launcher::out::{RunOutArgs, inventory};
use launcher::spawn::sibling;
use launcher::{Exit, Fleet, RestartPolicy, supervise};
use qfleet_args::{Plan, ShareMode};
use report::{ExperimentResult, OutDir, OutFile};

use crate::term::{self, out};

/// Options of `qfleet experiment`.
#[derive(Debug, Args)]
#[command(mut_arg("out", |a| a.help("Directory for results, per-robot phase files and logs \
    (default: a new private temporary directory, removed after success and kept after a \
    failure). A directory that is not empty is refused unless `--force`")))]
#[command(mut_arg("ignore_memory", |a| a.help("Start even if a repetition's estimated memory \
    (robots and coordinator, from the map's size) exceeds the memory available now")))]
pub struct ExperimentCmd {
    /// The experiment manifest (TOML; see examples/).
    file: PathBuf,
    /// Print the results (one per seed) as a JSON array on stdout.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    out: RunOutArgs,
    /// Restart a robot-agent or the coordinator that died, crashed or hung (with backoff; the
    /// coordinator warm-starts a robot from its goal's fleet table, a restarted coordinator
    /// resumes the experiment from its checkpoint).
    #[arg(long, value_enum, default_value_t = RestartPolicy::Never)]
    restart: RestartPolicy,
    /// Restarts allowed per process with `--restart on-failure`.
    #[arg(long, default_value_t = 3)]
    max_restarts: u32,
    /// Seconds a stopping process gets before it is killed.
    #[arg(long, default_value_t = 5.0)]
    grace: f64,
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
    /// `--live`, `--record`, `--pace`, `--foxglove` (in an experiment `q` in the live view
    /// stops like Ctrl-C).
    #[command(flatten)]
    watch: crate::live::WatchArgs,
    /// Robots on other hosts: the last `--remote-robots` of the manifest's robots join with
    /// `qfleet join ENDPOINT --robots N` there (every seed's run waits for them again).
    #[command(flatten)]
    remote: crate::join::RemoteArgs,
}

/// Runs one repetition of `plan` with `seed` and the sharing `rules` in `out`: claims the run
/// id, writes the seed's plan, starts and supervises the coordinator and the robots (after
/// `watch`, the live view / recorder, has joined), finishes the watch, cleans up, and returns
/// the coordinator's result. With `remote` (`--remote-robots K --listen …`) the last K robots
/// of the manifest are started by other hosts that join over the bridge.
#[allow(clippy::too_many_arguments)]
pub fn run_once(
    plan: &Plan,
    seed: u64,
    rules: Rules,
    run_id: &str,
    out: &Path,
    sup: launcher::Supervision,
    watch: Option<crate::live::Hook>,
    remote: Option<&crate::join::RemoteArgs>,
) -> Result<ExperimentResult> {
    let _claim = crate::launch::claim(run_id)?;
    // iceoryx2 root usable, no other user's file in the prefix, room in /dev/shm
    bus::preflight(&bus::BusConfig::new(run_id, plan.manifest.robots)?)?;

    let coord_bin = sibling("qfleet-coordinator")?;
    let robot_bin = sibling("robot-agent")?;
    let dir = OutDir::new(out);
    dir.create()?;
    // the checkpoint and result of an earlier experiment in this directory (`--force`) are
    // not ours: this run starts at its first phase, and an old result must not pass for ours
    for f in [OutFile::ExperimentCheckpoint, OutFile::Result] {
        let _ = std::fs::remove_file(dir.path(f));
    }
    let plan_file = dir.write_json(
        OutFile::Plan,
        &ExperimentPlan::of(plan, seed).context(Exit::BadInput)?,
    )?;
    crate::catch_interrupts()?;
    let m = &plan.manifest;
    let rules = rules.resolve(&m.learner.config().context(Exit::BadInput)?);
    let remote_robots = remote.map_or(0, |r| r.remote_robots);
    let local = m.robots.checked_sub(remote_robots).filter(|&l| l > 0).ok_or_else(|| {
        anyhow!(
            "--remote-robots {remote_robots} must be fewer than the manifest's {} robots (at least one runs on this host)",
            m.robots
        )
        .context(Exit::BadInput)
    })?;
    let hang_ms = remote.map(|r| r.hang_ms(contract::coordinator::DEFAULT_HANG_MS));
    let spin_us = contract::spin_us_for(None, remote_robots);
    // the coordinator waits for a lost robot while the launcher may still restart it
    let restarts = sup.policy.restarts(sup.max_restarts);
    let coordinator = || -> Command {
        // the plan gives the fleet, map and timeout; these are the rest
        let mut a = CoordArgs::new(run_id, out);
        a.plan = Some(plan_file.clone());
        a.merge = rules.merge;
        a.spin_us = spin_us;
        a.restarts = restarts;
        if let Some(h) = hang_ms {
            a.hang_ms = h;
        }
        let mut cmd = Command::new(&coord_bin);
        cmd.args(a.to_args());
        cmd
    };
    let robot = |r: u32| -> Command {
        let g0 = plan.assignment[0][r as usize];
        let mut learner = m.learner.clone();
        learner.episodes = m.phases[0].episodes;
        learner.seed = launcher::seed::repetition_robot(seed, r);
        let share = ShareArgs {
            share: m.sharing,
            apply: Some(rules.apply),
            ..ShareArgs::default()
        };
        let mut a = AgentArgs::new(
            run_id,
            r,
            m.robots,
            plan.map_args(r as usize, g0),
            learner,
            share,
        );
        a.timeout = m.timeout_s;
        a.pace = sup.pace;
        a.stop_at_optimum = m.stop_at_optimum;
        a.shared_grid = m.world == qfleet_args::World::Shared;
        a.out = Some(out.to_path_buf());
        let mut cmd = Command::new(&robot_bin);
        cmd.args(a.to_args());
        cmd
    };
    // the bridge to other hosts: remote robots get the options a local robot of their id would
    let hub = match remote {
        Some(r) => r
            .start_hub(run_id, local, bus::merged_buffer_for(m.robots), &robot, out)
            .context(Exit::BadInput)?,
        None => None,
    };
    let fleet = Fleet {
        coordinator: Some(&coordinator),
        robot: &robot,
        robots: local,
        policy: sup.policy,
        max_restarts: sup.max_restarts,
        grace: sup.grace,
        time_limit: Duration::ZERO,
        logs: out,
        before_robots: Some(&|| {
            if let Some(w) = &watch {
                w.wait_joined(m.timeout_s);
            }
        }),
    };
    let supervised = supervise(&fleet, &crate::INTERRUPTS, |_, _, _, _| {}, term::warn);
    // the watch leaves the run before its files are removed (its node is one of them)
    let watched = watch.map(crate::live::finish).transpose();
    // the hub's proxies are nodes of this run: gone before its files are removed
    let hosts = crate::join::finish_hub(hub, out);
    // whatever happened: no file of the run may stay behind
    crate::launch::clean_up(run_id);
    watched?;
    let supervised = supervised?;
    if supervised.restarts > 0 {
        term::warn(&format!(
            "{} process restarts during run {run_id}",
            supervised.restarts
        ));
    }
    if supervised.exit == Exit::Interrupted {
        return Err(anyhow!("interrupted by Ctrl-C").context(Exit::Interrupted));
    }
    if !supervised.failures.is_empty() {
        return Err(anyhow!(
            "{} (logs in {})",
            supervised.failures.join("; "),
            out.display()
        )
        .context(supervised.exit));
    }
    let mut result: ExperimentResult = dir
        .read_json(OutFile::Result)
        .context("the coordinator wrote no result")?;
    // the coordinator knows only the merge rule and this host: the result names both rules,
    // and where the robots ran
    result.rules = Some(rules.to_string());
    result.hosts = crate::join::host_entries(&hosts, local);
    dir.write_json(OutFile::Result, &result)?;
    Ok(result)
}

impl ExperimentCmd {
    /// Runs the command.
    pub fn run(mut self) -> Result<()> {
        let mut plan = Plan::load(&self.file).context(Exit::BadInput)?;
        if let Some(s) = &self.sharing {
            plan.manifest.sharing = ShareMode::parse(s)
                .ok_or_else(|| anyhow!("--sharing must be none, discoveries, hints or both"))
                .context(Exit::BadInput)?;
        }
        if let Some(s) = self.seed {
            plan.manifest.seeds = vec![s];
        }
        let grace = qfleet_args::seconds("--grace", self.grace)
            .map_err(|e| anyhow!(e))
            .context(Exit::BadInput)?;
        if let Some(p) = &self.run_id {
            launcher::run_id::validate(p).context(Exit::BadInput)?;
        }
        // room in memory for this host's robots and the coordinator (issue 27), as `qfleet
        // run` checks: refused before anything is created
        if !self.out.ignore_memory {
            let remote = self.remote.remote_robots.min(plan.manifest.robots);
            let cells = (plan.map.grid.width() * plan.map.grid.height()) as u64;
            bus::limits::check_memory(
                cells,
                u64::from(plan.manifest.robots - remote),
                bus::limits::mem_available(),
            )
            .context(Exit::BadInput)?;
        }
        let sup = launcher::Supervision {
            policy: self.restart,
            max_restarts: self.max_restarts,
            grace,
            pace: self.watch.pace,
        };
        let out_dir = crate::launch::out_dir(&self.out.dir, "exp")?;
        let out = out_dir.path().to_path_buf();
        let cfg = plan.manifest.learner.config().context(Exit::BadInput)?;
        if let Some(w) = self.rules.misfit(&cfg) {
            term::warn(&w);
        }
        if !self.json {
            out!(
                "learner {}, sharing rules {} (apply/merge)",
                plan.manifest.learner.learner,
                self.rules.resolve(&cfg)
            )?;
        }
        // a Foxglove port in use is bad input, found before any seed starts; one server for all
        let foxglove = self.watch.serve()?;
        // one join secret for all seeds: it names the seeds' run-id prefix
        self.remote.secret_label = Some(self.run_id.clone().unwrap_or_else(|| "exp".into()));
        let mut results = Vec::new();
        for &seed in &plan.manifest.seeds.clone() {
            let id = launcher::run_id::repetition(self.run_id.as_deref(), &format!("s{seed}"));
            let dir = out.join(format!("seed-{seed}"));
            let rec = self
                .watch
                .record
                .as_ref()
                .map(|p| match plan.manifest.seeds.len() {
                    1 => p.clone(),
                    _ => p.with_extension(format!("seed-{seed}.mcap")),
                });
            let cfg = vec![
                ("manifest".into(), self.file.display().to_string()),
                ("robots".into(), plan.starts.len().to_string()),
                ("seed".into(), seed.to_string()),
                (
                    "pace".into(),
                    qfleet_args::pace_cli(self.watch.pace).join(" "),
                ),
            ];
            let watch = crate::live::start(
                &id,
                &plan.view_task(),
                cfg,
                &self.watch,
                rec,
                foxglove.clone(),
                Box::new(crate::request_stop),
            )?;
            let r = run_once(
                &plan,
                seed,
                self.rules,
                &id,
                &dir,
                sup,
                Some(watch),
                Some(&self.remote),
            );
            let r = match r {
                Ok(r) => r,
                Err(e) => {
                    crate::live::stop_foxglove(foxglove);
                    let kept = out_dir.keep();
                    return Err(e.context(format!(
                        "seed {seed} (kept in {}: {})",
                        kept.display(),
                        inventory(&dir)
                    )));
                }
            };
            if !self.json {
                term::write_out(format_args!("{}", report::summary::experiment(&r)))?;
            }
            results.push(r);
        }
        crate::live::stop_foxglove(foxglove);
        if self.json {
            out!("{}", serde_json::to_string(&results)?)?;
        } else if !out_dir.is_temp() {
            out!("wrote {}/seed-*/result.json", out.display())?;
        }
        Ok(())
    }
}
