//! `qfleet join ENDPOINT --robots N`: run N robots of a run whose coordinator is on another host,
//! and the `--remote-robots K --listen ENDPOINT` options of `qfleet run` that wait for them.
//!
//! The joining host needs no map file and no learner option: the coordinator's host sends the
//! run id, fleet size, robot ids, every robot's options and the files they name at the join
//! (the `bridge` crate's `join` module). Robots start here as on one host, with this process as
//! their coordinator stand-in; the `bridge` crate carries their messages.

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use bridge::listen::{self, SECRET_ENV, SECRET_FILE, read_secret};
use bridge::{Ending, Hub, HubOptions, HubReport, JoinRequest, Secret, Tuning};
use clap::Args;
use contract::AgentArgs;
use launcher::Exit;

use crate::term;

/// Options of `qfleet run` (and `experiment`) for robots on other hosts.
#[derive(Debug, Clone, Args)]
pub struct RemoteArgs {
    /// Robots that join from other hosts with `qfleet join ENDPOINT --robots N` (ids after the
    /// local ones); the run waits for them like for local robots (the coordinator's 30 s).
    #[arg(long, default_value_t = 0, requires = "listen")]
    pub remote_robots: u32,
    /// Zenoh endpoint other hosts join on, e.g. `tcp/10.0.0.1:7447`.
    #[arg(long, value_name = "ENDPOINT")]
    pub listen: Option<String>,
    /// Seconds a silent host is waited for before its robots are reported lost.
    #[arg(long, default_value_t = 10.0)]
    pub host_deadline: f64,
    /// Milliseconds of heartbeat silence after which a host's link counts as down (a reconnect
    /// is counted when it is heard again).
    #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(u64).range(100..))]
    pub link_down_ms: u64,
    /// Seconds a joined host has to start its robots (each registered with the coordinator)
    /// before its slots are open again for another host.
    #[arg(long, default_value_t = 10.0)]
    pub start_within: f64,
    /// Seconds after the start during which hosts may join; robots no host runs then are
    /// given up and the run goes on without them (before the coordinator's 30 s registration
    /// timeout, so the run still completes).
    #[arg(long, default_value_t = 15.0)]
    pub join_within: f64,
    /// File holding the run's join secret (`qfleet-join-v1:RUN:HEX`), else the environment's
    /// `QFLEET_JOIN_SECRET`, else a fresh one, printed and written into the out directory as
    /// `join.secret` (mode 0600). Never on the command line.
    #[arg(long, value_name = "FILE", requires = "listen")]
    pub secret_file: Option<PathBuf>,
    /// After the join, send frames unencrypted and unauthenticated (joins still prove the
    /// secret); the joining host must say `--insecure-plain` too. For measuring only.
    #[arg(long, requires = "listen")]
    pub insecure_plain: bool,
    /// What a fresh secret names: the run id (`qfleet run`) or an experiment's run-id prefix,
    /// so one secret serves all its seeds.
    #[arg(skip)]
    pub secret_label: Option<String>,
    /// The secret, once read or made (one for all seeds of an experiment).
    #[arg(skip)]
    pub secret: std::sync::OnceLock<Secret>,
}

impl RemoteArgs {
    /// Local plus remote robots, checked against the fleet limit.
    pub fn total(&self, local: u32) -> Result<u32> {
        Ok(listen::fleet_total(local, self.remote_robots)?)
    }

    /// The coordinator's `--hang-ms` for this run (see [`listen::hang_ms`]).
    pub fn hang_ms(&self, hang_ms: u64) -> u64 {
        listen::hang_ms(self.remote_robots, self.host_deadline, hang_ms)
    }

    /// Starts the hub when `--remote-robots` is set: remote robots get ids `local..total` and
    /// exactly the options a local robot of that id would get (`robot(id)`, the same closure
    /// the launcher starts local robots with, less `--out`), with the files they name shipped.
    pub fn start_hub(
        &self,
        run_id: &str,
        local: u32,
        merged_buffer: usize,
        robot: &dyn Fn(u32) -> Command,
        out: &Path,
    ) -> Result<Option<Hub>> {
        let (Some(listen), true) = (&self.listen, self.remote_robots > 0) else {
            return Ok(None);
        };
        let secs = |flag: &str, v: f64| listen::seconds(flag, v).map_err(|e| anyhow!(e));
        let deadline = secs("--host-deadline", self.host_deadline)?;
        let start_within = secs("--start-within", self.start_within)?;
        let join_within = secs("--join-within", self.join_within)?;
        let words = |id: u32| -> Vec<String> {
            let cmd = robot(id);
            let args = cmd.get_args().map(|a| a.to_string_lossy().into_owned());
            args.collect()
        };
        let total = self.total(local)?;
        let plan = listen::remote_plan(run_id, local, total, HINT_BUFFER, merged_buffer, &words)?;
        if let Some(w) = listen::listen_warning(listen, self.insecure_plain) {
            crate::term::warn(&w);
        }
        let secret = match self.secret.get() {
            Some(s) => s.clone(),
            None => {
                let (s, fresh) = match read_secret(self.secret_file.as_deref(), &term::warn)? {
                    Some(s) => (s, false),
                    None => {
                        let label = self.secret_label.as_deref().unwrap_or(run_id);
                        (Secret::generate(label)?, true)
                    }
                };
                let _ = self.secret.set(s.clone());
                if fresh {
                    report::log_line!(
                        "qfleet: join secret of this run (also in {}, mode 0600; the joining hosts need it as a file, `--secret-file`, or in {SECRET_ENV}, never on a command line): {}",
                        out.join(SECRET_FILE).display(),
                        s.text()
                    );
                }
                s
            }
        };
        if !secret.names(run_id) {
            bail!(
                "the join secret is for run {:?}, this run is {run_id:?}: give the run that id (--run-id), or no secret to get a fresh one",
                secret.run_id()
            );
        }
        listen::write_secret(out, &secret)?;
        let hub = Hub::start(HubOptions {
            listen: listen.clone(),
            plan,
            down_after: Duration::from_millis(self.link_down_ms),
            deadline,
            tuning: Tuning::default(),
            start_within,
            join_within,
            out: Some(out.to_path_buf()),
            secret,
            plain: self.insecure_plain,
            door: bridge::DoorLimits::default(),
            door_mode: bridge::DoorMode::default(),
        })
        .with_context(|| format!("listening for other hosts on {listen}"))?;
        Ok(Some(hub))
    }
}

/// The coordinator's hint buffer per connection (its `--hint-buffer` default, which neither
/// `qfleet run` nor `qfleet experiment` changes).
const HINT_BUFFER: usize = 64;

/// Stops the hub and writes `bridge.json` (the hub's report) into the run's directory; the
/// caller puts [`HubReport::entries`] into the result as its `hosts` (which robots ran where,
/// reconnects, lost hosts, link latency). A failure is a warning: the result names no hosts.
pub fn finish_hub(hub: Option<Hub>, out: &Path) -> Option<HubReport> {
    let finish = |hub: Hub| -> Result<HubReport> {
        let report = hub.finish().context("the bridge to other hosts")?;
        for w in report.warnings() {
            term::warn(&w);
        }
        let path = out.join("bridge.json");
        std::fs::write(&path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(report)
    };
    let done = finish(hub?);
    done.inspect_err(|e| term::warn(&format!("warning: {e:#}")))
        .ok()
}

/// A result's `hosts` for a run whose hub reported `hub` (empty on one host).
pub fn host_entries(hub: &Option<HubReport>, local: u32) -> Vec<bridge::HostEntry> {
    hub.as_ref().map(|h| h.entries(local)).unwrap_or_default()
}

/// Options of `qfleet join`.
#[derive(Debug, Args)]
#[command(mut_arg("out", |a| a.help("Directory for the robots' results and logs and \
    `join.json` (default: a temporary directory, removed afterwards)")))]
pub struct JoinCmd {
    /// The coordinator's Zenoh endpoint (`qfleet run … --listen ENDPOINT` there), e.g.
    /// `tcp/10.0.0.1:7447`.
    endpoint: String,
    /// Robots to run on this host.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=bus::MAX_ROBOTS as i64))]
    robots: u32,
    /// This host's name in the run's result (default: the hostname).
    #[arg(long)]
    name: Option<String>,
    #[command(flatten)]
    out: launcher::out::OutArgs,
    /// Seconds to wait for the coordinator's host to answer.
    #[arg(long, default_value_t = 30.0)]
    timeout: f64,
    /// Seconds robots get to exit after the run ends before they are killed.
    #[arg(long, default_value_t = 5.0)]
    grace: f64,
    /// Print this host's link figures as JSON on stdout.
    #[arg(long)]
    json: bool,
    /// File holding the run's join secret (`join.secret` from the run's out directory on the
    /// coordinator's host), else the environment's `QFLEET_JOIN_SECRET`. Never on the command
    /// line.
    #[arg(long, value_name = "FILE")]
    secret_file: Option<PathBuf>,
    /// The run to join: refused unless the secret and the coordinator's host name this run
    /// (default: the run the secret names).
    #[arg(long, value_name = "RUN_ID")]
    run: Option<String>,
    /// Accept a link whose frames are unencrypted (the coordinator's host runs
    /// `--insecure-plain`).
    #[arg(long)]
    insecure_plain: bool,
    /// Testing only: claim another bus schema version in the join request.
    #[arg(long, hide = true)]
    schema_version_override: Option<u32>,
}

impl JoinCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        // bad input is exit code 2, before anything connects
        let secs = |flag: &str, v: f64| listen::seconds(flag, v).map_err(|e| anyhow!(e));
        let timeout = secs("--timeout", self.timeout).context(Exit::BadInput)?;
        let grace = secs("--grace", self.grace).context(Exit::BadInput)?;
        bridge::link::check_endpoint(&self.endpoint).context(Exit::BadInput)?;
        let secret = read_secret(self.secret_file.as_deref(), &term::warn)
            .context(Exit::BadInput)?
            .ok_or_else(|| {
                anyhow!(
                    "a join needs the run's secret: --secret-file FILE (join.secret in the run's \
                     out directory on the coordinator's host) or {SECRET_ENV}"
                )
            })
            .context(Exit::BadInput)?;
        bridge::join::secret_for(&secret, self.run.as_deref())
            .map_err(|e| anyhow!(e))
            .context(Exit::BadInput)?;
        // this host's directory, chosen here: never a path named after what the network sends
        let out_dir = crate::launch::out_dir(&self.out, "join")?;
        let out = out_dir.path().to_path_buf();
        let robot_bin = launcher::spawn::sibling("robot-agent")?;
        let host = self.name.clone().unwrap_or_else(bridge::join::hostname);
        let mut req = JoinRequest::new(host.clone(), self.robots, 0);
        if let Some(v) = self.schema_version_override {
            req.schema_version = v;
        }
        report::log_line!(
            "qfleet join: asking {} for {} robot(s)…",
            self.endpoint,
            self.robots
        );
        let joined = bridge::request(&self.endpoint, &req, &secret, timeout, Tuning::default())
            .map_err(|e| match e {
                bridge::BridgeError::Credentials { .. } => {
                    let file = match &self.secret_file {
                        Some(p) => format!("--secret-file {}", p.display()),
                        None => SECRET_ENV.to_string(),
                    };
                    anyhow!(e)
                        .context(format!(
                            "the join secret of {file} (run {:?}) was refused: copy join.secret \
                             from the out directory of the run now listening there",
                            secret.run_id()
                        ))
                        .context(Exit::BadInput)
                }
                e => anyhow!(e),
            })?;
        let plan = &joined.plan;
        plan.accept(self.run.as_deref(), self.insecure_plain)
            .map_err(|e| anyhow!(e))
            .context(Exit::BadInput)?;
        // everything from the network is checked before it names a file, a prefix or a process
        plan.check(self.robots)
            .map_err(|e| anyhow!(e))
            .with_context(|| format!("refusing the plan of {}", self.endpoint))
            .context(Exit::BadInput)?;
        let ids = plan.robot_ids.clone();
        report::log_line!(
            "qfleet join: joined run {} as host {} with robots {:?} (session via {})",
            plan.run_id,
            plan.host_index,
            ids,
            joined.via
        );
        let prefix = bus::bus_schema::names::iceoryx_prefix(&plan.run_id);
        if let Ok(r) = bus::clean_stale(&prefix)
            && !r.alive.is_empty()
        {
            bail!("run {} is already live on this host", plan.run_id);
        }
        for (name, text) in &plan.files {
            let clean = bridge::join::plain_file_name(name).context(Exit::BadInput)?;
            std::fs::write(out.join(clean), text)
                .with_context(|| format!("writing {}", out.join(clean).display()))?;
        }
        let stop = Arc::new(AtomicBool::new(false));
        {
            let s = Arc::clone(&stop);
            ctrlc::set_handler(move || s.store(true, Ordering::SeqCst))
                .context("installing the Ctrl-C handler")?;
        }
        let mut joiner = bridge::Joiner::new(joined, &host, Tuning::default())?;
        let plan = joiner.plan().clone();
        let robots = robot_options(&plan, &out).context(Exit::BadInput)?;
        let mut children: Vec<(u32, Child)> = Vec::new();
        let spawned = (|| -> Result<()> {
            for (id, args) in plan.robot_ids.iter().zip(&robots) {
                let log = std::fs::File::create(out.join(format!("robot-{id}.log")))
                    .with_context(|| format!("creating the log of robot {id}"))?;
                let child = Command::new(&robot_bin)
                    .args(args.to_args())
                    .stdin(Stdio::null())
                    .stdout(Stdio::null())
                    .stderr(log)
                    .process_group(0)
                    .spawn()
                    .with_context(|| format!("starting robot {id}"))?;
                children.push((*id, child));
            }
            Ok(())
        })();
        let ending = match spawned {
            // an ended robot is gone, whatever a node listing shows (see `bridge::roster`)
            Ok(()) => joiner.serve(&stop, |exited| {
                launcher::spawn::all_exited(&mut children, exited)
            }),
            Err(e) => {
                launcher::spawn::stop_all(&mut children, Duration::ZERO);
                return Err(e);
            }
        };
        let wait = match ending {
            Ok(Ending::Done | Ending::RunOver) => grace,
            _ => Duration::ZERO,
        };
        let failed = launcher::spawn::stop_all(&mut children, wait);
        let report = joiner.finish();
        let _ = bus::clean_stale(&prefix);
        let json = serde_json::to_string_pretty(&report)?;
        let _ = std::fs::write(out.join("join.json"), &json);
        if self.json {
            crate::term::out!("{}", serde_json::to_string(&report)?)?;
        }
        report::log_line!("{}", report.link_line(&self.endpoint));
        // a temporary directory is removed here (when `out_dir` is dropped)
        drop(out_dir);
        ending?
            .verdict(&self.endpoint, &failed)
            .map_err(|e| anyhow!(e))
    }
}

/// The options of every robot of `plan` ([`AgentArgs::for_slot`]): bad input before any
/// robot starts; the robots write into `out`, whatever host A asked.
fn robot_options(plan: &bridge::JoinPlan, out: &Path) -> Result<Vec<AgentArgs>> {
    let slot = |(i, &id): (usize, &u32)| -> Result<AgentArgs> {
        let words = plan.robot_command_line(i, out)?;
        AgentArgs::for_slot(&words, &plan.run_id, id, out).map_err(|e| anyhow!(e))
    };
    plan.robot_ids.iter().enumerate().map(slot).collect()
}

/// The `hosts` lines of `qfleet run`'s human output (nothing without `--remote-robots`).
pub fn print_hosts(hub: &Option<HubReport>, local: u32) -> Result<()> {
    match hub {
        Some(h) => term::write_out(format_args!("{}", h.summary(local))),
        None => Ok(()),
    }
}
