//! `qfleet run`: start a coordinator and N robot-agents for one run, show progress, stop them
//! cleanly, and print the run's result.
//!
//! The processes are found next to the `qfleet` executable and started by the `launcher` crate:
//! each in its own process group, so a Ctrl-C in the terminal reaches only this launcher, and
//! each killed by the kernel if the launcher dies. The launcher stops the run in order: the
//! first Ctrl-C asks the coordinator to stop (it tells the robots, collects their reports and
//! writes a partial result) and kills whatever is still running after `--grace` seconds; a
//! second Ctrl-C kills at once (SIGTERM to the launcher counts as a Ctrl-C). Afterwards every
//! shared-memory file of the run is removed. Restarts of failed processes: see
//! `launcher::supervise`. The run id is claimed exclusively (`launcher::run_id::RunClaim`)
//! before anything starts (`crate::launch`, as `qfleet experiment` does).

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use anyhow::{Context, Result, anyhow};
use clap::Args;
use contract::coordinator::{MergeRule, WaitStrategy};
use contract::{AgentArgs, CoordArgs, ShareArgs};
use indicatif::{ProgressBar, ProgressStyle};
use launcher::out::{RunOutArgs, inventory};
use launcher::spawn::sibling;
use launcher::{Exit, Fleet, RestartPolicy, supervise};
use qfleet_args::{LearnerArgs, MapArgs, WorldArgs};
use report::RunResult;

use crate::term::{self, out};

/// Options of `qfleet run`.
#[derive(Debug, Args)]
#[command(mut_arg("out", |a| a.help("Directory for result.json, per-robot results, .hgrm latency \
    files and process logs (default: a new private temporary directory, removed after a \
    successful run and kept after a failed one). A directory that is not empty is refused \
    unless `--force`")))]
#[command(mut_arg("ignore_memory", |a| a.help("Start even if the run's estimated memory (robots \
    and coordinator, from the map's size) exceeds the memory available now")))]
pub struct RunCmd {
    /// Number of robot-agent processes [default: 4, or `--agents`].
    #[arg(long = "robots", value_parser = clap::value_parser!(u32).range(1..=bus::MAX_ROBOTS as i64))]
    robots_asked: Option<u32>,
    /// Shared grid: the first N start/goal pairs of `--scen` (MovingAI's "first N agents"),
    /// one robot each; `--robots` defaults to N (less `--remote-robots`: the robots of this
    /// host).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=bus::MAX_ROBOTS as i64))]
    agents: Option<u32>,
    /// The fleet size `--robots` and `--agents` resolve to (set by [`RunCmd::run`]).
    #[arg(skip)]
    robots: u32,
    /// The lifelong problem of `--lorr`, read by [`RunCmd::run`] before anything starts.
    #[arg(skip)]
    lifelong: Option<qfleet_args::Lifelong>,
    #[command(flatten)]
    map: MapArgs,
    #[command(flatten)]
    world: WorldArgs,
    #[command(flatten)]
    learner: LearnerArgs,
    #[command(flatten)]
    share: ShareArgs,
    /// How the coordinator waits for messages.
    #[arg(long, value_parser = qfleet_args::choice::<WaitStrategy>(), default_value_t = WaitStrategy::Hybrid)]
    wait: WaitStrategy,
    /// Hybrid wait: microseconds of spinning after the last message before blocking [default:
    /// 200, or 0 when robots join from other hosts (`--remote-robots`): a spinning coordinator
    /// starves the bridge hub beside it]
    #[arg(long)]
    spin_us: Option<u64>,
    /// How the coordinator merges Q hints (default: the rule that fits the learner, `min` for
    /// planning, `max` for the paper's learners; see `--apply`).
    #[arg(long, value_parser = qfleet_args::choice::<MergeRule>())]
    merge: Option<MergeRule>,
    /// Run id (default: derived from the process id and the time).
    #[arg(long)]
    run_id: Option<String>,
    /// Print the run result as one JSON object on stdout.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    out: RunOutArgs,
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
    watch: crate::live::WatchArgs,
    #[command(flatten)]
    remote: crate::join::RemoteArgs,
}

impl RunCmd {
    /// Runs the command.
    pub fn run(mut self) -> Result<()> {
        // a lifelong problem names the map, the starts and the fleet: the coordinator's map
        // options become the problem's (robot 0's task), each robot gets its own
        self.lifelong = self.world.lifelong().context(Exit::BadInput)?;
        if let Some(l) = &self.lifelong {
            let team = l
                .fleet(
                    self.robots_asked,
                    self.agents,
                    &self.map,
                    self.remote.remote_robots,
                )
                .context(Exit::BadInput)?;
            (self.robots_asked, self.agents, self.map) = (Some(team), None, l.map_args(0));
        }
        self.robots =
            qfleet_args::local_robots(self.robots_asked, self.agents, self.remote.remote_robots)
                .context(Exit::BadInput)?;
        // check everything before starting any process: bad input is exit code 2
        let (task, cfg, grace, time_limit, run_id) = self.check().context(Exit::BadInput)?;
        // a Foxglove port in use is bad input too, found before anything starts
        let foxglove = self.watch.serve()?;
        // the sharing rules: those given, the ones that fit the learner for the others
        let rules = contract::Rules {
            apply: self.share.apply,
            merge: self.merge,
        };
        if self.share.share.hints()
            && let Some(w) = rules.misfit(&cfg)
        {
            term::warn(&w);
        }
        let rules = rules.resolve(&cfg);
        self.share.apply = Some(rules.apply);
        self.merge = Some(rules.merge);
        // robots on other hosts (issue 12): the coordinator waits for `fleet` robots, the
        // launcher starts the first `--robots` of them here
        let fleet = self.remote.total(self.robots).context(Exit::BadInput)?;
        // the run id is ours alone from here until this process ends, however it ends
        let claim = crate::launch::claim(&run_id)?;
        let coord_bin = sibling("qfleet-coordinator")?;
        let robot_bin = sibling("robot-agent")?;
        let out_dir = crate::launch::out_dir(&self.out.dir, &run_id)?;
        let out = out_dir.path().to_path_buf();
        if self.out.dir.force {
            // --force replaces the files a run writes: an old result must not pass for ours
            let _ = std::fs::remove_file(out.join("result.json"));
        }
        crate::catch_interrupts()?;
        // observers of the run (the live view, the recorder) start before its processes and are
        // joined after they exited, before the run's files are removed
        let config = vec![
            ("robots".into(), self.robots.to_string()),
            ("world".into(), self.world.world.to_string()),
            ("map_args".into(), self.map.to_cli().join(" ")),
            ("learner_args".into(), self.learner.to_cli().join(" ")),
            ("share_args".into(), self.share.to_cli().join(" ")),
            ("merge".into(), rules.merge.to_string()),
            ("wait".into(), self.wait.to_string()),
            (
                "pace".into(),
                qfleet_args::pace_cli(self.watch.pace).join(" "),
            ),
        ];
        // the bridge to other hosts starts before the run's processes (the coordinator's
        // registration wait is the joining hosts' window) and stops after they all ended
        let robot = self.robot_command(&run_id, &out, &robot_bin, fleet);
        let hub = self
            .remote
            .start_hub(
                &run_id,
                self.robots,
                bus::merged_buffer_for(fleet),
                &robot,
                &out,
            )
            .context(Exit::BadInput)?;
        let watch = crate::live::start(
            &run_id,
            &task,
            config,
            &self.watch,
            self.watch.record.clone(),
            foxglove.clone(),
            Box::new(crate::request_stop),
        )?;

        let outcome = self.supervise(
            &run_id,
            &out,
            &coord_bin,
            &robot,
            fleet,
            grace,
            time_limit,
            &task,
            cfg.episodes,
            &watch,
        );
        let quit = crate::live::finish(watch);
        crate::live::stop_foxglove(foxglove);
        // the hub's proxies are nodes of this run: gone before its files are removed
        let hosts = crate::join::finish_hub(hub, &out);
        // a coordinator that could not write its result (a full disk) sent it on its stdout
        let sent = outcome.as_ref().ok().and_then(|d| d.result.as_deref());
        let recovered = RunResult::recover(&out, sent);
        if let Some((_, true)) = &recovered {
            term::warn(&format!(
                "warning: the coordinator could not write {}; its result is printed from what \
                 it sent the launcher",
                out.join("result.json").display()
            ));
        }
        let mut result = recovered.map(|(r, _)| r);
        // the coordinator knows only the merge rule and this host: the result names the apply
        // rule too, and where the robots ran
        if let Some(r) = &mut result {
            r.apply = Some(rules.apply.to_string());
            r.hosts = crate::join::host_entries(&hosts, self.robots);
            let dir = report::OutDir::new(&out);
            if let Err(e) = dir.write_json(report::OutFile::Result, r) {
                term::warn(&format!(
                    "warning: adding the apply rule and hosts to result.json: {e}"
                ));
            }
        }
        // whatever happened: no file of the run may stay behind
        crate::launch::clean_up(&run_id);
        if result.is_some()
            && !out_dir.is_temp()
            && let Err(e) = studies::runplots::write(&out)
        {
            let e = anyhow::Error::from(e);
            term::warn(&format!("warning: plotting the run: {e:#}"));
        }
        let done = outcome?;
        match &result {
            Some(r) if self.json => out!("{}", serde_json::to_string(r)?)?,
            Some(r) => {
                let used = self.share.share.discoveries();
                let text = report::summary::run(r, &out, out_dir.is_temp(), used);
                term::write_out(format_args!("{text}"))?;
                crate::join::print_hosts(&hosts, self.robots)?;
            }
            None => {}
        }
        let (failures, exit) = done.verdict(quit.map_err(|e| format!("{e:#}")), result.is_some());
        drop(claim);
        if failures.is_empty() {
            return Ok(());
        }
        // a failed run keeps its directory, temporary or not, and says what is in it
        let kept = if out_dir.is_temp() {
            out_dir.keep()
        } else {
            out.clone()
        };
        Err(anyhow!(
            "{}; kept in {}: {}",
            failures.join("; "),
            kept.display(),
            inventory(&kept)
        )
        .context(exit))
    }

    /// The merge rule, once `run` resolved it (`max` before).
    fn merge_rule(&self) -> MergeRule {
        self.merge.unwrap_or(MergeRule::Max)
    }

    /// Validates every option; the task, learner config, grace, time limit and run id.
    fn check(
        &self,
    ) -> Result<(
        planner::task::Task,
        planner::LearnerConfig,
        Duration,
        Duration,
        String,
    )> {
        let task = self.map.task()?;
        if self.world.shared() && self.lifelong.is_none() {
            // two robots on one start, a goal walled in, too few scenario lines: said now, for
            // the whole fleet (robots of other hosts take the scenario lines after this host's)
            self.map.instance(self.remote.total(self.robots)?)?;
        } else if self.agents.is_some() {
            return Err(anyhow!(
                "--agents picks the first N start/goal pairs of --scen for a shared grid: give \
                 --world shared too (or --robots for robots on copies of the map)"
            ));
        }
        let cfg = self.learner.config()?;
        self.share.validate().map_err(|e| anyhow!(e))?;
        let grace = qfleet_args::seconds("--grace", self.grace).map_err(|e| anyhow!(e))?;
        let time_limit =
            qfleet_args::seconds("--time-limit", self.time_limit).map_err(|e| anyhow!(e))?;
        let run_id = match &self.run_id {
            Some(id) => id.clone(),
            None => launcher::run_id::generate("run"),
        };
        launcher::run_id::validate(&run_id)?;
        bus::validate_run_id(&run_id)?;
        // iceoryx2 root usable, no other user's file in the run's prefix, room in /dev/shm:
        // an error here, before any process exists, not an opaque failure in every process
        bus::preflight(&bus::BusConfig::new(
            run_id.clone(),
            self.remote.total(self.robots)?,
        )?)?;
        // every local process holds tables the size of the map: refuse what cannot fit (issue
        // 27: 32 robots on suite:maze-2048-1 need ~4.5 GB) rather than let the OOM killer choose
        if !self.out.ignore_memory {
            let cells = (task.grid.width() * task.grid.height()) as u64;
            bus::limits::check_memory(cells, u64::from(self.robots), bus::limits::mem_available())?;
        }
        Ok((task, cfg, grace, time_limit, run_id))
    }

    /// Robot `id`'s command, for the launcher (local robots) and the hub (remote robots: the
    /// same options, sent to their host at the join).
    fn robot_command<'a>(
        &'a self,
        run_id: &'a str,
        out: &'a Path,
        robot_bin: &'a Path,
        fleet: u32,
    ) -> impl Fn(u32) -> Command + Sync + 'a {
        // start-up waits that grow with the fleet (both sides wait the same)
        let timeout = launcher::timeouts::startup_timeout_s(fleet);
        move |id: u32| -> Command {
            let mut a = AgentArgs::new(
                run_id,
                id,
                fleet,
                self.map.clone(),
                self.learner.clone(),
                self.share.clone(),
            );
            if let Some(l) = &self.lifelong {
                a.lifelong(l, id);
            } else if self.world.shared() {
                // robot i learns line i of the scenario: its own start and goal
                a.map.scen_index = Some(id as usize);
                a.shared_grid = true;
            }
            a.learner.seed = launcher::seed::run_robot(self.learner.seed, id);
            a.pace = self.watch.pace;
            a.timeout = timeout;
            a.out = Some(out.to_path_buf());
            let mut cmd = Command::new(robot_bin);
            cmd.args(a.to_args());
            cmd
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn supervise(
        &self,
        run_id: &str,
        out: &Path,
        coord_bin: &Path,
        robot: &(dyn Fn(u32) -> Command + Sync),
        fleet_size: u32,
        grace: Duration,
        time_limit: Duration,
        task: &planner::task::Task,
        episodes: u32,
        watch: &crate::live::Hook,
    ) -> Result<launcher::Supervised> {
        let restarts = self.restart.restarts(self.max_restarts);
        // start-up waits that grow with the fleet (both sides wait the same)
        let timeout = launcher::timeouts::startup_timeout_s(fleet_size);
        let coordinator = || -> Command {
            let mut a = CoordArgs::new(run_id, out);
            a.robots = fleet_size;
            a.map = self.map.clone();
            a.world = self.world.clone();
            a.wait = self.wait;
            a.spin_us = contract::spin_us_for(self.spin_us, self.remote.remote_robots);
            a.merge = self.merge_rule();
            a.progress = true;
            a.hang_ms = self.remote.hang_ms(self.hang_ms);
            a.restarts = restarts;
            a.timeout = timeout;
            let mut cmd = Command::new(coord_bin);
            cmd.args(a.to_args());
            cmd
        };
        let fleet = Fleet {
            coordinator: Some(&coordinator),
            robot,
            robots: self.robots,
            policy: self.restart,
            max_restarts: self.max_restarts,
            grace,
            time_limit,
            logs: out,
            before_robots: Some(&|| watch.wait_joined(timeout)),
        };
        let total = u64::from(fleet_size) * u64::from(episodes);
        let bar = ProgressBar::new(total);
        if self.watch.live {
            bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
        }
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} {pos}/{len} episodes [{bar:30}] {msg} ({elapsed})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        bar.set_message(format!("{fleet_size} robots on {}", task.map_name));
        let done = supervise(
            &fleet,
            &crate::INTERRUPTS,
            |done, tot, p50, p99| {
                if tot > 0 {
                    bar.set_length(tot);
                }
                bar.set_position(done);
                bar.set_message(format!(
                    "hint→coordinator p50 {:.1} µs p99 {:.1} µs",
                    p50 as f64 / 1e3,
                    p99 as f64 / 1e3
                ));
            },
            |msg| bar.suspend(|| term::warn(msg)),
        );
        bar.finish_and_clear();
        let done = done?;
        if done.restarts > 0 {
            term::warn(&format!(
                "{} process restarts during the run",
                done.restarts
            ));
        }
        Ok(done)
    }
}
