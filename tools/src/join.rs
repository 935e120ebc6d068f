//! `qfleet join ENDPOINT --robots N`: run N robots of a run whose coordinator is on another host,
//! and the `--remote-robots K --listen ENDPOINT` options of `qfleet run` that wait for them.
//!
//! The joining host needs no map file and no learner option: the coordinator's host sends the
//! run id, fleet size, robot ids, every robot's options and the files they name at the join
//! (the `bridge` crate's `join` module). Robots start here as on one host, with this process as
//! their coordinator stand-in; the `bridge` crate carries their messages.

use std::collections::BTreeMap;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use bridge::join::{endpoint_host, every_interface, join_hint};
use bridge::{Ending, Hub, HubOptions, HubReport, JoinRequest, RemotePlan, Secret, Tuning};
use clap::Args;
use contract::AgentArgs;
use launcher::Exit;

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

/// The environment variable a join secret may come in (instead of `--secret-file`).
pub const SECRET_ENV: &str = "QFLEET_JOIN_SECRET";

/// The file a listening run writes its join secret into, in its out directory.
pub const SECRET_FILE: &str = "join.secret";

/// Reads a join secret from `file`, else from [`SECRET_ENV`]; None when neither is given. A
/// file others may read is used, with a warning.
pub fn read_secret(file: Option<&Path>) -> Result<Option<Secret>> {
    use std::os::unix::fs::PermissionsExt;
    let text = match file {
        Some(f) => {
            let meta = std::fs::metadata(f)
                .with_context(|| format!("reading the join secret {}", f.display()))?;
            if meta.permissions().mode() & 0o077 != 0 {
                crate::term::warn(&format!(
                    "warning: the join secret {} can be read by other users (chmod 600 it)",
                    f.display()
                ));
            }
            std::fs::read_to_string(f)
                .with_context(|| format!("reading the join secret {}", f.display()))?
        }
        None => match std::env::var(SECRET_ENV) {
            Ok(t) => t,
            Err(_) => return Ok(None),
        },
    };
    let what = file.map_or(SECRET_ENV.to_string(), |f| f.display().to_string());
    Secret::parse(&text)
        .map(Some)
        .with_context(|| format!("reading the join secret from {what}"))
}

/// Writes `secret` into `dir/join.secret`, readable by this user only.
pub fn write_secret(dir: &Path, secret: &Secret) -> Result<PathBuf> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let path = dir.join(SECRET_FILE);
    let _ = std::fs::remove_file(&path);
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(&path)
        .with_context(|| format!("writing {}", path.display()))?;
    writeln!(f, "{}", secret.text()).with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// How long after a host's deadline its silent robots may first count as hung: the hub's
/// drop of their nodes and the coordinator's next node listings (every few hundred ms) fit
/// well inside it.
pub const LOSS_MARGIN_MS: u64 = 2000;

impl RemoteArgs {
    /// Local plus remote robots, checked against the fleet limit.
    pub fn total(&self, local: u32) -> Result<u32> {
        let total = local + self.remote_robots;
        if total > bus::MAX_ROBOTS {
            bail!(
                "--robots {local} + --remote-robots {} = {total} exceeds the fleet limit {}",
                self.remote_robots,
                bus::MAX_ROBOTS
            );
        }
        Ok(total)
    }

    /// The coordinator's `--hang-ms` for this run: with remote robots past the host deadline
    /// by [`LOSS_MARGIN_MS`], so a link that is down (robots on the other host learning alone)
    /// is not mistaken for hung robots, and a host given up on has its robots reported lost
    /// (the hub drops their nodes, the coordinator's next listing sees them gone) before their
    /// silence could make them hung. At exactly the deadline the two raced: a killed host's
    /// robots came out `hung` in one CI-clone run of `tests/multihost.rs`.
    pub fn hang_ms(&self, hang_ms: u64) -> u64 {
        if self.remote_robots == 0 {
            return hang_ms;
        }
        hang_ms.max((self.host_deadline.max(0.0) * 1000.0) as u64 + LOSS_MARGIN_MS)
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
        let deadline = Duration::try_from_secs_f64(self.host_deadline).map_err(|_| {
            anyhow!(
                "--host-deadline must be seconds >= 0, got {}",
                self.host_deadline
            )
        })?;
        let secs = |name: &str, v: f64| {
            Duration::try_from_secs_f64(v)
                .map_err(|_| anyhow!("--{name} must be seconds >= 0, got {v}"))
        };
        let start_within = secs("start-within", self.start_within)?;
        let join_within = secs("join-within", self.join_within)?;
        let total = self.total(local)?;
        let mut files = BTreeMap::new();
        let mut robot_args = vec![Vec::new(); local as usize];
        for id in local..total {
            robot_args.push(ship_files(robot_cli(&robot(id)), &mut files)?);
        }
        let plan = RemotePlan {
            run_id: run_id.to_string(),
            robots_total: total,
            first_remote: local,
            robot_args,
            files,
            hint_buffer: HINT_BUFFER,
            merged_buffer,
        };
        if let Some(w) = listen_warning(listen, self.insecure_plain) {
            crate::term::warn(&w);
        }
        let secret = match self.secret.get() {
            Some(s) => s.clone(),
            None => {
                let (s, fresh) = match read_secret(self.secret_file.as_deref())? {
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
        write_secret(out, &secret)?;
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

/// A robot-agent command's options as text, without `--out DIR` (a joining host writes into
/// its own directory).
fn robot_cli(cmd: &Command) -> Vec<String> {
    let mut out = Vec::new();
    let mut it = cmd.get_args().map(|a| a.to_string_lossy().into_owned());
    while let Some(a) = it.next() {
        if a == "--out" {
            it.next();
            continue;
        }
        out.push(a);
    }
    out
}

/// Replaces the paths after `--map` (unless built-in or generated) and `--scen` with `{file:NAME}` and keeps
/// their content in `files`, so the joining host needs no copy of them.
fn ship_files(cli: Vec<String>, files: &mut BTreeMap<String, String>) -> Result<Vec<String>> {
    let mut out = Vec::with_capacity(cli.len());
    let mut it = cli.into_iter();
    while let Some(a) = it.next() {
        let is_file_opt = a == "--map" || a == "--scen";
        out.push(a);
        let Some(v) = (if is_file_opt { it.next() } else { None }) else {
            continue;
        };
        if v.starts_with("builtin:") || v.starts_with("suite:") {
            out.push(v);
            continue;
        }
        let path = PathBuf::from(&v);
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {} to send it to joining hosts", path.display()))?;
        let base = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "map".into());
        // two different files of the same name (robots of an experiment) keep both
        let mut name = base.clone();
        let mut n = 1;
        while files.get(&name).is_some_and(|t| *t != text) {
            n += 1;
            name = format!("{n}-{base}");
        }
        out.push(format!("{}{name}}}", bridge::join::FILE_PLACEHOLDER));
        files.insert(name, text);
    }
    Ok(out)
}

/// What to say before listening on `endpoint`: frames sent unencrypted (`plain`), and that the
/// other hosts join with this host's own address when it listens on every interface.
pub fn listen_warning(endpoint: &str, plain: bool) -> Option<String> {
    if plain {
        return Some(format!(
            "warning: --insecure-plain: after the join, frames to and from {} cross the network \
             unencrypted and unauthenticated: anyone on the path can read them and forge acks, \
             goodbyes and messages (README \"Threat model, network side\"); for measuring only",
            report::escape(endpoint)
        ));
    }
    if every_interface(endpoint_host(endpoint)) {
        return Some(format!(
            "listening on every interface ({}): the other hosts join with this host's own \
             address, e.g. `qfleet join {} --secret-file join.secret`",
            report::escape(endpoint),
            join_hint(endpoint)
        ));
    }
    None
}

/// Stops the hub and writes `bridge.json` (the hub's report) into the run's directory; the
/// caller puts [`HubReport::entries`] into the result as its `hosts` (which robots ran where,
/// reconnects, lost hosts, link latency).
pub fn finish_hub(hub: Option<Hub>, out: &Path) -> Result<Option<HubReport>> {
    let Some(hub) = hub else {
        return Ok(None);
    };
    let report = hub.finish().context("the bridge to other hosts")?;
    if report.joined_robots < report.remote_robots {
        crate::term::warn(&format!(
            "only {} of {} remote robots joined on {} (start `qfleet join {} --robots N` on the other hosts within --join-within of the start)",
            report.joined_robots,
            report.remote_robots,
            report.listen,
            join_hint(&report.listen)
        ));
    }
    if report.refused_total > report.refused.len() as u64 {
        crate::term::warn(&format!(
            "{} joins refused in all; the first {} reasons are in bridge.json",
            report.refused_total,
            report.refused.len()
        ));
    }
    let json = serde_json::to_string_pretty(&report)?;
    std::fs::write(out.join("bridge.json"), json)
        .with_context(|| format!("writing {}", out.join("bridge.json").display()))?;
    Ok(Some(report))
}

/// A result's `hosts` for a run whose hub reported `hub` (empty on one host).
pub fn host_entries(hub: &Option<HubReport>, local: u32) -> Vec<bridge::HostEntry> {
    hub.as_ref().map(|h| h.entries(local)).unwrap_or_default()
}

/// Options of `qfleet join`.
#[derive(Debug, Args)]
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
    /// Directory for the robots' results and logs and `join.json` (default: a temporary
    /// directory, removed afterwards).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write into a non-empty `--out` directory, replacing files of the same names.
    #[arg(long)]
    force: bool,
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

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "remote".into())
}

impl JoinCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        // bad input is exit code 2, before anything connects
        let timeout = Duration::try_from_secs_f64(self.timeout)
            .map_err(|_| anyhow!("--timeout must be seconds >= 0, got {}", self.timeout))
            .context(Exit::BadInput)?;
        let grace = Duration::try_from_secs_f64(self.grace)
            .map_err(|_| anyhow!("--grace must be seconds >= 0, got {}", self.grace))
            .context(Exit::BadInput)?;
        bridge::link::check_endpoint(&self.endpoint).context(Exit::BadInput)?;
        let secret = read_secret(self.secret_file.as_deref())
            .context(Exit::BadInput)?
            .ok_or_else(|| {
                anyhow!(
                    "a join needs the run's secret: --secret-file FILE (join.secret in the run's \
                     out directory on the coordinator's host) or {SECRET_ENV}"
                )
            })
            .context(Exit::BadInput)?;
        if let Some(run) = &self.run
            && run != secret.run_id()
        {
            return Err(anyhow!(
                "the join secret is for run {:?}, not the run {run:?} asked for",
                secret.run_id()
            ))
            .context(Exit::BadInput);
        }
        // this host's directory, chosen here: never a path named after what the network sends
        let out_dir = launcher::out::OutDir::prepare(self.out.as_deref(), self.force, "join")
            .map_err(|e| match e {
                launcher::out::OutError::Io { .. } => anyhow!(e),
                e => anyhow!(e).context(Exit::BadInput),
            })?;
        let out = out_dir.path().to_path_buf();
        let robot_bin = launcher::spawn::sibling("robot-agent")?;
        let host = self.name.clone().unwrap_or_else(hostname);
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
        if plan.plain && !self.insecure_plain {
            return Err(anyhow!(
                "the coordinator's host sends frames unencrypted (--insecure-plain there): join \
                 with --insecure-plain to accept that"
            ))
            .context(Exit::BadInput);
        }
        if let Some(run) = &self.run
            && *run != plan.run_id
        {
            return Err(anyhow!(
                "the coordinator's host runs {:?}, not the run {run:?} asked for",
                plan.run_id
            ))
            .context(Exit::BadInput);
        }
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
                let mut all = true;
                for (id, c) in children.iter_mut() {
                    if matches!(c.try_wait(), Ok(Some(_))) {
                        exited(*id);
                    } else {
                        all = false;
                    }
                }
                all
            }),
            Err(e) => {
                stop_children(&mut children, Duration::ZERO);
                return Err(e);
            }
        };
        let wait = match ending {
            Ok(Ending::Done | Ending::RunOver) => grace,
            _ => Duration::ZERO,
        };
        let failed = stop_children(&mut children, wait);
        let report = joiner.finish();
        let _ = bus::clean_stale(&prefix);
        let json = serde_json::to_string_pretty(&report)?;
        let _ = std::fs::write(out.join("join.json"), &json);
        if self.json {
            crate::term::out!("{}", serde_json::to_string(&report)?)?;
        }
        report::log_line!(
            "qfleet join: link to {}: {} reconnect(s), {} ms down, round trip p50 {:.1} µs, clock offset {} ns (±{} ns)",
            self.endpoint,
            report.link.reconnects,
            report.link.down_ms,
            report.link.rtt_ns.p50 as f64 / 1e3,
            report.link.clock_offset_ns,
            report.link.best_rtt_ns / 2
        );
        // a temporary directory is removed here (when `out_dir` is dropped)
        drop(out_dir);
        match ending? {
            Ending::Lost => bail!(
                "lost the coordinator's host {} (silent past the deadline); robots stopped",
                self.endpoint
            ),
            Ending::Stopped => bail!("interrupted"),
            Ending::Done | Ending::RunOver if !failed.is_empty() => {
                bail!("robots {failed:?} exited with an error (see their logs)")
            }
            Ending::Done | Ending::RunOver => Ok(()),
        }
    }
}

/// Waits up to `grace` for the robots to exit, then SIGTERMs and finally kills the rest;
/// returns the ids that exited unsuccessfully or had to be stopped.
fn stop_children(children: &mut [(u32, Child)], grace: Duration) -> Vec<u32> {
    let deadline = Instant::now() + grace;
    let mut failed = Vec::new();
    let mut termed = false;
    loop {
        let running: Vec<usize> = (0..children.len())
            .filter(|&i| matches!(children[i].1.try_wait(), Ok(None)))
            .collect();
        if running.is_empty() {
            break;
        }
        let now = Instant::now();
        if now >= deadline && !termed {
            for &i in &running {
                // SAFETY: kill(2) on a child we started and have not reaped
                unsafe { libc::kill(children[i].1.id() as i32, libc::SIGTERM) };
            }
            termed = true;
        } else if now >= deadline + Duration::from_secs(2) {
            for &i in &running {
                let _ = children[i].1.kill();
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    for (id, c) in children.iter_mut() {
        if !matches!(c.wait(), Ok(s) if s.success()) {
            failed.push(*id);
        }
    }
    failed
}

/// The options of every robot of `plan`, read as the robot-agent reads them (the process
/// contract's [`AgentArgs`]): an option it does not know, a value it refuses, another run id or
/// another robot id than the slot's is bad input before any robot starts; the robots write into
/// `out`, whatever host A asked.
fn robot_options(plan: &bridge::JoinPlan, out: &Path) -> Result<Vec<AgentArgs>> {
    plan.robot_ids
        .iter()
        .enumerate()
        .map(|(i, &id)| {
            let words = plan.robot_command_line(i, out)?;
            let mut a = AgentArgs::try_parse_args(&words).map_err(|e| {
                anyhow!(
                    "host A sent options robot {id} does not take: {}",
                    report::escape(e.to_string().lines().next().unwrap_or_default())
                )
            })?;
            if a.run_id != plan.run_id || a.robot_id != id {
                bail!(
                    "host A's options for robot {id} name run {} robot {}",
                    report::escape(&a.run_id),
                    a.robot_id
                );
            }
            a.out = Some(out.to_path_buf());
            Ok(a)
        })
        .collect()
}

/// The `hosts` lines of `qfleet run`'s human output: where each robot ran and what the link to
/// each joined host did (nothing without `--remote-robots`).
pub fn print_hosts(hub: &Option<HubReport>, local: u32) -> Result<()> {
    let Some(hub) = hub else {
        return Ok(());
    };
    crate::term::out!(
        "  hosts              local: robots 0..{}; {} of {} remote robots joined on {}",
        local.saturating_sub(1),
        hub.joined_robots,
        hub.remote_robots,
        hub.listen
    )?;
    for h in &hub.hosts {
        let state = h
            .state
            .map(|s| serde_json::to_string(&s).unwrap_or_default())
            .unwrap_or_default();
        crate::term::out!(
            "  host {:13} robots {:?}  link {}  reconnects {}  down {} ms  round trip p50 {:.1} µs p99.9 {:.1} µs  one-way in p50 {:.1} µs  resent {}  rejected {}  capped {}  forged {}",
            report::escape(&h.host),
            h.robots,
            state.trim_matches('"'),
            h.link.reconnects,
            h.link.down_ms,
            h.link.rtt_ns.p50 as f64 / 1e3,
            h.link.rtt_ns.p999 as f64 / 1e3,
            h.link.one_way_in_ns.p50 as f64 / 1e3,
            h.link.resent,
            h.link.rejected,
            h.link.capped,
            h.link.forged
        )?;
    }
    for r in &hub.refused {
        crate::term::out!("  refused join       {}", report::escape(r))?;
    }
    if hub.refused_total > hub.refused.len() as u64 {
        crate::term::out!(
            "  refused joins      {} in all ({} not kept)",
            hub.refused_total,
            hub.refused_total - hub.refused.len() as u64
        )?;
    }
    if hub.unauthenticated > 0 {
        crate::term::out!(
            "  unauthenticated    {} join queries without a valid proof of the join secret (dropped)",
            hub.unauthenticated
        )?;
    }
    if !hub.given_up.is_empty() || hub.foreign_frames > 0 || hub.expired_hosts > 0 {
        crate::term::out!(
            "  not joined         robots {:?} given up; {} host(s) did not start in time; {} frame(s) from no joined host",
            hub.given_up,
            hub.expired_hosts,
            hub.foreign_frames
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_frames_warn_and_the_hint_names_a_reachable_address() {
        for quiet in [
            "tcp/127.0.0.1:7447",
            "tcp/10.0.0.1:7447",
            "tcp/8.8.8.8:7447",
            "tcp/[::1]:7447",
            "tcp/hub.lan:7447",
        ] {
            // joins are authenticated and frames sealed: no address needs a warning
            assert_eq!(listen_warning(quiet, false), None, "{quiet}");
            assert_eq!(join_hint(quiet), quiet);
            let w = listen_warning(quiet, true).expect("plain frames always warn");
            assert!(w.contains("unencrypted"), "{w}");
        }
        let w = listen_warning("tcp/0.0.0.0:7447", false).expect("a note");
        assert!(
            w.contains("every interface") && w.contains("tcp/<this-host-address>:7447"),
            "{w}"
        );
        assert!(!w.contains("join tcp/0.0.0.0"), "{w}");
        assert_eq!(join_hint("tcp/[::]:9000"), "tcp/<this-host-address>:9000");
    }

    #[test]
    fn a_written_secret_is_private_and_reads_back() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("qfleet-secret-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let s = Secret::generate("run-7").unwrap();
        let path = write_secret(&dir, &s).unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        assert_eq!(read_secret(Some(&path)).unwrap(), Some(s.clone()));
        // written again (the next seed of an experiment): replaced, still private
        write_secret(&dir, &s).unwrap();
        std::fs::write(dir.join("bad"), "not a secret").unwrap();
        assert!(read_secret(Some(&dir.join("bad"))).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }

    fn remote(robots: u32, deadline_s: f64) -> RemoteArgs {
        RemoteArgs {
            remote_robots: robots,
            listen: Some("tcp/127.0.0.1:7447".into()),
            host_deadline: deadline_s,
            link_down_ms: 500,
            start_within: 10.0,
            join_within: 15.0,
            secret_file: None,
            insecure_plain: false,
            secret_label: None,
            secret: Default::default(),
        }
    }

    #[test]
    fn remote_robots_turn_hung_only_well_after_their_host_is_given_up() {
        // a killed host's robots must come out lost, not hung: the hang deadline is later
        assert_eq!(remote(2, 3.0).hang_ms(2000), 3000 + LOSS_MARGIN_MS);
        assert!(remote(2, 3.0).hang_ms(2000) > 3000);
        // a longer hang deadline asked for is kept; a local-only run is untouched
        assert_eq!(remote(2, 3.0).hang_ms(60_000), 60_000);
        assert_eq!(remote(0, 3.0).hang_ms(2000), 2000);
    }
}
